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
    /// Also write the same trained state with f32 storage here (for measuring what f16
    /// storage costs).
    pub write_f32: Option<PathBuf>,
    /// `--preset auto`: also write the state just before pruning here.
    pub write_unpruned: Option<PathBuf>,
    /// Capture loading choices (working size, UVs, mesh placement, alignment check).
    pub input: crate::capture::InputOptions,
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
    /// What loading found and did: timings, UVs, the alignment check.
    load: &'a crate::capture::LoadReport,
    /// `--preset auto`: what was measured and decided.
    #[serde(skip_serializing_if = "Option::is_none")]
    auto: Option<&'a crate::auto::AutoReport>,
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

/// A loaded capture with its views rasterised.
pub(crate) struct Loaded {
    pub capture: Capture,
    pub train: Vec<views::View>,
    pub test: Vec<views::View>,
    pub load: crate::capture::LoadReport,
}

/// Loads the capture and prepares the views (also sets the thread count).
pub(crate) fn load(cfg: &TrainConfig, opts: &BakeOptions) -> Result<Loaded, BakeError> {
    if cfg.threads > 0 {
        // Ignore the error when a global pool already exists (e.g. in tests).
        let _ = rayon::ThreadPoolBuilder::new()
            .num_threads(cfg.threads)
            .build_global();
    }
    let load: LoadOptions = opts.input.load_options(opts.mesh.clone(), opts.limits);
    let mut capture = Capture::load(&opts.capture, &load)?;
    // Before training: does the mesh line up with the photographs?
    let alignment = crate::capture::alignment::check(&mut capture, &opts.input.alignment)?;
    for w in &capture.warnings {
        eprintln!("dnr-bake: warning: {w}");
    }
    let load = capture.load_report(&load, alignment);
    if opts.input.verbose {
        for k in &load.ignored_keys {
            eprintln!("dnr-bake: ignored key {k}");
        }
        eprintln!(
            "dnr-bake: load timings (s): {}",
            serde_json::to_string(&load.timings).unwrap_or_default()
        );
    }
    let train = views::prepare(&capture.mesh, &capture.train);
    let test = views::prepare(&capture.mesh, &capture.test);
    Ok(Loaded {
        capture,
        train,
        test,
        load,
    })
}

/// What gets exported: the texture, the SH layer, the network.
pub(crate) struct ExportParts<'a> {
    pub pyr: &'a dnr_runtime::texture::Pyramid,
    pub sh: Option<(u32, u32)>,
    pub net: &'a export::ExportNet,
    pub out_ch: usize,
}

impl<'a> ExportParts<'a> {
    /// The trainer's current state with `net` (its [`Trainer::export_net`]).
    pub fn of(trainer: &'a Trainer, net: &'a export::ExportNet) -> Self {
        ExportParts {
            pyr: &trainer.pyr,
            sh: trainer.sh_layer(),
            net,
            out_ch: trainer.out_ch,
        }
    }
}

/// Builds and writes an asset atomically; returns its size.
pub(crate) fn write_asset(
    loaded: &Loaded,
    parts: &ExportParts,
    dtype: dnr_format::model::DType,
    path: &std::path::Path,
) -> Result<u64, BakeError> {
    let builder = export::build(
        &loaded.capture.mesh,
        parts.pyr,
        parts.sh,
        parts.net,
        parts.out_ch,
        dtype,
    )?;
    Ok(export::write(&builder, path)?)
}

/// Held-out error (PSNR, object MSE, SSIM) of a written asset through the runtime.
pub(crate) fn evaluate_asset(
    loaded: &Loaded,
    path: &std::path::Path,
) -> Result<(f64, f64, f64), BakeError> {
    if loaded.capture.test.is_empty() {
        return Ok((f64::NAN, f64::NAN, f64::NAN));
    }
    let read_back = |message: String| BakeError::ReadBack {
        path: path.display().to_string(),
        message,
    };
    let renderer =
        dnr_runtime::renderer::Renderer::from_path(path).map_err(|e| read_back(e.to_string()))?;
    let rep = crate::eval::evaluate(&renderer, &loaded.capture.test, None)
        .map_err(|e| read_back(e.to_string()))?;
    Ok((rep.mean.psnr, rep.mean.mse_obj, rep.mean.ssim))
}

