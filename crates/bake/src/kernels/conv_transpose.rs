//! Transposed convolution 4x4 stride 2 padding 1 (weights `[c_in, c_out, 4, 4]`): forward that
//! keeps what backward needs, and backward.

use super::conv::{bias_grad, conv_weight_grad, ConvCache};
use dnr_runtime::nn::activation::Act;
use dnr_runtime::nn::conv::{ConvGeom, ConvLayout};
use dnr_runtime::nn::conv_transpose::TconvLayout;
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
    // The four phases' products and interleave each in one parallel region, the weights read
    // in place on few columns (see `conv_forward_act`).
    let raws = layout.gemm_all_once(w, &buf);
    layout.interleave_all_act(&raws, Some(b), out_act, &mut y);
    raws.into_iter().for_each(pool::recycle);
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
    let mut parts: Vec<&mut Tensor> = dx.into_iter().collect();
    conv_transpose_backward_parts(cache, w, dy, dw, db, &mut parts);
}

/// [`conv_transpose_backward`] with the input gradient split over `dx_parts` as the forward's
/// input was over its `parts` (channels in order; none: no input gradient), each added to.
/// The U-Net hands its skip and decoder gradients here directly: no full-size gradient, no
/// copy of the concatenation's backward.
///
/// A transposed conv is the adjoint of the 4x4 s2 p1 conv `C` from `c_out` channels on
/// `2H x 2W` to `c_in` on `H x W` with the same weight tensor read as OIHW: its input gradient
/// is `C(dy)`, and its weight gradient is `C`'s weight gradient on input `dy` with the
/// (activated) tconv input `x` in the role of the output gradient. Both use one gather of dy.
pub fn conv_transpose_backward_parts(
    cache: &TconvCache,
    w: &[f32],
    dy: &Tensor,
    dw: &mut [f32],
    db: &mut [f32],
    dx_parts: &mut [&mut Tensor],
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
    assert!(
        dx_parts.is_empty()
            || (dx_parts.iter().map(|p| p.c).sum::<usize>() == l.c_in
                && dx_parts.iter().all(|p| p.h == l.h_in && p.w == l.w_in)),
        "conv_transpose_backward: input gradient shapes"
    );
    bias_grad(dy, db);
    let g = ConvGeom {
        c_in: l.c_out,
        c_out: l.c_in,
        k: 4,
        stride: 2,
        pad: 1,
    };
    let layout = ConvLayout::new(g, dy.h, dy.w).expect("a 4x4 s2 p1 conv of an even size");
    let adj_cache = ConvCache {
        buf: layout.gather(dy),
        layout,
    };
    let adj = &adj_cache;
    let input_grad = move || {
        if dx_parts.is_empty() {
            return;
        }
        let raw = adj.layout.gemm_once(w, &adj.buf);
        add_unpitched(&adj.layout, &raw, dx_parts);
        pool::recycle(raw);
    };
    let weight_grad = move || {
        let x = tconv_input(cache);
        conv_weight_grad(adj, &x, dw);
        x.recycle();
    };
    rayon::join(input_grad, weight_grad);
    pool::recycle(adj_cache.buf);
}

/// Adds the GEMM output `raw` of `layout` (plane `o` at `o * n`, rows at the layout's pitch)
/// to the planes of `parts`, which hold the output channels in order.
fn add_unpitched(layout: &ConvLayout, raw: &[f32], parts: &mut [&mut Tensor]) {
    let (ho, wo, n, pitch) = (layout.h_out, layout.w_out, layout.n, layout.pitch);
    let plane = ho * wo;
    if plane == 0 {
        return;
    }
    let mut first = 0;
    for part in parts.iter_mut() {
        let src = &raw[first * n..(first + part.c) * n];
        part.data
            .par_chunks_mut(plane)
            .zip(src.par_chunks(n))
            .with_min_len(par_min_items(plane))
            .for_each(|(dst, src)| {
                for y in 0..ho {
                    for (d, s) in dst[y * wo..(y + 1) * wo].iter_mut().zip(&src[y * pitch..]) {
                        *d += s;
                    }
                }
            });
        first += part.c;
    }
}

/// The activated input `c_in x H x W` of a transposed conv, from its zero-padded planes.
fn tconv_input(cache: &TconvCache) -> Tensor {
    let l = &cache.layout;
    let (h, w, p) = (l.h_in, l.w_in, l.pitch);
    let mut x = Tensor::scratch(l.c_in, h, w);
    if h * w == 0 {
        return x;
    }
    x.data
        .par_chunks_mut(h * w)
        .zip(cache.buf.par_chunks(l.plane_stride))
        .with_min_len(par_min_items(h * w))
        .for_each(|(dst, src)| {
            for y in 0..h {
                dst[y * w..(y + 1) * w].copy_from_slice(&src[(y + 1) * p + 1..][..w]);
            }
        });
    x
}
