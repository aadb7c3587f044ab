//! Backward of texture sampling and SH modulation against f64 central differences, the
//! serial oracle, and determinism across thread counts.
//!
//! Both operations are linear in the parameter being differentiated, so a central
//! difference with a large step (h = 0.5) has no truncation error; what remains is the f32
//! rounding of the forward (about 1e-7 relative per pixel, summed over a few hundred pixels
//! in f64), hence the tolerance `|analytic - fd| <= 1e-4 * (1 + |fd|)`.

// Index loops mirror the math (pixel i, channel c) and compare several arrays at once.
#![allow(clippy::needless_range_loop)]

use dnr_bake::kernels::adam::{AdamConfig, SparseAdam};
use dnr_bake::kernels::sample::{
    sample_backward, sample_backward_adam, sample_backward_serial, sample_forward,
    sample_forward_taps,
};
use dnr_bake::kernels::sh::{modulate_backward, modulate_forward};
use dnr_runtime::gbuffer::GBuffer;
use dnr_runtime::nn::gemm::set_force_scalar;
use dnr_runtime::texture::{Level, Pyramid, Wrap};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const H: f32 = 0.5;
const TOL: f64 = 1e-4;

fn close(a: f64, fd: f64) -> bool {
    (a - fd).abs() <= TOL * (1.0 + fd.abs())
}

fn pyramid(
    rng: &mut ChaCha8Rng,
    c: usize,
    sizes: &[(usize, usize)],
    ws: Wrap,
    wt: Wrap,
) -> Pyramid {
    let levels = sizes
        .iter()
        .map(|&(w, h)| Level {
            width: w,
            height: h,
            data: (0..w * h * c)
                .map(|_| rng.random_range(-1.0..1.0))
                .collect(),
        })
        .collect();
    Pyramid::new(c, levels, ws, wt).unwrap()
}

/// A G-buffer with random uv (well outside [0, 1] too), ~80% coverage and a few non-finite uv.
fn gbuffer(rng: &mut ChaCha8Rng, w: usize, h: usize) -> GBuffer {
    let mut g = GBuffer::new(w, h);
    for i in 0..w * h {
        g.uv[i] = [rng.random_range(-1.5..2.5), rng.random_range(-1.5..2.5)];
        g.coverage[i] = if rng.random_range(0.0..1.0) < 0.8 {
            1.0
        } else {
            0.0
        };
        let d = [
            rng.random_range(-1.0..1.0f32),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        ];
        let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt().max(1e-3);
        g.view_dir[i] = d.map(|x| x / n);
    }
    g.uv[5] = [f32::NAN, 0.3];
    g.coverage[5] = 1.0;
    g.uv[6] = [1e6, -1e6];
    g.coverage[6] = 1.0;
    g
}

fn dot(a: &[f32], b: &[f32]) -> f64 {
    a.iter().zip(b).map(|(&x, &y)| x as f64 * y as f64).sum()
}

fn random_vec(rng: &mut ChaCha8Rng, n: usize) -> Vec<f32> {
    (0..n).map(|_| rng.random_range(-1.0..1.0)).collect()
}

/// L(T) = <G, F(T)> in f64.
fn loss_sample(pyr: &Pyramid, g: &GBuffer, up: &[f32]) -> f64 {
    let mut out = vec![0.0; up.len()];
    sample_forward(pyr, g, &mut out).unwrap();
    dot(up, &out)
}

