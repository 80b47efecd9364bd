"""Stress test of the planner's numerics (issue 10): seeded perturbed tasks, planned, validated, classified.

A seed gives a deterministic list of tasks: each FAMILY perturbs one aspect of a base task (Capler's
robots/capler.toml, or a cheap point-mass hop) -- holes, targets and horizons, initial states
(standing, airborne, exactly at contact, grazing, penetrating by <= 1e-9 m), friction, auxiliary
gains, grid size N, rho_f, the homotopy, torque bounds, and targets out of reach. Each task is planned
(build_problem + solve; with --race the race of two solver variants on two CPUs that `planner plan`
runs, planner.race), a converged plan is replayed in MuJoCo (planner.replay.validate_plan), and the
task gets exactly one OUTCOME:

    converged and valid               the solve's verdict is converged and the MuJoCo validation passed
    converged but invalid in MuJoCo   converged, but the validation failed (its failures are recorded)
    did not converge, diagnosed       the solve returned not converged with its message (the diagnosis)
    crashed                           an exception (recorded with its stage and traceback), or a NaN/Inf
                                      in something the pipeline accepted (the build, the solution of a
                                      converged solve, its recovered trajectory, a passed validation)

NaN/Inf is looked for at every stage -- the built problem (x0, bounds, f and g at x0), each NLP's record
(objective, complementarity, terminal error), the returned solution, the recovered trajectory and the
validation's numbers -- and every finding is listed with its stage in the task's record (`nonfinite`),
also where the solver itself rejected the point. Tasks run through planner.batch (local processes, or
a Dask scheduler with --scheduler). Writes OUT/results.json (every task: its generated task as a
TOML-like dict, its outcome, timings and diagnostics) and OUT/summary.md (the table per family);
OUT/records.partial.jsonl gets each record as its task finishes (what a stopped run keeps); it becomes
OUT/records.jsonl when the run is done.

    python -m scripts.stress [--robot capler|point_mass] [--families F ...] [--per-family K] [--seed S]
                             [--N N] [--max-iter M] [--race] [--scheduler ADDRESS] [--workers W] [--out DIR] [--json]
"""
from __future__ import annotations

import copy
import dataclasses
import json
import math
import os
import shlex
import sys
import time
import tomllib
import zlib
from pathlib import Path

import numpy as np

from planner.batch import Crashed, default_workers, run_batch, stage
from planner.errors import InputError, usable_cpus
from planner.result import write_atomically
from planner.task import Contact
from scripts._report import machine_info as shared_machine_info
from scripts._report import out_dir, refuse_beside, run_info, run_main, script_parser

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_OUT = Path("results/stress")

CONVERGED_VALID = "converged and valid"
CONVERGED_INVALID = "converged but invalid in MuJoCo"
DIAGNOSED = "did not converge, diagnosed"
CRASHED = "crashed"
OUTCOMES = (CONVERGED_VALID, CONVERGED_INVALID, DIAGNOSED, CRASHED)

# The cheap base task: a point mass hopping 0.5 m along the table in 1 s (tests/test_plan.py's task), with
# a_t = mu a_n: an impact's tangential impulse then stays within mu times its normal one, as MuJoCo's
# Coulomb contact requires; the default a_t = 3 a_n stopped landings at 2-3 m/s along the ground that MuJoCo
# cannot stop (docs/stability.md). The friction and gains families keep a_t <= mu a_n.
POINT_MASS_TASK = {
    "contacts": [{"point": "point", "mu": 0.5, "a_n": 200.0, "a_t": 100.0}],
    "initial": {"q": [0.0, 0.0]},
    "horizon": {"tau_f": 1.0, "N": 40},
    "plan": {"target_q": [0.5, 0.0], "u_bound": 30.0},
}
BASES = {"capler": "robots/capler.xml", "point_mass": "robots/point_mass.xml"}
X, Z = 0, 1  # both base robots: q[0] is the horizontal, q[1] the vertical slide of the base [m]


# ==================================================================================================
# the seeded task generator
# ==================================================================================================

