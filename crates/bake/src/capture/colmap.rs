//! COLMAP sparse models (`cameras`, `images`, `points3D`, each `.bin` or `.txt`), read as
//! COLMAP's `doc/format.rst` and `scripts/python/read_write_model.py` describe them.
//!
//! Binary files are little-endian:
//! - `cameras.bin`: `u64` count; per camera `i32 camera_id`, `i32 model_id`, `u64 width`,
//!   `u64 height`, then the model's `f64` parameters.
//! - `images.bin`: `u64` count; per image `i32 image_id`, `f64 qw qx qy qz`, `f64 tx ty tz`,
//!   `i32 camera_id`, the name as bytes up to a NUL, `u64` number of 2D points, then per
//!   point `f64 x`, `f64 y`, `i64 point3D_id` (-1: none).
//! - `points3D.bin`: `u64` count; per point `u64 point3D_id`, `f64 x y z`, `u8 r g b`,
//!   `f64 error`, `u64` track length, then per track element `i32 image_id`,
//!   `i32 point2D_idx`.
//!
//! Text files hold the same fields separated by spaces, `#` comment lines, and in
//! `images.txt` two lines per image (the pose line, then the 2D points line, which may be
//! empty).
//!
//! Read: camera id, model, width, height and parameters; image id, pose (world-to-camera
//! quaternion `qw qx qy qz` and translation), camera id, name, and the ids of the 3D points it
//! observes; 3D point ids and positions. Ignored: 2D point positions, colours, reprojection
//! errors, tracks (the images' 2D points give the same visibility), `rigs`/`frames` files.
//!
//! Supported camera models: SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV,
//! OPENCV_FISHEYE; any other is an error naming the camera id and the model.
//!
//! Every count read from a file is checked against the bytes left (binary) before anything
//! is allocated for it, and the file size against a limit before the file is read.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::{DMat3, DMat4, DQuat, DVec3, DVec4};

use super::distortion::{Distortion, LensModel};
use super::error::CaptureError;

/// COLMAP camera models by id (`colmap/sensor/models.h`): name and parameter count.
const MODELS: [(&str, usize); 12] = [
    ("SIMPLE_PINHOLE", 3),
    ("PINHOLE", 4),
    ("SIMPLE_RADIAL", 4),
    ("RADIAL", 5),
    ("OPENCV", 8),
    ("OPENCV_FISHEYE", 8),
    ("FULL_OPENCV", 12),
    ("FOV", 5),
    ("SIMPLE_RADIAL_FISHEYE", 4),
    ("RADIAL_FISHEYE", 5),
    ("THIN_PRISM_FISHEYE", 12),
    ("RAD_TAN_THIN_PRISM_FISHEYE", 16),
];

/// The models a capture may use.
pub const SUPPORTED_MODELS: [&str; 6] = [
    "SIMPLE_PINHOLE",
    "PINHOLE",
    "SIMPLE_RADIAL",
    "RADIAL",
    "OPENCV",
    "OPENCV_FISHEYE",
];

/// Folders searched for a model, in order, relative to the capture folder.
pub const MODEL_DIRS: [&str; 2] = ["sparse/0", "sparse"];

/// One camera of `cameras.{bin,txt}`.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapCamera {
    /// `CAMERA_ID`.
    pub id: u32,
    /// Model name, e.g. `OPENCV`.
    pub model: &'static str,
    /// Width in pixels.
    pub width: u64,
    /// Height in pixels.
    pub height: u64,
    /// The model's parameters, in COLMAP's order.
    pub params: Vec<f64>,
}

/// Intrinsics of a supported camera: `(fx, fy, cx, cy)` and the lens.
pub type Intrinsics = ([f64; 4], Distortion);

