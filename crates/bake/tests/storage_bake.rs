//! `--storage`: bakes of the sample capture with quantised storage write revision 1.1 assets
//! that validate and store what was asked (PNG levels at the asked depth, `int8` weight
//! matrices, f16 biases); the last part of training runs through the rounding; the report
//! lists every storage of the same state, and its `chosen` row is the asset that was written.

mod capture_common;

use std::path::Path;

use dnr_bake::bake::{bake, BakeOptions, Summary};
use dnr_bake::storage::StorageMode;
use dnr_bake::train::config::{Arch, Preset, TrainConfig};
use dnr_format::model::DType;
use serde_json::Value;

fn cfg() -> TrainConfig {
    TrainConfig {
        resolution: 32,
        levels: 2,
        channels: 12,
        arch: Arch::Unet,
        widths: vec![4, 8],
        steps: 40,
        time_budget: 0.0,
        eval_every: 0.0,
        threads: 2,
        seed: 7,
        ..TrainConfig::preset(Preset::Fast)
    }
}

fn opts(out: &Path, storage: StorageMode, bound_db: f64) -> BakeOptions {
    BakeOptions {
        report: Some(out.with_extension("json")),
        storage,
        storage_bound_db: bound_db,
        write_f16: Some(out.with_extension("f16.glb")),
        ..BakeOptions::new(capture_common::sample_capture(), out)
    }
}

fn run(out: &Path, storage: StorageMode, bound_db: f64) -> (Summary, Value) {
    let summary = bake(&cfg(), &opts(out, storage, bound_db)).unwrap();
    let report: Value =
        serde_json::from_str(&std::fs::read_to_string(out.with_extension("json")).unwrap())
            .unwrap();
    (summary, report)
}

fn assert_clean(path: &Path) {
    let r = dnr_format::validate_file(path, &dnr_format::Limits::default()).unwrap();
    assert!(r.issues.is_empty(), "{}: {:#?}", path.display(), r.issues);
}

/// Per level, finest first, the quantisation bits (`None`: EXR).
type LevelBits = Vec<Option<u32>>;
/// Per tensor, its shape and dtype.
type TensorTypes = Vec<(String, Vec<u32>, DType)>;

/// The stored encodings of the asset's first texture and first renderer.
fn encodings(path: &Path) -> (LevelBits, TensorTypes) {
    let c = dnr_format::Container::read(path, &dnr_format::Limits::default()).unwrap();
    let v = dnr_format::asset::root_extension_value(&c.root).unwrap();
    let ext: dnr_format::model::Extension = serde_json::from_value(v.clone()).unwrap();
    let levels = ext.neural_textures[0]
        .levels
        .iter()
        .map(|l| l.quantization.as_ref().map(|q| q.bits))
        .collect();
    let weights = ext.renderers[0]
        .weights
        .iter()
        .map(|w| (w.name.clone(), w.shape.clone(), w.dtype.clone()))
        .collect();
    (levels, weights)
}

fn variant<'a>(report: &'a Value, name: &str) -> &'a Value {
    report["storage"]["variants"]
        .as_array()
        .unwrap()
        .iter()
        .find(|v| v["name"] == name)
        .unwrap_or_else(|| panic!("no variant {name}"))
}

