"""Equivalent tasks, other plans: does a task that says the same physics in another way give the same plan? (issue 10)

Each case is a base task and variants of it whose physics is the base's, moved or mirrored: the same scene shifted
along x, the same scene mirrored in x, the base with joint-range bounds far beyond the motion (a URDF slide must
have limits: robots/capler.urdf's ±100 m). Every variant
is built and solved with the default SolveOptions (one arm, as `planner plan --no-race`), and its plan is mapped
back onto the base's frame (x shifted back, mirrored coordinates negated) and compared with the base's plan at the
nodes. Per variant: IPOPT iterations, NLP 1's objective, convergence, control cost, impacts, and the largest mapped
node-state difference [m, rad, m/s, rad/s]. The same plan means a difference at round-off (~1e-9); the
time-freezing NLPs are not invariant under all of these (docs/stability.md, "Equivalent tasks").

Cases:

* hop: the point mass hopping 0.5 m in 1 s (robots/point_mass_hop.toml), mu = 0.5; and the same frictionless.
* capler: Capler without holes, N = 25 over tau_f = 1, target x = 0.4 m (robots/capler.toml otherwise).

    python -m scripts.probe_equivalent [--quick] [--cases NAME ...] [--out DIR] [--json]   (repository root)

--quick (the CI smoke run) runs the hop with N = 6.
"""
from __future__ import annotations

import sys
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from planner.cli import prepare_out_dir
from planner.homotopy import solve
from planner.model import load_robot
from planner.problem import build_problem
from planner.task import parse_task
from scripts._report import out_dir, refuse_with_quick, report, run_main, script_parser

DEFAULT_OUT = Path("results/probe/equivalent")
ROBOTS = Path(__file__).resolve().parents[1] / "robots"
SHIFT = 1.0  # [m] along x
FAR = 100.0  # [m] the far joint-range bounds of a slide, as robots/capler.urdf's


@dataclass(frozen=True)
class Variant:
    """A task dict and the map of its plan's coordinates back onto the base's: q_base = sign * q - offset."""
    name: str
    task: dict
    sign: np.ndarray  # (nq,)
    offset: np.ndarray  # (nq,) [m or rad]


def _variants(base: dict, nq: int, mirrored: np.ndarray, slides: list[str]) -> list[Variant]:
    """base, shifted, mirrored (coordinates `mirrored` negated), and far bounds on the joints `slides` if any."""
    one, zero = np.ones(nq), np.zeros(nq)

    def edit(change) -> dict:
        task = {k: (dict(v) if isinstance(v, dict) else v) for k, v in base.items()}
        change(task)
        return task

    def shift(task):
        task["initial"]["q"] = [q + SHIFT * (j == 0) for j, q in enumerate(task["initial"]["q"])]
        task["plan"]["target_q"] = [q + SHIFT * (j == 0) for j, q in enumerate(task["plan"]["target_q"])]
        task["plan"]["holes"] = [dict(h, x=h["x"] + SHIFT) for h in task["plan"].get("holes", [])]

    sign = np.where(mirrored, -1.0, 1.0)

    def mirror(task):
        task["initial"]["q"] = list(sign * task["initial"]["q"])
        task["plan"]["target_q"] = list(sign * task["plan"]["target_q"])
        task["plan"]["holes"] = [dict(h, x=-h["x"]) for h in task["plan"].get("holes", [])]

    def far(task):
        task["plan"]["joint_bounds"] = list(task["plan"].get("joint_bounds", [])) + [
            {"joint": j, "lower": -FAR, "upper": FAR} for j in slides]

    variants = [Variant("base", base, one, zero),
                Variant(f"shifted {SHIFT:g} m", edit(shift), one, SHIFT * np.eye(nq)[0]),
                Variant("mirrored", edit(mirror), sign, zero)]
    if slides:
        variants.append(Variant(f"slides bounded ±{FAR:g} m", edit(far), one, zero))
    return variants


