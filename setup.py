# `pip install .` of voxlat: the Python module (`import voxlat`), the `voxlat` command, and the
# printer profiles, example recipes and report.html's scripts in voxlat/share/voxlat.
#
# No network: `pip install --no-build-isolation .` with Debian's setuptools, wheel, CMake and
# pybind11 (python3-setuptools python3-wheel cmake pybind11-dev). The compiled parts come from a
# CMake build: the one named by VOXLAT_BUILD_DIR when set (used as it is), else `build/` of the
# checkout, the folder `make build` uses: configured as `make build` does when it is not there,
# brought up to date when it is (a Release build), so pip and make share one build and ccache's
# objects (its base_dir makes paths relative to `build/`, so any checkout's `build/` hits the
# same objects). A `build/` of another type is left alone and `build-release/` used instead.
# Setuptools' own files go to VOXLAT_PIP_WORK (default build-pip/).
import glob
import os
import shutil
import subprocess
import sys

from setuptools import setup
from setuptools.command.build_py import build_py
from setuptools.dist import Distribution

HERE = os.path.dirname(os.path.abspath(__file__))
WORK = os.path.abspath(os.environ.get("VOXLAT_PIP_WORK") or os.path.join(HERE, "build-pip"))
THREE = "/usr/share/javascript/three"


def version():
    with open(os.path.join(HERE, "CMakeLists.txt")) as f:
        for line in f:
            if line.startswith("project(voxlat VERSION "):
                return line.split()[2]
    raise RuntimeError("no project version in CMakeLists.txt")


def cached(build, name):
    """A variable of @build's CMakeCache.txt, or None."""
    try:
        with open(os.path.join(build, "CMakeCache.txt")) as f:
            for line in f:
                if line.startswith(name + ":"):
                    return line.split("=", 1)[1].strip()
    except OSError:
        return None
    return None


def cmake_build():
    """The CMake build folder holding voxlat, voxlat-engine and python/voxlat/_voxlat*.so."""
    given = os.environ.get("VOXLAT_BUILD_DIR")
    if given:
        return os.path.abspath(given)
    build = os.path.join(HERE, "build")
    if cached(build, "CMAKE_BUILD_TYPE") not in (None, "Release"):
        build = os.path.join(HERE, "build-release")
    configure = ["cmake", "-S", HERE, "-B", build, "-DCMAKE_BUILD_TYPE=Release"]
    # The module is built for the Python running pip (a venv's python is a link to it): named only
    # when the build's differs, so an existing build is not reconfigured for a link that may go.
    python = os.path.realpath(sys.executable)
    known = cached(build, "Python_EXECUTABLE")
    if not known or os.path.realpath(known) != python:
        configure.append("-DPython_EXECUTABLE=" + python)
    if not os.path.isfile(os.path.join(build, "CMakeCache.txt")):
        if shutil.which("ninja"):
            configure += ["-G", "Ninja"]
        if shutil.which("ccache"):
            configure += ["-DCMAKE_CXX_COMPILER_LAUNCHER=ccache"]
    print("voxlat: compiling in " + build + " (ccache " + ("on" if shutil.which("ccache") else "off") + ")",
          file=sys.stderr)
    subprocess.check_call(configure, stdout=sys.stderr)
    subprocess.check_call(["cmake", "--build", build, "-j", str(os.cpu_count() or 1),
                           "--target", "voxlat", "voxlat_cli", "voxlat_python"], stdout=sys.stderr)
    return build


class BuildWithEngine(build_py):
    """The pure-Python package plus the compiled module, the engine programs and the data."""

    def run(self):
        super().run()
        build = cmake_build()
        package = os.path.join(self.build_lib, "voxlat")
        modules = glob.glob(os.path.join(build, "python", "voxlat", "_voxlat*.so"))
        programs = [os.path.join(build, name) for name in ("voxlat", "voxlat-engine")]
        missing = [p for p in programs if not os.path.isfile(p)] + ([] if modules else ["python/voxlat/_voxlat*.so"])
        if missing:
            raise RuntimeError("the CMake build " + build + " lacks " + ", ".join(missing) + " (build it first)")
        self.copy_file(modules[0], os.path.join(package, os.path.basename(modules[0])))
        # The programs in voxlat/bin and the data in voxlat/share/voxlat: the engine finds its data
        # at <program>/../share/voxlat, as an installed copy does.
        os.makedirs(os.path.join(package, "bin"), exist_ok=True)
        for program in programs:
            target = os.path.join(package, "bin", os.path.basename(program))
            self.copy_file(program, target)
            os.chmod(target, 0o755)
        share = os.path.join(package, "share", "voxlat")
        for folder in ("printers", "recipes", "meshes", "scripts", "page"):
            self.copy_tree(os.path.join(HERE, "data", folder), os.path.join(share, folder))
        for script in (os.path.join(THREE, "three.min.js"), os.path.join(THREE, "examples/js/controls/OrbitControls.js")):
            if os.path.isfile(script):
                self.copy_file(script, os.path.join(share, "page", os.path.basename(script)))


class BinaryDistribution(Distribution):
    """The wheel holds a compiled module: platform-specific."""

    def has_ext_modules(self):
        return True


os.makedirs(WORK, exist_ok=True)
setup(
    name="voxlat",
    version=version(),
    description="Implicit lattices on sparse voxel grids: TPMS and strut lattices, meshes and resin slices",
    packages=["voxlat"],
    package_dir={"voxlat": "python/voxlat"},
    cmdclass={"build_py": BuildWithEngine},
    distclass=BinaryDistribution,
    entry_points={"console_scripts": ["voxlat = voxlat._command:main"]},
    python_requires=">=3.9",
    install_requires=["numpy"],
    zip_safe=False,
    options={
        "build": {"build_base": os.path.join(WORK, "setuptools")},
        "egg_info": {"egg_base": WORK},
    },
)
