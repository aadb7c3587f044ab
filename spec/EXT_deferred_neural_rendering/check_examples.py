#!/usr/bin/env python3
"""Checks the EXT_deferred_neural_rendering examples against the JSON Schemas and the spec's rules.

Usage:
    python check_examples.py            # check; exit status 1 on any failure
    python check_examples.py --write    # rewrite the generated examples, then check

What it checks:
  * every schema in schema/ is a valid draft 2020-12 schema;
  * every example validates against the schema for its object type;
  * objects that break the architecture-conditional rules are rejected by the schema;
  * the examples on disk equal what the builders below generate (byte for byte after decoding);
  * the minimal glTF passes a small reference validator written from the README, and mutated
    copies of it fail with the expected validator codes;
  * the U-Net example lists exactly the tensors the README's naming rules give;
  * the worked-example numbers (examples/worked_example.json and README) match the formulas.

Needs Python >= 3.9 and the `jsonschema` package (>= 4.18). `OpenEXR` is used, when installed,
to cross-check the example EXR files. No other dependencies.
"""
from __future__ import annotations

import base64
import copy
import json
import math
import pathlib
import re
import struct
import sys
import zlib

HERE = pathlib.Path(__file__).resolve().parent
SCHEMA_DIR = HERE / "schema"
EXAMPLES = HERE / "examples"
EXT = "EXT_deferred_neural_rendering"
UNLIT = "KHR_materials_unlit"

REPEAT, CLAMP_TO_EDGE, MIRRORED_REPEAT = 10497, 33071, 33648
WRAP_NAMES = {REPEAT: "REPEAT", CLAMP_TO_EDGE: "CLAMP_TO_EDGE", MIRRORED_REPEAT: "MIRRORED_REPEAT"}

# Real spherical harmonics, KHR_gaussian_splatting / 3DGS order and signs (README, View dependence).
SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, 0.31539156525252005, 0.5462742152960396)
SH_C3 = (0.5900435899266435, 2.890611442640554, 0.4570457994644658, 0.3731763325901154,
         1.445305721320277)

EXR_COMPRESSIONS = {0: "NONE", 1: "RLE", 2: "ZIPS", 3: "ZIP", 4: "PIZ", 5: "PXR24", 6: "B44",
                    7: "B44A", 8: "DWAA", 9: "DWAB"}
EXR_ALLOWED = {0, 1, 2, 3, 4}
EXR_LINES_PER_CHUNK = {0: 1, 1: 1, 2: 1, 3: 16, 4: 32, 5: 16, 6: 32, 7: 32, 8: 32, 9: 256}
HALF_MAX = 65504.0


# --------------------------------------------------------------------------------------------
# Reference formulas (README: Neural textures, View dependence, Renderers)
# --------------------------------------------------------------------------------------------

def wrap(i: int, n: int, mode: int) -> int:
    """Wraps an integer tap index into [0, n) with a core glTF sampler wrap mode."""
    if mode == REPEAT:
        return i % n  # Python's % is non-negative for n > 0
    if mode == CLAMP_TO_EDGE:
        return min(max(i, 0), n - 1)
    if mode == MIRRORED_REPEAT:
        m = i % (2 * n)
        return m if m < n else 2 * n - 1 - m
    raise ValueError(f"unknown wrap mode {mode}")


def bilinear(level: dict, u: float, v: float, wrap_s: int, wrap_t: int) -> list[float]:
    """Bilinear sample of one level. level: width, height, channels, data (HWC, row 0 = top)."""
    w, h, c = level["width"], level["height"], level["channels"]
    x = u * w - 0.5
    y = v * h - 0.5
    x0, y0 = math.floor(x), math.floor(y)
    fx, fy = x - x0, y - y0
    taps = ((x0, y0, (1 - fx) * (1 - fy)), (x0 + 1, y0, fx * (1 - fy)),
            (x0, y0 + 1, (1 - fx) * fy), (x0 + 1, y0 + 1, fx * fy))
    out = [0.0] * c
    for ti, tj, wt in taps:
        i, j = wrap(ti, w, wrap_s), wrap(tj, h, wrap_t)
        base = (j * w + i) * c
        for k in range(c):
            out[k] += wt * level["data"][base + k]
    return out


def feature(levels: list[dict], u: float, v: float, wrap_s: int, wrap_t: int) -> list[float]:
    """F = sum over levels (in listed order) of the bilinear samples; 0 for non-finite uv."""
    c = levels[0]["channels"]
    if not (math.isfinite(u) and math.isfinite(v)):
        return [0.0] * c
    acc = [0.0] * c
    for lv in levels:
        s = bilinear(lv, u, v, wrap_s, wrap_t)
        acc = [a + b for a, b in zip(acc, s)]
    return acc


def sh_basis(d: tuple[float, float, float], degree: int) -> list[float]:
    """Y_0 .. Y_((degree+1)^2 - 1) at the unit direction d = (x, y, z)."""
    x, y, z = d
    xx, yy, zz = x * x, y * y, z * z
    ys = [SH_C0]
    if degree >= 1:
        ys += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        ys += [SH_C2[0] * x * y, -SH_C2[0] * y * z, SH_C2[1] * (2 * zz - xx - yy),
               -SH_C2[0] * x * z, SH_C2[2] * (xx - yy)]
    if degree >= 3:
        ys += [-SH_C3[0] * y * (3 * xx - yy), SH_C3[1] * x * y * z,
               -SH_C3[2] * y * (4 * zz - xx - yy), SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy),
               -SH_C3[2] * x * (4 * zz - xx - yy), SH_C3[4] * z * (xx - yy),
               -SH_C3[0] * x * (xx - 3 * yy)]
    return ys


