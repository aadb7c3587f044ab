//! The project's single triangle rasteriser: draws a [`Scene`] from a [`Camera`] into a
//! [`GBuffer`] (uv, coverage, primitive/triangle ids, depth, local-space view direction).
//!
//! Pipeline, and why each step is built the way it is:
//!
//! 1. **Vertex transform** (f64): each vertex goes to camera space once per call, so every
//!    triangle that shares a vertex sees bit-identical coordinates.
//! 2. **Clipping** against the near plane `z = -near` and a guard band of
//!    [`GUARD_BAND`] pixels around the image (planes through the eye). Triangles crossing
//!    a plane are clipped (Sutherland–Hodgman, then fanned), never dropped or mirrored. The
//!    intersection on an edge is computed from its endpoints in a canonical (lexicographic)
//!    order, so the two triangles sharing a clipped edge get the same new vertex and stay
//!    watertight. `near = NEAR_RELATIVE (1e-5) * distance from the eye to the nearest
//!    vertex`. Depth is stored linearly (no 1/z z-buffer), so a tiny near costs no depth
//!    precision; the near plane only has to keep `1/z` finite and the clip well conditioned
//!    in f64, and the guard band (not the near plane) bounds screen coordinates. Tying it to
//!    the nearest vertex rather than to the scene's bounding radius keeps a far outlier
//!    vertex (a huge ground plane, a stray point at 1e30) from pushing the near plane into
//!    the object: only geometry within 1e-5 of the nearest vertex distance is cut, i.e. an
//!    eye practically touching the surface.
//! 3. **Snapping** to fixed point with [`SUBPIXEL_BITS`] fractional bits. After the guard
//!    band clip every coordinate is below 2^21 pixels, so edge functions are exact in i64
//!    (|E| < 2^61). Exact edge functions plus a top-left fill rule mean a pixel centre on a
//!    shared edge or vertex belongs to exactly one of the triangles around it: a closed
//!    mesh has no cracks and no double hits. (f64 edge functions are not enough: rounding
//!    can make the sign pattern around a shared vertex geometrically impossible.)
//! 4. **Binning** into horizontal bands of [`BAND_ROWS`] rows; bands are drawn in parallel
//!    with rayon, each one walking its triangles in submission order, so the result does
//!    not depend on the number of threads. The depth test keeps the nearest fragment
//!    (strictly nearer wins; ties keep the earlier triangle).
//! 5. **Resolve**: the depth pass stores perspective-correct barycentrics; uv and the local
//!    position (hence the view direction) are interpolated once per pixel afterwards.
//!
//! Back faces are drawn (proxies can be open). Triangles with a non-finite vertex, an index
//! out of range, or zero snapped area are skipped.

use glam::{DMat4, DVec3, DVec4, Vec3};
use rayon::prelude::*;

use crate::camera::Camera;
use crate::gbuffer::{GBuffer, NONE};
use crate::scene::{Primitive, Scene};

/// Fractional bits of the fixed-point screen coordinates (1/256 pixel).
pub const SUBPIXEL_BITS: u32 = 8;
/// Guard band around the image in pixels; geometry beyond it is clipped away in 3D.
pub const GUARD_BAND: f64 = (1u64 << 20) as f64;
/// Largest image side the rasteriser draws (larger cameras give an empty 0 x 0 G-buffer):
/// keeps image plus guard band inside the range where edge functions are exact in i64.
pub const MAX_IMAGE_SIDE: usize = 1 << 20;
/// Near plane distance as a fraction of the distance from the eye to the nearest vertex.
pub const NEAR_RELATIVE: f64 = 1e-5;
/// Floor of the near-plane distance (keeps 1/z finite when the eye sits on a vertex).
pub const MIN_NEAR: f64 = 1e-30;
/// Rows per parallel band.
pub const BAND_ROWS: usize = 16;

const ONE: i64 = 1 << SUBPIXEL_BITS;
const HALF: i64 = ONE / 2;
/// Any snapped coordinate must be below this many pixels (keeps edge functions in i64).
const COORD_LIMIT: f64 = (1u64 << 21) as f64;
/// Triangles per parallel setup task.
const SETUP_CHUNK: usize = 2048;

/// Rasterises `scene` as seen by `camera` into a new G-buffer of the camera's size.
pub fn rasterize(scene: &Scene, camera: &Camera) -> GBuffer {
    let mut g = GBuffer::default();
    rasterize_into(scene, camera, &mut g);
    g
}

