"""Importing the package: what it sets up for the process."""
from __future__ import annotations

import os
import subprocess
import sys


def _threads_seen(value: str | None) -> str:
    env = {k: v for k, v in os.environ.items() if k != "OMP_NUM_THREADS"}
    if value is not None:
        env["OMP_NUM_THREADS"] = value
    code = "import os, planner; print(os.environ['OMP_NUM_THREADS'])"
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout.strip()


def test_one_blas_thread_unless_the_caller_chose():
    """`import planner` sets OMP_NUM_THREADS to 1 when it is unset (the documented runs are one-thread runs:
    the thread count changes the rounding and so the homotopy's path) and keeps a value the caller set."""
    assert _threads_seen(None) == "1"
    assert _threads_seen("2") == "2"
