//! The generated sample capture `samples/capture/` (see its README.md) loads as documented:
//! 48 + 12 views of 128x128 RGBA with extension-less paths, camera_angle_x intrinsics, and a
//! UV-sphere proxy in mesh.glb whose vertices lie on the unit sphere.

use dnr_bake::capture::{Capture, LoadOptions};

#[test]
fn sample_capture_loads() {
    let dir = std::path::Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../samples/capture"
    ));
    let cap = Capture::load(dir, &LoadOptions::default()).unwrap();
    assert_eq!((cap.train.len(), cap.test.len()), (48, 12));
    assert!(cap.warnings.is_empty(), "{:?}", cap.warnings);
    assert!(cap.mesh_path.ends_with("mesh.glb"));
    assert_eq!(cap.train[5].name, "train/r_5");
    assert!(cap.train[5].image_path.ends_with("train/r_5.png"));
    let f = 64.0 / (0.5f32 * 0.691_111_2).tan();
    for fr in cap.train.iter().chain(&cap.test) {
        assert_eq!((fr.width(), fr.height()), (128, 128));
        assert!((fr.camera.fx - f).abs() < 1e-3);
        assert!((fr.camera.eye().length() - 4.0).abs() < 1e-4);
        // The sphere is in view: covered centre, empty corner, antialiased edge.
        assert_eq!(fr.alpha[64 * 128 + 64], 1.0);
        assert_eq!(fr.alpha[0], 0.0);
        assert!(fr.alpha.iter().any(|&a| a > 0.0 && a < 1.0));
    }
    let prims = &cap.mesh.primitives;
    assert_eq!(prims.len(), 1);
    let p = &prims[0];
    assert_eq!(p.indices.len() / 3, 24 * 12 * 2 - 2 * 24);
    assert!(p.positions.iter().all(|v| (v.length() - 1.0).abs() < 1e-5));
    assert!(p
        .uvs
        .iter()
        .all(|uv| (0.0..=1.0).contains(&uv.x) && (0.0..=1.0).contains(&uv.y)));
    // glTF uv convention: v = 0 at the +Y pole.
    // Same parameterisation as the shader: v = acos(y) / pi, u = atan2(-z, x) / 2pi (mod 1).
    let tau = 2.0 * std::f32::consts::PI;
    for (v, uv) in p.positions.iter().zip(&p.uvs) {
        assert!((uv.y - v.y.clamp(-1.0, 1.0).acos() / std::f32::consts::PI).abs() < 1e-5);
        if v.y.abs() < 0.999 {
            let u = (-v.z).atan2(v.x) / tau;
            let du = (uv.x - u).rem_euclid(1.0);
            assert!(!(1e-5..=1.0 - 1e-5).contains(&du), "{v} {uv}");
        }
    }
    // Triangles wind counter-clockwise seen from outside.
    for t in p.indices.chunks_exact(3) {
        let [a, b, c] = [0, 1, 2].map(|k| p.positions[t[k] as usize]);
        assert!((b - a).cross(c - a).dot(a + b + c) > 0.0);
    }
}

/// A capture built or edited by hand may ask for the mesh space to be decided without an
/// `applied_transform` to decide with: the check places the mesh in the poses' coordinates
/// instead of failing.
#[test]
fn deciding_the_mesh_space_without_an_applied_transform_takes_the_poses() {
    use dnr_bake::capture::alignment::{check, AlignmentOptions};
    use dnr_bake::capture::MeshSpace;
    let dir = std::path::Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../samples/capture"
    ));
    let mut cap = Capture::load(dir, &LoadOptions::default()).unwrap();
    cap.applied_transform = None;
    cap.mesh_space = MeshSpace::Auto;
    let report = check(&mut cap, &AlignmentOptions::default()).unwrap();
    assert_eq!(cap.mesh_space, MeshSpace::Poses);
    assert_eq!(report.mesh_space, MeshSpace::Poses);
}
