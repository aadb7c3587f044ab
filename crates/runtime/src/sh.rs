//! Real spherical harmonics for view-dependent features.
//!
//! As DESIGN.md "View dependence" defines them: degree 0..=3 in the KHR_gaussian_splatting / 3DGS
//! order and signs. Channel `first_channel + j` of the sampled features is multiplied by `Y_j(d)`,
//! with `d` the unit eye-to-surface direction in the primitive's local space.

use rayon::prelude::*;

/// Highest supported degree.
pub const MAX_DEGREE: u32 = 3;

// The DESIGN.md table's constants, written at full precision and rounded once to f32.
const C0: f32 = 0.282_094_791_773_878_14_f64 as f32;
const C1: f32 = 0.488_602_511_902_919_9_f64 as f32;
const C2: [f32; 5] = [
    1.092_548_430_592_079_2_f64 as f32,
    -1.092_548_430_592_079_2_f64 as f32,
    0.315_391_565_252_520_05_f64 as f32,
    -1.092_548_430_592_079_2_f64 as f32,
    0.546_274_215_296_039_6_f64 as f32,
];
const C3: [f32; 7] = [
    -0.590_043_589_926_643_5_f64 as f32,
    2.890_611_442_640_554_f64 as f32,
    -0.457_045_799_464_465_8_f64 as f32,
    0.373_176_332_590_115_4_f64 as f32,
    -0.457_045_799_464_465_8_f64 as f32,
    1.445_305_721_320_277_f64 as f32,
    -0.590_043_589_926_643_5_f64 as f32,
];

/// Number of basis functions of degree `degree`: `(degree + 1)^2`.
pub const fn coeff_count(degree: u32) -> usize {
    let n = degree as usize + 1;
    n * n
}

/// Why a [`modulate`] call is malformed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ShError {
    /// Degree above [`MAX_DEGREE`].
    #[error("spherical harmonics degree {0} is not supported (0..=3)")]
    Degree(u32),
    /// The SH channels do not fit the feature channels.
    #[error("channels {first}..{end} of the SH basis exceed the {channels} feature channels")]
    Channels {
        /// First SH channel.
        first: usize,
        /// One past the last SH channel.
        end: usize,
        /// Feature channels.
        channels: usize,
    },
    /// Buffer lengths disagree (features not a whole number of planes, or view_dir and
    /// coverage lengths differ).
    #[error("features hold {features} values for {pixels} pixels (view_dir {view_dirs})")]
    Shape {
        /// Feature values.
        features: usize,
        /// Coverage entries (pixels).
        pixels: usize,
        /// View direction entries.
        view_dirs: usize,
    },
}

/// Basis function `j` (0..16) at `d = (x, y, z)`. Returns 0 for `j >= 16`.
#[inline]
pub fn sh_component(j: usize, d: [f32; 3]) -> f32 {
    let [x, y, z] = d;
    match j {
        0 => C0,
        1 => -C1 * y,
        2 => C1 * z,
        3 => -C1 * x,
        4 => C2[0] * x * y,
        5 => C2[1] * y * z,
        6 => C2[2] * (2.0 * z * z - x * x - y * y),
        7 => C2[3] * x * z,
        8 => C2[4] * (x * x - y * y),
        9 => C3[0] * y * (3.0 * x * x - y * y),
        10 => C3[1] * x * y * z,
        11 => C3[2] * y * (4.0 * z * z - x * x - y * y),
        12 => C3[3] * z * (2.0 * z * z - 3.0 * x * x - 3.0 * y * y),
        13 => C3[4] * x * (4.0 * z * z - x * x - y * y),
        14 => C3[5] * z * (x * x - y * y),
        15 => C3[6] * x * (x * x - 3.0 * y * y),
        _ => 0.0,
    }
}

