//! The alignment check run before training: does the proxy mesh line up with the
//! photographs?
//!
//! Each view is scored at a reduced size (longest side [`CHECK_SIDE`]):
//! - **silhouette** (frames with an alpha channel or a mask): the intersection over union of
//!   the proxy's rasterised silhouette and the photograph's object (alpha above 0.5 inside
//!   the mask), over the pixels whose sample lay inside the photograph;
//! - **points** (a COLMAP model without alpha or masks): of the sparse points the image
//!   observes that project onto the proxy's silhouette, the fraction whose depth agrees with
//!   the proxy's surface there within [`POINT_DEPTH_TOLERANCE`] of the mesh's radius (a point
//!   that the photograph shows cannot lie behind or far in front of the surface that covers
//!   it). A view whose silhouette is empty scores 0; one with fewer than [`MIN_POINTS`] such
//!   points is not scored.
//!
//! The capture fails the check when the median training view scores below
//! [`THRESHOLD`]; single training views below it are reported, and dropped with
//! `--drop-misaligned`. With nerfstudio's `applied_transform` and `--mesh-space auto`, both
//! placements of the mesh are scored and the better one is kept.

use std::time::Instant;

use dnr_runtime::camera::Camera;
use dnr_runtime::gbuffer::GBuffer;
use dnr_runtime::raster::rasterize;
use dnr_runtime::scene::Scene;
use glam::{DVec3, Vec3};
use rayon::prelude::*;
use serde::Serialize;

use super::error::CaptureError;
use super::resample::source_position;
use super::{place_mesh, Capture, Frame, MeshSpace};

/// Longest side, in pixels, of the views the check rasterises.
pub const CHECK_SIDE: u32 = 256;

/// Score below which a view counts as misaligned, and the median below which the capture
/// fails. Measured (`examples/measure_alignment.rs`, docs/capture-format.md): aligned meshes,
/// exact or coarse, score 0.97 or more in every view of the sample, the Duck and the
/// phone-like capture; shifting the mesh by 10% of its radius gives 0.82, scaling it by 0.9
/// or 1.1 0.79 to 0.83, turning the Duck by 20 degrees 0.80, a coordinate-frame mistake
/// near 0.
pub const THRESHOLD: f64 = 0.85;

/// Depth agreement of a sparse point with the proxy surface, as a fraction of the mesh's
/// bounding radius.
pub const POINT_DEPTH_TOLERANCE: f64 = 0.05;

/// Fewest sparse points on the silhouette for a view to be scored by points.
pub const MIN_POINTS: usize = 8;

/// What the check may do.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct AlignmentOptions {
    /// Do not check (`--skip-alignment-check`).
    pub skip: bool,
    /// Drop training views that fail alone instead of stopping (`--drop-misaligned`).
    pub drop_misaligned: bool,
}

/// How a view was scored.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "camelCase")]
pub enum Method {
    /// Silhouette IoU against the alpha channel.
    Alpha,
    /// Silhouette IoU against the mask.
    Mask,
    /// Depth agreement of the sparse points.
    Points,
}

/// One view's score.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct ViewScore {
    /// Frame name.
    pub name: String,
    /// Held out for testing.
    pub test: bool,
    /// How it was scored.
    pub method: Method,
    /// IoU or point agreement in [0, 1].
    pub score: f64,
}

/// What the check measured and decided (in the bake report as `load.alignment`).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct AlignmentReport {
    /// Whether the check ran (false with `--skip-alignment-check` or when no view has alpha,
    /// a mask or sparse points).
    pub checked: bool,
    /// The threshold used.
    pub threshold: f64,
    /// Median score over the training views.
    pub median: Option<f64>,
    /// The five lowest-scoring training views, worst first.
    pub worst: Vec<ViewScore>,
    /// Every scored view (train and test).
    pub views: Vec<ViewScore>,
    /// Training views dropped by `--drop-misaligned`.
    pub dropped: Vec<String>,
    /// With `applied_transform`: the median of each placement tried, `(poses,
    /// reconstruction)`.
    pub placement_medians: Option<(f64, f64)>,
    /// Where the mesh was placed.
    pub mesh_space: MeshSpace,
    /// Wall-clock seconds of the check.
    pub seconds: f64,
}

