//! Joint optimisation of the neural texture and the renderer (the paper's Section 5): random
//! crops (or whole frames), L1 photometric loss, mean-colour loss on channels 0..2, per-level
//! L2 regularisation, Adam. One step reads top to bottom in [`Trainer::step`].

pub mod checkpoint;
pub mod config;
pub mod init;
pub mod views;

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use dnr_runtime::network::unet::{Decoder, Norm, UNet, UNetParams};
use dnr_runtime::nn::Tensor;
use dnr_runtime::texture::{sample_into, Pyramid, Wrap};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use crate::eval::metrics::{view_error, Rgba, ViewError};
use crate::export::ExportNet;
use crate::kernels::adam::{Adam, AdamConfig, SparseAdam};
use crate::kernels::loss::{colour_l1_loss, l1_loss, level_lambda};
use crate::kernels::unet::UNetTrain;
use config::{Arch, TrainConfig};
use views::View;

/// SH layer of the paper: degree 2 (9 values) on channels 3..11.
pub const SH_DEGREE: u32 = 2;
/// First channel the SH basis multiplies.
pub const SH_FIRST: u32 = 3;

/// Why a configuration cannot be trained.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    /// Inconsistent or out-of-range settings.
    #[error("invalid configuration: {0}")]
    Config(String),
    /// No training view covers any object pixel.
    #[error("no training view shows the proxy mesh: check the poses and the mesh")]
    NothingVisible,
    /// A kernel refused its input.
    #[error("{0}")]
    Kernel(String),
    /// Writing or reading a checkpoint failed.
    #[error(transparent)]
    Checkpoint(#[from] checkpoint::CheckpointError),
    /// Stopped by the user (Ctrl-C) after writing a checkpoint.
    #[error("interrupted at step {step}; checkpoint written to {path}: run again with --resume")]
    Interrupted {
        /// Steps done.
        step: u64,
        /// The checkpoint.
        path: String,
    },
}

/// One timed record of the report.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct Record {
    /// Optimisation steps done.
    pub step: u64,
    /// Training seconds (evaluation excluded).
    pub seconds: f64,
    /// Mean photometric L1 over the steps since the last record.
    pub train_loss: f64,
    /// Mean held-out PSNR (dB), full frame on white.
    pub test_psnr: f64,
    /// Mean held-out MSE on [0,255] over object pixels.
    pub test_mse: f64,
}

/// The renderer being trained.
enum Net {
    None,
    Unet { net: UNetTrain, adam: Vec<Adam> },
}

/// Training state: texture, network, optimiser moments, random stream.
pub struct Trainer {
    /// Resolved configuration.
    pub cfg: TrainConfig,
    /// The neural texture being optimised.
    pub pyr: Pyramid,
    /// Output channels of the renderer (4 when it predicts alpha).
    pub out_ch: usize,
    net: Net,
    tex_adam: Vec<SparseAdam>,
    tex_grads: Vec<Vec<f32>>,
    rng: ChaCha8Rng,
    /// Steps taken.
    pub step: u64,
    loss_sum: f64,
    loss_n: u64,
}

fn unet_params(cfg: &TrainConfig, out_ch: usize) -> UNetParams {
    UNetParams {
        in_ch: cfg.channels as usize,
        out_ch,
        widths: cfg.widths.iter().map(|&w| w as usize).collect(),
        decoder: Decoder::TransposedConv,
        norm: Norm::Instance,
    }
}

