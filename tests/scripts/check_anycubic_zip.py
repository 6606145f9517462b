#!/usr/bin/env python3
"""Checks voxlat's Anycubic zip archives (.pm7, .pm4u, ...) with a decoder written from
docs/formats/anycubic-zip.md alone (no code shared with the writer): the members the layout names,
the JSON settings (machine, resin, layers' table, estimates), scene.slice and
calc_layer_volumes.data field by field, the layer count, and every layer's PW0 code decoding to
exactly width x height pixels equal to the PNG folder the same recipe gives (at PW0's 4 bits); each
layer's area, bounds and pieces in scene.slice against the decoded image (pieces by scipy's own
8-connected labelling), the volume table against the PNG layers' exposure. Also the refusals:
`.pwsz` as a file, as `format:` and as a profile's `format:` (its reason, the profile's line,
nothing written).

usage: check_anycubic_zip.py VOXLAT_BINARY
"""
import io
import json
import os
import struct
import subprocess
import sys
import tempfile
import zipfile

import numpy as np
from scipy import ndimage

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from check_goo import read_png  # noqa: E402  (the PNG reader of the .goo check: no writer code)
# The PW0 layer codec is the binary Photon Workshop files' (anycubic-format.md §9.1): one decoder.
from check_photon_workshop import RECIPE, decode_pw0  # noqa: E402

SOURCE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "data", "printers")

failures = []


def check(condition, message):
    if not condition:
        failures.append(message)
        print("FAIL:", message)


def close(a, b, tol=1e-4):
    return abs(a - b) <= tol * max(1.0, abs(b))


def small_profile(tmp, name, display):
    """A shipped profile with a smaller display of the same pixel pitch (a 13312 x 5120 display
    would make this check slow for no more of the layout)."""
    text = open(os.path.join(SOURCE, name + ".yaml")).read()
    lines = [line for line in text.splitlines() if line.startswith("display:")]
    check(len(lines) == 1, f"{name}: one display line")
    path = os.path.join(tmp, name + "-small.yaml")
    open(path, "w").write(text.replace(lines[0], display))
    return path


def slice_pair(voxlat, tmp, printer, ext):
    name = os.path.basename(printer).replace(".yaml", "")
    recipe = os.path.join(tmp, f"{name}-recipe.yaml")
    open(recipe, "w").write(RECIPE.replace("PRINTER", printer).replace("FILE", f"part.{ext}"))
    path = os.path.join(tmp, f"{name}.{ext}")
    folder = os.path.join(tmp, f"{name}-png")
    for args in (["-o", path], ["--format", "png", "--preview", "off", "-o", folder]):
        run = subprocess.run([voxlat, "-q", "slice", recipe] + args, capture_output=True, text=True)
        check(run.returncode == 0, f"voxlat slice {printer} {args}: {run.stderr}")
        if run.returncode:
            return None, None
    return path, folder


