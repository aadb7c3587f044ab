//! Training the per-pixel MLP renderer: the training forward is the runtime's forward, the
//! whole graph (pyramid sample -> SH -> MLP -> photometric L1) against f64 central
//! differences, a short bake on a synthetic capture read back by the runtime, and resuming
//! from a checkpoint reproduces the straight run bit for bit.
//!
//! Central differences use eps = 1e-5 in f64 on an independent f64 forward of the MLP and the
//! loss; sampling and SH are linear, so a texel's direction in feature space is the f32
//! forward of the unit texel (exact up to the f32 bilinear weights the backward uses too).
//! Tolerance `TOL * (|fd| + rms(fd))` per element.

// Index loops mirror the math (pixel i, channel k) and compare several arrays at once.
#![allow(clippy::needless_range_loop)]

mod capture_common;

use dnr_bake::capture::{Capture, LoadOptions};
use dnr_bake::kernels::mlp::MlpTrain;
use dnr_bake::kernels::sample::{sample_backward, sample_forward};
use dnr_bake::kernels::sh::{modulate_backward, modulate_forward};
use dnr_bake::train::checkpoint::Checkpoint;
use dnr_bake::train::config::{Arch, Preset, TrainConfig, DEFAULT_SUPERSAMPLE};
use dnr_bake::train::views::{self, View};
use dnr_bake::train::{photometric_l1, RunState, Trainer};
use dnr_runtime::gbuffer::GBuffer;
use dnr_runtime::network::mlp::{Mlp, MlpParams};
use dnr_runtime::nn::Tensor;
use dnr_runtime::texture::{Level, Pyramid, Wrap};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const EPS: f64 = 1e-5;
const TOL: f64 = 1e-3;

fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

fn randv(r: &mut ChaCha8Rng, n: usize, lo: f32, hi: f32) -> Vec<f32> {
    (0..n).map(|_| r.random_range(lo..hi)).collect()
}

fn assert_grad(got: &[f32], want: &[f64], tol: f64, what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    let rms = (want.iter().map(|v| v * v).sum::<f64>() / want.len().max(1) as f64).sqrt();
    assert!(rms > 0.0, "{what}: the reference gradient is all zero");
    for (i, (&g, &w)) in got.iter().zip(want).enumerate() {
        let err = (g as f64 - w).abs();
        assert!(
            err <= tol * (w.abs() + rms),
            "{what}[{i}]: analytic {g} vs central difference {w} (rms {rms})"
        );
    }
}

// ---------------------------------------------------------------- f64 reference

/// The MLP in f64 on one feature vector: LeakyReLU(0.2) between layers, tanh at the end.
fn mlp64(p: &MlpParams, ws: &[Vec<f64>], z0: &[f64]) -> Vec<f64> {
    let dims = p.layer_dims();
    let mut z = z0.to_vec();
    for (l, &(ci, co)) in dims.iter().enumerate() {
        let (w, b) = (&ws[2 * l], &ws[2 * l + 1]);
        let mut a: Vec<f64> = (0..co)
            .map(|o| b[o] + (0..ci).map(|q| w[o * ci + q] * z[q]).sum::<f64>())
            .collect();
        if l + 1 < dims.len() {
            a.iter_mut().for_each(|v| {
                if *v < 0.0 {
                    *v *= 0.2
                }
            });
        } else {
            a.iter_mut().for_each(|v| *v = v.tanh());
        }
        z = a;
    }
    z
}