/// Runs the check on `capture` (see the module documentation). May place the mesh (mesh
/// space auto) and drop training views (`drop_misaligned`); fails with
/// [`CaptureError::Misaligned`] naming the figures, the likely cause and the worst frames.
pub fn check(
    capture: &mut Capture,
    opts: &AlignmentOptions,
) -> Result<AlignmentReport, CaptureError> {
    let start = Instant::now();
    let mut report = AlignmentReport {
        threshold: THRESHOLD,
        mesh_space: capture.mesh_space,
        ..Default::default()
    };
    let mut warnings = Vec::new();
    if let Some(w) = ngp_box_warning(capture) {
        warnings.push(w);
    }
    let decide_space = capture.mesh_space == MeshSpace::Auto;
    if opts.skip {
        if decide_space {
            capture.mesh_space = MeshSpace::Poses;
            report.mesh_space = MeshSpace::Poses;
            warnings.push("alignment check skipped: the mesh is taken to be in the poses' coordinates (set --mesh-space reconstruction if it is in the original reconstruction's)".into());
        }
        capture.warnings.extend(warnings);
        report.seconds = start.elapsed().as_secs_f64();
        return Ok(report);
    }

    let mut views = score_all(capture, &capture.mesh);
    // Without an `applied_transform` there is only one placement: the poses' coordinates
    // (the loader settles that case already; a capture built by hand may not have).
    if decide_space && capture.applied_transform.is_none() {
        capture.mesh_space = MeshSpace::Poses;
        report.mesh_space = MeshSpace::Poses;
    }
    if let (true, Some(t)) = (decide_space, capture.applied_transform) {
        let mut placed = capture.mesh.clone();
        place_mesh(&mut placed, t);
        let other = score_all(capture, &placed);
        let (a, b) = (train_median(&views), train_median(&other));
        let space = match (a, b) {
            (Some(a), Some(b)) => {
                report.placement_medians = Some((a, b));
                if b > a {
                    capture.mesh = placed;
                    views = other;
                    MeshSpace::Reconstruction
                } else {
                    MeshSpace::Poses
                }
            }
            _ => {
                warnings.push("applied_transform: nothing to tell the mesh's coordinates by (no alpha, masks or sparse points): the mesh is taken to be in the poses' coordinates".into());
                MeshSpace::Poses
            }
        };
        capture.mesh_space = space;
        report.mesh_space = space;
    }

    let Some(median) = train_median(&views) else {
        warnings.push(
            "alignment not checked: no frame has an alpha channel, a mask or sparse points".into(),
        );
        capture.warnings.extend(warnings);
        report.seconds = start.elapsed().as_secs_f64();
        return Ok(report);
    };
    report.checked = true;
    report.median = Some(median);
    let mut train: Vec<&ViewScore> = views.iter().filter(|v| !v.test).collect();
    train.sort_by(|a, b| a.score.total_cmp(&b.score));
    report.worst = train.iter().take(5).map(|v| (*v).clone()).collect();
    let list = |vs: &[&ViewScore]| {
        vs.iter()
            .take(5)
            .map(|v| format!("{} ({:.2})", v.name, v.score))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let what = match train.first().map(|v| v.method) {
        Some(Method::Points) => "sparse-point depth agreement",
        _ => "silhouette IoU",
    };
    if median < THRESHOLD {
        return Err(CaptureError::Misaligned {
            dir: capture.dir.clone(),
            message: format!(
                "median {what} {median:.2} over {} training views is below {THRESHOLD}: the mesh does not line up with the photographs; likely causes: the mesh is in other coordinates than the poses (exported from another tool, or scaled), a missing applied_transform (nerfstudio), or instant-ngp's recentring and rescaling of the poses (colmap2nerf); worst frames: {}; --skip-alignment-check trains anyway",
                train.len(),
                list(&train)
            ),
        });
    }
    let failing: Vec<&ViewScore> = train
        .iter()
        .copied()
        .filter(|v| v.score < THRESHOLD)
        .collect();
    if !failing.is_empty() {
        if !opts.drop_misaligned {
            return Err(CaptureError::Misaligned {
                dir: capture.dir.clone(),
                message: format!(
                    "{} of {} training views fail alone ({what} below {THRESHOLD}, median {median:.2}): {}; a wrong pose or a bad mask is likely; --drop-misaligned trains without them, --skip-alignment-check trains anyway",
                    failing.len(),
                    train.len(),
                    list(&failing)
                ),
            });
        }
        let names: Vec<String> = failing.iter().map(|v| v.name.clone()).collect();
        capture.train.retain(|f| !names.contains(&f.name));
        if capture.train.is_empty() {
            return Err(CaptureError::Misaligned {
                dir: capture.dir.clone(),
                message: "--drop-misaligned dropped every training view".into(),
            });
        }
        warnings.push(format!(
            "--drop-misaligned: dropped {} training view(s): {}",
            names.len(),
            list(&failing)
        ));
        report.dropped = names;
    }
    let bad_test: Vec<&ViewScore> = views
        .iter()
        .filter(|v| v.test && v.score < THRESHOLD)
        .collect();
    if !bad_test.is_empty() {
        warnings.push(format!(
            "{} held-out view(s) do not line up with the mesh ({what} below {THRESHOLD}): {}; their error will be high",
            bad_test.len(),
            list(&bad_test)
        ));
    }
    report.views = views;
    capture.warnings.extend(warnings);
    report.seconds = start.elapsed().as_secs_f64();
    Ok(report)
}

/// Median score of the training views among `views`.
pub fn train_median(views: &[ViewScore]) -> Option<f64> {
    let mut s: Vec<f64> = views.iter().filter(|v| !v.test).map(|v| v.score).collect();
    if s.is_empty() {
        return None;
    }
    s.sort_by(f64::total_cmp);
    let n = s.len();
    Some(if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    })
}

