//! The U-Net renderer as a training graph.
//!
//! Forward that keeps every activation backward needs, backward that accumulates the gradients of
//! all weights and returns the gradient of the input feature image. Same architecture and weight
//! names as `dnr_runtime::network::unet`.

use super::activation::{leaky_relu_backward, tanh_backward};
use super::concat::concat_backward;
use super::conv::{conv_backward, conv_forward, conv_forward_act, ConvCache};
use super::conv_transpose::{
    conv_transpose_backward_parts, conv_transpose_forward_act, TconvCache,
};
use super::norm::lrelu_instance_norm_backward;
use super::upsample::upsample_nearest2_backward;
use dnr_runtime::network::unet::{Decoder, Norm, UNetParams};
use dnr_runtime::network::{check_no_extra, fetch_tensors, map_lookup, NetworkError};
use dnr_runtime::nn::activation::{tanh, Act, LEAKY_SLOPE};
use dnr_runtime::nn::norm::{instance_norm, normalize, NormStats};
use dnr_runtime::nn::tensor::pool;
use dnr_runtime::nn::upsample::upsample_nearest2_concat;
use dnr_runtime::nn::{NnError, Tensor};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::collections::BTreeMap;

/// Cache of one up-sampling layer.
#[derive(Clone, Debug)]
enum UpCache {
    Tconv(TconvCache),
    /// Input size before the nearest upsample, and the 3x3 conv's cache.
    UpConv {
        h: usize,
        w: usize,
        conv: ConvCache,
    },
}

/// Activations of one [`UNetTrain::forward`], consumed by [`UNetTrain::backward`].
#[derive(Clone, Debug)]
pub struct UNetActs {
    /// Input size before padding.
    h: usize,
    w: usize,
    enc: Vec<ConvCache>,
    /// Normalised outputs before LeakyReLU (`z`) of encoders and decoders 1..D-1.
    enc_z: Vec<Tensor>,
    enc_stats: Vec<Option<NormStats>>,
    /// Indexed by decoder level; `None` at level 0 for z/stats.
    dec: Vec<Option<UpCache>>,
    dec_z: Vec<Option<Tensor>>,
    dec_stats: Vec<Option<NormStats>>,
    /// Network output after tanh on the padded frame.
    out: Tensor,
}

impl Drop for UNetActs {
    /// Hands every large buffer back to the runtime's pool for the next step.
    fn drop(&mut self) {
        for c in self.enc.drain(..) {
            pool::recycle(c.buf);
        }
        for c in self.dec.drain(..).flatten() {
            match c {
                UpCache::Tconv(t) => pool::recycle(t.buf),
                UpCache::UpConv { conv, .. } => pool::recycle(conv.buf),
            }
        }
        self.enc_z
            .drain(..)
            .chain(self.dec_z.drain(..).flatten())
            .for_each(Tensor::recycle);
        std::mem::replace(
            &mut self.out,
            Tensor {
                c: 0,
                h: 0,
                w: 0,
                data: Vec::new(),
            },
        )
        .recycle();
    }
}

/// U-Net weights with gradient accumulators, in [`UNetParams::tensor_specs`] order
/// (`encoder.0.weight`, `encoder.0.bias`, .., `decoder.{D-1}.bias`).
#[derive(Clone, Debug, PartialEq)]
pub struct UNetTrain {
    /// Architecture.
    pub params: UNetParams,
    /// Values of every tensor.
    pub weights: Vec<Vec<f32>>,
    /// dL/d(weights), accumulated by [`UNetTrain::backward`] until [`UNetTrain::zero_grad`].
    pub grads: Vec<Vec<f32>>,
}

impl UNetTrain {
    /// PyTorch's default initialisation: every weight and bias uniform in
    /// `±1/sqrt(fan_in)` (fan_in = `c_in k k` of the conv; for a transposed conv PyTorch uses
    /// `c_out k k` from its weight layout, which is also used here).
    pub fn init(params: UNetParams, seed: u64) -> Result<Self, NetworkError> {
        params.validate()?;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let specs = params.tensor_specs();
        let mut weights = Vec::with_capacity(specs.len());
        for pair in specs.chunks(2) {
            let s = &pair[0].1;
            let fan_in = s[1] * s[2] * s[3];
            let bound = 1.0 / (fan_in as f32).sqrt();
            for (_, shape) in pair {
                let n: usize = shape.iter().product();
                weights.push((0..n).map(|_| rng.random_range(-bound..bound)).collect());
            }
        }
        Ok(Self::with_weights(params, weights))
    }

    /// From a map of `name -> (shape, values)` (exactly the architecture's tensors).
    pub fn from_map(
        params: UNetParams,
        map: &BTreeMap<String, (Vec<usize>, Vec<f32>)>,
    ) -> Result<Self, NetworkError> {
        params.validate()?;
        let specs = params.tensor_specs();
        check_no_extra(&specs, map.keys().map(String::as_str))?;
        let weights = fetch_tensors(&specs, &map_lookup(map))?;
        Ok(Self::with_weights(params, weights))
    }

