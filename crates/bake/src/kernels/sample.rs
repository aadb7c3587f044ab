//! Neural texture sampling, forward and backward.
//!
//! Shapes:
//! - `pyr.levels[k].data`: `[H_k, W_k, C]` (HWC), `C = pyr.channels`.
//! - `gbuf`: `H x W` pixels (uv, coverage).
//! - forward `out`, backward `d_out`: `[C, H, W]` (CHW planar).
//! - `grads[k]`: `[H_k, W_k, C]`, the same layout as `pyr.levels[k].data`.
//!
//! Forward (the runtime's [`sample_into`]): `F[c, p] = sum_k sum_taps w * T_k[texel, c]` at
//! covered pixels with finite uv. Backward: `dL/dT_k[texel, c] += sum over (p, tap) hitting
//! that texel of w * dL/dF[c, p]`. Both use [`taps`], so they cannot disagree.
//!
//! The backward is a scatter (many pixels hit one texel). It runs in parallel without data
//! races by listing the pixels under the texel bands their taps fall in and letting each task
//! own a band; every texel still sums its contributions in pixel order, then tap order, so
//! the result is bit-identical to the naive [`sample_backward_serial`] (kept as the test
//! oracle) for any thread count.
//!
//! Training uses the pair [`sample_forward_taps`] / [`sample_backward_adam`]: the forward
//! gives exactly [`sample_into`]'s values (same taps, same order of additions) and keeps each
//! pixel's taps for the backward, which scatters band by band into a gradient buffer that
//! stays in cache and takes the lazy Adam step of each touched texel at once. See
//! `sample_backward_timing` in `tests/grad_sample_sh.rs` for timings.

use dnr_runtime::gbuffer::GBuffer;
use dnr_runtime::texture::{
    for_rows_of_planes, sample_into, taps, Level, Pyramid, TextureError, Wrap,
};
use rayon::prelude::*;

use super::adam::{SparseAdam, SparseAdamRows};
use dnr_runtime::nn::gemm::SimdLevel;
use dnr_runtime::nn::simd::prefetch;
use dnr_runtime::nn::simd::{widest, widest_up_to};
use dnr_runtime::nn::tensor::pool;

/// Forward: the runtime's sampler (`out` is `[C, H, W]`, zero at uncovered pixels).
pub fn sample_forward(pyr: &Pyramid, gbuf: &GBuffer, out: &mut [f32]) -> Result<(), TextureError> {
    sample_into(pyr, gbuf, out)
}

fn check_dout(pyr: &Pyramid, gbuf: &GBuffer, d_out: &[f32]) -> Result<(), TextureError> {
    pyr.validate()?;
    let expected = pyr.channels * gbuf.width * gbuf.height;
    if d_out.len() != expected || !gbuf.is_consistent() {
        return Err(TextureError::OutputSize {
            expected,
            found: d_out.len(),
        });
    }
    Ok(())
}

fn check(
    pyr: &Pyramid,
    gbuf: &GBuffer,
    d_out: &[f32],
    grads: &[Vec<f32>],
) -> Result<(), TextureError> {
    check_dout(pyr, gbuf, d_out)?;
    if grads.len() != pyr.levels.len() {
        return Err(TextureError::OutputSize {
            expected: pyr.levels.len(),
            found: grads.len(),
        });
    }
    for (k, (g, l)) in grads.iter().zip(&pyr.levels).enumerate() {
        if g.len() != l.data.len() {
            return Err(TextureError::LevelSize {
                level: k,
                width: l.width,
                height: l.height,
                channels: pyr.channels,
                expected: l.data.len(),
                found: g.len(),
            });
        }
    }
    Ok(())
}

