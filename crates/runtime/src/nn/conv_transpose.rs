//! Transposed convolution 4x4, stride 2, padding 1 (PyTorch `ConvTranspose2d` weight layout
//! `[c_in, c_out, 4, 4]`), computed as four sub-pixel 2x2 convolutions.
//!
//! Output pixel (2y + py, 2x + px) depends on the 2x2 input window whose top-left corner is
//! (y + py - 1, x + px - 1); tap (a, b) of phase (py, px) uses kernel element
//! (3 - py - 2a, 3 - px - 2b). Each phase is one GEMM over the zero-padded input planes read at
//! four shifted offsets, the same scheme as [`super::conv::ConvLayout`].

use super::gemm::{gemm_nn, PackedA};
use super::{NnError, Tensor};

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

impl TconvLayout {
    /// Layout for a `c_in x h x w` input.
    pub fn new(c_in: usize, c_out: usize, h: usize, w: usize) -> Self {
        let pitch = w + 2;
        let n = h * pitch;
        // Largest shift is 2 * pitch + 2; reads reach n - 1 + that.
        let plane_stride = (h + 2) * pitch + 2;
        TconvLayout { c_in, c_out, h_in: h, w_in: w, pitch, plane_stride, n }
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
        (0..self.c_in * 4).map(|kk| (kk / 4) * self.plane_stride + self.shift(ph, kk % 4)).collect()
    }

    /// Weights of phase `ph` packed as A (`c_out x 4 c_in`).
    pub fn pack_weights(&self, w: &[f32], ph: usize) -> PackedA {
        assert_eq!(w.len(), self.weight_len(), "transposed conv weights");
        PackedA::from_fn(self.c_out, self.c_in * 4, |o, kk| w[self.weight_index(ph, o, kk)])
    }

    /// Length of the gathered buffer.
    pub fn buffer_len(&self) -> usize {
        self.c_in * self.plane_stride
    }

    /// Zero-padded input planes (one pixel of zeros on every side).
    pub fn gather(&self, x: &Tensor) -> Vec<f32> {
        assert!(x.c == self.c_in && x.h == self.h_in && x.w == self.w_in, "tconv gather shape");
        let mut buf = vec![0.0f32; self.buffer_len()];
        for c in 0..x.c {
            let plane = &mut buf[c * self.plane_stride..];
            for y in 0..x.h {
                plane[(y + 1) * self.pitch + 1..][..x.w].copy_from_slice(&x.data[(c * x.h + y) * x.w..][..x.w]);
            }
        }
        buf
    }

    /// Raw GEMM output of phase `ph` (`c_out x n`).
    pub fn gemm(&self, a: &PackedA, buf: &[f32], ph: usize) -> Vec<f32> {
        let mut out = vec![0.0f32; self.c_out * self.n];
        gemm_nn(a, buf, &self.rows(ph), self.n, &mut out, self.n, false);
        out
    }

    /// Writes phase `ph`'s raw output (junk columns dropped, bias added) into `out`
    /// (`c_out x 2h x 2w`).
    pub fn interleave(&self, raw: &[f32], ph: usize, bias: Option<&[f32]>, out: &mut Tensor) {
        let (py, px) = (ph / 2, ph % 2);
        let (h, w) = (self.h_in, self.w_in);
        for o in 0..self.c_out {
            let b = bias.map_or(0.0, |b| b[o]);
            let src = &raw[o * self.n..(o + 1) * self.n];
            let dst = out.plane_mut(o);
            for y in 0..h {
                let drow = &mut dst[(2 * y + py) * 2 * w..(2 * y + py + 1) * 2 * w];
                for (x, s) in src[y * self.pitch..y * self.pitch + w].iter().enumerate() {
                    drow[2 * x + px] = s + b;
                }
            }
        }
    }
}

/// Transposed convolution 4x4 stride 2 padding 1: `c_in x h x w` to `c_out x 2h x 2w`.
/// `w` is `[c_in, c_out, 4, 4]`.
pub fn conv_transpose4s2(x: &Tensor, w: &[f32], bias: Option<&[f32]>, c_out: usize) -> Result<Tensor, NnError> {
    let l = TconvLayout::new(x.c, c_out, x.h, x.w);
    if w.len() != l.weight_len() {
        return Err(NnError::Shape(format!("transposed conv weight needs {} values, got {}", l.weight_len(), w.len())));
    }
    if bias.is_some_and(|b| b.len() != c_out) {
        return Err(NnError::Shape(format!("transposed conv bias needs {c_out} values")));
    }
    let buf = l.gather(x);
    let mut out = Tensor::zeros(c_out, 2 * x.h, 2 * x.w);
    for ph in 0..4 {
        let raw = l.gemm(&l.pack_weights(w, ph), &buf, ph);
        l.interleave(&raw, ph, bias, &mut out);
    }
    Ok(out)
}
