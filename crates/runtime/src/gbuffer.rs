//! The G-buffer the rasteriser writes and the texture sampler reads: per-pixel surface
//! attributes, row-major, row 0 at the top of the image.

/// Per-pixel rasterisation result. Every vector holds `width * height` entries, row-major,
/// row 0 at the top. Pixel (x, y) has its centre at (x + 0.5, y + 0.5).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GBuffer {
    /// Image width in pixels.
    pub width: usize,
    /// Image height in pixels.
    pub height: usize,
    /// Interpolated texture coordinate (perspective-correct). Zero where uncovered; NaN where
    /// the covering primitive has no UVs (the sampler then yields zero, per DESIGN.md).
    pub uv: Vec<[f32; 2]>,
    /// 1.0 where a triangle covers the pixel centre, else 0.0.
    pub coverage: Vec<f32>,
    /// Index of the covering primitive in `Scene::primitives`; `u32::MAX` where uncovered.
    pub prim: Vec<u32>,
    /// Index of the covering triangle within its primitive; `u32::MAX` where uncovered.
    pub tri: Vec<u32>,
    /// View-space depth of the visible surface (distance along the camera's -Z axis);
    /// `+inf` where uncovered.
    pub depth: Vec<f32>,
    /// Unit direction from the eye to the surface point in the covering primitive's local
    /// space (DESIGN.md "View dependence"); zero where uncovered or undefined (singular
    /// world matrix).
    pub view_dir: Vec<[f32; 3]>,
}

/// `prim`/`tri` value of an uncovered pixel.
pub const NONE: u32 = u32::MAX;

impl GBuffer {
    /// An all-uncovered G-buffer.
    pub fn new(width: usize, height: usize) -> Self {
        let n = width * height;
        GBuffer {
            width,
            height,
            uv: vec![[0.0; 2]; n],
            coverage: vec![0.0; n],
            prim: vec![NONE; n],
            tri: vec![NONE; n],
            depth: vec![f32::INFINITY; n],
            view_dir: vec![[0.0; 3]; n],
        }
    }

    /// Resizes to `width x height` (reusing the allocations) and marks every pixel uncovered.
    pub fn reset(&mut self, width: usize, height: usize) {
        let n = width * height;
        self.width = width;
        self.height = height;
        for (v, fill) in [(&mut self.prim, NONE), (&mut self.tri, NONE)] {
            v.clear();
            v.resize(n, fill);
        }
        self.uv.clear();
        self.uv.resize(n, [0.0; 2]);
        self.coverage.clear();
        self.coverage.resize(n, 0.0);
        self.depth.clear();
        self.depth.resize(n, f32::INFINITY);
        self.view_dir.clear();
        self.view_dir.resize(n, [0.0; 3]);
    }

    /// Number of pixels (`width * height`).
    pub fn len(&self) -> usize {
        self.width * self.height
    }

    /// Whether the image has no pixels.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Whether pixel `i` (row-major index) is covered.
    #[inline]
    pub fn is_covered(&self, i: usize) -> bool {
        self.coverage[i] != 0.0
    }

    /// Number of covered pixels.
    pub fn covered_count(&self) -> usize {
        self.coverage.iter().filter(|&&c| c != 0.0).count()
    }

    /// Checks that every per-pixel vector has `width * height` entries.
    pub fn is_consistent(&self) -> bool {
        let n = self.width.checked_mul(self.height);
        n.is_some_and(|n| {
            [
                self.uv.len(),
                self.coverage.len(),
                self.prim.len(),
                self.tri.len(),
                self.depth.len(),
                self.view_dir.len(),
            ]
            .iter()
            .all(|&l| l == n)
        })
    }
}
