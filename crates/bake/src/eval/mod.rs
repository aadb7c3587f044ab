//! Evaluation of an exported asset against held-out photographs: each frame is rendered
//! through the runtime ([`dnr_runtime::renderer::Renderer`], i.e. exactly what a viewer
//! draws from the file) and compared with [`metrics::view_error`]: PSNR over the full frame
//! composited on white, SSIM, and MSE on [0, 255] over the object's pixels.
//!
//! The CLI's `dnr eval` and the baker both call [`evaluate`].

pub mod metrics;
pub mod regions;

use std::path::{Path, PathBuf};
use std::time::Instant;

use dnr_runtime::renderer::{Renderer, RendererError, RgbaImage};

use crate::capture::Frame;
use metrics::{on_white_u8, view_error_masked, Rgba, ViewError};

/// Full-scale value of the error heat map: a mean absolute error of this many 8-bit levels
/// (over R, G, B, on white) or more is drawn white.
pub const HEATMAP_FULL_SCALE: f32 = 64.0;

/// Errors and timing of one view.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ViewReport {
    /// The frame's name (e.g. `test/r_3`).
    pub name: String,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// The metrics.
    #[serde(flatten)]
    pub error: ViewError,
    /// Wall-clock time of `Renderer::render` in milliseconds (rasterise + shade).
    pub render_ms: f64,
    /// The comparison image written, if any.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub image: Option<PathBuf>,
    /// The error by region of the proxy's silhouette (with [`Options::regions`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub regions: Option<regions::Regions>,
}

/// Means over the views.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct MeanReport {
    /// Mean PSNR in dB.
    pub psnr: f64,
    /// Mean SSIM.
    pub ssim: f64,
    /// Mean object MSE on [0, 255].
    pub mse_obj: f64,
    /// Mean render time in milliseconds.
    pub render_ms: f64,
}

/// The result of [`evaluate`].
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct EvalReport {
    /// Per view, in the order of the frames.
    pub views: Vec<ViewReport>,
    /// Means over the views (zeros when there are none).
    pub mean: MeanReport,
    /// Regions summed over the views (with [`Options::regions`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub regions: Option<regions::Regions>,
}

/// What [`evaluate_with`] does besides the metrics.
#[derive(Clone, Copy, Debug, Default)]
pub struct Options<'a> {
    /// Write comparison images to this folder.
    pub save: Option<&'a Path>,
    /// Split each view's error by region of the proxy's silhouette ([`regions`]).
    pub regions: bool,
}

/// Why an evaluation failed.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// The runtime could not render a frame.
    #[error("frame `{frame}`: {error}")]
    Render {
        /// Frame name.
        frame: String,
        /// The runtime's error.
        error: RendererError,
    },
    /// A frame's pixel buffers do not match its camera size.
    #[error("frame `{frame}`: pixel data does not match its {width}x{height} camera")]
    FrameData {
        /// Frame name.
        frame: String,
        /// Camera width.
        width: u32,
        /// Camera height.
        height: u32,
    },
    /// A comparison image could not be written.
    #[error("cannot write {}: {message}", path.display())]
    Save {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
}

/// Renders every frame with `renderer` from the frame's camera, compares it with the
/// frame's photograph, and (with `save`) writes `<save>/<frame>.png`: ground truth | render
/// | error heat map side by side, both images composited on white. Views are evaluated one
/// after the other (each render is parallel).
pub fn evaluate(
    renderer: &Renderer,
    frames: &[Frame],
    save: Option<&Path>,
) -> Result<EvalReport, EvalError> {
    evaluate_with(
        renderer,
        frames,
        Options {
            save,
            regions: false,
        },
    )
}

