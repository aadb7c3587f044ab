//! Transposed convolution 4x4, stride 2, padding 1 (PyTorch `ConvTranspose2d` weight layout
//! `[c_in, c_out, 4, 4]`), computed as four sub-pixel 2x2 convolutions.
//!
//! Output pixel (2y + py, 2x + px) depends on the 2x2 input window whose top-left corner is
//! (y + py - 1, x + px - 1); tap (a, b) of phase (py, px) uses kernel element
//! (3 - py - 2a, 3 - px - 2b). Each phase is one GEMM over the zero-padded input planes read at
//! four shifted offsets, the same scheme as [`super::conv::ConvLayout`].

use super::activation::Act;
use super::gemm::{gemm_nn, gemm_nn_batch, AOperand, NnProduct, PackedA, IN_PLACE_A_MAX_N};
use super::region::{self, ColPlan};
use super::tensor::{par_min_items, pool};
use super::{NnError, Tensor};
use rayon::prelude::*;

/// The GEMM form of a 4x4 stride-2 padding-1 transposed convolution on one input size.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TconvLayout {
    /// Input channels.
    pub c_in: usize,
    /// Output channels.
    pub c_out: usize,
    /// Input height (output is twice as high).
    pub h_in: usize,
    /// Input width.
    pub w_in: usize,
    /// Row pitch of the padded planes and of each phase's GEMM output (`w_in + 2`).
    pub pitch: usize,
    /// Distance between plane starts.
    pub plane_stride: usize,
    /// GEMM columns per phase: `h_in * pitch`.
    pub n: usize,
}

/// Values per activation block of [`TconvLayout::interleave_all_act`] (half an output row block).
const ROW_BLOCK: usize = 64;

impl TconvLayout {
    /// Layout for a `c_in x h x w` input.
    pub fn new(c_in: usize, c_out: usize, h: usize, w: usize) -> Self {
        let pitch = w + 2;
        let n = h * pitch;
        // Largest shift is 2 * pitch + 2; reads reach n - 1 + that.
        let plane_stride = (h + 2) * pitch + 2;
        TconvLayout {
            c_in,
            c_out,
            h_in: h,
            w_in: w,
            pitch,
            plane_stride,
            n,
        }
    }

    /// Number of weight values (`c_in * c_out * 16`).
    pub fn weight_len(&self) -> usize {
        self.c_in * self.c_out * 16
    }

    /// Multiply-adds of one forward pass (bias excluded).
    pub fn macs(&self) -> u64 {
        (self.h_in * self.w_in) as u64 * self.weight_len() as u64
    }

    /// Offset of tap `t = 2a + b` of phase `ph = 2py + px` within a plane.
    pub fn shift(&self, ph: usize, t: usize) -> usize {
        let (py, px, a, b) = (ph / 2, ph % 2, t / 2, t % 2);
        (py + a) * self.pitch + px + b
    }

    /// Kernel element (ky, kx) of tap `t` in phase `ph`.
    pub fn kernel_pos(ph: usize, t: usize) -> (usize, usize) {
        let (py, px, a, b) = (ph / 2, ph % 2, t / 2, t % 2);
        (3 - py - 2 * a, 3 - px - 2 * b)
    }

    /// Index into the `[c_in, c_out, 4, 4]` weights of GEMM element (o, c * 4 + t) of phase `ph`.
    pub fn weight_index(&self, ph: usize, o: usize, kk: usize) -> usize {
        let (c, t) = (kk / 4, kk % 4);
        let (ky, kx) = Self::kernel_pos(ph, t);
        ((c * self.c_out + o) * 4 + ky) * 4 + kx
    }

    /// Offsets of the GEMM rows (`c * 4 + t`) of phase `ph` in the gathered buffer.
    pub fn rows(&self, ph: usize) -> Vec<usize> {
        (0..self.c_in * 4)
            .map(|kk| (kk / 4) * self.plane_stride + self.shift(ph, kk % 4))
            .collect()
    }

    /// Weights of phase `ph` packed as A (`c_out x 4 c_in`).
    pub fn pack_weights(&self, w: &[f32], ph: usize) -> PackedA {
        assert_eq!(w.len(), self.weight_len(), "transposed conv weights");
        // weight_index(ph, o, kk) = (kk's part) + 16 o.
        let rows: Vec<usize> = (0..self.c_out).map(|o| 16 * o).collect();
        let cols: Vec<usize> = (0..self.c_in * 4)
            .map(|kk| self.weight_index(ph, 0, kk))
            .collect();
        PackedA::from_offsets(w, &rows, &cols)
    }

