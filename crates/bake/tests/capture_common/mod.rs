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

/// The bundled sample capture (a glossy sphere, 48 + 12 views of 128x128).
pub fn sample_capture() -> PathBuf {
    PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../samples/capture"
    ))
}

/// Copies the sample capture to `dir` and repaints every image analytically from the proxy
/// sphere's G-buffer: a checker albedo under a fixed directional light, plus a white
/// Blinn-Phong highlight of strength `specular` (0 = perfectly diffuse). The proxy is then
/// exact, and whether the images depend on the view is known by construction.
pub fn shaded_sphere_capture(dir: &Path, specular: f32) {
    let src = sample_capture();
    copy_dir(&src, dir);
    let cap = dnr_bake::capture::Capture::load(dir, &Default::default()).unwrap();
    let light = glam::Vec3::new(0.55, 0.75, 0.45).normalize();
    for f in cap.train.iter().chain(&cap.test) {
        let g = dnr_runtime::raster::rasterize(&cap.mesh, &f.camera);
        let (w, h) = (g.width as u32, g.height as u32);
        write_png_rgba(&f.image_path, w, h, |x, y| {
            let i = (y * w + x) as usize;
            if g.coverage[i] == 0.0 {
                return [0, 0, 0, 0];
            }
            let [u, v] = g.uv[i];
            // The proxy's uv parameterisation (see examples/make_capture.rs).
            let (th, ph) = (v * std::f32::consts::PI, u * 2.0 * std::f32::consts::PI);
            let n = glam::Vec3::new(th.sin() * ph.cos(), th.cos(), -th.sin() * ph.sin());
            let cell = ((u * 8.0).floor() as i32 + (v * 4.0).floor() as i32) % 2;
            let albedo = if cell == 0 {
                glam::Vec3::new(0.8, 0.3, 0.1)
            } else {
                glam::Vec3::new(0.1, 0.4, 0.7)
            };
            let k = 0.2 + 0.8 * n.dot(light).max(0.0);
            let to_eye = -glam::Vec3::from(g.view_dir[i]);
            let half = (light + to_eye).normalize_or_zero();
            let spec = specular * n.dot(half).max(0.0).powf(40.0);
            let c = albedo * k + glam::Vec3::splat(spec);
            let q = |t: f32| (t.clamp(0.0, 1.0).powf(1.0 / 2.2) * 255.0).round() as u8;
            [q(c.x), q(c.y), q(c.z), 255]
        });
    }
}

/// Copies a folder tree.
pub fn copy_dir(src: &Path, dst: &Path) {
    std::fs::create_dir_all(dst).unwrap();
    for e in std::fs::read_dir(src).unwrap() {
        let e = e.unwrap();
        let to = dst.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &to);
        } else {
            std::fs::copy(e.path(), &to).unwrap();
        }
    }
}
