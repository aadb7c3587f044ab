//! The fallback PNG's size: the smallest one whose error needs it.
//!
//! The fallback material (channels 0..2 of the texture, unlit) is what a viewer without the
//! extension shows. Made at the finest level's size it can be most of a small asset, while a
//! smooth texture loses nothing visible at a quarter of that. The baker tries the finest size
//! and each halving down to [`MIN_SIZE`] (box filter), renders the plain textured mesh on
//! the validation views (the training views when there are none) by sampling each candidate
//! bilinearly at the rasterised UVs, as a glTF viewer's linear sampler would, and keeps the
//! smallest whose PSNR against the photographs is at most [`BOUND_DB`] below the finest
//! size's.

use serde::Serialize;

use dnr_format::asset::{downsample_rgba8, encode_png_rgba8, halved_size, WrapMode};

use crate::train::views::View;

/// The PSNR (dB) the fallback may lose against the finest size: about the smallest step a
/// viewer notices, and the fallback is a stand-in, not the asset's appearance.
pub const BOUND_DB: f64 = 0.5;

/// No candidate side below this many texels (smaller gains little and UV charts blur
/// together).
pub const MIN_SIZE: u32 = 64;

/// At most this many pixels sampled per candidate (every k-th covered pixel beyond it).
const MAX_PROBES: usize = 1 << 21;

/// Added to both MSEs before their ratio so an exact fit costs 0 dB, not NaN.
const MSE_FLOOR: f64 = 1e-10;

/// One pixel of a view the fallback is judged on: where it samples and what the photograph
/// shows there (sRGB [0, 1]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Probe {
    /// Texture coordinate.
    pub uv: [f32; 2],
    /// Target colour.
    pub rgb: [f32; 3],
}

/// The covered, valid pixels of `views` with finite UVs (every k-th pixel when the views
/// hold more than about two million).
pub fn probes(views: &[View]) -> Vec<Probe> {
    let total: usize = views.iter().map(|v| v.width() * v.height()).sum();
    let stride = total.div_ceil(MAX_PROBES).max(1);
    let mut out = Vec::new();
    let mut k = 0usize;
    for v in views {
        let n = v.width() * v.height();
        for i in 0..n {
            k += 1;
            if !k.is_multiple_of(stride) || v.gbuf.coverage[i] < 0.5 || !v.is_valid(i) {
                continue;
            }
            let uv = v.gbuf.uv[i];
            if !(uv[0].is_finite() && uv[1].is_finite()) {
                continue;
            }
            out.push(Probe {
                uv,
                rgb: [v.target[i], v.target[n + i], v.target[2 * n + i]],
            });
        }
    }
    out
}

/// One candidate size, measured.
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Candidate {
    /// Halvings from the finest level's size.
    pub halvings: u32,
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// PNG bytes.
    pub bytes: u64,
    /// PSNR (dB) of the plain textured mesh against the photographs.
    pub psnr: f64,
    /// PSNR lost against the finest size (dB; NaN without probes).
    pub cost_db: f64,
}

/// The fallback size chosen and every candidate measured (the bake report's `fallback`).
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct FallbackReport {
    /// The PSNR a smaller fallback may lose ([`BOUND_DB`]).
    pub bound_db: f64,
    /// The views judged on: `validation`, `training`, or `none` (then the finest size).
    pub views: String,
    /// Pixels sampled.
    pub probes: usize,
    /// The chosen candidate's halvings.
    pub halvings: u32,
    /// The chosen width.
    pub width: u32,
    /// The chosen height.
    pub height: u32,
    /// The chosen PNG's bytes.
    pub bytes: u64,
    /// Every candidate, finest first.
    pub candidates: Vec<Candidate>,
}

/// Bilinear sample of an RGBA8 image's RGB at `uv` (texel centres at half-integers, as a
/// glTF linear sampler), on [0, 1].
fn sample(w: u32, h: u32, rgba: &[u8], wrap: (WrapMode, WrapMode), uv: [f32; 2]) -> [f32; 3] {
    let x = uv[0] as f64 * w as f64 - 0.5;
    let y = uv[1] as f64 * h as f64 - 0.5;
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = ((x - x0) as f32, (y - y0) as f32);
    let (x0, y0) = (x0 as i64, y0 as i64);
    let xs = [wrap.0.wrap(x0, w), wrap.0.wrap(x0 + 1, w)];
    let ys = [wrap.1.wrap(y0, h), wrap.1.wrap(y0 + 1, h)];
    let texel = |xi: u32, yi: u32, c: usize| {
        let i = 4 * (yi as usize * w as usize + xi as usize) + c;
        f32::from(rgba.get(i).copied().unwrap_or(0)) / 255.0
    };
    let mut out = [0.0f32; 3];
    for (c, o) in out.iter_mut().enumerate() {
        let top = texel(xs[0], ys[0], c) * (1.0 - fx) + texel(xs[1], ys[0], c) * fx;
        let bottom = texel(xs[0], ys[1], c) * (1.0 - fx) + texel(xs[1], ys[1], c) * fx;
        *o = top * (1.0 - fy) + bottom * fy;
    }
    out
}

/// Mean squared error (on [0, 1]) of an image sampled at the probes.
fn mse(w: u32, h: u32, rgba: &[u8], wrap: (WrapMode, WrapMode), probes: &[Probe]) -> f64 {
    if probes.is_empty() {
        return f64::NAN;
    }
    let sum: f64 = probes
        .iter()
        .map(|p| {
            let s = sample(w, h, rgba, wrap, p.uv);
            (0..3)
                .map(|c| f64::from(s[c] - p.rgb[c]).powi(2))
                .sum::<f64>()
        })
        .sum();
    sum / (3 * probes.len()) as f64
}

