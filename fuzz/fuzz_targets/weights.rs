#![no_main]
//! `cargo fuzz run weights`: see dnr_conformance::fuzz_targets::weights.
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| dnr_conformance::fuzz_targets::weights(data));