    fn with_weights(params: UNetParams, weights: Vec<Vec<f32>>) -> Self {
        let grads = weights.iter().map(|w| vec![0.0; w.len()]).collect();
        UNetTrain {
            params,
            weights,
            grads,
        }
    }

    /// `name -> (shape, values)` of every tensor (what the runtime's `UNet::from_map` takes).
    pub fn to_map(&self) -> BTreeMap<String, (Vec<usize>, Vec<f32>)> {
        self.params
            .tensor_specs()
            .into_iter()
            .zip(&self.weights)
            .map(|((n, s), w)| (n, (s, w.clone())))
            .collect()
    }

    /// Sets every gradient to zero.
    pub fn zero_grad(&mut self) {
        self.grads.iter_mut().for_each(|g| g.fill(0.0));
    }

    /// Number of scalar parameters.
    pub fn num_params(&self) -> usize {
        self.weights.iter().map(Vec::len).sum()
    }

    fn enc_w(&self, i: usize) -> (&[f32], &[f32]) {
        (&self.weights[2 * i], &self.weights[2 * i + 1])
    }

    fn dec_w(&self, i: usize) -> (&[f32], &[f32]) {
        let d = self.params.depth();
        (&self.weights[2 * (d + i)], &self.weights[2 * (d + i) + 1])
    }

    /// Instance norm in place when the architecture has it.
    fn norm(&self, y: &mut Tensor) -> Option<NormStats> {
        (self.params.norm == Norm::Instance).then(|| instance_norm(y))
    }

    /// Forward on a `in_ch x H x W` feature image: output after tanh (`out_ch x H x W`) and the
    /// activations for backward. Pads to a multiple of 2^D like the runtime; like the runtime,
    /// activations are kept before their LeakyReLU and the consumer applies it on read.
    pub fn forward(&self, x: &Tensor) -> Result<(Tensor, UNetActs), NnError> {
        let p = &self.params;
        if x.c != p.in_ch || x.h == 0 || x.w == 0 {
            return Err(NnError::Shape(format!(
                "U-Net training input {}x{}x{} for {} channels",
                x.c, x.h, x.w, p.in_ch
            )));
        }
        let d = p.depth();
        let (hp, wp) = p.padded_size(x.h, x.w);
        let lrelu = Act::LeakyRelu(LEAKY_SLOPE);
        let norm = p.norm == Norm::Instance;
        let (mut enc, mut enc_z, mut enc_stats) = (Vec::new(), Vec::<Tensor>::new(), Vec::new());
        for i in 0..d {
            let (w, b) = self.enc_w(i);
            let (src, act, size) = match enc_z.last() {
                None => (x, Act::Identity, (hp, wp)),
                Some(prev) => (prev, lrelu, (prev.h, prev.w)),
            };
            let (mut y, stats, cache) =
                conv_forward_act(src, act, size, w, b, p.encoder_geom(i), norm)?;
            if let Some(st) = &stats {
                normalize(&mut y, st);
            }
            enc.push(cache);
            enc_z.push(y);
            enc_stats.push(stats);
        }
        let mut dec: Vec<Option<UpCache>> = (0..d).map(|_| None).collect();
        let mut dec_z: Vec<Option<Tensor>> = (0..d).map(|_| None).collect();
        let mut dec_stats: Vec<Option<NormStats>> = (0..d).map(|_| None).collect();
        for i in (0..d).rev() {
            let (w, b) = self.dec_w(i);
            let (_, co) = p.decoder_channels(i);
            let cur = if i == d - 1 {
                &enc_z[d - 1]
            } else {
                dec_z[i + 1].as_ref().expect("decoder above")
            };
            let mut parts = vec![cur];
            if i < d - 1 {
                parts.push(&enc_z[i]);
            }
            let out_act = if i == 0 { Act::Tanh } else { Act::Identity };
            let (mut y, cache) = match p.decoder {
                Decoder::TransposedConv => {
                    let (y, c) = conv_transpose_forward_act(&parts, lrelu, w, b, co, out_act)?;
                    (y, UpCache::Tconv(c))
                }
                Decoder::UpsampleConv => {
                    let (h, ww) = (cur.h, cur.w);
                    let u = upsample_nearest2_concat(&parts, lrelu);
                    let (mut y, c) = conv_forward(&u, w, b, p.decoder_geom(i))?;
                    if i == 0 {
                        tanh(&mut y.data);
                    }
                    (y, UpCache::UpConv { h, w: ww, conv: c })
                }
            };
            dec[i] = Some(cache);
            if i == 0 {
                let out = y.crop_top_left(x.h, x.w);
                let acts = UNetActs {
                    h: x.h,
                    w: x.w,
                    enc,
                    enc_z,
                    enc_stats,
                    dec,
                    dec_z,
                    dec_stats,
                    out: y,
                };
                return Ok((out, acts));
            }
            dec_stats[i] = self.norm(&mut y);
            dec_z[i] = Some(y);
        }
        unreachable!("the decoder loop returns at level 0")
    }

