//! Generates the sample capture `samples/capture/`: an analytic ray tracer of a textured,
//! glossy sphere, independent of the neural renderer and of the runtime's rasteriser.
//!
//! Run: `cargo run --release -p dnr-bake --example make_capture -- samples/capture`
//!
//! - Object: the unit sphere at the origin. Texture defined procedurally in uv space (glTF
//!   convention, v down): u = atan2(-z, x) / 2pi in [0, 1), v = acos(y) / pi (v = 0 at +Y).
//!   8 x 4 coloured checker cells, each with its two-digit index in a 3x5 pixel font, thin
//!   latitude stripes and dark cell borders.
//! - Shading (linear light): albedo * (ambient + diffuse from a fixed world-space directional
//!   light) + white Blinn-Phong specular, so the capture is view dependent. sRGB-encoded
//!   8-bit RGBA PNG, straight alpha = coverage of 4x4 stratified samples per pixel.
//! - Cameras: NeRF-synthetic `transforms_train.json` (48 views, Fibonacci spiral over
//!   elevations -15..75 deg) and `transforms_test.json` (12 views, rising spiral 5..65 deg),
//!   128x128, `camera_angle_x` = 0.6911 rad, distance 4, looking at the origin, roll 0.
//! - Proxy: `mesh.glb`, a 24 x 12 UV sphere with the same uv parameterisation, whose flat
//!   facets lie inside the true sphere (an imperfect proxy, like photogrammetry).
//!
//! Deterministic: no random numbers; same bytes on every run on the same platform.

mod raytrace;

use std::f64::consts::PI;
use std::path::{Path, PathBuf};

use raytrace::*;

const SIZE: u32 = 128;
const CAMERA_ANGLE_X: f64 = 0.6911112070083618;
const RADIUS: f64 = 4.0;
const SPP_SIDE: u32 = 4;
const N_TRAIN: usize = 48;
const N_TEST: usize = 12;
const MESH_SEGMENTS: usize = 24;
const MESH_RINGS: usize = 12;

/// Camera-to-world (columns x, y, z, eye; OpenGL convention) looking at the origin.
fn look_at(eye: V3) -> [[f64; 4]; 4] {
    let z = normalize(eye);
    let x = normalize(cross([0.0, 1.0, 0.0], z));
    let y = cross(z, x);
    [
        [x[0], y[0], z[0], eye[0]],
        [x[1], y[1], z[1], eye[1]],
        [x[2], y[2], z[2], eye[2]],
        [0.0, 0.0, 0.0, 1.0],
    ]
}

fn eye_at(azimuth: f64, elevation: f64) -> V3 {
    [
        RADIUS * elevation.cos() * azimuth.cos(),
        RADIUS * elevation.sin(),
        RADIUS * elevation.cos() * azimuth.sin(),
    ]
}

/// Renders one RGBA8 view.
fn render(m: &[[f64; 4]; 4]) -> Vec<u8> {
    let f = 0.5 * SIZE as f64 / (0.5 * CAMERA_ANGLE_X).tan();
    let c = 0.5 * SIZE as f64;
    let eye = [m[0][3], m[1][3], m[2][3]];
    let mut out = vec![0u8; (SIZE * SIZE * 4) as usize];
    let n = SPP_SIDE * SPP_SIDE;
    for py in 0..SIZE {
        for px in 0..SIZE {
            let mut sum = [0.0; 3];
            let mut hits = 0u32;
            for s in 0..n {
                let x = px as f64 + ((s % SPP_SIDE) as f64 + 0.5) / SPP_SIDE as f64;
                let y = py as f64 + ((s / SPP_SIDE) as f64 + 0.5) / SPP_SIDE as f64;
                let dc = [(x - c) / f, -(y - c) / f, -1.0];
                let dw = normalize([
                    m[0][0] * dc[0] + m[0][1] * dc[1] + m[0][2] * dc[2],
                    m[1][0] * dc[0] + m[1][1] * dc[1] + m[1][2] * dc[2],
                    m[2][0] * dc[0] + m[2][1] * dc[1] + m[2][2] * dc[2],
                ]);
                if let Some(col) = shade(eye, dw) {
                    sum = add(sum, col);
                    hits += 1;
                }
            }
            let i = ((py * SIZE + px) * 4) as usize;
            if hits > 0 {
                for k in 0..3 {
                    // Straight alpha: mean radiance of the covered samples.
                    out[i + k] = (linear_to_srgb(sum[k] / hits as f64) * 255.0).round() as u8;
                }
                out[i + 3] = ((hits as f64 / n as f64) * 255.0).round() as u8;
            }
        }
    }
    out
}

