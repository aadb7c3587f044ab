//! The validator: reports every problem of an asset in one pass as [`Issue`]s with
//! stable codes (table in [`codes`]) and JSON pointers.
//!
//! It never panics and never allocates beyond [`Limits`]: sizes are checked before
//! decoding, and each check goes on after a failure wherever later checks still mean
//! something. Pointers are built lazily, only when an issue is reported.

pub mod codes;

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use gltf_json as json;
use serde::Serialize;
use serde_json::Value;

pub use codes::{code_info, CodeInfo, Severity, CODES};

use crate::architecture::{architecture_tensors, renderer_problems};
use crate::asset::{
    bound_primitive_values, fallback_problem, root_extension_value, FallbackProblem,
    TEXTURE_CHANNELS,
};
use crate::container::{self, parse_glb, parse_root, resolve_buffer, Problem};
use crate::error::{Error, Result};
use crate::exr_codec::{decode_level_halves, header_problems, read_level_header, LevelExpect};
use crate::limits::Limits;
use crate::model::{self, NeuralTexture, PrimitiveExtension, Renderer};
use crate::EXTENSION_NAME;

/// One problem found by the validator.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct Issue {
    /// Stable code from [`CODES`].
    pub code: &'static str,
    /// Severity (from the code table).
    pub severity: Severity,
    /// JSON pointer (RFC 6901) to the offending value; empty for the whole file.
    pub pointer: String,
    /// Human-readable explanation.
    pub message: String,
}

/// Everything the validator found.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Report {
    /// Issues in the order found.
    pub issues: Vec<Issue>,
}

impl Report {
    /// Number of issues of `severity`.
    pub fn count(&self, severity: Severity) -> usize {
        self.issues
            .iter()
            .filter(|i| i.severity == severity)
            .count()
    }

    /// Whether any issue is an error.
    pub fn has_errors(&self) -> bool {
        self.count(Severity::Error) > 0
    }

    /// The distinct codes reported, sorted.
    pub fn codes(&self) -> BTreeSet<&'static str> {
        self.issues.iter().map(|i| i.code).collect()
    }
}

/// A JSON pointer under construction: a chain of segments on the stack, rendered to a
/// string only when an issue is reported.
#[derive(Clone, Copy, Debug)]
pub struct Ptr<'a> {
    parent: Option<&'a Ptr<'a>>,
    seg: Seg<'a>,
}

#[derive(Clone, Copy, Debug)]
enum Seg<'a> {
    Root,
    Key(&'a str),
    Index(usize),
}

impl<'a> Ptr<'a> {
    /// The document root (`""`).
    pub const ROOT: Ptr<'static> = Ptr {
        parent: None,
        seg: Seg::Root,
    };

    /// Child `key` of this object.
    pub fn key(&'a self, key: &'a str) -> Ptr<'a> {
        Ptr {
            parent: Some(self),
            seg: Seg::Key(key),
        }
    }

    /// Element `index` of this array.
    pub fn index(&'a self, index: usize) -> Ptr<'a> {
        Ptr {
            parent: Some(self),
            seg: Seg::Index(index),
        }
    }

    /// Renders the pointer, escaping `~` and `/` as RFC 6901 requires.
    pub fn render(&self) -> String {
        let mut segs = Vec::new();
        let mut at = Some(self);
        while let Some(p) = at {
            segs.push(p.seg);
            at = p.parent;
        }
        let mut out = String::new();
        for s in segs.iter().rev() {
            match s {
                Seg::Root => {}
                Seg::Key(k) => {
                    out.push('/');
                    out.push_str(&k.replace('~', "~0").replace('/', "~1"));
                }
                Seg::Index(i) => {
                    out.push('/');
                    out.push_str(&i.to_string());
                }
            }
        }
        out
    }
}

/// Converts a gltf-json path (`meshes[0].attributes["POSITION"]`) to a JSON pointer.
fn gltf_path_to_pointer(path: &str) -> String {
    let path = path.split(" = ").next().unwrap_or(path);
    let mut out = String::new();
    let mut token = String::new();
    let flush = |out: &mut String, token: &mut String| {
        if !token.is_empty() {
            out.push('/');
            out.push_str(&token.replace('~', "~0").replace('/', "~1"));
            token.clear();
        }
    };
    let mut chars = path.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '.' => flush(&mut out, &mut token),
            '[' => {
                flush(&mut out, &mut token);
                let quoted = chars.peek() == Some(&'"');
                if quoted {
                    chars.next();
                }
                for d in chars.by_ref() {
                    if (quoted && d == '"') || (!quoted && d == ']') {
                        break;
                    }
                    token.push(d);
                }
                if quoted {
                    chars.next(); // the closing ']'
                }
                out.push('/');
                out.push_str(&token.replace('~', "~0").replace('/', "~1"));
                token.clear();
            }
            c => token.push(c),
        }
    }
    flush(&mut out, &mut token);
    out
}

struct Ctx<'l> {
    limits: &'l Limits,
    issues: Vec<Issue>,
}

impl Ctx<'_> {
    fn report(&mut self, code: &'static str, ptr: &Ptr<'_>, message: impl Into<String>) {
        self.report_at(code, ptr.render(), message);
    }

    fn report_at(&mut self, code: &'static str, pointer: String, message: impl Into<String>) {
        let severity = code_info(code).map_or(Severity::Error, |c| c.severity);
        self.issues.push(Issue {
            code,
            severity,
            pointer,
            message: message.into(),
        });
    }

    fn problem(&mut self, p: Problem, ptr: &Ptr<'_>) {
        self.report(p.code, ptr, p.message());
    }
}

