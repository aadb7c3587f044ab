//! The machine's multiply-add (FMA) peak, measured on every worker.
//!
//! Independent FMA chains on every worker, at the widest vectors the kernels use. The sgemm figure
//! says how far the convolutions are from our own best GEMM; this one says how far that GEMM is
//! from the hardware.

use super::time_min_median;
use dnr_runtime::nn::gemm::{simd_level, SimdLevel};
use rayon::prelude::*;

/// Multiply-adds per lane and chain of one timed call.
const ITERS: usize = 1 << 22;

/// GFLOP/s of `ITERS` rounds of 12 independent FMA chains per worker (best of `reps`), at
/// the instruction set in use (0 on the scalar build, which has no FMA kernels).
pub fn fma_peak_gflops(reps: usize) -> f64 {
    let level = simd_level();
    let lanes = match level {
        SimdLevel::Avx512 => 16,
        SimdLevel::Avx2 => 8,
        SimdLevel::Scalar => return 0.0,
    };
    let threads = rayon::current_num_threads();
    let (t, _) = time_min_median(reps, || {
        let s: f32 = (0..threads).into_par_iter().map(|_| chains(level)).sum();
        std::hint::black_box(s);
    });
    (threads * ITERS * 12 * lanes * 2) as f64 / t * 1e-9
}

fn chains(level: SimdLevel) -> f32 {
    #[cfg(target_arch = "x86_64")]
    {
        // SAFETY: the level is AVX-512 (AVX2) only when the CPU reports AVX-512F (AVX2 and
        // FMA), the only requirements of these functions.
        #[allow(unsafe_code)]
        return unsafe {
            match level {
                SimdLevel::Avx512 => x86::chains512(ITERS),
                _ => x86::chains256(ITERS),
            }
        };
    }
    #[allow(unreachable_code)]
    {
        let _ = level;
        0.0
    }
}

#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
mod x86 {
    use std::arch::x86_64::*;

    /// Twelve independent `acc = acc * a + b` chains of 16 lanes, `n` rounds.
    ///
    /// # Safety
    /// The CPU must support AVX-512F.
    #[target_feature(enable = "avx512f")]
    pub unsafe fn chains512(n: usize) -> f32 {
        let (a, b) = (_mm512_set1_ps(0.999_999), _mm512_set1_ps(1e-7));
        let mut acc = [_mm512_set1_ps(1.0); 12];
        for _ in 0..n {
            for x in acc.iter_mut() {
                *x = _mm512_fmadd_ps(*x, a, b);
            }
        }
        acc.iter().map(|&x| _mm512_reduce_add_ps(x)).sum()
    }

    /// As [`chains512`] with 8 lanes.
    ///
    /// # Safety
    /// The CPU must support AVX2 and FMA.
    #[target_feature(enable = "avx2,fma")]
    pub unsafe fn chains256(n: usize) -> f32 {
        let (a, b) = (_mm256_set1_ps(0.999_999), _mm256_set1_ps(1e-7));
        let mut acc = [_mm256_set1_ps(1.0); 12];
        for _ in 0..n {
            for x in acc.iter_mut() {
                *x = _mm256_fmadd_ps(*x, a, b);
            }
        }
        let mut out = [0.0f32; 8];
        let s = acc
            .iter()
            .fold(_mm256_setzero_ps(), |s, &x| _mm256_add_ps(s, x));
        _mm256_storeu_ps(out.as_mut_ptr(), s);
        out.iter().sum()
    }
}