/// Backward of [`sample_forward`]: adds `dL/dtexel` into `grads` (one `[H_k, W_k, C]` vector
/// per level) and returns, per level, the ascending list of texels (`y * W_k + x`) that
/// received a tap of non-zero weight, for a row-sparse optimiser.
///
/// Parallel, race-free and deterministic:
/// 1. fixed chunks of [`PIXEL_CHUNK`] covered pixels compute their four taps on every level
///    in parallel and list each pixel under the texel bands (power-of-two texel ranges, about
///    [`TARGET_BANDS`] per level) its taps fall in, keeping pixel order within each band;
/// 2. each band is then owned by one task, which walks the chunks in order and adds
///    `w * dL/dF` of the taps inside the band straight into its texels.
///
/// Every texel therefore receives its contributions in pixel order, then tap order, exactly
/// as the serial scatter does: the result is bit-identical to [`sample_backward_serial`]
/// for any thread count.
pub fn sample_backward(
    pyr: &Pyramid,
    gbuf: &GBuffer,
    d_out: &[f32],
    grads: &mut [Vec<f32>],
) -> Result<Vec<Vec<u32>>, TextureError> {
    check(pyr, gbuf, d_out, grads)?;
    let c = pyr.channels;
    let vt = ViewTaps::build(pyr, gbuf, None);
    let d_act = vt.gather_rows(d_out);
    let gather = Gather {
        vt: &vt,
        d_act: &d_act,
    };
    let mut touched = Vec::with_capacity(pyr.levels.len());
    for (k, grad) in grads.iter_mut().enumerate() {
        let band = 1usize << vt.levels[k].shift;
        let lists: Vec<Vec<u32>> = grad
            .par_chunks_mut(band * c)
            .enumerate()
            .map(|(b, g)| {
                let mut hit = vec![false; g.len() / c];
                let mut acc = vec![0.0f64; g.len()];
                gather.band(k, b, &mut acc, &mut hit);
                for (gv, a) in g.iter_mut().zip(&acc) {
                    *gv += *a as f32;
                }
                let t0 = b * band;
                hit.iter()
                    .enumerate()
                    .filter(|(_, &h)| h)
                    .map(|(i, _)| (t0 + i) as u32)
                    .collect()
            })
            .collect();
        touched.push(lists.concat());
    }
    pool::recycle(d_act);
    Ok(touched)
}

/// [`sample_forward`] that also keeps every covered pixel's taps for
/// [`sample_backward_adam`]: writes exactly [`sample_into`]'s values (each pixel adds its
/// taps level by level, tap by tap, from zero), computing each tap once per step instead of
/// once in the forward and again in the backward.
pub fn sample_forward_taps(
    pyr: &Pyramid,
    gbuf: &GBuffer,
    out: &mut [f32],
) -> Result<ViewTaps, TextureError> {
    check_dout(pyr, gbuf, out)?;
    let c = pyr.channels;
    let (w, h) = (gbuf.width, gbuf.height);
    let mut f_act = Vec::new();
    let vt = ViewTaps::build(pyr, gbuf, Some(&mut f_act));
    if out.is_empty() {
        return Ok(vt);
    }
    // The covered pixels' features ([P, C]) into the planes; zero elsewhere.
    let active = &vt.active;
    let row_start: Vec<usize> = (0..=h)
        .map(|y| active.partition_point(|&p| (p as usize) < y * w))
        .collect();
    for_rows_of_planes(out, c, w, h, |y, planes| {
        let (a0, a1) = (row_start[y], row_start[y + 1]);
        let xs = &active[a0..a1];
        let rows = &f_act[a0 * c..a1 * c];
        // Plane by plane: one output stream at a time, the row's features stay in L1.
        for (ch, plane) in planes.iter_mut().enumerate() {
            plane.fill(0.0);
            for (&p, f) in xs.iter().zip(rows.chunks_exact(c)) {
                plane[p as usize - y * w] = f[ch];
            }
        }
    });
    Ok(vt)
}

