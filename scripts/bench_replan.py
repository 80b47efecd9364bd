"""Replanning from a plan (`planner plan --init DIR`), with and without its held schedule, as the task moves.

For a robot in robots/ this plans its default task hint-free once (or takes `--init DIR`, a plan of it),
then replans copies of the task with one number changed, each twice: the penalty replan (`--init --penalty-replan`) and
the replan that first holds the start's contact schedule (`--init`, the default; walked through the tasks
between when that is refused: planner.replan; its NLPs "walk s" and "retime s: ..."), and on request the
one that also accepts a held schedule that adds impacts (`--variants new_impacts`). The number is the
target's first coordinate (`plan.target_q[0]`, Capler's x [m]) or, for a periodic task, the step
(`plan.periodic.step` [m]). Per run: exit code, converged, the NLPs (label, IPOPT iterations), solve time
[s] and its IPOPT setup [s], the whole command's wall [s], control cost, impact times [s], and with --validate the MuJoCo verdict (a walk's steps walked).
Writes OUT/results.json and prints a Markdown table.

    python -m scripts.bench_replan capler --values 2.8 2.9 2.95 3.1 [--init DIR] [--variants keep_schedule new_impacts] [--validate]
        [--out DIR] [--json]
    python -m scripts.bench_replan biped --values 0.22 0.24 0.26 0.27 0.28 0.3 --validate
    python -m scripts.bench_replan --quick --json     # CI smoke run: the point-mass hop, N = 20

Iterations are deterministic on one machine; the walls depend on its load.
"""
from __future__ import annotations

import json
import math
import re
import shutil
import sys
import time
import tomllib
from pathlib import Path

from planner.errors import InputError
from planner.result import read_summary, read_task, read_trajectory, write_atomically
from planner.task import parse_task
from scripts._report import drop_results, out_dir, planner_command, refuse_with_quick, report, run_main, script_parser

ROOT = Path(__file__).resolve().parent.parent
TARGET_LINE = re.compile(r"^(target_q = \[)([^,\]]+)", re.MULTILINE)
STEP_LINE = re.compile(r"^(step = )([^\s#]+)", re.MULTILINE)
QUICK_TASK = (ROOT / "robots" / "point_mass_hop.toml").read_text()
# variant names as in the docs' tables since session 9 ("replan": --init alone before session 42)
VARIANTS = {"replan": ["--penalty-replan"], "keep_schedule": [], "new_impacts": ["--allow-new-impacts"]}
DEFAULT_VARIANTS = ["replan", "keep_schedule"]


def moved_task(text: str, value: float) -> str:
    """The task file's text with its moved number (the periodic step, else the target's first coordinate) set."""
    name, pattern = ("step", STEP_LINE) if STEP_LINE.search(text) else ("target_q", TARGET_LINE)
    if len(pattern.findall(text)) != 1:
        raise InputError(f"the task needs exactly one '{name} = ...' line to move")
    return pattern.sub(lambda m: m.group(1) + repr(float(value)), text)


def record(out: Path, code: int) -> dict:
    """What a `planner plan` run wrote to `out` (OUT/failed when it did not converge); a run that wrote nothing (exit 2:
    the task was refused, e.g. a target inside a hole) is a row with "refused" true and no numbers."""
    plan = out if (out / "summary.json").is_file() else out / "failed"
    if not (plan / "summary.json").is_file():
        return {"exit_code": code, "refused": True, "converged": False, "nlps": [], "ipopt_iterations": None,
                "solve_time_s": None, "solver_setup_s": None, "control_cost": None, "impact_times_s": [],
                "impact_impulse_norms_Ns": [], "validation_passed": None, "steps_walked": None, "window_mean_m": None}
    s = json.loads((plan / "summary.json").read_text())
    v = s.get("validation") or {}
    return {"exit_code": code, "converged": s["converged"], "nlps": [[n["label"], n["iterations"]] for n in s["nlps"]],
            "ipopt_iterations": s["ipopt_iterations"], "solve_time_s": s["solve_time_s"],
            "solver_setup_s": s["timings"]["solver_setup_s"], "control_cost": s["control_cost"],
            "impact_times_s": [i["time"] for i in s["impacts"]],
            "impact_impulse_norms_Ns": [i["impulse_norm"] for i in s["impacts"]],
            "validation_passed": v.get("passed"), "steps_walked": v.get("steps_walked"),
            "window_mean_m": (v.get("windows") or {}).get("mean_m")}


