//! `dnr-bake`: trains a neural texture and renderer from a capture folder and exports an
//! `EXT_deferred_neural_rendering` asset.
//!
//! Uses the runtime's forward kernels so what it optimises is what the runtime draws.

pub mod auto;
pub mod bake;
pub mod bench;
pub mod capture;
pub mod eval;
pub mod export;
pub mod fixed;
pub mod kernels;
pub mod pipeline;
pub mod train;
