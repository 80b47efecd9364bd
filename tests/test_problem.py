"""The transcribed OCP is inspectable: named variable and constraint blocks, bounds, the hint-free guess."""
from __future__ import annotations

import dataclasses
import math
import pathlib
import re
import warnings

import numpy as np
import pytest

from planner.discretization import StepForm
from planner.errors import InputError, shown_up
from planner.model import load_robot
from planner.problem import Penalty, ProblemOptions, build_problem, static_controls
from planner.task import Horizon, VelocityBound, load_task, parse_task

ROBOTS = pathlib.Path(__file__).resolve().parents[1] / "robots"  # (not the working directory's)
SUM_ROUNDING_REL = 1e-12  # one sum of a few squares evaluated by CasADi and by NumPy: rounding only
# M^-1 written symbolically (EXPLICIT) against M times the forward dynamics' solve (MASS_MATRIX), cond(M) ~ 5e3 on
# Capler: rounding only (measured 5e-14 on rows of size ~10, contact_forces rows 5e-12)
FORM_TOL = 1e-9
# the solved plan's rows hold to IPOPT's tolerance (1e-8 scaled; the clock measured 5e-16 off T)
SOLVED_TOL = 1e-6


def hop_task(N: int = 40, holes=()):
    """Point mass resting on the ground with friction, asked to be at x = 0.5 m (no-slip: it must hop)."""
    return parse_task({"contacts": [{"point": "point", "mu": 0.5}], "initial": {"q": [0.0, 0.0]},
                       "horizon": {"tau_f": 1.0, "N": N},
                       "plan": {"target_q": [0.5, 0.0], "u_bound": 30.0, "holes": list(holes)}})


@pytest.fixture(scope="module")
def capler_small():
    robot = load_robot(f"{ROBOTS}/capler.xml")
    task = load_task(f"{ROBOTS}/capler.toml")
    task = dataclasses.replace(task, horizon=Horizon(tau_f=0.5, N=10))
    return robot, task, build_problem(robot, task)


def test_blocks_sizes_and_bounds(capler_small):
    """Every stage has u (nu), y (ny), w (nw) blocks; bounds come from the task (torques, joint bounds,
    selectors in [0, 1]); constraint blocks are named and sized per stage."""
    robot, task, prob = capler_small
    N, nu, ny, nw = 10, robot.nu, prob.system.ny, prob.builder.nw
    assert prob.var_blocks["u"].shape == (N, nu)
    assert prob.var_blocks["y"].shape == (N, ny)
    assert prob.var_blocks["w"].shape == (N, nw)
    assert "s" not in prob.var_blocks and "s_c" in prob.var_blocks  # no physical horizon, l_inf slack (default)
    assert prob.nx == N * (nu + ny + nw) + 1 == len(prob.var_names) == len(prob.lbx) == len(prob.x0)
    u = prob.var_blocks["u"]
    assert np.all(prob.lbx[u] == -60) and np.all(prob.ubx[u] == 60)
    hip = robot.dof_index("hip")
    assert np.allclose(prob.ubx[prob.var_blocks["y"][:, hip]], 3 * np.pi / 8)
    sig = prob.var_blocks["sigma"]
    assert np.all(prob.lbx[sig] == 0) and np.all(prob.ubx[sig] == 1)
    for name in ("dynamics", "stationarity", "lifting", "contact_forces", "above_ground", "holes", "friction_cone"):
        assert prob.g_blocks[name].shape[0] == N, name
    assert prob.g_blocks["holes"].shape[1] == 3 and prob.g_blocks["above_ground"].shape[1] == 2
    assert prob.g_blocks["friction_cone"].shape[1] == 2
    assert prob.g_blocks["terminal"].shape == (1, 2 * robot.nq)  # q and v (target_v defaults to zeros)
    assert len(prob.pairs) == N * 2 * prob.system.n_sigma
    assert set(prob.objective_parts) == {"control", "selectors", "penalty"}
    eq = np.concatenate([prob.g_blocks[n].ravel() for n in ("dynamics", "stationarity", "lifting", "contact_forces", "terminal")])
    assert np.all(prob.lbg[eq] == 0) | np.all(prob.lbg[eq] == prob.ubg[eq])
    assert np.all(prob.ubg[prob.g_blocks["holes"].ravel()] == np.inf)


def test_initial_guess_is_hint_free(capler_small):
    """x0: y0 at every node, zero controls, the same algebraic guess at every stage (paper Sec. 7)."""
    _, task, prob = capler_small
    Y = prob.x0[prob.var_blocks["y"]]
    assert np.allclose(Y, prob.y0[None, :])
    assert np.all(prob.x0[prob.var_blocks["u"]] == 0)
    W = prob.x0[prob.var_blocks["w"]]
    assert np.allclose(W, W[0][None, :])
    # the guess is consistent with the switching functions at y0: every product is zero
    assert prob.complementarity_residual(prob.x0) == pytest.approx(0.0, abs=1e-12)


# the static balance B u + J^T lambda = g(q0) by the planner's CasADi functions and by Pinocchio's numeric rnea and
# frame Jacobians: rounding of terms ~60 N (measured 1e-14); the cones and bounds hold to the QP's tolerance
STATIC_TOL = 1e-8  # [N, N m]
# [N m] a static torque above this is the start's own need, below it none: the stances that need torque need 0.24 to
# 18.4 (Capler's crouch, the biped on slippery ground), those that need none get rounding (~1e-16)
STATIC_TORQUE_NM = 0.1
CROUCH_Q = (0.0, 0.4 * math.cos(0.3), 0.3, -0.6)  # Capler's foot on the ground under a bent knee [m, m, rad, rad]
# [m/s^2, rad/s^2] the guessed acceleration of a start held at rest is rounding (~3e-15 on the crouched Capler): far
# below the ~1e3 rad/s^2 of the standing torques on a robot guessed in flight
REST_ACCEL_TOL = 1e-9


# (the biped's splayed stance needs no torque where its feet may push sideways, 18.5 N at 171.7 N, and hip torque
# where the cone forbids that: mu = 0.05 the QP's case, mu = 0 the frictionless contacts')
@pytest.mark.parametrize("robot_name, initial_q, mu, torque", [("capler", CROUCH_Q, None, True),
                                                               ("biped", None, None, False), ("biped", None, 0.05, True),
                                                               ("biped", None, 0.0, True)])
def test_static_controls_hold_the_start_against_gravity(robot_name, initial_q, mu, torque):
    """static_controls (SolveOptions.start_controls = static) gives torques u and contact forces that hold the start
    at rest: B u + sum_i J_i^T (n lambda_n + t lambda_t) equals the gravity term, Pinocchio's rnea at zero velocity
    and acceleration (with its own frame Jacobians), the forces push (lambda_n >= 0) inside each friction cone and u
    is within its bounds: a start that is statically feasible, on one contact (a crouched Capler, whose knee needs
    torque) and on two (the biped's feet, also on slippery ground, where the torques must do what friction cannot)."""
    import pinocchio as pin

    robot = load_robot(f"{ROBOTS}/{robot_name}.xml")
    task = load_task(f"{ROBOTS}/{robot_name}.toml")
    if initial_q is not None:
        task = dataclasses.replace(task, initial=dataclasses.replace(task.initial, q=initial_q),
                                   horizon=Horizon(tau_f=0.5, N=10))
    if mu is not None:
        task = dataclasses.replace(task, contacts=tuple(dataclasses.replace(c, mu=mu) for c in task.contacts))
    prob = build_problem(robot, task)
    u, forces = static_controls(prob)
    q0 = prob.y0[: robot.nq]
    data = robot.model.createData()
    gravity = pin.rnea(robot.model, data, q0, np.zeros(robot.nv), np.zeros(robot.nv))
    pin.computeJointJacobians(robot.model, data, q0)
    pin.updateFramePlacements(robot.model, data)
    balance = robot.actuation_matrix @ u
    for contact, (lam_n, lam_t) in zip(prob.system.contacts, forces):
        J = pin.getFrameJacobian(robot.model, data, robot.frame_id(contact.point), pin.LOCAL_WORLD_ALIGNED)[:3]
        balance += J.T @ (np.array([0.0, 0.0, 1.0]) * lam_n + np.array([1.0, 0.0, 0.0]) * lam_t)
        assert lam_n > 0 and abs(lam_t) <= contact.mu * lam_n + STATIC_TOL
    np.testing.assert_allclose(balance, gravity, atol=STATIC_TOL)
    u_block = prob.var_blocks["u"][0]
    assert np.all(u >= prob.lbx[u_block]) and np.all(u <= prob.ubx[u_block])
    assert (np.abs(u).max() > STATIC_TORQUE_NM) == torque


