"""What cuts IPOPT's steps in the homotopy's first NLPs: the fraction-to-the-boundary rule, and at which bounds (issue 9).

NLP 1 and NLP 2 are solved as `planner.homotopy.solve` solves them with the default SolveOptions (the race's
default arm: `bench_pipeline.nlp1_arguments` and `nlp2_setup`), with an IPOPT iteration callback that keeps every
iterate. IPOPT keeps each variable at least 1 - tau = 1 % of its distance to a bound (tau = 0.99), so a variable
whose distance (to the bound as IPOPT relaxes it) falls to <= CUT_RATIO of the last one in one step is where the
rule cut that step; inequality rows are read the same way through g (their slacks). Per NLP: iterations, IPOPT's
regularization delta_w
(iterations regularized, median lg delta_w) and primal step alpha_pr (median, full steps), the steps with a cut,
and the variables (by name without the step index, and bound side) and rows (by block) that sat at the rule
most often. Writes OUT/results.json.

    python -m scripts.probe_steps [--case capler125] [--nlps 1|2] [--no-lift] [--top 10] [--out DIR] [--json]
    python -m scripts.probe_steps --quick --json     # CI smoke run: the hop with N = 6
"""
from __future__ import annotations

import collections
import re
import shlex
import sys
from pathlib import Path

import casadi as ca
import numpy as np

from planner.homotopy import SolveOptions, ipopt_options
from planner.problem import ProblemOptions, build_problem
from scripts.bench_pipeline import CASES, nlp1_arguments, nlp2_setup
from scripts._report import out_dir, refuse_with_quick, report, run_main, script_parser

DEFAULT_OUT = Path("results/probe/steps")
# IPOPT leaves the variable that limits a step at 1 - tau = 1 % of its distance (tau_min 0.99); 2 % admits round-off
CUT_RATIO = 0.02
IPOPT_BOUND_RELAX = 1e-8  # IPOPT's default bound_relax_factor


class Iterates(ca.Callback):
    """IPOPT iteration callback that keeps every iterate x (nx,) and g (ng,)."""

    def __init__(self, nx: int, ng: int):
        ca.Callback.__init__(self)
        self.nx, self.ng, self.x, self.g = nx, ng, [], []
        self.construct("iterates", {})

    def get_n_in(self):
        return ca.nlpsol_n_out()

    def get_n_out(self):
        return 1

    def get_name_in(self, i):
        return ca.nlpsol_out(i)

    def get_name_out(self, i):
        return "ret"

    def get_sparsity_in(self, i):
        n = {"f": 1, "x": self.nx, "lam_x": self.nx, "g": self.ng, "lam_g": self.ng}.get(ca.nlpsol_out(i), 0)
        return ca.Sparsity.dense(n) if n else ca.Sparsity(0, 0)

    def eval(self, arg):
        self.x.append(np.array(arg[0], float).ravel())
        self.g.append(np.array(arg[2], float).ravel())
        return [0]


def cut_steps(X: np.ndarray, lower: np.ndarray, upper: np.ndarray, relax: float = 0.0) -> list[list[tuple[int, str]]]:
    """Per step i (X[i - 1] -> X[i], X (K + 1, n)): the (index, "lb" or "ub") whose distance to that finite bound
    fell to <= CUT_RATIO of its last value. relax: IPOPT's bound_relax_factor; the distances are to the bounds it
    works with, each moved out by relax max(1, |bound|)."""
    def widen(bound):  # infinite bounds stay as they are
        return relax * np.maximum(1.0, np.abs(np.where(np.isfinite(bound), bound, 0.0)))
    lower, upper = lower - widen(lower), upper + widen(upper)
    out = []
    for a, b in zip(X[:-1], X[1:]):
        cut = []
        for bound, side, sign in ((lower, "lb", 1.0), (upper, "ub", -1.0)):
            finite = np.isfinite(bound)
            d0, d1 = sign * (a - bound), sign * (b - bound)
            hit = finite & (d0 > 0) & (d1 >= 0) & (d1 <= CUT_RATIO * np.where(finite, d0, 0))
            cut += [(int(j), side) for j in np.flatnonzero(hit)]
        out.append(cut)
    return out


