//! Channel concatenation (the U-Net skip): forward is `Tensor::concat`.

use dnr_runtime::nn::Tensor;

/// Backward of `concat(a, b)`: dy `(ca + cb) x H x W`; adds the first `da.c` channels to `da`
/// and the rest to `db`.
pub fn concat_backward(dy: &Tensor, da: &mut Tensor, db: &mut Tensor) {
    assert!(
        dy.c == da.c + db.c && dy.h == da.h && dy.w == da.w && da.h == db.h && da.w == db.w,
        "concat backward shape"
    );
    let split = da.data.len();
    da.data
        .iter_mut()
        .zip(&dy.data[..split])
        .for_each(|(d, s)| *d += s);
    db.data
        .iter_mut()
        .zip(&dy.data[split..])
        .for_each(|(d, s)| *d += s);
}
