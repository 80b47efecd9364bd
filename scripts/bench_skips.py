"""Benchmark of the scene analysis (issue 9, "skip what a scene does not need"): each skip on and off.

For each case, the same task is built with ProblemOptions(scene_analysis=True) (the skip applies)
and scene_analysis=False (everything built), both solved with the default SolveOptions, one after the
other in this process. Per variant: variables, constraints, complementarity pairs, Jacobian nonzeros,
IPOPT iterations, build and solve wall time, convergence, complementarity, control cost. Per case:
the difference of the two solutions, max |y_on - y_off| over the nodes (q, v, clock; both variants
have the same grid and state layout) and max |q_on - q_off| in physical time (q interpolated on a
common grid over the shorter physical horizon) [m, rad, m/s, s].

Cases (planner.scene):

* frictionless: point mass (mu = 0) dropped from 0.2 m, pushed to x = 0.5 m: the tangential switch,
  jump field and pairs are dropped.
* never_touching: Capler with contacts foot and knee, the knee marked touches = false: one contact
  instead of two (with the analysis off the knee is a full contact of the several-contacts rule).
* dropped_holes: the point-mass hop to x = 0.5 m with x bounded to [-0.1, 0.6] m, one hole in reach
  (x = 0.25 m) and two beyond it (x = 1.5, 2.5 m): the two are dropped.
* elastic_state: not a case: no elastic state is built for inelastic scenes and the OCP refuses
  elastic contacts (planner.scene).

    python -m scripts.bench_skips [--quick] [--cases NAME ...] [--out DIR] [--json]   (repository root)

--quick (the CI smoke run) uses N = 6 steps and a short horizon. Wall times depend on the machine's load.
"""
from __future__ import annotations

import math
import os
import shlex
import sys
import time
from pathlib import Path

import casadi as ca
import numpy as np

from planner.cli import prepare_out_dir
from planner.dynamics import Dynamics
from planner.homotopy import solve
from planner.model import load_robot
from planner.problem import ProblemOptions, build_problem
from planner.task import load_task, parse_task
from scripts._report import out_dir, report, run_main, script_parser

DEFAULT_OUT = Path("results/bench/skips")
GRID_POINTS = 401  # common physical-time grid of the q comparison
CROUCH = 0.3  # hip angle [rad] of the never_touching case's start and target (knee -2 CROUCH)


def frictionless_case(quick: bool):
    N = 6 if quick else 20
    task = parse_task({"contacts": [{"point": "point", "mu": 0.0}], "initial": {"q": [0.0, 0.2]},
                       "horizon": {"tau_f": 1.0, "N": N}, "plan": {"target_q": [0.5, 0.0], "u_bound": 30.0}})
    return load_robot("point_mass"), task


def never_touching_case(quick: bool):
    base = load_task(Path(__file__).resolve().parents[1] / "robots" / "capler.toml")
    N, tau_f = (6, 0.3) if quick else (20, 1.0)
    foot = {"point": "foot", "mu": 0.8}
    plan = {"target_q": [0.1 if quick else 0.4, 0.4, 0.0, 0.0], "above_ground": ["base"],
            "joint_bounds": [{"joint": b.joint, "lower": b.lower, "upper": b.upper} for b in base.plan.joint_bounds]}
    # crouched, foot on the ground: standing straight, foot and knee have the same normal row, and the
    # several-contacts guess of the unskipped problem (both points on the ground) is then singular
    q0 = [0.0, 0.4 * math.cos(CROUCH), CROUCH, -2 * CROUCH]
    plan["target_q"] = [plan["target_q"][0]] + q0[1:]
    task = parse_task({"contacts": [foot, {"point": "knee", "mu": 0.8, "touches": False}], "initial": {"q": q0},
                       "horizon": {"tau_f": tau_f, "N": N}, "plan": plan})
    return load_robot("capler"), task


def dropped_holes_case(quick: bool):
    N = 6 if quick else 20
    holes = [{"x": 0.25, "z": 0.0, "a": 0.05, "b": 0.05}, {"x": 1.5, "z": 0.0, "a": 0.25, "b": 0.1}, {"x": 2.5, "z": 0.0, "a": 0.25, "b": 0.1}]
    task = parse_task({"contacts": [{"point": "point", "mu": 0.5}], "initial": {"q": [0.0, 0.0]}, "horizon": {"tau_f": 1.0, "N": N},
                       "plan": {"target_q": [0.5, 0.0], "u_bound": 30.0, "holes": holes,
                                "joint_bounds": [{"joint": "x", "lower": -0.1, "upper": 0.6}]}})
    return load_robot("point_mass"), task


CASES = {"frictionless": frictionless_case, "never_touching": never_touching_case, "dropped_holes": dropped_holes_case}


