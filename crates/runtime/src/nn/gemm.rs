//! Single-precision matrix products shaped for convolutions: few output channels (M), many
//! pixels (N).
//!
//! Two entry points:
//! - [`gemm_nn`]: `C = A B` with A pre-packed ([`PackedA`], the weights) and B given as rows that
//!   are each contiguous along N at arbitrary offsets into one buffer. A convolution passes the
//!   planes of its (padded) input shifted by each kernel tap, so no im2col matrix is ever
//!   materialised: B is copied KC x NC block by block (256 x 256, L2-sized) into NR-wide strips
//!   that the micro-kernel streams from L1 (BLIS loop order), which is what the thin
//!   convolution shapes (M = 3..64, N = 10^4..10^5) need to keep the FMA units busy.
//! - [`gemm_nt`]: `C = A Bᵀ` with both operands given as rows contiguous along K (the pixels):
//!   the weight gradient of a convolution, a dot product per (output, input, tap).
//!
//! Both split C into blocks that the rayon pool computes independently; every element of C is
//! summed in the same order whatever the blocking or thread count, so results are bit-identical
//! across runs and thread counts.
//!
//! This module and [`super::simd`] are the only ones of the crate with `unsafe`: the AVX2+FMA
//! and AVX-512 micro-kernels (selected at run time from what the CPU reports) use raw-pointer
//! loads. Every kernel has a
//! safe scalar twin that [`set_simd_cap`] can force, so tests run both paths.
#![allow(unsafe_code)]

use super::simd::prefetch;
use super::tensor::pool;
use rayon::prelude::*;
use std::sync::atomic::{AtomicBool, AtomicU8, Ordering};

/// Rows of A per micro-tile of [`gemm_nn`].
pub const MR: usize = 6;
/// Columns of B per micro-tile of [`gemm_nn`] (two 8-lane vectors).
pub const NR: usize = 16;
/// K block of [`gemm_nn`]: the B strip (KC x NR) stays in L1 across the M tiles.
const KC: usize = 256;
/// Columns of packed B per panel of [`gemm_nn`] (KC x NC floats, in L2).
const NC: usize = 256;
/// Rows of A per block of [`gemm_nn`] (MC x KC floats, in L2).
const MC: usize = 72;
/// A rows per micro-tile of [`gemm_nt`] (at most; AVX2 and scalar use 4 x 3 tiles, AVX-512
/// 8 x 3: each B vector is reused 8 times and each A vector 3 times, 11 loads per 24 FMAs).
const RT: usize = 8;
/// B rows per micro-tile of [`gemm_nt`].
const CT: usize = 3;
/// A-tile values per K block of [`gemm_nt`] (`rows x kc`, 16 KB: stays in L1).
const NT_TILE_VALUES: usize = 4096;
/// Columns per run of [`PackedA::from_offsets_multi`] (64 columns of a transposed conv's
/// phase read 16 input channels' weights: 96 cache lines per tile).
const MULTI_RUN: usize = 64;
/// Packed values per parallel task of [`PackedA::from_offsets_multi`].
const PAR_MIN_PACK: usize = 1 << 15;
/// Blocks of at most this many rows skip packing B in [`gemm_nn`] (AVX-512). Measured on
/// Zen 5 (48 KB L1): reading B in place wins up to M = 64 (4 x 128 x 16512: 65 -> 280
/// GFLOP/s, 16 x 256 x 16512: 240 -> 410); for large M packing wins (1024^3: 400 vs 240).
#[cfg(target_arch = "x86_64")]
const DIRECT_MAX_ROWS: usize = MC;
/// Products with at most this many columns read weights used once in place
/// ([`AOperand::offsets`]) instead of packing them first: each A value is then read about
/// N / 32 times, and past a few thousand columns packed panels (whole cache lines, sequential)
/// win back the packing pass (a 256 crop's first layers, one thread: 4-14% slower in place).
pub const IN_PLACE_A_MAX_N: usize = 2048;
/// Below this many multiply-adds a product runs on the calling thread.
const PARALLEL_MIN_MACS: usize = 1 << 19;

/// Instruction sets the kernels can use, in increasing order.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum SimdLevel {
    /// Portable safe Rust.
    Scalar = 0,
    /// AVX2 + FMA, 8 lanes.
    Avx2 = 1,
    /// AVX-512F, 16 lanes (NN products take two 16-column strips at once).
    Avx512 = 2,
}

static SIMD_CAP: AtomicU8 = AtomicU8::new(SimdLevel::Avx512 as u8);

/// Caps the instruction set the kernels may use (tests force [`SimdLevel::Scalar`]; benchmarks
/// can emulate an AVX2-only CPU). [`SimdLevel::Avx512`] restores full detection.
pub fn set_simd_cap(cap: SimdLevel) {
    SIMD_CAP.store(cap as u8, Ordering::Relaxed);
}

static IN_PLACE_B: AtomicBool = AtomicBool::new(true);

/// Lets [`gemm_nn`] read B in place for blocks of few rows (`true`, the default) or makes it
/// always pack B (`false`). Both give the same bits; tests compare them, benchmarks time them.
pub fn set_in_place_b(on: bool) {
    IN_PLACE_B.store(on, Ordering::Relaxed);
}

/// Forces the portable scalar kernels (`true`) or restores detection (`false`).
pub fn set_force_scalar(on: bool) {
    set_simd_cap(if on {
        SimdLevel::Scalar
    } else {
        SimdLevel::Avx512
    });
}

/// The instruction set in use: what the CPU has, limited by [`set_simd_cap`].
pub fn simd_level() -> SimdLevel {
    let cap = SIMD_CAP.load(Ordering::Relaxed);
    let cpu = cpu_level();
    if cap <= SimdLevel::Scalar as u8 {
        SimdLevel::Scalar
    } else if cap == SimdLevel::Avx2 as u8 {
        cpu.min(SimdLevel::Avx2)
    } else {
        cpu
    }
}

/// Whether SIMD kernels are in use.
pub fn simd_active() -> bool {
    simd_level() != SimdLevel::Scalar
}

