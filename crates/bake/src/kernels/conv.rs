//! Convolution (square kernel, stride, zero padding, OIHW weights): forward that keeps what
//! backward needs, and backward.

use dnr_runtime::nn::conv::{pack_conv_weights, ConvGeom, ConvLayout};
use dnr_runtime::nn::gemm::{gemm_nn, gemm_nt, PackedA};
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
pub fn conv_forward(x: &Tensor, w: &[f32], b: &[f32], geom: ConvGeom) -> Result<(Tensor, ConvCache), NnError> {
    if x.c != geom.c_in || w.len() != geom.weight_len() || b.len() != geom.c_out {
        return Err(NnError::Shape(format!("conv_forward: x {}ch, w {}, b {} for {geom:?}", x.c, w.len(), b.len())));
    }
    let layout = ConvLayout::new(geom, x.h, x.w)?;
    let buf = layout.gather(x);
    let raw = layout.gemm(&pack_conv_weights(geom, w), &buf);
    let y = layout.finish(&raw, Some(b));
    Ok((y, ConvCache { layout, buf }))
}

/// The output gradient as GEMM rows: plane `o` at `o * slot + margin`, row pitch `pitch`,
/// zero in the junk columns and in the `margin` values before and the slack after each plane.
pub(crate) fn pitched_rows(dy: &Tensor, pitch: usize, margin: usize, slot: usize) -> Vec<f32> {
    let mut buf = vec![0.0f32; dy.c * slot];
    let n = dy.plane_len();
    if n == 0 {
        return buf;
    }
    buf.par_chunks_mut(slot).zip(dy.data.par_chunks(n)).for_each(|(dst, src)| {
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
    let sums: Vec<f64> = dy.data.par_chunks(n).map(|p| p.iter().map(|&v| v as f64).sum()).collect();
    db.iter_mut().zip(sums).for_each(|(d, s)| *d += s as f32);
}

/// Backward of [`conv_forward`].
/// dy: `c_out x H_out x W_out`; w: `[c_out, c_in, k, k]`.
/// Adds to dw (`[c_out, c_in, k, k]`) and db (`[c_out]`); adds the input gradient to `dx`
/// (`c_in x H x W`) when given.
pub fn conv_backward(cache: &ConvCache, w: &[f32], dy: &Tensor, dw: &mut [f32], db: &mut [f32], dx: Option<&mut Tensor>) {
    let l = &cache.layout;
    let g = l.geom;
    assert!(dy.c == g.c_out && dy.h == l.h_out && dy.w == l.w_out, "conv_backward: dy shape");
    assert!(w.len() == g.weight_len() && dw.len() == w.len() && db.len() == g.c_out, "conv_backward: weight shapes");
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
    let mut dwg = vec![0.0f32; g.c_out * kk];
    gemm_nt(&dyp, &a_rows, &cache.buf, &l.rows(), l.n, &mut dwg, kk, false);
    let map: Vec<usize> = (0..kk).map(|k| l.weight_index(k)).collect();
    for o in 0..g.c_out {
        for k in 0..kk {
            dw[o * per_o + map[k]] += dwg[o * kk + k];
        }
    }

    // dB[p][m] = sum_{o,t} W(o, p taps + t) dY[o][m - shift_t]: the adjoint, again one GEMM
    // over shifted rows, then the adjoint of the gather.
    if let Some(dx) = dx {
        let taps = l.taps();
        let at = PackedA::from_fn(l.planes, g.c_out * taps, |p, ot| {
            let (o, t) = (ot / taps, ot % taps);
            w[o * per_o + map[p * taps + t]]
        });
        let b_rows: Vec<usize> = (0..g.c_out * taps).map(|ot| (ot / taps) * slot + margin - l.shifts[ot % taps]).collect();
        let mut dbuf = vec![0.0f32; l.buffer_len()];
        gemm_nn(&at, &dyp, &b_rows, in_len, &mut dbuf, l.plane_stride, false);
        l.scatter_add(&dbuf, dx);
    }
}
