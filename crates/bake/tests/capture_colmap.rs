//! COLMAP sparse models: both encodings and a nerfstudio `transforms.json` of the same
//! cameras give the same cameras; unsupported models and broken files are errors that name
//! the file and the camera or image.

mod capture_common;

use std::path::Path;

use capture_common::{quad_obj, write_json, write_png_rgba};
use dnr_bake::capture::colmap::{write, ColmapCamera, ColmapImage};
use dnr_bake::capture::{CaptureError, CapturePlan, FramePlan, LensModel, LoadOptions};
use serde_json::{json, Value};

/// One camera of every supported model, with the keys a nerfstudio frame would carry.
fn cameras() -> Vec<(ColmapCamera, Value)> {
    let (w, h) = (12u64, 9u64);
    let cam = |id: u32, model: &'static str, params: Vec<f64>, keys: Value| {
        (
            ColmapCamera {
                id,
                model,
                width: w,
                height: h,
                params,
            },
            keys,
        )
    };
    vec![
        cam(
            1,
            "SIMPLE_PINHOLE",
            vec![10.5, 6.1, 4.4],
            json!({"camera_model": "SIMPLE_PINHOLE", "fl_x": 10.5, "fl_y": 10.5, "cx": 6.1, "cy": 4.4}),
        ),
        cam(
            2,
            "PINHOLE",
            vec![10.5, 11.25, 5.9, 4.6],
            json!({"camera_model": "PINHOLE", "fl_x": 10.5, "fl_y": 11.25, "cx": 5.9, "cy": 4.6}),
        ),
        cam(
            3,
            "SIMPLE_RADIAL",
            vec![9.75, 6.0, 4.5, -0.07],
            json!({"camera_model": "SIMPLE_RADIAL", "fl_x": 9.75, "fl_y": 9.75, "cx": 6.0, "cy": 4.5, "k1": -0.07}),
        ),
        cam(
            4,
            "RADIAL",
            vec![9.5, 6.05, 4.45, -0.11, 0.025],
            json!({"camera_model": "RADIAL", "fl_x": 9.5, "fl_y": 9.5, "cx": 6.05, "cy": 4.45, "k1": -0.11, "k2": 0.025}),
        ),
        cam(
            5,
            "OPENCV",
            vec![10.1, 10.3, 6.2, 4.3, 0.11, -0.23, 0.0007, -0.0004],
            // distortion_params: nerfstudio's [k1, k2, k3, k4, p1, p2].
            json!({"fl_x": 10.1, "fl_y": 10.3, "cx": 6.2, "cy": 4.3,
                   "distortion_params": [0.11, -0.23, 0.0, 0.0, 0.0007, -0.0004]}),
        ),
        cam(
            6,
            "OPENCV_FISHEYE",
            vec![8.0, 8.1, 6.0, 4.5, 0.05, -0.01, 0.002, -0.0005],
            json!({"camera_model": "OPENCV_FISHEYE", "fl_x": 8.0, "fl_y": 8.1, "cx": 6.0, "cy": 4.5,
                   "k1": 0.05, "k2": -0.01, "k3": 0.002, "k4": -0.0005}),
        ),
    ]
}

/// A deterministic value in [-1, 1).
fn hash(i: usize, k: usize) -> f64 {
    let x = ((i * 7919 + k * 104729) as f64 * 0.618_033_988_75).fract();
    2.0 * x - 1.0
}

/// Images in a registration order that is not their name order, each with a distinct pose.
fn images(n: usize) -> Vec<ColmapImage> {
    (0..n)
        .map(|i| {
            let q = [1.0 + hash(i, 1), hash(i, 2), hash(i, 3), hash(i, 4)];
            let norm = q.iter().map(|v| v * v).sum::<f64>().sqrt();
            ColmapImage {
                id: (n - i) as u32 * 3,
                qvec: q.map(|v| v / norm),
                tvec: [hash(i, 5), hash(i, 6), 3.0 + hash(i, 7)],
                camera_id: (i % 6) as u32 + 1,
                name: format!("img_{:02}.png", (i * 5) % n),
                point_ids: vec![],
            }
        })
        .collect()
}

