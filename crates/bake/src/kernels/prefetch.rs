//! Software prefetch for the texture kernels, whose texel rows are scattered over arrays far
//! larger than the caches (the hardware prefetchers follow streams, not these).

/// Hints that `data[i..]` will be read soon; nothing happens when `i` is out of range or off
/// x86_64.
#[inline(always)]
pub fn prefetch<T>(data: &[T], i: usize) {
    #[cfg(target_arch = "x86_64")]
    if i < data.len() {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        // SAFETY: SSE is part of x86_64; a prefetch is a hint that never faults, and the
        // address is inside `data` anyway.
        #[allow(unsafe_code)]
        unsafe {
            _mm_prefetch::<_MM_HINT_T0>(data[i..].as_ptr().cast());
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (data, i);
}