/// Like [`rasterize`], reusing `gbuf`'s allocations (it is resized to the camera's size).
///
/// A camera with a side above [`MAX_IMAGE_SIDE`] gives an empty 0 x 0 G-buffer; one with
/// non-finite pose or non-positive focal lengths an all-uncovered one.
pub fn rasterize_into(scene: &Scene, camera: &Camera, gbuf: &mut GBuffer) {
    let (w, h) = (camera.width as usize, camera.height as usize);
    if w > MAX_IMAGE_SIDE || h > MAX_IMAGE_SIDE {
        gbuf.reset(0, 0);
        return;
    }
    let Some(prep) = Prepared::new(scene, camera) else {
        gbuf.reset(w, h);
        return;
    };
    // Every pixel is rewritten below (depth and ids cleared per band, the rest by the
    // resolve), so a same-sized buffer needs no serial clear.
    if (gbuf.width, gbuf.height) != (w, h) || !gbuf.is_consistent() {
        gbuf.reset(w, h);
    }
    let bands = gbuffer_bands(gbuf, w);
    let bins = &prep.bins;
    bands.into_par_iter().for_each(|mut band| {
        band.depth.fill(0.0); // holds 1/depth until the resolve
        band.prim.fill(NONE);
        let list = &bins.items[bins.offsets[band.index]..bins.offsets[band.index + 1]];
        for &t in list {
            draw_depth(&prep.tris[t as usize], &mut band, w);
        }
        resolve(scene, &prep.prims, &mut band);
    });
}

/// Per-pixel counts of triangles covering each pixel centre, ignoring depth: `front` counts
/// triangles seen counter-clockwise (glTF front faces), `back` the others. A debugging and
/// testing aid that runs the same setup, clipping, binning and coverage test as
/// [`rasterize`]; for a closed mesh `front == back` at every pixel the near plane does not
/// cut.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct CoverageCounts {
    /// Image width.
    pub width: usize,
    /// Image height.
    pub height: usize,
    /// Front-facing hits per pixel (row-major).
    pub front: Vec<u32>,
    /// Back-facing hits per pixel (row-major).
    pub back: Vec<u32>,
}

/// Counts coverage hits per pixel; see [`CoverageCounts`]. Empty (0 x 0) for a camera side
/// above [`MAX_IMAGE_SIDE`].
pub fn coverage_counts(scene: &Scene, camera: &Camera) -> CoverageCounts {
    let (w, h) = (camera.width as usize, camera.height as usize);
    if w > MAX_IMAGE_SIDE || h > MAX_IMAGE_SIDE {
        return CoverageCounts::default();
    }
    let mut c = CoverageCounts {
        width: w,
        height: h,
        front: vec![0; w * h],
        back: vec![0; w * h],
    };
    let Some(prep) = Prepared::new(scene, camera) else {
        return c;
    };
    let rows = BAND_ROWS * w;
    c.front
        .par_chunks_mut(rows)
        .zip(c.back.par_chunks_mut(rows))
        .enumerate()
        .for_each(|(bi, (front, back))| {
            let list = &prep.bins.items[prep.bins.offsets[bi]..prep.bins.offsets[bi + 1]];
            let y0 = bi * BAND_ROWS;
            let y1 = y0 + front.len() / w - 1;
            for &t in list {
                let t = &prep.tris[t as usize];
                let counts = if t.front { &mut *front } else { &mut *back };
                for_each_inside(t, y0, y1, |px, py, _| counts[(py - y0) * w + px] += 1);
            }
        });
    c
}

/// One parallel work unit: a band of rows of every G-buffer plane.
struct Band<'a> {
    index: usize,
    y0: usize,
    y1: usize,
    uv: &'a mut [[f32; 2]],
    coverage: &'a mut [f32],
    prim: &'a mut [u32],
    tri: &'a mut [u32],
    depth: &'a mut [f32],
    view_dir: &'a mut [[f32; 3]],
}