/// [`sample_backward`] fused with the texel optimiser, on the taps [`sample_forward_taps`]
/// kept: scatters `d_out` band by band into a small gradient buffer that stays in cache and
/// at once takes the lazy Adam step of every texel it touched (`opts[k]`, one per level,
/// with L2 `decay[k]`), then forgets the gradient. Exactly what `sample_backward` into zeroed
/// gradients followed by [`SparseAdam::step`] on the touched lists computes, bit for bit and
/// for any thread count, without full-size gradient buffers, touched lists or a second pass
/// over the texture. `pyr` must have the shape `vt` was made for.
pub fn sample_backward_adam(
    vt: &ViewTaps,
    pyr: &mut Pyramid,
    d_out: &[f32],
    opts: &mut [SparseAdam],
    decay: &[f32],
) -> Result<(), TextureError> {
    pyr.validate()?;
    let c = pyr.channels;
    let same_shape = vt.channels == c
        && vt.dims.len() == pyr.levels.len()
        && vt
            .dims
            .iter()
            .zip(&pyr.levels)
            .all(|(&d, l)| d == (l.width, l.height));
    if !same_shape || d_out.len() != c * vt.pixels {
        return Err(TextureError::OutputSize {
            expected: c * vt.pixels,
            found: d_out.len(),
        });
    }
    if opts.len() != pyr.levels.len() || decay.len() != pyr.levels.len() {
        return Err(TextureError::OutputSize {
            expected: pyr.levels.len(),
            found: opts.len().min(decay.len()),
        });
    }
    for (k, (o, l)) in opts.iter().zip(&pyr.levels).enumerate() {
        if o.width() != c || o.rows() != l.width * l.height {
            return Err(TextureError::LevelSize {
                level: k,
                width: l.width,
                height: l.height,
                channels: c,
                expected: l.data.len(),
                found: o.rows() * o.width(),
            });
        }
    }
    let d_act = vt.gather_rows(d_out);
    let gather = Gather { vt, d_act: &d_act };
    // Every texel band of every level that some pixel taps is one task.
    let mut work = Vec::new();
    for (k, (level, opt)) in pyr.levels.iter_mut().zip(opts.iter_mut()).enumerate() {
        let lt = &vt.levels[k];
        for (b, blk) in opt
            .row_blocks(&mut level.data, 1 << lt.shift)
            .into_iter()
            .enumerate()
        {
            if lt.chunks.iter().any(|t| !t.band(b).is_empty()) {
                work.push((k, b, blk));
            }
        }
    }
    let max_band = vt
        .levels
        .iter()
        .map(|l| 1usize << l.shift)
        .max()
        .unwrap_or(0);
    work.into_par_iter().for_each(|(k, b, mut blk)| {
        BAND_SCRATCH.with_borrow_mut(|scratch| {
            // Kept all zero / false between tasks: each task clears what it set.
            if scratch.hit.len() < max_band || scratch.g32.len() != c {
                scratch.g = vec![0.0f64; max_band * c];
                scratch.hit = vec![false; max_band];
                scratch.g32 = vec![0.0f32; c];
            }
            let task = BandTask {
                gather: &gather,
                k,
                b,
                decay: decay[k],
            };
            // Vectorised for the widest instruction set detected (the f64 sums and the Adam
            // arithmetic: the same operations in the same order, so the same bits).
            widest_up_to(
                SimdLevel::Avx2,
                #[inline(always)]
                || task.run(&mut blk, scratch),
            );
        })
    });
    pool::recycle(d_act);
    Ok(())
}

/// One texel band's scatter and lazy-Adam update (see [`sample_backward_adam`]).
struct BandTask<'a, 'g> {
    gather: &'a Gather<'g>,
    k: usize,
    b: usize,
    decay: f32,
}

impl BandTask<'_, '_> {
    /// Scatters the band's taps into `s.g` (its texels, `[texel][C]` in f64, all zero on
    /// entry) marking `s.hit`, then updates every hit row and clears what it set.
    #[inline(always)]
    fn run(&self, blk: &mut SparseAdamRows<'_>, s: &mut BandScratch) {
        let c = s.g32.len();
        let band = blk.len();
        let (g, hit, g32, rows) = (
            &mut s.g[..band * c],
            &mut s.hit[..band],
            &mut s.g32,
            &mut s.hits,
        );
        self.gather.band(self.k, self.b, g, hit);
        // The hit rows' parameters and moments are scattered over arrays far larger than the
        // caches: list the hits, then update each while prefetching the rows a few hits on.
        rows.clear();
        rows.extend(
            hit.iter_mut()
                .enumerate()
                .filter(|(_, h)| **h)
                .map(|(i, h)| {
                    *h = false;
                    i as u32
                }),
        );
        for (j, &i) in rows.iter().enumerate() {
            if let Some(&ahead) = rows.get(j + PREFETCH_ROWS_AHEAD) {
                blk.prefetch(ahead as usize);
            }
            let i = i as usize;
            let gi = &mut g[i * c..(i + 1) * c];
            for (o, a) in g32.iter_mut().zip(gi.iter()) {
                *o = *a as f32;
            }
            blk.update(i, g32, self.decay);
            gi.fill(0.0);
        }
    }
}

