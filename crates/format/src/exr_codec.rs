//! Low layer: one neural texture level as a single-part scanline OpenEXR file.
//!
//! On disk every channel is `HALF`, named `C` + zero-padded index (`C00`..`C15`), data
//! window = display window = (0,0)-(W-1,H-1), line order increasing Y, lossless
//! compression. In memory a level is `f32`, texel-interleaved (HWC), row 0 first.
//!
//! Decoding reads the header first and checks it against what the JSON declares and
//! the [`Limits`] before any pixel memory is allocated.

use std::io::Cursor;
use std::panic::{catch_unwind, AssertUnwindSafe};

use exr::meta::attribute::SampleType;
use exr::meta::BlockDescription;
use half::f16;

use crate::container::Problem;
use crate::error::{Error, Result};
use crate::limits::Limits;

/// One decoded level: `height * width * channels` values, HWC, row 0 first.
#[derive(Clone, Debug, PartialEq)]
pub struct TextureLevel {
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// Channels per texel.
    pub channels: u32,
    /// Texel-interleaved values, row 0 (top, v = 0) first.
    pub data: Vec<f32>,
}

impl TextureLevel {
    /// A zero level.
    pub fn zeros(width: u32, height: u32, channels: u32) -> Self {
        let n = width as usize * height as usize * channels as usize;
        TextureLevel {
            width,
            height,
            channels,
            data: vec![0.0; n],
        }
    }

    /// Value of channel `c` at texel (x, y); `None` outside.
    pub fn get(&self, x: u32, y: u32, c: u32) -> Option<f32> {
        if x >= self.width || y >= self.height || c >= self.channels {
            return None;
        }
        let i =
            (y as usize * self.width as usize + x as usize) * self.channels as usize + c as usize;
        self.data.get(i).copied()
    }
}

/// Lossless compressions a level may use.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum LevelCompression {
    /// No compression.
    None,
    /// Run-length encoding.
    Rle,
    /// Zlib, one scan line per block.
    Zips,
    /// Zlib, 16 scan lines per block.
    Zip,
    /// Wavelet + Huffman.
    Piz,
    /// Not a stored method: [`encode_level`] tries every method of [`LevelCompression::ALL`]
    /// (all lossless for half data) and keeps the smallest file, per level.
    Smallest,
}

impl LevelCompression {
    /// Every allowed compression.
    pub const ALL: [LevelCompression; 5] = [
        LevelCompression::None,
        LevelCompression::Rle,
        LevelCompression::Zips,
        LevelCompression::Zip,
        LevelCompression::Piz,
    ];

    fn to_exr(self) -> exr::compression::Compression {
        use exr::compression::Compression as C;
        match self {
            LevelCompression::None => C::Uncompressed,
            LevelCompression::Rle => C::RLE,
            LevelCompression::Zips => C::ZIP1,
            LevelCompression::Zip => C::ZIP16,
            LevelCompression::Piz => C::PIZ,
            // Resolved by `encode_level` before it gets here; ZIP is the usual winner.
            LevelCompression::Smallest => C::ZIP16,
        }
    }

    /// The allowed compression matching an EXR compression, `None` if lossy or unknown.
    pub fn from_exr(c: exr::compression::Compression) -> Option<Self> {
        use exr::compression::Compression as C;
        match c {
            C::Uncompressed => Some(LevelCompression::None),
            C::RLE => Some(LevelCompression::Rle),
            C::ZIP1 => Some(LevelCompression::Zips),
            C::ZIP16 => Some(LevelCompression::Zip),
            C::PIZ => Some(LevelCompression::Piz),
            _ => None,
        }
    }

    /// Name as OpenEXR spells it.
    pub fn name(self) -> &'static str {
        match self {
            LevelCompression::None => "NONE",
            LevelCompression::Rle => "RLE",
            LevelCompression::Zips => "ZIPS",
            LevelCompression::Zip => "ZIP",
            LevelCompression::Piz => "PIZ",
            LevelCompression::Smallest => "smallest",
        }
    }
}

/// Name of channel `index` of `channels`: `C` + index padded to `max(2, digits(C-1))`.
pub fn channel_name(index: u32, channels: u32) -> String {
    let digits = channels.saturating_sub(1).max(1).to_string().len().max(2);
    format!("C{index:0digits$}")
}

/// Largest finite half value.
pub const HALF_MAX: f32 = 65504.0;

