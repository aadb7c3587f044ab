//! `dnr bench bake CAPTURE`: held-out error against bake seconds, for presets and the
//! baselines that show what each component buys, as a JSON table and a PNG plot.
//!
//! Each configuration is baked once with the largest budget, evaluating the held-out views
//! through the runtime every `min(budget) / 2` seconds (at most 30 s). Training does not
//! depend on the budget (no schedule reads it), so the evaluation at `B` seconds is what a
//! bake with `--time-budget B` would have reached; a configuration whose step limit ends it
//! earlier keeps its final figures at later budgets. Seconds count the initialisation
//! (classical texturing) and exclude evaluation, as `dnr-bake` reports them.
//!
//! `auto` decides by the budget, so it bakes once per budget and each cell is its exported
//! asset's held-out error through the runtime (f16 storage included); the other cells are
//! the training state's evaluations (f32), which the runs' `finalPsnr` (f16 asset) checks.
//! Every bake also writes `NAME.f32.glb` (same state, f32 storage) and auto
//! `auto-B.unpruned.glb`, the references for `dnr bench render --against`.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use dnr_bake::bake::{bake, write_atomic, BakeOptions};
use dnr_bake::train::config::{Arch, Preset, TrainConfig, MLP_DEFAULT_WIDTHS};
use dnr_bake::train::Record;
use serde::Serialize;

/// What to run (from `dnr bench bake`'s flags).
pub struct Plan<'a> {
    /// Capture folder.
    pub capture: &'a Path,
    /// Configurations by name (see [`config`]).
    pub configs: Vec<String>,
    /// Budgets in seconds.
    pub budgets: Vec<f64>,
    /// Proxy mesh overriding the capture's.
    pub mesh: Option<&'a Path>,
    /// Folder for the assets and reports of every run.
    pub out: &'a Path,
    /// JSON table path.
    pub json: &'a Path,
    /// PNG plot path.
    pub plot: &'a Path,
    /// Worker threads (0 = all cores).
    pub threads: usize,
}

/// The baselines `--presets` adds unless `--no-baselines`: classical texturing, learned
/// texture only, the per-pixel MLP, and the U-Net without SH and without the pyramid.
pub const BASELINES: [&str; 5] = ["classical", "texture", "mlp", "unet-nosh", "unet-1level"];

/// The configuration a name stands for: a preset (`auto`, `fast`, `balanced`, `quality`, `paper`) or
/// a baseline built on `balanced` (`classical`: the mean-colour texture of the training pixels,
/// no learning; `texture`: learned texture, architecture `none`; `mlp`: per-pixel MLP 64,64;
/// `unet-nosh`: no SH layer; `unet-1level`: a single texture level, no pyramid).
pub fn config(name: &str) -> Result<TrainConfig> {
    let balanced = TrainConfig::preset(Preset::Balanced);
    Ok(match name {
        "fast" => TrainConfig::preset(Preset::Fast),
        "balanced" => balanced,
        "quality" => TrainConfig::preset(Preset::Quality),
        "paper" => TrainConfig::preset(Preset::Paper),
        "auto" => TrainConfig::preset(Preset::Auto),
        "classical" => TrainConfig {
            arch: Arch::None,
            steps: 0,
            ..balanced
        },
        "texture" => TrainConfig {
            arch: Arch::None,
            ..balanced
        },
        "mlp" => TrainConfig {
            arch: Arch::Mlp,
            widths: MLP_DEFAULT_WIDTHS.to_vec(),
            ..balanced
        },
        "unet-nosh" => TrainConfig {
            sh: false,
            ..balanced
        },
        "unet-1level" => TrainConfig {
            levels: 1,
            ..balanced
        },
        other => bail!(
            "unknown configuration `{other}` (presets: auto, fast, balanced, quality, paper; baselines: {})",
            BASELINES.join(", ")
        ),
    })
}

/// One cell of the table: a configuration at a budget.
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Cell {
    /// Configuration name.
    pub config: String,
    /// Budget in seconds.
    pub budget: f64,
    /// Training seconds of the evaluation used (the first at or after the budget, or the
    /// last one when the run ended earlier).
    pub seconds: f64,
    /// Steps at that evaluation.
    pub step: u64,
    /// Held-out PSNR (dB), full frame on white.
    pub psnr: f64,
    /// Held-out MSE on [0,255] over object pixels.
    pub mse: f64,
    /// For configurations baked once per budget (auto): that bake's asset size.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub asset_bytes: Option<u64>,
}

impl Cell {
    /// The cell of `config` at `budget` that evaluation `r` stands for.
    fn of(config: &str, budget: f64, r: &Record) -> Cell {
        Cell {
            config: config.to_string(),
            budget,
            seconds: r.seconds,
            step: r.step,
            psnr: r.test_psnr,
            mse: r.test_mse,
            asset_bytes: None,
        }
    }
}