/// The photometric loss the trainer differentiates (colour L1 on white, plus the alpha L1
/// against the mask with 4 outputs), in f64, over planar features `x` (`c x n`).
fn loss64(p: &MlpParams, ws: &[Vec<f64>], x: &[f64], v: &View) -> f64 {
    let n = v.gbuf.len();
    let c = p.in_ch;
    let mut col = 0.0;
    let mut al = 0.0;
    for i in 0..n {
        let t = if v.gbuf.coverage[i] != 0.0 {
            let z0: Vec<f64> = (0..c).map(|k| x[k * n + i]).collect();
            mlp64(p, ws, &z0)
        } else {
            vec![-1.0; p.out_ch]
        };
        let a = if p.out_ch == 4 {
            0.5 * (t[3] + 1.0)
        } else {
            v.gbuf.coverage[i] as f64
        };
        if p.out_ch == 4 {
            al += (a - v.alpha[i] as f64).abs();
        }
        for k in 0..3 {
            let comp = 0.5 * (t[k] + 1.0) * a + (1.0 - a);
            col += (comp - v.target[k * n + i] as f64).abs();
        }
    }
    col / (3 * n) as f64 + al / n as f64
}

// ---------------------------------------------------------------- fixtures

fn pyramid(r: &mut ChaCha8Rng, c: usize, sizes: &[(usize, usize)]) -> Pyramid {
    let levels = sizes
        .iter()
        .map(|&(w, h)| Level {
            width: w,
            height: h,
            data: randv(r, w * h * c, -1.0, 1.0),
        })
        .collect();
    Pyramid::new(c, levels, Wrap::Repeat, Wrap::MirroredRepeat).unwrap()
}

/// A view with ~75% coverage, random uv, directions, target and mask.
fn view(r: &mut ChaCha8Rng, w: usize, h: usize) -> View {
    let mut g = GBuffer::new(w, h);
    let n = w * h;
    for i in 0..n {
        g.uv[i] = [r.random_range(-0.3..1.3), r.random_range(-0.3..1.3)];
        g.coverage[i] = if r.random_range(0.0..1.0) < 0.75 {
            1.0
        } else {
            0.0
        };
        let d = [
            r.random_range(-1.0..1.0f32),
            r.random_range(-1.0..1.0),
            r.random_range(-1.0..1.0),
        ];
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt().max(1e-3);
        g.view_dir[i] = d.map(|x| x / len);
    }
    View {
        name: "synthetic".into(),
        gbuf: g,
        target: randv(r, 3 * n, 0.0, 1.0),
        alpha: (0..n)
            .map(|_| {
                if r.random_range(0.0..1.0) < 0.7 {
                    1.0
                } else {
                    0.0
                }
            })
            .collect(),
        has_alpha: true,
        valid: None,
        fine: None,
    }
}

fn covered(v: &View) -> Vec<bool> {
    v.gbuf.coverage.iter().map(|&c| c != 0.0).collect()
}

// ---------------------------------------------------------------- tests

#[test]
fn mlp_training_forward_is_the_runtime_forward() {
    let cases: [(Vec<usize>, usize); 4] = [
        (vec![], 3),
        (vec![7], 4),
        (vec![9, 5], 3),
        (vec![16, 16], 4),
    ];
    for (k, (hidden, out_ch)) in cases.into_iter().enumerate() {
        let mut r = rng(70 + k as u64);
        let p = MlpParams {
            in_ch: 6,
            hidden,
            out_ch,
        };
        let net = MlpTrain::init(p.clone(), 3 + k as u64).unwrap();
        // The exported names and shapes are exactly the runtime's.
        let map = net.to_map();
        let specs = p.tensor_specs();
        assert_eq!(map.len(), specs.len());
        for (name, shape) in &specs {
            assert_eq!(&map[name].0, shape, "{name}");
        }
        let runtime = Mlp::from_map(p.clone(), &map).unwrap();
        let (h, w) = (9, 11);
        let x = Tensor::from_vec(6, h, w, randv(&mut r, 6 * h * w, -2.0, 2.0)).unwrap();
        let cov: Vec<bool> = (0..h * w).map(|i| i % 4 != 1).collect();
        let (y, _) = net.forward_frame(&x, &cov).unwrap();
        let yr = runtime.forward(&x, &cov).unwrap();
        assert_eq!((y.c, y.h, y.w), (yr.c, yr.h, yr.w));
        let n = h * w;
        for o in 0..out_ch {
            for i in 0..n {
                let (a, b) = (y.data[o * n + i], yr.data[o * n + i]);
                if cov[i] {
                    assert!(
                        (a - b).abs() <= 1e-6,
                        "case {k} out {o} pixel {i}: {a} vs {b}"
                    );
                    assert_eq!(a.to_bits(), b.to_bits(), "same arithmetic, same bits");
                } else {
                    // Not evaluated: the runtime draws colour 0 and alpha 0, i.e. t = -1.
                    assert_eq!(a, -1.0);
                }
            }
        }
        // Initialisation: PyTorch's Linear default, bounded by 1/sqrt(fan_in), seeded.
        for (l, (ci, _)) in p.layer_dims().into_iter().enumerate() {
            let bound = 1.0 / (ci as f32).sqrt();
            for t in &net.weights[2 * l..2 * l + 2] {
                assert!(t.iter().all(|v| v.abs() <= bound));
                assert!(t.iter().any(|v| v.abs() > 0.5 * bound), "uses the range");
            }
        }
        assert_eq!(net, MlpTrain::init(p.clone(), 3 + k as u64).unwrap());
        assert_ne!(
            net.weights,
            MlpTrain::init(p, 4 + k as u64).unwrap().weights
        );
    }
}

