//! Checkpoints: the whole training state in one file, written atomically (temporary file,
//! fsync, rename) so a bake killed at any moment leaves either the previous checkpoint or the
//! new one, never a torn file. A CRC-32 over the file catches any other corruption.
//!
//! Layout: `DNRCKPT1` magic, u64 LE header length, JSON header, then the f32 LE arrays the
//! header lists (in order), then the CRC-32 (u32 LE) of everything before it.
//!
//! Arrays: `texture.{k}` per level with its optimiser `texture.{k}.adam.{m,v}`, and for a
//! network (U-Net or MLP) `net.{i}` with `net.{i}.adam.{m,v}` per tensor, in the order of the
//! architecture's `tensor_specs`. The header's configuration names the architecture and its
//! widths, so a checkpoint is only ever restored into the network it was written from.

use std::io::Write;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::kernels::adam::AdamState;

const MAGIC: &[u8; 8] = b"DNRCKPT1";
/// Largest header accepted (the arrays are bounded by the file size).
const MAX_HEADER: u64 = 64 << 20;

/// Checkpoint errors (each names the file).
#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    /// Reading or writing failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// The file is not a complete checkpoint of this version.
    #[error("{path}: corrupt or incompatible checkpoint: {what}")]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        what: String,
    },
}

/// Scalar state saved beside the arrays.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Header {
    /// The resolved configuration as JSON (a resume must match it).
    pub config: serde_json::Value,
    /// Steps taken.
    pub step: u64,
    /// Training seconds so far.
    pub train_secs: f64,
    /// Training second of the next evaluation.
    pub next_eval: f64,
    /// Progress of the next validation check (0 in checkpoints written before there were
    /// checks: the first step after a resume checks).
    #[serde(default)]
    pub next_check: f64,
    /// Records so far, as JSON.
    pub records: serde_json::Value,
    /// Random stream: seed and word position.
    pub rng_seed: [u8; 32],
    /// Word position of the random stream.
    pub rng_word_pos: u128,
    /// Loss accumulator since the last record.
    pub loss_sum: f64,
    /// Steps in the loss accumulator.
    pub loss_n: u64,
    /// Names and lengths of the arrays that follow.
    pub arrays: Vec<(String, u64)>,
    /// Step counts of the optimisers, by array name prefix.
    pub adam_steps: Vec<(String, Vec<u64>)>,
    /// Recoveries from divergence so far, as JSON (absent in older checkpoints).
    #[serde(default)]
    pub recoveries: serde_json::Value,
}

/// A checkpoint in memory.
#[derive(Clone, Debug, PartialEq)]
pub struct Checkpoint {
    /// Scalars.
    pub header: Header,
    /// Arrays, in `header.arrays` order.
    pub arrays: Vec<Vec<f32>>,
}

impl Checkpoint {
    /// Adds an array.
    pub fn push(&mut self, name: &str, data: &[f32]) {
        self.header
            .arrays
            .push((name.to_string(), data.len() as u64));
        self.arrays.push(data.to_vec());
    }

    /// Adds an optimiser's state under `name`.
    pub fn push_adam(&mut self, name: &str, s: &AdamState) {
        self.push(&format!("{name}.m"), &s.m);
        self.push(&format!("{name}.v"), &s.v);
        self.header.adam_steps.push((name.to_string(), s.t.clone()));
    }

    /// The array called `name`.
    pub fn array(&self, name: &str) -> Option<&[f32]> {
        let i = self.header.arrays.iter().position(|(n, _)| n == name)?;
        Some(&self.arrays[i])
    }

    /// The optimiser state saved under `name`.
    pub fn adam(&self, name: &str) -> Option<AdamState> {
        let t = self
            .header
            .adam_steps
            .iter()
            .find(|(n, _)| n == name)?
            .1
            .clone();
        Some(AdamState {
            m: self.array(&format!("{name}.m"))?.to_vec(),
            v: self.array(&format!("{name}.v"))?.to_vec(),
            t,
        })
    }

    /// Writes atomically to `path`.
    pub fn write(&self, path: &Path) -> Result<(), CheckpointError> {
        let io = |source| CheckpointError::Io {
            path: path.to_path_buf(),
            source,
        };
        let header = serde_json::to_vec(&self.header).map_err(|e| io(std::io::Error::other(e)))?;
        let total: usize = self.arrays.iter().map(|a| 4 * a.len()).sum();
        let mut bytes = Vec::with_capacity(8 + 8 + header.len() + total + 4);
        bytes.extend_from_slice(MAGIC);
        bytes.extend_from_slice(&(header.len() as u64).to_le_bytes());
        bytes.extend_from_slice(&header);
        for a in &self.arrays {
            for v in a {
                bytes.extend_from_slice(&v.to_le_bytes());
            }
        }
        let crc = crc32fast::hash(&bytes);
        bytes.extend_from_slice(&crc.to_le_bytes());
        let dir = path
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        std::fs::create_dir_all(dir).map_err(io)?;
        let tmp = dir.join(format!(
            ".{}.{}.tmp",
            path.file_name()
                .map(|n| n.to_string_lossy())
                .unwrap_or_default(),
            std::process::id()
        ));
        let mut f = std::fs::File::create(&tmp).map_err(io)?;
        f.write_all(&bytes).map_err(io)?;
        f.sync_all().map_err(io)?;
        drop(f);
        std::fs::rename(&tmp, path).map_err(|e| {
            let _ = std::fs::remove_file(&tmp);
            io(e)
        })?;
        Ok(())
    }