/// Encodes `level` (the `level_index`-th of its texture, for messages) as an EXR file.
///
/// Errors if the data length does not match the dimensions or a value is not finite or
/// beyond the half range (the message names level, channel and texel).
pub fn encode_level(
    level: &TextureLevel,
    level_index: usize,
    compression: LevelCompression,
) -> Result<Vec<u8>> {
    if compression == LevelCompression::Smallest {
        let mut best: Option<Vec<u8>> = None;
        for c in LevelCompression::ALL {
            let bytes = encode_level(level, level_index, c)?;
            if best.as_ref().is_none_or(|b| bytes.len() < b.len()) {
                best = Some(bytes);
            }
        }
        return best.ok_or_else(|| Error::invalid("no compression"));
    }
    use exr::prelude::{
        AnyChannel, AnyChannels, Blocks, Encoding, FlatSamples, Image, Layer, LayerAttributes,
        LineOrder, SmallVec, WritableImage,
    };
    let (w, h, c) = (
        level.width as usize,
        level.height as usize,
        level.channels as usize,
    );
    if w == 0 || h == 0 || c == 0 {
        return Err(Error::invalid(format!(
            "level {level_index}: size {w}x{h}x{c} has a zero dimension"
        )));
    }
    let expected = w
        .checked_mul(h)
        .and_then(|n| n.checked_mul(c))
        .ok_or_else(|| Error::invalid(format!("level {level_index}: size overflows")))?;
    if level.data.len() != expected {
        return Err(Error::invalid(format!(
            "level {level_index}: {} values for {w}x{h}x{c}",
            level.data.len()
        )));
    }
    let mut list = SmallVec::<[AnyChannel<FlatSamples>; 4]>::new();
    for ch in 0..c {
        let name = channel_name(ch as u32, level.channels);
        let mut plane = Vec::with_capacity(w * h);
        for (i, texel) in level.data.chunks_exact(c).enumerate() {
            let v = texel[ch];
            if !v.is_finite() || v.abs() > HALF_MAX {
                return Err(Error::invalid(format!(
                    "level {level_index} channel {name} texel ({}, {}): {v} is not a finite half value",
                    i % w,
                    i / w
                )));
            }
            plane.push(f16::from_f32(v));
        }
        list.push(AnyChannel::new(name.as_str(), FlatSamples::F16(plane)));
    }
    let encoding = Encoding {
        compression: compression.to_exr(),
        blocks: Blocks::ScanLines,
        line_order: LineOrder::Increasing,
    };
    let layer = Layer::new(
        (w, h),
        LayerAttributes::default(),
        encoding,
        AnyChannels::sort(list),
    );
    let image = Image::from_layer(layer);
    let mut out = Cursor::new(Vec::new());
    image
        .write()
        .non_parallel()
        .to_buffered(&mut out)
        .map_err(|e| Error::invalid(format!("level {level_index}: EXR encoding failed: {e}")))?;
    Ok(out.into_inner())
}

/// What an EXR header says, in the terms the format checks.
#[derive(Clone, Debug, PartialEq)]
pub struct LevelHeader {
    /// Number of parts (layers) in the file.
    pub parts: usize,
    /// Data window size.
    pub width: u64,
    /// Data window size.
    pub height: u64,
    /// Data window origin.
    pub origin: (i32, i32),
    /// Display window origin and size.
    pub display: ((i32, i32), (u64, u64)),
    /// Channel names, sample types and subsampling, in file order.
    pub channels: Vec<(String, SampleType, (usize, usize))>,
    /// Compression.
    pub compression: exr::compression::Compression,
    /// Tiled instead of scanline.
    pub tiled: bool,
    /// Deep data.
    pub deep: bool,
    /// Line order is increasing Y.
    pub increasing_y: bool,
}

/// Reads only the header of an EXR file (`EXR_INVALID` if it cannot be parsed).
pub fn read_level_header(bytes: &[u8]) -> Result<LevelHeader, Problem> {
    let meta = guard(|| exr::meta::MetaData::read_from_buffered(Cursor::new(bytes), false))
        .and_then(|r| r.map_err(|e| e.to_string()))
        .map_err(|e| Problem::invalid("EXR_INVALID", format!("EXR header: {e}")))?;
    let h = meta
        .headers
        .first()
        .ok_or_else(|| Problem::invalid("EXR_INVALID", "EXR file has no header"))?;
    let dw = h.shared_attributes.display_window;
    Ok(LevelHeader {
        parts: meta.headers.len(),
        width: h.layer_size.0 as u64,
        height: h.layer_size.1 as u64,
        origin: (
            h.own_attributes.layer_position.0,
            h.own_attributes.layer_position.1,
        ),
        display: (
            (dw.position.0, dw.position.1),
            (dw.size.0 as u64, dw.size.1 as u64),
        ),
        channels: h
            .channels
            .list
            .iter()
            .map(|c| {
                (
                    c.name.to_string(),
                    c.sample_type,
                    (c.sampling.0, c.sampling.1),
                )
            })
            .collect(),
        compression: h.compression,
        tiled: matches!(h.blocks, BlockDescription::Tiles(_)),
        deep: h.deep,
        increasing_y: matches!(h.line_order, exr::meta::attribute::LineOrder::Increasing),
    })
}

