//! The tensors each renderer architecture requires (names and shapes), and the checks
//! on its parameters. The runtime, the baker and the validator all use this table.

use crate::container::Problem;
use crate::error::{Error, Result};
use crate::model::{Architecture, Decoder, Normalization, Renderer, MAX_SUPERSAMPLE};

/// Most U-Net levels (`widths.len()`).
pub const MAX_UNET_DEPTH: usize = 8;

/// Every problem with a renderer's parameters (empty when it can be evaluated).
pub fn renderer_problems(r: &Renderer) -> Vec<Problem> {
    let mut out = Vec::new();
    let param = |what: String| Problem::invalid("RENDERER_PARAMETER_INVALID", what);
    if !r.architecture.is_known() {
        out.push(Problem::from_error(
            "RENDERER_UNKNOWN_ARCHITECTURE",
            Error::not_supported(format!("architecture `{}`", r.architecture)),
        ));
        return out;
    }
    if r.architecture == Architecture::None {
        // `none` passes channels 0..3 through as colour; it has no alpha output.
        if r.output_channels != 3 {
            out.push(Problem::invalid(
                "RENDERER_OUTPUT_CHANNELS",
                format!(
                    "outputChannels is {}, architecture `none` requires 3",
                    r.output_channels
                ),
            ));
        }
    } else if !(r.output_channels == 3 || r.output_channels == 4) {
        out.push(Problem::invalid(
            "RENDERER_OUTPUT_CHANNELS",
            format!("outputChannels is {}, must be 3 or 4", r.output_channels),
        ));
    }
    if r.input_channels == 0 {
        out.push(param("inputChannels is 0".into()));
    }
    if let Some(s) = r.supersample {
        if !(1..=MAX_SUPERSAMPLE).contains(&s) {
            out.push(param(format!(
                "supersample is {s}, must be 1..={MAX_SUPERSAMPLE}"
            )));
        }
    }
    match r.architecture {
        Architecture::None => {
            if r.input_channels < 3 {
                out.push(param(format!(
                    "architecture `none` reads channels 0..3, inputChannels is {}",
                    r.input_channels
                )));
            }
        }
        Architecture::Mlp => match &r.hidden {
            None => out.push(param("architecture `mlp` needs `hidden`".into())),
            Some(h) if h.contains(&0) => out.push(param(format!("hidden {h:?} has a zero width"))),
            Some(_) => {}
        },
        Architecture::Unet => {
            match &r.widths {
                None => out.push(param("architecture `unet` needs `widths`".into())),
                Some(w) if w.is_empty() || w.len() > MAX_UNET_DEPTH => out.push(param(format!(
                    "widths has {} entries, must have 1..={MAX_UNET_DEPTH}",
                    w.len()
                ))),
                Some(w) if w.contains(&0) => {
                    out.push(param(format!("widths {w:?} has a zero width")))
                }
                Some(_) => {}
            }
            match &r.decoder {
                None => out.push(param("architecture `unet` needs `decoder`".into())),
                Some(Decoder::Unknown(d)) => out.push(Problem::from_error(
                    "RENDERER_PARAMETER_INVALID",
                    Error::not_supported(format!("decoder `{d}`")),
                )),
                Some(_) => {}
            }
            match &r.normalization {
                None => out.push(param("architecture `unet` needs `normalization`".into())),
                Some(Normalization::Unknown(n)) => out.push(Problem::from_error(
                    "RENDERER_PARAMETER_INVALID",
                    Error::not_supported(format!("normalization `{n}`")),
                )),
                Some(_) => {}
            }
        }
        Architecture::Unknown(_) => {}
    }
    out
}

