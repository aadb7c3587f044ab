//! `--preset auto`: measure the scene and the machine, decide what the asset needs, train it
//! under one learning-rate schedule over the whole budget, prune what costs less than
//! [`PRUNE_DB`] on validation views, export. Every decision lands in the bake report with
//! what it measured and what it saved.
//!
//! [`bake`] reads top to bottom as its phases, each a function of this module (or of the
//! submodule that holds its measurement) whose figures go in the report. Within the budget
//! `B` (seconds counted like every bake's: initialisation, analysis, validation and pruning
//! included, the test-view records excluded):
//! 1. Validation views: the pipeline holds every 20th training view (at most 5) out of
//!    training; they decide, and the capture's test views stay untouched for the reported
//!    error.
//! 2. [`decide_view_dependence`]: the SH layer is kept only when the training images show
//!    colour that follows the view direction ([`view_dependence`]), at degree 3 (with
//!    [`DEGREE3_CHANNELS`] channels) when the degree-3 functions explain, beyond chance, more
//!    of what degree 2 leaves than the bar the layer itself must pass.
//! 3. [`decide_size`]: the largest rung of [`size::RUNGS`] whose step, timed here on this
//!    capture, allows at least [`size::MIN_STEPS`] steps; its finest texture level no finer
//!    than the training pixels resolve ([`footprint`]). With 2x2 subsamples per pixel (the
//!    default `--supersample 2`) where that rung still affords the steps with them
//!    ([`size::choose`]).
//! 4. [`decide_untouched`]: texels no training pixel touches are zero and never updated.
//! 5. [`train_phase`] to `PRUNE_AT` of the budget, trying the finest level on the way
//!    ([`resolution`]: removed as soon as it buys less than [`PRUNE_DB`]); then, when the network beats the classical
//!    texture by [`PRUNE_DB`] on the validation views, levels and channels that cost less than
//!    that are removed ([`prune`], its trials bounded by [`PRUNE_SHARE`] of the budget); when
//!    it does not (yet), it trains on unpruned to the end
//!    and the texture alone is written only if the network still buys less than that there.
//! 6. [`train_phase`] to the end of the budget; the schedule anneals the learning rates to
//!    its floor, and the best validated state is what gets written. With quantised storage
//!    (`--storage q8|q4|auto`) the last [`train::quantise::QAT_FRACTION`] of the budget trains
//!    through the rounding the asset will store ([`train::quantise`]).
//! 7. A budget of at least twice [`cycles::MIN_CYCLE_SECS`] runs 1-6 on half of it, then
//!    continues from that bake's state with the schedule run again ([`cycles`]), and keeps
//!    the continuation only when it beats that state on the validation views.

pub mod cycles;
pub mod footprint;
pub mod prune;
pub mod resolution;
pub mod size;
pub mod view_dependence;

use std::time::Instant;

use dnr_runtime::texture::{taps, Pyramid};
use serde::Serialize;

use crate::export::ExportNet;
use crate::pipeline::{
    self, BakeError, BakeOptions, ExportParts, Loaded, Outcome, Progress, Summary,
};
use crate::train::config::{TrainConfig, AUTO_DEFAULT_BUDGET};
use crate::train::views::View;
use crate::train::{self, RunState, TrainError, Trainer};

/// Validation PSNR (dB) a removal may cost and still be made; also the least a network must
/// buy over the classical texture to be kept.
pub const PRUNE_DB: f64 = 0.05;
/// Largest share of the budget pruning's validation renders may take. Why a bound: on the
/// development set pruning at 70% removed one channel in 24 bakes, and its renders took
/// 1.4 to 8.5 s of each, 2-3% of a 60 s bake (docs/benchmarks.md).
pub const PRUNE_SHARE: f64 = 0.01;
/// Fraction of the budget trained before pruning (the rest trains the pruned model on, as
/// the schedule anneals).
pub const PRUNE_AT: f64 = 0.7;

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

