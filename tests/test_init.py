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


def test_the_package_names_load_their_libraries_on_first_use():
    """`import planner` loads neither NumPy nor Pinocchio (the `planner` command imports the package before its main
    can turn a Ctrl-C into its one line and exit 130: a Ctrl-C while they loaded was a traceback), and the package's
    names still come from it: `from planner import Robot, load_robot, InputError, PlannerError, SolveError`, and
    dir(planner) lists them before their first use (help(planner) and tab completion showed none of them)."""
    code = ("import sys, planner; listed = {'Robot', 'load_robot', 'InputError'} <= set(dir(planner)); "
            "before = sorted({'numpy', 'pinocchio'} & set(sys.modules)); "
            "from planner import *; import planner.model, planner.errors; "
            "print(before, listed, sorted(planner.__all__) == sorted(planner._NAMES), "
            "load_robot is planner.model.load_robot, InputError is planner.errors.InputError)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "[] True True True True"


# the modules planner imports that come from another distribution than their name says, or only with an extra
PROVIDED_BY = {"pinocchio": "pin", "umsgpack": "meshcat", "zmq": "meshcat"}  # (meshcat's own dependencies)
OPTIONAL = {"dask"}  # the batch extra, imported where used with an error naming the install


def test_every_library_planner_imports_is_a_core_dependency():
    """Every third-party module planner/ imports (at any depth: in functions too) is installed by the package's core
    dependencies, pyproject.toml's [project] dependencies, or is an optional extra's: scipy was in the test extra
    only, so the README's install crashed `planner gait` with ModuleNotFoundError after its solve."""
    import ast
    import re
    import tomllib
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    core = {re.split(r"[<>=!~\[ ;]", d, maxsplit=1)[0].lower()
            for d in tomllib.loads((root / "pyproject.toml").read_text())["project"]["dependencies"]}
    imported = set()
    for path in (root / "planner").glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                imported |= {alias.name.split(".")[0] for alias in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                imported.add(node.module.split(".")[0])
    third_party = imported - set(sys.stdlib_module_names) - {"planner", "__future__"} - OPTIONAL
    missing = sorted(m for m in third_party if PROVIDED_BY.get(m, m).replace("_", "-") not in core)
    assert not missing, f"imported by planner/ but not in pyproject.toml's dependencies: {missing}"
