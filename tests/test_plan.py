"""`planner plan`: results, summary contract keys, exit codes; the full Capler task (slow, experimental)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from planner.cli import main
from planner.model import ROBOTS_DIR

HOP_TASK = (ROBOTS_DIR / "point_mass_hop.toml").read_text().replace("\nN = 20\n", "\nN = 40\n")
assert "\nN = 40\n" in HOP_TASK, "robots/point_mass_hop.toml's horizon line changed"

CONTRACT = ("command", "robot", "task", "converged", "solve_time_s", "n_nlp", "ipopt_iterations", "complementarity_residual",
            "terminal_error", "physical_duration_s", "impacts", "hops", "nlps", "versions")


def test_plan_command_writes_results(tmp_path, capsys):
    """plan --json writes trajectory.npz and summary.json with the contract keys and exits 0; its impacts are dated
    where the point first touches the ground."""
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
    # the hop's landings end a flight step at a node (the point at z = 0 moving down there): each impact is dated at
    # that node, where the point first touches (they were dated one step later, with the point already on the ground)
    for impact in summary["impacts"]:
        first = int(np.argmax(data["t"] >= impact["time"] - LANDING_TIME_TOL))
        assert abs(data["q"][first, 1]) <= GROUND_TOL and data["q"][first - 1, 1] > GROUND_TOL, impact["time"]
        assert impact["v_pre"][1] < 0  # the point's z velocity: moving into the ground


def test_plan_without_plan_table_is_bad_input(tmp_path, capsys):
    """A task with no [plan] exits 2 with one line on stderr."""
    code = main(["plan", "robots/point_mass.xml", "--out", str(tmp_path / "o")])
    assert code == 2
    assert "plan" in capsys.readouterr().err


@pytest.mark.slow
def test_capler_default_task(tmp_path):
    """The paper's hopper over three holes from the hint-free start (robots/capler.toml, N = 125): the
    plan is exactly complementary (active-set polished), meets the terminal pose to 1e-6, keeps every
    constraint to 1e-6 with the foot outside the holes and never below the ground, and hops at least
    three times, with Fig. 6's phases (assert_fig6_phases). Every NLP converges, with the task's
    scale_variables (docs/formulation.md rounds 6-7; 2856 iterations, ~1.5 min on a shared 2-core machine).
    scripts/probe_impacts reads each impact's kinetic energies as the plan records them (it took the posture a step
    after a landing dated at a node: 15.38 against 15.39 J on this plan)."""
    from planner.homotopy import SolveOptions, solve
    from planner.model import load_robot
    from planner.problem import build_problem
    from planner.task import load_task

    robot, task = load_robot("robots/capler.xml"), load_task("robots/capler.toml")
    prob = build_problem(robot, task)
    res = solve(prob, SolveOptions())
    assert res.stats.converged and res.polished, res.stats.message
    assert all(r.success for r in res.nlps), [(r.label, r.status) for r in res.nlps]
    assert res.stats.complementarity_residual <= 1e-6 and res.terminal_error <= 1e-6
    assert max(res.constraint_violation.values()) <= 1e-6
    gaps = [float(np.asarray(prob.system.gap_fn(y, np.zeros(prob.system.nu))).ravel()[0]) for y in res.trajectory.y]
    assert min(gaps) >= -1e-6  # the secant switching velocity: stances do not sink
    assert_fig6_phases(res, robot, task, re_sticking=True)
    from planner.result import write_results
    from scripts.probe_impacts import probe

    write_results(res, tmp_path)
    probed = [r["kinetic_energy"] for r in probe(tmp_path)["impacts"]]
    recorded = [[i.kinetic_energy_pre, i.kinetic_energy_post] for i in res.trajectory.impacts]
    assert np.allclose(probed, recorded, rtol=SAME_ENERGY_TOL, atol=0.0), (probed, recorded)


SAME_ENERGY_TOL = 1e-9  # relative: one formula at one posture, up to the rounding of the file's numbers

# Fig. 6 phase checks on the physical-time samples
LANDING_TIME_TOL = 1e-9  # [s] an impact's time and its node's clock are one number, up to rounding
STICK_TOL = 1e-6  # [m] foot displacement that counts as sticking (the plans' stances move it by < 1e-11 m)
GROUND_TOL = 1e-6  # [m] foot height that counts as on the ground (constraints hold to 1e-6)
HOLE_TOL = 1e-6  # ellipse level-set margin: the hole rows hold to the constraint tolerance
HOP_APEX = 0.01  # [m] a hop that counts: the plans also skim the ground between hops (apex ~0-4 mm)


def assert_fig6_phases(res, robot, task, re_sticking: bool):
    """The phases of paper 000's Fig. 6 in a Capler plan's physical-time samples: initial sticking (the
    foot fixed on the ground until the first take-off), contact breaking and flight (at least three hops
    higher than HOP_APEX), the foot outside every hole at every sample, impacts with a normal and a
    tangential jump, and (re_sticking) the foot fixed on the ground again after the last landing."""
    from planner.dynamics import Dynamics

    tr = res.trajectory
    pos = Dynamics(robot).point_position("foot")
    foot = np.array([np.asarray(pos(q), float).ravel() for q in tr.q])
    for hole in task.plan.holes:
        level = ((foot[:, 0] - hole.x) / hole.a) ** 2 + ((foot[:, 2] - hole.z) / hole.b) ** 2
        assert level.min() >= 1 - HOLE_TOL, f"foot inside the hole at x = {hole.x}"
    assert sum(h.apex > HOP_APEX for h in res.hops) >= 3
    # the contact breaks at the first flight phase, a skim along the ground too (extra["skims"], no hops since session
    # 60), and is made again at the last
    skims = res.extra.get("skims", [])
    first = min([h.takeoff_time for h in res.hops] + [s["takeoff_time"] for s in skims])
    last = max([h.landing_time for h in res.hops] + [s["landing_time"] for s in skims])
    before = tr.t <= first + 1e-9
    assert before.sum() >= 2 and np.ptp(foot[before], axis=0).max() <= STICK_TOL and foot[before, 2].max() <= GROUND_TOL
    assert any(imp.impulse > 0 and abs(imp.impulse_tangential) > 0 for imp in tr.impacts)
    if re_sticking:
        after = tr.t >= last - 1e-9
        assert after.sum() >= 2 and np.ptp(foot[after], axis=0).max() <= STICK_TOL and foot[after, 2].max() <= GROUND_TOL


@pytest.mark.slow
def test_capler_coarse_with_holes_every_nlp_converges_and_shows_fig6_phases():
    """The default recipe on the default scene at a coarser grid (N = 50, h = 0.05, the three holes)
    from the hint-free start: every NLP of the homotopy and the polish converges (none at its cap),
    complementarity and terminal error <= 1e-6, every constraint <= 1e-6, and the physical-time
    trajectory shows Fig. 6's phases (assert_fig6_phases; this plan lands at the horizon's end, so
    re-sticking is checked on the full task). Measured 66 s, 5015 iterations, 14 hops."""
    import dataclasses

    from planner.homotopy import SolveOptions, solve
    from planner.model import load_robot
    from planner.problem import build_problem
    from planner.task import load_task

    robot, task = load_robot("robots/capler.xml"), load_task("robots/capler.toml")
    task = dataclasses.replace(task, horizon=dataclasses.replace(task.horizon, N=50))
    res = solve(build_problem(robot, task), SolveOptions())
    assert res.stats.converged and res.polished, res.stats.message
    assert all(r.success for r in res.nlps), [(r.label, r.status) for r in res.nlps]
    assert res.stats.complementarity_residual <= 1e-6 and res.terminal_error <= 1e-6
    assert max(res.constraint_violation.values()) <= 1e-6
    assert_fig6_phases(res, robot, task, re_sticking=False)


FESD_N = 100  # the hint-free FESD plan converges at N = 50 (through the soft-terminal retry), 75, 100 and 125; 100 is the quickest
ON_GROUND_TOL = 1e-6  # [m] the foot's height at an FESD impact's start: the switch is an element boundary (rows to 1e-8)


@pytest.mark.slow
def test_capler_fesd_plan_from_the_hint_free_start():
    """`planner plan capler --discretization fesd --stages 1 --elements 2 --steps 100` through the API:
    FESD's own homotopy from the hint-free start converges (complementarity and terminal error <= 1e-6,
    every constraint <= 1e-6), the plan shows Fig. 6's phases, and every impact starts with the foot on
    the ground to ON_GROUND_TOL: switch detection puts the landing on an element boundary, where
    implicit Euler lands inside a step. 266 s here (session 9; the CLI run: 261 s, 4985 iterations, docs/benchmarks.md)."""
    import dataclasses

    from planner.cli import FESD_RHO_MAX
    from planner.discretization import Discretization, FESDOptions
    from planner.dynamics import Dynamics
    from planner.homotopy import SolveOptions, solve
    from planner.model import load_robot
    from planner.problem import ProblemOptions, build_problem
    from planner.task import load_task

    robot, task = load_robot("robots/capler.xml"), load_task("robots/capler.toml")
    task = dataclasses.replace(task, horizon=dataclasses.replace(task.horizon, N=FESD_N))
    options = ProblemOptions(discretization=Discretization.FESD, fesd=FESDOptions(n_s=1, n_fe=2))
    res = solve(build_problem(robot, task, options), SolveOptions(rho_max=FESD_RHO_MAX))
    assert res.stats.converged and res.polished, res.stats.message
    assert res.stats.complementarity_residual <= 1e-6 and res.terminal_error <= 1e-6
    assert max(res.constraint_violation.values()) <= 1e-6
    assert_fig6_phases(res, robot, task, re_sticking=False)
    foot = Dynamics(robot).point_position("foot")
    heights = [float(np.asarray(foot(imp.q)).ravel()[-1]) for imp in res.trajectory.impacts]
    assert heights and max(abs(z) for z in heights) <= ON_GROUND_TOL, heights
