//! The per-pixel MLP renderer as a training graph.
//!
//! Weights with gradient accumulators, and a frame-level forward/backward that evaluates covered
//! pixels only (background gets no network work). Same architecture, weight names and forward
//! arithmetic as `dnr_runtime::network::mlp`, so what is trained is what the runtime draws.

use super::dense::{mlp_backward, mlp_forward, MlpActs};
use dnr_runtime::network::mlp::MlpParams;
use dnr_runtime::network::{check_no_extra, fetch_tensors, map_lookup, NetworkError};
use dnr_runtime::nn::{NnError, Tensor};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::collections::BTreeMap;

/// Activations of one [`MlpTrain::forward_frame`], consumed by [`MlpTrain::backward_frame`].
#[derive(Clone, Debug)]
pub struct MlpFrameActs {
    /// Frame size.
    h: usize,
    w: usize,
    /// The evaluated (covered) pixels, ascending.
    idx: Vec<usize>,
    /// Per-layer activations of the packed pixels.
    acts: MlpActs,
}

/// MLP weights with gradient accumulators, in [`MlpParams::tensor_specs`] order
/// (`layers.0.weight`, `layers.0.bias`, `layers.1.weight`, ..).
#[derive(Clone, Debug, PartialEq)]
pub struct MlpTrain {
    /// Architecture.
    pub params: MlpParams,
    /// Values of every tensor.
    pub weights: Vec<Vec<f32>>,
    /// dL/d(weights), accumulated by the backward passes until [`MlpTrain::zero_grad`].
    pub grads: Vec<Vec<f32>>,
}

fn validate(p: &MlpParams) -> Result<(), NetworkError> {
    if p.in_ch == 0 || p.out_ch == 0 || p.hidden.contains(&0) {
        return Err(NetworkError::Params("MLP widths must be positive".into()));
    }
    Ok(())
}

impl MlpTrain {
    /// PyTorch's `nn.Linear` default initialisation (Kaiming-uniform with `a = sqrt(5)`):
    /// every weight and bias of a layer uniform in `±1/sqrt(fan_in)`, deterministic from `seed`.
    pub fn init(params: MlpParams, seed: u64) -> Result<Self, NetworkError> {
        validate(&params)?;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut weights = Vec::new();
        for (ci, co) in params.layer_dims() {
            let bound = 1.0 / (ci as f32).sqrt();
            for n in [co * ci, co] {
                weights.push((0..n).map(|_| rng.random_range(-bound..bound)).collect());
            }
        }
        Ok(Self::with_weights(params, weights))
    }

    /// From a map of `name -> (shape, values)` (exactly the architecture's tensors).
    pub fn from_map(
        params: MlpParams,
        map: &BTreeMap<String, (Vec<usize>, Vec<f32>)>,
    ) -> Result<Self, NetworkError> {
        validate(&params)?;
        let specs = params.tensor_specs();
        check_no_extra(&specs, map.keys().map(String::as_str))?;
        let weights = fetch_tensors(&specs, &map_lookup(map))?;
        Ok(Self::with_weights(params, weights))
    }

    fn with_weights(params: MlpParams, weights: Vec<Vec<f32>>) -> Self {
        let grads = weights.iter().map(|w| vec![0.0; w.len()]).collect();
        MlpTrain {
            params,
            weights,
            grads,
        }
    }

    /// `name -> (shape, values)` of every tensor (what the runtime's `Mlp::from_map` and the
    /// exporter take).
    pub fn to_map(&self) -> BTreeMap<String, (Vec<usize>, Vec<f32>)> {
        self.params
            .tensor_specs()
            .into_iter()
            .zip(&self.weights)
            .map(|((name, shape), w)| (name, (shape, w.clone())))
            .collect()
    }

    /// Clears the gradient accumulators.
    pub fn zero_grad(&mut self) {
        self.grads.iter_mut().for_each(|g| g.fill(0.0));
    }

    /// Number of parameters.
    pub fn num_params(&self) -> usize {
        self.weights.iter().map(Vec::len).sum()
    }

    fn layers(&self) -> Vec<(&[f32], &[f32])> {
        self.weights
            .chunks_exact(2)
            .map(|p| (p[0].as_slice(), p[1].as_slice()))
            .collect()
    }

