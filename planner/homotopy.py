"""Solve the time-freezing OCP: an l_inf (or l1) penalty homotopy of smooth NLPs (paper Sec. 5.2).

`solve(problem, options)` creates IPOPT once for the Problem's NLP (rho and the hole scale are NLP
parameters) and solves the task's homotopy rho_i = rho0 kappa^i, i = 0 .. n_nlp-1 (by default
without the values below SolveOptions.rho_min = 100 and continued up to rho_max = 1e6: weak
penalties are exploited by cheats, and the last bit of complementarity needs rho >> 1e4), each NLP
warm-started from the previous one (primal x and multipliers lam_x, lam_g). NLP 1 has a soft
terminal penalty instead of the hard terminal constraint (soft_terminal_nlps). With gating, the
selectors that the gates switch off are reset afterwards (ungate). Then, optionally:

* Polish.ACTIVE_SET: one more smooth NLP in which every complementarity pair has its smaller side
  fixed to zero by bounds (for a selector: sigma = 0 with lambda1 = 0, sigma = 1 with lambda0 = 0,
  or, for 0 < sigma < 1, lambda0 = lambda1 = 0) and the penalty dropped (rho = 0, s_c = 0). If that
  NLP converges, its point satisfies every complementarity condition exactly and every other
  constraint to IPOPT's tolerance; it is accepted only then, or (the projection polish) when IPOPT
  stopped short of its tolerances at an iterate the verdict's checks accept (NlpRecord.kept_iteration),
  and only if it keeps the terminal and hole constraints; otherwise the homotopy's point stands.
* HoleSchedule.RELAXED_FIRST: the first NLP drops the holes (hole scale 0) and the later ones
  enforce them: a continuation in the scene the solver runs itself; the user gives no hint.

The result's convergence verdict is about the plan it returns: the NLP that produced it converged
(IPOPT success: the polish, or the last homotopy NLP when the polish was not accepted; or the
projection polish's kept iterate),
complementarity residual <= options.comp_tol, terminal error <= options.terminal_tol, holes and
path constraints kept to options.constraint_tol. An earlier homotopy NLP that stopped at its
iteration cap is only a stepping stone; the message names it (SolveStats.message) and its record
says so (PlanResult.nlps).
"""
from __future__ import annotations

import contextlib
import difflib
import functools
import json
import math
import os
import threading
import time
import warnings
from dataclasses import dataclass, fields, replace
from enum import Enum
from typing import Callable

import casadi as ca
import numpy as np

from .derivatives import nlp_derivatives
from .errors import (C_INT_MAX, InputError, captured_stdout, check_field_types, enum_field, expect, interruptible,
                     interrupted, options_record, plain, real_array, representable)
from .model import robot_weight
from .problem import PARAMETERS, Penalty, Problem, plane_gap, static_controls
from .result import (COLLAPSED, FROZEN_TOL, ON_PLANE_M, TAP_SHARE, ArraysReadOnly, NlpRecord, PlanResult, SolveStats,
                     Trajectory, hops_of, slides_of, unrecorded_landings)
from .simulate import braked_outside_cone, element_trajectory, joints_outside_range, step_elements
from .task import MAX_NLPS, contact_labels, task_source

_M_TRIM_THRESHOLD, _M_MMAP_MAX = -1, -4  # glibc mallopt parameters (malloc.h)


@functools.cache  # find_library runs ldconfig (~3 ms), twice per solve()
def _libc():
    """glibc's C library through ctypes, or None (not glibc: macOS, musl without mallopt)."""
    import ctypes
    import ctypes.util
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or None)
        return libc if hasattr(libc, "mallopt") and hasattr(libc, "malloc_trim") else None
    except OSError:
        return None


def keep_freed_memory() -> bool:
    """Ask glibc's malloc to serve large blocks from the heap and keep freed memory (mallopt
    M_MMAP_MAX = 0, M_TRIM_THRESHOLD = 2 GiB, a C int's largest); True if it could. MUMPS allocates
    its factor storage at every factorization (two or more per IPOPT iteration); by default each of
    those blocks is a fresh mmap whose pages the kernel zeroes again: 16 of 95 s were system time on
    the default Capler task, 0.4 s with this (docs/benchmarks.md, "Speed of the pipeline").
    Process-wide until undone: solve() keeps it for its own run only (freed_memory_kept); a no-op off glibc."""
    libc = _libc()
    return libc is not None and bool(libc.mallopt(_M_MMAP_MAX, 0)) and bool(libc.mallopt(_M_TRIM_THRESHOLD, 2**31 - 1))


_KEEPING = threading.Lock()
os.register_at_fork(after_in_child=lambda: globals().update(_KEEPING=threading.Lock(), _kept=0))  # (a fork while
# another thread held the lock: the child's solve waited for it forever)
_kept, _kept_ok = 0, False  # freed_memory_kept blocks running (nested: FESD's implicit Euler start; threads), and
# whether the first could keep


@contextlib.contextmanager
def freed_memory_kept():
    """keep_freed_memory() while the block runs; after the last running block, glibc's default thresholds
    (M_MMAP_MAX 65536, M_TRIM_THRESHOLD 128 KiB) and the heap's free memory given back (malloc_trim): a program that
    solved through the API kept every later free() in its heap (a 512 MB array deleted after one solve stayed
    resident). The mmap threshold then stays at glibc's 128 KiB default instead of adapting (any mallopt stops that),
    and a MALLOC_*_ or GLIBC_TUNABLES setting of the program's is replaced by those defaults. Memory the program
    allocates inside the block and frees after it sits in the heap until the next trim. Yields whether
    keep_freed_memory could (glibc)."""
    global _kept, _kept_ok
    _libc()  # (outside the lock: its first call runs ldconfig, whose pipe a fork while it ran gave the child too)
    with _KEEPING:
        _kept += 1
        if _kept == 1:
            _kept_ok = keep_freed_memory()
        ok = _kept_ok
    try:
        yield ok
    finally:
        with _KEEPING:
            _kept -= 1
            libc = _libc() if _kept == 0 else None
            if libc is not None:
                libc.mallopt(_M_MMAP_MAX, 65536)
                libc.mallopt(_M_TRIM_THRESHOLD, 128 * 1024)
                libc.malloc_trim(0)


class MuStrategy(Enum):
    """IPOPT's barrier-parameter update (its mu_strategy option; SolveOptions.mu_strategy)."""

    ADAPTIVE = "adaptive"  # IPOPT's adaptive rule sets mu at every iteration (default)
    MONOTONE = "monotone"  # mu decreases from mu_init (warm_mu_init for the later NLPs), which only this one reads


class HoleSchedule(Enum):
    """When the holes (and other scene obstacles) are enforced during the homotopy."""

    ENFORCED = "enforced"  # from the first NLP on (faithful)
    RELAXED_FIRST = "relaxed_first"  # not in NLP 1, fully from NLP 2 on


class WarmStart(Enum):
    """What a homotopy NLP takes from the one before (docs/formulation.md, round 5)."""

    PRIMAL = "primal"  # x only; IPOPT initializes the multipliers itself and starts at mu_init
    PRIMAL_DUAL = "primal_dual"  # x and the multipliers (IPOPT's warm_start_init_point)


class Regularization(Enum):
    """Where IPOPT's Hessian regularization (inertia correction) starts at each new KKT matrix."""

    FROM_ZERO = "from_zero"  # IPOPT's rule: try the unregularized matrix first, then the last delta / 3, x 8 ...
    FROM_LAST = "from_last"  # start from the last delta / 3 (skips the first factorization; see _Solvers)


class Derivation(Enum):
    """How the homotopy's NLPs get their gradient, Jacobian and Hessian (the projection and the held schedule
    take the same; a replan derives step by step either way)."""

    WHOLE_GRAPH = "whole_graph"  # CasADi over the whole NLP (~3 s of a default Capler solve's setup): the documented paths
    STEPWISE = "stepwise"  # planner.derivatives, also wrapped for the scaled NLPs: ~1 s; equal to rounding, another path


class MumpsOrdering(Enum):
    """MUMPS's fill-reducing ordering of IPOPT's KKT matrix (IPOPT's mumps_pivot_order: the integer). SCOTCH (3) and
    PORD (4) are not built into the CasADi wheel's MUMPS, which then warns and takes its default: not offered."""

    AMD = "amd"  # 0
    AMF = "amf"  # 2
    METIS = "metis"  # 5
    QAMD = "qamd"  # 6
    AUTO = "auto"  # 7, MUMPS chooses by the matrix (IPOPT's default)


_MUMPS_PIVOT_ORDER = {MumpsOrdering.AMD: 0, MumpsOrdering.AMF: 2, MumpsOrdering.METIS: 5, MumpsOrdering.QAMD: 6,
                      MumpsOrdering.AUTO: 7}


class VariableScaling(Enum):
    """The variables IPOPT sees in the homotopy's NLPs (docs/formulation.md, round 6)."""

    NONE = "none"  # x as built
    FIRST_NLP = "first_nlp"  # from NLP 2 on, x = D xs with D = variable_scale(problem, NLP 1's solution)
    START = "start"  # from NLP 1 on, x = D xs with D = variable_scale(problem, the start x0) (a start that is a plan already)


class FESDStart(Enum):
    """Where the homotopy of an FESD problem (ProblemOptions.discretization FESD) starts (docs/formulation.md,
    "FESD in the OCP", "Continuation through implicit Euler"). An implicit-Euler problem refuses any but the default."""

    HINT_FREE = "hint_free"  # the problem's own x0 (y_0 everywhere, u = 0), the task's rho schedule
    # the implicit-Euler OCP of the same task and grid solved from its hint-free start (the default
    # implicit-Euler solve), mapped onto the FESD variables (problem.fesd_start_from_implicit_euler),
    # then the FESD NLPs of SolveOptions.fesd_rho_schedule and the polish: still no hint from the user
    IMPLICIT_EULER = "implicit_euler"


class ControlStart(Enum):
    """The controls u of the hint-free start (SolveOptions.start_controls)."""

    ZERO = "zero"  # the paper's: u = 0 at every step
    STATIC = "static"  # the least-norm torques holding the start's configuration at rest (problem.static_controls)


class Polish(Enum):
    """The NLP after the homotopy that makes complementarity exact (SolveOptions.polish; the module docstring)."""

    NONE = "none"  # no polish: the last homotopy NLP's point is returned
    ACTIVE_SET = "active_set"  # fix every pair's smaller side to zero, no penalty; accepted only if it converges (or
    # its projection's kept iterate passes the verdict's checks)
    HYBRID = "hybrid"  # fix only the clearly separated pairs, penalize the rest (rho = hybrid_rho), then ACTIVE_SET


# the SolveOptions fields that take an Enum (solve_options_from_dict reads them by value)
ENUM_FIELDS = {"mu_strategy": MuStrategy, "holes": HoleSchedule, "polish": Polish, "warm_start": WarmStart,
               "mumps_ordering": MumpsOrdering, "variable_scaling": VariableScaling, "regularization": Regularization,
               "fesd_start": FESDStart, "derivation": Derivation, "start_controls": ControlStart}


