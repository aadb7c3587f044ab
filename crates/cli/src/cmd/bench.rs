//! `dnr bench train | render | bake`: the benchmarks.
//!
//! `dnr bench train`: the training step and U-Net inference against the sgemm peak measured in
//! the same run, and (with `--torch`) PyTorch's same step timed in the same run.
//! `dnr bench render ASSET`: ms per frame of an asset at several sizes.
//! `dnr bench bake CAPTURE...`: held-out error against bake seconds (see [`super::bench_bake`]).

use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};

use anyhow::{bail, Context, Result};
use clap::{Args as ClapArgs, Subcommand};
use dnr_runtime::camera::Camera;
use dnr_runtime::renderer::Renderer;

use crate::markdown::{check_section, write_section, Align, Provenance, Table};

/// Benchmarks (time always reported with what it buys; see README "Benchmarks").
#[derive(ClapArgs)]
pub struct Args {
    #[command(subcommand)]
    what: What,
}

#[derive(Subcommand)]
enum What {
    /// Training step and inference of the CPU-sized (16..128) and paper (64..512) U-Nets at
    /// 128/256 (training) and 256/512 (inference), with GFLOP/s as a fraction of the sgemm
    /// peak measured in the same run.
    Train {
        /// Timed repetitions per row, at least (each row also runs for at least 3 s after 1 s of
        /// warm-up, as the PyTorch reference does; the minimum and median are reported).
        #[arg(long, default_value_t = 5)]
        reps: usize,
        /// Python with torch installed: also time the PyTorch reference (--peer) in the same
        /// run and print the ratio.
        #[arg(long, requires = "peer")]
        torch: Option<PathBuf>,
        /// The PyTorch reference script run with --torch: the paper's model in PyTorch, timed
        /// by its `bench` subcommand (`dnr_torch.py`; not part of this repository).
        #[arg(long, requires = "torch")]
        peer: Option<PathBuf>,
        /// Write the measurements as JSON.
        #[arg(long)]
        json: Option<PathBuf>,
        /// Write the tables of docs/benchmarks.md's training section as Markdown. A FILE
        /// holding the section's markers (`<!-- BEGIN dnr bench train -->` ... `END`) gets
        /// that section replaced and the rest kept; a file without markers is overwritten.
        #[arg(long, value_name = "FILE")]
        markdown: Option<PathBuf>,
        /// Measure nothing: render the tables of a run saved with --json (to stdout, or to
        /// --markdown).
        #[arg(long, value_name = "RUN.json", conflicts_with_all = ["torch", "json", "pairs"])]
        from_json: Option<PathBuf>,
        /// With --torch, also time the CPU-sized U-Net's step at 128 and 256 this many times
        /// alternately, ours then PyTorch's, and report each pair's ratio and their median: on
        /// a shared host the load drifts over the minutes between the main table's rows, and
        /// pairs taken seconds apart see it alike.
        #[arg(long, default_value_t = 0)]
        pairs: usize,
    },
    /// Held-out PSNR, SSIM and object MSE against bake seconds, on one capture or a whole
    /// development set: each configuration bakes once per budget (the learning-rate schedule
    /// spans the budget) and is measured by its exported asset through the runtime; with
    /// --torch, the PyTorch reference trains for the same seconds on the same machine. Writes
    /// per-capture and whole-set JSON, one PNG plot (a panel per capture) and, with
    /// --markdown, the tables with the set's mean and worst case.
    ///
    /// Configurations: the presets auto, fast, balanced, quality, paper, and the baselines
    /// classical (mean-colour texture, no learning), texture (learned texture only), mlp,
    /// unet-nosh (no SH layer), unet-1level (no pyramid), all built on balanced.
    ///
    /// Example: dnr bench bake caps/glossy caps/text --budgets 60,300 --torch venv/bin/python
    /// --peer dnr_torch.py --out bench/ --markdown bench/table.md
    Bake(super::bench_bake::BakeArgs),
    /// Milliseconds per frame of an asset at several sizes (camera on a circle around it).
    Render {
        /// The asset.
        asset: PathBuf,
        /// Square sizes.
        #[arg(long, value_delimiter = ',', default_value = "256,512")]
        sizes: Vec<u32>,
        /// Timed repetitions per size.
        #[arg(long, default_value_t = 5)]
        reps: usize,
        /// Reference assets (repeatable), e.g. the f32-storage or the unpruned asset of the
        /// same bake (`dnr-bake --write-f32 / --write-unpruned`): reports the error of
        /// ASSET's renders against each reference's, from four cameras around the object.
        #[arg(long, value_name = "REFERENCE")]
        against: Vec<PathBuf>,
        /// Also write the tables as Markdown, as section `dnr bench render NAME` (NAME: the
        /// asset's file name): a FILE holding that section's markers gets it replaced and
        /// the rest kept; a file without markers is overwritten.
        #[arg(long, value_name = "FILE")]
        markdown: Option<PathBuf>,
    },
}

