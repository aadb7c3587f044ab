//! Low layer: quantised levels (spec revision 1.1), stored as 8-bit RGBA PNG images with a
//! per-channel `scale` and `offset`.
//!
//! A level of `C` channels, `W x H` texels, quantised to `bits` (8 or 4) is one PNG of width
//! `W` and height `H * G`, `G = ceil(C / k)` channel groups stacked top to bottom, with
//! `k = 4` channels per RGBA texel at 8 bits and `k = 8` at 4 bits. Channel `c` lives in group
//! `c / k`; at 8 bits in component `c % 4`; at 4 bits in component `(c % 8) / 2`, low nibble
//! for even `c`, high nibble for odd `c`. The stack is the memory layout of a 2D texture
//! array of `G` layers, so a WebGL2 viewer uploads a decoded level in one `texImage3D` call.
//!
//! Dequantisation is normative: `value = offset[c] + scale[c] * q`, both operations rounded
//! to `f32` (no fused multiply-add), so every reader gets the same values.

use crate::container::Problem;
use crate::error::{Error, Result};
use crate::exr_codec::{LevelExpect, TextureLevel};
use crate::limits::Limits;
use crate::model::Quantization;

pub mod range;

/// The MIME type of a quantised level.
pub const PNG_MIME_TYPE: &str = "image/png";

/// Channels held by one RGBA8 texel at `bits` per value (4 or 8), `None` for other depths.
pub fn channels_per_texel(bits: u32) -> Option<u32> {
    match bits {
        8 => Some(4),
        4 => Some(8),
        _ => None,
    }
}

/// Largest integer a `bits`-bit value holds.
fn q_max(bits: u32) -> f32 {
    ((1u32 << bits) - 1) as f32
}

/// `(width, height)` of the PNG that holds a `width x height` level of `channels` at `bits`,
/// `None` for an unknown depth or an overflowing height.
pub fn png_size(width: u32, height: u32, channels: u32, bits: u32) -> Option<(u32, u32)> {
    let groups = channels.div_ceil(channels_per_texel(bits)?);
    Some((width, height.checked_mul(groups)?))
}

/// The normative dequantisation `offset + scale * q`, each operation rounded to `f32`.
#[inline]
pub fn dequantise(q: u8, scale: f32, offset: f32) -> f32 {
    // Rust never contracts this into a fused multiply-add.
    offset + scale * f32::from(q)
}

/// Problems of a `quantization` object against a texture of `channels` channels, as
/// `(code, field, message)`; empty when it is valid.
pub fn quantization_problems(
    q: &Quantization,
    channels: u32,
) -> Vec<(&'static str, &'static str, String)> {
    let mut out = Vec::new();
    if channels_per_texel(q.bits).is_none() {
        out.push((
            "QUANT_BITS",
            "bits",
            format!("bits is {}, must be 8 or 4", q.bits),
        ));
    }
    for (field, len) in [("scale", q.scale.len()), ("offset", q.offset.len())] {
        if len as u64 != u64::from(channels) {
            out.push((
                "QUANT_ARRAY_LENGTH",
                field,
                format!("{field} has {len} entries, the texture has {channels} channels"),
            ));
        }
    }
    let top = channels_per_texel(q.bits).map_or(255.0, |_| q_max(q.bits));
    for (c, (&s, &o)) in q.scale.iter().zip(&q.offset).enumerate() {
        // Largest value the channel can decode to must be finite too.
        if !(s.is_finite() && s > 0.0 && o.is_finite() && (o + s * top).is_finite()) {
            out.push((
                "QUANT_SCALE_INVALID",
                "scale",
                format!("channel {c}: scale {s}, offset {o}; scale must be finite and above 0, offset finite, offset + scale * {top} finite"),
            ));
        }
    }
    out
}

/// Per-channel `(scale, offset)` for `bits`-bit integers with the least squared rounding
/// error: the range may leave out a channel's rare extreme values, which then decode to the
/// range's ends ([`range`] says how it is searched; it is never worse than the full
/// minimum-to-maximum range). A constant channel gets scale 1 (every value then decodes to
/// `offset` exactly). A writer's choice, not the format's: readers only apply the formula.
pub fn fit_parameters(level: &TextureLevel, bits: u32) -> (Vec<f32>, Vec<f32>) {
    fit_parameters_hwc(&level.data, level.channels as usize, bits)
}

/// [`fit_parameters`] of texel-interleaved values with `channels` channels.
pub fn fit_parameters_hwc(data: &[f32], channels: usize, bits: u32) -> (Vec<f32>, Vec<f32>) {
    range::fit(data, channels, q_max(bits))
}

