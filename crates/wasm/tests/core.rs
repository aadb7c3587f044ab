//! The bindings' logic on the conformance samples: reports, GLB reassembly, decoding, and the
//! CPU renderer against `dnr-runtime` called directly.

use std::path::{Path, PathBuf};

use dnr_format::container::parse_glb;
use dnr_format::Limits;
use dnr_runtime::camera::Camera;
use dnr_runtime::raster::rasterize;
use dnr_runtime::renderer::Renderer;
use dnr_wasm::core::{glb_from_parts, validate_report, Loaded};

fn sample(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../samples")
        .join(rel)
}

fn read(rel: &str) -> Vec<u8> {
    std::fs::read(sample(rel)).unwrap_or_else(|e| panic!("{rel}: {e}"))
}

fn camera(w: u32, h: u32) -> Camera {
    Camera::look_at([0.3, 0.2, 1.6].into(), [0.0; 3].into(), 45.0, w, h)
}

#[test]
fn reports_codes_and_which_block_rendering() {
    let ok = validate_report(&read("valid/unet_transposed_instance_f16.glb"));
    assert_eq!(ok["errors"], 0);
    assert_eq!(ok["issues"].as_array().unwrap().len(), 0);

    let bad = validate_report(&read("invalid/weights_checksum.glb"));
    assert_eq!(
        bad["blocking"],
        serde_json::json!(["WEIGHTS_CHECKSUM_MISMATCH"])
    );
    assert_eq!(bad["issues"][0]["severity"], "error");
    assert!(bad["issues"][0]["pointer"]
        .as_str()
        .unwrap()
        .starts_with("/extensions/EXT_deferred_neural_rendering/renderers/0"));

    // Interoperability errors and warnings do not keep a reader on the fallback.
    let not_used = validate_report(&read("invalid/extension_not_used.glb"));
    assert_eq!(not_used["errors"], 1);
    assert_eq!(not_used["blocking"], serde_json::json!([]));
    let warn = validate_report(&read("warnings/texcoord_missing.glb"));
    assert_eq!(
        (warn["errors"].as_u64(), warn["warnings"].as_u64()),
        (Some(0), Some(1))
    );
    assert_eq!(warn["blocking"], serde_json::json!([]));

    let garbage = validate_report(b"not a glTF at all");
    assert!(garbage["errors"].as_u64().unwrap() >= 1);
}

#[test]
fn glb_from_parts_reassembles_glb_and_external_gltf() {
    // A GLB split into its JSON and BIN chunk, as a loader holds it.
    let bytes = read("valid/mlp_f32_sh2_4levels.glb");
    let glb = parse_glb(&bytes, &Limits::default()).unwrap();
    let rebuilt = glb_from_parts(glb.json, vec![glb.bin.unwrap().to_vec()]).unwrap();
    let a = Loaded::from_bytes(&bytes).unwrap();
    let b = Loaded::from_bytes(&rebuilt).unwrap();
    let m = camera(40, 30).cam_to_world.to_cols_array();
    assert_eq!(
        a.render(40.0, 40.0, 20.0, 15.0, &m, 40, 30).unwrap(),
        b.render(40.0, 40.0, 20.0, 15.0, &m, 40, 30).unwrap()
    );

    // A .gltf with an external buffer: the loader resolved the file.
    let json = read("valid/unet_depth1_external.gltf");
    let bin = read("valid/unet_depth1_external.bin");
    let rebuilt = glb_from_parts(&json, vec![bin.clone()]).unwrap();
    assert_eq!(validate_report(&rebuilt)["errors"], 0);
    let from_parts = Loaded::from_bytes(&rebuilt).unwrap();
    let from_file = Renderer::from_path(sample("valid/unet_depth1_external.gltf")).unwrap();
    let cam = camera(33, 21);
    assert_eq!(
        from_parts
            .render(
                cam.fx,
                cam.fy,
                cam.cx,
                cam.cy,
                &cam.cam_to_world.to_cols_array(),
                33,
                21
            )
            .unwrap(),
        from_file.render(&cam, 33, 21).unwrap().data
    );

    assert!(glb_from_parts(&json, vec![])
        .unwrap_err()
        .contains("1 buffers"));
    assert!(glb_from_parts(b"{", vec![])
        .unwrap_err()
        .contains("JSON_INVALID"));
}

