"""Side by side with the reference implementation (issue 9): the Capler hopper OCP in nosnoc.

Solves the task of robots/capler.toml (N = 125 steps of h = 0.02 in numerical time, tau_f = 2.5,
three holes at x = 0.5, 1.5, 2.5 with half-axes 0.25 x 0.1, a_n = 200, mu = 0.8, |u| <= 60, the joint
limits, knee and base above the ground, terminal q = (3, 0.4, 0, 0) with zero velocity, cost int u^2,
Scholtes homotopy sigma = 1 -> /10 in 5 NLPs) with nosnoc (the Python package `nosnoc`, "nosnoc_py"),
set up the way its examples/hopper_robot time-freezing example is: a hand-written time-freezing
piecewise smooth system in Stewart form with the switching functions (gap, n^T v, t^T v), the eight
"dense" regions, free flight in six of them and the two auxiliary impact fields
M^-1 (a_n J_n -/+ a_t J_t) in the two with gap < 0, n^T v < 0, and no slip while an auxiliary field
is active as a path complementarity |t^T v| (theta_7 + theta_8) = 0 -- with the Capler model of
docs (robot parameters of design.md's table) instead of the example's telescopic hopper.

Two variants: `hint-free` (the paper's initialization: y0 at every node, zero controls) and `hint`
(the initial guess the example uses: a cubic spline through take-off, apex and landing of one hop
per metre, the leg tucked at the apex). For each: wall time, IPOPT iterations, complementarity
residual (ours: max over the pairs theta_i lambda_i and the no-slip pair of the product at every
stage point; nosnoc's own: max over its FESD cross-complementarity products), terminal error
max |q_N - q_target|, penetration -min foot height over the nodes, the holes metric
min over nodes and holes of ((x - xc)/a)^2 + ((z - zc)/b)^2 (>= 1: outside), IPOPT statuses.

`--planner` also runs our own planner on the same task file in the same process, as `planner plan` does
(defaults of planner.problem / planner.homotopy, its race of two solver variants on two CPUs: planner.race)
for the wall-time ratio. `--quick` uses a coarse grid (N = 25, no holes) for both. nosnoc is an optional
dependency (pip install nosnoc); it is imported in main(), not for the planner alone (`--planner --variants`).

    python -m scripts.bench_nosnoc [--quick] [--planner] [--out DIR] [--json]   (from the repository root)
"""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import os
import shlex
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from planner.errors import InputError, interruptible
from planner.result import write_atomically
from planner.task import Ellipse  # the task's hole: ((x - x_c)/a)^2 + ((z - z_c)/b)^2 >= 1
from scripts._report import machine_info, out_dir, positive_float, run_info, run_main, script_parser, utc_now

DEFAULT_OUT = Path("results/bench/nosnoc")
TASK_FILE = Path(__file__).resolve().parents[1] / "robots" / "capler.toml"
ROBOT_FILE = Path(__file__).resolve().parents[1] / "robots" / "capler.xml"
G = 9.81
SUCCESS = ("Solve_Succeeded", "Solved_To_Acceptable_Level")
HOLE_TOL = 1e-3  # the holes metric may dip this far below 1 (IPOPT's constraint tolerance and more)


# ==================================================================================================
# the task (numbers of robots/capler.toml, read here so that nosnoc's problem does not need the planner's objects)
# ==================================================================================================

@dataclass(frozen=True)
class CaplerTask:
    """The OCP of robots/capler.toml (design.md, "The paper's hopper OCP")."""

    N: int = 125
    tau_f: float = 2.5
    q0: tuple = (0.0, 0.4, 0.0, 0.0)  # (x_B, z_B, phi_hip, phi_knee)
    q_target: tuple = (3.0, 0.4, 0.0, 0.0)
    mu: float = 0.8
    a_n: float = 200.0
    a_t: float = 600.0  # the task's value; nosnoc's example ties the tangential gain to mu * a_n
    u_max: float = 60.0
    hip_bounds: tuple = (-3 * math.pi / 8, 3 * math.pi / 8)
    knee_bounds: tuple = (-math.pi / 2, math.pi / 2)
    holes: tuple = (Ellipse(0.5, 0.25, 0.1), Ellipse(1.5, 0.25, 0.1), Ellipse(2.5, 0.25, 0.1))
    sigma0: float = 1.0
    kappa: float = 10.0
    n_nlp: int = 5

    @property
    def h(self) -> float:
        return self.tau_f / self.N


