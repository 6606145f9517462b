"""Marching cubes against the bcc extractor (marching tetrahedra on the body-centred-cubic lattice,
`outputs: {mesh: {extractor: bcc}}`) on the acceptance gyroid and on an octet strut lattice.

For every recipe and extractor, two runs of `voxlat run` (each its own process, one after the
other): the raw mesh, then the mesh with `project: on`. Reported per run: triangles, the minimum
angle of every triangle (share below 10 and 20 degrees, median, computed here from the STL), the
mesh stage's time and the whole run's wall time (report.json, the process), and for the projected
run the deviation report.json measures (|f| / |grad f| of the result clipped to the domain, on every
triangle). For the raw meshes the vertex deviation is measured here: `voxlat sample --gradient` at
a fixed random subset of vertices (first corners of triangles) more than two voxels inside the domain box, |f| / |grad f|.

Usage: /usr/bin/python3 bench/extractor_compare.py [--voxlat build/voxlat] [--threads N]
Prints a Markdown table; note the machine's load (printed before and after).
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from common import ROOT, measure

RECIPES = [
    ("gyroid (data/recipes/gyroid.yaml)", ROOT / "data/recipes/gyroid.yaml"),
    ("octet struts (data/recipes/struts-frame.yaml)", ROOT / "data/recipes/struts-frame.yaml"),
]
EXTRACTORS = ["marching-cubes", "bcc"]
SAMPLES = 100_000


def read_stl(path):
    data = np.fromfile(path, dtype=np.uint8)
    count = int(data[80:84].view(np.uint32)[0])
    records = data[84:84 + 50 * count].reshape(count, 50)
    return records[:, 12:48].copy().view(np.float32).reshape(count, 3, 3).astype(np.float64)


def min_angles(tris):
    """Smallest interior angle of every triangle, degrees."""
    a = tris[:, 1] - tris[:, 0]
    b = tris[:, 2] - tris[:, 1]
    c = tris[:, 0] - tris[:, 2]

    def angle(u, v):
        cos = np.einsum("ij,ij->i", u, v) / (np.linalg.norm(u, axis=1) * np.linalg.norm(v, axis=1))
        return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))

    return np.minimum(np.minimum(angle(a, -c), angle(b, -a)), angle(c, -b))


def raw_vertex_deviation(voxlat, recipe, tris, report, threads):
    """Max and RMS |f| / |grad f| of the result at a fixed random subset of the mesh's vertices (the
    first corner of each triangle, so vertices of many triangles are likelier picks)
    more than two voxels inside the domain box (the box's faces are the clip, not the field)."""
    points = tris[:, 0]  # one corner per triangle: every vertex is some triangle's first corner
    lo = np.array(report["domain"]["min"]) + 2 * report["domain"]["voxel"]
    hi = np.array(report["domain"]["max"]) - 2 * report["domain"]["voxel"]
    points = points[np.all((points > lo) & (points < hi), axis=1)]
    rng = np.random.default_rng(1)
    if len(points) > SAMPLES:
        points = points[rng.choice(len(points), SAMPLES, replace=False)]
    text = "\n".join(f"{p[0]:.9g} {p[1]:.9g} {p[2]:.9g}" for p in points) + "\n"
    cmd = [voxlat, "-q", "sample", str(recipe), "--gradient"]
    if threads:
        cmd[1:1] = ["--threads", str(threads)]
    out = subprocess.run([str(c) for c in cmd], input=text, capture_output=True, text=True, check=True).stdout
    values = np.array([[float(x) for x in line.split()] for line in out.splitlines() if line.strip()])
    d = np.abs(values[:, 0]) / np.linalg.norm(values[:, 1:4], axis=1)
    return float(d.max()), float(np.sqrt(np.mean(d * d))), len(points)


def run(voxlat, recipe, extractor, project, work, threads):
    spec = yaml.safe_load(recipe.read_text())
    entry = {"file": "mesh.stl", "extractor": extractor}
    if project:
        entry["project"] = "on"
    spec["outputs"] = {"mesh": entry}
    path = work / "recipe.yaml"
    path.write_text(yaml.safe_dump(spec))
    out = work / "out"
    cmd = [voxlat, "-q", "run", path, "--out", out, "--no-preview"]
    if threads:
        cmd[1:1] = ["--threads", str(threads)]
    seconds, mb, _ = measure(cmd)
    report = json.loads((out / "report.json").read_text())
    return seconds, mb, report, read_stl(out / "mesh.stl"), path


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--voxlat", default=str(ROOT / "build/voxlat"))
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--only", default="", help="run only the recipes whose name contains this")
    args = ap.parse_args()
    print(f"load average before: {os.getloadavg()}", flush=True)
    rows = []
    for name, recipe in RECIPES:
        if args.only not in name:
            continue
        for extractor in EXTRACTORS:
            for project in (False, True):
                with tempfile.TemporaryDirectory() as tmp:
                    seconds, mb, report, tris, path = run(args.voxlat, recipe, extractor, project, Path(tmp),
                                                          args.threads)
                    angles = min_angles(tris)
                    mesh = report["mesh"]
                    if project:
                        dev = mesh["deviation"]
                        deviation = f"{dev['max_mm']:.4f} / {dev['rms_mm']:.5f} (triangles)"
                    else:
                        mx, rms, n = raw_vertex_deviation(args.voxlat, path, tris, report, args.threads)
                        deviation = f"{mx:.4f} / {rms:.5f} ({n} vertices)"
                    timings = report["timings_s"]
                    mesh_s = timings.get("mesh", float("nan"))
                    project_s = timings.get("project vertices", 0.0)
                    rows.append((name, extractor + (", project" if project else ""), len(tris),
                                 100.0 * np.mean(angles < 10.0), 100.0 * np.mean(angles < 20.0),
                                 float(np.median(angles)), float(angles.min()), deviation, mesh_s, project_s,
                                 seconds, mb, mesh.get("closed_manifold", "(raw)")))
                    print(rows[-1], flush=True)
    print(f"load average after: {os.getloadavg()}")
    print()
    print("| recipe | extractor | triangles | min angle < 10° | < 20° | median | smallest | deviation max / RMS mm |"
          " mesh s | project s | run s | peak MB | closed |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: | --- | ---: | ---: | ---: | ---: | --- |")
    for r in rows:
        print(f"| {r[0]} | {r[1]} | {r[2]:,} | {r[3]:.1f} % | {r[4]:.1f} % | {r[5]:.1f}° | {r[6]:.2f}° | {r[7]} |"
              f" {r[8]:.2f} | {r[9]:.2f} | {r[10]:.2f} | {r[11]:.0f} | {r[12]} |")


if __name__ == "__main__":
    main()
