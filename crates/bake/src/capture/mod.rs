//! Capture folders: posed photographs plus a proxy mesh, in the NeRF / instant-ngp /
//! nerfstudio `transforms.json` convention (see `shared/capture-format.md`).
//!
//! [`Capture::load`] reads the transforms file(s), splits train/test, resolves every frame's
//! image and intrinsics, decodes the images (in parallel) to sRGB-encoded float RGB plus an
//! alpha mask, and loads the proxy mesh. Sizes are checked against [`Limits`] from the JSON
//! and the image headers before pixels are decoded. Every error names the file and, where
//! there is one, the field.

mod error;
pub mod image;
pub mod mesh;
pub mod transforms;

use std::path::{Path, PathBuf};

use dnr_runtime::camera::Camera;
use dnr_runtime::scene::Scene;
use rayon::prelude::*;

pub use error::CaptureError;
pub use mesh::{load_mesh, MeshLimits};
pub use transforms::Distortion;

use self::image::{
    check_side, decode_image, probe, resolve_image_path, undistort, TRIED_EXTENSIONS,
};
use transforms::{read_transforms, resolve_camera, TransformsFile};

/// Default mesh names, tried in this order when neither `--mesh` nor `mesh_path` is given.
pub const DEFAULT_MESH_NAMES: [&str; 4] = ["mesh.glb", "mesh.gltf", "mesh.obj", "mesh.ply"];

/// Resource limits, checked before the corresponding allocation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Most frames in one transforms file and in the whole capture.
    pub max_frames: usize,
    /// Largest image width or height in pixels.
    pub max_image_side: u32,
    /// Most pixels over all images together (each costs 16 bytes decoded).
    pub max_total_pixels: u64,
    /// Largest transforms file in bytes.
    pub max_json_bytes: u64,
    /// Mesh limits.
    pub mesh: MeshLimits,
}

impl Limits {
    /// Sets one limit from `NAME=VALUE`, as `dnr-bake --limit` gives it. Names:
    /// `max_frames`, `max_image_side`, `max_total_pixels`, `max_json_bytes`,
    /// `max_mesh_bytes`, `max_triangles`.
    pub fn set(&mut self, spec: &str) -> Result<(), String> {
        const NAMES: &str = "max_frames, max_image_side, max_total_pixels, max_json_bytes, max_mesh_bytes, max_triangles";
        let (name, value) = spec
            .split_once('=')
            .ok_or_else(|| format!("expected NAME=VALUE, got `{spec}` (names: {NAMES})"))?;
        let value: u64 = value
            .trim()
            .parse()
            .map_err(|e| format!("limit `{name}`: `{value}` is not a whole number: {e}"))?;
        let size =
            |v: u64| usize::try_from(v).map_err(|_| format!("limit `{name}`: {v} is too large"));
        match name.trim() {
            "max_frames" => self.max_frames = size(value)?,
            "max_image_side" => {
                self.max_image_side = u32::try_from(value)
                    .map_err(|_| format!("limit `{name}`: {value} is over {}", u32::MAX))?
            }
            "max_total_pixels" => self.max_total_pixels = value,
            "max_json_bytes" => self.max_json_bytes = value,
            "max_mesh_bytes" => self.mesh.max_file_bytes = value,
            "max_triangles" => self.mesh.max_triangles = size(value)?,
            other => return Err(format!("unknown limit `{other}` (names: {NAMES})")),
        }
        Ok(())
    }
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_frames: 10_000,
            max_image_side: 8192,
            max_total_pixels: 1 << 28,
            max_json_bytes: 64 << 20,
            mesh: MeshLimits::default(),
        }
    }
}

