//! `dnr-format`: the data model, codecs and validator of the `EXT_deferred_neural_rendering`
//! glTF 2.0 extension (see `spec/EXT_deferred_neural_rendering/`).
//!
//! Must not depend on rendering or training code; it is the one crate every reader and writer
//! of the format shares.
#![forbid(unsafe_code)]

/// The extension's name as it appears in `extensionsUsed` and `extensions` objects.
pub const EXTENSION_NAME: &str = "EXT_deferred_neural_rendering";
