//! The U-Net's convolutions alone, forward and backward (the "conv fwd+bwd" rows).
//!
//! At the shapes a training step runs them: what "convolution forward and backward as a fraction of
//! the sgemm peak" measures, without the norms, activations, losses and optimiser that the "train"
//! row also times.

use super::{bench_params, random_tensor, time_min_median, time_steady, BenchRow};
use crate::kernels::conv::{conv_backward, conv_forward_act};
use crate::kernels::conv_transpose::{conv_transpose_backward_parts, conv_transpose_forward_act};
use dnr_runtime::network::unet::UNetParams;
use dnr_runtime::nn::activation::Act;
use dnr_runtime::nn::awake::with_workers_awake;
use dnr_runtime::nn::Tensor;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// One layer's operands: inputs (one or two concatenated parts), weights, bias, upstream
/// gradient, and the gradient buffers the backward adds into.
struct Layer {
    parts: Vec<Tensor>,
    w: Vec<f32>,
    b: Vec<f32>,
    dy: Tensor,
    dw: Vec<f32>,
    db: Vec<f32>,
    dx: Vec<Tensor>,
    /// `None` for an encoder conv, the output channels for a decoder transposed conv.
    tconv: Option<usize>,
}

fn layers(p: &UNetParams, size: usize, r: &mut ChaCha8Rng) -> Vec<Layer> {
    let d = p.depth();
    let (mut h, mut w) = p.padded_size(size, size);
    let mut weights =
        |n: usize| -> Vec<f32> { (0..n).map(|_| r.random_range(-0.1..0.1)).collect() };
    let mut out = Vec::new();
    let mut skips = Vec::new();
    for i in 0..d {
        let g = p.encoder_geom(i);
        let (ho, wo) = (h / 2, w / 2);
        out.push(Layer {
            parts: vec![Tensor::zeros(g.c_in, h, w)],
            w: weights(g.weight_len()),
            b: weights(g.c_out),
            dy: Tensor::zeros(g.c_out, ho, wo),
            dw: vec![0.0; g.weight_len()],
            db: vec![0.0; g.c_out],
            dx: vec![Tensor::zeros(g.c_in, h, w)],
            tconv: None,
        });
        skips.push((g.c_out, ho, wo));
        (h, w) = (ho, wo);
    }
    for i in (0..d).rev() {
        let (ci, co) = p.decoder_channels(i);
        let (_, hs, ws) = skips[i];
        let shapes: Vec<usize> = if i == d - 1 {
            vec![ci]
        } else {
            vec![ci - skips[i].0, skips[i].0]
        };
        out.push(Layer {
            parts: shapes.iter().map(|&c| Tensor::zeros(c, hs, ws)).collect(),
            w: weights(ci * co * 16),
            b: weights(co),
            dy: Tensor::zeros(co, 2 * hs, 2 * ws),
            dw: vec![0.0; ci * co * 16],
            db: vec![0.0; co],
            dx: shapes.iter().map(|&c| Tensor::zeros(c, hs, ws)).collect(),
            tconv: Some(co),
        });
    }
    for l in &mut out {
        for t in l.parts.iter_mut().chain([&mut l.dy]) {
            *t = random_tensor(r, t.c, t.h, t.w);
        }
    }
    out
}

/// Layer `i` of `p` once: forward (layout gather, weight packing, GEMMs, bias), then backward
/// (weight, bias and input gradients).
fn run_layer(p: &UNetParams, i: usize, l: &mut Layer) {
    match l.tconv {
        None => {
            let x = &l.parts[0];
            let g = p.encoder_geom(i);
            let (y, _, cache) =
                conv_forward_act(x, Act::Identity, (x.h, x.w), &l.w, &l.b, g, false)
                    .expect("encoder shapes");
            y.recycle();
            conv_backward(
                &cache,
                &l.w,
                &l.dy,
                &mut l.dw,
                &mut l.db,
                Some(&mut l.dx[0]),
            );
        }
        Some(co) => {
            let parts: Vec<&Tensor> = l.parts.iter().collect();
            let (y, cache) =
                conv_transpose_forward_act(&parts, Act::Identity, &l.w, &l.b, co, Act::Identity)
                    .expect("decoder shapes");
            y.recycle();
            let mut dx: Vec<&mut Tensor> = l.dx.iter_mut().collect();
            conv_transpose_backward_parts(&cache, &l.w, &l.dy, &mut l.dw, &mut l.db, &mut dx);
        }
    }
}

