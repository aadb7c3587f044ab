fn main() {
    let size: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(256);
    let reps: usize = std::env::args()
        .nth(2)
        .and_then(|s| s.parse().ok())
        .unwrap_or(200);
    let (min, med, p) =
        dnr_bake::bench::step::bench_trainer_step(&[16, 32, 64, 128, 128], size, reps);
    println!("{size}: min {min:.2} med {med:.2} {p:?}");
}