fn cpu_level() -> SimdLevel {
    #[cfg(target_arch = "x86_64")]
    {
        if !(std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma")) {
            SimdLevel::Scalar
        } else if std::is_x86_feature_detected!("avx512f") {
            SimdLevel::Avx512
        } else {
            SimdLevel::Avx2
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        SimdLevel::Scalar
    }
}

/// The A operand of [`gemm_nn`], packed in panels of [`MR`] rows (`[tile][k][r]`, rows past M
/// zero) so the micro-kernel reads it sequentially.
#[derive(Clone, Debug)]
pub struct PackedA {
    m: usize,
    k: usize,
    data: Vec<f32>,
}

impl PackedA {
    /// Packs the M x K matrix whose element (i, k) is `a[i * rs + k * cs]`.
    pub fn new(m: usize, k: usize, a: &[f32], rs: usize, cs: usize) -> Self {
        let rows: Vec<usize> = (0..m).map(|i| i * rs).collect();
        let cols: Vec<usize> = (0..k).map(|kk| kk * cs).collect();
        Self::from_offsets(a, &rows, &cols)
    }

    /// Packs the M x K matrix with element (i, k) = `w[rows[i] + cols[k]]` (M = `rows.len()`,
    /// K = `cols.len()`): the weight layouts of every convolution are of this form.
    pub fn from_offsets(w: &[f32], rows: &[usize], cols: &[usize]) -> Self {
        Self::from_offsets_multi(w, rows, &[cols])
            .pop()
            .expect("one matrix asked, one packed")
    }

    /// Packs several M x K matrices that share `rows`: element (i, k) of matrix `q` is
    /// `w[rows[i] + cols[q][k]]` (every `cols[q]` the same length). One parallel pass over the
    /// row panels packs a panel of every matrix while the rows of `w` it reads are in cache: a
    /// transposed convolution's four phases read every weight once between them.
    pub fn from_offsets_multi(w: &[f32], rows: &[usize], cols: &[&[usize]]) -> Vec<Self> {
        let m = rows.len();
        let k = cols.first().map_or(0, |c| c.len());
        assert!(cols.iter().all(|c| c.len() == k), "PackedA: K differs");
        let max_col = cols
            .iter()
            .flat_map(|c| c.iter().copied())
            .max()
            .unwrap_or(0);
        let max = rows.iter().max().copied().unwrap_or(0) + max_col;
        assert!(
            m == 0 || k == 0 || max < w.len(),
            "PackedA: A out of bounds"
        );
        let tiles = m.div_ceil(MR);
        // Every value is written below (rows past M as zeros), so pooled scratch will do.
        let mut data: Vec<Vec<f32>> = cols.iter().map(|_| pool::scratch(tiles * k * MR)).collect();
        if k > 0 {
            // panels[t][q]: tile t's panel of matrix q.
            let mut panels: Vec<Vec<&mut [f32]>> = (0..tiles).map(|_| Vec::new()).collect();
            for d in data.iter_mut() {
                for (t, p) in d.chunks_mut(k * MR).enumerate() {
                    panels[t].push(p);
                }
            }
            let per_tile = k * MR * cols.len();
            panels
                .into_par_iter()
                .with_min_len(PAR_MIN_PACK.div_ceil(per_tile))
                .enumerate()
                .for_each(|(t, mut mats)| {
                    let r = &rows[t * MR..(t * MR + MR).min(m)];
                    // Runs of MULTI_RUN columns, matrix by matrix: the rows of `w` a run reads
                    // stay in L1 for every matrix, and each matrix is written in sequential
                    // runs (interleaving the matrices value by value was twice as slow).
                    for k0 in (0..k).step_by(MULTI_RUN) {
                        let k1 = (k0 + MULTI_RUN).min(k);
                        for (panel, c) in mats.iter_mut().zip(cols) {
                            let dst = &mut panel[k0 * MR..k1 * MR];
                            // SAFETY: every offset read is at most `max < w.len()` (asserted
                            // above).
                            unsafe { fill_panel(w, r, &c[k0..k1], dst) }
                        }
                    }
                });
        }
        data.into_iter()
            .map(|data| PackedA { m, k, data })
            .collect()
    }

    /// Packs the M x K matrix with element (i, k) = `f(i, k)`.
    pub fn from_fn(m: usize, k: usize, f: impl Fn(usize, usize) -> f32 + Sync) -> Self {
        let tiles = m.div_ceil(MR);
        let mut data = vec![0.0f32; tiles * k * MR];
        if k > 0 {
            data.par_chunks_mut(k * MR)
                .with_min_len(PAR_MIN_PACK.div_ceil(k * MR))
                .enumerate()
                .for_each(|(t, panel)| {
                    let rows = MR.min(m - t * MR);
                    for (kk, dst) in panel.chunks_exact_mut(MR).enumerate() {
                        for (r, d) in dst[..rows].iter_mut().enumerate() {
                            *d = f(t * MR + r, kk);
                        }
                    }
                });
        }
        PackedA { m, k, data }
    }

    /// Rows (M).
    pub fn m(&self) -> usize {
        self.m
    }

    /// Columns (K).
    pub fn k(&self) -> usize {
        self.k
    }

    /// Panel of tile `t` for k in `k0..k0 + kc`.
    fn panel(&self, t: usize, k0: usize, kc: usize) -> &[f32] {
        &self.data[t * self.k * MR + k0 * MR..][..kc * MR]
    }
}

/// Fills one packed panel (`[k][MR]`, rows past `r.len()` zero) with `w[r[i] + cols[k]]`.
///
/// # Safety
/// Every `r[i] + cols[k]` must be below `w.len()`.
#[inline(always)]
unsafe fn fill_panel(w: &[f32], r: &[usize], cols: &[usize], panel: &mut [f32]) {
    if let Ok(r) = <[usize; MR]>::try_from(r) {
        // A full panel: fixed-size rows, so the copy unrolls.
        for (dst, &c) in panel.chunks_exact_mut(MR).zip(cols) {
            let dst: &mut [f32; MR] = dst.try_into().expect("MR values");
            for (d, &ro) in dst.iter_mut().zip(&r) {
                // SAFETY: the caller's promise.
                *d = unsafe { *w.get_unchecked(ro + c) };
            }
        }
        return;
    }
    for (dst, &c) in panel.chunks_exact_mut(MR).zip(cols) {
        for (d, &ro) in dst.iter_mut().zip(r) {
            // SAFETY: the caller's promise.
            *d = unsafe { *w.get_unchecked(ro + c) };
        }
        dst[r.len()..].fill(0.0);
    }
}

impl Drop for PackedA {
    fn drop(&mut self) {
        pool::recycle(std::mem::take(&mut self.data));
    }
}

/// The A operand of [`gemm_nn`]: packed, or read where it lies.
#[derive(Clone, Copy, Debug)]
pub enum AOperand<'a> {
    /// Packed once ([`PackedA`]): weights that many products reuse (inference).
    Packed(&'a PackedA),
    /// Element (i, k) = `w[rows[i] + cols[k]]`, read in place by the micro-kernels: the
    /// weights of one training step, used by one product. Packing them first (a pass that
    /// waits on memory, a value at a time) cost as much as the product itself on the deep
    /// layers' few pixels. Same values in the same order as [`PackedA::from_offsets`] of the
    /// same arguments, so the same bits.
    Offsets {
        /// The values.
        w: &'a [f32],
        /// Offset of each of the M rows.
        rows: &'a [usize],
        /// Offset of each of the K columns.
        cols: &'a [usize],
    },
}

impl<'a> From<&'a PackedA> for AOperand<'a> {
    fn from(a: &'a PackedA) -> Self {
        AOperand::Packed(a)
    }
}

impl<'a> AOperand<'a> {
    /// A read in place; panics if an element lies outside `w` (caller bug).
    pub fn offsets(w: &'a [f32], rows: &'a [usize], cols: &'a [usize]) -> Self {
        if let (Some(r), Some(c)) = (rows.iter().max(), cols.iter().max()) {
            assert!(r + c < w.len(), "AOperand: A out of bounds");
        }
        AOperand::Offsets { w, rows, cols }
    }

    /// Rows (M).
    pub fn m(&self) -> usize {
        match self {
            AOperand::Packed(a) => a.m,
            AOperand::Offsets { rows, .. } => rows.len(),
        }
    }

    /// Columns (K).
    pub fn k(&self) -> usize {
        match self {
            AOperand::Packed(a) => a.k,
            AOperand::Offsets { cols, .. } => cols.len(),
        }
    }

    /// Tile `t` (rows `t * MR..`, at most MR) for k in `k0..k0 + kc`.
    fn panel(&self, t: usize, k0: usize, kc: usize) -> APanel<'a> {
        match *self {
            AOperand::Packed(a) => APanel::Packed(a.panel(t, k0, kc)),
            AOperand::Offsets { w, rows, cols } => APanel::Offsets {
                w,
                rows: &rows[t * MR..(t * MR + MR).min(rows.len())],
                cols: &cols[k0..k0 + kc],
            },
        }
    }
}

/// One tile of A over one K block, as the micro-kernels read it.
#[derive(Clone, Copy)]
enum APanel<'a> {
    /// `[k][MR]`, `kc * MR` values.
    Packed(&'a [f32]),
    /// (r, k) = `w[rows[r] + cols[k]]`, in bounds (checked by [`AOperand::offsets`]).
    Offsets {
        w: &'a [f32],
        rows: &'a [usize],
        cols: &'a [usize],
    },
}

impl APanel<'_> {
    /// Element (r, k), bounds-checked (the scalar kernel's read).
    fn at(&self, r: usize, k: usize) -> f32 {
        match self {
            APanel::Packed(a) => a[k * MR + r],
            APanel::Offsets { w, rows, cols } => rows.get(r).map_or(0.0, |&o| w[o + cols[k]]),
        }
    }
}

/// How a SIMD micro-kernel reads its A tile: step k's value of row r, then the next step.
#[cfg(target_arch = "x86_64")]
trait ATile: Copy {
    /// Row `r`'s value at the current step.
    ///
    /// # Safety
    /// `r` must be a row of the tile and the current step one of its `kc`.
    unsafe fn get(&self, r: usize) -> f32;
    /// Moves to the next step.
    ///
    /// # Safety
    /// As `get`, for the step moved to, unless no `get` follows.
    unsafe fn advance(&mut self);
}

/// A packed tile: one pointer that moves MR values a step.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
struct PackedTile(*const f32);

#[cfg(target_arch = "x86_64")]
impl ATile for PackedTile {
    #[inline(always)]
    unsafe fn get(&self, r: usize) -> f32 {
        // SAFETY: the caller's promise; the panel holds `kc * MR` values.
        unsafe { *self.0.add(r) }
    }
    #[inline(always)]
    unsafe fn advance(&mut self) {
        self.0 = self.0.wrapping_add(MR);
    }
}

