//! A capture that looks like one made with a phone, from the analytic sphere of
//! `raytrace`: JPEG photographs through an OpenCV lens with distortion, of the sphere on a
//! textured floor in front of a wall, with masks of the sphere, a proxy mesh without UVs as
//! binary PLY in the reconstruction's coordinates, and the poses twice: as a COLMAP binary
//! model and as nerfstudio's `transforms.json` (with its `applied_transform`). Plus the
//! undistorted pinhole twin: the same poses, scene and intrinsics without distortion, with
//! the proxy's authored UVs as GLB.
//!
//! Layout written under the output folder:
//! - `phone/`: `images/IMG_NNNN.jpg`, `masks/IMG_NNNN.jpg.png`, `sparse/0/{cameras,images,
//!   points3D}.bin`, `mesh.ply`, in COLMAP's world coordinates (the scene's turned, scaled
//!   and moved, see [`reconstruction_frame`]);
//! - `phone-ns/transforms.json`: the same photographs (paths into `../phone/`), poses
//!   in nerfstudio's coordinates, `applied_transform` from COLMAP's;
//! - `pinhole/`: `images/`, `masks/`, `transforms.json` (PINHOLE), `mesh.glb` with UVs, in
//!   the scene's coordinates.
//!
//! Deterministic: jitter comes from a hash of the frame index.
#![allow(dead_code)]

use std::path::Path;

use dnr_bake::capture::colmap::{write, ColmapCamera, ColmapImage};
use dnr_bake::capture::Distortion;
use glam::{DMat3, DMat4, DQuat, DVec3, DVec4};
use rayon::prelude::*;

use crate::raytrace::{linear_to_srgb, proxy_sphere, shade, write_glb, AMBIENT, LIGHT_DIR};

/// nerfstudio's `applied_transform` (ns-process-data from COLMAP): swap y and z, negate the
/// new z.
pub const APPLIED_TRANSFORM: [[f64; 4]; 3] = [
    [1.0, 0.0, 0.0, 0.0],
    [0.0, 0.0, 1.0, 0.0],
    [0.0, -1.0, 0.0, 0.0],
];

/// What to generate.
#[derive(Clone, Copy, Debug)]
pub struct PhoneConfig {
    /// Photograph width in pixels.
    pub width: u32,
    /// Photograph height in pixels.
    pub height: u32,
    /// Number of photographs.
    pub frames: usize,
    /// JPEG quality.
    pub quality: u8,
    /// Proxy sphere segments (rings are half).
    pub segments: usize,
}

impl Default for PhoneConfig {
    fn default() -> Self {
        PhoneConfig {
            width: 2016,
            height: 1512,
            frames: 64,
            quality: 92,
            segments: 48,
        }
    }
}

impl PhoneConfig {
    /// Pinhole intrinsics `(fx, fy, cx, cy)`: a 64 degree horizontal field of view and a
    /// principal point a little off centre, as a phone calibration gives.
    pub fn intrinsics(&self) -> [f64; 4] {
        let w = self.width as f64;
        let h = self.height as f64;
        [0.8 * w, 0.8 * w, 0.5 * w + 0.0035 * w, 0.5 * h - 0.002 * h]
    }

    /// The lens: OPENCV coefficients of the size a phone's main camera calibrates to.
    pub fn lens(&self) -> Distortion {
        Distortion::opencv(0.11, -0.23, 0.0007, -0.0004)
    }
}

/// Where COLMAP put the scene: its world is the scene's turned 30 degrees about (1, 1, 0),
/// scaled by 0.8 and moved, as a reconstruction's arbitrary frame is. Returns (rotation,
/// scale, translation).
pub fn reconstruction_frame() -> (DMat3, f64, DVec3) {
    (
        DMat3::from_axis_angle(DVec3::new(1.0, 1.0, 0.0).normalize(), 30f64.to_radians()),
        0.8,
        DVec3::new(0.4, 1.5, 2.2),
    )
}

/// A scene point in COLMAP's world.
pub fn to_reconstruction(p: DVec3) -> DVec3 {
    let (r, s, t) = reconstruction_frame();
    r * (p * s) + t
}

