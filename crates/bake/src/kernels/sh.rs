//! Spherical-harmonics modulation of the sampled features, forward and backward.
//!
//! Shapes: `features` / `d_features`: `[C, H, W]` (CHW planar); `view_dir`, `coverage`:
//! `H x W`. Forward (the runtime's [`modulate`]): at covered pixels,
//! `X[first + j, p] = F[first + j, p] * Y_j(d_p)` for `j < (degree + 1)^2`; other channels
//! and uncovered pixels pass through. The direction is not a parameter.
//!
//! Backward: `dL/dF[first + j, p] = Y_j(d_p) * dL/dX[first + j, p]` at covered pixels, and
//! `dL/dF = dL/dX` elsewhere: the operation is linear and diagonal in F, so its backward is
//! the same multiplication applied to the upstream gradient, in place.

use dnr_runtime::sh::modulate;
pub use dnr_runtime::sh::ShError;

/// Forward, in place: `features` becomes `X`.
pub fn modulate_forward(
    features: &mut [f32],
    view_dir: &[[f32; 3]],
    coverage: &[f32],
    first_channel: usize,
    degree: u32,
) -> Result<(), ShError> {
    modulate(features, view_dir, coverage, first_channel, degree)
}

/// Backward, in place: `d_out` (dL/dX) becomes dL/dF.
pub fn modulate_backward(
    d_out: &mut [f32],
    view_dir: &[[f32; 3]],
    coverage: &[f32],
    first_channel: usize,
    degree: u32,
) -> Result<(), ShError> {
    modulate(d_out, view_dir, coverage, first_channel, degree)
}
