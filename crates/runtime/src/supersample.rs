//! Supersampled features (spec "Supersampled Features", revision 1.3): the camera of a
//! renderer's `s x s` subsample grid, and the box mean that turns subsample features into
//! pixel features, with its adjoint for training.
//!
//! The runtime's shading and the baker's training both call [`box_mean`], so the feature
//! image the baker optimises is the one the runtime draws.

use rayon::prelude::*;

use crate::camera::Camera;
use crate::nn::NnError;

/// The camera whose pixel centres are the subsamples of `camera`'s pixels: `s` times the
/// width and height, intrinsics scaled by `s`. Fine pixel `(s px + i, s py + j)` has its
/// centre at image point `(px + (i + 0.5) / s, py + (j + 0.5) / s)` of `camera`.
pub fn subsample_camera(camera: &Camera, s: u32) -> Camera {
    let f = s as f32;
    Camera {
        fx: camera.fx * f,
        fy: camera.fy * f,
        cx: camera.cx * f,
        cy: camera.cy * f,
        width: camera.width.saturating_mul(s),
        height: camera.height.saturating_mul(s),
        cam_to_world: camera.cam_to_world,
    }
}

fn check(
    fine: usize,
    coarse: usize,
    channels: usize,
    width: usize,
    height: usize,
    s: usize,
) -> Result<(), NnError> {
    let n = channels
        .checked_mul(width)
        .and_then(|v| v.checked_mul(height));
    let nf = n
        .and_then(|v| v.checked_mul(s))
        .and_then(|v| v.checked_mul(s));
    if s == 0 || n != Some(coarse) || nf != Some(fine) {
        return Err(NnError::Shape(format!(
            "box mean of {channels} x {height} x {width} pixels at {s} x {s} subsamples: \
             {fine} subsample and {coarse} pixel values"
        )));
    }
    Ok(())
}

/// The pixel feature image from the subsample feature image: `out[c, y, x]` is the mean of
/// `fine[c, s y + j, s x + i]` over `0 <= i, j < s`, summed in `f32` row by row, then scaled
/// by `1 / s^2`. `fine` is `channels x (s height) x (s width)`, `out` `channels x height x
/// width`, both planar.
pub fn box_mean(
    fine: &[f32],
    channels: usize,
    width: usize,
    height: usize,
    s: usize,
    out: &mut [f32],
) -> Result<(), NnError> {
    check(fine.len(), out.len(), channels, width, height, s)?;
    if out.is_empty() {
        return Ok(());
    }
    let fw = width * s;
    let scale = 1.0 / (s * s) as f32;
    // One output row per task: row `r` of the stacked planes reads fine rows `s r .. s r + s`
    // (planes stack the same way at both resolutions).
    // Rows of 2048 pixels or more make a task each; narrower rows are grouped so a task
    // still reads tens of kilobytes.
    let rows_per_task = (2048 / width).max(1);
    out.par_chunks_mut(width * rows_per_task)
        .enumerate()
        .for_each(|(t, rows)| {
            for (k, row) in rows.chunks_exact_mut(width).enumerate() {
                let r = t * rows_per_task + k;
                let src = &fine[r * s * fw..][..s * fw];
                if s == 2 {
                    // The same additions in the same order as below, in a form the compiler
                    // vectorises.
                    let (a, b) = src.split_at(fw);
                    for ((o, a), b) in row.iter_mut().zip(a.chunks_exact(2)).zip(b.chunks_exact(2))
                    {
                        *o = ((((0.0 + a[0]) + a[1]) + b[0]) + b[1]) * scale;
                    }
                    continue;
                }
                for (x, o) in row.iter_mut().enumerate() {
                    let mut acc = 0.0f32;
                    for j in 0..s {
                        for v in &src[j * fw + s * x..][..s] {
                            acc += v;
                        }
                    }
                    *o = acc * scale;
                }
            }
        });
    Ok(())
}

