#![no_main]
//! `cargo fuzz run exr_level`: see dnr_conformance::fuzz_targets::exr_level.
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| dnr_conformance::fuzz_targets::exr_level(data));