/// Camera-to-world (OpenGL convention, row-major rows) written from COLMAP's quaternion and
/// translation with the textbook formulas, independently of the reader.
fn c2w_rows(im: &ColmapImage) -> [[f64; 4]; 4] {
    let [w, x, y, z] = im.qvec;
    let r = [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - z * w),
            2.0 * (x * z + y * w),
        ],
        [
            2.0 * (x * y + z * w),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - x * w),
        ],
        [
            2.0 * (x * z - y * w),
            2.0 * (y * z + x * w),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ];
    let t = im.tvec;
    let mut m = [[0.0; 4]; 4];
    for row in 0..3 {
        // R^T, with the camera's y and z axes negated (OpenCV -> OpenGL).
        m[row][0] = r[0][row];
        m[row][1] = -r[1][row];
        m[row][2] = -r[2][row];
        m[row][3] = -(r[0][row] * t[0] + r[1][row] * t[1] + r[2][row] * t[2]);
    }
    m[3][3] = 1.0;
    m
}

fn write_images(dir: &Path, ims: &[ColmapImage]) {
    for im in ims {
        write_png_rgba(&dir.join("images").join(&im.name), 12, 9, |x, y| {
            [(x * 20) as u8, (y * 25) as u8, 90, 255]
        });
    }
    std::fs::write(dir.join("mesh.obj"), quad_obj(true)).unwrap();
}

fn write_model(dir: &Path, bin: bool, cams: &[ColmapCamera], ims: &[ColmapImage]) {
    let m = dir.join("sparse/0");
    std::fs::create_dir_all(&m).unwrap();
    if bin {
        std::fs::write(m.join("cameras.bin"), write::cameras_bin(cams)).unwrap();
        std::fs::write(m.join("images.bin"), write::images_bin(ims)).unwrap();
    } else {
        std::fs::write(m.join("cameras.txt"), write::cameras_txt(cams)).unwrap();
        std::fs::write(m.join("images.txt"), write::images_txt(ims)).unwrap();
    }
}

fn plan(dir: &Path) -> Vec<FramePlan> {
    CapturePlan::read(dir, &LoadOptions::default())
        .unwrap_or_else(|e| panic!("{e}"))
        .frames
}

fn assert_same(a: &[FramePlan], b: &[FramePlan], what: &str) {
    assert_eq!(a.len(), b.len(), "{what}");
    for (fa, fb) in a.iter().zip(b) {
        assert_eq!(fa.name, fb.name, "{what}");
        assert_eq!(fa.test, fb.test, "{what}: {}", fa.name);
        let (ra, rb) = (&fa.record, &fb.record);
        assert_eq!((ra.width, ra.height), (rb.width, rb.height));
        for (x, y) in [
            (ra.fx, rb.fx),
            (ra.fy, rb.fy),
            (ra.cx, rb.cx),
            (ra.cy, rb.cy),
        ] {
            assert!(
                (x - y).abs() <= 1e-9,
                "{what}: {}: {ra:?} vs {rb:?}",
                fa.name
            );
        }
        let (ma, mb) = (
            ra.cam_to_world.to_cols_array(),
            rb.cam_to_world.to_cols_array(),
        );
        for (x, y) in ma.iter().zip(&mb) {
            assert!(
                (x - y).abs() <= 1e-9,
                "{what}: {}: {ma:?} vs {mb:?}",
                fa.name
            );
        }
        let (da, db) = (fa.distortion, fb.distortion);
        assert_eq!(da.model, db.model, "{what}: {}", fa.name);
        for (x, y) in [
            (da.k1, db.k1),
            (da.k2, db.k2),
            (da.k3, db.k3),
            (da.k4, db.k4),
            (da.p1, db.p1),
            (da.p2, db.p2),
        ] {
            assert!(
                (x - y).abs() <= 1e-9,
                "{what}: {}: {da:?} vs {db:?}",
                fa.name
            );
        }
    }
}

