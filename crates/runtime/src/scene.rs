//! Triangle geometry to rasterise: primitives in their local (mesh) space with the world
//! matrix of the node that instances them, and the glTF loader that builds them.
//!
//! The loader parses the document with `gltf::Gltf::from_slice` (which validates the JSON
//! structure and indices) and resolves buffers itself; images are never decoded. Accessor
//! data is read by a small checked reader (bounds computed with checked arithmetic), so a
//! lying file gives a [`SceneError`], never a panic.

use std::path::{Path, PathBuf};

use glam::{Mat4, Vec2, Vec3};
use gltf::accessor::{DataType, Dimensions};
use gltf::mesh::{Mode, Semantic};

/// One drawable primitive: an indexed triangle list in local space.
#[derive(Clone, Debug, Default)]
pub struct Primitive {
    /// Vertex positions in the primitive's local space.
    pub positions: Vec<Vec3>,
    /// Texture coordinates (glTF convention: (0,0) is the top-left of the image). Empty when
    /// the primitive has no UV set `tex_coord`; otherwise one per position.
    pub uvs: Vec<Vec2>,
    /// Triangles as vertex indices, three per triangle.
    pub indices: Vec<u32>,
    /// Local-to-world matrix of the node instancing this primitive.
    pub world: Mat4,
    /// glTF material index, if any (the core material: for a primitive with `neural`, its
    /// fallback).
    pub material: Option<u32>,
    /// `(neuralTexture, renderer)` of the primitive's `EXT_deferred_neural_rendering`
    /// binding, None for a primitive without the extension.
    pub neural: Option<(u32, u32)>,
    /// Which `TEXCOORD_n` set `uvs` was read from (the binding's `texCoord`, default 0).
    pub tex_coord: u32,
    /// glTF node that instances the primitive (None when built by hand).
    pub node: Option<u32>,
    /// glTF mesh index and primitive index within it (None when built by hand).
    pub source: Option<(u32, u32)>,
}

impl Primitive {
    /// Number of whole triangles in `indices`.
    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }

    /// Whether `uvs` holds one texture coordinate per vertex.
    pub fn has_uvs(&self) -> bool {
        !self.positions.is_empty() && self.uvs.len() == self.positions.len()
    }
}

/// Everything the rasteriser draws.
#[derive(Clone, Debug, Default)]
pub struct Scene {
    /// The primitives, each drawn with its own world matrix.
    pub primitives: Vec<Primitive>,
}

impl Scene {
    /// Total number of triangles over all primitives.
    pub fn triangle_count(&self) -> usize {
        self.primitives.iter().map(Primitive::triangle_count).sum()
    }

    /// World-space axis-aligned bounds `(min, max)` of all finite vertices referenced or not,
    /// or None when there is none.
    pub fn world_bounds(&self) -> Option<(Vec3, Vec3)> {
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        for p in &self.primitives {
            for &v in &p.positions {
                let w = p.world.transform_point3(v);
                if w.is_finite() {
                    lo = lo.min(w);
                    hi = hi.max(w);
                }
            }
        }
        (lo.x <= hi.x).then_some((lo, hi))
    }
}

