"""Renders the development set: posed-image captures unlike the Khronos Duck.

Run by Blender's `bpy` wheel (Blender 5.0.1) under plain Python 3.11; `make_devset.sh`
makes the virtual environment and calls this script. Everything is built here from
Blender primitives, modifiers and procedural or script-drawn textures; nothing is
downloaded. Deterministic: fixed view seeds, a fixed Cycles seed, fixed geometry.

Conventions follow the duck capture (see the README next to this file): Cycles CPU,
16 samples per pixel + OpenImageDenoise, 'Standard' view transform, exposure -0.6 EV,
sRGB 8-bit RGBA PNG with a transparent film (alpha is the object mask); the duck's
four lights and dim uniform world; world space = glTF space (+Y up) = mesh.glb; the
object normalised to bounding-box centre 0 and bounding radius 1; cameras at distance
3.6 looking at the origin, roll 0, camera_angle_x 0.6911112070083618.
"""

import argparse
import hashlib
import json
import math
import os
import shutil
import sys
import time

import bpy  # noqa: I001 (bpy first: it makes bmesh and mathutils importable)
import bmesh
import mathutils.noise
import numpy as np
from mathutils import Matrix, Vector
from PIL import Image, ImageDraw, ImageFont

CAMERA_ANGLE_X = 0.6911112070083618
CAMERA_RADIUS = 3.6
SAMPLES = 16
CYCLES_SEED = 0
EXPOSURE_EV = -0.6
WORLD_COLOR = 0.05
COARSE_RATIO = 0.1
TYRE_LOC = (-0.35, 0.05, 0.2)
TYRE_ROT_DEG = (0, 90, 15)
STRUT_RADIUS = 0.018
WIRE_RADIUS = 0.012
# Chart margin as a fraction of the uv square: 2 texels at 512^2, the baker's largest texture.
UV_MARGIN = 0.004
UV_ANGLE_LADDER_DEG = (66.0, 50.0, 35.0)

# The duck capture's lights, in glTF space (+Y up); area lights face the origin.
LIGHTS = [
    {"kind": "AREA", "position": [3.0, 4.5, 3.5], "power_w": 230.0, "size": 1.5, "color": [1.0, 0.97, 0.92]},
    {"kind": "AREA", "position": [-4.0, 2.5, 2.0], "power_w": 90.0, "size": 3.0, "color": [0.85, 0.9, 1.0]},
    {"kind": "AREA", "position": [0.5, 3.5, -4.5], "power_w": 150.0, "size": 1.0, "color": [1.0, 1.0, 1.0]},
    {"kind": "POINT", "position": [-1.5, 5.0, -2.0], "power_w": 60.0, "size": 0.15, "color": [1.0, 1.0, 1.0]},
]

# glTF (x, y, z) -> Blender (x, -z, y): what the glTF exporter's +Y-up conversion inverts.
GLTF_TO_BLENDER = Matrix(((1, 0, 0, 0), (0, 0, -1, 0), (0, 1, 0, 0), (0, 0, 0, 1)))


def gltf_to_blender(p):
    return Vector((p[0], -p[2], p[1]))


# ---------------------------------------------------------------------------------------
# Scene basics


def reset_scene():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    cy = scene.cycles
    cy.device = "CPU"
    cy.samples = SAMPLES
    cy.seed = CYCLES_SEED
    cy.use_animated_seed = False
    cy.use_denoising = True
    cy.denoiser = "OPENIMAGEDENOISE"
    scene.render.use_persistent_data = True
    scene.render.film_transparent = True
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = EXPOSURE_EV
    scene.view_settings.gamma = 1.0
    scene.display_settings.display_device = "sRGB"
    s = scene.render.image_settings
    s.file_format = "PNG"
    s.color_mode = "RGBA"
    s.color_depth = "8"
    s.compression = 15
    # No date, render time or host in the PNGs, so reruns give byte-identical files.
    for prop in scene.render.bl_rna.properties:
        if prop.identifier.startswith("use_stamp"):
            setattr(scene.render, prop.identifier, False)
    world = bpy.data.worlds.new("world")
    scene.world = world
    nodes = world.node_tree.nodes if world.node_tree else None
    if nodes is None:
        world.use_nodes = True
        nodes = world.node_tree.nodes
    bg = next(n for n in nodes if n.type == "BACKGROUND")
    bg.inputs["Color"].default_value = (WORLD_COLOR, WORLD_COLOR, WORLD_COLOR, 1.0)
    bg.inputs["Strength"].default_value = 1.0
    return scene


def add_lights(scene):
    for i, l in enumerate(LIGHTS):
        data = bpy.data.lights.new(f"light{i}", type=l["kind"])
        data.energy = l["power_w"]
        data.color = l["color"]
        if l["kind"] == "AREA":
            data.shape = "SQUARE"
            data.size = l["size"]
        else:
            data.shadow_soft_size = l["size"]
        obj = bpy.data.objects.new(f"light{i}", data)
        scene.collection.objects.link(obj)
        pos = gltf_to_blender(l["position"])
        # Area lights emit along their local -Z: aim it at the origin.
        rot = (-pos).to_track_quat("-Z", "Y")
        obj.matrix_world = Matrix.Translation(pos) @ rot.to_matrix().to_4x4()


def add_camera(scene, resolution):
    cam = bpy.data.cameras.new("camera")
    cam.sensor_fit = "HORIZONTAL"
    cam.angle = CAMERA_ANGLE_X
    cam.clip_start = 0.1
    cam.clip_end = 100.0
    obj = bpy.data.objects.new("camera", cam)
    scene.collection.objects.link(obj)
    scene.camera = obj
    scene.render.resolution_x = resolution
    scene.render.resolution_y = resolution
    scene.render.resolution_percentage = 100
    scene.render.pixel_aspect_x = 1.0
    scene.render.pixel_aspect_y = 1.0
    return obj


# ---------------------------------------------------------------------------------------
# Materials (node helpers)


def new_material(name):
    mat = bpy.data.materials.new(name)
    if mat.node_tree is None:
        mat.use_nodes = True
    return mat, mat.node_tree.nodes, mat.node_tree.links


def principled(nodes):
    return next(n for n in nodes if n.type == "BSDF_PRINCIPLED")


def obj_coords(nodes):
    tc = nodes.new("ShaderNodeTexCoord")
    return tc.outputs["Object"]


def color_ramp(nodes, links, factor_socket, stops):
    """A colour ramp from (position, linear RGB) stops, fed by `factor_socket`."""
    ramp = nodes.new("ShaderNodeValToRGB")
    els = ramp.color_ramp.elements
    while len(els) < len(stops):
        els.new(0.5)
    for el, (pos, rgb) in zip(els, stops):
        el.position = pos
        el.color = (*rgb, 1.0)
    links.new(factor_socket, ramp.inputs["Fac"])
    return ramp.outputs["Color"]


def noise(nodes, links, vector, scale, detail=2.0, roughness=0.5, distortion=0.0):
    n = nodes.new("ShaderNodeTexNoise")
    n.inputs["Scale"].default_value = scale
    n.inputs["Detail"].default_value = detail
    n.inputs["Roughness"].default_value = roughness
    n.inputs["Distortion"].default_value = distortion
    links.new(vector, n.inputs["Vector"])
    return n.outputs["Fac"]


def bump(nodes, links, height, strength, distance=0.02):
    b = nodes.new("ShaderNodeBump")
    b.inputs["Strength"].default_value = strength
    b.inputs["Distance"].default_value = distance
    links.new(height, b.inputs["Height"])
    return b.outputs["Normal"]


def set_bsdf(bsdf, **kw):
    names = {
        "base": "Base Color",
        "metallic": "Metallic",
        "roughness": "Roughness",
        "ior": "IOR",
        "specular": "Specular IOR Level",
        "coat": "Coat Weight",
        "coat_roughness": "Coat Roughness",
    }
    for k, v in kw.items():
        sock = bsdf.inputs[names[k]]
        sock.default_value = (*v, 1.0) if k == "base" else v


