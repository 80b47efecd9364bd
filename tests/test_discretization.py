"""The regularized implicit Euler step builder (eq. 24) with lifted selector products (Sec. 5.1)."""
from __future__ import annotations

import functools

import casadi as ca
import numpy as np
import pytest

from planner.discretization import G_BLOCKS, W_BLOCKS, ImplicitEulerStep, StepForm
from planner.errors import InputError
from planner.dynamics import Dynamics
from planner.model import ROBOTS_DIR, load_robot
from planner.task import Contact
from planner.timefreezing import TimeFreezingSystem

EVAL_TOL = 1e-12  # identical expressions evaluated two ways: rounding only


@functools.cache
def system(robot: str = "point_mass", mu: float = 0.0, restitution: float = 0.0) -> TimeFreezingSystem:
    point = {"point_mass": "point", "capler": "foot"}[robot]
    return TimeFreezingSystem(Dynamics(load_robot(robot)), [Contact(point, mu=mu, restitution=restitution)])


def symbols(s: TimeFreezingSystem):
    return ca.SX.sym("yk", s.ny), ca.SX.sym("yn", s.ny), ca.SX.sym("u", s.nu), ca.SX.sym("s")


def test_blocks_names_and_bounds():
    """Frictionless step: sigma (3), lifted products alpha*beta, alpha*gamma, alpha*beta*gamma (3),
    lambda0, lambda1 (3 each); constraints dynamics (ny), stationarity (3), lifting (3); 6 pairs."""
    s = system()
    b = ImplicitEulerStep(s, rho_f=1.0)
    assert b.lifted == ((0, 1), (0, 2), (0, 1, 2))
    yk, yn, u, sp = symbols(s)
    st = b.build(yk, yn, u, sp, 0.01, tag="_3")
    assert tuple(st.w_blocks) == W_BLOCKS and tuple(st.g_blocks) == G_BLOCKS
    assert st.w.shape[0] == 12 and st.g.shape[0] == s.ny + 3 + 3 and len(st.complementarity) == 6
    assert st.w_names[:4] == ("alpha[point]_3", "beta[point]_3", "gamma[point]_3", "alpha[point]*beta[point]_3")
    np.testing.assert_array_equal(st.lbw, 0.0)
    np.testing.assert_array_equal(st.ubw, [1] * 6 + [np.inf] * 6)
    np.testing.assert_allclose(st.w0[:6], [0.5, 0, 0, 0, 0, 0])


@pytest.mark.parametrize("robot,mu,eps", [("point_mass", 0.0, 0.0), ("capler", 0.8, 0.0), ("point_mass", 0.0, 0.5)])
def test_lifted_step_equals_unlifted_field(robot, mu, eps):
    """With theta = products of sigma (lifting constraints satisfied) the dynamics residual equals
    y_{k+1} - y_k - h s F(y_{k+1}, sigma, u) with the multi-affine F (random seeded point)."""
    s = system(robot, mu, eps)
    b = ImplicitEulerStep(s)
    yk, yn, u, sp = symbols(s)
    st = b.build(yk, yn, u, sp, 0.02)
    rng = np.random.default_rng(0)
    sigma = rng.uniform(size=s.n_sigma)
    w = b.w_from(sigma, rng.uniform(size=s.n_sigma), rng.uniform(size=s.n_sigma))
    g = ca.Function("g", [yk, yn, u, sp, st.w], [st.g])
    y0, y1 = rng.normal(size=s.ny), rng.normal(size=s.ny)
    y1[1] = abs(y1[1]) + 0.5  # keep the Capler base above the foot for a sane configuration
    uu = rng.normal(size=s.nu)
    gv = np.asarray(g(y0, y1, uu, 1.3, w), dtype=float).ravel()
    F = np.asarray(ca.Function("F", [s.y, s.u], [s.vector_field(sigma)])(y1, uu), dtype=float).ravel()
    np.testing.assert_allclose(gv[st.g_blocks["dynamics"]], y1 - y0 - 0.02 * 1.3 * F, atol=EVAL_TOL * 1e3)
    np.testing.assert_allclose(gv[st.g_blocks["lifting"]], 0.0, atol=EVAL_TOL)


