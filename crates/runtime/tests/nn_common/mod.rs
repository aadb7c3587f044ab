//! Shared helpers of the `nn_*` tests: seeded random data, naive direct-loop references in f64,
//! and the comparison rule.
#![allow(dead_code)]

use dnr_runtime::nn::conv::{conv2d, ConvGeom};
use dnr_runtime::nn::conv_transpose::conv_transpose4s2;
use dnr_runtime::nn::gemm::{gemm_nn, gemm_nt, PackedA};
use dnr_runtime::nn::Tensor;

/// Relative tolerance of the forward checks.
pub const RTOL: f64 = 1e-5;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Seeded generator.
pub fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

/// `n` values uniform in [-1, 1).
pub fn randv(r: &mut ChaCha8Rng, n: usize) -> Vec<f32> {
    (0..n).map(|_| r.random_range(-1.0f32..1.0)).collect()
}

/// Random tensor.
pub fn randt(r: &mut ChaCha8Rng, c: usize, h: usize, w: usize) -> Tensor {
    Tensor::from_vec(c, h, w, randv(r, c * h * w)).unwrap()
}

/// Every element within `rtol * (|want| + rms(want))` of the reference: relative, with the
/// rms as a floor so values that cancel to ~0 are judged against the tensor's scale.
pub fn assert_close(got: &[f32], want: &[f64], rtol: f64, what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    let rms = (want.iter().map(|v| v * v).sum::<f64>() / want.len().max(1) as f64).sqrt();
    for (i, (&g, &w)) in got.iter().zip(want).enumerate() {
        let tol = rtol * (w.abs() + rms);
        assert!(
            (g as f64 - w).abs() <= tol && g.is_finite(),
            "{what}: element {i}: got {g}, want {w} (tol {tol:e})"
        );
    }
}

/// Naive convolution, OIHW weights, f64 accumulation.
#[allow(clippy::too_many_arguments)]
pub fn conv_ref(
    x: &Tensor,
    w: &[f32],
    b: Option<&[f32]>,
    co: usize,
    k: usize,
    s: usize,
    p: usize,
) -> (usize, usize, Vec<f64>) {
    let ho = (x.h + 2 * p - k) / s + 1;
    let wo = (x.w + 2 * p - k) / s + 1;
    let mut out = vec![0.0f64; co * ho * wo];
    for o in 0..co {
        for oy in 0..ho {
            for ox in 0..wo {
                let mut acc = b.map_or(0.0, |b| b[o] as f64);
                for c in 0..x.c {
                    for ky in 0..k {
                        for kx in 0..k {
                            let iy = (oy * s + ky) as isize - p as isize;
                            let ix = (ox * s + kx) as isize - p as isize;
                            if iy < 0 || ix < 0 || iy >= x.h as isize || ix >= x.w as isize {
                                continue;
                            }
                            let wv = w[((o * x.c + c) * k + ky) * k + kx] as f64;
                            acc += wv * x.at(c, iy as usize, ix as usize) as f64;
                        }
                    }
                }
                out[(o * ho + oy) * wo + ox] = acc;
            }
        }
    }
    (ho, wo, out)
}

/// Naive transposed convolution 4x4 stride 2 padding 1, weights `[c_in, c_out, 4, 4]`, by
/// scattering every input pixel.
pub fn tconv_ref(x: &Tensor, w: &[f32], b: Option<&[f32]>, co: usize) -> Vec<f64> {
    let (ho, wo) = (2 * x.h, 2 * x.w);
    let mut out = vec![0.0f64; co * ho * wo];
    for o in 0..co {
        for i in 0..ho * wo {
            out[o * ho * wo + i] = b.map_or(0.0, |b| b[o] as f64);
        }
    }
    for c in 0..x.c {
        for iy in 0..x.h {
            for ix in 0..x.w {
                let v = x.at(c, iy, ix) as f64;
                for o in 0..co {
                    for ky in 0..4 {
                        for kx in 0..4 {
                            let oy = (2 * iy + ky) as isize - 1;
                            let ox = (2 * ix + kx) as isize - 1;
                            if oy < 0 || ox < 0 || oy >= ho as isize || ox >= wo as isize {
                                continue;
                            }
                            out[(o * ho + oy as usize) * wo + ox as usize] +=
                                v * w[((c * co + o) * 4 + ky) * 4 + kx] as f64;
                        }
                    }
                }
            }
        }
    }
    out
}

/// f32 slice widened.
pub fn f64s(v: &[f32]) -> Vec<f64> {
    v.iter().map(|&x| x as f64).collect()
}