/// A scene camera-to-world in COLMAP's world (the rotation turns, the centre moves).
pub fn pose_to_reconstruction(c2w: &DMat4) -> DMat4 {
    let (r, _, _) = reconstruction_frame();
    DMat4::from_cols(
        (r * c2w.x_axis.truncate()).extend(0.0),
        (r * c2w.y_axis.truncate()).extend(0.0),
        (r * c2w.z_axis.truncate()).extend(0.0),
        to_reconstruction(c2w.w_axis.truncate()).extend(1.0),
    )
}

/// A hash of `(i, k)` to [-1, 1).
fn jitter(i: usize, k: u64) -> f64 {
    let mut x =
        (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ k.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x ^= x >> 31;
    x = x.wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^= x >> 29;
    (x >> 11) as f64 / (1u64 << 52) as f64 - 1.0
}

/// Camera-to-world (OpenGL convention) of frame `i` of `n`: three rings around the sphere at
/// hand-held distances, a few degrees of roll, aim a little off the centre.
pub fn pose(i: usize, n: usize) -> DMat4 {
    let ring = i % 3;
    let elevation = [10.0f64, 28.0, 46.0][ring].to_radians() + 0.03 * jitter(i, 1);
    let azimuth = 2.0 * std::f64::consts::PI * (i as f64 + 0.5) / n as f64 + 0.05 * jitter(i, 2);
    let dist = 3.3 + 0.2 * jitter(i, 3);
    let eye = DVec3::new(
        dist * elevation.cos() * azimuth.cos(),
        dist * elevation.sin(),
        dist * elevation.cos() * azimuth.sin(),
    );
    let target = DVec3::new(
        0.05 * jitter(i, 4),
        0.05 * jitter(i, 5),
        0.05 * jitter(i, 6),
    );
    let z = (eye - target).normalize();
    let roll = 4f64.to_radians() * jitter(i, 7);
    let up = DVec3::new(roll.sin(), roll.cos(), 0.0);
    let x = up.cross(z).normalize();
    let y = z.cross(x);
    DMat4::from_cols(x.extend(0.0), y.extend(0.0), z.extend(0.0), eye.extend(1.0))
}

/// Linear radiance of the background along a ray: a checkered wooden floor at y = -1 lit by
/// the scene's light, a grey wall beyond.
fn background(o: DVec3, d: DVec3) -> [f64; 3] {
    if d.y < -1e-6 {
        let t = (-1.0 - o.y) / d.y;
        let p = o + d * t;
        if p.x.hypot(p.z) < 7.0 {
            let cell = ((p.x * 2.0).floor() as i64 + (p.z * 2.0).floor() as i64).rem_euclid(2);
            let grain = 0.9 + 0.1 * (p.x * 23.0 + (p.z * 3.0).sin()).sin();
            let base = if cell == 0 {
                [0.42, 0.27, 0.15]
            } else {
                [0.30, 0.19, 0.10]
            };
            let l = DVec3::from_array(LIGHT_DIR).normalize();
            let k = AMBIENT + (1.0 - AMBIENT) * l.y.max(0.0);
            return base.map(|c| c * grain * k);
        }
    }
    let g = 0.35 + 0.15 * d.y.clamp(-1.0, 1.0);
    [g * 0.95, g, g * 1.05]
}

/// Renders one photograph (RGB8) and its mask (L8: 255 where the sphere covers at least half
/// the samples). `lens` None renders the pinhole twin.
pub fn render(cfg: &PhoneConfig, c2w: &DMat4, lens: Option<&Distortion>) -> (Vec<u8>, Vec<u8>) {
    let (w, h) = (cfg.width as usize, cfg.height as usize);
    let [fx, fy, cx, cy] = cfg.intrinsics();
    let eye = c2w.w_axis.truncate();
    let rot = DMat3::from_cols(
        c2w.x_axis.truncate(),
        -c2w.y_axis.truncate(),
        -c2w.z_axis.truncate(),
    );
    // Angular radius of the sphere plus a margin: pixels well away from it get one sample.
    let to_centre = (-eye).normalize();
    let cos_edge = (1.0 / eye.length()).asin().cos();
    let ray = |x: f64, y: f64| -> Option<DVec3> {
        let (xn, yn) = ((x - cx) / fx, (y - cy) / fy);
        let (xu, yu) = match lens {
            Some(d) => d.undistort(xn, yn)?,
            None => (xn, yn),
        };
        Some((rot * DVec3::new(xu, yu, 1.0)).normalize())
    };
    let rows: Vec<(Vec<u8>, Vec<u8>)> = (0..h)
        .into_par_iter()
        .map(|py| {
            let mut rgb = vec![0u8; 3 * w];
            let mut mask = vec![0u8; w];
            for px in 0..w {
                let centre = ray(px as f64 + 0.5, py as f64 + 0.5);
                let near = centre.is_some_and(|d| d.dot(to_centre) > cos_edge - 0.02);
                let offsets: &[(f64, f64)] = if near {
                    &[(0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75)]
                } else {
                    &[(0.5, 0.5)]
                };
                let mut sum = [0.0; 3];
                let mut hits = 0;
                let mut count = 0;
                for &(ox, oy) in offsets {
                    let Some(d) = ray(px as f64 + ox, py as f64 + oy) else {
                        continue;
                    };
                    count += 1;
                    let c = match shade(eye.to_array(), d.to_array()) {
                        Some(c) => {
                            hits += 1;
                            c
                        }
                        None => background(eye, d),
                    };
                    for k in 0..3 {
                        sum[k] += c[k];
                    }
                }
                let count = count.max(1) as f64;
                for k in 0..3 {
                    rgb[3 * px + k] = (linear_to_srgb(sum[k] / count) * 255.0).round() as u8;
                }
                mask[px] = if 2 * hits >= offsets.len() { 255 } else { 0 };
            }
            (rgb, mask)
        })
        .collect();
    let mut rgb = Vec::with_capacity(3 * w * h);
    let mut mask = Vec::with_capacity(w * h);
    for (r, m) in rows {
        rgb.extend(r);
        mask.extend(m);
    }
    (rgb, mask)
}

fn save_jpeg(path: &Path, rgb: &[u8], cfg: &PhoneConfig) {
    let f = std::fs::File::create(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut enc =
        image::codecs::jpeg::JpegEncoder::new_with_quality(std::io::BufWriter::new(f), cfg.quality);
    enc.encode(rgb, cfg.width, cfg.height, image::ExtendedColorType::Rgb8)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
}

fn save_mask(path: &Path, mask: &[u8], cfg: &PhoneConfig) {
    image::GrayImage::from_raw(cfg.width, cfg.height, mask.to_vec())
        .expect("mask size")
        .save(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
}

/// The proxy sphere's positions welded (seam and pole copies merged) and its triangles: what a
/// reconstruction tool writes, without UVs.
pub fn welded_proxy(segments: usize) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let (pos, _, _, idx) = proxy_sphere(segments, segments / 2);
    let mut map = std::collections::HashMap::new();
    let mut out = Vec::new();
    let remap: Vec<u32> = pos
        .iter()
        .map(|p| {
            let key = p.map(|c| (c as f64 * 1e5).round() as i64);
            *map.entry(key).or_insert_with(|| {
                out.push(*p);
                (out.len() - 1) as u32
            })
        })
        .collect();
    let tris = idx
        .chunks_exact(3)
        .map(|t| [0, 1, 2].map(|k| remap[t[k] as usize]))
        .filter(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2])
        .collect();
    (out, tris)
}

/// Writes the proxy in COLMAP's world as binary little-endian PLY with normals and grey
/// vertex colours (as reconstruction tools do) and no UVs.
pub fn write_ply(path: &Path, segments: usize) {
    let (pos, tris) = welded_proxy(segments);
    let mut b = format!(
        "ply\nformat binary_little_endian 1.0\ncomment dnr-bake example make_phone_capture\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
        pos.len(),
        tris.len()
    )
    .into_bytes();
    let (r, _, _) = reconstruction_frame();
    for p in &pos {
        let q = to_reconstruction(DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64));
        let n = r * DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64);
        for c in q.to_array().iter().chain(&n.to_array()) {
            b.extend((*c as f32).to_le_bytes());
        }
        b.extend([200u8, 200, 200]);
    }
    for t in &tris {
        b.push(3);
        for i in t {
            b.extend((*i as i32).to_le_bytes());
        }
    }
    std::fs::write(path, b).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
}

