//! Writes the reference renders of the valid conformance samples:
//! `cargo run -p dnr-conformance --example make_references -- samples` (the samples folder).
//!
//! For every camera of `make_samples::reference_cameras` it renders the sample with
//! `dnr-runtime` and writes `references/<sample>/<camera>.png` (8-bit RGBA) and `.f32` (the
//! values the PNG is rounded from), and `references/cameras.json` with every camera in full.
//! Deterministic. It lives here rather than beside `make_samples` because `dnr-format` must not
//! depend on `dnr-runtime`; `tests/references.rs` includes it (`generate`) to check the
//! committed files.

#[path = "../../crates/format/examples/make_samples.rs"]
#[allow(dead_code)]
mod make_samples;

use std::error::Error;
use std::fs;
use std::path::{Path, PathBuf};

use dnr_format::asset::encode_png_rgba8;
use dnr_runtime::camera::Camera;
use dnr_runtime::renderer::{Renderer, RgbaImage};
use serde_json::{json, Value};

type Res<T> = Result<T, Box<dyn Error>>;

/// Near plane stated for every reference camera (no sample geometry is nearer).
pub const NEAR: f32 = 0.01;

/// One reference render.
pub struct Reference {
    /// Sample path relative to `samples/`, e.g. `valid/none_1level.glb`.
    pub sample: String,
    /// The camera as `make_samples` defines it.
    pub camera: Camera,
    /// `references/<stem>/<camera>` relative to `samples/`, without extension.
    pub stem: String,
    /// The runtime's output.
    pub image: RgbaImage,
}

/// Folder name of a sample's references: its file name without extension.
pub fn sample_stem(sample: &str) -> String {
    Path::new(sample)
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// Renders every reference camera of every valid sample under `samples`.
pub fn render_all(samples: &Path) -> Res<Vec<Reference>> {
    let mut out = Vec::new();
    for (sample, cams) in make_samples::reference_cameras() {
        let path = samples.join(sample);
        let r = Renderer::from_path(&path).map_err(|e| format!("{}: {e}", path.display()))?;
        for c in cams {
            let camera = Camera::look_at(c.eye.into(), c.target.into(), c.fov_y, c.width, c.height);
            let image = r.render(&camera, c.width, c.height)?;
            out.push(Reference {
                sample: sample.to_string(),
                camera,
                stem: format!("references/{}/{}", sample_stem(sample), c.name),
                image,
            });
        }
    }
    Ok(out)
}

/// The `.f32` file of an image: little-endian values, rows top first, RGBA per pixel.
pub fn f32_bytes(img: &RgbaImage) -> Vec<u8> {
    img.data.iter().flat_map(|v| v.to_le_bytes()).collect()
}

/// `cameras.json`: per sample, its cameras with intrinsics, pose, size and files.
pub fn cameras_json(refs: &[Reference]) -> Value {
    let mut by_sample = serde_json::Map::new();
    for (sample, cams) in make_samples::reference_cameras() {
        let list: Vec<Value> = cams
            .iter()
            .map(|c| {
                let r = refs
                    .iter()
                    .find(|r| r.sample == sample && r.stem.ends_with(&format!("/{}", c.name)))
                    .expect("rendered");
                let k = &r.camera;
                json!({
                    "name": c.name,
                    "eye": c.eye,
                    "target": c.target,
                    "fovY": c.fov_y,
                    "width": c.width,
                    "height": c.height,
                    "fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy,
                    "camToWorld": k.cam_to_world.to_cols_array(),
                    "near": NEAR,
                    "png": format!("{}.png", r.stem),
                    "f32": format!("{}.f32", r.stem),
                })
            })
            .collect();
        by_sample.insert(sample.to_string(), Value::Array(list));
    }
    Value::Object(by_sample)
}

/// Renders and writes every reference file under `samples` (`references/` is replaced).
pub fn generate(samples: &Path, into: &Path) -> Res<Vec<PathBuf>> {
    let refs = render_all(samples)?;
    let dir = into.join("references");
    if dir.exists() {
        fs::remove_dir_all(&dir)?;
    }
    let mut written = Vec::new();
    for r in &refs {
        let base = into.join(&r.stem);
        fs::create_dir_all(base.parent().expect("has a folder"))?;
        let (w, h) = (r.image.width as u32, r.image.height as u32);
        let png = encode_png_rgba8(w, h, &r.image.to_rgba8())?;
        for (ext, bytes) in [("png", png), ("f32", f32_bytes(&r.image))] {
            let p = base.with_extension(ext);
            fs::write(&p, bytes)?;
            written.push(p);
        }
    }
    let mut text = serde_json::to_vec_pretty(&cameras_json(&refs))?;
    text.push(b'\n');
    let p = dir.join("cameras.json");
    fs::write(&p, text)?;
    written.push(p);
    Ok(written)
}

#[allow(dead_code)]
fn main() -> Res<()> {
    let samples = PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| "samples".into()));
    let files = generate(&samples, &samples)?;
    println!(
        "wrote {} reference files under {}",
        files.len(),
        samples.join("references").display()
    );
    Ok(())
}
