"""Smoke tests of the benchmark scripts (scripts/): a quick run writes its files with the documented
fields. No timing assertions: the machine is shared, wall times are only recorded."""
from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import json
import math
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from planner import homotopy as H
from planner.errors import InputError
from planner.model import load_robot
from planner.problem import build_problem
from planner.task import load_task
from scripts._report import run_main

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


def _load(name: str):
    """Import scripts/NAME.py by path: scripts/ is not a package of the installed distribution."""
    spec = importlib.util.spec_from_file_location(name, SCRIPTS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up while the class is built
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def bench():
    return _load("bench_work_precision")


def test_work_precision_quick_run(bench, tmp_path, capsys):
    """--quick --json: results.json holds the machine, one converged record per run of every case with
    its grid, options, wall time and errors, and the convergence orders; the plot is a PNG; stdout is
    the JSON summary."""
    assert bench.main(["--quick", "--json", "--out", str(tmp_path)]) == 0
    summary = json.loads(capsys.readouterr().out)
    results = json.loads((tmp_path / "results.json").read_text())
    assert summary["n_records"] == len(results["records"]) and summary["n_failed"] == 0

    machine = results["machine"]
    for key in ("platform", "cpu_count", "python", "casadi", "pinocchio", "mujoco", "date", "load_average_before"):
        assert machine[key] is not None, key

    records = results["records"]
    assert {r["case"] for r in records} == {*bench.CASE_NAMES, "capler_pd_drop_mujoco"}
    for r in records:
        for key in ("case", "variant", "simulator", "h", "N", "options", "wall_time_s", "errors", "converged"):
            assert key in r, (key, r["case"])
        assert r["converged"] and r["wall_time_s"] > 0
    for r in records:
        if r["case"].startswith("pm_"):
            assert r["window_covered"], (r["case"], r["variant"], r["h"])  # --quick horizons reach the window
            assert r["errors"]["state_error_m"] > 0 and r["errors"]["impact_time_error_s"] is not None
            assert r["errors"]["penetration_m"] is not None
        elif r["simulator"] == "time-freezing":  # Capler: against the fine grid and MuJoCo
            for key in ("base_error_ref_m", "base_error_mujoco_m", "impact_time_diff_ref_s", "impact_time_diff_mujoco_s"):
                assert r["errors"][key] is not None, key
    assert {(r["case"], r["variant"]) for r in records if r["case"] == "pm_drop_frictionless"} >= {
        ("pm_drop_frictionless", "default"), ("pm_drop_frictionless", "horizon"), ("pm_drop_frictionless", "fesd n_s=2")}
    assert len({r["h"] for r in records if r["case"] == "pm_drop_noslip"}) == 2  # --quick: 2 grid points
    assert all(math.isfinite(o["order"]) for o in results["orders"]) and results["orders"]
    assert (tmp_path / "work_precision.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# MuJoCo's landing within this share of a step of the plan's, in the windows: 0.01-0.02 h measured, so a landing dated
# one step late (0.39 h before session 48) fails
WINDOW_LANDING_SHARE = 0.1


def test_work_precision_ocp_quick_run(bench, tmp_path, capsys):
    """--suite ocp --quick --json: the point-mass hop planned at N = 20 and 40 (no Capler), one record
    per N with wall time, IPOPT iterations, convergence, hops and impacts, and finite errors: the
    re-simulation defect, MuJoCo tracking, penetration, terminal error and the exact flight. The
    landing time error against the exact flight falls from N = 20 to 40 (measured 2.2e-2 and 1.15e-2 s:
    different local optima, one and two hops, but both land with implicit Euler's O(h) error). Every
    planned impact is a landing for MuJoCo started 25-50 ms before it, within WINDOW_LANDING_SHARE of a step of the
    plan (measured 0.49 and 0.51 ms, 0.01 h and 0.02 h, since session 48 dates a landing at a node there; 0.39 h and
    0.13 h before, one step late)."""
    assert bench.main(["--suite", "ocp", "--quick", "--json", "--out", str(tmp_path)]) == 0
    summary = json.loads(capsys.readouterr().out)
    results = json.loads((tmp_path / "results.json").read_text())
    assert results["suite"] == "ocp" and summary["n_records"] == len(results["records"]) == 2
    assert results["machine"]["cpu_count"] and results["machine"]["date"]
    records = sorted(results["records"], key=lambda r: r["N"])
    assert [(r["case"], r["N"]) for r in records] == [("ocp_pm_hop", 20), ("ocp_pm_hop", 40)]
    for r in records:
        for key in ("h", "wall_time_s", "ipopt_iterations", "converged", "hops", "n_impacts", "defect", "flight"):
            assert r.get(key) is not None, (key, r["N"])
        assert r["converged"] and r["wall_time_s"] > 0 and r["ipopt_iterations"] > 0
        for key in ("defect_base_m", "tracking_error_m", "tracking_window_mean_m", "penetration_m", "terminal_error", "flight_error_m", "landing_time_error_s"):
            assert r["errors"][key] is not None and math.isfinite(r["errors"][key]), (key, r["N"])
        assert r["defect"]["windows"] >= 5 and r["defect"]["failed_windows"] == []
        assert r["window_impacts_landed"] == [r["n_impacts"], r["n_impacts"]]
        assert r["errors"]["window_impact_time_error_s"] <= WINDOW_LANDING_SHARE * r["h"]
    assert records[1]["errors"]["landing_time_error_s"] < records[0]["errors"]["landing_time_error_s"]
    assert (tmp_path / "work_precision.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_work_precision_contact_phase_interpolation_and_exact_flight(bench, tmp_path, capsys):
    """--quick: post_impact_error_m shows the no-slip stop position off by more than 1 mm at both h (5.2e-2 and 1.2e-2
    m measured) where the frictionless slide is exact (<= ERROR_FLOOR), though both have the same state_error_m (the
    free-fall lead before the landing); interpolated_error_m is never below the samples' error, and for FESD n_s = 2
    (exact at its element ends) it is the chord error g dt^2 / 8 of the elements dt = h / 3 (2.18e-4 and 5.45e-5 m);
    flight_error_exact_m is there for every Capler run and reference, the implicit-Euler fine grid's above
    ERROR_FLOOR (a reference that lags the exact flight as the runs do), MuJoCo's halving with its timestep."""
    assert bench.main(["--quick", "--json", "--out", str(tmp_path)]) == 0
    capsys.readouterr()
    results = json.loads((tmp_path / "results.json").read_text())
    recs = results["records"]

    def errors(case, variant="default"):
        return {r["h"]: r["errors"] for r in recs if (r["case"], r["variant"]) == (case, variant)}

    slide, stop = errors("pm_drop_frictionless"), errors("pm_drop_noslip")
    assert sorted(slide) == sorted(stop) == [0.02, 0.04]
    for h in slide:
        assert slide[h]["state_error_m"] == pytest.approx(stop[h]["state_error_m"], rel=1e-3)
        assert slide[h]["post_impact_error_m"] <= bench.ERROR_FLOOR < 1e-3 < stop[h]["post_impact_error_m"]
    for r in recs:
        if r["case"].startswith("pm_"):
            assert r["errors"]["interpolated_error_m"] >= r["errors"]["state_error_m"], (r["case"], r["variant"])
    for h, e in errors("pm_drop_frictionless", "fesd n_s=2").items():
        assert e["state_error_m"] < bench.ERROR_FLOOR
        assert e["interpolated_error_m"] == pytest.approx(bench.G * (h / 3) ** 2 / 8, rel=0.05), h
    for r in recs:
        if r["case"].startswith("capler_"):
            assert r["errors"]["flight_error_exact_m"] is not None, (r["case"], r["h"])
    refs = results["references"]
    assert refs["capler_reference"]["flight_error_exact_m"] > bench.ERROR_FLOOR
    assert refs["capler_mujoco"]["flight_error_exact_m"] is not None
    mj = sorted((r["h"], r["errors"]["flight_error_exact_m"]) for r in recs if r["case"] == "capler_pd_drop_mujoco")
    assert mj[0][1] == pytest.approx(mj[1][1] / 2, rel=0.1)


def test_interpolated_error_reads_between_the_samples(bench):
    """interpolated_error joins the samples by straight lines: exact free-fall samples every dt have the chord error
    g dt^2 / 8 between them (the samples none); an impact's repeated time with two postures (the pre-impact sample 7 mm
    up, then the landing at z = 0, 1.15e-2 s before the exact impact) joins each interval's own samples, so the
    landing sample's error (the larger, 5.0e-2 m) counts: reading one posture per time had dropped it (4.3e-2 m)."""
    drop = bench.Drop(z0=1.0)
    dt = 0.04
    t = np.arange(0.0, 0.4, dt)
    assert bench.interpolated_error(t, drop.q(t), drop, 0.4) == pytest.approx(bench.G * dt**2 / 8, rel=1e-9)
    t2 = np.array([0.42, 0.44, 0.44, 0.46])
    q2 = np.column_stack([np.zeros(4), [drop.q(t2[:1])[0, 1], 0.007, 0.0, 0.0]])
    assert bench.interpolated_error(t2, q2, drop, 0.5) == pytest.approx(drop.q(t2[1:2])[0, 1], rel=1e-9)


def test_window_errors_reports_mean_median_and_worst(bench):
    """The windowed MuJoCo tracking goes to the JSON as mean, median and worst window (one bad window shows in the
    worst, not in the median); a report without windows gives None, not 0.0 (read as perfect tracking)."""
    from planner.replay import WindowReport

    report = WindowReport(window_s=0.1, stride_s=0.025, starts_s=(0.0, 0.025, 0.05),
                          max_base_error_m=(1e-3, 2e-3, 9e-3), diverged=False)
    assert bench.window_errors(report) == pytest.approx(
        {"tracking_window_mean_m": 4e-3, "tracking_window_median_m": 2e-3, "tracking_window_worst_m": 9e-3})
    empty = WindowReport(window_s=0.1, stride_s=0.025, starts_s=(), max_base_error_m=(), diverged=False)
    assert set(bench.window_errors(empty).values()) == {None}


def test_resimulation_defect_of_no_measured_window_is_none(bench, monkeypatch):
    """A plan whose windows all simulate nothing past their start (here every simulation stops at once) has no
    re-simulation defect: None, not 0.0, which the table and the plot read as a perfect re-simulation."""
    from types import SimpleNamespace

    from planner.dynamics import Dynamics

    robot, task = load_robot("point_mass"), load_task(Path("robots") / "point_mass_hop.toml")
    stopped = SimpleNamespace(stats=SimpleNamespace(converged=False), trajectory=SimpleNamespace(t=np.zeros(1)))
    monkeypatch.setattr(bench, "simulate", lambda *args, **kwargs: stopped)
    traj = SimpleNamespace(t=np.linspace(0.0, 0.1, 3), q=np.zeros((3, 2)), v=np.zeros((3, 2)), u=np.zeros((3, 2)))
    defect = bench.resimulation_defect(robot, Dynamics(robot), task, traj, scene=None)
    assert defect["defect_base_m"] is None and defect["defect_points_m"] is None and defect["windows"] == 1


def test_open_loop_schedule_replays_the_plan_controls(bench):
    """The plan's zero-order-hold controls (u[i] acts on [t[i-1], t[i]), an impact repeats a time)
    become a simulate.schedule in the window's own clock: the piece running at the window start
    comes first at t = 0, impacts hold no piece."""
    t = np.array([0.0, 0.1, 0.2, 0.2, 0.3])
    u = np.array([[0.0], [1.0], [2.0], [9.0], [3.0]])
    starts, controls = bench.control_pieces(t, u)
    np.testing.assert_allclose(starts, [0.0, 0.1, 0.2])
    np.testing.assert_allclose(controls.ravel(), [1.0, 2.0, 3.0])
    sched = bench.open_loop_schedule(t, u, 0.15, 0.3)
    assert [(c.t, c.u) for c in sched] == [(0.0, (2.0,)), (pytest.approx(0.05), (3.0,))]
    from planner.task import Simulate

    sim = Simulate(schedule=sched)
    assert sim.controls_at(0.01, 1)[0] == 2.0 and sim.controls_at(0.06, 1)[0] == 3.0


def test_exact_flight_of_an_exact_parabola(bench):
    """A point mass leaving the ground at v = (1, 2) m/s with u = 0, sampled exactly every 0.05 s and
    landing (an impact pair) at 4 / g: flight error ~0 and landing time error ~0; the same samples
    with the impact reported 0.01 s late give a landing time error of 0.01 s. A trajectory whose
    only impact is at rest (no sample above the ground before it) has no flight."""
    from types import SimpleNamespace

    from planner.dynamics import Dynamics

    robot = load_robot("point_mass")
    dyn, task = Dynamics(robot), bench.point_mass_hop_task(20)
    g, land = bench.G, 4.0 / bench.G
    ts = np.append(np.arange(0.0, land, 0.05), [land, land])
    q = np.column_stack([ts, 2 * ts - g * ts**2 / 2])
    q[-2:, 1] = 0.0
    v = np.column_stack([np.ones_like(ts), 2 - g * ts])
    v[-1] = 0.0
    traj = SimpleNamespace(t=ts, q=q, v=v, u=np.zeros((len(ts), 2)), impacts=(SimpleNamespace(time=land),))
    out = bench.exact_flight(robot, dyn, task, traj)
    assert out["flight_error_m"] < 1e-12 and out["landing_time_error_s"] < 1e-12 and out["flight_samples"] == len(ts) - 3
    late = SimpleNamespace(**{**vars(traj), "t": np.append(ts[:-2], [land + 0.01] * 2), "impacts": (SimpleNamespace(time=land + 0.01),)})
    assert bench.exact_flight(robot, dyn, task, late)["landing_time_error_s"] == pytest.approx(0.01)
    rest = SimpleNamespace(t=np.array([0.0, 0.1, 0.1]), q=np.zeros((3, 2)), v=np.zeros((3, 2)), u=np.zeros((3, 2)),
                           impacts=(SimpleNamespace(time=0.1),))
    assert bench.exact_flight(robot, dyn, task, rest) is None


def test_drop_exact_solution(bench):
    """The benchmark's ground truth: impact at sqrt(2 z0 / g); frictionless the mass slides on at vx,
    no-slip it stops; elastic bounces reach eps^(2k) z0 and leave at eps times the impact speed."""
    g = bench.G
    inelastic = bench.Drop(z0=1.0, vx=1.0)
    t1 = math.sqrt(2 / g)
    assert inelastic.impact_time == pytest.approx(t1)
    np.testing.assert_allclose(inelastic.q([0.0, t1, 1.0]), [[0.0, 1.0], [t1, 0.0], [1.0, 0.0]], atol=1e-12)
    np.testing.assert_allclose(bench.Drop(z0=1.0, vx=1.0, no_slip=True).q([1.0]), [[t1, 0.0]])
    np.testing.assert_allclose(bench.Drop(z0=1.0, vx=1.0, no_slip=True).v_post, [0.0, 0.0])
    bounce = bench.Drop(z0=1.0, restitution=0.5)
    np.testing.assert_allclose(bounce.v_post, [0.0, 0.5 * g * t1])
    t = np.linspace(0.0, 2.0, 200001)
    z = bounce.q(t)[:, 1]
    t2 = t1 + 2 * 0.5 * g * t1 / g  # second impact
    assert z[(t > t1) & (t < t2)].max() == pytest.approx(0.25, abs=1e-6)
    assert z[t > t2].max() == pytest.approx(0.0625, abs=1e-6)
    assert z.min() >= 0.0


# --- scripts/stress.py ---------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def stress():
    return _load("stress")


def test_stress_generator_is_seeded(stress):
    """A seed gives the same task list every time, a family's tasks do not depend on the other families
    run (nor on a family named twice: it ran twice under the same ids), another seed gives other tasks, and every
    generated task is a valid task for its robot."""
    from planner.task import parse_task

    a = stress.generate(3, per_family=2, robot="point_mass", N=20)
    assert a == stress.generate(3, per_family=2, robot="point_mass", N=20)
    assert [s["id"] for s in a] == [f"{f}-{k:02d}" for f in stress.FAMILIES for k in range(2)]
    assert [s for s in a if s["family"] == "torque"] == stress.generate(3, ["torque"], 2, "point_mass", 20)
    assert stress.generate(3, ["torque", "torque"], 2, "point_mass", 20) == stress.generate(3, ["torque"], 2, "point_mass", 20)
    assert a != stress.generate(4, per_family=2, robot="point_mass", N=20)
    json.dumps(a)  # plain data: results.json keeps each task
    for robot in ("point_mass", "capler"):
        r = load_robot(f"robots/{robot}.xml")
        for spec in stress.generate(0, per_family=3, robot=robot):
            parse_task(spec["task"]).check_against(r)
    with pytest.raises(stress.InputError, match="unknown family"):
        stress.generate(0, ["nope"])
    with pytest.raises(stress.InputError, match="--max-iter must be >= 1, got 0"):
        stress.generate(0, solve_options={"max_iter": 0})


def test_stress_homotopy_family_keeps_the_base_tasks_other_homotopy_keys(stress):
    """The homotopy family draws rho0, kappa and n_nlp and keeps the rest of the base task's [plan.homotopy]: Capler's
    scale_variables = true (it was dropped, so each of those tasks also ran the unscaled solve)."""
    for spec in stress.generate(0, ["homotopy"], 2, "capler"):
        hom = spec["task"]["plan"]["homotopy"]
        assert hom["scale_variables"] is True and set(hom) >= {"rho0", "kappa", "n_nlp"}


def test_stress_point_mass_impacts_within_the_friction_cone_and_torque_expectations(stress):
    """The point-mass tasks keep a_t <= mu a_n (an impact's tangential impulse within mu times its normal
    one: MuJoCo's Coulomb contact), Capler keeps the paper's a_t = 600; point-mass torque bounds below
    mu m g / (1 + mu) (3.27 N) are expected infeasible, the others make no claim; Capler makes none."""
    for spec in stress.generate(0, per_family=8, robot="point_mass"):
        c = spec["task"]["contacts"][0]
        if c["mu"] > 0:
            assert c["a_t"] <= c["mu"] * c["a_n"] * (1 + 1e-12), spec["id"]
        if spec["family"] == "torque":
            below = spec["task"]["plan"]["u_bound"] <= 0.5 * 9.81 / 1.5  # can neither lift off nor slide
            assert spec["expect"] == ("infeasible" if below else "feasible?"), spec["id"]
    assert any(s["expect"] == "infeasible" for s in stress.generate(0, ["torque"], 8, "point_mass"))
    for spec in stress.generate(0, ["friction", "torque"], 8, "capler"):
        assert spec["task"]["contacts"][0]["a_t"] == 600.0 and spec["expect"] == "feasible?", spec["id"]


def test_stress_summary_rates_count_only_feasible_tasks(stress):
    """The valid rate is over the tasks not expected infeasible; an expected-infeasible task that is not
    diagnosed (converged, valid or not, or crashed) is unexpected."""
    def rec(family, expect, outcome):
        return stress.finish({"id": family, "family": family, "index": 0, "seed": 0, "base": "point_mass", "expect": expect,
                              "params": {}, "task": {}},
                             {"id": family, "family": family, "index": 0, "seed": 0, "base": "point_mass", "expect": expect,
                              "params": {}, "outcome": outcome, "nonfinite": [], "times": {}})
    records = [rec("a", "feasible?", stress.CONVERGED_VALID), rec("b", "feasible?", stress.CONVERGED_INVALID),
               rec("c", "infeasible", stress.DIAGNOSED), rec("d", "infeasible", stress.CONVERGED_INVALID)]
    assert [r["unexpected"] for r in records] == [False, False, False, True]
    rates = stress.summarize(records)["rates"]
    assert rates == {"feasible": 2, "feasible_valid": 1, "infeasible": 2, "infeasible_diagnosed": 1, "feasible_valid_pct": 50.0}
    assert "1 of 2 converged and valid (50.0 %); expected infeasible: 1 of 2 diagnosed" in stress.markdown(
        stress.summarize(records), records, "h")


def test_stress_initial_state_families(stress):
    """Standing and at-contact start with the foot at gap 0, grazing within (0, 1e-4] m, penetrating
    within [-1e-9, 0) m, airborne well above."""
    b = stress.base_task("capler")
    for spec in stress.generate(1, [f for f in stress.FAMILIES if f.startswith("init_")], 3, "capler"):
        gap = b.foot_height(spec["task"]["initial"]["q"])
        fam = spec["family"]
        if fam in ("init_standing", "init_contact"):
            assert abs(gap) <= 1e-12, spec["id"]
        elif fam == "init_grazing":
            assert 0 < gap <= 1.0001e-4, spec["id"]
        elif fam == "init_penetrating":
            assert -1e-9 <= gap < 0, spec["id"]
        else:
            assert gap >= 0.02 - 1e-12, spec["id"]


def test_stress_reduced_run(stress, tmp_path, capsys):
    """Every family on the point mass (1 task each, N = 20, <= 300 IPOPT iterations per NLP) in two local
    processes: no crash, each outcome one of the four classes, the out-of-reach target diagnosed, the
    files written; a validated task records its windowed MuJoCo numbers (docs/validation.md)."""
    code = stress.main(["--robot", "point_mass", "--per-family", "1", "--N", "20", "--max-iter", "300", "--workers", "2",
                        "--seed", "0", "--out", str(tmp_path), "--json"])
    summary = json.loads(capsys.readouterr().out)
    results = json.loads((tmp_path / "results.json").read_text())
    records = results["records"]
    assert code == 0 and summary["n_tasks"] == len(records) == len(stress.FAMILIES)
    for r in records:
        assert r["outcome"] in stress.OUTCOMES, r["id"]
        assert r["outcome"] != stress.CRASHED, (r["id"], r["stage"], r["message"], r.get("traceback"))
        assert r["nonfinite"] == [], r["id"]
        if r["outcome"] == stress.DIAGNOSED:
            assert r["message"], r["id"]
        if r["outcome"] != stress.DIAGNOSED:
            assert "validation" in r and r["validation"]["passed"] == (r["outcome"] == stress.CONVERGED_VALID)
            landed, planned = r["validation"]["window_impacts_landed"]  # every impact timed in the windows
            assert planned == r["impacts"] and 0 <= landed <= planned and r["validation"]["window_mean_m"] >= 0
    infeasible = [r for r in records if r["expect"] == "infeasible"]
    assert {r["family"] for r in infeasible} == {"infeasible"}  # torque-00: 5.3 N, above 3.27 N: it may slide
    assert all(r["outcome"] == stress.DIAGNOSED and not r["unexpected"] for r in infeasible), infeasible
    assert summary["total"]["tasks"] == len(records) and summary["total"][stress.CRASHED] == 0
    assert sum(summary["total"][o] for o in stress.OUTCOMES) == len(records)
    assert len((tmp_path / "records.jsonl").read_text().splitlines()) == len(records)
    assert not (tmp_path / "records.partial.jsonl").exists()  # renamed to records.jsonl once the run is done
    md = (tmp_path / "summary.md").read_text()
    assert "| **all** | 14 |" in md and "init_grazing" in md and "MuJoCo windows" in md


def test_stress_race_solves_each_task_as_planner_plan_does(stress, tmp_path, capsys):
    """--race: each task is the race of planner.race.default_arms on two CPUs (its record lists both arms, the
    winner's iterations are the record's), one task per two CPUs unless --workers says otherwise; without it
    the record has no race, and results.json names the processes used."""
    from planner.race import usable_cpus

    if usable_cpus() < 2:
        pytest.skip("a race needs two CPUs (with one, planner.race solves the first arm alone)")
    argv = ["--robot", "point_mass", "--families", "friction", "--per-family", "1", "--N", "20", "--max-iter", "300",
            "--seed", "0", "--json"]
    assert stress.main(argv + ["--race", "--out", str(tmp_path / "race")]) == 0
    capsys.readouterr()
    results = json.loads((tmp_path / "race" / "results.json").read_text())
    assert results["race"] is True and results["workers"] == max(1, usable_cpus() // 2)
    (rec,) = results["records"]
    assert rec["outcome"] != stress.CRASHED, rec.get("traceback")
    arms = {a["arm"]: a for a in rec["race"]}
    assert set(arms) == {"default", "alternate"}
    won = [a for a in arms.values() if a["outcome"] == "won"]
    assert len(won) == 1 and won[0]["iterations"] == rec["ipopt_iterations"]
    assert stress.main(argv + ["--out", str(tmp_path / "plain")]) == 0
    capsys.readouterr()
    plain = json.loads((tmp_path / "plain" / "results.json").read_text())
    assert plain["race"] is False and "race" not in plain["records"][0]
    assert plain["workers"] == 1  # the processes run_batch used for the one task (null was recorded)


def _one(stress):
    """A task that converges in ~2 s: the frictionless point-mass hop (friction-00), N = 20."""
    spec = stress.generate(0, ["friction"], 1, "point_mass", N=20, solve_options={"max_iter": 300})[0]
    assert spec["params"]["mu"] == 0.0
    return spec


def test_stress_nan_in_build_is_a_crash_at_build(stress, monkeypatch):
    """A NaN in the built problem's initial guess is caught before the solve: crashed at stage build."""
    import planner.problem

    real = planner.problem.build_problem

    def nan_x0(*args, **kwargs):
        problem = real(*args, **kwargs)
        problem.x0[3] = np.nan
        return problem

    monkeypatch.setattr(planner.problem, "build_problem", nan_x0)
    spec = _one(stress)
    rec = stress.finish(spec, stress.run_batch(stress.run_task, [spec], workers=0)[0])
    assert rec["outcome"] == stress.CRASHED and rec["stage"] == "build"
    assert "x0: 1 NaN" in rec["message"] and rec["nonfinite"][0]["stage"] == "build"


def test_stress_nan_in_recovery_is_never_silent(stress, monkeypatch):
    """A NaN injected into the recovered trajectory of a converged solve: crashed at stage recovery."""
    import planner.homotopy

    real = planner.homotopy.element_trajectory

    def nan_q(*args, **kwargs):
        traj = real(*args, **kwargs)
        q = traj.q.copy()  # a Trajectory's arrays are read-only
        q[2, 0] = np.nan
        return dataclasses.replace(traj, q=q)

    monkeypatch.setattr(planner.homotopy, "element_trajectory", nan_q)
    spec = _one(stress)
    rec = stress.finish(spec, stress.run_batch(stress.run_task, [spec], workers=0)[0])
    assert rec["outcome"] == stress.CRASHED and rec["stage"] == "recovery", rec["message"]
    assert "q: 1 NaN" in rec["message"]


def test_stress_nan_in_an_nlp_is_reported_with_its_stage(stress, monkeypatch):
    """A NaN objective reported by one NLP of the homotopy is listed with that NLP's label, whatever
    the outcome."""
    import dataclasses

    import planner.homotopy

    real = planner.homotopy._run

    def nan_objective(*args, **kwargs):
        x, lam_x, lam_g, rec = real(*args, **kwargs)
        if rec.label == "homotopy 2":
            rec = dataclasses.replace(rec, objective=float("nan"))
        return x, lam_x, lam_g, rec

    monkeypatch.setattr(planner.homotopy, "_run", nan_objective)
    spec = _one(stress)
    rec = stress.finish(spec, stress.run_batch(stress.run_task, [spec], workers=0)[0])
    assert rec["outcome"] in stress.OUTCOMES
    assert {"stage": "homotopy 2", "what": "objective: 1 NaN, 0 Inf of 1", "status": "Solve_Succeeded"} in rec["nonfinite"]


def test_stress_exception_is_a_crash_with_its_stage(stress, monkeypatch):
    """An exception inside the MuJoCo validation: crashed at stage validation, with the traceback."""
    import planner.replay

    def boom(*args, **kwargs):
        raise RuntimeError("MuJoCo exploded")

    monkeypatch.setattr(planner.replay, "validate_trajectory", boom)
    spec = _one(stress)
    rec = stress.finish(spec, stress.run_batch(stress.run_task, [spec], workers=0)[0])
    assert rec["outcome"] == stress.CRASHED and rec["stage"] == "validation"
    assert rec["message"] == "RuntimeError: MuJoCo exploded" and "boom" in rec["traceback"]


@pytest.mark.slow
def test_stress_capler_reduced_run(stress, tmp_path, capsys):
    """Capler at N = 20, <= 200 IPOPT iterations per NLP, one task each of the penetrating start and the
    out-of-reach target (1-3 min): no crash, no NaN, the out-of-reach target diagnosed. The full Capler
    sweep is `python -m scripts.stress` (docs/stability.md)."""
    stress.main(["--robot", "capler", "--families", "init_penetrating", "infeasible", "--per-family", "1", "--N", "20",
                 "--max-iter", "200", "--workers", "1", "--out", str(tmp_path), "--json"])
    records = json.loads((tmp_path / "results.json").read_text())["records"]
    assert len(records) == 2 and all(r["outcome"] in stress.OUTCOMES for r in records)
    assert [r["id"] for r in records if r["outcome"] == stress.CRASHED] == []
    assert all(r["nonfinite"] == [] for r in records)
    assert next(r for r in records if r["family"] == "infeasible")["outcome"] == stress.DIAGNOSED

# --------------------------------------------------------------------------------------------------
# scripts/bench_nosnoc.py: nosnoc is an optional dependency (pip install nosnoc); the parts that do
# not need it run always, the solve only where it is installed
# --------------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def bench_nosnoc():
    return _load("bench_nosnoc")


def test_bench_nosnoc_task_and_arguments(bench_nosnoc):
    """The nosnoc side reads the numbers of robots/capler.toml; --quick is N = 25 without holes; the
    defaults are the task's grid (one implicit-Euler finite element per step) and both variants."""
    b = bench_nosnoc
    task = b.load_capler_task()
    assert (task.N, task.tau_f, task.h) == (125, 2.5, 0.02)
    assert task.q0 == (0.0, 0.4, 0.0, 0.0) and task.q_target == (3.0, 0.4, 0.0, 0.0)
    assert (task.mu, task.a_n, task.a_t, task.u_max) == (0.8, 200.0, 600.0, 60.0)
    assert [(h.x, h.a, h.b) for h in task.holes] == [(0.5, 0.25, 0.1), (1.5, 0.25, 0.1), (2.5, 0.25, 0.1)]
    assert math.isclose(task.hip_bounds[1], 3 * math.pi / 8) and math.isclose(task.knee_bounds[0], -math.pi / 2)
    assert (task.sigma0, task.kappa, task.n_nlp) == (1.0, 10.0, 5)
    quick = b.quick_task(task)
    assert quick.N == 25 and quick.holes == () and quick.q_target == task.q_target

    args = b.parse_args([])
    assert (args.quick, args.planner, args.json, args.n_fe, args.n_s, args.a_t) == (False, False, False, 1, 1, None)
    assert args.variants == ["hint-free", "hint"] and args.out == b.DEFAULT_OUT
    args = b.parse_args(["--quick", "--planner", "--variants", "hint", "--out", "x"])
    assert args.quick and args.planner and args.variants == ["hint"] and str(args.out) == "x"
    with pytest.raises(SystemExit):
        b.parse_args(["--n-fe", "0"])
    # nosnoc's settings with only the planner running: refused (recorded in the command, and unread)
    with pytest.raises(SystemExit):
        b.parse_args(["--planner", "--variants", "--max-iter", "7"])
    assert b.parse_args(["--planner", "--variants"]).variants == []


def test_bench_nosnoc_model_and_hint(bench_nosnoc):
    """The benchmark's own Capler model (CasADi only) has design.md's check values, and the example's
    hop-per-metre spline hint starts at q0, ends at the target and clears the holes at the apexes."""
    import casadi as ca

    b = bench_nosnoc
    cap = b.capler_model(ca)
    f = ca.Function("f", [cap["q"], cap["v"]], [cap["M"], cap["bias"], cap["foot"]])
    M, bias, foot = (np.asarray(a) for a in f([0.0, 0.4, 0.0, 0.0], np.zeros(4)))
    assert M[0, 0] == pytest.approx(6.305) and M[1, 1] == pytest.approx(6.305)
    assert -bias[1, 0] == pytest.approx(-61.852, abs=1e-3)  # gravity force on z_B
    assert np.allclose(foot.ravel(), [0.0, 0.0], atol=1e-12)  # q0 stands on the ground

    # the same robot as robots/capler.xml: mass matrix, bias forces and foot against Pinocchio
    import pinocchio as pin

    robot = load_robot(b.ROBOT_FILE)
    assert robot.dof_names == ("base_x", "base_z", "hip", "knee")
    model, data = robot.model, robot.model.createData()
    fn = ca.Function("fn", [cap["q"], cap["v"]], [cap["M"], cap["bias"], cap["foot"], cap["knee"]])
    rng = np.random.default_rng(3)
    for _ in range(5):
        q, v = rng.uniform(-1.5, 1.5, 4), rng.uniform(-3, 3, 4)
        M, bias, foot, knee = (np.asarray(a) for a in fn(q, v))
        M_pin = pin.crba(model, data, q)
        M_pin = np.triu(M_pin) + np.triu(M_pin, 1).T
        assert np.allclose(M, M_pin, atol=1e-12)
        assert np.allclose(bias.ravel(), pin.rnea(model, data, q, v, np.zeros(4)), atol=1e-10)
        pin.framesForwardKinematics(model, data, q)
        for name, pos in (("foot", foot), ("knee", knee)):
            xyz = data.oMf[model.getFrameId(name, pin.FrameType.OP_FRAME)].translation  # the site
            assert np.allclose(pos.ravel(), xyz[[0, 2]], atol=1e-12), name

    task = b.load_capler_task()
    hint = b.hop_hint(task, task.N)
    assert hint.shape == (task.N, 9)
    assert np.allclose(hint[-1, :4], task.q_target) and hint[-1, 8] == pytest.approx(task.tau_f)
    apex = np.argmin(np.abs(hint[:, 0] - 0.5))
    assert hint[apex, 1] > task.q0[1] + 0.1  # the base is up over the first hole

    line = b.table([{"solver": "nosnoc", "variant": "hint-free", "N": 25, "holes": 0, "wall_time_s": 1.5,
                     "ipopt_iterations": 10, "complementarity_ours": 1e-4, "complementarity_nosnoc": None,
                     "terminal_error": 0.0, "penetration_m": 0.1, "holes_metric": None, "converged": True,
                     "infeasible": False, "used_hint": False}])
    assert "hint-free" in line and "1.0e-04" in line and len(line.splitlines()) == 3


def test_bench_nosnoc_says_how_to_install(bench_nosnoc, monkeypatch, tmp_path, capsys):
    """Without nosnoc, main() stops with a message naming `pip install nosnoc`, before any work: one line
    `bench_nosnoc: error: ...` and exit 2 as stress without dask (it was exit 1 without the prefix); the planner alone
    (--planner --variants) runs without it, each record dated when it finished, and removes an earlier run's
    trajectories.npz (it stayed beside results.json as this run's)."""
    monkeypatch.setitem(sys.modules, "nosnoc", None)  # import nosnoc -> ImportError
    monkeypatch.setattr(sys, "argv", ["bench_nosnoc.py"])
    assert run_main(lambda: bench_nosnoc.main(["--quick", "--out", str(tmp_path)])) == 2
    err = capsys.readouterr().err
    assert err.startswith("bench_nosnoc: error: ") and "pip install nosnoc" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "results.json").exists()
    planned = {"solver": "planner", "variant": "hint-free", "N": 25, "holes": 0, "converged": True, "wall_time_s": 0.5}
    monkeypatch.setattr(bench_nosnoc, "run_planner", lambda quick: dict(planned))
    (tmp_path / "trajectories.npz").write_bytes(b"an earlier run's nosnoc solutions")  # not this run's: removed
    assert bench_nosnoc.main(["--quick", "--planner", "--variants", "--out", str(tmp_path)]) == 0
    assert not (tmp_path / "trajectories.npz").exists()
    results = json.loads((tmp_path / "results.json").read_text())
    (rec,) = results["records"]
    assert rec["solver"] == "planner" and rec["date"].endswith("+00:00") and results["machine"]["nosnoc"] is None
    assert results["run"]["command"].endswith("--quick --planner --variants --out " + str(tmp_path))


def test_bench_nosnoc_append_refuses_an_unreadable_results_json_before_any_solve(bench_nosnoc, monkeypatch, tmp_path):
    """--append reads OUT/results.json before any solve: an unreadable one is one line and exit 2 (it was a
    JSONDecodeError traceback after the whole run)."""
    def solve(*args, **kwargs):
        raise AssertionError("solved before the file to append to was read")

    monkeypatch.setattr(bench_nosnoc, "run_nosnoc", solve)
    for text in ('{"records": [\n', '[1, 2]\n', '{"records": [{"solver": "nosnoc"}]}\n'):
        (tmp_path / "results.json").write_text(text)
        with pytest.raises(InputError, match="--append: cannot read .*results.json"):  # run_main: one line, exit 2
            bench_nosnoc.main(["--quick", "--append", "--out", str(tmp_path)])


def test_bench_nosnoc_quick_run(bench_nosnoc, tmp_path, capsys):
    """--quick --json with nosnoc installed: results.json holds the machine and one record with the
    measures (wall time, iterations, both complementarity residuals, terminal error, penetration)."""
    pytest.importorskip("nosnoc")
    assert bench_nosnoc.main(["--quick", "--json", "--variants", "hint-free", "--out", str(tmp_path)]) == 0
    summary = json.loads(capsys.readouterr().out)
    results = json.loads((tmp_path / "results.json").read_text())
    for key in ("platform", "cpu_count", "python", "casadi", "nosnoc", "date"):
        assert results["machine"][key] is not None, key
    (rec,) = results["records"]
    assert summary["records"][0]["variant"] == rec["variant"] == "hint-free" and rec["N"] == 25
    for key in ("wall_time_s", "ipopt_iterations", "complementarity_ours", "complementarity_nosnoc",
                "terminal_error", "penetration_m", "converged", "infeasible", "nlp_statuses"):
        assert rec[key] is not None, key
    assert rec["wall_time_s"] > 0 and rec["ipopt_iterations"] > 0
    assert (tmp_path / "trajectories.npz").is_file()


def test_bench_nosnoc_append_keeps_only_records_of_the_same_settings(bench_nosnoc, monkeypatch, tmp_path, capsys):
    """--append keeps an earlier record only when it was run with the same settings (quick, n_fe, n_s, a_t, max_iter),
    and the table says which records are kept and from when: a hint run at max_iter 1 was judged against a hint-free
    run at 4000, "nosnoc needed the hint: no", silently. The planner's record is kept across nosnoc's settings (its
    solve does not use them; another --max-iter dropped it) and not across --quick."""
    pytest.importorskip("nosnoc")

    def fake(nosnoc, ca, task, variant, **settings):  # a record as run_nosnoc writes it, without the solve
        return {"solver": "nosnoc", "variant": variant, "N": task.N, "holes": len(task.holes), "converged": variant == "hint",
                "wall_time_s": 1.0}

    monkeypatch.setattr(bench_nosnoc, "run_nosnoc", fake)
    out = ["--quick", "--append", "--out", str(tmp_path)]
    assert bench_nosnoc.main(["--variants", "hint-free"] + out) == 0
    capsys.readouterr()
    assert bench_nosnoc.main(["--variants", "hint", "--max-iter", "1"] + out) == 0
    records = json.loads((tmp_path / "results.json").read_text())
    assert [r["variant"] for r in records["records"]] == ["hint"] and records["nosnoc_needs_hint"] is None
    assert "kept from" not in capsys.readouterr().out
    assert bench_nosnoc.main(["--variants", "hint-free", "--max-iter", "1"] + out) == 0  # the same settings: combined
    printed = capsys.readouterr().out
    assert "nosnoc hint: kept from the run of" in printed and "nosnoc needed the hint: yes" in printed
    planned = {"solver": "planner", "variant": "hint-free", "N": 25, "holes": 0, "converged": True, "wall_time_s": 0.5}
    monkeypatch.setattr(bench_nosnoc, "run_planner", lambda quick: dict(planned))
    assert bench_nosnoc.main(["--variants", "hint-free", "--max-iter", "1", "--planner"] + out) == 0
    capsys.readouterr()
    assert bench_nosnoc.main(["--variants", "hint-free", "--max-iter", "7"] + out) == 0
    records = json.loads((tmp_path / "results.json").read_text())
    assert [(r["solver"], r["variant"]) for r in records["records"]] == [("planner", "hint-free"),
                                                                         ("nosnoc", "hint-free")]
    assert records["wall_time_ratio_nosnoc_over_planner"] == 2.0
    assert "planner hint-free: kept from the run of" in capsys.readouterr().out


def test_bench_nosnoc_planner_side_races_as_planner_plan_does(bench_nosnoc, monkeypatch):
    """--planner solves as `planner plan` does: the race of planner.race.default_arms (two CPUs assumed here),
    recorded with each arm's outcome, exactly one "won", on the quick task (N = 25, no holes)."""
    from planner import race
    from planner.homotopy import SolveOptions

    monkeypatch.setattr(race, "usable_cpus", lambda: 2)
    rec = bench_nosnoc.run_planner(quick=True)
    assert rec["solver"] == "planner" and rec["N"] == 25 and rec["holes"] == 0 and rec["ipopt_iterations"] > 0
    assert [a["arm"] for a in rec["race"]] == [name for name, _ in race.default_arms(SolveOptions())]
    assert rec["converged"]  # the quick task converges (measured: 1630 iterations, ~7 s), so the race has a winner
    assert [a["outcome"] for a in rec["race"]].count("won") == 1


# --- scripts/readme_figures.py -------------------------------------------------------------------------

@pytest.mark.skipif(shutil.which("chromium") is None, reason="needs Debian's chromium: apt-get install -y chromium")
def test_readme_figures_photograph_the_replay(tmp_path):
    """The README's pictures come from the project's code: a result directory gives replay.png (an
    800 x 600 screenshot of the meshcat page that is not blank) and copies of its plots; a time past the end is
    refused."""
    from PIL import Image

    from planner.cli import main as cli

    result = tmp_path / "drop"
    assert cli(["simulate", "point_mass", "--out", str(result), "-q"]) == 0
    figures = _load("readme_figures")
    assert figures.main([str(result), "--out", str(tmp_path / "img"), "--at", "0.5"]) == 0
    img = np.asarray(Image.open(tmp_path / "img" / "replay.png").convert("RGB")).astype(float)
    assert img.shape[:2] == (600, 800) and img.std() > 5.0  # 5 levels: the blank-page bound of tests/test_view.py
    assert (tmp_path / "img" / "foot_path.png").is_file() and (tmp_path / "img" / "states.png").is_file()
    with pytest.raises(SystemExit) as stop:  # a time past the replay's end (it photographed the last frame, unsaid)
        figures.main([str(result), "--out", str(tmp_path / "img"), "--at", "100"])
    assert stop.value.code == 2


Z_TOL = 1e-6  # [m] the plan's start and terminal rows hold to IPOPT's tolerance (1e-8) and the verdict's 1e-6


def test_bench_skips_quick_run(tmp_path, capsys):
    """--quick --json: results.json has one record per skip case with both variants (sizes, iterations,
    wall time, convergence, the scene record, each contact point's height range: the point mass's from its start
    height to its target's) and the solution differences; the skip has fewer
    variables or constraints. No timing or convergence assertions: --quick is a smoke run."""
    bench_skips = _load("bench_skips")
    assert bench_skips.main(["--quick", "--json", "--out", str(tmp_path)]) == 0
    results = json.loads(capsys.readouterr().out)
    assert results == json.loads((tmp_path / "results.json").read_text())
    records = {r["case"]: r for r in results["records"]}
    assert set(records) == set(bench_skips.CASES)
    for name, r in records.items():
        on, off = r["on"], r["off"]
        for key in ("n_variables", "n_constraints", "n_pairs", "jacobian_nnz", "ipopt_iterations", "wall_s", "converged", "scene"):
            assert key in on and key in off, (name, key)
        assert on["scene"]["enabled"] and not off["scene"]["enabled"]
        assert on["n_variables"] + on["n_constraints"] < off["n_variables"] + off["n_constraints"], name
        assert math.isfinite(r["max_physical_q_diff"])
    assert records["frictionless"]["on"]["scene"]["frictionless"] == ["point"]
    for variant in ("on", "off"):  # the point mass's site is its origin: z = q_z falls from the start's 0.2 m to the target's 0
        lo, hi = records["frictionless"][variant]["point_z_range"]["point"]
        assert hi == pytest.approx(0.2, abs=Z_TOL) and abs(lo) <= Z_TOL
    assert set(records["never_touching"]["on"]["point_z_range"]) == {"foot", "knee"}
    assert records["never_touching"]["on"]["scene"]["never_touching"] == ["knee"]
    assert len(records["dropped_holes"]["on"]["scene"]["dropped_holes"]) == 2


def test_probe_steps_quick_run(tmp_path, capsys):
    """--quick --json: a record per NLP (1 and 2 of the hop) with the documented fields, the same in results.json, whose
    command is shell-quoted; the NLPs are the homotopy's own (as many iterations as solve()'s NLPs 1 and 2), and no
    more steps are cut than taken."""
    from scripts import probe_steps

    robot, task = probe_steps.CASES["hop"](True)
    homotopy = H.solve(build_problem(robot, task)).nlps
    out = tmp_path / "with space"
    assert probe_steps.main(["--quick", "--json", "--out", str(out)]) == 0
    rec = json.loads(capsys.readouterr().out)
    assert rec == json.loads((out / "results.json").read_text()) and rec["case"] == "hop"
    # the command as the shell reads it (an --out with a space, a --solve JSON were pasted back broken)
    assert shlex.split(rec["command"])[-1] == str(out)
    assert [r["nlp"] for r in rec["records"]] == ["NLP 1", "NLP 2"]
    assert [r["iterations"] for r in rec["records"]] == [n.iterations for n in homotopy[:2]]
    for r in rec["records"]:
        assert set(r) == {"nlp", "iterations", "status", "regularized", "median_lg_delta_w", "median_alpha_pr", "full_steps",
                          "steps_cut", "variables", "rows"}
        assert 0 <= r["steps_cut"] <= r["iterations"] and r["regularized"] <= r["iterations"]
        assert all(n <= r["steps_cut"] for _, _, n in r["variables"] + r["rows"])


def test_probe_early_stop_quick_run(tmp_path, capsys):
    """--quick --json: the records as printed and in results.json; the probe's NLP 2 is the alternate arm's own (as
    many iterations as solve() takes in it), its checkpoint is that NLP's iterate 5, the held schedule from the NLP's
    end is accepted (the hop converges) and its modes differ from themselves nowhere; selector_modes reads every
    selector of the converged plan as at 0, at 1 or inside; a malformed --at is a usage error; with a per-NLP
    schedule (the regularizer's factor) the probe's NLP 2 is still solve()'s (homotopy_nlp builds both); a checkpoint
    past the NLP's end gives no row."""
    from dataclasses import replace

    from planner.race import default_arms
    from scripts import probe_early_stop as pes

    problem = build_problem(*pes.CASES["hop"](True))
    alternate = dict(default_arms(H.SolveOptions()))["alternate"]
    plan = H.solve(problem, alternate)
    assert pes.main(["--quick", "--json", "--out", str(tmp_path)]) == 0
    rec = json.loads(capsys.readouterr().out)
    assert rec == json.loads((tmp_path / "results.json").read_text()) and rec["arm"] == "alternate"
    capped, end = rec["records"]
    assert (capped["nlp"], capped["at"], capped["nlp_iterations"]) == (2, 5, 5)
    assert end["at"] is None and end["nlp_iterations"] == plan.nlps[1].iterations
    assert end["accepted"] and end["modes_differing"] == 0 and end["control_cost"] > 0
    modes = pes.selector_modes(problem, plan.extra["_x"])
    assert modes.shape == problem.var_blocks["sigma"].shape and set(np.unique(modes)) <= set(pes.MODES.values())
    assert pes.parse_at(["3:40,20"]) == {3: [20, 40]}
    # a checkpoint past the NLP's end is none (a row "5000" beside the end's 88 read as an NLP run that long)
    assert [r["at"] for r in pes.probe(problem, alternate, {2: [5, 10**6]})] == [5, None]
    weighted = replace(alternate, rho_f_schedule=(10.0, 1.0))
    end_weighted = pes.probe(problem, weighted, {2: []})[-1]
    assert end_weighted["nlp_iterations"] == H.solve(problem, weighted).nlps[1].iterations != end["nlp_iterations"]
    for bad in (["0:5"], ["2:"], ["2:x"]):
        with pytest.raises(SystemExit):
            pes.main(["--at", *bad, "--out", str(tmp_path)])


def test_probe_steps_finds_the_variable_left_at_one_percent():
    """cut_steps: a step that leaves a variable at 1 % of its distance to a finite bound (the fraction-to-the-boundary
    rule) is reported with that bound's side; halving a distance, an infinite bound, or a variable that starts on its
    bound are not; distances are to the bounds as IPOPT relaxes them."""
    from scripts.probe_steps import cut_steps

    lower, upper = np.array([0.0, 0.0, -np.inf, 0.0]), np.array([1.0, np.inf, 5.0, 1.0])
    X = np.array([[0.5, 2.0, 4.0, 0.0],
                  [0.005, 1.0, 4.99, 0.0],   # x0 left at 1 % of 0.5 above 0; x2 at 1 % of 1 below 5; x1 halved
                  [0.9995, 1.0, 4.99, 0.5]])  # x0 at 0.1 % below 1 (from 0.995); x3 leaves its bound
    assert cut_steps(X, lower, upper) == [[(0, "lb"), (2, "ub")], [(0, "ub")]]
    # IPOPT relaxes the bounds (bound_relax_factor): a step to just below a bound is inside the relaxed one
    below = np.array([[1.0], [-5e-9]])
    assert cut_steps(below, np.zeros(1), np.ones(1)) == [[]] and cut_steps(below, np.zeros(1), np.ones(1), 1e-8) == [[(0, "lb")]]


def test_probe_smoothing_quick_run(tmp_path, capsys):
    """--quick --json: one record per smoothing scale with the documented fields, the same in results.json; the
    smoothed NLP holds every selector at its logistic of the switching function (the rewritten stationarity rows
    vanish at a point built that way) with the multipliers and the l_inf slack fixed at 0. No convergence
    assertion: --quick is a smoke run."""
    from scripts import probe_smoothing

    assert probe_smoothing.main(["--quick", "--json", "--out", str(tmp_path)]) == 0
    rec = json.loads(capsys.readouterr().out)
    assert rec == json.loads((tmp_path / "results.json").read_text())
    assert [r["eps_scale"] for r in rec["nlps"]] == [1.0, 0.1] and rec["N"] == 6
    for r in rec["nlps"]:
        assert set(r) == {"eps_scale", "iterations", "status", "wall_s", "control_cost", "terminal_error", "base_x_end"}
    robot, task = probe_smoothing.capler_case(6)
    problem = build_problem(robot, task)
    nlp = probe_smoothing.smoothed_nlp(problem)
    x, lbx, ubx = probe_smoothing.smoothed_bounds(problem, problem.x0)
    fixed = lbx == ubx
    assert np.all(x[fixed] == 0) and fixed[problem.var_blocks["lambda0"]].all() and fixed[problem.var_blocks["s_c"]].all()
    rows = problem.g_blocks["stationarity"].ravel()
    sigma = problem.var_blocks["sigma"].ravel()
    eps = np.array([probe_smoothing.EPS[s.function] for s in problem.system.switches])
    p = np.concatenate([problem.params(0.0, 1.0), eps])
    g = ca.Function("g", [nlp["x"], nlp["p"]], [nlp["g"]])
    x[sigma] = 0.5  # selectors off their logistic: the rows are nonzero somewhere
    assert np.abs(np.asarray(g(x, p)).ravel()[rows]).max() > 1e-3
    x[sigma] -= np.asarray(g(x, p)).ravel()[rows]  # h depends on the states and forces, not on sigma: one step sets them
    assert np.abs(np.asarray(g(x, p)).ravel()[rows]).max() <= 1e-12


# --- scripts/probe_multiphase.py ------------------------------------------------------------------------

# the per-step solves meet IPOPT's tol (1e-8) on their equality rows; only a step's complementarity may fail
STEP_ROW_TOL = 1e-8
# IPOPT relaxes each bound by bound_relax_factor (1e-8) relative to it: 6e-7 N m at Capler's 60 N m
U_BOUND_TOL = 1e-6


def test_probe_multiphase_quick_run(tmp_path, capsys):
    """--quick --json: the documented record, the same in results.json; the pd start is the time-freezing NLP's own
    steps, so packed into the NLP's layout it satisfies every step row (dynamics, stationarity, lifting, forces) of
    the N = 10 problem; so does the track start, whose controls stay in their bounds; the interpolated start runs its
    clock with tau and holds its controls in their bounds."""
    from scripts import probe_multiphase as pm

    assert pm.main(["--quick", "--json", "--out", str(tmp_path)]) == 0
    rec = json.loads(capsys.readouterr().out)
    assert rec == json.loads((tmp_path / "results.json").read_text())
    assert rec["N"] == 10 and rec["start"] == "pd" and "solve" not in rec
    assert set(rec["hop_ocp"]) == {"iterations", "status", "wall_s", "cost", "footholds"} and len(rec["hop_ocp"]["footholds"]) == 3
    assert set(rec["start_state"]) == {"step_iterations", "steps_failed", "wall_s", "base_x_end", "clock_end", "violations"}
    for block in ("dynamics", "stationarity", "lifting", "contact_forces"):
        assert rec["start_state"]["violations"][block] <= STEP_ROW_TOL, block
    robot, task = pm.capler_case(10)
    plan = pm.hop_ocp(robot, task, [1.0], 2.3, (3, 3), 30)
    problem = build_problem(robot, task)
    x, info = pm.interpolated_start(problem, plan)
    Y = x[problem.var_blocks["y"]]
    np.testing.assert_allclose(Y[:, -1], problem.h * np.arange(1, problem.N + 1), rtol=0, atol=1e-12)
    u = x[problem.var_blocks["u"]]
    assert np.all(u >= problem.lbx[problem.var_blocks["u"]]) and np.all(u <= problem.ubx[problem.var_blocks["u"]])
    assert info == {"step_iterations": 0, "steps_failed": 0}
    x, info = pm.stepwise_start(problem, plan, "track")  # u is each step's variable: in its bounds, the step rows met
    u = x[problem.var_blocks["u"]]
    assert np.all(u >= problem.lbx[problem.var_blocks["u"]] - U_BOUND_TOL) and np.all(u <= problem.ubx[problem.var_blocks["u"]] + U_BOUND_TOL)
    viol = pm.constraint_violation(problem, x)
    assert max(viol[b] for b in ("dynamics", "stationarity", "lifting", "contact_forces")) <= STEP_ROW_TOL


# the held replan stops at IPOPT's acceptable level (tol 1e-6) from the plan's own point: the cost moves below 1e-6 of it
# (measured 7e-8 on the hop at N = 10); the homotopy returns to the same plan (measured to 1e-15)
SAME_PLAN_COST_REL = 1e-6


def test_solve_from_a_plan_returns_to_it():
    """probe_multiphase.solve_from from a converged plan's own NLP point: the held-schedule replan converges to that
    plan in fewer iterations than the plan took, as one 'schedule' NLP; the hint-free homotopy from it converges too,
    to the same plan (point-mass hop, N = 10, 1-2 s)."""
    from scripts import probe_multiphase as pm
    from scripts.bench_pipeline import hop_case

    problem = build_problem(*hop_case(10))
    plan = H.solve(problem, H.SolveOptions())
    assert plan.stats.converged
    cost = plan.summary()["control_cost"]
    held = pm.solve_from(problem, plan.extra["_x"], held=True)
    assert held["converged"] and held["iterations"] < plan.stats.ipopt_iterations
    assert [label for label, _, _ in held["nlps"]] == ["schedule"]
    assert held["control_cost"] == pytest.approx(cost, rel=SAME_PLAN_COST_REL)
    homotopy = pm.solve_from(problem, plan.extra["_x"], held=False)
    assert homotopy["converged"] and homotopy["nlps"][0][0] == "homotopy 1"
    assert homotopy["control_cost"] == pytest.approx(cost, rel=SAME_PLAN_COST_REL)


# --- scripts/bench_biped_walk.py -----------------------------------------------------------------------

def test_bench_biped_walk_quick_run(tmp_path, capsys):
    """--quick --json: one record (the default bound) with the documented fields, as printed and as in
    results.json; the varied tasks are the default task with only the bound changed or removed (and for
    another step, the step and the standing guess), and they load; a bad --lower or --step is a usage
    error. No timing or convergence assertions: --quick (N = 6, no walk) is a smoke run."""
    import tomllib

    from planner.task import parse_task

    bench = _load("bench_biped_walk")
    assert bench.main(["--quick", "--json", "--out", str(tmp_path)]) == 0
    runs = json.loads(capsys.readouterr().out)
    assert runs == json.loads((tmp_path / "results.json").read_text())["runs"]
    (r,) = runs
    for key in ("lower_rad_s", "step_m", "exit_code", "converged", "ipopt_iterations", "solve_time_s", "control_cost",
                "physical_period_s", "impact_times_s", "walk_passed", "steps_walked", "max_torque_Nm", "failures"):
        assert key in r, key
    assert r["lower_rad_s"] == 0.3 and r["step_m"] == 0.25 and r["walk_passed"] is None  # --quick does not walk
    default = tomllib.loads(bench.TASK.read_text())
    default["plan"].pop("velocity_bounds")
    for lower, expect in (("none", []), ("0.2", [0.2])):
        task = tomllib.loads(bench.task_text(lower))
        parse_task(task)
        assert [b["lower"] for b in task["plan"].pop("velocity_bounds", [])] == expect
        assert task == default
    # another step moves the standing guess: feet `step` apart on the unit legs
    task = tomllib.loads(bench.task_text("0.3", 0.2))
    parse_task(task)
    q = task["initial"].pop("q")
    assert task["plan"]["periodic"].pop("step") == 0.2 and np.sin(q[4]) == pytest.approx(0.1) and q[3] == -q[4]
    assert q[1] == pytest.approx(np.cos(q[4]))
    del default["initial"]["q"], default["plan"]["periodic"]["step"]
    task["plan"].pop("velocity_bounds")
    assert task == default
    for bad in (["--lower", "fast"], ["--step", "2.5"]):
        with pytest.raises(SystemExit):
            bench.main(bad + ["--out", str(tmp_path)])


# --- scripts/bench_replan.py ---------------------------------------------------------------------------

def test_bench_replan_quick_run(tmp_path, capsys):
    """--quick --json: the hop's start plan, then one moved task replanned both ways, with the documented
    fields, as printed and as in results.json; the keep_schedule run's first NLP is "schedule" and the
    other's is not. moved_task changes only the periodic step or, without one, the target's first
    coordinate; a task without either is refused before any solve, and so is an --init inside a directory the run
    replaces. No timing assertions."""
    import tomllib

    bench = _load("bench_replan")
    assert bench.main(["--quick", "--json", "--out", str(tmp_path)]) == 0
    runs = json.loads(capsys.readouterr().out)
    assert runs == json.loads((tmp_path / "results.json").read_text())["runs"]
    assert [(r["value"], r["variant"]) for r in runs] == [(0.52, "replan"), (0.52, "keep_schedule")]
    for r in runs:
        for key in ("exit_code", "converged", "nlps", "ipopt_iterations", "solve_time_s", "control_cost", "impact_times_s",
                    "validation_passed", "steps_walked"):
            assert key in r, key
        assert r["command_s"] >= r["solve_time_s"]  # the command holds its solve
    assert runs[0]["nlps"][0][0] == "homotopy 1" and runs[1]["nlps"][0][0] == "schedule"
    hop = tomllib.loads(bench.QUICK_TASK)
    moved = tomllib.loads(bench.moved_task(bench.QUICK_TASK, 0.6))
    assert moved["plan"].pop("target_q") == [0.6, 0.0] and hop["plan"].pop("target_q") == [0.5, 0.0] and moved == hop
    biped = (bench.ROOT / "robots" / "biped.toml").read_text()
    walk, moved = tomllib.loads(biped), tomllib.loads(bench.moved_task(biped, 0.3))
    assert moved["plan"]["periodic"].pop("step") == 0.3 and walk["plan"]["periodic"].pop("step") == 0.25 and moved == walk
    with pytest.raises(InputError, match="exactly one 'target_q = ...' line"):
        bench.moved_task("[plan]\nu_bound = 1.0\n", 0.3)
    start = tmp_path / "keep_schedule_0.52"  # a replan of this run as the next one's start: it was deleted
    with pytest.raises(InputError, match="lies in .*keep_schedule_0.52, which this run replaces"):
        bench.main(["--quick", "--init", str(start), "--out", str(tmp_path)])
    assert (start / "trajectory.npz").is_file()


def test_bench_biped_walk_does_not_read_an_earlier_runs_result(tmp_path, monkeypatch):
    """A run whose `planner plan` wrote nothing (exit 2) is refused as such, not recorded from the summary.json an
    earlier run left in the same directory (a failed rerun recorded the earlier converged plan)."""
    bench = _load("bench_biped_walk")
    stale = tmp_path / "lower_0.3" / "plan"
    stale.mkdir(parents=True)
    (stale / "summary.json").write_text('{"converged": true}')
    monkeypatch.setattr(bench, "planner_command", lambda argv: 2)
    with pytest.raises(InputError, match="refused the task"):
        bench.run("0.3", bench.DEFAULT_STEP, tmp_path, quick=True)


def test_bench_biped_walk_labels_a_failed_solve_not_validated(tmp_path, monkeypatch):
    """A run whose solve did not converge (exit 1, summary.json in plan/failed, no validation: planner plan validates
    converged plans only) is labelled not validated because the solve did not converge, not refused for a
    non-monotonic stance-leg angle, a reason the walk never gave for it."""
    bench = _load("bench_biped_walk")

    def failed_solve(argv):
        failed = Path(argv[argv.index("--out") + 1]) / "failed"
        failed.mkdir(parents=True)
        (failed / "summary.json").write_text(json.dumps({
            "converged": False, "ipopt_iterations": 3000, "solve_time_s": 90.0, "control_cost": 12.0,
            "physical_duration_s": 0.5, "impacts": []}))
        return 1

    monkeypatch.setattr(bench, "planner_command", failed_solve)
    row = bench.run("0.3", bench.DEFAULT_STEP, tmp_path, quick=False)
    assert not row["converged"] and row["steps_walked"] is None
    walk = bench.table([row]).splitlines()[-1].split(" | ")[-1]
    assert walk == "not validated: the solve did not converge |"

def test_bench_replan_records_a_refused_value_and_goes_on(tmp_path, monkeypatch):
    """A value whose task planner refuses (exit 2, nothing written: Capler's target 2.7 m stands in a hole) is a row
    marked refused and the other values still run (the whole benchmark stopped, its finished rows lost); a run's
    directory is cleared first, so an earlier run's summary.json is not read as a refused run's."""
    bench = _load("bench_replan")
    out = tmp_path / "keep_schedule_2.7"
    out.mkdir()
    (out / "summary.json").write_text('{"converged": true}')  # an earlier run's
    monkeypatch.setattr(bench, "planner_command", lambda argv: 2)
    row = bench.plan("capler", tmp_path / "task.toml", out, [], False)
    assert row["refused"] and row["exit_code"] == 2 and row["ipopt_iterations"] is None and not out.exists()
    assert "| 2.7 | keep_schedule | 2 | refused" in bench.table([{"value": 2.7, "variant": "keep_schedule", **row}])


# --- scripts/_report.py: run_main ------------------------------------------------------------------------

def test_run_main_turns_an_os_error_into_one_line(capsys):
    """An OSError that no check before the run could see (--out under /proc: FileNotFoundError after the whole run,
    a traceback before) is one line: exit 2 when the system refuses a path, exit 1 naming the cause otherwise (a full
    disk), also when it reaches run_main as the PlannerError of a write (it said "error:", exit 2)."""
    import errno

    from scripts._report import run_main

    def refused():
        raise FileNotFoundError(errno.ENOENT, "No such file or directory", "/proc/x/results.json")

    def full():
        raise OSError(errno.ENOSPC, "No space left on device", "/data/results.json")

    assert run_main(refused) == 2
    assert capsys.readouterr().err.endswith("error: cannot use /proc/x/results.json: No such file or directory\n")
    assert run_main(full) == 1
    err = capsys.readouterr().err
    assert err.endswith("failed: No space left on device: /data/results.json\n") and len(err.splitlines()) == 1

    def written_full():  # write_atomically's error for a full disk: a PlannerError that is no InputError
        from planner.errors import write_error

        raise write_error("/data/results.json", OSError(errno.ENOSPC, "No space left on device"))

    assert run_main(written_full) == 1 and "failed: cannot write /data/results.json" in capsys.readouterr().err


def test_a_scripts_bad_input_is_one_line_and_exit_2(tmp_path):
    """A script run as a command turns a PlannerError (here: a missing result directory) into one line
    `SCRIPT: error: ...` on stderr and exit code 2, as planner's CLI does; every script's __main__ block goes through
    run_main, so none prints a traceback for a bad input."""
    proc = subprocess.run([sys.executable, "-m", "scripts.probe_impacts", str(tmp_path / "missing")], cwd=SCRIPTS.parent,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and proc.stderr.strip().startswith("probe_impacts: error: ")
    assert len(proc.stderr.strip().splitlines()) == 1 and "Traceback" not in proc.stderr
    for script in sorted(SCRIPTS.glob("*.py")):
        if script.name not in ("_report.py", "__init__.py"):
            text = script.read_text()
            assert "sys.exit(run_main(main))" in text.split('if __name__ == "__main__":')[-1], script.name
            assert "script_parser(__doc__" in text and "ArgumentParser(" not in text, script.name


IMPORT_ORDER = """
import sys
order = []
class Recorder:
    def find_spec(self, name, path=None, target=None):
        order.append(name)
sys.meta_path.insert(0, Recorder())
import scripts.{name}
print("numpy" in order, all(order.index("planner") < order.index(m) for m in ("numpy", "casadi") if m in order))
"""


@pytest.mark.parametrize("name", ["bench_skips", "stress", "bench_work_precision"])
def test_a_script_imports_planner_before_numpy_and_casadi(name):
    """planner fixes OpenBLAS's threads and kernels, which numpy and CasADi read when they load: a script run as
    `python -m scripts.NAME` imports planner first (scripts/__init__.py), where it imported numpy first and took
    another homotopy path on an AVX-512 machine (bench_skips' never-touching case: 1688 iterations, not 1404)."""
    proc = subprocess.run([sys.executable, "-c", IMPORT_ORDER.format(name=name)], cwd=SCRIPTS.parent,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and proc.stdout.split() == ["True", "True"], proc.stderr


def test_a_scripts_usage_error_is_one_line_and_exit_2():
    """A script's usage error (an unknown flag) is one line naming the flag and pointing at --help, exit 2, as planner's
    own parser does (argparse printed the usage line too)."""
    proc = subprocess.run([sys.executable, "-m", "scripts.bench_skips", "--bogus"], cwd=SCRIPTS.parent,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.strip() == "bench_skips: error: unrecognized arguments: --bogus (see --help)"  # as run_main names it


def test_a_scripts_default_out_is_checked_before_running(tmp_path):
    """A script's default --out (a Path, which argparse does not pass through its type) is checked up front as a
    given one is: its results.json a directory was found only after the whole run (bench_skips --quick: six solves);
    not where the run does not write it (stress --list)."""
    (tmp_path / "results" / "bench" / "skips" / "results.json").mkdir(parents=True)
    proc = subprocess.run([sys.executable, "-m", "scripts.bench_skips", "--quick"], cwd=tmp_path, capture_output=True,
                          text=True, timeout=120, env={**os.environ, "PYTHONPATH": str(SCRIPTS.parent)})
    assert proc.returncode == 2 and proc.stderr.strip() == (
        "bench_skips: error: argument --out (default): results/bench/skips/results.json is a directory; results.json "
        "is written there (see --help)"), proc.stderr
    (tmp_path / "results" / "stress" / "results.json").mkdir(parents=True)  # (--list writes nothing: not checked)
    listed = subprocess.run([sys.executable, "-m", "scripts.stress", "--robot", "point_mass", "--list"], cwd=tmp_path,
                            capture_output=True, text=True, timeout=120,
                            env={**os.environ, "PYTHONPATH": str(SCRIPTS.parent)})
    assert listed.returncode == 0, listed.stderr


@pytest.mark.parametrize("argv, fragment", [
    (["scripts.stress", "--robot", "point_mass", "--seed", "-1"], "stress: error: --seed must be >= 0"),  # numpy's traceback
    (["scripts.stress", "--robot", "point_mass", "--rho-schedule", "nan"], "SolveOptions.rho_schedule"),  # every task crashed
    (["scripts.bench_pipeline", "--quick", "--solve", '{"bogus": 1}'], "add --full or --full-only"),  # silently ignored
    # options of runs that do not happen: dropped, and recorded in results.json as if used
    (["scripts.bench_pipeline", "--quick", "--full-only", "--variants", "mumps_amd", "--iters", "50"],
     "--variants, --iters set the fixed-iteration runs, which --full-only skips"),
    (["scripts.bench_work_precision", "--suite", "ocp", "--cases", "ocp_pm_hop", "--capler-N", "40"],
     "--capler-N sets the grids of the Capler cases, and --cases runs none"),
    (["scripts.stress", "--robot", "point_mass", "--scheduler", "tcp://127.0.0.1:1", "--workers", "2"],
     "--workers sets the local processes; a Dask --scheduler has its own workers"),
    (["scripts.bench_replan", "capler", "--values", "3.1", "--out", "{file}"], "is a file, not a directory"),
    # a traceback
    (["scripts.bench_replan", "nosuch", "--values", "1"], "no robot file with a default task robots/nosuch.toml"),
    # a task file without a robot file: its start plan was refused, then reported as "did not converge", exit 1
    (["scripts.bench_replan", "point_mass_hop", "--values", "0.6"], "robots with one: biped, capler, point_mass"),
    (["scripts.bench_replan", "capler", "--values", "3.1", "3.1000001"], "name the same runs (3.1, 3.1)"),  # deleted one
    (["scripts.bench_replan", "point_mass", "--values", "1"], "exactly one 'target_q = ...' line"),  # exit 1
    (["scripts.bench_replan", "biped", "--quick", "--values", "0.9"], "give no robot or --values with it"),  # dropped
    (["scripts.bench_biped_walk", "--quick", "--lower", "fast"], "give no --lower with it"),  # dropped
    # refused before any solve: a later step's refusal lost the runs before it (FileNotFoundError before that)
    (["scripts.bench_biped_walk", "--quick", "--step", "0.25", "1.9"], "the task of step 1.9 m, lower 0.3 is refused"),
    (["scripts.bench_work_precision", "--suite", "ocp", "--quick", "--cases", "ocp_capler"], "runs the point-mass hop only"),
    (["scripts.readme_figures", "results", "--at", "nan"], "--at must be a number of seconds"),  # a traceback
    # an --out that is a file: refused after the whole run (70 s of nosnoc's solves)
    *[([f"scripts.{name}", "--quick", "--out", "{file}"], "is a file, not a directory")
      for name in ("bench_nosnoc", "bench_pipeline", "bench_skips", "bench_work_precision")],
    # an --out whose results.json is a directory: refused after the whole run
    *[([f"scripts.{name}", "--quick", "--out", "{dir}/rj"], "rj/results.json is a directory")
      for name in ("bench_skips", "stress")],
    # an empty --out (an unset shell variable): results.json was written into the working directory
    *[([f"scripts.{name}", "--quick", "--out", ""], "an empty path is not allowed")
      for name in ("bench_skips", "stress", "bench_replan")],
    (["scripts.bench_fatrop", "--case", "hop", "--N", "6", "--convexify", "bogus"], "invalid choice: 'bogus'"),  # RuntimeError
    # options of a solver or a step that does not run: ignored, and recorded as used (session 51)
    (["scripts.bench_fatrop", "--case", "hop", "--N", "6", "--solvers", "ipopt", "--fatrop-opt", "mu_init=0.5",
      "--scale"],
     "--fatrop-opt, --scale apply to FATROP, which --solvers ipopt does not run"),
    (["scripts.bench_pipeline", "--quick", "--codegen-flags=-O3"], "--codegen-flags applies to --codegen only"),
    # every homotopy-family task ran the one --rho-schedule, recorded with the schedules drawn
    (["scripts.stress", "--robot", "point_mass", "--families", "homotopy", "--rho-schedule", "100", "1000", "--list"],
     "--rho-schedule replaces the task's homotopy, which the homotopy family varies"),
    # one run directory for both: the later run deleted the earlier one's plan, two rows
    (["scripts.bench_biped_walk", "--quick", "--step", "0.25", "0.25"], "name the same run twice"),
    (["scripts.bench_fatrop", "--case", "hop", "--N", "6", "--solvers", "ipopt", "--max-iter", "2", "--ipopt-opt", "tol=abc"],
     "given as text: tol=abc"),  # CasADi's "type mismatch" traceback
    (["scripts.bench_fatrop", "--case", "hop", "--N", "6", "--out", "{dir}"], "must name a file to write"),  # after the run
    (["scripts.probe_steps", "--quick", "--case", "capler50"], "--quick runs the hop with N = 6: give no --case"),
    (["scripts.probe_steps", "--quick", "--top", "0"], "--top must be >= 1, got 0"),  # listed nothing, exit 0
    # --plan runs `planner plan`: the probe's own arguments were dropped, no results.json written
    (["scripts.probe_impacts", "{dir}", "--json", "--plan", "point_mass"], "give no plan_dir or --json with it"),
    (["scripts.probe_positions", "--cases", "pm_drop_noslip", "--plan", "point_mass"], "give no --cases with it"),
    pytest.param(["scripts.bench_pipeline", "--quick", "--codegen", "--codegen-flags=-Obogus", "--variants", "baseline",
                  "--cache", "{dir}/cache"], "gcc refused --codegen-flags -Obogus",  # CalledProcessError
                 marks=pytest.mark.skipif(shutil.which("gcc") is None, reason="the codegen variant needs gcc")),
])
def test_scripts_refuse_bad_input_before_running(tmp_path, argv, fragment):
    """Inputs that a script used to record as every task's crash, ignore, or end in a traceback on (an --out that is
    a file) are refused up front: exit 2, the reason on stderr's last line (a refused `planner plan` run's own error may
    precede it), no usage text, no traceback."""
    a_file = tmp_path / "a_file"
    a_file.write_text("")
    (tmp_path / "rj" / "results.json").mkdir(parents=True)
    argv = ([a.replace("{file}", str(a_file)).replace("{dir}", str(tmp_path)) for a in argv]
            + ([] if "--out" in argv or "bench_fatrop" in argv[0] else ["--out", str(tmp_path / "out")]))
    proc = subprocess.run([sys.executable, "-m", *argv], cwd=SCRIPTS.parent, capture_output=True, text=True, timeout=120)
    err = proc.stderr.strip()
    assert proc.returncode == 2 and fragment in err.splitlines()[-1] and "usage:" not in err and "Traceback" not in err, err


def test_probe_replay_refuses_a_plan_of_another_robot(tmp_path):
    """probe_replay indexes Capler's hip and knee: a point-mass plan is refused in one line, exit 2 (it raised a
    CasADi slice error; a biped plan gave numbers of the wrong joints)."""
    from planner.cli import main as planner_main

    task = tmp_path / "hop.toml"
    task.write_text('[[contacts]]\npoint = "point"\nmu = 0.5\n[initial]\nq = [0.0, 0.0]\n'
                    '[horizon]\ntau_f = 1.0\nN = 8\n[plan]\ntarget_q = [0.5, 0.0]\nu_bound = 30.0\n')
    assert planner_main(["plan", "point_mass", "--task", str(task), "--out", str(tmp_path / "hop"), "--no-validate", "-q",
                         "--no-race", "--no-plots"]) == 0
    proc = subprocess.run([sys.executable, "-m", "scripts.probe_replay", str(tmp_path / "hop"), "--out", str(tmp_path / "p")],
                          cwd=SCRIPTS.parent, capture_output=True, text=True, timeout=120)
    err = proc.stderr.strip()
    assert proc.returncode == 2 and "this probe reads plans of Capler" in err and len(err.splitlines()) == 1, err


@pytest.mark.parametrize("script, argv, fragment", [
    # nonsense numbers: a LinAlgError traceback (--r 0), or a run that wrote NaN (exit 0) or warned 35k times
    *[("probe_lqr", ["--quick", flag, value], f"argument {flag}: expected a finite number {bound}, got '{value}'")
      for flag, value, bound in (("--r", "0", "> 0"), ("--q", "nan", ">= 0"), ("--q", "-1", ">= 0"),
                                 ("--gap-tol", "nan", "> 0"))],
    ("probe_replay", ["{dir}", "--kp", "nan"], "argument --kp: expected a finite number >= 0"),
    ("probe_smoothing", ["--eps-scales", "1", "nan"], "argument --eps-scales: expected a finite number > 0"),
    ("probe_positions", ["--quick", "--power", "nan"], "argument --power: expected a finite number >= 0"),
    # what --quick replaces, given beside it: dropped silently
    ("probe_lqr", ["--quick", "{dir}"], "give no plan with it"),
    ("probe_smoothing", ["--quick", "--N", "0", "--max-iter", "0"], "give no --N or --max-iter with it"),
    ("probe_multiphase", ["--quick", "--nodes", "0", "0"], "give no --nodes with it"),
    ("probe_positions", ["--quick", "--cases", "pm_drop_noslip"], "give no --cases with it"),
    ("probe_early_stop", ["--quick", "--case", "hop"], "give no --case with it"),
    ("probe_early_stop", ["--quick", "--at", "2:5"], "give no --at with it"),
    ("probe_early_stop", ["--at", "2:abc"], "argument --at: '2:abc': give K:J1,J2,..."),
    ("probe_early_stop", ["--case", "hop", "--at", "2:5", "9:5"], "case hop has NLPs 1 to 6"),  # an empty table
    # a --cache written into the working directory, or refused after the derivation
    ("bench_pipeline", ["--quick", "--codegen", "--cache", ""], "argument --cache: an empty path is not allowed"),
    ("bench_pipeline", ["--quick", "--codegen", "--cache", "{file}"], "is a file, not a directory"),
])
def test_scripts_refuse_bad_arguments_before_any_solve(tmp_path, monkeypatch, capsys, script, argv, fragment):
    """Arguments a script ran on (or crashed on, or dropped) are refused before any solve, as `SCRIPT: error: ...` in
    one line and exit 2, with nothing written."""
    import importlib

    module = importlib.import_module(f"scripts.{script}")
    a_file = tmp_path / "a_file"
    a_file.write_text("")
    argv = [a.replace("{file}", str(a_file)).replace("{dir}", str(tmp_path)) for a in argv]
    monkeypatch.setattr(sys, "argv", [f"{script}.py"])  # the name script_parser and run_main give the error
    try:
        code = run_main(lambda: module.main(argv + ["--out", str(tmp_path / "out")]))
    except SystemExit as exc:  # a usage error (argparse)
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2 and err.startswith(f"{script}: error: ") and fragment in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "out").exists()


def test_bench_replan_refuses_a_start_plan_of_another_robot(tmp_path, capsys):
    """--init of a point-mass plan for capler is refused up front naming the plan's robot (each replan was a
    "refused" row, exit 0)."""
    from scripts import bench_replan

    start = tmp_path / "hop"
    start.mkdir()
    np.savez(start / "trajectory.npz", nlp_x=np.zeros(3))
    (start / "summary.json").write_text(json.dumps({"robot": "robots/point_mass.xml", "task": "hop.toml"}))
    with pytest.raises(InputError, match="is a plan of point_mass, not of capler"):
        bench_replan.main(["capler", "--values", "2.9", "3.1", "--init", str(start), "--out", str(tmp_path / "out")])
    assert not (tmp_path / "out").exists()


def test_report_stamps_results_with_the_run(tmp_path, monkeypatch):
    """report() adds "run" to a dict's results.json (and to its printed JSON): the command as the script's parser read
    it, the UTC date-time, the machine; keys of the results stay as they are, a list is written as it is."""
    from scripts import _report

    monkeypatch.setattr(sys, "argv", ["probe_x.py"])
    parser = _report.script_parser("A probe.")
    parser.add_argument("--n", type=int)
    parser.parse_args(["--n", "3"])
    assert _report.report(tmp_path, {"n": 3, "command": "mine"}, "table", False) == 0
    results = json.loads((tmp_path / "results.json").read_text())
    run = results.pop("run")
    assert results == {"n": 3, "command": "mine"} and run["command"] == "python -m scripts.probe_x --n 3"
    assert run["date"].endswith("+00:00") and run["cpu_count"] >= 1 and run["usable_cpus"] >= 1
    for key in ("cpu_model", "platform", "python", "casadi", "numpy", "load_average"):
        assert key in run, key
    _report.report(tmp_path, [1, 2], "table", False)
    assert json.loads((tmp_path / "results.json").read_text()) == [1, 2]


def test_stress_refused_scheduler_leaves_out_untouched(stress, tmp_path, monkeypatch, capsys):
    """A --scheduler refused (here: dask.distributed missing) is exit 2 with OUT not created (it held an empty
    records.partial.jsonl)."""
    monkeypatch.setitem(sys.modules, "dask.distributed", None)  # from dask.distributed import ... -> ImportError
    argv = ["--robot", "point_mass", "--families", "friction", "--per-family", "1", "--scheduler", "tcp://127.0.0.1:1"]
    assert stress.main(argv + ["--out", str(tmp_path / "out")]) == 2
    assert "stress: error: a Dask scheduler was given" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("script", ["bench_replan", "bench_biped_walk", "probe_multiphase", "probe_positions",
                                    "probe_replay", "probe_smoothing"])
def test_scripts_help_says_where_results_go(script, monkeypatch, capsys):
    """--out's help names the default directory (it had no help)."""
    import importlib

    module = importlib.import_module(f"scripts.{script}")
    with pytest.raises(SystemExit) as stopped:
        module.main(["--help"])
    assert stopped.value.code == 0
    printed = " ".join(capsys.readouterr().out.split())  # (argparse wraps the help)
    assert f"output directory (default results/bench/{script.removeprefix('bench_')}" in printed


# --- scripts/bench_pipeline.py -------------------------------------------------------------------------

def test_bench_pipeline_quick_run(tmp_path, capsys, monkeypatch):
    """--quick --codegen --json: the hop's stages (build, derivation and its serialized read-back, solver creation) and, per variant, the
    fixed-iteration NLP 1 split into callbacks and the rest; every variant that keeps the pivoting
    reaches the baseline's iterate (codegen: the same functions compiled). Without gcc the codegen
    variant is skipped with a message, never silently. No timing assertions."""
    bench = _load("bench_pipeline")
    argv = ["--quick", "--codegen", "--json", "--cache", str(tmp_path / "cache"), "--out", str(tmp_path / "out"),
            "--variants", "baseline", "fixed_relax_bounds"]
    assert bench.main(argv) == 0
    results = json.loads(capsys.readouterr().out)
    assert results == json.loads((tmp_path / "out" / "results.json").read_text())
    assert (tmp_path / "out" / "pipeline.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    (rec,) = results["records"]
    assert rec["case"] == "hop" and rec["build_s"] > 0 and rec["solver_create_s"] > 0
    assert rec["derivation_deserialize_s"] > 0 and rec["derivation_serialized_mb"] > 0
    variants = rec["variants"]
    base = variants["baseline"]
    assert base["iterations"] == 10 and set(base["eval_cpu_ms_per_iter"]) == set(bench.CALLBACKS)
    if shutil.which("gcc") is None:
        assert "gcc" in rec["codegen"]["skipped"] and "codegen_O1" not in variants
    else:
        assert variants["codegen_O1"]["iterations"] == base["iterations"]
        assert variants["codegen_O1"]["objective"] == pytest.approx(base["objective"], rel=1e-9)
        assert bench.main(argv) == 0  # the second run loads the cached library
        assert json.loads(capsys.readouterr().out)["records"][0]["codegen"]["cached"]
    monkeypatch.setattr(bench.shutil, "which", lambda name: None)
    assert "gcc not found" in bench.compile_nlp(None, tmp_path / "cache", ["-O1"])["skipped"]


def test_bench_pipeline_plot_keeps_its_legend_inside_the_figure(tmp_path, monkeypatch):
    """pipeline.png with one bar (one case, one variant) shows the whole legend: it sat over the axes in a figure
    1.55 in high and was cut at the figure's edge."""
    bench = _load("bench_pipeline")
    shown = {}
    monkeypatch.setattr(bench, "save_figure", lambda fig, path, dpi: shown.setdefault("fig", fig))
    per_iter = {"rest_cpu_ms_per_iter": 10.0, "eval_cpu_ms_per_iter": {c: 1.0 for c in bench.CALLBACKS}}
    bench.plot([{"case": "hop", "nlp": 1, "variants": {"baseline": per_iter}}], tmp_path / "pipeline.png")
    fig = shown["fig"]
    renderer = fig.canvas.get_renderer()
    fig.draw(renderer)
    (legend,) = fig.legends
    box, frame = legend.get_window_extent(renderer), fig.bbox
    assert frame.x0 <= box.x0 and box.x1 <= frame.x1 and frame.y0 <= box.y0 and box.y1 <= frame.y1, (box, frame)
    assert len(legend.get_texts()) == len(bench.CALLBACKS) + 1

def test_work_precision_plot_labels_walls_between_two_powers_of_ten(tmp_path, monkeypatch):
    """The work-precision panels label their wall-time axis where the walls lie between two powers of ten (the OCP
    quick run's 2.4 and 8.2 s had no number on it: the minor labels were switched off, and no major tick fell inside),
    and keep the minor labels off where a decade is marked (they overlapped)."""
    bench = _load("bench_work_precision")
    shown = []
    monkeypatch.setattr(bench, "save_figure", lambda fig, path, dpi: shown.append(fig))
    errors = {"defect_base_m": 1e-3, "tracking_window_mean_m": 2e-3, "flight_error_m": 1e-4}
    for walls in ((2.39, 8.24), (0.3, 40.0)):
        bench.plot([{"case": "ocp_pm_hop", "variant": "default", "h": h, "converged": True, "wall_time_s": w,
                     "errors": errors} for h, w in zip((0.05, 0.025), walls)], tmp_path / "wp.png", bench.OCP_PANELS)
        fig = shown[-1]
        fig.draw(fig.canvas.get_renderer())
        for ax in fig.axes[:len(bench.OCP_PANELS)]:
            lo, hi = ax.get_xlim()
            labelled = {(which, t.get_text()) for which in ("major", "minor")
                        for t, x in zip(ax.xaxis.get_ticklabels(which=which),
                                        ax.xaxis.get_ticklocs(minor=which == "minor"))
                        if t.get_text() and lo <= x <= hi}
            assert labelled, walls
            if walls[0] < 1:  # 10^0 and 10^1 inside
                assert {which for which, _ in labelled} == {"major"}, labelled


@pytest.mark.parametrize("flag", ["--iters", "--repeats"])
def test_bench_pipeline_rejects_a_count_below_one(capsys, flag):
    """--iters 0 and --repeats 0 are usage errors (exit 2 naming the flag), not the defaults they used to fall back to."""
    bench = _load("bench_pipeline")
    with pytest.raises(SystemExit) as exc:
        bench.main(["--cases", "hop", flag, "0"])
    assert exc.value.code == 2 and f"{flag} must be >= 1, got 0" in capsys.readouterr().err


def test_bench_pipeline_no_lift_builds_the_substituted_nlp(tmp_path, capsys):
    """--no-lift: the cases are built with ProblemOptions(lift_products=False), recorded as such, with the hop's 4
    lifted products per step gone from the variables and rows (N = 6 quick hop: 24 each)."""
    bench = _load("bench_pipeline")
    runs = {}
    for flag in ([], ["--no-lift"]):
        assert bench.main(["--quick", "--json", "--variants", "baseline", "--out", str(tmp_path)] + flag) == 0
        (runs[bool(flag)],) = json.loads(capsys.readouterr().out)["records"]
    assert runs[False]["lift_products"] and not runs[True]["lift_products"]
    assert runs[False]["n_variables"] - runs[True]["n_variables"] == 24 == runs[False]["n_constraints"] - runs[True]["n_constraints"]


def test_bench_pipeline_full_only_takes_solve_options(tmp_path, capsys):
    """--full-only --solve JSON: only the end-to-end solve runs, once per JSON object, with those SolveOptions fields (here
    warm_ipopt max_cpu_time ~0, so NLP 2 on stop with IPOPT's CPU-time status and NLP 1 does not); a field
    or value SolveOptions does not know is a usage error (exit 2)."""
    bench = _load("bench_pipeline")
    solve = json.dumps({"warm_ipopt": {"max_cpu_time": 1e-9}, "rho_schedule": [100, 1000], "polish": "none"})
    assert bench.main(["--quick", "--full-only", "--json", "--out", str(tmp_path), "--solve", solve]) == 0
    (rec,) = json.loads(capsys.readouterr().out)["records"]
    assert rec["variants"] == {} and not (tmp_path / "pipeline.png").exists()
    (full,) = rec["full_solves"]
    assert full["solve"] == json.loads(solve)
    assert full["nlp_status"][0] != "Maximum_CpuTime_Exceeded" and full["nlp_status"][1:] == ["Maximum_CpuTime_Exceeded"]
    with pytest.raises(SystemExit) as exit_info:
        bench.main(["--quick", "--full-only", "--out", str(tmp_path), "--solve", '{"polish": "sometimes"}'])
    assert exit_info.value.code == 2 and "active_set" in capsys.readouterr().err


def test_bench_pipeline_race_records_the_arms(tmp_path, capsys):
    """--full-only --race: the end-to-end solve is a race of the two default arms, recorded per full solve (each
    arm's outcome, exactly one "won") and named in the table's --solve column."""
    bench = _load("bench_pipeline")
    assert bench.main(["--quick", "--full-only", "--race", "--json", "--out", str(tmp_path)]) == 0
    (rec,) = json.loads(capsys.readouterr().out)["records"]
    (full,) = rec["full_solves"]
    assert [a["arm"] for a in full["race"]] == ["default", "alternate"]
    assert [a["outcome"] for a in full["race"]].count("won") == 1
    assert " race: default " in bench.table([rec])


def test_bench_pipeline_capler_set_is_seven_distinct_tasks_and_summarized_per_solve():
    """--cases capler_set names the seven Capler tasks (N = 125, 100, 75, 50; the target's x_B at 2.8, 2.9, 3.1 m, the
    rest of robots/capler.toml unchanged), and a multi-case table ends with one summary row per --solve object
    (converged count, median and total iterations and wall time) computed from its cases only."""
    bench = _load("bench_pipeline")
    tasks = {name: bench.CASES[name](False)[1] for name in bench.CAPLER_SET}
    assert [tasks[n].horizon.N for n in bench.CAPLER_SET] == [125, 100, 75, 50, 125, 125, 125]
    assert [tasks[n].plan.target_q[0] for n in bench.CAPLER_SET] == [3.0, 3.0, 3.0, 3.0, 2.8, 2.9, 3.1]
    assert all(t.plan.target_q[1:] == tasks["capler125"].plan.target_q[1:] and t.plan.holes == tasks["capler125"].plan.holes
               for t in tasks.values())

    def full(solve, its, ok):
        return {"solve": solve, "nlp_iterations": [its], "ipopt_iterations": its, "converged": ok, "control_cost": 1.0,
                "hops": 1, "wall_s": its / 100}
    records = [{"case": c, "variants": {}, "full_solves": [full({}, a, True), full({"x": 1}, b, ok)]}
               for c, a, b, ok in (("capler125", 100, 50, True), ("capler50", 300, 900, False), ("capler75", 200, 70, True))]
    summary = bench.table(records).splitlines()[-2:]
    assert summary == ["| `{}` | 3 of 3 | 200, 600 | 2.0, 6.0 |", '| `{"x": 1}` | 2 of 3 | 70, 1020 | 0.7, 10.2 |']


SAME_OBJECTIVE_REL = 1e-9  # the same IPOPT on the same NLP from the same point: equal up to round-off


def test_bench_pipeline_nlp2_is_the_homotopys_nlp2(tmp_path, capsys):
    """--nlp 2 runs the NLP that solve() hands IPOPT second (from NLP 1's solution, holes and hard terminal
    on, its variables and rho): run to convergence, its baseline takes solve()'s NLP 2 iterations to solve()'s
    NLP 2 objective."""
    bench = _load("bench_pipeline")
    robot, task = bench.hop_case(6)
    nlp2 = H.solve(build_problem(robot, task)).nlps[1]
    assert bench.main(["--quick", "--nlp", "2", "--iters", "3000", "--variants", "baseline", "--json", "--out", str(tmp_path)]) == 0
    (rec,) = json.loads(capsys.readouterr().out)["records"]
    base = rec["variants"]["baseline"]
    assert rec["nlp"] == 2 and base["status"] == nlp2.status == "Solve_Succeeded"
    assert base["iterations"] == nlp2.iterations
    assert base["objective"] == pytest.approx(nlp2.objective, rel=SAME_OBJECTIVE_REL)


# --- scripts/probe_positions.py -------------------------------------------------------------------------

# the simulator's steps meet IPOPT's tol (1e-8) and the complementarity tolerance; a ballistic flight's error under
# the trapezoidal rule is round-off plus those, implicit Euler's is g h t / 2 (~3e-2 m here)
FLIGHT_TOL_M = 1e-6


def test_probe_positions_flight_is_exact_with_the_trapezoid(tmp_path, capsys):
    """The rule's ground truth: the frictionless point mass thrown from (0, 1) m at (1, 0) m/s falls as z = 1 - g t^2 / 2
    at every step before its impact (0.45 s) with the trapezoidal positions, to the solver's tolerance, where implicit
    Euler is off by g h t / 2; outside the block the step is implicit Euler again. And --quick --json writes its records,
    both rules at both steps, the same in results.json."""
    from planner.simulate import simulate
    from planner.task import parse_task
    from scripts import probe_positions as pp

    robot = load_robot("point_mass")
    task = parse_task({"contacts": [{"point": "point", "mu": 0.0, "a_n": 100.0}], "initial": {"q": [0.0, 1.0], "v": [1.0, 0.0]},
                       "horizon": {"tau_f": 0.4, "N": 20}})

    def fall_error(tr):
        return float(np.max(np.abs(tr.q[:, 1] - (1.0 - 0.5 * 9.81 * tr.t**2))))

    with pp.trapezoid_positions():
        assert fall_error(simulate(robot, task).trajectory) <= FLIGHT_TOL_M
    plain = fall_error(simulate(robot, task).trajectory)
    assert plain == pytest.approx(0.5 * 9.81 * 0.02 * 0.4, rel=1e-3)  # g h t / 2 at the last step
    assert pp.main(["--quick", "--json", "--out", str(tmp_path)]) == 0
    rec = json.loads(capsys.readouterr().out)
    assert rec == json.loads((tmp_path / "results.json").read_text())
    assert [(r["rule"], r["h"]) for r in rec["records"]] == [("implicit_euler", 0.04), ("implicit_euler", 0.02),
                                                             ("trapezoid r^2", 0.04), ("trapezoid r^2", 0.02)]


# --- scripts/probe_replay.py ----------------------------------------------------------------------------

# the simulator's steps converge to IPOPT's tol 1e-8; a replay that follows its own rollout differs by round-off
REPLAY_TOL = 1e-6
BY_CLOCK_TOL = 0.02  # [m] base; the rollout's steps advance its clock within 2e-4 s of h = 0.25 s (measured 1.0e-2 m)
FROZEN_STANCE_MIN = 1.0  # a frozen standing step leaves products of order a_n h (measured 7.5-16 at N = 10); 1 is far above comp_tol


def test_probe_replay_follows_a_rollout_of_the_simulator(tmp_path):
    """A 'plan' that is the simulator's own rollout (Capler, N = 10, joint PD on a swinging knee reference) is a
    solution of every step, so the replay by step index stays on it (no departure, deviation at round-off) and that
    plan's steps solve the simulator's step NLP (rows at the solver's tolerance, complementarity rows >= 0); read one
    step late (the reference of step k + 1) the PD no longer vanishes at the plan's states and the replay leaves it.
    Its step 3 with the clock advance fixed is exact at its own advance and not at 0; it has no landing, and one
    node lifted 0.1 m makes the next one a landing. Read by its own clock the replay stays within BY_CLOCK_TOL of it.
    The lift-off-first rule follows it too, and the two first-start rules exclude each other."""
    from planner.simulate import SimulateOptions
    from scripts import probe_multiphase as pm
    from scripts import probe_replay as pr
    from scripts.bench_pipeline import capler_case

    problem = build_problem(*capler_case(10))
    nq, nv, nu = problem.system.nq, problem.system.nv, problem.system.nu
    q0 = problem.y0[:nq]

    def swing(k, clock):
        return np.zeros(nu), q0 + np.array([0.0, 0.0, 0.0, 0.3 * math.sin(0.6 * (k + 1))]), np.zeros(nv)

    x, info = pm.stepwise_start(problem, None, "pd", at=swing)
    assert info["steps_failed"] == 0
    rec = pr.replay(problem, x, 200.0, 5.0, plan_first=False)
    assert rec["departure"] is None and rec["max_deviation"] <= REPLAY_TOL and rec["steps_failed"] == 0
    vb, rollout = problem.var_blocks, problem.split(x)
    res = pr.step_residual(problem, 3, rollout["Y"], rollout["W"], rollout["U"])
    assert res["equality_max"] <= STEP_ROW_TOL and res["complementarity_min"] >= -SimulateOptions().comp_tol  # products within it
    # the step with its clock advance fixed: exact at its own advance, far from it at 0 (standing cannot be frozen: no
    # impact to absorb); clock_family warm-starts every advance from the step's own solution
    Y, W, U = rollout["Y"], rollout["W"], rollout["U"]
    own = Y[4, -1] - Y[3, -1]
    rows = pr.clock_family(problem, 3, Y[3], U, np.concatenate([Y[4], W[3]]), [own, 0.0])
    assert rows[0]["complementarity"] <= SimulateOptions().comp_tol and rows[1]["complementarity"] > FROZEN_STANCE_MIN
    assert pr.landings(problem, Y, W, U) == []  # standing: no node above the ground
    lifted = Y.copy()
    lifted[2, 1] += 0.1  # the base (and the foot) 0.1 m up at node 2, down again at node 3: a landing at node 3
    assert [ld["node"] for ld in pr.landings(problem, lifted, W, U)] == [3]
    late = x.copy()
    late[vb["y"][:-1]] = x[vb["y"][1:]]  # step k's reference becomes the state after step k + 1
    assert pr.replay(problem, late, 200.0, 5.0, plan_first=False)["max_deviation"] > 10 * REPLAY_TOL
    # the lift-off-first rule tries a free-flight start first; standing, no step has a flight solution, so the
    # replay takes the same branches as the rollout
    rec = pr.replay(problem, x, 200.0, 5.0, plan_first=False, liftoff_first=True)
    assert rec["departure"] is None and rec["max_deviation"] <= REPLAY_TOL
    # read by the rollout's own clock the reference is interpolated between nodes whose clocks are not exactly k h
    rec = pr.replay(problem, x, 200.0, 5.0, plan_first=False, by_clock=True)
    assert rec["by_clock"] and rec["max_deviation"] <= BY_CLOCK_TOL
    with pytest.raises(ValueError):
        pr.replay(problem, x, 200.0, 5.0, plan_first=True, liftoff_first=True)
    for argv in (["--first-rho0", "1e4"], ["--plan-first", "--liftoff-first"], ["--family", "-1"], ["--by-clock", "--plan-first"]):  # user errors
        with pytest.raises(SystemExit):
            pr.main([str(tmp_path), *argv])


LQR_DYNAMICS_TOL = 1e-8  # [m/s^2] MuJoCo's own accelerations and ours differ by round-off only


def test_probe_lqr_models_mujoco_and_keeps_the_validation_baseline(tmp_path, capsys):
    """probe_lqr: its unconstrained accelerations are MuJoCo's (contacts off) at a random Capler state, its impact
    map leaves the pinned foot at rest, its joint-PD baseline is the validation's tracking replay on the same plan
    (the same largest base error), and --quick --json writes the documented record as printed."""
    import mujoco

    from planner import replay as R
    from planner.cli import main as planner_main

    probe = _load("probe_lqr")
    rng = np.random.default_rng(0)
    plan = tmp_path / "hop"
    task = tmp_path / "hop.toml"
    task.write_text(probe.QUICK_TASK)
    assert planner_main(["plan", "point_mass", "--task", str(task), "--out", str(plan), "--no-validate", "--no-plots", "-q"]) == 0
    rec = probe.probe(plan, 1e4, 1e2, 1.0, 1.0, 20, 1e-6)
    assert rec["joint_pd"]["max_base_error_m"] == R.validate(plan).tracking.max_base_error_m

    robot_dir = Path(__file__).resolve().parent.parent / "robots"
    scene = R.build_scene(load_robot(robot_dir / "capler.xml"), load_task(robot_dir / "capler.toml"))
    model = probe._Model(scene)
    q = np.array([0.3, 0.35, 0.4, -0.6]) + 0.05 * rng.standard_normal(4)
    v, u = rng.standard_normal(4), 5 * rng.standard_normal(2)  # inside the motors' +-60 N m
    off = mujoco.MjData(scene.model)
    flags = scene.model.opt.disableflags
    scene.model.opt.disableflags = flags | int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    try:
        off.qpos[:], off.qvel[:], off.ctrl[:] = q, v, u
        mujoco.mj_forward(scene.model, off)
    finally:
        scene.model.opt.disableflags = flags
    assert np.max(np.abs(model.accel(q, v, u, []) - off.qacc)) < LQR_DYNAMICS_TOL
    G = model.impact_map(q, [0])
    foot = model._jacobian(model.data, [0])
    assert np.max(np.abs(foot @ (G[4:, 4:] @ v))) < LQR_DYNAMICS_TOL

    assert probe.main(["--quick", "--json", "--out", str(tmp_path / "out")]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out == json.loads((tmp_path / "out" / "results.json").read_text())
    for name in ("lqr", "joint_pd"):
        assert {"max_base_error_m", "base_error_up_to_m", "saturation", "mujoco_impacts_s"} <= set(out[name])


SECANT_FORCE_TOL = 1e-9  # [N] the patched CasADi rows against Pinocchio's numeric Jacobians: round-off only
ENERGY_TOL = 1e-9  # [J] the point mass's implicit-Euler energy identity: round-off only
SAME_NUMBERS_TOL = 1e-12  # the probe's velocities and energies of the point mass against J = I and m |v|^2 / 2: round-off
NO_DAE_SHARE = 1e-8  # alpha below this: the step mixes in no DAE field (no contact force besides the auxiliary ones)
DROP_TASK = ('[[contacts]]\npoint = "point"\nmu = 0.5\n[initial]\nq = [0.0, 0.2]\nv = [0.5, 0.0]\n'
             '[horizon]\ntau_f = 1.0\nN = 10\n[plan]\ntarget_q = [0.5, 0.0]\nu_bound = 30.0\n')


def test_probe_impacts_secant_impulses_act_along_the_secant_gradients():
    """probe_impacts.secant_impulses: on a Capler step whose posture moves, the patched step's velocity rows differ
    from the plain step's by exactly -h s [c_n a_n (nbar - n(q_{k+1})) + c_t a_t (tbar - t(q_{k+1}))], with the
    paper's Sec. 6 coefficients c_n = (1 - beta)(1 - 2 alpha + alpha gamma), c_t = (1 - beta)(1 - 2 zeta) and nbar,
    tbar the foot's height and x gradients averaged over the segment by 3-point Gauss-Legendre from Pinocchio's
    numeric Jacobians; every other row is unchanged, and after the block the step is the plain one again."""
    import pinocchio as pin

    from scripts.bench_pipeline import capler_case

    probe = _load("probe_impacts")
    problem = build_problem(*capler_case(10))
    builder, system = problem.builder, problem.system
    ny, nq, nv, nu, h, s = system.ny, system.nq, system.nv, system.nu, problem.h, 1.3
    yk, y1, u = ca.SX.sym("yk", ny), ca.SX.sym("y1", ny), ca.SX.sym("u", nu)

    def rows():
        step = builder.build(yk, y1, u, s, h)
        return ca.Function("g", [yk, y1, u, step.w], [step.g])

    plain = rows()
    with probe.secant_impulses():
        patched = rows()
    after = rows()
    rng = np.random.default_rng(0)
    q0 = np.array([0.3, 0.35, 0.4, -0.6])
    q1 = q0 + np.array([0.02, -0.01, 0.25, -0.3])
    args = (np.concatenate([q0, rng.standard_normal(nv), [0.5]]), np.concatenate([q1, rng.standard_normal(nv), [0.51]]),
            rng.standard_normal(nu))
    alpha, beta, gamma, zeta = 0.3, 0.2, 0.1, 0.3
    w = builder.w_from([alpha, beta, gamma, zeta], np.zeros(4), np.zeros(4))
    diff = np.asarray(patched(*args, w) - plain(*args, w)).ravel()

    model = system.dyn.robot.model
    data, frame = model.createData(), system.dyn.robot.frame_id("foot")

    def jacobian(q):
        return pin.computeFrameJacobian(model, data, q, frame, pin.LOCAL_WORLD_ALIGNED)[:3]

    nodes = (0.5 - math.sqrt(15) / 10, 0.5, 0.5 + math.sqrt(15) / 10)
    weights = (5 / 18, 4 / 9, 5 / 18)
    bar = sum(wt * jacobian(q0 + c * (q1 - q0)) for c, wt in zip(nodes, weights))
    contact = system.contacts[0]
    c_n, c_t = (1 - beta) * (1 - 2 * alpha + alpha * gamma), (1 - beta) * (1 - 2 * zeta)
    expected = -h * s * (c_n * contact.a_n * (bar[2] - jacobian(q1)[2]) + c_t * contact.a_t * (bar[0] - jacobian(q1)[0]))
    assert np.max(np.abs(diff[nq : nq + nv] - expected)) < SECANT_FORCE_TOL
    assert np.max(np.abs(expected)) > 1.0  # a posture that moves 0.3 rad: the secant is not the end point
    assert np.max(np.abs(np.delete(diff, np.s_[nq : nq + nv]))) == 0.0
    assert np.max(np.abs(np.asarray(after(*args, w) - plain(*args, w)))) == 0.0


def test_probe_impacts_balances_a_point_mass_landing(tmp_path, capsys):
    """probe_impacts on a planned point-mass drop: the contact point's velocities are the mass's own (J = I), the
    kinetic energies are m |v|^2 / 2 with the file's mass, and in every step of a frozen run without a DAE share
    (alpha = 0) the balance's rest is implicit Euler's exact loss -m |v_{k+1} - v_k|^2 / 2 (M constant) less the
    motors' and gravity's work on the part of the step the ODE field does not move (dq - h s c_ode v_{k+1}: the
    other fields' coefficients at alpha = 0 are the lifted products' residual, ~1e-9, not 0, so a plan's rest
    differs from the loss by ~1e-9 J on some plans, e.g. the race's alternate arm's); the landing loses energy;
    --json writes the record as printed. The plan is the default solve's (--no-race), not the race's winner."""
    import pinocchio as pin

    from planner.cli import main as planner_main
    from scripts.probe_replay import plan_problem

    probe = _load("probe_impacts")
    plan, task = tmp_path / "drop", tmp_path / "drop.toml"
    task.write_text(DROP_TASK)
    assert planner_main(["plan", "point_mass", "--task", str(task), "--out", str(plan), "--no-validate", "--no-plots", "--no-race", "-q"]) == 0
    capsys.readouterr()
    assert probe.main([str(plan), "--json", "--out", str(tmp_path / "out")]) == 0
    rec = json.loads(capsys.readouterr().out)
    assert rec == json.loads((tmp_path / "out" / "results.json").read_text())
    problem, x = plan_problem(plan)
    parts = problem.split(x)
    Y, U, W, S = parts["Y"], parts["U"], parts["W"], parts["S"]
    mass = pin.computeTotalMass(problem.system.dyn.robot.model)  # Pinocchio's, from the file
    summary = json.loads((plan / "summary.json").read_text())
    alpha = problem.builder.w_blocks["sigma"].start  # alpha[point] is the first selector
    sys_, nq = problem.system, problem.system.nq
    ode = [f.name for f in sys_.fields].index("ode")
    checked = 0
    assert rec["impacts"] and len(rec["impacts"]) == len(summary["impacts"])
    for r, imp in zip(rec["impacts"], summary["impacts"]):
        for v, n, t, e in zip((imp["v_pre"], imp["v_post"]), r["normal_velocity"], r["tangential_velocity"], r["kinetic_energy"]):
            assert (t, n) == pytest.approx(tuple(v), abs=SAME_NUMBERS_TOL)
            assert e == pytest.approx(0.5 * mass * float(np.dot(v, v)), rel=SAME_NUMBERS_TOL)
        for st in r["steps"]:
            k = st["step"]
            if W[k, alpha] < NO_DAE_SHARE:
                force = mass * np.asarray(sys_.fields_fn(Y[k + 1], U[k]))[nq : 2 * nq, ode]  # B u + gravity [N]
                unmoved = Y[k + 1, :nq] - Y[k, :nq] - problem.h * S[k] * problem.builder.coefficients(W[k])[ode] * Y[k + 1, nq : 2 * nq]
                loss = -0.5 * mass * float(np.sum((Y[k + 1, nq : 2 * nq] - Y[k, nq : 2 * nq]) ** 2))
                assert st["rest"] == pytest.approx(loss - float(force @ unmoved), abs=ENERGY_TOL)
                checked += 1
    assert checked >= 1
    first = rec["impacts"][0]
    assert first["normal_velocity"][0] < 0 and first["kinetic_energy"][1] < first["kinetic_energy"][0]


def test_probe_replay_landings_reads_every_contact():
    """probe_replay.landings on the biped's standing start (two feet on the ground): lifted 0.1 m at node 2, both feet
    land at node 3, each listed with its contact point; the standing nodes list none."""
    from scripts import probe_replay as pr

    robot_dir = Path(__file__).resolve().parent.parent / "robots"
    problem = build_problem(load_robot(robot_dir / "biped.xml"), load_task(robot_dir / "biped.toml"))
    N = problem.N
    Y = np.tile(problem.y0, (N + 1, 1))
    W, U = np.zeros((N, problem.builder.nw)), np.zeros((N, problem.system.nu))
    assert pr.landings(problem, Y, W, U) == []
    Y[2, 1] += 0.1  # the hip's z, and both feet with it
    assert [(ld["node"], ld["contact"]) for ld in pr.landings(problem, Y, W, U)] == [(3, "foot_1"), (3, "foot_2")]


# --- scripts/bench_fatrop.py ---------------------------------------------------------------------------

def test_bench_fatrop_smoke_run_and_its_input_errors(tmp_path, capsys):
    """The point-mass hop at N = 6, three iterations of each solver: --out gets the JSON record with one run per solver
    and the staged sizes, the table is printed; an unknown solver, an option without "=", an option IPOPT does not know
    and an --out in a missing directory are one line and exit 2 (they were tracebacks, the last after the whole run).
    No timing assertions."""
    bench = _load("bench_fatrop")
    out = tmp_path / "fatrop.json"
    assert bench.main(["--case", "hop", "--N", "6", "--max-iter", "3", "--out", str(out)]) == 0
    record = json.loads(out.read_text())
    assert [r["solver"] for r in record["runs"]] == ["ipopt", "fatrop"] and record["staged_nx"] > record["nx"]
    printed = capsys.readouterr().out
    assert "| fatrop | 1 | 3 |" in printed and json.loads(out.read_text())["run"]["cpu_count"]
    base = ["--case", "hop", "--N", "6", "--max-iter", "3"]
    for bad, message in ((["--solvers", "nope"], "invalid choice: 'nope'"), (["--out", str(tmp_path / "missing" / "x.json")], "no writable directory")):
        with pytest.raises(SystemExit) as stopped:
            bench.main(base + bad)
        assert stopped.value.code == 2 and message in capsys.readouterr().err
    for bad, message in ((["--fatrop-opt", "nokey"], "expected key=value"),
                         (["--solvers", "ipopt", "--ipopt-opt", "bogus_option=3"], "No such IPOPT option: bogus_option")):
        with pytest.raises(InputError, match=message):  # run_main makes it one line and exit 2
            bench.main(base + bad)
    assert "|---|---|" in printed  # a Markdown table: it lacked the row under its header

    def solve(*args):
        raise AssertionError("a solver ran before the options were checked")

    bench.run = solve  # (the module is this test's own: _load)
    for bad, message in ((["--fatrop-opt", "bogus=1"], "Fatrop option not supported: bogus"),  # after the IPOPT run
                         (["--solvers", "fatrop", "ipopt", "--ipopt-opt", "bogus_option=3"], "No such IPOPT option")):
        with pytest.raises(InputError, match=message):
            bench.main(base + bad)


def test_a_ctrl_c_in_a_scripts_planner_command_stops_the_script(monkeypatch, capsys):
    """A `planner` command run by a script that exits 130 (Ctrl-C inside it) raises KeyboardInterrupt in the script
    (bench_replan went on to its next run and recorded the interrupted one, exit 0), and run_main turns that into one
    line `SCRIPT: interrupted` and exit 130, as `planner` does; any other exit code is returned."""
    import planner.cli
    from scripts import _report

    monkeypatch.setattr(planner.cli, "main", lambda argv: 130)
    with pytest.raises(KeyboardInterrupt):
        _report.planner_command(["plan", "point_mass"])
    monkeypatch.setattr(planner.cli, "main", lambda argv: 1)
    assert _report.planner_command(["plan", "point_mass"]) == 1

    def interrupted():
        raise KeyboardInterrupt

    monkeypatch.setattr(sys, "argv", ["bench_x.py"])
    assert _report.run_main(interrupted) == 130
    assert capsys.readouterr().err == "bench_x: interrupted\n"


@pytest.mark.parametrize("script", ["bench_replan", "bench_biped_walk"])
def test_an_interrupted_rerun_leaves_no_results_json_of_the_runs_it_replaced(tmp_path, monkeypatch, script):
    """A rerun into an --out removes the earlier run's results.json before it empties the run directories that file
    describes: interrupted (Ctrl-C in its first `planner plan`), it left the old results.json naming plans it had
    already deleted."""
    import importlib

    module = importlib.import_module(f"scripts.{script}")
    out = tmp_path / "out"
    out.mkdir()
    (out / "results.json").write_text('{"runs": ["an earlier run"]}\n')

    def interrupted(argv):
        raise KeyboardInterrupt

    monkeypatch.setattr(module, "planner_command", interrupted)
    with pytest.raises(KeyboardInterrupt):
        module.main(["--quick", "--out", str(out)])
    assert not (out / "results.json").exists()


def test_bench_pipeline_and_replan_run_a_name_given_twice_once(tmp_path, monkeypatch):
    """bench_pipeline's cases and variants and bench_replan's variants named twice run once each (they ran twice, the
    replan's second run deleting the first one's plan); capler125 beside capler_set, which holds it, runs once."""
    import contextlib
    import importlib

    pipeline = importlib.import_module("scripts.bench_pipeline")
    seen = []
    monkeypatch.setattr(pipeline, "run_case", lambda name, quick, iters, repeats, variants, *rest: seen.append(
        (name, tuple(variants))) or {"case": name, "variants": []})
    monkeypatch.setattr(pipeline, "table", lambda records, *rest: "")
    argv = ["--cases", "hop", "hop", "capler125", "capler_set", "--variants", "baseline", "spral", "spral",
            "--out", str(tmp_path / "pipe"), "--json"]
    with contextlib.suppress(Exception):  # (the report of the stubbed records is not this test's)
        pipeline.main(argv)
    assert [name for name, _ in seen] == list(dict.fromkeys(["hop", "capler125", *pipeline.CAPLER_SET]))
    assert all(variants == ("baseline", "spral") for _, variants in seen)
    replan = importlib.import_module("scripts.bench_replan")
    runs = []
    monkeypatch.setattr(replan, "plan", lambda robot, task, out, extra, validate: runs.append(extra)
                        or {"exit_code": 0})
    monkeypatch.setattr(replan, "table", lambda rows: "")
    replan.main(["--quick", "--variants", "keep_schedule", "keep_schedule", "--out", str(tmp_path / "replan"),
                 "--json"])
    assert len([r for r in runs if "--init" in r]) == 1


def test_bench_skips_runs_a_case_named_twice_once(tmp_path, monkeypatch):
    """`bench_skips --cases A A` runs A once (it ran twice and wrote two records of it)."""
    import importlib

    module = importlib.import_module("scripts.bench_skips")
    names = []

    def recorded(cases, quick, log):
        names.extend(cases)
        raise KeyboardInterrupt  # (the run itself is not this test's)

    monkeypatch.setattr(module, "run", recorded)
    case = sorted(module.CASES)[0]
    with pytest.raises(KeyboardInterrupt):
        module.main(["--quick", "--cases", case, case, "--out", str(tmp_path / "out")])
    assert names == [case]


def test_a_script_whose_reader_left_exits_0():
    """`python -m scripts.stress --list | head -1`: the reader leaving is no failure (it printed "stress: failed: Broken
    pipe" and exited 1, which docs/stability.md keeps for a crashed task)."""
    proc = subprocess.Popen([sys.executable, "-m", "scripts.stress", "--list", "--per-family", "20"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=SCRIPTS.parent)
    proc.stdout.readline()
    proc.stdout.close()
    err = proc.stderr.read().decode()
    assert proc.wait() == 0 and "failed" not in err, err


# --- session 56's tester: scripts' defaults, refusals and order of writes ----------------------------------------

def test_bench_pipeline_codegen_generates_inside_its_cache(tmp_path, monkeypatch):
    """compile_nlp generates its C file inside --cache and removes it: the working directory is left as it was and the
    cache holds the library only. CasADi wrote the file into the cwd and Path.replace moved it into the cache, which
    failed across filesystems (--cache in /dev/shm: "Invalid cross-device link", exit 1) and left it in the cwd."""
    if shutil.which("gcc") is None:
        pytest.skip("the codegen variant needs gcc")
    bench = _load("bench_pipeline")
    generated_in = []

    class Solver:  # CasADi's generate_dependencies as it behaves: a C name, written into the working directory
        def generate_dependencies(self, name, opts):
            generated_in.append(Path.cwd())
            Path(name).write_text("double tiny(double x) { return 2 * x; }\n")
            return name

    cwd, cache = tmp_path / "cwd", tmp_path / "cache"
    cwd.mkdir()
    monkeypatch.chdir(cwd)
    info = bench.compile_nlp(Solver(), cache, bench.DEFAULT_CODEGEN_FLAGS)
    assert generated_in[0].parent == cache.resolve() and list(cwd.iterdir()) == []
    assert [p.name for p in cache.iterdir()] == [Path(info["so"]).name] and info["c_bytes"] > 0
    with pytest.raises(InputError, match="gcc refused --codegen-flags -Obogus"):  # a failed compile leaves none either
        bench.compile_nlp(Solver(), tmp_path / "cache2", ["-Obogus"])
    assert list(cwd.iterdir()) == [] and list((tmp_path / "cache2").iterdir()) == []


def test_bench_replan_refuses_a_start_plan_of_another_n(tmp_path, monkeypatch):
    """--init of a plan whose horizon.N is not the replanned task's is refused up front in one InputError naming both
    N (every replan was a "refused" row, exit 0, and `planner plan`'s advice named --steps, which bench_replan lacks);
    a start of the task's N is taken."""
    from planner.task import task_to_json

    bench = _load("bench_replan")
    task = load_task(bench.ROOT / "robots" / "point_mass_hop.toml")

    def start_plan(N: int) -> Path:
        start = tmp_path / f"hop{N}"
        start.mkdir()
        solved = dataclasses.replace(task, horizon=dataclasses.replace(task.horizon, N=N))
        np.savez(start / "trajectory.npz", nlp_x=np.zeros(3), task_json=np.array(task_to_json(solved)))
        (start / "summary.json").write_text(json.dumps({"robot": "robots/point_mass.xml", "task": "hop.toml"}))
        return start

    monkeypatch.setattr(bench, "planner_command", lambda argv: 2)  # (no solve: each replan a refused row)
    with pytest.raises(InputError, match=r"is a plan with horizon.N = 40, and the tasks replanned here have N = 20: "
                                         r"give a plan with N = 20"):
        bench.main(["--quick", "--init", str(start_plan(40)), "--out", str(tmp_path / "out")])
    assert not (tmp_path / "out").exists()
    assert bench.main(["--quick", "--init", str(start_plan(20)), "--out", str(tmp_path / "out")]) == 0


def test_work_precision_checks_its_default_out_before_running(bench, tmp_path, monkeypatch, capsys):
    """The suite's default --out is checked before any case runs, as a given --out is: its results.json a directory
    was found only after the whole run (prepare_out_dir let it through)."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "results" / "bench" / "work_precision_ocp" / "results.json").mkdir(parents=True)
    monkeypatch.setitem(bench.SUITES, "ocp", lambda *args, **kwargs: pytest.fail("the suite ran before --out's check"))
    with pytest.raises(SystemExit) as stopped:
        bench.main(["--suite", "ocp", "--quick"])
    err = capsys.readouterr().err
    assert stopped.value.code == 2 and "argument --out (default): results/bench/work_precision_ocp/results.json is a " \
        "directory" in err and len(err.splitlines()) == 1, err


def test_probe_early_stop_refuses_an_nlp_named_twice_in_at(tmp_path, monkeypatch, capsys):
    """--at 2:5 2:10 is one line and exit 2 before any build: the probe ran 2:10 only (dict() kept the last item of an
    NLP) while results.json's command recorded both."""
    import importlib

    module = importlib.import_module("scripts.probe_early_stop")
    monkeypatch.setattr(module, "build_problem", lambda *args: pytest.fail("built before --at was checked"))
    with pytest.raises(SystemExit) as stopped:
        module.main(["--case", "hop", "--at", "2:5", "2:10", "3:7", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert stopped.value.code == 2 and len(err.splitlines()) == 1, err
    assert "--at names NLP 2 more than once: give its iterations in one item, K:J1,J2,..." in err
    assert not (tmp_path / "out").exists()


def test_bench_pipeline_checks_its_cache_only_with_codegen(tmp_path, monkeypatch, capsys):
    """The default --cache is checked only where it is used, with --codegen, and refused there up front: a HOME where
    no cache can be made (HOME=/proc) refused every bench_pipeline run, with --codegen or not."""
    bench = _load("bench_pipeline")
    (tmp_path / "a_file").write_text("")
    monkeypatch.setattr(bench, "DEFAULT_CACHE", tmp_path / "a_file" / "codegen")

    class Ran(Exception):
        pass

    def ran(*args):
        raise Ran

    monkeypatch.setattr(bench, "run_case", ran)
    with pytest.raises(Ran):  # (the run itself is not this test's)
        bench.main(["--quick", "--variants", "baseline", "--out", str(tmp_path / "out")])
    with pytest.raises(SystemExit) as stopped:
        bench.main(["--quick", "--codegen", "--variants", "baseline", "--out", str(tmp_path / "out")])
    assert stopped.value.code == 2 and "argument --cache (default): " in capsys.readouterr().err


@pytest.mark.parametrize("script", ["bench_replan", "bench_biped_walk", "bench_nosnoc", "bench_pipeline", "bench_skips",
                                    "stress", "probe_early_stop", "probe_impacts", "probe_lqr", "probe_multiphase",
                                    "probe_positions", "probe_replay", "probe_smoothing", "probe_steps"])
def test_a_scripts_default_out_is_the_relative_directory_its_help_names(script, monkeypatch, capsys):
    """A script's default --out is the directory its help names, relative to the working directory as the help reads:
    the scripts built on the repository's root (bench_replan, bench_biped_walk, probe_*) wrote into the repository's
    results/ from any working directory, the others into the working directory's."""
    import importlib

    from scripts import _report

    module = importlib.import_module(f"scripts.{script}")
    parsers = []
    monkeypatch.setattr(module, "script_parser", lambda doc, **kw: parsers.append(_report.script_parser(doc, **kw))
                        or parsers[-1])
    with pytest.raises(SystemExit):
        module.main(["--help"])
    default = parsers[0].get_default("out")
    assert isinstance(default, Path) and not default.is_absolute(), default
    assert f"(default {default}" in " ".join(capsys.readouterr().out.split())  # (argparse wraps the help)


def test_readmes_bench_replan_commands_run(tmp_path, monkeypatch):
    """Each `python -m scripts.bench_replan ...` README.md quotes takes its arguments and goes on to its first plan: it
    cited a bare `python -m scripts.bench_replan`, which exits 2 (--values is required)."""
    bench = _load("bench_replan")
    commands = re.findall(r"`python -m scripts\.bench_replan([^`]*)`", (SCRIPTS.parent / "README.md").read_text())
    assert commands

    class Planning(Exception):
        pass

    def planning(*args):
        raise Planning

    monkeypatch.setattr(bench, "plan", planning)
    for args in commands:
        with pytest.raises(Planning):
            bench.main(shlex.split(args) + ["--out", str(tmp_path / "out")])


def test_formulation_says_its_bip_step_command_is_not_shipped():
    """docs/formulation.md's command of bip_step.py (session 8's scratch driver, which the repository does not hold)
    says so on its line: it was quoted as `bip_step.py --n_fe 6 ...`, as a script one could run from here."""
    root = SCRIPTS.parent
    lines = [line for line in (root / "docs" / "formulation.md").read_text().splitlines()
             if "bip_step.py" in line and "--n_fe 6" in line]
    assert lines and all("not shipped" in line for line in lines), lines
    assert not list(root.glob("*/bip_step.py")) and not (root / "bip_step.py").exists()


def test_probes_of_a_plan_refuse_a_simulate_result(tmp_path, monkeypatch, capsys):
    """probe_impacts and probe_replay given a `planner simulate` result say that it is no plan, in one line, exit 2:
    they said "task .../trajectory.npz has no [plan] table; `planner plan` needs one", as if a task were wrong."""
    import importlib

    from planner.cli import main as planner_main

    drop = tmp_path / "drop"
    assert planner_main(["simulate", "point_mass", "--out", str(drop), "-q", "--no-plots"]) == 0
    capsys.readouterr()
    for script in ("probe_impacts", "probe_replay"):
        module = importlib.import_module(f"scripts.{script}")
        monkeypatch.setattr(sys, "argv", [f"{script}.py"])  # (the name run_main gives the error)
        code = run_main(lambda: module.main([str(drop), "--out", str(tmp_path / "out")]))
        err = capsys.readouterr().err
        assert code == 2 and err == (f"{script}: error: {drop} is a `planner simulate` result, not a plan: give one of "
                                     "`planner plan`\n"), err
    assert not (tmp_path / "out").exists()


def test_stress_list_refuses_the_runs_arguments(stress, tmp_path, capsys):
    """--list prints the tasks and exits: --race, --json and --out beside it are refused (one line, exit 2), and an
    invalid --workers -1 too; they were ignored silently (the --workers check came after --list)."""
    for extra, said in ((["--json", "--race"], "--list prints the tasks and exits: give no --race or --json with it"),
                        (["--out", str(tmp_path / "out")], "give no --out with it"),
                        (["--workers", "-1"], "--workers must be >= 0, got -1")):
        with pytest.raises(SystemExit) as stopped:
            stress.main(["--robot", "point_mass", "--list", *extra])
        printed = capsys.readouterr()
        assert stopped.value.code == 2 and said in printed.err and printed.out == "", printed


def test_bench_pipeline_writes_its_results_before_its_plot(tmp_path, monkeypatch):
    """results.json is written before pipeline.png is drawn, so a plot that fails loses no run (the plot came first),
    and an earlier run's plot does not stay beside the new results as theirs."""
    bench = _load("bench_pipeline")
    per_iter = {"iterations": 10, "objective": 1.0, "cpu_ms_per_iter": 2.0, "wall_ms_per_iter": 2.0,
                "rest_cpu_ms_per_iter": 1.0, "eval_cpu_ms_per_iter": {c: 0.2 for c in bench.CALLBACKS}, "create_s": 0.1}
    monkeypatch.setattr(bench, "run_case", lambda name, *rest: {"case": name, "nlp": 1, "full_solves": [],
                                                                 "variants": {"baseline": per_iter}})

    def failed(records, path):
        raise RuntimeError("the plot failed")

    monkeypatch.setattr(bench, "plot", failed)
    out = tmp_path / "out"
    out.mkdir()
    (out / "pipeline.png").write_bytes(b"an earlier run's plot")
    with pytest.raises(RuntimeError, match="the plot failed"):
        bench.main(["--quick", "--variants", "baseline", "--out", str(out), "--json"])
    assert json.loads((out / "results.json").read_text())["records"][0]["variants"]["baseline"]["iterations"] == 10
    assert not (out / "pipeline.png").exists()


EQUIVALENT_TOL = 1e-9  # [m, m/s] round-off of IPOPT's solution (tol 1e-8) of two NLPs equal to the bit after the map


def test_probe_equivalent_quick_run(tmp_path, capsys):
    """--quick --json: results.json holds the hop's base, shifted and mirrored variants, with and without friction;
    the frictionless hop's shifted and mirrored plans map back onto the base's to round-off (the NLPs are the same
    up to the map, which checks the script's map), and every record says its iterations, cost and difference."""
    probe = _load("probe_equivalent")
    assert probe.main(["--quick", "--json", "--out", str(tmp_path)]) == 0
    results = json.loads(capsys.readouterr().out)
    assert results == json.loads((tmp_path / "results.json").read_text())
    records = {(r["case"], r["variant"]): r for r in results["records"]}
    variants = ("base", f"shifted {probe.SHIFT:g} m", "mirrored")
    assert set(records) == {(case, v) for case in ("hop", "hop, frictionless") for v in variants}
    for v in variants:
        assert records["hop, frictionless", v]["max_node_state_diff"] <= EQUIVALENT_TOL, v
    for r in records.values():
        assert r["ipopt_iterations"] > 0 and math.isfinite(r["control_cost"]) and "nlp1_objective" in r


def test_probe_equivalents_mirror_map_mirrors_capler():
    """probe_equivalent's mirror of Capler (x and both leg angles negated) puts the foot, the knee and the base at the
    x-mirror images of their places at q, for seeded random q: the map that compares a mirrored plan with the base's
    is the mirror of the robot (its two leg angles turn about y)."""
    from planner.dynamics import Dynamics
    from planner.model import load_robot

    probe = _load("probe_equivalent")
    robot_name, [(_, variants)] = probe.capler_case(False)
    mirror = next(v for v in variants if v.name == "mirrored")
    dyn = Dynamics(load_robot(robot_name))
    rng = np.random.default_rng(0)
    for q in rng.uniform(-1.0, 1.0, size=(20, 4)):
        for point in ("foot", "knee", "base"):
            p, m = (np.asarray(dyn.point_position(point)(x), float).ravel() for x in (q, mirror.sign * q))
            np.testing.assert_allclose(m, p * [-1.0, 1.0, 1.0], rtol=0, atol=EQUIVALENT_TOL)


class _ClockedSolver:
    """A solver whose call takes 1 s of CPU and 3 s of wall (a loaded machine) on a fake clock, 10 iterations."""

    def __init__(self, monkeypatch, module, stats):
        self.clock = {"cpu": 0.0, "wall": 0.0}
        self.stats_ = stats
        monkeypatch.setattr(module.time, "process_time", lambda: self.clock["cpu"])
        monkeypatch.setattr(module.time, "perf_counter", lambda: self.clock["wall"])

    def __call__(self, **kwargs):
        self.clock["cpu"] += 1.0
        self.clock["wall"] += 3.0
        return {"f": 1.0, "x": np.zeros(1)}

    def stats(self):
        return self.stats_


def test_bench_pipeline_times_cpu_as_process_time_and_takes_the_repeats_median(monkeypatch):
    """bench_pipeline's cpu_ms_per_iter is process time, wall_ms_per_iter wall time, the rest CPU less the callbacks'
    CPU; over repeats the record is the median (session 66's mutation testing: CPU measured as wall, the callbacks'
    wall subtracted, the mean taken, each with every test green). Ground truth: a fake clock."""
    pipeline = _load("bench_pipeline")
    stats = {"iter_count": 10, "return_status": "Maximum_Iterations_Exceeded"}
    for name in pipeline.CALLBACKS:
        stats[f"t_proc_nlp_{name}"], stats[f"t_wall_nlp_{name}"] = 0.01, 0.2
    record = pipeline.run_once(_ClockedSolver(monkeypatch, pipeline, stats), {})
    assert record["cpu_ms_per_iter"] == pytest.approx(100.0) and record["wall_ms_per_iter"] == pytest.approx(300.0)
    assert record["rest_cpu_ms_per_iter"] == pytest.approx(100.0 - len(pipeline.CALLBACKS) * 1.0)
    runs = [{**record, "cpu_ms_per_iter": ms} for ms in (1.0, 2.0, 30.0)]
    assert pipeline.median_record(runs)["cpu_ms_per_iter"] == 2.0


def test_bench_pipeline_tables_columns_are_the_records():
    """The table's CPU and wall ms/it columns are the record's cpu_ms_per_iter and wall_ms_per_iter, the columns
    docs/benchmarks.md copies (session 66's mutation testing: the wall column showed the CPU number)."""
    pipeline = _load("bench_pipeline")
    record = {"iterations": 10, "objective": 1.0, "cpu_ms_per_iter": 11.0, "wall_ms_per_iter": 33.0,
              "rest_cpu_ms_per_iter": 6.0, "eval_cpu_ms_per_iter": {name: 1.0 for name in pipeline.CALLBACKS},
              "create_s": 0.5}
    text = pipeline.table([{"case": "hop", "variants": {"baseline": record}, "full_solves": []}])
    row = next(line for line in text.splitlines() if line.startswith("| hop"))
    cells = [cell.strip() for cell in row.strip("|").split("|")]
    assert (cells[4], cells[7]) == ("11.00", "33.00"), cells


def test_bench_fatrop_times_cpu_as_process_time(monkeypatch):
    """bench_fatrop's cpu_s and cpu_ms_per_iter are process time, wall_s wall time (session 66's mutation testing: CPU
    measured as wall, with every test green). Ground truth: a fake clock."""
    fatrop = _load("bench_fatrop")
    stats = {"iter_count": 10, "return_status": "Solve_Succeeded", "success": True}
    record, _ = fatrop.run(_ClockedSolver(monkeypatch, fatrop, stats), {})
    assert (record["cpu_s"], record["wall_s"]) == (1.0, 3.0) and record["cpu_ms_per_iter"] == pytest.approx(100.0)


def test_stress_median_time_is_the_median_and_a_crash_of_an_infeasible_task_is_unexpected(stress):
    """summarize's median_time_s is the median of the tasks' times; an expected-infeasible task that crashed is
    unexpected, as test_stress_summary_rates_count_only_feasible_tasks states (session 66's mutation testing: the mean,
    and a crash let through, each with every test green)."""
    from planner.batch import Crashed

    base = {"family": "f", "index": 0, "seed": 0, "base": "point_mass", "params": {}, "task": {}, "expect": "feasible?"}
    records = [stress.finish({**base, "id": str(i)}, {**base, "id": str(i), "outcome": stress.CONVERGED_VALID,
                                                      "nonfinite": [], "times": {"total_s": s}})
               for i, s in enumerate((1.0, 2.0, 30.0))]
    assert stress.summarize(records)["total"]["median_time_s"] == 2.0
    crashed = stress.finish({**base, "id": "c", "expect": "infeasible"},
                            Crashed(stage="solve", error="RuntimeError: boom", traceback=""))
    assert crashed["outcome"] == stress.CRASHED and crashed["unexpected"] is True


def test_report_stamps_the_load_averages_in_order(monkeypatch):
    """results.json's run.load_average is (1, 5, 15 min) as os.getloadavg gives them (session 66's mutation testing:
    reversed, with every test green)."""
    report = importlib.import_module("scripts._report")
    monkeypatch.setattr(report.os, "getloadavg", lambda: (1.0, 2.0, 3.0))
    assert report.machine_info()["load_average"] == [1.0, 2.0, 3.0]


# [m, s] the work-precision tests' fake trajectories are the closed forms themselves: round-off only
CLOSED_FORM_TOL = 1e-9


def test_exact_flight_follows_each_control_piece(bench):
    """A point mass leaving the ground at v = (1, 3) m/s, unpushed for 0.1 s and then pushed along x (a piece of
    constant acceleration a), sampled exactly every 0.05 s on the two parabolas until it lands at 6 / g: flight error
    and landing time error ~0 (session 66's mutation testing: every sample read on the first piece's parabola, off by
    a (t - 0.1)^2 / 2, with every test green)."""
    from types import SimpleNamespace

    from planner.dynamics import Dynamics

    robot = load_robot("point_mass")
    dyn, task = Dynamics(robot), bench.point_mass_hop_task(20)
    g, land, t_push, push = bench.G, 6.0 / bench.G, 0.1, np.array([2.0, 0.0])
    a = np.asarray(dyn.forward(np.zeros(2), np.zeros(2), push), float).ravel()
    assert a[0] > 0.5 and a[1] == pytest.approx(-g)
    ts = np.append(np.arange(0.0, land, 0.05), [land, land])
    pushed = np.maximum(ts - t_push, 0.0)  # time under the push [s]
    q = np.column_stack([ts + a[0] * pushed**2 / 2, 3 * ts - g * ts**2 / 2])
    q[-2:, 1] = 0.0
    v = np.column_stack([1.0 + a[0] * pushed, 3 - g * ts])
    v[-1] = 0.0
    u = np.where((ts > t_push + 1e-12)[:, None], push, 0.0)  # u[i] acts on [t[i-1], t[i])
    traj = SimpleNamespace(t=ts, q=q, v=v, u=u, impacts=(SimpleNamespace(time=land),))
    out = bench.exact_flight(robot, dyn, task, traj)
    assert out["flight_error_m"] < CLOSED_FORM_TOL and out["landing_time_error_s"] < CLOSED_FORM_TOL


def test_resimulation_defect_is_the_worst_windows(bench, monkeypatch):
    """defect_base_m is the largest of the windows' base errors, as its docstring says: a fake simulation that lands
    each window's base 1, 2 and 3 cm off along x gives 0.03 m (session 66's mutation testing: the smallest, with every
    test green)."""
    from types import SimpleNamespace

    from planner import replay
    from planner.dynamics import Dynamics

    robot, task = load_robot("point_mass"), load_task(Path("robots") / "point_mass_hop.toml")
    t = np.linspace(0.0, 0.3, 31)
    traj = SimpleNamespace(t=t, q=np.column_stack([t, np.full_like(t, 0.5)]), v=np.zeros((31, 2)), u=np.zeros((31, 2)))
    calls = []

    def simulate_off(robot_, window_task, dynamics=None):
        calls.append(window_task)
        ts = np.linspace(0.0, 0.2, 201)
        x0, z0 = np.asarray(window_task.initial.q, float)
        q = np.column_stack([x0 + ts + 0.01 * len(calls), np.full_like(ts, z0)])
        return SimpleNamespace(stats=SimpleNamespace(converged=True), trajectory=SimpleNamespace(t=ts, q=q))

    monkeypatch.setattr(bench, "simulate", simulate_off)
    defect = bench.resimulation_defect(robot, Dynamics(robot), task, traj, replay.build_scene(robot, task), window=0.1)
    bases = [w["base_m"] for w in defect["per_window"]]
    assert defect["windows"] == 3 and max(bases) == pytest.approx(0.03, abs=CLOSED_FORM_TOL)
    assert defect["defect_base_m"] == pytest.approx(max(bases))


def test_interpolated_error_reads_the_kink_at_the_exact_impact(bench):
    """Samples at 0.40 s (in flight, exact) and 0.46 s (landed, z = 0) of the drop from 1 m (impact at 0.4515 s): the
    chord's largest error is at the exact impact, where the truth has its kink, z_chord(t_impact) - 0, and no
    subdivision point falls there (session 66's mutation testing: without the impact's own point, 0.028 m against
    0.0305, with every test green)."""
    drop = bench.Drop(z0=1.0)
    t = np.array([0.40, 0.46])
    q = np.column_stack([np.zeros(2), [drop.q(t[:1])[0, 1], 0.0]])
    chord_at_impact = q[0, 1] * (t[1] - drop.impact_time) / (t[1] - t[0])
    assert bench.interpolated_error(t, q, drop, 0.5) == pytest.approx(chord_at_impact, rel=CLOSED_FORM_TOL)


def test_point_mass_impact_time_error_is_a_magnitude(bench, monkeypatch):
    """A simulation landing 0.01 s before the exact impact records impact_time_error_s = 0.01, a magnitude the
    log-scale plot draws (session 66's mutation testing: -0.01, which a log axis drops silently, with every test
    green)."""
    from types import SimpleNamespace

    from planner.dynamics import Dynamics

    drop = bench.Drop(z0=1.0)
    t = np.linspace(0.0, 0.6, 61)
    q = drop.q(t)
    impact = SimpleNamespace(time=drop.impact_time - 0.01, tau_end=0.5, v_post=drop.v_post)
    traj = SimpleNamespace(t=t, tau=t, q=q, y=np.column_stack([q, np.zeros_like(q), t]), impacts=[impact],
                           physical_duration=0.6)
    stats = SimpleNamespace(converged=True, solve_time_s=0.0, n_nlp=1, ipopt_iterations=1, complementarity_residual=0.0)
    monkeypatch.setattr(bench, "simulate", lambda *args, **kwargs: SimpleNamespace(
        stats=stats, trajectory=traj, h=0.01, strategy="x", rho_f=0.0))
    case = bench.PointMassCase("pm", {"mu": 0.0}, drop, 0.6, 0.5, (0.01,))
    robot = load_robot("point_mass")
    (record,) = bench.point_mass_records(case, robot, Dynamics(robot), 1, lambda r: None)
    assert record["errors"]["impact_time_error_s"] == pytest.approx(0.01, rel=CLOSED_FORM_TOL)


# The quoted commands that test_readmes_and_docs_commands_parse lets fail, each a session log's command of its time
# whose text says what changed since: (file, the command as parsed) -> why it stays as it was written.
HISTORICAL_COMMANDS = {
    ("benchmarks.md", "scripts.bench_pipeline --cases capler125 --full-only --race --solve "
                      "'{\"smoothed_multipliers\": 0.01}'"):
        "session 23's trial of smoothed.diff, a patch its heading says was not kept (SolveOptions has no such field)",
}
_PLACEHOLDER = re.compile(r"[A-Z][A-Z0-9_]*(=[A-Z]+)?|\.\.\.|…")  # DIR, N, JSON, NAME=VALUE, ...: for the reader
# what a placeholder of these options (their dest) stands for: one value they take
_STAND_INS = {"solve": "{}", "ipopt": "alpha_for_y=min", "warm_ipopt": "alpha_for_y=min"}
_SHELL = re.compile(r"[();<>|&]+")  # shlex's punctuation: a command ends there (&&, ;, | head, 2>&1)


def _doc_snippets(path: Path):
    """(line, text) of every line of a Markdown file's fenced blocks (one ending in a backslash joined with the next)
    and of every code span outside them."""
    fenced, prose, joined = False, [], None
    for number, line in enumerate(path.read_text().split("\n"), 1):
        fence = line.lstrip().startswith("```")
        fenced ^= fence
        prose.append("" if fenced or fence else line)
        if fenced and not fence:
            joined = (joined[0], f"{joined[1][:-1]} {line.strip()}") if joined else (number, line.strip())
            if not joined[1].endswith("\\"):
                yield joined
                joined = None
    text = "\n".join(prose)
    for span in re.finditer(r"(`+)(.+?)\1", text, re.S):
        if "\n\n" not in span[2]:
            yield text.count("\n", 0, span.start()) + 1, span[2].replace("\n", " ")


def _doc_commands(text: str):
    """The `planner ...` and `python -m scripts.NAME ...` commands of a snippet as word lists (["planner", "plan", ...],
    ["scripts.NAME", ...]): a shell operator ends one (`&&`, `;`, `| head`, `2>&1`), a # comment is dropped, and so are
    the environment, /usr/bin/time, timeout and .venv/bin/ before one (`python -m planner.cli` is `planner`); an
    optional [group] is opened, with its first alternative ([--steps N | --task T]), or left out when it starts with
    no option ([options below]), and a choice of values (joint_pd|stance_retarget) is its first."""
    if not re.search(r"(^|[\s/])planner [a-zA-Z]|python -m (scripts\.|planner)", text):
        return
    lexer = shlex.shlex(re.sub(r"(?<=[\w.-])(\|[\w.-]+)+", "", text.replace("\\|", "|")), posix=True,
                        punctuation_chars=True)
    lexer.whitespace_split = True
    words, depth, skip = [], 0, 0  # skip: the depth of the group left out, 0 when none is
    for word in [*lexer, ";"]:
        literal = word.startswith("{")  # JSON: its brackets are its own
        opens, closes = (0, 0) if literal else (len(word) - len(word.lstrip("[")), len(word) - len(word.rstrip("]")))
        bare = word if literal else word.strip("[]")
        if opens and not skip and not bare.startswith("-"):
            skip = depth + 1
        depth += opens
        if word == "|" and depth:
            skip = skip or depth
        elif _SHELL.fullmatch(word) and not depth:
            while words and (re.fullmatch(r"\w+=\S*", words[0]) or words[0] in ("/usr/bin/time", "-v", "timeout")):
                del words[:2 if words[0] == "timeout" else 1]  # (timeout's duration with it)
            if words[:1] in (["planner"], [".venv/bin/planner"]):
                yield ["planner", *words[1:]]
            elif words[:3] in (["python", "-m", "planner"], ["python", "-m", "planner.cli"]):
                yield ["planner", *words[3:]]
            elif words[:2] == ["python", "-m"] and words[2:3] and words[2].startswith("scripts."):
                yield words[2:]
            words = []
        elif not skip and bare:
            words.append(bare)
        depth -= closes
        if skip > depth:
            skip = 0


def _filled(parser, words: list[str]) -> list[str]:
    """The words with each placeholder value of an option (N, START, JSON, NAME=VALUE, ...) replaced by one it takes:
    the first of its choices, 1 for a number, a _STAND_INS value; a path's (DIR, FILE) is kept."""
    out, action = [], None
    for word in words:
        if word.startswith("-") and word.split("=")[0] in parser._option_string_actions:
            action = parser._option_string_actions[word.split("=")[0]]
            action = action if action.nargs != 0 and "=" not in word else None
            out.append(word)
            continue
        if action is not None and (_PLACEHOLDER.fullmatch(word) or action.dest == "solve" and _PLACEHOLDER.search(
                re.sub(r'"[^"]*"', "", word))):
            if action.choices:
                word = str(next(iter(action.choices)))
            elif action.dest in _STAND_INS:
                word = _STAND_INS[action.dest]
            else:
                try:
                    (action.type or str)(word)
                except (ValueError, TypeError, argparse.ArgumentTypeError):
                    word = "1"
        out.append(word)
        action = action if action is not None and action.nargs in ("+", "*") else None
    return out


def _inexact(parser, words: list[str]) -> list[str]:
    """The words that look like options and are none of the parser's as spelled (argparse takes `--value` for --values
    too: a flag renamed to a longer name would still "parse")."""
    table, out = parser._option_string_actions, []
    for word in words:
        if word in table and table[word].nargs == argparse.REMAINDER:
            break  # (the script's --plan ARGS: `planner plan`'s, checked as such)
        if re.match(r"--?[a-zA-Z]", word) and word.split("=")[0] not in table and not (
                re.fullmatch(r"-[a-zA-Z]+", word) and all(f"-{c}" in table for c in word[1:])):
            out.append(word)
    return out


def _doc_command_error(words: list[str], parsers: dict, monkeypatch) -> str | None:
    """Why a quoted command (a _doc_commands word list) is refused today, or None when it is taken; see
    test_readmes_and_docs_commands_parse."""
    from planner import cli

    class Stop(Exception):
        pass

    def stop(*args, **kwargs):
        raise Stop

    if words[0] == "planner":
        parser = parsers.setdefault("planner", cli.build_parser())
        if len(words) < 2 or _PLACEHOLDER.fullmatch(words[1]):
            return None  # `planner`, `planner COMMAND ...`: no command named
        command = parser.subcommands.get(words[1])
        if command is None:
            return f"no command {words[1]!r}"
        filled = _filled(command, words[2:])
        if _inexact(command, filled):
            return f"no option {', '.join(_inexact(command, filled))} (argparse may take a prefix of one: spell it out)"
        table, values, given = command._option_string_actions, 0, []
        for word in filled:  # the positional words: none in a mention of options (`planner plan --init DIR`)
            action = table.get(word.split("=")[0]) if word.startswith("-") else None
            if action is not None:
                values = 0 if action.nargs == 0 or "=" in word else 1
            elif values:
                values -= 1
            else:
                given.append(word)
        try:  # a mention of options (`planner plan --init DIR`) with a ROBOT or DIR put in
            args = cli._parse(parser, [words[1], *filled] if given else [words[1], "X", *filled])
            # their options' checks, up to the robot's loading (not a mention's --task that gait requires)
            if words[1] in ("plan", "simulate") or given and words[1] in ("gait", "check-model"):
                with monkeypatch.context() as patched:
                    patched.setattr(cli, "_load_inputs", stop)
                    patched.setattr("planner.model.load_robot", stop)
                    args.run(args)
                return "ran on past its options' checks"
        except Stop:
            pass
        except cli.UsageExit as exc:
            if not given and "expected one argument" in exc.text:
                return None  # (an option named without its value: `planner validate --window`)
            return exc.text
        except InputError as exc:
            return str(exc)
        return None
    name = words[0].removeprefix("scripts.")
    if not (SCRIPTS / f"{name}.py").is_file():
        return f"no script {name}"
    if name not in parsers:  # the script's own parser, as its main builds it
        def caught(self, args=None, namespace=None):
            raise Stop(self)

        script = importlib.import_module(f"scripts.{name}")
        with monkeypatch.context() as patched, pytest.raises(Stop) as stopped:
            patched.setattr(argparse.ArgumentParser, "parse_args", caught)
            script.main([])
        parsers[name] = stopped.value.args[0]
    parser = parsers[name]
    if _inexact(parser, words[1:]):
        return f"no option {', '.join(_inexact(parser, words[1:]))} (argparse may take a prefix of one: spell it out)"
    try:
        with monkeypatch.context() as patched:  # (--out DIR, /work/scratch/...: no directory checked)
            patched.setattr("scripts._report.prepare_out_dir", lambda path, failed=False: path)
            args = parser.parse_args(_filled(parser, words[1:]))
        for text in getattr(args, "solve", None) or []:  # bench_pipeline's SolveOptions objects
            if isinstance(text, str) and text.startswith("{"):
                H.solve_options_from_dict(H.solve_fields_from_json(text))
        if isinstance(getattr(args, "plan", None), list):  # probe_impacts' and probe_positions' --plan ARGS
            return _doc_command_error(["planner", "plan", *args.plan], parsers, monkeypatch)
    except SystemExit as exc:
        return getattr(exc, "text", f"exit {exc.code}")
    except InputError as exc:
        return f"--solve: {exc}"
    return None


def test_readmes_and_docs_commands_parse(monkeypatch, capsys):
    """Every `planner ...` and `python -m scripts.NAME ...` command that README.md and docs/*.md quote (code spans and
    fenced blocks), its placeholders filled in (DIR, N, START, JSON, ...), is taken by today's parser, its options
    spelled out in full: planner.cli's, with plan's, simulate's, gait's and check-model's checks of their options
    up to the robot's loading (--solve's JSON as SolveOptions, --init's flags, the FESD flags), or the script's,
    with its --solve JSON as SolveOptions and its --plan ARGS as `planner plan ARGS`; a mention of a command's
    options without its ROBOT or DIR (`planner plan --init DIR`) is checked with one put in. Nothing is solved. The
    CLI and the scripts' flags changed over the sessions, and a quoted command that no longer parses is a doc a reader
    cannot follow; only HISTORICAL_COMMANDS, a session log's commands of their time, may fail."""
    root, parsers, failed = SCRIPTS.parent, {}, {}
    for path in [root / "README.md", *sorted((root / "docs").glob("*.md"))]:
        for line, text in _doc_snippets(path):
            try:
                commands = list(_doc_commands(text))
            except ValueError as exc:  # shlex: an unclosed quote
                failed[(path.name, text)] = f"line {line}: {exc}"
                continue
            for words in commands:
                error = _doc_command_error(words, parsers, monkeypatch)
                if error is not None:
                    failed[(path.name, shlex.join(words))] = f"line {line}: {error}"
    capsys.readouterr()  # (the usage errors' lines)
    assert parsers.keys() >= {"planner", "bench_pipeline", "bench_replan", "stress"}  # (the extraction found them)
    assert {k: v for k, v in failed.items() if k not in HISTORICAL_COMMANDS} == {}
    assert set(HISTORICAL_COMMANDS) <= set(failed), "HISTORICAL_COMMANDS that now parse: drop them"
