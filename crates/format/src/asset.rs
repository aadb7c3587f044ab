//! High layer: one-call reading and writing of whole assets, and the [`AssetBuilder`]
//! the baker uses to make them.
//!
//! [`read_asset`] decodes every neural texture level and weight tensor to `f32`;
//! [`write_asset`] writes the container as it is (the decoded parts are views of it;
//! to change them build a new asset with [`AssetBuilder`]).

use std::collections::BTreeMap;
use std::path::Path;

use gltf_json as json;
use json::validation::{Checked, USize64};
use serde_json::Value;

use crate::architecture::architecture_tensors;
use crate::container::{name_file, Container};
use crate::error::{Error, Result};
use crate::exr_codec::{decode_level, encode_level, LevelCompression, LevelExpect, TextureLevel};
use crate::limits::Limits;
use crate::model::{self, DType, PrimitiveExtension, Renderer, ViewDependence};
use crate::weights::{crc32, decode_tensor, pack_tensors_each, TensorF32};
use crate::EXTENSION_NAME;

/// The `channels` a neural texture may declare (spec: `3 <= C <= 1024`; at least 3 because
/// the fallback image and the `none` renderer read channels 0..3). Outside it is
/// `TEXTURE_CHANNELS_RANGE`; inside it but above [`Limits::max_channels`] is
/// `LIMIT_EXCEEDED`.
pub const TEXTURE_CHANNELS: std::ops::RangeInclusive<u32> = 3..=1024;

/// Texture coordinate wrapping of the core sampler (`wrapS`/`wrapT`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum WrapMode {
    /// `REPEAT` (10497), the default: `i mod n`, non-negative.
    #[default]
    Repeat,
    /// `CLAMP_TO_EDGE` (33071): `clamp(i, 0, n-1)`.
    ClampToEdge,
    /// `MIRRORED_REPEAT` (33648): `m = i mod 2n; m < n ? m : 2n-1-m`.
    MirroredRepeat,
}

impl WrapMode {
    /// Wraps integer tap index `i` into `0..n` (`n > 0`).
    pub fn wrap(self, i: i64, n: u32) -> u32 {
        let n = i64::from(n.max(1));
        let r = match self {
            WrapMode::Repeat => i.rem_euclid(n),
            WrapMode::ClampToEdge => i.clamp(0, n - 1),
            WrapMode::MirroredRepeat => {
                let m = i.rem_euclid(2 * n);
                if m < n {
                    m
                } else {
                    2 * n - 1 - m
                }
            }
        };
        r as u32 // 0 <= r < n <= u32::MAX
    }

    fn from_json(w: &Checked<json::texture::WrappingMode>) -> Result<Self> {
        use json::texture::WrappingMode as W;
        match w {
            Checked::Valid(W::Repeat) => Ok(WrapMode::Repeat),
            Checked::Valid(W::ClampToEdge) => Ok(WrapMode::ClampToEdge),
            Checked::Valid(W::MirroredRepeat) => Ok(WrapMode::MirroredRepeat),
            Checked::Invalid => Err(Error::invalid("sampler wrap mode")),
        }
    }

    fn to_json(self) -> json::texture::WrappingMode {
        use json::texture::WrappingMode as W;
        match self {
            WrapMode::Repeat => W::Repeat,
            WrapMode::ClampToEdge => W::ClampToEdge,
            WrapMode::MirroredRepeat => W::MirroredRepeat,
        }
    }
}

/// A decoded neural texture.
#[derive(Clone, Debug, PartialEq)]
pub struct DecodedTexture {
    /// Channels C of every level.
    pub channels: u32,
    /// Levels, finest first, `f32` HWC.
    pub levels: Vec<TextureLevel>,
    /// Horizontal wrap of the texture's sampler.
    pub wrap_s: WrapMode,
    /// Vertical wrap of the texture's sampler.
    pub wrap_t: WrapMode,
    /// Optional view dependence.
    pub view_dependence: Option<ViewDependence>,
}

impl DecodedTexture {
    /// `F(u, v)`: the sum over levels of the bilinear sample (DESIGN.md), into `out`
    /// (`channels` values). Non-finite uv gives zeros.
    pub fn sample(&self, u: f32, v: f32, out: &mut [f32]) {
        out.iter_mut().for_each(|o| *o = 0.0);
        if !(u.is_finite() && v.is_finite()) {
            return;
        }
        for level in &self.levels {
            bilinear_add(level, self.wrap_s, self.wrap_t, u, v, out);
        }
    }
}

fn bilinear_add(level: &TextureLevel, ws: WrapMode, wt: WrapMode, u: f32, v: f32, out: &mut [f32]) {
    let x = u * level.width as f32 - 0.5;
    let y = v * level.height as f32 - 0.5;
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let (x0, y0) = (x0 as i64, y0 as i64);
    let c = level.channels as usize;
    let taps = [
        (x0, y0, (1.0 - fx) * (1.0 - fy)),
        (x0 + 1, y0, fx * (1.0 - fy)),
        (x0, y0 + 1, (1.0 - fx) * fy),
        (x0 + 1, y0 + 1, fx * fy),
    ];
    for (tx, ty, w) in taps {
        let xi = ws.wrap(tx, level.width) as usize;
        let yi = wt.wrap(ty, level.height) as usize;
        let base = (yi * level.width as usize + xi) * c;
        for (o, &t) in out.iter_mut().zip(&level.data[base..base + c]) {
            *o += w * t;
        }
    }
}

/// A decoded renderer: its JSON parameters and its tensors by name.
#[derive(Clone, Debug, PartialEq)]
pub struct DecodedRenderer {
    /// The renderer object as stored (including weight descriptors).
    pub spec: Renderer,
    /// Every tensor, widened to `f32`.
    pub tensors: BTreeMap<String, TensorF32>,
}

impl DecodedRenderer {
    /// Total number of weight elements.
    pub fn parameter_count(&self) -> u64 {
        self.tensors.values().map(|t| t.data.len() as u64).sum()
    }
}

/// A whole asset: the container plus its decoded extension data.
#[derive(Clone, Debug)]
pub struct Asset {
    /// Core document and buffers; what [`write_asset`] writes.
    pub container: Container,
    /// The root extension object, if present.
    pub extension: Option<model::Extension>,
    /// Decoded neural textures, by index.
    pub textures: Vec<DecodedTexture>,
    /// Decoded renderers, by index.
    pub renderers: Vec<DecodedRenderer>,
    /// Each mesh primitive's binding object, indexed `[mesh][primitive]` like the glTF
    /// `meshes[m].primitives[p]` (`None` for primitives without the extension).
    pub primitives: Vec<Vec<Option<PrimitiveExtension>>>,
}

