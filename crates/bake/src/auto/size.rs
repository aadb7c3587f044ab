//! Network and texture size: rungs from large to small, each timed on this capture and this
//! machine; the largest whose measured step affords [`MIN_STEPS`] steps in the budget wins
//! (a measured rate against a stated floor: the larger rung overtakes the smaller only after
//! about that many steps).

use std::time::Instant;

use serde::Serialize;

use super::footprint::Footprint;
use crate::train::config::{Arch, TrainConfig};
use crate::train::views::View;
use crate::train::{TrainError, Trainer};

/// Steps a rung must be able to take in the budget to be chosen.
pub const MIN_STEPS: f64 = 2500.0;
/// Steps before timing a rung (pool and cache warm-up), and steps timed.
const WARM_STEPS: usize = 2;
const TIMED_STEPS: usize = 5;

/// A size auto may choose: texture resolution, levels, U-Net widths.
#[derive(Clone, Copy, Debug)]
pub struct Rung {
    /// Name (the preset it matches).
    pub name: &'static str,
    /// Finest texture side.
    pub resolution: u32,
    /// Pyramid levels.
    pub levels: u32,
    /// U-Net widths.
    pub widths: &'static [u32],
}

/// Largest first; the last is taken when none is fast enough.
pub const RUNGS: [Rung; 2] = [
    Rung {
        name: "balanced",
        resolution: 512,
        levels: 4,
        widths: &[16, 32, 64, 128, 128],
    },
    Rung {
        name: "fast",
        resolution: 256,
        levels: 3,
        widths: &[8, 16, 32, 64],
    },
];

/// One rung as measured.
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct RungTrial {
    /// The rung's name.
    pub name: String,
    /// Finest texture side.
    pub resolution: u32,
    /// Levels.
    pub levels: u32,
    /// U-Net widths.
    pub widths: Vec<u32>,
    /// Subsamples per pixel side of the features.
    pub supersample: u32,
    /// Measured training step (ms, mean of 5 after 2 warm-up steps).
    pub step_ms: f64,
    /// Steps that fit in what is left of the budget at that rate.
    pub steps_in_budget: f64,
    /// Chosen.
    pub chosen: bool,
}

/// Times the rungs largest first, each with `cfg.supersample` subsamples per pixel side and
/// then (when that is above 1) with one sample, and returns the trainer of the first that
/// affords [`MIN_STEPS`] (or of the last), its texture before the timed steps (the classical
/// texture), and every trial. `cfg.time_budget` is the whole budget; the time since
/// `t_analysis` counts against it.
///
/// Supersampling costs about twice the step; it is kept only where the rung still takes
/// [`MIN_STEPS`] with it, so a short budget trains as many steps as it did without it.
pub fn choose(
    cfg: &TrainConfig,
    fit: &[View],
    sh: bool,
    _fp: &Footprint,
    t_analysis: Instant,
) -> Result<(Trainer, dnr_runtime::texture::Pyramid, Vec<RungTrial>), TrainError> {
    let mut trials = Vec::new();
    let factors: &[u32] = if cfg.supersample > 1 {
        &[cfg.supersample, 1]
    } else {
        &[1]
    };
    let ladder = RUNGS
        .iter()
        .flat_map(|r| factors.iter().map(move |&s| (r, s)));
    let last = RUNGS.len() * factors.len() - 1;
    for (i, (r, s)) in ladder.enumerate() {
        let c = TrainConfig {
            resolution: r.resolution,
            levels: r.levels,
            widths: r.widths.to_vec(),
            arch: Arch::Unet,
            sh,
            supersample: s,
            ..cfg.clone()
        };
        let mut tr = Trainer::new(c, fit)?;
        let classical = tr.pyr.clone();
        // The first steps fill the tensor pool and the caches; time the ones after. (They
        // are taken at the warm-up's first factor, so they barely move the state.)
        tr.set_lr_scale(cfg.schedule.factor(0.0) as f32);
        for _ in 0..WARM_STEPS {
            tr.step(fit)?;
        }
        let ts = Instant::now();
        for _ in 0..TIMED_STEPS {
            tr.step(fit)?;
        }
        let step_s = ts.elapsed().as_secs_f64() / TIMED_STEPS as f64;
        let left = cfg.time_budget - t_analysis.elapsed().as_secs_f64();
        let steps = left.max(0.0) / step_s;
        let ok = steps >= MIN_STEPS || i == last;
        trials.push(RungTrial {
            name: r.name.into(),
            resolution: r.resolution,
            levels: r.levels,
            widths: r.widths.to_vec(),
            supersample: s,
            step_ms: 1e3 * step_s,
            steps_in_budget: steps,
            chosen: ok,
        });
        if ok {
            return Ok((tr, classical, trials));
        }
    }
    unreachable!("the last rung is always chosen")
}