@dataclass(frozen=True)
class SolveOptions:
    """Numerical settings of the homotopy (the homotopy's rho0, kappa, n_nlp come from the task).

    tol, acceptable_tol: IPOPT's tol and acceptable_tol (None: ACCEPTABLE_TOL, or tol if larger; a value below tol is
    refused, IPOPT would get tol); max_iter: IPOPT iterations per NLP (unscaled, NLP 2 of
    the default Capler task stopped at 3000 on its way to hopping, and allowed to converge, at 3958,
    the path led NLP 4 astray; with variable_scaling it converges in 1535: docs/formulation.md round 6);
    print_level: IPOPT's (0 silent, 5 the usual log); linear_solver: IPOPT's (the CasADi wheel has
    "mumps" and "spral"; SPRAL took 2-8x MUMPS's time per iteration, docs/benchmarks.md); mu_strategy:
    IPOPT's barrier update; mu_init: first barrier parameter of NLP 1;
    warm_start: WarmStart: PRIMAL (default) restarts IPOPT's multipliers and barrier at every NLP
    from the previous NLP's x; PRIMAL_DUAL also passes the multipliers. Measured: PRIMAL_DUAL gave
    the full Capler task a lower cost (91 vs 109) but led the biped walk into a worse local
    optimum (objective 546 vs 50 at rho = 1e6) whose polish failed; PRIMAL lets each NLP re-centre.
    warm_mu_init: barrier parameter the later NLPs start from (None: same as mu_init; a
    small value keeps a warm start near its point; IPOPT reads mu_init and warm_mu_init only with
    mu_strategy monotone, docs/formulation.md round 7); bound_push, bound_frac: how far IPOPT moves
    the initial point inside the bounds (the warm start uses the same); nlp_scaling_method:
    IPOPT's ("gradient-based" or "none"); holes: HoleSchedule; polish: Polish; polish_after_failure:
    also polish when an NLP of the homotopy stopped early (default: the polish decides; see the verdict below);
    polish_starts: polish from the last homotopy point, and if that polish is not accepted from the one
    before, ... (this many points: insurance; with the projection polish the first was enough in every run measured); comp_tol,
    terminal_tol [m, rad], constraint_tol: the convergence verdict's thresholds; frozen_tol: the
    recovery's relative clock deficit of a frozen step; frozen_tol_several: the same for problems
    with several contact points, where a step is frozen only when its clock advanced less than
    (1 - frozen_tol_several) h (default: 1 % of h): a stance step may run partly frozen (clock rate
    in (0, 1), the a_n field carrying part of the weight) and is a physical step, not an impact
    (docs/formulation.md, "Periodic walking").
    rho_schedule: the penalties of the homotopy's NLPs (None: the task's rho0 kappa^i, n_nlp).
    rho_min, rho_max: applied to the task's schedule (left at their defaults beside a rho_schedule): drop the NLPs with
    rho < rho_min (the weak penalties are exploited by cheats, docs/formulation.md) and continue
    rho_i = rho0 kappa^i past n_nlp until rho_max is reached. rho_refine: extra penalties sorted into
    the task's schedule, those strictly between its first and last penalty (the others are left out: the default
    3e3 does not apply to a schedule starting at 1e4): the honest hopping motion appears between rho = 1e3 and 1e4,
    where a step of kappa = 10 left NLP 3 at its iteration cap on the full Capler task while 3e3 in between let
    every NLP converge (docs/formulation.md, "OCP and solve", round 3).
    an_schedule, at_schedule: per-NLP scale of the auxiliary gains a_n, a_t (the last value repeats;
    needs ProblemOptions.aux_continuation; None: 1). soft_terminal_nlps: how many first NLPs replace
    the hard terminal constraint by soft_terminal_weight ||residual||^2 in the objective.
    hybrid_ratio, hybrid_rho: Polish.HYBRID fixes a pair only when one side exceeds the other by
    hybrid_ratio (in the problem's units) and penalizes the others with weight hybrid_rho (l1 per
    pair; with Penalty.LINF the slack, now free for the unfixed pairs, gets it).
    intermediate_tol: IPOPT tol for every homotopy NLP but the last (None: tol); a loose value
    saves the iterations IPOPT spends converging tightly at a point the next rho moves away from.
    polish_projection: the polishing NLP minimizes ||x - x_h||^2 (x_h the point it starts from)
    instead of the task's cost: a projection onto the fixed active set (default). Measured with the
    secant switching velocity: Capler N = 125 with holes, 311 iterations (12 s) to exact
    complementarity; N = 50 without holes, 112 iterations, where the cost polish stopped at its
    3000-iteration cap from each of the rho = 1e6, 1e5 and 1e4 points (docs/formulation.md, round 4).
    The plan keeps the homotopy's (penalized) optimum up to the projection; the task's cost is not
    re-optimized on the fixed active set. The projection runs IPOPT's monotone barrier from mu = 1e-9:
    its start is feasible to ~1e-6, and from mu = 1e-4 the adaptive rule raised mu to 1e-2, left the
    point and took 904-1322 iterations back (default Capler task; now 10-19; docs/formulation.md,
    round 7). With variable_scaling the distance is measured in xs = x / D. It gives up after
    PROJECTION_MAX_RESTO_ITER successive restoration iterations (a projection there had left its start for good),
    which IPOPT reports as Maximum_Iterations_Exceeded below max_iter, and it stops (User_Requested_Stop)
    PROJECTION_STALL_ITER iterations after its rows first came within min(constraint_tol, terminal_tol); a
    projection IPOPT does not finish hands over its iterate nearest feasibility when the verdict's checks accept it
    (NlpRecord.kept_iteration).
    l1_schedule: with Penalty.LINF, per-NLP weight of an extra l1 sum of the products (None: 0;
    the last value repeats).
    mumps_ordering: MumpsOrdering, MUMPS's fill-reducing ordering (only with linear_solver "mumps").
    MUMPS and IPOPT are ~88 % of an iteration's CPU on the default Capler task; with AMD NLP 1's
    iterations cost a third less CPU than with MUMPS's own choice (AUTO, default), but the ordering
    changes the round-off and so the path: the one full solve measured with AMD took 7239
    iterations instead of 6099 (docs/benchmarks.md, "Speed of the pipeline").
    variable_scaling: VariableScaling, or None (default) for the task's `[plan.homotopy]
    scale_variables` (FIRST_NLP if true, else NONE). FIRST_NLP: NLPs 2 and later see x = D xs, with D
    each variable column's largest magnitude in NLP 1's solution (variable_scale). IPOPT's Hessian
    regularization and fraction-to-the-boundary rule are not scale invariant, and Capler's variables
    span 1 (selectors) to 1.4e3 (accelerations): unscaled, NLP 2 of the default task crawled to its
    3000-iteration cap (3958 to converge); scaled it converges in 1535 and every NLP converges
    (robots/capler.toml opts in). On the biped walk it made NLP 5 stop at its cap (4222 iterations
    against 2143), so it is a per-task choice (docs/formulation.md, round 6). Not measured to help FESD:
    on the FESD point-mass hop (n_s = 2, n_fe = 3, N = 10, rho_max 1e5) the polishes stopped at their
    cap (before round 7's projection). NLP 1 sees x as built; the scaled IPOPT is created after NLP 1
    (D is a constant in it: ~1-4 s, measured in timings solver_setup_s).
    VariableScaling.START (used by FESDStart.IMPLICIT_EULER's FESD NLPs): D from the start x0 (for FESD
    also every stage state's column), seen by every NLP from the first on (and by the projection).
    fesd_start: FESDStart, only for FESD problems. HINT_FREE (default): the homotopy from the problem's x0.
    IMPLICIT_EULER: the implicit-Euler OCP of the same task solved first from its hint-free start with these
    options (its own rho schedule: rho_schedule / rho_min / rho_max / rho_refine), its plan mapped onto the
    FESD variables, then the FESD NLPs of fesd_rho_schedule (holes and hard terminal enforced, IPOPT settings
    FESD_FROM_EULER_IPOPT) and the polish. fesd_rho_schedule: those FESD penalties (default 1e4, 1e5).
    Measured: the point-mass hop converges (48 s against 10 s hint-free); Capler N = 50 with holes, n_s = 1, n_fe = 3
    converges (228 s against 52 s for implicit Euler alone; docs/formulation.md, "Continuation through implicit Euler",
    session 6). With VariableScaling.START (this route) the polish re-scales D from the point it starts from.
    retry_terminal_weight: when the solve did not converge and an NLP reported local infeasibility
    (IPOPT's Infeasible_Problem_Detected), solve once more with this soft_terminal_weight (None: no
    retry; only with soft_terminal_nlps >= 1). A weak soft terminal lets NLP 1 stop short of the
    target where the hard terminal of NLP 2 is locally infeasible: measured on the point-mass stress
    task holes-00 (docs/stability.md), NLP 1 landed on the hole's edge, 0.24 m short, and every later
    NLP was infeasible; with weight 1e4 (or 1e3) every NLP converged. Converging solves never retry.
    regularization: Regularization. FROM_ZERO (default, IPOPT's rule) or FROM_LAST: start each factorization's
    inertia correction from the last Hessian regularization instead of trying none first. NLP 2 of the
    default Capler task needs one in 1515 of 1543 iterations; FROM_LAST cuts its factorizations from 2.5 to
    1.55 per iteration and whole solves' CPU per iteration by 15-30 %, but it changes the homotopy's path:
    over Capler N = 40 ... 125 it failed twice and took 58 % more iterations on the default task, and
    helped at N = 75 and 100 (docs/formulation.md, round 8).
    early_stop_comp: end the homotopy at the first NLP after the soft-terminal ones, with the holes at
    full size, that converged with its largest gated product <= this value (None: run every rho). A
    larger rho cannot improve such a point; IPOPT's restart only moves away from it and back: on the
    default Capler task the rho = 3e3 NLP ends at 1.5e-11, and the rho = 1e4, 1e5, 1e6 NLPs cost 660
    iterations for nothing. The default 1e-10 is well below IPOPT's tol (1e-8), the level at which the
    barrier leaves pairs whose two sides are both ~0: the FESD point-mass hop's rho = 1e4 NLP ends at
    1e-8, and the polish from there took 2285 iterations to a plan without its landing, against 19 from
    the rho = 1e5 point.
    ipopt: further IPOPT options for every NLP of the homotopy (a dict or (name, value) pairs, kept as
    sorted pairs), e.g. {"alpha_for_y": "min"}; warm_ipopt: the same for NLP 2 and later only (over
    ipopt). Checked against IPOPT when the options are made: an unknown name or a value IPOPT rejects
    is an InputError, and so is an option a field above owns (IPOPT_OWNED: "tol" is set through tol).
    The projection polish keeps its own barrier settings. Measured on the default Capler task: warm
    alpha_for_y = min takes NLP 2 alone from 1535 to 1044 iterations, but the whole solve to more
    (docs/benchmarks.md, "Full solves and the gap", session 10).
    keep_schedule: before the homotopy, solve the task's own cost with the contact schedule of the
    start x0 held (active_set_bounds of x0: every complementarity pair's side that is zero at x0 stays
    zero), one smooth NLP of at most schedule_max_iter IPOPT iterations (SCHEDULE_IPOPT). Accepted as
    the polish is (converged, constraints and terminal kept) and only if it has no new impact (each of
    its impacts overlaps one of x0's at the same contact point, or is a tap: an impulse below result.TAP_SHARE of
    x0's largest, session 29: Capler's target 3.0 -> 3.2 ... 3.4 m in 36-135 iterations, 1.5-3.8 s of solve,
    instead of a walk of 25-60 s); then no homotopy runs, else the
    homotopy runs from x0 as without it. For a start that is a converged plan of a nearby task
    (planner plan --init DIR, its default): the motion moves, its impacts stay on their steps, so the
    plan is the best one with the old timing, not the best nearby. Measured (docs/benchmarks.md,
    "Replanning", session 12): Capler's target moved -0.2 ... +0.1 m in 38-106 iterations (the penalty
    replan: 375-4410) at its cost or lower; the biped's step 0.25 -> 0.22 ... 0.27 m in 15-30
    iterations (penalty replan: 234-2815) at twice its cost: the penalty replan also lengthens the
    period.
    schedule_only: with keep_schedule, stop after the held-schedule NLP: when it is not accepted the result is
    not converged (x0 stays the point) instead of the homotopy running. planner.replan's walk uses it.
    schedule_new_impacts: with keep_schedule, also accept a held-schedule point with new impacts of any impulse (at
    the selectors x0 leaves strictly inside (0, 1), which are not held). Measured (docs/benchmarks.md, "Replanning",
    session 28): on the biped it accepts a full stance-foot impact at the period's start and gaits 1.7-3x dearer,
    two of three not walkable in MuJoCo, so it is off by default (Capler's added impacts are taps, accepted
    without it).
    reoptimize: after an accepted polish, solve the task's own cost once more with the polished plan's
    contact schedule held (the keep_schedule NLP, from the polished plan); its plan replaces the polished
    one when accepted as the polish is and cheaper (the task's NLP objective). The projection polish only
    makes the homotopy's point complementary; this makes the plan the cheapest with that schedule. Its
    impacts may differ by a step from the polished plan's (a frozen step split in two). Implicit Euler
    only (FESD plans are returned as polished). Measured on seven Capler tasks (docs/benchmarks.md,
    "Re-optimizing on the polished schedule", session 13): 0.4-46 % cheaper, 26-58 iterations.
    rho_f_schedule: per-NLP factor on the task's rho_f in the homotopy's NLPs (the last value repeats; None: 1). The
    polish, the held-schedule NLPs and so `reoptimize` use the task's own rho_f. A speed-for-cost trade: (10,) took 44 %
    fewer IPOPT iterations over seven Capler tasks (default task 1731 against 2348, a quarter less wall) to plans 87 %
    dearer with fewer hops; (10, 10, 1) and (100,) less (docs/benchmarks.md, session 23).
    derivation: Derivation. WHOLE_GRAPH (default): CasADi derives every homotopy NLP over its whole graph. STEPWISE:
    planner.derivatives' step-by-step derivatives for every NLP (the scaled ones wrapped around them), the solvers
    created in ~1 s instead of ~4 s on the default Capler task, the values equal to rounding, which takes the
    homotopy on another path: over seven Capler tasks 24047 iterations against 21714, plans 10 % dearer
    (docs/benchmarks.md, session 26).
    start_controls: ControlStart. ZERO (default): the paper's hint-free start, u = 0 at every step. STATIC: u starts
    at every step at the least-norm torques that hold the start's configuration at rest on the contact points
    touching there (problem.static_controls: friction cones kept when they can be, bounds clipped), the step's
    algebraic variables guessed with them; the states stay y_0 everywhere. Only from the hint-free start (problem.x0
    as built) of an implicit-Euler problem, with a contact point on its plane there. Measured (docs/benchmarks.md, "The
    static-torque start", session 68) on four robots standing on bent legs: a planar quadruped standing still 97
    iterations to cost 0.016 (MuJoCo passed) against 597 to 0.057 (failed), without its torso pitch 85 against 388 to
    the same plan, but a three-contact tribot 1133 iterations to 0.045 (failed) against 477 to 0.008 (passed) and the
    crouched Capler 1092 to 63.1 against 1746 to 39.4; Capler's straight leg needs no torque (the same start), so the
    default stays ZERO.
    """

    tol: float = 1e-8
    acceptable_tol: float | None = None
    max_iter: int = 3000
    print_level: int = 0
    linear_solver: str = "mumps"
    mu_strategy: MuStrategy = MuStrategy.ADAPTIVE
    mu_init: float = 0.1
    warm_start: WarmStart = WarmStart.PRIMAL
    warm_mu_init: float | None = None
    bound_push: float = 0.01
    bound_frac: float = 0.01
    nlp_scaling_method: str = "gradient-based"
    holes: HoleSchedule = HoleSchedule.RELAXED_FIRST
    polish: Polish = Polish.ACTIVE_SET
    polish_after_failure: bool = True
    polish_starts: int = 2
    comp_tol: float = 1e-6
    terminal_tol: float = 1e-6
    constraint_tol: float = 1e-6
    frozen_tol: float = FROZEN_TOL
    frozen_tol_several: float = 1.0 - FROZEN_TOL
    rho_schedule: tuple[float, ...] | None = None
    rho_min: float | None = 100.0
    rho_max: float | None = 1e6
    rho_refine: tuple[float, ...] = (3e3,)
    an_schedule: tuple[float, ...] | None = None
    at_schedule: tuple[float, ...] | None = None
    soft_terminal_nlps: int = 1
    soft_terminal_weight: float = 100.0
    hybrid_ratio: float = 100.0
    hybrid_rho: float = 1e4
    l1_schedule: tuple[float, ...] | None = None
    polish_projection: bool = True
    intermediate_tol: float | None = None
    mumps_ordering: MumpsOrdering = MumpsOrdering.AUTO
    regularization: Regularization = Regularization.FROM_ZERO
    retry_terminal_weight: float | None = 1e4
    variable_scaling: VariableScaling | None = None
    early_stop_comp: float | None = 1e-10
    fesd_start: FESDStart = FESDStart.HINT_FREE
    fesd_rho_schedule: tuple[float, ...] = (1e4, 1e5)
    ipopt: tuple[tuple[str, object], ...] = ()
    warm_ipopt: tuple[tuple[str, object], ...] = ()
    keep_schedule: bool = False
    schedule_only: bool = False
    schedule_new_impacts: bool = False
    schedule_max_iter: int = 200
    reoptimize: bool = True
    rho_f_schedule: tuple[float, ...] | None = None
    derivation: Derivation = Derivation.WHOLE_GRAPH
    start_controls: ControlStart = ControlStart.ZERO

    def __post_init__(self):
        check_field_types(self)
        for key in ("ipopt", "warm_ipopt"):
            object.__setattr__(self, key, _ipopt_pairs(key, getattr(self, key), warm=key == "warm_ipopt"))
        for key, enum in ENUM_FIELDS.items():
            enum_field(self, key, enum, optional=key == "variable_scaling")
        checks = [
            (self.tol > 0, "tol", self.tol, "> 0"),
            (self.acceptable_tol is None or self.acceptable_tol >= self.tol, "acceptable_tol", self.acceptable_tol,
             f">= tol = {self.tol!r} (or None)"),
            (self.max_iter >= 1, "max_iter", self.max_iter, ">= 1"),
            (self.schedule_max_iter >= 1, "schedule_max_iter", self.schedule_max_iter, ">= 1"),
            (self.polish_starts >= 1, "polish_starts", self.polish_starts, ">= 1"),
            (0 <= self.print_level <= 12, "print_level", self.print_level, "in 0 .. 12"),
            (self.mu_init > 0, "mu_init", self.mu_init, "> 0"),
            (self.warm_mu_init is None or self.warm_mu_init > 0, "warm_mu_init", self.warm_mu_init, "> 0 or None"),
            (0 < self.bound_push < 0.5, "bound_push", self.bound_push, "in (0, 0.5)"),
            (0 < self.bound_frac <= 0.5, "bound_frac", self.bound_frac, "in (0, 0.5]"),
            (self.linear_solver in LINEAR_SOLVERS, "linear_solver", self.linear_solver, f"one of {list(LINEAR_SOLVERS)}"),
            # (equilibration-based needs HSL's MC19, which the CasADi wheel lacks: IPOPT rejected it at the solve)
            (self.nlp_scaling_method in ("gradient-based", "none"), "nlp_scaling_method", self.nlp_scaling_method,
             "gradient-based or none"),
            (self.comp_tol > 0, "comp_tol", self.comp_tol, "> 0"),
            (self.terminal_tol > 0, "terminal_tol", self.terminal_tol, "> 0"),
            (self.constraint_tol > 0, "constraint_tol", self.constraint_tol, "> 0"),
            (0 < self.frozen_tol < 1, "frozen_tol", self.frozen_tol, "in (0, 1)"),
            (0 < self.frozen_tol_several < 1, "frozen_tol_several", self.frozen_tol_several, "in (0, 1)"),
            (self.early_stop_comp is None or self.early_stop_comp > 0, "early_stop_comp", self.early_stop_comp, "> 0 or None"),
            (self.rho_f_schedule is None or _positive_tuple(self.rho_f_schedule), "rho_f_schedule", self.rho_f_schedule,
             "None or a non-empty tuple of factors > 0"),
            (self.rho_schedule is None or _positive_tuple(self.rho_schedule) and len(self.rho_schedule) <= MAX_NLPS,
             "rho_schedule", self.rho_schedule,
             f"None (the task's schedule) or a non-empty tuple of at most {MAX_NLPS} penalties > 0"),
            (self.rho_min is None or self.rho_min > 0, "rho_min", self.rho_min, "> 0 or None"),
            (self.rho_max is None or self.rho_max > 0, "rho_max", self.rho_max, "> 0 or None"),
            (self.rho_min is None or self.rho_max is None or self.rho_min <= self.rho_max, "rho_min", self.rho_min,
             f"<= rho_max = {self.rho_max!r}"),
            (self.rho_refine == () or _positive_tuple(self.rho_refine), "rho_refine", self.rho_refine, "a tuple of penalties > 0"),
            (self.an_schedule is None or _positive_tuple(self.an_schedule), "an_schedule", self.an_schedule,
             "None or a non-empty tuple of scales > 0"),
            (self.at_schedule is None or _positive_tuple(self.at_schedule), "at_schedule", self.at_schedule,
             "None or a non-empty tuple of scales > 0"),
            (self.l1_schedule is None or _positive_tuple(self.l1_schedule, zero_ok=True), "l1_schedule", self.l1_schedule,
             "None or a non-empty tuple of weights >= 0"),
            (self.soft_terminal_nlps >= 0, "soft_terminal_nlps", self.soft_terminal_nlps, ">= 0"),
            (self.soft_terminal_weight > 0, "soft_terminal_weight", self.soft_terminal_weight, "> 0"),
            (self.hybrid_ratio > 0, "hybrid_ratio", self.hybrid_ratio, "> 0"),
            (self.hybrid_rho > 0, "hybrid_rho", self.hybrid_rho, "> 0"),
            (self.intermediate_tol is None or self.intermediate_tol > 0, "intermediate_tol", self.intermediate_tol, "> 0 or None"),
            (self.retry_terminal_weight is None or self.retry_terminal_weight > 0, "retry_terminal_weight",
             self.retry_terminal_weight, "> 0 or None"),
            (_positive_tuple(self.fesd_rho_schedule), "fesd_rho_schedule", self.fesd_rho_schedule,
             "a non-empty tuple of penalties > 0"),
            (self.keep_schedule or not self.schedule_only, "schedule_only", self.schedule_only, "False unless keep_schedule is True"),
            (self.keep_schedule or not self.schedule_new_impacts, "schedule_new_impacts", self.schedule_new_impacts,
             "False unless keep_schedule is True"),
            # (they change the task's schedule, which rho_schedule replaces: accepted, recorded and ignored before)
            *[(self.rho_schedule is None or getattr(self, k) == getattr(SolveOptions, k), k, getattr(self, k),
               f"{getattr(SolveOptions, k)!r} (the default) unless rho_schedule is None") for k in _TASK_RHO_FIELDS],
            # (read by their polish only: accepted, recorded and ignored before)
            (self.polish is Polish.HYBRID or self.hybrid_ratio == SolveOptions.hybrid_ratio, "hybrid_ratio",
             self.hybrid_ratio, f"{SolveOptions.hybrid_ratio!r} (the default) unless polish is hybrid"),
            (self.polish is Polish.HYBRID or self.hybrid_rho == SolveOptions.hybrid_rho, "hybrid_rho",
             self.hybrid_rho, f"{SolveOptions.hybrid_rho!r} (the default) unless polish is hybrid"),
            (self.polish is not Polish.NONE or self.polish_starts == SolveOptions.polish_starts, "polish_starts",
             self.polish_starts, f"{SolveOptions.polish_starts!r} (the default) unless there is a polish"),
            (self.polish is not Polish.NONE or self.polish_after_failure == SolveOptions.polish_after_failure,
             "polish_after_failure", self.polish_after_failure,
             f"{SolveOptions.polish_after_failure!r} (the default) unless there is a polish"),
            (self.polish is not Polish.NONE or self.polish_projection == SolveOptions.polish_projection,
             "polish_projection", self.polish_projection, f"{SolveOptions.polish_projection!r} (the default) unless "
             "there is a polish"),
            (self.linear_solver == "mumps" or self.mumps_ordering is MumpsOrdering.AUTO, "mumps_ordering",
             self.mumps_ordering, "auto (the default) unless linear_solver is 'mumps'"),
            (self.soft_terminal_nlps >= 1 or self.soft_terminal_weight == SolveOptions.soft_terminal_weight,
             "soft_terminal_weight", self.soft_terminal_weight,
             f"{SolveOptions.soft_terminal_weight!r} (the default) unless soft_terminal_nlps >= 1"),
            # (IPOPT reads its barrier's start with the monotone strategy only, docs/formulation.md round 7)
            (self.mu_strategy is MuStrategy.MONOTONE or self.mu_init == SolveOptions.mu_init, "mu_init", self.mu_init,
             f"{SolveOptions.mu_init!r} (the default) unless mu_strategy is monotone"),
            (self.mu_strategy is MuStrategy.MONOTONE or self.warm_mu_init is None, "warm_mu_init", self.warm_mu_init,
             "None (the default) unless mu_strategy is monotone"),
        ]
        for ok, key, value, allowed in checks:
            if not ok:
                raise InputError(f"SolveOptions.{key} = {value!r} is not allowed; it must be {allowed}")


