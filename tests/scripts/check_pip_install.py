#!/usr/bin/env python3
"""`pip install --no-build-isolation .` into a fresh venv (--system-site-packages for numpy),
reusing the CMake build's compiled parts (VOXLAT_BUILD_DIR), then docs/python.md's first example
and the `voxlat` console command run there, from a folder outside the checkout, without
PYTHONPATH: the module and the command are the venv's, and read their printer profiles from it.

usage: check_pip_install.py BUILD_DIR SOURCE_DIR"""
import json
import os
import re
import subprocess
import sys
import tempfile

TINY = """voxel: 0.25
domain: {box: [[0, 0, 0], [8, 8, 1]]}
fields:
  lattice: {tpms: gyroid, cell: 4, solid: sheet, level: 0.4}
result: lattice
outputs: {slices: {printer: sl1s, layer: 0.1, file: tiny.sl1s}}
"""


def first_python_block(markdown):
    match = re.search(r"```python\n(.*?)```", markdown, re.S)
    if not match:
        raise SystemExit("docs/python.md has no ```python block")
    return match.group(1)


def main():
    build, source = (os.path.realpath(p) for p in sys.argv[1:3])
    failures = []

    def check(ok, what):
        if not ok:
            failures.append(what)

    env = {k: v for k, v in os.environ.items() if not k.startswith("VOXLAT_") and k != "PYTHONPATH"}
    with tempfile.TemporaryDirectory(prefix="voxlat-pip-") as tmp:
        venv = os.path.join(tmp, "venv")
        subprocess.run([sys.executable, "-m", "venv", "--system-site-packages", "--without-pip", venv], check=True)
        python = os.path.join(venv, "bin", "python")
        pip_env = dict(env, VOXLAT_BUILD_DIR=build, VOXLAT_PIP_WORK=os.path.join(tmp, "pip-work"), PIP_NO_INPUT="1",
                       PIP_DISABLE_PIP_VERSION_CHECK="1")
        p = subprocess.run([python, "-m", "pip", "install", "--no-build-isolation", "--no-index", "--no-deps", "-q", source],
                           cwd=tmp, env=pip_env, capture_output=True, text=True)
        if p.returncode != 0:
            print(p.stdout[-3000:], p.stderr[-3000:])
            print("FAIL: pip install exited", p.returncode)
            return 1
        work = os.path.join(tmp, "work")
        os.makedirs(work)
        with open(os.path.join(source, "docs", "python.md")) as f:
            example = first_python_block(f.read())
        probe = example + "\nimport json\nprint(json.dumps({'module': voxlat.__file__, 'data': voxlat._core.data_folder()}))\n"
        p = subprocess.run([python, "-c", probe], cwd=work, env=env, capture_output=True, text=True)
        check(p.returncode == 0, "docs/python.md's first example failed in the venv: " + p.stderr[-2000:])
        if p.returncode == 0:
            where = json.loads(p.stdout.strip().splitlines()[-1])
            check(os.path.realpath(where["module"]).startswith(os.path.realpath(venv) + os.sep),
                  "voxlat imported from outside the venv: " + where["module"])
            check(os.path.realpath(where["data"]).startswith(os.path.realpath(venv) + os.sep),
                  "the module reads its data from outside the venv: " + where["data"])
        command = os.path.join(venv, "bin", "voxlat")
        with open(os.path.join(work, "tiny.yaml"), "w") as f:
            f.write(TINY)
        p = subprocess.run([command, "run", "tiny.yaml", "--out", "out", "-q", "--no-html"], cwd=work, env=env,
                           capture_output=True, text=True)
        check(p.returncode == 0, "the venv's voxlat command failed: " + p.stderr[-2000:])
        if p.returncode == 0:
            with open(os.path.join(work, "out", "report.json")) as f:
                profile = os.path.realpath(json.load(f)["slices"][0]["printer_profile"])
            check(profile.startswith(os.path.realpath(venv) + os.sep), "printer_profile is not the venv's: " + profile)
    for f in failures:
        print("FAIL:", f)
    print("pip install: " + ("ok" if not failures else str(len(failures)) + " failures"))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