#[test]
fn sample_backward_matches_central_differences_for_all_wrap_modes() {
    let mut rng = ChaCha8Rng::seed_from_u64(10);
    let wraps = [Wrap::Repeat, Wrap::ClampToEdge, Wrap::MirroredRepeat];
    let (w, h, c) = (13, 11, 3);
    for ws in wraps {
        for wt in wraps {
            let pyr = pyramid(&mut rng, c, &[(7, 5), (4, 3)], ws, wt);
            let g = gbuffer(&mut rng, w, h);
            let up = random_vec(&mut rng, c * w * h);
            // `+=` semantics: start from a non-zero gradient.
            let mut grads: Vec<Vec<f32>> = pyr
                .levels
                .iter()
                .map(|l| vec![0.25; l.data.len()])
                .collect();
            let touched = sample_backward(&pyr, &g, &up, &mut grads).unwrap();
            let mut serial: Vec<Vec<f32>> = pyr
                .levels
                .iter()
                .map(|l| vec![0.25; l.data.len()])
                .collect();
            let touched_serial = sample_backward_serial(&pyr, &g, &up, &mut serial).unwrap();
            assert_eq!(touched, touched_serial);
            for k in 0..pyr.levels.len() {
                assert!(
                    touched[k].windows(2).all(|p| p[0] < p[1]),
                    "touched list is ascending and unique"
                );
                for i in 0..pyr.levels[k].data.len() {
                    let mut p = pyr.clone();
                    p.levels[k].data[i] += H;
                    let lp = loss_sample(&p, &g, &up);
                    p.levels[k].data[i] -= 2.0 * H;
                    let lm = loss_sample(&p, &g, &up);
                    let fd = (lp - lm) / (2.0 * H as f64);
                    let a = (grads[k][i] - 0.25) as f64;
                    assert!(
                        close(a, fd),
                        "{ws:?}/{wt:?} level {k} value {i}: analytic {a} vs fd {fd}"
                    );
                    assert_eq!(
                        grads[k][i].to_bits(),
                        serial[k][i].to_bits(),
                        "parallel and serial add in the same order"
                    );
                    let texel = (i / c) as u32;
                    let is_touched = touched[k].binary_search(&texel).is_ok();
                    if !is_touched {
                        assert_eq!(grads[k][i], 0.25, "untouched texel got a gradient");
                    }
                    if fd.abs() > 1e-3 {
                        assert!(
                            is_touched,
                            "texel {texel} of level {k} has a gradient but is not marked"
                        );
                    }
                }
            }
        }
    }
}

#[test]
fn sh_backward_matches_central_differences() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let (w, h, c) = (13, 11, 17);
    for (first, degree) in [(2usize, 2u32), (0, 0), (1, 3), (16, 0)] {
        let g = gbuffer(&mut rng, w, h);
        let n = w * h;
        let f = random_vec(&mut rng, c * n);
        let up = random_vec(&mut rng, c * n);
        let loss = |f: &[f32]| {
            let mut x = f.to_vec();
            modulate_forward(&mut x, &g.view_dir, &g.coverage, first, degree).unwrap();
            dot(&up, &x)
        };
        let mut d = up.clone();
        modulate_backward(&mut d, &g.view_dir, &g.coverage, first, degree).unwrap();
        for i in 0..c * n {
            let mut fp = f.clone();
            fp[i] += H;
            let lp = loss(&fp);
            fp[i] -= 2.0 * H;
            let lm = loss(&fp);
            let fd = (lp - lm) / (2.0 * H as f64);
            assert!(
                close(d[i] as f64, fd),
                "first {first} degree {degree} value {i}: {} vs {fd}",
                d[i]
            );
        }
    }
}

#[test]
fn sample_then_sh_chain_matches_central_differences() {
    let mut rng = ChaCha8Rng::seed_from_u64(12);
    let (w, h, c, first, degree) = (13, 11, 5, 1usize, 1u32);
    let pyr = pyramid(
        &mut rng,
        c,
        &[(7, 5), (4, 3)],
        Wrap::Repeat,
        Wrap::MirroredRepeat,
    );
    let g = gbuffer(&mut rng, w, h);
    let up = random_vec(&mut rng, c * w * h);
    let loss = |p: &Pyramid| {
        let mut x = vec![0.0; up.len()];
        sample_forward(p, &g, &mut x).unwrap();
        modulate_forward(&mut x, &g.view_dir, &g.coverage, first, degree).unwrap();
        dot(&up, &x)
    };
    let mut dx = up.clone();
    modulate_backward(&mut dx, &g.view_dir, &g.coverage, first, degree).unwrap();
    let mut grads: Vec<Vec<f32>> = pyr.levels.iter().map(|l| vec![0.0; l.data.len()]).collect();
    sample_backward(&pyr, &g, &dx, &mut grads).unwrap();
    for k in 0..2 {
        for i in 0..pyr.levels[k].data.len() {
            let mut p = pyr.clone();
            p.levels[k].data[i] += H;
            let lp = loss(&p);
            p.levels[k].data[i] -= 2.0 * H;
            let fd = (lp - loss(&p)) / (2.0 * H as f64);
            assert!(
                close(grads[k][i] as f64, fd),
                "level {k} value {i}: {} vs {fd}",
                grads[k][i]
            );
        }
    }
}

