//! The validator's stable issue codes, as data: docs, the CLI and tests read this table.

use serde::Serialize;

/// How bad an issue is. An asset is valid when it has no `Error`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Severity {
    /// Breaks the format: readers may reject the asset or show only the fallback.
    Error,
    /// Legal but probably not what was meant.
    Warning,
    /// For information.
    Info,
}

/// One row of the code table.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct CodeInfo {
    /// Stable code, e.g. `EXR_CHANNELS`.
    pub code: &'static str,
    /// Severity of every issue with this code.
    pub severity: Severity,
    /// What it means.
    pub meaning: &'static str,
}

const fn row(code: &'static str, severity: Severity, meaning: &'static str) -> CodeInfo {
    CodeInfo {
        code,
        severity,
        meaning,
    }
}

use Severity::{Error as E, Warning as W};

/// Every code the validator can report.
pub const CODES: &[CodeInfo] = &[
    row("GLB_INVALID_HEADER", E, "GLB magic, version or total length is wrong (including trailing bytes)."),
    row("GLB_TRUNCATED", E, "The GLB ends before its header, a chunk header or a chunk's data."),
    row("GLB_CHUNK_INVALID", E, "A GLB chunk has a bad type, order or length (not a multiple of 4)."),
    row("JSON_INVALID", E, "The JSON is not UTF-8 or not well-formed."),
    row("JSON_SCHEMA", E, "A JSON object misses a required property or has one of the wrong type or value."),
    row("INDEX_OUT_OF_RANGE", E, "An index refers to an object that does not exist."),
    row("BUFFER_VIEW_OUT_OF_RANGE", E, "A bufferView, accessor or weight tensor reaches past the data it lives in."),
    row("BUFFER_INVALID", E, "A buffer's data cannot be found (no BIN chunk, bad data: URI, missing file) or is shorter than byteLength."),
    row("VERSION_UNSUPPORTED", E, "The extension's version is not 1; version-1 readers ignore the extension and show the fallback."),
    row("EXTENSION_REQUIRED", E, "The extension is listed in extensionsRequired; it must only be in extensionsUsed so viewers can fall back."),
    row("EXTENSION_NOT_USED", E, "The extension is used but missing from extensionsUsed."),
    row("FALLBACK_MISSING", E, "A primitive with the extension has no material, or its material lacks pbrMetallicRoughness.baseColorTexture or KHR_materials_unlit."),
    row("TEXTURE_NO_LEVELS", E, "A neural texture has no levels."),
    row("TEXTURE_MIME_TYPE", E, "A level's mimeType is not image/x-exr or image/png."),
    row("TEXTURE_CHANNELS_RANGE", E, "A neural texture declares fewer than 3 or more than 1024 channels."),
    row("TEXTURE_LEVEL_ORDER", W, "A level is larger than the level before it (levels are listed finest first)."),
    row("EXR_INVALID", E, "A level is not a decodable single-part flat scanline EXR with increasing line order."),
    row("EXR_CHANNELS", E, "A level's EXR channel count, names (C00..), type (HALF) or sampling (1x1) is wrong."),
    row("EXR_SIZE_MISMATCH", E, "A level's EXR data or display window differs from (0,0)-(width-1,height-1) of the JSON."),
    row("EXR_COMPRESSION", E, "A level uses a compression other than NONE, RLE, ZIPS, ZIP, PIZ."),
    row("EXR_NON_FINITE", E, "A level holds a NaN or infinite half value."),
    row("QUANT_BITS", E, "A quantised level's bits is not 8 or 4."),
    row("QUANT_ARRAY_LENGTH", E, "A quantised level's scale or offset array does not have one entry per channel."),
    row("QUANT_SCALE_INVALID", E, "A quantised level's scale is zero, negative or not finite, an offset is not finite, or offset + scale * (2^bits - 1) overflows f32."),
    row("PNG_INVALID", E, "A quantised level's bytes are not a decodable PNG (bad signature, truncated or corrupt chunk)."),
    row("PNG_FORMAT", E, "A quantised level's PNG is not 8-bit RGBA (colour type 6, bit depth 8): wrong bit depth or channel count."),
    row("PNG_SIZE_MISMATCH", E, "A quantised level's PNG is not width x (height * ceil(channels / k)) texels, k = 4 at 8 bits, 8 at 4 bits."),
    row("SH_DEGREE_UNSUPPORTED", E, "viewDependence has a basis other than sphericalHarmonics or a degree above 3."),
    row("SH_CHANNELS_OUT_OF_RANGE", E, "firstChannel + (degree+1)^2 exceeds the texture's channels."),
    row("RENDERER_UNKNOWN_ARCHITECTURE", E, "The renderer's architecture is not none, mlp or unet."),
    row("RENDERER_PARAMETER_INVALID", E, "A renderer parameter (hidden, widths, decoder, normalization, inputChannels) is missing, unknown or out of range."),
    row("RENDERER_INPUT_MISMATCH", E, "A primitive's binding pairs a texture and a renderer whose channels and inputChannels differ."),
    row("RENDERER_OUTPUT_CHANNELS", E, "outputChannels is not 3 or 4, or is not 3 for architecture none."),
    row("WEIGHTS_MISSING", E, "A tensor the architecture requires is absent."),
    row("WEIGHTS_UNEXPECTED", E, "A tensor the architecture does not name is present, or a name repeats."),
    row("WEIGHTS_SHAPE_MISMATCH", E, "A tensor's shape differs from what the architecture requires."),
    row("WEIGHTS_DTYPE_UNKNOWN", E, "A tensor's dtype is not f16, f32, int8 or int4."),
    row("WEIGHTS_MISALIGNED", E, "A tensor's byteOffset (or its bufferView's) is not a multiple of 4."),
    row("WEIGHTS_CHECKSUM_MISMATCH", E, "A tensor's CRC-32 differs from its crc32 property."),
    row("WEIGHTS_NON_FINITE", E, "A tensor holds NaN or infinite values (int8, int4: scale * q overflows f32)."),
    row("WEIGHTS_SCALE_INVALID", E, "An int8 or int4 tensor has a row scale that is zero, negative or not finite."),
    row("LIMIT_EXCEEDED", E, "A size exceeds the validator's configured limits (raise them for trusted inputs)."),
    row("TEXCOORD_MISSING", W, "A primitive with the extension lacks the TEXCOORD_n attribute its binding names."),
];

/// The table row of `code`.
pub fn code_info(code: &str) -> Option<&'static CodeInfo> {
    CODES.iter().find(|c| c.code == code)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_are_unique_and_upper_snake() {
        for (i, c) in CODES.iter().enumerate() {
            assert!(c
                .code
                .bytes()
                .all(|b| b.is_ascii_uppercase() || b == b'_' || b.is_ascii_digit()));
            assert!(CODES[..i].iter().all(|d| d.code != c.code), "{}", c.code);
        }
    }
}
