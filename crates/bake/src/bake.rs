//! The entry point of a bake: `--preset auto` goes to [`crate::auto`], every other
//! configuration to [`crate::fixed`]; both are built from the steps in [`crate::pipeline`].

use crate::train::config::{Preset, TrainConfig};

pub use crate::pipeline::{write_atomic, BakeError, BakeOptions, Summary};

/// Runs the whole bake: capture in, validated asset and report out.
pub fn bake(cfg: &TrainConfig, opts: &BakeOptions) -> Result<Summary, BakeError> {
    if cfg.preset == Preset::Auto {
        crate::auto::bake(cfg, opts)
    } else {
        crate::fixed::bake(cfg, opts)
    }
}
