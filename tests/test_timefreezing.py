"""The time-freezing system: wanted selectors reproduce the DAE on Sigma, fields, elastic oscillator."""
from __future__ import annotations

import functools
import math

import casadi as ca
import numpy as np
import pinocchio as pin
import pytest
from scipy.linalg import expm

from planner.contact import contact_functions
from planner.discretization import ImplicitEulerStep, StepForm
from planner.dynamics import Dynamics
from planner.errors import InputError
from planner.model import load_robot
from planner.task import Contact
from planner.timefreezing import (PUSH_SPEED, ContactModel, Poly, TimeFreezingSystem, contact_model,
                                  oscillator_gains)

ON_SIGMA_TOL = 1e-9  # tangency of F to Sigma at numerically constructed points on Sigma (QR solves)
OSC_TOL = 1e-12  # the oscillator's exact solution by the matrix exponential
FIELD_TOL = 1e-12  # closed-form fields of the point mass (M = I, D = 1), CasADi's fields against Pinocchio's numeric
# algorithms, multi-affine factors at the selectors' vertices: only rounding (1.4e-15 measured)


@functools.cache
def dyn(name: str) -> Dynamics:
    return Dynamics(load_robot(name))


def system(name: str, **contact) -> TimeFreezingSystem:
    point = {"point_mass": "point", "capler": "foot", "biped": "foot_1"}[name]
    return TimeFreezingSystem(dyn(name), [Contact(point, **contact)])


def structurally_zero(expr) -> bool:
    expr = ca.SX(ca.simplify(expr))
    return all(expr.nz[i].is_zero() for i in range(expr.nnz()))


@pytest.mark.parametrize("robot", ["point_mass", "capler"])
def test_wanted_selectors_give_f_dae_symbolically(robot):
    """Frictionless (eqs. 17, 20): with (alpha*, beta*, gamma*) = (0.5, 0, 0), F is symbolically f_DAE."""
    s = system(robot)
    assert s.models == (ContactModel.FRICTIONLESS,)
    pt = s.contacts[0].point
    assert structurally_zero(s.vector_field(s.wanted) - s.field(f"dae[{pt}]"))
    with pytest.raises(InputError, match=r"no field 'dae\[nowhere\]'; fields: ode, "):  # a PlannerError, not KeyError
        s.field("dae[nowhere]")


@pytest.mark.parametrize("robot", ["point_mass", "capler"])
def test_wanted_selectors_give_f_dae_f_symbolically(robot):
    """No slip (Sec. 6 simplified): with (alpha*, beta*, gamma*, zeta*) = (0.5, 0, 0, 0.5), F is symbolically f_DAE,f."""
    s = system(robot, mu=0.8)
    assert s.models == (ContactModel.NO_SLIP,)
    pt = s.contacts[0].point
    assert structurally_zero(s.vector_field(s.wanted) - s.field(f"dae_f[{pt}]"))


@pytest.mark.parametrize("robot", ["point_mass", "capler"])
def test_pull_off_selectors_give_f_ode_and_a_running_clock(robot):
    """Frictionless pull-off (eq. 20 with alpha = alpha* = 1/2, beta = 0, gamma = 1): f_DF = 2 f_ODE, so
    F = (1 - alpha) f_A,n + alpha 2 f_ODE = f_ODE + f_A,n / 2, symbolically; its q rows are v and its clock rate is
    exactly 1 for every gamma in [0, 1] (the DAE and the free ODE both run physical time), so a contact that breaks
    off while sliding neither freezes nor speeds up the clock. The factor 2 on gamma f_ODE is what keeps t' = 1."""
    s = system(robot)
    assert s.models == (ContactModel.FRICTIONLESS,)
    pt = s.contacts[0].point
    pull_off = np.array([0.5, 0.0, 1.0])  # (alpha, beta, gamma) in the order of s.switches
    assert [sw.name for sw in s.switches] == [f"alpha[{pt}]", f"beta[{pt}]", f"gamma[{pt}]"]
    expected = s.field("ode") + 0.5 * s.field(f"a_n[{pt}]")
    assert structurally_zero(s.vector_field(pull_off) - expected)
    assert structurally_zero(s.vector_field(pull_off)[: s.nq] - s.y[s.nq : s.nq + s.nv])  # q' = v, as in flight
    for gamma in (0.0, 0.5, 1.0):
        F = s.vector_field(np.array([0.5, 0.0, gamma]))
        clock = ca.Function("clock", [s.y, s.u], [F[s.ny - 1]])(np.zeros(s.ny), np.zeros(s.nu))
        assert float(clock) == 1.0, (gamma, float(clock))


