//! Adam (PyTorch's formulation, with bias correction) for dense parameter groups, and a lazy
//! row-sparse variant for neural-texture texels.

use dnr_runtime::nn::simd::prefetch;
use dnr_runtime::nn::simd::widest;
use rayon::prelude::*;

/// Adam hyper-parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdamConfig {
    /// Learning rate.
    pub lr: f32,
    /// First-moment decay.
    pub beta1: f32,
    /// Second-moment decay.
    pub beta2: f32,
    /// Added to the denominator.
    pub eps: f32,
    /// Decoupled weight decay (AdamW): each update first scales the parameter by
    /// `1 - lr * weight_decay`. 0 (the default) leaves Adam exactly as it was.
    pub weight_decay: f32,
}

impl Default for AdamConfig {
    /// lr 1e-3, betas (0.9, 0.999), eps 1e-8.
    fn default() -> Self {
        AdamConfig {
            lr: 1e-3,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
            weight_decay: 0.0,
        }
    }
}

/// Step counts whose Adam constants a [`SparseAdamRows`] keeps.
const CONSTS_SLOTS: usize = 16;

/// Elements per parallel chunk (fixed, so results do not depend on the thread count).
const CHUNK: usize = 1 << 14;

/// The per-step constants of an Adam update, with `step_size = lr / (1 - beta1^t)` and
/// `bc2 = sqrt(1 - beta2^t)`: `step = step_size * bc2` and `eps_bc2 = eps * bc2`; `keep =
/// 1 - lr * weight_decay` scales the parameter first (decoupled decay, not bias-corrected,
/// as PyTorch's AdamW).
#[derive(Clone, Copy)]
struct StepConsts {
    beta1: f32,
    beta2: f32,
    step: f32,
    eps_bc2: f32,
    keep: f32,
}

impl StepConsts {
    /// Never inlined: LLVM may expand `powi` inline at one call site and call the library at
    /// another, and the two can differ in the last bit; one copy gives every optimiser (dense,
    /// fused, sparse) the same constants.
    #[inline(never)]
    fn new(cfg: &AdamConfig, t: u64) -> Self {
        let t = t.min(i32::MAX as u64) as i32;
        let step_size = cfg.lr / (1.0 - cfg.beta1.powi(t));
        let bc2 = (1.0 - cfg.beta2.powi(t)).sqrt();
        StepConsts {
            beta1: cfg.beta1,
            beta2: cfg.beta2,
            step: step_size * bc2,
            eps_bc2: cfg.eps * bc2,
            keep: 1.0 - cfg.lr * cfg.weight_decay,
        }
    }

    /// One Adam update of a single value. PyTorch computes
    /// `step_size * m / (sqrt(v) / bc2 + eps)`; multiplying through by `bc2` gives the same
    /// value (to rounding) with one division instead of two, a third less of the arithmetic
    /// that bounds the texel update (square roots and divisions).
    #[inline(always)]
    fn update(&self, p: &mut f32, g: f32, m: &mut f32, v: &mut f32) {
        *m = self.beta1 * *m + (1.0 - self.beta1) * g;
        *v = self.beta2 * *v + (1.0 - self.beta2) * g * g;
        let denom = v.sqrt() + self.eps_bc2;
        // `keep` is exactly 1 without decay, so the product changes no bit then.
        *p = *p * self.keep - self.step * *m / denom;
    }
}

/// Adam state of one dense parameter group (its own step count and learning rate).
#[derive(Clone, Debug, PartialEq)]
pub struct Adam {
    /// Hyper-parameters; `cfg.lr` is this group's learning rate.
    pub cfg: AdamConfig,
    m: Vec<f32>,
    v: Vec<f32>,
    t: u64,
}

impl Adam {
    /// State for `len` parameters.
    pub fn new(len: usize, cfg: AdamConfig) -> Self {
        Adam {
            cfg,
            m: vec![0.0; len],
            v: vec![0.0; len],
            t: 0,
        }
    }

