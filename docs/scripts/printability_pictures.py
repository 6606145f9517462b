#!/usr/bin/env python3
"""Makes the pictures of docs/recipes.md's printability section from real runs of voxlat: the
floating-ball recipe's island layer with the island marked, and a layer through the hollow
sphere's resin trap with the drain point marked, and a layer of a BCC lattice of 0.06 mm struts
(under two 35 um pixels) on a plate with the first thin feature of that layer marked. Each picture is the layer as the printer shows
it (PNG folder output, landscape, y up) in grey, the finding in red.

usage: printability_pictures.py VOXLAT_BINARY OUT_FOLDER
"""
import json
import os
import struct
import subprocess
import sys
import tempfile
import zlib

import numpy as np

BALL = """domain: {box: [[0, 0, 0], [40, 40, 12]]}
fields:
  plate: {box: [[0, 0, 0], [40, 40, 1]]}
  ball: {sphere: {center: [25, 15, 8], radius: 3}}
  part: {union: [plate, ball]}
result: part
outputs: {slices: {printer: mono-4k, layer: 0.1, file: layers, format: png, preview: off}}
"""
HOLLOW = """domain: {box: [[0, 0, 0], [16, 16, 16]]}
fields:
  block: {box: [[0, 0, 0], [16, 16, 16]]}
  cavity: {sphere: {center: [8, 8, 8], radius: 4}}
  part: {difference: [block, cavity]}
result: part
outputs: {slices: {printer: mono-4k, layer: 0.1, file: layers, format: png, preview: off}}
"""
THIN = """domain: {box: [[0, 0, 0], [6, 6, 3]]}
fields:
  plate: {box: [[0, 0, 0], [6, 6, 0.5]]}
  lattice: {struts: {cell: bcc, size: 3}, kernel: capsule, radius: 0.03}
  part: {union: [plate, lattice]}
result: part
outputs: {slices: {printer: mono-4k, layer: 0.05, file: layers, format: png, preview: off}}
"""


def first_thin_from(p, layer):
    """The first thin feature listed at or above @a layer: (layer, x, y)."""
    e = next(e for e in p["thin"]["first"] if e["layer"] >= layer)
    return e["layer"], e["x"], e["y"]


def read_png(path):
    b = open(path, "rb").read()
    pos, idat = 8, b""
    while pos < len(b):
        n, kind = struct.unpack(">I4s", b[pos:pos + 8])
        if kind == b"IHDR":
            w, h = struct.unpack(">II", b[pos + 8:pos + 16])
        elif kind == b"IDAT":
            idat += b[pos + 8:pos + 8 + n]
        pos += 12 + n
    raw = np.frombuffer(zlib.decompress(idat), np.uint8).reshape(h, w + 1)
    assert (raw[:, 0] == 0).all(), "voxlat's layer PNGs use filter NONE"
    return raw[:, 1:].copy()


def write_png(path, rgb):
    h, w, _ = rgb.shape
    raw = b"".join(b"\0" + rgb[r].tobytes() for r in range(h))

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)) +
                chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))


def picture(voxlat, recipe_text, tmp, name, pick, out):
    recipe = os.path.join(tmp, name + ".yaml")
    open(recipe, "w").write(recipe_text)
    subprocess.run([voxlat, "-q", "run", recipe, "--out", os.path.join(tmp, name)], check=True)
    report = json.load(open(os.path.join(tmp, name, "report.json")))
    s = report["slices"][0]
    layer, x, y = pick(s["printability"])
    image = read_png(os.path.join(tmp, name, "layers", f"{layer:05d}.png"))
    i0, j0, nx, ny = s["window_pixels"]
    pitch = s["display_mm"][0] / s["display_pixels"][0]
    # Stored rows run top to bottom (y flipped) on this landscape, unmirrored profile: crop the window.
    H = image.shape[0]
    crop = image[H - (j0 + ny):H - j0, i0:i0 + nx].astype(np.float64)
    rgb = np.stack([crop * 0.8 + 20] * 3, axis=-1)
    # A red ring around the finding (x, y in the part's frame; the window starts at the part's corner).
    ci = (x - report["recipe_canonical"]["domain"]["box"][0][0]) / pitch
    cj = (y - report["recipe_canonical"]["domain"]["box"][0][1]) / pitch
    jj, ii = np.mgrid[0:ny, 0:nx]
    r = np.hypot(ii + 0.5 - ci, (ny - 1 - jj) + 0.5 - cj)
    ring = (r > 25) & (r < 31)
    rgb[ring] = [230, 30, 30]
    write_png(out, np.clip(rgb, 0, 255).astype(np.uint8))
    print(f"{out}: layer {layer} at ({x:.2f}, {y:.2f})")


def main():
    voxlat, folder = sys.argv[1], sys.argv[2]
    os.makedirs(folder, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        picture(voxlat, BALL, tmp, "ball", lambda p: (p["islands"][0]["layer"], p["islands"][0]["x"],
                                                      p["islands"][0]["y"]),
                os.path.join(folder, "printability-island.png"))
        picture(voxlat, HOLLOW, tmp, "hollow",
                lambda p: (int(round(p["resin_traps"][0]["z"] / 0.1 - 0.5)), p["resin_traps"][0]["x"],
                           p["resin_traps"][0]["y"]),
                os.path.join(folder, "printability-trap.png"))
        picture(voxlat, THIN, tmp, "thin", lambda p: first_thin_from(p, 40),
                os.path.join(folder, "printability-thin.png"))


if __name__ == "__main__":
    sys.exit(main())
