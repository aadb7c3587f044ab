//! Texture sampling against a naive per-texel reference (tent weights summed over every
//! unwrapped integer position that wraps onto the texel, with exact integer wrapping), for
//! all wrap modes, uv far outside [0, 1] (1e6, negative), odd sizes and 1-texel levels.

// Index loops mirror the math (pixel i, channel c) and compare several arrays at once.
#![allow(clippy::needless_range_loop)]

use dnr_runtime::gbuffer::GBuffer;
use dnr_runtime::texture::{sample_into, taps, Level, Pyramid, TextureError, Wrap};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const WRAPS: [Wrap; 3] = [Wrap::Repeat, Wrap::ClampToEdge, Wrap::MirroredRepeat];

/// DESIGN.md wrap, on exact integers.
fn wrap_ref(i: i128, n: i128, mode: Wrap) -> i128 {
    match mode {
        Wrap::Repeat => i.rem_euclid(n),
        Wrap::ClampToEdge => i.clamp(0, n - 1),
        Wrap::MirroredRepeat => {
            let m = i.rem_euclid(2 * n);
            if m < n {
                m
            } else {
                2 * n - 1 - m
            }
        }
    }
}

/// Weight of texel `t` along one axis: sum of max(0, 1 - |x - k|) over integers k near x
/// that wrap to t.
fn axis_weight(x: f64, t: i128, n: i128, mode: Wrap) -> f64 {
    let fl = x.floor();
    let (base, frac) = (fl as i128, x - fl); // both exact
    (base - 2..=base + 2)
        .filter(|&k| wrap_ref(k, n, mode) == t)
        .map(|k| (1.0 - (frac + (base - k) as f64).abs()).max(0.0))
        .sum()
}

fn reference(pyr: &Pyramid, u: f32, v: f32) -> Vec<f64> {
    let c = pyr.channels;
    let mut out = vec![0.0f64; c];
    for l in &pyr.levels {
        let x = u as f64 * l.width as f64 - 0.5;
        let y = v as f64 * l.height as f64 - 0.5;
        for ty in 0..l.height {
            let wy = axis_weight(y, ty as i128, l.height as i128, pyr.wrap_t);
            if wy == 0.0 {
                continue;
            }
            for tx in 0..l.width {
                let wx = axis_weight(x, tx as i128, l.width as i128, pyr.wrap_s);
                for ch in 0..c {
                    out[ch] += wx * wy * l.data[(ty * l.width + tx) * c + ch] as f64;
                }
            }
        }
    }
    out
}

fn random_pyramid(
    rng: &mut ChaCha8Rng,
    c: usize,
    sizes: &[(usize, usize)],
    ws: Wrap,
    wt: Wrap,
) -> Pyramid {
    let levels = sizes
        .iter()
        .map(|&(w, h)| Level {
            width: w,
            height: h,
            data: (0..w * h * c)
                .map(|_| rng.random_range(-1.0..1.0))
                .collect(),
        })
        .collect();
    Pyramid::new(c, levels, ws, wt).unwrap()
}

fn special_uvs() -> Vec<[f32; 2]> {
    vec![
        [0.0, 0.0],
        [1.0, 1.0],
        [0.5, 0.5],
        [1.0 / 14.0, 0.1],
        [-0.25, 1.75],
        [2.0, -3.0],
        [1e6, 1e6],
        [-1e6, 1e6],
        [1e6 + 0.25, -1e6 - 0.3125],
        [-12345.678, 9876.543],
        [3.999_999_8, -0.000_000_1],
        [16_777_216.0, -16_777_215.0],
        // Beyond 4e15 texels the exact f64 path wraps (no fractional bits left).
        [1e16, -3e17],
        [-7.5e15, 2.5e20],
    ]
}

#[test]
fn sampling_matches_the_naive_reference_for_every_wrap_mode() {
    let mut rng = ChaCha8Rng::seed_from_u64(21);
    let (w, h) = (13, 11);
    for ws in WRAPS {
        for wt in WRAPS {
            let pyr = random_pyramid(&mut rng, 3, &[(7, 5), (4, 3), (1, 1)], ws, wt);
            let mut g = GBuffer::new(w, h);
            let specials = special_uvs();
            for i in 0..w * h {
                let uv = if i < specials.len() {
                    specials[i]
                } else {
                    [rng.random_range(-3.0..4.0), rng.random_range(-3.0..4.0)]
                };
                g.uv[i] = uv;
                g.coverage[i] = if i % 7 == 3 { 0.0 } else { 1.0 };
            }
            g.uv[w * h - 1] = [f32::NAN, 0.5];
            g.uv[w * h - 2] = [0.5, f32::INFINITY];
            let mut out = vec![123.0f32; 3 * w * h];
            sample_into(&pyr, &g, &mut out).unwrap();
            for i in 0..w * h {
                let [u, v] = g.uv[i];
                let expected = if g.coverage[i] == 0.0 || !u.is_finite() || !v.is_finite() {
                    vec![0.0; 3]
                } else {
                    reference(&pyr, u, v)
                };
                for ch in 0..3 {
                    let got = out[ch * w * h + i] as f64;
                    assert!(
                        (got - expected[ch]).abs() < 1e-5,
                        "{ws:?}/{wt:?} pixel {i} uv {u},{v} channel {ch}: {got} vs {}",
                        expected[ch]
                    );
                }
            }
        }
    }
}

