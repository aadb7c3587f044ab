//! The whole training step as the baker runs it (texture sampling, SH, U-Net forward and
//! backward, losses, texture scatter, sparse Adam on texels, Adam on weights), on synthetic
//! views of the size asked: what `dnr bench train` times against PyTorch's same step.

use dnr_runtime::gbuffer::GBuffer;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::time_min_median;
use crate::train::config::{Arch, Preset, TrainConfig};
use crate::train::views::View;
use crate::train::Trainer;

/// A synthetic fully covered view: random uv, random unit view directions, random target.
pub fn synthetic_view(size: usize, seed: u64) -> View {
    let mut r = ChaCha8Rng::seed_from_u64(seed);
    let n = size * size;
    let mut g = GBuffer::new(size, size);
    for i in 0..n {
        g.uv[i] = [r.random::<f32>(), r.random::<f32>()];
        g.coverage[i] = 1.0;
        g.prim[i] = 0;
        g.tri[i] = 0;
        g.depth[i] = 1.0;
        let d = [r.random::<f32>() - 0.5, r.random::<f32>() - 0.5, -1.0f32];
        let l = (d[0] * d[0] + d[1] * d[1] + 1.0).sqrt();
        g.view_dir[i] = [d[0] / l, d[1] / l, d[2] / l];
    }
    View {
        name: format!("synthetic{seed}"),
        gbuf: g,
        target: (0..3 * n).map(|_| r.random::<f32>()).collect(),
        alpha: vec![1.0; n],
        has_alpha: true,
    }
}

/// Milliseconds (min, median over `reps`) of one full training step at `size` x `size` with a
/// 512x512x16, 4-level texture, SH, and a U-Net of `widths` (RGBA output).
pub fn bench_trainer_step(widths: &[u32], size: usize, reps: usize) -> (f64, f64) {
    let views: Vec<View> = (0..2).map(|s| synthetic_view(size, s)).collect();
    let cfg = TrainConfig {
        arch: Arch::Unet,
        widths: widths.to_vec(),
        resolution: 512,
        levels: 4,
        channels: 16,
        sh: true,
        crop: 0,
        steps: u64::MAX,
        ..TrainConfig::preset(Preset::Balanced)
    };
    let mut t = Trainer::new(cfg, &views).expect("synthetic views train");
    let (min, med) = time_min_median(reps, || {
        t.step(&views).expect("step");
    });
    (1e3 * min, 1e3 * med)
}
