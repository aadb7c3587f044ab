//! `dnr-runtime`: decodes and renders `EXT_deferred_neural_rendering` assets on the CPU.
//!
//! What a third-party viewer links. Must not depend on training code or heavy dependencies.
#![forbid(unsafe_code)]

pub mod camera;
pub mod scene;
