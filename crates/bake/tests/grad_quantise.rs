//! Quantisation-aware fine-tuning (`train::quantise`): the straight-through gradients against
//! central differences of the loss as a function of the stored (rounded) values, and the
//! trainer's wiring (forward on the rounding, updates on the full-precision values).
//!
//! Rounding has a zero derivative almost everywhere, so the straight-through estimator
//! passes `dL/d(stored value)` to the full-precision value it was rounded from. What can be
//! checked exactly is that this gradient is the derivative of the loss with respect to the
//! stored values (the forward really runs on them), and that the backward's taps do not
//! depend on the values, so computing them from either pyramid gives the same result.

// Index loops mirror the math (level k, value i) and perturb copies in place.
#![allow(clippy::needless_range_loop)]

mod capture_common;

use dnr_bake::capture::{Capture, LoadOptions};
use dnr_bake::kernels::mlp::MlpTrain;
use dnr_bake::kernels::sample::{sample_backward, sample_forward};
use dnr_bake::train::config::{Arch, Preset, TrainConfig};
use dnr_bake::train::quantise::{quantised_pyramid, quantised_weights, QatTarget};
use dnr_bake::train::views;
use dnr_bake::train::Trainer;
use dnr_runtime::gbuffer::GBuffer;
use dnr_runtime::network::mlp::MlpParams;
use dnr_runtime::nn::Tensor;
use dnr_runtime::texture::{Level, Pyramid, Wrap};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn dot(a: &[f32], b: &[f32]) -> f64 {
    a.iter().zip(b).map(|(&x, &y)| x as f64 * y as f64).sum()
}

#[test]
fn texture_straight_through_gradient_is_the_derivative_at_the_stored_values() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let c = 5;
    let levels = [(9usize, 7usize), (5, 4)]
        .iter()
        .map(|&(w, h)| Level {
            width: w,
            height: h,
            data: (0..w * h * c)
                .map(|_| rng.random_range(-1.0..1.0))
                .collect(),
        })
        .collect();
    let pyr = Pyramid::new(c, levels, Wrap::Repeat, Wrap::ClampToEdge).unwrap();
    let q = quantised_pyramid(&pyr, &[Some(4), Some(8)]);
    assert_ne!(q.levels[0].data, pyr.levels[0].data, "level 0 is rounded");
    let (w, h) = (11, 9);
    let mut g = GBuffer::new(w, h);
    for i in 0..w * h {
        g.uv[i] = [rng.random_range(-0.2..1.2), rng.random_range(-0.2..1.2)];
        g.coverage[i] = 1.0;
    }
    let up: Vec<f32> = (0..c * w * h)
        .map(|_| rng.random_range(-1.0..1.0))
        .collect();
    let loss = |p: &Pyramid| {
        let mut out = vec![0.0; up.len()];
        sample_forward(p, &g, &mut out).unwrap();
        dot(&up, &out)
    };
    let zeros = |p: &Pyramid| -> Vec<Vec<f32>> {
        p.levels.iter().map(|l| vec![0.0; l.data.len()]).collect()
    };
    // The trainer takes the taps from the rounded pyramid and scatters into the full one.
    let mut from_q = zeros(&q);
    sample_backward(&q, &g, &up, &mut from_q).unwrap();
    let mut from_full = zeros(&pyr);
    sample_backward(&pyr, &g, &up, &mut from_full).unwrap();
    assert_eq!(from_q, from_full, "the backward does not read the values");
    // Linear in the stored values: a large central difference is exact up to rounding.
    let hstep = 0.5f32;
    for k in 0..q.levels.len() {
        for i in 0..q.levels[k].data.len() {
            let mut p = q.clone();
            p.levels[k].data[i] += hstep;
            let lp = loss(&p);
            p.levels[k].data[i] -= 2.0 * hstep;
            let lm = loss(&p);
            let fd = (lp - lm) / (2.0 * hstep as f64);
            let a = from_q[k][i] as f64;
            assert!(
                (a - fd).abs() <= 1e-4 * (1.0 + fd.abs()),
                "level {k} value {i}: straight-through {a} vs fd {fd}"
            );
        }
    }
}

#[test]
fn int8_straight_through_gradient_is_the_derivative_at_the_stored_weights() {
    straight_through_gradient_is_the_derivative_at_the_stored_weights(&QatTarget {
        int8_weights: true,
        ..QatTarget::default()
    });
}

#[test]
fn int4_straight_through_gradient_is_the_derivative_at_the_stored_weights() {
    // The first layer int4, the rest int8, as auto stores a large inner tensor.
    let p = MlpParams {
        in_ch: 4,
        hidden: vec![6],
        out_ch: 3,
    };
    let first = p.tensor_specs()[0].0.clone();
    let target = QatTarget {
        int8_weights: true,
        tensor_dtypes: [(first, dnr_format::model::DType::Int4)].into(),
        ..QatTarget::default()
    };
    let full = MlpTrain::init(p.clone(), 4).unwrap();
    let stored = quantised_weights(&p.tensor_specs(), &full.weights, &target);
    // Each row of the int4 tensor holds at most 15 values: -7..=7 steps of its scale.
    for row in stored[0].chunks(p.in_ch) {
        let mut v: Vec<f32> = row.to_vec();
        v.sort_by(f32::total_cmp);
        v.dedup();
        assert!(v.len() <= 15, "{row:?}");
    }
    straight_through_gradient_is_the_derivative_at_the_stored_weights(&target);
}

