//! Numerical stress suite (issue #7), runtime half: degenerate geometry, extreme uvs through
//! every wrap mode, extreme fields of view and scene scales, grazing views, and the
//! network's numerics (instance norm of constant and large-offset planes, saturated tanh).
//!
//! Every case asserts finite outputs and a sensible result, never just "no panic".

// Index loops compare several per-pixel arrays at once.
#![allow(clippy::needless_range_loop)]

use dnr_runtime::camera::Camera;
use dnr_runtime::gbuffer::{GBuffer, NONE};
use dnr_runtime::nn::activation::{tanh, tanh_f32, Act};
use dnr_runtime::nn::norm::{instance_norm, instance_norm_stats, plane_stats, EPS};
use dnr_runtime::nn::Tensor;
use dnr_runtime::raster::rasterize;
use dnr_runtime::scene::{Primitive, Scene};
use dnr_runtime::texture::{sample_into, Level, Pyramid, Wrap};
use glam::{Mat4, Vec2, Vec3};

/// A pinhole camera at `eye` looking along -Z.
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

/// Axis-aligned quad in the plane z = `z`, half side `r`, centred on the z axis, uvs
/// `uv0 + (0..1, 0..1)`.
fn quad(r: f32, z: f32, uv0: Vec2) -> Primitive {
    Primitive {
        positions: vec![
            Vec3::new(-r, r, z),
            Vec3::new(r, r, z),
            Vec3::new(r, -r, z),
            Vec3::new(-r, -r, z),
        ],
        uvs: [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)]
            .iter()
            .map(|&(u, v)| uv0 + Vec2::new(u, v))
            .collect(),
        indices: vec![0, 3, 2, 0, 2, 1],
        world: Mat4::IDENTITY,
        ..Default::default()
    }
}

fn scene(prims: Vec<Primitive>) -> Scene {
    Scene { primitives: prims }
}

/// Every G-buffer invariant a consumer relies on: covered pixels have finite uv, finite
/// positive depth and a unit (or, when undefined, zero) view direction; uncovered pixels
/// are exactly the documented defaults.
fn assert_sane(g: &GBuffer, what: &str) {
    assert!(g.is_consistent(), "{what}: inconsistent G-buffer");
    for i in 0..g.len() {
        if g.is_covered(i) {
            assert_eq!(g.coverage[i], 1.0, "{what}: pixel {i} coverage");
            assert!(
                g.uv[i].iter().all(|v| v.is_finite()),
                "{what}: pixel {i} uv {:?}",
                g.uv[i]
            );
            assert!(
                g.depth[i].is_finite() && g.depth[i] > 0.0,
                "{what}: pixel {i} depth {}",
                g.depth[i]
            );
            let d = Vec3::from(g.view_dir[i]);
            assert!(d.is_finite(), "{what}: pixel {i} view dir {d}");
            assert!(
                d == Vec3::ZERO || (d.length() - 1.0).abs() < 1e-4,
                "{what}: pixel {i} view dir {d} is not unit"
            );
            assert_ne!(g.prim[i], NONE, "{what}: pixel {i} prim");
        } else {
            assert_eq!(g.depth[i], f32::INFINITY, "{what}: pixel {i} depth");
            assert_eq!(g.prim[i], NONE, "{what}: pixel {i} prim");
            assert_eq!(g.uv[i], [0.0; 2], "{what}: pixel {i} uv");
        }
    }
}

/// A 4x4, 2-channel level with distinct texels.
fn pyramid(wrap: Wrap) -> Pyramid {
    let data = (0..16)
        .flat_map(|t| [t as f32, 100.0 - 3.0 * t as f32])
        .collect();
    Pyramid::new(
        2,
        vec![Level {
            width: 4,
            height: 4,
            data,
        }],
        wrap,
        wrap,
    )
    .unwrap()
}

fn sample(pyr: &Pyramid, g: &GBuffer) -> Vec<f32> {
    let mut out = vec![f32::NAN; pyr.channels * g.len()];
    sample_into(pyr, g, &mut out).unwrap();
    out
}

// ---------------------------------------------------------------- 3. degenerate geometry