fn gbuffer_bands(g: &mut GBuffer, w: usize) -> Vec<Band<'_>> {
    let rows = BAND_ROWS * w.max(1);
    let mut bands = Vec::with_capacity(g.len().div_ceil(rows));
    let iter =
        g.uv.chunks_mut(rows)
            .zip(g.coverage.chunks_mut(rows))
            .zip(g.prim.chunks_mut(rows))
            .zip(g.tri.chunks_mut(rows))
            .zip(g.depth.chunks_mut(rows))
            .zip(g.view_dir.chunks_mut(rows));
    for (index, (((((uv, coverage), prim), tri), depth), view_dir)) in iter.enumerate() {
        let y0 = index * BAND_ROWS;
        bands.push(Band {
            index,
            y0,
            y1: y0 + uv.len() / w - 1,
            uv,
            coverage,
            prim,
            tri,
            depth,
            view_dir,
        });
    }
    bands
}

/// A triangle ready to draw: snapped, oriented with positive area, bbox clamped to the image.
#[derive(Clone, Copy, Debug)]
struct SetupTri {
    /// Fixed-point screen positions (x right, y down).
    v: [[i64; 2]; 3],
    /// Minimum edge value counted as inside: 0 on top-left edges, 1 elsewhere.
    min_e: [i64; 3],
    /// `(1 / view depth at vertex k) / (twice the area)`: the interpolated 1/depth at a pixel
    /// is `sum_k e_k * kz[k]` for the pixel's edge values e_k.
    kz: [f64; 3],
    /// Barycentric coordinates, with respect to the original triangle, of each vertex
    /// (identity unless clipped; rows swapped with the vertices when re-oriented).
    bary: [[f32; 3]; 3],
    prim: u32,
    tri: u32,
    /// Inclusive pixel bounds [x0, x1, y0, y1].
    bbox: [usize; 4],
    /// Counter-clockwise on screen (glTF front face).
    front: bool,
}

/// Per-primitive data the resolve pass needs.
struct PrimInfo {
    has_uvs: bool,
    /// Eye position in the primitive's local space (None when the world matrix is singular).
    eye_local: Option<Vec3>,
}

/// Triangle indices per band in CSR form.
struct Bins {
    offsets: Vec<usize>,
    items: Vec<u32>,
}

struct Prepared {
    tris: Vec<SetupTri>,
    prims: Vec<PrimInfo>,
    bins: Bins,
}

/// Camera constants shared by setup.
struct Frame {
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    w: usize,
    h: usize,
    /// Clip planes in camera space: inside where `dot(n.xyz, p) + n.w >= 0`.
    planes: [DVec4; 5],
}

impl Prepared {
    fn new(scene: &Scene, camera: &Camera) -> Option<Prepared> {
        let (w, h) = (camera.width as usize, camera.height as usize);
        let (fx, fy, cx, cy) = (
            camera.fx as f64,
            camera.fy as f64,
            camera.cx as f64,
            camera.cy as f64,
        );
        let intrinsics_ok = fx > 0.0
            && fy > 0.0
            && fx.is_finite()
            && fy.is_finite()
            && cx.is_finite()
            && cy.is_finite();
        if w == 0 || h == 0 || w > MAX_IMAGE_SIDE || h > MAX_IMAGE_SIDE || !intrinsics_ok {
            return None;
        }
        let c2w = camera.cam_to_world.as_dmat4();
        let view = c2w.inverse();
        if !view.is_finite() {
            return None;
        }
        let eye = c2w.w_axis.truncate();

        // Every vertex to camera space once (shared vertices stay bit-identical).
        let cams: Vec<Vec<DVec3>> = scene
            .primitives
            .iter()
            .map(|p| camera_space(&view, p))
            .collect();
        let near = near_from_nearest(nearest_vertex_distance(&cams));

        let g = GUARD_BAND;
        let (wf, hf) = (w as f64, h as f64);
        let frame = Frame {
            fx,
            fy,
            cx,
            cy,
            w,
            h,
            planes: [
                DVec4::new(0.0, 0.0, -1.0, -near),
                DVec4::new(fx, 0.0, -(cx + g), 0.0),
                DVec4::new(-fx, 0.0, -(wf + g - cx), 0.0),
                DVec4::new(0.0, -fy, -(cy + g), 0.0),
                DVec4::new(0.0, fy, -(hf + g - cy), 0.0),
            ],
        };

        let mut prims = Vec::with_capacity(scene.primitives.len());
        let mut chunks: Vec<Vec<SetupTri>> = Vec::new();
        for (pi, (p, cam)) in scene.primitives.iter().zip(&cams).enumerate() {
            let inv = p.world.as_dmat4().inverse();
            let eye_local = inv
                .is_finite()
                .then(|| inv.transform_point3(eye).as_vec3())
                .filter(|e| e.is_finite());
            prims.push(PrimInfo {
                has_uvs: p.has_uvs(),
                eye_local,
            });
            let Ok(pi) = u32::try_from(pi) else { break };
            let frame = &frame;
            let n_tris = p.indices.len() / 3;
            let part: Vec<Vec<SetupTri>> = (0..n_tris.div_ceil(SETUP_CHUNK))
                .into_par_iter()
                .map(|ci| {
                    let mut out = Vec::new();
                    let end = ((ci + 1) * SETUP_CHUNK).min(n_tris);
                    for t in ci * SETUP_CHUNK..end {
                        let Ok(ti) = u32::try_from(t) else { break };
                        let ix = &p.indices[3 * t..3 * t + 3];
                        let (Some(&a), Some(&b), Some(&c)) = (
                            cam.get(ix[0] as usize),
                            cam.get(ix[1] as usize),
                            cam.get(ix[2] as usize),
                        ) else {
                            continue;
                        };
                        setup_triangle(frame, [a, b, c], pi, ti, &mut out);
                    }
                    out
                })
                .collect();
            chunks.extend(part);
        }
        let tris: Vec<SetupTri> = chunks.concat();
        let bins = bin(&tris, h);
        Some(Prepared { tris, prims, bins })
    }
}

