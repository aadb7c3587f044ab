//! The renderer's output image: RGBA `f32`, straight alpha, sRGB-encoded colour.

/// An RGBA image as the spec's renderers produce it: sRGB-encoded colour in `[0, 1]`,
/// straight (not premultiplied) alpha in `[0, 1]`, row-major HWC, row 0 at the top.
///
/// This is the *neural layer* `N` of the spec ("Compositing Several Renderers"): pixels of
/// primitives without an `EXT_deferred_neural_rendering` binding, and background pixels no
/// renderer reaches,
/// are `(0, 0, 0, 0)`; a viewer composites it over the rest of its image.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RgbaImage {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// `height * width * 4` values: r, g, b, a per pixel.
    pub data: Vec<f32>,
}

impl RgbaImage {
    /// A fully transparent black image.
    pub fn new(width: usize, height: usize) -> Self {
        RgbaImage {
            width,
            height,
            data: vec![0.0; width * height * 4],
        }
    }

    /// Number of pixels.
    pub fn len(&self) -> usize {
        self.width * self.height
    }

    /// Whether the image has no pixels.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The four values of pixel `(x, y)`; None outside the image.
    pub fn pixel(&self, x: usize, y: usize) -> Option<[f32; 4]> {
        if x >= self.width || y >= self.height {
            return None;
        }
        let i = (y * self.width + x) * 4;
        self.data.get(i..i + 4).map(|p| [p[0], p[1], p[2], p[3]])
    }

    /// Quantises to 8 bits per channel as the conformance references are stored:
    /// `q = floor(255 * clamp(c, 0, 1) + 0.5)`; non-finite values give 0.
    pub fn to_rgba8(&self) -> Vec<u8> {
        self.data.iter().map(|&c| quantize(c)).collect()
    }

    /// Composites over an opaque sRGB-encoded background colour (straight-alpha
    /// source-over in sRGB space, as a PNG viewer does) and returns `height * width * 3`
    /// values in `[0, 1]`.
    pub fn over(&self, background: [f32; 3]) -> Vec<f32> {
        let mut out = Vec::with_capacity(self.len() * 3);
        for px in self.data.chunks_exact(4) {
            let a = finite_unit(px[3]);
            for k in 0..3 {
                out.push(a * finite_unit(px[k]) + (1.0 - a) * background[k]);
            }
        }
        out
    }
}

/// `floor(255 * clamp(c, 0, 1) + 0.5)`; non-finite gives 0.
pub fn quantize(c: f32) -> u8 {
    // The clamp keeps the product in [0, 255.5], so the cast cannot saturate.
    (255.0 * finite_unit(c) + 0.5).floor() as u8
}

/// `c` clamped to `[0, 1]`, 0 when not finite.
fn finite_unit(c: f32) -> f32 {
    if c.is_finite() {
        c.clamp(0.0, 1.0)
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantize_rounds_half_up_and_clamps() {
        assert_eq!(quantize(0.0), 0);
        assert_eq!(quantize(1.0), 255);
        assert_eq!(quantize(0.5), 128); // 127.5 + 0.5 = 128
        assert_eq!(quantize(-3.0), 0);
        assert_eq!(quantize(7.0), 255);
        assert_eq!(quantize(f32::NAN), 0);
        assert_eq!(quantize(100.0 / 255.0), 100);
    }

    #[test]
    fn over_white_blends_straight_alpha() {
        let img = RgbaImage {
            width: 2,
            height: 1,
            data: vec![0.0, 0.0, 0.0, 0.5, 0.2, 0.4, 0.6, 1.0],
        };
        let rgb = img.over([1.0; 3]);
        assert_eq!(rgb, vec![0.5, 0.5, 0.5, 0.2, 0.4, 0.6]);
        assert_eq!(img.pixel(1, 0), Some([0.2, 0.4, 0.6, 1.0]));
        assert_eq!(img.pixel(2, 0), None);
    }
}
