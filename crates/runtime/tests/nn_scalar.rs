//! The portable scalar GEMM kernels (the safe path) against the naive references. Every test
//! in this binary forces the scalar path, so the switch is never raced.

mod nn_common;
use nn_common::*;

use dnr_runtime::nn::gemm::{set_force_scalar, simd_active};

fn scalar() {
    set_force_scalar(true);
    assert!(!simd_active());
}

#[test]
fn scalar_gemm_nn() {
    scalar();
    check_gemm_nn(11);
}

#[test]
fn scalar_gemm_nt() {
    scalar();
    check_gemm_nt(12);
}

#[test]
fn scalar_convolutions() {
    scalar();
    let mut r = rng(13);
    check_conv(&mut r, 3, 5, 7, 9, 4, 2, 1);
    check_conv(&mut r, 9, 17, 31, 37, 3, 1, 1);
    check_conv(&mut r, 2, 3, 11, 13, 5, 3, 2);
    check_tconv(14);
}
