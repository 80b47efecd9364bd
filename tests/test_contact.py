"""Per-contact quantities (planner.contact) against closed forms and finite differences."""
from __future__ import annotations

import functools
from types import SimpleNamespace

import numpy as np
import pytest

from planner.contact import contact_functions, contact_terms
from planner.dynamics import Dynamics
from planner.errors import InputError
from planner.model import load_robot

G = 9.81
EXACT_TOL = 1e-12  # closed-form quantities of the point mass: only rounding
IDENTITY_TOL = 1e-9  # algebraic identities through a symbolic QR solve of a 4x4 mass matrix
FD_STEP = 1e-6  # central differences: truncation ~ step^2, rounding ~ eps/step
FD_TOL = 1e-6
FD2_STEP = 1e-4  # second differences: truncation ~ step^2 |d4p| ~ 1e-8, rounding ~ eps |p| / step^2 ~ 1e-8
FD2_TOL = 1e-5  # m/s^2 on Capler's drifts (|v| ~ 1 rad/s, so drifts ~ 0.1-1 m/s^2): both errors above, x100


@functools.cache
def dyn(name: str) -> Dynamics:
    return Dynamics(load_robot(name))


@functools.cache
def funcs(name: str, point: str, ground: float = 0.0) -> dict:
    return contact_functions(dyn(name), point, ground)


def ev(f, *args) -> np.ndarray:
    return np.asarray(f(*args), dtype=float).ravel()


def capler_states(n: int, seed: int = 0):
    """Random Capler states (q, v, u), seeded."""
    rng = np.random.default_rng(seed)
    for _ in range(n):
        q = np.array([rng.uniform(-1, 1), rng.uniform(0.2, 0.6), rng.uniform(-1, 1), rng.uniform(-1.2, 1.2)])
        yield q, rng.normal(size=4), rng.normal(scale=10.0, size=2)


def test_point_mass_closed_form():
    """Point mass (1 kg, q = (x, z)): c = z - ground, n = (0, 1), t = (1, 0), D = 1, phi = u_z - g,
    lambda_n = g - u_z, no-slip lambda = (g - u_z, -u_x) and both DAE fields as in Example 1."""
    f = funcs("point_mass", "point", 0.25)
    q, v, u = np.array([0.3, 0.7]), np.array([1.5, -2.0]), np.array([3.0, 4.0])
    expected = {
        "gap": [0.7 - 0.25], "normal": [0, 1], "tangent": [1, 0], "delassus": [1.0], "normal_velocity": [-2.0],
        "tangential_velocity": [1.5], "phi": [4.0 - G], "lambda_n": [G - 4.0], "dae_v": [3.0, 0.0],
        "lambda_no_slip": [G - 4.0, -3.0], "dae_no_slip_v": [0.0, 0.0],
    }
    for name, value in expected.items():
        np.testing.assert_allclose(ev(f[name], q, v, u), value, atol=EXACT_TOL, err_msg=name)


def test_capler_normal_tangent_are_gradients():
    """Capler foot: n = grad c and t = grad p_x (central differences of the gap and of p_x)."""
    f = funcs("capler", "foot")
    px = dyn("capler").point_position("foot")
    for q, v, u in capler_states(5):
        fd_n, fd_t = np.zeros(4), np.zeros(4)
        for i in range(4):
            dq = np.zeros(4)
            dq[i] = FD_STEP
            fd_n[i] = (ev(f["gap"], q + dq, v, u)[0] - ev(f["gap"], q - dq, v, u)[0]) / (2 * FD_STEP)
            fd_t[i] = (ev(px, q + dq)[0] - ev(px, q - dq)[0]) / (2 * FD_STEP)
        np.testing.assert_allclose(ev(f["normal"], q, v, u), fd_n, atol=FD_TOL)
        np.testing.assert_allclose(ev(f["tangent"], q, v, u), fd_t, atol=FD_TOL)


def test_capler_phi_is_second_derivative_of_gap():
    """phi = n^T f_v + v^T grad^2 c v, with the curvature term from central differences of n along v."""
    f, d = funcs("capler", "foot"), dyn("capler")
    for q, v, u in capler_states(5, seed=1):
        fv = ev(d.forward, q, v, u)
        dn = (ev(f["normal"], q + FD_STEP * v, v, u) - ev(f["normal"], q - FD_STEP * v, v, u)) / (2 * FD_STEP)
        expected = ev(f["normal"], q, v, u) @ fv + dn @ v
        np.testing.assert_allclose(ev(f["phi"], q, v, u), expected, atol=FD_TOL * 100)