def test_static_controls_refuse_a_start_in_the_air_and_warn_when_they_cannot_hold_it():
    """static_controls refuses a start with no contact point on its plane (an InputError naming the points: nothing
    can hold it at rest, and the least-squares torques bent a falling hopper's leg, exit 0 and no word), and warns
    when the torques its bounds allow leave gravity unbalanced (a session-68 tester's bounder: 1.44 N m left, unsaid),
    naming the cause: the bounds, or a posture whose weight is not over its touching points, which no torque holds."""
    robot = load_robot(f"{ROBOTS}/capler.xml")
    task = load_task(f"{ROBOTS}/capler.toml")
    crouch = dataclasses.replace(task, initial=dataclasses.replace(task.initial, q=CROUCH_Q), horizon=Horizon(0.5, 10))
    lifted = dataclasses.replace(crouch, initial=dataclasses.replace(crouch.initial, q=(0.0, CROUCH_Q[1] + 0.1,
                                                                                        *CROUCH_Q[2:])))
    with pytest.raises(InputError, match="none of foot does .the start is in the air"):
        static_controls(build_problem(robot, lifted))
    prob = build_problem(robot, crouch)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        u, _ = static_controls(prob)  # (held within its bounds: no warning)
    u_block = prob.var_blocks["u"][0]
    prob.lbx[u_block], prob.ubx[u_block] = -0.1 * np.abs(u), 0.1 * np.abs(u)
    with pytest.warns(UserWarning, match="does not hold the start at rest: .* N or N m of gravity left unbalanced "
                                         r"\(the torque bounds\)"):
        static_controls(prob)
    # a pitched quadruped on its front foot alone (docs/examples' bounder, the back knee bent to lift the back foot):
    # its weight is not over the foot, which no torque mends (the warning had blamed the bounds, u at 0.26 of 5)
    examples = pathlib.Path(__file__).resolve().parents[1] / "docs" / "examples"
    bounder = load_task(examples / "bounder_stand.toml")
    one_foot = dataclasses.replace(bounder, initial=dataclasses.replace(
        bounder.initial, q=(0.0, 0.3821346, 0.0, 0.3, -0.6, 0.3, -1.0)))
    with pytest.warns(UserWarning, match="gravity left unbalanced .no torque can hold this posture"):
        static_controls(build_problem(load_robot(examples / "bounder.xml"), one_foot))


def test_static_controls_name_both_the_posture_and_the_torque_bounds_when_both_leave_gravity_unbalanced():
    """When a posture whose weight is not over its touching points leaves gravity unbalanced and the torque bounds
    also clip the torques that balance the rest, the warning names both causes: it named the posture alone, so a user
    who moved the robot over its feet would meet the bounds' imbalance only on the next run."""
    examples = pathlib.Path(__file__).resolve().parents[1] / "docs" / "examples"
    bounder = load_task(examples / "bounder_stand.toml")
    one_foot = dataclasses.replace(bounder, initial=dataclasses.replace(
        bounder.initial, q=(0.0, 0.3821346, 0.0, 0.3, -0.6, 0.3, -1.0)))  # (the pitched bounder on its front foot)
    prob = build_problem(load_robot(examples / "bounder.xml"), one_foot)
    with pytest.warns(UserWarning, match="no torque can hold this posture"):
        u, _ = static_controls(prob)
    u_block = prob.var_blocks["u"][0]
    prob.lbx[u_block], prob.ubx[u_block] = -0.1 * np.abs(u), 0.1 * np.abs(u)
    with pytest.warns(UserWarning, match=r"gravity left unbalanced \(no torque can hold this posture on the contact "
                                         r"points touching: its weight is not over them; and the torque bounds\)"):
        static_controls(prob)


def test_a_start_nanometres_above_the_ground_is_guessed_standing():
    """The step guess of a start 5e-9 m up (a height typed to 7 digits: docs/examples' tasks start 4.35e-9 m up) is
    the guess of the same start exactly on the ground, whose gap static_controls counts as touching (ON_PLANE_M): its
    selectors in contact mode (beta = 0) and, with the static torques (SolveOptions.start_controls = static), zero
    acceleration. By the gap's exact sign the guess was in flight (beta = 1): the crouched Capler's standing torques
    bent its free-floating knee at 1491 rad/s^2 and the zero start was a free fall, not the start the docs describe."""
    robot = load_robot(f"{ROBOTS}/capler.xml")
    task = load_task(f"{ROBOTS}/capler.toml")

    def crouched(dz):
        q = (0.0, CROUCH_Q[1] + dz, *CROUCH_Q[2:])
        return build_problem(robot, dataclasses.replace(task, initial=dataclasses.replace(task.initial, q=q),
                                                        horizon=Horizon(0.5, 10)))

    on, up = crouched(0.0), crouched(5e-9)
    system, nq, nv = on.system, on.system.nq, on.system.nv
    u, _ = static_controls(on)
    for controls in (u, np.zeros(system.nu)):
        w_on, w_up = on.builder.guess(on.y0, controls), up.builder.guess(up.y0, controls)
        sigma = on.builder.w_blocks["sigma"]
        np.testing.assert_array_equal(w_up[sigma], w_on[sigma])
        assert w_up[sigma][[s.name == "beta[foot]" for s in system.switches]] == 0.0
    w = up.builder.guess(up.y0, u)
    field = np.asarray(system.fields_fn(up.y0, u), float) @ np.asarray(up.builder.coefficients(w), float).ravel()
    np.testing.assert_allclose(field[nq : nq + nv], 0.0, atol=REST_ACCEL_TOL)


def test_mass_matrix_and_explicit_forms_agree_at_a_point(capler_small):
    """The MASS_MATRIX transcription (default; Capler, N = 10) is the EXPLICIT one with the velocity rows multiplied
    by M(q_{k+1}): at a seeded random point with y_{k+1} != y_k (products consistent, the force variables solving
    their defining rows, contact_forces = 0), step k's dynamics rows are diag(I, M(q_{k+1}), 1) times the explicit
    step's (M from the robot's dynamics, evaluated apart from the NLP), and the objective and every other block are
    equal. Audit: this test only compared the variable counts, and a mass-matrix step that left M out of M (v_{k+1} -
    v_k) passed it (Capler's M is not I, unlike the point mass's 1 kg)."""
    import casadi as ca

    robot, task, mm = capler_small
    ex = build_problem(robot, task, ProblemOptions(step_form=StepForm.EXPLICIT))
    assert mm.options.step_form is StepForm.MASS_MATRIX and mm.builder.nw > ex.builder.nw
    assert "contact_forces" in mm.g_blocks and "contact_forces" not in ex.g_blocks
    rng = np.random.default_rng(8)
    x = rng.uniform(np.maximum(mm.lbx, -1.0), np.minimum(mm.ubx, 1.0))
    Y = x[mm.var_blocks["y"]]
    Y[:, 1] = np.abs(Y[:, 1]) + 0.3  # the base above the ground
    x[mm.var_blocks["y"]] = Y
    sig, th = mm.var_blocks["sigma"], mm.var_blocks["theta"]
    for k in range(mm.N):
        for j, m in enumerate(mm.builder.lifted):
            x[th[k, j]] = np.prod(x[sig[k, list(m)]])
        x[mm.var_blocks["forces"][k]] = mm.builder.forces_at(Y[k], x[mm.var_blocks["u"][k]])
    index = {name: i for i, name in enumerate(mm.var_names)}
    xe = x[[index[name] for name in ex.var_names]]
    p = mm.params(1e3)
    fm, gm = (np.asarray(v, float).ravel() for v in ca.Function("mm", [mm.x, mm.p], [mm.f, mm.g])(x, p))
    fe, ge = (np.asarray(v, float).ravel() for v in ca.Function("ex", [ex.x, ex.p], [ex.f, ex.g])(xe, p))
    np.testing.assert_allclose(gm[mm.g_blocks["contact_forces"].ravel()], 0.0, atol=FORM_TOL)
    nq, ny = robot.nq, mm.system.ny
    Ys = np.vstack([mm.y0, Y])
    assert np.min(np.abs(np.diff(Ys[:, nq:2 * nq], axis=0))) > 1e-4  # every step's velocity moves: M dv matters
    for k in range(mm.N):
        scale = np.eye(ny)
        scale[nq:2 * nq, nq:2 * nq] = np.asarray(mm.system.dyn.mass(Ys[k + 1, :nq]), float)
        assert np.max(np.abs(scale[nq:2 * nq, nq:2 * nq] - np.eye(nq))) > 0.1
        np.testing.assert_allclose(gm[mm.g_blocks["dynamics"][k]], scale @ ge[ex.g_blocks["dynamics"][k]],
                                   rtol=FORM_TOL, atol=FORM_TOL, err_msg=f"step {k}")
    assert fm == pytest.approx(fe, rel=FORM_TOL)
    for name, rows in ex.g_blocks.items():
        if name != "dynamics":
            np.testing.assert_allclose(gm[mm.g_blocks[name].ravel()], ge[rows.ravel()], rtol=FORM_TOL, atol=FORM_TOL,
                                       err_msg=name)


def test_substituted_products_give_the_same_nlp(capler_small):
    """ProblemOptions(lift_products=False) drops the lifted products' variables and lifting rows (4 per
    Capler step; no empty `lifting` block is left in g_blocks), and at a random point (seeded, products consistent)
    the objective and every other constraint block (gates, friction and impact cones included) equal the lifted
    NLP's."""
    import casadi as ca

    robot, task, a = capler_small
    b = build_problem(robot, task, ProblemOptions(lift_products=False))
    n_prod = len(a.builder.lifted)
    assert (a.nx - b.nx, a.ng - b.ng) == (10 * n_prod, 10 * n_prod) and b.var_blocks["theta"].shape == (10, 0)
    rng = np.random.default_rng(2)
    x = rng.uniform(np.maximum(a.lbx, -2.0), np.minimum(a.ubx, 2.0))
    sig, th = a.var_blocks["sigma"], a.var_blocks["theta"]
    for k in range(10):
        for j, m in enumerate(a.builder.lifted):
            x[th[k, j]] = np.prod(x[sig[k, list(m)]])
    index = {name: i for i, name in enumerate(a.var_names)}
    xb = x[[index[name] for name in b.var_names]]
    p = a.params(1e3)
    fa, ga = (np.asarray(v, float).ravel() for v in ca.Function("a", [a.x, a.p], [a.f, a.g])(x, p))
    fb, gb = (np.asarray(v, float).ravel() for v in ca.Function("b", [b.x, b.p], [b.f, b.g])(xb, p))
    np.testing.assert_allclose(fb, fa, rtol=1e-12)
    assert "lifting" not in b.g_blocks  # (an empty (10, 0) block that constraint_violation reported as 0)
    for name, rows in b.g_blocks.items():
        np.testing.assert_allclose(gb[rows.ravel()], ga[a.g_blocks[name].ravel()], rtol=1e-10, atol=1e-10, err_msg=name)
    with pytest.raises(InputError, match="lift_products"):
        ProblemOptions(lift_products="no")