/// Runs the subcommand.
pub fn run(args: &Args) -> Result<ExitCode> {
    match &args.what {
        What::Train {
            reps,
            torch,
            peer,
            json,
            pairs,
            markdown,
            from_json,
        } => match from_json {
            Some(run) => train_from_json(run, markdown.as_deref()),
            None => {
                let peer = torch.as_deref().zip(peer.as_deref());
                train(*reps, peer, json.as_ref(), *pairs, markdown.as_deref())
            }
        },
        What::Render {
            asset,
            sizes,
            reps,
            against,
            markdown,
        } => render(asset, sizes, *reps, against, markdown.as_deref()),
        What::Bake(a) => super::bench_bake::main(a),
    }
}

/// The PyTorch reference: the Python to run it with, and the script.
type Peer<'a> = (&'a Path, &'a Path);

/// Runs the PyTorch reference's `bench` with `args` (and our thread count) and returns its
/// JSON report.
fn run_peer((py, peer): Peer<'_>, args: &[&str], threads: usize) -> Result<serde_json::Value> {
    let tmp = std::env::temp_dir().join(format!("dnr-torch-bench-{}.json", std::process::id()));
    let status = Command::new(py)
        .arg(peer)
        .arg("bench")
        .args(args)
        .args(["--threads", &threads.to_string()])
        .arg("--json")
        .arg(&tmp)
        .stdout(std::process::Stdio::null())
        .status()
        .with_context(|| format!("running {} {}", py.display(), peer.display()))?;
    if !status.success() {
        bail!("{}: PyTorch benchmark failed ({status})", peer.display());
    }
    let text = std::fs::read_to_string(&tmp).with_context(|| tmp.display().to_string())?;
    let _ = std::fs::remove_file(&tmp);
    serde_json::from_str(&text).context("PyTorch benchmark JSON")
}

/// The PyTorch report's training-step row at `size` as (min, median) ms.
fn peer_step(t: &serde_json::Value, size: usize) -> Option<(f64, f64)> {
    t["runs"]
        .as_array()?
        .iter()
        .find(|r| r["kind"] == "train_step" && r["size"].as_u64() == Some(size as u64))
        .and_then(|r| Some((r["min_ms"].as_f64()?, r["median_ms"].as_f64()?)))
}

/// `--pairs`: the CPU-sized step at 128 and 256, ours then PyTorch's, `pairs` times; prints
/// each pair and the median ratio per size, returns them as JSON.
fn paired(peer: Peer<'_>, reps: usize, threads: usize, pairs: usize) -> Result<serde_json::Value> {
    let widths: Vec<u32> = dnr_bake::bench::CPU_WIDTHS
        .iter()
        .map(|&w| w as u32)
        .collect();
    println!("Pairs (CPU-sized step, ours then PyTorch's, seconds apart):");
    println!("| pair | size | dnr ms (min / median) | PyTorch ms (min / median) | speed-up (min / median) |");
    println!("| ---: | ---: | ---: | ---: | ---: |");
    let mut rows = Vec::new();
    let mut ratios: Vec<(usize, f64, f64)> = Vec::new();
    for p in 0..pairs {
        for size in [128usize, 256] {
            let (d_min, d_med, _) =
                dnr_bake::bench::step::bench_trainer_step(&widths, size, 1, reps);
            let s = size.to_string();
            // The peer always times an inference row too: 64 keeps it short (16 fails there: the
            // CPU-sized U-Net's bottom level would be 1x1, which instance norm rejects).
            let args = [
                "--widths",
                "0.25",
                "--train-sizes",
                &s,
                "--infer-sizes",
                "64",
            ];
            let t = run_peer(peer, &args, threads)?;
            let (t_min, t_med) = peer_step(&t, size).context("PyTorch report has no step row")?;
            let (r_min, r_med) = (t_min / d_min, t_med / d_med);
            println!(
                "| {p} | {size} | {d_min:.1} / {d_med:.1} | {t_min:.1} / {t_med:.1} | {r_min:.2}x / {r_med:.2}x |"
            );
            rows.push(
                serde_json::json!({"pair": p, "size": size, "dnrMsMin": d_min,
                "dnrMsMedian": d_med, "torchMsMin": t_min, "torchMsMedian": t_med,
                "speedupMin": r_min, "speedup": r_med}),
            );
            ratios.push((size, r_min, r_med));
        }
    }
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
    };
    let mut summary = Vec::new();
    for size in [128usize, 256] {
        let of = |f: fn(&(usize, f64, f64)) -> f64| {
            median(ratios.iter().filter(|r| r.0 == size).map(f).collect())
        };
        let (m_min, m_med) = (of(|r| r.1), of(|r| r.2));
        println!("Median over {pairs} pairs at {size}: {m_min:.2}x (min) / {m_med:.2}x (median)");
        summary.push(serde_json::json!({"size": size, "speedupMin": m_min, "speedup": m_med}));
    }
    Ok(serde_json::json!({"rows": rows, "medians": summary}))
}

