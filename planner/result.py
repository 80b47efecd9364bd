"""Typed results, the physical-time recovery of Thm. 10, and the atomic result writers.

Recovery (paper Thm. 10, eq. 22) from a discretized time-freezing trajectory: a step is *frozen*
(partly or wholly) when its clock advanced less than h s. Samples of running steps are physical
samples at their clock time. A run of frozen steps (its first, the fully frozen ones after it, and at
most one more: see `recover`) is one impact at one physical time (the clock value inside the run):
it contributes a pre-impact and a post-impact sample at that time. The post-impact velocity is the
pre-impact one plus the sum of the auxiliary fields' velocity increments over the run; the
pre-impact velocity is the state after the run's first step minus that step's auxiliary increment
(the step may also hold some free flight). The impulse is the integral of the auxiliary force over
the run, sum h s P_j a_j (eq. 22).

File contract (docs/results.md): DIR/trajectory.npz with tau, y, t, q, v, u, impact_times (and
more), DIR/summary.json with command, robot, task, converged, solve_time_s, n_nlp,
ipopt_iterations, complementarity_residual, terminal_error, physical_duration_s, impacts.
"""
from __future__ import annotations

import contextlib
import fcntl
import glob
import importlib
import io
import json
import os
import platform
import stat
import tempfile
import threading
import time
import uuid
import zipfile
from dataclasses import dataclass, field, fields
from functools import cached_property
from pathlib import Path

import numpy as np

from .errors import InputError, expect, is_integer, read_error, real_array, shown, signals_held, write_error
from .task import Task, contact_labels, load_task, parse_task, task_to_json


def _read_only(obj) -> None:
    """Store each array field of a frozen dataclass as a read-only view of a read-only copy: a result is frozen through
    its arrays too (`trajectory.t[0] = 1` raised no error and changed physical_duration), and numpy refuses to make
    such a view or its base writable again (a view of the caller's array could be, and an owning copy through `.base`:
    the arrays are views of immutable bytes); the caller's own arrays stay writable. A dict
    field becomes a ReadOnlyDict, its arrays and dicts frozen the same way (`result.extra["_x"][0] = 123` changed
    the nlp_x written and the replan's start), its lists ReadOnlyLists."""
    for f in fields(obj):
        value = getattr(obj, f.name)
        if isinstance(value, (np.ndarray, dict)):
            object.__setattr__(obj, f.name, _frozen(value))


def _frozen(value):
    if isinstance(value, np.ndarray):
        if value.dtype.hasobject:
            frozen = np.array(value)
            frozen.flags.writeable = False
            return frozen.view()
        # over immutable bytes: an owning copy could be made writable again through the view's .base
        return np.frombuffer(value.tobytes(), dtype=value.dtype).reshape(value.shape)
    if isinstance(value, dict):
        return ReadOnlyDict({k: _frozen(v) for k, v in value.items()})
    if isinstance(value, list):  # summary.json's lists (extra["race"], the scene's reasons): a list still, read-only
        return ReadOnlyList(_frozen(v) for v in value)
    return value


class ReadOnlyDict(dict):
    """A dict field of a frozen result: reading as a dict does (json.dumps, `**`, dict(...)), writing raises TypeError;
    a changed copy is dataclasses.replace(result, extra={**result.extra, key: value})."""

    def _refuse(self, *args, **kwargs):
        raise TypeError("a result's dict is read-only: make a changed copy with dataclasses.replace(result, "
                        "field={**result.field, key: value})")

    __setitem__ = __delitem__ = __ior__ = clear = pop = popitem = setdefault = update = _refuse

    def __reduce__(self):  # pickle and deepcopy: rebuilt whole (dict's own way sets the items one by one), arrays frozen
        return _frozen, (dict(self),)


class ReadOnlyList(list):
    """A list inside a result's dict field: reads as a list (== a list, json.dumps), writing raises TypeError."""

    def _refuse(self, *args, **kwargs):
        raise TypeError("a result's list is read-only: make a changed copy with dataclasses.replace")

    __setitem__ = __delitem__ = __iadd__ = __imul__ = append = extend = insert = pop = remove = clear = sort = reverse = _refuse

    def __reduce__(self):
        return _frozen, (list(self),)


class ArraysReadOnly:
    """Base of the frozen result dataclasses with array or dict fields: read-only after construction, and after pickle
    or copy.deepcopy too, which restore the fields without __post_init__ (with writable arrays)."""

    def __post_init__(self):
        _read_only(self)

    def __setstate__(self, state: dict) -> None:
        # a cached property's array (Trajectory.taps) is restored writable too, and the summary reads it
        self.__dict__.update({k: _frozen(v) if isinstance(v, np.ndarray) else v for k, v in state.items()})
        _read_only(self)


def _no_negative_zero(obj, name: str) -> None:
    """A product's -0.0 (a * b with a = 0 and b < 0) stored as 0.0: it printed as "complementarity -0.0e+00"."""
    value = getattr(obj, name)
    if value == 0.0:
        object.__setattr__(obj, name, 0.0)


# An impact whose normal impulse is below -PULL_SHARE of the largest |normal impulse| pulls its point to the plane:
# far above rounding, far below the biped's -16.7 N s next to +18.6 (and the -0.3 next to +1.4 of formulation.md)
PULL_SHARE = 1e-3


def tap_flags(impulse_norms) -> np.ndarray:
    """(I,) bool: which of the impacts with these impulse norms (I,) [N s] are taps (TAP_SHARE)."""
    norms = np.abs(np.asarray(impulse_norms, float))
    return norms < TAP_SHARE * norms.max(initial=0.0)


@dataclass(frozen=True, eq=False)
class Impact(ArraysReadOnly):
    """One recovered impact (one frozen interval).

    time: physical time [s]; contact: the contact point's name; impulse: normal impulse int a_n dtau [N s] (eq. 22);
    impulse_tangential: tangential impulse int (1 - 2 zeta) a_t dtau [N s] (0 if frictionless);
    q (nq,): configuration at the impact; v_pre (nv,): pre-impact velocity, implicit Euler's: the landing step's end
    velocity less its auxiliary increment, so it holds what the step's smooth part did in its running share (a
    contact-mode push at the step's end: O(h), e.g. a falling walker's pitch rate -0.43 rad/s at v_pre where the
    sample before had 0); v_post (nv,): post-impact velocity; tau_start, tau_end: numerical time where the frozen
    interval starts and ends [s]; kinetic_energy_pre, kinetic_energy_post: 1/2 v^T M(q) v at q before (v_pre) and
    after (v_post) [J], nan where not computed.
    """

    time: float
    contact: str
    impulse: float
    impulse_tangential: float
    q: np.ndarray
    v_pre: np.ndarray
    v_post: np.ndarray
    tau_start: float
    tau_end: float
    kinetic_energy_pre: float = float("nan")
    kinetic_energy_post: float = float("nan")

    @property
    def gains_energy(self) -> bool:
        """The impact ends with more kinetic energy than it started with, by more than ENERGY_GAIN_SHARE of the larger:
        an impact only dissipates (restitution <= 1), so this is a push-off lumped into the impact's partly frozen
        steps (docs/validation.md, session 35), where MuJoCo's replay may see no impact."""
        pre, post = self.kinetic_energy_pre, self.kinetic_energy_post
        return bool(post - pre > max(ENERGY_GAIN_SHARE * max(pre, post), ENERGY_GAIN_FLOOR_J))  # (False for nan)

    @property
    def impulse_norm(self) -> float:
        """|(normal, tangential)| [N s]: the size TAP_SHARE compares."""
        return float(np.hypot(self.impulse, self.impulse_tangential))

    def to_json(self) -> dict:
        return {"time": self.time, "contact": self.contact, "impulse": self.impulse, "impulse_tangential": self.impulse_tangential,
                "impulse_norm": self.impulse_norm, "tau_start": self.tau_start, "tau_end": self.tau_end,
                "v_pre": self.v_pre.tolist(), "v_post": self.v_post.tolist(),
                "kinetic_energy_pre_J": _finite_or_none(self.kinetic_energy_pre),
                "kinetic_energy_post_J": _finite_or_none(self.kinetic_energy_post), "gains_energy": self.gains_energy}


# An impact whose kinetic energy grows by more than this share of the larger of its energies before and after gains
# energy (Impact.gains_energy). The main job's plan (session 57's summary.json) has seven such: five push-offs and
# landings lumped with their stance (+1.3 to +9.7 J), a tap's +1.1 J and another tap's +0.8 mJ; its other impacts lose
# energy or gain under 0.4 % (+0.05 J at 0.615 s).
ENERGY_GAIN_SHARE = 0.01
# ... and by more than this [J]: an impact at rest gains rounding (~1e-15 J), the main job's smallest gain is 0.8 mJ
ENERGY_GAIN_FLOOR_J = 1e-9


def _finite_or_none(value: float) -> float | None:
    return float(value) if np.isfinite(value) else None


# An impact whose impulse norm is below this share of the plan's largest is a tap: one step frozen just past
# FROZEN_TOL where a stance corrects its contact velocity, not a landing. Capler's main-job plan (session 57's
# summary.json) has three such (0.10-0.16 N s against its 24.6 N s landing, 0.4-0.7 %) and, since a run ends where
# the clock ran after its impact (session 36), a fourth: the first two steps of the run that lumped a landing with a
# push-off (0.74 N s, 3.0 %; the push-off's 3.0 N s is the next impact). Its smallest other impact, the landing at
# 0.591 s, is 5.2 % (1.28 N s): 0.2 points above this share, so a plan's landing can fall under it. MuJoCo sees no
# contact onset at a tap, so validation lists taps without matching them (docs/validation.md). The held schedule
# accepts an added tap (homotopy, docs/benchmarks.md "Replanning", session 29).
TAP_SHARE = 0.05
# A simulation's drift into a contact's plane [m] that its report names: half of what the MuJoCo validation fails
# (2 mm); a fixed arm's tip ended 45 mm in the ground in a run that said only "converged".
PENETRATION_NOTE_M = 1e-3


