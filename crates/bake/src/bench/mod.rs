//! The measurements behind `dnr bench train` and `dnr bench render`.
//!
//! U-Net training-step and inference benchmarks: min-of-reps wall time, conv FLOPs per step and the
//! achieved rate as a fraction of an sgemm peak measured in the same run with the same GEMM.

use crate::kernels::adam::{Adam, AdamConfig};
use crate::kernels::loss::l1_loss;
use crate::kernels::unet::UNetTrain;
use crate::train::PhaseSeconds;
use dnr_runtime::network::unet::{Decoder, Norm, UNet, UNetParams};
use dnr_runtime::nn::awake::with_workers_awake;
use dnr_runtime::nn::conv::ConvLayout;
use dnr_runtime::nn::gemm::{gemm_nn, simd_level, PackedA, SimdLevel};
use dnr_runtime::nn::tensor::pool;
use dnr_runtime::nn::Tensor;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::fmt;
use std::time::Instant;

pub mod conv;
pub mod peak;
pub mod step;

/// The CPU-sized U-Net widths.
pub const CPU_WIDTHS: [usize; 5] = [16, 32, 64, 128, 128];
/// The paper's U-Net widths.
pub const PAPER_WIDTHS: [usize; 5] = [64, 128, 256, 512, 512];

/// Minimum and median of `reps` timed runs of `f` (after one warm-up), in seconds.
pub fn time_min_median(reps: usize, mut f: impl FnMut()) -> (f64, f64) {
    f();
    let mut t: Vec<f64> = (0..reps.max(1))
        .map(|_| {
            let s = Instant::now();
            f();
            s.elapsed().as_secs_f64()
        })
        .collect();
    t.sort_by(f64::total_cmp);
    (t[0], t[t.len() / 2])
}

/// Warm-up of the training and inference rows: at least this many seconds (and two calls).
/// Until the allocator's thresholds and the pool's buffers settle (tens of steps), a step
/// runs slower than it does for the rest of a bake.
pub const WARM_SECONDS: f64 = 1.0;
/// Timed seconds of the training and inference rows: at least this long (and `reps` calls),
/// as the PyTorch reference's `timeit` (2 warm-up calls, then at least 3 s and 5 calls).
pub const STEADY_SECONDS: f64 = 3.0;

/// Calls `f` for at least `secs` seconds and `calls` times.
pub fn run_for(secs: f64, calls: usize, mut f: impl FnMut()) {
    let start = Instant::now();
    let mut n = 0;
    while n < calls || start.elapsed().as_secs_f64() < secs {
        f();
        n += 1;
    }
}

/// Minimum and median seconds of `f` in the steady state: warm-up of [`WARM_SECONDS`] (when
/// `warm`), then timed calls for at least [`STEADY_SECONDS`] and `reps` calls.
pub fn time_steady(reps: usize, warm: bool, mut f: impl FnMut()) -> (f64, f64) {
    if warm {
        run_for(WARM_SECONDS, 2, &mut f);
    }
    let mut t = Vec::new();
    run_for(STEADY_SECONDS, reps.max(1), || {
        let s = Instant::now();
        f();
        t.push(s.elapsed().as_secs_f64());
    });
    t.sort_by(f64::total_cmp);
    (t[0], t[t.len() / 2])
}

/// Worker threads of the global pool, which the benchmarks (and the runtime) run on.
pub fn worker_threads() -> usize {
    rayon::current_num_threads()
}

/// GFLOP/s of a square 1024 sgemm with [`gemm_nn`] (best of `reps`).
pub fn sgemm_peak_gflops(reps: usize) -> f64 {
    let n = 1024;
    let mut r = ChaCha8Rng::seed_from_u64(1);
    let a: Vec<f32> = (0..n * n).map(|_| r.random_range(-1.0..1.0)).collect();
    let b: Vec<f32> = (0..n * n).map(|_| r.random_range(-1.0..1.0)).collect();
    let mut c = vec![0.0f32; n * n];
    let pa = PackedA::new(n, n, &a, n, 1);
    let rows: Vec<usize> = (0..n).map(|k| k * n).collect();
    let (t, _) = time_min_median(reps, || gemm_nn(&pa, &b, &rows, n, &mut c, n, false));
    2.0 * (n * n * n) as f64 / t * 1e-9
}