/// A band task's working memory (see [`BAND_SCRATCH`]).
struct BandScratch {
    /// The band's gradient rows, `[texel][C]`.
    g: Vec<f64>,
    /// Which texels of the band were hit.
    hit: Vec<bool>,
    /// One gradient row in f32.
    g32: Vec<f32>,
    /// The hit texels, ascending.
    hits: Vec<u32>,
}

thread_local! {
    /// Per-thread working memory of [`sample_backward_adam`], kept across calls (half a
    /// megabyte at 16 channels: allocating it per task meant fresh, page-faulting memory at
    /// every step until the allocator's thresholds settled).
    static BAND_SCRATCH: std::cell::RefCell<BandScratch> = const {
        std::cell::RefCell::new(BandScratch {
            g: Vec::new(),
            hit: Vec::new(),
            g32: Vec::new(),
            hits: Vec::new(),
        })
    };
}

/// Hit texels ahead of the one being updated whose optimiser rows are prefetched (6 took 13%
/// off the update at a 128 crop, where hits are sparse; no change at 256).
const PREFETCH_ROWS_AHEAD: usize = 6;

/// Covered pixels per task of the forward and of the bucketing (fixed, so the work split
/// never depends on the thread count; at most 65536, pixels within a chunk are `u16`).
pub const PIXEL_CHUNK: usize = 2048;
/// Bands per level the band size aims at (bands are powers of two of texels).
pub const TARGET_BANDS: usize = 64;
/// Fewest texels per band.
pub const MIN_BAND: usize = 256;

/// The four bilinear taps of one pixel on one level.
#[derive(Clone, Copy, Default)]
struct Tap4 {
    texel: [u32; 4],
    weight: [f32; 4],
}

/// One pixel chunk's taps on one level, and its pixels bucketed by texel band: a pixel is
/// listed (in pixel order) in every band one of its taps falls in.
struct ChunkTaps {
    /// Per pixel of the chunk.
    taps: Vec<Tap4>,
    /// Pixel indices within the chunk, grouped by band.
    pixels: Vec<u16>,
    /// `pixels[start[b]..start[b + 1]]` tap band b.
    start: Vec<u32>,
}

impl ChunkTaps {
    fn band(&self, b: usize) -> &[u16] {
        &self.pixels[self.start[b] as usize..self.start[b + 1] as usize]
    }

    /// Counting sort of the chunk's pixels by band (stable: pixel order kept).
    #[inline(always)]
    fn new(taps: Vec<Tap4>, shift: u32, bands: usize) -> Self {
        let mut start = vec![0u32; bands + 1];
        for t in &taps {
            tap_bands(t, shift, |b| start[b + 1] += 1);
        }
        for b in 0..bands {
            start[b + 1] += start[b];
        }
        let mut fill = start.clone();
        let mut pixels = vec![0u16; start[bands] as usize];
        for (i, t) in taps.iter().enumerate() {
            tap_bands(t, shift, |b| {
                pixels[fill[b] as usize] = i as u16;
                fill[b] += 1;
            });
        }
        ChunkTaps {
            taps,
            pixels,
            start,
        }
    }
}

/// Calls `f` once for each distinct band among the taps of `t` (zero-weight taps included;
/// the scatter skips them).
#[inline(always)]
fn tap_bands(t: &Tap4, shift: u32, mut f: impl FnMut(usize)) {
    let [b0, b1, b2, b3] = t.texel.map(|x| (x >> shift) as usize);
    // Taps 0 and 1 share a texel row, as do 2 and 3; with rows inside one band (the usual
    // case) a pixel has one or two bands.
    if b0 == b1 && b2 == b3 {
        f(b0);
        if b2 != b0 {
            f(b2);
        }
        return;
    }
    f(b0);
    if b1 != b0 {
        f(b1);
    }
    if b2 != b0 && b2 != b1 {
        f(b2);
    }
    if b3 != b0 && b3 != b1 && b3 != b2 {
        f(b3);
    }
}

