//! Receptive-field skipping of the U-Net: `forward_masked` must equal `forward` bit for bit on
//! random networks, frame sizes and coverage masks, and must compute fewer GEMM columns when
//! little of the frame is covered.

mod nn_common;
use nn_common::*;

use dnr_runtime::network::unet::{Decoder, Norm, UNet, UNetParams};
use dnr_runtime::nn::Tensor;
use rand::Rng;
use std::collections::BTreeMap;

fn random_net(p: &UNetParams, seed: u64) -> UNet {
    let mut r = rng(seed);
    let map: BTreeMap<String, (Vec<usize>, Vec<f32>)> = p
        .tensor_specs()
        .into_iter()
        .map(|(n, s)| {
            let fan_in: usize = s.iter().skip(1).product::<usize>().max(1);
            // Large biases so that the background of every layer is far from zero.
            let scale = if s.len() == 1 {
                1.0
            } else {
                1.5 / (fan_in as f32).sqrt()
            };
            let v = randv(&mut r, s.iter().product())
                .iter()
                .map(|v| v * scale)
                .collect();
            (n, (s, v))
        })
        .collect();
    UNet::from_map(p.clone(), &map).unwrap()
}

/// Coverage masks: empty, one pixel, a small interior blob, a blob on the bottom-right
/// border, everything.
fn masks(h: usize, w: usize, r: &mut impl Rng) -> Vec<(&'static str, Vec<bool>)> {
    let blob = |cy: usize, cx: usize, rad: usize| -> Vec<bool> {
        (0..h * w)
            .map(|i| (i / w).abs_diff(cy) <= rad && (i % w).abs_diff(cx) <= rad)
            .collect()
    };
    let one = r.random_range(0..h * w);
    vec![
        ("empty", vec![false; h * w]),
        ("one pixel", (0..h * w).map(|i| i == one).collect()),
        ("blob", blob(h / 2, w / 3, 2)),
        ("border blob", blob(h - 1, w - 1, 3)),
        ("full", vec![true; h * w]),
    ]
}

fn input(c: usize, h: usize, w: usize, covered: &[bool], r: &mut impl Rng) -> Tensor {
    let mut x = Tensor::zeros(c, h, w);
    for ch in 0..c {
        for (i, &cov) in covered.iter().enumerate() {
            if cov {
                x.data[ch * h * w + i] = r.random_range(-1.0..1.0);
            }
        }
    }
    x
}

fn bits(t: &Tensor) -> Vec<u32> {
    t.data.iter().map(|v| v.to_bits()).collect()
}

#[test]
fn masked_forward_is_bit_identical() {
    let sizes = [(37, 53), (64, 64), (1, 1), (5, 130)];
    let mut r = rng(7);
    let mut k = 0;
    let mut skipped = 0;
    for &(h, w) in &sizes {
        for decoder in [Decoder::TransposedConv, Decoder::UpsampleConv] {
            for norm in [Norm::Instance, Norm::None] {
                let depth = 1 + k % 5;
                k += 1;
                let p = UNetParams {
                    in_ch: 3,
                    out_ch: 3 + k % 2,
                    widths: (0..depth).map(|i| 3 + (i + k) % 4).collect(),
                    decoder,
                    norm,
                };
                let net = random_net(&p, 100 + k as u64);
                for (name, cov) in masks(h, w, &mut r) {
                    let x = input(p.in_ch, h, w, &cov, &mut r);
                    let want = net.forward(&x).unwrap();
                    let got = net.forward_masked(&x, &cov).unwrap();
                    let plan = net.plan(h, w, &cov).unwrap();
                    skipped += plan.iter().filter(|l| l.computed < l.total).count();
                    assert_eq!((got.c, got.h, got.w), (want.c, want.h, want.w));
                    assert!(
                        bits(&got) == bits(&want),
                        "{h}x{w} {p:?} coverage {name}: masked output differs"
                    );
                }
            }
        }
    }
    assert!(
        skipped > 20,
        "the sparse path ran for only {skipped} layers"
    );
}

#[test]
fn nonzero_uncovered_features_count_as_covered() {
    let p = UNetParams {
        in_ch: 2,
        out_ch: 4,
        widths: vec![4, 5, 6],
        decoder: Decoder::TransposedConv,
        norm: Norm::Instance,
    };
    let net = random_net(&p, 3);
    let (h, w) = (29, 41);
    let mut r = rng(11);
    let x = input(2, h, w, &vec![true; h * w], &mut r);
    let mut cov = vec![false; h * w];
    cov[h / 2 * w + w / 2] = true;
    let got = net.forward_masked(&x, &cov).unwrap();
    assert!(bits(&got) == bits(&net.forward(&x).unwrap()));
    assert!(net.forward_masked(&x, &cov[1..]).is_err());
}

