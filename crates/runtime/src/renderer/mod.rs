//! The viewer API: load an `EXT_deferred_neural_rendering` asset once, then draw frames.
//!
//! A [`Renderer`] holds the scene's triangles (with node transforms), one sampling pyramid
//! per neural texture and one network per renderer of the asset. [`Renderer::render`]
//! rasterises a camera's view and shades it; [`Renderer::shade`] shades a G-buffer that a
//! viewer's own (GPU) rasteriser produced.
//!
//! What a frame does (spec "Evaluating a Frame" and "Compositing Several Renderers"):
//!
//! 1. Each covered pixel belongs to its visible primitive. Pixels of primitives with an
//!    `EXT_deferred_neural_rendering` binding belong to that binding's renderer (pixels are
//!    grouped by renderer, never by material: primitives sharing one fallback material keep
//!    their own bindings); pixels of unbound primitives are *core* pixels; uncovered pixels
//!    are *background*.
//! 2. Each renderer that owns at least one pixel runs once, on a feature image in which
//!    only its own pixels are covered: `F` summed over the levels of the neural texture of
//!    the pixel's primitive's binding, multiplied by the spherical harmonics of the local
//!    view direction where the texture has `viewDependence`. Renderers that own no pixel do
//!    no work; `none` runs no network; `none` and `mlp` touch only their own pixels.
//! 3. Output: at a renderer's own pixels its colour and alpha (alpha = coverage = 1 for
//!    3-channel outputs, `(t3 + 1) / 2` for 4-channel outputs); at core pixels
//!    `(0, 0, 0, 0)`; at background pixels the 4-channel `unet` outputs composited
//!    source-over in ascending renderer index. Non-finite outputs become 0.
//!
//! The result is the neural layer ([`RgbaImage`]: sRGB-encoded colour, straight alpha). The
//! CPU renderer does not shade core materials (neither unbound primitives' materials nor
//! the fallbacks): a viewer composites the layer over its own image of everything else.
//!
//! Errors are typed ([`RendererError`]); a bad asset or G-buffer never panics.

mod image;
mod net;
mod shade;

use std::path::Path;

use dnr_format::{Asset, DecodedTexture, WrapMode};

use crate::camera::Camera;
use crate::gbuffer::GBuffer;
use crate::network::NetworkError;
use crate::nn::awake::with_workers_awake;
use crate::nn::NnError;
use crate::raster::{self, rasterize};
use crate::scene::{from_gltf_slice, Primitive, Scene, SceneError};
use crate::sh;
use crate::supersample;
use crate::texture::{Level, Pyramid, TextureError, Wrap};

pub use image::{quantize, RgbaImage};
use net::Net;

/// Most pixels of one frame (`width * height`); larger frames are refused before anything
/// is allocated. 2^25 is 8192 x 4096.
pub const MAX_PIXELS: u64 = 1 << 25;

