//! U-Net and MLP renderers against a naive f64 composition of direct-loop layers, on odd image
//! sizes (padding and cropping exercised), plus weight-name/shape validation.
//! Tolerance: 1e-4 relative (several layers of f32 rounding, amplified by instance norm).

mod nn_common;
use nn_common::*;

use dnr_runtime::network::mlp::{Mlp, MlpParams};
use dnr_runtime::network::unet::{Decoder, Norm, UNet, UNetParams};
use dnr_runtime::network::NetworkError;
use dnr_runtime::nn::Tensor;
use std::collections::BTreeMap;

type Weights = BTreeMap<String, (Vec<usize>, Vec<f32>)>;

fn random_weights(specs: &[(String, Vec<usize>)], seed: u64) -> Weights {
    let mut r = rng(seed);
    specs
        .iter()
        .map(|(n, s)| {
            let fan_in: usize = if s.len() == 4 {
                s[1] * s[2] * s[3]
            } else {
                s.iter().product()
            };
            let scale = 1.0 / (fan_in.max(1) as f32).sqrt();
            (
                n.clone(),
                (
                    s.clone(),
                    randv(&mut r, s.iter().product())
                        .iter()
                        .map(|v| v * scale)
                        .collect(),
                ),
            )
        })
        .collect()
}

/// f64 tensor: (c, h, w, data).
#[derive(Clone)]
struct T64 {
    c: usize,
    h: usize,
    w: usize,
    d: Vec<f64>,
}

fn to_t32(t: &T64) -> Tensor {
    Tensor::from_vec(t.c, t.h, t.w, t.d.iter().map(|&v| v as f32).collect()).unwrap()
}

fn naive_norm_act(t: &mut T64, norm: bool, act: bool) {
    let n = t.h * t.w;
    for c in 0..t.c {
        let p = &mut t.d[c * n..(c + 1) * n];
        if norm {
            let mean = p.iter().sum::<f64>() / n as f64;
            let var = p.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n as f64;
            let rstd = 1.0 / (var + 1e-5).sqrt();
            p.iter_mut().for_each(|v| *v = (*v - mean) * rstd);
        }
        if act {
            p.iter_mut().for_each(|v| {
                if *v < 0.0 {
                    *v *= 0.2
                }
            });
        }
    }
}

/// Naive U-Net. The layer references take f32 inputs, so activations are rounded to f32
/// between layers (as the network under test does); accumulation is f64.
fn naive_unet(p: &UNetParams, w: &Weights, x: &Tensor) -> Vec<f64> {
    let d = p.widths.len();
    let pp = 1 << d;
    let (hp, wp) = (x.h.div_ceil(pp) * pp, x.w.div_ceil(pp) * pp);
    let xp = x.pad_bottom_right(hp, wp);
    let get = |n: &str| &w[n].1;
    let norm = p.norm == Norm::Instance;
    let mut skips = Vec::new();
    let mut cur = xp;
    for i in 0..d {
        let (h, ww, y) = conv_ref(
            &cur,
            get(&format!("encoder.{i}.weight")),
            Some(get(&format!("encoder.{i}.bias"))),
            p.widths[i],
            4,
            2,
            1,
        );
        let mut t = T64 {
            c: p.widths[i],
            h,
            w: ww,
            d: y,
        };
        naive_norm_act(&mut t, norm, true);
        cur = to_t32(&t);
        skips.push(cur.clone());
    }
    let mut cur = skips.pop().unwrap();
    for i in (0..d).rev() {
        let co = if i == 0 { p.out_ch } else { p.widths[i - 1] };
        let wt = get(&format!("decoder.{i}.weight"));
        let b = get(&format!("decoder.{i}.bias"));
        let y = match p.decoder {
            Decoder::TransposedConv => T64 {
                c: co,
                h: 2 * cur.h,
                w: 2 * cur.w,
                d: tconv_ref(&cur, wt, Some(b), co),
            },
            Decoder::UpsampleConv => {
                let mut u = Tensor::zeros(cur.c, 2 * cur.h, 2 * cur.w);
                for c in 0..cur.c {
                    for yy in 0..u.h {
                        for xx in 0..u.w {
                            u.data[(c * u.h + yy) * u.w + xx] = cur.at(c, yy / 2, xx / 2);
                        }
                    }
                }
                let (h, ww, y) = conv_ref(&u, wt, Some(b), co, 3, 1, 1);
                T64 {
                    c: co,
                    h,
                    w: ww,
                    d: y,
                }
            }
        };
        let mut y = y;
        if i == 0 {
            let mut out = Vec::new();
            for c in 0..co {
                for yy in 0..x.h {
                    for xx in 0..x.w {
                        out.push(y.d[(c * y.h + yy) * y.w + xx].tanh());
                    }
                }
            }
            return out;
        }
        naive_norm_act(&mut y, norm, true);
        cur = to_t32(&y).concat(&skips.pop().unwrap()).unwrap();
    }
    unreachable!()
}