impl ColmapCamera {
    /// Pixel intrinsics and lens of a supported model (the parameter count was checked
    /// when the camera was read).
    pub fn intrinsics(&self) -> Intrinsics {
        let p = &self.params;
        let none = Distortion::default();
        match self.model {
            "SIMPLE_PINHOLE" => ([p[0], p[0], p[1], p[2]], none),
            "PINHOLE" => ([p[0], p[1], p[2], p[3]], none),
            "SIMPLE_RADIAL" => (
                [p[0], p[0], p[1], p[2]],
                Distortion::opencv(p[3], 0.0, 0.0, 0.0),
            ),
            "RADIAL" => (
                [p[0], p[0], p[1], p[2]],
                Distortion::opencv(p[3], p[4], 0.0, 0.0),
            ),
            "OPENCV" => (
                [p[0], p[1], p[2], p[3]],
                Distortion::opencv(p[4], p[5], p[6], p[7]),
            ),
            "OPENCV_FISHEYE" => (
                [p[0], p[1], p[2], p[3]],
                Distortion {
                    model: LensModel::Fisheye,
                    k1: p[4],
                    k2: p[5],
                    k3: p[6],
                    k4: p[7],
                    ..Default::default()
                },
            ),
            // read_cameras refuses every other model.
            _ => ([p[0], p[0], 0.0, 0.0], none),
        }
    }
}

/// One registered image of `images.{bin,txt}`.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapImage {
    /// `IMAGE_ID`.
    pub id: u32,
    /// World-to-camera rotation `qw qx qy qz`.
    pub qvec: [f64; 4],
    /// World-to-camera translation.
    pub tvec: [f64; 3],
    /// `CAMERA_ID`.
    pub camera_id: u32,
    /// File name relative to the images folder.
    pub name: String,
    /// Ids of the 3D points this image observes (2D points without one are left out).
    pub point_ids: Vec<u64>,
}

impl ColmapImage {
    /// Camera-to-world in the capture convention (OpenGL camera: -Z forward, +Y up), in the
    /// model's world coordinates: COLMAP's camera looks along +Z with +Y down, so the camera
    /// axes y and z are negated after inverting the world-to-camera pose.
    pub fn cam_to_world(&self) -> DMat4 {
        let [w, x, y, z] = self.qvec;
        let q = DQuat::from_xyzw(x, y, z, w).normalize();
        let r = DMat3::from_quat(q);
        let rt = r.transpose();
        let centre = -(rt * DVec3::from_array(self.tvec));
        DMat4::from_cols(
            rt.x_axis.extend(0.0),
            (-rt.y_axis).extend(0.0),
            (-rt.z_axis).extend(0.0),
            DVec4::new(centre.x, centre.y, centre.z, 1.0),
        )
    }
}

/// Which encoding a model was read from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Encoding {
    /// `.bin` files.
    Binary,
    /// `.txt` files.
    Text,
}

/// A sparse model.
#[derive(Clone, Debug)]
pub struct ColmapModel {
    /// The cameras file read.
    pub cameras_path: PathBuf,
    /// The images file read.
    pub images_path: PathBuf,
    /// The points file read, if there was one.
    pub points_path: Option<PathBuf>,
    /// Cameras by id.
    pub cameras: HashMap<u32, ColmapCamera>,
    /// Registered images, in file order.
    pub images: Vec<ColmapImage>,
    /// 3D point positions by id (empty without a points file).
    pub points: HashMap<u64, DVec3>,
}

/// The model folder and encoding under a capture folder: the first of [`MODEL_DIRS`] that
/// holds `cameras.bin` and `images.bin` (preferred) or `cameras.txt` and `images.txt`.
pub fn find_model(dir: &Path) -> Option<(PathBuf, Encoding)> {
    MODEL_DIRS.iter().find_map(|sub| {
        let d = dir.join(sub);
        let has = |ext: &str| {
            d.join(format!("cameras.{ext}")).is_file() && d.join(format!("images.{ext}")).is_file()
        };
        if has("bin") {
            Some((d, Encoding::Binary))
        } else if has("txt") {
            Some((d, Encoding::Text))
        } else {
            None
        }
    })
}

