//! Where a view's error lies with respect to the proxy's silhouette: the question a coarse
//! proxy raises. A pixel is *object* where the photograph's alpha exceeds 0.5 and *covered*
//! where the proxy mesh is rasterised; the frame's squared error (composited on white, 8-bit,
//! as its PSNR) splits into:
//!
//! - `inside`: object and covered: the texture and the network had a surface to work with;
//! - `missed`: object, not covered: only a 4-channel network can paint it, from features
//!   within its receptive field of the silhouette (split by distance to the nearest covered
//!   pixel, in pixels);
//! - `excess`: covered, not object: the network's alpha must erase it;
//! - `background`: neither.
//!
//! Shares of the error that sit in `missed` and `excess` are what better features and a
//! larger network cannot remove without alpha; `missed` far beyond the receptive field is
//! what no network of that size can reach.
//!
//! Across those four, `silhouette` counts the photograph's anti-aliased outline: pixels of
//! partial alpha ([`EDGE_ALPHA`]) and their 4-neighbours. The rasteriser samples one point
//! per pixel, so the feature image has no partial coverage there; a large share of the
//! error in this band (with an exact proxy) says the outline's anti-aliasing, not the
//! surface, limits the result.

use serde::Serialize;

/// Upper bounds (pixels, chessboard distance) of the distance bins of missed pixels; the
/// last bin holds everything farther.
pub const DISTANCE_BINS: [u32; 5] = [1, 2, 4, 8, 16];

/// Alpha strictly between these bounds is a partly covered (anti-aliased) pixel of the
/// photograph's outline; 8-bit masks round fully covered or empty pixels to within 1/255.
pub const EDGE_ALPHA: (f32, f32) = (0.02, 0.98);

/// One region's pixels and squared error.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Region {
    /// Pixels in the region.
    pub pixels: usize,
    /// Sum of squared 8-bit differences over R, G, B.
    pub squared_error: f64,
}

impl Region {
    fn add(&mut self, se: f64) {
        self.pixels += 1;
        self.squared_error += se;
    }

    fn merge(&mut self, o: &Region) {
        self.pixels += o.pixels;
        self.squared_error += o.squared_error;
    }

    /// Mean squared error per channel value in the region (0 when empty).
    pub fn mse(&self) -> f64 {
        self.squared_error / (3 * self.pixels.max(1)) as f64
    }
}

/// The error of one view (or a sum of views) by region.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Regions {
    /// Object pixels the proxy covers.
    pub inside: Region,
    /// Object pixels the proxy misses.
    pub missed: Region,
    /// Covered pixels outside the object.
    pub excess: Region,
    /// Pixels of neither.
    pub background: Region,
    /// `missed` split by chessboard distance to the nearest covered pixel: bin `k` holds
    /// distances up to [`DISTANCE_BINS`]`[k]` (and above the previous bound); the last holds
    /// the rest (and every missed pixel of a frame the proxy does not cover at all).
    pub missed_by_distance: Vec<Region>,
    /// The photograph's outline band (overlaps the four regions above): pixels of partial
    /// alpha and their 4-neighbours.
    pub silhouette: Region,
}

impl Regions {
    /// Adds another view's regions.
    pub fn merge(&mut self, o: &Regions) {
        self.inside.merge(&o.inside);
        self.missed.merge(&o.missed);
        self.excess.merge(&o.excess);
        self.background.merge(&o.background);
        self.silhouette.merge(&o.silhouette);
        if self.missed_by_distance.len() < o.missed_by_distance.len() {
            self.missed_by_distance
                .resize(o.missed_by_distance.len(), Region::default());
        }
        for (a, b) in self
            .missed_by_distance
            .iter_mut()
            .zip(&o.missed_by_distance)
        {
            a.merge(b);
        }
    }

    /// Total squared error.
    pub fn squared_error(&self) -> f64 {
        self.inside.squared_error
            + self.missed.squared_error
            + self.excess.squared_error
            + self.background.squared_error
    }

    /// Share (0..1) of the total squared error in a region.
    pub fn share(&self, r: &Region) -> f64 {
        let t = self.squared_error();
        if t > 0.0 {
            r.squared_error / t
        } else {
            0.0
        }
    }
}

/// Splits a view's error by region. `render` and `truth` are the frames composited on white
/// (8-bit RGB, as [`super::metrics::on_white_u8`] gives), `alpha` the photograph's alpha,
/// `covered` the proxy's coverage, `valid` the pixels that count (None: all).
pub fn split(
    render: &[u8],
    truth: &[u8],
    alpha: &[f32],
    covered: &[bool],
    valid: Option<&[bool]>,
    width: usize,
    height: usize,
) -> Regions {
    let n = width * height;
    assert!(render.len() == 3 * n && truth.len() == 3 * n);
    assert!(alpha.len() == n && covered.len() == n);
    let dist = distance_to_covered(covered, width, height);
    let band = silhouette_band(alpha, width, height);
    let mut r = Regions {
        missed_by_distance: vec![Region::default(); DISTANCE_BINS.len() + 1],
        ..Regions::default()
    };
    for i in 0..n {
        if valid.is_some_and(|v| !v[i]) {
            continue;
        }
        let se: f64 = (0..3)
            .map(|c| {
                let d = f64::from(render[3 * i + c]) - f64::from(truth[3 * i + c]);
                d * d
            })
            .sum();
        if band[i] {
            r.silhouette.add(se);
        }
        match (alpha[i] > 0.5, covered[i]) {
            (true, true) => r.inside.add(se),
            (true, false) => {
                r.missed.add(se);
                let bin = DISTANCE_BINS
                    .iter()
                    .position(|&b| dist[i] <= b)
                    .unwrap_or(DISTANCE_BINS.len());
                r.missed_by_distance[bin].add(se);
            }
            (false, true) => r.excess.add(se),
            (false, false) => r.background.add(se),
        }
    }
    r
}

