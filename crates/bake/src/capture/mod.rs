//! Capture folders: posed photographs plus a proxy mesh (`docs/capture-format.md`), as a
//! `transforms.json` (NeRF / instant-ngp / nerfstudio convention) or a COLMAP sparse model.
//!
//! [`Capture::load`] works in two passes. The plan ([`CapturePlan::read`]) reads the poses,
//! splits train/test, resolves every frame's image, mask and intrinsics in f64 and reads the
//! image headers; sizes are checked against [`Limits`] there, before pixels are decoded. The
//! second pass decodes the images in parallel to sRGB-encoded float RGB plus alpha, and
//! resamples each once: downscaled with an area filter to [`LoadOptions::max_side`]
//! (intrinsics scaled to match), then, through a lens with distortion, undistorted to the
//! pinhole camera with the same intrinsics, with a per-pixel validity mask (the frame's
//! mask, and whether the pixel's sample lay inside the photograph). Then the proxy mesh is
//! loaded and, when it has no UVs or overlapping ones, given a generated atlas. Every error
//! names the file and, where there is one, the field or frame. Nothing is written to the
//! capture folder: resampled images live in memory.

pub mod alignment;
pub mod colmap;
pub mod distortion;
mod error;
pub mod image;
pub mod mesh;
mod obj;
mod plan;
mod ply;
pub mod resample;
pub mod transforms;
pub mod uv_atlas;

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use dnr_runtime::camera::Camera;
use dnr_runtime::scene::Scene;
use glam::{DMat4, DVec3, Mat4};
use rayon::prelude::*;
use serde::Serialize;

pub use distortion::{Distortion, LensModel};
pub use error::CaptureError;
pub use mesh::{load_mesh, MeshLimits};
pub use plan::{CapturePlan, FramePlan};
pub use uv_atlas::UvReport;

use self::image::{decode_image, decode_mask};
use resample::{downscale, undistort, Intrinsics, Planes};

/// Default mesh names, tried in this order when neither `--mesh` nor `mesh_path` is given.
pub const DEFAULT_MESH_NAMES: [&str; 4] = ["mesh.glb", "mesh.gltf", "mesh.obj", "mesh.ply"];

/// Meshes COLMAP's dense reconstruction writes, tried after [`DEFAULT_MESH_NAMES`] in a
/// COLMAP capture.
pub const COLMAP_MESH_NAMES: [&str; 4] = [
    "dense/0/meshed-poisson.ply",
    "dense/0/meshed-delaunay.ply",
    "dense/meshed-poisson.ply",
    "dense/meshed-delaunay.ply",
];

/// Default longest image side after loading (`--max-side`): photographs larger than this
/// are downscaled with an area filter. Measured on the phone-like capture (64 photos of
/// 2016x1512, 300 s auto bakes, held-out error evaluated at 1024x768): 512 gives 23.23 dB,
/// 768 23.42 dB, 1024 23.13 dB; training steps cost about 0.1, 0.2 and 0.26 s whole-frame
/// (docs/benchmarks/capture-2026-12-04).
pub const DEFAULT_MAX_SIDE: u32 = 768;

/// Resource limits, checked before the corresponding allocation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Most frames in one transforms file and in the whole capture.
    pub max_frames: usize,
    /// Largest image width or height in pixels (of the file, before downscaling).
    pub max_image_side: u32,
    /// Most pixels kept over all images together after downscaling (each costs about 20
    /// bytes), and most pixels of any one image file (decoding one costs 16 bytes a pixel).
    pub max_total_pixels: u64,
    /// Largest transforms file in bytes.
    pub max_json_bytes: u64,
    /// Largest COLMAP model file in bytes.
    pub max_model_bytes: u64,
    /// Mesh limits.
    pub mesh: MeshLimits,
}