/// Scores every frame (train and test) against `mesh` (placed in the poses' coordinates);
/// frames that cannot be scored are left out.
pub fn score_all(capture: &Capture, mesh: &Scene) -> Vec<ViewScore> {
    let radius = mesh_radius(mesh);
    let frames: Vec<(&Frame, bool)> = capture
        .train
        .iter()
        .map(|f| (f, false))
        .chain(capture.test.iter().map(|f| (f, true)))
        .collect();
    frames
        .par_iter()
        .filter_map(|&(f, test)| {
            let (method, score) = score_frame(capture, mesh, f, radius)?;
            Some(ViewScore {
                name: f.name.clone(),
                test,
                method,
                score,
            })
        })
        .collect()
}

/// The frame's camera scaled to the check size, and the scale.
fn small_camera(f: &Frame) -> (Camera, f64) {
    let (w, h) = (f.width(), f.height());
    let s = (CHECK_SIDE as f64 / w.max(h) as f64).min(1.0);
    let (sw, sh) = (
        ((w as f64 * s).round() as u32).max(1),
        ((h as f64 * s).round() as u32).max(1),
    );
    (f.record.resized(sw, sh).to_camera(), s)
}

fn score_frame(capture: &Capture, mesh: &Scene, f: &Frame, radius: f64) -> Option<(Method, f64)> {
    let (cam, _) = small_camera(f);
    let g = rasterize(mesh, &cam);
    if f.has_alpha || f.has_mask {
        let method = if f.has_alpha {
            Method::Alpha
        } else {
            Method::Mask
        };
        return Some((method, silhouette_iou(f, &cam, &g)));
    }
    if !f.point_ids.is_empty() && !capture.points.is_empty() {
        return points_score(capture, f, &cam, &g, radius).map(|s| (Method::Points, s));
    }
    None
}

