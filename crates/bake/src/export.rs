//! Export: the trained texture and renderer, the proxy mesh and the fallback material as one
//! `EXT_deferred_neural_rendering` asset (f16 storage with the format crate's range checks, or
//! quantised levels and `int8` weights, see [`Storage`]; written to a temporary file and
//! renamed).

use std::collections::BTreeMap;
use std::path::Path;

use dnr_format::asset::{
    AssetBuilder, LevelStorage, MaterialDesc, NeuralTextureDesc, Node, Primitive, RendererDesc,
    WrapMode,
};
use dnr_format::model::{Architecture, DType, Decoder, Normalization, Renderer, ViewDependence};
use dnr_format::{LevelCompression, TensorF32, TextureLevel};
use dnr_runtime::network::unet::{self, UNetParams};
use dnr_runtime::scene::Scene;
use dnr_runtime::texture::{Pyramid, Wrap};

/// The trained renderer to store.
#[derive(Clone, Debug)]
pub enum ExportNet {
    /// Texture only.
    None,
    /// Per-pixel MLP: hidden widths, output channels, tensors by name.
    Mlp {
        /// Hidden widths.
        hidden: Vec<usize>,
        /// Output channels (3 or 4).
        out_ch: usize,
        /// `name -> (shape, values)`.
        tensors: BTreeMap<String, (Vec<usize>, Vec<f32>)>,
    },
    /// U-Net.
    Unet {
        /// Architecture.
        params: UNetParams,
        /// `name -> (shape, values)`.
        tensors: BTreeMap<String, (Vec<usize>, Vec<f32>)>,
    },
}

/// How the asset stores its parts.
#[derive(Clone, Debug, PartialEq)]
pub struct Storage {
    /// Per level, finest first (levels past the end: EXR f16).
    pub levels: Vec<LevelStorage>,
    /// The renderer's tensors (`int8`: rank-2-and-up tensors int8, biases f16).
    pub weights: DType,
    /// Tensors stored otherwise than `weights`, by name (`int4` for large inner layers).
    pub tensor_dtypes: BTreeMap<String, DType>,
}

impl Storage {
    /// Every level EXR f16, weights `dtype`: revision 1.0 storage.
    pub fn exr(dtype: DType) -> Self {
        Storage {
            levels: Vec::new(),
            weights: dtype,
            tensor_dtypes: BTreeMap::new(),
        }
    }

    /// `levels` levels all stored as `level`, weights `int8` when `level` is quantised.
    pub fn uniform(level: LevelStorage, levels: usize) -> Self {
        Storage {
            levels: vec![level; levels],
            weights: if level == LevelStorage::Exr {
                DType::F16
            } else {
                DType::Int8
            },
            tensor_dtypes: BTreeMap::new(),
        }
    }

    /// Short text: `f16`, `q8`, `q4` when uniform, else the levels and weights.
    pub fn describe(&self) -> String {
        let names: Vec<&str> = self.levels.iter().map(|l| l.name()).collect();
        let overrides: Vec<String> = self
            .tensor_dtypes
            .iter()
            .filter(|(_, d)| **d != self.weights)
            .map(|(n, d)| format!("{n} {d}"))
            .collect();
        format!(
            "levels [{}], weights {}{}",
            if names.is_empty() {
                "f16".to_string()
            } else {
                names.join(", ")
            },
            self.weights,
            if overrides.is_empty() {
                String::new()
            } else {
                format!(" ({})", overrides.join(", "))
            }
        )
    }
}

/// Export errors.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// The format crate refused the data (e.g. a value beyond the half range).
    #[error("{path}: {source}")]
    Format {
        /// Output path.
        path: String,
        /// What the format crate said.
        #[source]
        source: dnr_format::Error,
    },
    /// A shape does not fit in the format's u32 fields.
    #[error("{0}")]
    Shape(String),
}

fn wrap_mode(w: Wrap) -> WrapMode {
    match w {
        Wrap::Repeat => WrapMode::Repeat,
        Wrap::ClampToEdge => WrapMode::ClampToEdge,
        Wrap::MirroredRepeat => WrapMode::MirroredRepeat,
    }
}

fn u32_of(x: usize) -> Result<u32, ExportError> {
    u32::try_from(x).map_err(|_| ExportError::Shape(format!("{x} does not fit in u32")))
}

fn tensors_f32(
    map: &BTreeMap<String, (Vec<usize>, Vec<f32>)>,
) -> Result<BTreeMap<String, TensorF32>, ExportError> {
    map.iter()
        .map(|(k, (shape, data))| {
            let shape = shape
                .iter()
                .map(|&s| u32_of(s))
                .collect::<Result<Vec<_>, _>>()?;
            Ok((
                k.clone(),
                TensorF32 {
                    shape,
                    data: data.clone(),
                },
            ))
        })
        .collect()
}

