//! Proxy mesh loading: glTF/GLB through `dnr_runtime::scene::load_gltf`, plus Wavefront OBJ
//! (`obj.rs`) and PLY (`ply.rs`) readers, all giving a [`Scene`] whose UVs, when the file has
//! them, follow the glTF convention ((0, 0) is the top-left of the texture, v grows
//! downwards). A primitive without UVs has an empty `uvs`; `uv_atlas` generates them.
//!
//! OBJ `vt` and PLY `s,t`/`u,v` use the OpenGL convention (v grows upwards, as Blender and
//! MeshLab write them), so their v is flipped: `v' = 1 - v`.

use std::collections::HashMap;
use std::path::Path;

use dnr_runtime::scene::{Primitive, Scene};
use glam::{Vec2, Vec3};

use super::error::CaptureError;
pub use super::obj::parse_obj;
pub use super::ply::parse_ply;

/// Size limits for mesh files, checked before large allocations.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MeshLimits {
    /// Largest mesh file in bytes.
    pub max_file_bytes: u64,
    /// Most triangles (after fan triangulation of polygons).
    pub max_triangles: usize,
    /// Most triangles of a mesh that gets a generated UV atlas (unwrapping time grows with
    /// them; about 5 s per million triangles on 2 cores).
    pub max_unwrap_triangles: usize,
}

impl Default for MeshLimits {
    fn default() -> Self {
        MeshLimits {
            max_file_bytes: 2 << 30,
            max_triangles: 20_000_000,
            max_unwrap_triangles: 2_000_000,
        }
    }
}

/// Loads a proxy mesh by extension (case-insensitive): `.glb`/`.gltf`, `.obj` or `.ply`.
/// The result is checked: at least one triangle, finite positions and UVs, indices in range,
/// UVs on every vertex of a primitive or on none.
pub fn load_mesh(path: &Path, limits: &MeshLimits) -> Result<Scene, CaptureError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    let scene = match ext.as_deref() {
        Some("glb") | Some("gltf") => {
            check_file_size(path, limits)?;
            dnr_runtime::scene::load_gltf(path).map_err(|e| CaptureError::Gltf {
                path: path.to_path_buf(),
                message: e.to_string(),
            })?
        }
        Some("obj") => {
            let bytes = read_limited(path, limits)?;
            let text = String::from_utf8_lossy(&bytes);
            Scene {
                primitives: vec![parse_obj(path, &text, limits)?],
            }
        }
        Some("ply") => {
            let bytes = read_limited(path, limits)?;
            Scene {
                primitives: vec![parse_ply(path, &bytes, limits)?],
            }
        }
        _ => {
            return Err(CaptureError::MeshFormat {
                path: path.to_path_buf(),
            })
        }
    };
    validate(path, &scene, limits)?;
    Ok(scene)
}

pub(crate) fn check_file_size(path: &Path, limits: &MeshLimits) -> Result<(), CaptureError> {
    let len = std::fs::metadata(path)
        .map_err(|e| CaptureError::io(path, e))?
        .len();
    if len > limits.max_file_bytes {
        return Err(CaptureError::MeshTooLarge {
            path: path.to_path_buf(),
            message: format!(
                "file is {len} bytes, over the limit of {}",
                limits.max_file_bytes
            ),
        });
    }
    Ok(())
}

pub(crate) fn read_limited(path: &Path, limits: &MeshLimits) -> Result<Vec<u8>, CaptureError> {
    check_file_size(path, limits)?;
    std::fs::read(path).map_err(|e| CaptureError::io(path, e))
}

/// Checks a loaded scene (also the glTF loader's output).
fn validate(path: &Path, scene: &Scene, limits: &MeshLimits) -> Result<(), CaptureError> {
    let triangles: usize = scene.primitives.iter().map(|p| p.indices.len() / 3).sum();
    if triangles == 0 {
        return Err(CaptureError::MeshEmpty {
            path: path.to_path_buf(),
        });
    }
    if triangles > limits.max_triangles {
        return Err(too_many_triangles(path, limits));
    }
    let many = scene.primitives.len() > 1;
    for (pi, p) in scene.primitives.iter().enumerate() {
        let what = if many {
            format!("primitive {pi}")
        } else {
            "mesh".to_string()
        };
        if p.indices.is_empty() {
            continue;
        }
        let bad = |message: String| CaptureError::MeshParse {
            path: path.to_path_buf(),
            location: what.clone(),
            message,
        };
        if p.indices.len() % 3 != 0 {
            return Err(bad(format!(
                "index count {} is not a multiple of 3",
                p.indices.len()
            )));
        }
        if let Some(i) = p.indices.iter().find(|&&i| i as usize >= p.positions.len()) {
            return Err(bad(format!(
                "index {i} out of range ({} vertices)",
                p.positions.len()
            )));
        }
        if !p.uvs.is_empty() && p.uvs.len() != p.positions.len() {
            return Err(bad(format!(
                "{} texture coordinates for {} vertices",
                p.uvs.len(),
                p.positions.len()
            )));
        }
        if let Some(i) = p.positions.iter().position(|v| !v.is_finite()) {
            return Err(bad(format!("vertex {i} has a non-finite position")));
        }
        if let Some(i) = p.uvs.iter().position(|v| !v.is_finite()) {
            return Err(bad(format!(
                "vertex {i} has a non-finite texture coordinate"
            )));
        }
    }
    Ok(())
}

