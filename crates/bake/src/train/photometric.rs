//! The photometric loss of a renderer output against a view's target, and its gradient.
//!
//! Two losses, both on the colour composited on white (as the target is) and on alpha:
//! - [`Loss::L1`], the paper's mean absolute error.
//! - [`Loss::L2`], squared error, with each crop's gradient scaled by the inverse of that
//!   crop's mean absolute error (held constant, not differentiated). The scale keeps the step
//!   sizes those of L1, so learning rates and the mean-colour term keep their meaning, while
//!   the direction is the squared error's: large errors (highlights, silhouettes, thin
//!   structures) pull harder than small ones. Held-out PSNR is a squared-error figure, but
//!   on the development set L2 won on some captures and lost more on others (mirror-like
//!   reflections it fits at the cost of the rest; docs/benchmarks.md), so L1 is the default.
//!
//! Either way the returned figure is the mean absolute error, so training records compare
//! across losses.

use rayon::prelude::*;
use serde::Serialize;

use super::views::View;

/// Pixels per parallel chunk (fixed: the sums are the same for any thread count).
const LOSS_CHUNK: usize = 4096;

/// Which photometric loss training minimises.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "camelCase")]
pub enum Loss {
    /// Mean absolute error (the paper's).
    L1,
    /// Squared error, each crop's gradient scaled to L1's size (see the module docs).
    L2,
}

impl std::str::FromStr for Loss {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "l1" => Ok(Loss::L1),
            "l2" => Ok(Loss::L2),
            _ => Err(format!("unknown loss '{s}' (expected l1 or l2)")),
        }
    }
}

impl std::fmt::Display for Loss {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Loss::L1 => "l1",
            Loss::L2 => "l2",
        })
    }
}

/// [`photometric_loss`] with [`Loss::L1`].
pub fn photometric_l1(y: &[f32], v: &View, out_ch: usize, dy: &mut [f32]) -> f64 {
    photometric_loss(y, v, out_ch, Loss::L1, dy)
}

/// One pixel's residuals: the composited colour's against the target, and with 4 outputs
/// alpha's against the mask; also alpha and the straight colour.
struct Residual {
    a: f32,
    col: [f32; 3],
    d: [f32; 3],
    da: f32,
}

fn residual(y: &[f32], v: &View, out_ch: usize, n: usize, i: usize) -> Residual {
    let a = if out_ch == 4 {
        0.5 * (y[3 * n + i] + 1.0)
    } else {
        v.gbuf.coverage[i]
    };
    let mut r = Residual {
        a,
        col: [0.0; 3],
        d: [0.0; 3],
        da: if out_ch == 4 { a - v.alpha[i] } else { 0.0 },
    };
    for c in 0..3 {
        let col = 0.5 * (y[c * n + i] + 1.0);
        r.col[c] = col;
        r.d[c] = col * a + (1.0 - a) - v.target[c * n + i];
    }
    r
}

/// Sums of |colour residual| (3 channels) and |alpha residual| over the valid pixels, in
/// fixed chunks added in order.
fn abs_sums(y: &[f32], v: &View, out_ch: usize, n: usize) -> (f64, f64) {
    let parts: Vec<(f64, f64)> = (0..n.div_ceil(LOSS_CHUNK))
        .into_par_iter()
        .map(|k| {
            let (mut sc, mut sa) = (0.0f64, 0.0f64);
            for i in k * LOSS_CHUNK..((k + 1) * LOSS_CHUNK).min(n) {
                if v.is_valid(i) {
                    let r = residual(y, v, out_ch, n, i);
                    sc += r.d.iter().map(|d| d.abs() as f64).sum::<f64>();
                    sa += r.da.abs() as f64;
                }
            }
            (sc, sa)
        })
        .collect();
    parts
        .iter()
        .fold((0.0, 0.0), |acc, p| (acc.0 + p.0, acc.1 + p.1))
}