/// A tile read in place: one base pointer per row and a cursor into the column offsets.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
struct OffsetTile {
    base: [*const f32; MR],
    col: *const usize,
}

#[cfg(target_arch = "x86_64")]
impl ATile for OffsetTile {
    #[inline(always)]
    unsafe fn get(&self, r: usize) -> f32 {
        // SAFETY: the caller's promise: `*col` is one of the panel's column offsets; every
        // base is `w` plus one of the panel's row offsets (rows past the panel's alias its
        // first), and every `rows[i] + cols[k]` is inside `w` (checked by AOperand::offsets).
        unsafe { *self.base[r].add(*self.col) }
    }
    #[inline(always)]
    unsafe fn advance(&mut self) {
        self.col = self.col.wrapping_add(1);
    }
}

/// A rectangle of C owned by one task: rows `i0..i0 + rows.len()`, columns `j0..j0 + width`.
struct Block<'c> {
    i0: usize,
    j0: usize,
    rows: Vec<&'c mut [f32]>,
}

/// Splits the first `m` rows (`n` columns each, stride `ldc`) of `c` into a grid of blocks
/// with the given row and column boundaries.
fn split_blocks<'c>(
    c: &'c mut [f32],
    ldc: usize,
    m: usize,
    n: usize,
    row_bounds: &[usize],
    col_bounds: &[usize],
) -> Vec<Block<'c>> {
    let ncb = col_bounds.len() - 1;
    let mut per_col: Vec<Vec<&'c mut [f32]>> = (0..ncb).map(|_| Vec::with_capacity(m)).collect();
    let mut rest = c;
    for i in 0..m {
        let take = if i + 1 < m { ldc } else { n };
        let (row, tail) = std::mem::take(&mut rest).split_at_mut(take);
        rest = tail;
        let mut row = &mut row[..n];
        for (cb, col) in per_col.iter_mut().enumerate() {
            let w = col_bounds[cb + 1] - col_bounds[cb];
            let (head, tail) = std::mem::take(&mut row).split_at_mut(w);
            col.push(head);
            row = tail;
        }
    }
    let mut blocks = Vec::with_capacity(ncb * (row_bounds.len() - 1));
    for (cb, col) in per_col.into_iter().enumerate() {
        let mut it = col.into_iter();
        for rb in 0..row_bounds.len() - 1 {
            let cnt = row_bounds[rb + 1] - row_bounds[rb];
            blocks.push(Block {
                i0: row_bounds[rb],
                j0: col_bounds[cb],
                rows: it.by_ref().take(cnt).collect(),
            });
        }
    }
    blocks
}

/// Boundaries `0, step, 2 step, .., total`.
fn bounds(total: usize, step: usize) -> Vec<usize> {
    let step = step.max(1);
    let mut b: Vec<usize> = (0..total).step_by(step).collect();
    b.push(total);
    b
}

/// Chooses a grid for an `m x n` product: about four blocks per thread, columns split first in
/// multiples of `nq`, rows in multiples of `mq` when columns run out.
fn grid(m: usize, n: usize, macs: usize, mq: usize, nq: usize) -> (Vec<usize>, Vec<usize>) {
    grid_shared(m, n, macs, 1, mq, nq)
}

/// [`grid`] for one of `share` products of [`gemm_nn_batch`] totalling `macs`: the blocks
/// aimed at are shared out among them.
fn grid_shared(
    m: usize,
    n: usize,
    macs: usize,
    share: usize,
    mq: usize,
    nq: usize,
) -> (Vec<usize>, Vec<usize>) {
    let threads = rayon::current_num_threads();
    if threads <= 1 || macs < PARALLEL_MIN_MACS || m == 0 || n == 0 {
        return (vec![0, m], vec![0, n]);
    }
    let target = (4 * threads).div_ceil(share.max(1));
    let col_units = n.div_ceil(nq);
    let ncb = col_units.min(target);
    let cols = bounds(n, col_units.div_ceil(ncb) * nq);
    let ncb = cols.len() - 1;
    let row_units = m.div_ceil(mq);
    let nrb = row_units.min(target.div_ceil(ncb));
    let rows = bounds(m, row_units.div_ceil(nrb) * mq);
    (rows, cols)
}

/// `C(i, j) (+)= sum_k A(i, k) B(k, j)` for `i < a.m()`, `j < n`, where
/// `B(k, j) = b[b_rows[k] + j]` and `C(i, j) = c[i * ldc + j]`. Without `accumulate` C is
/// overwritten.
///
/// Panics if a row of B or C is out of bounds or `b_rows.len() != a.k()` (caller bugs).
pub fn gemm_nn<'a>(
    a: impl Into<AOperand<'a>>,
    b: &[f32],
    b_rows: &[usize],
    n: usize,
    c: &mut [f32],
    ldc: usize,
    accumulate: bool,
) {
    gemm_nn_batch(vec![NnProduct {
        a: a.into(),
        b,
        b_rows,
        n,
        c,
        ldc,
        accumulate,
    }]);
}

/// One product of [`gemm_nn_batch`]: the arguments of [`gemm_nn`].
pub struct NnProduct<'a> {
    /// A (`m x k`).
    pub a: AOperand<'a>,
    /// B's values.
    pub b: &'a [f32],
    /// Offset of each of B's `k` rows in `b`.
    pub b_rows: &'a [usize],
    /// Columns.
    pub n: usize,
    /// C (`m` rows of stride `ldc`).
    pub c: &'a mut [f32],
    /// Row stride of C.
    pub ldc: usize,
    /// Add to C instead of overwriting it.
    pub accumulate: bool,
}

/// Several independent [`gemm_nn`] products in one parallel region: the blocks of all of them
/// are shared out at once, so small products (a transposed convolution's four phases on a
/// deep layer's few pixels) pay one fork and join instead of one each. Each product's blocks
/// sum in the same order as alone: the same bits as separate calls.
pub fn gemm_nn_batch(products: Vec<NnProduct<'_>>) {
    let level = simd_level();
    let count = products.len().max(1);
    let total_macs: usize = products.iter().map(|p| p.a.m() * p.n * p.a.k()).sum();
    let mut work = Vec::new();
    for p in products {
        let (m, k, n) = (p.a.m(), p.a.k(), p.n);
        assert_eq!(
            p.b_rows.len(),
            k,
            "gemm_nn: B has {} rows, A has {k} columns",
            p.b_rows.len()
        );
        if m == 0 || n == 0 {
            continue;
        }
        assert!(
            p.ldc >= n && p.c.len() >= (m - 1) * p.ldc + n,
            "gemm_nn: C too small"
        );
        let max_row = p.b_rows.iter().copied().max().unwrap_or(0);
        assert!(
            k == 0 || max_row + n <= p.b.len(),
            "gemm_nn: B row out of bounds"
        );
        // The batch shares about four blocks per thread out among its products.
        let (rows, cols) = grid_shared(m, n, total_macs, count, MR, 2 * NR);
        let ctx = NnCtx {
            a: p.a,
            b: p.b,
            b_rows: p.b_rows,
            max_row,
            accumulate: p.accumulate,
            level,
        };
        for blk in split_blocks(p.c, p.ldc, m, n, &rows, &cols) {
            work.push((ctx, blk));
        }
    }
    if work.len() == 1 || total_macs < PARALLEL_MIN_MACS || rayon::current_num_threads() <= 1 {
        work.into_iter().for_each(|(ctx, blk)| ctx.block(blk));
    } else {
        work.into_par_iter().for_each(|(ctx, blk)| ctx.block(blk));
    }
}

#[derive(Clone, Copy)]
struct NnCtx<'a> {
    a: AOperand<'a>,
    b: &'a [f32],
    b_rows: &'a [usize],
    max_row: usize,
    accumulate: bool,
    level: SimdLevel,
}

/// Floats of slack for [`aligned_mut`].
const ALIGN_SLACK: usize = 16;

/// The part of `v` that starts at a 64-byte boundary (a cache line: whole-line vector loads).
fn aligned_mut(v: &mut [f32]) -> &mut [f32] {
    let off = (v.as_ptr() as usize).wrapping_neg() % 64 / 4;
    let end = v.len() - ALIGN_SLACK + off;
    &mut v[off..end]
}

