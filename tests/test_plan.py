"""`planner plan`: results, summary contract keys, exit codes; the full Capler task (slow, experimental)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from planner.cli import main

HOP_TASK = """
[[contacts]]
point = "point"
mu = 0.5

[initial]
q = [0.0, 0.0]

[horizon]
tau_f = 1.0
N = 40

[plan]
target_q = [0.5, 0.0]
u_bound = 30.0
"""

CONTRACT = ("command", "robot", "task", "converged", "solve_time_s", "n_nlp", "ipopt_iterations", "complementarity_residual",
            "terminal_error", "physical_duration_s", "impacts", "hops", "nlps")


def test_plan_command_writes_results(tmp_path, capsys):
    """plan --json writes trajectory.npz and summary.json with the contract keys and exits 0."""
    task = tmp_path / "hop.toml"
    task.write_text(HOP_TASK)
    out = tmp_path / "out"
    code = main(["plan", "robots/point_mass.xml", "--task", str(task), "--out", str(out), "--json", "--no-validate"])
    summary = json.loads(capsys.readouterr().out)
    assert code == 0, summary["message"]
    for key in CONTRACT:
        assert key in summary, key
    assert summary["command"] == "plan" and summary["converged"]
    assert summary["complementarity_residual"] <= 1e-6 and summary["terminal_error"] <= 1e-6
    assert all({"rho", "objective", "complementarity_residual", "iterations", "time_s", "status"} <= set(r) for r in summary["nlps"])
    assert summary["control_cost"] > 0  # the task's cost h sum u^T u (not the polish's distance): a hop needs force
    data = np.load(out / "trajectory.npz")
    for key in ("tau", "y", "t", "q", "v", "u", "impact_times"):
        assert key in data.files
    assert json.loads((out / "summary.json").read_text())["converged"]


def test_plan_without_plan_table_is_bad_input(tmp_path, capsys):
    """A task with no [plan] exits 2 with one line on stderr."""
    code = main(["plan", "robots/point_mass.xml", "--out", str(tmp_path / "o")])
    assert code == 2
    assert "plan" in capsys.readouterr().err


@pytest.mark.slow
def test_capler_default_task():
    """The paper's hopper over three holes from the hint-free start (robots/capler.toml, N = 125): the
    plan is exactly complementary (active-set polished), meets the terminal pose to 1e-6, keeps every
    constraint to 1e-6 with the foot outside the holes and never below the ground, and hops at least
    three times. NLP 2 (rho = 1e3) stops at its iteration cap on the way (docs/formulation.md round 4);
    every other NLP converges. Measured 3.6 min of IPOPT on a shared 2-core machine."""
    from planner.homotopy import SolveOptions, solve
    from planner.model import load_robot
    from planner.problem import build_problem
    from planner.task import load_task

    robot, task = load_robot("robots/capler.xml"), load_task("robots/capler.toml")
    prob = build_problem(robot, task)
    res = solve(prob, SolveOptions())
    assert res.stats.converged and res.polished, res.stats.message
    assert [r.label for r in res.nlps if not r.success] in ([], ["homotopy 2"])
    assert res.stats.complementarity_residual <= 1e-6 and res.terminal_error <= 1e-6
    assert max(res.constraint_violation.values()) <= 1e-6
    gaps = [float(np.asarray(prob.system.gap_fn(y, np.zeros(prob.system.nu))).ravel()[0]) for y in res.trajectory.y]
    assert min(gaps) >= -1e-6  # the secant switching velocity: stances do not sink
    assert len(res.hops) >= 3


@pytest.mark.slow
def test_capler_coarse_no_holes_converges():
    """The default recipe on a coarser Capler task (N = 50, h = 0.05, no holes) from the hint-free
    start: every homotopy NLP converges, complementarity and terminal error are <= 1e-6 (reached by
    the homotopy itself since rho = 3e3 is in the schedule, else by the active-set polish), several
    hops (measured 80-90 s, docs/formulation.md rounds 2 and 3)."""
    import dataclasses

    from planner.homotopy import SolveOptions, solve
    from planner.model import load_robot
    from planner.problem import build_problem
    from planner.task import load_task

    robot, task = load_robot("robots/capler.xml"), load_task("robots/capler.toml")
    task = dataclasses.replace(task, plan=dataclasses.replace(task.plan, holes=()),
                               horizon=dataclasses.replace(task.horizon, N=50))
    res = solve(build_problem(robot, task), SolveOptions())
    assert res.stats.converged, res.stats.message
    assert all(r.success for r in res.nlps if r.label.startswith("homotopy"))
    assert res.stats.complementarity_residual <= 1e-6 and res.terminal_error <= 1e-6
    assert len(res.hops) >= 3
