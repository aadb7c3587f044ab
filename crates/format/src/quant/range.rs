//! Choosing a channel's quantisation range: the `(scale, offset)` whose rounding error is
//! smallest, not the one that covers every value.
//!
//! Learned features are heavy-tailed: a few texels sit far from the rest. Spanning the full
//! minimum-to-maximum range with 16 steps (4 bits) leaves most texels in two or three steps;
//! clamping the rare outliers to the range's ends makes the steps several times finer. The
//! search runs on a per-channel histogram, tries ranges between quantiles of each tail,
//! refines the best by least squares, and keeps it only when its squared error, measured
//! exactly on the same texels, is no larger than the full range's: never worse than the
//! minimum-to-maximum choice (on every texel up to 65536 of them, on an even sample above).

/// Bins of the histogram a channel's range is searched on: far finer than a 4- or 8-bit step.
const BINS: usize = 1024;
/// Texels the histogram and the exact comparison read at most (an even stride through the
/// level): the fit runs every few steps of quantisation-aware fine-tuning, and 65536 samples
/// pin a mean squared error far closer than the candidates differ.
const SAMPLE_TEXELS: usize = 1 << 16;
/// Fractions of the values clamped at each end that the search tries.
const TAILS: [f64; 8] = [0.0, 1e-4, 5e-4, 2e-3, 5e-3, 1e-2, 3e-2, 0.1];
/// Least-squares refinements of the best range found.
const REFINE: usize = 4;

/// Per-channel `(scale, offset)` of texel-interleaved `data` (`channels` values per texel) for
/// `bits`-bit integers (`top = 2^bits - 1`), chosen to minimise the squared rounding error of
/// `offset + scale * clamp(round((v - offset) / scale), 0, top)`. A constant (or empty)
/// channel gets scale 1 and its value as offset.
pub fn fit(data: &[f32], channels: usize, top: f32) -> (Vec<f32>, Vec<f32>) {
    let c = channels.max(1);
    let mut lo = vec![f32::INFINITY; c];
    let mut hi = vec![f32::NEG_INFINITY; c];
    for texel in data.chunks_exact(c) {
        for (k, &v) in texel.iter().enumerate() {
            lo[k] = lo[k].min(v);
            hi[k] = hi[k].max(v);
        }
    }
    let stride = (data.len() / c).div_ceil(SAMPLE_TEXELS).max(1);
    // Histograms of all channels in one pass.
    let mut count = vec![0u32; c * BINS];
    let inv: Vec<f32> = (0..c).map(|k| BINS as f32 / (hi[k] - lo[k])).collect();
    for texel in data.chunks_exact(c).step_by(stride) {
        for (k, &v) in texel.iter().enumerate() {
            if hi[k] > lo[k] {
                // Saturating cast: an infinite `inv` (a range below f32's resolution) lands
                // in the last bin.
                let b = (((v - lo[k]) * inv[k]) as usize).min(BINS - 1);
                count[k * BINS + b] += 1;
            }
        }
    }
    let full: Vec<(f32, f32)> = (0..c)
        .map(|k| {
            if lo[k] < hi[k] {
                full_range(lo[k], hi[k], top)
            } else {
                (1.0, if lo[k].is_finite() { lo[k] } else { 0.0 })
            }
        })
        .collect();
    let best: Vec<(f32, f32)> = (0..c)
        .map(|k| {
            if lo[k] < hi[k] {
                let hist = Histogram::new(&count[k * BINS..][..BINS], lo[k], hi[k]);
                hist.search(lo[k], hi[k], top).unwrap_or(full[k])
            } else {
                full[k]
            }
        })
        .collect();
    // The histogram's estimate picked `best`; the exact error decides against the full
    // range, so the search can only help.
    let (e_best, e_full) = exact_errors(data, stride, &best, &full, top);
    (0..c)
        .map(|k| {
            if e_best[k] <= e_full[k] {
                best[k]
            } else {
                full[k]
            }
        })
        .unzip()
}

/// `(scale, offset)` spanning `lo..=hi` exactly (the range's ends decode exactly).
fn full_range(lo: f32, hi: f32, top: f32) -> (f32, f32) {
    let s = (hi - lo) / top;
    (if s.is_normal() && s > 0.0 { s } else { 1.0 }, lo)
}