# IPOPT's linear solvers: the CasADi wheel ships mumps and spral; the others need their library (HSL, Pardiso, WSMP),
# else IPOPT stops with Invalid_Option (an InputError from solve)
LINEAR_SOLVERS = ("mumps", "spral", "ma27", "ma57", "ma77", "ma86", "ma97", "pardiso", "pardisomkl", "wsmp")


def _positive_tuple(values, zero_ok: bool = False) -> bool:
    """Whether values is a non-empty tuple of numbers > 0 (>= 0 with zero_ok; bools are not numbers here)."""
    return isinstance(values, tuple) and len(values) >= 1 and all(
        isinstance(r, (int, float)) and not isinstance(r, bool) and (r >= 0 if zero_ok else r > 0) for r in values)


def solve_fields_from_json(text: str) -> dict:
    """The SolveOptions fields of a JSON object (for solve_options_from_dict), e.g. '{"rho_f_schedule": [10]}'; text
    that is not JSON or not an object is an InputError."""
    expect(text, str, "solve_fields_from_json's text")

    def once(pairs):  # '{"rho_min": 1, "rho_min": 2}' kept the last silently
        keys = [k for k, _ in pairs]
        repeated = sorted({k for k in keys if keys.count(k) > 1})
        if repeated:
            raise InputError(f"{text!r:.80} gives {', '.join(repeated)} more than once; give each field once")
        return dict(pairs)

    try:
        values = json.loads(text, object_pairs_hook=once)
    except json.JSONDecodeError as exc:
        raise InputError(f"{text!r:.80} is not JSON ({exc.msg}); e.g. '{{\"rho_f_schedule\": [10]}}'") from None
    except ValueError as exc:  # an integer of more than 4300 digits: Python's limit on reading one
        raise InputError(f"{text!r:.80} is not SolveOptions fields: {exc}") from None
    except RecursionError:
        raise InputError(f"{text!r:.80} is nested too deeply to be SolveOptions fields") from None
    if not isinstance(values, dict):
        kind = {list: "an array", str: "a string", bool: "a boolean", type(None): "null"}.get(type(values), "a number")
        raise InputError(f"{text!r}: expected a JSON object of SolveOptions fields, got {kind}")
    return values


def solve_options_from_dict(values: dict, base: SolveOptions | None = None) -> SolveOptions:
    """`base` (default SolveOptions()) with the fields in `values` (e.g. parsed JSON): Enum fields by their
    value ("monotone"), lists as tuples, ipopt / warm_ipopt as dicts. Unknown fields and values are InputErrors."""
    expect(values, dict, "solve_options_from_dict's values")
    expect(base, (SolveOptions, type(None)), "solve_options_from_dict's base")
    names = [f.name for f in fields(SolveOptions)]
    out = {}
    for key, value in values.items():
        if key not in names:
            near = difflib.get_close_matches(str(key), names, n=1)  # (the 50 names alone hid a typo's field)
            raise InputError(f"SolveOptions has no field {key!r}" + (f" (did you mean {near[0]!r}?)" if near else "")
                             + f"; the fields are {names}")
        out[key] = tuple(value) if isinstance(value, list) else value  # (an Enum field's value: SolveOptions's own)
    return replace(base or SolveOptions(), **out)


# IPOPT options that SolveOptions fields set (ipopt_options): SolveOptions.ipopt must not fight them
IPOPT_OWNED = {"tol": "tol", "acceptable_tol": "acceptable_tol", "max_iter": "max_iter", "print_level": "print_level",
               "sb": "print_level", "linear_solver": "linear_solver", "mu_strategy": "mu_strategy", "mu_init": "mu_init",
               "bound_push": "bound_push", "bound_frac": "bound_frac", "nlp_scaling_method": "nlp_scaling_method",
               "mumps_pivot_order": "mumps_ordering", "warm_start_init_point": "warm_start"}


def _ipopt_pairs(field: str, given, warm: bool) -> tuple[tuple[str, object], ...]:
    """SolveOptions.ipopt / warm_ipopt as sorted (name, value) pairs, checked by IPOPT itself."""
    try:
        pairs = tuple(sorted((name, plain(value)) for name, value in dict(given).items()))  # np.int64(5) as 5
    except (TypeError, ValueError):
        raise InputError(f"SolveOptions.{field} = {given!r} is not allowed; it must be a dict of IPOPT options") from None
    for name, value in pairs:
        # IPOPT's own range check lets nan through (constr_viol_tol = nan "converged" every NLP)
        if (not isinstance(name, str) or isinstance(value, bool) or not isinstance(value, (int, float, str))
                or (isinstance(value, float) and not math.isfinite(value))):
            raise InputError(f"SolveOptions.{field}: {name!r} = {value!r} is not allowed; names are strings, values finite "
                             "numbers or strings")
        if name == "output_file":  # (also created by the check below, wherever it pointed)
            raise InputError(f"SolveOptions.{field} sets IPOPT's 'output_file', which each NLP of the homotopy (and "
                             "each arm of a race) writes anew: it kept the last NLP's log only; show IPOPT's log with "
                             "print_level (planner plan -v) and redirect it instead")
        owner = "warm_mu_init" if (warm and name == "mu_init") else IPOPT_OWNED.get(name)
        if owner:  # (IPOPT reads mu_init with the monotone strategy only: the owner set alone was refused next)
            also = " and mu_strategy 'monotone', which it needs" if owner in ("mu_init", "warm_mu_init") else ""
            raise InputError(f"SolveOptions.{field} sets IPOPT's {name!r}, which SolveOptions.{owner} owns; set that "
                             f"instead{also}")
    for name, value in pairs:  # CasADi hands IPOPT's integer options int(value): acceptable_iter = 2.5 ran as 2
        if isinstance(value, (int, float)) and _ipopt_option_is_integer(name) and not (
                float(value).is_integer() and representable(value, "int")):  # (2**32 + 1 wrapped around to 1)
            raise InputError(f"SolveOptions.{field}: {name!r} = {value!r} is not allowed; IPOPT's {name} is an integer "
                             f"a C int holds (at most {C_INT_MAX})")
    if pairs:
        _check_with_ipopt(field, dict(pairs))
    return pairs


def _ipopt_option_is_integer(name: str) -> bool:
    """Whether IPOPT registers `name` as an integer option: CasADi refuses a string for it with "is_int()" (a number
    it would take and truncate)."""
    x = ca.SX.sym("x")
    with captured_stdout():
        try:
            ca.nlpsol("ipopt_type_check", "ipopt", {"x": x, "f": x * x},
                      {"print_time": False, "ipopt": {name: "?", "print_level": 0, "sb": "yes"}})
        except RuntimeError as e:
            return '"is_int()" failed' in str(e)
    return False


def _check_with_ipopt(field: str, opts: dict) -> None:
    """Create IPOPT for min x^2 with `opts`; IPOPT's complaint (it prints it, CasADi raises) as an InputError."""
    x = ca.SX.sym("x")
    error = None
    with captured_stdout() as printed:  # CasADi's Python interface prints IPOPT's output through sys.stdout
        try:
            ca.nlpsol("ipopt_option_check", "ipopt", {"x": x, "f": x * x}, {"print_time": False, "ipopt": dict(opts, print_level=0, sb="yes")})
        except RuntimeError as e:
            error = e
    text = printed.getvalue()
    if error is None:
        return
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    reason = lines[0] if lines else str(error).strip().splitlines()[-1].split(": ", 1)[-1]
    if reason == "type mismatch":
        reason += " (IPOPT takes numbers for its numeric options and strings for the others)"
    if "Valid Settings:" in lines:
        names = [ln.split()[0] for ln in lines[lines.index("Valid Settings:") + 1:] if not ln.startswith("Default:")]
        reason += " Valid: " + ", ".join(names)
    else:
        reason += "".join(f" Range: {ln}" for ln in lines if "<=" in ln)
    raise InputError(f"SolveOptions.{field} = {opts!r} is not allowed: {reason}")


# Replanning from a converged plan of a nearby task (planner plan --init): its point is already
# complementary, so one NLP at a penalty that keeps it so, with the holes and the hard terminal
# constraint on from the start, and IPOPT's barrier started next to the point (monotone mu from 1e-6,
# bounds pushed by 1e-8) instead of re-centred: Capler with the target moved 3.0 -> 2.9 m, 598 + 23
# iterations (19 s); with the default barrier settings 802 and a failed polish (docs/benchmarks.md).
# When that NLP leaves the products above REPLAN_STOP_COMP, a second one at REPLAN_RHO_MAX closes them
# before the polish: the polish's fixed active set absorbed Capler's 1.8e-6 (23 iterations) but not the
# biped's 6.5e-5 (step 0.25 -> 0.26 m: "infeasible"; with the second NLP 302 iterations in all).
REPLAN_RHO = 1e4
REPLAN_RHO_MAX = 1e6
REPLAN_STOP_COMP = 1e-5
REPLAN_MU_INIT = 1e-6
REPLAN_BOUND_PUSH = 1e-8
# SolveOptions.keep_schedule's NLP starts at an exactly complementary, nearly feasible point and its pairs are
# held by bounds: a monotone barrier from 1e-9 with the start pushed in by 1e-9 stays next to it (Capler target
# 3.0 -> 2.9 m, IPOPT's bound relaxation at its default: 25 iterations; from mu = 1e-6 148, and from the adaptive
# rule's 0.1 425, to the same plan). The held pairs leave equality rows that depend on each other, so IPOPT
# needs a constraint regularization in every iteration: perturb_always_cd asks for it at once instead of after
# a failed factorization (same iterates, 50 instead of 70 ms per iteration). IPOPT's default acceptable_iter (15)
# then spent 13 iterations creeping from its acceptable level 1e-6 towards tol at a fixed mu (every Capler target).
# IPOPT's filter line search cut nearly every step of this NLP 5-7 times (Capler 3.0 -> 3.1 m: steps of 0.005-0.014
# for 200 iterations, refused at the cap): from next to its answer the full Newton step is the right one, so every
# trial step is taken (3.1 m: 26 iterations; 3.05 m: 22 instead of 99). A start too far away then fails in tens of
# iterations instead of at the cap, and the walk (planner.replan) halves its step (docs/benchmarks.md, "Replanning",
# session 28).
SCHEDULE_IPOPT = {"mu_strategy": "monotone", "mu_init": 1e-9, "bound_push": 1e-9, "bound_frac": 1e-9, "perturb_always_cd": "yes",
                  "acceptable_iter": 2, "accept_every_trial_step": "yes"}
# The NLPs whose barrier starts at mu = 1e-9 (the held-schedule NLP of keep_schedule and reoptimize, the projection
# polish): MUMPS's permuting scaling (its weighted matching, IPOPT's default 7) cost two thirds of an iteration
# there. Without it, Capler's schedule NLP (target 3.0 -> 2.9 m) took 35 instead of 39 iterations at 15 instead of
# 45 ms, the penalty replan's polish 24 iterations at 17 instead of 65 ms. On the homotopy's NLPs it changes the
# path, not the cost (docs/benchmarks.md, "Full solves and the gap", session 13).
SMALL_MU_MUMPS = {"mumps_permuting_scaling": 0}
# The projection polish starts next to a feasible point, so a restoration phase there (IPOPT's search for any feasible
# point, the distance to the start ignored) ends far from it if at all: Capler without holes at N = 40 stalled at a
# violation of 1.8e-8 (the fixed active set's floor, above tol 1e-8), entered restoration at iteration ~200 and stayed
# in it to the 3000 cap from both starts (8448 iterations, 130 s). With this cap each fails in ~300 iterations
# (docs/formulation.md, the session-69 note after the FESD table); IPOPT's default is 3000000.
PROJECTION_MAX_RESTO_ITER = 100
# A projection stops this many iterations after its rows first came within the verdict's constraint_tol (and
# terminal_tol, if smaller; _NearestFeasible), and its iterate nearest feasibility is kept: the penalty replan of
# Capler's raced N = 40 no-holes plan to its own task ran its projection to the 3000 cap (24 s) with the rows within
# 8e-9, the dual infeasibility never below IPOPT's tol. Projections that converge take 10-20 iterations on the
# shipped tasks. (A rule on the rows no longer halving read rounding noise: a hop's rows went 2e-15 -> 9e-16 after 35
# iterations.)
PROJECTION_STALL_ITER = 100


