#!/usr/bin/env python3
"""Cross-checks dnr-format's decoding of quantised PNG levels (revision 1.1) against a decoder
written here from the PNG specification (zlib, the five scanline filters) and the extension's
"Quantised Storage of a Level": channel groups stacked top to bottom, at 8 bits channel c in
component c % 4, at 4 bits in component (c % 8) / 2, low nibble for even c, and
value = offset[c] + scale[c] * q with both operations rounded to f32.

For every valid sample (samples/valid/*.glb|gltf) with quantised levels, every value must be
bit-identical with what `dnr-format` decodes, as printed by
`cargo run -p dnr-format --example dump_levels -- FILE` (its `pngLevels`).

Needs: numpy, and OpenEXR through check_exr.py, whose container reader it shares (tests/run.sh
installs both under .tools/venv). Usage:
    python tests/scripts/check_png_levels.py [SAMPLES_DIR] [--dump CMD]
"""
import json
import os
import shlex
import struct
import subprocess
import sys
import zlib

import numpy as np

from check_exr import EXT, load, view_bytes

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def paeth(a, b, c):
    p = a + b - c
    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
    if pa <= pb and pa <= pc:
        return a
    return b if pb <= pc else c


def decode_png_rgba8(data):
    """(width, height, rows of width * 4 bytes) of a non-interlaced 8-bit RGBA PNG."""
    assert data[:8] == PNG_SIGNATURE, "PNG signature"
    at, ihdr, idat = 8, None, b""
    while at < len(data):
        length, kind = struct.unpack_from(">I4s", data, at)
        body = data[at + 8 : at + 8 + length]
        (crc,) = struct.unpack_from(">I", data, at + 8 + length)
        assert zlib.crc32(kind + body) == crc, f"CRC of chunk {kind!r}"
        if kind == b"IHDR":
            ihdr = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat += body
        elif kind == b"IEND":
            break
        at += 12 + length
    w, h, depth, colour, compression, filt, interlace = ihdr
    assert (depth, colour, compression, filt) == (8, 6, 0, 0), f"IHDR {ihdr}"
    assert interlace == 0, "interlaced PNG (this reference reads non-interlaced images only)"
    raw = zlib.decompress(idat)
    stride, bpp = w * 4, 4
    assert len(raw) == h * (stride + 1), "decompressed size"
    rows, prev = [], bytearray(stride)
    for j in range(h):
        kind = raw[j * (stride + 1)]
        line = bytearray(raw[j * (stride + 1) + 1 : (j + 1) * (stride + 1)])
        for i in range(stride):
            a = line[i - bpp] if i >= bpp else 0
            b = prev[i]
            c = prev[i - bpp] if i >= bpp else 0
            if kind == 1:
                line[i] = (line[i] + a) & 0xFF
            elif kind == 2:
                line[i] = (line[i] + b) & 0xFF
            elif kind == 3:
                line[i] = (line[i] + (a + b) // 2) & 0xFF
            elif kind == 4:
                line[i] = (line[i] + paeth(a, b, c)) & 0xFF
            else:
                assert kind == 0, f"filter type {kind}"
        rows.append(bytes(line))
        prev = line
    return w, h, rows


def reference_level(png, width, height, channels, q):
    """The level's values (HWC, float32) from the PNG and its quantization object."""
    bits = q["bits"]
    per = 4 if bits == 8 else 8
    groups = -(-channels // per)
    w, h, rows = decode_png_rgba8(png)
    assert (w, h) == (width, height * groups), f"PNG {w}x{h} for {width}x{height}x{channels}"
    scale = np.array(q["scale"], dtype=np.float32)
    offset = np.array(q["offset"], dtype=np.float32)
    out = np.zeros((height, width, channels), dtype=np.float32)
    for c in range(channels):
        g, within = divmod(c, per)
        for j in range(height):
            row = rows[g * height + j]
            for i in range(width):
                if bits == 8:
                    v = row[i * 4 + within]
                else:
                    v = (row[i * 4 + within // 2] >> (4 * (within % 2))) & 0x0F
                # float32 * float32, then float32 + float32: two roundings, as the spec says.
                out[j, i, c] = offset[c] + scale[c] * np.float32(v)
    return out


def main():
    args = sys.argv[1:]
    dump = "cargo run -q -p dnr-format --example dump_levels --"
    if "--dump" in args:
        i = args.index("--dump")
        dump = args[i + 1]
        del args[i : i + 2]
    folder = args[0] if args else "samples/valid"
    files = sorted(f for f in os.listdir(folder) if f.lower().endswith((".glb", ".gltf")))
    passed = failed = checked = 0
    for name in files:
        path = os.path.join(folder, name)
        doc, buffers = load(path)
        textures = doc["extensions"][EXT]["neuralTextures"]
        declared = [(ti, li) for ti, t in enumerate(textures)
                    for li, lv in enumerate(t["levels"]) if "quantization" in lv]
        if not declared:
            continue
        ours = json.loads(subprocess.run(shlex.split(dump) + [path], check=True,
                                         capture_output=True, text=True).stdout)
        problems = []
        if [(lv["texture"], lv["level"]) for lv in ours["pngLevels"]] != declared:
            problems.append(f"dump has levels {ours['pngLevels']}, JSON {declared}")
        for lv in ours["pngLevels"]:
            tag = f"texture {lv['texture']} level {lv['level']}"
            spec = textures[lv["texture"]]["levels"][lv["level"]]
            ref = reference_level(view_bytes(doc, buffers, spec["bufferView"]), lv["width"],
                                  lv["height"], lv["channels"], spec["quantization"])
            got = np.array(lv["f32Bits"], dtype=np.uint32).reshape(ref.shape)
            differ = int(np.count_nonzero(ref.view(np.uint32) != got))
            if differ:
                problems.append(f"{tag}: {differ} of {ref.size} values differ")
            checked += 1
        if problems:
            failed += 1
            print(f"FAIL {name}")
            for p in problems:
                print(f"     {p}")
        else:
            passed += 1
            print(f"ok   {name}: {len(ours['pngLevels'])} quantised levels bit-identical")
    print(f"{passed} passed, {failed} failed ({checked} quantised levels)")
    if checked == 0:
        print(f"no quantised levels in {folder}", file=sys.stderr)
        return 2
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