/// Adds (or, on the first K block without `accumulate`, copies) `nv` columns of `mv` tile rows
/// into the block's C rows `r0..` at column `js`.
fn store_tile(
    rows: &mut [&mut [f32]],
    r0: usize,
    js: usize,
    mv: usize,
    nv: usize,
    tile: &[f32; MR * NR],
    first: bool,
) {
    for r in 0..mv {
        let src = &tile[r * NR..r * NR + nv];
        if nv == NR {
            // Fixed-size copies compile to a few vector moves instead of a memcpy call.
            let dst: &mut [f32; NR] = (&mut rows[r0 + r][js..js + NR])
                .try_into()
                .expect("NR columns");
            let src: &[f32; NR] = src.try_into().expect("NR columns");
            if first {
                *dst = *src;
            } else {
                for i in 0..NR {
                    dst[i] += src[i];
                }
            }
            continue;
        }
        let dst = &mut rows[r0 + r][js..js + nv];
        if first {
            dst.copy_from_slice(src);
        } else {
            dst.iter_mut().zip(src).for_each(|(d, s)| *d += s);
        }
    }
}

/// Runs `$body` with `$t` bound to the SIMD reader of `$panel` (packed or in place) for `$kc`
/// steps: the kernels are generic over the reader, so the body is compiled once for each.
#[cfg(target_arch = "x86_64")]
macro_rules! with_tile {
    ($panel:expr, $kc:expr, |$t:ident| $body:expr) => {
        match $panel {
            APanel::Packed(a) => {
                assert!(a.len() >= $kc * MR, "gemm_nn: A panel");
                let $t = PackedTile(a.as_ptr());
                $body
            }
            APanel::Offsets { w, rows, cols } => {
                assert!(cols.len() >= $kc && !rows.is_empty(), "gemm_nn: A panel");
                // Rows past the panel's (never read) alias its first.
                let $t = OffsetTile {
                    base: std::array::from_fn(|r| {
                        w.as_ptr()
                            .wrapping_add(rows.get(r).copied().unwrap_or(rows[0]))
                    }),
                    col: cols.as_ptr(),
                };
                $body
            }
        }
    };
}

impl NnCtx<'_> {
    /// BLIS loop order inside one block: column panels of NC (packed B in L2), K blocks of KC,
    /// row blocks of MC (A in L2), then NR-wide strips (in L1; pairs of strips with AVX-512)
    /// times MR-high tiles.
    fn block(&self, mut blk: Block<'_>) {
        let k = self.a.k();
        let width = blk.rows.first().map_or(0, |r| r.len());
        if k == 0 {
            if !self.accumulate {
                blk.rows.iter_mut().for_each(|r| r.fill(0.0));
            }
            return;
        }
        let nrows = blk.rows.len();
        debug_assert_eq!(blk.i0 % MR, 0);
        #[cfg(target_arch = "x86_64")]
        if self.level == SimdLevel::Avx512
            && nrows <= DIRECT_MAX_ROWS
            && IN_PLACE_B.load(Ordering::Relaxed)
        {
            self.block_direct(blk);
            return;
        }
        // pack_b writes every value the kernels read (zeros past the block's last column).
        let mut pack_store =
            pool::scratch(KC.min(k) * NC.min(width.div_ceil(NR) * NR) + ALIGN_SLACK);
        let pack = aligned_mut(&mut pack_store);
        // Strips per kernel call: AVX-512 has 32 registers, so it takes 2 strips (6 x 32 tile,
        // 12 accumulators), or 4 when there are at most 3 rows (3 x 64, 12 accumulators).
        let group = match self.level {
            SimdLevel::Avx512 if nrows <= 3 => 4,
            SimdLevel::Avx512 => 2,
            _ => 1,
        };
        let mut tiles = [[0.0f32; MR * NR]; 4];
        for jc in (0..width).step_by(NC) {
            let ncw = NC.min(width - jc);
            let nstrips = ncw.div_ceil(NR);
            for k0 in (0..k).step_by(KC) {
                let kc = KC.min(k - k0);
                self.pack_b(&mut pack[..nstrips * kc * NR], k0, kc, blk.j0 + jc, ncw);
                let pack = &*pack;
                let first = k0 == 0 && !self.accumulate;
                for ic in (0..nrows).step_by(MC) {
                    let mcw = MC.min(nrows - ic);
                    let mut s = 0;
                    while s < nstrips {
                        let g = if nstrips - s >= group { group } else { 1 };
                        let bp = &pack[s * kc * NR..(s + g) * kc * NR];
                        for r0 in (ic..ic + mcw).step_by(MR) {
                            let mv = MR.min(ic + mcw - r0);
                            let ap = self.a.panel((blk.i0 + r0) / MR, k0, kc);
                            // The tile's C lines, while the kernel runs: a block's MC rows are
                            // more streams than the hardware prefetchers follow, and with a
                            // short K (weight gradients of small planes) the store waited on
                            // memory for as long as the kernel computed.
                            let js = jc + s * NR;
                            let cols = (g * NR).min(ncw - s * NR);
                            for row in &blk.rows[r0..r0 + mv] {
                                prefetch(row, js);
                                prefetch(row, js + cols - 1);
                            }
                            if g == 1 {
                                self.kernel(mv, kc, ap, bp, &mut tiles[0]);
                            } else {
                                self.kernel_group(mv, g, kc, ap, bp, &mut tiles);
                            }
                            for (q, tile) in tiles.iter().enumerate().take(g) {
                                let js = jc + (s + q) * NR;
                                let nv = NR.min(ncw - (s + q) * NR);
                                store_tile(&mut blk.rows, r0, js, mv, nv, tile, first);
                            }
                        }
                        s += g;
                    }
                }
            }
        }
        pool::recycle(pack_store);
    }

    /// [`Self::block`] for few rows (AVX-512): the kernel reads B straight from its rows
    /// instead of a packed copy. Each B value then meets at most `DIRECT_MAX_ROWS` rows of A,
    /// so packing it (a load and a store per value) would cost about as much as the product.
    /// Same K blocks and summation order as the packed path: the same bits. Not for AVX2: on
    /// Zen 3 an AVX2 twin lost to packing (16 x 256 x 16512: 20 against 42 GFLOP/s), the
    /// 256 rows a strip reads at once outrunning its 32 KB L1 and its prefetchers.
    #[cfg(target_arch = "x86_64")]
    fn block_direct(&self, mut blk: Block<'_>) {
        let k = self.a.k();
        let width = blk.rows.first().map_or(0, |r| r.len());
        let nrows = blk.rows.len();
        // Column group per kernel call as in `block` (12 accumulators either way).
        let group = if nrows <= 3 { 4 } else { 2 };
        assert!(blk.j0 + width <= self.b.len() - self.max_row);
        for k0 in (0..k).step_by(KC) {
            let kc = KC.min(k - k0);
            let rows = &self.b_rows[k0..k0 + kc];
            let first = k0 == 0 && !self.accumulate;
            for jc in (0..width).step_by(group * NR) {
                // Valid columns of each strip of the group (0..=NR) as lane masks.
                let masks: [u16; 4] = std::array::from_fn(|q| {
                    let cols = width.saturating_sub(jc + q * NR).min(NR);
                    ((1u32 << cols) - 1) as u16
                });
                for r0 in (0..nrows).step_by(MR) {
                    let mv = MR.min(nrows - r0);
                    let ap = self.a.panel((blk.i0 + r0) / MR, k0, kc);
                    let out: [*mut f32; MR] = std::array::from_fn(|r| {
                        blk.rows
                            .get_mut(r0 + r)
                            .map_or(std::ptr::null_mut(), |row| row[jc..].as_mut_ptr())
                    });
                    // SAFETY: the level is AVX-512 only when the CPU reports AVX-512F; A holds
                    // `kc` steps of its rows (asserted by with_tile); lane `l` of strip q is
                    // unmasked only when `jc + q * NR + l < width`, so it reads
                    // `rows[kk] + j0 + jc + q * NR + l < max_row + j0 + width <= b.len()`
                    // (asserted above) and writes inside C row `r0 + r < nrows` (`width`
                    // long), which the kernel touches only for `r < mv`.
                    with_tile!(ap, kc, |ap| unsafe {
                        let (j, b) = (blk.j0 + jc, self.b);
                        match (mv, group) {
                            (1, 4) => avx512::kernel_nn_direct::<1, 4, _>(
                                ap, b, rows, j, masks, out, first,
                            ),
                            (2, 4) => avx512::kernel_nn_direct::<2, 4, _>(
                                ap, b, rows, j, masks, out, first,
                            ),
                            (3, 4) => avx512::kernel_nn_direct::<3, 4, _>(
                                ap, b, rows, j, masks, out, first,
                            ),
                            (1, _) => avx512::kernel_nn_direct::<1, 2, _>(
                                ap, b, rows, j, masks, out, first,
                            ),
                            (2, _) => avx512::kernel_nn_direct::<2, 2, _>(
                                ap, b, rows, j, masks, out, first,
                            ),
                            (3, _) => avx512::kernel_nn_direct::<3, 2, _>(
                                ap, b, rows, j, masks, out, first,
                            ),
                            (4, _) => avx512::kernel_nn_direct::<4, 2, _>(
                                ap, b, rows, j, masks, out, first,
                            ),
                            (5, _) => avx512::kernel_nn_direct::<5, 2, _>(
                                ap, b, rows, j, masks, out, first,
                            ),
                            _ => avx512::kernel_nn_direct::<6, 2, _>(
                                ap, b, rows, j, masks, out, first,
                            ),
                        }
                    });
                }
            }
        }
    }

    /// Copies B rows `k0..k0 + kc`, columns `j..j + ncw` into NR-wide strips
    /// (`pack[s][kk][0..NR]`, zero past `ncw`).
    fn pack_b(&self, pack: &mut [f32], k0: usize, kc: usize, j: usize, ncw: usize) {
        let full = ncw / NR;
        let rows = &self.b_rows[k0..k0 + kc];
        assert!(pack.len() >= ncw.div_ceil(NR) * kc * NR && j + ncw <= self.b.len() - self.max_row);
        // The SIMD copy exists on x86_64 only. (A `#[cfg]` on an `if` removes its `else` too,
        // which left full strips unpacked on every other target.)
        #[cfg(target_arch = "x86_64")]
        let simd = self.level >= SimdLevel::Avx2 && full > 0;
        #[cfg(not(target_arch = "x86_64"))]
        let simd = false;
        if simd {
            // SAFETY: the level implies the CPU has the instructions; every row is read at
            // `rows[kk] + j .. + full * NR <= max_row + j + ncw <= b.len()` and every write is
            // below `full * kc * NR <= pack.len()` (asserted above).
            #[cfg(target_arch = "x86_64")]
            unsafe {
                if self.level == SimdLevel::Avx512 {
                    avx512::pack_b(pack, self.b, rows, j, full);
                } else {
                    avx2::pack_b(pack, self.b, rows, j, full);
                }
            }
        } else {
            for (kk, &r) in rows.iter().enumerate() {
                let src = &self.b[r + j..r + j + full * NR];
                for (s, chunk) in src.chunks_exact(NR).enumerate() {
                    pack[(s * kc + kk) * NR..(s * kc + kk + 1) * NR].copy_from_slice(chunk);
                }
            }
        }
        let w = ncw - full * NR;
        if w > 0 {
            for (kk, &r) in rows.iter().enumerate() {
                let dst = &mut pack[(full * kc + kk) * NR..(full * kc + kk + 1) * NR];
                dst[..w].copy_from_slice(&self.b[r + j + full * NR..r + j + ncw]);
                dst[w..].fill(0.0);
            }
        }
    }

    /// One MR x NR tile over `kc` steps from an A panel and a packed B strip.
    fn kernel(&self, mv: usize, kc: usize, a: APanel<'_>, b: &[f32], out: &mut [f32; MR * NR]) {
        assert!(b.len() >= kc * NR);
        #[cfg(target_arch = "x86_64")]
        if self.level >= SimdLevel::Avx2 {
            // SAFETY: the level is at least AVX2 only when the CPU reports AVX2 and FMA;
            // with_tile checks A's `kc` steps, the assert above B's `kc * NR` values.
            with_tile!(a, kc, |t| unsafe {
                match mv {
                    1 => avx2::kernel_nn::<1, _>(kc, t, b, out),
                    2 => avx2::kernel_nn::<2, _>(kc, t, b, out),
                    3 => avx2::kernel_nn::<3, _>(kc, t, b, out),
                    4 => avx2::kernel_nn::<4, _>(kc, t, b, out),
                    5 => avx2::kernel_nn::<5, _>(kc, t, b, out),
                    _ => avx2::kernel_nn::<6, _>(kc, t, b, out),
                }
            });
            return;
        }
        scalar_kernel_nn(mv, kc, a, b, out);
    }

    /// `g` (2 or 4) MR x NR tiles from `g` consecutive packed B strips (AVX-512; `b` holds the
    /// `g` strips, `kc * NR` values each).
    fn kernel_group(
        &self,
        mv: usize,
        g: usize,
        kc: usize,
        a: APanel<'_>,
        b: &[f32],
        out: &mut [[f32; MR * NR]; 4],
    ) {
        assert!(b.len() >= g * kc * NR && (g == 2 || (g == 4 && mv <= 3)));
        #[cfg(target_arch = "x86_64")]
        if self.level == SimdLevel::Avx512 {
            // SAFETY: the level is AVX-512 only when the CPU reports AVX-512F; with_tile checks
            // A's `kc` steps, the assert above B's `g` strips of `kc * NR`.
            with_tile!(a, kc, |t| unsafe {
                match (mv, g) {
                    (1, 4) => avx512::kernel_nn_group::<1, 4, _>(kc, t, b, out),
                    (2, 4) => avx512::kernel_nn_group::<2, 4, _>(kc, t, b, out),
                    (3, 4) => avx512::kernel_nn_group::<3, 4, _>(kc, t, b, out),
                    (1, _) => avx512::kernel_nn_group::<1, 2, _>(kc, t, b, out),
                    (2, _) => avx512::kernel_nn_group::<2, 2, _>(kc, t, b, out),
                    (3, _) => avx512::kernel_nn_group::<3, 2, _>(kc, t, b, out),
                    (4, _) => avx512::kernel_nn_group::<4, 2, _>(kc, t, b, out),
                    (5, _) => avx512::kernel_nn_group::<5, 2, _>(kc, t, b, out),
                    _ => avx512::kernel_nn_group::<6, 2, _>(kc, t, b, out),
                }
            });
            return;
        }
        let strip = kc * NR;
        for (q, tile) in out.iter_mut().enumerate().take(g) {
            self.kernel(mv, kc, a, &b[q * strip..(q + 1) * strip], tile);
        }
    }
}