impl Limits {
    /// Sets one limit from `NAME=VALUE`, as `dnr-bake --limit` gives it. Names:
    /// `max_frames`, `max_image_side`, `max_total_pixels`, `max_json_bytes`,
    /// `max_model_bytes`, `max_mesh_bytes`, `max_triangles`, `max_unwrap_triangles`.
    pub fn set(&mut self, spec: &str) -> Result<(), String> {
        const NAMES: &str = "max_frames, max_image_side, max_total_pixels, max_json_bytes, max_model_bytes, max_mesh_bytes, max_triangles, max_unwrap_triangles";
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
            "max_model_bytes" => self.max_model_bytes = value,
            "max_mesh_bytes" => self.mesh.max_file_bytes = value,
            "max_triangles" => self.mesh.max_triangles = size(value)?,
            "max_unwrap_triangles" => self.mesh.max_unwrap_triangles = size(value)?,
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
            max_model_bytes: 1 << 30,
            mesh: MeshLimits::default(),
        }
    }
}

/// When the proxy mesh gets generated UVs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "camelCase")]
pub enum UvMode {
    /// Generate when the mesh has none or they overlap (more than
    /// [`uv_atlas::OVERLAP_LIMIT`] of their area); keep them otherwise.
    #[default]
    Auto,
    /// Keep the mesh's UVs whatever they are; a mesh without UVs is an error.
    Keep,
    /// Always generate, replacing the mesh's UVs.
    Generate,
}

impl std::str::FromStr for UvMode {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "auto" => Ok(UvMode::Auto),
            "keep" => Ok(UvMode::Keep),
            "generate" => Ok(UvMode::Generate),
            _ => Err(format!(
                "unknown UV mode '{s}' (expected auto, keep or generate)"
            )),
        }
    }
}

/// Which coordinates the proxy mesh is in, for a `transforms.json` with nerfstudio's
/// `applied_transform`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "camelCase")]
pub enum MeshSpace {
    /// Decide by the alignment check: the placement whose silhouettes match the
    /// photographs better (the poses' coordinates when nothing can tell).
    #[default]
    Auto,
    /// The poses' coordinates (as written in `transform_matrix`).
    Poses,
    /// The original reconstruction's coordinates: `applied_transform` is applied to the mesh.
    Reconstruction,
}

impl std::str::FromStr for MeshSpace {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "auto" => Ok(MeshSpace::Auto),
            "poses" => Ok(MeshSpace::Poses),
            "reconstruction" => Ok(MeshSpace::Reconstruction),
            _ => Err(format!(
                "unknown mesh space '{s}' (expected auto, poses or reconstruction)"
            )),
        }
    }
}

/// How to load a capture.
#[derive(Clone, Debug, PartialEq)]
pub struct LoadOptions {
    /// Proxy mesh to use instead of `mesh_path` / the default names (the CLI's `--mesh`;
    /// relative paths are relative to the working directory, not the capture).
    pub mesh: Option<PathBuf>,
    /// Without split files, every `llffhold`-th frame (index 0, n, 2n, ...; COLMAP images in
    /// name order) is held out for testing. 0 holds none out.
    pub llffhold: usize,
    /// Resample images through a lens with distortion to the ideal pinhole camera. When
    /// false they are used as they are (and a warning says so).
    pub undistort: bool,
    /// Longest image side after loading; larger photographs are downscaled with an area
    /// filter and their intrinsics scaled. 0 keeps every image at its size.
    pub max_side: u32,
    /// When to generate UVs for the proxy mesh.
    pub uv: UvMode,
    /// Which coordinates the mesh is in (matters only with `applied_transform`).
    pub mesh_space: MeshSpace,
    /// Resource limits.
    pub limits: Limits,
}

impl Default for LoadOptions {
    fn default() -> Self {
        LoadOptions {
            mesh: None,
            llffhold: 8,
            undistort: true,
            max_side: DEFAULT_MAX_SIDE,
            uv: UvMode::Auto,
            mesh_space: MeshSpace::Auto,
            limits: Limits::default(),
        }
    }
}