/// What the JSON declares for a level.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LevelExpect {
    /// Declared width.
    pub width: u32,
    /// Declared height.
    pub height: u32,
    /// The texture's channel count.
    pub channels: u32,
}

/// Every way `header` breaks the level storage rules for `expect` (empty if none).
pub fn header_problems(header: &LevelHeader, expect: LevelExpect) -> Vec<Problem> {
    let mut out = Vec::new();
    if header.parts != 1 || header.tiled || header.deep {
        out.push(Problem::invalid(
            "EXR_INVALID",
            format!(
                "EXR must be one flat scanline part (parts {}, tiled {}, deep {})",
                header.parts, header.tiled, header.deep
            ),
        ));
    }
    if !header.increasing_y {
        out.push(Problem::invalid(
            "EXR_INVALID",
            "EXR line order must be increasing Y",
        ));
    }
    let (w, h) = (u64::from(expect.width), u64::from(expect.height));
    if header.width != w || header.height != h || header.origin != (0, 0) {
        out.push(Problem::invalid(
            "EXR_SIZE_MISMATCH",
            format!(
                "EXR data window is {}x{} at {:?}, JSON declares {w}x{h} at (0, 0)",
                header.width, header.height, header.origin
            ),
        ));
    }
    if header.display != ((0, 0), (w, h)) {
        out.push(Problem::invalid(
            "EXR_SIZE_MISMATCH",
            format!(
                "EXR display window {:?} differs from the data window (0, 0) {w}x{h}",
                header.display
            ),
        ));
    }
    if header.channels.len() != expect.channels as usize {
        out.push(Problem::invalid(
            "EXR_CHANNELS",
            format!(
                "EXR has {} channels, the texture declares {}",
                header.channels.len(),
                expect.channels
            ),
        ));
    } else {
        for (i, (name, ty, sampling)) in header.channels.iter().enumerate() {
            let want = channel_name(i as u32, expect.channels);
            if *name != want || *ty != SampleType::F16 || *sampling != (1, 1) {
                out.push(Problem::invalid(
                    "EXR_CHANNELS",
                    format!(
                        "EXR channel {i} is `{name}` {ty:?} sampling {sampling:?}, expected `{want}` F16 sampling (1, 1)"
                    ),
                ));
            }
        }
    }
    if LevelCompression::from_exr(header.compression).is_none() {
        out.push(Problem::invalid(
            "EXR_COMPRESSION",
            format!(
                "EXR compression {:?} is not one of NONE, RLE, ZIPS, ZIP, PIZ",
                header.compression
            ),
        ));
    }
    out
}

/// Runs `f`, turning a panic of the third-party decoder into an error (defence in depth:
/// this crate promises not to panic on any input).
fn guard<T>(f: impl FnOnce() -> T) -> std::result::Result<T, String> {
    catch_unwind(AssertUnwindSafe(f)).map_err(|_| "the EXR decoder panicked".to_string())
}

/// Decodes a level after checking its header against `expect` and `limits`.
///
/// The result holds the stored half values widened to `f32`; non-finite halves are an
/// `EXR_NON_FINITE` problem.
pub fn decode_level(
    bytes: &[u8],
    expect: LevelExpect,
    limits: &Limits,
) -> Result<TextureLevel, Problem> {
    let halves = decode_level_halves(bytes, expect, limits)?;
    if let Some(i) = halves.iter().position(|v| !v.is_finite()) {
        let c = expect.channels.max(1) as usize;
        let texel = i / c;
        return Err(Problem::invalid(
            "EXR_NON_FINITE",
            format!(
                "EXR channel {} texel ({}, {}) is {}",
                channel_name((i % c) as u32, expect.channels),
                texel % expect.width.max(1) as usize,
                texel / expect.width.max(1) as usize,
                halves[i]
            ),
        ));
    }
    Ok(TextureLevel {
        width: expect.width,
        height: expect.height,
        channels: expect.channels,
        data: halves.into_iter().map(f16::to_f32).collect(),
    })
}

