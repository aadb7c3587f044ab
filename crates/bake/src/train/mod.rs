//! Joint optimisation of the neural texture and the renderer (the paper's Section 5): random
//! crops (or whole frames), a photometric loss (the paper's L1, or squared error), mean-colour
//! loss on channels 0..2, per-level L2 regularisation, Adam. One step reads top to bottom in [`Trainer::step`].

pub mod checkpoint;
pub mod config;
pub mod ema;
pub mod init;
pub mod photometric;
pub mod quantise;
pub mod run;
pub mod schedule;
pub mod views;

pub use photometric::{photometric_l1, photometric_loss, Loss};
pub use run::{run, Checkpointing, Recovery, RunState, MAX_RECOVERIES, PSNR_COLLAPSE_DB};

use std::borrow::Cow;
use std::path::Path;
use std::time::Instant;

use dnr_runtime::gbuffer::GBuffer;
use dnr_runtime::network::mlp::{Mlp, MlpParams};
use dnr_runtime::network::unet::{Decoder, Norm, UNet, UNetParams};
use dnr_runtime::nn::awake::with_workers_awake;
use dnr_runtime::nn::Tensor;
use dnr_runtime::supersample::{box_mean, box_mean_adjoint};
use dnr_runtime::texture::{sample_into, Pyramid, Wrap};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use crate::eval::metrics::{view_error_masked, Rgba, ViewError};
use crate::export::ExportNet;
use crate::kernels::adam::{Adam, AdamConfig, SparseAdam};
use crate::kernels::loss::{colour_l1_loss_where, l1_loss, level_lambda};
use crate::kernels::mlp::MlpTrain;
use crate::kernels::sample::{
    sample_backward, sample_backward_adam, sample_forward_taps, ViewTaps,
};
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
    /// Training diverged again and again although each recovery rolled back and halved the
    /// learning rates.
    #[error(
        "training diverged {recoveries} times (last at step {step}: {reason}); try a lower --lr"
    )]
    Diverged {
        /// Recoveries tried.
        recoveries: usize,
        /// Step of the last divergence.
        step: u64,
        /// What was seen.
        reason: String,
    },
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
    #[serde(deserialize_with = "f64_or_nan")]
    pub seconds: f64,
    /// Mean photometric L1 over the steps since the last record.
    #[serde(deserialize_with = "f64_or_nan")]
    pub train_loss: f64,
    /// Mean held-out PSNR (dB), full frame on white.
    #[serde(deserialize_with = "f64_or_nan")]
    pub test_psnr: f64,
    /// Mean held-out MSE on [0, 255] over object pixels.
    #[serde(deserialize_with = "f64_or_nan")]
    pub test_mse: f64,
    /// Mean PSNR (dB) of the validation views (training views held out of training), the
    /// figure best-state selection reads; NaN without validation views.
    #[serde(default = "nan", deserialize_with = "f64_or_nan")]
    pub val_psnr: f64,
    /// Learning-rate factor of the schedule at this record.
    #[serde(default = "one")]
    pub lr_factor: f64,
}

fn nan() -> f64 {
    f64::NAN
}

/// Reads a number, or `null` as NaN: serde_json writes NaN (a figure not measured) as
/// `null`, so saved reports and tables read back as they were.
pub fn f64_or_nan<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(<Option<f64> as serde::Deserialize>::deserialize(d)?.unwrap_or(f64::NAN))
}

fn one() -> f64 {
    1.0
}

/// The renderer being trained.
enum Net {
    None,
    Unet { net: UNetTrain, adam: Vec<Adam> },
    Mlp { net: MlpTrain, adam: Vec<Adam> },
}

impl Net {
    /// One Adam step of every weight tensor on its gradient, which it then clears.
    fn adam_step(&mut self) {
        if let Some((weights, grads, adam)) = self.params_mut() {
            for ((wt, g), a) in weights
                .iter_mut()
                .zip(grads.iter_mut())
                .zip(adam.iter_mut())
            {
                a.step_zero_grad(wt, g);
            }
        }
    }

    /// The network's tensors, their gradients and their optimisers (none for `None`), in the
    /// architecture's `tensor_specs` order (also the checkpoint's `net.{i}` order).
    #[allow(clippy::type_complexity)]
    fn params_mut(&mut self) -> Option<(&mut [Vec<f32>], &mut [Vec<f32>], &mut [Adam])> {
        match self {
            Net::None => None,
            Net::Unet { net, adam } => Some((&mut net.weights, &mut net.grads, adam)),
            Net::Mlp { net, adam } => Some((&mut net.weights, &mut net.grads, adam)),
        }
    }

    /// The network's tensors and optimisers, read-only.
    fn params(&self) -> Option<(&[Vec<f32>], &[Adam])> {
        match self {
            Net::None => None,
            Net::Unet { net, adam } => Some((&net.weights, adam)),
            Net::Mlp { net, adam } => Some((&net.weights, adam)),
        }
    }
}

