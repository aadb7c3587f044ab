//! Receptive-field skipping: which output positions of a layer can depend on a covered pixel,
//! and GEMMs that compute only those columns plus one representative per background class.
//!
//! Every position of every layer gets a *class*: [`ACTIVE`] when its input window holds an
//! active position (at the input: a covered pixel), otherwise the interned tuple of its
//! window's classes (zero padding is the class [`ZERO`], like uncovered input pixels). Two
//! positions of one class read identical GEMM columns, so they hold identical values: one
//! computed representative fills the others. Away from the frame border the background
//! classes repeat with the layer's period (a power of two); along the border, windows that
//! read padding form their own classes. The GEMM's result per element depends neither on the
//! number of columns nor on which are present (its K blocking is fixed; each column is one
//! FMA chain in K order), so the values are bit-identical to evaluating every column.

use super::gemm::{gemm_nn, PackedA};
use super::tensor::{par_min_items, pool};
use rayon::prelude::*;
use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

/// Class of a position whose value may depend on a covered pixel (never shared).
pub const ACTIVE: u32 = u32::MAX;
/// Class of a value that is exactly `+0.0` in every channel: uncovered input pixels and the
/// zero padding every convolution reads outside the frame.
pub const ZERO: u32 = 0;

/// Value classes over an `h x w` grid, row-major: two positions of one class hold the same
/// value in every channel (bit for bit); [`ACTIVE`] positions are each their own class.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Classes {
    /// Height.
    pub h: usize,
    /// Width.
    pub w: usize,
    /// `h * w` class ids.
    pub ids: Vec<u32>,
    /// Bound on the ids other than [`ACTIVE`].
    pub count: u32,
    /// Period (a power of two) with which the background classes repeat away from the
    /// border: only a hint that speeds up the classification; correctness does not rest on it.
    pub period: usize,
}

/// Class ids of an `h x w` output whose position (y, x) has the window key `key(y, x, ..)`:
/// equal keys, equal class. When `same_rows(y, y - period)` says that two output rows read
/// identical input rows, the row is copied; otherwise a position whose key equals that of
/// the position `period` rows up (as in the periodic background) reuses its id without
/// hashing.
fn classify(
    h: usize,
    w: usize,
    period: usize,
    key: impl Fn(usize, usize, &mut [u32; KEY]),
    same_rows: impl Fn(usize, usize) -> bool,
) -> (Vec<u32>, u32) {
    let mut int = Interner::new();
    let mut ids = Vec::with_capacity(h * w);
    let (mut k, mut up) = ([ZERO; KEY], [ZERO; KEY]);
    for y in 0..h {
        if y >= period && same_rows(y, y - period) {
            ids.extend_from_within((y - period) * w..(y - period + 1) * w);
            continue;
        }
        for x in 0..w {
            key(y, x, &mut k);
            if y >= period {
                let above = ids[(y - period) * w + x];
                if above != ACTIVE {
                    key(y - period, x, &mut up);
                    if up == k {
                        ids.push(above);
                        continue;
                    }
                }
            }
            ids.push(int.class(&k));
        }
    }
    (ids, int.next)
}

/// Interns window keys (an output position's class is the tuple of its inputs' classes).
struct Interner {
    map: HashMap<[u32; KEY], u32, BuildHasherDefault<KeyHasher>>,
    next: u32,
    /// The last key and its class: runs of equal windows skip the hash.
    last: Option<([u32; KEY], u32)>,
}

/// Multiply-rotate hash of the `u32` words of a key (the default SipHash costs more than the
/// rest of the planning; keys are not adversarial).
#[derive(Default)]
struct KeyHasher(u64);

impl Hasher for KeyHasher {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write(&mut self, bytes: &[u8]) {
        let mut chunks = bytes.chunks_exact(8);
        for c in &mut chunks {
            self.write_u64(u64::from_le_bytes(c.try_into().expect("8 bytes")));
        }
        chunks
            .remainder()
            .iter()
            .for_each(|&b| self.write_u64(b.into()));
    }

    fn write_u64(&mut self, v: u64) {
        self.0 = (self.0.rotate_left(5) ^ v).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }

