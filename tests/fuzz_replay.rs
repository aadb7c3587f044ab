//! Replays every fuzz target (the bodies `cargo fuzz` runs, `src/fuzz_targets.rs`) over its
//! seeds, the committed corpus `fuzz/corpus/<target>/` and every regression file
//! `fuzz/regressions/<target>/` (inputs that once crashed: each must now return normally),
//! then a short seeded mutation run per target: the stable-toolchain smoke version of the
//! fuzzers, a few seconds each (`DNR_STRESS_SCALE=100` for a longer run).

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;

use dnr_conformance::fuzz_targets::{seeds, TARGETS};
use dnr_conformance::repo_root;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut out: Vec<_> = entries
        .flatten()
        .filter(|e| e.path().is_file())
        .map(|e| {
            let p = e.path();
            let bytes = std::fs::read(&p).unwrap_or_else(|err| panic!("{}: {err}", p.display()));
            (p.display().to_string(), bytes)
        })
        .collect();
    out.sort();
    out
}

fn run_clean(name: &str, f: fn(&[u8]), what: &str, input: &[u8]) {
    if catch_unwind(AssertUnwindSafe(|| f(input))).is_err() {
        panic!("fuzz target {name} panicked on {what}");
    }
}

#[test]
fn seeds_corpus_and_regressions_run_clean() {
    let fuzz = repo_root().join("fuzz");
    for (name, f) in TARGETS {
        let seeds = seeds(name);
        assert!(!seeds.is_empty(), "{name}: no seeds");
        for (i, s) in seeds.iter().enumerate() {
            run_clean(name, f, &format!("seed {i}"), s);
        }
        for sub in ["corpus", "regressions"] {
            for (path, bytes) in files(&fuzz.join(sub).join(name)) {
                run_clean(name, f, &path, &bytes);
            }
        }
    }
}

/// `DNR_STRESS_SCALE=N` multiplies the mutation cases (the longer version of this smoke run).
fn stress_scale() -> usize {
    std::env::var("DNR_STRESS_SCALE")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1usize)
        .max(1)
}

/// Seeded byte flips, insertions, deletions and splices of the seeds.
#[test]
fn short_mutation_run_is_clean() {
    let cases = 30_000 * stress_scale();
    for (t, (name, f)) in TARGETS.into_iter().enumerate() {
        let seeds = seeds(name);
        let mut rng = ChaCha8Rng::seed_from_u64(0xf022 + t as u64);
        for case in 0..cases {
            let mut input = seeds[rng.random_range(0..seeds.len())].clone();
            for _ in 0..rng.random_range(1..8) {
                let len = input.len();
                match rng.random_range(0..5) {
                    0 if len > 0 => {
                        let i = rng.random_range(0..len);
                        input[i] ^= 1 << rng.random_range(0..8);
                    }
                    1 if len > 0 => {
                        let i = rng.random_range(0..len);
                        input[i] = [0, 0xff, 0x7f, 0x80, b'9', b'-'][rng.random_range(0..6)];
                    }
                    2 => {
                        let i = rng.random_range(0..=len);
                        input.insert(i, rng.random());
                    }
                    3 if len > 0 => {
                        let i = rng.random_range(0..len);
                        let n = rng.random_range(1..=(len - i).min(64));
                        input.drain(i..i + n);
                    }
                    _ => {
                        let other = &seeds[rng.random_range(0..seeds.len())];
                        let i = rng.random_range(0..=len);
                        let j = rng.random_range(0..=other.len());
                        input.truncate(i);
                        input.extend_from_slice(&other[j..]);
                    }
                }
            }
            run_clean(name, f, &format!("mutation case {case}"), &input);
        }
    }
}
