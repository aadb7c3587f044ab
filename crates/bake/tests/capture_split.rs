//! Train/test split rules and intrinsics resolution.

mod capture_common;

use capture_common::*;
use dnr_bake::capture::{Capture, LoadOptions, SplitSource};
use serde_json::json;

#[test]
fn llffhold_holds_out_every_eighth_frame_from_index_zero() {
    let dir = simple_capture(17, 4);
    let cap = Capture::load(dir.path(), &LoadOptions::default()).unwrap();
    let names =
        |v: &[dnr_bake::capture::Frame]| v.iter().map(|f| f.name.clone()).collect::<Vec<_>>();
    assert_eq!(
        names(&cap.test),
        vec!["images/f_0", "images/f_8", "images/f_16"]
    );
    let expected_train: Vec<String> = (0..17)
        .filter(|i| i % 8 != 0)
        .map(|i| format!("images/f_{i}"))
        .collect();
    assert_eq!(names(&cap.train), expected_train);
    assert!(matches!(cap.split, SplitSource::LlffHold { every: 8, .. }));
    // Each frame carries its own pose and pixels.
    let eye9 = eye(9);
    assert!(
        (cap.train[7].camera.eye()
            - glam::Vec3::new(eye9[0] as f32, eye9[1] as f32, eye9[2] as f32))
        .length()
            < 1e-5
    );
    assert_eq!(cap.train[7].rgb[0], pattern(9)(0, 0)[0] as f32 / 255.0);

    // Another period, and none held out.
    let cap = Capture::load(
        dir.path(),
        &LoadOptions {
            llffhold: 5,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!((cap.train.len(), cap.test.len()), (13, 4));
    let cap = Capture::load(
        dir.path(),
        &LoadOptions {
            llffhold: 0,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!((cap.train.len(), cap.test.len()), (17, 0));
}

/// Moves frames of transforms.json into split files.
fn split_files(dir: &std::path::Path, test_name: Option<&str>) {
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("transforms.json")).unwrap())
            .unwrap();
    let frames = v["frames"].as_array().unwrap();
    let (a, b) = frames.split_at(3);
    write_json(
        &dir.join("transforms_train.json"),
        &json!({ "camera_angle_x": 0.7, "frames": a }),
    );
    if let Some(t) = test_name {
        write_json(&dir.join(t), &json!({ "camera_angle_x": 0.9, "frames": b }));
    }
}

#[test]
fn split_files_win_over_transforms_json_and_val_is_the_fallback() {
    let dir = simple_capture(5, 4);
    split_files(dir.path(), Some("transforms_val.json"));
    let cap = Capture::load(dir.path(), &LoadOptions::default()).unwrap();
    assert_eq!((cap.train.len(), cap.test.len()), (3, 2));
    assert!(
        matches!(&cap.split, SplitSource::Files { test: Some(t), .. } if t.ends_with("transforms_val.json"))
    );
    // Each file's own top-level intrinsics apply.
    assert!((cap.train[0].camera.fx - 2.0 / (0.35f32).tan()).abs() < 1e-4);
    assert!((cap.test[0].camera.fx - 2.0 / (0.45f32).tan()).abs() < 1e-4);

    // transforms_test.json wins over transforms_val.json.
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("transforms.json")).unwrap())
            .unwrap();
    write_json(
        &dir.path().join("transforms_test.json"),
        &json!({ "camera_angle_x": 0.9, "frames": [v["frames"][4]] }),
    );
    let cap = Capture::load(dir.path(), &LoadOptions::default()).unwrap();
    assert_eq!(cap.test.len(), 1);
    assert_eq!(cap.test[0].name, "images/f_4");
}

#[test]
fn train_file_without_test_file_gives_a_warning_and_no_test_frames() {
    let dir = simple_capture(5, 4);
    split_files(dir.path(), None);
    let cap = Capture::load(dir.path(), &LoadOptions::default()).unwrap();
    assert_eq!((cap.train.len(), cap.test.len()), (3, 0));
    assert!(
        cap.warnings.iter().any(|w| w.contains("no held-out")),
        "{:?}",
        cap.warnings
    );
}

#[test]
fn pixel_intrinsics_win_and_frames_override() {
    let dir = simple_capture(3, 8);
    edit_json(&dir.path().join("transforms.json"), |v| {
        for (k, x) in [
            ("fl_x", 11.0),
            ("fl_y", 12.0),
            ("cx", 3.5),
            ("cy", 4.5),
            ("w", 8.0),
            ("h", 8.0),
        ] {
            v[k] = json!(x);
        }
        v["frames"][2]["fl_x"] = json!(20.0);
        v["frames"][2]["cy"] = json!(2.0);
    });
    let cap = Capture::load(
        dir.path(),
        &LoadOptions {
            llffhold: 0,
            ..Default::default()
        },
    )
    .unwrap();
    let c = cap.train[0].camera;
    assert_eq!(
        (c.fx, c.fy, c.cx, c.cy, c.width, c.height),
        (11.0, 12.0, 3.5, 4.5, 8, 8)
    );
    let c = cap.train[2].camera;
    assert_eq!((c.fx, c.fy, c.cx, c.cy), (20.0, 12.0, 3.5, 2.0));
}

#[test]
fn fl_y_defaults_to_fl_x_and_principal_point_to_centre() {
    let dir = simple_capture(2, 8);
    edit_json(&dir.path().join("transforms.json"), |v| {
        v.as_object_mut().unwrap().remove("camera_angle_x");
        v["frames"][0]["fl_x"] = json!(9.0);
        v["frames"][1]["camera_angle_x"] = json!(1.0);
    });
    let cap = Capture::load(
        dir.path(),
        &LoadOptions {
            llffhold: 0,
            ..Default::default()
        },
    )
    .unwrap();
    let c = cap.train[0].camera;
    assert_eq!((c.fx, c.fy, c.cx, c.cy), (9.0, 9.0, 4.0, 4.0));
    let f = 4.0 / (0.5f32).tan();
    assert!((cap.train[1].camera.fx - f).abs() < 1e-4 && (cap.train[1].camera.fy - f).abs() < 1e-4);
}

#[test]
fn three_by_four_matrices_are_accepted() {
    let dir = simple_capture(2, 4);
    edit_json(&dir.path().join("transforms.json"), |v| {
        v["frames"][1]["transform_matrix"]
            .as_array_mut()
            .unwrap()
            .pop();
    });
    let cap = Capture::load(
        dir.path(),
        &LoadOptions {
            llffhold: 0,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(
        cap.train[1].camera.cam_to_world.row(3),
        glam::Vec4::new(0.0, 0.0, 0.0, 1.0)
    );
}