/// Why a glTF file could not be turned into a [`Scene`].
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The file could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The container or JSON is not valid glTF (as judged by the `gltf` crate).
    #[error("invalid glTF: {0}")]
    Gltf(String),
    /// A buffer could not be resolved (missing BIN chunk, bad data URI, missing file, short).
    #[error("buffers[{index}]: {reason}")]
    Buffer {
        /// Buffer index.
        index: usize,
        /// What is wrong.
        reason: String,
    },
    /// An accessor does not fit its buffer view, or has a type the attribute does not allow.
    #[error("accessors[{index}] ({what}): {reason}")]
    Accessor {
        /// Accessor index.
        index: usize,
        /// The attribute or role it was read for, e.g. `POSITION`.
        what: String,
        /// What is wrong.
        reason: String,
    },
    /// A primitive is inconsistent (index out of range, attribute counts differ, ...).
    #[error("meshes[{mesh}].primitives[{primitive}]: {reason}")]
    Primitive {
        /// Mesh index.
        mesh: usize,
        /// Primitive index within the mesh.
        primitive: usize,
        /// What is wrong.
        reason: String,
    },
    /// Not produced any more: the `EXT_deferred_neural_rendering` binding moved from
    /// materials to mesh primitives, and a malformed binding is a [`SceneError::Primitive`].
    /// Kept so that code matching on it still compiles.
    #[error("materials[{material}].extensions.EXT_deferred_neural_rendering: {reason}")]
    Material {
        /// Material index.
        material: usize,
        /// What is wrong.
        reason: String,
    },
    /// The node graph is not a forest (a node is its own ancestor) or has a non-finite matrix.
    #[error("nodes[{node}]: {reason}")]
    Node {
        /// Node index.
        node: usize,
        /// What is wrong.
        reason: String,
    },
    /// The node graph instances more primitives than [`MAX_INSTANCES`].
    #[error("the node graph instances more than {MAX_INSTANCES} primitives")]
    TooManyInstances,
}

/// Hard limit on primitive instances produced by the node walk. glTF node graphs are trees,
/// but a file may list a node as a child of many parents; this bounds the expansion.
pub const MAX_INSTANCES: usize = 1 << 20;