/// IoU of the proxy's silhouette in `g` and the frame's object, at `g`'s size.
fn silhouette_iou(f: &Frame, cam: &Camera, g: &GBuffer) -> f64 {
    let (w, h) = (f.width() as usize, f.height() as usize);
    let (sw, sh) = (g.width, g.height);
    // Area fractions of object and of valid pixels per small pixel.
    let mut object = vec![0.0f32; sw * sh];
    let mut valid = vec![0.0f32; sw * sh];
    let mut count = vec![0.0f32; sw * sh];
    for y in 0..h {
        let sy = (y * sh / h).min(sh - 1);
        for x in 0..w {
            let sx = (x * sw / w).min(sw - 1);
            let i = y * w + x;
            let o = sy * sw + sx;
            count[o] += 1.0;
            if f.is_valid(i) || f.has_mask {
                // Inside the photograph (a mask's black pixels are background here).
                valid[o] += 1.0;
            }
            if f.is_valid(i) && f.alpha[i] > 0.5 {
                object[o] += 1.0;
            }
        }
    }
    // Pixels outside the photograph are known from the lens; a mask's zeros are not.
    let inside = |x: usize, y: usize| -> bool {
        if !f.undistorted {
            return true;
        }
        let k = super::resample::Intrinsics {
            fx: cam.fx as f64,
            fy: cam.fy as f64,
            cx: cam.cx as f64,
            cy: cam.cy as f64,
        };
        let (px, py) = source_position(&k, &f.distortion, x, y);
        px >= 0.0 && py >= 0.0 && px <= (sw - 1) as f64 && py <= (sh - 1) as f64
    };
    let (mut inter, mut union) = (0usize, 0usize);
    for y in 0..sh {
        for x in 0..sw {
            let o = y * sw + x;
            if count[o] == 0.0 || valid[o] < 0.5 * count[o] || !inside(x, y) {
                continue;
            }
            let s = g.coverage[o] > 0.5;
            let m = object[o] >= 0.5 * count[o];
            inter += (s && m) as usize;
            union += (s || m) as usize;
        }
    }
    if union == 0 {
        1.0
    } else {
        inter as f64 / union as f64
    }
}

/// Depth agreement of the frame's observed sparse points with the proxy surface.
fn points_score(
    capture: &Capture,
    f: &Frame,
    cam: &Camera,
    g: &GBuffer,
    radius: f64,
) -> Option<f64> {
    if g.coverage.iter().all(|&c| c == 0.0) {
        return Some(0.0);
    }
    let to_cam = f.record.cam_to_world.inverse();
    let tol = POINT_DEPTH_TOLERANCE * radius;
    let (mut on, mut agree) = (0usize, 0usize);
    for id in &f.point_ids {
        let Some(p) = capture.points.get(id) else {
            continue;
        };
        let c: DVec3 = to_cam.transform_point3(*p);
        if c.z >= -1e-9 {
            continue;
        }
        let depth = -c.z;
        let x = cam.fx as f64 * c.x / depth + cam.cx as f64;
        let y = cam.cy as f64 - cam.fy as f64 * c.y / depth;
        if !(x >= 0.0 && y >= 0.0 && x < g.width as f64 && y < g.height as f64) {
            continue;
        }
        let o = y as usize * g.width + x as usize;
        if g.coverage[o] <= 0.5 {
            continue;
        }
        on += 1;
        if (g.depth[o] as f64 - depth).abs() <= tol {
            agree += 1;
        }
    }
    (on >= MIN_POINTS).then(|| agree as f64 / on as f64)
}

/// World-space bounding box of a scene's vertices.
fn world_bounds(mesh: &Scene) -> (Vec3, Vec3) {
    let mut lo = Vec3::splat(f32::INFINITY);
    let mut hi = Vec3::splat(f32::NEG_INFINITY);
    for p in &mesh.primitives {
        for v in &p.positions {
            let w = p.world.transform_point3(*v);
            lo = lo.min(w);
            hi = hi.max(w);
        }
    }
    (lo, hi)
}

/// Half the diagonal of the mesh's world bounding box.
fn mesh_radius(mesh: &Scene) -> f64 {
    let (lo, hi) = world_bounds(mesh);
    (0.5 * (hi - lo).length() as f64).max(1e-9)
}

/// instant-ngp's `aabb_scale`: a mesh outside the box the poses were made for is suspect.
fn ngp_box_warning(capture: &Capture) -> Option<String> {
    let b = capture.ngp_box?;
    let (lo, hi) = world_bounds(&capture.mesh);
    let (blo, bhi) = b.bounds();
    let inside = (0..3).all(|k| lo[k] as f64 >= blo[k] && hi[k] as f64 <= bhi[k]);
    (!inside).then(|| {
        format!(
            "the mesh's bounding box {:?}..{:?} is not inside instant-ngp's scene box {blo:?}..{bhi:?} (aabb_scale {}): it may be in other coordinates than the poses",
            lo.to_array(),
            hi.to_array(),
            b.aabb_scale
        )
    })
}
