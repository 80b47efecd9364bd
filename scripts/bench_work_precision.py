"""Work-precision benchmark of the time-freezing simulation and of the planning OCP (issue 9): wall
time against error.

Suite "simulate" (the default; --cases picks among CASE_NAMES):

* point mass (robots/point_mass.xml) against its exact solution (class Drop): the inelastic
  frictionless drop from (0, 1) m with v = (1, 0) m/s (Example 1 of the paper) under several
  discretization options (rho_f, a_n, strategy), the same drop with no-slip friction, and the elastic
  drop (restitution 0.5) from rest. Errors: state error max |q - q_exact|_inf over the physical-time
  samples in [0, t_window] [m] (post_impact_error_m: over the samples after both first impacts only, the contact
  phase; interpolated_error_m: the samples read with linear interpolation, between them too), first impact time
  error vs sqrt(2 z0 / g) [s], post-impact velocity error |v_post - v_post_exact|_inf [m/s], penetration -min gap
  over the nodes [m] (FESD: the element ends, not the stages inside).
* Capler (robots/capler.xml) dropped from 5 cm while joint PD holds its posture: against a fine-grid
  run (h_ref = smallest h / 8) and against a MuJoCo rollout with the same PD law (planner.replay).
  Errors: base position error max |p_base - p_base_ref|_2 at the run's own samples (the references
  interpolated there) [m], impact time difference [s] (also vs the exact ballistic impact time: the
  held posture falls rigidly), the base error against that exact ballistic flight before the first landing
  (flight_error_exact_m; the references' own in "references"), penetration.
  A MuJoCo line (timestep varied, error against the fine-grid run) puts the soft-contact simulator on
  the same plot.

Suite "ocp" (--suite ocp; --cases among OCP_CASE_NAMES): the planner (build_problem + solve with the
default SolveOptions) over the grid N, h = tau_f / N. The plans of different N are different local
optima, so no plan is compared with another; each is judged against its own dynamics:

* ocp_pm_hop: the point-mass hop of tests/test_problem.py (to x = 0.5 m, tau_f = 1 s), N = 20 ... 80.
* ocp_capler: robots/capler.toml with its three holes, N = 40, 50, 75, 100 (--capler-N; the task's
  own 125 takes ~5 min and 6000 IPOPT iterations). Planned once whatever --repeat says.

Errors: the re-simulation defect (resimulation_defect: from the plan's state every 0.1 s of physical
time, planner.simulate at h / 8 with the plan's controls open loop for 0.1 s; max distance of the base
origin and of the contact points from the plan [m]); the MuJoCo tracking error (base, joint PD on the
plan: what `planner validate` reports; tracking_window_{mean,median,worst}_m over its windows) [m];
penetration -min gap over the nodes [m]; terminal error [m, rad]; point mass also the first flight against
the exact motion under the plan's controls from its own take-off state (max |q - q_exact|_inf [m], landing time
error [s]; exact_flight). Records also hold IPOPT iterations, NLPs, convergence, hops and impacts.

Writes OUT/results.json (one record per run, the convergence orders, the machine) and
OUT/work_precision.png (log-log error against wall time). Runs one simulation or plan at a time in
this process (no worker processes), so a 2-core machine shared with other jobs still gives comparable
numbers; the runs are deterministic (no random numbers).

    python -m scripts.bench_work_precision [--quick] [--out DIR] [--json]   (from the repository root)
    python -m scripts.bench_work_precision --suite ocp [--quick] [--capler-N 40 50 ...] [--out DIR]
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
import shlex
import statistics
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import matplotlib
import mujoco
import numpy as np
import pinocchio
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from planner import replay
from planner.discretization import Discretization, FESDOptions
from planner.dynamics import Dynamics
from planner.homotopy import SolveOptions, solve
from planner.model import load_robot
from planner.problem import build_problem
from planner.result import write_atomically
from planner.simulate import SimulateOptions, Strategy, pd_law, simulate
from planner.task import ControlChange, Horizon, Initial, Simulate, Task, load_task, parse_task
from planner.plots import save_figure
from scripts._report import machine_info as shared_machine_info
from scripts._report import checked_default, out_dir, run_info, run_main, script_parser

G = 9.81  # gravity of the robot files [m/s^2]
DEFAULT_OUT = Path("results/bench/work_precision")
DEFAULT_OUT_OCP = Path("results/bench/work_precision_ocp")
REFERENCE_REFINEMENT = 8  # Capler reference step = smallest h of the grid / 8
# IPOPT tol 1e-10 and complementarity <= 1e-9 leave errors up to ~1e-6 (the interior point keeps
# selectors ~3e-6 off their bounds; tests/test_simulate.py uses SOLVER_TOL = 1e-5): errors below it
# say nothing about the grid and are left out of the convergence orders
ERROR_FLOOR = 1e-5


# ==================================================================================================
# exact point-mass solutions
# ==================================================================================================

@dataclass(frozen=True)
class Drop:
    """Exact motion of a point mass dropped from (x0, z0) [m] with horizontal speed vx [m/s] onto z = 0.

    Free flight, first impact at sqrt(2 z0 / g), then: restitution 0 -> it stays on the table (sliding
    at vx when frictionless, stopped by no-slip friction); restitution eps > 0 -> bounces with
    eps^k of the first impact speed (frictionless only, vx kept).
    """

    z0: float
    x0: float = 0.0
    vx: float = 0.0
    restitution: float = 0.0
    no_slip: bool = False

    def __post_init__(self):
        if self.no_slip and self.restitution > 0:
            raise ValueError("Drop: no-slip with restitution > 0 is not an exact solution written here")

    @property
    def impact_time(self) -> float:
        """First impact [s]."""
        return math.sqrt(2.0 * self.z0 / G)

    @property
    def v_post(self) -> np.ndarray:
        """Velocity (2,) right after the first impact [m/s]."""
        return np.array([0.0 if self.no_slip else self.vx, self.restitution * G * self.impact_time])

    def q(self, t: np.ndarray) -> np.ndarray:
        """Positions (P, 2) [m] at times t (P,) [s]."""
        t = np.asarray(t, float)
        t1 = self.impact_time
        x = self.x0 + self.vx * (np.minimum(t, t1) if self.no_slip else t)
        z = np.where(t < t1, self.z0 - G * t**2 / 2, 0.0)
        start, speed = t1, self.restitution * G * t1
        while speed > 1e-9 and start <= t.max():  # each bounce: a parabola of launch speed eps^k v1
            flight = 2.0 * speed / G
            inside = (t >= start) & (t < start + flight)
            s = t[inside] - start
            z[inside] = speed * s - G * s**2 / 2
            start, speed = start + flight, speed * self.restitution
        return np.column_stack([x, z])


# ==================================================================================================
# runs and their records
# ==================================================================================================

@dataclass(frozen=True)
class Variant:
    """Discretization options of one line of the plot: contact keys (a_n, ...) replacing the case's,
    and SimulateOptions fields (strategy, rho_f, discretization, fesd as a dict of FESDOptions fields,
    ...); hs: the steps h [s] of this line when not the case's grid."""

    label: str
    contact: dict = field(default_factory=dict)
    options: dict = field(default_factory=dict)
    hs: tuple[float, ...] | None = None


