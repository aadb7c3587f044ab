//! Pinhole cameras in the capture convention (OpenGL: the camera looks along its local -Z,
//! +Y up, +X right; `cam_to_world` maps camera space to world space).

use glam::{Mat4, Vec3};

/// A pinhole camera with pixel intrinsics and a camera-to-world pose.
///
/// Pixel (px, py) has its centre at (px + 0.5, py + 0.5); py grows downwards. The ray through
/// image point (x, y) has camera-space direction `((x - cx) / fx, -(y - cy) / fy, -1)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Focal length in pixels along x.
    pub fx: f32,
    /// Focal length in pixels along y.
    pub fy: f32,
    /// Principal point x in pixels (from the left edge).
    pub cx: f32,
    /// Principal point y in pixels (from the top edge).
    pub cy: f32,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Camera-to-world matrix (OpenGL camera convention).
    pub cam_to_world: Mat4,
}

impl Camera {
    /// A camera from a horizontal field of view (radians), as NeRF's `camera_angle_x`; square
    /// pixels, principal point at the image centre.
    pub fn from_fov_x(fov_x: f32, width: u32, height: u32, cam_to_world: Mat4) -> Self {
        let fx = 0.5 * width as f32 / (0.5 * fov_x).tan();
        Camera {
            fx,
            fy: fx,
            cx: 0.5 * width as f32,
            cy: 0.5 * height as f32,
            width,
            height,
            cam_to_world,
        }
    }

    /// A camera at `eye` looking at `target` with +Y up and a vertical field of view in degrees.
    pub fn look_at(eye: Vec3, target: Vec3, fov_y_deg: f32, width: u32, height: u32) -> Self {
        let fy = 0.5 * height as f32 / (0.5 * fov_y_deg.to_radians()).tan();
        let mut up = Vec3::Y;
        let fwd = (target - eye).normalize_or_zero();
        if fwd.cross(up).length_squared() < 1e-12 {
            up = Vec3::Z;
        }
        // Camera axes: +X right, +Y up, looking along -Z.
        let z = -fwd;
        let x = up.cross(z).normalize();
        let y = z.cross(x);
        Camera {
            fx: fy,
            fy,
            cx: 0.5 * width as f32,
            cy: 0.5 * height as f32,
            width,
            height,
            cam_to_world: Mat4::from_cols(
                x.extend(0.0),
                y.extend(0.0),
                z.extend(0.0),
                eye.extend(1.0),
            ),
        }
    }

    /// The camera centre in world space.
    pub fn eye(&self) -> Vec3 {
        self.cam_to_world.w_axis.truncate()
    }
}
