//! `gemm_nn`'s two paths for blocks of few rows, B read in place or packed, against each other
//! at every instruction set the CPU has (AVX2 always packs, so there the runs must merely
//! agree), and AVX-512 in place against AVX2 packed: same K blocks, same summation order, so
//! the same bits. Likewise A read in place ([`AOperand::offsets`]) against A packed from the
//! same offsets, at every level including the scalar one. One test in this binary, so
//! switching the global path switches races nothing.

mod nn_common;
use nn_common::*;

use dnr_runtime::nn::gemm::{
    gemm_nn, set_in_place_b, set_simd_cap, simd_level, AOperand, PackedA, SimdLevel,
};

#[test]
fn unpacked_b_gives_the_packed_bits() {
    let mut levels = Vec::new();
    for level in [SimdLevel::Avx2, SimdLevel::Avx512] {
        set_simd_cap(level);
        if simd_level() == level {
            levels.push(level);
        }
    }
    if levels.is_empty() {
        eprintln!("no AVX2 on this CPU: the in-place paths never run here");
    }
    let mut r = rng(41);
    // Row counts on both sides of the in-place limit, partial column strips (widths 1..15
    // past the last full strip), several K blocks.
    for &(m, n, k) in &[
        (1, 5, 3),
        (4, 300, 129),
        (16, 1000, 257),
        (40, 77, 600),
        (72, 33, 64),
        (7, 9, 20),
        (80, 130, 300),
    ] {
        let pitch = n + 3;
        let b = randv(&mut r, k * pitch + 7);
        let rows: Vec<usize> = (0..k).map(|kk| ((kk * 5) % k) * pitch + (kk % 4)).collect();
        // A as scattered offsets (rows and columns in no simple order, like a transposed
        // conv's phases), packed and read in place.
        let w = randv(&mut r, m * (k + 5) + 3);
        let a_rows: Vec<usize> = (0..m).map(|i| ((i * 7) % m) * (k + 5)).collect();
        let a_cols: Vec<usize> = (0..k).map(|kk| (kk * 3) % k + (kk % 2) * 5 / 2).collect();
        let a = PackedA::from_offsets(&w, &a_rows, &a_cols);
        let a_in_place = AOperand::offsets(&w, &a_rows, &a_cols);
        for accumulate in [false, true] {
            let c0 = randv(&mut r, m * n);
            let run_a = |level, in_place, a: AOperand<'_>| {
                set_simd_cap(level);
                set_in_place_b(in_place);
                let mut c = c0.clone();
                gemm_nn(a, &b, &rows, n, &mut c, n, accumulate);
                c
            };
            let run = |level, in_place| run_a(level, in_place, AOperand::from(&a));
            let same =
                |x: &[f32], y: &[f32]| x.iter().zip(y).all(|(x, y)| x.to_bits() == y.to_bits());
            for level in [SimdLevel::Scalar].iter().chain(&levels).copied() {
                for in_place_b in [false, true] {
                    assert!(
                        same(
                            &run(level, in_place_b),
                            &run_a(level, in_place_b, a_in_place)
                        ),
                        "{level:?} {m}x{n}x{k} accumulate={accumulate} in-place B \
                         {in_place_b}: A in place and packed differ"
                    );
                }
            }
            for &level in &levels {
                let (fast, packed) = (run(level, true), run(level, false));
                assert!(
                    same(&fast, &packed),
                    "{level:?} {m}x{n}x{k} accumulate={accumulate}: in place and packed differ"
                );
                if level == SimdLevel::Avx512 {
                    let avx2 = run(SimdLevel::Avx2, false);
                    assert!(
                        same(&fast, &avx2),
                        "{m}x{n}x{k} accumulate={accumulate}: AVX-512 and AVX2 differ"
                    );
                }
            }
        }
    }
    set_in_place_b(true);
    set_simd_cap(SimdLevel::Avx512);
}
