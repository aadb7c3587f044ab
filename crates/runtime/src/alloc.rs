//! A global allocator for binaries that puts every large allocation on a cache-line boundary.
//!
//! The system allocator returns 16-byte aligned blocks (large ones sit 16 bytes into a page),
//! so in a `Vec<f32>` of 16-channel texels every texel's 64 bytes straddle two cache lines:
//! twice the lines for each texel the sampler reads and the optimiser updates, and every
//! AVX-512 load of a plane split across two lines. A library cannot choose the allocator;
//! binaries opt in with
//! `#[global_allocator] static ALLOC: dnr_runtime::alloc::LineAligned = dnr_runtime::alloc::LineAligned;`.
#![allow(unsafe_code)]

use std::alloc::{GlobalAlloc, Layout, System};

/// Cache-line size the large blocks are aligned to.
pub const LINE: usize = 64;
/// Blocks of at least this many bytes are line-aligned; smaller ones are left to the system
/// allocator as asked (its small-block paths are faster, and rows that short rarely matter).
pub const MIN_ALIGNED_SIZE: usize = 4096;

/// [`System`], with blocks of [`MIN_ALIGNED_SIZE`] bytes or more aligned to [`LINE`] bytes.
#[derive(Clone, Copy, Debug, Default)]
pub struct LineAligned;

/// The layout actually asked of the system for `l` (a pure function of size and alignment, so
/// `dealloc` recomputes what `alloc` used).
fn widened(l: Layout) -> Layout {
    if l.size() >= MIN_ALIGNED_SIZE && l.align() < LINE {
        Layout::from_size_align(l.size(), LINE).unwrap_or(l)
    } else {
        l
    }
}

// SAFETY: every block is allocated and freed by `System` with the same widened layout, which
// satisfies the caller's layout (same size, alignment at least as large).
unsafe impl GlobalAlloc for LineAligned {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: `widened` keeps the size (non-zero, as the caller promises) and gives a
        // valid power-of-two alignment.
        unsafe { System.alloc(widened(layout)) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        // SAFETY: as `alloc`.
        unsafe { System.alloc_zeroed(widened(layout)) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from `alloc`/`realloc` with this layout, hence from `System` with
        // its widened layout.
        unsafe { System.dealloc(ptr, widened(layout)) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let old = widened(layout);
        // SAFETY: the caller promises `new_size` does not overflow when rounded to the
        // alignment, which `Layout` requires.
        let new = widened(unsafe { Layout::from_size_align_unchecked(new_size, layout.align()) });
        if old.align() == new.align() {
            // SAFETY: `ptr` was allocated by `System` with `old`; `new_size` is non-zero.
            return unsafe { System.realloc(ptr, old, new_size) };
        }
        // The block crosses MIN_ALIGNED_SIZE: move it to a block of the other alignment.
        // SAFETY: `new` has a non-zero size; both blocks are valid for the bytes copied, and
        // `ptr` is freed with the layout it was allocated with.
        unsafe {
            let q = System.alloc(new);
            if !q.is_null() {
                std::ptr::copy_nonoverlapping(ptr, q, layout.size().min(new_size));
                System.dealloc(ptr, old);
            }
            q
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn large_blocks_are_line_aligned_and_keep_their_bytes_across_realloc() {
        let a = LineAligned;
        for (size, grown) in [
            (16usize, 32usize),
            (100, 8192),
            (4096, 1 << 20),
            (1 << 20, 64),
        ] {
            let l = Layout::from_size_align(size, 4).expect("layout");
            // SAFETY: non-zero sizes; every block is freed once with its current layout.
            unsafe {
                let p = a.alloc(l);
                assert!(!p.is_null());
                if size >= MIN_ALIGNED_SIZE {
                    assert_eq!(p as usize % LINE, 0, "{size} bytes not line-aligned");
                }
                for i in 0..size {
                    *p.add(i) = (i % 251) as u8;
                }
                let q = a.realloc(p, l, grown);
                assert!(!q.is_null());
                if grown >= MIN_ALIGNED_SIZE {
                    assert_eq!(q as usize % LINE, 0, "{grown} bytes not line-aligned");
                }
                for i in 0..size.min(grown) {
                    assert_eq!(*q.add(i), (i % 251) as u8, "byte {i} of {size} -> {grown}");
                }
                a.dealloc(q, Layout::from_size_align(grown, 4).expect("layout"));
                let z = a.alloc_zeroed(l);
                assert!((0..size).all(|i| *z.add(i) == 0));
                a.dealloc(z, l);
            }
        }
    }
}
