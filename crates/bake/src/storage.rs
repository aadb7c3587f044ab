//! `--storage`: how the asset stores its texture levels and weights (f16, quantised PNG
//! levels with `int8` weights), and `auto`'s choice by measurement on the validation views.
//!
//! Every candidate is measured as a reader sees it: the asset is encoded in memory, decoded
//! by `dnr-format` and rendered by the runtime, so its cost includes every rounding.

use serde::Serialize;

use dnr_format::asset::LevelStorage;
use dnr_format::model::DType;
use dnr_format::Container;

use crate::export::{self, ExportNet, Storage};
use crate::pipeline::{BakeError, ExportParts, Loaded};
use crate::train::quantise::QatTarget;

/// Validation PSNR (dB) that `--storage auto` lets the smaller encodings cost, by default.
pub const DEFAULT_BOUND_DB: f64 = 0.1;

/// What `--storage` asks for.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "camelCase")]
pub enum StorageMode {
    /// EXR f16 levels and f16 weights (revision 1.0 assets).
    #[default]
    F16,
    /// 8-bit PNG levels and `int8` weights.
    Q8,
    /// 4-bit PNG levels and `int8` weights.
    Q4,
    /// Per level and for the weights, the smallest encoding whose validation cost stays
    /// under the bound.
    Auto,
}

impl std::str::FromStr for StorageMode {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "f16" => Ok(StorageMode::F16),
            "q8" => Ok(StorageMode::Q8),
            "q4" => Ok(StorageMode::Q4),
            "auto" => Ok(StorageMode::Auto),
            _ => Err(format!(
                "unknown storage '{s}' (expected f16, q8, q4 or auto)"
            )),
        }
    }
}

impl StorageMode {
    /// What quantisation-aware fine-tuning imitates for a pyramid of `levels` levels: the
    /// encoding itself. For auto this is only a placeholder (q4 levels, `int8` weights): the
    /// bakes replace it with [`qat_target_of`] auto's choice at the start of the fine-tune.
    pub fn qat_target(self, levels: usize) -> Option<QatTarget> {
        let bits = match self {
            StorageMode::F16 => return None,
            StorageMode::Q8 => 8,
            StorageMode::Q4 | StorageMode::Auto => 4,
        };
        Some(QatTarget {
            level_bits: vec![Some(bits); levels],
            int8_weights: true,
            tensor_dtypes: Default::default(),
        })
    }
}

/// Bytes of an asset by part.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct PartBytes {
    /// Each texture level's file (EXR or PNG), finest first.
    pub levels: Vec<u64>,
    /// The renderer's tensors.
    pub weights: u64,
    /// The fallback PNG.
    pub fallback: u64,
    /// Everything else of the binary buffer: mesh attributes and indices, padding.
    pub mesh: u64,
    /// The JSON chunk (with the GLB headers).
    pub json: u64,
    /// The whole `.glb`.
    pub total: u64,
}

impl PartBytes {
    /// Sum of the levels.
    pub fn level_total(&self) -> u64 {
        self.levels.iter().sum()
    }
}

/// Bytes by part of a container as a `.glb`.
pub fn part_bytes(c: &Container) -> Result<PartBytes, BakeError> {
    let glb = c.to_glb().map_err(export_err)?;
    let view_len = |i: u32| -> u64 {
        c.root
            .buffer_views
            .get(i as usize)
            .map_or(0, |v| v.byte_length.0)
    };
    let mut out = PartBytes {
        total: glb.len() as u64,
        ..PartBytes::default()
    };
    let mut counted = std::collections::BTreeSet::new();
    if let Some(v) = dnr_format::asset::root_extension_value(&c.root) {
        if let Ok(ext) = serde_json::from_value::<dnr_format::model::Extension>(v.clone()) {
            for t in &ext.neural_textures {
                for l in &t.levels {
                    out.levels.push(view_len(l.buffer_view));
                    counted.insert(l.buffer_view);
                }
            }
            for r in &ext.renderers {
                for w in &r.weights {
                    if counted.insert(w.buffer_view) {
                        out.weights += view_len(w.buffer_view);
                    }
                }
            }
        }
    }
    for img in &c.root.images {
        if let Some(v) = &img.buffer_view {
            let i = v.value() as u32;
            if counted.insert(i) {
                out.fallback += view_len(i);
            }
        }
    }
    let bin: u64 = c.buffers.iter().map(|b| b.len() as u64).sum();
    let counted_bytes: u64 = counted.iter().map(|&i| view_len(i)).sum();
    out.mesh = bin.saturating_sub(counted_bytes);
    out.json = out.total.saturating_sub(bin);
    Ok(out)
}