/// Reads `cameras`, `images` and (if present) `points3D` from `dir` in `encoding`. Files
/// larger than `max_bytes` and more than `max_images` images are refused before reading on.
pub fn read_model(
    dir: &Path,
    encoding: Encoding,
    max_bytes: u64,
    max_images: usize,
) -> Result<ColmapModel, CaptureError> {
    let ext = match encoding {
        Encoding::Binary => "bin",
        Encoding::Text => "txt",
    };
    let cameras_path = dir.join(format!("cameras.{ext}"));
    let images_path = dir.join(format!("images.{ext}"));
    let points_path = dir.join(format!("points3D.{ext}"));
    let cameras = {
        let bytes = read_limited(&cameras_path, max_bytes)?;
        match encoding {
            Encoding::Binary => read_cameras_bin(&cameras_path, &bytes, max_images)?,
            Encoding::Text => read_cameras_txt(&cameras_path, text(&cameras_path, &bytes)?)?,
        }
    };
    let images = {
        let bytes = read_limited(&images_path, max_bytes)?;
        match encoding {
            Encoding::Binary => read_images_bin(&images_path, &bytes, max_images)?,
            Encoding::Text => read_images_txt(&images_path, text(&images_path, &bytes)?)?,
        }
    };
    if images.len() > max_images {
        return Err(CaptureError::TooManyFrames {
            path: images_path,
            count: images.len(),
            max: max_images,
        });
    }
    let (points, points_path) = if points_path.is_file() {
        let bytes = read_limited(&points_path, max_bytes)?;
        let p = match encoding {
            Encoding::Binary => read_points_bin(&points_path, &bytes)?,
            Encoding::Text => read_points_txt(&points_path, text(&points_path, &bytes)?)?,
        };
        (p, Some(points_path))
    } else {
        (HashMap::new(), None)
    };
    Ok(ColmapModel {
        cameras_path,
        images_path,
        points_path,
        cameras,
        images,
        points,
    })
}

fn read_limited(path: &Path, max_bytes: u64) -> Result<Vec<u8>, CaptureError> {
    let len = std::fs::metadata(path)
        .map_err(|e| CaptureError::io(path, e))?
        .len();
    if len > max_bytes {
        return Err(CaptureError::TooLarge {
            path: path.to_path_buf(),
            message: format!("COLMAP file is {len} bytes, over the limit of {max_bytes}"),
        });
    }
    std::fs::read(path).map_err(|e| CaptureError::io(path, e))
}

fn text<'a>(path: &Path, bytes: &'a [u8]) -> Result<&'a str, CaptureError> {
    std::str::from_utf8(bytes).map_err(|e| err(path, "(file)", format!("not UTF-8 text: {e}")))
}

fn err(path: &Path, location: impl Into<String>, message: impl Into<String>) -> CaptureError {
    CaptureError::Colmap {
        path: path.to_path_buf(),
        location: location.into(),
        message: message.into(),
    }
}

/// The model name and parameter count of a model id or name; an unsupported model is an
/// error naming the camera.
fn check_model(
    path: &Path,
    location: &str,
    model: Result<i32, &str>,
) -> Result<(&'static str, usize), CaptureError> {
    let found = match model {
        Ok(id) => usize::try_from(id)
            .ok()
            .and_then(|i| MODELS.get(i))
            .copied(),
        Err(name) => MODELS.iter().find(|(n, _)| *n == name).copied(),
    };
    let shown = match model {
        Ok(id) => found.map_or(format!("id {id} (unknown)"), |(n, _)| n.to_string()),
        Err(name) => name.to_string(),
    };
    match found {
        Some((name, count)) if SUPPORTED_MODELS.contains(&name) => Ok((name, count)),
        _ => Err(err(
            path,
            location,
            format!(
                "camera model {shown} is not supported (supported: {})",
                SUPPORTED_MODELS.join(", ")
            ),
        )),
    }
}

