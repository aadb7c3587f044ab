//! Neural texture sampling: the levels' bilinear samples, summed.
//!
//! `F(u, v) = sum over levels of bilinear(level, u, v)` exactly as DESIGN.md "Neural texture"
//! defines it (texel centres at half-integers, row 0 at v = 0, per-axis wrap of the integer tap
//! indices, no mipmapping).
//!
//! [`taps`] is the single definition of the four taps and their weights; the forward
//! sampler here and the baker's backward both call it, so they cannot drift apart.
//!
//! Precision: `x = u*W - 0.5` and `floor(x)` are computed in f64 and the wrap is applied to
//! the f64 integer value (`%` on f64 is exact), so any finite u works without integer
//! overflow. The result is exact while `|u| * W < 2^52` (for f32 u and W < 2^29 the product
//! `u * W` itself is exact); beyond that f64 has no fractional bits left and the sample
//! degenerates to a single texel, which is what the exact formula tends to anyway.

use rayon::prelude::*;

use crate::gbuffer::GBuffer;

/// Per-axis wrap mode of the integer tap indices (glTF sampler `wrapS` / `wrapT`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Wrap {
    /// `i mod n`, non-negative (glTF 10497, the default).
    #[default]
    Repeat,
    /// `clamp(i, 0, n - 1)` (glTF 33071).
    ClampToEdge,
    /// `m = i mod 2n; m < n ? m : 2n - 1 - m` (glTF 33648).
    MirroredRepeat,
}

impl Wrap {
    /// The wrap mode for a glTF sampler enum value; None for unknown values.
    pub fn from_gl(code: u32) -> Option<Wrap> {
        match code {
            10497 => Some(Wrap::Repeat),
            33071 => Some(Wrap::ClampToEdge),
            33648 => Some(Wrap::MirroredRepeat),
            _ => None,
        }
    }

    /// The glTF sampler enum value.
    pub fn to_gl(self) -> u32 {
        match self {
            Wrap::Repeat => 10497,
            Wrap::ClampToEdge => 33071,
            Wrap::MirroredRepeat => 33648,
        }
    }

    /// [`Wrap::pair`] for an integer `i0` (and `n >= 1`).
    #[inline(always)]
    fn pair_i64(self, i0: i64, n: i64) -> (usize, usize) {
        match self {
            Wrap::Repeat => {
                let m = if (0..n).contains(&i0) {
                    i0
                } else {
                    i0.rem_euclid(n)
                };
                (m as usize, if m + 1 == n { 0 } else { m as usize + 1 })
            }
            Wrap::ClampToEdge => (
                i0.clamp(0, n - 1) as usize,
                (i0 + 1).clamp(0, n - 1) as usize,
            ),
            Wrap::MirroredRepeat => {
                let m = if (0..2 * n).contains(&i0) {
                    i0
                } else {
                    i0.rem_euclid(2 * n)
                };
                let m1 = if m + 1 == 2 * n { 0 } else { m + 1 };
                let mirror = |m: i64| (if m < n { m } else { 2 * n - 1 - m }) as usize;
                (mirror(m), mirror(m1))
            }
        }
    }

    /// Wrapped indices of the integer-valued `i0` and of `i0 + 1` for an axis of `n >= 1`
    /// texels. `i0` may be any finite integer-valued f64.
    #[inline(always)]
    pub fn pair(self, i0: f64, n: usize) -> (usize, usize) {
        let nf = n as f64;
        match self {
            Wrap::Repeat => {
                let m = rem_euclid(i0, nf);
                let m1 = if m + 1 == n { 0 } else { m + 1 };
                (m, m1)
            }
            Wrap::ClampToEdge => {
                let hi = nf - 1.0;
                (
                    i0.clamp(0.0, hi) as usize,
                    (i0 + 1.0).clamp(0.0, hi) as usize,
                )
            }
            Wrap::MirroredRepeat => {
                let m = rem_euclid(i0, 2.0 * nf);
                let m1 = if m + 1 == 2 * n { 0 } else { m + 1 };
                let mirror = |m: usize| if m < n { m } else { 2 * n - 1 - m };
                (mirror(m), mirror(m1))
            }
        }
    }
}