@dataclasses.dataclass(frozen=True)
class Base:
    """A base task and the geometry the families need: where the base stands with its foot on the ground."""

    name: str
    robot: str  # robot file, relative to the repository root
    task: dict  # TOML-like task dict (parse_task)
    foot: str  # the contact point
    joints: tuple[int, ...]  # q indices of the actuated joints (perturbed postures)
    u_max: float  # largest actuator bound [N m or N]
    weight: float  # m g of the whole robot [N]
    coulomb_at: bool  # the families keep a_t <= mu a_n (point mass); Capler keeps the paper's a_t = 3 a_n

    def foot_height(self, q) -> float:
        """Height of the foot above z = 0 at q [m] (Pinocchio's forward kinematics)."""
        import pinocchio as pin

        robot = _robot(self.robot)
        data = robot.model.createData()
        pin.framesForwardKinematics(robot.model, data, np.asarray(q, float))
        return float(data.oMf[robot.frame_id(self.foot)].translation[2])

    def with_gap(self, q, gap: float) -> list[float]:
        """q with the base height moved so that the foot is `gap` above the ground [m]."""
        q = list(map(float, q))
        q[Z] = q[Z] - self.foot_height(q) + self.task.get("ground_height", 0.0) + gap
        return q


_ROBOTS: dict = {}


def _robot(path: str):
    if path not in _ROBOTS:
        from planner.model import load_robot

        _ROBOTS[path] = load_robot(ROOT / path)
    return _ROBOTS[path]


def base_task(name: str) -> Base:
    if name not in BASES:
        raise InputError(f"unknown base robot {name!r}; valid: {', '.join(BASES)}")
    path = BASES[name]
    task = tomllib.loads((ROOT / "robots/capler.toml").read_text()) if name == "capler" else copy.deepcopy(POINT_MASS_TASK)
    robot = _robot(path)
    joints = tuple(a.dof for a in robot.actuators if a.dof not in (X, Z))
    import pinocchio as pin

    weight = float(pin.computeTotalMass(robot.model)) * 9.81
    return Base(name, path, task, task["contacts"][0]["point"], joints, float(np.max(np.abs(robot.u_upper))), weight,
                name == "point_mass")


def _log_uniform(rng, lo: float, hi: float) -> float:
    return float(10 ** rng.uniform(math.log10(lo), math.log10(hi)))


def _target_x(t: dict) -> float:
    return float(t["plan"]["target_q"][X])


def _holes_clear(holes: list[dict], x_start: float, x_end: float, margin: float = 0.05) -> list[dict]:
    """The holes that leave the start and the target outside them (with a margin) [m]."""
    return [h for h in holes if abs(h["x"] - x_start) > h["a"] + margin and abs(h["x"] - x_end) > h["a"] + margin]


def fam_holes(b: Base, t: dict, rng, k: int) -> dict:
    """1-3 holes (Capler; point mass: 1) between start and target: centres moved, widths a in [0.1, 0.4] m,
    depths b in [0.05, 0.2] m (Capler; the point mass: a in [0.03, 0.12], b in [0.02, 0.1])."""
    xe = _target_x(t)
    if b.name == "capler":
        n = int(rng.integers(1, 4))
        centres = sorted(rng.choice([0.5, 1.5, 2.5], size=n, replace=False) + rng.uniform(-0.15, 0.15, size=n))
        holes = [{"x": float(c), "z": 0.0, "a": float(rng.uniform(0.1, 0.4)), "b": float(rng.uniform(0.05, 0.2))} for c in centres]
    else:
        holes = [{"x": float(rng.uniform(0.2, 0.3)), "z": 0.0, "a": float(rng.uniform(0.03, 0.12)), "b": float(rng.uniform(0.02, 0.1))}]
    for h in holes:  # keep the start and the target on solid ground
        h["a"] = float(min(h["a"], abs(h["x"]) - 0.05, abs(xe - h["x"]) - 0.05))
    t["plan"]["holes"] = holes
    return {"holes": holes}


def fam_targets(b: Base, t: dict, rng, k: int) -> dict:
    """Target x in [0.17, 1.33] x the base's, the base up to 0.1 m higher, horizon tau_f x [0.6, 1.6]
    (N kept, so h changes); holes that would cover the new target are dropped."""
    q = list(t["plan"]["target_q"])
    q[X] = _target_x(t) * float(rng.uniform(0.17, 1.33))
    q[Z] = b.with_gap(q, float(rng.uniform(0.0, 0.1)))[Z]
    t["plan"]["target_q"] = q
    t["horizon"]["tau_f"] = float(t["horizon"]["tau_f"] * rng.uniform(0.6, 1.6))
    t["plan"]["holes"] = _holes_clear(t["plan"].get("holes", []), 0.0, q[X])
    return {"target_q": q, "tau_f": t["horizon"]["tau_f"], "n_holes": len(t["plan"]["holes"])}


def _posture(b: Base, t: dict, rng) -> list[float]:
    q = list(map(float, t["initial"]["q"]))
    for j in b.joints:  # joints moved by up to 0.3 rad
        q[j] += float(rng.uniform(-0.3, 0.3))
    return q


def _initial(b: Base, t: dict, q: list[float], v: list[float]) -> None:
    t["initial"] = {"q": q, "v": v}