fn export_err(e: dnr_format::Error) -> BakeError {
    BakeError::Export(export::ExportError::Format {
        path: "(in memory)".into(),
        source: e,
    })
}

/// One storage measured: its bytes and its error on views through the runtime.
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Measured {
    /// Bytes by part.
    pub bytes: PartBytes,
    /// Mean PSNR (dB) on the views measured (NaN without views).
    pub psnr: f64,
}

/// Encodes the parts with `storage` in memory, decodes and renders them on `frames`.
pub fn measure(
    loaded: &Loaded,
    parts: &ExportParts,
    storage: &Storage,
    frames: &[crate::capture::Frame],
) -> Result<Measured, BakeError> {
    let (bytes, psnr) = measure_on(loaded, parts, storage, &[frames])?;
    Ok(Measured {
        bytes,
        psnr: psnr[0],
    })
}

/// [`measure`] on several sets of frames from one encoding: the mean PSNR of each set.
pub fn measure_on(
    loaded: &Loaded,
    parts: &ExportParts,
    storage: &Storage,
    sets: &[&[crate::capture::Frame]],
) -> Result<(PartBytes, Vec<f64>), BakeError> {
    let builder = crate::pipeline::build_asset(loaded, parts, storage)?;
    let container = builder.build_container().map_err(export_err)?;
    let bytes = part_bytes(&container)?;
    let asset = dnr_format::decode_asset(container, &dnr_format::Limits::unlimited())
        .map_err(export_err)?;
    let read_back = |message: String| BakeError::ReadBack {
        path: "(in memory)".into(),
        message,
    };
    let renderer = dnr_runtime::renderer::Renderer::from_asset(&asset)
        .map_err(|e| read_back(e.to_string()))?;
    let mut psnr = Vec::with_capacity(sets.len());
    for frames in sets {
        psnr.push(if frames.is_empty() {
            f64::NAN
        } else {
            crate::eval::evaluate(&renderer, frames, None)
                .map_err(|e| read_back(e.to_string()))?
                .mean
                .psnr
        });
    }
    Ok((bytes, psnr))
}

/// One trial of auto: a part in an encoding, measured with every other part f16.
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Trial {
    /// The part: `level 0 (512x512)` or `weights`.
    pub part: String,
    /// The encoding tried: `q3` to `q8` (a grid of `2^p` steps), `int8`.
    pub encoding: String,
    /// The part's bytes in that encoding.
    pub bytes: u64,
    /// The part's bytes in f16.
    pub f16_bytes: u64,
    /// Validation PSNR lost against all-f16 storage (dB), this part alone quantised.
    pub cost_db: f64,
    /// Whether it was kept.
    pub chosen: bool,
}

