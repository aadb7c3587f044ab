//! Renderer networks: the U-Net and the per-pixel MLP.
//!
//! Built from the [`crate::nn`] layers: the U-Net deferred neural renderer and the per-pixel MLP,
//! with weight validation against the names and shapes of `docs/DESIGN.md`.

pub mod mlp;
pub mod unet;

use crate::nn::NnError;

/// A weight tensor as the network constructors see it: shape and row-major values.
pub type TensorRef<'a> = (&'a [usize], &'a [f32]);

/// Errors of building or running a network.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum NetworkError {
    /// The architecture parameters are out of range.
    #[error("invalid network parameters: {0}")]
    Params(String),
    /// A tensor the architecture names is absent.
    #[error("missing weight tensor `{0}`")]
    Missing(String),
    /// A tensor has another shape than the architecture requires.
    #[error("weight tensor `{name}` has shape {got:?}, expected {expected:?}")]
    Shape {
        /// Tensor name.
        name: String,
        /// Shape the architecture requires.
        expected: Vec<usize>,
        /// Shape given.
        got: Vec<usize>,
    },
    /// A tensor's value count does not match its shape.
    #[error("weight tensor `{name}` has {got} values for shape {shape:?}")]
    Length {
        /// Tensor name.
        name: String,
        /// Declared shape.
        shape: Vec<usize>,
        /// Values given.
        got: usize,
    },
    /// A tensor the architecture does not name.
    #[error("unexpected weight tensor `{0}`")]
    Unexpected(String),
    /// A non-finite weight value.
    #[error("weight tensor `{0}` holds a non-finite value")]
    NonFinite(String),
    /// A layer rejected its input.
    #[error(transparent)]
    Nn(#[from] NnError),
}

/// Looks up every `(name, shape)` of `specs`, checking shape, length and finiteness; returns the
/// values in the same order.
pub fn fetch_tensors<'a>(
    specs: &[(String, Vec<usize>)],
    lookup: &dyn Fn(&str) -> Option<TensorRef<'a>>,
) -> Result<Vec<Vec<f32>>, NetworkError> {
    specs
        .iter()
        .map(|(name, expected)| {
            let (shape, data) = lookup(name).ok_or_else(|| NetworkError::Missing(name.clone()))?;
            if shape != expected.as_slice() {
                return Err(NetworkError::Shape {
                    name: name.clone(),
                    expected: expected.clone(),
                    got: shape.to_vec(),
                });
            }
            if data.len() != expected.iter().product::<usize>() {
                return Err(NetworkError::Length {
                    name: name.clone(),
                    shape: shape.to_vec(),
                    got: data.len(),
                });
            }
            if !data.iter().all(|v| v.is_finite()) {
                return Err(NetworkError::NonFinite(name.clone()));
            }
            Ok(data.to_vec())
        })
        .collect()
}

/// Errors with the first name in `names` that `specs` does not list (extra tensors are an error).
pub fn check_no_extra<'n>(
    specs: &[(String, Vec<usize>)],
    names: impl IntoIterator<Item = &'n str>,
) -> Result<(), NetworkError> {
    for n in names {
        if !specs.iter().any(|(s, _)| s == n) {
            return Err(NetworkError::Unexpected(n.to_string()));
        }
    }
    Ok(())
}

/// Adapts a map of `(shape, values)` to the lookup the constructors take.
pub fn map_lookup<'a>(
    map: &'a std::collections::BTreeMap<String, (Vec<usize>, Vec<f32>)>,
) -> impl Fn(&str) -> Option<TensorRef<'a>> + 'a {
    move |name| map.get(name).map(|(s, d)| (s.as_slice(), d.as_slice()))
}