impl Asset {
    /// The binding of `meshes[mesh].primitives[primitive]`, if it has one.
    pub fn binding(&self, mesh: usize, primitive: usize) -> Option<&PrimitiveExtension> {
        self.primitives.get(mesh)?.get(primitive)?.as_ref()
    }
}

/// The root extension value of a document, if any.
pub fn root_extension_value(root: &json::Root) -> Option<&Value> {
    root.extensions.as_ref()?.others.get(EXTENSION_NAME)
}

/// The extension value (binding object) of a mesh primitive, if any.
pub fn primitive_extension_value(p: &json::mesh::Primitive) -> Option<&Value> {
    p.extensions.as_ref()?.others.get(EXTENSION_NAME)
}

/// Every mesh primitive that carries the extension: `(mesh, primitive, value)`.
pub fn bound_primitive_values(root: &json::Root) -> Vec<(usize, usize, &Value)> {
    root.meshes
        .iter()
        .enumerate()
        .flat_map(|(mi, m)| {
            m.primitives
                .iter()
                .enumerate()
                .filter_map(move |(pi, p)| primitive_extension_value(p).map(|v| (mi, pi, v)))
        })
        .collect()
}

/// Why a bound primitive's core material is not a complete fallback (`FALLBACK_MISSING`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FallbackProblem {
    /// The primitive has no `material`.
    NoMaterial,
    /// The material (by index) has no `pbrMetallicRoughness.baseColorTexture`.
    NoBaseColorTexture(usize),
    /// The material (by index) does not carry `KHR_materials_unlit`.
    NoUnlit(usize),
}

impl std::fmt::Display for FallbackProblem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            FallbackProblem::NoMaterial => {
                f.write_str("the primitive has no material to fall back to")
            }
            FallbackProblem::NoBaseColorTexture(m) => {
                write!(f, "fallback material {m} has no baseColorTexture")
            }
            FallbackProblem::NoUnlit(m) => {
                write!(f, "fallback material {m} lacks KHR_materials_unlit")
            }
        }
    }
}

/// Checks the fallback of a primitive that carries the extension. A material index out of
/// range is not a fallback problem (the core checks report it).
pub fn fallback_problem(root: &json::Root, p: &json::mesh::Primitive) -> Option<FallbackProblem> {
    let Some(index) = p.material else {
        return Some(FallbackProblem::NoMaterial);
    };
    let i = index.value();
    let m = root.materials.get(i)?;
    if m.pbr_metallic_roughness.base_color_texture.is_none() {
        return Some(FallbackProblem::NoBaseColorTexture(i));
    }
    let unlit = m
        .extensions
        .as_ref()
        .is_some_and(|e| e.unlit.is_some() || e.others.contains_key("KHR_materials_unlit"));
    (!unlit).then_some(FallbackProblem::NoUnlit(i))
}

/// Reads and decodes an asset file (`.glb` or `.gltf`) under default [`Limits`].
pub fn read_asset(path: impl AsRef<Path>) -> Result<Asset> {
    read_asset_with_limits(path.as_ref(), &Limits::default())
}

/// Reads and decodes an asset file under `limits`.
pub fn read_asset_with_limits(path: &Path, limits: &Limits) -> Result<Asset> {
    let container = Container::read(path, limits)?;
    decode_asset(container, limits).map_err(|e| name_file(e, path))
}

/// Reads and decodes an asset from memory (buffers must be in the GLB or `data:` URIs).
pub fn read_asset_from_slice(bytes: &[u8]) -> Result<Asset> {
    read_asset_from_slice_with_limits(bytes, &Limits::default())
}

/// [`read_asset_from_slice`] under `limits`.
pub fn read_asset_from_slice_with_limits(bytes: &[u8], limits: &Limits) -> Result<Asset> {
    decode_asset(Container::from_slice(bytes, None, limits)?, limits)
}

/// Writes `asset.container` (`.glb` or embedded `.gltf` by extension), atomically.
pub fn write_asset(path: impl AsRef<Path>, asset: &Asset) -> Result<()> {
    asset.container.write(path.as_ref())
}

