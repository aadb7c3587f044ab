//! Nearest x2 upsampling: forward is `dnr_runtime::nn::upsample::upsample_nearest2`.

use dnr_runtime::nn::Tensor;

/// Backward of nearest x2 upsampling: each input pixel receives the sum of its 2x2 block.
/// dy: `c x 2H x 2W`; adds to dx: `c x H x W`.
pub fn upsample_nearest2_backward(dy: &Tensor, dx: &mut Tensor) {
    assert!(
        dy.c == dx.c && dy.h == 2 * dx.h && dy.w == 2 * dx.w,
        "upsample backward shape"
    );
    let (h, w) = (dx.h, dx.w);
    for c in 0..dx.c {
        let src = dy.plane(c);
        let dst = dx.plane_mut(c);
        for y in 0..h {
            let r0 = &src[2 * y * 2 * w..(2 * y + 1) * 2 * w];
            let r1 = &src[(2 * y + 1) * 2 * w..(2 * y + 2) * 2 * w];
            for x in 0..w {
                dst[y * w + x] += (r0[2 * x] + r0[2 * x + 1]) + (r1[2 * x] + r1[2 * x + 1]);
            }
        }
    }
}