/// One level's texel bands (`1 << shift` texels each) and every chunk's taps on it.
struct LevelTaps {
    shift: u32,
    chunks: Vec<ChunkTaps>,
}

/// The taps of every covered pixel of a view on every level of a pyramid, bucketed for the
/// scatter: what [`sample_forward_taps`] hands to [`sample_backward_adam`].
pub struct ViewTaps {
    channels: usize,
    /// Pixels of the view (`width * height`).
    pixels: usize,
    /// `(width, height)` of each level.
    dims: Vec<(usize, usize)>,
    /// Covered pixels with finite uv, ascending.
    active: Vec<u32>,
    levels: Vec<LevelTaps>,
}

impl ViewTaps {
    /// Taps (inputs checked), and with `f_act` the features of the active pixels (`[P, C]`).
    fn build(pyr: &Pyramid, gbuf: &GBuffer, f_act: Option<&mut Vec<f32>>) -> Self {
        let c = pyr.channels;
        let n = gbuf.width * gbuf.height;
        let active: Vec<u32> = (0..n)
            .filter(|&i| {
                gbuf.coverage[i] != 0.0 && gbuf.uv[i][0].is_finite() && gbuf.uv[i][1].is_finite()
            })
            .map(|i| i as u32)
            .collect();
        let shifts: Vec<u32> = pyr
            .levels
            .iter()
            .map(|l| {
                let band = (l.width * l.height)
                    .div_ceil(TARGET_BANDS)
                    .next_power_of_two()
                    .max(MIN_BAND);
                band.trailing_zeros()
            })
            .collect();
        let (ws, wt) = (pyr.wrap_s, pyr.wrap_t);
        // Compiled for the widest instruction set: the taps' f64 arithmetic runs in vector
        // lanes (and `floor` is one instruction), each texel's blend is one or two vectors.
        let chunk = |px: &[u32], mut acc: Option<&mut [f32]>| -> Vec<ChunkTaps> {
            widest(
                #[inline(always)]
                || {
                    // A loop, not an iterator chain: closures inside adapters are not always
                    // inlined, and outside this function they lose its instruction set.
                    let mut out = Vec::with_capacity(shifts.len());
                    for (l, &shift) in pyr.levels.iter().zip(&shifts) {
                        let taps = level_taps(l, c, ws, wt, &gbuf.uv, px, acc.as_deref_mut());
                        let bands = (l.width * l.height).div_ceil(1 << shift);
                        out.push(ChunkTaps::new(taps, shift, bands));
                    }
                    out
                },
            )
        };
        // [chunk][level]
        let mut per_chunk: Vec<Vec<ChunkTaps>> = match f_act {
            Some(f) => {
                *f = vec![0.0; active.len() * c];
                active
                    .par_chunks(PIXEL_CHUNK)
                    .zip(f.par_chunks_mut(PIXEL_CHUNK * c))
                    .map(|(px, acc)| chunk(px, Some(acc)))
                    .collect()
            }
            None => active
                .par_chunks(PIXEL_CHUNK)
                .map(|px| chunk(px, None))
                .collect(),
        };
        let mut levels: Vec<LevelTaps> = shifts
            .iter()
            .map(|&shift| LevelTaps {
                shift,
                chunks: Vec::with_capacity(per_chunk.len()),
            })
            .collect();
        for chunk in &mut per_chunk {
            for (l, t) in levels.iter_mut().zip(chunk.drain(..)) {
                l.chunks.push(t);
            }
        }
        ViewTaps {
            channels: c,
            pixels: n,
            dims: pyr.levels.iter().map(|l| (l.width, l.height)).collect(),
            active,
            levels,
        }
    }