#[test]
fn zero_area_sliver_and_duplicate_vertex_triangles_leave_a_sane_gbuffer() {
    let cam = axis_camera(Vec3::new(0.0, 0.0, 3.0), 40.0, 64, 64);
    let reference = rasterize(&scene(vec![quad(1.0, 0.0, Vec2::ZERO)]), &cam);
    assert_sane(&reference, "reference quad");
    let quad_pixels = reference.covered_count();
    assert!(quad_pixels > 500, "{quad_pixels}");

    let mut p = quad(1.0, 0.0, Vec2::ZERO);
    let n = p.positions.len() as u32;
    // Duplicate vertices: the same positions again with other uvs, and a triangle that
    // repeats an index (zero area).
    p.positions.extend_from_within(0..4);
    p.uvs.extend([Vec2::new(0.5, 0.5); 4]);
    p.indices.extend([n, n, n + 1, 0, n, 1]); // (0, n) is the same point twice
                                              // A sliver: 1e-6 wide, crossing the whole image diagonally, in front of the quad.
    let s = p.positions.len() as u32;
    p.positions.extend([
        Vec3::new(-5.0, -5.0, 0.5),
        Vec3::new(5.0, 5.0, 0.5),
        Vec3::new(5.0 + 1e-6, 5.0, 0.5),
    ]);
    p.uvs.extend([Vec2::new(2.0, 2.0); 3]);
    p.indices.extend([s, s + 1, s + 2]);
    // A needle: two coincident vertices and a far one (zero area, non-zero length).
    p.indices.extend([s, s, s + 1]);
    let g = rasterize(&scene(vec![p]), &cam);
    assert_sane(&g, "degenerate triangles");
    // The degenerate triangles add nothing; the sliver at most a pixel per row it crosses.
    let extra = g.covered_count() - quad_pixels;
    assert!(extra <= 64, "sliver covered {extra} extra pixels");
    let sliver_or_quad = (0..g.len())
        .filter(|&i| g.is_covered(i))
        .all(|i| g.tri[i] <= 1 || g.tri[i] == 4);
    assert!(sliver_or_quad, "a zero-area triangle covered a pixel");
    // Where the quad is still visible it is exactly the reference.
    for i in 0..g.len() {
        if g.tri[i] <= 1 {
            assert_eq!(g.uv[i], reference.uv[i], "pixel {i}");
            assert_eq!(g.depth[i], reference.depth[i], "pixel {i}");
        }
    }
    let out = sample(&pyramid(Wrap::Repeat), &g);
    assert!(out.iter().all(|v| v.is_finite()));
}

#[test]
fn huge_uvs_through_the_rasteriser_sample_finite_values_for_every_wrap_mode() {
    let cam = axis_camera(Vec3::new(0.0, 0.0, 3.0), 40.0, 48, 48);
    let base = rasterize(&scene(vec![quad(1.0, 0.0, Vec2::ZERO)]), &cam);
    for wrap in [Wrap::Repeat, Wrap::MirroredRepeat, Wrap::ClampToEdge] {
        let pyr = pyramid(wrap);
        let (lo, hi) = pyr.levels[0]
            .data
            .iter()
            .fold((f32::MAX, f32::MIN), |(a, b), &v| (a.min(v), b.max(v)));
        let want = sample(&pyr, &base);
        let mean = |o: &[f32]| o.iter().map(|&v| f64::from(v)).sum::<f64>() / o.len() as f64;
        for offset in [1e6f32, -1e6] {
            let g = rasterize(&scene(vec![quad(1.0, 0.0, Vec2::splat(offset))]), &cam);
            assert_sane(&g, &format!("{wrap:?} uv offset {offset}"));
            assert_eq!(g.coverage, base.coverage);
            let out = sample(&pyr, &g);
            for (i, &v) in out.iter().enumerate() {
                assert!(
                    v.is_finite() && v >= lo - 1e-3 && v <= hi + 1e-3,
                    "{wrap:?} {offset}: value {i} = {v} outside [{lo}, {hi}]"
                );
            }
            match wrap {
                // Beyond the edge every tap is the corner texel.
                Wrap::ClampToEdge => {
                    let t = if offset > 0.0 { 15 } else { 0 };
                    let corner = &pyr.levels[0].data[t * 2..t * 2 + 2];
                    for i in (0..g.len()).filter(|&i| g.is_covered(i)) {
                        for c in 0..2 {
                            let v = out[c * g.len() + i];
                            assert!((v - corner[c]).abs() < 1e-4, "{v} vs {}", corner[c]);
                        }
                    }
                }
                // 1e6 is a whole (even) number of periods: the image is the base one up to
                // the uv precision f32 has at 1e6 (1/16), i.e. close in the mean.
                _ => {
                    let (a, b) = (mean(&out), mean(&want));
                    assert!(
                        (a - b).abs() < 0.1 * f64::from(hi - lo),
                        "{wrap:?} {offset}: mean {a} vs {b}"
                    );
                }
            }
        }
    }
}

