//! Spherical harmonics: the basis against DESIGN.md's table (written out again here in
//! f64), orthonormality by Monte Carlo, and `modulate`'s channel/pixel selection and errors.

// Index loops mirror the math (pixel i, channel c) and compare several arrays at once.
#![allow(clippy::needless_range_loop)]

use dnr_runtime::sh::{check_modulate, coeff_count, modulate, sh_basis, sh_component, ShError};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// DESIGN.md "View dependence" table, d = (x, y, z).
fn table(d: [f64; 3]) -> [f64; 16] {
    let [x, y, z] = d;
    [
        0.28209479177387814,
        -0.4886025119029199 * y,
        0.4886025119029199 * z,
        -0.4886025119029199 * x,
        1.0925484305920792 * x * y,
        -1.0925484305920792 * y * z,
        0.31539156525252005 * (2.0 * z * z - x * x - y * y),
        -1.0925484305920792 * x * z,
        0.5462742152960396 * (x * x - y * y),
        -0.5900435899266435 * y * (3.0 * x * x - y * y),
        2.890611442640554 * x * y * z,
        -0.4570457994644658 * y * (4.0 * z * z - x * x - y * y),
        0.3731763325901154 * z * (2.0 * z * z - 3.0 * x * x - 3.0 * y * y),
        -0.4570457994644658 * x * (4.0 * z * z - x * x - y * y),
        1.445305721320277 * z * (x * x - y * y),
        -0.5900435899266435 * x * (x * x - 3.0 * y * y),
    ]
}

fn random_dir(rng: &mut ChaCha8Rng) -> [f32; 3] {
    loop {
        let v: [f32; 3] = [
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        ];
        let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if n > 0.1 && n <= 1.0 {
            return v.map(|c| c / n);
        }
    }
}

#[test]
fn basis_matches_the_design_table() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let axes = [
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 0.0, 1.0],
        [0.0, 0.0, -1.0],
    ];
    for k in 0..500 {
        let d = if k < axes.len() {
            axes[k]
        } else {
            random_dir(&mut rng)
        };
        let want = table(d.map(|c| c as f64));
        for degree in 0..=3u32 {
            let mut out = [f32::NAN; 16];
            let n = sh_basis(degree, d, &mut out);
            assert_eq!(n, coeff_count(degree));
            for j in 0..16 {
                if j < n {
                    assert!(
                        (out[j] as f64 - want[j]).abs() < 1e-6,
                        "degree {degree} j {j} d {d:?}: {} vs {}",
                        out[j],
                        want[j]
                    );
                    assert_eq!(out[j], sh_component(j, d));
                } else {
                    assert!(out[j].is_nan(), "wrote past the degree's coefficients");
                }
            }
        }
    }
}

#[test]
fn basis_caps_degree_and_output_length() {
    let d = [0.6, 0.0, 0.8];
    let mut out = [0.0f32; 16];
    assert_eq!(sh_basis(7, d, &mut out), 16);
    let mut short = [0.0f32; 5];
    assert_eq!(sh_basis(3, d, &mut short), 5);
    assert_eq!(sh_component(16, d), 0.0);
}

#[test]
fn basis_is_orthonormal_by_monte_carlo() {
    // 4π · mean(Y_i Y_j) over uniform directions ≈ δ_ij. With 200k samples the standard
    // error of each entry is below 0.01; 0.04 is 4 sigma. A wrong constant (e.g. 0.5 for
    // 0.546) or a missing term moves a diagonal entry by more than 0.1.
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let n = 200_000;
    let mut gram = [[0.0f64; 16]; 16];
    let mut y = [0.0f32; 16];
    for _ in 0..n {
        sh_basis(3, random_dir(&mut rng), &mut y);
        for i in 0..16 {
            for j in i..16 {
                gram[i][j] += y[i] as f64 * y[j] as f64;
            }
        }
    }
    let scale = 4.0 * std::f64::consts::PI / n as f64;
    for i in 0..16 {
        for j in i..16 {
            let g = gram[i][j] * scale;
            let want = if i == j { 1.0 } else { 0.0 };
            assert!((g - want).abs() < 0.04, "G[{i}][{j}] = {g}");
        }
    }
}

#[test]
fn modulate_multiplies_only_the_sh_channels_of_covered_pixels() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let (c, pixels, first, degree) = (14usize, 23usize, 3usize, 2u32);
    let features: Vec<f32> = (0..c * pixels)
        .map(|_| rng.random_range(-2.0..2.0))
        .collect();
    let dirs: Vec<[f32; 3]> = (0..pixels).map(|_| random_dir(&mut rng)).collect();
    let coverage: Vec<f32> = (0..pixels).map(|p| (p % 4 != 1) as u8 as f32).collect();
    let mut x = features.clone();
    modulate(&mut x, &dirs, &coverage, first, degree).unwrap();
    for ch in 0..c {
        for p in 0..pixels {
            let i = ch * pixels + p;
            let j = ch as isize - first as isize;
            let want = if coverage[p] != 0.0 && j >= 0 && (j as usize) < coeff_count(degree) {
                features[i] * table(dirs[p].map(|v| v as f64))[j as usize] as f32
            } else {
                features[i]
            };
            assert!((x[i] - want).abs() < 1e-6, "channel {ch} pixel {p}");
        }
    }
}

#[test]
fn modulate_rejects_bad_shapes() {
    let dirs = vec![[0.0, 0.0, 1.0f32]; 4];
    let cov = vec![1.0f32; 4];
    let mut f = vec![1.0f32; 4 * 9];
    assert_eq!(modulate(&mut f, &dirs, &cov, 0, 4), Err(ShError::Degree(4)));
    assert_eq!(
        modulate(&mut f, &dirs, &cov, 1, 2),
        Err(ShError::Channels {
            first: 1,
            end: 10,
            channels: 9
        })
    );
    assert!(modulate(&mut f, &dirs, &cov, 0, 2).is_ok());
    assert!(matches!(
        modulate(&mut f[..35], &dirs, &cov, 0, 0),
        Err(ShError::Shape { .. })
    ));
    assert!(matches!(
        modulate(&mut f, &dirs[..3], &cov, 0, 0),
        Err(ShError::Shape { .. })
    ));
    assert_eq!(
        check_modulate(0, 0, 0, 0, 0),
        Err(ShError::Channels {
            first: 0,
            end: 1,
            channels: 0
        })
    );
    assert!(matches!(
        modulate(&mut f, &dirs, &cov, usize::MAX, 1),
        Err(ShError::Channels { .. })
    ));
}
