"""Benchmarks, stress tests and probes, each a thin `main(argv=None)` program run as `python -m scripts.NAME`.

`planner` is imported first: it fixes the BLAS threads and kernels (OMP_NUM_THREADS, OPENBLAS_CORETYPE) that change
the homotopy's rounding, but OpenBLAS reads them when numpy or CasADi loads, and most scripts import those before
planner (bench_skips' never-touching case took 1688 IPOPT iterations instead of the documented 1404 on an AVX-512
machine, session 48's tester).
"""
import planner  # noqa: F401