/// Portable micro-kernel of [`gemm_nn`].
fn scalar_kernel_nn(mv: usize, kc: usize, a: APanel<'_>, b: &[f32], out: &mut [f32; MR * NR]) {
    let mut acc = [[0.0f32; NR]; MR];
    for k in 0..kc {
        let bk: &[f32; NR] = b[k * NR..k * NR + NR].try_into().expect("NR slice");
        for r in 0..mv {
            let av = a.at(r, k);
            for (acc, &bv) in acc[r].iter_mut().zip(bk) {
                *acc += av * bv;
            }
        }
    }
    for r in 0..mv {
        out[r * NR..(r + 1) * NR].copy_from_slice(&acc[r]);
    }
}

/// `C(i, j) (+)= sum_{k < kk} A(i, k) B(j, k)` for `i < a_rows.len()`, `j < b_rows.len()`, where
/// `A(i, k) = a[a_rows[i] + k]`, `B(j, k) = b[b_rows[j] + k]`, `C(i, j) = c[i * ldc + j]`.
///
/// Panics if a row is out of bounds (caller bug).
#[allow(clippy::too_many_arguments)]
pub fn gemm_nt(
    a: &[f32],
    a_rows: &[usize],
    b: &[f32],
    b_rows: &[usize],
    kk: usize,
    c: &mut [f32],
    ldc: usize,
    accumulate: bool,
) {
    let (m, n) = (a_rows.len(), b_rows.len());
    if m == 0 || n == 0 {
        return;
    }
    assert!(
        ldc >= n && c.len() >= (m - 1) * ldc + n,
        "gemm_nt: C too small"
    );
    assert!(
        a_rows.iter().all(|&r| r + kk <= a.len()),
        "gemm_nt: A row out of bounds"
    );
    assert!(
        b_rows.iter().all(|&r| r + kk <= b.len()),
        "gemm_nt: B row out of bounds"
    );
    let level = simd_level();
    let (rows, cols) = grid(m, n, m * n * kk, RT, CT * 4);
    let blocks = split_blocks(c, ldc, m, n, &rows, &cols);
    let ctx = NtCtx {
        a,
        a_rows,
        b,
        b_rows,
        k: kk,
        accumulate,
        level,
    };
    if blocks.len() == 1 {
        blocks.into_iter().for_each(|blk| ctx.block(blk));
    } else {
        blocks.into_par_iter().for_each(|blk| ctx.block(blk));
    }
}

