//! Writes the conformance samples: `cargo run -p dnr-format --example make_samples -- samples`.
//!
//! Deterministic: every random value comes from a ChaCha8 generator with a fixed seed per
//! sample, and every writer in `dnr-format` is deterministic, so running it twice gives
//! identical bytes. The conformance tests include this file (`generate`) and compare
//! its output with `samples/` so the samples cannot go stale.

use std::collections::BTreeMap;
use std::error::Error;
use std::fs;
use std::path::Path;

use dnr_format::container::{glb_bytes, parse_glb};
use dnr_format::exr_codec::{channel_name, encode_level};
use dnr_format::model::{DType, Decoder, Normalization, Renderer, ViewDependence};
use dnr_format::{
    architecture_tensors, AssetBuilder, Container, LevelCompression, LevelStorage, Limits,
    MaterialDesc, NeuralTextureDesc, Node, Primitive, RendererDesc, TensorF32, TextureLevel,
    WrapMode, EXTENSION_NAME,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde_json::{json, Value};

type Res<T> = Result<T, Box<dyn Error>>;

/// One generated file.
pub struct Sample {
    /// Path relative to the samples folder, e.g. `valid/mlp_f16.glb`.
    pub path: String,
    /// What it exercises.
    pub description: String,
    /// Validator codes it must produce (exactly this set), empty for valid samples.
    pub expected: Vec<&'static str>,
}

/// A reference camera of a valid sample: `dnr_runtime::camera::Camera::look_at(eye, target,
/// fov_y, width, height)` (+Y up, square pixels, principal point at the frame centre), which is
/// what `dnr render ASSET --look-at EYE,TARGET --fov FOV_Y --size WxH` draws. The reference
/// renders of `samples/references/` are made from these by `tests/examples/make_references.rs`.
pub struct RefCamera {
    /// File stem of the reference images.
    pub name: &'static str,
    /// Eye position in world space.
    pub eye: [f32; 3],
    /// Point looked at.
    pub target: [f32; 3],
    /// Vertical field of view in degrees.
    pub fov_y: f32,
    /// Frame width in pixels.
    pub width: u32,
    /// Frame height in pixels.
    pub height: u32,
    /// What the view shows.
    pub note: &'static str,
}

/// The reference cameras of every valid sample (path relative to `samples/`). Every sample has
/// one frame size that is not a multiple of its U-Net's stride (odd sizes); the scene's cameras
/// see several primitives. Eyes sit off the symmetry axes so that few pixel centres fall on
/// triangle edges.
pub fn reference_cameras() -> Vec<(&'static str, Vec<RefCamera>)> {
    let quad = || {
        vec![
            RefCamera {
                name: "front",
                eye: [0.07, -0.04, 1.5],
                target: [0.0, 0.0, 0.0],
                fov_y: 45.0,
                width: 64,
                height: 48,
                note: "the quad from the front",
            },
            RefCamera {
                name: "oblique",
                eye: [0.9, 0.55, 1.1],
                target: [0.03, -0.02, 0.0],
                fov_y: 40.0,
                width: 61,
                height: 45,
                note: "from above right; odd frame size",
            },
            RefCamera {
                name: "back",
                eye: [-0.35, 0.2, -1.3],
                target: [0.0, 0.01, 0.0],
                fov_y: 50.0,
                width: 37,
                height: 29,
                note: "the back face (never culled); odd frame size",
            },
        ]
    };
    let mut out: Vec<(&'static str, Vec<RefCamera>)> = [
        "valid/none_1level.glb",
        "valid/none_sh1_clamp.glb",
        "valid/mlp_f16_2levels.glb",
        "valid/mlp_f32_sh2_4levels.glb",
        "valid/mlp_linear.gltf",
        "valid/unet_transposed_instance_f16.glb",
        "valid/unet_upsample_none_f32.glb",
        "valid/unet_depth1_external.gltf",
        "valid/mlp_q8_levels.glb",
        "valid/mlp_q4_levels.glb",
        "valid/unet_int8_weights.glb",
        "valid/mlp_int4_weights.glb",
    ]
    .into_iter()
    .map(|s| (s, quad()))
    .collect();
    // The star of the revision 1.3 samples lies where the quad does: the same views, where
    // its tips and texture reach pixel scale (front), below it (oblique, compressed; back,
    // smaller).
    let star = || {
        let notes = [
            "the star from the front: tips and rings near pixel scale",
            "from above right: rings compressed below pixel scale; odd frame size",
            "the back face, small: texels under half a pixel; odd frame size",
        ];
        quad()
            .into_iter()
            .zip(notes)
            .map(|(c, note)| RefCamera { note, ..c })
            .collect::<Vec<_>>()
    };
    out.push((
        "valid/scene_multi_primitive.glb",
        vec![
            RefCamera {
                name: "overview",
                eye: [0.4, 1.3, 6.5],
                target: [-0.2, -0.1, 0.3],
                fov_y: 45.0,
                width: 96,
                height: 64,
                note: "every instance: both renderers, both textures, the pyramid",
            },
            RefCamera {
                name: "oblique",
                eye: [4.2, 2.6, 4.4],
                target: [0.1, -0.2, 0.4],
                fov_y: 40.0,
                width: 83,
                height: 57,
                note: "from the right, primitives overlapping; odd frame size",
            },
            RefCamera {
                name: "low",
                eye: [-2.9, -1.1, 4.8],
                target: [0.3, 0.1, 0.2],
                fov_y: 38.0,
                width: 71,
                height: 53,
                note: "from below left; odd frame size",
            },
        ],
    ));
    out.push(("valid/unet_supersample2.glb", star()));
    out.push(("valid/mlp_supersample3.glb", star()));
    out
}

#[allow(dead_code)]
fn main() -> Res<()> {
    let out = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "samples".to_string());
    let samples = generate(Path::new(&out))?;
    println!("wrote {} samples to {out}", samples.len());
    Ok(())
}

// ---------------------------------------------------------------------------------------
// Building blocks

fn quad(size: f32, z: f32, material: usize) -> Primitive {
    let s = size / 2.0;
    Primitive {
        positions: vec![[-s, -s, z], [s, -s, z], [s, s, z], [-s, s, z]],
        normals: Some(vec![[0.0, 0.0, 1.0]; 4]),
        // glTF uv (0,0) is the top-left of the image: the top edge (y = +s) gets v = 0.
        tex_coords: vec![[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]],
        indices: vec![0, 1, 2, 0, 2, 3],
        material: Some(material),
    }
}

/// A tetrahedron-like open pyramid without normals (normals are optional).
fn pyramid(material: usize) -> Primitive {
    Primitive {
        positions: vec![
            [0.0, 0.0, 0.5],
            [-0.5, -0.5, 0.0],
            [0.5, -0.5, 0.0],
            [0.0, 0.5, 0.0],
        ],
        normals: None,
        tex_coords: vec![[0.5, 0.5], [0.0, 1.0], [1.0, 1.0], [0.5, 0.0]],
        indices: vec![0, 1, 2, 0, 2, 3, 0, 3, 1],
        material: Some(material),
    }
}

/// Levels halving from `w` x `h` (rounding up), values shrinking with the level so the
/// finest level dominates the fallback image.
fn levels(rng: &mut ChaCha8Rng, w: u32, h: u32, channels: u32, count: usize) -> Vec<TextureLevel> {
    let (mut w, mut h) = (w, h);
    let mut out = Vec::new();
    for l in 0..count {
        let scale = 1.0 / (1u32 << l) as f32;
        let n = (w * h * channels) as usize;
        let data = (0..n)
            .map(|_| (rng.random::<f32>() * 1.2 - 0.1) * scale)
            .collect();
        out.push(TextureLevel {
            width: w,
            height: h,
            channels,
            data,
        });
        w = w.div_ceil(2);
        h = h.div_ceil(2);
    }
    out
}

fn tensors(rng: &mut ChaCha8Rng, r: &Renderer) -> Res<BTreeMap<String, TensorF32>> {
    let mut out = BTreeMap::new();
    for (name, shape) in architecture_tensors(r)? {
        let n: usize = shape.iter().map(|&d| d as usize).product();
        let fan_in: usize = shape
            .iter()
            .skip(1)
            .map(|&d| d as usize)
            .product::<usize>()
            .max(1);
        let s = 1.0 / (fan_in as f32).sqrt();
        let data = (0..n)
            .map(|_| (rng.random::<f32>() * 2.0 - 1.0) * s)
            .collect();
        out.insert(name, TensorF32::new(shape, data)?);
    }
    Ok(out)
}

