//! Shading a G-buffer: pixel ownership, feature images per renderer, the networks, and
//! compositing into the neural layer (spec "Evaluating a Frame", "Renderers",
//! "Compositing Several Renderers").

use rayon::prelude::*;

use super::image::RgbaImage;
use super::net::Net;
use super::{PrimOwner, Renderer, RendererError};
use crate::gbuffer::GBuffer;
use crate::nn::Tensor;
use crate::sh::{coeff_count, sh_component};
use crate::texture::for_rows_of_planes;

/// `owner` of an uncovered pixel.
const BACKGROUND: u32 = u32::MAX;
/// `owner` of a pixel whose visible primitive has no binding.
const CORE: u32 = u32::MAX - 1;

/// Who owns each pixel (the renderer of its visible primitive's binding), and with which
/// neural texture.
struct Ownership {
    /// Renderer index, [`BACKGROUND`] or [`CORE`], per pixel.
    owner: Vec<u32>,
    /// Neural texture index per pixel (meaningful where `owner` is a renderer).
    texture: Vec<u32>,
    /// The pixels of each renderer, ascending.
    pixels: Vec<Vec<u32>>,
}

/// Shades the frame of `g`; `fine` holds one G-buffer per supersample factor in use, each
/// `s` times `g`'s width and height (the caller checked them).
pub(super) fn shade(
    r: &Renderer,
    g: &GBuffer,
    fine: &[&GBuffer],
) -> Result<RgbaImage, RendererError> {
    let n = g.len();
    let own = ownership(r, g)?;
    // Subsample ownership, once per factor that a renderer with pixels needs.
    let mut fine_own: Vec<(usize, &GBuffer, Ownership)> = Vec::new();
    let mut image = RgbaImage::new(g.width, g.height);
    // Premultiplied colour and alpha of the 4-channel U-Nets at background pixels,
    // allocated when the first one runs.
    let mut background: Option<(Vec<[f32; 3]>, Vec<f32>)> = None;

    for (ri, slot) in r.renderers.iter().enumerate() {
        let pixels = &own.pixels[ri];
        if pixels.is_empty() {
            continue; // a renderer that covers no pixel is not evaluated
        }
        let id = ri as u32;
        let run_err = |error| RendererError::Run { index: ri, error };
        // A supersampled renderer's feature image, whole (C x H x W); None: features are
        // sampled at pixel centres where needed.
        let averaged = if slot.supersample > 1 {
            let s = slot.supersample;
            let k = match fine_own.iter().position(|(fs, ..)| *fs == s) {
                Some(k) => k,
                None => {
                    let fg = fine
                        .iter()
                        .find(|f| f.width == s * g.width && f.height == s * g.height)
                        .ok_or_else(|| {
                            RendererError::GBuffer(format!(
                                "renderer {ri} has supersample {s}: a subsample G-buffer of \
                                 {}x{} ({s} times the frame) is needed",
                                s * g.width,
                                s * g.height
                            ))
                        })?;
                    fine_own.push((s, fg, ownership(r, fg)?));
                    fine_own.len() - 1
                }
            };
            let (_, fg, fo) = &fine_own[k];
            Some(supersampled_features(r, id, g, fg, fo, slot).map_err(run_err)?)
        } else {
            None
        };
        let pixel_feature = |i: usize, f: &mut [f32]| match &averaged {
            Some(x) => {
                for (k, v) in f.iter_mut().enumerate() {
                    *v = x[k * n + i];
                }
            }
            None => feature(r, g, i, own.texture[i], f),
        };
        match &slot.net {
            Net::None => {
                image.data.par_chunks_mut(4).enumerate().for_each_init(
                    || vec![0.0f32; slot.input_channels],
                    |f, (i, px)| {
                        if own.owner[i] == id {
                            pixel_feature(i, f);
                            for k in 0..3 {
                                px[k] = finite(f[k].clamp(0.0, 1.0));
                            }
                            px[3] = 1.0;
                        }
                    },
                );
            }
            Net::Mlp(mlp) => {
                let c = slot.input_channels;
                let m = pixels.len();
                // Features of the renderer's pixels, pixel-major, then planar for the GEMM.
                let mut hwc = vec![0.0f32; m * c];
                hwc.par_chunks_mut(c)
                    .zip(pixels.par_iter())
                    .for_each(|(f, &i)| pixel_feature(i as usize, f));
                let mut planar = vec![0.0f32; c * m];
                for (p, f) in hwc.chunks_exact(c).enumerate() {
                    for (k, &v) in f.iter().enumerate() {
                        planar[k * m + p] = v;
                    }
                }
                drop(hwc);
                let t = mlp.forward_pixels(&planar, m).map_err(run_err)?;
                let four = slot.output_channels == 4;
                for (p, &i) in pixels.iter().enumerate() {
                    let px = &mut image.data[i as usize * 4..][..4];
                    for k in 0..3 {
                        px[k] = unit(t[k * m + p]);
                    }
                    px[3] = if four { unit(t[3 * m + p]) } else { 1.0 };
                }
            }
            Net::Unet(unet) => {
                let c = slot.input_channels;
                let (w, h) = (g.width, g.height);
                let x = match averaged {
                    Some(x) => x,
                    None => feature_image(r, id, g, &own, c),
                };
                let x = Tensor::from_vec(c, h, w, x).map_err(run_err)?;
                let covered: Vec<bool> = if r.skip_uncovered {
                    own.owner.iter().map(|&o| o == id).collect()
                } else {
                    Vec::new()
                };
                let t = if r.skip_uncovered && unet.skip_worthwhile(h, w, &covered) {
                    unet.forward_masked(&x, &covered)
                } else {
                    unet.forward(&x)
                }
                .map_err(run_err)?;
                if t.c != slot.output_channels || t.h != h || t.w != w {
                    return Err(run_err(crate::nn::NnError::Shape(format!(
                        "U-Net output {}x{}x{}, expected {}x{h}x{w}",
                        t.c, t.h, t.w, slot.output_channels
                    ))));
                }
                let four = slot.output_channels == 4;
                let tp = |k: usize, i: usize| t.data[k * n + i];
                image
                    .data
                    .par_chunks_mut(4)
                    .enumerate()
                    .for_each(|(i, px)| {
                        if own.owner[i] == id {
                            for (k, v) in px[..3].iter_mut().enumerate() {
                                *v = unit(tp(k, i));
                            }
                            px[3] = if four { unit(tp(3, i)) } else { 1.0 };
                        }
                    });
                if four {
                    // Background: source-over in ascending renderer index, premultiplied.
                    let (q, a) =
                        background.get_or_insert_with(|| (vec![[0.0; 3]; n], vec![0.0; n]));
                    q.par_iter_mut()
                        .zip(a.par_iter_mut())
                        .enumerate()
                        .for_each(|(i, (q, a))| {
                            if own.owner[i] == BACKGROUND {
                                let alpha = unit(tp(3, i));
                                for (k, v) in q.iter_mut().enumerate() {
                                    *v = alpha * unit(tp(k, i)) + (1.0 - alpha) * *v;
                                }
                                *a = alpha + (1.0 - alpha) * *a;
                            }
                        });
                }
                // Back to the tensor pool, where the next frame's layers find it (dropped, it
                // left them fresh allocations to page-fault in, every frame).
                t.recycle();
            }
        }
    }

    if let Some((q, a)) = background {
        image
            .data
            .par_chunks_mut(4)
            .enumerate()
            .for_each(|(i, px)| {
                if own.owner[i] == BACKGROUND && a[i] > 0.0 {
                    for k in 0..3 {
                        px[k] = finite(q[i][k] / a[i]);
                    }
                    px[3] = a[i];
                }
            });
    }
    Ok(image)
}

