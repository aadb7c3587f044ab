//! Image formats and path resolution: extension-less names, 16-bit / gray / RGB PNG, JPEG,
//! EXR (linear -> sRGB), missing alpha, distortion.

mod capture_common;

use capture_common::*;
use dnr_bake::capture::image::{decode_image, linear_to_srgb};
use dnr_bake::capture::{Capture, LoadOptions};
use serde_json::json;

#[test]
fn extensionless_paths_try_known_extensions_including_upper_case() {
    let dir = simple_capture(3, 4);
    std::fs::rename(
        dir.path().join("images/f_1.png"),
        dir.path().join("images/f_1.PNG"),
    )
    .unwrap();
    edit_json(&dir.path().join("transforms.json"), |v| {
        v["frames"][0]["file_path"] = json!("./images/f_0");
        v["frames"][1]["file_path"] = json!("./images/f_1");
    });
    let cap = Capture::load(
        dir.path(),
        &LoadOptions {
            llffhold: 0,
            ..Default::default()
        },
    )
    .unwrap();
    assert!(cap.train[0].image_path.ends_with("images/f_0.png"));
    assert!(cap.train[1].image_path.ends_with("images/f_1.PNG"));
    assert_eq!(cap.train[0].name, "images/f_0");
}

#[test]
fn png_variants_decode_to_unit_range_with_mask() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // 16-bit RGBA.
    let img16 = image::ImageBuffer::<image::Rgba<u16>, _>::from_fn(3, 2, |x, y| {
        image::Rgba([
            x as u16 * 30000,
            y as u16 * 65535,
            1234,
            if x == 0 { 0 } else { 65535 },
        ])
    });
    img16.save(d.join("a16.png")).unwrap();
    let a = decode_image(&d.join("a16.png"), 64).unwrap();
    assert!(a.has_alpha);
    assert_eq!((a.width, a.height), (3, 2));
    assert!((a.rgb[3] - 30000.0 / 65535.0).abs() < 1e-6);
    assert!((a.rgb[3 * 3 + 1] - 1.0).abs() < 1e-6);
    assert!((a.rgb[2] - 1234.0 / 65535.0).abs() < 1e-6);
    assert_eq!(&a.alpha, &[0.0, 1.0, 1.0, 0.0, 1.0, 1.0]);

    // 8-bit gray: replicated, alpha all ones.
    image::GrayImage::from_fn(2, 2, |x, y| image::Luma([(x * 100 + y * 50) as u8]))
        .save(d.join("g.png"))
        .unwrap();
    let g = decode_image(&d.join("g.png"), 64).unwrap();
    assert!(!g.has_alpha && g.alpha.iter().all(|&x| x == 1.0));
    assert_eq!(&g.rgb[9..12], &[150.0 / 255.0; 3]);

    // 8-bit RGB without alpha.
    image::RgbImage::from_fn(2, 1, |x, _| image::Rgb([x as u8 * 255, 7, 9]))
        .save(d.join("rgb.png"))
        .unwrap();
    let r = decode_image(&d.join("rgb.png"), 64).unwrap();
    assert_eq!(
        r.rgb,
        vec![0.0, 7.0 / 255.0, 9.0 / 255.0, 1.0, 7.0 / 255.0, 9.0 / 255.0]
    );
    assert_eq!(r.alpha, vec![1.0, 1.0]);

    // Over the side limit: refused from the header.
    assert!(decode_image(&d.join("a16.png"), 2)
        .unwrap_err()
        .to_string()
        .contains("a16.png"));
}

#[test]
fn jpeg_decodes_close_to_its_source() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("x.jpg");
    image::RgbImage::from_pixel(16, 16, image::Rgb([200, 100, 50]))
        .save(&p)
        .unwrap();
    let j = decode_image(&p, 64).unwrap();
    assert!(!j.has_alpha);
    for px in j.rgb.chunks_exact(3) {
        assert!(
            (px[0] - 200.0 / 255.0).abs() < 0.02
                && (px[1] - 100.0 / 255.0).abs() < 0.02
                && (px[2] - 50.0 / 255.0).abs() < 0.02
        );
    }
}

#[test]
fn exr_is_linear_premultiplied_and_becomes_srgb_straight() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("lin.exr");
    // Pixel 0: opaque 0.18 grey; pixel 1: half-covered, premultiplied 0.5 * 0.5; pixel 2: >1.
    let px = [
        (0.18f32, 0.18f32, 0.18f32, 1.0f32),
        (0.25, 0.0, 0.5, 0.5),
        (4.0, 1.0, 0.0, 1.0),
    ];
    exr::prelude::write_rgba_file(&p, 3, 1, |x, _| px[x]).unwrap();
    let e = decode_image(&p, 64).unwrap();
    assert!(e.has_alpha);
    assert!(
        (e.rgb[0] - linear_to_srgb(0.18)).abs() < 1e-3,
        "{}",
        e.rgb[0]
    );
    assert!((e.rgb[0] - 0.4613).abs() < 2e-3);
    assert!((e.rgb[3] - linear_to_srgb(0.5)).abs() < 1e-3);
    assert!((e.rgb[5] - 1.0).abs() < 1e-3);
    assert_eq!(e.alpha[1], 0.5);
    assert_eq!(e.rgb[6], 1.0);

    // And inside a capture, found without its extension.
    let cap_dir = simple_capture(2, 3);
    std::fs::copy(&p, cap_dir.path().join("images/lin.exr")).unwrap();
    edit_json(&cap_dir.path().join("transforms.json"), |v| {
        v["frames"][1]["file_path"] = json!("images/lin")
    });
    // Size mismatch with the other 3x3 frames is fine: camera_angle_x takes each image's size.
    let cap = Capture::load(
        cap_dir.path(),
        &LoadOptions {
            llffhold: 0,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!((cap.train[1].width(), cap.train[1].height()), (3, 1));
    assert!(cap.train[1].image_path.ends_with("images/lin.exr"));
}

#[test]
fn distortion_is_parsed_warned_about_and_undistorted() {
    let dir = simple_capture(2, 16);
    edit_json(&dir.path().join("transforms.json"), |v| {
        v["k1"] = json!(0.2);
        v["p2"] = json!(0.01);
        v["frames"][1]["k1"] = json!(0.0);
        v["frames"][1]["p2"] = json!(0.0);
    });
    let cap = Capture::load(
        dir.path(),
        &LoadOptions {
            llffhold: 0,
            ..Default::default()
        },
    )
    .unwrap();
    let f0 = &cap.train[0];
    assert_eq!((f0.distortion.k1, f0.distortion.p2), (0.2, 0.01));
    assert!(f0.undistorted && !cap.train[1].undistorted);
    assert!(
        cap.warnings.iter().any(|w| w.contains("transforms.json")
            && w.contains("1 frame(s)")
            && w.contains("distortion")),
        "{:?}",
        cap.warnings
    );
    // The resampled image differs from the raw one; the centre pixel barely moves.
    let raw = decode_image(&f0.image_path, 64).unwrap();
    assert_ne!(raw.rgb, f0.rgb);
    assert_eq!(f0.rgb.len(), raw.rgb.len());

    let cap = Capture::load(
        dir.path(),
        &LoadOptions {
            llffhold: 0,
            undistort: false,
            ..Default::default()
        },
    )
    .unwrap();
    assert!(!cap.train[0].undistorted);
    assert_eq!(cap.train[0].rgb, raw.rgb);
    assert!(
        cap.warnings.iter().any(|w| w.contains("not modelled")),
        "{:?}",
        cap.warnings
    );
}
