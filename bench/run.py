#!/usr/bin/env python3
"""voxlat benchmarks: each workload side by side with a reference pipeline in one run.

Wall time and peak memory (max RSS of the process tree's leader, from wait4) are measured for
both, on the same machine, back to back; the table prints the ratio and whether each target holds.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def measure(cmd, env=None):
    """Runs cmd; returns (seconds, peak MB, stdout+stderr)."""
    start = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env)
    out = proc.stdout.read().decode(errors="replace")
    _, status, usage = os.wait4(proc.pid, 0)
    seconds = time.perf_counter() - start
    if os.waitstatus_to_exitcode(status) != 0:
        sys.exit(f"failed: {' '.join(map(str, cmd))}\n{out}")
    return seconds, usage.ru_maxrss / 1024.0, out


def row(name, seconds, mb):
    print(f"  {name:<34} {seconds:8.2f} s {mb:9.0f} MB")


def w1(voxlat, tmp):
    print("W1  gyroid network 30 %, 50 mm cube, 0.1 mm voxels, recipe -> STL")
    t_v, m_v, out_v = measure([voxlat, "-q", "run", str(ROOT / "data/recipes/gyroid.yaml"), "--out", str(tmp / "w1")])
    report = json.loads((tmp / "w1" / "report.json").read_text())
    t_r, m_r, out_r = measure([sys.executable, str(ROOT / "bench/w1_openvdb_dense.py"), "--out", str(tmp / "w1-ref.stl")])
    row("voxlat", t_v, m_v)
    row("OpenVDB python, dense grid", t_r, m_r)
    ratio = t_r / t_v
    print(f"  speed-up {ratio:.1f}x (target >= 5x: {'met' if ratio >= 5 else 'MISSED'}); "
          f"voxlat peak {m_v:.0f} MB (target <= 1024 MB: {'met' if m_v <= 1024 else 'MISSED'})")
    print(f"  voxlat: density {report['fields']['lattice']['achieved_density']:.5f}, "
          f"{report['mesh']['triangles']} triangles; reference: {out_r.strip().splitlines()[-1]}")
    print(f"  voxlat stages: " + ", ".join(f"{k} {v:.2f}s" for k, v in report["timings_s"].items()))
    return {"workload": "W1", "voxlat_s": t_v, "reference_s": t_r, "ratio": ratio, "voxlat_mb": m_v, "reference_mb": m_r}


WORKLOADS = {"W1": w1}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--voxlat", default=str(ROOT / "build/voxlat"))
    ap.add_argument("--only", nargs="*", default=list(WORKLOADS))
    ap.add_argument("--json", help="also write the results here")
    a = ap.parse_args()
    results = []
    with tempfile.TemporaryDirectory(prefix="voxlat-bench-") as d:
        for name in a.only:
            results.append(WORKLOADS[name](os.path.abspath(a.voxlat), Path(d)))
    if a.json:
        Path(a.json).write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
