//! Image files of a capture: path resolution (extension-less names), header probing and
//! decoding to sRGB-encoded float RGB plus an alpha mask.
//!
//! Colour semantics: training and evaluation work on sRGB-encoded values in [0, 1] (what an
//! 8-bit PNG stores / 255), so PNG and JPEG samples are only rescaled (8-bit / 255, 16-bit /
//! 65535). EXR holds linear light with (by OpenEXR convention) premultiplied alpha: it is
//! un-premultiplied, clamped to [0, 1] and sRGB-encoded, so an EXR capture and the PNG a
//! tone-mapper-free export of it would give agree. Alpha is never encoded: it is coverage.
//! Images without alpha get a mask of all ones.
//!
//! Non-finite EXR samples (renderers write NaN and infinite fireflies) are replaced before
//! anything else, per sample: `NaN` and `-inf` become 0, `+inf` becomes 1 (the top of the
//! range colours are clamped to anyway). So a NaN alpha makes the pixel background and a NaN
//! colour makes it black. [`DecodedImage::non_finite`] counts them and names the first, and
//! [`super::Capture::load`] turns that into a warning naming the file and the pixel: no NaN
//! ever reaches training, and none is dropped silently.

use std::io::Read;
use std::path::{Path, PathBuf};

use super::error::CaptureError;

/// Extensions tried, in order, for a `file_path` that names no existing file.
pub const TRIED_EXTENSIONS: [&str; 8] = ["png", "jpg", "jpeg", "exr", "PNG", "JPG", "JPEG", "EXR"];

const EXR_MAGIC: [u8; 4] = [0x76, 0x2f, 0x31, 0x01];

/// A decoded image: `rgb` is HWC, sRGB-encoded, in [0, 1]; `alpha` is straight coverage.
#[derive(Clone, Debug, PartialEq)]
pub struct DecodedImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `height * width * 3` sRGB-encoded values, row 0 (top) first.
    pub rgb: Vec<f32>,
    /// `height * width` alpha values (all ones when the file has no alpha channel).
    pub alpha: Vec<f32>,
    /// Whether the file had an alpha channel.
    pub has_alpha: bool,
    /// Non-finite samples the file held (EXR only), replaced by the rule in the module
    /// documentation; None when every sample was finite.
    pub non_finite: Option<NonFinite>,
}

/// Non-finite samples found in an image file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct NonFinite {
    /// How many samples (over R, G, B and A) were NaN or infinite.
    pub count: u64,
    /// Pixel `(x, y)` (y = 0 at the top) of the first one, in row-major order.
    pub first_pixel: (u32, u32),
    /// Its channel: `R`, `G`, `B` or `A`.
    pub first_channel: char,
}

impl std::fmt::Display for NonFinite {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (x, y) = self.first_pixel;
        write!(
            f,
            "{} non-finite sample(s) (NaN or infinity), the first at pixel ({x}, {y}) channel {}; \
             replaced (NaN and -inf by 0, +inf by 1)",
            self.count, self.first_channel
        )
    }
}

/// The container a file holds, found from its first bytes (not its name).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum ImageKind {
    /// OpenEXR (linear).
    Exr,
    /// Anything the `image` crate reads (PNG, JPEG).
    Raster,
}

/// Resolves `file_path` against the capture folder. When it names no file, the extensions of
/// [`TRIED_EXTENSIONS`] are appended in turn (NeRF-synthetic writes `./train/r_0`).
pub(crate) fn resolve_image_path(dir: &Path, file_path: &str) -> Option<PathBuf> {
    let base = dir.join(file_path);
    if base.is_file() {
        return Some(base);
    }
    TRIED_EXTENSIONS.into_iter().find_map(|ext| {
        let mut s = base.clone().into_os_string();
        s.push(".");
        s.push(ext);
        let p = PathBuf::from(s);
        p.is_file().then_some(p)
    })
}