    /// Forward of `pixels` feature vectors stored planar (`in_ch x pixels`), keeping what
    /// backward needs; `acts.out` is the output after tanh (`out_ch x pixels`).
    pub fn forward_pixels(&self, x: &[f32], pixels: usize) -> Result<MlpActs, NnError> {
        mlp_forward(&self.layers(), &self.params.layer_dims(), x, pixels)
    }

    /// Backward of [`MlpTrain::forward_pixels`]: `dout` is dL/d(output after tanh). Adds to
    /// the gradients; returns dL/dx (`in_ch x pixels`).
    pub fn backward_pixels(&mut self, acts: &MlpActs, dout: &[f32]) -> Vec<f32> {
        let dims = self.params.layer_dims();
        let layers: Vec<(&[f32], &[f32])> = self
            .weights
            .chunks_exact(2)
            .map(|p| (p[0].as_slice(), p[1].as_slice()))
            .collect();
        let mut grads: Vec<(&mut [f32], &mut [f32])> = self
            .grads
            .chunks_exact_mut(2)
            .map(|p| {
                let (w, b) = p.split_at_mut(1);
                (w[0].as_mut_slice(), b[0].as_mut_slice())
            })
            .collect();
        mlp_backward(&layers, &dims, acts, dout, &mut grads)
    }

    /// Frame forward: the MLP on the pixels of `x` (`in_ch x h x w`) where `covered` is true.
    /// Returns the `out_ch x h x w` output after tanh with `-1` at the other pixels (colour 0
    /// and alpha 0 after `(t + 1) / 2`, what the runtime draws there), and the activations.
    pub fn forward_frame(
        &self,
        x: &Tensor,
        covered: &[bool],
    ) -> Result<(Tensor, MlpFrameActs), NnError> {
        let n = x.plane_len();
        if x.c != self.params.in_ch || covered.len() != n {
            return Err(NnError::Shape(format!(
                "MLP expects {} channels and {n} coverage flags, got {} and {}",
                self.params.in_ch,
                x.c,
                covered.len()
            )));
        }
        let idx: Vec<usize> = (0..n).filter(|&i| covered[i]).collect();
        let m = idx.len();
        let mut packed = Vec::with_capacity(x.c * m);
        for c in 0..x.c {
            let plane = x.plane(c);
            packed.extend(idx.iter().map(|&i| plane[i]));
        }
        let acts = self.forward_pixels(&packed, m)?;
        let out_ch = self.params.out_ch;
        let mut y = Tensor::from_vec(out_ch, x.h, x.w, vec![-1.0; out_ch * n])?;
        for o in 0..out_ch {
            let src = &acts.out[o * m..(o + 1) * m];
            let dst = y.plane_mut(o);
            for (&i, &v) in idx.iter().zip(src) {
                dst[i] = v;
            }
        }
        Ok((
            y,
            MlpFrameActs {
                h: x.h,
                w: x.w,
                idx,
                acts,
            },
        ))
    }

    /// Backward of [`MlpTrain::forward_frame`]: `dy` is dL/d(output after tanh) on the whole
    /// frame (values at unevaluated pixels are ignored: those outputs are constants). Adds to
    /// the gradients; returns dL/dx (`in_ch x h x w`, zero at unevaluated pixels).
    pub fn backward_frame(&mut self, a: &MlpFrameActs, dy: &Tensor) -> Tensor {
        let n = a.h * a.w;
        let (out_ch, in_ch) = (self.params.out_ch, self.params.in_ch);
        assert!(
            dy.c == out_ch && dy.h == a.h && dy.w == a.w,
            "MLP frame backward: dy shape"
        );
        let m = a.idx.len();
        let mut dout = Vec::with_capacity(out_ch * m);
        for o in 0..out_ch {
            let plane = &dy.data[o * n..(o + 1) * n];
            dout.extend(a.idx.iter().map(|&i| plane[i]));
        }
        let dpx = self.backward_pixels(&a.acts, &dout);
        let mut dx = Tensor::zeros(in_ch, a.h, a.w);
        for c in 0..in_ch {
            let src = &dpx[c * m..(c + 1) * m];
            let dst = dx.plane_mut(c);
            for (&i, &v) in a.idx.iter().zip(src) {
                dst[i] = v;
            }
        }
        dx
    }
}