@pytest.mark.parametrize("contacts,form", [(("foot",), StepForm.EXPLICIT), (("foot",), StepForm.MASS_MATRIX),
                                           (("foot", "knee"), StepForm.MASS_MATRIX)])
def test_substituted_products_give_the_lifted_step(contacts, form):
    """lift_products=False drops the lifted products' variables and lifting rows (the factors of several
    contacts stay), and every other row equals the lifted step's at the same selectors (random seeded
    point, theta consistent): the same step with fewer variables."""
    s = TimeFreezingSystem(Dynamics(load_robot("capler")), [Contact(p, mu=0.8) for p in contacts])
    lifted, plain = ImplicitEulerStep(s, form=form), ImplicitEulerStep(s, form=form, lift_products=False)
    yk, yn, u, sp = symbols(s)
    a, b = lifted.build(yk, yn, u, sp, 0.02), plain.build(yk, yn, u, sp, 0.02)
    n_prod = len(lifted.lifted)
    assert n_prod > 0 and plain.nw == lifted.nw - n_prod and b.g.shape[0] == a.g.shape[0] - n_prod
    assert b.g_blocks["lifting"].stop - b.g_blocks["lifting"].start == len(s.factors)
    rng = np.random.default_rng(1)
    sigma, lam0, lam1 = rng.uniform(size=(3, s.n_sigma))
    fb = lifted.w_blocks.get("forces")
    forces = rng.normal(size=fb.stop - fb.start) if fb else None
    wa, wb = lifted.w_from(sigma, lam0, lam1, forces), plain.w_from(sigma, lam0, lam1, forces)
    y0, y1, uu = rng.normal(size=s.ny), rng.normal(size=s.ny), rng.normal(size=s.nu)
    y1[1] = abs(y1[1]) + 0.5  # the base above the foot
    ga = np.asarray(ca.Function("g", [yk, yn, u, sp, a.w], [a.g])(y0, y1, uu, 1.3, wa), float).ravel()
    gb = np.asarray(ca.Function("g", [yk, yn, u, sp, b.w], [b.g])(y0, y1, uu, 1.3, wb), float).ravel()
    for name in b.g_blocks:  # lifting: the factors' rows come first in both
        n_rows = b.g_blocks[name].stop - b.g_blocks[name].start
        np.testing.assert_allclose(gb[b.g_blocks[name]], ga[a.g_blocks[name]][:n_rows], rtol=EVAL_TOL * 1e3, atol=EVAL_TOL * 1e3,
                                   err_msg=name)
    np.testing.assert_allclose(plain.coefficients(wb), lifted.coefficients(wa), atol=EVAL_TOL)
    with pytest.raises(InputError, match="lift_products must be True or False"):
        ImplicitEulerStep(s, lift_products="no")


def test_guess_solves_the_step_lp_kkt():
    """The state-based guess satisfies the LP's KKT conditions (24c-e) at that state: h = lambda1 - lambda0,
    sigma = theta(h) and every complementarity product zero."""
    s = system()
    b = ImplicitEulerStep(s)
    yk, yn, u, sp = symbols(s)
    st = b.build(yk, yn, u, sp, 0.01)
    g = ca.Function("g", [yk, yn, u, sp, st.w], [st.g, st.comp_products()])
    y = np.array([0.0, 0.3, 1.0, -2.0, 0.0])  # in flight, falling: alpha = 0, beta = 1, gamma = 0 (phi = -g)
    w = b.guess(y, np.zeros(2))
    np.testing.assert_allclose(w[st.w_blocks["sigma"]], [0, 1, 0])
    gv, comp = (np.asarray(x, dtype=float).ravel() for x in g(y, y, np.zeros(2), 1.0, w))
    np.testing.assert_allclose(gv[st.g_blocks["stationarity"]], 0.0, atol=EVAL_TOL)
    np.testing.assert_allclose(gv[st.g_blocks["lifting"]], 0.0, atol=EVAL_TOL)
    np.testing.assert_allclose(comp, 0.0, atol=EVAL_TOL)


