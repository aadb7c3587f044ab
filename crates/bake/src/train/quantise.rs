//! Quantisation-aware fine-tuning: over the last [`QAT_FRACTION`] of training the forward
//! pass reads the texture levels and the weights as the asset will store them (quantised
//! PNG levels, `int8` weights), and the gradient of each stored value is applied to the
//! full-precision value it was rounded from (the straight-through estimator). So the asset
//! holds what was optimised, not a rounding of it.
//!
//! The rounding is `dnr_format`'s own ([`dnr_format::quant`], [`dnr_format::weights`]), with
//! parameters fitted to the values exactly as the exporter fits them: afresh for every
//! evaluation (so what validation measures is bit for bit what a reader decodes), and every
//! [`REFIT_EVERY`] steps for training steps (the levels' range search is the costly part).

use dnr_format::quant::{fake_quantise_hwc, fit_parameters_hwc};
use std::collections::BTreeMap;

use dnr_format::model::DType;
use dnr_format::weights::{int8_dequantise, int_quantise};
use dnr_runtime::texture::Pyramid;
use serde::Serialize;

/// Fraction of the training progress, at the end, trained through fake quantisation.
pub const QAT_FRACTION: f64 = 0.15;

/// Progress (0..1) at which fake quantisation starts.
pub const QAT_START: f64 = 1.0 - QAT_FRACTION;

/// The storage the forward pass imitates.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct QatTarget {
    /// Bits of each level's grid (`2^p` steps per channel), finest first (`None`: stored as
    /// f16, not rounded here; levels past the end are `None` too).
    pub level_bits: Vec<Option<u32>>,
    /// Whether the tensors of rank 2 or more are stored `int8` (biases stay f16).
    pub int8_weights: bool,
    /// Tensors stored otherwise, by name (`int4`, `int8` or `f16`, whatever `int8_weights`
    /// says).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub tensor_dtypes: BTreeMap<String, DType>,
}

impl QatTarget {
    /// Whether it rounds nothing.
    pub fn is_identity(&self) -> bool {
        !self.rounds_weights() && self.level_bits.iter().all(Option::is_none)
    }

    /// Whether it rounds any weight tensor.
    pub fn rounds_weights(&self) -> bool {
        self.int8_weights
            || self
                .tensor_dtypes
                .values()
                .any(|d| d.integer_top().is_some())
    }

    /// How tensor `name` is stored when it is rounded: `int4` or `int8`; `None` when it is
    /// stored as floats (not rounded here).
    pub fn weight_dtype(&self, name: &str) -> Option<DType> {
        match self.tensor_dtypes.get(name) {
            Some(d) => d.integer_top().map(|_| d.clone()),
            None => self.int8_weights.then_some(DType::Int8),
        }
    }
}

/// The pyramid as a reader of the asset will decode it (levels without bits unchanged).
pub fn quantised_pyramid(pyr: &Pyramid, level_bits: &[Option<u32>]) -> Pyramid {
    quantised_pyramid_with(pyr, &fit_levels(pyr, level_bits))
}

/// Steps of fine-tuning between refits of the levels' ranges ([`fit_levels`]): the search
/// for each channel's range costs several times the rounding, and the texture moves little
/// in a few steps. Evaluations and the exporter always fit afresh.
pub const REFIT_EVERY: u32 = 8;

/// Each level's `(bits, scale, offset)` as the exporter would fit them now (`None`: stored
/// f16, not rounded).
pub type LevelFits = Vec<Option<(u32, Vec<f32>, Vec<f32>)>>;

/// Fits every level that `level_bits` rounds, as the exporter does.
pub fn fit_levels(pyr: &Pyramid, level_bits: &[Option<u32>]) -> LevelFits {
    pyr.levels
        .iter()
        .zip(level_bits.iter().chain(std::iter::repeat(&None)))
        .map(|(level, bits)| {
            bits.map(|b| {
                let (scale, offset) = fit_parameters_hwc(&level.data, pyr.channels, b);
                (b, scale, offset)
            })
        })
        .collect()
}

/// The pyramid rounded with given fits (levels without one unchanged).
pub fn quantised_pyramid_with(pyr: &Pyramid, fits: &LevelFits) -> Pyramid {
    let mut out = pyr.clone();
    for (level, fit) in out.levels.iter_mut().zip(fits) {
        if let Some((bits, scale, offset)) = fit {
            fake_quantise_hwc(&mut level.data, scale, offset, *bits);
        }
    }
    out
}

/// Rounds a tensor through `int8` storage in place (per first-axis row, as the exporter
/// stores it); tensors of rank below 2 (biases, stored f16) are left as they are.
pub fn fake_int8(shape: &[usize], data: &mut [f32]) {
    fake_int(shape, data, &DType::Int8);
}

/// [`fake_int8`] for `int8` or `int4` (`dtype`), with the exporter's scales.
pub fn fake_int(shape: &[usize], data: &mut [f32], dtype: &DType) {
    if let Some(fit) = fit_tensor(shape, data, dtype) {
        round_tensor(data, &fit);
    }
}

/// One tensor's integer type and per-row scales, as the exporter fits them (`None`: not
/// rounded, e.g. a bias or an f16 tensor).
pub type TensorFit = Option<(DType, Vec<f32>)>;

fn fit_tensor(shape: &[usize], data: &[f32], dtype: &DType) -> TensorFit {
    dtype.integer_top()?;
    if shape.len() < 2 {
        return None;
    }
    let shape32: Vec<u32> = shape.iter().map(|&d| d as u32).collect();
    let scales = dnr_format::weights::int_fit_scales(&shape32, data, dtype);
    Some((dtype.clone(), scales))
}

