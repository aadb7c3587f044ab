//! `transforms.json` parsing (NeRF / instant-ngp / nerfstudio convention) and camera
//! intrinsics resolution.
//!
//! Keys read, at the top level (`docs/capture-format.md` has their meaning): `camera_model`,
//! `fl_x`, `fl_y`, `cx`, `cy`, `w`, `h`, `k1`, `k2`, `k3`, `k4`, `p1`, `p2`,
//! `distortion_params`, `camera_angle_x`, `camera_angle_y`, `is_fisheye`, `aabb_scale`,
//! `scale`, `offset`, `applied_transform`, `mesh_path`, `frames`; in each frame: `file_path`,
//! `transform_matrix`, `mask_path` and, overriding the top level key by key, every intrinsic
//! and lens key above. Every other key is ignored and listed in
//! the parsed file's `ignored_keys` (`dnr-bake --verbose` prints them).
//!
//! The JSON is walked as a `serde_json::Value` so every problem can name its field
//! (`frames[3].transform_matrix[1][2]`). Python's `json.dump` writes the non-standard tokens
//! `NaN` and `Infinity`; a file holding them is re-read with those tokens as `null`, so the
//! error names the frame and matrix entry instead of only a line and column.

use std::path::{Path, PathBuf};

use glam::DMat4;
use serde_json::{Map, Value};

use super::distortion::{Distortion, LensModel};
use super::error::CaptureError;
use super::CameraRecord;

/// Intrinsic keys as written at the top level or in one frame; absent keys are `None`.
#[derive(Clone, Debug, Default)]
pub(crate) struct RawIntrinsics {
    pub fl_x: Option<f64>,
    pub fl_y: Option<f64>,
    pub cx: Option<f64>,
    pub cy: Option<f64>,
    pub w: Option<f64>,
    pub h: Option<f64>,
    pub camera_angle_x: Option<f64>,
    pub camera_angle_y: Option<f64>,
    pub k1: Option<f64>,
    pub k2: Option<f64>,
    pub k3: Option<f64>,
    pub k4: Option<f64>,
    pub p1: Option<f64>,
    pub p2: Option<f64>,
    /// `distortion_params`: nerfstudio's `[k1, k2, k3, k4, p1, p2]`.
    pub distortion_params: Option<[f64; 6]>,
    /// `camera_model`, checked to be a supported name.
    pub camera_model: Option<&'static str>,
    /// instant-ngp's `is_fisheye`.
    pub is_fisheye: Option<bool>,
}

impl RawIntrinsics {
    /// Per-frame keys override top-level keys of the same name.
    fn or(&self, top: &RawIntrinsics) -> RawIntrinsics {
        RawIntrinsics {
            fl_x: self.fl_x.or(top.fl_x),
            fl_y: self.fl_y.or(top.fl_y),
            cx: self.cx.or(top.cx),
            cy: self.cy.or(top.cy),
            w: self.w.or(top.w),
            h: self.h.or(top.h),
            camera_angle_x: self.camera_angle_x.or(top.camera_angle_x),
            camera_angle_y: self.camera_angle_y.or(top.camera_angle_y),
            k1: self.k1.or(top.k1),
            k2: self.k2.or(top.k2),
            k3: self.k3.or(top.k3),
            k4: self.k4.or(top.k4),
            p1: self.p1.or(top.p1),
            p2: self.p2.or(top.p2),
            distortion_params: self.distortion_params.or(top.distortion_params),
            camera_model: self.camera_model.or(top.camera_model),
            is_fisheye: self.is_fisheye.or(top.is_fisheye),
        }
    }
}

/// One entry of `frames[]`.
#[derive(Clone, Debug)]
pub(crate) struct RawFrame {
    /// Index in the file's `frames` array (for error messages).
    pub index: usize,
    /// `file_path` as written.
    pub file_path: String,
    /// `mask_path` as written, if any.
    pub mask_path: Option<String>,
    /// Camera-to-world, validated finite and non-singular.
    pub cam_to_world: DMat4,
    /// Per-frame intrinsic overrides.
    pub intrinsics: RawIntrinsics,
}

