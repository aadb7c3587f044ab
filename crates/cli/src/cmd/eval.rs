//! `dnr eval`: an asset's error against a capture's photographs.
//!
//! `dnr eval ASSET CAPTURE [--split test|train|all] [--json FILE] [--save-images DIR]`: renders the
//! capture's views from the exported asset with the CPU runtime and reports PSNR (full frame on
//! white), SSIM and object MSE per view and on average (`dnr_bake::eval::evaluate`).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use anyhow::Context;
use dnr_bake::eval::regions::{Regions, DISTANCE_BINS};
use dnr_bake::eval::{evaluate_with, Options};
use dnr_runtime::renderer::Renderer;

use super::render::{load_frames, Split};

/// Arguments of `dnr eval`.
#[derive(clap::Args)]
pub struct Args {
    /// The `.glb` or `.gltf` asset.
    pub asset: PathBuf,
    /// The capture folder with the held-out photographs (`transforms*.json`).
    pub capture: PathBuf,
    /// Frames to evaluate.
    #[arg(long, value_enum, default_value_t = Split::Test)]
    pub split: Split,
    /// Write the report as JSON to this file (`-` for standard output).
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,
    /// Write `ground truth | render | error` comparison PNGs to this folder.
    #[arg(long, value_name = "DIR")]
    pub save_images: Option<PathBuf>,
    /// Split the error by region of the proxy's silhouette: object pixels the proxy covers,
    /// object pixels it misses (by distance to the nearest covered pixel), covered pixels
    /// outside the object. Says whether a coarse proxy's error is in its surface or its outline.
    /// Also the photograph's anti-aliased outline band (partial alpha and its neighbours),
    /// across those regions: the error one sample per pixel leaves on silhouettes.
    #[arg(long)]
    pub regions: bool,
}

/// Evaluates and prints the report.
pub fn run(args: &Args) -> anyhow::Result<ExitCode> {
    let start = Instant::now();
    let renderer = Renderer::from_path(&args.asset)
        .with_context(|| format!("cannot load {}", args.asset.display()))?;
    let frames = load_frames(&args.capture, &args.asset, args.split)?;
    let load_ms = start.elapsed().as_secs_f64() * 1e3;
    let report = evaluate_with(
        &renderer,
        &frames,
        Options {
            save: args.save_images.as_deref(),
            regions: args.regions,
        },
    )?;

    let to_stdout = args.json.as_deref().is_some_and(|p| p.as_os_str() == "-");
    if !to_stdout {
        println!(
            "{:<24} {:>9} {:>8} {:>9} {:>10} {:>9}",
            "view", "PSNR dB", "SSIM", "MSE obj", "obj px", "render ms"
        );
        for v in &report.views {
            println!(
                "{:<24} {:>9.2} {:>8.4} {:>9.2} {:>10} {:>9.1}",
                v.name,
                v.error.psnr,
                v.error.ssim,
                v.error.mse_obj,
                v.error.obj_pixels,
                v.render_ms
            );
        }
        let m = &report.mean;
        println!(
            "{:<24} {:>9.2} {:>8.4} {:>9.2} {:>10} {:>9.1}",
            format!("mean of {}", report.views.len()),
            m.psnr,
            m.ssim,
            m.mse_obj,
            "",
            m.render_ms
        );
        if let Some(r) = &report.regions {
            print_regions(r);
        }
        if let Some(dir) = &args.save_images {
            println!(
                "comparison images (truth | render | error) in {}",
                dir.display()
            );
        }
        eprintln!("(asset and capture loaded in {load_ms:.0} ms)");
    }
    if let Some(path) = &args.json {
        let out = serde_json::json!({
            "asset": args.asset.display().to_string(),
            "capture": args.capture.display().to_string(),
            "split": format!("{:?}", args.split).to_lowercase(),
            "views": report.views,
            "mean": report.mean,
            "regions": report.regions,
        });
        let text = serde_json::to_string_pretty(&out)?;
        if to_stdout {
            println!("{text}");
        } else {
            write_atomic(path, text.as_bytes())?;
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// The error by region over all views: pixels, MSE and share of the frames' squared error.
fn print_regions(r: &Regions) {
    println!();
    println!(
        "{:<36} {:>10} {:>9} {:>8}",
        "error by region (all views)", "pixels", "MSE", "share"
    );
    let row = |name: &str, g: &dnr_bake::eval::regions::Region| {
        println!(
            "{:<36} {:>10} {:>9.2} {:>7.1}%",
            name,
            g.pixels,
            g.mse(),
            100.0 * r.share(g)
        );
    };
    row("object, covered by the proxy", &r.inside);
    row("object, missed by the proxy", &r.missed);
    let mut lo = 0;
    for (k, g) in r.missed_by_distance.iter().enumerate() {
        let name = match DISTANCE_BINS.get(k) {
            Some(&hi) => format!("  missed, {}..{} px from cover", lo + 1, hi),
            None => format!("  missed, over {lo} px from cover"),
        };
        row(&name, g);
        lo = DISTANCE_BINS.get(k).copied().unwrap_or(lo);
    }
    row("covered, not object", &r.excess);
    row("background", &r.background);
    // Overlaps the rows above: a share of the same total.
    row("outline band (partial alpha, +1 px)", &r.silhouette);
}

/// Writes `bytes` to a temporary file beside `path`, then renames it.
fn write_atomic(path: &std::path::Path, bytes: &[u8]) -> anyhow::Result<()> {
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent)
            .with_context(|| format!("cannot create {}", parent.display()))?;
    }
    let name = path
        .file_name()
        .context("--json needs a file name")?
        .to_string_lossy()
        .into_owned();
    let tmp = path.with_file_name(format!(".{name}.tmp{}", std::process::id()));
    std::fs::write(&tmp, bytes).with_context(|| format!("cannot write {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("cannot write {}", path.display()))
}