/// Loading choices `dnr-bake` exposes besides the mesh and the limits.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct InputOptions {
    /// `--max-side` (see [`LoadOptions::max_side`]).
    pub max_side: u32,
    /// `--uv`.
    pub uv: UvMode,
    /// `--mesh-space`.
    pub mesh_space: MeshSpace,
    /// `--skip-alignment-check`, `--drop-misaligned`.
    pub alignment: alignment::AlignmentOptions,
    /// `--verbose`: list ignored keys and load timings.
    pub verbose: bool,
}

impl Default for InputOptions {
    fn default() -> Self {
        InputOptions {
            max_side: DEFAULT_MAX_SIDE,
            uv: UvMode::Auto,
            mesh_space: MeshSpace::Auto,
            alignment: Default::default(),
            verbose: false,
        }
    }
}

impl InputOptions {
    /// The load options with these choices, `mesh` and `limits`.
    pub fn load_options(&self, mesh: Option<PathBuf>, limits: Limits) -> LoadOptions {
        LoadOptions {
            mesh,
            max_side: self.max_side,
            uv: self.uv,
            mesh_space: self.mesh_space,
            limits,
            ..LoadOptions::default()
        }
    }
}

/// What loading found and did, for the bake report (`load`).
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct LoadReport {
    /// `transforms`, `colmap-bin` or `colmap-txt`.
    pub format: &'static str,
    /// The working-size limit used.
    pub max_side: u32,
    /// Frames downscaled to it.
    pub frames_resized: usize,
    /// Frames resampled through their lens model.
    pub frames_undistorted: usize,
    /// Frames with a mask.
    pub frames_masked: usize,
    /// Where the mesh was placed.
    pub mesh_space: MeshSpace,
    /// Seconds per load step.
    pub timings: LoadTimings,
    /// The UV step.
    pub uv: UvReport,
    /// The alignment check.
    pub alignment: alignment::AlignmentReport,
    /// Keys of the transforms file(s) that were not used.
    pub ignored_keys: Vec<String>,
}

impl Capture {
    /// The report of this load with the alignment check's figures.
    pub fn load_report(
        &self,
        opts: &LoadOptions,
        alignment: alignment::AlignmentReport,
    ) -> LoadReport {
        let frames = || self.train.iter().chain(&self.test);
        LoadReport {
            format: match self.format {
                CaptureFormat::Transforms => "transforms",
                CaptureFormat::Colmap(colmap::Encoding::Binary) => "colmap-bin",
                CaptureFormat::Colmap(colmap::Encoding::Text) => "colmap-txt",
            },
            max_side: opts.max_side,
            frames_resized: frames()
                .filter(|f| (f.width(), f.height()) != f.source_size)
                .count(),
            frames_undistorted: frames().filter(|f| f.undistorted).count(),
            frames_masked: frames().filter(|f| f.has_mask).count(),
            mesh_space: self.mesh_space,
            timings: self.timings,
            uv: self.uv.clone(),
            alignment,
            ignored_keys: self.ignored_keys.clone(),
        }
    }
}

/// A camera as read, in f64: pinhole intrinsics in pixels (pixel centres at half-integers)
/// and camera-to-world in the capture convention (OpenGL camera: -Z forward, +Y up).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraRecord {
    /// Focal length along x in pixels.
    pub fx: f64,
    /// Focal length along y in pixels.
    pub fy: f64,
    /// Principal point x in pixels from the left edge.
    pub cx: f64,
    /// Principal point y in pixels from the top edge.
    pub cy: f64,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Camera-to-world.
    pub cam_to_world: DMat4,
}

impl CameraRecord {
    /// The same camera for the image resized to `width x height` (intrinsics scaled per axis).
    pub fn resized(&self, width: u32, height: u32) -> CameraRecord {
        let sx = width as f64 / self.width as f64;
        let sy = height as f64 / self.height as f64;
        CameraRecord {
            fx: self.fx * sx,
            fy: self.fy * sy,
            cx: self.cx * sx,
            cy: self.cy * sy,
            width,
            height,
            cam_to_world: self.cam_to_world,
        }
    }