/// One configuration's run.
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Run {
    /// Configuration name.
    pub config: String,
    /// The asset written with the largest budget.
    pub asset: String,
    /// Its size in bytes.
    pub asset_bytes: u64,
    /// Held-out PSNR of the written asset through the runtime (f16 storage included).
    pub final_psnr: f64,
    /// Every evaluation of the run.
    pub records: Vec<Record>,
}

/// The whole table.
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Table {
    /// Capture folder.
    pub capture: String,
    /// Proxy mesh given with `--mesh` (else the capture's own).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mesh: Option<String>,
    /// Budgets in seconds.
    pub budgets: Vec<f64>,
    /// One cell per configuration and budget.
    pub cells: Vec<Cell>,
    /// One run per configuration.
    pub runs: Vec<Run>,
}

/// The evaluation that stands for `budget`: the first at or after it (within a step's
/// rounding), else the last one.
fn at_budget(records: &[Record], budget: f64) -> Option<&Record> {
    records
        .iter()
        .find(|r| r.seconds >= budget * 0.999)
        .or(records.last())
}

/// Runs every configuration, writes the JSON table and the plot, and returns the table.
pub fn run(plan: &Plan<'_>) -> Result<Table> {
    if plan.budgets.is_empty() || plan.budgets.iter().any(|b| !(b.is_finite() && *b > 0.0)) {
        bail!("--budgets must be positive seconds, got {:?}", plan.budgets);
    }
    let configs: Vec<(String, TrainConfig)> = plan
        .configs
        .iter()
        .map(|n| config(n).map(|c| (n.clone(), c)))
        .collect::<Result<_>>()?;
    let max_budget = plan.budgets.iter().copied().fold(0.0, f64::max);
    let min_budget = plan.budgets.iter().copied().fold(f64::INFINITY, f64::min);
    std::fs::create_dir_all(plan.out)
        .with_context(|| format!("cannot create {}", plan.out.display()))?;
    let mut table = Table {
        capture: plan.capture.display().to_string(),
        mesh: plan.mesh.map(|m| m.display().to_string()),
        budgets: plan.budgets.clone(),
        cells: Vec::new(),
        runs: Vec::new(),
    };
    for (name, mut cfg) in configs {
        cfg.eval_every = (min_budget / 2.0).min(30.0);
        cfg.threads = plan.threads;
        // Auto's decisions depend on the budget: one bake per budget, each measured by its
        // exported asset. Every other configuration bakes once with the largest budget.
        let per_budget = cfg.preset == Preset::Auto;
        let bakes: Vec<f64> = if per_budget {
            plan.budgets.clone()
        } else {
            vec![max_budget]
        };
        let mut auto_points = Vec::new();
        let mut last = None;
        for budget in bakes {
            cfg.time_budget = budget;
            let stem = if per_budget {
                format!("{name}-{budget}")
            } else {
                name.clone()
            };
            let output = plan.out.join(format!("{stem}.glb"));
            eprintln!(
                "dnr bench bake: {name} for up to {budget} s -> {}",
                output.display()
            );
            let opts = BakeOptions {
                capture: plan.capture.to_path_buf(),
                output: output.clone(),
                mesh: plan.mesh.map(Path::to_path_buf),
                report: Some(plan.out.join(format!("{stem}.json"))),
                resume: false,
                progress: true,
                checkpoint_every: 1e9,
                limits: Default::default(),
                // The same state with f32 storage, and auto's state before pruning, for
                // `dnr bench render ASSET --against REFERENCE`.
                write_f32: Some(plan.out.join(format!("{stem}.f32.glb"))),
                write_unpruned: per_budget.then(|| plan.out.join(format!("{stem}.unpruned.glb"))),
                input: Default::default(),
            };
            let summary = bake(&cfg, &opts).with_context(|| format!("baking `{stem}`"))?;
            if per_budget {
                table.cells.push(Cell {
                    config: name.clone(),
                    budget,
                    seconds: summary.train_seconds,
                    step: summary.steps,
                    psnr: summary.test_psnr,
                    mse: summary.test_mse,
                    asset_bytes: Some(summary.asset_bytes),
                });
                auto_points.push(Record {
                    step: summary.steps,
                    seconds: summary.train_seconds,
                    train_loss: f64::NAN,
                    test_psnr: summary.test_psnr,
                    test_mse: summary.test_mse,
                });
            } else {
                for &b in &plan.budgets {
                    if let Some(r) = at_budget(&summary.records, b) {
                        table.cells.push(Cell::of(&name, b, r));
                    }
                }
            }
            last = Some((output, summary));
        }
        let (output, summary) = last.expect("at least one budget");
        table.runs.push(Run {
            config: name,
            asset: output.display().to_string(),
            asset_bytes: summary.asset_bytes,
            final_psnr: summary.test_psnr,
            records: if per_budget {
                auto_points
            } else {
                summary.records
            },
        });
    }
    let text = serde_json::to_string_pretty(&table)?;
    write_atomic(plan.json, text.as_bytes())
        .with_context(|| format!("cannot write {}", plan.json.display()))?;
    let png = plot(&table).context("drawing the plot")?;
    write_atomic(plan.plot, &png)
        .with_context(|| format!("cannot write {}", plan.plot.display()))?;
    Ok(table)
}