/// A primitive's vertices in camera space (f64).
fn camera_space(view: &DMat4, p: &Primitive) -> Vec<DVec3> {
    let mv = *view * p.world.as_dmat4();
    let mut cam = vec![DVec3::ZERO; p.positions.len()];
    cam.par_chunks_mut(4096)
        .zip(p.positions.par_chunks(4096))
        .for_each(|(c, v)| {
            for (c, v) in c.iter_mut().zip(v) {
                *c = mv.transform_point3(v.as_dvec3());
            }
        });
    cam
}

/// Distance from the eye to the nearest finite vertex (infinity when there is none).
fn nearest_vertex_distance(cams: &[Vec<DVec3>]) -> f64 {
    cams.par_iter()
        .flat_map_iter(|c| c.iter())
        .map(|p| {
            if p.is_finite() {
                p.length()
            } else {
                f64::INFINITY
            }
        })
        .reduce(|| f64::INFINITY, f64::min)
}

fn near_from_nearest(d: f64) -> f64 {
    if d.is_finite() {
        (NEAR_RELATIVE * d).max(MIN_NEAR)
    } else {
        MIN_NEAR
    }
}

/// The near-plane distance [`rasterize`] uses for this scene and camera:
/// `NEAR_RELATIVE` times the distance from the eye to the nearest finite vertex, at least
/// 1e-30. None when the camera is unusable (non-finite pose).
pub fn near_distance(scene: &Scene, camera: &Camera) -> Option<f64> {
    let view = camera.cam_to_world.as_dmat4().inverse();
    if !view.is_finite() {
        return None;
    }
    let cams: Vec<Vec<DVec3>> = scene
        .primitives
        .iter()
        .map(|p| camera_space(&view, p))
        .collect();
    Some(near_from_nearest(nearest_vertex_distance(&cams)))
}

fn bin(tris: &[SetupTri], h: usize) -> Bins {
    let n_bands = h.div_ceil(BAND_ROWS);
    let mut offsets = vec![0usize; n_bands + 1];
    for t in tris {
        for b in t.bbox[2] / BAND_ROWS..=t.bbox[3] / BAND_ROWS {
            offsets[b + 1] += 1;
        }
    }
    for b in 0..n_bands {
        offsets[b + 1] += offsets[b];
    }
    let mut fill = offsets.clone();
    let mut items = vec![0u32; offsets[n_bands]];
    for (i, t) in tris.iter().enumerate() {
        for b in t.bbox[2] / BAND_ROWS..=t.bbox[3] / BAND_ROWS {
            items[fill[b]] = i as u32;
            fill[b] += 1;
        }
    }
    Bins { offsets, items }
}

/// A polygon vertex during clipping: camera-space position and barycentrics with respect to
/// the original triangle.
#[derive(Clone, Copy, Default)]
struct ClipVert {
    p: DVec3,
    b: DVec3,
}

