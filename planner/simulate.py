"""Forward simulation of the time-freezing system with the regularized implicit Euler scheme.

Every step is the MPCC of eq. 24 (see planner.discretization). It is solved by an l_inf penalty
homotopy (Sec. 5.2): one slack s_c >= a * b for every complementarity pair, objective
rho_f ||sigma - sigma*||^2 + rho s_c, rho = rho0 kappa^i, each NLP warm-started from the last,
stopping as soon as the complementarity residual max(a * b) is below `comp_tol`.

Two strategies (SimulateOptions.strategy):
* STEPWISE: one OSNP at a time, a small NLP built once with (y_k, u_k, rho) as parameters;
  controls follow the task's schedule at the current clock value.
* HORIZON: all N steps as one NLP from y_0 at every node. A control schedule (given in physical
  time) is evaluated at the clock of the previous pass, repeated until the controls stop changing.
STEPWISE is the default: it was measured faster and it never fails on a whole horizon at once
(numbers in docs/formulation.md, "Simulation strategy"). A STEPWISE step whose homotopy stalls on a
spurious minimizer of the penalized NLP is restarted from predictors (SimulateOptions.restarts).

Joint PD (task key simulate.pd): u_k = u_ff + P (q_ref - q_{k+1}) - D v_{k+1}, with the feed-forward
u_ff from the schedule and the feedback at the END of the step -- an implicit controller, part of
the step's equations. It is not saturated; the result reports the steps beyond the actuator bounds.
"""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, replace
from enum import Enum

import casadi as ca
import numpy as np
import pinocchio as pin

from .discretization import Discretization, FESDInterval, FESDOptions, ImplicitEulerStep, SwitchVelocity
from .dynamics import Dynamics, dynamics_for
from .errors import InputError, check_field_types, enum_field, expect, interruptible, options_record, shown_up
from .model import Robot, coordinate_units
from .result import (APPROACH_MPS, COLLAPSED, CONE_FLOOR_N, FROZEN_TOL, IMPULSE_SHARE, ON_PLANE_M, SimulationResult,
                     SolveStats, Trajectory, clock_ran, cone_breach, forces_outside_cone, recover)
from .task import Task, contact_labels, task_source
from .timefreezing import ContactModel, TimeFreezingSystem

# An initial gap below -GAP_TOL [m] is "below the ground": the time-freezing system must start in c >= 0.
GAP_TOL = 1e-9
# A joint beyond the file's range by more than this [m or rad] is reported (a start on its limit stays there to rounding)
RANGE_TOL = 1e-9


class Strategy(Enum):
    """How `simulate` solves its steps (SimulateOptions.strategy; the module docstring)."""

    STEPWISE = "stepwise"  # one OSNP at a time, a small NLP built once (default)
    HORIZON = "horizon"  # all N steps as one NLP


@dataclass(frozen=True)
class SimulateOptions:
    """Numerical settings of `simulate`.

    strategy: STEPWISE (one OSNP at a time) or HORIZON (one NLP); rho_f: weight of ||sigma - sigma*||^2,
    None takes the task's simulate.rho_f; rho0, kappa, max_nlp: penalty homotopy rho = rho0 kappa^i,
    at most max_nlp NLPs per step (per horizon); comp_tol: complementarity residual max(a b) that ends
    the homotopy; ipopt_tol: IPOPT's tol; max_iter: IPOPT iterations per NLP; frozen_tol: relative
    clock deficit of a step that counts as frozen in the recovery; max_passes: HORIZON passes to make
    a control schedule consistent with the clock; verbose: IPOPT output.
    restarts (STEPWISE): when a step's homotopy ends above comp_tol, start it again from predictors,
    the implicit Euler step with the selectors held at free flight (sigma = 1) and at the previous
    step's values (solved by Newton), each with rho0 = restart_rho0 and then with rho0
    (docs/formulation.md, "Steps that do not converge").
    velocity_switch: the SwitchVelocity of the n^T v switching functions; None (default): with FESD of
    n_s >= 2 stages COLLOCATED for each contact that starts a step in persistent contact and POINT for
    the others (FESD's interior stages otherwise let the gap drift in persistent contact; an impact step
    keeps POINT; docs/formulation.md, "FESD in persistent contact"), POINT (the paper's) with implicit
    Euler and FESD n_s = 1. COLLOCATED: in every step.
    discretization: IMPLICIT_EULER (the paper's) or FESD; fesd: FESDOptions, FESD's elements and stages per step
    (with implicit Euler only its default).
    """

    strategy: Strategy = Strategy.STEPWISE
    rho_f: float | None = None
    rho0: float = 100.0
    kappa: float = 10.0
    max_nlp: int = 8
    comp_tol: float = 1e-9
    ipopt_tol: float = 1e-10
    max_iter: int = 3000
    # A persistent contact corrects the discrete drift of its contact velocity with small auxiliary
    # motions: clock deficits up to 3.4e-3 of a step were measured (Capler under joint PD, h = 2..10 ms),
    # while impacts freeze the clock for most of a step (entry steps measured down to 1.4e-2).
    frozen_tol: float = FROZEN_TOL
    max_passes: int = 5
    verbose: bool = False
    restarts: bool = True
    restart_rho0: float = 1e4  # holds an exact solution whose switching functions are >= 2 rho_f / 1e4 away from 0
    discretization: Discretization = Discretization.IMPLICIT_EULER
    # FESD's; only the default with implicit Euler. FESDOptions() has 2 elements per step, `planner simulate
    # --discretization fesd` 4 (an impact step holds its start, the end of the frozen phase and the landing mode)
    fesd: FESDOptions = FESDOptions()
    velocity_switch: SwitchVelocity | None = None

    def __post_init__(self):
        check_field_types(self)
        enum_field(self, "strategy", Strategy)
        enum_field(self, "discretization", Discretization)
        if not isinstance(self.fesd, FESDOptions):
            raise InputError(f"SimulateOptions.fesd = {self.fesd!r} is not allowed; it must be a FESDOptions")
        if self.discretization is not Discretization.FESD and self.fesd != FESDOptions():
            raise InputError(f"SimulateOptions.fesd = {self.fesd!r} sets the FESD discretization, which discretization "
                             f"= {self.discretization.value} would ignore; add discretization=Discretization.FESD")
        enum_field(self, "velocity_switch", SwitchVelocity, optional=True)
        if self.discretization is Discretization.FESD and self.strategy is not Strategy.STEPWISE:
            raise InputError("discretization = fesd is implemented for strategy = stepwise only")
        checks = [
            (self.rho_f is None or self.rho_f >= 0, "rho_f", self.rho_f, ">= 0 or None"),
            (self.rho0 > 0, "rho0", self.rho0, "> 0"),
            (self.kappa > 1, "kappa", self.kappa, "> 1"),
            (self.max_nlp >= 1, "max_nlp", self.max_nlp, ">= 1"),
            (self.comp_tol > 0, "comp_tol", self.comp_tol, "> 0"),
            (self.ipopt_tol > 0, "ipopt_tol", self.ipopt_tol, "> 0"),
            (self.max_iter >= 1, "max_iter", self.max_iter, ">= 1"),
            (0 < self.frozen_tol < 1, "frozen_tol", self.frozen_tol, "in (0, 1)"),
            (self.restart_rho0 > 0, "restart_rho0", self.restart_rho0, "> 0"),
            (self.max_passes >= 1, "max_passes", self.max_passes, ">= 1"),
            # (read by the other strategy only: accepted and ignored before)
            (self.strategy is Strategy.HORIZON or self.max_passes == SimulateOptions.max_passes, "max_passes",
             self.max_passes, f"{SimulateOptions.max_passes} (the default) unless strategy is horizon"),
            (self.strategy is Strategy.STEPWISE or self.restarts == SimulateOptions.restarts, "restarts",
             self.restarts, f"{SimulateOptions.restarts} (the default) unless strategy is stepwise"),
            (self.strategy is Strategy.STEPWISE or self.restart_rho0 == SimulateOptions.restart_rho0, "restart_rho0",
             self.restart_rho0, f"{SimulateOptions.restart_rho0:g} (the default) unless strategy is stepwise"),
            (self.restarts or self.restart_rho0 == SimulateOptions.restart_rho0, "restart_rho0", self.restart_rho0,
             f"{SimulateOptions.restart_rho0:g} (the default) unless restarts is on"),
        ]
        for ok, key, value, allowed in checks:
            if not ok:
                raise InputError(f"SimulateOptions.{key} = {value!r} is not allowed; it must be {allowed}")


