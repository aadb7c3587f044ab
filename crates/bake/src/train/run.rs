//! The training loop around [`Trainer::step`]: the learning-rate schedule, validation checks
//! that keep the best state and catch divergence, held-out records for the report, and
//! checkpoints.
//!
//! Two kinds of held-out views, never mixed:
//! - **validation** views are training views held out of training (see
//!   `crate::pipeline::split_validation`); they decide (best state, divergence) and their
//!   rendering counts against the budget, because it is part of the bake;
//! - **test** views are the capture's test split; they are only reported (the records), and
//!   their rendering is excluded from the training seconds, as PyTorch's peer excludes its
//!   evaluation.

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use serde::Serialize;

use super::checkpoint::Checkpoint;
use super::schedule;
use super::views::View;
use super::{Record, TrainError, Trainer};

/// A divergence the training loop recovered from: it rolled back to the last good state and
/// halved both learning rates (see [`run`]).
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct Recovery {
    /// Step at which the divergence was seen.
    pub step: u64,
    /// Step of the state rolled back to.
    pub rolled_back_to: u64,
    /// Training seconds when it happened.
    pub seconds: f64,
    /// What was seen (non-finite loss, validation PSNR collapse).
    pub reason: String,
    /// Network learning rate from then on (before the schedule's factor).
    pub lr_net: f32,
    /// Texture learning rate from then on (before the schedule's factor).
    pub lr_tex: f32,
}

/// Progress of a run that a checkpoint carries besides the trainer.
#[derive(Clone, Debug)]
pub struct RunState {
    /// Training seconds (initialisation and validation included, test records excluded).
    pub train_secs: f64,
    /// Training second of the next test record.
    pub next_eval: f64,
    /// Progress (0..1) of the next validation check.
    pub next_check: f64,
    /// The last validation PSNR measured (NaN before the first).
    pub last_val: f64,
    /// Records so far.
    pub records: Vec<Record>,
    /// Divergences recovered from so far.
    pub recoveries: Vec<Recovery>,
    /// Validation checks: (step, training seconds, validation PSNR).
    pub checks: Vec<(u64, f64, f64)>,
    /// Validation checks of the moving average (`train::ema`): (step, validation PSNR).
    pub ema_checks: Vec<(u64, f64)>,
    /// Periodic validation checks over the whole run (0 = not decided yet: the first call
    /// decides from the time one check takes, [`val_checks`]).
    pub val_checks: u32,
    /// Seconds the first validation render took (what [`val_checks`] was decided from).
    pub val_check_secs: f64,
    /// Validation PSNR of the trainer's current state, when known: [`run`] sets it when it
    /// returns and takes it as its starting state's value instead of rendering again. Code
    /// that changes the trainer between calls (a level removed, pruning, quantisation) sets
    /// it to what it measured, or clears it.
    pub current_val: Option<f64>,
    /// Progress (0..1) at which the current schedule cycle began: 0 for one cycle over the
    /// whole run; auto's budget cycles continue a finished bake and run the schedule again
    /// from there ([`schedule::within_cycle`]).
    pub cycle_start: f64,
}

impl Default for RunState {
    fn default() -> Self {
        RunState {
            train_secs: 0.0,
            next_eval: 0.0,
            next_check: 0.0,
            last_val: f64::NAN,
            records: Vec::new(),
            recoveries: Vec::new(),
            checks: Vec::new(),
            ema_checks: Vec::new(),
            val_checks: 0,
            val_check_secs: 0.0,
            current_val: None,
            cycle_start: 0.0,
        }
    }
}

/// Where and how often to checkpoint, and the flag that asks the loop to stop.
pub struct Checkpointing<'a> {
    /// Checkpoint file.
    pub path: &'a Path,
    /// Wall-clock seconds between checkpoints.
    pub every: f64,
    /// Set (e.g. by a Ctrl-C handler) to checkpoint and stop.
    pub stop: &'a AtomicBool,
}