def _users_last(opts: dict, options: SolveOptions, warm: bool) -> None:
    """The user's own IPOPT options (SolveOptions.ipopt, and warm_ipopt for a warm NLP) over those an NLP's own settings
    put into opts: `--ipopt acceptable_iter=10` reached every NLP but the held-schedule and projection ones, whose
    settings replaced it while summary.json recorded it."""
    opts["ipopt"].update(options.ipopt)
    if warm:
        opts["ipopt"].update(options.warm_ipopt)


def _small_mu_ipopt(options: SolveOptions) -> dict:
    """The IPOPT options of an NLP whose barrier starts at mu = 1e-9: SMALL_MU_MUMPS with MUMPS, else none."""
    return dict(SMALL_MU_MUMPS) if options.linear_solver == "mumps" else {}


ACCEPTABLE_TOL = 1e-6  # SolveOptions.acceptable_tol's default (IPOPT's acceptable_tol), or tol when larger
SCHEDULE_KEPT = " (the start's contact schedule kept)"  # a held-schedule NLP's result message


def replan_options(options: SolveOptions | None = None) -> SolveOptions:
    """`options` (default SolveOptions()) set up to start from a converged plan of a task with the same
    Problem.signature: one NLP at REPLAN_RHO (and one at REPLAN_RHO_MAX unless its products are <=
    REPLAN_STOP_COMP), holes and terminal constraint enforced, variables scaled from the start,
    monotone barrier from REPLAN_MU_INIT; then the usual polish. It finds the local optimum next to
    the old plan (the same contact sequence, moved), not a new hint-free search. With keep_schedule
    (planner plan --init DIR) the task's cost with the plan's contact schedule held comes first."""
    expect(options, (SolveOptions, type(None)), "replan_options' options")
    fields = dict(rho_schedule=(REPLAN_RHO, REPLAN_RHO_MAX), soft_terminal_nlps=0, early_stop_comp=REPLAN_STOP_COMP,
                  holes=HoleSchedule.ENFORCED, variable_scaling=VariableScaling.START,
                  mu_strategy=MuStrategy.MONOTONE, mu_init=REPLAN_MU_INIT,
                  bound_push=REPLAN_BOUND_PUSH, bound_frac=REPLAN_BOUND_PUSH)
    # a value of the replan's own (mu_strategy monotone, under which warm_mu_init is read) is no conflict
    given = [k for k in REPLAN_FIELDS if options is not None
             and getattr(options, k) not in (getattr(SolveOptions, k), fields.get(k, getattr(SolveOptions, k)))]
    if given:  # (they were replaced without a word)
        raise InputError(f"replan_options sets {', '.join(given)}: leave {'it' if len(given) == 1 else 'them'} at "
                         "the default (a replan's own homotopy from the plan, homotopy.REPLAN_FIELDS; README)")
    try:
        return replace(options or SolveOptions(), **fields)
    except InputError as exc:  # an option the replan's settings leave unread (soft_terminal_weight)
        raise InputError(f"{exc} (a replan solves with soft_terminal_nlps = 0)") from None


# the SolveOptions fields replan_options sets (`planner plan --init DIR --solve` may not: they were replaced), and
# those that act on the task's schedule only, which its rho_schedule replaces (rho_max 1e5 was recorded, 1e6 run)
REPLAN_FIELDS = ("rho_schedule", "soft_terminal_nlps", "early_stop_comp", "holes", "variable_scaling", "mu_strategy",
                 "mu_init", "bound_push", "bound_frac", "rho_min", "rho_max", "rho_refine")
_TASK_RHO_FIELDS = ("rho_min", "rho_max", "rho_refine")  # read by task_rho_schedule, unread beside a rho_schedule


def _distance(x, x_ref):
    """The projection polish's objective |x - x_ref|^2 and its gradient 2 (x - x_ref) (x, x_ref (n,), SX or MX): the
    NLP's f and the derivative functions handed to its IPOPT are both built from this."""
    d = x - x_ref
    return ca.dot(d, d), 2 * d


def ipopt_options(options: SolveOptions, warm: bool, loose: bool = False) -> dict:
    """CasADi nlpsol options for IPOPT (a cold solver for NLP 1, a warm one for the rest: with
    WarmStart.PRIMAL_DUAL it starts from the multipliers passed in; loose: an intermediate homotopy
    NLP solved to options.intermediate_tol)."""
    tol = options.intermediate_tol if (loose and options.intermediate_tol is not None) else options.tol
    ip = {
        "tol": tol, "acceptable_tol": max(tol, ACCEPTABLE_TOL if options.acceptable_tol is None
                                          else options.acceptable_tol),
        "max_iter": options.max_iter,
        "print_level": options.print_level, "sb": "yes", "linear_solver": options.linear_solver,
        "mu_strategy": options.mu_strategy.value, "mu_init": options.mu_init,
        "bound_push": options.bound_push, "bound_frac": options.bound_frac,
        "nlp_scaling_method": options.nlp_scaling_method,
    }
    if options.linear_solver == "mumps":
        ip["mumps_pivot_order"] = _MUMPS_PIVOT_ORDER[options.mumps_ordering]
    if warm and options.warm_start is WarmStart.PRIMAL_DUAL:
        ip.update(warm_start_init_point="yes", warm_start_bound_push=options.bound_push, warm_start_bound_frac=options.bound_frac,
                  warm_start_mult_bound_push=options.bound_push)
    if warm and options.warm_mu_init is not None:
        ip["mu_init"] = options.warm_mu_init
    ip.update(options.ipopt)
    if warm:
        ip.update(options.warm_ipopt)
    return {"print_time": False, "ipopt": ip}


Progress = Callable[[NlpRecord], None]


class _StopWhenInterrupted(ca.Callback):
    """IPOPT's iteration callback (CasADi's iteration_callback) where IPOPT prints its log (print_level > 0): it stops
    the NLP (User_Requested_Stop) once a Ctrl-C was taken (errors.interrupted); errors.interruptible raises it after.
    CasADi prints the log through Python's sys.stdout, and a Ctrl-C that Python took inside that write raised its
    KeyboardInterrupt there, which the write dropped (PySys_WriteStdout drops a write's error): CasADi's own check saw
    no signal left and the NLP ran to its end (seconds on the Capler task; 0.2 s without -v). It reads the iterate
    only: the solve's numbers are the same."""

    def __init__(self, nlp: dict):
        ca.Callback.__init__(self)
        nx, ng, n_p = (nlp[k].numel() if k in nlp else 0 for k in ("x", "g", "p"))
        # the inputs are nlpsol's outputs, by name
        self._sizes = [{"x": nx, "f": 1, "g": ng, "lam_x": nx, "lam_g": ng, "lam_p": n_p}[ca.nlpsol_out(i)]
                       for i in range(ca.nlpsol_n_out())]
        self.construct("stop_when_interrupted", {})

    def get_n_in(self):
        return ca.nlpsol_n_out()

    def get_n_out(self):
        return 1

    def get_sparsity_in(self, i):
        return ca.Sparsity.dense(self._sizes[i], 1)

    def eval(self, arg):
        return [1.0 if interrupted() else 0.0]  # (nonzero: IPOPT stops)


class _NearestFeasible(_StopWhenInterrupted):
    """The projection polish's iteration callback: besides stopping on a Ctrl-C, it keeps the iterate whose rows lie
    nearest their bounds, and of those within stall_tol the one nearest the projection's start (its objective; then
    the latest) (IPOPT's iterates keep the bounds of x), so that a projection IPOPT does not finish still hands over
    its feasible point (_kept_projection): at the rows' rounding floor every iterate ties, and the latest had drifted
    from the start (a hop's iterate 68: distance 4.8e-6, where iterate 28 had 5.6e-13). Capler without holes at
    N = 40: the projection's rows reached 1.8e-8 in 5 iterations and stayed there, above IPOPT's tol 1e-8, while the
    dual infeasibility stayed at 4e-4; IPOPT's end point, after a restoration phase, broke the rows by 3.7e-4. It
    stops IPOPT PROJECTION_STALL_ITER iterations after the rows first came within stall_tol. (CasADi calls it once more
    with IPOPT's final point after a restoration phase, so kept_iteration may be one past IPOPT's log.)"""

    def __init__(self, nlp: dict):
        super().__init__(nlp)
        self.reset(np.zeros(0), np.zeros(0), np.ones(0), 0.0)

    def reset(self, lbg: np.ndarray, ubg: np.ndarray, D: np.ndarray, stall_tol: float) -> None:
        """Before each solve: its row bounds (ng,), the variables' scale D (nx,) (x = D xs) and the row violation
        [constraint units] from which on IPOPT gets PROJECTION_STALL_ITER more iterations (0: only rows met exactly)."""
        self.lbg, self.ubg, self.D, self.stall_tol = lbg, ubg, D, stall_tol
        self.iteration, self.best = 0, None  # best: (largest row violation, iteration, x, f, lam_x, lam_g), unscaled
        self._rank = None  # best's (max(violation, stall_tol), f, -iteration): the smallest wins
        self.feasible_since = None  # the first iteration whose rows were within stall_tol

    def eval(self, arg):
        it = {ca.nlpsol_out(i): np.asarray(a, float).ravel() for i, a in enumerate(arg)}
        g = it["g"]
        viol = float(max(np.max(self.lbg - g, initial=0.0), np.max(g - self.ubg, initial=0.0)))
        f = float(it["f"][0])
        rank = (max(viol, self.stall_tol), f, -self.iteration)
        if self._rank is None or rank <= self._rank:
            self.best, self._rank = (viol, self.iteration, it["x"] * self.D, f, it["lam_x"] / self.D, it["lam_g"]), rank
        if self.feasible_since is None and viol <= self.stall_tol:
            self.feasible_since = self.iteration
        stalled = self.feasible_since is not None and self.iteration - self.feasible_since >= PROJECTION_STALL_ITER
        self.iteration += 1
        return [1.0] if stalled else super().eval(arg)


def _nlpsol(name: str, nlp: dict, opts: dict, keep: list, nearest_feasible: bool = False) -> ca.Function:
    """ca.nlpsol(name, "ipopt", nlp, opts), with _StopWhenInterrupted where IPOPT prints its log, or
    _NearestFeasible (nearest_feasible) always (kept alive in `keep`: CasADi holds no reference to a Python
    callback)."""
    if nearest_feasible or opts["ipopt"].get("print_level", 5) > 0:  # (IPOPT's default level is 5)
        keep.append((_NearestFeasible if nearest_feasible else _StopWhenInterrupted)(nlp))
        opts = dict(opts, iteration_callback=keep[-1])
    return ca.nlpsol(name, "ipopt", nlp, opts)


class _Solvers:
    """IPOPT for the problem's NLP, created on first use: cold (NLP 1) and warm (later NLPs).
    They differ only in IPOPT options that CasADi fixes at creation."""

    def __init__(self, problem: Problem, options: SolveOptions):
        # Regularization.FROM_LAST: one free variable that appears nowhere (the probe) makes the unregularized
        # KKT matrix singular, so IPOPT's degeneracy test marks the Hessian degenerate after three iterations and
        # from then on starts each factorization from the last delta / 3 instead of from 0. The homotopy NLPs'
        # Hessians are indefinite almost everywhere (NLP 2 of the default Capler task: 1515 of 1543 iterations
        # regularized), so the try at 0 is a wasted factorization (docs/formulation.md, round 8).
        self.n_probe = 1 if options.regularization is Regularization.FROM_LAST else 0
        self.nlp = self._probed({"x": problem.x, "p": problem.p, "f": problem.f, "g": problem.g})
        self.scale = None  # D (nx,) once set_scale was called: the warm solvers then solve for xs = x / D
        self.scale_cold = False  # VariableScaling.START: the cold solver (NLP 1) sees xs too
        self.options, self.cache, self.setup_time_s = options, {}, 0.0
        self.callbacks: list[_StopWhenInterrupted] = []  # those of the solvers made (_nlpsol)
        self.nearest_feasible: _NearestFeasible | None = None  # the projection's (made with it)
        self.eval_s: dict[str, dict[str, float]] = {}  # IPOPT's name -> callback -> wall s, summed over all its calls
        self.problem = problem
        self._derivs, self._derivs_stepwise = None, False

    def set_scale(self, D: np.ndarray) -> None:
        """From now on the warm (later-NLP) solvers see x = D xs (VariableScaling.FIRST_NLP)."""
        pb = self.problem
        self.scale = np.asarray(D, float)
        xs = ca.SX.sym("xs", pb.nx)
        x = ca.DM(self.scale) * xs
        self.scaled_nlp = self._probed({"x": xs, "p": pb.p, "f": ca.substitute(pb.f, pb.x, x), "g": ca.substitute(pb.g, pb.x, x)})
        # every solver made so far goes: the scaled ones were of another D, and the cold (NLP 1's) one, which is not
        # used again, held ~90 MB at Capler's N = 125 through the rest of the solve (session 57's tester)
        self.cache = {}

    def sees_scale(self, warm: bool, schedule: bool = False, projection: bool = False) -> bool:
        """Whether that solver solves for xs = x / D: once a scale is set, the warm ones, the projection, the
        held-schedule one, and the cold one with scale_cold (VariableScaling.START)."""
        return (warm or schedule or projection or self.scale_cold) and self.scale is not None

    def _bound_relax(self) -> float:
        """IPOPT's bound_relax_factor for a solver that sees xs = x / D: IPOPT relaxes each bound by it (default
        1e-8) in xs, i.e. by that times D in x; kept a tenth of the verdict's constraint_tol in x."""
        return min(1e-8, 0.1 * self.options.constraint_tol / float(np.max(self.scale)))

    def _probed(self, nlp: dict) -> dict:
        return dict(nlp, x=ca.vertcat(nlp["x"], ca.SX.sym("probe", self.n_probe))) if self.n_probe else nlp

    def derivatives(self, scaled: bool = False, projection: bool = False, homotopy: bool = False) -> dict:
        """nlpsol's options grad_f, jac_g and hess_lag for one IPOPT (all but the scaled homotopy NLPs, see get),
        derived from the unscaled NLP once per problem. homotopy (the homotopy's unscaled NLPs), unless
        SolveOptions.derivation is STEPWISE: CasADi's derivation over the whole graph (1.5 s on the default Capler
        task), whose rounding the documented homotopy paths follow
        (planner.derivatives' equal values to rounding took the default task on another path: 2766 iterations to
        cost 113.1 instead of 2348 to 88.35); the projection and the held schedule take those when they exist, else
        the step-by-step derivation (0.2 s: a replan's setup). A solver that sees xs = x / D gets them scaled
        around those (D grad f, J diag(D), diag(D) H diag(D)), the projection with its distance's terms added, so
        those IPOPTs are created in a fraction of that."""
        stepwise = not homotopy or self.options.derivation is Derivation.STEPWISE
        if self._derivs is None or (self._derivs_stepwise and not stepwise):
            self._derivs_stepwise = stepwise
            self._derivs = nlp_derivatives(self.problem, self.n_probe, stepwise=stepwise)
        d = self._derivs
        if not (scaled or projection):
            return dict(d)
        pb, n = self.problem, self.problem.nx + self.n_probe
        nv = pb.nx if projection else n  # the projection's x has no probe
        D = np.ones(n)
        if scaled:
            D[: pb.nx] = self.scale
        xs, lf, lg = ca.MX.sym("x", nv), ca.MX.sym("lam_f"), ca.MX.sym("lam_g", pb.g.numel())
        p = ca.MX.sym("p", (pb.nx if projection else 0) + pb.p.numel())
        x = ca.vertcat(D[:nv] * xs, ca.MX.zeros(n - nv))
        p_nlp, Dm = p[pb.nx:] if projection else p, ca.diag(ca.DM(D[:nv]))
        f, gf = d["grad_f"](x, p_nlp)
        g, J = d["jac_g"](x, p_nlp)
        H = d["hess_lag"](x, p_nlp, 0.0 if projection else lf, lg)
        gf, J, H = D[:nv] * gf[:nv], ca.mtimes(J[:, :nv], Dm), ca.mtimes(ca.mtimes(Dm, H[:nv, :nv]), Dm)
        if projection:
            f, gf = _distance(xs, p[: pb.nx])
            H = H + 2 * lf * ca.MX.eye(nv)
        return {"grad_f": ca.Function("nlp_grad_f", [xs, p], [f, gf], ["x", "p"], ["f", "grad_f_x"]),
                "jac_g": ca.Function("nlp_jac_g", [xs, p], [g, J], ["x", "p"], ["g", "jac_g_x"]),
                "hess_lag": ca.Function("nlp_hess_l", [xs, p, lf, lg], [H], ["x", "p", "lam_f", "lam_g"], ["triu_hess_gamma_x_x"])}

    def add_evals(self, name: str, stats: dict) -> None:
        """Add one call's callback wall times (CasADi's t_wall_nlp_* stats) to eval_s[name]."""
        acc = self.eval_s.setdefault(name, {})
        for key, value in stats.items():
            if key.startswith("t_wall_"):
                callback = key[len("t_wall_"):]
                acc[callback] = acc.get(callback, 0.0) + float(value)

    def projection(self):
        """IPOPT for min ||x - x_ref||^2 s.t. the problem's constraints (x_ref, then p, as parameters)."""
        if "projection" not in self.cache:
            t0 = time.perf_counter()
            pb = self.problem
            xref = ca.SX.sym("x_ref", pb.nx)
            # with a scale, the distance in xs = x / D: a 1e3 force and a 0..1 selector weigh alike
            scaled = self.sees_scale(False, projection=True)
            base = self.scaled_nlp if scaled else self.nlp
            x = base["x"][: pb.nx]  # without the probe: the projection is a Newton projection, unregularized
            nlp = {"x": x, "p": ca.vertcat(xref, pb.p), "f": _distance(x, xref)[0], "g": base["g"]}
            opts = ipopt_options(self.options, False)
            # start next to x_ref and stay there: x_ref is feasible to ~1e-6, so a monotone barrier at 1e-9 is a
            # Newton projection (10 iterations on the default Capler task); the adaptive rule from 1e-4 raised
            # mu to 1e-2, left the point and took 1322 iterations back (docs/formulation.md, round 7)
            opts["ipopt"].update(mu_init=1e-9, mu_strategy="monotone", bound_push=1e-6, bound_frac=1e-6,
                                 max_resto_iter=PROJECTION_MAX_RESTO_ITER)
            opts["ipopt"].update(_small_mu_ipopt(self.options))
            if pb.fesd is not None and self.scale is not None:
                # FESD Capler's gamma multipliers have D ~4e5 (flight stages), and the polished point of N = 50 broke
                # lambda >= 0 by 4.3e-3 against the verdict's constraint_tol 1e-6 (docs/formulation.md)
                opts["ipopt"]["bound_relax_factor"] = self._bound_relax()
            _users_last(opts, self.options, False)
            opts.update(self.derivatives(scaled, projection=True))
            self.cache["projection"] = _nlpsol("tf_ocp_projection", nlp, opts, self.callbacks, nearest_feasible=True)
            self.nearest_feasible = self.callbacks[-1]
            self.setup_time_s += time.perf_counter() - t0
        return self.cache["projection"]

    def get(self, warm: bool, loose: bool = False, schedule: bool = False):
        """schedule: the keep_schedule NLP's IPOPT (SCHEDULE_IPOPT, schedule_max_iter)."""
        opts = ipopt_options(self.options, warm, loose)
        if schedule:
            opts["ipopt"].update(SCHEDULE_IPOPT, max_iter=self.options.schedule_max_iter)
            opts["ipopt"].update(_small_mu_ipopt(self.options))
            if self.scale is not None:  # IPOPT's bound relaxation (1e-8 in xs) is 1e-8 D in x: Capler target 2.8 m broke a bound by 9.8e-6
                opts["ipopt"]["bound_relax_factor"] = self._bound_relax()
            _users_last(opts, self.options, warm)
        scaled = self.sees_scale(warm, schedule)
        key = ("scaled" if scaled else "") + repr(sorted(opts["ipopt"].items()))  # one IPOPT per option set (~1-4 s each)
        if key not in self.cache:
            t0 = time.perf_counter()
            name = "schedule" if schedule else ("loose_" if loose and self.options.intermediate_tol is not None else "") + ("warm" if warm else "cold")
            if schedule or not scaled or self.options.derivation is Derivation.STEPWISE:
                # the scaled homotopy NLPs keep CasADi's derivation of the substituted NLP unless Derivation.STEPWISE: the
                # wrapped derivatives equal it to rounding, and that rounding took the default Capler task's homotopy on
                # another path (472 / 1391 / 693 / 2129 / 934 iterations instead of 472 / 1535 / 839 to a plan of cost
                # 125.5 instead of 99.4)
                opts.update(self.derivatives(scaled, homotopy=not schedule))
            self.cache[key] = _nlpsol(f"tf_ocp_{name}", self.scaled_nlp if scaled else self.nlp, opts, self.callbacks)
            self.setup_time_s += time.perf_counter() - t0
        return self.cache[key]