#[test]
fn sample_sh_mlp_l1_graph_matches_central_differences() {
    let (c, first, degree) = (5usize, 1usize, 1u32);
    for (k, (hidden, out_ch)) in [(vec![6, 5], 4usize), (vec![7], 3)].into_iter().enumerate() {
        let mut r = rng(80 + k as u64);
        let pyr = pyramid(&mut r, c, &[(5, 4), (3, 2)]);
        let v = view(&mut r, 7, 6);
        let n = v.gbuf.len();
        let p = MlpParams {
            in_ch: c,
            hidden,
            out_ch,
        };
        let mut net = MlpTrain::init(p.clone(), 9 + k as u64).unwrap();
        // Analytic: the trainer's chain.
        let features = |pyr: &Pyramid| {
            let mut x = vec![0.0f32; c * n];
            sample_forward(pyr, &v.gbuf, &mut x).unwrap();
            modulate_forward(&mut x, &v.gbuf.view_dir, &v.gbuf.coverage, first, degree).unwrap();
            x
        };
        let f0 = features(&pyr);
        let x = Tensor::from_vec(c, 6, 7, f0.clone()).unwrap();
        let (y, acts) = net.forward_frame(&x, &covered(&v)).unwrap();
        let mut dy = Tensor::zeros(out_ch, 6, 7);
        let loss = photometric_l1(&y.data, &v, out_ch, &mut dy.data);
        let mut dx = net.backward_frame(&acts, &dy);
        modulate_backward(
            &mut dx.data,
            &v.gbuf.view_dir,
            &v.gbuf.coverage,
            first,
            degree,
        )
        .unwrap();
        let mut gtex: Vec<Vec<f32>> = pyr.levels.iter().map(|l| vec![0.0; l.data.len()]).collect();
        sample_backward(&pyr, &v.gbuf, &dx.data, &mut gtex).unwrap();

        // Reference.
        let ws: Vec<Vec<f64>> = net
            .weights
            .iter()
            .map(|w| w.iter().map(|&v| v as f64).collect())
            .collect();
        let x64: Vec<f64> = f0.iter().map(|&v| v as f64).collect();
        let what = format!("case {k}");
        // The returned loss is the colour term (the alpha term is gradient only).
        let colour_only = {
            let mut q = v.clone();
            q.alpha = vec![0.0; n];
            let mut l = loss64(&p, &ws, &x64, &q);
            if out_ch == 4 {
                // Remove the alpha term (|a - 0| summed) again.
                let mut al = 0.0;
                for i in 0..n {
                    if v.gbuf.coverage[i] != 0.0 {
                        let z0: Vec<f64> = (0..c).map(|kk| x64[kk * n + i]).collect();
                        al += 0.5 * (mlp64(&p, &ws, &z0)[3] + 1.0);
                    }
                }
                l -= al / n as f64;
            }
            l
        };
        assert!(
            (loss - colour_only).abs() < 1e-5,
            "{what} loss {loss} vs {colour_only}"
        );

        // Texture: each texel value moves the features along its (linear) footprint.
        for (lvl, g) in gtex.iter().enumerate() {
            let mut want = Vec::with_capacity(g.len());
            for j in 0..g.len() {
                let mut unit = pyr.clone();
                unit.levels.iter_mut().for_each(|l| l.data.fill(0.0));
                unit.levels[lvl].data[j] = 1.0;
                let d = features(&unit);
                let at = |s: f64| {
                    let xs: Vec<f64> = x64
                        .iter()
                        .zip(&d)
                        .map(|(&a, &b)| a + s * b as f64)
                        .collect();
                    loss64(&p, &ws, &xs, &v)
                };
                want.push((at(EPS) - at(-EPS)) / (2.0 * EPS));
            }
            assert_grad(g, &want, TOL, &format!("{what} texture level {lvl}"));
        }
        // Weights.
        let (names, _): (Vec<String>, Vec<Vec<usize>>) = p.tensor_specs().into_iter().unzip();
        for (ti, name) in names.iter().enumerate() {
            let want: Vec<f64> = (0..ws[ti].len())
                .map(|j| {
                    let at = |s: f64| {
                        let mut wv = ws.clone();
                        wv[ti][j] += s;
                        loss64(&p, &wv, &x64, &v)
                    };
                    (at(EPS) - at(-EPS)) / (2.0 * EPS)
                })
                .collect();
            assert_grad(&net.grads[ti], &want, TOL, &format!("{what} {name}"));
        }
        // The trainer's Adam step clears the gradients; zero_grad does too.
        net.zero_grad();
        assert!(net.grads.iter().flatten().all(|&g| g == 0.0));
    }
}

