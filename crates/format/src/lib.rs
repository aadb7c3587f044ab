//! `dnr-format`: the data model, codecs and validator of the `EXT_deferred_neural_rendering`
//! glTF extension (see `spec/EXT_deferred_neural_rendering/`).
//!
//! Must not depend on rendering or training code (`dnr-runtime`, `dnr-bake`), nor on anything
//! heavier than the codecs the format itself needs (glTF JSON, OpenEXR, half floats, CRC-32,
//! PNG for the fallback image); it is the one crate every reader and writer of the format
//! shares.
//!
//! Validate, read and write an asset:
//!
//! ```
//! use dnr_format::{read_asset, validate_file, write_asset, Limits, Severity};
//!
//! // A conformance sample of the repository: an `mlp` renderer over a 2-level texture.
//! let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../samples/valid/mlp_f16_2levels.glb");
//!
//! // Every problem in one pass, each with a stable code, a severity and a JSON pointer
//! // (what `dnr validate` prints). A file that cannot be read at all is an `Err`.
//! let report = validate_file(std::path::Path::new(path), &Limits::default())?;
//! for issue in &report.issues {
//!     println!("{:?} {} at {}: {}", issue.severity, issue.code, issue.pointer, issue.message);
//! }
//! assert!(!report.has_errors() && report.count(Severity::Warning) == 0);
//!
//! // Read: texture levels decoded to f32 (texel-interleaved, row 0 at the top) and weight
//! // tensors to f32, each checked against its declared shape, CRC-32 and the limits.
//! let asset = read_asset(path)?;
//! let texture = &asset.textures[0];
//! let level0 = &texture.levels[0];
//! assert_eq!(level0.data.len(), (level0.width * level0.height * texture.channels) as usize);
//! let renderer = &asset.renderers[0];
//! println!("{:?} renderer, {} parameters", renderer.spec.architecture, renderer.parameter_count());
//!
//! // Write: to a temporary file beside the target, then renamed over it (`.gltf` writes
//! // JSON with embedded buffers, anything else GLB). A valid asset round-trips byte for byte.
//! let dir = tempfile::tempdir()?;
//! let copy = dir.path().join("copy.glb");
//! write_asset(&copy, &asset)?;
//! assert_eq!(std::fs::read(&copy)?, std::fs::read(path)?);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! To make a new asset, fill an [`AssetBuilder`] (textures, renderers, meshes, bindings) and
//! write what [`AssetBuilder::build`] returns.
//!
//! Two layers, as in `exr`:
//! - high: [`read_asset`], [`read_asset_from_slice`], [`write_asset`], [`AssetBuilder`],
//!   [`validate::validate_file`];
//! - low, public too: [`model`] (serde structs of the JSON), [`container`] (GLB / glTF
//!   IO), [`exr_codec`] (one level as EXR), [`quant`] (one quantised level as PNG, revision
//!   1.1), [`weights`] (tensor codec, `int8` included),
//!   [`architecture`] (tensors each architecture requires), [`limits`].
//!
//! Contract: safe for untrusted input. Nothing here panics on any input, and every size
//! read from a file is checked against [`Limits`] before it sizes an allocation.
//!
//! Conventions: texture levels are `f32` texel-interleaved (HWC), row 0 = top = v 0;
//! weights are row-major; on disk levels are EXR `HALF` channels `C00`.. (or, revision 1.1,
//! 8- or 4-bit PNG with a per-channel scale and offset), weights little-endian `f16`/`f32`
//! (or `int8` with per-row scales) with a CRC-32 (zlib) each.
#![forbid(unsafe_code)]

pub mod architecture;
pub mod asset;
pub mod container;
pub mod error;
pub mod exr_codec;
pub mod limits;
pub mod model;
pub mod quant;
pub mod validate;
pub mod weights;

pub use architecture::{architecture_tensors, renderer_problems};
pub use asset::{
    decode_asset, read_asset, read_asset_from_slice, read_asset_from_slice_with_limits,
    read_asset_with_limits, write_asset, Asset, AssetBuilder, DecodedRenderer, DecodedTexture,
    FallbackProblem, LevelStorage, MaterialDesc, NeuralTextureDesc, Node, Primitive, RendererDesc,
    WrapMode,
};
pub use container::Container;
pub use error::{Error, Result};
pub use exr_codec::{LevelCompression, TextureLevel};
pub use limits::Limits;
pub use validate::{validate_file, validate_slice, Issue, Report, Severity};
pub use weights::TensorF32;

/// The extension's name as it appears in `extensionsUsed` and `extensions` objects.
pub const EXTENSION_NAME: &str = "EXT_deferred_neural_rendering";
