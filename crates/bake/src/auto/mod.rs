//! `--preset auto`: measure the scene and the machine, decide what the asset needs, train it,
//! prune what costs less than [`PRUNE_DB`] on validation views, fine-tune, export. Every
//! decision lands in the bake report with what it measured and what it saved.
//!
//! Within the budget `B` (seconds counted like every bake's: initialisation, analysis and
//! pruning included, the periodic held-out evaluations excluded):
//! 1. Validation views: every 20th training view (at most 5) is held out of training until
//!    the decisions are made, so they are judged on views the model did not fit; the
//!    capture's test views stay untouched for the reported error.
//! 2. View dependence ([`view_dependence`]): the SH layer is kept only when the training
//!    images show colour that follows the view direction.
//! 3. Network and texture size: the largest rung of [`RUNGS`] whose step, timed here on this
//!    capture, allows at least [`MIN_STEPS`] steps before pruning. (A measured rate against a
//!    stated floor: the larger rung overtakes the smaller only after about that many steps.)
//! 4. Texels no training pixel touches are zero from the start and never updated.
//! 5. Train to `PRUNE_AT * B`; texture only if the network buys less than [`PRUNE_DB`] over
//!    the classical texture on the validation views.
//! 6. Prune levels and channels ([`prune`]), put the validation views back into training and
//!    fine-tune to `B` at [`FINE_TUNE_LR`] times the learning rates.

pub mod prune;
pub mod view_dependence;

use std::path::{Path, PathBuf};
use std::time::Instant;

use dnr_runtime::texture::{taps, Pyramid};
use serde::Serialize;

use crate::bake::{self, BakeError, BakeOptions, ExportParts, Loaded, Outcome, Progress, Summary};
use crate::export::ExportNet;
use crate::train::config::{Arch, TrainConfig, AUTO_DEFAULT_BUDGET};
use crate::train::views::View;
use crate::train::{self, RunState, TrainError, Trainer};

/// Validation PSNR (dB) a removal may cost and still be made; also the least a network must
/// buy over the classical texture to be kept.
pub const PRUNE_DB: f64 = 0.05;
/// Fraction of the budget trained before pruning (the rest fine-tunes the pruned model).
pub const PRUNE_AT: f64 = 0.85;
/// Learning-rate factor of the fine-tuning phase.
pub const FINE_TUNE_LR: f32 = 0.3;
/// Steps a rung must be able to take before pruning to be chosen.
pub const MIN_STEPS: f64 = 2000.0;

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
    /// Measured training step (ms, mean of 5 after 2 warm-up steps).
    pub step_ms: f64,
    /// Steps that fit before pruning at that rate.
    pub steps_before_pruning: f64,
    /// Chosen.
    pub chosen: bool,
}

/// One decision with what it measured and what it saved.
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Decision {
    /// What was decided.
    pub what: String,
    /// The choice.
    pub choice: String,
    /// Measured validation error it costs (dB of PSNR; negative: it gained).
    pub cost_db: Option<f64>,
    /// Asset bytes it saved.
    pub bytes_saved: Option<i64>,
    /// Milliseconds per frame it saved (one validation view through the runtime).
    pub ms_saved: Option<f64>,
    /// Bake seconds it saved.
    pub seconds_saved: Option<f64>,
    /// The measurement behind it.
    pub why: String,
}

/// Seconds by phase.
#[derive(Clone, Debug, Default, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Phases {
    /// Split, view-dependence test, rung timing, initialisation.
    pub analysis: f64,
    /// Training up to pruning.
    pub train: f64,
    /// Pruning trials.
    pub prune: f64,
    /// Fine-tuning after pruning.
    pub fine_tune: f64,
}

/// What auto measured and decided (the bake report's `auto`).
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct AutoReport {
    /// Budget in seconds.
    pub budget: f64,
    /// Training views held out for the decisions.
    pub validation_views: Vec<String>,
    /// The view-dependence test.
    pub view_dependence: view_dependence::ViewDependence,
    /// The rungs timed.
    pub rungs: Vec<RungTrial>,
    /// Texels no training pixel touches, per level (zero in the asset).
    pub untouched_texels: Vec<usize>,
    /// Validation PSNR of the classical texture (the starting point).
    pub classical_psnr: f64,
    /// Validation PSNR of the trained model before pruning.
    pub trained_psnr: f64,
    /// Whether the network was dropped for the texture alone.
    pub texture_only: bool,
    /// The pruning pass (absent when texture only).
    pub pruning: Option<prune::Pruning>,
    /// Asset bytes and ms per frame before pruning.
    pub unpruned_bytes: u64,
    /// Milliseconds per frame before pruning.
    pub unpruned_ms: f64,
    /// Asset bytes after.
    pub pruned_bytes: u64,
    /// Milliseconds per frame after.
    pub pruned_ms: f64,
    /// Seconds by phase.
    pub seconds: Phases,
    /// Every decision.
    pub decisions: Vec<Decision>,
}

