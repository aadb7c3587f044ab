//! `dnr-runtime`: decodes and renders `EXT_deferred_neural_rendering` assets on the CPU.
//!
//! What a third-party viewer links. [`renderer::Renderer`] loads an asset once and draws
//! frames: [`Renderer::render`](renderer::Renderer::render) rasterises a camera's view and
//! shades it; [`Renderer::shade`](renderer::Renderer::shade) shades a G-buffer that the
//! viewer's own (GPU) rasteriser wrote. Either returns the *neural layer*, an RGBA image
//! (sRGB-encoded colour, straight alpha) that the viewer composites over its own image of
//! everything else.
//!
//! ```
//! use dnr_runtime::camera::Camera;
//! use dnr_runtime::renderer::Renderer;
//!
//! // A conformance sample of the repository: a unit quad with a U-Net renderer.
//! let path = concat!(
//!     env!("CARGO_MANIFEST_DIR"),
//!     "/../../samples/valid/unet_transposed_instance_f16.glb"
//! );
//! let renderer = Renderer::from_path(path)?;
//!
//! // 2.5 units in front of the quad, looking at its centre, 40 degrees vertical field of view.
//! let (width, height) = (128, 96);
//! let camera = Camera::look_at([0.0, 0.0, 2.5].into(), [0.0; 3].into(), 40.0, width, height);
//! let image = renderer.render(&camera, width, height)?;
//! assert_eq!((image.width, image.height), (128, 96));
//! let centre = image.pixel(64, 48).expect("inside the frame");
//! assert!(centre[3] > 0.0 && centre.iter().all(|v| v.is_finite()));
//!
//! // Save it as an 8-bit RGBA PNG (dnr-format's encoder; any PNG writer will do).
//! let png = dnr_format::asset::encode_png_rgba8(width, height, &image.to_rgba8())?;
//! let dir = tempfile::tempdir()?;
//! let out = dir.path().join("frame.png");
//! std::fs::write(&out, &png)?;
//! assert_eq!(&std::fs::read(&out)?[1..4], b"PNG");
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! The frame's steps follow the specification's "Evaluating a Frame"
//! (`spec/EXT_deferred_neural_rendering/README.md`): [`raster`] draws the [`scene`] into a
//! [`gbuffer::GBuffer`], [`texture`] samples the neural texture, [`sh`] applies the view
//! dependence, and [`network`] (built from the [`nn`] layers) turns features into colour.
//!
//! Dependencies: `dnr-format` to read assets, and small crates for geometry (`glam`, `gltf`),
//! half floats, threads (`rayon`) and matrix products. It must not depend on training code
//! (`dnr-bake`), on the command line (`dnr-cli`), or on heavy dependencies (image codecs,
//! GPU APIs, machine-learning frameworks): viewers link it, and what it draws is the
//! format's reference.
// `unsafe` is denied everywhere except the SIMD micro-kernels in `nn::gemm`, the
// instruction-set switch and prefetch in `nn::simd`, and the line-aligning allocator in `alloc`
// (which viewers may opt into for their binaries).
#![deny(unsafe_code)]

pub mod alloc;
pub mod camera;
pub mod gbuffer;
pub mod network;
pub mod nn;
pub mod raster;
pub mod renderer;
pub mod scene;
pub mod sh;
pub mod supersample;
pub mod texture;