fn round_tensor(data: &mut [f32], (dtype, scales): &(DType, Vec<f32>)) {
    let top = dtype.integer_top().unwrap_or(127.0);
    let per = (data.len() / scales.len().max(1)).max(1);
    for (i, v) in data.iter_mut().enumerate() {
        let s = scales[i / per];
        *v = int8_dequantise(int_quantise(*v, s, top), s);
    }
}

/// Fits the scales of every tensor `target` rounds (in parallel: int4's search over clipped
/// ranges reads each tensor fifteen times).
pub fn fit_weights(
    specs: &[(String, Vec<usize>)],
    weights: &[Vec<f32>],
    target: &QatTarget,
) -> Vec<TensorFit> {
    use rayon::prelude::*;
    specs
        .par_iter()
        .zip(weights.par_iter())
        .map(|((name, shape), w)| {
            target
                .weight_dtype(name)
                .and_then(|d| fit_tensor(shape, w, &d))
        })
        .collect()
}

/// The network's tensors rounded with `fits` (from [`fit_weights`]).
pub fn quantised_weights_with(weights: &[Vec<f32>], fits: &[TensorFit]) -> Vec<Vec<f32>> {
    weights
        .iter()
        .zip(fits)
        .map(|(w, fit)| {
            let mut q = w.clone();
            if let Some(fit) = fit {
                round_tensor(&mut q, fit);
            }
            q
        })
        .collect()
}

/// The network's tensors as the asset stores them under `target` (`specs` gives each
/// tensor's name and shape, in the order of `weights`).
pub fn quantised_weights(
    specs: &[(String, Vec<usize>)],
    weights: &[Vec<f32>],
    target: &QatTarget,
) -> Vec<Vec<f32>> {
    quantised_weights_with(weights, &fit_weights(specs, weights, target))
}

#[cfg(test)]
mod tests {
    use super::*;
    use dnr_format::asset::LevelStorage;
    use dnr_format::TextureLevel;
    use dnr_runtime::texture::Level;

    #[test]
    fn fake_quantisation_is_what_the_format_decodes() {
        let data: Vec<f32> = (0..7 * 5 * 6)
            .map(|i| ((i * 53 % 97) as f32 / 40.0 - 1.1) * (1 + i % 6) as f32)
            .collect();
        for (bits, storage) in [(8, LevelStorage::Q8), (4, LevelStorage::Q4)] {
            let pyr = Pyramid {
                channels: 6,
                levels: vec![Level {
                    width: 7,
                    height: 5,
                    data: data.clone(),
                }],
                ..Pyramid::default()
            };
            let q = quantised_pyramid(&pyr, &[Some(bits)]);
            assert_ne!(q.levels[0].data, data);
            let level = TextureLevel {
                width: 7,
                height: 5,
                channels: 6,
                data: data.clone(),
            };
            let (quant, png) = dnr_format::quant::encode_png_level(&level, bits).unwrap();
            let back = dnr_format::quant::decode_png_level(
                &png,
                dnr_format::exr_codec::LevelExpect {
                    width: 7,
                    height: 5,
                    channels: 6,
                },
                &quant,
                &dnr_format::Limits::default(),
            )
            .unwrap();
            assert_eq!(back.data, q.levels[0].data, "{storage:?}");
        }
    }

    #[test]
    fn kept_fits_round_onto_their_own_grid_and_unlisted_levels_stay_f16() {
        let level = |s: usize, k: f32| Level {
            width: s,
            height: s,
            data: (0..s * s * 3).map(|i| (i as f32 * k).sin()).collect(),
        };
        let mut pyr = Pyramid {
            channels: 3,
            levels: vec![level(8, 0.37), level(4, 0.53)],
            ..Pyramid::default()
        };
        let fits = fit_levels(&pyr, &[Some(4)]);
        assert!(fits[0].is_some() && fits[1].is_none());
        assert_eq!(
            quantised_pyramid_with(&pyr, &fits).levels,
            quantised_pyramid(&pyr, &[Some(4)]).levels
        );
        // The texture moves; the kept fit still rounds onto its 16 values per channel.
        for v in &mut pyr.levels[0].data {
            *v *= 1.01;
        }
        let q = quantised_pyramid_with(&pyr, &fits);
        let Some((_, scale, offset)) = &fits[0] else {
            unreachable!()
        };
        for (i, v) in q.levels[0].data.iter().enumerate() {
            let k = i % 3;
            let steps = (v - offset[k]) / scale[k];
            assert!((steps - steps.round()).abs() < 1e-3 && (0.0..=15.0).contains(&steps.round()));
        }
        assert_eq!(q.levels[1].data, pyr.levels[1].data);
    }

    #[test]
    fn int8_fake_quantisation_matches_the_codec() {
        let shape = [3usize, 4];
        let data: Vec<f32> = (0..12).map(|i| (i as f32 - 5.5) * 0.37).collect();
        let mut q = data.clone();
        fake_int8(&shape, &mut q);
        let bytes = dnr_format::weights::encode_int8("w", &[3, 4], &data).unwrap();
        let back = dnr_format::weights::decode_tensor(
            &bytes,
            &[3, 4],
            &dnr_format::model::DType::Int8,
            &dnr_format::Limits::default(),
        )
        .unwrap();
        assert_eq!(q, back);
        let mut bias = vec![0.123f32, 4.56];
        fake_int8(&[2], &mut bias);
        assert_eq!(bias, [0.123, 4.56]);
    }
}
