//! The Markdown tables of `dnr bench train` and `dnr bench render` (`--markdown`): what
//! `docs/benchmarks.md` shows for each, built from one run.

use anyhow::{Context, Result};
use serde_json::Value;

use crate::markdown::{min_median, Align, Provenance, Table};

/// Section name of the training tables in a page.
pub const TRAIN_SECTION: &str = "dnr bench train";

/// Section name of the render tables of the asset named `asset`.
pub fn render_section(asset: &str) -> String {
    format!("dnr bench render {asset}")
}

/// `widths` as the U-Net's name: the two benchmarked ones by name, others by their widths.
fn unet_name(widths: &[u64]) -> String {
    let cpu: Vec<u64> = dnr_bake::bench::CPU_WIDTHS
        .iter()
        .map(|&w| w as u64)
        .collect();
    let paper: Vec<u64> = dnr_bake::bench::PAPER_WIDTHS
        .iter()
        .map(|&w| w as u64)
        .collect();
    if widths == cpu {
        "CPU-sized".into()
    } else if widths == paper {
        "paper".into()
    } else {
        format!("{widths:?}")
    }
}

/// Field `key` of `v` as a number, or an error naming where it is missing.
fn num(v: &Value, key: &str, at: &str) -> Result<f64> {
    v[key]
        .as_f64()
        .with_context(|| format!("{at}.{key}: expected a number"))
}

fn widths(v: &Value, at: &str) -> Result<Vec<u64>> {
    v["widths"]
        .as_array()
        .and_then(|a| a.iter().map(Value::as_u64).collect())
        .with_context(|| format!("{at}.widths: expected an array of whole numbers"))
}