/// The feature image of renderer `id` sampled at the centres of `g`'s pixels: `X` where the
/// renderer owns the pixel, 0 elsewhere (`C x H x W`).
fn feature_image(r: &Renderer, id: u32, g: &GBuffer, own: &Ownership, c: usize) -> Vec<f32> {
    let (w, h) = (g.width, g.height);
    let mut x = vec![0.0f32; c * w * h];
    for_rows_of_planes(&mut x, c, w, h, |y, planes| {
        let mut f = vec![0.0f32; c];
        for xx in 0..w {
            let i = y * w + xx;
            if own.owner[i] == id {
                feature(r, g, i, own.texture[i], &mut f);
                for (plane, &v) in planes.iter_mut().zip(&f) {
                    plane[xx] = v;
                }
            }
        }
    });
    x
}

/// The feature image of a supersampled renderer (spec "Supersampled Features"): the features
/// of the subsamples it owns in `fine`, box-averaged to `g`'s pixels.
fn supersampled_features(
    r: &Renderer,
    id: u32,
    g: &GBuffer,
    fine: &GBuffer,
    fine_own: &Ownership,
    slot: &super::RendererSlot,
) -> Result<Vec<f32>, crate::nn::NnError> {
    let c = slot.input_channels;
    let sub = feature_image(r, id, fine, fine_own, c);
    let mut x = vec![0.0f32; c * g.len()];
    crate::supersample::box_mean(&sub, c, g.width, g.height, slot.supersample, &mut x)?;
    Ok(x)
}