def fesd_variant(n_s: int, n_fe: int, hs: tuple[float, ...] | None = None) -> Variant:
    """The FESD line with n_s Radau IIA stages and n_fe elements per step."""
    return Variant(f"fesd n_s={n_s}", options={"discretization": "fesd", "fesd": {"n_s": n_s, "n_fe": n_fe}}, hs=hs)


@dataclass(frozen=True)
class PointMassCase:
    """A point-mass task with an exact solution: contact keys, initial state, numerical horizon tau_f [s],
    comparison window [0, t_window] of physical time [s], the grid of steps h [s], the variants."""

    name: str
    contact: dict
    exact: Drop
    tau_f: float
    t_window: float
    hs: tuple[float, ...]
    variants: tuple[Variant, ...] = (Variant("default"),)


def _timed(fn, repeat: int):
    """(last result, median wall time [s]) of `repeat` calls of fn()."""
    times, out = [], None
    for _ in range(repeat):
        start = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - start)
    return out, statistics.median(times)


def _options(variant: Variant) -> SimulateOptions:
    opts = dict(variant.options)
    if "strategy" in opts:
        opts["strategy"] = Strategy(opts["strategy"])
    if "discretization" in opts:
        opts["discretization"] = Discretization(opts["discretization"])
    if "fesd" in opts:
        opts["fesd"] = FESDOptions(**opts["fesd"])
    return SimulateOptions(**opts)


def _run_record(case: str, variant: Variant, task, result, wall: float, contact: dict) -> dict:
    """The fields every simulation record has; errors are added by the caller."""
    st = result.stats
    return {"suite": "simulate", "simulator": "time-freezing", "case": case, "variant": variant.label, "h": result.h, "N": task.horizon.N,
            "tau_f": task.horizon.tau_f, "options": {"strategy": result.strategy, "rho_f": result.rho_f, **contact,
                                                     **{k: v for k, v in variant.options.items() if k not in ("strategy", "rho_f")}},
            "converged": st.converged, "wall_time_s": wall, "solve_time_s": st.solve_time_s, "n_nlp": st.n_nlp,
            "ipopt_iterations": st.ipopt_iterations, "complementarity_residual": st.complementarity_residual,
            "physical_duration_s": result.trajectory.physical_duration, "n_impacts": len(result.trajectory.impacts)}


def penetration(dyn: Dynamics, task, y: np.ndarray) -> float:
    """-min over the nodes y (K, ny) and the task's contact points of the gap [m] (> 0: below the ground).

    The nodes are the output's samples: with FESD the element ends only. The Radau stage states inside the elements
    are not in the SimulationResult, so a deeper gap there is not read."""
    q = np.asarray(y, float)[:, : dyn.nq].T  # (nq, K): one mapped call for all nodes
    gaps = [np.asarray(dyn.point_position(c.point).map(q.shape[1])(q))[2] - task.ground_height for c in task.contacts]
    return float(-np.min(gaps))


# points per interval of the samples where interpolated_error reads the linear interpolation: a parabola's chord error
# peaks mid-interval, which is one of them (8/16); an even number keeps it so
INTERP_SUBDIVISIONS = 16


def interpolated_error(t: np.ndarray, q: np.ndarray, exact: Drop, t_stop: float,
                       subdivisions: int = INTERP_SUBDIVISIONS) -> float:
    """max |q_lin(t) - q_exact(t)|_inf over [0, t_stop] [m], q_lin the samples (t (K,), q (K, nq)) joined by straight
    lines, as the Capler references and planner.replay read a trajectory: at `subdivisions` + 1 points of every sample
    interval of positive length (its ends too, so never below the samples' error) and at the exact first impact (its
    kink). The samples alone (state_error_m) miss the chord error between them, g dt^2 / 8 for dt between samples (a
    FESD element), where the FESD runs are exact at the samples. An impact's repeated time may hold two postures (the
    pre-impact sample above the ground, the landing): each interval joins its own two samples."""
    dt = np.diff(t)
    seg = np.nonzero((dt > 0) & (t[1:] <= t_stop))[0]
    frac = np.arange(subdivisions + 1) / subdivisions
    t1 = exact.impact_time
    kink = seg[(t[seg] < t1) & (t[seg + 1] > t1)]
    s = np.concatenate([np.broadcast_to(frac, (len(seg), len(frac))), ((t1 - t[kink]) / dt[kink])[:, None].repeat(
        len(frac), axis=1)])  # (S + kink, F) shares of the interval; the kink's row repeats its one point
    rows = np.concatenate([seg, kink])
    tt = t[rows, None] + s * dt[rows, None]
    q_lin = q[rows, None, :] + s[:, :, None] * (q[rows + 1] - q[rows])[:, None, :]
    return float(np.max(np.abs(q_lin - exact.q(tt.ravel()).reshape(q_lin.shape))))


def point_mass_records(case: PointMassCase, robot, dyn: Dynamics, repeat: int, log) -> list[dict]:
    """One record per (variant, h) of a point-mass case, errors against case.exact."""
    ex = case.exact
    records = []
    for variant in case.variants:
        contact = {"point": "point", **case.contact, **variant.contact}
        for h in variant.hs or case.hs:
            task = parse_task({"contacts": [contact], "initial": {"q": [ex.x0, ex.z0], "v": [ex.vx, 0.0]},
                               "horizon": {"tau_f": case.tau_f, "N": round(case.tau_f / h)}})
            result, wall = _timed(lambda: simulate(robot, task, _options(variant), dynamics=dyn), repeat)
            rec = _run_record(case.name, variant, task, result, wall, {k: v for k, v in contact.items() if k != "point"})
            tr = result.trajectory
            window = tr.t <= case.t_window
            covered = bool(tr.t[-1] >= case.t_window)  # a shorter window would understate the state error
            first = tr.impacts[0] if tr.impacts else None
            complete = first is not None and first.tau_end < tr.tau[-1]  # v_post is only known once the frozen interval ends
            # the contact phase alone (samples after both first impacts): in state_error_m the free-fall lead just
            # before the landing hides it, e.g. where no-slip friction stops the mass against the frictionless slide
            after = window & (tr.t > first.time) & (tr.t >= ex.impact_time) if complete else np.zeros_like(window)
            errors = {"state_error_m": float(np.max(np.abs(tr.q[window] - ex.q(tr.t[window])))) if covered else None,
                      "post_impact_error_m": float(np.max(np.abs(tr.q[after] - ex.q(tr.t[after]))))
                      if covered and after.any() else None,
                      "interpolated_error_m": interpolated_error(tr.t, tr.q, ex, case.t_window) if covered else None,
                      "impact_time_error_s": abs(first.time - ex.impact_time) if first else None,
                      "v_post_error_mps": float(np.max(np.abs(first.v_post - ex.v_post))) if complete else None,
                      "penetration_m": penetration(dyn, task, tr.y)}
            rec.update(errors=errors, window_covered=covered, first_impact_complete=complete)
            records.append(rec)
            log(rec)
    return records


# ==================================================================================================
# Capler under joint PD
# ==================================================================================================