/// Measures the finest fallback (`width` x `height` RGBA8) and each halving down to
/// [`MIN_SIZE`] on `probes`, and chooses the smallest that loses at most `bound_db`
/// (the finest without probes). `views` names the views the probes come from.
pub fn choose(
    width: u32,
    height: u32,
    rgba: &[u8],
    wrap: (WrapMode, WrapMode),
    probes: &[Probe],
    views: &str,
    bound_db: f64,
) -> Result<FallbackReport, dnr_format::Error> {
    let mut candidates = Vec::new();
    let mut base_mse = f64::NAN;
    for halvings in 0..32 {
        if halvings > 0 {
            let (w, h) = halved_size(width, height, halvings);
            if w.min(h) < MIN_SIZE {
                break;
            }
        }
        let (w, h, small) = downsample_rgba8(width, height, rgba, halvings);
        let bytes = encode_png_rgba8(w, h, &small)?.len() as u64;
        let m = mse(w, h, &small, wrap, probes);
        if halvings == 0 {
            base_mse = m;
        }
        candidates.push(Candidate {
            halvings,
            width: w,
            height: h,
            bytes,
            psnr: -10.0 * m.log10(),
            cost_db: 10.0 * ((m + MSE_FLOOR) / (base_mse + MSE_FLOOR)).log10(),
        });
    }
    // Smallest first: the first within the bound (NaN costs, i.e. no probes, never are).
    let chosen = candidates
        .iter()
        .rev()
        .find(|c| c.halvings == 0 || c.cost_db <= bound_db)
        .or(candidates.first())
        .cloned()
        .ok_or_else(|| dnr_format::Error::invalid("no fallback candidate"))?;
    Ok(FallbackReport {
        bound_db,
        views: if probes.is_empty() { "none" } else { views }.to_string(),
        probes: probes.len(),
        halvings: chosen.halvings,
        width: chosen.width,
        height: chosen.height,
        bytes: chosen.bytes,
        candidates,
    })
}

/// Lines for verbose output.
pub fn describe(r: &FallbackReport) -> Vec<String> {
    let mut lines = vec![format!(
        "fallback PNG {}x{} ({} bytes): the smallest within {:.2} dB of the finest on {} {} pixels",
        r.width, r.height, r.bytes, r.bound_db, r.probes, r.views
    )];
    for c in &r.candidates {
        lines.push(format!(
            "  {:>5}x{:<5} {:>9} bytes, {:.2} dB (cost {:+.2} dB)",
            c.width, c.height, c.bytes, c.psnr, c.cost_db
        ));
    }
    lines
}

#[cfg(test)]
mod tests {
    use super::*;

    const CLAMP: (WrapMode, WrapMode) = (WrapMode::ClampToEdge, WrapMode::ClampToEdge);

    /// An image and probes at every texel centre whose target is the image plus a little
    /// noise (as photographs differ from any texture).
    fn case(n: u32, f: impl Fn(u32, u32) -> u8) -> (Vec<u8>, Vec<Probe>) {
        let mut rgba = Vec::new();
        let mut probes = Vec::new();
        for y in 0..n {
            for x in 0..n {
                let v = f(x, y);
                rgba.extend([v, v / 2, 255 - v, 255]);
                let noise = ((x * 7 + y * 13) % 11) as f32 - 5.0;
                let t = |b: u8| (f32::from(b) + noise) / 255.0;
                probes.push(Probe {
                    uv: [(x as f32 + 0.5) / n as f32, (y as f32 + 0.5) / n as f32],
                    rgb: [t(v), t(v / 2), t(255 - v)],
                });
            }
        }
        (rgba, probes)
    }

    #[test]
    fn smooth_fallback_shrinks_to_the_minimum() {
        let (rgba, probes) = case(512, |_, _| 90);
        let r = choose(512, 512, &rgba, CLAMP, &probes, "validation", BOUND_DB).unwrap();
        assert_eq!(r.candidates.len(), 4, "512, 256, 128, 64");
        assert_eq!((r.width, r.height, r.halvings), (MIN_SIZE, MIN_SIZE, 3));
        assert!(r.bytes < r.candidates[0].bytes);
        // A low-frequency gradient too.
        let (rgba, probes) = case(256, |x, _| (x / 2) as u8);
        let r = choose(256, 256, &rgba, CLAMP, &probes, "validation", BOUND_DB).unwrap();
        assert_eq!(r.width, MIN_SIZE, "{:?}", r.candidates);
    }

    #[test]
    fn high_frequency_fallback_keeps_full_size() {
        let (rgba, probes) = case(256, |x, y| if (x + y) % 2 == 0 { 20 } else { 230 });
        let r = choose(256, 256, &rgba, CLAMP, &probes, "validation", BOUND_DB).unwrap();
        assert_eq!((r.width, r.halvings), (256, 0));
        assert!(r.candidates[1].cost_db > 10.0, "{:?}", r.candidates);
    }

    #[test]
    fn small_or_unjudged_fallbacks_stay_as_they_are() {
        let (rgba, probes) = case(64, |_, _| 7);
        let r = choose(64, 64, &rgba, CLAMP, &probes, "validation", BOUND_DB).unwrap();
        assert_eq!((r.candidates.len(), r.width), (1, 64));
        let (rgba, _) = case(128, |_, _| 7);
        let r = choose(128, 128, &rgba, CLAMP, &[], "validation", BOUND_DB).unwrap();
        assert_eq!((r.width, r.views.as_str()), (128, "none"));
    }
}