/// Why an asset cannot be loaded into a [`Renderer`], or a frame cannot be drawn.
#[derive(Debug, thiserror::Error)]
pub enum RendererError {
    /// The file could not be read or decoded as an asset (container, JSON, EXR, weights,
    /// limits, or an extension version/architecture this reader does not support).
    #[error(transparent)]
    Format(#[from] dnr_format::Error),
    /// The core glTF scene could not be turned into triangles.
    #[error(transparent)]
    Scene(#[from] SceneError),
    /// A neural texture is malformed.
    #[error("neural texture {index}: {reason}")]
    Texture {
        /// Index in the extension's `neuralTextures`.
        index: usize,
        /// What is wrong.
        reason: String,
    },
    /// A renderer's network cannot be built.
    #[error("renderer {index}: {error}")]
    Network {
        /// Index in the extension's `renderers`.
        index: usize,
        /// What is wrong.
        error: NetworkError,
    },
    /// A scene primitive's binding names a missing neural texture or renderer, or pairs a
    /// texture and a renderer whose channel counts differ.
    #[error("{}: {reason}", primitive_name(*primitive, *gltf))]
    Binding {
        /// Index in [`Scene::primitives`].
        primitive: usize,
        /// The glTF `(mesh, primitive)` it was loaded from, when known.
        gltf: Option<(u32, u32)>,
        /// What is wrong.
        reason: String,
    },
    /// The requested frame has more than [`MAX_PIXELS`] pixels (or a side beyond the
    /// rasteriser's limit).
    #[error("frame {width}x{height} is too large (at most {MAX_PIXELS} pixels)")]
    FrameTooLarge {
        /// Requested width.
        width: u64,
        /// Requested height.
        height: u64,
    },
    /// A G-buffer handed to [`Renderer::shade`] is inconsistent.
    #[error("G-buffer: {0}")]
    GBuffer(String),
    /// A network rejected its input while drawing (an internal inconsistency).
    #[error("renderer {index} failed: {error}")]
    Run {
        /// Index in the extension's `renderers`.
        index: usize,
        /// The layer error.
        error: NnError,
    },
}

/// A neural texture ready to sample.
#[derive(Clone, Debug)]
struct NeuralTexture {
    pyramid: Pyramid,
    /// `(firstChannel, degree)` of the view dependence, if any.
    sh: Option<(usize, u32)>,
}

/// One renderer of the asset.
#[derive(Clone, Debug)]
struct RendererSlot {
    net: Net,
    input_channels: usize,
    output_channels: usize,
    /// Subsamples per pixel side of the feature image (1: the pixel centre).
    supersample: usize,
}

/// What draws a scene primitive.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum PrimOwner {
    /// A primitive without a binding: drawn by the viewer's core path, not by this one.
    Core,
    /// A primitive with an `EXT_deferred_neural_rendering` binding.
    Neural {
        /// Neural texture index.
        texture: usize,
        /// Renderer index.
        renderer: usize,
    },
}

/// A loaded asset, ready to draw frames. Cheap to share between threads (`Sync`); each
/// call allocates its own buffers.
#[derive(Clone, Debug)]
pub struct Renderer {
    scene: Scene,
    textures: Vec<NeuralTexture>,
    renderers: Vec<RendererSlot>,
    /// Per `scene.primitives` entry: its binding, checked against the asset.
    owners: Vec<PrimOwner>,
    /// Whether `unet` renderers skip the work no covered pixel reaches (same output).
    skip_uncovered: bool,
}

impl Renderer {
    /// Reads a `.glb` or `.gltf` file (external buffers resolved beside it) and prepares it.
    ///
    /// ```no_run
    /// let renderer = dnr_runtime::renderer::Renderer::from_path("statue.glb")?;
    /// # Ok::<(), dnr_runtime::renderer::RendererError>(())
    /// ```
    pub fn from_path(path: impl AsRef<Path>) -> Result<Self, RendererError> {
        let asset = dnr_format::read_asset(path.as_ref())?;
        Self::from_asset(&asset)
    }

    /// Reads a GLB, or a `.gltf` whose buffers are all `data:` URIs, from memory.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, RendererError> {
        let asset = dnr_format::read_asset_from_slice(bytes)?;
        Self::from_asset(&asset)
    }

    /// Prepares a decoded asset: the scene from its glTF (each primitive with its binding),
    /// a pyramid per neural texture, a network per renderer. An asset without the extension
    /// gives a renderer that draws nothing (every pixel is core or background).
    pub fn from_asset(asset: &Asset) -> Result<Self, RendererError> {
        let glb = asset.container.to_glb()?;
        let scene = from_gltf_slice(&glb)?;
        Self::from_scene(scene, asset)
    }

