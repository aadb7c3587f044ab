//! Every forward layer against a naive direct-loop f64 reference, on odd shapes (sizes 1, primes,
//! non-multiples of the GEMM tiles), with the SIMD kernels when the CPU has them.
//! Tolerance: 1e-5 relative (see `nn_common::assert_close`).

mod nn_common;
use nn_common::*;

use dnr_runtime::nn::activation::{leaky_relu, tanh};
use dnr_runtime::nn::conv::{conv2d, ConvGeom};
use dnr_runtime::nn::dense::dense;
use dnr_runtime::nn::gemm::AOperand;
use dnr_runtime::nn::norm::instance_norm;
use dnr_runtime::nn::upsample::upsample_nearest2;
use dnr_runtime::nn::Tensor;

#[test]
fn gemm_nn_matches_naive() {
    check_gemm_nn(1);
}

#[test]
fn gemm_nt_matches_naive() {
    check_gemm_nt(2);
}

#[test]
fn conv_k4_s2_p1_matches_naive() {
    let mut r = rng(3);
    for &(ci, co, h, w) in &[
        (1, 1, 2, 2),
        (3, 5, 7, 9),
        (2, 7, 8, 6),
        (5, 13, 11, 2),
        (16, 16, 64, 64),
        (17, 3, 13, 31),
    ] {
        check_conv(&mut r, ci, co, h, w, 4, 2, 1);
    }
}

#[test]
fn conv_k3_s1_p1_matches_naive() {
    let mut r = rng(4);
    for &(ci, co, h, w) in &[(1, 1, 1, 1), (3, 4, 5, 7), (2, 7, 13, 3), (9, 17, 31, 37)] {
        check_conv(&mut r, ci, co, h, w, 3, 1, 1);
    }
}

#[test]
fn conv_generic_matches_naive() {
    let mut r = rng(5);
    for &(ci, co, h, w, k, s, p) in &[
        (3, 5, 7, 9, 3, 2, 0),
        (2, 3, 11, 13, 5, 3, 2),
        (4, 6, 5, 5, 1, 1, 0),
        (3, 2, 9, 7, 2, 2, 0),
        (2, 2, 3, 4, 5, 1, 2),
        (1, 1, 1, 1, 1, 2, 0),
        (3, 7, 10, 8, 4, 2, 2),
    ] {
        check_conv(&mut r, ci, co, h, w, k, s, p);
    }
}

#[test]
fn conv_rejects_bad_shapes() {
    let x = Tensor::zeros(2, 3, 3);
    let g = ConvGeom {
        c_in: 2,
        c_out: 1,
        k: 4,
        stride: 2,
        pad: 0,
    };
    assert!(
        conv2d(&x, &[0.0; 32], None, g).is_err(),
        "kernel larger than padded input"
    );
    let g = ConvGeom {
        c_in: 3,
        c_out: 1,
        k: 1,
        stride: 1,
        pad: 0,
    };
    assert!(conv2d(&x, &[0.0; 3], None, g).is_err(), "channel mismatch");
}

#[test]
fn conv_transpose_matches_naive() {
    check_tconv(6);
}

#[test]
fn upsample_matches_naive() {
    let mut r = rng(7);
    for &(c, h, w) in &[(1, 1, 1), (3, 5, 7), (2, 1, 6)] {
        let x = randt(&mut r, c, h, w);
        let y = upsample_nearest2(&x);
        assert_eq!((y.c, y.h, y.w), (c, 2 * h, 2 * w));
        for ch in 0..c {
            for yy in 0..2 * h {
                for xx in 0..2 * w {
                    assert_eq!(y.at(ch, yy, xx), x.at(ch, yy / 2, xx / 2));
                }
            }
        }
    }
}

#[test]
fn instance_norm_matches_naive() {
    let mut r = rng(8);
    for &(c, h, w) in &[(1, 1, 1), (3, 5, 7), (4, 13, 17), (2, 64, 63)] {
        let mut x = randt(&mut r, c, h, w);
        // Offset channels so the mean matters.
        for (ch, v) in x.data.iter_mut().enumerate() {
            *v = *v * 3.0 + (ch / (h * w)) as f32;
        }
        let x0 = x.clone();
        let st = instance_norm(&mut x);
        let n = (h * w) as f64;
        let mut want = Vec::new();
        for ch in 0..c {
            let p = f64s(x0.plane(ch));
            let mean = p.iter().sum::<f64>() / n;
            let var = p.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n;
            let rstd = 1.0 / (var + 1e-5).sqrt();
            assert!((st.mean[ch] as f64 - mean).abs() <= 1e-6 * (1.0 + mean.abs()));
            assert!((st.rstd[ch] as f64 - rstd).abs() <= 1e-5 * rstd);
            want.extend(p.iter().map(|v| (v - mean) * rstd));
        }
        assert_close(&x.data, &want, RTOL, &format!("instance norm {c}x{h}x{w}"));
    }
}