/// What `--storage` chose and why (the bake report's `storage`).
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct StorageReport {
    /// `--storage`.
    pub mode: StorageMode,
    /// `--storage-bound-db`.
    pub bound_db: f64,
    /// The storage written.
    pub chosen: String,
    /// Per level, finest first: `f16`, or `q1` to `q8` (the grid's bits; 4-bit PNG values up
    /// to `q4`, 8-bit above).
    pub levels: Vec<String>,
    /// `f16` or `int8` (biases stay f16).
    pub weights: String,
    /// Tensors stored otherwise than `weights` (`int4` or `int8`).
    pub tensor_dtypes: std::collections::BTreeMap<String, DType>,
    /// The storage the last part of training imitated, if any.
    pub qat: Option<QatTarget>,
    /// Auto's trials in order (empty for the fixed encodings).
    pub trials: Vec<Trial>,
    /// Auto's choices together, measured (auto only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub combined: Option<Combined>,
    /// The state auto's trial costs are measured against (auto only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub measured_on: Option<MeasuredOn>,
    /// Auto after a fine-tune: the bound checked on the final state.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub final_check: Option<FinalCheck>,
    /// With quantised storage, the same trained state in every uniform storage and the
    /// chosen one: bytes by part, validation and held-out test PSNR (empty for f16).
    pub variants: Vec<Variant>,
    /// Seconds spent choosing and measuring.
    pub seconds: f64,
}

/// The state auto's trials were measured on.
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct MeasuredOn {
    /// When: at the start of the fine-tune, or at the end of training (no fine-tune ran).
    pub when: String,
    /// Its validation PSNR (dB) stored as f16.
    pub val_psnr: f64,
}

/// One storage of the same trained state, measured.
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Variant {
    /// `f16`, `q8`, `q4` or `chosen`.
    pub name: String,
    /// What it stores.
    pub storage: String,
    /// Bytes by part.
    pub bytes: PartBytes,
    /// Mean PSNR on the validation views.
    pub val_psnr: f64,
    /// Mean PSNR on the capture's test views.
    pub test_psnr: f64,
}

/// Auto's choices measured together: each round solves for the fewest bytes whose summed
/// single-part costs stay under `budget_db`, then measures that storage; a round whose
/// measured cost exceeds the bound shrinks the budget for the next.
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Combined {
    /// Each round: `(budget_db, storage, bytes of the levels and weights, measured cost)`.
    pub rounds: Vec<Round>,
    /// The cost allowed before a fine-tune: the bound times [`FINE_TUNE_CREDIT`], or the
    /// bound when no fine-tune follows.
    pub accept_db: f64,
    /// The storage within the bound before the fine-tune, kept in reserve (when the chosen
    /// one is not).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub safe: Option<String>,
}

/// After the fine-tune: the chosen storage's validation cost against the f16 copy of the
/// same final state, and what was written.
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct FinalCheck {
    /// Each storage checked, in order: `(storage, validation cost in dB)`.
    pub checked: Vec<(String, f64)>,
    /// The storage written: the first checked within the bound, else f16.
    pub written: String,
}

/// One round of [`Combined`].
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Round {
    /// The summed single-part cost allowed.
    pub budget_db: f64,
    /// The storage solved for.
    pub storage: String,
    /// Its levels' and weights' bytes.
    pub bytes: u64,
    /// Its validation cost against all-f16 storage, measured.
    pub cost_db: f64,
}

/// Grids auto tries for each level, coarsest first (bits: `2^p` steps per channel).
pub const AUTO_PRECISIONS: [u32; 6] = [3, 4, 5, 6, 7, 8];

/// A level's finer grids are not tried once one costs at most this fraction of the bound:
/// they could only save that little and take more bytes.
const NEGLIGIBLE_FRACTION: f64 = 0.1;

/// Rounds of solving and measuring before auto settles for the last storage under the bound.
const ROUNDS: usize = 4;

/// Before a quantisation-aware fine-tune, auto may choose a storage that costs up to this
/// many times the bound on the unquantised state: the fine-tune trains through exactly that
/// rounding and wins most of the cost back. The written asset is then measured against the
/// f16 copy of its own final state, and a storage within the bound before the fine-tune
/// replaces it if the bound does not hold (DESIGN.md, "Storage").
pub const FINE_TUNE_CREDIT: f64 = 2.0;