def homotopy_rhos(problem: Problem, options: SolveOptions) -> list[float]:
    """The homotopy's penalties rho, one per NLP: options.rho_schedule, else the task's schedule as
    options.rho_min / rho_max / rho_refine change it (task_rho_schedule)."""
    if options.rho_schedule:
        return [float(r) for r in options.rho_schedule]
    return task_rho_schedule(problem.task.plan.homotopy, options.rho_min, options.rho_max, options.rho_refine)


@dataclass(frozen=True, eq=False)
class HomotopyNlp(ArraysReadOnly):
    """NLP i of the homotopy as solve() hands it to IPOPT (with problem.lbx, problem.ubx); its arrays are read-only
    copies (lbg was the problem's own array: written through it, the next solve ended elsewhere)."""
    label: str  # "homotopy {i + 1}"
    p: np.ndarray  # (7,) the parameters (Problem.params)
    lbg: np.ndarray  # (ng,) the row bounds: the terminal rows free while the terminal is soft
    ubg: np.ndarray  # (ng,)
    soft: bool  # the terminal is a penalty in the objective, not rows
    hole_scale: float  # 0: the holes relaxed (HoleSchedule.RELAXED_FIRST's first NLP), 1: enforced
    loose: bool  # not the last NLP: solved to the looser tolerances of _run


def _check_schedules(problem: Problem, options: SolveOptions) -> None:
    """InputError for per-NLP schedules the problem has no parameter for (they were silently ignored)."""
    for name in ("an_schedule", "at_schedule"):
        if getattr(options, name) is not None and not problem.options.aux_continuation:
            raise InputError(f"SolveOptions.{name} needs a problem built with ProblemOptions(aux_continuation=True)")
    if options.l1_schedule is not None and problem.options.penalty is not Penalty.LINF:
        raise InputError("SolveOptions.l1_schedule adds an l1 sum to Penalty.LINF's slack; the problem's penalty is "
                         f"{problem.options.penalty.value} (leave l1_schedule out)")


def homotopy_nlp(problem: Problem, options: SolveOptions, i: int, rhos: list[float] | None = None) -> HomotopyNlp:
    """NLP i (0-based) of solve()'s homotopy over `rhos` (default homotopy_rhos): its penalty, the
    holes relaxed or enforced, the terminal soft or hard, and the per-NLP schedules of `options`
    (an_schedule, at_schedule, l1_schedule, rho_f_schedule; a schedule shorter than the homotopy keeps
    its last value)."""
    _check_schedules(problem, options)
    rhos = homotopy_rhos(problem, options) if rhos is None else rhos
    i = plain(i)  # a loop's np.int64
    if not (isinstance(i, int) and not isinstance(i, bool) and 0 <= i < len(rhos)):
        raise InputError(f"homotopy_nlp's i = {i!r} is not allowed; the homotopy has NLPs 0 .. {len(rhos) - 1}")

    def sched(values, default):
        return default if not values else float(values[min(i, len(values) - 1)])

    hole_scale = 0.0 if (options.holes is HoleSchedule.RELAXED_FIRST and i == 0 and len(rhos) > 1) else 1.0
    soft = i < options.soft_terminal_nlps
    lbg, ubg = problem.lbg, problem.ubg
    if soft:
        rows = _terminal_rows(problem)
        lbg, ubg = lbg.copy(), ubg.copy()
        lbg[rows], ubg[rows] = -np.inf, np.inf
    p = problem.params(rhos[i], hole_scale, sched(options.an_schedule, 1.0), sched(options.at_schedule, 1.0),
                       options.soft_terminal_weight if soft else 0.0, sched(options.l1_schedule, 0.0),
                       sched(options.rho_f_schedule, 1.0))
    return HomotopyNlp(f"homotopy {i + 1}", p, lbg, ubg, soft, hole_scale, loose=i < len(rhos) - 1)


def _check_bounds(problem: Problem) -> None:
    """InputError naming the first bad entry of lbx/ubx (nx,) or lbg/ubg (ng,): another size, NaN, lower above upper, or
    a lower bound of +inf (upper -inf). CasADi's assertion on an edited Problem's bounds came out as a traceback."""
    names = {"x": problem.var_names, "g": None}
    for kind, n in (("x", problem.nx), ("g", problem.ng)):
        lower, upper = (real_array(getattr(problem, f"{side}{kind}"), f"problem.{side}{kind} ({n} numbers)").ravel()
                        for side in ("lb", "ub"))
        for side, bound in (("lb", lower), ("ub", upper)):
            if bound.size != n:
                raise InputError(f"problem.{side}{kind} has {bound.size} entries, the problem {n}")
        bad = np.isnan(lower) | np.isnan(upper) | (lower > upper) | (lower == np.inf) | (upper == -np.inf)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            what = f"{names[kind][i]}, entry {i}" if names[kind] else f"entry {i}"
            raise InputError(f"problem.lb{kind}/ub{kind} at {what}: [{lower[i]:g}, {upper[i]:g}] is no interval (a "
                             "NaN, lower above upper, or an infinite bound on the wrong side)")
        # as float vectors: a tuple (no .copy()) or a (1, nx) array (2-D indexing) passed here, then broke the polish
        setattr(problem, f"lb{kind}", lower)
        setattr(problem, f"ub{kind}", upper)


def solve(problem: Problem, options: SolveOptions = SolveOptions(), progress: Progress | None = None) -> PlanResult:
    """Run the homotopy (and the polishing NLP) on `problem`; returns a PlanResult.

    progress(record) is called after every NLP with its NlpRecord (rho, objective, complementarity
    residual, IPOPT iterations, wall time, IPOPT status). A failed solve is not an exception: the
    result has stats.converged = False and a message saying what failed. glibc's malloc keeps freed memory
    while it runs (freed_memory_kept).
    """
    with freed_memory_kept():
        return _solve(problem, options, progress)


def _static_start(problem: Problem) -> np.ndarray:
    """problem.x0 (nx,), the hint-free start, with u at every step at problem.static_controls and the step's algebraic
    variables guessed with it (a copy); an InputError for another start (a plan: --init), which has its own u, and
    for FESD, whose stages this does not guess."""
    if problem.fesd is not None:
        raise InputError("SolveOptions.start_controls = static applies to discretization implicit_euler only; leave it "
                         "at zero with fesd")
    if not np.array_equal(problem.x0, problem.notes.get("hint_free_x0")):
        raise InputError("SolveOptions.start_controls = static replaces the u of the hint-free start, but this "
                         "problem starts from another point (a plan, e.g. planner plan --init); leave start_controls "
                         "at zero there")
    u, _ = static_controls(problem)
    x0, blocks = problem.x0.copy(), problem.var_blocks
    x0[blocks["u"]] = u
    x0[blocks["w"]] = problem.builder.guess(problem.y0, u)
    if "s_c" in blocks:  # the slack at the largest product of the new guess, as build_problem sets it
        scaled = np.asarray(problem.products(x0), float).ravel() / problem.pair_scale
        x0[blocks["s_c"]] = float(np.max(scaled, initial=0.0))
    return x0


def _solve(problem: Problem, options: SolveOptions, progress: Progress | None) -> PlanResult:
    """solve()'s work."""
    expect(problem, Problem, "solve's problem")
    expect(options, SolveOptions, "solve's options")
    problem.check_solvable()
    if progress is not None and not callable(progress):  # it raised TypeError after NLP 1, its work lost
        raise InputError(f"solve's progress must be a function of an NlpRecord or None, got {type(progress).__name__}")
    start = problem.point(problem.x0)  # a start of another size (replace(problem, x0=...)) broke numpy broadcasting
    if not np.all(np.isfinite(start)):  # it ran the whole homotopy on NaN (IPOPT's Invalid_Number_Detected, 8 NLPs)
        bad = int(np.flatnonzero(~np.isfinite(start))[0])
        raise InputError(f"problem.x0 holds NaN or inf (first at {problem.var_names[bad]}, entry {bad}): a start "
                         "must be finite")
    problem.x0 = start  # (nx,) floats, whatever sequence the caller put there
    _check_bounds(problem)
    _check_schedules(problem, options)
    if problem.fesd is not None and options.polish is Polish.HYBRID:
        # its ratio test reads one selector's own multipliers; a FESD selector also pairs with its element's
        raise InputError("SolveOptions.polish = hybrid is not allowed with discretization fesd; it must be one of ['none', 'active_set']")
    if problem.fesd is not None and options.fesd_start is FESDStart.IMPLICIT_EULER:
        return _solve_through_implicit_euler(problem, options, progress)
    if options.fesd_start is not FESDStart.HINT_FREE:  # (accepted, ignored and recorded as done before)
        raise InputError(f"SolveOptions.fesd_start = {options.fesd_start.value} applies to discretization fesd only; "
                         "this problem is implicit Euler")
    if options.fesd_rho_schedule != SolveOptions.fesd_rho_schedule:  # (accepted and ignored before)
        raise InputError(f"SolveOptions.fesd_rho_schedule = {options.fesd_rho_schedule} applies to discretization fesd "
                         "with fesd_start implicit_euler only; this solve's penalties are rho_schedule's")
    first = _static_start(problem) if options.start_controls is ControlStart.STATIC else problem.x0.copy()
    start = time.perf_counter()
    hom = problem.task.plan.homotopy
    solvers = _Solvers(problem, options)
    x, lam_x, lam_g = first, None, None
    records: list[NlpRecord] = []
    starts = []  # (x, lam_x, lam_g, label) of the last homotopy NLPs, the latest first
    timings = {"build_s": problem.build_time_s}
    rhos = homotopy_rhos(problem, options)
    scaling = options.variable_scaling or (VariableScaling.FIRST_NLP if hom.scale_variables else VariableScaling.NONE)
    if scaling is VariableScaling.START:
        solvers.set_scale(variable_scale(problem, x, stages=True))
        solvers.scale_cold = True
    held = _keep_schedule(problem, solvers, options, x, records, progress) if options.keep_schedule else None
    for i in range(len(rhos) if held is None and not options.schedule_only else 0):
        nlp = homotopy_nlp(problem, options, i, rhos)
        x_start = x
        x, lam_x, lam_g, rec = _run(problem, solvers, x, lam_x, lam_g, nlp.p, problem.lbx, problem.ubx, nlp.label, nlp.lbg, nlp.ubg,
                                    loose=nlp.loose)
        if rec.status == "Invalid_Number_Detected" and rec.iterations == 0 and i == 0:
            # IPOPT cannot leave the task's start where the NLP is not finite, nor can the NLPs after it:
            # rho_f_schedule [1e308] ran 15 more NLPs and the retry on inf and NaN (100 s, 14084 iterations) before
            # failing "out of reach". (A later NLP starts at an earlier one's iterate, which may go on from elsewhere.)
            _refuse_not_finite(problem, x_start, nlp)
        records.append(rec)
        if progress:
            progress(rec)
        if i == 0 and scaling is VariableScaling.FIRST_NLP:
            solvers.set_scale(variable_scale(problem, x))
        starts = ([(x, lam_x, lam_g, rec.label)] + starts)[: options.polish_starts]
        if (options.early_stop_comp is not None and not nlp.soft and nlp.hole_scale == 1.0 and rec.success
                and rec.complementarity_residual <= options.early_stop_comp):
            break  # a larger rho cannot improve a point whose products are already ~0: IPOPT would only wander off and back
    homotopy_ok = all(r.success for r in records if r.label.startswith("homotopy"))
    source = None  # the label of the polishing NLP whose point x becomes (None: x stays the homotopy's)
    if held is not None:
        x, source = held, "schedule"
    elif options.polish is not Polish.NONE and (homotopy_ok or options.polish_after_failure):
        for x_start, lam_x, lam_g, start_label in starts:
            if scaling is VariableScaling.START and problem.fesd is not None:
                # the projection measures its distance in x / D: D from the point it starts from, not from the mapped
                # implicit-Euler start (Capler N = 50: 2265 iterations with the start's D, 65 with this one)
                solvers.set_scale(variable_scale(problem, x_start, stages=True))
            label = "polish" if start_label == starts[0][3] else f"polish from {start_label}"
            accepted = _polish(problem, solvers, options, x_start, lam_x, lam_g, records, progress, label)
            if accepted is not None:
                (x, lam_x, lam_g), source = accepted, label
                if options.reoptimize and problem.fesd is None:
                    better = _reoptimize(problem, solvers, options, x, records, progress)
                    if better is not None:
                        x, source = better, "reoptimize"
                break
    if source is None and "gates" in problem.notes:
        x = ungate(problem, x)
    timings["solver_setup_s"] = solvers.setup_time_s
    timings["ipopt_s"] = sum(r.time_s for r in records)
    stats_t = _ipopt_timing(solvers)
    timings.update(stats_t)
    # the homotopy's own point (no polish) is within IPOPT's default bound relaxation, 1e-8 of each scaled variable
    relaxed = 1e-8 * solvers.scale if source is None and solvers.scale is not None else None
    result = _result(problem, options, x, records, source, time.perf_counter() - start, timings, relaxed)
    result = replace(result, extra={
        **result.extra,
        "_x": x,  # the NLP solution (trajectory.npz's nlp_x, for planner plan --init; not in the summary)
        "_signature": problem.signature,
        "_task": problem.task,  # trajectory.npz's task_json
        # the task's cost at the returned plan (the projection polish's own objective is a distance)
        "control_cost": float(problem.objective_parts["control"](x, problem.params(0.0, 1.0))),
        "scene": problem.skips.to_json()})  # what the scene analysis left out, and why (summary.json)
    if (not result.stats.converged and options.retry_terminal_weight is not None and options.soft_terminal_nlps >= 1
            and any(r.status == "Infeasible_Problem_Detected" for r in records)):
        del solvers  # (its IPOPTs, ~90 MB at Capler's N = 125, stayed alive through the retry's own)
        return _retry(problem, options, result, progress)
    return result


