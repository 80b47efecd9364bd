"""Forward simulation against the exact solutions of the point mass (paper Example 1).

All runs use the 1 kg point mass q = (x, z) above the table z = 0 with gravity g = 9.81 m/s^2.
The scheme is implicit Euler, first order: every tolerance below that is not a solver tolerance is
a multiple of the step h, and the convergence tests show the first-order rate.
"""
from __future__ import annotations

import functools
import math

import numpy as np
import pytest

from planner.discretization import Discretization, FESDOptions
from planner.dynamics import Dynamics
from planner.errors import InputError
from planner.model import ROBOTS_DIR, load_robot
from planner.simulate import SimulateOptions, Strategy, simulate
from planner.task import parse_task
from planner.timefreezing import PUSH_SPEED

G = 9.81
# IPOPT tol 1e-10 and complementarity residual <= 1e-9: states are exact to ~1e-7; the interior
# point keeps selectors wanted at a bound (beta* = 0) ~sqrt(barrier) ~ 3e-6 off it, which leaks
# ~1e-6 into velocities through h a_n.
SOLVER_TOL = 1e-5
SELECTOR_TOL = 1e-5  # same barrier offset of sigma from sigma* on its bound
CLOCK_RATE_TOL = 1e-6  # t' = 1 up to the barrier offset times h
GAP_TOL = 1e-5  # c(q) on the ground (frozen intervals, sliding): solver accuracy
KE_ROUNDING = 1e-12  # 1/2 v^T M v with M = I from CasADi against 1/2 v.v: a few roundings


@functools.cache
def robot():
    return load_robot("point_mass")


@functools.cache
def dynamics():
    return Dynamics(robot())


def task(contact: dict, q0, v0, tau_f: float, N: int, **simulate_keys):
    return parse_task({"contacts": [{"point": "point", **contact}], "initial": {"q": list(q0), "v": list(v0)},
                       "horizon": {"tau_f": tau_f, "N": N}, "simulate": simulate_keys})


@functools.cache
def run(contact: tuple, q0: tuple, v0: tuple, tau_f: float, N: int, rho_f: float = 1.0, schedule: tuple = (),
        strategy: Strategy = Strategy.STEPWISE):
    """Cached simulation (several tests read the same run)."""
    t = task(dict(contact), q0, v0, tau_f, N, rho_f=rho_f, schedule=[{"t": s, "u": list(u)} for s, u in schedule])
    result = simulate(robot(), t, SimulateOptions(strategy=strategy), dynamics=dynamics())
    assert result.stats.converged, result.stats
    return result


def drop(N: int = 100, mu: float = 0.0, strategy: Strategy = Strategy.STEPWISE):
    """Example 1, inelastic: from (0, 1) with v = (1, 0), a_n = 100 (with friction a_t = 300), tau in [0, 1]."""
    contact = (("mu", mu), ("a_n", 100.0)) + ((("a_t", 300.0),) if mu > 0 else ())
    return run(contact, (0.0, 1.0), (1.0, 0.0), 1.0, N, strategy=strategy)


def frozen_steps(result) -> np.ndarray:
    """Indices k of the states y_{k+1} that end a step whose clock did not advance at all."""
    dt = np.diff(result.trajectory.y[:, -1])
    return np.where(dt < SELECTOR_TOL * result.h)[0]


def test_inelastic_frictionless_drop():
    """Impact at sqrt(2/g) (within one step h: time-stepping finds the switch to O(h)); afterwards
    the mass slides on the table at v = (1, 0) with x(t) = t; impulse (eq. 22) = -m v_z^- ; c = 0 while frozen."""
    r = drop()
    tr, h = r.trajectory, r.h
    assert len(tr.impacts) == 1
    imp = tr.impacts[0]
    assert abs(imp.time - math.sqrt(2 / G)) <= h
    np.testing.assert_allclose(imp.v_post, [1.0, 0.0], atol=SOLVER_TOL)
    assert imp.v_pre[1] < -4.0
    assert imp.impulse == pytest.approx(-imp.v_pre[1], abs=SOLVER_TOL)
    # the 1 kg mass's kinetic energy 1/2 |v|^2 (M = I): the landing keeps only the sliding 1/2 J
    assert imp.kinetic_energy_pre == pytest.approx(0.5 * imp.v_pre @ imp.v_pre, rel=KE_ROUNDING)
    assert imp.kinetic_energy_post == pytest.approx(0.5, abs=SOLVER_TOL) and not imp.gains_energy
    after = tr.t > imp.time
    np.testing.assert_allclose(tr.v[after], np.tile([1.0, 0.0], (after.sum(), 1)), atol=SOLVER_TOL)
    np.testing.assert_allclose(tr.q[after, 1], 0.0, atol=GAP_TOL)
    np.testing.assert_allclose(tr.q[:, 0], tr.t, atol=SOLVER_TOL)  # v_x = 1 throughout, nothing slows x
    assert np.all(np.abs(tr.y[frozen_steps(r) + 1, 1]) < GAP_TOL)
    assert np.all(np.diff(tr.t) >= 0)


def test_inelastic_no_slip_drop():
    """With no-slip friction both velocity components jump to 0 at the impact and stay 0; the
    tangential impulse is -m v_x^- = -1 N s and the normal one -m v_z^-."""
    r = drop(mu=0.5)
    tr = r.trajectory
    assert len(tr.impacts) == 1
    imp = tr.impacts[0]
    assert abs(imp.time - math.sqrt(2 / G)) <= r.h
    np.testing.assert_allclose(imp.v_pre[0], 1.0, atol=SOLVER_TOL)
    np.testing.assert_allclose(imp.v_post, [0.0, 0.0], atol=SOLVER_TOL)
    assert imp.impulse_tangential == pytest.approx(-1.0, abs=SOLVER_TOL)
    assert imp.impulse == pytest.approx(-imp.v_pre[1], abs=SOLVER_TOL)
    after = tr.t > imp.time
    np.testing.assert_allclose(tr.v[after], 0.0, atol=SOLVER_TOL)
    np.testing.assert_allclose(tr.q[after, 0], imp.q[0], atol=SOLVER_TOL)


def test_the_deepest_penetration_is_the_lowest_gap_over_the_nodes():
    """summary.json's `penetration` of a simulation is the deepest a contact point went into its plane over the
    nodes, the point and its physical time (the clock): for the point mass the gap is z, so max(0, -min z) over the
    states y (a fixed arm's tip ended 45 mm in the ground in a run that said only "converged"). The drop stays
    within solver accuracy of the table, below the report's PENETRATION_NOTE_M, so its report has no such line."""
    from planner.result import PENETRATION_NOTE_M

    r = drop()
    y, deepest = r.trajectory.y, r.extra["penetration"]
    k = int(np.argmin(y[:, 1]))
    assert deepest == {"max_m": max(0.0, -float(y[k, 1])), "point": "point", "t": float(y[k, -1])}
    assert deepest["max_m"] < GAP_TOL < PENETRATION_NOTE_M and "into its plane" not in r.report()
    assert r.summary()["penetration"] == deepest
    assert r.summary()["forces_outside_friction_cone"] == []  # resting on one no-slip point: no tangential force
    assert r.summary()["braked_outside_friction_cone"] == []


def test_braking_by_the_tangential_field_beyond_the_cone_is_reported():
    """A point mass started sliding at 2 m/s on its plane (mu = 0.1, a_t = 5) brakes at a_t / m = 5 m/s^2 in steps
    whose clock runs, not at mu g = 0.98 m/s^2 (the paper's no-slip contact, docs/tasks.md), with no impact and
    lambda_t = 0: summary.json's braked_outside_friction_cone names the point, the 40 steps it braked (2 m/s at
    0.05 m/s per step of 0.01 s) and the 5 N against mu lambda_n = 0.981 N, and the report says so (nothing did)."""
    task = parse_task({"contacts": [{"point": "point", "mu": 0.1, "a_n": 100.0, "a_t": 5.0}],
                       "initial": {"q": [0.0, 0.0], "v": [2.0, 0.0]}, "horizon": {"tau_f": 0.6, "N": 60}})
    r = simulate(robot(), task, dynamics=dynamics())
    assert r.stats.converged and r.trajectory.impacts == ()
    (brake,) = r.summary()["braked_outside_friction_cone"]
    assert brake["point"] == "point" and brake["steps"] == 40
    assert (brake["max_tangential_N"], brake["mu_normal_N"]) == pytest.approx((5.0, 0.1 * G), rel=1e-4)
    assert "point braked by the tangential auxiliary field beyond its friction cone in 40 running step(s)" in r.report()


def test_a_task_without_contacts_is_implicit_euler_free_flight():
    """contacts = [] simulates a free flight (it crashed in the penetration record, argmin of no gaps): the states
    are implicit Euler's exact recursion v+ = v - g h, q+ = q + h v+ (z_N = z_0 - g h^2 N (N + 1) / 2, x at the
    constant 1 m/s), no impacts, penetration 0 at no point, no force outside a cone; its MuJoCo validation report
    lists no feet."""
    N, h = 10, 0.05
    flight = simulate(robot(), parse_task({"contacts": [], "initial": {"q": [0.0, 1.0], "v": [1.0, 0.0]},
                                           "horizon": {"tau_f": N * h, "N": N}}), dynamics=dynamics())
    tr = flight.trajectory
    assert flight.stats.converged and tr.impacts == ()
    np.testing.assert_allclose(tr.q[-1], [N * h, 1.0 - G * h**2 * N * (N + 1) / 2], atol=SOLVER_TOL)
    assert flight.extra["penetration"] == {"max_m": 0.0, "point": None, "t": None}
    assert flight.extra["forces_outside_friction_cone"] == []
    from planner.replay import validate_plan

    report = validate_plan(robot(), parse_task({"contacts": [], "initial": {"q": [0.0, 1.0], "v": [1.0, 0.0]},
                                               "horizon": {"tau_f": N * h, "N": N}}), tr).report()
    assert "feet max" not in report and "saturation" in report  # no contact points, no "feet max ;"


