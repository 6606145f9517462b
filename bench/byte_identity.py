#!/usr/bin/env python3
"""Output bytes of every shipped recipe at a coarse voxel, to show a refactoring changed nothing.

  bench/byte_identity.py --voxlat build/voxlat record bench/reference/byte_identity.json
  bench/byte_identity.py --voxlat build/voxlat compare bench/reference/byte_identity.json

Each recipe of data/recipes with a `result:` runs with `--set voxel=V` (V = 0.4 mm, coarse enough
to run them all in a minute); its outputs are hashed (SHA-256), and report.json is hashed without
what differs run to run or by design of the report's format: timings, peak memory, threads, the
recipe's path, the voxlat version and the warnings list. The slices recipe's archive is hashed
as written (its timestamp is fixed)."""
import argparse
import hashlib
import json
import pathlib
import subprocess
import sys
import tempfile

ROOT = pathlib.Path(__file__).resolve().parent.parent
VOXEL = "0.4"
# "pieces" and "warnings" are added by the checks of issue 20 (new keys, not changed ones).
VOLATILE = {"timings_s", "peak_memory_mb", "threads", "recipe", "voxlat_version", "warnings", "outputs", "preview",
            "pieces"}


def sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def run_recipe(voxlat: str, recipe: pathlib.Path) -> dict:
    with tempfile.TemporaryDirectory() as out:
        cmd = [voxlat, "-q", "run", str(recipe), "--set", f"voxel={VOXEL}", "--out", out, "--no-preview", "--no-html"]
        done = subprocess.run(cmd, capture_output=True, text=True)
        if done.returncode != 0:
            return {"exit": done.returncode, "stderr": done.stderr.strip().splitlines()[-1:]}
        hashes = {}
        for f in sorted(pathlib.Path(out).rglob("*")):
            if f.is_file() and f.name != "report.json":
                hashes[f.relative_to(out).as_posix()] = sha(f.read_bytes())
        report = json.loads((pathlib.Path(out) / "report.json").read_text())
        for key in VOLATILE:
            report.pop(key, None)
        for entry in report.get("slices", []):
            entry.pop("voxlat_version", None)  # slices.json and the report name the version
            # How many finished layers waited for the writer at most: the threads' timing (3 or 4
            # on the drained bracket), a run's measure like peak_memory_mb.
            entry.pop("max_layers_held", None)
        # The temporary folder and the source tree (printer profiles) differ between checkouts.
        text = json.dumps(report, sort_keys=True).replace(out, "OUT").replace(str(ROOT), "ROOT")
        hashes["report.json (minus run-dependent keys)"] = sha(text.encode())
        return hashes


def collect(voxlat: str) -> dict:
    results = {}
    for recipe in sorted((ROOT / "data" / "recipes").glob("*.yaml")):
        if "result:" not in recipe.read_text():
            continue  # a library of fields for include:
        results[recipe.name] = run_recipe(voxlat, recipe)
    return results


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--voxlat", default=str(ROOT / "build" / "voxlat"))
    ap.add_argument("mode", choices=["record", "compare"])
    ap.add_argument("file")
    args = ap.parse_args()
    now = collect(args.voxlat)
    path = pathlib.Path(args.file)
    if args.mode == "record":
        path.write_text(json.dumps(now, indent=2, sort_keys=True) + "\n")
        print(f"recorded {len(now)} recipes in {path}")
        return 0
    before = json.loads(path.read_text())
    differ = [name for name in sorted(set(before) | set(now)) if before.get(name) != now.get(name)]
    for name in differ:
        print(f"DIFFERS {name}:\n  before {before.get(name)}\n  now    {now.get(name)}")
    print(f"{len(now) - len(differ)} of {len(now)} recipes give the same bytes")
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
