//! Point-wise activations: LeakyReLU and a vectorisable tanh, in place or applied while
//! another layer reads its input ([`Act`]).

use super::simd::widest;

/// Negative slope of the renderer's LeakyReLU.
pub const LEAKY_SLOPE: f32 = 0.2;

/// An activation applied to values as a layer reads or writes them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Act {
    /// No activation.
    Identity,
    /// LeakyReLU with the given negative slope.
    LeakyRelu(f32),
    /// Hyperbolic tangent ([`tanh_f32`]).
    Tanh,
}

impl Act {
    /// The activation of one value.
    #[inline(always)]
    pub fn apply(self, v: f32) -> f32 {
        match self {
            Act::Identity => v,
            Act::LeakyRelu(s) => lrelu(v, s),
            Act::Tanh => tanh_f32(v),
        }
    }

    /// The activation of every value of `src` written to `dst` (equal lengths), vectorised for
    /// the widest instruction set the CPU has ([`widest`]: the same bits on every path).
    #[inline]
    pub fn map(self, src: &[f32], dst: &mut [f32]) {
        widest(
            #[inline(always)]
            move || match self {
                Act::Identity => dst.copy_from_slice(src),
                Act::LeakyRelu(s) => dst.iter_mut().zip(src).for_each(|(d, &v)| *d = lrelu(v, s)),
                Act::Tanh => dst.iter_mut().zip(src).for_each(|(d, &v)| *d = tanh_f32(v)),
            },
        )
    }
}

/// LeakyReLU of one value (branch-free so loops vectorise).
#[inline(always)]
pub fn lrelu(v: f32, slope: f32) -> f32 {
    if v < 0.0 {
        v * slope
    } else {
        v
    }
}

/// LeakyReLU: `x` if `x >= 0`, else `slope * x`.
pub fn leaky_relu(x: &mut [f32], slope: f32) {
    x.iter_mut().for_each(|v| *v = lrelu(*v, slope));
}

/// Hyperbolic tangent of every value ([`tanh_f32`]).
pub fn tanh(x: &mut [f32]) {
    x.iter_mut().for_each(|v| *v = tanh_f32(*v));
}

/// `e^x` for `|x| <= 88`, Cephes `expf` (relative error about 1e-7); no library call, so loops
/// over it vectorise.
#[inline(always)]
fn exp_f32(x: f32) -> f32 {
    let x = x.clamp(-87.0, 88.0);
    // Round x / ln 2 to the nearest integer by the 1.5 * 2^23 trick (no rounding instruction
    // needed on baseline x86-64).
    const SHIFT: f32 = 12_582_912.0;
    let n = (x * std::f32::consts::LOG2_E + SHIFT) - SHIFT;
    let r = x - n * 0.693_359_4 - n * -2.121_944_4e-4;
    let z = r * r;
    let p = (((((1.987_569_1e-4 * r + 1.398_199_9e-3) * r + 8.333_452e-3) * r + 4.166_579_6e-2)
        * r
        + 1.666_666_5e-1)
        * r
        + 5e-1)
        * z
        + r
        + 1.0;
    p * f32::from_bits(((n as i32 + 127) << 23) as u32)
}

/// tanh of one value to within a few ulp (Cephes `tanhf`: an odd polynomial below 0.625,
/// `1 - 2 / (e^(2|x|) + 1)` above), written without branches or library calls so that loops
/// over it vectorise.
#[inline(always)]
pub fn tanh_f32(x: f32) -> f32 {
    let ax = x.abs();
    let z = x * x;
    let small =
        ((((-5.704_988_7e-3 * z + 2.063_909e-2) * z - 5.373_971_6e-2) * z + 1.333_144_2e-1) * z
            - 3.333_328e-1)
            * z
            * x
            + x;
    // tanh(9.1) rounds to 1 in f32; clamping keeps e^(2|x|) finite.
    let e = exp_f32(2.0 * ax.min(9.1));
    let large = (1.0 - 2.0 / (e + 1.0)).copysign(x);
    if ax < 0.625 || x.is_nan() {
        small
    } else {
        large
    }
}
