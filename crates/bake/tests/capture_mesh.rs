//! OBJ and PLY proxy-mesh loaders on small handwritten files.

use std::path::Path;

use dnr_bake::capture::mesh::{parse_obj, parse_ply, MeshLimits};
use dnr_bake::capture::{load_mesh, CaptureError};
use glam::{Vec2, Vec3};

/// Triangles as (position, uv) corner triples, for order-independent comparison of vertices.
fn corners(p: &dnr_runtime::scene::Primitive) -> Vec<[(Vec3, Vec2); 3]> {
    p.indices
        .chunks_exact(3)
        .map(|t| std::array::from_fn(|k| (p.positions[t[k] as usize], p.uvs[t[k] as usize])))
        .collect()
}

#[test]
fn obj_polygons_negative_indices_all_corner_forms_and_v_flip() {
    let text = "\
# a unit square as a quad, then a triangle with negative indices
mtllib x.mtl
o square
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
vn 0 0 1
usemtl m
s off
f 1/1/1 2/2/1 3/3/1 4/4/1
v 2 0 0
vt 0.25 0.75
f -1/-1 2/2 3/3/1   # same vertex 2/2 as above: welded
l 1 2
";
    let limits = MeshLimits::default();
    let p = parse_obj(Path::new("t.obj"), text, &limits).unwrap();
    // Quad fan: (1,2,3), (1,3,4); then (5,2,3).
    let t = corners(&p);
    assert_eq!(t.len(), 3);
    let c = |x: f32, y: f32, u: f32, v: f32| (Vec3::new(x, y, 0.0), Vec2::new(u, v));
    assert_eq!(
        t[0],
        [c(0., 0., 0., 1.), c(1., 0., 1., 1.), c(1., 1., 1., 0.)]
    );
    assert_eq!(
        t[1],
        [c(0., 0., 0., 1.), c(1., 1., 1., 0.), c(0., 1., 0., 0.)]
    );
    assert_eq!(
        t[2],
        [c(2., 0., 0.25, 0.25), c(1., 0., 1., 1.), c(1., 1., 1., 0.)]
    );
    // Welding: 5 distinct (v, vt) pairs.
    assert_eq!(p.positions.len(), 5);
    assert_eq!(p.uvs.len(), 5);
}

#[test]
fn obj_seam_vertices_are_split_by_uv() {
    // Vertex 1 used with two different vt: two output vertices.
    let text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nvt 0.5 0.5\nf 1/1 2/2 3/3\nf 1/4 3/3 2/2\n";
    let p = parse_obj(Path::new("t.obj"), text, &MeshLimits::default()).unwrap();
    assert_eq!(p.positions.len(), 4);
    assert_eq!(p.indices.len(), 6);
}

#[test]
fn obj_errors_name_file_and_line() {
    let l = MeshLimits::default();
    let e = parse_obj(
        Path::new("bad.obj"),
        "v 0 0 0\nv 1 0 0\nvt 0 0\nf 1/1 2/1 7/1\n",
        &l,
    )
    .unwrap_err();
    assert!(e.to_string().starts_with("bad.obj: line 4:"), "{e}");
    let e = parse_obj(Path::new("bad.obj"), "v 0 0\n", &l).unwrap_err();
    assert!(e.to_string().starts_with("bad.obj: line 1:"), "{e}");
    let e = parse_obj(
        Path::new("bad.obj"),
        "v 0 0 0\nv 1 0 0\nvt 0 0\nf 1/1 2/1\n",
        &l,
    )
    .unwrap_err();
    assert!(e.to_string().contains("at least 3"), "{e}");
    // A corner without vt: the mesh is read without UVs (an atlas is generated later).
    let p = parse_obj(
        Path::new("nouv.obj"),
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/1 3\n",
        &l,
    )
    .unwrap();
    assert!(p.uvs.is_empty() && p.positions.len() == 3 && p.indices.len() == 3);
    let small = MeshLimits {
        max_triangles: 1,
        ..l
    };
    let e = parse_obj(
        Path::new("big.obj"),
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nf 1/1 2/1 3/1 4/1\n",
        &small,
    )
    .unwrap_err();
    assert!(matches!(e, CaptureError::MeshTooLarge { .. }), "{e}");
}

const PLY_ASCII: &str = "ply
format ascii 1.0
comment made by hand
element vertex 4
property float x
property float y
property float z
property float nx
property float s
property float t
element face 1
property list uchar int vertex_indices
element edge 1
property int vertex1
property int vertex2
end_header
0 0 0 9 0 0
1 0 0 9 1 0
1 1 0 9 1 1
0 1 0 9 0 1
4 0 1 2 3
0 1
";

#[test]
fn ply_ascii_with_s_t() {
    let p = parse_ply(
        Path::new("q.ply"),
        PLY_ASCII.as_bytes(),
        &MeshLimits::default(),
    )
    .unwrap();
    assert_eq!(p.indices, vec![0, 1, 2, 0, 2, 3]);
    assert_eq!(p.positions[2], Vec3::new(1.0, 1.0, 0.0));
    // t up -> v down.
    assert_eq!(p.uvs[0], Vec2::new(0.0, 1.0));
    assert_eq!(p.uvs[2], Vec2::new(1.0, 0.0));
}

