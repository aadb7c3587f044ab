#![no_main]
//! `cargo fuzz run asset_reader`: see dnr_conformance::fuzz_targets::asset_reader.
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| dnr_conformance::fuzz_targets::asset_reader(data));