#[test]
fn describes_and_decodes_the_extension() {
    let bytes = read("valid/scene_multi_primitive.glb");
    let l = Loaded::from_bytes(&bytes).unwrap();
    let d = l.describe();
    let t = &d["textures"];
    assert_eq!(t.as_array().unwrap().len(), 2);
    assert_eq!(t[0]["channels"], 4);
    assert_eq!(
        (t[0]["wrapS"].as_u64(), t[0]["wrapT"].as_u64()),
        (Some(33071), Some(33648))
    );
    assert_eq!(t[1]["viewDependence"]["degree"], 3);
    assert_eq!(t[1]["viewDependence"]["firstChannel"], 3);
    assert_eq!(t[0]["levels"][0]["width"], 16);
    let r = &d["renderers"];
    assert_eq!(r[0]["architecture"], "none");
    assert_eq!(r[1]["architecture"], "mlp");
    assert_eq!(r[1]["hidden"], serde_json::json!([6]));
    assert_eq!(r[1]["tensors"].as_array().unwrap().len(), 4);
    assert_eq!(d["bindings"].as_array().unwrap().len(), 3);
    // Two instances of the two-primitive mesh and one pyramid.
    assert_eq!(d["scenePrimitives"].as_array().unwrap().len(), 5);

    // Levels: f32 and half bits agree exactly; tensors have their shape's size.
    let f32s = l.level_f32(1, 0).unwrap();
    assert_eq!(f32s.len(), 9 * 7 * 19);
    let halves = l.level_f16(1, 0).unwrap();
    for (a, h) in f32s.iter().zip(&halves) {
        assert_eq!(*a, half::f16::from_bits(*h).to_f32());
    }
    assert_eq!(l.tensor(1, "layers.0.weight").unwrap().len(), 6 * 19);
    assert!(l.tensor(1, "layers.9.weight").is_none());
    assert!(l.level_f32(2, 0).is_none());

    let unet = Loaded::from_bytes(&read("valid/unet_upsample_none_f32.glb")).unwrap();
    let u = &unet.describe()["renderers"][0];
    assert_eq!(u["architecture"], "unet");
    assert_eq!(u["widths"], serde_json::json!([4, 8]));
    assert_eq!(u["decoder"], "upsampleConv");
    assert_eq!(u["normalization"], "none");
}

#[test]
fn render_and_shade_equal_the_runtime() {
    let path = sample("valid/scene_multi_primitive.glb");
    let l = Loaded::from_bytes(&std::fs::read(&path).unwrap()).unwrap();
    let r = Renderer::from_path(&path).unwrap();
    let cam = Camera::look_at([0.5, 1.0, 5.0].into(), [0.0; 3].into(), 50.0, 57, 43);
    let m = cam.cam_to_world.to_cols_array();
    let img = l
        .render(cam.fx, cam.fy, cam.cx, cam.cy, &m, 57, 43)
        .unwrap();
    assert_eq!(img, r.render(&cam, 57, 43).unwrap().data);
    assert!(img.chunks_exact(4).filter(|p| p[3] > 0.0).count() > 100);

    let g = rasterize(r.scene(), &cam);
    let uv: Vec<f32> = g.uv.iter().flatten().copied().collect();
    let vd: Vec<f32> = g.view_dir.iter().flatten().copied().collect();
    let shaded = l
        .shade(g.width, g.height, &g.coverage, &g.prim, &uv, &vd)
        .unwrap();
    assert_eq!(shaded, img);

    let err = l
        .shade(2, 2, &[0.0; 4], &[0; 4], &[0.0; 8], &[0.0; 3])
        .unwrap_err();
    assert!(err.contains("12 viewDir"), "{err}");
    assert!(l.render(1.0, 1.0, 0.0, 0.0, &[0.0; 15], 4, 4).is_err());
    assert!(Loaded::from_bytes(&read("invalid/weights_nan.glb")).is_err());
}

#[test]
fn quantised_samples_decode_and_render_as_the_runtime() {
    for rel in [
        "valid/mlp_q8_levels.glb",
        "valid/mlp_q4_levels.glb",
        "valid/unet_int8_weights.glb",
        "valid/mlp_int4_weights.glb",
    ] {
        let path = sample(rel);
        let l = Loaded::from_bytes(&read(rel)).unwrap();
        // Every level as the format decodes it (offset + scale * q for the PNG levels).
        let asset = dnr_format::asset::read_asset(&path).unwrap();
        for (ti, t) in asset.textures.iter().enumerate() {
            for (li, level) in t.levels.iter().enumerate() {
                assert_eq!(
                    l.level_f32(ti, li).unwrap(),
                    &level.data[..],
                    "{rel} texture {ti} level {li}"
                );
            }
        }
        let r = Renderer::from_path(&path).unwrap();
        let cam = camera(40, 30);
        let m = cam.cam_to_world.to_cols_array();
        let img = l
            .render(cam.fx, cam.fy, cam.cx, cam.cy, &m, 40, 30)
            .unwrap();
        assert_eq!(img, r.render(&cam, 40, 30).unwrap().data, "{rel}");
        assert!(
            img.chunks_exact(4).filter(|p| p[3] > 0.0).count() > 50,
            "{rel}"
        );
    }
}
