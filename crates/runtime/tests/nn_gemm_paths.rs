//! The AVX-512 `gemm_nn` path that reads B in place (blocks of few rows) against the AVX2 path,
//! which always packs B: same K blocks, same summation order, so the same bits. One test in
//! this binary, so switching the instruction-set cap races nothing.

mod nn_common;
use nn_common::*;

use dnr_runtime::nn::gemm::{gemm_nn, set_simd_cap, simd_level, PackedA, SimdLevel};

#[test]
fn unpacked_b_gives_the_packed_bits() {
    set_simd_cap(SimdLevel::Avx512);
    if simd_level() < SimdLevel::Avx512 {
        eprintln!("no AVX-512 on this CPU: the in-place path never runs here");
        return;
    }
    let mut r = rng(41);
    // Row counts on both sides of the in-place limit, partial column strips, several K blocks.
    for &(m, n, k) in &[
        (1, 5, 3),
        (4, 300, 129),
        (16, 1000, 257),
        (40, 77, 600),
        (72, 33, 64),
        (80, 130, 300),
    ] {
        let pitch = n + 3;
        let b = randv(&mut r, k * pitch + 7);
        let rows: Vec<usize> = (0..k).map(|kk| ((kk * 5) % k) * pitch + (kk % 4)).collect();
        let a = PackedA::new(m, k, &randv(&mut r, m * k), k, 1);
        for accumulate in [false, true] {
            let c0 = randv(&mut r, m * n);
            let run = |level| {
                set_simd_cap(level);
                let mut c = c0.clone();
                gemm_nn(&a, &b, &rows, n, &mut c, n, accumulate);
                c
            };
            let (fast, packed) = (run(SimdLevel::Avx512), run(SimdLevel::Avx2));
            let same = fast
                .iter()
                .zip(&packed)
                .all(|(x, y)| x.to_bits() == y.to_bits());
            assert!(same, "{m}x{n}x{k} accumulate={accumulate}: paths differ");
        }
    }
    set_simd_cap(SimdLevel::Avx512);
}
