"""Symbolic rigid-body dynamics of a parsed robot as CasADi SX functions.

`Dynamics(robot)` reads only the data of the Pinocchio model (joint types and placements, inertias,
armature, frames, gravity) and builds CasADi functions of the configuration q (nq,) and the
velocity v (nv,): mass matrix, bias forces, forward dynamics, point positions, Jacobians and
Jacobian drifts, and the configuration update q (+) dq.

Backends: `pinocchio.casadi` when it imports (Pinocchio built with CasADi support); otherwise
(pip wheels) the algorithms below, written over the same `pinocchio.Model`:

* Composite joints (Pinocchio's MJCF parser merges the joints of one body into one) are unrolled
  into a chain of elementary joints; the links between them are massless.
* Every supported joint has a constant motion subspace S in its own frame, so the recursions
  run in world-aligned coordinates about one world-fixed point: a body's spatial velocity is its
  parent's plus (Ad_oMi S) v_i, its acceleration is d/dt of that, joint forces are S^T of the
  summed spatial forces of the subtree (RNEA), and M(q) comes from composite inertias (CRBA).

Conventions are Pinocchio's: spatial vectors are (linear, angular); a free flyer's q is
(x, y, z, qx, qy, qz, qw) and its velocity (linear, angular) is expressed in the body frame; a
planar joint's q is (x, y, cos th, sin th) with velocity (vx, vy, w) in the joint frame; an
unbounded revolute's q is (cos th, sin th). SI units throughout: m, rad, kg, s, N, N m.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from math import factorial

import casadi as ca
import numpy as np
import pinocchio as pin

from .errors import InputError, expect
from .model import Robot

try:  # Pinocchio built with CasADi scalars (conda, robotpkg); the pip wheels lack it
    import pinocchio.casadi as cpin
except ImportError:
    cpin = None

BACKENDS = ("auto", "symbolic", "pinocchio.casadi")

# Pinocchio joint short names -> (kind, axis). Unaligned and composite joints are read from the model.
_E = np.eye(3)
_ELEMENTARY = {
    **{f"JointModelR{a}": ("revolute", _E[i]) for i, a in enumerate("XYZ")},
    **{f"JointModelRUB{a}": ("revolute_unbounded", _E[i]) for i, a in enumerate("XYZ")},
    **{f"JointModelP{a}": ("prismatic", _E[i]) for i, a in enumerate("XYZ")},
    "JointModelRevoluteUnaligned": ("revolute", None),
    "JointModelRevoluteUnboundedUnaligned": ("revolute_unbounded", None),
    "JointModelPrismaticUnaligned": ("prismatic", None),
    "JointModelPlanar": ("planar", None),
    "JointModelFreeFlyer": ("free", None),
}
# the robot files' names of the joint types the symbolic dynamics lacks
_FILE_TERMS = {"JointModelSpherical": "ball", "JointModelSphericalZYX": "ball", "JointModelMimic": "mimic",
               "JointModelTranslation": "translation", "JointModelHelical": "helical",
               "JointModelHelicalUnaligned": "helical", "JointModelUniversal": "universal"}

# Motion subspaces S (6, nv) in the joint frame, rows (linear, angular), for the multi-DoF joints.
_S_PLANAR = np.zeros((6, 3))
_S_PLANAR[0, 0] = _S_PLANAR[1, 1] = _S_PLANAR[5, 2] = 1.0
_S_FREE = np.eye(6)


class UnsupportedJointError(InputError):
    """The robot has a joint type the symbolic dynamics does not implement."""


@dataclass(frozen=True)
class _Link:
    """One elementary joint and the body it moves (massless inside a composite joint)."""

    parent: int  # index of the parent link, -1 for the world
    placement: pin.SE3  # parent link frame -> this joint's frame at q = neutral
    kind: str  # revolute, revolute_unbounded, prismatic, planar, free
    axis: np.ndarray | None  # unit axis of 1-DoF joints, None otherwise
    iq: int  # first configuration index
    nq: int
    iv: int  # first velocity index
    nv: int
    inertia: pin.Inertia | None  # None for the massless links inside a composite joint

    @property
    def subspace(self) -> np.ndarray:
        """Motion subspace S (6, nv) in the joint frame, rows (linear, angular)."""
        if self.kind == "planar":
            return _S_PLANAR
        if self.kind == "free":
            return _S_FREE
        zero = np.zeros(3)
        rows = (self.axis, zero) if self.kind == "prismatic" else (zero, self.axis)
        return np.concatenate(rows).reshape(6, 1)


def dynamics_for(robot: Robot, dynamics: Dynamics | None = None) -> Dynamics:
    """`dynamics` (built once, reused) after checking that it was built from the robot's file contents, else the
    robot's own Dynamics: another robot's mass would be planned with silently."""
    if dynamics is None:
        return Dynamics(robot)
    expect(dynamics, Dynamics, "dynamics")
    mine, theirs = dynamics.robot, robot
    if (mine.sha256, mine.nq, mine.nv, mine.dof_names) != (theirs.sha256, theirs.nq, theirs.nv, theirs.dof_names):  # --floating
        raise InputError(f"dynamics were built from {dynamics.robot.path}, not from the robot {robot.path}; build them "
                         "with Dynamics(robot) or leave dynamics out")
    return dynamics


class Dynamics:
    """CasADi functions of a robot's dynamics; built once, evaluated fast (SX).

    Attributes (casadi.Function unless noted). A Function called on numbers returns a casadi.DM matrix, its
    vectors columns (nv, 1): np.asarray(...).ravel() for a NumPy vector (nv,) (np.asarray of a column minus
    B u (nv,) broadcasts to (nv, nv) without an error):
      mass      (q) -> M (nv, nv) [kg, kg m, kg m^2], symmetric, armature included
      bias      (q, v) -> h column (nv, 1) = C(q, v) v + g(q) [N, N m], i.e. RNEA(q, v, 0)
      actuation B (nv, nu) numpy array: generalized forces = B u
      forward   (q, v, u) -> dv/dt column (nv, 1) = M^-1 (B u - h)
      integrate (q, dq) -> q (+) dq column (nq, 1): identity-plus for Euclidean joints, the group
                exponential (Pinocchio's integrate) for free-flyer, planar and unbounded joints;
                dq is a tangent vector (nv,), e.g. v * dt
      nq, nv, nu (int), backend ("symbolic" or "pinocchio.casadi")
    Per named point (MJCF site, URDF link): point_position, point_rotation, point_jacobian,
    frame_jacobian, point_drift; built on first use and cached.
    """

    def __init__(self, robot: Robot, backend: str = "auto"):
        expect(robot, Robot, "Dynamics' robot")  # a path or a name raised AttributeError deep inside
        if backend not in BACKENDS:
            raise InputError(f"unknown dynamics backend {backend!r}; valid: {', '.join(BACKENDS)}")
        if backend == "pinocchio.casadi" and cpin is None:
            raise InputError("backend 'pinocchio.casadi' requested but pinocchio.casadi does not import")
        use_cpin = cpin is not None and backend != "symbolic"
        self.robot = robot
        self.backend = "pinocchio.casadi" if use_cpin else "symbolic"
        self.nq, self.nv, self.nu = robot.nq, robot.nv, robot.nu
        self.actuation = robot.actuation_matrix
        self._q, self._v = ca.SX.sym("q", self.nq), ca.SX.sym("v", self.nv)
        self._terms = (_PinocchioCasadi if use_cpin else _Symbolic)(robot.model, self._q, self._v)
        q, v, u, dq = self._q, self._v, ca.SX.sym("u", self.nu), ca.SX.sym("dq", self.nv)
        M, h = self._terms.mass(), self._terms.bias()
        self.mass = ca.Function("mass", [q], [M], ["q"], ["M"])
        self.bias = ca.Function("bias", [q, v], [h], ["q", "v"], ["h"])
        self.forward = ca.Function("forward", [q, v, u], [ca.solve(M, ca.mtimes(ca.DM(self.actuation), u) - h)], ["q", "v", "u"], ["dv"])
        self.integrate = ca.Function("integrate", [q, dq], [self._terms.integrate(q, dq)], ["q", "dq"], ["q_next"])
        self._points: dict[str, dict[str, ca.Function]] = {}

    def point_position(self, name: str) -> ca.Function:
        """(q) -> position, a casadi.DM column (3, 1) [m], of a named point in the world frame."""
        return self._point(name)["position"]

    def point_rotation(self, name: str) -> ca.Function:
        """(q) -> rotation (3, 3) of a named point's frame: world coordinates of its axes."""
        return self._point(name)["rotation"]

    def point_jacobian(self, name: str) -> ca.Function:
        """(q) -> J (3, nv): the point's world-frame linear velocity is J v [m/s]."""
        return self._point(name)["jacobian"]

    def frame_jacobian(self, name: str) -> ca.Function:
        """(q) -> J (6, nv), Pinocchio's LOCAL_WORLD_ALIGNED frame Jacobian: rows (linear, angular)."""
        return self._point(name)["frame_jacobian"]

    def point_drift(self, name: str) -> ca.Function:
        """(q, v) -> dJ/dt v, a casadi.DM column (3, 1) [m/s^2]: the point's world-frame acceleration when dv/dt = 0."""
        return self._point(name)["drift"]

    def _point(self, name: str) -> dict[str, ca.Function]:
        if name not in self._points:
            R, p, J, drift = self._terms.frame(self.robot.frame_id(name))
            q, v = self._q, self._v
            tag = re.sub(r"[^A-Za-z0-9]+", "_", name).strip("_")  # CasADi function names: letters, digits, single _
            self._points[name] = {
                "position": ca.Function(f"position_{tag}", [q], [p], ["q"], ["p"]),
                "rotation": ca.Function(f"rotation_{tag}", [q], [R], ["q"], ["R"]),
                "jacobian": ca.Function(f"jacobian_{tag}", [q], [J[:3, :]], ["q"], ["J"]),
                "frame_jacobian": ca.Function(f"frame_jacobian_{tag}", [q], [J], ["q"], ["J"]),
                "drift": ca.Function(f"drift_{tag}", [q, v], [drift], ["q", "v"], ["dJv"]),
            }
        return self._points[name]


# --------------------------------------------------------------------------------------------
# Symbolic backend


def _skew(w) -> ca.SX:
    return ca.vertcat(ca.horzcat(0, -w[2], w[1]), ca.horzcat(w[2], 0, -w[0]), ca.horzcat(-w[1], w[0], 0))


def _sx(a: np.ndarray) -> ca.SX:
    return ca.SX(ca.DM(np.asarray(a, dtype=float)))


def _rotation(axis: np.ndarray, c, s) -> ca.SX:
    """Rotation by angle (cos c, sin s) about a unit axis: c I + s [a]x + (1 - c) a a^T."""
    aa = np.outer(axis, axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return _sx(np.eye(3) - aa) * c + _sx(K) * s + _sx(aa)


def _quat_matrix(x, y, z, w) -> ca.SX:
    """Rotation matrix of a unit quaternion (x, y, z, w), Eigen's formula."""
    return ca.vertcat(
        ca.horzcat(1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
        ca.horzcat(2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
        ca.horzcat(2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
    )


_SMALL_ANGLE2 = 1e-2  # below this theta^2 the series (5 terms, error < 1e-17) replaces the closed form


def _series(t2, exact, coeff) -> ca.SX:
    """f(theta) from theta^2 = t2: `exact(theta)` or, near 0, sum_k coeff(k) (-t2)^k.

    The closed form never sees theta = 0 (it gets a dummy 1), so values and derivatives stay finite.
    """
    small = t2 < _SMALL_ANGLE2
    theta = ca.sqrt(ca.if_else(small, 1.0, t2))
    return ca.if_else(small, sum(coeff(k) * (-t2) ** k for k in range(5)), exact(theta))


def _sin_over(t2):  # sin(th)/th
    return _series(t2, lambda t: ca.sin(t) / t, lambda k: 1 / factorial(2 * k + 1))


def _one_minus_cos_over(t2):  # (1 - cos th)/th^2
    return _series(t2, lambda t: (1 - ca.cos(t)) / t**2, lambda k: 1 / factorial(2 * k + 2))


def _th_minus_sin_over(t2):  # (th - sin th)/th^3
    return _series(t2, lambda t: (t - ca.sin(t)) / t**3, lambda k: 1 / factorial(2 * k + 3))


def _cos_half(t2):  # cos(th/2)
    return _series(t2, lambda t: ca.cos(t / 2), lambda k: 1 / (4**k * factorial(2 * k)))


def _sin_half_over(t2):  # sin(th/2)/th
    return _series(t2, lambda t: ca.sin(t / 2) / t, lambda k: 0.5 / (4**k * factorial(2 * k + 1)))


def _expand(model: pin.Model) -> tuple[list[_Link], list[int]]:
    """Elementary links of the model, parents first; joint_link[jid] is the link carrying joint jid's frame."""
    links: list[_Link] = []
    joint_link = [-1]
    for jid in range(1, model.njoints):
        parent = joint_link[model.parents[jid]]
        parts = _elementary(model.joints[jid], model.names[jid], model.jointPlacements[jid], model.joints[jid].idx_q, model.joints[jid].idx_v)
        for k, (placement, kind, axis, iq, nq, iv, nv) in enumerate(parts):
            inertia = model.inertias[jid] if k == len(parts) - 1 else None
            links.append(_Link(parent, placement, kind, axis, iq, nq, iv, nv, inertia))
            parent = len(links) - 1
        joint_link.append(parent)
    return links, joint_link


def _elementary(joint, name: str, placement: pin.SE3, iq: int, iv: int) -> list[tuple]:
    """(placement, kind, axis, iq, nq, iv, nv) of a joint's elementary joints, composites unrolled."""
    short = joint.shortname()
    if short == "JointModelComposite":
        composite, parts = joint.extract(), []
        for k, (sub, sub_placement) in enumerate(zip(composite.joints, composite.jointPlacements)):
            parts += _elementary(sub, name, placement * sub_placement if k == 0 else sub_placement, iq, iv)
            iq, iv = iq + sub.nq, iv + sub.nv
        return parts
    if short not in _ELEMENTARY:
        kind = _FILE_TERMS.get(short)  # (Pinocchio's class names alone left a robot file's author to translate them)
        raise UnsupportedJointError(
            f"joint {name!r} has type {short}{f' (a {kind} joint)' if kind else ''}, which the symbolic dynamics does "
            "not support; it takes hinge (revolute), slide (prismatic), planar and free joints"
        )
    kind, axis = _ELEMENTARY[short]
    if axis is None and kind in ("revolute", "revolute_unbounded", "prismatic"):  # unaligned: read S
        S = np.array(joint.createData().S, dtype=float).ravel()  # (linear, angular); not every binding has .axis
        axis = S[:3] if kind == "prismatic" else S[3:]
    return [(pin.SE3(placement), kind, axis, iq, joint.nq, iv, joint.nv)]


def _joint_motion(link: _Link, q) -> tuple[ca.SX, ca.SX]:
    """Joint transform (R, p): joint frame -> moved child frame, from the link's slice of q."""
    qj = q[link.iq : link.iq + link.nq]
    if link.kind == "revolute":
        return _rotation(link.axis, ca.cos(qj[0]), ca.sin(qj[0])), ca.SX.zeros(3)
    if link.kind == "revolute_unbounded":
        return _rotation(link.axis, qj[0], qj[1]), ca.SX.zeros(3)
    if link.kind == "prismatic":
        return ca.SX.eye(3), _sx(link.axis) * qj[0]
    if link.kind == "planar":
        return _rotation(_E[2], qj[2], qj[3]), ca.vertcat(qj[0], qj[1], 0)
    return _quat_matrix(qj[3], qj[4], qj[5], qj[6]), qj[:3]  # free


def _cross_motion(v, w, mv, mw) -> tuple[ca.SX, ca.SX]:
    """(v, w) x (mv, mw) for spatial motion vectors (linear, angular)."""
    return ca.cross(w, mv) + ca.cross(v, mw), ca.cross(w, mw)


class _Symbolic:
    """World-frame recursive algorithms over the unrolled model; all results are SX in (q, v).

    Spatial vectors are taken at a fixed point that coincides, at the evaluated q, with the frame
    origin of the first body with mass (a floating robot's base): the algorithms hold for any fixed
    origin, and positions relative to the robot keep M and h accurate far from the world origin
    (about the world origin, m |p|^2 terms would cancel to leave entries of size m |p - p_base|^2).
    """

    def __init__(self, model: pin.Model, q: ca.SX, v: ca.SX):
        self.model, self.q, self.v = model, q, v
        self.links, self.joint_link = _expand(model)
        self.R, self.p_world, self.p, self.S, self.vel, self.acc = [], [], [], [], [], []
        zero = ca.SX.zeros(3)
        for link in self.links:  # placements: R (world from link), p_world (link origin in the world)
            R0, p0 = (self.R[link.parent], self.p_world[link.parent]) if link.parent >= 0 else (ca.SX.eye(3), zero)
            R = ca.mtimes(R0, _sx(link.placement.rotation))
            p = p0 + ca.mtimes(R0, _sx(link.placement.translation))
            Rj, pj = _joint_motion(link, q)
            self.p_world.append(p + ca.mtimes(R, pj))
            self.R.append(ca.mtimes(R, Rj))
        massive = [i for i, link in enumerate(self.links) if link.inertia is not None and link.inertia.mass > 0]
        self.origin = self.p_world[massive[0]] if massive else zero
        for i, link in enumerate(self.links):  # motion: columns of S, velocities, accelerations at dv/dt = 0
            parent = link.parent
            v0, w0 = self.vel[parent] if parent >= 0 else (zero, zero)
            a0, al0 = self.acc[parent] if parent >= 0 else (zero, zero)
            R, p = self.R[i], self.p_world[i] - self.origin
            S = _sx(link.subspace)
            Sw = ca.mtimes(R, S[3:, :])  # spatial columns (R s_v + p x R s_w, R s_w)
            Sv = ca.mtimes(R, S[:3, :]) + ca.mtimes(_skew(p), Sw)
            vj = v[link.iv : link.iv + link.nv]
            jv, jw = ca.mtimes(Sv, vj), ca.mtimes(Sw, vj)
            vel = (v0 + jv, w0 + jw)
            cv, cw = _cross_motion(*vel, jv, jw)  # d/dt (Ad S) vj with dv/dt = 0
            self.p.append(p)
            self.S.append((Sv, Sw))
            self.vel.append(vel)
            self.acc.append((a0 + cv, al0 + cw))

    def _ancestors(self, i: int) -> list[int]:
        """Links from i to the root, i first."""
        out = []
        while i >= 0:
            out.append(i)
            i = self.links[i].parent
        return out

    def _world_inertia(self, i: int) -> tuple[ca.SX, ca.SX, ca.SX]:
        """(m, m c, I_o) of link i, world-aligned: mass, first moment, rotational inertia about the origin."""
        inertia = self.links[i].inertia
        R = self.R[i]
        c = self.p[i] + ca.mtimes(R, _sx(inertia.lever))
        m = float(inertia.mass)
        Ic = ca.mtimes([R, _sx(inertia.inertia), R.T])
        return ca.SX(m), m * c, Ic - m * ca.mtimes(_skew(c), _skew(c))

    def mass(self) -> ca.SX:
        """CRBA: column block i is S_j^T (composite inertia of subtree i) S_i for every ancestor j of i."""
        n = len(self.links)
        comp = [self._world_inertia(i) if self.links[i].inertia is not None else (ca.SX(0), ca.SX.zeros(3), ca.SX.zeros(3, 3)) for i in range(n)]
        for i in reversed(range(n)):
            parent = self.links[i].parent
            if parent >= 0:
                comp[parent] = tuple(a + b for a, b in zip(comp[parent], comp[i]))
        M = ca.SX.zeros(self.model.nv, self.model.nv)
        for i, link in enumerate(self.links):
            m, mc, Io = comp[i]
            Sv, Sw = self.S[i]
            Fv = m * Sv - ca.mtimes(_skew(mc), Sw)
            Fw = ca.mtimes(_skew(mc), Sv) + ca.mtimes(Io, Sw)
            cols = slice(link.iv, link.iv + link.nv)
            for j in self._ancestors(i):
                rows = slice(self.links[j].iv, self.links[j].iv + self.links[j].nv)
                block = ca.mtimes(self.S[j][0].T, Fv) + ca.mtimes(self.S[j][1].T, Fw)
                M[rows, cols] = block
                if j != i:
                    M[cols, rows] = block.T
        return M + ca.diag(_sx(self.model.armature))

    def bias(self) -> ca.SX:
        """RNEA with dv/dt = 0: h = S^T of the subtree's spatial forces f = I (a - g) + v x* (I v)."""
        g = _sx(self.model.gravity.linear)
        forces = []
        for i, link in enumerate(self.links):
            if link.inertia is None:
                forces.append((ca.SX.zeros(3), ca.SX.zeros(3)))
                continue
            m, mc, Io = self._world_inertia(i)
            (v, w), (a, al) = self.vel[i], self.acc[i]

            def apply(lin, ang):  # spatial inertia times a motion vector: (m lin - mc x ang, mc x lin + Io ang)
                return m * lin - ca.cross(mc, ang), ca.cross(mc, lin) + ca.mtimes(Io, ang)

            fa, na = apply(a - g, al)
            hv, hw = apply(v, w)
            forces.append((fa + ca.cross(w, hv), na + ca.cross(w, hw) + ca.cross(v, hv)))
        h = ca.SX.zeros(self.model.nv)
        for i in reversed(range(len(self.links))):
            link, (f, n) = self.links[i], forces[i]
            Sv, Sw = self.S[i]
            h[link.iv : link.iv + link.nv] = ca.mtimes(Sv.T, f) + ca.mtimes(Sw.T, n)
            if link.parent >= 0:
                pf, pn = forces[link.parent]
                forces[link.parent] = (pf + f, pn + n)
        return h

    def frame(self, fid: int) -> tuple[ca.SX, ca.SX, ca.SX, ca.SX]:
        """(R (3,3), p (3,), J (6,nv) LOCAL_WORLD_ALIGNED, classical acceleration at dv/dt = 0 (3,))."""
        frame = self.model.frames[fid]
        i = self.joint_link[frame.parentJoint]
        J = ca.SX.zeros(6, self.model.nv)
        if i < 0:  # fixed to the world
            return _sx(frame.placement.rotation), _sx(frame.placement.translation), J, ca.SX.zeros(3)
        R = ca.mtimes(self.R[i], _sx(frame.placement.rotation))
        offset = ca.mtimes(self.R[i], _sx(frame.placement.translation))
        p = self.p[i] + offset  # from the origin of the spatial vectors
        for j in self._ancestors(i):
            link, (Sv, Sw) = self.links[j], self.S[j]
            J[:3, link.iv : link.iv + link.nv] = Sv - ca.mtimes(_skew(p), Sw)  # s_v + s_w x p
            J[3:, link.iv : link.iv + link.nv] = Sw
        (v, w), (a, al) = self.vel[i], self.acc[i]
        vp = v + ca.cross(w, p)
        return R, self.p_world[i] + offset, J, a + ca.cross(al, p) + ca.cross(w, vp)

    def integrate(self, q: ca.SX, dq: ca.SX) -> ca.SX:
        """q (+) dq per elementary joint, as pinocchio.integrate."""
        out = []
        for link in self.links:
            qj, d = q[link.iq : link.iq + link.nq], dq[link.iv : link.iv + link.nv]
            if link.kind in ("revolute", "prismatic"):
                out.append(qj + d)
            elif link.kind == "revolute_unbounded":
                c, s = ca.cos(d[0]), ca.sin(d[0])
                out.append(ca.vertcat(qj[0] * c - qj[1] * s, qj[1] * c + qj[0] * s))
            elif link.kind == "planar":  # SE(2) exponential in the joint frame
                t2 = d[2] ** 2
                A, B = _sin_over(t2), _one_minus_cos_over(t2) * d[2]
                c0, s0 = qj[2], qj[3]
                lx, ly = A * d[0] - B * d[1], B * d[0] + A * d[1]
                c, s = ca.cos(d[2]), ca.sin(d[2])
                out.append(ca.vertcat(qj[0] + c0 * lx - s0 * ly, qj[1] + s0 * lx + c0 * ly, c0 * c - s0 * s, s0 * c + c0 * s))
            else:  # free: SE(3) exponential of the body twist (linear, angular)
                lin, w = d[:3], d[3:]
                t2 = ca.dot(w, w)
                W = _skew(w)
                V = ca.SX.eye(3) + _one_minus_cos_over(t2) * W + _th_minus_sin_over(t2) * ca.mtimes(W, W)
                R0 = _quat_matrix(qj[3], qj[4], qj[5], qj[6])
                x, y, z, qw = qj[3], qj[4], qj[5], qj[6]
                e, ew = _sin_half_over(t2) * w, _cos_half(t2)  # exp(w): (e, ew) as (xyz, w)
                quat = ca.vertcat(
                    qw * e[0] + x * ew + y * e[2] - z * e[1],
                    qw * e[1] - x * e[2] + y * ew + z * e[0],
                    qw * e[2] + x * e[1] - y * e[0] + z * ew,
                    qw * ew - x * e[0] - y * e[1] - z * e[2],
                )
                out.append(ca.vertcat(qj[:3] + ca.mtimes(R0, ca.mtimes(V, lin)), quat))
        return ca.vertcat(*out) if out else ca.SX.zeros(0)


class _PinocchioCasadi:
    """The same terms from pinocchio.casadi (used when it imports; not available in pip wheels)."""

    def __init__(self, model: pin.Model, q: ca.SX, v: ca.SX):
        self.model, self.q, self.v = model, q, v
        self.cmodel = cpin.Model(model)
        self.cdata = self.cmodel.createData()

    def mass(self) -> ca.SX:
        M = cpin.crba(self.cmodel, self.cdata, self.q)
        return ca.triu(M) + ca.triu(M, False).T  # Pinocchio may fill only the upper triangle

    def bias(self) -> ca.SX:
        return cpin.rnea(self.cmodel, self.cdata, self.q, self.v, ca.SX.zeros(self.model.nv))

    def frame(self, fid: int):
        c, d = self.cmodel, self.cdata
        cpin.computeJointJacobians(c, d, self.q)
        cpin.forwardKinematics(c, d, self.q, self.v, ca.SX.zeros(self.model.nv))
        cpin.updateFramePlacements(c, d)
        J = cpin.getFrameJacobian(c, d, fid, pin.LOCAL_WORLD_ALIGNED)
        drift = cpin.getFrameClassicalAcceleration(c, d, fid, pin.LOCAL_WORLD_ALIGNED).linear
        return d.oMf[fid].rotation, d.oMf[fid].translation, J, drift

    def integrate(self, q: ca.SX, dq: ca.SX) -> ca.SX:
        return cpin.integrate(self.cmodel, q, dq)
