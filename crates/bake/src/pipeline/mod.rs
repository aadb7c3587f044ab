//! The steps every bake is made of, whichever preset drives them: load the capture (views
//! rasterised, validation views split off), train, write the asset, evaluate it through the
//! runtime, report. The fixed presets (`crate::fixed`) and auto (`crate::auto`) call these
//! from above; nothing here calls back up.

pub mod progress;

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::Serialize;

use crate::capture::{Capture, Frame, LoadOptions};
use crate::export::{self, ExportNet};
use crate::train::checkpoint;
use crate::train::config::TrainConfig;
use crate::train::views::{self, View};
use crate::train::{Record, Recovery, RunState, Trainer};
use dnr_format::model::DType;

pub use progress::Progress;

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
    /// `--storage`: how levels and weights are stored (quantised storage also fine-tunes
    /// through its rounding over the last part of training).
    pub storage: crate::storage::StorageMode,
    /// `--storage-bound-db`: the validation PSNR `--storage auto` may spend.
    pub storage_bound_db: f64,
    /// Also write the same trained state with f16 storage here (to compare a quantised asset
    /// with it).
    pub write_f16: Option<PathBuf>,
    /// Capture loading choices (working size, UVs, mesh placement, alignment check).
    pub input: crate::capture::InputOptions,
    /// `--min-cycle`: with `--preset auto`, the shortest budget cycle (a budget of at least
    /// twice this bakes half of it first; see `crate::auto::cycles`).
    pub min_cycle_secs: f64,
}

impl BakeOptions {
    /// A bake of `capture` into `output` with everything else off or at its default: no
    /// report, no progress, no periodic checkpoints, no extra copies, f16 storage.
    pub fn new(capture: impl Into<PathBuf>, output: impl Into<PathBuf>) -> Self {
        BakeOptions {
            capture: capture.into(),
            output: output.into(),
            mesh: None,
            report: None,
            resume: false,
            progress: false,
            checkpoint_every: f64::INFINITY,
            limits: Default::default(),
            write_f32: None,
            write_unpruned: None,
            storage: crate::storage::StorageMode::F16,
            storage_bound_db: crate::storage::DEFAULT_BOUND_DB,
            write_f16: None,
            input: Default::default(),
            min_cycle_secs: crate::auto::cycles::MIN_CYCLE_SECS,
        }
    }
}

