//! Nearest-neighbour upsampling by 2.

use super::activation::Act;
use super::Tensor;

/// `out[c][y][x] = x[c][y / 2][x / 2]`, output `c x 2h x 2w`.
pub fn upsample_nearest2(x: &Tensor) -> Tensor {
    let (h, w) = (x.h, x.w);
    let mut out = Tensor::zeros(x.c, 2 * h, 2 * w);
    for c in 0..x.c {
        let src = x.plane(c);
        let dst = out.plane_mut(c);
        for y in 0..h {
            let row = &mut dst[2 * y * 2 * w..(2 * y + 1) * 2 * w];
            for (pair, &v) in row.chunks_exact_mut(2).zip(&src[y * w..(y + 1) * w]) {
                pair[0] = v;
                pair[1] = v;
            }
            let (top, bottom) = dst[2 * y * 2 * w..(2 * y + 2) * 2 * w].split_at_mut(2 * w);
            bottom.copy_from_slice(top);
        }
    }
    out
}

/// Nearest x2 upsampling of `act(concat(parts))` (channels of the parts in order, all the same
/// size), without building the concatenation.
pub fn upsample_nearest2_concat(parts: &[&Tensor], act: Act) -> Tensor {
    let (h, w) = (parts[0].h, parts[0].w);
    assert!(
        parts.iter().all(|p| p.h == h && p.w == w),
        "upsample concat size"
    );
    let c: usize = parts.iter().map(|p| p.c).sum();
    let mut out = Tensor::zeros(c, 2 * h, 2 * w);
    let mut ch = 0;
    for p in parts {
        for pc in 0..p.c {
            let src = p.plane(pc);
            let dst = out.plane_mut(ch);
            for y in 0..h {
                let row = &mut dst[2 * y * 2 * w..(2 * y + 1) * 2 * w];
                for (pair, &v) in row.chunks_exact_mut(2).zip(&src[y * w..(y + 1) * w]) {
                    let a = act.apply(v);
                    pair[0] = a;
                    pair[1] = a;
                }
                let (top, bottom) = dst[2 * y * 2 * w..(2 * y + 2) * 2 * w].split_at_mut(2 * w);
                bottom.copy_from_slice(top);
            }
            ch += 1;
        }
    }
    out
}
