//! Low layer: weight tensors as little-endian `f16`/`f32`, or (revision 1.1) `int8` or
//! (revision 1.2) `int4` with a per-row `f32` scale; row-major, CRC-32 checked.

use half::f16;

use crate::error::{Error, Result};
use crate::limits::Limits;
use crate::model::{int8_rows, DType, WeightTensor};

/// A decoded tensor: `shape` and row-major `f32` data.
#[derive(Clone, Debug, PartialEq)]
pub struct TensorF32 {
    /// Shape, row-major (C order).
    pub shape: Vec<u32>,
    /// `product(shape)` values.
    pub data: Vec<f32>,
}

impl TensorF32 {
    /// A tensor, checking that `data` has `product(shape)` values.
    pub fn new(shape: Vec<u32>, data: Vec<f32>) -> Result<Self> {
        let n = element_count(&shape)?;
        if n != data.len() as u64 {
            return Err(Error::invalid(format!(
                "tensor of shape {shape:?} needs {n} values, has {}",
                data.len()
            )));
        }
        Ok(TensorF32 { shape, data })
    }
}

/// Product of a shape, `Invalid` on overflow.
pub fn element_count(shape: &[u32]) -> Result<u64> {
    shape
        .iter()
        .try_fold(1u64, |a, &d| a.checked_mul(u64::from(d)))
        .ok_or_else(|| Error::invalid(format!("shape {shape:?} overflows")))
}

/// CRC-32/ISO-HDLC (zlib's `crc32`).
pub fn crc32(bytes: &[u8]) -> u32 {
    crc32fast::hash(bytes)
}

/// Encodes `data` as `dtype`, little-endian. Every value must be finite and, for `f16`,
/// within the half range; the error names the tensor and the element.
pub fn encode_tensor(name: &str, data: &[f32], dtype: &DType) -> Result<Vec<u8>> {
    if let Some(i) = data.iter().position(|v| !v.is_finite()) {
        return Err(Error::invalid(format!(
            "tensor `{name}` element {i} is {}",
            data[i]
        )));
    }
    match dtype {
        DType::F32 => Ok(data.iter().flat_map(|v| v.to_le_bytes()).collect()),
        DType::F16 => {
            if let Some(i) = data
                .iter()
                .position(|v| v.abs() > crate::exr_codec::HALF_MAX)
            {
                return Err(Error::invalid(format!(
                    "tensor `{name}` element {i} is {}, beyond the f16 range",
                    data[i]
                )));
            }
            Ok(data
                .iter()
                .flat_map(|&v| f16::from_f32(v).to_le_bytes())
                .collect())
        }
        DType::Int8 | DType::Int4 => Err(Error::invalid(format!(
            "tensor `{name}`: {dtype} needs the shape (encode_int)"
        ))),
        DType::Unknown(s) => Err(Error::not_supported(format!("dtype `{s}`"))),
    }
}

/// Per-row symmetric scales of an `int8` tensor: `max |x| / 127` of each first-axis row, 1
/// for an all-zero row (its values are then 0 exactly).
pub fn int8_fit_scales(shape: &[u32], data: &[f32]) -> Vec<f32> {
    int_fit_scales(shape, data, &DType::Int8)
}

/// Fractions of a row's largest magnitude that `int4` scales may clip at (the largest `|q|`
/// is 7): 15 candidates from the full range down to 0.3 of it.
pub const INT4_CLIPS: [f32; 15] = [
    1.0, 0.95, 0.9, 0.85, 0.8, 0.75, 0.7, 0.65, 0.6, 0.55, 0.5, 0.45, 0.4, 0.35, 0.3,
];