struct NtCtx<'a> {
    a: &'a [f32],
    a_rows: &'a [usize],
    b: &'a [f32],
    b_rows: &'a [usize],
    k: usize,
    accumulate: bool,
    level: SimdLevel,
}

impl NtCtx<'_> {
    fn block(&self, mut blk: Block<'_>) {
        let nrows = blk.rows.len();
        let width = blk.rows.first().map_or(0, |r| r.len());
        if !self.accumulate {
            blk.rows.iter_mut().for_each(|r| r.fill(0.0));
        }
        let mut out = [[0.0f32; CT]; RT];
        let mut ao = [0usize; RT];
        let mut bo = [0usize; CT];
        let mut next = [0usize; CT];
        // AVX-512: 8 x 3 tiles (24 accumulators, 11 loads per 24 FMAs); else 4 x 3.
        let (rt, ct) = if self.level == SimdLevel::Avx512 {
            (RT, 3)
        } else {
            (4, CT)
        };
        let kc_max = NT_TILE_VALUES / rt;
        for k0 in (0..self.k).step_by(kc_max) {
            let kc = kc_max.min(self.k - k0);
            for r0 in (0..nrows).step_by(rt) {
                let rv = rt.min(nrows - r0);
                for (r, o) in ao.iter_mut().enumerate().take(rv) {
                    *o = self.a_rows[blk.i0 + r0 + r] + k0;
                }
                for c0 in (0..width).step_by(ct) {
                    let cv = ct.min(width - c0);
                    for (cc, o) in bo.iter_mut().enumerate().take(cv) {
                        *o = self.b_rows[blk.j0 + c0 + cc] + k0;
                    }
                    // The next tile's B rows (or the first's, for the next row tile): the
                    // kernel prefetches them, a cache line per step.
                    let c1 = if c0 + ct < width { c0 + ct } else { 0 };
                    for (cc, o) in next.iter_mut().enumerate() {
                        *o = self.b_rows[blk.j0 + (c1 + cc).min(width - 1)] + k0;
                    }
                    self.kernel(rv, cv, kc, &ao[..rv], &bo[..cv], &next, &mut out);
                    for (row, o) in blk.rows[r0..r0 + rv].iter_mut().zip(&out) {
                        for (d, v) in row[c0..c0 + cv].iter_mut().zip(o) {
                            *d += v;
                        }
                    }
                }
            }
        }
    }

    /// `ao`/`bo` are row offsets plus the K-block start `k0`, with `k0 + kc <= self.k`;
    /// `next` the next tile's B offsets, to prefetch.
    #[allow(clippy::too_many_arguments)]
    fn kernel(
        &self,
        rv: usize,
        cv: usize,
        kc: usize,
        ao: &[usize],
        bo: &[usize],
        next: &[usize; CT],
        out: &mut [[f32; CT]; RT],
    ) {
        // gemm_nt checked `row + k <= len` for every row; offsets are `row + k0` with
        // `k0 + kc <= k`, so every read below is in bounds.
        debug_assert!(
            ao.iter().all(|&o| o + kc <= self.a.len())
                && bo.iter().all(|&o| o + kc <= self.b.len())
        );
        assert!(ao.len() == rv && bo.len() == cv && kc <= self.k);
        #[cfg(not(target_arch = "x86_64"))]
        let _ = next; // only the x86_64 kernels prefetch
        #[cfg(target_arch = "x86_64")]
        if self.level == SimdLevel::Avx512 {
            let (a, b) = (self.a, self.b);
            // SAFETY: the level is AVX-512 only when the CPU reports AVX-512F; every row read
            // (`ao[r] .. ao[r] + kc`, `bo[c] .. bo[c] + kc`) is in bounds as argued above, and
            // `ao`/`bo` hold `rv`/`cv` entries.
            unsafe {
                match (rv, cv) {
                    (8, 3) => avx512::kernel_nt::<8, 3>(kc, a, ao, b, bo, next, out),
                    (8, 2) => avx512::kernel_nt::<8, 2>(kc, a, ao, b, bo, next, out),
                    (8, 1) => avx512::kernel_nt::<8, 1>(kc, a, ao, b, bo, next, out),
                    (7, 3) => avx512::kernel_nt::<7, 3>(kc, a, ao, b, bo, next, out),
                    (7, 2) => avx512::kernel_nt::<7, 2>(kc, a, ao, b, bo, next, out),
                    (7, 1) => avx512::kernel_nt::<7, 1>(kc, a, ao, b, bo, next, out),
                    (6, 3) => avx512::kernel_nt::<6, 3>(kc, a, ao, b, bo, next, out),
                    (6, 2) => avx512::kernel_nt::<6, 2>(kc, a, ao, b, bo, next, out),
                    (6, 1) => avx512::kernel_nt::<6, 1>(kc, a, ao, b, bo, next, out),
                    (5, 3) => avx512::kernel_nt::<5, 3>(kc, a, ao, b, bo, next, out),
                    (5, 2) => avx512::kernel_nt::<5, 2>(kc, a, ao, b, bo, next, out),
                    (5, 1) => avx512::kernel_nt::<5, 1>(kc, a, ao, b, bo, next, out),
                    (4, 3) => avx512::kernel_nt::<4, 3>(kc, a, ao, b, bo, next, out),
                    (4, 2) => avx512::kernel_nt::<4, 2>(kc, a, ao, b, bo, next, out),
                    (4, 1) => avx512::kernel_nt::<4, 1>(kc, a, ao, b, bo, next, out),
                    (3, 3) => avx512::kernel_nt::<3, 3>(kc, a, ao, b, bo, next, out),
                    (3, 2) => avx512::kernel_nt::<3, 2>(kc, a, ao, b, bo, next, out),
                    (3, 1) => avx512::kernel_nt::<3, 1>(kc, a, ao, b, bo, next, out),
                    (2, 3) => avx512::kernel_nt::<2, 3>(kc, a, ao, b, bo, next, out),
                    (2, 2) => avx512::kernel_nt::<2, 2>(kc, a, ao, b, bo, next, out),
                    (2, 1) => avx512::kernel_nt::<2, 1>(kc, a, ao, b, bo, next, out),
                    (1, 3) => avx512::kernel_nt::<1, 3>(kc, a, ao, b, bo, next, out),
                    (1, 2) => avx512::kernel_nt::<1, 2>(kc, a, ao, b, bo, next, out),
                    _ => avx512::kernel_nt::<1, 1>(kc, a, ao, b, bo, next, out),
                }
            }
            return;
        }
        #[cfg(target_arch = "x86_64")]
        if self.level == SimdLevel::Avx2 {
            let (a, b) = (self.a, self.b);
            // SAFETY: the level is AVX2 only when the CPU reports AVX2 and FMA; every row read
            // (`ao[r] .. ao[r] + kc`, `bo[c] .. bo[c] + kc`) is in bounds as argued above, and
            // `ao`/`bo` hold `rv`/`cv` entries.
            unsafe {
                match (rv, cv) {
                    (4, 3) => avx2::kernel_nt::<4, 3>(kc, a, ao, b, bo, next, out),
                    (4, 2) => avx2::kernel_nt::<4, 2>(kc, a, ao, b, bo, next, out),
                    (4, 1) => avx2::kernel_nt::<4, 1>(kc, a, ao, b, bo, next, out),
                    (3, 3) => avx2::kernel_nt::<3, 3>(kc, a, ao, b, bo, next, out),
                    (3, 2) => avx2::kernel_nt::<3, 2>(kc, a, ao, b, bo, next, out),
                    (3, 1) => avx2::kernel_nt::<3, 1>(kc, a, ao, b, bo, next, out),
                    (2, 3) => avx2::kernel_nt::<2, 3>(kc, a, ao, b, bo, next, out),
                    (2, 2) => avx2::kernel_nt::<2, 2>(kc, a, ao, b, bo, next, out),
                    (2, 1) => avx2::kernel_nt::<2, 1>(kc, a, ao, b, bo, next, out),
                    (1, 3) => avx2::kernel_nt::<1, 3>(kc, a, ao, b, bo, next, out),
                    (1, 2) => avx2::kernel_nt::<1, 2>(kc, a, ao, b, bo, next, out),
                    _ => avx2::kernel_nt::<1, 1>(kc, a, ao, b, bo, next, out),
                }
            }
            return;
        }
        scalar_kernel_nt(kc, self.a, ao, self.b, bo, out);
    }
}