/// Which texels of each level some training pixel's bilinear taps reach: exactly the texels
/// training can update (and the only ones training views ever read).
pub fn touched_texels(pyr: &Pyramid, views: &[View]) -> Vec<Vec<bool>> {
    pyr.levels
        .iter()
        .map(|l| {
            let mut t = vec![false; l.width * l.height];
            for v in views {
                for (uv, &c) in v.gbuf.uv.iter().zip(&v.gbuf.coverage) {
                    if c == 0.0 {
                        continue;
                    }
                    if let Some(tp) = taps(l.width, l.height, pyr.wrap_s, pyr.wrap_t, uv[0], uv[1])
                    {
                        for (i, w) in tp {
                            if w != 0.0 {
                                t[i] = true;
                            }
                        }
                    }
                }
            }
            t
        })
        .collect()
}

/// Indices of the training views held out for validation.
fn validation_indices(n: usize) -> Vec<usize> {
    if n < 4 {
        return Vec::new();
    }
    let k = (n / 20).clamp(1, 5);
    (0..k).map(|i| (i * n + n / 2) / k).collect()
}

fn mean_psnr(e: &[crate::eval::metrics::ViewError]) -> f64 {
    e.iter().map(|e| e.psnr).sum::<f64>() / e.len().max(1) as f64
}

/// Writes an asset to a temporary file beside the output (or to `keep`), returns its bytes
/// and the ms per frame of one camera through the runtime.
fn measure_asset(
    loaded: &Loaded,
    parts: &ExportParts,
    opts: &BakeOptions,
    keep: Option<&Path>,
    frame: Option<&crate::capture::Frame>,
) -> Result<(u64, f64), BakeError> {
    let tmp: PathBuf = match keep {
        Some(p) => p.to_path_buf(),
        None => {
            let dir = opts
                .output
                .parent()
                .filter(|p| !p.as_os_str().is_empty())
                .unwrap_or(Path::new("."));
            dir.join(format!(".auto-measure.{}.glb", std::process::id()))
        }
    };
    let bytes = bake::write_asset(loaded, parts, dnr_format::model::DType::F16, &tmp)?;
    let ms = match frame {
        Some(f) => {
            let r =
                dnr_runtime::renderer::Renderer::from_path(&tmp).map_err(|e| BakeError::ReadBack {
                    path: tmp.display().to_string(),
                    message: e.to_string(),
                });
            match r {
                Ok(r) => {
                    let (min, _) = crate::bench::time_min_median(3, || {
                        std::hint::black_box(r.render(&f.camera, f.width(), f.height()).ok());
                    });
                    1e3 * min
                }
                Err(e) => {
                    if keep.is_none() {
                        let _ = std::fs::remove_file(&tmp);
                    }
                    return Err(e);
                }
            }
        }
        None => f64::NAN,
    };
    if keep.is_none() {
        let _ = std::fs::remove_file(&tmp);
    }
    Ok((bytes, ms))
}