#[test]
fn mesh_entirely_behind_the_camera_draws_nothing() {
    let cam = axis_camera(Vec3::ZERO, 40.0, 32, 32);
    // Looking along -Z; the quad sits at z = +5 (behind), also a huge one at z = +1e-3.
    let g = rasterize(
        &scene(vec![
            quad(1.0, 5.0, Vec2::ZERO),
            quad(1e6, 1e-3, Vec2::ZERO),
        ]),
        &cam,
    );
    assert_sane(&g, "behind");
    assert_eq!(g.covered_count(), 0);
    // One triangle with two vertices behind and one in front is clipped, not mirrored:
    // every covered pixel's point (eye + ray * depth) lies on the triangle.
    let v = [
        Vec3::new(-1.0, -1.0, 1.0),
        Vec3::new(1.0, -1.0, 1.0),
        Vec3::new(0.0, 1.0, -2.0),
    ];
    let tri = Primitive {
        positions: v.to_vec(),
        uvs: vec![Vec2::ZERO, Vec2::X, Vec2::Y],
        indices: vec![0, 1, 2],
        world: Mat4::IDENTITY,
        ..Default::default()
    };
    let g = rasterize(&scene(vec![tri]), &cam);
    assert_sane(&g, "straddling");
    assert!(g.covered_count() > 50, "{}", g.covered_count());
    let n = (v[1] - v[0]).cross(v[2] - v[0]);
    for i in (0..g.len()).filter(|&i| g.is_covered(i)) {
        let (x, y) = ((i % 32) as f32 + 0.5, (i / 32) as f32 + 0.5);
        let ray = Vec3::new((x - cam.cx) / cam.fx, -(y - cam.cy) / cam.fy, -1.0);
        let p = ray * g.depth[i];
        // Inside: p is on the same side of every edge as the triangle (within rounding).
        for k in 0..3 {
            let (a, b) = (v[k], v[(k + 1) % 3]);
            let side = (b - a).cross(p - a).dot(n) / n.length_squared();
            assert!(side > -1e-3, "pixel {i}: {p} outside edge {k} ({side})");
        }
        assert!((p - v[0]).dot(n).abs() / n.length() < 1e-3 * p.length().max(1.0));
    }
}

#[test]
fn camera_surrounded_by_a_box_sees_every_pixel_once_with_finite_samples() {
    // A cube of half side 2 around the eye, built from 6 quads.
    let faces: [[Vec3; 4]; 6] = {
        let c = |x: f32, y: f32, z: f32| Vec3::new(x, y, z) * 2.0;
        [
            [
                c(-1., 1., -1.),
                c(1., 1., -1.),
                c(1., -1., -1.),
                c(-1., -1., -1.),
            ],
            [
                c(1., 1., 1.),
                c(-1., 1., 1.),
                c(-1., -1., 1.),
                c(1., -1., 1.),
            ],
            [
                c(-1., 1., 1.),
                c(-1., 1., -1.),
                c(-1., -1., -1.),
                c(-1., -1., 1.),
            ],
            [
                c(1., 1., -1.),
                c(1., 1., 1.),
                c(1., -1., 1.),
                c(1., -1., -1.),
            ],
            [
                c(-1., 1., 1.),
                c(1., 1., 1.),
                c(1., 1., -1.),
                c(-1., 1., -1.),
            ],
            [
                c(-1., -1., -1.),
                c(1., -1., -1.),
                c(1., -1., 1.),
                c(-1., -1., 1.),
            ],
        ]
    };
    let prims = faces
        .iter()
        .map(|f| {
            let mut q = quad(1.0, 0.0, Vec2::ZERO);
            q.positions = f.to_vec();
            q
        })
        .collect();
    let s = scene(prims);
    for (eye, target, fov) in [
        (Vec3::ZERO, Vec3::new(0.3, 0.2, -1.0), 90.0),
        (Vec3::new(1.9, -1.9, 1.9), Vec3::new(-1.0, 1.0, -1.0), 150.0),
        (Vec3::new(0.0, 0.0, 1.999), Vec3::new(0.0, 0.0, 3.0), 60.0),
    ] {
        let cam = Camera::look_at(eye, target, fov, 40, 30);
        let g = rasterize(&s, &cam);
        assert_sane(&g, &format!("inside box from {eye}"));
        assert_eq!(g.covered_count(), g.len(), "eye {eye}");
        let out = sample(&pyramid(Wrap::MirroredRepeat), &g);
        assert!(out.iter().all(|v| v.is_finite()));
    }
}

// ---------------------------------------------------------------- 4. cameras and scales

/// Side in pixels of a camera-facing square of side `2 r` at distance `d` under focal `f`.
fn projected_side(f: f32, r: f32, d: f32) -> f32 {
    f * 2.0 * r / d
}