pub(crate) fn too_many_triangles(path: &Path, limits: &MeshLimits) -> CaptureError {
    CaptureError::MeshTooLarge {
        path: path.to_path_buf(),
        message: format!("more than {} triangles", limits.max_triangles),
    }
}

/// Welds (position index, uv key) corners into output vertices. Corners without a UV are
/// allowed: if any corner lacks one, [`Welder::finish`] drops every UV and welds by position
/// alone (the mesh then gets a generated atlas).
pub(crate) struct Welder {
    map: HashMap<(u32, Option<u64>), u32>,
    prim: Primitive,
    /// Input position index of each output vertex.
    source: Vec<u32>,
    missing_uv: bool,
}

impl Welder {
    pub(crate) fn new() -> Self {
        Welder {
            map: HashMap::new(),
            prim: Primitive::default(),
            source: Vec::new(),
            missing_uv: false,
        }
    }

    /// `uv` is `(key, uv)` with the uv already in glTF convention and `key` identifying it
    /// (an index or the bit pattern), or None for a corner without one.
    pub(crate) fn vertex(&mut self, pos_index: u32, pos: Vec3, uv: Option<(u64, Vec2)>) -> u32 {
        self.missing_uv |= uv.is_none();
        let prim = &mut self.prim;
        let source = &mut self.source;
        *self
            .map
            .entry((pos_index, uv.map(|u| u.0)))
            .or_insert_with(|| {
                prim.positions.push(pos);
                prim.uvs.push(uv.map_or(Vec2::ZERO, |u| u.1));
                source.push(pos_index);
                (prim.positions.len() - 1) as u32
            })
    }

    /// Triangle indices so far.
    pub(crate) fn indices(&mut self) -> &mut Vec<u32> {
        &mut self.prim.indices
    }

    /// The primitive; without UVs (welded by position) when some corner had none.
    pub(crate) fn finish(self) -> Primitive {
        if !self.missing_uv {
            return self.prim;
        }
        let mut remap: HashMap<u32, u32> = HashMap::new();
        let mut out = Primitive::default();
        let mut new_index = vec![0u32; self.prim.positions.len()];
        for (v, &src) in self.source.iter().enumerate() {
            new_index[v] = *remap.entry(src).or_insert_with(|| {
                out.positions.push(self.prim.positions[v]);
                (out.positions.len() - 1) as u32
            });
        }
        out.indices = self
            .prim
            .indices
            .iter()
            .map(|&i| new_index[i as usize])
            .collect();
        out
    }
}

/// Fan-triangulates a convex polygon's corners; `None` when over the triangle limit.
pub(crate) fn push_fan(indices: &mut Vec<u32>, corners: &[u32], limits: &MeshLimits) -> Option<()> {
    if indices.len() / 3 + corners.len() - 2 > limits.max_triangles {
        return None;
    }
    for k in 1..corners.len() - 1 {
        indices.extend_from_slice(&[corners[0], corners[k], corners[k + 1]]);
    }
    Some(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn welder_drops_uvs_when_a_corner_has_none() {
        let mut w = Welder::new();
        let a = w.vertex(0, Vec3::ZERO, Some((1, Vec2::ONE)));
        let b = w.vertex(0, Vec3::ZERO, None);
        let c = w.vertex(1, Vec3::X, Some((2, Vec2::ZERO)));
        w.indices().extend([a, b, c]);
        let p = w.finish();
        assert!(p.uvs.is_empty());
        assert_eq!(p.positions.len(), 2);
        assert_eq!(p.indices, vec![0, 0, 1]);
    }
}
