//! Budget cycles: a long bake is the bake of half its budget, continued.
//!
//! Why: on the development set's coarse thin capture, a 600 s bake ended 0.1 to 0.3 dB below
//! the 300 s bake on the held-out views (docs/benchmarks.md). Its validation PSNR peaked
//! between 55% and 75% of the budget and then fell while the training loss kept falling:
//! over-fitting, whose onset moved from run to run, so no rule watching the curve caught it
//! in time.
//!
//! Here a budget of at least twice [`MIN_CYCLE_SECS`] (`--min-cycle`) first bakes half of it,
//! whole (every decision, the annealed schedule, the quantised fine-tune), then runs the
//! schedule again, warm-up and peak included, over the other half from that state, and keeps
//! the continuation only when it beats that state on the validation views. So a longer bake
//! is never worse on validation than the bake of half its budget, by construction;
//! recursively so for longer budgets. Where nothing over-fits, the continuation scored about
//! what one cycle over the whole budget does (docs/benchmarks.md, "Budget cycles"); a
//! gentler continuation (the longer bake's own schedule from its midpoint) scored less.

use serde::Serialize;

use crate::pipeline::{BakeError, Loaded, Progress};
use crate::train::quantise::{QatTarget, QAT_START};
use crate::train::run::{current_psnr, go_back, next_check_after};
use crate::train::{RunState, Trainer};

use super::train_phase;

/// Shortest cycle: budgets below twice this are one cycle. Why this length: on the
/// development set (2-vCPU AMD EPYC) 300 s bakes lost at most 0.14 dB of validation PSNR from
/// their best check to their end, while at 600 s the thin captures lost 0.2 to 0.4 dB.
pub const MIN_CYCLE_SECS: f64 = 250.0;

/// The budgets at which the cycles of a bake of `budget` seconds end, shortest first: the
/// last is `budget`, each is twice the one before, the first is below `2 * min_cycle`
/// ([`MIN_CYCLE_SECS`] by default). One cycle without a budget or a positive `min_cycle`.
pub fn budgets(budget: f64, min_cycle: f64) -> Vec<f64> {
    let mut ends = vec![budget];
    if !(budget.is_finite() && budget > 0.0 && min_cycle.is_finite() && min_cycle > 0.0) {
        return ends;
    }
    while ends[0] >= 2.0 * min_cycle {
        ends.insert(0, ends[0] / 2.0);
    }
    ends
}

/// One continuation past the end of an earlier cycle (the bake report's `auto.cycles`).
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Cycle {
    /// Budget (seconds) the earlier cycles ended at.
    pub from_budget: f64,
    /// Budget this cycle ends at.
    pub to_budget: f64,
    /// Validation PSNR of the state it started from (the earlier cycle's written state).
    pub start_psnr: f64,
    /// Validation PSNR of the state its training hands back (its start again when none of its
    /// checks beat that).
    pub end_psnr: f64,
    /// The best of its periodic validation checks (NaN when it made none).
    pub best_check_psnr: f64,
    /// Whether its state replaced the one it started from.
    pub kept: bool,
    /// Steps it trained.
    pub steps: u64,
    /// Seconds it took.
    pub seconds: f64,
}

/// Continues the trainer from the end of the cycle that ended at its configured budget to
/// `to_budget`: the schedule runs again from here ([`RunState::cycle_start`]), unquantised up
/// to the cycle's [`QAT_START`] and through `qat`'s rounding after it, as the first cycle did.
/// The state it starts from comes back when the continuation does not beat it on validation.
pub fn continue_to(
    tr: &mut Trainer,
    state: &mut RunState,
    qat: &Option<QatTarget>,
    to_budget: f64,
    loaded: &Loaded,
    progress: &Progress,
) -> Result<Cycle, BakeError> {
    let from_budget = tr.cfg.time_budget;
    let before = state.train_secs;
    let start_psnr = current_psnr(tr, state, loaded.val())?;
    let start = (tr.checkpoint(state), tr.step);
    let checks_before = state.checks.len();
    tr.cfg.time_budget = to_budget;
    state.cycle_start = (state.train_secs / to_budget).clamp(0.0, 1.0);
    let n = f64::from(state.val_checks.max(1));
    state.next_check = next_check_after(state.cycle_start, n);
    if qat.is_some() {
        tr.set_qat(None);
        state.current_val = None;
        let until = state.cycle_start + QAT_START * (1.0 - state.cycle_start);
        train_phase(tr, state, until, loaded, progress)?;
        tr.set_qat(qat.clone());
        state.current_val = None;
    }
    train_phase(tr, state, 1.0, loaded, progress)?;
    let end_psnr = current_psnr(tr, state, loaded.val())?;
    let best_check_psnr = state.checks[checks_before.min(state.checks.len())..]
        .iter()
        .map(|c| c.2)
        .fold(f64::NAN, f64::max);
    let steps = state
        .checks
        .last()
        .map_or(0, |c| c.0)
        .saturating_sub(start.1);
    let kept = end_psnr > start_psnr || !start_psnr.is_finite();
    if !kept {
        go_back(tr, state, &start.0, start_psnr)?;
        // The snapshot's rounding parameters are refitted from its own values.
        tr.set_qat(qat.clone());
        progress.println(&format!(
            "dnr-bake auto: the continuation to {to_budget:.0} s ends at {end_psnr:.2} dB on validation (best check {best_check_psnr:.2} dB), not above the {from_budget:.0} s bake's {start_psnr:.2} dB: keeping that bake"
        ));
    }
    Ok(Cycle {
        from_budget,
        to_budget,
        start_psnr,
        end_psnr,
        best_check_psnr,
        kept,
        steps,
        seconds: state.train_secs - before,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn long_budgets_continue_the_bake_of_half() {
        let m = MIN_CYCLE_SECS;
        assert_eq!(budgets(60.0, m), vec![60.0]);
        assert_eq!(budgets(300.0, m), vec![300.0]);
        assert_eq!(budgets(499.0, m), vec![499.0]);
        assert_eq!(budgets(600.0, m), vec![300.0, 600.0]);
        assert_eq!(budgets(1200.0, m), vec![300.0, 600.0, 1200.0]);
        assert_eq!(budgets(3600.0, m), vec![450.0, 900.0, 1800.0, 3600.0]);
        assert_eq!(budgets(20.0, 5.0), vec![5.0, 10.0, 20.0]);
        assert_eq!(budgets(0.0, m), vec![0.0]);
        assert_eq!(budgets(f64::INFINITY, m).len(), 1);
        assert_eq!(budgets(600.0, 0.0), vec![600.0]);
        assert_eq!(budgets(600.0, f64::NAN), vec![600.0]);
        for b in [500.0, 777.0, 1e5] {
            let c = budgets(b, m);
            assert!(c[0] >= m && c[0] < 2.0 * m);
            assert_eq!(c.last().copied(), Some(b));
            assert!(c.windows(2).all(|w| w[1] == 2.0 * w[0]));
        }
    }
}
