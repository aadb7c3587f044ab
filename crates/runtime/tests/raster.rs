//! Rasteriser tests: analytic uv and depth, depth order, exactly-once coverage of closed and
//! open meshes (including near-plane clipping on screen), local-space view directions and
//! robustness against hostile geometry.

// Index loops mirror the math (pixel i, channel c) and compare several arrays at once.
#![allow(clippy::needless_range_loop)]

use dnr_runtime::camera::Camera;
use dnr_runtime::gbuffer::NONE;
use dnr_runtime::raster::{coverage_counts, near_distance, rasterize};
use dnr_runtime::scene::{Primitive, Scene};
use glam::{Mat3, Mat4, Quat, Vec2, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A pinhole camera at `eye` with identity rotation (looking along -Z).
fn axis_camera(eye: Vec3, f: f32, w: u32, h: u32) -> Camera {
    Camera {
        fx: f,
        fy: f,
        cx: w as f32 / 2.0,
        cy: h as f32 / 2.0,
        width: w,
        height: h,
        cam_to_world: Mat4::from_translation(eye),
    }
}

/// World-space ray direction through pixel (x, y) centre (not normalised; camera z = -1).
fn ray(cam: &Camera, x: usize, y: usize) -> Vec3 {
    let d = Vec3::new(
        (x as f32 + 0.5 - cam.cx) / cam.fx,
        -(y as f32 + 0.5 - cam.cy) / cam.fy,
        -1.0,
    );
    cam.cam_to_world.transform_vector3(d)
}

/// Quad with corners `c[0..4]` (top-left, top-right, bottom-right, bottom-left) and uvs
/// (0,0) (1,0) (1,1) (0,1).
fn quad(c: [Vec3; 4], world: Mat4) -> Primitive {
    Primitive {
        positions: c.to_vec(),
        uvs: vec![
            Vec2::new(0.0, 0.0),
            Vec2::new(1.0, 0.0),
            Vec2::new(1.0, 1.0),
            Vec2::new(0.0, 1.0),
        ],
        indices: vec![0, 3, 2, 0, 2, 1],
        world,
        ..Default::default()
    }
}

fn scene(prims: Vec<Primitive>) -> Scene {
    Scene { primitives: prims }
}

#[test]
fn camera_facing_quad_has_exact_uv_and_depth() {
    // Camera at z = 2, f = 64, 64x64: X = ±0.75 at z = 0 projects to x = 32 ± 24, i.e.
    // exactly pixels 8..56; so u = (x - 8) / 48 at pixel centre x.
    let cam = axis_camera(Vec3::new(0.0, 0.0, 2.0), 64.0, 64, 64);
    let s = 0.75;
    let q = quad(
        [
            Vec3::new(-s, s, 0.0),
            Vec3::new(s, s, 0.0),
            Vec3::new(s, -s, 0.0),
            Vec3::new(-s, -s, 0.0),
        ],
        Mat4::IDENTITY,
    );
    let g = rasterize(&scene(vec![q]), &cam);
    assert_eq!((g.width, g.height), (64, 64));
    assert!(g.is_consistent());
    for y in 0..64 {
        for x in 0..64 {
            let i = y * 64 + x;
            let inside = (8..56).contains(&x) && (8..56).contains(&y);
            assert_eq!(
                g.coverage[i],
                if inside { 1.0 } else { 0.0 },
                "pixel {x},{y}"
            );
            if inside {
                let (u, v) = ((x as f32 + 0.5 - 8.0) / 48.0, (y as f32 + 0.5 - 8.0) / 48.0);
                assert!(
                    (g.uv[i][0] - u).abs() < 1e-6 && (g.uv[i][1] - v).abs() < 1e-6,
                    "uv {:?} vs {u},{v}",
                    g.uv[i]
                );
                assert!((g.depth[i] - 2.0).abs() < 1e-6);
                assert_eq!(g.prim[i], 0);
                assert!(g.tri[i] < 2);
                let p = Vec3::new(
                    (x as f32 + 0.5 - 32.0) / 32.0,
                    -(y as f32 + 0.5 - 32.0) / 32.0,
                    0.0,
                );
                let d = (p - Vec3::new(0.0, 0.0, 2.0)).normalize();
                let vd = Vec3::from(g.view_dir[i]);
                assert!((vd - d).length() < 1e-6, "{vd} vs {d}");
            } else {
                assert_eq!(g.prim[i], NONE);
                assert_eq!(g.tri[i], NONE);
                assert_eq!(g.depth[i], f32::INFINITY);
                assert_eq!(g.view_dir[i], [0.0; 3]);
            }
        }
    }
}

#[test]
fn tilted_quad_is_perspective_correct() {
    // A quad tilted 60 degrees in depth; ray-plane intersection gives the analytic uv.
    let cam = Camera::look_at(Vec3::new(0.3, 0.2, 3.0), Vec3::ZERO, 50.0, 80, 60);
    let rot = Mat4::from_quat(Quat::from_rotation_x(1.0) * Quat::from_rotation_y(0.3));
    let world = Mat4::from_translation(Vec3::new(0.1, -0.05, 0.2)) * rot;
    let c = [
        Vec3::new(-1.0, 1.0, 0.0),
        Vec3::new(1.0, 1.0, 0.0),
        Vec3::new(1.0, -1.0, 0.0),
        Vec3::new(-1.0, -1.0, 0.0),
    ];
    let g = rasterize(&scene(vec![quad(c, world)]), &cam);
    let inv = world.inverse();
    let (eye_l, mut covered, mut checked) = (inv.transform_point3(cam.eye()), 0, 0);
    for y in 0..60 {
        for x in 0..80 {
            let i = y * 80 + x;
            let d_l = inv.transform_vector3(ray(&cam, x, y));
            let t = -eye_l.z / d_l.z; // local plane z = 0
            let p = eye_l + d_l * t;
            let (u, v) = ((p.x + 1.0) / 2.0, (1.0 - p.y) / 2.0);
            let margin = 0.02;
            let clearly_in =
                t > 0.0 && u > margin && u < 1.0 - margin && v > margin && v < 1.0 - margin;
            let clearly_out =
                t <= 0.0 || u < -margin || u > 1.0 + margin || v < -margin || v > 1.0 + margin;
            if g.coverage[i] == 1.0 {
                covered += 1;
                assert!(!clearly_out, "pixel {x},{y} covered but outside");
            } else {
                assert!(!clearly_in, "pixel {x},{y} not covered but inside");
            }
            if clearly_in {
                checked += 1;
                // Snapping moves vertices by <= 1/512 px: the uv error is far below 1e-3.
                assert!(
                    (g.uv[i][0] - u).abs() < 1e-3 && (g.uv[i][1] - v).abs() < 1e-3,
                    "uv {:?} vs {u},{v}",
                    g.uv[i]
                );
                let depth = t; // camera-space ray has z = -1, so t is the view depth
                assert!(
                    (g.depth[i] - depth).abs() < 1e-3 * depth,
                    "depth {} vs {depth}",
                    g.depth[i]
                );
            }
        }
    }
    assert!(checked > 200 && covered >= checked, "{checked} {covered}");
}

#[test]
fn nearer_quad_wins_in_both_submission_orders() {
    let cam = axis_camera(Vec3::ZERO, 40.0, 48, 40);
    let near = quad(
        [
            Vec3::new(-1.0, 0.5, -2.0),
            Vec3::new(0.5, 0.5, -2.0),
            Vec3::new(0.5, -1.0, -2.0),
            Vec3::new(-1.0, -1.0, -2.0),
        ],
        Mat4::IDENTITY,
    );
    let far = quad(
        [
            Vec3::new(-0.5, 1.0, -3.0),
            Vec3::new(1.5, 1.0, -3.0),
            Vec3::new(1.5, -0.5, -3.0),
            Vec3::new(-0.5, -0.5, -3.0),
        ],
        Mat4::IDENTITY,
    );
    for order in 0..2 {
        let (prims, near_id) = if order == 0 {
            (vec![near.clone(), far.clone()], 0)
        } else {
            (vec![far.clone(), near.clone()], 1)
        };
        let g = rasterize(&scene(prims), &cam);
        let (mut overlap, mut only_far) = (0, 0);
        for y in 0..40 {
            for x in 0..48 {
                let i = y * 48 + x;
                let r = ray(&cam, x, y);
                let hit = |z: f32, x0: f32, x1: f32, y0: f32, y1: f32| {
                    let p = r * (-z);
                    p.x > x0 + 0.02 && p.x < x1 - 0.02 && p.y > y0 + 0.02 && p.y < y1 - 0.02
                };
                let hn = hit(-2.0, -1.0, 0.5, -1.0, 0.5);
                let hf = hit(-3.0, -0.5, 1.5, -0.5, 1.0);
                if hn {
                    assert_eq!(g.prim[i], near_id, "order {order} pixel {x},{y}");
                    assert!((g.depth[i] - 2.0).abs() < 1e-5);
                    overlap += hf as usize;
                } else if hf {
                    let p = r * 2.0;
                    let maybe_near = p.x > -1.02 && p.x < 0.52 && p.y > -1.02 && p.y < 0.52;
                    if !maybe_near {
                        assert_eq!(g.prim[i], 1 - near_id);
                        assert!((g.depth[i] - 3.0).abs() < 1e-5);
                        only_far += 1;
                    }
                }
            }
        }
        assert!(overlap > 50 && only_far > 50, "{overlap} {only_far}");
    }
}

/// Icosphere with shared vertices, consistently oriented.
fn icosphere(subdiv: usize) -> (Vec<Vec3>, Vec<u32>) {
    let t = (1.0 + 5f32.sqrt()) / 2.0;
    let mut v: Vec<Vec3> = [
        [-1.0, t, 0.0],
        [1.0, t, 0.0],
        [-1.0, -t, 0.0],
        [1.0, -t, 0.0],
        [0.0, -1.0, t],
        [0.0, 1.0, t],
        [0.0, -1.0, -t],
        [0.0, 1.0, -t],
        [t, 0.0, -1.0],
        [t, 0.0, 1.0],
        [-t, 0.0, -1.0],
        [-t, 0.0, 1.0],
    ]
    .iter()
    .map(|p| Vec3::from(*p).normalize())
    .collect();
    let mut f: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..subdiv {
        let mut cache = std::collections::HashMap::new();
        let mut mid = |a: u32, b: u32, v: &mut Vec<Vec3>| {
            *cache.entry((a.min(b), a.max(b))).or_insert_with(|| {
                v.push(((v[a as usize] + v[b as usize]) * 0.5).normalize());
                v.len() as u32 - 1
            })
        };
        let mut nf = Vec::new();
        for [a, b, c] in f {
            let (ab, bc, ca) = (mid(a, b, &mut v), mid(b, c, &mut v), mid(c, a, &mut v));
            nf.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        f = nf;
    }
    (v, f.into_iter().flatten().collect())
}

fn random_rotation(rng: &mut ChaCha8Rng) -> Quat {
    Quat::from_euler(
        glam::EulerRot::XYZ,
        rng.random_range(-3.0..3.0),
        rng.random_range(-3.0..3.0),
        rng.random_range(-3.0..3.0),
    )
}

/// Unit vector, uniform on the sphere.
fn random_dir(rng: &mut ChaCha8Rng) -> Vec3 {
    loop {
        let v = Vec3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        if v.length_squared() > 0.01 && v.length_squared() <= 1.0 {
            return v.normalize();
        }
    }
}

#[test]
fn closed_sphere_is_covered_once_by_front_and_once_by_back_faces() {
    let (v, idx) = icosphere(3);
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut inside_pixels = 0;
    for pose in 0..12 {
        let world = Mat4::from_scale_rotation_translation(
            Vec3::splat(0.8),
            random_rotation(&mut rng),
            Vec3::new(0.1, -0.2, 0.05),
        );
        let prim = Primitive {
            positions: v.clone(),
            indices: idx.clone(),
            world,
            ..Default::default()
        };
        let s = scene(vec![prim]);
        let eye = random_dir(&mut rng) * rng.random_range(1.5..5.0);
        let target = Vec3::new(
            rng.random_range(-0.3..0.3),
            rng.random_range(-0.3..0.3),
            rng.random_range(-0.3..0.3),
        );
        let (w, h) = (61 + pose as u32, 47);
        let cam = Camera::look_at(eye, target, rng.random_range(20.0..70.0), w, h);
        let c = coverage_counts(&s, &cam);
        let g = rasterize(&s, &cam);
        for i in 0..(w * h) as usize {
            assert_eq!(
                c.front[i], c.back[i],
                "pose {pose} pixel {i}: front {} back {}",
                c.front[i], c.back[i]
            );
            assert!(
                c.front[i] <= 1,
                "pose {pose} pixel {i}: covered {} times by front faces",
                c.front[i]
            );
            assert_eq!(g.coverage[i] == 1.0, c.front[i] > 0);
            inside_pixels += c.front[i] as usize;
            if g.coverage[i] == 1.0 {
                // The depth test keeps the near side of the sphere: there the eye-to-surface
                // direction points against the outward normal (the local position itself).
                let (p, t) = (g.prim[i] as usize, g.tri[i] as usize);
                let n = v[idx[3 * t] as usize]
                    + v[idx[3 * t + 1] as usize]
                    + v[idx[3 * t + 2] as usize];
                assert_eq!(p, 0);
                assert!(
                    Vec3::from(g.view_dir[i]).dot(n.normalize()) < 0.05,
                    "pose {pose} pixel {i} shows the far side"
                );
            }
        }
    }
    assert!(inside_pixels > 1000);
}

#[test]
fn camera_inside_closed_sphere_sees_every_pixel_once() {
    let (v, idx) = icosphere(2);
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    for pose in 0..8 {
        let world = Mat4::from_rotation_translation(random_rotation(&mut rng), Vec3::ZERO);
        let s = scene(vec![Primitive {
            positions: v.clone(),
            indices: idx.clone(),
            world,
            ..Default::default()
        }]);
        let eye = random_dir(&mut rng) * rng.random_range(0.0..0.6);
        let cam = Camera::look_at(
            eye,
            eye + random_dir(&mut rng),
            rng.random_range(30.0..120.0),
            53,
            41,
        );
        let c = coverage_counts(&s, &cam);
        for i in 0..c.front.len() {
            assert_eq!((c.front[i], c.back[i]), (0, 1), "pose {pose} pixel {i}");
        }
        let g = rasterize(&s, &cam);
        assert_eq!(g.covered_count(), 53 * 41);
    }
}

/// Unit cube [-1,1]^3 with 8 shared vertices, 12 outward triangles.
fn cube() -> (Vec<Vec3>, Vec<u32>) {
    let v = (0..8)
        .map(|k| {
            Vec3::new(
                if k & 1 == 0 { -1.0 } else { 1.0 },
                if k & 2 == 0 { -1.0 } else { 1.0 },
                if k & 4 == 0 { -1.0 } else { 1.0 },
            )
        })
        .collect();
    let quads = [
        [0, 4, 6, 2],
        [1, 3, 7, 5],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 2, 3, 1],
        [4, 5, 7, 6],
    ];
    let idx = quads
        .iter()
        .flat_map(|q| [q[0], q[1], q[2], q[0], q[2], q[3]])
        .collect();
    (v, idx)
}

#[test]
fn cube_edges_through_pixel_centres_are_owned_once() {
    // Front face edges land exactly on pixel centres (x = 32 ± 10.5 with f = 42 at distance
    // 4), and the face diagonals run through centres too: only the fill rule decides.
    let (v, idx) = cube();
    let prim = Primitive {
        positions: v,
        indices: idx,
        world: Mat4::IDENTITY,
        ..Default::default()
    };
    let s = scene(vec![prim.clone()]);
    let cams = [
        axis_camera(Vec3::new(0.0, 0.0, 5.0), 42.0, 64, 64),
        axis_camera(Vec3::new(0.0, 0.0, 5.0), 42.0, 64, 63),
        Camera::look_at(Vec3::new(3.0, 3.0, 3.0), Vec3::ZERO, 40.0, 64, 64),
        Camera::look_at(Vec3::new(4.0, 0.0, 0.0), Vec3::ZERO, 40.0, 64, 64),
    ];
    for (k, cam) in cams.iter().enumerate() {
        let c = coverage_counts(&s, cam);
        let mut total = vec![0u32; c.front.len()];
        // Rasterising each triangle on its own and summing the masks gives the same counts.
        for t in 0..12 {
            let one = Primitive {
                indices: prim.indices[3 * t..3 * t + 3].to_vec(),
                ..prim.clone()
            };
            let g = rasterize(&scene(vec![one]), cam);
            for (s, &cv) in total.iter_mut().zip(&g.coverage) {
                *s += cv as u32;
            }
        }
        let mut covered = 0;
        for i in 0..total.len() {
            assert_eq!(c.front[i], c.back[i], "camera {k} pixel {i}");
            assert!(c.front[i] <= 1, "camera {k} pixel {i}");
            assert_eq!(total[i], c.front[i] + c.back[i], "camera {k} pixel {i}");
            covered += c.front[i];
        }
        if k == 0 {
            // Pixels with centres in [21.5, 42.5]: the left/top edge is included, the
            // right/bottom excluded, 21 x 21 pixels.
            assert_eq!(covered, 21 * 21);
        }
    }
}

/// A jittered height-field grid over [-5,5]^2 in the y = 0 plane, shared vertices.
fn ground_grid(n: usize, rng: &mut ChaCha8Rng, jitter: f32) -> (Vec<Vec3>, Vec<Vec2>, Vec<u32>) {
    let mut v = Vec::new();
    let mut uv = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            let inner = i > 0 && i < n && j > 0 && j < n;
            let (ji, jj) = if inner {
                (
                    rng.random_range(-jitter..jitter),
                    rng.random_range(-jitter..jitter),
                )
            } else {
                (0.0, 0.0)
            };
            let (x, z) = (
                -5.0 + 10.0 * (i as f32 + ji) / n as f32,
                -5.0 + 10.0 * (j as f32 + jj) / n as f32,
            );
            v.push(Vec3::new(x, 0.0, z));
            uv.push(Vec2::new((x + 5.0) / 10.0, (z + 5.0) / 10.0));
        }
    }
    let mut idx = Vec::new();
    let at = |i: usize, j: usize| (j * (n + 1) + i) as u32;
    for j in 0..n {
        for i in 0..n {
            if (i + j) % 2 == 0 {
                idx.extend([
                    at(i, j),
                    at(i, j + 1),
                    at(i + 1, j + 1),
                    at(i, j),
                    at(i + 1, j + 1),
                    at(i + 1, j),
                ]);
            } else {
                idx.extend([
                    at(i, j),
                    at(i, j + 1),
                    at(i + 1, j),
                    at(i + 1, j),
                    at(i, j + 1),
                    at(i + 1, j + 1),
                ]);
            }
        }
    }
    (v, uv, idx)
}

