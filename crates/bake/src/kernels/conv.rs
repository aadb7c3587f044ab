//! Convolution (square kernel, stride, zero padding, OIHW weights): forward that keeps what
//! backward needs, and backward.

use dnr_runtime::nn::activation::Act;
use dnr_runtime::nn::conv::{pack_conv_weights, weight_index_parts, ConvGeom, ConvLayout};
use dnr_runtime::nn::gemm::{gemm_nn, gemm_nt, PackedA};
use dnr_runtime::nn::norm::NormStats;
use dnr_runtime::nn::tensor::{par_min_items, pool};
use dnr_runtime::nn::{NnError, Tensor};
use rayon::prelude::*;

/// What [`conv_forward`] keeps for [`conv_backward`].
#[derive(Clone, Debug)]
pub struct ConvCache {
    /// GEMM layout of the forward pass.
    pub layout: ConvLayout,
    /// The gathered input (the GEMM's B buffer).
    pub buf: Vec<f32>,
}

/// `y = conv(x, w) + b`.
/// x: `c_in x H x W`; w: `[c_out, c_in, k, k]`; b: `[c_out]`; y: `c_out x H_out x W_out`.
pub fn conv_forward(
    x: &Tensor,
    w: &[f32],
    b: &[f32],
    geom: ConvGeom,
) -> Result<(Tensor, ConvCache), NnError> {
    let (y, _, cache) = conv_forward_act(x, Act::Identity, (x.h, x.w), w, b, geom, false)?;
    Ok((y, cache))
}

/// `y = conv(act(x), w) + b` on an input of `size` (`x` zero-extended at the bottom/right when
/// smaller), with the per-channel instance-norm statistics of `y` when `with_stats`.
/// x: `c_in x h x w` (h, w <= size); w: `[c_out, c_in, k, k]`; b: `[c_out]`.
/// The cache holds `act(x)` as gathered, so [`conv_backward`] returns d/d(act(x)).
#[allow(clippy::type_complexity)]
pub fn conv_forward_act(
    x: &Tensor,
    act: Act,
    size: (usize, usize),
    w: &[f32],
    b: &[f32],
    geom: ConvGeom,
    with_stats: bool,
) -> Result<(Tensor, Option<NormStats>, ConvCache), NnError> {
    if x.c != geom.c_in
        || w.len() != geom.weight_len()
        || b.len() != geom.c_out
        || x.h > size.0
        || x.w > size.1
    {
        return Err(NnError::Shape(format!(
            "conv_forward: x {}x{}x{}, w {}, b {} for {geom:?} on {size:?}",
            x.c,
            x.h,
            x.w,
            w.len(),
            b.len()
        )));
    }
    let layout = ConvLayout::new(geom, size.0, size.1)?;
    let buf = layout.gather_act(x, act);
    let raw = layout.gemm(&pack_conv_weights(geom, w), &buf);
    let (y, stats) = if with_stats {
        let (y, s) = layout.finish_stats(&raw, Some(b));
        (y, Some(s))
    } else {
        (layout.finish(&raw, Some(b)), None)
    };
    pool::recycle(raw);
    Ok((y, stats, ConvCache { layout, buf }))
}

/// The output gradient as GEMM rows: plane `o` at `o * slot + margin`, row pitch `pitch`,
/// zero in the junk columns and in the `margin` values before and the slack after each plane.
pub(crate) fn pitched_rows(dy: &Tensor, pitch: usize, margin: usize, slot: usize) -> Vec<f32> {
    let mut buf = pool::zeroed(dy.c * slot);
    let n = dy.plane_len();
    if n == 0 {
        return buf;
    }
    buf.par_chunks_mut(slot)
        .zip(dy.data.par_chunks(n))
        .with_min_len(par_min_items(n))
        .for_each(|(dst, src)| {
            for y in 0..dy.h {
                dst[margin + y * pitch..][..dy.w].copy_from_slice(&src[y * dy.w..(y + 1) * dy.w]);
            }
        });
    buf
}

/// Per-channel sums of `dy` added to `db` (f64 accumulation).
pub(crate) fn bias_grad(dy: &Tensor, db: &mut [f32]) {
    let n = dy.plane_len();
    if n == 0 {
        return;
    }
    let sums: Vec<f64> = dy
        .data
        .par_chunks(n)
        .with_min_len(par_min_items(n))
        .map(|p| p.iter().map(|&v| v as f64).sum())
        .collect();
    db.iter_mut().zip(sums).for_each(|(d, s)| *d += s as f32);
}

/// Backward of [`conv_forward`].
/// dy: `c_out x H_out x W_out`; w: `[c_out, c_in, k, k]`.
/// Adds to dw (`[c_out, c_in, k, k]`) and db (`[c_out]`); adds the input gradient to `dx`
/// (`c_in x H x W`) when given.
pub fn conv_backward(
    cache: &ConvCache,
    w: &[f32],
    dy: &Tensor,
    dw: &mut [f32],
    db: &mut [f32],
    dx: Option<&mut Tensor>,
) {
    let l = &cache.layout;
    let g = l.geom;
    assert!(
        dy.c == g.c_out && dy.h == l.h_out && dy.w == l.w_out,
        "conv_backward: dy shape"
    );
    assert!(
        w.len() == g.weight_len() && dw.len() == w.len() && db.len() == g.c_out,
        "conv_backward: weight shapes"
    );
    bias_grad(dy, db);

    // Padded output gradient: each plane behind a margin of the largest shift, long enough to
    // be read at every position of an input plane (see the adjoint product below).
    let margin = l.shifts.iter().copied().max().unwrap_or(0);
    let in_len = l.plane_h * l.pitch;
    let slot = margin + in_len.max(l.n);
    let dyp = pitched_rows(dy, l.pitch, margin, slot);

    // dW[o][k] = sum_j dY[o][j] B[k][j]: a dot product per (output channel, GEMM row).
    let kk = l.gemm_k();
    let per_o = g.c_in * g.k * g.k;
    let a_rows: Vec<usize> = (0..g.c_out).map(|o| o * slot + margin).collect();
    let mut dwg = pool::scratch(g.c_out * kk);
    gemm_nt(
        &dyp,
        &a_rows,
        &cache.buf,
        &l.rows(),
        l.n,
        &mut dwg,
        kk,
        false,
    );
    let map: Vec<usize> = (0..kk).map(|k| l.weight_index(k)).collect();
    for o in 0..g.c_out {
        for k in 0..kk {
            dw[o * per_o + map[k]] += dwg[o * kk + k];
        }
    }
    pool::recycle(dwg);

    // dB[p][m] = sum_{o,t} W(o, p taps + t) dY[o][m - shift_t]: the adjoint, again one GEMM
    // over shifted rows, then the adjoint of the gather.
    if let Some(dx) = dx {
        let taps = l.taps();
        let (p_part, t_part) = weight_index_parts(g);
        let cols: Vec<usize> = (0..g.c_out * taps)
            .map(|ot| (ot / taps) * per_o + t_part[ot % taps])
            .collect();
        let at = PackedA::from_offsets(w, &p_part, &cols);
        let b_rows: Vec<usize> = (0..g.c_out * taps)
            .map(|ot| (ot / taps) * slot + margin - l.shifts[ot % taps])
            .collect();
        // Every value scatter_add reads (the first in_len of each plane) is written.
        let mut dbuf = pool::scratch(l.buffer_len());
        gemm_nn(&at, &dyp, &b_rows, in_len, &mut dbuf, l.plane_stride, false);
        l.scatter_add(&dbuf, dx);
        pool::recycle(dbuf);
    }
    pool::recycle(dyp);
}