/// Portable micro-kernel of [`gemm_nt`]: eight partial sums per dot product, added pairwise,
/// in the same order as the SIMD kernel.
fn scalar_kernel_nt(
    kc: usize,
    a: &[f32],
    ao: &[usize],
    b: &[f32],
    bo: &[usize],
    out: &mut [[f32; CT]; RT],
) {
    for (r, &oa) in ao.iter().enumerate() {
        let ar = &a[oa..oa + kc];
        for (c, &ob) in bo.iter().enumerate() {
            let br = &b[ob..ob + kc];
            let mut lanes = [0.0f32; 8];
            let k8 = kc / 8 * 8;
            for (ac, bc) in ar[..k8].chunks_exact(8).zip(br[..k8].chunks_exact(8)) {
                for l in 0..8 {
                    lanes[l] += ac[l] * bc[l];
                }
            }
            let mut s = hsum8(&lanes);
            for kk in k8..kc {
                s += ar[kk] * br[kk];
            }
            out[r][c] = s;
        }
    }
}

/// Fixed-order sum of eight lanes.
fn hsum8(l: &[f32; 8]) -> f32 {
    ((l[0] + l[4]) + (l[2] + l[6])) + ((l[1] + l[5]) + (l[3] + l[7]))
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::{hsum8, ATile, CT, MR, NR, RT};
    use std::arch::x86_64::*;

    /// `pack[(s * kc + kk) * NR..][..NR] = b[rows[kk] + j + s * NR..][..NR]` for `s < full`,
    /// `kc = rows.len()`.
    ///
    /// # Safety
    /// The CPU must support AVX2; `rows[kk] + j + full * NR <= b.len()` for every `kk` and
    /// `full * rows.len() * NR <= pack.len()`.
    #[target_feature(enable = "avx2")]
    pub unsafe fn pack_b(pack: &mut [f32], b: &[f32], rows: &[usize], j: usize, full: usize) {
        let kc = rows.len();
        let dst = pack.as_mut_ptr();
        for (kk, &r) in rows.iter().enumerate() {
            let src = b.as_ptr().add(r + j);
            for s in 0..full {
                let d = dst.add((s * kc + kk) * NR);
                _mm256_storeu_ps(d, _mm256_loadu_ps(src.add(s * NR)));
                _mm256_storeu_ps(d.add(8), _mm256_loadu_ps(src.add(s * NR + 8)));
            }
        }
    }

    /// `out[r][..] = sum_k A(r, k) * b[k * NR..][..NR]` for `r < R`.
    ///
    /// # Safety
    /// The CPU must support AVX2 and FMA; `a` must read `kc` steps of `R` rows and
    /// `b.len() >= kc * NR`.
    #[target_feature(enable = "avx2,fma")]
    pub unsafe fn kernel_nn<const R: usize, T: ATile>(
        kc: usize,
        mut ap: T,
        b: &[f32],
        out: &mut [f32; MR * NR],
    ) {
        let mut acc = [[_mm256_setzero_ps(); 2]; R];
        let mut bp = b.as_ptr();
        for _ in 0..kc {
            // SAFETY: `kc` steps of NR values of B and MR values of A are in bounds by the contract.
            let b0 = _mm256_loadu_ps(bp);
            let b1 = _mm256_loadu_ps(bp.add(8));
            for (r, acc) in acc.iter_mut().enumerate() {
                let av = _mm256_set1_ps(ap.get(r));
                acc[0] = _mm256_fmadd_ps(av, b0, acc[0]);
                acc[1] = _mm256_fmadd_ps(av, b1, acc[1]);
            }
            ap.advance();
            bp = bp.add(NR);
        }
        let op = out.as_mut_ptr();
        for (r, acc) in acc.iter().enumerate() {
            // SAFETY: `r < R <= MR`, so both stores stay inside the MR * NR tile.
            _mm256_storeu_ps(op.add(r * NR), acc[0]);
            _mm256_storeu_ps(op.add(r * NR + 8), acc[1]);
        }
    }

    /// `out[r][c] = sum_{k < kc} a[ao[r] + k] * b[bo[c] + k]` for `r < R`, `c < C`, while
    /// prefetching the rows at `next` (the next tile's B rows: they come from L2 or memory,
    /// and without it the first loads of each new row stall the tile).
    ///
    /// # Safety
    /// The CPU must support AVX2 and FMA; `ao.len() >= R`, `bo.len() >= C`,
    /// `ao[r] + kc <= a.len()` and `bo[c] + kc <= b.len()`.
    #[target_feature(enable = "avx2,fma")]
    pub unsafe fn kernel_nt<const R: usize, const C: usize>(
        kc: usize,
        a: &[f32],
        ao: &[usize],
        b: &[f32],
        bo: &[usize],
        next: &[usize; CT],
        out: &mut [[f32; CT]; RT],
    ) {
        let mut acc = [[_mm256_setzero_ps(); C]; R];
        // Prefetch addresses only (never dereferenced, so wrapping arithmetic).
        let mut pn = [b.as_ptr(); C];
        for c in 0..C {
            pn[c] = b.as_ptr().wrapping_add(next[c]);
        }
        let mut pa = [a.as_ptr(); R];
        let mut pb = [b.as_ptr(); C];
        for r in 0..R {
            pa[r] = a.as_ptr().add(ao[r]);
        }
        for c in 0..C {
            pb[c] = b.as_ptr().add(bo[c]);
        }
        let k8 = kc / 8 * 8;
        let mut k = 0;
        while k < k8 {
            // B vectors in registers, A one row at a time: 12 accumulators + 3 + 1 = 16 ymm,
            // no spills.
            let mut bv = [_mm256_setzero_ps(); C];
            for c in 0..C {
                bv[c] = _mm256_loadu_ps(pb[c].add(k));
            }
            // One cache line of each next B row every other step.
            if k % 16 == 0 {
                for p in &pn {
                    _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add(k) as *const i8);
                }
            }
            for r in 0..R {
                let av = _mm256_loadu_ps(pa[r].add(k));
                for c in 0..C {
                    acc[r][c] = _mm256_fmadd_ps(av, bv[c], acc[r][c]);
                }
            }
            k += 8;
        }
        let mut lanes = [0.0f32; 8];
        for r in 0..R {
            for c in 0..C {
                // SAFETY: `lanes` holds eight f32.
                _mm256_storeu_ps(lanes.as_mut_ptr(), acc[r][c]);
                let mut s = hsum8(&lanes);
                for kk in k8..kc {
                    s += *pa[r].add(kk) * *pb[c].add(kk);
                }
                out[r][c] = s;
            }
        }
    }
}

// AVX-512 intrinsics and `target_feature(enable = "avx512f")` are stable since Rust 1.89
// (the workspace's rust-version).
#[cfg(target_arch = "x86_64")]
mod avx512 {
    use super::{ATile, CT, MR, NR, RT};
    use std::arch::x86_64::*;

    /// As `avx2::pack_b`, one 16-float vector per strip row.
    ///
    /// # Safety
    /// The CPU must support AVX-512F; `rows[kk] + j + full * NR <= b.len()` for every `kk` and
    /// `full * rows.len() * NR <= pack.len()`.
    #[target_feature(enable = "avx512f")]
    pub unsafe fn pack_b(pack: &mut [f32], b: &[f32], rows: &[usize], j: usize, full: usize) {
        let kc = rows.len();
        let dst = pack.as_mut_ptr();
        for (kk, &r) in rows.iter().enumerate() {
            let src = b.as_ptr().add(r + j);
            for s in 0..full {
                _mm512_storeu_ps(
                    dst.add((s * kc + kk) * NR),
                    _mm512_loadu_ps(src.add(s * NR)),
                );
            }
        }
    }

    /// `G` tiles: `out[q][r][..] = sum_k A(r, k) * b[q * kc * NR + k * NR..][..NR]` for
    /// `r < R`, `q < G`.
    ///
    /// # Safety
    /// The CPU must support AVX-512F; `a` must read `kc` steps of `R` rows,
    /// `b.len() >= G * kc * NR`, `G <= 4`.
    #[target_feature(enable = "avx512f")]
    pub unsafe fn kernel_nn_group<const R: usize, const G: usize, T: ATile>(
        kc: usize,
        mut ap: T,
        b: &[f32],
        out: &mut [[f32; MR * NR]; 4],
    ) {
        let mut acc = [[_mm512_setzero_ps(); G]; R];
        let mut bp = [b.as_ptr(); G];
        for (q, p) in bp.iter_mut().enumerate() {
            *p = b.as_ptr().add(q * kc * NR);
        }
        for _ in 0..kc {
            // SAFETY: `kc` steps of NR values from each strip and MR from A are in bounds.
            let mut v = [_mm512_setzero_ps(); G];
            for q in 0..G {
                v[q] = _mm512_loadu_ps(bp[q]);
                bp[q] = bp[q].add(NR);
            }
            for (r, acc) in acc.iter_mut().enumerate() {
                let av = _mm512_set1_ps(ap.get(r));
                for q in 0..G {
                    acc[q] = _mm512_fmadd_ps(av, v[q], acc[q]);
                }
            }
            ap.advance();
        }
        for (r, acc) in acc.iter().enumerate() {
            for q in 0..G {
                // SAFETY: `r < R <= MR` and `q < G <= 4`: row r of tile q.
                _mm512_storeu_ps(out[q].as_mut_ptr().add(r * NR), acc[q]);
            }
        }
    }