def capler_on_sigma(s: TimeFreezingSystem, seed: int, no_slip: bool):
    """Random Capler state on Sigma: foot on the ground (shift z_B), n^T v = 0 (and t^T v = 0)."""
    rng = np.random.default_rng(seed)
    d = s.dyn
    q = np.array([rng.uniform(-1, 1), 0.4, rng.uniform(-1, 1), rng.uniform(-1.2, 1.2)])
    q[1] -= float(d.point_position("foot")(q)[2])
    J = np.asarray(d.point_jacobian("foot")(q), dtype=float)
    A = np.vstack([J[2], J[0]]) if no_slip else J[2:3]
    v = rng.normal(size=4)
    v -= A.T @ np.linalg.solve(A @ A.T, A @ v)
    y = s.initial_state(q, v)
    return y, rng.normal(scale=10.0, size=2)


@pytest.mark.parametrize("no_slip", [False, True])
def test_wanted_field_is_tangent_to_sigma(no_slip):
    """On Sigma (c = 0, n^T v = 0 [, t^T v = 0]) the wanted-selector field keeps h1, h2 (and h4) at 0:
    their derivatives along F(sigma*) vanish (Lemma 8 / Prop. 9(a) with the Capler foot)."""
    s = system("capler", mu=0.8 if no_slip else 0.0)
    grad = ca.Function("grad", [s.y, s.u], [ca.jacobian(s.switching, s.y)])
    F = ca.Function("F", [s.y, s.u], [s.vector_field(s.wanted)])
    keep = [0, 1, 3] if no_slip else [0, 1]  # alpha, beta (, zeta); gamma's phi is not a manifold here
    for seed in range(5):
        y, u = capler_on_sigma(s, seed, no_slip)
        h = np.asarray(s.switching_fn(y, u), dtype=float).ravel()
        assert np.all(np.abs(h[keep]) < ON_SIGMA_TOL)
        rates = np.asarray(grad(y, u), dtype=float) @ np.asarray(F(y, u), dtype=float).ravel()
        assert np.all(np.abs(rates[keep]) < ON_SIGMA_TOL * 1e3), rates


def test_no_slip_selectors_are_unique_on_sigma():
    """With beta = gamma = 0 on Sigma, tangency of h1 = n^T v and h4 = t^T v is a 2x2 linear system in
    (1 - 2 alpha, 1 - 2 zeta) with the contact Delassus matrix: its only solution is alpha = zeta = 1/2."""
    s = system("capler", mu=0.8)
    grad = ca.Function("grad", [s.y, s.u], [ca.jacobian(s.switching, s.y)])
    fields = s.fields_fn
    names = [f.name for f in s.fields]
    for seed in range(3):
        y, u = capler_on_sigma(s, seed, True)
        Gr = np.asarray(grad(y, u), dtype=float)[[0, 3]]
        Fm = np.asarray(fields(y, u), dtype=float)
        fa_n, fa_t, fdae = (Fm[:, names.index(f"{k}[foot]")] for k in ("a_n", "a_t", "dae_f"))
        # F = (1 - 2 alpha) f_A,n + (1 - 2 zeta) f_A,t + 2 alpha f_DAE,f with beta = gamma = 0
        A = np.column_stack([Gr @ fa_n, Gr @ fa_t])
        b = -Gr @ fdae  # 2 alpha f_DAE,f = f_DAE,f when alpha = 1/2; Gr @ f_DAE,f = 0 on Sigma
        x = np.linalg.solve(A, b)
        np.testing.assert_allclose(x, 0.0, atol=ON_SIGMA_TOL * 1e3)
        assert abs(np.linalg.det(A)) > 1e-6