def check_archive(voxlat, tmp, printer, ext, expect):
    path, folder = slice_pair(voxlat, tmp, printer, ext)
    if not path:
        return
    z = zipfile.ZipFile(path)
    check(z.testzip() is None, f"{ext}: every member's CRC")
    names = set(z.namelist())
    # §1: the members.
    for member in ("anycubic_photon_resins.pwsp", "layers_controller.conf", "lcd_function.json", "print_info.json",
                   "software_info.conf", "scene.slice", "calc_layer_volumes.data", "preview_images/preview_0.png",
                   "preview_images/preview_1.png", "preview_images/preview_2.png"):
        check(member in names, f"{ext}: member {member}")
    layers = json.loads(z.read("layers_controller.conf"))
    N = layers["count"]
    check(N == 10 and len(layers["paras"]) == N, f"{ext}: 10 layers of 0.05 mm in 0.5 mm, the table says {N}")
    layer_members = sorted(n for n in names if n.startswith("layer_images/"))
    check(layer_members == sorted(f"layer_images/layer_{i}.pw0Img" for i in range(N)),
          f"{ext}: one layer_images/layer_N.pw0Img per layer, N from 0: {layer_members[:3]}...")
    check(len(names) == 10 + N, f"{ext}: no other members ({len(names)})")
    # §2: the machine.
    pwsp = json.loads(z.read("anycubic_photon_resins.pwsp"))
    m = pwsp["machine_type"]
    W, H = m["res_x"], m["res_y"]
    check(pwsp["version"] == "3" and m["version"] == "3", f"{ext}: versions \"3\"")
    check(m["key_suffix"] == ext and m["key_image_format"] == "pw0Img" and m["name"] == expect["name"],
          f"{ext}: key_suffix, key_image_format, name: {m['key_suffix']} {m['key_image_format']} {m['name']}")
    check((W, H) == (expect["res_x"], expect["res_y"]), f"{ext}: res {W} x {H}")
    check(close(m["print_xsize"], expect["width_mm"]) and close(m["print_ysize"], expect["height_mm"]) and
          close(m["print_zsize"], expect["machine_z"]), f"{ext}: print sizes")
    px, py = m["xy_pixel"] / 1000.0, m["xy_pixel_y"] / 1000.0
    check(close(px, expect["width_mm"] / W) and close(py, expect["height_mm"] / H), f"{ext}: pixel pitch {px} {py}")
    check(m["child_screen"] == [{"x": 0, "y": 0, "width": W, "height": H}], f"{ext}: one child screen")
    check(m["rotate_z"] == 0 and m["raster_antialiasing"] == 16, f"{ext}: rotate_z 0, 16 greys (anti-aliased)")
    ext_data = pwsp["machine_extern"]
    active = ext_data["active_resins"][0]
    resins = [r for r in ext_data["user_resins"] + ext_data["factory_resins"] if r["property"]["name"] == active]
    check(len(resins) == 1, f"{ext}: the active resin `{active}` is there once")
    resin = resins[0]
    sp = resin["slicepara"]
    check(close(sp["zthick"], 0.05) and close(sp["exposure_time"], expect["exposure"]) and
          close(sp["bott_time"], expect["bottom_exposure"]) and sp["bott_layers"] == expect["bottom_layers"] and
          sp["use_indivi_layerpara"] == 0, f"{ext}: slicepara {sp}")
    check(close(sp["zup_height"], 8.0) and close(sp["zup_speed"], 2.0) and close(sp["zdown_speed"], 2.0) and
          close(sp["off_time"], 2.5), f"{ext}: the profile's moves in mm/s: {sp}")
    stages = resin["slice_extpara"]["multi_state_paras"]
    check(set(stages) == {"bott_0", "bott_1", "normal_0", "normal_1"} and close(stages["normal_0"]["height"], 8.0) and
          close(stages["bott_0"]["up_speed"], 2.0), f"{ext}: the two-stage moves")
    # §3: the layers' table.
    for i, p in enumerate(layers["paras"]):
        bottom = i < expect["bottom_layers"]
        check(p["layer_index"] == i and close(p["layer_minheight"], 0.05 * i) and close(p["layer_thickness"], 0.05) and
              close(p["exposure_time"], expect["bottom_exposure"] if bottom else expect["exposure"]),
              f"{ext}: layer {i} in the table: {p}")
    # §5: the estimates, against the PNG layers' exposure.
    info = json.loads(z.read("print_info.json"))
    pixel_mm2 = px * py
    pngs = [read_png(os.path.join(folder, f"{i:05d}.png")) for i in range(N)]
    volume_ml = sum(float(p.astype(np.float64).sum()) / 255.0 for p in pngs) * pixel_mm2 * 0.05 / 1000.0
    check(info["model_layers_count"] == N and close(info["volume"], volume_ml, 1e-6) and info["print_time"] > 0,
          f"{ext}: print_info volume {info['volume']} mL, the PNG layers expose {volume_ml} mL")
    check(len(info["sub_estimated_infos"]) == 1 and close(info["sub_estimated_infos"][0]["estimated_volume"],
                                                          info["volume"]), f"{ext}: the sub-estimate")
    json.loads(z.read("lcd_function.json"))["rerf_function"]
    check("Version" in json.loads(z.read("software_info.conf")), f"{ext}: software_info's Version")
    # §10: previews.
    for k, size in enumerate(((224, 168), (336, 252), (800, 600))):
        png = z.read(f"preview_images/preview_{k}.png")
        check(png[:8] == b"\x89PNG\r\n\x1a\n" and struct.unpack(">II", png[16:24]) == size,
              f"{ext}: preview {k} is a {size} PNG")
    # §7: scene.slice.
    s = z.read("scene.slice")
    check(len(s) == 0x18C + 64 * N + 4, f"{ext}: scene.slice is {len(s)} bytes")
    check(s[:16] == b"ANYCUBIC-PWSZ\0\0\0" and s[16:22] == b"voxlat", f"{ext}: scene magic and software")
    check(struct.unpack_from("<4I", s, 0x50) == (3, 3, 0, 0) and struct.unpack_from("<f", s, 0x60)[0] == 1.0 and
          struct.unpack_from("<I", s, 0x64)[0] == N, f"{ext}: scene header numbers")
    check(s[0x184:0x188] == b"<---" and struct.unpack_from("<I", s, 0x188)[0] == N and s[-4:] == b"--->",
          f"{ext}: scene markers and count")
    box = struct.unpack_from("<6f", s, 0x68)
    check(s[0x80:0x184] == b"\0" * 0x104, f"{ext}: scene padding")
    # The layers: decoded and compared.
    lows, highs, areas = [], [], []
    for i in range(N):
        image = decode_pw0(z.read(f"layer_images/layer_{i}.pw0Img"), W, H)
        if image is None:
            continue
        png = pngs[i]
        check(png.shape == image.shape and np.array_equal((png >> 4) * 17, image),
              f"{ext}: layer {i}: pixels differ from the PNG folder's")
        lit = image > 0
        rows, cols = np.nonzero(lit)
        zc, area, x0, y0, x1, y1, pieces, largest = struct.unpack_from("<6fIf", s, 0x18C + 64 * i)
        check(s[0x18C + 64 * i + 32:0x18C + 64 * i + 64] == b"\0" * 32, f"{ext}: layer {i} record padding")
        check(close(zc, 0.05 * i + 0.025, 1e-6), f"{ext}: layer {i} z {zc} is its middle")
        check(close(area, lit.sum() * pixel_mm2, 1e-5), f"{ext}: layer {i} area {area}, lit {lit.sum() * pixel_mm2}")
        want = ((cols.min() - W / 2) * px, (rows.min() - H / 2) * py, (cols.max() + 1 - W / 2) * px,
                (rows.max() + 1 - H / 2) * py)
        check(all(close(a, b, 1e-5) for a, b in zip((x0, y0, x1, y1), want)),
              f"{ext}: layer {i} bounds {(x0, y0, x1, y1)}, the image's {want}")
        labels, count = ndimage.label(lit, structure=np.ones((3, 3), int))
        sizes = np.bincount(labels.ravel())[1:]
        check(pieces == count and close(largest, sizes.max() * pixel_mm2, 1e-5),
              f"{ext}: layer {i}: {pieces} pieces, largest {largest} mm2; the image has {count}, "
              f"{sizes.max() * pixel_mm2}")
        lows.append(want[:2])
        highs.append(want[2:])
        areas.append(float(image.astype(np.float64).sum()) / 255.0 * pixel_mm2)
    want_box = (min(l[0] for l in lows), min(l[1] for l in lows), 0.0, max(h[0] for h in highs),
                max(h[1] for h in highs), 0.05 * N)
    check(all(close(a, b, 1e-5) for a, b in zip(box, want_box)), f"{ext}: scene box {box}, expected {want_box}")
    # §8: calc_layer_volumes.data: 0.2 mm slabs of 4 layers, the top 2 layers left out.
    v = z.read("calc_layer_volumes.data")
    magic, step, one, R = struct.unpack_from("<IfII", v, 0)
    check(magic == 0x20251024 and close(step, 0.2, 1e-6) and one == 1 and R == 2 and len(v) == 16 + 48 * R,
          f"{ext}: volume table head {magic:#x} {step} {one} {R}, {len(v)} bytes")
    raws = []
    for k in range(R):
        layer, z0, t = struct.unpack_from("<Iff", v, 16 + 48 * k)
        check(v[16 + 48 * k + 12:16 + 48 * k + 44] == b"\0" * 32, f"{ext}: slab {k} padding")
        raws.append(struct.unpack_from("<f", v, 16 + 48 * k + 44)[0])
        check(layer == (0 if k == 0 else 4 * k - 1) and close(z0, 0.2 * k, 1e-6) and close(t, 0.2, 1e-6),
              f"{ext}: slab {k}: layer {layer}, z {z0}, {t} mm")
    check(close(sum(raws) * 0.0011, info["volume"], 1e-5), f"{ext}: slabs add up to {sum(raws) * 0.0011} mL")
    slab = [sum(areas[4 * k:4 * k + 4]) * 0.05 for k in range(R)]
    check(close(raws[0] / raws[1], slab[0] / slab[1], 1e-4), f"{ext}: slabs in proportion to the layers' exposure")
    print(f"{printer}: .{ext}, {N} layers of {W} x {H} decoded, {len(names)} members, {os.path.getsize(path)} bytes")


