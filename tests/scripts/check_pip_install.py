#!/usr/bin/env python3
"""`pip install --no-build-isolation .` into a fresh venv (--system-site-packages for numpy),
reusing the CMake build's compiled parts (VOXLAT_BUILD_DIR), then docs/python.md's first example
and the `voxlat` console command run there, from a folder outside the checkout, without
PYTHONPATH: the module and the command are the venv's, and read their printer profiles from it.

With --from-scratch (`make check-pip-scratch`; minutes, so not in `make test`): the checkout's
tracked files are copied to BUILD_DIR/pip-scratch/src, a folder with no build in it, and pip
install runs there with no VOXLAT_BUILD_DIR, as a new user's does: setup.py configures and
compiles src/build itself (with ccache when present: on a machine that built the checkout, its
objects are reused), then the same checks; the copy is deleted at the end.

usage: check_pip_install.py [--from-scratch] BUILD_DIR SOURCE_DIR"""
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time

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


def tracked_copy(source, into):
    """The checkout's tracked files (git ls-files; without git, all but build folders) in @a into."""
    if os.path.exists(into):
        shutil.rmtree(into)
    try:
        files = subprocess.run(["git", "ls-files", "-z"], cwd=source, check=True, capture_output=True).stdout
        names = [n for n in files.decode().split("\0") if n]
    except (OSError, subprocess.CalledProcessError):
        names = None
    if names is None:
        shutil.copytree(source, into, ignore=shutil.ignore_patterns("build*", ".git"))
        return
    for name in names:
        if os.path.isfile(os.path.join(source, name)):
            os.makedirs(os.path.dirname(os.path.join(into, name)), exist_ok=True)
            shutil.copy2(os.path.join(source, name), os.path.join(into, name))


def main():
    scratch = "--from-scratch" in sys.argv
    build, source = (os.path.realpath(p) for p in [a for a in sys.argv[1:] if a != "--from-scratch"][:2])
    if scratch:
        copy = os.path.join(build, "pip-scratch", "src")
        tracked_copy(source, copy)
        source = copy
    failures = []

    def check(ok, what):
        if not ok:
            failures.append(what)

    env = {k: v for k, v in os.environ.items() if not k.startswith("VOXLAT_") and k != "PYTHONPATH"}
    with tempfile.TemporaryDirectory(prefix="voxlat-pip-") as tmp:
        venv = os.path.join(tmp, "venv")
        subprocess.run([sys.executable, "-m", "venv", "--system-site-packages", "--without-pip", venv], check=True)
        python = os.path.join(venv, "bin", "python")
        pip_env = dict(env, VOXLAT_PIP_WORK=os.path.join(tmp, "pip-work"), PIP_NO_INPUT="1",
                       PIP_DISABLE_PIP_VERSION_CHECK="1")
        if not scratch:
            pip_env["VOXLAT_BUILD_DIR"] = build
        started = time.monotonic()
        p = subprocess.run([python, "-m", "pip", "install", "--no-build-isolation", "--no-index", "--no-deps", "-q", source],
                           cwd=tmp, env=pip_env, capture_output=True, text=True)
        if scratch:
            print("pip install from scratch: %.0f s (compiled in %s)" % (time.monotonic() - started,
                                                                      os.path.join(source, "build")))
            check(os.path.isfile(os.path.join(source, "build", "CMakeCache.txt")),
                  "setup.py did not build in the copy's build/")
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
    if scratch and not failures:
        shutil.rmtree(os.path.dirname(source))
    for f in failures:
        print("FAIL:", f)
    print("pip install: " + ("ok" if not failures else str(len(failures)) + " failures"))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
