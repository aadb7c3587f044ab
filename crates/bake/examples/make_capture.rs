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

use std::f64::consts::PI;
use std::io::Write;
use std::path::{Path, PathBuf};

const SIZE: u32 = 128;
const CAMERA_ANGLE_X: f64 = 0.6911112070083618;
const RADIUS: f64 = 4.0;
const SPP_SIDE: u32 = 4;
const N_TRAIN: usize = 48;
const N_TEST: usize = 12;
const MESH_SEGMENTS: usize = 24;
const MESH_RINGS: usize = 12;
/// Direction towards the light (world space, +Y up), normalised at use.
const LIGHT_DIR: [f64; 3] = [0.55, 0.75, 0.45];
const AMBIENT: f64 = 0.18;
const SPECULAR: f64 = 0.55;
const SHININESS: f64 = 60.0;

type V3 = [f64; 3];

fn add(a: V3, b: V3) -> V3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
fn scale(a: V3, s: f64) -> V3 {
    [a[0] * s, a[1] * s, a[2] * s]
}
fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn cross(a: V3, b: V3) -> V3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
fn normalize(a: V3) -> V3 {
    scale(a, 1.0 / dot(a, a).sqrt())
}

/// 3x5 pixel digits, rows top to bottom, bit 2 = left column.
const FONT: [[u8; 5]; 10] = [
    [0b111, 0b101, 0b101, 0b101, 0b111],
    [0b010, 0b110, 0b010, 0b010, 0b111],
    [0b111, 0b001, 0b111, 0b100, 0b111],
    [0b111, 0b001, 0b111, 0b001, 0b111],
    [0b101, 0b101, 0b111, 0b001, 0b001],
    [0b111, 0b100, 0b111, 0b001, 0b111],
    [0b111, 0b100, 0b111, 0b101, 0b111],
    [0b111, 0b001, 0b010, 0b010, 0b010],
    [0b111, 0b101, 0b111, 0b101, 0b111],
    [0b111, 0b101, 0b111, 0b001, 0b111],
];

const PALETTE: [V3; 6] = [
    [0.80, 0.10, 0.06],
    [0.90, 0.55, 0.05],
    [0.15, 0.60, 0.12],
    [0.05, 0.35, 0.75],
    [0.45, 0.12, 0.65],
    [0.75, 0.72, 0.62],
];

/// Linear albedo at uv (glTF convention).
fn albedo(u: f64, v: f64) -> V3 {
    let (cu, cv) = (8.0, 4.0);
    let (fu, fv) = (u.rem_euclid(1.0) * cu, v.clamp(0.0, 1.0) * cv);
    let (ci, cj) = ((fu.floor() as usize).min(7), (fv.floor() as usize).min(3));
    let (s, t) = (fu - ci as f64, fv - cj as f64);
    let dark_cell = (ci + cj) % 2 == 1;
    let mut c = PALETTE[(ci + 3 * cj) % PALETTE.len()];
    if dark_cell {
        c = scale(c, 0.45);
    }
    // Two digits of the cell index, 7 font columns (3 + gap + 3) over s in [0.15, 0.85],
    // 5 rows over t in [0.2, 0.8].
    let index = cj * 8 + ci;
    if (0.15..0.85).contains(&s) && (0.2..0.8).contains(&t) {
        let col = ((s - 0.15) / 0.1).floor() as usize;
        let row = ((t - 0.2) / 0.12).floor() as usize;
        let digit = if col < 3 {
            Some((index / 10, col))
        } else if col > 3 {
            Some((index % 10, col - 4))
        } else {
            None
        };
        if let Some((d, x)) = digit {
            if FONT[d][row.min(4)] >> (2 - x) & 1 == 1 {
                c = if dark_cell {
                    [0.92, 0.92, 0.88]
                } else {
                    [0.03, 0.03, 0.04]
                };
            }
        }
    }
    // Thin latitude stripes (32 per v) and dark cell borders.
    let stripe = (v * 32.0).fract();
    if stripe < 0.08 {
        c = scale(c, 0.35);
    }
    if !(0.025..=0.975).contains(&s) || !(0.02..=0.98).contains(&t) {
        c = [0.02, 0.02, 0.02];
    }
    c
}