/// At most 3 + one vertex per clip plane.
const MAX_POLY: usize = 8;

fn setup_triangle(frame: &Frame, p: [DVec3; 3], prim: u32, tri: u32, out: &mut Vec<SetupTri>) {
    if !(p[0].is_finite() && p[1].is_finite() && p[2].is_finite()) {
        return;
    }
    let mut any_out = [false; 5];
    for (k, pl) in frame.planes.iter().enumerate() {
        let d = [dist(pl, p[0]), dist(pl, p[1]), dist(pl, p[2])];
        if d.iter().all(|&d| d < 0.0) {
            return; // entirely outside one plane
        }
        any_out[k] = d.iter().any(|&d| d < 0.0);
    }
    let mut poly = [ClipVert::default(); MAX_POLY];
    let mut n = 3;
    poly[0] = ClipVert {
        p: p[0],
        b: DVec3::X,
    };
    poly[1] = ClipVert {
        p: p[1],
        b: DVec3::Y,
    };
    poly[2] = ClipVert {
        p: p[2],
        b: DVec3::Z,
    };
    for (k, pl) in frame.planes.iter().enumerate() {
        if any_out[k] {
            n = clip_polygon(&mut poly, n, pl);
            if n < 3 {
                return;
            }
        }
    }
    // Project and snap.
    let mut fixed = [[0i64; 2]; MAX_POLY];
    let mut inv_z = [0f64; MAX_POLY];
    for i in 0..n {
        let c = poly[i].p;
        let iz = 1.0 / -c.z;
        let x = frame.cx + frame.fx * c.x * iz;
        let y = frame.cy - frame.fy * c.y * iz;
        if !(x.abs() < COORD_LIMIT && y.abs() < COORD_LIMIT && iz.is_finite() && iz > 0.0) {
            return; // only reachable with absurd intrinsics; the guard band bounds the rest
        }
        fixed[i] = [
            (x * ONE as f64).round() as i64,
            (y * ONE as f64).round() as i64,
        ];
        inv_z[i] = iz;
    }
    for i in 1..n - 1 {
        let ids = [0, i, i + 1];
        emit(
            frame,
            &ids.map(|k| fixed[k]),
            &ids.map(|k| inv_z[k]),
            &ids.map(|k| poly[k].b),
            prim,
            tri,
            out,
        );
    }
}

#[inline]
fn dist(pl: &DVec4, p: DVec3) -> f64 {
    pl.x * p.x + pl.y * p.y + pl.z * p.z + pl.w
}

/// Sutherland–Hodgman against one plane, in place; returns the new vertex count.
fn clip_polygon(poly: &mut [ClipVert; MAX_POLY], n: usize, pl: &DVec4) -> usize {
    let src = *poly;
    let mut m = 0;
    for i in 0..n {
        let a = src[i];
        let b = src[(i + 1) % n];
        let (da, db) = (dist(pl, a.p), dist(pl, b.p));
        if da >= 0.0 && m < MAX_POLY {
            poly[m] = a;
            m += 1;
        }
        if (da >= 0.0) != (db >= 0.0) && m < MAX_POLY {
            poly[m] = intersect(a, b, da, db);
            m += 1;
        }
    }
    m
}

/// Edge–plane intersection computed with the endpoints in lexicographic order of position,
/// so both triangles sharing the edge produce the bit-identical point.
fn intersect(a: ClipVert, b: ClipVert, da: f64, db: f64) -> ClipVert {
    let a_first = (a.p.x, a.p.y, a.p.z) <= (b.p.x, b.p.y, b.p.z);
    let (a, b, da, db) = if a_first {
        (a, b, da, db)
    } else {
        (b, a, db, da)
    };
    let t = da / (da - db);
    ClipVert {
        p: a.p + (b.p - a.p) * t,
        b: a.b + (b.b - a.b) * t,
    }
}

/// Edge function of edge a->b at p: twice the signed area of (a, b, p). Exact: every
/// coordinate is below 2^29 in magnitude, so each product is below 2^60.
#[inline]
fn edge(a: [i64; 2], b: [i64; 2], p: [i64; 2]) -> i64 {
    (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0])
}

