"""planner: contact-implicit motion planning with the time-freezing reformulation."""
import os

# One BLAS thread unless the caller chose (set before numpy and CasADi's IPOPT load their OpenBLAS): a second core
# does not make an IPOPT iteration faster (docs/benchmarks.md, session 6), and the thread count changes the rounding
# and so the homotopy's path. With the machine's default the biped's hint-free plan walked 9 instead of 10 steps in
# MuJoCo (tests/test_walk.py); the documented iteration counts are all one-thread runs.
os.environ.setdefault("OMP_NUM_THREADS", "1")

from .errors import InputError, PlannerError, SolveError  # noqa: E402
from .model import Robot, load_robot  # noqa: E402

__all__ = ["InputError", "PlannerError", "Robot", "SolveError", "load_robot"]
__version__ = "0.1.0"
