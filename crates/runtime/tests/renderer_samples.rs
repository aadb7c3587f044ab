//! Every valid conformance sample (and a built asset of each architecture) renders to a
//! finite image that shows the object; invalid samples give errors, never panics.

mod renderer_common;

use std::path::{Path, PathBuf};

use dnr_format::model::{Decoder, Normalization, ViewDependence};
use dnr_format::{RendererDesc, TensorF32, WrapMode};
use dnr_runtime::camera::Camera;
use dnr_runtime::renderer::{Renderer, RgbaImage};
use glam::Vec3;
use rand::{Rng, SeedableRng};
use renderer_common::*;

fn samples(kind: &str) -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../samples")
        .join(kind);
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .map(|rd| rd.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    files.retain(|p| matches!(p.extension().and_then(|e| e.to_str()), Some("glb" | "gltf")));
    files.sort();
    files
}

/// Cameras around the scene's bounds: one in front (+Z), one oblique from above.
fn cameras(r: &Renderer) -> Vec<Camera> {
    let (lo, hi) = r.scene().world_bounds().expect("the scene has geometry");
    let centre = (lo + hi) * 0.5;
    let radius = ((hi - lo).length() * 0.5).max(1e-3);
    let dist = 2.5 * radius;
    vec![
        Camera::look_at(centre + Vec3::new(0.0, 0.0, dist), centre, 45.0, 48, 40),
        Camera::look_at(
            centre + Vec3::new(0.6, 0.5, 0.62).normalize() * dist,
            centre,
            45.0,
            48,
            40,
        ),
        Camera::look_at(
            centre + Vec3::new(-0.3, -0.4, -0.87).normalize() * dist,
            centre,
            45.0,
            48,
            40,
        ),
    ]
}

/// Asserts the image is well formed and returns the number of pixels with alpha > 0.
fn check_image(img: &RgbaImage, what: &str) -> usize {
    assert_eq!(img.data.len(), img.width * img.height * 4, "{what}");
    assert!(
        img.data
            .iter()
            .all(|v| v.is_finite() && (0.0..=1.0).contains(v)),
        "{what}: value outside [0, 1]"
    );
    img.data.chunks_exact(4).filter(|p| p[3] > 0.0).count()
}

fn check_renders(r: &Renderer, what: &str) {
    let mut shown = 0;
    for (i, cam) in cameras(r).iter().enumerate() {
        let img = r
            .render(cam, cam.width, cam.height)
            .unwrap_or_else(|e| panic!("{what} camera {i}: {e}"));
        shown += check_image(&img, what);
        // Deterministic.
        assert_eq!(
            img,
            r.render(cam, cam.width, cam.height).unwrap(),
            "{what} camera {i}"
        );
    }
    assert!(shown > 0, "{what}: no camera shows the object");
}

#[test]
fn every_valid_sample_renders() {
    let files = samples("valid");
    let mut failures = Vec::new();
    for path in &files {
        let what = path.display().to_string();
        let r = match Renderer::from_path(path) {
            Ok(r) => r,
            Err(e) => {
                failures.push(format!("{what}: {e}"));
                continue;
            }
        };
        assert!(r.renderer_count() > 0, "{what}");
        check_renders(&r, &what);
        // from_bytes agrees for self-contained files.
        if path.extension().and_then(|e| e.to_str()) == Some("glb") {
            let bytes = std::fs::read(path).unwrap();
            let r2 = Renderer::from_bytes(&bytes).unwrap();
            let cam = &cameras(&r)[0];
            assert_eq!(
                r.render(cam, 32, 24).unwrap(),
                r2.render(cam, 32, 24).unwrap(),
                "{what}"
            );
        }
    }
    assert!(
        failures.is_empty(),
        "{} of {} valid samples failed to load:\n{}",
        failures.len(),
        files.len(),
        failures.join("\n")
    );
    eprintln!("rendered {} valid samples", files.len());
}

#[test]
fn invalid_samples_never_panic() {
    for path in samples("invalid") {
        let what = path.display().to_string();
        let loaded = std::panic::catch_unwind(|| Renderer::from_path(&path));
        let Ok(result) = loaded else {
            panic!("{what}: loading panicked")
        };
        // Some "invalid" samples only break interoperability rules (spec "Conforming
        // Readers" 3) and may load; those must then render.
        if let Ok(r) = result {
            if r.scene().world_bounds().is_some() {
                for cam in cameras(&r) {
                    let img = r
                        .render(&cam, cam.width, cam.height)
                        .unwrap_or_else(|e| panic!("{what}: {e}"));
                    check_image(&img, &what);
                }
            }
        }
    }
    // Garbage bytes are an error.
    assert!(Renderer::from_bytes(b"glTF\x02\0\0\0garbage").is_err());
    assert!(Renderer::from_bytes(b"{").is_err());
    assert!(Renderer::from_path("/nonexistent/asset.glb").is_err());
}

fn random_tensors(spec: &dnr_format::model::Renderer, seed: u64) -> RendererDesc {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let tensors = dnr_format::architecture_tensors(spec)
        .unwrap()
        .into_iter()
        .map(|(name, shape)| {
            let n: u32 = shape.iter().product();
            let data = (0..n).map(|_| rng.random_range(-0.5f32..0.5)).collect();
            (name, TensorF32::new(shape, data).unwrap())
        })
        .collect();
    RendererDesc {
        renderer: spec.clone(),
        tensors,
        dtype: dnr_format::model::DType::F16,
        tensor_dtypes: Default::default(),
    }
}

/// Built assets, one per architecture variant, with random features and weights: they run
/// whether or not `samples/valid` exists.
#[test]
fn built_assets_of_every_architecture_render() {
    use dnr_format::model::Renderer as Spec;
    let specs = [
        Spec::new(dnr_format::model::Architecture::None, 8, 3),
        Spec::mlp(8, 3, vec![16, 8]),
        Spec::mlp(8, 4, vec![]),
        Spec::unet(
            8,
            4,
            vec![4, 8, 8],
            Decoder::TransposedConv,
            Normalization::Instance,
        ),
        Spec::unet(8, 3, vec![6], Decoder::UpsampleConv, Normalization::None),
    ];
    for (i, spec) in specs.iter().enumerate() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(i as u64);
        let mut s = Scene::new();
        let l0 = level(16, 8, 8, |_, _, _| rng.random_range(-1.0f32..1.0));
        let l1 = level(8, 4, 8, |_, _, _| rng.random_range(-1.0f32..1.0));
        s.b.add_neural_texture(texture(
            vec![l0, l1],
            WrapMode::MirroredRepeat,
            Some(ViewDependence::spherical_harmonics(1, 3)),
        ));
        s.b.add_renderer(random_tensors(spec, 100 + i as u64));
        let m = s.material(0, 0);
        s.object(
            vec![
                quad(0.0, 0.0, 1.0, 0.0, Some(m)),
                quad(0.3, 0.2, 0.5, 0.4, Some(m)),
            ],
            [0.1, -0.2, 0.0],
        );
        let r = Renderer::from_asset(&s.build()).unwrap();
        check_renders(&r, &format!("built {}", spec.architecture));
        // Odd frame sizes (U-Net padding and cropping).
        let img = r.render(&cameras(&r)[1], 37, 19).unwrap();
        assert!(check_image(&img, "odd size") > 0);
    }
}
