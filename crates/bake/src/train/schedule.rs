//! Learning-rate schedules over a whole bake: a factor of the base learning rates as a
//! function of progress `p` in [0, 1] (training seconds over the time budget, or steps over
//! the step limit, whichever ends the run first).
//!
//! Why a schedule that knows the budget: with the paper's constant rate the last steps keep
//! the texture and network moving by about `lr` per step, so the state a bake ends in carries
//! that noise; an annealed tail settles it. Measured on the development set (see
//! `docs/benchmarks.md`), a decay over the whole budget beats a constant rate with a late
//! fine-tune at every budget.

use serde::{Deserialize, Serialize};

/// The shape of the decay after the warm-up.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub enum Shape {
    /// The paper's constant rate (no warm-up, no decay).
    Constant,
    /// Half a cosine from 1 down to the floor.
    Cosine,
    /// A straight line from 1 down to the floor.
    Linear,
}

impl std::str::FromStr for Shape {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "constant" => Ok(Shape::Constant),
            "cosine" => Ok(Shape::Cosine),
            "linear" => Ok(Shape::Linear),
            _ => Err(format!(
                "unknown schedule '{s}' (expected cosine, linear or constant)"
            )),
        }
    }
}

/// A learning-rate schedule: linear warm-up from `warmup_start` over the first `warmup` of
/// the run, then `shape` from 1 down to `floor` at the end.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct Schedule {
    /// Decay after the warm-up.
    pub shape: Shape,
    /// Fraction of the run spent warming up (0 = none).
    pub warmup: f64,
    /// Factor at the start of the warm-up.
    pub warmup_start: f64,
    /// Factor at the end of the run.
    pub floor: f64,
}

impl Schedule {
    /// The paper's constant rate.
    pub const CONSTANT: Schedule = Schedule {
        shape: Shape::Constant,
        warmup: 0.0,
        warmup_start: 1.0,
        floor: 1.0,
    };

    /// The default of every preset but `paper` (chosen on the development set).
    pub const DEFAULT: Schedule = Schedule {
        shape: Shape::Cosine,
        warmup: 0.02,
        warmup_start: 0.1,
        floor: 0.02,
    };

    /// The learning-rate factor at progress `p` (clamped to [0, 1]).
    pub fn factor(&self, p: f64) -> f64 {
        let p = if p.is_finite() {
            p.clamp(0.0, 1.0)
        } else {
            1.0
        };
        if self.shape == Shape::Constant {
            return 1.0;
        }
        if self.warmup > 0.0 && p < self.warmup {
            let s = self.warmup_start;
            return s + (1.0 - s) * p / self.warmup;
        }
        let q = if self.warmup < 1.0 {
            ((p - self.warmup) / (1.0 - self.warmup)).clamp(0.0, 1.0)
        } else {
            1.0
        };
        let decay = match self.shape {
            Shape::Cosine => 0.5 * (1.0 + (std::f64::consts::PI * q).cos()),
            Shape::Linear => 1.0 - q,
            Shape::Constant => 1.0,
        };
        self.floor + (1.0 - self.floor) * decay
    }

    /// Checks the fields are in range.
    pub fn validate(&self) -> Result<(), String> {
        let unit = |x: f64| x.is_finite() && (0.0..=1.0).contains(&x);
        if !unit(self.warmup)
            || !unit(self.floor)
            || self.warmup_start <= 0.0
            || !unit(self.warmup_start)
        {
            return Err(format!(
                "schedule: warm-up {} (fraction), warm-up start {} and floor {} must lie in [0, 1] (start > 0)",
                self.warmup, self.warmup_start, self.floor
            ));
        }
        Ok(())
    }
}

/// Progress of a run in [0, 1]: the larger of seconds over the budget and steps over the step
/// limit (whichever ends the run first); 0 with neither limit.
pub fn progress(seconds: f64, budget: f64, step: u64, steps: u64) -> f64 {
    let by_time = if budget > 0.0 { seconds / budget } else { 0.0 };
    let by_steps = if steps > 0 && steps < u64::MAX {
        step as f64 / steps as f64
    } else {
        0.0
    };
    by_time.max(by_steps).clamp(0.0, 1.0)
}

/// Progress within a cycle that began at run progress `start` (in [0, 1)): a bake continued
/// past the end of an earlier one (auto's budget cycles) runs the schedule again over the
/// rest of the run, warm-up included. `start` 0 is the whole run.
pub fn within_cycle(p: f64, start: f64) -> f64 {
    if start > 0.0 && start < 1.0 {
        ((p - start) / (1.0 - start)).clamp(0.0, 1.0)
    } else {
        p
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cosine_warms_up_then_decays_to_the_floor() {
        let s = Schedule::DEFAULT;
        assert!((s.factor(0.0) - s.warmup_start).abs() < 1e-12);
        assert!((s.factor(s.warmup) - 1.0).abs() < 1e-12);
        assert!((s.factor(1.0) - s.floor).abs() < 1e-12);
        let mid = s.warmup + 0.5 * (1.0 - s.warmup);
        assert!((s.factor(mid) - (s.floor + 0.5 * (1.0 - s.floor))).abs() < 1e-12);
        // Non-increasing after the warm-up.
        let mut last = f64::INFINITY;
        for i in 0..=100 {
            let p = s.warmup + (1.0 - s.warmup) * i as f64 / 100.0;
            let f = s.factor(p);
            assert!(f <= last + 1e-15, "{p}: {f} > {last}");
            last = f;
        }
    }

    #[test]
    fn constant_is_one_and_linear_is_a_line() {
        assert_eq!(Schedule::CONSTANT.factor(0.7), 1.0);
        let l = Schedule {
            shape: Shape::Linear,
            warmup: 0.0,
            warmup_start: 1.0,
            floor: 0.0,
        };
        assert!((l.factor(0.25) - 0.75).abs() < 1e-12);
        assert!(
            l.factor(f64::NAN).abs() < 1e-12,
            "NaN progress counts as the end"
        );
    }

    #[test]
    fn progress_takes_whichever_limit_ends_first() {
        assert_eq!(progress(30.0, 60.0, 10, 100), 0.5);
        assert_eq!(progress(6.0, 60.0, 50, 100), 0.5);
        assert_eq!(progress(90.0, 60.0, 0, 0), 1.0);
        assert_eq!(progress(5.0, 0.0, 0, 0), 0.0);
    }

    #[test]
    fn a_cycle_runs_the_schedule_again_over_the_rest() {
        let s = Schedule::DEFAULT;
        assert_eq!(within_cycle(0.3, 0.0), 0.3);
        assert_eq!(within_cycle(0.5, 0.5), 0.0);
        assert_eq!(within_cycle(0.75, 0.5), 0.5);
        assert_eq!(within_cycle(1.0, 0.5), 1.0);
        // Warm-up at the cycle's start, the floor at the run's end.
        assert!((s.factor(within_cycle(0.5, 0.5)) - s.warmup_start).abs() < 1e-12);
        assert!((s.factor(within_cycle(1.0, 0.5)) - s.floor).abs() < 1e-12);
        // Before its start (a rollback's progress) it counts as the start.
        assert_eq!(within_cycle(0.4, 0.5), 0.0);
    }

    #[test]
    fn out_of_range_fields_are_refused() {
        let mut s = Schedule::DEFAULT;
        assert!(s.validate().is_ok());
        s.floor = 1.5;
        assert!(s.validate().is_err());
        s = Schedule::DEFAULT;
        s.warmup_start = 0.0;
        assert!(s.validate().is_err());
    }
}