impl Trainer {
    /// Starts from the classical texture (see [`init`]) and a seeded network.
    pub fn new(cfg: TrainConfig, train: &[View]) -> Result<Trainer, TrainError> {
        let c = cfg.channels as usize;
        if cfg.sh && c < (SH_FIRST + (SH_DEGREE + 1).pow(2)) as usize {
            return Err(TrainError::Config(format!(
                "{c} channels: the SH layer needs at least 12 (or --no-sh)"
            )));
        }
        if c < 3
            || cfg.levels == 0
            || cfg.resolution == 0
            || cfg.resolution >> (cfg.levels - 1) == 0
        {
            return Err(TrainError::Config(format!(
                "{c} channels, {} levels at {}: need >= 3 channels and a coarsest level of >= 1 texel",
                cfg.levels, cfg.resolution
            )));
        }
        if !train.iter().any(|v| v.gbuf.covered_count() > 0) {
            return Err(TrainError::NothingVisible);
        }
        let has_alpha = train.iter().any(|v| v.has_alpha);
        let out_ch = if cfg.alpha && has_alpha && cfg.arch == Arch::Unet {
            4
        } else {
            3
        };
        let wrap = if uvs_in_unit_square(train) {
            Wrap::ClampToEdge
        } else {
            Wrap::Repeat
        };
        let (pyr, _seen, _stats) = init::classical_pyramid(
            train,
            c,
            cfg.resolution as usize,
            cfg.levels as usize,
            wrap,
            0.01,
            cfg.seed,
        );
        let tex_cfg = AdamConfig {
            lr: cfg.lr_tex,
            ..AdamConfig::default()
        };
        let tex_adam = pyr
            .levels
            .iter()
            .map(|l| SparseAdam::new(l.width * l.height, c, tex_cfg))
            .collect();
        let tex_grads = pyr.levels.iter().map(|l| vec![0.0; l.data.len()]).collect();
        let net = match cfg.arch {
            Arch::None => Net::None,
            Arch::Unet => {
                let net = UNetTrain::init(unet_params(&cfg, out_ch), cfg.seed ^ 0x5eed)
                    .map_err(|e| TrainError::Config(e.to_string()))?;
                let ncfg = AdamConfig {
                    lr: cfg.lr_net,
                    ..AdamConfig::default()
                };
                let adam = net
                    .weights
                    .iter()
                    .map(|w| Adam::new(w.len(), ncfg))
                    .collect();
                Net::Unet { net, adam }
            }
            Arch::Mlp => {
                return Err(TrainError::Config(
                    "training the mlp architecture is not implemented yet".into(),
                ))
            }
        };
        Ok(Trainer {
            rng: ChaCha8Rng::seed_from_u64(cfg.seed),
            cfg,
            pyr,
            out_ch,
            net,
            tex_adam,
            tex_grads,
            step: 0,
            loss_sum: 0.0,
            loss_n: 0,
        })
    }

    fn sh(&self) -> Option<(u32, u32)> {
        self.cfg.sh.then_some((SH_DEGREE, SH_FIRST))
    }

    /// Picks a training view and a crop of it that shows object pixels.
    fn sample_crop(&mut self, views: &[View]) -> View {
        for _ in 0..16 {
            let v = &views[self.rng.random_range(0..views.len())];
            let (w, h) = (v.width(), v.height());
            let cs = self.cfg.crop as usize;
            if cs == 0 || (cs >= w && cs >= h) {
                if v.gbuf.covered_count() > 0 {
                    return v.clone();
                }
                continue;
            }
            let (cw, ch) = (cs.min(w), cs.min(h));
            let x0 = self.rng.random_range(0..=w - cw);
            let y0 = self.rng.random_range(0..=h - ch);
            let c = v.crop(x0, y0, cw, ch);
            if c.gbuf.covered_count() > 0 {
                return c;
            }
        }
        views
            .iter()
            .find(|v| v.gbuf.covered_count() > 0)
            .expect("checked in new")
            .clone()
    }

    /// The feature image of a view: sampled pyramid (C x H x W), before and after SH.
    fn features(&self, v: &View) -> Result<(Tensor, Tensor), TrainError> {
        let c = self.pyr.channels;
        let mut raw = Tensor::zeros(c, v.height(), v.width());
        sample_into(&self.pyr, &v.gbuf, &mut raw.data)
            .map_err(|e| TrainError::Kernel(e.to_string()))?;
        let mut x = raw.clone();
        if let Some((deg, first)) = self.sh() {
            dnr_runtime::sh::modulate(
                &mut x.data,
                &v.gbuf.view_dir,
                &v.gbuf.coverage,
                first as usize,
                deg,
            )
            .map_err(|e| TrainError::Kernel(e.to_string()))?;
        }
        Ok((raw, x))
    }