/// Writes `Y_0 .. Y_{(degree+1)^2 - 1}` at direction `d` into `out`. The degree is capped at
/// [`MAX_DEGREE`], and at most `out.len()` values are written; returns how many were.
pub fn sh_basis(degree: u32, d: [f32; 3], out: &mut [f32]) -> usize {
    let n = coeff_count(degree.min(MAX_DEGREE)).min(out.len());
    for (j, o) in out[..n].iter_mut().enumerate() {
        *o = sh_component(j, d);
    }
    n
}

/// Checks a modulate call's shapes; returns the channel count.
pub fn check_modulate(
    features: usize,
    view_dirs: usize,
    pixels: usize,
    first_channel: usize,
    degree: u32,
) -> Result<usize, ShError> {
    if degree > MAX_DEGREE {
        return Err(ShError::Degree(degree));
    }
    // `is_multiple_of(0)` holds only for 0: no pixels means no features.
    if view_dirs != pixels || !features.is_multiple_of(pixels) {
        return Err(ShError::Shape {
            features,
            pixels,
            view_dirs,
        });
    }
    let channels = features.checked_div(pixels).unwrap_or(0);
    let end = first_channel.saturating_add(coeff_count(degree));
    if end > channels {
        return Err(ShError::Channels {
            first: first_channel,
            end,
            channels,
        });
    }
    Ok(channels)
}

/// In place on planar (CHW) `features`: multiplies channel `first_channel + j` by
/// `Y_j(view_dir)` at every covered pixel, for `j < (degree + 1)^2`. Uncovered pixels are
/// left as they are (zero after [`crate::texture::sample_into`]). The channel count is
/// `features.len() / coverage.len()`. Parallel over the modulated planes.
///
/// The operation is linear and diagonal in the features, so it is also its own backward
/// (the baker applies it to the upstream gradient).
pub fn modulate(
    features: &mut [f32],
    view_dir: &[[f32; 3]],
    coverage: &[f32],
    first_channel: usize,
    degree: u32,
) -> Result<(), ShError> {
    let pixels = coverage.len();
    check_modulate(
        features.len(),
        view_dir.len(),
        pixels,
        first_channel,
        degree,
    )?;
    if pixels == 0 {
        return Ok(());
    }
    let n = coeff_count(degree);
    features[first_channel * pixels..(first_channel + n) * pixels]
        .par_chunks_mut(pixels)
        .enumerate()
        .for_each(|(j, plane)| match j {
            0 => modulate_plane::<0>(plane, view_dir, coverage),
            1 => modulate_plane::<1>(plane, view_dir, coverage),
            2 => modulate_plane::<2>(plane, view_dir, coverage),
            3 => modulate_plane::<3>(plane, view_dir, coverage),
            4 => modulate_plane::<4>(plane, view_dir, coverage),
            5 => modulate_plane::<5>(plane, view_dir, coverage),
            6 => modulate_plane::<6>(plane, view_dir, coverage),
            7 => modulate_plane::<7>(plane, view_dir, coverage),
            8 => modulate_plane::<8>(plane, view_dir, coverage),
            9 => modulate_plane::<9>(plane, view_dir, coverage),
            10 => modulate_plane::<10>(plane, view_dir, coverage),
            11 => modulate_plane::<11>(plane, view_dir, coverage),
            12 => modulate_plane::<12>(plane, view_dir, coverage),
            13 => modulate_plane::<13>(plane, view_dir, coverage),
            14 => modulate_plane::<14>(plane, view_dir, coverage),
            15 => modulate_plane::<15>(plane, view_dir, coverage),
            _ => modulate_plane::<16>(plane, view_dir, coverage),
        });
    Ok(())
}

/// One feature plane times basis function `J` at covered pixels. `J` is a constant so the
/// basis' `match` folds away and the loop is branch-free (a select): the per-pixel `match`
/// and branch made modulation a few percent of a training step.
#[inline]
fn modulate_plane<const J: usize>(plane: &mut [f32], view_dir: &[[f32; 3]], coverage: &[f32]) {
    for ((f, &d), &c) in plane.iter_mut().zip(view_dir).zip(coverage) {
        let m = *f * sh_component(J, d);
        *f = if c != 0.0 { m } else { *f };
    }
}
