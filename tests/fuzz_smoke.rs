//! Fuzz smoke test: fixed-seed byte mutations of every valid sample, every truncation of
//! one sample and every truncation of one EXR level inside it. Nothing may panic (any
//! panic, even one caught inside the library, counts), and no case may allocate more than
//! the bound derived from the [`Limits`] used here.
//!
//! This test binary installs a counting global allocator, the one place in the workspace
//! that needs `unsafe` (implementing `GlobalAlloc` is an unsafe trait).

use std::alloc::{GlobalAlloc, Layout, System};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicUsize, Ordering::Relaxed};
use std::sync::Mutex;

use dnr_conformance::{expected, samples_dir};
use dnr_format::container::{glb_bytes, parse_glb};
use dnr_format::{read_asset_from_slice_with_limits, validate_slice, Limits};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

struct Counting;

static CURRENT: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

fn note_alloc(size: usize) {
    let now = CURRENT.fetch_add(size, Relaxed) + size;
    PEAK.fetch_max(now, Relaxed);
}

// SAFETY: forwards every call to the system allocator unchanged; only counts sizes.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note_alloc(layout.size());
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note_alloc(layout.size());
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        CURRENT.fetch_sub(layout.size(), Relaxed);
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if new_size > layout.size() {
            note_alloc(new_size - layout.size());
        } else {
            CURRENT.fetch_sub(layout.size() - new_size, Relaxed);
        }
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// The tests in this binary run one at a time so the peak belongs to one case.
static SERIAL: Mutex<()> = Mutex::new(());
static PANICS: AtomicUsize = AtomicUsize::new(0);

/// Limits for the fuzzed inputs: the samples are far below them, mutated sizes are not.
fn limits() -> Limits {
    Limits {
        max_file_bytes: 1 << 20,
        max_json_bytes: 256 << 10,
        max_buffer_bytes: 1 << 20,
        max_texture_side: 256,
        max_levels: 8,
        max_channels: 32,
        max_total_texel_values: 1 << 20,
        max_weight_elements: 1 << 18,
        max_tensors: 64,
        max_tensor_rank: 4,
    }
}

/// Peak heap growth allowed for one case.
///
/// Under [`limits`] the largest allocations a case can make are: decoded texels,
/// at most 2^20 values per asset, held as f16 (2 MiB) while validating or as f16 plus f32
/// (2 + 4 MiB) while reading; the `exr` crate's per-channel planes of one level (<= 2 MiB)
/// and its block buffers (a few KiB); weights, at most 2^18 elements as f32 (1 MiB); the
/// JSON DOMs (serde_json `Value` plus gltf-json structs, well under 64x a JSON chunk of at
/// most 256 KiB in practice, and the samples' JSON is < 16 KiB); and copies of the input
/// and its buffers (< 1 MiB each). That sums to < 16 MiB; the bound leaves 2x headroom.
/// Unchecked sizes from mutated headers (up to 4 GiB in a u32 field) would blow it.
const PEAK_BOUND: usize = 32 << 20;

fn install_panic_counter() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        PANICS.fetch_add(1, Relaxed);
        default(info);
    }));
}

/// Runs validator and reader on `bytes`; returns the peak heap growth.
fn run_case(bytes: &[u8], limits: &Limits) -> (usize, bool) {
    let base = CURRENT.load(Relaxed);
    PEAK.store(base, Relaxed);
    let outcome = catch_unwind(AssertUnwindSafe(|| {
        let report = validate_slice(bytes, None, limits);
        let read = read_asset_from_slice_with_limits(bytes, limits);
        (report.has_errors(), read.is_ok())
    }));
    let peak = PEAK.load(Relaxed).saturating_sub(base);
    match outcome {
        Ok((has_errors, _read_ok)) => (peak, has_errors),
        Err(_) => panic!("panicked on a {}-byte input", bytes.len()),
    }
}

fn valid_glb_samples() -> Vec<(String, Vec<u8>)> {
    expected()
        .into_keys()
        .filter(|f| f.starts_with("valid/") && f.ends_with(".glb"))
        .map(|f| {
            let bytes = std::fs::read(samples_dir().join(&f)).unwrap();
            (f, bytes)
        })
        .collect()
}

const INTERESTING_U32: [u32; 8] = [0, 1, 3, 0x7F, 0xFFFF, 0x7FFF_FFFF, 0xFFFF_FFFF, 0x1_0000];