    /// One optimisation step on one crop; returns the photometric L1.
    pub fn step(&mut self, views: &[View]) -> Result<f64, TrainError> {
        let v = self.sample_crop(views);
        let (h, w) = (v.height(), v.width());
        let n = h * w;
        let (raw, x) = self.features(&v)?;
        let target = Tensor::from_vec(3, h, w, v.target.clone())
            .map_err(|e| TrainError::Kernel(e.to_string()))?;

        // Forward to straight colour and alpha, then composite on white as the target is.
        let (colour, alpha, acts) = match &self.net {
            Net::None => {
                let colour: Vec<f32> = x.data[..3 * n].iter().map(|&t| t.clamp(0.0, 1.0)).collect();
                (colour, v.gbuf.coverage.clone(), None)
            }
            Net::Unet { net, .. } => {
                let (y, acts) = net
                    .forward(&x)
                    .map_err(|e| TrainError::Kernel(e.to_string()))?;
                let colour: Vec<f32> = y.data[..3 * n].iter().map(|&t| 0.5 * (t + 1.0)).collect();
                let alpha = if self.out_ch == 4 {
                    y.data[3 * n..4 * n]
                        .iter()
                        .map(|&t| 0.5 * (t + 1.0))
                        .collect()
                } else {
                    v.gbuf.coverage.clone()
                };
                (colour, alpha, Some((y, acts)))
            }
        };
        let mut comp = Tensor::zeros(3, h, w);
        for c in 0..3 {
            for i in 0..n {
                comp.data[c * n + i] = colour[c * n + i] * alpha[i] + (1.0 - alpha[i]);
            }
        }
        let mut dcomp = Tensor::zeros(3, h, w);
        let loss = l1_loss(&comp, &target, None, 1.0, &mut dcomp);
        let mut dalpha = vec![0.0f32; n];
        if self.out_ch == 4 {
            let pa = Tensor::from_vec(1, h, w, alpha.clone())
                .map_err(|e| TrainError::Kernel(e.to_string()))?;
            let ta = Tensor::from_vec(1, h, w, v.alpha.clone())
                .map_err(|e| TrainError::Kernel(e.to_string()))?;
            let mut da = Tensor::zeros(1, h, w);
            l1_loss(&pa, &ta, None, 1.0, &mut da);
            dalpha = da.data;
        }

        // Backward to the feature image.
        let mut dx = Tensor::zeros(self.pyr.channels, h, w);
        match (&mut self.net, acts) {
            (Net::None, _) => {
                // colour = clamp(x): gradient only where x is inside [0, 1].
                for ((d, &x), (&g, &a)) in dx.data[..3 * n]
                    .iter_mut()
                    .zip(&x.data[..3 * n])
                    .zip(dcomp.data.iter().zip(alpha.iter().cycle()))
                {
                    if (0.0..=1.0).contains(&x) {
                        *d = g * a;
                    }
                }
            }
            (Net::Unet { net, .. }, Some((y, acts))) => {
                // comp = colour * a + (1 - a), colour = (t + 1) / 2, a = (t3 + 1) / 2.
                let mut dy = Tensor::zeros(self.out_ch, h, w);
                let (dcol, dal) = dy.data.split_at_mut(3 * n);
                for (c, (dcol_c, dcomp_c)) in
                    dcol.chunks_mut(n).zip(dcomp.data.chunks(n)).enumerate()
                {
                    let col_c = &colour[c * n..(c + 1) * n];
                    for (i, (d, &g)) in dcol_c.iter_mut().zip(dcomp_c).enumerate() {
                        *d = 0.5 * g * alpha[i];
                        dalpha[i] += g * (col_c[i] - 1.0);
                    }
                }
                if self.out_ch == 4 {
                    for (d, &g) in dal.iter_mut().zip(&dalpha) {
                        *d = 0.5 * g;
                    }
                }
                let _ = y;
                net.zero_grad();
                dx = net.backward(&acts, &dy);
            }
            (Net::Unet { .. }, None) => unreachable!("U-Net forward always keeps activations"),
        }
        // SH modulation is linear and diagonal: its backward is itself.
        if let Some((deg, first)) = self.sh() {
            dnr_runtime::sh::modulate(
                &mut dx.data,
                &v.gbuf.view_dir,
                &v.gbuf.coverage,
                first as usize,
                deg,
            )
            .map_err(|e| TrainError::Kernel(e.to_string()))?;
        }
        // Mean-colour supervision of channels 0..2 over covered object pixels.
        if self.cfg.mean_colour_weight > 0.0 && self.cfg.arch != Arch::None {
            let covered: Vec<bool> = (0..n)
                .map(|i| v.gbuf.coverage[i] > 0.0 && v.alpha[i] > 0.5)
                .collect();
            colour_l1_loss(
                &raw,
                &target,
                &covered,
                self.cfg.mean_colour_weight,
                &mut dx,
            );
        }

        // Texture: scatter into the levels, then lazy Adam on the touched texels only.
        let touched = crate::kernels::sample::sample_backward(
            &self.pyr,
            &v.gbuf,
            &dx.data,
            &mut self.tex_grads,
        )
        .map_err(|e| TrainError::Kernel(e.to_string()))?;
        let k_total = self.pyr.levels.len();
        for (k, lvl) in self.pyr.levels.iter_mut().enumerate() {
            let decay = 2.0 * level_lambda(self.cfg.reg, k, k_total) / lvl.data.len() as f32;
            self.tex_adam[k].step(&mut lvl.data, &mut self.tex_grads[k], &touched[k], decay);
        }
        if let Net::Unet { net, adam } = &mut self.net {
            for ((wt, g), a) in net.weights.iter_mut().zip(&net.grads).zip(adam.iter_mut()) {
                a.step(wt, g);
            }
        }
        self.step += 1;
        self.loss_sum += loss;
        self.loss_n += 1;
        Ok(loss)
    }

