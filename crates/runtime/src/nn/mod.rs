//! Neural-network layers for the deferred neural renderer, forward only, on CHW planar f32
//! images (batch 1).
//!
//! Convolutions never build an im2col matrix when they can avoid it: the (zero-padded, for
//! stride 2 space-to-depth rearranged) input planes are read by the GEMM at one shifted offset
//! per kernel tap ([`conv::ConvLayout`]). The layout pieces are public so the trainer
//! (`dnr-bake`) computes gradients with the same code.

pub mod activation;
pub mod awake;
pub mod conv;
pub mod conv_transpose;
pub mod dense;
pub mod gemm;
pub mod norm;
pub mod region;
pub mod simd;
pub mod tensor;
pub mod upsample;

pub use tensor::Tensor;

/// Errors of the layer functions: shapes that do not fit together.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum NnError {
    /// Tensor or weight shapes do not match.
    #[error("shape mismatch: {0}")]
    Shape(String),
}