/// The adjoint of [`box_mean`]: every subsample of pixel `(x, y)` receives `dy[c, y, x] / s^2`.
pub fn box_mean_adjoint(
    dy: &[f32],
    channels: usize,
    width: usize,
    height: usize,
    s: usize,
    dfine: &mut [f32],
) -> Result<(), NnError> {
    check(dfine.len(), dy.len(), channels, width, height, s)?;
    if dy.is_empty() {
        return Ok(());
    }
    let fw = width * s;
    let scale = 1.0 / (s * s) as f32;
    // One pixel row (its s subsample rows) per task.
    dfine
        .par_chunks_mut(s * fw)
        .zip(dy.par_chunks(width))
        .for_each(|(rows, src)| {
            for row in rows.chunks_exact_mut(fw) {
                for (o, &d) in row.chunks_exact_mut(s).zip(src) {
                    o.fill(d * scale);
                }
            }
        });
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lcg(n: usize, seed: u64) -> Vec<f32> {
        let mut x = seed;
        (0..n)
            .map(|_| {
                x = x
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                ((x >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
            })
            .collect()
    }

    #[test]
    fn box_mean_averages_each_block() {
        // 1 channel, 2 x 1 pixels at s = 2: fine is 4 x 2.
        let fine = [1.0, 2.0, 10.0, 20.0, 3.0, 4.0, 30.0, 40.0];
        let mut out = [0.0; 2];
        box_mean(&fine, 1, 2, 1, 2, &mut out).unwrap();
        assert_eq!(out, [2.5, 25.0]);
        // s = 1 is the identity.
        let mut same = [0.0; 8];
        box_mean(&fine, 2, 2, 2, 1, &mut same).unwrap();
        assert_eq!(same, fine);
    }

    #[test]
    fn adjoint_matches_the_forward_in_the_inner_product() {
        // <box_mean(a), b> == <a, box_mean_adjoint(b)> for random a, b, at s = 2 and 3,
        // summed in f64: the finite-difference check of a linear map.
        for s in [2usize, 3] {
            let (c, w, h) = (3, 5, 4);
            let a = lcg(c * w * h * s * s, 1 + s as u64);
            let b = lcg(c * w * h, 7 + s as u64);
            let mut fa = vec![0.0; c * w * h];
            box_mean(&a, c, w, h, s, &mut fa).unwrap();
            let mut tb = vec![0.0; a.len()];
            box_mean_adjoint(&b, c, w, h, s, &mut tb).unwrap();
            let lhs: f64 = fa.iter().zip(&b).map(|(x, y)| *x as f64 * *y as f64).sum();
            let rhs: f64 = a.iter().zip(&tb).map(|(x, y)| *x as f64 * *y as f64).sum();
            assert!(
                (lhs - rhs).abs() < 1e-5 * lhs.abs().max(1.0),
                "{lhs} vs {rhs}"
            );
            // And a central difference of one output against one input.
            let (k, eps) = (17usize, 1e-2f32);
            let (mut up, mut dn) = (a.clone(), a.clone());
            up[k] += eps;
            dn[k] -= eps;
            let (mut ou, mut od) = (vec![0.0; fa.len()], vec![0.0; fa.len()]);
            box_mean(&up, c, w, h, s, &mut ou).unwrap();
            box_mean(&dn, c, w, h, s, &mut od).unwrap();
            let fd: f64 = ou
                .iter()
                .zip(&od)
                .zip(&b)
                .map(|((u, d), y)| (*u as f64 - *d as f64) / (2.0 * eps as f64) * *y as f64)
                .sum();
            assert!((fd - tb[k] as f64).abs() < 1e-4, "{fd} vs {}", tb[k]);
        }
    }

    #[test]
    fn shapes_are_checked() {
        let mut out = [0.0; 2];
        assert!(box_mean(&[0.0; 7], 1, 2, 1, 2, &mut out).is_err());
        assert!(box_mean(&[0.0; 8], 1, 2, 1, 0, &mut out).is_err());
        let mut d = [0.0; 7];
        assert!(box_mean_adjoint(&out, 1, 2, 1, 2, &mut d).is_err());
    }

    #[test]
    fn subsample_camera_puts_fine_centres_inside_pixels() {
        let c = Camera::look_at([0.0, 0.0, 3.0].into(), [0.0; 3].into(), 40.0, 8, 6);
        let f = subsample_camera(&c, 2);
        assert_eq!((f.width, f.height), (16, 12));
        // Fine pixel 3 (centre 3.5) is image point 1.75 of the coarse camera: the ray
        // directions agree.
        let fine_x = (3.5 - f.cx) / f.fx;
        let coarse_x = (1.75 - c.cx) / c.fx;
        assert!((fine_x - coarse_x).abs() < 1e-6);
    }
}