    /// Like [`Renderer::from_asset`] with a scene the caller built.
    ///
    /// A primitive's binding is its `neural` `(neuralTexture, renderer)`; when that is None
    /// and its `source` names a glTF `(mesh, primitive)`, the asset's binding of that
    /// primitive ([`Asset::binding`]) is used; otherwise the primitive is core (not drawn
    /// here). `material` is not read: the fallback material plays no part in neural shading.
    /// Every binding must name an existing texture and renderer whose `inputChannels` equal
    /// the texture's channels ([`RendererError::Binding`] otherwise).
    pub fn from_scene(scene: Scene, asset: &Asset) -> Result<Self, RendererError> {
        let textures = asset
            .textures
            .iter()
            .enumerate()
            .map(|(index, t)| {
                neural_texture(t).map_err(|reason| RendererError::Texture { index, reason })
            })
            .collect::<Result<Vec<_>, _>>()?;
        let renderers = asset
            .renderers
            .iter()
            .enumerate()
            .map(|(index, r)| {
                let net = Net::from_decoded(r)
                    .map_err(|error| RendererError::Network { index, error })?;
                Ok(RendererSlot {
                    net,
                    input_channels: r.spec.input_channels as usize,
                    output_channels: r.spec.output_channels as usize,
                    supersample: r.spec.supersample_factor() as usize,
                })
            })
            .collect::<Result<Vec<_>, RendererError>>()?;
        let owners = scene
            .primitives
            .iter()
            .enumerate()
            .map(|(index, p)| prim_owner(index, p, asset, &textures, &renderers))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Renderer {
            scene,
            textures,
            renderers,
            owners,
            skip_uncovered: true,
        })
    }

    /// The triangles this renderer draws. A viewer with its own rasteriser writes indices
    /// into `scene().primitives` as the G-buffer's `prim` ids.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// Number of renderers (networks) of the asset.
    pub fn renderer_count(&self) -> usize {
        self.renderers.len()
    }

    /// Architecture name (`none`, `mlp`, `unet`) of renderer `index`.
    pub fn architecture(&self, index: usize) -> Option<&'static str> {
        self.renderers.get(index).map(|r| r.net.architecture())
    }

    /// Number of neural textures of the asset.
    pub fn neural_texture_count(&self) -> usize {
        self.textures.len()
    }

    /// Turns receptive-field skipping of `unet` renderers on (the default) or off: with it,
    /// when the renderer's pixels reach little of the frame
    /// ([`crate::network::unet::UNet::skip_worthwhile`]), convolution outputs that no pixel
    /// it covers can reach are computed once per value class instead of at every position.
    /// The frames are bit-identical either way; off is for benchmarks and checks.
    pub fn set_skip_uncovered(&mut self, on: bool) {
        self.skip_uncovered = on;
    }

    /// Draws the scene as `camera` sees it into a `width x height` frame.
    ///
    /// When `width x height` differs from the camera's own size, the intrinsics are scaled
    /// to the new size (the same view at another resolution); a camera with a zero size
    /// keeps its intrinsics as they are.
    ///
    /// ```
    /// use dnr_format::model::{Architecture, DType, Renderer as RendererSpec};
    /// use dnr_format::{AssetBuilder, LevelCompression, MaterialDesc, NeuralTextureDesc, Node,
    ///                  Primitive, RendererDesc, TextureLevel, WrapMode};
    /// use dnr_runtime::{camera::Camera, renderer::Renderer};
    ///
    /// // A 2 x 2 quad at z = 0 whose 1 x 1 texture is orange, drawn by a `none` renderer.
    /// let mut b = AssetBuilder::new();
    /// let quad = Primitive {
    ///     positions: vec![[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]],
    ///     normals: None,
    ///     tex_coords: vec![[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]],
    ///     indices: vec![0, 1, 2, 0, 2, 3],
    ///     material: Some(0),
    /// };
    /// let mesh = b.add_mesh(None, vec![quad]);
    /// b.add_node(Node { mesh: Some(mesh), ..Node::default() });
    /// b.add_neural_texture(NeuralTextureDesc {
    ///     levels: vec![TextureLevel { width: 1, height: 1, channels: 3, data: vec![1.0, 0.5, 0.0] }],
    ///     wrap_s: WrapMode::Repeat,
    ///     wrap_t: WrapMode::Repeat,
    ///     view_dependence: None,
    ///     compression: LevelCompression::None,
    ///     storage: Vec::new(),
    /// });
    /// b.add_renderer(RendererDesc {
    ///     renderer: RendererSpec::new(Architecture::None, 3, 3),
    ///     tensors: Default::default(),
    ///     dtype: DType::F16,
    ///     tensor_dtypes: Default::default(),
    /// });
    /// // Binding (texture 0, renderer 0) for every primitive whose fallback material is 0.
    /// b.add_material(MaterialDesc { name: None, neural_texture: 0, renderer: 0 });
    /// let asset = b.build()?;
    ///
    /// let renderer = Renderer::from_asset(&asset)?;
    /// let camera = Camera::look_at([0.0, 0.0, 3.0].into(), [0.0; 3].into(), 40.0, 64, 48);
    /// let image = renderer.render(&camera, 64, 48)?;
    /// assert_eq!(image.pixel(32, 24), Some([1.0, 0.5, 0.0, 1.0])); // the quad
    /// assert_eq!(image.pixel(0, 0), Some([0.0; 4])); // background
    /// let png_bytes = image.to_rgba8(); // 64 * 48 * 4 bytes for an 8-bit RGBA PNG
    /// assert_eq!(&png_bytes[(24 * 64 + 32) * 4..][..4], &[255, 128, 0, 255]);
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn render(
        &self,
        camera: &Camera,
        width: u32,
        height: u32,
    ) -> Result<RgbaImage, RendererError> {
        check_frame(u64::from(width), u64::from(height))?;
        let factors = self.supersample_factors();
        for &s in &factors {
            check_frame(u64::from(width) * s as u64, u64::from(height) * s as u64)?;
        }
        let cam = resized_camera(camera, width, height);
        // One burst of parallel kernels: the workers poll through it (see `shade`). The
        // rasteriser's G-buffers are consistent and their sizes were checked above.
        with_workers_awake(|| {
            let fine: Vec<GBuffer> = factors
                .iter()
                .map(|&s| rasterize(&self.scene, &supersample::subsample_camera(&cam, s)))
                .collect();
            let fine: Vec<&GBuffer> = fine.iter().collect();
            shade::shade(self, &rasterize(&self.scene, &cam), &fine)
        })
    }

    /// The distinct `supersample` factors above 1 of the renderers that some scene primitive
    /// is bound to, ascending: the subsample G-buffers [`Renderer::shade_supersampled`]
    /// needs (empty for assets without supersampling).
    pub fn supersample_factors(&self) -> Vec<u32> {
        let mut f: Vec<u32> = self
            .owners
            .iter()
            .filter_map(|o| match o {
                PrimOwner::Neural { renderer, .. } => Some(self.renderers[*renderer].supersample),
                PrimOwner::Core => None,
            })
            .filter(|&s| s > 1)
            .map(|s| s as u32)
            .collect();
        f.sort_unstable();
        f.dedup();
        f
    }

    /// Shades a G-buffer: the neural layer of a frame whose visibility the caller computed.
    ///
    /// `gbuf.prim` must index [`Renderer::scene`]`().primitives` at every covered pixel
    /// (`coverage != 0`); `uv` is the binding's `TEXCOORD_<texCoord>` (non-finite where the
    /// primitive has none: the feature is then 0); `view_dir` is the unit eye-to-surface
    /// direction in the primitive's local space (only read where the neural texture has
    /// view dependence; non-finite is treated as `(0, 0, 0)`). Coverage is binary: any
    /// non-zero value counts as covered. `tri` and `depth` are not read.
    ///
    /// A viewer with its own rasteriser draws [`Renderer::scene`]'s primitives, reads back
    /// those four render targets and passes them here; the result is the neural layer, to
    /// composite over the viewer's own image. Here a ray through each pixel centre stands in
    /// for the viewer's GPU pass:
    ///
    /// ```
    /// use dnr_runtime::{camera::Camera, gbuffer::GBuffer, renderer::Renderer};
    /// use glam::Vec3;
    ///
    /// // A conformance sample of the repository: a unit quad with a `none` renderer.
    /// let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../samples/valid/none_1level.glb");
    /// let renderer = Renderer::from_path(path)?;
    /// let (w, h) = (64, 48);
    /// let camera = Camera::look_at(Vec3::new(0.3, 0.2, 2.5), Vec3::ZERO, 40.0, w, h);
    ///
    /// // The viewer's visibility pass: nearest hit per pixel centre.
    /// let mut g = GBuffer::new(w as usize, h as usize);
    /// for py in 0..h {
    ///     for px in 0..w {
    ///         // The ray through the pixel centre (the camera looks along -Z, +Y up).
    ///         let d = Vec3::new(
    ///             (px as f32 + 0.5 - camera.cx) / camera.fx,
    ///             -(py as f32 + 0.5 - camera.cy) / camera.fy,
    ///             -1.0,
    ///         );
    ///         let i = (py * w + px) as usize;
    ///         for (index, p) in renderer.scene().primitives.iter().enumerate() {
    ///             // In the primitive's local space, where view directions are given.
    ///             let to_local = p.world.inverse();
    ///             let eye = to_local.transform_point3(camera.eye());
    ///             let dir = to_local.transform_vector3(camera.cam_to_world.transform_vector3(d));
    ///             for (t, tri) in p.indices.chunks_exact(3).enumerate() {
    ///                 let [a, b, c] = [0, 1, 2].map(|k| p.positions[tri[k] as usize]);
    ///                 // Moller-Trumbore: barycentrics (b1, b2) and the ray parameter, which is
    ///                 // the view-space depth because the camera-space ray has z = -1.
    ///                 let (e1, e2, s) = (b - a, c - a, eye - a);
    ///                 let (q, r) = (dir.cross(e2), s.cross(e1));
    ///                 let det = e1.dot(q);
    ///                 let (b1, b2, depth) = (s.dot(q) / det, dir.dot(r) / det, e2.dot(r) / det);
    ///                 let inside = b1 >= 0.0 && b2 >= 0.0 && b1 + b2 <= 1.0;
    ///                 if det.abs() < 1e-12 || !inside || depth <= 0.0 || depth >= g.depth[i] {
    ///                     continue;
    ///                 }
    ///                 let uv = |k: usize| p.uvs[tri[k] as usize];
    ///                 g.coverage[i] = 1.0;
    ///                 g.prim[i] = index as u32; // index into renderer.scene().primitives
    ///                 g.tri[i] = t as u32;
    ///                 g.depth[i] = depth;
    ///                 g.uv[i] = (uv(0) * (1.0 - b1 - b2) + uv(1) * b1 + uv(2) * b2).to_array();
    ///                 g.view_dir[i] = (e1 * b1 + e2 * b2 - s).normalize().to_array();
    ///             }
    ///         }
    ///     }
    /// }
    /// let layer = renderer.shade(&g)?;
    ///
    /// // The runtime's own rasteriser sees the same view. The layers agree but where the two
    /// // passes round a UV differently (by 1e-4 or so) or disagree on an edge pixel.
    /// let reference = renderer.render(&camera, w, h)?;
    /// let agree = layer.data.chunks_exact(4).zip(reference.data.chunks_exact(4))
    ///     .filter(|(a, b)| a.iter().zip(*b).all(|(x, y)| (x - y).abs() < 1e-2))
    ///     .count();
    /// assert!(agree as f32 >= 0.99 * (w * h) as f32, "{agree} of {} pixels agree", w * h);
    /// assert!(g.coverage.iter().filter(|&&c| c > 0.0).count() > 100);
    ///
    /// // Composite over the viewer's (here white) background and save an 8-bit PNG.
    /// let rgb = layer.over([1.0; 3]);
    /// let rgba: Vec<u8> = rgb
    ///     .chunks_exact(3)
    ///     .flat_map(|p| [p[0], p[1], p[2], 1.0].map(dnr_runtime::renderer::quantize))
    ///     .collect();
    /// let png = dnr_format::asset::encode_png_rgba8(w, h, &rgba)?;
    /// let dir = tempfile::tempdir()?;
    /// std::fs::write(dir.path().join("composited.png"), png)?;
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    ///
    /// The fields one by one, filled by hand:
    ///
    /// ```
    /// use dnr_format::model::{Architecture, DType, Renderer as RendererSpec};
    /// use dnr_format::{AssetBuilder, LevelCompression, MaterialDesc, NeuralTextureDesc, Node,
    ///                  Primitive, RendererDesc, TextureLevel, WrapMode};
    /// use dnr_runtime::{gbuffer::GBuffer, renderer::Renderer};
    ///
    /// // One triangle with a 2 x 1 texture (red | blue), clamped at the edges.
    /// let mut b = AssetBuilder::new();
    /// let tri = Primitive {
    ///     positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
    ///     normals: None,
    ///     tex_coords: vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]],
    ///     indices: vec![0, 1, 2],
    ///     material: Some(0),
    /// };
    /// let mesh = b.add_mesh(None, vec![tri]);
    /// b.add_node(Node { mesh: Some(mesh), ..Node::default() });
    /// b.add_neural_texture(NeuralTextureDesc {
    ///     levels: vec![TextureLevel { width: 2, height: 1, channels: 3,
    ///                                 data: vec![1.0, 0.0, 0.0, 0.0, 0.0, 1.0] }],
    ///     wrap_s: WrapMode::ClampToEdge,
    ///     wrap_t: WrapMode::ClampToEdge,
    ///     view_dependence: None,
    ///     compression: LevelCompression::None,
    ///     storage: Vec::new(),
    /// });
    /// b.add_renderer(RendererDesc {
    ///     renderer: RendererSpec::new(Architecture::None, 3, 3),
    ///     tensors: Default::default(),
    ///     dtype: DType::F16,
    ///     tensor_dtypes: Default::default(),
    /// });
    /// b.add_material(MaterialDesc { name: None, neural_texture: 0, renderer: 0 });
    /// let renderer = Renderer::from_asset(&b.build()?)?;
    ///
    /// // A 3 x 1 G-buffer from "another rasteriser": pixel 0 sees u = 0.25 (the red texel's
    /// // centre), pixel 1 sees u = 0.5 (half way), pixel 2 is uncovered.
    /// let mut g = GBuffer::new(3, 1);
    /// for (i, u) in [(0, 0.25), (1, 0.5)] {
    ///     g.coverage[i] = 1.0;
    ///     g.prim[i] = 0; // index into renderer.scene().primitives
    ///     g.uv[i] = [u, 0.5];
    /// }
    /// let image = renderer.shade(&g)?;
    /// assert_eq!(image.pixel(0, 0), Some([1.0, 0.0, 0.0, 1.0]));
    /// assert_eq!(image.pixel(1, 0), Some([0.5, 0.0, 0.5, 1.0]));
    /// assert_eq!(image.pixel(2, 0), Some([0.0; 4]));
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    ///
    /// An asset with supersampled renderers ([`Renderer::supersample_factors`] not empty)
    /// needs [`Renderer::shade_supersampled`]; here it is a [`RendererError::GBuffer`].
    pub fn shade(&self, gbuf: &GBuffer) -> Result<RgbaImage, RendererError> {
        self.shade_supersampled(gbuf, &[])
    }

    /// [`Renderer::shade`] for assets with supersampled renderers (spec "Supersampled
    /// Features"): `subsamples` holds, for each factor `s` of
    /// [`Renderer::supersample_factors`], the G-buffer of the same view at `s` times the
    /// width and height (the camera's intrinsics scaled by `s`, as
    /// [`crate::supersample::subsample_camera`] gives), filled as `gbuf` is. Pixel
    /// ownership and coverage come from `gbuf`; the supersampled renderers' features are
    /// the means of their subsamples' features.
    pub fn shade_supersampled(
        &self,
        gbuf: &GBuffer,
        subsamples: &[GBuffer],
    ) -> Result<RgbaImage, RendererError> {
        for g in std::iter::once(gbuf).chain(subsamples) {
            if !g.is_consistent() {
                return Err(RendererError::GBuffer(format!(
                    "the per-pixel vectors do not all hold width * height = {} x {} entries",
                    g.width, g.height
                )));
            }
            check_frame(g.width as u64, g.height as u64)?;
        }
        for s in self.supersample_factors() {
            let (w, h) = (s as usize * gbuf.width, s as usize * gbuf.height);
            if !subsamples.iter().any(|g| (g.width, g.height) == (w, h)) {
                return Err(RendererError::GBuffer(format!(
                    "the asset has supersample {s}: a subsample G-buffer of {w}x{h} ({s} \
                     times the frame) is needed"
                )));
            }
        }
        let fine: Vec<&GBuffer> = subsamples.iter().collect();
        // Sampling, SH and the network fork many short kernels: the pool's workers poll
        // between them instead of sleeping.
        with_workers_awake(|| shade::shade(self, gbuf, &fine))
    }
}

