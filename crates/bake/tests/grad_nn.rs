//! Every backward kernel against f64 central differences of an independent f64 reference
//! forward, with a random upstream gradient (loss = sum r * y), on small odd shapes; the whole
//! U-Net + L1 loss graph; Adam against a hand-written f64 update; determinism of training.
//!
//! Central differences use eps = 1e-5 in f64 (truncation ~1e-10, rounding ~1e-11 relative), so
//! the comparison measures the f32 kernels: tolerance `TOL * (|fd| + rms(fd))` per element,
//! TOL = 1e-4 for single layers and 2e-3 for the whole U-Net (f32 activations through ~10
//! layers and instance norms on planes of 4 pixels).

use dnr_bake::kernels::activation::{leaky_relu_backward, tanh_backward};
use dnr_bake::kernels::adam::{Adam, AdamConfig, SparseAdam};
use dnr_bake::kernels::concat::concat_backward;
use dnr_bake::kernels::conv::{conv_backward, conv_forward, SMALL_N};
use dnr_bake::kernels::conv_transpose::{conv_transpose_backward, conv_transpose_forward};
use dnr_bake::kernels::dense::{dense_backward, mlp_backward, mlp_forward};
use dnr_bake::kernels::loss::{colour_l1_loss, l1_loss, texture_l2_reg};
use dnr_bake::kernels::norm::{instance_norm_backward, lrelu_instance_norm_backward};
use dnr_bake::kernels::unet::UNetTrain;
use dnr_bake::kernels::upsample::upsample_nearest2_backward;
use dnr_runtime::network::unet::{Decoder, Norm, UNetParams};
use dnr_runtime::nn::activation::{leaky_relu, tanh, Act};
use dnr_runtime::nn::conv::{ConvGeom, ConvLayout};
use dnr_runtime::nn::norm::instance_norm;
use dnr_runtime::nn::upsample::upsample_nearest2;
use dnr_runtime::nn::Tensor;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const EPS: f64 = 1e-5;
const TOL: f64 = 1e-4;

fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

fn randv(r: &mut ChaCha8Rng, n: usize) -> Vec<f32> {
    (0..n).map(|_| r.random_range(-1.0f32..1.0)).collect()
}

fn randt(r: &mut ChaCha8Rng, c: usize, h: usize, w: usize) -> Tensor {
    Tensor::from_vec(c, h, w, randv(r, c * h * w)).unwrap()
}