def load_capler_task(path: Path = TASK_FILE) -> CaplerTask:
    """The numbers of the task file (tomllib only); raises ValueError if the file is not the Capler task."""
    import tomllib

    data = tomllib.loads(Path(path).read_text())
    (contact,) = data["contacts"]
    plan, hz, hom = data["plan"], data["horizon"], data["plan"].get("homotopy", {})
    bounds = {b["joint"]: (b["lower"], b["upper"]) for b in plan.get("joint_bounds", [])}
    if set(bounds) != {"hip", "knee"} or len(data["initial"]["q"]) != 4:
        raise ValueError(f"{path}: not the Capler hopper task (q = x_B, z_B, hip, knee)")
    return CaplerTask(
        N=int(hz["N"]), tau_f=float(hz["tau_f"]), q0=tuple(data["initial"]["q"]), q_target=tuple(plan["target_q"]),
        mu=float(contact["mu"]), a_n=float(contact["a_n"]), a_t=float(contact["a_t"]),
        hip_bounds=bounds["hip"], knee_bounds=bounds["knee"],
        holes=tuple(Ellipse(h["x"], h["a"], h["b"], h.get("z", 0.0)) for h in plan.get("holes", [])),
        sigma0=float(hom.get("rho0", 1.0)), kappa=float(hom.get("kappa", 10.0)), n_nlp=int(hom.get("n_nlp", 5)))


def quick_task(task: CaplerTask) -> CaplerTask:
    """The --quick grid: N = 25 (h = 0.1), no holes."""
    return dataclasses.replace(task, N=25, holes=())


# ==================================================================================================
# the Capler model in CasADi symbols (design.md's table), as a nosnoc user writes it
# ==================================================================================================

# base + hip point mass, thigh, shank [kg]; link lengths, CoM offsets [m]; inertias about the CoM [kg m^2]
M_BASE, M_THIGH, M_SHANK = 3.975, 1.782, 0.548
L_THIGH, L_SHANK = 0.2, 0.2
C_THIGH, C_SHANK = 0.016, 0.1
I_THIGH, I_SHANK = 0.001, 0.0032


def capler_model(ca):
    """Symbolic Capler: q = (x_B, z_B, phi_hip, phi_knee), e(a) = (-sin a, -cos a).

    Returns a dict of SX: q, v, u, M (4x4), bias (C(q, v) v + g(q)), B (4x2), the knee and foot
    positions (2,), J_n = d z_foot / dq, J_t = d x_foot / dq. Lagrangian mechanics by symbolic
    differentiation (no closed form to mistype)."""
    q, v, u = ca.SX.sym("q", 4), ca.SX.sym("v", 4), ca.SX.sym("u", 2)
    e = lambda a: ca.vertcat(-ca.sin(a), -ca.cos(a))  # noqa: E731
    base = q[0:2]
    a_thigh, a_shank = q[2], q[2] + q[3]
    knee = base + L_THIGH * e(a_thigh)
    foot = knee + L_SHANK * e(a_shank)
    com_thigh = base + C_THIGH * e(a_thigh)
    com_shank = knee + C_SHANK * e(a_shank)
    kinetic, potential = 0, 0
    for m, p in ((M_BASE, base), (M_THIGH, com_thigh), (M_SHANK, com_shank)):
        pdot = ca.jtimes(p, q, v)
        kinetic += 0.5 * m * ca.dot(pdot, pdot)
        potential += m * G * p[1]
    kinetic += 0.5 * I_THIGH * v[2] ** 2 + 0.5 * I_SHANK * (v[2] + v[3]) ** 2
    M = ca.hessian(kinetic, v)[0]
    dT_dv = ca.gradient(kinetic, v)
    # d/dt dT/dv - dT/dq + dV/dq = B u  ->  M vdot = B u - bias
    bias = ca.jtimes(dT_dv, q, v) - ca.gradient(kinetic, q) + ca.gradient(potential, q)
    B = ca.vertcat(ca.SX.zeros(2, 2), ca.SX.eye(2))
    J_n = ca.jacobian(foot[1], q).T
    J_t = ca.jacobian(foot[0], q).T
    return {"q": q, "v": v, "u": u, "M": M, "bias": bias, "B": B, "knee": knee, "foot": foot, "J_n": J_n, "J_t": J_t}


# ==================================================================================================
# the nosnoc problem
# ==================================================================================================

N_REGIONS = 8
AUX_REGIONS = (6, 7)  # gap < 0, n^T v < 0, t^T v > 0 / < 0: the auxiliary impact fields


