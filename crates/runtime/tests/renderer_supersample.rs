//! Supersampled renderers (spec "Supersampled Features"): the feature of a pixel is the mean
//! of its `s x s` subsamples' features, computed here from an `s = 1` render of the same
//! asset at `s` times the size; ownership stays the pixel centre's.

mod renderer_common;

use dnr_format::WrapMode;
use dnr_runtime::gbuffer::GBuffer;
use dnr_runtime::renderer::{Renderer, RendererError};
use renderer_common::*;

/// A quad with a fine-grained texture in [0, 1] (so the `none` renderer's clamp is the
/// identity and its colour is the feature), bound to a `none` renderer with `supersample`.
fn asset(s: Option<u32>, second: bool) -> dnr_format::Asset {
    let l0 = level(16, 16, 3, |x, y, c| {
        ((x * 5 + y * 3 + c * 7) % 9) as f32 / 8.0
    });
    let mut sc = Scene::new();
    sc.b.add_neural_texture(texture(vec![l0], WrapMode::Repeat, None));
    let mut r = none_renderer(3);
    r.renderer.supersample = s;
    sc.b.add_renderer(r);
    let m = sc.material(0, 0);
    // Off-centre and rotated by the camera's aspect so its edges cross pixels anywhere.
    sc.object(vec![quad(0.13, -0.07, 0.61, 0.0, Some(m))], [0.0; 3]);
    if second {
        // A second renderer (s = 1) drawing a quad in front of part of the first.
        sc.b.add_neural_texture(solid(3, [0.25, 0.5, 0.75]));
        sc.b.add_renderer(none_renderer(3));
        let m2 = sc.material(1, 1);
        sc.object(vec![quad(0.5, 0.4, 0.3, 0.2, Some(m2))], [0.0; 3]);
    }
    sc.build()
}

#[test]
fn pixel_feature_is_the_mean_of_the_subsample_features() {
    for s in [2u32, 3] {
        let (w, h) = (37u32, 29u32);
        let cam = camera_down_z([0.0, 0.0, 3.0], 40.0, w, h);
        let ss = Renderer::from_asset(&asset(Some(s), true)).unwrap();
        assert_eq!(ss.supersample_factors(), vec![s]);
        let img = ss.render(&cam, w, h).unwrap();
        // The same asset without supersampling, drawn at s times the size: its pixels are
        // the subsamples, colour = feature where renderer 0 owns them.
        let plain = Renderer::from_asset(&asset(None, true)).unwrap();
        let fine_cam = dnr_runtime::supersample::subsample_camera(&cam, s);
        let fine = plain.render(&fine_cam, w * s, h * s).unwrap();
        let centre = plain.render(&cam, w, h).unwrap();
        // Which subsamples renderer 0 owns: those the second quad's colour does not show.
        let owned_by_0 = |p: [f32; 4]| {
            let second = [0.25, 0.5, 0.75]
                .iter()
                .zip(&p)
                .all(|(a, b)| (a - b).abs() < 1e-5);
            p[3] > 0.0 && !second
        };
        let mut checked = 0;
        let mut partial = 0;
        for y in 0..h as usize {
            for x in 0..w as usize {
                let c = px(&centre, x, y);
                let got = px(&img, x, y);
                if !owned_by_0(c) {
                    // Not renderer 0's pixel: what the s = 1 render shows (renderer 1's own
                    // pixels, or background), untouched by supersampling.
                    assert_eq!(got, c, "pixel ({x}, {y}) s={s}");
                    continue;
                }
                let mut want = [0.0f64; 3];
                let mut n = 0;
                for j in 0..s as usize {
                    for i in 0..s as usize {
                        let q = px(&fine, s as usize * x + i, s as usize * y + j);
                        if owned_by_0(q) {
                            n += 1;
                            for k in 0..3 {
                                want[k] += q[k] as f64;
                            }
                        }
                    }
                }
                if n < (s * s) as usize {
                    partial += 1;
                }
                for k in 0..3 {
                    let want = want[k] / (s * s) as f64;
                    assert!(
                        (got[k] as f64 - want).abs() < 1e-5,
                        "pixel ({x}, {y}) channel {k} s={s}: {} vs {want}",
                        got[k]
                    );
                }
                assert_eq!(got[3], 1.0);
                checked += 1;
            }
        }
        assert!(
            checked > 200 && partial > 20,
            "{checked} pixels, {partial} partial"
        );
    }
}

#[test]
fn shade_needs_the_subsample_gbuffer() {
    let r = Renderer::from_asset(&asset(Some(2), false)).unwrap();
    let g = GBuffer::new(8, 8);
    match r.shade(&g) {
        Err(RendererError::GBuffer(m)) => assert!(m.contains("16x16"), "{m}"),
        other => panic!("expected a G-buffer error, got {other:?}"),
    }
    // With it, an empty frame shades to nothing.
    let img = r.shade_supersampled(&g, &[GBuffer::new(16, 16)]).unwrap();
    assert!(img.data.iter().all(|&v| v == 0.0));
    // Without supersampling no subsample buffer is needed.
    let plain = Renderer::from_asset(&asset(None, false)).unwrap();
    assert!(plain.supersample_factors().is_empty());
    assert!(plain.shade(&g).is_ok());
}

#[test]
fn supersample_outside_the_range_is_refused() {
    let mut sc = Scene::new();
    sc.b.add_neural_texture(solid(3, [0.5; 3]));
    let mut r = none_renderer(3);
    r.renderer.supersample = Some(5);
    sc.b.add_renderer(r);
    let m = sc.material(0, 0);
    sc.object(vec![quad(0.0, 0.0, 0.5, 0.0, Some(m))], [0.0; 3]);
    let err = sc.b.build().unwrap_err().to_string();
    assert!(err.contains("supersample is 5"), "{err}");
}