/// A validation PSNR this far below the best so far counts as divergence.
pub const PSNR_COLLAPSE_DB: f64 = 3.0;
/// Recoveries tried before training gives up with [`TrainError::Diverged`].
pub const MAX_RECOVERIES: usize = 6;
/// Most validation checks over a whole run (one at the end of each equal part of its
/// progress).
pub const VAL_CHECKS: u32 = 20;
/// Fewest validation checks over a run with validation views.
pub const MIN_VAL_CHECKS: u32 = 4;
/// Largest share of a time budget the periodic validation checks may take.
pub const VAL_SHARE: f64 = 0.05;

/// How many periodic validation checks a run makes: [`VAL_CHECKS`], fewer when they would
/// take more than [`VAL_SHARE`] of the time budget at `check_secs` each (never fewer than
/// [`MIN_VAL_CHECKS`]). Why: at 60 s on the development set twenty checks took about 12% of
/// the budget, steps a short bake needs more than a finer choice of its best state. A run
/// without a budget (`budget` 0) keeps [`VAL_CHECKS`], so fixed-step runs stay reproducible.
pub fn val_checks(budget: f64, check_secs: f64) -> u32 {
    if !(budget > 0.0 && check_secs > 0.0) {
        return VAL_CHECKS;
    }
    let n = (VAL_SHARE * budget / check_secs).floor();
    if n >= f64::from(VAL_CHECKS) {
        VAL_CHECKS
    } else {
        // Below VAL_CHECKS here, so the cast cannot overflow.
        (n.max(0.0) as u32).max(MIN_VAL_CHECKS)
    }
}

/// Mean PSNR of the trainer's current state on `views`.
pub fn mean_psnr(trainer: &Trainer, views: &[View]) -> Result<f64, TrainError> {
    let e = trainer.evaluate(views)?;
    Ok(e.iter().map(|e| e.psnr).sum::<f64>() / e.len().max(1) as f64)
}

/// Validation PSNR of the trainer's current state: [`RunState::current_val`] when known,
/// else rendered (the time counts as training time, and then the figure is known). The first
/// render decides the number of periodic checks ([`val_checks`]) from its time.
pub fn current_psnr(
    trainer: &Trainer,
    state: &mut RunState,
    val: &[View],
) -> Result<f64, TrainError> {
    if let Some(v) = state.current_val.filter(|_| state.val_checks > 0) {
        return Ok(v);
    }
    let t = Instant::now();
    let v = mean_psnr(trainer, val)?;
    let secs = t.elapsed().as_secs_f64();
    state.train_secs += secs;
    if state.val_checks == 0 {
        state.val_check_secs = secs;
        state.val_checks = val_checks(trainer.cfg.time_budget, secs);
    }
    state.current_val = Some(v).filter(|v| v.is_finite());
    Ok(v)
}

/// The point of the next periodic check after one at progress `p`: the first of the `n`
/// checks' points (`k / n`) at least half a period after `p`, so that two checks are never
/// closer than that.
pub fn next_check_after(p: f64, n: f64) -> f64 {
    ((p * n + 0.5).floor() + 1.0) / n
}

