"""Which hint-free biped plans the MuJoCo walk replays, against plan.velocity_bounds and the step (issue 9 / 7B).

robots/biped.toml bounds leg 1's angular velocity (torso + hinge_1) from below at every node, so the
stance leg keeps turning forward, as the phase-indexed replay needs (planner.gait.PhaseReference). This runs
`planner plan biped` (hint-free solve, then the 10-step MuJoCo walk) once per lower bound and step
length, on a copy of the default task with only these changed ("none": the bound removed; a step s
also moves the standing guess to feet s apart: hinges -+a, hip height cos a, sin a = s / 2 for the
unit legs), and records per run: exit code, IPOPT iterations, solve time [s], control cost, the
impact's time against the physical period [s], and the walk (steps walked, max torque [N m]) or the
reason it was not walked. Writes OUT/results.json and prints a Markdown table.

    python -m scripts.bench_biped_walk [--lower none 0.1 ... 0.5] [--step 0.25 ...] [--out DIR] [--quick] [--json]

--quick (the CI smoke run): N = 6 steps, no MuJoCo walk, the default bound only. Iterations are
deterministic on one machine; the walls depend on its load.
"""
from __future__ import annotations

import json
import math
import re
import shutil
import sys
import tomllib
from pathlib import Path

from planner.errors import InputError
from planner.result import write_atomically
from scripts._report import drop_results, out_dir, planner_command, refuse_with_quick, report, run_main, script_parser

ROOT = Path(__file__).resolve().parent.parent
TASK = ROOT / "robots" / "biped.toml"
BOUND_LINE = re.compile(r"^velocity_bounds = .*$", re.MULTILINE)
STEP_LINE = re.compile(r"^step = .*$", re.MULTILINE)
GUESS_LINE = re.compile(r"^q = .*$", re.MULTILINE)  # [initial] q: the task's only line that starts so
DEFAULT_STEP = 0.25  # [m] robots/biped.toml's


def task_text(lower: str, step: float = DEFAULT_STEP) -> str:
    """robots/biped.toml with leg 1's lower velocity bound set to `lower` [rad/s] ("none": removed) and,
    for another step [m], plan.periodic.step and the standing guess (feet `step` apart) changed."""
    text = TASK.read_text()
    for name, pattern in (("velocity_bounds", BOUND_LINE), ("step", STEP_LINE), ("q", GUESS_LINE)):
        if len(pattern.findall(text)) != 1:
            raise InputError(f"{TASK} needs exactly one '{name} = ...' line to vary")
    line = "" if lower == "none" else f'velocity_bounds = [{{ joints = ["torso", "hinge_1"], lower = {float(lower)} }}]'
    text = BOUND_LINE.sub(line, text)
    if step != DEFAULT_STEP:
        a = math.asin(step / 2)
        text = STEP_LINE.sub(f"step = {step!r}", text)
        text = GUESS_LINE.sub(f"q = [0.0, {math.cos(a)!r}, 0.0, {-a!r}, {a!r}]", text)
    return text


def check_tasks(pairs: list[tuple[str, float]]) -> None:
    """Each (lower, step)'s task checked against the biped as `planner plan` checks it, before any solve: a refused
    one (e.g. a step whose standing guess breaks the joint bounds) stopped the script after the runs before it, whose
    results were lost."""
    from planner.model import load_robot
    from planner.task import parse_task

    robot = load_robot("biped")
    for lower, step in pairs:
        try:
            parse_task(tomllib.loads(task_text(lower, step)), source=str(TASK)).check_against(robot)
        except InputError as exc:
            raise InputError(f"the task of step {step:g} m, lower {lower} is refused: {exc}") from None