    /// Steps taken.
    pub fn steps(&self) -> u64 {
        self.t
    }

    /// [`Adam::step`], then zeroes `grads` in the same pass (saves the separate zero-grad
    /// sweep over every gradient).
    pub fn step_zero_grad(&mut self, params: &mut [f32], grads: &mut [f32]) {
        assert!(
            params.len() == self.m.len() && grads.len() == self.m.len(),
            "adam: length"
        );
        self.t += 1;
        let k = StepConsts::new(&self.cfg, self.t);
        params
            .par_chunks_mut(CHUNK)
            .zip(grads.par_chunks_mut(CHUNK))
            .zip(
                self.m
                    .par_chunks_mut(CHUNK)
                    .zip(self.v.par_chunks_mut(CHUNK)),
            )
            .for_each(|((p, g), (m, v))| {
                dense_chunk(&k, p, g, m, v);
                g.fill(0.0);
            });
    }

    /// One step: `params -= lr * mhat / (sqrt(vhat) + eps)`. Does not clear `grads`.
    pub fn step(&mut self, params: &mut [f32], grads: &[f32]) {
        assert!(
            params.len() == self.m.len() && grads.len() == self.m.len(),
            "adam: length"
        );
        self.t += 1;
        let k = StepConsts::new(&self.cfg, self.t);
        params
            .par_chunks_mut(CHUNK)
            .zip(grads.par_chunks(CHUNK))
            .zip(
                self.m
                    .par_chunks_mut(CHUNK)
                    .zip(self.v.par_chunks_mut(CHUNK)),
            )
            .for_each(|((p, g), (m, v))| dense_chunk(&k, p, g, m, v));
    }
}

/// [`StepConsts::update`] over a chunk, with the widest vectors the CPU has ([`widest`]): the
/// update is bound by its square root and two divisions, which the baseline build runs four
/// lanes at a time.
fn dense_chunk(k: &StepConsts, p: &mut [f32], g: &[f32], m: &mut [f32], v: &mut [f32]) {
    widest(
        #[inline(always)]
        || {
            let n = p.len().min(g.len()).min(m.len()).min(v.len());
            let (p, g, m, v) = (&mut p[..n], &g[..n], &mut m[..n], &mut v[..n]);
            for i in 0..n {
                k.update(&mut p[i], g[i], &mut m[i], &mut v[i]);
            }
        },
    )
}

/// Rows per parallel block of [`SparseAdam::step`] (fixed, so results do not depend on the
/// thread count; they do not depend on the block size either: rows are independent).
const ROW_BLOCK: usize = 1024;

/// Lazy Adam over rows of `width` values (texels of a neural texture): a step updates only the
/// rows it is given, and each row keeps its own step count for the bias correction.
///
/// Why per-row counts: a row's moments only ever see the steps that touched it, so with a
/// global count a row first touched at step 1000 would get `mhat = 0.1 g / (1 - 0.9^1000)`,
/// `vhat = 0.001 g^2`, an update of about 3 lr, where dense Adam starts with lr. With per-row
/// counts each row behaves exactly like dense Adam on its own gradient sequence (untouched
/// steps skipped, the moments not decayed across them, as TensorFlow's LazyAdam).
#[derive(Clone, Debug, PartialEq)]
pub struct SparseAdam {
    /// Hyper-parameters; `cfg.lr` is the learning rate.
    pub cfg: AdamConfig,
    width: usize,
    m: Vec<f32>,
    v: Vec<f32>,
    t: Vec<u32>,
}

impl SparseAdam {
    /// State for `rows` rows of `width` values.
    pub fn new(rows: usize, width: usize, cfg: AdamConfig) -> Self {
        SparseAdam {
            cfg,
            width,
            m: vec![0.0; rows * width],
            v: vec![0.0; rows * width],
            t: vec![0; rows],
        }
    }

