//! Instance norm (no affine, eps 1e-5, biased variance): forward is
//! `dnr_runtime::nn::norm::instance_norm`, which returns the statistics kept here.

use dnr_runtime::nn::norm::NormStats;
use dnr_runtime::nn::tensor::par_min_items;
use dnr_runtime::nn::Tensor;
use rayon::prelude::*;

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
            // Four f64 partial sums (fixed order) so the loop vectorises.
            let (mut s, mut sy) = ([0.0f64; 4], [0.0f64; 4]);
            for (gc, yc) in gp.chunks_mut(4).zip(yp.chunks(4)) {
                for (l, (gv, &yv)) in gc.iter_mut().zip(yc).enumerate() {
                    *gv *= if yv < 0.0 { slope } else { 1.0 };
                    s[l] += *gv as f64;
                    sy[l] += *gv as f64 * yv as f64;
                }
            }
            let (s, sy) = (
                (s[0] + s[1]) + (s[2] + s[3]),
                (sy[0] + sy[1]) + (sy[2] + sy[3]),
            );
            let (mg, mgy) = ((s / n as f64) as f32, (sy / n as f64) as f32);
            let r = stats.rstd[c];
            for (gv, &yv) in gp.iter_mut().zip(yp) {
                *gv = r * (*gv - mg - yv * mgy);
            }
        });
}
