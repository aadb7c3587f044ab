//! Conformance: the samples on disk are what the generator makes now; valid samples
//! validate clean and round-trip byte-identically; invalid samples give exactly their
//! expected codes, make `dnr validate` exit non-zero, and never panic.

#[path = "../crates/format/examples/make_samples.rs"]
#[allow(dead_code)]
mod make_samples;

use std::collections::BTreeSet;
use std::fs;
use std::panic::catch_unwind;
use std::path::{Path, PathBuf};
use std::process::Command;

use dnr_conformance::{dnr_exe, expected, samples_dir};
use dnr_format::validate::{code_info, Severity};
use dnr_format::{read_asset, validate_file, Container, Limits};

fn files_under(dir: &Path) -> BTreeSet<PathBuf> {
    let mut out = BTreeSet::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.insert(p.strip_prefix(dir).unwrap().to_path_buf());
            }
        }
    }
    out
}

#[test]
fn samples_on_disk_equal_generator_output() {
    let tmp = tempfile::tempdir().unwrap();
    let generated = make_samples::generate(tmp.path()).unwrap();
    let want = files_under(tmp.path());
    // Other folders of samples/ (e.g. capture/) belong to other tools.
    let have: BTreeSet<PathBuf> = files_under(&samples_dir())
        .into_iter()
        .filter(|p| {
            p.starts_with("valid")
                || p.starts_with("invalid")
                || p.starts_with("warnings")
                || p == Path::new("README.md")
                || p == Path::new("expected.json")
        })
        .collect();
    assert_eq!(
        have, want,
        "file lists differ: rerun `cargo run -p dnr-format --example make_samples -- samples`"
    );
    for f in &want {
        let a = fs::read(tmp.path().join(f)).unwrap();
        let b = fs::read(samples_dir().join(f)).unwrap();
        assert!(a == b, "{} is stale: rerun make_samples", f.display());
    }
    // And the generator is deterministic within one process too.
    let tmp2 = tempfile::tempdir().unwrap();
    make_samples::generate(tmp2.path()).unwrap();
    for f in &want {
        assert_eq!(
            fs::read(tmp.path().join(f)).unwrap(),
            fs::read(tmp2.path().join(f)).unwrap()
        );
    }
    assert!(generated.len() >= 40);
}

#[test]
fn expected_json_lists_every_sample() {
    let listed: BTreeSet<PathBuf> = expected().keys().map(PathBuf::from).collect();
    let on_disk: BTreeSet<PathBuf> = files_under(&samples_dir())
        .into_iter()
        .filter(|p| p.starts_with("valid") || p.starts_with("invalid") || p.starts_with("warnings"))
        .filter(|p| p.extension().is_some_and(|e| e == "glb" || e == "gltf"))
        .collect();
    assert_eq!(listed, on_disk);
    for codes in expected().values() {
        for c in codes {
            assert!(code_info(c).is_some(), "unknown code {c} in expected.json");
        }
    }
}

/// Re-encodes a container the way it is stored and returns the bytes of the main file
/// (and of the external buffer, for `.gltf` files with one).
fn rewrite(c: &Container, original: &Path, into: &Path) -> (Vec<u8>, Option<Vec<u8>>) {
    let name = original.file_name().unwrap();
    let is_gltf = original.extension().is_some_and(|e| e == "gltf");
    let external = is_gltf
        && c.root
            .buffers
            .iter()
            .any(|b| b.uri.as_deref().is_some_and(|u| !u.starts_with("data:")));
    let out = into.join(name);
    if external {
        c.write_gltf_external(&out).unwrap();
        let bin = out.with_extension("bin");
        (fs::read(&out).unwrap(), Some(fs::read(bin).unwrap()))
    } else {
        let bytes = if is_gltf {
            c.to_gltf_embedded().unwrap()
        } else {
            c.to_glb().unwrap()
        };
        fs::write(&out, &bytes).unwrap();
        (bytes, None)
    }
}

