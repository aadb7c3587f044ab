//! The training loop's guarantees: the schedule drives the learning rates over the run, and
//! the state it ends with is never worse on the validation views than a state it checked.

mod capture_common;

use dnr_bake::capture::{Capture, LoadOptions};
use dnr_bake::train::config::{Arch, Preset, TrainConfig, DEFAULT_SUPERSAMPLE};
use dnr_bake::train::schedule::Schedule;
use dnr_bake::train::views::{self, View};
use dnr_bake::train::{run, Loss, RunState, Trainer};

fn sample_views() -> (Vec<View>, Vec<View>) {
    let dir = capture_common::sample_capture();
    let cap = Capture::load(&dir, &LoadOptions::default()).unwrap();
    let all = views::prepare(&cap.mesh, &cap.train, DEFAULT_SUPERSAMPLE);
    // Every 8th view validates.
    let (mut fit, mut val) = (Vec::new(), Vec::new());
    for (i, v) in all.into_iter().enumerate() {
        if i % 8 == 4 {
            val.push(v);
        } else {
            fit.push(v);
        }
    }
    (fit, val)
}

fn cfg(lr: f32, steps: u64) -> TrainConfig {
    TrainConfig {
        resolution: 64,
        levels: 2,
        channels: 12,
        arch: Arch::Unet,
        widths: vec![4, 8],
        steps,
        lr_net: lr,
        lr_tex: lr,
        eval_every: 0.0,
        threads: 1,
        seed: 5,
        supersample: DEFAULT_SUPERSAMPLE,
        ..TrainConfig::preset(Preset::Fast)
    }
}

/// A whole run of `c` on `fit`, validated on `val`, with no test views and no callbacks.
fn train_quietly(c: TrainConfig, fit: &[View], val: &[View]) -> (Trainer, RunState) {
    let mut t = Trainer::new(c, fit).unwrap();
    let mut state = RunState::default();
    run_quietly(&mut t, &mut state, fit, val);
    (t, state)
}

/// One call of the loop to the end of the run, with no test views and no callbacks.
fn run_quietly(t: &mut Trainer, state: &mut RunState, fit: &[View], val: &[View]) {
    run(t, state, 1.0, fit, val, &[], None, |_, _| {}, |_| {}).unwrap();
}

#[test]
fn the_schedule_anneals_to_its_floor_over_the_steps() {
    let (fit, val) = sample_views();
    let c = cfg(1e-3, 60);
    let sched = c.schedule;
    assert_eq!(sched, Schedule::DEFAULT);
    let mut t = Trainer::new(c, &fit).unwrap();
    let mut state = RunState::default();
    let mut factors = Vec::new();
    run(
        &mut t,
        &mut state,
        1.0,
        &fit,
        &val,
        &[],
        None,
        |t, _| factors.push(t.lr_scale()),
        |_| {},
    )
    .unwrap();
    assert_eq!(t.step, 60);
    assert_eq!(factors.len(), 60);
    // Step i ran at the factor of progress i / 60.
    for (i, &f) in factors.iter().enumerate() {
        let want = sched.factor(i as f64 / 60.0) as f32;
        assert!((f - want).abs() < 1e-6, "step {i}: {f} != {want}");
    }
    assert!(factors[59] < 0.05, "the last step ran at {}", factors[59]);
    assert!(factors[10] > 0.9);
    // Validation checks at every twentieth of the run, and at the end.
    assert_eq!(state.checks.len(), 20, "{:?}", state.checks);
}

#[test]
fn the_final_state_is_never_worse_on_validation_than_a_checked_one() {
    let (fit, val) = sample_views();
    // A constant rate 30x the paper's: training jumps around, so some checked state beats
    // the last one, and the loop must hand that one back.
    let mut c = cfg(3e-2, 120);
    c.schedule = Schedule::CONSTANT;
    let (t, state) = train_quietly(c, &fit, &val);
    let best = state
        .checks
        .iter()
        .map(|c| c.2)
        .fold(f64::NEG_INFINITY, f64::max);
    let now = dnr_bake::train::run::mean_psnr(&t, &val).unwrap();
    eprintln!("checks {:?}, final {now:.3}", state.checks);
    assert!(
        (now - best).abs() < 1e-9,
        "final {now} dB, best check {best} dB"
    );
    assert!(
        t.step < 120,
        "the run must have handed back an earlier state (checks {:?})",
        state.checks
    );
}