#[test]
fn unet_matches_naive_composition() {
    let mut r = rng(20);
    let cases = [
        (vec![3, 4], Decoder::TransposedConv, Norm::Instance, 5, 7),
        (vec![4, 6, 5], Decoder::TransposedConv, Norm::None, 9, 3),
        (vec![3, 5], Decoder::UpsampleConv, Norm::Instance, 8, 13),
        (vec![2], Decoder::UpsampleConv, Norm::None, 1, 1),
        (vec![5], Decoder::TransposedConv, Norm::Instance, 3, 2),
        (
            vec![8, 16, 16, 32],
            Decoder::TransposedConv,
            Norm::Instance,
            37,
            29,
        ),
    ];
    for (k, (widths, decoder, norm, h, w)) in cases.into_iter().enumerate() {
        for out_ch in [3, 4] {
            let p = UNetParams {
                in_ch: 6,
                out_ch,
                widths: widths.clone(),
                decoder,
                norm,
            };
            let weights = random_weights(&p.tensor_specs(), 100 + k as u64);
            let net = UNet::from_map(p.clone(), &weights).unwrap();
            let x = randt(&mut r, 6, h, w);
            let y = net.forward(&x).unwrap();
            assert_eq!((y.c, y.h, y.w), (out_ch, h, w));
            assert_close(
                &y.data,
                &naive_unet(&p, &weights, &x),
                1e-4,
                &format!("unet case {k} out {out_ch}"),
            );
        }
    }
}

#[test]
fn unet_validates_weights() {
    let p = UNetParams {
        in_ch: 4,
        out_ch: 3,
        widths: vec![3, 5],
        decoder: Decoder::TransposedConv,
        norm: Norm::Instance,
    };
    let specs = p.tensor_specs();
    let names: Vec<&str> = specs.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(
        names,
        [
            "encoder.0.weight",
            "encoder.0.bias",
            "encoder.1.weight",
            "encoder.1.bias",
            "decoder.0.weight",
            "decoder.0.bias",
            "decoder.1.weight",
            "decoder.1.bias"
        ]
    );
    assert_eq!(specs[2].1, vec![5, 3, 4, 4]);
    assert_eq!(specs[4].1, vec![6, 3, 4, 4], "decoder.0: [2 w0, out, 4, 4]");
    assert_eq!(specs[6].1, vec![5, 3, 4, 4], "decoder.1: [w1, w0, 4, 4]");
    let up = UNetParams {
        decoder: Decoder::UpsampleConv,
        ..p.clone()
    };
    assert_eq!(up.tensor_specs()[4].1, vec![3, 6, 3, 3]);

    let good = random_weights(&specs, 1);
    assert!(UNet::from_map(p.clone(), &good).is_ok());
    let mut missing = good.clone();
    missing.remove("decoder.1.bias");
    assert_eq!(
        UNet::from_map(p.clone(), &missing).unwrap_err(),
        NetworkError::Missing("decoder.1.bias".into())
    );
    let mut extra = good.clone();
    extra.insert("decoder.2.bias".into(), (vec![1], vec![0.0]));
    assert_eq!(
        UNet::from_map(p.clone(), &extra).unwrap_err(),
        NetworkError::Unexpected("decoder.2.bias".into())
    );
    let mut wrong = good.clone();
    wrong.insert(
        "encoder.1.weight".into(),
        (vec![5, 3, 3, 3], vec![0.0; 135]),
    );
    assert!(matches!(
        UNet::from_map(p.clone(), &wrong),
        Err(NetworkError::Shape { .. })
    ));
    let mut short = good.clone();
    short.insert("encoder.1.bias".into(), (vec![5], vec![0.0; 4]));
    assert!(matches!(
        UNet::from_map(p.clone(), &short),
        Err(NetworkError::Length { .. })
    ));
    let mut nan = good;
    nan.get_mut("encoder.0.bias").unwrap().1[0] = f32::NAN;
    assert!(matches!(
        UNet::from_map(p.clone(), &nan),
        Err(NetworkError::NonFinite(_))
    ));
    for bad in [vec![], vec![4; 9], vec![3, 0]] {
        let q = UNetParams {
            widths: bad,
            ..p.clone()
        };
        assert!(matches!(
            UNet::from_map(q, &BTreeMap::new()),
            Err(NetworkError::Params(_))
        ));
    }
}

