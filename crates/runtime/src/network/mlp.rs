//! The per-pixel MLP renderer (`architecture: "mlp"`).
//!
//! Dense layers `layers.{i}.weight` `[out, in]`, `layers.{i}.bias` `[out]`, LeakyReLU(0.2) after
//! every layer but the last, tanh after the last; evaluated on covered pixels only.

use super::{check_no_extra, fetch_tensors, map_lookup, NetworkError, TensorRef};
use crate::nn::activation::{leaky_relu, tanh, LEAKY_SLOPE};
use crate::nn::dense::dense;
use crate::nn::{NnError, Tensor};
use std::collections::BTreeMap;

/// Architecture of an MLP renderer.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MlpParams {
    /// Input (feature) channels.
    pub in_ch: usize,
    /// Hidden layer widths (may be empty: one linear layer).
    pub hidden: Vec<usize>,
    /// Output channels.
    pub out_ch: usize,
}

impl MlpParams {
    /// Layer `i`'s (input, output) widths.
    pub fn layer_dims(&self) -> Vec<(usize, usize)> {
        let mut dims = Vec::with_capacity(self.hidden.len() + 1);
        let mut c = self.in_ch;
        for &h in self.hidden.iter().chain(std::iter::once(&self.out_ch)) {
            dims.push((c, h));
            c = h;
        }
        dims
    }

    /// Every tensor the architecture names with its shape.
    pub fn tensor_specs(&self) -> Vec<(String, Vec<usize>)> {
        let mut v = Vec::new();
        for (i, (ci, co)) in self.layer_dims().into_iter().enumerate() {
            v.push((format!("layers.{i}.weight"), vec![co, ci]));
            v.push((format!("layers.{i}.bias"), vec![co]));
        }
        v
    }

    /// FLOPs (2 per multiply-add) per evaluated pixel.
    pub fn flops_per_pixel(&self) -> u64 {
        self.layer_dims()
            .iter()
            .map(|&(a, b)| 2 * (a * b) as u64)
            .sum()
    }

    fn validate(&self) -> Result<(), NetworkError> {
        if self.in_ch == 0 || self.out_ch == 0 || self.hidden.contains(&0) {
            return Err(NetworkError::Params("MLP widths must be positive".into()));
        }
        Ok(())
    }
}

/// An MLP with validated weights.
#[derive(Clone, Debug)]
pub struct Mlp {
    params: MlpParams,
    /// (weight `[out, in]`, bias) per layer.
    layers: Vec<(Vec<f32>, Vec<f32>)>,
}

impl Mlp {
    /// Builds the MLP, fetching every tensor of [`MlpParams::tensor_specs`] through `lookup`.
    pub fn new<'a>(
        params: MlpParams,
        lookup: &dyn Fn(&str) -> Option<TensorRef<'a>>,
    ) -> Result<Self, NetworkError> {
        params.validate()?;
        let mut vals = fetch_tensors(&params.tensor_specs(), lookup)?.into_iter();
        let layers = params
            .layer_dims()
            .iter()
            .map(|_| (vals.next().expect("spec"), vals.next().expect("spec")))
            .collect();
        Ok(Mlp { params, layers })
    }

    /// Builds the MLP from a map of `name -> (shape, values)`; extra names are an error.
    pub fn from_map(
        params: MlpParams,
        map: &BTreeMap<String, (Vec<usize>, Vec<f32>)>,
    ) -> Result<Self, NetworkError> {
        params.validate()?;
        check_no_extra(&params.tensor_specs(), map.keys().map(String::as_str))?;
        Self::new(params, &map_lookup(map))
    }

    /// The architecture.
    pub fn params(&self) -> &MlpParams {
        &self.params
    }

    /// Outputs (after tanh) for `pixels` feature vectors stored planar (`in_ch x pixels`);
    /// returns `out_ch x pixels`.
    pub fn forward_pixels(&self, x: &[f32], pixels: usize) -> Result<Vec<f32>, NnError> {
        let dims = self.params.layer_dims();
        let mut cur = x.to_vec();
        for (i, ((w, b), &(ci, co))) in self.layers.iter().zip(&dims).enumerate() {
            cur = dense(&cur, pixels, w, b, ci, co)?;
            if i + 1 < dims.len() {
                leaky_relu(&mut cur, LEAKY_SLOPE);
            } else {
                tanh(&mut cur);
            }
        }
        Ok(cur)
    }

    /// Outputs for the pixels of `x` where `covered` is true (`covered.len() == h * w`); other
    /// pixels of the `out_ch x h x w` result are 0.
    pub fn forward(&self, x: &Tensor, covered: &[bool]) -> Result<Tensor, NnError> {
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
        let mut packed = Vec::with_capacity(x.c * idx.len());
        for c in 0..x.c {
            let plane = x.plane(c);
            packed.extend(idx.iter().map(|&i| plane[i]));
        }
        let y = self.forward_pixels(&packed, idx.len())?;
        let mut out = Tensor::zeros(self.params.out_ch, x.h, x.w);
        for o in 0..self.params.out_ch {
            let src = &y[o * idx.len()..(o + 1) * idx.len()];
            let dst = out.plane_mut(o);
            for (&i, &v) in idx.iter().zip(src) {
                dst[i] = v;
            }
        }
        Ok(out)
    }
}