    /// Step count of `row`.
    pub fn row_steps(&self, row: usize) -> u32 {
        self.t[row]
    }

    /// Number of rows.
    pub fn rows(&self) -> usize {
        self.t.len()
    }

    /// Values per row.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Splits the state and `params` (same layout as the moments) into consecutive blocks of
    /// `rows_per_block` rows (the last may be shorter) that can be updated independently,
    /// e.g. in parallel, with [`SparseAdamRows::update`].
    pub fn row_blocks<'a>(
        &'a mut self,
        params: &'a mut [f32],
        rows_per_block: usize,
    ) -> Vec<SparseAdamRows<'a>> {
        assert_eq!(params.len(), self.m.len(), "sparse adam: length");
        assert!(rows_per_block > 0, "sparse adam: empty blocks");
        let (cfg, w) = (self.cfg, self.width);
        let mut out = Vec::with_capacity(self.t.len().div_ceil(rows_per_block));
        let (mut p_rest, mut m_rest, mut v_rest) = (params, &mut self.m[..], &mut self.v[..]);
        for t in self.t.chunks_mut(rows_per_block) {
            let len = t.len() * w;
            let (p, pr) = std::mem::take(&mut p_rest).split_at_mut(len);
            let (m, mr) = std::mem::take(&mut m_rest).split_at_mut(len);
            let (v, vr) = std::mem::take(&mut v_rest).split_at_mut(len);
            (p_rest, m_rest, v_rest) = (pr, mr, vr);
            out.push(SparseAdamRows {
                cfg,
                width: w,
                params: p,
                m,
                v,
                t,
                consts: [None; CONSTS_SLOTS],
            });
        }
        out
    }

    /// Updates the rows listed in `rows` (each at most once, ascending order not required)
    /// from `grads` (same layout as `params`), adding `decay * param` to each gradient first
    /// (lazy L2: only touched rows decay), then zeroes those gradient rows.
    pub fn step(&mut self, params: &mut [f32], grads: &mut [f32], rows: &[u32], decay: f32) {
        let w = self.width;
        assert!(
            params.len() == self.m.len() && grads.len() == self.m.len(),
            "sparse adam: length"
        );
        let nrows = self.t.len();
        // Blocks of rows run in parallel, each on the part of the (sorted) row list that falls
        // in it; rows are independent, so results do not depend on the thread count.
        let sorted: std::borrow::Cow<'_, [u32]> = if rows.is_sorted() {
            rows.into()
        } else {
            let mut r = rows.to_vec();
            r.sort_unstable();
            r.into()
        };
        assert!(
            sorted.windows(2).all(|p| p[0] != p[1]),
            "sparse adam: duplicate row"
        );
        assert!(
            sorted.last().is_none_or(|&r| (r as usize) < nrows),
            "sparse adam: row out of range"
        );
        if w == 0 {
            sorted.iter().for_each(|&r| self.t[r as usize] += 1);
            return;
        }
        self.row_blocks(params, ROW_BLOCK)
            .into_par_iter()
            .zip(grads.par_chunks_mut(ROW_BLOCK * w))
            .enumerate()
            .for_each(|(b, (mut blk, g))| {
                let lo = b * ROW_BLOCK;
                let from = sorted.partition_point(|&r| (r as usize) < lo);
                let to = sorted.partition_point(|&r| (r as usize) < lo + blk.len());
                for &r in &sorted[from..to] {
                    let g = &mut g[(r as usize - lo) * w..][..w];
                    blk.update(r as usize - lo, g, decay);
                    g.fill(0.0);
                }
            });
    }
}

/// A block of consecutive rows of a [`SparseAdam`] with their parameters (from
/// [`SparseAdam::row_blocks`]).
pub struct SparseAdamRows<'a> {
    cfg: AdamConfig,
    width: usize,
    params: &'a mut [f32],
    m: &'a mut [f32],
    v: &'a mut [f32],
    t: &'a mut [u32],
    /// The constants of recent step counts, slot `t % CONSTS_SLOTS`: rows touched in the same
    /// steps share them, and computing them (two `powi`, a square root) costs as much as a
    /// row's update; a texture's rows interleave a few different counts.
    consts: [Option<(u32, StepConsts)>; CONSTS_SLOTS],
}

