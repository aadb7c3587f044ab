//! Instance norm (no affine, eps 1e-5, biased variance): forward is
//! `dnr_runtime::nn::norm::instance_norm`, which returns the statistics kept here.

use dnr_runtime::nn::norm::NormStats;
use dnr_runtime::nn::tensor::par_min_items;
use dnr_runtime::nn::Tensor;
use rayon::prelude::*;

use dnr_runtime::nn::simd::widest;

/// Values per f32 partial sum of [`lrelu_instance_norm_backward`] (then summed in f64).
const SUM_BLOCK: usize = 256;

/// Backward of instance norm, in place: `g` holds dL/dy on entry and dL/dx on return.
/// y: the normalised output `c x H x W`; stats: from the forward.
/// `dx = rstd * (dy - mean(dy) - y * mean(dy * y))`, means in f64.
pub fn instance_norm_backward(y: &Tensor, stats: &NormStats, g: &mut Tensor) {
    assert!(
        y.c == g.c && y.h == g.h && y.w == g.w && stats.rstd.len() == y.c,
        "instance norm backward shape"
    );
    let n = y.plane_len();
    if n == 0 {
        return;
    }
    g.data
        .par_chunks_mut(n)
        .zip(y.data.par_chunks(n))
        .with_min_len(par_min_items(n))
        .enumerate()
        .for_each(|(c, (gp, yp))| {
            let (mut s, mut sy) = (0.0f64, 0.0f64);
            for (&gv, &yv) in gp.iter().zip(yp) {
                s += gv as f64;
                sy += gv as f64 * yv as f64;
            }
            let (mg, mgy) = ((s / n as f64) as f32, (sy / n as f64) as f32);
            let r = stats.rstd[c];
            for (gv, &yv) in gp.iter_mut().zip(yp) {
                *gv = r * (*gv - mg - yv * mgy);
            }
        });
}

/// LeakyReLU backward followed by instance-norm backward, fused (two passes over the plane
/// instead of three), in place: `g` holds dL/d(lrelu(y)) on entry and dL/dx on return.
/// y: the normalised output before the LeakyReLU (`c x H x W`); stats: from the forward.
pub fn lrelu_instance_norm_backward(y: &Tensor, stats: &NormStats, slope: f32, g: &mut Tensor) {
    assert!(
        y.c == g.c && y.h == g.h && y.w == g.w && stats.rstd.len() == y.c,
        "instance norm backward shape"
    );
    let n = y.plane_len();
    if n == 0 {
        return;
    }
    g.data
        .par_chunks_mut(n)
        .zip(y.data.par_chunks(n))
        .with_min_len(par_min_items(n))
        .enumerate()
        .for_each(|(c, (gp, yp))| {
            widest(
                #[inline(always)]
                move || {
                    // f32 partial sums in 8 lanes over blocks of SUM_BLOCK values (vectorised),
                    // the blocks summed in f64: fixed order, so deterministic, and accurate at
                    // any size. `move` copies `slope` in: read through a reference it was
                    // loaded under a branch per value, mispredicted on every sign change.
                    let (mut s, mut sy) = (0.0f64, 0.0f64);
                    for (gb, yb) in gp.chunks_mut(SUM_BLOCK).zip(yp.chunks(SUM_BLOCK)) {
                        let (mut s8, mut sy8) = ([0.0f32; 8], [0.0f32; 8]);
                        let mut gc = gb.chunks_exact_mut(8);
                        let mut yc = yb.chunks_exact(8);
                        for (g8, y8) in gc.by_ref().zip(yc.by_ref()) {
                            for l in 0..8 {
                                let gv = g8[l] * if y8[l] < 0.0 { slope } else { 1.0 };
                                g8[l] = gv;
                                s8[l] += gv;
                                sy8[l] += gv * y8[l];
                            }
                        }
                        for (l, (gv, &yv)) in gc
                            .into_remainder()
                            .iter_mut()
                            .zip(yc.remainder())
                            .enumerate()
                        {
                            *gv *= if yv < 0.0 { slope } else { 1.0 };
                            s8[l] += *gv;
                            sy8[l] += *gv * yv;
                        }
                        s += s8.iter().map(|&v| f64::from(v)).sum::<f64>();
                        sy += sy8.iter().map(|&v| f64::from(v)).sum::<f64>();
                    }
                    let (mg, mgy) = ((s / n as f64) as f32, (sy / n as f64) as f32);
                    let r = stats.rstd[c];
                    for (gv, &yv) in gp.iter_mut().zip(yp) {
                        *gv = r * (*gv - mg - yv * mgy);
                    }
                },
            )
        });
}
