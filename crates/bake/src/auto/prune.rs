//! Pruning by measurement: remove a pyramid level or zero a feature channel, render the
//! validation views, keep the removal when it costs less than the threshold; then check the
//! removals together. And the export side: dropping channels that are held at zero, which
//! changes no pixel (a zero input contributes nothing to the first layer).

use std::collections::BTreeMap;

use dnr_runtime::texture::{Level, Pyramid};
use serde::Serialize;

use crate::export::ExportNet;
use crate::train::run::mean_psnr as psnr;
use crate::train::views::View;
use crate::train::{TrainError, Trainer};

/// What removing one item (a level or a channel) cost on the validation views.
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Trial {
    /// `level K` (0 = finest) or `channel C`.
    pub item: String,
    /// Validation PSNR lost (dB; negative: removing it helped).
    pub cost_db: f64,
    /// Texel values (width x height x channels) the removal saves.
    pub values_saved: usize,
    /// Whether it was pruned.
    pub pruned: bool,
}

/// The pruning pass's measurements.
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Pruning {
    /// Validation PSNR before pruning.
    pub base_psnr: f64,
    /// Every removal tried, alone.
    pub trials: Vec<Trial>,
    /// Validation PSNR lost by the kept removals together (before fine-tuning).
    pub joint_cost_db: f64,
    /// Levels removed (indices before removal, 0 = finest).
    pub levels: Vec<usize>,
    /// Channels held at zero and dropped at export.
    pub channels: Vec<usize>,
    /// Removals not tried: the budget's share for pruning ([`super::PRUNE_SHARE`]) did not
    /// afford their renders (the largest savings are tried first).
    pub untried: Vec<String>,
    /// Validation renders the share afforded (trials, and one for the joint check).
    pub renders_afforded: usize,
    /// Seconds the trials took.
    pub seconds: f64,
}

/// Channels pruning may remove: not the colour channels 0..2 (the mean-colour loss and the
/// fallback material read them) and not the SH band (the extension fixes its position).
pub fn prunable_channels(channels: usize, sh: Option<(u32, u32)>) -> Vec<usize> {
    let band = sh.map_or(0..0, |(deg, first)| {
        first as usize..first as usize + ((deg + 1) * (deg + 1)) as usize
    });
    (3..channels).filter(|c| !band.contains(c)).collect()
}