/// Validates a file (`.glb` or `.gltf`; external buffers resolve beside it).
///
/// `Err` only when the file itself cannot be read; every problem of its content is an
/// issue in the report.
pub fn validate_file(path: &Path, limits: &Limits) -> Result<Report> {
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if meta.len() > limits.max_file_bytes {
        let mut ctx = Ctx {
            limits,
            issues: Vec::new(),
        };
        ctx.report(
            "LIMIT_EXCEEDED",
            &Ptr::ROOT,
            format!(
                "file is {} bytes, above the limit of {}",
                meta.len(),
                limits.max_file_bytes
            ),
        );
        return Ok(Report { issues: ctx.issues });
    }
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    Ok(validate_slice(&bytes, path.parent(), limits))
}

/// Validates an asset held in memory; external buffers resolve against `base_dir`.
pub fn validate_slice(bytes: &[u8], base_dir: Option<&Path>, limits: &Limits) -> Report {
    let mut ctx = Ctx {
        limits,
        issues: Vec::new(),
    };
    validate_into(&mut ctx, bytes, base_dir);
    Report { issues: ctx.issues }
}

fn validate_into(ctx: &mut Ctx<'_>, bytes: &[u8], base_dir: Option<&Path>) {
    let root_ptr = Ptr::ROOT;
    let (json_bytes, bin) = if container::is_glb(bytes) {
        match parse_glb(bytes, ctx.limits) {
            Ok(g) => (g.json, g.bin),
            Err(p) => return ctx.problem(p, &root_ptr),
        }
    } else if bytes.len() as u64 > ctx.limits.max_json_bytes {
        return ctx.report(
            "LIMIT_EXCEEDED",
            &root_ptr,
            format!(
                "JSON is {} bytes, above the limit of {}",
                bytes.len(),
                ctx.limits.max_json_bytes
            ),
        );
    } else if !bytes.is_empty() && b"glTF".starts_with(bytes) {
        return ctx.report("GLB_TRUNCATED", &root_ptr, "file ends inside the GLB magic");
    } else if std::str::from_utf8(bytes).is_err() {
        return ctx.report(
            "GLB_INVALID_HEADER",
            &root_ptr,
            "neither a GLB (magic `glTF`) nor JSON text (not UTF-8)",
        );
    } else {
        (bytes, None)
    };
    let root = match parse_root(json_bytes) {
        Ok(r) => r,
        Err(p) => return ctx.problem(p, &root_ptr),
    };
    core_checks(ctx, &root);
    let buffers: Vec<Option<Vec<u8>>> = (0..root.buffers.len())
        .map(
            |i| match resolve_buffer(&root, i, bin, base_dir, ctx.limits) {
                Ok(b) => Some(b),
                Err(p) => {
                    let bp = root_ptr.key("buffers");
                    ctx.problem(p, &bp.index(i));
                    None
                }
            },
        )
        .collect();
    range_checks(ctx, &root);
    let doc = Doc {
        root: &root,
        buffers: &buffers,
    };
    extension_checks(ctx, &doc);
}

/// Only the core glTF checks (indices, enumerations, required fields, bufferView and
/// accessor ranges) of a parsed document; [`crate::read_asset`] refuses documents with
/// any of these issues.
pub fn validate_core(root: &json::Root, limits: &Limits) -> Report {
    let mut ctx = Ctx {
        limits,
        issues: Vec::new(),
    };
    core_checks(&mut ctx, root);
    range_checks(&mut ctx, root);
    Report { issues: ctx.issues }
}

/// gltf-json's own validation: index ranges, enums, required fields.
fn core_checks(ctx: &mut Ctx<'_>, root: &json::Root) {
    use json::validation::{Error as VErr, Validate};
    // gltf-json 1.4 indexes `accessors[POSITION]` in a validate hook without a bounds
    // check (found by tests/fuzz_smoke.rs), so such indices are reported here and
    // removed from the copy it validates.
    let positions = json::validation::Checked::Valid(json::mesh::Semantic::Positions);
    let mut patched: Option<json::Root> = None;
    let mut removed = BTreeSet::new();
    let meshes = Ptr::ROOT.key("meshes");
    for (mi, mesh) in root.meshes.iter().enumerate() {
        for (pi, prim) in mesh.primitives.iter().enumerate() {
            let Some(a) = prim.attributes.get(&positions) else {
                continue;
            };
            if a.value() < root.accessors.len() {
                continue;
            }
            let mp = meshes.index(mi);
            let pp = mp.key("primitives");
            let ip = pp.index(pi);
            let ap = ip.key("attributes");
            ctx.report(
                "INDEX_OUT_OF_RANGE",
                &ap.key("POSITION"),
                format!("accessor {} does not exist", a.value()),
            );
            removed.insert(format!("/meshes/{mi}/primitives/{pi}/attributes/POSITION"));
            let copy = patched.get_or_insert_with(|| root.clone());
            copy.meshes[mi].primitives[pi].attributes.remove(&positions);
        }
    }
    let root = patched.as_ref().unwrap_or(root);
    let mut found: Vec<(String, VErr)> = Vec::new();
    root.validate(
        root,
        json::Path::new,
        &mut |path: &dyn Fn() -> json::Path, e| {
            found.push((path().as_str().to_string(), e));
        },
    );
    for (path, e) in found {
        if path.starts_with("extensionsRequired") {
            continue; // our own rule below; other extensions are not ours to judge
        }
        let pointer = gltf_path_to_pointer(&path);
        if removed
            .iter()
            .any(|r: &String| pointer.starts_with(r.as_str()))
        {
            continue; // already reported as INDEX_OUT_OF_RANGE above
        }
        let (code, what) = match e {
            VErr::IndexOutOfBounds => ("INDEX_OUT_OF_RANGE", "index refers to a missing object"),
            VErr::Invalid => ("JSON_SCHEMA", "invalid value"),
            VErr::Missing => ("JSON_SCHEMA", "required value is missing"),
            VErr::Oversize => ("LIMIT_EXCEEDED", "size exceeds this platform's limits"),
            VErr::Unsupported => ("JSON_SCHEMA", "unsupported value"),
        };
        ctx.report_at(code, pointer, format!("{what} at {path}"));
    }
}