/// Decodes the extension data of a container.
///
/// `NotSupported` for an extension version, architecture, decoder, normalisation or dtype
/// this version does not know (a viewer then shows the core fallback); `Invalid` for
/// anything the validator reports as an error.
pub fn decode_asset(container: Container, limits: &Limits) -> Result<Asset> {
    let root = &container.root;
    let core = crate::validate::validate_core(root, limits);
    if let Some(i) = core
        .issues
        .iter()
        .find(|i| i.severity == crate::Severity::Error)
    {
        return Err(Error::invalid(format!(
            "{} at {}: {}",
            i.code, i.pointer, i.message
        )));
    }
    for i in 0..root.buffer_views.len() {
        // Every view must lie inside its buffer, used by the extension or not.
        container.view_bytes(i as u32)?;
    }
    let mut primitives = Vec::with_capacity(root.meshes.len());
    for (mi, mesh) in root.meshes.iter().enumerate() {
        let mut row = Vec::with_capacity(mesh.primitives.len());
        for (pi, p) in mesh.primitives.iter().enumerate() {
            row.push(match primitive_extension_value(p) {
                Some(v) => Some(PrimitiveExtension::deserialize_from(v).map_err(|e| {
                    Error::invalid(format!("mesh {mi} primitive {pi} extension: {e}"))
                })?),
                None => None,
            });
        }
        primitives.push(row);
    }
    let any_bound = primitives.iter().flatten().any(Option::is_some);
    let uses = root_extension_value(root).is_some() || any_bound;
    if uses && !root.extensions_used.iter().any(|e| e == EXTENSION_NAME) {
        return Err(Error::invalid(format!(
            "`{EXTENSION_NAME}` is used but not in extensionsUsed"
        )));
    }
    if root.extensions_required.iter().any(|e| e == EXTENSION_NAME) {
        return Err(Error::invalid(format!(
            "`{EXTENSION_NAME}` is in extensionsRequired"
        )));
    }
    for (mi, mesh) in root.meshes.iter().enumerate() {
        for (pi, p) in mesh.primitives.iter().enumerate() {
            if primitives[mi][pi].is_none() {
                continue;
            }
            if let Some(problem) = fallback_problem(root, p) {
                return Err(Error::invalid(format!(
                    "mesh {mi} primitive {pi}: {problem}"
                )));
            }
        }
    }
    let Some(value) = root_extension_value(root) else {
        if any_bound {
            return Err(Error::invalid(
                "mesh primitives use the extension but the root has none",
            ));
        }
        return Ok(Asset {
            container,
            extension: None,
            textures: Vec::new(),
            renderers: Vec::new(),
            primitives,
        });
    };
    if let Some(v) = value.get("version").and_then(Value::as_u64) {
        if v != u64::from(model::VERSION) {
            return Err(Error::not_supported(format!("extension version {v}")));
        }
    }
    let ext: model::Extension = serde_json::from_value(value.clone())
        .map_err(|e| Error::invalid(format!("extension object: {e}")))?;
    let mut texel_values = 0u64;
    let mut textures = Vec::with_capacity(ext.neural_textures.len());
    for (ti, t) in ext.neural_textures.iter().enumerate() {
        // Range before limit, as the validator reports them (TEXTURE_CHANNELS_RANGE).
        if !TEXTURE_CHANNELS.contains(&t.channels) {
            return Err(Error::invalid(format!(
                "texture {ti} has {} channels, must have {}..={}",
                t.channels,
                TEXTURE_CHANNELS.start(),
                TEXTURE_CHANNELS.end()
            )));
        }
        Limits::check(
            "texture levels",
            t.levels.len() as u64,
            u64::from(limits.max_levels),
        )?;
        Limits::check(
            "texture channels",
            u64::from(t.channels),
            u64::from(limits.max_channels),
        )?;
        if t.levels.is_empty() {
            return Err(Error::invalid(format!("texture {ti} has no levels")));
        }
        let mut levels = Vec::with_capacity(t.levels.len());
        for (li, l) in t.levels.iter().enumerate() {
            let png = l.mime_type == model::LEVEL_MIME_TYPE_PNG;
            if l.mime_type != model::LEVEL_MIME_TYPE && !png {
                return Err(Error::not_supported(format!(
                    "texture {ti} level {li} mimeType `{}`",
                    l.mime_type
                )));
            }
            if png != l.quantization.is_some() {
                return Err(Error::invalid(format!(
                    "texture {ti} level {li}: quantization must be present exactly on image/png levels"
                )));
            }
            texel_values = texel_values
                .saturating_add(u64::from(l.width) * u64::from(l.height) * u64::from(t.channels));
            Limits::check("texel values", texel_values, limits.max_total_texel_values)?;
            let bytes = container.view_bytes(l.buffer_view)?;
            let expect = LevelExpect {
                width: l.width,
                height: l.height,
                channels: t.channels,
            };
            let decoded = match &l.quantization {
                Some(q) => crate::quant::decode_png_level(bytes, expect, q, limits),
                None => decode_level(bytes, expect, limits),
            };
            let level = decoded.map_err(|p| match p.error {
                Error::Invalid { what } => {
                    Error::invalid(format!("texture {ti} level {li}: {what}"))
                }
                other => other,
            })?;
            levels.push(level);
        }
        let (wrap_s, wrap_t) = match t.sampler {
            None => (WrapMode::Repeat, WrapMode::Repeat),
            Some(s) => {
                let s = root.samplers.get(s as usize).ok_or_else(|| {
                    Error::invalid(format!("texture {ti}: sampler {s} does not exist"))
                })?;
                (
                    WrapMode::from_json(&s.wrap_s)?,
                    WrapMode::from_json(&s.wrap_t)?,
                )
            }
        };
        if let Some(vd) = &t.view_dependence {
            if vd.basis != model::BASIS_SPHERICAL_HARMONICS || vd.degree > 3 {
                return Err(Error::not_supported(format!(
                    "texture {ti} view dependence `{}` degree {}",
                    vd.basis, vd.degree
                )));
            }
            if u64::from(vd.first_channel) + vd.coefficient_count() > u64::from(t.channels) {
                return Err(Error::invalid(format!(
                    "texture {ti}: SH channels beyond the texture"
                )));
            }
        }
        textures.push(DecodedTexture {
            channels: t.channels,
            levels,
            wrap_s,
            wrap_t,
            view_dependence: t.view_dependence.clone(),
        });
    }
    let mut weight_elements = 0u64;
    let mut renderers = Vec::with_capacity(ext.renderers.len());
    for (ri, r) in ext.renderers.iter().enumerate() {
        let required: BTreeMap<String, Vec<u32>> = architecture_tensors(r)
            .map_err(|e| match e {
                Error::Invalid { what } => Error::invalid(format!("renderer {ri}: {what}")),
                Error::NotSupported { what } => {
                    Error::not_supported(format!("renderer {ri}: {what}"))
                }
                other => other,
            })?
            .into_iter()
            .collect();
        Limits::check(
            "tensors",
            r.weights.len() as u64,
            u64::from(limits.max_tensors),
        )?;
        let mut tensors = BTreeMap::new();
        for w in &r.weights {
            let what = format!("renderer {ri} tensor `{}`", w.name);
            if !w.dtype.is_known() {
                return Err(Error::not_supported(format!("{what}: dtype `{}`", w.dtype)));
            }
            match required.get(&w.name) {
                None => {
                    return Err(Error::invalid(format!(
                        "{what} is not used by the architecture"
                    )))
                }
                Some(s) if *s != w.shape => {
                    return Err(Error::invalid(format!(
                        "{what}: shape {:?}, expected {s:?}",
                        w.shape
                    )))
                }
                _ => {}
            }
            if w.byte_offset % 4 != 0 {
                return Err(Error::invalid(format!(
                    "{what}: byteOffset not a multiple of 4"
                )));
            }
            let n = w
                .element_count()
                .ok_or_else(|| Error::invalid(format!("{what}: shape overflows")))?;
            weight_elements = weight_elements.saturating_add(n);
            Limits::check(
                "weight elements",
                weight_elements,
                limits.max_weight_elements,
            )?;
            let view = container.view_bytes(w.buffer_view)?;
            let len = w.byte_length().unwrap_or(u64::MAX);
            let bytes = usize::try_from(w.byte_offset)
                .ok()
                .zip(usize::try_from(w.byte_offset.saturating_add(len)).ok())
                .and_then(|(s, e)| view.get(s..e))
                .ok_or_else(|| Error::invalid(format!("{what} reaches past its bufferView")))?;
            if crc32(bytes) != w.crc32 {
                return Err(Error::invalid(format!("{what}: checksum mismatch")));
            }
            let data = decode_tensor(bytes, &w.shape, &w.dtype, limits)?;
            if data.iter().any(|v| !v.is_finite()) {
                return Err(Error::invalid(format!("{what} has non-finite values")));
            }
            if tensors
                .insert(
                    w.name.clone(),
                    TensorF32 {
                        shape: w.shape.clone(),
                        data,
                    },
                )
                .is_some()
            {
                return Err(Error::invalid(format!("{what} appears twice")));
            }
        }
        if let Some(missing) = required.keys().find(|k| !tensors.contains_key(*k)) {
            return Err(Error::invalid(format!(
                "renderer {ri}: tensor `{missing}` is missing"
            )));
        }
        renderers.push(DecodedRenderer {
            spec: r.clone(),
            tensors,
        });
    }
    for (mi, row) in primitives.iter().enumerate() {
        for (pi, b) in row.iter().enumerate() {
            let Some(b) = b else { continue };
            let t = textures.get(b.neural_texture as usize);
            let r = renderers.get(b.renderer as usize);
            match (t, r) {
                (Some(t), Some(r)) if t.channels == r.spec.input_channels => {}
                (Some(_), Some(_)) => {
                    return Err(Error::invalid(format!(
                    "mesh {mi} primitive {pi}: texture channels differ from renderer inputChannels"
                )))
                }
                _ => {
                    return Err(Error::invalid(format!(
                        "mesh {mi} primitive {pi}: texture or renderer index"
                    )))
                }
            }
        }
    }
    Ok(Asset {
        container,
        extension: Some(ext),
        textures,
        renderers,
        primitives,
    })
}

