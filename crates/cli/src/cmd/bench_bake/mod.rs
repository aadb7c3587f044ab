//! `dnr bench bake CAPTURE...`: held-out error against bake seconds, on one capture or a
//! whole development set, for presets, baselines and (with `--torch`) the PyTorch reference
//! at the same seconds on the same machine; per capture a JSON table, and for the set the
//! mean and worst case, Markdown tables and two PNG plots (held-out PSNR against seconds and
//! against asset bytes, each storage of the same trained state a point, see `bytes`).
//!
//! Every preset's learning-rate schedule spans its budget, so each configuration bakes once
//! per budget, and each cell is that bake's exported asset evaluated through the runtime on
//! the capture's test views (f16 storage included). The curves of the plot are the
//! held-out records of the largest budget's bake. Seconds count the initialisation and the
//! validation checks and exclude the test-view records, as `dnr-bake` reports them; the
//! PyTorch reference's seconds likewise exclude its evaluation.

mod bytes;
mod configs;
mod peer;
mod plot;
mod table;

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use dnr_bake::bake::{bake, write_atomic, BakeOptions};
use dnr_bake::train::Record;
use serde::{Deserialize, Serialize};

pub use configs::{config, BASELINES};
pub use table::{markdown, summarise, Summary};

/// `dnr bench bake`'s arguments.
#[derive(clap::Args, Debug)]
pub struct BakeArgs {
    /// Capture folders (one or a development set).
    #[arg(required_unless_present = "from_json")]
    pub captures: Vec<PathBuf>,
    /// Presets (or any configuration names) to run.
    #[arg(long, value_delimiter = ',', default_value = "auto")]
    pub presets: Vec<String>,
    /// Also run the baselines (classical, texture, mlp, unet-nosh, unet-1level).
    #[arg(long)]
    pub baselines: bool,
    /// Budgets in seconds.
    #[arg(long, value_delimiter = ',', default_value = "60,300,600")]
    pub budgets: Vec<f64>,
    /// Proxy mesh file name inside each capture folder instead of its own mesh (e.g.
    /// mesh_coarse.glb).
    #[arg(long)]
    pub mesh_name: Option<String>,
    /// Folder for the assets, reports, tables (bench_bake.json) and plot (bench_bake.png).
    #[arg(long, default_value = "bench-bake")]
    pub out: PathBuf,
    /// Worker threads (default: all cores).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Python with torch installed: also train the PyTorch reference (--peer) for the same
    /// seconds on each capture, one run per budget, and measure its renders of the test
    /// views with the same metrics.
    #[arg(long, requires = "peer")]
    pub torch: Option<PathBuf>,
    /// The PyTorch reference script (dnr_torch.py).
    #[arg(long)]
    pub peer: Option<PathBuf>,
    /// Run the reference at the same time as the first configuration's bake at each
    /// budget, each on `--threads` threads (use 1 on two cores), so both see the same host;
    /// without it they run one after the other.
    #[arg(long, requires = "peer")]
    pub side_by_side: bool,
    /// Draw the tables and plots from saved runs instead of measuring: `bench_bake.json` of
    /// a set or of one capture, several to join runs made apart (per capture, or on other
    /// machines). Writes into `--out` and `--markdown` as a measuring run would.
    #[arg(long, num_args = 1.., value_name = "JSON", conflicts_with = "captures")]
    pub from_json: Vec<PathBuf>,
    /// U-Net width multiplier of the PyTorch reference (0.25: the CPU-sized 16..128).
    #[arg(long, default_value_t = 0.25)]
    pub peer_width: f64,
    /// Also write the tables as Markdown here.
    #[arg(long)]
    pub markdown: Option<PathBuf>,
    /// Storage of the assets (`dnr-bake --storage`): f16, or q8, q4, auto, whose reports
    /// also measure every uniform storage of the same trained state (the bytes axis).
    #[arg(long, value_name = "STORAGE", default_value = "f16")]
    pub storage: dnr_bake::storage::StorageMode,
}

/// One cell: a configuration's bake of a capture at a budget.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct Cell {
    /// Configuration name (`pytorch` for the reference).
    pub config: String,
    /// Budget in seconds.
    pub budget: f64,
    /// Training seconds the bake took.
    #[serde(deserialize_with = "dnr_bake::train::f64_or_nan")]
    pub seconds: f64,
    /// Steps taken.
    pub steps: u64,
    /// Held-out PSNR (dB), full frame on white.
    #[serde(deserialize_with = "dnr_bake::train::f64_or_nan")]
    pub psnr: f64,
    /// Held-out SSIM.
    #[serde(deserialize_with = "dnr_bake::train::f64_or_nan")]
    pub ssim: f64,
    /// Held-out MSE on [0, 255] over object pixels.
    #[serde(deserialize_with = "dnr_bake::train::f64_or_nan")]
    pub mse: f64,
    /// Asset bytes (0 for the reference, which writes none).
    pub asset_bytes: u64,
    /// The asset's bytes by part (absent for the reference).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub parts: Option<dnr_bake::storage::PartBytes>,
    /// Each storage of the same trained state: bytes and held-out PSNR (`--storage` q8, q4
    /// or auto measure f16, q8, q4 and the chosen mix; f16 only the asset).
    pub storages: Vec<bytes::StorageCell>,
}