/// uv of a point on the unit sphere (same as the proxy mesh's vertices).
fn sphere_uv(p: V3) -> (f64, f64) {
    let u = ((-p[2]).atan2(p[0]) / (2.0 * PI)).rem_euclid(1.0);
    let v = p[1].clamp(-1.0, 1.0).acos() / PI;
    (u, v)
}

/// Point on the unit sphere for uv (inverse of [`sphere_uv`]).
fn sphere_point(u: f64, v: f64) -> V3 {
    let (theta, phi) = (v * PI, u * 2.0 * PI);
    [
        theta.sin() * phi.cos(),
        theta.cos(),
        -theta.sin() * phi.sin(),
    ]
}

/// Linear radiance seen along the ray, or None on a miss.
fn shade(origin: V3, dir: V3) -> Option<V3> {
    // |o + t d|^2 = 1 with |d| = 1.
    let b = dot(origin, dir);
    let c = dot(origin, origin) - 1.0;
    let disc = b * b - c;
    if disc < 0.0 {
        return None;
    }
    let t = -b - disc.sqrt();
    if t <= 0.0 {
        return None;
    }
    let p = add(origin, scale(dir, t));
    let n = normalize(p);
    let (u, v) = sphere_uv(n);
    let a = albedo(u, v);
    let l = normalize(LIGHT_DIR);
    let ndl = dot(n, l).max(0.0);
    let view = scale(dir, -1.0);
    let h = normalize(add(l, view));
    let spec = if ndl > 0.0 {
        SPECULAR * dot(n, h).max(0.0).powf(SHININESS)
    } else {
        0.0
    };
    let k = AMBIENT + (1.0 - AMBIENT) * ndl;
    Some([a[0] * k + spec, a[1] * k + spec, a[2] * k + spec])
}

fn linear_to_srgb(x: f64) -> f64 {
    let x = x.clamp(0.0, 1.0);
    if x <= 0.0031308 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

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

/// The proxy: a UV sphere with `MESH_SEGMENTS` x `MESH_RINGS` quads (triangles at the poles),
/// positions on the unit sphere, uv as in the shader. Returns (positions, normals, uvs, indices).
#[allow(clippy::type_complexity)]
fn proxy_sphere() -> (Vec<[f32; 3]>, Vec<[f32; 3]>, Vec<[f32; 2]>, Vec<u16>) {
    let (mut pos, mut nrm, mut uv) = (Vec::new(), Vec::new(), Vec::new());
    let (s, r) = (MESH_SEGMENTS, MESH_RINGS);
    let mut vertex = |u: f64, v: f64| {
        let p = sphere_point(u, v);
        pos.push(p.map(|x| x as f32));
        nrm.push(p.map(|x| x as f32));
        uv.push([u as f32, v as f32]);
    };
    // Pole vertices, one per segment, take the u of the middle of their triangle; ring
    // vertices repeat u = 0 as u = 1 at the seam.
    for i in 0..s {
        vertex((i as f64 + 0.5) / s as f64, 0.0);
    }
    for j in 1..r {
        for i in 0..=s {
            vertex(i as f64 / s as f64, j as f64 / r as f64);
        }
    }
    for i in 0..s {
        vertex((i as f64 + 0.5) / s as f64, 1.0);
    }
    let at = |i: usize, j: usize| -> u16 {
        let k = if j == 0 {
            i
        } else if j == r {
            s + (r - 1) * (s + 1) + i
        } else {
            s + (j - 1) * (s + 1) + i
        };
        k as u16
    };
    let mut idx = Vec::new();
    let mut tri = |a: u16, b: u16, c: u16| {
        // Counter-clockwise seen from outside (glTF front faces).
        let (pa, pb, pc) = (pos[a as usize], pos[b as usize], pos[c as usize]);
        let d = |p: [f32; 3], q: [f32; 3]| {
            [
                (q[0] - p[0]) as f64,
                (q[1] - p[1]) as f64,
                (q[2] - p[2]) as f64,
            ]
        };
        let nrm = cross(d(pa, pb), d(pa, pc));
        let centre = [
            (pa[0] + pb[0] + pc[0]) as f64,
            (pa[1] + pb[1] + pc[1]) as f64,
            (pa[2] + pb[2] + pc[2]) as f64,
        ];
        if dot(nrm, centre) >= 0.0 {
            idx.extend_from_slice(&[a, b, c]);
        } else {
            idx.extend_from_slice(&[a, c, b]);
        }
    };
    for j in 0..MESH_RINGS {
        for i in 0..MESH_SEGMENTS {
            let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i, j + 1), at(i + 1, j + 1));
            if j == 0 {
                tri(a, c, d);
            } else if j == MESH_RINGS - 1 {
                tri(a, c, b);
            } else {
                tri(a, c, d);
                tri(a, d, b);
            }
        }
    }
    (pos, nrm, uv, idx)
}