/// A parsed transforms file.
#[derive(Clone, Debug)]
pub(crate) struct TransformsFile {
    pub path: PathBuf,
    pub top: RawIntrinsics,
    pub mesh_path: Option<String>,
    pub frames: Vec<RawFrame>,
    /// Non-fatal remarks (e.g. a non-orthonormal rotation).
    pub warnings: Vec<String>,
    /// nerfstudio's `applied_transform` (3x4 or 4x4, as a 4x4): what `ns-process-data` applied
    /// to the original reconstruction's world coordinates to get the poses' ones.
    pub applied_transform: Option<DMat4>,
    /// instant-ngp's scene box: `aabb_scale`, `scale` (default 0.33), `offset` (default 0.5
    /// on every axis).
    pub ngp_box: Option<NgpBox>,
    /// Keys this reader does not use: `key` at the top level, `frames[].key (N frames)`.
    pub ignored_keys: Vec<String>,
}

/// instant-ngp's scene bounding box keys.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NgpBox {
    /// `aabb_scale`.
    pub aabb_scale: f64,
    /// `scale`.
    pub scale: f64,
    /// `offset`.
    pub offset: [f64; 3],
}

impl NgpBox {
    /// The box in the poses' coordinates: instant-ngp maps `p` to `p * scale + offset` and
    /// trains inside the cube of side `aabb_scale` centred on `(0.5, 0.5, 0.5)` (its axis
    /// cycling leaves a cube with equal offsets unchanged). Returns `(min, max)`.
    pub fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        let h = 0.5 * self.aabb_scale;
        let lo = std::array::from_fn(|k| (0.5 - h - self.offset[k]) / self.scale);
        let hi = std::array::from_fn(|k| (0.5 + h - self.offset[k]) / self.scale);
        (lo, hi)
    }
}

/// Top-level keys the reader uses.
const TOP_KEYS: [&str; 23] = [
    "camera_model",
    "fl_x",
    "fl_y",
    "cx",
    "cy",
    "w",
    "h",
    "k1",
    "k2",
    "k3",
    "k4",
    "p1",
    "p2",
    "distortion_params",
    "camera_angle_x",
    "camera_angle_y",
    "is_fisheye",
    "aabb_scale",
    "scale",
    "offset",
    "applied_transform",
    "mesh_path",
    "frames",
];

/// Per-frame keys the reader uses besides the intrinsic and lens keys.
const FRAME_KEYS: [&str; 3] = ["file_path", "transform_matrix", "mask_path"];

/// Reads and parses a transforms file. `max_bytes` and `max_frames` are checked before the
/// file body is read and before frames are materialised.
pub(crate) fn read_transforms(
    path: &Path,
    max_bytes: u64,
    max_frames: usize,
) -> Result<TransformsFile, CaptureError> {
    let len = std::fs::metadata(path)
        .map_err(|e| CaptureError::io(path, e))?
        .len();
    if len > max_bytes {
        return Err(CaptureError::TooLarge {
            path: path.to_path_buf(),
            message: format!("transforms file is {len} bytes, over the limit of {max_bytes}"),
        });
    }
    let bytes = std::fs::read(path).map_err(|e| CaptureError::io(path, e))?;
    let text = String::from_utf8(bytes).map_err(|e| CaptureError::Field {
        path: path.to_path_buf(),
        field: "(file)".into(),
        message: format!("not UTF-8 text: {e}"),
    })?;
    parse_transforms(path, &text, max_frames)
}