def test_guess_puts_the_wanted_selector_where_a_switching_function_is_zero():
    """Capler's default start (robots/capler.toml: q = (0, 0.4, 0, 0), v = 0, foot exactly on the ground, no-slip)
    has switching values (n^T v, c, phi, t^T v) = (0, 0, -g, 0) exactly: the guess takes sigma* = (1/2, 0, 1/2) for
    alpha, beta, zeta (h = 0 is the sliding manifold, where the wanted selectors are the DAE's) and gamma = 0 (h < 0),
    with both multipliers of a zero h at 0. A selector of 1 there (h >= 0 read as h > 0) starts the hint-free OCP in
    free flight while the foot stands."""
    s = system("capler", 0.8)
    b = ImplicitEulerStep(s)
    y = s.initial_state(np.array([0.0, 0.4, 0.0, 0.0]), np.zeros(4))
    u = np.zeros(s.nu)
    assert [sw.name for sw in s.switches] == ["alpha[foot]", "beta[foot]", "gamma[foot]", "zeta[foot]"]
    np.testing.assert_array_equal(np.asarray(s.switching_fn(y, u), float).ravel(), [0.0, 0.0, -9.81, 0.0])
    w = b.guess(y, u)
    np.testing.assert_array_equal(w[b.w_blocks["sigma"]], [0.5, 0.0, 0.0, 0.5])
    np.testing.assert_array_equal(w[b.w_blocks["lambda0"]], [0.0, 0.0, 9.81, 0.0])
    np.testing.assert_array_equal(w[b.w_blocks["lambda1"]], [0.0, 0.0, 0.0, 0.0])


def test_objective_is_regularization():
    """Objective = rho_f ||sigma - sigma*||^2 (rho_f = 2.5 at a random sigma)."""
    s = system()
    b = ImplicitEulerStep(s, rho_f=2.5)
    yk, yn, u, sp = symbols(s)
    st = b.build(yk, yn, u, sp, 0.01)
    sigma = np.array([0.2, 0.9, 0.4])
    val = float(ca.Function("J", [st.w], [st.objective])(b.w_from(sigma, np.zeros(3), np.zeros(3))))
    assert val == pytest.approx(2.5 * np.sum((sigma - [0.5, 0, 0]) ** 2))


def test_steps_concatenate_and_accept_mx():
    """N steps chain into one NLP with distinct variable names; MX inputs give MX variables."""
    s = system()
    b = ImplicitEulerStep(s)
    Y = ca.MX.sym("Y", s.ny, 3)
    y0 = ca.MX.sym("y0", s.ny)
    steps = [b.build(y0 if k == 0 else Y[:, k - 1], Y[:, k], ca.MX.zeros(s.nu), 1.0, 0.01, tag=f"_{k}") for k in range(3)]
    assert all(isinstance(st.w, ca.MX) for st in steps)
    names = [n for st in steps for n in st.w_names]
    assert len(names) == len(set(names)) == 3 * b.nw
    g = ca.vertcat(*[st.g for st in steps])
    assert g.shape[0] == 3 * (s.ny + 6)


