//! The PyTorch reference side of `dnr bench bake`: trains `dnr_torch.py` for a budget on the
//! same capture and machine, renders its test views (`assets/peer_render.py`) and measures
//! them with the metrics our assets are measured with.

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{bail, Context, Result};
use dnr_bake::capture::{Capture, LoadOptions};
use dnr_bake::eval::metrics::{view_error, Rgba};
use dnr_bake::train::Record;

use super::Cell;

/// The script that renders a trained reference model's test views.
static RENDER_SCRIPT: &str = include_str!("../../../assets/peer_render.py");

/// How to run the reference.
pub struct Peer<'a> {
    /// Python with torch.
    pub python: &'a Path,
    /// `dnr_torch.py`.
    pub script: &'a Path,
    /// U-Net width multiplier.
    pub width: f64,
    /// Threads (0: 2, the reference's default).
    pub threads: usize,
}

impl Peer<'_> {
    /// Trains for `budget` seconds in `dir`, then measures the test views; returns the cell
    /// and the run's held-out records.
    pub fn run(
        &self,
        capture: &Path,
        mesh: Option<&Path>,
        budget: f64,
        dir: &Path,
    ) -> Result<(Cell, Vec<Record>)> {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
        let cache = dir.parent().unwrap_or(Path::new(".")).join("pytorch-cache");
        let cap = match mesh {
            Some(m) => shadow_capture(capture, m, &dir.join("capture"))?,
            None => capture.to_path_buf(),
        };
        let log = dir.join("log.jsonl");
        let threads = if self.threads == 0 { 2 } else { self.threads };
        let status = Command::new(self.python)
            .arg(self.script)
            .arg("train")
            .arg(&cap)
            .args(["--width", &self.width.to_string()])
            .args(["--time-budget-s", &budget.to_string()])
            .args([
                "--eval-every-s",
                &(budget / 10.0).clamp(5.0, 30.0).to_string(),
            ])
            .args(["--threads", &threads.to_string()])
            .arg("--cache")
            .arg(&cache)
            .arg("--out-dir")
            .arg(dir)
            .arg("--log")
            .arg(&log)
            .arg("--save")
            .stdout(std::process::Stdio::null())
            .status()
            .with_context(|| {
                format!(
                    "running {} {}",
                    self.python.display(),
                    self.script.display()
                )
            })?;
        if !status.success() {
            bail!("{}: training failed ({status})", self.script.display());
        }
        let (records, steps, seconds) = read_log(&log)?;
        let script = dir.join("peer_render.py");
        std::fs::write(&script, RENDER_SCRIPT)
            .with_context(|| format!("cannot write {}", script.display()))?;
        let renders = dir.join("renders");
        let status = Command::new(self.python)
            .arg(&script)
            .arg(self.script)
            .arg(&cap)
            .arg(dir.join("model.pt"))
            .arg(&renders)
            .arg(&cache)
            .arg(self.width.to_string())
            .status()
            .with_context(|| format!("running {}", script.display()))?;
        if !status.success() {
            bail!(
                "{}: rendering the test views failed ({status})",
                script.display()
            );
        }
        let (psnr, ssim, mse) = measure(capture, &renders)?;
        Ok((
            Cell {
                config: "pytorch".into(),
                budget,
                seconds,
                steps,
                psnr,
                ssim,
                mse,
                asset_bytes: 0,
                parts: None,
                storages: Vec::new(),
            },
            records,
        ))
    }
}