def refused(voxlat, tmp, name, recipe_text, needles):
    recipe = os.path.join(tmp, f"{name}.yaml")
    open(recipe, "w").write(recipe_text)
    out = os.path.join(tmp, name)
    run = subprocess.run([voxlat, "-q", "run", recipe, "--out", out], capture_output=True, text=True)
    check(run.returncode == 2 and all(n in run.stderr for n in needles),
          f"{name}: refused (exit 2) naming {needles}: exit {run.returncode}, {run.stderr}")
    check(not os.path.exists(out) or not os.listdir(out), f"{name}: nothing written")


def check_refusals(voxlat, tmp):
    m7 = os.path.join(SOURCE, "photon-mono-m7.yaml")
    refused(voxlat, tmp, "pwsz-file", RECIPE.replace("PRINTER", m7).replace("FILE", "part.pwsz"),
            ["pwsz-file.yaml:5", ".pwsz", "pwszImg"])
    refused(voxlat, tmp, "pwsz-format",
            RECIPE.replace("PRINTER", m7).replace("file: FILE", "file: part.pm7, format: pwsz"),
            ["pwsz-format.yaml:5", "pwszImg"])
    profile = os.path.join(tmp, "m7-pro.yaml")
    open(profile, "w").write(open(m7).read().replace("format: pm7", "format: pwsz"))
    refused(voxlat, tmp, "pwsz-profile", RECIPE.replace("PRINTER", profile).replace("FILE", "part.pm7"),
            ["m7-pro.yaml:13", "pwszImg"])