/// Per-row symmetric scales for an integer `dtype`, 1 for an all-zero row. `int8`: `max |x|
/// / 127` (every value within half a step). `int4`: of the ranges clipped at
/// [`INT4_CLIPS`] of `max |x|`, the one with the least squared rounding error over the row:
/// with 15 steps, spending them on the bulk of a heavy-tailed row beats covering its
/// extremes. A writer's choice; readers only apply `scale * q`.
pub fn int_fit_scales(shape: &[u32], data: &[f32], dtype: &DType) -> Vec<f32> {
    let top = dtype.integer_top().unwrap_or(127.0);
    let rows = int8_rows(shape).max(1) as usize;
    let per = data.len() / rows;
    (0..rows)
        .map(|r| {
            let row = &data[r * per..(r + 1) * per];
            let m = row.iter().fold(0.0f32, |a, v| a.max(v.abs()));
            let clips: &[f32] = if *dtype == DType::Int4 {
                &INT4_CLIPS
            } else {
                &[1.0]
            };
            let mut best = (f64::INFINITY, 1.0f32);
            for &f in clips {
                let s = m * f / top;
                if !s.is_normal() {
                    continue;
                }
                let err: f64 = row
                    .iter()
                    .map(|&v| {
                        let d = int8_dequantise(int_quantise(v, s, top), s) - v;
                        f64::from(d * d)
                    })
                    .sum();
                if err < best.0 {
                    best = (err, s);
                }
            }
            best.1
        })
        .collect()
}

/// The nearest integer step of `v` in `-top..=top` (127 for `int8`, 7 for `int4`).
#[inline]
pub fn int_quantise(v: f32, scale: f32, top: f32) -> i8 {
    (v / scale).round().clamp(-top, top) as i8
}

/// The nearest `int8` step of `v`, in `-127..=127`.
#[inline]
pub fn int8_quantise(v: f32, scale: f32) -> i8 {
    int_quantise(v, scale, 127.0)
}

/// The normative dequantisation of `int8` and `int4` values: `scale * q` in `f32`.
#[inline]
pub fn int8_dequantise(q: i8, scale: f32) -> f32 {
    scale * f32::from(q)
}

/// Element `e` of an integer tensor's value bytes: a byte (`int8`), or a nibble (`int4`: the
/// low one for even `e`), two's complement. `bytes` must hold it.
#[inline]
fn int_value(bytes: &[u8], e: usize, dtype: &DType) -> i8 {
    if *dtype == DType::Int4 {
        let nibble = (bytes[e / 2] >> (4 * (e % 2))) & 0x0F;
        // Sign-extend the 4-bit value.
        ((nibble << 4) as i8) >> 4
    } else {
        bytes[e] as i8
    }
}

/// Encodes a tensor as `int8`: the `product(shape)` values, zero padding to a multiple of 4
/// bytes, then one little-endian `f32` scale per first-axis row.
pub fn encode_int8(name: &str, shape: &[u32], data: &[f32]) -> Result<Vec<u8>> {
    encode_int(name, shape, data, &DType::Int8)
}

/// Encodes a tensor as `int8` or `int4` ([`int_fit_scales`]): the values (`int4`: two per
/// byte, low nibble first), zero padding to a multiple of 4 bytes, then one little-endian
/// `f32` scale per first-axis row.
pub fn encode_int(name: &str, shape: &[u32], data: &[f32], dtype: &DType) -> Result<Vec<u8>> {
    let top = dtype.integer_top().ok_or_else(|| {
        Error::invalid(format!("tensor `{name}`: {dtype} is not an integer type"))
    })?;
    if let Some(i) = data.iter().position(|v| !v.is_finite()) {
        return Err(Error::invalid(format!(
            "tensor `{name}` element {i} is {}",
            data[i]
        )));
    }
    if element_count(shape)? != data.len() as u64 {
        return Err(Error::invalid(format!(
            "tensor `{name}` of shape {shape:?} has {} values",
            data.len()
        )));
    }
    let scales = int_fit_scales(shape, data, dtype);
    let per = (data.len() / scales.len()).max(1);
    let q = data
        .iter()
        .enumerate()
        .map(|(i, &v)| int_quantise(v, scales[i / per], top) as u8);
    let mut out: Vec<u8> = if *dtype == DType::Int4 {
        let q: Vec<u8> = q.collect();
        q.chunks(2)
            .map(|p| (p[0] & 0x0F) | (p.get(1).copied().unwrap_or(0) << 4))
            .collect()
    } else {
        q.collect()
    };
    out.resize(out.len().next_multiple_of(4), 0);
    out.extend(scales.iter().flat_map(|s| s.to_le_bytes()));
    Ok(out)
}

/// The scales of an `int8` tensor's bytes (after its values and padding), `None` when the
/// bytes are too short.
pub fn int8_scales(bytes: &[u8], shape: &[u32]) -> Option<Vec<f32>> {
    int_scales(bytes, shape, &DType::Int8)
}