struct One {
    channels: u32,
    levels: usize,
    size: (u32, u32),
    wrap: (WrapMode, WrapMode),
    sh: Option<ViewDependence>,
    compression: LevelCompression,
    /// Per level storage (revision 1.1 quantised PNG); empty for EXR.
    storage: Vec<LevelStorage>,
    renderer: Renderer,
    dtype: DType,
}

/// A one-quad asset with one texture, one renderer and the quad bound to them (with its
/// unlit fallback material).
fn single(seed: u64, o: One) -> Res<Container> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut b = AssetBuilder::new();
    let t = b.add_neural_texture(NeuralTextureDesc {
        levels: levels(&mut rng, o.size.0, o.size.1, o.channels, o.levels),
        wrap_s: o.wrap.0,
        wrap_t: o.wrap.1,
        view_dependence: o.sh,
        compression: o.compression,
        storage: o.storage,
    });
    let tensors = tensors(&mut rng, &o.renderer)?;
    let r = b.add_renderer(RendererDesc {
        renderer: o.renderer,
        tensors,
        dtype: o.dtype,
        tensor_dtypes: Default::default(),
    });
    let m = b.add_material(MaterialDesc {
        name: Some("neural".into()),
        neural_texture: t,
        renderer: r,
    });
    let mesh = b.add_mesh(Some("quad".into()), vec![quad(1.0, 0.0, m)]);
    b.add_node(Node {
        name: Some("quad".into()),
        mesh: Some(mesh),
        ..Node::default()
    });
    Ok(b.build_container()?)
}

fn one(channels: u32, renderer: Renderer) -> One {
    One {
        channels,
        levels: 2,
        size: (8, 8),
        wrap: (WrapMode::Repeat, WrapMode::Repeat),
        sh: None,
        compression: LevelCompression::Zip,
        storage: Vec::new(),
        renderer,
        dtype: DType::F16,
    }
}

fn quat(axis: [f32; 3], degrees: f32) -> [f32; 4] {
    let n = (axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]).sqrt();
    let (s, c) = (degrees.to_radians() / 2.0).sin_cos();
    [axis[0] / n * s, axis[1] / n * s, axis[2] / n * s, c]
}

/// Two nodes (one child, rotated and scaled), a two-primitive mesh and a second mesh, two
/// bindings with different textures (one with degree-3 SH) and renderers, each with its own
/// fallback material.
fn scene(seed: u64) -> Res<Container> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut b = AssetBuilder::new();
    let t0 = b.add_neural_texture(NeuralTextureDesc {
        levels: levels(&mut rng, 16, 12, 4, 2),
        wrap_s: WrapMode::ClampToEdge,
        wrap_t: WrapMode::MirroredRepeat,
        view_dependence: None,
        compression: LevelCompression::Rle,
        storage: Vec::new(),
    });
    let t1 = b.add_neural_texture(NeuralTextureDesc {
        levels: levels(&mut rng, 9, 7, 19, 2),
        wrap_s: WrapMode::MirroredRepeat,
        wrap_t: WrapMode::Repeat,
        view_dependence: Some(ViewDependence::spherical_harmonics(3, 3)),
        compression: LevelCompression::Piz,
        storage: Vec::new(),
    });
    let r0 = Renderer::new(dnr_format::model::Architecture::None, 4, 3);
    let r0 = b.add_renderer(RendererDesc {
        tensors: tensors(&mut rng, &r0)?,
        renderer: r0,
        dtype: DType::F16,
        tensor_dtypes: Default::default(),
    });
    let r1 = Renderer::mlp(19, 4, vec![6]);
    let r1 = b.add_renderer(RendererDesc {
        tensors: tensors(&mut rng, &r1)?,
        renderer: r1,
        dtype: DType::F32,
        tensor_dtypes: Default::default(),
    });
    let m0 = b.add_material(MaterialDesc {
        name: Some("plain".into()),
        neural_texture: t0,
        renderer: r0,
    });
    let m1 = b.add_material(MaterialDesc {
        name: Some("view-dependent".into()),
        neural_texture: t1,
        renderer: r1,
    });
    let two = b.add_mesh(
        Some("two-primitives".into()),
        vec![quad(1.0, 0.0, m0), quad(0.5, 0.25, m1)],
    );
    let pyr = b.add_mesh(Some("pyramid".into()), vec![pyramid(m1)]);
    let child = b.add_node(Node {
        name: Some("child".into()),
        mesh: Some(pyr),
        translation: [0.0, 0.0, 0.75],
        rotation: quat([1.0, 1.0, 0.0], 35.0),
        scale: [0.5, 0.75, 1.25],
        ..Node::default()
    });
    b.add_node(Node {
        name: Some("parent".into()),
        mesh: Some(two),
        translation: [1.0, -0.5, 0.25],
        rotation: quat([0.0, 1.0, 0.0], 30.0),
        scale: [2.0, 2.0, 2.0],
        children: vec![child],
    });
    b.add_node(Node {
        name: Some("second".into()),
        mesh: Some(two),
        translation: [-1.5, 0.0, 0.0],
        ..Node::default()
    });
    Ok(b.build_container()?)
}

// ---------------------------------------------------------------------------------------
// Revision 1.3: supersampled renderers

/// A five-pointed star in the z = 0 plane (outer radius 0.5, inner 0.2) as a fan of 10
/// triangles: diagonal silhouettes and tips thinner than a pixel, where the pixel-centre
/// sample aliases. Planar uv, so the texture runs on undistorted across the inner edges.
/// Turned 7.5 degrees: no edge is axis-aligned, and no pixel centre or subsample (s = 2, 3)
/// of the reference cameras lies within 1/3000 pixel of the silhouette, so rasterisers
/// agree on every sample's coverage.
fn star(material: usize) -> Primitive {
    let mut positions = vec![[0.0f32, 0.0, 0.0]];
    for k in 0..10 {
        let r = if k % 2 == 0 { 0.5 } else { 0.2 };
        // f64 trigonometry rounded to f32: libms that differ in f64's last place still
        // give the same vertices.
        let (sin, cos) = (97.5 + 36.0 * k as f64).to_radians().sin_cos();
        positions.push([(r * cos) as f32, (r * sin) as f32, 0.0]);
    }
    Primitive {
        normals: Some(vec![[0.0, 0.0, 1.0]; positions.len()]),
        tex_coords: positions.iter().map(|p| [p[0] + 0.5, 0.5 - p[1]]).collect(),
        indices: (0..10u32)
            .flat_map(|k| [0, 1 + k, 1 + (k + 1) % 10])
            .collect(),
        positions,
        material: Some(material),
    }
}

/// Two levels, `w x h` then half that, of `channels` channels. Level 0's channels 0..3 hold
/// a zone plate (concentric rings whose frequency grows to one cycle per two texels at the
/// rim, phase-shifted per channel): detail near pixel scale in the reference views, where
/// the pixel-centre sample makes moiré and the subsample mean greys it out. Channel 3 is 1
/// on level 0 (the opacity the supersample U-Net reads); the others ramp gently across the
/// texture. Level 1 adds a small smooth tint. Smooth values, not noise, keep the files small.
fn zone_plate_levels(w: u32, h: u32, channels: u32) -> Vec<TextureLevel> {
    let level = |w: u32, h: u32, f: &dyn Fn(f64, f64, u32) -> f64| {
        let mut data = Vec::with_capacity((w * h * channels) as usize);
        for y in 0..h {
            for x in 0..w {
                // Texel centre in 0..1.
                let (u, v) = ((x as f64 + 0.5) / w as f64, (y as f64 + 0.5) / h as f64);
                data.extend((0..channels).map(|c| f(u, v, c) as f32));
            }
        }
        TextureLevel {
            width: w,
            height: h,
            channels,
            data,
        }
    };
    let r_max = w.min(h) as f64 / 2.0;
    let fine = level(w, h, &|u, v, c| {
        let (dx, dy) = ((u - 0.5) * w as f64, (v - 0.5) * h as f64);
        // Local frequency r / (2 r_max) cycles per texel at r texels from the centre.
        let phase = std::f64::consts::PI * (dx * dx + dy * dy) / (2.0 * r_max);
        match c {
            0..=2 => 0.5 + 0.5 * (phase + 2.1 * c as f64).cos(),
            3 => 1.0,
            _ if c % 2 == 0 => 0.6 + 0.4 * u,
            _ => 1.0 - 0.4 * v,
        }
    });
    let coarse = level(w.div_ceil(2), h.div_ceil(2), &|u, v, c| match c {
        3 => 0.0,
        _ => 0.1 * (u - v) * if c % 2 == 0 { 1.0 } else { -1.0 },
    });
    vec![fine, coarse]
}

