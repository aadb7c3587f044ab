//! UVs for the proxy mesh: overlap detection on the mesh's own UVs, and a generated atlas
//! (the `uvunwrap` crate: chart segmentation, LSCM + ARAP parameterisation, shape packing)
//! when it has none or they overlap.
//!
//! All primitives share one neural texture, so overlaps are measured, and charts packed,
//! over all of them together. Generated UVs replace the mesh's vertices (seam vertices are
//! duplicated), so the exporter writes them and the runtime and every viewer use the same
//! ones.

use std::path::Path;
use std::time::Instant;

use dnr_runtime::scene::Scene;
use glam::Vec2;
use serde::Serialize;

use super::error::CaptureError;
use super::UvMode;

/// Fraction of the covered UV area that may be covered more than once before `--uv auto`
/// replaces the mesh's UVs. Measured on [`MEASURE_SIDE`]: the sample sphere's UVs overlap on
/// 0.00% of their area, generated atlases on 0.00%, the shared Duck's authored UVs on 94%
/// (its mirrored halves share texels; 89% on the coarse Duck).
pub const OVERLAP_LIMIT: f64 = 0.01;

/// Side of the grid the overlap and texel-use figures are measured on (texel centres).
pub const MEASURE_SIDE: usize = 1024;

/// Side of the generated atlas page in texels; padding is 4 of them, so charts stay apart
/// at the 512-texel level too.
pub const ATLAS_PAGE: u32 = 1024;

/// Empty texels around each generated chart at [`ATLAS_PAGE`].
pub const ATLAS_PADDING: u32 = 4;

/// What the UV step found and did (in the bake report as `load.uv`).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct UvReport {
    /// Whether the UVs were generated.
    pub generated: bool,
    /// Why (or why not).
    pub reason: String,
    /// Of the mesh's own UVs: the fraction of their covered area covered more than once
    /// (None when it has none).
    pub overlap_fraction: Option<f64>,
    /// Triangles of the mesh.
    pub triangles: usize,
    /// Charts of the generated atlas.
    pub charts: Option<u32>,
    /// Fraction of the texture the final UVs cover.
    pub texel_use: f64,
    /// Seconds spent measuring and generating.
    pub seconds: f64,
}

impl UvReport {
    /// A line for the user when UVs were replaced or are questionable.
    pub fn warning(&self) -> Option<String> {
        if self.generated {
            Some(format!(
                "generated UVs for the mesh ({}): {} charts, {:.0}% of the texture used, {:.1} s",
                self.reason,
                self.charts.unwrap_or(0),
                100.0 * self.texel_use,
                self.seconds
            ))
        } else {
            match self.overlap_fraction {
                Some(f) if f > OVERLAP_LIMIT => Some(format!(
                    "the mesh's UVs overlap on {:.1}% of their area (kept: --uv keep); texels there are shared by several surface points",
                    100.0 * f
                )),
                _ => None,
            }
        }
    }
}

/// Per texel centre of a `side x side` grid, how many UV triangles cover it (strict interior,
/// saturating at 255). UVs outside [0, 1] wrap, as the texture repeats. Returns the counts
/// and whether some triangle spans the whole grid (it then overlaps itself).
fn coverage(scene: &Scene, side: usize) -> (Vec<u8>, bool) {
    let mut count = vec![0u8; side * side];
    let mut spans = false;
    let s = side as f64;
    for p in &scene.primitives {
        if p.uvs.len() != p.positions.len() {
            continue;
        }
        for t in p.indices.chunks_exact(3) {
            let q: [[f64; 2]; 3] = std::array::from_fn(|k| {
                let uv = p.uvs[t[k] as usize];
                [uv.x as f64 * s, uv.y as f64 * s]
            });
            let area = (q[1][0] - q[0][0]) * (q[2][1] - q[0][1])
                - (q[2][0] - q[0][0]) * (q[1][1] - q[0][1]);
            if area.abs() < 1e-12 {
                continue;
            }
            let sign = area.signum();
            let min = |k: usize| q.iter().map(|v| v[k]).fold(f64::INFINITY, f64::min);
            let max = |k: usize| q.iter().map(|v| v[k]).fold(f64::NEG_INFINITY, f64::max);
            let (x0, x1) = (min(0).floor() as i64, max(0).ceil() as i64);
            let (y0, y1) = (min(1).floor() as i64, max(1).ceil() as i64);
            if x1 - x0 > side as i64 || y1 - y0 > side as i64 {
                spans = true;
                continue;
            }
            for y in y0..y1 {
                for x in x0..x1 {
                    let (cx, cy) = (x as f64 + 0.5, y as f64 + 0.5);
                    let e = |a: [f64; 2], b: [f64; 2]| {
                        sign * ((b[0] - a[0]) * (cy - a[1]) - (b[1] - a[1]) * (cx - a[0]))
                    };
                    if e(q[0], q[1]) > 0.0 && e(q[1], q[2]) > 0.0 && e(q[2], q[0]) > 0.0 {
                        let i = y.rem_euclid(side as i64) as usize * side
                            + x.rem_euclid(side as i64) as usize;
                        count[i] = count[i].saturating_add(1);
                    }
                }
            }
        }
    }
    (count, spans)
}