def test_capler_index_reduction_keeps_contact():
    """Index reduction: with f_DAE,v the normal acceleration n^T v' + dJ_z v vanishes (eq. 16); with
    f_DAE,f,v both normal and tangential accelerations vanish; D = n^T M^-1 n > 0; lambda_n = -phi / D."""
    f, d = funcs("capler", "foot"), dyn("capler")
    drift = d.point_drift("foot")
    for q, v, u in capler_states(5, seed=2):
        n, t, dj = ev(f["normal"], q, v, u), ev(f["tangent"], q, v, u), ev(drift, q, v)
        M = np.asarray(d.mass(q), dtype=float)
        D = n @ np.linalg.solve(M, n)
        assert D > 0
        np.testing.assert_allclose(ev(f["delassus"], q, v, u), D, rtol=IDENTITY_TOL)
        np.testing.assert_allclose(ev(f["lambda_n"], q, v, u), -ev(f["phi"], q, v, u) / D, rtol=IDENTITY_TOL)
        a = ev(f["dae_v"], q, v, u)
        assert abs(n @ a + dj[2]) < IDENTITY_TOL * (1 + np.abs(a).max())
        a = ev(f["dae_no_slip_v"], q, v, u)
        assert abs(n @ a + dj[2]) < IDENTITY_TOL * (1 + np.abs(a).max())
        assert abs(t @ a + dj[0]) < IDENTITY_TOL * (1 + np.abs(a).max())


def test_tilted_plane_gap_is_the_signed_distance_to_the_plane_through_ground_height():
    """A plane tilted by theta = 0.4 rad (unit normal s = (-sin theta, 0, cos theta)) through the point (0, 0, g)
    with ground_height g = 0.25 m: the gap of the point mass at p = (x, 0, z) is s . (p - (0, 0, g)), at seeded
    random positions; the plane's own point (0, 0, g) has gap 0 (the plane passes through it for every tilt)."""
    import casadi as ca

    theta, g = 0.4, 0.25
    surface = (-np.sin(theta), 0.0, np.cos(theta))
    d = dyn("point_mass")
    q, v, u = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 2)
    gap = ca.Function("gap", [q], [contact_terms(d, "point", g, q, v, u, surface=surface).gap])
    assert ev(gap, np.array([0.0, g]))[0] == pytest.approx(0.0, abs=EXACT_TOL)
    rng = np.random.default_rng(3)
    for x, z in rng.uniform(-2.0, 2.0, size=(10, 2)):
        expected = np.dot(surface, np.array([x, 0.0, z]) - np.array([0.0, 0.0, g]))
        assert ev(gap, np.array([x, z]))[0] == pytest.approx(expected, abs=EXACT_TOL)


def test_capler_tilted_plane_velocities_and_drifts_are_derivatives_of_the_position():
    """Capler's foot on a 20-degree slope (task contact normal s = (-sin 20deg, 0, cos 20deg), in-plane tangent
    e = (cos 20deg, 0, sin 20deg)): at seeded random states (q, v), the normal and tangential velocities are d/dt of
    s . p(q + tau v) and e . p(q + tau v) at tau = 0, and the normal and tangent drifts (dJ/dt v, the point's
    acceleration at fixed v) are their second derivatives, both from central differences of Pinocchio's foot
    position alone; phi adds n^T f_v to the normal drift. (The tilted drifts were untested: a flipped sign of the
    tangent drift left the suite green.)"""
    import casadi as ca

    theta = np.deg2rad(20.0)
    s_axis = np.array([-np.sin(theta), 0.0, np.cos(theta)])
    e_axis = np.array([np.cos(theta), 0.0, np.sin(theta)])  # in the plane, x-ward: e . s = 0
    d = dyn("capler")
    q, v, u = ca.SX.sym("q", 4), ca.SX.sym("v", 4), ca.SX.sym("u", 2)
    terms = contact_terms(d, "foot", 0.1, q, v, u, surface=tuple(s_axis))
    names = ["normal_velocity", "tangential_velocity", "normal_drift", "tangent_drift", "phi", "normal"]
    f = ca.Function("tilted", [q, v, u], [getattr(terms, name) for name in names])
    pos = d.point_position("foot")
    h = FD2_STEP
    tangent_drifts = []
    for qk, vk, uk in capler_states(6, seed=4):
        out = dict(zip(names, (np.asarray(x, dtype=float).ravel() for x in f(qk, vk, uk))))
        p = {k: ev(pos, qk + k * h * vk) for k in (-1, 0, 1)}
        for axis, vel, drift in ((s_axis, "normal_velocity", "normal_drift"),
                                 (e_axis, "tangential_velocity", "tangent_drift")):
            fd_vel = axis @ (p[1] - p[-1]) / (2 * h)
            fd_acc = axis @ (p[1] - 2 * p[0] + p[-1]) / h**2
            assert out[vel][0] == pytest.approx(fd_vel, abs=FD2_TOL), vel
            assert out[drift][0] == pytest.approx(fd_acc, abs=FD2_TOL), drift
        fd_normal_acc = s_axis @ (p[1] - 2 * p[0] + p[-1]) / h**2
        expected_phi = out["normal"] @ ev(d.forward, qk, vk, uk) + fd_normal_acc
        assert out["phi"][0] == pytest.approx(expected_phi, abs=FD2_TOL), "phi"
        tangent_drifts.append(abs(out["tangent_drift"][0]))
    assert max(tangent_drifts) > 100 * FD2_TOL  # the states probe a drift well above the tolerance


def test_nq_different_from_nv_is_an_input_error():
    """A robot whose nq != nv (free flyer) is refused with a message naming the cause."""
    fake = SimpleNamespace(nq=7, nv=6, robot=SimpleNamespace(name="floating"))
    with pytest.raises(InputError, match="nq == nv"):
        contact_terms(fake, "foot", 0.0, None, None, None)