/// The table as Markdown: one row per configuration, PSNR / MSE per budget.
pub fn markdown(t: &Table) -> String {
    let mut s = String::from("| configuration |");
    for b in &t.budgets {
        s += &format!(" {b} s: PSNR dB / MSE |");
    }
    s += " asset bytes | asset PSNR (f16, runtime) |\n| --- |";
    s += &" ---: |".repeat(t.budgets.len() + 2);
    s.push('\n');
    for run in &t.runs {
        s += &format!("| {} |", run.config);
        for b in &t.budgets {
            match t
                .cells
                .iter()
                .find(|c| c.config == run.config && c.budget == *b)
            {
                Some(c) => s += &format!(" {:.2} / {:.1} |", c.psnr, c.mse),
                None => s += " - |",
            }
        }
        s += &format!(" {} | {:.2} |\n", run.asset_bytes, run.final_psnr);
    }
    s
}

/// The bundled font the plot's text is drawn with (DejaVu Sans; licence beside it), so
/// plotting needs no system fonts.
static FONT: &[u8] = include_bytes!("../../assets/DejaVuSans.ttf");

/// PSNR against seconds (log axis), one curve per configuration, a dot per budget; PNG bytes.
pub fn plot(t: &Table) -> Result<Vec<u8>> {
    use plotters::prelude::*;
    static REGISTERED: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    let font_ok = *REGISTERED.get_or_init(|| {
        plotters::style::register_font("sans-serif", FontStyle::Normal, FONT).is_ok()
    });
    if !font_ok {
        bail!("the bundled DejaVu Sans font could not be loaded");
    }
    let (w, h) = (1000u32, 640u32);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    let points: Vec<(f64, f64)> = t
        .runs
        .iter()
        .flat_map(|r| r.records.iter().map(|x| (x.seconds, x.test_psnr)))
        .filter(|(s, p)| s.is_finite() && p.is_finite())
        .collect();
    let x_hi = t.budgets.iter().copied().fold(1.0, f64::max) * 1.15;
    let x_lo = points
        .iter()
        .map(|p| p.0)
        .fold(x_hi, f64::min)
        .clamp(0.1, x_hi / 10.0)
        * 0.8;
    let (y_lo, y_hi) = points
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
            (a.min(p.1), b.max(p.1))
        });
    let (y_lo, y_hi) = if y_lo.is_finite() {
        (y_lo.floor() - 1.0, y_hi.ceil() + 1.0)
    } else {
        (0.0, 40.0)
    };
    let err = |e: &dyn std::fmt::Display| anyhow::anyhow!("plot: {e}");
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| err(&e))?;
        let mut chart = ChartBuilder::on(&root)
            .caption(
                match &t.mesh {
                    Some(m) => format!(
                        "held-out PSNR against bake seconds: {} (proxy {m})",
                        t.capture
                    ),
                    None => format!("held-out PSNR against bake seconds: {}", t.capture),
                },
                ("sans-serif", 20),
            )
            .margin(15)
            .x_label_area_size(45)
            .y_label_area_size(55)
            .build_cartesian_2d((x_lo..x_hi).log_scale(), y_lo..y_hi)
            .map_err(|e| err(&e))?;
        chart
            .configure_mesh()
            .x_desc("bake seconds (initialisation included, evaluation excluded; log scale)")
            .y_desc("held-out PSNR (dB, full frame on white)")
            .label_style(("sans-serif", 14))
            .draw()
            .map_err(|e| err(&e))?;
        const COLOURS: [RGBColor; 9] = [
            RGBColor(31, 119, 180),
            RGBColor(255, 127, 14),
            RGBColor(44, 160, 44),
            RGBColor(214, 39, 40),
            RGBColor(148, 103, 189),
            RGBColor(140, 86, 75),
            RGBColor(227, 119, 194),
            RGBColor(127, 127, 127),
            RGBColor(23, 190, 207),
        ];
        for (i, run) in t.runs.iter().enumerate() {
            let colour = COLOURS[i % COLOURS.len()];
            let curve: Vec<(f64, f64)> = run
                .records
                .iter()
                .map(|r| (r.seconds.max(x_lo), r.test_psnr))
                .filter(|(_, p)| p.is_finite())
                .collect();
            chart
                .draw_series(LineSeries::new(curve.clone(), colour.stroke_width(2)))
                .map_err(|e| err(&e))?
                .label(run.config.clone())
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2))
                });
            // A single evaluation (e.g. the classical texture) shows as a level line.
            if curve.len() == 1 {
                let y = curve[0].1;
                chart
                    .draw_series(LineSeries::new(
                        vec![(curve[0].0, y), (x_hi, y)],
                        colour.stroke_width(1),
                    ))
                    .map_err(|e| err(&e))?;
            }
            let dots = t
                .cells
                .iter()
                .filter(|c| c.config == run.config && c.psnr.is_finite())
                .map(|c| Circle::new((c.seconds.max(x_lo), c.psnr), 4, colour.filled()));
            chart.draw_series(dots).map_err(|e| err(&e))?;
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::LowerRight)
            .label_font(("sans-serif", 14))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()
            .map_err(|e| err(&e))?;
        root.present().map_err(|e| err(&e))?;
    }
    let mut png = Vec::new();
    {
        use image::ImageEncoder;
        image::codecs::png::PngEncoder::new(&mut png)
            .write_image(&buf, w, h, image::ExtendedColorType::Rgb8)
            .context("encoding the plot")?;
    }
    Ok(png)
}