/// Pixels of partial alpha ([`EDGE_ALPHA`]) and their 4-neighbours.
pub fn silhouette_band(alpha: &[f32], width: usize, height: usize) -> Vec<bool> {
    let edge = |i: usize| alpha[i] > EDGE_ALPHA.0 && alpha[i] < EDGE_ALPHA.1;
    let mut band = vec![false; width * height];
    for y in 0..height {
        for x in 0..width {
            let i = y * width + x;
            band[i] = edge(i)
                || (x > 0 && edge(i - 1))
                || (x + 1 < width && edge(i + 1))
                || (y > 0 && edge(i - width))
                || (y + 1 < height && edge(i + width));
        }
    }
    band
}

/// Chessboard distance of every pixel to the nearest covered pixel (0 on covered pixels,
/// `u32::MAX` everywhere when nothing is covered): the two-pass chamfer transform.
pub fn distance_to_covered(covered: &[bool], width: usize, height: usize) -> Vec<u32> {
    const FAR: u32 = u32::MAX / 2;
    let mut d: Vec<u32> = covered.iter().map(|&c| if c { 0 } else { FAR }).collect();
    let at = |x: usize, y: usize| y * width + x;
    for y in 0..height {
        for x in 0..width {
            let mut v = d[at(x, y)];
            if x > 0 {
                v = v.min(d[at(x - 1, y)] + 1);
            }
            if y > 0 {
                v = v.min(d[at(x, y - 1)] + 1);
                if x > 0 {
                    v = v.min(d[at(x - 1, y - 1)] + 1);
                }
                if x + 1 < width {
                    v = v.min(d[at(x + 1, y - 1)] + 1);
                }
            }
            d[at(x, y)] = v;
        }
    }
    for y in (0..height).rev() {
        for x in (0..width).rev() {
            let mut v = d[at(x, y)];
            if x + 1 < width {
                v = v.min(d[at(x + 1, y)] + 1);
            }
            if y + 1 < height {
                v = v.min(d[at(x, y + 1)] + 1);
                if x + 1 < width {
                    v = v.min(d[at(x + 1, y + 1)] + 1);
                }
                if x > 0 {
                    v = v.min(d[at(x - 1, y + 1)] + 1);
                }
            }
            d[at(x, y)] = v;
        }
    }
    if d.iter().all(|&v| v >= FAR) {
        return vec![u32::MAX; d.len()];
    }
    d
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chessboard_distance_from_one_pixel() {
        let (w, h) = (7, 5);
        let mut c = vec![false; w * h];
        c[2 * w + 3] = true;
        let d = distance_to_covered(&c, w, h);
        for y in 0..h {
            for x in 0..w {
                let want = (x as i32 - 3).abs().max((y as i32 - 2).abs()) as u32;
                assert_eq!(d[y * w + x], want, "({x}, {y})");
            }
        }
        assert!(distance_to_covered(&[false; 4], 2, 2)
            .iter()
            .all(|&v| v == u32::MAX));
    }

    #[test]
    fn silhouette_band_is_partial_alpha_and_its_neighbours() {
        // 5x1, partial alpha at x = 2 only: the band is x = 1..=3.
        let alpha = [1.0, 1.0, 0.5, 0.0, 0.0];
        let band = silhouette_band(&alpha, 5, 1);
        assert_eq!(band, [false, true, true, true, false]);
        // Its error is counted there as well as in its region.
        let truth = [0u8; 15];
        let mut render = [0u8; 15];
        render[3 * 3] = 2; // x = 3: background, in the band
        render[0] = 1; // x = 0: inside, not in the band
        let covered = [true, true, false, false, false];
        let r = split(&render, &truth, &alpha, &covered, None, 5, 1);
        assert_eq!(
            r.silhouette,
            Region {
                pixels: 3,
                squared_error: 4.0
            }
        );
        assert_eq!(r.background.squared_error, 4.0);
        assert!((r.share(&r.silhouette) - 0.8).abs() < 1e-12);
        // A vertical edge: the band follows rows too.
        let alpha = [0.0, 0.3, 0.0, 0.0, 0.0, 0.0];
        assert_eq!(
            silhouette_band(&alpha, 2, 3),
            [true, true, false, true, false, false]
        );
    }

    #[test]
    fn error_lands_in_its_region() {
        // 4x1: inside, missed (1 px from cover), excess, background.
        let truth = [0u8; 12];
        let mut render = [0u8; 12];
        for (i, v) in [1u8, 2, 3, 4].into_iter().enumerate() {
            render[3 * i] = v;
        }
        let alpha = [1.0, 1.0, 0.0, 0.0];
        let covered = [true, false, true, false];
        let r = split(&render, &truth, &alpha, &covered, None, 4, 1);
        assert_eq!(
            r.inside,
            Region {
                pixels: 1,
                squared_error: 1.0
            }
        );
        assert_eq!(
            r.missed,
            Region {
                pixels: 1,
                squared_error: 4.0
            }
        );
        assert_eq!(
            r.excess,
            Region {
                pixels: 1,
                squared_error: 9.0
            }
        );
        assert_eq!(
            r.background,
            Region {
                pixels: 1,
                squared_error: 16.0
            }
        );
        assert_eq!(r.missed_by_distance[0].pixels, 1);
        assert!((r.share(&r.missed) - 4.0 / 30.0).abs() < 1e-12);
        assert_eq!(r.silhouette.pixels, 0, "hard alpha has no outline band");
        let invalid = [true, false, true, true];
        let r = split(&render, &truth, &alpha, &covered, Some(&invalid), 4, 1);
        assert_eq!(r.missed.pixels, 0);
    }
}
