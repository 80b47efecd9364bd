"""FESD (finite elements with switch detection) for the time-freezing system: the Radau IIA tableau,
the step's equations against implicit Euler, the options, and exact switch detection on the point mass."""
from __future__ import annotations

import functools
import math
from pathlib import Path

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
        SimulateOptions(discretization="fed")
    with pytest.raises(InputError, match="stepwise"):
        SimulateOptions(discretization=Discretization.FESD, strategy=Strategy.HORIZON)
    with pytest.raises(InputError, match="velocity_switch"):
        SimulateOptions(velocity_switch="collocate")
    from planner.discretization import SwitchVelocity
    from planner.problem import ProblemOptions
    with pytest.raises(InputError, match="velocity_switch"):
        ProblemOptions(velocity_switch=SwitchVelocity.COLLOCATED)  # planner simulate only
    with pytest.raises(InputError, match="n_s must be 1, 2 or 3, got 4"):
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
    expected = {"name": "fesd", "n_s": n_s, "n_fe": n_fe, "rho_h": FESDOptions().rho_h, "velocity_switch": "collocated" if n_s >= 2 else "point"}
    assert {k: v for k, v in result.extra["discretization"].items() if k != "collocated_steps"} == expected


# A biped foot comes down at ~2.4 m/s from 0.3 m: the element boundary sits ~1e-8 m inside the
# ground (IPOPT's bound relaxation), i.e. ~4e-9 s of its impact time (measured 4.1e-9 s)
BIPED_DROP_M = 0.3
FOOT_REST_TOL = 1e-6  # [m/s] a landed foot's velocity after the impulse: the barrier's residue (measured 4.6e-8, and 4.5e-7 for the second landing)


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


# foot_1's landing while foot_2 stands (docs/formulation.md, "Several contact points"): implicit Euler
# at h = 1 ms puts it at 0.30170 s, early by O(h) like its foot_2 landing at that h (-4.9e-4 s); FESD's
# landing is exact to ~1e-8 s, so the two differ by IE's error, not more than 1e-3 s
BIPED_SECOND_LANDING_IE_1MS = 0.30170
BIPED_SECOND_LANDING_TOL = 1e-3
# a foot in stance stays on the ground to the barrier's residue; the stance foot sank 5e-7 m during
# the other foot's impact (docs/formulation.md, "Several contact points"); foot_1 ends at -1.4e-8 m (measured)
STANCE_GAP_TOL_M = 1e-6


@pytest.mark.slow
def test_fesd_runs_through_the_second_foot_landing_with_enough_elements():
    """The biped drop continued to tau = 0.4 s: foot_1 lands while foot_2 stands, and its step holds
    three switches (the landing; the end of foot_1's tangential jump, where foot_2 changes from held
    to lifted; the end of the normal jump, where the clock restarts and foot_2 lifts off). With
    n_fe = 4 elements (three free boundaries) and h = 0.01 s FESD runs through: foot_1's impact sits
    within BIPED_SECOND_LANDING_TOL of implicit Euler's at h = 1 ms, foot_1 is at rest after the
    impulse, stays on the ground, and foot_2 ends above the ground rising (implicit Euler: the body
    pivots onto foot_1). n_fe = 2 cannot hold the three switches; at h = 0.02 s a 4-element solution of
    that step exists, but the homotopy from the simulation's starts stalls above comp_tol (docs)."""
    robot = load_robot("biped")
    dyn = Dynamics(robot)
    q0 = np.array([0.0, 1.0, 0.0, 0.3, -0.1])
    q0[1] += BIPED_DROP_M - float(np.asarray(dyn.point_position("foot_2")(q0)).ravel()[-1])
    feet = [{"point": f, "mu": 0.8, "a_n": 4000.0, "a_t": 12000.0} for f in ("foot_1", "foot_2")]
    task = parse_task({"contacts": feet, "initial": {"q": q0.tolist()}, "horizon": {"tau_f": 0.4, "N": 40}})
    result = simulate(robot, task, SimulateOptions(discretization=Discretization.FESD, fesd=FESDOptions(n_s=2, n_fe=4)), dynamics=dyn)
    assert result.stats.converged, result.stats.message
    tr = result.trajectory
    assert tr.impacts[0].contact == "foot_2"
    assert tr.impacts[0].time == pytest.approx(math.sqrt(2.0 * BIPED_DROP_M / G), abs=IMPACT_TIME_TOL)
    second = next(imp for imp in tr.impacts if imp.contact == "foot_1")
    assert second.time == pytest.approx(BIPED_SECOND_LANDING_IE_1MS, abs=BIPED_SECOND_LANDING_TOL)
    after = int(np.nonzero(tr.t == second.time)[0][-1])  # the post-impact sample

    def velocity(foot, k):
        return np.asarray(dyn.point_jacobian(foot)(tr.q[k])) @ tr.v[k]

    def height(foot, k):
        return float(np.asarray(dyn.point_position(foot)(tr.q[k])).ravel()[-1])

    print(f"\nfoot_1 after its impact: velocity {np.abs(velocity('foot_1', after)).max():.2g} m/s; at the end: "
          f"height {height('foot_1', -1):.2g} m; foot_2 height {height('foot_2', -1):.3g} m")
    assert np.abs(velocity("foot_1", after)).max() < FOOT_REST_TOL
    assert abs(height("foot_1", -1)) < STANCE_GAP_TOL_M
    assert height("foot_2", -1) > 1e-3 and velocity("foot_2", -1)[-1] > 0


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


