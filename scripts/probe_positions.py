"""Second-order positions in the time-freezing step: more accurate simulations, and plans? (issue 9, session 31)

The implicit-Euler step moves the positions by q+ - q = dt v+ (dt = h s r, the physical time of the step, r its clock
rate). In free flight that is first order: the point mass's fall is dt^2 g / 2 per step too short, and a Capler
flight of 0.4 s at h = 0.02 s ends ~4 cm off. The probe replaces the position rows by

    q+ - q = dt (v+ + r^p (v - v+) / 2)

the trapezoidal rule (exact for a ballistic flight) in steps whose clock runs (r = 1), implicit Euler in frozen steps
(r = 0). The weight r^p (default p = 2) keeps a step that is partly frozen near implicit Euler: with the plain
trapezoid (p = 0) the step that ends an impact averages the pre-impact velocity into its motion and the point mass
sinks 2.6 mm into the ground at h = 0.02 s. Nothing else of the step changes (selectors, switching functions,
secant velocity); the rule is applied by patching ImplicitEulerStep.build for the duration of a run.

  simulate  the work-precision cases of scripts/bench_work_precision.py (default variant) with implicit Euler and
            with the rule: state error, impact time error, penetration per h.
  plan      `planner plan` with the rule (the CLI's arguments after --plan), e.g. the default Capler task hint-free
            and its MuJoCo validation.

    python -m scripts.probe_positions                          # the simulation cases, both rules (~3 min)
    python -m scripts.probe_positions --plan capler --out DIR  # the hint-free Capler plan with the rule (~8 min)
    python -m scripts.probe_positions --quick --json           # CI smoke run: the point mass at two steps
Writes OUT/results.json (simulate).
"""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import sys
from pathlib import Path
from unittest import mock

import casadi as ca

from planner.discretization import ImplicitEulerStep
from planner.errors import InputError
from scripts import bench_work_precision as wp
from scripts._report import (nonnegative_float, out_dir, refuse_beside, refuse_with_quick, report, run_main,
                             script_parser)

CASES = ("pm_drop_frictionless", "pm_drop_noslip", "capler_pd_drop")


@contextlib.contextmanager
def trapezoid_positions(power: float = 2.0):
    """Within the block, every ImplicitEulerStep built (not FESD's stages, which pass their own increments) has the
    position rows q+ - q = dt (v+ + r^power (v - v+) / 2) instead of q+ - q = dt v+ (module docstring)."""
    plain = ImplicitEulerStep.build

    def build(self, y_k, y_next, u_k, s_k=1.0, h=0.01, tag="", field_scale=None, dy=None, dgap=None, gap_weight=None):
        step = plain(self, y_k, y_next, u_k, s_k, h, tag, field_scale, dy, dgap, gap_weight)
        if dy is not None:
            return step
        nq, nv = self.system.nq, self.system.nv
        if nq != nv:  # q' = r v row by row only without a free flyer's quaternion
            raise InputError(f"the trapezoidal positions need nq = nv, got nq = {nq}, nv = {nv}")
        rows = step.g[step.g_blocks["dynamics"]]
        dt = (y_next[-1] - y_k[-1]) - rows[-1]  # the clock row is t+ - t - h s r: its h s r
        rate = dt / (h * s_k)
        shift = dt * rate**power * (y_k[nq : nq + nv] - y_next[nq : nq + nv]) / 2
        return dataclasses.replace(step, g=ca.vertcat(step.g[:nq] - shift, step.g[nq:]))

    with mock.patch.object(ImplicitEulerStep, "build", build):
        yield


def simulate_records(quick: bool, power: float, cases: tuple[str, ...]) -> list[dict]:
    """The work-precision records of `cases` (default variant only) with implicit Euler and with the rule."""
    pm_cases, capler = wp.simulate_cases(quick)
    pm_cases = [dataclasses.replace(c, variants=(wp.Variant("default"),)) for c in pm_cases if c.name in cases]
    capler = dataclasses.replace(capler, variants=(wp.Variant("default"),), fesd_reference=None)
    robot = wp.load_robot("point_mass")
    dyn = wp.Dynamics(robot)

    def run() -> list[dict]:
        recs = [r for case in pm_cases for r in wp.point_mass_records(case, robot, dyn, 1, lambda rec: None)]
        return recs + (wp.capler_records(capler, 1, lambda rec: None)[0] if "capler_pd_drop" in cases else [])

    records = [dict(r, rule="implicit_euler") for r in run()]
    with trapezoid_positions(power):
        records += [dict(r, rule=f"trapezoid r^{power:g}") for r in run()]
    return records


KEYS = ("state_error_m", "base_error_mujoco_m", "impact_time_error_s", "impact_time_diff_exact_s", "penetration_m")


def table(records: list[dict]) -> str:
    lines = [f"{'case':<22} {'rule':<16} {'h':>8} " + " ".join(f"{k:>26}" for k in KEYS)]
    for r in records:
        errs = r["errors"]
        cells = " ".join(f"{errs[k]:26.2e}" if errs.get(k) is not None else f"{'':>26}" for k in KEYS)
        lines.append(f"{r['case']:<22} {r['rule']:<16} {r['h']:8g} {cells}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = script_parser(__doc__)
    parser.add_argument("--power", type=nonnegative_float, default=2.0,
                        help="p of the weight r^p (0: the plain trapezoid)")
    parser.add_argument("--cases", nargs="+", choices=CASES, default=list(CASES),
                        help=f"the simulation cases (default all: {', '.join(CASES)})")
    parser.add_argument("--out", type=out_dir, default=Path("results/bench/probe_positions"),
                        help="output directory (default results/bench/probe_positions)")
    parser.add_argument("--quick", action="store_true", help="CI smoke run: the frictionless point mass at h = 0.04, 0.02")
    parser.add_argument("--json", action="store_true", help="print the records as JSON instead of the table")
    parser.add_argument("--plan", nargs=argparse.REMAINDER, metavar="ARGS", help="run `planner plan ARGS` with the rule instead (last option)")
    args = parser.parse_args(argv)
    refuse_with_quick(parser, args, ["cases", "plan"], "the frictionless point mass at two steps")
    if args.plan is not None:  # (the cases, --out and --json were dropped, no results.json written)
        refuse_beside(parser, args, ["cases", "out", "json"], "--plan runs `planner plan ARGS`, which writes its --out")
        from planner.cli import main as cli

        with trapezoid_positions(args.power):
            return cli(["plan", *args.plan])
    cases = ("pm_drop_frictionless",) if args.quick else tuple(args.cases)
    records = simulate_records(args.quick, args.power, cases)
    return report(args.out, {"power": args.power, "quick": args.quick, "records": records}, table(records), args.json)


if __name__ == "__main__":
    sys.exit(run_main(main))
