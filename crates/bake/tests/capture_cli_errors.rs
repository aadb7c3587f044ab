//! What a user sees when a capture cannot work: `dnr-bake` prints one line naming the file
//! and the frame or camera, and exits non-zero (nothing is written).

mod capture_common;

use std::path::Path;
use std::process::Command;

use capture_common::{edit_json, simple_capture, write_png_rgba};
use dnr_bake::capture::colmap::{write, ColmapCamera, ColmapImage};
use serde_json::json;

/// Runs dnr-bake on `dir`; returns (exit code, stderr).
fn run(dir: &Path) -> (i32, String) {
    let out = dir.join("out.glb");
    let o = Command::new(env!("CARGO_BIN_EXE_dnr-bake"))
        .arg(dir)
        .arg("-o")
        .arg(&out)
        .args(["--preset", "fast", "--steps", "1"])
        .output()
        .unwrap();
    assert!(!out.exists(), "no asset on failure");
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

fn assert_one_line(code: i32, stderr: &str, needles: &[&str]) {
    assert_ne!(code, 0, "{stderr}");
    assert_eq!(stderr.trim_end().lines().count(), 1, "{stderr}");
    assert!(stderr.starts_with("dnr-bake: error: "), "{stderr}");
    for n in needles {
        assert!(stderr.contains(n), "missing {n:?} in {stderr}");
    }
}

fn colmap_capture(model: &'static str, params: usize, images: &[&str]) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let m = dir.path().join("sparse/0");
    std::fs::create_dir_all(&m).unwrap();
    let cam = ColmapCamera {
        id: 1,
        model,
        width: 16,
        height: 12,
        params: [16.0, 16.0, 8.0, 6.0]
            .into_iter()
            .chain(std::iter::repeat(0.0))
            .take(params)
            .collect(),
    };
    let ims: Vec<ColmapImage> = (0..4)
        .map(|i| ColmapImage {
            id: i + 1,
            qvec: [1.0, 0.0, 0.0, 0.0],
            tvec: [i as f64 * 0.1, 0.0, 3.0],
            camera_id: 1,
            name: format!("im{i}.png"),
            point_ids: vec![],
        })
        .collect();
    std::fs::write(m.join("cameras.bin"), write::cameras_bin(&[cam])).unwrap();
    std::fs::write(m.join("images.bin"), write::images_bin(&ims)).unwrap();
    for name in images {
        write_png_rgba(&dir.path().join("images").join(name), 16, 12, |_, _| {
            [100, 100, 100, 255]
        });
    }
    std::fs::write(dir.path().join("mesh.obj"), capture_common::quad_obj(true)).unwrap();
    dir
}

#[test]
fn unsupported_camera_model() {
    let dir = colmap_capture(
        "FULL_OPENCV",
        12,
        &["im0.png", "im1.png", "im2.png", "im3.png"],
    );
    let (code, err) = run(dir.path());
    assert_one_line(
        code,
        &err,
        &["sparse/0/cameras.bin", "camera 1", "FULL_OPENCV"],
    );
    // And in transforms.json.
    let dir = simple_capture(3, 8);
    edit_json(&dir.path().join("transforms.json"), |v| {
        v["frames"][1]["camera_model"] = json!("FISHEYE624")
    });
    let (code, err) = run(dir.path());
    assert_one_line(
        code,
        &err,
        &["transforms.json", "frames[1].camera_model", "FISHEYE624"],
    );
}

#[test]
fn missing_image() {
    let dir = colmap_capture("PINHOLE", 4, &["im0.png", "im1.png", "im3.png"]);
    let (code, err) = run(dir.path());
    assert_one_line(
        code,
        &err,
        &["images.bin", "image 3 (im2.png)", "im2.png not found"],
    );
}

#[test]
fn mask_of_the_wrong_size() {
    let dir = simple_capture(3, 8);
    write_png_rgba(&dir.path().join("masks/m1.png"), 7, 8, |_, _| [255; 4]);
    edit_json(&dir.path().join("transforms.json"), |v| {
        v["frames"][1]["mask_path"] = json!("masks/m1.png")
    });
    let (code, err) = run(dir.path());
    assert_one_line(
        code,
        &err,
        &["transforms.json: frames[1]", "m1.png is 7x8", "8x8"],
    );
}

#[test]
fn mesh_in_the_wrong_coordinates() {
    let dir = simple_capture(6, 16);
    // The quad moved 50 units away: no view sees it where the photographs' alpha is.
    let far = "v 49 -1 0\nv 51 -1 0\nv 51 1 0\nv 49 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3 4/4\n";
    std::fs::write(dir.path().join("mesh.obj"), far).unwrap();
    let (code, err) = run(dir.path());
    assert_one_line(
        code,
        &err,
        &[
            "alignment check",
            "other coordinates",
            "images/f_1",
            "--skip-alignment-check",
        ],
    );
}
