//! Resampling a photograph once at load: area-filtered downscaling to the working size, and
//! undistortion to the ideal pinhole camera with the same intrinsics.
//!
//! Both keep colour premultiplied by alpha while filtering, so a transparent background
//! never bleeds into the object, and resample an optional mask with the same weights.

use super::distortion::Distortion;

/// Pixels of one image being resampled: interleaved RGB, alpha, an optional mask in [0, 1].
#[derive(Clone, Debug, PartialEq)]
pub struct Planes {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `height * width * 3` colour values (straight alpha).
    pub rgb: Vec<f32>,
    /// `height * width` alpha values.
    pub alpha: Vec<f32>,
    /// `height * width` mask values (1 keep, 0 ignore), if the frame has a mask.
    pub mask: Option<Vec<f32>>,
}

/// The output size for an image of `w x h` whose longer side is limited to `max_side` (0: no
/// limit): the same aspect ratio, each side rounded, at least 1.
pub fn fit_size(w: u32, h: u32, max_side: u32) -> (u32, u32) {
    let long = w.max(h);
    if max_side == 0 || long <= max_side {
        return (w, h);
    }
    let s = max_side as f64 / long as f64;
    let side = |v: u32| ((v as f64 * s).round() as u32).clamp(1, max_side);
    (side(w), side(h))
}

/// Per output index, the source indices it covers and their weights (overlap lengths,
/// normalised to sum to 1): the box filter of exact area averaging.
fn area_taps(src: usize, dst: usize) -> Vec<Vec<(usize, f32)>> {
    let ratio = src as f64 / dst as f64;
    (0..dst)
        .map(|o| {
            let (a, b) = (o as f64 * ratio, (o + 1) as f64 * ratio);
            let mut taps = Vec::new();
            let mut i = a.floor() as usize;
            while (i as f64) < b && i < src {
                let w = (b.min(i as f64 + 1.0) - a.max(i as f64)) / ratio;
                if w > 0.0 {
                    taps.push((i, w as f32));
                }
                i += 1;
            }
            taps
        })
        .collect()
}

/// Area-averages an interleaved `ch`-channel image from `w x h` to `w2 x h2`.
fn area_resize(data: &[f32], ch: usize, w: usize, h: usize, w2: usize, h2: usize) -> Vec<f32> {
    let tx = area_taps(w, w2);
    let ty = area_taps(h, h2);
    // Rows first (h x w2), then columns.
    let mut tmp = vec![0.0f32; h * w2 * ch];
    for y in 0..h {
        let row = &data[y * w * ch..(y + 1) * w * ch];
        let out = &mut tmp[y * w2 * ch..(y + 1) * w2 * ch];
        for (x, taps) in tx.iter().enumerate() {
            for &(i, wt) in taps {
                for c in 0..ch {
                    out[x * ch + c] += wt * row[i * ch + c];
                }
            }
        }
    }
    let mut out = vec![0.0f32; h2 * w2 * ch];
    for (y, taps) in ty.iter().enumerate() {
        let dst = &mut out[y * w2 * ch..(y + 1) * w2 * ch];
        for &(i, wt) in taps {
            let src = &tmp[i * w2 * ch..(i + 1) * w2 * ch];
            for (d, s) in dst.iter_mut().zip(src) {
                *d += wt * s;
            }
        }
    }
    out
}

/// Downscales with an area filter (exact box averaging over each output pixel's footprint).
/// The intrinsics of the result are the source's scaled by `w2 / w` and `h2 / h`.
pub fn downscale(p: &Planes, w2: u32, h2: u32) -> Planes {
    let (w, h) = (p.width as usize, p.height as usize);
    let (w2u, h2u) = (w2 as usize, h2 as usize);
    let n = w * h;
    let mut pre = vec![0.0f32; n * 3];
    for i in 0..n {
        for c in 0..3 {
            pre[3 * i + c] = p.rgb[3 * i + c] * p.alpha[i];
        }
    }
    let pre = area_resize(&pre, 3, w, h, w2u, h2u);
    let alpha = area_resize(&p.alpha, 1, w, h, w2u, h2u);
    let rgb = unpremultiply(&pre, &alpha);
    let mask = p.mask.as_ref().map(|m| area_resize(m, 1, w, h, w2u, h2u));
    Planes {
        width: w2,
        height: h2,
        rgb,
        alpha,
        mask,
    }
}

fn unpremultiply(pre: &[f32], alpha: &[f32]) -> Vec<f32> {
    let mut rgb = vec![0.0f32; pre.len()];
    for (i, &a) in alpha.iter().enumerate() {
        if a > 1e-6 {
            for c in 0..3 {
                rgb[3 * i + c] = (pre[3 * i + c] / a).clamp(0.0, 1.0);
            }
        }
    }
    rgb
}

/// Pinhole intrinsics in pixels (pixel centres at half-integers).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Intrinsics {
    /// Focal length along x.
    pub fx: f64,
    /// Focal length along y.
    pub fy: f64,
    /// Principal point x.
    pub cx: f64,
    /// Principal point y.
    pub cy: f64,
}

