#!/usr/bin/env python3
"""`cmake --install` into a temporary prefix, moved elsewhere afterwards, then a slice with a named
printer and a run from the installed copy, from a folder outside the checkout: the installed
command reads its profiles and examples from <prefix>/share/voxlat, never from the source tree or
the build folder (report.json's `printer_profile` says which file was read).

usage: check_install.py BUILD_DIR SOURCE_DIR"""
import json
import os
import shutil
import subprocess
import sys
import tempfile

TINY = """# a small gyroid sheet sliced for a named printer
voxel: 0.25
domain: {box: [[0, 0, 0], [8, 8, 1]]}
fields:
  lattice: {tpms: gyroid, cell: 4, solid: sheet, level: 0.4}
result: lattice
outputs:
  mesh: tiny.stl
  slices: {printer: sl1s, layer: 0.1, file: tiny.sl1s}
"""


def main():
    build, source = (os.path.realpath(p) for p in sys.argv[1:3])
    failures = []

    def check(ok, what):
        if not ok:
            failures.append(what)

    with tempfile.TemporaryDirectory(prefix="voxlat-install-") as tmp:
        staged = os.path.join(tmp, "staged")
        subprocess.run(["cmake", "--install", build, "--prefix", staged], check=True, stdout=subprocess.DEVNULL)
        # The prefix is moved after installing: the command finds its data relative to itself.
        prefix = os.path.join(tmp, "moved", "prefix")
        os.makedirs(os.path.dirname(prefix))
        shutil.move(staged, prefix)
        share = os.path.join(prefix, "share", "voxlat")
        for path in ("bin/voxlat", "bin/voxlat-engine", "share/voxlat/printers/sl1s.yaml", "share/voxlat/printers/saturn4.yaml",
                     "share/voxlat/recipes/gyroid.yaml", "share/voxlat/recipes/cells.yaml", "share/voxlat/meshes/bracket.stl",
                     "share/voxlat/page/report.js", "share/doc/voxlat/README.md", "share/doc/voxlat/python.md"):
            check(os.path.isfile(os.path.join(prefix, path)), "not installed: " + path)
        env = {k: v for k, v in os.environ.items() if not k.startswith("VOXLAT_")}
        work = os.path.join(tmp, "work")
        os.makedirs(work)
        with open(os.path.join(work, "tiny.yaml"), "w") as f:
            f.write(TINY)
        voxlat = os.path.join(prefix, "bin", "voxlat")

        def run(*args):
            p = subprocess.run([voxlat, *args], cwd=work, env=env, capture_output=True, text=True)
            check(p.returncode == 0, "voxlat " + " ".join(args) + " exited " + str(p.returncode) + ": " + p.stderr[-2000:])
            return p

        # A slice with a named printer (its profile from the installed share/voxlat).
        run("slice", "tiny.yaml", "--printer", "saturn4", "-o", "tiny.goo", "-q")
        check(os.path.getsize(os.path.join(work, "tiny.goo")) > 0 if os.path.exists(os.path.join(work, "tiny.goo")) else False,
              "the slice wrote no tiny.goo")
        listed = run("slice", "--help").stdout
        check("saturn4" in listed and "sl1s" in listed, "`voxlat slice --help` lists no installed printer: " + listed[-500:])
        # A run: the report names the installed profile, not the checkout's.
        run("run", "tiny.yaml", "--out", "out", "-q")
        with open(os.path.join(work, "out", "report.json")) as f:
            report = json.load(f)
        profile = os.path.realpath(report["slices"][0]["printer_profile"])
        check(profile.startswith(os.path.realpath(share) + os.sep), "printer_profile is not the installed one: " + profile)
        for place in (source, build):
            check(place not in json.dumps(report), "report.json names " + place)
        check(os.path.isfile(os.path.join(work, "out", "report.html")), "no report.html from the installed copy")
        # An installed example recipe that reads an installed mesh (../meshes/), from the work folder.
        run("check", os.path.join(share, "recipes", "bracket-infill.yaml"))

    for f in failures:
        print("FAIL:", f)
    print("install: " + ("ok" if not failures else str(len(failures)) + " failures"))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