@dataclass(frozen=True)
class CaplerDrop:
    """Capler dropped with its foot `drop` [m] above the ground while joint PD (kp [N m/rad], kd
    [N m s/rad] on hip and knee) holds the posture (hip, knee) [rad]; no-slip friction mu."""

    hs: tuple[float, ...]
    tau_f: float
    hold: tuple[float, float] = (0.0, 0.3)  # hip straight, knee bent: the foot 6 cm behind the hip
    drop: float = 0.05
    kp: float = 100.0
    kd: float = 2.0  # the law then stays inside the 60 N m motors on both simulators (tests/test_crosscheck.py)
    mu: float = 0.8
    mujoco_timesteps: tuple[float, ...] = (1e-3, 5e-4, 2.5e-4, 1.25e-4)
    variants: tuple[Variant, ...] = (Variant("default"),)
    # a second reference, FESD at this step: implicit Euler's fine grid is itself O(h_ref) off (its
    # impact 1.5e-4 s early), more than the FESD runs' own error; None skips it
    fesd_reference: Variant | None = None
    fesd_reference_h: float = 0.005

    def task(self, h: float):
        hip, knee = self.hold
        z_base = 0.2 * math.cos(hip) + 0.2 * math.cos(hip + knee) + self.drop  # thigh and shank are 0.2 m
        return parse_task({"contacts": [{"point": "foot", "mu": self.mu}], "initial": {"q": [0.0, z_base, hip, knee]},
                           "horizon": {"tau_f": self.tau_f, "N": round(self.tau_f / h)},
                           "simulate": {"pd": {"joints": ["hip", "knee"], "kp": [self.kp] * 2, "kd": [self.kd] * 2}}})