/// The star bound to one texture and one renderer (with its unlit fallback material).
fn star_asset(
    levels: Vec<TextureLevel>,
    sh: Option<ViewDependence>,
    renderer: Renderer,
    tensors: BTreeMap<String, TensorF32>,
    dtype: DType,
) -> Res<Container> {
    let mut b = AssetBuilder::new();
    let t = b.add_neural_texture(NeuralTextureDesc {
        levels,
        wrap_s: WrapMode::ClampToEdge,
        wrap_t: WrapMode::ClampToEdge,
        view_dependence: sh,
        compression: LevelCompression::Zip,
        storage: Vec::new(),
    });
    let r = b.add_renderer(RendererDesc {
        renderer,
        tensors,
        dtype,
        tensor_dtypes: Default::default(),
    });
    let m = b.add_material(MaterialDesc {
        name: Some("neural".into()),
        neural_texture: t,
        renderer: r,
    });
    let mesh = b.add_mesh(Some("star".into()), vec![star(m)]);
    b.add_node(Node {
        name: Some("star".into()),
        mesh: Some(mesh),
        ..Node::default()
    });
    Ok(b.build_container()?)
}

/// Index of `[j][k][ky][kx]` in a row-major `[_, n_k, 4, 4]` kernel.
fn k4(j: usize, k: usize, n_k: usize, ky: usize, kx: usize) -> usize {
    ((j * n_k + k) * 4 + ky) * 4 + kx
}

/// `unet` 8 -> [20, 8] -> 4 (transposedConv, instance norm) at `supersample` 2, 8 channels
/// (0..3 colour, 3 opacity, 4..8 SH degree 1). Random weights would give alpha near 0.5
/// everywhere and hide the silhouette, so the outer stage is designed: encoder.0 copies
/// each 2x2 block of the colour and opacity channels into 20 channels (space to depth: for
/// block offset (a, b), tap (1 + a, 1 + b) of the stride-2 4x4 kernel), opacity twice with
/// opposite signs so that LeakyReLU(z) - LeakyReLU(-z) = 1.2 z keeps it linear through the
/// instance norm; decoder.0's skip half puts each copy back at its offset (depth to space)
/// as colour and alpha. Alpha then follows the mean opacity of a pixel's subsamples: partial
/// at silhouettes with supersampling, 0 or 1 without. The SH channels tint the colour, and
/// small random weights everywhere else (the inner stage, the deep half of decoder.0) keep
/// it a generic network.
fn supersample_unet(rng: &mut ChaCha8Rng) -> Res<(Renderer, BTreeMap<String, TensorF32>)> {
    let (c, w0) = (8usize, 20usize);
    let r = Renderer {
        supersample: Some(2),
        ..Renderer::unet(
            c as u32,
            4,
            vec![w0 as u32, 8],
            Decoder::TransposedConv,
            Normalization::Instance,
        )
    };
    let mut t = tensors(rng, &r)?;
    for (name, scale) in [("encoder.0.weight", 0.05), ("decoder.0.weight", 0.1)] {
        if let Some(x) = t.get_mut(name) {
            x.data.iter_mut().for_each(|v| *v *= scale);
        }
    }
    // Gains and biases for the reference views' coverage (about 15 % of the frame): alpha
    // near 0 outside, near 1 inside; colour spread over most of 0..1.
    let (gain_colour, bias_colour, gain_alpha, bias_alpha) = (0.45, -1.0, 1.4, -1.6);
    for p in 0..4 {
        let (a, b) = (p / 2, p % 2);
        let base = p * 5;
        let e0 = &mut t.get_mut("encoder.0.weight").ok_or("encoder.0")?.data;
        for ch in 0..3 {
            e0[k4(base + ch, ch, c, 1 + a, 1 + b)] += 1.0;
            for sh in 4..8 {
                e0[k4(base + ch, sh, c, 1 + a, 1 + b)] += 0.4 * (rng.random::<f32>() * 2.0 - 1.0);
            }
        }
        e0[k4(base + 3, 3, c, 1 + a, 1 + b)] += 1.0;
        e0[k4(base + 4, 3, c, 1 + a, 1 + b)] -= 1.0;
        let d0 = &mut t.get_mut("decoder.0.weight").ok_or("decoder.0")?.data;
        for ch in 0..3 {
            d0[k4(w0 + base + ch, ch, 4, 1 + a, 1 + b)] += gain_colour;
        }
        d0[k4(w0 + base + 3, 3, 4, 1 + a, 1 + b)] += gain_alpha;
        d0[k4(w0 + base + 4, 3, 4, 1 + a, 1 + b)] -= gain_alpha;
    }
    let bias = &mut t.get_mut("decoder.0.bias").ok_or("decoder.0.bias")?.data;
    bias.copy_from_slice(&[bias_colour, bias_colour, bias_colour, bias_alpha]);
    Ok((r, t))
}

/// `mlp` 6 -> [8] -> 3 at `supersample` 3. A random MLP of this size saturates to one
/// colour and would hide the texture, so it is designed like [`supersample_unet`]: hidden
/// units 0..6 carry channels 0..3 with both signs (LeakyReLU(z) - LeakyReLU(-z) = 1.2 z), the
/// output maps them back to colour around 0.5, and units 6 and 7 and small random weights
/// mix in channels 3..6. Edge pixels, whose centre is covered but some of whose subsamples
/// are not (X = 0 there), darken in proportion.
fn supersample_mlp(rng: &mut ChaCha8Rng) -> Res<(Renderer, BTreeMap<String, TensorF32>)> {
    let r = Renderer {
        supersample: Some(3),
        ..Renderer::mlp(6, 3, vec![8])
    };
    let mut t = tensors(rng, &r)?;
    for x in t.values_mut() {
        x.data.iter_mut().for_each(|v| *v *= 0.1);
    }
    let gain = 1.6;
    let l0 = &mut t.get_mut("layers.0.weight").ok_or("layers.0")?.data;
    for ch in 0..3 {
        l0[ch * 6 + ch] += 1.0;
        l0[(3 + ch) * 6 + ch] -= 1.0;
        for unit in 6..8 {
            l0[unit * 6 + 3 + ch] += rng.random::<f32>() * 2.0 - 1.0;
        }
    }
    let l1 = &mut t.get_mut("layers.1.weight").ok_or("layers.1")?.data;
    for ch in 0..3 {
        l1[ch * 8 + ch] += gain;
        l1[ch * 8 + 3 + ch] -= gain;
        // Units 6 and 7 (random mixes of channels 3..6) tint each colour a little.
        l1[ch * 8 + 6] += 0.3 * (rng.random::<f32>() * 2.0 - 1.0);
        l1[ch * 8 + 7] += 0.3 * (rng.random::<f32>() * 2.0 - 1.0);
    }
    let b1 = &mut t.get_mut("layers.1.bias").ok_or("layers.1.bias")?.data;
    // 1.2 * gain * (x - 0.5): the zone plate's mid value to mid grey.
    b1.iter_mut().for_each(|b| *b -= 0.6 * gain);
    Ok((r, t))
}

// ---------------------------------------------------------------------------------------
// Mutations for invalid samples

fn glb(c: &Container) -> Res<Vec<u8>> {
    Ok(c.to_glb()?)
}

/// Edits the JSON (and optionally the BIN chunk) of a GLB and reassembles it.
fn edit(glb: &[u8], f: impl FnOnce(&mut Value, &mut Vec<u8>)) -> Res<Vec<u8>> {
    let g = parse_glb(glb, &Limits::default()).map_err(|p| p.error)?;
    let mut v: Value = serde_json::from_slice(g.json)?;
    let mut bin = g.bin.unwrap_or(&[]).to_vec();
    f(&mut v, &mut bin);
    Ok(glb_bytes(&serde_json::to_vec(&v)?, Some(&bin))?)
}

fn ext(v: &mut Value) -> &mut Value {
    &mut v["extensions"][EXTENSION_NAME]
}

/// The binding object on primitive 0 of mesh 0.
fn binding(v: &mut Value) -> &mut Value {
    &mut v["meshes"][0]["primitives"][0]["extensions"][EXTENSION_NAME]
}

fn as_usize(v: &Value) -> usize {
    v.as_u64().unwrap_or(0) as usize
}

/// Appends `bytes` to the BIN chunk and points bufferView `view` at them.
fn replace_view(v: &mut Value, bin: &mut Vec<u8>, view: usize, bytes: &[u8]) {
    bin.resize(bin.len().next_multiple_of(4), 0);
    let offset = bin.len();
    bin.extend_from_slice(bytes);
    bin.resize(bin.len().next_multiple_of(4), 0);
    v["bufferViews"][view]["byteOffset"] = json!(offset);
    v["bufferViews"][view]["byteLength"] = json!(bytes.len());
    v["buffers"][0]["byteLength"] = json!(bin.len());
}

