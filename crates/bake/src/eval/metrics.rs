//! Image error metrics: PSNR, object MSE and SSIM.
//!
//! In the capture format's convention (`docs/capture-format.md`): images are compared in sRGB 8-bit
//! space; PSNR over the full frame composited on white; MSE on [0, 255] colour values over the
//! object's pixels; SSIM (Wang et al. 2004, 11x11 Gaussian window, sigma 1.5, K1 0.01, K2 0.03)
//! averaged over the RGB channels.

/// An RGBA image with straight alpha, values in [0, 1], row-major HWC.
#[derive(Clone, Debug)]
pub struct Rgba<'a> {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// `width * height * 4` values in [0, 1], sRGB-encoded colour, straight alpha.
    pub data: &'a [f32],
}

/// Errors of one view.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct ViewError {
    /// PSNR in dB over the full frame composited on white (8-bit quantised).
    pub psnr: f64,
    /// MSE on [0, 255] over the object pixels (ground-truth alpha > 0.5), composited on white.
    pub mse_obj: f64,
    /// Number of object pixels the MSE was taken over.
    pub obj_pixels: usize,
    /// Mean SSIM over R, G, B of the frames composited on white.
    pub ssim: f64,
}

/// Composites straight-alpha RGBA over white and quantises to 8 bits, as a PNG viewer would.
pub fn on_white_u8(img: &Rgba) -> Vec<u8> {
    let mut out = Vec::with_capacity(img.width * img.height * 3);
    for px in img.data.chunks_exact(4) {
        let a = px[3].clamp(0.0, 1.0);
        for &c in &px[..3] {
            let v = c.clamp(0.0, 1.0) * a + (1.0 - a);
            out.push((v * 255.0).round() as u8);
        }
    }
    out
}

/// PSNR (dB) of two 8-bit RGB buffers; 100 dB for identical images.
pub fn psnr_u8(a: &[u8], b: &[u8]) -> f64 {
    let mse = mse_u8(a, b);
    if mse <= 1e-10 {
        100.0
    } else {
        10.0 * (255.0f64 * 255.0 / mse).log10()
    }
}

fn mse_u8(a: &[u8], b: &[u8]) -> f64 {
    let n = a.len().min(b.len()).max(1);
    let s: f64 = a
        .iter()
        .zip(b)
        .map(|(&x, &y)| {
            let d = x as f64 - y as f64;
            d * d
        })
        .sum();
    s / n as f64
}

/// All errors of a rendered view against its ground truth (same size).
pub fn view_error(render: &Rgba, truth: &Rgba) -> ViewError {
    view_error_masked(render, truth, None)
}

/// [`view_error`] over the pixels `valid` marks (every pixel when None): PSNR and object MSE
/// over them only; SSIM averaged over them, with the render's invalid pixels replaced by the
/// truth first, so they add no difference to their valid neighbours' windows.
pub fn view_error_masked(render: &Rgba, truth: &Rgba, valid: Option<&[bool]>) -> ViewError {
    assert_eq!((render.width, render.height), (truth.width, truth.height));
    let n = render.width * render.height;
    if let Some(v) = valid {
        assert_eq!(v.len(), n, "validity mask size");
    }
    let ok = |i: usize| valid.is_none_or(|v| v[i]);
    let mut r = on_white_u8(render);
    let t = on_white_u8(truth);
    for i in (0..n).filter(|&i| !ok(i)) {
        r[3 * i..3 * i + 3].copy_from_slice(&t[3 * i..3 * i + 3]);
    }
    let mut se = 0.0f64;
    let mut n_obj = 0usize;
    let mut se_all = 0.0f64;
    let mut n_valid = 0usize;
    for (i, px) in truth.data.chunks_exact(4).enumerate() {
        if !ok(i) {
            continue;
        }
        let mut d2 = 0.0;
        for c in 0..3 {
            let d = r[3 * i + c] as f64 - t[3 * i + c] as f64;
            d2 += d * d;
        }
        se_all += d2;
        n_valid += 1;
        if px[3] > 0.5 {
            se += d2;
            n_obj += 1;
        }
    }
    let mse = se_all / (3 * n_valid.max(1)) as f64;
    ViewError {
        psnr: if mse <= 1e-10 {
            100.0
        } else {
            10.0 * (255.0f64 * 255.0 / mse).log10()
        },
        mse_obj: if n_obj > 0 {
            se / (3 * n_obj) as f64
        } else {
            0.0
        },
        obj_pixels: n_obj,
        ssim: ssim_rgb_u8_masked(&r, &t, render.width, render.height, valid),
    }
}

/// Mean SSIM over the three channels of two interleaved 8-bit RGB images.
pub fn ssim_rgb_u8(a: &[u8], b: &[u8], w: usize, h: usize) -> f64 {
    ssim_rgb_u8_masked(a, b, w, h, None)
}