/// Final figures of a bake.
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Summary {
    /// Held-out PSNR (dB) of the exported asset rendered by the runtime.
    pub test_psnr: f64,
    /// Held-out object MSE on [0, 255].
    pub test_mse: f64,
    /// Held-out SSIM.
    pub test_ssim: f64,
    /// Training steps.
    pub steps: u64,
    /// Wall-clock seconds of the whole bake.
    pub seconds: f64,
    /// Training seconds (test-view evaluation excluded).
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
struct Report<'a, A: Serialize> {
    config: &'a TrainConfig,
    capture: String,
    mesh: String,
    train_views: usize,
    /// Training views held out of training to decide (best state, divergence, auto's
    /// choices), by name.
    validation_views: Vec<String>,
    test_views: usize,
    warnings: &'a [String],
    records: &'a [Record],
    /// Validation checks: `[step, training seconds, validation PSNR]`.
    validation_checks: &'a [(u64, f64, f64)],
    /// Validation checks of the moving average of the state: `[step, validation PSNR]`.
    ema_checks: &'a [(u64, f64)],
    /// Divergences the training loop recovered from (rollback, halved learning rates).
    recoveries: &'a [Recovery],
    /// What loading found and did: timings, UVs, the alignment check.
    load: &'a crate::capture::LoadReport,
    /// `--preset auto`: what was measured and decided.
    #[serde(skip_serializing_if = "Option::is_none")]
    auto: Option<&'a A>,
    /// `--storage`: the encoding of each part, auto's trials, every storage measured.
    storage: &'a crate::storage::StorageReport,
    /// The fallback PNG's size and every candidate measured.
    fallback: &'a crate::fallback::FallbackReport,
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

/// Most validation views held out of training.
pub const MAX_VALIDATION_VIEWS: usize = 5;

/// A loaded capture with its views rasterised and its validation views split off.
pub struct Loaded {
    /// The capture as loaded.
    pub capture: Capture,
    /// Training views: those trained on first, then the validation views.
    pub train: Vec<View>,
    /// How many of `train` are trained on.
    pub n_fit: usize,
    /// Indices (into `capture.train`) of the validation views.
    pub val_idx: Vec<usize>,
    /// The capture's test views (reported, never decided on).
    pub test: Vec<View>,
    /// What loading found and did.
    pub load: crate::capture::LoadReport,
    /// Subsamples per pixel side the views were prepared with: the configuration's, or 1
    /// when their G-buffers would pass [`SUBSAMPLE_MEMORY_LIMIT`].
    pub supersample: u32,
}

/// Most bytes the subsample G-buffers of all views may take (36 bytes a subsample); a
/// capture beyond it trains at one sample per pixel, with a warning.
pub const SUBSAMPLE_MEMORY_LIMIT: u64 = 6 << 30;

/// The supersample factor `wanted` if the subsample G-buffers of `pixels` pixels fit
/// [`SUBSAMPLE_MEMORY_LIMIT`], else 1 with the warning to print.
pub fn affordable_supersample(wanted: u32, pixels: u64) -> (u32, Option<String>) {
    let bytes = pixels
        .saturating_mul(u64::from(wanted) * u64::from(wanted))
        .saturating_mul(std::mem::size_of::<[f32; 9]>() as u64);
    if wanted <= 1 || bytes <= SUBSAMPLE_MEMORY_LIMIT {
        return (wanted.max(1), None);
    }
    (
        1,
        Some(format!(
            "--supersample {wanted} would need {:.1} GiB of subsample G-buffers for {pixels} \
             pixels (at most {} GiB); training at one sample per pixel",
            bytes as f64 / (1u64 << 30) as f64,
            SUBSAMPLE_MEMORY_LIMIT >> 30
        )),
    )
}

impl Loaded {
    /// Forgets the views' subsample G-buffers: training and evaluation at one sample per
    /// pixel.
    pub fn drop_subsamples(&mut self) {
        for v in self.train.iter_mut().chain(self.test.iter_mut()) {
            v.fine = None;
        }
        self.supersample = 1;
    }

    /// The views training fits.
    pub fn fit(&self) -> &[View] {
        &self.train[..self.n_fit]
    }

    /// The validation views (training views held out of training).
    pub fn val(&self) -> &[View] {
        &self.train[self.n_fit..]
    }

    /// A validation frame (for timing renders), or the first training frame.
    pub fn val_frame(&self) -> Option<&Frame> {
        self.val_idx
            .first()
            .and_then(|&i| self.capture.train.get(i))
            .or(self.capture.train.first())
    }

    /// Names of the validation views.
    pub fn val_names(&self) -> Vec<String> {
        self.val_idx
            .iter()
            .filter_map(|&i| self.capture.train.get(i).map(|f| f.name.clone()))
            .collect()
    }
}

/// Indices of the training views held out for validation: every 20th view (at most
/// [`MAX_VALIDATION_VIEWS`], none below 4 views), spread over the list.
pub fn validation_indices(n: usize) -> Vec<usize> {
    if n < 4 {
        return Vec::new();
    }
    let k = (n / 20).clamp(1, MAX_VALIDATION_VIEWS);
    (0..k).map(|i| (i * n + n / 2) / k).collect()
}

/// Loads the capture, prepares the views and splits off the validation views (also sets the
/// thread count).
pub fn load(cfg: &TrainConfig, opts: &BakeOptions) -> Result<Loaded, BakeError> {
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
    let pixels: u64 = capture
        .train
        .iter()
        .chain(&capture.test)
        .map(|f| u64::from(f.camera.width) * u64::from(f.camera.height))
        .sum();
    let (supersample, warning) = affordable_supersample(cfg.supersample, pixels);
    if let Some(w) = warning {
        eprintln!("dnr-bake: warning: {w}");
    }
    let all = views::prepare(&capture.mesh, &capture.train, supersample);
    let test = views::prepare(&capture.mesh, &capture.test, supersample);
    let val_idx = validation_indices(all.len());
    let (mut fit, mut val) = (Vec::new(), Vec::new());
    for (i, v) in all.into_iter().enumerate() {
        if val_idx.contains(&i) {
            val.push(v);
        } else {
            fit.push(v);
        }
    }
    let n_fit = fit.len();
    fit.append(&mut val);
    Ok(Loaded {
        capture,
        train: fit,
        n_fit,
        val_idx,
        test,
        load,
        supersample,
    })
}

/// What gets exported: the texture, the SH layer, the network.
pub struct ExportParts<'a> {
    /// The neural texture.
    pub pyr: &'a dnr_runtime::texture::Pyramid,
    /// SH layer `(degree, first channel)`.
    pub sh: Option<(u32, u32)>,
    /// The renderer.
    pub net: &'a ExportNet,
    /// Output channels (4 with alpha).
    pub out_ch: usize,
    /// Halvings of the fallback PNG from the finest level's size (see [`crate::fallback`]).
    pub fallback_halvings: u32,
    /// The renderer's `supersample` (subsamples per pixel side the network was trained on).
    pub supersample: u32,
}