/// U-Net parameters of the benchmarks: 16 input channels, 3 outputs, transposed-conv decoder,
/// instance norm.
pub fn bench_params(widths: &[usize]) -> UNetParams {
    UNetParams {
        in_ch: 16,
        out_ch: 3,
        widths: widths.to_vec(),
        decoder: Decoder::TransposedConv,
        norm: Norm::Instance,
    }
}

pub(crate) fn random_tensor(r: &mut ChaCha8Rng, c: usize, h: usize, w: usize) -> Tensor {
    Tensor::from_vec(
        c,
        h,
        w,
        (0..c * h * w)
            .map(|_| r.random_range(-1.0f32..1.0))
            .collect(),
    )
    .expect("sized")
}

/// One measured configuration.
#[derive(Clone, Debug)]
pub struct BenchRow {
    /// "train" (U-Net forward, backward, Adam), "conv fwd+bwd" (its convolutions alone, see
    /// [`conv::bench_conv_layers`]), "step" (the baker's whole step, texture included),
    /// "step 2x2" (the same with 2x2 subsamples per pixel), "infer", or "encoder GEMMs" (see
    /// [`bench_encoder_gemm`]).
    pub kind: &'static str,
    /// U-Net widths.
    pub widths: Vec<usize>,
    /// Square image size.
    pub size: usize,
    /// Best time in ms.
    pub ms_min: f64,
    /// Median time in ms.
    pub ms_median: f64,
    /// Conv GFLOP per step (training: forward + input gradient + weight gradient = 3x forward).
    pub gflop: f64,
    /// Mean milliseconds per step of each phase ("step" rows only).
    pub phases: Option<PhaseSeconds>,
}

impl BenchRow {
    /// A row without phases from `(min, median)` seconds and the work's GFLOP.
    pub(crate) fn timed(
        kind: &'static str,
        widths: &[usize],
        size: usize,
        (t_min, t_med): (f64, f64),
        gflop: f64,
    ) -> Self {
        Self {
            kind,
            widths: widths.to_vec(),
            size,
            ms_min: t_min * 1e3,
            ms_median: t_med * 1e3,
            gflop,
            phases: None,
        }
    }

    /// Achieved GFLOP/s at the best time.
    pub fn gflops(&self) -> f64 {
        self.gflop / (self.ms_min * 1e-3)
    }
}

/// Training step (zero grads, forward, L1 loss, backward, Adam on every tensor) on a random
/// `16 x size x size` feature image; the texture update is not included.
pub fn bench_train(widths: &[usize], size: usize, reps: usize) -> BenchRow {
    let p = bench_params(widths);
    let mut net = UNetTrain::init(p.clone(), 1).expect("valid params");
    let mut opts: Vec<Adam> = net
        .weights
        .iter()
        .map(|w| Adam::new(w.len(), AdamConfig::default()))
        .collect();
    let mut r = ChaCha8Rng::seed_from_u64(2);
    let x = random_tensor(&mut r, 16, size, size);
    let target = random_tensor(&mut r, 3, size, size);
    let mut dy = Tensor::zeros(3, size, size);
    // On a pool worker, as `Trainer::step` runs.
    let (t_min, t_med) = time_steady(reps, true, || {
        with_workers_awake(|| {
            // Gradients start at zero: step_zero_grad clears them after each update.
            let (y, acts) = net.forward(&x).expect("shapes");
            dy.data.fill(0.0);
            l1_loss(&y, &target, None, 1.0, &mut dy);
            let dx = net.backward(&acts, &dy);
            std::hint::black_box(dx);
            for ((w, g), o) in net.weights.iter_mut().zip(&mut net.grads).zip(&mut opts) {
                o.step_zero_grad(w, g);
            }
        })
    });
    BenchRow::timed(
        "train",
        widths,
        size,
        (t_min, t_med),
        3.0 * p.flops(size, size) as f64 * 1e-9,
    )
}

