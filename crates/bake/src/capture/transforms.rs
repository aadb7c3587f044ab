//! `transforms.json` parsing (NeRF / instant-ngp / nerfstudio convention) and camera
//! intrinsics resolution.
//!
//! The JSON is walked as a `serde_json::Value` so every problem can name its field
//! (`frames[3].transform_matrix[1][2]`). Python's `json.dump` writes the non-standard tokens
//! `NaN` and `Infinity`; a file holding them is re-read with those tokens as `null`, so the
//! error names the frame and matrix entry instead of only a line and column.

use std::path::{Path, PathBuf};

use dnr_runtime::camera::Camera;
use glam::Mat4;
use serde_json::{Map, Value};

use super::error::CaptureError;

/// OpenCV radial/tangential distortion coefficients (`k1`, `k2`, `k3`, `p1`, `p2`) of a
/// pinhole camera, applied to normalised image coordinates.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Distortion {
    /// Radial r^2 coefficient.
    pub k1: f32,
    /// Radial r^4 coefficient.
    pub k2: f32,
    /// Radial r^6 coefficient (nerfstudio writes it; the capture contract lists k1, k2, p1, p2).
    pub k3: f32,
    /// Tangential coefficient p1.
    pub p1: f32,
    /// Tangential coefficient p2.
    pub p2: f32,
}

impl Distortion {
    /// True when every coefficient is zero (a plain pinhole camera).
    pub fn is_identity(&self) -> bool {
        self.k1 == 0.0 && self.k2 == 0.0 && self.k3 == 0.0 && self.p1 == 0.0 && self.p2 == 0.0
    }

    /// Maps undistorted normalised coordinates to distorted ones (the OpenCV forward model).
    pub fn distort(&self, x: f32, y: f32) -> (f32, f32) {
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        let xd = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x);
        let yd = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y;
        (xd, yd)
    }
}

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
    pub p1: Option<f64>,
    pub p2: Option<f64>,
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
            p1: self.p1.or(top.p1),
            p2: self.p2.or(top.p2),
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
    /// Camera-to-world, validated finite and non-singular.
    pub cam_to_world: Mat4,
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
}

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
    if let Some(Value::String(model)) = obj.get("camera_model") {
        check_camera_model(&ctx, "camera_model", model)?;
    }
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
        if let Some(Value::String(model)) = fo.get("camera_model") {
            check_camera_model(&ctx, &format!("{field}.camera_model"), model)?;
        }
        let cam_to_world = read_matrix(&ctx, fo, &field, &mut warnings)?;
        let intrinsics = read_intrinsics(&ctx, fo, &format!("{field}."))?;
        frames.push(RawFrame {
            index: i,
            file_path,
            cam_to_world,
            intrinsics,
        });
    }
    Ok(TransformsFile {
        path: path.to_path_buf(),
        top,
        mesh_path,
        frames,
        warnings,
    })
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

fn check_camera_model(ctx: &Ctx<'_>, field: &str, model: &str) -> Result<(), CaptureError> {
    match model {
        "OPENCV" | "PINHOLE" | "SIMPLE_PINHOLE" | "SIMPLE_RADIAL" | "RADIAL" => Ok(()),
        other => Err(ctx.err(
            field,
            format!("camera model {other:?} is not supported (pinhole with OpenCV k1, k2, k3, p1, p2 only)"),
        )),
    }
}

const INTRINSIC_KEYS: [&str; 13] = [
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
    "p1",
    "p2",
];

fn read_intrinsics(
    ctx: &Ctx<'_>,
    obj: &Map<String, Value>,
    prefix: &str,
) -> Result<RawIntrinsics, CaptureError> {
    let mut vals = [None; 13];
    for (slot, key) in vals.iter_mut().zip(INTRINSIC_KEYS) {
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
    let [fl_x, fl_y, cx, cy, w, h, camera_angle_x, camera_angle_y, k1, k2, k3, p1, p2] = vals;
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
        p1,
        p2,
    })
}

/// Reads `transform_matrix` (4x4 row-major, or 3x4 with an implied `[0, 0, 0, 1]` row).
fn read_matrix(
    ctx: &Ctx<'_>,
    fo: &Map<String, Value>,
    field: &str,
    warnings: &mut Vec<String>,
) -> Result<Mat4, CaptureError> {
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
    let cols: [[f32; 4]; 4] = std::array::from_fn(|c| std::array::from_fn(|r| m[r][c] as f32));
    Ok(Mat4::from_cols_array_2d(&cols))
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
    pub camera: Camera,
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
    let distortion = Distortion {
        k1: k.k1.unwrap_or(0.0) as f32,
        k2: k.k2.unwrap_or(0.0) as f32,
        k3: k.k3.unwrap_or(0.0) as f32,
        p1: k.p1.unwrap_or(0.0) as f32,
        p2: k.p2.unwrap_or(0.0) as f32,
    };
    Ok(ResolvedCamera {
        camera: Camera {
            fx: fx as f32,
            fy: fy as f32,
            cx: cx as f32,
            cy: cy as f32,
            width: iw,
            height: ih,
            cam_to_world: frame.cam_to_world,
        },
        distortion,
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

    #[test]
    fn distortion_identity_and_radial() {
        let d = Distortion::default();
        assert!(d.is_identity());
        assert_eq!(d.distort(0.3, -0.2), (0.3, -0.2));
        let d = Distortion {
            k1: 0.1,
            ..Default::default()
        };
        let (x, y) = d.distort(0.5, 0.0);
        assert!((x - 0.5 * (1.0 + 0.1 * 0.25)).abs() < 1e-7 && y == 0.0);
    }
}
