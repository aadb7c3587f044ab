//! Generates a capture that looks like a phone's (see `phone/mod.rs` for what is written):
//! distorted 3-megapixel JPEGs with masks, a proxy without UVs as PLY, poses as a COLMAP
//! binary model and as nerfstudio's `transforms.json`, and the undistorted pinhole twin.
//!
//! Run: `cargo run --release -p dnr-bake --example make_phone_capture -- OUT [--size WxH]
//! [--frames N]` (default 2016x1512, 64 frames; about a minute per 10 frames on 2 cores).
//! Then, for example:
//!
//!     dnr-bake OUT/phone -o phone-colmap.glb            (COLMAP model)
//!     dnr-bake OUT/phone-ns -o phone-ns.glb             (nerfstudio transforms.json)
//!     dnr-bake OUT/pinhole -o pinhole.glb               (the undistorted twin)

mod phone;
mod raytrace;

use std::path::PathBuf;

fn main() {
    let mut args = std::env::args().skip(1);
    let mut out: Option<PathBuf> = None;
    let mut cfg = phone::PhoneConfig::default();
    while let Some(a) = args.next() {
        match a.as_str() {
            "--size" => {
                let v = args.next().expect("--size WxH");
                let (w, h) = v.split_once('x').expect("--size WxH");
                cfg.width = w.parse().expect("width");
                cfg.height = h.parse().expect("height");
            }
            "--frames" => cfg.frames = args.next().expect("--frames N").parse().expect("N"),
            "--segments" => cfg.segments = args.next().expect("--segments N").parse().expect("N"),
            _ if out.is_none() => out = Some(PathBuf::from(a)),
            other => panic!("unknown argument {other}"),
        }
    }
    let out = out.unwrap_or_else(|| PathBuf::from("phone-capture"));
    phone::generate(&out, &cfg);
    eprintln!(
        "wrote {} views of {}x{} to {}/phone, {}/phone-ns and {}/pinhole",
        cfg.frames,
        cfg.width,
        cfg.height,
        out.display(),
        out.display(),
        out.display()
    );
}
