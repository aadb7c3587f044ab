//! The set's summary (mean and worst case over the captures) and the Markdown tables.

use serde::Serialize;

use super::{Cell, Suite, Table};

/// One configuration at one budget over the whole set.
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Summary {
    /// Configuration name.
    pub config: String,
    /// Budget in seconds.
    pub budget: f64,
    /// Captures measured.
    pub captures: usize,
    /// Mean held-out PSNR (dB).
    pub mean_psnr: f64,
    /// Mean held-out SSIM.
    pub mean_ssim: f64,
    /// Mean held-out object MSE.
    pub mean_mse: f64,
    /// Lowest held-out PSNR and the capture it was measured on.
    pub worst_psnr: f64,
    /// The capture of the worst PSNR.
    pub worst_capture: String,
    /// Mean over the captures of the PSNR minus the PyTorch reference's at the same budget
    /// (absent without the reference).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mean_db_over_pytorch: Option<f64>,
    /// The smallest such difference.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub worst_db_over_pytorch: Option<f64>,
}

/// SSIM to 4 places, `-` where it was not measured (NaN; runs joined with `--from-json` may
/// lack it).
fn ssim(v: f64) -> String {
    if v.is_nan() {
        "-".into()
    } else {
        format!("{v:.4}")
    }
}

fn cell<'a>(t: &'a Table, config: &str, budget: f64) -> Option<&'a Cell> {
    t.cells
        .iter()
        .find(|c| c.config == config && c.budget == budget)
}

/// Configurations in the order they first appear.
fn configs(tables: &[Table]) -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    for c in tables.iter().flat_map(|t| &t.cells) {
        if !out.contains(&c.config) {
            out.push(c.config.clone());
        }
    }
    out
}

/// Mean and worst case per configuration and budget.
pub fn summarise(tables: &[Table]) -> Vec<Summary> {
    let budgets = tables
        .first()
        .map(|t| t.budgets.clone())
        .unwrap_or_default();
    let mut out = Vec::new();
    for config in configs(tables) {
        for &b in &budgets {
            let cells: Vec<(&Table, &Cell)> = tables
                .iter()
                .filter_map(|t| cell(t, &config, b).map(|c| (t, c)))
                .collect();
            if cells.is_empty() {
                continue;
            }
            let n = cells.len() as f64;
            let mean = |f: &dyn Fn(&Cell) -> f64| cells.iter().map(|(_, c)| f(c)).sum::<f64>() / n;
            let worst = cells
                .iter()
                .min_by(|a, b| a.1.psnr.total_cmp(&b.1.psnr))
                .expect("non-empty");
            let diffs: Vec<f64> = cells
                .iter()
                .filter_map(|(t, c)| cell(t, "pytorch", b).map(|r| c.psnr - r.psnr))
                .collect();
            let has_ref = config != "pytorch" && diffs.len() == cells.len();
            out.push(Summary {
                config: config.clone(),
                budget: b,
                captures: cells.len(),
                mean_psnr: mean(&|c| c.psnr),
                mean_ssim: mean(&|c| c.ssim),
                mean_mse: mean(&|c| c.mse),
                worst_psnr: worst.1.psnr,
                worst_capture: worst.0.name.clone(),
                mean_db_over_pytorch: has_ref.then(|| diffs.iter().sum::<f64>() / n),
                worst_db_over_pytorch: has_ref
                    .then(|| diffs.iter().copied().fold(f64::INFINITY, f64::min)),
            });
        }
    }
    out
}

/// The per-capture table and the summary as Markdown.
pub fn markdown(s: &Suite) -> String {
    let budgets = s
        .tables
        .first()
        .map(|t| t.budgets.clone())
        .unwrap_or_default();
    let mut md = String::from("| capture | configuration |");
    for b in &budgets {
        md += &format!(" {b} s: PSNR dB / SSIM / object MSE |");
    }
    md += "\n| --- | --- |";
    md += &" ---: |".repeat(budgets.len());
    md.push('\n');
    for t in &s.tables {
        for config in configs(std::slice::from_ref(t)) {
            md += &format!("| {} | {config} |", t.name);
            for &b in &budgets {
                match cell(t, &config, b) {
                    Some(c) => md += &format!(" {:.2} / {} / {:.1} |", c.psnr, ssim(c.ssim), c.mse),
                    None => md += " - |",
                }
            }
            md.push('\n');
        }
    }
    md += "\n| configuration | budget s | captures | mean PSNR dB | mean SSIM | mean object MSE | worst PSNR dB (capture) | mean / worst dB over PyTorch |\n";
    md += "| --- | ---: | ---: | ---: | ---: | ---: | --- | --- |\n";
    for r in &s.summary {
        let vs = match (r.mean_db_over_pytorch, r.worst_db_over_pytorch) {
            (Some(m), Some(w)) => format!("{m:+.2} / {w:+.2}"),
            _ => "-".into(),
        };
        md += &format!(
            "| {} | {} | {} | {:.2} | {} | {:.1} | {:.2} ({}) | {vs} |\n",
            r.config,
            r.budget,
            r.captures,
            r.mean_psnr,
            ssim(r.mean_ssim),
            r.mean_mse,
            r.worst_psnr,
            r.worst_capture
        );
    }
    md
}

#[cfg(test)]
mod tests {
    use super::*;

    fn c(config: &str, budget: f64, psnr: f64) -> Cell {
        Cell {
            config: config.into(),
            budget,
            seconds: budget,
            steps: 10,
            psnr,
            ssim: 0.9,
            mse: 50.0,
            asset_bytes: 1,
            parts: None,
            storages: Vec::new(),
        }
    }

    fn t(name: &str, cells: Vec<Cell>) -> Table {
        Table {
            capture: name.into(),
            name: name.into(),
            mesh: None,
            budgets: vec![60.0, 300.0],
            cells,
            curves: Vec::new(),
        }
    }

    #[test]
    fn mean_worst_and_the_margin_over_the_reference() {
        let tables = vec![
            t(
                "a",
                vec![
                    c("auto", 60.0, 30.0),
                    c("auto", 300.0, 33.0),
                    c("pytorch", 300.0, 31.0),
                ],
            ),
            t(
                "b",
                vec![
                    c("auto", 60.0, 26.0),
                    c("auto", 300.0, 29.0),
                    c("pytorch", 300.0, 28.0),
                ],
            ),
        ];
        let s = summarise(&tables);
        let auto300 = s
            .iter()
            .find(|r| r.config == "auto" && r.budget == 300.0)
            .unwrap();
        assert_eq!(auto300.captures, 2);
        assert!((auto300.mean_psnr - 31.0).abs() < 1e-12);
        assert_eq!(auto300.worst_capture, "b");
        assert!((auto300.mean_db_over_pytorch.unwrap() - 1.5).abs() < 1e-12);
        assert!((auto300.worst_db_over_pytorch.unwrap() - 1.0).abs() < 1e-12);
        // No reference at 60 s: no margin.
        let auto60 = s
            .iter()
            .find(|r| r.config == "auto" && r.budget == 60.0)
            .unwrap();
        assert!(auto60.mean_db_over_pytorch.is_none());
        let md = markdown(&Suite { tables, summary: s });
        assert!(
            md.contains("| a | auto | 30.00 / 0.9000 / 50.0 | 33.00 /"),
            "{md}"
        );
        assert!(md.contains("| auto | 300 | 2 | 31.00 |"), "{md}");
        assert!(md.contains("+1.50 / +1.00"), "{md}");
    }
}