/// Loads the default scene of a `.glb` or `.gltf` file (external buffers are resolved
/// relative to the file's folder; data URIs are decoded). Images are never read.
pub fn load_gltf(path: &Path) -> Result<Scene, SceneError> {
    let bytes = std::fs::read(path).map_err(|source| SceneError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let base = path.parent().unwrap_or_else(|| Path::new("."));
    load(&bytes, Some(base))
}

/// Loads the default scene of a GLB, or of a `.gltf` JSON whose buffers are all embedded as
/// data URIs (an external buffer is an error here: there is no folder to resolve it from).
pub fn from_gltf_slice(bytes: &[u8]) -> Result<Scene, SceneError> {
    load(bytes, None)
}

fn load(bytes: &[u8], base: Option<&Path>) -> Result<Scene, SceneError> {
    let gltf = gltf::Gltf::from_slice(bytes).map_err(|e| SceneError::Gltf(e.to_string()))?;
    let doc = &gltf.document;
    let buffers = resolve_buffers(doc, base, gltf.blob.clone())?;
    let buffers: Vec<&[u8]> = buffers.iter().map(|b| &b.0[..]).collect();

    // Roots: the default scene, else the first scene, else every parentless node.
    let roots: Vec<gltf::Node> = match doc.default_scene().or_else(|| doc.scenes().next()) {
        Some(scene) => scene.nodes().collect(),
        None => {
            let mut has_parent = vec![false; doc.nodes().len()];
            for n in doc.nodes() {
                for c in n.children() {
                    has_parent[c.index()] = true;
                }
            }
            doc.nodes().filter(|n| !has_parent[n.index()]).collect()
        }
    };

    // Geometry is decoded once per glTF primitive and shared by every instance.
    let mut decoded: Vec<Vec<Option<Decoded>>> = doc
        .meshes()
        .map(|m| vec![None; m.primitives().len()])
        .collect();

    let mut scene = Scene::default();
    let mut on_path = vec![false; doc.nodes().len()];
    for root in roots {
        walk(
            root,
            Mat4::IDENTITY,
            &mut on_path,
            &buffers,
            &mut decoded,
            &mut scene,
        )?;
    }
    Ok(scene)
}

fn resolve_buffers(
    doc: &gltf::Document,
    base: Option<&Path>,
    mut blob: Option<Vec<u8>>,
) -> Result<Vec<gltf::buffer::Data>, SceneError> {
    let mut out = Vec::with_capacity(doc.buffers().len());
    for buffer in doc.buffers() {
        let index = buffer.index();
        let data = gltf::buffer::Data::from_source_and_blob(buffer.source(), base, &mut blob)
            .map_err(|e| SceneError::Buffer {
                index,
                reason: e.to_string(),
            })?;
        if data.len() < buffer.length() {
            return Err(SceneError::Buffer {
                index,
                reason: format!(
                    "declares {} bytes but only {} are present",
                    buffer.length(),
                    data.len()
                ),
            });
        }
        out.push(data);
    }
    Ok(out)
}

/// Geometry of one glTF primitive in local space (shared by its instances).
#[derive(Clone)]
struct Decoded {
    positions: Vec<Vec3>,
    uvs: Vec<Vec2>,
    indices: Vec<u32>,
    neural: Option<(u32, u32)>,
    tex_coord: u32,
}

fn walk(
    node: gltf::Node,
    parent: Mat4,
    on_path: &mut [bool],
    buffers: &[&[u8]],
    decoded: &mut [Vec<Option<Decoded>>],
    scene: &mut Scene,
) -> Result<(), SceneError> {
    let ni = node.index();
    if on_path[ni] {
        return Err(SceneError::Node {
            node: ni,
            reason: "the node is its own ancestor (cycle in children)".into(),
        });
    }
    let local = Mat4::from_cols_array_2d(&node.transform().matrix());
    if !local.is_finite() {
        return Err(SceneError::Node {
            node: ni,
            reason: "transform is not finite".into(),
        });
    }
    let world = parent * local;
    if let Some(mesh) = node.mesh() {
        let mi = mesh.index();
        for prim in mesh.primitives() {
            let pi = prim.index();
            if decoded[mi][pi].is_none() {
                decoded[mi][pi] = Some(decode_primitive(&prim, mi, buffers)?.unwrap_or(Decoded {
                    positions: Vec::new(),
                    uvs: Vec::new(),
                    indices: Vec::new(),
                    neural: None,
                    tex_coord: 0,
                }));
            }
            let Some(d) = decoded[mi][pi].as_ref() else {
                continue;
            };
            if d.indices.is_empty() {
                continue; // points, lines or no POSITION: nothing to rasterise
            }
            if scene.primitives.len() >= MAX_INSTANCES {
                return Err(SceneError::TooManyInstances);
            }
            scene.primitives.push(Primitive {
                positions: d.positions.clone(),
                uvs: d.uvs.clone(),
                indices: d.indices.clone(),
                world,
                material: prim.material().index().and_then(|m| u32::try_from(m).ok()),
                neural: d.neural,
                tex_coord: d.tex_coord,
                node: u32::try_from(ni).ok(),
                source: u32::try_from(mi).ok().zip(u32::try_from(pi).ok()),
            });
        }
    }
    on_path[ni] = true;
    for child in node.children() {
        walk(child, world, on_path, buffers, decoded, scene)?;
    }
    on_path[ni] = false;
    Ok(())
}

/// A primitive's `extensions.EXT_deferred_neural_rendering` binding:
/// `(Some((neuralTexture, renderer)), texCoord)`, or `(None, 0)` without the extension.
fn primitive_binding(
    prim: &gltf::Primitive,
    mesh: usize,
) -> Result<(Option<(u32, u32)>, u32), SceneError> {
    let Some(ext) = prim.extension_value(dnr_format::EXTENSION_NAME) else {
        return Ok((None, 0));
    };
    let bad = |reason: &str| SceneError::Primitive {
        mesh,
        primitive: prim.index(),
        reason: format!("extensions.{}: {reason}", dnr_format::EXTENSION_NAME),
    };
    let obj = ext.as_object().ok_or_else(|| bad("must be an object"))?;
    let index = |key: &str| {
        obj.get(key)
            .and_then(|v| v.as_u64())
            .and_then(|n| u32::try_from(n).ok())
            .ok_or_else(|| bad(&format!("{key} must be a non-negative integer")))
    };
    let tex_coord = if obj.contains_key("texCoord") {
        index("texCoord")?
    } else {
        0
    };
    let neural = (index("neuralTexture")?, index("renderer")?);
    Ok((Some(neural), tex_coord))
}

/// Decodes one primitive; Ok(None) when it has nothing to rasterise.
fn decode_primitive(
    prim: &gltf::Primitive,
    mesh: usize,
    buffers: &[&[u8]],
) -> Result<Option<Decoded>, SceneError> {
    let primitive = prim.index();
    let perr = |reason: String| SceneError::Primitive {
        mesh,
        primitive,
        reason,
    };
    match prim.mode() {
        Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan => {}
        Mode::Points | Mode::Lines | Mode::LineLoop | Mode::LineStrip => return Ok(None),
    }
    // glTF: "When positions are not specified, client implementations SHOULD skip
    // primitive's rendering".
    let Some(pos_acc) = prim.get(&Semantic::Positions) else {
        return Ok(None);
    };
    if pos_acc.dimensions() != Dimensions::Vec3 {
        return Err(acc_err(&pos_acc, "POSITION", "must be VEC3"));
    }
    let flat = read_accessor(&pos_acc, "POSITION", buffers)?;
    let positions: Vec<Vec3> = flat
        .chunks_exact(3)
        .map(|c| Vec3::new(c[0], c[1], c[2]))
        .collect();
    let n = positions.len();

    let (neural, tex_coord) = primitive_binding(prim, mesh)?;
    let uvs = match prim.get(&Semantic::TexCoords(tex_coord)) {
        None => Vec::new(),
        Some(acc) => {
            let what = format!("TEXCOORD_{tex_coord}");
            if acc.dimensions() != Dimensions::Vec2 {
                return Err(acc_err(&acc, &what, "must be VEC2"));
            }
            let flat = read_accessor(&acc, &what, buffers)?;
            if flat.len() / 2 != n {
                return Err(perr(format!(
                    "{what} has {} elements but POSITION has {n}",
                    flat.len() / 2
                )));
            }
            flat.chunks_exact(2)
                .map(|c| Vec2::new(c[0], c[1]))
                .collect()
        }
    };

    let list: Vec<u32> = match prim.indices() {
        Some(acc) => {
            if acc.dimensions() != Dimensions::Scalar
                || !matches!(
                    acc.data_type(),
                    DataType::U8 | DataType::U16 | DataType::U32
                )
            {
                return Err(acc_err(
                    &acc,
                    "indices",
                    "must be SCALAR unsigned byte, short or int",
                ));
            }
            let idx = read_indices(&acc, buffers)?;
            if let Some(&bad) = idx.iter().find(|&&i| i as usize >= n) {
                return Err(perr(format!("index {bad} out of range for {n} vertices")));
            }
            idx
        }
        None => {
            let n32 = u32::try_from(n).map_err(|_| perr(format!("{n} vertices is too many")))?;
            (0..n32).collect()
        }
    };

    let indices = match prim.mode() {
        Mode::TriangleStrip => strip_to_list(&list),
        Mode::TriangleFan => fan_to_list(&list),
        _ => {
            let mut l = list;
            l.truncate(l.len() / 3 * 3);
            l
        }
    };
    Ok(Some(Decoded {
        positions,
        uvs,
        indices,
        neural,
        tex_coord,
    }))
}

/// glTF 2.0 §3.7.2.1: strip triangle i is (v_i, v_{i+1+i%2}, v_{i+2-i%2}).
fn strip_to_list(s: &[u32]) -> Vec<u32> {
    let mut out = Vec::with_capacity(s.len().saturating_sub(2) * 3);
    for i in 0..s.len().saturating_sub(2) {
        let (a, b) = if i % 2 == 0 { (1, 2) } else { (2, 1) };
        out.extend_from_slice(&[s[i], s[i + a], s[i + b]]);
    }
    out
}

/// glTF 2.0 §3.7.2.1: fan triangle i is (v_{i+1}, v_{i+2}, v_0).
fn fan_to_list(s: &[u32]) -> Vec<u32> {
    let mut out = Vec::with_capacity(s.len().saturating_sub(2) * 3);
    for i in 0..s.len().saturating_sub(2) {
        out.extend_from_slice(&[s[i + 1], s[i + 2], s[0]]);
    }
    out
}

fn acc_err(acc: &gltf::Accessor, what: &str, reason: &str) -> SceneError {
    SceneError::Accessor {
        index: acc.index(),
        what: what.into(),
        reason: reason.into(),
    }
}

/// Bytes of a buffer view, checked against the buffer.
fn view_bytes<'b>(
    view: &gltf::buffer::View,
    buffers: &[&'b [u8]],
    acc: &gltf::Accessor,
    what: &str,
) -> Result<&'b [u8], SceneError> {
    let buf = buffers
        .get(view.buffer().index())
        .ok_or_else(|| acc_err(acc, what, "buffer view names a missing buffer"))?;
    view.offset()
        .checked_add(view.length())
        .and_then(|end| buf.get(view.offset()..end))
        .ok_or_else(|| {
            acc_err(
                acc,
                what,
                &format!("bufferViews[{}] lies outside its buffer", view.index()),
            )
        })
}