/// Little-endian reader over a binary file with its position for error messages.
struct Bin<'a> {
    path: &'a Path,
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Bin<'a> {
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], CaptureError> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.bytes.len());
        match end {
            Some(e) => {
                let s = &self.bytes[self.pos..e];
                self.pos = e;
                Ok(s)
            }
            None => Err(err(
                self.path,
                format!("byte {}", self.pos),
                format!("file ends inside {what}"),
            )),
        }
    }
    fn u64(&mut self, what: &str) -> Result<u64, CaptureError> {
        let b = self.take(8, what)?;
        Ok(u64::from_le_bytes(b.try_into().expect("8 bytes")))
    }
    fn i32(&mut self, what: &str) -> Result<i32, CaptureError> {
        let b = self.take(4, what)?;
        Ok(i32::from_le_bytes(b.try_into().expect("4 bytes")))
    }
    fn f64(&mut self, what: &str) -> Result<f64, CaptureError> {
        let b = self.take(8, what)?;
        Ok(f64::from_le_bytes(b.try_into().expect("8 bytes")))
    }
    fn left(&self) -> usize {
        self.bytes.len() - self.pos
    }
    /// A count followed by records of at least `min_record` bytes each: refused when they
    /// cannot fit in the bytes left.
    fn count(&mut self, what: &str, min_record: usize) -> Result<usize, CaptureError> {
        let at = self.pos;
        let n = self.u64(what)?;
        if n.saturating_mul(min_record as u64) > self.left() as u64 {
            return Err(err(
                self.path,
                format!("byte {at}"),
                format!(
                    "{what} {n} cannot fit in the {} bytes that follow",
                    self.left()
                ),
            ));
        }
        Ok(n as usize)
    }
    fn done(&self) -> Result<(), CaptureError> {
        if self.pos != self.bytes.len() {
            return Err(err(
                self.path,
                format!("byte {}", self.pos),
                format!(
                    "{} bytes after the last record",
                    self.bytes.len() - self.pos
                ),
            ));
        }
        Ok(())
    }
}

fn id_u32(path: &Path, location: &str, what: &str, v: i64) -> Result<u32, CaptureError> {
    u32::try_from(v).map_err(|_| err(path, location, format!("{what} {v} is negative")))
}

fn finite(path: &Path, location: &str, what: &str, v: f64) -> Result<f64, CaptureError> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(err(path, location, format!("{what} is not finite ({v})")))
    }
}

fn read_cameras_bin(
    path: &Path,
    bytes: &[u8],
    max_cameras: usize,
) -> Result<HashMap<u32, ColmapCamera>, CaptureError> {
    let mut b = Bin {
        path,
        bytes,
        pos: 0,
    };
    let n = b.count("the camera count", 24)?;
    if n > max_cameras {
        return Err(err(
            path,
            "header",
            format!("{n} cameras exceed the limit of {max_cameras}"),
        ));
    }
    let mut cameras = HashMap::with_capacity(n);
    for k in 0..n {
        let at = format!("camera record {k}");
        let id = b.i32(&at)?;
        let id = id_u32(path, &at, "camera id", id.into())?;
        let location = format!("camera {id}");
        let model_id = b.i32(&location)?;
        let (model, count) = check_model(path, &location, Ok(model_id))?;
        let width = b.u64(&location)?;
        let height = b.u64(&location)?;
        let params = (0..count)
            .map(|i| {
                let v = b.f64(&location)?;
                finite(path, &location, &format!("parameter {i}"), v)
            })
            .collect::<Result<Vec<_>, _>>()?;
        insert_camera(
            path,
            &mut cameras,
            ColmapCamera {
                id,
                model,
                width,
                height,
                params,
            },
        )?;
    }
    b.done()?;
    Ok(cameras)
}

fn insert_camera(
    path: &Path,
    cameras: &mut HashMap<u32, ColmapCamera>,
    c: ColmapCamera,
) -> Result<(), CaptureError> {
    let location = format!("camera {}", c.id);
    if c.width == 0 || c.height == 0 || c.width > u32::MAX as u64 || c.height > u32::MAX as u64 {
        return Err(err(
            path,
            &location,
            format!("size {}x{} is out of range", c.width, c.height),
        ));
    }
    let ([fx, fy, _, _], _) = c.intrinsics();
    if !(fx > 0.0 && fy > 0.0) {
        return Err(err(
            path,
            &location,
            format!("focal length must be positive, got {fx}, {fy}"),
        ));
    }
    if cameras.insert(c.id, c).is_some() {
        return Err(err(path, location, "camera id appears twice"));
    }
    Ok(())
}