fn f64s(v: &[f32]) -> Vec<f64> {
    v.iter().map(|&x| x as f64).collect()
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Central differences of `f` at `x0`, every coordinate.
fn fd(x0: &[f32], f: &dyn Fn(&[f64]) -> f64) -> Vec<f64> {
    let mut x = f64s(x0);
    (0..x.len())
        .map(|i| {
            let v = x[i];
            x[i] = v + EPS;
            let fp = f(&x);
            x[i] = v - EPS;
            let fm = f(&x);
            x[i] = v;
            (fp - fm) / (2.0 * EPS)
        })
        .collect()
}

fn assert_grad(got: &[f32], want: &[f64], tol: f64, what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    let rms = (want.iter().map(|v| v * v).sum::<f64>() / want.len().max(1) as f64).sqrt();
    assert!(
        rms > 0.0 || want.is_empty(),
        "{what}: gradient identically zero, test is vacuous"
    );
    for (i, (&g, &w)) in got.iter().zip(want).enumerate() {
        let t = tol * (w.abs() + rms);
        assert!(
            (g as f64 - w).abs() <= t,
            "{what}[{i}]: analytic {g}, numeric {w} (tol {t:e})"
        );
    }
}

// ---------------------------------------------------------------- f64 reference forwards

#[allow(clippy::too_many_arguments)]
fn conv64(
    x: &[f64],
    c: usize,
    h: usize,
    w: usize,
    wt: &[f64],
    b: &[f64],
    co: usize,
    k: usize,
    s: usize,
    p: usize,
) -> (usize, usize, Vec<f64>) {
    let ho = (h + 2 * p - k) / s + 1;
    let wo = (w + 2 * p - k) / s + 1;
    let mut out = vec![0.0; co * ho * wo];
    for o in 0..co {
        for oy in 0..ho {
            for ox in 0..wo {
                let mut acc = b[o];
                for ci in 0..c {
                    for ky in 0..k {
                        for kx in 0..k {
                            let iy = (oy * s + ky) as isize - p as isize;
                            let ix = (ox * s + kx) as isize - p as isize;
                            if iy >= 0 && ix >= 0 && (iy as usize) < h && (ix as usize) < w {
                                acc += wt[((o * c + ci) * k + ky) * k + kx]
                                    * x[(ci * h + iy as usize) * w + ix as usize];
                            }
                        }
                    }
                }
                out[(o * ho + oy) * wo + ox] = acc;
            }
        }
    }
    (ho, wo, out)
}

fn tconv64(x: &[f64], c: usize, h: usize, w: usize, wt: &[f64], b: &[f64], co: usize) -> Vec<f64> {
    let (ho, wo) = (2 * h, 2 * w);
    let mut out = vec![0.0; co * ho * wo];
    for o in 0..co {
        out[o * ho * wo..(o + 1) * ho * wo].fill(b[o]);
    }
    for ci in 0..c {
        for iy in 0..h {
            for ix in 0..w {
                for o in 0..co {
                    for ky in 0..4 {
                        for kx in 0..4 {
                            let oy = (2 * iy + ky) as isize - 1;
                            let ox = (2 * ix + kx) as isize - 1;
                            if oy >= 0 && ox >= 0 && (oy as usize) < ho && (ox as usize) < wo {
                                out[(o * ho + oy as usize) * wo + ox as usize] += x
                                    [(ci * h + iy) * w + ix]
                                    * wt[((ci * co + o) * 4 + ky) * 4 + kx];
                            }
                        }
                    }
                }
            }
        }
    }
    out
}

fn upsample64(x: &[f64], c: usize, h: usize, w: usize) -> Vec<f64> {
    let mut out = vec![0.0; c * 4 * h * w];
    for ci in 0..c {
        for y in 0..2 * h {
            for xx in 0..2 * w {
                out[(ci * 2 * h + y) * 2 * w + xx] = x[(ci * h + y / 2) * w + xx / 2];
            }
        }
    }
    out
}

fn norm64(x: &mut [f64], c: usize) {
    let n = x.len() / c;
    for p in x.chunks_mut(n) {
        let mean = p.iter().sum::<f64>() / n as f64;
        let var = p.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n as f64;
        let r = 1.0 / (var + 1e-5).sqrt();
        p.iter_mut().for_each(|v| *v = (*v - mean) * r);
    }
}

fn lrelu64(x: &mut [f64]) {
    x.iter_mut().for_each(|v| {
        if *v < 0.0 {
            *v *= 0.2
        }
    });
}

// ---------------------------------------------------------------- layers

#[allow(clippy::too_many_arguments)]
fn check_conv(seed: u64, ci: usize, co: usize, h: usize, w: usize, k: usize, s: usize, p: usize) {
    let mut r = rng(seed);
    let g = ConvGeom {
        c_in: ci,
        c_out: co,
        k,
        stride: s,
        pad: p,
    };
    let x = randt(&mut r, ci, h, w);
    let wt = randv(&mut r, g.weight_len());
    let b = randv(&mut r, co);
    let (y, cache) = conv_forward(&x, &wt, &b, g).unwrap();
    let up = randv(&mut r, y.data.len());
    let dy = Tensor::from_vec(y.c, y.h, y.w, up.clone()).unwrap();
    // Accumulation: start from non-zero gradients and subtract them afterwards.
    let (mut dw, mut db) = (vec![0.5f32; wt.len()], vec![0.5f32; co]);
    let mut dx = Tensor::from_vec(ci, h, w, vec![0.5; ci * h * w]).unwrap();
    conv_backward(&cache, &wt, &dy, &mut dw, &mut db, Some(&mut dx));
    let sub = |v: &[f32]| v.iter().map(|a| a - 0.5).collect::<Vec<f32>>();
    let r64 = f64s(&up);
    let (x64, w64, b64) = (f64s(&x.data), f64s(&wt), f64s(&b));
    let what = format!("conv {ci}->{co} {h}x{w} k{k} s{s} p{p}");
    assert_grad(
        &sub(&dx.data),
        &fd(&x.data, &|xx| {
            dot(&r64, &conv64(xx, ci, h, w, &w64, &b64, co, k, s, p).2)
        }),
        TOL,
        &format!("{what} dx"),
    );
    assert_grad(
        &sub(&dw),
        &fd(&wt, &|ww| {
            dot(&r64, &conv64(&x64, ci, h, w, ww, &b64, co, k, s, p).2)
        }),
        TOL,
        &format!("{what} dw"),
    );
    assert_grad(
        &sub(&db),
        &fd(&b, &|bb| {
            dot(&r64, &conv64(&x64, ci, h, w, &w64, bb, co, k, s, p).2)
        }),
        TOL,
        &format!("{what} db"),
    );
}

#[test]
fn conv_backward_matches_fd() {
    check_conv(1, 3, 5, 7, 9, 4, 2, 1);
    check_conv(2, 2, 3, 6, 4, 4, 2, 1);
    check_conv(3, 1, 1, 2, 2, 4, 2, 1);
    check_conv(4, 3, 4, 5, 7, 3, 1, 1);
    check_conv(5, 2, 7, 1, 1, 3, 1, 1);
    check_conv(6, 3, 2, 9, 7, 3, 2, 0);
    check_conv(7, 2, 3, 11, 8, 5, 3, 2);
    check_conv(8, 4, 3, 5, 6, 1, 1, 0);
    check_conv(9, 2, 2, 5, 5, 4, 2, 2);
    // More than SMALL_N GEMM columns: the shifted-row products instead of the im2col matrix,
    // for each layout kind (space-to-depth, padded, explicit im2col).
    for (seed, (h, w, k, s, p)) in [(36, 35, 4, 2, 1), (17, 17, 3, 1, 1), (50, 49, 5, 3, 2)]
        .into_iter()
        .enumerate()
    {
        let l = ConvLayout::new(
            ConvGeom {
                c_in: 1,
                c_out: 2,
                k,
                stride: s,
                pad: p,
            },
            h,
            w,
        )
        .unwrap();
        assert!(l.n > SMALL_N, "{h}x{w} k{k}: {} columns", l.n);
        check_conv(20 + seed as u64, 1, 2, h, w, k, s, p);
    }
}

#[test]
fn conv_transpose_backward_matches_fd() {
    // The last shape's adjoint conv has more than SMALL_N GEMM columns (shifted-row path).
    for (seed, &(ci, co, h, w)) in [
        (1, 1, 1, 1),
        (3, 5, 2, 3),
        (2, 7, 5, 3),
        (13, 2, 3, 2),
        (1, 2, 17, 16),
    ]
    .iter()
    .enumerate()
    {
        let mut r = rng(10 + seed as u64);
        let x = randt(&mut r, ci, h, w);
        let wt = randv(&mut r, ci * co * 16);
        let b = randv(&mut r, co);
        let (y, cache) = conv_transpose_forward(&x, &wt, &b, co).unwrap();
        let up = randv(&mut r, y.data.len());
        let dy = Tensor::from_vec(y.c, y.h, y.w, up.clone()).unwrap();
        let (mut dw, mut db) = (vec![0.0f32; wt.len()], vec![0.0f32; co]);
        let mut dx = Tensor::zeros(ci, h, w);
        conv_transpose_backward(&cache, &wt, &dy, &mut dw, &mut db, Some(&mut dx));
        let r64 = f64s(&up);
        let (x64, w64, b64) = (f64s(&x.data), f64s(&wt), f64s(&b));
        let what = format!("tconv {ci}->{co} {h}x{w}");
        assert_grad(
            &dx.data,
            &fd(&x.data, &|xx| {
                dot(&r64, &tconv64(xx, ci, h, w, &w64, &b64, co))
            }),
            TOL,
            &format!("{what} dx"),
        );
        assert_grad(
            &dw,
            &fd(&wt, &|ww| dot(&r64, &tconv64(&x64, ci, h, w, ww, &b64, co))),
            TOL,
            &format!("{what} dw"),
        );
        assert_grad(
            &db,
            &fd(&b, &|bb| dot(&r64, &tconv64(&x64, ci, h, w, &w64, bb, co))),
            TOL,
            &format!("{what} db"),
        );
    }
}

#[test]
fn upsample_backward_matches_fd() {
    let mut r = rng(20);
    let (c, h, w) = (3, 5, 7);
    let x = randt(&mut r, c, h, w);
    let y = upsample_nearest2(&x);
    let up = randv(&mut r, y.data.len());
    let mut dx = Tensor::zeros(c, h, w);
    upsample_nearest2_backward(
        &Tensor::from_vec(y.c, y.h, y.w, up.clone()).unwrap(),
        &mut dx,
    );
    let r64 = f64s(&up);
    assert_grad(
        &dx.data,
        &fd(&x.data, &|xx| dot(&r64, &upsample64(xx, c, h, w))),
        TOL,
        "upsample dx",
    );
}

#[test]
fn instance_norm_backward_matches_fd() {
    let mut r = rng(21);
    for &(c, h, w) in &[(3, 5, 7), (2, 1, 3), (2, 16, 13)] {
        let mut x = randt(&mut r, c, h, w);
        x.data
            .iter_mut()
            .enumerate()
            .for_each(|(i, v)| *v = *v * 2.0 + (i / (h * w)) as f32);
        let mut y = x.clone();
        let st = instance_norm(&mut y);
        let up = randv(&mut r, y.data.len());
        let mut g = Tensor::from_vec(c, h, w, up.clone()).unwrap();
        instance_norm_backward(&y, &st, &mut g);
        let r64 = f64s(&up);
        let num = fd(&x.data, &|xx| {
            let mut v = xx.to_vec();
            norm64(&mut v, c);
            dot(&r64, &v)
        });
        assert_grad(&g.data, &num, TOL, &format!("instance norm {c}x{h}x{w}"));
    }
}

#[test]
fn fused_lrelu_norm_backward_matches_fd() {
    let mut r = rng(26);
    let (c, h, w) = (3, 7, 5);
    let x = randt(&mut r, c, h, w);
    let mut z = x.clone();
    let st = instance_norm(&mut z);
    let up = randv(&mut r, z.data.len());
    let mut g = Tensor::from_vec(c, h, w, up.clone()).unwrap();
    lrelu_instance_norm_backward(&z, &st, 0.2, &mut g);
    let r64 = f64s(&up);
    let num = fd(&x.data, &|xx| {
        let mut v = xx.to_vec();
        norm64(&mut v, c);
        lrelu64(&mut v);
        dot(&r64, &v)
    });
    assert_grad(&g.data, &num, TOL, "lrelu(instance norm)");
}

/// `dnr_runtime::nn::simd::widest` compiles the fused norm backward, dense Adam and the
/// runtime's activations for AVX-512, AVX2 or the baseline: every path must give the same bits
/// (no reordering, no fused multiply-add), on planes with a partial last block and vector.
#[test]
fn simd_paths_give_the_same_bits() {
    use dnr_runtime::nn::gemm::{set_simd_cap, SimdLevel};
    let mut r = rng(27);
    let (c, h, w) = (3, 23, 29);
    let mut z = randt(&mut r, c, h, w);
    let st = instance_norm(&mut z);
    let up = randv(&mut r, z.data.len());
    let (params0, grads) = (randv(&mut r, 1003), randv(&mut r, 1003));
    let run = || {
        let mut g = Tensor::from_vec(c, h, w, up.clone()).unwrap();
        lrelu_instance_norm_backward(&z, &st, 0.2, &mut g);
        let mut p = params0.clone();
        let mut adam = Adam::new(p.len(), AdamConfig::default());
        for _ in 0..3 {
            adam.step(&mut p, &grads);
        }
        let act_in: Vec<f32> = up.iter().map(|v| 12.0 * v).collect();
        let (mut th, mut lr) = (vec![0.0; act_in.len()], vec![0.0; act_in.len()]);
        Act::Tanh.map(&act_in, &mut th);
        Act::LeakyRelu(0.2).map(&act_in, &mut lr);
        g.data
            .iter()
            .chain(&p)
            .chain(&th)
            .chain(&lr)
            .map(|v| v.to_bits())
            .collect::<Vec<u32>>()
    };
    let widest = run();
    set_simd_cap(SimdLevel::Avx2);
    let avx2 = run();
    set_simd_cap(SimdLevel::Scalar);
    let scalar = run();
    set_simd_cap(SimdLevel::Avx512);
    assert_eq!(widest, scalar, "widest path against the baseline");
    assert_eq!(avx2, scalar, "AVX2 path against the baseline");
}

#[test]
fn activations_backward_match_fd() {
    let mut r = rng(22);
    let x: Vec<f32> = randv(&mut r, 301).iter().map(|v| v * 3.0).collect();
    let up = randv(&mut r, x.len());
    let r64 = f64s(&up);
    let mut y = x.clone();
    leaky_relu(&mut y, 0.2);
    let mut g = up.clone();
    leaky_relu_backward(&y, &mut g, 0.2);
    assert_grad(
        &g,
        &fd(&x, &|xx| {
            let mut v = xx.to_vec();
            lrelu64(&mut v);
            dot(&r64, &v)
        }),
        TOL,
        "leaky relu",
    );
    let mut t = x.clone();
    tanh(&mut t);
    let mut g = up.clone();
    tanh_backward(&t, &mut g);
    assert_grad(
        &g,
        &fd(&x, &|xx| {
            xx.iter().zip(&r64).map(|(v, r)| v.tanh() * r).sum()
        }),
        TOL,
        "tanh",
    );
}

#[test]
fn concat_backward_splits() {
    let mut r = rng(23);
    let dy = randt(&mut r, 5, 3, 2);
    let mut a = Tensor::from_vec(2, 3, 2, vec![1.0; 12]).unwrap();
    let mut b = Tensor::zeros(3, 3, 2);
    concat_backward(&dy, &mut a, &mut b);
    let x1 = randt(&mut r, 2, 3, 2);
    let x2 = randt(&mut r, 3, 3, 2);
    let r64 = f64s(&dy.data);
    let both: Vec<f32> = x1.data.iter().chain(&x2.data).copied().collect();
    // concat is the identity on the stacked data.
    let num = fd(&both, &|v| dot(&r64, v));
    assert_grad(
        &a.data.iter().map(|v| v - 1.0).collect::<Vec<_>>(),
        &num[..12],
        TOL,
        "concat a",
    );
    assert_grad(&b.data, &num[12..], TOL, "concat b");
}

#[test]
fn dense_and_mlp_backward_match_fd() {
    let mut r = rng(24);
    let (ci, co, p) = (5, 4, 13);
    let x = randv(&mut r, ci * p);
    let w = randv(&mut r, co * ci);
    let b = randv(&mut r, co);
    let up = randv(&mut r, co * p);
    let (mut dw, mut db, mut dx) = (vec![0.0; w.len()], vec![0.0; co], vec![0.0; x.len()]);
    dense_backward(&x, &w, &up, p, ci, co, &mut dw, &mut db, Some(&mut dx));
    let r64 = f64s(&up);
    let dense64 = |x: &[f64], w: &[f64], b: &[f64], ci: usize, co: usize| -> Vec<f64> {
        let p = x.len() / ci;
        (0..co * p)
            .map(|i| {
                b[i / p]
                    + (0..ci)
                        .map(|c| w[(i / p) * ci + c] * x[c * p + i % p])
                        .sum::<f64>()
            })
            .collect()
    };
    let (x64, w64, b64) = (f64s(&x), f64s(&w), f64s(&b));
    assert_grad(
        &dx,
        &fd(&x, &|v| dot(&r64, &dense64(v, &w64, &b64, ci, co))),
        TOL,
        "dense dx",
    );
    assert_grad(
        &dw,
        &fd(&w, &|v| dot(&r64, &dense64(&x64, v, &b64, ci, co))),
        TOL,
        "dense dw",
    );
    assert_grad(
        &db,
        &fd(&b, &|v| dot(&r64, &dense64(&x64, &w64, v, ci, co))),
        TOL,
        "dense db",
    );

    // Two-layer MLP 5 -> 6 -> 3.
    let dims = [(5usize, 6usize), (6, 3)];
    let w0 = randv(&mut r, 30);
    let b0 = randv(&mut r, 6);
    let w1 = randv(&mut r, 18);
    let b1 = randv(&mut r, 3);
    let layers: [(&[f32], &[f32]); 2] = [(&w0, &b0), (&w1, &b1)];
    let acts = mlp_forward(&layers, &dims, &x, p).unwrap();
    let up = randv(&mut r, 3 * p);
    let (mut gw0, mut gb0, mut gw1, mut gb1) =
        (vec![0.0; 30], vec![0.0; 6], vec![0.0; 18], vec![0.0; 3]);
    let dx = {
        let mut grads: [(&mut [f32], &mut [f32]); 2] = [(&mut gw0, &mut gb0), (&mut gw1, &mut gb1)];
        mlp_backward(&layers, &dims, &acts, &up, &mut grads)
    };
    let r64 = f64s(&up);
    let mlp64 = |x: &[f64], w0: &[f64], w1: &[f64]| -> f64 {
        let mut h = dense64(x, w0, &f64s(&b0), 5, 6);
        lrelu64(&mut h);
        let o = dense64(&h, w1, &f64s(&b1), 6, 3);
        o.iter().zip(&r64).map(|(v, r)| v.tanh() * r).sum()
    };
    let (w0_64, w1_64) = (f64s(&w0), f64s(&w1));
    assert_grad(&dx, &fd(&x, &|v| mlp64(v, &w0_64, &w1_64)), TOL, "mlp dx");
    assert_grad(&gw0, &fd(&w0, &|v| mlp64(&x64, v, &w1_64)), TOL, "mlp dw0");
    assert_grad(&gw1, &fd(&w1, &|v| mlp64(&x64, &w0_64, v)), TOL, "mlp dw1");
}

#[test]
fn losses_match_fd() {
    let mut r = rng(25);
    let (c, h, w) = (3, 5, 7);
    let pred = randt(&mut r, c, h, w);
    let target = randt(&mut r, c, h, w);
    let weight: Vec<f32> = (0..h * w)
        .map(|i| {
            if i % 4 == 0 {
                0.0
            } else {
                0.5 + (i % 3) as f32
            }
        })
        .collect();
    let t64 = f64s(&target.data);
    for wopt in [None, Some(&weight[..])] {
        let mut g = Tensor::zeros(c, h, w);
        let l = l1_loss(&pred, &target, wopt, 2.0, &mut g);
        let f = |p: &[f64]| -> f64 {
            let wsum: f64 = wopt.map_or((h * w) as f64, |wt| wt.iter().map(|&v| v as f64).sum());
            p.iter()
                .zip(&t64)
                .enumerate()
                .map(|(i, (a, b))| wopt.map_or(1.0, |wt| wt[i % (h * w)] as f64) * (a - b).abs())
                .sum::<f64>()
                / (c as f64 * wsum)
        };
        assert!((l - f(&f64s(&pred.data))).abs() < 1e-6, "l1 value");
        let num: Vec<f64> = fd(&pred.data, &f).iter().map(|v| 2.0 * v).collect();
        assert_grad(&g.data, &num, TOL, "l1 loss");
    }
    // Colour L1 on channels 0..2 of a 5-channel feature image over covered pixels.
    let feat = randt(&mut r, 5, h, w);
    let covered: Vec<bool> = (0..h * w).map(|i| i % 3 != 0).collect();
    let mut g = Tensor::zeros(5, h, w);
    let l = colour_l1_loss(&feat, &target, &covered, 1.0, &mut g);
    let f = |fe: &[f64]| -> f64 {
        let n = covered.iter().filter(|&&c| c).count() as f64;
        (0..3 * h * w)
            .filter(|&i| covered[i % (h * w)])
            .map(|i| (fe[i] - t64[i]).abs())
            .sum::<f64>()
            / (3.0 * n)
    };
    assert!((l - f(&f64s(&feat.data))).abs() < 1e-6, "colour l1 value");
    assert_grad(&g.data, &fd(&feat.data, &f), TOL, "colour l1");
    // Texture regulariser, 3 levels: lambda = 2 reg, reg, 0.
    let levels = [randv(&mut r, 12), randv(&mut r, 6), randv(&mut r, 3)];
    let mut grads = [vec![0.0f32; 12], vec![0.0; 6], vec![0.0; 3]];
    let reg = 0.3;
    let val = {
        let lv: Vec<&[f32]> = levels.iter().map(|v| v.as_slice()).collect();
        let mut gv: Vec<&mut [f32]> = grads.iter_mut().map(|v| v.as_mut_slice()).collect();
        texture_l2_reg(&lv, reg, &mut gv)
    };
    let all: Vec<f32> = levels.concat();
    let f = |v: &[f64]| -> f64 {
        let m = |s: &[f64]| s.iter().map(|x| x * x).sum::<f64>() / s.len() as f64;
        2.0 * reg as f64 * m(&v[..12]) + reg as f64 * m(&v[12..18])
    };
    assert!((val - f(&f64s(&all))).abs() < 1e-6);
    let num = fd(&all, &f);
    assert_grad(&grads.concat()[..18], &num[..18], TOL, "texture reg");
    assert!(
        grads[2].iter().all(|&v| v == 0.0),
        "no regulariser on the coarsest level"
    );
}

// ---------------------------------------------------------------- whole U-Net + L1 loss

/// f64 U-Net with the weights in `tensor_specs` order.
fn unet64(p: &UNetParams, ws: &[Vec<f64>], x: &[f64], h: usize, w: usize) -> Vec<f64> {
    let d = p.widths.len();
    let pp = 1 << d;
    let (hp, wp) = (h.div_ceil(pp) * pp, w.div_ceil(pp) * pp);
    let mut cur = vec![0.0; p.in_ch * hp * wp];
    for c in 0..p.in_ch {
        for y in 0..h {
            for xx in 0..w {
                cur[(c * hp + y) * wp + xx] = x[(c * h + y) * w + xx];
            }
        }
    }
    let (mut ch, mut hh, mut ww) = (p.in_ch, hp, wp);
    let norm = p.norm == Norm::Instance;
    let mut skips = Vec::new();
    for i in 0..d {
        let (h2, w2, mut y) = conv64(
            &cur,
            ch,
            hh,
            ww,
            &ws[2 * i],
            &ws[2 * i + 1],
            p.widths[i],
            4,
            2,
            1,
        );
        if norm {
            norm64(&mut y, p.widths[i]);
        }
        lrelu64(&mut y);
        (cur, ch, hh, ww) = (y.clone(), p.widths[i], h2, w2);
        skips.push(y);
    }
    skips.pop();
    for i in (0..d).rev() {
        let (wt, b) = (&ws[2 * (d + i)], &ws[2 * (d + i) + 1]);
        let (_, co) = p.decoder_channels(i);
        let mut y = match p.decoder {
            Decoder::TransposedConv => tconv64(&cur, ch, hh, ww, wt, b, co),
            Decoder::UpsampleConv => {
                conv64(
                    &upsample64(&cur, ch, hh, ww),
                    ch,
                    2 * hh,
                    2 * ww,
                    wt,
                    b,
                    co,
                    3,
                    1,
                    1,
                )
                .2
            }
        };
        (hh, ww) = (2 * hh, 2 * ww);
        if i == 0 {
            let mut out = Vec::new();
            for c in 0..co {
                for yy in 0..h {
                    for xx in 0..w {
                        out.push(y[(c * hh + yy) * ww + xx].tanh());
                    }
                }
            }
            return out;
        }
        if norm {
            norm64(&mut y, co);
        }
        lrelu64(&mut y);
        y.extend(skips.pop().unwrap());
        cur = y;
        ch = co + p.widths[i - 1];
    }
    unreachable!()
}

#[test]
fn unet_with_l1_loss_matches_fd() {
    let cases = [
        (vec![3, 4], Decoder::TransposedConv, Norm::Instance, 7, 5, 3),
        (vec![3, 4], Decoder::UpsampleConv, Norm::Instance, 8, 7, 4),
        (vec![2, 3, 2], Decoder::TransposedConv, Norm::None, 8, 7, 3),
        (vec![3], Decoder::UpsampleConv, Norm::None, 3, 3, 3),
    ];
    for (k, (widths, decoder, norm, h, w, out_ch)) in cases.into_iter().enumerate() {
        let mut r = rng(30 + k as u64);
        let p = UNetParams {
            in_ch: 4,
            out_ch,
            widths,
            decoder,
            norm,
        };
        let mut net = UNetTrain::init(p.clone(), 7 + k as u64).unwrap();
        let x = randt(&mut r, 4, h, w);
        let target = randt(&mut r, out_ch, h, w);
        let mask: Vec<f32> = (0..h * w)
            .map(|i| if i % 5 == 2 { 0.0 } else { 1.0 })
            .collect();
        let (y, acts) = net.forward(&x).unwrap();
        let mut dy = Tensor::zeros(out_ch, h, w);
        l1_loss(&y, &target, Some(&mask), 1.0, &mut dy);
        let dx = net.backward(&acts, &dy);
        let t64 = f64s(&target.data);
        let msum: f64 = mask.iter().map(|&v| v as f64).sum();
        let loss = |o: &[f64]| -> f64 {
            o.iter()
                .zip(&t64)
                .enumerate()
                .map(|(i, (a, b))| mask[i % (h * w)] as f64 * (a - b).abs())
                .sum::<f64>()
                / (out_ch as f64 * msum)
        };
        let ws: Vec<Vec<f64>> = net.weights.iter().map(|v| f64s(v)).collect();
        let x64 = f64s(&x.data);
        let what = format!("unet case {k}");
        assert_grad(
            &dx.data,
            &fd(&x.data, &|xx| loss(&unet64(&p, &ws, xx, h, w))),
            2e-3,
            &format!("{what} dx"),
        );
        let names = p.tensor_specs();
        for (ti, (name, _)) in names.iter().enumerate() {
            if name.ends_with("bias") && name != "decoder.0.bias" && norm == Norm::Instance {
                // A bias before instance norm cancels: gradient zero up to rounding.
                assert!(
                    net.grads[ti].iter().all(|g| g.abs() < 1e-5),
                    "{what} {name} should vanish"
                );
                continue;
            }
            let num = fd(&net.weights[ti], &|v| {
                let mut wv = ws.clone();
                wv[ti] = v.to_vec();
                loss(&unet64(&p, &wv, &x64, h, w))
            });
            assert_grad(&net.grads[ti], &num, 2e-3, &format!("{what} {name}"));
        }
    }
}

// ---------------------------------------------------------------- Adam and determinism

#[test]
fn adam_matches_reference_update() {
    let cfg = AdamConfig {
        lr: 0.01,
        ..AdamConfig::default()
    };
    let mut r = rng(40);
    let mut p = randv(&mut r, 37);
    let mut want: Vec<f64> = f64s(&p);
    let (mut m, mut v) = (vec![0.0f64; 37], vec![0.0f64; 37]);
    let mut opt = Adam::new(37, cfg);
    for t in 1..=5 {
        let g = randv(&mut r, 37);
        opt.step(&mut p, &g);
        for i in 0..37 {
            m[i] = 0.9 * m[i] + 0.1 * g[i] as f64;
            v[i] = 0.999 * v[i] + 0.001 * (g[i] as f64).powi(2);
            let mh = m[i] / (1.0 - 0.9f64.powi(t));
            let vh = v[i] / (1.0 - 0.999f64.powi(t));
            want[i] -= 0.01 * mh / (vh.sqrt() + 1e-8);
        }
    }
    for (a, b) in p.iter().zip(&want) {
        assert!((*a as f64 - b).abs() < 1e-6, "adam: {a} vs {b}");
    }
    assert_eq!(opt.steps(), 5);
    // The fused variant takes the same step and clears the gradient.
    let (mut p1, mut p2) = (randv(&mut r, 37), Vec::new());
    p2.extend_from_slice(&p1);
    let (mut o1, mut o2) = (Adam::new(37, cfg), Adam::new(37, cfg));
    for _ in 0..3 {
        let g = randv(&mut r, 37);
        let mut g2 = g.clone();
        o1.step(&mut p1, &g);
        o2.step_zero_grad(&mut p2, &mut g2);
        assert!(g2.iter().all(|&v| v == 0.0));
    }
    assert_eq!(p1, p2);
}

#[test]
fn adam_weight_decay_is_decoupled() {
    // AdamW (PyTorch's): p <- p * (1 - lr * wd), then the Adam step; the sparse variant takes
    // the same step per touched row.
    let cfg = AdamConfig {
        lr: 0.01,
        weight_decay: 3.0,
        ..AdamConfig::default()
    };
    let mut r = rng(42);
    let mut p = randv(&mut r, 12);
    let mut ps = p.clone();
    let mut want: Vec<f64> = f64s(&p);
    let (mut m, mut v) = (vec![0.0f64; 12], vec![0.0f64; 12]);
    let mut opt = Adam::new(12, cfg);
    let mut sparse = SparseAdam::new(4, 3, cfg);
    for t in 1..=4 {
        let g = randv(&mut r, 12);
        opt.step(&mut p, &g);
        let mut gs = g.clone();
        sparse.step(&mut ps, &mut gs, &[0, 1, 2, 3], 0.0);
        for i in 0..12 {
            m[i] = 0.9 * m[i] + 0.1 * g[i] as f64;
            v[i] = 0.999 * v[i] + 0.001 * (g[i] as f64).powi(2);
            let mh = m[i] / (1.0 - 0.9f64.powi(t));
            let vh = v[i] / (1.0 - 0.999f64.powi(t));
            want[i] = want[i] * (1.0 - 0.01 * 3.0) - 0.01 * mh / (vh.sqrt() + 1e-8);
        }
    }
    for ((a, s), b) in p.iter().zip(&ps).zip(&want) {
        assert!((*a as f64 - b).abs() < 1e-6, "adamw: {a} vs {b}");
        assert!((*s as f64 - b).abs() < 1e-6, "sparse adamw: {s} vs {b}");
    }
    // With a zero gradient a parameter only shrinks, by the factor each step.
    let mut q = vec![1.0f32; 3];
    let mut o = Adam::new(3, cfg);
    o.step(&mut q, &[0.0; 3]);
    assert!((q[0] - 0.97).abs() < 1e-7, "{}", q[0]);
}

#[test]
fn sparse_adam_is_dense_adam_per_row() {
    // A row touched at steps 2 and 4 must end exactly where dense Adam ends after the same two
    // gradients; untouched rows must not move.
    let cfg = AdamConfig::default();
    let (rows, width) = (6, 3);
    let mut r = rng(41);
    let init = randv(&mut r, rows * width);
    let mut params = init.clone();
    let mut grads = vec![0.0f32; rows * width];
    let mut opt = SparseAdam::new(rows, width, cfg);
    let steps: [&[u32]; 4] = [&[0, 5], &[2, 0], &[5], &[2, 4]];
    let mut seen: Vec<Vec<Vec<f32>>> = vec![Vec::new(); rows];
    for touched in steps {
        for &row in touched {
            let g = randv(&mut r, width);
            grads[row as usize * width..(row as usize + 1) * width].copy_from_slice(&g);
            seen[row as usize].push(g);
        }
        opt.step(&mut params, &mut grads, touched, 0.0);
        assert!(
            grads.iter().all(|&g| g == 0.0),
            "touched gradient rows are cleared"
        );
    }
    for row in 0..rows {
        let mut p = init[row * width..(row + 1) * width].to_vec();
        let mut dense = Adam::new(width, cfg);
        for g in &seen[row] {
            dense.step(&mut p, g);
        }
        assert_eq!(&params[row * width..(row + 1) * width], &p[..], "row {row}");
        assert_eq!(opt.row_steps(row) as usize, seen[row].len());
    }
}

/// Three Adam steps of the U-Net on random data; returns all parameters.
fn train_three_steps(seed: u64) -> Vec<Vec<f32>> {
    let p = UNetParams {
        in_ch: 5,
        out_ch: 3,
        widths: vec![8, 16, 16],
        decoder: Decoder::TransposedConv,
        norm: Norm::Instance,
    };
    let mut net = UNetTrain::init(p, seed).unwrap();
    let mut opts: Vec<Adam> = net
        .weights
        .iter()
        .map(|w| Adam::new(w.len(), AdamConfig::default()))
        .collect();
    let mut r = rng(seed);
    for _ in 0..3 {
        let x = randt(&mut r, 5, 40, 36);
        let target = randt(&mut r, 3, 40, 36);
        net.zero_grad();
        let (y, acts) = net.forward(&x).unwrap();
        let mut dy = Tensor::zeros(3, 40, 36);
        l1_loss(&y, &target, None, 1.0, &mut dy);
        net.backward(&acts, &dy);
        for ((w, g), o) in net.weights.iter_mut().zip(&net.grads).zip(&mut opts) {
            o.step(w, g);
        }
    }
    net.weights
}

#[test]
fn training_is_deterministic_across_runs_and_thread_counts() {
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| train_three_steps(3))
    };
    let a = run(2);
    let b = run(2);
    let c = run(1);
    let bits = |v: &Vec<Vec<f32>>| v.iter().flatten().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&a), bits(&b), "same seed and thread count");
    assert_eq!(bits(&a), bits(&c), "1 vs 2 threads");
    assert_ne!(
        bits(&a),
        bits(
            &rayon::ThreadPoolBuilder::new()
                .num_threads(2)
                .build()
                .unwrap()
                .install(|| train_three_steps(4))
        )
    );
}

#[test]
fn training_forward_is_the_runtime_forward() {
    // What is trained is what the runtime draws: identical bits for both decoders.
    for decoder in [Decoder::TransposedConv, Decoder::UpsampleConv] {
        let p = UNetParams {
            in_ch: 6,
            out_ch: 4,
            widths: vec![4, 8, 8],
            decoder,
            norm: Norm::Instance,
        };
        let net = UNetTrain::init(p.clone(), 5).unwrap();
        let runtime = dnr_runtime::network::unet::UNet::from_map(p, &net.to_map()).unwrap();
        let x = randt(&mut rng(50), 6, 21, 19);
        let (y, _) = net.forward(&x).unwrap();
        let yr = runtime.forward(&x).unwrap();
        assert_eq!(
            y.data.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            yr.data.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
        );
    }
}