# IPOPT settings of the FESD NLPs that start from the mapped implicit-Euler plan (Capler N = 50 with holes,
# docs/formulation.md "FESD in the OCP"): with the defaults (adaptive barrier from mu 0.1, bound push 1e-2)
# the barrier rose to 10^3.6 and NLP 1 crawled with steps of 1e-4 for > 12 min; a monotone barrier from 1e-3,
# a start kept next to the mapped point and the variables scaled by the mapped point's magnitudes
# (VariableScaling.START: selectors 1, multipliers and accelerations up to ~1e3) made it feasible and
# descend, still too slowly to converge in 3000 iterations (complementarity 0.11 at rho 1e4)
FESD_FROM_EULER_IPOPT = dict(mu_strategy=MuStrategy.MONOTONE, mu_init=1e-3, bound_push=1e-4, bound_frac=1e-4,
                             variable_scaling=VariableScaling.START)


def _solve_through_implicit_euler(problem: Problem, options: SolveOptions, progress: Progress | None) -> PlanResult:
    """FESDStart.IMPLICIT_EULER: solve the implicit-Euler OCP of the same task, grid and formulation options
    from its hint-free start (with `options`: its rho schedule, scaling, polish), map its plan onto the FESD
    variables (fesd_start_from_implicit_euler) and solve the FESD problem from there over
    options.fesd_rho_schedule with the holes and the hard terminal enforced from the first NLP on (the
    start already keeps them), then polish. Returns the FESD PlanResult; its NLP records start with the
    implicit-Euler ones (labelled "implicit Euler: ..."), and iterations and solve time count both."""
    from .discretization import Discretization, FESDOptions
    from .problem import build_problem, fesd_start_from_implicit_euler

    start = time.perf_counter()
    euler_options = replace(problem.options, discretization=Discretization.IMPLICIT_EULER, fesd=FESDOptions())
    euler = build_problem(problem.robot, problem.task, euler_options, dynamics=problem.system.dyn)

    def euler_progress(rec):
        if progress:
            progress(replace(rec, label=f"implicit Euler: {rec.label}"))

    # reoptimize off: the FESD NLPs start from the polished plan, as measured (docs/formulation.md)
    done = SolveOptions.fesd_rho_schedule  # (read here: the inner solves refuse any other)
    first = solve(euler, replace(options, fesd_start=FESDStart.HINT_FREE, reoptimize=False, fesd_rho_schedule=done),
                  euler_progress)
    x0 = fesd_start_from_implicit_euler(problem, euler, first.extra["_x"])
    fesd_options = replace(options, fesd_start=FESDStart.HINT_FREE, rho_schedule=options.fesd_rho_schedule,
                           **{k: getattr(SolveOptions, k) for k in _TASK_RHO_FIELDS},  # (read by the Euler stage)
                           fesd_rho_schedule=done, holes=HoleSchedule.ENFORCED, soft_terminal_nlps=0,
                           soft_terminal_weight=SolveOptions.soft_terminal_weight,  # (the Euler stage's, read there)
                           retry_terminal_weight=None, **FESD_FROM_EULER_IPOPT)
    result = solve(replace(problem, x0=x0), fesd_options, progress)
    nlps = tuple(replace(r, label=f"implicit Euler: {r.label}") for r in first.nlps) + result.nlps
    note = (f"; from the implicit-Euler plan ({first.stats.ipopt_iterations} iterations, "
            + ("converged" if first.stats.converged else f"not converged: {first.stats.message}") + ")")
    stats = replace(result.stats, message=result.stats.message + note, n_nlp=len(nlps), solve_time_s=time.perf_counter() - start,
                    ipopt_iterations=first.stats.ipopt_iterations + result.stats.ipopt_iterations)
    timings = dict(result.timings, implicit_euler_s=first.stats.solve_time_s, implicit_euler_build_s=euler.build_time_s)
    implicit_euler = {"converged": first.stats.converged, "ipopt_iterations": first.stats.ipopt_iterations,
                      "solve_time_s": first.stats.solve_time_s,
                      "complementarity_residual": first.stats.complementarity_residual}
    # the options the caller gave (the record said fesd_start hint_free: the inner FESD solve's own)
    recorded = {**result.options, "solve": options_record(options)}
    return replace(result, stats=stats, nlps=nlps, timings=timings, options=recorded,
                   extra={**result.extra, "implicit_euler": implicit_euler})


def _retry(problem: Problem, options: SolveOptions, first: PlanResult, progress: Progress | None) -> PlanResult:
    """SolveOptions.retry_terminal_weight: the solve once more with that soft-terminal weight. Returns the
    retry when it converged, else the first result; either way the NLPs of both attempts are recorded
    (the first attempt's labelled "try 1: ...") and the message says what happened."""
    w = options.retry_terminal_weight
    retry = solve(problem, replace(options, soft_terminal_weight=w, retry_terminal_weight=None), progress)
    tried = tuple(replace(r, label=f"try 1: {r.label}") for r in first.nlps)
    if retry.stats.converged:
        keep, note = retry, f"; after a retry with soft_terminal_weight {w:g} (try 1: {first.stats.message})"
    else:
        keep, note = first, f"; a retry with soft_terminal_weight {w:g} did not converge either ({retry.stats.message})"
    stats = replace(keep.stats, message=keep.stats.message + note, n_nlp=first.stats.n_nlp + retry.stats.n_nlp,
                    solve_time_s=first.stats.solve_time_s + retry.stats.solve_time_s,
                    ipopt_iterations=first.stats.ipopt_iterations + retry.stats.ipopt_iterations)
    nlps = tried + retry.nlps if keep is retry else first.nlps + tuple(replace(r, label=f"retry: {r.label}") for r in retry.nlps)
    return replace(keep, stats=stats, nlps=nlps)


def _held(problem, solvers, options, x0, records, progress, label, refuse=None, failed_note=""):
    """The task's cost with the contact schedule of x0 (ungated) held (SCHEDULE_IPOPT): the accepted point, or None.
    refuse(x0, x): why an accepted point x is set aside (its record's note), or ""; failed_note: the record's note
    when the point is not accepted."""
    lbx, ubx, x_held = active_set_bounds(problem, x0)
    x, _, _, rec = _run(problem, solvers, x_held, None, None, problem.params(0.0, 1.0), lbx, ubx, label, schedule=True)
    accepted = _accepted(problem, options, x, rec)
    note = (refuse(x0, x) if refuse is not None else "") if accepted else failed_note
    rec = replace(rec, note=note) if note else rec
    records.append(rec)
    if progress:
        progress(rec)
    return x if accepted and not note else None


def _held_scaled(problem, solvers, options, x0, records, progress, label, **held):
    """_held from x0 (ungated), the variables scaled by x0's own magnitudes as the replan's schedule NLP is
    (VariableScaling.START): (x0 ungated, the accepted point or None). held: _held's refuse, failed_note."""
    if "gates" in problem.notes:
        x0 = ungate(problem, x0)
    solvers.set_scale(variable_scale(problem, x0, stages=True))
    return x0, _held(problem, solvers, options, x0, records, progress, label, **held)


def _reoptimize(problem, solvers, options, x0, records, progress):
    """SolveOptions.reoptimize: the held-schedule NLP from the polished plan x0; its point if cheaper, else None.
    Its record's note says when the polished plan is kept (a failed last row read as the plan's source)."""
    f, p = _nlp_fn(problem, "f"), problem.params(0.0, 1.0)
    dearer = (lambda start, x: "" if float(f(x, p)) < float(f(start, p)) else
              "not taken: no cheaper than the polished plan, which is kept")
    return _held_scaled(problem, solvers, options, x0, records, progress, "reoptimize", refuse=dearer,
                        failed_note="not taken: the polished plan is kept")[1]


def _keep_schedule(problem, solvers, options, x0, records, progress):
    """SolveOptions.keep_schedule: the task's cost with x0's contact schedule held; the accepted point, or None."""
    if "gates" in problem.notes:
        x0 = ungate(problem, x0)
    return _held(problem, solvers, options, x0, records, progress, "schedule",
                 None if options.schedule_new_impacts else lambda start, x: _new_impacts(problem, options, start, x))


def _new_impacts(problem, options, x0, x) -> str:
    """Why the held schedule's point x adds impacts to the start x0 (both ungated), or "" when it does not."""
    # a selector strictly inside (0, 1) at x0 is not held: the biped's step 0.25 -> 0.28 m made its first step a
    # frozen impact of the stance foot that the start does not have. The schedule is kept if every impact overlaps
    # one of the start's at the same point: one may end a step later (Capler at 3.1 m: steps 95-98 -> 95-99), and one
    # may go (the N = 20 hop's start has steps 6-10 partly frozen, a stance the held schedule runs unfrozen), or is
    # a tap: below result.TAP_SHARE of the start's largest impulse. Capler's held schedule refused every target beyond
    # 3.1 m (and hole 2 moved 0.2 m) only for taps (0.3-0.8 % of its landing), whose plans are as cheap and track
    # MuJoCo as closely as the walk's; the biped's refused new impacts are full ones (4.0 N s, as its only impact)
    old = _impacts(problem, x0, options)
    largest = max((j for *_, j in old), default=0.0)
    new = [(c, a, j) for c, a, b, j in _impacts(problem, x, options)
           if not any(c == c0 and a < b0 and a0 < b for c0, a0, b0, _ in old) and j >= TAP_SHARE * largest]
    if not new:
        return ""
    said = ", ".join(f"{j:.3g} N s at {c} (step {a})" for c, a, j in new)
    return (f"set aside: it adds {len(new)} impact(s) the start does not have ({said}); --allow-new-impacts "
            "(SolveOptions.schedule_new_impacts) accepts it")


def _impacts(problem: Problem, x, options) -> list[tuple[str, int, int, float]]:
    """The plan's impacts at NLP point x as (contact point, first step, last step + 1, impulse [N s]: the norm of
    its normal and tangential parts)."""
    traj, _, _ = plan_trajectory(problem, problem.split(x), _frozen_tol(problem, options))
    return [(i.contact, round(i.tau_start / problem.h), round(i.tau_end / problem.h), i.impulse_norm)
            for i in traj.impacts]


def _frozen_tol(problem: Problem, options) -> float:
    return options.frozen_tol_several if len(problem.system.contacts) > 1 else options.frozen_tol


def _accepted(problem, options, x, rec) -> bool:
    """A polishing NLP's point stands in for the homotopy's: IPOPT converged, or its kept iterate is the point and
    complementary (an accepted polish ends the search over polish_starts, so a kept point the verdict would refuse
    must not), constraints and terminal kept."""
    kept = rec.kept_iteration is not None and problem.complementarity_residual(x) <= options.comp_tol
    return (rec.success or kept) and _feasible(problem, x, options) and rec.terminal_error <= options.terminal_tol


def _kept_projection(problem, solvers, rec):
    """A projection polish IPOPT did not finish: (x, lam_x, lam_g, record) of its iterate nearest feasibility
    (_NearestFeasible), the record's numbers that point's and kept_iteration its iteration, or None."""
    if rec.success or solvers.nearest_feasible is None or solvers.nearest_feasible.best is None:
        return None
    viol, k, x, f, lam_x, lam_g = solvers.nearest_feasible.best
    note = (f"its iterate {k} kept: IPOPT stopped short of its tolerances with the rows within {viol:.1e} of their "
            "bounds there")
    return x, lam_x, lam_g, replace(rec, objective=f, complementarity_residual=gated_complementarity(problem, x),
                                    terminal_error=terminal_error(problem, x), kept_iteration=k, note=note)


def _polish(problem, solvers, options, x, lam_x, lam_g, records, progress, label):
    """The polishing stage(s) from one homotopy point: (x, lam_x, lam_g) of the accepted polish, or None."""
    if "gates" in problem.notes:
        x = ungate(problem, x)
    if options.polish is Polish.HYBRID:
        lbx, ubx, x_fixed = active_set_bounds(problem, x, options.hybrid_ratio)
        xh, lxh, lgh, rec = _run(problem, solvers, x_fixed, lam_x, lam_g, problem.params(options.hybrid_rho, 1.0, rho_l1=0.0 if "s_c" in problem.var_blocks else options.hybrid_rho),
                                 lbx, ubx, label.replace("polish", "hybrid"))
        records.append(rec)
        if progress:
            progress(rec)
        if rec.success:
            x, lam_x, lam_g = xh, lxh, lgh
            if "gates" in problem.notes:
                x = ungate(problem, x)
    lbx, ubx, x_fixed = active_set_bounds(problem, x)
    xp, lxp, lgp, rec = _run(problem, solvers, x_fixed, lam_x, lam_g, problem.params(0.0, 1.0), lbx, ubx, label,
                             projection=options.polish_projection)
    kept = _kept_projection(problem, solvers, rec) if options.polish_projection else None
    if kept is not None and _accepted(problem, options, kept[0], kept[3]):
        xp, lxp, lgp, rec = kept
    records.append(rec)
    if progress:
        progress(rec)
    if _accepted(problem, options, xp, rec):
        return xp, lxp, lgp
    return None


def variable_scale(problem: Problem, x, stages: bool = False) -> np.ndarray:
    """D (nx,) for VariableScaling.FIRST_NLP and START (stages: FESD's stage states Y too): for each column
    of the stage blocks u, y, w (one column per variable kind: a joint's angle, a contact force, a
    selector, ...) the largest |value| over the stages at x, at least 1; 1 for every other variable
    (speeds of time, the slack, a periodic y0)."""
    x = problem.point(x)
    D = np.ones(problem.nx)
    for name in ("u", "y", "w") + (("Y",) if stages and "Y" in problem.var_blocks else ()):  # START: FESD's every stage state too
        rows = problem.var_blocks[name]
        D[rows] = np.maximum(np.abs(x[rows]).max(axis=0), 1.0)[None, :]
    return D


