//! Transposed convolution 4x4 stride 2 padding 1 (weights `[c_in, c_out, 4, 4]`): forward that
//! keeps what backward needs, and backward.

use super::conv::bias_grad;
use dnr_runtime::nn::conv::{conv2d, ConvGeom};
use dnr_runtime::nn::conv_transpose::TconvLayout;
use dnr_runtime::nn::gemm::gemm_nt;
use dnr_runtime::nn::{NnError, Tensor};
use rayon::prelude::*;

/// What [`conv_transpose_forward`] keeps for [`conv_transpose_backward`].
#[derive(Clone, Debug)]
pub struct TconvCache {
    /// GEMM layout of the forward pass.
    pub layout: TconvLayout,
    /// The zero-padded input planes.
    pub buf: Vec<f32>,
}

/// x: `c_in x H x W`; w: `[c_in, c_out, 4, 4]`; b: `[c_out]`; y: `c_out x 2H x 2W`.
pub fn conv_transpose_forward(x: &Tensor, w: &[f32], b: &[f32], c_out: usize) -> Result<(Tensor, TconvCache), NnError> {
    let layout = TconvLayout::new(x.c, c_out, x.h, x.w);
    if w.len() != layout.weight_len() || b.len() != c_out {
        return Err(NnError::Shape(format!("conv_transpose_forward: w {}, b {} for {}->{c_out}", w.len(), b.len(), x.c)));
    }
    let buf = layout.gather(x);
    let mut y = Tensor::zeros(c_out, 2 * x.h, 2 * x.w);
    for ph in 0..4 {
        let raw = layout.gemm(&layout.pack_weights(w, ph), &buf, ph);
        layout.interleave(&raw, ph, Some(b), &mut y);
    }
    Ok((y, TconvCache { layout, buf }))
}

/// Backward of [`conv_transpose_forward`].
/// dy: `c_out x 2H x 2W`; w: `[c_in, c_out, 4, 4]`.
/// Adds to dw and db; adds the input gradient (`c_in x H x W`) to `dx` when given.
pub fn conv_transpose_backward(cache: &TconvCache, w: &[f32], dy: &Tensor, dw: &mut [f32], db: &mut [f32], dx: Option<&mut Tensor>) {
    let l = &cache.layout;
    assert!(dy.c == l.c_out && dy.h == 2 * l.h_in && dy.w == 2 * l.w_in, "conv_transpose_backward: dy shape");
    assert!(w.len() == l.weight_len() && dw.len() == w.len() && db.len() == l.c_out, "conv_transpose_backward: weights");
    bias_grad(dy, db);
    let (h, wi, n, pitch) = (l.h_in, l.w_in, l.n, l.pitch);
    let kk = 4 * l.c_in;
    let a_rows: Vec<usize> = (0..l.c_out).map(|o| o * n).collect();
    let mut dwg = vec![0.0f32; l.c_out * kk];
    for ph in 0..4 {
        let (py, px) = (ph / 2, ph % 2);
        // This phase's output gradient with the GEMM's row pitch (junk columns zero).
        let mut dyp = vec![0.0f32; l.c_out * n];
        dyp.par_chunks_mut(n).zip(dy.data.par_chunks(dy.plane_len())).for_each(|(dst, src)| {
            for y in 0..h {
                let srow = &src[(2 * y + py) * dy.w..(2 * y + py + 1) * dy.w];
                for (d, s) in dst[y * pitch..y * pitch + wi].iter_mut().zip(srow[px..].iter().step_by(2)) {
                    *d = *s;
                }
            }
        });
        gemm_nt(&dyp, &a_rows, &cache.buf, &l.rows(ph), n, &mut dwg, kk, false);
        for o in 0..l.c_out {
            for k in 0..kk {
                dw[l.weight_index(ph, o, k)] += dwg[o * kk + k];
            }
        }
    }
    if let Some(dx) = dx {
        // A transposed conv is the adjoint of the 4x4 s2 p1 conv with the same weight tensor
        // read as OIHW `[c_in, c_out, 4, 4]`, so its input gradient is that conv of dy.
        let g = ConvGeom { c_in: l.c_out, c_out: l.c_in, k: 4, stride: 2, pad: 1 };
        let d = conv2d(dy, w, None, g).expect("shapes checked above");
        dx.data.iter_mut().zip(&d.data).for_each(|(a, b)| *a += b);
    }
}