#[test]
fn ground_crossing_the_near_plane_is_clipped_on_screen_without_cracks() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let (v, uv, idx) = ground_grid(24, &mut rng, 0.3);
    let prim = Primitive {
        positions: v,
        uvs: uv,
        indices: idx,
        world: Mat4::IDENTITY,
        ..Default::default()
    };
    let s = scene(vec![prim]);
    let (w, h, f) = (64u32, 64u32, 48.0f32);
    for (k, yaw) in [0.0f32, 0.4, -1.1, 2.5].into_iter().enumerate() {
        let rot = Mat4::from_rotation_y(yaw);
        let make = |height: f32| {
            let eye = Vec3::new(0.37, height, -0.21);
            Camera {
                fx: f,
                fy: f,
                cx: 32.0,
                cy: 32.0,
                width: w,
                height: h,
                cam_to_world: Mat4::from_translation(eye) * rot,
            }
        };
        // Eye so low that the near plane meets the ground 16 px below the horizon: triangles
        // under the camera are clipped and the clipped edges are on screen.
        let height = near_distance(&s, &make(0.0)).unwrap() as f32 * 16.0 / f;
        let cam = make(height);
        let eye = cam.eye();
        let near = near_distance(&s, &cam).unwrap() as f32;
        let c = coverage_counts(&s, &cam);
        let g = rasterize(&s, &cam);
        let mut in_band = 0;
        for y in 0..h as usize {
            for x in 0..w as usize {
                let i = y * w as usize + x;
                let hits = c.front[i] + c.back[i];
                assert!(hits <= 1, "yaw {k}: pixel {x},{y} hit {hits} times");
                let r = ray(&cam, x, y);
                // View depth of the ground hit: camera-space ray has z = -1.
                let depth = -eye.y / r.y;
                let p = eye + r * depth;
                let in_grid = p.x.abs() < 4.9 && p.z.abs() < 4.9;
                if r.y < 0.0 && depth > near * 1.05 && in_grid {
                    assert_eq!(hits, 1, "yaw {k}: crack at {x},{y}");
                    assert!((g.depth[i] - depth).abs() < 1e-3 * depth);
                    let (u, vv) = ((p.x + 5.0) / 10.0, (p.z + 5.0) / 10.0);
                    assert!(
                        (g.uv[i][0] - u).abs() < 2e-3 && (g.uv[i][1] - vv).abs() < 2e-3,
                        "{:?} vs {u},{vv}",
                        g.uv[i]
                    );
                    in_band += (depth < near * 2.0) as usize;
                } else if r.y >= 0.0 || depth < near * 0.95 {
                    assert_eq!(
                        hits, 0,
                        "yaw {k}: pixel {x},{y} must not be drawn (mirrored or too near)"
                    );
                }
            }
        }
        assert!(in_band > 20, "the clip line is on screen ({in_band})");
    }
}