/// bufferViews within buffers, accessors within bufferViews.
fn range_checks(ctx: &mut Ctx<'_>, root: &json::Root) {
    let views_ptr = Ptr::ROOT.key("bufferViews");
    for (i, v) in root.buffer_views.iter().enumerate() {
        let Some(buffer) = root.buffers.get(v.buffer.value()) else {
            continue;
        };
        let start = v.byte_offset.map_or(0, |o| o.0);
        let end = start.checked_add(v.byte_length.0);
        if end.is_none_or(|e| e > buffer.byte_length.0) {
            ctx.report(
                "BUFFER_VIEW_OUT_OF_RANGE",
                &views_ptr.index(i),
                format!(
                    "bufferView {i} covers bytes {start}..{} of buffer {} with byteLength {}",
                    start as u128 + v.byte_length.0 as u128,
                    v.buffer.value(),
                    buffer.byte_length.0
                ),
            );
        }
    }
    let acc_ptr = Ptr::ROOT.key("accessors");
    for (i, a) in root.accessors.iter().enumerate() {
        let (Some(vi), json::validation::Checked::Valid(ct), json::validation::Checked::Valid(ty)) =
            (a.buffer_view, &a.component_type, &a.type_)
        else {
            continue;
        };
        let Some(view) = root.buffer_views.get(vi.value()) else {
            continue;
        };
        if a.count.0 == 0 {
            continue;
        }
        let elem = ct.0.size() as u128 * ty.multiplicity() as u128;
        let stride = view.byte_stride.map_or(elem, |s| s.0 as u128);
        let need = u128::from(a.byte_offset.map_or(0, |o| o.0))
            + stride * (u128::from(a.count.0) - 1)
            + elem;
        if need > u128::from(view.byte_length.0) {
            ctx.report(
                "BUFFER_VIEW_OUT_OF_RANGE",
                &acc_ptr.index(i),
                format!(
                    "accessor {i} needs {need} bytes, bufferView {} has {}",
                    vi.value(),
                    view.byte_length.0
                ),
            );
        }
    }
}

/// A view's bytes and its offset in the buffer, `None` if the buffer failed to load, or
/// a code and message.
type ViewResult<'a> = std::result::Result<Option<(&'a [u8], u64)>, (&'static str, String)>;

struct Doc<'a> {
    root: &'a json::Root,
    buffers: &'a [Option<Vec<u8>>],
}

impl Doc<'_> {
    /// Bytes of a bufferView: `Ok(None)` if its buffer failed to load (already reported),
    /// `Err` with a code when the index or range is bad.
    fn view(&self, view: u32) -> ViewResult<'_> {
        let v = self.root.buffer_views.get(view as usize).ok_or_else(|| {
            (
                "INDEX_OUT_OF_RANGE",
                format!("bufferView {view} does not exist"),
            )
        })?;
        let Some(Some(data)) = self.buffers.get(v.buffer.value()) else {
            return Ok(None);
        };
        let offset = v.byte_offset.map_or(0, |o| o.0);
        let slice = offset
            .checked_add(v.byte_length.0)
            .filter(|&e| {
                self.root
                    .buffers
                    .get(v.buffer.value())
                    .is_some_and(|b| e <= b.byte_length.0)
            })
            .and_then(|e| data.get(usize::try_from(offset).ok()?..usize::try_from(e).ok()?))
            .ok_or_else(|| {
                (
                    "BUFFER_VIEW_OUT_OF_RANGE",
                    format!("bufferView {view} reaches past its buffer"),
                )
            })?;
        Ok(Some((slice, offset)))
    }
}

fn deserialize<T: serde::de::DeserializeOwned>(v: &Value) -> std::result::Result<T, String> {
    T::deserialize(v).map_err(|e| e.to_string())
}