/// Squared rounding error of each channel under two candidate parameter sets `a` and `b`
/// (one `(scale, offset)` per channel each), summed in f64, in one pass over every
/// `stride`-th texel.
fn exact_errors(
    data: &[f32],
    stride: usize,
    a: &[(f32, f32)],
    b: &[(f32, f32)],
    top: f32,
) -> (Vec<f64>, Vec<f64>) {
    let c = a.len().min(b.len()).max(1);
    let err = |v: f32, (s, o): (f32, f32)| {
        let q = super::round_in_range((v - o) / s, top);
        let d = o + s * q - v;
        d * d
    };
    let (mut ea, mut eb) = (vec![0f64; c], vec![0f64; c]);
    // f32 partial sums per texel row keep the inner loop in f32.
    let mut pa = vec![0f32; c];
    let mut pb = vec![0f32; c];
    for (i, texel) in data.chunks_exact(c).step_by(stride.max(1)).enumerate() {
        for k in 0..c {
            pa[k] += err(texel[k], a[k]);
            pb[k] += err(texel[k], b[k]);
        }
        if i % 256 == 255 {
            for k in 0..c {
                ea[k] += f64::from(std::mem::take(&mut pa[k]));
                eb[k] += f64::from(std::mem::take(&mut pb[k]));
            }
        }
    }
    for k in 0..c {
        ea[k] += f64::from(pa[k]);
        eb[k] += f64::from(pb[k]);
    }
    (ea, eb)
}

/// A channel's non-empty bins as weighted points at their centres.
struct Histogram {
    /// `(count, centre)` of each non-empty bin, in increasing order.
    points: Vec<(f64, f64)>,
    total: f64,
}

impl Histogram {
    fn new(count: &[u32], lo: f32, hi: f32) -> Self {
        let width = (f64::from(hi) - f64::from(lo)) / BINS as f64;
        let points: Vec<(f64, f64)> = count
            .iter()
            .enumerate()
            .filter(|(_, &n)| n > 0)
            .map(|(b, &n)| (f64::from(n), f64::from(lo) + (b as f64 + 0.5) * width))
            .collect();
        let total = points.iter().map(|p| p.0).sum();
        Self { points, total }
    }

    /// The value below which a fraction `f` of the values lie (from the low end), or above
    /// which it lies (from the high end when `from_top`).
    fn quantile(&self, f: f64, from_top: bool) -> f64 {
        let want = f * self.total;
        let mut seen = 0.0;
        let first_past = |&&(n, _): &&(f64, f64)| {
            seen += n;
            seen > want
        };
        let found = if from_top {
            self.points.iter().rev().find(first_past)
        } else {
            self.points.iter().find(first_past)
        };
        found.or(self.points.last()).map_or(0.0, |p| p.1)
    }

    /// Estimated squared error of the range `a..=b` with `top` steps.
    fn error(&self, a: f64, b: f64, top: f64) -> f64 {
        let s = (b - a) / top;
        self.points
            .iter()
            .map(|&(n, m)| {
                let q = super::round_in_range(((m - a) / s) as f32, top as f32) as f64;
                let d = a + s * q - m;
                n * d * d
            })
            .sum()
    }

    /// Weighted least squares of `m ≈ a + s q` with each point's integer `q` held fixed.
    fn refine(&self, a: f64, b: f64, top: f64) -> Option<(f64, f64)> {
        let s = (b - a) / top;
        let (mut sw, mut sq, mut sm, mut sqq, mut sqm) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for &(n, m) in &self.points {
            let q = super::round_in_range(((m - a) / s) as f32, top as f32) as f64;
            sw += n;
            sq += n * q;
            sm += n * m;
            sqq += n * q * q;
            sqm += n * q * m;
        }
        let det = sw * sqq - sq * sq;
        if det <= 0.0 {
            return None;
        }
        let s2 = (sw * sqm - sq * sm) / det;
        let a2 = (sm - s2 * sq) / sw;
        (s2 > 0.0 && s2.is_finite() && a2.is_finite()).then_some((a2, a2 + s2 * top))
    }

