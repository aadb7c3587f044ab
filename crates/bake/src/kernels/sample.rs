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
//! The backward is a scatter (many pixels hit one texel). [`sample_backward`] makes it
//! parallel without data races and bit-for-bit independent of the thread count by
//! counting-sorting the taps by texel (a stable sort, so each texel's contributions keep
//! pixel order) and then letting each thread own a disjoint range of texels, summing its
//! contributions in that fixed order. [`sample_backward_serial`] is the naive scatter, kept
//! as the test oracle and for comparison.

use dnr_runtime::gbuffer::GBuffer;
use dnr_runtime::texture::{sample_into, taps, Pyramid, TextureError};
use rayon::prelude::*;

/// Forward: the runtime's sampler (`out` is `[C, H, W]`, zero at uncovered pixels).
pub fn sample_forward(pyr: &Pyramid, gbuf: &GBuffer, out: &mut [f32]) -> Result<(), TextureError> {
    sample_into(pyr, gbuf, out)
}

/// Texels per parallel task of the gather.
const TEXEL_CHUNK: usize = 4096;

fn check(
    pyr: &Pyramid,
    gbuf: &GBuffer,
    d_out: &[f32],
    grads: &[Vec<f32>],
) -> Result<(), TextureError> {
    pyr.validate()?;
    let expected = pyr.channels * gbuf.width * gbuf.height;
    if d_out.len() != expected || !gbuf.is_consistent() {
        return Err(TextureError::OutputSize {
            expected,
            found: d_out.len(),
        });
    }
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
/// Parallel and deterministic: the result is bit-identical for any thread count.
pub fn sample_backward(
    pyr: &Pyramid,
    gbuf: &GBuffer,
    d_out: &[f32],
    grads: &mut [Vec<f32>],
) -> Result<Vec<Vec<u32>>, TextureError> {
    check(pyr, gbuf, d_out, grads)?;
    let c = pyr.channels;
    let n = gbuf.width * gbuf.height;

    // Pixels that contribute, and their upstream gradient transposed to [P, C] so each tap
    // reads C contiguous values.
    let active: Vec<u32> = (0..n)
        .filter(|&i| {
            gbuf.coverage[i] != 0.0 && gbuf.uv[i][0].is_finite() && gbuf.uv[i][1].is_finite()
        })
        .map(|i| i as u32)
        .collect();
    let mut d_act = vec![0.0f32; active.len() * c];
    d_act
        .par_chunks_mut(c * 1024)
        .zip(active.par_chunks(1024))
        .for_each(|(dst, px)| {
            for (row, &p) in dst.chunks_exact_mut(c).zip(px) {
                for (ch, v) in row.iter_mut().enumerate() {
                    *v = d_out[ch * n + p as usize];
                }
            }
        });

    let mut touched = Vec::with_capacity(pyr.levels.len());
    let mut tap_texel = vec![0u32; active.len() * 4];
    let mut tap_weight = vec![0.0f32; active.len() * 4];
    for (level, grad) in pyr.levels.iter().zip(grads.iter_mut()) {
        let (lw, lh) = (level.width, level.height);
        let texels = lw * lh;
        // 1. Taps of every active pixel (parallel, each pixel writes its own 4 slots).
        tap_texel
            .par_chunks_mut(4 * 1024)
            .zip(tap_weight.par_chunks_mut(4 * 1024))
            .zip(active.par_chunks(1024))
            .for_each(|((tt, tw), px)| {
                for ((tt, tw), &p) in tt.chunks_exact_mut(4).zip(tw.chunks_exact_mut(4)).zip(px) {
                    let [u, v] = gbuf.uv[p as usize];
                    // Active pixels have finite uv and the level is non-empty: taps exist.
                    let tp = taps(lw, lh, pyr.wrap_s, pyr.wrap_t, u, v).unwrap_or([(0, 0.0); 4]);
                    for (k, (t, w)) in tp.into_iter().enumerate() {
                        tt[k] = t as u32;
                        tw[k] = w;
                    }
                }
            });
        // 2. Stable counting sort of the non-zero taps by texel.
        let mut start = vec![0u32; texels + 1];
        for (&t, &w) in tap_texel.iter().zip(&tap_weight) {
            if w != 0.0 {
                start[t as usize + 1] += 1;
            }
        }
        let mut list = Vec::new();
        for t in 0..texels {
            if start[t + 1] != 0 {
                list.push(t as u32);
            }
            start[t + 1] += start[t];
        }
        let mut order = vec![0u32; start[texels] as usize];
        let mut fill = start.clone();
        for (e, (&t, &w)) in tap_texel.iter().zip(&tap_weight).enumerate() {
            if w != 0.0 {
                order[fill[t as usize] as usize] = e as u32;
                fill[t as usize] += 1;
            }
        }
        // 3. Gather: each task owns a disjoint range of texels and sums in pixel order.
        grad.par_chunks_mut(TEXEL_CHUNK * c)
            .enumerate()
            .for_each(|(chunk, g)| {
                let t0 = chunk * TEXEL_CHUNK;
                let mut acc = vec![0.0f32; c];
                for (i, gt) in g.chunks_exact_mut(c).enumerate() {
                    let t = t0 + i;
                    let (s, e) = (start[t] as usize, start[t + 1] as usize);
                    if s == e {
                        continue;
                    }
                    acc.fill(0.0);
                    for &entry in &order[s..e] {
                        let w = tap_weight[entry as usize];
                        let d = &d_act[(entry as usize / 4) * c..][..c];
                        for (a, &dv) in acc.iter_mut().zip(d) {
                            *a += w * dv;
                        }
                    }
                    for (gv, a) in gt.iter_mut().zip(&acc) {
                        *gv += a;
                    }
                }
            });
        touched.push(list);
    }
    Ok(touched)
}

/// The naive serial scatter: same contract as [`sample_backward`] (same touched lists;
/// gradients equal up to f32 summation order). Test oracle.
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
    for p in 0..n {
        if gbuf.coverage[p] == 0.0 {
            continue;
        }
        let [u, v] = gbuf.uv[p];
        for ((level, grad), mark) in pyr.levels.iter().zip(grads.iter_mut()).zip(&mut marks) {
            let Some(tp) = taps(level.width, level.height, pyr.wrap_s, pyr.wrap_t, u, v) else {
                break;
            };
            for (t, w) in tp {
                if w == 0.0 {
                    continue;
                }
                mark[t] = true;
                for ch in 0..c {
                    grad[t * c + ch] += w * d_out[ch * n + p];
                }
            }
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