/// Builds the asset. `sh` is `(degree, first_channel)` when the texture is view dependent;
/// `supersample` is the subsamples per pixel side the network was trained on (written as the
/// renderer's `supersample` when above 1). Each primitive keeps its own node (its world
/// matrix as TRS) so the local frame the view directions were trained in is the one a
/// reader sees.
pub fn build(
    scene: &Scene,
    pyr: &Pyramid,
    sh: Option<(u32, u32)>,
    net: &ExportNet,
    out_ch: usize,
    supersample: u32,
    dtype: DType,
) -> Result<AssetBuilder, ExportError> {
    build_with(
        scene,
        pyr,
        sh,
        net,
        out_ch,
        supersample,
        &Storage::exr(dtype),
    )
}

/// [`build`] with any [`Storage`].
pub fn build_with(
    scene: &Scene,
    pyr: &Pyramid,
    sh: Option<(u32, u32)>,
    net: &ExportNet,
    out_ch: usize,
    supersample: u32,
    storage: &Storage,
) -> Result<AssetBuilder, ExportError> {
    let dtype = storage.weights.clone();
    let mut b = AssetBuilder::new();
    b.generator = Some(format!("dnr-bake {}", env!("CARGO_PKG_VERSION")));
    let channels = u32_of(pyr.channels)?;
    let levels = pyr
        .levels
        .iter()
        .map(|l| {
            Ok(TextureLevel {
                width: u32_of(l.width)?,
                height: u32_of(l.height)?,
                channels,
                data: l.data.clone(),
            })
        })
        .collect::<Result<Vec<_>, ExportError>>()?;
    let tex = b.add_neural_texture(NeuralTextureDesc {
        levels,
        wrap_s: wrap_mode(pyr.wrap_s),
        wrap_t: wrap_mode(pyr.wrap_t),
        view_dependence: sh.map(|(d, f)| ViewDependence::spherical_harmonics(d, f)),
        // Per level, the smallest of the lossless methods (zeros of unseen texels compress).
        compression: LevelCompression::Smallest,
        storage: storage.levels.clone(),
    });
    let out = u32_of(out_ch)?;
    let (renderer, tensors) = match net {
        ExportNet::None => (
            Renderer::new(Architecture::None, channels, 3),
            BTreeMap::new(),
        ),
        ExportNet::Mlp {
            hidden,
            out_ch,
            tensors,
        } => {
            let mut r = Renderer::new(Architecture::Mlp, channels, u32_of(*out_ch)?);
            r.hidden = Some(
                hidden
                    .iter()
                    .map(|&h| u32_of(h))
                    .collect::<Result<_, _>>()?,
            );
            (r, tensors_f32(tensors)?)
        }
        ExportNet::Unet { params, tensors } => {
            let mut r = Renderer::new(Architecture::Unet, channels, out);
            r.widths = Some(
                params
                    .widths
                    .iter()
                    .map(|&w| u32_of(w))
                    .collect::<Result<_, _>>()?,
            );
            r.decoder = Some(match params.decoder {
                unet::Decoder::TransposedConv => Decoder::TransposedConv,
                unet::Decoder::UpsampleConv => Decoder::UpsampleConv,
            });
            r.normalization = Some(match params.norm {
                unet::Norm::Instance => Normalization::Instance,
                unet::Norm::None => Normalization::None,
            });
            (r, tensors_f32(tensors)?)
        }
    };
    let mut renderer = renderer;
    renderer.supersample = (supersample > 1).then_some(supersample);
    let rend = b.add_renderer(RendererDesc {
        renderer,
        tensors,
        dtype,
        tensor_dtypes: storage.tensor_dtypes.clone(),
    });
    let mat = b.add_material(MaterialDesc {
        name: Some("neural".into()),
        neural_texture: tex,
        renderer: rend,
    });
    for (i, p) in scene.primitives.iter().enumerate() {
        let prim = Primitive {
            positions: p.positions.iter().map(|v| v.to_array()).collect(),
            normals: None,
            tex_coords: p.uvs.iter().map(|v| v.to_array()).collect(),
            indices: p.indices.clone(),
            material: Some(mat),
        };
        let mesh = b.add_mesh(Some(format!("proxy{i}")), vec![prim]);
        let (s, r, t) = p.world.to_scale_rotation_translation();
        b.add_node(Node {
            name: Some(format!("proxy{i}")),
            mesh: Some(mesh),
            translation: t.to_array(),
            rotation: r.to_array(),
            scale: s.to_array(),
            children: Vec::new(),
        });
    }
    Ok(b)
}

/// Writes the asset atomically (temporary file in the same folder, then rename); returns its
/// size in bytes.
pub fn write(builder: &AssetBuilder, path: &Path) -> Result<u64, ExportError> {
    let err = |source| ExportError::Format {
        path: path.display().to_string(),
        source,
    };
    builder.write(path).map_err(err)?;
    Ok(std::fs::metadata(path).map(|m| m.len()).unwrap_or(0))
}