def test_contact_force_balances_gravity_after_the_drop():
    """The recorded persistent-contact force (Trajectory.contact_force, written as lambda_n, lambda_t
    for the force plot): 0 in flight, and once the no-slip mass (1 kg) rests on the table the normal
    force is m g and the tangential one 0; the physical-time samples carry the same values, from the first one after
    the impact on (the step it ends in read its running share of m g)."""
    r = drop(mu=0.5)
    tr = r.trajectory
    imp = tr.impacts[0]
    clock = tr.y[1:, -1]
    flight, resting = clock < imp.time - r.h, clock > imp.time + 2 * r.h
    np.testing.assert_allclose(tr.contact_force[flight], 0.0, atol=SOLVER_TOL)
    np.testing.assert_allclose(tr.contact_force[resting, 0, 0], G, rtol=SELECTOR_TOL)
    np.testing.assert_allclose(tr.contact_force[resting, 0, 1], 0.0, atol=SOLVER_TOL)
    lam_n, lam_t = tr.contact_force_samples()
    assert lam_n.shape == lam_t.shape == (len(tr.t), 1)
    np.testing.assert_allclose(lam_n[tr.t > imp.time + 2 * r.h, 0], G, rtol=SELECTOR_TOL)
    # the step the impact ends in runs its clock in stance only: m g there too, not m g times its running share
    after = tr.t > imp.time + 1e-12
    assert 0 < tr.t[after][0] - imp.time < r.h
    np.testing.assert_allclose(lam_n[after, 0], G, rtol=SELECTOR_TOL)
    np.testing.assert_allclose(lam_n[tr.t < imp.time - r.h, 0], 0.0, atol=SOLVER_TOL)


def test_fig5_regularization_keeps_wanted_selectors():
    """Fig. 5: q0 = (0, 0), v0 = (5, 0), frictionless, t in [0, 2]. With rho_f = 1 the selectors stay
    at sigma* = (0.5, 0, 0), t' = 1 at every step, no impact is recovered and x = 5 t, z = 0."""
    r = run((("a_n", 200.0),), (0.0, 0.0), (5.0, 0.0), 2.0, 100, rho_f=1.0)
    tr = r.trajectory
    np.testing.assert_allclose(tr.sigma, np.tile([0.5, 0.0, 0.0], (100, 1)), atol=SELECTOR_TOL)
    np.testing.assert_allclose(np.diff(tr.y[:, -1]) / r.h, 1.0, atol=CLOCK_RATE_TOL)
    assert tr.impacts == ()
    np.testing.assert_allclose(tr.q[:, 0], 5.0 * tr.t, atol=SOLVER_TOL)
    np.testing.assert_allclose(tr.q[:, 1], 0.0, atol=GAP_TOL)


def test_fig5_without_regularization_runs_the_clock_slow_but_has_no_impact():
    """Fig. 5 with rho_f = 0: the selectors drift (beta ~0.55) and the clock runs at 0.9729 in every step, each step
    partly frozen while the point stays at rest on the ground (z = 0, v_z = 0 at every node). Those steps are support,
    not impacts: none is recovered (50 spurious impacts of 0.2164 N s in session 46, 100 of half that after session
    54's first rule, then one in the last step)."""
    r = run((("a_n", 200.0),), (0.0, 0.0), (5.0, 0.0), 2.0, 100, rho_f=0.0)
    tr = r.trajectory
    assert tr.impacts == ()
    assert np.all(np.diff(tr.y[:, -1]) / r.h < 1.0 - 1e-3)  # every step partly frozen (the rate ~0.9729)
    np.testing.assert_allclose(tr.q[:, 1], 0.0, atol=GAP_TOL)


def test_contact_breaking_under_pull():
    """A mass resting on the table is pulled up by 15 N > m g from t1 = 0.3 s: it rests (z = 0, v = 0)
    until t1, leaves the table at t1 (within one step), and then follows z = (15 - g)(t - t1)^2 / 2
    to first order in h. No impact happens."""
    t1, force, N, tau_f = 0.3, 15.0, 100, 1.0
    r = run((("a_n", 200.0),), (0.0, 0.0), (0.0, 0.0), tau_f, N, schedule=((t1, (0.0, force)),))
    tr, h = r.trajectory, r.h
    assert tr.impacts == ()
    before = tr.t < t1 - h / 2
    np.testing.assert_allclose(tr.q[before], 0.0, atol=GAP_TOL)
    np.testing.assert_allclose(tr.v[before], 0.0, atol=SOLVER_TOL)
    airborne = tr.q[:, 1] > GAP_TOL
    t_leave = tr.t[np.argmax(airborne) - 1]  # last sample on the table
    assert abs(t_leave - t1) <= h
    assert np.all(airborne[tr.t > t1 + 1.5 * h])
    late = tr.t > t1 + 0.2
    exact = (force - G) * (tr.t[late] - t1) ** 2 / 2
    np.testing.assert_allclose(tr.q[late, 1], exact, atol=(force - G) * (tr.t[-1] - t1) * 2 * h)


FESD_PULL_TOL = 1e-4  # [m] FESD's flight after the pull-off is exact to the step solves' tolerance (measured 1e-6)


def test_fesd_pulls_a_resting_mass_off_the_table_at_a_scheduled_step():
    """FESD: a mass resting on the table, pulled up by 20 N > m g from the step at t1 = 0.3 s (the schedule's rule):
    the step after the control's jump starts from the multipliers of its own switching functions, so it converges
    (the previous step's, of the old control, left it no solution: "complementarity residual 5", exit 1) and the
    flight is z = (20 - g)(t - t1)^2 / 2."""
    t1, force = 0.3, 20.0
    t = task({"a_n": 100.0}, (0.0, 0.0), (0.0, 0.0), 0.6, 30, schedule=[{"t": t1, "u": [0.0, force]}])
    result = simulate(robot(), t, SimulateOptions(discretization=Discretization.FESD, fesd=FESDOptions()),
                      dynamics=dynamics())
    assert result.stats.converged, result.stats.message
    tr = result.trajectory
    assert tr.impacts == ()
    assert tr.q[-1, 1] == pytest.approx((force - G) * (tr.t[-1] - t1) ** 2 / 2, abs=FESD_PULL_TOL)


def test_fesd_keeps_a_standing_robots_contact_through_a_control_jump():
    """FESD: Capler standing under its joint PD while the schedule's feed-forward jumps (0 -> (1, -1) -> 0 N m): its
    foot stays in persistent contact, no impact, as implicit Euler has it. The boundary multipliers of the new
    control's switching functions are the fallback of a step the last stage's cannot solve (used first, they gave a
    0.22 N s "impact" at the jump that gained kinetic energy)."""
    capler = load_robot("capler")
    t = parse_task({"contacts": [{"point": "foot", "mu": 0.8, "a_n": 200.0, "a_t": 600.0}],
                    "initial": {"q": [0.0, 0.4, 0.0, 0.0]}, "horizon": {"tau_f": 0.5, "N": 25},
                    "simulate": {"schedule": [{"t": 0.1, "u": [1.0, -1.0]}, {"t": 0.3, "u": [0.0, 0.0]}],
                                 "pd": {"joints": ["hip", "knee"], "kp": [100.0, 100.0], "kd": [2.0, 2.0]}}})
    result = simulate(capler, t, SimulateOptions(discretization=Discretization.FESD, fesd=FESDOptions()))
    assert result.stats.converged, result.stats.message
    assert result.trajectory.impacts == ()


FESD_IMPULSE_RTOL = 1e-4  # the landing's impulse against m sqrt(2 g h0): measured 5e-6 (the step solves' tolerance)


def test_fesd_flight_selectors_leaks_are_no_braking_outside_the_cone():
    """FESD with friction (mu = 0.5, 6 elements): the thrown mass's flight elements leak the tangential field by ~1e-6
    N, which is no braking beyond the cone (the report flagged 1.95e-6 N "where mu normal = 0 N"; the floor is 1e-5 of
    the robot's weight); the landing's impulse is still m |v_pre|."""
    t = task({"mu": 0.5, "a_n": 100.0}, (0.0, 1.0), (1.0, 0.0), 0.6, 30)
    result = simulate(robot(), t, SimulateOptions(discretization=Discretization.FESD, fesd=FESDOptions(n_fe=6)),
                      dynamics=dynamics())
    assert result.stats.converged, result.stats.message
    assert result.extra["braked_outside_friction_cone"] == []
    (impact,) = result.trajectory.impacts
    assert impact.impulse == pytest.approx(math.sqrt(2 * G), rel=FESD_IMPULSE_RTOL)


# --- elastic impacts (Sec. 4.5) -------------------------------------------------------------------

ELASTIC_K = 16.0  # oscillator stiffness a_n [1/s^2]: frozen interval pi / omega_d ~ 0.8 s of numerical time
ELASTIC_H0 = 1.0  # drop height [m]
ELASTIC_TAU = {0.5: 2.8, 0.9: 3.8}  # numerical horizons covering two impacts and the second apex
# Implicit Euler damps the oscillator: per impact the restitution comes out low by ~ (pi/2) h sqrt(k)
# (6.3 h for k = 16, measured 6.2 h to 6.4 h for h = 0.005 .. 0.001); 25 % margin.
def ratio_rtol(h: float) -> float:
    return 1.25 * (math.pi / 2) * math.sqrt(ELASTIC_K) * h


# Apex heights add twice the ratio error per impact and implicit Euler's flight error (~ g h / v per
# flight): first order with measured constants ~25 h (first apex) and ~60 h (second apex) for
# h = 0.005 .. 0.001; the tolerances are 30 h and 70 h (0.15 and 0.35 at h = 0.005, 0.03 and 0.07
# at h = 0.001, the slow test).
APEX_RTOL_PER_H = (30.0, 70.0)


def elastic(eps: float, h: float):
    tau_f = ELASTIC_TAU[eps]
    return run((("restitution", eps), ("a_n", ELASTIC_K)), (0.0, ELASTIC_H0), (0.0, 0.0), tau_f, round(tau_f / h))


