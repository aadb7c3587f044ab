//! Broken captures: every error names the file (and the field or frame) at fault.

mod capture_common;

use capture_common::*;
use dnr_bake::capture::{Capture, CaptureError, Limits, LoadOptions};
use serde_json::json;

fn load_err(dir: &std::path::Path) -> (CaptureError, String) {
    load_err_with(dir, &LoadOptions::default())
}

fn load_err_with(dir: &std::path::Path, opts: &LoadOptions) -> (CaptureError, String) {
    let e = Capture::load(dir, opts).expect_err("capture should fail to load");
    let msg = e.to_string();
    (e, msg)
}

#[test]
fn the_simple_capture_itself_loads() {
    let dir = simple_capture(9, 8);
    let cap = Capture::load(dir.path(), &LoadOptions::default()).unwrap();
    assert_eq!((cap.train.len(), cap.test.len()), (7, 2));
}

#[test]
fn missing_image_names_transforms_file_field_and_image() {
    let dir = simple_capture(4, 8);
    std::fs::remove_file(dir.path().join("images/f_2.png")).unwrap();
    let (e, msg) = load_err(dir.path());
    assert!(matches!(e, CaptureError::ImageNotFound { .. }), "{msg}");
    assert!(
        msg.contains("transforms.json") && msg.contains("frames[2].file_path"),
        "{msg}"
    );
    assert!(msg.contains("f_2.png"), "{msg}");
}

#[test]
fn unreadable_image_names_the_image() {
    let dir = simple_capture(4, 8);
    std::fs::write(
        dir.path().join("images/f_1.png"),
        b"\x89PNG\r\n\x1a\nthis is not a png",
    )
    .unwrap();
    let (e, msg) = load_err(dir.path());
    assert!(matches!(e, CaptureError::ImageDecode { .. }), "{msg}");
    assert!(msg.contains("f_1.png"), "{msg}");
}

#[test]
fn malformed_json_gives_line_and_column() {
    let dir = simple_capture(2, 8);
    std::fs::write(
        dir.path().join("transforms.json"),
        "{\n  \"camera_angle_x\": 0.7,\n  \"frames\": [,]\n}\n",
    )
    .unwrap();
    let (e, msg) = load_err(dir.path());
    match e {
        CaptureError::Json { line, column, .. } => assert_eq!((line, column), (3, 14), "{msg}"),
        other => panic!("expected a JSON error, got {other}"),
    }
    assert!(msg.contains("transforms.json:3:14"), "{msg}");
}

#[test]
fn mesh_without_uvs_is_refused_with_uv_keep_and_unwrapped_otherwise() {
    let dir = simple_capture(2, 8);
    std::fs::write(dir.path().join("mesh.obj"), quad_obj(false)).unwrap();
    let keep = LoadOptions {
        uv: dnr_bake::capture::UvMode::Keep,
        ..Default::default()
    };
    let (e, msg) = load_err_with(dir.path(), &keep);
    assert!(matches!(e, CaptureError::MeshNoUvs { .. }), "{msg}");
    assert!(
        msg.contains("mesh.obj") && msg.contains("--uv auto generates"),
        "{msg}"
    );
    let cap = Capture::load(dir.path(), &LoadOptions::default()).unwrap();
    assert!(cap.uv.generated && cap.uv.charts == Some(1), "{:?}", cap.uv);
    let p = &cap.mesh.primitives[0];
    assert_eq!(p.uvs.len(), p.positions.len());
}

#[test]
fn nan_in_matrix_names_frame_and_entry() {
    let dir = simple_capture(3, 8);
    // What Python's json.dump writes for float('nan').
    let path = dir.path().join("transforms.json");
    let text = std::fs::read_to_string(&path).unwrap();
    let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
    v["frames"][1]["transform_matrix"][0][3] = json!(12345.5);
    let text = serde_json::to_string_pretty(&v)
        .unwrap()
        .replace("12345.5", "NaN");
    std::fs::write(&path, text).unwrap();
    let (e, msg) = load_err(dir.path());
    assert!(matches!(e, CaptureError::Field { .. }), "{msg}");
    assert!(
        msg.contains("transforms.json") && msg.contains("frames[1].transform_matrix[0][3]"),
        "{msg}"
    );
    assert!(msg.contains("finite"), "{msg}");
}

#[test]
fn null_in_matrix_is_not_finite_either() {
    let dir = simple_capture(3, 8);
    edit_json(&dir.path().join("transforms.json"), |v| {
        v["frames"][2]["transform_matrix"][1][1] = json!(null)
    });
    let (_, msg) = load_err(dir.path());
    assert!(msg.contains("frames[2].transform_matrix[1][1]"), "{msg}");
}

#[test]
fn singular_matrix_names_the_frame() {
    let dir = simple_capture(3, 8);
    edit_json(&dir.path().join("transforms.json"), |v| {
        v["frames"][2]["transform_matrix"] =
            json!([[1, 0, 0, 0], [0, 1, 0, 0], [1, 1, 0, 3], [0, 0, 0, 1]]);
    });
    let (e, msg) = load_err(dir.path());
    assert!(matches!(e, CaptureError::Field { .. }), "{msg}");
    assert!(
        msg.contains("transforms.json")
            && msg.contains("frames[2].transform_matrix")
            && msg.contains("singular"),
        "{msg}"
    );
}