/// How to load a capture.
#[derive(Clone, Debug, PartialEq)]
pub struct LoadOptions {
    /// Proxy mesh to use instead of `mesh_path` / the default names (the CLI's `--mesh`;
    /// relative paths are relative to the working directory, not the capture).
    pub mesh: Option<PathBuf>,
    /// With a single `transforms.json`, every `llffhold`-th frame (index 0, n, 2n, ...) is
    /// held out for testing. 0 holds none out.
    pub llffhold: usize,
    /// Resample images with non-zero distortion coefficients to the ideal pinhole camera.
    /// When false they are used as they are (and a warning says so).
    pub undistort: bool,
    /// Resource limits.
    pub limits: Limits,
}

impl Default for LoadOptions {
    fn default() -> Self {
        LoadOptions {
            mesh: None,
            llffhold: 8,
            undistort: true,
            limits: Limits::default(),
        }
    }
}

/// Where the train/test split came from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum SplitSource {
    /// `transforms_train.json` plus `transforms_test.json` or `transforms_val.json` (or no
    /// held-out file).
    Files {
        /// The training transforms file.
        train: PathBuf,
        /// The held-out transforms file, if any.
        test: Option<PathBuf>,
    },
    /// One `transforms.json`, every `every`-th frame held out (0: none).
    LlffHold {
        /// The transforms file.
        file: PathBuf,
        /// The hold-out period.
        every: usize,
    },
}

/// One posed photograph.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    /// `file_path` as written, without a leading `./` and without an image extension
    /// (e.g. `train/r_000`); unique within a capture.
    pub name: String,
    /// The image file that was read.
    pub image_path: PathBuf,
    /// Intrinsics (pixels) and camera-to-world pose; `width`/`height` are the image's.
    pub camera: Camera,
    /// Distortion coefficients as written (zero when absent).
    pub distortion: Distortion,
    /// Whether `rgb`/`alpha` were resampled to remove `distortion`.
    pub undistorted: bool,
    /// `height * width * 3` sRGB-encoded colour values in [0, 1], row 0 (top) first.
    pub rgb: Vec<f32>,
    /// `height * width` coverage values in [0, 1] (1 everywhere for images without alpha).
    pub alpha: Vec<f32>,
    /// Whether the image had an alpha channel.
    pub has_alpha: bool,
}

impl Frame {
    /// Image width in pixels.
    pub fn width(&self) -> u32 {
        self.camera.width
    }

    /// Image height in pixels.
    pub fn height(&self) -> u32 {
        self.camera.height
    }
}

/// A loaded capture folder.
#[derive(Clone, Debug)]
pub struct Capture {
    /// The capture folder.
    pub dir: PathBuf,
    /// Training frames, in file order.
    pub train: Vec<Frame>,
    /// Held-out frames, in file order.
    pub test: Vec<Frame>,
    /// The proxy mesh file.
    pub mesh_path: PathBuf,
    /// The proxy mesh (UVs in glTF convention, present on every primitive).
    pub mesh: Scene,
    /// Where the split came from.
    pub split: SplitSource,
    /// Non-fatal remarks for the user (distortion handling, odd rotations, no test set).
    pub warnings: Vec<String>,
}

/// Which frames of a transforms file are held out for testing.
#[derive(Clone, Copy, Debug)]
enum HoldOut {
    None,
    All,
    /// Index 0, n, 2n, ... (the llffhold convention); 0 holds none out.
    Every(usize),
}

impl HoldOut {
    fn holds(self, index: usize) -> bool {
        match self {
            HoldOut::None => false,
            HoldOut::All => true,
            HoldOut::Every(n) => n != 0 && index.is_multiple_of(n),
        }
    }
}

/// A frame whose image header has been read, not yet decoded.
struct Planned {
    test: bool,
    name: String,
    image_path: PathBuf,
    camera: Camera,
    distortion: Distortion,
}