/// Parses the text of a transforms file (see [`read_transforms`]).
pub(crate) fn parse_transforms(
    path: &Path,
    text: &str,
    max_frames: usize,
) -> Result<TransformsFile, CaptureError> {
    let root: Value = match serde_json::from_str(text) {
        Ok(v) => v,
        Err(e) => {
            let original = CaptureError::Json {
                path: path.to_path_buf(),
                line: e.line(),
                column: e.column(),
                // serde_json appends the position, which the error already shows.
                message: {
                    let m = e.to_string();
                    let suffix = format!(" at line {} column {}", e.line(), e.column());
                    m.strip_suffix(&suffix).map(str::to_string).unwrap_or(m)
                },
            };
            if !e.is_syntax() {
                return Err(original);
            }
            match sanitize_non_finite(text).and_then(|t| serde_json::from_str(&t).ok()) {
                Some(v) => v,
                None => return Err(original),
            }
        }
    };
    let ctx = Ctx { path };
    let obj = root
        .as_object()
        .ok_or_else(|| ctx.err("(root)", "expected a JSON object"))?;

    let top = read_intrinsics(&ctx, obj, "")?;
    let mesh_path = match obj.get("mesh_path") {
        None | Some(Value::Null) => None,
        Some(Value::String(s)) => Some(s.clone()),
        Some(_) => return Err(ctx.err("mesh_path", "expected a string")),
    };
    let applied_transform = match obj.get("applied_transform") {
        None | Some(Value::Null) => None,
        Some(v) => Some(read_applied_transform(&ctx, v)?),
    };
    let ngp_box = read_ngp_box(&ctx, obj)?;
    let mut ignored_keys: Vec<String> = obj
        .keys()
        .filter(|k| !TOP_KEYS.contains(&k.as_str()))
        .cloned()
        .collect();
    let mut frame_ignored: Vec<(String, usize)> = Vec::new();
    let frames_v = obj
        .get("frames")
        .ok_or_else(|| ctx.err("frames", "missing (expected an array of frames)"))?
        .as_array()
        .ok_or_else(|| ctx.err("frames", "expected an array"))?;
    if frames_v.is_empty() {
        return Err(CaptureError::NoFrames {
            path: path.to_path_buf(),
            message: "the frames array is empty".into(),
        });
    }
    if frames_v.len() > max_frames {
        return Err(CaptureError::TooManyFrames {
            path: path.to_path_buf(),
            count: frames_v.len(),
            max: max_frames,
        });
    }

    let mut frames = Vec::with_capacity(frames_v.len());
    let mut warnings = Vec::new();
    for (i, fv) in frames_v.iter().enumerate() {
        let field = format!("frames[{i}]");
        let fo = fv
            .as_object()
            .ok_or_else(|| ctx.err(&field, "expected an object"))?;
        let file_path = match fo.get("file_path") {
            Some(Value::String(s)) if !s.is_empty() => s.clone(),
            Some(Value::String(_)) => {
                return Err(ctx.err(&format!("{field}.file_path"), "is empty"))
            }
            Some(_) => return Err(ctx.err(&format!("{field}.file_path"), "expected a string")),
            None => return Err(ctx.err(&format!("{field}.file_path"), "missing")),
        };
        let mask_path = match fo.get("mask_path") {
            None | Some(Value::Null) => None,
            Some(Value::String(s)) if !s.is_empty() => Some(s.clone()),
            Some(_) => {
                return Err(ctx.err(&format!("{field}.mask_path"), "expected a non-empty string"))
            }
        };
        let cam_to_world = read_matrix(&ctx, fo, &field, &mut warnings)?;
        let intrinsics = read_intrinsics(&ctx, fo, &format!("{field}."))?;
        for k in fo.keys() {
            if !FRAME_KEYS.contains(&k.as_str()) && !INTRINSIC_KEYS.contains(&k.as_str()) {
                match frame_ignored.iter_mut().find(|(name, _)| name == k) {
                    Some((_, n)) => *n += 1,
                    None => frame_ignored.push((k.clone(), 1)),
                }
            }
        }
        frames.push(RawFrame {
            index: i,
            file_path,
            mask_path,
            cam_to_world,
            intrinsics,
        });
    }
    ignored_keys.extend(
        frame_ignored
            .into_iter()
            .map(|(k, n)| format!("frames[].{k} ({n} frames)")),
    );
    Ok(TransformsFile {
        path: path.to_path_buf(),
        top,
        mesh_path,
        frames,
        warnings,
        applied_transform,
        ngp_box,
        ignored_keys,
    })
}