def fam_init_standing(b: Base, t: dict, rng, k: int) -> dict:
    """Standing: foot exactly on the ground (gap 0), joints moved by up to 0.3 rad, at rest."""
    q = b.with_gap(_posture(b, t, rng), 0.0)
    _initial(b, t, q, [0.0] * len(q))
    return {"gap": 0.0, "q": q}


def fam_init_airborne(b: Base, t: dict, rng, k: int) -> dict:
    """Airborne: foot 0.02-0.3 m up, base velocity in [-1, 1] m/s both ways."""
    gap = float(rng.uniform(0.02, 0.3))
    q = b.with_gap(_posture(b, t, rng), gap)
    v = [0.0] * len(q)
    v[X], v[Z] = float(rng.uniform(-1, 1)), float(rng.uniform(-1, 1))
    _initial(b, t, q, v)
    return {"gap": gap, "v": v}


def fam_init_contact(b: Base, t: dict, rng, k: int) -> dict:
    """Exactly at contact while moving down at 0.2-2 m/s (an impact at tau = 0), sideways up to 0.5 m/s."""
    q = b.with_gap(_posture(b, t, rng), 0.0)
    v = [0.0] * len(q)
    v[X], v[Z] = float(rng.uniform(-0.5, 0.5)), -float(rng.uniform(0.2, 2.0))
    _initial(b, t, q, v)
    return {"gap": 0.0, "v": v}


def fam_init_grazing(b: Base, t: dict, rng, k: int) -> dict:
    """Grazing: foot 1e-9 to 1e-4 m above the ground, sliding along it at 0.2-1 m/s, vertical speed
    within +-1e-6 m/s."""
    gap = _log_uniform(rng, 1e-9, 1e-4)
    q = b.with_gap(_posture(b, t, rng), gap)
    v = [0.0] * len(q)
    v[X], v[Z] = float(rng.uniform(0.2, 1.0)), float(rng.uniform(-1e-6, 1e-6))
    _initial(b, t, q, v)
    return {"gap": gap, "v": v}


def fam_init_penetrating(b: Base, t: dict, rng, k: int) -> dict:
    """Penetrating: foot 0.5e-9 to 1e-9 m below the ground (build_problem accepts down to 1e-9), at rest."""
    gap = -float(rng.uniform(0.5e-9, 1e-9))
    q = b.with_gap(_posture(b, t, rng), gap)
    _initial(b, t, q, [0.0] * len(q))
    return {"gap": gap, "q": q}


def fam_friction(b: Base, t: dict, rng, k: int) -> dict:
    """mu = 0 (the first task of the family) or log-uniform in [1e-3, 20]; the point mass keeps a_t = mu a_n."""
    mu = 0.0 if k == 0 else _log_uniform(rng, 1e-3, 20.0)
    c = t["contacts"][0]
    c["mu"] = mu
    if mu == 0:  # a frictionless contact reads no a_t: any but the default is refused beside mu = 0
        c["a_t"] = Contact.a_t
    elif b.coulomb_at:
        c["a_t"] = mu * c["a_n"]
    return {"mu": mu, "a_t": c.get("a_t", 600.0)}


def fam_gains(b: Base, t: dict, rng, k: int) -> dict:
    """a_n and a_t each scaled by a log-uniform factor in [0.1, 10] (a_t may end below a_n); the point
    mass: a_n likewise, a_t = mu a_n x a log-uniform factor in [0.1, 1] (an impact within the friction cone)."""
    c = t["contacts"][0]
    sn, st = _log_uniform(rng, 0.1, 10.0), _log_uniform(rng, 0.1, 1.0 if b.coulomb_at else 10.0)
    c["a_n"] = c.get("a_n", 200.0) * sn
    c["a_t"] = c["mu"] * c["a_n"] * st if b.coulomb_at else c.get("a_t", 600.0) * st
    return {"a_n_scale": sn, "a_t_scale": st, "a_n": c["a_n"], "a_t": c["a_t"]}


def fam_resolution(b: Base, t: dict, rng, k: int) -> dict:
    """N x a log-uniform factor in [0.5, 2.5] of the base N (of --N when given), at least 5; tau_f kept."""
    factor = _log_uniform(rng, 0.5, 2.5)
    t["horizon"]["N"] = max(5, int(round(t["horizon"]["N"] * factor)))
    return {"N": t["horizon"]["N"], "factor": factor}