COLLOCATED_TOL = 1e-12  # the same numbers combined two ways: rounding only


def test_collocated_switch_velocity_is_the_collocated_rate_of_the_gap():
    """SwitchVelocity.COLLOCATED in a FESD element (Capler, n_s = 2): at stage states whose velocities
    are the collocation polynomial's q-derivative at the stages (clock rate 1, persistent contact), the
    n^T v switching function of stage j is the same polynomial's derivative of the foot's gap,
    sum_l (A^-1)_jl (c(q_l) - c(q_0)) / h_n; so alpha's sliding mode (zero at every stage) leaves the
    gap at every stage where the element started. POINT's n(q_j)^T v_j misses it by the collocation
    error of c(q) (measured >= 1e-3 m/s on these 0.2 rad elements). Other switches are untouched;
    for the point mass (a gap linear in q) both are the same function."""
    from planner.discretization import SwitchVelocity

    system = TimeFreezingSystem(Dynamics(load_robot("capler")), [Contact("foot", mu=0.8)])
    names = [sw.function for sw in system.switches]
    ia = names.index("n^T v")
    nq, ny, n_s, h_n = system.nq, system.ny, 2, 0.005
    A_inv = np.linalg.inv(radau_iia(n_s)[0])
    gap = system.dyn.point_position("foot")
    rng = np.random.default_rng(5)
    q0 = np.array([0.0, 0.35, 0.4, -0.8])
    Q = [q0 + rng.normal(size=nq) * 0.2 for _ in range(n_s)]  # the stages' postures
    V = [sum(A_inv[j, l] * (Q[l] - q0) for l in range(n_s)) / h_n for j in range(n_s)]  # q' of the polynomial
    c = [float(gap(q)[2]) for q in [q0] + Q]
    y0 = np.concatenate([q0, rng.normal(size=nq), [0.3]])
    rows = {}
    for vs in (SwitchVelocity.POINT, SwitchVelocity.COLLOCATED):
        fesd = FESDInterval(ImplicitEulerStep(system, velocity_switch=vs), FESDOptions(n_s=n_s, n_fe=1))
        y_k = ca.SX.sym("y_k", ny)
        iv = fesd.build(y_k, lambda y: ca.DM.zeros(system.nu), h_n, ca.DM.zeros(2 * system.n_sigma))
        x = np.zeros(fesd.nx)
        x[0] = h_n
        for j in range(n_s):
            sl = fesd.stage_slice(0, j)
            x[sl.start : sl.start + ny] = np.concatenate([Q[j], V[j], [0.3]])  # w = 0: the multipliers are zero
        g = np.asarray(ca.Function("g", [y_k, iv.x], [iv.g])(y0, x), float).ravel()
        rows[vs] = g[iv.g_blocks["stationarity"]].reshape(n_s, system.n_sigma)  # = the switching functions
    for j in range(n_s):
        rate = sum(A_inv[j, l] * (c[l + 1] - c[0]) for l in range(n_s)) / h_n
        assert rows[SwitchVelocity.COLLOCATED][j, ia] == pytest.approx(rate, abs=COLLOCATED_TOL)
        assert abs(rows[SwitchVelocity.POINT][j, ia] - rate) >= 1e-3
    others = [i for i in range(system.n_sigma) if i != ia]
    np.testing.assert_allclose(rows[SwitchVelocity.COLLOCATED][:, others], rows[SwitchVelocity.POINT][:, others], atol=COLLOCATED_TOL)
    # the point mass: gap linear in q, no correction
    pm = TimeFreezingSystem(point_mass()[1], [Contact("point", mu=0.0)])
    y_k, y_n, u = ca.SX.sym("y_k", pm.ny), ca.SX.sym("y_n", pm.ny), ca.SX.sym("u", pm.nu)
    g = [ImplicitEulerStep(pm, velocity_switch=vs).build(y_k, y_n, u, 1.0, 0.02) for vs in (SwitchVelocity.POINT, SwitchVelocity.COLLOCATED)]
    diff = ca.Function("d", [y_k, y_n, u, g[0].w], [g[0].g - ca.substitute(g[1].g, g[1].w, g[0].w)])
    residual = diff(rng.normal(size=pm.ny), rng.normal(size=pm.ny), rng.normal(size=pm.nu), rng.uniform(size=g[0].w.shape[0]))
    np.testing.assert_allclose(np.asarray(residual, float), 0.0, atol=COLLOCATED_TOL)


