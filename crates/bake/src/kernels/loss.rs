//! Losses and regularisers with their gradients.

use dnr_runtime::nn::Tensor;
use rayon::prelude::*;

/// Pixels per parallel chunk of the colour loss (fixed: the same sums for any thread count).
const LOSS_CHUNK: usize = 4096;

/// L1 loss, mean over channels and pixels, with an optional per-pixel weight:
/// `L = sum_{c,p} w_p |pred - target| / (C * sum_p w_p)` (`w_p = 1` without weights, so the
/// plain mean; a 0/1 mask gives the mean over the masked pixels).
/// pred, target: `C x H x W`; weight: `H * W`. Adds `scale * dL/dpred` to `grad` (subgradient
/// 0 where pred == target). Returns L (0 when the weights sum to 0).
pub fn l1_loss(
    pred: &Tensor,
    target: &Tensor,
    weight: Option<&[f32]>,
    scale: f32,
    grad: &mut Tensor,
) -> f64 {
    assert!(
        pred.c == target.c && pred.h == target.h && pred.w == target.w,
        "l1 loss: target shape"
    );
    assert!(
        grad.c == pred.c && grad.h == pred.h && grad.w == pred.w,
        "l1 loss: grad shape"
    );
    let n = pred.plane_len();
    if let Some(w) = weight {
        assert_eq!(w.len(), n, "l1 loss: weight length");
    }
    let wsum = weight.map_or(n as f64, |w| w.iter().map(|&v| v as f64).sum());
    if wsum <= 0.0 || pred.c == 0 {
        return 0.0;
    }
    let denom = pred.c as f64 * wsum;
    let g = (scale as f64 / denom) as f32;
    let mut total = 0.0f64;
    for c in 0..pred.c {
        let (p, t, gr) = (pred.plane(c), target.plane(c), grad.plane_mut(c));
        let mut s = 0.0f64;
        for i in 0..n {
            let wi = weight.map_or(1.0, |w| w[i]);
            let d = p[i] - t[i];
            s += (wi * d.abs()) as f64;
            if d != 0.0 {
                gr[i] += g * wi * d.signum();
            }
        }
        total += s;
    }
    total / denom
}

/// Colour L1 on the first three feature channels over covered pixels:
/// `L = sum_{c<3, p covered} |features_c - target_c| / (3 * covered)`.
/// features: `C x H x W` (C >= 3); target: `3 x H x W` (or more; channels 0..2 used);
/// covered: `H * W`. Adds `scale * dL/dfeatures` (channels 0..2) to `grad` (`C x H x W`).
/// Returns L (0 without covered pixels).
pub fn colour_l1_loss(
    features: &Tensor,
    target: &Tensor,
    covered: &[bool],
    scale: f32,
    grad: &mut Tensor,
) -> f64 {
    assert!(
        target.c >= 3 && target.h == features.h && target.w == features.w,
        "colour l1: shapes"
    );
    assert_eq!(
        covered.len(),
        features.plane_len(),
        "colour l1: coverage length"
    );
    colour_l1_loss_where(features, &target.data, |i| covered[i], scale, grad)
}

/// [`colour_l1_loss`] with the target as planar values (`3 x H x W`, or more channels; 0..2
/// used) and the covered pixels given by a predicate on the pixel index, so a caller need not
/// build a target tensor or a mask. Same values, bit for bit.
pub fn colour_l1_loss_where(
    features: &Tensor,
    target: &[f32],
    covered: impl Fn(usize) -> bool + Sync,
    scale: f32,
    grad: &mut Tensor,
) -> f64 {
    let n = features.plane_len();
    assert!(
        features.c >= 3 && target.len() >= 3 * n,
        "colour l1: shapes"
    );
    assert!(
        grad.c == features.c && grad.h == features.h && grad.w == features.w,
        "colour l1: grad shape"
    );
    // Fixed chunks of pixels in parallel; the chunk sums are added in chunk order, so the
    // loss does not depend on the thread count.
    let count: usize = (0..n)
        .into_par_iter()
        .with_min_len(LOSS_CHUNK)
        .filter(|&i| covered(i))
        .count();
    if count == 0 {
        return 0.0;
    }
    let denom = 3.0 * count as f64;
    let g = (scale as f64 / denom) as f32;
    let mut total = 0.0f64;
    for c in 0..3 {
        let (f, t) = (features.plane(c), &target[c * n..(c + 1) * n]);
        let sums: Vec<f64> = grad
            .plane_mut(c)
            .par_chunks_mut(LOSS_CHUNK)
            .enumerate()
            .map(|(k, gr)| {
                let i0 = k * LOSS_CHUNK;
                let mut s = 0.0f64;
                for (j, gv) in gr.iter_mut().enumerate() {
                    let i = i0 + j;
                    if !covered(i) {
                        continue;
                    }
                    let d = f[i] - t[i];
                    s += d.abs() as f64;
                    if d != 0.0 {
                        *gv += g * d.signum();
                    }
                }
                s
            })
            .collect();
        total += sums.iter().sum::<f64>();
    }
    total / denom
}

/// Weight of level `k` of `levels` in the texture regulariser: `reg * (levels - 1 - k)`
/// (strongest on the finest level 0, none on the coarsest).
pub fn level_lambda(reg: f32, k: usize, levels: usize) -> f32 {
    reg * (levels - 1 - k) as f32
}

/// Per-level L2 regulariser `R = sum_k lambda_k mean(T_k^2)` with
/// `lambda_k = `[`level_lambda`]. Adds `dR/dT_k = 2 lambda_k T_k / numel(T_k)` to each
/// level's gradient; returns R.
pub fn texture_l2_reg(levels: &[&[f32]], reg: f32, grads: &mut [&mut [f32]]) -> f64 {
    assert_eq!(levels.len(), grads.len(), "texture reg: level count");
    let k_total = levels.len();
    let mut r = 0.0f64;
    for (k, (t, g)) in levels.iter().zip(grads.iter_mut()).enumerate() {
        assert_eq!(t.len(), g.len(), "texture reg: level {k} length");
        let lam = level_lambda(reg, k, k_total);
        if lam == 0.0 || t.is_empty() {
            continue;
        }
        let n = t.len() as f64;
        r += lam as f64 * t.iter().map(|&v| v as f64 * v as f64).sum::<f64>() / n;
        let c = (2.0 * lam as f64 / n) as f32;
        g.iter_mut()
            .zip(t.iter())
            .for_each(|(gv, &tv)| *gv += c * tv);
    }
    r
}