/// `applied_transform`: a 3x4 or 4x4 row-major matrix whose 3x3 part is a rotation times a
/// positive scale (a similarity; nerfstudio writes an axis permutation).
fn read_applied_transform(ctx: &Ctx<'_>, v: &Value) -> Result<DMat4, CaptureError> {
    let field = "applied_transform";
    let rows = v
        .as_array()
        .filter(|r| r.len() == 3 || r.len() == 4)
        .ok_or_else(|| ctx.err(field, "expected a 3x4 or 4x4 array of rows"))?;
    let mut m = [[0.0f64; 4]; 4];
    m[3][3] = 1.0;
    for (r, row) in rows.iter().enumerate() {
        let row = row
            .as_array()
            .filter(|c| c.len() == 4)
            .ok_or_else(|| ctx.err(&format!("{field}[{r}]"), "expected a row of 4 numbers"))?;
        for (c, x) in row.iter().enumerate() {
            m[r][c] = x
                .as_f64()
                .filter(|x| x.is_finite())
                .ok_or_else(|| ctx.err(&format!("{field}[{r}][{c}]"), "not a finite number"))?;
        }
    }
    if m[3] != [0.0, 0.0, 0.0, 1.0] {
        return Err(ctx.err(&format!("{field}[3]"), "last row must be [0, 0, 0, 1]"));
    }
    let cols: [[f64; 4]; 4] = std::array::from_fn(|c| std::array::from_fn(|r| m[r][c]));
    let t = DMat4::from_cols_array_2d(&cols);
    let a = [
        t.x_axis.truncate(),
        t.y_axis.truncate(),
        t.z_axis.truncate(),
    ];
    let s = a[0].length();
    let similar = s > 1e-9
        && a.iter().all(|c| (c.length() - s).abs() <= 1e-4 * s)
        && a[0].dot(a[1]).abs() <= 1e-4 * s * s
        && a[0].dot(a[2]).abs() <= 1e-4 * s * s
        && a[1].dot(a[2]).abs() <= 1e-4 * s * s;
    if !similar {
        return Err(ctx.err(
            field,
            "the 3x3 part must be a rotation (or reflection) times a positive scale",
        ));
    }
    Ok(t)
}

/// instant-ngp's `aabb_scale` with its `scale` and `offset`.
fn read_ngp_box(ctx: &Ctx<'_>, obj: &Map<String, Value>) -> Result<Option<NgpBox>, CaptureError> {
    let num = |key: &str| -> Result<Option<f64>, CaptureError> {
        match obj.get(key) {
            None | Some(Value::Null) => Ok(None),
            Some(v) => v
                .as_f64()
                .filter(|x| x.is_finite() && *x > 0.0)
                .map(Some)
                .ok_or_else(|| ctx.err(key, "expected a positive number")),
        }
    };
    let Some(aabb_scale) = num("aabb_scale")? else {
        return Ok(None);
    };
    let scale = num("scale")?.unwrap_or(0.33);
    let offset = match obj.get("offset") {
        None | Some(Value::Null) => [0.5; 3],
        Some(Value::Array(a)) if a.len() == 3 => {
            let mut o = [0.0; 3];
            for (k, x) in a.iter().enumerate() {
                o[k] = x
                    .as_f64()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| ctx.err(&format!("offset[{k}]"), "not a finite number"))?;
            }
            o
        }
        Some(_) => return Err(ctx.err("offset", "expected an array of 3 numbers")),
    };
    Ok(Some(NgpBox {
        aabb_scale,
        scale,
        offset,
    }))
}

struct Ctx<'a> {
    path: &'a Path,
}

impl Ctx<'_> {
    fn err(&self, field: &str, message: impl Into<String>) -> CaptureError {
        CaptureError::Field {
            path: self.path.to_path_buf(),
            field: field.to_string(),
            message: message.into(),
        }
    }
}

/// Camera models `camera_model` may name.
pub const CAMERA_MODELS: [&str; 6] = [
    "OPENCV",
    "OPENCV_FISHEYE",
    "PINHOLE",
    "SIMPLE_PINHOLE",
    "SIMPLE_RADIAL",
    "RADIAL",
];