/// Byte range of weight descriptor `w` of renderer 0 in the BIN chunk.
fn weight_range(v: &Value, w: usize) -> (usize, usize) {
    let d = &v["extensions"][EXTENSION_NAME]["renderers"][0]["weights"][w];
    let view = &v["bufferViews"][as_usize(&d["bufferView"])];
    let start = as_usize(&view["byteOffset"]) + as_usize(&d["byteOffset"]);
    let n: usize = d["shape"]
        .as_array()
        .map_or(0, |s| s.iter().map(as_usize).product());
    let size = if d["dtype"] == "f16" { 2 } else { 4 };
    (start, start + n * size)
}

/// An EXR level written with the `exr` crate directly, bypassing our encoder's checks.
fn raw_exr(
    w: usize,
    h: usize,
    channels: u32,
    compression: exr::compression::Compression,
    poison: bool,
) -> Res<Vec<u8>> {
    use exr::prelude::*;
    let mut list = SmallVec::<[AnyChannel<FlatSamples>; 4]>::new();
    for c in 0..channels {
        let mut plane: Vec<f16> = (0..w * h)
            .map(|i| f16::from_f32(((i as u32 + c) % 7) as f32 * 0.1))
            .collect();
        if poison && c == 0 {
            plane[w * h / 2] = f16::NAN;
        }
        list.push(AnyChannel::new(
            channel_name(c, channels).as_str(),
            FlatSamples::F16(plane),
        ));
    }
    let enc = Encoding {
        compression,
        blocks: Blocks::ScanLines,
        line_order: LineOrder::Increasing,
    };
    let image = Image::from_layer(Layer::new(
        (w, h),
        LayerAttributes::default(),
        enc,
        AnyChannels::sort(list),
    ));
    let mut out = std::io::Cursor::new(Vec::new());
    image.write().non_parallel().to_buffered(&mut out)?;
    Ok(out.into_inner())
}

/// A PNG of `w x h` pixels of `color` at `depth`, every sample 0.
fn raw_png(w: u32, h: u32, color: png::ColorType, depth: png::BitDepth) -> Res<Vec<u8>> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, w, h);
    enc.set_color(color);
    enc.set_depth(depth);
    let samples = color.samples()
        * if depth == png::BitDepth::Sixteen {
            2
        } else {
            1
        };
    let mut wr = enc.write_header()?;
    wr.write_image_data(&vec![0u8; w as usize * h as usize * samples])?;
    wr.finish()?;
    Ok(out)
}

/// Invalid samples of revisions 1.1 and 1.2's quantised storage, derived from the valid `q8`
/// (level 0 is 13x10, 6 channels: a 13x20 PNG), `int8` and `int4` samples.
fn quantised_invalid(w: &mut Writer<'_>, q8: &[u8], int8: &[u8], int4: &[u8]) -> Res<()> {
    let level = |v: &mut Value| -> Value { ext(v)["neuralTextures"][0]["levels"][0].clone() };
    let set_q = |v: &mut Value, key: &str, value: Value| {
        ext(v)["neuralTextures"][0]["levels"][0]["quantization"][key] = value;
    };
    let out = edit(q8, |v, _| {
        set_q(v, "scale", json!([0.0, 0.01, 0.01, 0.01, 0.01, 0.01]))
    })?;
    w.put(
        "invalid/quant_scale_zero.glb",
        &out,
        "revision 1.1: a quantised level's scale of channel 0 is 0",
        &["QUANT_SCALE_INVALID"],
    )?;
    // JSON has no NaN; a number beyond the f32 range reads as infinite.
    let out = edit(q8, |v, _| {
        set_q(v, "scale", json!([0.01, 1e39, 0.01, 0.01, 0.01, 0.01]))
    })?;
    w.put(
        "invalid/quant_scale_infinite.glb",
        &out,
        "revision 1.1: a quantised level's scale is 1e39, infinite in f32 (JSON cannot hold NaN)",
        &["QUANT_SCALE_INVALID"],
    )?;
    let out = edit(q8, |v, _| {
        set_q(v, "offset", json!([0.0, 0.0, 0.0, 0.0, 0.0]))
    })?;
    w.put(
        "invalid/quant_offset_length.glb",
        &out,
        "revision 1.1: a quantised level's offset has 5 entries for 6 channels",
        &["QUANT_ARRAY_LENGTH"],
    )?;
    let out = edit(q8, |v, _| set_q(v, "bits", json!(16)))?;
    w.put(
        "invalid/quant_bits_16.glb",
        &out,
        "revision 1.1: a quantised level declares 16 bits",
        &["QUANT_BITS"],
    )?;
    let out = edit(q8, |v, _| {
        if let Some(o) = ext(v)["neuralTextures"][0]["levels"][0].as_object_mut() {
            o.remove("quantization");
        }
    })?;
    w.put(
        "invalid/png_level_without_quantization.glb",
        &out,
        "revision 1.1: an image/png level without its quantization object",
        &["JSON_SCHEMA"],
    )?;
    let pngs: [(&str, Vec<u8>, &str, &'static str); 5] = [
        (
            "png_rgb",
            raw_png(13, 20, png::ColorType::Rgb, png::BitDepth::Eight)?,
            "the level's PNG is RGB (3 channels), not RGBA",
            "PNG_FORMAT",
        ),
        (
            "png_16bit",
            raw_png(13, 20, png::ColorType::Rgba, png::BitDepth::Sixteen)?,
            "the level's PNG is RGBA at 16 bits per sample",
            "PNG_FORMAT",
        ),
        (
            "png_size_mismatch",
            raw_png(13, 10, png::ColorType::Rgba, png::BitDepth::Eight)?,
            "the level's PNG is 13x10, 6 channels at 8 bits need 13x20",
            "PNG_SIZE_MISMATCH",
        ),
        (
            "png_truncated",
            {
                let good = raw_png(13, 20, png::ColorType::Rgba, png::BitDepth::Eight)?;
                good[..good.len() - 20].to_vec()
            },
            "the level's PNG is cut before its last chunks",
            "PNG_INVALID",
        ),
        (
            "png_not_png",
            b"\x89PNX not a PNG file at all".to_vec(),
            "the level's bytes do not start with the PNG signature",
            "PNG_INVALID",
        ),
    ];
    for (name, bytes, what, code) in pngs {
        let out = edit(q8, |v, bin| {
            let view = as_usize(&level(v)["bufferView"]);
            replace_view(v, bin, view, &bytes);
        })?;
        w.put(
            &format!("invalid/{name}.glb"),
            &out,
            &format!("revision 1.1: {what}"),
            &[code],
        )?;
    }
    // int8 and int4: replace the first row scale of the first tensor, with a matching CRC so
    // only the scale is wrong: 0, NaN, and f32::MAX (finite, but scale * q overflows).
    let set_row0_scale = |src: &[u8], value_bytes: fn(usize) -> usize, scale: f32| {
        edit(src, move |v, bin| {
            let d = ext(v)["renderers"][0]["weights"][0].clone();
            let view = &v["bufferViews"][as_usize(&d["bufferView"])];
            let start = as_usize(&view["byteOffset"]) + as_usize(&d["byteOffset"]);
            let n: usize = d["shape"]
                .as_array()
                .map_or(0, |s| s.iter().map(as_usize).product());
            let rows = d["shape"][0].as_u64().unwrap_or(1) as usize;
            let at = start + value_bytes(n).next_multiple_of(4);
            bin[at..at + 4].copy_from_slice(&scale.to_le_bytes());
            let crc = crc32fast::hash(&bin[start..at + 4 * rows]);
            ext(v)["renderers"][0]["weights"][0]["crc32"] = json!(crc);
        })
    };
    let bytes8: fn(usize) -> usize = |n| n;
    let bytes4: fn(usize) -> usize = |n| n.div_ceil(2);
    w.put(
        "invalid/int8_scale_zero.glb",
        &set_row0_scale(int8, bytes8, 0.0)?,
        "revision 1.1: an int8 tensor's first row scale is 0 (its CRC-32 matches)",
        &["WEIGHTS_SCALE_INVALID"],
    )?;
    w.put(
        "invalid/int8_scale_overflow.glb",
        &set_row0_scale(int8, bytes8, f32::MAX)?,
        "revision 1.1: an int8 tensor's first row scale is f32::MAX, so scale * q overflows (its CRC-32 matches)",
        &["WEIGHTS_NON_FINITE"],
    )?;
    w.put(
        "invalid/int4_scale_zero.glb",
        &set_row0_scale(int4, bytes4, 0.0)?,
        "revision 1.2: an int4 tensor's first row scale is 0 (its CRC-32 matches)",
        &["WEIGHTS_SCALE_INVALID"],
    )?;
    w.put(
        "invalid/int4_scale_nan.glb",
        &set_row0_scale(int4, bytes4, f32::NAN)?,
        "revision 1.2: an int4 tensor's first row scale is NaN (its CRC-32 matches)",
        &["WEIGHTS_SCALE_INVALID"],
    )?;
    w.put(
        "invalid/int4_scale_overflow.glb",
        &set_row0_scale(int4, bytes4, f32::MAX)?,
        "revision 1.2: an int4 tensor's first row scale is f32::MAX, so scale * q overflows (its CRC-32 matches)",
        &["WEIGHTS_NON_FINITE"],
    )?;
    // An int8 tensor's bytes read as int4: half the values, so the scales sit elsewhere and
    // the CRC-32 covers other bytes.
    let out = edit(int8, |v, _| {
        ext(v)["renderers"][0]["weights"][0]["dtype"] = json!("int4")
    })?;
    w.put(
        "invalid/int8_read_as_int4.glb",
        &out,
        "revision 1.2: an int8 tensor declared int4 (its bytes were written for int8: the CRC-32 covers fewer bytes and differs, and a scale read from the wrong bytes is not a finite positive float)",
        &["WEIGHTS_CHECKSUM_MISMATCH", "WEIGHTS_SCALE_INVALID"],
    )?;
    let out = edit(int8, |v, _| {
        ext(v)["renderers"][0]["weights"][0]["dtype"] = json!("int2")
    })?;
    w.put(
        "invalid/weights_dtype_int2.glb",
        &out,
        "a tensor's dtype is int2, which no revision defines",
        &["WEIGHTS_DTYPE_UNKNOWN"],
    )?;
    Ok(())
}

// ---------------------------------------------------------------------------------------

struct Writer<'a> {
    dir: &'a Path,
    samples: Vec<Sample>,
}

