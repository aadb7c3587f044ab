//! The main job, end to end: load the capture, precompute the views, train, export, evaluate
//! the exported asset through the runtime, report.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::time::Instant;

use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;

use crate::capture::{Capture, LoadOptions};
use crate::export;
use crate::train::checkpoint::{self, Checkpoint};
use crate::train::config::TrainConfig;
use crate::train::{self, views, Checkpointing, Record, RunState, TrainError, Trainer};

/// What to bake and where to put it.
#[derive(Clone, Debug)]
pub struct BakeOptions {
    /// Capture folder.
    pub capture: PathBuf,
    /// Output `.glb`.
    pub output: PathBuf,
    /// Proxy mesh overriding the capture's.
    pub mesh: Option<PathBuf>,
    /// JSON report path.
    pub report: Option<PathBuf>,
    /// Continue from the last checkpoint.
    pub resume: bool,
    /// Show a progress bar (plain lines when stderr is not a terminal).
    pub progress: bool,
    /// Wall-clock seconds between checkpoints.
    pub checkpoint_every: f64,
    /// Capture size limits.
    pub limits: crate::capture::Limits,
}

/// Final figures of a bake.
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Summary {
    /// Held-out PSNR (dB) of the exported asset rendered by the runtime.
    pub test_psnr: f64,
    /// Held-out object MSE on [0,255].
    pub test_mse: f64,
    /// Held-out SSIM.
    pub test_ssim: f64,
    /// Training steps.
    pub steps: u64,
    /// Wall-clock seconds of the whole bake.
    pub seconds: f64,
    /// Training seconds (evaluation excluded).
    pub train_seconds: f64,
    /// Size of the asset.
    pub asset_bytes: u64,
    /// Divergences recovered from during training (see `train::run`).
    pub recoveries: usize,
    /// Every held-out evaluation during training (in the report, not in `--json`).
    #[serde(skip)]
    pub records: Vec<Record>,
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct Report<'a> {
    config: &'a TrainConfig,
    capture: String,
    mesh: String,
    train_views: usize,
    test_views: usize,
    warnings: &'a [String],
    records: &'a [Record],
    /// Divergences the training loop recovered from (rollback, halved learning rates).
    recoveries: &'a [crate::train::Recovery],
    summary: &'a Summary,
}

