//! Where training starts: the classical texture (each texel the weighted mean colour of the
//! training pixels that see it), split over the pyramid like a Laplacian pyramid, in channels
//! 0..2. Learning then only has to add what an average texture cannot hold.

use dnr_runtime::texture::{taps, Level, Pyramid, Wrap};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::views::View;

/// Per-level splat of the training colours: `sum(w * colour)` and `sum(w)` per texel.
struct Splat {
    width: usize,
    height: usize,
    colour: Vec<f64>,
    weight: Vec<f64>,
}

fn splat(views: &[View], width: usize, height: usize, wrap_s: Wrap, wrap_t: Wrap) -> Splat {
    let mut s = Splat {
        width,
        height,
        colour: vec![0.0; 3 * width * height],
        weight: vec![0.0; width * height],
    };
    for v in views {
        let n = v.width() * v.height();
        for i in 0..n {
            // Only pixels the proxy covers and the photo shows as object.
            if v.gbuf.coverage[i] == 0.0 || v.alpha[i] < 0.5 || !v.is_valid(i) {
                continue;
            }
            let [u, vv] = v.gbuf.uv[i];
            let Some(tp) = taps(width, height, wrap_s, wrap_t, u, vv) else {
                continue;
            };
            for (t, w) in tp {
                let w = w as f64;
                s.weight[t] += w;
                for c in 0..3 {
                    s.colour[3 * t + c] += w * v.target[c * n + i] as f64;
                }
            }
        }
    }
    s
}

/// What the initialisation measured (reported by the baker).
#[derive(Clone, Debug, Default, serde::Serialize)]
#[serde(rename_all = "camelCase")]
pub struct InitStats {
    /// Texels of the finest level seen by at least one training pixel, as a fraction.
    pub finest_seen_fraction: f64,
    /// Mean colour over all object pixels (fills texels no camera saw).
    pub mean_colour: [f32; 3],
}

/// Builds the starting pyramid: level sizes `resolution >> k`, channels 0..2 the Laplacian
/// split of the mean-colour texture, other channels small seeded noise (std `noise`).
/// Also returns, for each level, which texels some training pixel touches (`seen`).
pub fn classical_pyramid(
    views: &[View],
    channels: usize,
    resolution: usize,
    levels: usize,
    wrap: Wrap,
    noise: f32,
    seed: u64,
) -> (Pyramid, Vec<Vec<bool>>, InitStats) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let sizes: Vec<usize> = (0..levels).map(|k| (resolution >> k).max(1)).collect();
    let splats: Vec<Splat> = sizes
        .iter()
        .map(|&r| splat(views, r, r, wrap, wrap))
        .collect();

    // Global mean colour over object pixels (from the coarsest splat, which sums all of them).
    let coarse = splats.last().expect("at least one level");
    let wsum: f64 = coarse.weight.iter().sum();
    let mut mean = [0.5f32; 3];
    if wsum > 0.0 {
        for (c, m) in mean.iter_mut().enumerate() {
            let s: f64 = coarse.colour.iter().skip(c).step_by(3).sum();
            *m = (s / wsum) as f32;
        }
    }

    let mut pyr = Pyramid {
        channels,
        levels: sizes
            .iter()
            .map(|&r| Level {
                width: r,
                height: r,
                data: (0..r * r * channels)
                    .map(|i| {
                        if i % channels < 3 {
                            0.0
                        } else {
                            noise * gauss(&mut rng)
                        }
                    })
                    .collect(),
            })
            .collect(),
        wrap_s: wrap,
        wrap_t: wrap,
    };

    // Coarse to fine: level k holds mean_k minus what the coarser levels already give at its
    // texel centres; unseen texels hold 0 (the coarser levels' value shows through).
    let mut seen = vec![Vec::new(); levels];
    for k in (0..levels).rev() {
        let s = &splats[k];
        let coarser = Pyramid {
            channels,
            levels: pyr.levels[k + 1..].to_vec(),
            wrap_s: wrap,
            wrap_t: wrap,
        };
        let mut acc = vec![0.0f32; channels];
        let mut lvl_seen = vec![false; s.width * s.height];
        for y in 0..s.height {
            for x in 0..s.width {
                let t = y * s.width + x;
                let w = s.weight[t];
                lvl_seen[t] = w > 0.0;
                let target: [f32; 3] = if w > 1e-6 {
                    std::array::from_fn(|c| (s.colour[3 * t + c] / w) as f32)
                } else if k + 1 == levels {
                    mean
                } else {
                    continue;
                };
                acc.fill(0.0);
                if k + 1 < levels {
                    let u = (x as f32 + 0.5) / s.width as f32;
                    let v = (y as f32 + 0.5) / s.height as f32;
                    coarser.accumulate(u, v, &mut acc);
                }
                for c in 0..3 {
                    pyr.levels[k].data[t * channels + c] = target[c] - acc[c];
                }
            }
        }
        seen[k] = lvl_seen;
    }
    let finest_seen = seen[0].iter().filter(|&&b| b).count() as f64 / seen[0].len().max(1) as f64;
    (
        pyr,
        seen,
        InitStats {
            finest_seen_fraction: finest_seen,
            mean_colour: mean,
        },
    )
}

/// A standard normal sample (Box-Muller), deterministic for a seeded generator.
pub fn gauss(rng: &mut ChaCha8Rng) -> f32 {
    let u1: f64 = rng.random::<f64>().max(1e-300);
    let u2: f64 = rng.random::<f64>();
    ((-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()) as f32
}