fn straight_through_gradient_is_the_derivative_at_the_stored_weights(target: &QatTarget) {
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let p = MlpParams {
        in_ch: 4,
        hidden: vec![6],
        out_ch: 3,
    };
    let full = MlpTrain::init(p.clone(), 4).unwrap();
    let stored = quantised_weights(&p.tensor_specs(), &full.weights, target);
    assert_ne!(stored[0], full.weights[0], "the weight matrix is rounded");
    assert_eq!(
        stored[1], full.weights[1],
        "biases stay as they are (f16 storage)"
    );
    let (h, w) = (3, 4);
    let x = Tensor::from_vec(
        4,
        h,
        w,
        (0..4 * h * w)
            .map(|_| rng.random_range(-1.0..1.0))
            .collect(),
    )
    .unwrap();
    let covered = vec![true; h * w];
    let up: Vec<f32> = (0..3 * h * w)
        .map(|_| rng.random_range(-1.0..1.0))
        .collect();
    let mut net = MlpTrain::init(p.clone(), 4).unwrap();
    net.weights = stored.clone();
    let (_, acts) = net.forward_frame(&x, &covered).unwrap();
    let dy = Tensor::from_vec(3, h, w, up.clone()).unwrap();
    net.backward_frame(&acts, &dy);
    // Reference: the MLP in f64 on the stored weights (LeakyReLU(0.2) between layers, tanh
    // at the end). Central differences with a small step in f64 do not straddle a kink of the
    // LeakyReLU, as a step of 1e-2 through the f32 network can (one did, by 0.025).
    let n = h * w;
    let x64: Vec<f64> = x.data.iter().map(|&v| v as f64).collect();
    let dims = p.layer_dims();
    let loss = |ws: &[Vec<f64>]| -> f64 {
        let mut total = 0.0;
        for i in 0..n {
            let mut z: Vec<f64> = (0..p.in_ch).map(|c| x64[c * n + i]).collect();
            for (l, &(ci, co)) in dims.iter().enumerate() {
                let (wt, b) = (&ws[2 * l], &ws[2 * l + 1]);
                z = (0..co)
                    .map(|o| {
                        let a = b[o] + (0..ci).map(|q| wt[o * ci + q] * z[q]).sum::<f64>();
                        if l + 1 == dims.len() {
                            a.tanh()
                        } else if a < 0.0 {
                            0.2 * a
                        } else {
                            a
                        }
                    })
                    .collect();
            }
            total += (0..p.out_ch)
                .map(|o| up[o * n + i] as f64 * z[o])
                .sum::<f64>();
        }
        total
    };
    let stored64: Vec<Vec<f64>> = stored
        .iter()
        .map(|t| t.iter().map(|&v| v as f64).collect())
        .collect();
    // The reference is the network: its loss at the stored weights is the f32 forward's.
    let (y, _) = net.forward_frame(&x, &covered).unwrap();
    let l32 = dot(&up, &y.data);
    assert!((loss(&stored64) - l32).abs() <= 1e-5 * (1.0 + l32.abs()));
    let eps = 1e-5;
    for t in 0..stored.len() {
        for i in 0..stored[t].len() {
            let mut wp = stored64.clone();
            wp[t][i] += eps;
            let lp = loss(&wp);
            wp[t][i] -= 2.0 * eps;
            let lm = loss(&wp);
            let fd = (lp - lm) / (2.0 * eps);
            let a = net.grads[t][i] as f64;
            assert!(
                (a - fd).abs() <= 1e-4 * (1.0 + fd.abs()),
                "tensor {t} element {i}: straight-through {a} vs fd {fd}"
            );
        }
    }
}

#[test]
fn fine_tuning_runs_on_the_rounding_and_updates_full_precision_values() {
    let dir = capture_common::sample_capture();
    let cap = Capture::load(&dir, &LoadOptions::default()).unwrap();
    let all = views::prepare(&cap.mesh, &cap.train, 1);
    let cfg = TrainConfig {
        resolution: 32,
        levels: 2,
        channels: 12,
        arch: Arch::Unet,
        widths: vec![4, 8],
        steps: 20,
        eval_every: 0.0,
        threads: 1,
        seed: 5,
        ..TrainConfig::preset(Preset::Fast)
    };
    let mut t = Trainer::new(cfg, &all).unwrap();
    for _ in 0..5 {
        t.step(&all).unwrap();
    }
    let plain = t.evaluate(&all[..2]).unwrap();
    t.set_qat(Some(QatTarget {
        level_bits: vec![Some(4), Some(4)],
        int8_weights: true,
        tensor_dtypes: Default::default(),
    }));
    let rounded = t.evaluate(&all[..2]).unwrap();
    assert_ne!(
        plain[0].psnr, rounded[0].psnr,
        "evaluation during fine-tuning reads the rounding"
    );
    let before = t.pyr.clone();
    for _ in 0..5 {
        assert!(t.step(&all).unwrap().is_finite());
    }
    assert_ne!(before, t.pyr, "the texture is updated");
    // The full-precision texture is not snapped to the 16 values per channel a 4-bit level
    // holds: the gradients land on the values the rounding was made from.
    let c = t.pyr.channels;
    let level = &t.pyr.levels[0].data;
    let mut distinct: Vec<u32> = level.iter().step_by(c).map(|v| v.to_bits()).collect();
    distinct.sort_unstable();
    distinct.dedup();
    assert!(distinct.len() > 16, "{} distinct values", distinct.len());
    // Turning it off restores the plain forward.
    t.set_qat(None);
    assert!(t.qat().is_none());
}
