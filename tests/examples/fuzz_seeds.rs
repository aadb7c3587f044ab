//! Writes the seed corpus of every fuzz target: `cargo run -p dnr-conformance --example
//! fuzz_seeds -- fuzz/corpus` (one folder per target, files named by index).
use std::path::PathBuf;

use dnr_conformance::fuzz_targets::{seeds, TARGETS};

fn main() -> std::io::Result<()> {
    let root = PathBuf::from(
        std::env::args()
            .nth(1)
            .unwrap_or_else(|| "fuzz/corpus".into()),
    );
    for (name, _) in TARGETS {
        let dir = root.join(name);
        std::fs::create_dir_all(&dir)?;
        let seeds = seeds(name);
        for (i, s) in seeds.iter().enumerate() {
            std::fs::write(dir.join(format!("seed-{i:03}")), s)?;
        }
        println!("{name}: {} seeds in {}", seeds.len(), dir.display());
    }
    Ok(())
}