fn rows(m: &DMat4) -> serde_json::Value {
    let r = |k: usize| [m.x_axis[k], m.y_axis[k], m.z_axis[k], m.w_axis[k]];
    serde_json::json!([r(0), r(1), r(2), r(3)])
}

/// The applied transform as a 4x4 matrix.
pub fn applied_transform() -> DMat4 {
    let a = APPLIED_TRANSFORM;
    DMat4::from_cols(
        DVec4::new(a[0][0], a[1][0], a[2][0], 0.0),
        DVec4::new(a[0][1], a[1][1], a[2][1], 0.0),
        DVec4::new(a[0][2], a[1][2], a[2][2], 0.0),
        DVec4::new(a[0][3], a[1][3], a[2][3], 1.0),
    )
}

/// Sparse points: on the sphere (Fibonacci) and on the floor, with the images that see them.
fn sparse_points(cfg: &PhoneConfig, poses: &[DMat4]) -> (Vec<(u64, DVec3)>, Vec<Vec<u64>>) {
    let mut pts = Vec::new();
    let n_sphere = 1200;
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    for i in 0..n_sphere {
        let y = 1.0 - 2.0 * (i as f64 + 0.5) / n_sphere as f64;
        let r = (1.0 - y * y).sqrt();
        let a = i as f64 * golden;
        pts.push(DVec3::new(r * a.cos(), y, r * a.sin()));
    }
    for i in 0..400 {
        let r = 1.3 + 2.5 * (0.5 + 0.5 * jitter(i, 11));
        let a = 2.0 * std::f64::consts::PI * (0.5 + 0.5 * jitter(i, 12));
        pts.push(DVec3::new(r * a.cos(), -1.0, r * a.sin()));
    }
    let [fx, fy, cx, cy] = cfg.intrinsics();
    let lens = cfg.lens();
    let seen = poses
        .iter()
        .map(|c2w| {
            let eye = c2w.w_axis.truncate();
            let to_cam = c2w.inverse();
            pts.iter()
                .enumerate()
                .filter(|(k, p)| {
                    let c = to_cam.transform_point3(**p);
                    if c.z >= -1e-6 {
                        return false;
                    }
                    // OpenCV normalised coordinates: x right, y down, z forward.
                    let (xd, yd) = lens.distort(c.x / -c.z, -c.y / -c.z);
                    let (u, v) = (fx * xd + cx, fy * yd + cy);
                    if !(u >= 0.0 && v >= 0.0 && u < cfg.width as f64 && v < cfg.height as f64) {
                        return false;
                    }
                    if *k < n_sphere {
                        p.dot(eye - **p) > 0.0
                    } else {
                        shade(eye.to_array(), (**p - eye).normalize().to_array()).is_none()
                    }
                })
                .map(|(k, _)| k as u64 + 1)
                .collect()
        })
        .collect();
    (
        pts.into_iter()
            .enumerate()
            .map(|(k, p)| (k as u64 + 1, to_reconstruction(p)))
            .collect(),
        seen,
    )
}