fn check_camera_model(
    ctx: &Ctx<'_>,
    field: &str,
    model: &str,
) -> Result<&'static str, CaptureError> {
    CAMERA_MODELS
        .iter()
        .find(|m| **m == model)
        .copied()
        .ok_or_else(|| {
            ctx.err(
                field,
                format!(
                    "camera model {model:?} is not supported (supported: {})",
                    CAMERA_MODELS.join(", ")
                ),
            )
        })
}

/// Intrinsic and lens keys, at the top level or per frame.
const INTRINSIC_KEYS: [&str; 17] = [
    "fl_x",
    "fl_y",
    "cx",
    "cy",
    "w",
    "h",
    "camera_angle_x",
    "camera_angle_y",
    "k1",
    "k2",
    "k3",
    "k4",
    "p1",
    "p2",
    "distortion_params",
    "camera_model",
    "is_fisheye",
];

/// The numeric intrinsic keys, in the order of [`read_intrinsics`]'s array.
const NUMERIC_KEYS: [&str; 14] = [
    "fl_x",
    "fl_y",
    "cx",
    "cy",
    "w",
    "h",
    "camera_angle_x",
    "camera_angle_y",
    "k1",
    "k2",
    "k3",
    "k4",
    "p1",
    "p2",
];

fn read_intrinsics(
    ctx: &Ctx<'_>,
    obj: &Map<String, Value>,
    prefix: &str,
) -> Result<RawIntrinsics, CaptureError> {
    let mut vals = [None; 14];
    for (slot, key) in vals.iter_mut().zip(NUMERIC_KEYS) {
        *slot = match obj.get(key) {
            None => None,
            Some(Value::Number(n)) => {
                let x = n
                    .as_f64()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| ctx.err(&format!("{prefix}{key}"), "not a finite number"))?;
                Some(x)
            }
            Some(Value::Null) => {
                return Err(ctx.err(
                    &format!("{prefix}{key}"),
                    "not a finite number (NaN, Infinity or null)",
                ))
            }
            Some(_) => return Err(ctx.err(&format!("{prefix}{key}"), "expected a number")),
        };
    }
    let [fl_x, fl_y, cx, cy, w, h, camera_angle_x, camera_angle_y, k1, k2, k3, k4, p1, p2] = vals;
    let camera_model = match obj.get("camera_model") {
        None | Some(Value::Null) => None,
        Some(Value::String(m)) => Some(check_camera_model(
            ctx,
            &format!("{prefix}camera_model"),
            m,
        )?),
        Some(_) => return Err(ctx.err(&format!("{prefix}camera_model"), "expected a string")),
    };
    let is_fisheye = match obj.get("is_fisheye") {
        None | Some(Value::Null) => None,
        Some(Value::Bool(b)) => Some(*b),
        Some(_) => return Err(ctx.err(&format!("{prefix}is_fisheye"), "expected true or false")),
    };
    let distortion_params = match obj.get("distortion_params") {
        None | Some(Value::Null) => None,
        Some(Value::Array(a)) if a.len() <= 6 => {
            let mut d = [0.0; 6];
            for (k, x) in a.iter().enumerate() {
                d[k] = x.as_f64().filter(|x| x.is_finite()).ok_or_else(|| {
                    ctx.err(
                        &format!("{prefix}distortion_params[{k}]"),
                        "not a finite number",
                    )
                })?;
            }
            Some(d)
        }
        Some(_) => {
            return Err(ctx.err(
                &format!("{prefix}distortion_params"),
                "expected an array of at most 6 numbers [k1, k2, k3, k4, p1, p2]",
            ))
        }
    };
    Ok(RawIntrinsics {
        fl_x,
        fl_y,
        cx,
        cy,
        w,
        h,
        camera_angle_x,
        camera_angle_y,
        k1,
        k2,
        k3,
        k4,
        p1,
        p2,
        distortion_params,
        camera_model,
        is_fisheye,
    })
}