/// Decodes a level to its stored half values, HWC (no finiteness check).
pub fn decode_level_halves(
    bytes: &[u8],
    expect: LevelExpect,
    limits: &Limits,
) -> Result<Vec<f16>, Problem> {
    use exr::prelude::{read, FlatSamples, ReadChannels, ReadLayers};
    let limit = |what: &str, v: u64, max: u64| {
        Limits::check(what, v, max).map_err(|e| Problem::from_error("LIMIT_EXCEEDED", e))
    };
    limit(
        "texture side",
        u64::from(expect.width),
        u64::from(limits.max_texture_side),
    )?;
    limit(
        "texture side",
        u64::from(expect.height),
        u64::from(limits.max_texture_side),
    )?;
    limit(
        "texture channels",
        u64::from(expect.channels),
        u64::from(limits.max_channels),
    )?;
    let values = u64::from(expect.width) * u64::from(expect.height) * u64::from(expect.channels);
    limit(
        "texel values of one level",
        values,
        limits.max_total_texel_values,
    )?;
    let header = read_level_header(bytes)?;
    if let Some(p) = header_problems(&header, expect).into_iter().next() {
        return Err(p);
    }
    let image = guard(|| {
        read()
            .no_deep_data()
            .largest_resolution_level()
            .all_channels()
            .first_valid_layer()
            .all_attributes()
            .non_parallel()
            .from_buffered(Cursor::new(bytes))
    })
    .and_then(|r| r.map_err(|e| e.to_string()))
    .map_err(|e| Problem::invalid("EXR_INVALID", format!("EXR pixels: {e}")))?;
    let channels = &image.layer_data.channel_data.list;
    let (w, h, c) = (
        expect.width as usize,
        expect.height as usize,
        expect.channels as usize,
    );
    let mut out = vec![f16::ZERO; w * h * c];
    for (ci, channel) in channels.iter().enumerate() {
        let FlatSamples::F16(samples) = &channel.sample_data else {
            return Err(Problem::invalid("EXR_CHANNELS", "EXR channel is not HALF"));
        };
        if samples.len() != w * h || ci >= c {
            return Err(Problem::invalid(
                "EXR_SIZE_MISMATCH",
                "EXR channel sample count",
            ));
        }
        for (i, &v) in samples.iter().enumerate() {
            out[i * c + ci] = v;
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn level(w: u32, h: u32, c: u32) -> TextureLevel {
        let n = (w * h * c) as usize;
        TextureLevel {
            width: w,
            height: h,
            channels: c,
            data: (0..n).map(|i| (i as f32 * 0.37).sin() * 3.0).collect(),
        }
    }

    #[test]
    fn names() {
        assert_eq!(channel_name(0, 1), "C00");
        assert_eq!(channel_name(15, 16), "C15");
        assert_eq!(channel_name(5, 100), "C05");
        assert_eq!(channel_name(5, 101), "C005");
    }

    #[test]
    fn round_trip_every_compression() {
        let l = level(7, 5, 3);
        let expect = LevelExpect {
            width: 7,
            height: 5,
            channels: 3,
        };
        for c in LevelCompression::ALL {
            let bytes = encode_level(&l, 0, c).unwrap();
            let h = read_level_header(&bytes).unwrap();
            assert!(header_problems(&h, expect).is_empty(), "{c:?}");
            assert_eq!(LevelCompression::from_exr(h.compression), Some(c));
            let d = decode_level(&bytes, expect, &Limits::default()).unwrap();
            for (a, b) in l.data.iter().zip(&d.data) {
                assert_eq!(f16::from_f32(*a).to_f32(), *b);
            }
        }
    }

    #[test]
    fn range_errors_name_level_and_channel() {
        let mut l = level(2, 2, 3);
        l.data[5] = 70000.0;
        let e = encode_level(&l, 2, LevelCompression::Zip)
            .unwrap_err()
            .to_string();
        assert!(e.contains("level 2") && e.contains("C02"), "{e}");
        l.data[5] = f32::NAN;
        assert!(encode_level(&l, 0, LevelCompression::Zip).is_err());
        l.data[5] = 65504.0;
        assert!(encode_level(&l, 0, LevelCompression::Zip).is_ok());
    }

    #[test]
    fn header_checked_before_pixels() {
        let bytes = encode_level(&level(4, 4, 2), 0, LevelCompression::Zip).unwrap();
        let wrong = LevelExpect {
            width: 4,
            height: 4,
            channels: 3,
        };
        assert_eq!(
            decode_level(&bytes, wrong, &Limits::default())
                .unwrap_err()
                .code,
            "EXR_CHANNELS"
        );
        let wrong = LevelExpect {
            width: 5,
            height: 4,
            channels: 2,
        };
        assert_eq!(
            decode_level(&bytes, wrong, &Limits::default())
                .unwrap_err()
                .code,
            "EXR_SIZE_MISMATCH"
        );
        let tight = Limits {
            max_texture_side: 3,
            ..Limits::default()
        };
        let ok = LevelExpect {
            width: 4,
            height: 4,
            channels: 2,
        };
        assert_eq!(
            decode_level(&bytes, ok, &tight).unwrap_err().code,
            "LIMIT_EXCEEDED"
        );
        for n in 0..bytes.len() {
            assert!(
                decode_level(&bytes[..n], ok, &Limits::default()).is_err(),
                "prefix {n}"
            );
        }
    }
}