/// The checked binding of scene primitive `index` (see [`Renderer::from_scene`]).
fn prim_owner(
    index: usize,
    p: &Primitive,
    asset: &Asset,
    textures: &[NeuralTexture],
    renderers: &[RendererSlot],
) -> Result<PrimOwner, RendererError> {
    let from_asset = || {
        let (mesh, prim) = p.source?;
        let b = asset.binding(mesh as usize, prim as usize)?;
        Some((b.neural_texture, b.renderer))
    };
    let Some((ti, ri)) = p.neural.or_else(from_asset) else {
        return Ok(PrimOwner::Core);
    };
    let bad = |reason: String| RendererError::Binding {
        primitive: index,
        gltf: p.source,
        reason,
    };
    let (ti, ri) = (ti as usize, ri as usize);
    let t = textures
        .get(ti)
        .ok_or_else(|| bad(format!("neural texture {ti} does not exist")))?;
    let r = renderers
        .get(ri)
        .ok_or_else(|| bad(format!("renderer {ri} does not exist")))?;
    if t.pyramid.channels != r.input_channels {
        return Err(bad(format!(
            "neural texture {ti} has {} channels, renderer {ri} takes {}",
            t.pyramid.channels, r.input_channels
        )));
    }
    Ok(PrimOwner::Neural {
        texture: ti,
        renderer: ri,
    })
}