def fam_rho_f(b: Base, t: dict, rng, k: int) -> dict:
    """rho_f = 0 (the first task: the plain implicit Euler MPCC) or log-uniform in [1e-2, 1e2]."""
    rho_f = 0.0 if k == 0 else _log_uniform(rng, 1e-2, 1e2)
    t["plan"]["rho_f"] = rho_f
    return {"rho_f": rho_f}


def fam_homotopy(b: Base, t: dict, rng, k: int) -> dict:
    """The task's homotopy: rho0 log-uniform in [1e-2, 1e3], kappa in [2, 100], n_nlp in 1..8 (the solve's
    rho_min / rho_max then drop and extend the schedule, planner.homotopy.task_rho_schedule)."""
    hom = {"rho0": _log_uniform(rng, 1e-2, 1e3), "kappa": _log_uniform(rng, 2.0, 100.0), "n_nlp": int(rng.integers(1, 9))}
    # the base task's other homotopy keys stay (Capler's scale_variables = true was dropped: an unscaled solve too)
    t["plan"]["homotopy"] = {**t["plan"].get("homotopy", {}), **hom}
    return dict(hom)


def fam_torque(b: Base, t: dict, rng, k: int) -> dict:
    """|u| <= u_bound with u_bound = the actuators' bound x a log-uniform factor in [1e-2, 1e2]
    (Capler: 0.6 to 6000 N m)."""
    factor = _log_uniform(rng, 1e-2, 1e2)
    t["plan"]["u_bound"] = b.u_max * factor
    return {"u_bound": t["plan"]["u_bound"], "factor": factor}


def fam_infeasible(b: Base, t: dict, rng, k: int) -> dict:
    """Target out of reach: 20-60 m (Capler; point mass 30-60 m) away in the base horizon; expected to be
    diagnosed, never to converge or crash."""
    q = list(t["plan"]["target_q"])
    q[X] = float(rng.uniform(20.0, 60.0) if b.name == "capler" else rng.uniform(30.0, 60.0))
    t["plan"]["target_q"] = q
    t["plan"]["holes"] = _holes_clear(t["plan"].get("holes", []), 0.0, q[X])
    return {"target_q": q}


FAMILIES = {
    "holes": fam_holes,
    "targets": fam_targets,
    "init_standing": fam_init_standing,
    "init_airborne": fam_init_airborne,
    "init_contact": fam_init_contact,
    "init_grazing": fam_init_grazing,
    "init_penetrating": fam_init_penetrating,
    "friction": fam_friction,
    "gains": fam_gains,
    "resolution": fam_resolution,
    "rho_f": fam_rho_f,
    "homotopy": fam_homotopy,
    "torque": fam_torque,
    "infeasible": fam_infeasible,
}


def _torque_expect(b: Base, t: dict, params: dict) -> str:
    """The point mass at rest on the ground with |u_x|, |u_z| <= U can neither lift off (U < m g) nor
    slide (U <= mu (m g - U), i.e. U <= mu m g / (1 + mu)) below U = mu m g / (1 + mu): the target is
    out of reach. Above it the point may slide (the plan of torque-00, U = 5.3 N, slides and is valid
    in MuJoCo). No claim for Capler, whose forces depend on the posture."""
    mu = t["contacts"][0]["mu"]
    return "infeasible" if b.name == "point_mass" and params["u_bound"] <= mu * b.weight / (1 + mu) else "feasible?"


# what a family's task is expected to be: "infeasible" must be diagnosed; "feasible?" makes no claim
EXPECT = {"infeasible": lambda b, t, params: "infeasible", "torque": _torque_expect}


def generate(seed: int, families=None, per_family: int = 2, robot: str = "capler", N: int | None = None,
             solve_options: dict | None = None) -> list[dict]:
    """The task list of a seed: per_family tasks of each family, each a JSON-able spec with its task
    dict. Deterministic: a family's tasks depend only on (seed, family name, index), not on which other
    families are run."""
    families = list(dict.fromkeys(families or FAMILIES))  # a family named twice ran twice under the same ids
    unknown = [f for f in families if f not in FAMILIES]
    if unknown:
        raise InputError(f"unknown famil{'y' if len(unknown) == 1 else 'ies'} {', '.join(unknown)}; valid: {', '.join(FAMILIES)}")
    if per_family < 1:
        raise InputError(f"--per-family must be >= 1, got {per_family}")
    if N is not None and N < 1:
        raise InputError(f"--N must be >= 1, got {N}")
    if (solve_options or {}).get("max_iter", 1) < 1:
        raise InputError(f"--max-iter must be >= 1, got {solve_options['max_iter']}")
    if seed < 0:  # numpy's generators take seeds >= 0 only
        raise InputError(f"--seed must be >= 0, got {seed}")
    if solve_options:  # before any task runs: a bad value was recorded as every task's crash
        from planner.homotopy import solve_options_from_dict

        solve_options_from_dict(solve_options)
    b = base_task(robot)
    specs = []
    for fam in families:
        rng = np.random.default_rng([seed, zlib.crc32(fam.encode())])
        for k in range(per_family):
            t = copy.deepcopy(b.task)
            if N is not None:
                t["horizon"]["N"] = N
            params = FAMILIES[fam](b, t, rng, k)
            specs.append({"id": f"{fam}-{k:02d}", "family": fam, "index": k, "seed": seed, "robot": b.robot, "base": b.name,
                          "expect": EXPECT.get(fam, lambda b, t, p: "feasible?")(b, t, params), "params": _plain(params), "task": _plain(t),
                          "solve_options": dict(solve_options or {})})
    return specs