#[test]
fn quantised_bakes_store_what_was_asked_and_report_every_storage() {
    let dir = tempfile::tempdir().unwrap();
    let mut level_bytes = Vec::new();
    for (mode, bits) in [(StorageMode::Q8, 8), (StorageMode::Q4, 4)] {
        let out = dir.path().join(format!("q{bits}.glb"));
        let (summary, report) = run(&out, mode, 0.1);
        assert_clean(&out);
        assert_clean(&out.with_extension("f16.glb"));
        let (levels, weights) = encodings(&out);
        assert_eq!(levels, vec![Some(bits); levels.len()], "q{bits}");
        for (_, shape, dtype) in &weights {
            let want = if shape.len() >= 2 {
                DType::Int8
            } else {
                DType::F16
            };
            assert_eq!(*dtype, want, "tensor of shape {shape:?}");
        }
        let (f16_levels, f16_weights) = encodings(&out.with_extension("f16.glb"));
        assert!(f16_levels.iter().all(Option::is_none));
        assert!(f16_weights.iter().all(|(_, _, d)| *d == DType::F16));

        let storage = &report["storage"];
        assert_eq!(storage["mode"], format!("q{bits}"));
        let qat = &storage["qat"];
        assert_eq!(qat["int8Weights"], true, "{qat}");
        assert!(
            qat["levelBits"]
                .as_array()
                .unwrap()
                .iter()
                .all(|b| b.as_u64() == Some(u64::from(bits))),
            "{qat}"
        );
        // The chosen row is the written asset: its bytes and, rendered by the runtime, its
        // held-out PSNR.
        let chosen = variant(&report, "chosen");
        let file_len = std::fs::metadata(&out).unwrap().len();
        assert_eq!(chosen["bytes"]["total"].as_u64(), Some(file_len));
        assert_eq!(summary.asset_bytes, file_len);
        let test_psnr = chosen["testPsnr"].as_f64().unwrap();
        assert!(
            (test_psnr - summary.test_psnr).abs() < 1e-9,
            "{test_psnr} vs {}",
            summary.test_psnr
        );
        let f16 = variant(&report, "f16");
        assert_eq!(
            f16["bytes"]["total"].as_u64(),
            Some(
                std::fs::metadata(out.with_extension("f16.glb"))
                    .unwrap()
                    .len()
            )
        );
        let level_total = |v: &Value| -> u64 {
            v["bytes"]["levels"]
                .as_array()
                .unwrap()
                .iter()
                .map(|b| b.as_u64().unwrap())
                .sum()
        };
        assert!(
            chosen["bytes"]["weights"].as_u64() < f16["bytes"]["weights"].as_u64(),
            "int8 weights are smaller"
        );
        // Quantisation costs little on a model this small: within 1 dB of f16.
        let f16_test = f16["testPsnr"].as_f64().unwrap();
        assert!(
            test_psnr > f16_test - 1.0,
            "q{bits} {test_psnr} dB, f16 {f16_test} dB"
        );
        level_bytes.push((
            level_total(f16),
            level_total(variant(&report, "q8")),
            level_total(variant(&report, "q4")),
        ));
    }
    for (f16, q8, q4) in level_bytes {
        assert!(
            q4 < q8 && q8 < f16,
            "level bytes f16 {f16}, q8 {q8}, q4 {q4}"
        );
    }
}