#[test]
fn sample_backward_is_bit_identical_across_runs_and_thread_counts() {
    let mut rng = ChaCha8Rng::seed_from_u64(13);
    // Level 0 spans several texel ranges (96 x 64 = 6144 texels), the ~2300 covered pixels
    // two pixel chunks; a dense, small texture
    // region makes many pixels share texels.
    let pyr = pyramid(
        &mut rng,
        16,
        &[(96, 64), (48, 32), (24, 16)],
        Wrap::Repeat,
        Wrap::ClampToEdge,
    );
    let (w, h) = (61, 47);
    let mut g = gbuffer(&mut rng, w, h);
    for i in 0..w * h {
        if i.is_multiple_of(3) {
            g.uv[i] = [
                0.5 + 0.01 * rng.random_range(-1.0..1.0f32),
                0.5 + 0.01 * rng.random_range(-1.0..1.0f32),
            ];
        }
    }
    let up = random_vec(&mut rng, 16 * w * h);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut grads: Vec<Vec<f32>> =
                pyr.levels.iter().map(|l| vec![0.0; l.data.len()]).collect();
            let t = sample_backward(&pyr, &g, &up, &mut grads).unwrap();
            (
                grads
                    .concat()
                    .iter()
                    .map(|x| x.to_bits())
                    .collect::<Vec<u32>>(),
                t,
            )
        })
    };
    let reference = run(1);
    assert!(reference.1[0].len() > 100);
    let mut serial: Vec<Vec<f32>> = pyr.levels.iter().map(|l| vec![0.0; l.data.len()]).collect();
    let t = sample_backward_serial(&pyr, &g, &up, &mut serial).unwrap();
    let serial_bits: Vec<u32> = serial.concat().iter().map(|x| x.to_bits()).collect();
    assert!(
        serial_bits == reference.0 && t == reference.1,
        "parallel equals the serial oracle"
    );
    for threads in [1, 2, 3, 4] {
        assert_eq!(run(threads), reference, "{threads} threads");
    }
}

#[test]
fn fused_scatter_and_adam_equal_the_separate_passes_bit_for_bit() {
    // Training's pair (forward keeping the taps; scatter fused with lazy Adam) against the
    // plain sampler, the parallel scatter into zeroed gradients and SparseAdam::step on the
    // touched rows: two steps, on the SIMD path and on the forced baseline path.
    let mut rng = ChaCha8Rng::seed_from_u64(17);
    let pyr0 = pyramid(
        &mut rng,
        16,
        &[(300, 200), (150, 100), (75, 50)],
        Wrap::Repeat,
        Wrap::MirroredRepeat,
    );
    let (w, h) = (83, 59);
    let views: Vec<GBuffer> = (0..2).map(|_| gbuffer(&mut rng, w, h)).collect();
    let ups: Vec<Vec<f32>> = (0..2).map(|_| random_vec(&mut rng, 16 * w * h)).collect();
    let cfg = AdamConfig {
        lr: 0.01,
        ..AdamConfig::default()
    };
    let decay = [0.0, 1e-3, 4e-3];
    let adams = |p: &Pyramid| -> Vec<SparseAdam> {
        p.levels
            .iter()
            .map(|l| SparseAdam::new(l.width * l.height, 16, cfg))
            .collect()
    };
    let fused = || {
        let (mut p, mut opts) = (pyr0.clone(), adams(&pyr0));
        for (g, up) in views.iter().zip(&ups) {
            let mut out = vec![0.0; 16 * w * h];
            let taps = sample_forward_taps(&p, g, &mut out).unwrap();
            let mut plain = vec![0.0; 16 * w * h];
            sample_forward(&p, g, &mut plain).unwrap();
            assert_eq!(out, plain, "the forward that keeps its taps is the sampler");
            sample_backward_adam(&taps, &mut p, up, &mut opts, &decay).unwrap();
        }
        p
    };
    let (mut p, mut opts) = (pyr0.clone(), adams(&pyr0));
    for (g, up) in views.iter().zip(&ups) {
        let mut grads: Vec<Vec<f32>> = p.levels.iter().map(|l| vec![0.0; l.data.len()]).collect();
        let touched = sample_backward(&p, g, up, &mut grads).unwrap();
        for (k, l) in p.levels.iter_mut().enumerate() {
            opts[k].step(&mut l.data, &mut grads[k], &touched[k], decay[k]);
        }
    }
    let bits = |p: &Pyramid| -> Vec<u32> {
        p.levels
            .iter()
            .flat_map(|l| l.data.iter().map(|x| x.to_bits()))
            .collect()
    };
    assert_ne!(bits(&p), bits(&pyr0), "the steps changed the texture");
    assert_eq!(bits(&fused()), bits(&p), "fused, SIMD path");
    set_force_scalar(true);
    let scalar = fused();
    set_force_scalar(false);
    assert_eq!(bits(&scalar), bits(&p), "fused, baseline path");
}

