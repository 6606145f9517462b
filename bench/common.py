"""Shared helpers of the benchmark workloads: run a command, measure wall time and peak memory."""
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# Debian's python3 has python3-openvdb / scipy / skimage; a pyenv python on PATH does not.
PYTHON = "/usr/bin/python3" if Path("/usr/bin/python3").exists() else sys.executable


def measure(cmd, env=None, cwd=None):
    """Runs cmd; returns (seconds, peak MB of the process, stdout+stderr). Exits on failure.

    The dirty pages earlier runs left (a side's 1 GB STL) are written out first, so neither side
    of a comparison pays for the other's writeback (W2g's voxlat STL stage took 1.9 s instead of
    1.1 s right after the reference's STL)."""
    os.sync()
    start = time.perf_counter()
    proc = subprocess.Popen([str(c) for c in cmd], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env, cwd=cwd)
    out = proc.stdout.read().decode(errors="replace")
    _, status, usage = os.wait4(proc.pid, 0)
    seconds = time.perf_counter() - start
    if os.waitstatus_to_exitcode(status) != 0:
        sys.exit(f"failed: {' '.join(map(str, cmd))}\n{out}")
    return seconds, usage.ru_maxrss / 1024.0, out


def row(name, seconds, mb):
    print(f"  {name:<40} {seconds:8.2f} s {mb:9.0f} MB")


def verdict(ok):
    return "met" if ok else "MISSED"