/// Default output paths under `out`.
pub fn default_paths(out: &Path) -> (PathBuf, PathBuf) {
    (out.join("bench_bake.json"), out.join("bench_bake.png"))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(step: u64, seconds: f64, psnr: f64) -> Record {
        Record {
            step,
            seconds,
            train_loss: 0.1,
            test_psnr: psnr,
            test_mse: 100.0 / seconds,
        }
    }

    #[test]
    fn budget_takes_the_first_evaluation_at_or_after_it_else_the_last() {
        let r = [
            rec(10, 30.02, 25.0),
            rec(20, 60.01, 28.0),
            rec(25, 70.0, 28.5),
        ];
        assert_eq!(at_budget(&r, 30.0).unwrap().step, 10);
        assert_eq!(at_budget(&r, 60.0).unwrap().step, 20);
        assert_eq!(at_budget(&r, 600.0).unwrap().step, 25);
        assert!(at_budget(&[], 60.0).is_none());
    }

    #[test]
    fn unknown_configurations_and_budgets_are_refused() {
        assert!(config("turbo").is_err());
        for name in ["fast", "balanced", "quality", "paper"]
            .iter()
            .chain(&BASELINES)
        {
            config(name).unwrap();
        }
        assert_eq!(config("classical").unwrap().steps, 0);
        assert!(!config("unet-nosh").unwrap().sh);
        assert_eq!(config("unet-1level").unwrap().levels, 1);
        let dir = tempfile_dir();
        let plan = Plan {
            capture: Path::new("nowhere"),
            configs: vec!["fast".into()],
            budgets: vec![60.0, -1.0],
            mesh: None,
            out: &dir,
            json: &dir.join("t.json"),
            plot: &dir.join("t.png"),
            threads: 1,
        };
        assert!(run(&plan).unwrap_err().to_string().contains("--budgets"));
    }

    fn tempfile_dir() -> PathBuf {
        std::env::temp_dir().join(format!("dnr-bench-bake-{}", std::process::id()))
    }

    #[test]
    fn plot_and_markdown_show_every_configuration() {
        let runs = vec![
            Run {
                config: "classical".into(),
                asset: "a.glb".into(),
                asset_bytes: 10,
                final_psnr: 24.0,
                records: vec![rec(0, 1.5, 24.0)],
            },
            Run {
                config: "balanced".into(),
                asset: "b.glb".into(),
                asset_bytes: 20,
                final_psnr: 33.0,
                records: (1..=20)
                    .map(|i| rec(i * 100, 30.0 * i as f64, 25.0 + (i as f64).ln() * 3.0))
                    .collect(),
            },
        ];
        let mut cells = Vec::new();
        for run in &runs {
            for b in [60.0, 180.0, 600.0] {
                let r = at_budget(&run.records, b).unwrap();
                cells.push(Cell::of(&run.config, b, r));
            }
        }
        let t = Table {
            capture: "cap".into(),
            mesh: None,
            budgets: vec![60.0, 180.0, 600.0],
            cells,
            runs,
        };
        let md = markdown(&t);
        assert_eq!(md.lines().count(), 4, "{md}");
        assert!(
            md.contains("| classical | 24.00 /") && md.contains("| balanced |"),
            "{md}"
        );
        let png = plot(&t).unwrap();
        let img = image::load_from_memory(&png).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (1000, 640));
        // Both curves' colours are on the picture.
        let has = |c: [u8; 3]| img.pixels().any(|p| p.0 == c);
        assert!(has([31, 119, 180]) && has([255, 127, 14]));
    }
}
