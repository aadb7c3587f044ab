//! 2-D convolution (square kernel, stride, zero padding; weights OIHW), as one GEMM whose B
//! operand is the input read at shifted offsets.
//!
//! The input is rearranged once into *planes* with a row pitch; output pixel (y, x) is GEMM
//! column `y * pitch + x`, and GEMM row `plane * taps + t` is plane `plane` read from offset
//! `shift[t]`. Columns `x >= w_out` of each output row are junk and dropped by
//! [`ConvLayout::finish`]. Three layouts:
//! - [`LayoutKind::SpaceToDepth`] (kernel 4, stride 2, pad 1): the padded input split into its
//!   four 2x2 phases (4 C planes), so the conv is a 2x2 stride-1 conv of those (4 taps).
//! - [`LayoutKind::Padded`] (stride 1): the zero-padded input (C planes, k*k taps).
//! - [`LayoutKind::Im2col`] (anything else): one plane per (c, ky, kx), one tap.

use super::activation::{lrelu, tanh_f32, Act};
use super::gemm::{gemm_nn, AOperand, PackedA, IN_PLACE_A_MAX_N};
use super::norm::{plane_stats, NormStats};
use super::region::{self, ColPlan};
use super::tensor::{par_min_items, pool};
use super::{NnError, Tensor};
use rayon::prelude::*;

/// `dst[i] = act(src[2 i])` for as many values as both hold; returns how many.
fn map_stride2(act: Act, src: &[f32], dst: &mut [f32]) -> usize {
    let n = dst.len().min(src.len().div_ceil(2));
    let (dst, src) = (&mut dst[..n], &src[..(2 * n).min(src.len())]);
    // `chunks(2)` (not `step_by(2)`) so the loops vectorise as de-interleaves.
    match act {
        Act::Identity => dst
            .iter_mut()
            .zip(src.chunks(2))
            .for_each(|(d, s)| *d = s[0]),
        Act::LeakyRelu(sl) => dst
            .iter_mut()
            .zip(src.chunks(2))
            .for_each(|(d, s)| *d = lrelu(s[0], sl)),
        Act::Tanh => dst
            .iter_mut()
            .zip(src.chunks(2))
            .for_each(|(d, s)| *d = tanh_f32(s[0])),
    }
    n
}

/// Geometry of a convolution with a square kernel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ConvGeom {
    /// Input channels.
    pub c_in: usize,
    /// Output channels.
    pub c_out: usize,
    /// Kernel size (k x k).
    pub k: usize,
    /// Stride.
    pub stride: usize,
    /// Zero padding on every side.
    pub pad: usize,
}

impl ConvGeom {
    /// Output height and width for an `h x w` input.
    pub fn out_size(&self, h: usize, w: usize) -> Result<(usize, usize), NnError> {
        if self.k == 0 || self.stride == 0 {
            return Err(NnError::Shape(
                "conv kernel and stride must be positive".into(),
            ));
        }
        if h + 2 * self.pad < self.k || w + 2 * self.pad < self.k {
            return Err(NnError::Shape(format!(
                "conv input {h}x{w} with padding {} is smaller than kernel {}",
                self.pad, self.k
            )));
        }
        Ok((
            (h + 2 * self.pad - self.k) / self.stride + 1,
            (w + 2 * self.pad - self.k) / self.stride + 1,
        ))
    }

    /// Number of weight values (`c_out * c_in * k * k`).
    pub fn weight_len(&self) -> usize {
        self.c_out * self.c_in * self.k * self.k
    }

    /// Multiply-adds of one forward pass on an `h x w` input (bias excluded).
    pub fn macs(&self, h: usize, w: usize) -> u64 {
        match self.out_size(h, w) {
            Ok((ho, wo)) => (ho * wo) as u64 * self.weight_len() as u64,
            Err(_) => 0,
        }
    }