/// A strided run of `count` elements of `elem` bytes starting at `offset` within `bytes`,
/// checked: returns the stride.
fn check_run(
    bytes: &[u8],
    offset: usize,
    count: usize,
    elem: usize,
    stride: Option<usize>,
) -> Option<usize> {
    let stride = stride.unwrap_or(elem);
    if stride < elem || count == 0 {
        return None;
    }
    let end = (count - 1)
        .checked_mul(stride)?
        .checked_add(elem)?
        .checked_add(offset)?;
    (end <= bytes.len()).then_some(stride)
}

fn read_component(b: &[u8], ty: DataType, normalized: bool) -> f32 {
    // glTF 2.0 §3.11 (normalised integers): unsigned c / max, signed max(c / max, -1).
    match ty {
        DataType::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
        DataType::U8 => {
            let c = b[0] as f32;
            if normalized {
                c / 255.0
            } else {
                c
            }
        }
        DataType::I8 => {
            let c = b[0] as i8 as f32;
            if normalized {
                (c / 127.0).max(-1.0)
            } else {
                c
            }
        }
        DataType::U16 => {
            let c = u16::from_le_bytes([b[0], b[1]]) as f32;
            if normalized {
                c / 65535.0
            } else {
                c
            }
        }
        DataType::I16 => {
            let c = i16::from_le_bytes([b[0], b[1]]) as f32;
            if normalized {
                (c / 32767.0).max(-1.0)
            } else {
                c
            }
        }
        DataType::U32 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f32,
    }
}

