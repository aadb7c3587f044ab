//! Numerical stress suite (issue #7), baker half: export beyond the half range, non-finite
//! capture pixels and proxy vertices, and the accuracy of the texture-gradient scatter.

mod capture_common;

use std::collections::BTreeMap;

use capture_common::*;
use dnr_bake::capture::image::decode_image;
use dnr_bake::capture::{load_mesh, Capture, CaptureError, LoadOptions, MeshLimits};
use dnr_bake::export::{self, ExportNet};
use dnr_bake::kernels::sample::sample_backward;
use dnr_format::asset::{AssetBuilder, Node, Primitive as AssetPrimitive};
use dnr_format::model::DType;
use dnr_runtime::gbuffer::GBuffer;
use dnr_runtime::scene::{Primitive, Scene};
use dnr_runtime::texture::{Level, Pyramid, Wrap};
use glam::{Mat4, Vec2, Vec3};
use serde_json::json;

// ---------------------------------------------------------------- 1. half-precision export

fn export_scene() -> Scene {
    Scene {
        primitives: vec![Primitive {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y],
            uvs: vec![Vec2::ZERO, Vec2::X, Vec2::Y],
            indices: vec![0, 1, 2],
            world: Mat4::IDENTITY,
            ..Default::default()
        }],
    }
}

/// Two levels (4x4 and 2x2) of 3 channels, values in [-1, 1].
fn export_pyramid() -> Pyramid {
    let level = |s: usize| Level {
        width: s,
        height: s,
        data: (0..s * s * 3).map(|i| (i as f32 * 0.7).sin()).collect(),
    };
    Pyramid::new(3, vec![level(4), level(2)], Wrap::Repeat, Wrap::Repeat).unwrap()
}

/// A linear MLP (no hidden layer) from 3 channels to 3 outputs.
fn export_mlp(weight: Vec<f32>) -> ExportNet {
    let mut tensors = BTreeMap::new();
    tensors.insert("layers.0.weight".to_string(), (vec![3, 3], weight));
    tensors.insert("layers.0.bias".to_string(), (vec![3], vec![0.0; 3]));
    ExportNet::Mlp {
        hidden: vec![],
        out_ch: 3,
        tensors,
    }
}

fn export_err(pyr: &Pyramid, net: &ExportNet, dtype: DType) -> (String, std::path::PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("out.glb");
    let b = export::build(&export_scene(), pyr, None, net, 3, 1, dtype).unwrap();
    let e = export::write(&b, &path).expect_err("export should fail");
    assert!(!path.exists(), "a failed export left {}", path.display());
    (e.to_string(), path)
}

#[test]
fn export_beyond_the_half_range_names_the_level_channel_or_tensor() {
    let ok_weights = vec![0.5, -0.25, 0.125, 1.0, 0.0, -1.0, 2.0, 0.3, 0.7];
    // Sanity: the unmodified data exports.
    let dir = tempfile::tempdir().unwrap();
    let b = export::build(
        &export_scene(),
        &export_pyramid(),
        None,
        &export_mlp(ok_weights.clone()),
        3,
        1,
        DType::F16,
    )
    .unwrap();
    assert!(export::write(&b, &dir.path().join("ok.glb")).unwrap() > 0);

    // Features: level 1, texel (1, 0), channel 2.
    for v in [65519.9f32, 65520.0, -7e4, f32::NAN, f32::INFINITY] {
        let mut pyr = export_pyramid();
        pyr.levels[1].data[3 + 2] = v;
        let (msg, path) = export_err(&pyr, &export_mlp(ok_weights.clone()), DType::F16);
        assert!(
            msg.contains(&path.display().to_string())
                && msg.contains("level 1")
                && msg.contains("C02")
                && msg.contains("(1, 0)"),
            "{v}: {msg}"
        );
    }
    // Weights: f16 refuses beyond 65504, f32 only non-finite values.
    for (v, dtype) in [
        (65519.9f32, DType::F16),
        (65520.0, DType::F16),
        (-1e6, DType::F16),
        (f32::NAN, DType::F32),
        (f32::NEG_INFINITY, DType::F32),
    ] {
        let mut w = ok_weights.clone();
        w[4] = v;
        let (msg, _) = export_err(&export_pyramid(), &export_mlp(w), dtype.clone());
        assert!(
            msg.contains("layers.0.weight") && msg.contains("element 4"),
            "{v} {dtype:?}: {msg}"
        );
    }
}