#[test]
fn valid_samples_are_clean_and_round_trip() {
    let limits = Limits::default();
    let mut n = 0;
    for (file, codes) in expected() {
        if !file.starts_with("valid/") {
            continue;
        }
        n += 1;
        assert!(codes.is_empty());
        let path = samples_dir().join(&file);
        let report = validate_file(&path, &limits).unwrap();
        assert!(report.issues.is_empty(), "{file}: {:#?}", report.issues);

        // write -> read -> write is byte-identical, and equal to the file on disk.
        let original = fs::read(&path).unwrap();
        let c1 = Container::read(&path, &limits).unwrap();
        let t1 = tempfile::tempdir().unwrap();
        let (w1, bin1) = rewrite(&c1, &path, t1.path());
        assert!(w1 == original, "{file}: rewriting changed the bytes");
        if let Some(bin) = &bin1 {
            assert_eq!(bin, &fs::read(path.with_extension("bin")).unwrap());
        }
        let c2 = Container::read(&t1.path().join(path.file_name().unwrap()), &limits).unwrap();
        let t2 = tempfile::tempdir().unwrap();
        let (w2, bin2) = rewrite(&c2, &path, t2.path());
        assert!(w1 == w2 && bin1 == bin2, "{file}: second rewrite differs");

        // The high layer decodes everything and agrees with the JSON.
        let asset = read_asset(&path).unwrap();
        let ext = asset.extension.as_ref().unwrap();
        assert_eq!(asset.textures.len(), ext.neural_textures.len());
        for (t, j) in asset.textures.iter().zip(&ext.neural_textures) {
            assert_eq!(t.levels.len(), j.levels.len());
            for (l, lj) in t.levels.iter().zip(&j.levels) {
                assert_eq!(
                    (l.width, l.height, l.channels),
                    (lj.width, lj.height, j.channels)
                );
                assert_eq!(l.data.len(), (l.width * l.height * l.channels) as usize);
                assert!(l.data.iter().all(|v| v.is_finite()));
            }
        }
        // Bindings live on mesh primitives; fallback materials carry only KHR_materials_unlit
        // (with anything else beside it glTF-Validator warns MULTIPLE_EXTENSIONS).
        let root = &asset.container.root;
        for (i, m) in root.materials.iter().enumerate() {
            let ext = m.extensions.as_ref().unwrap();
            assert!(
                ext.unlit.is_some() && ext.others.is_empty(),
                "{file}: material {i}"
            );
            assert!(m.pbr_metallic_roughness.base_color_texture.is_some());
        }
        assert_eq!(asset.primitives.len(), root.meshes.len(), "{file}");
        let mut bound = 0;
        for (mi, mesh) in root.meshes.iter().enumerate() {
            assert_eq!(asset.primitives[mi].len(), mesh.primitives.len(), "{file}");
            for (pi, p) in mesh.primitives.iter().enumerate() {
                let json = dnr_format::asset::primitive_extension_value(p);
                let b = asset.binding(mi, pi);
                assert_eq!(
                    json.is_some(),
                    b.is_some(),
                    "{file}: mesh {mi} primitive {pi}"
                );
                if let (Some(json), Some(b)) = (json, b) {
                    bound += 1;
                    assert_eq!(json["neuralTexture"], b.neural_texture, "{file}");
                    assert_eq!(json["renderer"], b.renderer, "{file}");
                    assert!((b.neural_texture as usize) < asset.textures.len());
                    assert!((b.renderer as usize) < asset.renderers.len());
                    assert!(
                        p.material.is_some(),
                        "{file}: bound primitive without fallback"
                    );
                }
            }
        }
        assert!(bound > 0, "{file}: no primitive is bound");
        for r in &asset.renderers {
            let required = dnr_format::architecture_tensors(&r.spec).unwrap();
            assert_eq!(r.tensors.len(), required.len(), "{file}");
            for (name, shape) in required {
                assert_eq!(r.tensors[&name].shape, shape, "{file} {name}");
            }
        }
        let asset_bytes = {
            let t3 = tempfile::tempdir().unwrap();
            let out = t3.path().join("a.glb");
            dnr_format::write_asset(&out, &asset).unwrap();
            fs::read(out).unwrap()
        };
        assert_eq!(asset_bytes, asset.container.to_glb().unwrap());
    }
    assert!(n >= 9, "only {n} valid samples");
}

