//! `dnr-wasm`: WebAssembly bindings of `dnr-format` and `dnr-runtime` for web viewers.
//!
//! Built for `wasm32-unknown-unknown` and packaged by `wasm-bindgen --target web` (a plain ES
//! module: `await init(); validate(bytes)`), see `viewers/three/scripts/build-wasm.sh`. It
//! exposes
//!
//! - [`validate`]: the validator's report with its codes;
//! - [`DnrAsset`]: the decoded extension (every level of every neural texture as `f32` or
//!   half bits, every renderer's parameters and named tensors) and the CPU renderer
//!   ([`DnrAsset::render`] for a camera, [`DnrAsset::shade`] for a viewer's G-buffer), the
//!   fallback and the reference of a GPU implementation;
//! - [`glb_from_parts`]: a GLB from a loader's JSON and resolved buffers.
//!
//! No thread pool is created: on `wasm32-unknown-unknown` rayon's implicit global pool runs
//! every parallel iterator on the calling thread. The logic lives in [`core`] (plain Rust,
//! tested natively); this file converts to and from JavaScript values.
#![forbid(unsafe_code)]

pub mod core;

use js_sys::{Array, Float32Array, Uint16Array, Uint8Array};
use wasm_bindgen::prelude::*;

/// JSON text to a JavaScript value (objects and arrays, not a string).
fn to_js(v: &serde_json::Value) -> Result<JsValue, JsError> {
    js_sys::JSON::parse(&v.to_string()).map_err(|_| JsError::new("internal JSON conversion"))
}

/// Validates a GLB (or a `.gltf` whose buffers are all `data:` URIs) and returns
/// `{ issues: [{code, severity, pointer, message}], errors, warnings, blocking }`;
/// `blocking` lists the error codes that keep a conforming reader on the fallback.
#[wasm_bindgen]
pub fn validate(bytes: &[u8]) -> Result<JsValue, JsError> {
    to_js(&core::validate_report(bytes))
}

/// A GLB from a glTF JSON document (`json`, UTF-8 bytes) and the bytes of each of its
/// buffers, in order (as `GLTFLoader`'s `parser.getDependency('buffer', i)` gives them).
#[wasm_bindgen(js_name = glbFromParts)]
pub fn glb_from_parts(json: &[u8], buffers: Array) -> Result<Uint8Array, JsError> {
    let bufs: Vec<Vec<u8>> = buffers
        .iter()
        .map(|b| {
            if b.is_instance_of::<Uint8Array>() {
                Ok(Uint8Array::from(b).to_vec())
            } else if b.is_instance_of::<js_sys::ArrayBuffer>() {
                Ok(Uint8Array::new(&b).to_vec())
            } else {
                Err(JsError::new(
                    "buffers must be Uint8Array or ArrayBuffer values",
                ))
            }
        })
        .collect::<Result<_, _>>()?;
    let glb = core::glb_from_parts(json, bufs).map_err(|e| JsError::new(&e))?;
    Ok(Uint8Array::from(glb.as_slice()))
}

/// A decoded `EXT_deferred_neural_rendering` asset with its CPU renderer.
#[wasm_bindgen]
pub struct DnrAsset {
    inner: core::Loaded,
}

#[wasm_bindgen]
impl DnrAsset {
    /// Decodes a GLB (or self-contained `.gltf`): every level, every tensor (checksums and
    /// finiteness checked), the scene's triangles. Throws with the reason on failure.
    #[wasm_bindgen(constructor)]
    pub fn new(bytes: &[u8]) -> Result<DnrAsset, JsError> {
        core::Loaded::from_bytes(bytes)
            .map(|inner| DnrAsset { inner })
            .map_err(|e| JsError::new(&e))
    }

    /// `{ textures, renderers, bindings, scenePrimitives }`: every texture's channels, wrap
    /// modes (GL codes), view dependence and level sizes; every renderer's architecture
    /// parameters and tensor names and shapes; every primitive binding; the CPU renderer's
    /// primitive order.
    pub fn describe(&self) -> Result<JsValue, JsError> {
        to_js(&self.inner.describe())
    }

    /// Level `level` of neural texture `texture` as `f32`: `height * width * channels`
    /// values, texel-interleaved, row 0 (v = 0) first.
    #[wasm_bindgen(js_name = levelF32)]
    pub fn level_f32(&self, texture: usize, level: usize) -> Result<Float32Array, JsError> {
        self.inner
            .level_f32(texture, level)
            .map(Float32Array::from)
            .ok_or_else(|| JsError::new(&format!("no level {level} of texture {texture}")))
    }

    /// The same level as IEEE 754 half-precision bits, for `HALF_FLOAT` textures: exact for
    /// EXR levels (stored as half); quantised PNG levels are rounded to the nearest half.
    #[wasm_bindgen(js_name = levelF16)]
    pub fn level_f16(&self, texture: usize, level: usize) -> Result<Uint16Array, JsError> {
        self.inner
            .level_f16(texture, level)
            .map(|v| Uint16Array::from(v.as_slice()))
            .ok_or_else(|| JsError::new(&format!("no level {level} of texture {texture}")))
    }

    /// Tensor `name` of renderer `renderer`, row-major, as `f32`.
    pub fn tensor(&self, renderer: usize, name: &str) -> Result<Float32Array, JsError> {
        self.inner
            .tensor(renderer, name)
            .map(Float32Array::from)
            .ok_or_else(|| JsError::new(&format!("renderer {renderer} has no tensor `{name}`")))
    }

    /// The neural layer of the asset's own scene for a pinhole camera: `height * width * 4`
    /// values (sRGB colour, straight alpha), row 0 at the top. `camToWorld`: 16 values,
    /// column-major (three.js `Matrix4.elements`), OpenGL camera convention.
    #[allow(clippy::too_many_arguments)]
    pub fn render(
        &self,
        fx: f32,
        fy: f32,
        cx: f32,
        cy: f32,
        cam_to_world: &[f32],
        width: u32,
        height: u32,
    ) -> Result<Float32Array, JsError> {
        self.inner
            .render(fx, fy, cx, cy, cam_to_world, width, height)
            .map(|v| Float32Array::from(v.as_slice()))
            .map_err(|e| JsError::new(&e))
    }

    /// Shades a viewer's G-buffer (row 0 at the top): `coverage` (n), `prim` (n, indices of
    /// `scenePrimitives`), `uv` (2n), `viewDir` (3n, local-space unit eye-to-surface
    /// directions). Returns `n * 4` values like [`DnrAsset::render`]. Assets with supersampled
    /// renderers (format revision 1.3) give an error here: draw them with
    /// [`DnrAsset::render`].
    pub fn shade(
        &self,
        width: usize,
        height: usize,
        coverage: &[f32],
        prim: &[u32],
        uv: &[f32],
        view_dir: &[f32],
    ) -> Result<Float32Array, JsError> {
        self.inner
            .shade(width, height, coverage, prim, uv, view_dir)
            .map(|v| Float32Array::from(v.as_slice()))
            .map_err(|e| JsError::new(&e))
    }
}