/// Reads `transform_matrix` (4x4 row-major, or 3x4 with an implied `[0, 0, 0, 1]` row).
fn read_matrix(
    ctx: &Ctx<'_>,
    fo: &Map<String, Value>,
    field: &str,
    warnings: &mut Vec<String>,
) -> Result<DMat4, CaptureError> {
    let mfield = format!("{field}.transform_matrix");
    let rows = fo
        .get("transform_matrix")
        .ok_or_else(|| ctx.err(&mfield, "missing"))?
        .as_array()
        .filter(|r| r.len() == 4 || r.len() == 3)
        .ok_or_else(|| ctx.err(&mfield, "expected a 4x4 (or 3x4) array of rows"))?;
    let mut m = [[0.0f64; 4]; 4];
    m[3][3] = 1.0;
    for (r, row) in rows.iter().enumerate() {
        let row = row
            .as_array()
            .filter(|c| c.len() == 4)
            .ok_or_else(|| ctx.err(&format!("{mfield}[{r}]"), "expected a row of 4 numbers"))?;
        for (c, v) in row.iter().enumerate() {
            let x = v.as_f64().filter(|x| x.is_finite()).ok_or_else(|| {
                let what = if v.is_null() || v.is_number() {
                    "not a finite number (NaN, Infinity or null)"
                } else {
                    "expected a number"
                };
                ctx.err(&format!("{mfield}[{r}][{c}]"), what)
            })?;
            m[r][c] = x;
        }
    }
    let last = m[3];
    if (last[0].abs() + last[1].abs() + last[2].abs() + (last[3] - 1.0).abs()) > 1e-4 {
        return Err(ctx.err(
            &format!("{mfield}[3]"),
            format!("last row must be [0, 0, 0, 1] for a rigid camera pose, got {last:?}"),
        ));
    }
    // Columns of the rotation part (camera axes in world space).
    let col = |c: usize| [m[0][c], m[1][c], m[2][c]];
    let (a, b, cc) = (col(0), col(1), col(2));
    let norm = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    let det = a[0] * (b[1] * cc[2] - b[2] * cc[1]) - b[0] * (a[1] * cc[2] - a[2] * cc[1])
        + cc[0] * (a[1] * b[2] - a[2] * b[1]);
    let scale = norm(a) * norm(b) * norm(cc);
    // Scale-invariant test: |det| / product of column norms is |sin| of the axes' skew.
    if scale < 1e-30 || (det / scale).abs() < 1e-6 {
        return Err(ctx.err(
            &mfield,
            "singular (the 3x3 rotation part has zero determinant)",
        ));
    }
    let dot = |u: [f64; 3], v: [f64; 3]| u[0] * v[0] + u[1] * v[1] + u[2] * v[2];
    let off = dot(a, b).abs().max(dot(a, cc).abs()).max(dot(b, cc).abs());
    let unit = (norm(a) - 1.0)
        .abs()
        .max((norm(b) - 1.0).abs())
        .max((norm(cc) - 1.0).abs());
    if off > 1e-3 || unit > 1e-3 || det < 0.0 {
        warnings.push(format!(
            "{}: {mfield}: rotation part is not a proper orthonormal rotation (used as given)",
            ctx.path.display()
        ));
    }
    let cols: [[f64; 4]; 4] = std::array::from_fn(|c| std::array::from_fn(|r| m[r][c]));
    Ok(DMat4::from_cols_array_2d(&cols))
}

/// Replaces the bare tokens `NaN`, `Infinity` and `-Infinity` outside string literals by
/// `null`. Returns `None` when there were none (the syntax error has another cause).
fn sanitize_non_finite(text: &str) -> Option<String> {
    let mut out = String::with_capacity(text.len());
    let mut in_string = false;
    let mut escaped = false;
    let mut replaced = false;
    let mut rest = text;
    while let Some(ch) = rest.chars().next() {
        if in_string {
            out.push(ch);
            if escaped {
                escaped = false;
            } else if ch == '\\' {
                escaped = true;
            } else if ch == '"' {
                in_string = false;
            }
            rest = &rest[ch.len_utf8()..];
            continue;
        }
        if ch == '"' {
            in_string = true;
        } else {
            let token = ["-Infinity", "Infinity", "NaN"]
                .into_iter()
                .find(|t| rest.starts_with(t));
            if let Some(t) = token {
                out.push_str("null");
                rest = &rest[t.len()..];
                replaced = true;
                continue;
            }
        }
        out.push(ch);
        rest = &rest[ch.len_utf8()..];
    }
    replaced.then_some(out)
}