fn train(
    reps: usize,
    peer: Option<Peer<'_>>,
    json: Option<&PathBuf>,
    pairs: usize,
    markdown: Option<&Path>,
) -> Result<ExitCode> {
    if pairs > 0 && peer.is_none() {
        bail!("--pairs needs --torch (the Python to time PyTorch with) and --peer");
    }
    if let Some(p) = markdown {
        check_section(p, super::bench_tables::TRAIN_SECTION)?;
    }
    // Taken before the run: the load average then says whether the machine was shared.
    let provenance = Provenance::now();
    let report = dnr_bake::bench::run_standard(reps);
    println!("{report}");
    let mut out = serde_json::json!({
        "provenance": provenance,
        "sgemmPeakGflops": report.peak_gflops,
        "fmaPeakGflops": report.fma_peak_gflops,
        "threads": report.threads,
        "simd": format!("{:?}", report.simd),
        "rows": report.rows.iter().map(|r| serde_json::json!({
            "kind": r.kind, "widths": r.widths, "size": r.size,
            "msMin": r.ms_min, "msMedian": r.ms_median, "gflop": r.gflop,
            "gflops": r.gflops(), "fractionOfPeak": r.gflops() / report.peak_gflops,
            "phasesMs": r.phases,
        })).collect::<Vec<_>>(),
        "convLayers": report.conv_layers.iter().map(|(size, layers)| serde_json::json!({
            "widths": dnr_bake::bench::CPU_WIDTHS, "size": size, "layers": layers,
        })).collect::<Vec<_>>(),
    });
    if let Some(peer) = peer {
        let args = [
            "--widths",
            "0.25",
            "1.0",
            "--train-sizes",
            "128",
            "256",
            "--infer-sizes",
            "256",
            "512",
        ];
        let t = run_peer(peer, &args, report.threads)?;
        println!(
            "PyTorch {} (same run, {} threads):",
            t["torch"], t["threads"]
        );
        // Medians are the headline; the minima (each side's fastest timed call) show the
        // same comparison with less of this machine's drift in it.
        println!(
            "| kind | widths | size | PyTorch ms (min / median) | dnr ms (min / median) | dnr speed-up (min / median) |"
        );
        println!("| --- | --- | ---: | ---: | ---: | ---: |");
        let mut cmp = Vec::new();
        for r in t["runs"].as_array().into_iter().flatten() {
            let widths: Vec<usize> = r["unet_widths"]
                .as_array()
                .into_iter()
                .flatten()
                .filter_map(|v| v.as_u64())
                .map(|v| v as usize)
                .collect();
            let size = r["size"].as_u64().unwrap_or(0) as usize;
            let kind = if r["kind"] == "train_step" {
                "step"
            } else {
                "infer"
            };
            let ms_t = r["median_ms"].as_f64().unwrap_or(f64::NAN);
            let min_t = r["min_ms"].as_f64().unwrap_or(f64::NAN);
            if let Some(ours) = report
                .rows
                .iter()
                .find(|o| o.kind == kind && o.widths == widths && o.size == size)
            {
                println!(
                    "| {kind} | {widths:?} | {size} | {min_t:.1} / {ms_t:.1} | {:.1} / {:.1} | {:.2}x / {:.2}x |",
                    ours.ms_min,
                    ours.ms_median,
                    min_t / ours.ms_min,
                    ms_t / ours.ms_median
                );
                cmp.push(serde_json::json!({"kind": kind, "widths": widths, "size": size,
                    "torchMsMedian": ms_t, "dnrMsMedian": ours.ms_median, "speedup": ms_t / ours.ms_median,
                    "torchMsMin": min_t, "dnrMsMin": ours.ms_min, "speedupMin": min_t / ours.ms_min}));
            }
        }
        out["torch"] = serde_json::json!({"version": t["torch"], "comparisons": cmp});
        if pairs > 0 {
            out["torch"]["pairs"] = paired(peer, reps, report.threads, pairs)?;
        }
    }
    if let Some(p) = json {
        std::fs::write(p, serde_json::to_string_pretty(&out)?)
            .with_context(|| p.display().to_string())?;
    }
    if let Some(p) = markdown {
        let body = super::bench_tables::train(&out).context("the run's tables")?;
        write_section(p, super::bench_tables::TRAIN_SECTION, &body)?;
        eprintln!("wrote the tables to {}", p.display());
    }
    Ok(ExitCode::SUCCESS)
}