@dataclass
class NosnocSetup:
    """What build_nosnoc made: the nosnoc objects and CasADi functions to measure the solution."""

    model: object
    ocp: object
    opts: object
    fk: object  # x (8,) -> (foot x, foot z, knee z)
    vt: object  # x (8,) -> t^T v
    tangential_gain: float
    x_hint: np.ndarray | None = None
    details: dict = field(default_factory=dict)


def build_nosnoc(ns, ca, task: CaplerTask, *, n_fe: int = 1, n_s: int = 1, a_t: float | None = None,
                 max_iter: int = 4000) -> NosnocSetup:
    """The time-freezing Capler OCP in nosnoc, following examples/hopper_robot (dense Stewart regions).

    Grid: N_stages = task.N control intervals with n_fe finite elements each (n_fe = 1: one
    finite element per step of h, the task's grid) and n_s Radau IIA stages (n_s = 1: implicit Euler,
    as the paper's regularized implicit Euler). a_t: tangential gain of the auxiliary fields; None
    = mu * a_n, the example's construction (M^-1 (J_n -/+ mu J_t) a_n), which keeps the impact
    impulse in the friction cone; the task's a_t = 600 > mu a_n would let it leave the cone.
    """
    cap = capler_model(ca)
    q, v, u = cap["q"], cap["v"], cap["u"]
    t = ca.SX.sym("t")  # the clock (physical time)
    x = ca.vertcat(q, v)
    theta = ca.SX.sym("theta", N_REGIONS)
    M, J_n, J_t = cap["M"], cap["J_n"], cap["J_t"]
    gap = cap["foot"][1]
    v_n, v_t = ca.dot(J_n, v), ca.dot(J_t, v)
    a_n = task.a_n
    a_tan = task.mu * a_n if a_t is None else a_t

    f_ode = ca.vertcat(v, ca.solve(M, cap["B"] @ u - cap["bias"]), 1)
    zeros_q = ca.SX.zeros(4, 1)
    f_aux_pos = ca.vertcat(zeros_q, ca.solve(M, a_n * J_n - a_tan * J_t), 0)  # t^T v > 0: push back
    f_aux_neg = ca.vertcat(zeros_q, ca.solve(M, a_n * J_n + a_tan * J_t), 0)
    F = [ca.horzcat(*([f_ode] * 6), f_aux_pos, f_aux_neg)]
    S = [np.array([[s1, s2, s3] for s1 in (1, -1) for s2 in (1, -1) for s3 in (1, -1)])]
    c = [ca.vertcat(gap, v_n, v_t)]

    x0 = np.concatenate([task.q0, np.zeros(4), [0.0]])
    model = ns.NosnocModel(x=ca.vertcat(x, t), F=F, S=S, c=c, x0=x0, u=u, t_var=t, theta=[theta])

    inf = np.inf
    lbx = np.array([-inf, 0.0, task.hip_bounds[0], task.knee_bounds[0], -inf, -inf, -inf, -inf, -inf])
    ubx = np.array([inf, inf, task.hip_bounds[1], task.knee_bounds[1], inf, inf, inf, inf, inf])
    g_path = [cap["knee"][1]]  # knee above the ground (the base: lbx)
    lbg, ubg = [0.0], [inf]
    fx, fz = cap["foot"][0], cap["foot"][1]
    for hole in task.holes:
        g_path.append(((fx - hole.x) / hole.a) ** 2 + ((fz - hole.z) / hole.b) ** 2)
        lbg.append(1.0)
        ubg.append(inf)
    aux = theta[AUX_REGIONS[0]] + theta[AUX_REGIONS[1]]
    g_comp_path = ca.horzcat(ca.vertcat(v_t, -v_t), ca.vertcat(aux, aux))  # no slip while an impact field acts
    g_terminal = ca.vertcat(q - np.array(task.q_target), v)
    ocp = ns.NosnocOcp(lbu=-task.u_max * np.ones(2), ubu=task.u_max * np.ones(2), u_guess=np.zeros(2),
                       f_q=ca.dot(u, u), g_path=ca.vertcat(*g_path), lbg=np.array(lbg), ubg=np.array(ubg),
                       g_path_comp=g_comp_path, g_terminal=g_terminal, lbx=lbx, ubx=ubx)

    opts = ns.NosnocOpts()
    opts.pss_mode = ns.PssMode.STEWART
    opts.use_fesd = True
    opts.n_s = n_s
    opts.irk_scheme = ns.IrkSchemes.RADAU_IIA
    opts.N_stages = task.N
    opts.N_finite_elements = n_fe
    opts.terminal_time = task.tau_f
    opts.mpcc_mode = ns.MpccMode.SCHOLTES_INEQ
    opts.sigma_0 = task.sigma0
    opts.homotopy_update_rule = ns.HomotopyUpdateRule.LINEAR
    opts.homotopy_update_slope = 1.0 / task.kappa
    opts.max_iter_homotopy = task.n_nlp
    opts.comp_tol = 1e-9
    opts.step_equilibration = ns.StepEquilibrationMode.HEURISTIC_MEAN
    opts.print_level = 1
    opts.opts_casadi_nlp["ipopt"]["max_iter"] = max_iter
    opts.opts_casadi_nlp["ipopt"]["acceptable_tol"] = 1e-6
    # The example also sets opts.time_freezing = True with a speed-of-time control: nosnoc then pins
    # the clock to the numerical time at every control stage (t = tau_f at the end), a physical-time
    # target the task does not have (the paper lets physical time end where it ends). Off: the
    # clock is an ordinary state here, as in the task.
    opts.time_freezing = False
    opts.equidistant_control_grid = True

    fk = ca.Function("fk", [x], [ca.vertcat(fx, fz, cap["knee"][1])])
    vt = ca.Function("vt", [x], [v_t])
    setup = NosnocSetup(model=model, ocp=ocp, opts=opts, fk=fk, vt=vt, tangential_gain=a_tan)
    setup.details = {"n_fe": n_fe, "n_s": n_s, "a_n": a_n, "a_t": a_tan, "regions": N_REGIONS,
                     "switching_functions": ["gap", "n^T v", "t^T v"], "time_freezing_opt": False,
                     "mpcc_mode": "SCHOLTES_INEQ", "sigma_0": task.sigma0, "homotopy_update_slope": 1.0 / task.kappa,
                     "max_iter_homotopy": task.n_nlp, "ipopt_max_iter": max_iter,
                     "step_equilibration": "HEURISTIC_MEAN", "irk": f"RADAU_IIA n_s={n_s}"}
    return setup