/// Non-negative remainder of an integer-valued f64 by a positive integer-valued f64, as an
/// index. Exact: IEEE `%` (fmod) is exact, and the result is a small integer.
#[inline]
fn rem_euclid(i: f64, n: f64) -> usize {
    // Fast paths (f64 `%` is a libm call): the usual uv range, one period below it, and
    // anything an i64 holds exactly.
    if (0.0..n).contains(&i) {
        return i as usize;
    }
    if i < 0.0 && i >= -n {
        return (i + n) as usize;
    }
    if i.abs() < 4.0e15 {
        return (i as i64).rem_euclid(n as i64) as usize;
    }
    let r = i % n;
    let r = if r < 0.0 { r + n } else { r };
    // r is an integer in [0, n); the min guards the cast against any doubt.
    (r as usize).min(n as usize - 1)
}

/// Wrapped tap indices `wrap(floor(x))`, `wrap(floor(x) + 1)` and the fraction
/// `x - floor(x)` for one axis of `n >= 1` texels; x finite.
///
/// Where |x| < 4e15 the floor goes through i64 (exact there), which also avoids the libm
/// `floor` call baseline x86-64 (no SSE4.1) makes; beyond, every f64 is an integer and the
/// exact f64 path of [`Wrap::pair`] takes over.
#[inline(always)]
fn axis(x: f64, n: usize, wrap: Wrap) -> (usize, usize, f32) {
    if x.abs() < 4.0e15 {
        let t = x as i64;
        let i0 = if t as f64 > x { t - 1 } else { t };
        let (a, b) = wrap.pair_i64(i0, n as i64);
        (a, b, (x - i0 as f64) as f32)
    } else {
        let (a, b) = wrap.pair(x, n);
        (a, b, 0.0)
    }
}

/// One bilinear tap: texel index within its level (`y * width + x`) and weight.
pub type Tap = (usize, f32);

/// The four bilinear taps of `(u, v)` on a `width x height` level, in the order
/// `(x0, y0), (x0+1, y0), (x0, y0+1), (x0+1, y0+1)` with weights
/// `(1-fx)(1-fy), fx(1-fy), (1-fx)fy, fx fy`. None when u or v is not finite or the level
/// is empty. Wrapped taps may coincide (clamping, width 1); their weights then add up.
///
/// Always inlined: the samplers call it per pixel and level, and the call (a few kB of code
/// for the three wrap modes) cost about as much as the bilinear blend it feeds.
#[inline(always)]
pub fn taps(
    width: usize,
    height: usize,
    wrap_s: Wrap,
    wrap_t: Wrap,
    u: f32,
    v: f32,
) -> Option<[Tap; 4]> {
    if !(u.is_finite() && v.is_finite()) || width == 0 || height == 0 {
        return None;
    }
    let (xa, xb, fx) = axis(u as f64 * width as f64 - 0.5, width, wrap_s);
    let (ya, yb, fy) = axis(v as f64 * height as f64 - 0.5, height, wrap_t);
    Some([
        (ya * width + xa, (1.0 - fx) * (1.0 - fy)),
        (ya * width + xb, fx * (1.0 - fy)),
        (yb * width + xa, (1.0 - fx) * fy),
        (yb * width + xb, fx * fy),
    ])
}

/// One level of a neural texture.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Level {
    /// Width in texels.
    pub width: usize,
    /// Height in texels.
    pub height: usize,
    /// `height * width * channels` values, texel-interleaved (HWC), row 0 (v = 0) first.
    pub data: Vec<f32>,
}

/// A neural texture: levels finest first, all with the same channel count, sampled
/// together with one sampler.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Pyramid {
    /// Channels per texel.
    pub channels: usize,
    /// The levels, finest first.
    pub levels: Vec<Level>,
    /// Wrap along u (x).
    pub wrap_s: Wrap,
    /// Wrap along v (y).
    pub wrap_t: Wrap,
}

