//! The analytic scene shared by the capture generators (`make_capture`,
//! `make_phone_capture`): a textured glossy unit sphere, its ray tracer, and the proxy UV
//! sphere written as a minimal GLB.
#![allow(dead_code)]

use std::f64::consts::PI;
use std::io::Write;
use std::path::Path;

/// Direction towards the light (world space, +Y up), normalised at use.
pub const LIGHT_DIR: [f64; 3] = [0.55, 0.75, 0.45];
pub const AMBIENT: f64 = 0.18;
pub const SPECULAR: f64 = 0.55;
pub const SHININESS: f64 = 60.0;

/// A 3-vector in f64.
pub type V3 = [f64; 3];

pub fn add(a: V3, b: V3) -> V3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
pub fn scale(a: V3, s: f64) -> V3 {
    [a[0] * s, a[1] * s, a[2] * s]
}
pub fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
pub fn cross(a: V3, b: V3) -> V3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
pub fn normalize(a: V3) -> V3 {
    scale(a, 1.0 / dot(a, a).sqrt())
}

/// 3x5 pixel digits, rows top to bottom, bit 2 = left column.
pub const FONT: [[u8; 5]; 10] = [
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

pub const PALETTE: [V3; 6] = [
    [0.80, 0.10, 0.06],
    [0.90, 0.55, 0.05],
    [0.15, 0.60, 0.12],
    [0.05, 0.35, 0.75],
    [0.45, 0.12, 0.65],
    [0.75, 0.72, 0.62],
];

/// Linear albedo at uv (glTF convention).
pub fn albedo(u: f64, v: f64) -> V3 {
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
pub fn sphere_uv(p: V3) -> (f64, f64) {
    let u = ((-p[2]).atan2(p[0]) / (2.0 * PI)).rem_euclid(1.0);
    let v = p[1].clamp(-1.0, 1.0).acos() / PI;
    (u, v)
}

/// Point on the unit sphere for uv (inverse of [`sphere_uv`]).
pub fn sphere_point(u: f64, v: f64) -> V3 {
    let (theta, phi) = (v * PI, u * 2.0 * PI);
    [
        theta.sin() * phi.cos(),
        theta.cos(),
        -theta.sin() * phi.sin(),
    ]
}

/// Linear radiance seen along the ray, or None on a miss.
pub fn shade(origin: V3, dir: V3) -> Option<V3> {
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

pub fn linear_to_srgb(x: f64) -> f64 {
    let x = x.clamp(0.0, 1.0);
    if x <= 0.0031308 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

/// The proxy: a UV sphere with `MESH_SEGMENTS` x `MESH_RINGS` quads (triangles at the poles),
/// positions on the unit sphere, uv as in the shader. Returns (positions, normals, uvs, indices).
#[allow(clippy::type_complexity)]
pub fn proxy_sphere(
    segments: usize,
    rings: usize,
) -> (Vec<[f32; 3]>, Vec<[f32; 3]>, Vec<[f32; 2]>, Vec<u16>) {
    let (mut pos, mut nrm, mut uv) = (Vec::new(), Vec::new(), Vec::new());
    let (s, r) = (segments, rings);
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
    for j in 0..r {
        for i in 0..s {
            let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i, j + 1), at(i + 1, j + 1));
            if j == 0 {
                tri(a, c, d);
            } else if j == r - 1 {
                tri(a, c, b);
            } else {
                tri(a, c, d);
                tri(a, d, b);
            }
        }
    }
    (pos, nrm, uv, idx)
}

/// Writes a minimal GLB: one node, one mesh, POSITION / NORMAL / TEXCOORD_0 and u16 indices,
/// the mesh being the proxy sphere of `segments x rings`.
pub fn write_glb(path: &Path, segments: usize, rings: usize, generator: &str) {
    let (pos, nrm, uv, idx) = proxy_sphere(segments, rings);
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
        "asset": { "version": "2.0", "generator": generator },
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
