//! The phone-like capture of `examples/make_phone_capture.rs` at a tiny size: its COLMAP and
//! nerfstudio forms load to the same frames and bake to assets that agree; masks and the
//! lens's validity mask reach training and evaluation; the alignment check places the mesh,
//! stops on a misplaced one and drops a single bad view on request.

#[path = "../examples/phone/mod.rs"]
mod phone;
#[path = "../examples/raytrace/mod.rs"]
mod raytrace;

use std::path::Path;

use dnr_bake::bake::{bake, BakeOptions};
use dnr_bake::capture::alignment::{check, AlignmentOptions};
use dnr_bake::capture::{Capture, CaptureError, LoadOptions, MeshSpace};
use dnr_bake::train::config::{Arch, Preset, TrainConfig};
use dnr_bake::train::views::View;
use glam::DMat4;

fn tiny(dir: &Path) {
    phone::generate(
        dir,
        &phone::PhoneConfig {
            width: 160,
            height: 120,
            frames: 10,
            quality: 90,
            segments: 16,
        },
    );
}

#[test]
fn colmap_and_nerfstudio_forms_load_to_the_same_frames() {
    let dir = tempfile::tempdir().unwrap();
    tiny(dir.path());
    let opts = LoadOptions::default();
    let mut colmap = Capture::load(&dir.path().join("phone"), &opts).unwrap();
    let mut ns = Capture::load(&dir.path().join("phone-ns"), &opts).unwrap();
    let a: DMat4 = ns.applied_transform.expect("applied_transform read");
    assert_eq!(a, phone::applied_transform());
    assert_eq!(ns.mesh_space, MeshSpace::Auto);
    // The alignment check finds the mesh in the reconstruction's coordinates for nerfstudio.
    let rc = check(&mut colmap, &AlignmentOptions::default()).unwrap();
    let rn = check(&mut ns, &AlignmentOptions::default()).unwrap();
    assert_eq!(ns.mesh_space, MeshSpace::Reconstruction);
    let (poses, recon) = rn.placement_medians.unwrap();
    assert!(poses < 0.5 && recon > 0.9, "{poses} {recon}");
    assert!(rc.median.unwrap() > 0.9 && rc.checked);
    assert_eq!(colmap.train.len(), 8);
    assert_eq!(colmap.test.len(), 2);
    for (fc, fs) in colmap
        .train
        .iter()
        .chain(&colmap.test)
        .zip(ns.train.iter().chain(&ns.test))
    {
        assert_eq!(fs.name, format!("../phone/images/{}", fc.name));
        assert!(fc.undistorted && fs.undistorted && fc.has_mask && fs.has_mask);
        // The same pixels and validity.
        assert_eq!(fc.rgb, fs.rgb);
        assert_eq!(fc.valid, fs.valid);
        let valid = fc.valid.as_ref().unwrap();
        let n_valid = valid.iter().filter(|&&v| v).count();
        assert!(n_valid > 0 && n_valid < valid.len() / 2, "{n_valid}");
        // The same camera, up to the applied transform.
        let back = a.inverse() * fs.record.cam_to_world;
        for (x, y) in back
            .to_cols_array()
            .iter()
            .zip(fc.record.cam_to_world.to_cols_array())
        {
            assert!((x - y).abs() < 1e-9, "{}", fc.name);
        }
        assert_eq!(
            (fc.record.fx, fc.record.cx, fc.distortion),
            (fs.record.fx, fs.record.cx, fs.distortion)
        );
    }
    // The mesh had no UVs: both got the same generated atlas.
    assert!(colmap.uv.generated && ns.uv.generated);
    assert_eq!(colmap.mesh.primitives[0].uvs, ns.mesh.primitives[0].uvs);
}

fn fast_cfg() -> TrainConfig {
    let mut cfg = TrainConfig::preset(Preset::Fast);
    cfg.arch = Arch::None;
    cfg.steps = 40;
    cfg.time_budget = 0.0;
    cfg.threads = 2;
    cfg
}