/// Trains from the state's progress up to progress `until` (1 = the end of the run: its
/// time budget or step limit, whichever comes first; auto stops earlier to prune, then calls
/// again). The learning rates follow the configuration's schedule over the whole run (over
/// the current cycle, from [`RunState::cycle_start`], in a continued run).
///
/// - Every `1 / n` of progress (and at the end) the validation views are rendered, `n` from
///   [`val_checks`] (decided by the first call from the time its first render takes).
/// - The call that reaches the end of the run hands back its best state when the final one
///   is worse, so the result is never worse on validation than an earlier state of that
///   call, its starting state included. A call that stops earlier (auto's phases) hands back
///   its last state: the next phase continues the trajectory instead of restarting from a
///   check that validation noise flattered. (On the development set's coarse thin capture at
///   600 s, returns to one lucky check at every phase end cost 40% of the bake.)
/// - The starting state's validation PSNR is [`RunState::current_val`] when known, else
///   rendered.
/// - Divergence recovery: a non-finite training loss, or a validation PSNR that is
///   non-finite or [`PSNR_COLLAPSE_DB`] below the best so far, rolls the trainer back to the
///   best state (or the start), halves both base learning rates and records a [`Recovery`];
///   after [`MAX_RECOVERIES`] the run fails.
/// - Test records every `eval_every` training seconds and at the end (excluded from the
///   training seconds); `on_step` and `on_record` drive the progress display.
#[allow(clippy::too_many_arguments)]
pub fn run(
    trainer: &mut Trainer,
    state: &mut RunState,
    until: f64,
    train: &[View],
    val: &[View],
    test: &[View],
    ckpt: Option<&Checkpointing>,
    mut on_step: impl FnMut(&Trainer, f64),
    mut on_record: impl FnMut(&Record),
) -> Result<(), TrainError> {
    if state.next_eval <= 0.0 {
        state.next_eval = trainer.cfg.eval_every;
    }
    let (budget, steps, sched) = (
        trainer.cfg.time_budget,
        trainer.cfg.steps,
        trainer.cfg.schedule,
    );
    let progress =
        |t: &Trainer, s: &RunState| schedule::progress(s.train_secs, budget, t.step, steps);
    let until = until.clamp(0.0, 1.0);
    let mut last_ckpt = Instant::now();
    // The best validated state so far, starting with the state this call starts from: auto
    // trains in phases (one call each), and a last phase that only loses on validation must
    // hand back its start, not the best of its own checks.
    let start_val = if val.is_empty() {
        f64::NEG_INFINITY
    } else {
        let v = current_psnr(trainer, state, val)?;
        if v.is_finite() {
            v
        } else {
            f64::NEG_INFINITY
        }
    };
    // Training changes the state from here on.
    state.current_val = None;
    let start_step = trainer.step;
    // Without validation views no check is made (and no count decided).
    let n_checks = f64::from(if state.val_checks == 0 {
        VAL_CHECKS
    } else {
        state.val_checks
    });
    if state.next_check <= 0.0 {
        state.next_check = 1.0 / n_checks;
    }
    let mut best: (Checkpoint, f64) = (trainer.checkpoint(state), start_val);
    let recover = |trainer: &mut Trainer,
                   state: &mut RunState,
                   good: &Checkpoint,
                   reason: String|
     -> Result<(), TrainError> {
        let step = trainer.step;
        let keep = keep_progress(state);
        // Roll back first, so that even a run that gives up leaves a good state behind.
        let lr_before = (trainer.cfg.lr_net, trainer.cfg.lr_tex);
        trainer.restore(good, Path::new("(in-memory snapshot)"))?;
        if state.recoveries.len() >= MAX_RECOVERIES {
            trainer.set_learning_rates(lr_before.0, lr_before.1);
            put_progress(state, keep);
            return Err(TrainError::Diverged {
                recoveries: state.recoveries.len(),
                step,
                reason,
            });
        }
        let (lr_net, lr_tex) = (lr_before.0 * 0.5, lr_before.1 * 0.5);
        trainer.set_learning_rates(lr_net, lr_tex);
        put_progress(state, keep);
        eprintln!(
            "dnr-bake: {reason} at step {step}: rolled back to step {}, learning rates halved to {lr_net:e} (network) and {lr_tex:e} (texture)",
            trainer.step
        );
        state.recoveries.push(Recovery {
            step,
            rolled_back_to: trainer.step,
            seconds: state.train_secs,
            reason,
            lr_net,
            lr_tex,
        });
        Ok(())
    };
    while trainer.step < steps && progress(trainer, state) < until {
        let p = progress(trainer, state);
        trainer.set_lr_scale(sched.factor(schedule::within_cycle(p, state.cycle_start)) as f32);
        let t0 = Instant::now();
        let loss = trainer.step(train)?;
        state.train_secs += t0.elapsed().as_secs_f64();
        if !loss.is_finite() {
            recover(trainer, state, &best.0, format!("training loss {loss}"))?;
            continue;
        }
        on_step(trainer, state.train_secs);
        if !val.is_empty() && progress(trainer, state) >= state.next_check {
            let p = progress(trainer, state);
            state.next_check = next_check_after(p, n_checks);
            // A call that ends within half a period checks its end instead.
            if until - p >= 0.5 / n_checks {
                let v = check(trainer, state, val)?;
                if !v.is_finite() || v < best.1 - PSNR_COLLAPSE_DB {
                    recover(
                        trainer,
                        state,
                        &best.0,
                        format!("validation PSNR fell to {v:.2} dB (best {:.2} dB)", best.1),
                    )?;
                    continue;
                } else if v >= best.1 {
                    best = (trainer.checkpoint(state), v);
                }
                check_ema(trainer, state, val, &mut best)?;
            }
        }
        if trainer.cfg.eval_every > 0.0 && state.train_secs >= state.next_eval && !test.is_empty() {
            state.next_eval += trainer.cfg.eval_every;
            let rec = record(trainer, state, test)?;
            on_record(&rec);
            state.records.push(rec);
        }
        if let Some(c) = ckpt {
            let stop = c.stop.load(Ordering::SeqCst);
            if stop || last_ckpt.elapsed().as_secs_f64() >= c.every {
                trainer.checkpoint(state).write(c.path)?;
                last_ckpt = Instant::now();
            }
            if stop {
                return Err(TrainError::Interrupted {
                    step: trainer.step,
                    path: c.path.display().to_string(),
                });
            }
        }
    }
    // The final state is checked too; at the end of the run the best replaces it when better.
    let at_end = until >= 1.0 || trainer.step >= steps;
    if !val.is_empty() {
        let v = if trainer.step == start_step {
            // No step taken: the start's figure is the state's.
            start_val
        } else if state.checks.last().is_some_and(|c| c.0 == trainer.step) {
            state.last_val
        } else {
            let v = check(trainer, state, val)?;
            // The average competes with the final state, not with an older best.
            if v >= best.1 && trainer.ema_ready() {
                best = (trainer.checkpoint(state), v);
            }
            check_ema(trainer, state, val, &mut best)?;
            v
        };
        let worse = v.is_nan() || v < best.1;
        state.current_val = Some(v).filter(|v| v.is_finite());
        let p = progress(trainer, state);
        state.next_check = state.next_check.max(next_check_after(p, n_checks));
        if at_end && best.1.is_finite() && worse {
            let last = trainer.step;
            go_back(trainer, state, &best.0, best.1)?;
            eprintln!(
                "dnr-bake: the state at step {last} ({v:.2} dB on validation) is worse than the one at step {} ({:.2} dB): keeping that",
                trainer.step, best.1
            );
        }
    }
    if !test.is_empty()
        && state
            .records
            .last()
            .is_none_or(|r: &Record| r.step != trainer.step)
    {
        let rec = record(trainer, state, test)?;
        on_record(&rec);
        state.records.push(rec);
    }
    Ok(())
}