    /// The best `(scale, offset)` found, in f32 (`None` when no candidate is representable).
    fn search(&self, lo: f32, hi: f32, top: f32) -> Option<(f32, f32)> {
        let top64 = f64::from(top);
        // Candidate ends: the exact extreme for a tail of 0, else the tail's quantile.
        let ends = |extreme: f32, from_top: bool| -> Vec<f64> {
            TAILS
                .iter()
                .map(|&f| match f {
                    0.0 => f64::from(extreme),
                    _ => self.quantile(f, from_top),
                })
                .collect()
        };
        let (lows, highs) = (ends(lo, false), ends(hi, true));
        let mut best: Option<(f64, f64, f64)> = None;
        let consider = |a: f64, b: f64, best: &mut Option<(f64, f64, f64)>| {
            if b > a {
                let e = self.error(a, b, top64);
                if best.is_none_or(|(_, _, be)| e < be) {
                    *best = Some((a, b, e));
                }
            }
        };
        for &a in &lows {
            for &b in &highs {
                consider(a, b, &mut best);
            }
        }
        for _ in 0..REFINE {
            let (a, b, _) = best?;
            match self.refine(a, b, top64) {
                Some((a2, b2)) => consider(a2, b2, &mut best),
                None => break,
            }
        }
        let (a, b, _) = best?;
        let (s, o) = ((b - a) as f32 / top, a as f32);
        (s.is_normal() && s > 0.0 && o.is_finite() && (o + s * top).is_finite()).then_some((s, o))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A heavy-tailed channel (Laplace-like) and a uniform one, interleaved.
    fn values(n: usize) -> Vec<f32> {
        let mut state = 12345u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        let mut out = Vec::with_capacity(2 * n);
        for _ in 0..n {
            let u = next() - 0.5;
            out.push((-(1.0 - 2.0 * u.abs()).ln() * u.signum() * 0.05) as f32);
            out.push((next() * 2.0 - 1.0) as f32);
        }
        out
    }

    #[test]
    fn clamping_the_tails_beats_the_full_range_at_4_bits_and_is_never_worse() {
        let data = values(20_000);
        for top in [15.0, 255.0] {
            let (s, o) = fit(&data, 2, top);
            for k in 0..2 {
                let lo = data
                    .iter()
                    .skip(k)
                    .step_by(2)
                    .fold(f32::INFINITY, |a, &b| a.min(b));
                let hi = data
                    .iter()
                    .skip(k)
                    .step_by(2)
                    .fold(f32::NEG_INFINITY, |a, &b| a.max(b));
                // Channel k's full range (the other entry is not read).
                let (full, ours) = exact_errors(
                    &data,
                    1,
                    &[full_range(lo, hi, top); 2],
                    &[(s[0], o[0]), (s[1], o[1])],
                    top,
                );
                let (full, ours) = (full[k], ours[k]);
                assert!(ours <= full, "top {top} channel {k}: {ours} > {full}");
                if top == 15.0 && k == 0 {
                    // The heavy tail: several times less error than spanning it.
                    assert!(ours < 0.5 * full, "heavy tail: {ours} vs {full}");
                }
                if k == 1 {
                    // Uniform values: the full range is near optimal; stay close to it.
                    assert!(ours >= 0.8 * full, "uniform: {ours} vs {full}");
                }
            }
        }
    }

    #[test]
    fn extreme_ranges_give_parameters_a_reader_accepts() {
        let cases: [&[f32]; 4] = [
            &[-3e38, 3e38, 0.0, 1.0],
            &[1e-40, 2e-40, 3e-40, 1e-40],
            &[1.0, 1.0 + f32::EPSILON, 1.0, 1.0],
            &[f32::MAX, f32::MAX, -f32::MAX, 0.0],
        ];
        for data in cases {
            for top in [15.0, 255.0] {
                let (s, o) = fit(data, 1, top);
                let ok = s[0].is_finite() && s[0] > 0.0 && o[0].is_finite();
                assert!(
                    ok && (o[0] + s[0] * top).is_finite(),
                    "{data:?}: {s:?} {o:?}"
                );
            }
        }
    }

    #[test]
    fn constant_and_empty_channels_decode_exactly() {
        let (s, o) = fit(&[0.25, 3.0, 0.25, 3.0], 2, 15.0);
        assert_eq!((s, o), (vec![1.0, 1.0], vec![0.25, 3.0]));
        let (s, o) = fit(&[], 3, 255.0);
        assert_eq!((s, o), (vec![1.0; 3], vec![0.0; 3]));
    }
}
