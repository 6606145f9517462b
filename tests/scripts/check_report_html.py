#!/usr/bin/env python3
"""report.html in a real browser: headless Chromium loads the page of shipped recipes (address
ending in #check: the page reads its own pixels back and writes what it found into
<pre id="voxlat-check">, dumped with the DOM). Checked: the page is one file that fetches nothing,
the browser logs no console message (errors included), the 3D canvas is not blank, on a recipe
with islands the layer slider, set to the first island's layer, marks it in the island colour, and a
graded recipe's part is coloured (a colour per slab, and a legend). A sheet with graded walls
carries the walls measured at each vertex in the page's mesh (read here without the browser: its
colouring is the same per-vertex path), which match the recipe's thickness ramp at both ends.

usage: check_report_html.py --chromium CHROMIUM VOXLAT SOURCE_DIR"""
import argparse
import base64
import json
import os
import re
import subprocess
import sys
import tempfile

import numpy as np

# (recipe, overrides making it quick, what the page must show): the graded gyroid (coloured by
# density per slab), sliced too, where the lattice's lowest bridges start as islands; and a sheet
# whose walls thicken from 0.4 mm at x = 0 to 1.0 mm at x = 20 (docs/recipes.md's `ramped`),
# coloured by the walls measured at each vertex.
WALLS = """voxel: 0.2
domain: {box: [[0, 0, 0], [20, 10, 10]]}
fields:
  ramped: {tpms: gyroid, cell: 10, solid: sheet, thickness: {ramp: {axis: x, from: 0.4, to: 1.0}}}
result: ramped
outputs: {mesh: ramped.stl}
"""
# A thin plate sliced alone (no mesh output): the page's mesh is meshed on a coarse grid that a
# plate 1 mm tall barely holds, so the layer view shows the slices' own layers, kept small.
PLATE = """domain: {box: [[0, 0, 0], [20, 14, 1]]}
fields:
  plate: {tpms: gyroid, cell: 4, solid: sheet, level: 0.4}
result: plate
outputs: {slices: {printer: sl1s, layer: 0.05, file: plate.sl1s}}
"""
CASES = [
    ("gyroid-graded.yaml", ["voxel=0.4", "domain.box=[[0,0,0],[12,12,30]]",
                            "outputs.slices={printer: sl1s, layer: 0.1, file: graded.sl1s}"], {"graded", "islands"}),
    (WALLS, [], {"walls"}),
    (PLATE, [], {"plate"}),
]