def _base_positions(scene, t_grid: np.ndarray, t: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Base origin (P, 3) [m] at t_grid (P,) of a trajectory sampled at t (K,) with postures q (K, nq):
    q is interpolated linearly (impacts are repeated samples with the same q, so q is continuous)."""
    q_grid = np.column_stack([np.interp(t_grid, t, q[:, i]) for i in range(q.shape[1])])
    return replay._planned_positions(scene, q_grid)[0]


def ballistic_flight_error(scene, case: CaplerDrop, t: np.ndarray, q: np.ndarray,
                           landing: float | None) -> float | None:
    """max |p_base - p_base_exact|_2 [m] over the samples t (K,), q (K, nq) before the earlier of the run's first
    impact (`landing`, None: none) and the exact one sqrt(2 drop / g): there the held posture falls rigidly (PD of zero
    error and zero speed: no torque), so the exact motion is the base's parabola with the joints still. Unlike the
    fine-grid and MuJoCo references, it has no step of its own. None without a sample before the landing."""
    t_exact = math.sqrt(2.0 * case.drop / G)
    stop = t_exact if landing is None else min(landing, t_exact)
    keep = t < stop
    if not keep.any():
        return None
    q0 = np.asarray(case.task(case.hs[0]).initial.q, float)
    q_exact = np.tile(q0, (int(keep.sum()), 1))
    q_exact[:, 1] -= G * t[keep] ** 2 / 2  # base z: the free fall
    base, base_exact = replay._planned_positions(scene, q[keep])[0], replay._planned_positions(scene, q_exact)[0]
    return float(np.linalg.norm(base - base_exact, axis=1).max())


def capler_records(case: CaplerDrop, repeat: int, log) -> tuple[list[dict], dict]:
    """Records of the Capler drop over case.hs (errors vs the fine-grid run and vs MuJoCo), plus the
    MuJoCo timestep records, and a dict describing both references."""
    robot = load_robot("capler")
    dyn = Dynamics(robot)
    h_ref = min(case.hs) / REFERENCE_REFINEMENT
    ref_task = case.task(h_ref)
    ref, ref_wall = _timed(lambda: simulate(robot, ref_task, dynamics=dyn), 1)
    if not ref.stats.converged:
        raise RuntimeError(f"the Capler reference run (h = {h_ref:g} s) did not converge: {ref.stats.message}")
    law = pd_law(robot, ref_task)

    def control(t, q, v):  # the simulation's law, evaluated at MuJoCo's state (explicit in MuJoCo)
        return law(ref_task.simulate.controls_at(t, robot.nu), q, v)

    def rollout(timestep: float):
        scene = replay.build_scene(robot, ref_task, replay.ContactSettings(timestep=timestep))
        return scene, replay.mujoco_rollout(scene, ref_task.initial.q, np.zeros(robot.nv), ref.trajectory.t[-1], control)

    (scene, mj), mj_wall = _timed(lambda: rollout(replay.ContactSettings().timestep), repeat)
    t_end = min(ref.trajectory.t[-1], mj["t"][-1])
    exact_impact = math.sqrt(2.0 * case.drop / G)  # the held posture falls rigidly: the foot is ballistic
    refs = {"capler_reference": {"h": h_ref, "N": ref_task.horizon.N, "wall_time_s": ref_wall,
                                 "impact_time_s": ref.trajectory.impacts[0].time if ref.trajectory.impacts else None,
                                 "n_nlp": ref.stats.n_nlp},
            "capler_mujoco": {"timestep": replay.ContactSettings().timestep, "wall_time_s": mj_wall,
                              "impact_time_s": float(mj["impact_times"][0]) if mj["impact_times"].size else None},
            "capler_exact_impact_time_s": exact_impact}
    # the references against the exact flight: they lag as the runs do (implicit Euler's fine grid by O(h_ref))
    refs["capler_reference"]["flight_error_exact_m"] = ballistic_flight_error(
        scene, case, ref.trajectory.t, ref.trajectory.q, refs["capler_reference"]["impact_time_s"])
    refs["capler_mujoco"]["flight_error_exact_m"] = ballistic_flight_error(
        scene, case, mj["t"], mj["q"], refs["capler_mujoco"]["impact_time_s"])
    fesd_ref = None
    if case.fesd_reference is not None:
        fesd_task = case.task(case.fesd_reference_h)
        fesd_ref, fesd_wall = _timed(lambda: simulate(robot, fesd_task, _options(case.fesd_reference), dynamics=dyn), 1)
        if not fesd_ref.stats.converged:
            raise RuntimeError(f"the Capler FESD reference run did not converge: {fesd_ref.stats.message}")
        t_end = min(t_end, fesd_ref.trajectory.t[-1])
        refs["capler_reference_fesd"] = {"h": case.fesd_reference_h, "N": fesd_task.horizon.N, "wall_time_s": fesd_wall,
                                         "options": case.fesd_reference.options, "n_nlp": fesd_ref.stats.n_nlp,
                                         "impact_time_s": fesd_ref.trajectory.impacts[0].time if fesd_ref.trajectory.impacts else None}
        refs["capler_reference_fesd"]["flight_error_exact_m"] = ballistic_flight_error(
            scene, case, fesd_ref.trajectory.t, fesd_ref.trajectory.q, refs["capler_reference_fesd"]["impact_time_s"])
    default_against = ("ref", "mujoco") + (("fesd_ref",) if fesd_ref is not None else ())

    def compare(t, q, impacts, t_stop, against=default_against):
        """Base error [m] at the run's own samples in [0, t_stop] and first impact time difference [s]
        against the fine-grid run ("ref") and the default MuJoCo rollout ("mujoco"); impact time
        difference to the exact one. Only the references are interpolated (at their finer steps):
        interpolating the run itself would add its chord error h^2 |a| / 8 (4.9e-4 m at h = 0.02 s
        under gravity), which hid FESD's accuracy behind a second-order floor."""
        keep = t <= t_stop
        grid, first_of = np.unique(t[keep], return_index=True)
        base = replay._planned_positions(scene, q[keep][first_of])[0]
        others = {"ref": (ref.trajectory.t, ref.trajectory.q, refs["capler_reference"]["impact_time_s"]),
                  "mujoco": (mj["t"], mj["q"], refs["capler_mujoco"]["impact_time_s"])}
        if fesd_ref is not None:
            others["fesd_ref"] = (fesd_ref.trajectory.t, fesd_ref.trajectory.q, refs["capler_reference_fesd"]["impact_time_s"])
        first = impacts[0] if len(impacts) else None
        err = {}
        for key in against:
            t_o, q_o, impact_o = others[key]
            err[f"base_error_{key}_m"] = float(np.linalg.norm(base - _base_positions(scene, grid, t_o, q_o), axis=1).max())
            err[f"impact_time_diff_{key}_s"] = abs(first - impact_o) if first is not None and impact_o is not None else None
        err["impact_time_diff_exact_s"] = abs(first - exact_impact) if first is not None else None
        err["flight_error_exact_m"] = ballistic_flight_error(scene, case, t, q, first)
        return err

    records = []
    for variant in case.variants:
        for h in variant.hs or case.hs:
            task = case.task(h)
            result, wall = _timed(lambda: simulate(robot, task, _options(variant), dynamics=dyn), repeat)
            rec = _run_record("capler_pd_drop", variant, task, result, wall, {"mu": case.mu, "a_n": task.contacts[0].a_n, "a_t": task.contacts[0].a_t})
            tr = result.trajectory
            errors = compare(tr.t, tr.q, tr.impact_times, min(t_end, tr.t[-1]))
            errors["penetration_m"] = penetration(dyn, task, tr.y)
            rec.update(errors=errors, steps_beyond_actuator_bounds=result.extra["pd"]["steps_beyond_actuator_bounds"])
            records.append(rec)
            log(rec)
    for timestep in case.mujoco_timesteps:  # MuJoCo's own work-precision line, judged by the fine-grid run
        (_, run), wall = _timed(lambda: rollout(timestep), repeat)
        errors = compare(run["t"], run["q"], run["impact_times"], min(t_end, run["t"][-1]), against=("ref",) + default_against[2:])
        rec = {"suite": "simulate", "simulator": "mujoco", "case": "capler_pd_drop_mujoco", "variant": "default", "h": timestep,
               "N": len(run["t"]) - 1, "tau_f": float(run["t"][-1]), "options": {"simulator": f"mujoco {mujoco.__version__}"},
               "converged": True, "wall_time_s": wall, "errors": errors}
        records.append(rec)
        log(rec)
    return records, refs


# ==================================================================================================
# the OCP suite: the planner's wall time against the accuracy of its plan, over the grid N
# ==================================================================================================

# The defect windows: restart the simulation every DEFECT_WINDOW_S of the plan's physical time
DEFECT_WINDOW_S = 0.1
# numerical time of a window's simulation per second of physical time: room for its frozen intervals
DEFECT_TAU_MARGIN = 1.25
# Capler grids (h = 2.5 s / N): N = 50 plans in 66-90 s on the shared 2-core machine, the task's own N = 125 in ~5 min
CAPLER_NS = (40, 50, 75, 100)
ROBOTS = Path(__file__).resolve().parents[1] / "robots"
# the errors whose slope against h is reported (the others are the plan's optimum, not the grid's)
OCP_ORDER_KEYS = ("defect_base_m", "defect_points_m", "flight_error_m", "landing_time_error_s", "tracking_window_mean_m")


@dataclass(frozen=True)
class OcpCase:
    """A planning task over the grids Ns (h = tau_f / N): name, robot name (robots/NAME.xml), the task
    at a given N (task(N) -> Task), and whether the flight phases are checked against the exact
    constant-acceleration solution (only true for the point mass, whose contact point is q = (x, z))."""

    name: str
    robot: str
    task: Callable[[int], Task]
    Ns: tuple[int, ...]
    exact_flight: bool = False
    repeat: bool = True  # honour --repeat (the Capler plans run once: minutes each)


def point_mass_hop_task(N: int):
    """The point-mass hop of tests/test_problem.py: at rest on the ground (mu = 0.5, no slip), asked to
    be at x = 0.5 m at tau_f = 1 s with |u| <= 30 N; it must hop."""
    return parse_task({"contacts": [{"point": "point", "mu": 0.5}], "initial": {"q": [0.0, 0.0]},
                       "horizon": {"tau_f": 1.0, "N": N}, "plan": {"target_q": [0.5, 0.0], "u_bound": 30.0}})


def capler_task(N: int):
    """robots/capler.toml (three holes, tau_f = 2.5 s) on N steps."""
    task = load_task(ROBOTS / "capler.toml")
    return dataclasses.replace(task, horizon=dataclasses.replace(task.horizon, N=N))


def ocp_cases(quick: bool, capler_Ns: tuple[int, ...] | None = None) -> list[OcpCase]:
    """The point-mass hop (quick: N = 20, 40) and, unless quick, Capler over capler_Ns (default
    CAPLER_NS; the task's own N = 125 takes ~5 min and is left to --capler-N)."""
    pm = OcpCase("ocp_pm_hop", "point_mass", point_mass_hop_task, (20, 40) if quick else (20, 30, 40, 60, 80), exact_flight=True)
    if quick:
        return [pm]
    return [pm, OcpCase("ocp_capler", "capler", capler_task, tuple(capler_Ns or CAPLER_NS), repeat=False)]


def control_pieces(t: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The zero-order-hold controls of physical-time samples t (P,), u (P, nu) (u[i] acts on
    [t[i-1], t[i]), planner.result.recover) as pieces: start times (M,) [s] and controls (M, nu).
    Impacts (repeated times) hold no piece."""
    keep = np.diff(t) > 0
    return t[:-1][keep], u[1:][keep]


def open_loop_schedule(t: np.ndarray, u: np.ndarray, t0: float, t1: float) -> tuple[ControlChange, ...]:
    """task.simulate.schedule that replays the plan's controls (samples t (P,), u (P, nu)) open loop on
    [t0, t1] of its physical time, with the simulation's clock starting at t0 (schedule time t - t0 >= 0)."""
    starts, controls = control_pieces(t, u)
    idx = np.nonzero((starts >= t0 - 1e-12) & (starts < t1))[0]
    before = np.nonzero(starts < t0 - 1e-12)[0]  # the piece running at t0 (t0 inside a piece)
    if before.size and (not idx.size or starts[idx[0]] > t0 + 1e-12):
        idx = np.concatenate([[before[-1]], idx])
    return tuple(ControlChange(t=max(float(starts[i] - t0), 0.0), u=tuple(float(x) for x in controls[i])) for i in idx)


def _window_starts(t: np.ndarray, window: float) -> list[int]:
    """Sample indices of the defect windows: the first sample at or after each multiple of `window`
    [s] of physical time that is not an impact (its time is not repeated), leaving >= window / 2 of
    plan after it."""
    unique = np.ones(len(t), bool)
    unique[1:] &= np.diff(t) > 0
    unique[:-1] &= np.diff(t) > 0
    out = []
    for start in np.arange(t[0], t[-1] - window / 2, window):
        cand = np.nonzero(unique & (t >= start - 1e-12))[0]
        if cand.size and t[cand[0]] < start + window / 2 and (not out or cand[0] > out[-1]):
            out.append(int(cand[0]))
    return out


def resimulation_defect(robot, dyn: Dynamics, task, traj, scene, refinement: int = REFERENCE_REFINEMENT,
                        window: float = DEFECT_WINDOW_S) -> dict:
    """The plan's local defect against a fine time-freezing simulation of its own controls.

    From the plan's state (q, v) at each window start (every `window` s of physical time, _window_starts)
    planner.simulate runs the task's contacts with the plan's controls held as planned (open loop,
    open_loop_schedule) on the step h / refinement for `window` s of physical time; the defect is the
    largest distance of the base origin and of the contact points from the plan at the plan's own
    samples in each window (the fine run interpolated linearly there) [m]. The windows restart from the
    plan, so a feedback-free drift of the unstable robot does not grow over the whole plan, and every
    plan is judged against its own dynamics (the plans of different N are different local optima).
    A contact point slightly below the ground at a start (the plan's complementarity tolerance,
    <= 1e-6 m) lowers that window's ground by as much: the simulation must start in c >= 0.
    Returns defect_base_m, defect_points_m, the windows' count, the failed ones, and their wall time [s].
    """
    t, q, v, u = traj.t, traj.q, traj.v, traj.u
    h_ref = task.horizon.h / refinement
    n_steps = max(1, math.ceil(DEFECT_TAU_MARGIN * window / h_ref))
    gap_fns = [dyn.point_position(c.point) for c in task.contacts]
    # None until a window is measured: a plan of no measurable window read as a defect of 0 (perfect)
    base_err, point_err, failed, per_window, start = None, None, [], [], time.perf_counter()
    for i0 in _window_starts(t, window):
        t0, t1 = float(t[i0]), min(float(t[i0]) + window, float(t[-1]))
        low = min(float(np.asarray(f(q[i0])).ravel()[2]) for f in gap_fns) - task.ground_height
        w_task = dataclasses.replace(
            task, plan=None, ground_height=task.ground_height + min(low, 0.0),
            initial=Initial(q=tuple(map(float, q[i0])), v=tuple(map(float, v[i0]))),
            horizon=Horizon(tau_f=n_steps * h_ref, N=n_steps),
            simulate=Simulate(schedule=open_loop_schedule(t, u, t0, t1), rho_f=task.plan.rho_f))
        sim = simulate(robot, w_task, dynamics=dyn)
        if not sim.stats.converged:
            failed.append(round(t0, 6))  # its solved steps still count, up to where they reach
        st = sim.trajectory
        keep = (t > t0) & (t <= min(t1, t0 + st.t[-1]))
        if not keep.any():
            per_window.append((t0, None, None))
            continue
        q_sim = np.column_stack([np.interp(t[keep] - t0, st.t, st.q[:, j]) for j in range(robot.nq)])
        base_p, pts_p = replay._planned_positions(scene, q[keep])
        base_s, pts_s = replay._planned_positions(scene, q_sim)
        per_window.append((t0, float(np.linalg.norm(base_p - base_s, axis=1).max()), float(np.linalg.norm(pts_p - pts_s, axis=2).max())))
        base_err, point_err = (per_window[-1][j] if err is None else max(err, per_window[-1][j])
                               for j, err in ((1, base_err), (2, point_err)))
    return {"defect_base_m": base_err, "defect_points_m": point_err, "windows": len(per_window), "failed_windows": failed,
            "per_window": [{"t0": a, "base_m": b, "points_m": c} for a, b, c in per_window],
            "h_ref": h_ref, "window_s": window, "wall_time_s": time.perf_counter() - start}


# a sample "is on the ground" when the point mass is less than this above it [m] (the plan's
# complementarity tolerance is 1e-6; a step of flight lifts it by mm)
GROUND_TOL_M = 1e-6


def first_flight(traj, iz: int, ground: float) -> tuple[int, float] | None:
    """(take-off sample index, landing impact time [s]) of the plan's first flight: the first impact
    preceded by samples above the ground (height q[:, iz] > ground + GROUND_TOL_M) with at most one
    ground sample (the touchdown node) between them and the impact; take-off is the last ground
    sample before those. None when no impact ends a flight (an impact at rest is no landing)."""
    t, z = traj.t, traj.q[:, iz] - ground
    for imp in traj.impacts:
        i = int(np.searchsorted(t, imp.time - 1e-12))  # the impact's pre-impact sample
        j = i - 1 if i >= 1 and z[i - 1] <= GROUND_TOL_M else i
        k = j - 1
        while k >= 0 and z[k] > GROUND_TOL_M:
            k -= 1
        if k < j - 1 and k >= 0:
            return k, imp.time
    return None


def exact_flight(robot, dyn: Dynamics, task, traj) -> dict | None:
    """The plan's first flight (first_flight) against the exact solution of its own controls (point
    mass only: the contact point is q = (x, z) and the acceleration M^-1 (B u - h) is constant per
    control piece; the plans push in flight too, so the motion is not the ballistic parabola).

    From the plan's state at take-off the exact motion under the plan's zero-order-hold controls is
    one parabola per control piece, landing where z reaches the ground. Returns flight_error_m (max
    |q - q_exact|_inf over the plan's samples strictly between take-off and the earlier of the two
    landings [m]), landing_time_error_s (|the plan's impact - the exact landing| [s]; None when the
    exact motion does not land within the plan), the take-off, plan and exact landing times [s] and
    the number of samples compared; None when the plan has no flight."""
    iz, zg = robot.dof_index("z"), task.ground_height
    flight = first_flight(traj, iz, zg)
    if flight is None:
        return None
    i0, plan_landing = flight
    t, q, v = traj.t, traj.q, traj.v
    takeoff_time = float(t[i0])
    starts, controls = control_pieces(t, traj.u)
    ends = np.append(starts[1:], t[-1])
    qk, vk, tk = q[i0].astype(float), v[i0].astype(float), takeoff_time
    pieces, landing = [], None  # (start [s], q, v, acceleration) of each exact parabola
    for s1, uk in zip(ends, controls):
        if s1 <= tk + 1e-12:
            continue
        a = np.asarray(dyn.forward(qk, vk, uk), float).ravel()
        pieces.append((tk, qk, vk, a))
        dt = s1 - tk
        # z(s) = z + vz s + az s^2 / 2 comes down on the ground at the smallest root in (0, dt] where it
        # falls (a take-off state at the ground, z ~ 1e-9 m, has a rising root near 0: not a landing)
        roots = np.roots([a[iz] / 2, vk[iz], qk[iz] - zg])
        hits = [r.real for r in np.atleast_1d(roots) if abs(r.imag) < 1e-12 and 0 < r.real <= dt + 1e-9 and vk[iz] + a[iz] * r.real < 0]
        if hits:
            landing = tk + min(hits)
            break
        qk, vk, tk = qk + vk * dt + a * dt**2 / 2, vk + a * dt, float(s1)
    stop = min(x for x in (landing, plan_landing) if x is not None)
    inside = np.nonzero((t > takeoff_time + 1e-12) & (t < stop - 1e-12))[0]
    err = 0.0
    for i in inside:
        s0, qs, vs, a = [p for p in pieces if p[0] <= t[i]][-1]
        s = t[i] - s0
        err = max(err, float(np.max(np.abs(q[i] - (qs + vs * s + a * s**2 / 2)))))
    return {"flight_error_m": err if inside.size else None,
            "landing_time_error_s": abs(plan_landing - landing) if landing is not None else None,
            "takeoff_time_s": takeoff_time, "plan_landing_time_s": plan_landing, "exact_landing_time_s": landing,
            "flight_samples": int(inside.size)}


def window_errors(windows: replay.WindowReport) -> dict:
    """The windowed MuJoCo tracking (validate's windows: each window's largest base error [m]) as its mean, median and
    worst window: tracking_window_{mean,median,worst}_m; the mean alone hid whether one window or all were off. None
    without windows (no 0.0: it read as perfect tracking)."""
    has = bool(windows.max_base_error_m)
    return {"tracking_window_mean_m": windows.mean_m if has else None,
            "tracking_window_median_m": windows.median_m if has else None,
            "tracking_window_worst_m": windows.worst_m if has else None}


def _plan(robot, task, dyn: Dynamics):
    """build_problem + solve with the planner's defaults; (result, build wall [s])."""
    start = time.perf_counter()
    problem = build_problem(robot, task, dynamics=dyn)
    build = time.perf_counter() - start
    return solve(problem, SolveOptions()), build


def ocp_records(case: OcpCase, repeat: int, log) -> list[dict]:
    """One record per N of an OCP case: wall time (build_problem + solve), IPOPT iterations, converged,
    hops, impacts and the errors (penetration, terminal error, MuJoCo tracking, re-simulation defect;
    point mass also the exact flight and landing)."""
    robot = load_robot(case.robot)
    dyn = Dynamics(robot)
    records = []
    for N in case.Ns:
        task = case.task(N)
        (result, build), wall = _timed(lambda: _plan(robot, task, dyn), repeat if case.repeat else 1)
        tr, st = result.trajectory, result.stats
        rec = {"suite": "ocp", "simulator": "planner", "case": case.name, "variant": "default", "h": task.horizon.h, "N": N,
               "tau_f": task.horizon.tau_f, "options": {"solve": "SolveOptions() defaults", "holes": len(task.plan.holes)},
               "converged": st.converged, "message": st.message, "wall_time_s": wall, "build_time_s": build,
               "solve_time_s": st.solve_time_s, "n_nlp": st.n_nlp, "ipopt_iterations": st.ipopt_iterations,
               "nlps_failed": [r.label for r in result.nlps if not r.success], "polished": result.polished,
               "complementarity_residual": st.complementarity_residual, "physical_duration_s": tr.physical_duration,
               "n_impacts": len(tr.impacts), "hops": len(result.hops)}
        errors = {"penetration_m": penetration(dyn, task, tr.y), "terminal_error": result.terminal_error}
        if len(tr.t) > 1:
            validation = replay.validate_plan(robot, task, tr)
            errors["tracking_error_m"] = validation.max_tracking_error_m
            errors.update(window_errors(validation.windows))  # restarted every 25 ms for 0.1 s
            # each impact against MuJoCo's onset in the window started 25-50 ms before it; "none" (a push-off in a
            # stance, a tap) is not an error of the impact's time, so the share MuJoCo sees as a landing goes beside it
            windows = validation.windows
            errors["window_impact_time_error_s"] = windows.max_abs_impact_time_difference_s
            rec["window_impacts_landed"] = [windows.landed, len(windows.impacts)]
            errors["tracking_point_error_m"] = max(validation.tracking.max_foot_error_m.values(), default=None)
            rec["tracking_diverged"] = validation.tracking.diverged
            scene = replay.build_scene(robot, task)
            defect = resimulation_defect(robot, dyn, task, tr, scene)
            errors["defect_base_m"], errors["defect_points_m"] = defect.pop("defect_base_m"), defect.pop("defect_points_m")
            rec["defect"] = defect
        flight = exact_flight(robot, dyn, task, tr) if case.exact_flight else None
        if flight is not None:
            errors["flight_error_m"], errors["landing_time_error_s"] = flight.pop("flight_error_m"), flight.pop("landing_time_error_s")
            rec["flight"] = flight
        rec["errors"] = errors
        records.append(rec)
        log(rec)
    return records


def run_ocp_suite(quick: bool, repeat: int, log, cases: set[str] | None = None, capler_Ns: tuple[int, ...] | None = None) -> tuple[list[dict], dict]:
    """All OCP records; `cases` restricts to case names (None: all). No references: each plan is judged
    against its own dynamics and the exact flight (returned dict: how)."""
    records = []
    for case in ocp_cases(quick, capler_Ns):
        if cases is None or case.name in cases:
            records += ocp_records(case, repeat, log)
    refs = {"defect": {"refinement": REFERENCE_REFINEMENT, "window_s": DEFECT_WINDOW_S, "simulator": "planner.simulate (implicit Euler, stepwise)"}}
    return records, refs


# ==================================================================================================
# the suites
# ==================================================================================================

def simulate_cases(quick: bool) -> tuple[list[PointMassCase], CaplerDrop]:
    """The point-mass cases and the Capler drop; quick: 2 grid points, short horizons (CI smoke run)."""
    hs = (0.04, 0.02) if quick else (0.04, 0.02, 0.01, 0.005, 0.0025)
    # tau_f leaves room for the frozen interval (longest with a_n = 25) after the impact at 0.45 s
    drop_tau, drop_window = (0.8, 0.5) if quick else (1.2, 0.8)
    frictionless = {"mu": 0.0, "a_n": 100.0}
    drop = Drop(z0=1.0, vx=1.0)
    # FESD: n_fe = 3 elements per step, since the step with the impact can also hold the end of the
    # frozen interval (|v| / a_n = 0.044 s of numerical time): two switches
    fesd = (fesd_variant(2, 3),) if quick else tuple(fesd_variant(n_s, 3, (0.04, 0.02, 0.01)) for n_s in (1, 2, 3))
    variants = (Variant("default"), Variant("rho_f=0.1", options={"rho_f": 0.1}), Variant("rho_f=10", options={"rho_f": 10.0}),
                Variant("a_n=25", contact={"a_n": 25.0}), Variant("a_n=400", contact={"a_n": 400.0}),
                Variant("horizon", options={"strategy": "horizon"})) + fesd
    # k = a_n = 16: each elastic frozen interval lasts ~0.8 s of numerical time; the window ends before
    # the exact second impact (0.90 s), after the first apex (0.68 s); at h = 0.04 the restitution comes
    # out low (0.2), the bounces are shorter and 3.6 s of numerical time are needed to reach t = 0.85 s
    elastic_tau = 1.6 if quick else 3.6
    cases = [PointMassCase("pm_drop_frictionless", frictionless, drop, drop_tau, drop_window, hs, variants),
             PointMassCase("pm_drop_noslip", {"mu": 0.5, "a_n": 100.0, "a_t": 300.0}, Drop(z0=1.0, vx=1.0, no_slip=True),
                           drop_tau, drop_window, hs),
             PointMassCase("pm_drop_elastic_0.5", {"restitution": 0.5, "a_n": 16.0}, Drop(z0=1.0, restitution=0.5),
                           elastic_tau, 0.5 if quick else 0.85, hs)]
    # FESD on Capler: n_fe = 4, since the impact step holds the landing, the ends of the normal and the
    # tangential jump (a_n = 200, a_t = 600) and the start of sticking
    capler_fesd = () if quick else tuple(fesd_variant(n_s, 4, (0.02, 0.01)) for n_s in (1, 2, 3))
    # implicit Euler down to h = 1 ms: at 1.25 ms it costs what FESD n_s = 2 costs at h = 0.01 s, at 1 ms a
    # little more (a direct run at equal wall time)
    capler = CaplerDrop(hs=(0.02, 0.01) if quick else (0.02, 0.01, 0.005, 0.0025, 0.00125, 0.001), tau_f=0.2 if quick else 0.5,
                        mujoco_timesteps=(5e-4, 2.5e-4) if quick else CaplerDrop.mujoco_timesteps,
                        variants=(Variant("default"),) + capler_fesd, fesd_reference=None if quick else fesd_variant(2, 4))
    return cases, capler


def run_simulate_suite(quick: bool, repeat: int, log, cases: set[str] | None = None) -> tuple[list[dict], dict]:
    """All simulation records and the references; `cases` restricts to case names (None: all)."""
    pm_cases, capler = simulate_cases(quick)
    robot = load_robot("point_mass")
    dyn = Dynamics(robot)  # built once: its cost belongs to the robot, not to a run
    records, refs = [], {}
    for case in pm_cases:
        if cases is None or case.name in cases:
            records += point_mass_records(case, robot, dyn, repeat, log)
    if cases is None or "capler_pd_drop" in cases:
        capler_recs, refs = capler_records(capler, repeat, log)
        records += capler_recs
    return records, refs


SUITES = {"simulate": run_simulate_suite, "ocp": run_ocp_suite}
CASE_NAMES = ("pm_drop_frictionless", "pm_drop_noslip", "pm_drop_elastic_0.5", "capler_pd_drop")  # suite "simulate"
OCP_CASE_NAMES = ("ocp_pm_hop", "ocp_capler")  # suite "ocp"


# ==================================================================================================
# orders, machine, outputs
# ==================================================================================================

def convergence_orders(records: list[dict], keys: tuple[str, ...] | None = None) -> list[dict]:
    """Slope of log(error) against log(h) per (case, variant, error) of the time-freezing simulations
    and plans, over the converged runs with an error above ERROR_FLOOR (below it the error is the
    solver's, not the grid's); keys: only these errors (None: all)."""
    out = []
    tf = [r for r in records if r["simulator"] in ("time-freezing", "planner") and r["converged"]]
    for case, variant in sorted({(r["case"], r["variant"]) for r in tf}):
        runs = [r for r in tf if (r["case"], r["variant"]) == (case, variant)]
        for key in sorted({k for r in runs for k in r["errors"] if keys is None or k in keys}):
            pts = [(r["h"], r["errors"][key]) for r in runs if r["errors"].get(key) is not None and r["errors"][key] > ERROR_FLOOR]
            if len({h for h, _ in pts}) >= 2:
                hs, errs = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
                out.append({"case": case, "variant": variant, "error": key, "order": float(np.polyfit(hs, errs, 1)[0]),
                            "h": [p[0] for p in pts]})
    return out


def machine_info() -> dict:
    """The shared machine record (scripts._report.machine_info: platform, CPU model, cores, load, date UTC) with the
    memory [GiB] and this benchmark's library versions."""
    meminfo = Path("/proc/meminfo")
    lines = meminfo.read_text().splitlines() if meminfo.is_file() else []
    kib = next((int(line.split()[1]) for line in lines if line.startswith("MemTotal")), None)
    return {**shared_machine_info(), "memory_gib": round(kib / 2**20, 1) if kib else None,
            "pinocchio": pinocchio.__version__, "mujoco": mujoco.__version__, "matplotlib": matplotlib.__version__}


# Which error each panel of the plot shows, by case: (panel title, error key per case prefix)
PANELS = (("position error [m]\npoint mass: max |q - q_exact|; Capler: base vs FESD n_s=2 at 5 ms (else IE fine grid)",
           {"pm_": "state_error_m", "capler_": ("base_error_fesd_ref_m", "base_error_ref_m")}),
          ("impact time error [s]\npoint mass: vs sqrt(2 z0/g); Capler: vs sqrt(2 drop/g)", {"pm_": "impact_time_error_s", "capler_": "impact_time_diff_exact_s"}))
# the OCP suite's panels: the plan against a fine simulation of its own controls, against MuJoCo,
# and (point mass) against the exact flight
OCP_PANELS = (("re-simulation defect [m]\nbase vs implicit Euler at h/8 from the plan's state, every 0.1 s", {"ocp_": "defect_base_m"}),
              ("MuJoCo tracking error [m]\nbase, joint PD, mean over 0.1 s windows from the plan (planner validate)",
               {"ocp_": "tracking_window_mean_m"}),
              ("flight error [m]\npoint mass: max |q - q_exact| from its take-off", {"ocp_pm": "flight_error_m"}))
MARKERS = "osD^vPX*hp<>"


def plot(records: list[dict], path: Path, panels=PANELS) -> None:
    """Log-log error against wall time: one panel per entry of `panels`, one line per (case,
    variant), one marker per h."""
    fig = Figure(figsize=(6 * len(panels), 5))
    FigureCanvasAgg(fig)
    hs = sorted({r["h"] for r in records}, reverse=True)
    marker = {h: MARKERS[i % len(MARKERS)] for i, h in enumerate(hs)}
    lines = sorted({(r["case"], r["variant"]) for r in records}, key=lambda cv: (cv[0], cv[1] != "default", cv[1]))
    axes = fig.subplots(1, len(panels))
    for ax, (title, keys) in zip(axes, panels):
        for i, (case, variant) in enumerate(lines):
            key = next((k for prefix, k in keys.items() if case.startswith(prefix)), None)
            if key is None:  # a panel for some cases only
                continue
            if isinstance(key, tuple):  # the first key the runs have (the quick run has no FESD reference)
                key = next((k for k in key if any(r["errors"].get(k) is not None for r in records if r["case"] == case)), key[-1])
            runs = sorted((r for r in records if (r["case"], r["variant"]) == (case, variant) and r["converged"]
                           and (r["errors"].get(key) or 0) > 0), key=lambda r: -r["h"])  # refinement order
            if not runs:
                continue
            color = matplotlib.colormaps["tab20"](i % 20)  # 11 lines in the quick run: tab10 gave two the same blue
            style = "--" if variant.startswith("fesd") else "-"  # FESD lines dashed: told apart from implicit Euler at a glance
            ax.plot([r["wall_time_s"] for r in runs], [r["errors"][key] for r in runs], style, color=color,
                    label=case if variant == "default" else f"{case} {variant}")
            for r in runs:
                ax.plot(r["wall_time_s"], r["errors"][key], marker[r["h"]], color=color, markersize=6)
        ax.set(xscale="log", yscale="log", xlabel="wall time [s]", ylabel=title.split("\n")[0])
        # (times within ~1.5 decades got labelled minor ticks, 2x10^-1 3x10^-1 ..., overlapping; times between two
        # powers of ten keep them: they are the axis' only numbers, 2.4 and 8.2 s had none)
        lo, hi = ax.get_xlim()
        if math.floor(math.log10(hi)) > math.floor(math.log10(lo)):
            ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_title(title, fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    h_handles = [axes[1].plot([], [], MARKERS[i % len(MARKERS)], color="gray")[0] for i, _ in enumerate(hs)]
    right = 1 - 0.23 * 2 / len(panels)  # the legend column keeps its width
    fig.legend(handles + h_handles, labels + [f"h = {h:g} s" for h in hs], loc="center left", bbox_to_anchor=(right + 0.005, 0.5), fontsize=7)
    fig.subplots_adjust(left=0.06 * 2 / len(panels), right=right, wspace=0.22)
    save_figure(fig, path, dpi=80)


def table(records: list[dict]) -> str:
    """A Markdown table of the records (errors in their own units, times in s)."""
    keys = ["state_error_m", "post_impact_error_m", "interpolated_error_m", "base_error_ref_m", "base_error_fesd_ref_m",
            "base_error_mujoco_m", "flight_error_exact_m", "impact_time_error_s", "impact_time_diff_ref_s",
            "impact_time_diff_mujoco_s", "impact_time_diff_exact_s", "v_post_error_mps", "penetration_m"]
    keys = [k for k in keys if any(r["errors"].get(k) is not None for r in records)]
    lines = ["| case | variant | h [s] | N | wall [s] | NLPs | " + " | ".join(keys) + " |", "|---" * (6 + len(keys)) + "|"]
    for r in records:
        cells = [r["case"], r["variant"], f"{r['h']:g}", str(r["N"]), f"{r['wall_time_s']:.2f}" + ("" if r["converged"] else " (failed)"),
                 str(r.get("n_nlp", "")), *(("" if r["errors"].get(k) is None else f"{r['errors'][k]:.2e}") for k in keys)]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def ocp_table(records: list[dict]) -> str:
    """A Markdown table of the OCP records (errors in m or s, times in s)."""
    keys = ["defect_base_m", "defect_points_m", "tracking_error_m", "tracking_window_mean_m",
            "tracking_window_median_m", "tracking_window_worst_m", "window_impact_time_error_s", "flight_error_m",
            "landing_time_error_s", "penetration_m", "terminal_error"]
    keys = [k for k in keys if any(r["errors"].get(k) is not None for r in records)]
    lines = ["| case | N | h [s] | wall [s] | IPOPT it | converged | hops | impacts | " + " | ".join(keys) + " |", "|---" * (8 + len(keys)) + "|"]
    for r in records:
        cells = [r["case"], str(r["N"]), f"{r['h']:g}", f"{r['wall_time_s']:.1f}", str(r["ipopt_iterations"]),
                 "yes" if r["converged"] else "no", str(r["hops"]), str(r["n_impacts"]),
                 *(("" if r["errors"].get(k) is None else f"{r['errors'][k]:.2e}") for k in keys)]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _strict(obj):
    """obj with numpy scalars as Python numbers and non-finite floats as None (strict JSON)."""
    if isinstance(obj, dict):
        return {k: _strict(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_strict(v) for v in obj]
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def main(argv: list[str] | None = None) -> int:
    parser = script_parser(__doc__)
    parser.add_argument("--out", type=out_dir, help=f"output directory (default {DEFAULT_OUT}, suite ocp: {DEFAULT_OUT_OCP})")
    parser.add_argument("--quick", action="store_true", help="CI smoke run: 2 grid points, short horizons (ocp: the point mass only)")
    parser.add_argument("--json", action="store_true", help="print the summary (orders, machine, files) as JSON")
    parser.add_argument("--suite", choices=sorted(SUITES), default="simulate",
                        help="simulate (default: the simulator's cases against exact solutions) or ocp (plans)")
    parser.add_argument("--cases", nargs="+", choices=CASE_NAMES + OCP_CASE_NAMES, help="run only these cases of the suite (default: all)")
    parser.add_argument("--repeat", type=int, default=1, help="runs per point; the wall time is their median (ocp: not Capler, planned once)")
    parser.add_argument("--capler-N", type=int, nargs="+", metavar="N",
                        help=f"suite ocp: the Capler grids (default {' '.join(map(str, CAPLER_NS))}; the task's own 125 takes ~5 min)")
    args = parser.parse_args(argv)
    if args.repeat < 1:
        parser.error("--repeat must be >= 1")
    if args.capler_N and (args.suite != "ocp" or min(args.capler_N) < 1):
        parser.error("--capler-N needs --suite ocp and N >= 1")
    suite_cases = CASE_NAMES if args.suite == "simulate" else OCP_CASE_NAMES
    if args.cases and not set(args.cases) <= set(suite_cases):
        parser.error(f"--cases of suite {args.suite}: {', '.join(suite_cases)}")
    if args.quick and args.suite == "ocp" and (args.capler_N or set(args.cases or ()) - {"ocp_pm_hop"}):
        # the quick ocp suite is the point mass only: Capler's cases and grids were dropped, and an empty results.json
        # written over the last one
        parser.error("--quick with --suite ocp runs the point-mass hop only: give no Capler --cases or --capler-N with it")
    if args.capler_N and args.cases and not any(c.startswith("ocp_capler") for c in args.cases):
        parser.error("--capler-N sets the grids of the Capler cases, and --cases runs none")  # (it was dropped)
    # before the runs, the suite's default as a given --out (prepare_out_dir let a results.json that is a directory
    # through: its write failed after the whole run)
    out = args.out or checked_default(parser, "--out", DEFAULT_OUT if args.suite == "simulate" else DEFAULT_OUT_OCP)

    def log(rec):  # progress on stderr: stdout keeps the table or the JSON
        errs = ", ".join(f"{k} {v:.2e}" for k, v in rec["errors"].items() if v is not None)
        print(f"{rec['case']:<22} {rec['variant']:<10} h {rec['h']:<8g} {rec['wall_time_s']:7.2f} s "
              f"{'' if rec['converged'] else 'NOT CONVERGED '}{errs}", file=sys.stderr, flush=True)

    load_before = os.getloadavg()
    start = time.perf_counter()
    extra = {"capler_Ns": tuple(args.capler_N)} if args.capler_N else {}
    records, refs = SUITES[args.suite](args.quick, args.repeat, log, set(args.cases) if args.cases else None, **extra)
    machine = {**machine_info(), "load_average_before": load_before, "load_average_after": os.getloadavg()}
    orders = convergence_orders(records, None if args.suite == "simulate" else OCP_ORDER_KEYS)
    out.mkdir(parents=True, exist_ok=True)
    results = {"command": "python -m scripts.bench_work_precision "
               + shlex.join(argv if argv is not None else sys.argv[1:]),
               "suite": args.suite, "quick": args.quick, "repeat": args.repeat, "total_wall_time_s": time.perf_counter() - start,
               "machine": machine, "references": refs, "orders": orders, "records": records, "run": run_info()}
    write_atomically(out / "results.json", json.dumps(_strict(results), indent=1, allow_nan=False) + "\n")
    plot(records, out / "work_precision.png", PANELS if args.suite == "simulate" else OCP_PANELS)
    summary = {"results": str(out / "results.json"), "plot": str(out / "work_precision.png"),
               "n_records": len(records), "n_failed": sum(not r["converged"] for r in records),
               "total_wall_time_s": results["total_wall_time_s"], "machine": machine, "orders": orders}
    if args.json:
        print(json.dumps(_strict(summary), indent=1))
    else:
        print(table(records) if args.suite == "simulate" else ocp_table(records))
        if orders:  # one grid has no slope
            print("\nconvergence orders (slope of log error vs log h):")
        for o in orders:
            print(f"  {o['case']:<22} {o['variant']:<10} {o['error']:<26} {o['order']:5.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(run_main(main))
