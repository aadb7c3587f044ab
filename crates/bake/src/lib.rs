//! `dnr-bake`: trains a neural texture and renderer from a capture folder and exports an
//! `EXT_deferred_neural_rendering` asset.
//!
//! Uses the runtime's forward kernels so what it optimises is what the runtime draws: each
//! backward in [`kernels`] sits beside the runtime forward it differentiates. The capture
//! format it reads is described in `docs/capture-format.md`.
//!
//! Layering: it depends on `dnr-runtime` and `dnr-format` and must not depend on `dnr-cli`;
//! neither the runtime nor the format may depend on it (viewers must never link training
//! code).

pub mod auto;
pub mod bake;
pub mod bench;
pub mod capture;
pub mod eval;
pub mod export;
pub mod fallback;
pub mod fixed;
pub mod kernels;
pub mod pipeline;
pub mod storage;
pub mod train;
