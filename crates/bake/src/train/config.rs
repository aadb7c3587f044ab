//! Training configuration: presets and the explicit overrides that refine them.

use serde::Serialize;

use super::photometric::Loss;
use super::schedule::Schedule;
use super::SH_DEGREE;

/// Which renderer architecture to train.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "camelCase")]
pub enum Arch {
    /// Texture only: channels 0..2 are the colour.
    None,
    /// Per-pixel MLP.
    Mlp,
    /// The paper's U-Net.
    Unet,
}

impl std::str::FromStr for Arch {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "none" => Ok(Arch::None),
            "mlp" => Ok(Arch::Mlp),
            "unet" => Ok(Arch::Unet),
            _ => Err(format!(
                "unknown architecture '{s}' (expected none, mlp or unet)"
            )),
        }
    }
}

/// MLP hidden widths used with `--arch mlp` when no `--widths` are given (the presets' widths
/// are U-Net stage widths).
pub const MLP_DEFAULT_WIDTHS: [u32; 2] = [64, 64];

/// Named starting points; every field can still be overridden.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "camelCase")]
pub enum Preset {
    /// CPU-sized, a useful asset from a tiny capture in under two minutes.
    Fast,
    /// The trade-off of the paper's sizes scaled to a CPU: the largest size auto chooses,
    /// and the preset used when a flag auto would decide is given without `--preset`.
    Balanced,
    /// Bigger texture and network, longer training.
    Quality,
    /// The paper's exact sizes: 512x512, 4 levels, 16 channels, U-Net 64..512.
    Paper,
    /// Measure the scene and the machine, then decide: SH layer or not, network size,
    /// pyramid levels and channels, unseen texels (see `dnr_bake::auto`). Needs a time
    /// budget (default [`AUTO_DEFAULT_BUDGET`] seconds).
    Auto,
}

/// Subsamples per pixel side `balanced`, `quality` and `auto` train with (`fast` and `paper`
/// take 1; auto keeps it only where its budget affords it, see `auto::size`). Measured on the
/// whole development set (docs/benchmarks.md, "Supersampled features").
pub const DEFAULT_SUPERSAMPLE: u32 = 2;

/// Seconds `--preset auto` trains for when no `--time-budget` is given.
pub const AUTO_DEFAULT_BUDGET: f64 = 600.0;

impl std::str::FromStr for Preset {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "fast" => Ok(Preset::Fast),
            "balanced" => Ok(Preset::Balanced),
            "quality" => Ok(Preset::Quality),
            "paper" => Ok(Preset::Paper),
            "auto" => Ok(Preset::Auto),
            _ => Err(format!(
                "unknown preset '{s}' (expected auto, fast, balanced, quality or paper)"
            )),
        }
    }
}

/// Everything that determines a bake (the report records it resolved).
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct TrainConfig {
    /// Preset the values started from.
    pub preset: Preset,
    /// Side of the finest texture level in texels.
    pub resolution: u32,
    /// Number of pyramid levels (each halves the side).
    pub levels: u32,
    /// Feature channels per texel.
    pub channels: u32,
    /// Whether channels 3.. are modulated by the SH basis of the view direction.
    pub sh: bool,
    /// Degree of that basis: channels `3 .. 3 + (degree + 1)^2` are modulated (0 to 3; the
    /// paper's 2 modulates 9 channels, 3 modulates 16 and needs 19 channels).
    pub sh_degree: u32,
    /// Renderer architecture.
    pub arch: Arch,
    /// U-Net widths (or MLP hidden widths).
    pub widths: Vec<u32>,
    /// Side of the square training crop in pixels (0 = whole frame).
    pub crop: u32,
    /// Maximum optimisation steps.
    pub steps: u64,
    /// Adam learning rate of the network.
    pub lr_net: f32,
    /// Adam learning rate of the texture.
    pub lr_tex: f32,
    /// L2 regularisation strength: level k (0 = finest) gets `reg * (K-1-k)`.
    pub reg: f32,
    /// Photometric loss training minimises.
    pub loss: Loss,
    /// Weight of the mean-colour L1 loss on channels 0..2.
    pub mean_colour_weight: f32,
    /// Predict alpha (RGBA output) when the capture has masks.
    pub alpha: bool,
    /// Random seed (crops, initialisation).
    pub seed: u64,
    /// Worker threads (0 = all cores).
    pub threads: usize,
    /// Wall-clock budget in seconds for training (0 = none).
    pub time_budget: f64,
    /// Seconds between held-out evaluations (0 = only at the end).
    pub eval_every: f64,
    /// Learning-rate schedule over the whole run (budget or step limit).
    pub schedule: Schedule,
    /// Subsamples per pixel side of the feature image (spec "Supersampled Features"): the
    /// renderer sees the mean of `s x s` subsample features, which carries partial coverage
    /// at silhouettes and texture detail below a pixel. 1 samples pixel centres only.
    pub supersample: u32,
    /// Per-step decay of the moving average of the texture and the weights that validation
    /// checks weigh against the current state (`train::ema`; 0 = none).
    pub ema: f32,
    /// Crops (of random views) whose gradients one step averages. 1 (the paper's) takes a
    /// step per crop.
    pub batch: u32,
    /// Decoupled weight decay (AdamW) of the finest texture level; level k of K (0 =
    /// finest) gets `tex_decay * (K-1-k) / (K-1)`, so the coarsest never decays. Unlike
    /// `reg` (a penalty on the mean square, whose gradient Adam normalises away), it pulls
    /// each texel toward zero at `lr * tex_decay` of its value per update: texels whose
    /// gradients disagree across views shrink, consistent ones hold (0 = none).
    pub tex_decay: f32,
    /// Decoupled weight decay (AdamW) of the network's weights and biases: each update
    /// scales them by `1 - lr * net_decay` before the Adam step (0 = none).
    pub net_decay: f32,
}

