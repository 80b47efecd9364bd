"""Smoothed selectors instead of complementarity: does a smooth NLP find the Capler motion? (issue 9)

Every selector of the default Capler OCP (`build_problem`) becomes a function of its switching function,
sigma = 1 / (1 + exp(-h / eps)): the stationarity rows are rewritten so, the multipliers lambda0, lambda1 and
the l_inf slack are fixed at 0 and the selector regularizer rho_f ||sigma - sigma*||^2 is left out. The NLP is
then smooth and no selector can cheat (levitate, push for free), at the price of a soft contact of width eps.
The widths are per switching function (EPS [m/s, m, m/s^2, m/s]) times a scale; one IPOPT solve per scale of
--eps-scales, each from the last. Per NLP: IPOPT iterations and status, control cost int u^2 dtau, terminal
error [m, m/s], the base's final x [m] (the target is 3 m), wall time [s]. Writes OUT/results.json.

    python -m scripts.probe_smoothing [--start paper|line|nlp1] [--terminal-weight W] [--no-holes] [--eps-scales 10 3 1]
    python -m scripts.probe_smoothing --quick --json     # CI smoke run: N = 6, two scales, 10 iterations each

Starts: `paper` the hint-free start (y_0 at every node), `line` the base's x on a straight line to the target at
its mean speed with a running clock, `nlp1` the homotopy's NLP 1 point (rho = 100, the levitating cheat).
--terminal-weight W > 0 puts W ||terminal residual||^2 in the objective instead of the hard terminal rows.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import casadi as ca
import numpy as np

from planner.homotopy import SolveOptions, _Solvers, _terminal_rows, ipopt_options, terminal_error
from planner.problem import build_problem
from scripts.bench_pipeline import capler_case, nlp1_arguments
from scripts._report import (nonnegative_float, out_dir, positive_float, refuse_with_quick, report, run_main,
                             script_parser)

# smoothing width per switching function at scale 1: a tenth of Capler's speeds, a centimetre of gap, and for phi
# (the normal acceleration, 100-1000x n^T v on Capler) 5 m/s^2
EPS = {"n^T v": 0.1, "c(q)": 0.01, "phi": 5.0, "t^T v": 0.1}


def smoothed_nlp(problem) -> dict:
    """The problem's NLP {x, p, f, g} with sigma = logistic(h / eps) in place of the stationarity rows; p = (problem.p,
    eps (n_sigma,)). The multipliers stay variables (bound to 0 by `smoothed_bounds`)."""
    x = problem.x
    lam = ca.vertcat(x[problem.var_blocks["lambda0"].ravel()], x[problem.var_blocks["lambda1"].ravel()])
    rows = problem.g_blocks["stationarity"].ravel()
    h = ca.substitute(problem.g[rows], lam, ca.DM.zeros(lam.shape[0]))  # h / switch_scale, row by row
    eps = ca.SX.sym("eps", problem.system.n_sigma)
    g = ca.SX(problem.g)
    g[rows] = x[problem.var_blocks["sigma"].ravel()] - 0.5 * (1 + ca.tanh(h / (2 * ca.repmat(eps, problem.N, 1))))
    f = problem.f - problem.objective_parts["selectors"](x, problem.p)
    return {"x": x, "p": ca.vertcat(problem.p, eps), "f": f, "g": g}


def smoothed_bounds(problem, start: np.ndarray):
    """(x0, lbx, ubx): the multipliers and the l_inf slack fixed at 0, start's other variables as they are."""
    fixed = np.concatenate([problem.var_blocks["lambda0"].ravel(), problem.var_blocks["lambda1"].ravel(),
                            problem.var_blocks.get("s_c", np.zeros(0, int)).ravel()])
    x0, lbx, ubx = start.copy(), problem.lbx.copy(), problem.ubx.copy()
    x0[fixed] = lbx[fixed] = ubx[fixed] = 0.0
    return x0, lbx, ubx


def start_point(problem, kind: str) -> np.ndarray:
    """The start `kind` (paper, line, nlp1; see the module docstring) as an NLP point (nx,)."""
    x = problem.x0.copy()
    if kind == "line":
        Y = problem.var_blocks["y"]
        target, tau_f = problem.task.plan.target_q[0], problem.N * problem.h
        nq = problem.system.nq
        for k in range(problem.N):
            x[Y[k, 0]] = problem.y0[0] + (target - problem.y0[0]) * (k + 1) / problem.N
            x[Y[k, nq]] = (target - problem.y0[0]) / tau_f
            x[Y[k, -1]] = problem.h * (k + 1)
    elif kind == "nlp1":
        solver = _Solvers(problem, SolveOptions()).get(False)
        x = np.asarray(solver(**nlp1_arguments(problem, SolveOptions()))["x"], float).ravel()
    return x


