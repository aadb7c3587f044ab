//! Prints, as JSON, every neural texture level of an asset as decoded by `dnr-format`:
//! `cargo run -p dnr-format --example dump_levels -- FILE`.
//!
//! Output: `{"file": ..., "levels": [{"texture", "level", "bufferView", "width", "height",
//! "channels", "channelNames", "halfBits": [HWC u16 bit patterns]}]}`. Used by
//! `tests/scripts/check_exr.py` to compare against the reference OpenEXR library.

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
    for (ti, t) in ext.neural_textures.iter().enumerate() {
        for (li, l) in t.levels.iter().enumerate() {
            let bytes = c.view_bytes(l.buffer_view)?;
            let expect = LevelExpect {
                width: l.width,
                height: l.height,
                channels: t.channels,
            };
            let halves = decode_level_halves(bytes, expect, &limits).map_err(|p| p.error)?;
            levels.push(json!({
                "texture": ti,
                "level": li,
                "bufferView": l.buffer_view,
                "width": l.width,
                "height": l.height,
                "channels": t.channels,
                "channelNames": (0..t.channels).map(|i| channel_name(i, t.channels)).collect::<Vec<_>>(),
                "halfBits": halves.iter().map(|h| h.to_bits()).collect::<Vec<_>>(),
            }));
        }
    }
    println!("{}", json!({ "file": file, "levels": levels }));
    Ok(())
}