/// [`evaluate`] with [`Options`].
pub fn evaluate_with(
    renderer: &Renderer,
    frames: &[Frame],
    opts: Options,
) -> Result<EvalReport, EvalError> {
    let save = opts.save;
    if let Some(dir) = save {
        std::fs::create_dir_all(dir).map_err(|e| EvalError::Save {
            path: dir.to_path_buf(),
            message: e.to_string(),
        })?;
    }
    let mut views = Vec::with_capacity(frames.len());
    for frame in frames {
        let (w, h) = (frame.width(), frame.height());
        let n = w as usize * h as usize;
        if frame.rgb.len() != n * 3 || frame.alpha.len() != n {
            return Err(EvalError::FrameData {
                frame: frame.name.clone(),
                width: w,
                height: h,
            });
        }
        let start = Instant::now();
        let render = renderer
            .render(&frame.camera, w, h)
            .map_err(|error| EvalError::Render {
                frame: frame.name.clone(),
                error,
            })?;
        let render_ms = start.elapsed().as_secs_f64() * 1e3;
        let truth = truth_rgba(frame);
        let truth = Rgba {
            width: w as usize,
            height: h as usize,
            data: &truth,
        };
        let mine = Rgba {
            width: render.width,
            height: render.height,
            data: &render.data,
        };
        // Masked-out pixels and those outside the undistorted photograph do not count.
        let error = view_error_masked(&mine, &truth, frame.valid.as_deref());
        let regions = if opts.regions {
            let g = dnr_runtime::raster::rasterize(renderer.scene(), &frame.camera);
            // The camera's own size must be the photograph's for the coverage to line up.
            if g.coverage.len() != n || frame.valid.as_ref().is_some_and(|v| v.len() != n) {
                return Err(EvalError::FrameData {
                    frame: frame.name.clone(),
                    width: w,
                    height: h,
                });
            }
            let covered: Vec<bool> = g.coverage.iter().map(|&c| c != 0.0).collect();
            Some(regions::split(
                &on_white_u8(&mine),
                &on_white_u8(&truth),
                &frame.alpha,
                &covered,
                frame.valid.as_deref(),
                w as usize,
                h as usize,
            ))
        } else {
            None
        };
        let image = match save {
            Some(dir) => {
                let path = dir.join(format!("{}.png", frame_file_stem(&frame.name)));
                write_comparison(&path, &truth, &mine)?;
                Some(path)
            }
            None => None,
        };
        views.push(ViewReport {
            name: frame.name.clone(),
            width: w,
            height: h,
            error,
            render_ms,
            image,
            regions,
        });
    }
    let mean = mean_of(&views);
    let regions = opts.regions.then(|| {
        let mut sum = regions::Regions::default();
        for r in views.iter().filter_map(|v| v.regions.as_ref()) {
            sum.merge(r);
        }
        sum
    });
    Ok(EvalReport {
        views,
        mean,
        regions,
    })
}

fn mean_of(views: &[ViewReport]) -> MeanReport {
    if views.is_empty() {
        return MeanReport::default();
    }
    let k = views.len() as f64;
    let sum = |f: &dyn Fn(&ViewReport) -> f64| views.iter().map(f).sum::<f64>() / k;
    MeanReport {
        psnr: sum(&|v| v.error.psnr),
        ssim: sum(&|v| v.error.ssim),
        mse_obj: sum(&|v| v.error.mse_obj),
        render_ms: sum(&|v| v.render_ms),
    }
}

/// The photograph as straight-alpha RGBA (HWC), what renders are measured against.
pub fn truth_rgba(frame: &Frame) -> Vec<f32> {
    let mut out = Vec::with_capacity(frame.alpha.len() * 4);
    for (rgb, &a) in frame.rgb.chunks_exact(3).zip(&frame.alpha) {
        out.extend_from_slice(rgb);
        out.push(a);
    }
    out
}

/// A file stem for a frame name: `/` and `\` become `_`, characters other than ASCII
/// letters, digits, `-`, `_` and `.` become `_`, and a leading `.` becomes `_` (so a name
/// can never leave the output folder or hide the file).
pub fn frame_file_stem(name: &str) -> String {
    let mut s: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.') {
                c
            } else {
                '_'
            }
        })
        .collect();
    if s.is_empty() || s.starts_with('.') {
        s.insert(0, '_');
    }
    s
}

/// Writes `truth | render | heat map` as an 8-bit RGB PNG (temporary file, then rename).
fn write_comparison(path: &Path, truth: &Rgba, render: &Rgba) -> Result<(), EvalError> {
    let (w, h) = (truth.width, truth.height);
    let t = on_white_u8(truth);
    let r = on_white_u8(render);
    let mut out = vec![0u8; 3 * w * h * 3];
    let row = 3 * w * 3;
    for y in 0..h {
        for x in 0..w {
            let i = 3 * (y * w + x);
            let base = y * row;
            out[base + 3 * x..][..3].copy_from_slice(&t[i..i + 3]);
            out[base + 3 * (w + x)..][..3].copy_from_slice(&r[i..i + 3]);
            let err = (0..3)
                .map(|k| (t[i + k] as f32 - r[i + k] as f32).abs())
                .sum::<f32>()
                / 3.0;
            out[base + 3 * (2 * w + x)..][..3].copy_from_slice(&heat(err / HEATMAP_FULL_SCALE));
        }
    }
    let width = u32::try_from(3 * w).ok();
    let height = u32::try_from(h).ok();
    let (Some(width), Some(height)) = (width, height) else {
        return Err(EvalError::Save {
            path: path.to_path_buf(),
            message: "image too large".into(),
        });
    };
    save_png_rgb8(path, width, height, out).map_err(|message| EvalError::Save {
        path: path.to_path_buf(),
        message,
    })
}

