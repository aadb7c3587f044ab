//! Training kernels: the backward of each layer, beside the forward it differentiates.
//!
//! Each backward sits beside the forward wrapper it differentiates (llm.c style: shapes stated at
//! the top of each function, parameter gradients accumulated with `+=`). Forwards reuse
//! `dnr_runtime::nn`, so what is trained is what the runtime draws.

pub mod activation;
pub mod adam;
pub mod concat;
pub mod conv;
pub mod conv_transpose;
pub mod dense;
pub mod loss;
pub mod mlp;
pub mod norm;
pub mod sample;
pub mod sh;
pub mod unet;
pub mod upsample;