# ==================================================================================================
# one task: plan, validate, classify (runs in a worker)
# ==================================================================================================

class NonFinite(Exception):
    """A NaN or Inf in something the pipeline accepted (the stage is set by planner.batch.stage)."""


def _nonfinite(name: str, value) -> str | None:
    """'name: 3 NaN, 1 Inf of 40' when value holds non-finite numbers, else None."""
    a = np.asarray(value, dtype=float)
    n_nan, n_inf = int(np.isnan(a).sum()), int(np.isinf(a).sum())
    return f"{name}: {n_nan} NaN, {n_inf} Inf of {a.size}" if n_nan or n_inf else None


def check_problem(problem) -> list[str]:
    """Non-finite numbers in a built problem: x0, NaN bounds (infinite bounds are allowed), f and g at x0
    (at the first penalty of the homotopy)."""
    import casadi as ca

    found = [_nonfinite("x0", problem.x0), _nonfinite("y0", problem.y0)]
    for name in ("lbx", "ubx", "lbg", "ubg"):
        nan = int(np.isnan(getattr(problem, name)).sum())
        found.append(f"{name}: {nan} NaN" if nan else None)
    fg = ca.Function("fg", [problem.x, problem.p], [problem.f, problem.g])
    f0, g0 = fg(problem.x0, problem.params(problem.task.plan.homotopy.rho0, 1.0))
    found += [_nonfinite("f(x0)", f0), _nonfinite("g(x0)", g0)]
    return [f for f in found if f]


def run_task(spec: dict) -> dict:
    """Plan, validate and classify one generated task; returns its JSON-able record. Exceptions are
    labelled with their stage and left to planner.batch, which makes them a crashed record."""
    from planner.homotopy import solve, solve_options_from_dict
    from planner.problem import build_problem
    from planner.race import default_arms, race
    from planner.replay import validate_plan
    from planner.task import parse_task

    rec = {k: spec[k] for k in ("id", "family", "index", "seed", "base", "expect", "params")}
    rec.update(outcome=None, stage=None, message="", nonfinite=[], times={})
    t0 = time.perf_counter()
    with stage("build"):
        robot = _robot(spec["robot"])
        task = parse_task(spec["task"], source=f"stress:{spec['id']}")
        problem = build_problem(robot, task)
        found = check_problem(problem)
        rec["times"]["build_s"] = time.perf_counter() - t0
        rec["n_x"], rec["n_g"], rec["N"] = int(problem.nx), int(problem.ng), int(problem.N)
        if found:
            rec["nonfinite"] += [{"stage": "build", "what": f} for f in found]
            raise NonFinite("non-finite numbers in the built problem: " + "; ".join(found))

    with stage("solve"):
        options = solve_options_from_dict(spec["solve_options"])

        def progress(nlp):  # each NLP's numbers, as the homotopy goes
            for name in ("objective", "complementarity_residual", "terminal_error"):
                bad = _nonfinite(name, getattr(nlp, name))
                if bad:
                    rec["nonfinite"].append({"stage": nlp.label, "what": bad, "status": nlp.status})

        t1 = time.perf_counter()
        if spec.get("race"):
            result = race(problem, default_arms(options), progress=progress)
            rec["race"] = result.extra.get("race")  # the arms: outcome, iterations, wall [s]
        else:
            result = solve(problem, options, progress=progress)
        rec["times"]["solve_s"] = time.perf_counter() - t1
    st = result.stats
    rec.update(converged=bool(st.converged), message=st.message, n_nlp=st.n_nlp, ipopt_iterations=st.ipopt_iterations,
               complementarity_residual=st.complementarity_residual, terminal_error=result.terminal_error,
               polished=result.polished, nlps=[{"label": r.label, "rho": r.rho, "status": r.status, "iterations": r.iterations,
                                                "time_s": r.time_s} for r in result.nlps],
               hops=len(result.hops), impacts=len(result.trajectory.impacts))

    with stage("recovery"):
        found = [f for f in (_nonfinite("solution x", result.extra.get("_x", [])),
                             *(_nonfinite(k, getattr(result.trajectory, k)) for k in ("tau", "y", "sigma", "t", "q", "v", "u")),
                             _nonfinite("impact_times", result.trajectory.impact_times)) if f]
        rec["nonfinite"] += [{"stage": "recovery", "what": f} for f in found]
        if found and st.converged:
            raise NonFinite("the solve says converged but its result holds " + "; ".join(found))

    if not st.converged:
        if not st.message:
            with stage("solve"):
                raise RuntimeError("the solve did not converge and gave no diagnosis (empty message)")
        rec["outcome"] = DIAGNOSED
        rec["times"]["total_s"] = time.perf_counter() - t0
        return rec

    with stage("validation"):
        t2 = time.perf_counter()
        val = validate_plan(robot, task, result.trajectory)
        rec["times"]["validation_s"] = time.perf_counter() - t2
        numbers = {"max_tracking_error_m": val.max_tracking_error_m, "final_tracking_error_m": val.final_tracking_error_m,
                   "max_penetration_m": val.max_penetration_m}
        found = [f for f in (_nonfinite(k, v) for k, v in numbers.items()) if f]
        rec["nonfinite"] += [{"stage": "validation", "what": f} for f in found]
        # the windows (restarted from the plan, docs/validation.md) are information, as in `planner validate`
        w = val.windows
        rec["validation"] = {**numbers, "passed": bool(val.passed), "failures": list(val.failures),
                             "window_mean_m": w.mean_m, "window_worst_m": w.worst_m,
                             "window_impacts_landed": [w.landed, len(w.impacts)],
                             "window_impact_time_error_s": w.max_abs_impact_time_difference_s}
        if found and val.passed:
            raise NonFinite("the validation passed with " + "; ".join(found))
    rec["outcome"] = CONVERGED_VALID if val.passed else CONVERGED_INVALID
    if not val.passed:
        rec["message"] = "; ".join(val.failures) or "validation failed"
    rec["times"]["total_s"] = time.perf_counter() - t0
    return rec


