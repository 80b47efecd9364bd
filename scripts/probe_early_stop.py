"""Could the homotopy stop early: does the held-schedule NLP from an iterate inside NLP k already give the plan? (issue 9)

The homotopy's NLPs are run as `planner.homotopy.solve` runs them for one race arm (the same solvers, scaling and
parameters; NLPs after the last checkpointed one are not run), each checkpointed NLP also capped at each of the
given iteration counts from its start (IPOPT's first j iterations do not depend on max_iter, so the capped run's
point is the uncapped run's iterate j). From every such point, and from the end of each NLP, the solve's own
held-schedule NLP (the `reoptimize` stage: the contact schedule of the point held, the task's cost, SCHEDULE_IPOPT)
is tried. Per point: the largest gated product, the held NLP's iterations, status and whether the solve would
accept it, the plan's control cost and impacts, and in how many selectors the point's contact mode
(homotopy.active_set_bounds: at 0, at 1, inside) differs from the mode at the NLP's end. Writes OUT/results.json.

    python -m scripts.probe_early_stop [--case capler125] [--arm alternate] [--at 2:300,600,900 3:200,400,600,700]
    python -m scripts.probe_early_stop --quick --json     # CI smoke run: the hop with N = 6
"""
from __future__ import annotations

import argparse
import shlex
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from planner import homotopy as H
from planner.errors import InputError
from planner.problem import build_problem
from planner.race import default_arms
from scripts.bench_pipeline import CASES
from scripts._report import out_dir, refuse_with_quick, report, run_main, script_parser

DEFAULT_OUT = Path("results/probe/early_stop")
DEFAULT_AT = ["2:300,600,900", "3:200,400,600,700"]
MODES = {"at 0": 0, "at 1": 1, "inside": 2}


def at_item(text: str) -> tuple[int, list[int]]:
    """An --at item 'K:j1,j2,...' -> (K, [j1, j2, ...] sorted); NLP K and the iterations whole numbers >= 1."""
    k, _, js = text.partition(":")
    try:
        nlp, its = int(k), sorted(int(j) for j in js.split(","))
    except ValueError:
        nlp, its = 0, []
    if nlp < 1 or not its or its[0] < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: give K:J1,J2,... with NLP K and iterations J whole numbers >= 1")
    return nlp, its


def parse_at(items: list[str]) -> dict[int, list[int]]:
    """'K:j1,j2,...' items -> {K: [j1, j2, ...]} (at_item's)."""
    return dict(at_item(item) for item in items)


def selector_modes(problem, x) -> np.ndarray:
    """(N, n_sel) contact mode of every selector at NLP point x (MODES), as the held schedule would fix it."""
    x = H.ungate(problem, x) if "gates" in problem.notes else x
    lbx, ubx, _ = H.active_set_bounds(problem, x)
    s = problem.var_blocks["sigma"]
    lo, hi = lbx[s.ravel()], ubx[s.ravel()]
    return np.where((lo == 0) & (hi == 0), 0, np.where((lo == 1) & (hi == 1), 1, 2)).reshape(s.shape)


