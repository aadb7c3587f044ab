//! The baker's whole training step on synthetic views (the "step" rows).
//!
//! The step as the baker runs it (texture sampling, SH, U-Net forward and backward, losses, texture
//! scatter, sparse Adam on texels, Adam on weights), on synthetic views of the size asked: what
//! `dnr bench train` times against PyTorch's same step.

use dnr_runtime::gbuffer::GBuffer;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::{run_for, time_steady, WARM_SECONDS};
use crate::train::config::{Arch, Preset, TrainConfig};
use crate::train::views::View;
use crate::train::{PhaseSeconds, Trainer};

/// A synthetic view shaped like a real one, mirroring `synthetic_inputs` of the PyTorch
/// reference (`dnr_torch.py`) so `dnr bench train --torch` compares like with like:
/// with `x, y` the pixel's position in [0, 1] (`linspace`, ends included) and a random phase
/// `ph`, a smooth, slightly warped uv field covering about 80% of the texture
/// (`u = 0.1 + 0.8 x + 0.03 sin(6.28 (2 y) + ph)`,
/// `v = 0.1 + 0.8 (1 - y) + 0.03 sin(6.28 (3 x) + ph)`), coverage on the disc `(x - .5)^2 + (y - .5)^2 < 0.19` (about 60% of the frame),
/// view directions `normalize(x - .5, y - .5, -1)`, a random target colour and the disc as the
/// target alpha. Neighbouring pixels hit neighbouring texels, as on a rasterised mesh.
pub fn synthetic_view(size: usize, seed: u64) -> View {
    let mut r = ChaCha8Rng::seed_from_u64(seed);
    let n = size * size;
    // torch.linspace(0, 1, size).
    let lin = |i: usize| {
        if size > 1 {
            i as f32 / (size - 1) as f32
        } else {
            0.0
        }
    };
    // The reference uses 6.28 for 2 pi; keep its numbers.
    #[allow(clippy::approx_constant)]
    let tau = 6.28f32;
    let ph = r.random::<f32>() * tau;
    let mut g = GBuffer::new(size, size);
    let mut alpha = vec![0.0f32; n];
    for yi in 0..size {
        let y = lin(yi);
        for xi in 0..size {
            let x = lin(xi);
            let i = yi * size + xi;
            let (dx, dy) = (x - 0.5, y - 0.5);
            if dx * dx + dy * dy >= 0.19 {
                continue;
            }
            let u = 0.1 + 0.8 * x + 0.03 * (tau * y * 2.0 + ph).sin();
            let v = 0.1 + 0.8 * (1.0 - y) + 0.03 * (tau * x * 3.0 + ph).sin();
            g.uv[i] = [u, v];
            g.coverage[i] = 1.0;
            g.prim[i] = 0;
            g.tri[i] = 0;
            g.depth[i] = 1.0;
            let l = (dx * dx + dy * dy + 1.0).sqrt();
            g.view_dir[i] = [dx / l, dy / l, -1.0 / l];
            alpha[i] = 1.0;
        }
    }
    View {
        name: format!("synthetic{seed}"),
        gbuf: g,
        target: (0..3 * n).map(|_| r.random::<f32>()).collect(),
        alpha,
        has_alpha: true,
        valid: None,
        fine: None,
    }
}

/// Milliseconds (min, median in the steady state, see [`time_steady`]) of one full training
/// step at `size` x `size` with a 512x512x16, 4-level texture, SH, and a U-Net of `widths`
/// (RGBA output), with `supersample` x `supersample` subsamples per pixel, and the mean
/// milliseconds per timed step of each phase.
pub fn bench_trainer_step(
    widths: &[u32],
    size: usize,
    supersample: u32,
    reps: usize,
) -> (f64, f64, PhaseSeconds) {
    let views: Vec<View> = (0..2)
        .map(|seed| {
            let mut v = synthetic_view(size, seed);
            // The same uv field sampled s times as densely: what the subsample pass gives.
            v.fine =
                (supersample > 1).then(|| synthetic_view(size * supersample as usize, seed).gbuf);
            v
        })
        .collect();
    let cfg = TrainConfig {
        arch: Arch::Unet,
        widths: widths.to_vec(),
        resolution: 512,
        levels: 4,
        channels: 16,
        sh: true,
        crop: 0,
        steps: u64::MAX,
        supersample,
        ..TrainConfig::preset(Preset::Balanced)
    };
    let mut t = Trainer::new(cfg, &views).expect("synthetic views train");
    run_for(WARM_SECONDS, 2, || {
        t.step(&views).expect("step");
    });
    t.phase_seconds = PhaseSeconds::default();
    let warm_steps = t.step;
    let (min, med) = time_steady(reps, false, || {
        t.step(&views).expect("step");
    });
    let p = t.phase_seconds;
    let k = 1e3 / (t.step - warm_steps).max(1) as f64;
    let per_step = PhaseSeconds {
        features: p.features * k,
        forward: p.forward * k,
        backward: p.backward * k,
        feature_grads: p.feature_grads * k,
        updates: p.updates * k,
    };
    (1e3 * min, 1e3 * med, per_step)
}
