//! The bodies of the `cargo fuzz` targets, shared with stable `cargo test`.
//!
//! The targets in `fuzz/` call these bodies, kept here so that stable `cargo test` replays the
//! committed corpus and every regression file through exactly the same code
//! (`tests/fuzz_replay.rs`). Each body must return normally for every input: errors are fine,
//! panics and unbounded allocations are the bugs the fuzzers look for.

use std::path::Path;

use dnr_format::exr_codec::{decode_level, LevelExpect};
use dnr_format::model::DType;
use dnr_format::weights::decode_tensor;
use dnr_format::{read_asset_from_slice_with_limits, validate_slice, Limits};

/// Limits small enough that a fuzzer's input cannot ask for gigabytes, large enough for
/// every sample in `samples/`.
pub fn fuzz_limits() -> Limits {
    Limits {
        max_texture_side: 1024,
        max_total_texel_values: 1 << 22,
        max_weight_elements: 1 << 22,
        ..Limits::default()
    }
}

/// A whole asset (GLB or glTF JSON): the validator and the reader.
pub fn asset_reader(data: &[u8]) {
    let limits = fuzz_limits();
    let _ = validate_slice(data, None, &limits);
    let _ = read_asset_from_slice_with_limits(data, &limits);
}

/// One EXR texture level. The first 3 bytes choose the declared width, height (1..=256)
/// and channel count (1..=32) the level is checked against; the rest is the EXR file.
pub fn exr_level(data: &[u8]) {
    let [w, h, c, rest @ ..] = data else { return };
    let expect = LevelExpect {
        width: u32::from(*w) + 1,
        height: u32::from(*h) + 1,
        channels: u32::from(*c % 32) + 1,
    };
    let _ = decode_level(rest, expect, &fuzz_limits());
}

/// One quantised PNG texture level (revision 1.1). The first 4 bytes choose the declared
/// width, height (1..=256), channel count (1..=32) and bits (even: 8, odd: 4); every channel
/// has scale 1/64 and offset -1; the rest is the PNG file.
pub fn png_level(data: &[u8]) {
    let [w, h, c, b, rest @ ..] = data else {
        return;
    };
    let channels = u32::from(*c % 32) + 1;
    let expect = LevelExpect {
        width: u32::from(*w) + 1,
        height: u32::from(*h) + 1,
        channels,
    };
    let q = dnr_format::model::Quantization {
        bits: if b % 2 == 0 { 8 } else { 4 },
        scale: vec![1.0 / 64.0; channels as usize],
        offset: vec![-1.0; channels as usize],
        ..Default::default()
    };
    let _ = dnr_format::quant::decode_png_level(rest, expect, &q, &fuzz_limits());
}

/// One weights tensor. Byte 0 chooses the dtype (`% 4`: f16, f32, int8, int4) and the rank
/// (`/ 4 % 4 + 1`), the next 4 bytes per dimension the shape (little-endian u32, as a hostile file
/// could claim); the rest is the tensor data.
pub fn weights(data: &[u8]) {
    let Some((&head, mut rest)) = data.split_first() else {
        return;
    };
    let dtype = match head % 4 {
        0 => DType::F16,
        1 => DType::F32,
        2 => DType::Int8,
        _ => DType::Int4,
    };
    let rank = usize::from(head / 4 % 4) + 1;
    let mut shape = Vec::with_capacity(rank);
    for _ in 0..rank {
        let Some((dim, tail)) = rest.split_first_chunk::<4>() else {
            return;
        };
        shape.push(u32::from_le_bytes(*dim));
        rest = tail;
    }
    let _ = decode_tensor(rest, &shape, &dtype, &fuzz_limits());
}

/// A capture's `transforms.json` text: parsing, every frame's intrinsics and matrix checks.
pub fn transforms(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let _ = dnr_bake::capture::transforms::check_transforms_text(
        Path::new("transforms.json"),
        text,
        4096,
        (64, 48),
    );
}

/// A fuzz target body: takes any bytes, must return normally.
pub type Target = fn(&[u8]);

/// The targets by name, as `fuzz/fuzz_targets/<name>.rs` and `fuzz/corpus/<name>/` call them.
pub const TARGETS: [(&str, Target); 5] = [
    ("asset_reader", asset_reader),
    ("exr_level", exr_level),
    ("png_level", png_level),
    ("weights", weights),
    ("transforms", transforms),
];