/// `--from-json`: the tables of a saved run, printed or written as a section.
fn train_from_json(run: &Path, markdown: Option<&Path>) -> Result<ExitCode> {
    let text = std::fs::read_to_string(run).with_context(|| run.display().to_string())?;
    let v: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("{}: not JSON", run.display()))?;
    let body = super::bench_tables::train(&v).with_context(|| run.display().to_string())?;
    match markdown {
        Some(p) => {
            write_section(p, super::bench_tables::TRAIN_SECTION, &body)?;
            eprintln!("wrote the tables of {} to {}", run.display(), p.display());
        }
        None => print!("{body}"),
    }
    Ok(ExitCode::SUCCESS)
}

/// A path's file name for tables and section names (assets live anywhere; the name is what
/// a reader recognises).
fn file_name(p: &Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| p.display().to_string())
}

fn render(
    asset: &PathBuf,
    sizes: &[u32],
    reps: usize,
    against: &[PathBuf],
    markdown: Option<&Path>,
) -> Result<ExitCode> {
    if let Some(p) = markdown {
        check_section(p, &super::bench_tables::render_section(&file_name(asset)))?;
    }
    let provenance = Provenance::now();
    let r = Renderer::from_path(asset).with_context(|| asset.display().to_string())?;
    // The same renderer evaluating every U-Net position (no receptive-field skipping).
    let mut full = r.clone();
    full.set_skip_uncovered(false);
    let camera = |s: u32, k: usize| {
        let a = k as f32 * std::f32::consts::FRAC_PI_2;
        let eye = glam::Vec3::new(3.4 * a.sin(), 1.2, 3.4 * a.cos());
        Camera::look_at(eye, glam::Vec3::ZERO, 40.0, s, s)
    };
    let mut times = Table::new(&[
        ("size", Align::Right),
        ("ms per frame (min)", Align::Right),
        ("ms (median)", Align::Right),
        ("ms without skipping (min)", Align::Right),
    ]);
    for &s in sizes {
        let cam = camera(s, 0);
        // A frame that fails (a bad size, a network error) is reported here, before timing.
        for rr in [&r, &full] {
            rr.render(&cam, s, s)
                .with_context(|| format!("{}: a {s}x{s} frame", asset.display()))?;
        }
        // ok: the same frames rendered above, so these cannot fail.
        let (min, med) = dnr_bake::bench::time_min_median(reps, || {
            std::hint::black_box(r.render(&cam, s, s).expect("render"));
        });
        // ok: as above.
        let (full_min, _) = dnr_bake::bench::time_min_median(reps, || {
            std::hint::black_box(full.render(&cam, s, s).expect("render"));
        });
        times.row(vec![
            s.to_string(),
            format!("{:.1}", 1e3 * min),
            format!("{:.1}", 1e3 * med),
            format!("{:.1}", 1e3 * full_min),
        ]);
    }
    print!("{}", times.render());
    let mut errors = Table::new(&[
        ("reference", Align::Left),
        ("size", Align::Right),
        (
            "PSNR of ASSET against it (dB, float, on white)",
            Align::Right,
        ),
        ("max abs difference", Align::Right),
        ("reference ms (min)", Align::Right),
    ]);
    for reference in against {
        let q = Renderer::from_path(reference).with_context(|| reference.display().to_string())?;
        for &s in sizes {
            let (mut se, mut n, mut max_abs) = (0.0f64, 0usize, 0.0f32);
            for k in 0..4 {
                let cam = camera(s, k);
                let a = r
                    .render(&cam, s, s)
                    .with_context(|| asset.display().to_string())?;
                let b = q
                    .render(&cam, s, s)
                    .with_context(|| reference.display().to_string())?;
                for (pa, pb) in a.data.chunks_exact(4).zip(b.data.chunks_exact(4)) {
                    for c in 0..3 {
                        let on_white = |p: &[f32]| p[c] * p[3] + (1.0 - p[3]);
                        let d = on_white(pa) - on_white(pb);
                        se += (d as f64) * (d as f64);
                        max_abs = max_abs.max(d.abs());
                    }
                    n += 3;
                }
            }
            let psnr = 10.0 * (1.0 / (se / n.max(1) as f64)).log10();
            let cam = camera(s, 0);
            let (q_min, _) = dnr_bake::bench::time_min_median(reps, || {
                // Rendered with this camera above already, so an error cannot first appear here.
                std::hint::black_box(q.render(&cam, s, s).ok());
            });
            errors.row(vec![
                file_name(reference),
                s.to_string(),
                format!("{psnr:.2}"),
                format!("{max_abs:.2e}"),
                format!("{:.1}", 1e3 * q_min),
            ]);
        }
    }
    if !errors.is_empty() {
        println!();
        print!("{}", errors.render());
    }
    let decode = level_decode_table(asset, reps)?;
    println!();
    print!("{}", decode.render());
    if let Some(p) = markdown {
        let bytes = std::fs::metadata(asset)
            .with_context(|| asset.display().to_string())?
            .len();
        let archs: Vec<&str> = (0..r.renderer_count())
            .filter_map(|i| r.architecture(i))
            .collect();
        let name = file_name(asset);
        let body = super::bench_tables::render(
            &provenance,
            &super::bench_tables::RenderRun {
                asset: &name,
                bytes,
                architectures: &archs,
                reps,
                threads: dnr_bake::bench::worker_threads(),
            },
            &times,
            &errors,
        );
        let body = format!(
            "{body}\nDecoding each texture level of the asset, re-encoded in each storage (`dnr_format` readers, min over {reps} runs):\n\n{}",
            decode.render()
        );
        write_section(p, &super::bench_tables::render_section(&name), &body)?;
        eprintln!("wrote the tables to {}", p.display());
    }
    Ok(ExitCode::SUCCESS)
}

