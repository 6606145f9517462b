#!/usr/bin/env python3
"""voxlat benchmarks: each workload runs side by side with its reference pipeline in one run.

Workloads are the modules bench/workload_*.py; each has TITLE and run(voxlat, tmp) -> dict.
Wall time and peak memory (max RSS from wait4) are measured for both sides back to back on the
same machine; each workload prints its ratios and whether its targets hold.
"""
import argparse
import importlib
import json
import os
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))


def workloads():
    return sorted(p.stem[len("workload_"):] for p in HERE.glob("workload_*.py"))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--voxlat", default=str(HERE.parent / "build/voxlat"))
    ap.add_argument("--only", nargs="*", default=workloads(), help="workload names, e.g. w1 w2")
    ap.add_argument("--json", help="also write the results here")
    a = ap.parse_args()
    results = {}
    with tempfile.TemporaryDirectory(prefix="voxlat-bench-") as d:
        for name in a.only:
            module = importlib.import_module("workload_" + name)
            print(module.TITLE)
            tmp = Path(d) / name
            tmp.mkdir()
            results[name] = module.run(os.path.abspath(a.voxlat), tmp)
            print()
    if a.json:
        Path(a.json).write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