#[test]
fn extreme_vertical_fields_of_view_give_the_projected_coverage() {
    for (fov, d) in [(1.0f32, 100.0f32), (170.0, 0.05)] {
        let (w, h) = (96u32, 64u32);
        let cam = Camera::look_at(Vec3::new(0.0, 0.0, d), Vec3::ZERO, fov, w, h);
        assert!(
            cam.fy.is_finite() && cam.fy > 0.0,
            "fov {fov}: fy {}",
            cam.fy
        );
        let g = rasterize(&scene(vec![quad(0.5, 0.0, Vec2::ZERO)]), &cam);
        assert_sane(&g, &format!("fov {fov}"));
        let side = projected_side(cam.fy, 0.5, d);
        assert!(side > 10.0 && side < h as f32, "fov {fov}: side {side}");
        let expected = side * side;
        let found = g.covered_count() as f32;
        // Within one pixel row/column around the edges.
        assert!(
            (found - expected).abs() <= 4.0 * side + 4.0,
            "fov {fov}: {found} covered, expected about {expected}"
        );
        // Centre pixel sees uv 0.5 and depth d.
        let c = (h as usize / 2) * w as usize + w as usize / 2;
        assert!((g.depth[c] - d).abs() < 1e-4 * d, "{}", g.depth[c]);
        assert!((g.uv[c][0] - 0.5).abs() < 1.5 / side);
    }
}

/// A small scene of three primitives at scale 1: tilted quad, a triangle in front of it and
/// a far ground quad.
fn scaled_scene(s: f32) -> Scene {
    let mut a = quad(1.0, 0.0, Vec2::ZERO);
    a.world = Mat4::from_rotation_y(0.4) * Mat4::from_rotation_x(-0.3);
    let b = Primitive {
        positions: vec![
            Vec3::new(-0.3, -0.8, 0.7),
            Vec3::new(0.9, -0.2, 0.5),
            Vec3::new(0.1, 0.6, 0.9),
        ],
        uvs: vec![Vec2::ZERO, Vec2::X, Vec2::Y],
        indices: vec![0, 1, 2],
        world: Mat4::IDENTITY,
        ..Default::default()
    };
    let mut c = quad(4.0, -6.0, Vec2::ZERO);
    c.world = Mat4::from_rotation_x(-1.2);
    let mut prims = vec![a, b, c];
    for p in &mut prims {
        p.world = Mat4::from_scale(Vec3::splat(s)) * p.world;
    }
    scene(prims)
}

#[test]
fn scaled_scenes_cover_the_same_pixels_as_at_scale_one() {
    let (w, h) = (80u32, 60u32);
    let eye = Vec3::new(0.7, 0.9, 4.0);
    let cam_at = |s: f32| Camera::look_at(eye * s, Vec3::ZERO, 50.0, w, h);
    let g1 = rasterize(&scaled_scene(1.0), &cam_at(1.0));
    assert_sane(&g1, "scale 1");
    assert!(g1.covered_count() > 1000);
    for s in [1e-3f32, 1e4] {
        let g = rasterize(&scaled_scene(s), &cam_at(s));
        assert_sane(&g, &format!("scale {s}"));
        let differ = (0..g.len())
            .filter(|&i| g.coverage[i] != g1.coverage[i] || g.prim[i] != g1.prim[i])
            .count();
        assert!(differ <= 6, "scale {s}: {differ} pixels differ");
        for i in (0..g.len()).filter(|&i| g.prim[i] == g1.prim[i] && g1.is_covered(i)) {
            let rel = (g.depth[i] / s - g1.depth[i]).abs() / g1.depth[i];
            assert!(
                rel < 1e-4,
                "scale {s}: pixel {i} depth {} vs {}",
                g.depth[i],
                g1.depth[i]
            );
            assert!((g.uv[i][0] - g1.uv[i][0]).abs() < 1e-3);
            assert!((g.uv[i][1] - g1.uv[i][1]).abs() < 1e-3);
            let dv = Vec3::from(g.view_dir[i]) - Vec3::from(g1.view_dir[i]);
            assert!(dv.length() < 1e-3, "scale {s}: view dir differs by {dv}");
        }
    }
}