def probe(N: int, start: str, scales: list[float], terminal_weight: float, holes: bool, max_iter: int) -> dict:
    """One start, the NLPs over `scales`; returns the record (rows per NLP)."""
    robot, task = capler_case(N)
    problem = build_problem(robot, task)
    nlp = smoothed_nlp(problem)
    opts = ipopt_options(SolveOptions(max_iter=max_iter), False)
    t0 = time.perf_counter()
    solver = ca.nlpsol("smoothed", "ipopt", nlp, opts)
    setup = time.perf_counter() - t0
    x, lbx, ubx = smoothed_bounds(problem, start_point(problem, start))
    lbg, ubg = problem.lbg.copy(), problem.ubg.copy()
    if terminal_weight > 0:
        rows = _terminal_rows(problem)
        lbg[rows], ubg[rows] = -np.inf, np.inf
    eps0 = np.array([EPS[s.function] for s in problem.system.switches])
    rows_out = []
    for scale in scales:
        p = np.concatenate([problem.params(0.0, 1.0 if holes else 0.0, terminal_weight=terminal_weight), scale * eps0])
        t0 = time.perf_counter()
        sol = solver(x0=x, p=p, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
        wall = time.perf_counter() - t0
        st, x = solver.stats(), np.asarray(sol["x"], float).ravel()
        rows_out.append({"eps_scale": scale, "iterations": int(st["iter_count"]), "status": st["return_status"], "wall_s": wall,
                         "control_cost": float(problem.objective_parts["control"](x, problem.params(0.0, 1.0))),
                         "terminal_error": terminal_error(problem, x), "base_x_end": float(problem.split(x)["Y"][-1, 0])})
    return {"N": N, "start": start, "terminal_weight": terminal_weight, "holes": holes, "max_iter": max_iter,
            "solver_setup_s": setup, "eps": EPS, "nlps": rows_out}


def table(rec: dict) -> str:
    lines = ["| eps scale | IPOPT it. | status | control cost | terminal error | base x at the end [m] | wall [s] |",
             "|---|---|---|---|---|---|---|"]
    for r in rec["nlps"]:
        lines.append(f"| {r['eps_scale']:g} | {r['iterations']} | {r['status']} | {r['control_cost']:.2f} | {r['terminal_error']:.2e} "
                     f"| {r['base_x_end']:.3f} | {r['wall_s']:.1f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = script_parser(__doc__)
    parser.add_argument("--start", choices=("paper", "line", "nlp1"), default="paper",
                        help="the NLPs' first start: paper (y_0 at every node, default), line or nlp1 (see above)")
    parser.add_argument("--eps-scales", type=positive_float, nargs="+", default=[10.0, 3.0, 1.0, 0.3, 0.1],
                        help="the smoothing widths' scales, one NLP each from the last (default 10 3 1 0.3 0.1)")
    parser.add_argument("--terminal-weight", type=nonnegative_float, default=0.0,
                        help="soft terminal weight (default 0: the hard terminal rows)")
    parser.add_argument("--no-holes", action="store_true", help="the holes switched off (hole scale 0)")
    parser.add_argument("--N", type=int, default=125, help="steps over the task's tau_f (default the task's 125)")
    parser.add_argument("--max-iter", type=int, default=3000, help="IPOPT iterations per NLP (default 3000)")
    parser.add_argument("--out", type=out_dir, default=Path("results/bench/probe_smoothing"),
                        help="output directory (default results/bench/probe_smoothing)")
    parser.add_argument("--quick", action="store_true", help="CI smoke run: N = 6, scales 1 and 0.1, 10 iterations each")
    parser.add_argument("--json", action="store_true", help="print the record as JSON instead of the table")
    args = parser.parse_args(argv)
    refuse_with_quick(parser, args, ["N", "max_iter", "eps_scales"], "N = 6, scales 1 and 0.1, 10 iterations each")
    if args.quick:
        args.N, args.eps_scales, args.max_iter = 6, [1.0, 0.1], 10
    if args.N < 1 or args.max_iter < 1:
        parser.error(f"--N and --max-iter must be >= 1, got {args.N}, {args.max_iter}")
    rec = probe(args.N, args.start, args.eps_scales, args.terminal_weight, not args.no_holes, args.max_iter)
    return report(args.out, rec, table(rec), args.json)


if __name__ == "__main__":
    sys.exit(run_main(main))