    /// Mean training loss since the last call.
    pub fn take_loss(&mut self) -> f64 {
        let l = if self.loss_n > 0 {
            self.loss_sum / self.loss_n as f64
        } else {
            f64::NAN
        };
        self.loss_sum = 0.0;
        self.loss_n = 0;
        l
    }

    /// The renderer in the form the exporter and the runtime take.
    pub fn export_net(&self) -> ExportNet {
        match &self.net {
            Net::None => ExportNet::None,
            Net::Unet { net, .. } => ExportNet::Unet {
                params: net.params.clone(),
                tensors: net.to_map(),
            },
        }
    }

    /// SH layer as `(degree, first_channel)`, if trained with one.
    pub fn sh_layer(&self) -> Option<(u32, u32)> {
        self.sh()
    }

    /// Renders whole views with the runtime's forward (f32 weights) and measures them.
    pub fn evaluate(&self, views: &[View]) -> Result<Vec<ViewError>, TrainError> {
        let unet = match &self.net {
            Net::Unet { net, .. } => Some(
                UNet::from_map(net.params.clone(), &net.to_map())
                    .map_err(|e| TrainError::Kernel(e.to_string()))?,
            ),
            Net::None => None,
        };
        let mut out = Vec::with_capacity(views.len());
        for v in views {
            let (h, w) = (v.height(), v.width());
            let n = h * w;
            let (_, x) = self.features(v)?;
            let (colour, alpha): (Vec<f32>, Vec<f32>) = match &unet {
                None => (
                    x.data[..3 * n].iter().map(|t| t.clamp(0.0, 1.0)).collect(),
                    v.gbuf.coverage.clone(),
                ),
                Some(net) => {
                    let y = net
                        .forward(&x)
                        .map_err(|e| TrainError::Kernel(e.to_string()))?;
                    let col = y.data[..3 * n].iter().map(|&t| 0.5 * (t + 1.0)).collect();
                    let a = if self.out_ch == 4 {
                        y.data[3 * n..].iter().map(|&t| 0.5 * (t + 1.0)).collect()
                    } else {
                        v.gbuf.coverage.clone()
                    };
                    (col, a)
                }
            };
            let mut render = vec![0.0f32; 4 * n];
            let mut truth = vec![0.0f32; 4 * n];
            for i in 0..n {
                for c in 0..3 {
                    render[4 * i + c] = colour[c * n + i];
                    // The target is already on white; alpha 1 keeps it as is.
                    truth[4 * i + c] = v.target[c * n + i];
                }
                render[4 * i + 3] = alpha[i];
                truth[4 * i + 3] = 1.0;
            }
            // Object pixels come from the capture's mask, so measure them with it.
            let mut e = view_error(
                &Rgba {
                    width: w,
                    height: h,
                    data: &render,
                },
                &Rgba {
                    width: w,
                    height: h,
                    data: &truth,
                },
            );
            let (mut se, mut cnt) = (0.0f64, 0usize);
            let r8 = crate::eval::metrics::on_white_u8(&Rgba {
                width: w,
                height: h,
                data: &render,
            });
            let t8 = crate::eval::metrics::on_white_u8(&Rgba {
                width: w,
                height: h,
                data: &truth,
            });
            for i in 0..n {
                if v.alpha[i] > 0.5 {
                    for c in 0..3 {
                        let d = r8[3 * i + c] as f64 - t8[3 * i + c] as f64;
                        se += d * d;
                    }
                    cnt += 1;
                }
            }
            e.mse_obj = if cnt > 0 { se / (3 * cnt) as f64 } else { 0.0 };
            e.obj_pixels = cnt;
            out.push(e);
        }
        Ok(out)
    }
}

