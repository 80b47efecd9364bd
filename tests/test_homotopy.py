"""The homotopy solves a small frictional hop exactly; options are validated."""
from __future__ import annotations

import numpy as np
import pytest

from planner import homotopy as H
from planner.errors import InputError
from planner.model import load_robot
from planner.problem import build_problem

from test_problem import hop_task

# Verdict thresholds of the issue: complementarity residual and terminal error at most 1e-6.
COMP_TOL = 1e-6
TERMINAL_TOL = 1e-6  # [m]


@pytest.fixture(scope="module")
def hop():
    robot = load_robot("robots/point_mass.xml")
    prob = build_problem(robot, hop_task(N=40))
    records = []
    result = H.solve(prob, H.SolveOptions(), progress=records.append)
    return prob, result, records


def test_point_mass_hop_converges(hop):
    """From y0 everywhere and u = 0 the no-slip point mass finds a hop to x = 0.5: every NLP
    converges, the polished point has complementarity <= 1e-6 and terminal error <= 1e-6."""
    prob, res, records = hop
    assert res.stats.converged, res.stats.message
    assert all(r.success for r in res.nlps)
    assert res.polished
    assert res.stats.complementarity_residual <= COMP_TOL
    assert res.terminal_error <= TERMINAL_TOL
    assert len(records) == len(res.nlps) == prob.task.plan.homotopy.n_nlp + 1
    assert [r.rho for r in records[:-1]] == [1.0, 10.0, 100.0, 1000.0, 10000.0]


def test_point_mass_hop_phases(hop):
    """The plan flies (a hop) and lands inelastically: post-impact normal velocity 0, a tangential
    impulse against the sliding direction. (The z motor can hold the mass at zero height, so the
    plan may glide after the impact instead of sticking: both are solutions of the model.)"""
    _, res, _ = hop
    tr = res.trajectory
    assert len(res.hops) >= 1 and res.hops[0].distance > 0.3
    assert len(tr.impacts) >= 1
    imp = tr.impacts[-1]
    assert imp.impulse > 0 and abs(imp.impulse_tangential) > 0
    assert imp.v_post[1] == pytest.approx(0.0, abs=1e-6)  # inelastic: no normal velocity after the impact
    assert imp.impulse_tangential * imp.v_pre[0] < 0  # friction opposes the sliding velocity
    assert tr.t[-1] == pytest.approx(1.0, abs=0.05)  # the clock ran almost the whole horizon


def test_active_set_bounds_fix_one_side():
    """Polishing bounds fix, per selector, sigma and the opposite multiplier (sigma at a bound) or both
    multipliers (interior sigma)."""
    robot = load_robot("robots/point_mass.xml")
    prob = build_problem(robot, hop_task(N=2))
    x = prob.x0.copy()
    s, l0, l1 = (prob.var_blocks[b][0] for b in ("sigma", "lambda0", "lambda1"))
    x[s[:3]] = [0.0, 1.0, 0.4]
    x[l0[:3]] = [2.0, 0.0, 1e-3]
    x[l1[:3]] = [0.0, 3.0, 1e-3]
    lbx, ubx, xc = H.active_set_bounds(prob, x)
    assert lbx[s[0]] == ubx[s[0]] == 0 and ubx[l1[0]] == 0 and ubx[l0[0]] == np.inf
    assert lbx[s[1]] == ubx[s[1]] == 1 and ubx[l0[1]] == 0 and ubx[l1[1]] == np.inf
    assert ubx[l0[2]] == ubx[l1[2]] == 0 and (lbx[s[2]], ubx[s[2]]) == (0, 1)
    assert np.all(xc >= lbx) and np.all(xc <= ubx)


@pytest.mark.parametrize("kwargs, key", [({"tol": 0}, "tol"), ({"max_iter": 0}, "max_iter"), ({"mu_strategy": "adaptive"}, "mu_strategy"),
                                         ({"nlp_scaling_method": "magic"}, "nlp_scaling_method"), ({"comp_tol": -1}, "comp_tol"),
                                         ({"polish": "yes"}, "polish")])
def test_bad_options(kwargs, key):
    """Out-of-range or wrongly typed options are InputErrors naming the option."""
    with pytest.raises(InputError, match=key):
        H.SolveOptions(**kwargs)
