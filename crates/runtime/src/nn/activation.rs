//! Point-wise activations, in place.

/// Negative slope of the renderer's LeakyReLU.
pub const LEAKY_SLOPE: f32 = 0.2;

/// LeakyReLU: `x` if `x >= 0`, else `slope * x`.
pub fn leaky_relu(x: &mut [f32], slope: f32) {
    for v in x {
        if *v < 0.0 {
            *v *= slope;
        }
    }
}

/// Hyperbolic tangent.
pub fn tanh(x: &mut [f32]) {
    for v in x {
        *v = v.tanh();
    }
}