/// Reads a float-valued accessor (any component type, normalised as declared), sparse
/// substitution included, into a flat `count * components` vector.
fn read_accessor(
    acc: &gltf::Accessor,
    what: &str,
    buffers: &[&[u8]],
) -> Result<Vec<f32>, SceneError> {
    let comps = acc.dimensions().multiplicity();
    let ty = acc.data_type();
    let csize = ty.size();
    let elem = comps * csize;
    let count = acc.count();
    let total = count
        .checked_mul(comps)
        .filter(|&t| t <= (1 << 31))
        .ok_or_else(|| acc_err(acc, what, "count is too large"))?;
    let norm = acc.normalized();
    let mut out = vec![0.0f32; total];
    if let Some(view) = acc.view() {
        let bytes = view_bytes(&view, buffers, acc, what)?;
        let stride = check_run(bytes, acc.offset(), count, elem, view.stride())
            .ok_or_else(|| acc_err(acc, what, "elements do not fit the buffer view"))?;
        for (i, o) in out.chunks_exact_mut(comps).enumerate() {
            let base = acc.offset() + i * stride;
            for (k, v) in o.iter_mut().enumerate() {
                *v = read_component(&bytes[base + k * csize..], ty, norm);
            }
        }
    }
    if let Some(sparse) = acc.sparse() {
        let idx = read_sparse_indices(acc, &sparse, what, buffers)?;
        let values = sparse.values();
        let vbytes = view_bytes(&values.view(), buffers, acc, what)?;
        check_run(vbytes, values.offset(), idx.len(), elem, None)
            .ok_or_else(|| acc_err(acc, what, "sparse values do not fit their buffer view"))?;
        for (j, &i) in idx.iter().enumerate() {
            let i = i as usize;
            if i >= count {
                return Err(acc_err(
                    acc,
                    what,
                    &format!("sparse index {i} out of range"),
                ));
            }
            let base = values.offset() + j * elem;
            for k in 0..comps {
                out[i * comps + k] = read_component(&vbytes[base + k * csize..], ty, norm);
            }
        }
    }
    Ok(out)
}