/// Refuses a decoupled weight decay (of `what`: "texture" or "network") that is negative, not
/// finite, or so large that `lr * decay` reaches a half: at 1 or above it would flip a
/// parameter's sign each update, below a half it keeps shrinking it.
fn check_decay(what: &str, decay: f32, lr: f32) -> Result<(), TrainError> {
    if decay.is_finite() && decay >= 0.0 && decay * lr.max(0.0) < 0.5 {
        return Ok(());
    }
    Err(TrainError::Config(format!(
        "{what} weight decay {decay}: must be at least 0 (off) and below 0.5 / the {what} learning rate ({lr})"
    )))
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
    rng: ChaCha8Rng,
    /// Steps taken.
    pub step: u64,
    loss_sum: f64,
    loss_n: u64,
    /// Channels pruned by `--preset auto`: held at zero in every level after each step.
    zero_channels: Vec<usize>,
    /// The schedule's factor on the configuration's learning rates (what the optimisers use
    /// is `cfg.lr_* * lr_scale`).
    lr_scale: f32,
    /// Seconds spent in each phase of [`Trainer::step`] since construction.
    pub phase_seconds: PhaseSeconds,
    /// Quantisation-aware fine-tuning: the storage the forward pass imitates, when active.
    qat: Option<quantise::QatTarget>,
    /// The levels' fits the training steps round with, and the steps since they were fitted.
    qat_fits: Option<(quantise::LevelFits, u32)>,
    /// The weights' scales during fine-tuning, refitted like the levels' ranges.
    qat_weight_fits: Option<(Vec<quantise::TensorFit>, u32)>,
    /// The moving average of the texture and the weights (see [`ema`]), restarted whenever
    /// the state changes other than by a step.
    ema: Option<ema::Ema>,
    /// The texture gradients a batched step gathers (one per level, all zero between steps;
    /// empty until the first batched step).
    batch_grads: Vec<Vec<f32>>,
}

/// Wall seconds of the phases of [`Trainer::step`], summed over steps (what `dnr bench train`
/// breaks the whole step into).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct PhaseSeconds {
    /// Crop selection, texture sampling (with the taps backward reuses) and SH.
    pub features: f64,
    /// Renderer forward and the photometric loss.
    pub forward: f64,
    /// Renderer backward to the feature image.
    pub backward: f64,
    /// SH backward and mean-colour loss on the feature image's gradient.
    pub feature_grads: f64,
    /// Texture scatter with its sparse Adam, and Adam on the renderer's weights, side by
    /// side (and pruned channels held at zero).
    pub updates: f64,
}

impl PhaseSeconds {
    /// Sum of the phases.
    pub fn total(&self) -> f64 {
        self.features + self.forward + self.backward + self.feature_grads + self.updates
    }
}

/// Adds the seconds since `*t` to `acc` and restarts `*t`.
/// The weights rounded for a fine-tuning step: scales refitted every
/// [`quantise::REFIT_EVERY`] steps and reused in between (fitting int4's scales reads every
/// weight fifteen times, several times a step's own cost on the balanced U-Net).
fn step_weights(
    cache: &mut Option<(Vec<quantise::TensorFit>, u32)>,
    specs: &[(String, Vec<usize>)],
    weights: &[Vec<f32>],
    target: &quantise::QatTarget,
) -> Vec<Vec<f32>> {
    let (fits, age) = match cache.take() {
        Some((fits, age)) if age < quantise::REFIT_EVERY && fits.len() == weights.len() => {
            (fits, age)
        }
        _ => (quantise::fit_weights(specs, weights, target), 0),
    };
    let out = quantise::quantised_weights_with(weights, &fits);
    *cache = Some((fits, age + 1));
    out
}

fn lap(t: &mut Instant, acc: &mut f64) {
    let now = Instant::now();
    *acc += (now - *t).as_secs_f64();
    *t = now;
}