/// How [`RendererError::Binding`] names a primitive.
fn primitive_name(primitive: usize, gltf: Option<(u32, u32)>) -> String {
    match gltf {
        Some((mesh, prim)) => {
            format!("scene primitive {primitive} (mesh {mesh} primitive {prim}) binding")
        }
        None => format!("scene primitive {primitive} binding"),
    }
}

/// Refuses frames beyond [`MAX_PIXELS`] or the rasteriser's side limit.
fn check_frame(width: u64, height: u64) -> Result<(), RendererError> {
    let side = raster::MAX_IMAGE_SIDE as u64;
    if width.saturating_mul(height) > MAX_PIXELS || width > side || height > side {
        return Err(RendererError::FrameTooLarge { width, height });
    }
    Ok(())
}

/// `camera` at `width x height`, intrinsics scaled from its own size.
fn resized_camera(camera: &Camera, width: u32, height: u32) -> Camera {
    let mut c = *camera;
    if (c.width, c.height) != (width, height) && c.width > 0 && c.height > 0 {
        let sx = width as f32 / c.width as f32;
        let sy = height as f32 / c.height as f32;
        c.fx *= sx;
        c.cx *= sx;
        c.fy *= sy;
        c.cy *= sy;
    }
    c.width = width;
    c.height = height;
    c
}

