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
}

/// Validates, prints the report, exits 1 if it has errors.
pub fn run(args: &Args) -> anyhow::Result<ExitCode> {
    let report = validate_file(&args.file, &Limits::default())
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