    /// The upstream gradient `[C, H, W]` at the active pixels, transposed to `[P, C]` (each
    /// tap of the scatter reads C contiguous values). From the tensor pool (every value is
    /// written): a fresh zeroed buffer each step cost a memset and its page faults.
    fn gather_rows(&self, d_out: &[f32]) -> Vec<f32> {
        let (c, n) = (self.channels, self.pixels);
        let mut d_act = pool::scratch(self.active.len() * c);
        d_act
            .par_chunks_mut(c * PIXEL_CHUNK)
            .zip(self.active.par_chunks(PIXEL_CHUNK))
            .for_each(|(dst, px)| {
                // Blocks of pixels, plane by plane: one input stream at a time, the output
                // block stays in L1.
                for (dst, px) in dst.chunks_mut(c * 64).zip(px.chunks(64)) {
                    for ch in 0..c {
                        let plane = &d_out[ch * n..(ch + 1) * n];
                        for (row, &p) in dst.chunks_exact_mut(c).zip(px) {
                            row[ch] = plane[p as usize];
                        }
                    }
                }
            });
        d_act
    }
}

/// The taps of the pixels `px` on `level`; with `acc` (`[px][C]`) also adds each pixel's
/// bilinear sample into it, tap by tap.
#[inline(always)]
fn level_taps(
    level: &Level,
    c: usize,
    ws: Wrap,
    wt: Wrap,
    uv: &[[f32; 2]],
    px: &[u32],
    acc: Option<&mut [f32]>,
) -> Vec<Tap4> {
    match (acc, c) {
        (None, _) => level_tap_list(level, ws, wt, uv, px),
        (Some(acc), 16) => level_taps_n::<16>(level, ws, wt, uv, px, acc),
        (Some(acc), 12) => level_taps_n::<12>(level, ws, wt, uv, px, acc),
        (Some(acc), 8) => level_taps_n::<8>(level, ws, wt, uv, px, acc),
        (Some(acc), 4) => level_taps_n::<4>(level, ws, wt, uv, px, acc),
        (Some(acc), c) => px
            .iter()
            .zip(acc.chunks_exact_mut(c))
            .map(|(&p, a)| {
                let [u, v] = uv[p as usize];
                let tp = taps(level.width, level.height, ws, wt, u, v);
                for &(t, w) in tp.iter().flatten() {
                    for (o, &x) in a.iter_mut().zip(&level.data[t * c..(t + 1) * c]) {
                        *o += w * x;
                    }
                }
                tap4(tp)
            })
            .collect(),
    }
}

/// [`level_taps`] with an accumulator, for a channel count known at compile time (the sum
/// stays in registers across the taps). The taps of the whole chunk come first, so the blend
/// can prefetch the texels of the pixel [`PREFETCH_AHEAD`] places on: the finest levels are
/// far larger than the caches and each pixel's four texels are scattered lines.
#[inline(always)]
fn level_taps_n<const C: usize>(
    level: &Level,
    ws: Wrap,
    wt: Wrap,
    uv: &[[f32; 2]],
    px: &[u32],
    acc: &mut [f32],
) -> Vec<Tap4> {
    let all = level_tap_list(level, ws, wt, uv, px);
    for (i, (t, a)) in all.iter().zip(acc.chunks_exact_mut(C)).enumerate() {
        if let Some(next) = all.get(i + PREFETCH_AHEAD) {
            for &tx in &next.texel {
                // First and last value: a texel need not start on a cache line.
                prefetch(&level.data, tx as usize * C);
                prefetch(&level.data, tx as usize * C + C - 1);
            }
        }
        // All weights zero: no taps (bilinear weights of real taps sum to one).
        if t.weight == [0.0; 4] {
            continue;
        }
        let a: &mut [f32; C] = a.try_into().expect("C values");
        let mut s = *a;
        for (&tx, &w) in t.texel.iter().zip(&t.weight) {
            let tx = tx as usize;
            let x: [f32; C] = level.data[tx * C..(tx + 1) * C]
                .try_into()
                .expect("C values");
            for (o, x) in s.iter_mut().zip(x) {
                *o += w * x;
            }
        }
        *a = s;
    }
    all
}

/// Pixels whose taps [`level_tap_list`] computes side by side.
const TAP_LANES: usize = 8;

