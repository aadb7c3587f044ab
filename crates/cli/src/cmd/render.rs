//! `dnr render`: an asset drawn by the CPU runtime to PNG files.
//!
//! `dnr render ASSET (--capture DIR [--split test|train|all] | --look-at EX,EY,EZ,TX,TY,TZ
//! [--fov DEG] [--size WxH]) -o OUT [--json]`: draws an asset with the CPU runtime to
//! 8-bit RGBA PNGs (straight alpha, sRGB-encoded colour, transparent background).

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{bail, Context};
use dnr_bake::capture::{Capture, Frame, LoadOptions};
use dnr_bake::eval::{frame_file_stem, save_png_rgba};
use dnr_runtime::camera::Camera;
use dnr_runtime::raster::rasterize;
use dnr_runtime::renderer::Renderer;
use dnr_runtime::supersample::subsample_camera;
use serde::Serialize;

/// Which frames of a capture to use.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Split {
    /// Held-out frames.
    Test,
    /// Training frames.
    Train,
    /// Training then held-out frames.
    All,
}

/// Arguments of `dnr render`.
#[derive(clap::Args)]
pub struct Args {
    /// The `.glb` or `.gltf` asset.
    pub asset: PathBuf,
    /// Render the views of this capture folder (`transforms*.json`); PNGs named after the
    /// frames go to the output folder.
    #[arg(long, conflicts_with = "look_at")]
    pub capture: Option<PathBuf>,
    /// Frames of the capture to render.
    #[arg(long, value_enum, default_value_t = Split::Test, requires = "capture")]
    pub split: Split,
    /// Render one view from eye (EX,EY,EZ) towards target (TX,TY,TZ), +Y up.
    #[arg(long, value_name = "EX,EY,EZ,TX,TY,TZ", allow_hyphen_values = true)]
    pub look_at: Option<String>,
    /// Vertical field of view in degrees (with --look-at).
    #[arg(long, default_value_t = 40.0)]
    pub fov: f32,
    /// Frame size (with --look-at).
    #[arg(long, value_name = "WxH", default_value = "512x512")]
    pub size: String,
    /// Output: a folder with --capture, a `.png` file with --look-at.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Print per-view timing as JSON.
    #[arg(long)]
    pub json: bool,
}

#[derive(Serialize)]
struct ViewTiming {
    name: String,
    file: String,
    width: u32,
    height: u32,
    covered_pixels: usize,
    raster_ms: f64,
    shade_ms: f64,
    total_ms: f64,
}

#[derive(Serialize)]
struct Report {
    asset: String,
    load_ms: f64,
    views: Vec<ViewTiming>,
    mean_total_ms: f64,
}