def check_elastic(eps: float, h: float):
    r = elastic(eps, h)
    tr = r.trajectory
    complete = [imp for imp in tr.impacts if imp.tau_end < tr.tau[-1]]
    assert len(complete) >= 2
    for imp in complete:  # post-impact normal velocity = -eps x pre-impact
        assert imp.v_post[1] / imp.v_pre[1] == pytest.approx(-eps, rel=ratio_rtol(h))
        assert imp.impulse == pytest.approx(imp.v_post[1] - imp.v_pre[1], rel=SOLVER_TOL * 100)
        assert imp.kinetic_energy_post == pytest.approx(eps ** 2 * imp.kinetic_energy_pre, rel=2 * ratio_rtol(h))
        assert not imp.gains_energy  # a bounce gives back at most what it took
    times = [imp.time for imp in tr.impacts] + [np.inf]
    for k in (1, 2):  # apex heights eps^(2k) h0
        apex = tr.q[(tr.t > times[k - 1]) & (tr.t < times[k]), 1].max()
        assert apex == pytest.approx(eps ** (2 * k) * ELASTIC_H0, rel=APEX_RTOL_PER_H[k - 1] * h)
    # frozen intervals: q does not dive, c(q) = 0, while p < 0 carries the oscillation
    inside = frozen_steps(r) + 1
    assert len(inside) > 0
    assert np.all(np.abs(tr.y[inside, 1]) < GAP_TOL)
    assert np.min(tr.y[:, 1]) > -GAP_TOL
    assert np.min(tr.y[inside, 4]) < -0.1
    assert np.all(np.abs(tr.y[:, 4]) < ELASTIC_H0 * 2) and PUSH_SPEED > 2 * math.sqrt(2 * G * ELASTIC_H0)


@pytest.mark.parametrize("eps", [0.5, 0.9])
def test_elastic_restitution_and_apex_heights(eps):
    """Elastic eps in {0.5, 0.9}, drop from 1 m at rest, h = 0.005: post-impact normal velocity
    = -eps x pre-impact, apex heights eps^(2k) h0 (to first order in h, see the tolerances), c(q) = 0
    during frozen intervals (no diving), impulse = change of normal momentum."""
    check_elastic(eps, 0.005)


@pytest.mark.slow
@pytest.mark.parametrize("eps", [0.5, 0.9])
def test_elastic_restitution_and_apex_heights_fine(eps):
    """The same at h = 0.001: the tolerances shrink with h (ratio 0.8 %, apex heights 3 % and 7 %)."""
    check_elastic(eps, 0.001)


# --- convergence -------------------------------------------------------------------------------

MIN_RATE = 0.8  # first order expected; a rate of at least 0.8 over the last halvings shows it


def fit_rate(hs, errors) -> float:
    return float(np.polyfit(np.log(hs), np.log(errors), 1)[0])


def drop_error(r) -> float:
    """max |q(t) - q_exact(t)| over the physical samples, plus the impact time error [m + s]."""
    tr = r.trajectory
    ts = math.sqrt(2 / G)
    z = np.where(tr.t < ts, 1 - G * tr.t**2 / 2, 0.0)
    err_q = np.max(np.abs(tr.q - np.column_stack([tr.t, z])))
    return err_q + abs(tr.impacts[0].time - ts)


def bounce_exact(t: np.ndarray, eps: float, h0: float) -> np.ndarray:
    """Height of the elastic bouncing ball at times t."""
    t1, v = math.sqrt(2 * h0 / G), math.sqrt(2 * G * h0)
    z = np.where(t < t1, h0 - G * t**2 / 2, 0.0)
    start = t1
    for _ in range(10):
        v *= eps
        T = 2 * v / G
        inside = (t >= start) & (t < start + T)
        s = t[inside] - start
        z[inside] = v * s - G * s**2 / 2
        start += T
    return z


def elastic_error(r, eps: float) -> float:
    """max |z(t) - z_exact(t)| up to the first apex after the first impact [m], plus the ratio error."""
    tr = r.trajectory
    imp = tr.impacts[0]
    t_apex = imp.time + eps * math.sqrt(2 * G * ELASTIC_H0) / G
    m = tr.t <= t_apex
    err_q = np.max(np.abs(tr.q[m, 1] - bounce_exact(tr.t[m], eps, ELASTIC_H0)))
    return err_q + abs(imp.v_post[1] / imp.v_pre[1] + eps)


def test_convergence_inelastic_drop(capsys):
    """Case 1: the physical-time error falls at least linearly in h (h = 0.04 .. 0.005); prints the rate."""
    hs = [0.04, 0.02, 0.01, 0.005]
    errors = [drop_error(drop(N=round(1.0 / h))) for h in hs]
    rate = fit_rate(hs, errors)
    with capsys.disabled():
        print(f"\ninelastic drop: h {hs} error {np.round(errors, 5).tolist()} rate {rate:.2f}")
    assert rate >= MIN_RATE and errors[-1] < errors[0]


def test_convergence_elastic(capsys):
    """Case 4 (eps = 0.5): the physical-time error through the first impact falls at least linearly
    in h (h = 0.02 .. 0.005); prints the rate."""
    hs = [0.02, 0.01, 0.005]
    errors = [elastic_error(elastic(0.5, h), 0.5) for h in hs]
    rate = fit_rate(hs, errors)
    with capsys.disabled():
        print(f"\nelastic eps = 0.5: h {hs} error {np.round(errors, 5).tolist()} rate {rate:.2f}")
    assert rate >= MIN_RATE and errors[-1] < errors[0]


# --- strategies and bad input --------------------------------------------------------------------

def test_horizon_strategy_agrees_with_stepwise():
    """Solving all steps as one NLP gives the same trajectory as stepping one OSNP at a time
    (the discretized problem has one solution; both solve it to the solver tolerance)."""
    a, b = drop(N=50), drop(N=50, strategy=Strategy.HORIZON)
    np.testing.assert_allclose(b.trajectory.y, a.trajectory.y, atol=SOLVER_TOL)
    assert b.trajectory.impacts[0].time == pytest.approx(a.trajectory.impacts[0].time, abs=SOLVER_TOL)


def test_a_simulation_records_its_options():
    """summary.json's options are the SimulateOptions the run was given, field by field (a notebook run with other
    options wrote the same keys as a default run's, so its files could not say how to reproduce it), and they build
    the same options again."""
    r = drop(N=50, strategy=Strategy.HORIZON)
    recorded = r.summary()["options"]
    assert recorded["strategy"] == "horizon" and recorded["max_iter"] == SimulateOptions().max_iter
    assert SimulateOptions(**{**recorded, "fesd": FESDOptions(**recorded["fesd"])}) == SimulateOptions(
        strategy=Strategy.HORIZON)


def test_initial_state_below_ground_is_input_error():
    """An initial state with the contact point below the ground is refused, naming the key."""
    t = task({}, (0.0, -0.01), (0.0, 0.0), 1.0, 10)
    with pytest.raises(InputError, match="initial.q"):
        simulate(robot(), t, dynamics=dynamics())


def test_options_are_validated():
    """Options are checked when built: unknown strategy values and out-of-range numbers are errors, named with the
    class as every options class names its fields ("strategy = 'fast'" alone did not say whose)."""
    with pytest.raises(InputError, match=r"^SimulateOptions.strategy = 'fast' is not allowed; it must be one of"):
        SimulateOptions(strategy="fast")
    with pytest.raises(InputError, match=r"^SimulateOptions.velocity_switch = 'x' is not allowed"):
        SimulateOptions(velocity_switch="x")
    with pytest.raises(InputError, match="kappa"):
        SimulateOptions(kappa=1.0)


def test_simulate_task_keys_are_validated():
    """The [simulate] keys added for this issue: rho_f >= 0, schedule sorted by strictly increasing t >= 0 and nu
    controls each; every error names the key."""
    from planner.errors import TaskError

    base = {"contacts": [{"point": "point"}], "initial": {"q": [0.0, 1.0]}, "horizon": {"tau_f": 1.0, "N": 10}}
    with pytest.raises(TaskError, match="simulate.rho_f"):
        parse_task({**base, "simulate": {"rho_f": -1.0}})
    for second in (0.2, 0.5):  # two entries at one time would leave which acts to the order
        with pytest.raises(TaskError, match=r"simulate.schedule .*strictly increasing t"):
            parse_task({**base, "simulate": {"schedule": [{"t": 0.5, "u": [0, 1]}, {"t": second, "u": [0, 0]}]}})
    with pytest.raises(TaskError, match=r"simulate.schedule\[0\].t = -0.5"):
        parse_task({**base, "simulate": {"schedule": [{"t": -0.5, "u": [0, 1]}]}})
    with pytest.raises(TaskError, match="unknown key 'simulate.schedule\\[0\\].force'|unknown key"):
        parse_task({**base, "simulate": {"schedule": [{"t": 0.5, "force": [0, 1]}]}})
    t = parse_task({**base, "simulate": {"schedule": [{"t": 0.5, "u": [0.0]}]}})
    with pytest.raises(TaskError, match=r"simulate.schedule\[0\].u"):
        t.check_against(robot())
    t = parse_task({**base, "simulate": {"u": [1.0, 2.0], "schedule": [{"t": 0.5, "u": [3.0, 4.0]}]}})
    np.testing.assert_array_equal(t.simulate.controls_at(0.49, 2), [1.0, 2.0])
    np.testing.assert_array_equal(t.simulate.controls_at(0.5, 2), [3.0, 4.0])


def test_failed_step_returns_diagnostics():
    """A step whose NLP fails (here: one IPOPT iteration allowed) ends the simulation with
    converged = False, a message naming the step, and the steps solved before it."""
    t = task({"a_n": 100.0}, (0.0, 1.0), (1.0, 0.0), 0.2, 10)
    r = simulate(robot(), t, SimulateOptions(max_iter=1, max_nlp=1), dynamics=dynamics())
    assert not r.stats.converged and "step 0" in r.stats.message
    assert len(r.trajectory.tau) == 1 and r.summary()["converged"] is False