/// Decode time and bytes of each texture level of `asset` stored as EXR (ZIP, f16) and as
/// quantised PNG at 8 and 4 bits (format revision 1.1), through `dnr_format`'s readers.
fn level_decode_table(asset: &Path, reps: usize) -> Result<Table> {
    use dnr_format::exr_codec::{decode_level, encode_level, LevelExpect};
    use dnr_format::quant::{decode_png_level, encode_png_level};
    let a = dnr_format::read_asset(asset).with_context(|| asset.display().to_string())?;
    let mut t = Table::new(&[
        ("level", Align::Right),
        ("size", Align::Left),
        ("storage", Align::Left),
        ("bytes", Align::Right),
        ("decode ms (min)", Align::Right),
    ]);
    let limits = dnr_format::Limits::default();
    for tex in &a.textures {
        for (li, l) in tex.levels.iter().enumerate() {
            let expect = LevelExpect {
                width: l.width,
                height: l.height,
                channels: l.channels,
            };
            let size = format!("{}x{}x{}", l.width, l.height, l.channels);
            let exr = encode_level(l, li, dnr_format::LevelCompression::Zip)
                .with_context(|| format!("level {li} as EXR"))?;
            decode_level(&exr, expect, &limits).map_err(|p| anyhow::anyhow!("{}", p.error))?;
            let (min, _) = dnr_bake::bench::time_min_median(reps, || {
                std::hint::black_box(decode_level(&exr, expect, &limits).ok());
            });
            t.row(vec![
                li.to_string(),
                size.clone(),
                "EXR f16 (ZIP)".into(),
                exr.len().to_string(),
                format!("{:.2}", 1e3 * min),
            ]);
            for bits in [8, 4] {
                let (q, png) = encode_png_level(l, bits)
                    .with_context(|| format!("level {li} as {bits}-bit PNG"))?;
                decode_png_level(&png, expect, &q, &limits)
                    .map_err(|p| anyhow::anyhow!("{}", p.error))?;
                let (min, _) = dnr_bake::bench::time_min_median(reps, || {
                    std::hint::black_box(decode_png_level(&png, expect, &q, &limits).ok());
                });
                t.row(vec![
                    li.to_string(),
                    size.clone(),
                    format!("PNG q{bits}"),
                    png.len().to_string(),
                    format!("{:.2}", 1e3 * min),
                ]);
            }
        }
    }
    Ok(t)
}
