//! A cheap test of view dependence on the training images, before any training: does a
//! surface point's colour change with the direction it is seen from?
//!
//! Every interior object pixel is an observation `(texel, view direction, colour)`. Per texel
//! of a coarse uv grid, the colours are fitted by least squares with the degree-2 SH basis of
//! the view direction (the 9 functions the SH layer multiplies by; the first is the constant).
//! The part of the within-texel variance the basis explains, beyond what 8 free coefficients
//! explain in pure noise (`(p - 1) / (n - 1)` of it for `n` observations), is view-dependent
//! signal: highlights move with the camera, noise and sub-texel detail do not follow the
//! direction. The statistic is that excess, pooled over texels, as a fraction of the pooled
//! within-texel variance.
//!
//! The same observations choose the SH degree: the 7 degree-3 functions are fitted on top of
//! the 9, and what they explain of the degree-2 fit's residual beyond chance (`7 / (n - 9)` of
//! it) is sharper view dependence (highlights, reflections) that degree 2 smooths away.

use serde::Serialize;

use super::super::train::views::View;

/// Side of the uv grid the observations are binned into.
pub const GRID: usize = 64;
/// Observations a texel needs to take part (enough for 9 coefficients to mean something).
pub const MIN_OBSERVATIONS: usize = 24;
/// Excess explained fraction above which the scene counts as view dependent.
pub const THRESHOLD: f64 = 0.08;
/// Excess fraction the degree-3 functions must explain beyond degree 2 for degree 3: the
/// bar the layer itself must pass. On the development set (docs/benchmarks.md) degree 3 gained
/// 1 dB on the one capture above it (glossy, 0.097) and -0.6 to +0.4 dB below it.
pub const DEGREE3_THRESHOLD: f64 = THRESHOLD;

/// Basis functions of degree 2 and of degree 3.
const P2: usize = 9;
const P: usize = 16;

/// What the test measured.
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct ViewDependence {
    /// Excess fraction of the within-texel colour variance explained by the view direction.
    pub excess_explained: f64,
    /// Within-texel variance as a fraction of the total colour variance of the observations
    /// (how much of the image is not a fixed texture colour at all).
    pub within_texel_fraction: f64,
    /// Texels with enough observations.
    pub texels: usize,
    /// Observations used.
    pub observations: usize,
    /// The threshold the decision used ([`THRESHOLD`]).
    pub threshold: f64,
    /// The decision: keep the SH layer.
    pub view_dependent: bool,
    /// Excess fraction of the within-texel variance the degree-3 functions explain beyond
    /// the degree-2 fit.
    pub excess_explained_degree3: f64,
    /// The threshold of the degree decision ([`DEGREE3_THRESHOLD`]).
    pub degree3_threshold: f64,
    /// The SH degree the layer takes when kept: 3 above that threshold, else 2.
    pub degree: u32,
}

#[derive(Clone)]
struct Acc {
    n: usize,
    /// Upper triangle of `sum b b^T`.
    bb: [f64; P * P],
    /// `sum b y^T`, 9 x 3.
    by: [f64; P * 3],
    y: [f64; 3],
    yy: [f64; 3],
}

impl Default for Acc {
    fn default() -> Self {
        Acc {
            n: 0,
            bb: [0.0; P * P],
            by: [0.0; P * 3],
            y: [0.0; 3],
            yy: [0.0; 3],
        }
    }
}

/// Runs the test on the training views (wrap-around uvs are folded into the unit square).
pub fn measure(views: &[View]) -> ViewDependence {
    let mut acc = vec![Acc::default(); GRID * GRID];
    let mut b = [0.0f32; P];
    for v in views {
        let n = v.width() * v.height();
        for i in 0..n {
            // Interior object pixels only: silhouettes mix in the background.
            if v.gbuf.coverage[i] == 0.0 || v.alpha[i] < 0.99 {
                continue;
            }
            let [u, t] = v.gbuf.uv[i];
            let d = v.gbuf.view_dir[i];
            if !(u.is_finite() && t.is_finite()) || d == [0.0; 3] {
                continue;
            }
            let gx = ((u.rem_euclid(1.0) * GRID as f32) as usize).min(GRID - 1);
            let gy = ((t.rem_euclid(1.0) * GRID as f32) as usize).min(GRID - 1);
            dnr_runtime::sh::sh_basis(3, d, &mut b);
            let a = &mut acc[gy * GRID + gx];
            a.n += 1;
            for r in 0..P {
                for c in r..P {
                    a.bb[r * P + c] += (b[r] * b[c]) as f64;
                }
            }
            for c in 0..3 {
                let y = v.target[c * n + i] as f64;
                a.y[c] += y;
                a.yy[c] += y * y;
                for (r, &br) in b.iter().enumerate() {
                    a.by[r * 3 + c] += br as f64 * y;
                }
            }
        }
    }
    let (mut within, mut excess, mut texels, mut obs) = (0.0f64, 0.0f64, 0usize, 0usize);
    let mut excess3 = 0.0f64;
    let (mut all_n, mut all_y, mut all_yy) = (0usize, [0.0f64; 3], [0.0f64; 3]);
    for a in &acc {
        all_n += a.n;
        for c in 0..3 {
            all_y[c] += a.y[c];
            all_yy[c] += a.yy[c];
        }
        if a.n < MIN_OBSERVATIONS {
            continue;
        }
        let nf = a.n as f64;
        let ss_tot: f64 = (0..3).map(|c| a.yy[c] - a.y[c] * a.y[c] / nf).sum();
        let (Some(e2), Some(e3)) = (explained(a, P2), explained(a, P)) else {
            continue;
        };
        let e2 = e2.clamp(0.0, ss_tot.max(0.0));
        let e3 = e3.clamp(e2, ss_tot.max(0.0));
        let chance = ss_tot.max(0.0) * (P2 - 1) as f64 / (nf - 1.0);
        let chance3 = (ss_tot - e2).max(0.0) * (P - P2) as f64 / (nf - P2 as f64);
        within += ss_tot.max(0.0);
        excess += e2 - chance;
        excess3 += e3 - e2 - chance3;
        texels += 1;
        obs += a.n;
    }
    let total: f64 = (0..3)
        .map(|c| all_yy[c] - all_y[c] * all_y[c] / all_n.max(1) as f64)
        .sum();
    let excess_explained = if within > 0.0 { excess / within } else { 0.0 };
    let excess_explained_degree3 = if within > 0.0 { excess3 / within } else { 0.0 };
    ViewDependence {
        excess_explained,
        within_texel_fraction: if total > 0.0 { within / total } else { 0.0 },
        texels,
        observations: obs,
        threshold: THRESHOLD,
        view_dependent: excess_explained > THRESHOLD,
        excess_explained_degree3,
        degree3_threshold: DEGREE3_THRESHOLD,
        degree: if excess_explained_degree3 > DEGREE3_THRESHOLD {
            3
        } else {
            2
        },
    }
}