def task_rho_schedule(hom, rho_min: float | None = None, rho_max: float | None = None,
                      refine: tuple[float, ...] = ()) -> list[float]:
    """rho0 kappa^i for i < n_nlp, continued while <= rho_max, without the values below rho_min
    (at least the last one is kept); each value of `refine` inside that range is sorted in."""
    def too_many(count: str) -> InputError:
        return InputError(f"rho_min, rho_max = {rho_min!r}, {rho_max!r} with the task's rho0 = {hom.rho0!r} and kappa = "
                          f"{hom.kappa!r} schedule {count} NLPs, more than {MAX_NLPS}; raise plan.homotopy.kappa or narrow "
                          "[rho_min, rho_max]")

    if rho_max is not None and hom.rho0 > rho_max:  # (1e200 ran 3000 iterations to objective -1e192, "out of reach")
        raise InputError(f"the task's plan.homotopy.rho0 = {hom.rho0!r} is above rho_max = {rho_max!r}, the largest "
                         "penalty the homotopy goes to; lower rho0 (or raise SolveOptions.rho_max, `--solve "
                         "'{\"rho_max\": ...}'`: 1e6 by default, 1e5 for `planner plan --discretization fesd`)")
    rhos = [hom.rho0 * hom.kappa**i for i in range(hom.n_nlp)]
    if rho_max is not None and hom.kappa > 1:
        # counted before listed: kappa = 1.0001 continued the schedule to 92109 NLPs, and rho0 = 1e-300 with kappa =
        # 1 + 1e-7 would list 7e9 penalties below rho_min before dropping them
        def span(low: float) -> float:
            return math.log(max(rho_max / low, 1.0)) / math.log(hom.kappa)

        if span(max(hom.rho0, rho_min or 0.0)) > MAX_NLPS + 1 or span(hom.rho0) > 1e6:
            raise too_many(f"about {span(max(hom.rho0, rho_min or 0.0)):.3g}")
        while rhos[-1] * hom.kappa <= rho_max * (1 + 1e-12):
            rhos.append(rhos[-1] * hom.kappa)
    if rho_min is not None:
        rhos = [r for r in rhos if r >= rho_min * (1 - 1e-12)] or rhos[-1:]
    inside = [r for r in refine if rhos[0] < r < rhos[-1] and all(abs(r - x) > 1e-9 * x for x in rhos)]
    rhos = sorted(rhos + inside)
    if len(rhos) > MAX_NLPS:
        raise too_many(str(len(rhos)))
    return rhos


def _run(problem, solvers, x0, lam_x, lam_g, p, lbx, ubx, label, lbg=None, ubg=None, projection=False, loose=False, schedule=False):
    warm = lam_x is not None
    scaled = solvers.sees_scale(warm, schedule, projection)
    solver = solvers.projection() if projection else solvers.get(warm, loose, schedule)
    D = solvers.scale if scaled else np.ones(problem.nx)
    if projection:
        lam_x, lam_g, warm = None, None, False
        p = np.concatenate([np.asarray(x0, float) / D, p])
    k = len(p) - problem.p.numel()  # the projection's p starts with its reference point
    rho, hole_scale = float(p[k]), float(p[k + 1])
    lbg = problem.lbg if lbg is None else lbg
    ubg = problem.ubg if ubg is None else ubg
    if projection:
        solvers.nearest_feasible.reset(lbg, ubg, D, min(solvers.options.constraint_tol, solvers.options.terminal_tol))
    args = {"x0": np.asarray(x0, float) / D, "p": p, "lbx": lbx / D, "ubx": ubx / D, "lbg": lbg, "ubg": ubg}
    if warm:
        args.update(lam_x0=np.asarray(lam_x, float) * D, lam_g0=lam_g)
    n_probe = 0 if projection else solvers.n_probe
    if n_probe:  # the probe is free, starts at 0 and is dropped from the solution
        pad = np.zeros(n_probe)
        for key, value in (("x0", pad), ("lbx", pad - np.inf), ("ubx", pad + np.inf), ("lam_x0", pad)):
            if key in args:
                args[key] = np.concatenate([args[key], value])
    t0 = time.perf_counter()
    with interruptible():
        sol = solver(**args)
    wall = time.perf_counter() - t0
    st = solver.stats()
    if st.get("return_status") == "Invalid_Option":  # e.g. an HSL solver without its library: no iterate, no counts
        raise InputError(f"IPOPT rejected its options in {label} (Invalid_Option): an option needs a library this "
                         f"install lacks, e.g. linear_solver {solvers.options.linear_solver!r} (the CasADi wheel ships "
                         "'mumps' and 'spral') or HSL's MC19 (linear_system_scaling 'mc19'); its log says which "
                         "(print_level 5)")
    solvers.add_evals(solver.name(), st)
    if n_probe:
        sol = dict(sol, x=sol["x"][: problem.nx], lam_x=sol["lam_x"][: problem.nx])
    x = np.asarray(sol["x"], float).ravel() * D
    rec = NlpRecord(label=label, rho=float(rho), hole_scale=float(hole_scale), objective=float(sol["f"]),
                    complementarity_residual=gated_complementarity(problem, x), iterations=int(st.get("iter_count", 0)),
                    time_s=wall, status=str(st.get("return_status", "")), success=bool(st.get("success", False)),
                    terminal_error=terminal_error(problem, x))
    return x, np.asarray(sol["lam_x"], float).ravel() / D, np.asarray(sol["lam_g"], float).ravel(), rec


# a last NLP's gated complementarity below this share of the verdict's (all pairs) is explained in the message; at
# equal numbers (one ulp apart) the note would explain nothing
GATED_GAP = 0.99


def gated_complementarity(problem: Problem, x) -> float:
    """An NLP point's complementarity as its record reports it: with gating the largest gated product
    (what the l_inf slack bounds), else problem.complementarity_residual. Not |.|: a gate IPOPT left at
    -1e-8 (its bound relaxation) times a 1e6 multiplier of a switched-off pair is a negative product
    that ungate removes."""
    gp = problem.notes.get("gated_products")
    return float(np.max(np.asarray(gp(x), float), initial=0.0)) if gp is not None else problem.complementarity_residual(x)


def _ipopt_timing(solvers) -> dict:
    """Where IPOPT's time went in the NLP callbacks: "ipopt_evals_s" = {IPOPT's name: {callback: wall s}}, summed
    over every call of that IPOPT in the solve (a re-scaled IPOPT of the same name adds to the same entry)."""
    # CasADi 3.8 reports per-callback times only (no t_wall_total): the NLP records carry each call's wall time
    return {"ipopt_evals_s": {name: dict(v) for name, v in solvers.eval_s.items()}}


# a gate (the factor a gated pair's product carries) at or below this leaves its selector without effect on
# F: ungate resets such selectors, and active_set_bounds leaves FESD cross pairs with such gates free
GATE_OFF = 1e-6


def ungate(problem: Problem, x, tol: float = GATE_OFF) -> np.ndarray:
    """ProblemOptions.gating: at every step whose gate of a selector is <= tol (the selector does not
    act on F there), reset that selector and its multipliers to theta(h) of the step's own switching
    value h = lambda1 - lambda0 (stationarity) and recompute the lifted products. The state trajectory
    and every equality constraint stay as they are; only irrelevant algebraic variables change."""
    x = problem.point(x).copy()
    gates = np.asarray(problem.notes["gates"](x), float).ravel()
    b = problem.builder
    n = problem.system.n_sigma
    stages = problem.var_blocks["w"].reshape(-1, b.nw)  # implicit Euler: the N steps; FESD: every stage
    for k in range(len(stages)):
        wk = stages[k]
        w = x[wk]
        sig, l0, l1 = w[b.w_blocks["sigma"]].copy(), w[b.w_blocks["lambda0"]].copy(), w[b.w_blocks["lambda1"]].copy()
        g = gates[k * 2 * n : k * 2 * n + n]
        changed = False
        for i in range(n):
            if g[i] <= tol:
                hv = l1[i] - l0[i]
                sig[i] = 1.0 if hv > 0 else 0.0 if hv < 0 else np.clip(sig[i], 0.0, 1.0)
                l1[i], l0[i] = max(hv, 0.0), max(-hv, 0.0)
                changed = True
        if changed:
            forces = w[b.w_blocks["forces"]] if "forces" in b.w_blocks else None
            x[wk] = b.w_from(sig, l0, l1, forces)
    return x


def active_set_bounds(problem: Problem, x, ratio: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bounds that fix the smaller side of every complementarity pair to zero (module docstring),
    the l_inf slack to 0, and x clipped into them. Returns (lbx, ubx, x). With `ratio`, a selector's
    pairs are fixed only when clearly separated (the kept side >= ratio x the fixed side, or both
    multipliers below 1e-8 for an interior selector); the others stay free (Polish.HYBRID)."""
    x = problem.point(x)
    lbx, ubx = problem.lbx.copy(), problem.ubx.copy()
    sig, l0, l1 = (problem.var_blocks[b] for b in ("sigma", "lambda0", "lambda1"))
    fesd_gates = None
    if problem.fesd is not None:
        fesd_gates = np.asarray(problem.notes["pair_gates"](x), float).ravel() if "pair_gates" in problem.notes else np.ones(len(problem.pairs))
    # the FESD pairs the rules below impose: own-stage ones and the cross pairs the gates leave on
    imposed = [own or gate > GATE_OFF for own, gate in zip(problem.notes["own_pairs"], fesd_gates)] if fesd_gates is not None else []
    side0, side1 = x[l0.ravel()], x[l1.ravel()]  # what a selector is compared with: its own multipliers, ...
    if fesd_gates is not None and ratio is None:
        # ... and with FESD every multiplier of its element it is paired with (cross-complementarity, the pairs
        # imposed below): a selector at 1 whose left boundary's lambda1 is 4.2 (n^T v > 0 there, no switch)
        # but whose own lambda1 is ~1e-7 was left free, and the cross rule then zeroed that lambda1 = 4.2,
        # a stationarity row 4.2 off at the polish start (Capler N = 50, docs/formulation.md)
        pos = {int(js): m for m, js in enumerate(sig.ravel())}
        for pr, on in zip(problem.pairs, imposed):
            if on:
                side = side1 if pr.b_upper else side0
                side[pos[pr.b]] = max(side[pos[pr.b]], x[pr.a])
    for js, j0, j1, a0, a1 in zip(sig.ravel(), l0.ravel(), l1.ravel(), side0, side1):
        s = x[js]  # the sides are compared in the problem's own (scaled) units: the products the penalty saw
        if ratio is not None:
            lo_ok = x[j0] >= ratio * s and x[j1] <= 1e-8 and s <= 0.5
            hi_ok = x[j1] >= ratio * (1.0 - s) and x[j0] <= 1e-8 and s > 0.5
            mid_ok = x[j0] <= 1e-8 and x[j1] <= 1e-8 and 1e-3 < s < 1 - 1e-3
            if not (lo_ok or hi_ok or mid_ok):
                continue
        if a0 >= s and s <= 0.5:
            lbx[js] = ubx[js] = 0.0
            lbx[j1] = ubx[j1] = 0.0
        elif a1 >= 1.0 - s and s > 0.5:
            lbx[js] = ubx[js] = 1.0
            lbx[j0] = ubx[j0] = 0.0
        else:
            lbx[j0] = ubx[j0] = lbx[j1] = ubx[j1] = 0.0
    if problem.fesd is not None:
        # cross-complementarity: a multiplier at any point of an element is fixed to zero unless the
        # selector it pairs with is fixed at that multiplier's bound (the rule above is its own-stage case)
        for pr, on in zip(problem.pairs, imposed):
            held = lbx[pr.b] == ubx[pr.b] == (1.0 if pr.b_upper else 0.0)
            if on and not held:  # a cross pair of a selector the gates switch off is not imposed
                lbx[pr.a] = ubx[pr.a] = 0.0
    if "s_c" in problem.var_blocks and ratio is None:  # the hybrid stage keeps the l_inf slack for its free pairs
        j = problem.var_blocks["s_c"][0]
        lbx[j] = ubx[j] = 0.0
        if "s_c_step" in problem.var_blocks:  # FESD: the step slacks under s_c
            lbx[problem.var_blocks["s_c_step"]] = ubx[problem.var_blocks["s_c_step"]] = 0.0
    return lbx, ubx, np.clip(x, lbx, ubx)


def terminal_error(problem: Problem, x) -> float:
    """The terminal rows' (q, and v when imposed) largest distance outside [lbg, ubg] at x (nx,) [m, rad, m/s, rad/s]:
    max |terminal residual| for the built rows (lbg = ubg = the target)."""
    g_fn = _nlp_fn(problem, "g")
    g = np.asarray(g_fn(problem.point(x), problem.params(0.0, 1.0)), float).ravel()
    rows = _terminal_rows(problem)
    # the distance outside [lbg, ubg]: an edited row's range (or a freed row) is met anywhere inside it
    return float(np.max(np.maximum(problem.lbg[rows] - g[rows], g[rows] - problem.ubg[rows]), initial=0.0))


def _terminal_rows(problem: Problem) -> np.ndarray:
    """The rows of g the soft terminal relaxes and the terminal error measures: "terminal", or for a
    periodic task (plan.periodic) the "periodic" rows (q_N - S q_0 - shift, v_N - S v_0)."""
    return (problem.g_blocks["terminal"] if "terminal" in problem.g_blocks else problem.g_blocks["periodic"]).ravel()


def _first_not_finite(m: ca.DM) -> tuple[int, int] | None:
    """(row, column) of the first NaN or inf among the stored entries of m (a sparse matrix), or None."""
    bad = np.flatnonzero(~np.isfinite(np.asarray(m.nonzeros(), float)))
    if not bad.size:
        return None
    rows, cols = m.sparsity().get_triplet()
    return int(rows[bad[0]]), int(cols[bad[0]])


def _refuse_not_finite(problem: Problem, x, nlp: HomotopyNlp) -> None:
    """InputError for homotopy NLP `nlp`, which IPOPT could not evaluate at its start x (nx,), naming what: its
    objective's value, gradient or Hessian, or a constraint block's value or Jacobian, that holds NaN or inf there;
    else IPOPT's own derivatives, evaluated at the start pushed inside the bounds and scaled (rho_f_schedule [3e307]:
    IPOPT's Hessian of the Lagrangian was NaN where this one's is finite, 6e307)."""
    f, g = problem.f, problem.g
    fn = ca.Function("finite_at_start", [problem.x, problem.p],
                     [f, ca.gradient(f, problem.x), ca.hessian(f, problem.x)[0], g, ca.jacobian(g, problem.x)])
    block = {int(r): name for name, rows in problem.g_blocks.items() for r in np.ravel(rows)}
    names = problem.var_names
    what = ""
    kinds = ("objective", "objective's gradient", "objective's Hessian", "constraint", "constraint Jacobian")
    for kind, m in zip(kinds, fn(problem.point(x), nlp.p)):
        at = _first_not_finite(m)
        if at is None:
            continue
        row, col = at
        if kind.startswith("constraint"):
            what = f"the {kind} of the {block.get(row, 'unnamed')} rows (row {row}" + (
                f", by {names[col]})" if kind.endswith("Jacobian") else ")")
        else:
            what = f"the {kind}" + ("" if kind == "objective" else f" (at {names[row]}" + (
                f", {names[col]})" if kind.endswith("Hessian") else ")"))
        break
    if not what:
        what = "IPOPT's own derivatives (its Hessian of the Lagrangian, at the start pushed inside the bounds)"
    p = dict(zip(PARAMETERS, np.asarray(nlp.p, float).ravel()))
    raise InputError(
        f"{nlp.label}'s NLP is not finite at its start: {what} is NaN or inf there, so IPOPT stopped "
        "(Invalid_Number_Detected) and so would every NLP after it. A weight too large for double precision "
        f"overflows with what it multiplies; this NLP's are rho {p['rho']:g}, plan.rho_f {problem.task.plan.rho_f:g} "
        f"times rho_f_schedule {p['rho_f_scale']:g}, soft_terminal_weight {p['terminal_weight']:g}, l1_schedule "
        f"{p['rho_l1']:g}: lower the one that is too large")


def _nlp_fn(problem: Problem, name: str):
    """The NLP's objective ("f") or constraints ("g") as a Function of (x, p), built once per expression (an edited
    problem's f or g, or a dataclasses.replace variant's, which shares the notes, gets its own)."""
    key, expr = f"{name}_fn", getattr(problem, name)
    if key not in problem.notes or problem.notes[key][0] is not expr:
        problem.notes[key] = (expr, ca.Function(name, [problem.x, problem.p], [expr]))
    return problem.notes[key][1]


def constraint_violation(problem: Problem, x, hole_scale: float = 1.0) -> dict[str, float]:
    """Largest violation [constraint units] of each constraint block and of the bounds at x (nx,)."""
    x = problem.point(x)
    g = np.asarray(_nlp_fn(problem, "g")(x, problem.params(0.0, hole_scale)), float).ravel()
    viol = np.maximum(problem.lbg - g, 0.0) + np.maximum(g - problem.ubg, 0.0)
    out = {name: float(np.max(viol[rows.ravel()], initial=0.0)) for name, rows in problem.g_blocks.items() if name != "penalty"}
    out["bounds"] = float(np.max(np.maximum(problem.lbx - x, 0.0) + np.maximum(x - problem.ubx, 0.0), initial=0.0))
    return out


def _within_relaxation(problem: Problem, x, relaxed: np.ndarray, tol: float) -> bool:
    """Whether x breaks no bound by more than relaxed (nx,) times max(1, |bound|) plus tol: IPOPT's bound_relax_factor."""
    x = problem.point(x)
    lo = problem.lbx - relaxed * np.maximum(1.0, np.abs(np.nan_to_num(problem.lbx, posinf=0.0, neginf=0.0)))
    hi = problem.ubx + relaxed * np.maximum(1.0, np.abs(np.nan_to_num(problem.ubx, posinf=0.0, neginf=0.0)))
    return bool(np.all(x >= lo - tol) and np.all(x <= hi + tol))