/// Top-left rule for the positive orientation (y down): an edge whose interior side is
/// below a horizontal edge (top edge: dy == 0, dx > 0) or to the right (left edge: dy < 0)
/// owns the pixel centres lying exactly on it. Of an edge's two directions exactly one is
/// top-left, so a shared edge's centres go to exactly one side.
#[inline]
fn is_top_left(a: [i64; 2], b: [i64; 2]) -> bool {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    dy < 0 || (dy == 0 && dx > 0)
}

fn emit(
    frame: &Frame,
    v: &[[i64; 2]; 3],
    iz: &[f64; 3],
    b: &[DVec3; 3],
    prim: u32,
    tri: u32,
    out: &mut Vec<SetupTri>,
) {
    let area = edge(v[0], v[1], v[2]);
    if area == 0 {
        return;
    }
    // Negative area in y-down coordinates is counter-clockwise as seen: a glTF front face.
    let front = area < 0;
    let (v, iz, b, area) = if front {
        (
            [v[0], v[2], v[1]],
            [iz[0], iz[2], iz[1]],
            [b[0], b[2], b[1]],
            -area,
        )
    } else {
        (*v, *iz, *b, area)
    };
    let (minx, maxx) = (
        v[0][0].min(v[1][0]).min(v[2][0]),
        v[0][0].max(v[1][0]).max(v[2][0]),
    );
    let (miny, maxy) = (
        v[0][1].min(v[1][1]).min(v[2][1]),
        v[0][1].max(v[1][1]).max(v[2][1]),
    );
    // Pixel px's centre is px * ONE + HALF; keep the pixels whose centre is in the box.
    let first = |lo: i64| -((HALF - lo).div_euclid(ONE));
    let last = |hi: i64| (hi - HALF).div_euclid(ONE);
    let x0 = first(minx).max(0);
    let x1 = last(maxx).min(frame.w as i64 - 1);
    let y0 = first(miny).max(0);
    let y1 = last(maxy).min(frame.h as i64 - 1);
    if x0 > x1 || y0 > y1 {
        return;
    }
    // Edge k is opposite vertex k.
    let ed = [(1, 2), (2, 0), (0, 1)];
    let min_e = ed.map(|(i, j)| if is_top_left(v[i], v[j]) { 0 } else { 1 });
    out.push(SetupTri {
        v,
        min_e,
        kz: iz.map(|z| z / area as f64),
        bary: b.map(|d| [d.x as f32, d.y as f32, d.z as f32]),
        prim,
        tri,
        bbox: [x0 as usize, x1 as usize, y0 as usize, y1 as usize],
        front,
    });
}

/// Calls `f(px, py, [e0, e1, e2])` for every pixel of rows `y0..=y1` whose centre the
/// triangle covers (edge values exact, vertex k weighted by e_k / area2).
#[inline]
fn for_each_inside(t: &SetupTri, y0: usize, y1: usize, mut f: impl FnMut(usize, usize, [i64; 3])) {
    let ys = t.bbox[2].max(y0);
    let ye = t.bbox[3].min(y1);
    let (x0, x1) = (t.bbox[0], t.bbox[1]);
    let ed = [(1usize, 2usize), (2, 0), (0, 1)];
    // Stepping one pixel right adds -(dy) * ONE to each edge function; exact in i64.
    let step = ed.map(|(i, j)| -(t.v[j][1] - t.v[i][1]) * ONE);
    // Exclusive ranges: `..=` loops carry an extra exhaustion flag in the hot loop.
    for py in ys..ye + 1 {
        let p = [x0 as i64 * ONE + HALF, py as i64 * ONE + HALF];
        let mut e = ed.map(|(i, j)| edge(t.v[i], t.v[j], p));
        for px in x0..x1 + 1 {
            if (e[0] - t.min_e[0]) | (e[1] - t.min_e[1]) | (e[2] - t.min_e[2]) >= 0 {
                f(px, py, e);
            }
            e[0] += step[0];
            e[1] += step[1];
            e[2] += step[2];
        }
    }
}

