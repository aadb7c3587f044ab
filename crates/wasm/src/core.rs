//! The bindings' logic in plain Rust types, so that native tests can run it; `lib.rs` only
//! converts to and from JavaScript values.

use dnr_format::container::parse_root;
use dnr_format::validate::Severity;
use dnr_format::{Asset, Container, Limits, WrapMode};
use dnr_runtime::camera::Camera;
use dnr_runtime::gbuffer::GBuffer;
use dnr_runtime::renderer::Renderer;
use glam::Mat4;
use serde_json::{json, Value};

/// Validator codes that concern other readers, not the data neural rendering reads (spec,
/// "Conforming Readers", rule 3): a reader renders the primitive in spite of them.
pub const NON_BLOCKING: [&str; 4] = [
    "EXTENSION_REQUIRED",
    "EXTENSION_NOT_USED",
    "FALLBACK_MISSING",
    "TEXCOORD_MISSING",
];

/// The validator's report on `bytes` (a GLB, or a `.gltf` whose buffers are `data:` URIs)
/// as JSON: `{ issues: [{code, severity, pointer, message}], errors, warnings, blocking }`,
/// where `blocking` lists the distinct error codes that keep a reader on the fallback.
pub fn validate_report(bytes: &[u8]) -> Value {
    let report = dnr_format::validate_slice(bytes, None, &Limits::default());
    let mut blocking: Vec<&str> = report
        .issues
        .iter()
        .filter(|i| i.severity == Severity::Error && !NON_BLOCKING.contains(&i.code))
        .map(|i| i.code)
        .collect();
    blocking.sort_unstable();
    blocking.dedup();
    json!({
        "issues": report.issues.iter().map(|i| json!({
            "code": i.code,
            "severity": match i.severity { Severity::Error => "error", _ => "warning" },
            "pointer": i.pointer,
            "message": i.message,
        })).collect::<Vec<_>>(),
        "errors": report.count(Severity::Error),
        "warnings": report.count(Severity::Warning),
        "blocking": blocking,
    })
}

/// A GLB built from a glTF JSON document and the bytes of each of its buffers, as a glTF
/// loader resolved them (GLB `BIN` chunk, `data:` URI or external file): buffer 0 becomes
/// the `BIN` chunk, the others `data:` URIs. Lets a viewer validate and decode what it
/// loaded without the original file.
pub fn glb_from_parts(json: &[u8], buffers: Vec<Vec<u8>>) -> Result<Vec<u8>, String> {
    let limits = Limits::default();
    if json.len() as u64 > limits.max_json_bytes {
        return Err(format!(
            "JSON is {} bytes, above the limit of {}",
            json.len(),
            limits.max_json_bytes
        ));
    }
    let root = parse_root(json).map_err(|p| format!("{}: {}", p.code, p.message()))?;
    if root.buffers.len() != buffers.len() {
        return Err(format!(
            "the document has {} buffers, {} were given",
            root.buffers.len(),
            buffers.len()
        ));
    }
    for (i, b) in buffers.iter().enumerate() {
        if b.len() as u64 > limits.max_buffer_bytes {
            return Err(format!(
                "buffer {i} is {} bytes, above the limit of {}",
                b.len(),
                limits.max_buffer_bytes
            ));
        }
    }
    Container { root, buffers }
        .to_glb()
        .map_err(|e| e.to_string())
}

/// A decoded asset and its CPU renderer.
pub struct Loaded {
    asset: Asset,
    renderer: Renderer,
}

/// GL code of a wrap mode.
fn gl_wrap(w: WrapMode) -> u32 {
    match w {
        WrapMode::Repeat => 10497,
        WrapMode::ClampToEdge => 33071,
        WrapMode::MirroredRepeat => 33648,
    }
}

impl Loaded {
    /// Decodes every level and tensor of a GLB (or self-contained `.gltf`) and prepares the
    /// CPU renderer. Fails on anything the runtime refuses (the message names what).
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, String> {
        let asset = dnr_format::read_asset_from_slice(bytes).map_err(|e| e.to_string())?;
        let renderer = Renderer::from_asset(&asset).map_err(|e| e.to_string())?;
        Ok(Loaded { asset, renderer })
    }