// ---------------------------------------------------------------- 2. non-finite input

#[test]
fn non_finite_exr_pixels_follow_the_documented_rule_and_are_reported() {
    let dir = simple_capture(3, 4);
    // Frame 1 becomes a 4x4 EXR with NaN / infinities at known pixels.
    let p = dir.path().join("images/f_1.exr");
    let nan = f32::NAN;
    let inf = f32::INFINITY;
    let px = |x: usize, y: usize| match (x, y) {
        (2, 1) => (nan, 0.5, 0.5, 1.0),    // NaN colour: black
        (3, 1) => (inf, 0.0, -inf, 1.0),   // +inf: 1, -inf: 0
        (0, 3) => (0.5, 0.5, 0.5, nan),    // NaN alpha: background
        (1, 3) => (0.25, 0.25, 0.25, inf), // +inf alpha: opaque
        _ => (0.18, 0.18, 0.18, 1.0),
    };
    exr::prelude::write_rgba_file(&p, 4, 4, px).unwrap();
    let img = decode_image(&p, 64).unwrap();
    assert!(img.rgb.iter().chain(&img.alpha).all(|v| v.is_finite()));
    assert!(img
        .rgb
        .iter()
        .chain(&img.alpha)
        .all(|v| (0.0..=1.0).contains(v)));
    let at = |x: usize, y: usize| {
        let i = y * 4 + x;
        (&img.rgb[i * 3..i * 3 + 3], img.alpha[i])
    };
    assert_eq!(at(2, 1).0[0], 0.0);
    assert_eq!(at(3, 1).0, &[1.0, 0.0, 0.0]);
    assert_eq!(at(0, 3).1, 0.0);
    assert_eq!(at(1, 3).1, 1.0);
    let nf = img.non_finite.expect("non-finite samples must be reported");
    assert_eq!(nf.count, 5);
    assert_eq!((nf.first_pixel, nf.first_channel), ((2, 1), 'R'));

    // Inside a capture: loads, and a warning names the file and the pixel.
    edit_json(&dir.path().join("transforms.json"), |v| {
        v["frames"][1]["file_path"] = json!("images/f_1.exr")
    });
    let cap = Capture::load(
        dir.path(),
        &LoadOptions {
            llffhold: 0,
            ..Default::default()
        },
    )
    .unwrap();
    let w: Vec<&String> = cap
        .warnings
        .iter()
        .filter(|w| w.contains("f_1.exr"))
        .collect();
    assert_eq!(w.len(), 1, "{:?}", cap.warnings);
    assert!(
        w[0].contains("5 non-finite") && w[0].contains("pixel (2, 1) channel R"),
        "{}",
        w[0]
    );
    assert!(cap
        .train
        .iter()
        .all(|f| f.rgb.iter().chain(&f.alpha).all(|v| v.is_finite())));
    // A clean EXR gives no warning.
    exr::prelude::write_rgba_file(&p, 4, 4, |_, _| (0.2f32, 0.3f32, 0.4f32, 1.0f32)).unwrap();
    assert!(decode_image(&p, 64).unwrap().non_finite.is_none());
}

#[test]
fn nan_vertices_or_uvs_in_an_obj_proxy_name_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let l = MeshLimits::default();
    let good = quad_obj(true);
    for (what, bad) in [
        (
            "line 2: vertex has a non-finite position",
            good.replacen("v 1 -1 0", "v 1 nan 0", 1),
        ),
        (
            "line 3: vertex has a non-finite position",
            good.replacen("v 1 1 0", "v inf 1 0", 1),
        ),
        (
            "line 6: vertex has a non-finite texture",
            good.replacen("vt 1 0", "vt NaN 0", 1),
        ),
        (
            "line 7: vertex has a non-finite texture",
            good.replacen("vt 1 1", "vt 1 -inf", 1),
        ),
    ] {
        assert_ne!(bad, good);
        let p = dir.path().join("proxy.obj");
        std::fs::write(&p, &bad).unwrap();
        let e = load_mesh(&p, &l).expect_err(&bad);
        let msg = e.to_string();
        assert!(msg.contains("proxy.obj") && msg.contains(what), "{msg}");
    }
}