#[test]
fn taps_weights_sum_to_one_and_stay_in_range_for_extreme_uv() {
    for ws in WRAPS {
        for wt in WRAPS {
            for &(u, v) in &[
                (3.0e38f32, -3.0e38f32),
                (1e20, 1e-20),
                (-1e9, 7.5),
                (f32::MAX, f32::MIN),
                (f32::MIN_POSITIVE, -0.0),
            ] {
                for (w, h) in [(1, 1), (7, 5), (512, 256)] {
                    let t = taps(w, h, ws, wt, u, v).unwrap();
                    let sum: f32 = t.iter().map(|t| t.1).sum();
                    assert!((sum - 1.0).abs() < 1e-6, "{sum}");
                    assert!(t
                        .iter()
                        .all(|&(i, wgt)| i < w * h && (0.0..=1.0).contains(&wgt)));
                }
            }
            assert!(taps(4, 4, ws, wt, f32::NAN, 0.0).is_none());
            assert!(taps(4, 4, ws, wt, 0.0, f32::NEG_INFINITY).is_none());
            assert!(taps(0, 4, ws, wt, 0.0, 0.0).is_none());
        }
    }
}

#[test]
fn texel_centres_sample_exactly_and_tap_order_is_the_documented_one() {
    // uv at a texel centre gives that texel alone.
    let t = taps(8, 4, Wrap::Repeat, Wrap::Repeat, 2.5 / 8.0, 1.5 / 4.0).unwrap();
    assert_eq!(t[0], (8 + 2, 1.0));
    // Halfway between texel columns 2 and 3 of row 1: (x0, y0), (x0+1, y0), (x0, y0+1), ...
    let t = taps(8, 4, Wrap::Repeat, Wrap::Repeat, 3.0 / 8.0, 1.5 / 4.0).unwrap();
    assert_eq!(t, [(10, 0.5), (11, 0.5), (18, 0.0), (19, 0.0)]);
    // uv (0, 0) with REPEAT blends the four corner texels equally.
    let t = taps(8, 4, Wrap::Repeat, Wrap::Repeat, 0.0, 0.0).unwrap();
    assert_eq!(t, [(3 * 8 + 7, 0.25), (3 * 8, 0.25), (7, 0.25), (0, 0.25)]);
    // MIRRORED_REPEAT at u = 0: texel -1 mirrors to 0.
    let t = taps(8, 4, Wrap::MirroredRepeat, Wrap::ClampToEdge, 0.0, 0.0).unwrap();
    assert_eq!(t, [(0, 0.25), (0, 0.25), (0, 0.25), (0, 0.25)]);
}

#[test]
fn wrap_enum_values_round_trip() {
    for w in WRAPS {
        assert_eq!(Wrap::from_gl(w.to_gl()), Some(w));
    }
    assert_eq!(Wrap::from_gl(9729), None);
    assert_eq!(Wrap::default(), Wrap::Repeat);
}

#[test]
fn malformed_inputs_are_errors() {
    let lvl = |w: usize, h: usize, n: usize| Level {
        width: w,
        height: h,
        data: vec![0.0; n],
    };
    assert_eq!(
        Pyramid::new(0, vec![lvl(1, 1, 0)], Wrap::Repeat, Wrap::Repeat),
        Err(TextureError::Empty)
    );
    assert_eq!(
        Pyramid::new(2, vec![], Wrap::Repeat, Wrap::Repeat),
        Err(TextureError::Empty)
    );
    assert!(matches!(
        Pyramid::new(2, vec![lvl(2, 2, 7)], Wrap::Repeat, Wrap::Repeat),
        Err(TextureError::LevelSize { level: 0, .. })
    ));
    assert!(matches!(
        Pyramid::new(
            1,
            vec![lvl(2, 2, 4), lvl(0, 3, 0)],
            Wrap::Repeat,
            Wrap::Repeat
        ),
        Err(TextureError::LevelSize { level: 1, .. })
    ));
    let pyr = Pyramid::new(2, vec![lvl(2, 2, 8)], Wrap::Repeat, Wrap::Repeat).unwrap();
    let g = GBuffer::new(3, 2);
    let mut out = vec![0.0; 11];
    assert!(matches!(
        sample_into(&pyr, &g, &mut out),
        Err(TextureError::OutputSize {
            expected: 12,
            found: 11
        })
    ));
    let mut empty = GBuffer::new(0, 0);
    assert!(sample_into(&pyr, &empty, &mut []).is_ok());
    empty.width = 2; // inconsistent G-buffer: 2x1 pixels, empty planes
    empty.height = 1;
    assert!(sample_into(&pyr, &empty, &mut [0.0; 4]).is_err());
}

#[test]
fn sampling_is_identical_across_thread_counts() {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let pyr = random_pyramid(
        &mut rng,
        16,
        &[(64, 48), (32, 24), (16, 12)],
        Wrap::Repeat,
        Wrap::MirroredRepeat,
    );
    let (w, h) = (37, 29);
    let mut g = GBuffer::new(w, h);
    for i in 0..w * h {
        g.uv[i] = [rng.random_range(-2.0..2.0), rng.random_range(-2.0..2.0)];
        g.coverage[i] = (i % 5 != 0) as u8 as f32;
    }
    let run = |n| {
        let mut out = vec![0.0; 16 * w * h];
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .unwrap()
            .install(|| sample_into(&pyr, &g, &mut out))
            .unwrap();
        out
    };
    assert_eq!(run(1), run(3));
}
