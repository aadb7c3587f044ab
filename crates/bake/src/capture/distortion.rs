//! Lens models of capture cameras: the forward model (undistorted normalised coordinates to
//! distorted ones) in closed form, and its inverse by Newton's method.
//!
//! Normalised coordinates are `((x - cx) / fx, (y - cy) / fy)` in the OpenCV / COLMAP
//! camera (x right, y down, looking along +z), with pixel centres at half-integers.
//!
//! - [`LensModel::OpenCv`]: `r2 = x^2 + y^2`,
//!   `radial = 1 + k1 r2 + k2 r2^2 + k3 r2^3 + k4 r2^4`,
//!   `xd = x radial + 2 p1 x y + p2 (r2 + 2 x^2)`, `yd = y radial + p1 (r2 + 2 y^2) + 2 p2 x y`.
//!   This is COLMAP's OPENCV (k3 = k4 = 0), RADIAL and SIMPLE_RADIAL (p1 = p2 = 0) and
//!   nerfstudio's OPENCV, whose `k4` is the r^8 term as above (not OpenCV's rational k4).
//! - [`LensModel::Fisheye`]: OpenCV's fisheye model (COLMAP's OPENCV_FISHEYE, instant-ngp's
//!   `is_fisheye`): `theta = atan(r)`, `theta_d = theta (1 + k1 theta^2 + k2 theta^4 +
//!   k3 theta^6 + k4 theta^8)`, `(xd, yd) = (x, y) theta_d / r`.
//! - [`LensModel::Pinhole`]: no distortion.

use serde::Serialize;

/// Which distortion formula the coefficients of a [`Distortion`] go into.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub enum LensModel {
    /// An ideal pinhole camera: the coefficients are ignored.
    #[default]
    Pinhole,
    /// OpenCV radial-tangential: k1..k4 radial (r^2 .. r^8), p1, p2 tangential.
    OpenCv,
    /// OpenCV fisheye (equidistant with a polynomial in theta): k1..k4.
    Fisheye,
}

impl LensModel {
    /// The name used in `transforms.json` and by COLMAP.
    pub fn name(self) -> &'static str {
        match self {
            LensModel::Pinhole => "PINHOLE",
            LensModel::OpenCv => "OPENCV",
            LensModel::Fisheye => "OPENCV_FISHEYE",
        }
    }
}

/// A lens model and its coefficients (zero when absent).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Distortion {
    /// The formula.
    pub model: LensModel,
    /// First radial coefficient.
    pub k1: f64,
    /// Second radial coefficient.
    pub k2: f64,
    /// Third radial coefficient.
    pub k3: f64,
    /// Fourth radial coefficient.
    pub k4: f64,
    /// First tangential coefficient (OpenCV model only).
    pub p1: f64,
    /// Second tangential coefficient (OpenCV model only).
    pub p2: f64,
}

/// Newton iterations of [`Distortion::undistort`] before it gives up.
const NEWTON_ITERATIONS: usize = 50;

impl Distortion {
    /// An OpenCV radial-tangential lens.
    pub fn opencv(k1: f64, k2: f64, p1: f64, p2: f64) -> Self {
        Distortion {
            model: LensModel::OpenCv,
            k1,
            k2,
            p1,
            p2,
            ..Default::default()
        }
    }

    /// An OpenCV fisheye lens.
    pub fn fisheye(k1: f64, k2: f64, k3: f64, k4: f64) -> Self {
        Distortion {
            model: LensModel::Fisheye,
            k1,
            k2,
            k3,
            k4,
            ..Default::default()
        }
    }

    /// True when the forward model is the identity (a pinhole camera, or OpenCV with every
    /// coefficient zero). A fisheye lens never is: it maps `tan(theta)` to `theta`.
    pub fn is_identity(&self) -> bool {
        match self.model {
            LensModel::Pinhole => true,
            LensModel::OpenCv => {
                self.k1 == 0.0
                    && self.k2 == 0.0
                    && self.k3 == 0.0
                    && self.k4 == 0.0
                    && self.p1 == 0.0
                    && self.p2 == 0.0
            }
            LensModel::Fisheye => false,
        }
    }