/// One capture's table.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct Table {
    /// Capture folder.
    pub capture: String,
    /// Short name (the folder's, with the proxy's stem when `--mesh-name` was given).
    pub name: String,
    /// Proxy mesh used instead of the capture's own.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mesh: Option<String>,
    /// Budgets in seconds.
    pub budgets: Vec<f64>,
    /// One cell per configuration and budget.
    pub cells: Vec<Cell>,
    /// Held-out records of each configuration's largest-budget bake (the plot's curves).
    pub curves: Vec<(String, Vec<Record>)>,
}

/// Everything one `dnr bench bake` measured.
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Suite {
    /// Per capture.
    pub tables: Vec<Table>,
    /// Mean and worst case over the captures, per configuration and budget.
    pub summary: Vec<Summary>,
}

/// Runs `dnr bench bake`.
pub fn main(a: &BakeArgs) -> Result<ExitCode> {
    if !a.from_json.is_empty() {
        return from_json(a);
    }
    if a.budgets.is_empty() || a.budgets.iter().any(|b| !(b.is_finite() && *b > 0.0)) {
        bail!("--budgets must be positive seconds, got {:?}", a.budgets);
    }
    let mut names = a.presets.clone();
    if a.baselines {
        for b in BASELINES {
            if !names.iter().any(|c| c == b) {
                names.push(b.to_string());
            }
        }
    }
    // Refuse unknown names before baking anything.
    for n in &names {
        config(n)?;
    }
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    let mut tables = Vec::new();
    for capture in &a.captures {
        let t = run_capture(a, capture, &names)?;
        // Written after each capture, so a long run that stops keeps what it measured.
        let dir = a.out.join(&t.name);
        write_json(&dir.join("bench_bake.json"), &t)?;
        tables.push(t);
        write_suite(a, &tables)?;
    }
    let suite = write_suite(a, &tables)?;
    println!("{}", full_markdown(&suite));
    eprintln!(
        "wrote {}, {} and {}",
        a.out.join("bench_bake.json").display(),
        a.out.join("bench_bake.png").display(),
        a.out.join("bench_bake_bytes.png").display()
    );
    Ok(ExitCode::SUCCESS)
}

/// `--from-json`: the tables of saved runs, joined, drawn and written as a run would.
fn from_json(a: &BakeArgs) -> Result<ExitCode> {
    let tables = read_tables(&a.from_json)?;
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    let suite = write_suite(a, &tables)?;
    println!("{}", full_markdown(&suite));
    Ok(ExitCode::SUCCESS)
}

/// The tables of saved `bench_bake.json` files (a set's or one capture's), in order; a
/// capture in two files is an error.
fn read_tables(paths: &[PathBuf]) -> Result<Vec<Table>> {
    let mut tables: Vec<Table> = Vec::new();
    for path in paths {
        let text =
            std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
        let v: serde_json::Value = serde_json::from_slice(&text)
            .with_context(|| format!("{}: not JSON", path.display()))?;
        // A set's file holds `tables`; one capture's file is a table itself.
        let found: Vec<Table> = match v.get("tables") {
            Some(t) => serde_json::from_value(t.clone()),
            None => serde_json::from_value(v).map(|t| vec![t]),
        }
        .with_context(|| {
            format!(
                "{}: not a `dnr bench bake` table or set (bench_bake.json)",
                path.display()
            )
        })?;
        for t in found {
            if tables.iter().any(|u| u.name == t.name) {
                bail!(
                    "{}: capture `{}` is in two of the files",
                    path.display(),
                    t.name
                );
            }
            tables.push(t);
        }
    }
    Ok(tables)
}

fn write_json<T: Serialize>(path: &Path, v: &T) -> Result<()> {
    if let Some(d) = path.parent() {
        std::fs::create_dir_all(d).with_context(|| format!("cannot create {}", d.display()))?;
    }
    let text = serde_json::to_string_pretty(v)?;
    write_atomic(path, text.as_bytes()).with_context(|| format!("cannot write {}", path.display()))
}

