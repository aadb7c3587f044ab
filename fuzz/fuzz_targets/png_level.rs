#![no_main]
//! `cargo fuzz run png_level`: see dnr_conformance::fuzz_targets::png_level.
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| dnr_conformance::fuzz_targets::png_level(data));