def hop_hint(task: CaplerTask, n_points: int, apex_rise: float = 0.2, tuck=(0.5, -1.0)) -> np.ndarray:
    """The example's initial guess adapted to the Capler: one hop per metre (n = round(distance)),
    each a cubic spline through take-off, apex (base apex_rise higher, over the middle of the hop,
    leg tucked: hip, knee = tuck) and landing, zero velocities in the spline's knots; the clock
    linear. Returns (n_points, 9): the states at the end of each control stage."""
    from scipy.interpolate import CubicSpline

    q0, qT = np.array(task.q0, float), np.array(task.q_target, float)
    n_jumps = max(1, int(round(qT[0] - q0[0])))
    step = (qT[0] - q0[0]) / n_jumps
    per_jump = n_points // n_jumps
    rows, start = [], np.concatenate([q0, np.zeros(4)])
    for k in range(n_jumps):
        end = np.concatenate([[q0[0] + (k + 1) * step], qT[1:] if k == n_jumps - 1 else q0[1:], np.zeros(4)])
        mid = np.concatenate([[start[0] + step / 2, start[1] + apex_rise, *tuck], np.zeros(4)])
        spline = CubicSpline([0.0, 0.5, 1.0], np.stack([start, mid, end]))
        m = per_jump if k < n_jumps - 1 else n_points - per_jump * (n_jumps - 1)
        rows.append(spline(np.linspace(0.0, 1.0, m + 1)[1:]))
        start = end
    x_ref = np.concatenate(rows)
    clock = np.linspace(task.tau_f / n_points, task.tau_f, n_points)
    return np.column_stack([x_ref, clock])


class _StatusLog:
    """Wraps nosnoc's CasADi IPOPT solver to keep every NLP's status (nosnoc keeps only the last) and to stop at a
    Ctrl-C: IPOPT stops that NLP and nosnoc went on through its homotopy for minutes, then wrote the results."""

    def __init__(self, solver):
        self._solver, self.statuses = solver, []

    def __call__(self, *args, **kwargs):
        with interruptible():
            out = self._solver(*args, **kwargs)
        self.statuses.append(self._solver.stats()["return_status"])
        return out

    def __getattr__(self, name):
        return getattr(self._solver, name)