/// Camera and distortion of one frame once its image size is known.
pub(crate) struct ResolvedCamera {
    pub camera: CameraRecord,
    pub distortion: Distortion,
}

/// Resolves a frame's intrinsics: pixel intrinsics (`fl_x` ...) win over `camera_angle_x`;
/// per-frame keys override top-level ones; `fl_y` defaults to `camera_angle_y`, else `fl_x`;
/// `cx`, `cy` default to the image centre. `w`/`h`, when given, must equal the image size.
pub(crate) fn resolve_camera(
    file: &TransformsFile,
    frame: &RawFrame,
    image: &Path,
    image_size: (u32, u32),
) -> Result<ResolvedCamera, CaptureError> {
    let k = frame.intrinsics.or(&file.top);
    let ctx = Ctx { path: &file.path };
    let field = |key: &str| -> String {
        let set_in_frame = match key {
            "w" => frame.intrinsics.w.is_some(),
            "h" => frame.intrinsics.h.is_some(),
            "fl_x" => frame.intrinsics.fl_x.is_some(),
            "fl_y" => frame.intrinsics.fl_y.is_some(),
            "camera_angle_x" => frame.intrinsics.camera_angle_x.is_some(),
            "camera_angle_y" => frame.intrinsics.camera_angle_y.is_some(),
            _ => false,
        };
        if set_in_frame {
            format!("frames[{}].{key}", frame.index)
        } else {
            key.to_string()
        }
    };
    let (iw, ih) = image_size;
    let dim = |v: Option<f64>, key: &str| -> Result<Option<u32>, CaptureError> {
        match v {
            None => Ok(None),
            Some(x) if x >= 1.0 && x <= u32::MAX as f64 && x.fract() == 0.0 => Ok(Some(x as u32)),
            Some(x) => Err(ctx.err(
                &field(key),
                format!("expected a positive whole number of pixels, got {x}"),
            )),
        }
    };
    let w = dim(k.w, "w")?;
    let h = dim(k.h, "h")?;
    if w.is_some_and(|w| w != iw) || h.is_some_and(|h| h != ih) {
        return Err(CaptureError::ImageSize {
            image: image.to_path_buf(),
            path: file.path.clone(),
            field: format!("frames[{}] {}/{}", frame.index, field("w"), field("h")),
            width: iw,
            height: ih,
            expected_width: w.unwrap_or(iw),
            expected_height: h.unwrap_or(ih),
        });
    }
    let (wf, hf) = (iw as f64, ih as f64);
    let angle_focal = |angle: f64, extent: f64, key: &str| -> Result<f64, CaptureError> {
        if !(angle > 0.0 && angle < std::f64::consts::PI) {
            return Err(ctx.err(
                &field(key),
                format!("field of view must be in (0, pi) radians, got {angle}"),
            ));
        }
        Ok(0.5 * extent / (0.5 * angle).tan())
    };
    let fx = match (k.fl_x, k.camera_angle_x) {
        (Some(f), _) => f,
        (None, Some(a)) => angle_focal(a, wf, "camera_angle_x")?,
        (None, None) => match (k.fl_y, k.camera_angle_y) {
            (Some(f), _) => f,
            (None, Some(a)) => angle_focal(a, hf, "camera_angle_y")?,
            (None, None) => {
                return Err(ctx.err(
                    &format!("frames[{}]", frame.index),
                    "no intrinsics: need fl_x (pixels) or camera_angle_x (radians), at the top level or in the frame",
                ))
            }
        },
    };
    let fy = match (k.fl_y, k.camera_angle_y) {
        (Some(f), _) => f,
        (None, Some(a)) if k.fl_x.is_none() => angle_focal(a, hf, "camera_angle_y")?,
        _ => fx,
    };
    for (f, key) in [(fx, "fl_x"), (fy, "fl_y")] {
        if !(f.is_finite() && f > 0.0 && f < 1e9) {
            return Err(ctx.err(
                &field(key),
                format!("focal length must be positive and finite, got {f}"),
            ));
        }
    }
    let cx = k.cx.unwrap_or(0.5 * wf);
    let cy = k.cy.unwrap_or(0.5 * hf);
    let distortion = resolve_lens(&ctx, frame, &file.top, &k)?;
    Ok(ResolvedCamera {
        camera: CameraRecord {
            fx,
            fy,
            cx,
            cy,
            width: iw,
            height: ih,
            cam_to_world: frame.cam_to_world,
        },
        distortion,
    })
}

