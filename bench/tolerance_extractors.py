"""Marching cubes against the bcc extractor for a tolerance mesh (issue 16): the 20 mm gyroid of
data/recipes/gyroid-tolerance.yaml (network, 30 %, 0.1 mm voxels) meshed to 0.01 mm with each
extractor, as an STL. Reported per extractor: triangles, minimum-angle distribution (share below
10 and 20 degrees, median), the deviation measured here independently of the mesher (W9's measure:
every triangle sampled at most 0.05 mm apart, distance from the gyroid's own equation and analytic
gradient combined with the domain box; overall and more than two voxels inside the box), the
mesh stages' times from report.json and the whole run's wall time.

Usage: /usr/bin/python3 bench/tolerance_extractors.py [--voxlat build/voxlat] [--tolerance 0.01]
Prints a Markdown table; note the machine's load (printed before and after).
"""
import argparse
import json
import os
import tempfile
from pathlib import Path

import numpy as np

from common import ROOT, measure
from extractor_compare import min_angles
from workload_w9 import deviation, read_stl

RECIPE = ROOT / "data/recipes/gyroid-tolerance.yaml"


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--voxlat", default=str(ROOT / "build/voxlat"))
    parser.add_argument("--tolerance", type=float, default=0.01)
    args = parser.parse_args()
    print(f"load before: {os.getloadavg()[0]:.2f}")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for extractor in ["marching-cubes", "bcc"]:
            out = Path(tmp) / extractor
            spec = f"outputs.mesh={{file: gyroid.stl, tolerance: {args.tolerance}, extractor: {extractor}}}"
            seconds, mb, _ = measure([args.voxlat, "-q", "run", "--no-preview", RECIPE, "--out", out, "--set", spec])
            report = json.loads((out / "report.json").read_text())
            tris = read_stl(out / "gyroid.stl")
            angles = min_angles(tris)
            worst, rms, _, inner = deviation(tris, report)
            timings = report["timings_s"]
            mesh_s = sum(v for k, v in timings.items() if k not in ("build fields", "evaluate", "solve lattice",
                                                                    "count pieces"))
            rows.append((extractor, len(tris), float((angles < 10).mean()), float((angles < 20).mean()),
                         float(np.median(angles)), worst, rms, inner, mesh_s, seconds, mb,
                         report["mesh"].get("decimation", {}).get("triangles_before")))
    print(f"load after: {os.getloadavg()[0]:.2f}")
    print("| extractor | triangles (before decimation) | min angle < 10° | < 20° | median | deviation max / RMS (mm) "
          "| max > 2 voxels inside | mesh stages | run | peak |")
    print("| --- | ---: | ---: | ---: | ---: | --- | ---: | ---: | ---: | ---: |")
    for e, n, a10, a20, med, worst, rms, inner, mesh_s, seconds, mb, before in rows:
        print(f"| {e} | {n:,} ({before:,}) | {100 * a10:.1f} % | {100 * a20:.1f} % | {med:.1f}° | {worst:.4f} / {rms:.5f} "
              f"| {inner:.4f} | {mesh_s:.1f} s | {seconds:.1f} s | {mb:.0f} MB |")


if __name__ == "__main__":
    main()
