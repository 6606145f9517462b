#!/usr/bin/env python3
"""Checks voxlat's Elegoo .goo archives with a decoder written from shared/reference/goo-format.md
alone (no code shared with the writer): the header fields, the layer definitions, every layer's
checksum and run-length code decoding to exactly width x height pixels, the ending string, and
every layer's pixels against the PNG folder the same recipe gives. Also: an unknown profile format
and a display too large for the format are refused with the profile file named, nothing written.

usage: check_goo.py VOXLAT_BINARY
"""
import os
import struct
import subprocess
import sys
import tempfile
import zlib

import numpy as np

HEADER = 195477
MAGIC = bytes([0x07, 0x00, 0x00, 0x00, 0x44, 0x4C, 0x50, 0x00])
ENDING = bytes([0x00, 0x00, 0x00]) + MAGIC

RECIPE = """domain: {box: [[0, 0, 0], [24, 18, 3]]}
fields:
  lattice: {tpms: gyroid, cell: 6, solid: sheet, level: 0.5}
result: lattice
outputs: {slices: {printer: PRINTER, layer: 0.05, file: FILE}}
"""

failures = []


def check(condition, message):
    if not condition:
        failures.append(message)
        print("FAIL:", message)


def read_header(b):
    """The header as a dict, read field by field at the reference's absolute offsets."""
    def f32(off):
        return struct.unpack(">f", b[off:off + 4])[0]

    def u32(off):
        return struct.unpack(">I", b[off:off + 4])[0]

    def u16(off):
        return struct.unpack(">H", b[off:off + 2])[0]

    def text(off, n):
        return b[off:off + n].split(b"\0")[0].decode("ascii")

    return {
        "version": b[0:4].decode("ascii"), "magic": b[4:12], "software": text(12, 32),
        "printer": text(92, 32), "delim1": b[27106:27108], "delim2": b[195308:195310],
        "layers": u32(195310), "res_x": u16(195314), "res_y": u16(195316), "mirror_x": b[195318],
        "mirror_y": b[195319], "width_mm": f32(195320), "height_mm": f32(195324), "machine_z": f32(195328),
        "layer_mm": f32(195332), "exposure": f32(195336), "delay_mode": b[195340],
        "bottom_exposure": f32(195369), "bottom_layers": u32(195373), "lift1": f32(195385),
        "lift_speed1": f32(195389), "pwm": u16(195443), "advance": b[195445], "offset": u32(195470),
        "grey": b[195474], "transition": u16(195475),
    }


def decode_image(data, width, height):
    """Decodes one layer's image data (0x55, chunks, checksum) into a height x width array."""
    check(data[0] == 0x55, "image data starts with 0x55")
    body = data[1:-1]
    check((~sum(body)) & 0xFF == data[-1], "layer checksum")
    values, lengths = [], []
    previous, k = 0, 0
    while k < len(body):
        b0 = body[k]
        kind = b0 >> 6
        if kind == 2:  # difference chunk (voxlat does not write them; a reader must take them)
            d = b0 & 0x0F
            value = previous - d if b0 & 0x20 else previous + d
            if b0 & 0x10:
                n = body[k + 1]
                k += 2
            else:
                n = 1
                k += 1
        else:
            k += 1
            if kind == 0:
                value = 0
            elif kind == 3:
                value = 255
            else:
                value = body[k]
                k += 1
            extra = (b0 >> 4) & 3
            n = 0
            for _ in range(extra):
                n = (n << 8) | body[k]
                k += 1
            n = (n << 4) | (b0 & 0x0F)
        check(n > 0, "runs are never empty")
        values.append(value)
        lengths.append(n)
        previous = value
    total = sum(lengths)
    check(total == width * height, f"a layer decodes to {total} pixels, not {width} x {height}")
    if total != width * height:
        return None
    return np.repeat(np.array(values, np.uint8), lengths).reshape(height, width)


def read_png(path):
    """An 8-bit grey PNG (filter types 0-4) as an array."""
    b = open(path, "rb").read()
    pos, idat = 8, b""
    while pos < len(b):
        n, kind = struct.unpack(">I4s", b[pos:pos + 8])
        chunk = b[pos + 8:pos + 8 + n]
        if kind == b"IHDR":
            w, h, depth, colour = struct.unpack(">IIBB", chunk[:10])
            assert depth == 8 and colour == 0, "grey 8-bit PNG expected"
        elif kind == b"IDAT":
            idat += chunk
        pos += 12 + n
    raw = np.frombuffer(zlib.decompress(idat), np.uint8).reshape(h, w + 1)
    out = np.zeros((h, w), np.uint8)
    prior = np.zeros(w, np.int32)
    for r in range(h):
        f, line = raw[r, 0], raw[r, 1:].astype(np.int32)
        if f == 0:
            cur = line
        elif f == 2:
            cur = (line + prior) & 255
        else:
            cur = np.zeros(w, np.int32)
            for i in range(w):
                a = cur[i - 1] if i else 0
                c = prior[i - 1] if i else 0
                p = a + prior[i] - c
                pred = {1: a, 3: (a + prior[i]) // 2,
                        4: a if abs(p - a) <= min(abs(p - prior[i]), abs(p - c)) else
                        (prior[i] if abs(p - prior[i]) <= abs(p - c) else c)}[int(f)]
                cur[i] = (line[i] + pred) & 255
        out[r] = cur
        prior = cur
    return out