def _stage_values(prob, w: np.ndarray):
    """theta (K, 8), lambda (K, 8), x (K, 9) at every Runge-Kutta stage point of every finite element
    (nosnoc's index lists: ind_theta[stage][fe][rk][subsystem], ind_x[stage][fe][rk])."""
    thetas, lams, xs = [], [], []
    for th_s, la_s, x_s in zip(prob.ind_theta, prob.ind_lam, prob.ind_x):
        for th_f, la_f, x_f in zip(th_s, la_s, x_s):
            for th_r, la_r, x_r in zip(th_f, la_f, x_f):
                thetas.append(w[np.concatenate([np.asarray(i, int) for i in th_r])])
                lams.append(w[np.concatenate([np.asarray(i, int) for i in la_r])])
                xs.append(w[np.asarray(x_r, int)])
    return np.array(thetas), np.array(lams), np.array(xs)


def run_nosnoc(ns, ca, task: CaplerTask, variant: str, **build_kw) -> dict:
    """Build and solve one variant ('hint-free' or 'hint'); returns the record."""
    t_start = time.perf_counter()
    setup = build_nosnoc(ns, ca, task, **build_kw)
    solver = ns.NosnocSolver(setup.opts, setup.model, setup.ocp)
    build_s = time.perf_counter() - t_start
    if variant == "hint":
        setup.opts.initialization_strategy = ns.InitializationStrategy.EXTERNAL
        solver.set("x", hop_hint(task, setup.opts.N_stages))
    elif variant != "hint-free":
        raise ValueError(variant)
    log = _StatusLog(solver.solver)
    solver.solver = log
    t0 = time.perf_counter()
    error = None
    try:
        res = solver.solve()
    except Exception as exc:  # noqa: BLE001 -- a crash inside nosnoc is a result too
        res, error = None, f"{type(exc).__name__}: {exc}"
    solve_s = time.perf_counter() - t0
    rec = {"solver": "nosnoc", "variant": variant, "used_hint": variant == "hint", "N": task.N, "h": task.h,
           "holes": len(task.holes), "build_time_s": build_s, "solve_time_s": solve_s, "wall_time_s": build_s + solve_s,
           "nlp_statuses": log.statuses, "options": setup.details}
    if res is None:
        rec.update(converged=False, infeasible=False, error=error)
        return rec
    prob = solver.problem
    w = np.asarray(res["w_sol"], float)
    iters = [int(i) for i in res["nlp_iter"] if i is not None]
    own = float(prob.comp_res(w, solver.p_val).full().ravel()[0])
    # ours: theta_i lambda_i at every stage point, and the no-slip pair |t^T v| (theta_7 + theta_8)
    thetas, lams, x_stage = _stage_values(prob, w)
    x_nodes = np.asarray(res["x_traj"], float)  # x0 and the end of every finite element
    pairs = float(np.max(thetas * lams))
    vt = np.abs(np.asarray(setup.vt(x_stage[:, :8].T)).ravel())
    noslip = float(np.max(vt * thetas[:, list(AUX_REGIONS)].sum(axis=1)))
    fk = np.asarray(setup.fk(x_nodes[:, :8].T))  # (3, K)
    holes_metric = None
    if task.holes:
        holes_metric = float(min(np.min(((fk[0] - hl.x) / hl.a) ** 2 + ((fk[1] - hl.z) / hl.b) ** 2) for hl in task.holes))
    q_N = x_nodes[-1, :4]
    statuses = log.statuses
    rec.update(
        converged=bool(statuses) and all(s in SUCCESS for s in statuses),
        final_status=statuses[-1] if statuses else None,
        infeasible=any("Infeasible" in s for s in statuses),
        ipopt_iterations=int(sum(iters)), nlp_iterations=iters, n_nlp=len(iters),
        nlp_times_s=[float(c) for c in res["cpu_time_nlp"] if c is not None],
        complementarity_ours=max(pairs, noslip),
        complementarity_pairs=pairs, complementarity_noslip=noslip, complementarity_nosnoc=own,
        terminal_error=float(np.max(np.abs(q_N - np.array(task.q_target)))),
        terminal_velocity=float(np.max(np.abs(x_nodes[-1, 4:8]))),
        penetration_m=float(-np.min(fk[1])), knee_min_z_m=float(np.min(fk[2])), base_min_z_m=float(np.min(x_nodes[:, 1])),
        holes_metric=holes_metric, holes_respected=None if holes_metric is None else holes_metric >= 1.0 - HOLE_TOL,
        physical_time_s=float(x_nodes[-1, 8]), cost=float(res["cost_val"]),
        foot_x_range=[float(np.min(fk[0])), float(np.max(fk[0]))])
    rec["_trajectory"] = {"x": x_nodes, "u": np.asarray(res["u_traj"], float), "tau": np.asarray(res["t_grid"], float),
                          "foot": fk.T, "theta": thetas, "lam": lams, "x_stage": x_stage}
    return rec