/// A tiny MLP configuration for a synthetic capture.
fn tiny_cfg(steps: u64) -> TrainConfig {
    TrainConfig {
        resolution: 16,
        levels: 2,
        channels: 12,
        arch: Arch::Mlp,
        widths: vec![16, 16],
        steps,
        lr_net: 1e-2,
        lr_tex: 1e-2,
        eval_every: 0.0,
        seed: 5,
        // Trained and drawn with subsamples: the runtime must reproduce the trainer's mean.
        supersample: DEFAULT_SUPERSAMPLE,
        ..TrainConfig::preset(Preset::Fast)
    }
}

fn load(dir: &std::path::Path) -> Capture {
    Capture::load(dir, &LoadOptions::default()).unwrap()
}

#[test]
fn short_mlp_bake_learns_exports_and_renders() {
    let dir = capture_common::simple_capture(10, 24);
    // Learnable images: a smooth colour ramp with a soft mask (the test pattern is noise).
    for i in 0..10 {
        capture_common::write_png_rgba(
            &dir.path().join(format!("images/f_{i}.png")),
            24,
            24,
            |x, y| {
                let a = if (4..20).contains(&x) && (4..20).contains(&y) {
                    255
                } else {
                    0
                };
                [
                    (40 + 8 * x) as u8,
                    (200 - 6 * y) as u8,
                    (60 + 3 * (x + y)) as u8,
                    a,
                ]
            },
        );
    }
    let cap = load(dir.path());
    assert!(!cap.test.is_empty());
    let train = views::prepare(&cap.mesh, &cap.train, DEFAULT_SUPERSAMPLE);
    let test = views::prepare(&cap.mesh, &cap.test, DEFAULT_SUPERSAMPLE);
    let mut t = Trainer::new(tiny_cfg(60), &train).unwrap();
    assert_eq!(t.out_ch, 4, "the capture has masks: learned alpha");
    let before = t.evaluate(&test).unwrap();
    let losses: Vec<f64> = (0..60).map(|_| t.step(&train).unwrap()).collect();
    assert!(losses.iter().all(|l| l.is_finite()));
    let first: f64 = losses[..10].iter().sum::<f64>() / 10.0;
    let last: f64 = losses[50..].iter().sum::<f64>() / 10.0;
    assert!(
        last < 0.7 * first,
        "training loss went from {first} to {last}"
    );
    let after = t.evaluate(&test).unwrap();
    let psnr = |e: &[dnr_bake::eval::metrics::ViewError]| {
        e.iter().map(|v| v.psnr).sum::<f64>() / e.len() as f64
    };
    assert!(
        psnr(&after) > psnr(&before) + 0.5,
        "held-out PSNR {} -> {}",
        psnr(&before),
        psnr(&after)
    );

    // Export with f32 weights and read back through the runtime.
    let out = tempfile::tempdir().unwrap();
    let path = out.path().join("mlp.glb");
    let b = dnr_bake::export::build(
        &cap.mesh,
        &t.pyr,
        t.sh_layer(),
        &t.export_net(),
        t.out_ch,
        t.cfg.supersample,
        dnr_format::model::DType::F32,
    )
    .unwrap();
    dnr_bake::export::write(&b, &path).unwrap();
    let renderer = dnr_runtime::renderer::Renderer::from_path(&path).unwrap();
    assert_eq!(renderer.architecture(0), Some("mlp"));
    let rep = dnr_bake::eval::evaluate(&renderer, &cap.test, None).unwrap();
    assert_eq!(rep.views.len(), test.len());
    // The runtime's rendering of the asset is the trainer's evaluation (same rasteriser,
    // features, network; the texture levels go through f16 EXR storage).
    let mine = psnr(&after);
    eprintln!(
        "loss {first:.4} -> {last:.4}; held-out {:.2} -> {mine:.2} dB; runtime {:.2} dB",
        psnr(&before),
        rep.mean.psnr
    );
    assert!(
        (rep.mean.psnr - mine).abs() < 0.05,
        "runtime {} dB vs trainer {mine} dB",
        rep.mean.psnr
    );
}