/// Why a [`Pyramid`] or a sampling call is malformed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TextureError {
    /// Zero channels or no levels.
    #[error("a neural texture needs at least one channel and one level")]
    Empty,
    /// A level with a zero side or a data length that is not `width * height * channels`.
    #[error("level {level}: {width}x{height}x{channels} needs {expected} values, found {found}")]
    LevelSize {
        /// Level index.
        level: usize,
        /// Width.
        width: usize,
        /// Height.
        height: usize,
        /// Channels.
        channels: usize,
        /// Expected value count (0 when overflowing).
        expected: usize,
        /// Actual value count.
        found: usize,
    },
    /// The output buffer does not hold `channels * width * height` values, or the G-buffer
    /// is inconsistent.
    #[error("output holds {found} values, expected {expected} (channels x height x width)")]
    OutputSize {
        /// Expected.
        expected: usize,
        /// Found.
        found: usize,
    },
}

impl Pyramid {
    /// A checked pyramid.
    pub fn new(
        channels: usize,
        levels: Vec<Level>,
        wrap_s: Wrap,
        wrap_t: Wrap,
    ) -> Result<Self, TextureError> {
        let p = Pyramid {
            channels,
            levels,
            wrap_s,
            wrap_t,
        };
        p.validate()?;
        Ok(p)
    }

    /// Checks channel count, level sizes and data lengths.
    pub fn validate(&self) -> Result<(), TextureError> {
        if self.channels == 0 || self.levels.is_empty() {
            return Err(TextureError::Empty);
        }
        for (i, l) in self.levels.iter().enumerate() {
            let expected = l
                .width
                .checked_mul(l.height)
                .and_then(|n| n.checked_mul(self.channels));
            if l.width == 0 || l.height == 0 || expected != Some(l.data.len()) {
                return Err(TextureError::LevelSize {
                    level: i,
                    width: l.width,
                    height: l.height,
                    channels: self.channels,
                    expected: expected.unwrap_or(0),
                    found: l.data.len(),
                });
            }
        }
        Ok(())
    }

    /// Adds `F(u, v)` (all levels) to `out[..channels]`; leaves it unchanged when u or v is
    /// not finite. The pyramid must be valid.
    #[inline]
    pub fn accumulate(&self, u: f32, v: f32, out: &mut [f32]) {
        let c = self.channels;
        let out = &mut out[..c];
        for l in &self.levels {
            let Some(tp) = taps(l.width, l.height, self.wrap_s, self.wrap_t, u, v) else {
                return;
            };
            for (t, w) in tp {
                let texel = &l.data[t * c..t * c + c];
                for (o, &x) in out.iter_mut().zip(texel) {
                    *o += w * x;
                }
            }
        }
    }
}

