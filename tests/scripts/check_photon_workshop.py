#!/usr/bin/env python3
"""Checks voxlat's Anycubic Photon Workshop files (.pwmx, .pwmb, .pm4n, ...) with a decoder written
from shared/reference/anycubic-format.md alone (no code shared with the writer): the file mark and
every named table at its address (HEADER, PREVIEW, colour table, LAYERDEF, EXTRA, MACHINE and, for
file version 517, SOFTWARE and MODEL), each table's length rule, the layers back to back to the end
of the file, every layer's PW0 code decoding to exactly width x height pixels, its non-zero pixel
count equal to LAYERDEF's, and its pixels equal to the PNG folder the same recipe gives (at the
format's 4 bits). (The format has no checksum: its integrity is the exact pixel count and the
stored count of every layer.) Also: a profile whose format is unknown is refused with its file.

usage: check_photon_workshop.py VOXLAT_BINARY
"""
import os
import struct
import subprocess
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from check_goo import read_png  # noqa: E402  (the PNG reader of the .goo check: no writer code)

RECIPE = """domain: {box: [[0, 0, 0], [24, 18, 1]]}
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


def u32(b, off):
    return struct.unpack_from("<I", b, off)[0]


def f32(b, off):
    return struct.unpack_from("<f", b, off)[0]


def name_at(b, off, n=12):
    return b[off:off + n].split(b"\0")[0].decode()


def decode_pw0(data, width, height):
    """§9.1: colour c in the high nibble; c 0 or 15: a big-endian 12-bit run, else a 4-bit run."""
    values, lengths = [], []
    k = 0
    while k < len(data):
        c = data[k] >> 4
        if c in (0, 15):
            run = ((data[k] & 0x0F) << 8) | data[k + 1]
            k += 2
        else:
            run = data[k] & 0x0F
            k += 1
        check(run > 0, "runs are never empty")
        values.append(c * 17)
        lengths.append(run)
    total = sum(lengths)
    check(total == width * height, f"a layer decodes to {total} pixels, not {width} x {height}")
    if total != width * height:
        return None
    return np.repeat(np.array(values, np.uint8), lengths).reshape(height, width)


def check_archive(voxlat, tmp, printer, ext, version, expect):
    recipe = os.path.join(tmp, f"{printer}.yaml")
    open(recipe, "w").write(RECIPE.replace("PRINTER", printer).replace("FILE", f"part.{ext}"))
    path = os.path.join(tmp, f"{printer}.{ext}")
    folder = os.path.join(tmp, f"{printer}-png")
    for args in (["-o", path], ["--format", "png", "--preview", "off", "-o", folder]):
        run = subprocess.run([voxlat, "-q", "slice", recipe] + args, capture_output=True, text=True)
        check(run.returncode == 0, f"voxlat slice {printer} {args}: {run.stderr}")
        if run.returncode:
            return
    b = open(path, "rb").read()
    # File mark (§3).
    check(b[:12] == b"ANYCUBIC\0\0\0\0", f"{printer}: mark")
    check(u32(b, 12) == version, f"{printer}: version {u32(b, 12)}, expected {version}")
    tables = {515: 5, 516: 8, 517: 9}[version]
    check(u32(b, 16) == tables, f"{printer}: {tables} tables")
    mark_size = {515: 48, 516: 52, 517: 56}[version]
    a_header, a_software, a_preview, a_colour, a_layerdef, a_extra = struct.unpack_from("<6I", b, 0x14)
    if version == 515:
        a_machine, a_layers = 0, u32(b, 0x2C)
    else:
        a_machine, a_layers = u32(b, 0x2C), u32(b, 0x30)
    a_model = u32(b, 0x34) if version >= 517 else 0
    check(a_header == mark_size, f"{printer}: HEADER right after the file mark")
    # HEADER (§4).
    body = {515: 80, 516: 84, 517: 92}[version]
    check(name_at(b, a_header) == "HEADER" and u32(b, a_header + 12) == body, f"{printer}: HEADER name and length")
    o = a_header
    h = {"pixel_um": f32(b, o + 0x10), "layer_mm": f32(b, o + 0x14), "exposure": f32(b, o + 0x18),
         "bottom_exposure": f32(b, o + 0x20), "bottom_layers": f32(b, o + 0x24), "lift_mm": f32(b, o + 0x28),
         "lift_speed": f32(b, o + 0x2C), "aa": u32(b, o + 0x38), "res_x": u32(b, o + 0x3C),
         "res_y": u32(b, o + 0x40), "per_layer": u32(b, o + 0x50)}
    for key, value in expect.items():
        if key in h:
            check(abs(h[key] - value) < 1e-3, f"{printer}: header {key} = {h[key]}, expected {value}")
    check(h["aa"] == 1 and h["per_layer"] == 0, f"{printer}: AA 1 and per-layer values off")
    W, H = h["res_x"], h["res_y"]
    # PREVIEW (§5): length counts the whole table.
    check(a_preview == a_header + 16 + body, f"{printer}: PREVIEW follows HEADER")
    pw, ph = u32(b, a_preview + 16), u32(b, a_preview + 24)
    check(name_at(b, a_preview) == "PREVIEW" and (pw, ph) == (224, 168), f"{printer}: PREVIEW is 224 x 168")
    check(u32(b, a_preview + 12) == 28 + pw * ph * 2 and b[a_preview + 20:a_preview + 24] == b"x\0\0\0",
          f"{printer}: PREVIEW length and its `x`")
    # Colour table (§6).
    check(a_colour == a_preview + 28 + pw * ph * 2, f"{printer}: colour table after the preview")
    check(u32(b, a_colour + 4) == 16 and b[a_colour + 8:a_colour + 24] == b"\xff" * 16, f"{printer}: colour table")
    # LAYERDEF (§7): length counts the body.
    check(a_layerdef == a_colour + 28 and name_at(b, a_layerdef) == "LAYERDEF", f"{printer}: LAYERDEF")
    N = u32(b, a_layerdef + 16)
    check(u32(b, a_layerdef + 12) == 4 + 32 * N, f"{printer}: LAYERDEF length")
    check(N == 20, f"{printer}: 20 layers of 0.05 mm in 1 mm, LAYERDEF says {N}")
    next_table = a_layerdef + 20 + 32 * N
    if version >= 516:
        check(a_extra == next_table and name_at(b, a_extra) == "EXTRA" and u32(b, a_extra + 12) == 24,
              f"{printer}: EXTRA (length 24)")
        check(u32(b, a_extra + 16) == 2 and u32(b, a_extra + 44) == 2, f"{printer}: EXTRA's two stage counts")
        check(a_machine == a_extra + 72 and name_at(b, a_machine) == "MACHINE" and u32(b, a_machine + 12) == 156,
              f"{printer}: MACHINE")
        check(name_at(b, a_machine + 16, 96) == expect["name"], f"{printer}: machine name")
        check(name_at(b, a_machine + 112, 16) == "pw0Img", f"{printer}: layer image format pw0Img")
        check(abs(f32(b, a_machine + 0x88) - expect["width_mm"]) < 1e-3 and
              abs(f32(b, a_machine + 0x8C) - expect["height_mm"]) < 1e-3 and
              abs(f32(b, a_machine + 0x90) - expect["machine_z"]) < 1e-3, f"{printer}: MACHINE display and Z")
        check(u32(b, a_machine + 0x94) == version, f"{printer}: MACHINE max file version")
        next_table = a_machine + 156
    if version >= 517:
        check(a_software == next_table and name_at(b, a_software, 32) == "voxlat" and
              u32(b, a_software + 32) == 164, f"{printer}: SOFTWARE")
        check(a_model == a_software + 164 and name_at(b, a_model) == "MODEL" and u32(b, a_model + 12) == 48,
              f"{printer}: MODEL")
        next_table = a_model + 48
    else:
        check(a_software == 0, f"{printer}: no SOFTWARE before 517")
    check(a_layers == next_table, f"{printer}: layers right after the tables ({a_layers} vs {next_table})")
    # The layers, back to back in order, each decoded and compared.
    expected_address = a_layers
    for i in range(N):
        r = a_layerdef + 20 + 32 * i
        address, length, lift, lift_speed, exposure, thickness, exposed, _ = struct.unpack_from("<IIffffII", b, r)
        check(address == expected_address, f"{printer}: layer {i} at {address}, expected {expected_address}")
        expected_address = address + length
        check(abs(thickness - 0.05) < 1e-6, f"{printer}: layer {i} thickness {thickness}")
        bottom = i < int(h["bottom_layers"])
        check(abs(exposure - (h["bottom_exposure"] if bottom else h["exposure"])) < 1e-5,
              f"{printer}: layer {i} exposure")
        image = decode_pw0(b[address:address + length], W, H)
        if image is None:
            continue
        check(int(np.count_nonzero(image)) == exposed, f"{printer}: layer {i}: LAYERDEF counts {exposed} pixels")
        png = read_png(os.path.join(folder, f"{i:05d}.png"))
        # The format keeps 4 bits: grey g is stored as g >> 4 and read as (g >> 4) * 17.
        check(png.shape == image.shape and np.array_equal((png >> 4) * 17, image),
              f"{printer}: layer {i}: pixels differ from the PNG folder's")
    check(expected_address == len(b), f"{printer}: the file ends with the last layer")
    print(f"{printer}: .{ext} version {version}, {N} layers of {W} x {H} decoded, {len(b)} bytes")


def check_refusals(voxlat, tmp):
    path = os.path.join(tmp, "bad-format.yaml")
    open(path, "w").write("name: test\nformat: pwmz\ndisplay: {width: 200, height: 100, pixels_x: 2000, "
                          "pixels_y: 1000}\nmirror_x: true\nmirror_y: false\norientation: landscape\nmax_height: 100\n")
    recipe = os.path.join(tmp, "bad.yaml")
    open(recipe, "w").write(RECIPE.replace("PRINTER", path).replace("FILE", "bad.pwmx"))
    run = subprocess.run([voxlat, "-q", "run", recipe, "--out", os.path.join(tmp, "bad")], capture_output=True,
                         text=True)
    check(run.returncode == 2 and "bad-format.yaml:2" in run.stderr and "pwmz" in run.stderr,
          f"an unknown profile format is refused at its line: {run.stderr}")
    check(not os.path.exists(os.path.join(tmp, "bad", "bad.pwmx")), "nothing written")


def main():
    voxlat = sys.argv[1]
    with tempfile.TemporaryDirectory() as tmp:
        check_archive(voxlat, tmp, "photon-mono-x", "pwmx", 516,
                      {"res_x": 3840, "res_y": 2400, "pixel_um": 50.0, "layer_mm": 0.05, "exposure": 2.0,
                       "bottom_exposure": 40.0, "bottom_layers": 6.0, "lift_mm": 8.0, "lift_speed": 2.0,
                       "name": "Anycubic Photon Mono X", "width_mm": 192.0, "height_mm": 120.0,
                       "machine_z": 245.0})
        check_archive(voxlat, tmp, "photon-mono-4", "pm4n", 517,
                      {"res_x": 9024, "res_y": 5120, "name": "Anycubic Photon Mono 4", "width_mm": 153.408,
                       "height_mm": 87.04, "machine_z": 165.0})
        check_refusals(voxlat, tmp)
    if failures:
        print(f"{len(failures)} check(s) failed")
        return 1
    print("photon workshop files: all checks passed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
