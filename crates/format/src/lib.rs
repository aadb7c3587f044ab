//! `dnr-format`: the data model, codecs and validator of the `EXT_deferred_neural_rendering`
//! glTF extension (see `spec/EXT_deferred_neural_rendering/`).
//!
//! Must not depend on rendering or training code; it is the one crate every reader and writer
//! of the format shares.
//!
//! Two layers, as in `exr`:
//! - high: [`read_asset`], [`read_asset_from_slice`], [`write_asset`], [`AssetBuilder`],
//!   [`validate::validate_file`];
//! - low, public too: [`model`] (serde structs of the JSON), [`container`] (GLB / glTF
//!   IO), [`exr_codec`] (one level as EXR), [`weights`] (tensor codec),
//!   [`architecture`] (tensors each architecture requires), [`limits`].
//!
//! Contract: safe for untrusted input. Nothing here panics on any input, and every size
//! read from a file is checked against [`Limits`] before it sizes an allocation.
//!
//! Conventions: texture levels are `f32` texel-interleaved (HWC), row 0 = top = v 0;
//! weights are row-major; on disk levels are EXR `HALF` channels `C00`.., weights
//! little-endian `f16`/`f32` with a CRC-32 (zlib) each.
#![forbid(unsafe_code)]

pub mod architecture;
pub mod asset;
pub mod container;
pub mod error;
pub mod exr_codec;
pub mod limits;
pub mod model;
pub mod validate;
pub mod weights;

pub use architecture::{architecture_tensors, renderer_problems};
pub use asset::{
    decode_asset, read_asset, read_asset_from_slice, read_asset_from_slice_with_limits,
    read_asset_with_limits, write_asset, Asset, AssetBuilder, DecodedRenderer, DecodedTexture,
    FallbackProblem, MaterialDesc, NeuralTextureDesc, Node, Primitive, RendererDesc, WrapMode,
};
pub use container::Container;
pub use error::{Error, Result};
pub use exr_codec::{LevelCompression, TextureLevel};
pub use limits::Limits;
pub use validate::{validate_file, validate_slice, Issue, Report, Severity};
pub use weights::TensorF32;

/// The extension's name as it appears in `extensionsUsed` and `extensions` objects.
pub const EXTENSION_NAME: &str = "EXT_deferred_neural_rendering";