/// The "hot" colour map: black, red, yellow, white for t = 0, 1/3, 2/3, 1.
fn heat(t: f32) -> [u8; 3] {
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        1.0
    };
    let ch = |v: f32| (255.0 * v.clamp(0.0, 1.0) + 0.5) as u8;
    [ch(3.0 * t), ch(3.0 * t - 1.0), ch(3.0 * t - 2.0)]
}

/// Writes an 8-bit RGB PNG atomically: a temporary file beside `path`, then a rename.
pub fn save_png_rgb8(path: &Path, width: u32, height: u32, rgb: Vec<u8>) -> Result<(), String> {
    let img = image::RgbImage::from_raw(width, height, rgb).ok_or("pixel buffer size")?;
    save_atomic(path, |tmp| {
        img.save_with_format(tmp, image::ImageFormat::Png)
            .map_err(|e| e.to_string())
    })
}

/// Writes an 8-bit RGBA PNG of a rendered image atomically.
pub fn save_png_rgba(path: &Path, img: &RgbaImage) -> Result<(), String> {
    let (w, h) = (
        u32::try_from(img.width).map_err(|e| e.to_string())?,
        u32::try_from(img.height).map_err(|e| e.to_string())?,
    );
    let buf = image::RgbaImage::from_raw(w, h, img.to_rgba8()).ok_or("pixel buffer size")?;
    save_atomic(path, |tmp| {
        buf.save_with_format(tmp, image::ImageFormat::Png)
            .map_err(|e| e.to_string())
    })
}