    /// Backward from `dout` = dL/d(output after tanh) (`out_ch x H x W`). Adds to
    /// [`Self::grads`]; returns dL/d(input feature image) (`in_ch x H x W`).
    pub fn backward(&mut self, acts: &UNetActs, dout: &Tensor) -> Tensor {
        let p = self.params.clone();
        let d = p.depth();
        assert!(
            dout.c == p.out_ch && dout.h == acts.h && dout.w == acts.w,
            "U-Net backward: dout shape"
        );
        let mut g = dout.pad_bottom_right(acts.out.h, acts.out.w);
        tanh_backward(&acts.out.data, &mut g.data);
        // Gradients w.r.t. the activated encoder outputs lrelu(z_i), from skips and the chain.
        let mut de: Vec<Tensor> = acts
            .enc_z
            .iter()
            .map(|z| Tensor::zeros(z.c, z.h, z.w))
            .collect();
        for i in 0..d {
            // g = dL/d(output of up_i before norm), after the chain rule through norm and act.
            if i > 0 {
                let z = acts.dec_z[i].as_ref().expect("decoder activations");
                match &acts.dec_stats[i] {
                    Some(st) => lrelu_instance_norm_backward(z, st, LEAKY_SLOPE, &mut g),
                    None => leaky_relu_backward(&z.data, &mut g.data, LEAKY_SLOPE),
                }
            }
            let (ci, _) = p.decoder_channels(i);
            let in_hw = (g.h / 2, g.w / 2);
            let cache = acts.dec[i].as_ref().expect("decoder cache");
            if i == d - 1 {
                self.up_backward(i, cache, &g, &mut [&mut de[d - 1]]);
            } else {
                // The input was concat(a_(i+1), e_i): decoder part first, then the skip.
                let mut da = Tensor::zeros(ci - p.widths[i], in_hw.0, in_hw.1);
                self.up_backward(i, cache, &g, &mut [&mut da, &mut de[i]]);
                std::mem::replace(&mut g, da).recycle();
            }
        }
        let mut dinput = Tensor::zeros(p.in_ch, acts.out.h, acts.out.w);
        for i in (0..d).rev() {
            let mut gi = std::mem::replace(&mut de[i], Tensor::zeros(0, 0, 0));
            match &acts.enc_stats[i] {
                Some(st) => lrelu_instance_norm_backward(&acts.enc_z[i], st, LEAKY_SLOPE, &mut gi),
                None => leaky_relu_backward(&acts.enc_z[i].data, &mut gi.data, LEAKY_SLOPE),
            }
            let (wi, bi) = (2 * i, 2 * i + 1);
            let (gw, gb) = two_mut(&mut self.grads, wi, bi);
            let target = if i == 0 { &mut dinput } else { &mut de[i - 1] };
            conv_backward(&acts.enc[i], &self.weights[wi], &gi, gw, gb, Some(target));
            gi.recycle();
        }
        g.recycle();
        if (acts.h, acts.w) == (dinput.h, dinput.w) {
            return dinput;
        }
        let out = dinput.crop_top_left(acts.h, acts.w);
        dinput.recycle();
        out
    }

    /// Backward of up-sampling layer `i` from `g`, adding its input gradient to `dx_parts`
    /// (the parts its input was concatenated from, in order).
    fn up_backward(&mut self, i: usize, cache: &UpCache, g: &Tensor, dx_parts: &mut [&mut Tensor]) {
        let d = self.params.depth();
        let (wi, bi) = (2 * (d + i), 2 * (d + i) + 1);
        let w = &self.weights[wi];
        let (gw, gb) = two_mut(&mut self.grads, wi, bi);
        match cache {
            UpCache::Tconv(c) => conv_transpose_backward_parts(c, w, g, gw, gb, dx_parts),
            UpCache::UpConv { h, w: ww, conv } => {
                let ci: usize = dx_parts.iter().map(|p| p.c).sum();
                let mut du = Tensor::zeros(ci, 2 * h, 2 * ww);
                conv_backward(conv, w, g, gw, gb, Some(&mut du));
                let mut dx = Tensor::zeros(ci, *h, *ww);
                upsample_nearest2_backward(&du, &mut dx);
                du.recycle();
                match dx_parts {
                    [a] => a.data.iter_mut().zip(&dx.data).for_each(|(a, b)| *a += b),
                    [a, b] => concat_backward(&dx, a, b),
                    _ => unreachable!("a decoder input has one or two parts"),
                }
                dx.recycle();
            }
        }
    }
}

/// Two distinct elements of a vector, mutably (`a < b`).
fn two_mut(v: &mut [Vec<f32>], a: usize, b: usize) -> (&mut [f32], &mut [f32]) {
    assert!(a < b);
    let (lo, hi) = v.split_at_mut(b);
    (&mut lo[a], &mut hi[0])
}