fn extension_checks(ctx: &mut Ctx<'_>, doc: &Doc<'_>) {
    let root = doc.root;
    let ext_value = root_extension_value(root);
    let bound = bound_primitive_values(root);
    if ext_value.is_none() && bound.is_empty() {
        return;
    }
    if !root.extensions_used.iter().any(|e| e == EXTENSION_NAME) {
        ctx.report(
            "EXTENSION_NOT_USED",
            &Ptr::ROOT.key("extensionsUsed"),
            format!("`{EXTENSION_NAME}` is used but not listed in extensionsUsed"),
        );
    }
    let req = Ptr::ROOT.key("extensionsRequired");
    for (i, e) in root.extensions_required.iter().enumerate() {
        if e == EXTENSION_NAME {
            ctx.report(
                "EXTENSION_REQUIRED",
                &req.index(i),
                format!(
                    "`{EXTENSION_NAME}` must not be required: viewers without it show the fallback"
                ),
            );
        }
    }
    let exts = Ptr::ROOT.key("extensions");
    let ext_ptr = exts.key(EXTENSION_NAME);
    let obj = match ext_value {
        None => {
            ctx.report(
                "JSON_SCHEMA",
                &exts,
                format!(
                    "mesh primitives use `{EXTENSION_NAME}` but the root has no such extension object"
                ),
            );
            // The indices name nothing; the checks that do not need the root still apply.
            return check_primitives(ctx, root, &bound, None);
        }
        Some(Value::Object(obj)) => obj,
        Some(_) => {
            return ctx.report(
                "JSON_SCHEMA",
                &ext_ptr,
                "the extension object must be an object",
            )
        }
    };
    match obj.get("version").map(Value::as_u64) {
        None | Some(None) => {
            return ctx.report(
                "JSON_SCHEMA",
                &ext_ptr.key("version"),
                "version must be a non-negative integer",
            )
        }
        Some(Some(v)) if v != u64::from(model::VERSION) => {
            return ctx.report(
                "VERSION_UNSUPPORTED",
                &ext_ptr.key("version"),
                format!(
                    "version {v} is not supported (this validator knows version {})",
                    model::VERSION
                ),
            )
        }
        _ => {}
    }
    let textures: Vec<Option<NeuralTexture>> =
        array_of(ctx, obj.get("neuralTextures"), &ext_ptr, "neuralTextures");
    let renderers: Vec<Option<Renderer>> =
        array_of(ctx, obj.get("renderers"), &ext_ptr, "renderers");
    let tex_ptr = ext_ptr.key("neuralTextures");
    let mut texel_values = 0u64;
    for (i, t) in textures.iter().enumerate() {
        if let Some(t) = t {
            check_texture(ctx, doc, t, &tex_ptr.index(i), &mut texel_values);
        }
    }
    let ren_ptr = ext_ptr.key("renderers");
    let mut weight_elements = 0u64;
    for (i, r) in renderers.iter().enumerate() {
        if let Some(r) = r {
            check_renderer(ctx, doc, r, &ren_ptr.index(i), &mut weight_elements);
        }
    }
    check_primitives(ctx, root, &bound, Some((&textures, &renderers)));
}

/// Deserializes each element of an optional array on its own, so one bad element does
/// not hide the others.
fn array_of<T: serde::de::DeserializeOwned>(
    ctx: &mut Ctx<'_>,
    v: Option<&Value>,
    parent: &Ptr<'_>,
    key: &str,
) -> Vec<Option<T>> {
    let ptr = parent.key(key);
    match v {
        None => Vec::new(),
        Some(Value::Array(items)) => items
            .iter()
            .enumerate()
            .map(|(i, item)| match deserialize::<T>(item) {
                Ok(t) => Some(t),
                Err(e) => {
                    ctx.report("JSON_SCHEMA", &ptr.index(i), e);
                    None
                }
            })
            .collect(),
        Some(_) => {
            ctx.report("JSON_SCHEMA", &ptr, format!("{key} must be an array"));
            Vec::new()
        }
    }
}

