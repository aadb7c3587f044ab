//! Per-pixel dense layers and the MLP renderer: forwards that keep what backward needs, and
//! backward. Activations are planar `channels x pixels`.

use super::activation::{leaky_relu_backward, tanh_backward};
use dnr_runtime::nn::activation::{leaky_relu, tanh, LEAKY_SLOPE};
use dnr_runtime::nn::dense::dense;
use dnr_runtime::nn::gemm::{gemm_nn, gemm_nt, PackedA};
use dnr_runtime::nn::NnError;

/// Backward of `y = W x + b` over `pixels`.
/// x: `c_in x pixels`; w: `[c_out, c_in]`; dy: `c_out x pixels`.
/// Adds to dw and db; adds the input gradient (`c_in x pixels`) to `dx` when given.
#[allow(clippy::too_many_arguments)]
pub fn dense_backward(
    x: &[f32],
    w: &[f32],
    dy: &[f32],
    pixels: usize,
    c_in: usize,
    c_out: usize,
    dw: &mut [f32],
    db: &mut [f32],
    dx: Option<&mut [f32]>,
) {
    assert!(
        x.len() == c_in * pixels && dy.len() == c_out * pixels,
        "dense backward activations"
    );
    assert!(
        w.len() == c_out * c_in && dw.len() == w.len() && db.len() == c_out,
        "dense backward weights"
    );
    if pixels == 0 {
        return;
    }
    for (o, row) in dy.chunks_exact(pixels).enumerate() {
        db[o] += row.iter().map(|&v| v as f64).sum::<f64>() as f32;
    }
    let dy_rows: Vec<usize> = (0..c_out).map(|o| o * pixels).collect();
    let x_rows: Vec<usize> = (0..c_in).map(|i| i * pixels).collect();
    gemm_nt(dy, &dy_rows, x, &x_rows, pixels, dw, c_in, true);
    if let Some(dx) = dx {
        assert_eq!(dx.len(), c_in * pixels, "dense backward dx");
        // A(i, o) = w[o][i].
        let wt = PackedA::new(c_in, c_out, w, 1, c_in);
        gemm_nn(&wt, dy, &dy_rows, pixels, dx, pixels, true);
    }
}

/// Activations of one MLP forward pass, kept for [`mlp_backward`].
#[derive(Clone, Debug)]
pub struct MlpActs {
    /// Input of every layer (`c_in_i x pixels`), the network input first.
    pub inputs: Vec<Vec<f32>>,
    /// Output after tanh (`c_out x pixels`).
    pub out: Vec<f32>,
    /// Evaluated pixels.
    pub pixels: usize,
}

/// MLP forward: dense layers `(w [out, in], b)` with widths `dims` (`(in, out)` per layer),
/// LeakyReLU(0.2) between, tanh at the end. x: `dims[0].0 x pixels`.
pub fn mlp_forward(
    layers: &[(&[f32], &[f32])],
    dims: &[(usize, usize)],
    x: &[f32],
    pixels: usize,
) -> Result<MlpActs, NnError> {
    let mut inputs = vec![x.to_vec()];
    let mut cur = x.to_vec();
    for (i, ((w, b), &(ci, co))) in layers.iter().zip(dims).enumerate() {
        cur = dense(&cur, pixels, w, b, ci, co)?;
        if i + 1 < dims.len() {
            leaky_relu(&mut cur, LEAKY_SLOPE);
            inputs.push(cur.clone());
        } else {
            tanh(&mut cur);
        }
    }
    Ok(MlpActs {
        inputs,
        out: cur,
        pixels,
    })
}

/// Backward of [`mlp_forward`]: `dout` is dL/d(output after tanh). Adds to each layer's
/// `(dw, db)`; returns dL/dx (`dims[0].0 x pixels`).
pub fn mlp_backward(
    layers: &[(&[f32], &[f32])],
    dims: &[(usize, usize)],
    acts: &MlpActs,
    dout: &[f32],
    grads: &mut [(&mut [f32], &mut [f32])],
) -> Vec<f32> {
    let p = acts.pixels;
    let mut g = dout.to_vec();
    tanh_backward(&acts.out, &mut g);
    for i in (0..dims.len()).rev() {
        let (ci, co) = dims[i];
        let mut dx = vec![0.0f32; ci * p];
        let (dw, db) = &mut grads[i];
        dense_backward(
            &acts.inputs[i],
            layers[i].0,
            &g,
            p,
            ci,
            co,
            dw,
            db,
            Some(&mut dx),
        );
        if i > 0 {
            // inputs[i] is the LeakyReLU output of layer i - 1 (same sign as its input).
            leaky_relu_backward(&acts.inputs[i], &mut dx, LEAKY_SLOPE);
        }
        g = dx;
    }
    g
}
