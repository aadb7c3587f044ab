//! Measures the alignment check's scores on a capture with its mesh as given and moved:
//! shifted by a fraction of its radius, turned, scaled, and (with `applied_transform`) placed
//! both ways. The figures behind `capture::alignment::THRESHOLD`.
//!
//! Run: `cargo run --release -p dnr-bake --example measure_alignment -- CAPTURE [--mesh M]`

use std::path::PathBuf;

use dnr_bake::capture::alignment::{score_all, train_median};
use dnr_bake::capture::{place_mesh, Capture, LoadOptions, MeshSpace};
use glam::{DMat4, DQuat, DVec3};

fn main() {
    let mut args = std::env::args().skip(1);
    let dir = PathBuf::from(args.next().expect("CAPTURE"));
    let mut opts = LoadOptions {
        mesh_space: MeshSpace::Poses,
        ..Default::default()
    };
    if args.next().as_deref() == Some("--mesh") {
        opts.mesh = args.next().map(PathBuf::from);
    }
    let cap = Capture::load(&dir, &opts).unwrap_or_else(|e| panic!("{e}"));
    let (lo, hi) = cap.mesh.primitives.iter().fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(lo, hi), p| {
            p.positions.iter().fold((lo, hi), |(lo, hi), v| {
                let w = p.world.transform_point3(*v).as_dvec3();
                (lo.min(w), hi.max(w))
            })
        },
    );
    let centre = 0.5 * (lo + hi);
    let radius = 0.5 * (hi - lo).length();
    let about_centre =
        |m: DMat4| DMat4::from_translation(centre) * m * DMat4::from_translation(-centre);
    let mut cases: Vec<(String, DMat4)> = vec![("as given".into(), DMat4::IDENTITY)];
    for f in [0.02, 0.05, 0.1, 0.2] {
        cases.push((
            format!("shifted {:.0}% of the radius", f * 100.0),
            DMat4::from_translation(DVec3::new(f * radius, 0.0, 0.0)),
        ));
    }
    for deg in [5.0f64, 10.0, 20.0] {
        cases.push((
            format!("turned {deg} deg about z"),
            about_centre(DMat4::from_quat(DQuat::from_rotation_z(deg.to_radians()))),
        ));
    }
    for s in [0.9, 1.1] {
        cases.push((
            format!("scaled {s}"),
            about_centre(DMat4::from_scale(DVec3::splat(s))),
        ));
    }
    if let Some(t) = cap.applied_transform {
        cases.push(("applied_transform applied".into(), t));
    }
    println!(
        "{}: {} train + {} test views, mesh radius {radius:.3}",
        dir.display(),
        cap.train.len(),
        cap.test.len()
    );
    println!("| mesh | median | worst | method |");
    println!("| --- | --- | --- | --- |");
    for (name, m) in cases {
        let mut mesh = cap.mesh.clone();
        place_mesh(&mut mesh, m);
        let views = score_all(&cap, &mesh);
        let worst = views
            .iter()
            .filter(|v| !v.test)
            .map(|v| v.score)
            .fold(f64::INFINITY, f64::min);
        let method = views
            .first()
            .map(|v| format!("{:?}", v.method))
            .unwrap_or_default();
        match train_median(&views) {
            Some(m) => println!("| {name} | {m:.3} | {worst:.3} | {method} |"),
            None => println!("| {name} | - | - | none |"),
        }
    }
}