/// Everything `finish` reports besides the asset.
pub(crate) struct Outcome<'a> {
    /// The configuration trained with.
    pub config: &'a TrainConfig,
    pub steps: u64,
    pub state: RunState,
    pub auto: Option<&'a crate::auto::AutoReport>,
}

/// Writes the asset (and the f32 copy if asked), evaluates it, writes the report.
pub(crate) fn finish(
    loaded: &Loaded,
    parts: &ExportParts,
    outcome: Outcome,
    opts: &BakeOptions,
    t_start: Instant,
) -> Result<Summary, BakeError> {
    let asset_bytes = write_asset(loaded, parts, dnr_format::model::DType::F16, &opts.output)?;
    if let Some(p) = &opts.write_f32 {
        write_asset(loaded, parts, dnr_format::model::DType::F32, p)?;
    }
    // The asset is complete: the checkpoint is no longer needed.
    let ckpt_path = checkpoint::path_for(&opts.output);
    if let Some(dir) = ckpt_path.parent() {
        let _ = std::fs::remove_dir_all(dir);
    }
    let (test_psnr, test_mse, test_ssim) = evaluate_asset(loaded, &opts.output)?;
    let records = outcome.state.records;
    let recoveries = outcome.state.recoveries;
    let train_seconds = records.last().map_or(0.0, |r| r.seconds);
    let summary = Summary {
        test_psnr,
        test_mse,
        test_ssim,
        steps: outcome.steps,
        seconds: t_start.elapsed().as_secs_f64(),
        train_seconds,
        asset_bytes,
        recoveries: recoveries.len(),
        records: records.clone(),
    };
    if let Some(path) = &opts.report {
        let rep = Report {
            config: outcome.config,
            capture: opts.capture.display().to_string(),
            mesh: loaded.capture.mesh_path.display().to_string(),
            train_views: loaded.train.len(),
            test_views: loaded.test.len(),
            warnings: &loaded.capture.warnings,
            records: &records,
            recoveries: &recoveries,
            load: &loaded.load,
            auto: outcome.auto,
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

/// The progress display of a training run: a bar on a terminal, plain lines otherwise.
pub(crate) struct Progress {
    bar: Option<ProgressBar>,
    enabled: bool,
    plain: bool,
    last_psnr: std::cell::Cell<f64>,
    last_line: std::cell::Cell<f64>,
    by_time: bool,
}

impl Progress {
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
            b.set_message(format!("step {} | {held_out}", t.step));
        }
        if self.enabled && self.plain && secs - self.last_line.get() >= 10.0 {
            self.last_line.set(secs);
            eprintln!("step {} | {secs:.0} s | {held_out}", t.step);
        }
    }

    pub fn on_record(&self, r: &Record) {
        self.last_psnr.set(r.test_psnr);
        if self.enabled && self.plain {
            eprintln!(
                "eval: step {} | {:.1} s | loss {:.4} | held-out {:.2} dB, object MSE {:.1}",
                r.step, r.seconds, r.train_loss, r.test_psnr, r.test_mse
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

    pub fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}

/// Runs the whole bake (`--preset auto` hands over to [`crate::auto::bake`]).
pub fn bake(cfg: &TrainConfig, opts: &BakeOptions) -> Result<Summary, BakeError> {
    if cfg.preset == crate::train::config::Preset::Auto {
        return crate::auto::bake(cfg, opts);
    }
    let t_start = Instant::now();
    let loaded = load(cfg, opts)?;
    let t_init = Instant::now();
    let mut trainer = Trainer::new(cfg.clone(), &loaded.train)?;
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

    let progress = Progress::new(opts.progress, cfg);
    train::run(
        &mut trainer,
        &mut state,
        &loaded.train,
        &loaded.test,
        Some(&ckpt),
        |t, secs| progress.on_step(t, secs),
        |r| progress.on_record(r),
    )?;
    progress.finish();
    let net = trainer.export_net();
    let parts = ExportParts::of(&trainer, &net);
    let outcome = Outcome {
        config: &trainer.cfg,
        steps: trainer.step,
        state,
        auto: None,
    };
    finish(&loaded, &parts, outcome, opts, t_start)
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