    fn check(&self, x: &Tensor, w: &[f32], bias: Option<&[f32]>) -> Result<(), NnError> {
        if x.c != self.c_in {
            return Err(NnError::Shape(format!(
                "conv expects {} input channels, got {}",
                self.c_in, x.c
            )));
        }
        if w.len() != self.weight_len() {
            return Err(NnError::Shape(format!(
                "conv weight needs {} values, got {}",
                self.weight_len(),
                w.len()
            )));
        }
        if let Some(b) = bias {
            if b.len() != self.c_out {
                return Err(NnError::Shape(format!(
                    "conv bias needs {} values, got {}",
                    self.c_out,
                    b.len()
                )));
            }
        }
        Ok(())
    }
}

/// How a [`ConvLayout`] arranges the input.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LayoutKind {
    /// Kernel 4, stride 2, padding 1: padded input split into 2x2 phases.
    SpaceToDepth,
    /// Stride 1: zero-padded input.
    Padded,
    /// Explicit im2col matrix.
    Im2col,
}

/// The GEMM form of a convolution on one input size. See the module documentation.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ConvLayout {
    /// Convolution geometry.
    pub geom: ConvGeom,
    /// Input arrangement.
    pub kind: LayoutKind,
    /// Input height.
    pub h_in: usize,
    /// Input width.
    pub w_in: usize,
    /// Output height.
    pub h_out: usize,
    /// Output width.
    pub w_out: usize,
    /// Number of planes.
    pub planes: usize,
    /// Rows per plane.
    pub plane_h: usize,
    /// Row pitch of the planes and of the GEMM output.
    pub pitch: usize,
    /// Distance between plane starts (>= `plane_h * pitch`, with slack for the largest shift).
    pub plane_stride: usize,
    /// Offset of each tap within a plane.
    pub shifts: Vec<usize>,
    /// GEMM columns: `h_out * pitch`.
    pub n: usize,
}

impl LayoutKind {
    /// The arrangement used for `geom` (independent of the input size).
    pub fn for_geom(geom: ConvGeom) -> Self {
        if geom.k == 4 && geom.stride == 2 && geom.pad == 1 {
            LayoutKind::SpaceToDepth
        } else if geom.stride == 1 {
            LayoutKind::Padded
        } else {
            LayoutKind::Im2col
        }
    }

    /// Taps per plane.
    pub fn taps(self, geom: ConvGeom) -> usize {
        match self {
            LayoutKind::SpaceToDepth => 4,
            LayoutKind::Padded => geom.k * geom.k,
            LayoutKind::Im2col => 1,
        }
    }
}

/// Index within one output channel's OIHW weights (`(c * k + ky) * k + kx`) of GEMM row `kk`
/// (`plane * taps + t`) of layout `kind`.
pub fn weight_index(geom: ConvGeom, kind: LayoutKind, kk: usize) -> usize {
    let k = geom.k;
    let taps = kind.taps(geom);
    let (p, t) = (kk / taps, kk % taps);
    let (c, ky, kx) = match kind {
        LayoutKind::SpaceToDepth => {
            let (c, a, b) = (p / 4, (p / 2) % 2, p % 2);
            (c, 2 * (t / 2) + a, 2 * (t % 2) + b)
        }
        LayoutKind::Padded => (p, t / k, t % k),
        LayoutKind::Im2col => (p / (k * k), (p / k) % k, p % k),
    };
    (c * k + ky) * k + kx
}

/// OIHW weights packed as the GEMM's A operand (`c_out x c_in k k`) in the row order of
/// [`LayoutKind::for_geom`]; valid for every input size.
pub fn pack_conv_weights(geom: ConvGeom, w: &[f32]) -> PackedA {
    assert_eq!(w.len(), geom.weight_len(), "conv weights");
    let (rows, cols) = conv_weight_offsets(geom);
    PackedA::from_offsets(w, &rows, &cols)
}

/// Where element (o, kk) of the GEMM's A operand lies in OIHW weights: `rows[o] + cols[kk]`
/// (what [`pack_conv_weights`] packs; `AOperand::offsets` reads it in place, same bits).
pub fn conv_weight_offsets(geom: ConvGeom) -> (Vec<usize>, Vec<usize>) {
    let kind = LayoutKind::for_geom(geom);
    let per_o = geom.c_in * geom.k * geom.k;
    let cols: Vec<usize> = (0..per_o).map(|kk| weight_index(geom, kind, kk)).collect();
    let rows: Vec<usize> = (0..geom.c_out).map(|o| o * per_o).collect();
    (rows, cols)
}