impl<'a> ExportParts<'a> {
    /// The trainer's current state with `net` (its [`Trainer::export_net`]).
    pub fn of(trainer: &'a Trainer, net: &'a ExportNet) -> Self {
        ExportParts {
            pyr: &trainer.pyr,
            sh: trainer.sh_layer(),
            net,
            out_ch: trainer.out_ch,
            fallback_halvings: 0,
            supersample: trainer.cfg.supersample,
        }
    }
}

/// Builds an asset (not yet encoded).
pub fn build_asset(
    loaded: &Loaded,
    parts: &ExportParts,
    storage: &export::Storage,
) -> Result<dnr_format::asset::AssetBuilder, BakeError> {
    let mut builder = export::build_with(
        &loaded.capture.mesh,
        parts.pyr,
        parts.sh,
        parts.net,
        parts.out_ch,
        parts.supersample,
        storage,
    )?;
    builder.set_fallback_halvings(0, parts.fallback_halvings);
    Ok(builder)
}

/// Builds and writes an asset atomically; returns its size.
pub fn write_asset(
    loaded: &Loaded,
    parts: &ExportParts,
    storage: &export::Storage,
    path: &Path,
) -> Result<u64, BakeError> {
    let builder = build_asset(loaded, parts, storage)?;
    Ok(export::write(&builder, path)?)
}

/// Chooses the fallback PNG's size ([`crate::fallback`]) on the validation views (the
/// training views when there are none).
pub fn choose_fallback(
    loaded: &Loaded,
    parts: &ExportParts,
) -> Result<crate::fallback::FallbackReport, BakeError> {
    let builder = build_asset(loaded, parts, &export::Storage::exr(DType::F16))?;
    let err = |source| {
        BakeError::Export(export::ExportError::Format {
            path: "(fallback)".into(),
            source,
        })
    };
    let tex = builder
        .textures
        .first()
        .ok_or_else(|| err(dnr_format::Error::invalid("no neural texture")))?;
    let (w, h, rgba) = dnr_format::asset::fallback_rgba8(&tex.decoded()).map_err(err)?;
    let (views, name) = if loaded.val().is_empty() {
        (loaded.fit(), "training")
    } else {
        (loaded.val(), "validation")
    };
    let probes = crate::fallback::probes(views);
    crate::fallback::choose(
        w,
        h,
        &rgba,
        (tex.wrap_s, tex.wrap_t),
        &probes,
        name,
        crate::fallback::BOUND_DB,
    )
    .map_err(err)
}