/// Errors of the whole job (each names the file it concerns).
#[derive(Debug, thiserror::Error)]
pub enum BakeError {
    /// The capture could not be loaded.
    #[error(transparent)]
    Capture(#[from] crate::capture::CaptureError),
    /// Training failed.
    #[error(transparent)]
    Train(#[from] crate::train::TrainError),
    /// Export failed.
    #[error(transparent)]
    Export(#[from] crate::export::ExportError),
    /// The report could not be written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// The exported asset could not be read back.
    #[error("{path}: reading back the exported asset: {message}")]
    ReadBack {
        /// The file.
        path: String,
        /// Why.
        message: String,
    },
}

/// Runs the whole bake.
pub fn bake(cfg: &TrainConfig, opts: &BakeOptions) -> Result<Summary, BakeError> {
    let t_start = Instant::now();
    if cfg.threads > 0 {
        // Ignore the error when a global pool already exists (e.g. in tests).
        let _ = rayon::ThreadPoolBuilder::new()
            .num_threads(cfg.threads)
            .build_global();
    }
    let load = LoadOptions {
        mesh: opts.mesh.clone(),
        limits: opts.limits,
        ..LoadOptions::default()
    };
    let capture = Capture::load(&opts.capture, &load)?;
    for w in &capture.warnings {
        eprintln!("dnr-bake: warning: {w}");
    }
    let train_views = views::prepare(&capture.mesh, &capture.train);
    let test_views = views::prepare(&capture.mesh, &capture.test);
    let t_init = Instant::now();
    let mut trainer = Trainer::new(cfg.clone(), &train_views)?;
    // The classical initialisation is part of learning the texture, so it counts against the
    // time budget and shows in the records' seconds (a fair equal-time comparison).
    let init_secs = t_init.elapsed().as_secs_f64();

    // Checkpoints live next to the output; --resume continues from the last one.
    let ckpt_path = checkpoint::path_for(&opts.output);
    let mut state = RunState {
        train_secs: init_secs,
        ..RunState::default()
    };
    if opts.resume && ckpt_path.is_file() {
        let c = Checkpoint::read(&ckpt_path).map_err(TrainError::from)?;
        state = trainer.restore(&c, &ckpt_path)?;
        eprintln!(
            "dnr-bake: resuming from {} at step {}",
            ckpt_path.display(),
            trainer.step
        );
    }
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    {
        let stop = stop.clone();
        // Only one handler per process may exist; a second bake in-process keeps the first.
        let _ = ctrlc::set_handler(move || stop.store(true, std::sync::atomic::Ordering::SeqCst));
    }
    let ckpt = Checkpointing {
        path: &ckpt_path,
        every: opts.checkpoint_every,
        stop: &stop,
    };

    let bar = progress_bar(opts.progress, cfg);
    let last_psnr = std::cell::Cell::new(f64::NAN);
    let mut last_line = 0.0f64;
    let plain = !std::io::stderr().is_terminal();
    train::run(
        &mut trainer,
        &mut state,
        &train_views,
        &test_views,
        Some(&ckpt),
        |t, secs| {
            if let Some(b) = &bar {
                b.set_position(if cfg.time_budget > 0.0 {
                    secs as u64
                } else {
                    t.step
                });
                b.set_message(format!(
                    "step {} | held-out {:.2} dB",
                    t.step,
                    last_psnr.get()
                ));
            }
            if opts.progress && plain && secs - last_line >= 10.0 {
                last_line = secs;
                eprintln!(
                    "step {} | {:.0} s | held-out {:.2} dB",
                    t.step,
                    secs,
                    last_psnr.get()
                );
            }
        },
        |r| {
            last_psnr.set(r.test_psnr);
            if opts.progress && plain {
                eprintln!(
                    "eval: step {} | {:.1} s | loss {:.4} | held-out {:.2} dB, object MSE {:.1}",
                    r.step, r.seconds, r.train_loss, r.test_psnr, r.test_mse
                );
            }
        },
    )?;
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    let records = state.records;
    let recoveries = state.recoveries;

    let builder = export::build(
        &capture.mesh,
        &trainer.pyr,
        trainer.sh_layer(),
        &trainer.export_net(),
        trainer.out_ch,
        dnr_format::model::DType::F16,
    )?;
    let asset_bytes = export::write(&builder, &opts.output)?;
    // The asset is complete: the checkpoint is no longer needed.
    if let Some(dir) = ckpt_path.parent() {
        let _ = std::fs::remove_dir_all(dir);
    }

    // Held-out error of what was written, through the runtime.
    let (test_psnr, test_mse, test_ssim) = if capture.test.is_empty() {
        (f64::NAN, f64::NAN, f64::NAN)
    } else {
        let renderer = dnr_runtime::renderer::Renderer::from_path(&opts.output).map_err(|e| {
            BakeError::ReadBack {
                path: opts.output.display().to_string(),
                message: e.to_string(),
            }
        })?;
        let rep = crate::eval::evaluate(&renderer, &capture.test, None).map_err(|e| {
            BakeError::ReadBack {
                path: opts.output.display().to_string(),
                message: e.to_string(),
            }
        })?;
        (rep.mean.psnr, rep.mean.mse_obj, rep.mean.ssim)
    };
    let train_seconds = records.last().map_or(0.0, |r| r.seconds);
    let summary = Summary {
        test_psnr,
        test_mse,
        test_ssim,
        steps: trainer.step,
        seconds: t_start.elapsed().as_secs_f64(),
        train_seconds,
        asset_bytes,
        recoveries: recoveries.len(),
        records: records.clone(),
    };
    if let Some(path) = &opts.report {
        let rep = Report {
            // The configuration trained with (recoveries lower the learning rates).
            config: &trainer.cfg,
            capture: opts.capture.display().to_string(),
            mesh: capture.mesh_path.display().to_string(),
            train_views: train_views.len(),
            test_views: test_views.len(),
            warnings: &capture.warnings,
            records: &records,
            recoveries: &recoveries,
            summary: &summary,
        };
        let text = serde_json::to_string_pretty(&rep).expect("report serialises");
        write_atomic(path, text.as_bytes()).map_err(|source| BakeError::Io {
            path: path.display().to_string(),
            source,
        })?;
    }
    Ok(summary)
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

/// Writes `bytes` to `path` through a temporary file in the same folder and a rename, so a
/// crash never leaves a partial file.
pub fn write_atomic(path: &std::path::Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(std::path::Path::new("."));
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = dir.join(format!(".{name}.{}.tmp", std::process::id()));
    std::fs::write(&tmp, bytes)?;
    std::fs::rename(&tmp, path).inspect_err(|_| {
        let _ = std::fs::remove_file(&tmp);
    })
}
