//! Per-pixel dense layer (1x1 convolution) as one GEMM over pixels.

use super::gemm::{gemm_nn, PackedA};
use super::NnError;

/// `y[o][p] = sum_i w[o][i] x[i][p] + b[o]` for `p < pixels`: `x` is `c_in x pixels` planar,
/// `w` is `[c_out, c_in]` row-major; returns `c_out x pixels`.
pub fn dense(
    x: &[f32],
    pixels: usize,
    w: &[f32],
    b: &[f32],
    c_in: usize,
    c_out: usize,
) -> Result<Vec<f32>, NnError> {
    if x.len() != c_in * pixels || w.len() != c_out * c_in || b.len() != c_out {
        return Err(NnError::Shape(format!(
            "dense {c_in}->{c_out} on {pixels} pixels: x {}, w {}, b {}",
            x.len(),
            w.len(),
            b.len()
        )));
    }
    let mut y = vec![0.0f32; c_out * pixels];
    if pixels == 0 {
        return Ok(y);
    }
    for (o, row) in y.chunks_exact_mut(pixels).enumerate() {
        row.fill(b[o]);
    }
    let a = PackedA::new(c_out, c_in, w, c_in, 1);
    let rows: Vec<usize> = (0..c_in).map(|i| i * pixels).collect();
    gemm_nn(&a, x, &rows, pixels, &mut y, pixels, true);
    Ok(y)
}