def image_from_array(name, rgb, colorspace="sRGB"):
    """A packed Blender image from an (H, W, 3) uint8 array whose row 0 is the top."""
    h, w, _ = rgb.shape
    img = bpy.data.images.new(name, width=w, height=h, alpha=False)
    img.colorspace_settings.name = colorspace
    rgba = np.concatenate([rgb.astype(np.float32) / 255.0, np.ones((h, w, 1), np.float32)], axis=2)
    # Blender's pixel rows start at the bottom.
    img.pixels.foreach_set(rgba[::-1].ravel())
    img.pack()
    return img


# ---------------------------------------------------------------------------------------
# Geometry helpers


def link(obj):
    bpy.context.scene.collection.objects.link(obj)
    return obj


def select_only(objs):
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    for o in objs:
        o.select_set(True)
    bpy.context.view_layer.objects.active = objs[0]


def apply_modifiers(obj):
    select_only([obj])
    for m in list(obj.modifiers):
        bpy.ops.object.modifier_apply(modifier=m.name)


def set_material(obj, mat):
    obj.data.materials.clear()
    obj.data.materials.append(mat)


def shade(obj, smooth_angle_deg=None):
    """Smooth shading; with an angle, edges sharper than it stay hard."""
    select_only([obj])
    if smooth_angle_deg is None:
        bpy.ops.object.shade_smooth()
    else:
        bpy.ops.object.shade_smooth_by_angle(angle=math.radians(smooth_angle_deg))


def transform(obj, loc=(0, 0, 0), rot_deg=(0, 0, 0), scale=(1, 1, 1)):
    obj.location = loc
    obj.rotation_euler = [math.radians(a) for a in rot_deg]
    obj.scale = scale
    select_only([obj])
    bpy.ops.object.transform_apply(location=True, rotation=True, scale=True)


def mesh_from_pydata(name, verts, faces):
    me = bpy.data.meshes.new(name)
    me.from_pydata([tuple(v) for v in verts], [], [tuple(f) for f in faces])
    me.validate()
    me.update()
    return link(bpy.data.objects.new(name, me))


def lathe(name, profile, segments):
    """Surface of revolution about Blender Z from (r, z) points, both ends closed by fans."""
    verts, faces = [], []
    n = len(profile)
    for j in range(segments):
        a = 2 * math.pi * j / segments
        for r, z in profile:
            verts.append((r * math.cos(a), r * math.sin(a), z))
    for j in range(segments):
        j1 = (j + 1) % segments
        for i in range(n - 1):
            faces.append((j * n + i, j1 * n + i, j1 * n + i + 1, j * n + i + 1))
    bottom = len(verts)
    verts.append((0.0, 0.0, profile[0][1]))
    top = len(verts)
    verts.append((0.0, 0.0, profile[-1][1]))
    for j in range(segments):
        j1 = (j + 1) % segments
        faces.append((bottom, j1 * n, j * n))
        faces.append((top, j * n + n - 1, j1 * n + n - 1))
    return mesh_from_pydata(name, verts, faces)


class Parts:
    """Accumulates vertices, faces and per-face-corner uvs, then makes one mesh object.

    The uvs of each part are its own chart(s) at true scale; `pack_uvs` arranges them later.
    """

    def __init__(self):
        self.verts, self.faces, self.uvs = [], [], []

    def add(self, verts, faces, uvs):
        base = len(self.verts)
        self.verts += [tuple(map(float, v)) for v in verts]
        self.faces += [tuple(base + i for i in f) for f in faces]
        self.uvs += uvs

    def object(self, name):
        obj = mesh_from_pydata(name, self.verts, self.faces)
        me = obj.data
        if len(me.polygons) != len(self.faces):
            raise RuntimeError(f"{name}: mesh validation changed the faces")
        layer = me.uv_layers.new(name="UVMap")
        flat = [c for face in self.uvs for uv in face for c in uv]
        layer.data.foreach_set("uv", flat)
        return obj


