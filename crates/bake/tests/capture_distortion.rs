//! Lens models: the forward model against OpenCV's own numbers, distort-then-undistort round
//! trips over whole frames for every supported model, and the resampling of a distorted
//! photograph to the pinhole camera with its validity mask.

use dnr_bake::capture::distortion::{Distortion, LensModel};
use dnr_bake::capture::resample::{undistort, Intrinsics, Planes};

/// Points (normalised, z = 1) and their pixels under K = [[500, 0, 320], [0, 510, 240]]
/// from OpenCV 5.1's `cv2.projectPoints` (dist = k1 0.11, k2 -0.23, p1 0.0007, p2 -0.0004,
/// k3 0.05) and `cv2.fisheye.projectPoints` (D = 0.05, -0.01, 0.002, -0.0005).
const POINTS: [[f64; 2]; 4] = [[0.3, -0.2], [-0.55, 0.4], [0.6, 0.45], [-0.1, -0.62]];
const OPENCV_PIXELS: [[f64; 2]; 4] = [
    [471.47442750000005, 137.02611929999998],
    [42.811135253906286, 445.720233984375],
    [619.3326464843749, 469.27634956054686],
    [269.42678699904, -79.18536109807104],
];
const FISHEYE_PIXELS: [[f64; 2]; 4] = [
    [464.80603577852503, 141.53189567060298],
    [74.48088662038728, 422.1305422888763],
    [582.3212344033575, 440.6757443185685],
    [274.69381571397275, -46.51630942483621],
];

#[test]
fn forward_models_match_opencv() {
    let opencv = Distortion {
        k3: 0.05,
        ..Distortion::opencv(0.11, -0.23, 0.0007, -0.0004)
    };
    let fisheye = Distortion::fisheye(0.05, -0.01, 0.002, -0.0005);
    for (d, expected) in [(opencv, OPENCV_PIXELS), (fisheye, FISHEYE_PIXELS)] {
        for (p, e) in POINTS.iter().zip(expected) {
            let (xd, yd) = d.distort(p[0], p[1]);
            let (u, v) = (500.0 * xd + 320.0, 510.0 * yd + 240.0);
            assert!(
                (u - e[0]).abs() < 1e-9 && (v - e[1]).abs() < 1e-9,
                "{:?} {p:?}: ({u}, {v}) vs {e:?}",
                d.model
            );
        }
    }
}

/// Every supported model, with coefficients of the size calibrations give.
fn lenses() -> Vec<(&'static str, Distortion)> {
    vec![
        ("PINHOLE", Distortion::default()),
        ("SIMPLE_RADIAL", Distortion::opencv(-0.08, 0.0, 0.0, 0.0)),
        ("RADIAL", Distortion::opencv(-0.12, 0.03, 0.0, 0.0)),
        ("OPENCV", Distortion::opencv(0.11, -0.23, 0.0007, -0.0004)),
        (
            "OPENCV k3 k4 (nerfstudio)",
            Distortion {
                k3: 0.04,
                k4: -0.01,
                ..Distortion::opencv(-0.2, 0.05, -0.001, 0.0015)
            },
        ),
        (
            "OPENCV_FISHEYE",
            Distortion::fisheye(0.05, -0.01, 0.002, -0.0005),
        ),
    ]
}

#[test]
fn every_model_round_trips_within_a_hundredth_of_a_pixel_over_the_frame() {
    // A 1600 x 1200 frame with a 70 degree horizontal field of view.
    let (w, h) = (1600usize, 1200usize);
    let (fx, fy, cx, cy) = (1140.0, 1142.0, 801.3, 598.7);
    for (name, d) in lenses() {
        let mut worst = 0.0f64;
        for y in (0..=h).step_by(10) {
            for x in (0..=w).step_by(10) {
                // A pixel of the photograph: undistort, distort back.
                let (xd, yd) = ((x as f64 - cx) / fx, (y as f64 - cy) / fy);
                let (xu, yu) = d
                    .undistort(xd, yd)
                    .unwrap_or_else(|| panic!("{name}: ({x}, {y}) did not converge"));
                let (x2, y2) = d.distort(xu, yu);
                let err = ((x2 - xd) * fx).hypot((y2 - yd) * fy);
                // A pixel of the pinhole image: distort, undistort back.
                let (px, py) = d.distort(xd, yd);
                let (bx, by) = d.undistort(px, py).expect("converges");
                let err2 = ((bx - xd) * fx).hypot((by - yd) * fy);
                worst = worst.max(err).max(err2);
            }
        }
        assert!(worst < 0.01, "{name}: worst round trip {worst} px");
        if d.model != LensModel::Pinhole {
            // And the model really moves the corner (the test is not of an identity).
            let (xd, _) = d.distort(-cx / fx, -cy / fy);
            assert!(((xd + cx / fx) * fx).abs() > 1.0, "{name}");
        }
    }
}

/// A smooth pattern in undistorted normalised coordinates.
fn pattern(x: f64, y: f64) -> f64 {
    0.5 + 0.35 * (3.0 * x).sin() * (2.5 * y + 0.3).cos()
}

#[test]
fn undistorting_a_photograph_recovers_the_pinhole_image_with_a_validity_mask() {
    let (w, h) = (200usize, 150usize);
    let k = Intrinsics {
        fx: 150.0,
        fy: 151.0,
        cx: 100.4,
        cy: 74.8,
    };
    for (name, d) in lenses() {
        // The photograph: each pixel centre undistorted (Newton) and the pattern evaluated
        // there; alpha 1.
        let mut rgb = vec![0.0f32; 3 * w * h];
        for y in 0..h {
            for x in 0..w {
                let (xd, yd) = (
                    (x as f64 + 0.5 - k.cx) / k.fx,
                    (y as f64 + 0.5 - k.cy) / k.fy,
                );
                let (xu, yu) = d.undistort(xd, yd).expect("converges");
                let v = pattern(xu, yu) as f32;
                rgb[3 * (y * w + x)..3 * (y * w + x) + 3].copy_from_slice(&[v, 1.0 - v, 0.5]);
            }
        }
        let photo = Planes {
            width: w as u32,
            height: h as u32,
            rgb,
            alpha: vec![1.0; w * h],
            mask: Some(vec![1.0; w * h]),
        };
        let (out, inside) = undistort(&photo, &k, &d);
        let (mut worst, mut valid) = (0.0f64, 0usize);
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let (xn, yn) = (
                    (x as f64 + 0.5 - k.cx) / k.fx,
                    (y as f64 + 0.5 - k.cy) / k.fy,
                );
                // Valid exactly when the sample lies inside the photograph.
                let (xd, yd) = d.distort(xn, yn);
                let (sx, sy) = (k.fx * xd + k.cx - 0.5, k.fy * yd + k.cy - 0.5);
                let expect_inside =
                    sx >= 0.0 && sy >= 0.0 && sx <= (w - 1) as f64 && sy <= (h - 1) as f64;
                assert_eq!(inside[i], expect_inside, "{name}: ({x}, {y})");
                if inside[i] {
                    valid += 1;
                    let e = (out.rgb[3 * i] as f64 - pattern(xn, yn)).abs();
                    worst = worst.max(e);
                    assert!(out.mask.as_ref().unwrap()[i] > 0.9999);
                }
            }
        }
        // Bilinear resampling of a smooth pattern: within a few thousandths.
        assert!(worst < 4e-3, "{name}: worst error {worst}");
        assert!(valid > w * h / 2, "{name}: {valid} valid pixels");
        if name == "OPENCV" {
            // Pincushion corners sample outside the photograph.
            assert!(valid < w * h, "{name}");
        }
    }
}
