//! Generated UV atlases on the shared and bundled meshes: every UV inside [0, 1]^2 and no two
//! triangles overlapping in UV space (checked pair by pair with a separating-axis test, not
//! with the loader's own raster measure), and the overlap measure on authored UVs.

mod capture_common;

use std::path::Path;

use capture_common::{sample_capture, shared_captures};
use dnr_bake::capture::uv_atlas::{ensure_uvs, overlap_fraction};
use dnr_bake::capture::{load_mesh, MeshLimits, UvMode};
use dnr_runtime::scene::Scene;
use glam::DVec2;

/// Triangles (in UV) of every primitive together.
fn uv_triangles(scene: &Scene) -> Vec<[DVec2; 3]> {
    scene
        .primitives
        .iter()
        .flat_map(|p| {
            p.indices
                .chunks_exact(3)
                .map(move |t| std::array::from_fn(|k| p.uvs[t[k] as usize].as_dvec2()))
        })
        .collect()
}

fn area(t: &[DVec2; 3]) -> f64 {
    0.5 * (t[1] - t[0]).perp_dot(t[2] - t[0])
}

/// Whether the interiors of two triangles overlap by more than `eps` along every axis that
/// could separate them (edge normals of both).
fn overlap(a: &[DVec2; 3], b: &[DVec2; 3], eps: f64) -> bool {
    for tri in [a, b] {
        for k in 0..3 {
            let e = tri[(k + 1) % 3] - tri[k];
            let n = DVec2::new(-e.y, e.x).normalize_or_zero();
            if n == DVec2::ZERO {
                return false;
            }
            let proj = |t: &[DVec2; 3]| {
                let v = t.map(|p| p.dot(n));
                (v[0].min(v[1]).min(v[2]), v[0].max(v[1]).max(v[2]))
            };
            let (a0, a1) = proj(a);
            let (b0, b1) = proj(b);
            if a1 <= b0 + eps || b1 <= a0 + eps {
                return false;
            }
        }
    }
    true
}

/// Pairs of triangles whose UV interiors overlap (degenerate UV triangles are skipped),
/// found through a uniform grid.
fn overlapping_pairs(tris: &[[DVec2; 3]]) -> Vec<(usize, usize)> {
    let g = 128usize;
    let mut cells: Vec<Vec<usize>> = vec![Vec::new(); g * g];
    let cell = |v: f64| ((v * g as f64).floor().max(0.0) as usize).min(g - 1);
    for (i, t) in tris.iter().enumerate() {
        if area(t).abs() < 1e-14 {
            continue;
        }
        let (x0, x1) = (
            cell(t.iter().map(|p| p.x).fold(f64::INFINITY, f64::min)),
            cell(t.iter().map(|p| p.x).fold(f64::NEG_INFINITY, f64::max)),
        );
        let (y0, y1) = (
            cell(t.iter().map(|p| p.y).fold(f64::INFINITY, f64::min)),
            cell(t.iter().map(|p| p.y).fold(f64::NEG_INFINITY, f64::max)),
        );
        for y in y0..=y1 {
            for x in x0..=x1 {
                cells[y * g + x].push(i);
            }
        }
    }
    let mut pairs = std::collections::BTreeSet::new();
    for c in &cells {
        for (k, &i) in c.iter().enumerate() {
            for &j in &c[k + 1..] {
                // 1e-7 of the texture: touching edges and shared vertices are not overlaps.
                if overlap(&tris[i], &tris[j], 1e-7) {
                    pairs.insert((i.min(j), i.max(j)));
                }
            }
        }
    }
    pairs.into_iter().collect()
}

fn meshes() -> Vec<std::path::PathBuf> {
    vec![
        shared_captures().join("duck/mesh.glb"),
        shared_captures().join("duck/mesh_coarse.glb"),
        sample_capture().join("mesh.glb"),
    ]
}

#[test]
fn generated_atlases_are_inside_the_unit_square_without_overlaps() {
    for path in meshes() {
        let mut scene = load_mesh(&path, &MeshLimits::default()).unwrap();
        let before: usize = scene.primitives.iter().map(|p| p.indices.len()).sum();
        for p in &mut scene.primitives {
            p.uvs.clear();
        }
        let report = ensure_uvs(&mut scene, &path, UvMode::Auto, 2_000_000).unwrap();
        assert!(report.generated, "{}", path.display());
        assert!(report.charts.unwrap() >= 1);
        assert!(report.texel_use > 0.4, "{report:?}");
        let after: usize = scene.primitives.iter().map(|p| p.indices.len()).sum();
        assert_eq!(before, after, "triangles kept");
        for p in &scene.primitives {
            assert_eq!(p.uvs.len(), p.positions.len());
            assert!(
                p.uvs
                    .iter()
                    .all(|uv| (0.0..=1.0).contains(&uv.x) && (0.0..=1.0).contains(&uv.y)),
                "{}",
                path.display()
            );
        }
        let tris = uv_triangles(&scene);
        let pairs = overlapping_pairs(&tris);
        assert!(
            pairs.is_empty(),
            "{}: {} overlapping triangle pairs, e.g. {:?}",
            path.display(),
            pairs.len(),
            pairs.first().map(|&(i, j)| (tris[i], tris[j]))
        );
        assert_eq!(overlap_fraction(&scene), Some(0.0), "{}", path.display());
    }
}

#[test]
fn overlap_is_measured_on_authored_uvs_and_decides_auto() {
    // The sample sphere's UVs are unique; the Duck's mirror its halves onto one another.
    let sphere = sample_capture().join("mesh.glb");
    let scene = load_mesh(&sphere, &MeshLimits::default()).unwrap();
    assert_eq!(overlap_fraction(&scene), Some(0.0));
    assert!(overlapping_pairs(&uv_triangles(&scene)).is_empty());
    let duck = shared_captures().join("duck/mesh.glb");
    let mut scene = load_mesh(&duck, &MeshLimits::default()).unwrap();
    let f = overlap_fraction(&scene).unwrap();
    assert!(f > 0.5, "{f}");
    // The independent pair test agrees that the authored UVs overlap.
    assert!(overlapping_pairs(&uv_triangles(&scene)).len() > 100);
    let kept = ensure_uvs(&mut scene.clone(), &duck, UvMode::Keep, 2_000_000).unwrap();
    assert!(!kept.generated && kept.overlap_fraction == Some(f));
    let auto = ensure_uvs(&mut scene, &duck, UvMode::Auto, 2_000_000).unwrap();
    assert!(
        auto.generated && auto.reason.contains("overlap"),
        "{auto:?}"
    );
    // Above the unwrap limit: refused with a message.
    let mut big = load_mesh(&duck, &MeshLimits::default()).unwrap();
    let msg = ensure_uvs(&mut big, Path::new("duck.glb"), UvMode::Generate, 1000)
        .unwrap_err()
        .to_string();
    assert!(
        msg.contains("duck.glb") && msg.contains("4212 triangles") && msg.contains("decimate"),
        "{msg}"
    );
}