#[test]
fn activations_match_naive() {
    let mut r = rng(9);
    let x = randv(&mut r, 1001)
        .iter()
        .map(|v| v * 4.0)
        .collect::<Vec<_>>();
    let mut y = x.clone();
    leaky_relu(&mut y, 0.2);
    let want: Vec<f64> = x
        .iter()
        .map(|&v| if v >= 0.0 { v as f64 } else { 0.2 * v as f64 })
        .collect();
    assert_close(&y, &want, RTOL, "leaky relu");
    // tanh: a dense sweep over [-20, 20] plus tiny values, each within 4 ulp-ish of f64 tanh.
    let mut x: Vec<f32> = (-20_000..=20_000).map(|i| i as f32 * 1e-3).collect();
    x.extend([
        1e-30f32, -1e-20, 1e-8, 0.0, -0.0, 0.6249, 0.625, 0.6251, 9.0, 9.2, 50.0, -1e30,
    ]);
    let mut y = x.clone();
    tanh(&mut y);
    for (&v, &t) in x.iter().zip(&y) {
        let want = (v as f64).tanh();
        assert!(
            (t as f64 - want).abs() <= 3e-7 * want.abs() + 1e-38,
            "tanh({v}) = {t}, want {want}"
        );
    }
    let mut nan = [f32::NAN];
    tanh(&mut nan);
    assert!(nan[0].is_nan());
}

#[test]
fn dense_matches_naive() {
    let mut r = rng(10);
    for &(ci, co, p) in &[(1, 1, 1), (16, 3, 17), (5, 33, 1000), (7, 4, 0)] {
        let x = randv(&mut r, ci * p);
        let w = randv(&mut r, co * ci);
        let b = randv(&mut r, co);
        let y = dense(&x, p, &w, &b, ci, co).unwrap();
        let mut want = vec![0.0f64; co * p];
        for o in 0..co {
            for px in 0..p {
                want[o * p + px] = b[o] as f64
                    + (0..ci)
                        .map(|i| w[o * ci + i] as f64 * x[i * p + px] as f64)
                        .sum::<f64>();
            }
        }
        assert_close(&y, &want, RTOL, &format!("dense {ci}->{co} x{p}"));
    }
    assert!(dense(&[0.0; 3], 1, &[0.0; 2], &[0.0], 3, 1).is_err());
}

/// The transposed conv's four phases packed, multiplied and interleaved together
/// (`pack_weights_all`, `gemm_all` / `gemm_nn_batch`, `interleave_all_act`) give the bits of
/// each phase packed and multiplied alone and interleaved by a plain loop, with every
/// activation and a cropped (odd-sized) output.
#[test]
fn conv_transpose_batched_phases_give_the_phase_by_phase_bits() {
    use dnr_runtime::nn::activation::{Act, LEAKY_SLOPE};
    use dnr_runtime::nn::conv_transpose::TconvLayout;
    let mut r = rng(17);
    // Sizes from one pixel to several GEMM blocks; channel counts off the tile sizes.
    for &(ci, co, h, w) in &[(1, 1, 1, 1), (5, 3, 3, 7), (24, 13, 9, 5), (48, 70, 16, 16)] {
        let x = randt(&mut r, ci, h, w);
        let wt = randv(&mut r, ci * co * 16);
        let b = randv(&mut r, co);
        let l = TconvLayout::new(ci, co, h, w);
        let buf = l.gather(&x);
        for act in [Act::Identity, Act::LeakyRelu(LEAKY_SLOPE), Act::Tanh] {
            for (oh, ow) in [(2 * h, 2 * w), (2 * h - 1, 2 * w - 1)] {
                // Phase by phase: output (2y + py, 2x + px) = act(phase (py, px) at (y, x) + b).
                let mut want = Tensor::zeros(co, oh, ow);
                for ph in 0..4 {
                    let raw = l.gemm(&l.pack_weights(&wt, ph), &buf, ph);
                    let (py, px) = (ph / 2, ph % 2);
                    for o in 0..co {
                        for y in (0..h).filter(|y| 2 * y + py < oh) {
                            for x in (0..w).filter(|x| 2 * x + px < ow) {
                                want.data[(o * oh + 2 * y + py) * ow + 2 * x + px] =
                                    act.apply(raw[o * l.n + y * l.pitch + x] + b[o]);
                            }
                        }
                    }
                }
                // Batched, the weights packed in one pass and read in place (training).
                let packed = l.pack_weights_all(&wt);
                let (rows, cols) = l.weight_offsets();
                let operands: [Vec<AOperand<'_>>; 2] = [
                    packed.iter().map(AOperand::from).collect(),
                    cols.iter()
                        .map(|c| AOperand::offsets(&wt, &rows, c))
                        .collect(),
                ];
                for (a, how) in operands.iter().zip(["packed", "in place"]) {
                    let mut got = Tensor::zeros(co, oh, ow);
                    let raws = l.gemm_all(a, &buf);
                    l.interleave_all_act(&raws, Some(&b), act, &mut got);
                    assert!(
                        got.data
                            .iter()
                            .zip(&want.data)
                            .all(|(g, w)| g.to_bits() == w.to_bits()),
                        "{ci}->{co} on {h}x{w}, {act:?}, out {oh}x{ow}: batched phases ({how}) \
                         differ"
                    );
                }
            }
        }
    }
}
