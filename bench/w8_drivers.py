#!/usr/bin/env python3
"""W8 (b) for several builds of voxlat_homogenize_cell side by side in one run.

The 64^3 gyroid network cell at 20 % of W8 (b) is solved once by the scipy reference
(tests/scripts/homogenization_reference.py, Jacobi-preconditioned CG to 1e-10) and by each driver
given, RUNS times each in interleaved order (driver 1, driver 2, ..., then again), at the default
tolerance of `voxlat properties` (1e-6) and the default threads. It prints each side's CPU time
(user + system; the fair measure on a shared machine, where wall times of the single-threaded
reference stretch more than voxlat's), the medians, the speed-up against the reference and the
largest difference of C from the reference's (relative to its largest entry).

    /usr/bin/python3 bench/w8_drivers.py --runs 7 BEFORE/voxlat_homogenize_cell build/voxlat_homogenize_cell
"""
import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
REFERENCE = ROOT / "tests/scripts/homogenization_reference.py"
PYTHON = "/usr/bin/python3"


def timed(cmd):
    """(CPU seconds of the child, its stdout)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    out = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, check=True).stdout
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), out


def max_rel_diff(a, b):
    scale = max(abs(v) for r in b for v in r)
    return max(abs(x - y) for ra, rb in zip(a, b) for x, y in zip(ra, rb)) / scale


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("drivers", nargs="+")
    ap.add_argument("--runs", type=int, default=7)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="voxlat-w8-") as tmp:
        cell = Path(tmp) / "gyroid64.txt"
        subprocess.run([PYTHON, "-c", f"import sys; sys.path.insert(0, {str(REFERENCE.parent)!r}); "
                        f"import homogenization_reference as r; "
                        f"r.write_cell({str(cell)!r}, r.gyroid_cell(64, 0.2), 1.0 / 64, 1.0, 0.3)"], check=True)
        print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
        ref_cpu, out = timed([PYTHON, REFERENCE, "--cell", cell, "--method", "cg"])
        ref = json.loads(out)["C"]
        print(f"scipy reference: {ref_cpu:.1f} s of CPU")
        cpu = {d: [] for d in args.drivers}
        C = {}
        for _ in range(args.runs):
            for d in args.drivers:
                t, out = timed([d, "--tolerance", "1e-6", cell])
                cpu[d].append(t)
                C[d] = json.loads(out)
        for d in args.drivers:
            median = statistics.median(cpu[d])
            print(f"{d}: CPU {', '.join(f'{t:.3f}' for t in cpu[d])} s; median {median:.3f} s: "
                  f"{ref_cpu / median:.1f}x the reference; iterations {C[d]['iterations']}, "
                  f"C against the reference {max_rel_diff(C[d]['C'], ref):.1e}")
        print(f"load average {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
