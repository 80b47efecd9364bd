"""Smoke tests of the benchmark scripts (scripts/): a quick run writes its files with the documented
fields. No timing assertions: the machine is shared, wall times are only recorded."""
from __future__ import annotations

import importlib.util
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

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
        ("pm_drop_frictionless", "default"), ("pm_drop_frictionless", "horizon")}
    assert len({r["h"] for r in records if r["case"] == "pm_drop_noslip"}) == 2  # --quick: 2 grid points
    assert all(math.isfinite(o["order"]) for o in results["orders"]) and results["orders"]
    assert (tmp_path / "work_precision.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


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