def run(lower: str, step: float, out: Path, quick: bool) -> dict:
    run_dir = out / (f"lower_{lower}" + ("" if step == DEFAULT_STEP else f"_step_{step}"))
    run_dir.mkdir(parents=True, exist_ok=True)
    task = run_dir / "task.toml"
    write_atomically(task, task_text(lower, step))
    shutil.rmtree(run_dir / "plan", ignore_errors=True)  # an earlier run's summary.json would be read as this run's
    argv = ["plan", "biped", "--task", str(task), "--out", str(run_dir / "plan"), "-q"]
    code = planner_command(argv + (["--steps", "6", "--no-validate"] if quick else []))
    plan = run_dir / "plan"
    if not (plan / "summary.json").is_file():  # a solve that did not converge writes to OUT/failed
        plan = plan / "failed"
    if not (plan / "summary.json").is_file():  # exit 2: e.g. a step whose guess breaks the task's joint bounds
        raise InputError(f"planner plan refused the task of step {step:g} m, lower {lower} (exit {code}; its error is above)")
    s = json.loads((plan / "summary.json").read_text())
    v = s.get("validation") or {}
    walk = v.get("walking") or {}
    # the bound a number in the JSON (None: removed), not its command-line text
    return {"lower_rad_s": None if lower == "none" else float(lower), "step_m": step, "exit_code": code,
            "converged": s["converged"], "ipopt_iterations": s["ipopt_iterations"],
            "solve_time_s": s["solve_time_s"], "control_cost": s["control_cost"],
            "physical_period_s": s["physical_duration_s"], "impact_times_s": [i["time"] for i in s["impacts"]],
            "walk_passed": v.get("passed"), "steps_walked": v.get("steps_walked"),
            "max_torque_Nm": walk.get("max_torque_Nm"), "failures": v.get("failures", [])}


def table(rows: list[dict]) -> str:
    lines = ["| lower bound [rad/s] | step [m] | exit | IPOPT it. | solve [s] | cost | impact / period [s] | MuJoCo walk |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        # (planner plan validates converged plans only: a failed solve's row read "refused: the stance-leg angle is
        # not monotonic", a refusal the walk never made)
        walk = ("not validated: the solve did not converge" if not r["converged"] else
                "not run" if r["walk_passed"] is None and r["exit_code"] == 0 else
                f"{r['steps_walked']} of 10, max torque {r['max_torque_Nm']:.0f} N m" if r["steps_walked"] is not None
                else "refused: the stance-leg angle is not monotonic")
        impacts = ", ".join(f"{t:.3f}" for t in r["impact_times_s"]) or "none"
        lower = "none" if r["lower_rad_s"] is None else format(r["lower_rad_s"], "g")
        lines.append(f"| {lower} | {r['step_m']:g} | {r['exit_code']} | {r['ipopt_iterations']} | {r['solve_time_s']:.1f} | "
                     f"{r['control_cost']:.2f} | {impacts} / {r['physical_period_s']:.3f} | {walk} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = script_parser(__doc__)
    parser.add_argument("--lower", nargs="+", default=["none", "0.1", "0.2", "0.3", "0.4", "0.5"],
                        help="lower bounds of leg 1's angular velocity [rad/s], or none (default: none 0.1 ... 0.5)")
    parser.add_argument("--step", type=float, nargs="+", default=[DEFAULT_STEP],
                        help=f"step lengths [m], each with every bound (default {DEFAULT_STEP}: the task's)")
    parser.add_argument("--out", type=out_dir, default=Path("results/bench/biped_walk"),
                        help="output directory (default results/bench/biped_walk)")
    parser.add_argument("--quick", action="store_true", help="CI smoke run: N = 6, no walk, the default bound")
    parser.add_argument("--json", action="store_true", help="print the results as JSON instead of the table")
    args = parser.parse_args(argv)
    refuse_with_quick(parser, args, ["lower"], "the default bound 0.3 rad/s")
    lowers = ["0.3"] if args.quick else args.lower
    for lower in lowers:  # a typo fails here, before any solve
        try:
            if lower != "none" and not float(lower) >= 0:
                raise ValueError
        except ValueError:
            parser.error(f"--lower {lower!r}: give a number >= 0 [rad/s] or none")
    if not all(0 < s < 2 for s in args.step):
        parser.error(f"--step {args.step}: give lengths in (0, 2) m (the legs are 1 m long)")
    pairs = [(lower, step) for step in args.step for lower in lowers]
    runs = [(None if lower == "none" else float(lower), step) for lower, step in pairs]
    if len(set(runs)) != len(runs):  # (the later run deleted the earlier one's plan, two rows for one directory)
        parser.error(f"--lower {' '.join(lowers)} --step {' '.join(map(str, args.step))} name the same run twice: give "
                     "each value once")
    check_tasks(pairs)
    drop_results(args.out)
    rows = [run(lower, step, args.out, args.quick) for lower, step in pairs]
    return report(args.out, {"task": str(TASK), "quick": args.quick, "runs": rows}, table(rows), args.json, printed=rows)


if __name__ == "__main__":
    sys.exit(run_main(main))
