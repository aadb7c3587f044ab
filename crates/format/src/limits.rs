//! Limits on sizes read from untrusted files, checked before anything is allocated.
//!
//! Every count, dimension and length that comes from a file passes through
//! [`Limits::check`] before it sizes an allocation, so a lying header cannot make a
//! reader allocate more than these limits allow. The defaults fit any asset the baker
//! makes with room to spare; raise them for trusted, larger inputs.

use crate::error::{Error, Result};

/// Upper bounds applied while reading and validating.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Largest `.glb` file or `.gltf` JSON + buffers, in bytes. Default 2 GiB.
    pub max_file_bytes: u64,
    /// Largest JSON chunk or `.gltf` file, in bytes. Default 64 MiB.
    pub max_json_bytes: u64,
    /// Largest single buffer (BIN chunk, data: URI or external file), in bytes. Default 2 GiB.
    pub max_buffer_bytes: u64,
    /// Largest texture width or height. Default 16384 (the common GPU maximum).
    pub max_texture_side: u32,
    /// Most levels in one neural texture. Default 16 (enough to halve 16384 down to 1).
    pub max_levels: u32,
    /// Most channels in one neural texture. Default 64.
    pub max_channels: u32,
    /// Most texel values (`sum of width * height * channels` over every level of every
    /// texture) decoded for one asset; each costs 4 bytes as `f32`. Default 2^28 (1 GiB).
    pub max_total_texel_values: u64,
    /// Most weight elements over every tensor of one asset; 4 bytes each as `f32`.
    /// Default 2^27 (512 MiB).
    pub max_weight_elements: u64,
    /// Most tensors in one renderer. Default 1024.
    pub max_tensors: u32,
    /// Highest tensor rank. Default 8.
    pub max_tensor_rank: u32,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_file_bytes: 2 << 30,
            max_json_bytes: 64 << 20,
            max_buffer_bytes: 2 << 30,
            max_texture_side: 16384,
            max_levels: 16,
            max_channels: 64,
            max_total_texel_values: 1 << 28,
            max_weight_elements: 1 << 27,
            max_tensors: 1024,
            max_tensor_rank: 8,
        }
    }
}

impl Limits {
    /// No limits (for trusted inputs only).
    pub fn unlimited() -> Self {
        Limits {
            max_file_bytes: u64::MAX,
            max_json_bytes: u64::MAX,
            max_buffer_bytes: u64::MAX,
            max_texture_side: u32::MAX,
            max_levels: u32::MAX,
            max_channels: u32::MAX,
            max_total_texel_values: u64::MAX,
            max_weight_elements: u64::MAX,
            max_tensors: u32::MAX,
            max_tensor_rank: u32::MAX,
        }
    }

    /// Every limit by the name [`Limits::set`] takes (the field name), with its value.
    pub fn entries(&self) -> [(&'static str, u64); 10] {
        [
            ("max_file_bytes", self.max_file_bytes),
            ("max_json_bytes", self.max_json_bytes),
            ("max_buffer_bytes", self.max_buffer_bytes),
            ("max_texture_side", u64::from(self.max_texture_side)),
            ("max_levels", u64::from(self.max_levels)),
            ("max_channels", u64::from(self.max_channels)),
            ("max_total_texel_values", self.max_total_texel_values),
            ("max_weight_elements", self.max_weight_elements),
            ("max_tensors", u64::from(self.max_tensors)),
            ("max_tensor_rank", u64::from(self.max_tensor_rank)),
        ]
    }

    /// Sets one limit from `NAME=VALUE` (a field name of [`Limits`], e.g.
    /// `max_texture_side=32768`), as a command-line flag gives it. The message of an error
    /// lists the names.
    pub fn set(&mut self, spec: &str) -> std::result::Result<(), String> {
        let names = || {
            self.entries()
                .iter()
                .map(|(n, _)| *n)
                .collect::<Vec<_>>()
                .join(", ")
        };
        let (name, value) = spec
            .split_once('=')
            .ok_or_else(|| format!("expected NAME=VALUE, got `{spec}` (names: {})", names()))?;
        let value: u64 = value
            .trim()
            .parse()
            .map_err(|e| format!("limit `{name}`: `{value}` is not a whole number: {e}"))?;
        let narrow = |v: u64| -> std::result::Result<u32, String> {
            u32::try_from(v).map_err(|_| format!("limit `{name}`: {v} is over {}", u32::MAX))
        };
        match name.trim() {
            "max_file_bytes" => self.max_file_bytes = value,
            "max_json_bytes" => self.max_json_bytes = value,
            "max_buffer_bytes" => self.max_buffer_bytes = value,
            "max_texture_side" => self.max_texture_side = narrow(value)?,
            "max_levels" => self.max_levels = narrow(value)?,
            "max_channels" => self.max_channels = narrow(value)?,
            "max_total_texel_values" => self.max_total_texel_values = value,
            "max_weight_elements" => self.max_weight_elements = value,
            "max_tensors" => self.max_tensors = narrow(value)?,
            "max_tensor_rank" => self.max_tensor_rank = narrow(value)?,
            other => return Err(format!("unknown limit `{other}` (names: {})", names())),
        }
        Ok(())
    }

    /// `Err(LimitExceeded)` when `value > limit`.
    pub fn check(what: &str, value: u64, limit: u64) -> Result<()> {
        if value > limit {
            Err(Error::LimitExceeded {
                what: what.to_string(),
                value,
                limit,
            })
        } else {
            Ok(())
        }
    }

    /// Converts a length read from a file to `usize` after checking it against `limit`.
    pub fn checked_len(what: &str, value: u64, limit: u64) -> Result<usize> {
        Self::check(what, value, limit)?;
        usize::try_from(value).map_err(|_| Error::LimitExceeded {
            what: what.to_string(),
            value,
            limit: usize::MAX as u64,
        })
    }
}