def test_a_step_ipopt_failed_is_not_converged_even_if_complementary(monkeypatch):
    """A step whose IPOPT run reports failure (stubbed: the real solve's point, flagged as
    Maximum_Iterations_Exceeded) is not converged even though that point is complementary (residual <= comp_tol):
    IPOPT's point may violate the dynamics rows, which the complementarity residual does not see. The simulation
    stops there with converged = False and a message naming the step and IPOPT's status, and not the residual (it
    read "complementarity residual 0 > 1e-09")."""
    import planner.simulate as sim

    real = sim._solve_homotopy

    def failing(*args, **kwargs):
        x, lam, comp, n_nlp, iterations, _, _ = real(*args, **kwargs)
        return x, lam, comp, n_nlp, iterations, False, "Maximum_Iterations_Exceeded"

    monkeypatch.setattr(sim, "_solve_homotopy", failing)
    options = SimulateOptions(restarts=False)
    r = simulate(robot(), task({"a_n": 100.0}, (0.0, 1.0), (1.0, 0.0), 0.02, 2), options, dynamics=dynamics())
    assert r.stats.complementarity_residual <= options.comp_tol  # the iterate itself is complementary
    assert r.stats.converged is False
    assert "step 0" in r.stats.message and "IPOPT Maximum_Iterations_Exceeded" in r.stats.message
    assert "complementarity residual" not in r.stats.message


def test_a_scheduled_control_acts_from_the_step_whose_midpoint_passed_it():
    """[[simulate.schedule]] is read at each step's physical midpoint t_k + h / 2: with a change at t1 = 2.4 h
    (point mass in flight, clock rate 1, h = 10 ms) steps 0 and 1 (midpoints 0.5 h, 1.5 h) use the old control and
    step 2 (midpoint 2.5 h, start 2 h < t1) already the new one, so the change acts from the step nearest t1. The
    recovered samples carry the control of the step that ends at them; z follows implicit Euler with it."""
    h, u_old, u_new = 0.01, (0.0, 0.0), (0.0, 20.0)
    r = run((("a_n", 100.0),), (0.0, 1.0), (0.0, 0.0), 4 * h, 4, schedule=((2.4 * h, u_new),))
    tr = r.trajectory
    assert r.h == pytest.approx(h, rel=1e-15) and tr.impacts == ()
    np.testing.assert_allclose(np.diff(tr.y[:, -1]), h, atol=CLOCK_RATE_TOL * h)
    np.testing.assert_array_equal(tr.u[1:], [u_old, u_old, u_new, u_new])
    vz = np.cumsum([0.0] + [h * (u[1] - G) for u in (u_old, u_old, u_new, u_new)])  # implicit Euler: v_{k+1} = v_k + h a
    np.testing.assert_allclose(tr.v[:, 1], vz, atol=SOLVER_TOL)


@pytest.mark.parametrize("second_impulse, contacts_hit", [(0.5, ("a", "b")), (0.05, ("a",))])
def test_a_contact_takes_part_in_an_impact_from_a_hundredth_of_the_largest_impulse(second_impulse, contacts_hit):
    """planner.result.recover on a hand-built run of three implicit Euler steps (h = 0.1 s; q, v (2,) each): step 1
    is a landing (the clock runs 0.05 s of it, then freezes) in which two contacts take normal impulses of 10 N s and
    `second_impulse`. A contact with at least IMPULSE_SHARE = 1/100 of the largest impulse took part in the impact and
    gets its own Impact record (0.5 N s: two records, the largest first, both at t = 0.15 s); 0.05 N s is a resting
    contact's drift correction: one record. Either way the impact is one pair of samples."""
    from planner.result import recover

    h = 0.1
    tau = h * np.arange(4)
    clock = np.array([0.0, h, 1.5 * h, 2.5 * h])  # step 1 runs half its clock: frozen (an impact), not fully
    y = np.column_stack([np.zeros((4, 4)), clock])
    y[2:, 3] = 1.0  # v_z after the impact
    dv_aux = np.zeros((3, 2))
    dv_aux[1, 1] = 1.0
    impulses = np.zeros((3, 2, 2))  # (steps, contacts, normal/tangential)
    impulses[1, :, 0] = (10.0, second_impulse)
    t, q, v, u, impacts = recover(tau, y, np.zeros((3, 2)), np.full(3, h), dv_aux, impulses, 2, 2, ("a", "b"))
    assert tuple(imp.contact for imp in impacts) == contacts_hit
    assert [imp.impulse for imp in impacts] == [10.0, second_impulse][: len(contacts_hit)]
    assert all(imp.time == 1.5 * h for imp in impacts)
    np.testing.assert_array_equal(t, [0.0, h, 1.5 * h, 1.5 * h, 2.5 * h])
    np.testing.assert_array_equal(v[2:4, 1], [0.0, 1.0])  # pre- and post-impact v_z


# --- joint PD (simulate.pd) and predictor restarts ------------------------------------------------

PD_KP, PD_KD = 40.0, 3.0  # [N/m, N s/m] on the 1 kg mass: underdamped, so the recursion shows in x(t)


def test_pd_is_an_implicit_controller():
    """PD on x of the mass resting on the frictionless table: x follows the implicit Euler recursion
    of m x'' = kp (x_ref - x) - kd x' with the force evaluated at the END of each step,
    (m + h kd + h^2 kp) v_{k+1} = m v_k + h kp (x_ref - x_k), x_{k+1} = x_k + h v_{k+1}, and the
    recorded controls are the PD at the recorded states; the explicit recursion is far away. The
    HORIZON strategy (all steps in one NLP) gives the same trajectory."""
    N, tau_f, x0, x_ref = 50, 0.5, 0.1, 0.0
    t = parse_task({"contacts": [{"point": "point"}], "initial": {"q": [x0, 0.0]}, "horizon": {"tau_f": tau_f, "N": N},
                    "simulate": {"pd": {"joints": ["x"], "kp": [PD_KP], "kd": [PD_KD], "q_ref": [x_ref]}}})
    r = simulate(robot(), t, dynamics=dynamics())
    assert r.stats.converged and r.trajectory.impacts == ()
    h, tr = r.h, r.trajectory
    implicit, explicit = np.zeros((N + 1, 2)), np.zeros((N + 1, 2))
    implicit[0] = explicit[0] = [x0, 0.0]
    for k in range(N):
        x, v = implicit[k]
        v1 = (v + h * PD_KP * (x_ref - x)) / (1.0 + h * PD_KD + h**2 * PD_KP)
        implicit[k + 1] = [x + h * v1, v1]
        x, v = explicit[k]
        v1 = v + h * (PD_KP * (x_ref - x) - PD_KD * v)
        explicit[k + 1] = [x + h * v1, v1]
    np.testing.assert_allclose(tr.q[:, 0], implicit[:, 0], atol=SOLVER_TOL)
    np.testing.assert_allclose(tr.v[:, 0], implicit[:, 1], atol=SOLVER_TOL)
    assert np.abs(explicit[:, 0] - implicit[:, 0]).max() > 100 * SOLVER_TOL
    np.testing.assert_allclose(tr.u[1:, 0], PD_KP * (x_ref - tr.q[1:, 0]) - PD_KD * tr.v[1:, 0], atol=SOLVER_TOL)
    np.testing.assert_allclose(tr.u[:, 1], 0.0)  # z has no PD and no feed-forward
    assert r.summary()["pd"]["steps_beyond_actuator_bounds"] == 0
    whole = simulate(robot(), t, SimulateOptions(strategy=Strategy.HORIZON), dynamics=dynamics())  # the PD in one NLP
    np.testing.assert_allclose(whole.trajectory.y, tr.y, atol=SOLVER_TOL)


# A body on a vertical slide carrying a foot on a prismatic leg (the leg under PD): the foot's impulse only stops the
# foot (J M^-1 J^T = 1 / FOOT_MASS), so an inelastic landing takes FOOT_MASS times the touchdown speed.
BODY_MASS, FOOT_MASS = 5.0, 0.5  # [kg]
LEGGED_SLIDER = f"""<mujoco><worldbody><body name="body"><joint name="z" type="slide" axis="0 0 1"/>
<inertial pos="0 0 0" mass="{BODY_MASS}" diaginertia="0.05 0.05 0.05"/><body name="foot" pos="0 0 -0.5">
<joint name="leg" type="slide" axis="0 0 -1"/><inertial pos="0 0 0" mass="{FOOT_MASS}" diaginertia="0.002 0.002 0.002"/>
<site name="foot"/></body></body></worldbody><actuator><motor name="leg_m" joint="leg"/></actuator></mujoco>"""


def test_a_landing_under_pd_records_the_flight_before_it(tmp_path):
    """A drop held by a stiff leg PD falls rigidly (zero error, zero speed: no force), so the impact record must read
    free fall, v_pre = (-g t, 0), and the inelastic impulse FOOT_MASS g t at its time t. The implicit step evaluates
    the PD at its end, after the impact: its reaction to the leg's post-impact compression had been read into v_pre
    (the leg moving at 0.8 m/s in free fall) and the impulse (55 % too large on a hopper), misleading a user who checks
    the energy lost at impacts."""
    path = tmp_path / "legged_slider.xml"
    path.write_text(LEGGED_SLIDER)
    t = parse_task({"contacts": [{"point": "foot"}], "initial": {"q": [0.6, 0.0]}, "horizon": {"tau_f": 0.3, "N": 15},
                    "simulate": {"pd": {"joints": ["leg"], "kp": [2000.0], "kd": [50.0]}}})
    r = simulate(load_robot(path), t)
    assert r.stats.converged and len(r.trajectory.impacts) == 1
    (imp,) = r.trajectory.impacts
    np.testing.assert_allclose(imp.v_pre, [-G * imp.time, 0.0], atol=SOLVER_TOL)
    assert imp.impulse == pytest.approx(FOOT_MASS * G * imp.time, abs=SOLVER_TOL)
    assert imp.kinetic_energy_pre == pytest.approx(0.5 * (BODY_MASS + FOOT_MASS) * (G * imp.time) ** 2, abs=SOLVER_TOL)