def unet_sizes(width: int, height: int, depth: int) -> dict:
    """Padded frame and the size of every encoder output e_i of a U-Net with D stages."""
    p = 2 ** depth
    wp, hp = -(-width // p) * p, -(-height // p) * p
    enc = [(wp >> (i + 1), hp >> (i + 1)) for i in range(depth)]
    return {"padded": (wp, hp), "encoder": enc}


def expected_tensors(renderer: dict, in_channels: int) -> dict[str, list[int]]:
    """The tensor names and shapes an architecture defines (README, Renderers)."""
    arch = renderer["architecture"]
    out = renderer["outputChannels"]
    if arch == "none":
        return {}
    if arch == "mlp":
        sizes = [in_channels] + list(renderer["hidden"]) + [out]
        t = {}
        for i in range(len(sizes) - 1):
            t[f"layers.{i}.weight"] = [sizes[i + 1], sizes[i]]
            t[f"layers.{i}.bias"] = [sizes[i + 1]]
        return t
    if arch == "unet":
        w = list(renderer["widths"])
        d = len(w)
        t = {}
        for i in range(d):
            c_in = in_channels if i == 0 else w[i - 1]
            t[f"encoder.{i}.weight"] = [w[i], c_in, 4, 4]
            t[f"encoder.{i}.bias"] = [w[i]]
        for i in range(d - 1, -1, -1):
            c_in = w[d - 1] if i == d - 1 else 2 * w[i]
            c_out = w[i - 1] if i >= 1 else out
            if renderer["decoder"] == "transposedConv":
                t[f"decoder.{i}.weight"] = [c_in, c_out, 4, 4]
            else:
                t[f"decoder.{i}.weight"] = [c_out, c_in, 3, 3]
            t[f"decoder.{i}.bias"] = [c_out]
        return t
    raise ValueError(arch)


def exr_channel_names(c: int) -> list[str]:
    digits = max(2, len(str(c - 1)))
    return [f"C{k:0{digits}d}" for k in range(c)]


# --------------------------------------------------------------------------------------------
# Binary codecs: OpenEXR (uncompressed writer, header parser), PNG (stored deflate), tensors
# --------------------------------------------------------------------------------------------

def _attr(name: str, typ: str, value: bytes) -> bytes:
    return name.encode() + b"\0" + typ.encode() + b"\0" + struct.pack("<i", len(value)) + value


def exr_write(width: int, height: int, channels: int, data: list[float]) -> bytes:
    """Single-part scanline EXR, HALF channels C00.., compression NONE, INCREASING_Y."""
    names = exr_channel_names(channels)  # already in sorted (header) order
    chlist = b"".join(n.encode() + b"\0" + struct.pack("<iB3xii", 1, 0, 1, 1) for n in names)
    box = struct.pack("<iiii", 0, 0, width - 1, height - 1)
    header = b"".join([
        struct.pack("<ii", 20000630, 2),
        _attr("channels", "chlist", chlist + b"\0"),
        _attr("compression", "compression", b"\0"),
        _attr("dataWindow", "box2i", box),
        _attr("displayWindow", "box2i", box),
        _attr("lineOrder", "lineOrder", b"\0"),
        _attr("pixelAspectRatio", "float", struct.pack("<f", 1.0)),
        _attr("screenWindowCenter", "v2f", struct.pack("<ff", 0.0, 0.0)),
        _attr("screenWindowWidth", "float", struct.pack("<f", 1.0)),
        b"\0",
    ])
    line_bytes = width * channels * 2
    first = len(header) + 8 * height
    offsets = b"".join(struct.pack("<Q", first + y * (8 + line_bytes)) for y in range(height))
    chunks = []
    for y in range(height):
        row = b"".join(
            struct.pack("<e", data[(y * width + x) * channels + k])
            for k in range(channels) for x in range(width))
        chunks.append(struct.pack("<ii", y, line_bytes) + row)
    return header + offsets + b"".join(chunks)


class ExrError(Exception):
    def __init__(self, code: str, msg: str):
        super().__init__(f"{code}: {msg}")
        self.code = code


def exr_read(buf: bytes) -> dict:
    """Parses the header; decodes pixels (HWC floats) when compression is NONE."""
    def need(n, at):
        if at + n > len(buf):
            raise ExrError("EXR_INVALID", "truncated")
    need(8, 0)
    magic, ver = struct.unpack_from("<ii", buf, 0)
    if magic != 20000630 or (ver & 0xFF) != 2:
        raise ExrError("EXR_INVALID", "bad magic or version")
    if ver & (0x200 | 0x800 | 0x1000):
        raise ExrError("EXR_INVALID", "tiled, deep or multi-part file")
    pos, attrs = 8, {}
    while True:
        end = buf.index(b"\0", pos)
        name = buf[pos:end].decode()
        pos = end + 1
        if not name:
            break
        end = buf.index(b"\0", pos)
        typ = buf[pos:end].decode()
        pos = end + 1
        need(4, pos)
        (size,) = struct.unpack_from("<i", buf, pos)
        pos += 4
        need(size, pos)
        attrs[name] = (typ, buf[pos:pos + size])
        pos += size
    for req in ("channels", "compression", "dataWindow", "displayWindow", "lineOrder"):
        if req not in attrs:
            raise ExrError("EXR_INVALID", f"missing attribute {req}")
    chans, raw = [], attrs["channels"][1]
    p = 0
    while raw[p:p + 1] != b"\0":
        end = raw.index(b"\0", p)
        cname = raw[p:end].decode()
        ptype, _plin, xs, ys = struct.unpack_from("<iB3xii", raw, end + 1)
        chans.append((cname, ptype, xs, ys))
        p = end + 1 + 16
    info = {
        "channels": chans,
        "compression": attrs["compression"][1][0],
        "dataWindow": struct.unpack("<iiii", attrs["dataWindow"][1]),
        "displayWindow": struct.unpack("<iiii", attrs["displayWindow"][1]),
        "lineOrder": attrs["lineOrder"][1][0],
    }
    x0, y0, x1, y1 = info["dataWindow"]
    w, h = x1 - x0 + 1, y1 - y0 + 1
    info["size"] = (w, h)
    if info["compression"] == 0 and w > 0 and h > 0:
        nchunks = h
        offsets = struct.unpack_from(f"<{nchunks}Q", buf, pos)
        data = [0.0] * (w * h * len(chans))
        for off in offsets:
            need(8, off)
            y, size = struct.unpack_from("<ii", buf, off)
            need(size, off + 8)
            if size != w * len(chans) * 2:
                raise ExrError("EXR_INVALID", "scanline size")
            vals = struct.unpack_from(f"<{w * len(chans)}e", buf, off + 8)
            row = y - y0
            for k in range(len(chans)):
                for x in range(w):
                    data[(row * w + x) * len(chans) + k] = vals[k * w + x]
        info["data"] = data
    return info


def png_rgb(width: int, height: int, rgb: list[int]) -> bytes:
    """8-bit RGB PNG with one stored (uncompressed) deflate block: byte-for-byte reproducible."""
    raw = b"".join(b"\0" + bytes(rgb[y * width * 3:(y + 1) * width * 3]) for y in range(height))
    assert len(raw) < 65536
    z = (b"\x78\x01" + b"\x01" + struct.pack("<HH", len(raw), len(raw) ^ 0xFFFF) + raw
         + struct.pack(">I", zlib.adler32(raw)))

    def chunk(t: bytes, d: bytes) -> bytes:
        return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d))
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", z) + chunk(b"IEND", b""))


def tensor_bytes(values: list[float], dtype: str) -> bytes:
    fmt = {"f16": "e", "f32": "f"}[dtype]
    return struct.pack(f"<{len(values)}{fmt}", *values)


# Smallest magnitude that rounds to an f32 infinity (round to nearest even).
F32_OVERFLOW = 2.0 ** 128 - 2.0 ** 103


def tensor_values(buf: bytes, dtype: str) -> tuple[float, ...]:
    size = {"f16": 2, "f32": 4}[dtype]
    fmt = {"f16": "e", "f32": "f"}[dtype]
    return struct.unpack(f"<{len(buf) // size}{fmt}", buf)