@dataclass(frozen=True, eq=False)
class Trajectory(ArraysReadOnly):
    """A time-freezing trajectory in numerical time and its recovery in physical time.

    tau (K,) numerical time grid [s]; y (K, ny) states, clock last; state_names (ny,);
    sigma (K-1, n_sigma) selectors of each step (at its end point), selector_names;
    t (P,) physical times [s]; q (P, nq), v (P, nv), u (P, nu) physical-time samples; an impact is
    two samples with the same time (pre- and post-impact velocity; three with FESD, which repeats the
    flight element's end too); impacts (Impact, ...).
    forces (K-1, n_lambda), force_names: the index-reduced contact forces [N] of each step (at its end
    point) when the system has several contact points (zero for points off the ground), else None.
    contact_force (K-1, n_contacts, 2): the persistent-contact force (normal, tangential) [N] each
    step applies (0 in flight and in frozen impacts), or None; `contact_force_samples` maps it onto
    the physical-time samples.
    """

    tau: np.ndarray
    y: np.ndarray
    state_names: tuple[str, ...]
    sigma: np.ndarray
    selector_names: tuple[str, ...]
    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    u: np.ndarray
    impacts: tuple[Impact, ...] = ()
    forces: np.ndarray | None = None  # several contacts: (K-1, n_lambda) contact forces of each step [N]
    force_names: tuple[str, ...] = ()  # lambda_n[point], lambda_t[point], ...
    contact_force: np.ndarray | None = None  # (K-1, n_contacts, 2) persistent-contact force of each step [N]

    def __post_init__(self):
        # a Trajectory edited with dataclasses.replace (q shorter than t) was written and validated as it was
        samples = {name: len(getattr(self, name)) for name in ("t", "q", "v", "u")}
        if len(set(samples.values())) > 1 or len(self.tau) != len(self.y):
            grid = {name: len(getattr(self, name)) for name in ("tau", "y")}
            raise InputError(f"a Trajectory's arrays must agree in length: the samples {samples}, the grid {grid}")
        super().__post_init__()

    def contact_force_samples(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(lambda_n, lambda_t), each (P, n_contacts) [N], at the physical-time samples: linear in
        physical time between the ends of the steps whose clock ran (more than FROZEN_TOL of the step), so an
        impact's two samples get one value there (its impulse is the Impact's, not a force). None without
        contact_force."""
        if self.contact_force is None or len(self.contact_force) == 0:
            return None
        clock = self.y[1:, -1]
        # a step that ran the clock ends at a new time (a frozen one's leak had read as running)
        running = np.concatenate([[True], clock_ran(clock, np.diff(self.tau)[1:])])
        ts, f = clock[running], self.contact_force[running]
        out = [np.column_stack([np.interp(self.t, ts, f[:, c, j]) for c in range(f.shape[1])]) for j in (0, 1)]
        return out[0], out[1]

    @property
    def impact_times(self) -> np.ndarray:
        """(I,) physical times of the impacts [s], in order (Impact.time)."""
        return np.array([imp.time for imp in self.impacts], dtype=float)

    @cached_property  # read by the summary, the report, the plots and the validation's matching
    def taps(self) -> np.ndarray:
        """(I,) bool, read-only: which impacts are taps (TAP_SHARE)."""
        # computed once per trajectory, so no caller may change it for the next (a view: not made writable again)
        return _frozen(tap_flags([imp.impulse_norm for imp in self.impacts]))

    @property
    def physical_duration(self) -> float:
        """Physical time from the first sample to the last [s] (0 without samples)."""
        return float(self.t[-1] - self.t[0]) if len(self.t) else 0.0


@dataclass(frozen=True)
class SolveStats:
    """How the numerics went: totals over every NLP solved.

    converged: the verdict of the solve (planner.homotopy's module docstring says when a plan converged);
    solve_time_s: wall time of the solve [s]; n_nlp: NLPs solved; ipopt_iterations: IPOPT iterations of them all;
    complementarity_residual: max over all pairs of a * b at the solution (the switching functions' units);
    message: how the run ended, or why it failed.
    """

    converged: bool
    solve_time_s: float
    n_nlp: int
    ipopt_iterations: int
    complementarity_residual: float
    message: str = ""

    def __post_init__(self):
        _no_negative_zero(self, "complementarity_residual")


@dataclass(frozen=True, eq=False)
class SimulationResult(ArraysReadOnly):
    """What `planner.simulate.simulate` returns."""

    robot: str  # robot file path (the viewer loads it back)
    task: str  # task file path ("" for a task built in code)
    trajectory: Trajectory
    stats: SolveStats
    strategy: str
    h: float
    rho_f: float
    command: str = "simulate"
    extra: dict = field(default_factory=dict)
    robot_sha256: str = ""  # the robot file's contents as simulated (validate refuses the file changed since)
    options: dict = field(default_factory=dict)  # the SimulateOptions, as summary.json records them

    @property
    def ends_in_impact(self) -> bool:
        """The horizon ends while the last impact is still frozen (its clock never ran again, to FROZEN_TOL of a step;
        its post-impact kinetic energy is then not computed, nan): a simulation has no
        terminal state to end it, so that impact is unfinished and its impulse and v_post are partial (a 100 kg point
        mass landing at 4.4 m/s stays frozen for ~m |v_n| / a_n = 2.2 s of numerical time at a_n = 200)."""
        tr = self.trajectory  # (a failed run's last node is where it stopped, not the horizon's end)
        if not (self.stats.converged and tr.impacts and tr.impacts[-1].tau_end >= tr.tau[-1]):
            return False
        # and the clock did not run after it (a landing inside the last step, the clock running after it, is finished)
        return bool(tr.y[-1, -1] - tr.impacts[-1].time <= FROZEN_TOL * (tr.tau[-1] - tr.tau[-2]))

    def report(self) -> str:
        """A few human-readable lines for the terminal."""
        lines = [_headline(self, f"{self.strategy}, ") + ")"] + _trajectory_lines(self.trajectory, task=self.extra.get("_task"))
        deepest = self.extra.get("penetration", {})
        if deepest.get("max_m", 0.0) > PENETRATION_NOTE_M:
            lines.append(f"  {deepest['point']} went {deepest['max_m'] * 1e3:.1f} mm into its plane (t = {deepest['t']:.4g} s): the "
                         "steps keep a contact's velocity on the plane, not its position; a smaller h (more steps) drifts less")
        lines += outside_range_lines(self.extra, len(self.trajectory.tau), "the simulation has no joint limits")
        lines += _braked_lines(self.extra)
        for force in self.extra.get("forces_outside_friction_cone", ()):
            where = _cone_where(force)
            lines.append(f"  {force['point']}'s contact force outside its friction cone at {force['samples']} of "
                         f"{len(self.trajectory.t)} samples (|tangential| up to {force['max_tangential_N']:.4g} N "
                         f"{where}): a simulation's no-slip contact holds the point with any tangential force "
                         "(docs/tasks.md)")
        if self.ends_in_impact:
            last, task = self.trajectory.impacts[-1], self.extra.get("_task")
            elastic = task is not None and any(label == last.contact and c.restitution > 0  # a corner's point#k too
                                               for label, c in zip(contact_labels(task.contacts), task.contacts))
            lines.append("  the horizon ends inside the last impact (its clock is still stopped): its impulse and "
                         "post-impact velocity are partial; lengthen tau_f or raise the contact's a_n" + (
                             f", unless {last.contact}'s bounces (restitution > 0) accumulate to a point in time "
                             "(Zeno: ever shorter bounces), which the time-freezing simulation does not pass; "
                             "restitution = 0 makes the landing a stance" if elastic else ""))
        if not self.stats.converged:  # (shown only by -q's failure line)
            lines.append(f"  {self.stats.message}")
        return "\n".join(lines)

    def summary(self) -> dict:
        """The summary.json object (contract keys first)."""
        return {
            **_contract_keys(self, terminal_error=None),
            "robot_sha256": self.robot_sha256,
            "strategy": self.strategy,
            "h": self.h,
            "rho_f": self.rho_f,
            "n_steps": len(self.trajectory.tau) - 1,
            "ends_in_impact": self.ends_in_impact,
            "message": self.stats.message,
            "options": self.options,
            **{k: v for k, v in self.extra.items() if not k.startswith("_")},
        }


def task_path(source: str) -> str:
    """A task's source as summary.json stores it: the absolute path of its file when it names one (a --task given
    relative to the working directory meant nothing from another; the robot's path is absolute), else as given."""
    return str(Path(source).absolute()) if source and Path(source).is_file() else source


def _contract_keys(result, terminal_error: float | None) -> dict:
    """The keys every summary.json holds (docs/results.md), in the contract's order."""
    tr, st = result.trajectory, result.stats
    return {
        "command": result.command,
        "robot": result.robot,
        "task": task_path(result.task),
        "converged": st.converged,
        "solve_time_s": st.solve_time_s,
        "n_nlp": st.n_nlp,
        "ipopt_iterations": st.ipopt_iterations,
        "complementarity_residual": st.complementarity_residual,
        "terminal_error": terminal_error,
        "physical_duration_s": tr.physical_duration,
        "impacts": [{**imp.to_json(), "tap": bool(tap), "outside_friction_cone": bool(out)}
                    for imp, tap, out in zip(tr.impacts, tr.taps, outside_cone(tr, result.extra.get("_task")))],
    }


def _headline(result, details: str) -> str:
    """`COMMAND ROBOT: verdict in T s (steps, DETAILS NLPs, iterations, complementarity` (unclosed)."""
    tr, st = result.trajectory, result.stats
    steps = round(float(tr.tau[-1] - tr.tau[0]) / result.h)  # not len(tau) - 1: FESD samples every element
    return (f"{result.command} {Path(result.robot).name}: {'converged' if st.converged else 'NOT converged'} in "
            f"{st.solve_time_s:.2f} s ({steps} steps of h = {result.h:g} s, {details}{st.n_nlp} NLPs, "
            f"{st.ipopt_iterations} IPOPT iterations, complementarity {st.complementarity_residual:.1e}")


# An impact's tangential impulse above mu times its normal one by more than this factor (and CONE_FLOOR_NS) is outside
# the friction cone: the tangential auxiliary field stops a sliding foot beyond Coulomb, in a plan when a_t > mu a_n
# (the paper's a_t = 600 against mu a_n = 160 on Capler), in a simulation for any a_t (docs/tasks.md). Rounding stays
# orders of magnitude below both.
CONE_SLACK = 1.01
CONE_FLOOR_NS = 1e-9


def outside_cone(tr: Trajectory, task: Task | None) -> np.ndarray:
    """(I,) bool: which impacts have a tangential impulse outside their contact's friction cone (CONE_SLACK); all
    False without the task (its mu) or for frictionless contacts."""
    if task is None:
        return np.zeros(len(tr.impacts), dtype=bool)
    mu = dict(zip(contact_labels(task.contacts), (c.mu for c in task.contacts)))
    return np.array([mu.get(imp.contact, 0.0) > 0.0 and abs(imp.impulse_tangential)
                     > CONE_SLACK * mu[imp.contact] * max(imp.impulse, 0.0) + CONE_FLOOR_NS for imp in tr.impacts], dtype=bool)


# A persistent contact force [N] beyond CONE_SLACK mu lambda_n by more than this is outside the cone: a simulation's
# forces come from step solves at 1e-9 (the brick's frictionless-looking corners read 6e-9 N).
CONE_FLOOR_N = 1e-6


def forces_outside_cone(tr: Trajectory, task: Task | None) -> list[dict]:
    """The contacts whose persistent force leaves their friction cone, one entry each: point, samples (how many of
    the physical-time samples), max_tangential_N (the largest |lambda_t| outside [N]), mu_normal_N (mu lambda_n
    there, lambda_n clipped at 0 [N]) and normal_N (lambda_n there [N]). A simulation's no-slip contact holds a
    point with whatever tangential force it takes (the paper's model: no cone); a brick on two corners was held by
    +-3641 N against a normal force of 0.016 N. [] without the
    task, the forces or any contact outside."""
    samples = tr.contact_force_samples()
    if task is None or samples is None or samples[0].shape[1] != len(task.contacts):
        return []
    lambda_n, lambda_t = samples
    out = []
    for c, (label, contact) in enumerate(zip(contact_labels(task.contacts), task.contacts)):
        entry = cone_breach(label, "samples", contact.mu, lambda_t[:, c], lambda_n[:, c])
        if entry:
            out.append(entry)
    return out


def _cone_where(entry: dict) -> str:
    """How a cone_breach entry's normal force reads in a report line: mu times it, or that it pulls (it read "mu normal
    = 0 N" of a normal force of -4.23 N, the bound clipped at 0); summaries before normal_N: mu times it."""
    if entry.get("normal_N", 0.0) < -CONE_FLOOR_N:
        return f"where the normal force pulls, {entry['normal_N']:.4g} N"
    return f"where mu normal = {entry['mu_normal_N']:.4g} N"


def cone_breach(point: str, counted: str, mu: float, tangential, normal, where=True,
                floor: float = CONE_FLOOR_N) -> dict | None:
    """{point, counted: how many, max_tangential_N, mu_normal_N, normal_N} of the entries (where True) whose
    tangential force (n,) [N] leaves the friction cone of mu times the normal force (n,) [N] by more than floor [N]
    (CONE_SLACK), the largest one named with its normal force (negative: it pulls, where mu_normal_N reads 0); None
    when none does or mu = 0."""
    tangential = np.abs(tangential)
    bound = mu * np.maximum(normal, 0.0)
    outside = where & (tangential > CONE_SLACK * bound + floor)
    if not (mu > 0 and outside.any()):
        return None
    worst = int(np.argmax(np.where(outside, tangential, -1.0)))
    return {"point": point, counted: int(outside.sum()), "max_tangential_N": float(tangential[worst]),
            "mu_normal_N": float(bound[worst]), "normal_N": float(normal[worst])}


def _trajectory_lines(tr: Trajectory, extra: str = "", task: Task | None = None) -> list[str]:
    """Terminal lines for the physical duration and each impact (those outside the friction cone flagged)."""
    taps, outside = tr.taps, outside_cone(tr, task)
    largest = max((abs(imp.impulse) for imp in tr.impacts), default=0.0)
    pulls = [imp.impulse < -PULL_SHARE * largest for imp in tr.impacts]
    n_taps = f" ({int(taps.sum())} tap(s): below {TAP_SHARE:.0%} of the largest impulse, by norm)" if taps.any() else ""
    lines = [f"physical time {tr.physical_duration:.4f} s of numerical time {tr.tau[-1]:.4f} s; {len(tr.impacts)} impact(s){n_taps}{extra}"]
    lines += [f"  {'tap' if tap else 'impact'} at t = {imp.time:.4f} s on {imp.contact}: impulse {imp.impulse:.4g} N s normal, "
              f"{imp.impulse_tangential:.4g} N s tangential" + (" (outside the friction cone)" if out else "")
              + (" (pulls the point to its plane)" if pull else "")
              + (f" (kinetic energy {imp.kinetic_energy_pre:.4g} -> {imp.kinetic_energy_post:.4g} J)"
                 if imp.gains_energy else "")
              for imp, tap, out, pull in zip(tr.impacts, taps, outside, pulls)]
    if any(pulls):  # (flagged only as outside the friction cone: a biped's stance foot held by -16.7 N s)
        lines.append(f"  {sum(pulls)} impact(s) with a negative normal impulse: the contact held its point on the "
                     "plane where it should lift off, as a landing on another contact can (docs/formulation.md, "
                     "\"Two planes meeting at an obtuse angle\")")
    gains = [imp for imp in tr.impacts if imp.gains_energy]
    if gains:
        gain = max(i.kinetic_energy_post - i.kinetic_energy_pre for i in gains)
        lines.append(f"  {len(gains)} impact(s) gain kinetic energy (up to {gain:+.3g} J): an impact only "
                     "dissipates, so these are pushes their partly frozen steps lump into them (a push-off, or support "
                     "the auxiliary field carries), where MuJoCo's replay may see no impact (docs/validation.md)")
    if outside.any():
        lines.append(f"  {int(outside.sum())} impact(s) outside the friction cone (|tangential| > mu normal): the tangential "
                     "auxiliary field stopped sliding beyond Coulomb; `planner plan` of one contact keeps impacts inside "
                     "the cone when a_t <= mu a_n (docs/tasks.md)")
    return lines


@dataclass(frozen=True)
class NlpRecord:
    """One NLP of the plan's homotopy (or its polishing NLP).

    label: "homotopy 1" .. "homotopy n", "polish"; rho: complementarity penalty; hole_scale: scale r of the holes
    (0: relaxed, 1: the task's); objective: NLP objective at its solution; complementarity_residual: max over all
    pairs of a * b (unscaled; with gating the largest gated product); iterations: IPOPT iterations; time_s: wall time
    of the IPOPT call [s]; status: IPOPT return status; success: IPOPT's success flag; terminal_error: the terminal
    rows' largest distance outside [lbg, ubg] [m, rad (, m/s, rad/s)]; note: why the planner set aside the NLP's
    point though IPOPT succeeded (a held schedule that adds an impact), or kept one though IPOPT did not, or "";
    kept_iteration: a projection polish IPOPT did not finish, whose iterate of that number (0: the start) the planner
    kept because the plan's checks accept it (the record's numbers are that point's), or None.
    """

    label: str
    rho: float
    hole_scale: float
    objective: float
    complementarity_residual: float
    iterations: int
    time_s: float
    status: str
    success: bool
    terminal_error: float
    note: str = ""
    kept_iteration: int | None = None

    def __post_init__(self):
        _no_negative_zero(self, "complementarity_residual")

    def to_json(self) -> dict:
        return dict(vars(self))


@dataclass(frozen=True)
class Hop:
    """One flight phase of a contact point: from the step that leaves the ground to the impact.

    takeoff_time: physical time of the last ground step [s]; landing_time: physical time of the touchdown (the
    impact time) [s]; distance: horizontal distance of the point from takeoff to landing [m]; apex: the point's
    highest height above its takeoff height [m].
    """

    takeoff_time: float
    landing_time: float
    distance: float
    apex: float

    def to_json(self) -> dict:
        return dict(vars(self))


# A flight phase whose contact point stays within this distance of its takeoff position [m] is no hop: FESD's point-mass
# hop kept beta = 1 for 65 ms at rest on the ground after its landing and reported a second hop of distance and apex 0.
HOP_MIN_TRAVEL_M = 1e-6
# A point this far from its contact plane [m] is on it: far above the plans' contact gaps (~1e-9 m at rest, 4e-11 m
# where a landing ends a whole flight step at a node) and far below a flight step's height (~1 cm).
ON_PLANE_M = 1e-6
# A point on its plane moving into it faster than this [m/s] is landing: far above a stance's velocity (~1e-9 m/s), far
# below a landing's (0.1-2 m/s).
APPROACH_MPS = 1e-3
# An impact this far past a flight's last node still ends it [s]: the node clock and the recovered impact time round
# apart (implicit Euler's equal them to ~1e-16 s).
LANDING_SLACK_S = 1e-9


def _passes_over(hole, start, end) -> bool:
    """Whether the straight segment from start to end (3,) [m] enters hole (a task's Ellipse in x, z)."""
    (x0, z0), (dx, dz) = (start[0] - hole.x, start[2] - hole.z), (end[0] - start[0], end[2] - start[2])
    # the metric along the segment, s in [0, 1]: quad s^2 + lin s + hole.metric(start), smallest at s
    quad = (dx / hole.a) ** 2 + (dz / hole.b) ** 2
    lin = 2.0 * (x0 * dx / hole.a**2 + z0 * dz / hole.b**2)
    s = min(max(-lin / (2.0 * quad), 0.0), 1.0) if quad > 0.0 else 0.0
    return hole.metric(start[0] + s * dx, start[2] + s * dz) < 1.0


def _flight_phases(flight):
    """The flight phases of the per-step flight indicator `flight` (N,) (beta, 1 in flight) as (a, k): steps a..k-1
    end in flight, nodes a..k; node a is the last on the ground."""
    # (beta > 0.5 also reads a sliding stance, beta 0.82-0.92 with the point on the ground, as flight; a one-step phase
    # cannot be told apart by the point's height: a one-step hop over a hole starts and ends on the ground, session 48)
    air = np.asarray(flight, float).ravel() > 0.5
    k, N = 0, len(air)
    while k < N:
        if not air[k]:
            k += 1
            continue
        a = k
        while k < N and air[k]:
            k += 1
        yield a, k


def _over_hole(seg, holes) -> bool:
    """Whether the polyline through the nodes seg (n, 3) [m] passes over one of holes (the task's Ellipses)."""
    return any(_passes_over(hole, seg[s], seg[s + 1]) for hole in holes for s in range(len(seg) - 1))


def hops_of(traj: Trajectory, flight, point_xyz, normal=(0.0, 0.0, 1.0), gap=None, holes=()) -> list[Hop]:
    """Flight phases from the per-step flight indicator `flight` (N,) (beta, 1 in flight) and the
    contact point's positions point_xyz (N+1, 3) at the nodes; times are the node clocks. A phase in which the point
    does not move (HOP_MIN_TRAVEL_M), or of two steps or more whose nodes all keep the point's distance from its
    contact plane (unit normal (3,); ON_PLANE_M: a slide, on a slope too), is left out. gap (N+1,), the smallest
    distance of the contact points from their planes at the nodes [m], when given: a phase from node 0 off the planes
    is a fall, no hop, a phase whose last node is off them lands in the next step (partly frozen), whose end node it
    takes too, and one whose last node is on them without an impact lands there; a one-step phase on the planes at
    both ends is a skim, no hop, unless its point passes over one of holes (the task's Ellipses) on the way, as a
    slide is unless one of its steps does (slides_of lists each point's skims)."""
    clock = traj.y[:, -1]
    hops, N = [], len(np.asarray(flight).ravel())
    for a, k in _flight_phases(flight):
        if a == 0 and gap is not None and gap[0] > ON_PLANE_M:  # (a drop was a hop with takeoff 0.0)
            continue
        # (the landing step's travel was left out of the distance: a drop with a_n = 20 landed 1 cm past it)
        seg = point_xyz[a : k + 2 if gap is not None and gap[k] > ON_PLANE_M and k < N else k + 1]
        if np.abs(seg - seg[0]).max() <= HOP_MIN_TRAVEL_M:
            continue
        over_hole = _over_hole(seg, holes)
        distance, apex = float(seg[-1, 0] - seg[0, 0]), float(seg[:, 2].max() - seg[0, 2])
        if k - a >= 2 and np.abs((seg - seg[0]) @ np.asarray(normal, float)).max() <= ON_PLANE_M and not over_hole:
            continue
        # (flight mode along the ground is frictionless: Capler at N = 50 slid its foot 7-10 cm so, twice backwards,
        # 4-8 mm below the ground between the nodes; a one-step hop over a hole starts and ends on the ground)
        if k - a == 1 and gap is not None and max(gap[a], gap[k]) <= ON_PLANE_M and not over_hole:
            continue
        end = float(clock[min(k + 1, N)])
        # the touchdown is the flight's impact: implicit Euler's landing step ends at it (node k + 1), but FESD's frozen
        # impact element still reads as flight (beta = 1), so node k + 1 lies one element (26 ms) past it
        # (the last impact of the phase: FESD's phase may start on the ground, with beta between 0.5 and 1, and hold a
        # tap)
        # without an impact, a phase whose last node is on the plane touched down there, not a step later
        on_plane = gap is not None and k < N and gap[k] <= ON_PLANE_M
        landing = max((i.time for i in traj.impacts if clock[a] < i.time <= end + LANDING_SLACK_S),
                      default=float(clock[k]) if on_plane else end)
        hops.append(Hop(float(clock[a]), float(landing), distance, apex))
    return hops


def slides_of(traj: Trajectory, flight, point_xyz, gap, point: str, holes=(), skims: list | None = None) -> list[dict]:
    """The slides of one contact point along its plane in flight mode, where no friction acts: its flight phases (its
    own beta, `flight` (N,), read as hops_of reads it), or runs of their steps, of two steps or more whose nodes all
    keep its own gap (N+1,) within ON_PLANE_M of its plane and that move it (point_xyz (N+1, 3) [m]) by more than HOP_MIN_TRAVEL_M without
    passing over one of holes (then hops_of's hop). Each as {"point", "start_time", "end_time" [s] (its first and last
    node's clocks), "distance" [m] (along x, as a hop's)}. Such a phase of one step is a skim, no slide: skims, when
    given, gets each as {"point", "takeoff_time", "landing_time" [s] (its two nodes' clocks), "distance", "apex" [m]
    (as a hop's)}."""
    clock = traj.y[:, -1]
    slides = []
    for a, k in ((i, j) for p, e in _flight_phases(flight) for i, j in _on_plane_runs(gap, p, e)):
        seg = point_xyz[a : k + 1]
        if np.abs(seg - seg[0]).max() <= HOP_MIN_TRAVEL_M or _over_hole(seg, holes):
            continue
        distance = float(seg[-1, 0] - seg[0, 0])
        if k - a == 1:  # (one step: hops_of's skim, which read the robot's flight and the first contact only)
            if skims is not None:
                skims.append({"point": point, "takeoff_time": float(clock[a]), "landing_time": float(clock[k]),
                              "distance": distance, "apex": float(seg[:, 2].max() - seg[0, 2])})
            continue
        slides.append({"point": point, "start_time": float(clock[a]), "end_time": float(clock[k]),
                       "distance": distance})
    return slides


def _on_plane_runs(gap, a: int, k: int):
    """The runs (i, j) of two nodes or more within the flight phase's nodes a..k at which gap (N+1,) [m] keeps the
    point on its plane (ON_PLANE_M): the whole phase when it does so at every node, else the steps i..j-1 inside it
    that move the point along the plane (a biped's swing foot slid 3.1 cm at 1.5 m/s in one such step inside a longer
    flight, unreported), not those at its first or last node: a hop's take-off and landing, its distance already."""
    if max(gap[a : k + 1]) <= ON_PLANE_M:
        yield a, k
        return
    i = a
    while i < k:
        if gap[i] > ON_PLANE_M:
            i += 1
            continue
        j = i
        while j < k and gap[j + 1] <= ON_PLANE_M:
            j += 1
        if j > i and i > a and j < k:
            yield i, j
        i = j + 1


# [m/s] an unrecorded landing is listed when its point approached at least this fast: slower runs are the implicit
# step settling a foot onto its plane (the biped's default plan: 0.03 and 0.07 m/s; a bounder's 3.5-11 mm/s), no landing
# a user needs to hear of (a 1 kg foot at 0.1 m/s carries 5 mJ)
LANDING_MIN_MPS = 0.1
# [m] a point on its plane whose node velocity does not point into it landed from the air only when the node before was
# at least this high, or it fell this far over the two steps before: a point hovering a few micrometres above ON_PLANE_M
# that drifts onto it is no fall, whatever the step's clock (2 um -> 0.5 um read 0.30 m/s over a step whose clock leaked
# 1e-4 h); 100 ON_PLANE_M, far below a flight step's fall (the saved plans' landings and impacts came down from 2.3 mm
# to 23 cm)
FALL_MIN_M = 1e-4


def unrecorded_landings(traj: Trajectory, approach, gap, dt_steps, contacts: tuple[str, ...]) -> list[dict]:
    """Each contact point's landings that no Impact record holds: runs of nodes at which the point lies on its plane
    (gap (K, n_c) [m], ON_PLANE_M) and moves into it (approach (K, n_c), its normal velocity [m/s], below
    -APPROACH_MPS), its first node also whatever its approach when the point fell FALL_MIN_M or more onto it over the
    step before or the two steps before (a step that runs the clock can brake the point to rest before the node),
    outside every Impact of that point (its tau_start..tau_end, dated at the node, or over a step that brought the point
    down), that come from the air: the node before is off the plane, or the run starts at the start (a point on its
    plane before, standing or skimming, has a node velocity J v that the implicit step's rotation can leave pointing
    into the plane at up to ~4 m/s while the point stays on it: no landing). With several contacts the recovery freezes
    a step only when its clock stood still, so a landing in steps that ran the clock is no impact (docs/formulation.md,
    "Partly frozen stance"). Each as {"point", "time" [s] (the run's first node's clock), "approach_mps" (the fastest
    approach of the run, the mean speed at which the point came down over its last step, and the approach of the node
    before it when the step before that moved the point down to it: a step that runs the clock can brake part of the
    landing before the node; a node velocity that moved the point up did not approach; runs slower than LANDING_MIN_MPS
    are left out), "clock_share" (how much of the step that braked it, length dt_steps (K-1,) [s] of numerical time, its
    clock ran: the step from the run's first node, which a recovered impact freezes, or the step before it for a point
    braked before its node)}, in time order. contacts (n_c,): their names."""
    clock, tau = traj.y[:, -1], traj.tau
    approach, gap = (np.asarray(arr, float).reshape(len(clock), -1) for arr in (approach, gap))
    from_air = np.zeros_like(gap, dtype=bool)
    from_air[1:] = gap[:-1] > ON_PLANE_M
    # a node on its plane that fell from FALL_MIN_M or higher is a landing whatever its J v: the auxiliary dynamics of
    # a step that runs the clock can brake the point to rest before the node, where J v then reads ~0; the fall is
    # read over two steps too (a flight step can leave the point tens of micrometres up, still falling at 4 m/s)
    fell = np.zeros_like(gap, dtype=bool)
    fell[1:] = gap[:-1] >= FALL_MIN_M
    fell[2:] |= gap[:-2] - gap[2:] >= FALL_MIN_M
    braked = fell & (gap <= ON_PLANE_M) & (approach >= -APPROACH_MPS)
    landing = ((gap <= ON_PLANE_M) & (approach < -APPROACH_MPS)) | braked
    for c, point in enumerate(contacts):
        for k in range(len(clock) - 1):
            # (an Impact over a step that brought the point down holds its landing too: one frozen step's impact
            # ends at the node, dated at the node before when its clock leaked, or leaves the point micrometres up)
            landing[k, c] &= not any(i.contact == point and (i.tau_start <= tau[k] < i.tau_end
                                                            or abs(i.time - clock[k]) <= LANDING_SLACK_S
                                                            or from_air[k, c] and i.tau_start <= tau[k - 1] < i.tau_end
                                                            or braked[k, c] and k > 1
                                                            and i.tau_start <= tau[k - 2] < i.tau_end)
                                     for i in traj.impacts)
    landing[-1] = False  # (the last node starts no step)
    found = []
    for c, point in enumerate(contacts):
        k = 0
        while k < len(clock):
            if not landing[k, c]:
                k += 1
                continue
            a = k
            while k < len(clock) and landing[k, c]:
                k += 1
            if a and gap[a - 1, c] <= ON_PLANE_M:
                continue
            fastest = -approach[a:k, c].min()
            # the gap it came down over the step's physical time (a node's J v read 0.21 m/s for a tribot's foot that
            # came down 6.75 cm in a whole step of 0.05 s; a fully frozen step's leaked clock would divide solver
            # noise), over both steps when only those two made the fall (a micrometre drift over one step whose
            # clock leaked 1e-4 h read 0.2 m/s)
            s = a - 2 if braked[a, c] and gap[a - 1, c] < FALL_MIN_M else a - 1
            if a and clock[a] - clock[s] > CLOCK_LEAK * dt_steps[s:a].sum():
                fastest = max(fastest, (gap[s, c] - gap[a, c]) / (clock[a] - clock[s]))
            if a == 1 or (a > 1 and gap[a - 2, c] > gap[a - 1, c]):
                fastest = max(fastest, -approach[a - 1, c])
            if fastest < LANDING_MIN_MPS:
                continue
            b = a - 1 if braked[a, c] else a  # the step that braked it (a recovered impact freezes the step from its
            # first node, where the point arrives moving into the plane; a braked point stopped in the step before)
            found.append({"point": point, "time": float(clock[a]), "approach_mps": float(fastest),
                          "clock_share": float((clock[b + 1] - clock[b]) / dt_steps[b])})
    return sorted(found, key=lambda f: f["time"])


def outside_range_lines(extra: dict, nodes: int, why: str) -> list[str]:
    """The report lines of extra["joints_outside_range"] (simulate.joints_outside_range's entries, as summary.json
    stores them), one per joint, indented by two spaces: the joint, the robot file's range [m or rad] it left, at how
    many of `nodes` nodes and how far, and `why` the motion could leave it (MuJoCo's replay enforces the range);
    [] when there is none. A plan's and a simulation's report list them, `planner gait` its joint violations."""
    return [f"  {j['joint']} left the robot file's range [{j['lower']:.4g}, {j['upper']:.4g}]"
            + (f" {j['unit']}" if j.get("unit") else "")  # (older summaries have none)
            + f" at {j['nodes']} of {nodes} nodes (to {j['farthest']:.4g}): {why}, MuJoCo's replay enforces the range"
            for j in extra.get("joints_outside_range", ())]


def _braked_lines(extra: dict) -> list[str]:
    """The report's lines for extra["braked_outside_friction_cone"] (simulate.braked_outside_cone)."""
    return [f"  {brake['point']} braked by the tangential auxiliary field beyond its friction cone in {brake['steps']} "
            f"running step(s) (up to {brake['max_tangential_N']:.4g} N {_cone_where(brake)}): a point sliding on its "
            "plane brakes at a_t / m whatever mu, with no impact and no lambda_t (docs/tasks.md)"
            for brake in extra.get("braked_outside_friction_cone", ())]


@dataclass(frozen=True, eq=False)
class PlanResult(ArraysReadOnly):
    """What `planner.homotopy.solve` returns: the plan, how the homotopy went, and its hops.

    robot: robot file path; task: the task's source (its file path, "" for one built in code; "ABSOLUTE_PATH (edited)",
    planner.task.EDITED, when the task solved differs from that file: extra["_task"] and trajectory.npz's task_json hold
    it); trajectory; stats; h: step length tau_f / N [s of numerical time]; rho_f: the task's weight of ||sigma -
    sigma*||^2; terminal_error: the terminal rows' largest distance outside their bounds [m, rad (, m/s, rad/s)]; nlps:
    one NlpRecord per NLP solved, in order; hops: the robot's flight phases (Hop); polished: the returned point is a
    polishing NLP's; constraint_violation: block name of Problem.g_blocks (but the penalty's) -> largest violation at
    the returned point in the constraint's units, and "bounds" of the variable bounds; timings: where the wall time went
    [s] (build_s, solver_setup_s, ipopt_s, ...; docs/results.md); options: "problem" and "solve", the ProblemOptions and
    SolveOptions field by field; extra: what the report and summary.json add (e.g. skims, slides, race; keys starting
    with "_" are private); robot_sha256: the robot file's contents as planned (validate and --init refuse the file
    changed since). docs/results.md describes each as summary.json holds it.
    """

    robot: str
    task: str
    trajectory: Trajectory
    stats: SolveStats
    h: float
    rho_f: float
    terminal_error: float
    nlps: tuple[NlpRecord, ...]
    hops: tuple[Hop, ...] = ()
    polished: bool = False
    constraint_violation: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    options: dict = field(default_factory=dict)
    command: str = "plan"
    extra: dict = field(default_factory=dict)
    robot_sha256: str = ""

    def nlp_point(self, problem) -> np.ndarray:
        """The NLP point (problem.nx,) this plan ended at, to start `problem` from (a replan:
        `dataclasses.replace(problem, x0=result.nlp_point(problem))`, as `planner plan --init DIR` reads it from
        trajectory.npz): a copy; an InputError when `problem` has other variables (Problem.signature: another N,
        contact set, discretization or formulation) or the result holds none (it was only in a private key)."""
        from .problem import Problem

        expect(problem, Problem, "nlp_point's problem")
        if "_x" not in self.extra or "_signature" not in self.extra:
            raise InputError("this plan holds no NLP point to start from")
        if self.extra["_signature"] != problem.signature:
            raise InputError(f"this plan's NLP variables ({self.extra['_signature'][:16]!r}) are not those of the "
                             f"problem ({problem.signature!r}): a start needs the same robot, contacts, N, "
                             "discretization and options")
        return np.array(self.extra["_x"], dtype=float)

    def report(self) -> str:
        """A few human-readable lines for the terminal (what `planner plan` prints)."""
        tr, st = self.trajectory, self.stats
        task = self.extra.get("_task")  # a periodic plan's terminal rows are its periodicity (it read "terminal error")
        residual = "periodicity" if task is not None and task.is_periodic else "terminal"
        lines = [_headline(self, "") + f", {residual} error {self.terminal_error:.1e})"]
        lines += [f"  {r.label:<11} rho {r.rho:8.3g}  holes x{r.hole_scale:g}  {r.iterations:5d} it  {r.time_s:7.2f} s  "
                  f"objective {r.objective:10.4g}  complementarity {r.complementarity_residual:.1e}  {r.status}"
                  + (f"; {r.note}" if r.note else "") for r in self.nlps]
        lines += _trajectory_lines(tr, f", {len(self.hops)} hop(s)", self.extra.get("_task"))
        if self.extra.get("unrecorded_landings"):  # (a bounder's feet landed at 1-5 m/s beside "0 impact(s)")
            lines.append(f"  {len(self.extra['unrecorded_landings'])} landing(s) with no impact record, in steps that "
                         "ran the clock (several contacts: docs/formulation.md, \"Partly frozen stance\"): "
                         + ", ".join(f"{f['point']} t = {f['time']:.4g} s at {f['approach_mps']:.3g} m/s (the clock "
                                     # (a share, "clock 140% of the step", read as a bug: docs/results.md says why
                                     # it can exceed 1)
                                     f"ran {f['clock_share']:.2g} times the step's numerical length)"
                                     for f in self.extra["unrecorded_landings"]))
        # (summary.json's scene listed them, the run said nothing of holes it left out of the NLP)
        lines += [f"  left out: {reason}" for reason in self.extra.get("scene", {}).get("reasons", ())
                  if " is out of reach " in reason]
        lines += outside_range_lines(self.extra, len(tr.tau), "its NLP's bounds (plan.joint_bounds, or lbx and ubx "
                                     "edited through the Python API) allow it")
        lines += _braked_lines(self.extra)
        if self.extra.get("skims"):  # (they were counted as hops: frictionless slides of the foot along the ground)
            lines.append(f"  {len(self.extra['skims'])} skim(s) along the ground in one flight-mode step, where no "
                         "friction acts (no hops): " + ", ".join(f"{s['point']} t = {s['takeoff_time']:.4g} s "
                                                                f"{s['distance']:+.3g} m" for s in self.extra["skims"]))
        if self.extra.get("slides"):  # (several contacts: a foot slid so while another stood, and went unreported)
            lines.append(f"  {len(self.extra['slides'])} slide(s) of a contact point along its plane in flight mode, "
                         "where no friction acts: " + ", ".join(f"{s['point']} t = {s['start_time']:.4g} s "
                                                               f"{s['distance']:+.3g} m" for s in self.extra["slides"]))
        if "control_cost" in self.extra:
            # (with physical_time the sum is h s_k u_k^T u_k: "over numerical time" alone read as h u_k^T u_k)
            timed = task is not None and task.horizon.physical_time is not None
            scaled = " scaled by the speed of time s" if timed else ""
            lines.append(f"cost: integral of u^T u over numerical time{scaled} {self.extra['control_cost']:.4g}")
        if "race" in self.extra:  # planner.race: which variant this plan is, and what became of the others
            lines.append("race: " + race_arms_text(self.extra["race"]))
        if self.extra.get("no_walk"):  # planner.replan
            lines.append(f"  ({self.extra['no_walk']})")
        # the table's status column shows them; the verdict is the returned point's (only summary.json said so, by
        # the same rule: an unpolished plan's point is its last homotopy NLP's, whose status is the verdict's)
        hom = [r for r in self.nlps if r.label.startswith("homotopy")]
        early = [r.label for r in hom if not r.success and (self.polished or r is not hom[-1])]
        # a replan's last NLP held a schedule: whose, the start's or a re-timed one, is in the message (summary.json's)
        if not st.converged or self.nlps and self.nlps[-1].label.startswith(("schedule", "walk")):
            lines.append(f"  {st.message}")
        elif early:
            lines.append(f"  on the way, IPOPT stopped early in {', '.join(early)}; the verdict is the returned "
                         "point's")
        return "\n".join(lines)

    def summary(self) -> dict:
        """The summary.json object (contract keys first), without result_id, versions and validation."""
        st = self.stats
        return {
            **_contract_keys(self, terminal_error=self.terminal_error),
            "robot_sha256": self.robot_sha256,
            "hops": [hp.to_json() for hp in self.hops],
            "nlps": [r.to_json() for r in self.nlps],
            "polished": self.polished,
            "constraint_violation": self.constraint_violation,
            "timings": self.timings,
            "h": self.h,
            "rho_f": self.rho_f,
            "n_steps": len(self.trajectory.tau) - 1,
            "message": st.message,
            "options": self.options,
            **{k: v for k, v in self.extra.items() if not k.startswith("_")},
        }


def race_arms_text(arms: list[dict]) -> str:
    """planner.race's table (PlanResult.extra["race"]) as one line: each arm's outcome, iterations, wall time. A stopped
    arm's iterations are those of its finished NLPs (a stopped arm in its first NLP read "0 it" after 17 s)."""
    return ", ".join(f"{a['arm']} {a['outcome']} ({a['iterations']} it{' in finished NLPs' if a['outcome'] == 'stopped' else ''}, "
                     f"{a['wall_s']:.1f} s)" for a in arms)


# Relative clock deficit of a step that counts as frozen (an impact). In persistent contact the
# implicit step corrects the drift of the contact velocity with frozen fractions up to 3.4e-3 of a
# step; real impact entries froze at least 1.4e-2 (point mass and Capler drops): 1e-4 reported
# false impacts of 3e-4 to 2e-3 N s next to a 2 N s landing.
FROZEN_TOL = 1e-2


def clock_ran(clock: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """(N,) bool: which of N steps ran the clock, by the clock at their nodes clock (N+1,) [s] and their numerical
    lengths (N,) [s]: more than FROZEN_TOL of the step (a fully frozen step's clock leaks ~1e-6 of it)."""
    return np.diff(clock) > FROZEN_TOL * np.asarray(lengths, float)


# A FESD element shorter than this share of the longest is collapsed (its length is ~0 up to IPOPT's
# bound relaxation, ~1e-10 s measured) and never frozen; implicit Euler steps all have length h s >= h.
COLLAPSED = 1e-6
# A step after a fully frozen one that stopped the clock for more than this share of it ends that impact.
TAIL_SHARE = 1e-6
# A fully frozen step whose clock advanced less than this share of it did not run it: IPOPT's bound relaxation leaks
# ~1e-6 of a step (2.3e-6 on the default biped plan's landing, 1.9e-7 on a bounder's), no physical time.
CLOCK_LEAK = 1e-5
# Several contacts: a contact takes part in an impact (gets its own Impact record, same time and
# velocities) when its normal impulse over the frozen interval is at least this share of the
# largest one; smaller shares are the implicit step's drift corrections of contacts at rest.
IMPULSE_SHARE = 1e-2


def _at_rest(resting, k: int, step_impulses) -> bool:
    """Every contact that took a share of a step's normal impulse (step_impulses (n_contacts, 2) [N s]; IMPULSE_SHARE
    of the largest) rests on its plane at node k (resting (K-1 or K, n_contacts) bool; None: unknown): an inelastic
    impact that was on in the step before is over there (a partly frozen step after it was lumped into it: a Coulomb
    slide's v_post read +0.22 m/s off the ground), and a partly frozen step at rest at both ends is support. (Not the
    largest impulse's contact alone: a plank resting on one end takes 2.9 times the impulse of its other end landing
    at 6.4 m/s.)"""
    if resting is None or k >= len(resting):
        return False
    normal = np.abs(np.asarray(step_impulses, float)[:, 0])
    involved = normal >= IMPULSE_SHARE * normal.max() if normal.max() > 0 else np.arange(len(normal)) == 0
    return bool(np.all(np.asarray(resting[k])[involved]))


def recover(tau, y, u_steps, dt_steps, dv_aux, impulses, nq: int, nv: int, contacts: tuple[str, ...],
            frozen_tol: float = FROZEN_TOL, switch_at_start: bool = False,
            landed=None, approach=None, resting=None, pre_impact=None
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, tuple[Impact, ...]]:
    """Physical-time samples and impacts from a solved discretization (Thm. 10).

    tau (K,), y (K, ny) with the clock last; for each step k (K-1 of them, from y_k to y_{k+1}):
    u_steps (K-1, nu) control, dt_steps (K-1,) numerical-time length h s [s], dv_aux (K-1, nv)
    velocity increment of the auxiliary fields, impulses (K-1, n_contacts, 2) normal and tangential
    impulse [N s]. A step is frozen when its clock advanced less than (1 - frozen_tol) h s, fully frozen
    when less than still h s, still = min(frozen_tol, 1 - frozen_tol) (several contacts pass 1 - FROZEN_TOL). A run
    of frozen steps (one impact) is a first frozen step, the fully frozen steps after it and at most one more frozen
    step (a landing: the clock runs, the impact, the clock runs again; not when its contacts rest on their planes at
    that step's start, by `resting`: the impact was over); a frozen step after a partly frozen one that is not the
    run's first starts the next run. A partly frozen step whose contacts (those taking its normal impulse) rest at both
    its ends is support, no frozen step. A run that ends with a fully frozen step whose contact (the one taking the
    run's first step's largest normal impulse) still moves into its plane at the step's end, or a run of one step
    whose landing inside it is still on there, takes the next step too when that froze more than TAIL_SHARE of it (the
    impact's end, below frozen_tol).
    A landing at a node (below) whose step before froze more than TAIL_SHARE of it (and less than frozen_tol) began
    there: that step's increment and impulse are the impact's start, the node's sample becomes its pre-impact one, and
    tau_start is that step's. approach (K-1 or K, n_contacts) [m/s]: each contact's normal velocity at the start of
    each step (and at the last node), moving into its plane below -APPROACH_MPS (None: no such step is taken).
    resting (K-1 or K, n_contacts) bool: each contact on its plane (ON_PLANE_M) and at rest along its normal
    (APPROACH_MPS) there (None: no step is read as support, no impact ended by it). A run is an impact when the
    numerical time it froze, sum(h s - clock advance), is at least still times the longest step (so a FESD element
    a few 1e-8 s long is none).
    A frozen interval gives one Impact per contact whose normal impulse is at least IMPULSE_SHARE of
    the largest (the largest first; one contact: always one Impact), all with the interval's time,
    posture and pre-/post-impact velocities, and one pair of samples.
    switch_at_start: the first frozen step of an interval starts at the impact (FESD puts the switch on
    an element boundary), so the impact's time, posture and pre-impact velocity are its start point;
    otherwise (implicit Euler) the landing happens inside that step and they are taken at its end, less the step's
    auxiliary increment (the time: the node's before it when the step was fully frozen and its clock leaked less than
    CLOCK_LEAK of it, that node's sample then the pre-impact one), unless landed[a, c] (K-1, n_contacts) says the step
    starts with contact c, the one taking the step's largest normal impulse, already on its plane and moving into it (a
    landing that ended a whole flight step at a node) and the step ran the clock for part of its length (not fully
    frozen): then the impact comes first, at the step's start point, and the clock runs after it (the stance), so a
    frozen step after it is the next impact; dated
    at the step's end, it was one step late (a point-mass hop's landing 46 ms, Capler's 12-19 ms) with the stance's motion in
    its pre-impact velocity.
    pre_impact (dv (K-1, nv), dimp (K-1, n_contacts, 2)) or None: added to the pre-impact velocity and the impulse of
    a landing inside step k (implicit Euler's joint PD reacted to the post-impact velocity there; simulate's
    _pd_before_landing); v_post stays the run's end state.
    Returns t (P,), q (P, nq), v (P, nv), u (P, nu), impacts.
    """
    y, u_steps = np.asarray(y, float), np.asarray(u_steps, float)
    n_steps = len(y) - 1
    clock = y[:, -1]
    advance = np.diff(clock)
    dt_steps = np.asarray(dt_steps, float)
    # a FESD element collapsed to length ~0 (no switch to pin it) advances nothing and is no impact
    frozen = (advance < (1.0 - frozen_tol) * dt_steps) & (dt_steps > COLLAPSED * np.max(dt_steps, initial=0.0))
    # with several contacts frozen_tol is 1 - FROZEN_TOL (a step is frozen only when the clock stood still): the clock
    # stood still, and a run's last step ran it, by the smaller share (0.99 had dropped the end sample of a tail step
    # that ran the clock for 87.5 % of it after a bounder's landing, and the validation then blamed the user)
    still = min(frozen_tol, 1.0 - frozen_tol)
    fully = advance < still * dt_steps  # the clock (nearly) stood still over the whole step
    # a partly frozen step whose contacts (those taking its normal impulse) rest on their planes at both ends is
    # support, not an impact: its auxiliary field carried part of the weight (a Coulomb slide read as 13 impacts, a
    # physical_time stance as 12 to 25 that MuJoCo never saw); its end is a physical sample
    impulses = np.asarray(impulses, float)
    for k in range(n_steps if resting is not None and not switch_at_start and len(contacts) else 0):
        if frozen[k] and not fully[k] and _at_rest(resting, k, impulses[k]) and _at_rest(resting, k + 1, impulses[k]):
            frozen[k] = False
    min_frozen = still * np.max(dt_steps, initial=0.0)  # [s] of numerical time
    nu = u_steps.shape[1] if u_steps.ndim == 2 else 0
    u0 = u_steps[0] if n_steps else np.zeros(nu)
    ts, qs, vs, us = [clock[0]], [y[0, :nq]], [y[0, nq : nq + nv]], [u0]
    impacts = []
    k, run_end = 0, -1  # run_end: the last step of the previous frozen run
    while k < n_steps:
        if not frozen[k]:
            ts.append(clock[k + 1]); qs.append(y[k + 1, :nq]); vs.append(y[k + 1, nq : nq + nv]); us.append(u_steps[k])
            k += 1
            continue
        a = b = k
        # the impact goes on into the next frozen step only if it was still on at step b's end: after the run's
        # first step (the clock may run before the impact, a landing inside the step) and after a fully frozen
        # step. A later partly frozen step ran the clock after the impact, so its end is a physical sample and a
        # frozen step after it is the next impact: lumping it in made v_post the sum of every auxiliary increment
        # (support over the running parts too), a velocity the plan never has (docs/validation.md, session 36)
        # an implicit-Euler landing at a node ran the clock after its impact already in step a (one that froze the
        # whole step is the same instant either way: dated as before, so the biped's plans keep their samples)
        # (the contact that takes the step's largest normal impulse: another foot's stance drift is no landing)
        lander = int(np.argmax(np.abs(impulses[a, :, 0]))) if len(contacts) else 0
        at_node = landed is not None and bool(landed[a][lander]) and not switch_at_start and not fully[a]
        over = _at_rest(resting, b + 1, impulses[b])  # (a landing inside step a that ended there)
        while b + 1 < n_steps and frozen[b + 1] and ((b == a and not at_node and not over) or fully[b]):
            b += 1
        # an impact still on at the end of a fully frozen step (its contact still moving into its plane there) ends
        # in the next one, however little of it that step froze (below frozen_tol it is no frozen step): its increment
        # and impulse are the impact's end (a drop whose last step ran the clock for 99.2 % of it kept v_post moving
        # into the ground at 7.8 mm/s). A stance's drift correction after an impact that ended at the step's end is
        # not (a replan's push-off was counted into its landing). Implicit Euler: FESD ends impacts on element bounds.
        # So does a landing inside the run's first step still on at its end (the clock ran before the impact; a_n = 1e4
        # at h = 0.02 had its v_post moving into the ground at 2 m/s, the next step freezing 0.99 % of it)
        tail = (not switch_at_start and approach is not None and (fully[b] or (b == a and not at_node))
                and b + 1 < n_steps)
        if tail and approach[b + 1][lander] < -APPROACH_MPS and advance[b + 1] < (1 - TAIL_SHARE) * dt_steps[b + 1]:
            b += 1
        # a landing at a node that began in the step before (it froze less than frozen_tol, so no frozen step, and
        # more than TAIL_SHARE): that step's increment and impulse are the impact's start (a_n = 1e4 at h = 0.01 read
        # v_pre -3.4 m/s for -4.4 and 23 % of the impulse missing); the node's sample becomes the pre-impact one
        head = at_node and a - 1 > run_end and advance[a - 1] < (1 - TAIL_SHARE) * dt_steps[a - 1]
        first = a - 1 if head else a
        if np.sum(dt_steps[a : b + 1] - advance[a : b + 1]) < min_frozen:
            # a FESD sliver: an element of ~1e-8 s between two switches leaks its clock like a frozen one
            # (the biped's second landing at h = 0.01 had one: a false 8e-5 N s impact); run on through it
            frozen[a : b + 1] = False
            continue
        # the first frozen step may run the clock for part of the step (a landing), never backwards: a
        # solver's bound relaxation can leave it 1e-10 s behind the previous sample
        if switch_at_start or at_node:
            # the clock a selector leaks while frozen (~1e-6 of a step) stays out of the impact time
            t_imp, q_imp, v_pre = max(clock[a], ts[-1]), y[a, :nq], y[a, nq : nq + nv]
            # the run's end state: v_pre plus the auxiliary increments when every element stopped the clock, and
            # also right where the last element ran it for part of its length (a stance whose auxiliary field
            # carries part of the weight at 95 % clock: its increment, support included, read +0.94 m/s upward
            # for a point mass at rest). An implicit-Euler landing at a node: likewise the step's end state, since
            # v_pre plus the step's increment is no state of the plan (it lumps the push-off the step runs after it)
            v_post = y[b + 1, nq : nq + nv]
            if head:
                v_pre = v_pre - dv_aux[a - 1]
                vs[-1] = v_pre
        else:
            t_imp, q_imp = max(clock[a + 1], ts[-1]), y[a + 1, :nq]
            if fully[a] and t_imp - ts[-1] < CLOCK_LEAK * dt_steps[a]:
                # the impact is at the node's time, whose sample is then its pre-impact one (below): dated at the
                # leaked clock, the node's state was repeated 4.5e-8 s later as the pre-impact sample, three in all
                t_imp = ts[-1]
            v_pre = y[a + 1, nq : nq + nv] - dv_aux[a]
            v_post = v_pre + np.sum(dv_aux[a : b + 1], axis=0)
        imp = np.sum(impulses[first : b + 1], axis=0)  # (n_contacts, 2)
        if pre_impact is not None and not (switch_at_start or at_node):
            v_pre, imp = v_pre + pre_impact[0][a], imp + pre_impact[1][a]
        order = np.argsort(-np.abs(imp[:, 0]), kind="stable") if len(contacts) else np.zeros(1, int)
        # one Impact per contact that took a normal impulse in this frozen interval, the largest first;
        # with one contact (or none) exactly one Impact, as before
        hit = [c for c in order if len(contacts) <= 1 or c == order[0]
               or abs(imp[c, 0]) >= IMPULSE_SHARE * abs(imp[order[0], 0])]
        for c in hit:
            impacts.append(Impact(time=float(t_imp), contact=contacts[c] if contacts else "", impulse=float(imp[c, 0]) if len(contacts) else 0.0,
                                  impulse_tangential=float(imp[c, 1]) if len(contacts) else 0.0, q=q_imp.copy(),
                                  v_pre=v_pre, v_post=v_post, tau_start=float(tau[first]), tau_end=float(tau[b + 1])))
        # a landing at a node: that node's sample is already the pre-impact one (an impact is two samples at one time);
        # so is it when implicit Euler's first step froze whole without advancing the clock: its end less the step's
        # increment is the node's state to rounding (a Capler plan had three samples at one time, 4e-10 m/s apart)
        repeated = ts[-1] == t_imp and (
            (at_node and np.array_equal(qs[-1], q_imp) and np.array_equal(vs[-1], v_pre))
            or (fully[a] and not switch_at_start))
        for vel in (v_pre, v_post)[int(repeated):]:
            ts.append(t_imp); qs.append(q_imp); vs.append(vel); us.append(u_steps[a])
        if clock[b + 1] > t_imp + still * dt_steps[b]:  # the run's last step also ran the clock
            ts.append(clock[b + 1]); qs.append(y[b + 1, :nq]); vs.append(y[b + 1, nq : nq + nv]); us.append(u_steps[b])
        k, run_end = b + 1, b
    return np.array(ts), np.array(qs), np.array(vs), np.array(us).reshape(len(ts), nu), tuple(impacts)


def write_results(result: SimulationResult | PlanResult, out_dir: str | os.PathLike,
                  result_id: str | None = None) -> tuple[Path, Path]:
    """Write DIR/trajectory.npz and DIR/summary.json, each atomically (temp file + os.replace), with result_id (None:
    a new one; the caller that makes it knows its own files from another run's written to DIR after them)."""
    expect(result, (SimulationResult, PlanResult), "write_results' result")
    tr = result.trajectory
    arrays = {
        "tau": tr.tau, "y": tr.y, "t": tr.t, "q": tr.q, "v": tr.v, "u": tr.u,
        "impact_times": tr.impact_times,
        "impact_impulses": np.array([imp.impulse for imp in tr.impacts], dtype=float),
        "sigma": tr.sigma,
        "state_names": np.array(tr.state_names, dtype=str),
        "selector_names": np.array(tr.selector_names, dtype=str),
    }
    if tr.forces is not None:
        arrays.update(forces=tr.forces, force_names=np.array(tr.force_names, dtype=str))
    if "_x" in result.extra and "_signature" in result.extra:  # a plan: its NLP point, to start a replan from
        arrays.update(nlp_x=np.asarray(result.extra["_x"], float), nlp_signature=np.array(result.extra["_signature"]))
    if "_task" in result.extra:  # the task as solved (--steps applied): a replan's walk and validate(DIR) read it
        arrays["task_json"] = np.array(task_to_json(result.extra["_task"]))
    sampled = tr.contact_force_samples()
    if sampled is not None:
        arrays.update(lambda_n=sampled[0], lambda_t=sampled[1])
    return write_files(out_dir, arrays, result.summary(), result_id)


@contextlib.contextmanager
def directory_lock(out_dir: Path):
    """Hold an exclusive lock on the directory (flock on its own descriptor: no lock file left behind) while a result
    is renamed into it or its summary rewritten: a validation read the summary, another run replaced it, and the
    validation wrote the old summary back over the new one. Where locks are not possible, no lock."""
    try:
        fd = os.open(out_dir, os.O_RDONLY)
    except OSError:
        yield
        return
    try:
        with contextlib.suppress(OSError):
            fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # closing releases the lock


# the modules whose versions a result records: a plan's homotopy path moves with CasADi's rounding, and the
# dynamics and the validation come from Pinocchio and MuJoCo
VERSIONED = ("casadi", "pinocchio", "mujoco", "numpy")


def software_versions() -> dict[str, str]:
    """planner's, Python's and VERSIONED's versions, as summary.json's `versions` records them: each module's own
    __version__ (pip's distribution of pinocchio is "pin", conda's "pinocchio"), "not installed" for one that does not
    import."""
    from . import __version__
    versions = {"planner": __version__, "python": platform.python_version()}
    for name in VERSIONED:
        try:
            versions[name] = str(importlib.import_module(name).__version__)
        except ImportError:
            versions[name] = "not installed"
    return versions


def write_files(out_dir: str | os.PathLike, arrays: dict, summary: dict,
                result_id: str | None = None) -> tuple[Path, Path]:
    """Write DIR/trajectory.npz (arrays) and DIR/summary.json atomically (temp files + os.replace), both written before
    either is renamed, each with the same `result_id` (check_same_result; None: a new one). DIR is created if missing;
    an existing file there is an InputError."""
    expect(out_dir, (str, os.PathLike), "the output directory")
    expect(result_id, (str, type(None)), "result_id")  # (an int 123 was written, and its readers compared '123')
    if os.fspath(out_dir) == "":  # Path("") is the working directory, which the CLI's --out "" refuses too
        raise InputError("the output directory is empty (''); name one, '.' for the working directory")
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(f"cannot write results to {out}: it is a file, not a directory")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:  # a parent that is a file, no permission, a read-only file system (a full disk: exit 1)
        raise write_error(out, exc, "cannot create output directory") from None
    # one id in both files: a crash between their renames leaves two results' files, which readers then refuse
    result_id = uuid.uuid4().hex if result_id is None else result_id
    arrays = {**arrays, "result_id": np.array(result_id)}
    summary = {**summary, "versions": software_versions(), "result_id": result_id}
    npz, path = out / "trajectory.npz", out / "summary.json"
    for target in (npz, path):  # its rename would fail after the other's: refused before either file is written
        if target.is_dir():
            raise InputError(f"cannot write {target}: it is a directory")
    staged = []
    try:  # both written before either replaces a file: a full disk or a bad value leaves the earlier result whole
        staged.append((_stage(npz, lambda f: np.savez(f, **arrays)), npz))
        staged.append((_stage(path, json.dumps(summary, indent=2, default=_json_default) + "\n"), path))
    except BaseException:
        for tmp, _ in staged:
            Path(tmp).unlink(missing_ok=True)
        raise
    try:
        with directory_lock(out):
            _replace(staged)
    except BaseException:  # a Ctrl-C while waiting for the lock: the staged files go (_replace removes its own)
        for tmp, _ in staged:
            Path(tmp).unlink(missing_ok=True)
        raise
    return npz, path


def check_same_result(out_dir: str | os.PathLike, summary: dict, arrays: dict) -> None:
    """InputError when out_dir's summary.json and trajectory.npz (read as `summary`, `arrays`) carry different
    result ids, or only one of them an id: files of two results, a run stopped between writing them (a summary.json
    without its id beside another run's trajectory.npz was validated as one result). Files without ids (older
    results) pass."""
    ids = summary.get("result_id"), str(arrays["result_id"]) if "result_id" in arrays else None
    if ids[0] != ids[1]:
        raise InputError(f"{out_dir}: summary.json and trajectory.npz are files of two different results (a run stopped "
                         "between writing them?); run the plan or simulation again")


# summary.json's impact times against trajectory.npz's: the same floats, written twice
IMPACT_TIME_AGREE_S = 1e-9


def check_impacts_agree(out_dir: str | os.PathLike, impacts, impact_times) -> None:
    """InputError when summary.json's impacts (a list) and trajectory.npz's impact_times (I,) [s] differ in number or
    in a (numeric) time: the two files no longer say the same (impact_times moved by 0.1 s validated against the moved
    times; an edited summary was drawn by view)."""
    if not isinstance(impacts, list):
        return
    if len(impacts) != len(impact_times):  # (an impact added or removed validated against the npz's alone)
        raise InputError(f"{out_dir}: trajectory.npz has {len(impact_times)} impact time(s), summary.json "
                         f"{len(impacts)} impact(s): the two files disagree (was one edited?)")
    for i, (item, when) in enumerate(zip(impacts, impact_times)):
        said = item.get("time") if isinstance(item, dict) else None
        numeric = isinstance(said, (int, float)) and not isinstance(said, bool)
        if numeric and not abs(said - when) <= IMPACT_TIME_AGREE_S:
            raise InputError(f"{out_dir}: trajectory.npz's impact_times[{i}] = {when:.9g} s, summary.json's "
                             f"impacts[{i}] time {said:.9g} s: the two files disagree (was one edited?)")


def clock_goes_back(t: np.ndarray) -> str:
    """Where the physical time t (P,) [s] of a result falls, or "" when it never does: its largest fall (by how much,
    from and to which time, at which sample) and how many samples fall. A failed solve's last iterate may: the
    far-hole hop's went back from 0.541 s to -0.110 s."""
    falls = np.flatnonzero(np.diff(t) < 0)
    if not falls.size:
        return ""
    k = int(falls[np.argmax(t[falls] - t[falls + 1])])
    return (f"t falls by {t[k] - t[k + 1]:.3g} s, from {t[k]:.6g} s to {t[k + 1]:.6g} s at sample {k + 1}"
            + (f", and falls at {falls.size - 1} more sample(s)" if falls.size > 1 else ""))


def _json_default(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"not JSON serializable: {type(obj).__name__}")


def _keep(path: Path) -> tuple[bool, str | None]:
    """Whether path holds a file, and a hard link to it under a temp name beside it (None: no file there, or links
    not possible)."""
    if not path.is_file():
        return False, None
    link = f"{path.parent}/.{path.name}.{os.getpid()}.{threading.get_ident()}.kept.tmp"  # _remove_stale's, if killed
    try:
        Path(link).unlink(missing_ok=True)
        os.link(path, link)
    except OSError:  # a file system without hard links, an immutable file: no rollback for this one
        return True, None
    return True, link


def _umask() -> int:
    """The process's umask, read without setting it where Linux says it (/proc/self/status "Umask:"): os.umask(0)
    and back left it 0 for a moment, in which another thread's files came out world-writable."""
    with contextlib.suppress(OSError, StopIteration, ValueError):
        with open("/proc/self/status", encoding="ascii") as f:
            return int(next(line for line in f if line.startswith("Umask:")).split()[1], 8)
    umask = os.umask(0)  # (not Linux)
    os.umask(umask)
    return umask


def write_atomically(path: str | os.PathLike, write, follow_links: bool = True) -> None:
    """Write path through a temp file in the same directory, then os.replace: readers never see half a
    file, and a crash leaves the previous file as it was. write(f) gets the binary file object; a str
    or bytes is written as it is (str as UTF-8). The file gets the mode a plain open() would give (0666 less the
    umask), not mkstemp's private 0600. An OSError (no permission, a read-only directory) is an InputError naming
    the path. A symbolic link is written through: its target gets the file (`view --html LINK` replaced the link by a
    file, the page it pointed at left stale); follow_links False replaces the link itself (a result directory's own
    file: a summary.json linked to another directory's was rewritten there)."""
    path = Path(os.path.realpath(path)) if follow_links and Path(path).is_symlink() else Path(path)
    _replace([(_stage(path, write), path)])


def write_beside_result(path: str | os.PathLike, write, result_id: str | None) -> bool:
    """write_atomically, renamed in only while the directory's summary.json is still the result `result_id`'s (checked
    under directory_lock, which a result's write holds): False, and nothing written, once another run's result has
    replaced it. A run's plots, drawn after its result was written, landed beside another run's result written into
    the same directory meanwhile. result_id None: write_atomically."""
    if result_id is None:
        write_atomically(path, write)
        return True
    path = Path(path)
    tmp = _stage(path, write)
    with directory_lock(path.parent):
        try:
            ours = json.loads((path.parent / "summary.json").read_text()).get("result_id") == result_id
        except (OSError, ValueError, AttributeError):  # (gone, half a file, not an object: not ours either)
            ours = False
        if not ours:
            Path(tmp).unlink(missing_ok=True)
            return False
        _replace([(tmp, path)])
    return True


# A temp file of a write older than this [s] is a killed writer's (SIGKILL, or the plot process ended at exit): the
# next write of the same file removes it. A live writer's is seconds old.
STALE_TEMP_S = 3600.0


def _temp_prefix(path: Path) -> str:
    """The start of the names of `path`'s temp files: "." + its name + ".", the name cut so that the temp's name (14
    characters more) stays within NAME_MAX = 255 bytes (a valid 245-character name was refused as too long)."""
    name = path.name
    while len(os.fsencode(f".{name}.XXXXXXXX.tmp")) > 255:  # (bytes as the OS sees them: a name of \xff bytes too)
        name = name[:-1]
    return f".{name}."


def _remove_stale(path: Path) -> None:
    """Remove the temp files of earlier writes of `path` left older than STALE_TEMP_S (nothing else cleaned them)."""
    now = time.time()
    for old in path.parent.glob(f"{glob.escape(_temp_prefix(path))}*.tmp"):
        with contextlib.suppress(OSError):  # another process removed it first, or it cannot be: left as it is
            if now - old.lstat().st_mtime > STALE_TEMP_S:
                old.unlink()


def _stage(path: str | os.PathLike, write) -> str:
    """The temp file beside `path` that write_atomically renames to it, written (write as there); its name."""
    path = Path(path)
    if path.exists() and not path.is_file() and not path.is_dir():  # (a directory: said by the caller or the rename)
        # the rename replaces whatever is there: `view --html /dev/full` deleted the device
        raise InputError(f"cannot write {path}: it is not a regular file (a device, FIFO or socket), which the write "
                         "would replace; name a file")
    if isinstance(write, (str, bytes)):
        data = write.encode() if isinstance(write, str) else write
        write = lambda f: f.write(data)  # noqa: E731
    _remove_stale(path)
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=_temp_prefix(path), suffix=".tmp")
    except OSError as exc:
        raise write_error(path, exc) from None
    try:
        # a file replaced keeps its mode (validate made a private summary.json world-readable)
        os.fchmod(fd, stat.S_IMODE(path.stat().st_mode) if path.is_file() else 0o666 & ~_umask())
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())  # on disk before the rename: a power cut after it could leave an empty file
    except BaseException as exc:
        Path(tmp).unlink(missing_ok=True)
        if isinstance(exc, OSError):
            raise write_error(path, exc) from None
        raise
    return tmp


def _replace(staged: list[tuple[str, Path]]) -> None:
    """Rename each staged temp file to its path; on an error the files already renamed are rolled back to the earlier
    ones (kept as hard links until all are renamed: a summary.json that could not be replaced had left the new
    trajectory.npz beside the old summary) and the temp files not yet renamed are removed. Ctrl-C and
    SIGTERM wait until all are renamed (errors.signals_held): between two renames they left files of two results."""
    kept: dict[Path, tuple[bool, str | None]] = {}  # path -> (it held a file, a hard link to that file)
    with signals_held():
        try:
            for i, (tmp, path) in enumerate(staged):
                try:
                    kept[path] = _keep(path) if len(staged) > 1 else (False, None)
                    os.replace(tmp, path)
                except OSError as exc:
                    for left, _ in staged[i:]:
                        Path(left).unlink(missing_ok=True)
                    for _, done in staged[:i]:
                        existed, link = kept.pop(done)
                        with contextlib.suppress(OSError):  # the error to report is the one above
                            if link is not None:
                                os.replace(link, done)
                            elif not existed:  # there was none: the new one goes too
                                done.unlink()
                    raise write_error(path, exc) from None
            with contextlib.suppress(OSError):  # the renames on disk too (a directory that cannot be opened: as before)
                for folder in {path.parent for _, path in staged}:
                    fd = os.open(folder, os.O_RDONLY)
                    try:
                        os.fsync(fd)
                    finally:
                        os.close(fd)
        finally:
            for _, link in kept.values():
                if link is not None:
                    Path(link).unlink(missing_ok=True)


# --- reading a result directory back (replay and view use these) -------------------------------------

def result_dir(out_dir) -> Path:
    """out_dir as a Path, or an InputError when it is missing or a file ("afile/trajectory.npz not found" and "result
    directory not found: afile" named a path that exists)."""
    directory = Path(out_dir)
    if not directory.is_dir():
        raise InputError(f"{directory} is a file, not a result directory" if directory.exists() else
                         f"result directory not found: {directory}")
    return directory


def _failed_hint(out_dir) -> str:
    """"; a failed run's diagnostics are in DIR/failed" when they are (a result file missing from DIR), or ""."""
    failed = Path(out_dir) / "failed"
    return f"; a failed run's diagnostics are in {failed}" if (failed / "summary.json").is_file() else ""


def read_summary(out_dir: Path, require: tuple[str, ...] = ("robot", "task")) -> dict:
    """summary.json as a dict holding a path for each key of `require` (InputError otherwise)."""
    path = result_dir(out_dir) / "summary.json"
    if path.exists() and not path.is_file():  # a FIFO (or a device) there made validate wait for ever
        raise InputError(f"{path} is not a regular file")
    try:
        summary = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(f"{path} not found: is {out_dir} a result directory of `planner plan`/`simulate`?"
                         f"{_failed_hint(out_dir)}") from None
    except OSError as exc:
        raise read_error(path, exc) from None
    except UnicodeDecodeError as exc:
        raise InputError(f"cannot read {path}: {exc}") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{path} is not valid JSON: {exc}") from None
    except RecursionError:
        raise InputError(f"{path} is nested too deeply to be a result's summary") from None
    except ValueError as exc:  # an integer of more than 4300 digits
        raise InputError(f"{path} cannot be read as a result's summary: {exc}") from None
    if not isinstance(summary, dict):
        raise InputError(f"{path} must hold a JSON object, got {type(summary).__name__}")
    for key in require:
        if not isinstance(summary.get(key), str) or not summary[key]:
            raise InputError(f"{path} has no {key!r} path (a string); it is needed to rebuild the scene")
    return summary


def read_trajectory(out_dir: Path, required: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """The arrays of out_dir/trajectory.npz; InputError when missing, unreadable or lacking `required`."""
    path = result_dir(out_dir) / "trajectory.npz"
    if not path.is_file():
        raise InputError(f"{path} not found{_failed_hint(out_dir)}")
    try:  # read whole (~0.1-1 MB): zipfile.is_zipfile took an I/O error for "no zip archive", the user's (exit 2)
        data = path.read_bytes()
    except OSError as exc:
        raise read_error(path, exc) from None
    if not zipfile.is_zipfile(io.BytesIO(data)):  # (numpy read any other file as pickled data, said to allow pickles)
        raise InputError(f"{path} is not a readable .npz file: it is no zip archive (a Git LFS pointer, a truncated "
                         "or another file?)")
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as npz:
            arrays = {k: np.asarray(npz[k]) for k in npz.files}
    except OSError as exc:  # (no errno: numpy's own "cannot read" of a damaged file, the user's; EIO the machine's)
        raise read_error(path, exc) from None
    except Exception as exc:  # zipfile.BadZipFile, ValueError (pickled object arrays), EOFError
        raise InputError(f"{path} is not a readable .npz file: {type(exc).__name__}: {exc}") from None
    missing = [k for k in required if k not in arrays]
    if missing:
        raise InputError(f"{path} lacks {', '.join(missing)}")
    return arrays


def check_start(out_dir: Path, robot, arrays: dict) -> None:
    """InputError unless out_dir (a replan's start: `--init DIR`, read_start's robot) holds one converged plan of the
    robot's file (planner.model.Robot), arrays its trajectory arrays: a failed plan's last iterate (DIR/failed) was held
    as a contact schedule, and a plan of another file with the same joint and point names (another mass) was accepted,
    as the NLP variables' names match."""
    from .model import file_sha256

    summary = read_summary(out_dir, require=())
    check_same_result(out_dir, summary, arrays)
    if summary.get("converged") is not True:  # "no" (an edited file) passed as converged
        raise InputError(f"{out_dir} holds a plan that did not converge (summary.json's converged is "
                         f"{shown(summary.get('converged'))}): a replan starts from a converged plan")
    if check_robot_unchanged(summary, robot, out_dir):
        return
    named = summary.get("robot")
    try:  # a result written before summary.json kept robot_sha256
        path = locate_input(named, out_dir, "robot") if isinstance(named, str) else None
    except InputError:  # moved since: the variables' names are still compared
        path = None
    if path is not None and file_sha256(path) != robot.sha256:
        raise InputError(f"{out_dir} is a plan of the robot file {named}, whose contents differ from {robot.path}: a "
                         "replan starts from a plan of the same robot")


def read_start(out_dir: str | os.PathLike, signature: str, nx: int, arrays: dict[str, np.ndarray] | None = None,
               robot=None) -> np.ndarray:
    """The NLP point (nx,) that a plan stored in out_dir/trajectory.npz, to start a problem whose
    Problem.signature is `signature` from it; InputError when out_dir holds no plan's point or one of
    other variables (another N, contact set, discretization or formulation). arrays: out_dir's trajectory
    arrays when already read. robot: the problem's (planner.model.Robot); given, out_dir must hold a converged plan of
    that robot file's contents too (check_start, as `planner plan --init DIR`: the API replanned from a failed plan's
    last iterate, and from a plan of the file before an edit)."""
    expect(out_dir, (str, os.PathLike), "read_start's out_dir")
    expect(signature, str, "read_start's signature (Problem.signature)")
    if not is_integer(nx):  # ("5" read as "291 against this problem's 5")
        raise InputError(f"read_start's nx (Problem.nx) must be an int, got {type(nx).__name__} {nx!r:.60}")
    from .model import Robot

    expect(robot, (Robot, type(None)), "read_start's robot")
    arrays = read_trajectory(out_dir) if arrays is None else arrays
    if robot is not None:
        check_start(out_dir, robot, arrays)
    if "nlp_x" not in arrays or "nlp_signature" not in arrays:
        plan = False
        with contextlib.suppress(InputError):  # (a plan of an older planner was said not to be a plan)
            plan = read_summary(out_dir, require=()).get("command") == "plan"
        raise InputError(f"{Path(out_dir) / 'trajectory.npz'} holds no NLP point: "
                         + ("the plan was written by an older planner, which did not keep it; plan without --init"
                            if plan else "a start needs a result of `planner plan`"))
    x = real_array(arrays["nlp_x"], f"{Path(out_dir) / 'trajectory.npz'}: nlp_x")
    if str(arrays["nlp_signature"]) != signature or x.shape != (nx,):
        which = (f"{x.size} against this problem's {nx}" if x.size != nx else
                 f"variables {str(arrays['nlp_signature'])[:16]!r} against this problem's {signature!r}" if x.ndim == 1 else
                 f"an array of shape {x.shape} against this problem's ({nx},)")
        raise InputError(f"the plan in {out_dir} has other NLP variables ({which}): "
                         "a start needs the same robot, contacts, N, discretization and options")
    if not np.all(np.isfinite(x)):
        raise InputError(f"the NLP point in {Path(out_dir) / 'trajectory.npz'} is not finite")
    return x


def read_task(out_dir: Path, arrays: dict[str, np.ndarray] | None = None, summary: dict | None = None) -> Task:
    """The task a result solved: trajectory.npz's task_json (`planner plan` keeps it, --steps included), else
    (a result without it) the task file its summary.json names. arrays, summary: out_dir's trajectory arrays
    and summary when already read. InputError when neither can be read."""
    arrays = read_trajectory(out_dir) if arrays is None else arrays
    if "task_json" not in arrays:
        summary = read_summary(out_dir, require=()) if summary is None else summary
        if not isinstance(summary.get("task"), str) or not summary["task"]:
            raise InputError(f"{Path(out_dir) / 'summary.json'} has no 'task' path (a string) and trajectory.npz no "
                             "task_json; one of them is needed to rebuild the scene")
        return load_task(locate_input(summary["task"], out_dir, "task"))
    try:
        data = json.loads(str(arrays["task_json"]))
    except (json.JSONDecodeError, RecursionError) as exc:
        raise InputError(f"{Path(out_dir) / 'trajectory.npz'}: task_json is not valid JSON: {exc}") from None
    if not isinstance(data, dict):
        raise InputError(f"{Path(out_dir) / 'trajectory.npz'}: task_json must hold a JSON object, got {type(data).__name__}")
    return parse_task(data, source=f"{Path(out_dir) / 'trajectory.npz'}")


def read_robot(out_dir: Path, summary: dict):
    """The robot (planner.model.Robot) of a result: the file its summary.json names (locate_input), refused when its
    contents differ from those the result was computed with (summary.json's robot_sha256; results written before it
    had none): a plan of a 1 kg mass passed validation against the file edited to 1.3 kg."""
    from .model import load_robot

    robot = load_robot(locate_input(summary["robot"], out_dir, "robot"))
    check_robot_unchanged(summary, robot, out_dir)
    return robot


def check_robot_unchanged(summary: dict, robot, out_dir: Path) -> bool:
    """InputError when `robot`'s file has other contents than the result's summary.json says it was computed from
    (robot_sha256: a file edited in place since is caught too); False when the summary predates robot_sha256."""
    then = summary.get("robot_sha256")
    if then is not None and not isinstance(then, str):  # a number or a list there switched the check off
        raise InputError(f"{Path(out_dir) / 'summary.json'}: robot_sha256 must be a string (the robot file's SHA-256), "
                         f"got {shown(then)}")
    if not then:
        return False
    if then != robot.sha256:
        source, named = summary.get("robot"), None
        with contextlib.suppress(InputError):  # (the file as validate and view find it: a relative or bare name too)
            named = locate_input(source, Path(out_dir), "robot") if isinstance(source, str) and source else None
        if named is not None and named.resolve() != Path(robot.path).resolve():  # another robot, not an edited file
            raise InputError(f"the result in {out_dir} was computed for another robot file, {source}, not "
                             f"{robot.path}: use that file, or a result of this one")
        raise InputError(f"the robot file {robot.path} has other contents (SHA-256 {robot.sha256[:12]}...) than the "
                         f"one the result in {out_dir} was computed from ({then[:12]}...): compute the result "
                         "again with this file, or use that one")
    return True


def locate_input(name: str, out_dir: Path, what: str) -> Path:
    """A robot or task path named in summary.json: as written (from the working directory), else
    relative to the result directory; a bare robot name (e.g. `capler`) is a file of robots/."""
    from .model import resolve_robot_path

    for candidate in (Path(name), Path(out_dir) / name):
        if candidate.is_file():
            return candidate
    if what == "robot" and not Path(name).suffix and Path(name).parent == Path("."):
        return resolve_robot_path(name)
    raise InputError(f"the {what} file {name!r} named in {Path(out_dir) / 'summary.json'} was not found "
                     f"(tried from the working directory and from {out_dir})")