def variant(robot, task, dyn, analysis: bool) -> tuple[dict, object, object]:
    """Build and solve one variant: (record, problem, result)."""
    t0 = time.perf_counter()
    prob = build_problem(robot, task, ProblemOptions(scene_analysis=analysis), dynamics=dyn)
    build_s = time.perf_counter() - t0
    res = solve(prob)
    rec = {"scene_analysis": analysis, "n_variables": prob.nx, "n_constraints": prob.ng, "n_pairs": len(prob.pairs),
           "n_selectors": prob.system.n_sigma, "jacobian_nnz": int(ca.jacobian(prob.g, prob.x).nnz()),
           "g_blocks": {k: list(v.shape) for k, v in prob.g_blocks.items()}, "build_s": build_s,
           "solve_s": res.stats.solve_time_s, "wall_s": build_s + res.stats.solve_time_s,
           "ipopt_iterations": res.stats.ipopt_iterations, "n_nlp": res.stats.n_nlp, "converged": res.stats.converged,
           "complementarity": res.stats.complementarity_residual, "terminal_error": res.terminal_error,
           "control_cost": res.extra["control_cost"], "impacts": len(res.trajectory.impacts), "scene": prob.skips.to_json(),
           # where each contact point went (lowest, highest z [m] over the physical samples): whether a skipped point touched
           "point_z_range": {c.point: _z_range(dyn, c.point, res.trajectory.q) for c in task.contacts},
           "message": res.stats.message}
    return rec, prob, res


def _z_range(dyn, point: str, q: np.ndarray) -> list[float]:
    """[lowest, highest] height z [m] of `point` over the configurations q (P, nq)."""
    z = np.asarray(dyn.point_position(point).map(len(q))(np.asarray(q).T))[2]
    return [float(z.min()), float(z.max())]


def solution_difference(a, b) -> dict:
    """Node states max |y_a - y_b| (same grid and layout) and physical-time max |q_a - q_b| on a common grid."""
    ya, yb = a.trajectory.y, b.trajectory.y
    out = {"max_node_state_diff": float(np.max(np.abs(ya - yb))) if ya.shape == yb.shape else None}
    T = min(a.trajectory.t[-1], b.trajectory.t[-1])
    grid = np.linspace(0.0, T, GRID_POINTS)

    def sample(tr):
        return np.column_stack([np.interp(grid, tr.t, tr.q[:, j]) for j in range(tr.q.shape[1])])

    out["max_physical_q_diff"] = float(np.max(np.abs(sample(a.trajectory) - sample(b.trajectory))))
    out["physical_horizon_s"] = [float(a.trajectory.t[-1]), float(b.trajectory.t[-1])]
    return out


def run(names, quick: bool, log) -> list[dict]:
    records = []
    for name in names:
        robot, task = CASES[name](quick)
        dyn = Dynamics(robot)  # built once per case: it belongs to the robot, not to a variant
        on, _, res_on = variant(robot, task, dyn, True)
        log(name, on)
        off, _, res_off = variant(robot, task, dyn, False)
        log(name, off)
        rec = {"case": name, "N": task.horizon.N, "h": task.horizon.h, "on": on, "off": off, **solution_difference(res_on, res_off)}
        records.append(rec)
    return records


def table(records) -> str:
    lines = ["| skip | analysis | variables | constraints | pairs | Jacobian nnz | IPOPT it. | wall [s] | converged | max node diff | max q diff (physical) |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in records:
        for key in ("on", "off"):
            v = r[key]
            diff = (f"{r['max_node_state_diff']:.1e}" if r["max_node_state_diff"] is not None else "—", f"{r['max_physical_q_diff']:.1e}") if key == "on" else ("", "")
            lines.append(f"| {r['case']} | {key} | {v['n_variables']} | {v['n_constraints']} | {v['n_pairs']} | {v['jacobian_nnz']} | "
                         f"{v['ipopt_iterations']} | {v['wall_s']:.2f} | {v['converged']} | {diff[0]} | {diff[1]} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = script_parser(__doc__)
    parser.add_argument("--out", type=out_dir, default=DEFAULT_OUT, help=f"output directory (default {DEFAULT_OUT})")
    parser.add_argument("--quick", action="store_true", help="CI smoke run: N = 6, short horizons")
    parser.add_argument("--cases", nargs="+", choices=sorted(CASES), help="run only these cases (default: all)")
    parser.add_argument("--json", action="store_true", help="print results.json on stdout instead of the table")
    args = parser.parse_args(argv)
    prepare_out_dir(args.out)  # before the runs: an --out that is a file was refused only after them

    def log(name, rec):  # progress on stderr: stdout keeps the table or the JSON
        print(f"{name:<15} analysis {'on ' if rec['scene_analysis'] else 'off'}  nx {rec['n_variables']:6d}  ng {rec['n_constraints']:6d}  "
              f"pairs {rec['n_pairs']:5d}  {rec['ipopt_iterations']:6d} it  {rec['wall_s']:7.2f} s  "
              f"{'converged' if rec['converged'] else 'NOT converged: ' + rec['message']}", file=sys.stderr, flush=True)

    start = time.perf_counter()
    records = run(list(dict.fromkeys(args.cases or CASES)), args.quick, log)  # a case named twice ran twice
    results = {"command": "python -m scripts.bench_skips " + shlex.join(argv if argv is not None else sys.argv[1:]),
               "quick": args.quick, "total_wall_time_s": time.perf_counter() - start, "cpu_count": os.cpu_count(),
               "omp_num_threads": os.environ.get("OMP_NUM_THREADS"), "load_average": os.getloadavg(), "records": records}
    return report(args.out, results, table(records), args.json)


if __name__ == "__main__":
    sys.exit(run_main(main))