impl Capture {
    /// Loads the capture in `dir` (see the module docs and `shared/capture-format.md`).
    pub fn load(dir: &Path, opts: &LoadOptions) -> Result<Capture, CaptureError> {
        let limits = &opts.limits;
        let read =
            |name: &str| read_transforms(&dir.join(name), limits.max_json_bytes, limits.max_frames);
        let train_path = dir.join("transforms_train.json");
        let single_path = dir.join("transforms.json");

        // Each transforms file with the rule for which of its frames are held out.
        let mut files: Vec<(TransformsFile, HoldOut)> = Vec::new();
        let mut warnings = Vec::new();
        let split = if train_path.is_file() {
            files.push((read("transforms_train.json")?, HoldOut::None));
            let test = ["transforms_test.json", "transforms_val.json"]
                .into_iter()
                .map(|n| dir.join(n))
                .find(|p| p.is_file());
            if let Some(t) = &test {
                files.push((
                    read_transforms(t, limits.max_json_bytes, limits.max_frames)?,
                    HoldOut::All,
                ));
            } else {
                warnings.push(format!(
                    "{}: no transforms_test.json or transforms_val.json: no held-out frames",
                    dir.display()
                ));
            }
            SplitSource::Files {
                train: train_path,
                test,
            }
        } else if single_path.is_file() {
            let every = opts.llffhold;
            let file = read("transforms.json")?;
            let n = file.frames.len();
            let held = if every == 0 { 0 } else { n.div_ceil(every) };
            if held >= n {
                return Err(CaptureError::NoFrames {
                    path: single_path,
                    message: format!(
                        "{n} frame(s) leave none for training after holding out every {every}th (llffhold)"
                    ),
                });
            }
            files.push((file, HoldOut::Every(every)));
            SplitSource::LlffHold {
                file: single_path,
                every,
            }
        } else {
            return Err(CaptureError::NoTransforms {
                dir: dir.to_path_buf(),
            });
        };

        let total_frames: usize = files.iter().map(|(f, _)| f.frames.len()).sum();
        if total_frames > limits.max_frames {
            return Err(CaptureError::TooManyFrames {
                path: files[0].0.path.clone(),
                count: total_frames,
                max: limits.max_frames,
            });
        }

        // Pass 1: resolve paths, read headers, resolve cameras; nothing large is allocated.
        let mut planned = Vec::with_capacity(total_frames);
        let mut total_pixels = 0u64;
        for (file, hold_out) in &files {
            warnings.extend(file.warnings.iter().cloned());
            let mut distorted = 0usize;
            for frame in &file.frames {
                let image_path = resolve_image_path(dir, &frame.file_path).ok_or_else(|| {
                    CaptureError::ImageNotFound {
                        path: file.path.clone(),
                        field: format!("frames[{}].file_path", frame.index),
                        image: dir.join(&frame.file_path),
                    }
                })?;
                let (_, w, h) = probe(&image_path)?;
                check_side(&image_path, w, h, limits.max_image_side)?;
                total_pixels += w as u64 * h as u64;
                if total_pixels > limits.max_total_pixels {
                    return Err(CaptureError::TooLarge {
                        path: file.path.clone(),
                        message: format!(
                            "images up to frames[{}] hold more than the limit of {} pixels in all",
                            frame.index, limits.max_total_pixels
                        ),
                    });
                }
                let resolved = resolve_camera(file, frame, &image_path, (w, h))?;
                if !resolved.distortion.is_identity() {
                    distorted += 1;
                }
                planned.push(Planned {
                    test: hold_out.holds(frame.index),
                    name: frame_name(&frame.file_path),
                    image_path,
                    camera: resolved.camera,
                    distortion: resolved.distortion,
                });
            }
            if distorted > 0 {
                let how = if opts.undistort {
                    "images are resampled to an ideal pinhole camera with the same intrinsics (border pixels clamped)"
                } else {
                    "distortion is not modelled: images are used as they are"
                };
                warnings.push(format!(
                    "{}: {distorted} frame(s) have non-zero distortion (k1, k2, k3, p1, p2): {how}",
                    file.path.display()
                ));
            }
        }

        // Pass 2: decode in parallel; the first error in file order is reported.
        let max_side = limits.max_image_side;
        let undistort_on = opts.undistort;
        let decoded: Vec<Result<(Frame, Option<String>), CaptureError>> = planned
            .par_iter()
            .map(|p| {
                let mut img = decode_image(&p.image_path, max_side)?;
                if (img.width, img.height) != (p.camera.width, p.camera.height) {
                    return Err(CaptureError::ImageDecode {
                        path: p.image_path.clone(),
                        message: "image changed size while loading".into(),
                    });
                }
                let do_undistort = undistort_on && !p.distortion.is_identity();
                if do_undistort {
                    img = undistort(&img, &p.camera, &p.distortion);
                }
                let warning = img
                    .non_finite
                    .map(|nf| format!("{}: {nf}", p.image_path.display()));
                let frame = Frame {
                    name: p.name.clone(),
                    image_path: p.image_path.clone(),
                    camera: p.camera,
                    distortion: p.distortion,
                    undistorted: do_undistort,
                    rgb: img.rgb,
                    alpha: img.alpha,
                    has_alpha: img.has_alpha,
                };
                Ok((frame, warning))
            })
            .collect();
        let mut train = Vec::new();
        let mut test = Vec::new();
        for (p, frame) in planned.iter().zip(decoded) {
            let (frame, warning) = frame?;
            warnings.extend(warning);
            if p.test {
                test.push(frame);
            } else {
                train.push(frame);
            }
        }

        let mesh_path = find_mesh(dir, opts, &files.iter().map(|(f, _)| f).collect::<Vec<_>>())?;
        let mesh = load_mesh(&mesh_path, &limits.mesh)?;
        Ok(Capture {
            dir: dir.to_path_buf(),
            train,
            test,
            mesh_path,
            mesh,
            split,
            warnings,
        })
    }
}