fn check_texture(
    ctx: &mut Ctx<'_>,
    doc: &Doc<'_>,
    t: &NeuralTexture,
    ptr: &Ptr<'_>,
    texel_values: &mut u64,
) {
    let limits = ctx.limits;
    let mut channels_ok = true;
    if !TEXTURE_CHANNELS.contains(&t.channels) {
        ctx.report(
            "TEXTURE_CHANNELS_RANGE",
            &ptr.key("channels"),
            format!(
                "channels is {}, must be in {}..={}",
                t.channels,
                TEXTURE_CHANNELS.start(),
                TEXTURE_CHANNELS.end()
            ),
        );
        channels_ok = false;
    } else if t.channels > limits.max_channels {
        ctx.report(
            "LIMIT_EXCEEDED",
            &ptr.key("channels"),
            format!(
                "{} channels, above the limit of {}",
                t.channels, limits.max_channels
            ),
        );
        channels_ok = false;
    }
    if let Some(s) = t.sampler {
        if s as usize >= doc.root.samplers.len() {
            ctx.report(
                "INDEX_OUT_OF_RANGE",
                &ptr.key("sampler"),
                format!("sampler {s} does not exist"),
            );
        }
    }
    if let Some(vd) = &t.view_dependence {
        let vp = ptr.key("viewDependence");
        if vd.basis != model::BASIS_SPHERICAL_HARMONICS {
            ctx.report(
                "SH_DEGREE_UNSUPPORTED",
                &vp.key("basis"),
                format!("basis `{}` is not sphericalHarmonics", vd.basis),
            );
        } else if vd.degree > 3 {
            ctx.report(
                "SH_DEGREE_UNSUPPORTED",
                &vp.key("degree"),
                format!("degree {} is above 3", vd.degree),
            );
        } else if u64::from(vd.first_channel) + vd.coefficient_count() > u64::from(t.channels) {
            ctx.report(
                "SH_CHANNELS_OUT_OF_RANGE",
                &vp.key("firstChannel"),
                format!(
                    "channels {}..{} are modulated but the texture has {}",
                    vd.first_channel,
                    u64::from(vd.first_channel) + vd.coefficient_count(),
                    t.channels
                ),
            );
        }
    }
    let lp = ptr.key("levels");
    if t.levels.is_empty() {
        ctx.report(
            "TEXTURE_NO_LEVELS",
            &lp,
            "a neural texture needs at least one level",
        );
        return;
    }
    if t.levels.len() as u64 > u64::from(limits.max_levels) {
        ctx.report(
            "LIMIT_EXCEEDED",
            &lp,
            format!(
                "{} levels, above the limit of {}",
                t.levels.len(),
                limits.max_levels
            ),
        );
        return;
    }
    let mut prev: Option<(u32, u32)> = None;
    for (li, l) in t.levels.iter().enumerate() {
        let p = lp.index(li);
        let png = l.mime_type == model::LEVEL_MIME_TYPE_PNG;
        let known_mime = png || l.mime_type == model::LEVEL_MIME_TYPE;
        if !known_mime {
            ctx.report(
                "TEXTURE_MIME_TYPE",
                &p.key("mimeType"),
                format!(
                    "mimeType `{}`, expected `image/x-exr` or `image/png`",
                    l.mime_type
                ),
            );
        }
        // The schema's if/then: quantization exactly on PNG levels.
        let mut quant_ok = true;
        if known_mime && png != l.quantization.is_some() {
            ctx.report(
                "JSON_SCHEMA",
                &p,
                if png {
                    "an image/png level needs a quantization object"
                } else {
                    "quantization is only defined on image/png levels"
                },
            );
            quant_ok = false;
        }
        if let (true, Some(q)) = (channels_ok, &l.quantization) {
            let qp = p.key("quantization");
            for (code, field, msg) in crate::quant::quantization_problems(q, t.channels) {
                ctx.report(code, &qp.key(field), msg);
                quant_ok = false;
            }
        }
        if l.width == 0 || l.height == 0 {
            ctx.report(
                "JSON_SCHEMA",
                &p,
                format!("level size {}x{} has a zero side", l.width, l.height),
            );
            continue;
        }
        if l.width.max(l.height) > limits.max_texture_side {
            ctx.report(
                "LIMIT_EXCEEDED",
                &p,
                format!(
                    "level {}x{} exceeds the side limit {}",
                    l.width, l.height, limits.max_texture_side
                ),
            );
            continue;
        }
        if let Some((pw, ph)) = prev {
            if l.width > pw || l.height > ph {
                ctx.report(
                    "TEXTURE_LEVEL_ORDER",
                    &p,
                    format!(
                        "level {}x{} is larger than the level before it ({pw}x{ph})",
                        l.width, l.height
                    ),
                );
            }
        }
        prev = Some((l.width, l.height));
        let bytes = match doc.view(l.buffer_view) {
            Ok(Some((b, _))) => b,
            Ok(None) => continue,
            Err((code, msg)) => {
                ctx.report(code, &p.key("bufferView"), msg);
                continue;
            }
        };
        if !channels_ok || !known_mime || !quant_ok {
            continue;
        }
        let values = u64::from(l.width) * u64::from(l.height) * u64::from(t.channels);
        *texel_values = texel_values.saturating_add(values);
        if *texel_values > limits.max_total_texel_values {
            ctx.report(
                "LIMIT_EXCEEDED",
                &p,
                format!(
                    "{} texel values so far, above the limit of {}",
                    texel_values, limits.max_total_texel_values
                ),
            );
            continue;
        }
        let expect = LevelExpect {
            width: l.width,
            height: l.height,
            channels: t.channels,
        };
        if let Some(q) = &l.quantization {
            if let Err(pr) = crate::quant::decode_png_level(bytes, expect, q, limits) {
                ctx.problem(pr, &p.key("bufferView"));
            }
            continue;
        }
        let header = match read_level_header(bytes) {
            Ok(h) => h,
            Err(pr) => {
                ctx.problem(pr, &p.key("bufferView"));
                continue;
            }
        };
        let problems = header_problems(&header, expect);
        if !problems.is_empty() {
            for pr in problems {
                ctx.problem(pr, &p.key("bufferView"));
            }
            continue;
        }
        match decode_level_halves(bytes, expect, limits) {
            Ok(h) => {
                let bad = h.iter().filter(|v| !v.is_finite()).count();
                if bad > 0 {
                    ctx.report(
                        "EXR_NON_FINITE",
                        &p.key("bufferView"),
                        format!("{bad} half values are NaN or infinite"),
                    );
                }
            }
            Err(pr) => ctx.problem(pr, &p.key("bufferView")),
        }
    }
}