/// Writes the three folders (see the module documentation) under `out`.
pub fn generate(out: &Path, cfg: &PhoneConfig) {
    let phone = out.join("phone");
    let ns = out.join("phone-ns");
    let twin = out.join("pinhole");
    for d in [
        phone.join("images"),
        phone.join("masks"),
        phone.join("sparse/0"),
        ns.clone(),
        twin.join("images"),
        twin.join("masks"),
    ] {
        std::fs::create_dir_all(&d).unwrap_or_else(|e| panic!("{}: {e}", d.display()));
    }
    let poses: Vec<DMat4> = (0..cfg.frames).map(|i| pose(i, cfg.frames)).collect();
    let lens = cfg.lens();
    let names: Vec<String> = (0..cfg.frames)
        .map(|i| format!("IMG_{:04}.jpg", i + 1))
        .collect();
    for (i, (c2w, name)) in poses.iter().zip(&names).enumerate() {
        let (rgb, mask) = render(cfg, c2w, Some(&lens));
        save_jpeg(&phone.join("images").join(name), &rgb, cfg);
        save_mask(&phone.join("masks").join(format!("{name}.png")), &mask, cfg);
        let (rgb, mask) = render(cfg, c2w, None);
        save_jpeg(&twin.join("images").join(name), &rgb, cfg);
        save_mask(&twin.join("masks").join(format!("{name}.png")), &mask, cfg);
        eprint!("\rrendered {}/{} views", i + 1, cfg.frames);
    }
    eprintln!();

    // COLMAP: world-to-camera in the OpenCV camera convention.
    let [fx, fy, cx, cy] = cfg.intrinsics();
    let camera = ColmapCamera {
        id: 1,
        model: "OPENCV",
        width: cfg.width as u64,
        height: cfg.height as u64,
        params: vec![fx, fy, cx, cy, lens.k1, lens.k2, lens.p1, lens.p2],
    };
    let (points, seen) = sparse_points(cfg, &poses);
    let colmap_poses: Vec<DMat4> = poses.iter().map(pose_to_reconstruction).collect();
    let images: Vec<ColmapImage> = colmap_poses
        .iter()
        .zip(&names)
        .zip(seen)
        .enumerate()
        .map(|(i, ((c2w, name), point_ids))| {
            let r_c2w = DMat3::from_cols(
                c2w.x_axis.truncate(),
                -c2w.y_axis.truncate(),
                -c2w.z_axis.truncate(),
            );
            let r = r_c2w.transpose();
            let t = -(r * c2w.w_axis.truncate());
            let q = DQuat::from_mat3(&r);
            ColmapImage {
                // COLMAP registers images in its own order: ids are not the name order.
                id: ((i * 7) % cfg.frames + 1) as u32,
                qvec: [q.w, q.x, q.y, q.z],
                tvec: t.to_array(),
                camera_id: 1,
                name: name.clone(),
                point_ids,
            }
        })
        .collect();
    let sparse = phone.join("sparse/0");
    std::fs::write(sparse.join("cameras.bin"), write::cameras_bin(&[camera])).unwrap();
    std::fs::write(sparse.join("images.bin"), write::images_bin(&images)).unwrap();
    std::fs::write(sparse.join("points3D.bin"), write::points_bin(&points)).unwrap();
    write_ply(&phone.join("mesh.ply"), cfg.segments);

    // nerfstudio: poses moved by applied_transform, photographs and mesh shared with phone/.
    let a = applied_transform();
    let frames: Vec<serde_json::Value> = colmap_poses
        .iter()
        .zip(&names)
        .zip(&images)
        .map(|((c2w, name), im)| {
            serde_json::json!({
                "file_path": format!("../phone/images/{name}"),
                "mask_path": format!("../phone/masks/{name}.png"),
                "transform_matrix": rows(&(a * *c2w)),
                "colmap_im_id": im.id,
            })
        })
        .collect();
    let ns_json = serde_json::json!({
        "w": cfg.width, "h": cfg.height,
        "fl_x": fx, "fl_y": fy, "cx": cx, "cy": cy,
        "k1": lens.k1, "k2": lens.k2, "p1": lens.p1, "p2": lens.p2,
        "camera_model": "OPENCV",
        "frames": frames,
        "applied_transform": APPLIED_TRANSFORM,
        "mesh_path": "../phone/mesh.ply",
    });
    std::fs::write(
        ns.join("transforms.json"),
        serde_json::to_string_pretty(&ns_json).unwrap() + "\n",
    )
    .unwrap();

    // The pinhole twin: the scene's coordinates, the proxy with its authored UVs.
    let frames: Vec<serde_json::Value> = poses
        .iter()
        .zip(&names)
        .map(|(c2w, name)| {
            serde_json::json!({
                "file_path": format!("images/{name}"),
                "mask_path": format!("masks/{name}.png"),
                "transform_matrix": rows(c2w),
            })
        })
        .collect();
    let twin_json = serde_json::json!({
        "w": cfg.width, "h": cfg.height,
        "fl_x": fx, "fl_y": fy, "cx": cx, "cy": cy,
        "camera_model": "PINHOLE",
        "frames": frames,
        "mesh_path": "mesh.glb",
    });
    std::fs::write(
        twin.join("transforms.json"),
        serde_json::to_string_pretty(&twin_json).unwrap() + "\n",
    )
    .unwrap();
    write_glb(
        &twin.join("mesh.glb"),
        cfg.segments,
        cfg.segments / 2,
        "dnr-bake example make_phone_capture",
    );
}