# ==================================================================================================
# our planner on the same task
# ==================================================================================================

def run_planner(quick: bool) -> dict:
    """One solve of robots/capler.toml (quick: N = 25, no holes) as `planner plan` solves it: planner's
    defaults, raced on the usable CPUs (planner.race.default_arms; one CPU: the default solve)."""
    from planner.homotopy import SolveOptions
    from planner.model import load_robot
    from planner.problem import build_problem
    from planner.race import default_arms, race
    from planner.task import load_task

    robot = load_robot(ROBOT_FILE)
    task = load_task(TASK_FILE)
    if quick:
        task = dataclasses.replace(task, horizon=dataclasses.replace(task.horizon, N=25),
                                   plan=dataclasses.replace(task.plan, holes=()))
    t0 = time.perf_counter()
    problem = build_problem(robot, task)
    res = race(problem, default_arms(SolveOptions()))
    wall = time.perf_counter() - t0
    st = res.stats
    tr = res.trajectory
    rec = {"solver": "planner", "variant": "hint-free", "used_hint": False, "N": task.horizon.N, "h": task.horizon.h,
           "holes": len(task.plan.holes), "wall_time_s": wall, "solve_time_s": float(st.solve_time_s),
           "converged": bool(st.converged), "infeasible": "nfeasib" in (st.message or ""),
           "ipopt_iterations": int(st.ipopt_iterations), "n_nlp": int(st.n_nlp),
           "complementarity_ours": float(st.complementarity_residual), "complementarity_nosnoc": None,
           "terminal_error": float(res.terminal_error), "constraint_violation": res.constraint_violation,
           "message": st.message, "nlp_statuses": [r.status for r in res.nlps], "race": res.extra.get("race")}
    # penetration and holes at the numerical-time nodes, with this script's kinematics (the same as
    # robots/capler.xml: tests compare them with Pinocchio)
    import casadi as ca

    cap = capler_model(ca)
    foot_fn = ca.Function("foot", [cap["q"]], [cap["foot"]])
    foot = np.asarray(foot_fn(np.asarray(tr.y, float)[:, :4].T))  # (2, K)
    rec["penetration_m"] = float(-np.min(foot[1]))
    if task.plan.holes:
        rec["holes_metric"] = float(min(np.min(((foot[0] - hl.x) / hl.a) ** 2 + ((foot[1] - hl.z) / hl.b) ** 2)
                                        for hl in task.plan.holes))
        rec["holes_respected"] = rec["holes_metric"] >= 1.0 - HOLE_TOL
    return rec


# ==================================================================================================
# output
# ==================================================================================================

def _fmt(x, spec):
    if x is None:
        return "-"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, float) and not math.isfinite(x):
        return "nan"
    return format(x, spec)


def table(records: list[dict]) -> str:
    head = ("solver", "variant", "N", "holes", "wall s", "IPOPT it", "compl. ours", "compl. nosnoc",
            "term. err", "penetr. m", "holes metric", "converged", "infeasible", "hint used")
    rows = [head]
    for r in records:
        rows.append((r["solver"], r["variant"], str(r["N"]), str(r["holes"]), _fmt(r.get("wall_time_s"), ".1f"),
                     _fmt(r.get("ipopt_iterations"), "d"), _fmt(r.get("complementarity_ours"), ".1e"),
                     _fmt(r.get("complementarity_nosnoc"), ".1e"), _fmt(r.get("terminal_error"), ".1e"),
                     _fmt(r.get("penetration_m"), ".1e"), _fmt(r.get("holes_metric"), ".3f"),
                     _fmt(r.get("converged"), ""), _fmt(r.get("infeasible"), ""), _fmt(r.get("used_hint"), "")))
    widths = [max(len(row[i]) for row in rows) for i in range(len(head))]
    lines = ["| " + " | ".join(c.ljust(w) for c, w in zip(row, widths)) + " |" for row in rows]
    lines.insert(1, "|" + "|".join("-" * (w + 2) for w in widths) + "|")
    return "\n".join(lines)