/// The taps of the pixels `px` (finite uv) on `level`, each exactly what [`taps`] gives it:
/// [`TAP_LANES`] pixels at a time where all of their taps fall inside the level (every wrap
/// mode then yields `floor(x)` and `floor(x) + 1`, and `floor(x)` equals the integer `taps`
/// derives), through [`taps`] itself otherwise. The same f64 and f32 operations in the same
/// order, so the same bits.
#[inline(always)]
fn level_tap_list(level: &Level, ws: Wrap, wt: Wrap, uv: &[[f32; 2]], px: &[u32]) -> Vec<Tap4> {
    let (w, h) = (level.width, level.height);
    let (wf, hf, w32) = (w as f64, h as f64, w as u32);
    let one = |p: u32| {
        let [u, v] = uv[p as usize];
        tap4(taps(w, h, ws, wt, u, v))
    };
    let mut out = Vec::with_capacity(px.len());
    let mut blocks = px.chunks_exact(TAP_LANES);
    for blk in blocks.by_ref() {
        let (mut x, mut y) = ([0.0f64; TAP_LANES], [0.0f64; TAP_LANES]);
        for i in 0..TAP_LANES {
            let [u, v] = uv[blk[i] as usize];
            x[i] = u as f64 * wf - 0.5;
            y[i] = v as f64 * hf - 0.5;
        }
        let (x0, y0) = (x.map(f64::floor), y.map(f64::floor));
        let mut inside = true;
        for i in 0..TAP_LANES {
            inside &= x0[i] >= 0.0 && x0[i] + 1.0 < wf && y0[i] >= 0.0 && y0[i] + 1.0 < hf;
        }
        if !inside {
            out.extend(blk.iter().map(|&p| one(p)));
            continue;
        }
        for i in 0..TAP_LANES {
            let (fx, fy) = ((x[i] - x0[i]) as f32, (y[i] - y0[i]) as f32);
            let t = (y0[i] as usize * w + x0[i] as usize) as u32;
            out.push(Tap4 {
                texel: [t, t + 1, t + w32, t + w32 + 1],
                weight: [
                    (1.0 - fx) * (1.0 - fy),
                    fx * (1.0 - fy),
                    (1.0 - fx) * fy,
                    fx * fy,
                ],
            });
        }
    }
    out.extend(blocks.remainder().iter().map(|&p| one(p)));
    out
}

/// Pixels ahead in a band's list whose taps and gradient row [`Gather::each_tap`] prefetches.
const GATHER_AHEAD: usize = 8;

/// Pixels ahead whose texels [`level_taps_n`] prefetches.
const PREFETCH_AHEAD: usize = 8;

/// The record of [`taps`]' result; all weights zero (never scattered) without taps, which
/// active pixels (finite uv, non-empty levels) always have.
#[inline(always)]
fn tap4(tp: Option<[(usize, f32); 4]>) -> Tap4 {
    match tp {
        Some(tp) => Tap4 {
            texel: tp.map(|(t, _)| t as u32),
            weight: tp.map(|(_, w)| w),
        },
        None => Tap4::default(),
    }
}

/// Step 2 of the scatter: the taps of a view and the upstream gradient at its active pixels.
struct Gather<'a> {
    vt: &'a ViewTaps,
    /// `[P, C]`.
    d_act: &'a [f32],
}

