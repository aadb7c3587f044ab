//! Golden test of the `none` architecture: a camera-facing quad with a known two-level
//! texture; every pixel's expected colour is computed here from the spec's bilinear formula
//! (in f64, independently of the runtime's sampler).

mod renderer_common;

use dnr_format::WrapMode;
use dnr_runtime::renderer::Renderer;
use renderer_common::*;

const W: usize = 64;
const H: usize = 64;

/// Spec wrap of an integer tap index.
fn wrap(i: i64, n: i64, mode: WrapMode) -> usize {
    (match mode {
        WrapMode::Repeat => i.rem_euclid(n),
        WrapMode::ClampToEdge => i.clamp(0, n - 1),
        WrapMode::MirroredRepeat => {
            let m = i.rem_euclid(2 * n);
            if m < n {
                m
            } else {
                2 * n - 1 - m
            }
        }
    }) as usize
}

/// Spec bilinear sample of channel `c` of a level at `(u, v)`.
fn bilinear(l: &dnr_format::TextureLevel, mode: WrapMode, u: f64, v: f64, c: usize) -> f64 {
    let (w, h) = (l.width as i64, l.height as i64);
    let x = u * w as f64 - 0.5;
    let y = v * h as f64 - 0.5;
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let (x0, y0) = (x0 as i64, y0 as i64);
    let t = |xi: i64, yi: i64| {
        let (xi, yi) = (wrap(xi, w, mode), wrap(yi, h, mode));
        l.data[(yi * w as usize + xi) * l.channels as usize + c] as f64
    };
    (1.0 - fx) * (1.0 - fy) * t(x0, y0)
        + fx * (1.0 - fy) * t(x0 + 1, y0)
        + (1.0 - fx) * fy * t(x0, y0 + 1)
        + fx * fy * t(x0 + 1, y0 + 1)
}

fn golden(mode: WrapMode) {
    // Values on a 1/8 grid (exact in f16), some outside [0, 1] to exercise the clamp.
    let l0 = level(4, 4, 3, |x, y, c| {
        ((x * 3 + y * 5 + c * 7) % 11) as f32 / 8.0 - 0.25
    });
    let l1 = level(2, 2, 3, |x, y, c| {
        ((x + 2 * y + c) % 3) as f32 / 8.0 - 0.125
    });
    let mut s = Scene::new();
    s.b.add_neural_texture(texture(vec![l0.clone(), l1.clone()], mode, None));
    s.b.add_renderer(none_renderer(3));
    let m = s.material(0, 0);
    s.object(vec![quad(0.0, 0.0, 1.0, 0.0, Some(m))], [0.0; 3]);
    let renderer = Renderer::from_asset(&s.build()).expect("renderer");

    // Eye at z = 2, f = 32 px on a 64 x 64 frame: 1 world unit is 16 pixels on the z = 0
    // plane, so the quad covers pixels 16..48 in both directions and pixel centre px maps
    // to u = (px + 0.5 - 16) / 32 exactly.
    let cam = camera_down_z([0.0, 0.0, 2.0], 32.0, W as u32, H as u32);
    let img = renderer.render(&cam, W as u32, H as u32).expect("render");
    assert_eq!((img.width, img.height, img.data.len()), (W, H, W * H * 4));

    let mut clamped = 0;
    let mut max_err = 0.0f64;
    for y in 0..H {
        for x in 0..W {
            let got = px(&img, x, y);
            if !(16..48).contains(&x) || !(16..48).contains(&y) {
                assert_eq!(got, [0.0; 4], "background pixel ({x}, {y})");
                continue;
            }
            let u = (x as f64 + 0.5 - 16.0) / 32.0;
            let v = (y as f64 + 0.5 - 16.0) / 32.0;
            for (c, &g) in got[..3].iter().enumerate() {
                let f = bilinear(&l0, mode, u, v, c) + bilinear(&l1, mode, u, v, c);
                if !(0.0..=1.0).contains(&f) {
                    clamped += 1;
                }
                let want = f.clamp(0.0, 1.0);
                let err = (g as f64 - want).abs();
                max_err = max_err.max(err);
                assert!(
                    err <= 1e-6,
                    "pixel ({x}, {y}) channel {c}: got {g}, want {want}"
                );
            }
            assert_eq!(got[3], 1.0, "alpha at ({x}, {y})");
        }
    }
    // The texture really exercises the clamp and the interpolation.
    assert!(clamped > 100, "only {clamped} clamped values");
    assert!(max_err <= 1e-6);
}

#[test]
fn none_reproduces_channels_0_to_2_repeat() {
    golden(WrapMode::Repeat);
}

#[test]
fn none_reproduces_channels_0_to_2_clamp() {
    golden(WrapMode::ClampToEdge);
}

#[test]
fn none_reproduces_channels_0_to_2_mirrored() {
    golden(WrapMode::MirroredRepeat);
}

#[test]
fn render_at_another_size_scales_the_intrinsics() {
    let mut s = Scene::new();
    s.b.add_neural_texture(solid(3, [0.25, 0.5, 0.75]));
    s.b.add_renderer(none_renderer(3));
    let m = s.material(0, 0);
    s.object(vec![quad(0.0, 0.0, 1.0, 0.0, Some(m))], [0.0; 3]);
    let renderer = Renderer::from_asset(&s.build()).unwrap();
    let cam = camera_down_z([0.0, 0.0, 2.0], 32.0, 64, 64);
    // Half the size: the quad covers pixels 8..24.
    let img = renderer.render(&cam, 32, 32).unwrap();
    let covered: Vec<(usize, usize)> = (0..32)
        .flat_map(|y| (0..32).map(move |x| (x, y)))
        .filter(|&(x, y)| px(&img, x, y)[3] > 0.0)
        .collect();
    assert_eq!(covered.len(), 16 * 16);
    assert!(covered
        .iter()
        .all(|&(x, y)| (8..24).contains(&x) && (8..24).contains(&y)));
    assert_eq!(px(&img, 10, 10), [0.25, 0.5, 0.75, 1.0]);
}

#[test]
fn too_large_frames_are_refused() {
    let mut s = Scene::new();
    s.b.add_neural_texture(solid(3, [1.0, 0.0, 0.0]));
    s.b.add_renderer(none_renderer(3));
    let m = s.material(0, 0);
    s.object(vec![quad(0.0, 0.0, 1.0, 0.0, Some(m))], [0.0; 3]);
    let renderer = Renderer::from_asset(&s.build()).unwrap();
    let cam = camera_down_z([0.0, 0.0, 2.0], 32.0, 64, 64);
    let e = renderer.render(&cam, 100_000, 100_000).unwrap_err();
    assert!(
        matches!(
            e,
            dnr_runtime::renderer::RendererError::FrameTooLarge { .. }
        ),
        "{e}"
    );
    let empty = renderer.render(&cam, 0, 7).unwrap();
    assert!(empty.is_empty());
}