fn write_png(path: &Path, rgba: &[u8]) {
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    use image::ImageEncoder;
    let file = std::fs::File::create(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let enc = PngEncoder::new_with_quality(
        std::io::BufWriter::new(file),
        CompressionType::Best,
        FilterType::Adaptive,
    );
    enc.write_image(rgba, SIZE, SIZE, image::ExtendedColorType::Rgba8)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
}

/// Views: train = Fibonacci spiral over elevations -15..75 deg; test = rising spiral 5..65 deg.
fn views() -> (Vec<V3>, Vec<V3>) {
    let golden = PI * (3.0 - 5f64.sqrt());
    let (lo, hi) = ((-15f64).to_radians(), 75f64.to_radians());
    let train = (0..N_TRAIN)
        .map(|i| {
            // Uniform in sin(elevation) over the band, so directions are area-uniform.
            let t = (i as f64 + 0.5) / N_TRAIN as f64;
            let s = lo.sin() + t * (hi.sin() - lo.sin());
            eye_at(i as f64 * golden, s.asin())
        })
        .collect();
    let test = (0..N_TEST)
        .map(|i| {
            let t = i as f64 / (N_TEST - 1) as f64;
            eye_at(0.3 + t * 2.0 * PI, (5.0 + 60.0 * t).to_radians())
        })
        .collect();
    (train, test)
}

fn write_transforms(dir: &Path, split: &str, eyes: &[V3]) {
    let sub = dir.join(split);
    std::fs::create_dir_all(&sub).unwrap();
    let mut frames = Vec::new();
    for (i, &eye) in eyes.iter().enumerate() {
        let m = look_at(eye);
        write_png(&sub.join(format!("r_{i}.png")), &render(&m));
        frames.push(serde_json::json!({
            "file_path": format!("./{split}/r_{i}"),
            "rotation": 0.0,
            "transform_matrix": m,
        }));
    }
    let json = serde_json::json!({ "camera_angle_x": CAMERA_ANGLE_X, "frames": frames });
    let text = serde_json::to_string_pretty(&json).unwrap() + "\n";
    std::fs::write(dir.join(format!("transforms_{split}.json")), text).unwrap();
}

fn readme() -> String {
    let l = normalize(LIGHT_DIR);
    format!(
        "# Sample capture: analytic textured glossy sphere

A small capture in the format of the baker's input (`transforms_train.json` /
`transforms_test.json`, NeRF-synthetic style), for trying `dnr-bake` end to end:

    dnr-bake samples/capture -o sphere.glb

Generated by `crates/bake/examples/make_capture.rs` (deterministic; no random numbers):

    cargo run --release -p dnr-bake --example make_capture -- samples/capture

It is ground truth from an analytic ray tracer, independent of the neural renderer and of the
runtime's rasteriser:

- Object: the unit sphere at the origin (world space = glTF space, +Y up). Colour texture
  defined procedurally in uv space, glTF convention (v down): u = atan2(-z, x) / 2pi,
  v = acos(y) / pi (v = 0 at the +Y pole). 8 x 4 coloured checker cells each showing its
  two-digit index (0..31) in a 3x5 pixel font, 32 thin latitude stripes, dark cell borders.
- Shading in linear light: albedo * ({AMBIENT} + {diff:.2} * max(n.l, 0)) + {SPECULAR} * max(n.h, 0)^{SHININESS}
  (white Blinn-Phong highlight), light direction l = ({l0:.4}, {l1:.4}, {l2:.4}) fixed in world
  space, so the highlight moves over the texture as the camera moves (view dependence).
- Images: {SIZE}x{SIZE} RGBA PNG, sRGB-encoded 8-bit, straight alpha = coverage;
  {spp} stratified samples per pixel ({SPP_SIDE}x{SPP_SIDE}), colour = mean linear radiance of the
  covered samples. Background transparent (alpha 0, colour 0).
- Cameras: camera_angle_x = {CAMERA_ANGLE_X} rad, distance {RADIUS} from the origin, looking at it,
  roll 0 (OpenGL convention, camera-to-world). Train: {N_TRAIN} views on a Fibonacci spiral,
  area-uniform over elevations -15..75 deg. Test: {N_TEST} views on a rising spiral, elevation
  5..65 deg, one turn. `file_path` has no extension (`./train/r_0`), as in NeRF-synthetic.
- Proxy mesh `mesh.glb`: a {MESH_SEGMENTS} x {MESH_RINGS} UV sphere (POSITION, NORMAL, TEXCOORD_0, {tris}
  triangles) with the same uv parameterisation; its flat facets lie inside the true sphere
  (up to {sag:.1}% of the radius), so it is an imperfect proxy, like a photogrammetry mesh.
  UVs are interpolated linearly across facets, so they also deviate slightly from the
  shader's uv away from the vertices.
",
        diff = 1.0 - AMBIENT,
        l0 = l[0],
        l1 = l[1],
        l2 = l[2],
        spp = SPP_SIDE * SPP_SIDE,
        tris = proxy_sphere(MESH_SEGMENTS, MESH_RINGS).3.len() / 3,
        sag = 100.0 * (1.0 - (PI / MESH_SEGMENTS as f64).cos() * (PI / 2.0 / MESH_RINGS as f64).cos()),
    )
}

fn main() {
    let out: PathBuf = std::env::args_os()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("samples/capture"));
    std::fs::create_dir_all(&out).unwrap_or_else(|e| panic!("{}: {e}", out.display()));
    let (train, test) = views();
    write_transforms(&out, "train", &train);
    write_transforms(&out, "test", &test);
    write_glb(
        &out.join("mesh.glb"),
        MESH_SEGMENTS,
        MESH_RINGS,
        "dnr-bake example make_capture",
    );
    std::fs::write(out.join("README.md"), readme()).unwrap();
    eprintln!(
        "wrote {} train + {} test views and mesh.glb to {}",
        train.len(),
        test.len(),
        out.display()
    );
}