impl Writer<'_> {
    fn put(
        &mut self,
        path: &str,
        bytes: &[u8],
        description: &str,
        expected: &[&'static str],
    ) -> Res<()> {
        let full = self.dir.join(path);
        if let Some(parent) = full.parent() {
            fs::create_dir_all(parent)?;
        }
        fs::write(&full, bytes)?;
        self.samples.push(Sample {
            path: path.to_string(),
            description: description.to_string(),
            expected: expected.to_vec(),
        });
        Ok(())
    }
}

/// Writes every sample, `README.md` and `expected.json` under `dir`; returns the list.
pub fn generate(dir: &Path) -> Res<Vec<Sample>> {
    let mut w = Writer {
        dir,
        samples: Vec::new(),
    };
    use dnr_format::model::Architecture as A;
    use LevelCompression as LC;
    use WrapMode as WM;

    // ---- valid
    let none = single(
        1,
        One {
            levels: 1,
            size: (8, 8),
            compression: LC::None,
            ..one(3, Renderer::new(A::None, 3, 3))
        },
    )?;
    w.put(
        "valid/none_1level.glb",
        &glb(&none)?,
        "architecture none, 3 channels, 1 level 8x8, REPEAT, EXR NONE",
        &[],
    )?;

    let none_sh = single(
        2,
        One {
            levels: 2,
            size: (13, 11),
            wrap: (WM::ClampToEdge, WM::ClampToEdge),
            sh: Some(ViewDependence::spherical_harmonics(1, 3)),
            compression: LC::Rle,
            ..one(7, Renderer::new(A::None, 7, 3))
        },
    )?;
    w.put("valid/none_sh1_clamp.glb", &glb(&none_sh)?, "none reading 7 channels, SH degree 1 on channels 3..7, 2 odd-sized levels 13x11, CLAMP_TO_EDGE, EXR RLE", &[])?;

    let mlp16 = single(
        3,
        One {
            wrap: (WM::MirroredRepeat, WM::MirroredRepeat),
            compression: LC::Zips,
            ..one(6, Renderer::mlp(6, 3, vec![8]))
        },
    )?;
    w.put(
        "valid/mlp_f16_2levels.glb",
        &glb(&mlp16)?,
        "mlp hidden [8], 6 channels, 2 levels 8x8, f16 weights, MIRRORED_REPEAT, EXR ZIPS",
        &[],
    )?;

    let mlp32 = single(
        4,
        One {
            levels: 4,
            size: (33, 17),
            sh: Some(ViewDependence::spherical_harmonics(2, 3)),
            compression: LC::Zip,
            dtype: DType::F32,
            ..one(12, Renderer::mlp(12, 4, vec![8, 8]))
        },
    )?;
    w.put("valid/mlp_f32_sh2_4levels.glb", &glb(&mlp32)?, "mlp hidden [8, 8], RGBA output, SH degree 2 on channels 3..12, 4 levels from 33x17, f32 weights, EXR ZIP", &[])?;

    let mlp0 = single(
        5,
        One {
            levels: 1,
            size: (5, 3),
            wrap: (WM::Repeat, WM::ClampToEdge),
            compression: LC::Piz,
            ..one(4, Renderer::mlp(4, 3, vec![]))
        },
    )?;
    w.put("valid/mlp_linear.gltf", &mlp0.to_gltf_embedded()?, "mlp without hidden layers, .gltf with an embedded data: URI buffer, 1 level 5x3, REPEAT/CLAMP_TO_EDGE, EXR PIZ", &[])?;

    let unet_t = single(
        6,
        One {
            size: (31, 29),
            compression: LC::Zip,
            ..one(
                8,
                Renderer::unet(
                    8,
                    4,
                    vec![4, 8],
                    Decoder::TransposedConv,
                    Normalization::Instance,
                ),
            )
        },
    )?;
    w.put(
        "valid/unet_transposed_instance_f16.glb",
        &glb(&unet_t)?,
        "unet widths [4, 8], transposedConv, instance norm, RGBA, 2 levels from 31x29, f16",
        &[],
    )?;

    let unet_u = single(
        7,
        One {
            levels: 1,
            size: (16, 16),
            sh: Some(ViewDependence::spherical_harmonics(0, 7)),
            dtype: DType::F32,
            ..one(
                8,
                Renderer::unet(8, 3, vec![4, 8], Decoder::UpsampleConv, Normalization::None),
            )
        },
    )?;
    w.put("valid/unet_upsample_none_f32.glb", &glb(&unet_u)?, "unet widths [4, 8], upsampleConv, no norm, RGB, SH degree 0 on channel 7, 1 level 16x16, f32", &[])?;

    let unet_1 = single(
        8,
        One {
            levels: 4,
            size: (20, 20),
            wrap: (WM::MirroredRepeat, WM::Repeat),
            ..one(
                4,
                Renderer::unet(4, 3, vec![4], Decoder::TransposedConv, Normalization::None),
            )
        },
    )?;
    let dir_valid = dir.join("valid");
    fs::create_dir_all(&dir_valid)?;
    unet_1.write_gltf_external(&dir_valid.join("unet_depth1_external.gltf"))?;
    w.samples.push(Sample {
        path: "valid/unet_depth1_external.gltf".into(),
        description: "unet of depth 1 (no skip connections), .gltf with external unet_depth1_external.bin, 4 levels from 20x20".into(),
        expected: vec![],
    });

    // ---- revision 1.1: quantised storage
    let q8 = single(
        11,
        One {
            levels: 2,
            size: (13, 10),
            compression: LC::Zip,
            storage: vec![LevelStorage::Q8, LevelStorage::Q8],
            ..one(6, Renderer::mlp(6, 3, vec![8]))
        },
    )?;
    w.put("valid/mlp_q8_levels.glb", &glb(&q8)?, "revision 1.1: 2 levels from 13x10 as 8-bit quantised PNG (6 channels: 2 groups, the second half empty), mlp hidden [8], f16 weights", &[])?;

    let q4 = single(
        12,
        One {
            levels: 3,
            size: (15, 9),
            sh: Some(ViewDependence::spherical_harmonics(1, 3)),
            compression: LC::Zip,
            storage: vec![LevelStorage::Q4, LevelStorage::Q4],
            ..one(11, Renderer::mlp(11, 3, vec![8]))
        },
    )?;
    w.put("valid/mlp_q4_levels.glb", &glb(&q4)?, "revision 1.1: 3 levels from 15x9, the first two 4-bit quantised PNG (11 channels: 2 groups of 8, two per byte), the third EXR ZIP, SH degree 1, mlp hidden [8]", &[])?;

    let int8 = single(
        13,
        One {
            size: (20, 18),
            compression: LC::Zip,
            dtype: DType::Int8,
            ..one(
                8,
                Renderer::unet(
                    8,
                    4,
                    vec![4, 8],
                    Decoder::TransposedConv,
                    Normalization::Instance,
                ),
            )
        },
    )?;
    w.put("valid/unet_int8_weights.glb", &glb(&int8)?, "revision 1.1: unet widths [4, 8], transposedConv, instance norm, int8 weights with per-row f32 scales (biases f16), 2 EXR levels from 20x18", &[])?;

    // 11 input channels and 7 hidden: rows of 11 nibbles start mid-byte, and the first
    // tensor's 77 values leave the last byte's high nibble empty.
    let int4 = single(
        14,
        One {
            size: (12, 10),
            compression: LC::Zip,
            dtype: DType::Int4,
            ..one(11, Renderer::mlp(11, 4, vec![7]))
        },
    )?;
    w.put("valid/mlp_int4_weights.glb", &glb(&int4)?, "revision 1.2: mlp 11 -> [7] -> 4, int4 weights with per-row f32 scales (rows of 11 nibbles; 77 and 28 values; biases f16), 2 EXR levels from 12x10", &[])?;

    let sc = scene(9)?;
    w.put("valid/scene_multi_primitive.glb", &glb(&sc)?, "3 nodes (child with rotation + non-uniform scale), a 2-primitive mesh instanced twice, a pyramid without normals, primitives bound to 2 textures/renderers (none; mlp with SH degree 3, 19 channels, f32), CLAMP_TO_EDGE/MIRRORED_REPEAT, EXR RLE and PIZ", &[])?;

    // ---- revision 1.3: supersampled features
    let mut rng = ChaCha8Rng::seed_from_u64(15);
    let lv = zone_plate_levels(64, 64, 8);
    let (r, t) = supersample_unet(&mut rng)?;
    let ss2 = star_asset(
        lv,
        Some(ViewDependence::spherical_harmonics(1, 4)),
        r,
        t,
        DType::F16,
    )?;
    w.put("valid/unet_supersample2.glb", &glb(&ss2)?, "revision 1.3: unet widths [20, 8] at supersample 2, transposedConv, instance norm, RGBA, SH degree 1 on channels 4..8, f16; a star (diagonal silhouettes, sub-pixel tips) with a zone-plate texture (2 levels from 64x64) and weights designed so that alpha follows the subsamples' mean opacity", &[])?;

    let mut rng = ChaCha8Rng::seed_from_u64(16);
    let lv = zone_plate_levels(56, 56, 6);
    let (r, t) = supersample_mlp(&mut rng)?;
    let ss3 = star_asset(lv, None, r, t, DType::F16)?;
    w.put("valid/mlp_supersample3.glb", &glb(&ss3)?, "revision 1.3: mlp hidden [8] at supersample 3 (9 subsamples, one at the pixel centre), RGB, f16; the star with a zone-plate texture (2 levels from 56x56)", &[])?;

    // ---- invalid, derived from the valid ones
    let base = glb(&mlp16)?;
    let half = &base[..base.len() / 2];
    w.put(
        "invalid/truncated.glb",
        half,
        "GLB cut to half its length",
        &["GLB_TRUNCATED"],
    )?;
    let mut bad = base.clone();
    bad[0] = b'x';
    w.put(
        "invalid/bad_magic.glb",
        &bad,
        "GLB magic is not glTF",
        &["GLB_INVALID_HEADER"],
    )?;
    let mut bad = base.clone();
    bad[4] = 3;
    w.put(
        "invalid/glb_version_3.glb",
        &bad,
        "GLB container version 3",
        &["GLB_INVALID_HEADER"],
    )?;
    let mut bad = base.clone();
    bad[16..20].copy_from_slice(&0x004E_4942u32.to_le_bytes());
    w.put(
        "invalid/glb_first_chunk_bin.glb",
        &bad,
        "first chunk typed BIN instead of JSON",
        &["GLB_CHUNK_INVALID"],
    )?;
    let mut bad = base.clone();
    bad[20] = b'[';
    w.put(
        "invalid/json_syntax.glb",
        &bad,
        "JSON chunk starts with `[` where `{` was: not well-formed",
        &["JSON_INVALID"],
    )?;

    let json_schema = edit(&base, |v, _| {
        ext(v)["neuralTextures"][0]["levels"][0]["width"] = json!("eight")
    })?;
    w.put(
        "invalid/level_width_string.glb",
        &json_schema,
        "a level's width is a string",
        &["JSON_SCHEMA"],
    )?;

    let out = edit(&base, |v, _| {
        let len = as_usize(&v["buffers"][0]["byteLength"]);
        v["bufferViews"][0]["byteLength"] = json!(len + 64);
    })?;
    w.put(
        "invalid/buffer_view_out_of_range.glb",
        &out,
        "bufferView 0 reaches 64 bytes past the buffer",
        &["BUFFER_VIEW_OUT_OF_RANGE"],
    )?;

    let out = edit(&base, |v, _| {
        v["meshes"][0]["primitives"][0]["attributes"]["POSITION"] = json!(99)
    })?;
    w.put("invalid/position_accessor_index.glb", &out, "POSITION refers to accessor 99 (fuzz regression: gltf-json 1.4's validator indexes it unchecked)", &["INDEX_OUT_OF_RANGE"])?;

    let out = edit(&base, |v, _| binding(v)["neuralTexture"] = json!(5))?;
    w.put(
        "invalid/primitive_texture_index.glb",
        &out,
        "the primitive's binding refers to neural texture 5 of 1",
        &["INDEX_OUT_OF_RANGE"],
    )?;

    let out = edit(&base, |v, _| binding(v)["renderer"] = json!(3))?;
    w.put(
        "invalid/primitive_renderer_index.glb",
        &out,
        "the primitive's binding refers to renderer 3 of 1",
        &["INDEX_OUT_OF_RANGE"],
    )?;

    let out = edit(&base, |v, _| binding(v)["neuralTexture"] = json!("zero"))?;
    w.put(
        "invalid/binding_texture_string.glb",
        &out,
        "the primitive's binding has a string neuralTexture",
        &["JSON_SCHEMA"],
    )?;

    let out = edit(&base, |v, _| {
        if let Some(o) = v.as_object_mut() {
            o.remove("extensions");
        }
    })?;
    w.put(
        "invalid/binding_without_root.glb",
        &out,
        "a primitive carries a binding but the root extension object is gone",
        &["JSON_SCHEMA"],
    )?;

    let out = edit(&base, |v, _| {
        let view = as_usize(&ext(v)["neuralTextures"][0]["levels"][0]["bufferView"]);
        let len = as_usize(&v["bufferViews"][view]["byteLength"]);
        v["bufferViews"][view]["byteLength"] = json!(len / 2);
    })?;
    w.put(
        "invalid/exr_truncated.glb",
        &out,
        "level 0's bufferView holds only the first half of its EXR file",
        &["EXR_INVALID"],
    )?;

    let exr5 = encode_level(&TextureLevel::zeros(8, 8, 5), 0, LC::Zip)?;
    let out = edit(&base, |v, bin| {
        let view = as_usize(&ext(v)["neuralTextures"][0]["levels"][0]["bufferView"]);
        replace_view(v, bin, view, &exr5);
    })?;
    w.put(
        "invalid/exr_channel_count.glb",
        &out,
        "level 0's EXR has 5 channels, the texture declares 6",
        &["EXR_CHANNELS"],
    )?;

    let exr_b44 = raw_exr(8, 8, 6, exr::compression::Compression::B44, false)?;
    let out = edit(&base, |v, bin| {
        let view = as_usize(&ext(v)["neuralTextures"][0]["levels"][0]["bufferView"]);
        replace_view(v, bin, view, &exr_b44);
    })?;
    w.put(
        "invalid/exr_lossy_b44.glb",
        &out,
        "level 0's EXR uses lossy B44 compression",
        &["EXR_COMPRESSION"],
    )?;

    let exr_nan = raw_exr(8, 8, 6, exr::compression::Compression::ZIP16, true)?;
    let out = edit(&base, |v, bin| {
        let view = as_usize(&ext(v)["neuralTextures"][0]["levels"][0]["bufferView"]);
        replace_view(v, bin, view, &exr_nan);
    })?;
    w.put(
        "invalid/exr_nan.glb",
        &out,
        "level 0's EXR holds a NaN half",
        &["EXR_NON_FINITE"],
    )?;

    let out = edit(&base, |v, _| {
        ext(v)["neuralTextures"][0]["levels"][1]["height"] = json!(5)
    })?;
    w.put(
        "invalid/exr_size_mismatch.glb",
        &out,
        "level 1 declares 4x5, its EXR is 4x4",
        &["EXR_SIZE_MISMATCH"],
    )?;

    let out = edit(&base, |v, _| {
        ext(v)["neuralTextures"][0]["levels"] = json!([])
    })?;
    w.put(
        "invalid/texture_no_levels.glb",
        &out,
        "neural texture with an empty levels array",
        &["TEXTURE_NO_LEVELS"],
    )?;

    let out = edit(&base, |v, _| {
        // Revision 1.1 defines image/png (with quantization); webp is in no revision.
        ext(v)["neuralTextures"][0]["levels"][0]["mimeType"] = json!("image/webp")
    })?;
    w.put(
        "invalid/texture_mime_type.glb",
        &out,
        "level mimeType image/webp (no revision defines it)",
        &["TEXTURE_MIME_TYPE"],
    )?;

    let out = edit(&base, |v, _| {
        ext(v)["neuralTextures"][0]["channels"] = json!(0)
    })?;
    w.put(
        "invalid/texture_zero_channels.glb",
        &out,
        "texture declares 0 channels (so it also mismatches the renderer)",
        &["TEXTURE_CHANNELS_RANGE", "RENDERER_INPUT_MISMATCH"],
    )?;
    let out = edit(&base, |v, _| {
        ext(v)["neuralTextures"][0]["channels"] = json!(2)
    })?;
    w.put(
        "invalid/texture_channels_2.glb",
        &out,
        "texture declares 2 channels, below the minimum 3 (so it also mismatches the renderer)",
        &["TEXTURE_CHANNELS_RANGE", "RENDERER_INPUT_MISMATCH"],
    )?;
    let out = edit(&base, |v, _| {
        ext(v)["neuralTextures"][0]["channels"] = json!(1025)
    })?;
    w.put(
        "invalid/texture_channels_1025.glb",
        &out,
        "texture declares 1025 channels, above the maximum 1024: a range error, not LIMIT_EXCEEDED (so it also mismatches the renderer)",
        &["TEXTURE_CHANNELS_RANGE", "RENDERER_INPUT_MISMATCH"],
    )?;

    let out = edit(&base, |v, _| {
        ext(v)["neuralTextures"][0]["levels"][0]["width"] = json!(100000)
    })?;
    w.put(
        "invalid/limit_texture_side.glb",
        &out,
        "level 0 declares width 100000, above the default side limit 16384",
        &["LIMIT_EXCEEDED"],
    )?;

    let sh_base = glb(&none_sh)?;
    let out = edit(&sh_base, |v, _| {
        ext(v)["neuralTextures"][0]["viewDependence"]["degree"] = json!(4)
    })?;
    w.put(
        "invalid/sh_degree_4.glb",
        &out,
        "SH degree 4",
        &["SH_DEGREE_UNSUPPORTED"],
    )?;
    let out = edit(&sh_base, |v, _| {
        ext(v)["neuralTextures"][0]["viewDependence"]["firstChannel"] = json!(4)
    })?;
    w.put(
        "invalid/sh_channels_out_of_range.glb",
        &out,
        "SH degree 1 from channel 4 needs channels 4..8 of 7",
        &["SH_CHANNELS_OUT_OF_RANGE"],
    )?;

    let out = edit(&base, |v, _| {
        ext(v)["renderers"][0]["architecture"] = json!("transformer")
    })?;
    w.put(
        "invalid/unknown_architecture.glb",
        &out,
        "architecture `transformer`",
        &["RENDERER_UNKNOWN_ARCHITECTURE"],
    )?;

    let unet_base = glb(&unet_t)?;
    let out = edit(&unet_base, |v, _| {
        ext(v)["renderers"][0]["decoder"] = json!("pixelShuffle")
    })?;
    w.put(
        "invalid/unet_unknown_decoder.glb",
        &out,
        "unet decoder `pixelShuffle`",
        &["RENDERER_PARAMETER_INVALID"],
    )?;
    let out = edit(&unet_base, |v, _| {
        ext(v)["renderers"][0]["widths"] = json!([])
    })?;
    w.put(
        "invalid/unet_no_widths.glb",
        &out,
        "unet with empty widths",
        &["RENDERER_PARAMETER_INVALID"],
    )?;

    let out = edit(&glb(&none)?, |v, _| {
        ext(v)["renderers"][0]["outputChannels"] = json!(4)
    })?;
    w.put(
        "invalid/none_output_channels_4.glb",
        &out,
        "architecture none with outputChannels 4 (none has no alpha output: it requires 3)",
        &["RENDERER_OUTPUT_CHANNELS"],
    )?;

    let out = edit(&base, |v, _| {
        ext(v)["renderers"][0]["outputChannels"] = json!(5)
    })?;
    w.put(
        "invalid/output_channels_5.glb",
        &out,
        "outputChannels 5",
        &["RENDERER_OUTPUT_CHANNELS"],
    )?;

    let out = edit(&base, |v, _| {
        ext(v)["renderers"][0]["inputChannels"] = json!(5)
    })?;
    w.put(
        "invalid/renderer_input_mismatch.glb",
        &out,
        "renderer takes 5 channels, texture has 6 (so layers.0.weight has the wrong shape too)",
        &["RENDERER_INPUT_MISMATCH", "WEIGHTS_SHAPE_MISMATCH"],
    )?;

    let out = edit(&base, |v, _| {
        if let Some(a) = ext(v)["renderers"][0]["weights"].as_array_mut() {
            a.remove(1);
        }
    })?;
    w.put(
        "invalid/weights_missing.glb",
        &out,
        "descriptor of layers.0.bias removed",
        &["WEIGHTS_MISSING"],
    )?;

    let out = edit(&base, |v, _| {
        let mut extra = ext(v)["renderers"][0]["weights"][1].clone();
        extra["name"] = json!("layers.9.bias");
        if let Some(a) = ext(v)["renderers"][0]["weights"].as_array_mut() {
            a.push(extra);
        }
    })?;
    w.put(
        "invalid/weights_unexpected.glb",
        &out,
        "an extra tensor layers.9.bias",
        &["WEIGHTS_UNEXPECTED"],
    )?;

    let out = edit(&base, |v, _| {
        ext(v)["renderers"][0]["weights"][1]["shape"] = json!([2, 4])
    })?;
    w.put(
        "invalid/weights_shape_mismatch.glb",
        &out,
        "layers.0.bias declared [2, 4] instead of [8] (same byte count)",
        &["WEIGHTS_SHAPE_MISMATCH"],
    )?;

    let out = edit(&base, |v, _| {
        ext(v)["renderers"][0]["weights"][0]["dtype"] = json!("bf16")
    })?;
    w.put(
        "invalid/weights_dtype_bf16.glb",
        &out,
        "dtype bf16",
        &["WEIGHTS_DTYPE_UNKNOWN"],
    )?;

    let out = edit(&base, |v, bin| {
        // Shift layers.0.bias by 2 bytes and fix its checksum, so only the alignment is wrong.
        let off = as_usize(&ext(v)["renderers"][0]["weights"][1]["byteOffset"]);
        ext(v)["renderers"][0]["weights"][1]["byteOffset"] = json!(off + 2);
        let (s, e) = weight_range(v, 1);
        let crc = crc32fast::hash(&bin[s..e]);
        ext(v)["renderers"][0]["weights"][1]["crc32"] = json!(crc);
    })?;
    w.put(
        "invalid/weights_misaligned.glb",
        &out,
        "layers.0.bias at byteOffset + 2 (checksum matching the shifted bytes)",
        &["WEIGHTS_MISALIGNED"],
    )?;

    let out = edit(&base, |v, _| {
        let crc = ext(v)["renderers"][0]["weights"][2]["crc32"]
            .as_u64()
            .unwrap_or(0);
        ext(v)["renderers"][0]["weights"][2]["crc32"] = json!(crc ^ 1);
    })?;
    w.put(
        "invalid/weights_checksum.glb",
        &out,
        "crc32 of layers.1.weight off by one bit",
        &["WEIGHTS_CHECKSUM_MISMATCH"],
    )?;

    let out = edit(&base, |v, bin| {
        let (s, e) = weight_range(v, 0);
        bin[s..s + 2].copy_from_slice(&half::f16::NAN.to_le_bytes());
        let crc = crc32fast::hash(&bin[s..e]);
        ext(v)["renderers"][0]["weights"][0]["crc32"] = json!(crc);
    })?;
    w.put(
        "invalid/weights_nan.glb",
        &out,
        "layers.0.weight holds a NaN (checksum updated)",
        &["WEIGHTS_NON_FINITE"],
    )?;

    let out = edit(&base, |v, _| {
        ext(v)["renderers"][0]["weights"][0]["byteOffset"] = json!(1 << 20)
    })?;
    w.put(
        "invalid/weights_past_view.glb",
        &out,
        "layers.0.weight starts 1 MiB into a small bufferView",
        &["BUFFER_VIEW_OUT_OF_RANGE"],
    )?;

    let out = edit(&base, |v, _| {
        v["extensionsRequired"] = json!([EXTENSION_NAME]);
        if let Some(p) = v["materials"][0]["pbrMetallicRoughness"].as_object_mut() {
            p.remove("baseColorTexture");
        }
    })?;
    w.put(
        "invalid/required_without_fallback.glb",
        &out,
        "extension in extensionsRequired and the fallback material has no baseColorTexture",
        &["EXTENSION_REQUIRED", "FALLBACK_MISSING"],
    )?;

    let out = edit(&base, |v, _| {
        if let Some(o) = v["materials"][0].as_object_mut() {
            o.remove("extensions");
        }
    })?;
    w.put(
        "invalid/fallback_no_unlit.glb",
        &out,
        "the bound primitive's material lacks KHR_materials_unlit",
        &["FALLBACK_MISSING"],
    )?;

    let out = edit(&base, |v, _| {
        if let Some(o) = v["meshes"][0]["primitives"][0].as_object_mut() {
            o.remove("material");
        }
    })?;
    w.put(
        "invalid/fallback_no_material.glb",
        &out,
        "the bound primitive has no material",
        &["FALLBACK_MISSING"],
    )?;

    let out = edit(&base, |v, _| {
        v["extensionsUsed"] = json!(["KHR_materials_unlit"])
    })?;
    w.put(
        "invalid/extension_not_used.glb",
        &out,
        "extension missing from extensionsUsed",
        &["EXTENSION_NOT_USED"],
    )?;

    let out = edit(&base, |v, _| ext(v)["version"] = json!(2))?;
    w.put(
        "invalid/version_2.glb",
        &out,
        "extension version 2",
        &["VERSION_UNSUPPORTED"],
    )?;

    let out = edit(&base, |v, _| binding(v)["texCoord"] = json!(1))?;
    w.put(
        "warnings/texcoord_missing.glb",
        &out,
        "the binding addresses TEXCOORD_1, the primitive has only TEXCOORD_0 (a warning: exit code 0)",
        &["TEXCOORD_MISSING"],
    )?;

    // Levels listed coarsest first: a warning only.
    let mut rng = ChaCha8Rng::seed_from_u64(10);
    let mut lv = levels(&mut rng, 8, 8, 3, 2);
    lv.reverse();
    let mut b = AssetBuilder::new();
    let t = b.add_neural_texture(NeuralTextureDesc {
        levels: lv,
        wrap_s: WM::Repeat,
        wrap_t: WM::Repeat,
        view_dependence: None,
        compression: LC::Zip,
        storage: Vec::new(),
    });
    let r = b.add_renderer(RendererDesc {
        renderer: Renderer::new(A::None, 3, 3),
        tensors: BTreeMap::new(),
        dtype: DType::F16,
        tensor_dtypes: Default::default(),
    });
    let m = b.add_material(MaterialDesc {
        name: None,
        neural_texture: t,
        renderer: r,
    });
    let mesh = b.add_mesh(None, vec![quad(1.0, 0.0, m)]);
    b.add_node(Node {
        mesh: Some(mesh),
        ..Node::default()
    });
    w.put(
        "warnings/levels_coarse_first.glb",
        &glb(&b.build_container()?)?,
        "levels listed 4x4 then 8x8 (a warning: exit code 0)",
        &["TEXTURE_LEVEL_ORDER"],
    )?;

    let mut gltf: Value = serde_json::from_slice(&mlp0.to_gltf_embedded()?)?;
    gltf["buffers"][0]["uri"] = json!("missing.bin");
    let mut text = serde_json::to_vec_pretty(&gltf)?;
    text.push(b'\n');
    w.put(
        "invalid/missing_external_buffer.gltf",
        &text,
        ".gltf whose buffer is an external file that does not exist",
        &["BUFFER_INVALID"],
    )?;

    quantised_invalid(&mut w, &glb(&q8)?, &glb(&int8)?, &glb(&int4)?)?;

    // From the small mlp sample rather than the supersampled ones: the check is the same.
    for (value, what) in [(0, "0, below the minimum 1"), (5, "5, above the maximum 4")] {
        let out = edit(&base, |v, _| {
            ext(v)["renderers"][0]["supersample"] = json!(value)
        })?;
        w.put(
            &format!("invalid/supersample_{value}.glb"),
            &out,
            &format!("revision 1.3: a renderer's supersample is {what}"),
            &["RENDERER_PARAMETER_INVALID"],
        )?;
    }

    write_index(dir, &w.samples)?;
    Ok(w.samples)
}