/// The weight index of GEMM row `p * taps + t` split as `plane_part(p) + tap_part(t)` (it is a
/// sum for every layout), for packing the transposed weights of the input gradient.
pub fn weight_index_parts(geom: ConvGeom) -> (Vec<usize>, Vec<usize>) {
    let kind = LayoutKind::for_geom(geom);
    let taps = kind.taps(geom);
    let planes = geom.c_in * geom.k * geom.k / taps;
    let tap0 = weight_index(geom, kind, 0);
    let p_part: Vec<usize> = (0..planes)
        .map(|p| weight_index(geom, kind, p * taps) - tap0)
        .collect();
    let t_part: Vec<usize> = (0..taps).map(|t| weight_index(geom, kind, t)).collect();
    debug_assert!((0..planes * taps)
        .all(|kk| weight_index(geom, kind, kk) == p_part[kk / taps] + t_part[kk % taps]));
    (p_part, t_part)
}

impl ConvLayout {
    /// The layout of `geom` on an `h x w` input.
    pub fn new(geom: ConvGeom, h: usize, w: usize) -> Result<Self, NnError> {
        let (h_out, w_out) = geom.out_size(h, w)?;
        let kind = LayoutKind::for_geom(geom);
        let (planes, plane_h, pitch, shifts) = match kind {
            LayoutKind::SpaceToDepth => {
                let pitch = w_out + 1;
                (
                    4 * geom.c_in,
                    h_out + 1,
                    pitch,
                    vec![0, 1, pitch, pitch + 1],
                )
            }
            LayoutKind::Padded => {
                let pitch = w + 2 * geom.pad;
                let shifts = (0..geom.k * geom.k)
                    .map(|t| (t / geom.k) * pitch + t % geom.k)
                    .collect();
                (geom.c_in, h + 2 * geom.pad, pitch, shifts)
            }
            LayoutKind::Im2col => (geom.c_in * geom.k * geom.k, h_out, w_out, vec![0]),
        };
        let max_shift = shifts.iter().copied().max().unwrap_or(0);
        let n = h_out * pitch;
        // Reads reach `n - 1 + max_shift`; keep them inside the plane's own slot.
        let plane_stride = (plane_h * pitch).max(n + max_shift);
        Ok(ConvLayout {
            geom,
            kind,
            h_in: h,
            w_in: w,
            h_out,
            w_out,
            planes,
            plane_h,
            pitch,
            plane_stride,
            shifts,
            n,
        })
    }

    /// Taps per plane.
    pub fn taps(&self) -> usize {
        self.shifts.len()
    }

    /// GEMM depth: `planes * taps` (= `c_in * k * k`).
    pub fn gemm_k(&self) -> usize {
        self.planes * self.taps()
    }

    /// Length of the buffer [`Self::gather`] fills.
    pub fn buffer_len(&self) -> usize {
        self.planes * self.plane_stride
    }

    /// Offset of every GEMM row (`plane * taps + t`) in the gathered buffer.
    pub fn rows(&self) -> Vec<usize> {
        let mut rows = Vec::with_capacity(self.gemm_k());
        for p in 0..self.planes {
            for &s in &self.shifts {
                rows.push(p * self.plane_stride + s);
            }
        }
        rows
    }

    /// Index within one output channel's OIHW weights (`(c * k + ky) * k + kx`) of GEMM row `kk`.
    pub fn weight_index(&self, kk: usize) -> usize {
        weight_index(self.geom, self.kind, kk)
    }

    /// Packs OIHW weights as the GEMM's A operand (`c_out x gemm_k`).
    pub fn pack_weights(&self, w: &[f32]) -> PackedA {
        pack_conv_weights(self.geom, w)
    }