/// Auto's choice, measured on one state: for each level (finest first) and for the weights,
/// each encoding alone against all-f16 storage of that state; then the fewest bytes whose
/// measured cost, all choices together, stays under `bound_db`.
#[derive(Clone, Debug)]
pub struct AutoChoice {
    /// The storage chosen.
    pub storage: Storage,
    /// With a fine-tune to follow: the fewest bytes measured within the bound itself (before
    /// the fine-tune), stored instead if the chosen storage is over the bound after it.
    /// `None` when the chosen storage is within the bound already.
    pub safe: Option<Storage>,
    /// Every trial in order.
    pub trials: Vec<Trial>,
    /// The rounds that measured the choices together.
    pub combined: Combined,
    /// Validation PSNR (dB) of the state stored as f16: what the costs are measured against.
    pub base_val_psnr: f64,
}

/// Auto's validation views (training frames held out from fitting).
fn validation_frames(loaded: &Loaded) -> Vec<crate::capture::Frame> {
    loaded
        .val_idx
        .iter()
        .filter_map(|&i| loaded.capture.train.get(i).cloned())
        .collect()
}

/// One option for one part: `(trial index or None for f16, bytes, cost)`.
type PartOption = (Option<usize>, u64, f64);

/// What one trial changes from all-f16 storage.
#[derive(Clone, Debug)]
enum Change {
    /// Level `li` stored so.
    Level(usize, LevelStorage),
    /// The tensors outside `large` stored so (rank-1 ones stay f16).
    Small(DType),
    /// One large tensor stored so.
    Tensor(String, DType),
}

/// All-f16 storage with `changes` applied; `large` tensors not changed stay f16.
fn apply(levels: usize, large: &[String], changes: &[&Change]) -> Storage {
    let mut s = Storage::uniform(LevelStorage::Exr, levels);
    for c in changes {
        match c {
            Change::Level(li, enc) => s.levels[*li] = *enc,
            Change::Small(d) => s.weights = d.clone(),
            Change::Tensor(name, d) => {
                s.tensor_dtypes.insert(name.clone(), d.clone());
            }
        }
    }
    for name in large {
        s.tensor_dtypes.entry(name.clone()).or_insert(DType::F16);
    }
    s.tensor_dtypes.retain(|_, d| *d != s.weights);
    s
}

/// The renderer's tensors of rank 2 or more holding at least [`LARGE_FRACTION`] of all
/// weights: they are tried at `int4` each (the U-Net's inner stages, where most weights
/// are and rounding costs least). Empty for a texture-only asset.
fn large_tensors(net: &ExportNet) -> Vec<String> {
    let tensors = match net {
        ExportNet::None => return Vec::new(),
        ExportNet::Mlp { tensors, .. } | ExportNet::Unet { tensors, .. } => tensors,
    };
    let total: usize = tensors.values().map(|(_, v)| v.len()).sum();
    tensors
        .iter()
        .filter(|(_, (shape, v))| {
            shape.len() >= 2 && v.len() as f64 >= total as f64 * LARGE_FRACTION
        })
        .map(|(name, _)| name.clone())
        .collect()
}

/// Share of all weights that makes a tensor large enough to try alone at `int4`.
const LARGE_FRACTION: f64 = 1.0 / 16.0;

