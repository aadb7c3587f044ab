//! Low layer: the glTF container, `.glb` (binary) and `.gltf` (JSON + `data:` URIs or
//! external files), around a core [`gltf_json::Root`].
//!
//! Reading checks every length against [`Limits`] before allocating; writing is
//! deterministic (the same [`Container`] always gives the same bytes) and atomic (a
//! temporary file in the destination folder, then a rename).

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};
use crate::limits::Limits;

/// `glTF` magic, little-endian (glTF 2.0 spec, "Binary glTF Layout").
pub const GLB_MAGIC: u32 = 0x4654_6C67;
/// `JSON` chunk type.
pub const CHUNK_JSON: u32 = 0x4E4F_534A;
/// `BIN\0` chunk type.
pub const CHUNK_BIN: u32 = 0x004E_4942;
/// Size of the GLB header (magic, version, length).
pub const GLB_HEADER_LEN: usize = 12;

/// A problem found while reading, with the validator code it maps to.
#[derive(Debug)]
pub struct Problem {
    /// Stable validator code (see [`crate::validate::codes`]).
    pub code: &'static str,
    /// The typed error.
    pub error: Error,
}

impl Problem {
    /// A problem with code `code` and an [`Error::Invalid`] saying `what`.
    pub fn invalid(code: &'static str, what: impl Into<String>) -> Self {
        Problem {
            code,
            error: Error::invalid(what),
        }
    }

    /// Wraps a limit error as `LIMIT_EXCEEDED`, any other error under `code`.
    pub fn from_error(code: &'static str, error: Error) -> Self {
        let code = match error {
            Error::LimitExceeded { .. } => "LIMIT_EXCEEDED",
            _ => code,
        };
        Problem { code, error }
    }
}

impl Problem {
    /// The message for a report: the error text without the `invalid` prefix.
    pub fn message(&self) -> String {
        match &self.error {
            Error::Invalid { what } => what.clone(),
            other => other.to_string(),
        }
    }
}

impl From<Problem> for Error {
    fn from(p: Problem) -> Error {
        p.error
    }
}

/// The chunks of a `.glb` file, borrowed from its bytes.
#[derive(Clone, Copy, Debug)]
pub struct Glb<'a> {
    /// JSON chunk contents (may end with padding spaces).
    pub json: &'a [u8],
    /// BIN chunk contents (may end with padding zeros).
    pub bin: Option<&'a [u8]>,
}

fn read_u32(bytes: &[u8], at: usize) -> Option<u32> {
    let b = bytes.get(at..at.checked_add(4)?)?;
    Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
}

/// Whether `bytes` start with the GLB magic.
pub fn is_glb(bytes: &[u8]) -> bool {
    bytes.starts_with(b"glTF")
}