def summary(problem, label: str, cb: Iterates, args: dict, stats: dict, top: int, relax: float) -> dict:
    """One NLP's record from its iterates, its IPOPT arguments (bounds in the solver's units), IPOPT's stats and its
    bound_relax_factor."""
    var_kind = [re.sub(r"_\d+$", "", n) for n in problem.var_names]
    row_kind = np.empty(problem.ng, dtype=object)
    for name, rows in problem.g_blocks.items():
        row_kind[np.asarray(rows).ravel()] = name
    lbg, ubg = np.asarray(args["lbg"], float), np.asarray(args["ubg"], float)
    inequality = lbg != ubg
    var_cuts = cut_steps(np.array(cb.x), np.asarray(args["lbx"], float), np.asarray(args["ubx"], float), relax)
    row_cuts = cut_steps(np.array(cb.g), np.where(inequality, lbg, -np.inf), np.where(inequality, ubg, np.inf), relax)
    # per kind (a variable's name without its step index, a row's block) and side: the steps it cut, once per step
    variables = collections.Counter(kind for cut in var_cuts for kind in {(var_kind[j], side) for j, side in cut})
    rows = collections.Counter(kind for cut in row_cuts for kind in {(row_kind[j], side) for j, side in cut})
    it = stats.get("iterations", {})
    reg = np.asarray(it.get("regularization_size", [])[1:], float)
    alpha = np.asarray(it.get("alpha_pr", [])[1:], float)
    return {"nlp": label, "iterations": int(stats["iter_count"]), "status": stats["return_status"],
            "regularized": int(np.sum(reg > 0)), "median_lg_delta_w": float(np.median(np.log10(reg[reg > 0]))) if np.any(reg > 0) else None,
            "median_alpha_pr": float(np.median(alpha)) if alpha.size else None, "full_steps": int(np.sum(alpha >= 0.999)),
            "steps_cut": int(sum(1 for v, r in zip(var_cuts, row_cuts) if v or r)),
            "variables": [[name, side, n] for (name, side), n in variables.most_common(top)],
            "rows": [[name, side, n] for (name, side), n in rows.most_common(top)]}


def probe(problem, nlps: int = 2, top: int = 10) -> list[dict]:
    """NLP 1 (and NLP 2) of the default solve with every iterate kept: a record each (see summary)."""
    options = SolveOptions()
    records = []
    nlp = {"x": problem.x, "p": problem.p, "f": problem.f, "g": problem.g}
    args = nlp1_arguments(problem, options)
    for k in range(1, nlps + 1):
        cb = Iterates(problem.nx, problem.ng)
        opts = ipopt_options(options, warm=k > 1)
        opts["iteration_callback"] = cb
        solver = ca.nlpsol(f"probe_nlp{k}", "ipopt", nlp, opts)
        sol = solver(**args)
        relax = float(opts["ipopt"].get("bound_relax_factor", IPOPT_BOUND_RELAX))
        records.append(summary(problem, f"NLP {k}", cb, args, solver.stats(), top, relax))
        if k < nlps:
            nlp, args = nlp2_setup(problem, np.asarray(sol["x"], float).ravel())
    return records


def table(records) -> str:
    lines = ["| NLP | iterations | regularized (median lg delta_w) | median alpha_pr, full steps | steps cut | most often at (variable, bound: steps) | rows |",
             "|---|---|---|---|---|---|---|"]
    for r in records:
        lg = "-" if r["median_lg_delta_w"] is None else f"{r['median_lg_delta_w']:.1f}"
        alpha = "-" if r["median_alpha_pr"] is None else f"{r['median_alpha_pr']:.2f}"
        lines.append(f"| {r['nlp']} | {r['iterations']} ({r['status']}) | {r['regularized']} ({lg}) | {alpha}, {r['full_steps']} | "
                     f"{r['steps_cut']} | {', '.join(f'{n} {s}: {c}' for n, s, c in r['variables'])} | "
                     f"{', '.join(f'{n} {s}: {c}' for n, s, c in r['rows'])} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = script_parser(__doc__)
    parser.add_argument("--case", choices=sorted(CASES), default="capler125", help="the task (bench_pipeline's cases; default capler125)")
    parser.add_argument("--nlps", type=int, choices=(1, 2), default=2, help="NLP 1, or NLPs 1 and 2 (default)")
    parser.add_argument("--no-lift", action="store_true", help="ProblemOptions.lift_products = False")
    parser.add_argument("--top", type=int, default=10, help="variables and rows listed per NLP (default 10)")
    parser.add_argument("--quick", action="store_true", help="CI smoke run: the hop with N = 6")
    parser.add_argument("--out", type=out_dir, default=DEFAULT_OUT, help=f"output directory (default {DEFAULT_OUT})")
    parser.add_argument("--json", action="store_true", help="print results.json on stdout instead of the table")
    args = parser.parse_args(argv)
    if args.top < 1:  # (Counter.most_common listed nothing, exit 0)
        parser.error(f"--top must be >= 1, got {args.top}")
    refuse_with_quick(parser, args, ["case"], "the hop with N = 6")
    case = "hop" if args.quick else args.case
    robot, task = CASES[case](args.quick)
    problem = build_problem(robot, task, ProblemOptions(lift_products=not args.no_lift))
    records = probe(problem, args.nlps, args.top)
    results = {"command": "python -m scripts.probe_steps "
               + shlex.join(argv if argv is not None else sys.argv[1:]), "case": case,
               "lift_products": not args.no_lift, "cut_ratio": CUT_RATIO, "records": records}
    return report(args.out, results, table(records), args.json)


if __name__ == "__main__":
    sys.exit(run_main(main))