#[test]
fn colmap_bin_txt_and_nerfstudio_json_give_the_same_cameras() {
    let cams = cameras();
    let colmap_cams: Vec<ColmapCamera> = cams.iter().map(|(c, _)| c.clone()).collect();
    let ims = images(16);
    let (bin, txt, ns) = (
        tempfile::tempdir().unwrap(),
        tempfile::tempdir().unwrap(),
        tempfile::tempdir().unwrap(),
    );
    for d in [&bin, &txt, &ns] {
        write_images(d.path(), &ims);
    }
    write_model(bin.path(), true, &colmap_cams, &ims);
    write_model(txt.path(), false, &colmap_cams, &ims);
    // nerfstudio: frames in name order; size and one lens key at the top level, the rest
    // per frame (overrides key by key).
    let mut sorted: Vec<&ColmapImage> = ims.iter().collect();
    sorted.sort_by(|a, b| a.name.cmp(&b.name));
    let frames: Vec<Value> = sorted
        .iter()
        .map(|im| {
            let mut f = cams[im.camera_id as usize - 1].1.clone();
            f["file_path"] = json!(format!("images/{}", im.name));
            f["transform_matrix"] = json!(c2w_rows(im));
            if f.get("k2").is_none() && f.get("distortion_params").is_none() {
                f["k2"] = json!(0.0);
            }
            f
        })
        .collect();
    write_json(
        &ns.path().join("transforms.json"),
        &json!({"w": 12, "h": 9, "k2": 0.5, "frames": frames}),
    );

    let (b, t, n) = (plan(bin.path()), plan(txt.path()), plan(ns.path()));
    assert_eq!(b.len(), 16);
    // Name order and every 8th held out (0 and 8).
    let names: Vec<&str> = b.iter().map(|f| f.name.as_str()).collect();
    assert_eq!(names[0], "img_00");
    assert_eq!(names[15], "img_15");
    let held: Vec<usize> = (0..16).filter(|&i| b[i].test).collect();
    assert_eq!(held, vec![0, 8]);
    let models: Vec<LensModel> = b.iter().map(|f| f.distortion.model).collect();
    assert!(models.contains(&LensModel::Fisheye) && models.contains(&LensModel::OpenCv));
    // nerfstudio's names carry their folder.
    let n_renamed: Vec<FramePlan> = n
        .into_iter()
        .map(|mut f| {
            f.name = f.name.trim_start_matches("images/").to_string();
            f
        })
        .collect();
    assert_same(&b, &t, "bin vs txt");
    assert_same(&b, &n_renamed, "bin vs transforms.json");

    // And the capture loads, undistorting the cameras with a lens.
    let cap = dnr_bake::capture::Capture::load(bin.path(), &LoadOptions::default()).unwrap();
    assert_eq!(cap.train.len() + cap.test.len(), 16);
    let undistorted = cap.train.iter().filter(|f| f.undistorted).count();
    assert!(undistorted >= 8, "{undistorted}");
}