/// Splits a `.glb` file into its chunks.
pub fn parse_glb<'a>(bytes: &'a [u8], limits: &Limits) -> Result<Glb<'a>, Problem> {
    if !is_glb(bytes) {
        return Err(Problem::invalid(
            "GLB_INVALID_HEADER",
            "GLB magic is not `glTF`",
        ));
    }
    Limits::check("GLB size", bytes.len() as u64, limits.max_file_bytes)
        .map_err(|e| Problem::from_error("LIMIT_EXCEEDED", e))?;
    let (Some(version), Some(length)) = (read_u32(bytes, 4), read_u32(bytes, 8)) else {
        return Err(Problem::invalid(
            "GLB_TRUNCATED",
            format!("GLB header needs 12 bytes, file has {}", bytes.len()),
        ));
    };
    if version != 2 {
        return Err(Problem::invalid(
            "GLB_INVALID_HEADER",
            format!("GLB version {version}, expected 2"),
        ));
    }
    let length = u64::from(length);
    let actual = bytes.len() as u64;
    if length > actual {
        return Err(Problem::invalid(
            "GLB_TRUNCATED",
            format!("GLB header declares {length} bytes, file has {actual}"),
        ));
    }
    if length < actual {
        return Err(Problem::invalid(
            "GLB_INVALID_HEADER",
            format!("GLB header declares {length} bytes, file has {actual} (trailing bytes)"),
        ));
    }
    let mut at = GLB_HEADER_LEN;
    let mut json = None;
    let mut bin = None;
    let mut index = 0usize;
    while at < bytes.len() {
        let (Some(len), Some(kind)) = (read_u32(bytes, at), read_u32(bytes, at + 4)) else {
            return Err(Problem::invalid(
                "GLB_TRUNCATED",
                format!("chunk {index} header at byte {at} is cut off"),
            ));
        };
        let start = at + 8;
        let len = len as usize; // u32 always fits usize on supported targets (>= 32-bit)
        let Some(end) = start.checked_add(len).filter(|&e| e <= bytes.len()) else {
            return Err(Problem::invalid(
                "GLB_TRUNCATED",
                format!("chunk {index} declares {len} bytes past the end of the file"),
            ));
        };
        if !len.is_multiple_of(4) {
            return Err(Problem::invalid(
                "GLB_CHUNK_INVALID",
                format!("chunk {index} length {len} is not a multiple of 4"),
            ));
        }
        let data = &bytes[start..end];
        match (index, kind) {
            (0, CHUNK_JSON) => {
                Limits::check("JSON chunk size", len as u64, limits.max_json_bytes)
                    .map_err(|e| Problem::from_error("LIMIT_EXCEEDED", e))?;
                json = Some(data);
            }
            (0, _) => {
                return Err(Problem::invalid(
                    "GLB_CHUNK_INVALID",
                    format!("first chunk has type {kind:#010x}, expected JSON"),
                ))
            }
            (1, CHUNK_BIN) => bin = Some(data),
            (_, CHUNK_JSON) | (_, CHUNK_BIN) => {
                return Err(Problem::invalid(
                    "GLB_CHUNK_INVALID",
                    format!("chunk {index} repeats a JSON or BIN chunk"),
                ))
            }
            _ => {} // unknown chunk types are skipped, as the glTF spec requires
        }
        at = end;
        index += 1;
    }
    let Some(json) = json else {
        return Err(Problem::invalid("GLB_TRUNCATED", "GLB has no JSON chunk"));
    };
    Ok(Glb { json, bin })
}

/// Assembles a `.glb`: JSON padded with spaces, BIN padded with zeros, 4-byte aligned.
pub fn glb_bytes(json: &[u8], bin: Option<&[u8]>) -> Result<Vec<u8>> {
    let pad4 = |n: usize| (4 - n % 4) % 4;
    let json_len = json.len() + pad4(json.len());
    let bin_len = bin.map(|b| b.len() + pad4(b.len()));
    let total = GLB_HEADER_LEN + 8 + json_len + bin_len.map_or(0, |l| 8 + l);
    let total32 = u32::try_from(total)
        .map_err(|_| Error::invalid(format!("GLB of {total} bytes exceeds 4 GiB")))?;
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(&GLB_MAGIC.to_le_bytes());
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&total32.to_le_bytes());
    out.extend_from_slice(&(json_len as u32).to_le_bytes());
    out.extend_from_slice(&CHUNK_JSON.to_le_bytes());
    out.extend_from_slice(json);
    out.resize(out.len() + pad4(json.len()), b' ');
    if let (Some(bin), Some(bin_len)) = (bin, bin_len) {
        out.extend_from_slice(&(bin_len as u32).to_le_bytes());
        out.extend_from_slice(&CHUNK_BIN.to_le_bytes());
        out.extend_from_slice(bin);
        out.resize(out.len() + pad4(bin.len()), 0);
    }
    Ok(out)
}

/// How a container is stored on disk.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ContainerKind {
    /// Binary `.glb`: buffer 0 is the BIN chunk.
    Glb,
    /// JSON `.gltf`; buffers are `data:` URIs or external files.
    Gltf,
}

/// A core glTF document with its buffers resolved to bytes.
#[derive(Clone, Debug)]
pub struct Container {
    /// The core document, extensions included (ours in `extensions.others`).
    pub root: gltf_json::Root,
    /// Contents of `root.buffers[i]`, each exactly `byteLength` long or longer (GLB padding).
    pub buffers: Vec<Vec<u8>>,
}