#[test]
fn image_size_disagreeing_with_intrinsics() {
    let dir = simple_capture(3, 8);
    edit_json(&dir.path().join("transforms.json"), |v| {
        let o = v.as_object_mut().unwrap();
        o.remove("camera_angle_x");
        for (k, x) in [
            ("fl_x", 10.0),
            ("fl_y", 10.0),
            ("cx", 4.0),
            ("cy", 4.0),
            ("w", 8.0),
            ("h", 8.0),
        ] {
            o.insert(k.into(), json!(x));
        }
    });
    // One image of the wrong size.
    write_png_rgba(&dir.path().join("images/f_1.png"), 8, 6, pattern(1));
    let (e, msg) = load_err(dir.path());
    assert!(
        matches!(
            e,
            CaptureError::ImageSize {
                width: 8,
                height: 6,
                expected_width: 8,
                expected_height: 8,
                ..
            }
        ),
        "{msg}"
    );
    assert!(
        msg.contains("f_1.png") && msg.contains("transforms.json") && msg.contains("frames[1]"),
        "{msg}"
    );
}

#[test]
fn no_frames() {
    let dir = simple_capture(2, 8);
    edit_json(&dir.path().join("transforms.json"), |v| {
        v["frames"] = json!([])
    });
    let (e, msg) = load_err(dir.path());
    assert!(matches!(e, CaptureError::NoFrames { .. }), "{msg}");
    assert!(
        msg.contains("transforms.json") && msg.contains("frames"),
        "{msg}"
    );
}

#[test]
fn one_frame_leaves_nothing_to_train_on_with_llffhold() {
    let dir = simple_capture(1, 8);
    let (e, msg) = load_err(dir.path());
    assert!(matches!(e, CaptureError::NoFrames { .. }), "{msg}");
    assert!(
        msg.contains("transforms.json") && msg.contains("llffhold"),
        "{msg}"
    );
}

#[test]
fn missing_frames_key_and_no_transforms() {
    let dir = simple_capture(2, 8);
    edit_json(&dir.path().join("transforms.json"), |v| {
        v.as_object_mut().unwrap().remove("frames");
    });
    let (_, msg) = load_err(dir.path());
    assert!(msg.contains("transforms.json: frames: missing"), "{msg}");

    std::fs::remove_file(dir.path().join("transforms.json")).unwrap();
    let (e, _) = load_err(dir.path());
    assert!(matches!(e, CaptureError::NoTransforms { .. }));
}

#[test]
fn no_intrinsics_and_bad_fov() {
    let dir = simple_capture(2, 8);
    let path = dir.path().join("transforms.json");
    edit_json(&path, |v| {
        v.as_object_mut().unwrap().remove("camera_angle_x");
    });
    let (_, msg) = load_err(dir.path());
    assert!(
        msg.contains("transforms.json") && msg.contains("no intrinsics"),
        "{msg}"
    );
    edit_json(&path, |v| v["camera_angle_x"] = json!(4.0));
    let (_, msg) = load_err(dir.path());
    assert!(msg.contains("transforms.json: camera_angle_x"), "{msg}");
    edit_json(&path, |v| v["camera_angle_x"] = json!("wide"));
    let (_, msg) = load_err(dir.path());
    assert!(msg.contains("camera_angle_x: expected a number"), "{msg}");
}

#[test]
fn mesh_problems_name_the_mesh() {
    let dir = simple_capture(2, 8);
    // Empty mesh.
    std::fs::write(dir.path().join("mesh.obj"), "# nothing\nv 0 0 0\n").unwrap();
    let (e, msg) = load_err(dir.path());
    assert!(
        matches!(e, CaptureError::MeshEmpty { .. }) && msg.contains("mesh.obj"),
        "{msg}"
    );
    // No mesh at all.
    std::fs::remove_file(dir.path().join("mesh.obj")).unwrap();
    let (e, _) = load_err(dir.path());
    assert!(matches!(e, CaptureError::NoMesh { .. }));
    // mesh_path naming a missing file.
    edit_json(&dir.path().join("transforms.json"), |v| {
        v["mesh_path"] = json!("proxy/missing.glb")
    });
    let (_, msg) = load_err(dir.path());
    assert!(
        msg.contains("transforms.json: mesh_path") && msg.contains("missing.glb"),
        "{msg}"
    );
    // Unsupported extension via the override.
    let stl = dir.path().join("mesh.stl");
    std::fs::write(&stl, "solid x\nendsolid x\n").unwrap();
    let opts = LoadOptions {
        mesh: Some(stl),
        ..Default::default()
    };
    let (e, msg) = load_err_with(dir.path(), &opts);
    assert!(
        matches!(e, CaptureError::MeshFormat { .. }) && msg.contains("mesh.stl"),
        "{msg}"
    );
    // Malformed glTF goes through the runtime loader and still names the file.
    let glb = dir.path().join("broken.glb");
    std::fs::write(&glb, b"glTF\x02\x00\x00\x00garbage").unwrap();
    let opts = LoadOptions {
        mesh: Some(glb),
        ..Default::default()
    };
    let (e, msg) = load_err_with(dir.path(), &opts);
    assert!(
        matches!(e, CaptureError::Gltf { .. }) && msg.contains("broken.glb"),
        "{msg}"
    );
}