/// Restores an in-memory snapshot of the trainer whose validation PSNR was `val`, keeping
/// the run's progress (time moves on, records stay): the state to be written is that one.
pub fn go_back(
    trainer: &mut Trainer,
    state: &mut RunState,
    snapshot: &Checkpoint,
    val: f64,
) -> Result<(), TrainError> {
    let keep = keep_progress(state);
    trainer.restore(snapshot, Path::new("(in-memory snapshot)"))?;
    put_progress(state, keep);
    state.last_val = val;
    state.current_val = Some(val).filter(|v| v.is_finite());
    Ok(())
}

type Progress = (f64, f64, f64, f64, Vec<Record>, Vec<(u64, f64, f64)>);

/// What a rollback keeps of the run's progress (time moves on, records stay).
fn keep_progress(state: &mut RunState) -> Progress {
    (
        state.train_secs,
        state.next_eval,
        state.next_check,
        state.last_val,
        std::mem::take(&mut state.records),
        std::mem::take(&mut state.checks),
    )
}

fn put_progress(state: &mut RunState, p: Progress) {
    (
        state.train_secs,
        state.next_eval,
        state.next_check,
        state.last_val,
        state.records,
        state.checks,
    ) = p;
}

/// Renders the validation views (the time counts as training time), records the check.
fn check(trainer: &Trainer, state: &mut RunState, val: &[View]) -> Result<f64, TrainError> {
    let t = Instant::now();
    let v = mean_psnr(trainer, val)?;
    state.train_secs += t.elapsed().as_secs_f64();
    state.last_val = v;
    state.checks.push((trainer.step, state.train_secs, v));
    Ok(v)
}