/// The training tables of a `dnr bench train` run, from its JSON (what `--json` writes):
/// the comparison with PyTorch, the pairs, every row against the peaks, the step's phases.
pub fn train(run: &Value) -> Result<String> {
    let mut out = String::new();
    match serde_json::from_value::<Provenance>(run["provenance"].clone()) {
        Ok(p) => out.push_str(&p.line()),
        Err(_) => out.push_str("Date, commit and machine: not recorded with this run."),
    }
    let peak = num(run, "sgemmPeakGflops", "run")?;
    let fma = num(run, "fmaPeakGflops", "run")?;
    out.push_str(&format!(
        " {} worker threads, {} kernels; sgemm peak {peak:.1} GFLOP/s and FMA peak {fma:.1} GFLOP/s measured in the same run.\n\n",
        run["threads"].as_u64().context("run.threads: expected a whole number")?,
        run["simd"].as_str().unwrap_or("unknown"),
    ));

    let torch = &run["torch"];
    if let Some(cmp) = torch["comparisons"].as_array() {
        out.push_str(&format!(
            "Against PyTorch {} (same run, same threads; speed-up = PyTorch ms / dnr ms):\n\n",
            torch["version"].as_str().unwrap_or("(version unknown)")
        ));
        let mut t = Table::new(&[
            ("kind", Align::Left),
            ("U-Net", Align::Left),
            ("size", Align::Right),
            ("dnr ms (min / median)", Align::Right),
            ("PyTorch ms (min / median)", Align::Right),
            ("speed-up (min / median)", Align::Right),
        ]);
        for (i, c) in cmp.iter().enumerate() {
            let at = format!("torch.comparisons[{i}]");
            t.row(vec![
                c["kind"].as_str().unwrap_or("?").to_string(),
                unet_name(&widths(c, &at)?),
                format!("{}", c["size"].as_u64().unwrap_or(0)),
                min_median(num(c, "dnrMsMin", &at)?, num(c, "dnrMsMedian", &at)?, 1),
                min_median(num(c, "torchMsMin", &at)?, num(c, "torchMsMedian", &at)?, 1),
                format!(
                    "{:.2}x / {:.2}x",
                    num(c, "speedupMin", &at)?,
                    num(c, "speedup", &at)?
                ),
            ]);
        }
        out.push_str(&t.render());
    } else {
        out.push_str("PyTorch was not timed in this run (no `--torch`).\n");
    }

    if let Some(pairs) = torch["pairs"]["rows"].as_array() {
        out.push_str(
            "\nPairs: the CPU-sized step, ours then PyTorch's seconds apart, so both see the same load:\n\n",
        );
        let mut t = Table::new(&[
            ("pair", Align::Right),
            ("size", Align::Right),
            ("dnr ms (min / median)", Align::Right),
            ("PyTorch ms (min / median)", Align::Right),
            ("speed-up (min / median)", Align::Right),
        ]);
        for (i, p) in pairs.iter().enumerate() {
            let at = format!("torch.pairs.rows[{i}]");
            t.row(vec![
                format!("{}", p["pair"].as_u64().unwrap_or(0)),
                format!("{}", p["size"].as_u64().unwrap_or(0)),
                min_median(num(p, "dnrMsMin", &at)?, num(p, "dnrMsMedian", &at)?, 1),
                min_median(num(p, "torchMsMin", &at)?, num(p, "torchMsMedian", &at)?, 1),
                format!(
                    "{:.2}x / {:.2}x",
                    num(p, "speedupMin", &at)?,
                    num(p, "speedup", &at)?
                ),
            ]);
        }
        out.push_str(&t.render());
        let mut m = Table::new(&[
            ("size", Align::Right),
            (
                "median speed-up over the pairs (min / median)",
                Align::Right,
            ),
        ]);
        for (i, p) in torch["pairs"]["medians"]
            .as_array()
            .into_iter()
            .flatten()
            .enumerate()
        {
            let at = format!("torch.pairs.medians[{i}]");
            m.row(vec![
                format!("{}", p["size"].as_u64().unwrap_or(0)),
                format!(
                    "{:.2}x / {:.2}x",
                    num(p, "speedupMin", &at)?,
                    num(p, "speedup", &at)?
                ),
            ]);
        }
        out.push('\n');
        out.push_str(&m.render());
    }

    out.push_str(
        "\nEvery row against the peaks (GFLOP/s from the convolution FLOPs and the minimum time):\n\n",
    );
    let mut t = Table::new(&[
        ("kind", Align::Left),
        ("U-Net", Align::Left),
        ("size", Align::Right),
        ("ms (min / median)", Align::Right),
        ("GFLOP", Align::Right),
        ("GFLOP/s", Align::Right),
        ("of sgemm peak", Align::Right),
        ("of FMA peak", Align::Right),
    ]);
    let rows = run["rows"]
        .as_array()
        .context("run.rows: expected an array")?;
    let mut phases = Table::new(&[
        ("U-Net", Align::Left),
        ("size", Align::Right),
        ("features", Align::Right),
        ("forward", Align::Right),
        ("backward", Align::Right),
        ("feature grads", Align::Right),
        ("updates", Align::Right),
    ]);
    for (i, r) in rows.iter().enumerate() {
        let at = format!("rows[{i}]");
        let gflops = num(r, "gflop", &at)? / num(r, "msMin", &at)? * 1e3;
        let name = unet_name(&widths(r, &at)?);
        let size = format!("{}", r["size"].as_u64().unwrap_or(0));
        t.row(vec![
            r["kind"].as_str().unwrap_or("?").to_string(),
            name.clone(),
            size.clone(),
            min_median(num(r, "msMin", &at)?, num(r, "msMedian", &at)?, 1),
            format!("{:.3}", num(r, "gflop", &at)?),
            format!("{gflops:.1}"),
            format!("{:.0}%", 100.0 * gflops / peak),
            format!("{:.0}%", 100.0 * gflops / fma),
        ]);
        let p = &r["phasesMs"];
        if p.is_object() {
            let at = format!("{at}.phasesMs");
            let mut cells = vec![name, size];
            for key in [
                "features",
                "forward",
                "backward",
                "feature_grads",
                "updates",
            ] {
                cells.push(format!("{:.2}", num(p, key, &at)?));
            }
            phases.row(cells);
        }
    }
    out.push_str(&t.render());
    if !phases.is_empty() {
        out.push_str("\nThe whole step by phase (mean ms per timed step):\n\n");
        out.push_str(&phases.render());
    }
    Ok(out)
}

/// What a `dnr bench render` run measured, besides its tables.
pub struct RenderRun<'a> {
    /// The asset's file name.
    pub asset: &'a str,
    /// Its size in bytes.
    pub bytes: u64,
    /// The architecture of each of its renderers.
    pub architectures: &'a [&'a str],
    /// Timed frames per size.
    pub reps: usize,
    /// Worker threads.
    pub threads: usize,
}