@dataclass(frozen=True, eq=False)
class PDLaw:
    """The task's joint PD mapped onto the actuators: u = u_ff + P (q_ref - q) - D v.

    P (nu, nq), D (nu, nv) [control units per rad or m, per rad/s or m/s], q_ref (nq,) (entries of
    joints without PD are irrelevant: their P columns are zero). Calling it works on numbers
    (numpy, for the MuJoCo side of a cross-check) and on CasADi expressions (the simulation).
    """

    P: np.ndarray
    D: np.ndarray
    q_ref: np.ndarray

    def __call__(self, u_ff, q, v):
        """Controls (nu,) from the feed-forward u_ff (nu,) and the state q (nq,), v (nv,)."""
        if isinstance(q, (ca.SX, ca.MX)) or isinstance(v, (ca.SX, ca.MX)):
            return u_ff + ca.mtimes(ca.DM(self.P), ca.DM(self.q_ref) - q) - ca.mtimes(ca.DM(self.D), v)
        return np.asarray(u_ff, float) + self.P @ (self.q_ref - np.asarray(q, float)) - self.D @ np.asarray(v, float)


def pd_law(robot: Robot, task: Task) -> PDLaw | None:
    """The PDLaw of task.simulate.pd (None without one); q_ref defaults to the joints' initial.q.
    Raises the task's errors for unknown or unactuated joints (Task.pd_actuators)."""
    pd = task.simulate.pd
    if pd is None:
        return None
    P, D, q_ref = np.zeros((robot.nu, robot.nq)), np.zeros((robot.nu, robot.nv)), np.zeros(robot.nq)
    for j, (iq, iv, a) in enumerate(task.pd_actuators(robot)):
        gear = robot.actuators[a].gear
        P[a, iq], D[a, iv] = pd.kp[j] / gear, pd.kd[j] / gear
        q_ref[iq] = task.initial.q[iq] if pd.q_ref is None else pd.q_ref[j]
    return PDLaw(P, D, q_ref)


def simulate(robot: Robot, task: Task, options: SimulateOptions = SimulateOptions(), dynamics: Dynamics | None = None) -> SimulationResult:
    """Simulate the task's initial state over its horizon (tau_f, N) with speed of time s = 1.

    Returns a SimulationResult (numerical- and physical-time trajectory, impacts, solver stats).
    Raises InputError for a bad task (checked against the robot, initial state below the ground).
    A step (STEPWISE) or the horizon (HORIZON) that does not reach the complementarity tolerance
    gives a result with stats.converged = False and stats.message saying where: STEPWISE keeps the
    steps solved before it, HORIZON the last iterate (diagnostics to write, exit code 1).
    """
    expect(robot, Robot, "simulate's robot")
    expect(task, Task, "simulate's task")
    expect(options, SimulateOptions, "simulate's options")
    task.check_against(robot)
    task.warn_dependent_contacts(robot)
    task.check_no_slip_forces(robot)
    task.warn_controls_beyond_range(robot)
    dyn = dynamics_for(robot, dynamics)
    system = TimeFreezingSystem(dyn, task.contacts, task.ground_height)
    v0 = np.zeros(robot.nv) if task.initial.v is None else np.array(task.initial.v, float)
    y0 = system.initial_state(np.array(task.initial.q, float), v0)
    gaps = np.asarray(system.gap_fn(y0, np.zeros(robot.nu)), float).ravel()
    for c, gap in zip(task.contacts, gaps):
        if gap < -GAP_TOL:
            raise InputError(f"initial.q puts contact point {c.point!r} {shown_up(-gap)} m "
                             f"{c.beyond(task.ground_height)}; "
                             "the initial state must have every contact on the free side of its plane")
    rho_f = task.simulate.rho_f if options.rho_f is None else options.rho_f
    law = pd_law(robot, task)
    builder = ImplicitEulerStep(system, rho_f, velocity_switch=_velocity_switch(options))
    h, N = task.horizon.h, task.horizon.N
    start = time.perf_counter()
    if options.discretization is Discretization.FESD:
        fesd = FESDInterval(builder, options.fesd)
        elements, stats, U = _stepwise_fesd(system, fesd, y0, task, h, N, options, law)
        weights = fesd.b
    else:
        run = _stepwise if options.strategy is Strategy.STEPWISE else _horizon
        Y, W, U, stats = run(system, builder, y0, task, h, N, options, law)
        elements, weights = step_elements(system, builder, Y, W, U, h), np.ones(1)
    stats = dict(stats, solve_time_s=time.perf_counter() - start)
    trajectory = element_trajectory(system, builder, *elements, weights, options.frozen_tol,
                                    switch_at_start=options.discretization is Discretization.FESD, law=law)
    converged = stats["comp"] <= options.comp_tol and stats["ok"]
    solve = SolveStats(converged=converged, solve_time_s=stats["solve_time_s"], n_nlp=stats["n_nlp"],
                       ipopt_iterations=stats["iterations"], complementarity_residual=stats["comp"], message=stats["message"])
    # the task as simulated (one built in code has no file; one on disk may change), for validate(DIR)
    per_step = options.fesd.n_fe if options.discretization is Discretization.FESD else 1
    extra = {"_task": task} if law is None else {"pd": _pd_summary(robot, task, law, U, per_step), "_task": task}
    if options.discretization is Discretization.FESD:
        extra["discretization"] = {"name": "fesd", "n_s": options.fesd.n_s, "n_fe": options.fesd.n_fe, "rho_h": options.fesd.rho_h,
                                   "velocity_switch": builder.velocity_switch.value}
        if builder.velocity_switch is SwitchVelocity.COLLOCATED:  # steps solved with the gap correction on
            extra["discretization"]["collocated_steps"] = stats["collocated_steps"]
    if "restarted_steps" in stats:
        extra["restarted_steps"] = stats["restarted_steps"]  # steps that needed a predictor restart
    _warn_inside_holes(system, task, trajectory)
    extra["penetration"] = _penetration(system, task, trajectory)
    extra["joints_outside_range"] = joints_outside_range(robot, trajectory)
    extra["forces_outside_friction_cone"] = forces_outside_cone(trajectory, task)
    extra["braked_outside_friction_cone"] = braked_outside_cone(system, builder, elements, weights, options.frozen_tol,
                                                                trajectory)
    result = SimulationResult(robot=str(robot.path), robot_sha256=robot.sha256, task=task_source(task), trajectory=trajectory,
                              stats=solve, strategy=options.strategy.value, h=h, rho_f=rho_f, extra=extra,
                              options=options_record(options))
    if result.ends_in_impact:  # unfinished: its v_post is partial, no energy to judge (a passive ball's last, partial
        # bounce was flagged as gaining energy, "a push-off"); a plan's terminal rows finish its last impact
        last = replace(trajectory.impacts[-1], kinetic_energy_post=float("nan"))
        result = replace(result, trajectory=replace(trajectory, impacts=(*trajectory.impacts[:-1], last)))
    return result