    /// The runtime's (f32) camera.
    pub fn to_camera(&self) -> Camera {
        Camera {
            fx: self.fx as f32,
            fy: self.fy as f32,
            cx: self.cx as f32,
            cy: self.cy as f32,
            width: self.width,
            height: self.height,
            cam_to_world: self.cam_to_world.as_mat4(),
        }
    }

    fn intrinsics(&self) -> Intrinsics {
        Intrinsics {
            fx: self.fx,
            fy: self.fy,
            cx: self.cx,
            cy: self.cy,
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
    /// One `transforms.json` or COLMAP images file, every `every`-th frame held out (0: none).
    LlffHold {
        /// The transforms file or COLMAP images file.
        file: PathBuf,
        /// The hold-out period.
        every: usize,
    },
}

/// Which kind of capture folder was read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CaptureFormat {
    /// `transforms.json` or split files.
    Transforms,
    /// A COLMAP sparse model.
    Colmap(colmap::Encoding),
}

/// One posed photograph, resampled to its working size and an ideal pinhole camera.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    /// `file_path` as written (COLMAP: the image name), without a leading `./` and without an
    /// image extension (e.g. `train/r_000`); unique within a capture.
    pub name: String,
    /// The image file that was read.
    pub image_path: PathBuf,
    /// The mask file that was read, if any.
    pub mask_path: Option<PathBuf>,
    /// Intrinsics (pixels) and camera-to-world pose; `width`/`height` are the working size.
    pub camera: Camera,
    /// The same camera in f64.
    pub record: CameraRecord,
    /// The lens of the photograph as read (its coefficients apply to the working size too).
    pub distortion: Distortion,
    /// Whether `rgb`/`alpha` were resampled to remove `distortion`.
    pub undistorted: bool,
    /// The size of the image file.
    pub source_size: (u32, u32),
    /// `height * width * 3` sRGB-encoded colour values in [0, 1], row 0 (top) first.
    pub rgb: Vec<f32>,
    /// `height * width` coverage values in [0, 1] (1 everywhere for images without alpha).
    pub alpha: Vec<f32>,
    /// Whether the image had an alpha channel.
    pub has_alpha: bool,
    /// `height * width` flags: false where a pixel gives no loss and does not count in
    /// evaluation (its mask is black, or undistortion sampled outside the photograph). None
    /// when every pixel is valid.
    pub valid: Option<Vec<bool>>,
    /// Whether the frame had a mask file (then `valid` is also the object's silhouette for
    /// the alignment check).
    pub has_mask: bool,
    /// COLMAP: ids of the sparse points the image observes (empty otherwise).
    pub point_ids: Vec<u64>,
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

    /// Whether pixel `i` gives loss and counts in evaluation.
    pub fn is_valid(&self, i: usize) -> bool {
        self.valid.as_ref().is_none_or(|v| v[i])
    }
}

/// Seconds each load step took. Per-frame steps run in parallel over frames: their figure is
/// the sum over frames (thread seconds); `images_wall` is the wall time of the whole pass.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct LoadTimings {
    /// Reading poses, resolving cameras and image headers.
    pub plan: f64,
    /// Decoding images (thread seconds).
    pub decode: f64,
    /// Decoding masks (thread seconds).
    pub masks: f64,
    /// Area downscaling (thread seconds).
    pub downscale: f64,
    /// Undistortion (thread seconds).
    pub undistort: f64,
    /// Wall time of the image pass (decode, masks, downscale, undistort).
    pub images_wall: f64,
    /// Reading the mesh.
    pub mesh: f64,
    /// Checking UVs for overlaps and generating an atlas.
    pub uv: f64,
}