/// The scales of an `int8` or `int4` tensor's bytes (after its values and padding), `None`
/// when the bytes are too short or `dtype` is not an integer type.
pub fn int_scales(bytes: &[u8], shape: &[u32], dtype: &DType) -> Option<Vec<f32>> {
    let n = dtype.integer_value_bytes(element_count(shape).ok()?)?;
    let n = usize::try_from(n).ok()?;
    let rows = usize::try_from(int8_rows(shape)).ok()?;
    let at = n.next_multiple_of(4);
    let raw = bytes.get(at..at.checked_add(rows.checked_mul(4)?)?)?;
    Some(
        raw.chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect(),
    )
}

/// Values of an `int8` or `int4` tensor's bytes that decode to an infinity (`scale * q`
/// overflows `f32`); 0 when the bytes are too short to hold the values and scales. Scales
/// that are not finite and above 0 are not counted here (they are a problem of their own).
pub fn int_non_finite(bytes: &[u8], shape: &[u32], dtype: &DType) -> usize {
    let Some(scales) = int_scales(bytes, shape, dtype) else {
        return 0;
    };
    let Some(n) = element_count(shape)
        .ok()
        .and_then(|n| usize::try_from(n).ok())
    else {
        return 0;
    };
    // `int_scales` found the scales after the values, so the values are in `bytes`.
    let per = (n / scales.len().max(1)).max(1);
    (0..n)
        .filter(|&e| {
            let s = scales[e / per];
            s.is_finite() && s > 0.0 && !int8_dequantise(int_value(bytes, e, dtype), s).is_finite()
        })
        .count()
}

/// [`int_non_finite`] of an `int8` tensor.
pub fn int8_non_finite(bytes: &[u8], shape: &[u32]) -> usize {
    int_non_finite(bytes, shape, &DType::Int8)
}

/// Decodes exactly `product(shape)` elements of `dtype` from the start of `bytes`,
/// after checking the count against `limits.max_weight_elements`.
pub fn decode_tensor(
    bytes: &[u8],
    shape: &[u32],
    dtype: &DType,
    limits: &Limits,
) -> Result<Vec<f32>> {
    let size = dtype
        .size_of()
        .ok_or_else(|| Error::not_supported(format!("dtype `{dtype}`")))?;
    let n = Limits::checked_len(
        "tensor elements",
        element_count(shape)?,
        limits.max_weight_elements,
    )?;
    if dtype.integer_top().is_some() {
        let scales = int_scales(bytes, shape, dtype).ok_or_else(|| {
            Error::invalid(format!(
                "{dtype} tensor of shape {shape:?} needs its values and scales, {} bytes available",
                bytes.len()
            ))
        })?;
        if let Some(r) = scales.iter().position(|s| !(s.is_finite() && *s > 0.0)) {
            return Err(Error::invalid(format!(
                "{dtype} scale of row {r} is {}, must be finite and above 0",
                scales[r]
            )));
        }
        let per = (n / scales.len().max(1)).max(1);
        return Ok((0..n)
            .map(|e| int8_dequantise(int_value(bytes, e, dtype), scales[e / per]))
            .collect());
    }
    let len = n
        .checked_mul(size)
        .ok_or_else(|| Error::invalid("tensor byte length overflows"))?;
    let bytes = bytes.get(..len).ok_or_else(|| {
        Error::invalid(format!(
            "tensor needs {len} bytes, {} available",
            bytes.len()
        ))
    })?;
    Ok(match dtype {
        DType::F16 => bytes
            .chunks_exact(2)
            .map(|b| f16::from_le_bytes([b[0], b[1]]).to_f32())
            .collect(),
        _ => bytes
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect(),
    })
}

/// Packs tensors one after another into one blob (each start 4-byte aligned, zero
/// padding) and returns the blob and one descriptor per tensor, in input order, with
/// `buffer_view` set to `buffer_view`. With `int8` or `int4`, tensors of rank 2 or more are
/// stored so and the others (biases) as `f16`: a per-row scale of a rank-1 tensor would cost
/// more bytes than `f16`.
pub fn pack_tensors<'a>(
    tensors: impl IntoIterator<Item = (&'a str, &'a TensorF32)>,
    dtype: &DType,
    buffer_view: u32,
) -> Result<(Vec<u8>, Vec<WeightTensor>)> {
    pack_tensors_each(
        tensors.into_iter().map(|(n, t)| (n, t, dtype.clone())),
        buffer_view,
    )
}