def _penetration(system: TimeFreezingSystem, task: Task, trajectory) -> dict:
    """The deepest a contact point went into its plane over the nodes: max_m [m] (0: never), its point and physical
    time t [s] (None, None without contacts). A simulation converges on its step equations, which keep the contact's
    velocity, not its position, on the plane (the index-reduced DAE): a fixed arm's tip ended 45 mm in the ground with
    the run "converged"."""
    if not task.contacts:  # a free flight (contacts = []): nothing to go into
        return {"max_m": 0.0, "point": None, "t": None}
    u0 = np.zeros(system.dyn.nu)
    gaps = np.array([np.asarray(system.gap_fn(y, u0), float).ravel() for y in trajectory.y])  # (K, contacts) [m]
    k, c = np.unravel_index(np.argmin(gaps), gaps.shape)
    return {"max_m": float(max(0.0, -gaps[k, c])), "point": contact_labels(task.contacts)[c],
            "t": float(trajectory.y[k, -1])}


def joints_outside_range(robot: Robot, trajectory, tol: float = RANGE_TOL) -> list[dict]:
    """Each joint whose position left the robot file's range at the nodes: joint, nodes (how many), the farthest value
    and the range, in `unit` (m or rad). A simulation has no joint limits (the planner's dynamics have none), a plan
    the task's joint_bounds, which may be wider; MuJoCo's replay enforces the file's: a pogo leg driven to -0.176 m
    past its -0.05 m limit failed validation as a tracking error. trajectory: one with y (K, ny), or the positions
    (K, nq) themselves (a gait's walk). tol [m or rad]: how far past counts."""
    if robot.nq != robot.nv:  # a free flyer's quaternion: its coordinates are not the named degrees of freedom
        return []
    q = (trajectory if isinstance(trajectory, np.ndarray) else trajectory.y)[:, : robot.nq]
    units = coordinate_units(robot.model)[0]
    out = []
    for i, (lo, hi) in enumerate(zip(robot.q_lower, robot.q_upper)):
        beyond = (q[:, i] < lo - tol) | (q[:, i] > hi + tol)
        if beyond.any():
            far = q[beyond, i][np.argmax(np.maximum(lo - q[beyond, i], q[beyond, i] - hi))]
            out.append({"joint": robot.dof_names[i], "nodes": int(beyond.sum()), "farthest": float(far),
                        "lower": float(lo), "upper": float(hi), "unit": units[i]})
    return out


def _why(msg: str, comp: float, comp_tol: float) -> str:
    """Why a step's solve failed: IPOPT's status, and the complementarity residual when it is above comp_tol (a failed
    IPOPT at a complementary point read "complementarity residual 0 > 1e-09")."""
    return f"IPOPT {msg}" + (f", complementarity residual {comp:.3g} > {comp_tol:g}" if comp > comp_tol else "")


def _velocity_switch(options: SimulateOptions) -> SwitchVelocity:
    """options.velocity_switch, or by default COLLOCATED for FESD with n_s >= 2 stages (used per step
    for the contacts in persistent contact, _persistent_weights) and POINT (the paper's) otherwise.
    With one stage there is no interior collocation point and the correction is only first order
    (dc / h - n^T v = O(h |v|^2)): it left n^T v at 1.8e-2 m/s after the Capler PD drop's impact and
    stopped that run (tests/test_fesd.py, n_s = 1)."""
    if options.velocity_switch is not None:
        return options.velocity_switch
    fesd = options.discretization is Discretization.FESD and options.fesd.n_s >= 2
    return SwitchVelocity.COLLOCATED if fesd else SwitchVelocity.POINT


# A contact starts a step in persistent contact when the multipliers at the step's start say alpha
# slides (both of n^T v's below this) and the point is not above the ground (beta's lambda1 = max(c, 0)
# below it) [m/s, m]: sliding multipliers are ~1e-8 (IPOPT's bound relaxation), a flight's >= |n^T v| or c
PERSISTENT_TOL = 1e-6


def _persistent_weights(system, lam0, lam1) -> np.ndarray:
    """(n_sigma,) weights of the COLLOCATED correction for one FESD step from the multipliers (lam0,
    lam1) (n_sigma,) at its start: 1 on the n^T v row of a contact in persistent contact, else 0 (POINT:
    an impact step keeps the paper's switching function, which ends the impact at n^T v = 0)."""
    functions = [sw.function for sw in system.switches]
    weights = np.zeros(system.n_sigma)
    for i, sw in enumerate(system.switches):
        if sw.function != "n^T v":
            continue
        b = next(k for k, other in enumerate(system.switches) if other.contact == sw.contact and functions[k] == "c(q)")
        if lam0[i] + lam1[i] <= PERSISTENT_TOL and lam1[b] <= PERSISTENT_TOL:
            weights[i] = 1.0
    return weights