def check_archive(voxlat, tmp, printer, expect):
    recipe = os.path.join(tmp, f"{printer}.yaml")
    open(recipe, "w").write(RECIPE.replace("PRINTER", printer).replace("FILE", "part.goo"))
    goo = os.path.join(tmp, f"{printer}.goo")
    folder = os.path.join(tmp, f"{printer}-png")
    for args in (["-o", goo], ["--format", "png", "--preview", "off", "-o", folder]):
        run = subprocess.run([voxlat, "-q", "slice", recipe] + args, capture_output=True, text=True)
        check(run.returncode == 0, f"voxlat slice {printer} {args}: {run.stderr}")
        if run.returncode:
            return
    b = open(goo, "rb").read()
    h = read_header(b)
    check(h["version"] == "V3.0" and h["magic"] == MAGIC, "version and magic")
    check(h["delim1"] == b"\r\n" and h["delim2"] == b"\r\n", "delimiters after the previews")
    check(h["offset"] == HEADER and h["grey"] == 1 and h["advance"] == 0, "layer offset, grey level, advance mode")
    check(h["layers"] == 60, f"60 layers of 0.05 mm in 3 mm, header says {h['layers']}")
    for key, value in expect.items():
        check(abs(h[key] - value) < 1e-4 if isinstance(value, float) else h[key] == value,
              f"{printer}: header {key} = {h[key]}, expected {value}")
    check(abs(h["layer_mm"] - 0.05) < 1e-7, "layer height")
    pos, previous_z = HEADER, 0.0
    W, H = h["res_x"], h["res_y"]
    for i in range(h["layers"]):
        d = b[pos:pos + 66]
        z, exposure = struct.unpack(">ff", d[6:14])
        check(d[64:66] == b"\r\n", f"layer {i}: definition ends in 0D 0A")
        check(z > previous_z and abs(z - (i + 1) * 0.05) < 1e-5, f"layer {i}: Z {z}")
        bottom = i < h["bottom_layers"]
        check(abs(exposure - (h["bottom_exposure"] if bottom else h["exposure"])) < 1e-5, f"layer {i}: exposure")
        previous_z = z
        size = struct.unpack(">I", b[pos + 66:pos + 70])[0]
        image = decode_image(b[pos + 70:pos + 70 + size], W, H)
        check(b[pos + 70 + size:pos + 72 + size] == b"\r\n", f"layer {i}: image ends in 0D 0A")
        png = read_png(os.path.join(folder, f"{i:05d}.png"))
        if image is not None:
            check(png.shape == image.shape and np.array_equal(png, image),
                  f"layer {i}: .goo pixels differ from the PNG folder's "
                  f"(areas {image.sum() / 255.0:.1f} vs {png.sum() / 255.0:.1f} pixels)")
        pos += 72 + size
    check(b[pos:] == ENDING, "the file ends with the 11-byte ending string")
    print(f"{printer}: {h['layers']} layers of {W} x {H} decoded, {len(b)} bytes")


def check_refusals(voxlat, tmp):
    recipe = os.path.join(tmp, "bad.yaml")
    for name, profile, words in [
            ("unknown-format", "format: gooo\n", ["unknown format", "unknown-format.yaml"]),
            ("too-big", "format: goo\n", ["65535", "too-big.yaml:3"])]:
        path = os.path.join(tmp, f"{name}.yaml")
        display = "{width: 2000, height: 100, pixels_x: 70000, pixels_y: 3000}" if name == "too-big" else \
            "{width: 200, height: 100, pixels_x: 2000, pixels_y: 1000}"
        open(path, "w").write(f"name: test\n{profile}display: {display}\nmirror_x: true\nmirror_y: false\n"
                              "orientation: landscape\nmax_height: 100\n")
        open(recipe, "w").write(RECIPE.replace("PRINTER", path).replace("FILE", "bad.goo"))
        out = os.path.join(tmp, f"out-{name}")
        run = subprocess.run([voxlat, "-q", "run", recipe, "--out", out], capture_output=True, text=True)
        check(run.returncode != 0, f"{name}: refused")
        for w in words:
            check(w in run.stderr, f"{name}: the message names `{w}`: {run.stderr.strip()}")
        check(not os.path.exists(os.path.join(out, "bad.goo")), f"{name}: no archive left")


def main():
    voxlat = sys.argv[1]
    with tempfile.TemporaryDirectory() as tmp:
        check_archive(voxlat, tmp, "mars4-max", {"res_x": 5760, "res_y": 3600, "mirror_x": 1, "mirror_y": 0,
                                                 "width_mm": 195.84, "height_mm": 122.4, "machine_z": 150.0,
                                                 "printer": "ELEGOO Mars 4 Max", "bottom_layers": 4,
                                                 "delay_mode": 1, "pwm": 255})
        check_refusals(voxlat, tmp)
    if failures:
        print(f"{len(failures)} check(s) failed")
        return 1
    print("goo archives: all checks passed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
