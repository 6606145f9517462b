#!/usr/bin/env python3
"""Checks voxlat's Anycubic Photon Workshop files (.pwmx, .pm4n, .m5sp, .pws, ...) with a decoder written
from shared/reference/anycubic-format.md alone (no code shared with the writer): the file mark and
every named table at its address (HEADER, PREVIEW, colour table, LAYERDEF, EXTRA, MACHINE and, for
file version 517, SOFTWARE and MODEL, for 518 SUBIMGS and PREVIEW2; version 1 without the colour
table), each table's length rule, the layers back to back to the end of the file, every layer's PW0
code (or .pws bit planes) decoding to exactly width x height pixels, its non-zero pixel count equal
to LAYERDEF's, and its pixels equal to the PNG folder the same recipe gives (at the format's 4 bits;
.pws: the nearest of its bit planes' grey levels). (The format has no checksum: its integrity is the
exact pixel count and the stored count of every layer.) Also: a profile whose format is unknown is
refused with its file.

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

RECIPE = """domain: {box: [[0, 0, 0], [24, 18, 0.5]]}
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


def decode_planes(data, width, height, planes):
    """§9.2: AA bit planes of one-byte runs (bit 7 on, 7-bit count); grey n·(256/AA) − 1 or 0."""
    data = np.frombuffer(data, np.uint8)
    counts = (data & 0x7F).astype(np.int64)
    check(bool(np.all(counts > 0)) and bool(np.all(counts <= 125)), "bit-plane runs of 1 to 125 pixels")
    ends = np.cumsum(counts)
    check(ends.size > 0 and ends[-1] == planes * width * height,
          f"a layer's planes cover {ends[-1] if ends.size else 0} pixels, not {planes} x {width} x {height}")
    if ends.size == 0 or ends[-1] != planes * width * height:
        return None
    bits = np.repeat((data >> 7).astype(np.int32), counts).reshape(planes, height, width)
    check(bool(np.isin(np.arange(1, planes + 1) * width * height, ends).all()),
          "every plane ends with a run (no run crosses into the next plane)")
    n = bits.sum(axis=0)
    return np.where(n == 0, 0, n * (256 // planes) - 1).astype(np.uint8)


def nearest_levels(png, planes):
    """Whether each decoded grey is (one of) the nearest of the planes' levels to the PNG's grey."""
    levels = np.array([0] + [n * (256 // planes) - 1 for n in range(1, planes + 1)], np.int32)
    return np.abs(png.astype(np.int32)[..., None] - levels).min(axis=-1)


PNG_FOLDERS = {}


def slice_pair(voxlat, tmp, printer, ext, display):
    """The archive, and the PNG folder of the same recipe (one per display: printers that share
    one share it)."""
    name = os.path.basename(printer).replace(".yaml", "")
    recipe = os.path.join(tmp, f"{name}-recipe.yaml")
    open(recipe, "w").write(RECIPE.replace("PRINTER", printer).replace("FILE", f"part.{ext}"))
    path = os.path.join(tmp, f"{name}.{ext}")
    runs = [["-o", path]]
    if display not in PNG_FOLDERS:
        PNG_FOLDERS[display] = os.path.join(tmp, f"{name}-png")
        runs.append(["--format", "png", "--preview", "off", "-o", PNG_FOLDERS[display]])
    for args in runs:
        run = subprocess.run([voxlat, "-q", "slice", recipe] + args, capture_output=True, text=True)
        check(run.returncode == 0, f"voxlat slice {printer} {args}: {run.stderr}")
        if run.returncode:
            return None, None
    return path, PNG_FOLDERS[display]


def check_archive(voxlat, tmp, printer, ext, version, expect):
    # Printers of one display (pixels, millimetres and mirror alike) share one PNG folder.
    path, folder = slice_pair(voxlat, tmp, printer, ext, (expect["res_x"], expect["res_y"], expect.get("width_mm")))
    if not path:
        return
    b = open(path, "rb").read()
    # File mark (§3).
    check(b[:12] == b"ANYCUBIC\0\0\0\0", f"{printer}: mark")
    check(u32(b, 12) == version, f"{printer}: version {u32(b, 12)}, expected {version}")
    tables = {1: 4, 515: 5, 516: 8, 517: 9, 518: 11}[version]
    check(u32(b, 16) == tables, f"{printer}: {tables} tables")
    mark_size = {1: 48, 515: 48, 516: 52, 517: 56, 518: 64}[version]
    a_header, a_software, a_preview, a_colour, a_layerdef, a_extra = struct.unpack_from("<6I", b, 0x14)
    if version <= 515:
        a_machine, a_layers = 0, u32(b, 0x2C)
    else:
        a_machine, a_layers = u32(b, 0x2C), u32(b, 0x30)
    a_model = u32(b, 0x34) if version >= 517 else 0
    a_subimgs, a_preview2 = struct.unpack_from("<2I", b, 0x38) if version >= 518 else (0, 0)
    check(a_header == mark_size, f"{printer}: HEADER right after the file mark")
    # HEADER (§4).
    body = {1: 80, 515: 80, 516: 84, 517: 92, 518: 96}[version]
    check(name_at(b, a_header) == "HEADER" and u32(b, a_header + 12) == body, f"{printer}: HEADER name and length")
    o = a_header
    h = {"pixel_um": f32(b, o + 0x10), "layer_mm": f32(b, o + 0x14), "exposure": f32(b, o + 0x18),
         "bottom_exposure": f32(b, o + 0x20), "bottom_layers": f32(b, o + 0x24), "lift_mm": f32(b, o + 0x28),
         "lift_speed": f32(b, o + 0x2C), "aa": u32(b, o + 0x38), "res_x": u32(b, o + 0x3C),
         "res_y": u32(b, o + 0x40), "per_layer": u32(b, o + 0x50)}
    for key, value in expect.items():
        if key in h:
            check(abs(h[key] - value) < 1e-3, f"{printer}: header {key} = {h[key]}, expected {value}")
    planes = expect.get("planes", 1)
    check(h["aa"] == planes and h["per_layer"] == 0, f"{printer}: AA {h['aa']} ({planes}), per-layer values off")
    W, H = h["res_x"], h["res_y"]
    # PREVIEW (§5): length counts the whole table.
    check(a_preview == a_header + 16 + body, f"{printer}: PREVIEW follows HEADER")
    pw, ph = u32(b, a_preview + 16), u32(b, a_preview + 24)
    check(name_at(b, a_preview) == "PREVIEW" and (pw, ph) == (224, 168), f"{printer}: PREVIEW is 224 x 168")
    check(u32(b, a_preview + 12) == 28 + pw * ph * 2 and b[a_preview + 20:a_preview + 24] == b"x\0\0\0",
          f"{printer}: PREVIEW length and its `x`")
    if version >= 515:
        # Colour table (§6).
        check(a_colour == a_preview + 28 + pw * ph * 2, f"{printer}: colour table after the preview")
        check(u32(b, a_colour + 4) == 16 and b[a_colour + 8:a_colour + 24] == b"\xff" * 16,
              f"{printer}: colour table")
        table_before = a_colour + 28
    else:
        check(a_colour == 0 and a_extra == 0, f"{printer}: version 1 has no colour table, no EXTRA")
        table_before = a_preview + 28 + pw * ph * 2
    # LAYERDEF (§7): length counts the body.
    check(a_layerdef == table_before and name_at(b, a_layerdef) == "LAYERDEF", f"{printer}: LAYERDEF")
    N = u32(b, a_layerdef + 16)
    check(u32(b, a_layerdef + 12) == 4 + 32 * N, f"{printer}: LAYERDEF length")
    check(N == 10, f"{printer}: 10 layers of 0.05 mm in 0.5 mm, LAYERDEF says {N}")
    next_table = a_layerdef + 20 + 32 * N
    if version >= 516:
        check(a_extra == next_table and name_at(b, a_extra) == "EXTRA" and u32(b, a_extra + 12) == 24,
              f"{printer}: EXTRA (length 24)")
        check(u32(b, a_extra + 16) == 2 and u32(b, a_extra + 44) == 2, f"{printer}: EXTRA's two stage counts")
        machine_size = 224 if version >= 518 else 156
        check(a_machine == a_extra + 72 and name_at(b, a_machine) == "MACHINE" and
              u32(b, a_machine + 12) == machine_size, f"{printer}: MACHINE")
        check(name_at(b, a_machine + 16, 96) == expect["name"], f"{printer}: machine name")
        check(name_at(b, a_machine + 112, 16) == "pw0Img", f"{printer}: layer image format pw0Img")
        check(abs(f32(b, a_machine + 0x88) - expect["width_mm"]) < 1e-3 and
              abs(f32(b, a_machine + 0x8C) - expect["height_mm"]) < 1e-3 and
              abs(f32(b, a_machine + 0x90) - expect["machine_z"]) < 1e-3, f"{printer}: MACHINE display and Z")
        check(u32(b, a_machine + 0x94) == version, f"{printer}: MACHINE max file version")
        if version >= 518:
            check(struct.unpack_from("<I", b, a_machine + 0xC4)[0] == 1 and
                  struct.unpack_from("<HH", b, a_machine + 0xCC) == (W, H) and
                  abs(f32(b, a_machine + 0x9C) - 1000 * expect["width_mm"] / W) < 1e-2,
                  f"{printer}: MACHINE's 518 fields (one display, its pixels and pitch)")
        next_table = a_machine + machine_size
    if version >= 517:
        check(a_software == next_table and name_at(b, a_software, 32) == "voxlat" and
              u32(b, a_software + 32) == 164, f"{printer}: SOFTWARE")
        check(a_model == a_software + 164 and name_at(b, a_model) == "MODEL" and u32(b, a_model + 12) == 48,
              f"{printer}: MODEL")
        next_table = a_model + 48
        if version >= 518:
            check(a_subimgs == next_table and name_at(b, a_subimgs) == "SUBIMGS" and
                  u32(b, a_subimgs + 12) == 24 + 44 * N and u32(b, a_subimgs + 16) == N,
                  f"{printer}: SUBIMGS")
            for i in range(N):
                check(b[a_subimgs + 24 + 44 * i:a_subimgs + 36 + 44 * i] ==
                      b[a_layerdef + 20 + 32 * i:a_layerdef + 28 + 32 * i] + b[a_layerdef + 44 + 32 * i:
                                                                               a_layerdef + 48 + 32 * i],
                      f"{printer}: SUBIMGS {i} copies LAYERDEF's address, length and count")
            a2 = a_subimgs + 24 + 44 * N
            p2w, p2h = u32(b, a_preview2 + 16), u32(b, a_preview2 + 24)
            check(a_preview2 == a2 and name_at(b, a_preview2) == "PREVIEW2" and
                  u32(b, a_preview2 + 12) == 28 + 2 * p2w * p2h and (p2w, p2h) in ((320, 190), (330, 190)),
                  f"{printer}: PREVIEW2 ({p2w} x {p2h})")
            next_table = a_preview2 + 28 + 2 * p2w * p2h
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
        if ext == "pws":
            image = decode_planes(b[address:address + length], W, H, planes)
        else:
            image = decode_pw0(b[address:address + length], W, H)
        if image is None:
            continue
        check(int(np.count_nonzero(image)) == exposed, f"{printer}: layer {i}: LAYERDEF counts {exposed} pixels")
        png = read_png(os.path.join(folder, f"{i:05d}.png"))
        if ext == "pws":
            # Each pixel at the level nearest its grey (ties either way).
            best = nearest_levels(png, planes)
            check(png.shape == image.shape and
                  np.array_equal(np.abs(png.astype(np.int32) - image.astype(np.int32)), best),
                  f"{printer}: layer {i}: pixels are not the nearest levels to the PNG folder's")
        else:
            # The format keeps 4 bits: grey g is stored as g >> 4 and read as (g >> 4) * 17.
            check(png.shape == image.shape and np.array_equal((png >> 4) * 17, image),
                  f"{printer}: layer {i}: pixels differ from the PNG folder's")
    check(expected_address == len(b), f"{printer}: the file ends with the last layer")
    print(f"{printer}: .{ext} version {version}, {N} layers of {W} x {H} decoded ({planes} plane(s)), {len(b)} bytes")


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
        # Version 518 on the M5s Pro's profile with the Photon S's display (its own 13312 x 5120
        # pixels would make this the costliest check here for no more of the layout).
        source = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "data", "printers")
        small = open(os.path.join(source, "photon-mono-m5s-pro.yaml")).read().replace(
            "display: {width: 223.642, height: 126.976, pixels_x: 13312, pixels_y: 5120}",
            "display: {width: 68.04, height: 120.96, pixels_x: 1440, pixels_y: 2560}")
        check("pixels_x: 1440" in small, "the M5s Pro profile's display line")
        m5sp = os.path.join(tmp, "m5sp-small.yaml")
        open(m5sp, "w").write(small)
        check_archive(voxlat, tmp, m5sp, "m5sp", 518,
                      {"res_x": 1440, "res_y": 2560, "name": "Anycubic Photon Mono M5s Pro", "width_mm": 68.04,
                       "height_mm": 120.96, "machine_z": 200.0})
        # .pws: version 1, anti-aliasing on (the recipe's default) in 4 bit planes.
        check_archive(voxlat, tmp, "photon-s", "pws", 1,
                      {"res_x": 1440, "res_y": 2560, "width_mm": 68.04, "exposure": 8.0, "bottom_exposure": 60.0,
                       "planes": 4})
        # Version 1 with PW0 layers (.pw0, .pwx): the Photon S profile as a .pw0 printer.
        pw0 = os.path.join(tmp, "pw0-small.yaml")
        open(pw0, "w").write(open(os.path.join(source, "photon-s.yaml")).read().replace("format: pws", "format: pw0"))
        check_archive(voxlat, tmp, pw0, "pw0", 1, {"res_x": 1440, "res_y": 2560, "width_mm": 68.04})
        check_refusals(voxlat, tmp)
    if failures:
        print(f"{len(failures)} check(s) failed")
        return 1
    print("photon workshop files: all checks passed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
