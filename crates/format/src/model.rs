//! Low layer: serde structs mirroring the `EXT_deferred_neural_rendering` JSON.
//!
//! One struct per JSON object, field docs taken from the specification
//! (`docs/DESIGN.md`, normative text in `spec/EXT_deferred_neural_rendering/`).
//! Nothing here is validated: indices are plain `u32` (never cast from wider
//! integers) and enumerations keep values they do not know (`Unknown(String)`), so a
//! reader can round-trip and the validator can report them. Unknown fields survive in
//! each object's flattened `others` map.

use serde::{Deserialize, Deserializer, Serialize, Serializer};
use serde_json::{Map, Value};

/// The only extension version this crate reads and writes.
pub const VERSION: u32 = 1;

/// The MIME type of a neural texture level stored as EXR.
pub const LEVEL_MIME_TYPE: &str = "image/x-exr";

/// The MIME type of a quantised level (revision 1.1), see [`crate::quant`].
pub const LEVEL_MIME_TYPE_PNG: &str = "image/png";

/// Root object: `extensions.EXT_deferred_neural_rendering` of the glTF root.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct Extension {
    /// Version of the extension's data layout; this document describes version 1.
    pub version: u32,
    /// Neural textures (multi-level learned feature images).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub neural_textures: Vec<NeuralTexture>,
    /// Neural renderers turning a feature image into colour.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub renderers: Vec<Renderer>,
    /// Extension-specific objects, kept verbatim.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub extensions: Option<Map<String, Value>>,
    /// Application-specific data, kept verbatim.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub extras: Option<Value>,
    /// Fields this version does not define, kept verbatim.
    #[serde(flatten)]
    pub others: Map<String, Value>,
}

/// Binding object of a mesh primitive:
/// `meshes[m].primitives[p].extensions.EXT_deferred_neural_rendering`.
///
/// The primitive's core material is its fallback (an unlit base colour texture) and carries
/// nothing of this extension.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct PrimitiveExtension {
    /// Index of the neural texture in the root object's `neuralTextures`.
    pub neural_texture: u32,
    /// Index of the renderer in the root object's `renderers`.
    pub renderer: u32,
    /// The `n` of the `TEXCOORD_n` attribute that addresses the neural texture.
    #[serde(default)]
    pub tex_coord: u32,
    /// Extension-specific objects, kept verbatim.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub extensions: Option<Map<String, Value>>,
    /// Application-specific data, kept verbatim.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub extras: Option<Value>,
    /// Fields this version does not define, kept verbatim.
    #[serde(flatten)]
    pub others: Map<String, Value>,
}

/// A neural texture: `channels` learned features stored as a pyramid of EXR levels.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct NeuralTexture {
    /// Number of feature channels C, identical in every level.
    pub channels: u32,
    /// Levels, finest first; the feature is the sum of every level's bilinear sample.
    pub levels: Vec<Level>,
    /// Index of the core sampler whose `wrapS`/`wrapT` apply (default REPEAT both ways);
    /// its filters are ignored (always bilinear, no mipmaps).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sampler: Option<u32>,
    /// Optional view-dependent modulation of a range of channels.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub view_dependence: Option<ViewDependence>,
    /// Extension-specific objects, kept verbatim.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub extensions: Option<Map<String, Value>>,
    /// Application-specific data, kept verbatim.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub extras: Option<Value>,
    /// Fields this version does not define, kept verbatim.
    #[serde(flatten)]
    pub others: Map<String, Value>,
}

/// One level of a neural texture: a single-part scanline OpenEXR image in a bufferView.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct Level {
    /// Width in texels; equals the EXR data window width.
    pub width: u32,
    /// Height in texels; equals the EXR data window height.
    pub height: u32,
    /// Index of the bufferView holding the EXR file.
    pub buffer_view: u32,
    /// `image/x-exr`, or `image/png` for a quantised level (revision 1.1).
    pub mime_type: String,
    /// Revision 1.1: the quantisation of an `image/png` level; absent for EXR levels.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub quantization: Option<Quantization>,
    /// Extension-specific objects, kept verbatim.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub extensions: Option<Map<String, Value>>,
    /// Application-specific data, kept verbatim.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub extras: Option<Value>,
    /// Fields this version does not define, kept verbatim.
    #[serde(flatten)]
    pub others: Map<String, Value>,
}

