//! The first pass of loading: poses, split, files and cameras of every frame, from a
//! `transforms.json` (or split files) or a COLMAP sparse model, with image headers read and
//! sizes checked, but no pixels decoded.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::{DMat4, DVec3};

use super::colmap::{self, ColmapModel};
use super::distortion::Distortion;
use super::error::CaptureError;
use super::image::{check_side, probe, resolve_image_path, TRIED_EXTENSIONS};
use super::resample::fit_size;
use super::transforms::{read_transforms, resolve_camera, NgpBox, TransformsFile};
use super::{
    CameraRecord, CaptureFormat, Limits, LoadOptions, SplitSource, COLMAP_MESH_NAMES,
    DEFAULT_MESH_NAMES,
};

/// A frame before its pixels are read.
#[derive(Clone, Debug, PartialEq)]
pub struct FramePlan {
    /// Held out for testing.
    pub test: bool,
    /// The frame's name (see [`super::Frame::name`]).
    pub name: String,
    /// How error messages name the frame: `frames[3]` or `image 12 (IMG_0012.JPG)`.
    pub label: String,
    /// The file that lists the frame (transforms file or COLMAP images file).
    pub list_path: PathBuf,
    /// The image file.
    pub image_path: PathBuf,
    /// The mask file, if any.
    pub mask_path: Option<PathBuf>,
    /// The camera at the image file's size, in f64.
    pub record: CameraRecord,
    /// The lens.
    pub distortion: Distortion,
    /// The working size after downscaling to `max_side`.
    pub out_size: (u32, u32),
    /// COLMAP: ids of the sparse points the image observes.
    pub point_ids: Vec<u64>,
}

/// Everything about a capture but its pixels and mesh.
#[derive(Clone, Debug)]
pub struct CapturePlan {
    /// The kind of folder.
    pub format: CaptureFormat,
    /// The frames, train and test, in file order (COLMAP: name order).
    pub frames: Vec<FramePlan>,
    /// Where the split came from.
    pub split: SplitSource,
    /// The file that lists the frames (the first transforms file, or COLMAP images file).
    pub list_path: PathBuf,
    /// The proxy mesh file.
    pub mesh_path: PathBuf,
    /// nerfstudio's `applied_transform`.
    pub applied_transform: Option<DMat4>,
    /// instant-ngp's scene box.
    pub ngp_box: Option<NgpBox>,
    /// COLMAP sparse points by id.
    pub points: HashMap<u64, DVec3>,
    /// Unused keys of the transforms file(s).
    pub ignored_keys: Vec<String>,
    /// Non-fatal remarks.
    pub warnings: Vec<String>,
}

/// Which frames of a list are held out for testing.
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

/// Checks the running pixel totals of one image: the file against the per-image decode
/// bound, the working size against the capture total.
fn count_pixels(
    list: &Path,
    label: &str,
    image: &Path,
    source: (u32, u32),
    out: (u32, u32),
    total: &mut u64,
    limits: &Limits,
) -> Result<(), CaptureError> {
    let file_px = source.0 as u64 * source.1 as u64;
    if file_px > limits.max_total_pixels {
        return Err(CaptureError::TooLarge {
            path: image.to_path_buf(),
            message: format!(
                "image has {file_px} pixels, over the limit of {} pixels",
                limits.max_total_pixels
            ),
        });
    }
    *total += out.0 as u64 * out.1 as u64;
    if *total > limits.max_total_pixels {
        return Err(CaptureError::TooLarge {
            path: list.to_path_buf(),
            message: format!(
                "images up to {label} hold more than the limit of {} pixels in all (after downscaling to --max-side)",
                limits.max_total_pixels
            ),
        });
    }
    Ok(())
}

impl CapturePlan {
    /// Reads the poses and image headers of the capture in `dir`: split files or
    /// `transforms.json` if present, else a COLMAP model under `sparse/0/` or `sparse/`.
    pub fn read(dir: &Path, opts: &LoadOptions) -> Result<CapturePlan, CaptureError> {
        if dir.join("transforms_train.json").is_file() || dir.join("transforms.json").is_file() {
            return read_transforms_capture(dir, opts);
        }
        if let Some((model_dir, encoding)) = colmap::find_model(dir) {
            let model = colmap::read_model(
                &model_dir,
                encoding,
                opts.limits.max_model_bytes,
                opts.limits.max_frames,
            )?;
            return read_colmap_capture(dir, model, encoding, opts);
        }
        Err(CaptureError::NoTransforms {
            dir: dir.to_path_buf(),
        })
    }
}