#[test]
fn nan_vertices_or_uvs_in_a_gltf_proxy_name_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let write = |name: &str, pos: [f32; 3], uv: [f32; 2]| {
        let mut b = AssetBuilder::new();
        let m = b.add_mesh(
            None,
            vec![AssetPrimitive {
                positions: vec![[0.0, 0.0, 0.0], pos, [0.0, 1.0, 0.0]],
                normals: None,
                tex_coords: vec![[0.0, 0.0], uv, [0.0, 1.0]],
                indices: vec![0, 1, 2],
                material: None,
            }],
        );
        b.add_node(Node {
            name: None,
            mesh: Some(m),
            translation: [0.0; 3],
            rotation: [0.0, 0.0, 0.0, 1.0],
            scale: [1.0; 3],
            children: Vec::new(),
        });
        let path = dir.path().join(name);
        b.write(&path).map(|_| path)
    };
    let ok = write("ok.glb", [1.5, 2.25, 0.0], [0.375, 0.0]).unwrap();
    assert_eq!(
        load_mesh(&ok, &MeshLimits::default())
            .unwrap()
            .triangle_count(),
        1
    );
    // The format writer refuses non-finite positions itself, with a clear error.
    let e = write("nan.glb", [f32::NAN, 0.0, 0.0], [1.0, 0.0]).unwrap_err();
    assert!(e.to_string().contains("finite"), "{e}");
    // A file from another writer: patch the binary chunk of the good file (2.25 is the only
    // such float in it, as is 0.375).
    let bytes = std::fs::read(&ok).unwrap();
    for (name, find, with, what) in [
        ("nanpos.glb", 2.25f32, f32::NAN, "position"),
        ("infpos.glb", 2.25, f32::NEG_INFINITY, "position"),
        ("nanuv.glb", 0.375, f32::NAN, "texture coordinate"),
    ] {
        let (find, with) = (find.to_le_bytes(), with.to_le_bytes());
        let at: Vec<usize> = (0..bytes.len() - 3)
            .filter(|&i| bytes[i..i + 4] == find)
            .collect();
        assert_eq!(at.len(), 1, "{name}");
        let mut patched = bytes.clone();
        patched[at[0]..at[0] + 4].copy_from_slice(&with);
        let path = dir.path().join(name);
        std::fs::write(&path, patched).unwrap();
        let e = load_mesh(&path, &MeshLimits::default()).expect_err(name);
        let msg = e.to_string();
        assert!(
            matches!(
                e,
                CaptureError::MeshParse { .. } | CaptureError::Gltf { .. }
            ) && msg.contains(name)
                && msg.contains(what),
            "{msg}"
        );
    }
}

// ---------------------------------------------------------------- 5. gradient accumulation

#[test]
fn texture_gradient_scatter_of_4m_equal_contributions_is_accurate() {
    // 2048 x 2048 covered pixels (4096 x 4096 with DNR_STRESS_SCALE >= 2, the longer
    // version) all sampling the centre of a 1x1 texture: every pixel sends d_out = 0.1 with
    // tap weight 1 into the same texel.
    let long = std::env::var("DNR_STRESS_SCALE")
        .ok()
        .and_then(|s| s.parse::<usize>().ok())
        .is_some_and(|s| s >= 2);
    let side = if long { 4096usize } else { 2048 };
    let (w, h) = (side, side);
    let mut g = GBuffer::new(w, h);
    g.coverage.fill(1.0);
    g.uv.fill([0.5, 0.5]);
    g.prim.fill(0);
    g.tri.fill(0);
    g.depth.fill(1.0);
    let pyr = Pyramid::new(
        1,
        vec![Level {
            width: 1,
            height: 1,
            data: vec![0.0],
        }],
        Wrap::Repeat,
        Wrap::Repeat,
    )
    .unwrap();
    let d = 0.1f32;
    let d_out = vec![d; w * h];
    let mut grads = vec![vec![0.0f32]];
    let touched = sample_backward(&pyr, &g, &d_out, &mut grads).unwrap();
    assert_eq!(touched, vec![vec![0u32]]);
    let exact = f64::from(d) * (w * h) as f64;
    let got = f64::from(grads[0][0]);
    assert!(
        ((got - exact) / exact).abs() < 1e-4,
        "scatter sum {got}, exact {exact} (relative error {:e})",
        (got - exact) / exact
    );
}