/// Writes the set's JSON, plot and Markdown for the tables so far.
fn write_suite(a: &BakeArgs, tables: &[Table]) -> Result<Suite> {
    let suite = Suite {
        tables: tables.to_vec(),
        summary: summarise(tables),
    };
    write_json(&a.out.join("bench_bake.json"), &suite)?;
    let png = plot::plot(&suite).context("drawing the plot")?;
    let p = a.out.join("bench_bake.png");
    write_atomic(&p, &png).with_context(|| format!("cannot write {}", p.display()))?;
    let png = plot::plot_bytes(&suite).context("drawing the bytes plot")?;
    let p = a.out.join("bench_bake_bytes.png");
    write_atomic(&p, &png).with_context(|| format!("cannot write {}", p.display()))?;
    if let Some(md) = &a.markdown {
        write_atomic(md, full_markdown(&suite).as_bytes())
            .with_context(|| format!("cannot write {}", md.display()))?;
    }
    Ok(suite)
}

/// The PSNR tables, then the bytes section.
fn full_markdown(s: &Suite) -> String {
    format!("{}\n{}", markdown(s), bytes::markdown(s))
}

/// The short name of a capture run.
fn run_name(capture: &Path, mesh_name: Option<&str>) -> String {
    let base = capture
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "capture".into());
    match mesh_name {
        Some(m) => {
            let stem = Path::new(m)
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
            format!("{base}-{stem}")
        }
        None => base,
    }
}

/// Bakes every configuration at every budget on one capture (and the reference).
fn run_capture(a: &BakeArgs, capture: &Path, names: &[String]) -> Result<Table> {
    let name = run_name(capture, a.mesh_name.as_deref());
    let dir = a.out.join(&name);
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let mesh = a.mesh_name.as_ref().map(|m| capture.join(m));
    if let Some(m) = &mesh {
        if !m.is_file() {
            bail!("{}: no such proxy mesh (--mesh-name)", m.display());
        }
    }
    let max_budget = a.budgets.iter().copied().fold(0.0, f64::max);
    let mut table = Table {
        capture: capture.display().to_string(),
        name: name.clone(),
        mesh: mesh.as_ref().map(|m| m.display().to_string()),
        budgets: a.budgets.clone(),
        cells: Vec::new(),
        curves: Vec::new(),
    };
    let peer = match (&a.torch, &a.peer) {
        (Some(python), Some(script)) => Some(peer::Peer {
            python,
            script,
            width: a.peer_width,
            threads: a.threads,
        }),
        _ => None,
    };
    let run_peer = |p: &peer::Peer, budget: f64| {
        eprintln!("dnr bench bake: {name}: PyTorch reference for {budget} s");
        p.run(
            capture,
            mesh.as_deref(),
            budget,
            &dir.join(format!("pytorch-{budget}")),
        )
        .with_context(|| format!("PyTorch reference on {name} for {budget} s"))
    };
    let mut peer_cells = Vec::new();
    for (i, cname) in names.iter().enumerate() {
        let mut cfg = config(cname)?;
        cfg.threads = a.threads;
        for &budget in &a.budgets {
            cfg.time_budget = budget;
            cfg.eval_every = (budget / 10.0).clamp(5.0, 30.0);
            let stem = format!("{cname}-{budget}");
            let output = dir.join(format!("{stem}.glb"));
            eprintln!(
                "dnr bench bake: {name}: {cname} for {budget} s -> {}",
                output.display()
            );
            let opts = BakeOptions {
                mesh: mesh.clone(),
                report: Some(dir.join(format!("{stem}.json"))),
                progress: !a.side_by_side,
                storage: a.storage,
                ..BakeOptions::new(capture, output.clone())
            };
            let beside = peer.as_ref().filter(|_| a.side_by_side && i == 0);
            let (baked, peer_run) = std::thread::scope(|sc| {
                let handle = beside.map(|p| sc.spawn(|| run_peer(p, budget)));
                let baked = bake(&cfg, &opts);
                let peer_run = handle.map(|h| {
                    h.join()
                        .unwrap_or_else(|_| Err(anyhow::anyhow!("the reference's thread panicked")))
                });
                (baked, peer_run)
            });
            if let Some(r) = peer_run {
                peer_cells.push((budget, r?));
            }
            let s = baked.with_context(|| format!("baking `{stem}` of {name}"))?;
            let mut cell = Cell {
                config: cname.clone(),
                budget,
                seconds: s.train_seconds,
                steps: s.steps,
                psnr: s.test_psnr,
                ssim: s.test_ssim,
                mse: s.test_mse,
                asset_bytes: s.asset_bytes,
                parts: Some(bytes::read_parts(&output)?),
                storages: Vec::new(),
            };
            let report_path = dir.join(format!("{stem}.json"));
            let report: serde_json::Value = serde_json::from_slice(
                &std::fs::read(&report_path)
                    .with_context(|| format!("cannot read {}", report_path.display()))?,
            )
            .with_context(|| format!("{}: malformed report", report_path.display()))?;
            cell.storages = bytes::storages(&report, &cell);
            table.cells.push(cell);
            if budget == max_budget {
                table.curves.push((cname.clone(), s.records.clone()));
            }
        }
    }
    if let Some(p) = peer.as_ref().filter(|_| !a.side_by_side) {
        for &budget in &a.budgets {
            peer_cells.push((budget, run_peer(p, budget)?));
        }
    }
    for (budget, (cell, records)) in peer_cells {
        table.cells.push(cell);
        if budget == max_budget {
            table.curves.push(("pytorch".into(), records));
        }
    }
    Ok(table)
}