/// The render tables: ms per frame, and (when there are references) the error against each.
pub fn render(p: &Provenance, run: &RenderRun<'_>, times: &Table, errors: &Table) -> String {
    let mut out = format!(
        "{} {} worker threads. `{}`: {} bytes, renderers: {}; minimum and median of {} frames per size, from a camera 3.6 units from the origin.\n\n",
        p.line(),
        run.threads,
        run.asset,
        run.bytes,
        if run.architectures.is_empty() {
            "none".to_string()
        } else {
            run.architectures.join(", ")
        },
        run.reps
    );
    out.push_str(&times.render());
    if !errors.is_empty() {
        out.push_str(
            "\nThe asset's frames against each reference's, from four cameras around the object:\n\n",
        );
        out.push_str(&errors.render());
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A run as `dnr bench train --json` writes it, cut to one row of each kind.
    fn run() -> Value {
        serde_json::json!({
            "provenance": {"date": "2026-12-03 10:00 UTC", "commit": "abc1234",
                           "machine": "Test CPU, 2 logical CPUs, 24 GiB", "load": 0.25},
            "sgemmPeakGflops": 200.0, "fmaPeakGflops": 250.0, "threads": 2, "simd": "Avx512",
            "rows": [
                {"kind": "step", "widths": [16, 32, 64, 128, 128], "size": 256, "msMin": 30.0,
                 "msMedian": 35.0, "gflop": 2.5,
                 "phasesMs": {"features": 3.0, "forward": 9.0, "backward": 16.0,
                              "feature_grads": 0.5, "updates": 4.0}},
                {"kind": "infer", "widths": [64, 128, 256, 512, 512], "size": 512,
                 "msMin": 250.0, "msMedian": 300.0, "gflop": 45.9, "phasesMs": null}
            ],
            "torch": {"version": "2.15.0", "comparisons": [
                {"kind": "step", "widths": [16, 32, 64, 128, 128], "size": 256,
                 "dnrMsMin": 30.0, "dnrMsMedian": 35.0, "torchMsMin": 99.0,
                 "torchMsMedian": 105.0, "speedupMin": 3.3, "speedup": 3.0}],
              "pairs": {"rows": [{"pair": 0, "size": 256, "dnrMsMin": 29.0, "dnrMsMedian": 31.0,
                                  "torchMsMin": 90.0, "torchMsMedian": 93.0,
                                  "speedupMin": 3.1, "speedup": 3.0}],
                        "medians": [{"size": 256, "speedupMin": 3.1, "speedup": 3.0}]}}
        })
    }

    #[test]
    fn train_tables_carry_every_figure_of_the_run() {
        let md = train(&run()).unwrap();
        assert!(md.starts_with(
            "Measured 2026-12-03 10:00 UTC at commit `abc1234` on Test CPU, 2 logical CPUs, 24 GiB; load average 0.25 at the start. 2 worker threads, Avx512 kernels; sgemm peak 200.0 GFLOP/s and FMA peak 250.0 GFLOP/s"
        ), "{md}");
        assert!(md.contains("Against PyTorch 2.15.0"));
        assert!(
            md.contains("| step | CPU-sized | 256 | 30.0 / 35.0 | 99.0 / 105.0 | 3.30x / 3.00x |")
        );
        assert!(md.contains("| 0 | 256 | 29.0 / 31.0 | 90.0 / 93.0 | 3.10x / 3.00x |"));
        assert!(md.contains("| 256 | 3.10x / 3.00x |"));
        // 2.5 GFLOP in 30 ms: 83.3 GFLOP/s, 42% of 200, 33% of 250.
        assert!(md.contains("| step | CPU-sized | 256 | 30.0 / 35.0 | 2.500 | 83.3 | 42% | 33% |"));
        assert!(md.contains("| infer | paper | 512 | 250.0 / 300.0 | 45.900 | 183.6 | 92% | 73% |"));
        assert!(md.contains("| CPU-sized | 256 | 3.00 | 9.00 | 16.00 | 0.50 | 4.00 |"));
    }

    #[test]
    fn train_tables_of_a_run_without_pytorch_or_provenance() {
        let mut r = run();
        let o = r.as_object_mut().unwrap();
        o.remove("torch");
        o.remove("provenance");
        let md = train(&r).unwrap();
        assert!(md.starts_with("Date, commit and machine: not recorded with this run."));
        assert!(md.contains("PyTorch was not timed in this run"));
        assert!(!md.contains("Pairs"));
    }

    #[test]
    fn a_run_missing_a_figure_is_an_error_naming_it() {
        let mut r = run();
        r["rows"][1]
            .as_object_mut()
            .unwrap()
            .remove("msMedian")
            .unwrap();
        let e = train(&r).unwrap_err().to_string();
        assert_eq!(e, "rows[1].msMedian: expected a number");
    }

    #[test]
    fn render_tables() {
        let p = Provenance {
            date: "d".into(),
            commit: "c".into(),
            machine: "m".into(),
            load: None,
        };
        let mut times = Table::new(&[("size", Align::Right), ("ms", Align::Right)]);
        times.row(vec!["256".into(), "9.6".into()]);
        let errors = Table::new(&[("reference", Align::Left)]);
        let run = RenderRun {
            asset: "a.glb",
            bytes: 10,
            architectures: &["unet"],
            reps: 5,
            threads: 2,
        };
        let md = render(&p, &run, &times, &errors);
        assert_eq!(
            md,
            "Measured d at commit `c` on m. 2 worker threads. `a.glb`: 10 bytes, renderers: unet; minimum and median of 5 frames per size, from a camera 3.6 units from the origin.\n\n| size | ms |\n| ---: | ---: |\n| 256 | 9.6 |\n"
        );
    }
}