/// The option of each part with the fewest bytes in all whose costs (negative ones counted
/// as 0) sum to at most `budget_db`; f16 (option 0, cost 0) always fits.
fn fewest_bytes(options: &[Vec<PartOption>], budget_db: f64) -> Vec<usize> {
    // Costs in steps of a thousandth of a dB, rounded up, so the sum never exceeds the budget.
    const STEP: f64 = 1e-3;
    let cap = ((budget_db.max(0.0) / STEP).floor() as usize).min(100_000);
    let units = |c: f64| (c.max(0.0) / STEP).ceil() as usize;
    // best[u] = (bytes, choices) with total units <= u.
    let mut best: Vec<Option<(u64, Vec<usize>)>> = vec![Some((0, Vec::new())); cap + 1];
    for part in options {
        let mut next: Vec<Option<(u64, Vec<usize>)>> = vec![None; cap + 1];
        for (u, slot) in next.iter_mut().enumerate() {
            for (k, &(_, bytes, cost)) in part.iter().enumerate() {
                let c = units(cost);
                if c > u {
                    continue;
                }
                if let Some((b, ch)) = &best[u - c] {
                    let total = b + bytes;
                    if slot.as_ref().is_none_or(|(sb, _)| total < *sb) {
                        let mut ch = ch.clone();
                        ch.push(k);
                        *slot = Some((total, ch));
                    }
                }
            }
        }
        best = next;
    }
    best.pop()
        .flatten()
        .map_or_else(|| vec![0; options.len()], |(_, ch)| ch)
}

