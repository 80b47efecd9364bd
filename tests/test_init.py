"""Importing the package: what it sets up for the process."""
from __future__ import annotations

import os
import subprocess
import sys


def _seen(name: str, value: str | None) -> str:
    """The environment variable `name` as a fresh `import planner` leaves it, given `value` (None: unset) before."""
    env = {k: v for k, v in os.environ.items() if k != name}
    if value is not None:
        env[name] = value
    code = f"import os, planner; print(os.environ.get({name!r}, 'unset'))"
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout.strip()


def test_one_blas_thread_unless_the_caller_chose():
    """`import planner` sets OMP_NUM_THREADS to 1 when it is unset (the documented runs are one-thread runs:
    the thread count changes the rounding and so the homotopy's path) and keeps a value the caller set."""
    assert _seen("OMP_NUM_THREADS", None) == "1"
    assert _seen("OMP_NUM_THREADS", "2") == "2"


def test_the_same_blas_kernels_on_every_avx2_cpu_unless_the_caller_chose():
    """`import planner` sets OPENBLAS_CORETYPE to Haswell on a CPU with AVX2 and FMA (/proc/cpuinfo's flags: the
    ground truth here), so OpenBLAS rounds alike on every such machine (an AVX-512 machine's own kernels changed the
    biped's FESD drop), leaves it unset elsewhere, and keeps a value the caller set."""
    try:
        flags = next(line.split(":", 1)[1].split() for line in open("/proc/cpuinfo") if line.startswith("flags"))
    except (OSError, StopIteration):
        flags = []
    assert _seen("OPENBLAS_CORETYPE", None) == ("Haswell" if {"avx2", "fma"} <= set(flags) else "unset")
    assert _seen("OPENBLAS_CORETYPE", "Zen") == "Zen"
