//! Point-wise activations: forwards are in `dnr_runtime::nn::activation`.

/// LeakyReLU backward in place: `g *= 1` where the activation input `z >= 0`, else `slope`.
/// (The output has the same sign as the input, so either may be passed as `z`.)
pub fn leaky_relu_backward(z: &[f32], g: &mut [f32], slope: f32) {
    assert_eq!(z.len(), g.len(), "leaky relu backward length");
    // A select, not a branch: signs are random, and the loop vectorises.
    for (gv, &zv) in g.iter_mut().zip(z) {
        *gv *= if zv < 0.0 { slope } else { 1.0 };
    }
}

/// tanh backward in place from the output `t`: `g *= 1 - t^2`.
pub fn tanh_backward(t: &[f32], g: &mut [f32]) {
    assert_eq!(t.len(), g.len(), "tanh backward length");
    for (gv, &tv) in g.iter_mut().zip(t) {
        *gv *= 1.0 - tv * tv;
    }
}
