//! Several materials and renderers in one frame (spec "Compositing Several Renderers").

mod renderer_common;

use dnr_runtime::gbuffer::GBuffer;
use dnr_runtime::raster::rasterize;
use dnr_runtime::renderer::{Renderer, RendererError};
use renderer_common::*;

/// `(tanh(b) + 1) / 2` in f64.
fn unit(b: f32) -> f32 {
    (((b as f64).tanh() + 1.0) / 2.0) as f32
}

const B1: [f32; 4] = [0.5, -1.0, 0.25, -0.5]; // renderer 1 (unet, 4 outputs)
const B2: [f32; 4] = [-0.75, 0.3, 1.0, 0.2]; // renderer 2 (unet, 4 outputs)
const B3: [f32; 4] = [0.1, 0.2, -0.3, 0.6]; // renderer 3 (mlp, 4 outputs)
const B4: [f32; 4] = [2.0, 2.0, 2.0, 3.0]; // renderer 4 (unet): never on screen

/// Eye at z = 4, f = 32 on 64 x 64: 8 pixels per unit on z = 0, centre at pixel 32.
/// World (X, Y) on z = 0 is pixel (32 + 8 X, 32 - 8 Y).
fn scene() -> (Renderer, dnr_runtime::camera::Camera) {
    let mut s = Scene::new();
    // Textures: red, green, and three more for the network renderers (content irrelevant).
    let red = s.b.add_neural_texture(solid(3, [1.0, 0.0, 0.0]));
    let green = s.b.add_neural_texture(solid(3, [0.0, 1.0, 0.0]));
    let grey = s.b.add_neural_texture(solid(3, [0.5, 0.5, 0.5]));
    let r0 = s.b.add_renderer(none_renderer(3));
    let r1 = s.b.add_renderer(unet_constant(3, B1));
    let r2 = s.b.add_renderer(unet_constant(3, B2));
    let r3 = s.b.add_renderer(mlp_constant(3, &B3));
    let r4 = s.b.add_renderer(unet_constant(3, B4));
    // Two materials sharing renderer 0 with different textures.
    let ma = s.material(red, r0);
    let mb = s.material(green, r0);
    let mc = s.material(grey, r1);
    let md = s.material(grey, r2);
    let mf = s.material(grey, r3);
    let mg = s.material(grey, r4);
    s.object(vec![quad(-1.5, 0.0, 1.0, 0.0, Some(ma))], [0.0; 3]); // x 12..28, y 24..40
    s.object(vec![quad(1.5, 0.0, 1.0, 0.0, Some(mb))], [0.0; 3]); // x 36..52, y 24..40
    s.object(vec![quad(0.0, 2.0, 0.5, 0.0, Some(mc))], [0.0; 3]); // x 28..36, y 12..20
    s.object(vec![quad(0.0, -2.0, 0.5, 0.0, Some(md))], [0.0; 3]); // x 28..36, y 44..52
    s.object(vec![quad(0.0, 0.0, 0.5, 0.0, Some(mf))], [0.0; 3]); // x 28..36, y 28..36
                                                                  // A core-material quad (no material) in front of the middle of the red quad.
    s.object(vec![quad(-1.5, 0.0, 0.25, 1.0, None)], [0.0; 3]);
    // Renderer 4's only surface is behind the camera.
    s.object(vec![quad(0.0, 0.0, 1.0, 10.0, Some(mg))], [0.0; 3]);
    let renderer = Renderer::from_asset(&s.build()).expect("renderer");
    (renderer, camera_down_z([0.0, 0.0, 4.0], 32.0, 64, 64))
}

#[test]
fn each_pixel_shows_its_own_renderer() {
    let (renderer, cam) = scene();
    let img = renderer.render(&cam, 64, 64).unwrap();
    let tol = 2e-6;
    // Materials sharing the `none` renderer keep their own textures.
    assert_close(px(&img, 14, 26), [1.0, 0.0, 0.0, 1.0], tol, "red quad");
    assert_close(px(&img, 50, 38), [0.0, 1.0, 0.0, 1.0], tol, "green quad");
    // The core quad (z = 1: 32/3 px per unit, pixels 13.3..18.7 around (16, 32)) shows
    // nothing and hides the red quad behind it.
    assert_eq!(px(&img, 16, 32), [0.0; 4], "core material pixel");
    assert_eq!(px(&img, 17, 30), [0.0; 4], "core material pixel");
    // U-Net pixels: its own colour and alpha, other renderers discarded.
    let c1 = [unit(B1[0]), unit(B1[1]), unit(B1[2]), unit(B1[3])];
    let c2 = [unit(B2[0]), unit(B2[1]), unit(B2[2]), unit(B2[3])];
    assert_close(px(&img, 31, 15), c1, tol, "unet 1 pixel");
    assert_close(px(&img, 31, 48), c2, tol, "unet 2 pixel");
    // MLP with 4 outputs: alpha = coverage * (t3 + 1) / 2.
    let c3 = [unit(B3[0]), unit(B3[1]), unit(B3[2]), unit(B3[3])];
    assert_close(px(&img, 31, 31), c3, tol, "mlp pixel");
    // Background: the two visible U-Nets composited source-over in index order; the MLP
    // and `none` add nothing; renderer 4 covers no pixel and is not evaluated.
    let (a1, a2) = (c1[3] as f64, c2[3] as f64);
    let a = a2 + (1.0 - a2) * a1;
    let mut want = [0.0f32; 4];
    for k in 0..3 {
        let q = a2 * c2[k] as f64 + (1.0 - a2) * a1 * c1[k] as f64;
        want[k] = (q / a) as f32;
    }
    want[3] = a as f32;
    for (x, y) in [(0, 0), (63, 63), (5, 40), (32, 60)] {
        assert_close(px(&img, x, y), want, 1e-5, "background pixel");
    }
}