fn check_renderer(
    ctx: &mut Ctx<'_>,
    doc: &Doc<'_>,
    r: &Renderer,
    ptr: &Ptr<'_>,
    weight_elements: &mut u64,
) {
    let limits = ctx.limits;
    for p in renderer_problems(r) {
        let field = match p.code {
            "RENDERER_UNKNOWN_ARCHITECTURE" => ptr.key("architecture"),
            "RENDERER_OUTPUT_CHANNELS" => ptr.key("outputChannels"),
            _ => *ptr,
        };
        ctx.problem(p, &field);
    }
    let required: Option<BTreeMap<String, Vec<u32>>> = architecture_tensors(r)
        .ok()
        .map(|v| v.into_iter().collect());
    let wp = ptr.key("weights");
    if r.weights.len() as u64 > u64::from(limits.max_tensors) {
        return ctx.report(
            "LIMIT_EXCEEDED",
            &wp,
            format!(
                "{} tensors, above the limit of {}",
                r.weights.len(),
                limits.max_tensors
            ),
        );
    }
    let mut seen = BTreeSet::new();
    for (j, w) in r.weights.iter().enumerate() {
        let p = wp.index(j);
        if !seen.insert(w.name.as_str()) {
            ctx.report(
                "WEIGHTS_UNEXPECTED",
                &p.key("name"),
                format!("tensor `{}` appears more than once", w.name),
            );
        }
        if let Some(req) = &required {
            match req.get(&w.name) {
                None => ctx.report(
                    "WEIGHTS_UNEXPECTED",
                    &p.key("name"),
                    format!(
                        "architecture `{}` has no tensor `{}`",
                        r.architecture, w.name
                    ),
                ),
                Some(shape) if *shape != w.shape => ctx.report(
                    "WEIGHTS_SHAPE_MISMATCH",
                    &p.key("shape"),
                    format!(
                        "tensor `{}` has shape {:?}, the architecture requires {shape:?}",
                        w.name, w.shape
                    ),
                ),
                Some(_) => {}
            }
        }
        if w.shape.len() as u64 > u64::from(limits.max_tensor_rank) {
            ctx.report(
                "LIMIT_EXCEEDED",
                &p.key("shape"),
                format!("rank {} above the limit", w.shape.len()),
            );
            continue;
        }
        if !w.dtype.is_known() {
            ctx.report(
                "WEIGHTS_DTYPE_UNKNOWN",
                &p.key("dtype"),
                format!("dtype `{}` is not f16, f32, int8 or int4", w.dtype),
            );
            continue;
        }
        let Some(count) = w.element_count() else {
            ctx.report("LIMIT_EXCEEDED", &p.key("shape"), "element count overflows");
            continue;
        };
        *weight_elements = weight_elements.saturating_add(count);
        if *weight_elements > limits.max_weight_elements {
            ctx.report(
                "LIMIT_EXCEEDED",
                &p.key("shape"),
                format!(
                    "{} weight elements so far, above the limit of {}",
                    weight_elements, limits.max_weight_elements
                ),
            );
            continue;
        }
        let (view, view_offset) = match doc.view(w.buffer_view) {
            Ok(Some(v)) => v,
            Ok(None) => continue,
            Err((code, msg)) => {
                ctx.report(code, &p.key("bufferView"), msg);
                continue;
            }
        };
        if w.byte_offset % 4 != 0 || view_offset % 4 != 0 {
            ctx.report(
                "WEIGHTS_MISALIGNED",
                &p.key("byteOffset"),
                format!(
                    "tensor `{}` starts at byteOffset {} in a bufferView at buffer offset {view_offset}; both must be multiples of 4",
                    w.name, w.byte_offset
                ),
            );
        }
        // count <= max_weight_elements, so this cannot overflow.
        let len = w.byte_length().unwrap_or(u64::MAX);
        let bytes = w
            .byte_offset
            .checked_add(len)
            .filter(|&e| e <= view.len() as u64)
            .and_then(|e| view.get(usize::try_from(w.byte_offset).ok()?..usize::try_from(e).ok()?));
        let Some(bytes) = bytes else {
            ctx.report(
                "BUFFER_VIEW_OUT_OF_RANGE",
                &p.key("byteOffset"),
                format!(
                    "tensor `{}` needs bytes {}..{} of a {}-byte bufferView",
                    w.name,
                    w.byte_offset,
                    u128::from(w.byte_offset) + u128::from(len),
                    view.len()
                ),
            );
            continue;
        };
        let crc = crate::weights::crc32(bytes);
        if crc != w.crc32 {
            ctx.report(
                "WEIGHTS_CHECKSUM_MISMATCH",
                &p.key("crc32"),
                format!(
                    "tensor `{}` has CRC-32 {crc}, crc32 says {}",
                    w.name, w.crc32
                ),
            );
        }
        if w.dtype.integer_top().is_some() {
            let scales = crate::weights::int_scales(bytes, &w.shape, &w.dtype).unwrap_or_default();
            let bad = scales
                .iter()
                .filter(|s| !(s.is_finite() && **s > 0.0))
                .count();
            if bad > 0 {
                ctx.report(
                    "WEIGHTS_SCALE_INVALID",
                    &p,
                    format!(
                        "{} tensor `{}` has {bad} row scales that are not finite and above 0",
                        w.dtype, w.name
                    ),
                );
            } else {
                let overflows = crate::weights::int_non_finite(bytes, &w.shape, &w.dtype);
                if overflows > 0 {
                    ctx.report(
                        "WEIGHTS_NON_FINITE",
                        &p,
                        format!(
                            "{} tensor `{}` has {overflows} values whose scale * q overflows f32",
                            w.dtype, w.name
                        ),
                    );
                }
            }
            continue;
        }
        let non_finite = match w.dtype {
            model::DType::F16 => bytes
                .chunks_exact(2)
                .filter(|b| !half::f16::from_le_bytes([b[0], b[1]]).is_finite())
                .count(),
            _ => bytes
                .chunks_exact(4)
                .filter(|b| !f32::from_le_bytes([b[0], b[1], b[2], b[3]]).is_finite())
                .count(),
        };
        if non_finite > 0 {
            ctx.report(
                "WEIGHTS_NON_FINITE",
                &p,
                format!(
                    "tensor `{}` holds {non_finite} NaN or infinite values",
                    w.name
                ),
            );
        }
    }
    if let Some(req) = &required {
        for (name, shape) in req {
            if !seen.contains(name.as_str()) {
                ctx.report(
                    "WEIGHTS_MISSING",
                    &wp,
                    format!(
                        "architecture `{}` requires tensor `{name}` of shape {shape:?}",
                        r.architecture
                    ),
                );
            }
        }
    }
}

/// The neural textures and renderers of the root object (`None` where an element failed
/// its schema check).
type RootArrays<'a> = (&'a [Option<NeuralTexture>], &'a [Option<Renderer>]);