def test_clock_and_q_frozen_in_auxiliary_fields():
    """f_A,n and f_A,t leave q and the clock unchanged and push v along M^-1 n and M^-1 t with gains a_n, a_t."""
    s = system("point_mass", mu=0.5, a_n=7.0, a_t=11.0)
    y, u = np.array([0.1, 0.0, 1.0, -2.0, 0.3]), np.zeros(2)
    Fm = np.asarray(s.fields_fn(y, u), dtype=float)
    names = [f.name for f in s.fields]
    np.testing.assert_allclose(Fm[:, names.index("a_n[point]")], [0, 0, 0, 7.0, 0])
    np.testing.assert_allclose(Fm[:, names.index("a_t[point]")], [0, 0, 11.0, 0, 0])
    np.testing.assert_allclose(Fm[:, names.index("ode")], [1.0, -2.0, 0, -9.81, 1])
    assert [f.auxiliary for f in s.fields] == [False, True, False, True]


@pytest.mark.parametrize("eps", [0.1, 0.5, 0.9, 1.0])
def test_oscillator_gains_give_restitution(eps):
    """Sec. 4.5: the damped oscillator p'' = -k p - c p' started at (p, p') = (0, -1) is back at p = 0
    after pi / omega_d with p' = eps (exact solution by the matrix exponential)."""
    k, c = oscillator_gains(eps, 25.0)
    wd = math.sqrt(k - c * c / 4)
    A = np.array([[0.0, 1.0], [-k, -c]])
    p, w = expm(A * math.pi / wd) @ np.array([0.0, -1.0])
    assert abs(p) < OSC_TOL and abs(w - eps) < OSC_TOL
    if eps == 1.0:
        assert c == 0.0


def test_elastic_frozen_field_is_the_oscillator():
    """Elastic model on the point mass (n = (0, 1), M = I, D = 1): at every one of the 8 corners of the selectors
    (alpha, beta, eta) = (n^T v > 0, c > 0, p >= 0) the field is the one docs/formulation.md's region table puts
    there: c > 0, p >= 0 flight f_ODE (p' = 0); c > 0, p < 0 f_push (q' = -a_p n / |n|^2, p' = a_p, clock frozen);
    c <= 0, p < 0 the frozen oscillator f_osc (q and clock frozen, p' = n^T v, (n^T v)' = -k p - c n^T v);
    c <= 0, p >= 0 f_osc when n^T v < 0 (entry corner), f_ODE when n^T v > 0 (exit corner); alpha matters only
    there. Each expected field is written in closed form here. (The test probed 2 of the 8 corners: swapping
    alpha's roles in the ground corner, or the push for the oscillator above the ground, left it green.)"""
    s = system("point_mass", restitution=0.5, a_n=16.0)
    assert s.models == (ContactModel.ELASTIC,) and s.state_names[-2:] == ("p[point]", "t")
    assert [sw.name for sw in s.switches] == ["alpha[point]", "beta[point]", "eta[point]"]
    k, c = oscillator_gains(0.5, 16.0)
    y, u = np.array([0.2, 0.0, 0.7, -1.5, -0.05, 0.4]), np.array([3.0, 1.0])
    w, p, a_p = y[3], y[4], PUSH_SPEED  # n^T v = v_z; a_p = PUSH_SPEED = 10 m/s (docs/formulation.md)
    ode = [0.7, -1.5, 3.0, 1.0 - 9.81, 0.0, 1.0]  # (v, M^-1 (B u - h), p' = 0, t' = 1)
    osc = [0.0, 0.0, 0.0, -k * p - c * w, w, 0.0]  # q, clock frozen; v_z' = (-k p - c w) / D
    push = [0.0, -a_p, 0.0, 0.0, a_p, 0.0]  # q' = -a_p n / |n|^2, v frozen, p' = a_p
    expected = {}
    for alpha in (0.0, 1.0):
        expected[alpha, 1.0, 1.0] = ode  # flight
        expected[alpha, 1.0, 0.0] = push  # above the plane with p < 0
        expected[alpha, 0.0, 0.0] = osc  # the frozen impact
        expected[alpha, 0.0, 1.0] = ode if alpha == 1.0 else osc  # exit corner / entry corner
    assert len(expected) == 8
    for sigma, field in expected.items():
        F = np.asarray(ca.Function("F", [s.y, s.u], [s.vector_field(np.array(sigma))])(y, u), dtype=float).ravel()
        np.testing.assert_allclose(F, field, atol=FIELD_TOL, err_msg=f"(alpha, beta, eta) = {sigma}")