/// gemm_nn against a naive product over odd shapes.
pub fn check_gemm_nn(seed: u64) {
    let mut r = rng(seed);
    for &(m, n, k) in &[
        (1, 1, 1),
        (5, 17, 3),
        (6, 16, 7),
        (7, 33, 257),
        (13, 100, 300),
        (3, 1000, 64),
        (40, 301, 129),
        (70, 301, 300),
        (131, 47, 513),
    ] {
        // B rows at scattered offsets (with gaps) into one buffer.
        let pitch = n + 5;
        let b = randv(&mut r, k * pitch + 11);
        let rows: Vec<usize> = (0..k).map(|kk| ((kk * 7) % k) * pitch + (kk % 3)).collect();
        let a = randv(&mut r, m * k);
        let ldc = n + 2;
        for accumulate in [false, true] {
            let c0 = randv(&mut r, m * ldc);
            let mut c = c0.clone();
            gemm_nn(
                &PackedA::new(m, k, &a, k, 1),
                &b,
                &rows,
                n,
                &mut c,
                ldc,
                accumulate,
            );
            let mut want = Vec::new();
            let mut got = Vec::new();
            for i in 0..m {
                for j in 0..n {
                    let mut s = if accumulate {
                        c0[i * ldc + j] as f64
                    } else {
                        0.0
                    };
                    for kk in 0..k {
                        s += a[i * k + kk] as f64 * b[rows[kk] + j] as f64;
                    }
                    want.push(s);
                    got.push(c[i * ldc + j]);
                }
                // Padding columns untouched.
                assert_eq!(
                    &c[i * ldc + n..i * ldc + ldc],
                    &c0[i * ldc + n..i * ldc + ldc]
                );
            }
            assert_close(
                &got,
                &want,
                RTOL,
                &format!("gemm_nn {m}x{n}x{k} acc={accumulate}"),
            );
        }
    }
}

/// gemm_nt against a naive product over odd shapes.
pub fn check_gemm_nt(seed: u64) {
    let mut r = rng(seed);
    for &(m, n, k) in &[
        (1, 1, 1),
        (5, 7, 3),
        (4, 3, 8),
        (7, 11, 517),
        (13, 29, 1031),
        (2, 300, 2000),
    ] {
        let a = randv(&mut r, m * k + 9);
        let b = randv(&mut r, n * k + 4);
        let a_rows: Vec<usize> = (0..m).map(|i| ((i * 5) % m) * k + (i % 9).min(9)).collect();
        let b_rows: Vec<usize> = (0..n).map(|j| ((j * 3) % n) * k + (j % 4)).collect();
        for accumulate in [false, true] {
            let c0 = randv(&mut r, m * n);
            let mut c = c0.clone();
            gemm_nt(&a, &a_rows, &b, &b_rows, k, &mut c, n, accumulate);
            let mut want = Vec::new();
            for i in 0..m {
                for j in 0..n {
                    let mut s = if accumulate {
                        c0[i * n + j] as f64
                    } else {
                        0.0
                    };
                    for kk in 0..k {
                        s += a[a_rows[i] + kk] as f64 * b[b_rows[j] + kk] as f64;
                    }
                    want.push(s);
                }
            }
            assert_close(
                &c,
                &want,
                RTOL,
                &format!("gemm_nt {m}x{n}x{k} acc={accumulate}"),
            );
        }
    }
}

/// conv2d against `conv_ref`.
#[allow(clippy::too_many_arguments)]
pub fn check_conv(
    r: &mut rand_chacha::ChaCha8Rng,
    ci: usize,
    co: usize,
    h: usize,
    w: usize,
    k: usize,
    s: usize,
    p: usize,
) {
    let x = randt(r, ci, h, w);
    let wt = randv(r, co * ci * k * k);
    let b = randv(r, co);
    let geom = ConvGeom {
        c_in: ci,
        c_out: co,
        k,
        stride: s,
        pad: p,
    };
    let y = conv2d(&x, &wt, Some(&b), geom).unwrap();
    let (ho, wo, want) = conv_ref(&x, &wt, Some(&b), co, k, s, p);
    assert_eq!((y.c, y.h, y.w), (co, ho, wo), "conv shape");
    assert_close(
        &y.data,
        &want,
        RTOL,
        &format!("conv {ci}->{co} {h}x{w} k{k} s{s} p{p}"),
    );
}

/// Transposed conv against `tconv_ref` over odd shapes.
pub fn check_tconv(seed: u64) {
    let mut r = rng(seed);
    for &(ci, co, h, w) in &[
        (1, 1, 1, 1),
        (3, 5, 2, 3),
        (2, 7, 5, 7),
        (13, 3, 11, 2),
        (32, 16, 32, 32),
    ] {
        let x = randt(&mut r, ci, h, w);
        let wt = randv(&mut r, ci * co * 16);
        let b = randv(&mut r, co);
        let y = conv_transpose4s2(&x, &wt, Some(&b), co).unwrap();
        assert_eq!((y.c, y.h, y.w), (co, 2 * h, 2 * w));
        assert_close(
            &y.data,
            &tconv_ref(&x, &wt, Some(&b), co),
            RTOL,
            &format!("tconv {ci}->{co} {h}x{w}"),
        );
    }
}