/// The colour sum of squares a least-squares fit with the first `p` basis functions explains
/// beyond the texel's mean (the basis starts with the constant): `b^T y . beta - n ybar^2`.
fn explained(a: &Acc, p: usize) -> Option<f64> {
    let beta = solve(&a.bb, &a.by, p)?;
    let nf = a.n as f64;
    Some(
        (0..3)
            .map(|c| {
                (0..p)
                    .map(|r| beta[r * 3 + c] * a.by[r * 3 + c])
                    .sum::<f64>()
                    - a.y[c] * a.y[c] / nf
            })
            .sum(),
    )
}

/// Solves `A beta = B` for the first `p` basis functions (A symmetric, the leading `p x p`
/// block of `bb`'s upper triangle, B the first `p` rows of `by`) by Cholesky with a small
/// ridge (directions that cover only part of the sphere make A near singular).
fn solve(bb: &[f64; P * P], by: &[f64; P * 3], p: usize) -> Option<[f64; P * 3]> {
    let mut a = [0.0f64; P * P];
    let trace: f64 = (0..p).map(|i| bb[i * P + i]).sum();
    let ridge = 1e-6 * trace / p as f64;
    for r in 0..p {
        for c in r..p {
            a[r * P + c] = bb[r * P + c];
            a[c * P + r] = bb[r * P + c];
        }
        a[r * P + r] += ridge;
    }
    // In-place Cholesky: lower triangle L with A = L L^T.
    for j in 0..p {
        let mut d = a[j * P + j];
        for k in 0..j {
            d -= a[j * P + k] * a[j * P + k];
        }
        if d <= 0.0 || !d.is_finite() {
            return None;
        }
        let d = d.sqrt();
        a[j * P + j] = d;
        for i in j + 1..p {
            let mut s = a[i * P + j];
            for k in 0..j {
                s -= a[i * P + k] * a[j * P + k];
            }
            a[i * P + j] = s / d;
        }
    }
    let mut x = [0.0f64; P * 3];
    x[..p * 3].copy_from_slice(&by[..p * 3]);
    for c in 0..3 {
        // Forward then back substitution.
        for i in 0..p {
            let mut s = x[i * 3 + c];
            for k in 0..i {
                s -= a[i * P + k] * x[k * 3 + c];
            }
            x[i * 3 + c] = s / a[i * P + i];
        }
        for i in (0..p).rev() {
            let mut s = x[i * 3 + c];
            for k in i + 1..p {
                s -= a[k * P + i] * x[k * 3 + c];
            }
            x[i * 3 + c] = s / a[i * P + i];
        }
    }
    Some(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cholesky_solves_a_known_system() {
        // A = diag(1..9) + 0.5 on the first off-diagonal, B from a known beta.
        let mut bb = [0.0; P * P];
        for i in 0..P {
            bb[i * P + i] = (i + 1) as f64;
            if i + 1 < P {
                bb[i * P + i + 1] = 0.5;
            }
        }
        let beta: Vec<f64> = (0..P * 3).map(|k| (k as f64 * 0.37).sin()).collect();
        let mut by = [0.0; P * 3];
        for r in 0..P {
            for c in 0..3 {
                by[r * 3 + c] = (0..P)
                    .map(|k| {
                        let (lo, hi) = (r.min(k), r.max(k));
                        bb[lo * P + hi] * beta[k * 3 + c]
                    })
                    .sum();
            }
        }
        let x = solve(&bb, &by, P).expect("positive definite");
        // The ridge (1e-6 of the mean diagonal) biases the solution by about that much.
        for k in 0..P * 3 {
            assert!(
                (x[k] - beta[k]).abs() < 1e-4,
                "{k}: {} vs {}",
                x[k],
                beta[k]
            );
        }
    }
}