    /// Input pixel (c, y, x) read by plane `p` at plane position (row, col), if any.
    fn source(&self, p: usize, row: usize, col: usize) -> Option<(usize, usize, usize)> {
        let g = &self.geom;
        let (c, y, x) = match self.kind {
            LayoutKind::SpaceToDepth => {
                let (c, a, b) = (p / 4, (p / 2) % 2, p % 2);
                (c, (2 * row + a) as isize - 1, (2 * col + b) as isize - 1)
            }
            LayoutKind::Padded => (
                p,
                row as isize - g.pad as isize,
                col as isize - g.pad as isize,
            ),
            LayoutKind::Im2col => {
                let (c, ky, kx) = (p / (g.k * g.k), (p / g.k) % g.k, p % g.k);
                (
                    c,
                    (row * g.stride + ky) as isize - g.pad as isize,
                    (col * g.stride + kx) as isize - g.pad as isize,
                )
            }
        };
        (y >= 0 && x >= 0 && (y as usize) < self.h_in && (x as usize) < self.w_in)
            .then_some((c, y as usize, x as usize))
    }

    /// Rearranges `x` into the GEMM's B buffer (zeros where the kernel reads padding).
    pub fn gather(&self, x: &Tensor) -> Vec<f32> {
        self.gather_act(x, Act::Identity)
    }

    /// [`Self::gather`] of `act(x)`. `x` may be smaller than the layout's input
    /// (`h_in x w_in`): it is zero-extended at the bottom and right (the U-Net's padding).
    pub fn gather_act(&self, x: &Tensor, act: Act) -> Vec<f32> {
        assert!(
            x.c == self.geom.c_in && x.h <= self.h_in && x.w <= self.w_in,
            "conv gather shape"
        );
        let mut buf = pool::scratch(self.buffer_len());
        let (pw, ph) = (self.pitch, self.plane_h);
        let min = par_min_items(self.plane_stride);
        buf.par_chunks_mut(self.plane_stride)
            .with_min_len(min)
            .enumerate()
            .for_each(|(pl, plane)| self.gather_plane(x, act, pl, plane, pw, ph));
        buf
    }

    /// Fills one plane slot completely (data, padding zeros and slack zeros), so the buffer
    /// needs no separate zeroing pass.
    fn gather_plane(
        &self,
        x: &Tensor,
        act: Act,
        pl: usize,
        plane: &mut [f32],
        pw: usize,
        ph: usize,
    ) {
        plane[ph * pw..].fill(0.0);
        match self.kind {
            LayoutKind::SpaceToDepth => {
                let (c, a, b) = (pl / 4, (pl / 2) % 2, pl % 2);
                // Plane (a, b) row Y col X holds x[2Y + a - 1][2X + b - 1].
                let (x0, col0) = if b == 0 { (1, 1) } else { (0, 0) };
                for row in 0..ph {
                    let r = &mut plane[row * pw..(row + 1) * pw];
                    let Some(y) = (2 * row + a).checked_sub(1).filter(|&y| y < x.h) else {
                        r.fill(0.0);
                        continue;
                    };
                    let src = &x.data[(c * x.h + y) * x.w..][..x.w];
                    r[..col0].fill(0.0);
                    let written = map_stride2(act, &src[x0.min(x.w)..], &mut r[col0..]);
                    r[col0 + written..].fill(0.0);
                }
            }
            LayoutKind::Padded => {
                let p = self.geom.pad;
                for row in 0..ph {
                    let r = &mut plane[row * pw..(row + 1) * pw];
                    match row.checked_sub(p).filter(|&y| y < x.h) {
                        None => r.fill(0.0),
                        Some(y) => {
                            r[..p].fill(0.0);
                            act.map(&x.data[(pl * x.h + y) * x.w..][..x.w], &mut r[p..p + x.w]);
                            r[p + x.w..].fill(0.0);
                        }
                    }
                }
            }
            LayoutKind::Im2col => {
                plane.fill(0.0);
                for row in 0..ph {
                    for col in 0..pw {
                        if let Some((c, y, xx)) = self.source(pl, row, col) {
                            if y < x.h && xx < x.w {
                                plane[row * pw + col] = act.apply(x.data[(c * x.h + y) * x.w + xx]);
                            }
                        }
                    }
                }
            }
        }
    }