fn read_images_bin(
    path: &Path,
    bytes: &[u8],
    max_images: usize,
) -> Result<Vec<ColmapImage>, CaptureError> {
    let mut b = Bin {
        path,
        bytes,
        pos: 0,
    };
    // id, 7 f64, camera id, an empty name's NUL, a zero point count.
    let n = b.count("the image count", 4 + 56 + 4 + 1 + 8)?;
    if n > max_images {
        return Err(CaptureError::TooManyFrames {
            path: path.to_path_buf(),
            count: n,
            max: max_images,
        });
    }
    let mut images = Vec::with_capacity(n);
    for k in 0..n {
        let at = format!("image record {k}");
        let id = b.i32(&at)?;
        let id = id_u32(path, &at, "image id", id.into())?;
        let location = format!("image {id}");
        let mut pose = [0.0f64; 7];
        for (i, v) in pose.iter_mut().enumerate() {
            *v = finite(
                path,
                &location,
                &format!("pose value {i}"),
                b.f64(&location)?,
            )?;
        }
        let camera_id = b.i32(&location)?;
        let camera_id = id_u32(path, &location, "camera id", camera_id.into())?;
        let rest = &b.bytes[b.pos..];
        let len = rest
            .iter()
            .position(|&c| c == 0)
            .ok_or_else(|| err(path, &location, "file ends inside the image name"))?;
        let name = std::str::from_utf8(&rest[..len])
            .map_err(|_| err(path, &location, "image name is not UTF-8"))?
            .to_string();
        b.pos += len + 1;
        let points = b.count("the 2D point count", 24)?;
        let mut point_ids = Vec::new();
        for _ in 0..points {
            b.take(16, &location)?;
            let pid = b.u64(&location)?;
            // -1 (all bits set) marks a 2D point without a 3D point.
            if pid != u64::MAX {
                point_ids.push(pid);
            }
        }
        images.push(image(path, id, pose, camera_id, name, point_ids)?);
    }
    b.done()?;
    Ok(images)
}

fn image(
    path: &Path,
    id: u32,
    pose: [f64; 7],
    camera_id: u32,
    name: String,
    point_ids: Vec<u64>,
) -> Result<ColmapImage, CaptureError> {
    let location = format!("image {id}");
    let q = [pose[0], pose[1], pose[2], pose[3]];
    let norm = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    if norm.is_nan() || norm <= 1e-6 {
        return Err(err(
            path,
            location,
            format!("quaternion {q:?} has zero length"),
        ));
    }
    if name.is_empty() {
        return Err(err(path, location, "image name is empty"));
    }
    Ok(ColmapImage {
        id,
        qvec: q,
        tvec: [pose[4], pose[5], pose[6]],
        camera_id,
        name,
        point_ids,
    })
}

fn read_points_bin(path: &Path, bytes: &[u8]) -> Result<HashMap<u64, DVec3>, CaptureError> {
    let mut b = Bin {
        path,
        bytes,
        pos: 0,
    };
    // id, xyz, rgb, error, track length.
    let n = b.count("the point count", 8 + 24 + 3 + 8 + 8)?;
    let mut points = HashMap::with_capacity(n);
    for k in 0..n {
        let at = format!("point record {k}");
        let id = b.u64(&at)?;
        let location = format!("point {id}");
        let mut p = [0.0f64; 3];
        for v in p.iter_mut() {
            *v = finite(path, &location, "position", b.f64(&location)?)?;
        }
        b.take(3 + 8, &location)?;
        let track = b.count("the track length", 8)?;
        b.take(track * 8, &location)?;
        points.insert(id, DVec3::from_array(p));
    }
    b.done()?;
    Ok(points)
}

/// Non-comment, non-empty lines with their 1-based numbers.
fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
}

fn parse_num<T: std::str::FromStr>(
    path: &Path,
    line: usize,
    what: &str,
    tok: Option<&str>,
) -> Result<T, CaptureError> {
    let tok = tok.ok_or_else(|| err(path, format!("line {line}"), format!("missing {what}")))?;
    tok.parse::<T>().map_err(|_| {
        err(
            path,
            format!("line {line}"),
            format!("{what} {tok:?} is not a number of the right kind"),
        )
    })
}