def test_rho_f_scale_multiplies_the_selector_regularizer(capler_small):
    """Problem.params' rho_f_scale s gives the objective f + (s - 1) rho_f ||sigma - sigma*||^2 (the "selectors" part),
    and at s = 1 exactly the task's objective, at a seeded random point."""
    import casadi as ca

    _, _, prob = capler_small
    rng = np.random.default_rng(3)
    x = rng.uniform(np.maximum(prob.lbx, -2.0), np.minimum(prob.ubx, 2.0))
    f = ca.Function("f", [prob.x, prob.p], [prob.f])
    p1, p10 = prob.params(1e3, 1.0), prob.params(1e3, 1.0, rho_f_scale=10.0)
    selectors = float(prob.objective_parts["selectors"](x, p1))
    assert selectors > 0
    assert float(f(x, p10)) == pytest.approx(float(f(x, p1)) + 9.0 * selectors, rel=1e-12)
    parts = sum(float(prob.objective_parts[name](x, p1)) for name in ("control", "selectors"))
    assert float(f(x, prob.params(0.0, 1.0))) == pytest.approx(parts, rel=1e-12)  # rho 0, no soft terminal: no other term


def test_physical_time_adds_speed_and_constraint():
    """horizon.physical_time adds s_k >= 1 per stage and t_N = T."""
    robot = load_robot(f"{ROBOTS}/point_mass.xml")
    task = hop_task(N=5)
    task = dataclasses.replace(task, horizon=Horizon(tau_f=1.0, N=5, physical_time=0.8))
    prob = build_problem(robot, task, ProblemOptions(penalty=Penalty.LINF))
    assert prob.var_blocks["s"].shape == (5, 1) and np.all(prob.lbx[prob.var_blocks["s"]] == 1)
    rows = prob.g_blocks["physical_time"].ravel()
    assert np.all(prob.lbg[rows] == 0.8) and np.all(prob.ubg[rows] == 0.8)
    assert prob.var_blocks["s_c"].shape == (1,) and prob.g_blocks["penalty"].shape == (5, 2 * prob.system.n_sigma)


@pytest.mark.parametrize("discretization", ["implicit_euler", "fesd"])
def test_max_time_speed_is_every_speeds_upper_bound(discretization):
    """horizon.max_time_speed is the upper bound (ubx) of every s_k, and without it s_k is unbounded above as before
    (point-mass hop, N = 5, T = 0.8; the implicit Euler and the FESD builds). Unbounded, the clock's catch-up went
    into a few steps 6-9 h long (a drop failed MuJoCo's validation for it; session 70's tester)."""
    from planner.discretization import Discretization, FESDOptions

    robot = load_robot(f"{ROBOTS}/point_mass.xml")
    options = (ProblemOptions() if discretization == "implicit_euler"
               else ProblemOptions(discretization=Discretization.FESD, fesd=FESDOptions(n_s=1, n_fe=2)))
    for cap, upper in ((None, np.inf), (1.5, 1.5)):
        horizon = Horizon(tau_f=1.0, N=5, physical_time=0.8, max_time_speed=cap)
        task = dataclasses.replace(hop_task(N=5), horizon=horizon)
        prob = build_problem(robot, task, options)
        s = prob.var_blocks["s"].ravel()
        assert s.shape == (5,) and np.all(prob.lbx[s] == 1.0) and np.all(prob.ubx[s] == upper), cap


def test_physical_time_rows_scale_the_step_by_the_speed_and_pin_the_clock():
    """With horizon.physical_time (point-mass hop, N = 5, T = 0.8, EXPLICIT steps) step k's dynamics rows are
    y_{k+1} - y_k - h s_k F(y_{k+1}, sigma_k, u_k), the speed of time s_k times the unlifted field F (the system's
    vector_field, evaluated apart from the NLP), and the physical_time row is y_N's clock (its last entry), at a seeded
    random point with s_k in [1, 3]. Audit: a step built with speed 1 (s_k in no row) and a row pinning y_N's v_z
    instead of its clock both passed the suite, whose test read the bounds only."""
    import casadi as ca

    robot = load_robot(f"{ROBOTS}/point_mass.xml")
    task = dataclasses.replace(hop_task(N=5), horizon=Horizon(tau_f=1.0, N=5, physical_time=0.8))
    prob = build_problem(robot, task, ProblemOptions(step_form=StepForm.EXPLICIT))
    system, builder = prob.system, prob.builder
    rng = np.random.default_rng(9)
    x = rng.uniform(np.maximum(prob.lbx, -2.0), np.minimum(prob.ubx, 2.0))
    S = rng.uniform(1.0, 3.0, size=prob.N)
    x[prob.var_blocks["s"].ravel()] = S
    sig, th = prob.var_blocks["sigma"], prob.var_blocks["theta"]
    for k in range(prob.N):
        for j, m in enumerate(builder.lifted):
            x[th[k, j]] = np.prod(x[sig[k, list(m)]])
    g = np.asarray(ca.Function("g", [prob.x, prob.p], [prob.g])(x, prob.params(1.0)), float).ravel()
    Y = np.vstack([prob.y0, x[prob.var_blocks["y"]]])
    assert np.min(np.abs(Y[-1, -1] - Y[-1, :-1])) > 0.05  # the clock differs from every other entry of y_N
    for k in range(prob.N):
        u = x[prob.var_blocks["u"][k]]
        field = np.asarray(system.vector_field(x[sig[k]], Y[k + 1], u), float).ravel()
        assert np.linalg.norm(field) > 1.0
        np.testing.assert_allclose(g[prob.g_blocks["dynamics"][k]], Y[k + 1] - Y[k] - prob.h * S[k] * field,
                                   rtol=FORM_TOL, atol=FORM_TOL, err_msg=f"step {k}")
    assert system.state_names[-1] == "t"
    np.testing.assert_array_equal(g[prob.g_blocks["physical_time"].ravel()], [Y[-1, -1]])


@pytest.mark.parametrize("discretization", ["implicit_euler", "fesd"])
def test_physical_time_charges_each_control_for_its_steps_length(discretization):
    """With horizon.physical_time step k lasts h s_k, so its control costs h s_k u_k^T u_k: the objective's control
    part at a seeded random point with s_k in [1, 3] equals that sum in NumPy (point-mass hop, N = 5, T = 0.8; the
    implicit Euler and the FESD builds). Charged h u_k^T u_k, a push was cheaper in a sped-up step, plans put theirs
    there and the reported control_cost understated the effort 1.2-2.8 times (session 70's tester)."""
    from planner.discretization import Discretization, FESDOptions

    robot = load_robot(f"{ROBOTS}/point_mass.xml")
    task = dataclasses.replace(hop_task(N=5), horizon=Horizon(tau_f=1.0, N=5, physical_time=0.8))
    options = (ProblemOptions() if discretization == "implicit_euler"
               else ProblemOptions(discretization=Discretization.FESD, fesd=FESDOptions(n_s=1, n_fe=2)))
    prob = build_problem(robot, task, options)
    rng = np.random.default_rng(4)
    x = rng.uniform(np.maximum(prob.lbx, -2.0), np.minimum(prob.ubx, 2.0))
    S = rng.uniform(1.0, 3.0, size=prob.N)
    x[prob.var_blocks["s"].ravel()] = S
    U = x[prob.var_blocks["u"]]
    control = float(prob.objective_parts["control"](x, prob.params(0.0, 1.0)))
    assert control == pytest.approx(prob.h * np.sum(S * np.sum(U ** 2, axis=1)), rel=SUM_ROUNDING_REL)


def test_physical_time_plan_ends_its_clock_at_T():
    """A physical_time plan's clock ends at T: the point-mass hop (N = 20, T = 0.9 s of tau_f = 1 s; a solve of about
    1.5 s) converges with y_N's clock and the trajectory's last time at 0.9 s, every speed s_k >= 1 and every step's
    clock advancing by h s_k R_k (R_k the ODE field's coefficient at its selectors). Audit: with the terminal row on
    another state than the clock, or the steps built with speed 1, the suite passed."""
    from planner.homotopy import solve

    robot = load_robot(f"{ROBOTS}/point_mass.xml")
    task = dataclasses.replace(hop_task(N=20), horizon=Horizon(tau_f=1.0, N=20, physical_time=0.9))
    prob = build_problem(robot, task)
    res = solve(prob)
    assert res.stats.converged, res.stats.message
    parts = prob.split(res.nlp_point(prob))
    Y, W, S = parts["Y"], parts["W"], parts["S"]
    assert Y[-1, -1] == pytest.approx(0.9, abs=SOLVED_TOL)
    assert res.trajectory.t[-1] == pytest.approx(0.9, abs=SOLVED_TOL)
    assert np.all(S >= 1.0 - SOLVED_TOL)
    assert prob.system.fields[0].name == "ode"
    rate = np.array([prob.builder.coefficients(w)[0] for w in W])
    np.testing.assert_allclose(np.diff(Y[:, -1]), prob.h * S * rate, atol=SOLVED_TOL)