fn bake_opts(capture: &Path, out: &Path) -> BakeOptions {
    BakeOptions {
        report: Some(out.with_extension("json")),
        ..BakeOptions::new(capture, out)
    }
}

#[test]
fn both_forms_bake_to_assets_that_agree_and_carry_the_generated_uvs() {
    let dir = tempfile::tempdir().unwrap();
    tiny(dir.path());
    let cfg = fast_cfg();
    let out_c = dir.path().join("colmap.glb");
    let out_n = dir.path().join("ns.glb");
    let sc = bake(&cfg, &bake_opts(&dir.path().join("phone"), &out_c)).unwrap();
    let sn = bake(&cfg, &bake_opts(&dir.path().join("phone-ns"), &out_n)).unwrap();
    assert!(
        (sc.test_psnr - sn.test_psnr).abs() < 0.05 && (sc.test_mse - sn.test_mse).abs() < 1.0,
        "{sc:?} {sn:?}"
    );
    // The asset holds the capture's generated UVs: what the runtime draws with.
    let cap = Capture::load(&dir.path().join("phone"), &LoadOptions::default()).unwrap();
    for out in [&out_c, &out_n] {
        let scene = dnr_runtime::scene::load_gltf(out).unwrap();
        assert_eq!(scene.primitives.len(), 1);
        let (p, q) = (&scene.primitives[0], &cap.mesh.primitives[0]);
        assert_eq!(p.indices, q.indices);
        for (a, b) in p.uvs.iter().zip(&q.uvs) {
            assert!((*a - *b).abs().max_element() < 1e-6, "{a} {b}");
        }
    }
    // The report carries the load figures.
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out_n.with_extension("json")).unwrap())
            .unwrap();
    let load = &report["load"];
    assert_eq!(load["meshSpace"], "reconstruction");
    assert_eq!(load["framesUndistorted"], 10);
    assert!(load["uv"]["generated"].as_bool().unwrap());
    assert!(load["alignment"]["median"].as_f64().unwrap() > 0.9);
    assert!(load["timings"]["undistort"].as_f64().unwrap() > 0.0);
}