impl TrainConfig {
    /// The configuration a preset starts from.
    pub fn preset(preset: Preset) -> Self {
        let base = TrainConfig {
            preset,
            resolution: 512,
            levels: 4,
            channels: 16,
            sh: true,
            sh_degree: SH_DEGREE,
            arch: Arch::Unet,
            widths: vec![16, 32, 64, 128, 128],
            crop: 0,
            steps: 20_000,
            // Twice the paper's rate: with the cosine schedule's warm-up and annealing it gained
            // 0.03 to 0.5 dB on every capture of the development set (docs/benchmarks.md).
            lr_net: 2e-3,
            lr_tex: 2e-3,
            reg: 1e-3,
            // The paper's L1: squared error gained on some captures of the development set and
            // lost more on others (docs/benchmarks.md), so it is an option, not the default.
            loss: Loss::L1,
            mean_colour_weight: 1.0,
            alpha: true,
            seed: 1,
            threads: 0,
            time_budget: 0.0,
            eval_every: 30.0,
            schedule: Schedule::DEFAULT,
            supersample: DEFAULT_SUPERSAMPLE,
            // Off: at 300 s it moved held-out PSNR by -0.12 to +0.08 dB on the development
            // set, within run-to-run spread (docs/benchmarks.md).
            ema: 0.0,
            batch: 1,
            // At 300 s it gained on every capture of the development set, most where
            // validation shows over-fitting (docs/benchmarks.md, "Texture weight decay").
            tex_decay: 4.0,
            // At 300 s it gained 0.26 to 0.48 dB held out on each of four captures of the
            // development set beside the texture decay (docs/benchmarks.md, "Network weight decay").
            net_decay: 1.0,
        };
        match preset {
            // The quick preset keeps the cheaper step (subsamples about double it).
            Preset::Fast => TrainConfig {
                resolution: 256,
                levels: 3,
                widths: vec![8, 16, 32, 64],
                steps: 3_000,
                supersample: 1,
                ..base
            },
            Preset::Balanced => base,
            Preset::Quality => TrainConfig {
                resolution: 1024,
                levels: 5,
                widths: vec![32, 64, 128, 256, 256],
                steps: 60_000,
                ..base
            },
            // The paper's recipe, constant learning rate included.
            Preset::Paper => TrainConfig {
                widths: vec![64, 128, 256, 512, 512],
                alpha: false,
                lr_net: 1e-3,
                lr_tex: 1e-3,
                steps: 60_000,
                schedule: Schedule::CONSTANT,
                supersample: 1,
                tex_decay: 0.0,
                net_decay: 0.0,
                ..base
            },
            // The budget ends an auto bake, not a step count; the sizes here are the largest
            // rung auto may choose (see `dnr_bake::auto::RUNGS`).
            Preset::Auto => TrainConfig {
                steps: 10_000_000,
                time_budget: AUTO_DEFAULT_BUDGET,
                ..base
            },
        }
    }
}