/// [`ssim_rgb_u8`] with the SSIM map averaged over the pixels `valid` marks.
fn ssim_rgb_u8_masked(a: &[u8], b: &[u8], w: usize, h: usize, valid: Option<&[bool]>) -> f64 {
    let mut total = 0.0;
    for c in 0..3 {
        let pa: Vec<f64> = a.iter().skip(c).step_by(3).map(|&v| v as f64).collect();
        let pb: Vec<f64> = b.iter().skip(c).step_by(3).map(|&v| v as f64).collect();
        total += ssim_plane(&pa, &pb, w, h, valid);
    }
    total / 3.0
}

/// SSIM of two planes with values on [0, 255]; Gaussian window with "valid" borders
/// (the window is renormalised where it leaves the image, so tiny images still work).
fn ssim_plane(a: &[f64], b: &[f64], w: usize, h: usize, valid: Option<&[bool]>) -> f64 {
    const R: isize = 5;
    const SIGMA: f64 = 1.5;
    let c1 = (0.01f64 * 255.0).powi(2);
    let c2 = (0.03f64 * 255.0).powi(2);
    let g: Vec<f64> = (-R..=R)
        .map(|i| (-((i * i) as f64) / (2.0 * SIGMA * SIGMA)).exp())
        .collect();
    // Separable blur of the five moment images.
    let blur = |src: &dyn Fn(usize) -> f64| -> Vec<f64> {
        let mut tmp = vec![0.0; w * h];
        for y in 0..h {
            for x in 0..w {
                let (mut s, mut ws) = (0.0, 0.0);
                for (k, gk) in g.iter().enumerate() {
                    let xx = x as isize + k as isize - R;
                    if xx >= 0 && (xx as usize) < w {
                        s += gk * src(y * w + xx as usize);
                        ws += gk;
                    }
                }
                tmp[y * w + x] = s / ws;
            }
        }
        let mut out = vec![0.0; w * h];
        for y in 0..h {
            for x in 0..w {
                let (mut s, mut ws) = (0.0, 0.0);
                for (k, gk) in g.iter().enumerate() {
                    let yy = y as isize + k as isize - R;
                    if yy >= 0 && (yy as usize) < h {
                        s += gk * tmp[yy as usize * w + x];
                        ws += gk;
                    }
                }
                out[y * w + x] = s / ws;
            }
        }
        out
    };
    let ma = blur(&|i| a[i]);
    let mb = blur(&|i| b[i]);
    let saa = blur(&|i| a[i] * a[i]);
    let sbb = blur(&|i| b[i] * b[i]);
    let sab = blur(&|i| a[i] * b[i]);
    let mut total = 0.0;
    let mut count = 0usize;
    for i in 0..w * h {
        if valid.is_some_and(|v| !v[i]) {
            continue;
        }
        count += 1;
        let va = saa[i] - ma[i] * ma[i];
        let vb = sbb[i] - mb[i] * mb[i];
        let cov = sab[i] - ma[i] * mb[i];
        total += ((2.0 * ma[i] * mb[i] + c1) * (2.0 * cov + c2))
            / ((ma[i] * ma[i] + mb[i] * mb[i] + c1) * (va + vb + c2));
    }
    total / count.max(1) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    fn img(w: usize, h: usize, f: impl Fn(usize, usize) -> [f32; 4]) -> Vec<f32> {
        (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .flat_map(|(x, y)| f(x, y))
            .collect()
    }

    #[test]
    fn identical_images_are_perfect() {
        let d = img(13, 7, |x, y| [x as f32 / 13.0, y as f32 / 7.0, 0.5, 1.0]);
        let a = Rgba {
            width: 13,
            height: 7,
            data: &d,
        };
        let e = view_error(&a, &a);
        assert_eq!(e.psnr, 100.0);
        assert_eq!(e.mse_obj, 0.0);
        assert!((e.ssim - 1.0).abs() < 1e-12);
    }

    #[test]
    fn psnr_and_object_mse_match_hand_computation() {
        // Truth: left half object (alpha 1, black), right half background.
        let t = img(4, 2, |x, _| {
            if x < 2 {
                [0.0, 0.0, 0.0, 1.0]
            } else {
                [0.0; 4]
            }
        });
        // Render: object pixels off by 10/255 in red only; background exact (white).
        let r = img(4, 2, |x, _| {
            if x < 2 {
                [10.0 / 255.0, 0.0, 0.0, 1.0]
            } else {
                [0.3, 0.3, 0.3, 0.0]
            }
        });
        let e = view_error(
            &Rgba {
                width: 4,
                height: 2,
                data: &r,
            },
            &Rgba {
                width: 4,
                height: 2,
                data: &t,
            },
        );
        // Object: 4 pixels x 3 channels, one channel each off by 10 -> MSE = 4*100/12.
        assert!((e.mse_obj - 100.0 / 3.0).abs() < 1e-9, "{}", e.mse_obj);
        // Frame: 24 values, 4 off by 10 -> MSE 400/24.
        let want = 10.0 * (255.0f64 * 255.0 / (400.0 / 24.0)).log10();
        assert!((e.psnr - want).abs() < 1e-9);
        assert!(e.ssim < 1.0);
    }
}