/// Tries removing each level and each prunable channel alone, keeps those costing less than
/// `threshold_db`, then re-measures them together and takes back the costliest until the
/// joint cost is within the threshold. Applies the result to the trainer (levels removed,
/// channels held at zero). `base` is the current state's validation PSNR when known.
///
/// `renders` bounds the validation renders: levels (finest first) and then channels are
/// tried while they leave one render for the joint check, and the rest are recorded as
/// untried. Zero renders tries nothing.
pub fn prune(
    trainer: &mut Trainer,
    views: &[View],
    base: Option<f64>,
    threshold_db: f64,
    renders: usize,
) -> Result<Pruning, TrainError> {
    let t0 = std::time::Instant::now();
    let c = trainer.pyr.channels;
    let nlev = trainer.pyr.levels.len();
    let mut items: Vec<Item> = if nlev > 1 {
        (0..nlev).map(Item::Level).collect()
    } else {
        Vec::new()
    };
    items.extend(
        prunable_channels(c, trainer.sh_layer())
            .into_iter()
            .filter(|ch| !trainer.zero_channels().contains(ch))
            .map(Item::Channel),
    );
    // One render is the base when it is not known; one is kept for the joint check.
    let base_renders = usize::from(base.is_none());
    let tried = match renders.checked_sub(base_renders + 1) {
        Some(n) if n > 0 => n.min(items.len()),
        _ => 0,
    };
    let untried: Vec<String> = items[tried..].iter().map(Item::to_string).collect();
    items.truncate(tried);
    let base = match base {
        Some(b) => b,
        None if items.is_empty() => f64::NAN,
        None => psnr(trainer, views)?,
    };
    let texels: usize = trainer.pyr.levels.iter().map(|l| l.width * l.height).sum();
    let mut trials = Vec::new();
    for it in items {
        let (p, values) = match it {
            Item::Level(k) => {
                let l = &trainer.pyr.levels[k];
                let (values, n) = (l.width * l.height * c, l.data.len());
                let saved = std::mem::replace(&mut trainer.pyr.levels[k].data, vec![0.0; n]);
                let p = psnr(trainer, views);
                trainer.pyr.levels[k].data = saved;
                (p?, values)
            }
            Item::Channel(ch) => {
                let saved = zero_channel(&mut trainer.pyr, ch);
                let p = psnr(trainer, views);
                restore_channel(&mut trainer.pyr, ch, &saved);
                (p?, texels)
            }
        };
        trials.push((it, base - p, values));
    }
    // Cheap removals first; keep a level at least.
    let mut chosen: Vec<(Item, f64)> = trials
        .iter()
        .filter(|t| t.1 < threshold_db)
        .map(|t| (t.0, t.1))
        .collect();
    let levels_chosen = chosen
        .iter()
        .filter(|t| matches!(t.0, Item::Level(_)))
        .count();
    if levels_chosen == nlev {
        // Keep the level whose removal alone costs most.
        let worst = chosen
            .iter()
            .enumerate()
            .filter(|(_, t)| matches!(t.0, Item::Level(_)))
            .max_by(|a, b| a.1 .1.total_cmp(&b.1 .1))
            .map(|(i, _)| i)
            .expect("levels chosen");
        chosen.remove(worst);
    }
    chosen.sort_by(|a, b| a.1.total_cmp(&b.1));
    let mut joint = 0.0;
    while !chosen.is_empty() {
        // One removal alone was measured by its trial.
        joint = match chosen.as_slice() {
            [(_, cost)] => *cost,
            _ => base - joint_psnr(trainer, views, &chosen)?,
        };
        if joint <= threshold_db {
            break;
        }
        chosen.pop();
        joint = 0.0;
    }
    let levels: Vec<usize> = chosen
        .iter()
        .filter_map(|t| match t.0 {
            Item::Level(k) => Some(k),
            Item::Channel(_) => None,
        })
        .collect();
    let channels: Vec<usize> = chosen
        .iter()
        .filter_map(|t| match t.0 {
            Item::Channel(c) => Some(c),
            Item::Level(_) => None,
        })
        .collect();
    let mut desc = levels.clone();
    desc.sort_unstable_by(|a, b| b.cmp(a));
    for k in desc {
        trainer.remove_level(k);
    }
    trainer.freeze_zero_channels(&channels);
    Ok(Pruning {
        base_psnr: base,
        trials: trials
            .iter()
            .map(|t| Trial {
                item: t.0.to_string(),
                cost_db: t.1,
                values_saved: t.2,
                pruned: chosen.iter().any(|c| c.0 == t.0),
            })
            .collect(),
        joint_cost_db: joint,
        levels,
        channels,
        untried,
        renders_afforded: renders,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Item {
    Level(usize),
    Channel(usize),
}

impl std::fmt::Display for Item {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Item::Level(k) => write!(f, "level {k}"),
            Item::Channel(c) => write!(f, "channel {c}"),
        }
    }
}

/// Validation PSNR with all `items` removed at once (the trainer is left as it was).
fn joint_psnr(
    trainer: &mut Trainer,
    views: &[View],
    items: &[(Item, f64)],
) -> Result<f64, TrainError> {
    let mut saved_levels = Vec::new();
    let mut saved_channels = Vec::new();
    for (it, _) in items {
        match *it {
            Item::Level(k) => {
                let n = trainer.pyr.levels[k].data.len();
                saved_levels.push((
                    k,
                    std::mem::replace(&mut trainer.pyr.levels[k].data, vec![0.0; n]),
                ));
            }
            Item::Channel(c) => saved_channels.push((c, zero_channel(&mut trainer.pyr, c))),
        }
    }
    let p = psnr(trainer, views);
    for (c, saved) in saved_channels.iter().rev() {
        restore_channel(&mut trainer.pyr, *c, saved);
    }
    for (k, d) in saved_levels {
        trainer.pyr.levels[k].data = d;
    }
    p
}

/// Zeroes channel `ch` in every level; returns the old values (level by level, texel order).
fn zero_channel(pyr: &mut Pyramid, ch: usize) -> Vec<f32> {
    let c = pyr.channels;
    let mut saved = Vec::new();
    for l in &mut pyr.levels {
        for t in l.data.chunks_exact_mut(c) {
            saved.push(t[ch]);
            t[ch] = 0.0;
        }
    }
    saved
}

fn restore_channel(pyr: &mut Pyramid, ch: usize, saved: &[f32]) {
    let c = pyr.channels;
    let mut it = saved.iter();
    for l in &mut pyr.levels {
        for t in l.data.chunks_exact_mut(c) {
            t[ch] = *it.next().expect("saved by zero_channel");
        }
    }
}

/// The texture and network without the channels in `drop` (which must be zero in every
/// texel for the result to render the same). The network's first layer loses the matching
/// input columns; nothing else reads the texture channels directly.
pub fn strip_channels(pyr: &Pyramid, net: &ExportNet, drop: &[usize]) -> (Pyramid, ExportNet) {
    let c = pyr.channels;
    let keep: Vec<usize> = (0..c).filter(|ch| !drop.contains(ch)).collect();
    let k = keep.len();
    let levels = pyr
        .levels
        .iter()
        .map(|l| Level {
            width: l.width,
            height: l.height,
            data: l
                .data
                .chunks_exact(c)
                .flat_map(|t| keep.iter().map(move |&ch| t[ch]))
                .collect(),
        })
        .collect();
    let stripped = Pyramid {
        channels: k,
        levels,
        wrap_s: pyr.wrap_s,
        wrap_t: pyr.wrap_t,
    };
    // Slices dimension 1 (input channels) of `name`, shape [out, in, rest...].
    let slice_inputs = |tensors: &BTreeMap<String, (Vec<usize>, Vec<f32>)>, name: &str| {
        let mut t = tensors.clone();
        if let Some((shape, data)) = t.get_mut(name) {
            if shape.len() >= 2 && shape[1] == c {
                let inner: usize = shape[2..].iter().product();
                let out = shape[0];
                let mut v = Vec::with_capacity(out * k * inner);
                for o in 0..out {
                    for &ch in &keep {
                        let at = (o * c + ch) * inner;
                        v.extend_from_slice(&data[at..at + inner]);
                    }
                }
                shape[1] = k;
                *data = v;
            }
        }
        t
    };
    let net = match net {
        ExportNet::None => ExportNet::None,
        ExportNet::Unet { params, tensors } => {
            let mut params = params.clone();
            params.in_ch = k;
            ExportNet::Unet {
                params,
                tensors: slice_inputs(tensors, "encoder.0.weight"),
            }
        }
        ExportNet::Mlp {
            hidden,
            out_ch,
            tensors,
        } => ExportNet::Mlp {
            hidden: hidden.clone(),
            out_ch: *out_ch,
            tensors: slice_inputs(tensors, "layers.0.weight"),
        },
    };
    (stripped, net)
}