impl Trainer {
    /// The whole training state (with the run's progress) as a checkpoint.
    pub fn checkpoint(&self, state: &RunState) -> checkpoint::Checkpoint {
        let mut c = checkpoint::Checkpoint {
            header: checkpoint::Header {
                config: serde_json::to_value(&self.cfg).unwrap_or_default(),
                step: self.step,
                train_secs: state.train_secs,
                next_eval: state.next_eval,
                records: serde_json::to_value(&state.records).unwrap_or_default(),
                rng_seed: self.rng.get_seed(),
                rng_word_pos: self.rng.get_word_pos(),
                loss_sum: self.loss_sum,
                loss_n: self.loss_n,
                arrays: Vec::new(),
                adam_steps: Vec::new(),
            },
            arrays: Vec::new(),
        };
        for (k, l) in self.pyr.levels.iter().enumerate() {
            c.push(&format!("texture.{k}"), &l.data);
            c.push_adam(&format!("texture.{k}.adam"), &self.tex_adam[k].state());
        }
        if let Net::Unet { net, adam } = &self.net {
            for (i, (w, a)) in net.weights.iter().zip(adam).enumerate() {
                c.push(&format!("net.{i}"), w);
                c.push_adam(&format!("net.{i}.adam"), &a.state());
            }
        }
        c
    }