# LEGGED_SLIDER with two legs, the "low" foot 3 cm below the "high" one: the low foot lands first and stands while its
# leg's PD brakes the body, then the high foot lands inside a step.
TWO_LEGGED_SLIDER = f"""<mujoco><worldbody><body name="body"><joint name="z" type="slide" axis="0 0 1"/>
<inertial pos="0 0 0" mass="{BODY_MASS}" diaginertia="0.05 0.05 0.05"/><body name="low" pos="0.1 0 -0.53">
<joint name="low" type="slide" axis="0 0 -1"/><inertial pos="0 0 0" mass="{FOOT_MASS}" diaginertia="0.002 0.002 0.002"/>
<site name="low"/></body><body name="high" pos="-0.1 0 -0.5"><joint name="high" type="slide" axis="0 0 -1"/>
<inertial pos="0 0 0" mass="{FOOT_MASS}" diaginertia="0.002 0.002 0.002"/><site name="high"/></body></body></worldbody>
<actuator><motor name="low_m" joint="low"/><motor name="high_m" joint="high"/></actuator></mujoco>"""


def test_a_landing_beside_a_standing_foot_under_pd_keeps_its_support(tmp_path):
    """When the second foot lands inside a step while the first stands on the ground, the standing foot must not move
    into the ground at the impact: its pre-impact velocity along the normal, v_z - v_low, is zero. That flight is not
    free; a reading of the free field alone dropped the standing foot's support and had it sink at 1.2 m/s in v_pre
    (the body in free fall, a bounder's standing foot recorded with a 0.44 N s impact for its 0.06 N s tap)."""
    path = tmp_path / "two_legged_slider.xml"
    path.write_text(TWO_LEGGED_SLIDER)
    t = parse_task({"contacts": [{"point": "low"}, {"point": "high"}], "initial": {"q": [0.6, 0.0, 0.0]},
                    "horizon": {"tau_f": 0.3, "N": 15},
                    "simulate": {"pd": {"joints": ["low", "high"], "kp": [2000.0] * 2, "kd": [50.0] * 2}}})
    r = simulate(load_robot(path), t)
    assert r.stats.converged
    assert [imp.contact for imp in r.trajectory.impacts] == ["low", "high"]
    landing = r.trajectory.impacts[-1]
    assert landing.time > r.trajectory.impacts[0].time
    assert landing.v_pre[0] - landing.v_pre[1] == pytest.approx(0.0, abs=SOLVER_TOL)


def test_simulate_pd_keys_are_validated():
    """[simulate.pd]: one kp, kd (>= 0) and q_ref per joint, no repeated joints; against the robot:
    known joints with exactly one actuator. Every error names the key."""
    from planner.errors import TaskError, UnknownNameError

    base = {"contacts": [{"point": "foot"}], "initial": {"q": [0.0, 0.4, 0.0, 0.0]}, "horizon": {"tau_f": 1.0, "N": 10}}

    def pd(**keys):
        return parse_task({**base, "simulate": {"pd": {"joints": ["hip", "knee"], "kp": [1.0, 1.0], "kd": [0.1, 0.1], **keys}}})

    with pytest.raises(TaskError, match=r"simulate.pd.kp .* 2 numbers"):
        pd(kp=[1.0])
    with pytest.raises(TaskError, match=r"simulate.pd.kd .* >= 0"):
        pd(kd=[0.1, -0.1])
    with pytest.raises(TaskError, match=r"simulate.pd.q_ref .* 2 numbers"):
        pd(q_ref=[0.0])
    with pytest.raises(TaskError, match=r"simulate.pd.joints .* repeated"):
        pd(joints=["hip", "hip"])
    with pytest.raises(TaskError, match=r"unknown key 'simulate.pd.gain'"):
        pd(gain=1.0)
    capler = load_robot("capler")
    with pytest.raises(UnknownNameError, match="valid joints: base_x"):
        pd(joints=["hip", "ankle"]).check_against(capler)
    with pytest.raises(TaskError, match="'base_z' is driven by 0 actuators"):
        pd(joints=["hip", "base_z"]).check_against(capler)
    pd().check_against(capler)


# A flight step of the unactuated Capler collapsing after a no-slip landing (its state 30 of a drop
# from 5 cm, h = 4 ms): the foot 0.3 mm above the ground, the implicit flight step ends 0.9 mm above it.
HARD_STEP_Q = [-0.00064, 0.37318, -0.18126, 0.67462]
HARD_STEP_V = [-0.02782, -0.95944, -8.46535, 17.46552]


def test_stalled_step_restarts_from_the_flight_predictor():
    """From the warm start with rho0 = 100, rho_f ||sigma - sigma*||^2 pulls the selectors off the exact
    solution (free flight, sigma = 1) into a spurious minimizer of the penalized NLP, complementarity
    2e-5 whatever rho; restarting from the implicit flight step with rho0 = 1e4 finds the exact solution."""
    t = parse_task({"contacts": [{"point": "foot", "mu": 0.8}], "initial": {"q": HARD_STEP_Q, "v": HARD_STEP_V},
                    "horizon": {"tau_f": 0.004, "N": 1}})
    capler = load_robot("capler")
    stalled = simulate(capler, t, SimulateOptions(restarts=False))
    assert not stalled.stats.converged and stalled.stats.complementarity_residual > 1e-5
    r = simulate(capler, t)
    assert r.stats.converged and r.summary()["restarted_steps"] == 1
    np.testing.assert_allclose(r.trajectory.sigma[0], 1.0, atol=SELECTOR_TOL)
    assert r.trajectory.impacts == ()


# --- several contact points ----------------------------------------------------------------------

BIPED_MASS = 35.0  # [kg] hip 15 + torso 10 + legs 2 x 5 (robots/biped.xml)
# Sum of normal forces vs m g: the interior point leaves beta ~3e-6 off its bound (see SOLVER_TOL),
# which mixes ~1e-6 of f_ODE and f_A,n into the step; measured 1.5e-6 relative.
FORCE_BALANCE_RTOL = 1e-5
# The clock rate R = r_1 r_2 of two feet at rest: each r_i = beta_i + 2 alpha_i (1 - beta_i) carries the
# barrier offset of beta_i (~3e-6, see SELECTOR_TOL); measured 1 - R = 2.3e-6.
CLOCK_RATE_TOL_TWO = 1e-5
FOOT_DRIFT_M = 1e-6  # a foot in persistent no-slip contact: the implicit step's O(h^2) gap drift, measured 5e-7 m


@functools.cache
def biped():
    return load_robot("biped")


def biped_task(q0, tau_f: float, N: int, **simulate_keys):
    return parse_task({"contacts": [{"point": "foot_1", "mu": 0.8}, {"point": "foot_2", "mu": 0.8}],
                       "initial": {"q": list(q0)}, "horizon": {"tau_f": tau_f, "N": N}, "simulate": simulate_keys})


def foot_positions(result, foot: str) -> np.ndarray:
    dyn = Dynamics(biped())
    return np.array([np.asarray(dyn.point_position(foot)(q), float).ravel() for q in result.trajectory.q])


def test_biped_stands_on_both_feet(capsys):
    """The biped standing on both feet (legs +-0.2 rad, joint PD holding them) stays still for 0.2 s:
    no impact, no motion, the clock runs at rate 1, and the two normal contact forces add up to its
    weight m g (the horizontal forces cancel)."""
    spread = 0.2
    t = biped_task([0.0, math.cos(spread), 0.0, spread, -spread], 0.2, 20,
                   pd={"joints": ["hinge_1", "hinge_2"], "kp": [2000.0] * 2, "kd": [50.0] * 2})
    r = simulate(biped(), t)
    tr = r.trajectory
    assert r.stats.converged and tr.impacts == ()
    np.testing.assert_allclose(tr.q, np.tile(t.initial.q, (len(tr.q), 1)), atol=SOLVER_TOL)
    np.testing.assert_allclose(tr.v, 0.0, atol=SOLVER_TOL)
    np.testing.assert_allclose(np.diff(tr.y[:, -1]) / r.h, 1.0, atol=CLOCK_RATE_TOL_TWO)
    assert tr.force_names == ("lambda_n[foot_1]", "lambda_t[foot_1]", "lambda_n[foot_2]", "lambda_t[foot_2]")
    normal = tr.forces[:, 0] + tr.forces[:, 2]
    err = np.abs(normal / (BIPED_MASS * G) - 1.0).max()
    with capsys.disabled():
        print(f"\nbiped on both feet: normal forces {tr.forces[-1, [0, 2]].round(4).tolist()} N, sum vs m g relative error {err:.1e}")
    assert err < FORCE_BALANCE_RTOL
    np.testing.assert_allclose(tr.forces[:, 1] + tr.forces[:, 3], 0.0, atol=FORCE_BALANCE_RTOL * BIPED_MASS * G)


def test_biped_single_support_swings_the_other_leg():
    """On foot_1 (leg vertical, PD on its hinge) with foot_2 17 cm up, a -20 N m torque on hinge_2
    swings leg 2 up for 0.2 s: foot_1 stays where it is (no slip, on the ground) with a positive
    normal force, foot_2 moves 7 cm forward and 5 cm up with zero force, and there is no impact."""
    t = biped_task([0.0, 1.0, 0.0, 0.0, -0.6], 0.2, 50, u=[0.0, -20.0], pd={"joints": ["hinge_1"], "kp": [2000.0], "kd": [50.0]})
    r = simulate(biped(), t)
    tr = r.trajectory
    assert r.stats.converged and tr.impacts == ()
    f1, f2 = foot_positions(r, "foot_1"), foot_positions(r, "foot_2")
    np.testing.assert_allclose(f1, np.tile(f1[0], (len(f1), 1)), atol=FOOT_DRIFT_M)
    assert f2[-1, 0] - f2[0, 0] > 0.05 and f2[-1, 2] - f2[0, 2] > 0.03 and f2[:, 2].min() > 0.17
    assert tr.forces[:, 0].min() > 0.5 * BIPED_MASS * G
    np.testing.assert_allclose(tr.forces[:, 2:], 0.0, atol=SOLVER_TOL)
    np.testing.assert_allclose(tr.sigma[:, 5], 1.0, atol=SELECTOR_TOL)  # beta[foot_2]: in flight


def wall_normals(slope_deg: float):
    """Unit normals (x, 0, z) of the two planes of a V-shaped corner at the origin, slopes +-slope_deg:
    the left wall rises to the left, the right wall to the right; the wedge between them (the free
    space) has the angle 180 - 2 slope_deg."""
    a = math.radians(slope_deg)
    return [math.sin(a), 0.0, math.cos(a)], [-math.sin(a), 0.0, math.cos(a)]


