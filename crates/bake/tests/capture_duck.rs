//! Loads the shared `duck-tiny` capture (24 train + 8 test, camera_angle_x, RGBA PNG, GLB mesh).

mod capture_common;

use capture_common::shared_captures;
use dnr_bake::capture::{Capture, LoadOptions, SplitSource};
use glam::Vec3;

#[test]
fn duck_tiny_loads_with_split_intrinsics_alpha_and_mesh() {
    let dir = shared_captures().join("duck-tiny");
    let cap = Capture::load(&dir, &LoadOptions::default()).unwrap();
    assert_eq!(cap.train.len(), 24);
    assert_eq!(cap.test.len(), 8);
    assert!(
        matches!(&cap.split, SplitSource::Files { test: Some(t), .. } if t.ends_with("transforms_test.json"))
    );
    // The Duck's authored UVs map its mirrored halves onto the same texels: auto replaces
    // them (the only remark).
    assert!(
        cap.uv.generated && cap.uv.overlap_fraction.unwrap() > 0.5,
        "{:?}",
        cap.uv
    );
    assert_eq!(cap.warnings.len(), 1, "{:?}", cap.warnings);
    assert!(cap.warnings[0].contains("overlap"), "{:?}", cap.warnings);

    // Intrinsics from camera_angle_x and the 128x128 image size.
    let fov = 0.6911112070083618f64 as f32;
    let f = 64.0 / (0.5 * fov).tan();
    for fr in cap.train.iter().chain(&cap.test) {
        assert_eq!((fr.width(), fr.height()), (128, 128));
        assert!((fr.camera.fx - f).abs() < 1e-3 && (fr.camera.fy - f).abs() < 1e-3);
        assert_eq!((fr.camera.cx, fr.camera.cy), (64.0, 64.0));
        assert_eq!(fr.rgb.len(), 128 * 128 * 3);
        assert_eq!(fr.alpha.len(), 128 * 128);
        assert!(fr.has_alpha && !fr.undistorted);
        // Cameras sit at distance 3.6 looking at the origin (-Z axis towards it).
        let eye = fr.camera.eye();
        assert!((eye.length() - 3.6).abs() < 1e-3, "{}: eye {eye}", fr.name);
        let fwd = -fr.camera.cam_to_world.z_axis.truncate();
        assert!(fwd.dot(-eye.normalize()) > 0.999);
        assert!(fr
            .rgb
            .iter()
            .chain(&fr.alpha)
            .all(|v| (0.0..=1.0).contains(v)));
        // Alpha is a real mask: background and object both present.
        assert!(fr.alpha.contains(&0.0) && fr.alpha.contains(&1.0));
    }
    assert_eq!(cap.train[0].name, "train/r_000");
    assert_eq!(cap.test[7].name, "test/r_007");

    // Pose of train/r_000 as written in transforms_train.json (row-major).
    let eye0 = cap.train[0].camera.eye();
    let written = [
        -0.5473597510502608f64,
        3.0615226818527304,
        -1.8131398653803472,
    ];
    assert!((eye0 - Vec3::from_array(written.map(|x| x as f32))).length() < 1e-5);
    let m20 = 0.2890030303212531f64 as f32;
    assert!((cap.train[0].camera.cam_to_world.x_axis.z - m20).abs() < 1e-6);

    // Pixels equal an independent decode / 255 (sRGB values kept as they are).
    let png = image::open(&cap.train[3].image_path).unwrap().to_rgba8();
    for (i, p) in png.pixels().enumerate().step_by(97) {
        for c in 0..3 {
            assert_eq!(cap.train[3].rgb[i * 3 + c], p.0[c] as f32 / 255.0);
        }
        assert_eq!(cap.train[3].alpha[i], p.0[3] as f32 / 255.0);
    }

    // Mesh from mesh_path with UVs.
    assert!(cap.mesh_path.ends_with("mesh.glb"));
    let tris: usize = cap
        .mesh
        .primitives
        .iter()
        .map(|p| p.indices.len() / 3)
        .sum();
    assert_eq!(tris, 4212);
    assert!(cap
        .mesh
        .primitives
        .iter()
        .all(|p| p.uvs.len() == p.positions.len()));
}

#[test]
fn mesh_override_wins_over_mesh_path() {
    let dir = shared_captures().join("duck-tiny");
    let opts = LoadOptions {
        mesh: Some(dir.join("mesh_coarse.glb")),
        ..Default::default()
    };
    let cap = Capture::load(&dir, &opts).unwrap();
    assert!(cap.mesh_path.ends_with("mesh_coarse.glb"));
    let tris: usize = cap
        .mesh
        .primitives
        .iter()
        .map(|p| p.indices.len() / 3)
        .sum();
    assert!(tris > 0 && tris < 1000, "{tris}");
}
