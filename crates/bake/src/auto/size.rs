//! Network and texture size: rungs from large to small, timed on this capture and this
//! machine; the largest whose measured step affords [`MIN_STEPS`] steps in the budget wins
//! (a measured rate against a stated floor: the larger rung overtakes the smaller only after
//! about that many steps). Only the rungs the decision needs are timed (see [`choose`]).

use std::time::Instant;

use serde::Serialize;

use super::footprint::Footprint;
use crate::train::config::{Arch, TrainConfig};
use crate::train::views::View;
use crate::train::{TrainError, Trainer};

/// Steps a rung must be able to take in the budget to be chosen.
pub const MIN_STEPS: f64 = 2500.0;
/// Steps before timing a rung (pool and cache warm-up), and steps timed.
const WARM_STEPS: usize = 4;
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

/// Largest first; the last (smallest) is taken when none is fast enough.
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

/// Times the rungs and returns the trainer of the largest that affords [`MIN_STEPS`] (or of
/// the smallest), its texture before the timed steps (the classical texture), and every
/// trial. `cfg.time_budget` is the whole budget; the time since `t_analysis` counts against
/// it.
///
/// The smallest rung is timed first: a larger rung's step is never faster, so when the
/// smallest does not afford [`MIN_STEPS`] none does, and a short budget is not spent timing
/// rungs it cannot take (at 60 s, timing the balanced rung took about 1 s of the minute).
/// Otherwise the larger rungs are timed largest first.
///
/// With `cfg.supersample` above 1, a rung chosen on its merit (one that affords
/// [`MIN_STEPS`], not the last resort) is timed again with its subsamples, and trains with
/// them if it still affords [`SUPERSAMPLE_MIN_STEPS`]. Supersampling costs about twice the step,
/// so a short budget keeps the rung and the step count it had without it.
pub fn choose(
    cfg: &TrainConfig,
    fit: &[View],
    sh: bool,
    _fp: &Footprint,
    t_analysis: Instant,
) -> Result<(Trainer, dnr_runtime::texture::Pyramid, Vec<RungTrial>), TrainError> {
    let (smallest, larger) = RUNGS.split_last().expect("at least one rung");
    let mut trials = Vec::new();
    let (small_tr, small_classical, small_trial) =
        time_rung(cfg, fit, sh, smallest, 1, t_analysis)?;
    let merit = small_trial.steps_in_budget >= MIN_STEPS;
    trials.push(small_trial);
    if merit {
        for r in larger {
            let (tr, classical, trial) = time_rung(cfg, fit, sh, r, 1, t_analysis)?;
            let affords = trial.steps_in_budget >= MIN_STEPS;
            trials.push(trial);
            if affords {
                return with_subsamples(cfg, fit, sh, r, t_analysis, (tr, classical), trials);
            }
        }
        return with_subsamples(
            cfg,
            fit,
            sh,
            smallest,
            t_analysis,
            (small_tr, small_classical),
            trials,
        );
    }
    trials[0].chosen = true;
    Ok((small_tr, small_classical, trials))
}

/// Rung `r` chosen on its merit (its one-sample trainer in `one`, its one-sample trial among
/// `trials`): timed again with `cfg.supersample` subsamples, which it keeps where it still
/// affords [`SUPERSAMPLE_MIN_STEPS`].
fn with_subsamples(
    cfg: &TrainConfig,
    fit: &[View],
    sh: bool,
    r: &Rung,
    t_analysis: Instant,
    one: (Trainer, dnr_runtime::texture::Pyramid),
    mut trials: Vec<RungTrial>,
) -> Result<(Trainer, dnr_runtime::texture::Pyramid, Vec<RungTrial>), TrainError> {
    if cfg.supersample > 1 {
        let (ts, cs, t2) = time_rung(cfg, fit, sh, r, cfg.supersample, t_analysis)?;
        let affords = t2.steps_in_budget >= SUPERSAMPLE_MIN_STEPS;
        trials.push(t2);
        if affords {
            trials.last_mut().expect("pushed").chosen = true;
            return Ok((ts, cs, trials));
        }
    }
    trials
        .iter_mut()
        .find(|t| t.name == r.name && t.supersample == 1)
        .expect("timed at one sample")
        .chosen = true;
    Ok((one.0, one.1, trials))
}

/// Steps the chosen rung must still afford with its subsamples to keep them. Below
/// [`MIN_STEPS`]: on every capture of the development set, 2x2 bakes of 300 s had passed the
/// one-sample 300 s bake's final held-out PSNR (3000 to 5000 steps) by about their 2000th
/// step, still mid-schedule (docs/benchmarks.md, "Supersampled features"). A floor at
/// [`MIN_STEPS`] sat at the edge of a 300 s budget, where a loaded host's slower step flipped
/// the choice. Subsamples cost at least 1.25x the step (1.26x to 2.1x measured there), so a
/// rung that affords fewer than [`MIN_STEPS`] without them could not keep them: it is not
/// timed with them.
pub const SUPERSAMPLE_MIN_STEPS: f64 = 2000.0;

/// A trainer of rung `r` at `s x s` subsamples, its classical texture, and its timing (not
/// yet chosen).
fn time_rung(
    cfg: &TrainConfig,
    fit: &[View],
    sh: bool,
    r: &Rung,
    s: u32,
    t_analysis: Instant,
) -> Result<(Trainer, dnr_runtime::texture::Pyramid, RungTrial), TrainError> {
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
    // The first steps fill the tensor pool and the caches; time the ones after. (They are
    // taken at the warm-up's first factor, so they barely move the state.)
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
    let trial = RungTrial {
        name: r.name.into(),
        resolution: r.resolution,
        levels: r.levels,
        widths: r.widths.to_vec(),
        supersample: s,
        step_ms: 1e3 * step_s,
        steps_in_budget: steps,
        chosen: false,
    };
    Ok((tr, classical, trial))
}
