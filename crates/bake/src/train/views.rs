//! Per-view training data, computed once: the runtime's G-buffer of the proxy mesh (uv in
//! f32, coverage, view directions) and the target image, composited on white.

use dnr_runtime::gbuffer::GBuffer;
use dnr_runtime::raster::rasterize;
use dnr_runtime::scene::Scene;
use dnr_runtime::supersample::subsample_camera;
use rayon::prelude::*;

use crate::capture::Frame;

/// One view ready for training or evaluation.
#[derive(Clone, Debug)]
pub struct View {
    /// The frame's name (for reports).
    pub name: String,
    /// Rasterised proxy: uv, coverage, view directions (the same rasteriser the runtime draws
    /// with, so training sees exactly what rendering will).
    pub gbuf: GBuffer,
    /// Target colour composited on white, planar (3 x H x W), sRGB-encoded [0, 1].
    pub target: Vec<f32>,
    /// Target alpha (the capture's mask), H x W.
    pub alpha: Vec<f32>,
    /// Whether the capture gave a mask (alpha channel).
    pub has_alpha: bool,
    /// H x W: false where a pixel gives no loss and does not count in evaluation (masked
    /// out, or outside the undistorted photograph); None when all are valid.
    pub valid: Option<Vec<bool>>,
    /// The G-buffer of the subsamples (`s` times the width and height) when the renderer
    /// is supersampled (spec "Supersampled Features"); None at one sample per pixel.
    pub fine: Option<GBuffer>,
}

impl View {
    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.gbuf.width
    }
    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.gbuf.height
    }

    /// Whether pixel `i` gives loss and counts in evaluation.
    pub fn is_valid(&self, i: usize) -> bool {
        self.valid.as_ref().is_none_or(|v| v[i])
    }

    /// Subsamples per pixel side of the features (1 without a subsample G-buffer).
    pub fn supersample(&self) -> usize {
        self.fine
            .as_ref()
            .map_or(1, |f| f.width / self.gbuf.width.max(1))
    }

    /// The G-buffer the features are sampled at: the subsamples', or the pixels'.
    pub fn feature_gbuf(&self) -> &GBuffer {
        self.fine.as_ref().unwrap_or(&self.gbuf)
    }

    /// Rasterises `scene` for `frame` (and, with `s > 1`, for its `s x s` subsamples) and
    /// converts its image to planar targets.
    pub fn new(scene: &Scene, frame: &Frame, s: u32) -> View {
        let gbuf = rasterize(scene, &frame.camera);
        let fine = (s > 1).then(|| rasterize(scene, &subsample_camera(&frame.camera, s)));
        let n = gbuf.width * gbuf.height;
        let mut target = vec![0.0f32; 3 * n];
        for i in 0..n {
            let a = frame.alpha[i].clamp(0.0, 1.0);
            for c in 0..3 {
                target[c * n + i] = frame.rgb[3 * i + c] * a + (1.0 - a);
            }
        }
        View {
            name: frame.name.clone(),
            gbuf,
            target,
            alpha: frame.alpha.clone(),
            has_alpha: frame.has_alpha,
            valid: frame.valid.clone(),
            fine,
        }
    }

    /// A crop `[x0, x0+w) x [y0, y0+h)` of this view (uv maps are cut, never resampled).
    /// The subsamples are cut too when `with_subsamples` (dropped otherwise).
    pub fn crop(&self, x0: usize, y0: usize, w: usize, h: usize, with_subsamples: bool) -> View {
        let src_w = self.width();
        let n_src = src_w * self.height();
        let g = crop_gbuffer(&self.gbuf, x0, y0, w, h);
        let ss = self.supersample();
        let fine = self
            .fine
            .as_ref()
            .filter(|_| with_subsamples)
            .map(|f| crop_gbuffer(f, ss * x0, ss * y0, ss * w, ss * h));
        let mut target = vec![0.0f32; 3 * w * h];
        let mut alpha = vec![0.0f32; w * h];
        let mut valid = self.valid.as_ref().map(|_| vec![false; w * h]);
        for y in 0..h {
            for x in 0..w {
                let s = (y0 + y) * src_w + x0 + x;
                let d = y * w + x;
                for c in 0..3 {
                    target[c * w * h + d] = self.target[c * n_src + s];
                }
                alpha[d] = self.alpha[s];
                if let Some(v) = valid.as_mut() {
                    v[d] = self.is_valid(s);
                }
            }
        }
        View {
            name: self.name.clone(),
            gbuf: g,
            target,
            alpha,
            has_alpha: self.has_alpha,
            valid,
            fine,
        }
    }

    /// Fraction of pixels covered by the proxy or by the target mask.
    pub fn object_fraction(&self) -> f32 {
        let n = self.alpha.len().max(1);
        let hits = self
            .alpha
            .iter()
            .zip(&self.gbuf.coverage)
            .filter(|(&a, &c)| a > 0.0 || c > 0.0)
            .count();
        hits as f32 / n as f32
    }
}

/// The window `[x0, x0+w) x [y0, y0+h)` of a G-buffer (values cut, never resampled).
fn crop_gbuffer(src: &GBuffer, x0: usize, y0: usize, w: usize, h: usize) -> GBuffer {
    let mut g = GBuffer::new(w, h);
    for y in 0..h {
        let s = (y0 + y) * src.width + x0;
        let d = y * w;
        g.uv[d..d + w].copy_from_slice(&src.uv[s..s + w]);
        g.coverage[d..d + w].copy_from_slice(&src.coverage[s..s + w]);
        g.prim[d..d + w].copy_from_slice(&src.prim[s..s + w]);
        g.tri[d..d + w].copy_from_slice(&src.tri[s..s + w]);
        g.depth[d..d + w].copy_from_slice(&src.depth[s..s + w]);
        g.view_dir[d..d + w].copy_from_slice(&src.view_dir[s..s + w]);
    }
    g
}

/// Prepares all frames in parallel, with `s x s` subsamples per pixel when `s > 1`.
pub fn prepare(scene: &Scene, frames: &[Frame], s: u32) -> Vec<View> {
    frames.par_iter().map(|f| View::new(scene, f, s)).collect()
}