/// Parses JSON text into the core document (`JSON_INVALID` / `JSON_SCHEMA` on failure).
pub fn parse_root(json: &[u8]) -> Result<gltf_json::Root, Problem> {
    let text = std::str::from_utf8(json)
        .map_err(|e| Problem::invalid("JSON_INVALID", format!("JSON is not UTF-8: {e}")))?;
    // Syntax first, so a syntax error is not reported as a schema error.
    serde_json::from_str::<serde::de::IgnoredAny>(text)
        .map_err(|e| Problem::invalid("JSON_INVALID", format!("JSON syntax: {e}")))?;
    serde_json::from_str::<gltf_json::Root>(text)
        .map_err(|e| Problem::invalid("JSON_SCHEMA", format!("glTF schema: {e}")))
}

/// Bytes of buffer `index`, from the GLB BIN chunk, a `data:` URI or a file under
/// `base_dir` (external files need a base folder).
pub fn resolve_buffer(
    root: &gltf_json::Root,
    index: usize,
    bin: Option<&[u8]>,
    base_dir: Option<&Path>,
    limits: &Limits,
) -> Result<Vec<u8>, Problem> {
    let buffer = root
        .buffers
        .get(index)
        .ok_or_else(|| Problem::invalid("INDEX_OUT_OF_RANGE", format!("no buffer {index}")))?;
    let declared = buffer.byte_length.0;
    Limits::check("buffer byteLength", declared, limits.max_buffer_bytes)
        .map_err(|e| Problem::from_error("LIMIT_EXCEEDED", e))?;
    let data = match buffer.uri.as_deref() {
        None => {
            let bin = bin.filter(|_| index == 0).ok_or_else(|| {
                Problem::invalid(
                    "BUFFER_INVALID",
                    format!("buffer {index} has no uri and there is no GLB BIN chunk for it"),
                )
            })?;
            bin.to_vec()
        }
        Some(uri) if uri.starts_with("data:") => {
            decode_data_uri(uri, limits).map_err(|e| Problem::from_error("BUFFER_INVALID", e))?
        }
        Some(uri) => {
            let base = base_dir.ok_or_else(|| {
                Problem::from_error(
                    "BUFFER_INVALID",
                    Error::not_supported(format!(
                        "buffer {index} refers to external file `{uri}` but no folder is known"
                    )),
                )
            })?;
            read_external(base, uri, limits)
                .map_err(|e| Problem::from_error("BUFFER_INVALID", e))?
        }
    };
    if (data.len() as u64) < declared {
        return Err(Problem::invalid(
            "BUFFER_INVALID",
            format!(
                "buffer {index} has {} bytes of data, byteLength declares {declared}",
                data.len()
            ),
        ));
    }
    Ok(data)
}

fn read_external(base: &Path, uri: &str, limits: &Limits) -> Result<Vec<u8>> {
    if uri.contains(':') {
        return Err(Error::not_supported(format!("URI scheme in `{uri}`")));
    }
    let rel = percent_decode(uri)?;
    let path = base.join(rel);
    // Invalid rather than Io: the asset refers to a file that is not there, and the
    // message must name the asset (the caller adds it) as well as the missing file.
    let unreadable = |e: std::io::Error| {
        Error::invalid(format!(
            "external buffer `{uri}` ({}) cannot be read: {e}",
            path.display()
        ))
    };
    let meta = fs::metadata(&path).map_err(unreadable)?;
    Limits::check("external buffer size", meta.len(), limits.max_buffer_bytes)?;
    fs::read(&path).map_err(unreadable)
}

fn percent_decode(s: &str) -> Result<String> {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' {
            let hex = b
                .get(i + 1..i + 3)
                .and_then(|h| std::str::from_utf8(h).ok())
                .and_then(|h| u8::from_str_radix(h, 16).ok())
                .ok_or_else(|| Error::invalid(format!("percent escape in URI `{s}`")))?;
            out.push(hex);
            i += 3;
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    String::from_utf8(out).map_err(|_| Error::invalid(format!("URI `{s}` is not UTF-8")))
}

const B64: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";