def corner_task(slope_deg: float, x0: float, tau_f: float, N: int):
    n1, n2 = wall_normals(slope_deg)
    a = math.radians(slope_deg)
    return parse_task({"contacts": [{"point": "point", "normal": n1}, {"point": "point", "normal": n2}],
                       "initial": {"q": [x0, abs(x0) * math.tan(a)]}, "horizon": {"tau_f": tau_f, "N": N}})


def test_point_mass_rests_in_an_obtuse_corner():
    """A 1 kg mass at the bottom of two frictionless walls meeting at 140 deg (slopes +-20 deg) stays
    there with the wall forces m g / (2 cos 20 deg) each: the two contacts share the weight."""
    r = simulate(robot(), corner_task(20.0, 0.0, 0.2, 20), dynamics=dynamics())
    tr = r.trajectory
    assert r.stats.converged and tr.impacts == ()
    np.testing.assert_allclose(tr.q, 0.0, atol=SOLVER_TOL)
    assert tr.force_names == ("lambda_n[point#1]", "lambda_n[point#2]")
    np.testing.assert_allclose(tr.forces, G / (2 * math.cos(math.radians(20.0))), rtol=FORCE_BALANCE_RTOL)


def test_a_frozen_impact_in_several_contacts_carries_no_persistent_force():
    """Dropped 2 m into the obtuse corner with a_n = 20 N, the mass lands on both walls in an impact frozen over
    several steps (the clock stopped): those steps' persistent-contact forces (lambda_n, lambda_t) are 0, as
    docs/results.md says, while the NLP's joint forces (`forces`) there hold the resting 5.22 N each (lambda_n had read
    them); the samples at the impact read the landing step's force, and the rest after it m g / (2 cos 20 deg)."""
    n1, n2 = wall_normals(20.0)
    task = parse_task({"contacts": [{"point": "point", "normal": n1, "a_n": 20.0},
                                    {"point": "point", "normal": n2, "a_n": 20.0}],
                       "initial": {"q": [0.0, 2.0]}, "horizon": {"tau_f": 1.0, "N": 50}})
    r = simulate(robot(), task, dynamics=dynamics())
    tr = r.trajectory
    assert r.stats.converged and len(tr.impacts) == 2
    frozen = np.diff(tr.y[:, -1]) <= 1e-2 * r.h
    assert frozen.sum() >= 3
    np.testing.assert_allclose(tr.forces[frozen], G / (2 * math.cos(math.radians(20.0))), rtol=FORCE_BALANCE_RTOL)
    np.testing.assert_array_equal(tr.contact_force[frozen], 0.0)
    lam_n, _ = tr.contact_force_samples()
    at_impact = np.isclose(tr.t, tr.impacts[0].time, rtol=0.0, atol=1e-12)
    landing = int(np.argmax(frozen)) - 1  # the partly frozen step before the frozen run
    np.testing.assert_allclose(lam_n[at_impact], tr.contact_force[landing, :, 0][None, :].repeat(at_impact.sum(), 0))
    np.testing.assert_allclose(lam_n[-1], G / (2 * math.cos(math.radians(20.0))), rtol=FORCE_BALANCE_RTOL)


def test_point_mass_slides_into_an_acute_corner_and_stops():
    """Released on the left wall of a 60 deg wedge (slopes +-60 deg, frictionless), the mass slides
    down, hits the right wall and stops in the corner: the inelastic impact of two walls whose normals
    are 120 deg apart takes the whole velocity (both walls push, v+ = 0), then it rests in the corner."""
    r = simulate(robot(), corner_task(60.0, -0.1, 0.5, 100), dynamics=dynamics())
    tr = r.trajectory
    assert r.stats.converged
    first = [imp for imp in tr.impacts if imp.time == tr.impacts[0].time]
    assert {imp.contact for imp in first} == {"point#1", "point#2"} and all(imp.impulse > 0 for imp in first)
    np.testing.assert_allclose(first[0].v_post, 0.0, atol=SOLVER_TOL)
    np.testing.assert_allclose(tr.q[-1], 0.0, atol=GAP_TOL)


def test_point_mass_slides_through_an_obtuse_corner():
    """Released on the left wall of a 140 deg corner (slopes +-20 deg, frictionless), the mass slides
    down and meets the right wall: it then moves up the right wall (v+ tangent to it, leaving the
    left one), never below either wall. The rigid impact (LCP) keeps the tangential speed, v+ = v- -
    (n2 . v-) n2; the time-freezing step also pulls on the left wall while the clock restarts (a
    negative impulse, docs/formulation.md "Several contacts"): v+ is the LCP direction at 79 % of
    its speed (measured), and never faster."""
    n1, n2 = (np.array([n[0], n[2]]) for n in wall_normals(20.0))
    r = simulate(robot(), corner_task(20.0, -0.3, 0.6, 120), dynamics=dynamics())
    tr = r.trajectory
    assert r.stats.converged
    imp = tr.impacts[0]
    assert imp.contact == "point#2" and imp.impulse > 0
    lcp = imp.v_pre - (n2 @ imp.v_pre) * n2
    assert n2 @ imp.v_post == pytest.approx(0.0, abs=SOLVER_TOL) and n1 @ imp.v_post > 0
    assert imp.v_post[0] * lcp[1] - imp.v_post[1] * lcp[0] == pytest.approx(0.0, abs=SOLVER_TOL)  # same direction
    assert 0.7 < np.linalg.norm(imp.v_post) / np.linalg.norm(lcp) <= 1.0
    gaps = np.column_stack([tr.q @ n1, tr.q @ n2])
    assert gaps.min() > -GAP_TOL
    after = tr.t > imp.time + 0.05
    assert np.all(tr.q[after, 0] > 0) and np.all(gaps[after, 0] > GAP_TOL)  # up the right wall, off the left one


def test_a_horizon_that_ends_inside_an_impact_says_so(tmp_path):
    """The frozen interval of a landing lasts ~2 m |v_n| / a_n of numerical time (measured: 0.44 s for 10 kg at
    4.4 m/s and a_n = 200): a 100 kg point mass dropped from 1 m needs 4.4 s and the 1.5 s horizon ends inside its
    impact. The result says so (ends_in_impact, the report's last line, summary.json); its impulse, 105 N s of the
    443 N s that stop it, was reported as the impact's. The 10 kg drop's impact ends within the horizon."""
    source = (load_robot("point_mass").path).read_text()
    assert source.count('mass="1"') == 1
    task = parse_task({"contacts": [{"point": "point", "mu": 0.0}], "initial": {"q": [0.0, 1.0]},
                       "horizon": {"tau_f": 1.5, "N": 150}})
    for mass, unfinished in (("100", True), ("10", False)):
        path = tmp_path / f"pm_{mass}.xml"
        path.write_text(source.replace('mass="1"', f'mass="{mass}"'))
        result = simulate(load_robot(path), task)
        assert result.stats.converged and len(result.trajectory.impacts) == 1
        assert result.ends_in_impact is unfinished and result.summary()["ends_in_impact"] is unfinished
        assert ("the horizon ends inside the last impact" in result.report()) is unfinished


def test_fesd_simulates_a_robot_without_actuators(tmp_path):
    """The FESD simulation of a robot without actuators (the point mass without its motors: nu = 0) drops it from
    z = 0.2 m to one impact and converges: reshaping its element controls, an empty array, to (-1, n_s, 0) raised
    "ValueError: cannot reshape array of size 0" after the last step."""
    source = robot().path.read_text()
    start, end = source.index("<actuator>"), source.index("</actuator>") + len("</actuator>")
    passive = tmp_path / "passive.xml"
    passive.write_text(source[:start] + source[end:])
    unactuated = load_robot(passive)
    assert unactuated.nu == 0
    task = parse_task({"contacts": [{"point": "point"}], "initial": {"q": [0.0, 0.2]}, "horizon": {"tau_f": 0.3, "N": 6}})
    # `planner simulate --discretization fesd`'s elements: FESDOptions' default n_fe = 2 leaves no spare element for
    # the landing step (it ends unconverged with the motors too)
    result = simulate(unactuated, task, SimulateOptions(discretization=Discretization.FESD, fesd=FESDOptions(n_s=2, n_fe=4)))
    assert result.stats.converged, result.stats.message
    assert len(result.trajectory.impacts) == 1 and result.trajectory.u.shape[1] == 0


def test_a_joint_beyond_the_files_range_is_reported(tmp_path):
    """A simulation has no joint limits but MuJoCo's replay has the file's: a slide joint falling through its range
    (no contacts, range [-0.1, 0.1] m) is listed in summary.json with its nodes beyond and its farthest value, and
    the report names it; a joint that stays inside is not listed."""
    path = tmp_path / "slider.xml"
    path.write_text('<mujoco><worldbody><body name="b"><joint name="z" type="slide" axis="0 0 1" range="-0.1 0.1"/>'
                    '<inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/><site name="s"/><body name="arm">'
                    '<joint name="x" type="slide" axis="1 0 0" range="-1 1"/><inertial pos="0 0 0" mass="1" '
                    'diaginertia="1 1 1"/></body></body></worldbody><actuator><motor name="m" joint="x"/></actuator>'
                    '</mujoco>')
    task = parse_task({"contacts": [], "initial": {"q": [0.0, 0.0]}, "horizon": {"tau_f": 0.3, "N": 10}})
    res = simulate(load_robot(path), task)
    z = res.trajectory.y[:, 0]
    assert res.stats.converged and z.min() < -0.1
    (entry,) = res.summary()["joints_outside_range"]
    assert entry == {"joint": "z", "nodes": int(np.sum(z < -0.1)), "farthest": float(z.min()), "lower": -0.1,
                     "upper": 0.1, "unit": "m"}
    assert f"z left the robot file's range [-0.1, 0.1] m at {entry['nodes']} of 11 nodes" in res.report()