    /// Where element (o, kk) of phase `ph`'s A lies in the weights: `rows[o] + cols[ph][kk]`
    /// (`weight_index(ph, o, kk)` is a sum of the two).
    pub fn weight_offsets(&self) -> (Vec<usize>, [Vec<usize>; 4]) {
        let rows: Vec<usize> = (0..self.c_out).map(|o| 16 * o).collect();
        let cols = std::array::from_fn(|ph| {
            (0..self.c_in * 4)
                .map(|kk| self.weight_index(ph, 0, kk))
                .collect()
        });
        (rows, cols)
    }

    /// The weights of all four phases packed as A, in one pass over the weights
    /// ([`PackedA::from_offsets_multi`]): what [`Self::pack_weights`] gives phase by phase.
    pub fn pack_weights_all(&self, w: &[f32]) -> Vec<PackedA> {
        assert_eq!(w.len(), self.weight_len(), "transposed conv weights");
        let (rows, cols) = self.weight_offsets();
        let cols: Vec<&[usize]> = cols.iter().map(Vec::as_slice).collect();
        PackedA::from_offsets_multi(w, &rows, &cols)
    }

    /// Raw GEMM outputs of all four phases ([`Self::gemm`] of each) in one parallel region.
    /// `a`: the phases' A operands, in phase order (packed, or the weights read in place
    /// through [`Self::weight_offsets`]: the same bits).
    pub fn gemm_all(&self, a: &[AOperand<'_>], buf: &[f32]) -> Vec<Vec<f32>> {
        assert_eq!(a.len(), 4, "four phases");
        let rows: Vec<Vec<usize>> = (0..4).map(|ph| self.rows(ph)).collect();
        let mut raws: Vec<Vec<f32>> = (0..4).map(|_| pool::scratch(self.c_out * self.n)).collect();
        gemm_nn_batch(
            raws.iter_mut()
                .zip(a)
                .zip(&rows)
                .map(|((c, &a), b_rows)| NnProduct {
                    a,
                    b: buf,
                    b_rows,
                    n: self.n,
                    c,
                    ldc: self.n,
                    accumulate: false,
                })
                .collect(),
        );
        raws
    }

    /// [`Self::gemm_all`] of weights used for this one product (training; [`conv_transpose4s2`]):
    /// read in place on few columns, packed in one pass otherwise (as `ConvLayout::gemm_once`).
    pub fn gemm_all_once(&self, w: &[f32], buf: &[f32]) -> Vec<Vec<f32>> {
        if self.n > IN_PLACE_A_MAX_N {
            let packed = self.pack_weights_all(w);
            let a: Vec<AOperand<'_>> = packed.iter().map(AOperand::from).collect();
            return self.gemm_all(&a, buf);
        }
        assert_eq!(w.len(), self.weight_len(), "transposed conv weights");
        let (rows, cols) = self.weight_offsets();
        let a: Vec<AOperand<'_>> = cols
            .iter()
            .map(|c| AOperand::offsets(w, &rows, c))
            .collect();
        self.gemm_all(&a, buf)
    }

    /// Length of the gathered buffer.
    pub fn buffer_len(&self) -> usize {
        self.c_in * self.plane_stride
    }

    /// Zero-padded input planes (one pixel of zeros on every side).
    pub fn gather(&self, x: &Tensor) -> Vec<f32> {
        self.gather_concat(&[x], Act::Identity)
    }

    /// [`Self::gather`] of `act(concat(parts))`: the parts' channels in order (they sum to
    /// `c_in`), each `h_in x w_in`. Reading the parts in place saves the concat copy.
    pub fn gather_concat(&self, parts: &[&Tensor], act: Act) -> Vec<f32> {
        assert_eq!(
            parts.iter().map(|p| p.c).sum::<usize>(),
            self.c_in,
            "tconv gather channels"
        );
        assert!(
            parts.iter().all(|p| p.h == self.h_in && p.w == self.w_in),
            "tconv gather size"
        );
        let mut buf = pool::scratch(self.buffer_len());
        let planes: Vec<&[f32]> = parts
            .iter()
            .flat_map(|p| (0..p.c).map(move |c| p.plane(c)))
            .collect();
        let (h, w) = (self.h_in, self.w_in);
        let min = par_min_items(self.plane_stride);
        buf.par_chunks_mut(self.plane_stride)
            .zip(planes)
            .with_min_len(min)
            .for_each(|(dst, src)| {
                // Every value of the slot is written once: data, the zero border, the slack.
                let p = self.pitch;
                dst[..p].fill(0.0);
                for y in 0..h {
                    let r = &mut dst[(y + 1) * p..(y + 2) * p];
                    r[0] = 0.0;
                    act.map(&src[y * w..(y + 1) * w], &mut r[1..w + 1]);
                    r[w + 1..].fill(0.0);
                }
                dst[(h + 1) * p..].fill(0.0);
            });
        buf
    }

    /// GEMM column (in every phase) of input-grid position (y, x), i.e. output pixel
    /// (2y + py, 2x + px) of phase (py, px).
    pub fn column(&self, y: usize, x: usize) -> usize {
        y * self.pitch + x
    }

    /// [`Self::gemm`] exact only at the columns `plan` covers ([`region::gemm_planned`]);
    /// also returns the columns computed.
    pub fn gemm_planned(
        &self,
        a: &PackedA,
        buf: &[f32],
        ph: usize,
        plan: &ColPlan,
    ) -> (Vec<f32>, usize) {
        region::gemm_planned(a, buf, &self.rows(ph), self.n, plan)
    }

    /// Raw GEMM output of phase `ph` (`c_out x n`).
    pub fn gemm(&self, a: &PackedA, buf: &[f32], ph: usize) -> Vec<f32> {
        let mut out = pool::scratch(self.c_out * self.n);
        gemm_nn(a, buf, &self.rows(ph), self.n, &mut out, self.n, false);
        out
    }

    /// Writes the four phases' raw outputs (`raws`, in phase order; junk columns dropped)
    /// into `out` (`c_out x 2h x 2w`) with the bias added and `act` applied: output pixel
    /// (2y + py, 2x + px) is phase (py, px)'s column (y, x). Each output row is assembled
    /// from its two phases, biased and activated whole, so it is written once and
    /// contiguously. `out` may be smaller than `2h x 2w` (a top-left crop): pixels outside
    /// it are dropped.
    pub fn interleave_all_act(
        &self,
        raws: &[Vec<f32>],
        bias: Option<&[f32]>,
        act: Act,
        out: &mut Tensor,
    ) {
        assert!(
            raws.len() == 4
                && out.c == self.c_out
                && out.h <= 2 * self.h_in
                && out.w <= 2 * self.w_in,
            "tconv output shape"
        );
        let (oh, ow) = (out.h, out.w);
        if ow == 0 || oh == 0 {
            return;
        }
        out.data
            .par_chunks_mut(oh * ow)
            .with_min_len(par_min_items(oh * ow))
            .enumerate()
            .for_each(|(o, dst)| {
                let b = bias.map_or(0.0, |b| b[o]);
                let mut row = [0.0f32; 2 * ROW_BLOCK];
                for (y2, drow) in dst.chunks_exact_mut(ow).enumerate() {
                    let (y, py) = (y2 / 2, y2 % 2);
                    let at = o * self.n + y * self.pitch;
                    let (s0, s1) = (&raws[2 * py][at..], &raws[2 * py + 1][at..]);
                    for (blk, d) in drow.chunks_mut(2 * ROW_BLOCK).enumerate() {
                        let t = &mut row[..d.len()];
                        let j0 = blk * ROW_BLOCK;
                        for (i, pair) in t.chunks_mut(2).enumerate() {
                            pair[0] = s0[j0 + i] + b;
                            if let Some(v) = pair.get_mut(1) {
                                *v = s1[j0 + i] + b;
                            }
                        }
                        act.map(t, d);
                    }
                }
            });
    }
}

/// Transposed convolution 4x4 stride 2 padding 1: `c_in x h x w` to `c_out x 2h x 2w`.
/// `w` is `[c_in, c_out, 4, 4]`.
pub fn conv_transpose4s2(
    x: &Tensor,
    w: &[f32],
    bias: Option<&[f32]>,
    c_out: usize,
) -> Result<Tensor, NnError> {
    let l = TconvLayout::new(x.c, c_out, x.h, x.w);
    if w.len() != l.weight_len() {
        return Err(NnError::Shape(format!(
            "transposed conv weight needs {} values, got {}",
            l.weight_len(),
            w.len()
        )));
    }
    if bias.is_some_and(|b| b.len() != c_out) {
        return Err(NnError::Shape(format!(
            "transposed conv bias needs {c_out} values"
        )));
    }
    let buf = l.gather(x);
    let mut out = Tensor::scratch(c_out, 2 * x.h, 2 * x.w);
    let raws = l.gemm_all_once(w, &buf);
    l.interleave_all_act(&raws, bias, Act::Identity, &mut out);
    raws.into_iter().for_each(pool::recycle);
    pool::recycle(buf);
    Ok(out)
}