/// Measures auto's trials on `parts` (see [`AutoChoice`]). Run at the start of the
/// quantisation-aware fine-tune (`fine_tune_follows`), the costs are those of the
/// unquantised state and the choice may cost up to [`FINE_TUNE_CREDIT`] times the bound
/// there; the fine-tune then imitates what was chosen, and [`choose`] checks the bound on the
/// final state.
pub fn choose_auto(
    loaded: &Loaded,
    parts: &ExportParts,
    bound_db: f64,
    fine_tune_follows: bool,
) -> Result<AutoChoice, BakeError> {
    let n = parts.pyr.levels.len();
    let val = validation_frames(loaded);
    let large = large_tensors(parts.net);
    let f16 = apply(n, &large, &[]);
    let mut trials: Vec<Trial> = Vec::new();
    let mut changes: Vec<Change> = Vec::new();
    let base = measure(loaded, parts, &f16, &val)?;
    let mut options: Vec<Vec<PartOption>> = Vec::new();
    // Without validation views nothing can be measured: every option but f16 is left out.
    // Each part's encodings are tried coarsest first, until one costs next to nothing.
    let mut try_part = |part: String,
                        f16_bytes: u64,
                        encodings: Vec<(String, Change)>,
                        bytes_of: &dyn Fn(&PartBytes) -> u64|
     -> Result<Vec<PartOption>, BakeError> {
        let mut opts = vec![(None, f16_bytes, 0.0)];
        for (name, change) in encodings {
            let trial = apply(n, &large, &[&change]);
            let m = measure(loaded, parts, &trial, &val)?;
            let cost = base.psnr - m.psnr;
            let bytes = bytes_of(&m.bytes);
            trials.push(Trial {
                part: part.clone(),
                encoding: name,
                bytes,
                f16_bytes,
                cost_db: cost,
                chosen: false,
            });
            changes.push(change);
            if !cost.is_finite() {
                break;
            }
            opts.push((Some(trials.len() - 1), bytes, cost));
            if cost <= bound_db * NEGLIGIBLE_FRACTION {
                break;
            }
        }
        Ok(opts)
    };
    for li in 0..n {
        let l = &parts.pyr.levels[li];
        let encodings = AUTO_PRECISIONS
            .iter()
            .filter_map(|&p| LevelStorage::png(p))
            .map(|enc| (enc.name().to_string(), Change::Level(li, enc)))
            .collect();
        let f16_bytes = base.bytes.levels.get(li).copied().unwrap_or(0);
        options.push(try_part(
            format!("level {li} ({}x{})", l.width, l.height),
            f16_bytes,
            encodings,
            &|b: &PartBytes| b.levels.get(li).copied().unwrap_or(0),
        )?);
    }
    if base.bytes.weights > 0 {
        // Weight bytes are one buffer view: a part's bytes are the view's change from f16
        // plus the part's own f16 bytes.
        let tensors = match parts.net {
            ExportNet::Mlp { tensors, .. } | ExportNet::Unet { tensors, .. } => Some(tensors),
            ExportNet::None => None,
        };
        let f16_of = |names: &dyn Fn(&str) -> bool| -> u64 {
            tensors.map_or(0, |t| {
                t.iter()
                    .filter(|(k, _)| names(k))
                    .map(|(_, (_, v))| 2 * v.len() as u64)
                    .sum()
            })
        };
        let base_w = base.bytes.weights;
        let small_f16 = f16_of(&|k| !large.iter().any(|l| l == k));
        let part_name = if large.is_empty() {
            "weights".to_string()
        } else {
            "weights (all but the large tensors)".to_string()
        };
        options.push(try_part(
            part_name,
            small_f16,
            vec![("int8".into(), Change::Small(DType::Int8))],
            &|b: &PartBytes| (b.weights + small_f16).saturating_sub(base_w),
        )?);
        for name in &large {
            let own = f16_of(&|k| k == name);
            options.push(try_part(
                format!("tensor {name}"),
                own,
                vec![
                    ("int4".into(), Change::Tensor(name.clone(), DType::Int4)),
                    ("int8".into(), Change::Tensor(name.clone(), DType::Int8)),
                ],
                &|b: &PartBytes| (b.weights + own).saturating_sub(base_w),
            )?);
        }
    }
    // Solve, measure together, and shrink the budget while the measured cost is over: first
    // to the credited bound (the choice), then to the bound itself (the safe storage).
    let accept = if fine_tune_follows {
        bound_db * FINE_TUNE_CREDIT
    } else {
        bound_db
    };
    let mut rounds = Vec::new();
    let mut budget = accept;
    let mut chosen: Option<(Storage, Vec<usize>)> = None;
    let mut safe = (f16.clone(), Vec::new());
    for _ in 0..2 * ROUNDS {
        let pick = fewest_bytes(&options, budget);
        let picked: Vec<usize> = pick
            .iter()
            .zip(&options)
            .filter_map(|(&k, o)| o.get(k).and_then(|opt| opt.0))
            .collect();
        let s = apply(
            n,
            &large,
            &picked.iter().map(|&t| &changes[t]).collect::<Vec<_>>(),
        );
        if picked.is_empty() {
            chosen.get_or_insert((s, picked));
            break;
        }
        let m = measure(loaded, parts, &s, &val)?;
        let cost = base.psnr - m.psnr;
        rounds.push(Round {
            budget_db: budget,
            storage: s.describe(),
            bytes: m.bytes.level_total() + m.bytes.weights,
            cost_db: cost,
        });
        let within = |b: f64| cost.is_finite() && cost <= b;
        if chosen.is_none() && within(accept) {
            chosen = Some((s.clone(), picked.clone()));
            budget = budget.min(bound_db);
        }
        if within(bound_db) {
            safe = (s, picked);
            break;
        }
        if chosen.is_none() && rounds.len() == ROUNDS {
            // Settle for the safe storage alone: as many rounds as without the credit.
            budget = budget.min(bound_db);
        }
        // Parts' costs added up to less than they cost together: ask for less next time.
        let summed: f64 = pick
            .iter()
            .zip(&options)
            .map(|(&k, o)| o.get(k).map_or(0.0, |opt| opt.2.max(0.0)))
            .sum();
        let target = if chosen.is_none() { accept } else { bound_db };
        budget = (summed * target / cost.max(1e-9)).min(budget * 0.7);
    }
    let (storage, picked) = chosen.unwrap_or_else(|| safe.clone());
    for t in picked {
        trials[t].chosen = true;
    }
    let safe = (safe.0 != storage).then_some(safe.0);
    Ok(AutoChoice {
        combined: Combined {
            rounds,
            accept_db: accept,
            safe: safe.as_ref().map(Storage::describe),
        },
        safe,
        storage,
        trials,
        base_val_psnr: base.psnr,
    })
}