@pytest.mark.slow
def test_unactuated_capler_fesd_simulation_holds_the_collapsing_stance():
    """The default Capler task without its [simulate.pd] (zero controls), FESD n_s = 2, n_fe = 4,
    h = 0.02 s (`planner simulate capler --discretization fesd` before session 8): the unactuated
    leg buckles in persistent contact (knee to 11 rad/s by tau = 1.02 s). With the default switching
    velocity (COLLOCATED for a contact in persistent contact) every step to tau = 1.2 s converges with
    complementarity <= comp_tol in one NLP, the foot never rises above the ground (beyond IPOPT's 1e-8
    bound relaxation; it sinks by at most 1.3e-7 m, measured) and there is no spurious impact.
    With POINT the Radau stages move the gap up to 3e-8 m above the ground under a compressive force
    and the run stops at step 51 (complementarity 1.7e-9 > 1e-9; docs/formulation.md, "FESD in
    persistent contact")."""
    from dataclasses import replace

    from planner.discretization import SwitchVelocity
    from planner.task import load_task

    robot = load_robot("capler")
    task = load_task(Path(__file__).parents[1] / "robots" / "capler.toml")
    task = replace(task, horizon=replace(task.horizon, tau_f=1.2, N=60), simulate=replace(task.simulate, pd=None))
    options = SimulateOptions(discretization=Discretization.FESD, fesd=FESDOptions(n_s=2, n_fe=4))
    result = simulate(robot, task, options)
    assert result.stats.converged, result.stats.message
    assert result.stats.complementarity_residual <= options.comp_tol
    assert result.stats.n_nlp == task.horizon.N and result.extra["restarted_steps"] == 0
    assert result.extra["discretization"]["collocated_steps"] == task.horizon.N  # standing on the foot from the start
    assert len(result.trajectory.impacts) == 0
    system = TimeFreezingSystem(Dynamics(robot), task.contacts, task.ground_height)
    gaps = [float(np.asarray(system.gap_fn(y, np.zeros(robot.nu))).ravel()[0]) for y in result.trajectory.y]
    print(f"gap range over the element boundaries: [{min(gaps):.3g}, {max(gaps):.3g}] m")
    assert max(gaps) <= 1e-8 and min(gaps) >= -5e-7  # never above the ground beyond IPOPT's bound relaxation
    point = simulate(robot, task, replace(options, velocity_switch=SwitchVelocity.POINT))
    assert not point.stats.converged and "step 51 " in point.stats.message


def test_a_number_of_elements_beyond_a_thousand_is_refused():
    """FESDOptions.n_fe is at most discretization.MAX_ELEMENTS = 1000 finite elements per step: n_fe = 10**7 (a typo)
    was accepted, and building a one-step problem ran out of memory after 16 s; it is an InputError naming n_fe and
    its range, before anything is built. 1000 is still allowed."""
    with pytest.raises(InputError, match=r"^FESDOptions\.n_fe = 10000000 is not allowed; it must be in \[1, 1000\]"):
        FESDOptions(n_fe=10**7)
    assert FESDOptions(n_fe=1000).n_fe == 1000