    /// Adjoint of [`Self::gather`]: sums the gradient of the B buffer back onto the input
    /// pixels (padding positions are dropped). `dbuf` holds `planes` planes at `plane_stride`.
    pub fn scatter(&self, dbuf: &[f32]) -> Tensor {
        let mut dx = Tensor::zeros(self.geom.c_in, self.h_in, self.w_in);
        self.scatter_add(dbuf, &mut dx);
        dx
    }

    /// [`Self::scatter`] added onto `dx` (`c_in x h_in x w_in`).
    pub fn scatter_add(&self, dbuf: &[f32], dx: &mut Tensor) {
        assert!(dbuf.len() >= (self.planes - 1) * self.plane_stride + self.plane_h * self.pitch);
        assert!(
            dx.c == self.geom.c_in && dx.h == self.h_in && dx.w == self.w_in,
            "conv scatter shape"
        );
        let (pw, ph, ps) = (self.pitch, self.plane_h, self.plane_stride);
        let n = self.h_in * self.w_in;
        if n == 0 {
            return;
        }
        match self.kind {
            LayoutKind::SpaceToDepth => dx
                .data
                .par_chunks_mut(n)
                .with_min_len(par_min_items(n))
                .enumerate()
                .for_each(|(c, dplane)| {
                    // Each input pixel appears in exactly one phase plane: even columns come
                    // from phase b = 1 (column i), odd ones from b = 0 (column i + 1). Both in
                    // one pass, so the row is written contiguously.
                    let w = self.w_in;
                    for a in 0..2 {
                        let p0 = &dbuf[(c * 4 + a * 2) * ps..];
                        let p1 = &dbuf[(c * 4 + a * 2 + 1) * ps..];
                        for row in 0..ph {
                            let Some(y) = (2 * row + a).checked_sub(1).filter(|&y| y < self.h_in)
                            else {
                                continue;
                            };
                            let odd = &p0[row * pw + 1..(row + 1) * pw];
                            let even = &p1[row * pw..(row + 1) * pw];
                            let dst = &mut dplane[y * w..(y + 1) * w];
                            let mut pairs = dst.chunks_exact_mut(2);
                            for ((d, &e), &o) in pairs.by_ref().zip(even).zip(odd) {
                                d[0] += e;
                                d[1] += o;
                            }
                            if let [last] = pairs.into_remainder() {
                                *last += even[w / 2];
                            }
                        }
                    }
                }),
            LayoutKind::Padded => dx
                .data
                .par_chunks_mut(n)
                .with_min_len(par_min_items(n))
                .enumerate()
                .for_each(|(c, dplane)| {
                    let p = self.geom.pad;
                    for y in 0..self.h_in {
                        let src = &dbuf[c * ps + (y + p) * pw + p..][..self.w_in];
                        dplane[y * self.w_in..(y + 1) * self.w_in]
                            .iter_mut()
                            .zip(src)
                            .for_each(|(d, s)| *d += *s);
                    }
                }),
            LayoutKind::Im2col => {
                for pl in 0..self.planes {
                    let plane = &dbuf[pl * ps..];
                    for row in 0..ph {
                        for col in 0..pw {
                            if let Some((c, y, x)) = self.source(pl, row, col) {
                                dx.data[(c * self.h_in + y) * self.w_in + x] +=
                                    plane[row * pw + col];
                            }
                        }
                    }
                }
            }
        }
    }

    /// GEMM column of output pixel (y, x).
    pub fn column(&self, y: usize, x: usize) -> usize {
        y * self.pitch + x
    }

    /// [`Self::gemm`] exact only at the columns `plan` covers, computing the active ones and
    /// one per background class ([`region::gemm_planned`]); also returns the columns computed.
    pub fn gemm_planned(&self, a: &PackedA, buf: &[f32], plan: &ColPlan) -> (Vec<f32>, usize) {
        region::gemm_planned(a, buf, &self.rows(), self.n, plan)
    }

