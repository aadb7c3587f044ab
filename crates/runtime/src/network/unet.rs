//! The U-Net deferred neural renderer (`architecture: "unet"` in `docs/DESIGN.md`).
//!
//! Encoder i: conv 4x4 s2 p1 to `w_i`, norm, LeakyReLU(0.2). Decoder i = D-1 .. 1: up_i to
//! `w_(i-1)`, norm, LeakyReLU, concat with encoder i-1 (decoder channels first). Last: up_0 to
//! `out_ch`, tanh. The input is zero-padded at the bottom/right to a multiple of 2^D and the
//! output cropped back.

use super::{check_no_extra, fetch_tensors, map_lookup, NetworkError, TensorRef};
use crate::nn::activation::{Act, LEAKY_SLOPE};
use crate::nn::awake::with_workers_awake;
use crate::nn::conv::{pack_conv_weights, ConvGeom, ConvLayout};
use crate::nn::conv_transpose::TconvLayout;
use crate::nn::gemm::{AOperand, PackedA};
use crate::nn::norm::{instance_norm, normalize};
use crate::nn::region::{Classes, ColPlan};
use crate::nn::tensor::pool;
use crate::nn::upsample::upsample_nearest2_concat;
use crate::nn::{NnError, Tensor};
use std::collections::BTreeMap;

/// How the decoder doubles the resolution.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Decoder {
    /// Transposed convolution 4x4 stride 2 padding 1, weight `[c_in, c_out, 4, 4]`.
    TransposedConv,
    /// Nearest x2 upsample, then conv 3x3 stride 1 padding 1, weight `[c_out, c_in, 3, 3]`.
    UpsampleConv,
}

/// Normalisation after every conv but the last.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Norm {
    /// Instance norm without affine parameters (eps 1e-5, biased variance).
    Instance,
    /// None.
    None,
}

/// Architecture of a U-Net renderer.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct UNetParams {
    /// Input (feature) channels.
    pub in_ch: usize,
    /// Output channels (3 or 4 for a renderer).
    pub out_ch: usize,
    /// Encoder widths `w_0 .. w_(D-1)`, 1 <= D <= 8.
    pub widths: Vec<usize>,
    /// Decoder kind.
    pub decoder: Decoder,
    /// Normalisation.
    pub norm: Norm,
}

/// Maximum depth.
pub const MAX_DEPTH: usize = 8;

impl UNetParams {
    /// Depth D.
    pub fn depth(&self) -> usize {
        self.widths.len()
    }

    /// Checks the ranges of the parameters.
    pub fn validate(&self) -> Result<(), NetworkError> {
        let d = self.depth();
        if d == 0 || d > MAX_DEPTH {
            return Err(NetworkError::Params(format!(
                "U-Net depth {d} outside 1..={MAX_DEPTH}"
            )));
        }
        if self.in_ch == 0 || self.out_ch == 0 || self.widths.contains(&0) {
            return Err(NetworkError::Params(
                "U-Net channel counts must be positive".into(),
            ));
        }
        Ok(())
    }

    /// Input and output channels of decoder `i`.
    pub fn decoder_channels(&self, i: usize) -> (usize, usize) {
        let d = self.depth();
        let c_in = if i == d - 1 {
            self.widths[d - 1]
        } else {
            2 * self.widths[i]
        };
        let c_out = if i == 0 {
            self.out_ch
        } else {
            self.widths[i - 1]
        };
        (c_in, c_out)
    }

    /// Input channels of encoder `i`.
    pub fn encoder_in(&self, i: usize) -> usize {
        if i == 0 {
            self.in_ch
        } else {
            self.widths[i - 1]
        }
    }

    /// Geometry of encoder `i`.
    pub fn encoder_geom(&self, i: usize) -> ConvGeom {
        ConvGeom {
            c_in: self.encoder_in(i),
            c_out: self.widths[i],
            k: 4,
            stride: 2,
            pad: 1,
        }
    }