/// The integer nearest to `(v - offset) / scale` (halves away from zero), clamped to
/// `0..=2^bits-1`; NaN gives 0.
#[inline]
pub fn quantise(v: f32, scale: f32, offset: f32, bits: u32) -> u8 {
    round_in_range((v - offset) / scale, q_max(bits)) as u8
}

/// `x.round().clamp(0.0, top)` for an integer `top` below 2^23, without the library call
/// `round` compiles to on baseline x86-64 (the baker rounds every texel of every step).
#[inline]
pub(crate) fn round_in_range(x: f32, top: f32) -> f32 {
    // Clamping first is the same (the bounds are integers); then the integer part is exact
    // and so is the fraction `x - t`.
    let x = x.clamp(0.0, top);
    let t = x as u32 as f32;
    if x - t >= 0.5 {
        t + 1.0
    } else {
        t
    }
}

/// Rounds every value of `level` through `bits`-bit storage with the given parameters
/// (what a reader will decode), in place.
pub fn fake_quantise_level(level: &mut TextureLevel, scale: &[f32], offset: &[f32], bits: u32) {
    fake_quantise_hwc(&mut level.data, scale, offset, bits);
}

/// [`fake_quantise_level`] of texel-interleaved values (`scale.len()` channels).
pub fn fake_quantise_hwc(data: &mut [f32], scale: &[f32], offset: &[f32], bits: u32) {
    let c = scale.len().min(offset.len());
    for texel in data.chunks_exact_mut(c.max(1)) {
        for (k, v) in texel.iter_mut().enumerate() {
            *v = dequantise(quantise(*v, scale[k], offset[k], bits), scale[k], offset[k]);
        }
    }
}

/// Encodes a level as a quantised PNG at `bits` (8 or 4): the `quantization` object and the
/// PNG bytes. Values must be finite.
pub fn encode_png_level(level: &TextureLevel, bits: u32) -> Result<(Quantization, Vec<u8>)> {
    encode_png_level_at(level, bits, bits)
}

/// [`encode_png_level`] on a coarser grid: values rounded to `precision` bits (`1..=bits`),
/// stored as `q << (bits - precision)` with `scale` divided by `2^(bits - precision)`. A
/// reader's `offset + scale * q` is then exactly `offset + scale_p * k`, the value rounded
/// on the `precision`-bit grid (both factors only change by a power of two), and deflate
/// codes fewer distinct values, so the PNG is smaller.
pub fn encode_png_level_at(
    level: &TextureLevel,
    bits: u32,
    precision: u32,
) -> Result<(Quantization, Vec<u8>)> {
    let per = channels_per_texel(bits)
        .ok_or_else(|| Error::invalid(format!("quantisation to {bits} bits")))?;
    if !(1..=bits).contains(&precision) {
        return Err(Error::invalid(format!(
            "a {precision}-bit grid in {bits}-bit values"
        )));
    }
    let shift = bits - precision;
    if let Some(i) = level.data.iter().position(|v| !v.is_finite()) {
        return Err(Error::invalid(format!(
            "texel value {i} is {}",
            level.data[i]
        )));
    }
    let (w, h, c) = (
        level.width as usize,
        level.height as usize,
        level.channels as usize,
    );
    if level.data.len() != w * h * c {
        return Err(Error::invalid("level data length differs from its size"));
    }
    let (scale_p, offset) = fit_parameters(level, precision);
    let (pw, ph) = png_size(level.width, level.height, level.channels, bits)
        .ok_or_else(|| Error::invalid("quantised level height overflows"))?;
    let groups = c.div_ceil(per as usize);
    let mut rgba = vec![0u8; w * h * groups * 4];
    for j in 0..h {
        for i in 0..w {
            let texel = &level.data[(j * w + i) * c..][..c];
            for (k, &v) in texel.iter().enumerate() {
                let q = quantise(v, scale_p[k], offset[k], precision) << shift;
                let (g, within) = (k / per as usize, k % per as usize);
                let (comp, shift) = if bits == 8 {
                    (within, 0)
                } else {
                    (within / 2, 4 * (within % 2))
                };
                rgba[((g * h + j) * w + i) * 4 + comp] |= q << shift;
            }
        }
    }
    let png = crate::asset::encode_png_rgba8(pw, ph, &rgba)?;
    let step = 1.0 / (1u32 << shift) as f32;
    let scale = scale_p.iter().map(|s| s * step).collect();
    Ok((
        Quantization {
            bits,
            scale,
            offset,
            extensions: None,
            extras: None,
            others: Default::default(),
        },
        png,
    ))
}

