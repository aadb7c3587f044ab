//! `dnr-bake`: capture folder in, validated `.glb` out.
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::Parser;
use dnr_bake::bake::{bake, BakeOptions};
use dnr_bake::train::config::{Arch, Preset, TrainConfig, MLP_DEFAULT_WIDTHS};
use dnr_bake::train::schedule::{Schedule, Shape};
use dnr_bake::train::Loss;

/// Large buffers (texture levels, optimiser moments, feature planes) on cache-line
/// boundaries: see `dnr_runtime::alloc`.
#[global_allocator]
static ALLOC: dnr_runtime::alloc::LineAligned = dnr_runtime::alloc::LineAligned;

/// Train a neural texture and deferred neural renderer from posed photographs and write one
/// self-contained glTF asset (EXT_deferred_neural_rendering, with a plain fallback material).
///
/// CAPTURE is a folder of posed photographs and a proxy mesh (docs/capture-format.md in the dnr repository
/// lists every key read, the defaults, the limits (--limit) and the errors):
///   - transforms.json (nerfstudio's ns-process-data, instant-ngp, NeRF-synthetic), or
///     transforms_train.json + transforms_test.json: the split files decide the test set;
///     with one transforms.json every 8th frame (0, 8, 16, ...) is held out;
///   - a COLMAP sparse model: sparse/0/ (or sparse/) with cameras and images .bin or .txt,
///     photos in images/, optional masks in masks/NAME.png; every 8th image in name order
///     (0, 8, 16, ...) is held out.
///
/// Photos through a lens with distortion (OPENCV, OPENCV_FISHEYE, RADIAL, ...) are
/// undistorted once at load; photos larger than --max-side are downscaled; black mask
/// pixels give no loss and do not count in evaluation. The mesh (glb, gltf, obj or ply) may
/// lack UVs: an atlas is generated and written into the asset. Before training, the mesh's
/// silhouette is checked against the photos' alpha or masks (or COLMAP's sparse points).
///
/// Examples:
///   dnr-bake samples/capture -o sample.glb --preset fast
///   dnr-bake capture/ -o asset.glb --time-budget 600 --report report.json
///   dnr-bake colmap_project/ -o asset.glb --mesh dense/0/meshed-poisson.ply
///   dnr-bake ns_data/ -o asset.glb --mesh poisson.ply --mesh-space reconstruction
///   dnr-bake capture/ -o asset.glb --mesh proxy.obj --arch none      (texture only)
#[derive(Parser, Debug)]
#[command(name = "dnr-bake", version, verbatim_doc_comment)]
struct Args {
    /// Capture folder (transforms.json, transforms_{train,test}.json or a COLMAP sparse/
    /// model; images; mesh).
    capture: PathBuf,
    /// Output asset (.glb). Written to a temporary file and renamed when complete.
    #[arg(short, long)]
    output: PathBuf,
    /// Starting point. auto (the default): measure and decide within --time-budget (default
    /// 600 s) whether the scene needs the SH layer, which network and texture size the budget
    /// affords, which levels and channels are worth their bytes; the --report lists every
    /// decision with what it cost and saved. Fixed presets: fast (CPU-sized, minutes),
    /// balanced, quality, paper (the paper's sizes: 512x512, 4 levels, 16 channels, U-Net
    /// 64..512). Without --preset, a flag that auto would decide (--resolution, --levels,
    /// --no-sh, --arch, --widths, --steps) or --resume selects balanced instead.
    #[arg(long)]
    preset: Option<Preset>,
    /// Proxy mesh (.glb/.gltf/.obj/.ply) instead of the capture's (mesh_path, else mesh.glb,
    /// mesh.gltf, mesh.obj, mesh.ply, and for COLMAP dense/0/meshed-poisson.ply ...).
    #[arg(long)]
    mesh: Option<PathBuf>,
    /// Longest image side after loading: larger photos are downscaled with an area filter
    /// and their intrinsics scaled (0 keeps every photo at its size).
    #[arg(long, value_name = "PIXELS", default_value_t = dnr_bake::capture::DEFAULT_MAX_SIDE)]
    max_side: u32,
    /// UVs of the mesh: auto (generate an atlas when the mesh has none or they overlap on
    /// more than 1% of their area), keep (use the mesh's, fail without), generate (always).
    #[arg(long, value_name = "MODE", default_value = "auto")]
    uv: dnr_bake::capture::UvMode,
    /// With nerfstudio's applied_transform: whether the mesh is in the poses' coordinates
    /// (poses) or the original reconstruction's (reconstruction: applied_transform is
    /// applied to it, e.g. a COLMAP or Metashape mesh); auto picks the placement whose
    /// silhouettes match the photos.
    #[arg(long, value_name = "SPACE", default_value = "auto")]
    mesh_space: dnr_bake::capture::MeshSpace,
    /// Train even when the mesh's silhouette does not line up with the photos.
    #[arg(long)]
    skip_alignment_check: bool,
    /// Drop training views that fail the alignment check alone (a wrong pose, a bad mask)
    /// instead of stopping.
    #[arg(long)]
    drop_misaligned: bool,
    /// List the transforms keys that were not used and the time of each load step.
    #[arg(long)]
    verbose: bool,
    /// Side of the finest texture level in texels.
    #[arg(long)]
    resolution: Option<u32>,
    /// Number of pyramid levels.
    #[arg(long)]
    levels: Option<u32>,
    /// Feature channels per texel (>= 12 with SH at degree 2, >= 19 at degree 3, >= 3 without).
    #[arg(long)]
    channels: Option<u32>,
    /// Drop the spherical-harmonics view-dependent layer.
    #[arg(long)]
    no_sh: bool,
    /// Degree of the spherical-harmonics layer, 0 to 3: it modulates (degree + 1)^2 channels
    /// from channel 3, so 3 needs --channels 19 or more. Fixed presets use the paper's 2;
    /// auto takes 3 (and 20 channels) when the training images show sharp view dependence.
    #[arg(long, value_name = "DEGREE")]
    sh_degree: Option<u32>,
    /// Renderer architecture: none (texture only), mlp, unet.
    #[arg(long)]
    arch: Option<Arch>,
    /// Comma-separated U-Net widths (or MLP hidden widths, default 64,64 with --arch mlp),
    /// e.g. 16,32,64,128,128.
    #[arg(long, value_delimiter = ',')]
    widths: Option<Vec<u32>>,
    /// Training crop side in pixels (0 = whole frames).
    #[arg(long)]
    crop: Option<u32>,
    /// Maximum optimisation steps.
    #[arg(long)]
    steps: Option<u64>,
    /// Adam learning rate (texture and network; --lr-net / --lr-tex set one).
    #[arg(long)]
    lr: Option<f32>,
    /// Adam learning rate of the network.
    #[arg(long)]
    lr_net: Option<f32>,
    /// Adam learning rate of the neural texture.
    #[arg(long)]
    lr_tex: Option<f32>,
    /// Learning-rate schedule over the whole --time-budget (or --steps): cosine (default:
    /// a short linear warm-up, then half a cosine down to --lr-floor), linear, or constant
    /// (the paper's; the default of --preset paper).
    #[arg(long)]
    schedule: Option<Shape>,
    /// Fraction of the run the schedule warms up over.
    #[arg(long)]
    warmup: Option<f64>,
    /// Learning-rate factor the schedule ends at.
    #[arg(long)]
    lr_floor: Option<f64>,
    /// Texture L2 regularisation: level k of K (0 = finest) gets REG * (K-1-k).
    #[arg(long)]
    reg: Option<f32>,
    /// Photometric loss: l1 (default, the paper's) or l2 (squared error, with each crop's
    /// steps scaled to L1's size). l2 weighs large errors (silhouettes, thin parts,
    /// highlights) more: at 300 s it gained 1.7 dB held out on the duck and lost 1.25 dB on a
    /// capture with mirror-like reflections, which it fits at the cost of the rest.
    #[arg(long)]
    loss: Option<Loss>,
    /// Subsamples per pixel side of the feature image, 1 to 4 (default 2; 1 with --preset
    /// fast or paper): the network sees the mean of S x S subsample features per pixel, so it learns
    /// anti-aliased silhouettes and detail below a pixel. The asset records it (format
    /// revision 1.3); viewers then draw S x S subsamples per pixel. 1 trains faster and
    /// writes an asset every revision 1.0 reader draws exactly.
    #[arg(long, value_name = "S", value_parser = clap::value_parser!(u32).range(1..=4))]
    supersample: Option<u32>,
    /// Per-step decay of the moving average of the texture and the weights (Polyak
    /// averaging) that each validation check weighs against the current state; the better
    /// on validation is kept. Default 0 (off): 0.995 moved held-out PSNR by -0.12 to
    /// +0.08 dB at 300 s on the development set, within run-to-run spread.
    #[arg(long, value_name = "DECAY")]
    ema: Option<f32>,
    /// Crops of random views whose gradients each step averages (1 to 16; default 1, one
    /// crop per step as in the paper). On a CPU a batch of 2 costs about 2.2 steps and lost
    /// 0.14 to 0.24 dB held out at 300 s on the development set with the size held fixed.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=16))]
    batch: Option<u32>,
    /// Decoupled weight decay (AdamW) of the finest texture level, falling linearly to none
    /// at the coarsest (default 4; 0 with --preset paper): each update shrinks a texel by
    /// LR * DECAY of its value, so detail the views disagree on fades and the coarser levels
    /// carry the rest. At 300 s a decay of 2 gained 0.1 to 0.8 dB held out on every capture
    /// of the development set, most on thin structures and coarse proxies; 4 scored within
    /// run-to-run spread of 2.
    #[arg(long, value_name = "DECAY")]
    tex_decay: Option<f32>,
    /// Decoupled weight decay (AdamW) of the network's weights and biases (default 1; 0 with
    /// --preset paper): each update shrinks every weight by LR * DECAY of its value. At
    /// 300 s it gained 0.26 to 0.48 dB held out on each of four captures of the development
    /// set (glossy, thin, mixed, the duck with its coarse proxy).
    #[arg(long, value_name = "DECAY")]
    net_decay: Option<f32>,
    /// Random seed.
    #[arg(long)]
    seed: Option<u64>,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Stop training after this many seconds and export the best state.
    #[arg(long)]
    time_budget: Option<f64>,
    /// Seconds between held-out evaluations.
    #[arg(long)]
    eval_every: Option<f64>,
    /// Write a JSON report (configuration, timed records, final figures).
    #[arg(long)]
    report: Option<PathBuf>,
    /// Continue a killed bake from its last checkpoint (OUTPUT.ckpt/ next to the output).
    #[arg(long)]
    resume: bool,
    /// Seconds between checkpoints (also written on Ctrl-C).
    #[arg(long, default_value_t = 30.0)]
    checkpoint_every: f64,
    /// Also write the same trained state with f32 storage (to measure what f16 costs with
    /// `dnr bench render ASSET --against F32_ASSET`).
    #[arg(long, value_name = "PATH")]
    write_f32: Option<PathBuf>,
    /// With --preset auto: also write the state just before pruning.
    #[arg(long, value_name = "PATH")]
    write_unpruned: Option<PathBuf>,
    /// How the asset stores texture levels and weights: f16 (EXR levels, f16 weights; readable
    /// by every reader of the format), q8 or q4 (8- or 4-bit quantised PNG levels, int8
    /// weights; format revision 1.1), or auto (the fewest bytes whose validation PSNR cost
    /// stays under --storage-bound-db: per level a 3- to 8-bit grid in a 4- or 8-bit PNG, int8
    /// weights, and int4 or int8 for each large tensor, revision 1.2 when int4 is chosen).
    /// Quantised storage trains the last 15 % of the run through its rounding. The --report
    /// lists each choice with its bytes and cost.
    #[arg(long, value_name = "STORAGE", default_value = "f16")]
    storage: dnr_bake::storage::StorageMode,
    /// Validation PSNR (dB) that --storage auto lets the smaller encodings cost.
    #[arg(long, value_name = "DB", default_value_t = dnr_bake::storage::DEFAULT_BOUND_DB)]
    storage_bound_db: f64,
    /// Also write the same trained state with f16 storage (to compare a quantised asset with
    /// it).
    #[arg(long, value_name = "PATH")]
    write_f16: Option<PathBuf>,
    /// With --preset auto: the shortest budget cycle, in seconds. A --time-budget of at least
    /// twice this first bakes half of it, whole, then runs the schedule again from there
    /// and keeps the result only when it beats that half-budget bake on the validation
    /// views, so a longer budget never ends worse on them. Set it above half the budget for
    /// one cycle.
    #[arg(long, value_name = "SECONDS", default_value_t = dnr_bake::auto::cycles::MIN_CYCLE_SECS)]
    min_cycle: f64,
    /// Print the final figures as JSON on stdout.
    #[arg(long)]
    json: bool,
    /// Raise (or lower) a capture size limit, NAME=VALUE; repeatable. Names: max_frames
    /// (default 10000), max_image_side (8192), max_total_pixels (2^28), max_json_bytes,
    /// max_mesh_bytes, max_model_bytes (COLMAP files), max_triangles (20000000),
    /// max_unwrap_triangles (2000000, meshes that get generated UVs).
    #[arg(long = "limit", value_name = "NAME=VALUE")]
    limits: Vec<String>,
}