#[test]
fn view_dir_is_the_inverse_transformed_world_direction() {
    let (v, idx) = icosphere(2);
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let world = Mat4::from_scale_rotation_translation(
        Vec3::new(0.5, 1.3, 0.8),
        random_rotation(&mut rng),
        Vec3::new(0.4, -0.3, 0.2),
    );
    let s = scene(vec![Primitive {
        positions: v,
        indices: idx,
        world,
        ..Default::default()
    }]);
    let cam = Camera::look_at(
        Vec3::new(1.5, 2.0, 2.5),
        Vec3::new(0.4, -0.3, 0.2),
        45.0,
        70,
        50,
    );
    let g = rasterize(&s, &cam);
    let inv3 = Mat3::from_mat4(world).inverse();
    let mut n = 0;
    for y in 0..50 {
        for x in 0..70 {
            let i = y * 70 + x;
            if g.coverage[i] == 0.0 {
                continue;
            }
            let r = ray(&cam, x, y);
            let p_world = cam.eye() + r * g.depth[i];
            let expected = (inv3 * (p_world - cam.eye())).normalize();
            let got = Vec3::from(g.view_dir[i]);
            assert!((got - expected).length() < 1e-4, "{got} vs {expected}");
            assert!((got.length() - 1.0).abs() < 1e-5);
            n += 1;
        }
    }
    assert!(n > 300);
}