/// A copy of the capture's transforms whose mesh is `mesh` and whose images are the
/// capture's (absolute paths), for the reference, which takes its mesh from the transforms.
fn shadow_capture(capture: &Path, mesh: &Path, dir: &Path) -> Result<PathBuf> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let abs = |p: &Path| std::fs::canonicalize(p).with_context(|| format!("{}", p.display()));
    let (cap, mesh) = (abs(capture)?, abs(mesh)?);
    let mut any = false;
    for name in [
        "transforms.json",
        "transforms_train.json",
        "transforms_test.json",
    ] {
        let src = cap.join(name);
        if !src.is_file() {
            continue;
        }
        any = true;
        let text =
            std::fs::read_to_string(&src).with_context(|| format!("reading {}", src.display()))?;
        let mut v: serde_json::Value =
            serde_json::from_str(&text).with_context(|| format!("{}", src.display()))?;
        v["mesh_path"] = serde_json::json!(mesh.display().to_string());
        if let Some(frames) = v["frames"].as_array_mut() {
            for f in frames {
                if let Some(p) = f["file_path"].as_str() {
                    f["file_path"] = serde_json::json!(cap.join(p).display().to_string());
                }
            }
        }
        std::fs::write(dir.join(name), serde_json::to_vec_pretty(&v)?)
            .with_context(|| format!("writing {}", dir.join(name).display()))?;
    }
    if !any {
        bail!("{}: no transforms file", cap.display());
    }
    Ok(dir.to_path_buf())
}

/// The reference's evaluations (as records), its steps and training seconds.
fn read_log(log: &Path) -> Result<(Vec<Record>, u64, f64)> {
    let text =
        std::fs::read_to_string(log).with_context(|| format!("reading {}", log.display()))?;
    let mut records = Vec::new();
    let (mut steps, mut seconds) = (0, f64::NAN);
    for line in text.lines() {
        let v: serde_json::Value =
            serde_json::from_str(line).with_context(|| format!("{}: {line}", log.display()))?;
        let f = |k: &str| v[k].as_f64().unwrap_or(f64::NAN);
        match v["event"].as_str() {
            Some("eval") => records.push(Record {
                step: v["step"].as_u64().unwrap_or(0),
                seconds: f("train_s"),
                train_loss: f("train_l1_recent"),
                test_psnr: f("psnr_white"),
                test_mse: f("mse_obj_255"),
                val_psnr: f64::NAN,
                lr_factor: 1.0,
            }),
            Some("done") => {
                steps = v["steps"].as_u64().unwrap_or(0);
                seconds = f("train_s");
            }
            _ => {}
        }
    }
    if records.is_empty() {
        bail!("{}: no evaluation records", log.display());
    }
    Ok((records, steps, seconds))
}

/// Mean PSNR, SSIM and object MSE of the rendered test views (`renders/NNNN.png`, in the
/// order of the capture's test split) against the capture's images.
fn measure(capture: &Path, renders: &Path) -> Result<(f64, f64, f64)> {
    let cap = Capture::load(capture, &LoadOptions::default())?;
    if cap.test.is_empty() {
        bail!("{}: no test views", capture.display());
    }
    let (mut p, mut s, mut m) = (0.0, 0.0, 0.0);
    for (i, frame) in cap.test.iter().enumerate() {
        let path = renders.join(format!("{i:04}.png"));
        let img = image::open(&path)
            .with_context(|| format!("reading {}", path.display()))?
            .to_rgb8();
        let (w, h) = (frame.width() as usize, frame.height() as usize);
        if (img.width() as usize, img.height() as usize) != (w, h) {
            bail!(
                "{}: {}x{}, the view is {w}x{h}",
                path.display(),
                img.width(),
                img.height()
            );
        }
        let render: Vec<f32> = img
            .pixels()
            .flat_map(|px| {
                let c = px.0;
                [
                    f32::from(c[0]) / 255.0,
                    f32::from(c[1]) / 255.0,
                    f32::from(c[2]) / 255.0,
                    1.0,
                ]
            })
            .collect();
        let truth = dnr_bake::eval::truth_rgba(frame);
        let e = view_error(
            &Rgba {
                width: w,
                height: h,
                data: &render,
            },
            &Rgba {
                width: w,
                height: h,
                data: &truth,
            },
        );
        p += e.psnr;
        s += e.ssim;
        m += e.mse_obj;
    }
    let n = cap.test.len() as f64;
    Ok((p / n, s / n, m / n))
}
