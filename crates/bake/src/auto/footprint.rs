//! How much texture detail the training images can resolve: the footprint of a pixel in uv
//! space, measured on the rasterised training views.
//!
//! At an interior object pixel the proxy's uv changes by `J = d(u, v)/d(x, y)` per pixel
//! (finite differences with the right and lower neighbours on the same primitive). The
//! pixel covers `sqrt(|det J|)` of the uv square along each side, so a level of side `R`
//! has `R sqrt(|det J|)` texels per pixel side there. A level whose texels are much smaller
//! than every pixel that sees them is not determined by the images: its values are fitted
//! between the pixel samples, that is, to noise. The finest level auto trains is the side
//! at which a pixel of the closer views (a low quantile of the footprint) spans about one
//! texel.

use serde::Serialize;

use crate::train::views::View;

/// Footprint quantile that sets the finest resolution (the closer views' pixels).
pub const QUANTILE: f64 = 0.1;
/// Texels per pixel side wanted at that quantile on the finest level.
pub const TEXELS_PER_PIXEL: f64 = 1.0;
/// Pixels sampled per view (a regular stride over the interior object pixels).
const SAMPLES_PER_VIEW: usize = 4096;

/// The measured footprints.
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Footprint {
    /// Pixels measured.
    pub samples: usize,
    /// uv length per pixel side at quantiles 0.1, 0.25, 0.5, 0.75, 0.9.
    pub quantiles: [f64; 5],
    /// The finest-level side at which a pixel at [`QUANTILE`] spans [`TEXELS_PER_PIXEL`]
    /// texels (rounded to a power of two; 0 when nothing could be measured).
    pub resolution: u32,
}

/// Measures the footprints on `views`.
pub fn measure(views: &[View]) -> Footprint {
    let mut ells = Vec::new();
    for v in views {
        let (w, h) = (v.width(), v.height());
        let g = &v.gbuf;
        let interior = |i: usize| g.coverage[i] > 0.0 && v.alpha[i] >= 0.99;
        let mut cand = Vec::new();
        for y in 0..h.saturating_sub(1) {
            for x in 0..w.saturating_sub(1) {
                let i = y * w + x;
                let (r, d) = (i + 1, i + w);
                if interior(i)
                    && interior(r)
                    && interior(d)
                    && g.prim[i] == g.prim[r]
                    && g.prim[i] == g.prim[d]
                {
                    cand.push(i);
                }
            }
        }
        let stride = cand.len().div_ceil(SAMPLES_PER_VIEW).max(1);
        for &i in cand.iter().step_by(stride) {
            let (a, r, d) = (g.uv[i], g.uv[i + 1], g.uv[i + w]);
            let j = [r[0] - a[0], d[0] - a[0], r[1] - a[1], d[1] - a[1]];
            let det = (f64::from(j[0]) * f64::from(j[3]) - f64::from(j[1]) * f64::from(j[2])).abs();
            let ell = det.sqrt();
            // A jump across a uv seam is not a footprint.
            if ell.is_finite() && ell > 0.0 && ell < 0.05 {
                ells.push(ell);
            }
        }
    }
    if ells.is_empty() {
        return Footprint {
            samples: 0,
            quantiles: [f64::NAN; 5],
            resolution: 0,
        };
    }
    ells.sort_by(f64::total_cmp);
    let q = |p: f64| ells[((p * (ells.len() - 1) as f64).round() as usize).min(ells.len() - 1)];
    let at = q(QUANTILE);
    let side = TEXELS_PER_PIXEL / at;
    Footprint {
        samples: ells.len(),
        quantiles: [q(0.1), q(0.25), q(0.5), q(0.75), q(0.9)],
        resolution: 2f64.powf(side.log2().round()).clamp(1.0, 1e9) as u32,
    }
}
