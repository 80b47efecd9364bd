"""Per-contact quantities of a point touching the ground plane z = ground_height (paper Secs. 4.1, 6).

For a named point with world position p(q):

* gap       c(q) = p_z(q) - ground_height [m]
* normal    n(q) = grad c(q) = J_z(q)^T (nv,)   (q' = v, so configuration and velocity gradients agree)
* tangent   t(q) = grad p_x(q) = J_x(q)^T (nv,) (planar contact: one tangent, paper Sec. 6)

A tilted plane (task key contacts.normal, unit surface normal s = (s_x, 0, s_z) through
(0, 0, ground_height)) replaces z by s and x by the in-plane tangent e = (s_z, 0, -s_x):
c = s^T p - s_z ground_height, n = J^T s, t = J^T e, and the drifts s^T (dJ/dt v), e^T (dJ/dt v).
The default s = (0, 0, 1) is the ground, built with the very expressions above.
* Delassus  D(q) = n^T M^-1 n [1/kg]
* phi(q, v, u) = n^T f_v + v^T grad^2 c v = d^2c/dt^2 without contact force [m/s^2], with
  v^T grad^2 c v = (dJ_z/dt) v the drift of the point
* index-reduced forces: frictionless lambda_n = -phi / D (eq. 16a); no slip
  lambda = (lambda_n, lambda_t) = -(J M^-1 J^T)^-1 (J f_v + dJ/dt v) with J = [n t]^T

All quantities are CasADi expressions of the symbols q (nq,), v (nv,), u (nu,) that the caller
passes in, so that one time-freezing system shares them.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca

from .dynamics import Dynamics
from .errors import InputError


@dataclass(frozen=True, eq=False)
class ContactTerms:
    """Symbolic contact quantities of one point (SX expressions of q, v, u); see the module docstring.

    Shapes: scalars are (1, 1); vectors (nv, 1). Units: SI (m, s, kg, N).
    """

    point: str
    gap: ca.SX  # c(q) [m]
    normal: ca.SX  # n(q) (nv,)
    tangent: ca.SX  # t(q) (nv,)
    minv_normal: ca.SX  # M^-1 n (nv,)
    minv_tangent: ca.SX  # M^-1 t (nv,)
    delassus: ca.SX  # D = n^T M^-1 n
    normal_velocity: ca.SX  # h1 = n^T v [m/s]
    tangential_velocity: ca.SX  # h4 = t^T v [m/s]
    phi: ca.SX  # h3 = n^T f_v + (dJ_z/dt) v [m/s^2]
    normal_drift: ca.SX  # v^T grad^2 c v = (dJ_z/dt) v [m/s^2]
    tangent_drift: ca.SX  # (dJ_x/dt) v [m/s^2]
    lambda_n: ca.SX  # frictionless contact force -phi / D [N] (eq. 16a)
    dae_v: ca.SX  # f_DAE,v = f_v + M^-1 n lambda_n (nv,) (eq. 16b)
    lambda_no_slip: ca.SX  # (lambda_n, lambda_t) (2,) for sticking contact [N]
    dae_no_slip_v: ca.SX  # f_DAE,f,v = f_v + M^-1 J^T lambda (nv,)


def plane_axes(surface) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """The contact plane's unit normal s = (s_x, 0, s_z) and in-plane tangent e = (s_z, 0, -s_x) (3,) each:
    the directions of the gap c and of the tangential coordinate (module docstring)."""
    sx, _, sz = surface
    return (sx, 0.0, sz), (sz, 0.0, -sx)


def contact_terms(dyn: Dynamics, point: str, ground_height: float, q, v, u, M=None, fv=None,
                  surface=(0.0, 0.0, 1.0)) -> ContactTerms:
    """Build the contact quantities of `point` from the robot's dynamics.

    q, v, u: CasADi symbols (nq,), (nv,), (nu,); M (nv, nv) and fv = M^-1 (B u - h) (nv,) may be
    passed when the caller already has them (they are then shared, not rebuilt). surface (3,): unit
    normal of the contact plane (module docstring), default the ground.
    Raises InputError when nq != nv (the contact dynamics use q' = v).
    """
    if dyn.nq != dyn.nv:
        raise InputError(f"contact dynamics need nq == nv (q' = v); robot {dyn.robot.name!r} has nq = {dyn.nq}, nv = {dyn.nv} "
                         "(free-flyer, planar or unbounded joints); use slide and hinge joints")
    M = dyn.mass(q) if M is None else M
    fv = dyn.forward(q, v, u) if fv is None else fv
    pos, jac, drift = dyn.point_position(point)(q), dyn.point_jacobian(point)(q), dyn.point_drift(point)(q, v)
    if tuple(surface) == (0.0, 0.0, 1.0):
        gap, n, t, drift_n, drift_t = pos[2] - ground_height, jac[2, :].T, jac[0, :].T, drift[2], drift[0]
    else:
        s, e = (ca.DM(d) for d in plane_axes(surface))
        gap = ca.dot(s, pos[:3]) - surface[2] * ground_height
        n, t = ca.mtimes(jac[:3, :].T, s), ca.mtimes(jac[:3, :].T, e)
        drift_n, drift_t = ca.dot(s, drift[:3]), ca.dot(e, drift[:3])
    minv_nt = ca.solve(M, ca.horzcat(n, t))  # one solve for both columns
    minv_n, minv_t = minv_nt[:, 0], minv_nt[:, 1]
    D = ca.dot(n, minv_n)
    phi = ca.dot(n, fv) + drift_n
    lambda_n = -phi / D
    # no slip: J = [n t]^T, J M^-1 J^T (2, 2) is the contact's Delassus matrix
    J = ca.horzcat(n, t).T
    G = ca.mtimes(J, minv_nt)
    lam = -ca.solve(G, ca.mtimes(J, fv) + ca.vertcat(drift_n, drift_t))
    return ContactTerms(
        point=point,
        gap=gap,
        normal=n,
        tangent=t,
        minv_normal=minv_n,
        minv_tangent=minv_t,
        delassus=D,
        normal_velocity=ca.dot(n, v),
        tangential_velocity=ca.dot(t, v),
        phi=phi,
        normal_drift=drift_n,
        tangent_drift=drift_t,
        lambda_n=lambda_n,
        dae_v=fv + minv_n * lambda_n,
        lambda_no_slip=lam,
        dae_no_slip_v=fv + ca.mtimes(minv_nt, lam),
    )


def contact_functions(dyn: Dynamics, point: str, ground_height: float) -> dict[str, ca.Function]:
    """Numeric CasADi Functions of (q, v, u) for every field of ContactTerms (tests, path constraints)."""
    q, v, u = ca.SX.sym("q", dyn.nq), ca.SX.sym("v", dyn.nv), ca.SX.sym("u", dyn.nu)
    terms = contact_terms(dyn, point, ground_height, q, v, u)
    names = [f for f in ContactTerms.__dataclass_fields__ if f != "point"]
    return {name: ca.Function(name, [q, v, u], [getattr(terms, name)], ["q", "v", "u"], [name]) for name in names}