#[test]
fn unet_flops_match_paper_figures() {
    // docs: CPU-sized U-Net at 256x256, 16 -> 3 channels: 0.856 GFLOP; paper U-Net 11.48 GFLOP.
    let cpu = UNetParams {
        in_ch: 16,
        out_ch: 3,
        widths: vec![16, 32, 64, 128, 128],
        decoder: Decoder::TransposedConv,
        norm: Norm::Instance,
    };
    assert_eq!(cpu.flops(256, 256), 855_638_016);
    let paper = UNetParams {
        widths: vec![64, 128, 256, 512, 512],
        ..cpu
    };
    assert!((paper.flops(256, 256) as f64 / 11.48e9 - 1.0).abs() < 1e-3);
}

#[test]
fn mlp_matches_naive_on_covered_pixels() {
    let mut r = rng(21);
    for hidden in [vec![], vec![7], vec![9, 5]] {
        let p = MlpParams {
            in_ch: 5,
            hidden: hidden.clone(),
            out_ch: 4,
        };
        let weights = random_weights(&p.tensor_specs(), 7);
        let net = Mlp::from_map(p.clone(), &weights).unwrap();
        let (h, w) = (7, 11);
        let x = randt(&mut r, 5, h, w);
        let covered: Vec<bool> = (0..h * w).map(|i| i % 3 != 1).collect();
        let y = net.forward(&x, &covered).unwrap();
        let dims = p.layer_dims();
        let mut want = vec![0.0f64; 4 * h * w];
        for px in 0..h * w {
            if !covered[px] {
                continue;
            }
            let mut v: Vec<f64> = (0..5).map(|c| x.data[c * h * w + px] as f64).collect();
            for (i, &(ci, co)) in dims.iter().enumerate() {
                let (wt, b) = (
                    &weights[&format!("layers.{i}.weight")].1,
                    &weights[&format!("layers.{i}.bias")].1,
                );
                v = (0..co)
                    .map(|o| {
                        b[o] as f64 + (0..ci).map(|c| wt[o * ci + c] as f64 * v[c]).sum::<f64>()
                    })
                    .collect();
                let last = i + 1 == dims.len();
                v.iter_mut().for_each(|t| {
                    *t = if last {
                        t.tanh()
                    } else if *t < 0.0 {
                        0.2 * *t
                    } else {
                        *t
                    }
                });
            }
            for o in 0..4 {
                want[o * h * w + px] = v[o];
            }
        }
        assert_close(&y.data, &want, 1e-5, &format!("mlp {hidden:?}"));
    }
    let p = MlpParams {
        in_ch: 2,
        hidden: vec![],
        out_ch: 3,
    };
    let mut wts = random_weights(&p.tensor_specs(), 1);
    wts.insert("layers.1.weight".into(), (vec![1], vec![0.0]));
    assert_eq!(
        Mlp::from_map(p, &wts).unwrap_err(),
        NetworkError::Unexpected("layers.1.weight".into())
    );
}