def test_contact_models_and_unsupported_combinations():
    """eps > 0 is elastic, mu > 0 no-slip, else frictionless; eps > 0 with mu > 0, and an elastic point
    among several contact points, are input errors."""
    assert contact_model(Contact("p")) is ContactModel.FRICTIONLESS
    assert contact_model(Contact("p", mu=0.3)) is ContactModel.NO_SLIP
    assert contact_model(Contact("p", restitution=0.4)) is ContactModel.ELASTIC
    with pytest.raises(InputError, match="restitution"):
        contact_model(Contact("p", mu=0.3, restitution=0.4))
    with pytest.raises(InputError, match="must all be inelastic"):
        TimeFreezingSystem(dyn("capler"), [Contact("foot", restitution=0.5), Contact("knee")])


def test_no_contacts_is_free_flight():
    """Without contact points F = f_ODE and there are no selectors."""
    s = TimeFreezingSystem(dyn("point_mass"), [])
    assert s.n_sigma == 0 and s.ny == 5
    assert structurally_zero(s.vector_field(np.zeros(0)) - s.field("ode"))


def test_poly_is_multi_affine():
    """Selector polynomials multiply out exactly and refuse a repeated factor (sigma_i^2 never appears)."""
    a, b = Poly.var(0), Poly.var(1)
    p = (1 - a) * (1 - b)
    assert p.terms == {(): 1.0, (0,): -1.0, (1,): -1.0, (0, 1): 1.0}
    assert p([0.25, 0.5]) == pytest.approx(0.375)
    with pytest.raises(ValueError):
        _ = a * a


# --- several contact points (docs/formulation.md, "Several contacts") ----------------------------

FORCE_TOL = 1e-9  # index-reduced forces from two dense solves of the same linear system [N]


def biped_two_feet(mu: float = 0.8) -> TimeFreezingSystem:
    return TimeFreezingSystem(dyn("biped"), [Contact("foot_1", mu=mu), Contact("foot_2", mu=mu)])


