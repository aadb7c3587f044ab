#!/usr/bin/env python3
"""Cross-checks dnr-format's EXR codec against the reference OpenEXR library.

For every valid sample (samples/valid/*.glb|gltf) this script parses the container itself
(GLB chunks, data: URIs or external .bin), extracts each EXR neural texture level's
bufferView (quantised PNG levels of revision 1.1 are not EXR and are skipped), decodes it with the PyPI `OpenEXR` package and checks that the channel names,
size and every half value (bit for bit) equal what `dnr-format` decodes, as printed by
`cargo run -p dnr-format --example dump_levels -- FILE`.

Needs: pip install OpenEXR numpy (e.g. into .tools/py). Usage:
    python tests/scripts/check_exr.py [SAMPLES_DIR] [--dump CMD]
where CMD defaults to `cargo run -q -p dnr-format --example dump_levels --`.
"""
import base64
import json
import os
import shlex
import struct
import subprocess
import sys
import tempfile
import urllib.parse

import numpy as np
import OpenEXR

EXT = "EXT_deferred_neural_rendering"
EXR_MIME_TYPE = "image/x-exr"


def load(path):
    """Returns (gltf JSON, list of buffer bytes)."""
    data = open(path, "rb").read()
    if data[:4] == b"glTF":
        _, _, total = struct.unpack_from("<4sII", data, 0)
        assert total == len(data), "GLB length"
        at, doc, bin_chunk = 12, None, None
        while at < len(data):
            length, kind = struct.unpack_from("<II", data, at)
            chunk = data[at + 8 : at + 8 + length]
            if kind == 0x4E4F534A:
                doc = json.loads(chunk.decode("utf-8"))
            elif kind == 0x004E4942:
                bin_chunk = chunk
            at += 8 + length
    else:
        doc = json.loads(data.decode("utf-8"))
        bin_chunk = None
    buffers = []
    for i, b in enumerate(doc.get("buffers", [])):
        uri = b.get("uri")
        if uri is None:
            assert i == 0 and bin_chunk is not None
            buffers.append(bin_chunk)
        elif uri.startswith("data:"):
            buffers.append(base64.b64decode(uri.split(",", 1)[1]))
        else:
            rel = urllib.parse.unquote(uri)
            buffers.append(open(os.path.join(os.path.dirname(path), rel), "rb").read())
    return doc, buffers


def view_bytes(doc, buffers, index):
    v = doc["bufferViews"][index]
    start = v.get("byteOffset", 0)
    return buffers[v["buffer"]][start : start + v["byteLength"]]


def decode_reference(exr_bytes):
    """Channel name -> (H, W) uint16 half bit patterns, decoded by OpenEXR."""
    with tempfile.NamedTemporaryFile(suffix=".exr", delete=False) as f:
        f.write(exr_bytes)
        name = f.name
    try:
        with OpenEXR.File(name, separate_channels=True) as exr:
            assert len(exr.parts) == 1, "EXR must have one part"
            header = dict(exr.parts[0].header)
            out = {}
            for cname, ch in exr.channels().items():
                px = np.asarray(ch.pixels)
                assert px.dtype == np.float16, f"channel {cname} is {px.dtype}, expected float16"
                out[cname] = px.view(np.uint16)
            return header, out
    finally:
        os.unlink(name)


def main():
    args = sys.argv[1:]
    dump = "cargo run -q -p dnr-format --example dump_levels --"
    if "--dump" in args:
        i = args.index("--dump")
        dump = args[i + 1]
        del args[i : i + 2]
    folder = args[0] if args else "samples/valid"
    files = sorted(f for f in os.listdir(folder) if f.lower().endswith((".glb", ".gltf")))
    if not files:
        print(f"no samples in {folder}", file=sys.stderr)
        return 2
    passed = failed = 0
    for name in files:
        path = os.path.join(folder, name)
        ours = json.loads(subprocess.run(shlex.split(dump) + [path], check=True, capture_output=True, text=True).stdout)
        doc, buffers = load(path)
        textures = doc["extensions"][EXT]["neuralTextures"]
        expected_levels = sum(1 for t in textures for lv in t["levels"]
                              if lv.get("mimeType") == EXR_MIME_TYPE)
        problems = []
        if expected_levels != len(ours["levels"]):
            problems.append(f"dump has {len(ours['levels'])} levels, JSON {expected_levels}")
        for lv in ours["levels"]:
            tag = f"texture {lv['texture']} level {lv['level']}"
            declared = textures[lv["texture"]]["levels"][lv["level"]]
            header, ref = decode_reference(view_bytes(doc, buffers, declared["bufferView"]))
            w, h, c = lv["width"], lv["height"], lv["channels"]
            for window in ("dataWindow", "displayWindow"):
                (x0, y0), (x1, y1) = (tuple(int(v) for v in corner) for corner in header[window])
                if (x0, y0, x1 - x0 + 1, y1 - y0 + 1) != (0, 0, w, h):
                    problems.append(f"{tag}: OpenEXR {window} {(x0, y0, x1, y1)} vs {w}x{h}")
            if str(header.get("type")) != "Storage.scanlineimage":
                problems.append(f"{tag}: OpenEXR storage {header.get('type')}, expected scanline")
            if sorted(ref) != sorted(lv["channelNames"]):
                problems.append(f"{tag}: OpenEXR channels {sorted(ref)} vs {lv['channelNames']}")
                continue
            bits = np.array(lv["halfBits"], dtype=np.uint16).reshape(h, w, c)
            for ci, cname in enumerate(lv["channelNames"]):
                if not np.array_equal(ref[cname], bits[:, :, ci]):
                    n = int(np.count_nonzero(ref[cname] != bits[:, :, ci]))
                    problems.append(f"{tag} channel {cname}: {n} half values differ")
        if problems:
            failed += 1
            print(f"FAIL {name}")
            for p in problems:
                print(f"     {p}")
        else:
            passed += 1
            skipped = sum(len(t["levels"]) for t in textures) - expected_levels
            note = f" ({skipped} quantised PNG levels skipped)" if skipped else ""
            print(f"ok   {name}: {len(ours['levels'])} levels bit-identical with OpenEXR{note}")
    print(f"{passed} passed, {failed} failed")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