fn write_index(dir: &Path, samples: &[Sample]) -> Res<()> {
    let mut expected = serde_json::Map::new();
    for s in samples {
        expected.insert(s.path.clone(), json!(s.expected));
    }
    let mut text = serde_json::to_vec_pretty(&Value::Object(expected))?;
    text.push(b'\n');
    fs::write(dir.join("expected.json"), text)?;

    let mut md = String::from(
        "# Conformance samples\n\n\
         Generated by `cargo run -p dnr-format --example make_samples -- samples` (deterministic,\n\
         fixed seeds); do not edit by hand. `tests/conformance.rs` regenerates them and fails if\n\
         these files differ. `expected.json` maps each file to the exact set of validator codes it\n\
         must produce (`[]` for valid files, which must also have no warnings and round-trip\n\
         byte-identically). `dnr validate` exits 1 on every file in `invalid/`; the files in\n\
         `warnings/` load and render but draw a warning (`TEXCOORD_MISSING`,\n\
         `TEXTURE_LEVEL_ORDER`), so `dnr validate` reports them and exits 0.\n\n\
         The bindings live on mesh primitives\n\
         (`meshes[m].primitives[p].extensions.EXT_deferred_neural_rendering`); fallback materials\n\
         carry only `KHR_materials_unlit`, and the Khronos glTF-Validator reports no error and no\n\
         warning on any valid sample (`tests/scripts/gltf_validator.mjs`, no exception list).\n\n\
         | file | exercises | expected codes |\n|---|---|---|\n",
    );
    for s in samples {
        let codes = if s.expected.is_empty() {
            "none".to_string()
        } else {
            s.expected.join(", ")
        };
        md.push_str(&format!(
            "| `{}` | {} | {} |\n",
            s.path, s.description, codes
        ));
    }
    md.push_str("\n`valid/unet_depth1_external.bin` is the external buffer of `valid/unet_depth1_external.gltf`.\n");
    md.push_str(&references_section());
    fs::write(dir.join("README.md"), md)?;
    Ok(())
}

