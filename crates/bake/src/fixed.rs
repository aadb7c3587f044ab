//! A bake with a fixed preset (`fast`, `balanced`, `quality`, `paper`, or explicit flags):
//! load, train with the configuration as given (checkpointed, resumable), export, evaluate.

use std::time::Instant;

use crate::pipeline::{self, BakeError, BakeOptions, ExportParts, Outcome, Progress, Summary};
use crate::storage::StorageMode;
use crate::train::checkpoint::{self, Checkpoint};
use crate::train::config::TrainConfig;
use crate::train::{self, Checkpointing, RunState, TrainError, Trainer};

/// Runs the whole bake for a fixed configuration.
pub fn bake(cfg: &TrainConfig, opts: &BakeOptions) -> Result<Summary, BakeError> {
    let t_start = Instant::now();
    let loaded = pipeline::load(cfg, opts)?;
    let t_init = Instant::now();
    let cfg = &TrainConfig {
        supersample: loaded.supersample,
        ..cfg.clone()
    };
    let mut trainer = Trainer::new(cfg.clone(), loaded.fit())?;
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
    // Quantised storage: the last part of training runs through the rounding it will get.
    let mut qat = opts.storage.qat_target(trainer.pyr.levels.len());
    let until = if qat.is_some() {
        train::quantise::QAT_START
    } else {
        1.0
    };
    train::run(
        &mut trainer,
        &mut state,
        until,
        loaded.fit(),
        loaded.val(),
        &loaded.test,
        Some(&ckpt),
        |t, secs| progress.on_step(t, secs),
        |r| progress.on_record(r),
    )?;
    // `--storage auto` chooses now, on the unquantised state, and fine-tunes toward that.
    let mut storage_choice = None;
    if qat.is_some() && opts.storage == StorageMode::Auto {
        let net = trainer.export_net();
        let choice = crate::storage::choose_auto(
            &loaded,
            &ExportParts::of(&trainer, &net),
            opts.storage_bound_db,
            true,
        )?;
        qat = Some(crate::storage::qat_target_of(&choice.storage)).filter(|t| !t.is_identity());
        storage_choice = Some(choice);
    }
    if qat.is_some() {
        trainer.set_qat(qat.clone());
        state.current_val = None;
        train::run(
            &mut trainer,
            &mut state,
            1.0,
            loaded.fit(),
            loaded.val(),
            &loaded.test,
            Some(&ckpt),
            |t, secs| progress.on_step(t, secs),
            |r| progress.on_record(r),
        )?;
    }
    progress.finish();
    let net = trainer.export_net();
    let parts = ExportParts::of(&trainer, &net);
    let outcome: Outcome<()> = Outcome {
        config: &trainer.cfg,
        steps: trainer.step,
        state,
        auto: None,
        qat,
        storage_choice,
    };
    pipeline::finish(&loaded, &parts, outcome, opts, t_start)
}