    /// Restores a checkpoint written by [`Trainer::checkpoint`] for the same configuration.
    pub fn restore(
        &mut self,
        c: &checkpoint::Checkpoint,
        path: &Path,
    ) -> Result<RunState, TrainError> {
        let bad = |what: String| checkpoint::CheckpointError::Corrupt {
            path: path.to_path_buf(),
            what,
        };
        let mut want = serde_json::to_value(&self.cfg).unwrap_or_default();
        let mut have = c.header.config.clone();
        // The budget may be raised on resume; everything else must match.
        for v in [&mut want, &mut have] {
            if let Some(o) = v.as_object_mut() {
                o.remove("timeBudget");
            }
        }
        if want != have {
            return Err(bad(format!("written for another configuration: {have}")).into());
        }
        for (k, l) in self.pyr.levels.iter_mut().enumerate() {
            let name = format!("texture.{k}");
            let a = c
                .array(&name)
                .filter(|a| a.len() == l.data.len())
                .ok_or_else(|| bad(name.clone()))?;
            l.data.copy_from_slice(a);
            let st = c
                .adam(&format!("{name}.adam"))
                .ok_or_else(|| bad(format!("{name}.adam")))?;
            if !self.tex_adam[k].set_state(st) {
                return Err(bad(format!("{name}.adam size")).into());
            }
        }
        if let Net::Unet { net, adam } = &mut self.net {
            for (i, (w, a)) in net.weights.iter_mut().zip(adam.iter_mut()).enumerate() {
                let name = format!("net.{i}");
                let v = c
                    .array(&name)
                    .filter(|v| v.len() == w.len())
                    .ok_or_else(|| bad(name.clone()))?;
                w.copy_from_slice(v);
                let st = c
                    .adam(&format!("{name}.adam"))
                    .ok_or_else(|| bad(format!("{name}.adam")))?;
                if !a.set_state(st) {
                    return Err(bad(format!("{name}.adam size")).into());
                }
            }
        }
        self.rng = ChaCha8Rng::from_seed(c.header.rng_seed);
        self.rng.set_word_pos(c.header.rng_word_pos);
        self.step = c.header.step;
        self.loss_sum = c.header.loss_sum;
        self.loss_n = c.header.loss_n;
        let records =
            serde_json::from_value(c.header.records.clone()).map_err(|e| bad(e.to_string()))?;
        Ok(RunState {
            train_secs: c.header.train_secs,
            next_eval: c.header.next_eval,
            records,
        })
    }
}

fn uvs_in_unit_square(views: &[View]) -> bool {
    views.iter().all(|v| {
        v.gbuf.uv.iter().zip(&v.gbuf.coverage).all(|(uv, &c)| {
            c == 0.0 || (-1e-3..=1.001).contains(&uv[0]) && (-1e-3..=1.001).contains(&uv[1])
        })
    })
}

/// Progress of a run that a checkpoint carries besides the trainer.
#[derive(Clone, Debug, Default)]
pub struct RunState {
    /// Training seconds (evaluation excluded).
    pub train_secs: f64,
    /// Training second of the next evaluation.
    pub next_eval: f64,
    /// Records so far.
    pub records: Vec<Record>,
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

/// Trains until the step limit or the time budget, evaluating every `eval_every` seconds
/// and checkpointing as asked. `on_step` and `on_record` drive the progress display.
pub fn run(
    trainer: &mut Trainer,
    state: &mut RunState,
    train: &[View],
    test: &[View],
    ckpt: Option<&Checkpointing>,
    mut on_step: impl FnMut(&Trainer, f64),
    mut on_record: impl FnMut(&Record),
) -> Result<(), TrainError> {
    if state.next_eval <= 0.0 {
        state.next_eval = trainer.cfg.eval_every;
    }
    let budget = trainer.cfg.time_budget;
    let mut last_ckpt = Instant::now();
    while trainer.step < trainer.cfg.steps && (budget <= 0.0 || state.train_secs < budget) {
        let t0 = Instant::now();
        trainer.step(train)?;
        state.train_secs += t0.elapsed().as_secs_f64();
        on_step(trainer, state.train_secs);
        if trainer.cfg.eval_every > 0.0 && state.train_secs >= state.next_eval && !test.is_empty() {
            state.next_eval += trainer.cfg.eval_every;
            let rec = record(trainer, test, state.train_secs)?;
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
    if !test.is_empty()
        && state
            .records
            .last()
            .is_none_or(|r: &Record| r.step != trainer.step)
    {
        let rec = record(trainer, test, state.train_secs)?;
        on_record(&rec);
        state.records.push(rec);
    }
    Ok(())
}

fn record(trainer: &mut Trainer, test: &[View], seconds: f64) -> Result<Record, TrainError> {
    let errs = trainer.evaluate(test)?;
    let k = errs.len().max(1) as f64;
    Ok(Record {
        step: trainer.step,
        seconds,
        train_loss: trainer.take_loss(),
        test_psnr: errs.iter().map(|e| e.psnr).sum::<f64>() / k,
        test_mse: errs.iter().map(|e| e.mse_obj).sum::<f64>() / k,
    })
}