/// Reads only the header: the container kind and the size.
pub(crate) fn probe(path: &Path) -> Result<(ImageKind, u32, u32), CaptureError> {
    let mut magic = [0u8; 4];
    let mut f = std::fs::File::open(path).map_err(|e| CaptureError::io(path, e))?;
    let n = read_up_to(&mut f, &mut magic).map_err(|e| CaptureError::io(path, e))?;
    if n == 4 && magic == EXR_MAGIC {
        let meta =
            exr::meta::MetaData::read_from_file(path, false).map_err(|e| decode_err(path, e))?;
        let header = meta
            .headers
            .first()
            .ok_or_else(|| decode_err(path, "EXR file has no layers"))?;
        let size = header.layer_size;
        let to_u32 =
            |v: usize| u32::try_from(v).map_err(|_| decode_err(path, "EXR layer too large"));
        return Ok((ImageKind::Exr, to_u32(size.0)?, to_u32(size.1)?));
    }
    let reader = image::ImageReader::open(path)
        .map_err(|e| CaptureError::io(path, e))?
        .with_guessed_format()
        .map_err(|e| CaptureError::io(path, e))?;
    if reader.format().is_none() {
        return Err(decode_err(
            path,
            "unknown image format (expected PNG, JPEG or EXR)",
        ));
    }
    let (w, h) = reader.into_dimensions().map_err(|e| decode_err(path, e))?;
    Ok((ImageKind::Raster, w, h))
}

fn read_up_to(r: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut n = 0;
    while n < buf.len() {
        match r.read(&mut buf[n..])? {
            0 => break,
            k => n += k,
        }
    }
    Ok(n)
}