fn read_transforms_capture(dir: &Path, opts: &LoadOptions) -> Result<CapturePlan, CaptureError> {
    let limits = &opts.limits;
    let read = |path: &Path| read_transforms(path, limits.max_json_bytes, limits.max_frames);
    let train_path = dir.join("transforms_train.json");
    let single_path = dir.join("transforms.json");
    let mut files: Vec<(TransformsFile, HoldOut)> = Vec::new();
    let mut warnings = Vec::new();
    let split = if train_path.is_file() {
        files.push((read(&train_path)?, HoldOut::None));
        let test = ["transforms_test.json", "transforms_val.json"]
            .into_iter()
            .map(|n| dir.join(n))
            .find(|p| p.is_file());
        if let Some(t) = &test {
            files.push((read(t)?, HoldOut::All));
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
    } else {
        let every = opts.llffhold;
        let file = read(&single_path)?;
        check_hold_out(&single_path, file.frames.len(), every)?;
        files.push((file, HoldOut::Every(every)));
        SplitSource::LlffHold {
            file: single_path,
            every,
        }
    };

    let total_frames: usize = files.iter().map(|(f, _)| f.frames.len()).sum();
    if total_frames > limits.max_frames {
        return Err(CaptureError::TooManyFrames {
            path: files[0].0.path.clone(),
            count: total_frames,
            max: limits.max_frames,
        });
    }

    let mut frames = Vec::with_capacity(total_frames);
    let mut total_pixels = 0u64;
    let mut ignored_keys = Vec::new();
    for (file, hold_out) in &files {
        warnings.extend(file.warnings.iter().cloned());
        ignored_keys.extend(file.ignored_keys.iter().map(|k| {
            let name = file.path.file_name().unwrap_or_default().to_string_lossy();
            format!("{name}: {k}")
        }));
        let mut distorted = 0usize;
        for frame in &file.frames {
            let label = format!("frames[{}]", frame.index);
            let image_path = resolve_image_path(dir, &frame.file_path).ok_or_else(|| {
                CaptureError::ImageNotFound {
                    path: file.path.clone(),
                    field: format!("{label}.file_path"),
                    image: dir.join(&frame.file_path),
                }
            })?;
            let mask_path = match &frame.mask_path {
                None => None,
                Some(m) => {
                    let p = dir.join(m);
                    if !p.is_file() {
                        return Err(CaptureError::Frame {
                            path: file.path.clone(),
                            frame: format!("{label}.mask_path"),
                            message: format!("mask {} not found", p.display()),
                        });
                    }
                    Some(p)
                }
            };
            let (_, w, h) = probe(&image_path)?;
            check_side(&image_path, w, h, limits.max_image_side)?;
            let out_size = fit_size(w, h, opts.max_side);
            count_pixels(
                &file.path,
                &label,
                &image_path,
                (w, h),
                out_size,
                &mut total_pixels,
                limits,
            )?;
            let resolved = resolve_camera(file, frame, &image_path, (w, h))?;
            if !resolved.distortion.is_identity() {
                distorted += 1;
            }
            frames.push(FramePlan {
                test: hold_out.holds(frame.index),
                name: frame_name(&frame.file_path),
                label,
                list_path: file.path.clone(),
                image_path,
                mask_path,
                record: resolved.camera,
                distortion: resolved.distortion,
                out_size,
                point_ids: Vec::new(),
            });
        }
        if distorted > 0 {
            warnings.push(distortion_note(&file.path, distorted, opts.undistort));
        }
    }
    let refs: Vec<&TransformsFile> = files.iter().map(|(f, _)| f).collect();
    let mesh_path = find_mesh(dir, opts, &refs, false)?;
    let list_path = files[0].0.path.clone();
    let applied_transform = files.iter().find_map(|(f, _)| f.applied_transform);
    let ngp_box = files.iter().find_map(|(f, _)| f.ngp_box);
    Ok(CapturePlan {
        format: CaptureFormat::Transforms,
        frames,
        split,
        list_path,
        mesh_path,
        applied_transform,
        ngp_box,
        points: HashMap::new(),
        ignored_keys,
        warnings,
    })
}

fn distortion_note(list: &Path, distorted: usize, undistort: bool) -> String {
    let how = if undistort {
        "images are resampled to the ideal pinhole camera with the same intrinsics; pixels whose sample falls outside the photograph give no loss"
    } else {
        "distortion is not modelled: images are used as they are"
    };
    format!(
        "{}: {distorted} frame(s) have lens distortion: {how}",
        list.display()
    )
}

fn check_hold_out(path: &Path, n: usize, every: usize) -> Result<(), CaptureError> {
    let held = if every == 0 { 0 } else { n.div_ceil(every) };
    if held >= n {
        return Err(CaptureError::NoFrames {
            path: path.to_path_buf(),
            message: format!(
                "{n} frame(s) leave none for training after holding out every {every}th (llffhold)"
            ),
        });
    }
    Ok(())
}

/// The mask of a COLMAP image: COLMAP's own convention `masks/NAME.png`, else `masks/NAME`,
/// else `masks/STEM.png`, if a `masks/` folder exists.
fn colmap_mask(dir: &Path, name: &str) -> Option<PathBuf> {
    let masks = dir.join("masks");
    if !masks.is_dir() {
        return None;
    }
    let stem = Path::new(name).with_extension("png");
    [
        masks.join(format!("{name}.png")),
        masks.join(name),
        masks.join(stem),
    ]
    .into_iter()
    .find(|p| p.is_file())
}

fn read_colmap_capture(
    dir: &Path,
    model: ColmapModel,
    encoding: colmap::Encoding,
    opts: &LoadOptions,
) -> Result<CapturePlan, CaptureError> {
    let limits = &opts.limits;
    let list = model.images_path.clone();
    let mut images: Vec<&colmap::ColmapImage> = model.images.iter().collect();
    if images.is_empty() {
        return Err(CaptureError::NoFrames {
            path: list,
            message: "the model has no registered images".into(),
        });
    }
    // Name order: the hold-out does not depend on the order COLMAP registered images in.
    images.sort_by(|a, b| a.name.cmp(&b.name));
    let every = opts.llffhold;
    check_hold_out(&list, images.len(), every)?;
    let mut frames = Vec::with_capacity(images.len());
    let mut total_pixels = 0u64;
    let mut distorted = 0usize;
    let mut without_mask = 0usize;
    let has_masks = dir.join("masks").is_dir();
    for (index, im) in images.iter().enumerate() {
        let label = format!("image {} ({})", im.id, im.name);
        let cam = model
            .cameras
            .get(&im.camera_id)
            .ok_or_else(|| CaptureError::Frame {
                path: list.clone(),
                frame: label.clone(),
                message: format!(
                    "camera {} is not in {}",
                    im.camera_id,
                    model.cameras_path.display()
                ),
            })?;
        let image_path = dir.join("images").join(&im.name);
        if !image_path.is_file() {
            return Err(CaptureError::Frame {
                path: list.clone(),
                frame: label,
                message: format!("image {} not found", image_path.display()),
            });
        }
        let (_, w, h) = probe(&image_path)?;
        check_side(&image_path, w, h, limits.max_image_side)?;
        if (w as u64, h as u64) != (cam.width, cam.height) {
            return Err(CaptureError::Frame {
                path: list.clone(),
                frame: label,
                message: format!(
                    "image {} is {w}x{h} but camera {} in {} is {}x{}",
                    image_path.display(),
                    cam.id,
                    model.cameras_path.display(),
                    cam.width,
                    cam.height
                ),
            });
        }
        let out_size = fit_size(w, h, opts.max_side);
        count_pixels(
            &list,
            &label,
            &image_path,
            (w, h),
            out_size,
            &mut total_pixels,
            limits,
        )?;
        let ([fx, fy, cx, cy], distortion) = cam.intrinsics();
        if !distortion.is_identity() {
            distorted += 1;
        }
        let mask_path = colmap_mask(dir, &im.name);
        if has_masks && mask_path.is_none() {
            without_mask += 1;
        }
        frames.push(FramePlan {
            test: HoldOut::Every(every).holds(index),
            name: frame_name(&im.name),
            label,
            list_path: list.clone(),
            image_path,
            mask_path,
            record: CameraRecord {
                fx,
                fy,
                cx,
                cy,
                width: w,
                height: h,
                cam_to_world: im.cam_to_world(),
            },
            distortion,
            out_size,
            point_ids: im.point_ids.clone(),
        });
    }
    let mut warnings = Vec::new();
    if distorted > 0 {
        warnings.push(distortion_note(&list, distorted, opts.undistort));
    }
    if without_mask > 0 {
        warnings.push(format!(
            "{}: {without_mask} image(s) have no mask (masks/NAME.png): all their pixels are used",
            dir.join("masks").display()
        ));
    }
    let mesh_path = find_mesh(dir, opts, &[], true)?;
    Ok(CapturePlan {
        format: CaptureFormat::Colmap(encoding),
        frames,
        split: SplitSource::LlffHold {
            file: list.clone(),
            every,
        },
        list_path: list,
        mesh_path,
        applied_transform: None,
        ngp_box: None,
        points: model.points,
        ignored_keys: Vec::new(),
        warnings,
    })
}

/// `file_path` without `./` and without a known image extension.
pub(crate) fn frame_name(file_path: &str) -> String {
    let mut s = file_path;
    while let Some(rest) = s.strip_prefix("./") {
        s = rest;
    }
    if let Some((stem, ext)) = s.rsplit_once('.') {
        if TRIED_EXTENSIONS.iter().any(|e| e.eq_ignore_ascii_case(ext)) {
            return stem.to_string();
        }
    }
    s.to_string()
}

/// The proxy mesh: `--mesh`, else the first `mesh_path` in the transforms files, else the
/// first default name that exists (for COLMAP also its dense meshes).
fn find_mesh(
    dir: &Path,
    opts: &LoadOptions,
    files: &[&TransformsFile],
    colmap: bool,
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
    let extra: &[&str] = if colmap { &COLMAP_MESH_NAMES } else { &[] };
    DEFAULT_MESH_NAMES
        .iter()
        .chain(extra)
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