def int8_codes(buf: bytes, shape: list[int]) -> list[str]:
    """Revision 1.1 checks of an int8 tensor's bytes (values, padding, one f32 scale per
    first-axis row): every scale finite and > 0, every value scale * q finite in f32."""
    n = math.prod(shape)
    rows = shape[0] if shape else 1
    at = (n + 3) // 4 * 4
    scales = struct.unpack(f"<{rows}f", buf[at:at + 4 * rows])
    if any(not (math.isfinite(sc) and sc > 0) for sc in scales):
        return ["WEIGHTS_SCALE_INVALID"]
    per = max(n // rows, 1) if rows else 1
    q = struct.unpack(f"<{n}b", buf[:n])
    # The product of an f32 and an integer below 2^8 is exact in f64.
    if any(abs(scales[i // per] * v) >= F32_OVERFLOW for i, v in enumerate(q)):
        return ["WEIGHTS_NON_FINITE"]
    return []


# --------------------------------------------------------------------------------------------
# Example builders
# --------------------------------------------------------------------------------------------

def _lcg(seed: int):
    state = seed
    while True:
        state = (state * 6364136223846793005 + 1442695040888963407) % 2 ** 64
        yield (state >> 40) / 2 ** 24  # [0, 1)


def minimal_texture_levels() -> list[dict]:
    """8 channels; level 0 is 4x4, level 1 is 2x2. Values are multiples of 1/16 (exact in half)."""
    c = 8
    levels = []
    for (w, h, scale) in ((4, 4, 1.0), (2, 2, 0.5)):
        data = []
        for j in range(h):
            for i in range(w):
                for k in range(c):
                    q = (i * 7 + j * 3 + k * 5) % 17
                    val = q / 16 if k < 3 else (q - 8) / 16
                    data.append(val * scale)
        levels.append({"width": w, "height": h, "channels": c, "data": data})
    return levels


def build_minimal() -> dict:
    """A complete .gltf: one textured quad bound (on its mesh primitive) to a neural texture and
    an mlp renderer, with an unlit PNG fallback material; all binary data is embedded as a
    data URI."""
    levels = minimal_texture_levels()
    channels = levels[0]["channels"]
    wrap_mode = CLAMP_TO_EDGE
    # Fallback image: channels 0..2 of F at level-0 texel centres, clamped, 8-bit.
    w0, h0 = levels[0]["width"], levels[0]["height"]
    rgb = []
    for j in range(h0):
        for i in range(w0):
            f = feature(levels, (i + 0.5) / w0, (j + 0.5) / h0, wrap_mode, wrap_mode)
            rgb += [int(math.floor(min(max(f[k], 0.0), 1.0) * 255 + 0.5)) for k in range(3)]
    png = png_rgb(w0, h0, rgb)
    exrs = [exr_write(lv["width"], lv["height"], channels, lv["data"]) for lv in levels]

    renderer = {"name": "mlp", "architecture": "mlp", "inputChannels": channels,
                "outputChannels": 4, "hidden": [8]}
    rnd = _lcg(2019)
    shapes = expected_tensors(renderer, channels)
    dtypes = {"layers.0.weight": "f16", "layers.0.bias": "f16",
              "layers.1.weight": "f32", "layers.1.bias": "f32"}
    weight_blob, weights = b"", []
    for name, shape in shapes.items():
        n = math.prod(shape)
        vals = [round((next(rnd) - 0.5) * 256) / 256 for _ in range(n)]
        b = tensor_bytes(vals, dtypes[name])
        weights.append({"name": name, "shape": shape, "dtype": dtypes[name], "bufferView": 6,
                        "byteOffset": len(weight_blob), "crc32": zlib.crc32(b)})
        weight_blob += b + b"\0" * (-len(b) % 4)
    renderer["weights"] = weights

    positions = [(-1.0, -1.0, 0.0), (1.0, -1.0, 0.0), (1.0, 1.0, 0.0), (-1.0, 1.0, 0.0)]
    uvs = [(0.0, 1.0), (1.0, 1.0), (1.0, 0.0), (0.0, 0.0)]
    indices = [0, 1, 2, 0, 2, 3]
    parts = [
        b"".join(struct.pack("<3f", *p) for p in positions),
        b"".join(struct.pack("<2f", *t) for t in uvs),
        struct.pack("<6H", *indices),
        exrs[0], exrs[1], png, weight_blob,
    ]
    targets = [34962, 34962, 34963, None, None, None, None]
    blob, views = b"", []
    for part, target in zip(parts, targets):
        view = {"buffer": 0, "byteOffset": len(blob), "byteLength": len(part)}
        if target:
            view["target"] = target
        views.append(view)
        blob += part + b"\0" * (-len(part) % 4)

    return {
        "asset": {"version": "2.0", "generator": "dnr spec check_examples.py"},
        "extensionsUsed": [UNLIT, EXT],
        "extensions": {EXT: {
            "version": 1,
            "neuralTextures": [{
                "name": "quad features",
                "channels": channels,
                "levels": [{"width": lv["width"], "height": lv["height"], "bufferView": 3 + i,
                            "mimeType": "image/x-exr"} for i, lv in enumerate(levels)],
                "sampler": 0,
                "viewDependence": {"basis": "sphericalHarmonics", "degree": 1, "firstChannel": 3},
            }],
            "renderers": [renderer],
        }},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "quad"}],
        "meshes": [{"primitives": [{
            "attributes": {"POSITION": 0, "TEXCOORD_0": 1},
            "indices": 2, "material": 0, "mode": 4,
            "extensions": {EXT: {"neuralTexture": 0, "renderer": 0, "texCoord": 0}},
        }]}],
        "materials": [{
            "name": "quad fallback",
            "pbrMetallicRoughness": {"baseColorTexture": {"index": 0, "texCoord": 0},
                                     "metallicFactor": 0.0, "roughnessFactor": 0.9},
            "doubleSided": True,
            "extensions": {UNLIT: {}},
        }],
        "textures": [{"source": 0, "sampler": 0}],
        "images": [{"bufferView": 5, "mimeType": "image/png"}],
        "samplers": [{"magFilter": 9729, "minFilter": 9729, "wrapS": wrap_mode, "wrapT": wrap_mode}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
             "min": [-1.0, -1.0, 0.0], "max": [1.0, 1.0, 0.0]},
            {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"},
            {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"},
        ],
        "bufferViews": views,
        "buffers": [{"byteLength": len(blob),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode()}],
    }


def build_unet_renderer() -> dict:
    """The U-Net of DESIGN.md's example: 16 input channels, widths [16, 32, 64, 128, 128], f16.
    byteOffsets pack the tensors back to back in one buffer view; each crc32 is that of
    all-zero tensor bytes (an illustrative asset whose weights are all 0.0)."""
    r = {"name": "unet-5", "architecture": "unet", "inputChannels": 16, "outputChannels": 4,
         "widths": [16, 32, 64, 128, 128], "decoder": "transposedConv",
         "normalization": "instance"}
    off, weights = 0, []
    for name, shape in expected_tensors(r, 16).items():
        nbytes = math.prod(shape) * 2
        weights.append({"name": name, "shape": shape, "dtype": "f16", "bufferView": 7,
                        "byteOffset": off, "crc32": zlib.crc32(bytes(nbytes))})
        off += nbytes + (-nbytes % 4)
    r["weights"] = weights
    return r


def build_upsample_renderer() -> dict:
    """A small U-Net with the upsampleConv decoder, no normalisation, 3 outputs, f32, and
    (revision 1.3) supersampled features, 2 x 2 per pixel."""
    r = {"architecture": "unet", "inputChannels": 8, "outputChannels": 3, "widths": [8, 16],
         "decoder": "upsampleConv", "normalization": "none"}
    off, weights = 0, []
    for name, shape in expected_tensors(r, 8).items():
        nbytes = math.prod(shape) * 4
        weights.append({"name": name, "shape": shape, "dtype": "f32", "bufferView": 2,
                        "byteOffset": off, "crc32": zlib.crc32(bytes(nbytes))})
        off += nbytes
    r["weights"] = weights
    r["supersample"] = 2
    return r


def build_none_renderer() -> dict:
    return {"name": "features as colour", "architecture": "none", "inputChannels": 16,
            "outputChannels": 3}


def build_worked_example() -> dict:
    t = {"width": 2, "height": 2, "channels": 1, "data": [1.0, 2.0, 3.0, 4.0]}
    t2 = {"width": 1, "height": 1, "channels": 1, "data": [10.0]}
    u, v = 1.3, 0.2
    bil = {name: round(bilinear(t, u, v, mode, mode)[0], 12) for mode, name in WRAP_NAMES.items()}
    centre = bilinear(t, 0.25, 0.75, REPEAT, REPEAT)[0]
    total = round(feature([t, t2], u, v, REPEAT, REPEAT)[0], 12)
    sh = [0.0 if y == 0 else round(y, 16) for y in sh_basis((0.0, 0.0, -1.0), 3)]
    s = unet_sizes(250, 130, 5)
    return {
        "bilinear": {"texels_row_major": t["data"], "width": 2, "height": 2, "uv": [u, v],
                     "results": bil, "texel_centre_uv": [0.25, 0.75], "texel_centre_value": centre,
                     "with_1x1_level_of_10_REPEAT": total},
        "sh_d": [0.0, 0.0, -1.0],
        "sh_basis": sh,
        "unet": {"frame": [250, 130], "depth": 5, "padded": list(s["padded"]),
                 "encoder": [list(e) for e in s["encoder"]]},
        "crc32_123456789": zlib.crc32(b"123456789"),
        "exr_channel_names": {"3": exr_channel_names(3), "16": exr_channel_names(16)[:3] + ["..."]
                              + exr_channel_names(16)[-1:], "101": exr_channel_names(101)[:2]
                              + ["..."] + exr_channel_names(101)[-1:]},
    }


GENERATED = {
    "minimal.gltf": build_minimal,
    "unet_renderer.json": build_unet_renderer,
    "unet_upsample_renderer.json": build_upsample_renderer,
    "none_renderer.json": build_none_renderer,
    "worked_example.json": build_worked_example,
}


# --------------------------------------------------------------------------------------------
# A small reference validator (README, Conformance), enough for the examples and mutations
# --------------------------------------------------------------------------------------------

def _buffer_bytes(gltf: dict, index: int) -> bytes:
    uri = gltf["buffers"][index]["uri"]
    assert uri.startswith("data:"), "examples embed their buffers"
    return base64.b64decode(uri.split(",", 1)[1])


def view_bytes(gltf: dict, vi: int) -> bytes | None:
    views = gltf.get("bufferViews", [])
    if not 0 <= vi < len(views):
        return None
    v = views[vi]
    data = _buffer_bytes(gltf, v["buffer"])
    start, length = v.get("byteOffset", 0), v["byteLength"]
    if start + length > len(data) or start + length > gltf["buffers"][v["buffer"]]["byteLength"]:
        return None
    return data[start:start + length]


def bound_primitives(gltf: dict) -> list[dict]:
    """The mesh primitives that carry the extension's binding object."""
    return [p for mesh in gltf.get("meshes", []) for p in mesh.get("primitives", [])
            if EXT in p.get("extensions", {})]


def check_primitives(gltf: dict, textures: list | None, renderers: list | None) -> list[str]:
    """README, Extending Mesh Primitives: fallback material, TEXCOORD_n, and (when the root
    object is there) the indices and the pairing."""
    codes = []
    materials = gltf.get("materials", [])
    for prim in bound_primitives(gltf):
        ext = prim["extensions"][EXT]
        mi = prim.get("material")
        if mi is None:
            codes.append("FALLBACK_MISSING")
        elif 0 <= mi < len(materials):
            m = materials[mi]
            if ("baseColorTexture" not in m.get("pbrMetallicRoughness", {})
                    or UNLIT not in m.get("extensions", {})):
                codes.append("FALLBACK_MISSING")
        if f"TEXCOORD_{ext.get('texCoord', 0)}" not in prim["attributes"]:
            codes.append("TEXCOORD_MISSING")
        if textures is None:
            continue
        ti, ri = ext["neuralTexture"], ext["renderer"]
        if not 0 <= ti < len(textures) or not 0 <= ri < len(renderers):
            codes.append("INDEX_OUT_OF_RANGE")
            continue
        if textures[ti]["channels"] != renderers[ri]["inputChannels"]:
            codes.append("RENDERER_INPUT_MISMATCH")
    return codes


def validate(gltf: dict) -> list[str]:
    """Returns the codes found (order of discovery). Schema checks are done separately."""
    codes = []
    root = gltf.get("extensions", {}).get(EXT)
    bound = bound_primitives(gltf)
    if (root is not None or bound) and EXT not in gltf.get("extensionsUsed", []):
        codes.append("EXTENSION_NOT_USED")
    if EXT in gltf.get("extensionsRequired", []):
        codes.append("EXTENSION_REQUIRED")
    if root is None:
        # The bindings' indices name nothing; the checks that do not need the root apply.
        return codes + (["JSON_SCHEMA"] + check_primitives(gltf, None, None) if bound else [])
    if root["version"] != 1:
        return codes + ["VERSION_UNSUPPORTED"]
    textures, renderers = root["neuralTextures"], root["renderers"]

    for t in textures:
        c = t["channels"]
        if not 3 <= c <= 1024:
            codes.append("TEXTURE_CHANNELS_RANGE")
            continue
        if c > 64:  # default limit
            codes.append("LIMIT_EXCEEDED")
            continue
        if not t["levels"]:
            codes.append("TEXTURE_NO_LEVELS")
        vd = t.get("viewDependence")
        if vd is not None:
            if vd["basis"] != "sphericalHarmonics" or not 0 <= vd["degree"] <= 3:
                codes.append("SH_DEGREE_UNSUPPORTED")
            elif vd["firstChannel"] + (vd["degree"] + 1) ** 2 > c:
                codes.append("SH_CHANNELS_OUT_OF_RANGE")
        if "sampler" in t and not 0 <= t["sampler"] < len(gltf.get("samplers", [])):
            codes.append("INDEX_OUT_OF_RANGE")
        for lv in t["levels"]:
            if lv["mimeType"] not in ("image/x-exr", "image/png"):
                codes.append("TEXTURE_MIME_TYPE")
                continue
            if (lv["mimeType"] == "image/png") != ("quantization" in lv):
                codes.append("JSON_SCHEMA")
                continue
            if not 0 <= lv["bufferView"] < len(gltf.get("bufferViews", [])):
                codes.append("INDEX_OUT_OF_RANGE")
                continue
            buf = view_bytes(gltf, lv["bufferView"])
            if buf is None:
                codes.append("BUFFER_VIEW_OUT_OF_RANGE")
                continue
            if "quantization" in lv:
                codes.extend(png_level_codes(lv, c, buf))
                continue
            try:
                info = exr_read(buf)
            except (ExrError, ValueError, struct.error, UnicodeDecodeError) as e:
                codes.append(getattr(e, "code", "EXR_INVALID"))
                continue
            if info["lineOrder"] != 0:
                codes.append("EXR_INVALID")
                continue
            names = [ch[0] for ch in info["channels"]]
            if (sorted(names) != exr_channel_names(c)
                    or any(ch[1] != 1 or ch[2] != 1 or ch[3] != 1 for ch in info["channels"])):
                codes.append("EXR_CHANNELS")
                continue
            box = (0, 0, lv["width"] - 1, lv["height"] - 1)
            if info["dataWindow"] != box or info["displayWindow"] != box:
                codes.append("EXR_SIZE_MISMATCH")
                continue
            if info["compression"] not in EXR_ALLOWED:
                codes.append("EXR_COMPRESSION")
                continue
            if any(not math.isfinite(x) for x in info.get("data", [])):
                codes.append("EXR_NON_FINITE")

    for r in renderers:
        arch = r["architecture"]
        want = None  # tensor names and shapes, when the architecture and parameters are valid
        if arch not in ("none", "mlp", "unet"):
            codes.append("RENDERER_UNKNOWN_ARCHITECTURE")
        elif r["outputChannels"] not in (3, 4) or (arch == "none" and r["outputChannels"] != 3):
            codes.append("RENDERER_OUTPUT_CHANNELS")
        else:
            bad = r["inputChannels"] < (3 if arch == "none" else 1)
            # Revision 1.3; the schema's bounds, reported as a parameter error.
            bad |= not 1 <= r.get("supersample", 1) <= 4
            if arch == "mlp":
                bad |= "hidden" not in r or any(h < 1 for h in r["hidden"])
            if arch == "unet":
                bad |= any(k not in r for k in ("widths", "decoder", "normalization"))
                bad = bad or not 1 <= len(r["widths"]) <= 8 or any(w < 1 for w in r["widths"])
                bad = bad or r["decoder"] not in ("transposedConv", "upsampleConv")
                bad = bad or r["normalization"] not in ("instance", "none")
            if bad:
                codes.append("RENDERER_PARAMETER_INVALID")
            else:
                want = expected_tensors(r, r["inputChannels"])
        seen = set()
        for wt in r.get("weights", []):
            name = wt["name"]
            if name in seen or (want is not None and name not in want):
                codes.append("WEIGHTS_UNEXPECTED")
            elif want is not None and wt["shape"] != want[name]:
                codes.append("WEIGHTS_SHAPE_MISMATCH")
            seen.add(name)
            # Byte-level checks, independent of the name checks.
            if wt["dtype"] not in ("f16", "f32", "int8"):
                codes.append("WEIGHTS_DTYPE_UNKNOWN")
                continue
            if not 0 <= wt["bufferView"] < len(gltf.get("bufferViews", [])):
                codes.append("INDEX_OUT_OF_RANGE")
                continue
            view = view_bytes(gltf, wt["bufferView"])
            n = math.prod(wt["shape"])
            if wt["dtype"] == "int8":
                # Revision 1.1: values, padding to 4 bytes, one f32 scale per first-axis row.
                nbytes = (n + 3) // 4 * 4 + 4 * wt["shape"][0]
            else:
                nbytes = n * (2 if wt["dtype"] == "f16" else 4)
            off = wt.get("byteOffset", 0)
            if view is None or off + nbytes > len(view):
                codes.append("BUFFER_VIEW_OUT_OF_RANGE")
                continue
            if off % 4 or gltf["bufferViews"][wt["bufferView"]].get("byteOffset", 0) % 4:
                codes.append("WEIGHTS_MISALIGNED")
            data = view[off:off + nbytes]
            if zlib.crc32(data) != wt["crc32"]:
                codes.append("WEIGHTS_CHECKSUM_MISMATCH")
            if wt["dtype"] == "int8":
                codes += int8_codes(data, wt["shape"])
            elif any(not math.isfinite(x) for x in tensor_values(data, wt["dtype"])):
                codes.append("WEIGHTS_NON_FINITE")
        if want is not None and set(want) - seen:
            codes.append("WEIGHTS_MISSING")

    return codes + check_primitives(gltf, textures, renderers)


def _set_view_byte(g: dict, vi: int, at: int, value: int) -> None:
    """Overwrites one byte of a buffer view in the embedded buffer."""
    v = g["bufferViews"][vi]
    data = bytearray(_buffer_bytes(g, v["buffer"]))
    data[v.get("byteOffset", 0) + at] = value
    g["buffers"][v["buffer"]]["uri"] = ("data:application/octet-stream;base64,"
                                        + base64.b64encode(bytes(data)).decode())


def _replace_view(g: dict, vi: int, new: bytes) -> None:
    """Appends new bytes to the buffer and points buffer view vi at them."""
    v = g["bufferViews"][vi]
    data = _buffer_bytes(g, v["buffer"])
    data += b"\0" * (-len(data) % 4)
    v["byteOffset"], v["byteLength"] = len(data), len(new)
    data += new
    g["buffers"][v["buffer"]].update(
        byteLength=len(data),
        uri="data:application/octet-stream;base64," + base64.b64encode(data).decode())


def _store_int8(g: dict, ti: int, row0_scale: float | None = None) -> None:
    """Re-stores tensor ti of the first renderer as int8 (scale max |w| / 127 per first-axis
    row) in a new buffer view with its CRC; row0_scale, if given, replaces row 0's scale."""
    w = g["extensions"][EXT]["renderers"][0]["weights"][ti]
    n, rows = math.prod(w["shape"]), w["shape"][0]
    size = 2 if w["dtype"] == "f16" else 4
    off = w.get("byteOffset", 0)
    vals = tensor_values(view_bytes(g, w["bufferView"])[off:off + n * size], w["dtype"])
    per = n // rows
    f32 = lambda x: struct.unpack("<f", struct.pack("<f", x))[0]  # noqa: E731
    scales = [f32(max(abs(v) for v in vals[r * per:(r + 1) * per]) / 127) or 1.0
              for r in range(rows)]
    q = [max(-127, min(127, round(v / scales[i // per]))) for i, v in enumerate(vals)]
    if row0_scale is not None:
        scales[0] = row0_scale
    blob = struct.pack(f"<{n}b", *q) + b"\0" * (-n % 4) + struct.pack(f"<{rows}f", *scales)
    data = _buffer_bytes(g, 0)
    data += b"\0" * (-len(data) % 4)
    g["bufferViews"].append({"buffer": 0, "byteOffset": len(data), "byteLength": len(blob)})
    data += blob
    g["buffers"][0].update(
        byteLength=len(data),
        uri="data:application/octet-stream;base64," + base64.b64encode(data).decode())
    w.update(bufferView=len(g["bufferViews"]) - 1, byteOffset=0, dtype="int8",
             crc32=zlib.crc32(blob))


def mutations(base: dict):
    """(description, mutated glTF, expected codes) triples."""
    def m(fn):
        g = copy.deepcopy(base)
        fn(g)
        return g
    root = lambda g: g["extensions"][EXT]  # noqa: E731
    rend = lambda g: root(g)["renderers"][0]  # noqa: E731
    tex = lambda g: root(g)["neuralTextures"][0]  # noqa: E731
    prim = lambda g: g["meshes"][0]["primitives"][0]  # noqa: E731
    binding = lambda g: prim(g)["extensions"][EXT]  # noqa: E731

    def binding_on_material(g):
        g["materials"][0]["extensions"][EXT] = prim(g).pop("extensions")[EXT]
    lv = tex(base)["levels"][0]
    nan_exr = exr_write(lv["width"], lv["height"], 8, [float("nan")] + [0.0] * (4 * 4 * 8 - 1))
    exr9 = exr_write(lv["width"], lv["height"], 9, [0.0] * (4 * 4 * 9))
    zip_exr = bytearray(exr_write(lv["width"], lv["height"], 8, [0.0] * (4 * 4 * 8)))
    zip_exr[zip_exr.index(b"compression\0compression\0") + 28] = 8  # DWAA
    return [
        ("extension in extensionsRequired", m(lambda g: g.update(extensionsRequired=[EXT])),
         ["EXTENSION_REQUIRED"]),
        ("extension not in extensionsUsed", m(lambda g: g.update(extensionsUsed=[UNLIT])),
         ["EXTENSION_NOT_USED"]),
        ("version 2", m(lambda g: root(g).update(version=2)), ["VERSION_UNSUPPORTED"]),
        ("no unlit fallback", m(lambda g: g["materials"][0]["extensions"].pop(UNLIT)),
         ["FALLBACK_MISSING"]),
        ("no fallback baseColorTexture",
         m(lambda g: g["materials"][0]["pbrMetallicRoughness"].pop("baseColorTexture")),
         ["FALLBACK_MISSING"]),
        ("no fallback material", m(lambda g: prim(g).pop("material")), ["FALLBACK_MISSING"]),
        ("binding on the material instead of the primitive (binds nothing)",
         m(binding_on_material), []),
        ("renderer index 5", m(lambda g: binding(g).update(renderer=5)),
         ["INDEX_OUT_OF_RANGE"]),
        ("neuralTexture index 1", m(lambda g: binding(g).update(neuralTexture=1)),
         ["INDEX_OUT_OF_RANGE"]),
        ("inputChannels 9", m(lambda g: rend(g).update(inputChannels=9)),
         ["WEIGHTS_SHAPE_MISMATCH", "RENDERER_INPUT_MISMATCH"]),
        ("level width 5", m(lambda g: tex(g)["levels"][0].update(width=5)), ["EXR_SIZE_MISMATCH"]),
        ("mime type png without quantization",
         m(lambda g: tex(g)["levels"][0].update(mimeType="image/png")), ["JSON_SCHEMA"]),
        ("mime type webp", m(lambda g: tex(g)["levels"][0].update(mimeType="image/webp")),
         ["TEXTURE_MIME_TYPE"]),
        ("NaN texel", m(lambda g: _replace_view(g, 3, nan_exr)), ["EXR_NON_FINITE"]),
        ("9 EXR channels", m(lambda g: _replace_view(g, 3, exr9)), ["EXR_CHANNELS"]),
        ("DWAA compression", m(lambda g: _replace_view(g, 3, bytes(zip_exr))), ["EXR_COMPRESSION"]),
        ("degree 2 from channel 3", m(lambda g: tex(g)["viewDependence"].update(degree=2)),
         ["SH_CHANNELS_OUT_OF_RANGE"]),
        ("architecture transformer", m(lambda g: rend(g).update(architecture="transformer")),
         ["RENDERER_UNKNOWN_ARCHITECTURE"]),
        ("outputChannels 5", m(lambda g: rend(g).update(outputChannels=5)),
         ["RENDERER_OUTPUT_CHANNELS"]),
        ("renamed tensor", m(lambda g: rend(g)["weights"][3].update(name="layers.1.b")),
         ["WEIGHTS_UNEXPECTED", "WEIGHTS_MISSING"]),
        ("wrong shape", m(lambda g: rend(g)["weights"][1].update(shape=[4])),
         ["WEIGHTS_SHAPE_MISMATCH", "WEIGHTS_CHECKSUM_MISMATCH"]),
        ("dtype bf16", m(lambda g: rend(g)["weights"][0].update(dtype="bf16")),
         ["WEIGHTS_DTYPE_UNKNOWN"]),
        ("byteOffset 2", m(lambda g: rend(g)["weights"][0].update(byteOffset=2)),
         ["WEIGHTS_MISALIGNED", "WEIGHTS_CHECKSUM_MISMATCH"]),
        ("basis wavelets", m(lambda g: tex(g)["viewDependence"].update(basis="wavelets")),
         ["SH_DEGREE_UNSUPPORTED"]),
        ("no root object", m(lambda g: g.pop("extensions")), ["JSON_SCHEMA"]),
        ("no root object, binding on TEXCOORD_1",
         m(lambda g: (g.pop("extensions"), binding(g).update(texCoord=1))),
         ["JSON_SCHEMA", "TEXCOORD_MISSING"]),
        ("mlp without hidden", m(lambda g: rend(g).pop("hidden")), ["RENDERER_PARAMETER_INVALID"]),
        ("supersample 4", m(lambda g: rend(g).update(supersample=4)), []),
        ("supersample 0", m(lambda g: rend(g).update(supersample=0)),
         ["RENDERER_PARAMETER_INVALID"]),
        ("supersample 5", m(lambda g: rend(g).update(supersample=5)),
         ["RENDERER_PARAMETER_INVALID"]),
        ("mlp without weights", m(lambda g: rend(g).pop("weights")), ["WEIGHTS_MISSING"]),
        ("2 channels", m(lambda g: (tex(g).update(channels=2), rend(g).update(inputChannels=2))),
         ["TEXTURE_CHANNELS_RANGE", "WEIGHTS_SHAPE_MISMATCH"]),
        ("100 channels", m(lambda g: (tex(g).update(channels=100))),
         ["LIMIT_EXCEEDED", "RENDERER_INPUT_MISMATCH"]),
        ("flipped weight byte", m(lambda g: _set_view_byte(g, 6, 0, 0x55)),
         ["WEIGHTS_CHECKSUM_MISMATCH"]),
        ("tensor past view end", m(lambda g: rend(g)["weights"][3].update(byteOffset=4096)),
         ["BUFFER_VIEW_OUT_OF_RANGE"]),
        ("f32 NaN weight", m(lambda g: (_set_view_byte(g, 6, 144 + 2, 0xC0),
                                       _set_view_byte(g, 6, 144 + 3, 0x7F),
                                       rend(g)["weights"][2].update(crc32=zlib.crc32(
                                           view_bytes(g, 6)[144:144 + 128])))),
         ["WEIGHTS_NON_FINITE"]),
        ("TEXCOORD_1", m(lambda g: binding(g).update(texCoord=1)), ["TEXCOORD_MISSING"]),
        ("int8 weight matrix", m(lambda g: _store_int8(g, 0)), []),
        ("int8 row scale 0", m(lambda g: _store_int8(g, 0, 0.0)), ["WEIGHTS_SCALE_INVALID"]),
        ("int8 row scale NaN", m(lambda g: _store_int8(g, 0, math.nan)),
         ["WEIGHTS_SCALE_INVALID"]),
        ("int8 row scale 3e38 (scale * q overflows f32)",
         m(lambda g: _store_int8(g, 0, 3e38)), ["WEIGHTS_NON_FINITE"]),
    ]


# --------------------------------------------------------------------------------------------
# Schema checks
# --------------------------------------------------------------------------------------------

# Minimal stand-ins for the core glTF 2.0 schemas the extension schemas reference.
CORE_STUBS = {
    "glTFProperty.schema.json": {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "$id": "glTFProperty.schema.json", "type": "object",
        "properties": {"extensions": {"type": "object"}, "extras": {}}},
    "glTFChildOfRootProperty.schema.json": {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "$id": "glTFChildOfRootProperty.schema.json", "type": "object",
        "allOf": [{"$ref": "glTFProperty.schema.json"}],
        "properties": {"name": {"type": "string"}}},
    "glTFid.schema.json": {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "$id": "glTFid.schema.json", "type": "integer", "minimum": 0},
}


def load_validators():
    from jsonschema import Draft202012Validator
    from referencing import Registry, Resource

    schemas = {p.name: json.loads(p.read_text()) for p in sorted(SCHEMA_DIR.glob("*.json"))}
    resources = [(k, Resource.from_contents(v)) for k, v in {**CORE_STUBS, **schemas}.items()]
    registry = Registry().with_resources(resources)
    for name, s in schemas.items():
        Draft202012Validator.check_schema(s)
        assert s["$id"] == name, f"{name}: $id must equal the file name"
    return schemas, {name: Draft202012Validator(s, registry=registry)
                     for name, s in schemas.items()}


NEGATIVE_RENDERERS = [
    ("unet without widths", {"architecture": "unet", "inputChannels": 4, "outputChannels": 3,
                             "decoder": "transposedConv", "normalization": "none", "weights": []}),
    ("unet without decoder", {"architecture": "unet", "inputChannels": 4, "outputChannels": 3,
                              "widths": [4], "normalization": "none", "weights": []}),
    ("unet with 9 stages", {"architecture": "unet", "inputChannels": 4, "outputChannels": 3,
                            "widths": [4] * 9, "decoder": "upsampleConv", "normalization": "none",
                            "weights": []}),
    ("mlp without hidden", {"architecture": "mlp", "inputChannels": 4, "outputChannels": 3,
                            "weights": []}),
    ("mlp without weights", {"architecture": "mlp", "inputChannels": 4, "outputChannels": 3,
                             "hidden": []}),
    ("none with 4 outputs", {"architecture": "none", "inputChannels": 4, "outputChannels": 4}),
    ("none with weights", {"architecture": "none", "inputChannels": 4, "outputChannels": 3,
                           "weights": [{"name": "x", "shape": [1], "dtype": "f32",
                                        "bufferView": 0, "crc32": 0}]}),
    ("no outputChannels", {"architecture": "mlp", "inputChannels": 4, "hidden": [],
                           "weights": []}),
    ("misaligned tensor", {"architecture": "mlp", "inputChannels": 4, "outputChannels": 3,
                           "hidden": [], "weights": [{"name": "layers.0.bias", "shape": [3],
                                                      "dtype": "f32", "bufferView": 0,
                                                      "byteOffset": 2, "crc32": 0}]}),
    ("supersample 0", {"architecture": "none", "inputChannels": 4, "outputChannels": 3,
                       "supersample": 0}),
    ("supersample 5", {"architecture": "none", "inputChannels": 4, "outputChannels": 3,
                       "supersample": 5}),
    ("supersample 1.5", {"architecture": "none", "inputChannels": 4, "outputChannels": 3,
                         "supersample": 1.5}),
    ("crc32 too large", {"architecture": "mlp", "inputChannels": 4, "outputChannels": 3,
                         "hidden": [], "weights": [{"name": "layers.0.bias", "shape": [3],
                                                    "dtype": "f32", "bufferView": 0,
                                                    "crc32": 4294967296}]}),
]

POSITIVE_RENDERERS = [
    ("unknown architecture with its own fields",
     {"architecture": "siren", "inputChannels": 4, "outputChannels": 3, "omega": 30}),
    ("unet with an unknown decoder value (reported as RENDERER_PARAMETER_INVALID, not schema)",
     {"architecture": "unet", "inputChannels": 4, "outputChannels": 3, "widths": [4],
      "decoder": "pixelShuffle", "normalization": "none", "weights": []}),
    ("mlp with no hidden layer", {"architecture": "mlp", "inputChannels": 4, "outputChannels": 4,
                                  "hidden": [], "weights": []}),
    ("supersample 4 (revision 1.3)", {"architecture": "mlp", "inputChannels": 4,
                                      "outputChannels": 3, "hidden": [], "weights": [],
                                      "supersample": 4}),
]

PRIMITIVE_SCHEMA = "mesh.primitive.EXT_deferred_neural_rendering.schema.json"

NEGATIVE_OTHER = [
    ("root.EXT without version", "glTF.EXT_deferred_neural_rendering.schema.json",
     {"neuralTextures": [], "renderers": []}),
    ("primitive binding without renderer", PRIMITIVE_SCHEMA, {"neuralTexture": 0}),
    ("primitive binding with a negative texCoord", PRIMITIVE_SCHEMA,
     {"neuralTexture": 0, "renderer": 0, "texCoord": -1}),
    ("texture with 2 channels", "neuralTexture.schema.json",
     {"channels": 2, "levels": [{"width": 1, "height": 1, "bufferView": 0,
                                 "mimeType": "image/x-exr"}]}),
    ("texture without levels", "neuralTexture.schema.json", {"channels": 3, "levels": []}),
    ("level with png", "neuralTextureLevel.schema.json",
     {"width": 1, "height": 1, "bufferView": 0, "mimeType": "image/png"}),
    ("SH degree 4", "viewDependence.schema.json",
     {"basis": "sphericalHarmonics", "degree": 4, "firstChannel": 0}),
    ("negative index", PRIMITIVE_SCHEMA, {"neuralTexture": -1, "renderer": 0}),
]


# --------------------------------------------------------------------------------------------
# Main
# --------------------------------------------------------------------------------------------

class Results:
    def __init__(self):
        self.passed = 0
        self.failed = 0

    def check(self, ok: bool, what: str, detail: str = "") -> None:
        if ok:
            self.passed += 1
        else:
            self.failed += 1
            print(f"FAIL: {what}" + (f": {detail}" if detail else ""))


def dumps(obj) -> str:
    """JSON with 2-space indentation and arrays of numbers or short strings on one line."""
    text = json.dumps(obj, indent=2)
    scalar = r'(?:-?\d[\d.eE+-]*|"[^"\n]{0,24}"|true|false|null)'
    return re.sub(r"\[\s*(" + scalar + r"(?:,\s*" + scalar + r")*)\s*\]",
                  lambda m: "[" + re.sub(r",\s+", ", ", m.group(1)) + "]", text) + "\n"


def _errors(validator, obj) -> list[str]:
    return [f"{'/'.join(map(str, e.absolute_path))}: {e.message}"
            for e in validator.iter_errors(obj)]


def main(argv: list[str]) -> int:
    if "--write" in argv:
        for name, build in GENERATED.items():
            text = dumps(build())
            (EXAMPLES / name).write_text(text)
            print(f"wrote examples/{name}")

    res = Results()
    try:
        schemas, v = load_validators()
        res.check(True, "schemas")
    except Exception as e:  # noqa: BLE001 - report any schema problem as one failure
        res.check(False, "schemas are valid draft 2020-12 and resolve", repr(e))
        print(f"{res.passed} passed, {res.failed} failed")
        return 1
    res.check(len(schemas) == 7, "seven schema files", str(sorted(schemas)))
    root_v = v["glTF.EXT_deferred_neural_rendering.schema.json"]
    prim_v = v[PRIMITIVE_SCHEMA]
    rend_v = v["renderer.schema.json"]

    # 1. Examples on disk equal the builders' output.
    for name, build in GENERATED.items():
        path = EXAMPLES / name
        ok = path.exists() and json.loads(path.read_text()) == json.loads(json.dumps(build()))
        res.check(ok, f"examples/{name} is up to date (run with --write to regenerate)")

    # 2. Every example validates against its schema.
    minimal = json.loads((EXAMPLES / "minimal.gltf").read_text())
    res.check(not (e := _errors(root_v, minimal["extensions"][EXT])), "minimal root object", str(e))
    bound = bound_primitives(minimal)
    res.check(len(bound) == 1, "minimal.gltf binds its primitive")
    for i, p in enumerate(bound):
        res.check(not (e := _errors(prim_v, p["extensions"][EXT])), f"minimal binding {i}", str(e))
    # The fallback material is plain: KHR_materials_unlit only (anything beside it makes
    # glTF-Validator warn MULTIPLE_EXTENSIONS).
    for i, m in enumerate(minimal["materials"]):
        res.check(list(m.get("extensions", {})) == [UNLIT],
                  f"minimal material {i} carries only {UNLIT}", str(m.get("extensions")))
    for name in ("unet_renderer.json", "unet_upsample_renderer.json", "none_renderer.json"):
        obj = json.loads((EXAMPLES / name).read_text())
        res.check(not (e := _errors(rend_v, obj)), f"examples/{name} against renderer schema", str(e))
    for what, obj in POSITIVE_RENDERERS:
        res.check(not (e := _errors(rend_v, obj)), f"schema accepts: {what}", str(e))
    for what, obj in NEGATIVE_RENDERERS:
        res.check(bool(_errors(rend_v, obj)), f"schema rejects: {what}")
    for what, schema, obj in NEGATIVE_OTHER:
        res.check(bool(_errors(v[schema], obj)), f"schema rejects: {what}")

    # 3. Tensor lists follow the naming rules.
    unet = json.loads((EXAMPLES / "unet_renderer.json").read_text())
    listed = {w["name"]: w["shape"] for w in unet["weights"]}
    want = expected_tensors(unet, unet["inputChannels"])
    res.check(listed == want, "U-Net example tensors", f"{listed} != {want}")
    res.check(len(unet["weights"]) == 20 and listed["decoder.3.weight"] == [256, 64, 4, 4]
              and listed["decoder.0.weight"] == [32, 4, 4, 4]
              and listed["encoder.0.weight"] == [16, 16, 4, 4],
              "U-Net example spot checks (independent of the generator)")
    res.check(all(w["byteOffset"] % 4 == 0 for w in unet["weights"]), "U-Net offsets aligned")

    # 4. The minimal glTF passes the reference validator; each mutation gives its codes.
    codes = validate(minimal)
    res.check(codes == [], "minimal.gltf validates clean", str(codes))
    for what, g, expected in mutations(minimal):
        got = validate(g)
        res.check(sorted(set(got)) == sorted(set(expected)), f"mutation '{what}'",
                  f"got {got}, expected {expected}")
    # The EXR levels decode to the texture values; cross-check with OpenEXR when available.
    levels = minimal_texture_levels()
    for i, lv in enumerate(levels):
        info = exr_read(view_bytes(minimal, 3 + i))
        res.check(info["data"] == lv["data"], f"EXR level {i} decodes to its texels")
        try:
            import OpenEXR  # type: ignore
            import numpy  # type: ignore  # noqa: F401
        except ImportError:
            continue
        import os
        import tempfile
        with tempfile.NamedTemporaryFile(suffix=".exr", delete=False) as f:
            f.write(view_bytes(minimal, 3 + i))
        try:
            with OpenEXR.File(f.name, separate_channels=True) as ef:
                ch = ef.channels()
                names = sorted(ch)
                ok = names == exr_channel_names(8)
                for k, n in enumerate(names):
                    px = ch[n].pixels
                    ok &= px.dtype.name == "float16" and px.shape == (lv["height"], lv["width"])
                    ok &= all(float(px[j, x]) == lv["data"][(j * lv["width"] + x) * 8 + k]
                              for j in range(lv["height"]) for x in range(lv["width"]))
                res.check(ok, f"OpenEXR reads level {i} identically")
        finally:
            os.unlink(f.name)
    # The fallback PNG decodes (zlib/CRC) and is made from channels 0..2.
    png = view_bytes(minimal, 5)
    ihdr = struct.unpack(">IIBBBBB", png[16:29])
    res.check(png[:8] == b"\x89PNG\r\n\x1a\n" and ihdr[:4] == (4, 4, 8, 2), "fallback PNG header")

    # 5. Worked example numbers.
    we = json.loads((EXAMPLES / "worked_example.json").read_text())
    bil = we["bilinear"]["results"]
    res.check(abs(bil["REPEAT"] - 1.3) < 1e-9 and abs(bil["CLAMP_TO_EDGE"] - 2.0) < 1e-9
              and abs(bil["MIRRORED_REPEAT"] - 1.9) < 1e-9, "bilinear worked example", str(bil))
    res.check(we["bilinear"]["texel_centre_value"] == 3.0, "texel centre samples the texel")
    res.check(abs(we["bilinear"]["with_1x1_level_of_10_REPEAT"] - 11.3) < 1e-9, "level sum")
    sh = we["sh_basis"]
    res.check(len(sh) == 16 and abs(sh[2] + SH_C1) < 1e-15 and abs(sh[6] - 2 * SH_C2[1]) < 1e-15
              and abs(sh[12] + 2 * SH_C3[3]) < 1e-15
              and all(sh[j] == 0 for j in range(16) if j not in (0, 2, 6, 12)),
              "SH at (0,0,-1)", str(sh))
    res.check(we["unet"]["padded"] == [256, 160]
              and we["unet"]["encoder"] == [[128, 80], [64, 40], [32, 20], [16, 10], [8, 5]],
              "U-Net sizes for 250x130, D=5")
    res.check(we["crc32_123456789"] == 0xCBF43926, "CRC-32/ISO-HDLC check value")
    readme = (HERE / "README.md").read_text()
    for s in ("1.3", "1.9", "11.3", "0.6307831305050401", "-0.7463526651802308",
              "-0.4886025119029199", "256 x 160", "8 x 5", "3421780262", "C000", "C100",
              "KHR_materials_unlit", "check_examples.py"):
        res.check(s in readme, f"README mentions {s}")
    for s in sorted({c for c in _ALL_CODES}):
        res.check(f"`{s}`" in readme, f"README documents {s}")
    for name in schemas:
        res.check(name in readme, f"README lists schema/{name}")

    print(f"{res.passed} passed, {res.failed} failed")
    return 1 if res.failed else 0


_ALL_CODES = """GLB_INVALID_HEADER GLB_TRUNCATED GLB_CHUNK_INVALID JSON_INVALID JSON_SCHEMA
INDEX_OUT_OF_RANGE BUFFER_VIEW_OUT_OF_RANGE VERSION_UNSUPPORTED EXTENSION_REQUIRED
EXTENSION_NOT_USED FALLBACK_MISSING TEXTURE_NO_LEVELS TEXTURE_MIME_TYPE TEXTURE_CHANNELS_RANGE
EXR_INVALID EXR_CHANNELS EXR_SIZE_MISMATCH EXR_COMPRESSION EXR_NON_FINITE SH_DEGREE_UNSUPPORTED
SH_CHANNELS_OUT_OF_RANGE RENDERER_UNKNOWN_ARCHITECTURE RENDERER_PARAMETER_INVALID
RENDERER_INPUT_MISMATCH RENDERER_OUTPUT_CHANNELS WEIGHTS_MISSING WEIGHTS_UNEXPECTED
WEIGHTS_SHAPE_MISMATCH WEIGHTS_DTYPE_UNKNOWN WEIGHTS_MISALIGNED WEIGHTS_CHECKSUM_MISMATCH
WEIGHTS_NON_FINITE LIMIT_EXCEEDED TEXCOORD_MISSING QUANT_BITS QUANT_ARRAY_LENGTH
QUANT_SCALE_INVALID PNG_INVALID PNG_FORMAT PNG_SIZE_MISMATCH WEIGHTS_SCALE_INVALID""".split()


def png_level_codes(lv, channels, buf):
    """Revision 1.1 checks of a quantised PNG level (parameters, then the PNG header; the
    pixels are not decoded by this reference)."""
    q = lv["quantization"]
    codes = []
    bits = q.get("bits")
    if bits not in (8, 4):
        codes.append("QUANT_BITS")
    scale, offset = q.get("scale", []), q.get("offset", [])
    if len(scale) != channels or len(offset) != channels:
        codes.append("QUANT_ARRAY_LENGTH")
    top = 255 if bits not in (8, 4) else 2 ** bits - 1
    for s_, o_ in zip(scale, offset):
        s32 = struct.unpack("<f", struct.pack("<f", s_))[0] if abs(s_) < 3.5e38 else math.inf
        if not (math.isfinite(s32) and s32 > 0 and math.isfinite(o_)
                and abs(o_ + s32 * top) < 3.4e38):
            codes.append("QUANT_SCALE_INVALID")
            break
    if codes:
        return codes
    if len(buf) < 33 or buf[:8] != b"\x89PNG\r\n\x1a\n" or buf[12:16] != b"IHDR":
        return ["PNG_INVALID"]
    w, h, depth, colour = struct.unpack(">IIBB", buf[16:26])
    if depth != 8 or colour != 6:
        return ["PNG_FORMAT"]
    groups = -(-channels // (4 if bits == 8 else 8))
    if (w, h) != (lv["width"], lv["height"] * groups):
        return ["PNG_SIZE_MISMATCH"]
    return []

if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