/// Inference (runtime `UNet::forward`) on a random `16 x size x size` feature image.
pub fn bench_infer(widths: &[usize], size: usize, reps: usize) -> BenchRow {
    let p = bench_params(widths);
    let net = UNetTrain::init(p.clone(), 1).expect("valid params");
    let unet = UNet::from_map(p.clone(), &net.to_map()).expect("own weights");
    let mut r = ChaCha8Rng::seed_from_u64(3);
    let x = random_tensor(&mut r, 16, size, size);
    let (t_min, t_med) = time_steady(reps, true, || {
        std::hint::black_box(unet.forward(&x).expect("shapes"));
    });
    BenchRow::timed(
        "infer",
        widths,
        size,
        (t_min, t_med),
        p.flops(size, size) as f64 * 1e-9,
    )
}

/// The encoder convolutions alone, as GEMMs on their gathered inputs (gathers, bias, norms
/// and activations outside the timing): the rate of the convolution kernels themselves, which
/// the "infer" row's whole-network figure understates. FLOPs are the convolutions' own (the
/// layout's junk columns are computed but not counted).
pub fn bench_encoder_gemm(widths: &[usize], size: usize, reps: usize) -> BenchRow {
    let p = bench_params(widths);
    let mut r = ChaCha8Rng::seed_from_u64(4);
    let (mut h, mut w, mut flops) = (size, size, 0u64);
    let mut layers = Vec::with_capacity(p.depth());
    for i in 0..p.depth() {
        let g = p.encoder_geom(i);
        let l = ConvLayout::new(g, h, w).expect("encoder geometry");
        let buf = l.gather(&random_tensor(&mut r, g.c_in, h, w));
        let wts: Vec<f32> = (0..g.weight_len())
            .map(|_| r.random_range(-0.1..0.1))
            .collect();
        let a = l.pack_weights(&wts);
        flops += 2 * g.macs(h, w);
        (h, w) = (l.h_out, l.w_out);
        layers.push((l, a, buf));
    }
    let (t_min, t_med) = time_min_median(reps, || {
        for (l, a, buf) in &layers {
            pool::recycle(std::hint::black_box(l.gemm(a, buf)));
        }
    });
    BenchRow::timed(
        "encoder GEMMs",
        widths,
        size,
        (t_min, t_med),
        flops as f64 * 1e-9,
    )
}

/// A full benchmark run.
#[derive(Clone, Debug)]
pub struct BenchReport {
    /// sgemm 1024 GFLOP/s measured in this run.
    pub peak_gflops: f64,
    /// The FMA units' GFLOP/s measured in this run ([`peak::fma_peak_gflops`]).
    pub fma_peak_gflops: f64,
    /// Kernel instruction set used (see `dnr_runtime::nn::gemm::set_simd_cap` to emulate an
    /// AVX2-only CPU).
    pub simd: SimdLevel,
    /// Worker threads.
    pub threads: usize,
    /// Measurements.
    pub rows: Vec<BenchRow>,
    /// The CPU-sized U-Net's convolutions layer by layer, at each training crop size.
    pub conv_layers: Vec<(usize, Vec<conv::LayerRow>)>,
}

