//! `dnr-runtime`: decodes and renders `EXT_deferred_neural_rendering` assets on the CPU.
//!
//! What a third-party viewer links. Must not depend on training code or heavy dependencies.
// `unsafe` is denied everywhere except the SIMD micro-kernels in `nn::gemm`, the
// instruction-set switch and prefetch in `nn::simd`, and the line-aligning allocator in `alloc`
// (which viewers may opt into for their binaries).
#![deny(unsafe_code)]

pub mod alloc;
pub mod camera;
pub mod gbuffer;
pub mod network;
pub mod nn;
pub mod raster;
pub mod renderer;
pub mod scene;
pub mod sh;
pub mod texture;
