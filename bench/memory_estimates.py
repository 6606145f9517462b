#!/usr/bin/env python3
"""Memory estimates against peak RSS (issue 40: "estimate, then refuse").

A job refuses, before the work, what its estimate says cannot fit in 70 % of the memory the
machine has free: the evaluation of a grid (SparseOptions::bytesPerLeaf per evaluated leaf), the
density solve (a coverage solve keeps each band voxel's value and two coverage samples beside the
grid), a frame's struts, a properties cell. An estimate below what the job really takes lets a job
pass the check and then run out of memory, so each must be at least the peak it stands for.

This runs shipped recipes at two or three voxels and compares, per run, the largest estimate report.json
gives (`memory_estimate_mb` of the result and of each solved field) plus the process's own
baseline (a tiny job's peak) against the peak RSS (/usr/bin/time's maximum resident set). It
prints estimate / (peak - baseline) per run; a ratio below 1 is an underestimate (a failure).

    /usr/bin/python3 bench/memory_estimates.py --voxlat build/voxlat
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RUNS = [
    # (recipe, voxels): a TPMS, Gaussian and capsule struts (the capsule solve measures sub-voxel
    # coverage), an infill of a part (a masked solve), a tolerance mesh.
    ("gyroid.yaml", [0.2, 0.14]),
    ("bcc-convolution.yaml", [0.2, 0.14]),
    ("struts-frame.yaml", [0.1, 0.07, 0.05]),
    ("bracket-infill.yaml", [0.1, 0.07]),
    ("gyroid-tolerance.yaml", [0.1, 0.07]),
]
TINY = """voxel: 0.5
domain: {box: [[0, 0, 0], [5, 5, 5]]}
fields:
  s: {tpms: gyroid, cell: 5, solid: network, density: 0.3}
result: s
outputs: {mesh: s.stl}
"""


def run(voxlat, recipe, out, voxel=None):
    cmd = ["/usr/bin/time", "-f", "%M", "-o", str(out) + ".rss", voxlat, "-q", "run", str(recipe), "--out", str(out),
           "--no-html", "--no-preview"]
    if voxel is not None:
        cmd += ["--set", f"voxel={voxel}"]
    proc = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    rss_mb = int(Path(str(out) + ".rss").read_text().split()[-1]) / 1024.0
    report = json.loads((Path(out) / "report.json").read_text()) if (Path(out) / "report.json").exists() else None
    return proc.returncode, rss_mb, report


def estimates(report):
    """The largest estimate the report states, and where."""
    best = (report.get("result", {}).get("memory_estimate_mb", 0.0), "result")
    for name, entry in report.get("fields", {}).items():
        if isinstance(entry, dict) and entry.get("memory_estimate_mb", 0.0) > best[0]:
            best = (entry["memory_estimate_mb"], f"solve {name}")
    return best


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--voxlat", default="build/voxlat")
    ap.add_argument("--only", help="run only recipes whose name contains this")
    args = ap.parse_args()
    voxlat = os.path.abspath(args.voxlat)
    tmp = Path(tempfile.mkdtemp(prefix="memory-estimates-"))
    (tmp / "tiny.yaml").write_text(TINY)
    _, baseline, _ = run(voxlat, tmp / "tiny.yaml", tmp / "tiny")
    print(f"baseline (a tiny job's peak): {baseline:.0f} MB")
    print(f"{'recipe':<24}{'voxel':>7}{'leaves':>9}{'estimate MB':>13}{'peak MB':>9}{'ratio':>7}  largest estimate")
    worst = None
    for recipe, voxels in RUNS:
        if args.only and args.only not in recipe:
            continue
        for voxel in voxels:
            out = tmp / f"{recipe}-{voxel}"
            rc, peak, report = run(voxlat, ROOT / "data" / "recipes" / recipe, out, voxel)
            if rc != 0 or report is None:
                print(f"{recipe:<24}{voxel:>7} exit {rc}")
                continue
            estimate, where = estimates(report)
            ratio = estimate / max(peak - baseline, 1.0)
            worst = ratio if worst is None else min(worst, ratio)
            leaves = report.get("result", {}).get("evaluated_leaves", 0)
            print(f"{recipe:<24}{voxel:>7}{leaves:>9}{estimate:>13.0f}{peak:>9.0f}{ratio:>7.2f}  {where}", flush=True)
    print(f"lowest estimate / (peak - baseline): {worst:.2f} (below 1: an underestimate)")
    return 0 if worst is not None and worst >= 1.0 else 1


if __name__ == "__main__":
    sys.exit(main())