/// Assigns every pixel to the renderer of its visible primitive's binding, to core shading
/// (unbound primitive), or to the background.
fn ownership(r: &Renderer, g: &GBuffer) -> Result<Ownership, RendererError> {
    let n = g.len();
    let prims = r.owners.len();
    let mut owner = vec![BACKGROUND; n];
    let mut texture = vec![0u32; n];
    owner
        .par_iter_mut()
        .zip(texture.par_iter_mut())
        .enumerate()
        .try_for_each(|(i, (o, t))| {
            if g.coverage[i] == 0.0 {
                return Ok(());
            }
            let p = g.prim[i];
            match r.owners.get(p as usize) {
                None => Err(RendererError::GBuffer(format!(
                    "pixel ({}, {}) is covered by primitive {p}, but the scene has {prims}",
                    i % g.width.max(1),
                    i / g.width.max(1)
                ))),
                Some(PrimOwner::Core) => {
                    *o = CORE;
                    Ok(())
                }
                Some(&PrimOwner::Neural {
                    texture: ti,
                    renderer: ri,
                }) => {
                    // Both indices were checked against the asset's arrays (< u32::MAX - 1).
                    *o = ri as u32;
                    *t = ti as u32;
                    Ok(())
                }
            }
        })?;
    let mut pixels = vec![Vec::new(); r.renderers.len()];
    for (i, &o) in owner.iter().enumerate() {
        if let Some(list) = pixels.get_mut(o as usize) {
            list.push(i as u32);
        }
    }
    Ok(Ownership {
        owner,
        texture,
        pixels,
    })
}

/// The modulated feature `X` of covered pixel `i` from neural texture `ti`, into `out`
/// (the texture's channel count, which equals the renderer's input channels).
#[inline]
fn feature(r: &Renderer, g: &GBuffer, i: usize, ti: u32, out: &mut [f32]) {
    out.fill(0.0);
    let t = &r.textures[ti as usize];
    let [u, v] = g.uv[i];
    t.pyramid.accumulate(u, v, out); // no-op for non-finite uv: F = 0
    if let Some((first, degree)) = t.sh {
        let d = g.view_dir[i];
        let d = if d.iter().all(|c| c.is_finite()) {
            d
        } else {
            [0.0; 3]
        };
        for (j, x) in out[first..first + coeff_count(degree)]
            .iter_mut()
            .enumerate()
        {
            *x *= sh_component(j, d);
        }
    }
}

/// The output transform `(t + 1) / 2`, 0 when not finite.
#[inline]
fn unit(t: f32) -> f32 {
    finite((t + 1.0) * 0.5)
}

/// `x`, or 0 when not finite.
#[inline]
fn finite(x: f32) -> f32 {
    if x.is_finite() {
        x
    } else {
        0.0
    }
}