def test_fesd_pd_summary_counts_steps_not_elements():
    """Under FESD the PD summary's steps_beyond_actuator_bounds counts steps (at most N), each step's largest element
    command standing for it, as implicit Euler's does: a saturating PD over 10 steps of 4 elements read 33."""
    from planner.simulate import Discretization

    task = parse_task({"contacts": [{"point": "point", "mu": 0.5}], "initial": {"q": [0.0, 0.0]},
                       "horizon": {"tau_f": 0.1, "N": 10},
                       "simulate": {"pd": {"joints": ["x"], "kp": [20000.0], "kd": [50.0], "q_ref": [0.1]}}})
    robot = load_robot("point_mass")
    fesd = simulate(robot, task, SimulateOptions(discretization=Discretization.FESD, fesd=FESDOptions(n_fe=4)))
    euler = simulate(robot, task)
    fesd_pd, euler_pd = fesd.summary()["pd"], euler.summary()["pd"]
    assert 0 < fesd_pd["steps_beyond_actuator_bounds"] <= task.horizon.N
    assert fesd_pd["steps_beyond_actuator_bounds"] == pytest.approx(euler_pd["steps_beyond_actuator_bounds"], abs=1)


def test_a_failed_step_counts_the_nlps_of_all_its_attempts(monkeypatch):
    """A step that fails after restarts says how many NLPs the step ran in all its attempts (it said the last
    attempt's: "after 8 NLPs (3 restarts)" of a step that had run 32)."""
    import planner.simulate as S

    monkeypatch.setattr(S, "_solve_homotopy", lambda *args, **kw: (None, None, 1.0, 5, 50, True, "Solve_Succeeded"))
    total = {"n_nlp": 0, "iterations": 0, "restarted_steps": 0, "comp": 0.0, "ok": True}
    starts = [(None, SimulateOptions())] * 4
    assert S._first_converged(None, None, iter(starts), None, (None,) * 4, SimulateOptions(), total, "step 7") is None
    assert total["message"].endswith("after 20 NLPs (3 restarts)") and total["n_nlp"] == 20


@pytest.mark.parametrize("kwargs, key", [({"strategy": "stepwise", "max_passes": 1}, "max_passes = 1"),
                                         ({"strategy": "horizon", "restarts": False}, "restarts = False"),
                                         ({"strategy": "horizon", "restart_rho0": 5.0}, "restart_rho0 = 5.0")])
def test_options_of_the_other_strategy_are_refused(kwargs, key):
    """max_passes (read by the horizon strategy only) and restarts, restart_rho0 (stepwise only) given with the other
    strategy are InputErrors naming the option (they were accepted and ignored)."""
    with pytest.raises(InputError, match=key + ".* unless strategy is"):
        SimulateOptions(**kwargs)
    # restart_rho0 without the restarts that read it (session 56's tester: the same drop, accepted)
    with pytest.raises(InputError, match=r"restart_rho0 = 5.0 .* unless restarts is on"):
        SimulateOptions(strategy="stepwise", restarts=False, restart_rho0=5.0)


def test_an_unfinished_last_impact_is_not_judged_for_energy():
    """An impact still frozen when the horizon ends is unfinished (its v_post partial): its post-impact kinetic energy
    is not computed (nan), so it is never flagged as gaining energy (a passive ball's last, partial bounce read
    "5.8e-17 -> 4.8e-09 J", a push-off); the finished impacts before it keep theirs."""
    task = parse_task({"contacts": [{"point": "point", "restitution": 0.01, "a_n": 16.0}], "initial": {"q": [0.0, 1.0]},
                       "horizon": {"tau_f": 0.6, "N": 120}})
    result = simulate(load_robot("point_mass"), task)
    assert result.ends_in_impact
    last = result.trajectory.impacts[-1]
    assert math.isnan(last.kinetic_energy_post) and not last.gains_energy and last.kinetic_energy_pre > 0
    assert "gain kinetic energy" not in result.report()


def test_a_step_counts_as_beyond_the_bounds_when_any_of_its_elements_is():
    """FESD's PD summary judges each element's command against the bounds and counts a step once if any of its
    elements left them: with a range [0, 5] the elements (-0.5, 3.0) of one step are beyond (a reduction to the
    largest |u| kept 3.0 and counted none)."""
    from types import SimpleNamespace

    from planner.simulate import _pd_summary

    robot = SimpleNamespace(u_lower=np.array([0.0]), u_upper=np.array([5.0]), nu=1)
    pd = SimpleNamespace(joints=("x",), kp=(1.0,), kd=(1.0,))
    task = SimpleNamespace(simulate=SimpleNamespace(pd=pd), pd_actuators=lambda robot: [])
    U = np.array([[-0.5], [3.0], [2.0], [1.0]])  # two steps of two elements
    assert _pd_summary(robot, task, None, U, per_step=2)["steps_beyond_actuator_bounds"] == 1
    assert _pd_summary(robot, task, None, U)["steps_beyond_actuator_bounds"] == 1  # four steps of one element


STRADDLE_IMPULSE_RTOL = 1e-3  # the impulse m |v_pre| against the drop's: gravity over the frozen part, solver tolerance


@pytest.mark.parametrize("z0, v0, N", [(1.032, 0.0, 35), (1.005, 1.0, 70)])
def test_a_stiff_landing_across_a_node_is_one_whole_impact(z0, v0, N):
    """With a_n = 1e4 a landing straddles a node, one of its two steps freezing under frozen_tol (1 %): the impact is
    still whole, v_pre the fall's sqrt(2 g z0) (within g h), v_post at rest on the ground and the impulse
    m |v_pre|. At z0 = 1.032 the second step froze 0.99 % and v_post kept moving into the ground at 2 m/s (44 % of the
    impulse missing); at z0 = 1.005 the first froze 0.998 % and v_pre read -3.4 m/s (23 % missing)."""
    task = parse_task({"contacts": [{"point": "point", "a_n": 1e4}], "initial": {"q": [0.0, z0], "v": [v0, 0.0]},
                       "horizon": {"tau_f": 0.7, "N": N}})
    impacts = simulate(load_robot("point_mass"), task).trajectory.impacts
    assert len(impacts) == 1
    imp, fall = impacts[0], math.sqrt(2 * G * z0)
    assert abs(-imp.v_pre[1] - fall) <= G * 0.7 / N  # implicit Euler's speed is the fall's within one step's g h
    assert abs(imp.v_post[1]) < GAP_TOL and imp.v_post[0] == pytest.approx(v0, abs=GAP_TOL)
    assert imp.impulse == pytest.approx(-imp.v_pre[1], rel=STRADDLE_IMPULSE_RTOL)


PLANK_XML = ('<mujoco><worldbody><body name="plank"><joint name="x" type="slide" axis="1 0 0"/><joint name="z" '
             'type="slide" axis="0 0 1"/><joint name="pitch" type="hinge" axis="0 1 0"/><inertial pos="0 0 0" '
             'mass="1" diaginertia="0.01 0.01 0.01"/><site name="A" pos="1 0 -0.49"/><site name="B" pos="-0.3 0 -0.5"/>'
             '</body></worldbody></mujoco>')
MOMENTUM_TOL = 1e-3  # [N s] the impulses against M dv_z: the steps' solver tolerance, far below the 1.5 N s


def test_a_landing_beside_a_resting_contact_is_an_impact(tmp_path):
    """A plank resting on its end B (frictionless) whose other end A swings down and lands at ~6.4 m/s: the landing
    is an impact of both ends (B takes 2.9 times A's impulse, as the rigid LCP), whose normal impulses sum to the
    plank's vertical momentum change. Read by the larger impulse's contact (B at rest on the ground at both ends of
    the steps) it was support, and no impact was left."""
    path = tmp_path / "plank.xml"
    path.write_text(PLANK_XML)
    plank = parse_task({"contacts": [{"point": "A", "a_n": 200.0}, {"point": "B", "a_n": 200.0}],
                        "initial": {"q": [0.0, 0.5, 0.0], "v": [0.0, -1.5, 5.0]}, "horizon": {"tau_f": 0.2, "N": 20}})
    result = simulate(load_robot(path), plank)
    assert result.stats.converged
    impacts = result.trajectory.impacts
    assert {im.contact for im in impacts} == {"A", "B"}
    before, after = (result.trajectory.v[result.trajectory.t == impacts[0].time][i, 1] for i in (0, -1))
    assert sum(im.impulse for im in impacts) == pytest.approx(after - before, abs=MOMENTUM_TOL)


def test_a_simulation_that_fails_at_its_first_step_returns_its_diagnostics():
    """A simulation whose very first step does not converge (here: one IPOPT iteration per NLP; a tester's point 0.1 mm
    up thrown up at 0.3 m/s) returns a failed result, as any failed step's (it raised an IndexError reading the last
    node of no steps)."""
    t = parse_task({"contacts": [{"point": "point", "a_n": 200.0}], "initial": {"q": [0.0, 1e-4], "v": [0.0, 0.3]},
                    "horizon": {"tau_f": 0.2, "N": 10}})
    result = simulate(robot(), t, SimulateOptions(max_iter=1))
    assert not result.stats.converged and "step 0" in result.stats.message


def test_a_simulation_through_a_hole_warns_that_it_has_flat_ground():
    """A point mass dropped over one of the task's plan.holes lands on the flat ground a simulation has there: a
    warning names the point and the hole (it landed and validated without a word, session 58's tester); the same drop
    beside the hole says nothing."""
    import warnings

    def drop(hole_x: float) -> list[str]:
        task = parse_task({"contacts": [{"point": "point", "mu": 0.5}], "initial": {"q": [0.25, 0.5]},
                           "horizon": {"tau_f": 1.0, "N": 100},
                           "plan": {"target_q": [0.25, 0.0], "holes": [{"x": hole_x, "a": 0.1, "b": 0.1}]}})
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            simulate(load_robot("robots/point_mass.xml"), task)
        return [str(w.message) for w in caught]

    assert any(m.startswith("'point' is inside plan.holes[0] from t = 0.29 s: a simulation runs on flat ground")
               for m in drop(0.25))
    assert not any("plan.holes" in m for m in drop(2.0))


SEED = 0  # the seeded states below
PD_ROUNDING = 1e-12  # [N] the PD law's force through gear and back: a few products of numbers ~10
ONE_PRODUCT = 1e-15  # h S computed once each way: one product's rounding
POINT_MASS = (ROBOTS_DIR / "point_mass.xml").read_text()  # the file a variant edits