fn read_sparse_indices(
    acc: &gltf::Accessor,
    sparse: &gltf::accessor::sparse::Sparse,
    what: &str,
    buffers: &[&[u8]],
) -> Result<Vec<u32>, SceneError> {
    use gltf::accessor::sparse::IndexType;
    let ind = sparse.indices();
    let bytes = view_bytes(&ind.view(), buffers, acc, what)?;
    let size = match ind.index_type() {
        IndexType::U8 => 1,
        IndexType::U16 => 2,
        IndexType::U32 => 4,
    };
    let n = sparse.count();
    check_run(bytes, ind.offset(), n, size, None)
        .ok_or_else(|| acc_err(acc, what, "sparse indices do not fit their buffer view"))?;
    Ok((0..n)
        .map(|j| {
            let b = &bytes[ind.offset() + j * size..];
            match size {
                1 => b[0] as u32,
                2 => u16::from_le_bytes([b[0], b[1]]) as u32,
                _ => u32::from_le_bytes([b[0], b[1], b[2], b[3]]),
            }
        })
        .collect())
}

/// Reads an index accessor exactly (as integers; f32 would round indices above 2^24).
fn read_indices(acc: &gltf::Accessor, buffers: &[&[u8]]) -> Result<Vec<u32>, SceneError> {
    let what = "indices";
    let ty = acc.data_type();
    let size = ty.size();
    let count = acc.count();
    if count > (1 << 31) {
        return Err(acc_err(acc, what, "count is too large"));
    }
    let read = |b: &[u8]| match ty {
        DataType::U8 => b[0] as u32,
        DataType::U16 => u16::from_le_bytes([b[0], b[1]]) as u32,
        _ => u32::from_le_bytes([b[0], b[1], b[2], b[3]]),
    };
    let mut out = vec![0u32; count];
    if let Some(view) = acc.view() {
        let bytes = view_bytes(&view, buffers, acc, what)?;
        let stride = check_run(bytes, acc.offset(), count, size, view.stride())
            .ok_or_else(|| acc_err(acc, what, "elements do not fit the buffer view"))?;
        for (i, o) in out.iter_mut().enumerate() {
            *o = read(&bytes[acc.offset() + i * stride..]);
        }
    }
    if let Some(sparse) = acc.sparse() {
        let idx = read_sparse_indices(acc, &sparse, what, buffers)?;
        let values = sparse.values();
        let vbytes = view_bytes(&values.view(), buffers, acc, what)?;
        check_run(vbytes, values.offset(), idx.len(), size, None)
            .ok_or_else(|| acc_err(acc, what, "sparse values do not fit their buffer view"))?;
        for (j, &i) in idx.iter().enumerate() {
            let slot = out
                .get_mut(i as usize)
                .ok_or_else(|| acc_err(acc, what, &format!("sparse index {i} out of range")))?;
            *slot = read(&vbytes[values.offset() + j * size..]);
        }
    }
    Ok(out)
}