fn ply_binary(big_endian: bool, with_uv: bool) -> Vec<u8> {
    let fmt = if big_endian {
        "binary_big_endian"
    } else {
        "binary_little_endian"
    };
    let uvp = if with_uv {
        "property float texture_u\nproperty float texture_v\n"
    } else {
        ""
    };
    let mut b = format!(
        "ply\nformat {fmt} 1.0\nelement vertex 3\nproperty double x\nproperty double y\nproperty double z\n{uvp}property uchar red\nelement face 1\nproperty uchar flags\nproperty list uchar uint vertex_indices\nend_header\n"
    )
    .into_bytes();
    let f64b = |x: f64| {
        if big_endian {
            x.to_be_bytes().to_vec()
        } else {
            x.to_le_bytes().to_vec()
        }
    };
    let f32b = |x: f32| {
        if big_endian {
            x.to_be_bytes().to_vec()
        } else {
            x.to_le_bytes().to_vec()
        }
    };
    let u32b = |x: u32| {
        if big_endian {
            x.to_be_bytes().to_vec()
        } else {
            x.to_le_bytes().to_vec()
        }
    };
    for (i, (x, y)) in [(0.0, 0.0), (2.0, 0.0), (0.0, 3.0)].into_iter().enumerate() {
        b.extend(f64b(x));
        b.extend(f64b(y));
        b.extend(f64b(-1.0));
        if with_uv {
            b.extend(f32b(i as f32 * 0.25));
            b.extend(f32b(0.75));
        }
        b.push(200);
    }
    b.push(7);
    b.push(3);
    for i in [0u32, 1, 2] {
        b.extend(u32b(i));
    }
    b
}

#[test]
fn ply_binary_little_and_big_endian() {
    for big in [false, true] {
        let p = parse_ply(
            Path::new("b.ply"),
            &ply_binary(big, true),
            &MeshLimits::default(),
        )
        .unwrap();
        assert_eq!(p.indices, vec![0, 1, 2]);
        assert_eq!(
            p.positions,
            vec![
                Vec3::new(0., 0., -1.),
                Vec3::new(2., 0., -1.),
                Vec3::new(0., 3., -1.)
            ]
        );
        assert_eq!(p.uvs[2], Vec2::new(0.5, 0.25));
    }
}

#[test]
fn ply_errors() {
    let l = MeshLimits::default();
    let p = parse_ply(Path::new("nouv.ply"), &ply_binary(false, false), &l).unwrap();
    assert!(p.uvs.is_empty() && !p.indices.is_empty());
    let mut truncated = ply_binary(false, true);
    truncated.truncate(truncated.len() - 3);
    let e = parse_ply(Path::new("trunc.ply"), &truncated, &l).unwrap_err();
    assert!(
        e.to_string().starts_with("trunc.ply: element face[0]"),
        "{e}"
    );
    let huge = "ply\nformat binary_little_endian 1.0\nelement vertex 1000000\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
    let e = parse_ply(Path::new("huge.ply"), huge.as_bytes(), &l).unwrap_err();
    assert!(e.to_string().contains("does not fit"), "{e}");
    let bad_index = PLY_ASCII.replace("4 0 1 2 3", "4 0 1 2 9");
    let e = parse_ply(Path::new("idx.ply"), bad_index.as_bytes(), &l).unwrap_err();
    assert!(e.to_string().starts_with("idx.ply: line 21:"), "{e}");
}

#[test]
fn ply_per_corner_texcoord_list() {
    let text = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 2\nproperty list uchar int vertex_indices\nproperty list uchar float texcoord\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2 6 0 0 1 0 0 1\n3 0 2 1 6 0.5 0.5 0 1 1 0\n";
    let p = parse_ply(Path::new("tc.ply"), text.as_bytes(), &MeshLimits::default()).unwrap();
    assert_eq!(p.indices.len(), 6);
    // Vertex 0 has two different UVs (split); vertices 1 and 2 repeat theirs (welded).
    assert_eq!(p.positions.len(), 4);
    assert_eq!(p.uvs[p.indices[3] as usize], Vec2::new(0.5, 0.5));
}

#[test]
fn load_mesh_dispatches_by_extension() {
    let dir = tempfile::tempdir().unwrap();
    let obj = dir.path().join("Q.OBJ");
    std::fs::write(
        &obj,
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n",
    )
    .unwrap();
    let s = load_mesh(&obj, &MeshLimits::default()).unwrap();
    assert_eq!(s.primitives.len(), 1);
    assert_eq!(s.primitives[0].indices.len(), 3);
    let ply = dir.path().join("q.ply");
    std::fs::write(&ply, PLY_ASCII).unwrap();
    let s = load_mesh(&ply, &MeshLimits::default()).unwrap();
    assert_eq!(s.primitives[0].indices.len(), 6);
    let e = load_mesh(&dir.path().join("q.fbx"), &MeshLimits::default()).unwrap_err();
    assert!(matches!(e, CaptureError::MeshFormat { .. }));
}