/// Forward multiply-adds of layer `l`: output pixels x output channels x taps x input channels.
fn layer_macs(l: &Layer) -> u64 {
    let c_in: usize = l.parts.iter().map(|t| t.c).sum();
    (l.dy.c * l.dy.h * l.dy.w * c_in * 16) as u64 / if l.tconv.is_some() { 4 } else { 1 }
}

/// Every convolution of the U-Net of `widths` at a `size` crop, layer by layer on random
/// operands: each layer's forward (layout gather, weight packing, GEMMs, bias), then its
/// backward (weight, bias and input gradients). FLOPs: 3x the forward's, as for the "train" row.
pub fn bench_conv_layers(widths: &[usize], size: usize, reps: usize) -> BenchRow {
    let p = bench_params(widths);
    let mut r = ChaCha8Rng::seed_from_u64(5);
    let mut ls = layers(&p, size, &mut r);
    let (t_min, t_med) = time_steady(reps, true, || {
        with_workers_awake(|| {
            for (i, l) in ls.iter_mut().enumerate() {
                run_layer(&p, i, l);
            }
        })
    });
    BenchRow::timed(
        "conv fwd+bwd",
        widths,
        size,
        (t_min, t_med),
        3.0 * p.flops(size, size) as f64 * 1e-9,
    )
}

/// Timed batches per layer of [`bench_conv_breakdown`] (the minimum is kept).
const BREAKDOWN_BATCHES: usize = 5;
/// Fewest calls per batch of [`bench_conv_breakdown`].
const BREAKDOWN_MIN_BATCH: usize = 20;

/// One layer's row of [`bench_conv_breakdown`].
#[derive(Debug, Clone, serde::Serialize)]
#[serde(rename_all = "camelCase")]
pub struct LayerRow {
    /// `enc0`.. for the encoder's convs, `dec<i>` for the decoder's transposed convs.
    pub layer: String,
    /// GEMM shape of the forward: output channels x (input channels x 16 taps) x output pixels
    /// (per phase for a transposed conv: its 4 phases each run a quarter of the taps).
    pub shape: String,
    /// Minimum seconds of forward + backward.
    pub min_s: f64,
    /// Forward + backward GFLOP (3x the forward's).
    pub gflop: f64,
}

/// Each convolution of [`bench_conv_layers`] timed alone: where the "conv fwd+bwd" row's time
/// goes, layer by layer. Each timing is the mean of a batch of `reps` calls inside one
/// [`with_workers_awake`] region, as the layer runs inside a step (waking the workers for
/// every call would add their wake-up to each small layer); the minimum over batches.
pub fn bench_conv_breakdown(widths: &[usize], size: usize, reps: usize) -> Vec<LayerRow> {
    let p = bench_params(widths);
    let d = p.depth();
    let mut r = ChaCha8Rng::seed_from_u64(5);
    let mut ls = layers(&p, size, &mut r);
    ls.iter_mut()
        .enumerate()
        .map(|(i, l)| {
            let batch = reps.max(BREAKDOWN_MIN_BATCH);
            let (t_min, _) = time_min_median(BREAKDOWN_BATCHES, || {
                with_workers_awake(|| (0..batch).for_each(|_| run_layer(&p, i, l)))
            });
            let t_min = t_min / batch as f64;
            let c_in: usize = l.parts.iter().map(|t| t.c).sum();
            let (name, shape) = match l.tconv {
                None => (
                    format!("enc{i}"),
                    format!("{}x{}x{}", l.dy.c, c_in * 16, l.dy.h * l.dy.w),
                ),
                Some(_) => (
                    format!("dec{}", 2 * d - 1 - i),
                    format!("{}x{}x{}", l.dy.c, c_in * 4, l.dy.h * l.dy.w / 4),
                ),
            };
            LayerRow {
                layer: name,
                shape,
                min_s: t_min,
                gflop: 6.0 * layer_macs(l) as f64 * 1e-9,
            }
        })
        .collect()
}