    fn write_u32(&mut self, v: u32) {
        self.write_u64(v.into());
    }

    fn write_usize(&mut self, v: usize) {
        self.write_u32(v as u32);
        self.write_u32((v as u64 >> 32) as u32);
    }
}

/// Longest key: 16 taps plus a tag.
const KEY: usize = 17;

impl Interner {
    fn new() -> Self {
        Interner {
            map: HashMap::default(),
            next: ZERO + 1,
            last: None,
        }
    }

    /// The class of `key`, or [`ACTIVE`] when any of its entries is.
    fn class(&mut self, key: &[u32; KEY]) -> u32 {
        if key.contains(&ACTIVE) {
            return ACTIVE;
        }
        if let Some((k, id)) = &self.last {
            if k == key {
                return *id;
            }
        }
        let next = &mut self.next;
        let id = *self.map.entry(*key).or_insert_with(|| {
            *next += 1;
            *next - 1
        });
        self.last = Some((*key, id));
        id
    }
}

impl Classes {
    /// Input classes of an `h x w` frame: `active` flags (`h * w`) are [`ACTIVE`], the rest
    /// [`ZERO`] (uncovered features are zero).
    pub fn input(h: usize, w: usize, active: &[bool]) -> Self {
        assert_eq!(active.len(), h * w, "input classes");
        Classes {
            h,
            w,
            ids: active
                .iter()
                .map(|&a| if a { ACTIVE } else { ZERO })
                .collect(),
            count: ZERO + 1,
            period: 1,
        }
    }

    /// The class at (y, x) as signed coordinates; [`ZERO`] outside the grid (zero padding).
    fn at(&self, y: isize, x: isize) -> u32 {
        if y >= 0 && x >= 0 && (y as usize) < self.h && (x as usize) < self.w {
            self.ids[y as usize * self.w + x as usize]
        } else {
            ZERO
        }
    }

    /// Whether input rows `a` and `b` (signed; outside the grid reads as [`ZERO`] padding)
    /// hold the same classes.
    fn same_row(&self, a: isize, b: isize) -> bool {
        let row = |y: isize| {
            (y >= 0 && (y as usize) < self.h)
                .then(|| &self.ids[y as usize * self.w..(y as usize + 1) * self.w])
        };
        match (row(a), row(b)) {
            (None, None) => true,
            (Some(x), Some(y)) => x == y,
            _ => false,
        }
    }

    /// Number of [`ACTIVE`] positions.
    pub fn active(&self) -> usize {
        self.ids.iter().filter(|&&c| c == ACTIVE).count()
    }

    /// Classes of the channel concatenation of two maps of the same size.
    pub fn concat(&self, other: &Classes) -> Classes {
        assert!(
            self.h == other.h && self.w == other.w,
            "classes concat size"
        );
        let mut int = Interner::new();
        let ids = self
            .ids
            .iter()
            .zip(&other.ids)
            .map(|(&a, &b)| {
                let mut key = [ZERO; KEY];
                (key[0], key[1]) = (a, b);
                if (a, b) == (ZERO, ZERO) {
                    ZERO
                } else {
                    int.class(&key)
                }
            })
            .collect();
        Classes {
            h: self.h,
            w: self.w,
            ids,
            count: int.next,
            period: self.period.max(other.period),
        }
    }

    /// Output classes of a `k x k` convolution (`k * k <= 16`; stride, zero padding `pad`) with
    /// output size `h_out x w_out`: the tuple of the window's classes.
    pub fn conv(
        &self,
        k: usize,
        stride: usize,
        pad: usize,
        (h_out, w_out): (usize, usize),
    ) -> Self {
        assert!(k * k < KEY, "window too large for a class key");
        let period = self.period.div_ceil(stride);
        let top = |oy: usize| (oy * stride) as isize - pad as isize;
        let (ids, count) = classify(
            h_out,
            w_out,
            period,
            |oy, ox, key| {
                let (y0, x0) = (top(oy), (ox * stride) as isize - pad as isize);
                for (t, v) in key[..k * k].iter_mut().enumerate() {
                    *v = self.at(y0 + (t / k) as isize, x0 + (t % k) as isize);
                }
            },
            |a, b| (0..k as isize).all(|t| self.same_row(top(a) + t, top(b) + t)),
        );
        Classes {
            h: h_out,
            w: w_out,
            ids,
            count,
            period,
        }
    }