/// The auto bake (see the module documentation).
pub fn bake(cfg: &TrainConfig, opts: &BakeOptions) -> Result<Summary, BakeError> {
    let t_start = Instant::now();
    if opts.resume {
        return Err(TrainError::Config(
            "--resume is not supported with --preset auto (its decisions depend on the whole run); bake again".into(),
        )
        .into());
    }
    let budget = if cfg.time_budget > 0.0 {
        cfg.time_budget
    } else {
        AUTO_DEFAULT_BUDGET
    };
    let mut loaded = bake::load(cfg, opts)?;
    let t_analysis = Instant::now();

    // 1. Validation views last, so `train[..n_fit]` is what the first phase fits.
    let val_idx = validation_indices(loaded.train.len());
    let all = std::mem::take(&mut loaded.train);
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
    loaded.train = fit;
    let loaded = loaded;
    let fit = &loaded.train[..n_fit];
    let val: &[View] = if n_fit < loaded.train.len() {
        &loaded.train[n_fit..]
    } else {
        &loaded.train
    };
    let val_frame = val_idx
        .first()
        .and_then(|&i| loaded.capture.train.get(i))
        .or(loaded.capture.train.first());

    // 2. View dependence.
    let vd = view_dependence::measure(fit);

    // 3. Rungs, largest first; the chosen trainer keeps its timed steps.
    let mut rungs = Vec::new();
    let mut chosen = None;
    for (i, r) in RUNGS.iter().enumerate() {
        let c = TrainConfig {
            resolution: r.resolution,
            levels: r.levels,
            widths: r.widths.to_vec(),
            arch: Arch::Unet,
            sh: vd.view_dependent,
            time_budget: budget * PRUNE_AT,
            ..cfg.clone()
        };
        let mut tr = Trainer::new(c, fit)?;
        // 4. Untouched texels are zero from the start.
        let touched = touched_texels(&tr.pyr, fit);
        tr.zero_untouched(&touched);
        let untouched: Vec<usize> = touched
            .iter()
            .map(|t| t.iter().filter(|&&b| !b).count())
            .collect();
        let classical = (tr.pyr.clone(), mean_psnr(&tr.evaluate_texture_only(val)?));
        // The first steps fill the tensor pool and the caches; time the ones after.
        for _ in 0..WARM_STEPS {
            tr.step(fit)?;
        }
        let ts = Instant::now();
        for _ in 0..TIMED_STEPS {
            tr.step(fit)?;
        }
        let step_s = ts.elapsed().as_secs_f64() / TIMED_STEPS as f64;
        let left = budget * PRUNE_AT - t_analysis.elapsed().as_secs_f64();
        let steps = left.max(0.0) / step_s;
        let ok = steps >= MIN_STEPS || i + 1 == RUNGS.len();
        rungs.push(RungTrial {
            name: r.name.into(),
            resolution: r.resolution,
            levels: r.levels,
            widths: r.widths.to_vec(),
            step_ms: 1e3 * step_s,
            steps_before_pruning: steps,
            chosen: ok,
        });
        if ok {
            chosen = Some((tr, classical, untouched));
            break;
        }
    }
    let (mut tr, (classical_pyr, classical_psnr), untouched) = chosen.expect("last rung");
    let mut phases = Phases {
        analysis: t_analysis.elapsed().as_secs_f64(),
        ..Phases::default()
    };
    let mut state = RunState {
        train_secs: phases.analysis,
        ..RunState::default()
    };

    // 5. Train to the pruning point.
    let progress = Progress::new(opts.progress, &tr.cfg);
    progress.println(&format!(
        "dnr-bake auto: SH {} (view-dependence {:.3}, threshold {}), rung {} ({:.0} ms/step), {} validation views",
        if vd.view_dependent { "kept" } else { "dropped" },
        vd.excess_explained,
        vd.threshold,
        rungs.last().map_or("?", |r| r.name.as_str()),
        rungs.last().map_or(f64::NAN, |r| r.step_ms),
        val_idx.len()
    ));
    train::run(
        &mut tr,
        &mut state,
        fit,
        val,
        None,
        |t, s| progress.on_step(t, s),
        |r| progress.on_record(r),
    )?;
    phases.train = state.train_secs - phases.analysis;
    let trained_psnr = prune::psnr(&tr, val)?;

    let mut decisions = vec![
        Decision {
            what: "view dependence".into(),
            choice: if vd.view_dependent {
                "keep the SH layer".into()
            } else {
                "drop the SH layer".into()
            },
            cost_db: None,
            bytes_saved: None,
            ms_saved: None,
            seconds_saved: None,
            why: format!(
                "the view direction explains {:.3} of the within-texel colour variance beyond chance ({} texels, {} observations; threshold {})",
                vd.excess_explained, vd.texels, vd.observations, vd.threshold
            ),
        },
        Decision {
            what: "network and texture size".into(),
            choice: rungs
                .last()
                .map(|r| format!("{} ({}x{}, {} levels, U-Net {:?})", r.name, r.resolution, r.resolution, r.levels, r.widths))
                .unwrap_or_default(),
            cost_db: None,
            bytes_saved: None,
            ms_saved: None,
            seconds_saved: None,
            why: rungs
                .iter()
                .map(|r| format!("{}: {:.1} ms/step, {:.0} steps before pruning", r.name, r.step_ms, r.steps_before_pruning))
                .collect::<Vec<_>>()
                .join("; ")
                + &format!(" (a rung needs {MIN_STEPS})"),
        },
        Decision {
            what: "texels no training pixel touches".into(),
            choice: "zero, never updated".into(),
            cost_db: None,
            bytes_saved: None,
            ms_saved: None,
            seconds_saved: None,
            why: format!(
                "{} of {} texels over the levels",
                untouched.iter().sum::<usize>(),
                tr.pyr.levels.iter().map(|l| l.width * l.height).sum::<usize>()
            ),
        },
    ];

    let net = tr.export_net();
    let unpruned = ExportParts::of(&tr, &net);
    let (unpruned_bytes, unpruned_ms) = measure_asset(
        &loaded,
        &unpruned,
        opts,
        opts.write_unpruned.as_deref(),
        val_frame,
    )?;

    let texture_only = trained_psnr - classical_psnr < PRUNE_DB;
    let (pyr, net, sh, out_ch, pruning) = if texture_only {
        // The network buys nothing: the classical texture's colour channels alone.
        let (p, n) = prune::strip_channels(
            &classical_pyr,
            &ExportNet::None,
            &(3..classical_pyr.channels).collect::<Vec<_>>(),
        );
        (p, n, None, 3, None)
    } else {
        // 6. Prune, then fine-tune on every training view.
        let pruning = prune::prune(&mut tr, val, PRUNE_DB)?;
        phases.prune = pruning.seconds;
        state.train_secs += pruning.seconds;
        tr.cfg.time_budget = budget;
        // The budget is known, so the last phase anneals: smaller steps settle the state the
        // asset is written from (the fixed presets keep the paper's constant rate).
        tr.set_learning_rates(tr.cfg.lr_net * FINE_TUNE_LR, tr.cfg.lr_tex * FINE_TUNE_LR);
        let before = state.train_secs;
        train::run(
            &mut tr,
            &mut state,
            &loaded.train,
            val,
            None,
            |t, s| progress.on_step(t, s),
            |r| progress.on_record(r),
        )?;
        phases.fine_tune = state.train_secs - before;
        let (p, n) = prune::strip_channels(&tr.pyr, &tr.export_net(), &pruning.channels);
        (p, n, tr.sh_layer(), tr.out_ch, Some(pruning))
    };
    progress.finish();
    let parts = ExportParts {
        pyr: &pyr,
        sh,
        net: &net,
        out_ch,
    };
    let (pruned_bytes, pruned_ms) = measure_asset(&loaded, &parts, opts, None, val_frame)?;
    let saved_bytes = unpruned_bytes as i64 - pruned_bytes as i64;
    let saved_ms = unpruned_ms - pruned_ms;
    if texture_only {
        decisions.push(Decision {
            what: "renderer".into(),
            choice: "texture only (the classical texture)".into(),
            cost_db: Some(trained_psnr - classical_psnr),
            bytes_saved: Some(saved_bytes),
            ms_saved: Some(saved_ms),
            seconds_saved: Some(budget - state.train_secs),
            why: format!(
                "the trained network reaches {trained_psnr:.2} dB on the validation views, the classical texture {classical_psnr:.2} dB: the network buys less than {PRUNE_DB} dB"
            ),
        });
    } else if let Some(p) = &pruning {
        decisions.push(Decision {
            what: "renderer".into(),
            choice: "keep the network".into(),
            cost_db: None,
            bytes_saved: None,
            ms_saved: None,
            seconds_saved: None,
            why: format!(
                "it reaches {trained_psnr:.2} dB on the validation views against {classical_psnr:.2} dB for the classical texture"
            ),
        });
        let items: Vec<String> = p
            .trials
            .iter()
            .filter(|t| t.pruned)
            .map(|t| t.item.clone())
            .collect();
        decisions.push(Decision {
            what: "pyramid levels and channels".into(),
            choice: if items.is_empty() {
                "keep all".into()
            } else {
                format!("remove {}", items.join(", "))
            },
            cost_db: Some(p.joint_cost_db),
            bytes_saved: Some(saved_bytes),
            ms_saved: Some(saved_ms),
            seconds_saved: None,
            why: p
                .trials
                .iter()
                .map(|t| format!("{}: {:+.3} dB", t.item, -t.cost_db))
                .collect::<Vec<_>>()
                .join(", ")
                + &format!(
                    " (removed when it costs less than {PRUNE_DB} dB; then fine-tuned {:.0} s on every training view at {FINE_TUNE_LR}x the learning rates)",
                    phases.fine_tune
                ),
        });
    }
    let report = AutoReport {
        budget,
        validation_views: val_idx
            .iter()
            .filter_map(|&i| loaded.capture.train.get(i).map(|f| f.name.clone()))
            .collect(),
        view_dependence: vd,
        rungs,
        untouched_texels: untouched,
        classical_psnr,
        trained_psnr,
        texture_only,
        pruning,
        unpruned_bytes,
        unpruned_ms,
        pruned_bytes,
        pruned_ms,
        seconds: phases,
        decisions,
    };
    let outcome = Outcome {
        config: &tr.cfg,
        steps: tr.step,
        state,
        auto: Some(&report),
    };
    bake::finish(&loaded, &parts, outcome, opts, t_start)
}