def _feasible(problem, x, options) -> bool:
    viol = constraint_violation(problem, x)
    return max(viol.values()) <= options.constraint_tol


def _result(problem: Problem, options: SolveOptions, x, records, source: str | None, wall, timings,
            relaxed: np.ndarray | None = None) -> PlanResult:
    """source: the label of the polishing NLP whose point x is (None: x is the homotopy's last point). relaxed (nx,):
    by how much IPOPT relaxed each variable's bounds for x (the message says when a bound's violation is that)."""
    polished = source is not None
    frozen_tol = _frozen_tol(problem, options)
    traj, elements, b = plan_trajectory(problem, problem.split(x), frozen_tol)
    W, nodes = elements[3][:, -1], elements[1]  # each interval's end's algebraic variables (K, nw), the nodes (K+1, ny)
    # (the plan's cone rows bound the persistent forces only: a sliding step's auxiliary braking went unreported)
    braked = braked_outside_cone(problem.system, problem.builder, elements, b, frozen_tol, traj)
    comp = problem.complementarity_residual(x)
    term = terminal_error(problem, x)
    viol = constraint_violation(problem, x)
    # polishing stages are accepted only on success (or a projection's kept iterate)
    homotopy = [r for r in records if r.label.startswith("homotopy")]
    last = next(r for r in reversed(records) if r.label == source) if polished else (homotopy or records)[-1]
    reasons = []
    if not (polished or homotopy):  # SolveOptions.schedule_only: x is the start, not a plan of this task
        reasons.append("the held-schedule NLP was not accepted")
    if not (last.success or last.kept_iteration is not None):
        reasons.append(f"IPOPT did not converge in {last.label} ({last.status})")
    if comp > options.comp_tol:
        reasons.append(f"complementarity residual {comp:.3g} > {options.comp_tol:g}")
        # the table's row of the same point reads otherwise (below the tolerance, or 2.9e-02 against 6.9e+00)
        if not polished and last.complementarity_residual < GATED_GAP * comp:
            reasons[-1] += (f" (of all pairs; {last.label}'s {last.complementarity_residual:.1e} is of the gated "
                            "pairs: a pair whose selector has no effect in a step's mode (alpha's in flight) is not "
                            "counted there, and only the polish makes those complementary too)")
    if term > options.terminal_tol:
        reasons.append(f"terminal error {term:.3g} > {options.terminal_tol:g}")
    worst = max(viol, key=viol.get)
    if viol[worst] > options.constraint_tol:
        reasons.append(f"constraint {worst} violated by {viol[worst]:.3g}")
        if worst == "bounds" and relaxed is not None and _within_relaxation(problem, x, relaxed, options.constraint_tol):
            # a multiplier of size D ~1e5 at -1e-3: the scaled NLP's tolerance, kept by the default path (tightening
            # it made neither race arm converge on the default Capler task, docs/benchmarks.md session 40)
            reasons[-1] += (" (within IPOPT's bound relaxation: 1e-8 of each variable as IPOPT scales it, so up to "
                            "~1e-3 in the units of a variable scaled by its size)")
    capped = [r.label for r in homotopy if not r.success and r is not last]
    converged = not reasons
    how = {"schedule": SCHEDULE_KEPT,
           "reoptimize": " (active-set polished, then re-optimized on its contact schedule)"}.get(last.label, " (active-set polished)")
    message = "ok" + (how if polished else "") if converged else "; ".join(reasons)
    if capped:
        message += f"; on the way, IPOPT stopped early in {', '.join(capped)}"
    infeasible = [r.label for r in records if r.status == "Infeasible_Problem_Detected"]
    if infeasible and not converged:  # (the failure line named the last NLP's status only)
        never = problem.skips.never_touching  # (their rows are as binding as the holes')
        message += (f"; IPOPT found {', '.join(infeasible)} locally infeasible: the target may be out of reach in the "
                    "horizon with these control bounds, holes and joint limits"
                    + (", the robot file's joint speed limits" if np.isfinite(problem.robot.v_limit).any() else "")
                    + (f", and {', '.join(never)} kept off the ground (touches = false)" if never else "")
                    + " (a local verdict: some reachable tasks end so, docs/stability.md)")
    # each contact point's gap at the nodes (K+1, n_c) [m]: the levitation's check and the hops' read them
    gaps = np.array([np.asarray(problem.system.gap_fn(y, np.zeros(problem.system.nu)), float).ravel() for y in nodes])
    floating = _levitating(problem, traj, gaps) if not converged else []
    if floating:  # (Capler with its knee a contact too failed "out of reach" with the knee holding it up 0.17 m high)
        # the field's support is also how the relaxed NLPs meet a target the robot cannot reach (Capler 30 m in 2.5 s
        # ended so, its terminal errors no larger than a converged Capler plan's): both causes are said
        message += (f"; {', '.join(floating)}: levitating on the contact field, the penalty homotopy's local minimum"
                    + ("" if infeasible else ", or the target may be out of reach in the horizon with these control "
                       "bounds, holes and joint limits, and the field's support alone meets it")
                    + ("; a point that need not touch the ground is better declared touches = false (docs/tasks.md)"
                       if len(problem.system.contacts) > 1 else ""))
    if not converged:
        message += _far_sized(problem)
    T = problem.task.horizon.physical_time
    # (physical_time = 1e-6 s failed in 35 s blaming control bounds and holes only; T = tau_f, the paper's use, is no
    # such cause)
    if not converged and T is not None and T < problem.task.horizon.tau_f:
        message += (f"; horizon.physical_time T = {T:g} s may be below the time the motion needs, which makes the "
                    "target unreachable: the speed of time s >= 1 only speeds the clock up, so a T below tau_f = "
                    f"{problem.task.horizon.tau_f:g} s is met only by frozen time (docs/tasks.md, physical_time)")
    stats = SolveStats(converged=converged, solve_time_s=wall, n_nlp=len(records), ipopt_iterations=sum(r.iterations for r in records),
                       complementarity_residual=comp, message=message)
    sig_names = [s.name for s in problem.system.switches]
    beta = W[:, problem.builder.w_blocks["sigma"]][:, [i for i, n in enumerate(sig_names) if n.startswith("beta")]]
    # each contact point's positions at the nodes (n_c, K+1, 3) [m]
    points = [np.array([np.asarray(problem.system.dyn.point_position(c.point)(y[: problem.system.nq]), float).ravel()
                        for y in nodes]) for c in problem.system.contacts]
    # the robot flies when every contact point does (one contact: its beta): so its gap is the smallest
    gap = gaps.min(axis=1, initial=np.inf)
    if converged:
        _warn_never_touching_on_plane(problem, nodes)
    # the robot's flights (every contact point in flight mode), measured on the first contact point; a one-step
    # phase along the ground is no hop
    hops = hops_of(traj, beta.min(axis=1) if beta.size else np.zeros(len(W)), points[0],
                   problem.system.contacts[0].normal, gap, problem.task.plan.holes)
    # skims and slides per contact, by its own beta and gap: a foot that slides while another stands is no flight of
    # the robot
    skims: list = []
    slides = [s for i, c in enumerate(problem.system.contacts)
              for s in slides_of(traj, beta[:, i], points[i], gaps[:, i], c.point, problem.task.plan.holes, skims)]
    skims.sort(key=lambda s: s["takeoff_time"])
    landings = []
    if len(problem.system.contacts) > 1:  # (one contact: a landing is frozen when the clock ran < 99 % of the step)
        u0 = np.zeros(problem.system.nu)
        approach = np.array([np.asarray(problem.system.normal_velocity_fn(y, u0), float).ravel() for y in nodes])
        landings = unrecorded_landings(traj, approach, gaps, elements[5], problem.system.labels)
    return PlanResult(robot=str(problem.robot.path), task=task_source(problem.task), trajectory=traj, stats=stats,
                      h=problem.h,
                      rho_f=problem.task.plan.rho_f, terminal_error=term, nlps=tuple(records), hops=tuple(hops), polished=polished,
                      constraint_violation=viol, timings=timings,
                      options={"problem": options_record(problem.options), "solve": options_record(options)},
                      robot_sha256=problem.robot.sha256,
                      # (an edited problem's plan is not the task file's alone: its readers are told)
                      extra={"braked_outside_friction_cone": braked,
                             **({"skims": skims} if skims else {}),
                             **({"slides": slides} if slides else {}),
                             **({"unrecorded_landings": landings} if landings else {}),
                             **({"joints_outside_range": outside}
                                if (outside := _outside_range(problem, traj)) else {}),
                             **({"edited_problem": list(problem.edited)} if problem.edited else {})})


def _outside_range(problem: Problem, traj: Trajectory) -> list[dict]:
    """simulate.joints_outside_range of a plan: the joints whose bounds in the NLP (plan.joint_bounds, or lbx and ubx
    edited through the Python API) are wider than the robot file's range and that left it by more than PLAN_RANGE_TOL
    (the validation failed such a plan as a tracking error alone)."""
    robot, blocks = problem.robot, problem.var_blocks
    q = np.concatenate([blocks["y"][:, : robot.nq]] + ([blocks["y0"][None, : robot.nq]] if "y0" in blocks else []))
    lower, upper = np.asarray(problem.lbx)[q].min(axis=0), np.asarray(problem.ubx)[q].max(axis=0)
    wider = {robot.dof_names[i] for i in range(robot.nq) if lower[i] < robot.q_lower[i] or upper[i] > robot.q_upper[i]}
    return [j for j in joints_outside_range(robot, traj, PLAN_RANGE_TOL) if j["joint"] in wider] if wider else []


PLAN_RANGE_TOL = 1e-6  # [m or rad] IPOPT's relaxed bounds leave a plan resting on its limit ~1e-8 past it
LEVITATION_GAP_M = 1e-3  # [m] a contact point this far off its plane holds no force in a plan
LEVITATION_N = 1e-2  # [N] a persistent contact force below this is not named


# [N] the robot's weight m g and plan.u_bound for which the homotopy's absolute weights were tuned: the shipped robots
# weigh 9.8-343 N with controls of tens of N (m); a 1000 kg point mass with its task's forces scaled failed "out of
# reach" until rho_schedule and soft_terminal_weight were scaled by 1e6 (session 70's tester)
FORCE_SCALE_RANGE_N = (0.1, 1e3)


def _far_sized(problem: Problem) -> str:
    """"; ..." pointing at docs/tasks.md's "Robots of other sizes" when the robot's weight or plan.u_bound is
    outside FORCE_SCALE_RANGE_N (a failed plan's message ends with it), else ""."""
    lo, hi = FORCE_SCALE_RANGE_N
    # (a robot without gravity weighs 0 N: no size to read; u_bound is N or N m as its joints are)
    forces = {"the robot's weight m g": (robot_weight(problem.robot) or None, "N"),
              "plan.u_bound": (problem.task.plan.u_bound, "N or N m")}
    far = [f"{name} = {value:.3g} {unit}" for name, (value, unit) in forces.items()
           if value is not None and not lo <= value <= hi]
    if not far:
        return ""
    return (f"; {' and '.join(far)} outside [{lo:g}, {hi:g}], the sizes the homotopy's absolute weights suit: "
            "scale rho_schedule, soft_terminal_weight and rho_f with the control cost (docs/tasks.md, \"Robots of "
            "other sizes\")")


def _levitating(problem: Problem, traj: Trajectory, gaps: np.ndarray) -> list[str]:
    """The contacts whose persistent normal force (traj.contact_force, step k at node k + 1) acts while they are off
    their plane (gaps (K+1, n_c) [m] at the nodes), as "knee carried up to 2.4 N while 0.17 m off its plane"."""
    if traj.contact_force is None or not len(traj.contact_force):
        return []
    gaps = np.asarray(gaps, float)[1:]
    normal = np.asarray(traj.contact_force, float)[:, :, 0]
    out = []
    for c, label in enumerate(problem.system.labels):
        held = np.where((gaps[:, c] > LEVITATION_GAP_M) & (normal[:, c] > LEVITATION_N), normal[:, c], 0.0)
        if held.any():
            k = int(np.argmax(held))
            out.append(f"{label} carried up to {normal[k, c]:.3g} N while {gaps[k, c]:.3g} m off its plane")
    return out


def plan_trajectory(problem: Problem, parts: dict, frozen_tol: float):
    """The plan's Trajectory from problem.split(x), with the intervals it was recovered from and their quadrature
    weights (plan_elements): implicit Euler's N steps, FESD's N n_fe elements less the collapsed ones."""
    elements, b = plan_elements(problem, parts)
    traj = element_trajectory(problem.system, problem.builder, *elements, b, frozen_tol,
                              switch_at_start=problem.fesd is not None)
    return traj, elements, b


def plan_elements(problem: Problem, parts: dict) -> tuple[tuple, np.ndarray]:
    """The plan's intervals as element_trajectory takes them, (tau, Y, Ys, Ws, Us, dt), and the quadrature weights b:
    implicit Euler's steps, or FESD's elements less those of length ~0 (result.COLLAPSED; the Radau quadrature of the
    auxiliary fields, impacts starting at an element boundary)."""
    if problem.fesd is None:
        return step_elements(problem.system, problem.builder, parts["Y"], parts["W"], parts["U"], problem.h,
                             parts["S"]), np.ones(1)
    fesd, ny, nw, nu = problem.fesd, problem.system.ny, problem.builder.nw, problem.system.nu
    K, n_s = problem.N * fesd.n_fe, fesd.n_s
    lengths = parts["h"].ravel()
    # an element of length ~0 (no switch pins it; IPOPT leaves it at ~1e-10 s or a hair below 0) ends where
    # it starts and carries nothing: leave it out, so that tau increases strictly (planner.view requires it)
    keep = lengths > COLLAPSED * lengths.max()
    Ys, Ws = parts["Ys"].reshape(K, n_s, ny)[keep], parts["Ws"].reshape(K, n_s, nw)[keep]
    nodes = np.vstack([parts["Y"][:1], Ys[:, -1]])
    Us = np.repeat(parts["U"], fesd.n_fe * n_s, axis=0).reshape(K, n_s, nu)[keep]  # u_k is constant over the step
    dt = (lengths * np.repeat(parts["S"], fesd.n_fe))[keep]
    tau = np.concatenate([[0.0], np.cumsum(lengths[keep])])
    return (tau, nodes, Ys, Ws, Us, dt), fesd.b


def _warn_never_touching_on_plane(problem: Problem, nodes) -> None:
    """Warn of each touches = false contact point that the plan puts on its plane (gap <= ON_PLANE_M at
    some node): its row gap >= 0 is active there, so the plan leans on a contact the task said never happens, and a
    plan with touches = true may differ (session 56's tester: a point resting on the ground all plan long, exit 0 and
    no word). The nodes are (nq + ...) states."""
    task, nq = problem.task, problem.system.nq
    for label, c in zip(contact_labels(task.contacts), task.contacts):
        if c.point not in problem.skips.never_touching:
            continue
        gaps = np.array([float(plane_gap(problem.system.dyn, c, np.asarray(y[:nq], float), task.ground_height))
                         for y in nodes])
        on = np.flatnonzero(gaps <= ON_PLANE_M)
        if on.size:
            shown_nodes = ", ".join(str(k) for k in on[:8]) + (", ..." if on.size > 8 else "")
            warnings.warn(f"contact {label!r} (touches = false) lies on its plane at {on.size} of {len(gaps)} "
                          f"nodes ({shown_nodes}; gap <= {ON_PLANE_M:g} m): the task says it never touches, "
                          "so the plan holds it there without a contact force; with touches = true the plan may "
                          "differ")

