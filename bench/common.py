"""Shared helpers of the benchmark workloads: run a command, measure wall time and peak memory."""
import os
import tempfile
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# Debian's python3 has python3-openvdb / scipy / skimage; a pyenv python on PATH does not.
PYTHON = "/usr/bin/python3" if Path("/usr/bin/python3").exists() else sys.executable


#: The CPU seconds of the last measure()'s command and its children: {"user": .., "system": ..}.
#: The system time shows what fresh memory cost: on a virtual machine that reports its free pages
#: to its host, each page a run touches first is backed again by the host (bench/history.md,
#: forty-fifth round: W2g's trimmed frame 1.2-2.2 s of system time cold, 0.16 s on pages just freed).
LAST_CPU = {"user": 0.0, "system": 0.0}


def cpu_text(cpu=LAST_CPU):
    """CPU times (LAST_CPU, or a copy of it kept past later runs) as a phrase for a report line."""
    return f"user {cpu['user']:.2f} s, system {cpu['system']:.2f} s"


def measure(cmd, env=None, cwd=None):
    """Runs cmd; returns (seconds, peak MB of the process, stdout+stderr). Exits on failure.
    Its CPU times (user, system) are left in LAST_CPU.

    The dirty pages earlier runs left (a side's 1 GB STL) are written out first, so neither side
    of a comparison pays for the other's writeback (W2g's voxlat STL stage took 1.9 s instead of
    1.1 s right after the reference's STL)."""
    os.sync()
    # The peak is taken by GNU time when it is there: a child forked from this Python process
    # inherits its resident size as its own high-water mark (Linux keeps the larger across exec),
    # so after a workload that held gigabytes of numpy arrays every later peak read that instead.
    gnu_time = os.path.exists("/usr/bin/time")
    peak_file = None
    argv = [str(c) for c in cmd]
    if gnu_time:
        fd, peak_file = tempfile.mkstemp(prefix="voxlat-peak-")
        os.close(fd)
        argv = ["/usr/bin/time", "-f", "%M", "-o", peak_file] + argv
    start = time.perf_counter()
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env, cwd=cwd)
    out = proc.stdout.read().decode(errors="replace")
    _, status, usage = os.wait4(proc.pid, 0)
    seconds = time.perf_counter() - start
    LAST_CPU["user"], LAST_CPU["system"] = usage.ru_utime, usage.ru_stime
    peak_mb = usage.ru_maxrss / 1024.0
    if peak_file:
        text = open(peak_file).read().split()
        os.unlink(peak_file)
        if text and text[-1].isdigit():
            peak_mb = int(text[-1]) / 1024.0
    if os.waitstatus_to_exitcode(status) != 0:
        sys.exit(f"failed: {' '.join(map(str, cmd))}\n{out}")
    return seconds, peak_mb, out


def row(name, seconds, mb):
    print(f"  {name:<40} {seconds:8.2f} s {mb:9.0f} MB")


def verdict(ok):
    return "met" if ok else "MISSED"
