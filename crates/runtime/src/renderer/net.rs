//! The bridge from a decoded renderer (`dnr_format::DecodedRenderer`) to the networks of
//! [`crate::network`]. Shading calls the networks only through [`Net`].

use std::collections::BTreeMap;

use dnr_format::model::{Architecture, Decoder, Normalization};
use dnr_format::DecodedRenderer;

use crate::network::mlp::{Mlp, MlpParams};
use crate::network::unet::{self, UNet, UNetParams};
use crate::network::{check_no_extra, NetworkError, TensorRef};

/// A renderer's network, ready to run.
#[derive(Clone, Debug)]
pub(crate) enum Net {
    /// `none`: colour is channels 0..2 of the features.
    None,
    /// `mlp`: dense layers applied per covered pixel.
    Mlp(Mlp),
    /// `unet`: a U-Net over the whole frame.
    Unet(UNet),
}

impl Net {
    /// Builds the network of a decoded renderer, checking parameters, tensor names and
    /// shapes (extra tensors are an error).
    pub(crate) fn from_decoded(r: &DecodedRenderer) -> Result<Net, NetworkError> {
        let spec = &r.spec;
        let in_ch = spec.input_channels as usize;
        let out_ch = spec.output_channels as usize;
        if !(out_ch == 3 || out_ch == 4) {
            return Err(NetworkError::Params(format!(
                "outputChannels {out_ch} is not 3 or 4"
            )));
        }
        let shapes: BTreeMap<&str, Vec<usize>> = r
            .tensors
            .iter()
            .map(|(name, t)| (name.as_str(), t.shape.iter().map(|&d| d as usize).collect()))
            .collect();
        let lookup = |name: &str| -> Option<TensorRef<'_>> {
            let data = r.tensors.get(name)?;
            let shape = shapes.get(name)?;
            Some((shape.as_slice(), data.data.as_slice()))
        };
        let names = || r.tensors.keys().map(String::as_str);
        match &spec.architecture {
            Architecture::None => {
                if in_ch < 3 || out_ch != 3 {
                    return Err(NetworkError::Params(format!(
                        "`none` needs at least 3 input and exactly 3 output channels, has {in_ch} and {out_ch}"
                    )));
                }
                if let Some(extra) = names().next() {
                    return Err(NetworkError::Unexpected(extra.to_string()));
                }
                Ok(Net::None)
            }
            Architecture::Mlp => {
                let hidden = spec
                    .hidden
                    .as_ref()
                    .ok_or_else(|| NetworkError::Params("`mlp` without `hidden`".into()))?;
                let params = MlpParams {
                    in_ch,
                    hidden: hidden.iter().map(|&h| h as usize).collect(),
                    out_ch,
                };
                check_no_extra(&params.tensor_specs(), names())?;
                Ok(Net::Mlp(Mlp::new(params, &lookup)?))
            }
            Architecture::Unet => {
                let widths = spec
                    .widths
                    .as_ref()
                    .ok_or_else(|| NetworkError::Params("`unet` without `widths`".into()))?;
                let decoder = match &spec.decoder {
                    Some(Decoder::TransposedConv) => unet::Decoder::TransposedConv,
                    Some(Decoder::UpsampleConv) => unet::Decoder::UpsampleConv,
                    other => return Err(NetworkError::Params(format!("`unet` decoder {other:?}"))),
                };
                let norm = match &spec.normalization {
                    Some(Normalization::Instance) => unet::Norm::Instance,
                    Some(Normalization::None) => unet::Norm::None,
                    other => {
                        return Err(NetworkError::Params(format!(
                            "`unet` normalization {other:?}"
                        )))
                    }
                };
                let params = UNetParams {
                    in_ch,
                    out_ch,
                    widths: widths.iter().map(|&w| w as usize).collect(),
                    decoder,
                    norm,
                };
                params.validate()?;
                check_no_extra(&params.tensor_specs(), names())?;
                Ok(Net::Unet(UNet::new(params, &lookup)?))
            }
            Architecture::Unknown(a) => Err(NetworkError::Params(format!(
                "architecture `{a}` is not supported"
            ))),
        }
    }

    /// The spec's architecture name.
    pub(crate) fn architecture(&self) -> &'static str {
        match self {
            Net::None => "none",
            Net::Mlp(_) => "mlp",
            Net::Unet(_) => "unet",
        }
    }
}
