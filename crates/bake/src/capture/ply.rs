//! PLY proxy meshes (ascii, binary little- and big-endian).

use std::path::Path;

use dnr_runtime::scene::Primitive;
use glam::{Vec2, Vec3};

use super::error::CaptureError;
use super::mesh::{push_fan, too_many_triangles, MeshLimits, Welder};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum PlyFormat {
    Ascii,
    Little,
    Big,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(s: &str) -> Option<Scalar> {
        Some(match s {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }
}

#[derive(Clone, Debug)]
enum PlyProperty {
    Scalar {
        name: String,
        ty: Scalar,
    },
    List {
        name: String,
        count: Scalar,
        item: Scalar,
    },
}

#[derive(Clone, Debug)]
struct PlyElement {
    name: String,
    count: usize,
    props: Vec<PlyProperty>,
}

/// Reads values of a PLY body one at a time, ascii (one record per line) or binary.
struct PlyBody<'a> {
    format: PlyFormat,
    bytes: &'a [u8],
    pos: usize,
    line: usize,
    tokens: std::vec::IntoIter<&'a str>,
}

impl<'a> PlyBody<'a> {
    /// Starts a record (ascii: reads its line).
    fn begin_record(&mut self) -> Result<(), String> {
        if self.format != PlyFormat::Ascii {
            return Ok(());
        }
        if self.tokens.len() != 0 {
            return Err("extra values at the end of the previous record".into());
        }
        loop {
            if self.pos >= self.bytes.len() {
                return Err("unexpected end of file".into());
            }
            let end = self.bytes[self.pos..]
                .iter()
                .position(|&b| b == b'\n')
                .map_or(self.bytes.len(), |e| self.pos + e);
            let line = std::str::from_utf8(&self.bytes[self.pos..end])
                .map_err(|_| "not UTF-8 text".to_string())?;
            self.pos = end + 1;
            self.line += 1;
            let toks: Vec<&'a str> = line.split_whitespace().collect();
            if !toks.is_empty() {
                self.tokens = toks.into_iter();
                return Ok(());
            }
        }
    }

    fn value(&mut self, ty: Scalar) -> Result<f64, String> {
        if self.format == PlyFormat::Ascii {
            let t = self.tokens.next().ok_or("too few values in the record")?;
            return t
                .parse::<f64>()
                .map_err(|_| format!("{t:?} is not a number"));
        }
        let n = ty.size();
        let b = self
            .bytes
            .get(self.pos..self.pos + n)
            .ok_or("unexpected end of file")?;
        self.pos += n;
        let mut a = [0u8; 8];
        a[..n].copy_from_slice(b);
        if self.format == PlyFormat::Big {
            a[..n].reverse();
        }
        Ok(match ty {
            Scalar::I8 => a[0] as i8 as f64,
            Scalar::U8 => a[0] as f64,
            Scalar::I16 => i16::from_le_bytes([a[0], a[1]]) as f64,
            Scalar::U16 => u16::from_le_bytes([a[0], a[1]]) as f64,
            Scalar::I32 => i32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
            Scalar::U32 => u32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
            Scalar::F32 => f32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
            Scalar::F64 => f64::from_le_bytes(a),
        })
    }

    fn location(&self, element: &str, index: usize) -> String {
        match self.format {
            PlyFormat::Ascii => format!("line {}", self.line),
            _ => format!("element {element}[{index}]"),
        }
    }
}

/// UV property name pairs accepted on PLY vertices, in order of preference.
const PLY_UV_NAMES: [(&str, &str); 4] = [
    ("s", "t"),
    ("u", "v"),
    ("texture_u", "texture_v"),
    ("texture_s", "texture_t"),
];

/// Parses a PLY file (ascii, binary little- or big-endian): vertex `x, y, z` plus UVs as
/// `s, t`, `u, v`, `texture_u, texture_v` or `texture_s, texture_t`, or per-corner UVs as a
/// face list property `texcoord` (without either the mesh is read without UVs); faces from
/// the list `vertex_indices` (or `vertex_index`), fan triangulated. Other elements and
/// properties (normals, colours, confidences) are skipped.
pub fn parse_ply(
    path: &Path,
    bytes: &[u8],
    limits: &MeshLimits,
) -> Result<Primitive, CaptureError> {
    let perr = |location: String, message: String| CaptureError::MeshParse {
        path: path.to_path_buf(),
        location,
        message,
    };
    // Header: text lines up to `end_header`.
    let mut pos = 0usize;
    let mut line_no = 0usize;
    let mut format = None;
    let mut elements: Vec<PlyElement> = Vec::new();
    loop {
        let end = bytes[pos..]
            .iter()
            .position(|&b| b == b'\n')
            .map(|e| pos + e)
            .ok_or_else(|| {
                perr(
                    format!("line {}", line_no + 1),
                    "header has no end_header line".into(),
                )
            })?;
        line_no += 1;
        let here = format!("line {line_no}");
        let line = std::str::from_utf8(&bytes[pos..end])
            .map_err(|_| perr(here.clone(), "header is not text".into()))?;
        let line = line.trim_end_matches('\r').trim();
        pos = end + 1;
        let toks: Vec<&str> = line.split_whitespace().collect();
        if line_no == 1 {
            if line != "ply" {
                return Err(perr(
                    here,
                    "not a PLY file (first line must be `ply`)".into(),
                ));
            }
            continue;
        }
        match toks.first().copied() {
            Some("format") => {
                format = Some(match toks.get(1).copied() {
                    Some("ascii") => PlyFormat::Ascii,
                    Some("binary_little_endian") => PlyFormat::Little,
                    Some("binary_big_endian") => PlyFormat::Big,
                    other => return Err(perr(here, format!("unknown format {other:?}"))),
                });
            }
            Some("element") => {
                let (Some(name), Some(count)) = (
                    toks.get(1),
                    toks.get(2).and_then(|c| c.parse::<usize>().ok()),
                ) else {
                    return Err(perr(here, "expected `element NAME COUNT`".into()));
                };
                elements.push(PlyElement {
                    name: name.to_string(),
                    count,
                    props: Vec::new(),
                });
            }
            Some("property") => {
                let el = elements
                    .last_mut()
                    .ok_or_else(|| perr(here.clone(), "property before any element".into()))?;
                let prop = if toks.get(1) == Some(&"list") {
                    match (
                        toks.get(2).and_then(|t| Scalar::parse(t)),
                        toks.get(3).and_then(|t| Scalar::parse(t)),
                        toks.get(4),
                    ) {
                        (Some(count), Some(item), Some(name)) => PlyProperty::List {
                            name: name.to_string(),
                            count,
                            item,
                        },
                        _ => {
                            return Err(perr(
                                here,
                                "expected `property list COUNT_TYPE ITEM_TYPE NAME`".into(),
                            ))
                        }
                    }
                } else {
                    match (toks.get(1).and_then(|t| Scalar::parse(t)), toks.get(2)) {
                        (Some(ty), Some(name)) => PlyProperty::Scalar {
                            name: name.to_string(),
                            ty,
                        },
                        _ => return Err(perr(here, "expected `property TYPE NAME`".into())),
                    }
                };
                el.props.push(prop);
            }
            Some("end_header") => break,
            Some("comment") | Some("obj_info") | None => {}
            Some(other) => return Err(perr(here, format!("unknown header keyword {other:?}"))),
        }
    }
    let format = format.ok_or_else(|| perr("header".into(), "missing `format` line".into()))?;

    // Counts are checked against the limits and the bytes left before anything is allocated.
    let remaining = bytes.len() - pos;
    for el in &elements {
        let min_record = match format {
            PlyFormat::Ascii => 2,
            _ => el
                .props
                .iter()
                .map(|p| match p {
                    PlyProperty::Scalar { ty, .. } => ty.size(),
                    PlyProperty::List { count, .. } => count.size(),
                })
                .sum::<usize>(),
        };
        let too_many = (el.name == "face" && el.count > limits.max_triangles)
            || (el.name == "vertex" && el.count > limits.max_triangles.saturating_mul(3));
        if too_many {
            return Err(CaptureError::MeshTooLarge {
                path: path.to_path_buf(),
                message: format!("element {} count {} over the limit", el.name, el.count),
            });
        }
        if el.count.saturating_mul(min_record) > remaining {
            return Err(perr(
                "header".into(),
                format!(
                    "element {} count {} does not fit in the file",
                    el.name, el.count
                ),
            ));
        }
    }

    let mut body = PlyBody {
        format,
        bytes,
        pos,
        line: line_no,
        tokens: Vec::new().into_iter(),
    };
    let mut positions: Vec<Vec3> = Vec::new();
    let mut vertex_uvs: Vec<Vec2> = Vec::new();
    let mut have_vertex_uvs = false;
    let mut welder = Welder::new();
    let mut corners: Vec<u32> = Vec::new();
    for el in &elements {
        match el.name.as_str() {
            "vertex" => {
                let idx = |n: &str| {
                    el.props
                        .iter()
                        .position(|p| matches!(p, PlyProperty::Scalar { name, .. } if name == n))
                };
                let (Some(ix), Some(iy), Some(iz)) = (idx("x"), idx("y"), idx("z")) else {
                    return Err(perr(
                        "header".into(),
                        "element vertex needs scalar properties x, y, z".into(),
                    ));
                };
                let uv_idx = PLY_UV_NAMES
                    .iter()
                    .find_map(|(a, b)| Some((idx(a)?, idx(b)?)));
                have_vertex_uvs = uv_idx.is_some();
                positions.reserve(el.count);
                vertex_uvs.reserve(if have_vertex_uvs { el.count } else { 0 });
                let mut vals = vec![0.0f64; el.props.len()];
                for r in 0..el.count {
                    let e = |m: String, b: &PlyBody<'_>| perr(b.location("vertex", r), m);
                    body.begin_record().map_err(|m| e(m, &body))?;
                    for (k, p) in el.props.iter().enumerate() {
                        vals[k] = read_property(&mut body, p).map_err(|m| e(m, &body))?;
                    }
                    positions.push(Vec3::new(vals[ix] as f32, vals[iy] as f32, vals[iz] as f32));
                    if let Some((iu, iv)) = uv_idx {
                        vertex_uvs.push(Vec2::new(vals[iu] as f32, 1.0 - vals[iv] as f32));
                    }
                }
            }
            "face" => {
                let list_idx = |n: &str| {
                    el.props
                        .iter()
                        .position(|p| matches!(p, PlyProperty::List { name, .. } if name == n))
                };
                let Some(iv) = list_idx("vertex_indices").or_else(|| list_idx("vertex_index"))
                else {
                    return Err(perr(
                        "header".into(),
                        "element face needs a list property vertex_indices".into(),
                    ));
                };
                let itc = list_idx("texcoord");
                for r in 0..el.count {
                    let e = |m: String, b: &PlyBody<'_>| perr(b.location("face", r), m);
                    body.begin_record().map_err(|m| e(m, &body))?;
                    let mut verts: Vec<u32> = Vec::new();
                    let mut tcs: Vec<f32> = Vec::new();
                    for (k, p) in el.props.iter().enumerate() {
                        let PlyProperty::List { count, item, .. } = p else {
                            read_property(&mut body, p).map_err(|m| e(m, &body))?;
                            continue;
                        };
                        let n = body.value(*count).map_err(|m| e(m, &body))?;
                        if !(0.0..=1e6).contains(&n) || n.fract() != 0.0 {
                            return Err(e(format!("bad list length {n}"), &body));
                        }
                        for _ in 0..n as usize {
                            let x = body.value(*item).map_err(|m| e(m, &body))?;
                            if k == iv {
                                if !(0.0..positions.len() as f64).contains(&x) || x.fract() != 0.0 {
                                    return Err(e(
                                        format!(
                                            "vertex index {x} out of range ({} vertices)",
                                            positions.len()
                                        ),
                                        &body,
                                    ));
                                }
                                verts.push(x as u32);
                            } else if Some(k) == itc {
                                tcs.push(x as f32);
                            }
                        }
                    }
                    if verts.len() < 3 {
                        return Err(e(
                            format!("face with {} corners (at least 3 needed)", verts.len()),
                            &body,
                        ));
                    }
                    corners.clear();
                    if tcs.len() == verts.len() * 2 {
                        for (c, &vi) in verts.iter().enumerate() {
                            let uv = Vec2::new(tcs[2 * c], 1.0 - tcs[2 * c + 1]);
                            let key = (uv.x.to_bits() as u64) << 32 | uv.y.to_bits() as u64;
                            corners.push(welder.vertex(
                                vi,
                                positions[vi as usize],
                                Some((key, uv)),
                            ));
                        }
                    } else {
                        for &vi in &verts {
                            let uv = have_vertex_uvs.then(|| (0, vertex_uvs[vi as usize]));
                            corners.push(welder.vertex(vi, positions[vi as usize], uv));
                        }
                    }
                    push_fan(welder.indices(), &corners, limits)
                        .ok_or_else(|| too_many_triangles(path, limits))?;
                }
            }
            other => {
                for r in 0..el.count {
                    let e = |m: String, b: &PlyBody<'_>| perr(b.location(other, r), m);
                    body.begin_record().map_err(|m| e(m, &body))?;
                    for p in &el.props {
                        read_property(&mut body, p).map_err(|m| e(m, &body))?;
                    }
                }
            }
        }
    }
    if welder.indices().is_empty() {
        return Err(CaptureError::MeshEmpty {
            path: path.to_path_buf(),
        });
    }
    Ok(welder.finish())
}

/// Reads one property; lists are consumed and their first value is returned (unused).
fn read_property(body: &mut PlyBody<'_>, p: &PlyProperty) -> Result<f64, String> {
    match p {
        PlyProperty::Scalar { ty, .. } => body.value(*ty),
        PlyProperty::List { count, item, name } => {
            let n = body.value(*count)?;
            if !(0.0..=1e6).contains(&n) || n.fract() != 0.0 {
                return Err(format!("bad length {n} of list {name}"));
            }
            let mut first = 0.0;
            for i in 0..n as usize {
                let x = body.value(*item)?;
                if i == 0 {
                    first = x;
                }
            }
            Ok(first)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ply_scalar_names() {
        assert_eq!(Scalar::parse("float32"), Some(Scalar::F32));
        assert_eq!(Scalar::parse("uchar"), Some(Scalar::U8));
        assert_eq!(Scalar::parse("bogus"), None);
    }
}