/// The flags `--preset auto` decides itself, and whether each was given.
fn auto_decided(a: &Args) -> [(&'static str, bool); 7] {
    [
        ("--sh-degree", a.sh_degree.is_some()),
        ("--resolution", a.resolution.is_some()),
        ("--levels", a.levels.is_some()),
        ("--no-sh", a.no_sh),
        ("--arch", a.arch.is_some()),
        ("--widths", a.widths.is_some()),
        ("--steps", a.steps.is_some()),
    ]
}

/// `--preset`, or auto unless a flag asks for what only a fixed preset has.
fn preset(a: &Args) -> Preset {
    a.preset
        .unwrap_or(if a.resume || auto_decided(a).iter().any(|d| d.1) {
            Preset::Balanced
        } else {
            Preset::Auto
        })
}

fn config(a: &Args) -> TrainConfig {
    let mut c = TrainConfig::preset(preset(a));
    if let Some(v) = a.resolution {
        c.resolution = v;
    }
    if let Some(v) = a.levels {
        c.levels = v;
    }
    if let Some(v) = a.channels {
        c.channels = v;
    }
    if a.no_sh {
        c.sh = false;
    }
    if let Some(v) = a.sh_degree {
        c.sh_degree = v;
    }
    if let Some(v) = a.arch {
        c.arch = v;
    }
    if let Some(v) = &a.widths {
        c.widths = v.clone();
    } else if c.arch == Arch::Mlp {
        // The presets' widths are U-Net stages, not MLP hidden layers.
        c.widths = MLP_DEFAULT_WIDTHS.to_vec();
    }
    if let Some(v) = a.crop {
        c.crop = v;
    }
    if let Some(v) = a.steps {
        c.steps = v;
    }
    if let Some(v) = a.lr {
        c.lr_net = v;
        c.lr_tex = v;
    }
    if let Some(v) = a.lr_net {
        c.lr_net = v;
    }
    if let Some(v) = a.lr_tex {
        c.lr_tex = v;
    }
    if let Some(v) = a.schedule {
        c.schedule.shape = v;
        if v == Shape::Constant {
            c.schedule = Schedule::CONSTANT;
        }
    }
    if let Some(v) = a.warmup {
        c.schedule.warmup = v;
    }
    if let Some(v) = a.lr_floor {
        c.schedule.floor = v;
    }
    if let Some(v) = a.tex_decay {
        c.tex_decay = v;
    }
    if let Some(v) = a.net_decay {
        c.net_decay = v;
    }
    if let Some(v) = a.reg {
        c.reg = v;
    }
    if let Some(v) = a.loss {
        c.loss = v;
    }
    if let Some(v) = a.supersample {
        c.supersample = v;
    }
    if let Some(v) = a.ema {
        c.ema = v;
    }
    if let Some(v) = a.batch {
        c.batch = v;
    }
    if let Some(v) = a.seed {
        c.seed = v;
    }
    if let Some(v) = a.threads {
        c.threads = v;
    }
    if let Some(v) = a.time_budget {
        c.time_budget = v;
    }
    if let Some(v) = a.eval_every {
        c.eval_every = v;
    }
    c
}

fn run(a: Args) -> Result<()> {
    if preset(&a) == Preset::Auto {
        if let Some((flag, _)) = auto_decided(&a).iter().find(|d| d.1) {
            anyhow::bail!("{flag} cannot be combined with --preset auto, which decides it by measurement (pick a fixed preset to set it)");
        }
    } else if a.write_unpruned.is_some() {
        anyhow::bail!("--write-unpruned needs --preset auto");
    }
    if !(a.storage_bound_db.is_finite() && a.storage_bound_db >= 0.0) {
        anyhow::bail!(
            "--storage-bound-db must be a finite number of dB at least 0, not {}",
            a.storage_bound_db
        );
    }
    if !(a.min_cycle.is_finite() && a.min_cycle > 0.0) {
        anyhow::bail!(
            "--min-cycle must be a finite number of seconds above 0, not {}",
            a.min_cycle
        );
    }
    let cfg = config(&a);
    cfg.schedule
        .validate()
        .map_err(|e| anyhow::anyhow!("--warmup/--lr-floor: {e}"))?;
    let mut limits = dnr_bake::capture::Limits::default();
    for spec in &a.limits {
        limits
            .set(spec)
            .map_err(|e| anyhow::anyhow!("--limit: {e}"))?;
    }
    let opts = BakeOptions {
        limits,
        capture: a.capture.clone(),
        output: a.output.clone(),
        mesh: a.mesh.clone(),
        report: a.report.clone(),
        resume: a.resume,
        progress: true,
        checkpoint_every: a.checkpoint_every,
        write_f32: a.write_f32.clone(),
        write_unpruned: a.write_unpruned.clone(),
        storage: a.storage,
        storage_bound_db: a.storage_bound_db,
        write_f16: a.write_f16.clone(),
        min_cycle_secs: a.min_cycle,
        input: dnr_bake::capture::InputOptions {
            max_side: a.max_side,
            uv: a.uv,
            mesh_space: a.mesh_space,
            alignment: dnr_bake::capture::alignment::AlignmentOptions {
                skip: a.skip_alignment_check,
                drop_misaligned: a.drop_misaligned,
            },
            verbose: a.verbose,
        },
    };
    let summary = bake(&cfg, &opts).with_context(|| format!("baking {}", a.capture.display()))?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        eprintln!(
            "wrote {} ({} bytes): held-out PSNR {:.2} dB, object MSE {:.1}, {:.1} s",
            a.output.display(),
            summary.asset_bytes,
            summary.test_psnr,
            summary.test_mse,
            summary.seconds
        );
    }
    Ok(())
}