    /// Geometry of the 3x3 conv of decoder `i` (upsampleConv).
    pub fn decoder_geom(&self, i: usize) -> ConvGeom {
        let (c_in, c_out) = self.decoder_channels(i);
        ConvGeom {
            c_in,
            c_out,
            k: 3,
            stride: 1,
            pad: 1,
        }
    }

    /// Every tensor the architecture names with its shape, encoder first.
    pub fn tensor_specs(&self) -> Vec<(String, Vec<usize>)> {
        let mut v = Vec::new();
        for i in 0..self.depth() {
            v.push((
                format!("encoder.{i}.weight"),
                vec![self.widths[i], self.encoder_in(i), 4, 4],
            ));
            v.push((format!("encoder.{i}.bias"), vec![self.widths[i]]));
        }
        for i in 0..self.depth() {
            let (ci, co) = self.decoder_channels(i);
            let shape = match self.decoder {
                Decoder::TransposedConv => vec![ci, co, 4, 4],
                Decoder::UpsampleConv => vec![co, ci, 3, 3],
            };
            v.push((format!("decoder.{i}.weight"), shape));
            v.push((format!("decoder.{i}.bias"), vec![co]));
        }
        v
    }

    /// Padded frame size for an `h x w` image (multiples of 2^D).
    pub fn padded_size(&self, h: usize, w: usize) -> (usize, usize) {
        let p = 1usize << self.depth();
        (h.div_ceil(p) * p, w.div_ceil(p) * p)
    }

    /// Convolution FLOPs (2 per multiply-add, bias, norm and activations excluded) of one
    /// forward pass on an `h x w` image, counted on the padded frame.
    pub fn flops(&self, h: usize, w: usize) -> u64 {
        let (mut hh, mut ww) = self.padded_size(h, w);
        let mut macs = 0u64;
        for i in 0..self.depth() {
            macs += self.encoder_geom(i).macs(hh, ww);
            hh /= 2;
            ww /= 2;
        }
        for i in (0..self.depth()).rev() {
            let (ci, co) = self.decoder_channels(i);
            macs += match self.decoder {
                Decoder::TransposedConv => (hh * ww * ci * co * 16) as u64,
                Decoder::UpsampleConv => (4 * hh * ww * ci * co * 9) as u64,
            };
            hh *= 2;
            ww *= 2;
        }
        2 * macs
    }
}

/// Cost of planning [`UNet::forward_masked`] per position of every layer, in FLOPs of GEMM
/// work: measured planning at about 29 ns per position (20 ms for a 512x512 frame) while the
/// CPU-sized U-Net's convolutions ran at about 88 GFLOP/s on 2 cores (`unet_skip` test
/// `timing`, `dnr bench render`), so 29e-9 * 88e9 = 2500. See [`UNet::skip_worthwhile`].
pub const PLAN_FLOPS_PER_POSITION: f64 = 2500.0;

/// Work of one convolution of a masked forward pass ([`UNet::plan`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LayerWork {
    /// `encoder.{i}` or `decoder.{i}`.
    pub name: String,
    /// Output positions needed (the last layer's crop excluded).
    pub positions: usize,
    /// Active positions: those whose receptive field holds a covered pixel.
    pub active: usize,
    /// GEMM columns computed (over all phases of a transposed convolution).
    pub computed: usize,
    /// GEMM columns of the whole-frame evaluation (junk columns included).
    pub total: usize,
}

/// Column plans of every GEMM of a masked forward pass.
#[derive(Clone, Debug)]
struct SkipPlan {
    /// Per encoder i.
    enc: Vec<ColPlan>,
    /// Per decoder i: one plan (upsampleConv) or four, one per phase (transposedConv).
    dec: Vec<Vec<ColPlan>>,
    /// Work per convolution in evaluation order.
    work: Vec<LayerWork>,
}

/// Weights of one convolution with its packed GEMM form.
#[derive(Clone, Debug)]
struct Layer {
    bias: Vec<f32>,
    /// One packed A per GEMM: conv 1, transposed conv 4 (phases).
    packed: Vec<PackedA>,
}