def test_fesd_settings_under_implicit_euler_are_refused():
    """SimulateOptions and ProblemOptions refuse FESD settings (n_s, n_fe, rho_h) other than the default when the
    discretization is implicit Euler, which would ignore them (the CLI already refused --stages without
    --discretization fesd); the default FESDOptions and any FESD settings under FESD are accepted."""
    from planner.problem import ProblemOptions

    for options in (SimulateOptions, ProblemOptions):
        with pytest.raises(InputError, match=rf"^{options.__name__}\.fesd = FESDOptions\(n_s=1, n_fe=2, rho_h=1.0\) "
                                             r"sets the FESD discretization, .*implicit_euler would ignore"):
            options(fesd=FESDOptions(n_s=1))
        assert options(fesd=FESDOptions()).discretization is Discretization.IMPLICIT_EULER
        assert options(discretization=Discretization.FESD, fesd=FESDOptions(n_s=1)).fesd.n_s == 1


def test_a_collapsed_element_is_left_out_of_a_simulation():
    """An FESD simulation whose IPOPT left an element a hair below length 0 (-1.3e-9 s, within its bound relaxation:
    the point-mass slide with mu = 0.5 at 6 elements per step) keeps numerical and physical time increasing: the
    element is left out as the plans leave it, so the converged run's writer, validate and view take the result
    (it exited 2, "t must be non-decreasing")."""
    data = {"contacts": [{"point": "point", "mu": 0.5, "a_n": 100.0}], "initial": {"q": [0.0, 1.0], "v": [1.0, 0.0]},
            "horizon": {"tau_f": 1.0, "N": 50}}
    task = parse_task(data)
    options = SimulateOptions(discretization=Discretization.FESD, fesd=FESDOptions(2, 6))
    res = simulate(load_robot("point_mass"), task, options)
    tr = res.trajectory
    assert res.stats.converged and np.all(np.diff(tr.tau) > 0) and np.all(np.diff(tr.t) >= 0)
    assert len(tr.tau) - 1 < 50 * 6  # (an element was left out: the case this test is about)
    # the PD summary counts steps from every element's controls, collapsed ones too (it reshaped the kept ones)
    held = parse_task({**data, "simulate": {"pd": {"joints": ["x"], "kp": [0.0], "kd": [0.0]}}})
    assert simulate(load_robot("point_mass"), held, options).extra["pd"]["steps_beyond_actuator_bounds"] == 0


# The 2-stage Radau IIA weights in closed form (Hairer & Wanner, Table IV.5.6): b = (3/4, 1/4)
RADAU2_B = (0.75, 0.25)


def test_fesd_objective_is_the_step_equilibration_plus_the_regularization_quadrature():
    """An FESD step's objective, against its formula recomputed from the element lengths and the stage selectors
    (point mass, n_s = 2, n_fe = 3, random lengths and selectors): the step equilibration
    rho_h sum_n ((h_n - H / n_fe) / (H / n_fe))^2 (also alone as Interval.equilibration), plus the stages' rho_f
    ||sigma - sigma*||^2 (regularized selectors) weighted by the Radau weight b_j times h_n / H (session 66's
    mutation testing: the equilibration divided by H instead of H / n_fe, its target H / (n_fe + 1), and the
    weights b_j / n_fe that let a collapsed element's selectors go to sigma* for free, each killed only by a test
    that asserts a simulation's failure or a collapsed element, with every test green)."""
    rho_f, rho_h, H, n_s, n_fe = 0.7, 2.5, 0.06, 2, 3
    system = TimeFreezingSystem(point_mass()[1], [Contact("point", mu=0.5)])
    fesd = FESDInterval(ImplicitEulerStep(system, rho_f=rho_f), FESDOptions(n_s=n_s, n_fe=n_fe, rho_h=rho_h))
    y_k, u = ca.SX.sym("y_k", system.ny), ca.SX.sym("u", system.nu)
    iv = fesd.build(y_k, lambda y: u, H, ca.DM.zeros(2 * system.n_sigma))
    f = ca.Function("f", [y_k, u, iv.x], [iv.objective, iv.equilibration])
    rng = np.random.default_rng(7)
    x = rng.uniform(size=fesd.nx)
    x[:n_fe] = rng.uniform(0.0, H, n_fe)  # lengths that do not sum to H: the objective reads each
    objective, equilibration = (float(v) for v in f(rng.normal(size=system.ny), rng.normal(size=system.nu), x))
    h_bar = H / n_fe
    expected_eq = rho_h * sum(((h - h_bar) / h_bar) ** 2 for h in x[:n_fe])
    wanted, regularized = system.wanted, np.asarray(system.regularized, bool)
    sig = fesd.step.w_blocks["sigma"]
    expected_reg = 0.0
    for e in range(n_fe):
        for j in range(n_s):
            sigma = x[fesd.stage_slice(e, j)][system.ny:][sig]
            expected_reg += RADAU2_B[j] * x[e] / H * rho_f * np.sum((sigma - wanted)[regularized] ** 2)
    assert equilibration == pytest.approx(expected_eq, rel=EVAL_TOL)
    assert objective == pytest.approx(expected_eq + expected_reg, rel=EVAL_TOL)