fn main() -> ExitCode {
    let args = Args::parse();
    match run(args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("dnr-bake: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg_of(extra: &[&str]) -> TrainConfig {
        let mut argv = vec!["dnr-bake", "cap", "-o", "out.glb"];
        argv.extend_from_slice(extra);
        config(&Args::parse_from(argv))
    }

    #[test]
    fn auto_is_the_default_unless_a_fixed_preset_flag_is_given() {
        assert_eq!(cfg_of(&[]).preset, Preset::Auto);
        assert_eq!(cfg_of(&["--arch", "none"]).preset, Preset::Balanced);
        assert_eq!(cfg_of(&["--resume"]).preset, Preset::Balanced);
        assert_eq!(cfg_of(&["--preset", "fast"]).preset, Preset::Fast);
        assert_eq!(cfg_of(&["--time-budget", "60"]).preset, Preset::Auto);
    }

    #[test]
    fn mlp_gets_mlp_widths_unless_given() {
        assert_eq!(
            cfg_of(&["--arch", "mlp"]).widths,
            MLP_DEFAULT_WIDTHS.to_vec()
        );
        assert_eq!(
            cfg_of(&["--arch", "mlp", "--widths", "8,4"]).widths,
            vec![8, 4]
        );
        let unet = cfg_of(&["--arch", "unet", "--preset", "fast"]);
        assert_eq!(unet.widths, TrainConfig::preset(Preset::Fast).widths);
    }
}