    /// Maps undistorted normalised coordinates to distorted ones (the forward model, closed
    /// form; see the module documentation).
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        match self.model {
            LensModel::Pinhole => (x, y),
            LensModel::OpenCv => {
                let r2 = x * x + y * y;
                let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * (self.k3 + r2 * self.k4)));
                let xd = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x);
                let yd = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y;
                (xd, yd)
            }
            LensModel::Fisheye => {
                let r = (x * x + y * y).sqrt();
                if r < 1e-12 {
                    return (x, y);
                }
                let s = self.fisheye_scale(r.atan()) / r;
                (x * s, y * s)
            }
        }
    }

    /// `theta_d` of the fisheye model for an angle `theta` off the axis.
    fn fisheye_scale(&self, theta: f64) -> f64 {
        let t2 = theta * theta;
        theta * (1.0 + t2 * (self.k1 + t2 * (self.k2 + t2 * (self.k3 + t2 * self.k4))))
    }

    /// Inverts [`Distortion::distort`] by Newton's method: the undistorted normalised
    /// coordinates that distort to `(xd, yd)`, or None where the iteration does not converge
    /// to 1e-12 (outside the region where the model is invertible).
    pub fn undistort(&self, xd: f64, yd: f64) -> Option<(f64, f64)> {
        match self.model {
            LensModel::Pinhole => Some((xd, yd)),
            LensModel::OpenCv => {
                let (mut x, mut y) = (xd, yd);
                for _ in 0..NEWTON_ITERATIONS {
                    let (fx, fy) = self.distort(x, y);
                    let (ex, ey) = (fx - xd, fy - yd);
                    if ex.abs() < 1e-12 && ey.abs() < 1e-12 {
                        return Some((x, y));
                    }
                    let [[a, b], [c, d]] = self.opencv_jacobian(x, y);
                    let det = a * d - b * c;
                    if det.abs() < 1e-15 || !det.is_finite() {
                        return None;
                    }
                    x -= (d * ex - b * ey) / det;
                    y -= (-c * ex + a * ey) / det;
                }
                None
            }
            LensModel::Fisheye => {
                let rd = (xd * xd + yd * yd).sqrt();
                if rd < 1e-12 {
                    return Some((xd, yd));
                }
                // Solve theta_d(theta) = rd on [0, pi/2).
                let mut t = rd.min(1.5);
                for _ in 0..NEWTON_ITERATIONS {
                    let f = self.fisheye_scale(t) - rd;
                    if f.abs() < 1e-12 {
                        if !(0.0..std::f64::consts::FRAC_PI_2).contains(&t) {
                            return None;
                        }
                        let s = t.tan() / rd;
                        return Some((xd * s, yd * s));
                    }
                    let t2 = t * t;
                    let df = 1.0
                        + t2 * (3.0 * self.k1
                            + t2 * (5.0 * self.k2 + t2 * (7.0 * self.k3 + t2 * 9.0 * self.k4)));
                    if df.abs() < 1e-15 {
                        return None;
                    }
                    t -= f / df;
                }
                None
            }
        }
    }

    /// Jacobian `[[dxd/dx, dxd/dy], [dyd/dx, dyd/dy]]` of the OpenCV model.
    fn opencv_jacobian(&self, x: f64, y: f64) -> [[f64; 2]; 2] {
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * (self.k3 + r2 * self.k4)));
        // d radial / d r2
        let dr = self.k1 + r2 * (2.0 * self.k2 + r2 * (3.0 * self.k3 + r2 * 4.0 * self.k4));
        let (p1, p2) = (self.p1, self.p2);
        let dxdx = radial + 2.0 * x * x * dr + 2.0 * p1 * y + 6.0 * p2 * x;
        let dxdy = 2.0 * x * y * dr + 2.0 * p1 * x + 2.0 * p2 * y;
        let dydx = 2.0 * x * y * dr + 2.0 * p1 * x + 2.0 * p2 * y;
        let dydy = radial + 2.0 * y * y * dr + 6.0 * p1 * y + 2.0 * p2 * x;
        [[dxdx, dxdy], [dydx, dydy]]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identity_and_radial() {
        let d = Distortion::default();
        assert!(d.is_identity());
        assert_eq!(d.distort(0.3, -0.2), (0.3, -0.2));
        let d = Distortion::opencv(0.1, 0.0, 0.0, 0.0);
        let (x, y) = d.distort(0.5, 0.0);
        assert!((x - 0.5 * (1.0 + 0.1 * 0.25)).abs() < 1e-15 && y == 0.0);
        assert!(!Distortion::fisheye(0.0, 0.0, 0.0, 0.0).is_identity());
    }

    #[test]
    fn jacobian_matches_finite_differences() {
        let d = Distortion {
            model: LensModel::OpenCv,
            k1: -0.2,
            k2: 0.07,
            k3: -0.01,
            k4: 0.002,
            p1: 0.003,
            p2: -0.002,
        };
        let (x, y) = (0.31, -0.22);
        let j = d.opencv_jacobian(x, y);
        let h = 1e-7;
        let (a0, b0) = d.distort(x - h, y);
        let (a1, b1) = d.distort(x + h, y);
        let (c0, e0) = d.distort(x, y - h);
        let (c1, e1) = d.distort(x, y + h);
        let num = [
            [(a1 - a0) / (2.0 * h), (c1 - c0) / (2.0 * h)],
            [(b1 - b0) / (2.0 * h), (e1 - e0) / (2.0 * h)],
        ];
        for r in 0..2 {
            for c in 0..2 {
                assert!((j[r][c] - num[r][c]).abs() < 1e-6, "{j:?} {num:?}");
            }
        }
    }
}
