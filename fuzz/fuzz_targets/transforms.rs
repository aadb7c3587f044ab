#![no_main]
//! `cargo fuzz run transforms`: see dnr_conformance::fuzz_targets::transforms.
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| dnr_conformance::fuzz_targets::transforms(data));