def biped_standing(seed: int):
    """A random biped state with both feet on the ground and both feet at rest (n^T v = t^T v = 0)."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(0.1, 0.4)
    q = np.array([rng.uniform(-1, 1), math.cos(a), rng.uniform(-0.3, 0.3), 0.0, 0.0])
    q[3], q[4] = a - q[2], -a - q[2]  # absolute leg angles +-a: both feet at z = 0
    J = np.vstack([np.asarray(dyn("biped").point_jacobian(f)(q), float)[[2, 0]] for f in ("foot_1", "foot_2")])
    v = rng.normal(size=5)
    v -= J.T @ np.linalg.solve(J @ J.T, J @ v)
    return q, v, J, rng.normal(scale=50.0, size=2)


def test_several_contacts_wanted_selectors_give_joint_dae():
    """Both biped feet on the ground with the wanted selectors: F = f_ODE + sum_i M^-1 J_i^T lambda_i
    exactly (the coefficients are those of f_ODE and the unit-force fields), and the force rows switched
    on for both feet give the index-reduced forces of the STACKED Jacobian, -(J M^-1 J^T)^-1 (J f_v +
    dJ/dt v), which keep both feet at rest; the sum of the two single-foot DAE forces is different
    (the feet are coupled through M) and would not."""
    s = biped_two_feet()
    coef = s.coefficient_vector(s.wanted, np.zeros(s.n_lambda))
    np.testing.assert_array_equal(coef, [1.0] + [0.0] * (s.n_fields - 1))
    b = ImplicitEulerStep(s)
    for seed in range(3):
        q, v, J, u = biped_standing(seed)
        y = s.initial_state(q, v)
        lam = b.contact_forces(y, u, s.wanted)
        M = np.asarray(dyn("biped").mass(q), float)
        fv = np.asarray(dyn("biped").forward(q, v, u), float).ravel()
        drift = np.concatenate([np.asarray(dyn("biped").point_drift(f)(q, v), float).ravel()[[2, 0]] for f in ("foot_1", "foot_2")])
        stacked = -np.linalg.solve(J @ np.linalg.solve(M, J.T), J @ fv + drift)
        np.testing.assert_allclose(lam, stacked, atol=FORCE_TOL * np.abs(stacked).max())
        F = np.asarray(s.vector_field(s.wanted, y, u, lam), float).ravel()
        np.testing.assert_allclose(J @ F[5:10] + drift, 0.0, atol=ON_SIGMA_TOL * 1e3)  # feet stay at rest
        single = np.concatenate([np.asarray(contact_functions(dyn("biped"), f, 0.0)["lambda_no_slip"](q, v, u), float).ravel()
                                 for f in ("foot_1", "foot_2")])
        assert np.abs(single - stacked).max() > 1.0  # [N]: the coupling is not small


def test_several_contacts_tangency_forces_wanted_selectors():
    """On Sigma of both feet (beta = gamma = 0, forces of both feet on), the tangency of the four
    h = (n_i^T v, t_i^T v) is linear in e = (e_n,i, e_t,i), the net auxiliary coefficients
    e_n,i = 1 - alpha_i - R_-i alpha_i and e_t,i = 1 - 2 zeta_i, with the joint Delassus matrix: e = 0 is
    its only solution, and e = 0 with R_-i = 2 alpha_k gives alpha = 1/2 (so R = 1: the clock runs)."""
    s = biped_two_feet()
    names = [f.name for f in s.fields]
    q, v, J, u = biped_standing(7)
    y = s.initial_state(q, v)
    Fm = np.asarray(s.fields_fn(y, u), float)
    lam = ImplicitEulerStep(s).contact_forces(y, u, s.wanted)
    Gr = np.asarray(ca.Function("g", [s.y, s.u, s.lam], [ca.jacobian(s.switching, s.y)])(y, u, lam), float)[[0, 3, 4, 7]]
    dae = Fm[:, 0] + sum(lam[k] * Fm[:, j] for k, j in enumerate(s.force_columns))
    np.testing.assert_allclose(Gr @ dae, 0.0, atol=ON_SIGMA_TOL * 1e3)
    A = np.column_stack([Gr @ Fm[:, names.index(f"{k}[{f}]")] for f in ("foot_1", "foot_2") for k in ("a_n", "a_t")])
    assert np.linalg.matrix_rank(A) == 4
    alpha = np.linspace(0.05, 1.0, 96)  # e_n = 0 on the symmetric branch: alpha (1 + 2 alpha) = 1
    roots = alpha[np.abs(alpha * (1 + 2 * alpha) - 1) < 1e-2]
    np.testing.assert_allclose(roots, 0.5, atol=0.01)


def test_frozen_impact_stops_the_clock_and_other_pulls():
    """While one foot is in its impact region (alpha = beta = 0) the clock and q are frozen whatever
    the other foot's selectors (R = 0), and the other foot's normal auxiliary coefficient is
    (1 - beta)(1 - alpha) >= 0: it can push but never pull (no adhesive impulse from the DAE-forming
    term while another point is frozen); two simultaneous impacts push both feet with the clock frozen."""
    s = biped_two_feet()
    names = [f.name for f in s.fields]
    rng = np.random.default_rng(1)
    for _ in range(20):
        sigma = rng.uniform(size=s.n_sigma)
        sigma[4] = sigma[5] = 0.0  # foot_2 in its impact region
        c = s.coefficient_vector(sigma, rng.normal(size=s.n_lambda))
        assert c[names.index("ode")] == 0.0 and all(c[j] == 0.0 for j in s.force_columns)
        a1, b1 = sigma[0], sigma[1]
        assert c[names.index("a_n[foot_1]")] == pytest.approx((1 - b1) * (1 - a1)) and c[names.index("a_n[foot_2]")] == 1.0
    both = np.array([0.0, 0.0, 0.0, 0.5] * 2)
    c = s.coefficient_vector(both, np.zeros(s.n_lambda))
    assert c[names.index("ode")] == 0.0 and c[names.index("a_n[foot_1]")] == c[names.index("a_n[foot_2]")] == 1.0


@pytest.mark.parametrize("mu, frictionless_tangential", [(0.8, False), (0.0, True)])
def test_several_contacts_in_flight_give_the_free_ode(mu, frictionless_tangential):
    """With both biped feet above the ground (beta_i = 1), whatever the other selectors, F is f_ODE: coefficient 1 on
    f_ODE and 0 on every auxiliary field (a_n and a_t of both feet), with the contact forces 0 that the force rows
    switched off ((1 - beta)(1 - gamma) = 0) give; so a flight at a drawn velocity (the feet moving along the
    ground too; zeta at 0 or 1) is not braked and its clock runs. Ground truth: free flight, M v' = B u - h (session
    66's mutation testing: the a_t term not gated by (1 - beta_i), a tangential kick in every flight, with every test
    green)."""
    s = TimeFreezingSystem(dyn("biped"), [Contact("foot_1", mu=mu), Contact("foot_2", mu=mu)],
                           frictionless_tangential=frictionless_tangential)
    betas = [i for i, sw in enumerate(s.switches) if sw.function == "c(q)"]
    assert len(betas) == 2 and sum(sw.function == "t^T v" for sw in s.switches) == 2
    rng = np.random.default_rng(4)
    q, _, _, u = biped_standing(5)
    v = rng.normal(size=5)
    y = s.initial_state(q + np.array([0.0, 0.5, 0.0, 0.0, 0.0]), v)  # lifted 0.5 m: both feet in the air
    model = dyn("biped").robot.model
    free = pin.aba(model, model.createData(), y[:5], v, np.asarray(dyn("biped").actuation, float) @ u)
    for sigma in [rng.uniform(size=s.n_sigma) for _ in range(10)] + [rng.integers(0, 2, size=s.n_sigma) * 1.0]:
        sigma[betas] = 1.0
        assert [float(switch(sigma)) for switch in s.constraint_switches] == [0.0] * s.n_lambda
        coef = s.coefficient_vector(sigma, np.zeros(s.n_lambda))
        np.testing.assert_allclose(coef, [1.0] + [0.0] * (s.n_fields - 1), atol=FIELD_TOL)
        F = np.asarray(s.vector_field(sigma, y, u, np.zeros(s.n_lambda)), float).ravel()
        np.testing.assert_allclose(F[5:10], free, atol=FIELD_TOL * np.abs(free).max())
        np.testing.assert_allclose(np.append(F[:5], F[-1]), np.append(v, 1.0), atol=FIELD_TOL)  # q' = v, t' = 1


@pytest.mark.parametrize("mu", [0.0, 0.5])
def test_each_factors_upper_bound_is_its_largest_value(mu):
    """Each factor variable (clock factor r_i, gate g_i, chain products) of a point against three planes is bounded
    above by `upper` (the step NLP's bound), which is its largest value over the selectors' box: the factors are
    multi-affine in the selectors, so the largest is at a vertex; every vertex is enumerated. r_i = 2 at a lift-off
    (alpha_i = 1, beta_i = 0), so a bound of 1 would cut lift-offs out of the step's feasible set (session 66's
    mutation testing: r_i's upper bound 1 instead of 1/alpha* = 2, with every test green)."""
    import itertools

    planes = [Contact("point", mu=mu, normal=(math.sin(0.1 * k), 0.0, math.cos(0.1 * k))) for k in range(3)]
    s = TimeFreezingSystem(dyn("point_mass"), planes)
    values = np.array([s.variables(np.array(v, float))[s.n_sigma:]
                       for v in itertools.product((0.0, 1.0), repeat=s.n_sigma)])
    np.testing.assert_allclose(values.max(axis=0), [f.upper for f in s.factors], rtol=FIELD_TOL)
    assert values.min() >= 0.0 and max(f.upper for f in s.factors) > 1.0


@pytest.mark.parametrize("mu", [0.0, 0.5])
def test_several_contacts_scale_linearly(mu):
    """m contacts (one point against m planes): fields, selectors, factor variables and the lifted
    products of a step grow linearly in m (no 2^m or 3^m modes), and products stay of degree <= 3."""
    counts = []
    for m in range(2, 7):
        cs = [Contact("point", mu=mu, normal=(math.sin(0.1 * k), 0.0, math.cos(0.1 * k))) for k in range(m)]
        s = TimeFreezingSystem(dyn("point_mass"), cs)
        b = ImplicitEulerStep(s)
        assert max(len(mono) for mono in b.lifted) <= 3
        counts.append((s.n_fields, s.n_sigma, len(s.factors), len(b.lifted), b.nw))
    steps = np.diff(np.array(counts), axis=0)
    assert np.all(steps == steps[-1]), counts  # constant increments: linear


def test_several_contacts_step_forms_agree():
    """The mass-matrix step (forces acc, lambda, d with M acc = B u - h, M d = J^T lambda) and the
    explicit step have the same residual at a random point once the extra variables solve their rows."""
    s = biped_two_feet()
    q, v, _, u = biped_standing(3)
    y = s.initial_state(q, v)
    rng = np.random.default_rng(2)
    sigma = rng.uniform(size=s.n_sigma)
    for form in (StepForm.EXPLICIT, StepForm.MASS_MATRIX):
        b = ImplicitEulerStep(s, form=form)
        w = b.w_from(sigma, np.zeros(s.n_sigma), np.zeros(s.n_sigma), b.forces_at(y, u, sigma))
        yk, yn, uu = ca.SX.sym("yk", s.ny), ca.SX.sym("yn", s.ny), ca.SX.sym("u", s.nu)
        st = b.build(yk, yn, uu, 1.0, 0.01)
        g = np.asarray(ca.Function("g", [yk, yn, uu, st.w], [st.g])(y, y, u, w), float).ravel()
        np.testing.assert_allclose(g[st.g_blocks["lifting"]], 0.0, atol=1e-12)
        np.testing.assert_allclose(g[st.g_blocks["contact_forces"]], 0.0, atol=1e-8)
        dyn_rows = g[st.g_blocks["dynamics"]]
        if form is StepForm.MASS_MATRIX:
            dyn_rows = dyn_rows.copy()
            dyn_rows[5:10] = np.linalg.solve(np.asarray(dyn("biped").mass(q), float), dyn_rows[5:10])
        if form is StepForm.EXPLICIT:
            ref = dyn_rows
        else:
            np.testing.assert_allclose(dyn_rows, ref, atol=1e-10)


# closed-form quantities of a 2 kg point mass and of Capler's fields, evaluated by CasADi: rounding only
FIELD_ROUNDING = 1e-9


def test_elastic_oscillator_moves_the_normal_velocity_as_the_oscillator_for_any_mass(tmp_path):
    """In the frozen oscillator (n^T v)' = -k p - c n^T v whatever the robot's Delassus D = n^T M^-1 n: here a 2 kg
    point mass (D = 1/2). Session 65's mutation testing: the oscillator's force multiplied by D instead of divided by
    it gives a restitution of 0.7 for 0.5, which the 1 kg point mass of every other elastic test, D = 1, cannot see."""
    path = tmp_path / "point_mass_2kg.xml"
    source = load_robot("point_mass").path.read_text()
    assert source.count('mass="1"') == 1
    path.write_text(source.replace('mass="1"', 'mass="2"'))
    s = TimeFreezingSystem(Dynamics(load_robot(path)), [Contact("point", restitution=0.5, a_n=16.0)])
    k, c = oscillator_gains(0.5, 16.0)
    y, u = np.array([0.2, 0.0, 0.7, -1.5, -0.05, 0.4]), np.array([3.0, 1.0])
    ground = np.zeros(3)  # the selectors' corner of the frozen oscillator
    F = np.asarray(ca.Function("F", [s.y, s.u], [s.vector_field(ground)])(y, u), float).ravel()
    assert F[3] == pytest.approx(-k * y[4] - c * y[3], rel=FIELD_ROUNDING)  # n = (0, 1): n^T v = v_z


@pytest.mark.parametrize("frictionless_tangential", [False, True])
@pytest.mark.parametrize("mus", [(0.0, 0.0), (0.8, 0.0), (0.8, 0.8)])
def test_impulse_rates_are_the_fields_generalized_forces(frictionless_tangential, mus):
    """For every auxiliary field of Capler with two contacts, M(q) f_v(y) = sum_i n_i rate_n,i + t_i rate_t,i: the
    impulse rates the result reads its impacts from are the forces the field applies (session 65's mutation testing:
    a tangential rate reported for a frictionless contact's a_t field, which applies none, left every test green)."""
    d = dyn("capler")
    s = TimeFreezingSystem(d, (Contact("foot", mu=mus[0]), Contact("knee", mu=mus[1])), 0.0,
                           frictionless_tangential=frictionless_tangential)
    rng = np.random.default_rng(2)
    y, u = np.concatenate([[0.1, 0.4, 0.3, -0.5], rng.normal(size=4), [0.0]]), rng.normal(size=2)
    F, R = (np.asarray(f(y, u), float) for f in (s.fields_fn, s.impulse_fn))
    M = np.asarray(d.mass(y[:4]), float)
    directions = [[np.asarray(ca.Function("d", [s.y], [e])(y), float).ravel() for e in (ct.normal, ct.tangent)]
                  for ct in s.terms]
    for j, field in enumerate(s.fields):
        if field.auxiliary:
            forces = sum(n * R[2 * i, j] + t * R[2 * i + 1, j] for i, (n, t) in enumerate(directions))
            np.testing.assert_allclose(M @ F[4:8, j], forces, atol=FIELD_ROUNDING, err_msg=field.name)


@pytest.mark.parametrize("frictionless_tangential", [False, True])
@pytest.mark.parametrize("mus", [(0.8, 0.0), (0.0, 0.8)])
def test_the_mass_matrix_forms_forces_are_m_times_the_fields(frictionless_tangential, mus):
    """For every field of Capler with two contacts, one with friction and one without, the mass-matrix form's
    generalized force is M(q) times the explicit field's velocity rows, and its q and clock rows are the field's: a
    frictionless contact's a_t (carried with frictionless_tangential) applies no force in either form (session 66's
    mutation testing: the mass-matrix form gave that a_t the gain a_t, a tangential impulse the explicit form does not
    apply, with every test green)."""
    d = dyn("capler")
    s = TimeFreezingSystem(d, (Contact("foot", mu=mus[0]), Contact("knee", mu=mus[1])), 0.0,
                           frictionless_tangential=frictionless_tangential)
    form = s.mass_matrix_form()
    rng = np.random.default_rng(6)
    y, u = np.concatenate([[0.1, 0.4, 0.3, -0.5], rng.normal(size=4), [0.0]]), rng.normal(size=2)
    F = np.asarray(s.fields_fn(y, u), float)
    G = np.asarray(form.fn(y, u, np.zeros(form.z.shape[0]))[0], float)
    M = np.asarray(d.mass(y[:4]), float)
    for j, field in enumerate(s.fields):
        np.testing.assert_allclose(G[4:8, j], M @ F[4:8, j], atol=FIELD_ROUNDING, err_msg=field.name)
        np.testing.assert_array_equal(np.delete(G[:, j], range(4, 8)), np.delete(F[:, j], range(4, 8)))