def test_switch_scale_divides_the_named_switching_function():
    """ProblemOptions.switch_scale (("phi", 100),) divides phi, gamma's switching function, in its stationarity rows
    and no other: at a seeded random point (point-mass hop, N = 3), (row + lambda1 - lambda0) of gamma is the unscaled
    problem's divided by 100, every other row is the unscaled problem's, and gamma's pairs are reported times 100 (the
    unscaled units). Audit: the stationarity rows built without the division left every test green."""
    import casadi as ca

    robot = load_robot(f"{ROBOTS}/point_mass.xml")
    plain = build_problem(robot, hop_task(N=3))
    scaled = build_problem(robot, hop_task(N=3), ProblemOptions(switch_scale=(("phi", 100.0),)))
    assert plain.var_names == scaled.var_names
    names = [sw.name for sw in plain.system.switches]
    i = [sw.function for sw in plain.system.switches].index("phi")
    assert names[i] == "gamma[point]"
    x = np.random.default_rng(10).uniform(np.maximum(plain.lbx, -2.0), np.minimum(plain.ubx, 2.0))
    g0, g1 = (np.asarray(ca.Function("g", [pr.x, pr.p], [pr.g])(x, pr.params(1.0)), float).ravel()
              for pr in (plain, scaled))
    rows = plain.g_blocks["stationarity"]
    lam = x[plain.var_blocks["lambda1"]] - x[plain.var_blocks["lambda0"]]  # (N, n_sigma)
    hval = g0[rows] + lam  # the unscaled switching functions
    assert np.all(np.abs(hval[:, i]) > 0.01)  # the scale shows in every row
    np.testing.assert_allclose(g1[rows][:, i] + lam[:, i], hval[:, i] / 100.0, rtol=FORM_TOL)
    others = np.delete(np.arange(len(names)), i)
    np.testing.assert_array_equal(g1[rows][:, others], g0[rows][:, others])
    for name in set(plain.g_blocks) - {"stationarity"}:
        np.testing.assert_array_equal(g1[scaled.g_blocks[name].ravel()], g0[plain.g_blocks[name].ravel()], err_msg=name)
    np.testing.assert_allclose(np.asarray(scaled.products(x), float).ravel(),
                               np.asarray(plain.products(x), float).ravel() * scaled.pair_scale, rtol=1e-15)
    assert sorted(set(scaled.pair_scale)) == [1.0, 100.0]
    assert all((s == 100.0) == (f"[{names[i]}]" in pair.name) for s, pair in zip(scaled.pair_scale, scaled.pairs))


def test_target_v_is_the_terminal_velocity():
    """plan.target_v = (0.3, 0) m/s (point mass): the terminal rows pin y_N's (q, v) to (target_q, target_v), so the
    v_x row's bounds are exactly 0.3 (an omitted target_v means zeros; a target_v read and dropped ends every plan at
    rest, silently), and the row evaluates y_N's velocity; built without the velocity rows, a target_v is an
    InputError."""
    import casadi as ca

    robot = load_robot(f"{ROBOTS}/point_mass.xml")
    task = hop_task(N=3)
    task = dataclasses.replace(task, plan=dataclasses.replace(task.plan, target_v=(0.3, 0.0)))
    prob = build_problem(robot, task)
    rows = prob.g_blocks["terminal"].ravel()
    assert rows.shape == (2 * robot.nq,)
    np.testing.assert_array_equal(prob.lbg[rows], [0.5, 0.0, 0.3, 0.0])
    np.testing.assert_array_equal(prob.ubg[rows], [0.5, 0.0, 0.3, 0.0])
    x = np.random.default_rng(4).normal(size=prob.nx)
    g = np.asarray(ca.Function("g", [prob.x, prob.p], [prob.g[rows.tolist()]])(x, prob.params(1.0)), float).ravel()
    np.testing.assert_array_equal(g, x[prob.var_blocks["y"][-1, : 2 * robot.nq]])
    # without the velocity rows a given target_v is refused (it was dropped unsaid: the q rows only)
    with pytest.raises(InputError, match=r"plan.target_v = \[0.3, 0.0\] needs the terminal velocity rows"):
        build_problem(robot, task, ProblemOptions(terminal_velocity=False))


def test_control_cost_is_h_times_the_sum_of_squared_controls():
    """Objective part "control" = h sum_k |u_k|^2 (the rectangle rule for int |u|^2 dtau), at a seeded random x with
    h = tau_f / N = 0.2 s: without the factor h the control effort would weigh 1/h times more against the selector
    regularizer, and change with N."""
    robot = load_robot(f"{ROBOTS}/point_mass.xml")
    prob = build_problem(robot, hop_task(N=5))
    assert prob.h == pytest.approx(0.2, rel=1e-15)
    x = np.random.default_rng(5).normal(size=prob.nx)
    U = x[prob.var_blocks["u"]]
    assert U.shape == (5, robot.nu)
    control = float(prob.objective_parts["control"](x, prob.params(1.0)))
    assert control == pytest.approx(prob.h * float(np.sum(U**2)), rel=SUM_ROUNDING_REL)


def test_bad_inputs():
    """A task without [plan], an unknown or malformed switch-scale entry, a wrong enum, a value of the wrong type are
    InputErrors naming the field."""
    robot = load_robot(f"{ROBOTS}/point_mass.xml")
    no_plan = load_task(f"{ROBOTS}/point_mass.toml")
    with pytest.raises(InputError, match="no \\[plan\\]"):
        build_problem(robot, no_plan)
    with pytest.raises(InputError, match="switch_scale"):
        build_problem(robot, hop_task(N=3), ProblemOptions(switch_scale=(("psi", 2.0),)))
    # not pairs of (name, finite scale > 0), or a name twice: ValueErrors and TypeErrors, or the last silently won
    for bad in ((("phi", -1.0),), (("phi",),), {"phi": 2.0}, "phi", None, (("phi", "2"),), ("ab",), (("phi", math.inf),),
                (("phi", True),), (("phi", 1.0), ("phi", 2.0))):
        with pytest.raises(InputError, match="ProblemOptions.switch_scale"):
            ProblemOptions(switch_scale=bad)
    for scale in (np.int64(2), np.float32(2.0)):  # a notebook's numbers (refused as "not a finite scale > 0")
        assert ProblemOptions(switch_scale=(("phi", scale),)).switch_scale == (("phi", 2.0),)
    as_list = ProblemOptions(switch_scale=[("phi", 2)])  # stored as the tuple form: equal and hashable
    assert as_list == ProblemOptions(switch_scale=(("phi", 2.0),)) and hash(as_list) == hash(ProblemOptions(switch_scale=(("phi", 2.0),)))
    with pytest.raises(InputError, match=r"ProblemOptions.penalty = 'l2' is not allowed; it must be one of "
                                         r"\['linf', 'l1'\]"):
        ProblemOptions(penalty="l2")
    with pytest.raises(InputError, match="ProblemOptions.clock_weight = 'x' is not allowed; it must be a finite number"):
        ProblemOptions(clock_weight="x")
    with pytest.raises(InputError, match="ProblemOptions.friction_cone = 1 is not allowed; it must be true or false"):
        ProblemOptions(friction_cone=1)


def test_impact_cone_only_where_a_t_is_within_mu_a_n():
    """ProblemOptions.impact_cone: two rows per step (mu a_n P_an -+ a_t P_at >= 0) for a no-slip contact
    with a_t <= mu a_n; none with the paper's a_t = 600 > mu a_n, nor when switched off. At a frozen
    impact (P_an = 1, P_at = 1 - 2 zeta) the rows are mu a_n -+ a_t (1 - 2 zeta)."""
    import casadi as ca

    robot = load_robot(f"{ROBOTS}/point_mass.xml")
    coulomb = {"contacts": [{"point": "point", "mu": 0.5, "a_n": 200.0, "a_t": 100.0}], "initial": {"q": [0.0, 0.0]},
               "horizon": {"tau_f": 1.0, "N": 5}, "plan": {"target_q": [0.5, 0.0], "u_bound": 30.0}}
    prob = build_problem(robot, parse_task(coulomb))
    assert prob.g_blocks["impact_cone"].shape == (5, 2)
    assert "impact_cone" not in build_problem(robot, hop_task(N=5)).g_blocks  # a_t = 600 > mu a_n = 100
    assert "impact_cone" not in build_problem(robot, parse_task(coulomb), ProblemOptions(impact_cone=False)).g_blocks
    # a frozen impact step sliding forward (zeta = 0: the a_t field at full strength) sits on the cone's edge
    rows = prob.g_blocks["impact_cone"][0]
    g = ca.Function("g", [prob.x, prob.p], [prob.g[rows.tolist()]])
    x = prob.x0.copy()
    sig = dict(zip([s.name for s in prob.system.switches], prob.var_blocks["sigma"][0]))
    x[sig["alpha[point]"]], x[sig["beta[point]"]], x[sig["gamma[point]"]], x[sig["zeta[point]"]] = 0.0, 0.0, 0.0, 0.0
    x[prob.var_blocks["w"][0]] = prob.builder.w_from(x[prob.var_blocks["sigma"][0]], np.zeros(len(sig)), np.zeros(len(sig)))
    assert np.allclose(np.asarray(g(x, prob.params(1.0))).ravel(), [0.5 * 200 - 100, 0.5 * 200 + 100])


