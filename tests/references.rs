//! The reference renders of the valid samples (`samples/references/`): the runtime reproduces
//! them, within the spec's conformance tolerance and to within f32 rounding of the committed
//! values, and the committed files are what `make_references` writes now.

#[path = "examples/make_references.rs"]
#[allow(dead_code)]
mod make_references;

use std::collections::BTreeSet;
use std::fs;
use std::path::{Path, PathBuf};

use dnr_conformance::samples_dir;
use dnr_runtime::renderer::quantize;

fn files_under(dir: &Path) -> BTreeSet<PathBuf> {
    let mut out = BTreeSet::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in fs::read_dir(&d).unwrap_or_else(|e| panic!("{}: {e}", d.display())) {
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

/// RGBA8 pixels and size of a PNG.
fn decode_png(path: &Path) -> (u32, u32, Vec<u8>) {
    let dec = png::Decoder::new(std::io::BufReader::new(fs::File::open(path).unwrap()));
    let mut reader = dec.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgba, "{}", path.display());
    assert_eq!(info.bit_depth, png::BitDepth::Eight, "{}", path.display());
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

fn read_f32(path: &Path) -> Vec<f32> {
    fs::read(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect()
}

/// The spec's comparison of two 8-bit RGBA images: alpha at every pixel, colour where the
/// reference alpha is above 0. Returns (fraction of pixels within 2 in every compared
/// channel, mean absolute difference over the compared channels).
fn conformance(reference: &[u8], out: &[u8]) -> (f64, f64) {
    assert_eq!(reference.len(), out.len());
    let (mut ok, mut sum, mut count) = (0usize, 0u64, 0u64);
    for (r, o) in reference.chunks_exact(4).zip(out.chunks_exact(4)) {
        let channels: &[usize] = if r[3] > 0 { &[0, 1, 2, 3] } else { &[3] };
        let mut worst = 0;
        for &k in channels {
            let d = r[k].abs_diff(o[k]);
            worst = worst.max(d);
            sum += u64::from(d);
            count += 1;
        }
        ok += usize::from(worst <= 2);
    }
    let n = reference.len() / 4;
    (ok as f64 / n as f64, sum as f64 / count.max(1) as f64)
}

#[test]
fn committed_references_are_current_and_the_runtime_reproduces_them() {
    let samples = samples_dir();
    let tmp = tempfile::tempdir().unwrap();
    make_references::generate(&samples, tmp.path()).unwrap();
    let want = files_under(&tmp.path().join("references"));
    let have = files_under(&samples.join("references"));
    assert_eq!(
        have, want,
        "file lists differ: rerun `cargo run -p dnr-conformance --example make_references`"
    );
    let cams = "cameras.json";
    assert!(
        fs::read(samples.join("references").join(cams)).unwrap()
            == fs::read(tmp.path().join("references").join(cams)).unwrap(),
        "references/cameras.json is stale: rerun make_references"
    );
    let mut images = 0;
    for f in want
        .iter()
        .filter(|f| f.extension().is_some_and(|e| e == "f32"))
    {
        let committed = read_f32(&samples.join("references").join(f));
        let now = read_f32(&tmp.path().join("references").join(f));
        assert_eq!(committed.len(), now.len(), "{}", f.display());
        // Bit-identical on one machine; the margin is for another CPU's f32 rounding.
        let worst = committed
            .iter()
            .zip(&now)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(
            worst <= 1e-5,
            "{}: the runtime differs by {worst}",
            f.display()
        );

        // The PNG is the committed f32 rounded, and matches the runtime's output now.
        let png = f.with_extension("png");
        let (w, h, px) = decode_png(&samples.join("references").join(&png));
        assert_eq!(px.len(), committed.len(), "{}", png.display());
        let rounded: Vec<u8> = committed.iter().map(|&v| quantize(v)).collect();
        assert!(px == rounded, "{} is not its .f32 rounded", png.display());
        let now8: Vec<u8> = now.iter().map(|&v| quantize(v)).collect();
        let (frac, mean) = conformance(&px, &now8);
        assert!(
            frac >= 0.995 && mean <= 0.5,
            "{}: {frac} within 2/255, mean {mean}",
            png.display()
        );
        let shown = px.chunks_exact(4).filter(|p| p[3] > 0).count();
        assert!(
            shown * 10 >= (w * h) as usize,
            "{}: only {shown} of {} pixels show the sample",
            png.display(),
            w * h
        );
        images += 1;
    }
    assert_eq!(
        images,
        3 * 15,
        "three cameras for each of the fifteen valid samples"
    );
}

#[test]
fn every_valid_sample_has_reference_cameras() {
    let listed: BTreeSet<String> = dnr_conformance::expected()
        .into_iter()
        .filter(|(f, _)| f.starts_with("valid/"))
        .map(|(f, _)| f)
        .collect();
    let json: serde_json::Value =
        serde_json::from_slice(&fs::read(samples_dir().join("references/cameras.json")).unwrap())
            .unwrap();
    let with_cameras: BTreeSet<String> = json.as_object().unwrap().keys().cloned().collect();
    assert_eq!(listed, with_cameras);
    for (sample, cams) in json.as_object().unwrap() {
        let cams = cams.as_array().unwrap();
        assert!(cams.len() >= 2, "{sample}");
        // At least one frame size that no U-Net stride (a power of two >= 2) divides.
        assert!(
            cams.iter()
                .any(|c| c["width"].as_u64().unwrap() % 2 == 1
                    || c["height"].as_u64().unwrap() % 2 == 1),
            "{sample}"
        );
    }
}

#[test]
fn the_comparison_can_fail() {
    let a = vec![100u8; 4 * 100];
    let mut b = a.clone();
    assert_eq!(conformance(&a, &b), (1.0, 0.0));
    b[0] = 103; // one pixel off by 3: 99 % within 2
    let (frac, _) = conformance(&a, &b);
    assert!(frac < 0.995);
    let c: Vec<u8> = a.iter().map(|&v| v + 1).collect(); // all off by 1: mean 1 > 0.5
    assert!(conformance(&a, &c).1 > 0.5);
}
