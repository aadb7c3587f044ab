//! `dnr`: validate, inspect, render, evaluate and benchmark `EXT_deferred_neural_rendering`
//! assets.
//!
//! The top of the stack: it may use every crate of the workspace (`dnr-format`,
//! `dnr-runtime`, `dnr-bake`), and no crate may depend on it. Errors are `anyhow` here, typed
//! in the libraries.
#![forbid(unsafe_code)]

mod cmd;
mod markdown;

/// Large buffers (texture levels, optimiser moments, feature planes) on cache-line
/// boundaries: see `dnr_runtime::alloc`.
#[global_allocator]
static ALLOC: dnr_runtime::alloc::LineAligned = dnr_runtime::alloc::LineAligned;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// Tools for EXT_deferred_neural_rendering glTF assets.
#[derive(Parser)]
#[command(name = "dnr", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Check an asset against the format; exit 0 when it has no errors, 1 when it has.
    Validate(cmd::validate::Args),
    /// Summarise an asset: textures, renderers, parameter counts, bytes by part.
    Inspect(cmd::inspect::Args),
    // --- render / eval (renderer engineer) ---
    /// Render an asset with the CPU runtime: the views of a capture, or one look-at view.
    Render(cmd::render::Args),
    /// Evaluate an asset against a capture's held-out photographs (PSNR, SSIM, MSE).
    Eval(cmd::eval::Args),
    /// Benchmarks: `train` (training step and inference vs the sgemm peak and PyTorch),
    /// `render ASSET` (ms per frame).
    Bench(cmd::bench::Args),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Validate(args) => cmd::validate::run(&args),
        Command::Inspect(args) => cmd::inspect::run(&args),
        // --- render / eval (renderer engineer) ---
        Command::Render(args) => cmd::render::run(&args),
        Command::Eval(args) => cmd::eval::run(&args),
        Command::Bench(args) => cmd::bench::run(&args),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("dnr: {e:#}");
            ExitCode::from(2)
        }
    }
}