def finish(spec: dict, result) -> dict:
    """The record of a task from run_batch's result: a crash becomes outcome "crashed" with its stage."""
    if isinstance(result, Crashed):
        rec = {k: spec[k] for k in ("id", "family", "index", "seed", "base", "expect", "params")}
        rec.update(outcome=CRASHED, stage=result.stage, message=result.error, traceback=result.traceback, nonfinite=[])
        if result.error.startswith("NonFinite"):
            rec["nonfinite"] = [{"stage": result.stage, "what": result.error}]
    else:
        rec = result
    rec["unexpected"] = rec["expect"] == "infeasible" and rec["outcome"] != DIAGNOSED
    rec["task"] = spec["task"]
    assert rec["outcome"] in OUTCOMES, rec["outcome"]
    return rec


# ==================================================================================================
# summary and files
# ==================================================================================================

def summarize(records: list[dict]) -> dict:
    """Counts per outcome, per family, tasks with NaN/Inf seen (by stage), unexpected outcomes."""
    def counts(recs):
        c = {o: sum(r["outcome"] == o for r in recs) for o in OUTCOMES}
        c["tasks"] = len(recs)
        c["nonfinite"] = sum(bool(r["nonfinite"]) for r in recs)
        c["unexpected"] = sum(bool(r.get("unexpected")) for r in recs)
        times = [r["times"]["total_s"] for r in recs if r.get("times", {}).get("total_s") is not None]
        c["median_time_s"] = float(np.median(times)) if times else None
        return c

    families = list(dict.fromkeys(r["family"] for r in records))
    stages = {}
    for r in records:
        for f in r["nonfinite"]:
            stages[f["stage"]] = stages.get(f["stage"], 0) + 1
    feasible = [r for r in records if r["expect"] != "infeasible"]
    infeasible = [r for r in records if r["expect"] == "infeasible"]
    rates = {"feasible": len(feasible), "feasible_valid": sum(r["outcome"] == CONVERGED_VALID for r in feasible),
             "infeasible": len(infeasible), "infeasible_diagnosed": sum(r["outcome"] == DIAGNOSED for r in infeasible)}
    rates["feasible_valid_pct"] = 100.0 * rates["feasible_valid"] / len(feasible) if feasible else None
    return {"total": counts(records), "families": {f: counts([r for r in records if r["family"] == f]) for f in families},
            "rates": rates,
            "nonfinite_by_stage": stages,
            "crashed": [{"id": r["id"], "stage": r["stage"], "error": r["message"]} for r in records if r["outcome"] == CRASHED]}