/// [`pack_tensors`] with a type for each tensor.
pub fn pack_tensors_each<'a>(
    tensors: impl IntoIterator<Item = (&'a str, &'a TensorF32, DType)>,
    buffer_view: u32,
) -> Result<(Vec<u8>, Vec<WeightTensor>)> {
    let mut blob = Vec::new();
    let mut descriptors = Vec::new();
    for (name, tensor, dtype) in tensors {
        if element_count(&tensor.shape)? != tensor.data.len() as u64 {
            return Err(Error::invalid(format!(
                "tensor `{name}` of shape {:?} has {} values",
                tensor.shape,
                tensor.data.len()
            )));
        }
        let dtype = if dtype.integer_top().is_some() && tensor.shape.len() < 2 {
            DType::F16
        } else {
            dtype
        };
        let bytes = if dtype.integer_top().is_some() {
            encode_int(name, &tensor.shape, &tensor.data, &dtype)?
        } else {
            encode_tensor(name, &tensor.data, &dtype)?
        };
        let offset = blob.len() as u64;
        descriptors.push(WeightTensor {
            name: name.to_string(),
            shape: tensor.shape.clone(),
            dtype,
            buffer_view,
            byte_offset: offset,
            crc32: crc32(&bytes),
            extensions: None,
            extras: None,
            others: Default::default(),
        });
        blob.extend_from_slice(&bytes);
        blob.resize(blob.len().next_multiple_of(4), 0);
    }
    Ok((blob, descriptors))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc_is_zlib() {
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
    }

    #[test]
    fn round_trip_and_alignment() {
        let a = TensorF32::new(vec![3], vec![1.0, -2.5, 0.125]).unwrap();
        let b = TensorF32::new(vec![1, 2], vec![7.0, 8.0]).unwrap();
        for dtype in [DType::F16, DType::F32] {
            let (blob, d) = pack_tensors([("a", &a), ("b", &b)], &dtype, 5).unwrap();
            assert_eq!(d[1].byte_offset % 4, 0);
            for (desc, t) in d.iter().zip([&a, &b]) {
                let at = &blob[desc.byte_offset as usize..];
                let len = desc.byte_length().unwrap() as usize;
                assert_eq!(crc32(&at[..len]), desc.crc32);
                let back = decode_tensor(at, &desc.shape, &dtype, &Limits::default()).unwrap();
                assert_eq!(back, t.data);
            }
        }
    }

    #[test]
    fn int4_round_trip_is_the_formula_with_nibbles_low_first() {
        // Row 0 heavy-tailed (one outlier), row 1 spread evenly; 5 values a row, so row 1
        // starts in the high nibble of byte 2.
        let w = TensorF32::new(
            vec![2, 5],
            vec![0.1, -0.12, 0.08, 0.05, 2.0, -0.7, 0.35, 0.0, 0.7, -0.35],
        )
        .unwrap();
        let (blob, d) = pack_tensors([("w", &w)], &DType::Int4, 0).unwrap();
        assert_eq!(d[0].dtype, DType::Int4);
        // 10 values in 5 bytes, 3 bytes padding, 2 scales.
        assert_eq!(d[0].byte_length(), Some(8 + 8));
        let scales = int_scales(&blob, &w.shape, &DType::Int4).unwrap();
        let back = decode_tensor(&blob, &w.shape, &DType::Int4, &Limits::default()).unwrap();
        for (e, (&a, &b)) in w.data.iter().zip(&back).enumerate() {
            let q = int_value(&blob, e, &DType::Int4);
            assert!((-7..=7).contains(&q), "{e}: {q}");
            assert_eq!(b, int8_dequantise(q, scales[e / 5]));
            if e >= 5 {
                // Row 1 is spanned whole: within half a step.
                assert!((a - b).abs() <= scales[1] * 0.5 + 1e-6, "{a} {b}");
            }
        }
        // Each row's scale rounds with no more squared error than the full range's.
        let sq = |row: &[f32], s: f32| -> f32 {
            row.iter()
                .map(|&v| (int8_dequantise(int_quantise(v, s, 7.0), s) - v).powi(2))
                .sum()
        };
        for (r, row) in w.data.chunks(5).enumerate() {
            let m = row.iter().fold(0.0f32, |a, v| a.max(v.abs()));
            assert!(sq(row, scales[r]) <= sq(row, m / 7.0), "row {r}");
        }
        // A long heavy-tailed row is clipped below its largest value.
        let long: Vec<f32> = (0..256)
            .map(|i| {
                if i == 7 {
                    1.0
                } else {
                    ((i * 37 % 101) as f32 / 101.0 - 0.5) * 0.2
                }
            })
            .collect();
        let s = int_fit_scales(&[1, 256], &long, &DType::Int4)[0];
        assert!(s < 1.0 / 7.0 && sq(&long, s) < sq(&long, 1.0 / 7.0), "{s}");
        // Sign extension: nibble 0xF is -1, 0x8 is -8 (never written, decoded as the formula).
        let mut neg = blob.clone();
        neg[0] = 0x8F;
        let back = decode_tensor(&neg, &w.shape, &DType::Int4, &Limits::default()).unwrap();
        assert_eq!((back[0], back[1]), (-scales[0], -8.0 * scales[0]));
        // Short bytes, a zero scale and an overflowing one are caught.
        assert!(decode_tensor(&blob[..12], &w.shape, &DType::Int4, &Limits::default()).is_err());
        let mut zero = blob.clone();
        zero[8..12].copy_from_slice(&0.0f32.to_le_bytes());
        assert!(decode_tensor(&zero, &w.shape, &DType::Int4, &Limits::default()).is_err());
        let mut big = blob.clone();
        big[8..12].copy_from_slice(&f32::MAX.to_le_bytes());
        assert!(int_non_finite(&big, &w.shape, &DType::Int4) > 0);
        assert_eq!(int_non_finite(&blob, &w.shape, &DType::Int4), 0);
    }

    #[test]
    fn int8_round_trip_is_the_formula() {
        let w = TensorF32::new(vec![3, 2], vec![0.5, -0.25, 0.0, 0.0, 3.0, 1.0]).unwrap();
        let b = TensorF32::new(vec![3], vec![0.1, 0.2, 0.3]).unwrap();
        let (blob, d) = pack_tensors([("w", &w), ("b", &b)], &DType::Int8, 0).unwrap();
        assert_eq!(
            (d[0].dtype.clone(), d[1].dtype.clone()),
            (DType::Int8, DType::F16)
        );
        // 6 values, 2 bytes padding, 3 scales.
        assert_eq!(d[0].byte_length(), Some(8 + 12));
        assert_eq!(d[1].byte_offset, 20);
        let back = decode_tensor(&blob, &w.shape, &DType::Int8, &Limits::default()).unwrap();
        assert_eq!(back[2..4], [0.0, 0.0]);
        for (a, b) in w.data.iter().zip(&back) {
            assert!((a - b).abs() <= 3.0 / 127.0 / 2.0 + 1e-6, "{a} {b}");
        }
        assert_eq!(back[0], int8_dequantise(127, 0.5 / 127.0));
        let mut zero = blob.clone();
        zero[8..12].copy_from_slice(&0.0f32.to_le_bytes());
        assert!(decode_tensor(&zero, &w.shape, &DType::Int8, &Limits::default()).is_err());
        assert!(decode_tensor(&blob[..10], &w.shape, &DType::Int8, &Limits::default()).is_err());
        assert_eq!(int8_non_finite(&blob, &w.shape), 0);
        assert_eq!(int8_non_finite(&blob[..10], &w.shape), 0);
        // A finite scale whose product with a stored value overflows: row 0 holds 127 and -64.
        let mut huge = blob.clone();
        huge[8..12].copy_from_slice(&f32::MAX.to_le_bytes());
        assert_eq!(int8_non_finite(&huge, &w.shape), 2);
        let back = decode_tensor(&huge, &w.shape, &DType::Int8, &Limits::default()).unwrap();
        assert!(back[..2].iter().all(|v| v.is_infinite()));
    }

    #[test]
    fn range_checked_before_narrowing() {
        assert!(encode_tensor("x", &[70000.0], &DType::F16).is_err());
        assert!(encode_tensor("x", &[70000.0], &DType::F32).is_ok());
        assert!(encode_tensor("x", &[f32::NAN], &DType::F32).is_err());
        let tight = Limits {
            max_weight_elements: 2,
            ..Limits::default()
        };
        assert!(matches!(
            decode_tensor(&[0; 12], &[3], &DType::F32, &tight),
            Err(Error::LimitExceeded { .. })
        ));
    }
}
