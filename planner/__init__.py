"""planner: contact-implicit motion planning with the time-freezing reformulation."""
import os

# One BLAS thread unless the caller chose (set before numpy and CasADi's IPOPT load their OpenBLAS): a second core
# does not make an IPOPT iteration faster (docs/benchmarks.md, session 6), and the thread count changes the rounding
# and so the homotopy's path. With the machine's default the biped's hint-free plan walked 9 instead of 10 steps in
# MuJoCo (tests/test_walk.py); the documented iteration counts are all one-thread runs.
os.environ.setdefault("OMP_NUM_THREADS", "1")


def _same_blas_kernels() -> None:
    """OpenBLAS's Haswell kernels on every x86 CPU that has them (AVX2 and FMA), unless the caller chose: OpenBLAS
    (numpy's and CasADi's own) picks its kernels by CPU, and their rounding, like the thread count, changes the
    homotopy's path. On an AVX-512 machine its SkylakeX kernels sent the biped's FESD drop to a step it could not
    solve (tests/test_fesd.py), which the Haswell kernels pass on both machines."""
    if "OPENBLAS_CORETYPE" in os.environ:
        return
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as f:
            flags = next((line.split(":", 1)[1].split() for line in f if line.startswith("flags")), [])
    except OSError:  # not Linux: OpenBLAS's own choice
        return
    if {"avx2", "fma"} <= set(flags):
        os.environ["OPENBLAS_CORETYPE"] = "Haswell"


_same_blas_kernels()

from .errors import InputError, PlannerError, SolveError  # noqa: E402
from .model import Robot, load_robot  # noqa: E402

__all__ = ["InputError", "PlannerError", "Robot", "SolveError", "load_robot"]
__version__ = "0.1.0"
