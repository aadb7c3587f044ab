//! Pixels belong to the binding of their visible primitive
//! (`meshes[m].primitives[p].extensions.EXT_deferred_neural_rendering`), never to its
//! fallback material.

mod renderer_common;

use dnr_format::{read_asset_from_slice, validate_slice, Asset, Limits};
use dnr_runtime::raster::rasterize;
use dnr_runtime::renderer::{Renderer, RendererError};
use dnr_runtime::scene::from_gltf_slice;
use gltf::json::Index;
use renderer_common::*;

/// `(tanh(b) + 1) / 2` in f64.
fn unit(b: f32) -> f32 {
    (((b as f64).tanh() + 1.0) / 2.0) as f32
}

const B1: [f32; 3] = [0.6, -0.4, 0.2]; // renderer 1 (mlp, 3 outputs)

/// Two quads in one mesh: primitive 0 (left, x 12..28) bound to (red, `none`), primitive 1
/// (right, x 36..52) bound to (grey, `mlp`); then both are given fallback material 0.
fn shared_fallback() -> Asset {
    let mut s = Scene::new();
    let red = s.b.add_neural_texture(solid(3, [1.0, 0.0, 0.0]));
    let grey = s.b.add_neural_texture(solid(3, [0.5, 0.5, 0.5]));
    let r0 = s.b.add_renderer(none_renderer(3));
    let r1 = s.b.add_renderer(mlp_constant(3, &B1));
    let ma = s.material(red, r0);
    let mb = s.material(grey, r1);
    s.object(
        vec![
            quad(-1.5, 0.0, 1.0, 0.0, Some(ma)),
            quad(1.5, 0.0, 1.0, 0.0, Some(mb)),
        ],
        [0.0; 3],
    );
    let mut asset = s.build();
    // The builder gives each binding its own fallback; point primitive 1 at material 0 too
    // (its binding stays renderer 1).
    let prims = &mut asset.container.root.meshes[0].primitives;
    assert_eq!(prims[1].material, Some(Index::new(1)));
    prims[1].material = Some(Index::new(0));
    let bytes = asset.container.to_glb().expect("glb");
    let report = validate_slice(&bytes, None, &Limits::default());
    assert!(report.issues.is_empty(), "{report:#?}");
    read_asset_from_slice(&bytes).expect("asset reads")
}

#[test]
fn primitives_sharing_a_fallback_render_with_their_own_renderers() {
    let asset = shared_fallback();
    let glb = asset.container.to_glb().unwrap();
    let scene = from_gltf_slice(&glb).unwrap();
    let got: Vec<_> = scene
        .primitives
        .iter()
        .map(|p| (p.material, p.neural))
        .collect();
    assert_eq!(got, [(Some(0), Some((0, 0))), (Some(0), Some((1, 1)))]);

    let renderer = Renderer::from_asset(&asset).unwrap();
    let cam = camera_down_z([0.0, 0.0, 4.0], 32.0, 64, 64);
    let img = renderer.render(&cam, 64, 64).unwrap();
    let tol = 2e-6;
    assert_close(
        px(&img, 20, 32),
        [1.0, 0.0, 0.0, 1.0],
        tol,
        "left: none, red",
    );
    let mlp = [unit(B1[0]), unit(B1[1]), unit(B1[2]), 1.0];
    assert_close(px(&img, 44, 32), mlp, tol, "right: mlp");
    assert_close(px(&img, 32, 32), [0.0; 4], 0.0, "gap between the quads");
    assert_close(px(&img, 20, 10), [0.0; 4], 0.0, "background");
}

#[test]
fn from_scene_reads_each_primitives_binding() {
    let asset = shared_fallback();
    let glb = asset.container.to_glb().unwrap();
    let cam = camera_down_z([0.0, 0.0, 4.0], 32.0, 64, 64);
    let tol = 2e-6;
    let mlp = [unit(B1[0]), unit(B1[1]), unit(B1[2]), 1.0];

    // Swapped bindings in the scene win over the asset's.
    let mut scene = from_gltf_slice(&glb).unwrap();
    scene.primitives[0].neural = Some((1, 1));
    scene.primitives[1].neural = Some((0, 0));
    let img = Renderer::from_scene(scene, &asset)
        .unwrap()
        .render(&cam, 64, 64)
        .unwrap();
    assert_close(px(&img, 20, 32), mlp, tol, "left now mlp");
    assert_close(
        px(&img, 44, 32),
        [1.0, 0.0, 0.0, 1.0],
        tol,
        "right now none",
    );

    // Without `neural`, `source` finds the asset's binding; without both, core.
    let mut scene = from_gltf_slice(&glb).unwrap();
    scene.primitives[0].neural = None;
    scene.primitives[1].neural = None;
    scene.primitives[1].source = None;
    let r = Renderer::from_scene(scene.clone(), &asset).unwrap();
    let img = r.render(&cam, 64, 64).unwrap();
    assert_close(
        px(&img, 20, 32),
        [1.0, 0.0, 0.0, 1.0],
        tol,
        "left from source",
    );
    assert_close(px(&img, 44, 32), [0.0; 4], 0.0, "right is core");
    // Core pixels stay covered in the G-buffer but get nothing from the neural layer.
    let g = rasterize(r.scene(), &cam);
    assert_eq!(g.coverage[32 * 64 + 44], 1.0);
}

#[test]
fn bad_bindings_name_the_primitive() {
    let asset = shared_fallback();
    let glb = asset.container.to_glb().unwrap();
    let cases = [
        ((0, 2), "renderer 2 does not exist"),
        ((2, 0), "neural texture 2 does not exist"),
    ];
    for ((t, r), want) in cases {
        let mut scene = from_gltf_slice(&glb).unwrap();
        scene.primitives[1].neural = Some((t, r));
        let err = Renderer::from_scene(scene, &asset).unwrap_err();
        match &err {
            RendererError::Binding {
                primitive,
                gltf,
                reason,
            } => {
                assert_eq!((*primitive, *gltf), (1, Some((0, 1))));
                assert_eq!(reason, want);
            }
            other => panic!("binding ({t}, {r}): expected a Binding error, got {other:?}"),
        }
        let text = err.to_string();
        assert!(text.contains("mesh 0 primitive 1"), "{text}");
    }
}

#[test]
fn texture_and_renderer_channels_must_agree() {
    let mut s = Scene::new();
    let t3 = s.b.add_neural_texture(solid(3, [1.0, 0.0, 0.0]));
    let t4 = s.b.add_neural_texture(solid(4, [0.0, 1.0, 0.0]));
    let r3 = s.b.add_renderer(none_renderer(3));
    let _r4 = s.b.add_renderer(none_renderer(4));
    let m = s.material(t3, r3);
    s.object(vec![quad(0.0, 0.0, 1.0, 0.0, Some(m))], [0.0; 3]);
    let asset = s.build();
    let mut scene = from_gltf_slice(&asset.container.to_glb().unwrap()).unwrap();
    scene.primitives[0].neural = Some((t4 as u32, r3 as u32));
    scene.primitives[0].source = None;
    let err = Renderer::from_scene(scene, &asset).unwrap_err();
    assert!(
        matches!(
            &err,
            RendererError::Binding { primitive: 0, gltf: None, reason }
                if reason.contains("has 4 channels, renderer 0 takes 3")
        ),
        "{err:?}"
    );
}