#[test]
fn misplaced_mesh_stops_and_single_bad_views_can_be_dropped() {
    let dir = tempfile::tempdir().unwrap();
    tiny(dir.path());
    let ns = dir.path().join("phone-ns");
    // The mesh declared in the poses' coordinates: it sits where COLMAP put it, not where
    // the poses look.
    let opts = LoadOptions {
        mesh_space: MeshSpace::Poses,
        ..Default::default()
    };
    let mut cap = Capture::load(&ns, &opts).unwrap();
    let e = check(&mut cap, &AlignmentOptions::default()).unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, CaptureError::Misaligned { .. }), "{msg}");
    assert!(
        msg.contains("alignment check")
            && msg.contains("applied_transform")
            && msg.contains("IMG_0002")
            && !msg.contains('\n'),
        "{msg}"
    );
    // Skipping trains anyway.
    let mut cap = Capture::load(&ns, &opts).unwrap();
    let r = check(
        &mut cap,
        &AlignmentOptions {
            skip: true,
            ..Default::default()
        },
    )
    .unwrap();
    assert!(!r.checked);

    // One pose turned away: that view fails alone.
    let twin = dir.path().join("pinhole");
    let path = twin.join("transforms.json");
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    let m = &mut v["frames"][3]["transform_matrix"];
    for r in 0..3 {
        let x = m[r][0].as_f64().unwrap();
        let z = m[r][2].as_f64().unwrap();
        m[r][0] = serde_json::json!(z);
        m[r][2] = serde_json::json!(-x);
    }
    std::fs::write(&path, v.to_string()).unwrap();
    let mut cap = Capture::load(&twin, &LoadOptions::default()).unwrap();
    let msg = check(&mut cap, &AlignmentOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        msg.contains("1 of 8 training views fail alone") && msg.contains("images/IMG_0004"),
        "{msg}"
    );
    let mut cap = Capture::load(&twin, &LoadOptions::default()).unwrap();
    let r = check(
        &mut cap,
        &AlignmentOptions {
            drop_misaligned: true,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(r.dropped, vec!["images/IMG_0004".to_string()]);
    assert_eq!(cap.train.len(), 7);
}

#[test]
fn masks_and_lens_validity_reach_the_loss() {
    let dir = tempfile::tempdir().unwrap();
    tiny(dir.path());
    let cap = Capture::load(&dir.path().join("phone"), &LoadOptions::default()).unwrap();
    let f = &cap.train[0];
    let v = View::new(&cap.mesh, f, 1);
    assert_eq!(v.valid, f.valid);
    let n = v.width() * v.height();
    // A renderer output; the loss must not see the invalid pixels' targets.
    let y: Vec<f32> = (0..3 * n)
        .map(|i| ((i * 37) % 100) as f32 / 50.0 - 1.0)
        .collect();
    let mut dy = vec![0.0f32; 3 * n];
    let loss = dnr_bake::train::photometric_l1(&y, &v, 3, &mut dy);
    let mut changed = v.clone();
    for i in (0..n).filter(|&i| !v.is_valid(i)) {
        for c in 0..3 {
            changed.target[c * n + i] = 1.0 - changed.target[c * n + i];
        }
    }
    let mut dy2 = vec![1.0f32; 3 * n];
    let loss2 = dnr_bake::train::photometric_l1(&y, &changed, 3, &mut dy2);
    assert_eq!(loss, loss2);
    assert_eq!(dy, dy2);
    for i in (0..n).filter(|&i| !v.is_valid(i)) {
        assert_eq!([dy[i], dy[n + i], dy[2 * n + i]], [0.0; 3]);
    }
    // Without the mask the changed targets would count.
    let mut open = changed.clone();
    open.valid = None;
    let loss3 = dnr_bake::train::photometric_l1(&y, &open, 3, &mut dy2);
    assert!((loss3 - loss).abs() > 1e-3, "{loss3} {loss}");
}

#[test]
fn a_mask_of_the_wrong_size_names_the_mask_and_frame() {
    let dir = tempfile::tempdir().unwrap();
    tiny(dir.path());
    let mask = dir.path().join("pinhole/masks/IMG_0003.jpg.png");
    image::GrayImage::new(80, 60).save(&mask).unwrap();
    let e = Capture::load(&dir.path().join("pinhole"), &LoadOptions::default()).unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, CaptureError::Frame { .. }), "{msg}");
    assert!(
        msg.contains("transforms.json: frames[2]")
            && msg.contains("IMG_0003.jpg.png is 80x60")
            && msg.contains("160x120"),
        "{msg}"
    );
}

#[test]
fn large_photographs_are_downscaled_with_their_intrinsics() {
    let dir = tempfile::tempdir().unwrap();
    tiny(dir.path());
    let twin = dir.path().join("pinhole");
    let full = Capture::load(&twin, &LoadOptions::default()).unwrap();
    let half = Capture::load(
        &twin,
        &LoadOptions {
            max_side: 80,
            ..Default::default()
        },
    )
    .unwrap();
    let (a, b) = (&full.train[0], &half.train[0]);
    assert_eq!((b.width(), b.height()), (80, 60));
    assert_eq!(b.source_size, (160, 120));
    assert!((b.record.fx - a.record.fx / 2.0).abs() < 1e-12);
    assert!((b.record.cx - a.record.cx / 2.0).abs() < 1e-12);
    // Area filter: each pixel is the mean of its 2x2 block (mask 1 everywhere inside).
    for (y, x) in [(10usize, 10usize), (30, 40), (59, 79)] {
        let mean: f32 = [(0, 0), (0, 1), (1, 0), (1, 1)]
            .iter()
            .map(|(dy, dx)| a.rgb[3 * ((2 * y + dy) * 160 + 2 * x + dx)])
            .sum::<f32>()
            / 4.0;
        assert!((b.rgb[3 * (y * 80 + x)] - mean).abs() < 1e-5);
    }
}