/// Standard base64 with padding.
pub fn base64_encode(data: &[u8]) -> String {
    let mut out = String::with_capacity(data.len().div_ceil(3) * 4);
    for c in data.chunks(3) {
        let n = (u32::from(c[0]) << 16)
            | (u32::from(*c.get(1).unwrap_or(&0)) << 8)
            | u32::from(*c.get(2).unwrap_or(&0));
        let sym = |shift: u32| B64[((n >> shift) & 63) as usize] as char;
        out.push(sym(18));
        out.push(sym(12));
        out.push(if c.len() > 1 { sym(6) } else { '=' });
        out.push(if c.len() > 2 { sym(0) } else { '=' });
    }
    out
}

/// Decodes standard base64 (padding optional).
pub fn base64_decode(text: &str) -> Result<Vec<u8>> {
    let text = text.trim_end_matches('=');
    let mut out = Vec::with_capacity(text.len() / 4 * 3 + 3);
    let mut acc = 0u32;
    let mut bits = 0u32;
    for ch in text.bytes() {
        let v = match ch {
            b'A'..=b'Z' => ch - b'A',
            b'a'..=b'z' => ch - b'a' + 26,
            b'0'..=b'9' => ch - b'0' + 52,
            b'+' => 62,
            b'/' => 63,
            _ => return Err(Error::invalid("base64 character in data: URI")),
        };
        acc = (acc << 6) | u32::from(v);
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
            acc &= (1 << bits) - 1;
        }
    }
    Ok(out)
}

fn decode_data_uri(uri: &str, limits: &Limits) -> Result<Vec<u8>> {
    let comma = uri
        .find(',')
        .ok_or_else(|| Error::invalid("data: URI without a comma"))?;
    let (header, payload) = (&uri[..comma], &uri[comma + 1..]);
    if !header.ends_with(";base64") {
        return Err(Error::not_supported("data: URI that is not base64"));
    }
    Limits::check(
        "data: URI decoded size",
        (payload.len() as u64 / 4) * 3,
        limits.max_buffer_bytes,
    )?;
    base64_decode(payload)
}

/// The `data:` URI for a binary buffer.
pub fn data_uri(data: &[u8]) -> String {
    format!(
        "data:application/octet-stream;base64,{}",
        base64_encode(data)
    )
}

impl Container {
    /// Reads a `.glb` or `.gltf` from memory; external files resolve against `base_dir`.
    pub fn from_slice(bytes: &[u8], base_dir: Option<&Path>, limits: &Limits) -> Result<Self> {
        let (json, bin) = if is_glb(bytes) {
            let glb = parse_glb(bytes, limits)?;
            (glb.json, glb.bin)
        } else {
            Limits::check("JSON size", bytes.len() as u64, limits.max_json_bytes)?;
            (bytes, None)
        };
        let root = parse_root(json)?;
        let buffers = (0..root.buffers.len())
            .map(|i| resolve_buffer(&root, i, bin, base_dir, limits).map_err(Error::from))
            .collect::<Result<Vec<_>>>()?;
        Ok(Container { root, buffers })
    }

    /// Reads a `.glb` or `.gltf` file.
    pub fn read(path: &Path, limits: &Limits) -> Result<Self> {
        let bytes = read_file_limited(path, limits.max_file_bytes)?;
        Container::from_slice(&bytes, path.parent(), limits).map_err(|e| name_file(e, path))
    }

    /// Bytes of bufferView `view` (bounds checked).
    pub fn view_bytes(&self, view: u32) -> Result<&[u8]> {
        view_bytes(&self.root, &self.buffers, view)
    }

    /// The `.glb` bytes: buffer 0 becomes the BIN chunk, other buffers `data:` URIs.
    pub fn to_glb(&self) -> Result<Vec<u8>> {
        let mut root = self.root.clone();
        for (i, buffer) in root.buffers.iter_mut().enumerate() {
            if i == 0 {
                buffer.uri = None;
            } else {
                buffer.uri = Some(data_uri(self.buffer_data(i)?));
            }
        }
        let json = serde_json::to_vec(&root)
            .map_err(|e| Error::invalid(format!("glTF document cannot be written: {e}")))?;
        let bin = if root.buffers.is_empty() {
            None
        } else {
            Some(self.buffer_data(0)?)
        };
        glb_bytes(&json, bin)
    }