def main():
    voxlat = sys.argv[1]
    with tempfile.TemporaryDirectory() as tmp:
        # The M7's pixels are not square (16.8 x 24.8 um): a 2000 x 1000 window of its pitch.
        m7 = small_profile(tmp, "photon-mono-m7", "display: {width: 33.6, height: 24.8, pixels_x: 2000, pixels_y: 1000}")
        check_archive(voxlat, tmp, m7, "pm7",
                      {"name": "Anycubic Photon Mono M7", "res_x": 2000, "res_y": 1000, "width_mm": 33.6,
                       "height_mm": 24.8, "machine_z": 230.0, "exposure": 2.0, "bottom_exposure": 30.0,
                       "bottom_layers": 6})
        m4u = small_profile(tmp, "photon-mono-4-ultra",
                            "display: {width: 34.0, height: 25.5, pixels_x: 2000, pixels_y: 1500}")
        check_archive(voxlat, tmp, m4u, "pm4u",
                      {"name": "Anycubic Photon Mono 4 Ultra", "res_x": 2000, "res_y": 1500, "width_mm": 34.0,
                       "height_mm": 25.5, "machine_z": 165.0, "exposure": 2.0, "bottom_exposure": 30.0,
                       "bottom_layers": 6})
        check_refusals(voxlat, tmp)
    if failures:
        print(f"{len(failures)} check(s) failed")
        return 1
    print("anycubic zip archives: all checks passed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