    /// Output classes (`2h x 2w`) of a 4x4 stride-2 padding-1 transposed convolution: output
    /// (2y + py, 2x + px) reads the 2x2 input window at (y + py - 1, x + px - 1) with the
    /// weights of phase (py, px), which is part of the key.
    pub fn tconv(&self) -> Self {
        let (h, w) = (2 * self.h, 2 * self.w);
        let period = 2 * self.period;
        let top = |oy: usize| (oy / 2 + oy % 2) as isize - 1;
        let (ids, count) = classify(
            h,
            w,
            period,
            |oy, ox, key| {
                let (y0, x0) = (top(oy), (ox / 2 + ox % 2) as isize - 1);
                key[4] = (2 * (oy % 2) + ox % 2) as u32;
                for (t, v) in key[..4].iter_mut().enumerate() {
                    *v = self.at(y0 + (t / 2) as isize, x0 + (t % 2) as isize);
                }
            },
            // `period` is even, so rows `period` apart have the same phase.
            |a, b| (0..2).all(|t| self.same_row(top(a) + t, top(b) + t)),
        );
        Classes {
            h,
            w,
            ids,
            count,
            period,
        }
    }

    /// Nearest x2 upsampling.
    pub fn upsample2(&self) -> Self {
        let (h, w) = (2 * self.h, 2 * self.w);
        let ids = (0..h * w)
            .map(|i| self.ids[(i / w / 2) * self.w + (i % w) / 2])
            .collect();
        Classes {
            h,
            w,
            ids,
            count: self.count,
            period: 2 * self.period,
        }
    }
}

/// Which GEMM columns to compute and how to fill the others.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ColPlan {
    /// GEMM columns computed (active positions and one representative per inactive phase),
    /// ascending.
    pub cols: Vec<usize>,
    /// `(column, representative column)` for every inactive position not computed.
    pub fill: Vec<(usize, usize)>,
    /// Active positions among the planned ones.
    pub active: usize,
    /// Positions planned (computed or filled).
    pub positions: usize,
}

impl ColPlan {
    /// Plans from `(gemm column, class)` of every position that is needed, in ascending
    /// column order; positions of one class (other than [`ACTIVE`]) must read identical GEMM
    /// columns. `count` bounds the classes.
    pub fn new(positions: impl Iterator<Item = (usize, u32)>, count: u32) -> Self {
        let mut rep: Vec<Option<usize>> = vec![None; count as usize];
        let mut plan = ColPlan::default();
        for (col, class) in positions {
            plan.positions += 1;
            if class == ACTIVE {
                plan.active += 1;
                plan.cols.push(col);
            } else if let Some(r) = rep[class as usize] {
                plan.fill.push((col, r));
            } else {
                rep[class as usize] = Some(col);
                plan.cols.push(col);
            }
        }
        plan
    }

    /// Runs `(start, len)` of GEMM columns that cover [`Self::cols`]: planned columns less
    /// than [`SPAN_GAP`] apart share a run (the columns between are computed too, harmlessly).
    pub fn spans(&self) -> Vec<(usize, usize)> {
        let mut spans: Vec<(usize, usize)> = Vec::new();
        for &c in &self.cols {
            match spans.last_mut() {
                Some((s, len)) if c < *s + *len + SPAN_GAP => *len = c + 1 - *s,
                _ => spans.push((c, 1)),
            }
        }
        spans
    }

    /// GEMM columns computed out of `n`: the runs' total, or `n` when that is not clearly
    /// less ([`gemm_planned`] then computes everything).
    pub fn computed(&self, n: usize) -> usize {
        let c: usize = self.spans().iter().map(|s| s.1).sum();
        if 10 * c < 9 * n {
            c
        } else {
            n
        }
    }
}