def test_pd_gains_are_joint_gains_whatever_the_gear(robot_variant):
    """[simulate.pd]'s kp, kd are the joint's stiffness and damping [N/m, N s/m] (docs/tasks.md: u += (kp (q_ref - q)
    - kd v) / g): on the point mass with force_x at gear 2 (and -0.5), the generalized force of the PD law, B u, is
    kp (q_ref - x) - kd v_x exactly (analytic). Every shipped robot has gear 1, so a law that left out the division by
    the gear (a mutant of session 65's mutation testing) doubled the stiffness of a geared joint unnoticed."""
    from planner.simulate import pd_law

    kp, kd, x_ref = 40.0, 3.0, 0.25
    task = parse_task({"contacts": [{"point": "point"}], "initial": {"q": [0.1, 0.5]},
                       "horizon": {"tau_f": 0.1, "N": 10},
                       "simulate": {"pd": {"joints": ["x"], "kp": [kp], "kd": [kd], "q_ref": [x_ref]}}})
    rng = np.random.default_rng(SEED)
    for gear in ("2", "-0.5"):
        robot = robot_variant(POINT_MASS, '<motor name="force_x" joint="x" gear="1"',
                              f'<motor name="force_x" joint="x" gear="{gear}"', f"gear{gear}.xml")
        law = pd_law(robot, task)
        for _ in range(3):
            q, v = rng.uniform(-1.0, 1.0, 2), rng.uniform(-1.0, 1.0, 2)
            force = robot.actuation_matrix @ law(np.zeros(robot.nu), q, v)
            assert force == pytest.approx([kp * (x_ref - q[0]) - kd * v[0], 0.0], abs=PD_ROUNDING)


TWO_SITES = ('<mujoco><worldbody><body name="b"><joint name="z" type="slide" axis="0 0 1"/><inertial pos="0 0 0" '
             'mass="1" diaginertia="1 1 1"/><site name="high" pos="0 0 0.05"/><site name="low" pos="0 0 0"/></body>'
             '</worldbody></mujoco>')


def test_the_penetration_names_the_contact_with_the_lowest_gap(tmp_path):
    """summary.json's `penetration` names the contact point whose gap is the lowest over the nodes and the clock there:
    a slider falling with two contact points, "high" 5 cm above "low", listed either way round, names "low" at the
    last node (ground truth: the gaps, z and z + 0.05, at the states; the slider does not reach the ground, so max_m is
    0). A report that named the first contact whatever its gap (a mutant of session 65's mutation testing) sent the
    user to the wrong foot of a robot."""
    from planner.simulate import simulate

    path = tmp_path / "two_sites.xml"
    path.write_text(TWO_SITES)
    for order in (["high", "low"], ["low", "high"]):
        task = parse_task({"contacts": [{"point": point} for point in order], "initial": {"q": [0.1]},
                           "horizon": {"tau_f": 0.1, "N": 5}})
        r = simulate(load_robot(path), task)
        assert r.stats.converged, r.stats.message
        z = r.trajectory.y[:, 0]
        k = int(np.argmin(z))
        assert z[k] > 0.0 and r.extra["penetration"] == {"max_m": 0.0, "point": "low",
                                                          "t": float(r.trajectory.y[k, -1])}


def test_fesd_collocates_only_the_steps_that_start_on_the_ground():
    """FESD with n_s >= 2 solves a step with the COLLOCATED n^T v switching function only for a contact that starts it
    in persistent contact: on its plane (gap multiplier lambda1 of c(q) ~ 0) with n^T v ~ 0 (SimulateOptions'
    velocity_switch, docs/formulation.md "FESD in persistent contact"). The point mass released at rest 0.5 m above the
    table (n^T v = 0, gap 0.5 m) and falling 0.06 s never touches it: no step is collocated (ground truth: the gaps at
    the steps' starts are > 0.48 m). Weights read from n^T v alone (a mutant of session 65's mutation testing)
    collocated the first step of every fall from rest, and of every apex, in the air."""
    from planner.discretization import Discretization
    from planner.simulate import SimulateOptions, simulate

    task = parse_task({"contacts": [{"point": "point"}], "initial": {"q": [0.0, 0.5]},
                       "horizon": {"tau_f": 0.06, "N": 3}})
    r = simulate(load_robot("point_mass"), task, SimulateOptions(discretization=Discretization.FESD))
    assert r.stats.converged and r.trajectory.y[:, 1].min() > 0.48
    assert r.extra["discretization"]["velocity_switch"] == "collocated"
    assert r.extra["discretization"]["collocated_steps"] == 0


def test_the_reported_complementarity_is_the_worst_steps(monkeypatch):
    """stats.complementarity_residual of a STEPWISE simulation is the largest residual over its steps (the run is as
    complementary as its worst step): with the steps' homotopies stubbed to report 5e-10 for step 0 and 1e-12 after it
    (the real solves' points, both under comp_tol), the run reports 5e-10. Read from the last step alone (a mutant of
    session 65's mutation testing), an early step's residual up to comp_tol was hidden behind a later one's 1e-12."""
    import planner.simulate as sim
    from planner.simulate import SimulateOptions, simulate

    real, calls = sim._solve_homotopy, []

    def stubbed(*args, **kwargs):
        x, lam, _, n_nlp, iterations, ok, message = real(*args, **kwargs)
        calls.append(None)
        return x, lam, 5e-10 if len(calls) == 1 else 1e-12, n_nlp, iterations, ok, message

    monkeypatch.setattr(sim, "_solve_homotopy", stubbed)
    task = parse_task({"contacts": [{"point": "point"}], "initial": {"q": [0.0, 0.5]},
                       "horizon": {"tau_f": 0.04, "N": 3}})
    r = simulate(load_robot("point_mass"), task, SimulateOptions(restarts=False))
    assert r.stats.converged and len(calls) == 3
    assert r.stats.complementarity_residual == 5e-10


def test_step_elements_integrate_h_times_the_speed_of_time():
    """step_elements turns N implicit-Euler steps into element_trajectory's elements with the integrated lengths dt = h
    S_k (its docstring: step k integrates h S[k] F; a plan with horizon.physical_time has a speed of time S_k != 1 per
    step), and dt = h without S (a simulation). The impulses, the auxiliary velocity increments and the contact forces'
    clock share of a plan's recovered trajectory are quadratures over dt. Built with h alone (a mutant of session 65's
    mutation testing), a timed plan's impacts were reported with impulses off by the factor S_k."""
    from planner.discretization import ImplicitEulerStep
    from planner.dynamics import Dynamics
    from planner.simulate import step_elements
    from planner.task import Contact
    from planner.timefreezing import TimeFreezingSystem

    sys_ = TimeFreezingSystem(Dynamics(load_robot("point_mass")), [Contact("point")])
    builder = ImplicitEulerStep(sys_)
    N, h = 4, 0.02
    rng = np.random.default_rng(SEED)
    Y, W, U = rng.normal(size=(N + 1, sys_.ny)), rng.normal(size=(N, builder.nw)), rng.normal(size=(N, sys_.nu))
    S = rng.uniform(0.5, 2.0, N)
    tau, Y_b, Ys, Ws, Us, dt = step_elements(sys_, builder, Y, W, U, h, S)
    assert dt == pytest.approx(h * S, rel=ONE_PRODUCT) and tau == pytest.approx(h * np.arange(N + 1))
    assert step_elements(sys_, builder, Y, W, U, h)[-1] == pytest.approx(np.full(N, h), rel=ONE_PRODUCT)


def test_the_pd_summary_gives_each_joints_reference():
    """summary.json's pd.q_ref lists each PD joint's reference in the order of pd.joints: the task's q_ref, else the
    joint's initial.q (docs/tasks.md); here z (q index 1) before x, so each joint's entry is its own coordinate's, not
    that of the coordinate at the joint's position in the list (session 66's mutation testing: q_ref read at the list's
    index, x's and z's references swapped, Capler's hip and knee given those of x_B and z_B, with every test green)."""
    robot = load_robot("point_mass")
    for q_ref, expected in ((None, [0.5, 0.3]), ([0.7, 0.2], [0.7, 0.2])):
        pd = {"joints": ["z", "x"], "kp": [10.0, 20.0], "kd": [1.0, 2.0]} | ({} if q_ref is None else {"q_ref": q_ref})
        task = parse_task({"contacts": [{"point": "point"}], "initial": {"q": [0.3, 0.5]},
                           "horizon": {"tau_f": 0.02, "N": 2}, "simulate": {"pd": pd}})
        assert simulate(robot, task).summary()["pd"]["q_ref"] == expected


def test_a_velocity_switch_given_is_the_one_fesd_steps_use():
    """SimulateOptions.velocity_switch, when given, is the switching function of the steps, also where the default
    would differ: FESD with 2 stages (default COLLOCATED) asked for POINT runs POINT, as summary.json's
    discretization says, and no step is collocated (session 66's mutation testing: the option ignored, every FESD run
    collocated, with every test green)."""
    from planner.discretization import SwitchVelocity

    task = parse_task({"contacts": [{"point": "point"}], "initial": {"q": [0.0, 0.5]},
                       "horizon": {"tau_f": 0.06, "N": 3}})
    options = SimulateOptions(discretization=Discretization.FESD, velocity_switch=SwitchVelocity.POINT)
    assert options.fesd.n_s >= 2  # where the default is COLLOCATED
    r = simulate(load_robot("point_mass"), task, options)
    assert r.stats.converged and r.extra["discretization"]["velocity_switch"] == "point"
    assert "collocated_steps" not in r.extra["discretization"]


def test_a_simulation_of_a_task_edited_in_code_does_not_claim_its_file():
    """A simulation's task (summary.json's "task") of a task edited in code with dataclasses.replace, which keeps the
    file's source, is that file's absolute path followed by " (edited)": point_mass.toml with N edited to 3 was named
    plainly, though its file's N is 150 (as a plan's since session 69)."""
    from dataclasses import replace
    from pathlib import Path

    from planner.task import EDITED, load_task

    on_file = load_task(ROBOTS_DIR / "point_mass.toml")
    edited = replace(on_file, horizon=replace(on_file.horizon, N=3))
    assert simulate(robot(), edited, dynamics=dynamics()).task == str(Path(on_file.source).absolute()) + EDITED
