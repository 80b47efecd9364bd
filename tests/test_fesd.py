"""FESD (finite elements with switch detection) for the time-freezing system: the Radau IIA tableau,
the step's equations against implicit Euler, the options, and exact switch detection on the point mass."""
from __future__ import annotations

import functools
import math

import casadi as ca
import numpy as np
import pytest

from planner.discretization import Discretization, FESDInterval, FESDOptions, ImplicitEulerStep, radau_iia
from planner.dynamics import Dynamics
from planner.errors import InputError, PlannerError
from planner.model import load_robot
from planner.simulate import SimulateOptions, Strategy, simulate
from planner.task import Contact, parse_task
from planner.timefreezing import TimeFreezingSystem

G = 9.81
# The bar for "exact": the interior point leaves the switching function ~1e-8 off zero at
# the boundary and the clock ~1e-10 per element off; measured impact time errors <= 3e-9 s
IMPACT_TIME_TOL = 1e-8
EVAL_TOL = 1e-12  # the same expression built two ways: rounding only
ORDER_TOL = 0.15  # measured slopes differ from 2 n_s - 1 by < 0.05 on the grids below


@functools.cache
def point_mass():
    robot = load_robot("point_mass")
    return robot, Dynamics(robot)


@pytest.mark.parametrize("n_s", [1, 2, 3])
def test_radau_tableau_has_order_2s_minus_1(n_s):
    """The tableau is a collocation method (row sums c, b = last row, c_s = 1) and integrates the smooth
    linear ODE y' = -y + cos(t), y(0) = 1, to t = 1 with end-point error O(h^(2 n_s - 1))."""
    A, b, c = radau_iia(n_s)
    np.testing.assert_allclose(A.sum(axis=1), c, atol=EVAL_TOL)
    np.testing.assert_allclose(b, A[-1], atol=EVAL_TOL)
    assert c[-1] == 1.0

    def exact(t):  # y = (cos t + sin t) / 2 + e^-t / 2
        return 0.5 * (math.cos(t) + math.sin(t)) + 0.5 * math.exp(-t)

    def integrate(N):
        h, y = 1.0 / N, 1.0
        for k in range(N):
            t = k * h + c * h
            stages = np.linalg.solve(np.eye(n_s) + h * A, y + h * A @ np.cos(t))  # Y = y + h A (-Y + cos t)
            y = stages[-1]
        return y

    Ns = (4, 8, 16) if n_s == 3 else (8, 16, 32)
    errors = [abs(integrate(N) - exact(1.0)) for N in Ns]
    slope = np.polyfit(np.log(1.0 / np.array(Ns)), np.log(errors), 1)[0]
    assert slope == pytest.approx(2 * n_s - 1, abs=ORDER_TOL)


def test_one_stage_one_element_is_the_implicit_euler_step():
    """FESD with n_s = 1, n_fe = 1 writes exactly the implicit-Euler step's equations (several contacts:
    the biped's two feet, with the force rows); only the complementarity and the objective differ."""
    system = TimeFreezingSystem(Dynamics(load_robot("biped")), [Contact("foot_1", mu=0.8), Contact("foot_2", mu=0.8)])
    step = ImplicitEulerStep(system)
    fesd = FESDInterval(step, FESDOptions(n_s=1, n_fe=1))
    y_k, u = ca.SX.sym("y_k", system.ny), ca.SX.sym("u", system.nu)
    H = 0.01
    iv = fesd.build(y_k, lambda y: u, H, ca.DM.zeros(2 * system.n_sigma))
    sl = fesd.stage_slice(0, 0)
    y_next, w = iv.x[sl][: system.ny], iv.x[sl][system.ny :]
    ie = step.build(y_k, y_next, u, 1.0, H)
    g_ie = ca.substitute(ie.g, ie.w, w)
    g_fesd = ca.substitute(iv.g[1:], iv.x[0], H)  # the first row is sum h = H
    f = ca.Function("f", [y_k, u, iv.x], [g_fesd - g_ie])
    rng = np.random.default_rng(1)
    x = rng.normal(size=fesd.nx)
    x[sl.start : sl.start + system.ny] = rng.normal(size=system.ny) + np.r_[np.zeros(2), 1.0, np.zeros(system.ny - 3)]
    residual = np.asarray(f(rng.normal(size=system.ny), rng.normal(size=system.nu), x), float)
    np.testing.assert_allclose(residual, 0.0, atol=EVAL_TOL)
    assert len(iv.complementarity) == 2 * 2 * system.n_sigma  # left boundary and the stage, lambda0 and lambda1