/// Runs `write` on a temporary path in `path`'s folder, then renames it to `path`.
fn save_atomic(path: &Path, write: impl FnOnce(&Path) -> Result<(), String>) -> Result<(), String> {
    let name = path
        .file_name()
        .ok_or("no file name")?
        .to_string_lossy()
        .into_owned();
    let tmp = path.with_file_name(format!(".{name}.tmp{}", std::process::id()));
    let result = write(&tmp).and_then(|()| std::fs::rename(&tmp, path).map_err(|e| e.to_string()));
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn file_stems_stay_in_the_folder() {
        assert_eq!(frame_file_stem("test/r_3"), "test_r_3");
        assert_eq!(frame_file_stem("../../etc/passwd"), "_.._.._etc_passwd");
        assert_eq!(frame_file_stem(".hidden"), "_.hidden");
        assert_eq!(frame_file_stem(""), "_");
        assert_eq!(frame_file_stem("a b\\c"), "a_b_c");
    }

    /// A renderer of a camera-facing quad with a 2 x 2 `none` texture, and a frame whose
    /// photograph is that renderer's own output.
    fn quad_and_frame() -> (Renderer, Frame) {
        use dnr_format::model::{Architecture, DType, Renderer as Spec};
        use dnr_format::{
            AssetBuilder, LevelCompression, MaterialDesc, NeuralTextureDesc, Node, Primitive,
            RendererDesc, TextureLevel, WrapMode,
        };
        let mut b = AssetBuilder::new();
        let quad = Primitive {
            positions: vec![
                [-1.0, -1.0, 0.0],
                [1.0, -1.0, 0.0],
                [1.0, 1.0, 0.0],
                [-1.0, 1.0, 0.0],
            ],
            normals: None,
            tex_coords: vec![[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]],
            indices: vec![0, 1, 2, 0, 2, 3],
            material: Some(0),
        };
        let mesh = b.add_mesh(None, vec![quad]);
        b.add_node(Node {
            mesh: Some(mesh),
            ..Node::default()
        });
        let data = vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 0.0];
        b.add_neural_texture(NeuralTextureDesc {
            levels: vec![TextureLevel {
                width: 2,
                height: 2,
                channels: 3,
                data,
            }],
            wrap_s: WrapMode::ClampToEdge,
            wrap_t: WrapMode::ClampToEdge,
            view_dependence: None,
            compression: LevelCompression::None,
            storage: Vec::new(),
        });
        b.add_renderer(RendererDesc {
            renderer: Spec::new(Architecture::None, 3, 3),
            tensors: Default::default(),
            dtype: DType::F16,
            tensor_dtypes: Default::default(),
        });
        b.add_material(MaterialDesc {
            name: None,
            neural_texture: 0,
            renderer: 0,
        });
        let renderer = Renderer::from_asset(&b.build().unwrap()).unwrap();
        let camera = dnr_runtime::camera::Camera::look_at(
            [0.0, 0.0, 3.0].into(),
            [0.0; 3].into(),
            45.0,
            40,
            30,
        );
        let img = renderer.render(&camera, 40, 30).unwrap();
        let rgb = img
            .data
            .chunks_exact(4)
            .flat_map(|p| [p[0], p[1], p[2]])
            .collect();
        let alpha = img.data.chunks_exact(4).map(|p| p[3]).collect();
        let frame = Frame {
            name: "test/quad".into(),
            image_path: PathBuf::from("quad.png"),
            mask_path: None,
            record: crate::capture::CameraRecord {
                fx: camera.fx as f64,
                fy: camera.fy as f64,
                cx: camera.cx as f64,
                cy: camera.cy as f64,
                width: camera.width,
                height: camera.height,
                cam_to_world: camera.cam_to_world.as_dmat4(),
            },
            camera,
            distortion: Default::default(),
            undistorted: false,
            source_size: (40, 30),
            rgb,
            alpha,
            has_alpha: true,
            valid: None,
            has_mask: false,
            point_ids: Vec::new(),
        };
        (renderer, frame)
    }

    #[test]
    fn evaluate_scores_a_perfect_and_a_perturbed_view() {
        let (renderer, frame) = quad_and_frame();
        let dir = std::env::temp_dir().join(format!("dnr-eval-test-{}", std::process::id()));
        let report = evaluate(&renderer, std::slice::from_ref(&frame), Some(&dir)).unwrap();
        assert_eq!(report.views.len(), 1);
        let v = &report.views[0];
        assert_eq!((v.error.psnr, v.error.mse_obj), (100.0, 0.0));
        assert!(v.error.obj_pixels > 100, "{}", v.error.obj_pixels);
        let png = v.image.as_ref().unwrap();
        assert_eq!(png, &dir.join("test_quad.png"));
        let saved = image::open(png).unwrap();
        assert_eq!((saved.width(), saved.height()), (120, 30));

        // Darken the photograph's object by 10 levels: MSE 100 over the object.
        let mut dark = frame.clone();
        for (rgb, &a) in dark.rgb.chunks_exact_mut(3).zip(&frame.alpha) {
            if a > 0.5 {
                rgb.iter_mut()
                    .for_each(|c| *c = (*c - 10.0 / 255.0).max(0.0));
            }
        }
        // The same darkened pixels marked invalid (a mask, or outside an undistorted photo)
        // do not count: the view is perfect again.
        let mut masked = dark.clone();
        masked.valid = Some(frame.alpha.iter().map(|&a| a <= 0.5).collect());
        let m = evaluate(&renderer, &[masked], None).unwrap().views[0].error;
        assert_eq!((m.psnr, m.mse_obj, m.obj_pixels), (100.0, 0.0, 0));
        assert!((m.ssim - 1.0).abs() < 1e-12, "{m:?}");
        let report = evaluate(&renderer, &[frame.clone(), dark], None).unwrap();
        let e = report.views[1].error;
        assert!(
            e.psnr < 50.0 && e.mse_obj > 20.0 && e.mse_obj <= 100.0,
            "{e:?}"
        );
        assert!((report.mean.psnr - (100.0 + e.psnr) / 2.0).abs() < 1e-9);
        assert!(report.views[1].image.is_none());

        // Frames whose pixels do not match their camera are an error, not a panic.
        let mut bad = frame;
        bad.rgb.pop();
        assert!(matches!(
            evaluate(&renderer, &[bad], None),
            Err(EvalError::FrameData { .. })
        ));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn heat_map_ends() {
        assert_eq!(heat(0.0), [0, 0, 0]);
        assert_eq!(heat(1.0), [255, 255, 255]);
        assert_eq!(heat(1.0 / 3.0), [255, 0, 0]);
        assert_eq!(heat(f32::NAN), [255, 255, 255]);
    }
}