def test_collocated_switch_velocity_of_a_later_element_starts_at_its_left_boundary():
    """SwitchVelocity.COLLOCATED in the second element of an FESD step (Capler, n_s = 2, n_fe = 2): at stage states
    whose velocities are each element's collocation polynomial's q-derivative, the n^T v switching function of
    stage j of element 1 is that element's derivative of the foot's gap from its left boundary (element 0's last
    stage), sum_l (A^-1)_jl (c(q_1l) - c(q_0,last)) / h_1, as element 0's is from the step's start (session 66's
    mutation testing: every element's gap increments taken from the step's start y_k, which the test above, of one
    element, cannot see, with every test green)."""
    from planner.discretization import SwitchVelocity

    system = TimeFreezingSystem(Dynamics(load_robot("capler")), [Contact("foot", mu=0.8)])
    ia = [sw.function for sw in system.switches].index("n^T v")
    nq, ny, n_s, n_fe, h_n = system.nq, system.ny, 2, 2, 0.005
    A_inv = np.linalg.inv(radau_iia(n_s)[0])
    gap = system.dyn.point_position("foot")
    rng = np.random.default_rng(6)
    q0 = np.array([0.0, 0.35, 0.4, -0.8])
    Q = [[q0 + rng.normal(size=nq) * 0.2 for _ in range(n_s)] for _ in range(n_fe)]  # the stages' postures
    starts = [q0, Q[0][-1]]  # each element's left boundary
    step = ImplicitEulerStep(system, velocity_switch=SwitchVelocity.COLLOCATED)
    fesd = FESDInterval(step, FESDOptions(n_s=n_s, n_fe=n_fe))
    y_k = ca.SX.sym("y_k", ny)
    iv = fesd.build(y_k, lambda y: ca.DM.zeros(system.nu), n_fe * h_n, ca.DM.zeros(2 * system.n_sigma))
    x = np.zeros(fesd.nx)
    x[:n_fe] = h_n
    for e in range(n_fe):
        for j in range(n_s):
            v = sum(A_inv[j, l] * (Q[e][l] - starts[e]) for l in range(n_s)) / h_n  # q' of the element's polynomial
            sl = fesd.stage_slice(e, j)
            x[sl.start : sl.start + ny] = np.concatenate([Q[e][j], v, [0.3]])  # w = 0: the multipliers are zero
    y0 = np.concatenate([q0, rng.normal(size=nq), [0.3]])
    g = np.asarray(ca.Function("g", [y_k, iv.x], [iv.g])(y0, x), float).ravel()
    rows = g[iv.g_blocks["stationarity"]].reshape(n_fe, n_s, system.n_sigma)  # = the switching functions
    for e in range(n_fe):
        c = [float(gap(q)[2]) for q in [starts[e]] + Q[e]]
        for j in range(n_s):
            rate = sum(A_inv[j, l] * (c[l + 1] - c[0]) for l in range(n_s)) / h_n
            assert rows[e, j, ia] == pytest.approx(rate, abs=COLLOCATED_TOL)