/// `file_path` without `./` and without a known image extension.
fn frame_name(file_path: &str) -> String {
    let mut s = file_path;
    while let Some(rest) = s.strip_prefix("./") {
        s = rest;
    }
    if let Some((stem, ext)) = s.rsplit_once('.') {
        if TRIED_EXTENSIONS.contains(&ext)
            || TRIED_EXTENSIONS.iter().any(|e| e.eq_ignore_ascii_case(ext))
        {
            return stem.to_string();
        }
    }
    s.to_string()
}

/// The proxy mesh: `--mesh`, else the first `mesh_path` in the transforms files, else the
/// first default name that exists.
fn find_mesh(
    dir: &Path,
    opts: &LoadOptions,
    files: &[&TransformsFile],
) -> Result<PathBuf, CaptureError> {
    if let Some(p) = &opts.mesh {
        if !p.is_file() {
            return Err(CaptureError::io(
                p,
                std::io::Error::new(std::io::ErrorKind::NotFound, "mesh file not found (--mesh)"),
            ));
        }
        return Ok(p.clone());
    }
    if let Some(file) = files.iter().find(|f| f.mesh_path.is_some()) {
        let rel = file.mesh_path.as_deref().unwrap_or_default();
        let p = dir.join(rel);
        if !p.is_file() {
            return Err(CaptureError::Field {
                path: file.path.clone(),
                field: "mesh_path".into(),
                message: format!("{} not found", p.display()),
            });
        }
        return Ok(p);
    }
    DEFAULT_MESH_NAMES
        .iter()
        .map(|n| dir.join(n))
        .find(|p| p.is_file())
        .ok_or_else(|| CaptureError::NoMesh {
            dir: dir.to_path_buf(),
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_names() {
        assert_eq!(frame_name("./train/r_0"), "train/r_0");
        assert_eq!(frame_name("train/r_000.png"), "train/r_000");
        assert_eq!(frame_name("images/IMG_1.JPG"), "images/IMG_1");
        assert_eq!(frame_name("images/frame.001"), "images/frame.001");
    }
}