/// Quantisation of a PNG level (revision 1.1): texel channel `c` is
/// `offset[c] + scale[c] * q`, computed in `f32`, with `q` the stored `bits`-bit integer.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct Quantization {
    /// Bits per stored value: 8 (4 channels per RGBA texel) or 4 (8 channels, two per byte).
    pub bits: u32,
    /// Per channel step, finite and above 0.
    pub scale: Vec<f32>,
    /// Per channel value of `q = 0`, finite.
    pub offset: Vec<f32>,
    /// Extension-specific objects, kept verbatim.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub extensions: Option<Map<String, Value>>,
    /// Application-specific data, kept verbatim.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub extras: Option<Value>,
    /// Fields this version does not define, kept verbatim.
    #[serde(flatten)]
    pub others: Map<String, Value>,
}

/// View dependence: channels `firstChannel + j`, `j < (degree+1)^2`, are multiplied by the
/// real spherical harmonic `Y_j(d)` of the view direction `d` (3DGS order and signs).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct ViewDependence {
    /// Basis of the modulation; only `sphericalHarmonics` is defined.
    pub basis: String,
    /// Spherical harmonic degree, 0..=3.
    pub degree: u32,
    /// First modulated channel.
    pub first_channel: u32,
    /// Extension-specific objects, kept verbatim.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub extensions: Option<Map<String, Value>>,
    /// Application-specific data, kept verbatim.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub extras: Option<Value>,
    /// Fields this version does not define, kept verbatim.
    #[serde(flatten)]
    pub others: Map<String, Value>,
}

/// The one basis version 1 defines.
pub const BASIS_SPHERICAL_HARMONICS: &str = "sphericalHarmonics";

impl ViewDependence {
    /// Spherical harmonics of `degree` starting at `first_channel`.
    pub fn spherical_harmonics(degree: u32, first_channel: u32) -> Self {
        ViewDependence {
            basis: BASIS_SPHERICAL_HARMONICS.to_string(),
            degree,
            first_channel,
            extensions: None,
            extras: None,
            others: Map::new(),
        }
    }

    /// Number of modulated channels, `(degree+1)^2` (saturating).
    pub fn coefficient_count(&self) -> u64 {
        let d = u64::from(self.degree) + 1;
        d.saturating_mul(d)
    }
}

/// A neural renderer: architecture, its parameters and its weight tensors.
///
/// The architecture-specific fields are flat, as in the JSON: `hidden` for `mlp`;
/// `widths`, `decoder`, `normalization` for `unet`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct Renderer {
    /// Network architecture: `none`, `mlp` or `unet`.
    pub architecture: Architecture,
    /// Input channels; must equal the paired neural texture's `channels`.
    pub input_channels: u32,
    /// Output channels: 3 (RGB, alpha = coverage) or 4 (RGBA).
    pub output_channels: u32,
    /// `mlp`: hidden layer widths `h1..hn` (n >= 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hidden: Option<Vec<u32>>,
    /// `unet`: encoder widths `w0..w(D-1)`, 1 <= D <= 8.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub widths: Option<Vec<u32>>,
    /// `unet`: upsampling layer kind.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub decoder: Option<Decoder>,
    /// `unet`: normalisation after each inner layer.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub normalization: Option<Normalization>,
    /// Weight tensor descriptors; exactly the tensors the architecture names.
    #[serde(default)]
    pub weights: Vec<WeightTensor>,
    /// Revision 1.3: subsamples per pixel side (`1..=`[`MAX_SUPERSAMPLE`]); the feature image
    /// is the mean of `s x s` subsample features. None means 1 (writers omit it then).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub supersample: Option<u32>,
    /// Extension-specific objects, kept verbatim.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub extensions: Option<Map<String, Value>>,
    /// Application-specific data, kept verbatim.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub extras: Option<Value>,
    /// Fields this version does not define, kept verbatim.
    #[serde(flatten)]
    pub others: Map<String, Value>,
}