def test_bad_step_arguments_are_refused():
    """rho_f < 0 (or NaN, or not a number), a non-positive switch scale or one of the wrong length and an unknown step
    form are InputErrors naming the value; the form's value selects the member as the options' values do (a string
    used to build the explicit step silently; rho_f = "1" and a short switch_scale raised TypeError and numpy's
    ValueError)."""
    for rho_f, shown_as in ((-1.0, "-1.0"), (float("nan"), "nan"), ("1", "'1'"), (float("inf"), "inf")):
        with pytest.raises(InputError, match=f"rho_f must be a finite number >= 0, got {shown_as}"):
            ImplicitEulerStep(system(), rho_f=rho_f)
    assert ImplicitEulerStep(system(), rho_f=np.array(2.0)).rho_f == 2.0  # a number as numpy holds it (regression)
    with pytest.raises(InputError, match=r"switch_scale must be 3 numbers > 0, got 'abc'"):
        ImplicitEulerStep(system(), switch_scale="abc")
    with pytest.raises(InputError, match=r"switch_scale must have one entry per switching function \(3\), got 2"):
        ImplicitEulerStep(system(), switch_scale=[1.0, 1.0])
    for scale in ([1.0, 0.0, 1.0], [1.0, float("nan"), 1.0], [1.0, float("inf"), 1.0]):  # (nan, inf were accepted)
        with pytest.raises(InputError, match=r"switch_scale must be finite and > 0, got \[1.0, "):
            ImplicitEulerStep(system(), switch_scale=scale)
    with pytest.raises(InputError, match=r"form = 'typo' is not allowed; it must be one of \['explicit', 'mass_"):
        ImplicitEulerStep(system(), form="typo")
    by_value = ImplicitEulerStep(system(), form="mass_matrix")
    assert by_value.form is StepForm.MASS_MATRIX and by_value.mm is not None


SECANT_TOL = 1e-7  # 3-point Gauss on a step of |dq| <= 0.3 rad: the quadrature error is O(|dq|^7) (measured 5e-9)
POINT_ERR_MIN = 1e-3  # the end-point gradient misses the same gap change by the curvature term (measured 4e-2)


def test_secant_switch_velocity_keeps_the_gap_of_a_step():
    """SwitchVelocity.SECANT: the row that replaces n^T v (t^T v) times q_b - q_a equals the change of
    the foot's height (x) over the step, so n-bar^T v = 0 in persistent contact keeps the gap; the
    end-point gradient n(q_b) of the paper's scheme misses it by the curvature term. Capler, random
    steps of 0.3 rad, seeded."""
    from planner.discretization import SwitchVelocity, _secant_rows

    s = system("capler", mu=0.8)
    rows, mask = _secant_rows(s)
    names = [sw.function for sw in s.switches]
    assert mask.tolist() == [1.0 if f in ("n^T v", "t^T v") else 0.0 for f in names]
    pos, jac = s.dyn.point_position("foot"), s.dyn.point_jacobian("foot")
    rng = np.random.default_rng(3)
    point_errs = []
    for _ in range(5):
        qa = rng.normal(size=s.nq) * 0.5
        qb = qa + rng.normal(size=s.nq) * 0.3
        R = np.asarray(rows(qa, qb), float)
        d_pos = np.asarray(pos(qb) - pos(qa), float).ravel()
        assert abs(R[names.index("n^T v")] @ (qb - qa) - d_pos[2]) <= SECANT_TOL
        assert abs(R[names.index("t^T v")] @ (qb - qa) - d_pos[0]) <= SECANT_TOL
        point_errs.append(abs(np.asarray(jac(qb), float)[2] @ (qb - qa) - d_pos[2]))
    assert max(point_errs) >= POINT_ERR_MIN
    # the step's stationarity rows use it, the other switches are untouched
    yk, yn, u, sk = symbols(s)
    point = ImplicitEulerStep(s).build(yk, yn, u, sk, 0.02)
    secant = ImplicitEulerStep(s, velocity_switch=SwitchVelocity.SECANT).build(yk, yn, u, sk, 0.02)
    y_a = np.concatenate([rng.normal(size=s.nq) * 0.5, rng.normal(size=s.nv), [0.1]])
    y_b = y_a + np.concatenate([rng.normal(size=s.nq) * 0.1, rng.normal(size=s.nv), [0.02]])
    w = rng.uniform(size=point.w.shape[0])
    ev = [ca.Function("st", [yk, yn, u, sk, st.w], [st.g[st.g_blocks["stationarity"]]])(y_a, y_b, np.zeros(s.nu), 1.0, w) for st in (point, secant)]
    diff = np.abs(np.asarray(ev[0] - ev[1], float).ravel())
    assert np.all(diff[mask == 0] <= EVAL_TOL) and np.all(diff[mask == 1] > 0)
    # the value, as options take it
    assert ImplicitEulerStep(s, velocity_switch="secant").velocity_switch is SwitchVelocity.SECANT
    with pytest.raises(InputError, match=r"velocity_switch = 'chord' is not allowed; it must be one of \['point'"):
        ImplicitEulerStep(s, velocity_switch="chord")