/// Runs the standard table: training at 128 and 256, inference at 256 and 512, for the
/// CPU-sized and the paper U-Net. `reps` timed repetitions each (min reported). Both peaks are
/// measured before and after the table and the higher kept: on a shared machine a neighbour's
/// burst can halve one reading (seen on Zen 3: an FMA peak of 90.8 GFLOP/s against 171-175).
pub fn run_standard(reps: usize) -> BenchReport {
    let peaks = || {
        (
            sgemm_peak_gflops(reps.max(3)),
            peak::fma_peak_gflops(reps.max(3)),
        )
    };
    let before = peaks();
    let mut rows = Vec::new();
    for widths in [&CPU_WIDTHS[..], &PAPER_WIDTHS[..]] {
        for size in [128, 256] {
            rows.push(bench_train(widths, size, reps));
            rows.push(conv::bench_conv_layers(widths, size, reps));
            // The baker's whole step: texture sampling, SH, U-Net, losses, texture update.
            let w32: Vec<u32> = widths.iter().map(|&w| w as u32).collect();
            // And with the default 2x2 subsamples, at the size the baker trains the CPU net.
            let factors: &[u32] = if widths == &CPU_WIDTHS[..] && size == 256 {
                &[1, 2]
            } else {
                &[1]
            };
            for &s in factors {
                let (ms_min, ms_median, phases) = step::bench_trainer_step(&w32, size, s, reps);
                rows.push(BenchRow {
                    kind: if s == 1 { "step" } else { "step 2x2" },
                    widths: widths.to_vec(),
                    size,
                    ms_min,
                    ms_median,
                    gflop: 3.0 * bench_params(widths).flops(size, size) as f64 * 1e-9,
                    phases: Some(phases),
                });
            }
        }
        for size in [256, 512] {
            rows.push(bench_infer(widths, size, reps));
        }
        rows.push(bench_encoder_gemm(widths, 512, reps));
    }
    let conv_layers = [128, 256]
        .into_iter()
        .map(|size| (size, conv::bench_conv_breakdown(&CPU_WIDTHS, size, reps)))
        .collect();
    let after = peaks();
    BenchReport {
        peak_gflops: before.0.max(after.0),
        fma_peak_gflops: before.1.max(after.1),
        simd: simd_level(),
        threads: worker_threads(),
        rows,
        conv_layers,
    }
}

impl fmt::Display for BenchReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "sgemm 1024 peak (same GEMM): {:.1} GFLOP/s; FMA peak {:.1} GFLOP/s; kernels {:?}; {} threads",
            self.peak_gflops, self.fma_peak_gflops, self.simd, self.threads
        )?;
        writeln!(
            f,
            "| kind | widths | size | ms (min) | ms (median) | conv GFLOP | GFLOP/s | of sgemm peak | of FMA peak |"
        )?;
        writeln!(
            f,
            "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"
        )?;
        for r in &self.rows {
            writeln!(
                f,
                "| {} | {:?} | {} | {:.1} | {:.1} | {:.3} | {:.1} | {:.0}% | {:.0}% |",
                r.kind,
                r.widths,
                r.size,
                r.ms_min,
                r.ms_median,
                r.gflop,
                r.gflops(),
                100.0 * r.gflops() / self.peak_gflops,
                100.0 * r.gflops() / self.fma_peak_gflops
            )?;
        }
        writeln!(
            f,
            "\nWhole step by phase (mean ms per timed step): | widths | size | features | forward | backward | feature grads | updates |"
        )?;
        writeln!(f, "| --- | ---: | ---: | ---: | ---: | ---: | ---: |")?;
        for r in &self.rows {
            if let Some(p) = &r.phases {
                writeln!(
                    f,
                    "| {:?} | {} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} |",
                    r.widths, r.size, p.features, p.forward, p.backward, p.feature_grads, p.updates
                )?;
            }
        }
        for (size, layers) in &self.conv_layers {
            writeln!(
                f,
                "\nConvolutions of {CPU_WIDTHS:?} at {size} by layer (forward + backward, min ms): | layer | GEMM M x K x N | ms | GFLOP | GFLOP/s | of sgemm peak |"
            )?;
            writeln!(f, "| --- | --- | ---: | ---: | ---: | ---: |")?;
            for l in layers {
                let gf = l.gflop / l.min_s;
                writeln!(
                    f,
                    "| {} | {} | {:.3} | {:.3} | {:.1} | {:.0}% |",
                    l.layer,
                    l.shape,
                    l.min_s * 1e3,
                    l.gflop,
                    gf,
                    100.0 * gf / self.peak_gflops
                )?;
            }
        }
        Ok(())
    }
}
