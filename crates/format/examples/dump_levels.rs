//! Prints, as JSON, every neural texture level of an asset as decoded by `dnr-format`:
//! `cargo run -p dnr-format --example dump_levels -- FILE`.
//!
//! Output: `{"file": ..., "levels": [{"texture", "level", "bufferView", "width", "height",
//! "channels", "channelNames", "halfBits": [HWC u16 bit patterns]}], "pngLevels":
//! [{"texture", "level", "bufferView", "width", "height", "channels", "bits", "f32Bits":
//! [HWC u32 bit patterns]}]}`: the EXR levels in `levels`, the quantised PNG levels of
//! revision 1.1 in `pngLevels`. Used by `tests/scripts/check_exr.py` to compare against the
//! reference OpenEXR library and by `tests/scripts/check_png_levels.py` against a PNG decoder
//! written from the PNG and extension specifications.

use std::path::Path;

use dnr_format::exr_codec::{channel_name, decode_level_halves, LevelExpect};
use dnr_format::{Container, Limits};
use serde_json::json;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let file = std::env::args().nth(1).ok_or("usage: dump_levels FILE")?;
    let limits = Limits::default();
    let c = Container::read(Path::new(&file), &limits)?;
    let value = dnr_format::asset::root_extension_value(&c.root).ok_or("no extension object")?;
    let ext: dnr_format::model::Extension = serde_json::from_value(value.clone())?;
    let mut levels = Vec::new();
    let mut png_levels = Vec::new();
    for (ti, t) in ext.neural_textures.iter().enumerate() {
        for (li, l) in t.levels.iter().enumerate() {
            let bytes = c.view_bytes(l.buffer_view)?;
            let expect = LevelExpect {
                width: l.width,
                height: l.height,
                channels: t.channels,
            };
            // The fields every entry has; each storage adds its values.
            let common = json!({
                "texture": ti,
                "level": li,
                "bufferView": l.buffer_view,
                "width": l.width,
                "height": l.height,
                "channels": t.channels,
            });
            if let Some(q) = &l.quantization {
                let level = dnr_format::quant::decode_png_level(bytes, expect, q, &limits)
                    .map_err(|p| p.error)?;
                let mut e = common;
                e["bits"] = json!(q.bits);
                e["f32Bits"] = json!(level.data.iter().map(|v| v.to_bits()).collect::<Vec<_>>());
                png_levels.push(e);
                continue;
            }
            let halves = decode_level_halves(bytes, expect, &limits).map_err(|p| p.error)?;
            let mut e = common;
            e["channelNames"] = json!((0..t.channels)
                .map(|i| channel_name(i, t.channels))
                .collect::<Vec<_>>());
            e["halfBits"] = json!(halves.iter().map(|h| h.to_bits()).collect::<Vec<_>>());
            levels.push(e);
        }
    }
    println!(
        "{}",
        json!({ "file": file, "levels": levels, "pngLevels": png_levels })
    );
    Ok(())
}