def test_guess_with_dependent_contact_rows_is_finite():
    """Capler standing straight with the foot and the knee as contact points: their constraint rows
    are linearly dependent (one line), so the guess's force system is singular; the guess still
    returns finite values whose switching-function signs give the selectors (least squares)."""
    s = TimeFreezingSystem(Dynamics(load_robot("capler")), [Contact("foot", mu=0.8), Contact("knee", mu=0.8)])
    y = np.zeros(s.ny)
    y[1] = 0.4  # base height: the straight leg's foot exactly on the ground
    w = ImplicitEulerStep(s).guess(y, np.zeros(s.nu))
    assert np.all(np.isfinite(w))


SWITCH_SCALES = (0.5, 2.0, 100.0, 7.0)  # distinct per switch, below and above 1 (sliced to n_sigma)


@pytest.mark.parametrize("robot,mu", [("point_mass", 0.0), ("capler", 0.8)])
def test_switch_scale_divides_each_switching_function_in_its_stationarity_row(robot, mu):
    """switch_scale a (n_sigma,) divides the switching functions in the stationarity rows (eq. 24c): row i is
    h_i(y_{k+1}, u_k) / a_i - lambda1_i + lambda0_i, with h the system's switching function evaluated apart from the
    step (random seeded point, a distinct scale per switch); the state-based guess with that scale still solves those
    rows (its multipliers are max(-+h / a, 0)). Audit: the row built without the division, h - lambda1 + lambda0,
    left every test green."""
    s = system(robot, mu)
    scale = np.array(SWITCH_SCALES[: s.n_sigma])
    b = ImplicitEulerStep(s, switch_scale=scale)
    yk, yn, u, sp = symbols(s)
    st = b.build(yk, yn, u, sp, 0.02)
    rows = ca.Function("st", [yk, yn, u, sp, st.w], [st.g[st.g_blocks["stationarity"]]])
    rng = np.random.default_rng(6)
    w = rng.uniform(size=b.nw)
    y0, y1, uu = rng.normal(size=s.ny), rng.normal(size=s.ny), rng.normal(size=s.nu)
    y1[1] = abs(y1[1]) + 0.5  # above the ground (Capler: the base above the foot)
    hval = np.asarray(s.switching_fn(y1, uu), float).ravel()
    assert np.all(np.abs(hval) > 1e-3)  # every row's scale shows
    lam0, lam1 = w[b.w_blocks["lambda0"]], w[b.w_blocks["lambda1"]]
    got = np.asarray(rows(y0, y1, uu, 1.3, w), float).ravel()
    np.testing.assert_allclose(got, hval / scale - lam1 + lam0, rtol=EVAL_TOL * 1e3, atol=EVAL_TOL * 1e3)
    # the guess at y_{k+1} itself: its multipliers carry the scale (lambda1 - lambda0 = h / a), its KKT rows are zero
    guess = b.guess(y1, uu)
    np.testing.assert_allclose(guess[b.w_blocks["lambda1"]] - guess[b.w_blocks["lambda0"]], hval / scale, rtol=EVAL_TOL)
    np.testing.assert_allclose(np.asarray(rows(y1, y1, uu, 1.0, guess), float).ravel(), 0.0, atol=EVAL_TOL * 1e3)


SEED = 0  # the seeded states and selectors below


