//! Low layer: weight tensors as little-endian `f16`/`f32`, or (revision 1.1) `int8` with a
//! per-row `f32` scale; row-major, CRC-32 checked.

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
        DType::Int8 => Err(Error::invalid(format!(
            "tensor `{name}`: int8 needs the shape (encode_int8)"
        ))),
        DType::Unknown(s) => Err(Error::not_supported(format!("dtype `{s}`"))),
    }
}

/// Per-row symmetric scales of an `int8` tensor: `max |x| / 127` of each first-axis row, 1
/// for an all-zero row (its values are then 0 exactly).
pub fn int8_fit_scales(shape: &[u32], data: &[f32]) -> Vec<f32> {
    let rows = int8_rows(shape).max(1) as usize;
    let per = data.len() / rows;
    (0..rows)
        .map(|r| {
            let m = data[r * per..(r + 1) * per]
                .iter()
                .fold(0.0f32, |a, v| a.max(v.abs()));
            let s = m / 127.0;
            if s.is_normal() {
                s
            } else {
                1.0
            }
        })
        .collect()
}

/// The nearest `int8` step of `v`, in `-127..=127`.
#[inline]
pub fn int8_quantise(v: f32, scale: f32) -> i8 {
    (v / scale).round().clamp(-127.0, 127.0) as i8
}

/// The normative `int8` dequantisation: `scale * q` in `f32`.
#[inline]
pub fn int8_dequantise(q: i8, scale: f32) -> f32 {
    scale * f32::from(q)
}

/// Encodes a tensor as `int8`: the `product(shape)` values, zero padding to a multiple of 4
/// bytes, then one little-endian `f32` scale per first-axis row.
pub fn encode_int8(name: &str, shape: &[u32], data: &[f32]) -> Result<Vec<u8>> {
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
    let scales = int8_fit_scales(shape, data);
    let per = data.len() / scales.len();
    let mut out: Vec<u8> = data
        .iter()
        .enumerate()
        .map(|(i, &v)| int8_quantise(v, scales[i / per.max(1)]) as u8)
        .collect();
    out.resize(out.len().next_multiple_of(4), 0);
    out.extend(scales.iter().flat_map(|s| s.to_le_bytes()));
    Ok(out)
}

/// The scales of an `int8` tensor's bytes (after its values and padding), `None` when the
/// bytes are too short.
pub fn int8_scales(bytes: &[u8], shape: &[u32]) -> Option<Vec<f32>> {
    let n = usize::try_from(element_count(shape).ok()?).ok()?;
    let rows = usize::try_from(int8_rows(shape)).ok()?;
    let at = n.next_multiple_of(4);
    let raw = bytes.get(at..at.checked_add(rows.checked_mul(4)?)?)?;
    Some(
        raw.chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect(),
    )
}

/// Values of an `int8` tensor's bytes that decode to an infinity (`scale * q` overflows
/// `f32`); 0 when the bytes are too short to hold the values and scales. Scales that are not
/// finite and above 0 are not counted here (they are a problem of their own).
pub fn int8_non_finite(bytes: &[u8], shape: &[u32]) -> usize {
    let Some(scales) = int8_scales(bytes, shape) else {
        return 0;
    };
    let Some(n) = element_count(shape)
        .ok()
        .and_then(|n| usize::try_from(n).ok())
    else {
        return 0;
    };
    // `int8_scales` found the scales after the values, so `n <= bytes.len()`.
    let per = (n / scales.len().max(1)).max(1);
    bytes[..n]
        .iter()
        .enumerate()
        .filter(|&(i, &b)| {
            let s = scales[i / per];
            s.is_finite() && s > 0.0 && !int8_dequantise(b as i8, s).is_finite()
        })
        .count()
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
    if *dtype == DType::Int8 {
        let scales = int8_scales(bytes, shape).ok_or_else(|| {
            Error::invalid(format!(
                "int8 tensor of shape {shape:?} needs its values and scales, {} bytes available",
                bytes.len()
            ))
        })?;
        if let Some(r) = scales.iter().position(|s| !(s.is_finite() && *s > 0.0)) {
            return Err(Error::invalid(format!(
                "int8 scale of row {r} is {}, must be finite and above 0",
                scales[r]
            )));
        }
        let per = n / scales.len().max(1);
        return Ok(bytes[..n]
            .iter()
            .enumerate()
            .map(|(i, &b)| int8_dequantise(b as i8, scales[i / per.max(1)]))
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
/// `buffer_view` set to `buffer_view`. With `int8`, tensors of rank 2 or more are stored as
/// `int8` and the others (biases) as `f16`: a per-row scale of a rank-1 tensor would cost
/// more bytes than `f16`.
pub fn pack_tensors<'a>(
    tensors: impl IntoIterator<Item = (&'a str, &'a TensorF32)>,
    dtype: &DType,
    buffer_view: u32,
) -> Result<(Vec<u8>, Vec<WeightTensor>)> {
    let mut blob = Vec::new();
    let mut descriptors = Vec::new();
    for (name, tensor) in tensors {
        if element_count(&tensor.shape)? != tensor.data.len() as u64 {
            return Err(Error::invalid(format!(
                "tensor `{name}` of shape {:?} has {} values",
                tensor.shape,
                tensor.data.len()
            )));
        }
        let dtype = match dtype {
            DType::Int8 if tensor.shape.len() < 2 => &DType::F16,
            d => d,
        };
        let bytes = match dtype {
            DType::Int8 => encode_int8(name, &tensor.shape, &tensor.data)?,
            d => encode_tensor(name, &tensor.data, d)?,
        };
        let offset = blob.len() as u64;
        descriptors.push(WeightTensor {
            name: name.to_string(),
            shape: tensor.shape.clone(),
            dtype: dtype.clone(),
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