/// A loaded capture folder.
#[derive(Clone, Debug)]
pub struct Capture {
    /// The capture folder.
    pub dir: PathBuf,
    /// What kind of folder it is.
    pub format: CaptureFormat,
    /// Training frames, in file order (COLMAP: name order).
    pub train: Vec<Frame>,
    /// Held-out frames, in file order (COLMAP: name order).
    pub test: Vec<Frame>,
    /// The proxy mesh file.
    pub mesh_path: PathBuf,
    /// The proxy mesh (UVs in glTF convention on every primitive: read or generated), placed
    /// in the poses' coordinates (see [`Capture::mesh_space`]).
    pub mesh: Scene,
    /// Where the split came from.
    pub split: SplitSource,
    /// Non-fatal remarks for the user (distortion handling, odd rotations, no test set).
    pub warnings: Vec<String>,
    /// Keys of the transforms file(s) that were not used (`--verbose` lists them).
    pub ignored_keys: Vec<String>,
    /// nerfstudio's `applied_transform`, if the transforms file has one.
    pub applied_transform: Option<DMat4>,
    /// Which coordinates the mesh is in: `Auto` until the alignment check decides.
    pub mesh_space: MeshSpace,
    /// instant-ngp's scene box, if `aabb_scale` was given.
    pub ngp_box: Option<transforms::NgpBox>,
    /// COLMAP sparse points by id (empty without a points file or for transforms.json).
    pub points: HashMap<u64, DVec3>,
    /// What the UV step found and did.
    pub uv: UvReport,
    /// Seconds per load step.
    pub timings: LoadTimings,
}

/// Measures one step.
fn timed<T>(acc: &mut f64, f: impl FnOnce() -> T) -> T {
    let t = Instant::now();
    let r = f();
    *acc += t.elapsed().as_secs_f64();
    r
}

impl Capture {
    /// Loads the capture in `dir` (see the module docs and `docs/capture-format.md`).
    pub fn load(dir: &Path, opts: &LoadOptions) -> Result<Capture, CaptureError> {
        let mut timings = LoadTimings::default();
        let t_plan = Instant::now();
        let plan = CapturePlan::read(dir, opts)?;
        timings.plan = t_plan.elapsed().as_secs_f64();

        // Decode and resample in parallel; the first error in file order is reported.
        let t_images = Instant::now();
        let decoded: Vec<Result<LoadedFrame, CaptureError>> = plan
            .frames
            .par_iter()
            .map(|p| load_frame(p, opts))
            .collect();
        let mut train = Vec::new();
        let mut test = Vec::new();
        let mut warnings = plan.warnings.clone();
        for (p, frame) in plan.frames.iter().zip(decoded) {
            let (frame, t, warning) = frame?;
            timings.decode += t.decode;
            timings.masks += t.masks;
            timings.downscale += t.downscale;
            timings.undistort += t.undistort;
            warnings.extend(warning);
            if p.test {
                test.push(frame);
            } else {
                train.push(frame);
            }
        }
        timings.images_wall = t_images.elapsed().as_secs_f64();

        let mut mesh = timed(&mut timings.mesh, || {
            load_mesh(&plan.mesh_path, &opts.limits.mesh)
        })?;
        let uv = timed(&mut timings.uv, || {
            uv_atlas::ensure_uvs(
                &mut mesh,
                &plan.mesh_path,
                opts.uv,
                opts.limits.mesh.max_unwrap_triangles,
            )
        })?;
        if let Some(w) = uv.warning() {
            warnings.push(w);
        }
        let mut mesh_space = opts.mesh_space;
        match (plan.applied_transform, opts.mesh_space) {
            (Some(t), MeshSpace::Reconstruction) => place_mesh(&mut mesh, t),
            (None, MeshSpace::Reconstruction) => {
                return Err(CaptureError::Field {
                    path: plan.list_path.clone(),
                    field: "applied_transform".into(),
                    message: "missing, so a mesh in the original reconstruction's coordinates (--mesh-space reconstruction) cannot be placed".into(),
                })
            }
            // Without applied_transform both spaces are one.
            (None, _) => mesh_space = MeshSpace::Poses,
            (Some(_), _) => {}
        }
        Ok(Capture {
            dir: dir.to_path_buf(),
            format: plan.format,
            train,
            test,
            mesh_path: plan.mesh_path,
            mesh,
            split: plan.split,
            warnings,
            ignored_keys: plan.ignored_keys,
            applied_transform: plan.applied_transform,
            mesh_space,
            ngp_box: plan.ngp_box,
            points: plan.points,
            uv,
            timings,
        })
    }
}