def hop_case(quick: bool) -> tuple[str, list[tuple[str, list[Variant]]]]:
    base = tomllib.loads((ROBOTS / "point_mass_hop.toml").read_text())
    if quick:
        base["horizon"] = dict(base["horizon"], N=6)
    frictionless = dict(base, contacts=[dict(c, mu=0.0) for c in base["contacts"]])
    mirrored = np.array([True, False])
    return "point_mass", [(name, _variants(b, 2, mirrored, [])) for name, b in
                          (("hop", base), ("hop, frictionless", frictionless))]


def capler_case(quick: bool) -> tuple[str, list[tuple[str, list[Variant]]]]:
    base = tomllib.loads((ROBOTS / "capler.toml").read_text())
    base["horizon"] = dict(base["horizon"], tau_f=1.0, N=25)
    base["plan"] = {k: v for k, v in base["plan"].items() if k != "holes"}
    base["plan"]["target_q"] = [0.4] + list(base["plan"]["target_q"][1:])
    mirrored = np.array([True, False, True, True])  # x and the two leg angles about y
    return "capler", [("capler", _variants(base, 4, mirrored, ["base_x", "base_z"]))]


CASES = {"hop": hop_case, "capler": capler_case}


def _solve(robot, variant: Variant) -> tuple[dict, object]:
    t0 = time.perf_counter()
    res = solve(build_problem(robot, parse_task(variant.task)))
    return {"variant": variant.name, "ipopt_iterations": res.stats.ipopt_iterations,
            "nlp1_objective": res.nlps[0].objective, "converged": res.stats.converged,
            "control_cost": res.extra["control_cost"], "impacts": len(res.trajectory.impacts),
            "wall_s": time.perf_counter() - t0}, res


def run(names, quick: bool, log) -> list[dict]:
    records = []
    for name in names:
        robot_name, families = CASES[name](quick)
        robot = load_robot(robot_name)
        for family, variants in families:
            base = None
            for variant in variants:
                rec, res = _solve(robot, variant)
                tr = res.trajectory
                nq = tr.q.shape[1]
                # nodes' states (q, v) mapped back: q -> sign q - offset, v -> sign v; the clock is left out
                y = np.hstack([tr.y[:, :nq] * variant.sign - variant.offset, tr.y[:, nq:2 * nq] * variant.sign])
                base = y if base is None else base
                rec.update(case=family, max_node_state_diff=float(np.max(np.abs(y - base))))
                log(rec)
                records.append(rec)
    return records


def table(records) -> str:
    lines = ["| case | variant | IPOPT it. | NLP 1 objective | converged | control cost | impacts | "
             "max mapped node diff |",
             "|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r['case']} | {r['variant']} | {r['ipopt_iterations']} | {r['nlp1_objective']:.6g} | "
              f"{r['converged']} | {r['control_cost']:.4g} | {r['impacts']} | {r['max_node_state_diff']:.1e} |"
              for r in records]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = script_parser(__doc__)
    parser.add_argument("--out", type=out_dir, default=DEFAULT_OUT, help=f"output directory (default {DEFAULT_OUT})")
    parser.add_argument("--quick", action="store_true", help="CI smoke run: the hop with N = 6")
    parser.add_argument("--cases", nargs="+", choices=sorted(CASES), help="run only these cases (default: all)")
    parser.add_argument("--json", action="store_true", help="print results.json on stdout instead of the table")
    args = parser.parse_args(argv)
    refuse_with_quick(parser, args, ["cases"], "the hop with N = 6")
    prepare_out_dir(args.out)

    def log(rec):  # progress on stderr: stdout keeps the table or the JSON
        print(f"{rec['case']:<18} {rec['variant']:<22} {rec['ipopt_iterations']:6d} it  "
              f"cost {rec['control_cost']:9.4g}  diff {rec['max_node_state_diff']:.1e}  {rec['wall_s']:6.1f} s",
              file=sys.stderr, flush=True)

    names = ["hop"] if args.quick else list(dict.fromkeys(args.cases or CASES))
    records = run(names, args.quick, log)
    return report(args.out, {"quick": args.quick, "records": records}, table(records), args.json)


if __name__ == "__main__":
    sys.exit(run_main(main))