/// Largest `supersample` a renderer may declare (16 subsamples per pixel).
pub const MAX_SUPERSAMPLE: u32 = 4;

impl Renderer {
    /// Subsamples per pixel side: `supersample`, or 1 when absent.
    pub fn supersample_factor(&self) -> u32 {
        self.supersample.unwrap_or(1)
    }

    /// A renderer with the given architecture and channel counts and no parameters.
    pub fn new(architecture: Architecture, input_channels: u32, output_channels: u32) -> Self {
        Renderer {
            architecture,
            input_channels,
            output_channels,
            hidden: None,
            widths: None,
            decoder: None,
            normalization: None,
            weights: Vec::new(),
            supersample: None,
            extensions: None,
            extras: None,
            others: Map::new(),
        }
    }

    /// An `mlp` renderer with the given hidden widths.
    pub fn mlp(input_channels: u32, output_channels: u32, hidden: Vec<u32>) -> Self {
        Renderer {
            hidden: Some(hidden),
            ..Renderer::new(Architecture::Mlp, input_channels, output_channels)
        }
    }

    /// A `unet` renderer.
    pub fn unet(
        input_channels: u32,
        output_channels: u32,
        widths: Vec<u32>,
        decoder: Decoder,
        normalization: Normalization,
    ) -> Self {
        Renderer {
            widths: Some(widths),
            decoder: Some(decoder),
            normalization: Some(normalization),
            ..Renderer::new(Architecture::Unet, input_channels, output_channels)
        }
    }
}

/// Descriptor of one weight tensor stored in a bufferView.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct WeightTensor {
    /// Tensor name, e.g. `encoder.0.weight`.
    pub name: String,
    /// Shape, row-major (C order).
    pub shape: Vec<u32>,
    /// Element type: `f16` or `f32`, little-endian, or (revision 1.1) `int8`, or (revision
    /// 1.2) `int4`.
    pub dtype: DType,
    /// Index of the bufferView holding the tensor.
    pub buffer_view: u32,
    /// Offset within the bufferView; a multiple of 4.
    #[serde(default)]
    pub byte_offset: u64,
    /// CRC-32/ISO-HDLC (zlib's crc32) of the tensor's bytes.
    pub crc32: u32,
    /// Extension-specific objects, kept verbatim.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub extensions: Option<Map<String, Value>>,
    /// Application-specific data, kept verbatim.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub extras: Option<Value>,
    /// Fields this version does not define, kept verbatim.
    #[serde(flatten)]
    pub others: Map<String, Value>,
}

impl WeightTensor {
    /// Number of elements (product of the shape), `None` on overflow.
    pub fn element_count(&self) -> Option<u64> {
        self.shape
            .iter()
            .try_fold(1u64, |acc, &d| acc.checked_mul(u64::from(d)))
    }

    /// Byte length of the tensor data, `None` on overflow or unknown dtype. For `int8` and
    /// `int4` it includes the padding and the per-row `f32` scales ([`int8_rows`]).
    pub fn byte_length(&self) -> Option<u64> {
        let n = self.element_count()?;
        match self.dtype.integer_value_bytes(n) {
            Some(values) => values
                .next_multiple_of(4)
                .checked_add(int8_rows(&self.shape).checked_mul(4)?),
            None => n.checked_mul(self.dtype.size_of()? as u64),
        }
    }
}

/// Number of `f32` scales of an `int8` or `int4` tensor: one per index of the first axis (the output
/// channel of dense layers and convolutions), 1 for a scalar.
pub fn int8_rows(shape: &[u32]) -> u64 {
    shape.first().map_or(1, |&d| u64::from(d))
}