def test_a_t_below_mu_a_n_warns_of_sliding_below_coulomb():
    """With a_t < mu a_n the impact cone lets a plan slide on the ground braked at a_t / a_n of its normal force, less
    than mu (a hop task with a_n = 200, a_t = 50, mu = 0.5 slid 0.5 m where Coulomb friction lets it slide 0.07 m, and
    MuJoCo's tracking passed it): the build warns, naming the ratio, with any count of contacts and without the impact
    cone too; a_t = mu a_n (Coulomb) builds without a word."""
    import warnings

    robot = load_robot(f"{ROBOTS}/point_mass.xml")
    task = {"contacts": [{"point": "point", "mu": 0.5, "a_n": 200.0, "a_t": 50.0}], "initial": {"q": [0.0, 0.0]},
            "horizon": {"tau_f": 1.0, "N": 3}, "plan": {"target_q": [0.5, 0.0], "u_bound": 30.0}}
    slow = r"contact point: a_t = 50 < mu a_n = 100, so a plan may slide along the ground braked at a_t / a_n = 0.25"
    with pytest.warns(UserWarning, match=slow + r" of its normal force, less than mu = 0.5"):
        build_problem(robot, parse_task(task))
    # without the impact cone, and beside another contact (a wall), as well (a box's two corners were not warned of)
    with pytest.warns(UserWarning, match=slow):
        build_problem(robot, parse_task(task), ProblemOptions(impact_cone=False))
    walled = {**task, "contacts": task["contacts"] + [{"point": "point", "normal": [1.0, 0.0, 0.0]}]}
    with pytest.warns(UserWarning, match=slow):
        build_problem(robot, parse_task(walled))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for mu, a_t in ((0.5, 100.0), (0.07, 14.0)):  # 0.07 * 200 is 14.000000000000002: a_t = mu a_n to rounding
            task["contacts"][0].update(mu=mu, a_t=a_t)
            build_problem(robot, parse_task(task))


def test_an_a_n_far_from_the_robots_weight_warns(robot_variant):
    """An a_n far from the robot's weight m g warns, naming the keys and docs/tasks.md's "Robots of other sizes": a 1 g
    point mass at the default a_n = 200 (2e4 m g) planned its landings with none recorded, a 1000 kg one (0.02 m g)
    failed; the shipped point mass (1 kg, 20 m g) and a 1000 kg one with a_n scaled along build without a word."""
    text = (ROBOTS / "point_mass.xml").read_text()
    task = {"contacts": [{"point": "point", "mu": 0.5, "a_n": 200.0, "a_t": 600.0}], "initial": {"q": [0.0, 0.0]},
            "horizon": {"tau_f": 1.0, "N": 3}, "plan": {"target_q": [0.5, 0.0], "u_bound": 30.0}}
    far = "contact point: a_n = 200 N is {} times the robot's weight m g = {} N, outside [0.05, 1000]: scale a_n"
    for mass, ratio, weight in (("1e-3", "2.04e+04", "0.00981"), ("1e3", "0.0204", "9.81e+03")):
        robot = robot_variant(text, 'mass="1"', f'mass="{mass}"', name=f"m{mass}.xml")
        with pytest.warns(UserWarning, match=re.escape(far.format(ratio, weight)) + r".*Robots of other sizes"):
            build_problem(robot, parse_task(task))
    heavy = robot_variant(text, 'mass="1"', 'mass="1e3"', name="heavy.xml")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        build_problem(load_robot(f"{ROBOTS}/point_mass.xml"), parse_task(task))
        task["contacts"][0].update(a_n=2e5, a_t=6e5)
        build_problem(heavy, parse_task(task))


def test_one_step_to_a_target_away_from_the_start_is_refused():
    """horizon.N = 1 with a target away from the start and the end at rest has no plan (the one implicit Euler
    step's q_1 - q_0 = h s v_1 is zero at v_1 = 0): an InputError says so before the solve, which ran 16 NLPs into
    "out of reach" with CasADi's "overconstrained" warnings; one step that can have a plan (to the start itself, or
    with a target_v along the way, or FESD's stages) builds."""
    from planner.discretization import Discretization

    robot = load_robot(f"{ROBOTS}/point_mass.xml")
    with pytest.raises(InputError, match=r"^horizon.N = 1 \(or --steps 1\) cannot reach plan.target_q away from "):
        build_problem(robot, hop_task(N=1))
    plan = hop_task(N=1).plan
    for changed in (dict(target_q=(0.0, 0.0)), dict(target_v=(0.5, 0.0))):
        build_problem(robot, dataclasses.replace(hop_task(N=1), plan=dataclasses.replace(plan, **changed)))
    build_problem(robot, hop_task(N=1), ProblemOptions(discretization=Discretization.FESD))


def test_velocity_bounds_rows_are_the_joint_rate_sums():
    """plan.velocity_bounds: one row per bound at y_1 .. y_N (block velocity_bounds (N, m)) and, for a
    periodic plan whose y_0 is free, at y_0 (velocity_bounds_y0 (1, m)); each row is the sum of the
    named joints' velocities, bounded by the task's lower and upper. With FESD the rows sit at every
    element boundary (N, n_fe m). Checked at a seeded random point."""
    import casadi as ca

    from planner.discretization import Discretization, FESDOptions

    robot = load_robot(f"{ROBOTS}/biped.xml")
    task = load_task(f"{ROBOTS}/biped.toml")
    plan = dataclasses.replace(task.plan, velocity_bounds=(VelocityBound(("torso", "hinge_1"), lower=0.3),
                                                           VelocityBound(("x",), lower=-1.0, upper=2.0)))
    task = dataclasses.replace(task, horizon=Horizon(tau_f=0.12, N=4), plan=plan)
    prob = build_problem(robot, task)
    assert prob.g_blocks["velocity_bounds"].shape == (4, 2) and prob.g_blocks["velocity_bounds_y0"].shape == (1, 2)
    x = np.random.default_rng(7).normal(size=prob.nx)
    g = np.asarray(ca.Function("g", [prob.x, prob.p], [prob.g])(x, prob.params(1.0)), float).ravel()
    nq = robot.nq
    V = np.vstack([x[prob.var_blocks["y0"]][None, nq:2 * nq], x[prob.var_blocks["y"]][:, nq:2 * nq]])
    expect = np.column_stack([V[:, 2] + V[:, 3], V[:, 0]])  # torso + hinge_1, x
    rows = np.vstack([prob.g_blocks["velocity_bounds_y0"], prob.g_blocks["velocity_bounds"]])
    np.testing.assert_allclose(g[rows], expect, rtol=1e-15, atol=0)
    np.testing.assert_array_equal(prob.lbg[rows], np.tile([0.3, -1.0], (5, 1)))
    np.testing.assert_array_equal(prob.ubg[rows], np.tile([np.inf, 2.0], (5, 1)))
    fesd = build_problem(robot, task, ProblemOptions(discretization=Discretization.FESD, fesd=FESDOptions(n_s=1, n_fe=2)))
    assert fesd.g_blocks["velocity_bounds"].shape == (4, 4) and fesd.g_blocks["velocity_bounds_y0"].shape == (1, 2)
    # a periodic plan has no terminal velocity rows to drop (built alike, with another signature: a start refused)
    with pytest.raises(InputError, match=r"terminal_velocity=False\) drops the terminal velocity rows, which a "):
        build_problem(robot, task, ProblemOptions(terminal_velocity=False))


def test_an_end_velocity_outside_the_velocity_bounds_is_an_input_error():
    """The velocity bounds hold at the last node, where v_N = target_v (zeros when omitted): a bound that excludes it
    leaves no plan (IPOPT ended "infeasible" after the whole homotopy, naming the terminal row). An InputError names
    the bound and the velocity; target_v inside it, or terminal_velocity off, builds."""
    robot, task = load_robot("point_mass"), hop_task(N=5)
    bounded = dataclasses.replace(task.plan, velocity_bounds=(VelocityBound(("x",), lower=0.1),))
    with pytest.raises(InputError, match=r"plan.velocity_bounds\[0\] = \[0.1, inf\] excludes the end velocity, 0 by "
                                         r"plan.target_v \(omitted: zeros\)"):
        build_problem(robot, dataclasses.replace(task, plan=bounded))
    build_problem(robot, dataclasses.replace(task, plan=dataclasses.replace(bounded, target_v=(0.5, 0.0))))
    build_problem(robot, dataclasses.replace(task, plan=bounded), ProblemOptions(terminal_velocity=False))