/// The exact tensors (name, shape) the renderer's architecture requires, in the order
/// the network uses them. `none` requires none.
///
/// Errors if the parameters are invalid (see [`renderer_problems`]).
pub fn architecture_tensors(r: &Renderer) -> Result<Vec<(String, Vec<u32>)>> {
    if let Some(p) = renderer_problems(r).into_iter().next() {
        return Err(p.error);
    }
    let (c, out_c) = (r.input_channels, r.output_channels);
    let mut t = Vec::new();
    let mut push = |name: String, shape: Vec<u32>| t.push((name, shape));
    match r.architecture {
        Architecture::Mlp => {
            let hidden = r.hidden.as_deref().unwrap_or(&[]);
            let mut fan_in = c;
            for (i, &fan_out) in hidden.iter().chain(std::iter::once(&out_c)).enumerate() {
                push(format!("layers.{i}.weight"), vec![fan_out, fan_in]);
                push(format!("layers.{i}.bias"), vec![fan_out]);
                fan_in = fan_out;
            }
        }
        Architecture::Unet => {
            let w = r.widths.as_deref().unwrap_or(&[]);
            let d = w.len();
            for i in 0..d {
                let c_in = if i == 0 { c } else { w[i - 1] };
                push(format!("encoder.{i}.weight"), vec![w[i], c_in, 4, 4]);
                push(format!("encoder.{i}.bias"), vec![w[i]]);
            }
            let transposed = r.decoder == Some(Decoder::TransposedConv);
            for i in (0..d).rev() {
                let c_in = if i == d - 1 { w[d - 1] } else { 2 * w[i] };
                let c_out = if i == 0 { out_c } else { w[i - 1] };
                let shape = if transposed {
                    vec![c_in, c_out, 4, 4]
                } else {
                    vec![c_out, c_in, 3, 3]
                };
                push(format!("decoder.{i}.weight"), shape);
                push(format!("decoder.{i}.bias"), vec![c_out]);
            }
        }
        _ => {}
    }
    Ok(t)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mlp_shapes() {
        let t = architecture_tensors(&Renderer::mlp(8, 4, vec![16, 12])).unwrap();
        let shapes: Vec<_> = t.iter().map(|(n, s)| (n.as_str(), s.clone())).collect();
        assert_eq!(
            shapes,
            vec![
                ("layers.0.weight", vec![16, 8]),
                ("layers.0.bias", vec![16]),
                ("layers.1.weight", vec![12, 16]),
                ("layers.1.bias", vec![12]),
                ("layers.2.weight", vec![4, 12]),
                ("layers.2.bias", vec![4]),
            ]
        );
        assert_eq!(
            architecture_tensors(&Renderer::mlp(3, 3, vec![]))
                .unwrap()
                .len(),
            2
        );
    }

    #[test]
    fn unet_shapes_follow_design() {
        let r = Renderer::unet(
            6,
            4,
            vec![4, 8, 16],
            Decoder::TransposedConv,
            Normalization::Instance,
        );
        let t: std::collections::BTreeMap<_, _> =
            architecture_tensors(&r).unwrap().into_iter().collect();
        assert_eq!(t["encoder.0.weight"], vec![4, 6, 4, 4]);
        assert_eq!(t["encoder.2.weight"], vec![16, 8, 4, 4]);
        assert_eq!(t["decoder.2.weight"], vec![16, 8, 4, 4]);
        assert_eq!(t["decoder.1.weight"], vec![16, 4, 4, 4]);
        assert_eq!(t["decoder.0.weight"], vec![8, 4, 4, 4]);
        assert_eq!(t["decoder.0.bias"], vec![4]);
        let r = Renderer::unet(6, 3, vec![5], Decoder::UpsampleConv, Normalization::None);
        let t: std::collections::BTreeMap<_, _> =
            architecture_tensors(&r).unwrap().into_iter().collect();
        assert_eq!(t["decoder.0.weight"], vec![3, 5, 3, 3]);
        assert_eq!(t.len(), 4);
    }

    #[test]
    fn invalid_parameters() {
        let mut r = Renderer::unet(
            6,
            5,
            vec![],
            Decoder::Unknown("x".into()),
            Normalization::Instance,
        );
        let codes: Vec<_> = renderer_problems(&r).iter().map(|p| p.code).collect();
        assert_eq!(
            codes,
            [
                "RENDERER_OUTPUT_CHANNELS",
                "RENDERER_PARAMETER_INVALID",
                "RENDERER_PARAMETER_INVALID"
            ]
        );
        r.architecture = Architecture::Unknown("gan".into());
        assert!(architecture_tensors(&r).is_err());
    }

    #[test]
    fn none_takes_three_outputs_and_at_least_three_inputs() {
        let codes = |i, o| -> Vec<&str> {
            renderer_problems(&Renderer::new(Architecture::None, i, o))
                .iter()
                .map(|p| p.code)
                .collect()
        };
        assert!(codes(3, 3).is_empty());
        assert!(codes(7, 3).is_empty());
        assert_eq!(codes(7, 4), ["RENDERER_OUTPUT_CHANNELS"]);
        assert_eq!(codes(3, 5), ["RENDERER_OUTPUT_CHANNELS"]);
        assert_eq!(codes(2, 3), ["RENDERER_PARAMETER_INVALID"]);
        assert!(architecture_tensors(&Renderer::new(Architecture::None, 7, 4)).is_err());
        // 4 outputs stay valid for the networks.
        assert!(renderer_problems(&Renderer::mlp(3, 4, vec![])).is_empty());
    }

    #[test]
    fn supersample_range() {
        let with = |s: Option<u32>| Renderer {
            supersample: s,
            ..Renderer::unet(
                8,
                4,
                vec![4, 8],
                Decoder::UpsampleConv,
                Normalization::Instance,
            )
        };
        assert_eq!(with(None).supersample_factor(), 1);
        assert!(renderer_problems(&with(None)).is_empty());
        for s in 1..=MAX_SUPERSAMPLE {
            let r = with(Some(s));
            assert!(renderer_problems(&r).is_empty(), "supersample {s}");
            assert_eq!(r.supersample_factor(), s);
            // The factor does not change the tensors.
            assert_eq!(
                architecture_tensors(&r).unwrap(),
                architecture_tensors(&with(None)).unwrap()
            );
        }
        for s in [0, MAX_SUPERSAMPLE + 1, u32::MAX] {
            let codes: Vec<_> = renderer_problems(&with(Some(s)))
                .iter()
                .map(|p| p.code)
                .collect();
            assert_eq!(codes, ["RENDERER_PARAMETER_INVALID"], "supersample {s}");
            assert!(architecture_tensors(&with(Some(s))).is_err());
        }
        // Checked for every architecture, `none` included.
        let none = Renderer {
            supersample: Some(5),
            ..Renderer::new(Architecture::None, 3, 3)
        };
        assert_eq!(renderer_problems(&none).len(), 1);
    }

    #[test]
    fn supersample_json_round_trip() {
        let mut r = Renderer::mlp(6, 3, vec![8]);
        let v = serde_json::to_value(&r).unwrap();
        // Writers omit it when absent (a revision 1.2 renderer).
        assert!(v.get("supersample").is_none(), "{v}");
        assert_eq!(serde_json::from_value::<Renderer>(v).unwrap(), r);
        r.supersample = Some(3);
        let v = serde_json::to_value(&r).unwrap();
        assert_eq!(v["supersample"], 3);
        let back: Renderer = serde_json::from_value(v).unwrap();
        assert_eq!(back.supersample, Some(3));
        assert!(back.others.is_empty(), "read as the known property");
        assert_eq!(back, r);
        // Out-of-range values still read (the parameter check reports them).
        let v = serde_json::json!({
            "architecture": "none", "inputChannels": 3, "outputChannels": 3, "supersample": 0
        });
        assert_eq!(
            serde_json::from_value::<Renderer>(v).unwrap().supersample,
            Some(0)
        );
    }
}