    /// Everything but the bulk data, as JSON:
    /// `textures[t] = { channels, wrapS, wrapT, viewDependence: {degree, firstChannel} | null,
    /// levels: [{width, height}] }`, `renderers[r] = { architecture, inputChannels,
    /// outputChannels, hidden?, widths?, decoder?, normalization?, tensors: [{name, shape}] }`,
    /// `bindings = [{mesh, primitive, neuralTexture, renderer, texCoord}]` and
    /// `scenePrimitives = [{mesh, primitive, node, neural}]` (the CPU renderer's primitive
    /// order, which [`Loaded::shade`]'s `prim` ids index).
    pub fn describe(&self) -> Value {
        let textures: Vec<Value> = self
            .asset
            .textures
            .iter()
            .map(|t| {
                json!({
                    "channels": t.channels,
                    "wrapS": gl_wrap(t.wrap_s),
                    "wrapT": gl_wrap(t.wrap_t),
                    "viewDependence": t.view_dependence.as_ref().map(|v| json!({
                        "basis": v.basis, "degree": v.degree, "firstChannel": v.first_channel,
                    })),
                    "levels": t.levels.iter().map(|l| json!({
                        "width": l.width, "height": l.height,
                    })).collect::<Vec<_>>(),
                })
            })
            .collect();
        let renderers: Vec<Value> = self
            .asset
            .renderers
            .iter()
            .map(|r| {
                let s = &r.spec;
                let mut v = json!({
                    "architecture": self.renderer_arch(s),
                    "inputChannels": s.input_channels,
                    "outputChannels": s.output_channels,
                    "tensors": r.tensors.iter().map(|(name, t)| json!({
                        "name": name, "shape": t.shape,
                    })).collect::<Vec<_>>(),
                });
                let o = v.as_object_mut().expect("object");
                if let Some(h) = &s.hidden {
                    o.insert("hidden".into(), json!(h));
                }
                if let Some(w) = &s.widths {
                    o.insert("widths".into(), json!(w));
                }
                if let Some(d) = &s.decoder {
                    o.insert(
                        "decoder".into(),
                        serde_json::to_value(d).unwrap_or(Value::Null),
                    );
                }
                if let Some(n) = &s.normalization {
                    o.insert(
                        "normalization".into(),
                        serde_json::to_value(n).unwrap_or(Value::Null),
                    );
                }
                v
            })
            .collect();
        let mut bindings = Vec::new();
        for (m, prims) in self.asset.primitives.iter().enumerate() {
            for (p, b) in prims.iter().enumerate() {
                if let Some(b) = b {
                    bindings.push(json!({
                        "mesh": m, "primitive": p, "neuralTexture": b.neural_texture,
                        "renderer": b.renderer, "texCoord": b.tex_coord,
                    }));
                }
            }
        }
        let scene_primitives: Vec<Value> = self
            .renderer
            .scene()
            .primitives
            .iter()
            .map(|p| {
                json!({
                    "mesh": p.source.map(|s| s.0),
                    "primitive": p.source.map(|s| s.1),
                    "node": p.node,
                    "neural": p.neural.map(|(t, r)| json!([t, r])),
                })
            })
            .collect();
        json!({
            "textures": textures,
            "renderers": renderers,
            "bindings": bindings,
            "scenePrimitives": scene_primitives,
        })
    }

    fn renderer_arch(&self, s: &dnr_format::model::Renderer) -> Value {
        serde_json::to_value(&s.architecture).unwrap_or(Value::Null)
    }

    /// Level `l` of neural texture `t`: `height * width * channels` values, texel-interleaved,
    /// row 0 (v = 0) first.
    pub fn level_f32(&self, t: usize, l: usize) -> Option<&[f32]> {
        Some(&self.asset.textures.get(t)?.levels.get(l)?.data)
    }

    /// [`Loaded::level_f32`] as IEEE half bits: exact for EXR levels (stored as half); the
    /// values of a quantised PNG level (`offset + scale * q` in `f32`) are rounded to the
    /// nearest half.
    pub fn level_f16(&self, t: usize, l: usize) -> Option<Vec<u16>> {
        self.level_f32(t, l).map(|d| {
            d.iter()
                .map(|&v| half::f16::from_f32(v).to_bits())
                .collect()
        })
    }

    /// The values of tensor `name` of renderer `r`, row-major, converted to `f32`.
    pub fn tensor(&self, r: usize, name: &str) -> Option<&[f32]> {
        Some(&self.asset.renderers.get(r)?.tensors.get(name)?.data)
    }

    /// The neural layer (`height * width * 4` values: sRGB colour, straight alpha, row 0 at
    /// the top) of the asset's scene seen by a pinhole camera (`cam_to_world`: 16 values,
    /// column-major, OpenGL convention).
    #[allow(clippy::too_many_arguments)]
    pub fn render(
        &self,
        fx: f32,
        fy: f32,
        cx: f32,
        cy: f32,
        cam_to_world: &[f32],
        width: u32,
        height: u32,
    ) -> Result<Vec<f32>, String> {
        let m: [f32; 16] = cam_to_world
            .try_into()
            .map_err(|_| format!("camToWorld has {} values, not 16", cam_to_world.len()))?;
        let cam = Camera {
            fx,
            fy,
            cx,
            cy,
            width,
            height,
            cam_to_world: Mat4::from_cols_array(&m),
        };
        self.renderer
            .render(&cam, width, height)
            .map(|img| img.data)
            .map_err(|e| e.to_string())
    }

    /// Shades a G-buffer a viewer rasterised (row 0 at the top): per pixel `coverage`
    /// (non-zero = covered), `prim` (index into `scenePrimitives`), `uv` (2 values) and
    /// `view_dir` (3 values, unit eye-to-surface direction in the primitive's local space).
    /// Assets with supersampled renderers (format revision 1.3) need their subsamples' view
    /// too and give an error here: draw them with [`Loaded::render`].
    pub fn shade(
        &self,
        width: usize,
        height: usize,
        coverage: &[f32],
        prim: &[u32],
        uv: &[f32],
        view_dir: &[f32],
    ) -> Result<Vec<f32>, String> {
        let n = width
            .checked_mul(height)
            .ok_or_else(|| "frame size overflows".to_string())?;
        if coverage.len() != n || prim.len() != n || uv.len() != 2 * n || view_dir.len() != 3 * n {
            return Err(format!(
                "a {width}x{height} G-buffer needs {n} coverage and prim values, {} uv and {} \
                 viewDir values; got {}, {}, {}, {}",
                2 * n,
                3 * n,
                coverage.len(),
                prim.len(),
                uv.len(),
                view_dir.len()
            ));
        }
        let g = GBuffer {
            width,
            height,
            uv: uv.chunks_exact(2).map(|c| [c[0], c[1]]).collect(),
            coverage: coverage.to_vec(),
            prim: prim.to_vec(),
            tri: vec![0; n],
            depth: vec![0.0; n],
            view_dir: view_dir
                .chunks_exact(3)
                .map(|c| [c[0], c[1], c[2]])
                .collect(),
        };
        self.renderer
            .shade(&g)
            .map(|img| img.data)
            .map_err(|e| e.to_string())
    }
}