/// Moves every primitive of `mesh` by `t` (applied after its own node transform).
pub fn place_mesh(mesh: &mut Scene, t: DMat4) {
    let t: Mat4 = t.as_mat4();
    for p in &mut mesh.primitives {
        p.world = t * p.world;
    }
}

/// A decoded frame with its step timings and a warning.
type LoadedFrame = (Frame, LoadTimings, Option<String>);

/// Decodes and resamples one frame.
fn load_frame(p: &FramePlan, opts: &LoadOptions) -> Result<LoadedFrame, CaptureError> {
    let mut t = LoadTimings::default();
    let max_side = opts.limits.max_image_side;
    let img = timed(&mut t.decode, || decode_image(&p.image_path, max_side))?;
    let (w, h) = (p.record.width, p.record.height);
    if (img.width, img.height) != (w, h) {
        return Err(CaptureError::ImageDecode {
            path: p.image_path.clone(),
            message: "image changed size while loading".into(),
        });
    }
    let mask = match &p.mask_path {
        None => None,
        Some(mp) => {
            let (mw, mh, m) = timed(&mut t.masks, || decode_mask(mp, max_side))?;
            if (mw, mh) != (w, h) {
                return Err(CaptureError::Frame {
                    path: p.list_path.clone(),
                    frame: p.label.clone(),
                    message: format!(
                        "mask {} is {mw}x{mh} but image {} is {w}x{h}",
                        mp.display(),
                        p.image_path.display()
                    ),
                });
            }
            Some(m)
        }
    };
    let warning = img
        .non_finite
        .map(|nf| format!("{}: {nf}", p.image_path.display()));
    let has_alpha = img.has_alpha;
    let mut planes = Planes {
        width: w,
        height: h,
        rgb: img.rgb,
        alpha: img.alpha,
        mask,
    };
    let (w2, h2) = p.out_size;
    if (w2, h2) != (w, h) {
        planes = timed(&mut t.downscale, || downscale(&planes, w2, h2));
    }
    let record = p.record.resized(w2, h2);
    let do_undistort = opts.undistort && !p.distortion.is_identity();
    let mut inside = None;
    if do_undistort {
        let (q, ins) = timed(&mut t.undistort, || {
            undistort(&planes, &record.intrinsics(), &p.distortion)
        });
        planes = q;
        inside = Some(ins);
    }
    let has_mask = planes.mask.is_some();
    let valid: Option<Vec<bool>> = match (&planes.mask, &inside) {
        (None, None) => None,
        _ => {
            let n = (w2 * h2) as usize;
            Some(
                (0..n)
                    .map(|i| {
                        inside.as_ref().is_none_or(|v| v[i])
                            && planes.mask.as_ref().is_none_or(|m| m[i] >= 0.5)
                    })
                    .collect(),
            )
        }
    };
    let frame = Frame {
        name: p.name.clone(),
        image_path: p.image_path.clone(),
        mask_path: p.mask_path.clone(),
        camera: record.to_camera(),
        record,
        distortion: p.distortion,
        undistorted: do_undistort,
        source_size: (w, h),
        rgb: planes.rgb,
        alpha: planes.alpha,
        has_alpha,
        valid,
        has_mask,
        point_ids: p.point_ids.clone(),
    };
    Ok((frame, t, warning))
}