impl PrimitiveExtension {
    fn deserialize_from(v: &Value) -> serde_json::Result<Self> {
        serde::Deserialize::deserialize(v)
    }
}

// ---------------------------------------------------------------------------------------
// Builder

/// A triangle list primitive.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Primitive {
    /// Vertex positions.
    pub positions: Vec<[f32; 3]>,
    /// Optional unit normals, one per vertex.
    pub normals: Option<Vec<[f32; 3]>>,
    /// `TEXCOORD_0`, one per vertex.
    pub tex_coords: Vec<[f32; 2]>,
    /// Triangle indices (three per triangle).
    pub indices: Vec<u32>,
    /// Index of a [`MaterialDesc`] in the builder, if any: the primitive then carries that
    /// neural binding (`texCoord` 0) and uses its fallback material.
    pub material: Option<usize>,
}

/// A scene node.
#[derive(Clone, Debug, PartialEq)]
pub struct Node {
    /// Optional name.
    pub name: Option<String>,
    /// Mesh index in the builder.
    pub mesh: Option<usize>,
    /// Translation.
    pub translation: [f32; 3],
    /// Unit quaternion (x, y, z, w).
    pub rotation: [f32; 4],
    /// Scale.
    pub scale: [f32; 3],
    /// Child node indices in the builder.
    pub children: Vec<usize>,
}

impl Default for Node {
    fn default() -> Self {
        Node {
            name: None,
            mesh: None,
            translation: [0.0; 3],
            rotation: [0.0, 0.0, 0.0, 1.0],
            scale: [1.0; 3],
            children: Vec::new(),
        }
    }
}

/// A neural texture to store.
#[derive(Clone, Debug, PartialEq)]
pub struct NeuralTextureDesc {
    /// Levels, finest first, all with the same channel count.
    pub levels: Vec<TextureLevel>,
    /// Horizontal wrap.
    pub wrap_s: WrapMode,
    /// Vertical wrap.
    pub wrap_t: WrapMode,
    /// Optional view dependence.
    pub view_dependence: Option<ViewDependence>,
    /// EXR compression of every level stored as EXR.
    pub compression: LevelCompression,
    /// Storage of each level, finest first; levels past the end of the list (all of them
    /// when it is empty) are EXR.
    pub storage: Vec<LevelStorage>,
}

impl NeuralTextureDesc {
    /// The texture as a reader decodes it before storage (f32 levels, no quantisation).
    pub fn decoded(&self) -> DecodedTexture {
        DecodedTexture {
            channels: self.levels.first().map_or(0, |l| l.channels),
            levels: self.levels.clone(),
            wrap_s: self.wrap_s,
            wrap_t: self.wrap_t,
            view_dependence: self.view_dependence.clone(),
        }
    }
}

/// How one level is stored.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum LevelStorage {
    /// OpenEXR `HALF` channels (revision 1.0).
    #[default]
    Exr,
    /// Quantised PNG (revision 1.1) on a grid of `2^p` steps per channel, `p` in `1..=8`:
    /// 4-bit values for `p <= 4`, 8-bit above. Below the container's depth the stored
    /// integers are multiples of `2^(bits - p)` (and `scale` is divided by as much), which
    /// readers decode like any other; deflate then codes fewer distinct values, so the PNG
    /// is smaller. A writer's choice: the format has no field for it.
    Png(u8),
}

impl LevelStorage {
    /// 8-bit quantised PNG at full precision.
    pub const Q8: LevelStorage = LevelStorage::Png(8);
    /// 4-bit quantised PNG at full precision.
    pub const Q4: LevelStorage = LevelStorage::Png(4);

    /// A PNG level at `precision` bits, `None` outside `1..=8`.
    pub fn png(precision: u32) -> Option<LevelStorage> {
        (1..=8)
            .contains(&precision)
            .then_some(LevelStorage::Png(precision as u8))
    }

    /// The container's depth (the `quantization.bits` written), `None` for EXR.
    pub fn bits(self) -> Option<u32> {
        self.precision().map(|p| if p <= 4 { 4 } else { 8 })
    }

    /// Bits of the grid the values are rounded to (`log2` of its steps), `None` for EXR.
    pub fn precision(self) -> Option<u32> {
        match self {
            LevelStorage::Exr => None,
            LevelStorage::Png(p) => Some(u32::from(p.clamp(1, 8))),
        }
    }

    /// The name the baker's `--storage` and reports use: `f16`, `q8`, `q4`, or `q1` to `q7`
    /// for the other grids.
    pub fn name(self) -> &'static str {
        const NAMES: [&str; 8] = ["q1", "q2", "q3", "q4", "q5", "q6", "q7", "q8"];
        match self.precision() {
            None => "f16",
            Some(p) => NAMES[p as usize - 1],
        }
    }
}

/// A renderer to store.
#[derive(Clone, Debug, PartialEq)]
pub struct RendererDesc {
    /// Architecture and parameters (`weights` is ignored and filled in).
    pub renderer: Renderer,
    /// Exactly the tensors [`architecture_tensors`] names.
    pub tensors: BTreeMap<String, TensorF32>,
    /// Storage type of every tensor not in `tensor_dtypes`.
    pub dtype: DType,
    /// Storage types of single tensors, by name, overriding `dtype` (for instance `int4` for
    /// the large inner layers of an `int8` network). Integer types keep rank-1 tensors `f16`.
    pub tensor_dtypes: BTreeMap<String, DType>,
}