def plan(robot: str, task: Path, out: Path, extra: list[str], validate: bool) -> dict:
    """One `planner plan` in this process; its record with command_s, the command's wall time [s] (the
    imports paid once per benchmark, before its first run)."""
    shutil.rmtree(out, ignore_errors=True)  # an earlier run's files there would be read as this run's
    started = time.perf_counter()
    code = planner_command(["plan", robot, "--task", str(task), "--out", str(out), "-q", *extra] + ([] if validate else ["--no-validate"]))
    return dict(record(out, code), command_s=time.perf_counter() - started)


def _start_N(init: Path, arrays: dict) -> int | None:
    """horizon.N of the task the --init plan solved, or None when that task cannot be read (`planner plan --init`
    replans such a start without its walk)."""
    try:
        return read_task(init, arrays).horizon.N
    except InputError:
        return None


def table(rows: list[dict]) -> str:
    lines = ["| value | variant | exit | NLPs (iterations) | IPOPT it. | solve [s] (IPOPT setup) | command [s] | cost | impacts: time [s] / impulse [N s] | MuJoCo |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if r.get("refused"):
            lines.append(f"| {r['value']:g} | {r['variant']} | {r['exit_code']} | refused (the error above) | | | "
                         f"{r['command_s']:.2f} | | | |")
            continue
        nlps = ", ".join(f"{label} {its}" for label, its in r["nlps"])
        mujoco = ("not run" if r["validation_passed"] is None else
                  f"{'passed' if r['validation_passed'] else 'failed'}" + (f", walked {r['steps_walked']}" if r["steps_walked"] is not None else "")
                  + (f", windows {1e3 * r['window_mean_m']:.2f} mm" if r["window_mean_m"] is not None else ""))
        impacts = ", ".join(f"{t:.3f}/{j:.3g}" for t, j in zip(r["impact_times_s"], r["impact_impulse_norms_Ns"]))
        impacts = impacts or "none"
        lines.append(f"| {r['value']:g} | {r['variant']} | {r['exit_code']} | {nlps} | {r['ipopt_iterations']} | "
                     f"{r['solve_time_s']:.2f} ({r['solver_setup_s']:.2f}) | {r['command_s']:.2f} | "
                     f"{r['control_cost']:.2f} | {impacts} | {mujoco} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = script_parser(__doc__)
    parser.add_argument("robot", nargs="?", default="capler", help="a robot in robots/ with its default task (default capler)")
    parser.add_argument("--values", type=float, nargs="+", help="the moved number's values (target x or step [m])")
    parser.add_argument("--init", type=Path, metavar="DIR", help="the start plan (default: plan the default task hint-free first)")
    parser.add_argument("--variants", nargs="+", choices=list(VARIANTS), default=DEFAULT_VARIANTS,
                        help="the replans to run per value (default replan: --penalty-replan, and keep_schedule: --init's "
                             "default; new_impacts: --allow-new-impacts)")
    parser.add_argument("--validate", action="store_true", help="also validate each replan in MuJoCo")
    parser.add_argument("--out", type=out_dir, default=Path("results/bench/replan"),
                        help="output directory (default results/bench/replan)")
    parser.add_argument("--quick", action="store_true", help="CI smoke run: the point-mass hop (N = 20) to 0.52 m")
    parser.add_argument("--json", action="store_true", help="print the results as JSON instead of the table")
    args = parser.parse_args(argv)
    args.variants = list(dict.fromkeys(args.variants))  # a variant named twice ran twice, into one directory
    refuse_with_quick(parser, args, ["robot", "values"], "the point-mass hop to 0.52 m")
    if args.quick:
        robot, values, base_text = "point_mass", [0.52], QUICK_TASK
    else:
        if not args.values:
            parser.error("--values is required (the moved target x or step [m])")
        if not all(math.isfinite(v) for v in args.values):
            parser.error(f"--values must be finite numbers, got {args.values}")
        labels = [f"{v:g}" for v in args.values]  # a value's run directory and task file are named so
        if len(set(labels)) != len(labels):  # (the later run deleted the earlier one's plan)
            parser.error(f"--values {' '.join(map(repr, args.values))} name the same runs ({', '.join(labels)}): give "
                         "each value once, apart in its first 6 digits")
        task_file = ROOT / "robots" / f"{args.robot}.toml"
        robot_files = [ROOT / "robots" / f"{args.robot}{ext}" for ext in (".xml", ".urdf")]
        if not task_file.is_file() or not any(f.is_file() for f in robot_files):  # (point_mass_hop is a task only)
            known = sorted(p.stem for p in (ROOT / "robots").glob("*.toml")
                           if any((ROOT / "robots" / f"{p.stem}{ext}").is_file() for ext in (".xml", ".urdf")))
            raise InputError(f"no robot file with a default task robots/{args.robot}.toml; robots with one: "
                             f"{', '.join(known)}")
        robot, values, base_text = args.robot, args.values, task_file.read_text()
    moved_task(base_text, values[0])  # a task without the number to move fails here, before any solve
    runs = {(value, variant): args.out / f"{variant}_{value:g}" for value in values for variant in args.variants}
    if args.init is not None:
        # a start that is no plan fails here, not in every replan (each a refused row)
        arrays = read_trajectory(args.init, ("nlp_x",))
        made_for = Path(str(read_summary(args.init, require=("robot",))["robot"])).stem
        if made_for != robot:  # each replan was refused instead, a row each, exit 0
            raise InputError(f"--init {args.init} is a plan of {made_for}, not of {robot}: give a plan of {robot}")
        start_N, N = _start_N(args.init, arrays), parse_task(tomllib.loads(base_text)).horizon.N
        if start_N not in (None, N):  # each replan was refused too, exit 0, its advice a --steps this script lacks
            raise InputError(f"--init {args.init} is a plan with horizon.N = {start_N}, and the tasks replanned here "
                             f"have N = {N}: give a plan with N = {N}")
        init = args.init.resolve()
        for replaced in runs.values():  # plan() empties each run's directory first: it deleted such a start
            if replaced.resolve() == init or replaced.resolve() in init.parents:
                raise InputError(f"--init {args.init} lies in {replaced}, which this run replaces; copy it elsewhere "
                                 "or give another --out")
    args.out.mkdir(parents=True, exist_ok=True)
    drop_results(args.out)
    base_task = args.out / "base.toml"
    write_atomically(base_task, base_text)
    start = args.init
    if start is None:
        start = args.out / "base"
        code = plan(robot, base_task, start, [], False)["exit_code"]
        if code == 2:  # (it was reported as "did not converge", exit 1, with nothing solved)
            raise InputError("the start plan's command was refused (its error above)")
        if code != 0:
            raise SystemExit(f"the start plan did not converge: see {start}")
    rows = []
    for value in values:
        task = args.out / f"task_{value:g}.toml"
        write_atomically(task, moved_task(base_text, value))
        for variant in args.variants:
            run = plan(robot, task, runs[value, variant], ["--init", str(start), *VARIANTS[variant]], args.validate)
            rows.append({"value": value, "variant": variant, **run})
    return report(args.out, {"robot": robot, "start": str(start), "quick": args.quick, "runs": rows}, table(rows), args.json, printed=rows)


if __name__ == "__main__":
    sys.exit(run_main(main))