#[test]
fn small_blob_computes_fewer_columns() {
    for decoder in [Decoder::TransposedConv, Decoder::UpsampleConv] {
        let p = UNetParams {
            in_ch: 16,
            out_ch: 4,
            widths: vec![16, 32, 64, 128, 128],
            decoder,
            norm: Norm::Instance,
        };
        let net = random_net(&p, 5);
        let (h, w) = (512usize, 512usize);
        let cov: Vec<bool> = (0..h * w)
            .map(|i| (i / w).abs_diff(256) < 64 && (i % w).abs_diff(256) < 64)
            .collect();
        let work = net.plan(h, w, &cov).unwrap();
        assert_eq!(work.len(), 10);
        for l in &work {
            println!(
                "{decoder:?} {}: active {}/{} computed {}/{}",
                l.name, l.active, l.positions, l.computed, l.total
            );
        }
        let (done, all): (usize, usize) = work
            .iter()
            .fold((0, 0), |(d, a), l| (d + l.computed, a + l.total));
        for l in &work {
            assert!(l.active <= l.positions && l.computed <= l.total, "{l:?}");
            assert!(l.active > 0, "{l:?}");
        }
        // The outermost layers see mostly background.
        assert!(work[0].computed * 4 < work[0].total, "{:?}", work[0]);
        assert!(work[9].computed < work[9].total, "{:?}", work[9]);
        assert!(done * 4 < all * 3, "{done} of {all} columns");
        assert!(net.skip_worthwhile(h, w, &cov));
        let big: Vec<bool> = (0..h * w).map(|i| (i % w) < 200).collect();
        assert!(!net.skip_worthwhile(h, w, &big));
        // Full coverage computes everything.
        let full = net.plan(h, w, &vec![true; h * w]).unwrap();
        assert!(full
            .iter()
            .all(|l| l.computed == l.total && l.active == l.positions));
    }
}

/// Timing of the skipping on a 512x512 frame with a centred 128x128 blob (run by hand:
/// `cargo test -p dnr-runtime --test unet_skip timing -- --ignored --nocapture`).
#[test]
#[ignore]
fn timing() {
    use std::time::Instant;
    for decoder in [Decoder::TransposedConv, Decoder::UpsampleConv] {
        let p = UNetParams {
            in_ch: 16,
            out_ch: 4,
            widths: vec![16, 32, 64, 128, 128],
            decoder,
            norm: Norm::Instance,
        };
        let net = random_net(&p, 5);
        let (h, w) = (512usize, 512usize);
        let cov: Vec<bool> = (0..h * w)
            .map(|i| (i / w).abs_diff(256) < 64 && (i % w).abs_diff(256) < 64)
            .collect();
        let x = input(16, h, w, &cov, &mut rng(1));
        let t = Instant::now();
        let work = net.plan(h, w, &cov).unwrap();
        let tp = t.elapsed();
        let t = Instant::now();
        let a = net.forward(&x).unwrap();
        let tf = t.elapsed();
        let t = Instant::now();
        let b = net.forward_masked(&x, &cov).unwrap();
        let tm = t.elapsed();
        assert!(bits(&a) == bits(&b));
        println!("{decoder:?}: plan {tp:?} full {tf:?} masked {tm:?}");
        let _ = work;
    }
}

/// Planning costs the same per position whatever the widths, so a thin network never skips
/// (measured: the sample U-Nets of widths 4, 8 ran 2x slower with skipping), while the
/// CPU-sized one does on the same coverage.
#[test]
fn thin_networks_are_evaluated_whole() {
    let (h, w) = (512usize, 512usize);
    let cov: Vec<bool> = (0..h * w)
        .map(|i| (i / w).abs_diff(256) < 64 && (i % w).abs_diff(256) < 64)
        .collect();
    let net = |widths: Vec<usize>| {
        let p = UNetParams {
            in_ch: 16,
            out_ch: 4,
            widths,
            decoder: Decoder::TransposedConv,
            norm: Norm::Instance,
        };
        random_net(&p, 3)
    };
    assert!(!net(vec![4, 8]).skip_worthwhile(h, w, &cov));
    assert!(net(vec![16, 32, 64, 128, 128]).skip_worthwhile(h, w, &cov));
    // Nothing covered: only the background classes are computed, whatever the widths.
    assert!(net(vec![4, 8]).skip_worthwhile(h, w, &vec![false; h * w]));
}