def probe(problem, options: H.SolveOptions, at: dict[int, list[int]]) -> list[dict]:
    """One record per tried point: the checkpoints of each NLP in `at` it reaches, then that NLP's end; the NLPs are
    solve()'s (planner.homotopy.homotopy_nlp)."""
    H.keep_freed_memory()
    # the held NLPs get their own solvers: each scales by its start's magnitudes (_held_scaled), which would replace
    # the scale the homotopy's warm NLPs see
    solvers, held_solvers = H._Solvers(problem, options), H._Solvers(problem, options)
    rhos = H.homotopy_rhos(problem, options)
    control = problem.objective_parts["control"]
    scaled = problem.task.plan.homotopy.scale_variables

    def run(i, x, lam_x, lam_g, cap=None):
        nlp = H.homotopy_nlp(problem, options, i, rhos)
        solvers.options = options if cap is None else replace(options, max_iter=cap)  # solvers.get keeps one IPOPT per option set
        return H._run(problem, solvers, x, lam_x, lam_g, nlp.p, problem.lbx, problem.ubx, nlp.label, nlp.lbg, nlp.ubg,
                      loose=nlp.loose)

    def held(x, rec) -> dict:
        records = []
        _, xh = H._held_scaled(problem, held_solvers, options, x, records, None, "held")
        out = {"complementarity": rec.complementarity_residual, "nlp_iterations": rec.iterations,
               "held_iterations": records[-1].iterations, "held_status": records[-1].status, "accepted": xh is not None}
        if xh is not None:
            out.update(control_cost=float(control(xh, problem.params(0.0, 1.0))), impacts=len(H._impacts(problem, xh, options)))
        return dict(out, modes=selector_modes(problem, x))

    records = []
    x, lam_x, lam_g = problem.x0.copy(), None, None
    for i in range(min(max(at), len(rhos))):
        tried = []
        for j in at.get(i + 1, []):
            x_j, _, _, rec_j = run(i, x, lam_x, lam_g, cap=j)
            if rec_j.iterations < j:  # the NLP ended before it: its end's row (a row "5000" read as run that long)
                break
            tried.append((j, held(x_j, rec_j)))
        x, lam_x, lam_g, rec = run(i, x, lam_x, lam_g)
        if i == 0 and scaled:
            solvers.set_scale(H.variable_scale(problem, x))
        if i + 1 in at:
            end = held(x, rec)
            end_modes = end["modes"]
            for j, r in tried + [(None, end)]:
                modes = r.pop("modes")
                records.append({"nlp": i + 1, "rho": rhos[i], "at": j, **r, "modes_differing": int(np.sum(modes != end_modes))})
    return records


def table(records) -> str:
    lines = ["| NLP | at iteration | largest product | held NLP | accepted | control cost | impacts | modes differing from the NLP's end |",
             "|---|---|---|---|---|---|---|---|"]
    for r in records:
        cost = f"{r['control_cost']:.2f}" if "control_cost" in r else "-"
        lines.append(f"| {r['nlp']} (rho {r['rho']:g}) | {r['at'] if r['at'] is not None else 'end (' + str(r['nlp_iterations']) + ')'} | "
                     f"{r['complementarity']:.1e} | {r['held_iterations']} {r['held_status']} | {r['accepted']} | {cost} | "
                     f"{r.get('impacts', '-')} | {r['modes_differing']} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = script_parser(__doc__)
    parser.add_argument("--case", choices=sorted(CASES), default="capler125", help="the task (bench_pipeline's cases; default capler125)")
    parser.add_argument("--arm", choices=("default", "alternate"), default="alternate",
                        help="the race arm's SolveOptions (planner.race.default_arms; default alternate, the main job's winner)")
    parser.add_argument("--at", nargs="+", type=at_item, metavar="K:J1,J2",
                        help="NLP K capped at iterations J1, J2, ... (default 2:300,600,900 3:200,400,600,700)")
    parser.add_argument("--quick", action="store_true", help="CI smoke run: the hop with N = 6, NLP 2 at 5 iterations")
    parser.add_argument("--out", type=out_dir, default=DEFAULT_OUT, help=f"output directory (default {DEFAULT_OUT})")
    parser.add_argument("--json", action="store_true", help="print results.json on stdout instead of the table")
    args = parser.parse_args(argv)
    refuse_with_quick(parser, args, ["case", "at"], "the hop with N = 6, NLP 2 at 5 iterations")
    named = [nlp for nlp, _ in args.at or ()]
    if len(set(named)) < len(named):  # dict() kept the last item of an NLP: the others were dropped, recorded as run
        twice = sorted({nlp for nlp in named if named.count(nlp) > 1})
        parser.error(f"--at names NLP {', '.join(map(str, twice))} more than once: give its iterations in one item, "
                     "K:J1,J2,...")
    at = parse_at(["2:5"] if args.quick else DEFAULT_AT) if args.at is None else dict(args.at)
    case = "hop" if args.quick else args.case
    problem = build_problem(*CASES[case](args.quick))
    options = dict(default_arms(H.SolveOptions()))[args.arm]
    n_nlps = len(H.homotopy_rhos(problem, options))
    if max(at) > n_nlps:  # those NLPs are never run: an empty table, exit 0
        raise InputError(f"--at {max(at)}:...: the homotopy of case {case} has NLPs 1 to {n_nlps}")
    records = probe(problem, options, at)
    results = {"command": "python -m scripts.probe_early_stop "
               + shlex.join(argv if argv is not None else sys.argv[1:]),
               "case": case, "arm": args.arm, "records": records}
    return report(args.out, results, table(records), args.json)


if __name__ == "__main__":
    sys.exit(run_main(main))