def test_a_urdf_joint_speed_limit_bounds_that_joint_at_every_node(capler_small, tmp_path):
    """A URDF joint's <limit velocity> is the plan's: the velocity of each limited joint at y_1 .. y_N (and at every
    FESD stage) is bounded by it (a leg's knee limited to 5 rad/s was planned at 14.5, the limit read and dropped);
    velocity="0", as CAD exporters write an unknown limit, and an MJCF file give none; a target_v beyond a limit is an
    InputError."""
    from planner.discretization import Discretization, FESDOptions

    _, task, mjcf = capler_small
    source = (pathlib.Path(ROBOTS) / "capler.urdf").read_text()
    assert source.count('velocity="0"') == 4  # x, z, hip, knee in file order: none (capler.xml has none either)
    urdf = tmp_path / "capler.urdf"
    urdf.write_text(source.replace('velocity="0"', 'velocity="100"').replace('velocity="100"', 'velocity="0"', 2)
                    .replace('velocity="100"', 'velocity="5"', 1))
    robot = load_robot(urdf)
    limit = [np.inf, np.inf, 5.0, 100.0]
    np.testing.assert_array_equal(robot.v_limit, limit)
    nq = robot.nq
    fesd = ProblemOptions(discretization=Discretization.FESD, fesd=FESDOptions(n_s=1, n_fe=2))
    for options in (ProblemOptions(), fesd):
        prob = build_problem(robot, task, options)
        speeds = prob.var_blocks["Y" if "Y" in prob.var_blocks else "y"][..., nq:2 * nq].reshape(-1, nq)
        assert len(speeds) == 10 * (2 if "Y" in prob.var_blocks else 1)
        np.testing.assert_array_equal(prob.ubx[speeds], np.tile(limit, (len(speeds), 1)))
        np.testing.assert_array_equal(prob.lbx[speeds], -prob.ubx[speeds])
    for twin in (mjcf, build_problem(load_robot(pathlib.Path(ROBOTS) / "capler.urdf"), task)):  # the shipped files
        assert np.all(np.isinf(twin.ubx[twin.var_blocks["y"][:, nq:2 * nq]]))
    fast = dataclasses.replace(task.plan, target_v=(0.0, 0.0, 6.0, 0.0))
    with pytest.raises(InputError, match=r"joint speed limit \(<limit velocity>\) of hip \(6 beyond 5\)"):
        build_problem(robot, dataclasses.replace(task, plan=fast))


@pytest.mark.parametrize("discretization", ["implicit_euler", "fesd"])
def test_a_target_inside_a_hole_is_an_input_error(capler_small, discretization):
    """A task whose target puts a contact point inside a hole (Capler's base at x = 2.6 m stands the foot in the
    third hole, 2.25 .. 2.75 m) has no plan: build_problem says which point and hole. A target on the hole's rim
    (x = 2.75 m) is outside and builds, and one 10 nm inside it is refused with digits and the ellipse metric that show
    it inside. A start inside a hole is refused the same way."""
    from planner.discretization import Discretization

    robot, task, _ = capler_small
    options = ProblemOptions(discretization=Discretization(discretization))

    def at(x: float):
        return dataclasses.replace(task, plan=dataclasses.replace(task.plan, target_q=(x,) + task.plan.target_q[1:]))

    with pytest.raises(InputError, match=r"plan.target_q puts contact point 'foot' .* inside plan.holes\[2\]"):
        build_problem(robot, at(2.6), options)
    build_problem(robot, at(2.75), options)
    # 10 nm inside the rim: the message's digits show it inside (x = 2.75, the rim itself, was printed)
    with pytest.raises(InputError, match=r"at x = 2\.74999999, z = 0 m, inside plan.holes\[2\] .*ellipse metric "
                                         r"0\.99999992 < 1\)"):
        build_problem(robot, at(2.75 - 1e-8), options)
    # a start standing in a hole likewise (the holes' rows start at node 1: it was planned, and validated)
    hole = dataclasses.replace(task.plan.holes[0], x=0.0)
    start_in_hole = dataclasses.replace(task, plan=dataclasses.replace(task.plan, holes=(hole,) + task.plan.holes[1:]))
    with pytest.raises(InputError, match=r"^initial.q puts contact point 'foot' .* inside plan.holes\[0\] .*no plan can "
                                         r"start there: move the start or the hole"):
        build_problem(robot, start_in_hole, options)


@pytest.mark.parametrize("discretization", ["implicit_euler", "fesd"])
def test_a_target_below_the_ground_is_an_input_error(discretization):
    """A target that puts a contact point below the ground (the point mass at z = -1 m) or behind a wall has no plan,
    as an initial state there has none: build_problem says which point, by how much, behind which plane (it
    built, and the solve failed) and how far in is allowed."""
    from planner.discretization import Discretization

    def hop(target_z: float):
        return parse_task({"contacts": [{"point": "point", "mu": 0.5}], "initial": {"q": [0.0, 0.0]},
                           "horizon": {"tau_f": 1.0, "N": 4}, "plan": {"target_q": [0.5, target_z], "u_bound": 30.0}})

    robot, options = load_robot(f"{ROBOTS}/point_mass.xml"), ProblemOptions(discretization=Discretization(discretization))
    # the allowance said with the fix (session 56's tester: a start typed to 6 digits was refused 2.4e-7 m in, no hint)
    with pytest.raises(InputError, match=r"plan.target_q puts contact point 'point' 1 m below the ground \(z = 0\); "
                                         r"move it out by that much \(up to 1e-09 m in is allowed\)"):
        build_problem(robot, hop(-1.0), options)
    build_problem(robot, hop(0.0), options)
    # rounded up at 10 decimals, the float error of 0.07 not taken for depth, 1e300 m printed whole (ceil overflowed)
    assert (shown_up(0.07), shown_up(1e300), shown_up(1.0 / 3.0)) == ("0.07", "1.0000000000000001e+300", "0.3333333334")
    with warnings.catch_warnings():  # a numpy depth of 1e300 m: printed whole, without numpy's overflow warning
        warnings.simplefilter("error")
        assert shown_up(np.float64(1e300)) == "1.0000000000000001e+300"
    for z in (-1.0 / 3.0, -12.345678901234):  # the depth printed, added back, builds (6 digits did not, nor 10 at 12 m)
        with pytest.raises(InputError) as refused:
            build_problem(robot, hop(z), options)
        depth = float(re.search(r"'point' (\S+) m below", str(refused.value)).group(1))
        build_problem(robot, hop(z + depth), options)
    walled = parse_task({"contacts": [{"point": "point", "mu": 0.5}, {"point": "point", "normal": [-1.0, 0.0, 0.0]}],
                         "initial": {"q": [-0.5, 0.0]}, "horizon": {"tau_f": 1.0, "N": 4},
                         "plan": {"target_q": [0.5, 0.0], "u_bound": 30.0}})
    with pytest.raises(InputError, match=r"target_q puts contact point 'point' 0.5 m behind its plane \(normal \(-1, 0, 0\)"):
        build_problem(robot, walled, options)  # it said "below the ground" of a point on the ground, behind a wall


def test_a_start_or_target_with_an_above_ground_point_in_the_ground_is_an_input_error():
    """plan.above_ground points (Capler's knee, base) are held above the ground from node 1 on: a start or target that
    puts one in the ground has no plan, as for a contact point. Session 57's tester: a start with the knee 4 cm in the
    ground was planned and converged (exit 0), a target there failed after 105 s as "locally infeasible"."""
    robot = load_robot(f"{ROBOTS}/capler.xml")
    task = load_task(f"{ROBOTS}/capler.toml")
    knee_in = [0.0, 0.05, 1.1, 1.5]  # the foot 0.13 m up, the knee 0.041 m down
    for key, plan, initial in (("initial.q", task.plan, dataclasses.replace(task.initial, q=tuple(knee_in))),
                               ("plan.target_q", dataclasses.replace(task.plan, target_q=tuple(knee_in)),
                                task.initial)):
        with pytest.raises(InputError, match=rf"^{key} puts point 'knee' 0.04\d* m below the ground "
                                             r"\(plan.above_ground holds it above\); move it up by that much"):
            build_problem(robot, dataclasses.replace(task, plan=plan, initial=initial), ProblemOptions())


def test_a_corner_plan_builds_with_each_contacts_own_gates():
    """A point listed twice with two normals (a corner: the ground and a wall) builds an OCP whose pairs carry
    both contacts' labels (point#1, point#2); the gates look each selector's contact up by that label (they looked
    up the point's name and raised ValueError)."""
    task = parse_task({"contacts": [{"point": "point", "mu": 0.5}, {"point": "point", "normal": [1.0, 0.0, 0.0]}],
                       "initial": {"q": [0.1, 0.0]}, "horizon": {"tau_f": 1.0, "N": 10},
                       "plan": {"target_q": [0.5, 0.0], "u_bound": 30.0}})
    prob = build_problem(load_robot(f"{ROBOTS}/point_mass.xml"), task)
    for label in ("point#1", "point#2"):
        assert any(f"[alpha[{label}]]" in pair.name for pair in prob.pairs)


@pytest.mark.parametrize("mu", [0.0, 0.5])
def test_an_elastic_contact_is_refused_naming_the_simulator(mu):
    """A plan with an elastic contact (restitution > 0) is refused whatever its friction, with a message that names
    the contact, restitution = 0 and `planner simulate` (which models frictionless elastic impacts): with mu > 0
    the time-freezing system refused first and said "set mu = 0", after which the plan was refused again for the
    restitution."""
    task = parse_task({"contacts": [{"point": "point", "mu": mu, "restitution": 0.5}], "initial": {"q": [0.0, 0.0]},
                       "horizon": {"tau_f": 1.0, "N": 3}, "plan": {"target_q": [0.5, 0.0], "u_bound": 30.0}})
    with pytest.raises(InputError, match=r"^contact\(s\) point: planning with elastic contacts .*set restitution = 0 "
                                         r"\(`planner simulate` models frictionless elastic impacts\)") as err:
        build_problem(load_robot(f"{ROBOTS}/point_mass.xml"), task)
    assert "mu = 0" not in str(err.value)


def test_an_elastic_never_touching_contact_is_refused_as_any(capler_small):
    """restitution > 0 on a touches = false contact is refused as on any contact, with scene analysis on or off (on, it
    dropped the contact first: the restitution accepted and ignored, while off refused it)."""
    robot, task, _ = capler_small
    knee = dataclasses.replace(task.contacts[0], point="knee", touches=False, restitution=0.5, mu=0.7)
    elastic = dataclasses.replace(task, contacts=(*task.contacts, knee))
    for options in (ProblemOptions(), ProblemOptions(scene_analysis=False)):
        with pytest.raises(InputError, match=r"^contact\(s\) knee: planning with elastic contacts"):
            build_problem(robot, elastic, options)