#[test]
fn hostile_geometry_is_skipped_not_fatal() {
    let nan = f32::NAN;
    let inf = f32::INFINITY;
    let good = [
        Vec3::new(-1.0, -1.0, 0.0),
        Vec3::new(1.0, -1.0, 0.0),
        Vec3::new(0.0, 1.0, 0.0),
    ];
    let positions = vec![
        good[0],
        good[1],
        good[2],
        Vec3::new(nan, 0.0, 0.0),
        Vec3::new(0.0, inf, 0.0),
        Vec3::new(1e30, 1e30, -1e30),
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(1.0, 1.0, 0.0),
        Vec3::new(2.0, 2.0, 0.0), // collinear
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(1e-12, 0.0, 0.0),
        Vec3::new(0.0, 1e-12, 0.0), // tiny
        Vec3::new(-1e30, -1e30, -1e10),
        Vec3::new(1e30, -1e30, -1e10),
        Vec3::new(0.0, 1e30, -1e10), // huge
    ];
    let uvs = vec![Vec2::new(1e30, -1e30); positions.len()];
    let indices = vec![
        0, 1, 2, 0, 3, 1, 2, 4, 1, 5, 0, 1, 6, 7, 8, 9, 10, 11, 12, 13, 14, 0, 1, 99, 0, 1,
    ];
    let prim = Primitive {
        positions,
        uvs,
        indices,
        world: Mat4::IDENTITY,
        ..Default::default()
    };
    let cam = axis_camera(Vec3::new(0.0, 0.0, 3.0), 30.0, 40, 40);
    let g = rasterize(&scene(vec![prim.clone()]), &cam);
    assert!(g.covered_count() > 100);
    assert!(g.depth.iter().all(|d| !d.is_nan()));
    // The huge triangle (z = -1e10) covers the background but is farther than the good one.
    let centre = 20 * 40 + 20;
    assert_eq!(g.tri[centre], 0);
    // Non-finite world matrix or camera: nothing drawn, no panic.
    let bad_world = Primitive {
        world: Mat4::from_scale(Vec3::splat(nan)),
        ..prim.clone()
    };
    assert_eq!(rasterize(&scene(vec![bad_world]), &cam).covered_count(), 0);
    let mut bad_cam = cam;
    bad_cam.cam_to_world = Mat4::from_translation(Vec3::new(nan, 0.0, 0.0));
    assert_eq!(
        rasterize(&scene(vec![prim.clone()]), &bad_cam).covered_count(),
        0
    );
    bad_cam = cam;
    bad_cam.fx = 0.0;
    assert_eq!(
        rasterize(&scene(vec![prim.clone()]), &bad_cam).covered_count(),
        0
    );
    bad_cam = cam;
    bad_cam.width = u32::MAX; // beyond MAX_IMAGE_SIDE: empty, and no giant allocation
    assert!(rasterize(&scene(vec![prim.clone()]), &bad_cam).is_empty());
    assert!(coverage_counts(&scene(vec![prim.clone()]), &bad_cam)
        .front
        .is_empty());
    bad_cam = cam;
    bad_cam.width = 0;
    assert!(rasterize(&scene(vec![prim.clone()]), &bad_cam).is_empty());
    // Singular world matrix (flattened): drawn, view_dir zero, no panic.
    let flat = Primitive {
        world: Mat4::from_scale(Vec3::new(1.0, 1.0, 0.0)),
        ..prim
    };
    let g = rasterize(&scene(vec![flat]), &cam);
    assert!(g.covered_count() > 100);
    assert!(g.view_dir.iter().all(|d| *d == [0.0; 3]));
    // Empty scene.
    assert_eq!(rasterize(&Scene::default(), &cam).covered_count(), 0);
}