/// Renders and writes the PNGs.
pub fn run(args: &Args) -> anyhow::Result<ExitCode> {
    let start = Instant::now();
    let renderer = Renderer::from_path(&args.asset)
        .with_context(|| format!("cannot load {}", args.asset.display()))?;
    let load_ms = ms(start);

    // (name, camera, output file)
    let jobs: Vec<(String, Camera, PathBuf)> = match (&args.capture, &args.look_at) {
        (Some(dir), None) => {
            let frames = load_frames(dir, &args.asset, args.split)?;
            std::fs::create_dir_all(&args.output)
                .with_context(|| format!("cannot create {}", args.output.display()))?;
            frames
                .iter()
                .map(|f| {
                    (
                        f.name.clone(),
                        f.camera,
                        args.output
                            .join(format!("{}.png", frame_file_stem(&f.name))),
                    )
                })
                .collect()
        }
        (None, Some(spec)) => {
            let (eye, target) = parse_look_at(spec)?;
            let (w, h) = parse_size(&args.size)?;
            if !(args.fov > 0.0 && args.fov < 180.0) {
                bail!("--fov must be between 0 and 180 degrees, got {}", args.fov);
            }
            if eye == target {
                bail!("--look-at: eye and target coincide");
            }
            if let Some(parent) = args.output.parent().filter(|p| !p.as_os_str().is_empty()) {
                std::fs::create_dir_all(parent)
                    .with_context(|| format!("cannot create {}", parent.display()))?;
            }
            // `look_at` takes glam vectors; `into` converts the arrays (no glam dependency here).
            let cam = Camera::look_at(eye.into(), target.into(), args.fov, w, h);
            vec![("look-at".to_string(), cam, args.output.clone())]
        }
        _ => bail!("give either --capture DIR or --look-at EX,EY,EZ,TX,TY,TZ"),
    };

    let mut views = Vec::with_capacity(jobs.len());
    for (name, cam, path) in jobs {
        let t0 = Instant::now();
        let g = rasterize(renderer.scene(), &cam);
        // Supersampled renderers (format revision 1.3) also need their subsamples' view.
        let factors = renderer.supersample_factors();
        if let Some(s) = factors.last() {
            let px = u64::from(cam.width) * u64::from(cam.height) * u64::from(s * s);
            if px > dnr_runtime::renderer::MAX_PIXELS {
                bail!(
                    "cannot render `{name}`: {}x{} at the asset's {s}x{s} subsamples is {px} \
                     samples, more than {}",
                    cam.width,
                    cam.height,
                    dnr_runtime::renderer::MAX_PIXELS
                );
            }
        }
        let fine: Vec<_> = factors
            .into_iter()
            .map(|s| rasterize(renderer.scene(), &subsample_camera(&cam, s)))
            .collect();
        let raster_ms = ms(t0);
        let t1 = Instant::now();
        let img = renderer
            .shade_supersampled(&g, &fine)
            .with_context(|| format!("cannot render `{name}`"))?;
        let shade_ms = ms(t1);
        save_png_rgba(&path, &img)
            .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", path.display()))?;
        let view = ViewTiming {
            name,
            file: path.display().to_string(),
            width: cam.width,
            height: cam.height,
            covered_pixels: g.covered_count(),
            raster_ms,
            shade_ms,
            total_ms: raster_ms + shade_ms,
        };
        if !args.json {
            println!(
                "{}  {}x{}  raster {:.1} ms  shade {:.1} ms  -> {}",
                view.name, view.width, view.height, view.raster_ms, view.shade_ms, view.file
            );
        }
        views.push(view);
    }
    let mean_total_ms = if views.is_empty() {
        0.0
    } else {
        views.iter().map(|v| v.total_ms).sum::<f64>() / views.len() as f64
    };
    if args.json {
        let report = Report {
            asset: args.asset.display().to_string(),
            load_ms,
            views,
            mean_total_ms,
        };
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!(
            "{} view(s), mean {mean_total_ms:.1} ms per view (asset loaded in {load_ms:.0} ms)",
            views.len()
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// The frames of `split` of the capture in `dir`.
///
/// The capture's own proxy mesh is not needed (the asset has the geometry), so the asset
/// is given as the mesh: the capture loads even without one.
pub fn load_frames(dir: &Path, asset: &Path, split: Split) -> anyhow::Result<Vec<Frame>> {
    let opts = LoadOptions {
        mesh: Some(asset.to_path_buf()),
        ..LoadOptions::default()
    };
    let capture = Capture::load(dir, &opts)
        .with_context(|| format!("cannot load capture {}", dir.display()))?;
    for w in &capture.warnings {
        eprintln!("dnr: warning: {w}");
    }
    let frames = match split {
        Split::Test => capture.test,
        Split::Train => capture.train,
        Split::All => capture.train.into_iter().chain(capture.test).collect(),
    };
    if frames.is_empty() {
        bail!("capture {} has no {split:?} frames", dir.display());
    }
    Ok(frames)
}

/// Eye and target of `EX,EY,EZ,TX,TY,TZ`.
fn parse_look_at(s: &str) -> anyhow::Result<([f32; 3], [f32; 3])> {
    let v: Vec<f32> = s
        .split(',')
        .map(|p| p.trim().parse::<f32>())
        .collect::<Result<_, _>>()
        .with_context(|| format!("--look-at `{s}`: expected six numbers EX,EY,EZ,TX,TY,TZ"))?;
    if v.len() != 6 || v.iter().any(|x| !x.is_finite()) {
        bail!("--look-at `{s}`: expected six finite numbers EX,EY,EZ,TX,TY,TZ");
    }
    Ok(([v[0], v[1], v[2]], [v[3], v[4], v[5]]))
}

fn parse_size(s: &str) -> anyhow::Result<(u32, u32)> {
    let parsed = s
        .split_once(['x', 'X'])
        .and_then(|(w, h)| Some((w.trim().parse::<u32>().ok()?, h.trim().parse::<u32>().ok()?)));
    match parsed {
        Some((w, h))
            if w > 0
                && h > 0
                && u64::from(w) * u64::from(h) <= dnr_runtime::renderer::MAX_PIXELS =>
        {
            Ok((w, h))
        }
        _ => bail!(
            "--size `{s}`: expected WxH with positive sizes and at most {} pixels",
            dnr_runtime::renderer::MAX_PIXELS
        ),
    }
}

fn ms(since: Instant) -> f64 {
    since.elapsed().as_secs_f64() * 1e3
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_look_at_and_size() {
        let (e, t) = parse_look_at("0,1.5,-4, 0,0,0").unwrap();
        assert_eq!((e, t), ([0.0, 1.5, -4.0], [0.0; 3]));
        assert!(parse_look_at("1,2,3").is_err());
        assert!(parse_look_at("1,2,3,4,5,nan").is_err());
        assert_eq!(parse_size("640x480").unwrap(), (640, 480));
        assert!(parse_size("640").is_err());
        assert!(parse_size("0x10").is_err());
        assert!(parse_size("100000x100000").is_err());
    }
}
