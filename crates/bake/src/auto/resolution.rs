//! Texture resolution by validation: during training, at [`CHECKS`] of the budget, the
//! validation views are rendered with and without the finest pyramid level; when it buys
//! less than [`super::PRUNE_DB`] it is removed there and then, so the rest of the budget
//! trains the coarser pyramid instead of a level that fits noise.
//!
//! Why during training, not once at the start: how fine a texture the capture supports shows
//! only as the finest level starts to over-fit (on the development set, the 512² level of a
//! glossy capture stopped helping validation after about 40% of a 4000-step bake, while the
//! duck's kept gaining). Why not only at the end: a level removed late leaves little budget
//! for the coarser levels and the network to take over its work.

use serde::Serialize;

use crate::train::run::{current_psnr, mean_psnr};
use crate::train::views::View;
use crate::train::RunState;
use crate::train::{TrainError, Trainer};

/// Fractions of the budget at which the finest level is tried.
pub const CHECKS: [f64; 4] = [0.3, 0.4, 0.5, 0.6];
/// Levels that are never removed this way (the coarse ones carry the low frequencies).
pub const MIN_LEVELS: usize = 2;

/// One trial of the finest level.
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct LevelCheck {
    /// Fraction of the budget when it was made.
    pub progress: f64,
    /// Side of the finest level tried.
    pub side: usize,
    /// Validation PSNR with it.
    pub with_db: f64,
    /// Validation PSNR without it.
    pub without_db: f64,
    /// Whether it was removed.
    pub removed: bool,
    /// Seconds the trial took: the render without the level (the render with it is the
    /// state's known figure, or counted as training time where it had none).
    pub seconds: f64,
}

/// Tries the finest level (when more than [`MIN_LEVELS`] remain) and removes it when it buys
/// less than `threshold_db` on `val`. The state's known validation PSNR (the phase's last
/// check) stands for the render with it.
pub fn check_finest(
    trainer: &mut Trainer,
    state: &mut RunState,
    val: &[View],
    progress: f64,
    threshold_db: f64,
) -> Result<Option<LevelCheck>, TrainError> {
    if val.is_empty() || trainer.pyr.levels.len() <= MIN_LEVELS {
        return Ok(None);
    }
    let with_db = current_psnr(trainer, state, val)?;
    let t0 = std::time::Instant::now();
    let n = trainer.pyr.levels[0].data.len();
    let side = trainer.pyr.levels[0]
        .width
        .max(trainer.pyr.levels[0].height);
    let saved = std::mem::replace(&mut trainer.pyr.levels[0].data, vec![0.0; n]);
    let without = mean_psnr(trainer, val);
    trainer.pyr.levels[0].data = saved;
    let without_db = without?;
    let removed = with_db - without_db < threshold_db;
    if removed {
        trainer.remove_level(0);
        state.current_val = None;
    }
    Ok(Some(LevelCheck {
        progress,
        side,
        with_db,
        without_db,
        removed,
        seconds: t0.elapsed().as_secs_f64(),
    }))
}