/// The lens of a frame: `is_fisheye` or `camera_model` pick the formula (without either, an
/// OpenCV lens when a coefficient is non-zero). Coefficients: the top level's `k1`..`p2` or
/// `distortion_params`, then the frame's: its `distortion_params` replace them all, its
/// `k1`..`p2` replace one each. Both forms at one level are an error.
fn resolve_lens(
    ctx: &Ctx<'_>,
    frame: &RawFrame,
    top: &RawIntrinsics,
    k: &RawIntrinsics,
) -> Result<Distortion, CaptureError> {
    let at = format!("frames[{}]", frame.index);
    let explicit = |r: &RawIntrinsics| [r.k1, r.k2, r.k3, r.k4, r.p1, r.p2];
    let mut c = [0.0f64; 6];
    for (level, r) in [("the top level", top), (at.as_str(), &frame.intrinsics)] {
        let keys = explicit(r);
        if r.distortion_params.is_some() && keys.iter().any(Option::is_some) {
            return Err(ctx.err(
                &at,
                format!("both distortion_params and k1..k4/p1/p2 are given at {level}: keep one"),
            ));
        }
        if let Some(d) = r.distortion_params {
            c = d;
        }
        for (slot, v) in c.iter_mut().zip(keys) {
            if let Some(v) = v {
                *slot = v;
            }
        }
    }
    let model = match (k.is_fisheye, k.camera_model) {
        (Some(true), None | Some("OPENCV_FISHEYE")) => LensModel::Fisheye,
        (Some(true), Some(m)) => {
            return Err(ctx.err(&at, format!("is_fisheye is true but camera_model is {m}")))
        }
        (_, Some("OPENCV_FISHEYE")) => LensModel::Fisheye,
        (_, Some("PINHOLE" | "SIMPLE_PINHOLE")) => {
            if c.iter().any(|&v| v != 0.0) {
                return Err(ctx.err(
                    &at,
                    "camera_model is a pinhole model but distortion coefficients are non-zero (set camera_model to OPENCV, or remove them)",
                ));
            }
            LensModel::Pinhole
        }
        (_, Some(_)) => LensModel::OpenCv,
        (_, None) if c.iter().any(|&v| v != 0.0) => LensModel::OpenCv,
        (_, None) => LensModel::Pinhole,
    };
    let [k1, k2, k3, k4, p1, p2] = c;
    if model == LensModel::Fisheye && (p1 != 0.0 || p2 != 0.0) {
        return Err(ctx.err(&at, "a fisheye lens has no tangential coefficients p1, p2"));
    }
    Ok(Distortion {
        model,
        k1,
        k2,
        k3,
        k4,
        p1,
        p2,
    })
}

/// Parses a transforms file's text and resolves every frame's camera for an image of
/// `image_size`, without touching the file system: the checks `Capture::load` runs on a
/// transforms file, for fuzzing and for tools that vet a file before loading images.
/// Returns the number of frames.
pub fn check_transforms_text(
    path: &Path,
    text: &str,
    max_frames: usize,
    image_size: (u32, u32),
) -> Result<usize, CaptureError> {
    let file = parse_transforms(path, text, max_frames)?;
    for frame in &file.frames {
        resolve_camera(&file, frame, path, image_size)?;
    }
    Ok(file.frames.len())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sanitize_replaces_tokens_outside_strings_only() {
        let s = sanitize_non_finite(r#"{"a": NaN, "NaN": "x NaN", "b": [-Infinity, Infinity]}"#)
            .unwrap();
        assert_eq!(s, r#"{"a": null, "NaN": "x NaN", "b": [null, null]}"#);
        assert!(sanitize_non_finite(r#"{"a": 1,}"#).is_none());
    }
}