/// What the fine-tune imitates for a chosen storage: each quantised level's grid, and `int8`
/// weights when chosen.
pub fn qat_target_of(storage: &Storage) -> QatTarget {
    QatTarget {
        level_bits: storage.levels.iter().map(|l| l.precision()).collect(),
        int8_weights: storage.weights == DType::Int8,
        tensor_dtypes: storage.tensor_dtypes.clone(),
    }
}

/// Chooses the storage for `mode`: the fixed encodings as asked, auto by measurement (`pre`:
/// auto's choice already made at the start of the fine-tune). Also measures every uniform
/// storage of the same state for the report.
pub fn choose(
    loaded: &Loaded,
    parts: &ExportParts,
    mode: StorageMode,
    bound_db: f64,
    qat: Option<QatTarget>,
    pre: Option<AutoChoice>,
) -> Result<(Storage, StorageReport), BakeError> {
    let t0 = std::time::Instant::now();
    let n = parts.pyr.levels.len();
    let val = validation_frames(loaded);
    let f16 = Storage::uniform(LevelStorage::Exr, n);
    let mut trials = Vec::new();
    let mut combined = None;
    let mut measured_on = None;
    // Auto after a fine-tune: the storages to check on the final state, in order.
    let mut reserve: Vec<Storage> = Vec::new();
    let mut chosen = match mode {
        StorageMode::F16 => f16.clone(),
        StorageMode::Q8 => Storage::uniform(LevelStorage::Q8, n),
        StorageMode::Q4 => Storage::uniform(LevelStorage::Q4, n),
        StorageMode::Auto => {
            // Chosen at the start of the fine-tune, on the unquantised state (unless the
            // texture changed shape since, which the phases before the fine-tune rule out).
            let p = match pre.filter(|p| p.storage.levels.len() == n) {
                Some(p) => {
                    measured_on = Some(MeasuredOn {
                        when: "start of the fine-tune (unquantised)".into(),
                        val_psnr: p.base_val_psnr,
                    });
                    reserve.extend(p.safe.clone());
                    reserve.push(f16.clone());
                    p
                }
                None => {
                    let p = choose_auto(loaded, parts, bound_db, false)?;
                    measured_on = Some(MeasuredOn {
                        when: "end of training".into(),
                        val_psnr: p.base_val_psnr,
                    });
                    p
                }
            };
            trials = p.trials;
            combined = Some(p.combined);
            p.storage
        }
    };
    let mut variants = Vec::new();
    // f16 bakes (the default) cost nothing more than before; quantised ones measure every
    // uniform storage of the same state for the report.
    let compared = if mode == StorageMode::F16 {
        Vec::new()
    } else {
        vec![
            ("f16", f16.clone()),
            ("q8", Storage::uniform(LevelStorage::Q8, n)),
            ("q4", Storage::uniform(LevelStorage::Q4, n)),
        ]
    };
    let variant = |name: &str, s: &Storage| -> Result<Variant, BakeError> {
        let (bytes, psnr) = measure_on(loaded, parts, s, &[&val, &loaded.capture.test])?;
        Ok(Variant {
            name: name.into(),
            storage: s.describe(),
            bytes,
            val_psnr: psnr[0],
            test_psnr: psnr[1],
        })
    };
    for (name, s) in &compared {
        variants.push(variant(name, s)?);
    }
    let mut final_check = None;
    if mode != StorageMode::F16 {
        let mut last = variant("chosen", &chosen)?;
        if !reserve.is_empty() {
            // The fine-tune trained through the chosen rounding: check the bound on the final
            // state, against its own f16 copy, and fall back while it does not hold.
            let f16_val = variants[0].val_psnr;
            let cost = |v: &Variant| f16_val - v.val_psnr;
            let mut checked = vec![(chosen.describe(), cost(&last))];
            for s in reserve {
                if cost(&last).is_finite() && cost(&last) <= bound_db {
                    break;
                }
                last = variant("chosen", &s)?;
                checked.push((s.describe(), cost(&last)));
                chosen = s;
            }
            final_check = Some(FinalCheck {
                checked,
                written: chosen.describe(),
            });
        }
        variants.push(last);
    }
    let report = StorageReport {
        mode,
        bound_db,
        chosen: chosen.describe(),
        levels: (0..n)
            .map(|i| {
                chosen
                    .levels
                    .get(i)
                    .copied()
                    .unwrap_or_default()
                    .name()
                    .into()
            })
            .collect(),
        weights: chosen.weights.to_string(),
        tensor_dtypes: chosen.tensor_dtypes.clone(),
        qat,
        trials,
        combined,
        measured_on,
        final_check,
        variants,
        seconds: t0.elapsed().as_secs_f64(),
    };
    Ok((chosen, report))
}