#[test]
fn a_finest_level_of_noise_is_removed_and_one_within_the_bound_kept() {
    use dnr_bake::auto::resolution::check_finest;
    let (fit, val) = sample_views();
    let c = TrainConfig {
        levels: 3,
        ..cfg(2e-3, 150)
    };
    let (mut t, _) = train_quietly(c, &fit, &val);
    let trained = t.pyr.clone();

    // Loud noise in the finest level: removing it gains, so it goes.
    let mut x = 0x9e37_79b9u32;
    for v in &mut t.pyr.levels[0].data {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        *v = (x as f32 / u32::MAX as f32 - 0.5) * 4.0;
    }
    let c = check_finest(&mut t, &mut RunState::default(), &val, 0.5, 0.05)
        .unwrap()
        .unwrap();
    assert!(c.without_db > c.with_db, "{c:?}");
    assert!(c.removed && t.pyr.levels.len() == 2, "{c:?}");
    // Two levels left: never tried.
    assert!(
        check_finest(&mut t, &mut RunState::default(), &val, 0.6, 0.05)
            .unwrap()
            .is_none()
    );

    // The trained level, against a bound it beats (removal only below a 1 dB loss): kept,
    // and the texture is left exactly as it was.
    t.pyr = trained.clone();
    let c = check_finest(&mut t, &mut RunState::default(), &val, 0.5, -1.0)
        .unwrap()
        .unwrap();
    assert!(!c.removed && c.with_db - c.without_db >= -1.0, "{c:?}");
    assert_eq!(t.pyr.levels.len(), 3);
    assert_eq!(t.pyr.levels[0].data, trained.levels[0].data);
}

#[test]
fn both_photometric_losses_train_the_sample() {
    let (fit, val) = sample_views();
    let start = {
        let t = Trainer::new(cfg(2e-3, 80), &fit).unwrap();
        dnr_bake::train::run::mean_psnr(&t, &val).unwrap()
    };
    for loss in [Loss::L1, Loss::L2] {
        let mut c = cfg(2e-3, 80);
        c.loss = loss;
        let (t, _) = train_quietly(c, &fit, &val);
        let now = dnr_bake::train::run::mean_psnr(&t, &val).unwrap();
        eprintln!("{loss}: {start:.2} -> {now:.2} dB");
        assert!(
            now > start + 3.0,
            "{loss}: validation {start:.2} -> {now:.2} dB in 80 steps"
        );
    }
}

#[test]
fn a_call_that_only_loses_on_validation_hands_back_its_start() {
    let (fit, val) = sample_views();
    // A trained state, then a second call (as auto's later phases are) at a rate far too
    // high: every check of that call is worse than the state it started from.
    let (mut t, mut state) = train_quietly(cfg(2e-3, 80), &fit, &val);
    let start = dnr_bake::train::run::mean_psnr(&t, &val).unwrap();
    let checks_before = state.checks.len();
    t.cfg.steps = 160;
    t.cfg.schedule = Schedule::CONSTANT;
    t.set_learning_rates(0.5, 0.5);
    run_quietly(&mut t, &mut state, &fit, &val);
    let new_checks: Vec<f64> = state.checks[checks_before..].iter().map(|c| c.2).collect();
    eprintln!("start {start:.3} dB, this call's checks {new_checks:?}");
    assert!(
        !new_checks.is_empty() && new_checks.iter().all(|&v| v < start),
        "the scenario needs a call whose every check is worse than its start: {new_checks:?} vs {start}"
    );
    let now = dnr_bake::train::run::mean_psnr(&t, &val).unwrap();
    assert!(
        (now - start).abs() < 1e-9,
        "final {now} dB, start {start} dB"
    );
    assert_eq!(t.step, 80, "the start state (step 80) must be handed back");
}

