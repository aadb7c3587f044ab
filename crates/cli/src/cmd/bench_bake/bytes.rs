//! The bytes axis: each bake's asset bytes by part (the baker's own
//! [`dnr_bake::storage::part_bytes`], as its report counts them) and, per storage of the
//! same trained state, bytes and held-out PSNR (the report's `storage.variants`), as a
//! Markdown section.

use std::path::Path;

use anyhow::{Context, Result};
use dnr_bake::storage::{part_bytes, PartBytes};
use serde::Serialize;

use super::{Cell, Suite};

/// One storage of a bake's trained state.
#[derive(Clone, Debug, PartialEq, Serialize, serde::Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct StorageCell {
    /// `f16`, `q8`, `q4` or `chosen` (the written asset).
    pub name: String,
    /// Asset bytes.
    pub bytes: u64,
    /// Held-out PSNR (dB).
    #[serde(deserialize_with = "dnr_bake::train::f64_or_nan")]
    pub psnr: f64,
}

/// Bytes by part of a written asset.
pub fn read_parts(path: &Path) -> Result<PartBytes> {
    let c = dnr_format::Container::read(path, &dnr_format::Limits::unlimited())
        .with_context(|| format!("reading {}", path.display()))?;
    part_bytes(&c).with_context(|| format!("counting the bytes of {}", path.display()))
}

/// The storages a bake report lists (`storage.variants`: quantised bakes measure f16, q8,
/// q4 and the chosen mix); for an f16 bake, which lists none, the written asset as `f16`.
pub fn storages(report: &serde_json::Value, cell: &Cell) -> Vec<StorageCell> {
    let variants = report
        .pointer("/storage/variants")
        .and_then(|v| v.as_array())
        .map(|vs| {
            vs.iter()
                .filter_map(|v| {
                    Some(StorageCell {
                        name: v.get("name")?.as_str()?.to_string(),
                        bytes: v.pointer("/bytes/total")?.as_u64()?,
                        psnr: v.get("testPsnr")?.as_f64().unwrap_or(f64::NAN),
                    })
                })
                .collect::<Vec<_>>()
        })
        .unwrap_or_default();
    if variants.is_empty() {
        vec![StorageCell {
            name: "f16".into(),
            bytes: cell.asset_bytes,
            psnr: cell.psnr,
        }]
    } else {
        variants
    }
}

/// The bytes section: per bake its parts, then per storage its bytes and held-out PSNR.
pub fn markdown(s: &Suite) -> String {
    let mut md = String::from(
        "| capture | configuration | budget s | asset bytes | levels | weights | fallback PNG | mesh |\n\
         | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |\n",
    );
    for t in &s.tables {
        for c in &t.cells {
            if let Some(p) = &c.parts {
                md += &format!(
                    "| {} | {} | {} | {} | {} | {} | {} | {} |\n",
                    t.name,
                    c.config,
                    c.budget,
                    p.total,
                    p.level_total(),
                    p.weights,
                    p.fallback,
                    p.mesh
                );
            }
        }
    }
    md += "\n| capture | configuration | budget s | storage | bytes | held-out PSNR dB |\n";
    md += "| --- | --- | ---: | --- | ---: | ---: |\n";
    for t in &s.tables {
        for c in &t.cells {
            for v in &c.storages {
                md += &format!(
                    "| {} | {} | {} | {} | {} | {:.2} |\n",
                    t.name, c.config, c.budget, v.name, v.bytes, v.psnr
                );
            }
        }
    }
    md
}

#[cfg(test)]
mod tests {
    use super::super::Table;
    use super::*;

    pub(crate) fn cell() -> Cell {
        Cell {
            config: "fast".into(),
            budget: 60.0,
            seconds: 60.0,
            steps: 10,
            psnr: 30.0,
            ssim: 0.9,
            mse: 5.0,
            asset_bytes: 1000,
            parts: Some(PartBytes {
                levels: vec![600, 150],
                weights: 100,
                fallback: 80,
                mesh: 40,
                json: 30,
                total: 1000,
            }),
            storages: Vec::new(),
        }
    }

    #[test]
    fn storages_come_from_the_report_or_the_asset() {
        let c = cell();
        let report = serde_json::json!({"storage": {"variants": [
            {"name": "f16", "bytes": {"total": 1000}, "testPsnr": 30.1},
            {"name": "q4", "bytes": {"total": 300}, "testPsnr": 29.5},
        ]}});
        let s = storages(&report, &c);
        assert_eq!(s.len(), 2);
        assert_eq!(
            (s[1].name.as_str(), s[1].bytes, s[1].psnr),
            ("q4", 300, 29.5)
        );
        let plain = storages(&serde_json::json!({"storage": {"variants": []}}), &c);
        assert_eq!(
            plain,
            [StorageCell {
                name: "f16".into(),
                bytes: 1000,
                psnr: 30.0
            }]
        );
    }

    #[test]
    fn markdown_lists_parts_and_storages() {
        let mut c = cell();
        c.storages = vec![StorageCell {
            name: "q8".into(),
            bytes: 500,
            psnr: 29.87,
        }];
        let s = Suite {
            tables: vec![Table {
                capture: "a".into(),
                name: "a".into(),
                mesh: None,
                budgets: vec![60.0],
                cells: vec![c],
                curves: Vec::new(),
            }],
            summary: Vec::new(),
        };
        let md = markdown(&s);
        assert!(
            md.contains("| a | fast | 60 | 1000 | 750 | 100 | 80 | 40 |"),
            "{md}"
        );
        assert!(md.contains("| a | fast | 60 | q8 | 500 | 29.87 |"), "{md}");
    }
}