/// Of the texel centres some UV triangle covers, the fraction covered more than once (1
/// when a triangle spans the whole texture); None when no primitive has UVs.
pub fn overlap_fraction(scene: &Scene) -> Option<f64> {
    if scene
        .primitives
        .iter()
        .all(|p| p.uvs.is_empty() || p.indices.is_empty())
    {
        return None;
    }
    let (count, spans) = coverage(scene, MEASURE_SIDE);
    if spans {
        return Some(1.0);
    }
    let covered = count.iter().filter(|&&c| c > 0).count();
    let twice = count.iter().filter(|&&c| c > 1).count();
    Some(if covered == 0 {
        0.0
    } else {
        twice as f64 / covered as f64
    })
}

/// Fraction of the texture's texel centres some UV triangle covers.
pub fn texel_use(scene: &Scene) -> f64 {
    let (count, _) = coverage(scene, MEASURE_SIDE);
    count.iter().filter(|&&c| c > 0).count() as f64 / count.len() as f64
}

/// Makes sure every primitive of `scene` has usable UVs, by `mode` (see [`UvMode`]). A mesh
/// that needs an atlas and has more than `max_triangles` triangles is refused.
pub fn ensure_uvs(
    scene: &mut Scene,
    path: &Path,
    mode: UvMode,
    max_triangles: usize,
) -> Result<UvReport, CaptureError> {
    let start = Instant::now();
    let triangles: usize = scene.primitives.iter().map(|p| p.indices.len() / 3).sum();
    let missing = scene
        .primitives
        .iter()
        .any(|p| !p.indices.is_empty() && p.uvs.len() != p.positions.len());
    let overlap = if missing {
        None
    } else {
        overlap_fraction(scene)
    };
    let reason = match (mode, missing, overlap) {
        (UvMode::Keep, true, _) => {
            return Err(CaptureError::MeshNoUvs {
                path: path.to_path_buf(),
                what: "mesh".into(),
            })
        }
        (UvMode::Keep, false, _) => None,
        (UvMode::Generate, _, _) => Some("--uv generate".to_string()),
        (UvMode::Auto, true, _) => Some("the mesh has no UVs".to_string()),
        (UvMode::Auto, false, Some(f)) if f > OVERLAP_LIMIT => Some(format!(
            "its UVs overlap on {:.1}% of their area",
            100.0 * f
        )),
        (UvMode::Auto, false, _) => None,
    };
    let mut report = UvReport {
        overlap_fraction: overlap,
        triangles,
        ..Default::default()
    };
    match reason {
        None => {
            report.reason = format!(
                "kept the mesh's UVs ({:.2}% overlap)",
                100.0 * overlap.unwrap_or(0.0)
            );
        }
        Some(r) => {
            if triangles > max_triangles {
                return Err(CaptureError::MeshTooLarge {
                    path: path.to_path_buf(),
                    message: format!(
                        "generating UVs ({r}): the mesh has {triangles} triangles, over the limit of {max_triangles} for unwrapping; decimate it first (e.g. Blender's Decimate modifier, MeshLab's quadric edge collapse) or raise --limit max_unwrap_triangles"
                    ),
                });
            }
            report.charts = Some(generate(scene, path)?);
            report.generated = true;
            report.reason = r;
        }
    }
    report.texel_use = texel_use(scene);
    report.seconds = start.elapsed().as_secs_f64();
    Ok(report)
}

/// Replaces every primitive's UVs with one shared generated atlas (charts sized by world
/// area); returns the chart count.
pub fn generate(scene: &mut Scene, path: &Path) -> Result<u32, CaptureError> {
    let fail = |message: String| CaptureError::UvAtlas {
        path: path.to_path_buf(),
        message,
    };
    let world: Vec<Vec<[f32; 3]>> = scene
        .primitives
        .iter()
        .map(|p| {
            p.positions
                .iter()
                .map(|&v| p.world.transform_point3(v).to_array())
                .collect()
        })
        .collect();
    let inputs: Vec<uvunwrap::MeshInput<'_>> = world
        .iter()
        .zip(&scene.primitives)
        .map(|(pos, p)| uvunwrap::MeshInput::new(pos, &p.indices))
        .collect();
    let options = uvunwrap::Options {
        padding: ATLAS_PADDING,
        density: uvunwrap::Density::Auto {
            page_size: ATLAS_PAGE,
        },
        ..Default::default()
    };
    let atlas = uvunwrap::generate(&inputs, &options).map_err(|e| fail(e.to_string()))?;
    if atlas.page_count != 1 {
        return Err(fail(format!(
            "the {} charts need {} atlas pages; one texture holds one",
            atlas.chart_count, atlas.page_count
        )));
    }
    for (p, out) in scene.primitives.iter_mut().zip(&atlas.meshes) {
        let positions = out
            .vertices
            .iter()
            .map(|v| p.positions[v.xref as usize])
            .collect();
        // uvunwrap's (0, 0) is the corner of texel row 0 with v growing down the rows: the
        // glTF convention.
        let uvs = out.vertices.iter().map(|v| Vec2::from(v.uv)).collect();
        p.positions = positions;
        p.uvs = uvs;
        p.indices = out.indices.clone();
    }
    Ok(atlas.chart_count)
}