/// Renders the validation views with the moving average in place of the state (when it
/// has run long enough); keeps it as the best state when it beats every state so far.
fn check_ema(
    trainer: &mut Trainer,
    state: &mut RunState,
    val: &[View],
    best: &mut (Checkpoint, f64),
) -> Result<(), TrainError> {
    if !trainer.swap_ema() {
        return Ok(());
    }
    let t = Instant::now();
    let v = mean_psnr(trainer, val);
    if let Ok(v) = v {
        if v.is_finite() && v > best.1 {
            *best = (trainer.checkpoint(state), v);
        }
        state.ema_checks.push((trainer.step, v));
    }
    trainer.swap_ema();
    state.train_secs += t.elapsed().as_secs_f64();
    v.map(|_| ())
}

fn record(trainer: &mut Trainer, state: &RunState, test: &[View]) -> Result<Record, TrainError> {
    let errs = trainer.evaluate(test)?;
    let k = errs.len().max(1) as f64;
    Ok(Record {
        step: trainer.step,
        seconds: state.train_secs,
        train_loss: trainer.take_loss(),
        test_psnr: errs.iter().map(|e| e.psnr).sum::<f64>() / k,
        test_mse: errs.iter().map(|e| e.mse_obj).sum::<f64>() / k,
        val_psnr: state.last_val,
        lr_factor: f64::from(trainer.lr_scale()),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn checks_take_at_most_their_share_of_a_budget() {
        // No budget (a fixed-step run) or no measurement: the most checks.
        assert_eq!(val_checks(0.0, 0.3), VAL_CHECKS);
        assert_eq!(val_checks(60.0, 0.0), VAL_CHECKS);
        assert_eq!(val_checks(60.0, f64::NAN), VAL_CHECKS);
        // Cheap checks on a long budget: capped.
        assert_eq!(val_checks(300.0, 0.5), VAL_CHECKS);
        // 5% of 60 s is 3 s: eight checks of 0.34 s fit, nine do not.
        let n = val_checks(60.0, 0.34);
        assert_eq!(n, 8);
        assert!(f64::from(n) * 0.34 <= VAL_SHARE * 60.0);
        assert!(f64::from(n + 1) * 0.34 > VAL_SHARE * 60.0);
        // Checks dearer than the share allows still leave the fewest.
        assert_eq!(val_checks(10.0, 5.0), MIN_VAL_CHECKS);
        assert_eq!(val_checks(1e300, 1e-300), VAL_CHECKS);
    }

    #[test]
    fn checks_are_at_least_half_a_period_apart() {
        // Just past a point, as a periodic check is: the next point.
        assert_eq!(next_check_after(0.3 + 1e-6, 20.0), 0.35);
        assert_eq!(next_check_after(0.250_01, 8.0), 0.375);
        // A phase's end check between points: the next point at least half a period on
        // (0.375 is 0.6 of a period after 0.3; 0.5 only 0.4 after 0.45, so 0.625).
        assert_eq!(next_check_after(0.3, 8.0), 0.375);
        assert_eq!(next_check_after(0.45, 8.0), 0.625);
        for (p, n) in [(0.3, 8.0), (0.61, 9.0), (0.999, 20.0), (0.0, 4.0)] {
            let next = next_check_after(p, n);
            assert!(next - p >= 0.5 / n - 1e-12 && next - p <= 1.5 / n + 1e-12);
        }
    }
}
