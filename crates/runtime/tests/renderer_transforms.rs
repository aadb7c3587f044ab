//! Node transforms: they move the object on screen, and view dependence is evaluated in the
//! primitive's local frame (the appearance moves with the object).

mod renderer_common;

use dnr_format::model::ViewDependence;
use dnr_format::{Node, WrapMode};
use dnr_runtime::camera::Camera;
use dnr_runtime::renderer::{Renderer, RgbaImage};
use glam::{Mat4, Quat, Vec3};
use renderer_common::*;

/// A 4 x 4 texture that varies per texel, on a unit quad, with a `none` renderer.
fn textured_quad(translation: [f32; 3]) -> Renderer {
    let mut s = Scene::new();
    let l = level(4, 4, 3, |x, y, c| ((x + 4 * y + c * 5) % 16) as f32 / 16.0);
    s.b.add_neural_texture(texture(vec![l], WrapMode::ClampToEdge, None));
    s.b.add_renderer(none_renderer(3));
    let m = s.material(0, 0);
    s.object(vec![quad(0.0, 0.0, 1.0, 0.0, Some(m))], translation);
    Renderer::from_asset(&s.build()).unwrap()
}

#[test]
fn translated_node_shifts_the_image() {
    // 16 pixels per unit: (0.25, -0.5) moves the quad 4 pixels right and 8 down.
    let cam = camera_down_z([0.0, 0.0, 2.0], 32.0, 64, 64);
    let a = textured_quad([0.0; 3]).render(&cam, 64, 64).unwrap();
    let b = textured_quad([0.25, -0.5, 0.0])
        .render(&cam, 64, 64)
        .unwrap();
    assert_ne!(a, b);
    let mut compared = 0;
    for y in 0..56 {
        for x in 0..60 {
            assert_close(
                px(&b, x + 4, y + 8),
                px(&a, x, y),
                1e-6,
                &format!("pixel ({x}, {y})"),
            );
            compared += (px(&a, x, y)[3] > 0.0) as usize;
        }
    }
    assert_eq!(compared, 32 * 32);
    // Nothing of b lies where a's quad started but b's does not.
    assert_eq!(px(&b, 17, 17), [0.0; 4]);
}

/// A quad whose texture is view dependent: SH degree 1 on channels 0..4 with F = (1, -1,
/// -1, 1), so colour = clamp(Y0, -Y1, -Y2) = (0.28, 0.49 d.y, -0.49 d.z) clamped.
fn sh_quad(node: Node) -> Renderer {
    let mut s = Scene::new();
    let vd = ViewDependence::spherical_harmonics(1, 0);
    let l = level(1, 1, 4, |_, _, c| [1.0, -1.0, -1.0, 1.0][c as usize]);
    s.b.add_neural_texture(texture(vec![l], WrapMode::Repeat, Some(vd)));
    s.b.add_renderer(none_renderer(4));
    let m = s.material(0, 0);
    let mesh = s.b.add_mesh(None, vec![quad(0.0, 0.0, 1.0, 0.0, Some(m))]);
    s.b.add_node(Node {
        mesh: Some(mesh),
        ..node
    });
    Renderer::from_asset(&s.build()).unwrap()
}

fn max_diff(a: &RgbaImage, b: &RgbaImage) -> f32 {
    a.data
        .iter()
        .zip(&b.data)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

#[test]
fn view_dependence_follows_the_node() {
    let base = camera_down_z([0.0, 0.3, 2.0], 32.0, 64, 64);
    let a = sh_quad(Node::default()).render(&base, 64, 64).unwrap();

    // The colour really depends on the direction: green grows towards the top (d.y > 0
    // above the eye) and blue is -0.49 d.z > 0.
    let top = px(&a, 32, 24);
    let bottom = px(&a, 32, 44);
    assert!(top[1] > bottom[1] + 0.05, "top {top:?} bottom {bottom:?}");
    assert!((top[0] - 0.282_094_8).abs() < 1e-6);
    assert!(top[2] > 0.3);

    // Analytic check at one pixel: the ray through pixel (32, 24)'s centre. (The
    // rasteriser snaps vertices to 1/256 pixel, which moves the interpolated surface point
    // and so d by up to ~1e-4 of a pixel's angle: hence the tolerance.)
    let d = Vec3::new(0.5 / 32.0, (32.0 - 24.5) / 32.0, -1.0).normalize();
    assert_close(
        top,
        [0.282_094_8, 0.488_602_5 * d.y, -0.488_602_5 * d.z, 1.0],
        1e-4,
        "SH pixel",
    );

    // Translating object and camera together changes nothing.
    let t = [5.0, -2.0, 1.5];
    let cam_t = Camera {
        cam_to_world: Mat4::from_translation(Vec3::from(t)) * base.cam_to_world,
        ..base
    };
    let b = sh_quad(Node {
        translation: t,
        ..Node::default()
    })
    .render(&cam_t, 64, 64)
    .unwrap();
    assert!(max_diff(&a, &b) < 1e-5, "translated: {}", max_diff(&a, &b));

    // Rotating and uniformly scaling them together changes nothing either.
    let q = Quat::from_axis_angle(Vec3::new(1.0, 2.0, 0.5).normalize(), 0.7);
    let cam_r = Camera {
        cam_to_world: Mat4::from_quat(q) * base.cam_to_world,
        ..base
    };
    let node = Node {
        rotation: q.to_array(),
        ..Node::default()
    };
    let c = sh_quad(node).render(&cam_r, 64, 64).unwrap();
    assert!(max_diff(&a, &c) < 1e-4, "rotated: {}", max_diff(&a, &c));

    // Rotating only the object (a quarter turn about Z: same silhouette) changes the
    // colours, since the direction is taken in the object's frame: local d.y = -world d.x.
    let quarter = Quat::from_rotation_z(std::f32::consts::FRAC_PI_2);
    let turned = sh_quad(Node {
        rotation: quarter.to_array(),
        ..Node::default()
    })
    .render(&base, 64, 64)
    .unwrap();
    let p = px(&turned, 32, 24);
    assert_close(
        p,
        [
            0.282_094_8,
            (-0.488_602_5 * d.x).max(0.0),
            -0.488_602_5 * d.z,
            1.0,
        ],
        1e-4,
        "turned",
    );
    assert!((p[1] - top[1]).abs() > 0.05, "{p:?} vs {top:?}");
}