/// Decodes a quantised PNG level to `f32` texels (HWC), after checking the parameters, the
/// PNG header (8-bit RGBA, the expected size) and the size against `limits`.
pub fn decode_png_level(
    bytes: &[u8],
    expect: LevelExpect,
    q: &Quantization,
    limits: &Limits,
) -> std::result::Result<TextureLevel, Problem> {
    if let Some((code, _, msg)) = quantization_problems(q, expect.channels).into_iter().next() {
        return Err(Problem::invalid(code, msg));
    }
    let (pw, ph) = png_size(expect.width, expect.height, expect.channels, q.bits)
        .ok_or_else(|| Problem::invalid("PNG_SIZE_MISMATCH", "level height overflows"))?;
    let values = u64::from(expect.width) * u64::from(expect.height) * u64::from(expect.channels);
    Limits::check("texel values", values, limits.max_total_texel_values).map_err(|error| {
        Problem {
            code: "LIMIT_EXCEEDED",
            error,
        }
    })?;
    let rgba = decode_png_rgba8(bytes, pw, ph)?;
    let per = channels_per_texel(q.bits).unwrap_or(4) as usize;
    let (w, h, c) = (
        expect.width as usize,
        expect.height as usize,
        expect.channels as usize,
    );
    let mut data = Vec::with_capacity(w * h * c);
    for j in 0..h {
        for i in 0..w {
            for k in 0..c {
                let (g, within) = (k / per, k % per);
                let byte_at = ((g * h + j) * w + i) * 4;
                let qv = if q.bits == 8 {
                    rgba[byte_at + within]
                } else {
                    (rgba[byte_at + within / 2] >> (4 * (within % 2))) & 0x0F
                };
                data.push(dequantise(qv, q.scale[k], q.offset[k]));
            }
        }
    }
    Ok(TextureLevel {
        width: expect.width,
        height: expect.height,
        channels: expect.channels,
        data,
    })
}