def test_options_are_validated():
    """Bad FESD settings and combinations raise InputError (a PlannerError) naming the valid values."""
    for bad in ({"n_s": 4}, {"n_s": 0}, {"n_fe": 0}, {"n_fe": 1.5}, {"rho_h": -1.0}):
        with pytest.raises(InputError, match="FESDOptions"):
            FESDOptions(**bad)
    with pytest.raises(PlannerError, match="implicit_euler"):
        SimulateOptions(discretization="fesd")
    with pytest.raises(InputError, match="stepwise"):
        SimulateOptions(discretization=Discretization.FESD, strategy=Strategy.HORIZON)
    with pytest.raises(ValueError):
        radau_iia(4)


def drop(discretization: Discretization, n_s: int = 2, n_fe: int = 2, h: float = 0.02, z0: float = 1.0):
    """The point mass dropped from rest at height z0 [m] onto the table (a_n = 100), tau in [0, 0.5]."""
    robot, dyn = point_mass()
    task = parse_task({"contacts": [{"point": "point", "mu": 0.0, "a_n": 100.0}], "initial": {"q": [0.0, z0], "v": [0.0, 0.0]},
                       "horizon": {"tau_f": 0.5, "N": round(0.5 / h)}})
    options = SimulateOptions(discretization=discretization, fesd=FESDOptions(n_s=n_s, n_fe=n_fe))
    result = simulate(robot, task, options, dynamics=dyn)
    assert result.stats.converged, result.stats
    return result


@pytest.mark.parametrize("n_s,n_fe,h", [(2, 2, 0.02), (3, 2, 0.04)])
def test_fesd_detects_the_impact_exactly(n_s, n_fe, h):
    """With n_s >= 2 the free fall is integrated exactly (a quadratic) and the switch of beta lands on
    an element boundary: the impact time is sqrt(2 h0 / g) to IMPACT_TIME_TOL, for a step h that does
    not divide it; the element boundary sits on the ground."""
    result = drop(Discretization.FESD, n_s, n_fe, h)
    impacts = result.trajectory.impacts
    assert len(impacts) == 1
    assert impacts[0].time == pytest.approx(math.sqrt(2.0 / G), abs=IMPACT_TIME_TOL)
    assert abs(impacts[0].q[1]) < IMPACT_TIME_TOL * G * math.sqrt(2.0 / G)  # |v| = g t at the impact
    assert result.extra["discretization"] == {"name": "fesd", "n_s": n_s, "n_fe": n_fe, "rho_h": FESDOptions().rho_h}


# A biped foot comes down at ~2.4 m/s from 0.3 m: the element boundary sits ~1e-8 m inside the
# ground (IPOPT's bound relaxation), i.e. ~4e-9 s of its impact time (measured 4.1e-9 s)
BIPED_DROP_M = 0.3
FOOT_REST_TOL = 1e-6  # [m/s] the landed foot's velocity after the impulse: the barrier's residue (measured 4.6e-8)


