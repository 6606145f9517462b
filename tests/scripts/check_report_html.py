#!/usr/bin/env python3
"""report.html in a real browser: headless Chromium loads the page of shipped recipes (address
ending in #check: the page reads its own pixels back and writes what it found into
<pre id="voxlat-check">, dumped with the DOM). Checked: the page is one file that fetches nothing,
the browser logs no console message (errors included), the 3D canvas is not blank, and on a recipe
with islands the layer slider, set to the first island's layer, marks it in the island colour.

usage: check_report_html.py --chromium CHROMIUM VOXLAT SOURCE_DIR"""
import argparse
import json
import os
import re
import subprocess
import sys
import tempfile

# (recipe, overrides making it quick, what the page must show): the graded gyroid (coloured by
# density per slab), sliced too, where the lattice's lowest bridges start as islands.
CASES = [
    ("gyroid-graded.yaml", ["voxel=0.4", "domain.box=[[0,0,0],[12,12,30]]",
                            "outputs.slices={printer: sl1s, layer: 0.1, file: graded.sl1s}"], {"graded", "islands"}),
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
            out = os.path.join(tmp, recipe.replace(".yaml", ""))
            command = [args.voxlat, "run", os.path.join(args.source, "data", "recipes", recipe), "--out", out, "-q"]
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
            found, console, run = load(args.chromium, page, tmp)
            check(found is not None, recipe + ": the page wrote no check result (exit " + str(run.returncode) + "): " +
                  run.stderr[-1500:])
            check(not console, recipe + ": console messages:\n  " + "\n  ".join(console[:10]))
            if found is None:
                continue
            view = found.get("view3d") or {}
            check(view.get("drawn", 0) > 0.02 * view.get("total", 1),
                  recipe + ": the 3D view is blank (" + json.dumps(view) + ")")
            check(found.get("outline_pixels", 0) > 0, recipe + ": the layer view draws no cut of the part")
            if "graded" in shows:
                graded = [name for name, f in report.get("fields", {}).items() if "slabs" in f]
                check(graded and found.get("coloured_by") == graded[0],
                      recipe + ": the 3D view is not coloured by the graded field's slabs (" + json.dumps(found) + ")")
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