/// Depth pass: keeps the nearest fragment, storing 1/depth in the depth plane, the ids, and
/// the perspective-correct barycentrics (b1, b2) of the original triangle times 1/depth in
/// the uv plane, for [`resolve`] to normalise.
fn draw_depth(t: &SetupTri, band: &mut Band, w: usize) {
    let y0 = band.y0;
    let depth = &mut *band.depth;
    let uv = &mut *band.uv;
    let prim = &mut *band.prim;
    let tri = &mut *band.tri;
    for_each_inside(t, y0, band.y1, |px, py, e| {
        // Perspective-correct weights, not yet normalised: w_k = e_k * kz_k, and their sum is
        // 1/depth. The test compares 1/depth (nearer = larger), which needs no division.
        let wgt = [
            e[0] as f64 * t.kz[0],
            e[1] as f64 * t.kz[1],
            e[2] as f64 * t.kz[2],
        ];
        let inv_depth = (wgt[0] + wgt[1] + wgt[2]) as f32;
        let i = (py - y0) * w + px;
        if inv_depth > depth[i] {
            depth[i] = inv_depth;
            let (s0, s1, s2) = (wgt[0] as f32, wgt[1] as f32, wgt[2] as f32);
            let b = &t.bary;
            uv[i] = [
                s0 * b[0][1] + s1 * b[1][1] + s2 * b[2][1],
                s0 * b[0][2] + s1 * b[1][2] + s2 * b[2][2],
            ];
            prim[i] = t.prim;
            tri[i] = t.tri;
        }
    });
}

/// Turns stored barycentrics into uv, coverage and the local-space view direction.
fn resolve(scene: &Scene, prims: &[PrimInfo], band: &mut Band) {
    for i in 0..band.prim.len() {
        let pi = band.prim[i];
        if pi == NONE {
            band.coverage[i] = 0.0;
            band.uv[i] = [0.0; 2];
            band.tri[i] = NONE;
            band.depth[i] = f32::INFINITY;
            band.view_dir[i] = [0.0; 3];
            continue;
        }
        band.coverage[i] = 1.0;
        let inv_depth = band.depth[i];
        band.depth[i] = 1.0 / inv_depth;
        let p = &scene.primitives[pi as usize];
        let info = &prims[pi as usize];
        let t = band.tri[i] as usize;
        let ix = [
            p.indices[3 * t] as usize,
            p.indices[3 * t + 1] as usize,
            p.indices[3 * t + 2] as usize,
        ];
        let [b1, b2] = band.uv[i].map(|b| b / inv_depth);
        band.uv[i] = if info.has_uvs {
            let (u0, u1, u2) = (p.uvs[ix[0]], p.uvs[ix[1]], p.uvs[ix[2]]);
            let uv = u0 + (u1 - u0) * b1 + (u2 - u0) * b2;
            [uv.x, uv.y]
        } else {
            [f32::NAN; 2]
        };
        band.view_dir[i] = match info.eye_local {
            Some(eye) => {
                let (p0, p1, p2) = (p.positions[ix[0]], p.positions[ix[1]], p.positions[ix[2]]);
                let local = p0 + (p1 - p0) * b1 + (p2 - p0) * b2;
                let d = (local - eye).normalize_or_zero();
                [d.x, d.y, d.z]
            }
            None => [0.0; 3],
        };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn top_left_picks_one_direction() {
        let dirs = [
            [1, 0],
            [0, 1],
            [-1, 0],
            [0, -1],
            [3, 7],
            [-3, 7],
            [3, -7],
            [-3, -7],
        ];
        for d in dirs {
            let a = [0, 0];
            assert_ne!(is_top_left(a, d), is_top_left(a, [-d[0], -d[1]]), "{d:?}");
        }
    }

    #[test]
    fn intersect_is_symmetric() {
        let a = ClipVert {
            p: DVec3::new(0.3, -1.7, 0.25),
            b: DVec3::X,
        };
        let b = ClipVert {
            p: DVec3::new(-2.1, 0.9, -3.5),
            b: DVec3::Y,
        };
        let pl = DVec4::new(0.0, 0.0, -1.0, -0.001);
        let (da, db) = (dist(&pl, a.p), dist(&pl, b.p));
        assert_eq!(intersect(a, b, da, db).p, intersect(b, a, db, da).p);
    }

    #[test]
    fn pixel_bounds_follow_centres() {
        // A pixel centre exactly on the box edge is kept.
        let first = |lo: i64| -((HALF - lo).div_euclid(ONE));
        let last = |hi: i64| (hi - HALF).div_euclid(ONE);
        assert_eq!(first(HALF), 0);
        assert_eq!(first(HALF + 1), 1);
        assert_eq!(last(HALF), 0);
        assert_eq!(last(HALF - 1), -1);
        assert_eq!(first(-5 * ONE), -5);
    }
}