#[test]
fn shade_of_the_rasterised_gbuffer_equals_render() {
    let (renderer, cam) = scene();
    let g = rasterize(renderer.scene(), &cam);
    let shaded = renderer.shade(&g).unwrap();
    let rendered = renderer.render(&cam, 64, 64).unwrap();
    assert_eq!(shaded, rendered);
    assert_eq!(renderer.renderer_count(), 5);
    assert_eq!(renderer.architecture(1), Some("unet"));
    assert_eq!(renderer.architecture(3), Some("mlp"));
    assert_eq!(renderer.architecture(9), None);
}

#[test]
fn background_without_four_channel_unets_is_transparent() {
    let mut s = Scene::new();
    let t = s.b.add_neural_texture(solid(3, [0.2, 0.4, 0.6]));
    let r0 = s.b.add_renderer(none_renderer(3));
    let r1 = s.b.add_renderer(mlp_constant(3, &[0.0, 0.0, 0.0, 5.0]));
    let m0 = s.material(t, r0);
    let m1 = s.material(t, r1);
    s.object(
        vec![
            quad(-1.0, 0.0, 0.5, 0.0, Some(m0)),
            quad(1.0, 0.0, 0.5, 0.0, Some(m1)),
        ],
        [0.0; 3],
    );
    let renderer = Renderer::from_asset(&s.build()).unwrap();
    let img = renderer
        .render(&camera_down_z([0.0, 0.0, 4.0], 32.0, 64, 64), 64, 64)
        .unwrap();
    let covered = img.data.chunks_exact(4).filter(|p| p[3] > 0.0).count();
    assert_eq!(covered, 2 * 8 * 8);
    assert_eq!(px(&img, 0, 0), [0.0; 4]);
    assert_close(
        px(&img, 41, 31),
        [0.5, 0.5, 0.5, unit(5.0)],
        1e-6,
        "mlp pixel",
    );
}

#[test]
fn bad_gbuffers_are_errors_not_panics() {
    let (renderer, _) = scene();
    let mut g = GBuffer::new(4, 4);
    g.coverage[5] = 1.0;
    g.prim[5] = 1000; // no such primitive
    assert!(matches!(renderer.shade(&g), Err(RendererError::GBuffer(_))));
    g.prim[5] = dnr_runtime::gbuffer::NONE;
    assert!(matches!(renderer.shade(&g), Err(RendererError::GBuffer(_))));
    let mut short = GBuffer::new(4, 4);
    short.uv.pop();
    assert!(matches!(
        renderer.shade(&short),
        Err(RendererError::GBuffer(_))
    ));
    // Non-finite uv and view direction at a covered pixel: F = 0, no NaN in the output.
    let mut g = GBuffer::new(2, 1);
    g.coverage[0] = 1.0;
    g.prim[0] = 0;
    g.uv[0] = [f32::NAN, 0.5];
    g.view_dir[0] = [f32::INFINITY, 0.0, 0.0];
    let img = renderer.shade(&g).unwrap();
    assert_eq!(px(&img, 0, 0), [0.0, 0.0, 0.0, 1.0]);
}

#[test]
fn renderer_is_shareable_between_threads() {
    fn assert_send_sync<T: Send + Sync>() {}
    assert_send_sync::<Renderer>();
    let (renderer, cam) = scene();
    let images: Vec<_> = std::thread::scope(|s| {
        let hs: Vec<_> = (0..2)
            .map(|_| s.spawn(|| renderer.render(&cam, 64, 64).unwrap()))
            .collect();
        hs.into_iter().map(|h| h.join().unwrap()).collect()
    });
    assert_eq!(images[0], images[1]);
}