def _pd_summary(robot: Robot, task: Task, law: PDLaw, U: np.ndarray, per_step: int = 1) -> dict:
    """What summary.json says about the joint PD: gains, reference, and in how many steps the (unsaturated)
    controls U (steps per_step, nu) left the actuator bounds (per_step: FESD's elements per step, each a row of U: a
    step counts once, where its elements were counted, 33 of 10 steps)."""
    pd = task.simulate.pd
    outside = np.any((U < robot.u_lower) | (U > robot.u_upper), axis=1) if len(U) else np.zeros(0, bool)
    beyond = outside.reshape(len(outside) // per_step, per_step).any(axis=1)
    return {"joints": list(pd.joints), "kp": list(pd.kp), "kd": list(pd.kd),
            "q_ref": [float(law.q_ref[iq]) for iq, _, _ in task.pd_actuators(robot)],
            "max_abs_u": np.abs(U).max(axis=0).tolist() if len(U) else [0.0] * robot.nu,
            "steps_beyond_actuator_bounds": int(beyond.sum())}


def _ipopt_options(options: SimulateOptions) -> dict:
    # MUMPS's column permutation (maximum transversal) costs more than it saves on these small step
    # KKT systems: without it FESD Capler steps take 25-30 % less time, implicit Euler 5-10 %, same
    # iterations within 3 % (docs/benchmarks.md, "FESD against implicit Euler", session 7)
    ipopt = {"tol": options.ipopt_tol, "max_iter": options.max_iter, "print_level": 5 if options.verbose else 0,
             "sb": "yes", "warm_start_init_point": "yes", "mu_strategy": "adaptive", "mumps_permuting_scaling": 0}
    return {"print_time": False, "ipopt": ipopt}


def _penalized_nlp(x_vars, steps, params):
    """NLP of the steps plus one l_inf slack s_c >= a * b for every pair, objective + rho s_c.
    Returns (nlp dict, comp_fn (x, p) -> products, number of equalities, number of pairs)."""
    s_c = ca.SX.sym("s_c")
    rho = ca.SX.sym("rho")
    prods = ca.vertcat(*[st.comp_products() for st in steps])
    f = sum(st.objective for st in steps) + rho * s_c
    g = ca.vertcat(*[st.g for st in steps], s_c - prods)
    x = ca.vertcat(x_vars, s_c)
    p = ca.vertcat(params, rho)
    n_eq = sum(st.g.shape[0] for st in steps)
    comp_fn = ca.Function("comp", [x, p], [prods])
    return {"x": x, "p": p, "f": f, "g": g}, comp_fn, n_eq, prods.shape[0]


def _solve_homotopy(solver, comp_fn, x0, p_base, lbx, ubx, lbg, ubg, options, lam=None):
    """Run the penalty homotopy from x0; returns (x, lam, comp, n_nlp, iterations, ok, message)."""
    x, lam_x, lam_g = x0, None, None
    if lam is not None:
        lam_x, lam_g = lam
    n_nlp = iterations = 0
    comp, ok, message = np.inf, False, ""
    for i in range(options.max_nlp):
        rho = options.rho0 * options.kappa**i
        p = np.concatenate([p_base, [rho]])
        args = {"x0": x, "p": p, "lbx": lbx, "ubx": ubx, "lbg": lbg, "ubg": ubg}
        if lam_x is not None:
            args.update(lam_x0=lam_x, lam_g0=lam_g)
        with interruptible():
            sol = solver(**args)
        st = solver.stats()
        n_nlp += 1
        iterations += int(st.get("iter_count", 0))
        x, lam_x, lam_g = np.asarray(sol["x"]).ravel(), sol["lam_x"], sol["lam_g"]
        comp = float(np.max(np.asarray(comp_fn(x, p)), initial=0.0))
        ok, message = bool(st.get("success", False)), str(st.get("return_status", ""))
        if ok and comp <= options.comp_tol:
            break
    return x, (lam_x, lam_g), comp, n_nlp, iterations, ok, message


def _applied(law: PDLaw | None, system, u_ff, y):
    """The controls acting in a step ending at y: u_ff, plus the PD at y when there is one."""
    if law is None:
        return u_ff
    nq, nv = system.nq, system.nv
    return law(u_ff, y[:nq], y[nq : nq + nv])


def _stepwise(system, builder, y0, task, h, N, options, law=None):
    """One OSNP per step; the NLP is built once with (y_k, u_ff, rho) as parameters (u_ff the
    feed-forward; with a PD law the step's control is an expression of y_{k+1})."""
    ny, nu, nw = system.ny, system.nu, builder.nw
    y_k, u_k, y_next = ca.SX.sym("y_k", ny), ca.SX.sym("u_k", nu), ca.SX.sym("y_next", ny)
    step = builder.build(y_k, y_next, _applied(law, system, u_k, y_next), 1.0, h)
    nlp, comp_fn, n_eq, n_comp = _penalized_nlp(ca.vertcat(y_next, step.w), [step], ca.vertcat(y_k, u_k))
    solver = ca.nlpsol("osnp", "ipopt", nlp, _ipopt_options(options))
    lbx = np.concatenate([np.full(ny, -np.inf), step.lbw, [0.0]])
    ubx = np.concatenate([np.full(ny, np.inf), step.ubw, [np.inf]])
    lbg = np.concatenate([np.zeros(n_eq), np.zeros(n_comp)])
    ubg = np.concatenate([np.zeros(n_eq), np.full(n_comp, np.inf)])
    predict = _predictor(system, law, h) if options.restarts and system.n_sigma else None
    Y, W, U = np.zeros((N + 1, ny)), np.zeros((N, nw)), np.zeros((N, nu))
    Y[0] = y0
    total = {"n_nlp": 0, "iterations": 0, "comp": 0.0, "ok": True, "message": "ok", "restarted_steps": 0}
    w_prev = None
    for k in range(N):
        u = task.simulate.controls_at(Y[k, -1] + 0.5 * h, nu)  # midpoint: a change at t1 acts from the step nearest t1
        w_guess = builder.guess(Y[k], _applied(law, system, u, Y[k])) if w_prev is None else w_prev
        starts = _starts(np.concatenate([Y[k], w_guess, [0.0]]), predict, system, builder, law, Y[k], u, w_prev, options)
        x = _first_converged(solver, comp_fn, starts, np.concatenate([Y[k], u]), (lbx, ubx, lbg, ubg), options, total,
                             f"step {k} (tau = {k * h:.4g} s, t = {Y[k, -1]:.4g} s)")
        if x is None:  # stop here; the steps so far are the diagnostics
            return Y[: k + 1], W[:k], U[:k], total
        Y[k + 1], W[k] = x[:ny], x[ny : ny + nw]
        U[k] = _applied(law, system, u, Y[k + 1])
        w_prev = W[k]
    return Y, W, U, total


def _stepwise_fesd(system, fesd: FESDInterval, y0, task, h, N, options, law=None):
    """STEPWISE with FESD: one NLP per step h of n_fe Radau IIA elements, built once with (y_k, u_ff,
    the multipliers at y_k, rho) as parameters; a PD law acts at every stage state.

    Returns the elements (tau (K+1,), Y (K+1, ny) element boundaries, stage states (K, n_s, ny),
    stage algebraic variables (K, n_s, nw), stage controls (K, n_s, nu), lengths (K,)) with K = n_fe
    times the steps solved less the elements collapsed to length ~0, the stats dict of _stepwise, and the controls
    at every element's end (n_fe times the steps solved, nu), collapsed ones too (the PD summary counts steps). A
    step that fails is restarted from the
    selectors of its own start state and with a stronger first penalty (_fesd_starts)."""
    builder = fesd.step
    ny, nu, n = system.ny, system.nu, system.n_sigma
    y_k, u_k, lam_prev = ca.SX.sym("y_k", ny), ca.SX.sym("u_k", nu), ca.SX.sym("lam_prev", 2 * n)
    # COLLOCATED: a second NLP whose n^T v rows carry the gap correction times a parameter per switch;
    # steps with no contact in persistent contact use the first, built with weight 0: its expressions
    # are POINT's exactly (CasADi drops 0 * x), so flight and impact steps are solved as before
    collocated = builder.velocity_switch is SwitchVelocity.COLLOCATED
    weights_fixed = collocated and options.velocity_switch is SwitchVelocity.COLLOCATED
    kinds = ("collocated",) if weights_fixed else ("point", "collocated") if collocated else ("point",)
    nlps = {}
    for kind in kinds:  # a POINT builder ignores gap_weight
        gap_weight = ca.SX.sym("gap_weight", n) if kind == "collocated" else ca.SX.zeros(0)
        iv = fesd.build(y_k, lambda y: _applied(law, system, u_k, y), h, lam_prev,
                        gap_weight=gap_weight if kind == "collocated" else 0.0)
        nlp, comp_fn, n_eq, n_comp = _penalized_nlp(iv.x, [iv], ca.vertcat(y_k, u_k, lam_prev, gap_weight))
        nlps[kind] = (ca.nlpsol(f"fesd_{kind}", "ipopt", nlp, _ipopt_options(options)), comp_fn)
    lbx, ubx = np.concatenate([iv.lbx, [0.0]]), np.concatenate([iv.ubx, [np.inf]])
    lbg = np.zeros(n_eq + n_comp)
    ubg = np.concatenate([np.zeros(n_eq), np.full(n_comp, np.inf)])
    control = ca.Function("control", [y_k, u_k], [_applied(law, system, u_k, y_k)])
    lam0, lam1 = builder.w_blocks["lambda0"], builder.w_blocks["lambda1"]
    w_guess = builder.guess(y0, _applied(law, system, task.simulate.controls_at(0.0, nu), y0))
    left = np.concatenate([w_guess[lam0], w_guess[lam1]])  # the multipliers at y0 from its switching functions
    y, lengths, bounds, Ys, Ws, Us = np.asarray(y0, float), [], [y0], [], [], []
    total = {"n_nlp": 0, "iterations": 0, "comp": 0.0, "ok": True, "message": "ok", "restarted_steps": 0, "collocated_steps": 0}
    u_prev = task.simulate.controls_at(0.0, nu)
    for k in range(N):
        u = task.simulate.controls_at(y[-1] + 0.5 * h, nu)
        lefts = [left]
        if not np.array_equal(u, u_prev):  # the schedule's jump moves the switching functions (gamma's, with
            # lambda_n): when the last stage's multipliers, the old control's, leave the step no solution (a
            # pull-off's), those of the switching functions at y with the new control (tried second: a robot standing
            # through the jump kept its contact with the old ones, and took an impact with these)
            guess = builder.guess(y, _applied(law, system, u, y))
            lefts.append(np.concatenate([guess[lam0], guess[lam1]]))
        u_prev = u
        for attempt, left in enumerate(lefts):
            said = {key: total[key] for key in ("comp", "ok", "message")}
            starts = ((np.concatenate([fesd.guess(h, y, w), [0.0]]), opts)
                      for w, opts in _fesd_starts(builder, law, system, y, u, w_guess, options))
            weights = np.zeros(n)
            if collocated:  # options.velocity_switch COLLOCATED: everywhere; None: the contacts in persistent contact
                weights = np.ones(n) if weights_fixed else _persistent_weights(system, left[:n], left[n:])
            kind = "collocated" if weights.any() else "point"
            solver, comp_fn = nlps[kind]
            p = np.concatenate([y, u, left] + ([weights] if kind == "collocated" else []))
            x = _first_converged(solver, comp_fn, starts, p, (lbx, ubx, lbg, ubg), options, total,
                                 f"step {k} (tau = {k * h:.4g} s, t = {y[-1]:.4g} s)")
            if x is not None or attempt == len(lefts) - 1:
                break
            total.update(said)  # the first boundary's failure is not the step's
        total["collocated_steps"] += kind == "collocated"
        if x is None:
            break
        hk, Yk, Wk = fesd.unpack(x)
        lengths += list(hk)
        bounds += list(Yk[:, -1])
        Ys.append(Yk)
        Ws.append(Wk)
        Us.append([[np.asarray(control(ys, u), float).ravel() for ys in Ye] for Ye in Yk])
        y, w_guess = Yk[-1, -1], Wk[-1, -1]
        left = np.concatenate([w_guess[lam0], w_guess[lam1]])
    n_s, nw = fesd.n_s, builder.nw
    # an element of length ~0 or a hair below it (IPOPT's bound relaxation, -1.3e-9 s) carries nothing: left out as
    # the plans leave it (plan_trajectory), so tau increases (the converged run's own writer refused it, exit 2)
    lengths = np.array(lengths, float)
    keep = lengths > COLLAPSED * lengths.max(initial=0.0)
    # the element count given, not -1: a robot without actuators (nu = 0) has empty controls to reshape
    shape = lambda parts, m: np.array(parts, float).reshape(len(lengths), n_s, m)  # noqa: E731
    nodes = np.array(bounds, float).reshape(-1, ny)
    elements = (np.concatenate([[0.0], np.cumsum(lengths[keep])]), np.vstack([nodes[:1], nodes[1:][keep]]),
                shape(Ys, ny)[keep], shape(Ws, nw)[keep], shape(Us, nu)[keep], lengths[keep])
    return elements, total, shape(Us, nu)[:, -1]


def _first_converged(solver, comp_fn, starts, p, bounds, options, total: dict, where: str):
    """Solve one step's homotopy from each (x0, options) of `starts` (consumed lazily) until one ends
    with complementarity <= options.comp_tol; counts NLPs, iterations and restarts into `total`.
    Returns the solution x, or None with total["ok"] = False and the message naming `where`."""
    step_nlps = 0  # (the message gave the last attempt's count: "after 8 NLPs (3 restarts)" of a step that ran 32)
    for attempt, (x0, opts) in enumerate(starts):
        x, _, comp, n_nlp, iters, ok, msg = _solve_homotopy(solver, comp_fn, x0, p, *bounds, opts)
        step_nlps += n_nlp
        total["n_nlp"] += n_nlp
        total["iterations"] += iters
        if ok and comp <= options.comp_tol:
            break
    total["comp"] = max(total["comp"], comp)
    total["restarted_steps"] += attempt > 0
    if ok and comp <= options.comp_tol:
        return x
    total["ok"] = False
    total["message"] = (f"{where} did not converge: {_why(msg, comp, options.comp_tol)} after {step_nlps} NLPs "
                        f"({attempt} restarts)")
    return None


def _fesd_starts(builder, law, system, y, u, w_prev, options):
    """Starting selectors (w (nw,), options) of one FESD step: the previous element's, then (only while
    the step fails) those of the switching functions at y itself, each also with rho0 = restart_rho0."""
    yield w_prev, options
    if not options.restarts:
        return
    fresh = builder.guess(y, _applied(law, system, u, y))
    for rho0 in (options.restart_rho0, options.rho0):
        for w in (w_prev, fresh):
            if not (rho0 == options.rho0 and w is w_prev):
                yield w, replace(options, rho0=rho0)


def _predictor(system, law, h):
    """predict(y_k (ny,), u_ff (nu,), sigma (n_sigma,)) -> y_{k+1} (ny,) of the implicit Euler step with
    the selectors held at sigma (a smooth equation, solved by Newton from y_k), None if Newton fails."""
    if system.n_lambda:
        return _predictor_with_forces(system, law, h)
    ny, nu = system.ny, system.nu
    y_next, y_k, u_ff = ca.SX.sym("y_next", ny), ca.SX.sym("y_k", ny), ca.SX.sym("u_ff", nu)
    coef = ca.SX.sym("coef", system.n_fields)  # P_j(sigma), fixed
    F = ca.mtimes(system.fields_fn(y_next, _applied(law, system, u_ff, y_next)), coef)
    residual = ca.Function("residual", [y_next, ca.vertcat(y_k, u_ff, coef)], [y_next - y_k - h * F])
    newton = ca.rootfinder("predictor", "newton", residual, {"error_on_fail": False})

    def predict(y, u, sigma):
        y_pred = np.asarray(newton(y, np.concatenate([y, u, system.coefficient_vector(sigma)])), float).ravel()
        ok = newton.stats()["success"] and np.all(np.isfinite(y_pred))
        return y_pred if ok else None
    return predict


def _predictor_with_forces(system, law, h):
    """_predictor for several contacts: Newton on (y_{k+1}, lambda) with the step's force rows."""
    ny, nu, nl = system.ny, system.nu, system.n_lambda
    y_next, y_k, u_ff = ca.SX.sym("y_next", ny), ca.SX.sym("y_k", ny), ca.SX.sym("u_ff", nu)
    lam, sigma = ca.SX.sym("lam", nl), ca.SX.sym("sigma", system.n_sigma)
    u = _applied(law, system, u_ff, y_next)
    F = ca.mtimes(system.fields_fn(y_next, u), system.coefficient_vector(sigma, lam))
    x = system.variables(sigma)
    s = ca.vertcat(*[p(x) for p in system.constraint_switches])
    unknown = ca.vertcat(y_next, lam)
    residual = ca.Function("residual", [unknown, ca.vertcat(y_k, u_ff, sigma)],
                           [ca.vertcat(y_next - y_k - h * F, system.constraint_rows(y_next, u, lam, s))])
    newton = ca.rootfinder("predictor", "newton", residual, {"error_on_fail": False})

    def predict(y, u, sigma):
        sol = np.asarray(newton(np.concatenate([y, np.zeros(nl)]), np.concatenate([y, u, sigma])), float).ravel()
        ok = newton.stats()["success"] and np.all(np.isfinite(sol))
        return sol[:ny] if ok else None
    return predict


def _starts(x0, predict, system, builder, law, y_k, u, w_prev, options):
    """Starting points (x0, options) of one step's homotopy: the warm start x0, then (consumed only
    while the step fails) the predictors with sigma = 1 (free flight) and sigma = the previous step's
    selectors, each with rho0 = restart_rho0, then with rho0."""
    yield x0, options
    if predict is None:
        return
    sigmas = [np.ones(system.n_sigma)]
    if w_prev is not None:
        sigmas.append(w_prev[builder.w_blocks["sigma"]])
    for sigma in sigmas:
        y_pred = predict(y_k, u, sigma)
        if y_pred is None:
            continue
        start = np.concatenate([y_pred, builder.guess(y_pred, _applied(law, system, u, y_pred)), [0.0]])
        for rho0 in (options.restart_rho0, options.rho0):
            yield start, replace(options, rho0=rho0)


def _horizon(system, builder, y0, task, h, N, options, law=None):
    """All N steps as one NLP, y_0 fixed, every node initialized at y_0 (feed-forward U as parameters,
    a PD law evaluated at each step's end node)."""
    ny, nu, nw = system.ny, system.nu, builder.nw
    Ys = ca.SX.sym("Y", ny, N)
    Us = ca.SX.sym("U", nu, N)
    y_init = ca.SX.sym("y0", ny)
    steps, w_vars = [], []
    for k in range(N):
        prev = y_init if k == 0 else Ys[:, k - 1]
        st = builder.build(prev, Ys[:, k], _applied(law, system, Us[:, k], Ys[:, k]), 1.0, h, tag=f"_{k}")
        steps.append(st)
        w_vars.append(st.w)
    x_vars = ca.vertcat(ca.vec(Ys), *w_vars)
    nlp, comp_fn, n_eq, n_comp = _penalized_nlp(x_vars, steps, ca.vertcat(y_init, ca.vec(Us)))
    solver = ca.nlpsol("horizon", "ipopt", nlp, _ipopt_options(options))
    lbx = np.concatenate([np.full(N * ny, -np.inf), np.tile(builder.lbw, N), [0.0]])
    ubx = np.concatenate([np.full(N * ny, np.inf), np.tile(builder.ubw, N), [np.inf]])
    lbg = np.zeros(n_eq + n_comp)
    ubg = np.concatenate([np.zeros(n_eq), np.full(n_comp, np.inf)])
    x0 = np.concatenate([np.tile(y0, N), np.tile(builder.guess(y0, _applied(law, system, task.simulate.controls_at(0.0, nu), y0)), N), [0.0]])
    clock = np.zeros(N)  # clock at the start of each step, first pass: 0 everywhere
    total = {"n_nlp": 0, "iterations": 0, "comp": 0.0, "ok": True, "message": "ok"}
    U = x = None
    for _ in range(options.max_passes):
        U_new = np.array([task.simulate.controls_at(t + 0.5 * h, nu) for t in clock])
        if U is not None and np.array_equal(U, U_new):
            break
        U = U_new
        x, _, comp, n_nlp, iters, ok, msg = _solve_homotopy(solver, comp_fn, x0, np.concatenate([y0, U.ravel()]), lbx, ubx, lbg, ubg, options)
        total["n_nlp"] += n_nlp
        total["iterations"] += iters
        total["comp"], total["ok"], total["message"] = comp, ok, msg
        Y = np.vstack([y0, x[: N * ny].reshape(N, ny)])
        if not (ok and comp <= options.comp_tol):  # the last iterate is the diagnostics
            total["message"] = f"the horizon NLP did not converge: {_why(msg, comp, options.comp_tol)}"
            break
        clock = Y[:-1, -1]
        x0 = x
    else:
        if not np.array_equal(U, [task.simulate.controls_at(t + 0.5 * h, nu) for t in clock]):
            total["ok"] = False
            total["message"] = f"the control schedule did not settle on the clock in {options.max_passes} passes"
    W = x[N * ny : N * ny + N * nw].reshape(N, nw)
    U = np.array([_applied(law, system, U[k], Y[k + 1]) for k in range(N)]).reshape(N, nu)
    return Y, W, U, total


def step_elements(system: TimeFreezingSystem, builder: ImplicitEulerStep, Y, W, U, h, S=None) -> tuple:
    """N implicit-Euler steps as element_trajectory's one-stage elements (Y (N+1, ny), W (N, nw), U (N, nu) of N solved
    steps of length h [s]; S (N,) speeds of time, default 1: step k integrates h S[k] F):
    (tau (N+1,), Y (N+1, ny), Ys (N, 1, ny), Ws (N, 1, nw), Us (N, 1, nu), dt (N,))."""
    N = len(W)
    S = np.ones(N) if S is None else np.asarray(S, float).ravel()
    Y, W, U = np.asarray(Y, float), np.asarray(W, float).reshape(N, builder.nw), np.asarray(U, float).reshape(N, system.nu)
    return h * np.arange(N + 1), Y, Y[1:, None], W[:, None], U[:, None], h * S


def element_trajectory(system: TimeFreezingSystem, builder: ImplicitEulerStep, tau, Y, Ys, Ws, Us, dt, b, frozen_tol,
                       switch_at_start: bool = True, law: PDLaw | None = None) -> Trajectory:
    """Per-element auxiliary increments and impulses by the elements' quadrature, then the Thm. 10 recovery.

    tau (N+1,) numerical time [s] and Y (N+1, ny) states at the element boundaries; per element k the
    stage states Ys (N, n_s, ny), algebraic variables Ws (N, n_s, nw) and controls Us (N, n_s, nu);
    dt (N,) the integrated length h s [s]; b (n_s,) the quadrature weights of the stages (Radau IIA,
    the last stage the element's end; implicit Euler: n_s = 1, b = (1,)). Selectors and forces are
    reported at the elements' last stage. switch_at_start: impacts start at an element boundary
    (FESD; see result.recover). law: the joint PD the steps applied at their ends (implicit Euler: a landing inside a
    step that starts with no contact at rest reads its pre-impact velocity and impulse from the flight before it,
    _pd_before_landing)."""
    N = len(Ws)
    nq, nv = system.nq, system.nv
    n_c = len(system.contacts)
    dv_aux, impulses = _auxiliary_parts(system, builder, Ys, Ws, Us, dt, b)
    sigma = np.array([Ws[k, -1][builder.w_blocks["sigma"]] for k in range(N)]).reshape(N, system.n_sigma)
    W, U = Ws[:, -1], Us[:, -1]
    landed = approach = resting = None
    if not switch_at_start and n_c:  # a step that starts with a point on its plane moving into it: its impact first
        # at every node, the last too, where the last step ends (support or impact, result.recover); (neither reads u)
        u0 = np.zeros(system.nu)
        gaps = np.array([np.asarray(system.gap_fn(y, u0), float).ravel() for y in Y[: N + 1]]).reshape(-1, n_c)
        approach = np.array([np.asarray(system.normal_velocity_fn(y, u0), float).ravel()
                             for y in Y[: N + 1]]).reshape(-1, n_c)
        landed = (gaps[:N] <= ON_PLANE_M) & (approach[:N] < -APPROACH_MPS)  # (N, n_c)
        resting = (gaps <= ON_PLANE_M) & (np.abs(approach) <= APPROACH_MPS)  # (N + 1, n_c)
    pre_impact = None if switch_at_start or law is None else _pd_before_landing(system, builder, law, Y, W, U, dt,
                                                                                  dv_aux, impulses, frozen_tol, resting)
    t, q, v, u, impacts = recover(tau, Y, U, dt, dv_aux, impulses, nq, nv, system.labels, frozen_tol,
                                  switch_at_start=switch_at_start, landed=landed, approach=approach, resting=resting,
                                  pre_impact=pre_impact)
    impacts = tuple(replace(imp, kinetic_energy_pre=_kinetic(system, imp.q, imp.v_pre),
                            kinetic_energy_post=_kinetic(system, imp.q, imp.v_post)) for imp in impacts)
    forces = None
    if system.n_lambda:
        forces = np.array([W[k][builder.w_blocks["forces"]][builder.lam_slice] for k in range(N)]).reshape(N, system.n_lambda)
    return Trajectory(tau=tau, y=Y, state_names=system.state_names, sigma=sigma, selector_names=tuple(s.name for s in system.switches),
                      forces=forces, force_names=system.lam_names,
                      contact_force=_contact_force(system, builder, Y, W, U, dt, forces),
                      t=t, q=q, v=v, u=u, impacts=impacts)


def _pd_before_landing(system: TimeFreezingSystem, builder: ImplicitEulerStep, law: PDLaw, Y, W, U, dt, dv_aux,
                       impulses, frozen_tol, resting) -> tuple[np.ndarray, np.ndarray]:
    """Per implicit-Euler step k, the corrections (dv (N, nv) [m/s, rad/s], dimp (N, n_contacts, 2) [N s]) of the
    pre-impact velocity and the impulse that result.recover reads for a landing inside it (Y (N+1, ny), W (N, nw),
    U (N, nu) applied controls, dt (N,) [s], dv_aux and impulses as _auxiliary_parts gives them, resting (N+1,
    n_contacts) the contacts at rest on their planes at the nodes, as element_trajectory finds them, or None).

    The step evaluates its fields at its end, after the impact: in its running share the PD reacted to the post-impact
    velocity and to the posture q_{k+1} = q_k + h v_{k+1} it moved to (a hopper's leg slide read 0.83 m/s in free fall,
    its impulse 1.05 N s for m v = 0.70), and with several feet landing in it their persistent forces held it up.
    recover dates the impact at the step's end: the clock's advance d is flight up to it. So the pre-impact velocity is
    that flight, the free field f_ODE from y_k over d by implicit Euler with the PD at its end, as in a flight step
    (Newton from y_k). The auxiliary impulse also stopped what the end-point reading r = v_pre,step - v_pre drove into
    the contacts; dimp adds r's least-squares part (in the kinetic metric M) along the auxiliary fields of the contacts
    that took the step's impulse (G^-1 J r for one contact, G = J M^-1 J^T), so that the impulse takes the contacts
    from v_pre to v_post. Zero for steps that ran the clock (not frozen) and for steps that start with a contact at rest
    on its plane: their flight is not free (a second foot landing beside a standing one), and f_ODE alone would drop
    the standing foot's support, reading free fall into v_pre and the support over d into an impulse (a bounder's
    standing front foot 0.44 N s for its 0.06 N s tap), so the step's own reading stays there."""
    nq, nv, N = system.nq, system.nv, len(W)
    dv, dimp = np.zeros((N, nv)), np.zeros((N, len(system.contacts), 2))
    frozen = np.flatnonzero(np.diff(np.asarray(Y, float)[:, -1]) < (1.0 - frozen_tol) * np.asarray(dt, float))
    if not frozen.size:
        return dv, dimp
    ode = [f.name for f in system.fields].index("ode")
    y_end, y_k, u_ff, d = (ca.SX.sym(n, m) for n, m in (("y_end", system.ny), ("y_k", system.ny), ("u_ff", system.nu),
                                                         ("d", 1)))
    residual = ca.Function("flight", [y_end, ca.vertcat(y_k, u_ff, d)],
                           [y_end - y_k - d * system.fields_fn(y_end, _applied(law, system, u_ff, y_end))[:, ode]])
    flight = ca.rootfinder("flight", "newton", residual, {"error_on_fail": False})
    aux = system.auxiliary_mask
    for k in frozen:
        if resting is not None and resting[k].any():
            continue  # (a standing contact holds the robot over d: no free flight, the step's own reading stays)
        y1, u1 = Y[k + 1], U[k]
        ff = u1 - law(np.zeros(system.nu), y1[:nq], y1[nq : nq + nv])  # the step's feed-forward
        y_pre = np.asarray(flight(Y[k], np.concatenate([Y[k], ff, [Y[k + 1, -1] - Y[k, -1]]])), float).ravel()
        if not (flight.stats()["success"] and np.all(np.isfinite(y_pre))):
            continue  # (a flight of a fraction of a step that Newton cannot solve: the step's own reading stays)
        dv[k] = y_pre[nq : nq + nv] - (y1[nq : nq + nv] - dv_aux[k])
        normal = np.abs(impulses[k, :, 0])
        took = normal >= IMPULSE_SHARE * normal.max() if normal.max() > 0 else np.zeros(len(normal), bool)
        rates = np.asarray(system.impulse_fn(y1, u1), float)  # (2 n_contacts, n_fields) [N s per unit of P_j h]
        along = aux & np.any(rates[np.repeat(took, 2)] != 0, axis=0)
        if not np.any(along):
            continue
        M = np.asarray(system.dyn.mass(y1[:nq]), float)
        fields = np.asarray(system.fields_fn(y1, u1), float)[nq : nq + nv, along]
        share = np.linalg.lstsq(fields.T @ M @ fields, fields.T @ M @ -dv[k], rcond=None)[0]  # (normal equations)
        dimp[k] = (rates[:, along] @ share).reshape(-1, 2)
    return dv, dimp


def _auxiliary_parts(system: TimeFreezingSystem, builder: ImplicitEulerStep, Ys, Ws, Us, dt, b):
    """Per element k (arguments as element_trajectory's): the velocity increment of the auxiliary fields dv_aux
    (N, nv) [m/s, rad/s] and the contacts' normal and tangential impulses (N, n_contacts, 2) [N s], by quadrature."""
    N, nq, nv, n_c = len(Ws), system.nq, system.nv, len(system.contacts)
    aux = system.auxiliary_mask
    dv_aux, impulses = np.zeros((N, nv)), np.zeros((N, n_c, 2))
    for k in range(N):
        for j, weight in enumerate(b):
            coef = builder.coefficients(Ws[k, j])
            fmat = np.asarray(system.fields_fn(Ys[k, j], Us[k, j]))
            dv_aux[k] += weight * dt[k] * fmat[nq : nq + nv, aux] @ coef[aux]
            if n_c:
                impulse = np.asarray(system.impulse_fn(Ys[k, j], Us[k, j]))
                impulses[k] += (weight * dt[k] * impulse @ coef).reshape(n_c, 2)
    return dv_aux, impulses


# A braking below this share of the robot's weight is no braking to report: FESD's stage selectors leak the tangential
# field by up to 8.5e-6 N on the 1 kg point mass, 7.6e-5 N on Capler, in flight elements whose clock runs
BRAKE_FLOOR_SHARE = 1e-5


def _warn_inside_holes(system: TimeFreezingSystem, task: Task, trajectory: Trajectory) -> None:
    """Warn of each contact point that a sample puts inside one of the task's plan.holes: the simulation has flat
    ground there (a drop over a hole landed on ground that is not there, and validated, session 58's tester)."""
    holes = task.plan.holes if task.plan is not None else ()
    for point in dict.fromkeys(c.point for c in task.contacts) if holes else ():
        position = system.dyn.point_position(point)
        xz = np.array([np.asarray(position(q), float).ravel()[[0, 2]] for q in trajectory.q])
        for i, e in enumerate(holes):
            inside = np.flatnonzero(e.metric(xz[:, 0], xz[:, 1]) < 1.0)
            if inside.size:
                warnings.warn(f"{point!r} is inside plan.holes[{i}] from t = {trajectory.t[inside[0]]:.4g} s: a "
                              "simulation runs on flat ground, holes or not (plan.holes are for `planner plan`)")


def braked_outside_cone(system: TimeFreezingSystem, builder: ImplicitEulerStep, elements, b, frozen_tol: float,
                        trajectory: Trajectory) -> list[dict]:
    """The contacts a tangential auxiliary field held beyond their friction cone in steps whose clock ran (no impact,
    no lambda_t): a point sliding on its plane brakes at a_t / m whatever mu (docs/tasks.md). One entry per contact
    with mu > 0: point, steps (how many), max_tangential_N (the field's tangential impulse over the step's physical
    time [N]), mu_normal_N (mu times the normal force there: the persistent one at the step's end and the field's,
    clipped at 0 [N]) and normal_N (that normal force [N]). elements: (tau, Y, Ys, Ws, Us, dt) as
    element_trajectory takes them."""
    _, Y, Ys, Ws, Us, dt = elements
    if not len(system.contacts) or not len(Ws):
        return []
    impulses = _auxiliary_parts(system, builder, Ys, Ws, Us, dt, b)[1]
    clock = np.asarray(Y, float)[:, -1]
    advance = np.diff(clock)
    running = (advance >= (1.0 - frozen_tol) * dt) & (advance > 0)
    samples = trajectory.contact_force_samples()
    at_end = np.clip(np.searchsorted(trajectory.t, clock[1:], side="right") - 1, 0, len(trajectory.t) - 1)
    persistent = samples[0][at_end] if samples is not None else np.zeros((len(advance), len(system.contacts)))
    model = system.dyn.robot.model
    floor = max(CONE_FLOOR_N, BRAKE_FLOOR_SHARE * pin.computeTotalMass(model) * np.linalg.norm(model.gravity.linear))
    out = []
    for c, contact in enumerate(system.contacts):
        rate = impulses[:, c] / np.where(running, advance, 1.0)[:, None]  # (N, 2) [N]
        entry = cone_breach(system.labels[c], "steps", contact.mu, rate[:, 1], rate[:, 0] + persistent[:, c], running,
                            floor)
        if entry:
            out.append(entry)
    return out


def _kinetic(system: TimeFreezingSystem, q, v) -> float:
    """1/2 v^T M(q) v [J] of q (nq,), v (nv,)."""
    return 0.5 * float(v @ np.asarray(system.dyn.mass(q)) @ v)


def _contact_force(system: TimeFreezingSystem, builder: ImplicitEulerStep, Y, W, U, dt, forces) -> np.ndarray | None:
    """(N, n_contacts, 2) persistent-contact force (normal, tangential) [N] of each step. Several
    contacts: the step's joint forces (zero for points off the ground and in a step whose clock ran at most FROZEN_TOL
    of it: a frozen impact's hold the NLP's values, the full weight on a landing foot). One contact: the index-reduced
    force at the step's end point times the DAE field's share of the step's physical time, its coefficient in F
    over the clock's rate (1 in persistent contact, 0 in flight and in a frozen impact; a landing step whose clock
    ran a sixth of it in stance had read a sixth of the force). dt (N,): the steps' integrated lengths [s].
    None for elastic contacts."""
    n_c = len(system.contacts)
    if forces is not None:
        out = np.zeros((len(W), n_c, 2))
        for c, label in enumerate(system.labels):
            for j, kind in enumerate(("n", "t")):
                name = f"lambda_{kind}[{label}]"
                if name in system.lam_names:
                    out[:, c, j] = forces[:, system.lam_names.index(name)]
        out[~clock_ran(Y[:, -1], dt)] = 0.0
        return out
    if n_c != 1 or system.models[0] is ContactModel.ELASTIC:
        return None
    terms, label = system.terms[0], system.labels[0]
    no_slip = system.models[0] is ContactModel.NO_SLIP
    lam = terms.lambda_no_slip if no_slip else ca.vertcat(terms.lambda_n, 0)
    lam_fn = ca.Function("contact_force", [system.y, system.u], [lam])
    j = [f.name for f in system.fields].index(f"{'dae_f' if no_slip else 'dae'}[{label}]")
    rate = np.diff(Y[:, -1]) / np.asarray(dt, float)  # the clock's advance per unit of the step's numerical time
    # (the DAE field is one of those that run the clock, so its share is in [0, 1] but for rounding)
    share = [min(max(builder.coefficients(W[k])[j] / rate[k], 0.0), 1.0) if rate[k] > 0 else 0.0 for k in range(len(W))]
    return np.array([share[k] * np.asarray(lam_fn(Y[k + 1], U[k]), float).ravel()
                     for k in range(len(W))]).reshape(len(W), 1, 2)