/// The photometric loss of a renderer output `y` (U-Net or MLP, after tanh, `out_ch x n`,
/// n = the view's pixels) and its gradient, written to `dy` (same shape):
/// `colour = (t + 1) / 2`, `alpha = (t3 + 1) / 2` with 4 outputs (else the coverage),
/// `comp = colour * alpha + (1 - alpha)` (on white, like the target); the colour term over
/// 3 x n values, plus with 4 outputs the alpha term against the mask (gradient only).
/// With [`Loss::L1`] both terms are mean absolute errors. With [`Loss::L2`] each is
/// `sum d^2 / (2 m N)`, N the values and m their mean |d| (a constant of the step).
/// Pixels the view marks invalid (masked out, outside the undistorted photograph) give no
/// loss and no gradient, and n counts only the valid ones.
/// Returns the colour term's mean absolute error (whatever the loss); the sums run over
/// fixed chunks of pixels in parallel, added in chunk order (the same for any thread count).
///
/// Panics if `y`, `dy` or the view's target do not have those shapes (trainer-internal data).
pub fn photometric_loss(y: &[f32], v: &View, out_ch: usize, loss: Loss, dy: &mut [f32]) -> f64 {
    let n = v.gbuf.len();
    assert!(
        y.len() == out_ch * n && dy.len() == out_ch * n && v.target.len() >= 3 * n,
        "photometric loss: shapes"
    );
    // Valid pixels only (all of them for a view without a validity mask).
    let nv = v
        .valid
        .as_ref()
        .map_or(n, |m| m.iter().filter(|&&b| b).count());
    if nv == 0 {
        dy.fill(0.0);
        return 0.0;
    }
    // dL/dd per residual d: L1's sign times 1 / N, or L2's d / (m N).
    let (mut g, mut ga) = (1.0f64 / (3.0 * nv as f64), 1.0f64 / nv as f64);
    if loss == Loss::L2 {
        let (sc, sa) = abs_sums(y, v, out_ch, n);
        // A perfect crop has no gradient either way; the floor only avoids 0 / 0.
        g /= (sc / (3.0 * nv as f64)).max(1e-6);
        ga /= (sa / nv as f64).max(1e-6);
    }
    let (g, ga) = (g as f32, ga as f32);
    let slope = move |d: f32| match loss {
        Loss::L1 => d.signum(),
        Loss::L2 => d,
    };
    let (dcol, dal) = dy.split_at_mut(3 * n);
    let (d0, rest) = dcol.split_at_mut(n);
    let (d1, d2) = rest.split_at_mut(n);
    // Fixed chunks of pixels in parallel; every pixel's gradient is its own.
    let alpha_chunks: Vec<Option<&mut [f32]>> = if out_ch == 4 {
        dal.chunks_mut(LOSS_CHUNK).map(Some).collect()
    } else {
        (0..n.div_ceil(LOSS_CHUNK)).map(|_| None).collect()
    };
    let chunks: Vec<_> = d0
        .chunks_mut(LOSS_CHUNK)
        .zip(d1.chunks_mut(LOSS_CHUNK))
        .zip(d2.chunks_mut(LOSS_CHUNK))
        .zip(alpha_chunks)
        .enumerate()
        .collect();
    let partial: Vec<f64> = chunks
        .into_par_iter()
        .map(|(ci, (((c0, c1), c2), mut dal))| {
            let i0 = ci * LOSS_CHUNK;
            let mut dcol = [c0, c1, c2];
            let mut sum = 0.0f64;
            for j in 0..dcol[0].len() {
                let i = i0 + j;
                if !v.is_valid(i) {
                    for d in dcol.iter_mut() {
                        d[j] = 0.0;
                    }
                    if let Some(dal) = dal.as_deref_mut() {
                        dal[j] = 0.0;
                    }
                    continue;
                }
                let r = residual(y, v, out_ch, n, i);
                // dL/dalpha: the alpha term first, then each colour channel's share.
                let mut da = if r.da != 0.0 { ga * slope(r.da) } else { 0.0 };
                for ((dc, &d), &col) in dcol.iter_mut().zip(&r.d).zip(&r.col) {
                    sum += d.abs() as f64;
                    let dcomp = if d != 0.0 { g * slope(d) } else { 0.0 };
                    // comp = colour * a + (1 - a), colour = (t + 1) / 2.
                    dc[j] = 0.5 * dcomp * r.a;
                    da += dcomp * (col - 1.0);
                }
                if let Some(dal) = dal.as_deref_mut() {
                    dal[j] = 0.5 * da;
                }
            }
            sum
        })
        .collect();
    partial.iter().sum::<f64>() / (3.0 * nv as f64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use dnr_runtime::gbuffer::GBuffer;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A view with random targets, coverage, mask and (every 5th pixel) invalid pixels.
    fn view(r: &mut ChaCha8Rng, w: usize, h: usize) -> View {
        let n = w * h;
        let mut g = GBuffer::new(w, h);
        for c in g.coverage.iter_mut() {
            *c = r.random_range(0.0..1.0);
        }
        View {
            name: "synthetic".into(),
            gbuf: g,
            target: (0..3 * n).map(|_| r.random_range(0.0..1.0)).collect(),
            alpha: (0..n).map(|_| r.random_range(0.0..1.0)).collect(),
            has_alpha: true,
            valid: Some((0..n).map(|i| i % 5 != 2).collect()),
            fine: None,
        }
    }

    /// The loss in f64 whose gradient `photometric_loss` writes: L1's mean |d|, or L2's
    /// `sum d^2 / (2 m N)` with the scales `m` given (held constant, as in training).
    fn loss64(y: &[f64], v: &View, out_ch: usize, loss: Loss, m: (f64, f64)) -> f64 {
        let n = v.gbuf.len();
        let nv = (0..n).filter(|&i| v.is_valid(i)).count() as f64;
        let term = |d: f64, m: f64| match loss {
            Loss::L1 => d.abs(),
            Loss::L2 => d * d / (2.0 * m),
        };
        let mut total = 0.0;
        for i in (0..n).filter(|&i| v.is_valid(i)) {
            let a = if out_ch == 4 {
                0.5 * (y[3 * n + i] + 1.0)
            } else {
                v.gbuf.coverage[i] as f64
            };
            if out_ch == 4 {
                total += term(a - v.alpha[i] as f64, m.1) / nv;
            }
            for c in 0..3 {
                let comp = 0.5 * (y[c * n + i] + 1.0) * a + (1.0 - a);
                total += term(comp - v.target[c * n + i] as f64, m.0) / (3.0 * nv);
            }
        }
        total
    }

    #[test]
    fn gradients_match_central_differences() {
        let (w, h) = (7usize, 5usize);
        let n = w * h;
        for (k, (loss, out_ch)) in [(Loss::L1, 4), (Loss::L1, 3), (Loss::L2, 4), (Loss::L2, 3)]
            .into_iter()
            .enumerate()
        {
            let mut r = ChaCha8Rng::seed_from_u64(k as u64);
            let v = view(&mut r, w, h);
            let y: Vec<f32> = (0..out_ch * n).map(|_| r.random_range(-0.9..0.9)).collect();
            let mut dy = vec![0.0f32; out_ch * n];
            let mae = photometric_loss(&y, &v, out_ch, loss, &mut dy);
            let (sc, sa) = abs_sums(&y, &v, out_ch, n);
            let nv = (0..n).filter(|&i| v.is_valid(i)).count() as f64;
            let m = (sc / (3.0 * nv), sa / nv);
            // The returned figure is the colour term's mean absolute error, whatever the loss.
            assert!((mae - m.0).abs() < 1e-9, "case {k}: {mae} vs {}", m.0);
            let y64: Vec<f64> = y.iter().map(|&t| t as f64).collect();
            let eps = 1e-4;
            for j in 0..out_ch * n {
                let (mut p, mut q) = (y64.clone(), y64.clone());
                p[j] += eps;
                q[j] -= eps;
                let fd = (loss64(&p, &v, out_ch, loss, m) - loss64(&q, &v, out_ch, loss, m))
                    / (2.0 * eps);
                let tol = 1e-4 * (1.0 + fd.abs());
                assert!(
                    (dy[j] as f64 - fd).abs() < tol,
                    "case {k} ({loss}, {out_ch} outputs), value {j}: analytic {} vs {fd}",
                    dy[j]
                );
                if !v.is_valid(j % n) {
                    assert_eq!(dy[j], 0.0, "case {k}: invalid pixel {j} has a gradient");
                }
            }
        }
    }

    #[test]
    fn l2_weighs_large_errors_more_than_l1() {
        // Two covered pixels, errors 0.05 and 0.4 in red (0.1, 0.2 green; 0.3, 0.15 blue): L1
        // pushes both equally, L2 by size.
        let mut g = GBuffer::new(2, 1);
        g.coverage = vec![1.0, 1.0];
        let v = View {
            name: "two".into(),
            gbuf: g,
            target: vec![0.5, 0.5, 0.5, 0.5, 0.5, 0.5],
            alpha: vec![1.0, 1.0],
            has_alpha: true,
            valid: None,
            fine: None,
        };
        // colour = (t + 1) / 2, so t = 2 * colour - 1.
        let y = vec![0.1, 0.8, 0.2, 0.4, 0.6, 0.3];
        let mut d1 = vec![0.0f32; 6];
        let mut d2 = vec![0.0f32; 6];
        photometric_loss(&y, &v, 3, Loss::L1, &mut d1);
        photometric_loss(&y, &v, 3, Loss::L2, &mut d2);
        assert!((d1[0] - d1[1]).abs() < 1e-7);
        assert!((d2[1] / d2[0] - 8.0).abs() < 1e-4, "{:?}", d2);
        // The scale keeps L2's mean step that of L1 (every error non-zero here).
        let s1: f32 = d1.iter().map(|d| d.abs()).sum();
        let s2: f32 = d2.iter().map(|d| d.abs()).sum();
        assert!((s1 - s2).abs() < 1e-6, "{s1} vs {s2}");
    }
}
