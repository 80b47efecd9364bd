"""Solve the time-freezing OCP: an l_inf (or l1) penalty homotopy of smooth NLPs (paper Sec. 5.2).

`solve(problem, options)` creates IPOPT once for the Problem's NLP (rho and the hole scale are NLP
parameters) and solves the task's homotopy rho_i = rho0 kappa^i, i = 0 .. n_nlp-1, each NLP
warm-started from the previous one (primal x and multipliers lam_x, lam_g). Then, optionally:

* Polish.ACTIVE_SET: one more smooth NLP in which every complementarity pair has its smaller side
  fixed to zero by bounds (for a selector: sigma = 0 with lambda1 = 0, sigma = 1 with lambda0 = 0,
  or, for 0 < sigma < 1, lambda0 = lambda1 = 0) and the penalty dropped (rho = 0, s_c = 0). If that
  NLP converges, its point satisfies every complementarity condition exactly and every other
  constraint to IPOPT's tolerance; it is accepted only then (and only if it keeps the terminal and
  hole constraints), otherwise the homotopy's point stands.
* HoleSchedule.RELAXED_FIRST: the first NLP drops the holes (hole scale 0) and the later ones
  enforce them: a continuation in the scene the solver runs itself; the user gives no hint.

The result's convergence verdict: every NLP solved (IPOPT success), complementarity residual
<= options.comp_tol, terminal error <= options.terminal_tol, holes and path constraints kept to
options.constraint_tol.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from enum import Enum
from typing import Callable

import casadi as ca
import numpy as np

from .errors import InputError
from .problem import Problem
from .result import NlpRecord, PlanResult, SolveStats, hops_of
from .simulate import step_trajectory


class MuStrategy(Enum):
    ADAPTIVE = "adaptive"
    MONOTONE = "monotone"


class HoleSchedule(Enum):
    """When the holes (and other scene obstacles) are enforced during the homotopy."""

    ENFORCED = "enforced"  # from the first NLP on (faithful)
    RELAXED_FIRST = "relaxed_first"  # not in NLP 1, fully from NLP 2 on


class Polish(Enum):
    NONE = "none"
    ACTIVE_SET = "active_set"


@dataclass(frozen=True)
class SolveOptions:
    """Numerical settings of the homotopy (the homotopy's rho0, kappa, n_nlp come from the task).

    tol, acceptable_tol: IPOPT's tol and acceptable_tol; max_iter: IPOPT iterations per NLP;
    print_level: IPOPT's (0 silent, 5 the usual log); linear_solver: IPOPT's (the CasADi wheel has
    "mumps"); mu_strategy: IPOPT's barrier update; mu_init: first barrier parameter of NLP 1;
    warm_mu_init: barrier parameter the warm-started NLPs start from (None: same as mu_init; a
    small value keeps a warm start near its point); bound_push, bound_frac: how far IPOPT moves
    the initial point inside the bounds (the warm start uses the same); nlp_scaling_method:
    IPOPT's ("gradient-based" or "none"); holes: HoleSchedule; polish: Polish; polish_after_failure:
    also polish when an NLP of the homotopy failed (the verdict still reports the failure); comp_tol,
    terminal_tol [m, rad], constraint_tol: the convergence verdict's thresholds; frozen_tol: the
    recovery's relative clock deficit of a frozen step.
    """

    tol: float = 1e-8
    acceptable_tol: float = 1e-6
    max_iter: int = 3000
    print_level: int = 0
    linear_solver: str = "mumps"
    mu_strategy: MuStrategy = MuStrategy.ADAPTIVE
    mu_init: float = 0.1
    warm_mu_init: float | None = None
    bound_push: float = 0.01
    bound_frac: float = 0.01
    nlp_scaling_method: str = "gradient-based"
    holes: HoleSchedule = HoleSchedule.RELAXED_FIRST
    polish: Polish = Polish.ACTIVE_SET
    polish_after_failure: bool = False
    comp_tol: float = 1e-6
    terminal_tol: float = 1e-6
    constraint_tol: float = 1e-6
    frozen_tol: float = 1e-4

    def __post_init__(self):
        for key, enum in (("mu_strategy", MuStrategy), ("holes", HoleSchedule), ("polish", Polish)):
            if not isinstance(getattr(self, key), enum):
                raise InputError(f"SolveOptions.{key} = {getattr(self, key)!r} is not allowed; it must be one of {[e.value for e in enum]}")
        checks = [
            (self.tol > 0, "tol", self.tol, "> 0"),
            (self.acceptable_tol > 0, "acceptable_tol", self.acceptable_tol, "> 0"),
            (self.max_iter >= 1, "max_iter", self.max_iter, ">= 1"),
            (0 <= self.print_level <= 12, "print_level", self.print_level, "in 0 .. 12"),
            (self.mu_init > 0, "mu_init", self.mu_init, "> 0"),
            (self.warm_mu_init is None or self.warm_mu_init > 0, "warm_mu_init", self.warm_mu_init, "> 0 or None"),
            (0 < self.bound_push < 0.5, "bound_push", self.bound_push, "in (0, 0.5)"),
            (0 < self.bound_frac <= 0.5, "bound_frac", self.bound_frac, "in (0, 0.5]"),
            (self.nlp_scaling_method in ("gradient-based", "none", "equilibration-based"), "nlp_scaling_method",
             self.nlp_scaling_method, "gradient-based, equilibration-based or none"),
            (self.comp_tol > 0, "comp_tol", self.comp_tol, "> 0"),
            (self.terminal_tol > 0, "terminal_tol", self.terminal_tol, "> 0"),
            (self.constraint_tol > 0, "constraint_tol", self.constraint_tol, "> 0"),
            (0 < self.frozen_tol < 1, "frozen_tol", self.frozen_tol, "in (0, 1)"),
        ]
        for ok, key, value, allowed in checks:
            if not ok:
                raise InputError(f"SolveOptions.{key} = {value!r} is not allowed; it must be {allowed}")


def ipopt_options(options: SolveOptions, warm: bool) -> dict:
    """CasADi nlpsol options for IPOPT (a cold solver for NLP 1, a warm one for the rest)."""
    ip = {
        "tol": options.tol, "acceptable_tol": options.acceptable_tol, "max_iter": options.max_iter,
        "print_level": options.print_level, "sb": "yes", "linear_solver": options.linear_solver,
        "mu_strategy": options.mu_strategy.value, "mu_init": options.mu_init,
        "bound_push": options.bound_push, "bound_frac": options.bound_frac,
        "nlp_scaling_method": options.nlp_scaling_method,
    }
    if warm:
        ip.update(warm_start_init_point="yes", warm_start_bound_push=options.bound_push, warm_start_bound_frac=options.bound_frac,
                  warm_start_mult_bound_push=options.bound_push)
        if options.warm_mu_init is not None:
            ip["mu_init"] = options.warm_mu_init
    return {"print_time": False, "ipopt": ip}


Progress = Callable[[NlpRecord], None]


class _Solvers:
    """IPOPT for the problem's NLP, created on first use: cold (NLP 1) and warm (later NLPs).
    They differ only in IPOPT options that CasADi fixes at creation."""

    def __init__(self, problem: Problem, options: SolveOptions):
        self.nlp = {"x": problem.x, "p": problem.p, "f": problem.f, "g": problem.g}
        self.options, self.cache, self.setup_time_s = options, {}, 0.0

    def get(self, warm: bool):
        need_two = self.options.warm_mu_init is not None
        key = warm and need_two
        if key not in self.cache:
            t0 = time.perf_counter()
            self.cache[key] = ca.nlpsol("tf_ocp_warm" if key else "tf_ocp", "ipopt", self.nlp, ipopt_options(self.options, warm))
            self.setup_time_s += time.perf_counter() - t0
        return self.cache[key]


def solve(problem: Problem, options: SolveOptions = SolveOptions(), progress: Progress | None = None) -> PlanResult:
    """Run the homotopy (and the polishing NLP) on `problem`; returns a PlanResult.

    progress(record) is called after every NLP with its NlpRecord (rho, objective, complementarity
    residual, IPOPT iterations, wall time, IPOPT status). A failed solve is not an exception: the
    result has stats.converged = False and a message saying what failed.
    """
    start = time.perf_counter()
    hom = problem.task.plan.homotopy
    solvers = _Solvers(problem, options)
    x, lam_x, lam_g = problem.x0.copy(), None, None
    records: list[NlpRecord] = []
    timings = {"build_s": problem.build_time_s}
    for i in range(hom.n_nlp):
        rho = hom.rho0 * hom.kappa**i
        scale = 0.0 if (options.holes is HoleSchedule.RELAXED_FIRST and i == 0 and hom.n_nlp > 1) else 1.0
        x, lam_x, lam_g, rec = _run(problem, solvers, x, lam_x, lam_g, rho, scale, problem.lbx, problem.ubx, f"homotopy {i + 1}")
        records.append(rec)
        if progress:
            progress(rec)
    homotopy_ok = all(r.success for r in records)
    polished = False
    if options.polish is Polish.ACTIVE_SET and (homotopy_ok or options.polish_after_failure):
        lbx, ubx, x_fixed = active_set_bounds(problem, x)
        xp, lxp, lgp, rec = _run(problem, solvers, x_fixed, lam_x, lam_g, 0.0, 1.0, lbx, ubx, "polish")
        records.append(rec)
        if progress:
            progress(rec)
        if rec.success and _feasible(problem, xp, options) and rec.terminal_error <= options.terminal_tol:
            x, lam_x, lam_g, polished = xp, lxp, lgp, True
    timings["solver_setup_s"] = solvers.setup_time_s
    timings["ipopt_s"] = sum(r.time_s for r in records)
    stats_t = _ipopt_timing(solvers)
    timings.update(stats_t)
    result = _result(problem, options, x, records, polished, time.perf_counter() - start, timings)
    result.extra["_x"] = x  # the NLP solution, for diagnostics (not written to the summary)
    return result


def _run(problem, solvers, x0, lam_x, lam_g, rho, hole_scale, lbx, ubx, label):
    warm = lam_x is not None
    solver = solvers.get(warm)
    args = {"x0": x0, "p": problem.params(rho, hole_scale), "lbx": lbx, "ubx": ubx, "lbg": problem.lbg, "ubg": problem.ubg}
    if warm:
        args.update(lam_x0=lam_x, lam_g0=lam_g)
    t0 = time.perf_counter()
    sol = solver(**args)
    wall = time.perf_counter() - t0
    st = solver.stats()
    x = np.asarray(sol["x"], float).ravel()
    rec = NlpRecord(label=label, rho=float(rho), hole_scale=float(hole_scale), objective=float(sol["f"]),
                    complementarity_residual=problem.complementarity_residual(x), iterations=int(st.get("iter_count", 0)),
                    time_s=wall, status=str(st.get("return_status", "")), success=bool(st.get("success", False)),
                    terminal_error=terminal_error(problem, x))
    return x, np.asarray(sol["lam_x"], float).ravel(), np.asarray(sol["lam_g"], float).ravel(), rec


def _ipopt_timing(solvers) -> dict:
    """Where IPOPT's time went over the last call of each solver (function evaluations vs the rest)."""
    out = {}
    for key, s in solvers.cache.items():
        st = s.stats()
        evals = {k[len("t_wall_"):]: float(v) for k, v in st.items() if k.startswith("t_wall_") and k != "t_wall_total"}
        out["ipopt_last_call_" + ("warm" if key else "cold")] = {"total_s": float(st.get("t_wall_total", 0.0)), **evals}
    return out


def active_set_bounds(problem: Problem, x) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bounds that fix the smaller side of every complementarity pair to zero (module docstring),
    the l_inf slack to 0, and x clipped into them. Returns (lbx, ubx, x)."""
    x = np.asarray(x, float).ravel()
    lbx, ubx = problem.lbx.copy(), problem.ubx.copy()
    sig, l0, l1 = (problem.var_blocks[b] for b in ("sigma", "lambda0", "lambda1"))
    for js, j0, j1 in zip(sig.ravel(), l0.ravel(), l1.ravel()):
        s = x[js]  # the sides are compared in the problem's own (scaled) units: the products the penalty saw
        if x[j0] >= s and s <= 0.5:
            lbx[js] = ubx[js] = 0.0
            lbx[j1] = ubx[j1] = 0.0
        elif x[j1] >= 1.0 - s and s > 0.5:
            lbx[js] = ubx[js] = 1.0
            lbx[j0] = ubx[j0] = 0.0
        else:
            lbx[j0] = ubx[j0] = lbx[j1] = ubx[j1] = 0.0
    if "s_c" in problem.var_blocks:
        j = problem.var_blocks["s_c"][0]
        lbx[j] = ubx[j] = 0.0
    return lbx, ubx, np.clip(x, lbx, ubx)


def terminal_error(problem: Problem, x) -> float:
    """max |terminal residual| (q, and v when imposed) [m, rad, m/s, rad/s]."""
    g_fn = _g_fn(problem)
    g = np.asarray(g_fn(x, problem.params(0.0, 1.0)), float).ravel()
    rows = problem.g_blocks["terminal"].ravel()
    return float(np.max(np.abs(g[rows] - problem.lbg[rows])))


def _g_fn(problem: Problem):
    fn = problem.notes.get("g_fn")
    if fn is None:
        fn = problem.notes["g_fn"] = ca.Function("g", [problem.x, problem.p], [problem.g])
    return fn


def constraint_violation(problem: Problem, x, hole_scale: float = 1.0) -> dict[str, float]:
    """Largest violation [constraint units] of each constraint block and of the bounds at x."""
    g = np.asarray(_g_fn(problem)(x, problem.params(0.0, hole_scale)), float).ravel()
    viol = np.maximum(problem.lbg - g, 0.0) + np.maximum(g - problem.ubg, 0.0)
    out = {name: float(np.max(viol[rows.ravel()], initial=0.0)) for name, rows in problem.g_blocks.items() if name != "penalty"}
    x = np.asarray(x, float).ravel()
    out["bounds"] = float(np.max(np.maximum(problem.lbx - x, 0.0) + np.maximum(x - problem.ubx, 0.0), initial=0.0))
    return out


def _feasible(problem, x, options) -> bool:
    viol = constraint_violation(problem, x)
    return max(viol.values()) <= options.constraint_tol


def _result(problem: Problem, options: SolveOptions, x, records, polished, wall, timings) -> PlanResult:
    parts = problem.split(x)
    traj = step_trajectory(problem.system, problem.builder, parts["Y"], parts["W"], parts["U"], problem.h, options.frozen_tol, parts["S"])
    comp = problem.complementarity_residual(x)
    term = terminal_error(problem, x)
    viol = constraint_violation(problem, x)
    homotopy = [r for r in records if r.label != "polish"]
    failed = [r.label for r in homotopy if not r.success]
    reasons = []
    if failed:
        reasons.append(f"IPOPT did not converge in {', '.join(failed)} ({', '.join(r.status for r in homotopy if not r.success)})")
    if comp > options.comp_tol:
        reasons.append(f"complementarity residual {comp:.3g} > {options.comp_tol:g}")
    if term > options.terminal_tol:
        reasons.append(f"terminal error {term:.3g} > {options.terminal_tol:g}")
    worst = max(viol, key=viol.get)
    if viol[worst] > options.constraint_tol:
        reasons.append(f"constraint {worst} violated by {viol[worst]:.3g}")
    converged = not reasons
    message = "ok" + (" (active-set polished)" if polished else "") if converged else "; ".join(reasons)
    stats = SolveStats(converged=converged, solve_time_s=wall, n_nlp=len(records), ipopt_iterations=sum(r.iterations for r in records),
                       complementarity_residual=comp, message=message)
    sig_names = [s.name for s in problem.system.switches]
    beta = parts["W"][:, problem.builder.w_blocks["sigma"]][:, [i for i, n in enumerate(sig_names) if n.startswith("beta")]]
    contact = problem.task.contacts[0].point
    foot = np.array([np.asarray(problem.system.dyn.point_position(contact)(y[: problem.system.nq]), float).ravel() for y in parts["Y"]])
    hops = hops_of(traj, beta.max(axis=1) if beta.size else np.zeros(problem.N), foot)
    return PlanResult(robot=str(problem.robot.path), task=problem.task.source, trajectory=traj, stats=stats, h=problem.h,
                      rho_f=problem.task.plan.rho_f, terminal_error=term, nlps=tuple(records), hops=tuple(hops), polished=polished,
                      constraint_violation=viol, timings=timings,
                      options={"problem": _plain(problem.options), "solve": _plain(options)})


def _plain(opts) -> dict:
    out = {}
    for k, v in vars(opts).items():
        out[k] = v.value if isinstance(v, Enum) else [list(e) for e in v] if isinstance(v, tuple) else v
    return out