impl SparseAdamRows<'_> {
    /// Rows in the block.
    pub fn len(&self) -> usize {
        self.t.len()
    }

    /// Whether the block has no rows.
    pub fn is_empty(&self) -> bool {
        self.t.is_empty()
    }

    /// Hints that row `row`'s parameters, moments and step count will be updated soon (both
    /// ends of each row: rows need not start on a cache line).
    #[inline(always)]
    pub fn prefetch(&self, row: usize) {
        let (lo, hi) = (row * self.width, (row + 1) * self.width);
        for a in [&*self.params, &*self.m, &*self.v] {
            prefetch(a, lo);
            prefetch(a, hi.saturating_sub(1));
        }
        prefetch(self.t, row);
    }

    /// One lazy-Adam step of the block's row `row` from its gradient `grad` (`width` values),
    /// with `decay * param` added to the gradient first: exactly what [`SparseAdam::step`]
    /// does to a listed row (the gradient is not cleared here).
    #[inline(always)]
    pub fn update(&mut self, row: usize, grad: &[f32], decay: f32) {
        let w = self.width;
        assert_eq!(grad.len(), w, "sparse adam: gradient row");
        let t = &mut self.t[row];
        *t += 1;
        let slot = &mut self.consts[*t as usize % CONSTS_SLOTS];
        let k = match *slot {
            Some((tc, k)) if tc == *t => k,
            _ => {
                let k = StepConsts::new(&self.cfg, u64::from(*t));
                *slot = Some((*t, k));
                k
            }
        };
        let range = row * w..(row + 1) * w;
        let (p, m, v) = (
            &mut self.params[range.clone()],
            &mut self.m[range.clone()],
            &mut self.v[range],
        );
        for (((p, &g), m), v) in p.iter_mut().zip(grad).zip(m).zip(v) {
            let gi = g + decay * *p;
            k.update(p, gi, m, v);
        }
    }
}

/// The moments and step counts of an optimiser, for checkpoints.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AdamState {
    /// First moments.
    pub m: Vec<f32>,
    /// Second moments.
    pub v: Vec<f32>,
    /// Step count(s): one entry for dense Adam, one per row for the sparse variant.
    pub t: Vec<u64>,
}

impl Adam {
    /// A copy of the moments and step count.
    pub fn state(&self) -> AdamState {
        AdamState {
            m: self.m.clone(),
            v: self.v.clone(),
            t: vec![self.t],
        }
    }

    /// Restores [`Adam::state`]; false (and nothing changed) when the sizes disagree.
    pub fn set_state(&mut self, s: AdamState) -> bool {
        if s.m.len() != self.m.len() || s.v.len() != self.v.len() || s.t.len() != 1 {
            return false;
        }
        (self.m, self.v, self.t) = (s.m, s.v, s.t[0]);
        true
    }
}

impl SparseAdam {
    /// A copy of the moments and per-row step counts.
    pub fn state(&self) -> AdamState {
        AdamState {
            m: self.m.clone(),
            v: self.v.clone(),
            t: self.t.iter().map(|&t| t as u64).collect(),
        }
    }

    /// Restores [`SparseAdam::state`]; false (and nothing changed) when the sizes disagree.
    pub fn set_state(&mut self, s: AdamState) -> bool {
        if s.m.len() != self.m.len() || s.v.len() != self.v.len() || s.t.len() != self.t.len() {
            return false;
        }
        let Ok(t) =
            s.t.iter()
                .map(|&t| u32::try_from(t))
                .collect::<Result<Vec<u32>, _>>()
        else {
            return false;
        };
        (self.m, self.v, self.t) = (s.m, s.v, t);
        true
    }
}
