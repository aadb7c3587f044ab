//! Transposed convolution 4x4 stride 2 padding 1 (weights `[c_in, c_out, 4, 4]`): forward that
//! keeps what backward needs, and backward.

use super::conv::bias_grad;
use dnr_runtime::nn::activation::Act;
use dnr_runtime::nn::conv::{conv2d, ConvGeom};
use dnr_runtime::nn::conv_transpose::TconvLayout;
use dnr_runtime::nn::gemm::gemm_nt;
use dnr_runtime::nn::tensor::{par_min_items, pool};
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
pub fn conv_transpose_forward(
    x: &Tensor,
    w: &[f32],
    b: &[f32],
    c_out: usize,
) -> Result<(Tensor, TconvCache), NnError> {
    conv_transpose_forward_act(&[x], Act::Identity, w, b, c_out, Act::Identity)
}

/// `y = out_act(tconv(in_act(concat(parts)), w) + b)`: the parts' channels in order (summing to
/// `c_in`), all `H x W`. The cache holds the activated input, so [`conv_transpose_backward`]
/// returns d/d(in_act(concat)) and expects d/d(tconv + b) (undo `out_act` first).
pub fn conv_transpose_forward_act(
    parts: &[&Tensor],
    in_act: Act,
    w: &[f32],
    b: &[f32],
    c_out: usize,
    out_act: Act,
) -> Result<(Tensor, TconvCache), NnError> {
    let c_in: usize = parts.iter().map(|p| p.c).sum();
    let (h, wd) = (parts[0].h, parts[0].w);
    if parts.iter().any(|p| p.h != h || p.w != wd) {
        return Err(NnError::Shape(
            "conv_transpose_forward: parts differ in size".into(),
        ));
    }
    let layout = TconvLayout::new(c_in, c_out, h, wd);
    if w.len() != layout.weight_len() || b.len() != c_out {
        return Err(NnError::Shape(format!(
            "conv_transpose_forward: w {}, b {} for {c_in}->{c_out}",
            w.len(),
            b.len()
        )));
    }
    let buf = layout.gather_concat(parts, in_act);
    let mut y = Tensor::scratch(c_out, 2 * h, 2 * wd);
    for ph in 0..4 {
        let raw = layout.gemm(&layout.pack_weights(w, ph), &buf, ph);
        layout.interleave_act(&raw, ph, Some(b), out_act, &mut y);
        pool::recycle(raw);
    }
    Ok((y, TconvCache { layout, buf }))
}

/// Backward of [`conv_transpose_forward`].
/// dy: `c_out x 2H x 2W`; w: `[c_in, c_out, 4, 4]`.
/// Adds to dw and db; adds the input gradient (`c_in x H x W`) to `dx` when given.
pub fn conv_transpose_backward(
    cache: &TconvCache,
    w: &[f32],
    dy: &Tensor,
    dw: &mut [f32],
    db: &mut [f32],
    dx: Option<&mut Tensor>,
) {
    let l = &cache.layout;
    assert!(
        dy.c == l.c_out && dy.h == 2 * l.h_in && dy.w == 2 * l.w_in,
        "conv_transpose_backward: dy shape"
    );
    assert!(
        w.len() == l.weight_len() && dw.len() == w.len() && db.len() == l.c_out,
        "conv_transpose_backward: weights"
    );
    bias_grad(dy, db);
    let (h, wi, n, pitch) = (l.h_in, l.w_in, l.n, l.pitch);
    let kk = 4 * l.c_in;
    let a_rows: Vec<usize> = (0..l.c_out).map(|o| o * n).collect();
    let mut dwg = pool::scratch(l.c_out * kk);
    let mut dyp = pool::zeroed(l.c_out * n);
    for ph in 0..4 {
        let (py, px) = (ph / 2, ph % 2);
        // This phase's output gradient with the GEMM's row pitch (junk columns stay zero).
        dyp.par_chunks_mut(n)
            .zip(dy.data.par_chunks(dy.plane_len()))
            .with_min_len(par_min_items(n))
            .for_each(|(dst, src)| {
                for y in 0..h {
                    let srow = &src[(2 * y + py) * dy.w..(2 * y + py + 1) * dy.w];
                    for (d, s) in dst[y * pitch..y * pitch + wi]
                        .iter_mut()
                        .zip(srow[px..].chunks(2))
                    {
                        *d = s[0];
                    }
                }
            });
        gemm_nt(
            &dyp,
            &a_rows,
            &cache.buf,
            &l.rows(ph),
            n,
            &mut dwg,
            kk,
            false,
        );
        // dw[c][o][ky][kx]: GEMM column c * 4 + t of phase ph is kernel element kernel_pos(ph, t).
        for c in 0..l.c_in {
            for t in 0..4 {
                let (ky, kx) = TconvLayout::kernel_pos(ph, t);
                for o in 0..l.c_out {
                    dw[((c * l.c_out + o) * 4 + ky) * 4 + kx] += dwg[o * kk + c * 4 + t];
                }
            }
        }
    }
    pool::recycle(dwg);
    pool::recycle(dyp);
    if let Some(dx) = dx {
        // A transposed conv is the adjoint of the 4x4 s2 p1 conv with the same weight tensor
        // read as OIHW `[c_in, c_out, 4, 4]`, so its input gradient is that conv of dy.
        let g = ConvGeom {
            c_in: l.c_out,
            c_out: l.c_in,
            k: 4,
            stride: 2,
            pad: 1,
        };
        let d = conv2d(dy, w, None, g).expect("shapes checked above");
        dx.data.iter_mut().zip(&d.data).for_each(|(a, b)| *a += b);
        d.recycle();
    }
}