def _import_nosnoc():
    try:
        import nosnoc
    except ImportError as exc:
        raise InputError(  # run_main: `bench_nosnoc: error: ...`, exit 2, as stress without dask
            "bench_nosnoc needs the optional benchmark dependency nosnoc: `pip install nosnoc` "
            f"(or `pip install -e .[bench]`), or give --planner --variants (the planner only); see docs/benchmarks.md "
            f"({exc})") from None
    return nosnoc


def read_previous(path: Path) -> dict | None:
    """OUT/results.json that --append adds to (None: there is none), read before any solve: an unreadable one ended the
    whole run in a traceback."""
    if not path.is_file():
        return None
    try:
        old = json.loads(path.read_text())
        if not (isinstance(old, dict) and isinstance(old.get("records", []), list)
                and all(isinstance(r, dict) and {"solver", "variant", "N"} <= set(r) for r in old.get("records", []))):
            raise ValueError("not a results.json of bench_nosnoc")
    except (ValueError, UnicodeDecodeError) as exc:  # (json.JSONDecodeError is a ValueError)
        raise InputError(f"--append: cannot read {path}: {exc}; move it away or run without --append") from None
    return old


def _nosnoc_version(nosnoc) -> str | None:
    try:
        from importlib.metadata import version
        return version("nosnoc")
    except Exception:  # noqa: BLE001
        return getattr(nosnoc, "__version__", None)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = script_parser(__doc__)
    parser.add_argument("--out", type=out_dir, default=DEFAULT_OUT, help=f"output directory (default {DEFAULT_OUT})")
    parser.add_argument("--quick", action="store_true", help="coarse grid (N = 25, no holes) for every solver")
    parser.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    parser.add_argument("--planner", action="store_true", help="also solve with our planner (its defaults and race, as planner plan) for the ratio")
    parser.add_argument("--variants", nargs="*", choices=("hint-free", "hint"), default=["hint-free", "hint"],
                        help="nosnoc's initial guesses: hint-free (y0 everywhere) and hint (the example's spline); "
                             "default both; none: with --planner, the planner only (no nosnoc needed)")
    parser.add_argument("--n-fe", type=int, default=1, help="nosnoc finite elements per control stage (default 1)")
    parser.add_argument("--n-s", type=int, default=1, help="nosnoc Radau IIA stages (default 1: implicit Euler)")
    parser.add_argument("--a-t", type=positive_float, default=None,
                        help="tangential gain of nosnoc's impact fields (default mu * a_n, the example's; the task says 600)")
    parser.add_argument("--append", action="store_true",
                        help="keep the records of OUT/results.json that this run does not redo (run the variants one at a time)")
    parser.add_argument("--max-iter", type=int, default=4000, help="IPOPT max_iter per NLP (the example's 4000)")
    args = parser.parse_args(argv)
    if args.n_fe < 1 or args.n_s < 1 or args.max_iter < 1:
        parser.error("--n-fe, --n-s and --max-iter must be >= 1")
    if not args.variants and not args.planner:
        parser.error("nothing to run: give --variants hint-free and/or hint, or --planner")
    nosnoc_flags = (("--n-fe", "n_fe"), ("--n-s", "n_s"), ("--a-t", "a_t"), ("--max-iter", "max_iter"))
    unread = [flag for flag, dest in nosnoc_flags if getattr(args, dest) != parser.get_default(dest)]
    if unread and not args.variants:  # (a --max-iter 7 was recorded in the command and ran the planner unchanged)
        parser.error(f"{', '.join(unread)} set nosnoc's solve, and no nosnoc variant runs (--variants none)")
    args.variants = list(dict.fromkeys(args.variants or []))  # (a variant named twice ran twice)
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    old = read_previous(args.out / "results.json") if args.append else None
    nosnoc = _import_nosnoc() if args.variants else None  # the planner alone does not need it
    import casadi as ca

    task = load_capler_task()
    if args.quick:
        task = quick_task(task)
    # --append combines records of the same settings only: a hint run at max_iter 1 was judged against a hint-free
    # run at 4000 ("needed the hint: no"). The planner's record depends on the task alone (nosnoc's max_iter had
    # dropped it)
    nosnoc_settings = {"quick": args.quick, "n_fe": args.n_fe, "n_s": args.n_s, "a_t": args.a_t,
                       "max_iter": args.max_iter}

    def settings(solver: str) -> dict:
        return nosnoc_settings if solver == "nosnoc" else {"quick": args.quick}

    def finished(rec: dict) -> dict:  # stamped as it finishes: the end of the whole run dated every record alike
        load = list(os.getloadavg()) if hasattr(os, "getloadavg") else None
        return dict(rec, date=utc_now(), load_average_after=load, settings=settings(rec["solver"]))

    records = []
    for variant in args.variants:
        print(f"nosnoc {variant}: N = {task.N}, {len(task.holes)} holes ...", file=sys.stderr, flush=True)
        with contextlib.redirect_stdout(sys.stderr):  # nosnoc's iteration table: stdout is the table or the JSON
            rec = run_nosnoc(nosnoc, ca, task, variant, n_fe=args.n_fe, n_s=args.n_s, a_t=args.a_t,
                             max_iter=args.max_iter)
        records.append(finished(rec))
        print(table([rec]), file=sys.stderr, flush=True)
    if args.planner:
        print(f"planner: N = {task.N}, {len(task.holes)} holes ...", file=sys.stderr, flush=True)
        with contextlib.redirect_stdout(sys.stderr):
            records.append(finished(run_planner(args.quick)))
    previous_machines, kept = [], []
    if old is not None:
        redone = {(r["solver"], r["variant"]) for r in records}
        kept = [r for r in old.get("records", []) if (r["solver"], r["variant"]) not in redone and r["N"] == task.N
                and r.get("settings") == settings(r["solver"])]
        records = kept + records
        previous_machines = old.get("previous_machines", []) + [{**(old.get("machine") or {}), "command": old.get("command")}]
    ratio = None
    ours = next((r for r in records if r["solver"] == "planner"), None)
    ref = next((r for r in records if r["solver"] == "nosnoc" and r["variant"] == "hint-free"), None)
    if ours and ref:
        ratio = ref["wall_time_s"] / ours["wall_time_s"]
    needs_hint = None  # nosnoc needed the hint: the hint-free run failed and the hinted one converged
    hinted = next((r for r in records if r["solver"] == "nosnoc" and r["variant"] == "hint"), None)
    if ref is not None and hinted is not None:
        needs_hint = (not ref["converged"]) and bool(hinted["converged"])
    results = {"benchmark": "bench_nosnoc", "command": "python -m scripts.bench_nosnoc "
               + shlex.join(argv if argv is not None else sys.argv[1:]),
               "quick": args.quick, "task": dataclasses.asdict(task),
               "machine": {**machine_info(), "nosnoc": _nosnoc_version(nosnoc) if nosnoc else None},
               "previous_machines": previous_machines, "run": run_info(),
               "records": records, "nosnoc_needs_hint": needs_hint, "wall_time_ratio_nosnoc_over_planner": ratio}
    args.out.mkdir(parents=True, exist_ok=True)
    arrays = {}
    if args.append and (args.out / "trajectories.npz").is_file():
        prefixes = tuple(f"{r['solver']}_{r['variant']}_" for r in kept)  # not those of the records dropped above
        with np.load(args.out / "trajectories.npz") as old_arrays:
            arrays.update({k: old_arrays[k] for k in old_arrays.files if k.startswith(prefixes)})
    for rec in records:  # the nosnoc solutions, for plots and checks: OUT/trajectories.npz
        for key, value in (rec.pop("_trajectory", None) or {}).items():
            arrays[f"{rec['solver']}_{rec['variant']}_{key}"] = value
    if arrays:
        write_atomically(args.out / "trajectories.npz", lambda f: np.savez(f, **arrays))
    else:  # an earlier run's solutions would sit beside these results as theirs
        (args.out / "trajectories.npz").unlink(missing_ok=True)
    write_atomically(args.out / "results.json", json.dumps(results, indent=1, default=str) + "\n")
    text = table(records) + "".join(f"\n{r['solver']} {r['variant']}: kept from the run of {r['date']}" for r in kept)
    if ratio is not None:
        text += f"\nwall time nosnoc (hint-free) / planner = {ratio:.2f}"
    if needs_hint is not None:
        text += f"\nnosnoc needed the hint: {'yes' if needs_hint else 'no'}"
    if args.json:
        print(json.dumps({"results": str(args.out / "results.json"), "machine": results["machine"],
                          "records": records, "nosnoc_needs_hint": needs_hint,
                          "wall_time_ratio_nosnoc_over_planner": ratio}, default=str))
    else:
        print(text)
    return 0


if __name__ == "__main__":
    sys.exit(run_main(main))