/// Seed inputs for a target, made from `samples/` and small encoded examples (the corpus
/// `fuzz/corpus/<name>/` starts from these; see `examples/fuzz_seeds.rs`).
pub fn seeds(name: &str) -> Vec<Vec<u8>> {
    use dnr_format::exr_codec::{encode_level, LevelCompression, TextureLevel};
    use dnr_format::weights::encode_tensor;
    let samples = crate::samples_dir();
    let files_in = |dirs: &[&str], exts: &[&str]| -> Vec<Vec<u8>> {
        let mut out = Vec::new();
        for d in dirs {
            let Ok(entries) = std::fs::read_dir(samples.join(d)) else {
                continue;
            };
            let mut paths: Vec<_> = entries.flatten().map(|e| e.path()).collect();
            paths.sort();
            for p in paths {
                let ext = p.extension().and_then(|e| e.to_str()).unwrap_or("");
                if exts.contains(&ext) {
                    if let Ok(bytes) = std::fs::read(&p) {
                        out.push(bytes);
                    }
                }
            }
        }
        out
    };
    match name {
        "asset_reader" => files_in(&["valid", "invalid", "warnings"], &["glb", "gltf"]),
        "exr_level" => {
            let mut out = Vec::new();
            for (i, comp) in LevelCompression::ALL.into_iter().enumerate() {
                let (w, h, c) = (3 + i as u32, 2 + 2 * i as u32, [3, 16, 1, 4, 12][i]);
                let data = (0..w * h * c).map(|k| ((k * 37 % 101) as f32 - 50.0) / 7.0);
                let level = TextureLevel {
                    width: w,
                    height: h,
                    channels: c,
                    data: data.collect(),
                };
                if let Ok(bytes) = encode_level(&level, 0, comp) {
                    let mut input = vec![(w - 1) as u8, (h - 1) as u8, (c - 1) as u8];
                    input.extend(bytes);
                    out.push(input);
                }
            }
            out
        }
        "weights" => {
            let mut out = Vec::new();
            for (dtype, shape, first_scale) in [
                (DType::F16, vec![4u32, 3], None),
                (DType::F32, vec![2, 3, 4, 4], None),
                (DType::F16, vec![7], None),
                (DType::Int8, vec![3, 5], None),
                (DType::Int8, vec![2, 3, 4, 4], None),
                (DType::Int4, vec![3, 5], None),
                (DType::Int4, vec![2, 3, 4, 4], None),
                // Hostile scales: zero and NaN.
                (DType::Int4, vec![3, 5], Some(0.0f32)),
                (DType::Int8, vec![3, 5], Some(f32::NAN)),
            ] {
                let n: u32 = shape.iter().product();
                let data: Vec<f32> = (0..n).map(|k| k as f32 * 0.25 - 1.0).collect();
                let encoded = match dtype {
                    DType::Int8 | DType::Int4 => {
                        dnr_format::weights::encode_int("t", &shape, &data, &dtype)
                    }
                    _ => encode_tensor("t", &data, &dtype),
                };
                let Ok(mut bytes) = encoded else {
                    continue;
                };
                if let (Some(s), Some(values)) =
                    (first_scale, dtype.integer_value_bytes(u64::from(n)))
                {
                    let at = (values as usize).next_multiple_of(4);
                    bytes[at..at + 4].copy_from_slice(&s.to_le_bytes());
                }
                let kind = match dtype {
                    DType::F16 => 0,
                    DType::F32 => 1,
                    DType::Int8 => 2,
                    _ => 3,
                };
                let code = kind + 4 * (shape.len() as u8 - 1);
                let mut input = vec![code];
                shape
                    .iter()
                    .for_each(|d| input.extend_from_slice(&d.to_le_bytes()));
                input.extend(bytes);
                out.push(input);
            }
            out
        }
        "png_level" => {
            let mut out = Vec::new();
            for (i, bits) in [8u32, 4, 8, 4].into_iter().enumerate() {
                let (w, h, c) = (3 + i as u32, 2 + i as u32, [3, 6, 9, 16][i]);
                let data = (0..w * h * c).map(|k| ((k * 37 % 101) as f32 - 50.0) / 64.0);
                let level = TextureLevel {
                    width: w,
                    height: h,
                    channels: c,
                    data: data.collect(),
                };
                if let Ok((_, png)) = dnr_format::quant::encode_png_level(&level, bits) {
                    let b = u8::from(bits == 4);
                    let mut input = vec![(w - 1) as u8, (h - 1) as u8, (c - 1) as u8, b];
                    input.extend(png);
                    out.push(input);
                }
            }
            out
        }
        "transforms" => {
            let mut out = files_in(&["capture"], &["json"]);
            out.push(
                br#"{"fl_x": 50, "fl_y": 50, "cx": 32, "cy": 24, "w": 64, "h": 48,
                "frames": [{"file_path": "a", "transform_matrix":
                [[1,0,0,0],[0,1,0,0],[0,0,1,3],[0,0,0,1]], "k1": 0.01}]}"#
                    .to_vec(),
            );
            out
        }
        _ => Vec::new(),
    }
}