/// The sampling pyramid and view dependence of a decoded texture.
fn neural_texture(t: &DecodedTexture) -> Result<NeuralTexture, String> {
    let channels = t.channels as usize;
    let mut levels = Vec::with_capacity(t.levels.len());
    for (i, l) in t.levels.iter().enumerate() {
        if l.channels != t.channels {
            return Err(format!(
                "level {i} has {} channels, the texture {}",
                l.channels, t.channels
            ));
        }
        levels.push(Level {
            width: l.width as usize,
            height: l.height as usize,
            data: l.data.clone(),
        });
    }
    let pyramid = Pyramid::new(channels, levels, wrap(t.wrap_s), wrap(t.wrap_t))
        .map_err(|e: TextureError| e.to_string())?;
    let sh = match &t.view_dependence {
        None => None,
        Some(vd) => {
            if vd.basis != dnr_format::model::BASIS_SPHERICAL_HARMONICS
                || vd.degree > sh::MAX_DEGREE
            {
                return Err(format!(
                    "view dependence `{}` of degree {} is not supported",
                    vd.basis, vd.degree
                ));
            }
            let first = vd.first_channel as usize;
            if first.saturating_add(sh::coeff_count(vd.degree)) > channels {
                return Err(format!(
                    "view dependence channels {first}..{} exceed the {channels} channels",
                    first.saturating_add(sh::coeff_count(vd.degree))
                ));
            }
            Some((first, vd.degree))
        }
    };
    Ok(NeuralTexture { pyramid, sh })
}

fn wrap(w: WrapMode) -> Wrap {
    match w {
        WrapMode::Repeat => Wrap::Repeat,
        WrapMode::ClampToEdge => Wrap::ClampToEdge,
        WrapMode::MirroredRepeat => Wrap::MirroredRepeat,
    }
}