    /// Reads and verifies a checkpoint.
    pub fn read(path: &Path) -> Result<Checkpoint, CheckpointError> {
        let corrupt = |what: &str| CheckpointError::Corrupt {
            path: path.to_path_buf(),
            what: what.to_string(),
        };
        let bytes = std::fs::read(path).map_err(|source| CheckpointError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        if bytes.len() < 20 || &bytes[..8] != MAGIC {
            return Err(corrupt("bad magic or too short"));
        }
        let body = &bytes[..bytes.len() - 4];
        let crc = u32::from_le_bytes(bytes[bytes.len() - 4..].try_into().expect("4 bytes"));
        if crc32fast::hash(body) != crc {
            return Err(corrupt("checksum mismatch"));
        }
        let hlen = u64::from_le_bytes(body[8..16].try_into().expect("8 bytes"));
        if hlen > MAX_HEADER || hlen as usize > body.len() - 16 {
            return Err(corrupt("header length"));
        }
        let hend = 16 + hlen as usize;
        let header: Header =
            serde_json::from_slice(&body[16..hend]).map_err(|e| corrupt(&e.to_string()))?;
        // Checked: a crafted header (with a valid CRC) could make the lengths wrap around.
        let total = header
            .arrays
            .iter()
            .try_fold(0u64, |acc, (_, n)| acc.checked_add(*n));
        if total.and_then(|t| t.checked_mul(4)) != Some((body.len() - hend) as u64) {
            return Err(corrupt("array lengths disagree with the file size"));
        }
        let mut arrays = Vec::with_capacity(header.arrays.len());
        let mut at = hend;
        for (_, n) in &header.arrays {
            let n = *n as usize;
            let a = body[at..at + 4 * n]
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
                .collect();
            at += 4 * n;
            arrays.push(a);
        }
        Ok(Checkpoint { header, arrays })
    }
}

/// Where the checkpoint of a bake writing `output` lives: a folder next to it.
pub fn path_for(output: &Path) -> PathBuf {
    let name = output
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "asset".into());
    output
        .with_file_name(format!("{name}.ckpt"))
        .join("state.bin")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Checkpoint {
        let mut c = Checkpoint {
            header: Header {
                config: serde_json::json!({"a": 1}),
                step: 7,
                train_secs: 1.5,
                next_eval: 3.0,
                next_check: 0.25,
                records: serde_json::json!([]),
                rng_seed: [3; 32],
                rng_word_pos: 12345,
                loss_sum: 0.25,
                loss_n: 2,
                arrays: vec![],
                adam_steps: vec![],
                recoveries: serde_json::json!([]),
            },
            arrays: vec![],
        };
        c.push("x", &[1.0, -2.5, f32::MAX]);
        c.push_adam(
            "opt",
            &AdamState {
                m: vec![0.5],
                v: vec![0.25],
                t: vec![9],
            },
        );
        c
    }

    #[test]
    fn round_trip_and_every_corruption_is_caught() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("ck/state.bin");
        let c = sample();
        c.write(&p).unwrap();
        assert_eq!(Checkpoint::read(&p).unwrap(), c);
        assert_eq!(
            Checkpoint::read(&p).unwrap().adam("opt").unwrap().t,
            vec![9]
        );
        let bytes = std::fs::read(&p).unwrap();
        // Every truncation and a flipped byte anywhere must be rejected, never panic.
        for len in 0..bytes.len() {
            std::fs::write(&p, &bytes[..len]).unwrap();
            assert!(
                Checkpoint::read(&p).is_err(),
                "truncation to {len} accepted"
            );
        }
        for i in (0..bytes.len()).step_by(7) {
            let mut b = bytes.clone();
            b[i] ^= 0x40;
            std::fs::write(&p, &b).unwrap();
            assert!(Checkpoint::read(&p).is_err(), "flip at {i} accepted");
        }
        // Array lengths that wrap around u64 (2^63 + 2^63 = 0 bytes) behind a valid CRC.
        let mut h = c.header.clone();
        h.arrays = vec![("a".into(), 1 << 63), ("b".into(), 1 << 63)];
        let json = serde_json::to_vec(&h).unwrap();
        let mut b = MAGIC.to_vec();
        b.extend_from_slice(&(json.len() as u64).to_le_bytes());
        b.extend_from_slice(&json);
        let crc = crc32fast::hash(&b);
        b.extend_from_slice(&crc.to_le_bytes());
        std::fs::write(&p, &b).unwrap();
        let e = Checkpoint::read(&p).unwrap_err().to_string();
        assert!(e.contains("array lengths"), "{e}");
        std::fs::write(&p, &bytes).unwrap();
        // No temporary file is left behind.
        let names: Vec<_> = std::fs::read_dir(p.parent().unwrap())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names.len(), 1, "{names:?}");
    }
}