#[test]
fn grazing_views_of_a_plane_stay_finite() {
    // Ground plane y = 0, 20 x 20, looked at from heights down to exactly in the plane.
    let mut ground = quad(10.0, 0.0, Vec2::ZERO);
    ground.world = Mat4::from_rotation_x(-std::f32::consts::FRAC_PI_2);
    let s = scene(vec![ground]);
    let mut last = usize::MAX;
    for height in [1e-1f32, 1e-3, 1e-5, 1e-7, 0.0] {
        let eye = Vec3::new(0.0, height, 9.0);
        let cam = Camera::look_at(eye, Vec3::new(0.0, height, -9.0), 60.0, 64, 48);
        let g = rasterize(&s, &cam);
        assert_sane(&g, &format!("grazing at height {height}"));
        let n = g.covered_count();
        // Lower eye, thinner sliver of ground below the horizon; edge-on covers nothing.
        assert!(n <= last, "height {height}: {n} covered, {last} above");
        last = n;
        for i in (0..g.len()).filter(|&i| g.is_covered(i)) {
            let [u, v] = g.uv[i];
            assert!((-1e-3..=1.001).contains(&u) && (-1e-3..=1.001).contains(&v));
            // The view direction points down into the plane (local -z after the rotation).
            assert!(g.view_dir[i][2] <= 1e-6, "{:?}", g.view_dir[i]);
        }
        let out = sample(&pyramid(Wrap::ClampToEdge), &g);
        assert!(out.iter().all(|v| v.is_finite()));
    }
    assert_eq!(last, 0, "an edge-on plane covers no pixel centre");
}

// ---------------------------------------------------------------- 5. network numerics

#[test]
fn instance_norm_of_a_constant_plane_is_exactly_zero() {
    for value in [0.0f32, 0.1, -3.75, 1e4, 65504.0, 1e-30] {
        let (h, w) = (37, 53); // not a multiple of the 4-lane partial sums
        let mut t = Tensor::from_vec(2, h, w, vec![value; 2 * h * w]).unwrap();
        let st = instance_norm(&mut t);
        assert_eq!(st.mean, vec![value; 2], "value {value}");
        let rstd = (1.0 / EPS.sqrt()) as f32;
        assert!(st.rstd.iter().all(|&r| r == rstd), "{:?}", st.rstd);
        assert!(t.data.iter().all(|&v| v == 0.0), "value {value}");
    }
}

#[test]
fn tanh_saturates_to_exactly_one() {
    for x in [9.1f32, 20.0, 88.0, 89.0, 1e4, 1e30, f32::MAX, f32::INFINITY] {
        assert_eq!(tanh_f32(x), 1.0, "tanh({x})");
        assert_eq!(tanh_f32(-x), -1.0, "tanh({})", -x);
        assert_eq!(Act::Tanh.apply(x), 1.0);
    }
    let mut v = vec![1e4f32, -1e4, f32::INFINITY, f32::NEG_INFINITY, 0.0, -0.0];
    tanh(&mut v);
    assert_eq!(v, [1.0, -1.0, 1.0, -1.0, 0.0, -0.0]);
    // Tiny inputs keep their value (tanh x ~ x), subnormals included.
    for x in [1e-20f32, -1e-38, 1e-45] {
        assert_eq!(tanh_f32(x), x);
    }
}

/// Mean and biased variance in f64, two passes (the reference).
fn reference_stats(p: &[f32]) -> (f64, f64) {
    let n = p.len() as f64;
    let mean = p.iter().map(|&v| f64::from(v)).sum::<f64>() / n;
    let var = p
        .iter()
        .map(|&v| (f64::from(v) - mean).powi(2))
        .sum::<f64>()
        / n;
    (mean, var)
}

#[test]
fn instance_norm_statistics_of_a_large_offset_plane_match_f64() {
    // 4096 x 4096 values 1e4 + noise in [-0.5, 0.5): the variance (1/12) is 1e-9 of the
    // mean square, so E[x^2] - E[x]^2 loses it.
    let n = 4096 * 4096;
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    let data: Vec<f32> = (0..n)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            1e4 + ((state >> 40) as f32 / (1u64 << 24) as f32 - 0.5)
        })
        .collect();
    let (mean, var) = reference_stats(&data);
    assert!(var > 0.05 && var < 0.1, "{var}");
    let want_rstd = 1.0 / (var + EPS).sqrt();
    let (m, r) = plane_stats(&data);
    assert!(
        (f64::from(m) - mean).abs() <= 1e-6 * mean.abs(),
        "mean {m} vs {mean}"
    );
    assert!(
        (f64::from(r) - want_rstd).abs() <= 1e-6 * want_rstd,
        "rstd {r} vs {want_rstd} (variance {var})"
    );
    // Through the tensor API too (the same statistics per channel).
    let t = Tensor::from_vec(1, 4096, 4096, data).unwrap();
    let st = instance_norm_stats(&t);
    assert_eq!((st.mean[0], st.rstd[0]), (m, r));
}
