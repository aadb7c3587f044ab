//! The AVX2 kernels (what an AVX2-only CPU runs) against the naive references, on CPUs that
//! also have AVX-512. Every test in this binary sets the same cap, so the switch is never raced.

mod nn_common;
use nn_common::*;

use dnr_runtime::nn::gemm::{set_simd_cap, simd_level, SimdLevel};

fn avx2() {
    set_simd_cap(SimdLevel::Avx2);
    assert!(simd_level() <= SimdLevel::Avx2);
}

#[test]
fn avx2_gemm_nn() {
    avx2();
    check_gemm_nn(31);
}

#[test]
fn avx2_gemm_nt() {
    avx2();
    check_gemm_nt(32);
}

#[test]
fn avx2_convolutions() {
    avx2();
    let mut r = rng(33);
    check_conv(&mut r, 3, 5, 7, 9, 4, 2, 1);
    check_conv(&mut r, 16, 70, 33, 35, 4, 2, 1);
    check_conv(&mut r, 9, 17, 31, 37, 3, 1, 1);
    check_tconv(34);
}