def load(chromium, page, tmp):
    """(the page's check result, the console lines) of @a page opened in headless Chromium."""
    env = dict(os.environ, HOME=tmp)
    command = [chromium, "--headless=new", "--no-sandbox", "--user-data-dir=" + os.path.join(tmp, "profile"),
               "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--enable-logging=stderr", "--v=0",
               "--no-first-run", "--disable-extensions", "--dump-dom", "file://" + page + "#check"]
    p = subprocess.run(command, env=env, capture_output=True, text=True, timeout=120)
    console = [line for line in p.stderr.splitlines() if ":CONSOLE" in line]
    # The element the page appends last (the scripts' text, dumped too, may name it earlier).
    found = re.findall(r'<pre id="voxlat-check">(\{.*?\})</pre>', p.stdout, re.S)
    return (json.loads(found[-1]) if found else None), console, p


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--chromium", required=True)
    parser.add_argument("voxlat")
    parser.add_argument("source")
    args = parser.parse_args()
    failures = []

    def check(ok, what):
        if not ok:
            failures.append(what)

    with tempfile.TemporaryDirectory(prefix="voxlat-html-") as tmp:
        for recipe, sets, shows in CASES:
            if recipe.endswith(".yaml"):
                path = os.path.join(args.source, "data", "recipes", recipe)
            else:
                name = "walls.yaml" if "walls" in shows else "plate.yaml"
                path = os.path.join(tmp, name)
                with open(path, "w") as f:
                    f.write(recipe)
                recipe = name
            out = os.path.join(tmp, recipe.replace(".yaml", ""))
            command = [args.voxlat, "run", path, "--out", out, "-q"]
            for s in sets:
                command += ["--set", s]
            p = subprocess.run(command, capture_output=True, text=True)
            if p.returncode != 0:
                failures.append(recipe + ": voxlat run exited " + str(p.returncode) + ": " + p.stderr[-2000:])
                continue
            page = os.path.join(out, "report.html")
            with open(page, encoding="utf-8") as f:
                html = f.read()
            with open(os.path.join(out, "report.json")) as f:
                report = json.load(f)
            # One file: no element loads anything (scripts and styles are inline).
            fetches = re.findall(r"<(?:script|link|img|iframe)\b[^>]*\b(?:src|href)\s*=", html, re.I)
            check(not fetches, recipe + ": the page fetches " + str(fetches[:3]))
            if shows == {"walls"}:
                # The walls measured at each vertex, read from the page's data (the browser's part,
                # colours and legend from per-vertex values, is the graded case's above).
                mesh = json.loads(re.search(r'<script type="application/json" id="voxlat-mesh">(.*?)</script>', html,
                                            re.S).group(1).replace("<\\/", "</"))
                colour = mesh.get("colour") or {}
                check(colour.get("by") == "wall thickness" and colour.get("field") == "ramped",
                      recipe + ": the page's mesh is not coloured by the walls of `ramped` (" + str(colour.keys()) + ")")
                if not colour:
                    continue
                xs = np.frombuffer(base64.b64decode(mesh["points"]), np.float32).reshape(-1, 3)[:, 0]
                walls = np.frombuffer(base64.b64decode(colour["values"]), np.float32)
                check(walls.size == xs.size, recipe + ": one wall per vertex")
                order = np.argsort(xs, kind="stable")
                tenth = max(1, xs.size // 10)
                # The walls at the thin and the thick end against the ramp there (0.4 to 0.46 mm over
                # the first tenth, 0.94 to 1.0 over the last; chords read a little long).
                low, high = float(np.median(walls[order[:tenth]])), float(np.median(walls[order[-tenth:]]))
                print("walls measured: %.3f mm at the thin end, %.3f at the thick end (%d vertices)" % (low, high, xs.size))
                check(0.38 <= low <= 0.52 and 0.88 <= high <= 1.12,
                      recipe + ": walls measured " + str(low) + " mm at the thin end (ramp 0.4-0.46), " + str(high) +
                      " mm at the thick end (0.94-1.0)")
                continue
            found, console, run = load(args.chromium, page, tmp)
            check(found is not None, recipe + ": the page wrote no check result (exit " + str(run.returncode) + "): " +
                  run.stderr[-1500:])
            check(not console, recipe + ": console messages:\n  " + "\n  ".join(console[:10]))
            if found is None:
                continue
            view = found.get("view3d") or {}
            check(view.get("drawn", 0) > 0.02 * view.get("total", 1),
                  recipe + ": the 3D view is blank (" + json.dumps(view) + ")")
            if "islands" in shows:
                check(found.get("outline_pixels", 0) > 0, recipe + ": the layer view draws no cut of the part")
            if "plate" in shows:
                # Every layer kept (20 of them), the first one drawn from the slices: its exposed
                # pixels cover part of the canvas. The kept layers' exposed area, read from the
                # page's data (cells x cell area), against the slices' own mean layer area.
                entry = report["slices"][0]
                # A slice-only job has no result volume: the heading gives the slices' exposed one.
                shown = re.search(r"exposed volume ([0-9.e+-]+) mm³", run.stdout)
                check(shown is not None and
                      abs(float(shown.group(1)) - entry["exposed_volume_mm3"]) <= 1e-3 * entry["exposed_volume_mm3"],
                      recipe + ": the heading does not give the slices' exposed volume " +
                      str(entry["exposed_volume_mm3"]) + " (" + (shown.group(0) if shown else "none") + ")")
                check(found.get("layers_kept") == entry["layers"] and found.get("first_layer_image") and
                      found.get("first_layer_dark", 0) > 5000,
                      recipe + ": the layer view does not show the first layer's slice (" + json.dumps(found) + ")")
                kept = json.loads(re.search(r'<script type="application/json" id="voxlat-layers">(.*?)</script>', html,
                                            re.S).group(1).replace("<\\/", "</"))
                cell = kept["cell_mm"][0] * kept["cell_mm"][1]
                areas = [np.frombuffer(base64.b64decode(im), np.uint8).astype(float).sum() / 255 * cell
                         for im in kept["images"]]
                mean = float(np.mean(areas)) if areas else 0.0
                print("layer view: %d layers kept, mean exposed area %.3f mm2 against the slices' %.3f mm2" %
                      (len(areas), mean, entry["mean_layer_area_mm2"]))
                check(abs(mean - entry["mean_layer_area_mm2"]) <= 0.01 * entry["mean_layer_area_mm2"],
                      recipe + ": the kept layers hold %.3f mm2 on average, the slices %.3f" % (mean, entry["mean_layer_area_mm2"]))
                # Placed where the part is: the cells span the part's box in x and y (within a cell
                # and a pixel).
                box = entry["part_box"]
                for a in range(2):
                    lo = kept["origin_mm"][a]
                    hi = lo + kept["size"][a] * kept["cell_mm"][a]
                    check(abs(lo - box["min"][a]) <= kept["cell_mm"][a] and -0.1 <= hi - box["max"][a] <= 2 * kept["cell_mm"][a],
                          recipe + ": the kept layers span %.3f..%.3f mm along axis %d, the part %.3f..%.3f" %
                          (lo, hi, a, box["min"][a], box["max"][a]))
            if "graded" in shows:
                # One colour per slab, and the legend.
                legend = found.get("legend") or {}
                slabs = [len(f["slabs"]["slabs"]) for f in report.get("fields", {}).values() if "slabs" in f]
                colours = slabs[0] if slabs else 2
                check(found.get("legend_shown") and legend.get("colours", 0) >= colours and
                      legend.get("hi", 0) > legend.get("lo", 0),
                      recipe + ": no legend, or fewer than " + str(colours) + " vertex colours (" + json.dumps(legend) + ")")
            if "islands" in shows:
                islands = report["slices"][0]["printability"]["islands"]
                check(len(islands) > 0, recipe + ": the recipe has no island (choose another for this check)")
                if islands:
                    check(found.get("island_layer") == islands[0]["layer"],
                          recipe + ": the slider went to layer " + str(found.get("island_layer")) + ", not the island's " +
                          str(islands[0]["layer"]))
                    check(found.get("island_marks", 0) >= 1 and found.get("island_pixels", 0) > 20,
                          recipe + ": the island is not marked on its layer (" + json.dumps(found) + ")")
        # report.html is checked like every output: a folder in its place refuses the run before
        # anything is written; --no-html neither writes nor checks it.
        tiny = os.path.join(tmp, "tiny.yaml")
        with open(tiny, "w") as f:
            f.write("voxel: 0.5\ndomain: {box: [[0, 0, 0], [4, 4, 4]]}\nfields:\n  ball: {sphere: {radius: 1.5, center: [2, 2, 2]}}\n"
                    "result: ball\noutputs: {mesh: ball.stl}\n")
        out = os.path.join(tmp, "blocked")
        os.makedirs(os.path.join(out, "report.html"))
        p = subprocess.run([args.voxlat, "run", tiny, "--out", out, "-q"], capture_output=True, text=True)
        check(p.returncode == 2 and "report.html" in p.stderr, "a folder named report.html was not refused (exit " +
              str(p.returncode) + "): " + p.stderr[-500:])
        check(sorted(os.listdir(out)) == ["report.html"], "a refused run wrote " + str(os.listdir(out)))
        p = subprocess.run([args.voxlat, "run", tiny, "--out", out, "-q", "--no-html"], capture_output=True, text=True)
        check(p.returncode == 0 and os.path.isfile(os.path.join(out, "report.json")) and
              os.path.isdir(os.path.join(out, "report.html")), "--no-html did not run past the folder: " + p.stderr[-500:])
    for f in failures:
        print("FAIL:", f)
    print("report.html: " + ("ok" if not failures else str(len(failures)) + " failures"))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