#[test]
fn unsupported_models_name_the_camera_and_model_in_both_encodings() {
    let unsupported = [
        ("FULL_OPENCV", 12),
        ("FOV", 5),
        ("SIMPLE_RADIAL_FISHEYE", 4),
        ("RADIAL_FISHEYE", 5),
        ("THIN_PRISM_FISHEYE", 12),
        ("RAD_TAN_THIN_PRISM_FISHEYE", 16),
    ];
    let ims = images(3);
    for (model, n) in unsupported {
        for bin in [true, false] {
            let dir = tempfile::tempdir().unwrap();
            write_images(dir.path(), &ims);
            let mut cams: Vec<ColmapCamera> = cameras().into_iter().map(|(c, _)| c).collect();
            cams[2] = ColmapCamera {
                id: 3,
                model,
                width: 12,
                height: 9,
                params: vec![1.0; n],
            };
            write_model(dir.path(), bin, &cams, &ims);
            let e = CapturePlan::read(dir.path(), &LoadOptions::default()).unwrap_err();
            let msg = e.to_string();
            let file = if bin { "cameras.bin" } else { "cameras.txt" };
            assert!(matches!(e, CaptureError::Colmap { .. }), "{msg}");
            assert!(
                msg.contains(file) && msg.contains("camera 3") && msg.contains(model),
                "{msg}"
            );
            assert!(msg.contains("supported: SIMPLE_PINHOLE"), "{msg}");
        }
    }
    // An id COLMAP does not define.
    let dir = tempfile::tempdir().unwrap();
    write_images(dir.path(), &ims);
    let mut bytes = write::cameras_bin(&[ColmapCamera {
        id: 4,
        model: "PINHOLE",
        width: 12,
        height: 9,
        params: vec![1.0; 4],
    }]);
    bytes[12..16].copy_from_slice(&99i32.to_le_bytes());
    let m = dir.path().join("sparse/0");
    std::fs::create_dir_all(&m).unwrap();
    std::fs::write(m.join("cameras.bin"), bytes).unwrap();
    std::fs::write(m.join("images.bin"), write::images_bin(&ims)).unwrap();
    let msg = CapturePlan::read(dir.path(), &LoadOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        msg.contains("camera 4") && msg.contains("id 99 (unknown)"),
        "{msg}"
    );
}

#[test]
fn broken_models_name_the_file_and_the_place() {
    let cams: Vec<ColmapCamera> = cameras().into_iter().map(|(c, _)| c).collect();
    let ims = images(4);
    let dir = tempfile::tempdir().unwrap();
    write_images(dir.path(), &ims);
    write_model(dir.path(), true, &cams, &ims);
    let images_bin = dir.path().join("sparse/0/images.bin");
    let good = std::fs::read(&images_bin).unwrap();
    // Every truncation is an error naming the file, never a panic.
    for cut in (0..good.len()).step_by(7) {
        std::fs::write(&images_bin, &good[..cut]).unwrap();
        let msg = CapturePlan::read(dir.path(), &LoadOptions::default())
            .unwrap_err()
            .to_string();
        assert!(msg.contains("images.bin"), "{cut}: {msg}");
    }
    // A count that cannot fit is refused before anything is allocated for it.
    let mut lying = good.clone();
    lying[..8].copy_from_slice(&(u64::MAX / 2).to_le_bytes());
    std::fs::write(&images_bin, &lying).unwrap();
    let msg = CapturePlan::read(dir.path(), &LoadOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        msg.contains("images.bin") && msg.contains("cannot fit"),
        "{msg}"
    );
    std::fs::write(&images_bin, &good).unwrap();

    // A missing photograph names the images file, the image and the path tried.
    std::fs::remove_file(dir.path().join("images").join(&ims[2].name)).unwrap();
    let e = CapturePlan::read(dir.path(), &LoadOptions::default()).unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, CaptureError::Frame { .. }), "{msg}");
    assert!(
        msg.contains("images.bin")
            && msg.contains(&format!("image {} ({})", ims[2].id, ims[2].name))
            && msg.contains("not found"),
        "{msg}"
    );

    // A camera id no camera has.
    let mut bad = ims.clone();
    bad[1].camera_id = 42;
    write_images(dir.path(), &bad);
    write_model(dir.path(), true, &cams, &bad);
    let msg = CapturePlan::read(dir.path(), &LoadOptions::default())
        .unwrap_err()
        .to_string();
    assert!(msg.contains("camera 42 is not in"), "{msg}");

    // Text: a bad number names the line.
    let dir = tempfile::tempdir().unwrap();
    write_images(dir.path(), &ims);
    write_model(dir.path(), false, &cams, &ims);
    let p = dir.path().join("sparse/0/cameras.txt");
    let text = std::fs::read_to_string(&p)
        .unwrap()
        .replace("10.5 6.1", "ten 6.1");
    std::fs::write(&p, text).unwrap();
    let msg = CapturePlan::read(dir.path(), &LoadOptions::default())
        .unwrap_err()
        .to_string();
    assert!(msg.contains("cameras.txt: line 3"), "{msg}");
}