/// The report's storage section as text lines (what `dnr-bake` prints).
pub fn describe(r: &StorageReport) -> Vec<String> {
    let mut out = vec![format!(
        "storage {:?} (bound {} dB): {}",
        r.mode, r.bound_db, r.chosen
    )];
    if let Some(m) = &r.measured_on {
        out.push(format!(
            "  costs measured at the {}, against {:.2} dB on validation as f16",
            m.when, m.val_psnr
        ));
    }
    for t in &r.trials {
        out.push(format!(
            "  {} as {}: {} bytes (f16 {}), costs {:.3} dB{}",
            t.part,
            t.encoding,
            t.bytes,
            t.f16_bytes,
            t.cost_db,
            if t.chosen { ", chosen" } else { "" }
        ));
    }
    if let Some(c) = &r.combined {
        for round in &c.rounds {
            out.push(format!(
                "  together, within {:.3} dB summed: {} ({} bytes), costs {:.3} dB (allowed {:.3})",
                round.budget_db, round.storage, round.bytes, round.cost_db, c.accept_db
            ));
        }
        if let Some(safe) = &c.safe {
            out.push(format!("  in reserve, within the bound: {safe}"));
        }
    }
    if let Some(f) = &r.final_check {
        for (s, cost) in &f.checked {
            out.push(format!(
                "  after the fine-tune: {s} costs {cost:.3} dB against its f16 copy"
            ));
        }
        out.push(format!("  written: {}", f.written));
    }
    for v in &r.variants {
        out.push(format!(
            "  {:>6}: {} bytes (levels {}, weights {}, fallback {}, mesh {}), validation {:.2} dB, test {:.2} dB",
            v.name,
            v.bytes.total,
            v.bytes.level_total(),
            v.bytes.weights,
            v.bytes.fallback,
            v.bytes.mesh,
            v.val_psnr,
            v.test_psnr
        ));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fewest_bytes_spends_the_budget_where_it_saves_most() {
        // Two levels and the weights; option 0 is f16.
        let options = vec![
            vec![
                (None, 1000, 0.0),
                (Some(0), 300, 0.08),
                (Some(1), 500, 0.02),
            ],
            vec![(None, 400, 0.0), (Some(2), 100, 0.05), (Some(3), 200, 0.01)],
            vec![(None, 200, 0.0), (Some(4), 100, -0.01)],
        ];
        // 0.1 dB: level 0's coarsest grid with level 1's finer one (600 bytes, 0.09 dB) beats
        // level 0's finer grid with level 1's coarsest (700 bytes, 0.07 dB).
        assert_eq!(fewest_bytes(&options, 0.1), vec![1, 2, 1]);
        // 0.07 dB: the coarsest level 0 no longer fits.
        assert_eq!(fewest_bytes(&options, 0.07), vec![2, 1, 1]);
        // Nothing to spend: only free options (a negative cost counts as 0).
        assert_eq!(fewest_bytes(&options, 0.0), vec![0, 0, 1]);
        assert_eq!(fewest_bytes(&options, -1.0), vec![0, 0, 1]);
        assert_eq!(fewest_bytes(&[], 0.1), Vec::<usize>::new());
    }
}