/// Where output pixel `(x, y)` of the ideal pinhole camera `k` samples a photograph taken
/// through lens `d` with the same intrinsics, in index space (pixel centres at integers).
pub fn source_position(k: &Intrinsics, d: &Distortion, x: usize, y: usize) -> (f64, f64) {
    let xn = (x as f64 + 0.5 - k.cx) / k.fx;
    let yn = (y as f64 + 0.5 - k.cy) / k.fy;
    let (xd, yd) = d.distort(xn, yn);
    (k.fx * xd + k.cx - 0.5, k.fy * yd + k.cy - 0.5)
}

/// Resamples a photograph taken through lens `d` to the ideal pinhole camera with the same
/// intrinsics and size: each output pixel centre goes through the forward model in closed
/// form and the photograph is sampled bilinearly there. Returns the planes and, per pixel,
/// whether its sample lies inside the photograph (all four bilinear taps in the image):
/// pixels outside give no loss and do not count in evaluation.
pub fn undistort(p: &Planes, k: &Intrinsics, d: &Distortion) -> (Planes, Vec<bool>) {
    let (w, h) = (p.width as usize, p.height as usize);
    let n = w * h;
    let mut pre = vec![0.0f32; n * 3];
    let mut alpha = vec![0.0f32; n];
    let mut mask = p.mask.as_ref().map(|_| vec![0.0f32; n]);
    let mut inside = vec![false; n];
    let (xmax, ymax) = ((w - 1) as f64, (h - 1) as f64);
    // A tolerance of 1e-9 px keeps the identity map's border pixels inside.
    let eps = 1e-9;
    for y in 0..h {
        for x in 0..w {
            let (sx, sy) = source_position(k, d, x, y);
            if !(sx >= -eps && sy >= -eps && sx <= xmax + eps && sy <= ymax + eps) {
                continue;
            }
            let (sx, sy) = (sx.clamp(0.0, xmax), sy.clamp(0.0, ymax));
            let o = y * w + x;
            inside[o] = true;
            let (x0, y0) = (sx.floor() as usize, sy.floor() as usize);
            let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
            let (fx, fy) = ((sx - x0 as f64) as f32, (sy - y0 as f64) as f32);
            let taps = [
                (y0 * w + x0, (1.0 - fx) * (1.0 - fy)),
                (y0 * w + x1, fx * (1.0 - fy)),
                (y1 * w + x0, (1.0 - fx) * fy),
                (y1 * w + x1, fx * fy),
            ];
            let mut acc = [0.0f32; 4];
            let mut m = 0.0f32;
            for (i, wt) in taps {
                let a = p.alpha[i];
                for (c, v) in acc[..3].iter_mut().zip(&p.rgb[3 * i..3 * i + 3]) {
                    *c += wt * a * v;
                }
                acc[3] += wt * a;
                if let Some(src) = &p.mask {
                    m += wt * src[i];
                }
            }
            pre[3 * o..3 * o + 3].copy_from_slice(&acc[..3]);
            alpha[o] = acc[3];
            if let Some(mm) = mask.as_mut() {
                mm[o] = m;
            }
        }
    }
    let rgb = unpremultiply(&pre, &alpha);
    (
        Planes {
            width: p.width,
            height: p.height,
            rgb,
            alpha,
            mask,
        },
        inside,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fit_size_keeps_aspect() {
        assert_eq!(fit_size(4032, 3024, 1024), (1024, 768));
        assert_eq!(fit_size(3024, 4032, 1024), (768, 1024));
        assert_eq!(fit_size(800, 600, 1024), (800, 600));
        assert_eq!(fit_size(800, 600, 0), (800, 600));
        assert_eq!(fit_size(10000, 1, 100), (100, 1));
    }

    #[test]
    fn area_filter_preserves_the_mean_and_averages_blocks() {
        // 6 x 4 -> 3 x 2: each output pixel is the mean of a 2 x 2 block.
        let (w, h) = (6usize, 4usize);
        let data: Vec<f32> = (0..w * h).map(|i| i as f32).collect();
        let out = area_resize(&data, 1, w, h, 3, 2);
        assert_eq!(out[0], (0.0 + 1.0 + 6.0 + 7.0) / 4.0);
        let mean = |v: &[f32]| v.iter().sum::<f32>() / v.len() as f32;
        // Non-integer ratio: the mean is still preserved.
        let out = area_resize(&data, 1, w, h, 4, 3);
        assert!((mean(&out) - mean(&data)).abs() < 1e-4);
    }

    #[test]
    fn identity_lens_is_a_copy() {
        let p = Planes {
            width: 5,
            height: 3,
            rgb: (0..45).map(|i| i as f32 / 45.0).collect(),
            alpha: vec![1.0; 15],
            mask: Some(vec![1.0; 15]),
        };
        let k = Intrinsics {
            fx: 4.0,
            fy: 4.0,
            cx: 2.5,
            cy: 1.5,
        };
        let (q, inside) = undistort(&p, &k, &Distortion::default());
        assert!(inside.iter().all(|&b| b));
        for (a, b) in p.rgb.iter().zip(&q.rgb) {
            assert!((a - b).abs() < 1e-6);
        }
    }
}
