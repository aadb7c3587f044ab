//! `dnr validate FILE [--json]`.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use dnr_format::validate::{validate_file, Severity};
use dnr_format::Limits;

/// Arguments of `dnr validate`.
#[derive(clap::Args)]
pub struct Args {
    /// The `.glb` or `.gltf` file.
    pub file: PathBuf,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
    /// Raise (or lower) a reader limit, NAME=VALUE; repeatable (e.g. max_texture_side=32768).
    /// Names: max_file_bytes, max_json_bytes, max_buffer_bytes, max_texture_side, max_levels,
    /// max_channels, max_total_texel_values, max_weight_elements, max_tensors, max_tensor_rank.
    #[arg(long = "limit", value_name = "NAME=VALUE")]
    pub limits: Vec<String>,
}

/// The default limits with the `--limit` flags applied.
pub(crate) fn limits_from(specs: &[String]) -> anyhow::Result<Limits> {
    let mut l = Limits::default();
    for s in specs {
        l.set(s).map_err(|e| anyhow::anyhow!("--limit: {e}"))?;
    }
    Ok(l)
}

/// Validates, prints the report, exits 1 if it has errors.
pub fn run(args: &Args) -> anyhow::Result<ExitCode> {
    let report = validate_file(&args.file, &limits_from(&args.limits)?)
        .with_context(|| format!("cannot validate {}", args.file.display()))?;
    let (errors, warnings, infos) = (
        report.count(Severity::Error),
        report.count(Severity::Warning),
        report.count(Severity::Info),
    );
    if args.json {
        let out = serde_json::json!({
            "file": args.file.display().to_string(),
            "valid": errors == 0,
            "errors": errors,
            "warnings": warnings,
            "infos": infos,
            "issues": report.issues,
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        for i in &report.issues {
            let sev = match i.severity {
                Severity::Error => "error",
                Severity::Warning => "warning",
                Severity::Info => "info",
            };
            let at = if i.pointer.is_empty() {
                "(file)"
            } else {
                &i.pointer
            };
            println!("{sev} {} at {at}: {}", i.code, i.message);
        }
        println!(
            "{}: {} ({errors} errors, {warnings} warnings, {infos} infos)",
            args.file.display(),
            if errors == 0 { "valid" } else { "INVALID" }
        );
    }
    Ok(if errors == 0 {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}