#[test]
fn primitive_without_uvs_gets_nan_uv_but_coverage() {
    let cam = axis_camera(Vec3::new(0.0, 0.0, 2.0), 32.0, 16, 16);
    let mut q = quad(
        [
            Vec3::new(-1.0, 1.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(1.0, -1.0, 0.0),
            Vec3::new(-1.0, -1.0, 0.0),
        ],
        Mat4::IDENTITY,
    );
    q.uvs.clear();
    let g = rasterize(&scene(vec![q]), &cam);
    assert_eq!(g.covered_count(), 256);
    assert!(g.uv.iter().all(|uv| uv[0].is_nan() && uv[1].is_nan()));
}

#[test]
fn result_does_not_depend_on_thread_count() {
    let (v, idx) = icosphere(3);
    let s = scene(vec![Primitive {
        positions: v,
        indices: idx,
        world: Mat4::IDENTITY,
        ..Default::default()
    }]);
    let cam = Camera::look_at(Vec3::new(0.5, 1.0, 2.5), Vec3::ZERO, 50.0, 97, 83);
    let run = |n| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .unwrap()
            .install(|| rasterize(&s, &cam))
    };
    let a = run(1);
    let b = run(3);
    assert_eq!(a.prim, b.prim);
    assert_eq!(a.tri, b.tri);
    assert_eq!(a.depth, b.depth);
    assert_eq!(
        a.uv.iter().map(|u| u.map(f32::to_bits)).collect::<Vec<_>>(),
        b.uv.iter().map(|u| u.map(f32::to_bits)).collect::<Vec<_>>()
    );
}

#[test]
fn reusing_a_gbuffer_gives_the_same_result_as_a_fresh_one() {
    let (v, idx) = icosphere(2);
    let sphere = scene(vec![Primitive {
        positions: v,
        indices: idx,
        world: Mat4::IDENTITY,
        ..Default::default()
    }]);
    let cam = Camera::look_at(Vec3::new(0.2, 0.5, 2.5), Vec3::ZERO, 50.0, 45, 37);
    let far_cam = Camera::look_at(Vec3::new(0.2, 0.5, 9.0), Vec3::ZERO, 20.0, 45, 37);
    let mut g = rasterize(&sphere, &cam);
    for (s, c) in [
        (&sphere, &far_cam),
        (&Scene::default(), &cam),
        (&sphere, &cam),
    ] {
        dnr_runtime::raster::rasterize_into(s, c, &mut g);
        let fresh = rasterize(s, c);
        assert_eq!(g.prim, fresh.prim);
        assert_eq!(g.tri, fresh.tri);
        assert_eq!(g.coverage, fresh.coverage);
        assert_eq!(g.depth, fresh.depth);
        assert_eq!(g.view_dir, fresh.view_dir);
        assert_eq!(format!("{:?}", g.uv), format!("{:?}", fresh.uv));
    }
}