#[test]
fn limits_are_checked_before_decoding() {
    let dir = simple_capture(5, 16);
    let opts = |l: Limits| LoadOptions {
        limits: l,
        ..Default::default()
    };
    let (e, msg) = load_err_with(
        dir.path(),
        &opts(Limits {
            max_frames: 4,
            ..Default::default()
        }),
    );
    assert!(
        matches!(
            e,
            CaptureError::TooManyFrames {
                count: 5,
                max: 4,
                ..
            }
        ) && msg.contains("transforms.json"),
        "{msg}"
    );
    let (e, msg) = load_err_with(
        dir.path(),
        &opts(Limits {
            max_image_side: 15,
            ..Default::default()
        }),
    );
    assert!(
        matches!(e, CaptureError::TooLarge { .. }) && msg.contains("f_0.png"),
        "{msg}"
    );
    let (e, msg) = load_err_with(
        dir.path(),
        &opts(Limits {
            max_total_pixels: 16 * 16 * 4,
            ..Default::default()
        }),
    );
    assert!(
        matches!(e, CaptureError::TooLarge { .. }) && msg.contains("frames[4]"),
        "{msg}"
    );
    let (e, msg) = load_err_with(
        dir.path(),
        &opts(Limits {
            max_json_bytes: 100,
            ..Default::default()
        }),
    );
    assert!(
        matches!(e, CaptureError::TooLarge { .. }) && msg.contains("transforms.json"),
        "{msg}"
    );
}

#[test]
fn bad_last_row_and_unsupported_camera_model() {
    let dir = simple_capture(2, 8);
    let path = dir.path().join("transforms.json");
    edit_json(&path, |v| {
        v["frames"][1]["transform_matrix"][3] = json!([0, 0, 1, 1])
    });
    let (_, msg) = load_err(dir.path());
    assert!(msg.contains("frames[1].transform_matrix[3]"), "{msg}");
    edit_json(&path, |v| {
        v["frames"][1]["transform_matrix"][3] = json!([0, 0, 0, 1]);
        v["camera_model"] = json!("EQUIRECTANGULAR");
    });
    let (_, msg) = load_err(dir.path());
    assert!(
        msg.contains("transforms.json: camera_model") && msg.contains("EQUIRECTANGULAR"),
        "{msg}"
    );
}

/// A PNG whose header claims 60000 x 60000 pixels (14 GB decoded) with 4 bytes of pixel data:
/// refused from the header, before any pixel buffer exists.
#[test]
fn image_header_claiming_a_huge_size_is_refused_before_decoding() {
    let dir = simple_capture(3, 16);
    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = b"IHDR".to_vec();
    ihdr.extend_from_slice(&60000u32.to_be_bytes());
    ihdr.extend_from_slice(&60000u32.to_be_bytes());
    ihdr.extend_from_slice(&[8, 6, 0, 0, 0]); // 8-bit RGBA
                                              // IHDR, then a few bytes of IDAT (the decoder reads the header up to the first IDAT)
                                              // and IEND: a well-formed file whose pixel data is far too short.
    for (kind, body) in [
        (&b"IHDR"[..], &ihdr[4..]),
        (&b"IDAT"[..], &[0x78, 0x9c, 0x03, 0x00][..]),
        (&b"IEND"[..], &[][..]),
    ] {
        let mut chunk = kind.to_vec();
        chunk.extend_from_slice(body);
        png.extend_from_slice(&(body.len() as u32).to_be_bytes());
        png.extend_from_slice(&chunk);
        png.extend_from_slice(&crc32fast::hash(&chunk).to_be_bytes());
    }
    std::fs::write(dir.path().join("images/f_1.png"), &png).unwrap();
    let (e, msg) = load_err_with(dir.path(), &LoadOptions::default());
    assert!(
        matches!(e, CaptureError::TooLarge { .. })
            && msg.contains("f_1.png")
            && msg.contains("60000"),
        "{msg}"
    );
    // A user who trusts the capture can raise the limit; then the missing pixel data is
    // the error, still without a 14 GB allocation (the total-pixel limit stops it first).
    let mut limits = Limits::default();
    limits.set("max_image_side=70000").unwrap();
    let (e, msg) = load_err_with(
        dir.path(),
        &LoadOptions {
            limits,
            ..Default::default()
        },
    );
    assert!(
        matches!(e, CaptureError::TooLarge { .. }) && msg.contains("pixels"),
        "{msg}"
    );
    assert!(limits
        .set("max_nonsense=1")
        .unwrap_err()
        .contains("max_frames"));
    assert!(limits.set("max_frames").is_err());
    assert!(limits.set("max_frames=-3").is_err());
}
