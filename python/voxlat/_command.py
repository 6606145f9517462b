"""The `voxlat` console command of a pip-installed package: runs the bundled program
(voxlat/bin/voxlat, the same command line as a CMake build's) with the same arguments."""
import os
import sys


def main():
    program = os.path.join(os.path.dirname(os.path.abspath(__file__)), "bin", "voxlat")
    if not os.path.isfile(program):
        sys.exit("voxlat: the command is not part of this copy of the package (%s missing; "
                 "install with `pip install .` from the source tree)" % program)
    os.execv(program, [program] + sys.argv[1:])