def tube(parts, pts, radius, sides, closed=False, pieces=1, caps=False):
    """A tube of `sides` facets along the polyline `pts` (parallel-transported frame).

    Its uv charts are unrolled rectangles (u round the tube, v along it), cut into `pieces`
    along its length so no chart is much longer than the object; caps are small disks.
    """
    pts = [np.asarray(p, np.float64) for p in pts]
    n = len(pts)
    tang = []
    for i in range(n):
        a = pts[(i - 1) % n] if (closed or i > 0) else pts[i]
        b = pts[(i + 1) % n] if (closed or i < n - 1) else pts[i]
        t = b - a
        tang.append(t / np.linalg.norm(t))
    helper = np.array([0.0, 0.0, 1.0]) if abs(tang[0][2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    nrm = np.cross(tang[0], helper)
    nrm /= np.linalg.norm(nrm)
    frames = []
    for i in range(n):
        if i > 0:  # parallel transport: remove the component along the new tangent
            nrm = nrm - tang[i] * nrm.dot(tang[i])
            nrm /= np.linalg.norm(nrm)
        frames.append((nrm, np.cross(tang[i], nrm)))
    verts = []
    for i in range(n):
        nv, bv = frames[i]
        for k in range(sides):
            th = 2 * math.pi * k / sides
            verts.append(pts[i] + radius * (math.cos(th) * nv + math.sin(th) * bv))
    nseg = n if closed else n - 1
    arc = [0.0]
    for i in range(nseg):
        arc.append(arc[-1] + float(np.linalg.norm(pts[(i + 1) % n] - pts[i])))
    circ = 2 * math.pi * radius
    starts = [None] * pieces
    faces, uvs = [], []
    for i in range(nseg):
        pc = min(pieces - 1, i * pieces // nseg)
        if starts[pc] is None:
            starts[pc] = arc[i]
        u0 = pc * (circ + 1.0)  # pieces apart, so no two share a uv
        i1 = (i + 1) % n
        for k in range(sides):
            k1 = (k + 1) % sides
            faces.append((i * sides + k, i * sides + k1, i1 * sides + k1, i1 * sides + k))
            ua, ub = u0 + circ * k / sides, u0 + circ * (k + 1) / sides
            va, vb = arc[i] - starts[pc], arc[i + 1] - starts[pc]
            uvs.append([(ua, va), (ub, va), (ub, vb), (ua, vb)])
    if caps and not closed:
        for end, ring in ((0, 0), (1, n - 1)):
            idx = [ring * sides + k for k in range(sides)]
            if end == 0:
                idx = idx[::-1]
            faces.append(tuple(idx))
            cu, cv = -2.0 - 3 * radius * end, -2.0
            uvs.append(
                [(cu + radius * math.cos(2 * math.pi * (j % sides) / sides), cv + radius * math.sin(2 * math.pi * (j % sides) / sides)) for j in idx]
            )
    parts.add(verts, faces, uvs)


def uv_sphere(parts, centre, radius, segments, rings, bumps=None):
    """A latitude-longitude sphere whose chart is the unrolled rectangle (pole rows triangles).

    `bumps(direction)` scales the radius along a unit direction (a mathutils Vector).
    """
    c = np.asarray(centre, np.float64)

    def point(d):
        d = Vector(d)
        return c + radius * (bumps(d) if bumps else 1.0) * np.array(d)

    verts = [point((0, 0, 1))]
    for r in range(1, rings):
        ph = math.pi * r / rings
        for j in range(segments):
            th = 2 * math.pi * j / segments
            verts.append(point((math.sin(ph) * math.cos(th), math.sin(ph) * math.sin(th), math.cos(ph))))
    verts.append(point((0, 0, -1)))
    south = len(verts) - 1

    def vi(r, j):  # ring r in 1..rings-1
        return 1 + (r - 1) * segments + (j % segments)

    def uv(r, j):
        return (2 * math.pi * radius * j / segments, math.pi * radius * (1 - r / rings))

    faces, uvs = [], []
    for j in range(segments):
        faces.append((0, vi(1, j), vi(1, j + 1)))
        uvs.append([(2 * math.pi * radius * (j + 0.5) / segments, math.pi * radius), uv(1, j), uv(1, j + 1)])
        for r in range(1, rings - 1):
            faces.append((vi(r, j), vi(r + 1, j), vi(r + 1, j + 1), vi(r, j + 1)))
            uvs.append([uv(r, j), uv(r + 1, j), uv(r + 1, j + 1), uv(r, j + 1)])
        faces.append((vi(rings - 1, j), south, vi(rings - 1, j + 1)))
        uvs.append([uv(rings - 1, j), (2 * math.pi * radius * (j + 0.5) / segments, 0.0), uv(rings - 1, j + 1)])
    parts.add(verts, faces, uvs)


def bowl_shell(outer, inner, radius, thickness, theta_max_deg, rings, segments):
    """A sphere cap about the south pole, up to polar angle theta_max, shelled inward.

    `outer` gets the outside; `inner` the inside (facing the cavity) and the rim. Charts: the
    outside and inside are azimuthal-equidistant disks (true scale along meridians), the rim a
    strip cut into four pieces.
    """
    tmax = math.radians(theta_max_deg)

    def point(r, th, ph):
        return np.array([r * math.sin(th) * math.cos(ph), r * math.sin(th) * math.sin(ph), -r * math.cos(th)])

    def orient(verts, face, uvs, want):
        """Winds `face` so its normal points along `want`."""
        p = [verts[i] for i in face]
        n = np.cross(p[1] - p[0], p[2] - p[0]) if len(p) == 3 else np.cross(p[2] - p[0], p[3] - p[1])
        return (face, uvs) if n.dot(want) > 0 else (face[::-1], uvs[::-1])

    for parts, r, sign in ((outer, radius, 1.0), (inner, radius - thickness, -1.0)):
        verts = [point(r, 0.0, 0.0)]
        for k in range(1, rings + 1):
            for j in range(segments):
                verts.append(point(r, tmax * k / rings, 2 * math.pi * j / segments))

        def vi(k, j):
            return 1 + (k - 1) * segments + (j % segments)

        def uv(k, j):
            th, ph = tmax * k / rings, 2 * math.pi * j / segments
            return (r * th * math.cos(ph), r * th * math.sin(ph))

        faces, uvs = [], []
        for j in range(segments):
            f, u = orient(verts, (0, vi(1, j), vi(1, j + 1)), [(0.0, 0.0), uv(1, j), uv(1, j + 1)], sign * verts[vi(1, j)])
            faces.append(f)
            uvs.append(u)
            for k in range(1, rings):
                f, u = orient(
                    verts,
                    (vi(k, j), vi(k, j + 1), vi(k + 1, j + 1), vi(k + 1, j)),
                    [uv(k, j), uv(k, j + 1), uv(k + 1, j + 1), uv(k + 1, j)],
                    sign * verts[vi(k, j)],
                )
                faces.append(f)
                uvs.append(u)
        parts.add(verts, faces, uvs)

    # Rim: quads from the outer to the inner top ring, facing along the meridian.
    verts, faces, uvs = [], [], []
    r_mid = (radius - thickness / 2) * math.sin(tmax)
    for j in range(segments):
        ph = 2 * math.pi * j / segments
        verts += [point(radius, tmax, ph), point(radius - thickness, tmax, ph)]
    pieces = 4
    for j in range(segments):
        pc = j * pieces // segments
        j1 = (j + 1) % segments
        u0, u1 = r_mid * 2 * math.pi * (j - pc * segments / pieces) / segments, r_mid * 2 * math.pi * (j + 1 - pc * segments / pieces) / segments
        off = pc * 10.0  # pieces apart, so no two share a uv
        ph = 2 * math.pi * (j + 0.5) / segments
        want = np.array([math.cos(tmax) * math.cos(ph), math.cos(tmax) * math.sin(ph), math.sin(tmax)])
        f, u = orient(
            verts,
            (2 * j, 2 * j1, 2 * j1 + 1, 2 * j + 1),
            [(off + u0, 0.0), (off + u1, 0.0), (off + u1, thickness), (off + u0, thickness)],
            want,
        )
        faces.append(f)
        uvs.append(u)
    inner.add(verts, faces, uvs)


def join(objs, name):
    select_only(objs)
    bpy.ops.object.join()
    obj = bpy.context.view_layer.objects.active
    obj.name = name
    obj.data.name = name
    return obj


def triangulate(obj):
    """Triangles before rendering, so the rendered and exported geometry are the same."""
    bm = bmesh.new()
    bm.from_mesh(obj.data)
    bmesh.ops.triangulate(bm, faces=bm.faces[:], quad_method="BEAUTY", ngon_method="BEAUTY")
    bm.to_mesh(obj.data)
    bm.free()
    obj.data.update()


def normalise(obj):
    """Bounding-box centre to 0 and bounding radius (about it) to 1, as the object transform.

    The mesh data keeps the builder's coordinates, so the materials' object-space textures
    stay where the builder put them; `export_glb` bakes the transform into the vertices.
    """
    me = obj.data
    co = np.empty(len(me.vertices) * 3, np.float64)
    me.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3)
    centre = (co.min(0) + co.max(0)) / 2
    radius = float(np.sqrt(((co - centre) ** 2).sum(1)).max())
    obj.matrix_world = Matrix.Scale(1.0 / radius, 4) @ Matrix.Translation(-Vector(centre.tolist()))
    return centre.tolist(), 1.0 / radius


def only_uv_layer(obj):
    """Keeps one uv layer, named UVMap (a primitive's own, or a new empty one)."""
    me = obj.data
    while len(me.uv_layers) > 1:
        me.uv_layers.remove(me.uv_layers[-1])
    if not len(me.uv_layers):
        me.uv_layers.new(name="UVMap")
    me.uv_layers[0].name = "UVMap"


def edit_all(obj):
    select_only([obj])
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.select_all(action="SELECT")
    bpy.ops.uv.select_all(action="SELECT")


def smart_uv(obj):
    """Charts for a part without usable uvs: Smart UV Project, then each chart flattened again
    by conformal (LSCM) unwrapping, which removes projection folds and distortion.

    Wide angle limits give few large charts but may fold; the first limit of UV_ANGLE_LADDER_DEG
    whose charts do not overlap wins, else a plain projection at the last limit.
    """
    only_uv_layer(obj)
    for angle in UV_ANGLE_LADDER_DEG:
        edit_all(obj)
        bpy.ops.uv.smart_project(
            angle_limit=math.radians(angle), island_margin=UV_MARGIN, area_weight=0.0, correct_aspect=True
        )
        bpy.ops.uv.seams_from_islands(mark_seams=True)
        bpy.ops.uv.unwrap(method="CONFORMAL", fill_holes=False, margin_method="FRACTION", margin=UV_MARGIN)
        bpy.ops.object.mode_set(mode="OBJECT")
        if check_uvs(obj, report_only=True)["uv_overlap_cells"] == 0:
            return f"Smart UV Project at {angle} deg + conformal unwrap"
    edit_all(obj)
    bpy.ops.uv.smart_project(
        angle_limit=math.radians(UV_ANGLE_LADDER_DEG[-1]), island_margin=UV_MARGIN, area_weight=0.0
    )
    bpy.ops.object.mode_set(mode="OBJECT")
    return f"Smart UV Project at {UV_ANGLE_LADDER_DEG[-1]} deg"


def pack_uvs(obj):
    """All charts at one texel density (3D area), packed into [0,1]^2 with a margin."""
    edit_all(obj)
    bpy.ops.uv.average_islands_scale()
    bpy.ops.uv.pack_islands(
        rotate=True,
        rotate_method="CARDINAL",
        scale=True,
        margin_method="FRACTION",
        margin=UV_MARGIN,
        shape_method="CONVEX",
    )
    bpy.ops.object.mode_set(mode="OBJECT")


def uv_triangles(me):
    me.calc_loop_triangles()
    uv = np.empty(len(me.loops) * 2, np.float64)
    me.uv_layers[0].data.foreach_get("uv", uv)
    uv = uv.reshape(-1, 2)
    loops = np.empty(len(me.loop_triangles) * 3, np.int64)
    me.loop_triangles.foreach_get("loops", loops)
    return uv[loops.reshape(-1, 3)]


def check_uvs(obj, grid=2048, report_only=False):
    """Raises unless every uv lies in [0,1]^2 and no two triangles overlap in uv.

    Overlap test: each triangle is rasterised at the centres of a grid x grid raster,
    counting only centres strictly inside it; a centre counted twice is an overlap
    (triangles that only share an edge never both hold a centre strictly).
    """
    tris = uv_triangles(obj.data)
    lo, hi = float(tris.min()), float(tris.max())
    if lo < 0.0 or hi > 1.0:
        raise RuntimeError(f"{obj.name}: uv outside [0,1] ({lo:.4f}..{hi:.4f})")
    count = np.zeros((grid, grid), np.uint8)
    eps = 1e-9
    for t in tris * grid:
        x0, y0 = np.floor(t.min(0)).astype(int)
        x1, y1 = np.ceil(t.max(0)).astype(int)
        x0, y0 = max(x0, 0), max(y0, 0)
        x1, y1 = min(x1, grid), min(y1, grid)
        if x1 <= x0 or y1 <= y0:
            continue
        xs = np.arange(x0, x1) + 0.5
        ys = np.arange(y0, y1) + 0.5
        px, py = np.meshgrid(xs, ys)
        (ax, ay), (bx, by), (cx, cy) = t
        area = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
        if abs(area) < 1e-12:
            continue
        w0 = ((bx - px) * (cy - py) - (by - py) * (cx - px)) / area
        w1 = ((cx - px) * (ay - py) - (cy - py) * (ax - px)) / area
        w2 = 1.0 - w0 - w1
        inside = (w0 > eps) & (w1 > eps) & (w2 > eps)
        count[y0:y1, x0:x1] += inside.astype(np.uint8)
    overlaps = int((count > 1).sum())
    stats = {"uv_coverage": round(float((count > 0).mean()), 4), "uv_overlap_cells": overlaps}
    if overlaps and not report_only:
        raise RuntimeError(f"{obj.name}: {overlaps} uv raster cells covered by two triangles")
    return stats


# ---------------------------------------------------------------------------------------
# The captures. Each builder returns (object, how its uv charts were made, description).
# Parts are placed in Blender space (Z up) at roughly unit size, then joined; materials use
# the object coordinates of the builder (normalisation is the object transform).


def build_glossy():
    """Lacquered Suzanne (glossy dielectric with a clear coat) inside a polished gold ring."""
    lacquer, nodes, links = new_material("lacquer")
    bsdf = principled(nodes)
    f = noise(nodes, links, obj_coords(nodes), scale=2.5, detail=3.0, roughness=0.55)
    col = color_ramp(
        nodes, links, f, [(0.35, (0.45, 0.02, 0.02)), (0.5, (0.75, 0.22, 0.03)), (0.65, (0.06, 0.12, 0.45))]
    )
    links.new(col, bsdf.inputs["Base Color"])
    set_bsdf(bsdf, roughness=0.12, ior=1.5, specular=1.0, coat=0.6, coat_roughness=0.03)

    gold, nodes, _ = new_material("gold")
    set_bsdf(principled(nodes), base=(1.0, 0.766, 0.336), metallic=1.0, roughness=0.15)

    silver, nodes, _ = new_material("silver")
    set_bsdf(principled(nodes), base=(0.95, 0.93, 0.88), metallic=1.0, roughness=0.06)

    bpy.ops.mesh.primitive_monkey_add(size=1.5)
    monkey = bpy.context.view_layer.objects.active
    transform(monkey, rot_deg=(-10, 0, 35))
    sub = monkey.modifiers.new("subsurf", "SUBSURF")
    sub.levels = sub.render_levels = 2
    apply_modifiers(monkey)
    uv_note = smart_uv(monkey)
    set_material(monkey, lacquer)
    shade(monkey)

    # Ring: a torus as a closed tube (charts: four unrolled quarter strips).
    parts = Parts()
    tilt = Matrix.Translation((0, 0, -0.05)) @ Matrix.Rotation(math.radians(20), 4, "Z")
    tilt = tilt @ Matrix.Rotation(math.radians(15), 4, "Y") @ Matrix.Rotation(math.radians(70), 4, "X")
    circle = [tilt @ Vector((0.95 * math.cos(a), 0.95 * math.sin(a), 0)) for a in np.linspace(0, 2 * math.pi, 96, endpoint=False)]
    tube(parts, circle, 0.065, 16, closed=True, pieces=4)
    ring = parts.object("ring")
    set_material(ring, gold)
    shade(ring)

    parts = Parts()
    uv_sphere(parts, (0.5, -0.45, -0.6), 0.2, 48, 24)
    ball = parts.object("ball")
    set_material(ball, silver)
    shade(ball)

    obj = join([monkey, ring, ball], "glossy")
    return obj, uv_note + " (Suzanne); unrolled tube and sphere charts (ring, ball)", (
        "Suzanne (subdivided twice) in a glossy lacquer (roughness 0.12, clear coat 0.6 at roughness 0.03) "
        "whose colour varies smoothly (red, orange, blue noise), a polished gold ring (metallic, roughness 0.15) "
        "and a silver ball (metallic, roughness 0.06). Sharp highlights of the static lights move over the "
        "surface with the view."
    )


def label_texture(width=2048, height=1024):
    """A jar label: bands of text at falling sizes, fine stripes and a checker (row 0 = top)."""
    img = Image.new("RGB", (width, height), (232, 224, 200))
    d = ImageDraw.Draw(img)
    ink, red, blue = (25, 30, 60), (170, 30, 30), (30, 70, 150)

    def font(px):
        return ImageFont.load_default(size=px)

    # Lid and lip plain (the cylindrical mapping pinches there), then diagonal stripes of
    # 24 px period on the neck and shoulder.
    d.rectangle([0, 0, width, 70], fill=blue)
    for x in range(-height, width + height, 24):
        d.polygon([(x, 70), (x + 12, 70), (x + 12 + 130, 200), (x + 130, 200)], fill=blue)
    d.rectangle([0, 200, width, 214], fill=ink)
    # Title and text rows, each size twice round the jar.
    y = 224
    rows = [
        (96, "DEFERRED NEURAL RENDERING", red),
        (56, "development set: high-frequency albedo", ink),
        (40, "The quick brown fox jumps over the lazy dog 0123456789", ink),
        (28, "Pack my box with five dozen liquor jugs. Sphinx of black quartz, judge my vow!", blue),
        (20, "How vexingly quick daft zebras jump; the five boxing wizards jump quickly. 2718281828 3141592653", ink),
        (14, "Lorem ipsum dolor sit amet, consectetur adipiscing elit, sed do eiusmod tempor incididunt ut labore et dolore magna aliqua. 1 2 3 4 5 6 7 8 9 0", ink),
    ]
    for px, text, colour in rows:
        f = font(px)
        tw = d.textlength(text, font=f)
        x = 16.0
        while x < width:
            d.text((x, y), text, font=f, fill=colour)
            x += tw + px
        y += int(px * 1.35)
    # Vertical pin stripes (8 px period) and a barcode-like band.
    y += 8
    for x in range(0, width, 8):
        d.rectangle([x, y, x + 3, y + 40], fill=ink)
    y += 52
    rng = np.random.RandomState(7)
    x = 0
    while x < width:
        w = int(rng.randint(2, 9))
        if rng.rand() < 0.5:
            d.rectangle([x, y, x + w - 1, y + 50], fill=ink)
        x += w
    y += 62
    # Bottom: a 32 px checker down to the base.
    for cy in range(y, height, 32):
        for cx in range(0, width, 32):
            if ((cx // 32) + ((cy - y) // 32)) % 2 == 0:
                d.rectangle([cx, cy, cx + 31, cy + 31], fill=red if (cx // 256) % 2 else ink)
    return np.asarray(img)


def build_text():
    """A jar (surface of revolution) wrapped in a printed label; mostly diffuse paper."""
    # Profile (r, z) from the bottom centre round the base, up the body, shoulder, neck, lip.
    prof = []
    for k in range(0, 7):  # rounded bottom edge
        a = -math.pi / 2 + (math.pi / 2) * k / 6
        prof.append((0.56 + 0.1 * math.cos(a), -0.85 + 0.1 * math.sin(a)))
    for k in range(1, 13):  # body
        prof.append((0.66, -0.85 + 1.2 * k / 12))
    for k in range(1, 9):  # shoulder
        a = (math.pi / 2) * k / 8
        prof.append((0.38 + 0.28 * math.cos(a), 0.35 + 0.3 * math.sin(a)))
    prof += [(0.38, 0.8), (0.44, 0.82), (0.45, 0.88), (0.42, 0.92)]
    prof.insert(0, (0.35, -0.95))
    jar = lathe("jar", prof, segments=128)
    shade(jar, smooth_angle_deg=50)

    tex = image_from_array("label", label_texture())
    paper, nodes, links = new_material("paper")
    bsdf = principled(nodes)
    sep = nodes.new("ShaderNodeSeparateXYZ")
    links.new(obj_coords(nodes), sep.inputs["Vector"])
    # Cylindrical mapping u = atan2(y, x) / 2pi + 1/2, v = (z + 0.95) / 1.9 over the jar's height
    # in the builder's coordinates (the normalisation is the object transform).
    at = nodes.new("ShaderNodeMath")
    at.operation = "ARCTAN2"
    links.new(sep.outputs["Y"], at.inputs[0])
    links.new(sep.outputs["X"], at.inputs[1])
    u = nodes.new("ShaderNodeMath")
    u.operation = "MULTIPLY_ADD"
    links.new(at.outputs[0], u.inputs[0])
    u.inputs[1].default_value = 1.0 / (2 * math.pi)
    u.inputs[2].default_value = 0.5
    v = nodes.new("ShaderNodeMapRange")
    v.inputs["From Min"].default_value = -0.95
    v.inputs["From Max"].default_value = 0.95
    links.new(sep.outputs["Z"], v.inputs["Value"])
    comb = nodes.new("ShaderNodeCombineXYZ")
    links.new(u.outputs[0], comb.inputs["X"])
    links.new(v.outputs["Result"], comb.inputs["Y"])
    teximg = nodes.new("ShaderNodeTexImage")
    teximg.image = tex
    teximg.interpolation = "Linear"
    teximg.extension = "EXTEND"
    links.new(comb.outputs["Vector"], teximg.inputs["Vector"])
    links.new(teximg.outputs["Color"], bsdf.inputs["Base Color"])
    set_bsdf(bsdf, roughness=0.85, specular=0.25)
    set_material(jar, paper)
    return jar, smart_uv(jar), (
        "A jar (surface of revolution, 128 segments) wrapped in a printed paper label: text rows at six sizes "
        "(from about 18 down to 3 screen pixels tall at 256x256), 8-texel pin stripes, a random barcode, "
        "diagonal stripes on the shoulder and a 32-texel checker at the base. Mostly diffuse (roughness 0.85, "
        "specular level 0.25), so appearance is nearly view-independent."
    )


def build_dark():
    """Dark wood block, black rubber tyre and a charcoal lump: albedo 0.02..0.08 with subtle detail."""
    wood, nodes, links = new_material("dark_wood")
    bsdf = principled(nodes)
    wave = nodes.new("ShaderNodeTexWave")
    wave.wave_type = "RINGS"
    wave.inputs["Scale"].default_value = 3.0
    wave.inputs["Distortion"].default_value = 6.0
    wave.inputs["Detail"].default_value = 3.0
    mapping = nodes.new("ShaderNodeMapping")
    mapping.inputs["Scale"].default_value = (0.35, 1.0, 1.0)
    links.new(obj_coords(nodes), mapping.inputs["Vector"])
    links.new(mapping.outputs["Vector"], wave.inputs["Vector"])
    col = color_ramp(nodes, links, wave.outputs["Fac"], [(0.0, (0.028, 0.016, 0.009)), (1.0, (0.085, 0.05, 0.028))])
    links.new(col, bsdf.inputs["Base Color"])
    links.new(bump(nodes, links, wave.outputs["Fac"], 0.15, 0.01), bsdf.inputs["Normal"])
    set_bsdf(bsdf, roughness=0.7, specular=0.35)

    rubber, nodes, links = new_material("rubber")
    bsdf = principled(nodes)
    # Tread: stripes across the tyre, 36 round it, by the angle about its axis in tyre space
    # (the 'texture' mapping applies the inverse of the tyre's placement).
    local = nodes.new("ShaderNodeMapping")
    local.vector_type = "TEXTURE"
    local.inputs["Location"].default_value = TYRE_LOC
    local.inputs["Rotation"].default_value = [math.radians(a) for a in TYRE_ROT_DEG]
    links.new(obj_coords(nodes), local.inputs["Vector"])
    sep = nodes.new("ShaderNodeSeparateXYZ")
    links.new(local.outputs["Vector"], sep.inputs["Vector"])
    at = nodes.new("ShaderNodeMath")
    at.operation = "ARCTAN2"
    links.new(sep.outputs["Y"], at.inputs[0])
    links.new(sep.outputs["X"], at.inputs[1])
    tread = nodes.new("ShaderNodeMath")
    tread.operation = "SINE"
    scale = nodes.new("ShaderNodeMath")
    scale.operation = "MULTIPLY"
    scale.inputs[1].default_value = 36.0
    links.new(at.outputs[0], scale.inputs[0])
    links.new(scale.outputs[0], tread.inputs[0])
    f = noise(nodes, links, obj_coords(nodes), scale=9.0, detail=2.0)
    col = color_ramp(nodes, links, f, [(0.3, (0.018, 0.018, 0.02)), (0.7, (0.032, 0.03, 0.03))])
    links.new(col, bsdf.inputs["Base Color"])
    links.new(bump(nodes, links, tread.outputs[0], 0.35, 0.01), bsdf.inputs["Normal"])
    set_bsdf(bsdf, roughness=0.6, specular=0.5)

    charcoal, nodes, links = new_material("charcoal")
    bsdf = principled(nodes)
    vor = nodes.new("ShaderNodeTexVoronoi")
    vor.feature = "DISTANCE_TO_EDGE"
    vor.inputs["Scale"].default_value = 7.0
    links.new(obj_coords(nodes), vor.inputs["Vector"])
    col = color_ramp(nodes, links, vor.outputs["Distance"], [(0.0, (0.012, 0.012, 0.012)), (0.06, (0.045, 0.043, 0.04))])
    links.new(col, bsdf.inputs["Base Color"])
    links.new(bump(nodes, links, vor.outputs["Distance"], 0.3, 0.02), bsdf.inputs["Normal"])
    set_bsdf(bsdf, roughness=0.95, specular=0.3)

    bpy.ops.mesh.primitive_cube_add(size=1.0)
    block = bpy.context.view_layer.objects.active
    transform(block, loc=(0, 0, -0.45), scale=(1.7, 1.05, 0.32))
    bev = block.modifiers.new("bevel", "BEVEL")
    bev.width = 0.04
    bev.segments = 3
    apply_modifiers(block)
    set_material(block, wood)
    shade(block, smooth_angle_deg=40)

    parts = Parts()
    circle = [(0.42 * math.cos(a), 0.42 * math.sin(a), 0.0) for a in np.linspace(0, 2 * math.pi, 72, endpoint=False)]
    tube(parts, circle, 0.17, 24, closed=True, pieces=2)
    tyre = parts.object("tyre")
    transform(tyre, loc=TYRE_LOC, rot_deg=TYRE_ROT_DEG)
    set_material(tyre, rubber)
    shade(tyre)

    # Charcoal lump: a latitude-longitude sphere, radius displaced by Perlin noise.
    parts = Parts()
    uv_sphere(parts, (0, 0, 0), 0.3, 64, 32, bumps=lambda d: 1.0 + 0.3 * mathutils.noise.noise(d * 1.7 + Vector((3.1, 0.4, 1.7))))
    lump = parts.object("lump")
    transform(lump, loc=(0.5, -0.1, -0.05), rot_deg=(10, 20, 0), scale=(1.1, 0.9, 0.75))
    set_material(lump, charcoal)
    shade(lump, smooth_angle_deg=60)

    smart = smart_uv(block)
    obj = join([block, tyre, lump], "dark")
    return obj, smart + " (block); unrolled tube and sphere charts (tyre, lump)", (
        "A dark wood block (bevelled; ring grain, linear albedo 0.03..0.085, light bump), a black rubber tyre "
        "(albedo 0.018..0.032, fine tread by bump) standing on it and a lump of charcoal (noise-displaced sphere, "
        "albedo 0.012..0.045 with Voronoi cracks). Rough, so nearly view-independent; the detail is faint."
    )


def build_thin():
    """A geodesic strut lattice round a small core, with a wire helix: thin structures."""
    paint, nodes, links = new_material("paint")
    bsdf = principled(nodes)
    f = noise(nodes, links, obj_coords(nodes), scale=1.8, detail=1.0)
    col = color_ramp(nodes, links, f, [(0.35, (0.03, 0.35, 0.4)), (0.65, (0.8, 0.6, 0.05))])
    links.new(col, bsdf.inputs["Base Color"])
    set_bsdf(bsdf, roughness=0.45, specular=0.5)

    core_mat, nodes, links = new_material("core")
    bsdf = principled(nodes)
    chk = nodes.new("ShaderNodeTexChecker")
    chk.inputs["Scale"].default_value = 6.0
    chk.inputs["Color1"].default_value = (0.7, 0.15, 0.05, 1.0)
    chk.inputs["Color2"].default_value = (0.85, 0.8, 0.7, 1.0)
    links.new(obj_coords(nodes), chk.inputs["Vector"])
    links.new(chk.outputs["Color"], bsdf.inputs["Base Color"])
    set_bsdf(bsdf, roughness=0.7, specular=0.4)

    copper, nodes, _ = new_material("copper")
    set_bsdf(principled(nodes), base=(0.95, 0.64, 0.54), metallic=1.0, roughness=0.3)

    # Lattice: a hexagonal-prism strut on every edge of a geodesic sphere, a ball on every node.
    bm = bmesh.new()
    bmesh.ops.create_icosphere(bm, subdivisions=2, radius=0.95)
    nodes_xyz = [v.co.copy() for v in bm.verts]
    edges = [(e.verts[0].index, e.verts[1].index) for e in bm.edges]
    bm.free()
    parts = Parts()
    for a, b in edges:
        tube(parts, [nodes_xyz[a], nodes_xyz[b]], STRUT_RADIUS, 6)
    for p in nodes_xyz:
        uv_sphere(parts, p, STRUT_RADIUS * 1.6, 12, 6)
    dome = parts.object("lattice")
    set_material(dome, paint)
    shade(dome, smooth_angle_deg=35)

    parts = Parts()
    uv_sphere(parts, (0, 0, 0), 0.3, 48, 24)
    core = parts.object("core")
    set_material(core, core_mat)
    shade(core)

    parts = Parts()
    n = 400
    path = []
    for i in range(n):
        t = i / (n - 1)
        a = 2 * math.pi * 5 * t
        z = -0.75 + 1.5 * t
        r = 0.55 * math.sqrt(max(0.0, 1 - (z / 0.85) ** 2)) + 0.05
        path.append((r * math.cos(a), r * math.sin(a), z))
    tube(parts, path, WIRE_RADIUS, 8, pieces=12, caps=True)
    helix = parts.object("helix")
    set_material(helix, copper)
    shade(helix, smooth_angle_deg=50)

    obj = join([dome, core, helix], "thin")
    return obj, "unrolled tube and sphere charts", (
        f"A geodesic lattice (struts: hexagonal prisms {2 * STRUT_RADIUS} wide, about 3 pixels at 256x256, on the "
        "120 edges of a twice-subdivided icosphere, balls at the 42 nodes) "
        "painted in a slowly varying teal/yellow, a checkered core sphere seen through it and a copper wire "
        f"helix ({2 * WIRE_RADIUS} thick, metallic, roughness 0.3) between them. The 10% proxy loses or merges most struts."
    )


def build_mixed():
    """A concave glazed bowl holding a chrome ball and a wooden die: diffuse, glossy and metal parts."""
    terracotta, nodes, links = new_material("terracotta")
    bsdf = principled(nodes)
    sep = nodes.new("ShaderNodeSeparateXYZ")
    links.new(obj_coords(nodes), sep.inputs["Vector"])
    band = nodes.new("ShaderNodeMath")
    band.operation = "SINE"
    sc = nodes.new("ShaderNodeMath")
    sc.operation = "MULTIPLY"
    sc.inputs[1].default_value = 40.0
    links.new(sep.outputs["Z"], sc.inputs[0])
    links.new(sc.outputs[0], band.inputs[0])
    col = color_ramp(nodes, links, band.outputs[0], [(0.45, (0.45, 0.16, 0.07)), (0.55, (0.75, 0.62, 0.45))])
    links.new(col, bsdf.inputs["Base Color"])
    set_bsdf(bsdf, roughness=0.9, specular=0.3)

    glaze, nodes, links = new_material("glaze")
    bsdf = principled(nodes)
    f = noise(nodes, links, obj_coords(nodes), scale=5.0, detail=4.0)
    col = color_ramp(nodes, links, f, [(0.4, (0.03, 0.12, 0.35)), (0.6, (0.25, 0.55, 0.65))])
    links.new(col, bsdf.inputs["Base Color"])
    set_bsdf(bsdf, roughness=0.07, ior=1.5, specular=1.0)

    chrome, nodes, _ = new_material("chrome")
    set_bsdf(principled(nodes), base=(0.9, 0.9, 0.9), metallic=1.0, roughness=0.04)

    maple, nodes, links = new_material("maple")
    bsdf = principled(nodes)
    wave = nodes.new("ShaderNodeTexWave")
    wave.inputs["Scale"].default_value = 6.0
    wave.inputs["Distortion"].default_value = 3.0
    links.new(obj_coords(nodes), wave.inputs["Vector"])
    col = color_ramp(nodes, links, wave.outputs["Fac"], [(0.0, (0.55, 0.35, 0.17)), (1.0, (0.8, 0.6, 0.35))])
    links.new(col, bsdf.inputs["Base Color"])
    set_bsdf(bsdf, roughness=0.55, specular=0.5)

    # Bowl: a sphere cap shelled inward, built here rather than by the Solidify modifier, whose
    # vertex positions vary in the last bit from run to run (and the uv layout with them).
    parts_out, parts_in = Parts(), Parts()
    bowl_shell(parts_out, parts_in, radius=0.9, thickness=0.07, theta_max_deg=105.0, rings=28, segments=96)
    bowl = parts_out.object("bowl")
    transform(bowl, loc=(0, 0, 0.3))
    set_material(bowl, terracotta)
    shade(bowl)
    glazed = parts_in.object("glazed")
    transform(glazed, loc=(0, 0, 0.3))
    set_material(glazed, glaze)
    shade(glazed, smooth_angle_deg=60)

    bpy.ops.mesh.primitive_cylinder_add(radius=0.38, depth=0.16, vertices=64)
    foot = bpy.context.view_layer.objects.active
    transform(foot, loc=(0, 0, -0.58))
    bev = foot.modifiers.new("bevel", "BEVEL")
    bev.width = 0.02
    bev.segments = 2
    apply_modifiers(foot)
    set_material(foot, terracotta)
    shade(foot, smooth_angle_deg=40)

    parts = Parts()
    uv_sphere(parts, (-0.2, 0.1, -0.2), 0.3, 64, 32)
    ball = parts.object("ball")
    set_material(ball, chrome)
    shade(ball)

    bpy.ops.mesh.primitive_cube_add(size=0.42)
    die = bpy.context.view_layer.objects.active
    transform(die, loc=(0.3, -0.15, 0.05), rot_deg=(25, 15, 30))
    bev = die.modifiers.new("bevel", "BEVEL")
    bev.width = 0.04
    bev.segments = 3
    apply_modifiers(die)
    set_material(die, maple)
    shade(die, smooth_angle_deg=40)

    smart = smart_uv(foot)
    assert smart_uv(die) == smart, "foot and die unwrapped differently: say so in the note"
    obj = join([bowl, glazed, foot, ball, die], "mixed")
    return obj, smart + " (foot, die); disk, strip and sphere charts (bowl, ball)", (
        "A concave bowl (sphere cap shelled inward, 0.07 thick): diffuse terracotta outside with painted bands, glossy "
        "blue glaze inside and on the rim (roughness 0.07), holding a chrome ball (metallic, roughness 0.04) "
        "and a wooden die (diffuse, roughness 0.55), on a terracotta foot. Self-shadowing, inter-reflection "
        "and mirror-like reflections of the bowl in the ball."
    )


CAPTURES = {
    "glossy": (build_glossy, 2401),
    "text": (build_text, 2402),
    "dark": (build_dark, 2403),
    "thin": (build_thin, 2404),
    "mixed": (build_mixed, 2405),
}


# ---------------------------------------------------------------------------------------
# Cameras


def look_at_origin(eye):
    """Camera-to-world 4x4 (glTF space, OpenGL camera: looks along -Z, +Y up, roll 0)."""
    eye = np.asarray(eye, np.float64)
    back = eye / np.linalg.norm(eye)
    right = np.cross([0.0, 1.0, 0.0], back)
    n = np.linalg.norm(right)
    right = right / n if n > 1e-9 else np.array([1.0, 0.0, 0.0])
    up = np.cross(back, right)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, up, back, eye
    return m


def train_views(n, seed):
    """Directions uniform on the upper (+Y) hemisphere: y = cos(polar) uniform in [0, 1)."""
    rng = np.random.RandomState(seed)
    out = []
    for _ in range(n):
        y = rng.uniform(0.0, 1.0)
        phi = rng.uniform(-math.pi, math.pi)
        s = math.sqrt(max(0.0, 1 - y * y))
        out.append(look_at_origin(CAMERA_RADIUS * np.array([s * math.sin(phi), y, s * math.cos(phi)])))
    return out


def test_views(n, az0_deg):
    """A rising spiral: elevation 8..72 deg, two turns, t = i / (n - 1)."""
    out = []
    for i in range(n):
        t = i / max(1, n - 1)
        el = math.radians(8 + 64 * t)
        az = math.radians(az0_deg) - 2 * 2 * math.pi * t
        d = np.array([math.cos(el) * math.sin(az), math.sin(el), math.cos(el) * math.cos(az)])
        out.append(look_at_origin(CAMERA_RADIUS * d))
    return out


# ---------------------------------------------------------------------------------------
# Export


def export_glb(obj, path, decimate_ratio=None):
    """Writes a copy of `obj`: positions, normals, TEXCOORD_0; no material. Returns triangles."""
    me = obj.data.copy()
    me.materials.clear()
    me.transform(obj.matrix_world)
    copy = link(bpy.data.objects.new(obj.name + ("_coarse" if decimate_ratio else ""), me))
    if decimate_ratio:
        dec = copy.modifiers.new("decimate", "DECIMATE")
        dec.decimate_type = "COLLAPSE"
        dec.ratio = decimate_ratio
        dec.use_collapse_triangulate = True
        apply_modifiers(copy)
        triangulate(copy)
    select_only([copy])
    tmp = path + ".tmp.glb"
    bpy.ops.export_scene.gltf(
        filepath=tmp,
        export_format="GLB",
        use_selection=True,
        export_yup=True,
        export_apply=False,
        export_texcoords=True,
        export_normals=True,
        export_tangents=False,
        export_materials="NONE",
        export_vertex_color="NONE",
        export_attributes=False,
        export_cameras=False,
        export_lights=False,
        export_animations=False,
        export_skins=False,
        export_morph=False,
        export_extras=False,
    )
    os.replace(tmp, path)
    copy.data.calc_loop_triangles()
    tris = len(copy.data.loop_triangles)
    bpy.data.objects.remove(copy)
    return tris


# ---------------------------------------------------------------------------------------
# Rendering


def render_views(scene, cam, mats, folder, split, log):
    os.makedirs(os.path.join(folder, split), exist_ok=True)
    t0 = time.time()
    done = 0
    for i, m in enumerate(mats):
        final = os.path.join(folder, split, f"r_{i:03d}.png")
        if os.path.exists(final):
            continue  # resumed run; rendering is deterministic
        cam.matrix_world = GLTF_TO_BLENDER @ Matrix(m.tolist())
        tmp = os.path.join(folder, split, f".r_{i:03d}.tmp.png")
        scene.render.filepath = tmp
        bpy.ops.render.render(write_still=True)
        # Re-encoded without Blender's metadata (Cycles writes its render time into it), so
        # reruns give byte-identical files; the pixels are Blender's.
        with Image.open(tmp) as im:
            im.load()
            if im.mode != "RGBA":
                raise RuntimeError(f"{tmp}: expected RGBA, Blender wrote {im.mode}")
            im.save(tmp + ".png", format="PNG")
        os.remove(tmp)
        os.replace(tmp + ".png", final)
        done += 1
        if done % 10 == 0 or i == len(mats) - 1:
            el = time.time() - t0
            log(f"  {split} {i + 1}/{len(mats)}  {el:.0f} s ({el / done:.2f} s/frame)")
    return time.time() - t0


def write_transforms(path, frames, mesh_path="mesh.glb"):
    doc = {
        "camera_angle_x": CAMERA_ANGLE_X,
        "mesh_path": mesh_path,
        "frames": [{"file_path": fp, "transform_matrix": m.tolist()} for fp, m in frames],
    }
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(doc, f, indent=1)
    os.replace(tmp, path)


def make_capture(name, out_dir, n_train, n_test, resolution, log):
    build, seed = CAPTURES[name]
    final = os.path.join(out_dir, name)
    if os.path.exists(os.path.join(final, "meta.json")):
        log(f"{name}: complete, skipped ({final})")
        return
    work = os.path.join(out_dir, f".{name}.partial")
    # A partial folder from an interrupted run is resumed only if it was made by this script
    # with the same settings.
    with open(os.path.abspath(__file__), "rb") as f:
        script_sha = hashlib.sha256(f.read()).hexdigest()
    settings = {"script_sha256": script_sha, "train": n_train, "test": n_test, "resolution": resolution}
    stamp = os.path.join(work, ".settings.json")
    if os.path.exists(work):
        try:
            with open(stamp) as f:
                same = json.load(f) == settings
        except (OSError, ValueError):
            same = False
        if not same:
            log(f"{name}: discarding {work} (made with other settings or another script version)")
            shutil.rmtree(work)
    os.makedirs(work, exist_ok=True)
    with open(stamp, "w") as f:
        json.dump(settings, f)
    t_start = time.time()

    scene = reset_scene()
    add_lights(scene)
    cam = add_camera(scene, resolution)
    obj, uv_note, description = build()
    apply_modifiers(obj)
    triangulate(obj)
    centre, scale = normalise(obj)
    pack_uvs(obj)
    uv_check = check_uvs(obj)
    tris = export_glb(obj, os.path.join(work, "mesh.glb"))
    tris_coarse = export_glb(obj, os.path.join(work, "mesh_coarse.glb"), COARSE_RATIO)
    log(f"{name}: {tris} triangles, coarse {tris_coarse}, uv coverage {uv_check['uv_coverage']:.2f}")

    train = train_views(n_train, seed)
    test = test_views(n_test, az0_deg=-101.39)
    t_train = render_views(scene, cam, train, work, "train", log)
    t_test = render_views(scene, cam, test, work, "test", log)

    # Default split: the first half of the train views and every other test view (the whole spiral).
    n_def_train = n_train // 2
    def_test = list(range(0, n_test, 2))
    write_transforms(
        os.path.join(work, "transforms_train.json"),
        [(f"train/r_{i:03d}.png", train[i]) for i in range(n_def_train)],
    )
    write_transforms(
        os.path.join(work, "transforms_test.json"), [(f"test/r_{i:03d}.png", test[i]) for i in def_test]
    )
    meta = {
        "name": name,
        "description": description,
        "renderer": f"Blender {bpy.app.version_string} Cycles (CPU, bpy wheel), {SAMPLES} spp, "
        "OpenImageDenoise, view transform Standard, sRGB 8-bit RGBA PNG, transparent film",
        "generator": "crates/bake/examples/devset/make_devset.py",
        "resolution": [resolution, resolution],
        "camera_angle_x": CAMERA_ANGLE_X,
        "camera_radius": CAMERA_RADIUS,
        "world_space": "glTF (+Y up) = mesh.glb coordinates; object normalised to bbox centre 0, bounding radius 1",
        "train_views": "uniform random directions on the upper (+Y) hemisphere, roll 0, looking at origin",
        "test_views": "rising spiral, elevation 8..72 deg, 2 turns, roll 0, looking at origin",
        "lights_gltf_space": LIGHTS,
        "area_lights_face": "the origin",
        "world_color_linear": WORLD_COLOR,
        "exposure_ev": EXPOSURE_EV,
        "cycles_seed": CYCLES_SEED,
        "seed": seed,
        "normalisation": {"source_bbox_center_blender": centre, "source_scale": scale},
        "uv": {
            "charts": uv_note,
            "packing": f"islands scaled to equal texel density, packed (convex hulls, quarter-turn rotations), margin {UV_MARGIN}",
            "check": "no two triangles strictly hold the same cell centre of a 2048x2048 raster; all uvs in [0,1]",
            **uv_check,
        },
        "triangles": {"mesh.glb": tris, "mesh_coarse.glb": tris_coarse},
        "coarse": f"Decimate (collapse) to ratio {COARSE_RATIO}, uvs kept",
        "rendered": {"train": n_train, "test": n_test},
        "counts": {"train": n_def_train, "test": len(def_test)},
        "split": f"transforms_train.json: train views 0..{n_def_train - 1}; transforms_test.json: every other "
        f"test view (0, 2, ..., {def_test[-1]}); the sibling folder {name}-{n_train} uses all {n_train} + {n_test}",
        "render_seconds": {"train": round(t_train, 1), "test": round(t_test, 1)},
        "total_seconds": round(time.time() - t_start, 1),
    }
    with open(os.path.join(work, "meta.json"), "w") as f:
        json.dump(meta, f, indent=1)
    os.remove(stamp)
    if os.path.exists(final):
        shutil.rmtree(final)
    os.replace(work, final)

    # The all-views variant: its own transforms, the same image files by relative path.
    var = os.path.join(out_dir, f"{name}-{n_train}")
    var_tmp = os.path.join(out_dir, f".{name}-{n_train}.partial")
    if os.path.exists(var_tmp):
        shutil.rmtree(var_tmp)
    os.makedirs(var_tmp)
    for mesh in ("mesh.glb", "mesh_coarse.glb"):
        shutil.copyfile(os.path.join(final, mesh), os.path.join(var_tmp, mesh))
    write_transforms(
        os.path.join(var_tmp, "transforms_train.json"),
        [(f"../{name}/train/r_{i:03d}.png", m) for i, m in enumerate(train)],
    )
    write_transforms(
        os.path.join(var_tmp, "transforms_test.json"),
        [(f"../{name}/test/r_{i:03d}.png", m) for i, m in enumerate(test)],
    )
    var_meta = dict(meta)
    var_meta["name"] = f"{name}-{n_train}"
    var_meta["counts"] = {"train": n_train, "test": n_test}
    var_meta["split"] = f"all rendered views; images are those of ../{name} (relative file_path)"
    with open(os.path.join(var_tmp, "meta.json"), "w") as f:
        json.dump(var_meta, f, indent=1)
    if os.path.exists(var):
        shutil.rmtree(var)
    os.replace(var_tmp, var)
    log(f"{name}: done in {time.time() - t_start:.0f} s -> {final}, {var}")


def main():
    argv = sys.argv[1:]
    ap = argparse.ArgumentParser(
        description="Render the dnr development set (posed-image captures) with Blender Cycles.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="""Writes OUT_DIR/NAME (transforms_train.json with the first half of the training views,
transforms_test.json with every other test view, train/, test/, mesh.glb, mesh_coarse.glb,
meta.json) and OUT_DIR/NAME-<train> (all views, the same images by relative path).
Finished captures are skipped; an interrupted one resumes. See README.md next to this script.

examples:
  make_devset.py devset                       # everything: 5 x (200 + 60) views at 256x256
  make_devset.py smoke --quick                # 8 + 4 views at 64x64, the same meshes
  make_devset.py devset --only thin           # one capture""",
    )
    ap.add_argument("out_dir", help="folder to write the captures into (one sub-folder per capture)")
    ap.add_argument("--quick", action="store_true", help="smoke test: 8 + 4 views at 64x64")
    ap.add_argument("--only", action="append", choices=sorted(CAPTURES), help="render only this capture (repeatable)")
    ap.add_argument("--train", type=int, default=200, help="train views rendered (default 200; the default split uses half)")
    ap.add_argument("--test", type=int, default=60, help="test views rendered (default 60; the default split uses every other)")
    ap.add_argument("--resolution", type=int, default=256, help="image side in pixels (default 256)")
    args = ap.parse_args(argv)
    if args.quick:
        args.train, args.test, args.resolution = 8, 4, 64
    if args.train < 2 or args.test < 1 or not 16 <= args.resolution <= 4096:
        ap.error("need --train >= 2, --test >= 1 and 16 <= --resolution <= 4096")
    out = os.path.abspath(args.out_dir)
    os.makedirs(out, exist_ok=True)

    def log(msg):
        print(msg, flush=True)

    names = args.only or list(CAPTURES)
    t0 = time.time()
    for name in names:
        make_capture(name, out, args.train, args.test, args.resolution, log)
    log(f"all done in {time.time() - t0:.0f} s")


if __name__ == "__main__":
    main()