def test_an_unregularized_selector_has_no_rho_f_term():
    """The step's objective is rho_f sum (sigma_i - sigma_i*)^2 over the regularized selectors only
    (Switch.regularized): a frictionless contact with frictionless_tangential (a plan without scene analysis) has the
    tangential selector zeta, which multiplies a zero field, so no rho_f term prices it. At seeded selectors the
    objective equals that sum (ground truth: the formula over TimeFreezingSystem.regularized) and does not depend on
    zeta. With every selector regularized (a mutant of session 65's mutation testing) zeta was pulled to its sigma*,
    pricing tangential sliding."""
    from planner.discretization import ImplicitEulerStep
    from planner.dynamics import Dynamics
    from planner.task import Contact
    from planner.timefreezing import TimeFreezingSystem

    sys_ = TimeFreezingSystem(Dynamics(load_robot("point_mass")), [Contact("point", mu=0.0)],
                              frictionless_tangential=True)
    keep = sys_.regularized
    assert not keep.all() and keep.any()
    rho_f = 2.5
    builder = ImplicitEulerStep(sys_, rho_f)
    y, y1, u = ca.SX.sym("y", sys_.ny), ca.SX.sym("y1", sys_.ny), ca.SX.sym("u", sys_.nu)
    step = builder.build(y, y1, u, 1.0, 0.01)
    objective = ca.Function("objective", [step.w], [step.objective])
    rng = np.random.default_rng(SEED)
    for _ in range(5):
        sigma = rng.uniform(0.0, 1.0, sys_.n_sigma)
        w = builder.w_from(sigma, np.zeros(sys_.n_sigma), np.zeros(sys_.n_sigma))
        expected = rho_f * np.sum((sigma - sys_.wanted)[keep] ** 2)
        assert float(objective(w)) == pytest.approx(expected, rel=EVAL_TOL, abs=EVAL_TOL * rho_f)
    zeta = np.flatnonzero(~keep).tolist()
    assert not ca.depends_on(step.objective, step.sigma[zeta])


def test_the_several_contacts_guess_switches_the_selectors_of_its_own_forces():
    """ImplicitEulerStep.guess for several contacts computes the forces of the points its selectors switch on, then the
    selectors from those forces' switching functions (twice: from sigma*, then from the first selectors). Ground truth:
    the step's own equations, contact_forces and switching_fn. Over 200 seeded biped states (standing, or lifted by up
    to 2 cm, random velocities and motor torques), the guess's selectors are a fixed point of selectors -> forces ->
    switching functions -> selectors in at least GUESS_FIXED_POINTS of them (measured: 150 with the two passes, 66 with
    one). Guessing with one pass (a mutant of session 65's mutation testing) started IPOPT from selectors its own forces
    contradict."""
    from planner.discretization import ImplicitEulerStep
    from planner.dynamics import Dynamics
    from planner.task import load_task
    from planner.timefreezing import TimeFreezingSystem

    GUESS_FIXED_POINTS = 120  # of 200: between one pass's 66 and two passes' 150
    robot, task = load_robot("biped"), load_task(ROBOTS_DIR / "biped.toml")
    sys_ = TimeFreezingSystem(Dynamics(robot), task.contacts, task.ground_height)
    builder = ImplicitEulerStep(sys_)
    rng = np.random.default_rng(SEED)
    q0, fixed = np.array(task.initial.q, float), 0
    for i in range(200):
        q = q0 + np.r_[0.0, rng.uniform(0.0, 0.02), rng.uniform(-0.1, 0.1, 3)] * (i % 2)
        v, u = rng.uniform(-0.5, 0.5, robot.nv), rng.uniform(-300.0, 300.0, robot.nu)
        y = sys_.initial_state(q, v)
        sigma = builder.guess(y, u)[builder.w_blocks["sigma"]]
        h = np.asarray(sys_.switching_fn(y, u, builder.contact_forces(y, u, sigma)), float).ravel()
        fixed += np.array_equal(sigma, np.where(h > 0, 1.0, np.where(h < 0, 0.0, sys_.wanted)))
    assert fixed >= GUESS_FIXED_POINTS, fixed