fn decode_err(path: &Path, e: impl std::fmt::Display) -> CaptureError {
    CaptureError::ImageDecode {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

/// Checks an image size against `max_side`.
pub(crate) fn check_side(path: &Path, w: u32, h: u32, max_side: u32) -> Result<(), CaptureError> {
    if w == 0 || h == 0 {
        return Err(decode_err(path, format!("image has zero size {w}x{h}")));
    }
    if w > max_side || h > max_side {
        return Err(CaptureError::TooLarge {
            path: path.to_path_buf(),
            message: format!("image is {w}x{h}, over the limit of {max_side} pixels per side"),
        });
    }
    Ok(())
}

/// Decodes a PNG (8/16-bit gray, gray+alpha, RGB, RGBA), JPEG or EXR file. The size is
/// checked against `max_side` from the header before any pixel is decoded.
pub fn decode_image(path: &Path, max_side: u32) -> Result<DecodedImage, CaptureError> {
    let (kind, w, h) = probe(path)?;
    check_side(path, w, h, max_side)?;
    let img = match kind {
        ImageKind::Exr => decode_exr(path)?,
        ImageKind::Raster => decode_raster(path, max_side)?,
    };
    if (img.width, img.height) != (w, h) {
        return Err(decode_err(path, "decoded size differs from the header"));
    }
    Ok(img)
}

fn decode_raster(path: &Path, max_side: u32) -> Result<DecodedImage, CaptureError> {
    let mut reader = image::ImageReader::open(path)
        .map_err(|e| CaptureError::io(path, e))?
        .with_guessed_format()
        .map_err(|e| CaptureError::io(path, e))?;
    let mut limits = image::Limits::no_limits();
    limits.max_image_width = Some(max_side);
    limits.max_image_height = Some(max_side);
    reader.limits(limits);
    let img = reader.decode().map_err(|e| decode_err(path, e))?;
    let has_alpha = img.color().has_alpha();
    let (width, height) = (img.width(), img.height());
    // 8-bit / 255 and 16-bit / 65535; gray is replicated; no colour-space change.
    let rgba = img.into_rgba32f();
    let n = width as usize * height as usize;
    let mut rgb = Vec::with_capacity(n * 3);
    let mut alpha = Vec::with_capacity(n);
    for p in rgba.pixels() {
        rgb.extend_from_slice(&[p.0[0], p.0[1], p.0[2]].map(|c| c.clamp(0.0, 1.0)));
        alpha.push(if has_alpha {
            p.0[3].clamp(0.0, 1.0)
        } else {
            1.0
        });
    }
    Ok(DecodedImage {
        width,
        height,
        rgb,
        alpha,
        has_alpha,
        non_finite: None,
    })
}

struct ExrPixels {
    width: usize,
    has_alpha: bool,
    rgba: Vec<f32>,
}

fn decode_exr(path: &Path) -> Result<DecodedImage, CaptureError> {
    let image = exr::prelude::read_first_rgba_layer_from_file(
        path,
        |res, channels: &exr::image::RgbaChannels| ExrPixels {
            width: res.0,
            has_alpha: channels.3.is_some(),
            rgba: vec![0.0; res.0 * res.1 * 4],
        },
        |px: &mut ExrPixels, pos, (r, g, b, a): (f32, f32, f32, f32)| {
            let i = (pos.1 * px.width + pos.0) * 4;
            px.rgba[i..i + 4].copy_from_slice(&[r, g, b, a]);
        },
    )
    .map_err(|e| decode_err(path, e))?;
    let size = image.layer_data.size;
    let px = image.layer_data.channel_data.pixels;
    let (width, height) = (
        u32::try_from(size.0).map_err(|_| decode_err(path, "EXR too large"))?,
        u32::try_from(size.1).map_err(|_| decode_err(path, "EXR too large"))?,
    );
    let n = size.0 * size.1;
    let mut rgb = Vec::with_capacity(n * 3);
    let mut alpha = Vec::with_capacity(n);
    let mut non_finite: Option<NonFinite> = None;
    for (i, p) in px.rgba.chunks_exact(4).enumerate() {
        let channels = if px.has_alpha { 4 } else { 3 };
        for (c, v) in p[..channels].iter().enumerate() {
            if !v.is_finite() {
                let nf = non_finite.get_or_insert(NonFinite {
                    count: 0,
                    // i < width * height, both checked to fit in u32 above.
                    first_pixel: ((i % size.0) as u32, (i / size.0) as u32),
                    first_channel: ['R', 'G', 'B', 'A'][c],
                });
                nf.count += 1;
            }
        }
        let a = if px.has_alpha {
            sanitize(p[3]).clamp(0.0, 1.0)
        } else {
            1.0
        };
        // Un-premultiply; fully transparent pixels keep their (zero) colour.
        let inv = if px.has_alpha && a > 1e-6 {
            1.0 / a
        } else {
            1.0
        };
        for &c in &p[..3] {
            rgb.push(linear_to_srgb(sanitize(c) * inv));
        }
        alpha.push(a);
    }
    Ok(DecodedImage {
        width,
        height,
        rgb,
        alpha,
        has_alpha: px.has_alpha,
        non_finite,
    })
}

/// The replacement rule for non-finite EXR samples (module documentation).
fn sanitize(x: f32) -> f32 {
    if x.is_finite() {
        x
    } else if x == f32::INFINITY {
        1.0
    } else {
        0.0
    }
}

/// sRGB transfer function (IEC 61966-2-1) after clamping to [0, 1]; computed in f64 so
/// 0 and 1 map exactly to 0 and 1.
pub fn linear_to_srgb(x: f32) -> f32 {
    let x = f64::from(x.clamp(0.0, 1.0));
    let y = if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    };
    y.clamp(0.0, 1.0) as f32
}

/// Inverse of [`linear_to_srgb`] on [0, 1].
pub fn srgb_to_linear(x: f32) -> f32 {
    let x = f64::from(x.clamp(0.0, 1.0));
    let y = if x <= 0.040_45 {
        x / 12.92
    } else {
        ((x + 0.055) / 1.055).powf(2.4)
    };
    y.clamp(0.0, 1.0) as f32
}

/// Decodes a mask image (PNG or JPEG, any channel layout) to one value per pixel in [0, 1]:
/// the luma of its colour (nerfstudio and COLMAP masks are grey: black means ignore). The
/// size is checked against `max_side` from the header first.
pub fn decode_mask(path: &Path, max_side: u32) -> Result<(u32, u32, Vec<f32>), CaptureError> {
    let (kind, w, h) = probe(path)?;
    check_side(path, w, h, max_side)?;
    if kind == ImageKind::Exr {
        return Err(decode_err(path, "masks must be PNG or JPEG, not EXR"));
    }
    let mut reader = image::ImageReader::open(path)
        .map_err(|e| CaptureError::io(path, e))?
        .with_guessed_format()
        .map_err(|e| CaptureError::io(path, e))?;
    let mut limits = image::Limits::no_limits();
    limits.max_image_width = Some(max_side);
    limits.max_image_height = Some(max_side);
    reader.limits(limits);
    let img = reader.decode().map_err(|e| decode_err(path, e))?;
    let luma = img.to_luma32f();
    Ok((
        luma.width(),
        luma.height(),
        luma.into_raw()
            .into_iter()
            .map(|v| v.clamp(0.0, 1.0))
            .collect(),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_round_trip_and_anchors() {
        assert_eq!(linear_to_srgb(0.0), 0.0);
        assert_eq!(linear_to_srgb(1.0), 1.0);
        assert_eq!(linear_to_srgb(7.0), 1.0);
        assert_eq!(linear_to_srgb(-1.0), 0.0);
        assert!((linear_to_srgb(0.18) - 0.4613).abs() < 1e-3);
        for i in 0..=100 {
            let x = i as f32 / 100.0;
            assert!((srgb_to_linear(linear_to_srgb(x)) - x).abs() < 1e-5);
        }
    }
}
