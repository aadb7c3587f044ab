use dnr_bake::bench::step::synthetic_view;
use dnr_bake::train::config::{Preset, TrainConfig};
use dnr_bake::train::Trainer;
fn main() {
    if std::env::var("MICRO").is_ok() {
        micro();
        micro2();
        return;
    }
    let s: usize = std::env::args()
        .nth(1)
        .map(|a| a.parse().unwrap())
        .unwrap_or(1);
    let size = 256;
    let mut views: Vec<_> = (0..4).map(|i| synthetic_view(size, i)).collect();
    if s > 1 {
        for (i, v) in views.iter_mut().enumerate() {
            v.fine = Some(synthetic_view(size * s, i as u64).gbuf);
        }
    }
    let cfg = TrainConfig {
        supersample: s as u32,
        threads: 1,
        sh: true,
        ..TrainConfig::preset(Preset::Fast)
    };
    let _ = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build_global();
    let mut t = Trainer::new(cfg, &views).unwrap();
    for _ in 0..10 {
        t.step(&views).unwrap();
    }
    t.phase_seconds = Default::default();
    let n = 60;
    let t0 = std::time::Instant::now();
    for _ in 0..n {
        t.step(&views).unwrap();
    }
    let p = t.phase_seconds;
    let ms = |x: f64| 1e3 * x / n as f64;
    println!("s={s} step {:.1} ms: features {:.1} forward {:.1} backward {:.1} feature_grads {:.1} updates {:.1}", 1e3*t0.elapsed().as_secs_f64()/n as f64, ms(p.features), ms(p.forward), ms(p.backward), ms(p.feature_grads), ms(p.updates));
}

#[allow(dead_code)]
pub fn micro() {
    use dnr_runtime::supersample::*;
    let (c, w, h, s) = (16usize, 256usize, 256usize, 2usize);
    let fine = vec![0.5f32; c * w * h * s * s];
    let mut out = vec![0.0f32; c * w * h];
    let t = std::time::Instant::now();
    for _ in 0..20 {
        box_mean(&fine, c, w, h, s, &mut out).unwrap();
    }
    println!("box_mean {:.2} ms", t.elapsed().as_secs_f64() * 1e3 / 20.0);
    let mut d = vec![0.0f32; fine.len()];
    let t = std::time::Instant::now();
    for _ in 0..20 {
        box_mean_adjoint(&out, c, w, h, s, &mut d).unwrap();
    }
    println!("adjoint {:.2} ms", t.elapsed().as_secs_f64() * 1e3 / 20.0);
    let g = synthetic_view(512, 0).gbuf;
    let t = std::time::Instant::now();
    for _ in 0..20 {
        dnr_runtime::sh::modulate(&mut d, &g.view_dir, &g.coverage, 3, 2).unwrap();
    }
    println!("sh 512 {:.2} ms", t.elapsed().as_secs_f64() * 1e3 / 20.0);
}

#[allow(dead_code)]
pub fn micro2() {
    use dnr_bake::kernels::sample::sample_forward_taps;
    let cfg = TrainConfig {
        threads: 1,
        ..TrainConfig::preset(Preset::Fast)
    };
    let views: Vec<_> = (0..1).map(|i| synthetic_view(256, i)).collect();
    let t = Trainer::new(
        TrainConfig {
            supersample: 1,
            ..cfg
        },
        &views,
    )
    .unwrap();
    for size in [256usize, 512] {
        let g = synthetic_view(size, 0).gbuf;
        let mut x = vec![0.0f32; 16 * size * size];
        let t0 = std::time::Instant::now();
        for _ in 0..10 {
            let taps = sample_forward_taps(&t.pyr, &g, &mut x).unwrap();
            drop(taps);
        }
        println!(
            "taps {size}: {:.2} ms, active {}",
            t0.elapsed().as_secs_f64() * 1e2,
            g.covered_count()
        );
    }
}
