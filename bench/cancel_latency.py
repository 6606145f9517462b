#!/usr/bin/env python3
"""Cancel latency per stage (issue 42 item 8: "cancel in under a second anywhere").

Runs a recipe once to learn its stages (report.json's `timings_s`), then once per stage that
takes at least --min-stage seconds, cancelled 30 % into that stage (--at) by the test hook
VOXLAT_TEST_CANCEL_AT / VOXLAT_TEST_CANCEL_AFTER_MS (Job::timed cancels the job's context exactly
as SIGINT's handler does, that long after the stage begins, and writes the moment to
VOXLAT_TEST_CANCEL_STAMP). The latency is the time from that moment to the process's exit. Each
cancelled run must exit 130 and leave nothing in --out. The machine's load stretches the stages:
the cancel may then land in a later stage.

    /usr/bin/python3 bench/cancel_latency.py --voxlat build/voxlat [--recipe R.yaml]

The built-in recipes: a gyroid network in a 45 mm box at 0.08 mm meshed with `project: on`
(marching cubes, projection, the box cut, the deviation measure and the crossing check: each
several seconds here), Gaussian struts meshed to a tolerance (decimation), and a 200 x 110 mm
strut plate sliced for a Saturn 4 and laid 20 mm tall (the frame, the density solve, the layers).
`--only NAME` picks built-in recipes; `--at 0.1,0.3,0.6,0.9` cancels each stage at several
fractions of its length (default 0.3).
"""
import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

RECIPES = {
    "gyroid-projected": """voxel: 0.08
domain: {box: [[0, 0, 0], [45, 45, 45]]}
fields:
  lattice: {tpms: gyroid, cell: 10, solid: network, density: 0.30}
result: lattice
outputs: {mesh: {file: g.stl, project: on}}
""",
    "struts-tolerance": """voxel: 0.15
domain: {box: [[0, 0, 0], [20, 20, 20]]}
fields:
  lattice: {struts: {cell: bcc, size: 5}, kernel: {gaussian: {sigma: 0.5}}, density: 0.2}
result: lattice
outputs: {mesh: {file: s.stl, tolerance: 0.02}}
""",
    # The plate: Gaussian BCC struts on a 200 x 110 mm plate sliced for a Saturn 4
    # (11 520 x 5 120 pixels; six layers: the slicing, the density solve's coarse pass, the floor).
    "struts-plate": """voxel: 0.1
domain: {box: [[0, 0, 0], [200, 110, 0.3]]}
fields:
  lattice: {struts: {cell: bcc, size: 2}, kernel: {gaussian: {sigma: 0.2}}, density: 0.2}
result: lattice
outputs: {slices: {printer: saturn4, layer: 0.05, file: p.goo}}
""",
    # A 20 mm tall plate of the same cells at a coarse voxel: 4.4e5 struts laid, checked for
    # symmetry and tabled before the first evaluation (the `build fields` stage).
    "struts-plate-frame": """voxel: 0.4
domain: {box: [[0, 0, 0], [200, 110, 20]]}
fields:
  lattice: {struts: {cell: bcc, size: 2}, kernel: {gaussian: {sigma: 0.2}}, density: 0.2}
result: lattice
allow: [pieces]
outputs: {vdb: p.vdb}
""",
}


def run_once(voxlat, recipe, out, env=None):
    start = time.monotonic()
    proc = subprocess.run([voxlat, "-q", "run", str(recipe), "--out", str(out), "--no-html", "--no-preview"],
                          env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    return proc, start, time.monotonic()


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--voxlat", default="build/voxlat")
    ap.add_argument("--recipe", help="a recipe file instead of the built-in ones")
    ap.add_argument("--min-stage", type=float, default=0.5, help="only stages at least this long (s)")
    ap.add_argument("--only", help="built-in recipes whose name contains this")
    ap.add_argument("--at", default="0.3", help="fractions of each stage to cancel at, comma-separated")
    args = ap.parse_args()
    voxlat = os.path.abspath(args.voxlat)
    tmp = Path(tempfile.mkdtemp(prefix="cancel-latency-"))
    worst = 0.0
    failures = []
    try:
        recipes = {Path(args.recipe).stem: Path(args.recipe).read_text()} if args.recipe else RECIPES
        if args.only:
            recipes = {k: v for k, v in recipes.items() if args.only in k}
        fractions = [float(f) for f in args.at.split(",")]
        for name, text in recipes.items():
            recipe = tmp / f"{name}.yaml"
            recipe.write_text(text)
            out = tmp / f"{name}-full"
            proc, start, end = run_once(voxlat, recipe, out)
            if proc.returncode != 0:
                print(f"{name}: full run exited {proc.returncode}: {proc.stderr.strip()[:300]}")
                failures.append(name)
                continue
            timings = json.loads((out / "report.json").read_text())["timings_s"]
            print(f"{name}: full run {end - start:.1f} s")
            print(f"  {'stage':34s} {'at':>4s} {'stage s':>8s} {'stop s':>8s}  exit  left")
            for stage, seconds, fraction in [(st, sec, f) for st, sec in timings.items() for f in fractions]:
                if seconds < args.min_stage:
                    continue
                cut = tmp / f"{name}-cut"
                shutil.rmtree(cut, ignore_errors=True)
                stamp = tmp / "stamp"
                stamp.unlink(missing_ok=True)
                env = dict(os.environ, VOXLAT_TEST_CANCEL_AT=stage, VOXLAT_TEST_CANCEL_STAMP=str(stamp),
                           VOXLAT_TEST_CANCEL_AFTER_MS=str(int(1000 * fraction * seconds)))
                proc, _, end = run_once(voxlat, recipe, cut, env)
                if not stamp.exists():
                    print(f"  {stage:34s} {fraction:4.1f} {seconds:8.2f}     (finished first, exit {proc.returncode})")
                    continue
                latency = end - int(stamp.read_text()) / 1e9
                left = sorted(p.name for p in cut.rglob("*")) if cut.exists() else []
                worst = max(worst, latency)
                ok = proc.returncode == 130 and not left
                if not ok:
                    failures.append(f"{name}/{stage}")
                print(f"  {stage:34s} {fraction:4.1f} {seconds:8.2f} {latency:8.2f}  {proc.returncode:4d}  {len(left)}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"worst stop {worst:.2f} s (target < 1 s: {'met' if worst < 1.0 else 'MISSED'})")
    if failures:
        print("cancelled runs that did not exit 130 with nothing left:", ", ".join(failures))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
