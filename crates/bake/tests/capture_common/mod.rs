//! Helpers shared by the capture tests: small synthetic capture folders in temp dirs.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use serde_json::{json, Value};

/// The shared sample captures (read-only).
pub fn shared_captures() -> PathBuf {
    PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../shared/captures"
    ))
}

/// Writes an 8-bit RGBA PNG whose pixel (x, y) is `f(x, y)`.
pub fn write_png_rgba(path: &Path, w: u32, h: u32, f: impl Fn(u32, u32) -> [u8; 4]) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    let img = image::RgbaImage::from_fn(w, h, |x, y| image::Rgba(f(x, y)));
    img.save(path).unwrap();
}

/// A deterministic test pattern: distinct values per pixel and frame.
pub fn pattern(frame: usize) -> impl Fn(u32, u32) -> [u8; 4] {
    move |x, y| {
        let a = if (x + y) % 3 == 0 { 0 } else { 255 };
        [
            (x * 17 + frame as u32) as u8,
            (y * 29) as u8,
            (x * y + 3) as u8,
            a,
        ]
    }
}

/// A camera-to-world matrix (row-major JSON) at `eye` looking at the origin, +Y up.
pub fn look_at_rows(eye: [f64; 3]) -> Value {
    let n = (eye[0] * eye[0] + eye[1] * eye[1] + eye[2] * eye[2]).sqrt();
    let z = [eye[0] / n, eye[1] / n, eye[2] / n];
    // x = up x z
    let up = [0.0, 1.0, 0.0];
    let mut x = [
        up[1] * z[2] - up[2] * z[1],
        up[2] * z[0] - up[0] * z[2],
        up[0] * z[1] - up[1] * z[0],
    ];
    let xn = (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt();
    x = [x[0] / xn, x[1] / xn, x[2] / xn];
    let y = [
        z[1] * x[2] - z[2] * x[1],
        z[2] * x[0] - z[0] * x[2],
        z[0] * x[1] - z[1] * x[0],
    ];
    json!([
        [x[0], y[0], z[0], eye[0]],
        [x[1], y[1], z[1], eye[1]],
        [x[2], y[2], z[2], eye[2]],
        [0.0, 0.0, 0.0, 1.0]
    ])
}

/// Eye positions on a ring of radius 3.
pub fn eye(i: usize) -> [f64; 3] {
    let a = i as f64 * 0.7;
    [3.0 * a.cos(), 1.0, 3.0 * a.sin()]
}

/// An OBJ quad (two triangles) with or without `vt`.
pub fn quad_obj(with_uv: bool) -> String {
    if with_uv {
        "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3 4/4\n".into()
    } else {
        "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nf 1 2 3 4\n".into()
    }
}

/// Writes `n` frames `images/f_{i}.png` (`size` x `size`) plus `transforms.json` with
/// `camera_angle_x`, and `mesh.obj`. Returns the temp dir.
pub fn simple_capture(n: usize, size: u32) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let frames: Vec<Value> = (0..n)
        .map(|i| {
            write_png_rgba(&dir.path().join(format!("images/f_{i}.png")), size, size, pattern(i));
            json!({ "file_path": format!("images/f_{i}.png"), "transform_matrix": look_at_rows(eye(i)) })
        })
        .collect();
    write_json(
        &dir.path().join("transforms.json"),
        &json!({ "camera_angle_x": 0.7, "frames": frames }),
    );
    std::fs::write(dir.path().join("mesh.obj"), quad_obj(true)).unwrap();
    dir
}

/// Writes pretty JSON.
pub fn write_json(path: &Path, v: &Value) {
    std::fs::write(path, serde_json::to_string_pretty(v).unwrap()).unwrap();
}

/// Reads, edits and rewrites a JSON file.
pub fn edit_json(path: &Path, f: impl FnOnce(&mut Value)) {
    let mut v: Value = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    f(&mut v);
    write_json(path, &v);
}