def test_fesd_detects_the_first_foot_of_a_falling_biped():
    """Several contact points: the biped (two feet, mu = 0.8) dropped from rest with its feet at
    different heights falls as a rigid body (uniform gravity, no torque, so no joint acceleration):
    its lower foot lands at sqrt(2 d / g) for a drop d. FESD (n_s = 2, two elements per step) puts
    that impact on an element boundary to IMPACT_TIME_TOL, assigns it to the right foot, and the
    inelastic, sticking impact leaves that foot at rest (the post-impact sample); implicit Euler at
    the same step misses the time by O(h)."""
    robot = load_robot("biped")
    dyn = Dynamics(robot)
    q0 = np.array([0.0, 1.0, 0.0, 0.3, -0.1])  # leg 2 closer to vertical: foot_2 is the lower one
    heights = [float(np.asarray(dyn.point_position(f)(q0)).ravel()[-1]) for f in ("foot_1", "foot_2")]
    assert heights[1] < heights[0] - 0.03
    q0[1] += BIPED_DROP_M - heights[1]
    # a_n is a force per unit of the contact's inverse inertia: 35 kg need a large one for the impact to end
    # within the horizon (ends before foot_1 lands at t ~ 0.30 s)
    feet = [{"point": f, "mu": 0.8, "a_n": 4000.0, "a_t": 12000.0} for f in ("foot_1", "foot_2")]
    task = parse_task({"contacts": feet, "initial": {"q": q0.tolist()}, "horizon": {"tau_f": 0.3, "N": 15}})
    exact = math.sqrt(2.0 * BIPED_DROP_M / G)
    times = {}
    for disc in (Discretization.FESD, Discretization.IMPLICIT_EULER):
        result = simulate(robot, task, SimulateOptions(discretization=disc, fesd=FESDOptions(n_s=2, n_fe=2)), dynamics=dyn)
        assert result.stats.converged, result.stats.message
        first = result.trajectory.impacts[0]
        assert first.contact == "foot_2"
        times[disc] = first.time
        if disc is Discretization.FESD:
            after = int(np.nonzero(result.trajectory.t == first.time)[0][-1])  # the post-impact sample
            foot_velocity = np.asarray(dyn.point_jacobian("foot_2")(result.trajectory.q[after])) @ result.trajectory.v[after]
            assert np.abs(foot_velocity).max() < FOOT_REST_TOL
    assert times[Discretization.FESD] == pytest.approx(exact, abs=IMPACT_TIME_TOL)
    assert abs(times[Discretization.IMPLICIT_EULER] - exact) > 1e4 * IMPACT_TIME_TOL


def test_implicit_euler_misses_the_impact_time():
    """Implicit Euler at the same step lands inside a step: its impact time is off by O(h), far more
    than IMPACT_TIME_TOL (measured 8.8e-3 s at h = 0.02)."""
    result = drop(Discretization.IMPLICIT_EULER)
    assert abs(result.trajectory.impacts[0].time - math.sqrt(2.0 / G)) > 1e4 * IMPACT_TIME_TOL


def test_fesd_restart_rescues_the_capler_impact_step():
    """Capler dropped under joint PD with FESD n_s = 1, n_fe = 4, h = 0.01 s: the impact step fails
    from the previous element's selectors and converges when restarted from its own state's
    selectors (restarts=False stops there)."""
    robot = load_robot("capler")
    hip, knee = 0.0, 0.3
    z_base = 0.2 * math.cos(hip) + 0.2 * math.cos(hip + knee) + 0.05  # the foot 5 cm above the ground
    task = parse_task({"contacts": [{"point": "foot", "mu": 0.8}], "initial": {"q": [0.0, z_base, hip, knee]},
                       "horizon": {"tau_f": 0.2, "N": 20},
                       "simulate": {"pd": {"joints": ["hip", "knee"], "kp": [100.0] * 2, "kd": [2.0] * 2}}})
    fesd = FESDOptions(n_s=1, n_fe=4)
    plain = simulate(robot, task, SimulateOptions(discretization=Discretization.FESD, fesd=fesd, restarts=False))
    assert not plain.stats.converged
    rescued = simulate(robot, task, SimulateOptions(discretization=Discretization.FESD, fesd=fesd))
    assert rescued.stats.converged, rescued.stats.message
    assert rescued.extra["restarted_steps"] >= 1 and len(rescued.trajectory.impacts) == 1