/// A neural binding (a neural texture paired with a renderer) and the fallback material made
/// for it. Every [`Primitive`] whose `material` names it carries the binding in its own
/// `extensions.EXT_deferred_neural_rendering` and uses the fallback as its core material: a
/// plain material with the PNG of channels 0..2 as `baseColorTexture` and
/// `KHR_materials_unlit`, holding nothing of this extension.
#[derive(Clone, Debug, PartialEq)]
pub struct MaterialDesc {
    /// Optional name.
    pub name: Option<String>,
    /// Neural texture index in the builder.
    pub neural_texture: usize,
    /// Renderer index in the builder.
    pub renderer: usize,
}

/// Builds a complete, valid asset: meshes, nodes, neural textures, renderers, the bindings
/// on the mesh primitives and, per [`MaterialDesc`], a fallback material with a PNG (channels
/// 0..2 of the summed pyramid at the finest resolution, or box-filtered smaller per
/// [`AssetBuilder::fallback_halvings`]) and `KHR_materials_unlit`.
#[derive(Clone, Debug, Default)]
pub struct AssetBuilder {
    /// `asset.generator`.
    pub generator: Option<String>,
    /// Meshes (lists of primitives) with optional names.
    pub meshes: Vec<(Option<String>, Vec<Primitive>)>,
    /// Nodes; those that are nobody's child are the scene's roots.
    pub nodes: Vec<Node>,
    /// Neural textures.
    pub textures: Vec<NeuralTextureDesc>,
    /// Renderers.
    pub renderers: Vec<RendererDesc>,
    /// Neural bindings with their fallback materials (glTF material `i` is the fallback of
    /// `materials[i]`).
    pub materials: Vec<MaterialDesc>,
    /// Per neural texture (by index), how many times its fallback PNG is halved from the
    /// finest level's size (box filter, [`downsample_rgba8`]); textures not listed keep the
    /// finest size.
    pub fallback_halvings: BTreeMap<usize, u32>,
}

/// Accumulates bufferViews in one buffer, each 4-byte aligned.
struct BinWriter {
    data: Vec<u8>,
    views: Vec<json::buffer::View>,
}

impl BinWriter {
    fn push(&mut self, bytes: &[u8], target: Option<json::buffer::Target>) -> Result<u32> {
        self.data.resize(self.data.len().next_multiple_of(4), 0);
        let offset = self.data.len() as u64;
        self.data.extend_from_slice(bytes);
        let index =
            u32::try_from(self.views.len()).map_err(|_| Error::invalid("too many bufferViews"))?;
        self.views.push(json::buffer::View {
            buffer: json::Index::new(0),
            byte_length: USize64(bytes.len() as u64),
            byte_offset: Some(USize64(offset)),
            byte_stride: None,
            name: None,
            target: target.map(Checked::Valid),
            extensions: None,
            extras: Default::default(),
        });
        Ok(index)
    }
}

fn idx<T>(i: usize) -> Result<json::Index<T>> {
    u32::try_from(i)
        .map(json::Index::new)
        .map_err(|_| Error::invalid("index beyond u32"))
}

impl AssetBuilder {
    /// An empty builder.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds a mesh, returning its index.
    pub fn add_mesh(&mut self, name: Option<String>, primitives: Vec<Primitive>) -> usize {
        self.meshes.push((name, primitives));
        self.meshes.len() - 1
    }

    /// Adds a node, returning its index.
    pub fn add_node(&mut self, node: Node) -> usize {
        self.nodes.push(node);
        self.nodes.len() - 1
    }

    /// Adds a neural texture, returning its index.
    pub fn add_neural_texture(&mut self, t: NeuralTextureDesc) -> usize {
        self.textures.push(t);
        self.textures.len() - 1
    }

    /// Adds a renderer, returning its index.
    pub fn add_renderer(&mut self, r: RendererDesc) -> usize {
        self.renderers.push(r);
        self.renderers.len() - 1
    }

    /// Halves the fallback PNG of neural texture `texture` `halvings` times (box filter).
    pub fn set_fallback_halvings(&mut self, texture: usize, halvings: u32) {
        self.fallback_halvings.insert(texture, halvings);
    }

    /// Adds a neural binding with its fallback material, returning its index (for
    /// [`Primitive::material`]).
    pub fn add_material(&mut self, m: MaterialDesc) -> usize {
        self.materials.push(m);
        self.materials.len() - 1
    }

    /// Builds and writes the asset to `path` (`.glb`, or `.gltf` with embedded buffers).
    pub fn write(&self, path: impl AsRef<Path>) -> Result<Asset> {
        let asset = self.build()?;
        write_asset(path, &asset)?;
        Ok(asset)
    }

    /// Encodes everything into a container and decodes it back as an [`Asset`].
    pub fn build(&self) -> Result<Asset> {
        let container = self.build_container()?;
        decode_asset(container, &Limits::unlimited())
    }