def _windows_cell(rec: dict) -> str:
    """A validated record's windowed MuJoCo numbers (run_task's "validation"), else empty."""
    v = rec.get("validation") or {}
    if v.get("window_mean_m") is None:
        return ""
    landed, planned = v["window_impacts_landed"]
    dt = v["window_impact_time_error_s"]
    return (f"{v['window_mean_m'] * 1e3:.1f} / {v['window_worst_m'] * 1e3:.1f}, {landed} of {planned}"
            + ("" if dt is None else f", {dt * 1e3:.1f}"))


def markdown(summary: dict, records: list[dict], header: str) -> str:
    cols = ("tasks", CONVERGED_VALID, CONVERGED_INVALID, DIAGNOSED, CRASHED, "nonfinite", "unexpected", "median_time_s")
    names = ("tasks", "converged, valid", "converged, invalid in MuJoCo", "not converged, diagnosed", "crashed",
             "NaN/Inf seen", "unexpected", "median time [s]")
    lines = [header, "", "| family | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]

    def row(name, c):
        cells = [str(c[k]) for k in cols[:-1]] + ["" if c["median_time_s"] is None else f"{c['median_time_s']:.1f}"]
        return f"| {name} | " + " | ".join(cells) + " |"

    lines += [row(f, c) for f, c in summary["families"].items()] + [row("**all**", summary["total"])]
    r = summary["rates"]
    pct = "" if r["feasible_valid_pct"] is None else f" ({r['feasible_valid_pct']:.1f} %)"
    lines += ["", f"Feasible tasks (all but the expected infeasible): {r['feasible_valid']} of {r['feasible']} converged and "
              f"valid{pct}; expected infeasible: {r['infeasible_diagnosed']} of {r['infeasible']} diagnosed."]
    lines += ["", "| task | outcome | stage | message | MuJoCo windows: mean / worst [mm], impacts landed, worst \\|Δt\\| [ms] |",
              "|---|---|---|---|---|"]
    for r in records:
        if r["outcome"] != CONVERGED_VALID:
            msg = (r.get("message") or "").replace("|", "\\|").replace("\n", " ")
            expect = " (expected infeasible)" if r["expect"] == "infeasible" else ""
            lines.append(f"| {r['id']} | {r['outcome']}{expect} | {r.get('stage') or ''} | {msg[:200]} | {_windows_cell(r)} |")
    if summary["nonfinite_by_stage"]:
        lines += ["", "NaN/Inf seen, by stage: " + ", ".join(f"{k} {v}" for k, v in summary["nonfinite_by_stage"].items())]
    return "\n".join(lines) + "\n"


def machine_info() -> dict:
    """The shared machine record (scripts._report.machine_info) with the solver's and the replay's library versions."""
    import mujoco
    import pinocchio

    return {**shared_machine_info(), "pinocchio": pinocchio.__version__, "mujoco": mujoco.__version__}


def _plain(obj):
    """obj with numpy scalars and arrays as Python numbers and lists (JSON and pickle friendly)."""
    if isinstance(obj, dict):
        return {k: _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _plain(obj.tolist())
    if isinstance(obj, np.floating):
        return float(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def _strict(obj):
    """_plain, with non-finite floats as the strings "nan", "inf", "-inf" (strict JSON, nothing hidden)."""
    obj = _plain(obj)
    if isinstance(obj, dict):
        return {k: _strict(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_strict(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return str(obj)
    return obj


def main(argv: list[str] | None = None) -> int:
    parser = script_parser(__doc__)
    parser.add_argument("--robot", choices=sorted(BASES), default="capler", help="base task (default capler)")
    parser.add_argument("--families", nargs="+", metavar="F", help=f"families to run (default all: {', '.join(FAMILIES)})")
    parser.add_argument("--per-family", type=int, default=2, help="tasks per family (default 2)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the task generator (default 0)")
    parser.add_argument("--N", type=int, help="override the base task's N (quick runs); the resolution family scales it")
    parser.add_argument("--max-iter", type=int, help="IPOPT iterations per NLP (default: SolveOptions')")
    parser.add_argument("--rho-schedule", type=float, nargs="+", metavar="RHO", help="the homotopy's penalties (default: SolveOptions')")
    parser.add_argument("--race", action="store_true",
                        help="solve each task as `planner plan` does: the race of two solver variants, two CPUs per task")
    parser.add_argument("--scheduler", help="address of a Dask distributed scheduler (default: local processes)")
    parser.add_argument("--workers", type=int,
                        help="local worker processes (default: cpu count, with --race half of it; 0 = in this process)")
    parser.add_argument("--out", type=out_dir, default=DEFAULT_OUT, help=f"output directory (default {DEFAULT_OUT})")
    parser.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    parser.add_argument("--list", action="store_true", help="print the generated tasks (JSON lines) and exit")
    args = parser.parse_args(argv)
    if args.scheduler is not None and args.workers is not None:  # (ignored, and written to results.json as used)
        parser.error("--workers sets the local processes; a Dask --scheduler has its own workers")
    if args.workers is not None and args.workers < 0:  # before OUT is touched, and beside --list too
        parser.error(f"--workers must be >= 0, got {args.workers}")

    overrides = {k: v for k, v in (("max_iter", args.max_iter), ("rho_schedule", args.rho_schedule)) if v is not None}
    try:
        specs = generate(args.seed, args.families, args.per_family, args.robot, args.N, overrides)
    except InputError as exc:
        print(f"stress: error: {exc}", file=sys.stderr)
        return 2
    if args.rho_schedule is not None and any(spec["family"] == "homotopy" for spec in specs):
        # (the solve reads rho_schedule, never the task's homotopy: the family's tasks all ran one schedule, their
        # records still listing the rho0, kappa and n_nlp drawn)
        parser.error("--rho-schedule replaces the task's homotopy, which the homotopy family varies: leave that family "
                     "out (--families ...) or the schedule")
    for spec in specs:
        spec["race"] = args.race
    if args.list:  # the run's own arguments were ignored beside it (--race only marked the tasks printed)
        refuse_beside(parser, args, ["race", "scheduler", "workers", "out", "json"],
                      "--list prints the tasks and exits")
        for s in specs:
            print(json.dumps(_strict(s)))
        return 0

    # one line per finished task, so a stopped run keeps what it did; records.jsonl once the run is done (a stopped
    # run emptied it beside the previous run's results.json). Made by the first finished task: a refused --scheduler
    # (dask missing, unreachable) left OUT with an empty one
    partial = args.out / "records.partial.jsonl"
    logged = []

    def log(i, result):
        rec = finish(specs[i], result)
        if not logged:
            args.out.mkdir(parents=True, exist_ok=True)
        with partial.open("a" if logged else "w") as f:
            f.write(json.dumps(_strict(rec), allow_nan=False) + "\n")
        logged.append(i)
        where = f" at {rec['stage']}" if rec["outcome"] == CRASHED else ""
        print(f"{rec['id']:<20} {rec['outcome']}{where}  {(rec.get('message') or '')[:120]}", file=sys.stderr, flush=True)

    command = "python -m scripts.stress " + shlex.join(argv if argv is not None else sys.argv[1:])
    workers = args.workers
    if workers is None and args.race and args.scheduler is None:
        workers = max(1, usable_cpus() // 2)  # each task's race takes two CPUs
    elif workers is None and args.scheduler is None:  # run_batch's own default, resolved (results.json said null)
        workers = max(1, default_workers(len(specs)))
    start = time.perf_counter()
    try:
        raw = run_batch(run_task, specs, scheduler=args.scheduler, workers=workers, progress=log)
    except InputError as exc:
        print(f"stress: error: {exc}", file=sys.stderr)
        return 2
    records = [finish(s, r) for s, r in zip(specs, raw)]
    summary = summarize(records)
    wall = time.perf_counter() - start
    machine = machine_info()
    results = {"command": command, "seed": args.seed, "robot": args.robot, "per_family": args.per_family, "N": args.N,
               "solve_options": overrides, "race": args.race, "scheduler": args.scheduler, "workers": workers, "total_wall_time_s": wall,
               "machine": machine, "summary": summary, "records": records, "run": run_info()}
    write_atomically(args.out / "results.json", json.dumps(_strict(results), indent=1, allow_nan=False) + "\n")
    os.replace(partial, args.out / "records.jsonl")
    header = (f"Stress run `{command}` on {machine['date'][:10]}: {len(records)} tasks, base {args.robot}, seed {args.seed}, "
              f"{wall:.0f} s wall")
    write_atomically(args.out / "summary.md", markdown(summary, records, header))
    out = {"results": str(args.out / "results.json"), "summary_md": str(args.out / "summary.md"), "n_tasks": len(records),
           "total_wall_time_s": wall, **summary}
    if args.json:
        print(json.dumps(_strict(out), indent=1))
    else:
        print(markdown(summary, records, header))
    return 1 if summary["total"][CRASHED] else 0


if __name__ == "__main__":
    sys.exit(run_main(main))