#[test]
fn mlp_resume_is_bit_identical() {
    let dir = capture_common::simple_capture(6, 16);
    let cap = load(dir.path());
    let train = views::prepare(&cap.mesh, &cap.train, DEFAULT_SUPERSAMPLE);
    let mut cfg = tiny_cfg(12);
    cfg.crop = 10;
    let mut straight = Trainer::new(cfg.clone(), &train).unwrap();
    for _ in 0..12 {
        straight.step(&train).unwrap();
    }
    let mut first = Trainer::new(cfg.clone(), &train).unwrap();
    for _ in 0..5 {
        first.step(&train).unwrap();
    }
    let tmp = tempfile::tempdir().unwrap();
    let ck = tmp.path().join("a.ckpt");
    first.checkpoint(&RunState::default()).write(&ck).unwrap();
    let read = Checkpoint::read(&ck).unwrap();
    assert!(
        read.header.arrays.iter().any(|(n, _)| n == "net.0.adam.m"),
        "the MLP and its optimiser are in the checkpoint"
    );
    let mut resumed = Trainer::new(cfg.clone(), &train).unwrap();
    resumed.restore(&read, &ck).unwrap();
    assert_eq!(resumed.step, 5);
    for _ in 5..12 {
        resumed.step(&train).unwrap();
    }
    let a = straight.checkpoint(&RunState::default());
    let b = resumed.checkpoint(&RunState::default());
    assert_eq!(a.header, b.header);
    let bits = |c: &Checkpoint| {
        c.arrays
            .iter()
            .flatten()
            .map(|v| v.to_bits())
            .collect::<Vec<_>>()
    };
    assert_eq!(
        bits(&a),
        bits(&b),
        "resumed state differs from the straight run"
    );
    // A checkpoint of another architecture is refused.
    let mut other = cfg;
    other.widths = vec![8];
    let mut t = Trainer::new(other, &train).unwrap();
    assert!(t.restore(&read, &ck).is_err());
}
