//! The progress display of a training run: a bar on a terminal (`indicatif`), plain lines
//! every 10 s otherwise (logs, CI).

use std::io::IsTerminal;

use indicatif::{ProgressBar, ProgressStyle};

use crate::train::config::TrainConfig;
use crate::train::{Record, Trainer};

/// A run's progress display.
pub struct Progress {
    bar: Option<ProgressBar>,
    enabled: bool,
    plain: bool,
    last_psnr: std::cell::Cell<f64>,
    last_line: std::cell::Cell<f64>,
    by_time: bool,
}

impl Progress {
    /// A display for a run of `cfg` (nothing at all when `enabled` is false).
    pub fn new(enabled: bool, cfg: &TrainConfig) -> Progress {
        Progress {
            bar: progress_bar(enabled, cfg),
            enabled,
            plain: !std::io::stderr().is_terminal(),
            last_psnr: std::cell::Cell::new(f64::NAN),
            last_line: std::cell::Cell::new(0.0),
            by_time: cfg.time_budget > 0.0,
        }
    }

    /// After each step.
    pub fn on_step(&self, t: &Trainer, secs: f64) {
        // Before the first evaluation there is no held-out figure to show.
        let psnr = self.last_psnr.get();
        let held_out = if psnr.is_nan() {
            String::from("held-out: first evaluation pending")
        } else {
            format!("held-out {psnr:.2} dB")
        };
        if let Some(b) = &self.bar {
            b.set_position(if self.by_time { secs as u64 } else { t.step });
            b.set_message(format!(
                "step {} | lr x{:.2} | {held_out}",
                t.step,
                t.lr_scale()
            ));
        }
        if self.enabled && self.plain && secs - self.last_line.get() >= 10.0 {
            self.last_line.set(secs);
            eprintln!(
                "step {} | {secs:.0} s | lr x{:.2} | {held_out}",
                t.step,
                t.lr_scale()
            );
        }
    }

    /// After each held-out record.
    pub fn on_record(&self, r: &Record) {
        self.last_psnr.set(r.test_psnr);
        if self.enabled && self.plain {
            eprintln!(
                "eval: step {} | {:.1} s | loss {:.4} | validation {:.2} dB | held-out {:.2} dB, object MSE {:.1}",
                r.step, r.seconds, r.train_loss, r.val_psnr, r.test_psnr, r.test_mse
            );
        }
    }

    /// Prints a line above the bar (or plainly).
    pub fn println(&self, line: &str) {
        match &self.bar {
            Some(b) => b.println(line),
            None if self.enabled => eprintln!("{line}"),
            None => {}
        }
    }

    /// Removes the bar.
    pub fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}

fn progress_bar(enabled: bool, cfg: &TrainConfig) -> Option<ProgressBar> {
    if !enabled || !std::io::stderr().is_terminal() {
        return None;
    }
    let (len, unit) = if cfg.time_budget > 0.0 {
        (cfg.time_budget as u64, "s")
    } else {
        (cfg.steps, "steps")
    };
    let bar = ProgressBar::new(len);
    let style = ProgressStyle::with_template(&format!(
        "{{spinner}} [{{elapsed_precise}}] {{bar:30}} {{pos}}/{{len}} {unit} (ETA {{eta}}) {{msg}}"
    ))
    .unwrap_or_else(|_| ProgressStyle::default_bar());
    bar.set_style(style);
    Some(bar)
}