#[test]
fn a_call_that_stops_early_hands_back_its_last_state_and_what_it_measured() {
    let (fit, val) = sample_views();
    // As above, a trained state and a call at a rate far too high, but one that stops at
    // half the run (as auto's phases before the last do): it keeps its last state, however
    // much worse, and says what that state scores.
    let (mut t, mut state) = train_quietly(cfg(2e-3, 80), &fit, &val);
    let start = dnr_bake::train::run::mean_psnr(&t, &val).unwrap();
    let known = |s: &RunState| s.current_val.expect("the call says what it handed back");
    assert!((known(&state) - start).abs() < 1e-9);
    t.cfg.steps = 200;
    t.cfg.schedule = Schedule::CONSTANT;
    t.set_learning_rates(0.5, 0.5);
    run(
        &mut t,
        &mut state,
        0.6,
        &fit,
        &val,
        &[],
        None,
        |_, _| {},
        |_| {},
    )
    .unwrap();
    assert_eq!(t.step, 120, "the call stops at 60% of 200 steps");
    let now = dnr_bake::train::run::mean_psnr(&t, &val).unwrap();
    assert!(
        now < start,
        "the scenario needs a worse state: {now} vs {start}"
    );
    assert!((known(&state) - now).abs() < 1e-9);
    // The next call, to the end, counts that state as its start (no render of its own), and
    // a state no worse than it is what the run ends with.
    let checks_before = state.checks.len();
    run_quietly(&mut t, &mut state, &fit, &val);
    let end = dnr_bake::train::run::mean_psnr(&t, &val).unwrap();
    assert!(
        end >= now - 1e-9,
        "end {end} dB, start of the last call {now} dB"
    );
    assert!((known(&state) - end).abs() < 1e-9);
    assert!(state.checks.len() > checks_before);
}

#[test]
fn the_moving_average_competes_with_the_state_and_the_best_of_both_is_kept() {
    let (fit, val) = sample_views();
    // A noisy constant rate (as above), with an average over about 10 steps.
    let mut c = cfg(3e-2, 120);
    c.schedule = Schedule::CONSTANT;
    c.ema = 0.9;
    let (mut t, state) = train_quietly(c, &fit, &val);
    eprintln!("checks {:?}\naverage {:?}", state.checks, state.ema_checks);
    assert!(
        state.ema_checks.len() >= 10,
        "the average must be checked beside the state once warm: {:?}",
        state.ema_checks
    );
    let best = state
        .checks
        .iter()
        .map(|c| c.2)
        .chain(state.ema_checks.iter().map(|c| c.1))
        .fold(f64::NEG_INFINITY, f64::max);
    let now = dnr_bake::train::run::mean_psnr(&t, &val).unwrap();
    assert!(
        (now - best).abs() < 1e-9,
        "final {now} dB, best of the state's and the average's checks {best} dB"
    );
    // Stepping on, the average is warm (restarted or not); exchanging it in changes the state, and
    // exchanging twice is the identity.
    let (ema_steps, warm) = (20, 10);
    for _ in 0..ema_steps {
        t.step(&fit).unwrap();
    }
    assert!(ema_steps >= warm + dnr_bake::train::ema::EVERY as usize);
    let before = t.checkpoint(&RunState::default());
    assert!(t.swap_ema(), "warm after {ema_steps} steps");
    let swapped = t.checkpoint(&RunState::default());
    assert!(swapped.arrays != before.arrays);
    assert!(t.swap_ema());
    let after = t.checkpoint(&RunState::default());
    assert!(before.arrays == after.arrays);
}

#[test]
fn a_decay_outside_zero_to_one_is_refused() {
    let (fit, _) = sample_views();
    for bad in [1.0, -0.1, f32::NAN] {
        let mut c = cfg(1e-3, 10);
        c.ema = bad;
        let e = Trainer::new(c, &fit).err().expect("refused");
        assert!(e.to_string().contains("moving-average decay"), "{e}");
    }
}

