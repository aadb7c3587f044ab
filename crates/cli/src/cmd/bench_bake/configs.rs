//! The configurations `dnr bench bake` knows by name: the presets and the baselines that
//! show what each component buys.

use anyhow::{bail, Result};
use dnr_bake::train::config::{Arch, Preset, TrainConfig, MLP_DEFAULT_WIDTHS};

/// The baselines `--baselines` adds: classical texturing, learned
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_name_resolves_and_unknown_ones_are_refused() {
        assert!(config("turbo").is_err());
        for name in ["auto", "fast", "balanced", "quality", "paper"]
            .iter()
            .chain(&BASELINES)
        {
            config(name).unwrap();
        }
        assert_eq!(config("classical").unwrap().steps, 0);
        assert!(!config("unet-nosh").unwrap().sh);
        assert_eq!(config("unet-1level").unwrap().levels, 1);
    }
}
