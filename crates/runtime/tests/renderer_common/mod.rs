//! Small assets for the renderer tests, built with `dnr_format::AssetBuilder`.
#![allow(dead_code)] // each test file uses a different subset

use std::collections::BTreeMap;

use dnr_format::model::{
    Architecture, DType, Decoder, Normalization, Renderer as RendererSpec, ViewDependence,
};
use dnr_format::{
    Asset, AssetBuilder, LevelCompression, MaterialDesc, NeuralTextureDesc, Node, Primitive,
    RendererDesc, TensorF32, TextureLevel, WrapMode,
};
use dnr_runtime::camera::Camera;
use dnr_runtime::renderer::RgbaImage;
use glam::{Mat4, Vec3};

/// An axis-aligned square in the plane `z`, centred at `(cx, cy)` with half side `half`,
/// facing +Z, uv (0,0) at the top-left corner (glTF convention).
pub fn quad(cx: f32, cy: f32, half: f32, z: f32, material: Option<usize>) -> Primitive {
    Primitive {
        positions: vec![
            [cx - half, cy - half, z],
            [cx + half, cy - half, z],
            [cx + half, cy + half, z],
            [cx - half, cy + half, z],
        ],
        normals: None,
        tex_coords: vec![[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]],
        indices: vec![0, 1, 2, 0, 2, 3],
        material,
    }
}

/// A level whose texel `(x, y)` channel `c` is `f(x, y, c)`.
pub fn level(
    width: u32,
    height: u32,
    channels: u32,
    mut f: impl FnMut(u32, u32, u32) -> f32,
) -> TextureLevel {
    let mut data = Vec::with_capacity((width * height * channels) as usize);
    for y in 0..height {
        for x in 0..width {
            for c in 0..channels {
                data.push(f(x, y, c));
            }
        }
    }
    TextureLevel {
        width,
        height,
        channels,
        data,
    }
}

/// A texture from levels.
pub fn texture(
    levels: Vec<TextureLevel>,
    wrap: WrapMode,
    view_dependence: Option<ViewDependence>,
) -> NeuralTextureDesc {
    NeuralTextureDesc {
        levels,
        wrap_s: wrap,
        wrap_t: wrap,
        view_dependence,
        compression: LevelCompression::Zip,
        storage: Vec::new(),
    }
}

/// A one-texel texture of constant colour (remaining channels 0).
pub fn solid(channels: u32, rgb: [f32; 3]) -> NeuralTextureDesc {
    texture(
        vec![level(1, 1, channels, |_, _, c| {
            rgb.get(c as usize).copied().unwrap_or(0.0)
        })],
        WrapMode::Repeat,
        None,
    )
}

/// A `none` renderer.
pub fn none_renderer(channels: u32) -> RendererDesc {
    RendererDesc {
        renderer: RendererSpec::new(Architecture::None, channels, 3),
        tensors: BTreeMap::new(),
        dtype: DType::F32,
        tensor_dtypes: Default::default(),
    }
}

fn tensor(shape: Vec<u32>, data: Vec<f32>) -> TensorF32 {
    TensorF32::new(shape, data).expect("tensor")
}

/// A 4-output `unet` of depth 1 (width 1, transposedConv, no norm) whose weights are zero:
/// its output is `tanh(bias)` at every pixel, covered or not.
pub fn unet_constant(channels: u32, bias: [f32; 4]) -> RendererDesc {
    let mut t = BTreeMap::new();
    t.insert(
        "encoder.0.weight".into(),
        tensor(vec![1, channels, 4, 4], vec![0.0; 16 * channels as usize]),
    );
    t.insert("encoder.0.bias".into(), tensor(vec![1], vec![0.0]));
    t.insert(
        "decoder.0.weight".into(),
        tensor(vec![1, 4, 4, 4], vec![0.0; 64]),
    );
    t.insert("decoder.0.bias".into(), tensor(vec![4], bias.to_vec()));
    RendererDesc {
        renderer: RendererSpec::unet(
            channels,
            4,
            vec![1],
            Decoder::TransposedConv,
            Normalization::None,
        ),
        tensors: t,
        dtype: DType::F32,
        tensor_dtypes: Default::default(),
    }
}

/// An `mlp` without hidden layers whose weights are zero: output `tanh(bias)` at covered
/// pixels.
pub fn mlp_constant(channels: u32, bias: &[f32]) -> RendererDesc {
    let out = bias.len() as u32;
    let mut t = BTreeMap::new();
    t.insert(
        "layers.0.weight".into(),
        tensor(vec![out, channels], vec![0.0; (out * channels) as usize]),
    );
    t.insert("layers.0.bias".into(), tensor(vec![out], bias.to_vec()));
    RendererDesc {
        renderer: RendererSpec::mlp(channels, out, vec![]),
        tensors: t,
        dtype: DType::F32,
        tensor_dtypes: Default::default(),
    }
}

/// A builder with one node per mesh (translation given), materials pairing texture `i`
/// with renderer `r_i`.
pub struct Scene {
    pub b: AssetBuilder,
}

impl Scene {
    pub fn new() -> Self {
        Scene {
            b: AssetBuilder::new(),
        }
    }

    /// Adds a mesh of `prims` on a node with `translation`; returns the node index.
    pub fn object(&mut self, prims: Vec<Primitive>, translation: [f32; 3]) -> usize {
        let mesh = self.b.add_mesh(None, prims);
        self.b.add_node(Node {
            mesh: Some(mesh),
            translation,
            ..Node::default()
        })
    }

    /// Adds a material using texture `t` and renderer `r`.
    pub fn material(&mut self, t: usize, r: usize) -> usize {
        self.b.add_material(MaterialDesc {
            name: None,
            neural_texture: t,
            renderer: r,
        })
    }

    pub fn build(&self) -> Asset {
        self.b.build().expect("asset builds")
    }
}

/// A pinhole camera at `eye` looking down -Z (no rotation), `fx = fy = f`, centred principal
/// point.
pub fn camera_down_z(eye: [f32; 3], f: f32, width: u32, height: u32) -> Camera {
    Camera {
        fx: f,
        fy: f,
        cx: 0.5 * width as f32,
        cy: 0.5 * height as f32,
        width,
        height,
        cam_to_world: Mat4::from_translation(Vec3::from(eye)),
    }
}

/// Pixel `(x, y)` of an image.
pub fn px(img: &RgbaImage, x: usize, y: usize) -> [f32; 4] {
    img.pixel(x, y).expect("pixel inside the image")
}

/// Asserts two pixels agree within `tol` per channel.
pub fn assert_close(got: [f32; 4], want: [f32; 4], tol: f32, what: &str) {
    for k in 0..4 {
        assert!(
            (got[k] - want[k]).abs() <= tol,
            "{what}: got {got:?}, want {want:?} (channel {k}, tolerance {tol})"
        );
    }
}