    /// [`kernel_nn_group`] on unpacked B, into C: strip q is the lanes of `mask[q]` (low bits)
    /// of `b[rows[kk] + j + q * NR..]`, zero elsewhere, for `kk < rows.len()`; the tile's row
    /// r, strip q is stored to (`first`) or added to `c[r] + q * NR`, unmasked lanes only.
    /// Prefetches the same rows' next group of columns: the rows are far apart, too many
    /// streams for the hardware prefetcher.
    ///
    /// # Safety
    /// The CPU must support AVX-512F; `a` must read `rows.len()` steps of `R` rows, `G <= 4`,
    /// every unmasked lane is inside `b`, and for `r < R` every unmasked lane of `c[r]` is
    /// writable and aliases nothing else in use.
    #[allow(clippy::too_many_arguments)]
    #[target_feature(enable = "avx512f")]
    pub unsafe fn kernel_nn_direct<const R: usize, const G: usize, T: ATile>(
        mut ap: T,
        b: &[f32],
        rows: &[usize],
        j: usize,
        mask: [u16; 4],
        c: [*mut f32; MR],
        first: bool,
    ) {
        let mut acc = [[_mm512_setzero_ps(); G]; R];
        let base = b.as_ptr().wrapping_add(j);
        for &row in rows {
            let p = base.wrapping_add(row);
            let mut v = [_mm512_setzero_ps(); G];
            for q in 0..G {
                // SAFETY: unmasked lanes are in bounds by the contract.
                v[q] = _mm512_maskz_loadu_ps(mask[q], p.wrapping_add(q * NR));
                _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add((G + q) * NR) as *const i8);
            }
            for (r, acc) in acc.iter_mut().enumerate() {
                let av = _mm512_set1_ps(ap.get(r));
                for q in 0..G {
                    acc[q] = _mm512_fmadd_ps(av, v[q], acc[q]);
                }
            }
            ap.advance();
        }
        for (r, acc) in acc.iter().enumerate() {
            for q in 0..G {
                // SAFETY: unmasked lanes of row r are writable by the contract.
                let p = c[r].wrapping_add(q * NR);
                let v = if first {
                    acc[q]
                } else {
                    _mm512_add_ps(_mm512_maskz_loadu_ps(mask[q], p), acc[q])
                };
                _mm512_mask_storeu_ps(p, mask[q], v);
            }
        }
    }

    /// `out[r][c] = sum_{k < kc} a[ao[r] + k] * b[bo[c] + k]` for `r < R`, `c < C`, 16 k at a
    /// time with a masked last step, prefetching the rows at `next` as the AVX2 kernel.
    ///
    /// # Safety
    /// The CPU must support AVX-512F; `ao.len() >= R`, `bo.len() >= C`,
    /// `ao[r] + kc <= a.len()` and `bo[c] + kc <= b.len()`.
    #[target_feature(enable = "avx512f")]
    pub unsafe fn kernel_nt<const R: usize, const C: usize>(
        kc: usize,
        a: &[f32],
        ao: &[usize],
        b: &[f32],
        bo: &[usize],
        next: &[usize; CT],
        out: &mut [[f32; CT]; RT],
    ) {
        let mut acc = [[_mm512_setzero_ps(); C]; R];
        // Prefetch addresses only (never dereferenced, so wrapping arithmetic).
        let mut pn = [b.as_ptr(); C];
        for c in 0..C {
            pn[c] = b.as_ptr().wrapping_add(next[c]);
        }
        let mut pa = [a.as_ptr(); R];
        let mut pb = [b.as_ptr(); C];
        for r in 0..R {
            pa[r] = a.as_ptr().add(ao[r]);
        }
        for c in 0..C {
            pb[c] = b.as_ptr().add(bo[c]);
        }
        let k16 = kc / 16 * 16;
        let mut k = 0;
        while k < k16 {
            // SAFETY: `k + 16 <= kc`; every row has `kc` readable values by the contract.
            // B vectors in registers, A one row at a time: up to 24 accumulators + 3 + 1.
            let mut bv = [_mm512_setzero_ps(); C];
            for c in 0..C {
                bv[c] = _mm512_loadu_ps(pb[c].add(k));
                _mm_prefetch::<_MM_HINT_T0>(pn[c].wrapping_add(k) as *const i8);
            }
            for r in 0..R {
                let av = _mm512_loadu_ps(pa[r].add(k));
                for c in 0..C {
                    acc[r][c] = _mm512_fmadd_ps(av, bv[c], acc[r][c]);
                }
            }
            k += 16;
        }
        if k < kc {
            // SAFETY: masked-off lanes are not read, so only `k..kc` is touched. Same register
            // use as the main loop (B in registers, A a row at a time).
            let mask: __mmask16 = ((1u32 << (kc - k)) - 1) as __mmask16;
            let mut bv = [_mm512_setzero_ps(); C];
            for c in 0..C {
                bv[c] = _mm512_maskz_loadu_ps(mask, pb[c].add(k));
            }
            for r in 0..R {
                let av = _mm512_maskz_loadu_ps(mask, pa[r].add(k));
                for c in 0..C {
                    acc[r][c] = _mm512_fmadd_ps(av, bv[c], acc[r][c]);
                }
            }
        }
        for c in 0..C {
            let mut col = [_mm512_setzero_ps(); RT];
            for r in 0..R {
                col[r] = acc[r][c];
            }
            let sums = reduce8(col);
            for r in 0..R {
                out[r][c] = sums[r];
            }
        }
    }

    /// The lane sums of eight vectors at once (23 shuffles and adds instead of eight separate
    /// reductions of 8 each, which cost a quarter of a 512-long dot-product tile).
    ///
    /// # Safety
    /// The CPU must support AVX-512F.
    #[target_feature(enable = "avx512f")]
    #[inline]
    unsafe fn reduce8(v: [__m512; RT]) -> [f32; RT] {
        // Halves: [a.lo + a.hi | b.lo + b.hi], 8-lane partials of a and b.
        // Macros, not closures: the shuffles must inline into this AVX-512 function.
        macro_rules! half {
            ($a:expr, $b:expr) => {
                _mm512_add_ps(
                    _mm512_shuffle_f32x4::<0x44>($a, $b),
                    _mm512_shuffle_f32x4::<0xEE>($a, $b),
                )
            };
        }
        let (w0, w1, w2, w3) = (
            half!(v[0], v[1]),
            half!(v[2], v[3]),
            half!(v[4], v[5]),
            half!(v[6], v[7]),
        );
        // Quarters: 128-bit lane q holds the 4-lane partial of vector q (x0) or q + 4 (x1).
        macro_rules! quarter {
            ($a:expr, $b:expr) => {
                _mm512_add_ps(
                    _mm512_shuffle_f32x4::<0x88>($a, $b),
                    _mm512_shuffle_f32x4::<0xDD>($a, $b),
                )
            };
        }
        let (x0, x1) = (quarter!(w0, w1), quarter!(w2, w3));
        // Per 128-bit lane q: [pair sums of x0 (vector q), pair sums of x1 (vector q + 4)].
        let y = _mm512_add_ps(
            _mm512_shuffle_ps::<0x88>(x0, x1),
            _mm512_shuffle_ps::<0xDD>(x0, x1),
        );
        // Lane 4q: total of vector q; lane 4q + 2: of vector q + 4.
        let z = _mm512_add_ps(y, _mm512_shuffle_ps::<0xB1>(y, y));
        let mut lanes = [0.0f32; 16];
        _mm512_storeu_ps(lanes.as_mut_ptr(), z);
        std::array::from_fn(|r| lanes[4 * (r % 4) + 2 * (r / 4)])
    }
}
