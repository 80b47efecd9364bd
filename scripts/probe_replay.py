"""Does the time-freezing simulator reproduce a plan from the plan's own controls? (issue 9, session 31)

The route to the speed goal that docs/solve-research.md names starts the OCP from a motion built by stepping the
time-freezing dynamics (a rollout), so it matters whether a rollout can follow a plan at all. This probe replays a
Capler plan (a `planner plan` result directory) on its own grid: step k is solved by the simulator's step NLP
(`planner.simulate`'s penalty homotopy, as scripts/probe_multiphase.py's pd start) from the rollout's state with the
plan's control U_k plus a joint PD towards the plan's next state (hip and knee; at the plan's own states the PD adds
nothing, so the plan is a solution of every step). Reported: the first step where the rollout leaves the plan (state
difference above DEPARTURE_TOL), the plan's and the rollout's selectors (alpha, beta, gamma, zeta) there, how well the plan's
own step solves the simulator's step NLP there (largest equality row, smallest complementarity row), and where the
rollout ends against the plan. --plan-first starts each step's solve at the plan's own solution; --liftoff-first at a
free-flight prediction (explicit Euler under gravity, selectors guessed there), a branch rule that needs no plan;
--first-rho0 R starts either one's penalty homotopy at R.

    python -m scripts.probe_replay DIR              # DIR: e.g. `planner plan capler --out DIR`
    python -m scripts.probe_replay DIR --plan-first [--first-rho0 1e4]
    python -m scripts.probe_replay DIR --liftoff-first --first-rho0 1e4
Writes OUT/results.json.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import casadi as ca
import numpy as np

from planner.model import load_robot
from planner.problem import build_problem
from planner.result import locate_input, read_start, read_summary, read_trajectory
from planner.simulate import _penalized_nlp
from planner.task import parse_task
from scripts import probe_multiphase as pm
from scripts._report import report

ROOT = Path(__file__).resolve().parent.parent
DEPARTURE_TOL = 1e-3  # [m, rad, m/s, rad/s] the simulator's steps meet IPOPT's tol; 1e-3 is a different branch, not round-off
BASE_Z, GRAVITY = 1, 9.81  # Capler's base height in q [m] and gravity [m/s^2] (robots/capler.xml)


def plan_problem(out_dir: Path):
    """(problem, x) of the plan in out_dir: the task as kept in its trajectory.npz, the robot its summary.json names."""
    arrays = read_trajectory(out_dir, ("task_json",))
    task = parse_task(json.loads(str(arrays["task_json"])), source=f"{out_dir}/trajectory.npz")
    robot = load_robot(locate_input(read_summary(out_dir)["robot"], out_dir, "robot"))
    problem = build_problem(robot, task)
    return problem, read_start(out_dir, problem.signature, problem.nx)


def step_residual(problem, k: int, Y: np.ndarray, W: np.ndarray, U: np.ndarray) -> dict:
    """The plan's step k (Y (N + 1, ny), W (N, nw), U (N, nu)) in the simulator's step NLP (controls U_k, no PD):
    the largest equality row and the smallest complementarity row (>= 0 when its pairs are complementary)."""
    ny = problem.system.ny
    y_k, y_next = ca.SX.sym("y_k", ny), ca.SX.sym("y_next", ny)
    step = problem.builder.build(y_k, y_next, ca.DM(U[k]), 1.0, problem.h)
    nlp, _, n_eq, _ = _penalized_nlp(ca.vertcat(y_next, step.w), [step], y_k)
    g = np.asarray(ca.Function("g", [nlp["x"], nlp["p"]], [nlp["g"]])(np.concatenate([Y[k + 1], W[k], [0.0]]),
                                                                       np.concatenate([Y[k], [1.0]]))).ravel()
    return {"equality_max": float(np.max(np.abs(g[:n_eq]))), "complementarity_min": float(np.min(g[n_eq:]))}


def replay(problem, x_plan: np.ndarray, kp: float, kd: float, plan_first: bool, tol: float = DEPARTURE_TOL,
           first_rho0: float | None = None, liftoff_first: bool = False) -> dict:
    """The record of the module docstring for the plan x_plan (nx,) of problem; first_rho0: the penalty the
    plan-first or lift-off-first start's homotopy begins with (None: the simulator's)."""
    if plan_first and liftoff_first:
        raise ValueError("plan_first and liftoff_first are two rules for the same first start: choose one")
    nq, nv, system, builder = problem.system.nq, problem.system.nv, problem.system, problem.builder
    plan = problem.split(x_plan)
    Y, U, W = plan["Y"], plan["U"], plan["W"]

    def at(k, clock):
        return U[k], Y[k + 1, :nq], Y[k + 1, nq : nq + nv]

    def plan_start(k, y_k, u_ff):  # the plan's own solution of step k
        return np.concatenate([Y[k + 1], W[k], [0.0]])

    def liftoff_start(k, y_k, u_ff):
        # free flight for one step, explicit: the base falls, the joints keep their speed. Not the simulator's restart
        # predictor (planner.simulate._predictor, the implicit-Euler step with every selector 1): from its prediction
        # the main job's replay still stays on the ground at step 26 (measured, --first-rho0 1e4: 0.43 m short)
        y = y_k.copy()
        y[nq + BASE_Z] -= GRAVITY * problem.h
        y[:nq] += problem.h * y[nq : nq + nv]
        y[-1] += problem.h
        return np.concatenate([y, builder.guess(y, u_ff), [0.0]])

    first = plan_start if plan_first else liftoff_start if liftoff_first else None
    x, info = pm.stepwise_start(problem, None, "pd", kp=(kp, kp), kd=(kd, kd), at=at, first=first, first_rho0=first_rho0)
    rollout = problem.split(x)
    Yr, Wr = rollout["Y"], rollout["W"]
    dev = np.max(np.abs(Yr[:, : nq + nv] - Y[:, : nq + nv]), axis=1)  # per node
    rec = {"N": problem.N, "kp": kp, "kd": kd, "plan_first": plan_first, "liftoff_first": liftoff_first, "first_rho0": first_rho0, "tol": tol,
           "steps_failed": info["steps_failed"], "max_deviation": float(dev.max()),
           "end_base_error_m": (Yr[-1, :2] - Y[-1, :2]).tolist(), "departure": None}
    if dev.max() > tol:
        k = int(np.argmax(dev > tol)) - 1  # the step whose end state left the plan
        n_sel = system.n_sigma
        rec["departure"] = {"step": k, "clock_s": float(Y[k, -1]), "deviation": float(dev[k + 1]),
                            "plan_selectors": W[k, :n_sel].tolist(), "rollout_selectors": Wr[k, :n_sel].tolist(),
                            "plan_step_in_simulator": step_residual(problem, k, Y, W, U)}
    return rec


def table(rec: dict) -> str:
    lines = [f"replay of {rec.get('plan', 'the plan')} (N = {rec['N']}, PD kp {rec['kp']:g} kd {rec['kd']:g}, plan first: "
             f"{rec['plan_first']}, lift-off first: {rec['liftoff_first']}): {rec['steps_failed']} steps failed, largest deviation {rec['max_deviation']:.3g}, "
             f"end base error {np.round(rec['end_base_error_m'], 4).tolist()} m"]
    d = rec["departure"]
    if d is None:
        lines.append(f"  the rollout stays within {rec['tol']:g} of the plan")
    else:
        r = d["plan_step_in_simulator"]
        lines += [f"  leaves the plan at step {d['step']} (clock {d['clock_s']:.4f} s, deviation {d['deviation']:.3g})",
                  f"  selectors there: plan {np.round(d['plan_selectors'], 3).tolist()}, rollout {np.round(d['rollout_selectors'], 3).tolist()}",
                  f"  the plan's step in the simulator's NLP: equality rows {r['equality_max']:.1e}, complementarity rows >= {r['complementarity_min']:.1e}"]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("plan", type=Path, help="a `planner plan` result directory of Capler (hip and knee PD)")
    parser.add_argument("--kp", type=float, default=200.0, help="joint PD stiffness [N m/rad]")
    parser.add_argument("--kd", type=float, default=5.0, help="joint PD damping [N m s/rad]")
    parser.add_argument("--plan-first", action="store_true", help="start each step's solve at the plan's own solution")
    parser.add_argument("--liftoff-first", action="store_true", help="start each step's solve at a free-flight prediction")
    parser.add_argument("--first-rho0", type=float, help="with --plan-first or --liftoff-first: the penalty that start's homotopy "
                        "begins with (default the simulator's; 1e4 keeps the start's branch where a weak penalty lets the regularizer move it)")
    parser.add_argument("--out", type=Path, default=ROOT / "results" / "bench" / "probe_replay")
    parser.add_argument("--json", action="store_true", help="print the record as JSON instead of the table")
    args = parser.parse_args(argv)
    if args.plan_first and args.liftoff_first:
        parser.error("--plan-first and --liftoff-first are two rules for the same first start: choose one")
    if args.first_rho0 is not None and (not (args.plan_first or args.liftoff_first) or args.first_rho0 <= 0):
        parser.error("--first-rho0 needs --plan-first or --liftoff-first and a value > 0")
    problem, x = plan_problem(args.plan)
    rec = {"plan": str(args.plan), **replay(problem, x, args.kp, args.kd, args.plan_first, first_rho0=args.first_rho0,
                                                liftoff_first=args.liftoff_first)}
    return report(args.out, rec, table(rec), args.json)


if __name__ == "__main__":
    sys.exit(main())