impl Gather<'_> {
    /// Adds every tap's `w * dL/dF` that falls in band `b` of level `k` into `g` (the band's
    /// texels, `[texel][C]`) in pixel order, then tap order, and marks the texels hit.
    /// Accumulates in `f64`: a texel of a large level seen by many pixels sums millions of
    /// terms, where an `f32` running sum loses several percent (tested in `tests/stress.rs`).
    /// Always inlined (as are the helpers), so [`BandTask::run_avx2`] compiles it for AVX2.
    #[inline(always)]
    fn band(&self, k: usize, b: usize, g: &mut [f64], hit: &mut [bool]) {
        match self.vt.channels {
            16 => self.band_n::<16>(k, b, g, hit),
            12 => self.band_n::<12>(k, b, g, hit),
            8 => self.band_n::<8>(k, b, g, hit),
            4 => self.band_n::<4>(k, b, g, hit),
            c => self.each_tap(k, b, hit, |local, w, p| {
                let d = &self.d_act[p * c..(p + 1) * c];
                for (gv, &dv) in g[local * c..(local + 1) * c].iter_mut().zip(d) {
                    *gv += f64::from(w * dv);
                }
            }),
        }
    }

    /// [`Gather::band`] for a channel count known at compile time.
    #[inline(always)]
    fn band_n<const C: usize>(&self, k: usize, b: usize, g: &mut [f64], hit: &mut [bool]) {
        // The closure inlined too (perf showed it as its own baseline-x86 function, called per
        // tap, so the band sums ran in 2-lane SSE2 instead of AVX2).
        self.each_tap(
            k,
            b,
            hit,
            #[inline(always)]
            |local, w, p| {
                // Copies in and out, so the compiler sees no aliasing and uses vector registers.
                let d: [f32; C] = self.d_act[p * C..(p + 1) * C].try_into().expect("C values");
                let gv: &mut [f64; C] = (&mut g[local * C..(local + 1) * C])
                    .try_into()
                    .expect("C values");
                let mut acc = *gv;
                for (a, dv) in acc.iter_mut().zip(d) {
                    *a += f64::from(w * dv);
                }
                *gv = acc;
            },
        );
    }

    /// Calls `f(texel within the band, weight, active pixel)` for every non-zero tap in band
    /// `b` of level `k`, in pixel order, then tap order, marking the texels in `hit`.
    #[inline(always)]
    fn each_tap(&self, k: usize, b: usize, hit: &mut [bool], mut f: impl FnMut(usize, f32, usize)) {
        let lt = &self.vt.levels[k];
        let lo = (b << lt.shift) as u32;
        let len = hit.len() as u32;
        let c = self.vt.channels;
        for (ci, chunk) in lt.chunks.iter().enumerate() {
            let list = chunk.band(b);
            for (j, &i) in list.iter().enumerate() {
                // The band's pixels skip through the chunk: fetch the taps and the gradient
                // row of a pixel a few places on.
                if let Some(&ia) = list.get(j + GATHER_AHEAD) {
                    prefetch(&chunk.taps, ia as usize);
                    prefetch(self.d_act, (ci * PIXEL_CHUNK + ia as usize) * c);
                }
                let t = &chunk.taps[i as usize];
                let p = ci * PIXEL_CHUNK + i as usize;
                for (&tx, &w) in t.texel.iter().zip(&t.weight) {
                    let local = tx.wrapping_sub(lo);
                    if w != 0.0 && local < len {
                        hit[local as usize] = true;
                        f(local as usize, w, p);
                    }
                }
            }
        }
    }
}

/// The naive serial scatter: same contract as [`sample_backward`] (same touched lists, same
/// `f64` sums in the same order, so bit-identical gradients). Test oracle.
pub fn sample_backward_serial(
    pyr: &Pyramid,
    gbuf: &GBuffer,
    d_out: &[f32],
    grads: &mut [Vec<f32>],
) -> Result<Vec<Vec<u32>>, TextureError> {
    check(pyr, gbuf, d_out, grads)?;
    let c = pyr.channels;
    let n = gbuf.width * gbuf.height;
    let mut marks: Vec<Vec<bool>> = pyr
        .levels
        .iter()
        .map(|l| vec![false; l.width * l.height])
        .collect();
    // Same f64 accumulation, same order (pixel, then tap) as the parallel scatter.
    let mut acc: Vec<Vec<f64>> = grads.iter().map(|g| vec![0.0; g.len()]).collect();
    for p in 0..n {
        if gbuf.coverage[p] == 0.0 {
            continue;
        }
        let [u, v] = gbuf.uv[p];
        for ((level, acc), mark) in pyr.levels.iter().zip(acc.iter_mut()).zip(&mut marks) {
            let Some(tp) = taps(level.width, level.height, pyr.wrap_s, pyr.wrap_t, u, v) else {
                break;
            };
            for (t, w) in tp {
                if w == 0.0 {
                    continue;
                }
                mark[t] = true;
                for ch in 0..c {
                    acc[t * c + ch] += f64::from(w * d_out[ch * n + p]);
                }
            }
        }
    }
    for (grad, acc) in grads.iter_mut().zip(&acc) {
        for (g, a) in grad.iter_mut().zip(acc) {
            *g += *a as f32;
        }
    }
    Ok(marks
        .iter()
        .map(|m| {
            m.iter()
                .enumerate()
                .filter(|(_, &b)| b)
                .map(|(t, _)| t as u32)
                .collect()
        })
        .collect())
}