def test_a_periodic_plans_free_start_stays_out_of_the_holes():
    """A periodic plan's start y_0 is a variable: the holes' rows hold it as they hold nodes 1..N (block holes_y0
    (1, 1)), so the point mass whose initial guess stands in a hole starts its plan outside it (it started at metric
    0.36 inside, exit 0, session 58's tester); FESD builds it too (one row at y_0 beside one per element crashed)."""
    from planner.discretization import Discretization, FESDOptions
    from planner.homotopy import SolveOptions, solve

    task = parse_task({"contacts": [{"point": "point", "mu": 0.5}], "initial": {"q": [0.0, 0.12]},
                       "horizon": {"tau_f": 1.0, "N": 20},
                       "plan": {"u_bound": 30.0, "holes": [{"x": 0.0, "a": 0.1, "b": 0.1}], "periodic": {"step": 0.5}}})
    robot = load_robot(f"{ROBOTS}/point_mass.xml")
    prob = build_problem(robot, task)
    assert prob.g_blocks["holes"].shape == (20, 1) and prob.g_blocks["holes_y0"].shape == (1, 1)
    fesd = build_problem(robot, task, ProblemOptions(discretization=Discretization.FESD,
                                                     fesd=FESDOptions(n_s=1, n_fe=2)))
    assert fesd.g_blocks["holes"].shape == (20, 2) and fesd.g_blocks["holes_y0"].shape == (1, 1)
    result = solve(prob, SolveOptions())
    assert result.stats.converged, result.stats.message
    x0, z0 = result.trajectory.q[0]
    assert task.plan.holes[0].metric(x0, z0) >= 1.0 - 1e-6  # outside, up to IPOPT's bound relaxation


def test_a_periodic_guess_in_the_ground_is_refused_as_a_guess():
    """A periodic task's initial.q is the guess of q(0), not a start: a guess 1 cm in the ground, or in a hole, is
    refused with that said (it read as a start, where the joint-bounds message of the same task said it was a
    guess)."""
    robot = load_robot(f"{ROBOTS}/biped.xml")
    task = load_task(f"{ROBOTS}/biped.toml")
    assert task.is_periodic
    q = list(task.initial.q)
    q[1] -= 0.01  # the hip's height [m]
    task = dataclasses.replace(task, initial=dataclasses.replace(task.initial, q=tuple(q)),
                               horizon=Horizon(tau_f=0.12, N=4))
    with pytest.raises(InputError, match=r"^initial.q \(with plan.periodic the initial guess of q\(0\)\) puts contact "
                                         r"point 'foot_\d' 0.01 m below the ground"):
        build_problem(robot, task)
    # the same said of a guess standing in a hole
    from planner.dynamics import Dynamics
    from planner.task import Ellipse

    q[1] += 0.01
    foot = np.asarray(Dynamics(robot).point_position("foot_1")(np.array(q)), float).ravel()
    holed = dataclasses.replace(task, initial=dataclasses.replace(task.initial, q=tuple(q)),
                                plan=dataclasses.replace(task.plan, holes=(Ellipse(x=float(foot[0]), a=0.01, b=0.01),)))
    with pytest.raises(InputError, match=r"^initial.q \(with plan.periodic the initial guess of q\(0\)\) puts contact "
                                         r"point 'foot_1' at x = .* inside plan.holes\[0\]"):
        build_problem(robot, holed)


def test_a_target_moving_into_the_ground_on_it_is_an_input_error():
    """A target on the ground (within 2 mm) whose target_v moves the contact point into it has no plan that ends after
    its impact: build_problem refuses it naming the point, the gap and the speed (the point-mass hop ended inside an
    impact, exit 0; up to 1.2 mm up it failed); 2 mm above the ground the same velocity is planned, without impact,
    and along the ground it builds."""
    def hop(target_z: float, target_v):
        return parse_task({"contacts": [{"point": "point", "mu": 0.5}], "initial": {"q": [0.0, 0.0]},
                           "horizon": {"tau_f": 1.0, "N": 4},
                           "plan": {"target_q": [0.5, target_z], "target_v": target_v, "u_bound": 30.0}})

    robot = load_robot(f"{ROBOTS}/point_mass.xml")
    for z in (0.0, 1e-6, 1.2e-3):  # (1e-6 m up ended inside an impact too, 1e-5 m to 1.2 mm up failed at N = 4)
        with pytest.raises(InputError, match=rf"^plan.target_q puts contact point 'point' {z:.3g} m from its plane "
                                             r"and plan.target_v moves it 1 m/s into it: the plan would end inside "
                                             r"an impact; .* or a target at least 0.002 m from it"):
            build_problem(robot, hop(z, [0.0, -1.0]))
    from planner.homotopy import solve  # 2 mm up the plan ends above the ground, no impact

    res = solve(build_problem(robot, hop(2e-3, [0.0, -2.0])))
    assert res.stats.converged and not res.trajectory.impacts, res.stats.message
    build_problem(robot, hop(0.0, [1.0, 0.0]))


def test_a_built_problem_names_its_edits_and_refuses_changed_inputs():
    """Problem.edited names the bounds, cost and rows changed after build_problem (what solve honours), and
    Problem.check_solvable (solve's and race's first check) refuses what the NLP was built from changed since: a robot,
    a task or options swapped by dataclasses.replace (planned for the old target, written with the new), y0 edited in
    place, new variables, a vector cost or a symbol that is not x or p (the raw CasADi errors came after NLP 1); bounds
    extended with casadi.vertcat, as the rows are, are taken."""
    import casadi as ca

    robot = load_robot(f"{ROBOTS}/point_mass.xml")
    pb = build_problem(robot, hop_task(N=4))
    assert pb.edited == () and pb.check_solvable() is None
    pb.lbx[0] = pb.lbx[0] + 0.0  # the same value: no edit
    ceiling = pb.x[pb.var_blocks["y"][2, 1]]  # z at node 3 [m]
    edited = dataclasses.replace(pb, f=pb.f + ceiling**2, g=ca.vertcat(pb.g, ceiling),
                                 lbg=np.append(pb.lbg, -np.inf), ubg=np.append(pb.ubg, 0.1), ubx=pb.ubx.copy())
    edited.ubx[0] = 1.0
    assert edited.edited == ("f", "g", "ubx", "lbg", "ubg") and pb.edited == ()
    edited.check_solvable()
    # the bounds extended as the rows are, with casadi.vertcat (README's pattern: "object of type 'DM' has no len()")
    dm = dataclasses.replace(edited, lbg=ca.vertcat(pb.lbg, -np.inf), ubg=ca.vertcat(pb.ubg, 0.1))
    assert dm.edited == edited.edited and dm.check_solvable() is None
    moved = dataclasses.replace(pb.task, plan=dataclasses.replace(pb.task.plan, target_q=(0.8, 0.0)))
    with pytest.raises(InputError, match=r"^problem.task changed after build_problem, which built the NLP from them: "
                                         r"build the problem again .*takes edits of f, g, lbx, ubx, lbg, ubg and x0"):
        dataclasses.replace(pb, task=moved).check_solvable()
    with pytest.raises(InputError, match=r"^problem.robot changed"):  # (the 1 kg NLP was written as the other file's)
        dataclasses.replace(pb, robot=load_robot(f"{ROBOTS}/point_mass.xml")).check_solvable()
    with pytest.raises(InputError, match=r"^problem.options changed"):
        dataclasses.replace(pb, options=ProblemOptions(friction_cone=False)).check_solvable()
    shifted = dataclasses.replace(pb, y0=pb.y0.copy())
    shifted.y0[0] = 0.2
    with pytest.raises(InputError, match=r"^problem.y0 changed"):
        shifted.check_solvable()
    with pytest.raises(InputError, match=r"^problem.x, problem.var_names changed"):
        slack = ca.vertcat(pb.x, ca.SX.sym("slack"))
        dataclasses.replace(pb, x=slack, var_names=pb.var_names + ("slack",)).check_solvable()
    with pytest.raises(InputError, match=r"^problem.f must be a scalar expression, got shape \(2, 1\)"):
        dataclasses.replace(pb, f=ca.vertcat(pb.f, pb.f)).check_solvable()
    with pytest.raises(InputError, match=r"uses symbols that are not problem.x or problem.p: a; new variables are not"):
        dataclasses.replace(pb, f=pb.f + ca.SX.sym("a")).check_solvable()
    other = build_problem(robot, hop_task(N=4))  # the same names, other symbols
    with pytest.raises(InputError, match=r"uses symbols that are not problem.x or problem.p: u_0_0; new"):
        dataclasses.replace(pb, f=pb.f + other.x[0] ** 2).check_solvable()


def test_a_bad_g_blocks_entry_is_refused_before_the_solve():
    """solve refuses a problem.g_blocks entry that is not row indices of g (a float, a row past the end, a negative one)
    before IPOPT starts, naming the block and what is allowed: constraint_violation read it only after the whole
    homotopy (40-60 s on Capler) and crashed with an IndexError, or silently reported another row for a negative one.
    A list or range of rows, the obvious "indices", is taken and made an int array."""
    from planner.homotopy import constraint_violation, solve

    pb = build_problem(load_robot(f"{ROBOTS}/point_mass.xml"), hop_task(N=4))
    last = pb.ng - 1
    for rows in (np.array([0.5]), [pb.ng], np.array([-1]), "terminal", [[0], [1, 2]]):
        pb.g_blocks["mine"] = rows
        started = []
        with pytest.raises(InputError, match=rf"^problem.g_blocks\['mine'\] = .* is not allowed; it must be row "
                                             rf"indices of problem.g, integers in 0 \.\. {last} \(a list, range"):
            solve(pb, progress=started.append)
        assert started == [], rows
    for rows in ([last], range(last - 1, last + 1), []):
        pb.g_blocks["mine"] = rows
        pb.check_solvable()
        assert pb.g_blocks["mine"].dtype.kind == "i" and "mine" in constraint_violation(pb, pb.x0)