/// Samples the pyramid at every pixel of `gbuf` into `out`, planar `channels x height x
/// width` (CHW). Covered pixels with finite uv get the sum over levels; all other pixels
/// are set to zero (without sampling). Parallel over rows.
///
/// Same values, bit for bit, as [`Pyramid::accumulate`] into zeros at each pixel: every
/// pixel still adds its taps level by level, tap by tap. The loop runs level-major over a
/// row (all pixels of level 0, then of level 1, ...) so that consecutive pixels are
/// independent work (their texel loads overlap instead of waiting on one pixel's chain of
/// additions), with the pixel's partial sum held in registers for the channel counts the
/// baker uses.
pub fn sample_into(pyr: &Pyramid, gbuf: &GBuffer, out: &mut [f32]) -> Result<(), TextureError> {
    pyr.validate()?;
    let (w, h, c) = (gbuf.width, gbuf.height, pyr.channels);
    let expected = c * w * h;
    if out.len() != expected || !gbuf.is_consistent() {
        return Err(TextureError::OutputSize {
            expected,
            found: out.len(),
        });
    }
    if expected == 0 {
        return Ok(());
    }
    for_rows_of_planes(out, c, w, h, |y, planes| {
        let row = y * w..(y + 1) * w;
        let uv = &gbuf.uv[row.clone()];
        // Pixels that sample: covered with finite uv (the rest stay zero).
        let px: Vec<u32> = gbuf.coverage[row]
            .iter()
            .zip(uv)
            .enumerate()
            .filter(|(_, (&cov, [u, v]))| cov != 0.0 && u.is_finite() && v.is_finite())
            .map(|(x, _)| x as u32)
            .collect();
        if px.is_empty() {
            planes.iter_mut().for_each(|p| p.fill(0.0));
            return;
        }
        // The row texel-interleaved (each tap adds C contiguous values), then transposed
        // into the planes.
        let mut acc = vec![0.0f32; w * c];
        match c {
            4 => accumulate_row::<4>(pyr, uv, &px, &mut acc),
            8 => accumulate_row::<8>(pyr, uv, &px, &mut acc),
            12 => accumulate_row::<12>(pyr, uv, &px, &mut acc),
            16 => accumulate_row::<16>(pyr, uv, &px, &mut acc),
            _ => {
                for l in &pyr.levels {
                    for &x in &px {
                        let x = x as usize;
                        let [u, v] = uv[x];
                        let Some(tp) = taps(l.width, l.height, pyr.wrap_s, pyr.wrap_t, u, v) else {
                            continue;
                        };
                        let a = &mut acc[x * c..(x + 1) * c];
                        for (t, wt) in tp {
                            for (o, &tx) in a.iter_mut().zip(&l.data[t * c..(t + 1) * c]) {
                                *o += wt * tx;
                            }
                        }
                    }
                }
            }
        }
        for (ch, plane) in planes.iter_mut().enumerate() {
            for (p, a) in plane.iter_mut().zip(acc.chunks_exact(c)) {
                *p = a[ch];
            }
        }
    });
    Ok(())
}

/// Adds every level's taps at the pixels `px` of one row into `acc` (`[x][C]`), level-major,
/// for a channel count known at compile time (the sum stays in registers across the taps).
/// `px` holds only pixels with finite uv.
#[inline]
fn accumulate_row<const C: usize>(pyr: &Pyramid, uv: &[[f32; 2]], px: &[u32], acc: &mut [f32]) {
    for l in &pyr.levels {
        for &x in px {
            let x = x as usize;
            let [u, v] = uv[x];
            let Some(tp) = taps(l.width, l.height, pyr.wrap_s, pyr.wrap_t, u, v) else {
                continue;
            };
            let a: &mut [f32; C] = (&mut acc[x * C..(x + 1) * C]).try_into().expect("C values");
            let mut s = *a;
            for (t, wt) in tp {
                let texel: &[f32; C] = l.data[t * C..(t + 1) * C].try_into().expect("C values");
                for (o, &tx) in s.iter_mut().zip(texel) {
                    *o += wt * tx;
                }
            }
            *a = s;
        }
    }
}

/// Runs `f(y, rows)` in parallel over image rows, where `rows[k]` is row `y` of plane `k` of
/// the planar (CHW) buffer `buf`. Disjoint mutable slices, no unsafe.
pub fn for_rows_of_planes<F>(buf: &mut [f32], planes: usize, w: usize, h: usize, f: F)
where
    F: Fn(usize, &mut [&mut [f32]]) + Sync + Send,
{
    assert_eq!(buf.len(), planes * w * h, "planar buffer size");
    if buf.is_empty() {
        return;
    }
    let mut rows: Vec<Vec<&mut [f32]>> = (0..h).map(|_| Vec::with_capacity(planes)).collect();
    for plane in buf.chunks_mut(w * h) {
        for (y, row) in plane.chunks_mut(w).enumerate() {
            rows[y].push(row);
        }
    }
    rows.into_par_iter()
        .enumerate()
        .for_each(|(y, mut r)| f(y, &mut r));
}