impl Decision {
    /// A decision that saved nothing measurable by itself.
    fn plain(what: &str, choice: String, why: String) -> Decision {
        Decision {
            what: what.into(),
            choice,
            cost_db: None,
            bytes_saved: None,
            ms_saved: None,
            seconds_saved: None,
            why,
        }
    }
}

/// Seconds by phase.
#[derive(Clone, Debug, Default, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Phases {
    /// View-dependence test, footprints, rung timing, initialisation.
    pub analysis: f64,
    /// Training up to pruning.
    pub train: f64,
    /// Pruning trials.
    pub prune: f64,
    /// Training after pruning.
    pub train_after_pruning: f64,
}

/// What auto measured and decided (the bake report's `auto`).
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct AutoReport {
    /// Budget in seconds.
    pub budget: f64,
    /// Training views held out for the decisions.
    pub validation_views: Vec<String>,
    /// The learning-rate schedule over the budget.
    pub schedule: train::schedule::Schedule,
    /// The view-dependence test.
    pub view_dependence: view_dependence::ViewDependence,
    /// Pixel footprints in uv space.
    pub footprint: footprint::Footprint,
    /// The rungs timed.
    pub rungs: Vec<size::RungTrial>,
    /// Texels no training pixel touches, per level (zero in the asset).
    pub untouched_texels: Vec<usize>,
    /// The trials of the finest level during training ([`resolution`]).
    pub level_checks: Vec<resolution::LevelCheck>,
    /// Validation PSNR of the classical texture (the starting point).
    pub classical_psnr: f64,
    /// Validation PSNR of the trained model before pruning.
    pub trained_psnr: f64,
    /// Whether the network was dropped for the texture alone.
    pub texture_only: bool,
    /// The pruning pass (absent when texture only, or when the network trained on unpruned).
    pub pruning: Option<prune::Pruning>,
    /// Asset bytes before pruning.
    pub unpruned_bytes: u64,
    /// Milliseconds per frame before pruning.
    pub unpruned_ms: f64,
    /// Asset bytes after.
    pub pruned_bytes: u64,
    /// Milliseconds per frame after.
    pub pruned_ms: f64,
    /// Validation PSNR of the written state.
    pub final_val_psnr: f64,
    /// The budget cycles after the first ([`cycles`]; empty for a budget of one cycle).
    pub cycles: Vec<cycles::Cycle>,
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
                let g = v.feature_gbuf();
                for (uv, &c) in g.uv.iter().zip(&g.coverage) {
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
    // A long budget bakes half of it, then continues ([`cycles`]).
    let cycle_ends = cycles::budgets(budget, opts.min_cycle_secs);
    let (first_budget, later) = cycle_ends
        .split_first()
        .map_or((budget, &[][..]), |(f, l)| (*f, l));
    // 1. Validation views (held out by the pipeline).
    let mut loaded = pipeline::load(cfg, opts)?;
    let t_analysis = Instant::now();
    let mut decisions = Vec::new();

    // 2-4. What the scene needs, what the machine affords.
    let vd = decide_view_dependence(loaded.fit(), &mut decisions);
    let fp = footprint::measure(loaded.fit());
    let cfg = TrainConfig {
        time_budget: first_budget,
        supersample: loaded.supersample,
        sh_degree: vd.degree,
        channels: channels_for(cfg.channels, &vd),
        ..cfg.clone()
    };
    let sized = decide_size(
        &cfg,
        &loaded,
        vd.view_dependent,
        &fp,
        t_analysis,
        &mut decisions,
    )?;
    let mut tr = sized.trainer;
    let mut classical_pyr = sized.classical;
    if tr.cfg.supersample != loaded.supersample {
        // The budget does not afford subsamples: free them (and skip cutting them in crops).
        loaded.drop_subsamples();
    }
    let untouched = decide_untouched(&mut tr, loaded.fit(), &mut decisions);
    let classical_psnr = {
        // The classical texture's colour channels alone, with the same texels zeroed.
        let touched = touched_texels(&classical_pyr, loaded.fit());
        std::mem::swap(&mut tr.pyr, &mut classical_pyr);
        tr.zero_untouched(&touched);
        let e = tr.evaluate_texture_only(loaded.val());
        std::mem::swap(&mut tr.pyr, &mut classical_pyr);
        let e = e?;
        e.iter().map(|e| e.psnr).sum::<f64>() / e.len().max(1) as f64
    };
    let mut phases = Phases {
        analysis: t_analysis.elapsed().as_secs_f64(),
        ..Phases::default()
    };
    let mut state = RunState {
        train_secs: phases.analysis,
        ..RunState::default()
    };

    // 5. Train to the pruning point.
    let progress = Progress::new(
        opts.progress,
        &TrainConfig {
            time_budget: budget,
            ..tr.cfg.clone()
        },
    );
    progress.println(&format!(
        "dnr-bake auto: SH {}, {}, {} validation views",
        if vd.view_dependent {
            format!("kept at degree {}", vd.degree)
        } else {
            "dropped".into()
        },
        sized.summary,
        loaded.val_idx.len()
    ));
    let mut level_checks = Vec::new();
    for &at in &resolution::CHECKS {
        phases.train += train_phase(&mut tr, &mut state, at, &loaded, &progress)?;
        if let Some(c) = resolution::check_finest(&mut tr, &mut state, loaded.val(), at, PRUNE_DB)?
        {
            state.train_secs += c.seconds;
            phases.train += c.seconds;
            level_checks.push(c);
        }
    }
    decisions.push(resolution_decision(&level_checks, &tr));
    decisions.push(checks_decision(&state, tr.cfg.time_budget));
    phases.train += train_phase(&mut tr, &mut state, PRUNE_AT, &loaded, &progress)?;
    let trained_psnr = train::run::current_psnr(&tr, &mut state, loaded.val())?;
    let net = tr.export_net();
    let (unpruned_bytes, unpruned_ms) = pipeline::measure_asset(
        &loaded,
        &ExportParts::of(&tr, &net),
        opts,
        opts.write_unpruned.as_deref(),
        loaded.val_frame(),
    )?;

    // Quantised storage: the last part of training runs through the rounding it will get.
    let mut qat = opts.storage.qat_target(tr.pyr.levels.len());
    let mut to_end = None;
    // A network that does not beat the classical texture yet may still be learning (few
    // steps on a slow or loaded machine): it trains on to the end, unpruned, and is compared
    // again there; only then may the texture alone win.
    let behind = trained_psnr - classical_psnr < PRUNE_DB;
    let end_psnr = if behind {
        to_end = Some(train_to_end(
            &mut tr, &mut state, &mut qat, later, opts, &loaded, &progress,
        )?);
        train::run::current_psnr(&tr, &mut state, loaded.val())?
    } else {
        trained_psnr
    };
    let texture_only = end_psnr - classical_psnr < PRUNE_DB;
    let (pyr, net, sh, out_ch, pruning) = if texture_only {
        // The network buys nothing: the classical texture's colour channels alone.
        decisions.push(Decision {
            what: "renderer".into(),
            choice: "texture only (the classical texture)".into(),
            cost_db: Some(trained_psnr - classical_psnr),
            bytes_saved: None,
            ms_saved: None,
            seconds_saved: None,
            why: format!(
                "the trained network reaches {trained_psnr:.2} dB on the validation views at {:.0}% of the budget and {end_psnr:.2} dB at its end, the classical texture {classical_psnr:.2} dB: the network buys less than {PRUNE_DB} dB",
                100.0 * PRUNE_AT
            ),
        });
        let (p, n) = prune::strip_channels(
            &classical_pyr,
            &ExportNet::None,
            &(3..classical_pyr.channels).collect::<Vec<_>>(),
        );
        (p, n, None, 3, None)
    } else if behind {
        decisions.push(Decision::plain(
            "renderer",
            "keep the network (unpruned)".into(),
            format!("at {:.0}% of the budget it reached {trained_psnr:.2} dB on the validation views against {classical_psnr:.2} dB for the classical texture, so it trained on without pruning; at the end it reaches {end_psnr:.2} dB", 100.0 * PRUNE_AT),
        ));
        let net = tr.export_net();
        (tr.pyr.clone(), net, tr.sh_layer(), tr.out_ch, None)
    } else {
        decisions.push(Decision::plain(
            "renderer",
            "keep the network".into(),
            format!("it reaches {trained_psnr:.2} dB on the validation views against {classical_psnr:.2} dB for the classical texture"),
        ));
        // 5. Prune; 6. train on to the end of the budget.
        let renders = prune_renders(tr.cfg.time_budget, state.val_check_secs);
        let pruning = prune::prune(
            &mut tr,
            loaded.val(),
            state.current_val.take(),
            PRUNE_DB,
            renders,
        )?;
        phases.prune = pruning.seconds;
        state.train_secs += pruning.seconds;
        to_end = Some(train_to_end(
            &mut tr, &mut state, &mut qat, later, opts, &loaded, &progress,
        )?);
        let (p, n) = prune::strip_channels(&tr.pyr, &tr.export_net(), &pruning.channels);
        (p, n, tr.sh_layer(), tr.out_ch, Some(pruning))
    };
    progress.finish();
    let ToEnd {
        secs,
        storage_choice,
        cycles: cycle_runs,
    } = to_end.unwrap_or_default();
    phases.train_after_pruning = secs;
    let final_val_psnr = state.last_val;
    let parts = ExportParts {
        pyr: &pyr,
        sh,
        net: &net,
        out_ch,
        fallback_halvings: 0,
        supersample: tr.cfg.supersample,
    };
    let (pruned_bytes, pruned_ms) =
        pipeline::measure_asset(&loaded, &parts, opts, None, loaded.val_frame())?;
    if let Some(p) = &pruning {
        decisions.push(pruning_decision(
            p,
            unpruned_bytes as i64 - pruned_bytes as i64,
            unpruned_ms - pruned_ms,
            phases.train_after_pruning,
        ));
    }
    decisions.extend(cycle_runs.iter().map(cycle_decision));
    let report = AutoReport {
        budget,
        validation_views: loaded.val_names(),
        schedule: tr.cfg.schedule,
        view_dependence: vd,
        footprint: fp,
        rungs: sized.rungs,
        untouched_texels: untouched,
        level_checks,
        classical_psnr,
        trained_psnr,
        texture_only,
        pruning,
        unpruned_bytes,
        unpruned_ms,
        pruned_bytes,
        pruned_ms,
        final_val_psnr,
        cycles: cycle_runs,
        seconds: phases,
        decisions,
    };
    let outcome = Outcome {
        config: &tr.cfg,
        steps: tr.step,
        state,
        auto: Some(&report),
        qat: if texture_only { None } else { qat },
        storage_choice: if texture_only { None } else { storage_choice },
    };
    pipeline::finish(&loaded, &parts, outcome, opts, t_start)
}

/// Channels of a degree-3 SH layer: its 16 functions from channel 3 need 19, and 20 fill the
/// last group of four the web viewer samples at once.
pub const DEGREE3_CHANNELS: u32 = 20;

/// The texture's channels for the SH layer auto chose: at least [`DEGREE3_CHANNELS`] at
/// degree 3, else as configured.
fn channels_for(channels: u32, vd: &view_dependence::ViewDependence) -> u32 {
    if vd.view_dependent && vd.degree >= 3 {
        channels.max(DEGREE3_CHANNELS)
    } else {
        channels
    }
}

/// Phase 2: keep the SH layer only when the training images show view-dependent colour,
/// at degree 3 when they show sharper view dependence than degree 2 fits.
pub fn decide_view_dependence(
    fit: &[View],
    decisions: &mut Vec<Decision>,
) -> view_dependence::ViewDependence {
    let vd = view_dependence::measure(fit);
    decisions.push(Decision::plain(
        "view dependence",
        if !vd.view_dependent {
            "drop the SH layer".into()
        } else if vd.degree >= 3 {
            format!("keep the SH layer at degree 3 ({DEGREE3_CHANNELS} channels)")
        } else {
            "keep the SH layer at degree 2".into()
        },
        format!(
            "the view direction explains {:.3} of the within-texel colour variance beyond chance ({} texels, {} observations; threshold {}); degree 3 explains {:.3} more than degree 2 (threshold {})",
            vd.excess_explained,
            vd.texels,
            vd.observations,
            vd.threshold,
            vd.excess_explained_degree3,
            vd.degree3_threshold
        ),
    ));
    vd
}

/// What [`decide_size`] chose: the trainer of the chosen rung (its timed steps taken).
pub struct Sized {
    /// The trainer, at the chosen size.
    pub trainer: Trainer,
    /// Its texture before the timed steps: the classical texture.
    pub classical: Pyramid,
    /// Every rung timed.
    pub rungs: Vec<size::RungTrial>,
    /// One line for the progress display.
    pub summary: String,
}

/// Phase 3: network and texture size (see [`size`]).
pub fn decide_size(
    cfg: &TrainConfig,
    loaded: &Loaded,
    sh: bool,
    fp: &footprint::Footprint,
    t_analysis: Instant,
    decisions: &mut Vec<Decision>,
) -> Result<Sized, BakeError> {
    let (trainer, classical, rungs) = size::choose(cfg, loaded.fit(), sh, fp, t_analysis)?;
    let chosen = rungs.iter().find(|r| r.chosen).or(rungs.last());
    let summary = chosen.map_or(String::new(), |r| {
        format!(
            "rung {} ({:.0} ms/step), texture {}x{} in {} levels, {}x{} subsamples",
            r.name, r.step_ms, r.resolution, r.resolution, r.levels, r.supersample, r.supersample
        )
    });
    decisions.push(Decision::plain(
        "network and texture size",
        chosen
            .map(|r| {
                format!(
                    "{} ({}x{}, {} levels, U-Net {:?}), {}x{} subsamples per pixel",
                    r.name, r.resolution, r.resolution, r.levels, r.widths, r.supersample,
                    r.supersample
                )
            })
            .unwrap_or_default(),
        rungs
            .iter()
            .map(|r| {
                format!(
                    "{} at {}x{} subsamples: {:.1} ms/step, {:.0} steps in the budget",
                    r.name, r.supersample, r.supersample, r.step_ms, r.steps_in_budget
                )
            })
            .collect::<Vec<_>>()
            .join("; ")
            + &format!(
                " (a rung needs {}; a rung that does is timed with its subsamples, and keeps them where it still affords {}); pixel footprint in uv {:.2e} / {:.2e} / {:.2e} at quantiles 0.1 / 0.5 / 0.9: {} texels of side resolve a pixel of the closer views",
                size::MIN_STEPS,
                size::SUPERSAMPLE_MIN_STEPS,
                fp.quantiles[0],
                fp.quantiles[2],
                fp.quantiles[4],
                fp.resolution
            ),
    ));
    Ok(Sized {
        trainer,
        classical,
        rungs,
        summary,
    })
}

/// Phase 4: texels no training pixel touches are zero from the start and never updated;
/// returns their count per level.
pub fn decide_untouched(
    tr: &mut Trainer,
    fit: &[View],
    decisions: &mut Vec<Decision>,
) -> Vec<usize> {
    let touched = touched_texels(&tr.pyr, fit);
    tr.zero_untouched(&touched);
    let untouched: Vec<usize> = touched
        .iter()
        .map(|t| t.iter().filter(|&&b| !b).count())
        .collect();
    decisions.push(Decision::plain(
        "texels no training pixel touches",
        "zero, never updated".into(),
        format!(
            "{} of {} texels over the levels",
            untouched.iter().sum::<usize>(),
            tr.pyr
                .levels
                .iter()
                .map(|l| l.width * l.height)
                .sum::<usize>()
        ),
    ));
    untouched
}

/// Phases 5 and 6: trains on the fitted views up to progress `until` of the budget; returns
/// the training seconds it took.
pub fn train_phase(
    tr: &mut Trainer,
    state: &mut RunState,
    until: f64,
    loaded: &Loaded,
    progress: &Progress,
) -> Result<f64, BakeError> {
    let before = state.train_secs;
    train::run(
        tr,
        state,
        until,
        loaded.fit(),
        loaded.val(),
        &loaded.test,
        None,
        |t, s| progress.on_step(t, s),
        |r| progress.on_record(r),
    )?;
    Ok(state.train_secs - before)
}

/// [`train_phase`] to the end of the budget; with quantised storage (`qat`), the part from
/// [`train::quantise::QAT_START`] on reads the texture and the weights rounded as they will be
/// stored. Then the later budget cycles, `later` ([`cycles::continue_to`]).
/// With `--storage auto`, the storage is chosen at that point, on the unquantised state, and
/// the fine-tune imitates what was chosen (`qat` is updated, the choice returned).
fn train_to_end(
    tr: &mut Trainer,
    state: &mut RunState,
    qat: &mut Option<train::quantise::QatTarget>,
    later: &[f64],
    opts: &BakeOptions,
    loaded: &Loaded,
    progress: &Progress,
) -> Result<ToEnd, BakeError> {
    let (secs, storage_choice) = train_first_cycle(tr, state, qat, opts, loaded, progress)?;
    let mut to_end = ToEnd {
        secs,
        storage_choice,
        cycles: Vec::new(),
    };
    for &b in later {
        let c = cycles::continue_to(tr, state, qat, b, loaded, progress)?;
        to_end.secs += c.seconds;
        to_end.cycles.push(c);
    }
    Ok(to_end)
}

/// What [`train_to_end`] trained.
#[derive(Default)]
struct ToEnd {
    /// Seconds trained.
    secs: f64,
    /// The storage `--storage auto` chose.
    storage_choice: Option<crate::storage::AutoChoice>,
    /// The cycles after the first.
    cycles: Vec<cycles::Cycle>,
}

/// [`train_to_end`]'s first cycle: returns the seconds trained and the storage chosen.
fn train_first_cycle(
    tr: &mut Trainer,
    state: &mut RunState,
    qat: &mut Option<train::quantise::QatTarget>,
    opts: &BakeOptions,
    loaded: &Loaded,
    progress: &Progress,
) -> Result<(f64, Option<crate::storage::AutoChoice>), BakeError> {
    if qat.is_none() {
        return Ok((train_phase(tr, state, 1.0, loaded, progress)?, None));
    }
    let before = train_phase(tr, state, train::quantise::QAT_START, loaded, progress)?;
    let mut choice = None;
    if opts.storage == crate::storage::StorageMode::Auto {
        let net = tr.export_net();
        let c = crate::storage::choose_auto(
            loaded,
            &ExportParts::of(tr, &net),
            opts.storage_bound_db,
            true,
        )?;
        *qat = Some(crate::storage::qat_target_of(&c.storage)).filter(|t| !t.is_identity());
        choice = Some(c);
    }
    tr.set_qat(qat.clone());
    state.current_val = None;
    let after = train_phase(tr, state, 1.0, loaded, progress)?;
    Ok((before + after, choice))
}

/// Validation renders pruning may take: [`PRUNE_SHARE`] of the budget at `render_secs` each
/// (the run's first validation render). Without a budget or a timing, no bound.
fn prune_renders(budget: f64, render_secs: f64) -> usize {
    if budget > 0.0 && render_secs > 0.0 {
        // Non-negative and finite here; the cast saturates.
        (PRUNE_SHARE * budget / render_secs).floor() as usize
    } else {
        usize::MAX
    }
}

/// The report line of how often validation checks the state ([`train::run::val_checks`]).
fn checks_decision(state: &RunState, budget: f64) -> Decision {
    let n = state.val_checks;
    let secs = state.val_check_secs;
    Decision::plain(
        "validation checks",
        format!("{n} over the budget"),
        format!(
            "one render of the validation views took {secs:.2} s; {n} checks take {:.1}% of the {budget:.0} s budget (at most {} checks, and fewer when they would take more than {:.0}% of it, never fewer than {})",
            100.0 * f64::from(n) * secs / budget.max(f64::MIN_POSITIVE),
            train::run::VAL_CHECKS,
            100.0 * train::run::VAL_SHARE,
            train::run::MIN_VAL_CHECKS
        ),
    )
}

/// The report line of a budget cycle ([`cycles`]).
fn cycle_decision(c: &cycles::Cycle) -> Decision {
    let (from, to) = (c.from_budget, c.to_budget);
    Decision {
        cost_db: c.kept.then_some(c.start_psnr - c.end_psnr),
        ..Decision::plain(
            "budget cycle",
            if c.kept {
                format!("the continuation from {from:.0} s to {to:.0} s")
            } else {
                format!("the {from:.0} s bake (the continuation to {to:.0} s did not beat it)")
            },
            format!(
                "the bake of {from:.0} s reached {:.2} dB on the validation views; the schedule ran again from its state for {:.0} s ({} steps): its best check {:.2} dB, the state it hands back {:.2} dB",
                c.start_psnr, c.seconds, c.steps, c.best_check_psnr, c.end_psnr
            ),
        )
    }
}

/// The report line of the texture-resolution trials.
fn resolution_decision(checks: &[resolution::LevelCheck], tr: &Trainer) -> Decision {
    let finest = tr.pyr.levels.first().map_or(0, |l| l.width.max(l.height));
    let removed: Vec<&resolution::LevelCheck> = checks.iter().filter(|c| c.removed).collect();
    Decision {
        what: "texture resolution".into(),
        choice: if removed.is_empty() {
            format!("keep {finest}x{finest}, {} levels", tr.pyr.levels.len())
        } else {
            format!(
                "{finest}x{finest}, {} levels (removed the {} level{} during training)",
                tr.pyr.levels.len(),
                removed
                    .iter()
                    .map(|c| format!("{0}x{0}", c.side))
                    .collect::<Vec<_>>()
                    .join(" and "),
                if removed.len() > 1 { "s" } else { "" }
            )
        },
        cost_db: removed
            .iter()
            .map(|c| c.with_db - c.without_db)
            .reduce(f64::max),
        bytes_saved: None,
        ms_saved: None,
        seconds_saved: None,
        why: if checks.is_empty() {
            format!(
                "no trial (at most {} levels, or no validation views)",
                resolution::MIN_LEVELS
            )
        } else {
            checks
                .iter()
                .map(|c| {
                    format!(
                        "at {:.0}%: the {}x{} level buys {:+.3} dB ({:.2} with, {:.2} without){}",
                        100.0 * c.progress,
                        c.side,
                        c.side,
                        c.with_db - c.without_db,
                        c.with_db,
                        c.without_db,
                        if c.removed { ", removed" } else { "" }
                    )
                })
                .collect::<Vec<_>>()
                .join("; ")
                + &format!(" (a level is removed when it buys less than {PRUNE_DB} dB)")
        },
    }
}

/// The report line of the pruning pass.
fn pruning_decision(p: &prune::Pruning, bytes: i64, ms: f64, after: f64) -> Decision {
    let items: Vec<String> = p
        .trials
        .iter()
        .filter(|t| t.pruned)
        .map(|t| t.item.clone())
        .collect();
    Decision {
        what: "pyramid levels and channels".into(),
        choice: if items.is_empty() {
            "keep all".into()
        } else {
            format!("remove {}", items.join(", "))
        },
        cost_db: Some(p.joint_cost_db),
        bytes_saved: Some(bytes),
        ms_saved: Some(ms),
        seconds_saved: None,
        why: p
            .trials
            .iter()
            .map(|t| format!("{}: {:+.3} dB", t.item, -t.cost_db))
            .collect::<Vec<_>>()
            .join(", ")
            + &format!(
                " (removed when it costs less than {PRUNE_DB} dB; then trained {after:.0} s more as the schedule annealed)"
            )
            + &if p.untried.is_empty() {
                String::new()
            } else {
                format!(
                    "; not tried: {} ({} validation renders fit in {:.0}% of the budget)",
                    p.untried.join(", "),
                    p.renders_afforded,
                    100.0 * PRUNE_SHARE
                )
            },
    }
}
