//! Numerical stress suite (issue #7), format half: half-precision range, rounding and
//! subnormals in the EXR level codec and the weights codec, and non-finite values.

use dnr_format::exr_codec::{decode_level, encode_level, LevelExpect, HALF_MAX};
use dnr_format::model::DType;
use dnr_format::weights::{decode_tensor, encode_tensor};
use dnr_format::{LevelCompression, Limits, TextureLevel};
use half::f16;

/// A 3x2, 2-channel level of small values with `v` at texel (2, 1) channel C01.
fn level_with(v: f32) -> TextureLevel {
    let mut l = TextureLevel {
        width: 3,
        height: 2,
        channels: 2,
        data: (0..12).map(|i| i as f32 * 0.25 - 1.0).collect(),
    };
    l.data[(3 + 2) * 2 + 1] = v;
    l
}

const EXPECT: LevelExpect = LevelExpect {
    width: 3,
    height: 2,
    channels: 2,
};

#[test]
fn level_values_beyond_the_half_range_are_errors_naming_level_channel_and_texel() {
    // 65519.9 rounds to 65504 in f16 and 65520 to infinity; both are beyond the range the
    // spec allows (|x| <= 65504), as are infinities and NaN.
    for v in [
        65504.01f32,
        65519.9,
        65520.0,
        -65520.0,
        1e10,
        f32::MAX,
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::NAN,
    ] {
        let e = encode_level(&level_with(v), 3, LevelCompression::Zip)
            .expect_err(&format!("{v} accepted"))
            .to_string();
        assert!(
            e.contains("level 3") && e.contains("C01") && e.contains("(2, 1)"),
            "{v}: {e}"
        );
    }
    assert_eq!(f16::from_f32(65520.0), f16::INFINITY, "premise of the test");
    // The extremes themselves are fine and exact.
    for v in [HALF_MAX, -HALF_MAX] {
        let bytes = encode_level(&level_with(v), 0, LevelCompression::Piz).unwrap();
        let back = decode_level(&bytes, EXPECT, &Limits::default()).unwrap();
        assert_eq!(back.data[11], v);
    }
}

/// Values that exercise f16 rounding: subnormals, the smallest normal, ties, negative zero.
fn awkward_values() -> Vec<f32> {
    vec![
        1e-7,
        6e-8,
        -6e-8,
        5.960_464_5e-8, // smallest f16 subnormal (2^-24)
        2.9e-8,         // rounds to 0
        3.0e-8,         // rounds up to the smallest subnormal
        6.1e-5,         // just below the smallest normal
        6.103_515_6e-5, // smallest normal (2^-14)
        -0.0,
        1e-30,
        0.1,
        1.0 / 3.0,
        2049.0, // tie between 2048 and 2050
        -1e4,
    ]
}

#[test]
fn subnormals_and_rounding_round_trip_as_f16_does_in_every_compression() {
    let values = awkward_values();
    let level = TextureLevel {
        width: values.len() as u32,
        height: 1,
        channels: 1,
        data: values.clone(),
    };
    let expect = LevelExpect {
        width: level.width,
        height: 1,
        channels: 1,
    };
    for c in LevelCompression::ALL {
        let bytes = encode_level(&level, 0, c).unwrap();
        let back = decode_level(&bytes, expect, &Limits::default()).unwrap();
        for (&v, &b) in values.iter().zip(&back.data) {
            let want = f16::from_f32(v);
            assert_eq!(
                b.to_bits(),
                want.to_f32().to_bits(),
                "{c:?}: {v} came back as {b}, f16 gives {want}"
            );
        }
    }
    // Spot checks of the premises: 1e-7 and 6e-8 are f16 subnormals, not zero.
    let sub = f16::from_f32(1e-7);
    assert!(!sub.is_normal() && sub != f16::ZERO);
    assert_eq!(f16::from_f32(6e-8).to_f32(), 5.960_464_5e-8);
}

#[test]
fn weights_beyond_the_half_range_are_errors_naming_the_tensor_and_element() {
    for v in [65519.9f32, 65520.0, -1e5, f32::INFINITY, f32::NAN] {
        let data = [0.5, -2.0, v, 1.0];
        let e = encode_tensor("encoder.1.weight", &data, &DType::F16)
            .expect_err(&format!("{v} accepted"))
            .to_string();
        assert!(
            e.contains("encoder.1.weight") && e.contains("element 2"),
            "{v}: {e}"
        );
    }
    // f32 storage takes large finite values but still refuses non-finite ones.
    assert!(encode_tensor("w", &[65520.0, -1e30], &DType::F32).is_ok());
    for v in [f32::NAN, f32::NEG_INFINITY] {
        let e = encode_tensor("w", &[0.0, v], &DType::F32)
            .unwrap_err()
            .to_string();
        assert!(e.contains("`w` element 1"), "{e}");
    }
}

#[test]
fn weight_subnormals_round_trip_as_f16_does() {
    let mut values = awkward_values();
    values.extend([HALF_MAX, -HALF_MAX]);
    let bytes = encode_tensor("t", &values, &DType::F16).unwrap();
    let back = decode_tensor(
        &bytes,
        &[values.len() as u32],
        &DType::F16,
        &Limits::default(),
    )
    .unwrap();
    for (&v, &b) in values.iter().zip(&back) {
        assert_eq!(b.to_bits(), f16::from_f32(v).to_f32().to_bits(), "{v}");
        assert!(b.is_finite());
    }
    // And f32 storage is exact, subnormals of f32 included.
    let tiny = [1e-45f32, -1e-40, f32::MIN_POSITIVE];
    let bytes = encode_tensor("t", &tiny, &DType::F32).unwrap();
    let back = decode_tensor(&bytes, &[3], &DType::F32, &Limits::default()).unwrap();
    assert_eq!(back, tiny);
}

#[test]
fn limits_can_be_raised_by_name() {
    let mut l = dnr_format::Limits::default();
    l.set("max_texture_side=32768").unwrap();
    assert_eq!(l.max_texture_side, 32768);
    l.set(" max_weight_elements = 5 ").unwrap();
    assert_eq!(l.max_weight_elements, 5);
    for (name, _) in dnr_format::Limits::default().entries() {
        l.set(&format!("{name}=7")).unwrap();
    }
    assert!(l.entries().iter().all(|(_, v)| *v == 7));
    let e = l.set("max_texture_sides=1").unwrap_err();
    assert!(e.contains("max_texture_side"), "{e}");
    assert!(l.set("max_levels=4294967296").is_err());
    assert!(l.set("max_levels=x").is_err());
    assert!(l.set("max_levels").is_err());
}
