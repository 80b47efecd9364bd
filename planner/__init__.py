"""planner: contact-implicit motion planning with the time-freezing reformulation."""
import os
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the names' types for a user's type checker (the package ships py.typed); at run time they load
    # on first use (__getattr__)
    from .errors import InputError, PlannerError, SolveError
    from .model import Robot, load_robot

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

# each name the package gives, by the module that defines it
_NAMES = {"InputError": "errors", "PlannerError": "errors", "SolveError": "errors", "Robot": "model",
          "load_robot": "model"}
# spelled out, not sorted(_NAMES): pyflakes and type checkers read a literal list (strict mypy re-exports only these)
__all__ = ["InputError", "PlannerError", "Robot", "SolveError", "load_robot"]
__version__ = "0.1.0"


def __getattr__(name: str):
    """The package's names, imported on first use (PEP 562): the `planner` command imports this package before its
    main runs, and a Ctrl-C while NumPy and Pinocchio loaded here printed a traceback (exit by SIGINT) instead of the
    one line and exit 130 that main gives once it runs, where they now load."""
    if name not in _NAMES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from importlib import import_module

    value = globals()[name] = getattr(import_module(f".{_NAMES[name]}", __name__), name)
    return value


def __dir__() -> list[str]:
    """The module's names with the ones not loaded yet (dir(), help() and tab completion listed none of them)."""
    return sorted(set(globals()) | set(_NAMES))