    /// Encodes everything into a container (no decoding).
    pub fn build_container(&self) -> Result<Container> {
        let mut root = json::Root {
            asset: json::Asset {
                generator: Some(self.generator.clone().unwrap_or_else(|| "dnr".to_string())),
                ..Default::default()
            },
            ..Default::default()
        };
        let mut bin = BinWriter {
            data: Vec::new(),
            views: Vec::new(),
        };

        for (mi, (name, prims)) in self.meshes.iter().enumerate() {
            let mut primitives = Vec::new();
            for (pi, p) in prims.iter().enumerate() {
                primitives.push(self.encode_primitive(&mut root, &mut bin, p, mi, pi)?);
            }
            root.meshes.push(json::Mesh {
                name: name.clone(),
                primitives,
                weights: None,
                extensions: None,
                extras: Default::default(),
            });
        }

        let mut is_child = vec![false; self.nodes.len()];
        for n in &self.nodes {
            for &c in &n.children {
                *is_child
                    .get_mut(c)
                    .ok_or_else(|| Error::invalid(format!("child node {c} does not exist")))? =
                    true;
            }
        }
        for n in &self.nodes {
            if let Some(m) = n.mesh.filter(|&m| m >= self.meshes.len()) {
                return Err(Error::invalid(format!("node mesh {m} does not exist")));
            }
            let q = n.rotation;
            root.nodes.push(json::Node {
                name: n.name.clone(),
                mesh: n.mesh.map(idx).transpose()?,
                translation: (n.translation != [0.0; 3]).then_some(n.translation),
                rotation: (q != [0.0, 0.0, 0.0, 1.0]).then_some(json::scene::UnitQuaternion(q)),
                scale: (n.scale != [1.0; 3]).then_some(n.scale),
                children: if n.children.is_empty() {
                    None
                } else {
                    Some(n.children.iter().map(|&c| idx(c)).collect::<Result<_>>()?)
                },
                ..Default::default()
            });
        }
        if !self.nodes.is_empty() {
            root.scenes.push(json::Scene {
                nodes: (0..self.nodes.len())
                    .filter(|&i| !is_child[i])
                    .map(idx)
                    .collect::<Result<_>>()?,
                name: None,
                extensions: None,
                extras: Default::default(),
            });
            root.scene = Some(json::Index::new(0));
        }

        // Neural textures: one core sampler each, shared with its PNG fallback texture.
        let mut ext = model::Extension {
            version: model::VERSION,
            ..Default::default()
        };
        let mut fallback_textures = Vec::new();
        for (ti, t) in self.textures.iter().enumerate() {
            let first = t
                .levels
                .first()
                .ok_or_else(|| Error::invalid(format!("texture {ti} has no levels")))?;
            let channels = first.channels;
            let sampler =
                u32::try_from(root.samplers.len()).map_err(|_| Error::invalid("samplers"))?;
            root.samplers.push(json::texture::Sampler {
                mag_filter: Some(Checked::Valid(json::texture::MagFilter::Linear)),
                min_filter: Some(Checked::Valid(json::texture::MinFilter::Linear)),
                wrap_s: Checked::Valid(t.wrap_s.to_json()),
                wrap_t: Checked::Valid(t.wrap_t.to_json()),
                ..Default::default()
            });
            let (w, h, rgba) = fallback_rgba8(&t.decoded())?;
            let halvings = self.fallback_halvings.get(&ti).copied().unwrap_or(0);
            let (w, h, rgba) = downsample_rgba8(w, h, &rgba, halvings);
            let png = encode_png_rgba8(w, h, &rgba)?;
            let png_view = bin.push(&png, None)?;
            let image = root.images.len();
            root.images.push(json::Image {
                buffer_view: Some(json::Index::new(png_view)),
                mime_type: Some(json::image::MimeType("image/png".to_string())),
                name: None,
                uri: None,
                extensions: None,
                extras: Default::default(),
            });
            fallback_textures.push(root.textures.len());
            root.textures.push(json::Texture {
                name: None,
                sampler: Some(json::Index::new(sampler)),
                source: idx(image)?,
                extensions: None,
                extras: Default::default(),
            });
            let mut levels = Vec::new();
            for (li, l) in t.levels.iter().enumerate() {
                if l.channels != channels {
                    return Err(Error::invalid(format!(
                        "texture {ti} level {li} has {} channels, level 0 has {channels}",
                        l.channels
                    )));
                }
                let storage = t.storage.get(li).copied().unwrap_or_default();
                let (bytes, mime, quantization) = match storage.bits().zip(storage.precision()) {
                    None => (
                        encode_level(l, li, t.compression)
                            .map_err(|e| Error::invalid(format!("texture {ti}: {e}")))?,
                        model::LEVEL_MIME_TYPE,
                        None,
                    ),
                    Some((bits, precision)) => {
                        let (q, png) = crate::quant::encode_png_level_at(l, bits, precision)
                            .map_err(|e| Error::invalid(format!("texture {ti} level {li}: {e}")))?;
                        (png, model::LEVEL_MIME_TYPE_PNG, Some(q))
                    }
                };
                levels.push(model::Level {
                    width: l.width,
                    height: l.height,
                    buffer_view: bin.push(&bytes, None)?,
                    mime_type: mime.to_string(),
                    quantization,
                    extensions: None,
                    extras: None,
                    others: Default::default(),
                });
            }
            ext.neural_textures.push(model::NeuralTexture {
                channels,
                levels,
                sampler: Some(sampler),
                view_dependence: t.view_dependence.clone(),
                extensions: None,
                extras: None,
                others: Default::default(),
            });
        }

        for (ri, r) in self.renderers.iter().enumerate() {
            let required = architecture_tensors(&r.renderer)
                .map_err(|e| Error::invalid(format!("renderer {ri}: {e}")))?;
            let mut ordered = Vec::with_capacity(required.len());
            for (name, shape) in &required {
                let t = r.tensors.get(name).ok_or_else(|| {
                    Error::invalid(format!("renderer {ri}: tensor `{name}` is missing"))
                })?;
                if t.shape != *shape {
                    return Err(Error::invalid(format!(
                        "renderer {ri}: tensor `{name}` has shape {:?}, expected {shape:?}",
                        t.shape
                    )));
                }
                ordered.push((name.as_str(), t));
            }
            if let Some(extra) = r
                .tensors
                .keys()
                .find(|k| !required.iter().any(|(n, _)| n == *k))
            {
                return Err(Error::invalid(format!(
                    "renderer {ri}: tensor `{extra}` is not used"
                )));
            }
            let mut spec = r.renderer.clone();
            spec.weights = Vec::new();
            if !ordered.is_empty() {
                let view =
                    u32::try_from(bin.views.len()).map_err(|_| Error::invalid("bufferViews"))?;
                let typed = ordered.into_iter().map(|(name, t)| {
                    let d = r.tensor_dtypes.get(name).unwrap_or(&r.dtype).clone();
                    (name, t, d)
                });
                let (blob, descriptors) = pack_tensors_each(typed, view)
                    .map_err(|e| Error::invalid(format!("renderer {ri}: {e}")))?;
                bin.push(&blob, None)?;
                spec.weights = descriptors;
            }
            ext.renderers.push(spec);
        }

        for (mi, m) in self.materials.iter().enumerate() {
            let tex = *fallback_textures.get(m.neural_texture).ok_or_else(|| {
                Error::invalid(format!("material {mi}: texture {}", m.neural_texture))
            })?;
            if m.renderer >= self.renderers.len() {
                return Err(Error::invalid(format!(
                    "material {mi}: renderer {}",
                    m.renderer
                )));
            }
            // A plain core material: the binding lives on the primitives (encode_primitive).
            root.materials.push(json::Material {
                name: m.name.clone(),
                pbr_metallic_roughness: json::material::PbrMetallicRoughness {
                    base_color_texture: Some(json::texture::Info {
                        index: idx(tex)?,
                        tex_coord: 0,
                        extensions: None,
                        extras: Default::default(),
                    }),
                    metallic_factor: json::material::StrengthFactor(0.0),
                    ..Default::default()
                },
                // More fields exist when other crates enable more gltf-json features.
                #[allow(clippy::needless_update)]
                extensions: Some(json::extensions::material::Material {
                    unlit: Some(json::extensions::material::Unlit {}),
                    ..Default::default()
                }),
                ..Default::default()
            });
        }

        let mut root_ext = json::extensions::root::Root::default();
        root_ext
            .others
            .insert(EXTENSION_NAME.to_string(), to_value(&ext)?);
        root.extensions = Some(root_ext);
        root.extensions_used.push(EXTENSION_NAME.to_string());
        if !self.materials.is_empty() {
            root.extensions_used.push("KHR_materials_unlit".to_string());
        }
        bin.data.resize(bin.data.len().next_multiple_of(4), 0);
        root.buffer_views = bin.views;
        root.buffers.push(json::Buffer {
            byte_length: USize64(bin.data.len() as u64),
            name: None,
            uri: None,
            extensions: None,
            extras: Default::default(),
        });
        Ok(Container {
            root,
            buffers: vec![bin.data],
        })
    }