#[test]
fn forward_taps_equal_the_sampler_inside_at_edges_and_outside() {
    // The training forward computes the taps of runs of pixels side by side when all of them
    // fall inside a level and through the runtime's `taps` otherwise: the features and the
    // scatter built on those taps must be the sampler's and the serial oracle's, bit for bit,
    // for uv well inside [0, 1] (vector runs), next to the edges (runs that fall back) and
    // outside, in every wrap mode, on the SIMD and the baseline path.
    let mut rng = ChaCha8Rng::seed_from_u64(29);
    let (w, h) = (67, 45);
    for (ws, wt) in [
        (Wrap::Repeat, Wrap::Repeat),
        (Wrap::ClampToEdge, Wrap::MirroredRepeat),
        (Wrap::MirroredRepeat, Wrap::ClampToEdge),
    ] {
        let pyr = pyramid(&mut rng, 16, &[(53, 37), (27, 19), (3, 2), (1, 1)], ws, wt);
        let mut g = gbuffer(&mut rng, w, h);
        for i in 0..w * h {
            let (x, y) = ((i % w) as f32 / w as f32, (i / w) as f32 / h as f32);
            g.uv[i] = match (i / w) % 3 {
                // Smooth rows inside, as a rasterised chart gives.
                0 | 1 => [0.05 + 0.9 * x, 0.05 + 0.9 * y],
                // Rows that run up to and across the edges.
                _ => [x * 1.04 - 0.02, 1.01 - y * 1.02],
            };
        }
        let up = random_vec(&mut rng, 16 * w * h);
        for scalar in [false, true] {
            set_force_scalar(scalar);
            let mut out = vec![0.0; 16 * w * h];
            let taps = sample_forward_taps(&pyr, &g, &mut out).unwrap();
            let mut plain = vec![0.0; 16 * w * h];
            sample_forward(&pyr, &g, &mut plain).unwrap();
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<u32>>();
            assert_eq!(bits(&out), bits(&plain), "{ws:?}/{wt:?}, scalar {scalar}");
            // The kept taps drive the fused scatter; one Adam step from zero moments moves
            // each touched value by about lr, so compare against the separate passes.
            let cfg = AdamConfig::default();
            let mut fused = pyr.clone();
            let mut opts: Vec<SparseAdam> = pyr
                .levels
                .iter()
                .map(|l| SparseAdam::new(l.width * l.height, 16, cfg))
                .collect();
            let decay = vec![0.0; pyr.levels.len()];
            sample_backward_adam(&taps, &mut fused, &up, &mut opts, &decay).unwrap();
            let mut sep = pyr.clone();
            let mut grads: Vec<Vec<f32>> =
                pyr.levels.iter().map(|l| vec![0.0; l.data.len()]).collect();
            let touched = sample_backward_serial(&pyr, &g, &up, &mut grads).unwrap();
            for (k, l) in sep.levels.iter_mut().enumerate() {
                let mut o = SparseAdam::new(l.width * l.height, 16, cfg);
                o.step(&mut l.data, &mut grads[k], &touched[k], 0.0);
            }
            for (a, b) in fused.levels.iter().zip(&sep.levels) {
                assert_eq!(bits(&a.data), bits(&b.data), "{ws:?}/{wt:?} scatter");
            }
        }
        set_force_scalar(false);
    }
}