/// Decodes a PNG that must be 8-bit RGBA of exactly `width x height`; the header is checked
/// before the pixels are allocated.
pub fn decode_png_rgba8(
    bytes: &[u8],
    width: u32,
    height: u32,
) -> std::result::Result<Vec<u8>, Problem> {
    let bad = |e: png::DecodingError| Problem::invalid("PNG_INVALID", format!("PNG: {e}"));
    let mut decoder = png::Decoder::new(std::io::Cursor::new(bytes));
    decoder.set_transformations(png::Transformations::IDENTITY);
    let mut reader = decoder.read_info().map_err(bad)?;
    let info = reader.info();
    if info.bit_depth != png::BitDepth::Eight || info.color_type != png::ColorType::Rgba {
        return Err(Problem::invalid(
            "PNG_FORMAT",
            format!(
                "PNG is {:?} at {} bits, must be RGBA (colour type 6) at 8 bits",
                info.color_type, info.bit_depth as u8
            ),
        ));
    }
    if (info.width, info.height) != (width, height) {
        return Err(Problem::invalid(
            "PNG_SIZE_MISMATCH",
            format!(
                "PNG is {}x{}, the level needs {width}x{height}",
                info.width, info.height
            ),
        ));
    }
    let len = reader
        .output_buffer_size()
        .ok_or_else(|| Problem::invalid("PNG_INVALID", "PNG size overflows"))?;
    let mut buf = vec![0u8; len];
    let frame = reader.next_frame(&mut buf).map_err(bad)?;
    buf.truncate(frame.buffer_size());
    if buf.len() != width as usize * height as usize * 4 {
        return Err(Problem::invalid(
            "PNG_INVALID",
            "PNG pixel data has the wrong length",
        ));
    }
    Ok(buf)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn level(w: u32, h: u32, c: u32) -> TextureLevel {
        let data = (0..w * h * c)
            .map(|i| ((i * 37 % 101) as f32 / 50.0 - 1.0) * (1.0 + (i % c) as f32))
            .collect();
        TextureLevel {
            width: w,
            height: h,
            channels: c,
            data,
        }
    }

    #[test]
    fn round_trip_is_the_formula_within_half_a_step_or_clamped_to_the_range() {
        for (c, bits) in [(6, 8), (6, 4), (16, 4), (3, 8), (9, 4)] {
            let l = level(5, 3, c);
            let (q, png) = encode_png_level(&l, bits).unwrap();
            let expect = LevelExpect {
                width: 5,
                height: 3,
                channels: c,
            };
            let back = decode_png_level(&png, expect, &q, &Limits::default()).unwrap();
            let mut fake = l.clone();
            fake_quantise_level(&mut fake, &q.scale, &q.offset, bits);
            assert_eq!(back.data, fake.data, "c {c} bits {bits}");
            for (k, (a, b)) in l.data.iter().zip(&back.data).enumerate() {
                let (s, o) = (q.scale[k % c as usize], q.offset[k % c as usize]);
                let end = o + s * q_max(bits);
                // Inside the range: within half a step; outside: clamped to its nearer end.
                let want = a.clamp(o, end);
                assert!((want - b).abs() <= 0.5 * s * 1.0001, "{a} {b} {s} {o}");
            }
        }
    }

    #[test]
    fn a_coarser_grid_decodes_to_its_own_rounding_and_takes_fewer_bytes() {
        // A smooth level with a little noise, like a trained one.
        let (w, h, c) = (64u32, 64u32, 8u32);
        let data = (0..w * h * c)
            .map(|i| {
                let (t, k) = ((i / c) as f32, (i % c) as f32);
                (t * 0.013 + k).sin() * 0.5 + ((i * 7919 % 97) as f32 / 97.0 - 0.5) * 0.05
            })
            .collect();
        let l = TextureLevel {
            width: w,
            height: h,
            channels: c,
            data,
        };
        let expect = LevelExpect {
            width: w,
            height: h,
            channels: c,
        };
        for bits in [8, 4] {
            let mut last = usize::MAX;
            for p in (1..=bits).rev() {
                let (q, png) = encode_png_level_at(&l, bits, p).unwrap();
                assert_eq!(q.bits, bits);
                let back = decode_png_level(&png, expect, &q, &Limits::default()).unwrap();
                // Bit for bit the value rounded on the p-bit grid with the p-bit fit.
                let (s, o) = fit_parameters(&l, p);
                let mut fake = l.clone();
                fake_quantise_level(&mut fake, &s, &o, p);
                assert_eq!(back.data, fake.data, "bits {bits} precision {p}");
                assert!(png.len() < last, "bits {bits} precision {p}: {}", png.len());
                last = png.len();
            }
            assert!(encode_png_level_at(&l, bits, bits + 1).is_err());
            assert!(encode_png_level_at(&l, bits, 0).is_err());
        }
    }

    #[test]
    fn fast_rounding_is_the_library_rounding() {
        let mut xs = vec![
            -1.0,
            -0.5,
            0.0,
            0.49999997,
            0.5,
            1.5,
            2.5,
            14.5,
            14.999999,
            15.5,
            254.5,
            255.49998,
            1e9,
            f32::NAN,
        ];
        xs.extend((0..100_000).map(|i| i as f32 * 0.002_717 - 10.0));
        for top in [15.0, 255.0] {
            for &x in &xs {
                let want = x.round().clamp(0.0, top) as u8;
                assert_eq!(round_in_range(x, top) as u8, want, "{x} top {top}");
            }
        }
    }

    #[test]
    fn hostile_parameters_and_images_have_codes() {
        let l = level(4, 4, 5);
        let (q, png) = encode_png_level(&l, 4).unwrap();
        let expect = LevelExpect {
            width: 4,
            height: 4,
            channels: 5,
        };
        let lim = Limits::default();
        let code = |r: std::result::Result<TextureLevel, Problem>| r.unwrap_err().code;
        let mut z = q.clone();
        z.scale[1] = 0.0;
        assert_eq!(
            code(decode_png_level(&png, expect, &z, &lim)),
            "QUANT_SCALE_INVALID"
        );
        z.scale[1] = f32::NAN;
        assert_eq!(
            code(decode_png_level(&png, expect, &z, &lim)),
            "QUANT_SCALE_INVALID"
        );
        let mut b = q.clone();
        b.bits = 6;
        assert_eq!(code(decode_png_level(&png, expect, &b, &lim)), "QUANT_BITS");
        let mut s = q.clone();
        s.offset.pop();
        assert_eq!(
            code(decode_png_level(&png, expect, &s, &lim)),
            "QUANT_ARRAY_LENGTH"
        );
        // The same PNG read as 8-bit needs twice the height.
        let mut e = q.clone();
        e.bits = 8;
        assert_eq!(
            code(decode_png_level(&png, expect, &e, &lim)),
            "PNG_SIZE_MISMATCH"
        );
        let rgb = {
            let mut out = Vec::new();
            let mut enc = png::Encoder::new(&mut out, 4, 4);
            enc.set_color(png::ColorType::Rgb);
            let mut wr = enc.write_header().unwrap();
            wr.write_image_data(&[0; 48]).unwrap();
            wr.finish().unwrap();
            out
        };
        assert_eq!(code(decode_png_level(&rgb, expect, &q, &lim)), "PNG_FORMAT");
        assert_eq!(
            code(decode_png_level(&png[..png.len() / 2], expect, &q, &lim)),
            "PNG_INVALID"
        );
        assert_eq!(
            code(decode_png_level(b"not a png", expect, &q, &lim)),
            "PNG_INVALID"
        );
    }
}