/// Writes a minimal GLB: one node, one mesh, POSITION / NORMAL / TEXCOORD_0 and u16 indices.
fn write_glb(path: &Path) {
    let (pos, nrm, uv, idx) = proxy_sphere();
    let mut bin: Vec<u8> = Vec::new();
    let mut views = Vec::new();
    let mut push = |bytes: Vec<u8>, target: u32| {
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
        views.push(serde_json::json!({ "buffer": 0, "byteOffset": bin.len(), "byteLength": bytes.len(), "target": target }));
        bin.extend(bytes);
    };
    push(
        pos.iter().flatten().flat_map(|x| x.to_le_bytes()).collect(),
        34962,
    );
    push(
        nrm.iter().flatten().flat_map(|x| x.to_le_bytes()).collect(),
        34962,
    );
    push(
        uv.iter().flatten().flat_map(|x| x.to_le_bytes()).collect(),
        34962,
    );
    push(idx.iter().flat_map(|x| x.to_le_bytes()).collect(), 34963);
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let min = (0..3)
        .map(|k| pos.iter().map(|p| p[k]).fold(f32::INFINITY, f32::min))
        .collect::<Vec<_>>();
    let max = (0..3)
        .map(|k| pos.iter().map(|p| p[k]).fold(f32::NEG_INFINITY, f32::max))
        .collect::<Vec<_>>();
    let json = serde_json::json!({
        "asset": { "version": "2.0", "generator": "dnr-bake example make_capture" },
        "scene": 0,
        "scenes": [{ "nodes": [0] }],
        "nodes": [{ "mesh": 0, "name": "proxy_sphere" }],
        "meshes": [{ "name": "proxy_sphere", "primitives": [{
            "attributes": { "POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2 }, "indices": 3, "mode": 4 }] }],
        "accessors": [
            { "bufferView": 0, "componentType": 5126, "count": pos.len(), "type": "VEC3", "min": min, "max": max },
            { "bufferView": 1, "componentType": 5126, "count": nrm.len(), "type": "VEC3" },
            { "bufferView": 2, "componentType": 5126, "count": uv.len(), "type": "VEC2" },
            { "bufferView": 3, "componentType": 5123, "count": idx.len(), "type": "SCALAR" }
        ],
        "bufferViews": views,
        "buffers": [{ "byteLength": bin.len() }]
    });
    let mut js = serde_json::to_vec(&json).unwrap();
    while !js.len().is_multiple_of(4) {
        js.push(b' ');
    }
    let total = 12 + 8 + js.len() + 8 + bin.len();
    let mut f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let u32le = |x: usize| u32::try_from(x).unwrap().to_le_bytes();
    f.write_all(b"glTF").unwrap();
    f.write_all(&2u32.to_le_bytes()).unwrap();
    f.write_all(&u32le(total)).unwrap();
    f.write_all(&u32le(js.len())).unwrap();
    f.write_all(b"JSON").unwrap();
    f.write_all(&js).unwrap();
    f.write_all(&u32le(bin.len())).unwrap();
    f.write_all(b"BIN\0").unwrap();
    f.write_all(&bin).unwrap();
    f.flush().unwrap();
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
        tris = proxy_sphere().3.len() / 3,
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
    write_glb(&out.join("mesh.glb"));
    std::fs::write(out.join("README.md"), readme()).unwrap();
    eprintln!(
        "wrote {} train + {} test views and mesh.glb to {}",
        train.len(),
        test.len(),
        out.display()
    );
}