#[test]
fn sample_backward_rejects_mismatched_shapes() {
    let mut rng = ChaCha8Rng::seed_from_u64(14);
    let pyr = pyramid(&mut rng, 3, &[(7, 5), (4, 3)], Wrap::Repeat, Wrap::Repeat);
    let g = gbuffer(&mut rng, 13, 11);
    let up = vec![0.0; 3 * 13 * 11];
    let ok = || -> Vec<Vec<f32>> { pyr.levels.iter().map(|l| vec![0.0; l.data.len()]).collect() };
    let mut one_level = vec![vec![0.0; 7 * 5 * 3]];
    assert!(sample_backward(&pyr, &g, &up, &mut one_level).is_err());
    let mut short = ok();
    short[1].pop();
    assert!(sample_backward(&pyr, &g, &up, &mut short).is_err());
    assert!(sample_backward(&pyr, &g, &up[1..], &mut ok()).is_err());
    assert!(sample_backward_serial(&pyr, &g, &up[1..], &mut ok()).is_err());
    assert!(modulate_backward(&mut [0.0; 10], &g.view_dir, &g.coverage, 0, 0).is_err());
}

/// Serial scatter vs the parallel counting-sort gather on a training-sized problem
/// (256 x 256 view, ~40% covered, 16 channels, levels 512..64). Prints timings:
/// `cargo test --release -p dnr-bake --test grad_sample_sh -- --ignored --nocapture`.
#[test]
#[ignore = "timing only"]
fn sample_backward_timing() {
    let mut rng = ChaCha8Rng::seed_from_u64(15);
    let pyr = pyramid(
        &mut rng,
        16,
        &[(512, 512), (256, 256), (128, 128), (64, 64)],
        Wrap::Repeat,
        Wrap::Repeat,
    );
    let (w, h) = (256, 256);
    let mut g = GBuffer::new(w, h);
    for y in 0..h {
        for x in 0..w {
            let (dx, dy) = (x as f32 - 128.0, y as f32 - 128.0);
            if dx * dx + dy * dy < 90.0 * 90.0 {
                let i = y * w + x;
                g.coverage[i] = 1.0;
                // A smooth, locally coherent uv map, like a rasterised mesh.
                g.uv[i] = [
                    0.3 + x as f32 / 600.0 + 0.02 * (y as f32 / 9.0).sin(),
                    0.2 + y as f32 / 500.0,
                ];
            }
        }
    }
    let up = random_vec(&mut rng, 16 * w * h);
    let mut grads: Vec<Vec<f32>> = pyr.levels.iter().map(|l| vec![0.0; l.data.len()]).collect();
    let n = 20;
    for (name, f) in [
        (
            "parallel",
            sample_backward as fn(&Pyramid, &GBuffer, &[f32], &mut [Vec<f32>]) -> _,
        ),
        ("serial", sample_backward_serial),
    ] {
        f(&pyr, &g, &up, &mut grads).unwrap();
        let t = std::time::Instant::now();
        for _ in 0..n {
            f(&pyr, &g, &up, &mut grads).unwrap();
        }
        println!(
            "{name}: {:.2} ms ({} threads)",
            t.elapsed().as_secs_f64() * 1e3 / n as f64,
            rayon::current_num_threads()
        );
    }
    let mut out = vec![0.0; up.len()];
    let t = std::time::Instant::now();
    for _ in 0..n {
        sample_forward(&pyr, &g, &mut out).unwrap();
    }
    println!(
        "forward: {:.2} ms",
        t.elapsed().as_secs_f64() * 1e3 / n as f64
    );
}