fn read_cameras_txt(path: &Path, text: &str) -> Result<HashMap<u32, ColmapCamera>, CaptureError> {
    let mut cameras = HashMap::new();
    for (line, l) in data_lines(text) {
        let mut t = l.split_whitespace();
        let id: u32 = parse_num(path, line, "CAMERA_ID", t.next())?;
        let model_name = t
            .next()
            .ok_or_else(|| err(path, format!("line {line}"), "missing MODEL"))?;
        let (model, count) =
            check_model(path, &format!("line {line}: camera {id}"), Err(model_name))?;
        let width: u64 = parse_num(path, line, "WIDTH", t.next())?;
        let height: u64 = parse_num(path, line, "HEIGHT", t.next())?;
        let params = (0..count)
            .map(|i| {
                let v: f64 = parse_num(path, line, &format!("parameter {i}"), t.next())?;
                finite(path, &format!("line {line}"), "parameter", v)
            })
            .collect::<Result<Vec<_>, _>>()?;
        if t.next().is_some() {
            return Err(err(
                path,
                format!("line {line}"),
                format!("more than the {count} parameters of {model}"),
            ));
        }
        insert_camera(
            path,
            &mut cameras,
            ColmapCamera {
                id,
                model,
                width,
                height,
                params,
            },
        )?;
    }
    Ok(cameras)
}

fn read_images_txt(path: &Path, text: &str) -> Result<Vec<ColmapImage>, CaptureError> {
    let mut images = Vec::new();
    // The pose line is the first non-comment line; the line right after it holds the 2D
    // points, even when empty (COLMAP writes an empty line for an image without points).
    let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l.trim()));
    while let Some((line, l)) = lines.next() {
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        let mut t = l.split_whitespace();
        let id: u32 = parse_num(path, line, "IMAGE_ID", t.next())?;
        let mut pose = [0.0f64; 7];
        for (i, v) in pose.iter_mut().enumerate() {
            let what = ["QW", "QX", "QY", "QZ", "TX", "TY", "TZ"][i];
            *v = parse_num(path, line, what, t.next())?;
            finite(path, &format!("line {line}"), what, *v)?;
        }
        let camera_id: u32 = parse_num(path, line, "CAMERA_ID", t.next())?;
        let name = t.collect::<Vec<_>>().join(" ");
        let mut point_ids = Vec::new();
        if let Some((pline, pl)) = lines.next() {
            let toks: Vec<&str> = pl.split_whitespace().collect();
            if !toks.len().is_multiple_of(3) {
                return Err(err(
                    path,
                    format!("line {pline}"),
                    "2D points must come as X Y POINT3D_ID triples",
                ));
            }
            for tri in toks.chunks_exact(3) {
                let pid: i64 = parse_num(path, pline, "POINT3D_ID", Some(tri[2]))?;
                if pid >= 0 {
                    point_ids.push(pid as u64);
                }
            }
        }
        images.push(image(path, id, pose, camera_id, name, point_ids)?);
    }
    Ok(images)
}

fn read_points_txt(path: &Path, text: &str) -> Result<HashMap<u64, DVec3>, CaptureError> {
    let mut points = HashMap::new();
    for (line, l) in data_lines(text) {
        let mut t = l.split_whitespace();
        let id: u64 = parse_num(path, line, "POINT3D_ID", t.next())?;
        let mut p = [0.0f64; 3];
        for (v, what) in p.iter_mut().zip(["X", "Y", "Z"]) {
            *v = parse_num(path, line, what, t.next())?;
            finite(path, &format!("line {line}"), what, *v)?;
        }
        points.insert(id, DVec3::from_array(p));
    }
    Ok(points)
}

/// Writers of both encodings, for tests and the sample generator (the inverse of the
/// readers above, field for field).
pub mod write {
    use super::{ColmapCamera, ColmapImage, MODELS};
    use glam::DVec3;
    use std::fmt::Write as _;

    fn model_id(name: &str) -> i32 {
        MODELS
            .iter()
            .position(|(n, _)| *n == name)
            .expect("a COLMAP model name") as i32
    }

    /// `cameras.bin`.
    pub fn cameras_bin(cameras: &[ColmapCamera]) -> Vec<u8> {
        let mut b = (cameras.len() as u64).to_le_bytes().to_vec();
        for c in cameras {
            b.extend((c.id as i32).to_le_bytes());
            b.extend(model_id(c.model).to_le_bytes());
            b.extend(c.width.to_le_bytes());
            b.extend(c.height.to_le_bytes());
            for p in &c.params {
                b.extend(p.to_le_bytes());
            }
        }
        b
    }