    /// The `.gltf` bytes with every buffer embedded as a `data:` URI (pretty JSON).
    pub fn to_gltf_embedded(&self) -> Result<Vec<u8>> {
        let mut root = self.root.clone();
        for (i, buffer) in root.buffers.iter_mut().enumerate() {
            buffer.uri = Some(data_uri(self.buffer_data(i)?));
        }
        gltf_json_text(&root)
    }

    /// Buffer `i` cut to its declared `byteLength`.
    fn buffer_data(&self, i: usize) -> Result<&[u8]> {
        let declared = self.root.buffers.get(i).map(|b| b.byte_length.0);
        let data = self.buffers.get(i);
        match (declared, data) {
            (Some(len), Some(d)) => usize::try_from(len)
                .ok()
                .and_then(|len| d.get(..len))
                .ok_or_else(|| Error::invalid(format!("buffer {i} is shorter than byteLength"))),
            _ => Err(Error::invalid(format!("buffer {i} has no data"))),
        }
    }

    /// Writes the container, `.glb` or `.gltf` by the path's extension; a `.gltf` gets
    /// embedded buffers. Atomic: a temporary file then a rename.
    pub fn write(&self, path: &Path) -> Result<()> {
        let bytes = match path.extension().and_then(|e| e.to_str()) {
            Some(e) if e.eq_ignore_ascii_case("gltf") => self.to_gltf_embedded()?,
            _ => self.to_glb()?,
        };
        write_atomic(path, &bytes)
    }

    /// Writes a `.gltf` whose buffer `i` lives in `<stem>.bin` (`<stem>_<i>.bin` for
    /// `i > 0`) beside it. Atomic per file.
    pub fn write_gltf_external(&self, path: &Path) -> Result<()> {
        let stem = path
            .file_stem()
            .and_then(|s| s.to_str())
            .ok_or_else(|| Error::invalid(format!("file name of {}", path.display())))?;
        let mut root = self.root.clone();
        let mut files = Vec::new();
        for (i, buffer) in root.buffers.iter_mut().enumerate() {
            let name = if i == 0 {
                format!("{stem}.bin")
            } else {
                format!("{stem}_{i}.bin")
            };
            buffer.uri = Some(name.clone());
            files.push((path.with_file_name(name), self.buffer_data(i)?));
        }
        for (file, data) in files {
            write_atomic(&file, data)?;
        }
        write_atomic(path, &gltf_json_text(&root)?)
    }
}

fn gltf_json_text(root: &gltf_json::Root) -> Result<Vec<u8>> {
    let mut text = serde_json::to_vec_pretty(root)
        .map_err(|e| Error::invalid(format!("glTF document cannot be written: {e}")))?;
    text.push(b'\n');
    Ok(text)
}

/// Bytes of bufferView `view` of `root` over resolved `buffers`, bounds checked.
pub fn view_bytes<'a>(
    root: &gltf_json::Root,
    buffers: &'a [Vec<u8>],
    view: u32,
) -> Result<&'a [u8]> {
    let v = root
        .buffer_views
        .get(view as usize)
        .ok_or_else(|| Error::invalid(format!("bufferView {view} does not exist")))?;
    let buffer = buffers
        .get(v.buffer.value())
        .ok_or_else(|| Error::invalid(format!("bufferView {view}: buffer does not exist")))?;
    let start = v.byte_offset.map_or(0, |o| o.0);
    let end = start.checked_add(v.byte_length.0);
    let declared = root.buffers.get(v.buffer.value()).map(|b| b.byte_length.0);
    match (end, declared) {
        (Some(end), Some(declared)) if end <= declared => {
            let range = usize::try_from(start).ok()..usize::try_from(end).ok();
            match range {
                std::ops::Range {
                    start: Some(s),
                    end: Some(e),
                } => buffer.get(s..e).ok_or_else(|| {
                    Error::invalid(format!("bufferView {view} reaches past its buffer's data"))
                }),
                _ => Err(Error::invalid(format!("bufferView {view} range"))),
            }
        }
        _ => Err(Error::invalid(format!(
            "bufferView {view} reaches past its buffer's byteLength"
        ))),
    }
}

