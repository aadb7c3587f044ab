//! Running an element-wise loop with the widest vectors the CPU has, and software prefetch.
//!
//! The crates are built for baseline x86-64 (SSE2: 4 lanes, no blends), so loops that are
//! bound by arithmetic (tanh's polynomial, Adam's square root and divisions, the norms'
//! select-multiply-sum passes) leave most of an AVX2 or AVX-512 core idle. [`widest`] runs a
//! closure inside a function compiled for the best instruction set detected at run time; the
//! closure, inlined there, is vectorised for it. IEEE operations round the same at every width and the compiler never
//! reorders or fuses float operations, so every path gives the same bits.
#![allow(unsafe_code)]

#[cfg(target_arch = "x86_64")]
use super::gemm::simd_level;
use super::gemm::SimdLevel;

/// Runs `f` compiled for AVX-512F, AVX2 + FMA or the baseline, whichever
/// [`simd_level`] allows (tests force the baseline with `set_simd_cap`). Keep `f` a plain
/// loop over slices: only what inlines into it is compiled for the wider set.
#[inline(always)]
pub fn widest<R>(f: impl FnOnce() -> R) -> R {
    widest_up_to(SimdLevel::Avx512, f)
}

/// [`widest`], at most `cap`: for loops that a wider set makes slower (the texel scatter's
/// gathers and sparse rows of 16 channels lost 20% with AVX-512 on an Intel Xeon).
#[inline(always)]
pub fn widest_up_to<R>(cap: SimdLevel, f: impl FnOnce() -> R) -> R {
    #[cfg(not(target_arch = "x86_64"))]
    let _ = cap; // one instruction set elsewhere
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx512f")]
        unsafe fn avx512<R>(f: impl FnOnce() -> R) -> R {
            f()
        }
        #[target_feature(enable = "avx2")]
        unsafe fn avx2<R>(f: impl FnOnce() -> R) -> R {
            f()
        }
        match simd_level().min(cap) {
            // SAFETY: the level is AVX-512 (AVX2) only when the CPU reports AVX-512F (AVX2
            // and FMA), the only requirement of these functions.
            SimdLevel::Avx512 => return unsafe { avx512(f) },
            SimdLevel::Avx2 => return unsafe { avx2(f) },
            SimdLevel::Scalar => {}
        }
    }
    f()
}

/// Hints that `data[i..]` will be touched soon (for rows scattered over arrays far larger
/// than the caches, or more streams than the hardware prefetchers follow); nothing happens
/// when `i` is out of range or off x86_64.
#[inline(always)]
pub fn prefetch<T>(data: &[T], i: usize) {
    #[cfg(target_arch = "x86_64")]
    if i < data.len() {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        // SAFETY: SSE is part of x86_64; a prefetch is a hint that never faults, and the
        // address is inside `data` anyway.
        unsafe {
            _mm_prefetch::<_MM_HINT_T0>(data[i..].as_ptr().cast());
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (data, i);
}