/// Planned columns closer than this are computed in one run (one micro-kernel strip is 16
/// columns wide, so shorter gaps cost little).
pub const SPAN_GAP: usize = 32;

/// `c_out x n` raw GEMM output (row stride `n`) of `a` on the B operand `B(k, j) =
/// buf[rows[k] + j]`, exact at every planned column of `plan` (other columns are unspecified),
/// and the number of columns computed ([`ColPlan::computed`]). Each run of
/// [`ColPlan::spans`] is one GEMM on the same buffer (rows shifted to the run's start), the
/// runs in parallel; then every filled position copies its representative.
pub fn gemm_planned(
    a: &PackedA,
    buf: &[f32],
    rows: &[usize],
    n: usize,
    plan: &ColPlan,
) -> (Vec<f32>, usize) {
    let m = a.m();
    let mut out = pool::scratch(m * n);
    let computed = plan.computed(n);
    if computed == n {
        gemm_nn(a, buf, rows, n, &mut out, n, false);
        return (out, n);
    }
    let spans = plan.spans();
    let parts: Vec<Vec<f32>> = spans
        .par_iter()
        .map(|&(start, len)| {
            let shifted: Vec<usize> = rows.iter().map(|r| r + start).collect();
            let mut c = pool::scratch(m * len);
            gemm_nn(a, buf, &shifted, len, &mut c, len, false);
            c
        })
        .collect();
    out.par_chunks_mut(n)
        .with_min_len(par_min_items(n))
        .enumerate()
        .for_each(|(o, dst)| {
            for (&(start, len), c) in spans.iter().zip(&parts) {
                dst[start..start + len].copy_from_slice(&c[o * len..(o + 1) * len]);
            }
            plan.fill.iter().for_each(|&(d, s)| dst[d] = dst[s]);
        });
    parts.into_iter().for_each(pool::recycle);
    (out, computed)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn conv_classes_dilate_and_share_the_background() {
        let mut a = vec![false; 64];
        a[3 * 8 + 4] = true;
        let c = Classes::input(8, 8, &a).conv(4, 2, 1, (4, 4));
        // Input row 3 is read by outputs oy with 2oy-1 <= 3 <= 2oy+2: oy = 1, 2 (same for x).
        let set: Vec<usize> = (0..16).filter(|&i| c.ids[i] == ACTIVE).collect();
        assert_eq!(set, vec![5, 6, 9, 10]);
        // Uncovered inputs are zero like the padding: one class for all the rest.
        assert!(c.ids.iter().all(|&i| i == ACTIVE || i == c.ids[0]));
        // One level deeper, padding differs from the background: border classes appear.
        let empty = Classes::input(16, 16, &[false; 256]).conv(4, 2, 1, (8, 8));
        let d = empty.conv(4, 2, 1, (4, 4));
        assert_eq!(d.active(), 0);
        assert_eq!((d.ids[0] == d.ids[5], d.ids[5] == d.ids[6]), (false, true));
        // Corners, edges and interior: 9 classes.
        let mut u = d.ids.clone();
        u.sort();
        u.dedup();
        assert_eq!(u.len(), 9);
        let t = d.tconv();
        assert_eq!(t.active(), 0);
        assert_ne!(t.ids[2 * 8 + 2], t.ids[2 * 8 + 3], "phases differ");
    }

    #[test]
    fn plan_picks_one_representative_per_phase() {
        let pos = (0..8).map(|c| (c, if c == 5 { ACTIVE } else { c as u32 % 2 }));
        let p = ColPlan::new(pos, 2);
        assert_eq!(p.cols, vec![0, 1, 5]);
        assert_eq!(p.fill, vec![(2, 0), (3, 1), (4, 0), (6, 0), (7, 1)]);
        assert_eq!((p.active, p.positions), (1, 8));
        let far = ColPlan {
            cols: vec![3, 4, 30, 100],
            ..ColPlan::default()
        };
        assert_eq!(far.spans(), vec![(3, 28), (100, 1)]);
        assert_eq!((far.computed(1000), far.computed(30)), (29, 30));
    }
}