/// Reads a whole file after checking its size against `max`.
pub fn read_file_limited(path: &Path, max: u64) -> Result<Vec<u8>> {
    let meta = fs::metadata(path).map_err(|e| Error::io(path, e))?;
    Limits::check("file size", meta.len(), max).map_err(|e| name_file(e, path))?;
    fs::read(path).map_err(|e| Error::io(path, e))
}

/// Prefixes a non-IO error with the file it came from.
pub(crate) fn name_file(e: Error, path: &Path) -> Error {
    let p = path.display();
    match e {
        Error::Invalid { what } => Error::Invalid {
            what: format!("{what} (in {p})"),
        },
        Error::NotSupported { what } => Error::NotSupported {
            what: format!("{what} (in {p})"),
        },
        Error::LimitExceeded { what, value, limit } => Error::LimitExceeded {
            what: format!("{what} (in {p})"),
            value,
            limit,
        },
        io @ Error::Io { .. } => io,
    }
}

/// Writes `bytes` to a temporary file beside `path`, syncs it, then renames it over
/// `path`, so `path` is never left partially written.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let name = path.file_name().ok_or_else(|| {
        Error::invalid(format!("output path {} has no file name", path.display()))
    })?;
    let mut tmp_name = std::ffi::OsString::from(".");
    tmp_name.push(name);
    tmp_name.push(format!(".{}.tmp", std::process::id()));
    let tmp = dir.join(tmp_name);
    let result = (|| {
        let mut f = fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        fs::rename(&tmp, path)
    })();
    result.map_err(|e| {
        let _ = fs::remove_file(&tmp);
        Error::io(path, e)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_round_trip() {
        for n in 0..20u8 {
            let data: Vec<u8> = (0..n).map(|i| i.wrapping_mul(37)).collect();
            assert_eq!(base64_decode(&base64_encode(&data)).unwrap(), data);
        }
        assert_eq!(base64_encode(b"Man"), "TWFu");
        assert_eq!(base64_encode(b"Ma"), "TWE=");
    }

    #[test]
    fn glb_layout_and_every_prefix() {
        let glb = glb_bytes(
            b"{\"asset\":{\"version\":\"2.0\"},\"a\":1}",
            Some(&[1, 2, 3]),
        )
        .unwrap();
        assert_eq!(glb.len() % 4, 0);
        let parsed = parse_glb(&glb, &Limits::default()).unwrap();
        assert_eq!(parsed.bin.unwrap(), &[1, 2, 3, 0]);
        assert!(parsed.json.ends_with(b"  "));
        for n in 0..glb.len() {
            assert!(
                parse_glb(&glb[..n], &Limits::default()).is_err(),
                "prefix {n}"
            );
        }
        let mut trailing = glb.clone();
        trailing.extend_from_slice(&[0; 4]);
        assert_eq!(
            parse_glb(&trailing, &Limits::default()).unwrap_err().code,
            "GLB_INVALID_HEADER"
        );
    }

    #[test]
    fn numbers_survive_read_and_rewrite_digit_for_digit() {
        // f32 values widened to f64, as the quantisation scales and offsets are written: a
        // JSON parser that is not correctly rounded reads some of them one unit in the last
        // place off (-0.09930949658155441 was), and the rewrite then prints other digits.
        let mut values: Vec<f64> = vec![-0.09930949658155441, 0.07881763577461243];
        let mut x = 0x9E37_79B9u32;
        for _ in 0..20_000 {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            let v = f32::from_bits(x);
            if v.is_finite() {
                values.push(f64::from(v));
            }
        }
        let array = serde_json::to_string(&values).unwrap();
        let json = format!(
            r#"{{"asset":{{"version":"2.0"}},"extensions":{{"EXT_test":{{"v":{array}}}}}}}"#
        );
        let c = Container::from_slice(json.as_bytes(), None, &Limits::default()).unwrap();
        let glb = c.to_glb().unwrap();
        let parsed = parse_glb(&glb, &Limits::default()).unwrap();
        let text = std::str::from_utf8(parsed.json).unwrap();
        assert!(text.contains(&array), "numbers changed in {text}");
    }
}