#[test]
fn auto_storage_keeps_only_what_costs_less_than_the_bound() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("auto.glb");
    let bound = 0.1;
    let (summary, report) = run(&out, StorageMode::Auto, bound);
    assert_clean(&out);
    let storage = &report["storage"];
    assert_eq!(storage["mode"], "auto");
    let trials = storage["trials"].as_array().unwrap();
    // Each level is tried (coarsest grid first), then the weights; at most one encoding of
    // a part is kept, and only one that alone costs less than the credited bound.
    assert!(trials.len() >= 3, "{trials:?}");
    let mut kept = std::collections::BTreeSet::new();
    for t in trials {
        if t["chosen"] == true {
            let credited = bound * dnr_bake::storage::FINE_TUNE_CREDIT;
            assert!(t["costDb"].as_f64().unwrap() <= credited, "{t}");
            assert!(kept.insert(t["part"].as_str().unwrap().to_string()), "{t}");
        }
    }
    // Together the choices were measured: the one fine-tuned toward cost at most the credited
    // bound before the fine-tune, and the reserve at most the bound itself.
    let combined = &storage["combined"];
    let rounds = combined["rounds"].as_array().unwrap();
    let accept = combined["acceptDb"].as_f64().unwrap();
    assert!((accept - bound * dnr_bake::storage::FINE_TUNE_CREDIT).abs() < 1e-12);
    let cost_of = |s: &Value| {
        rounds
            .iter()
            .find(|r| r["storage"] == *s)
            .and_then(|r| r["costDb"].as_f64())
    };
    let check = &storage["finalCheck"];
    let checked = check["checked"].as_array().unwrap();
    if !kept.is_empty() {
        let first = &checked[0][0];
        assert!(cost_of(first).unwrap() <= accept, "{storage}");
        if !combined["safe"].is_null() {
            assert!(cost_of(&combined["safe"]).unwrap() <= bound, "{storage}");
        }
    }
    // After the fine-tune the written storage is the first checked within the bound against
    // the f16 copy of the final state; those before it were over.
    assert_eq!(check["written"], storage["chosen"], "{storage}");
    let f16 = variant(&report, "f16");
    let written = variant(&report, "chosen");
    let cost = f16["valPsnr"].as_f64().unwrap() - written["valPsnr"].as_f64().unwrap();
    assert!(cost <= bound + 1e-9, "{storage}");
    for (i, c) in checked.iter().enumerate() {
        let over = c[1].as_f64().unwrap() > bound;
        assert_eq!(over, i + 1 < checked.len(), "{storage}");
    }
    assert_eq!(checked.last().unwrap()[0], storage["chosen"], "{storage}");
    // What the asset stores is what the report says was chosen: `qP` is a 4-bit PNG up to
    // q4 and an 8-bit one above.
    let (levels, weights) = encodings(&out);
    let names: Vec<&str> = storage["levels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    let precision = |name: &str| name.strip_prefix('q').and_then(|p| p.parse::<u32>().ok());
    let containers: Vec<Option<u32>> = names
        .iter()
        .map(|n| precision(n).map(|p| if p <= 4 { 4 } else { 8 }))
        .collect();
    assert_eq!(containers, levels, "{names:?}");
    // Each tensor is stored as its override says (the large tensors), else as the rest.
    let qat = &storage["qat"];
    let rest = if storage["weights"] == "int8" {
        DType::Int8
    } else {
        DType::F16
    };
    for (name, _, dtype) in &weights {
        let want = match storage["tensorDtypes"][name.as_str()].as_str() {
            Some("int4") => DType::Int4,
            Some("int8") => DType::Int8,
            Some(other) => panic!("{name}: unexpected override {other}"),
            None => rest.clone(),
        };
        assert_eq!(*dtype, want, "{name}: {storage}");
    }
    let int8 = rest == DType::Int8;
    // The choice was made on the unquantised state when the fine-tune started, and the
    // fine-tune imitated exactly that choice.
    let when = storage["measuredOn"]["when"].as_str().unwrap_or("");
    assert!(when.starts_with("start of the fine-tune"), "{storage}");
    if checked.len() > 1 {
        // Written in reserve: not what the fine-tune imitated.
    } else if qat.is_null() {
        assert!(names.iter().all(|s| *s == "f16") && !int8, "{storage}");
        assert!(
            weights.iter().all(|(_, _, d)| *d == DType::F16),
            "{storage}"
        );
    } else {
        let bits: Vec<Option<u32>> = qat["levelBits"]
            .as_array()
            .unwrap()
            .iter()
            .map(|b| b.as_u64().map(|b| b as u32))
            .collect();
        let want: Vec<Option<u32>> = names.iter().map(|n| precision(n)).collect();
        assert_eq!(bits, want, "{storage}");
        assert_eq!(qat["int8Weights"] == true, int8, "{storage}");
        assert_eq!(qat["tensorDtypes"], storage["tensorDtypes"], "{storage}");
    }
    let chosen = variant(&report, "chosen");
    assert!((chosen["testPsnr"].as_f64().unwrap() - summary.test_psnr).abs() < 1e-9);
}

#[test]
fn f16_bakes_write_revision_1_0_and_measure_nothing_more() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("f16.glb");
    let (_, report) = run(&out, StorageMode::F16, 0.1);
    assert_clean(&out);
    let (levels, weights) = encodings(&out);
    assert!(levels.iter().all(Option::is_none));
    assert!(weights.iter().all(|(_, _, d)| *d == DType::F16));
    let storage = &report["storage"];
    assert_eq!(storage["qat"], Value::Null);
    assert_eq!(storage["variants"].as_array().map(Vec::len), Some(0));
    // --write-f16 of an f16 bake is the same asset.
    assert_eq!(
        std::fs::read(&out).unwrap(),
        std::fs::read(out.with_extension("f16.glb")).unwrap()
    );
}