/// Held-out error (PSNR, object MSE, SSIM) of a written asset through the runtime.
pub fn evaluate_asset(loaded: &Loaded, path: &Path) -> Result<(f64, f64, f64), BakeError> {
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

/// Writes an asset to a temporary file beside the output (or to `keep`), returns its bytes
/// and the ms per frame of `frame` through the runtime (NaN without a frame).
pub fn measure_asset(
    loaded: &Loaded,
    parts: &ExportParts,
    opts: &BakeOptions,
    keep: Option<&Path>,
    frame: Option<&Frame>,
) -> Result<(u64, f64), BakeError> {
    let tmp: PathBuf = match keep {
        Some(p) => p.to_path_buf(),
        None => {
            let dir = opts
                .output
                .parent()
                .filter(|p| !p.as_os_str().is_empty())
                .unwrap_or(Path::new("."));
            dir.join(format!(".measure.{}.glb", std::process::id()))
        }
    };
    let result = (|| {
        let bytes = write_asset(
            loaded,
            parts,
            &export::Storage::exr(dnr_format::model::DType::F16),
            &tmp,
        )?;
        let Some(f) = frame else {
            return Ok((bytes, f64::NAN));
        };
        let r =
            dnr_runtime::renderer::Renderer::from_path(&tmp).map_err(|e| BakeError::ReadBack {
                path: tmp.display().to_string(),
                message: e.to_string(),
            })?;
        let (min, _) = crate::bench::time_min_median(3, || {
            std::hint::black_box(r.render(&f.camera, f.width(), f.height()).ok());
        });
        Ok((bytes, 1e3 * min))
    })();
    if keep.is_none() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// Everything [`finish`] reports besides the asset.
pub struct Outcome<'a, A: Serialize> {
    /// The configuration trained with.
    pub config: &'a TrainConfig,
    /// Steps taken.
    pub steps: u64,
    /// The training loop's state (records, checks, recoveries).
    pub state: RunState,
    /// Auto's decisions, if auto drove the bake.
    pub auto: Option<&'a A>,
    /// What quantisation-aware fine-tuning imitated, if it ran.
    pub qat: Option<crate::train::quantise::QatTarget>,
    /// `--storage auto`'s choice, made at the start of the fine-tune, if it ran.
    pub storage_choice: Option<crate::storage::AutoChoice>,
}

/// Writes the asset (and the f32 copy if asked), removes the checkpoint, evaluates the asset
/// on the test views through the runtime, writes the report.
pub fn finish<A: Serialize>(
    loaded: &Loaded,
    parts: &ExportParts,
    outcome: Outcome<A>,
    opts: &BakeOptions,
    t_start: Instant,
) -> Result<Summary, BakeError> {
    let fallback = choose_fallback(loaded, parts)?;
    if opts.progress || opts.input.verbose {
        for line in crate::fallback::describe(&fallback) {
            eprintln!("dnr-bake: {line}");
        }
    }
    let parts = &ExportParts {
        fallback_halvings: fallback.halvings,
        ..*parts
    };
    let (storage, storage_report) = crate::storage::choose(
        loaded,
        parts,
        opts.storage,
        opts.storage_bound_db,
        outcome.qat.clone(),
        outcome.storage_choice.clone(),
    )?;
    if opts.progress {
        for line in crate::storage::describe(&storage_report) {
            eprintln!("dnr-bake: {line}");
        }
    }
    let asset_bytes = write_asset(loaded, parts, &storage, &opts.output)?;
    if let Some(p) = &opts.write_f32 {
        write_asset(
            loaded,
            parts,
            &export::Storage::exr(dnr_format::model::DType::F32),
            p,
        )?;
    }
    if let Some(p) = &opts.write_f16 {
        write_asset(
            loaded,
            parts,
            &export::Storage::exr(dnr_format::model::DType::F16),
            p,
        )?;
    }
    // The asset is complete: the checkpoint is no longer needed.
    let ckpt_path = checkpoint::path_for(&opts.output);
    if let Some(dir) = ckpt_path.parent() {
        let _ = std::fs::remove_dir_all(dir);
    }
    let (test_psnr, test_mse, test_ssim) = evaluate_asset(loaded, &opts.output)?;
    let state = outcome.state;
    let train_seconds = state.train_secs;
    let summary = Summary {
        test_psnr,
        test_mse,
        test_ssim,
        steps: outcome.steps,
        seconds: t_start.elapsed().as_secs_f64(),
        train_seconds,
        asset_bytes,
        recoveries: state.recoveries.len(),
        records: state.records.clone(),
    };
    if let Some(path) = &opts.report {
        let rep = Report {
            config: outcome.config,
            capture: opts.capture.display().to_string(),
            mesh: loaded.capture.mesh_path.display().to_string(),
            train_views: loaded.n_fit,
            validation_views: loaded.val_names(),
            test_views: loaded.test.len(),
            warnings: &loaded.capture.warnings,
            records: &state.records,
            validation_checks: &state.checks,
            ema_checks: &state.ema_checks,
            recoveries: &state.recoveries,
            load: &loaded.load,
            auto: outcome.auto,
            storage: &storage_report,
            fallback: &fallback,
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

/// Writes `bytes` to `path` through a temporary file in the same folder and a rename, so a
/// crash never leaves a partial file.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn supersampling_falls_back_to_one_sample_beyond_the_memory_limit() {
        // 200 views of 256^2 at s = 2: about 1.8 GiB, kept.
        assert_eq!(affordable_supersample(2, 200 * 256 * 256), (2, None));
        // 1000 views of 1024^2 at s = 2: about 141 GiB, refused with a warning.
        let (s, w) = affordable_supersample(2, 1000 * 1024 * 1024);
        assert_eq!(s, 1);
        assert!(w.unwrap().contains("GiB"));
        assert_eq!(affordable_supersample(1, u64::MAX), (1, None));
    }
}
