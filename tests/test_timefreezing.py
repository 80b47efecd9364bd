"""The time-freezing system: wanted selectors reproduce the DAE on Sigma, fields, elastic oscillator."""
from __future__ import annotations

import functools
import math

import casadi as ca
import numpy as np
import pytest
from scipy.linalg import expm

from planner.dynamics import Dynamics
from planner.errors import InputError
from planner.model import load_robot
from planner.task import Contact
from planner.timefreezing import ContactModel, Poly, TimeFreezingSystem, contact_model, oscillator_gains

ON_SIGMA_TOL = 1e-9  # tangency of F to Sigma at numerically constructed points on Sigma (QR solves)
OSC_TOL = 1e-12  # the oscillator's exact solution by the matrix exponential


@functools.cache
def dyn(name: str) -> Dynamics:
    return Dynamics(load_robot(name))


def system(name: str, **contact) -> TimeFreezingSystem:
    point = {"point_mass": "point", "capler": "foot"}[name]
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


@pytest.mark.parametrize("robot", ["point_mass", "capler"])
def test_wanted_selectors_give_f_dae_f_symbolically(robot):
    """No slip (Sec. 6 simplified): with (alpha*, beta*, gamma*, zeta*) = (0.5, 0, 0, 0.5), F is symbolically f_DAE,f."""
    s = system(robot, mu=0.8)
    assert s.models == (ContactModel.NO_SLIP,)
    pt = s.contacts[0].point
    assert structurally_zero(s.vector_field(s.wanted) - s.field(f"dae_f[{pt}]"))


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
    """Elastic model with beta = eta = 0 (c <= 0, p < 0): q and clock frozen, p' = n^T v,
    (n^T v)' = -k p - c n^T v."""
    s = system("point_mass", restitution=0.5, a_n=16.0)
    assert s.models == (ContactModel.ELASTIC,) and s.state_names[-2:] == ("p[point]", "t")
    k, c = oscillator_gains(0.5, 16.0)
    y, u = np.array([0.2, 0.0, 0.7, -1.5, -0.05, 0.4]), np.array([3.0, 1.0])
    F = np.asarray(ca.Function("F", [s.y, s.u], [s.vector_field(np.array([0.0, 0.0, 0.0]))])(y, u), dtype=float).ravel()
    np.testing.assert_allclose(F, [0, 0, 0, -k * -0.05 - c * -1.5, -1.5, 0], atol=1e-12)
    # flight (beta = eta = 1): f_ODE with p' = 0
    F = np.asarray(ca.Function("F", [s.y, s.u], [s.vector_field(np.array([0.5, 1.0, 1.0]))])(y, u), dtype=float).ravel()
    np.testing.assert_allclose(F, [0.7, -1.5, 3.0, 1.0 - 9.81, 0, 1], atol=1e-12)


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
