//! Convolution (square kernel, stride, zero padding, OIHW weights): forward that keeps what
//! backward needs, and backward.

use dnr_runtime::nn::activation::Act;
use dnr_runtime::nn::conv::{weight_index_parts, ConvGeom, ConvLayout};
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
    // The weights change every step: read in place where packing them would cost as much as
    // the product (the same bits as the runtime's weights packed at load).
    let raw = layout.gemm_once(w, &buf);
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
        .map(|p| {
            // Eight f64 lanes (independent add chains) in a fixed order: deterministic, and
            // several times faster than one chain.
            let mut s = [0.0f64; 8];
            let mut c = p.chunks_exact(8);
            for v in c.by_ref() {
                for l in 0..8 {
                    s[l] += f64::from(v[l]);
                }
            }
            for (l, &v) in c.remainder().iter().enumerate() {
                s[l] += f64::from(v);
            }
            s.iter().sum::<f64>()
        })
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
    let g = cache.layout.geom;
    assert!(
        w.len() == g.weight_len() && db.len() == g.c_out,
        "conv_backward: weight shapes"
    );
    bias_grad(dy, db);
    conv_grads(cache, dy, Some(dw), dx.map(|d| (w, d)));
}

/// The weight gradient alone: adds `dL/dw` (`[c_out, c_in, k, k]`) of the convolution that
/// `cache` was gathered for, given `dy` (`c_out x H_out x W_out`). A transposed convolution's
/// weight gradient is this, with the roles of input and output gradient exchanged.
pub fn conv_weight_grad(cache: &ConvCache, dy: &Tensor, dw: &mut [f32]) {
    conv_grads(cache, dy, Some(dw), None);
}

/// GEMM columns (output pixels with the layout's junk columns) up to which the gradients are
/// taken with an explicit transposed im2col matrix: on the deep layers' small planes the
/// shifted-row products have an inner dimension of a few dozen and pay more for packing the
/// transposed weights than for the arithmetic (see `dnr bench train`).
pub const SMALL_N: usize = 256;

/// Weights per block of the im2col transposes: the block's input rows stay in L1 while its
/// output row segment is written whole.
const TRANSPOSE_BLOCK: usize = 16;

/// Adds the weight gradient to `dw` and, with `dx = Some((w, dx))`, the input gradient to
/// `dx`. dy: `c_out x H_out x W_out`.
fn conv_grads(
    cache: &ConvCache,
    dy: &Tensor,
    dw: Option<&mut [f32]>,
    dx: Option<(&[f32], &mut Tensor)>,
) {
    let l = &cache.layout;
    let g = l.geom;
    assert!(
        dy.c == g.c_out && dy.h == l.h_out && dy.w == l.w_out,
        "conv gradients: dy shape"
    );
    assert!(
        dw.as_ref().is_none_or(|d| d.len() == g.weight_len())
            && dx.as_ref().is_none_or(|(w, _)| w.len() == g.weight_len()),
        "conv gradients: weight shapes"
    );
    if l.n <= SMALL_N {
        conv_grads_small(cache, dy, dw, dx);
    } else {
        conv_grads_shifted(cache, dy, dw, dx);
    }
}