    fn encode_primitive(
        &self,
        root: &mut json::Root,
        bin: &mut BinWriter,
        p: &Primitive,
        mi: usize,
        pi: usize,
    ) -> Result<json::mesh::Primitive> {
        use json::accessor::{ComponentType, GenericComponentType, Type};
        let n = p.positions.len();
        let what = |s: &str| Error::invalid(format!("mesh {mi} primitive {pi}: {s}"));
        if n == 0 || p.tex_coords.len() != n || p.normals.as_ref().is_some_and(|v| v.len() != n) {
            return Err(what("attribute counts differ or are zero"));
        }
        if p.indices.is_empty()
            || !p.indices.len().is_multiple_of(3)
            || p.indices.iter().any(|&i| i as usize >= n)
        {
            return Err(what("indices are not a triangle list into the vertices"));
        }
        let binding = match p.material {
            None => None,
            Some(m) => {
                let d = self
                    .materials
                    .get(m)
                    .ok_or_else(|| what(&format!("material {m} does not exist")))?;
                let b = PrimitiveExtension {
                    neural_texture: u32::try_from(d.neural_texture)
                        .map_err(|_| what("neural texture index beyond u32"))?,
                    renderer: u32::try_from(d.renderer)
                        .map_err(|_| what("renderer index beyond u32"))?,
                    tex_coord: 0,
                    ..Default::default()
                };
                let mut others = serde_json::Map::new();
                others.insert(EXTENSION_NAME.to_string(), to_value(&b)?);
                // More fields exist when other crates enable more gltf-json features.
                #[allow(clippy::needless_update)]
                Some(json::extensions::mesh::Primitive {
                    others,
                    ..Default::default()
                })
            }
        };
        let mut accessor = |root: &mut json::Root,
                            bytes: Vec<u8>,
                            count: usize,
                            ty: Type,
                            ct: ComponentType,
                            target: json::buffer::Target,
                            minmax: Option<(Value, Value)>|
         -> Result<json::Index<json::Accessor>> {
            let view = bin.push(&bytes, Some(target))?;
            let i = idx(root.accessors.len())?;
            root.accessors.push(json::Accessor {
                buffer_view: Some(json::Index::new(view)),
                byte_offset: None,
                count: USize64(count as u64),
                component_type: Checked::Valid(GenericComponentType(ct)),
                extensions: None,
                extras: Default::default(),
                type_: Checked::Valid(ty),
                min: minmax.as_ref().map(|m| m.0.clone()),
                max: minmax.map(|m| m.1),
                name: None,
                normalized: false,
                sparse: None,
            });
            Ok(i)
        };
        let f32s =
            |v: &mut dyn Iterator<Item = f32>| v.flat_map(f32::to_le_bytes).collect::<Vec<u8>>();
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for v in &p.positions {
            for k in 0..3 {
                if !v[k].is_finite() {
                    return Err(what("position is not finite"));
                }
                lo[k] = lo[k].min(v[k]);
                hi[k] = hi[k].max(v[k]);
            }
        }
        let array = |a: [f32; 3]| Value::from(a.iter().map(|&x| f64::from(x)).collect::<Vec<_>>());
        let mut attributes = BTreeMap::new();
        let pos = accessor(
            root,
            f32s(&mut p.positions.iter().flatten().copied()),
            n,
            Type::Vec3,
            ComponentType::F32,
            json::buffer::Target::ArrayBuffer,
            Some((array(lo), array(hi))),
        )?;
        attributes.insert(Checked::Valid(json::mesh::Semantic::Positions), pos);
        if let Some(normals) = &p.normals {
            let a = accessor(
                root,
                f32s(&mut normals.iter().flatten().copied()),
                n,
                Type::Vec3,
                ComponentType::F32,
                json::buffer::Target::ArrayBuffer,
                None,
            )?;
            attributes.insert(Checked::Valid(json::mesh::Semantic::Normals), a);
        }
        let uv = accessor(
            root,
            f32s(&mut p.tex_coords.iter().flatten().copied()),
            n,
            Type::Vec2,
            ComponentType::F32,
            json::buffer::Target::ArrayBuffer,
            None,
        )?;
        attributes.insert(Checked::Valid(json::mesh::Semantic::TexCoords(0)), uv);
        // u16 when every index fits below the primitive-restart value 65535.
        let (bytes, ct) = if n < 65535 {
            (
                p.indices
                    .iter()
                    .flat_map(|&i| (i as u16).to_le_bytes())
                    .collect(),
                ComponentType::U16,
            )
        } else {
            (
                p.indices.iter().flat_map(|&i| i.to_le_bytes()).collect(),
                ComponentType::U32,
            )
        };
        let indices = accessor(
            root,
            bytes,
            p.indices.len(),
            Type::Scalar,
            ct,
            json::buffer::Target::ElementArrayBuffer,
            None,
        )?;
        Ok(json::mesh::Primitive {
            attributes,
            extensions: binding,
            extras: Default::default(),
            indices: Some(indices),
            material: p.material.map(idx).transpose()?,
            mode: Checked::Valid(json::mesh::Mode::Triangles),
            targets: None,
        })
    }
}

fn to_value<T: serde::Serialize>(v: &T) -> Result<Value> {
    serde_json::to_value(v).map_err(|e| Error::invalid(format!("extension JSON: {e}")))
}

/// The RGBA8 fallback image of a texture: channels 0..2 of the summed pyramid sampled at
/// the finest level's texel centres, clamped to [0, 1] (missing channels are 0), alpha 1.
pub fn fallback_rgba8(t: &DecodedTexture) -> Result<(u32, u32, Vec<u8>)> {
    let first = t
        .levels
        .first()
        .ok_or_else(|| Error::invalid("texture has no levels"))?;
    let (w, h) = (first.width, first.height);
    let mut out = Vec::with_capacity(w as usize * h as usize * 4);
    let mut f = vec![0.0f32; t.channels as usize];
    for y in 0..h {
        for x in 0..w {
            let u = (x as f32 + 0.5) / w as f32;
            let v = (y as f32 + 0.5) / h as f32;
            t.sample(u, v, &mut f);
            for c in 0..3 {
                let value = f.get(c).copied().unwrap_or(0.0).clamp(0.0, 1.0);
                out.push((value * 255.0).round() as u8);
            }
            out.push(255);
        }
    }
    Ok((w, h, out))
}