fn mlp_params(cfg: &TrainConfig, out_ch: usize) -> MlpParams {
    MlpParams {
        in_ch: cfg.channels as usize,
        hidden: cfg.widths.iter().map(|&w| w as usize).collect(),
        out_ch,
    }
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
        if cfg.sh && cfg.sh_degree > dnr_runtime::sh::MAX_DEGREE {
            return Err(TrainError::Config(format!(
                "SH degree {}: the extension defines degrees 0 to {}",
                cfg.sh_degree,
                dnr_runtime::sh::MAX_DEGREE
            )));
        }
        let sh_end =
            (SH_FIRST + (cfg.sh_degree.min(dnr_runtime::sh::MAX_DEGREE) + 1).pow(2)) as usize;
        if cfg.sh && c < sh_end {
            return Err(TrainError::Config(format!(
                "{c} channels: the degree-{} SH layer needs at least {sh_end} (or --no-sh)",
                cfg.sh_degree
            )));
        }
        check_decay("texture", cfg.tex_decay, cfg.lr_tex)?;
        check_decay("network", cfg.net_decay, cfg.lr_net)?;
        if !(0.0..1.0).contains(&cfg.ema) {
            return Err(TrainError::Config(format!(
                "moving-average decay {}: must be at least 0 (off) and below 1",
                cfg.ema
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
        // Views prepared with subsamples also train at one sample per pixel (auto times
        // both); the other way round they cannot.
        if let Some(v) = train
            .iter()
            .find(|v| cfg.supersample > 1 && v.supersample() != cfg.supersample as usize)
        {
            return Err(TrainError::Config(format!(
                "view {} has {} subsamples per pixel side, the configuration {}",
                v.name,
                v.supersample(),
                cfg.supersample
            )));
        }
        let has_alpha = train.iter().any(|v| v.has_alpha);
        let out_ch = if cfg.alpha && has_alpha && cfg.arch != Arch::None {
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
        let ncfg = AdamConfig {
            lr: cfg.lr_net,
            weight_decay: cfg.net_decay,
            ..AdamConfig::default()
        };
        let adams = |ws: &[Vec<f32>]| ws.iter().map(|w| Adam::new(w.len(), ncfg)).collect();
        let net = match cfg.arch {
            Arch::None => Net::None,
            Arch::Unet => {
                let net = UNetTrain::init(unet_params(&cfg, out_ch), cfg.seed ^ 0x5eed)
                    .map_err(|e| TrainError::Config(e.to_string()))?;
                let adam = adams(&net.weights);
                Net::Unet { net, adam }
            }
            Arch::Mlp => {
                let net = MlpTrain::init(mlp_params(&cfg, out_ch), cfg.seed ^ 0x5eed)
                    .map_err(|e| TrainError::Config(e.to_string()))?;
                let adam = adams(&net.weights);
                Net::Mlp { net, adam }
            }
        };
        let mut tr = Trainer {
            rng: ChaCha8Rng::seed_from_u64(cfg.seed),
            cfg,
            pyr,
            out_ch,
            net,
            tex_adam,
            step: 0,
            loss_sum: 0.0,
            loss_n: 0,
            zero_channels: Vec::new(),
            lr_scale: 1.0,
            phase_seconds: PhaseSeconds::default(),
            qat: None,
            qat_fits: None,
            qat_weight_fits: None,
            ema: None,
            batch_grads: Vec::new(),
        };
        tr.apply_tex_decay();
        Ok(tr)
    }

    /// The texture levels' and the network's tensors, in the moving average's order.
    fn param_slices(&self) -> Vec<&[f32]> {
        let mut v: Vec<&[f32]> = self.pyr.levels.iter().map(|l| &l.data[..]).collect();
        if let Some((weights, _)) = self.net.params() {
            v.extend(weights.iter().map(|w| &w[..]));
        }
        v
    }

    /// Folds the state into the moving average every [`ema::EVERY`] steps (when on).
    fn ema_after_step(&mut self) {
        let decay = self.cfg.ema;
        if decay <= 0.0 || !self.step.is_multiple_of(ema::EVERY) {
            return;
        }
        let mut avg = self.ema.take();
        let cur = self.param_slices();
        match &mut avg {
            Some(a) if a.fits(&cur) => a.update(&cur, decay.powi(ema::EVERY as i32)),
            _ => avg = Some(ema::Ema::start(&cur)),
        }
        self.ema = avg;
    }

    /// Whether [`Trainer::swap_ema`] would exchange the state with its average now.
    pub fn ema_ready(&self) -> bool {
        self.ema
            .as_ref()
            .is_some_and(|a| a.fits(&self.param_slices()) && a.warm(self.cfg.ema))
    }

    /// Exchanges the state with its moving average, when one has run for at least its time
    /// constant; calling it again exchanges them back. Returns whether it exchanged.
    pub fn swap_ema(&mut self) -> bool {
        let ok = self.ema_ready();
        let Some(mut avg) = self.ema.take() else {
            return false;
        };
        if ok {
            let mut t = avg.tensors.iter_mut();
            for l in &mut self.pyr.levels {
                if let Some(a) = t.next() {
                    std::mem::swap(&mut l.data, a);
                }
            }
            if let Some((weights, _, _)) = self.net.params_mut() {
                for w in weights.iter_mut() {
                    if let Some(a) = t.next() {
                        std::mem::swap(w, a);
                    }
                }
            }
        }
        self.ema = Some(avg);
        ok
    }

    /// Starts (or, with `None`, stops) quantisation-aware fine-tuning: from now on steps and
    /// evaluations read the texture and the weights rounded as `target` stores them, and
    /// gradients update the full-precision values (straight-through).
    pub fn set_qat(&mut self, target: Option<quantise::QatTarget>) {
        self.qat = target.filter(|t| !t.is_identity());
        self.qat_fits = None;
        self.qat_weight_fits = None;
        self.ema = None;
    }

    /// The storage quantisation-aware fine-tuning imitates, if active.
    pub fn qat(&self) -> Option<&quantise::QatTarget> {
        self.qat.as_ref()
    }

    /// The texture as the forward pass reads it: rounded as stored during fine-tuning, with
    /// ranges fitted now (evaluations).
    fn forward_pyramid(&self) -> Cow<'_, Pyramid> {
        match &self.qat {
            Some(q) if q.level_bits.iter().any(Option::is_some) => {
                Cow::Owned(quantise::quantised_pyramid(&self.pyr, &q.level_bits))
            }
            _ => Cow::Borrowed(&self.pyr),
        }
    }

    /// [`Self::forward_pyramid`] for a training step: the ranges are refitted every
    /// [`quantise::REFIT_EVERY`] steps and reused in between.
    fn step_pyramid(&mut self) -> Cow<'_, Pyramid> {
        let bits = match &self.qat {
            Some(q) if q.level_bits.iter().any(Option::is_some) => &q.level_bits,
            _ => return Cow::Borrowed(&self.pyr),
        };
        let (fits, age) = match self.qat_fits.take() {
            Some((fits, age)) if age < quantise::REFIT_EVERY => (fits, age),
            _ => (quantise::fit_levels(&self.pyr, bits), 0),
        };
        let out = quantise::quantised_pyramid_with(&self.pyr, &fits);
        self.qat_fits = Some((fits, age + 1));
        Cow::Owned(out)
    }

    /// What the forward pass rounds the weights to, when it rounds any.
    fn qat_weights(&self) -> Option<quantise::QatTarget> {
        self.qat.clone().filter(quantise::QatTarget::rounds_weights)
    }

    /// `name -> (shape, values)` of the network's tensors as the forward pass reads them.
    fn forward_map(
        &self,
        map: std::collections::BTreeMap<String, (Vec<usize>, Vec<f32>)>,
    ) -> std::collections::BTreeMap<String, (Vec<usize>, Vec<f32>)> {
        let Some(target) = self.qat_weights() else {
            return map;
        };
        map.into_iter()
            .map(|(k, (shape, mut data))| {
                if let Some(d) = target.weight_dtype(&k) {
                    quantise::fake_int(&shape, &mut data, &d);
                }
                (k, (shape, data))
            })
            .collect()
    }

    /// Removes pyramid level `k` (and its optimiser state): the renderer then sees the sum of
    /// the other levels. Used by pruning; the regularisation follows the new level indices.
    pub fn remove_level(&mut self, k: usize) {
        if k < self.pyr.levels.len() && self.pyr.levels.len() > 1 {
            self.pyr.levels.remove(k);
            self.tex_adam.remove(k);
            self.ema = None;
            self.apply_tex_decay();
        }
    }

    /// Sets each level's decoupled weight decay from `tex_decay` by its index (see
    /// [`TrainConfig::tex_decay`]).
    fn apply_tex_decay(&mut self) {
        let k_total = self.tex_adam.len();
        for (k, a) in self.tex_adam.iter_mut().enumerate() {
            a.cfg.weight_decay = if k_total > 1 {
                self.cfg.tex_decay * (k_total - 1 - k) as f32 / (k_total - 1) as f32
            } else {
                0.0
            };
        }
    }

    /// Holds `channels` at zero in every level from now on (zeroed now and after each step),
    /// so an export can drop them without changing a pixel.
    pub fn freeze_zero_channels(&mut self, channels: &[usize]) {
        for &c in channels {
            if c < self.pyr.channels && !self.zero_channels.contains(&c) {
                self.zero_channels.push(c);
            }
        }
        self.zero_frozen();
        self.ema = None;
    }

    /// Channels held at zero.
    pub fn zero_channels(&self) -> &[usize] {
        &self.zero_channels
    }

    fn zero_frozen(&mut self) {
        if self.zero_channels.is_empty() {
            return;
        }
        let c = self.pyr.channels;
        for l in &mut self.pyr.levels {
            for texel in l.data.chunks_exact_mut(c) {
                for &z in &self.zero_channels {
                    texel[z] = 0.0;
                }
            }
        }
    }

    /// Sets every channel of the texels no training pixel touches (`touched[k][texel]` false)
    /// to zero. Training never updates them (the texture optimiser is sparse), so they stay
    /// zero and compress to almost nothing.
    pub fn zero_untouched(&mut self, touched: &[Vec<bool>]) -> usize {
        let c = self.pyr.channels;
        let mut zeroed = 0;
        for (l, t) in self.pyr.levels.iter_mut().zip(touched) {
            for (texel, &seen) in l.data.chunks_exact_mut(c).zip(t) {
                if !seen {
                    texel.fill(0.0);
                    zeroed += 1;
                }
            }
        }
        self.ema = None;
        zeroed
    }

    fn sh(&self) -> Option<(u32, u32)> {
        self.cfg.sh.then_some((self.cfg.sh_degree, SH_FIRST))
    }

    /// Picks a training view and a crop of it that shows object pixels (a whole frame is
    /// borrowed, not copied).
    fn sample_crop<'v>(&mut self, views: &'v [View]) -> Cow<'v, View> {
        for _ in 0..16 {
            let v = &views[self.rng.random_range(0..views.len())];
            let (w, h) = (v.width(), v.height());
            let cs = self.cfg.crop as usize;
            if cs == 0 || (cs >= w && cs >= h) {
                if v.gbuf.covered_count() > 0 {
                    return Cow::Borrowed(v);
                }
                continue;
            }
            let (cw, ch) = (cs.min(w), cs.min(h));
            let x0 = self.rng.random_range(0..=w - cw);
            let y0 = self.rng.random_range(0..=h - ch);
            let c = v.crop(x0, y0, cw, ch, self.cfg.supersample > 1);
            if c.gbuf.covered_count() > 0 {
                return Cow::Owned(c);
            }
        }
        Cow::Borrowed(
            views
                .iter()
                .find(|v| v.gbuf.covered_count() > 0)
                .expect("checked in new"),
        )
    }

    /// The feature image of a view from `pyr` (the trainer's, or its rounding during
    /// fine-tuning): the sampled pyramid (C x H x W) after SH. SH never touches channels 0..2
    /// (`SH_FIRST >= 3`), so those are still the raw features the mean-colour loss supervises.
    ///
    /// A supersampled view's features are sampled and modulated at its subsamples, then
    /// box-averaged to pixels by the runtime's [`box_mean`].
    fn features_of(&self, pyr: &Pyramid, v: &View) -> Result<Tensor, TrainError> {
        let (g, _) = self.feature_gbuf(v);
        // sample_into writes every value.
        let mut x = Tensor::scratch(pyr.channels, g.height, g.width);
        sample_into(pyr, g, &mut x.data).map_err(|e| TrainError::Kernel(e.to_string()))?;
        self.sh_modulate(g, &mut x.data)?;
        self.to_pixels(v, x)
    }

    /// The pixel feature image of a view from its feature G-buffer's image: the box mean of
    /// the subsamples, or `x` itself at one sample per pixel.
    fn to_pixels(&self, v: &View, x: Tensor) -> Result<Tensor, TrainError> {
        let (_, s) = self.feature_gbuf(v);
        if s == 1 {
            return Ok(x);
        }
        let mut y = Tensor::scratch(x.c, v.height(), v.width());
        box_mean(&x.data, x.c, v.width(), v.height(), s, &mut y.data)
            .map_err(|e| TrainError::Kernel(e.to_string()))?;
        x.recycle();
        Ok(y)
    }

    /// The G-buffer a view's features are sampled at and its subsamples per pixel side: the
    /// subsamples' when this trainer supersamples, else the pixels'.
    fn feature_gbuf<'v>(&self, v: &'v View) -> (&'v GBuffer, usize) {
        match &v.fine {
            Some(f) if self.cfg.supersample > 1 => (f, v.supersample()),
            _ => (&v.gbuf, 1),
        }
    }

    /// Multiplies the SH channels of a `C x H x W` image by the basis of a G-buffer's
    /// directions (the SH layer's forward, and, being linear and diagonal, its backward).
    fn sh_modulate(&self, g: &GBuffer, data: &mut [f32]) -> Result<(), TrainError> {
        if let Some((deg, first)) = self.sh() {
            dnr_runtime::sh::modulate(data, &g.view_dir, &g.coverage, first as usize, deg)
                .map_err(|e| TrainError::Kernel(e.to_string()))?;
        }
        Ok(())
    }

    /// One optimisation step on one crop; returns the photometric L1 (whatever the loss).
    ///
    /// The network's gradients are zero between steps (the fused Adam step clears them),
    /// and large buffers go back to the runtime's tensor pool, so a step allocates little.
    pub fn step(&mut self, views: &[View]) -> Result<f64, TrainError> {
        // On a worker of the pool: the step's many small parallel kernels are then forked
        // from a worker (the others steal) instead of injected from outside, where the caller
        // sleeps and is woken at every one; and the other workers poll between kernels
        // instead of sleeping.
        with_workers_awake(|| self.step_in_pool(views))
    }

    fn step_in_pool(&mut self, views: &[View]) -> Result<f64, TrainError> {
        let batch = self.cfg.batch.max(1) as usize;
        if batch > 1 {
            return self.batch_step(views, batch);
        }
        let v = self.sample_crop(views);
        let (loss, dx, taps) = self.crop_gradient(&v, 1.0)?;
        let mut t = Instant::now();
        let mut ph = self.phase_seconds;

        // Texture: scatter into the levels fused with lazy Adam on the touched texels only.
        let decay = self.level_decay();
        // The texture's and the network's updates are independent: side by side (the texel
        // scatter waits on memory, the dense Adam streams it).
        let (pyr, tex_adam, net) = (&mut self.pyr, &mut self.tex_adam, &mut self.net);
        let (tex, ()) = rayon::join(
            || sample_backward_adam(&taps, pyr, &dx.data, tex_adam, &decay),
            || net.adam_step(),
        );
        tex.map_err(|e| TrainError::Kernel(e.to_string()))?;
        dx.recycle();
        self.zero_frozen();
        lap(&mut t, &mut ph.updates);
        self.phase_seconds = ph;
        Ok(self.count_step(loss))
    }

    /// Counts a finished step with its loss and folds the state into the moving average.
    fn count_step(&mut self, loss: f64) -> f64 {
        self.step += 1;
        self.loss_sum += loss;
        self.loss_n += 1;
        self.ema_after_step();
        loss
    }

    /// One step on `batch` crops of random views: their network gradients add up
    /// (each crop's loss weighs `1 / batch`), their texture gradients gather in full-size
    /// buffers, and one Adam step then updates the weights and every texel any crop touched.
    fn batch_step(&mut self, views: &[View], batch: usize) -> Result<f64, TrainError> {
        let scale = 1.0 / batch as f32;
        let mut grads = std::mem::take(&mut self.batch_grads);
        if grads.len() != self.pyr.levels.len()
            || grads
                .iter()
                .zip(&self.pyr.levels)
                .any(|(g, l)| g.len() != l.data.len())
        {
            grads = self
                .pyr
                .levels
                .iter()
                .map(|l| vec![0.0; l.data.len()])
                .collect();
        }
        let mut touched: Vec<Vec<u32>> = vec![Vec::new(); grads.len()];
        let mut loss = 0.0;
        for _ in 0..batch {
            let v = self.sample_crop(views);
            let (l, dx, _taps) = self.crop_gradient(&v, scale)?;
            let t = Instant::now();
            loss += l / batch as f64;
            let (fg, _) = self.feature_gbuf(&v);
            let hit = sample_backward(&self.pyr, fg, &dx.data, &mut grads)
                .map_err(|e| TrainError::Kernel(e.to_string()))?;
            for (all, new) in touched.iter_mut().zip(hit) {
                *all = merge_sorted(all, &new);
            }
            dx.recycle();
            self.phase_seconds.updates += t.elapsed().as_secs_f64();
        }
        let t = Instant::now();
        let decay = self.level_decay();
        for (k, ((lvl, adam), g)) in self
            .pyr
            .levels
            .iter_mut()
            .zip(self.tex_adam.iter_mut())
            .zip(grads.iter_mut())
            .enumerate()
        {
            // Clears the touched rows of the gradient: the buffers are all zero again.
            adam.step(&mut lvl.data, g, &touched[k], decay[k]);
        }
        self.batch_grads = grads;
        self.net.adam_step();
        self.zero_frozen();
        self.phase_seconds.updates += t.elapsed().as_secs_f64();
        Ok(self.count_step(loss))
    }

    /// Per-level L2 factor of the texel updates: the paper's growing regularisation of the
    /// finer levels, per texel.
    fn level_decay(&self) -> Vec<f32> {
        let k_total = self.pyr.levels.len();
        self.pyr
            .levels
            .iter()
            .enumerate()
            .map(|(k, lvl)| 2.0 * level_lambda(self.cfg.reg, k, k_total) / lvl.data.len() as f32)
            .collect()
    }

    /// Forward and backward of one crop, with its loss weighed by `scale`: the photometric
    /// L1, the gradient with respect to the feature G-buffer's samples (after SH's backward;
    /// the network's gradients are added to its own buffers), and the texture taps.
    fn crop_gradient(
        &mut self,
        v: &View,
        scale: f32,
    ) -> Result<(f64, Tensor, ViewTaps), TrainError> {
        let mut t = Instant::now();
        let mut ph = self.phase_seconds;
        let (h, w) = (v.height(), v.width());
        let n = h * w;
        // The features (what `features_of` computes, bit for bit), keeping the taps for the
        // texture's backward. SH leaves channels 0..2 alone, so after it `x` still holds the
        // raw colour features the mean-colour loss supervises.
        const _: () = assert!(
            SH_FIRST >= 3,
            "the colour loss reads channels 0..2 after SH"
        );
        let (fg, s) = self.feature_gbuf(v);
        let mut xf = Tensor::scratch(self.pyr.channels, fg.height, fg.width);
        // During fine-tuning the taps read the rounded texture; their positions and weights,
        // all the backward uses, are those of the full-precision one (straight-through).
        let taps = sample_forward_taps(&self.step_pyramid(), fg, &mut xf.data)
            .map_err(|e| TrainError::Kernel(e.to_string()))?;
        self.sh_modulate(fg, &mut xf.data)?;
        let x = self.to_pixels(v, xf)?;
        lap(&mut t, &mut ph.features);

        // Forward to straight colour and alpha, composite on white as the target is, L1, and
        // backward to the feature image. During fine-tuning with int8 weights the network
        // runs on the rounded weights and their gradients update the full-precision ones.
        let rounding = self.qat_weights();
        let (loss, mut dx) = match &mut self.net {
            Net::None => {
                let colour: Vec<f32> = x.data[..3 * n].iter().map(|&t| t.clamp(0.0, 1.0)).collect();
                let alpha = &v.gbuf.coverage;
                let mut comp = Tensor::zeros(3, h, w);
                for c in 0..3 {
                    for i in 0..n {
                        comp.data[c * n + i] = colour[c * n + i] * alpha[i] + (1.0 - alpha[i]);
                    }
                }
                let target = Tensor::from_vec(3, h, w, v.target.clone())
                    .map_err(|e| TrainError::Kernel(e.to_string()))?;
                let mut dcomp = Tensor::zeros(3, h, w);
                // Invalid pixels (masked out, outside the photograph) weigh nothing.
                let weight: Option<Vec<f32>> = v
                    .valid
                    .as_ref()
                    .map(|m| m.iter().map(|&b| if b { 1.0 } else { 0.0 }).collect());
                let loss = l1_loss(&comp, &target, weight.as_deref(), scale, &mut dcomp);
                lap(&mut t, &mut ph.forward);
                // colour = clamp(x): gradient only where x is inside [0, 1].
                let mut dx = Tensor::zeros(self.pyr.channels, h, w);
                for ((d, &x), (&g, &a)) in dx.data[..3 * n]
                    .iter_mut()
                    .zip(&x.data[..3 * n])
                    .zip(dcomp.data.iter().zip(alpha.iter().cycle()))
                {
                    if (0.0..=1.0).contains(&x) {
                        *d = g * a;
                    }
                }
                (loss, dx)
            }
            Net::Unet { net, .. } => {
                let full = rounding.as_ref().map(|target| {
                    let specs = net.params.tensor_specs();
                    let q = step_weights(&mut self.qat_weight_fits, &specs, &net.weights, target);
                    std::mem::replace(&mut net.weights, q)
                });
                let fwd = net.forward(&x);
                let out = fwd.map(|(y, acts)| {
                    let mut dy = Tensor::zeros(self.out_ch, h, w);
                    let loss =
                        photometric_loss(&y.data, v, self.out_ch, self.cfg.loss, &mut dy.data);
                    scale_in_place(&mut dy.data, scale);
                    y.recycle();
                    lap(&mut t, &mut ph.forward);
                    let dx = net.backward(&acts, &dy);
                    dy.recycle();
                    (loss, dx)
                });
                if let Some(full) = full {
                    net.weights = full;
                }
                out.map_err(|e| TrainError::Kernel(e.to_string()))?
            }
            Net::Mlp { net, .. } => {
                // Covered pixels only; the others are colour 0, alpha 0 (y = -1), constants.
                let covered: Vec<bool> = v.gbuf.coverage.iter().map(|&c| c != 0.0).collect();
                let full = rounding.as_ref().map(|target| {
                    let specs = net.params.tensor_specs();
                    let q = step_weights(&mut self.qat_weight_fits, &specs, &net.weights, target);
                    std::mem::replace(&mut net.weights, q)
                });
                let fwd = net.forward_frame(&x, &covered);
                let out = fwd.map(|(y, acts)| {
                    let mut dy = Tensor::zeros(self.out_ch, h, w);
                    let loss =
                        photometric_loss(&y.data, v, self.out_ch, self.cfg.loss, &mut dy.data);
                    scale_in_place(&mut dy.data, scale);
                    y.recycle();
                    lap(&mut t, &mut ph.forward);
                    let dx = net.backward_frame(&acts, &dy);
                    dy.recycle();
                    (loss, dx)
                });
                if let Some(full) = full {
                    net.weights = full;
                }
                out.map_err(|e| TrainError::Kernel(e.to_string()))?
            }
        };
        lap(&mut t, &mut ph.backward);
        // Mean-colour supervision of channels 0..2 over covered object pixels (SH leaves
        // them alone, so this commutes with its backward).
        if self.cfg.mean_colour_weight > 0.0 && self.cfg.arch != Arch::None {
            colour_l1_loss_where(
                &x,
                &v.target,
                |i| v.gbuf.coverage[i] > 0.0 && v.alpha[i] > 0.5 && v.is_valid(i),
                self.cfg.mean_colour_weight * scale,
                &mut dx,
            );
        }
        x.recycle();
        // Back to the subsamples: the box mean's adjoint.
        if s > 1 {
            let mut dxf = Tensor::scratch(dx.c, fg.height, fg.width);
            box_mean_adjoint(&dx.data, dx.c, w, h, s, &mut dxf.data)
                .map_err(|e| TrainError::Kernel(e.to_string()))?;
            dx.recycle();
            dx = dxf;
        }
        // SH modulation is linear and diagonal: its backward is itself.
        self.sh_modulate(fg, &mut dx.data)?;
        lap(&mut t, &mut ph.feature_grads);
        self.phase_seconds = ph;
        Ok((loss, dx, taps))
    }

    /// Sets the base texture and network learning rates (the configuration's; the
    /// optimisers take them times the schedule's current factor).
    pub fn set_learning_rates(&mut self, lr_net: f32, lr_tex: f32) {
        self.cfg.lr_net = lr_net;
        self.cfg.lr_tex = lr_tex;
        self.apply_learning_rates();
    }

    /// Sets the schedule's factor on the base learning rates.
    pub fn set_lr_scale(&mut self, scale: f32) {
        if scale != self.lr_scale {
            self.lr_scale = scale;
            self.apply_learning_rates();
        }
    }

    /// The schedule's current factor on the base learning rates.
    pub fn lr_scale(&self) -> f32 {
        self.lr_scale
    }

    fn apply_learning_rates(&mut self) {
        let (lr_net, lr_tex) = (
            self.cfg.lr_net * self.lr_scale,
            self.cfg.lr_tex * self.lr_scale,
        );
        self.tex_adam.iter_mut().for_each(|a| a.cfg.lr = lr_tex);
        self.apply_tex_decay();
        if let Some((_, _, adam)) = self.net.params_mut() {
            adam.iter_mut().for_each(|a| a.cfg.lr = lr_net);
        }
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
            Net::Mlp { net, .. } => ExportNet::Mlp {
                hidden: net.params.hidden.clone(),
                out_ch: net.params.out_ch,
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
        self.evaluate_as(views, false)
    }

    /// Renders whole views as a texture-only asset would (channels 0..2 as the colour, the
    /// proxy's coverage as alpha), whatever the network: right after [`Trainer::new`] this is
    /// the classical texture's error.
    pub fn evaluate_texture_only(&self, views: &[View]) -> Result<Vec<ViewError>, TrainError> {
        self.evaluate_as(views, true)
    }

    fn evaluate_as(
        &self,
        views: &[View],
        texture_only: bool,
    ) -> Result<Vec<ViewError>, TrainError> {
        let kerr = |e: &dyn std::fmt::Display| TrainError::Kernel(e.to_string());
        let runtime = match &self.net {
            _ if texture_only => EvalNet::None,
            Net::Unet { net, .. } => EvalNet::Unet(
                UNet::from_map(net.params.clone(), &self.forward_map(net.to_map()))
                    .map_err(|e| kerr(&e))?,
            ),
            Net::Mlp { net, .. } => EvalNet::Mlp(
                Mlp::from_map(net.params.clone(), &self.forward_map(net.to_map()))
                    .map_err(|e| kerr(&e))?,
            ),
            Net::None => EvalNet::None,
        };
        let pyr = self.forward_pyramid();
        let mut out = Vec::with_capacity(views.len());
        for v in views {
            let (h, w) = (v.height(), v.width());
            let n = h * w;
            let x = self.features_of(&pyr, v)?;
            let (colour, alpha): (Vec<f32>, Vec<f32>) = match &runtime {
                EvalNet::None => (
                    x.data[..3 * n].iter().map(|t| t.clamp(0.0, 1.0)).collect(),
                    v.gbuf.coverage.clone(),
                ),
                EvalNet::Mlp(net) => {
                    let covered: Vec<bool> = v.gbuf.coverage.iter().map(|&c| c != 0.0).collect();
                    let y = net.forward(&x, &covered).map_err(|e| kerr(&e))?;
                    // Unevaluated pixels are colour 0, alpha 0, as the runtime draws them.
                    let unit = |k: usize, i: usize| {
                        if covered[i] {
                            0.5 * (y.data[k * n + i] + 1.0)
                        } else {
                            0.0
                        }
                    };
                    let col = (0..3 * n).map(|j| unit(j / n, j % n)).collect();
                    let a = if self.out_ch == 4 {
                        (0..n).map(|i| unit(3, i)).collect()
                    } else {
                        v.gbuf.coverage.clone()
                    };
                    (col, a)
                }
                EvalNet::Unet(net) => {
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
            // Object pixels come from the capture's mask, so measure them with it; invalid
            // pixels do not count.
            let mut e = view_error_masked(
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
                v.valid.as_deref(),
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
                if v.alpha[i] > 0.5 && v.is_valid(i) {
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
                next_check: state.next_check,
                records: serde_json::to_value(&state.records).unwrap_or_default(),
                rng_seed: self.rng.get_seed(),
                rng_word_pos: self.rng.get_word_pos(),
                loss_sum: self.loss_sum,
                loss_n: self.loss_n,
                arrays: Vec::new(),
                adam_steps: Vec::new(),
                recoveries: serde_json::to_value(&state.recoveries).unwrap_or_default(),
            },
            arrays: Vec::new(),
        };
        for (k, l) in self.pyr.levels.iter().enumerate() {
            c.push(&format!("texture.{k}"), &l.data);
            c.push_adam(&format!("texture.{k}.adam"), &self.tex_adam[k].state());
        }
        if let Some((weights, adam)) = self.net.params() {
            for (i, (w, a)) in weights.iter().zip(adam).enumerate() {
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
        // The budget may be raised on resume, and recoveries lower the learning rates (the
        // checkpoint's win); everything else must match.
        let lr = |v: &serde_json::Value, key: &str| v.get(key).and_then(|x| x.as_f64());
        let (lr_net, lr_tex) = (lr(&have, "lrNet"), lr(&have, "lrTex"));
        for v in [&mut want, &mut have] {
            if let Some(o) = v.as_object_mut() {
                for key in ["timeBudget", "lrNet", "lrTex"] {
                    o.remove(key);
                }
            }
        }
        if want != have {
            return Err(bad(format!("written for another configuration: {have}")).into());
        }
        match (lr_net, lr_tex) {
            (Some(n), Some(t)) if n.is_finite() && t.is_finite() && n > 0.0 && t > 0.0 => {
                self.set_learning_rates(n as f32, t as f32);
            }
            _ => return Err(bad("learning rates".into()).into()),
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
        if let Some((weights, _, adam)) = self.net.params_mut() {
            for (i, (w, a)) in weights.iter_mut().zip(adam.iter_mut()).enumerate() {
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
        self.ema = None;
        self.step = c.header.step;
        self.loss_sum = c.header.loss_sum;
        self.loss_n = c.header.loss_n;
        let records =
            serde_json::from_value(c.header.records.clone()).map_err(|e| bad(e.to_string()))?;
        let recoveries = if c.header.recoveries.is_null() {
            Vec::new()
        } else {
            serde_json::from_value(c.header.recoveries.clone()).map_err(|e| bad(e.to_string()))?
        };
        Ok(RunState {
            train_secs: c.header.train_secs,
            next_eval: c.header.next_eval,
            next_check: c.header.next_check,
            records,
            recoveries,
            ..RunState::default()
        })
    }
}

/// The runtime's network for [`Trainer::evaluate`].
enum EvalNet {
    None,
    Mlp(Mlp),
    Unet(UNet),
}

/// Multiplies every value by `s` (a crop's share of a batched step's loss).
fn scale_in_place(x: &mut [f32], s: f32) {
    if s != 1.0 {
        x.iter_mut().for_each(|v| *v *= s);
    }
}

/// The ascending union of two ascending lists without duplicates.
fn merge_sorted(a: &[u32], b: &[u32]) -> Vec<u32> {
    let mut out = Vec::with_capacity(a.len() + b.len());
    let (mut i, mut j) = (0, 0);
    while i < a.len() && j < b.len() {
        let (x, y) = (a[i], b[j]);
        out.push(x.min(y));
        i += usize::from(x <= y);
        j += usize::from(y <= x);
    }
    out.extend_from_slice(&a[i..]);
    out.extend_from_slice(&b[j..]);
    out
}

fn uvs_in_unit_square(views: &[View]) -> bool {
    views.iter().all(|v| {
        v.gbuf.uv.iter().zip(&v.gbuf.coverage).all(|(uv, &c)| {
            c == 0.0 || (-1e-3..=1.001).contains(&uv[0]) && (-1e-3..=1.001).contains(&uv[1])
        })
    })
}