/// [`conv_grads`] as products over the gathered buffer's shifted rows (no im2col matrix).
fn conv_grads_shifted(
    cache: &ConvCache,
    dy: &Tensor,
    dw: Option<&mut [f32]>,
    dx: Option<(&[f32], &mut Tensor)>,
) {
    let l = &cache.layout;
    let g = l.geom;
    // Padded output gradient: each plane behind a margin of the largest shift, long enough to
    // be read at every position of an input plane (see the adjoint product below).
    let margin = l.shifts.iter().copied().max().unwrap_or(0);
    let in_len = l.plane_h * l.pitch;
    let slot = margin + in_len.max(l.n);
    let dyp_buf = pitched_rows(dy, l.pitch, margin, slot);
    let kk = l.gemm_k();
    let per_o = g.c_in * g.k * g.k;

    // dW[o][k] = sum_j dY[o][j] B[k][j]: a dot product per (output channel, GEMM row).
    let dyp = &dyp_buf;
    let weight_grad = move || {
        let Some(dw) = dw else { return };
        let a_rows: Vec<usize> = (0..g.c_out).map(|o| o * slot + margin).collect();
        let mut dwg = pool::scratch(g.c_out * kk);
        gemm_nt(
            dyp,
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
    };

    // dB[p][m] = sum_{o,t} W(o, p taps + t) dY[o][m - shift_t]: the adjoint, again one GEMM
    // over shifted rows, then the adjoint of the gather.
    let input_grad = move || {
        let Some((w, dx)) = dx else { return };
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
        gemm_nn(&at, dyp, &b_rows, in_len, &mut dbuf, l.plane_stride, false);
        l.scatter_add(&dbuf, dx);
        pool::recycle(dbuf);
    };
    // Independent products: side by side, each splitting further when a thread is idle.
    rayon::join(weight_grad, input_grad);
    pool::recycle(dyp_buf);
}

/// [`conv_grads`] on small planes, with the weights as they are: `dW += dY' Bᵀ` and
/// `dB' = dY'ᵀ W`, where `B` is the gathered input as an explicit im2col matrix whose rows are
/// in OIHW weight order (so `dW` accumulates straight into `dw`), and `dB'` goes back through
/// the im2col's and the gather's adjoints.
fn conv_grads_small(
    cache: &ConvCache,
    dy: &Tensor,
    dw: Option<&mut [f32]>,
    dx: Option<(&[f32], &mut Tensor)>,
) {
    let l = &cache.layout;
    let (g, n) = (l.geom, l.n);
    let per_o = g.c_in * g.k * g.k;
    debug_assert_eq!(l.gemm_k(), per_o, "one GEMM row per weight");
    // off[r]: where the gathered input row of weight r starts.
    let mut off = vec![0usize; per_o];
    for (k, &o) in l.rows().iter().enumerate() {
        off[l.weight_index(k)] = o;
    }
    // dY with the GEMM's pitch (c_out x n; junk columns zero).
    let dyp_buf = pitched_rows(dy, l.pitch, 0, n);
    let (dyp, off) = (&dyp_buf, &off);
    let weight_grad = move || {
        let Some(dw) = dw else { return };
        // bt[j][r] = B[r][j]: n x per_o.
        let mut bt = pool::scratch(n * per_o);
        for (blk, offs) in off.chunks(TRANSPOSE_BLOCK).enumerate() {
            let r0 = blk * TRANSPOSE_BLOCK;
            for j in 0..n {
                let dst = &mut bt[j * per_o + r0..][..offs.len()];
                for (d, &o) in dst.iter_mut().zip(offs) {
                    *d = cache.buf[o + j];
                }
            }
        }
        // dW (c_out x per_o) += dY' (c_out x n) bt (n x per_o).
        let bt_rows: Vec<usize> = (0..n).map(|j| j * per_o).collect();
        let a = PackedA::new(g.c_out, n, dyp, n, 1);
        gemm_nn(&a, &bt, &bt_rows, per_o, dw, per_o, true);
        pool::recycle(bt);
    };
    let input_grad = move || {
        let Some((w, dx)) = dx else { return };
        // dB'ᵀ (n x per_o) = dY'ᵀ (n x c_out) W (c_out x per_o).
        let w_rows: Vec<usize> = (0..g.c_out).map(|o| o * per_o).collect();
        let mut dbt = pool::scratch(n * per_o);
        let a = PackedA::new(n, g.c_out, dyp, 1, n);
        gemm_nn(&a, w, &w_rows, per_o, &mut dbt, per_o, false);
        // The im2col's adjoint into the layout buffer, then the gather's.
        let mut dbuf = pool::zeroed(l.buffer_len());
        for (blk, offs) in off.chunks(TRANSPOSE_BLOCK).enumerate() {
            let r0 = blk * TRANSPOSE_BLOCK;
            for j in 0..n {
                let src = &dbt[j * per_o + r0..][..offs.len()];
                for (&v, &o) in src.iter().zip(offs) {
                    dbuf[o + j] += v;
                }
            }
        }
        pool::recycle(dbt);
        l.scatter_add(&dbuf, dx);
        pool::recycle(dbuf);
    };
    rayon::join(weight_grad, input_grad);
    pool::recycle(dyp_buf);
}