/// [`fallback_rgba8`] encoded as PNG.
pub fn fallback_png(t: &DecodedTexture) -> Result<Vec<u8>> {
    let (w, h, rgba) = fallback_rgba8(t)?;
    encode_png_rgba8(w, h, &rgba)
}

/// The size after `halvings` halvings: each side halved (rounding down) `halvings` times,
/// at least 1.
pub fn halved_size(width: u32, height: u32, halvings: u32) -> (u32, u32) {
    let half = |n: u32| n.checked_shr(halvings).unwrap_or(0).max(1);
    (half(width), half(height))
}

/// Box-filters RGBA8 pixels down to [`halved_size`]: each output texel is the rounded mean
/// of the input texels its footprint covers (whole texels; odd sizes give some footprints an
/// extra row or column). `halvings == 0` returns the input unchanged.
pub fn downsample_rgba8(
    width: u32,
    height: u32,
    rgba: &[u8],
    halvings: u32,
) -> (u32, u32, Vec<u8>) {
    let (w, h) = halved_size(width, height, halvings);
    if (w, h) == (width, height) {
        return (width, height, rgba.to_vec());
    }
    let (sw, sh) = (width as usize, height as usize);
    let (w, h) = (w as usize, h as usize);
    let mut out = Vec::with_capacity(w * h * 4);
    for y in 0..h {
        let (y0, y1) = (y * sh / h, ((y + 1) * sh / h).max(y * sh / h + 1));
        for x in 0..w {
            let (x0, x1) = (x * sw / w, ((x + 1) * sw / w).max(x * sw / w + 1));
            let mut sum = [0u64; 4];
            for yy in y0..y1.min(sh) {
                for xx in x0..x1.min(sw) {
                    let i = 4 * (yy * sw + xx);
                    for (c, s) in sum.iter_mut().enumerate() {
                        *s += u64::from(rgba.get(i + c).copied().unwrap_or(0));
                    }
                }
            }
            let n = ((y1.min(sh) - y0) * (x1.min(sw) - x0)).max(1) as u64;
            out.extend(sum.iter().map(|s| ((s + n / 2) / n) as u8));
        }
    }
    (w as u32, h as u32, out)
}

/// Encodes RGBA8 pixels as PNG (deterministic).
pub fn encode_png_rgba8(width: u32, height: u32, rgba: &[u8]) -> Result<Vec<u8>> {
    // Which row filter compresses best depends on the content: none for packed 4-bit
    // levels (a nibble pair is not predicted by its neighbour's), per-row minimum entropy
    // or adaptive for 8-bit levels and colour. Encoding is cheap next to baking; keep the
    // smallest.
    let mut best: Option<Vec<u8>> = None;
    for filter in [
        png::Filter::NoFilter,
        png::Filter::Adaptive,
        png::Filter::MinEntropy,
    ] {
        let out = encode_png_rgba8_with(width, height, rgba, filter)?;
        if best.as_ref().is_none_or(|b| out.len() < b.len()) {
            best = Some(out);
        }
    }
    best.ok_or_else(|| Error::invalid("PNG encoding: no filter tried"))
}

fn encode_png_rgba8_with(
    width: u32,
    height: u32,
    rgba: &[u8],
    filter: png::Filter,
) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, width, height);
    enc.set_color(png::ColorType::Rgba);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::High);
    enc.set_filter(filter);
    let err = |e: png::EncodingError| Error::invalid(format!("PNG encoding: {e}"));
    let mut writer = enc.write_header().map_err(err)?;
    writer.write_image_data(rgba).map_err(err)?;
    writer.finish().map_err(err)?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn downsample_is_a_box_filter() {
        // 4x2 -> 2x1: each output texel averages a 2x2 block.
        let px = |v: u8| [v, v, v, 255];
        let rgba: Vec<u8> = [0, 10, 100, 200, 2, 12, 102, 202]
            .into_iter()
            .flat_map(px)
            .collect();
        let (w, h, out) = downsample_rgba8(4, 2, &rgba, 1);
        assert_eq!((w, h), (2, 1));
        assert_eq!(out, [6, 6, 6, 255, 151, 151, 151, 255]);
        assert_eq!(downsample_rgba8(4, 2, &rgba, 0).2, rgba);
        // Never below one texel; odd sizes cover every input texel.
        assert_eq!(halved_size(5, 3, 8), (1, 1));
        let (w, h, out) = downsample_rgba8(3, 1, &[px(3), px(6), px(9)].concat(), 1);
        assert_eq!((w, h, out), (1, 1, vec![6, 6, 6, 255]));
    }

    #[test]
    fn wrap_modes_follow_design() {
        let r: Vec<u32> = (-3..5).map(|i| WrapMode::Repeat.wrap(i, 3)).collect();
        assert_eq!(r, [0, 1, 2, 0, 1, 2, 0, 1]);
        let c: Vec<u32> = (-2..5).map(|i| WrapMode::ClampToEdge.wrap(i, 3)).collect();
        assert_eq!(c, [0, 0, 0, 1, 2, 2, 2]);
        let m: Vec<u32> = (-3..7)
            .map(|i| WrapMode::MirroredRepeat.wrap(i, 3))
            .collect();
        assert_eq!(m, [2, 1, 0, 0, 1, 2, 2, 1, 0, 0]);
    }

    #[test]
    fn sample_sums_levels_and_hits_texel_centres() {
        let l0 = TextureLevel {
            width: 2,
            height: 1,
            channels: 1,
            data: vec![1.0, 3.0],
        };
        let l1 = TextureLevel {
            width: 1,
            height: 1,
            channels: 1,
            data: vec![10.0],
        };
        let t = DecodedTexture {
            channels: 1,
            levels: vec![l0, l1],
            wrap_s: WrapMode::ClampToEdge,
            wrap_t: WrapMode::Repeat,
            view_dependence: None,
        };
        let mut f = [0.0];
        t.sample(0.25, 0.5, &mut f);
        assert_eq!(f[0], 11.0);
        t.sample(0.5, 0.5, &mut f);
        assert_eq!(f[0], 12.0);
        t.sample(f32::NAN, 0.5, &mut f);
        assert_eq!(f[0], 0.0);
    }
}