    /// Raw GEMM output (`c_out x n`, row stride `n`) of the weights (packed, or read in place
    /// through [`conv_weight_offsets`]) on a gathered buffer.
    pub fn gemm<'a>(&self, a: impl Into<AOperand<'a>>, buf: &[f32]) -> Vec<f32> {
        let mut out = pool::scratch(self.geom.c_out * self.n);
        gemm_nn(a, buf, &self.rows(), self.n, &mut out, self.n, false);
        out
    }

    /// [`Self::gemm`] of OIHW weights used for this one product (training, where they change
    /// every step; [`conv2d`]): read in place on few columns, where packing them cost as much as
    /// the product, packed otherwise ([`IN_PLACE_A_MAX_N`]). The same bits either way, and as
    /// with weights packed once.
    pub fn gemm_once(&self, w: &[f32], buf: &[f32]) -> Vec<f32> {
        let (rows, cols) = conv_weight_offsets(self.geom);
        if self.n <= IN_PLACE_A_MAX_N {
            self.gemm(AOperand::offsets(w, &rows, &cols), buf)
        } else {
            self.gemm(&PackedA::from_offsets(w, &rows, &cols), buf)
        }
    }

    /// [`Self::finish`] that also returns the instance-norm statistics of every output channel
    /// (computed in the same pass).
    pub fn finish_stats(&self, raw: &[f32], bias: Option<&[f32]>) -> (Tensor, NormStats) {
        let (ho, wo) = (self.h_out, self.w_out);
        let mut out = Tensor::scratch(self.geom.c_out, ho, wo);
        let stats: Vec<(f32, f32)> = if ho * wo == 0 {
            vec![plane_stats(&[]); self.geom.c_out]
        } else {
            out.data
                .par_chunks_mut(ho * wo)
                .with_min_len(par_min_items(ho * wo))
                .enumerate()
                .map(|(o, dst)| {
                    let b = bias.map_or(0.0, |b| b[o]);
                    let src = &raw[o * self.n..(o + 1) * self.n];
                    for y in 0..ho {
                        for (d, s) in dst[y * wo..(y + 1) * wo]
                            .iter_mut()
                            .zip(&src[y * self.pitch..])
                        {
                            *d = s + b;
                        }
                    }
                    plane_stats(dst)
                })
                .collect()
        };
        (
            out,
            NormStats {
                mean: stats.iter().map(|s| s.0).collect(),
                rstd: stats.iter().map(|s| s.1).collect(),
            },
        )
    }

    /// Drops the junk columns of the raw GEMM output and adds the bias.
    pub fn finish(&self, raw: &[f32], bias: Option<&[f32]>) -> Tensor {
        let (ho, wo) = (self.h_out, self.w_out);
        let mut out = Tensor::scratch(self.geom.c_out, ho, wo);
        if ho * wo == 0 {
            return out;
        }
        out.data
            .par_chunks_mut(ho * wo)
            .with_min_len(par_min_items(ho * wo))
            .enumerate()
            .for_each(|(o, dst)| {
                let b = bias.map_or(0.0, |b| b[o]);
                let src = &raw[o * self.n..(o + 1) * self.n];
                for y in 0..ho {
                    for (d, s) in dst[y * wo..(y + 1) * wo]
                        .iter_mut()
                        .zip(&src[y * self.pitch..])
                    {
                        *d = s + b;
                    }
                }
            });
        out
    }
}

/// Convolution of `x` with OIHW weights `w` and optional bias.
pub fn conv2d(
    x: &Tensor,
    w: &[f32],
    bias: Option<&[f32]>,
    geom: ConvGeom,
) -> Result<Tensor, NnError> {
    geom.check(x, w, bias)?;
    let layout = ConvLayout::new(geom, x.h, x.w)?;
    let buf = layout.gather(x);
    let raw = layout.gemm_once(w, &buf);
    pool::recycle(buf);
    let y = layout.finish(&raw, bias);
    pool::recycle(raw);
    Ok(y)
}