/// A U-Net with validated weights, ready to run.
#[derive(Clone, Debug)]
pub struct UNet {
    params: UNetParams,
    enc: Vec<Layer>,
    dec: Vec<Layer>,
}

impl UNet {
    /// Builds the network, fetching every tensor of [`UNetParams::tensor_specs`] through
    /// `lookup` and checking its shape. (Extra tensors cannot be seen through a lookup; see
    /// [`UNet::from_map`] or [`super::check_no_extra`].)
    pub fn new<'a>(
        params: UNetParams,
        lookup: &dyn Fn(&str) -> Option<TensorRef<'a>>,
    ) -> Result<Self, NetworkError> {
        params.validate()?;
        let specs = params.tensor_specs();
        let mut vals = fetch_tensors(&specs, lookup)?.into_iter();
        let d = params.depth();
        let mut enc = Vec::with_capacity(d);
        for i in 0..d {
            let (w, b) = (vals.next().expect("spec"), vals.next().expect("spec"));
            enc.push(Layer {
                bias: b,
                packed: vec![pack_conv_weights(params.encoder_geom(i), &w)],
            });
        }
        let mut dec = Vec::with_capacity(d);
        for i in 0..d {
            let (w, b) = (vals.next().expect("spec"), vals.next().expect("spec"));
            let packed = match params.decoder {
                Decoder::TransposedConv => {
                    let (ci, co) = params.decoder_channels(i);
                    let l = TconvLayout::new(ci, co, 1, 1);
                    l.pack_weights_all(&w)
                }
                Decoder::UpsampleConv => vec![pack_conv_weights(params.decoder_geom(i), &w)],
            };
            dec.push(Layer { bias: b, packed });
        }
        Ok(UNet { params, enc, dec })
    }

    /// Builds the network from a map of `name -> (shape, values)`; names the architecture does
    /// not list are an error.
    pub fn from_map(
        params: UNetParams,
        map: &BTreeMap<String, (Vec<usize>, Vec<f32>)>,
    ) -> Result<Self, NetworkError> {
        params.validate()?;
        check_no_extra(&params.tensor_specs(), map.keys().map(String::as_str))?;
        Self::new(params, &map_lookup(map))
    }

    /// The architecture.
    pub fn params(&self) -> &UNetParams {
        &self.params
    }

    /// Output (after tanh, in [-1, 1]) for a `in_ch x H x W` feature image; `out_ch x H x W`.
    ///
    /// Activations are kept before their LeakyReLU (normalised conv outputs, `z`); the next
    /// layer applies the LeakyReLU while it gathers its input, and the decoder reads its skip
    /// in place, so no activated copy or concatenation is ever built.
    pub fn forward(&self, x: &Tensor) -> Result<Tensor, NnError> {
        self.run(x, None)
    }

    /// [`Self::forward`] that skips the convolution work of positions whose value cannot
    /// depend on a covered pixel; the output is bit-identical to [`Self::forward`].
    ///
    /// `covered` holds `H * W` flags (row-major) of the unpadded frame. An uncovered pixel
    /// whose features are not all (positive) zero is treated as covered, so the result is
    /// exact whatever `x` holds. Positions that no covered pixel reaches hold per-phase
    /// constants; one representative per phase is computed and copied to the others, and
    /// normalisation runs over the whole materialised map as in [`Self::forward`].
    pub fn forward_masked(&self, x: &Tensor, covered: &[bool]) -> Result<Tensor, NnError> {
        self.check_input(x)?;
        if covered.len() != x.h * x.w {
            return Err(NnError::Shape(format!(
                "coverage has {} flags for a {}x{} frame",
                covered.len(),
                x.h,
                x.w
            )));
        }
        if x.h == 0 || x.w == 0 {
            return Ok(Tensor::zeros(self.params.out_ch, x.h, x.w));
        }
        let n = x.h * x.w;
        let active: Vec<bool> = (0..n)
            .map(|i| covered[i] || (0..x.c).any(|c| x.data[c * n + i].to_bits() != 0))
            .collect();
        if active.iter().all(|&a| a) {
            return self.run(x, None);
        }
        let plan = self.skip_plan(x.h, x.w, &active)?;
        self.run(x, Some(&plan))
    }

    /// A cheap estimate of whether [`Self::forward_masked`] pays off for coverage `covered`
    /// (`h * w` flags). The covered bounding box grown by `2^(D+1)` pixels (about how far a
    /// covered pixel's influence spreads) gives the fraction of the convolution work that
    /// stays; the rest is the saving. Planning classifies every position of every layer
    /// whatever the widths, and the gathers and normalisations stay whole-frame, so skipping
    /// must save more than [`PLAN_FLOPS_PER_POSITION`] FLOPs per planned position: thin
    /// networks (few FLOPs per position) and mostly covered frames are faster evaluated whole.
    pub fn skip_worthwhile(&self, h: usize, w: usize, covered: &[bool]) -> bool {
        if covered.len() != h * w || h == 0 || w == 0 {
            return false;
        }
        let (mut y0, mut y1, mut x0, mut x1) = (usize::MAX, 0, usize::MAX, 0);
        for (i, _) in covered.iter().enumerate().filter(|(_, &c)| c) {
            let (y, x) = (i / w, i % w);
            (y0, y1, x0, x1) = (y0.min(y), y1.max(y), x0.min(x), x1.max(x));
        }
        if y0 > y1 {
            return true; // nothing covered: only the background classes are computed
        }
        let m = 2usize << self.params.depth();
        let hh = (y1 + m).min(h - 1) + 1 - y0.saturating_sub(m);
        let ww = (x1 + m).min(w - 1) + 1 - x0.saturating_sub(m);
        let kept = (hh * ww) as f64 / (h * w) as f64;
        let saved = (1.0 - kept) * self.params.flops(h, w) as f64;
        let (hp, wp) = self.params.padded_size(h, w);
        // Input, encoder and decoder maps: about (2 + 2/3) frames of positions.
        let positions = (hp * wp) as f64 * (8.0 / 3.0);
        kept < 0.5 && saved > PLAN_FLOPS_PER_POSITION * positions
    }

    /// Per-convolution work of [`Self::forward_masked`] on an `h x w` frame with coverage
    /// `covered` (`h * w` flags), assuming uncovered features are zero.
    pub fn plan(&self, h: usize, w: usize, covered: &[bool]) -> Result<Vec<LayerWork>, NnError> {
        if covered.len() != h * w {
            return Err(NnError::Shape(format!(
                "coverage has {} flags for a {h}x{w} frame",
                covered.len()
            )));
        }
        if h == 0 || w == 0 {
            return Ok(Vec::new());
        }
        Ok(self.skip_plan(h, w, covered)?.work)
    }

    fn check_input(&self, x: &Tensor) -> Result<(), NnError> {
        if x.c != self.params.in_ch {
            return Err(NnError::Shape(format!(
                "U-Net expects {} input channels, got {}",
                self.params.in_ch, x.c
            )));
        }
        Ok(())
    }

    /// Value classes of every layer ([`crate::nn::region`]) and the column plans of every
    /// GEMM, for an `h x w` frame (`h, w > 0`) whose active input pixels are `active`.
    fn skip_plan(&self, h: usize, w: usize, active: &[bool]) -> Result<SkipPlan, NnError> {
        let p = &self.params;
        let d = p.depth();
        let (hp, wp) = p.padded_size(h, w);
        let mut padded = vec![false; hp * wp];
        for y in 0..h {
            padded[y * wp..y * wp + w].copy_from_slice(&active[y * w..(y + 1) * w]);
        }
        let input = Classes::input(hp, wp, &padded);
        let mut work = Vec::with_capacity(2 * d);
        let mut enc = Vec::with_capacity(d);
        let mut maps: Vec<Classes> = Vec::with_capacity(d);
        for i in 0..d {
            let src = maps.last().unwrap_or(&input);
            let l = ConvLayout::new(p.encoder_geom(i), src.h, src.w)?;
            let out = src.conv(4, 2, 1, (l.h_out, l.w_out));
            let pos = (0..l.h_out).flat_map(|y| (0..l.w_out).map(move |x| (y, x)));
            let plan = ColPlan::new(
                pos.map(|(y, x)| (l.column(y, x), out.ids[y * out.w + x])),
                out.count,
            );
            work.push(work_of(format!("encoder.{i}"), &[&plan], l.n));
            enc.push(plan);
            maps.push(out);
        }
        let mut dec: Vec<Vec<ColPlan>> = vec![Vec::new(); d];
        let mut cur = maps.pop().expect("depth >= 1");
        for i in (0..d).rev() {
            let inp = if i < d - 1 { cur.concat(&maps[i]) } else { cur };
            let (oh, ow) = if i == 0 {
                (h, w)
            } else {
                (2 * inp.h, 2 * inp.w)
            };
            let (ci, co) = p.decoder_channels(i);
            let (out, plans, total) = match p.decoder {
                Decoder::TransposedConv => {
                    let l = TconvLayout::new(ci, co, inp.h, inp.w);
                    let out = inp.tconv();
                    let plans: Vec<ColPlan> = (0..4)
                        .map(|ph| {
                            let (py, px) = (ph / 2, ph % 2);
                            let pos = (0..inp.h)
                                .flat_map(|y| (0..inp.w).map(move |x| (y, x)))
                                .filter(|&(y, x)| 2 * y + py < oh && 2 * x + px < ow);
                            ColPlan::new(
                                pos.map(|(y, x)| {
                                    let (yy, xx) = (2 * y + py, 2 * x + px);
                                    (l.column(y, x), out.ids[yy * out.w + xx])
                                }),
                                out.count,
                            )
                        })
                        .collect();
                    (out, plans, l.n)
                }
                Decoder::UpsampleConv => {
                    let u = inp.upsample2();
                    let l = ConvLayout::new(p.decoder_geom(i), u.h, u.w)?;
                    let out = u.conv(3, 1, 1, (l.h_out, l.w_out));
                    let pos = (0..oh).flat_map(|y| (0..ow).map(move |x| (y, x)));
                    let plan = ColPlan::new(
                        pos.map(|(y, x)| (l.column(y, x), out.ids[y * out.w + x])),
                        out.count,
                    );
                    (out, vec![plan], l.n)
                }
            };
            let refs: Vec<&ColPlan> = plans.iter().collect();
            work.push(work_of(format!("decoder.{i}"), &refs, total));
            dec[i] = plans;
            cur = out;
        }
        Ok(SkipPlan { enc, dec, work })
    }

    /// Whole-frame or planned evaluation, with the pool's workers kept polling between the
    /// layers' many short parallel kernels ([`with_workers_awake`]).
    fn run(&self, x: &Tensor, plan: Option<&SkipPlan>) -> Result<Tensor, NnError> {
        with_workers_awake(|| self.run_layers(x, plan))
    }

    fn run_layers(&self, x: &Tensor, plan: Option<&SkipPlan>) -> Result<Tensor, NnError> {
        let p = &self.params;
        self.check_input(x)?;
        if x.h == 0 || x.w == 0 {
            return Ok(Tensor::zeros(p.out_ch, x.h, x.w));
        }
        let (hp, wp) = p.padded_size(x.h, x.w);
        let d = p.depth();
        let lrelu = Act::LeakyRelu(LEAKY_SLOPE);
        let mut z: Vec<Tensor> = Vec::with_capacity(d);
        for i in 0..d {
            let (src, act, (h, w)) = match z.last() {
                None => (x, Act::Identity, (hp, wp)),
                Some(prev) => (prev, lrelu, (prev.h, prev.w)),
            };
            let l = ConvLayout::new(p.encoder_geom(i), h, w)?;
            let buf = l.gather_act(src, act);
            let a = &self.enc[i].packed[0];
            let raw = match plan {
                None => l.gemm(a, &buf),
                Some(s) => l.gemm_planned(a, &buf, &s.enc[i]).0,
            };
            pool::recycle(buf);
            z.push(self.finish_norm(&l, &raw, &self.enc[i].bias));
            pool::recycle(raw);
        }
        let mut cur = z.pop().expect("depth >= 1");
        for i in (0..d).rev() {
            let mut parts = vec![&cur];
            if i < d - 1 {
                parts.push(&z[i]);
            }
            if i == 0 {
                let out = self.up(0, &parts, Act::Tanh, x.h, x.w, plan);
                cur.recycle();
                z.into_iter().for_each(Tensor::recycle);
                return out;
            }
            let y = self.up(i, &parts, Act::Identity, 2 * cur.h, 2 * cur.w, plan)?;
            std::mem::replace(&mut cur, y).recycle();
            if self.params.norm == Norm::Instance {
                instance_norm(&mut cur);
            }
        }
        unreachable!("the loop returns at i = 0")
    }

    /// Conv output without junk columns, plus bias, normalised when the architecture says so.
    fn finish_norm(&self, l: &ConvLayout, raw: &[f32], bias: &[f32]) -> Tensor {
        if self.params.norm == Norm::Instance {
            let (mut y, st) = l.finish_stats(raw, Some(bias));
            normalize(&mut y, &st);
            y
        } else {
            l.finish(raw, Some(bias))
        }
    }

    /// Decoder `i` on `lrelu(concat(parts))`, output `act`-ed and cropped to `oh x ow`.
    fn up(
        &self,
        i: usize,
        parts: &[&Tensor],
        act: Act,
        oh: usize,
        ow: usize,
        plan: Option<&SkipPlan>,
    ) -> Result<Tensor, NnError> {
        let layer = &self.dec[i];
        let (ci, co) = self.params.decoder_channels(i);
        let (h, w) = (parts[0].h, parts[0].w);
        let lrelu = Act::LeakyRelu(LEAKY_SLOPE);
        match self.params.decoder {
            Decoder::TransposedConv => {
                let l = TconvLayout::new(ci, co, h, w);
                let buf = l.gather_concat(parts, lrelu);
                let mut out = Tensor::scratch(co, oh, ow);
                let raws = match plan {
                    None => {
                        let a: Vec<AOperand<'_>> =
                            layer.packed.iter().map(AOperand::from).collect();
                        l.gemm_all(&a, &buf)
                    }
                    Some(s) => (0..4)
                        .map(|ph| l.gemm_planned(&layer.packed[ph], &buf, ph, &s.dec[i][ph]).0)
                        .collect(),
                };
                l.interleave_all_act(&raws, Some(&layer.bias), act, &mut out);
                raws.into_iter().for_each(pool::recycle);
                pool::recycle(buf);
                Ok(out)
            }
            Decoder::UpsampleConv => {
                let u = upsample_nearest2_concat(parts, lrelu);
                let l = ConvLayout::new(self.params.decoder_geom(i), u.h, u.w)?;
                let buf = l.gather(&u);
                u.recycle();
                let a = &layer.packed[0];
                let raw = match plan {
                    None => l.gemm(a, &buf),
                    Some(s) => l.gemm_planned(a, &buf, &s.dec[i][0]).0,
                };
                pool::recycle(buf);
                let mut y = l.finish(&raw, Some(&layer.bias));
                pool::recycle(raw);
                if act != Act::Identity {
                    y.data.iter_mut().for_each(|v| *v = act.apply(*v));
                }
                Ok(if (oh, ow) == (y.h, y.w) {
                    y
                } else {
                    y.crop_top_left(oh, ow)
                })
            }
        }
    }
}

/// Work summary of one convolution's plans (`total` columns per GEMM).
fn work_of(name: String, plans: &[&ColPlan], total: usize) -> LayerWork {
    LayerWork {
        name,
        positions: plans.iter().map(|p| p.positions).sum(),
        active: plans.iter().map(|p| p.active).sum(),
        computed: plans.iter().map(|p| p.computed(total)).sum(),
        total: total * plans.len(),
    }
}