    /// `cameras.txt`.
    pub fn cameras_txt(cameras: &[ColmapCamera]) -> String {
        let mut s = String::from("# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n");
        for c in cameras {
            let _ = write!(s, "{} {} {} {}", c.id, c.model, c.width, c.height);
            for p in &c.params {
                let _ = write!(s, " {p:?}");
            }
            s.push('\n');
        }
        s
    }

    /// `images.bin`; each image's 2D points are written at (0, 0) with its point ids.
    pub fn images_bin(images: &[ColmapImage]) -> Vec<u8> {
        let mut b = (images.len() as u64).to_le_bytes().to_vec();
        for im in images {
            b.extend((im.id as i32).to_le_bytes());
            for v in im.qvec.iter().chain(&im.tvec) {
                b.extend(v.to_le_bytes());
            }
            b.extend((im.camera_id as i32).to_le_bytes());
            b.extend(im.name.as_bytes());
            b.push(0);
            b.extend((im.point_ids.len() as u64).to_le_bytes());
            for &pid in &im.point_ids {
                b.extend(0f64.to_le_bytes());
                b.extend(0f64.to_le_bytes());
                b.extend(pid.to_le_bytes());
            }
        }
        b
    }

    /// `images.txt`.
    pub fn images_txt(images: &[ColmapImage]) -> String {
        let mut s = String::from("# Image list with two lines of data per image:\n#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n#   POINTS2D[] as (X, Y, POINT3D_ID)\n");
        for im in images {
            let _ = write!(s, "{}", im.id);
            for v in im.qvec.iter().chain(&im.tvec) {
                let _ = write!(s, " {v:?}");
            }
            let _ = writeln!(s, " {} {}", im.camera_id, im.name);
            let pts: Vec<String> = im.point_ids.iter().map(|p| format!("0 0 {p}")).collect();
            s.push_str(&pts.join(" "));
            s.push('\n');
        }
        s
    }

    /// `points3D.bin`: grey points with an empty track.
    pub fn points_bin(points: &[(u64, DVec3)]) -> Vec<u8> {
        let mut b = (points.len() as u64).to_le_bytes().to_vec();
        for (id, p) in points {
            b.extend(id.to_le_bytes());
            for v in p.to_array() {
                b.extend(v.to_le_bytes());
            }
            b.extend([128u8, 128, 128]);
            b.extend(0f64.to_le_bytes());
            b.extend(0u64.to_le_bytes());
        }
        b
    }

    /// `points3D.txt`: grey points with an empty track.
    pub fn points_txt(points: &[(u64, DVec3)]) -> String {
        let mut s = String::from("# 3D point list with one line of data per point:\n#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n");
        for (id, p) in points {
            let _ = writeln!(s, "{id} {:?} {:?} {:?} 128 128 128 0", p.x, p.y, p.z);
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identity_pose_is_the_opencv_camera_flipped() {
        let im = ColmapImage {
            id: 1,
            qvec: [1.0, 0.0, 0.0, 0.0],
            tvec: [0.0, 0.0, 2.0],
            camera_id: 1,
            name: "a.jpg".into(),
            point_ids: vec![],
        };
        let m = im.cam_to_world();
        // World-to-camera translation (0, 0, 2): the centre is at z = -2, looking along +z
        // (OpenGL -Z axis = world +z).
        assert_eq!(m.w_axis.truncate(), DVec3::new(0.0, 0.0, -2.0));
        assert_eq!(m.z_axis.truncate(), DVec3::new(0.0, 0.0, -1.0));
        assert_eq!(m.y_axis.truncate(), DVec3::new(0.0, -1.0, 0.0));
    }

    #[test]
    fn truncated_binary_names_the_byte() {
        let cams = vec![ColmapCamera {
            id: 3,
            model: "PINHOLE",
            width: 4,
            height: 3,
            params: vec![2.0, 2.0, 2.0, 1.5],
        }];
        let b = write::cameras_bin(&cams);
        for cut in 0..b.len() {
            let e = read_cameras_bin(Path::new("c.bin"), &b[..cut], 10).unwrap_err();
            assert!(e.to_string().starts_with("c.bin: "), "{e}");
        }
        assert_eq!(
            read_cameras_bin(Path::new("c.bin"), &b, 10).unwrap()[&3],
            cams[0]
        );
    }
}
