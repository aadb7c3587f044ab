//! Wavefront OBJ proxy meshes.

use std::path::Path;

use dnr_runtime::scene::Primitive;
use glam::{Vec2, Vec3};

use super::error::CaptureError;
use super::mesh::{push_fan, too_many_triangles, MeshLimits, Welder};

/// Parses Wavefront OBJ text: `v`, `vt`, `vn` and `f` (forms `v`, `v/vt`, `v/vt/vn`,
/// `v//vn`; negative indices count back from the latest vertex; polygons are fan
/// triangulated). Other statements (groups, materials, lines) are ignored. When a face
/// corner has no `vt` index the mesh is read without UVs.
pub fn parse_obj(path: &Path, text: &str, limits: &MeshLimits) -> Result<Primitive, CaptureError> {
    let mut positions: Vec<Vec3> = Vec::new();
    let mut texcoords: Vec<Vec2> = Vec::new();
    let mut normals = 0usize;
    let mut welder = Welder::new();
    let mut corners: Vec<u32> = Vec::new();
    let mut lines = text.lines().enumerate();
    let mut joined = String::new();
    while let Some((i, raw)) = lines.next() {
        let line_no = i + 1;
        let err = |message: String| CaptureError::MeshParse {
            path: path.to_path_buf(),
            location: format!("line {line_no}"),
            message,
        };
        // Backslash continues a statement on the next line.
        joined.clear();
        joined.push_str(raw);
        while joined.trim_end().ends_with('\\') {
            let t = joined.trim_end().len() - 1;
            joined.truncate(t);
            joined.push(' ');
            match lines.next() {
                Some((_, next)) => joined.push_str(next),
                None => break,
            }
        }
        let content = joined.split('#').next().unwrap_or("");
        let mut toks = content.split_whitespace();
        let Some(keyword) = toks.next() else { continue };
        match keyword {
            "v" => {
                let v =
                    parse_floats::<3>(&mut toks).ok_or_else(|| err("expected `v x y z`".into()))?;
                let v = Vec3::from_array(v);
                if !v.is_finite() {
                    return Err(err(format!("vertex has a non-finite position {v}")));
                }
                positions.push(v);
            }
            "vt" => {
                let u = toks.next().and_then(|t| t.parse::<f32>().ok());
                let v = match toks.next() {
                    None => Some(0.0),
                    Some(t) => t.parse::<f32>().ok(),
                };
                match (u, v) {
                    (Some(u), Some(v)) if !(u.is_finite() && v.is_finite()) => {
                        return Err(err(format!(
                            "vertex has a non-finite texture coordinate ({u}, {v})"
                        )));
                    }
                    (Some(u), Some(v)) => texcoords.push(Vec2::new(u, 1.0 - v)),
                    _ => return Err(err("expected `vt u [v]`".into())),
                }
            }
            "vn" => {
                parse_floats::<3>(&mut toks).ok_or_else(|| err("expected `vn x y z`".into()))?;
                normals += 1;
            }
            "f" => {
                corners.clear();
                for tok in toks {
                    let mut parts = tok.split('/');
                    let vi = parts.next().unwrap_or("");
                    let ti = parts.next().unwrap_or("");
                    let ni = parts.next().unwrap_or("");
                    if parts.next().is_some() {
                        return Err(err(format!("bad face corner {tok:?}")));
                    }
                    let vi = resolve_index(vi, positions.len())
                        .map_err(|m| err(format!("face corner {tok:?}: vertex index {m}")))?;
                    if !ni.is_empty() {
                        resolve_index(ni, normals)
                            .map_err(|m| err(format!("face corner {tok:?}: normal index {m}")))?;
                    }
                    let uv = if ti.is_empty() {
                        None
                    } else {
                        let ti = resolve_index(ti, texcoords.len()).map_err(|m| {
                            err(format!("face corner {tok:?}: texture coordinate index {m}"))
                        })?;
                        Some((ti as u64, texcoords[ti]))
                    };
                    let v = welder.vertex(vi as u32, positions[vi], uv);
                    corners.push(v);
                }
                if corners.len() < 3 {
                    return Err(err(format!(
                        "face with {} corners (at least 3 needed)",
                        corners.len()
                    )));
                }
                push_fan(welder.indices(), &corners, limits)
                    .ok_or_else(|| too_many_triangles(path, limits))?;
            }
            _ => {}
        }
    }
    if welder.indices().is_empty() {
        return Err(CaptureError::MeshEmpty {
            path: path.to_path_buf(),
        });
    }
    Ok(welder.finish())
}

fn parse_floats<'a, const N: usize>(toks: &mut impl Iterator<Item = &'a str>) -> Option<[f32; N]> {
    let mut out = [0.0f32; N];
    for o in out.iter_mut() {
        *o = toks.next()?.parse().ok()?;
    }
    Some(out)
}

/// OBJ index (1-based, or negative from the end) to a 0-based index below `len`.
fn resolve_index(tok: &str, len: usize) -> Result<usize, String> {
    let i: i64 = tok
        .parse()
        .map_err(|_| format!("{tok:?} is not an integer"))?;
    let r = if i > 0 { i - 1 } else { len as i64 + i };
    if i == 0 || r < 0 || r >= len as i64 {
        return Err(format!("{i} out of range ({len} defined so far)"));
    }
    Ok(r as usize)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn obj_index_resolution() {
        assert_eq!(resolve_index("1", 3), Ok(0));
        assert_eq!(resolve_index("-1", 3), Ok(2));
        assert!(resolve_index("0", 3).is_err());
        assert!(resolve_index("4", 3).is_err());
        assert!(resolve_index("-4", 3).is_err());
    }
}