/// Declares a string-backed enum that keeps values it does not know.
macro_rules! string_enum {
    ($(#[$meta:meta])* $name:ident { $($(#[$vmeta:meta])* $variant:ident = $text:literal),+ $(,)? }) => {
        $(#[$meta])*
        #[derive(Clone, Debug, PartialEq, Eq, Hash)]
        pub enum $name {
            $($(#[$vmeta])* $variant,)+
            /// A value this version does not define, kept verbatim.
            Unknown(String),
        }

        impl $name {
            /// The JSON spelling.
            pub fn as_str(&self) -> &str {
                match self {
                    $($name::$variant => $text,)+
                    $name::Unknown(s) => s,
                }
            }

            /// Parses the JSON spelling; never fails (unknown values are kept).
            pub fn parse(s: &str) -> Self {
                match s {
                    $($text => $name::$variant,)+
                    other => $name::Unknown(other.to_string()),
                }
            }

            /// Whether this version defines the value.
            pub fn is_known(&self) -> bool {
                !matches!(self, $name::Unknown(_))
            }
        }

        impl std::fmt::Display for $name {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str(self.as_str())
            }
        }

        impl Serialize for $name {
            fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
                s.serialize_str(self.as_str())
            }
        }

        impl<'de> Deserialize<'de> for $name {
            fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
                let s = String::deserialize(d)?;
                Ok($name::parse(&s))
            }
        }
    };
}

string_enum! {
    /// Renderer architecture.
    Architecture {
        /// Colour is the first three feature channels, clamped; no weights.
        None = "none",
        /// Per-pixel dense layers.
        Mlp = "mlp",
        /// Convolutional U-Net over the feature image.
        Unet = "unet",
    }
}

string_enum! {
    /// U-Net upsampling layer.
    Decoder {
        /// 4x4 stride-2 transposed convolution.
        TransposedConv = "transposedConv",
        /// Nearest x2 upsample then 3x3 convolution.
        UpsampleConv = "upsampleConv",
    }
}

string_enum! {
    /// U-Net normalisation.
    Normalization {
        /// Instance normalisation without affine parameters.
        Instance = "instance",
        /// No normalisation.
        None = "none",
    }
}

string_enum! {
    /// Weight element type.
    DType {
        /// IEEE 754 binary16, little-endian.
        F16 = "f16",
        /// IEEE 754 binary32, little-endian.
        F32 = "f32",
        /// Revision 1.1: signed 8-bit integers, then one `f32` scale per first-axis index.
        Int8 = "int8",
        /// Revision 1.2: signed 4-bit integers, two per byte (low nibble first), then one
        /// `f32` scale per first-axis index.
        Int4 = "int4",
    }
}

impl DType {
    /// Bytes per element, `None` for unknown types.
    pub fn size_of(&self) -> Option<usize> {
        match self {
            DType::F16 => Some(2),
            DType::F32 => Some(4),
            DType::Int8 => Some(1),
            // Two per byte: callers use `integer_value_bytes`.
            DType::Int4 => Some(1),
            DType::Unknown(_) => None,
        }
    }

    /// For the integer types, the bytes that `n` values take before the padding and scales
    /// (`n` for `int8`, `ceil(n / 2)` for `int4`); `None` for the others.
    pub fn integer_value_bytes(&self, n: u64) -> Option<u64> {
        match self {
            DType::Int8 => Some(n),
            DType::Int4 => Some(n.div_ceil(2)),
            _ => None,
        }
    }

    /// The largest magnitude a writer stores in an integer type (127 or 7), `None` for the
    /// others.
    pub fn integer_top(&self) -> Option<f32> {
        match self {
            DType::Int8 => Some(127.0),
            DType::Int4 => Some(7.0),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unknown_values_and_fields_survive() {
        let text = r#"{"architecture":"transformer","inputChannels":4,"outputChannels":3,"weights":[],"futureField":{"a":1}}"#;
        let r: Renderer = serde_json::from_str(text).unwrap();
        assert_eq!(r.architecture, Architecture::Unknown("transformer".into()));
        assert!(r.others.contains_key("futureField"));
        let back = serde_json::to_string(&r).unwrap();
        assert_eq!(back, text);
    }

    #[test]
    fn rejects_negative_and_oversized_indices() {
        let neg = r#"{"width":-1,"height":1,"bufferView":0,"mimeType":"image/x-exr"}"#;
        assert!(serde_json::from_str::<Level>(neg).is_err());
        let big = r#"{"width":4294967296,"height":1,"bufferView":0,"mimeType":"image/x-exr"}"#;
        assert!(serde_json::from_str::<Level>(big).is_err());
    }
}