#[cfg(test)]
pub(super) mod testing {
    use super::{Cell, Table};
    use dnr_bake::train::Record;

    /// A held-out record at `seconds` with `psnr`.
    pub fn rec(seconds: f64, psnr: f64) -> Record {
        Record {
            step: 1,
            seconds,
            train_loss: 0.1,
            test_psnr: psnr,
            test_mse: 10.0,
            val_psnr: f64::NAN,
            lr_factor: 1.0,
        }
    }

    /// A capture's table: auto and the reference at 60 and 300 s, three storages each, and
    /// both curves.
    pub fn table(name: &str) -> Table {
        Table {
            capture: name.into(),
            name: name.into(),
            mesh: None,
            budgets: vec![60.0, 300.0],
            cells: ["auto", "pytorch"]
                .iter()
                .flat_map(|c| {
                    [60.0, 300.0].map(|b| Cell {
                        config: (*c).into(),
                        budget: b,
                        seconds: b,
                        steps: 1,
                        psnr: 30.0 + b / 100.0,
                        ssim: 0.9,
                        mse: 10.0,
                        asset_bytes: 1,
                        parts: None,
                        storages: ["f16", "q8", "q4"]
                            .iter()
                            .enumerate()
                            .map(|(i, n)| super::bytes::StorageCell {
                                name: (*n).into(),
                                bytes: 4_000_000 >> i,
                                psnr: 30.0 - i as f64 + b / 100.0,
                            })
                            .collect(),
                    })
                })
                .collect(),
            curves: vec![
                (
                    "auto".into(),
                    (1..30)
                        .map(|i| rec(10.0 * i as f64, 25.0 + i as f64 / 5.0))
                        .collect(),
                ),
                (
                    "pytorch".into(),
                    (1..30)
                        .map(|i| rec(10.0 * i as f64, 24.0 + i as f64 / 6.0))
                        .collect(),
                ),
            ],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn saved_sets_and_tables_read_back_joined_with_unmeasured_figures_kept() {
        let dir = tempfile::tempdir().unwrap();
        let mut a = testing::table("a");
        a.cells[2].ssim = f64::NAN; // the reference's SSIM, not measured
        let set = Suite {
            tables: vec![a, testing::table("b")],
            summary: Vec::new(),
        };
        let set_path = dir.path().join("set.json");
        write_json(&set_path, &set).unwrap();
        let one_path = dir.path().join("c.json");
        write_json(&one_path, &testing::table("c")).unwrap();
        let t = read_tables(&[set_path.clone(), one_path.clone()]).unwrap();
        assert_eq!(
            t.iter().map(|t| t.name.as_str()).collect::<Vec<_>>(),
            ["a", "b", "c"]
        );
        assert!(t[0].cells[2].ssim.is_nan() && t[0].cells[0].ssim == 0.9);
        assert!(t[0].curves[0].1[0].val_psnr.is_nan());
        assert_eq!(t[1].cells.len(), 4);
        let md = full_markdown(&Suite {
            summary: summarise(&t),
            tables: t,
        });
        assert!(md.contains("| a | pytorch | 30.60 / - / 10.0 |"), "{md}");
        // The same capture twice, and a file that is not a table, are errors naming it.
        let e = read_tables(&[set_path.clone(), set_path.clone()]).unwrap_err();
        assert!(format!("{e:#}").contains("`a` is in two"), "{e:#}");
        let bad = dir.path().join("bad.json");
        std::fs::write(&bad, "{\"cells\": 3}").unwrap();
        let e = read_tables(&[bad]).unwrap_err();
        assert!(
            format!("{e:#}").contains("bad.json: not a `dnr bench bake` table"),
            "{e:#}"
        );
    }

    #[test]
    fn run_names_carry_the_proxy() {
        assert_eq!(run_name(Path::new("caps/duck"), None), "duck");
        assert_eq!(
            run_name(Path::new("caps/duck/"), Some("mesh_coarse.glb")),
            "duck-mesh_coarse"
        );
    }
}