/// The binding objects on mesh primitives: their schema, fallback material and texture
/// coordinates, and, when the root object is there (`arrays`), their indices and pairing.
fn check_primitives(
    ctx: &mut Ctx<'_>,
    root: &json::Root,
    bound: &[(usize, usize, &Value)],
    arrays: Option<RootArrays<'_>>,
) {
    let meshes = Ptr::ROOT.key("meshes");
    let materials = Ptr::ROOT.key("materials");
    // A fallback material shared by several bound primitives is reported once.
    let mut reported_materials = BTreeSet::new();
    for &(mi, pi, v) in bound {
        let mp = meshes.index(mi);
        let pp = mp.key("primitives");
        let p = pp.index(pi);
        let ep = p.key("extensions");
        let ep = ep.key(EXTENSION_NAME);
        let prim = &root.meshes[mi].primitives[pi];
        if let Some(problem) = fallback_problem(root, prim) {
            match problem {
                FallbackProblem::NoMaterial => ctx.report(
                    "FALLBACK_MISSING",
                    &p,
                    format!("{problem}: a primitive with the extension needs an unlit fallback material"),
                ),
                FallbackProblem::NoBaseColorTexture(i) | FallbackProblem::NoUnlit(i) => {
                    if reported_materials.insert(i) {
                        let m = materials.index(i);
                        let at = match problem {
                            FallbackProblem::NoBaseColorTexture(_) => m.key("pbrMetallicRoughness"),
                            _ => m,
                        };
                        ctx.report("FALLBACK_MISSING", &at, problem.to_string());
                    }
                }
            }
        }
        let b: PrimitiveExtension = match deserialize(v) {
            Ok(b) => b,
            Err(e) => {
                ctx.report("JSON_SCHEMA", &ep, e);
                continue;
            }
        };
        let n = b.tex_coord;
        let has = prim.attributes.keys().any(|k| {
            matches!(k, json::validation::Checked::Valid(json::mesh::Semantic::TexCoords(t)) if *t == n)
        });
        if !has {
            ctx.report(
                "TEXCOORD_MISSING",
                &p.key("attributes"),
                format!("the binding addresses TEXCOORD_{n}, which this primitive lacks"),
            );
        }
        let Some((textures, renderers)) = arrays else {
            continue;
        };
        let t = textures.get(b.neural_texture as usize);
        let r = renderers.get(b.renderer as usize);
        if t.is_none() {
            ctx.report(
                "INDEX_OUT_OF_RANGE",
                &ep.key("neuralTexture"),
                format!("neural texture {} does not exist", b.neural_texture),
            );
        }
        if r.is_none() {
            ctx.report(
                "INDEX_OUT_OF_RANGE",
                &ep.key("renderer"),
                format!("renderer {} does not exist", b.renderer),
            );
        }
        if let (Some(Some(t)), Some(Some(r))) = (t, r) {
            if t.channels != r.input_channels {
                ctx.report(
                    "RENDERER_INPUT_MISMATCH",
                    &ep,
                    format!(
                        "neural texture {} has {} channels, renderer {} takes {}",
                        b.neural_texture, t.channels, b.renderer, r.input_channels
                    ),
                );
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pointers() {
        let r = Ptr::ROOT;
        let a = r.key("extensions");
        let b = a.key("a/b~c");
        let c = b.index(3);
        assert_eq!(c.render(), "/extensions/a~1b~0c/3");
        assert_eq!(Ptr::ROOT.render(), "");
        assert_eq!(
            gltf_path_to_pointer("meshes[0].primitives[1].attributes[\"TEXCOORD_0\"]"),
            "/meshes/0/primitives/1/attributes/TEXCOORD_0"
        );
        assert_eq!(gltf_path_to_pointer("scene"), "/scene");
    }

    #[test]
    fn garbage_is_reported_not_panicked() {
        let l = Limits::default();
        for input in [&b""[..], b"{", b"glTF", b"glT", b"[]", b"{}", b"\xff\xfe"] {
            let r = validate_slice(input, None, &l);
            assert!(r.has_errors(), "{input:?}: {r:?}");
        }
    }

    /// One mesh with two quads bound to (texture 0, renderer 0) and (texture 1, renderer 1),
    /// as GLB JSON (a `Value` to edit) and its BIN chunk.
    fn two_bindings() -> (Value, Vec<u8>) {
        use crate::asset::{AssetBuilder, MaterialDesc, NeuralTextureDesc, Node, Primitive};
        use crate::asset::{RendererDesc, WrapMode};
        use crate::exr_codec::{LevelCompression, TextureLevel};
        use crate::model::{Architecture, DType};
        let mut b = AssetBuilder::new();
        let quad = |x: f32, material| Primitive {
            positions: vec![[x, 0.0, 0.0], [x + 1.0, 0.0, 0.0], [x + 1.0, 1.0, 0.0]],
            normals: None,
            tex_coords: vec![[0.0, 1.0], [1.0, 1.0], [1.0, 0.0]],
            indices: vec![0, 1, 2],
            material: Some(material),
        };
        for _ in 0..2 {
            let t = b.add_neural_texture(NeuralTextureDesc {
                levels: vec![TextureLevel::zeros(2, 2, 3)],
                wrap_s: WrapMode::Repeat,
                wrap_t: WrapMode::Repeat,
                view_dependence: None,
                compression: LevelCompression::None,
                storage: Vec::new(),
            });
            let r = b.add_renderer(RendererDesc {
                renderer: model::Renderer::new(Architecture::None, 3, 3),
                tensors: Default::default(),
                dtype: DType::F16,
                tensor_dtypes: Default::default(),
            });
            b.add_material(MaterialDesc {
                name: None,
                neural_texture: t,
                renderer: r,
            });
        }
        let mesh = b.add_mesh(None, vec![quad(0.0, 0), quad(2.0, 1)]);
        b.add_node(Node {
            mesh: Some(mesh),
            ..Node::default()
        });
        let c = b.build_container().unwrap();
        (serde_json::to_value(&c.root).unwrap(), c.buffers[0].clone())
    }

    fn glb(v: &Value, bin: &[u8]) -> Vec<u8> {
        crate::container::glb_bytes(&serde_json::to_vec(v).unwrap(), Some(bin)).unwrap()
    }

    #[test]
    fn builder_binds_primitives_and_keeps_materials_plain() {
        let (v, bin) = two_bindings();
        for (i, m) in v["materials"].as_array().unwrap().iter().enumerate() {
            let ext = m["extensions"].as_object().unwrap();
            assert_eq!(
                ext.keys().collect::<Vec<_>>(),
                ["KHR_materials_unlit"],
                "material {i}"
            );
            assert_eq!(m["pbrMetallicRoughness"]["baseColorTexture"]["index"], i);
        }
        for (i, p) in v["meshes"][0]["primitives"]
            .as_array()
            .unwrap()
            .iter()
            .enumerate()
        {
            assert_eq!(p["material"], i);
            let b = &p["extensions"][EXTENSION_NAME];
            assert_eq!(
                (&b["neuralTexture"], &b["renderer"]),
                (&json_n(i), &json_n(i))
            );
            assert_eq!(b["texCoord"], 0);
        }
        let bytes = glb(&v, &bin);
        let report = validate_slice(&bytes, None, &Limits::default());
        assert!(report.issues.is_empty(), "{report:#?}");
        let asset = crate::read_asset_from_slice(&bytes).unwrap();
        let got: Vec<_> = asset.primitives[0]
            .iter()
            .map(|b| b.as_ref().map(|b| (b.neural_texture, b.renderer)))
            .collect();
        assert_eq!(got, [Some((0, 0)), Some((1, 1))]);
        assert_eq!(asset.binding(0, 1).map(|b| b.renderer), Some(1));
        assert!(asset.binding(0, 2).is_none() && asset.binding(1, 0).is_none());
    }

    fn json_n(i: usize) -> Value {
        Value::from(i)
    }

    #[test]
    fn primitives_sharing_a_fallback_keep_their_own_bindings() {
        let (mut v, bin) = two_bindings();
        v["meshes"][0]["primitives"][1]["material"] = json_n(0);
        let bytes = glb(&v, &bin);
        let report = validate_slice(&bytes, None, &Limits::default());
        assert!(report.issues.is_empty(), "{report:#?}");
        let asset = crate::read_asset_from_slice(&bytes).unwrap();
        assert_eq!(asset.binding(0, 0).map(|b| b.renderer), Some(0));
        assert_eq!(asset.binding(0, 1).map(|b| b.renderer), Some(1));
    }

    #[test]
    fn binding_on_a_material_is_not_a_binding() {
        // Earlier drafts put the object on the material; version 1 defines it on primitives
        // only, so there it is an unknown material extension and binds nothing.
        let (mut v, bin) = two_bindings();
        let moved = v["meshes"][0]["primitives"][0]["extensions"].take();
        v["materials"][0]["extensions"][EXTENSION_NAME] = moved[EXTENSION_NAME].clone();
        if let Some(p) = v["meshes"][0]["primitives"][0].as_object_mut() {
            p.remove("extensions");
        }
        let bytes = glb(&v, &bin);
        assert!(validate_slice(&bytes, None, &Limits::default())
            .issues
            .is_empty());
        let asset = crate::read_asset_from_slice(&bytes).unwrap();
        assert!(asset.binding(0, 0).is_none());
        assert_eq!(asset.binding(0, 1).map(|b| b.renderer), Some(1));
    }

    #[test]
    fn primitive_checks_point_at_the_primitive_and_its_material() {
        let (mut v, bin) = two_bindings();
        v["meshes"][0]["primitives"][0]["extensions"][EXTENSION_NAME]["texCoord"] = json_n(2);
        v["meshes"][0]["primitives"][0]["extensions"][EXTENSION_NAME]["renderer"] = json_n(7);
        v["materials"][0]["extensions"] = Value::Object(Default::default());
        if let Some(p) = v["meshes"][0]["primitives"][1].as_object_mut() {
            p.remove("material");
        }
        let report = validate_slice(&glb(&v, &bin), None, &Limits::default());
        let got: BTreeSet<(&str, &str)> = report
            .issues
            .iter()
            .map(|i| (i.code, i.pointer.as_str()))
            .collect();
        let want: BTreeSet<(&str, &str)> = [
            ("TEXCOORD_MISSING", "/meshes/0/primitives/0/attributes"),
            (
                "INDEX_OUT_OF_RANGE",
                "/meshes/0/primitives/0/extensions/EXT_deferred_neural_rendering/renderer",
            ),
            ("FALLBACK_MISSING", "/materials/0"),
            ("FALLBACK_MISSING", "/meshes/0/primitives/1"),
        ]
        .into_iter()
        .collect();
        assert_eq!(got, want, "{report:#?}");
        assert!(crate::read_asset_from_slice(&glb(&v, &bin)).is_err());
    }
}