#[test]
fn invalid_samples_give_expected_codes_without_panicking() {
    let limits = Limits::default();
    let mut n = 0;
    for (file, codes) in expected() {
        if !file.starts_with("invalid/") && !file.starts_with("warnings/") {
            continue;
        }
        n += 1;
        let path = samples_dir().join(&file);
        let want: BTreeSet<&str> = codes.iter().map(String::as_str).collect();
        let report = catch_unwind(|| validate_file(&path, &limits).unwrap())
            .unwrap_or_else(|_| panic!("{file}: the validator panicked"));
        assert_eq!(report.codes(), want, "{file}: {:#?}", report.issues);
        for i in &report.issues {
            assert!(
                i.pointer.is_empty() || i.pointer.starts_with('/'),
                "{file}: pointer {}",
                i.pointer
            );
        }
        // The reader must refuse what the validator calls an error.
        let has_error = want
            .iter()
            .any(|c| code_info(c).unwrap().severity == Severity::Error);
        // invalid/ files all carry an error (dnr validate exits 1); warnings/ files none.
        assert_eq!(
            has_error,
            file.starts_with("invalid/"),
            "{file}: folder and severity disagree"
        );
        let read = catch_unwind(|| read_asset(&path))
            .unwrap_or_else(|_| panic!("{file}: read_asset panicked"));
        assert_eq!(
            read.is_err(),
            has_error,
            "{file}: read_asset gave {:?}",
            read.as_ref().err()
        );
        if let Err(e) = read {
            let msg = e.to_string();
            assert!(
                msg.contains(path.file_name().unwrap().to_str().unwrap()),
                "{file}: the error does not name the file: {msg}"
            );
        }
    }
    assert!(n >= 30, "only {n} invalid samples");
}

#[test]
fn cli_validate_exit_codes_and_json() {
    let exe = dnr_exe();
    for (file, codes) in expected() {
        let path = samples_dir().join(&file);
        let has_error = codes
            .iter()
            .any(|c| code_info(c).unwrap().severity == Severity::Error);
        let out = Command::new(exe)
            .arg("validate")
            .arg(&path)
            .output()
            .unwrap();
        assert_eq!(
            out.status.code(),
            Some(if has_error { 1 } else { 0 }),
            "{file}"
        );
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(
            text.contains(path.file_name().unwrap().to_str().unwrap()),
            "{file}: {text}"
        );

        let out = Command::new(exe)
            .args(["validate", "--json"])
            .arg(&path)
            .output()
            .unwrap();
        assert_eq!(
            out.status.code(),
            Some(if has_error { 1 } else { 0 }),
            "{file}"
        );
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        assert_eq!(v["valid"], serde_json::json!(!has_error), "{file}");
        let got: BTreeSet<String> = v["issues"]
            .as_array()
            .unwrap()
            .iter()
            .map(|i| i["code"].as_str().unwrap().to_string())
            .collect();
        assert_eq!(
            got,
            codes.iter().cloned().collect::<BTreeSet<_>>(),
            "{file}"
        );
    }
    let missing = Command::new(exe)
        .args(["validate", "no/such/file.glb"])
        .output()
        .unwrap();
    assert_eq!(missing.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&missing.stderr).contains("no/such/file.glb"));
}

#[test]
fn cli_inspect_reports_every_part() {
    let exe = dnr_exe();
    let path = samples_dir().join("valid/scene_multi_primitive.glb");
    let out = Command::new(exe)
        .args(["inspect", "--json"])
        .arg(&path)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["neural_textures"].as_array().unwrap().len(), 2);
    assert_eq!(v["neural_textures"][1]["channels"], 19);
    assert!(v["neural_textures"][1]["view_dependence"]
        .as_str()
        .unwrap()
        .contains("degree 3"));
    assert_eq!(v["renderers"][1]["architecture"], "mlp");
    // Mesh 0 (two quads: none, then mlp) and mesh 1 (pyramid: mlp), each with its fallback.
    let bindings: Vec<_> = v["bindings"]
        .as_array()
        .unwrap()
        .iter()
        .map(|b| {
            let n = |k: &str| b[k].as_u64().unwrap();
            (
                n("mesh"),
                n("primitive"),
                n("neural_texture"),
                n("renderer"),
                n("material"),
            )
        })
        .collect();
    assert_eq!(
        bindings,
        [(0, 0, 0, 0, 0), (0, 1, 1, 1, 1), (1, 0, 1, 1, 1)]
    );
    // mlp 19 -> [6] -> 4: 19*6 + 6 + 6*4 + 4 parameters.
    assert_eq!(v["renderers"][1]["parameter_count"], 19 * 6 + 6 + 6 * 4 + 4);
    let b = &v["bytes"];
    for part in ["mesh", "fallback_images", "texture_levels", "weights"] {
        assert!(b[part].as_u64().unwrap() > 0, "{part}");
    }
    assert_eq!(b["other_buffer_views"], 0);
    let text = Command::new(exe)
        .arg("inspect")
        .arg(&path)
        .output()
        .unwrap();
    assert!(text.status.success());
    let text = String::from_utf8_lossy(&text.stdout);
    assert!(text.contains("level 1"));
    assert!(
        text.contains("mesh 1 primitive 0: neural texture 1, renderer 1"),
        "{text}"
    );
}