def test_a_plan_without_contacts_names_its_task(tmp_path):
    """build_problem refuses a task without [[contacts]] naming the task file, as the other task errors do (it named
    none)."""
    path = tmp_path / "free.toml"
    path.write_text('contacts = []\n[initial]\nq = [0.0, 1.0]\n[horizon]\ntau_f = 1.0\nN = 4\n[plan]\n'
                    'target_q = [0.5, 1.0]\n')
    with pytest.raises(InputError, match=rf"^task {re.escape(str(path))} has no \[\[contacts\]\]; the time-freezing"):
        build_problem(load_robot(f"{ROBOTS}/point_mass.xml"), load_task(path))


def test_a_built_problem_pickles_copies_and_has_a_short_repr():
    """A built problem goes through pickle (a multiprocessing worker's argument; CasADi's SX needed its pickle
    context, which no pool opens) and solves there to the same point bit for bit, with its edits still named;
    copy.copy shares the arrays, copy.deepcopy does not; repr leaves out the expressions and per-variable arrays
    (1.4 million characters for Capler)."""
    import copy
    import pickle

    from planner.homotopy import SolveOptions, solve

    problem = build_problem(load_robot(f"{ROBOTS}/point_mass.xml"), hop_task(N=6))
    edited = dataclasses.replace(problem, f=problem.f + 0.01 * problem.x[0] ** 2)
    back = pickle.loads(pickle.dumps(edited))
    assert back.edited == ("f",) and back.var_names == edited.var_names
    back.check_solvable()
    options = SolveOptions(max_iter=300)
    assert np.array_equal(solve(back, options).nlp_point(back), solve(edited, options).nlp_point(edited))
    assert copy.copy(problem).lbx is problem.lbx
    deep = copy.deepcopy(problem)
    assert deep.lbx is not problem.lbx and np.array_equal(deep.lbx, problem.lbx) and deep.edited == ()
    assert len(repr(problem)) < 5000, len(repr(problem))


@pytest.mark.parametrize("form", [StepForm.EXPLICIT, StepForm.MASS_MATRIX])
@pytest.mark.parametrize("fesd", [False, True])
def test_every_row_of_a_step_is_a_row_of_the_nlp(form, fesd):
    """Every equality row a step (or FESD interval) writes is in the NLP, once, in a named block: with several
    contacts the explicit form's constraint-force rows were left out (its contact forces were free, extra actuation
    at the feet) and the stepwise derivatives read unset row indices (session 61's tester)."""
    from planner.discretization import Discretization, FESDOptions

    robot = load_robot(f"{ROBOTS}/biped.xml")
    task = dataclasses.replace(load_task(f"{ROBOTS}/biped.toml"), horizon=Horizon(tau_f=0.1, N=4 if fesd else 5))
    fesd_options = {"discretization": Discretization.FESD, "fesd": FESDOptions(n_s=1, n_fe=2)} if fesd else {}
    options = ProblemOptions(step_form=form, **fesd_options)
    problem = build_problem(robot, task, options)
    assert "contact_forces" in problem.g_blocks
    rows = np.concatenate([np.ravel(r) for r in problem.g_blocks.values()])
    assert len(rows) == len(set(rows.tolist())) == problem.ng  # the blocks partition g
    if not fesd:
        rows = problem.stages.rows
        assert rows.min() >= 0 and len(set(rows.ravel().tolist())) == rows.size


# path rows evaluated by CasADi against the same products in NumPy: rounding of a few products of numbers ~1
PATH_ROW_ROUNDING = 1e-10


def _rows_at(prob, x) -> np.ndarray:
    """The NLP's constraint values g(x) at the default parameters (rho = 1)."""
    import casadi as ca

    return np.asarray(ca.Function("g", [prob.x, prob.p], [prob.g])(x, prob.params(rho=1.0)), float).ravel()


def _capler(**changes):
    """Capler's default task on a two-step grid, with `changes` to the Task; its build warnings (the grid) ignored."""
    task = dataclasses.replace(load_task(ROBOTS / "capler.toml"), horizon=Horizon(tau_f=0.1, N=2), **changes)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return build_problem(load_robot(ROBOTS / "capler.xml"), task), task


def test_above_ground_rows_are_heights_above_the_tasks_ground():
    """plan.above_ground's rows are each point's height above ground_height, z(q) - ground_height, computed here by
    Pinocchio's forward kinematics (session 65's mutation testing: rows that ignore ground_height, which would plan
    the knee below a raised floor, left every test green)."""
    from planner.dynamics import Dynamics

    prob, task = _capler(ground_height=-0.05)
    q0 = prob.y0[:4]
    dyn = Dynamics(load_robot(ROBOTS / "capler.xml"))
    want = [float(dyn.point_position(p)(q0)[2]) + 0.05 for p in task.plan.above_ground]
    rows = _rows_at(prob, prob.x0)[prob.g_blocks["above_ground"]]
    np.testing.assert_allclose(rows, np.tile(want, (prob.N, 1)), atol=PATH_ROW_ROUNDING)


def test_friction_cone_rows_bound_both_directions():
    """The friction cone's two rows per step are w (mu lam_n - lam_t) and w (mu lam_n + lam_t), w the rough field's
    coefficient, at a random point (only their count was checked: session 65's mutation testing made the second a
    copy of the first, which lets the plan push tangentially beyond mu lam_n one way, and every test stayed green)."""
    robot = load_robot(ROBOTS / "point_mass.xml")
    task = parse_task({"contacts": [{"point": "point", "mu": 0.5}], "initial": {"q": [0.0, 0.0]},
                       "horizon": {"tau_f": 0.2, "N": 2}, "plan": {"target_q": [0.1, 0.0], "u_bound": 30.0}})
    prob = build_problem(robot, task)
    x = np.random.default_rng(0).uniform(0.1, 0.9, prob.nx)
    g, b = _rows_at(prob, x), prob.builder
    j = [f.name for f in prob.system.fields].index("dae_f[point]")
    for k in range(prob.N):
        w = x[prob.var_blocks["w"][k]]
        weight, lam = b.coefficients(w)[j], w[b.w_blocks["forces"]][b.mm.lam_index["point"]]
        np.testing.assert_allclose(g[prob.g_blocks["friction_cone"][k]],
                                   [weight * (0.5 * lam[0] - lam[1]), weight * (0.5 * lam[0] + lam[1])],
                                   rtol=PATH_ROW_ROUNDING)


def test_several_contacts_friction_cone_rows_bound_both_directions():
    """With two rough contacts each point's cone rows are R (mu lam_n - lam_t) and R (mu lam_n + lam_t), R the ODE's
    coefficient, at a random point (the several-contact build's rows, as the one-contact test above)."""
    import casadi as ca

    from planner.task import Contact

    capler = load_task(ROBOTS / "capler.toml")
    prob, _ = _capler(contacts=capler.contacts + (Contact("knee", mu=0.5, a_t=600.0),))
    x = np.random.default_rng(3).uniform(0.1, 0.9, prob.nx)
    g, b = _rows_at(prob, x), prob.builder
    for k in range(prob.N):
        w = x[prob.var_blocks["w"][k]]
        R = float(np.asarray(ca.mtimes(ca.DM(b.C), b.monomials_of(w))).ravel()[0])
        want = []
        for label, mu in zip(prob.system.labels, (capler.contacts[0].mu, 0.5)):
            lam = w[b.w_blocks["forces"]][b.mm.lam_index[label]]
            want += [R * (mu * lam[0] - lam[1]), R * (mu * lam[0] + lam[1])]
        np.testing.assert_allclose(g[prob.g_blocks["friction_cone"][k]], want, rtol=PATH_ROW_ROUNDING)


def test_never_touching_rows_are_the_gap_to_a_tilted_plane_through_the_ground():
    """A `touches = false` contact on a tilted plane, with ground_height != 0, is held off by its row c(q), the gap
    contact.contact_terms gives that plane (session 65's mutation testing: ground_height unscaled by the normal's z,
    which keeps the point off a plane shifted by (1 - n_z) ground_height, left every test green)."""
    import casadi as ca

    from planner.contact import contact_terms
    from planner.dynamics import Dynamics
    from planner.task import Contact

    normal = (0.6, 0.0, 0.8)
    capler = load_task(ROBOTS / "capler.toml")
    prob, _ = _capler(ground_height=-0.05, contacts=capler.contacts + (Contact("knee", normal=normal, touches=False),))
    q = ca.SX.sym("q", 4)
    terms = contact_terms(Dynamics(load_robot(ROBOTS / "capler.xml")), "knee", -0.05, q, ca.SX.sym("v", 4),
                          ca.SX.sym("u", 2), surface=normal)
    want = float(ca.Function("gap", [q], [terms.gap])(prob.y0[:4]))
    rows = _rows_at(prob, prob.x0)[prob.g_blocks["never_touching"]].ravel()
    np.testing.assert_allclose(rows, [want] * prob.N, atol=PATH_ROW_ROUNDING)