/// The README section on the reference renders (spec, "Conformance Samples").
fn references_section() -> String {
    let mut md = String::from(
        "\n## Reference renders\n\n\
         For every valid sample, `references/<sample>/<camera>.png` is the neural layer that\n\
         `dnr-runtime` draws for each camera below: 8-bit RGBA, straight alpha, sRGB-encoded\n\
         colour, transparent where no renderer draws (`q = floor(255 * c + 0.5)`), and\n\
         `<camera>.f32` holds the values it was rounded from (`height * width * 4` little-endian\n\
         `f32`, rows top first, RGBA per pixel). `references/cameras.json` gives each camera in\n\
         full: pinhole `fx, fy, cx, cy` in pixels (pixel centres at `(px + 0.5, py + 0.5)`, rows\n\
         top first), `camToWorld` (16 values, column-major, OpenGL convention: the camera looks\n\
         along its local -Z, +Y up), the frame size and a near plane of 0.01 (no geometry is\n\
         nearer). Each camera is `look_at(eye, target)` with +Y up and a vertical field of view,\n\
         so `dnr render ASSET --look-at EX,EY,EZ,TX,TY,TZ --fov FOV --size WxH` draws it too.\n\
         They are written by `cargo run -p dnr-conformance --example make_references`\n\
         (deterministic); `tests/references.rs` checks that the runtime reproduces them and that\n\
         the committed files are current.\n\n\
         **Tolerance** (the spec's default): comparing alpha at every pixel and colour where the\n\
         reference alpha is above 0, at least 99.5 % of the pixels differ by at most 2 (of 255)\n\
         in every compared channel, and the mean absolute difference over the compared channels\n\
         is at most 0.5 (of 255).\n\n\
         | sample | camera | eye | target | fov (deg) | size | shows |\n|---|---|---|---|---|---|---|\n",
    );
    for (sample, cams) in reference_cameras() {
        for c in cams {
            let v = |a: [f32; 3]| format!("{}, {}, {}", a[0], a[1], a[2]);
            md.push_str(&format!(
                "| `{sample}` | `{}` | {} | {} | {} | {}x{} | {} |\n",
                c.name,
                v(c.eye),
                v(c.target),
                c.fov_y,
                c.width,
                c.height,
                c.note
            ));
        }
    }
    md
}