#[test]
fn a_batch_of_one_view_twice_steps_exactly_as_that_view_alone() {
    let (fit, _) = sample_views();
    let one = &fit[..1];
    let mut single = Trainer::new(cfg(1e-2, 10), one).unwrap();
    let mut c = cfg(1e-2, 10);
    c.batch = 2;
    let mut batched = Trainer::new(c, one).unwrap();
    for _ in 0..3 {
        let (a, b) = (single.step(one).unwrap(), batched.step(one).unwrap());
        assert_eq!(a, b, "the batch's loss is the mean of its crops'");
    }
    // Halving each crop's gradient is exact, so the two halves add up to the whole bit for
    // bit, and the dense-gradient update equals the fused one: texture, weights and moments.
    let (a, b) = (
        single.checkpoint(&RunState::default()),
        batched.checkpoint(&RunState::default()),
    );
    assert!(
        a.arrays == b.arrays,
        "a batch of two equal crops must take the same step"
    );
    // Over the whole sample, batches of three crops train.
    let mut c = cfg(1e-2, 40);
    c.batch = 3;
    let mut t = Trainer::new(c, &fit).unwrap();
    let losses: Vec<f64> = (0..40).map(|_| t.step(&fit).unwrap()).collect();
    let (early, late) = (
        losses[..10].iter().sum::<f64>(),
        losses[30..].iter().sum::<f64>(),
    );
    assert!(
        late < 0.8 * early,
        "loss {early} over the first 10 steps, {late} over the last"
    );
}

#[test]
fn texture_weight_decay_shrinks_the_finest_level_and_bad_values_are_refused() {
    let (fit, _) = sample_views();
    let sq = |t: &Trainer, k: usize| -> f64 {
        t.pyr.levels[k]
            .data
            .iter()
            .map(|&v| f64::from(v).powi(2))
            .sum()
    };
    let mut c = cfg(1e-2, 20);
    c.tex_decay = 0.0;
    let mut plain = Trainer::new(c.clone(), &fit).unwrap();
    c.tex_decay = 20.0;
    let mut decayed = Trainer::new(c, &fit).unwrap();
    let finest0 = sq(&plain, 0);
    assert_eq!(finest0, sq(&decayed, 0), "same start");
    for _ in 0..20 {
        plain.step(&fit).unwrap();
        decayed.step(&fit).unwrap();
    }
    // Each update shrinks a touched finest texel by 1 - 0.01 * 20 = 0.8 before Adam's step.
    let (p, d) = (sq(&plain, 0), sq(&decayed, 0));
    assert!(d < 0.5 * p, "finest level: {d} with decay, {p} without");
    refuses_bad_decays(&fit, "texture weight decay", |c, v| c.tex_decay = v);
}

#[test]
fn network_weight_decay_shrinks_the_weights_and_bad_values_are_refused() {
    let (fit, _) = sample_views();
    let sq = |t: &Trainer| -> f64 {
        match t.export_net() {
            dnr_bake::export::ExportNet::Unet { tensors, .. } => tensors
                .values()
                .flat_map(|(_, v)| v.iter())
                .map(|&v| f64::from(v).powi(2))
                .sum(),
            _ => panic!("the default network is a U-Net"),
        }
    };
    let mut c = cfg(1e-2, 20);
    c.net_decay = 0.0;
    let mut plain = Trainer::new(c.clone(), &fit).unwrap();
    c.net_decay = 20.0;
    let mut decayed = Trainer::new(c, &fit).unwrap();
    assert_eq!(sq(&plain), sq(&decayed), "same start");
    for _ in 0..20 {
        plain.step(&fit).unwrap();
        decayed.step(&fit).unwrap();
    }
    // Each update scales every weight by 1 - 0.01 * 20 = 0.8 before Adam's step.
    let (p, d) = (sq(&plain), sq(&decayed));
    assert!(d < 0.5 * p, "weights: {d} with decay, {p} without");
    refuses_bad_decays(&fit, "network weight decay", |c, v| c.net_decay = v);
}

/// Negative, non-finite and too-large decays are refused with an error naming them.
fn refuses_bad_decays(fit: &[View], what: &str, set: impl Fn(&mut TrainConfig, f32)) {
    for bad in [-1.0, f32::NAN, 50.0] {
        let mut c = cfg(1e-2, 10);
        set(&mut c, bad);
        let e = Trainer::new(c, fit).err().expect("refused");
        assert!(e.to_string().contains(what), "{e}");
    }
}