fn mutate(rng: &mut ChaCha8Rng, input: &[u8]) -> Vec<u8> {
    let mut b = input.to_vec();
    let n = rng.random_range(1..=8);
    for _ in 0..n {
        if b.is_empty() {
            b.push(0);
        }
        let at = rng.random_range(0..b.len());
        match rng.random_range(0..7) {
            0 => b[at] ^= 1 << rng.random_range(0..8),
            1 => b[at] = rng.random(),
            2 => {
                let v = INTERESTING_U32[rng.random_range(0..INTERESTING_U32.len())].to_le_bytes();
                let end = (at + 4).min(b.len());
                b[at..end].copy_from_slice(&v[..end - at]);
            }
            3 => {
                // Change a JSON digit so numbers (sizes, indices, offsets) shift.
                if let Some(p) = (at..b.len()).take(4096).find(|&i| b[i].is_ascii_digit()) {
                    b[p] = b'0' + rng.random_range(0..10);
                }
            }
            4 => {
                b.remove(at);
            }
            5 => b.insert(at, rng.random()),
            _ => {
                // Duplicate a short run (shifts everything after it).
                let len = rng.random_range(1..16).min(b.len() - at);
                let run: Vec<u8> = b[at..at + len].to_vec();
                b.splice(at..at, run);
            }
        }
    }
    b
}

#[test]
fn mutated_samples_never_panic_or_overallocate() {
    let _guard = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    install_panic_counter();
    let limits = limits();
    let samples = valid_glb_samples();
    assert!(samples.len() >= 5);
    let mut rng = ChaCha8Rng::seed_from_u64(0x0D1E_5EED);
    const CASES: usize = 40_000;
    let (mut max_peak, mut rejected) = (0usize, 0usize);
    for case in 0..CASES {
        let (_, input) = &samples[case % samples.len()];
        let bytes = mutate(&mut rng, input);
        let (peak, has_errors) = run_case(&bytes, &limits);
        max_peak = max_peak.max(peak);
        rejected += usize::from(has_errors);
        assert!(peak < PEAK_BOUND, "case {case}: peak {peak} bytes");
    }
    assert_eq!(
        PANICS.load(Relaxed),
        0,
        "a panic occurred (maybe caught inside the library)"
    );
    println!("{CASES} mutated cases, {rejected} with errors, peak heap growth {max_peak} bytes");
    // The mutations must mostly hit something, or the test proves little.
    assert!(
        rejected > CASES / 2,
        "only {rejected} of {CASES} mutations were detected"
    );
}

#[test]
fn every_truncation_fails_cleanly() {
    let _guard = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    install_panic_counter();
    let limits = limits();
    let (name, full) = valid_glb_samples()
        .into_iter()
        .find(|(f, _)| f.ends_with("mlp_f16_2levels.glb"))
        .unwrap();
    let mut max_peak = 0;
    for n in 0..full.len() {
        let (peak, has_errors) = run_case(&full[..n], &limits);
        assert!(has_errors, "{name} cut to {n} bytes validated");
        max_peak = max_peak.max(peak);
    }
    let (_, has_errors) = run_case(&full, &limits);
    assert!(!has_errors);

    // Every truncation of the first EXR level inside an otherwise intact GLB: only the
    // full length may decode.
    let glb = parse_glb(&full, &limits).unwrap();
    let json: serde_json::Value = serde_json::from_slice(glb.json).unwrap();
    let view = json["extensions"]["EXT_deferred_neural_rendering"]["neuralTextures"][0]["levels"][0]
        ["bufferView"]
        .as_u64()
        .unwrap() as usize;
    let len = json["bufferViews"][view]["byteLength"].as_u64().unwrap();
    for n in 0..len {
        let mut j = json.clone();
        j["bufferViews"][view]["byteLength"] = serde_json::json!(n);
        let bytes = glb_bytes(&serde_json::to_vec(&j).unwrap(), glb.bin).unwrap();
        let (peak, has_errors) = run_case(&bytes, &limits);
        assert!(has_errors, "EXR cut to {n} of {len} bytes validated");
        max_peak = max_peak.max(peak);
        assert!(peak < PEAK_BOUND);
    }
    assert_eq!(PANICS.load(Relaxed), 0);
    println!(
        "{} file truncations + {len} EXR truncations, peak heap growth {max_peak} bytes",
        full.len()
    );
    assert!(max_peak < PEAK_BOUND);
}
