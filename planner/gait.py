"""Periodic gaits of the three-link biped with torso (paper 001, Spedicato & Notarstefano 2017).

Everything is derived from the robot file through `Dynamics` (no biped equations are written here):

- **Pinned stance model** (`PinnedBiped`): the floating planar robot (slides x, z; hinge `torso` =
  theta3; leg hinges with absolute leg angle theta_i = theta3 + hinge_i) with the stance foot fixed at
  the origin. The coordinates theta = (theta1 stance leg, theta2 swing leg, theta3 torso) [rad]
  parameterize the constrained configurations through q(theta) (the hip is placed so that the
  stance foot is at the origin), and the reduced dynamics is the exact Lagrangian reduction
  M_r = Jq' M Jq, h_r = Jq' (M dJq/dt theta' + h), B_r = Jq' B, with Jq = dq/dtheta (5, 3).
- **Impact map** Delta: inelastic, no-slip impact of the swing foot on the floating model (impulse
  through the swing foot's Jacobian, the stance foot lifts off), then the legs are relabelled
  (theta+ = R theta-, R swaps theta1 and theta2): theta'+ = A(theta-) theta'-.

Input convention: u = (u_stance, u_swing) are the robot's motor commands on the stance and swing
hip hinges [N m] (positive = increases hinge_i = theta_i - theta3). The paper's inputs (B.4) act
with the opposite sign: u_paper = -u. Reports in docs/biped.md give both where it matters.

The periodic-orbit OCP x(T) = Delta^-1(x0) is solved with the three steps of the paper's Sec. 3
(`solve_gait`): dynamics embedding with a fictitious torso torque, penalty relaxation with doubling
continuation on rho_emb and rho_f, and Newton root finding on the target x_T; the inner solver is
PRONTO (`planner.pronto`). `solve_gait_ipopt` solves the same discretized OCP directly.
"""
from __future__ import annotations

import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path

import casadi as ca
import numpy as np
import pinocchio as pin

from .dynamics import Dynamics, dynamics_for
from .errors import (InputError, SolveError, TaskError, UnknownNameError, check_field_types, enum_field, expect,
                     interruptible, is_integer, plain, real_array, shown)
from .model import Robot
from .pronto import DiscreteOCP, Pronto, ProntoOptions
from .result import CONE_SLACK, ON_PLANE_M, ArraysReadOnly, outside_range_lines, task_path, write_files
from .simulate import joints_outside_range
from .task import MAX_STEPS, Contact, GaitContinuation, GaitPronto, Simulate, Task, task_source, task_to_json

# The leg swap of the relabelling: the swing leg becomes the stance leg (paper eq. 11).
RELABEL = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class BipedLayout:
    """Where the seed's angles live in the robot file (velocity indices and point names)."""

    x: int  # slide along the walking direction
    z: int  # vertical slide
    torso: int  # hinge of the base: theta3
    stance_hinge: int  # hinge of the stance leg: theta1 = theta3 + q[stance_hinge]
    swing_hinge: int
    stance_foot: str
    swing_foot: str
    stance_motor: int  # actuator index driving stance_hinge
    swing_motor: int


def find_layout(robot: Robot, stance_foot: str = "foot_1", swing_foot: str = "foot_2") -> BipedLayout:
    """Read the floating planar biped layout (docs/biped.md, "Model, derived from the robot file") from a robot file.

    The root joints must be two slides along x and z and a hinge about y; each foot's parent joint
    is its leg hinge, driven by exactly one motor. Raises InputError when the file is not laid out so.
    """
    model = robot.model
    for key, foot in (("gait.stance", stance_foot), ("gait.swing", swing_foot)):
        if foot not in robot.points:  # (the task key named, as the task's other names are)
            raise UnknownNameError("point", foot, robot.points, key)
    if robot.nq != robot.nv or robot.nq != 5:
        raise InputError(f"{robot.path}: the gait needs the floating planar biped (slide x, slide z, torso hinge, two leg "
                         f"hinges: nq = nv = 5); this robot has nq = {robot.nq}, nv = {robot.nv}")
    names = robot.dof_names

    def leg_hinge(foot: str) -> int:
        joint = model.frames[robot.frame_id(foot)].parentJoint
        return int(model.joints[joint].idx_v)

    stance, swing = leg_hinge(stance_foot), leg_hinge(swing_foot)
    if stance == swing:
        raise InputError(f"{robot.path}: feet {stance_foot!r} and {swing_foot!r} must hang from two different leg "
                         "hinges")
    motors = {a.dof: j for j, a in enumerate(robot.actuators)}
    for key, foot, dof in (("stance", stance_foot, stance), ("swing", swing_foot, swing)):
        if dof not in motors:  # gait.stance = "torso_top" read "leg hinge 'x' has no motor"
            raise InputError(f"{robot.path}: the {key} foot {foot!r} is not on a motor-driven leg hinge: it moves "
                             f"with joint {names[dof]!r}, which has no motor; the gait needs one motor per hip")
    root = [i for i in range(5) if i not in (stance, swing)]
    if len(root) != 3:
        raise InputError(f"{robot.path}: feet {stance_foot!r} and {swing_foot!r} must hang from two different leg hinges")
    # the root's motions at the neutral posture, in world axes at its joint: slide x, slide z, hinge about +y in order
    # (taken by position, a file with z before x had its hip's x put into the z slide)
    data, holder = model.createData(), next(j for j in range(1, model.njoints)
                                            if model.idx_vs[j] <= root[2] < model.idx_vs[j] + model.nvs[j])
    pin.computeJointJacobians(model, data, pin.neutral(model))
    motions = pin.getJointJacobian(model, data, holder, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)[:, root]
    if not np.allclose(motions, np.eye(6)[:, [0, 2, 4]], rtol=0.0, atol=1e-9):
        raise InputError(f"{robot.path}: the gait needs the root joints in the order slide x (axis 1 0 0), slide z "
                         f"(0 0 1), hinge about y (0 1 0); this file's are {', '.join(names[i] for i in root)}: "
                         "reorder or re-axis them")
    return BipedLayout(x=root[0], z=root[1], torso=root[2], stance_hinge=stance, swing_hinge=swing,
                       stance_foot=stance_foot, swing_foot=swing_foot,
                       stance_motor=motors[stance], swing_motor=motors[swing])


class PinnedBiped:
    """The stance-phase (pinned) model and the impact map of a floating planar biped robot file.

    State x = (theta (3,), theta' (3,)) [rad, rad/s]; inputs u = (u_stance, u_swing) [N m] (motor
    convention, see the module docstring) and the fictitious torso torque u_emb [N m] acting on
    theta3 (paper eq. 14's third column). CasADi functions (SX):

      q_of      (theta) -> q (nq,): floating configuration with the stance foot at the origin
      v_of      (theta, theta') -> v (nv,)
      mass      (theta) -> M_r (3, 3) [kg m^2]
      bias      (theta, theta') -> h_r (3,) = C + G [N m]
      actuation (theta) -> B_r (3, 2): generalized forces B_r u
      xdot      (x, ue) -> dx/dt (6,), ue = (u_stance, u_swing, u_emb)
      impact    (theta-) -> A (3, 3): theta'+ = A theta'- (relabelled)
      impulse   (x-) -> Lambda (2,) [N s]: swing-foot impulse (x, z) of the impact
      swing_height (theta) -> z of the swing foot [m] (stance foot at z = 0)
    """

    def __init__(self, robot: Robot, dynamics: Dynamics | None = None, layout: BipedLayout | None = None):
        self.robot = robot
        expect(robot, Robot, "PinnedBiped's robot")
        self.dyn = dynamics_for(robot, dynamics)
        self.layout = lay = layout or find_layout(robot)
        th, thd = ca.SX.sym("theta", 3), ca.SX.sym("dtheta", 3)
        # angles of the floating model: torso = theta3, hinge_i = theta_i - theta3
        L = np.zeros((5, 3))
        L[lay.torso, 2] = 1.0
        L[lay.stance_hinge, :] = [1.0, 0.0, -1.0]
        L[lay.swing_hinge, :] = [0.0, 1.0, -1.0]
        angles = ca.mtimes(ca.DM(L), th)
        foot = self.dyn.point_position(lay.stance_foot)(angles)  # stance foot seen from the hip (x = z = 0)
        q = angles + ca.DM(np.eye(5)[:, lay.x]) * (-foot[0]) + ca.DM(np.eye(5)[:, lay.z]) * (-foot[2])
        Jq = ca.jacobian(q, th)  # (5, 3)
        v = ca.mtimes(Jq, thd)
        Jdot_thd = ca.mtimes(ca.jacobian(v, th), thd)  # d/dt(Jq) theta'
        M, h = self.dyn.mass(q), self.dyn.bias(q, v)
        Mr = ca.mtimes([Jq.T, M, Jq])
        hr = ca.mtimes(Jq.T, ca.mtimes(M, Jdot_thd) + h)
        B = np.zeros((5, 2))
        B[:, 0] = self.dyn.actuation[:, lay.stance_motor]
        B[:, 1] = self.dyn.actuation[:, lay.swing_motor]
        Br = ca.mtimes(Jq.T, ca.DM(B))
        self.q_of = ca.Function("q_of", [th], [q])
        self.v_of = ca.Function("v_of", [th, thd], [v])
        self.mass = ca.Function("mass_pinned", [th], [Mr])
        self.bias = ca.Function("bias_pinned", [th, thd], [hr])
        self.actuation = ca.Function("actuation_pinned", [th], [Br])
        self.embedding = np.array([0.0, 0.0, 1.0])  # u_emb is a generalized torque on theta3
        ue = ca.SX.sym("ue", 3)
        Y = ca.horzcat(Br, ca.DM(self.embedding))
        self.xdot = ca.Function("xdot_pinned", [ca.vertcat(th, thd), ue],
                                [ca.vertcat(thd, ca.solve(Mr, ca.mtimes(Y, ue) - hr))])
        dd = ca.SX.sym("dd", 3)
        self.inverse = ca.Function("inverse_pinned", [th, thd, dd], [ca.solve(Y, ca.mtimes(Mr, dd) + hr)])

        # impact: M (v+ - v-) = Js' Lambda, Js v+ = 0 on the floating model (swing foot x and z rows)
        Js = self.dyn.point_jacobian(lay.swing_foot)(q)[[0, 2], :]
        Minv_Jt = ca.solve(M, Js.T)
        Lam_per_v = -ca.solve(ca.mtimes(Js, Minv_Jt), Js)  # Lambda = Lam_per_v v-
        v_plus_per_thd = ca.mtimes(ca.DM.eye(5) + ca.mtimes(Minv_Jt, Lam_per_v), Jq)
        # back to leg angles (theta' = L^+ v on the angle rows), then swap the legs
        Lpinv = np.linalg.pinv(L)
        A = ca.mtimes([ca.DM(RELABEL), ca.DM(Lpinv), v_plus_per_thd])
        self.impact = ca.Function("impact_matrix", [th], [A])
        self.impulse = ca.Function("impact_impulse", [ca.vertcat(th, thd)], [ca.mtimes([Lam_per_v, Jq, thd])])
        self.swing_height = ca.Function("swing_height", [th], [self.dyn.point_position(lay.swing_foot)(q)[2]])
        # ground reaction on the stance foot (x, z) [N]: J' lambda = M dv/dt + h - B u on the floating model
        u2 = ca.SX.sym("u", 2)
        thdd = ca.solve(Mr, ca.mtimes(Br, u2) - hr)
        vdot = ca.mtimes(Jq, thdd) + Jdot_thd
        Jst = self.dyn.point_jacobian(lay.stance_foot)(q)[[0, 2], :]
        rhs = ca.mtimes(M, vdot) + h - ca.mtimes(ca.DM(B), u2)
        self.stance_force = ca.Function("stance_force", [ca.vertcat(th, thd), u2],
                                        [ca.solve(ca.mtimes(Jst, Jst.T), ca.mtimes(Jst, rhs))])

    def delta(self, x) -> np.ndarray:
        """Impact map Delta(x-) (6,): post-impact, relabelled state."""
        x = np.asarray(x, float)
        return np.concatenate([RELABEL @ x[:3], np.array(self.impact(x[:3])) @ x[3:]])

    def delta_inverse(self, x_plus) -> np.ndarray:
        """Delta^-1(x+) (6,): the pre-impact state that jumps to x+ (R is its own inverse)."""
        x_plus = np.asarray(x_plus, float)
        theta = RELABEL @ x_plus[:3]
        return np.concatenate([theta, np.linalg.solve(np.array(self.impact(theta)), x_plus[3:])])

    def floating(self, theta, dtheta, foot_x: float = 0.0, swapped: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Floating-robot state (q (nq,), v (nv,)) of a pinned state with the stance foot at x = foot_x.

        swapped: the stance leg is the file's swing leg (odd steps of a walk): the hinges swap.
        """
        q = np.array(self.q_of(theta)).ravel()
        v = np.array(self.v_of(theta, dtheta)).ravel()
        lay = self.layout
        q[lay.x] += foot_x
        if swapped:
            for a in (q, v):
                a[[lay.stance_hinge, lay.swing_hinge]] = a[[lay.swing_hinge, lay.stance_hinge]]
        return q, v


# ==================================================================================================
# the periodic-orbit OCP (paper 001, Secs. 2-3)
# ==================================================================================================

class DesiredInput(Enum):
    """u_d of the cost: the desired curve's inverse-dynamics input (gait 1) or zero (gait 2)."""

    INVERSE_DYNAMICS = "inverse_dynamics"
    ZERO = "zero"


@dataclass(frozen=True, eq=False)  # arrays: equal by identity, hashable
class GaitSpec(ArraysReadOnly):
    """The numbers of one gait OCP (from a task's [gait] table and horizon).

    T [s] period, N grid steps (RK4, zero-order-hold inputs), x0 (6,) initial pinned state,
    Q (6,), R (2,) diagonal weights, desired input mode, and the task's continuation and PRONTO
    settings (planner.task.GaitContinuation, GaitPronto).
    """

    T: float
    N: int
    x0: np.ndarray
    jump_angle: float
    Q: np.ndarray
    R: np.ndarray
    desired_input: DesiredInput
    continuation: GaitContinuation
    pronto: GaitPronto

    def __post_init__(self):
        object.__setattr__(self, "N", plain(self.N))  # np.int64 was refused as "not an integer"
        # N = 1 has no inner node, where the swing foot's clearance is read: a ValueError after 60 outer loops
        if not (isinstance(self.N, int) and not isinstance(self.N, bool) and 2 <= self.N <= MAX_STEPS):
            raise InputError(f"GaitSpec.N = {shown(self.N)} is not allowed; a gait's horizon.N must be an integer in "
                             f"[2, {MAX_STEPS}] (the swing foot's clearance is read at the inner nodes)")
        check_field_types(self)  # T, jump_angle
        if not self.T > 0:
            raise InputError(f"GaitSpec.T = {self.T!r} is not allowed; it must be > 0 [s]")
        # a mode given by its value ("zero") fell through to the zero input whatever it named
        enum_field(self, "desired_input", DesiredInput)
        expect(self.continuation, GaitContinuation, "GaitSpec.continuation")
        expect(self.pronto, GaitPronto, "GaitSpec.pronto")
        rules = {"x0": (6, "", np.isfinite), "Q": (6, " >= 0", lambda a: a >= 0), "R": (2, " > 0", lambda a: a > 0)}
        for name, (n, sign, ok) in rules.items():
            value = real_array(getattr(self, name), f"GaitSpec.{name}")
            if value.shape != (n,) or not np.all(np.isfinite(value) & ok(value)):
                raise InputError(f"GaitSpec.{name} = {getattr(self, name)!r} is not allowed; "
                                 f"it must be {n} finite numbers{sign}")
            object.__setattr__(self, name, value)
        super().__post_init__()

    @classmethod
    def from_task(cls, task: Task, N: int | None = None) -> GaitSpec:
        """From a task with a [gait] table; N overrides horizon.N (e.g. a coarser grid in CI)."""
        g = task.gait
        if g is None:
            raise TaskError(f"{task_source(task) or 'the task'} has no [gait] table; `planner gait` needs one (docs/tasks.md)")
        # the gait model stands on z = 0 with the period tau_f: these were ignored (a ground at 0.3 m planned the same
        # gait, then MuJoCo's replay on the moved ground "fell" after one step)
        ignored = [f"ground_height = {task.ground_height:g}"] if task.ground_height != 0 else []
        ignored += [f"contacts[{i}].normal = {list(c.normal)}" for i, c in enumerate(task.contacts)
                    if c.normal != (0.0, 0.0, 1.0)]
        ignored += [f"contacts[{i}].restitution = {c.restitution:g}" for i, c in enumerate(task.contacts)
                    if c.restitution]
        ignored += [f"contacts[{i}].touches = false" for i, c in enumerate(task.contacts) if not c.touches]
        # (the time-freezing gains and `simulate`'s table were dropped unsaid too)
        ignored += [f"contacts[{i}].{key} = {getattr(c, key):g}" for i, c in enumerate(task.contacts)
                    for key in ("a_n", "a_t") if getattr(c, key) != getattr(Contact, key)]
        if task.horizon.physical_time is not None:
            ignored.append(f"horizon.physical_time = {task.horizon.physical_time:g}")
        ignored += ["[simulate]"] * (task.simulate != Simulate())  # ([plan] beside [gait] is refused by parse_task)
        if ignored:
            raise TaskError(f"{task_source(task) or 'the task'}: {', '.join(ignored)} would be ignored by `planner gait`, "
                            "whose model walks on the ground z = 0 with the period horizon.tau_f and lands with paper "
                            "001's inelastic impact map; remove them")
        if N is None and task.horizon.N < 2:  # (said of the file, as its other values are, not of GaitSpec)
            raise TaskError(f"{task_source(task) or 'the task'}: horizon.N = {task.horizon.N} is not allowed; a gait's "
                            f"horizon.N must be an integer in [2, {MAX_STEPS}] (its swing foot's clearance is read at "
                            "the inner nodes)")
        return cls(T=task.horizon.tau_f, N=task.horizon.N if N is None else N, x0=np.array(g.x0, float), jump_angle=g.jump_angle,
                   Q=np.array(g.q_weights, float), R=np.array(g.r_weights, float),
                   desired_input=DesiredInput(g.desired_input), continuation=g.continuation, pronto=g.pronto)


STOPPED = "stop: max_outer"  # an outer loop's action when it is the last one gait.continuation.max_outer allows


@dataclass(frozen=True)
class OuterLoop:
    """One outer loop of the strategy (one PRONTO solve): the progress record.

    stage: "embedding" (step 2) or "final_state" (step 3); action: what the loop does next
    ("rho_emb x factor", "drop u_emb", "rho_f x factor", "newton x_T", "done", or STOPPED: the last loop of
    max_outer); emb_max max |u_emb| [N m];
    final_error ||x(T) - Delta^-1(x0)|| (2-norm over rad, rad/s).
    """

    index: int
    stage: str
    rho_emb: float | None
    rho_f: float
    cost: float
    pronto_iterations: int
    pronto_converged: bool
    pronto_polished: bool  # its converged solve took and kept the final full Newton step (ProntoResult.polished)
    emb_max: float | None
    final_error: float
    action: str
    time_s: float  # [s] since the gait solve began, at this loop's end (cumulative: the last is about solve_time_s)

    def line(self) -> str:
        emb = f" max|u_emb| {self.emb_max:.2e} N m," if self.emb_max is not None else ""
        rho = f"rho_emb {self.rho_emb:.4g}, " if self.rho_emb is not None else ""
        # a converged solve may end with a full Newton step that is not counted (pronto.py): "0 PRONTO it." moved x(T)
        polish = " + its final full step, not counted" if self.pronto_polished and not self.pronto_iterations else ""
        return (f"[{self.index:2d}] {self.stage:11s} {rho}rho_f {self.rho_f:.4g}: cost {self.cost:.6g},{emb} "
                f"||x(T) - x_f|| {self.final_error:.2e}, {self.pronto_iterations} PRONTO it.{polish} -> {self.action}")


@dataclass(frozen=True, eq=False)
class GaitSolution(ArraysReadOnly):
    """A gait: t (N+1,) [s], x (N+1, 6), u (N, 2) [N m, motor convention]; the desired curve
    xd (N+1, 6), ud (N, 2); the step-2 (embedding) trajectory x_emb (N+1, 6), u_emb (N, 3);
    xf = Delta^-1(x0) (6,); the outer loops and totals."""

    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    xd: np.ndarray
    ud: np.ndarray
    x_emb: np.ndarray
    u_emb: np.ndarray
    xf: np.ndarray
    x_target: np.ndarray
    K: np.ndarray  # (N, 2, 6) LQR gains of the final projection: u = u_k + K_k (x_k - x) stabilizes the step
    cost: float  # the OCP (5) objective: 1/2 sum dt (||x - xd||_Q^2 + ||u - ud||_R^2), no penalty
    final_error: float
    converged: bool
    loops: tuple[OuterLoop, ...]
    pronto_iterations: int
    solve_time_s: float
    message: str = ""


@dataclass(frozen=True, eq=False)
class PinnedGait(ArraysReadOnly):
    """One step of a gait on the pinned model, what the walk replay needs (a GaitSolution is one too):
    t (N+1,) [s] increasing, not necessarily uniform; x (N+1, 6) pinned states from the post-impact
    state of the last landing to the pre-impact state of the next; u (N, 2) [N m, motor convention]
    held over each interval; K (N, 2, 6) LQR gains or None (only WalkControl.LQR uses them)."""

    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    K: np.ndarray | None = None


def desired_curve(model: PinnedBiped, x0: np.ndarray, xf: np.ndarray, T: float, N: int):
    """The paper's desired curve: per angle, the cubic Hermite spline with the values and slopes
    of x0 at t = 0 and xf at t = T, differentiated exactly; its embedded input by inverse dynamics.

    Returns t (N+1,), xd (N+1, 6), ude (N+1, 3) = (u_stance, u_swing, u_emb) [N m].
    """
    t = np.linspace(0.0, T, N + 1)
    s = t / T
    h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
    # d/dt = (1/T) d/ds: the basis for the tangents (scaled by T) loses that T once per derivative
    d00, d10, d01, d11 = (6 * s**2 - 6 * s) / T, 3 * s**2 - 4 * s + 1, (-6 * s**2 + 6 * s) / T, 3 * s**2 - 2 * s
    e00, e10, e01, e11 = (12 * s - 6) / T**2, (6 * s - 4) / T, (-12 * s + 6) / T**2, (6 * s - 2) / T
    p0, v0, p1, v1 = x0[:3], x0[3:], xf[:3], xf[3:]
    th = np.outer(h00, p0) + T * np.outer(h10, v0) + np.outer(h01, p1) + T * np.outer(h11, v1)
    thd = np.outer(d00, p0) + np.outer(d10, v0) + np.outer(d01, p1) + np.outer(d11, v1)
    thdd = np.outer(e00, p0) + np.outer(e10, v0) + np.outer(e01, p1) + np.outer(e11, v1)
    ude = np.array(model.inverse.map(N + 1)(th.T, thd.T, thdd.T)).T
    return t, np.hstack([th, thd]), ude


def _rk4(xdot: ca.Function, dt: float) -> ca.Function:
    """One RK4 step of dx/dt = xdot(x, u) with u held over the step [dt s]."""
    x, u = ca.SX.sym("x", xdot.size1_in(0)), ca.SX.sym("u", xdot.size1_in(1))
    k1 = xdot(x, u)
    k2 = xdot(x + dt / 2 * k1, u)
    k3 = xdot(x + dt / 2 * k2, u)
    k4 = xdot(x + dt * k3, u)
    return ca.Function("rk4", [x, u], [x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)])


class GaitOCP:
    """The discretized OCPs of the strategy on one grid, with their compiled PRONTO solvers.

    embedded (step 2): x (6,), u = (u_stance, u_swing, u_emb); stage parameters p = (xd, ud) (8,);
    theta = (rho_emb, rho_f, x_T (6,)); cost 1/2 dt (||x - xd||_Q^2 + ||u - ud||_R^2 + rho_emb^2
    u_emb^2) per step + 1/2 rho_f^2 ||x_N - x_T||^2 (paper eq. 8).
    underactuated (step 3): u = (u_stance, u_swing), theta = (rho_f, x_T) (paper eq. 9).
    """

    def __init__(self, model: PinnedBiped, spec: GaitSpec):
        self.model, self.spec = model, spec
        N, dt = spec.N, spec.T / spec.N
        self.dt = dt
        step_e = _rk4(model.xdot, dt)
        x, ue, u = ca.SX.sym("x", 6), ca.SX.sym("ue", 3), ca.SX.sym("u", 2)
        p, th_e, th = ca.SX.sym("p", 8), ca.SX.sym("theta", 8), ca.SX.sym("theta", 7)
        Q, R = ca.DM(spec.Q), ca.DM(spec.R)
        track = ca.dot(Q, (x - p[:6]) ** 2)
        stage_e = 0.5 * dt * (track + ca.dot(R, (ue[:2] - p[6:]) ** 2) + th_e[0] ** 2 * ue[2] ** 2)
        stage = 0.5 * dt * (track + ca.dot(R, (u - p[6:]) ** 2))
        self.embedded = DiscreteOCP(
            step=step_e, stage=ca.Function("stage_e", [x, ue, p, th_e], [stage_e]),
            terminal=ca.Function("terminal_e", [x, th_e], [0.5 * th_e[1] ** 2 * ca.sumsqr(x - th_e[2:])]), N=N)
        self.underactuated = DiscreteOCP(
            step=ca.Function("step_u", [x, u], [step_e(x, ca.vertcat(u, 0))]),
            stage=ca.Function("stage_u", [x, u, p, th], [stage]),
            terminal=ca.Function("terminal_u", [x, th], [0.5 * th[0] ** 2 * ca.sumsqr(x - th[1:])]), N=N)
        self.objective = ca.Function("objective", [x, u, p], [stage]).map(N)  # OCP (5) without penalties
        po = spec.pronto
        fq, fr = np.array(po.feedback_q) * dt, np.array(po.feedback_r) * dt  # continuous-time weights per step
        self.pronto_e = Pronto(self.embedded, ProntoOptions(feedback_q=tuple(fq), feedback_r=tuple(fr) + (fr[-1],),
                                                            max_iterations=po.max_iterations, tolerance=po.tolerance))
        self.pronto_u = Pronto(self.underactuated, ProntoOptions(feedback_q=tuple(fq), feedback_r=tuple(fr),
                                                                 max_iterations=po.max_iterations, tolerance=po.tolerance))

    def cost(self, x: np.ndarray, u: np.ndarray, xd: np.ndarray, ud: np.ndarray) -> float:
        """The OCP (5) objective of x (N+1, 6), u (N, 2) against xd (N+1, 6), ud (N, 2)."""
        return float(ca.sum2(self.objective(x[:-1].T, u.T, np.hstack([xd[:-1], ud]).T)))


def _check_hip(model: PinnedBiped, x0: np.ndarray) -> None:
    """TaskError when x0 (6,) puts the hip at or below the ground: |theta1| >= pi/2, a stance leg above its hip, had
    "converged" in 100 s to a ground that pulls."""
    hip = float(model.floating(x0[:3], x0[3:])[0][model.layout.z])
    if not hip > 0:
        raise TaskError(f"gait.x0 puts the hip at or below the ground (z = {hip * 1e3:.3g} mm, theta1 = "
                        f"{x0[0]:.6g} rad): the stance leg stands on its foot with |theta1| < pi/2")


def solve_gait(model: PinnedBiped, spec: GaitSpec, progress: Callable[[OuterLoop], None] | None = None,
               ocp: GaitOCP | None = None) -> GaitSolution:
    """Paper 001's strategy for x(T) = Delta^-1(x0) (Sec. 3, Algorithms 1 and 2) with PRONTO.

    Step 1: embedding (fictitious torso torque). Step 2: PRONTO on the embedded OCP (8) from the
    projected desired curve, rho_emb <- factor rho_emb until max |u_emb| < emb_tolerance. Step 3:
    drop u_emb, project, PRONTO on (9); rho_f <- factor rho_f (the target reset to x_f) while
    ||x(T) - x_f|| > newton_radius, else Newton on the target: x_T <- x_T + Dbeta^-1 (x_f - x(T)), Dbeta from the LQ
    sensitivity.
    progress(OuterLoop) is called after every outer loop. Raises TaskError when x0 does not jump
    from the jump set, SolveError when a projection diverges.
    """
    expect(spec, GaitSpec, "solve_gait's spec (GaitSpec.from_task)")
    start = time.perf_counter()
    cont = spec.continuation
    x0 = spec.x0
    xf = model.delta_inverse(x0)
    if abs(xf[0] - spec.jump_angle) > 1e-9:
        raise TaskError(f"gait.x0 does not come from the jump set: Delta^-1(x0) has theta1 = {xf[0]:.9g} rad, but "
                        f"gait.jump_angle = {spec.jump_angle:.9g} rad (theta2 of x0 must equal jump_angle)")
    gap = float(model.swing_height(xf[:3]))  # the impact happens where the swing foot lands: on the ground
    if abs(gap) > ON_PLANE_M:  # (a foot 31 mm below the ground was "converged")
        raise TaskError(f"gait.x0 lands its swing foot {abs(gap) * 1e3:.3g} mm {'below' if gap < 0 else 'above'} the ground "
                        f"(at Delta^-1(x0), the state before the impact): the impact map applies on the ground only; "
                        f"with legs of equal length theta1 of x0 must be -theta2 of x0")
    _check_hip(model, x0)
    ocp = ocp or GaitOCP(model, spec)
    N = spec.N
    t, xd, ude = desired_curve(model, x0, xf, spec.T, N)
    ud = ude[:N, :2] if spec.desired_input is DesiredInput.INVERSE_DYNAMICS else np.zeros((N, 2))
    params = np.hstack([xd[:N], ud])
    loops: list[OuterLoop] = []
    total_it = 0

    def record(**kw) -> None:
        loop = OuterLoop(index=len(loops), time_s=time.perf_counter() - start, **kw)
        loops.append(loop)
        if progress is not None:
            progress(loop)

    # step 2: embedded system, continuation on rho_emb
    pe = ocp.pronto_e
    rho_emb, rho_f, x_target = cont.rho_emb, cont.rho_f, xf.copy()
    x, u, K = xd, ude[:N], None
    while True:
        pe.set_parameters(params, np.concatenate([[rho_emb, rho_f], x_target]))
        res = pe.solve(x0, x, u, K)  # K: the last solve's gains stabilize its trajectory, the new start
        x, u, K = res.x, res.u, res.K
        total_it += res.iterations
        emb = float(np.max(np.abs(u[:, 2])))
        done = emb < cont.emb_tolerance
        out_of_loops = len(loops) + 1 >= cont.max_outer
        record(stage="embedding", rho_emb=rho_emb, rho_f=rho_f, cost=res.cost, pronto_iterations=res.iterations,
               pronto_converged=res.converged, pronto_polished=res.polished, emb_max=emb,
               final_error=float(np.linalg.norm(x[-1] - xf)),
               action=STOPPED if out_of_loops else "drop u_emb" if done else f"rho_emb x{cont.factor:g}")
        if done or out_of_loops:
            break
        rho_emb *= cont.factor
    x_emb, u_emb = x, u

    # step 3: underactuated system; rho_f continuation, then Newton on the target
    pu = ocp.pronto_u
    x, u, K = x_emb, u_emb[:, :2], None
    converged, message = False, "outer-loop limit (gait.continuation.max_outer) reached"
    if len(loops) >= cont.max_outer:  # (its diagnostics read as the robot's motion, which they are not)
        message += (" in the embedding stage: the trajectory is the embedded system's, driven also by a torso torque "
                    f"the robot does not have (up to {float(np.max(np.abs(u_emb[:, 2]))):.3g} N m)")
    while len(loops) < cont.max_outer:
        pu.set_parameters(params, np.concatenate([[rho_f], x_target]))
        res = pu.solve(x0, x, u, K)
        x, u, K = res.x, res.u, res.K
        total_it += res.iterations
        err = float(np.linalg.norm(x[-1] - xf))
        if err < cont.final_tolerance and res.converged:
            action = "done"
        elif err > cont.newton_radius:
            action = f"rho_f x{cont.factor:g}"
        else:
            action = "newton x_T"
        if action != "done" and len(loops) + 1 >= cont.max_outer:  # (the action it named never ran)
            action = STOPPED
        record(stage="final_state", rho_emb=None, rho_f=rho_f, cost=res.cost, pronto_iterations=res.iterations,
               pronto_converged=res.converged, pronto_polished=res.polished, emb_max=None, final_error=err,
               action=action)
        if action == "done":
            converged, message = True, "final-state constraint met"
            break
        if action == STOPPED:  # (x_target stays the one this loop solved for)
            break
        if action == "newton x_T":
            D = pu.terminal_response(x, u, res.K, -rho_f**2 * np.eye(6))  # d x_N / d x_T
            x_target = x_target + np.linalg.solve(D, xf - x[-1])
        else:  # back to the penalty on x_f itself: a target a Newton step moved would be pulled to instead (the
            # stance leg turned two full turns to reach one; T = 2 s failed where IPOPT solves in 8 iterations)
            rho_f *= cont.factor
            x_target = xf.copy()
    return GaitSolution(t=t, x=x, u=u, xd=xd, ud=ud, x_emb=x_emb, u_emb=u_emb, xf=xf, x_target=x_target, K=res.K,
                        cost=ocp.cost(x, u, xd, ud), final_error=float(np.linalg.norm(x[-1] - xf)), converged=converged,
                        loops=tuple(loops), pronto_iterations=total_it, solve_time_s=time.perf_counter() - start,
                        message=message)


@dataclass(frozen=True, eq=False)
class IpoptGait(ArraysReadOnly):
    """The same discretized OCP (5) solved directly by IPOPT (multiple shooting on the same RK4 grid,
    hard constraint x_N = Delta^-1(x0)), initialized with the desired curve and its input.
    x (N+1, 6), u (N, 2); cost as GaitSolution.cost; final_error ||x_N - x_f||."""

    x: np.ndarray
    u: np.ndarray
    cost: float
    final_error: float
    iterations: int
    solve_time_s: float
    success: bool
    status: str


def solve_gait_ipopt(model: PinnedBiped, spec: GaitSpec, ocp: GaitOCP | None = None, tol: float = 1e-10,
                     max_iter: int = 3000) -> IpoptGait:
    """Solve OCP (5) on the strategy's grid with IPOPT (MUMPS, exact Hessian) for comparison."""
    expect(spec, GaitSpec, "solve_gait_ipopt's spec (GaitSpec.from_task)")
    tol, max_iter = plain(tol), plain(max_iter)
    if not (isinstance(tol, (int, float)) and not isinstance(tol, bool) and 0 < tol < np.inf):  # (IPOPT crashed)
        raise InputError(f"solve_gait_ipopt's tol must be a number > 0, got {tol!r:.60}")
    if not (is_integer(max_iter) and max_iter >= 1):
        raise InputError(f"solve_gait_ipopt's max_iter must be an int >= 1, got {max_iter!r:.60}")
    ocp = ocp or GaitOCP(model, spec)
    N = spec.N
    xf = model.delta_inverse(spec.x0)
    _, xd, ude = desired_curve(model, spec.x0, xf, spec.T, N)
    ud = ude[:N, :2] if spec.desired_input is DesiredInput.INVERSE_DYNAMICS else np.zeros((N, 2))
    X, U = ca.MX.sym("X", 6, N + 1), ca.MX.sym("U", 2, N)
    P = ca.DM(np.hstack([xd[:N], ud]).T)
    step = ocp.underactuated.step.map(N)
    J = ca.sum2(ocp.objective(X[:, :N], U, P))
    g = ca.vec(X[:, 1:] - step(X[:, :N], U))
    w = ca.vertcat(ca.vec(X), ca.vec(U))
    lbw, ubw = np.full(w.shape[0], -np.inf), np.full(w.shape[0], np.inf)
    lbw[:6] = ubw[:6] = spec.x0  # vec(X) is column-major: x_0 first, x_N last
    lbw[6 * N:6 * N + 6] = ubw[6 * N:6 * N + 6] = xf
    solver = ca.nlpsol("gait_ipopt", "ipopt", {"x": w, "f": J, "g": g},
                       {"print_time": False, "ipopt.print_level": 0, "ipopt.sb": "yes", "ipopt.tol": tol,
                        "ipopt.max_iter": max_iter})
    w0 = np.concatenate([xd.ravel(), ude[:N, :2].ravel()])  # time-major rows = CasADi columns
    start = time.perf_counter()
    with interruptible():
        sol = solver(x0=w0, lbx=lbw, ubx=ubw, lbg=0, ubg=0)
    elapsed = time.perf_counter() - start
    stats = solver.stats()
    wopt = np.array(sol["x"]).ravel()
    x = wopt[:6 * (N + 1)].reshape(N + 1, 6)
    u = wopt[6 * (N + 1):].reshape(N, 2)
    return IpoptGait(x=x, u=u, cost=ocp.cost(x, u, xd, ud), final_error=float(np.linalg.norm(x[-1] - xf)),
                     iterations=int(stats["iter_count"]), solve_time_s=elapsed, success=bool(stats["success"]),
                     status=str(stats["return_status"]))


# ==================================================================================================
# the periodic walk on the floating robot, its MuJoCo replay, and the results contract
# ==================================================================================================

@dataclass(frozen=True, eq=False)
class Walk(ArraysReadOnly):
    """`steps` periods of a gait on the floating robot, in the results contract's arrays.

    t (P,) [s], q (P, nq), v (P, nv), u (P, nu) [robot motor order]; each impact is two samples at
    the same time (pre- and post-impact velocity). impacts: (time [s], swing foot name, normal
    impulse [N s], tangential impulse [N s]) per step; step_length [m].
    """

    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    u: np.ndarray
    impacts: tuple[tuple[float, str, float, float], ...]
    step_length: float


def _check_steps(steps, caller: str) -> None:
    """InputError unless steps is an int >= 1 (0 was an IndexError, 1.5 a TypeError)."""
    if not is_integer(steps) or steps < 1:
        raise InputError(f"{caller}'s steps must be an int >= 1, got {steps!r:.60}")


def periodic_walk(model: PinnedBiped, sol: GaitSolution, steps: int) -> Walk:
    """Repeat the gait `steps` times: step j has the stance foot at x = j * step_length and, for odd
    j, the legs swapped (the relabelling of the impact map)."""
    expect(sol, (GaitSolution, PinnedGait), "periodic_walk's sol")
    _check_steps(steps, "periodic_walk")
    lay, N = model.layout, len(sol.u)
    T = float(sol.t[-1])
    q_end, _ = model.floating(sol.x[-1, :3], sol.x[-1, 3:])
    swing_end = np.array(model.dyn.point_position(lay.swing_foot)(q_end)).ravel()
    step_length = float(swing_end[0])
    qs = np.array(model.q_of.map(N + 1)(sol.x[:, :3].T)).T
    vs = np.array(model.v_of.map(N + 1)(sol.x[:, :3].T, sol.x[:, 3:].T)).T
    # u[i] drove sample i-1 to i (the results' contract, drawn as steps-pre): the inputs shift one sample later, the
    # first (post-impact) sample taking the first (they sat one sample early: the torques were drawn 10 ms early)
    u_hold = np.vstack([sol.u[:1], sol.u])
    impulse = np.array(model.impulse(sol.x[-1])).ravel()
    ts, q, v, u, impacts = [], [], [], [], []
    for j in range(steps):
        qj, vj = qs.copy(), vs.copy()
        qj[:, lay.x] += j * step_length
        uj = np.zeros((N + 1, model.robot.nu))
        stance_motor, swing_motor = lay.stance_motor, lay.swing_motor
        if j % 2:
            for a in (qj, vj):
                a[:, [lay.stance_hinge, lay.swing_hinge]] = a[:, [lay.swing_hinge, lay.stance_hinge]]
            stance_motor, swing_motor = swing_motor, stance_motor
        uj[:, stance_motor], uj[:, swing_motor] = u_hold[:, 0], u_hold[:, 1]
        tj = j * T + sol.t
        tj[[0, -1]] = j * T, (j + 1) * T  # an impact's two samples at one time exactly (j T + t_N was 1 ulp off)
        ts.append(tj); q.append(qj); v.append(vj); u.append(uj)
        swing = lay.swing_foot if j % 2 == 0 else lay.stance_foot
        impacts.append(((j + 1) * T, swing, float(impulse[1]), float(impulse[0])))
    # the last step ends with its post-impact sample too
    q_last, v_last = q[-1][-1], model.floating(*np.split(model.delta(sol.x[-1]), 2), foot_x=steps * step_length,
                                               swapped=steps % 2 == 1)[1]
    ts.append(np.array([steps * T])); q.append(q_last[None]); v.append(v_last[None]); u.append(u[-1][-1:])
    return Walk(t=np.concatenate(ts), q=np.vstack(q), v=np.vstack(v), u=np.vstack(u), impacts=tuple(impacts),
                step_length=step_length)


class WalkControl(Enum):
    """Feedback of the MuJoCo replay.

    PHASE (default): the plan's swing-leg and torso angles as functions of the stance-leg angle
    theta1 (which increases monotonically over a step), tracked by computed torque on the pinned
    model: y = (theta2, theta3) - y_d(theta1) obeys y'' + 2 w y' + w^2 y = 0 (w = WalkGains.bandwidth).
    The reference follows the robot's own progress along the step, so timing errors (a late or
    early landing, a slower stance leg) do not turn into tracking errors; on the plan the torque
    equals the plan's. The unactuated stance-leg motion is then the gait's hybrid zero dynamics
    (Grizzle, Abba & Plestan 2001, paper 001's ref. [29]).
    LQR: feed-forward torques plus the projection's own time-varying gains on the whole pinned
    state, time-indexed from each landing: u = u_k + K_k (x_k - x).
    HINGE_PD: feed-forward torques plus PD on the two hinge angles, time-indexed.
    """

    PHASE = "phase"
    LQR = "lqr"
    HINGE_PD = "hinge_pd"


@dataclass(frozen=True)
class WalkGains:
    """Feedback of the MuJoCo replay (WalkControl). PHASE: bandwidth w [rad/s] of the critically
    damped output error. HINGE_PD: u = u_ff + kp (hinge_ref - hinge) + kd (hinge_rate_ref -
    hinge_rate) [N m/rad, N m s/rad]."""

    control: WalkControl = WalkControl.PHASE
    bandwidth: float = 20.0  # [rad/s] PHASE: fast against the 1.53 s step, slow against the 4 ms control sample
    kp: float = 400.0
    kd: float = 40.0
    ground_gap: float = 1e-3  # [m] the swing foot's contact switches on once the plan keeps it above -ground_gap
    sample_every: int = 4  # MuJoCo steps per control update (ZOH)
    stance_margin: float = 1e-4  # [m] the feet's contacts act from this height above the ground (MuJoCo pair
    #   margin): the stance foot rests ~0.1 um deep, so with margin 0 its contact drops out for single steps;
    #   near T such a drop lets it lift off (see replay_gait). 0.1 mm keeps it engaged.
    speed_gain: float = 0.0  # [rad per rad/s] PHASE: stride-to-stride torso lean on the landing speed error
    speed_integral: float = 0.0  # [rad per rad/s] the same on the sum of the errors of all steps so far; 0, 0: none

    def __post_init__(self):
        check_field_types(self)
        enum_field(self, "control", WalkControl)  # its value ("phase") too
        for name, ok, allowed in (("kp", self.kp >= 0, ">= 0"), ("kd", self.kd >= 0, ">= 0"),
                                  ("bandwidth", self.bandwidth > 0, "> 0"), ("ground_gap", self.ground_gap >= 0, ">= 0"),
                                  ("sample_every", self.sample_every >= 1, ">= 1"),
                                  ("stance_margin", self.stance_margin >= 0, ">= 0"),
                                  ("speed_gain", self.speed_gain >= 0, ">= 0"),
                                  ("speed_integral", self.speed_integral >= 0, ">= 0")):
            if not ok:
                raise InputError(f"WalkGains.{name} = {getattr(self, name)!r} is not allowed; it must be {allowed}")
        # (read by one control law only: accepted, recorded in the walk's report and ignored before, session 56)
        for names, control in ((("bandwidth", "speed_gain", "speed_integral"), WalkControl.PHASE),
                               (("kp", "kd"), WalkControl.HINGE_PD)):
            for name in names:
                if self.control is not control and getattr(self, name) != getattr(WalkGains, name):
                    raise InputError(f"WalkGains.{name} = {getattr(self, name)!r} is not allowed with control "
                                     f"{self.control.value!r}: only {control.value!r} reads it (leave it at its "
                                     f"default {getattr(WalkGains, name)!r})")


class PhaseReference:
    """The gait's actuated angles (theta2, theta3) as functions of the stance-leg angle theta1.

    A C1 piecewise cubic through the plan's samples with the exact slopes d theta_j / d theta1 =
    theta_j' / theta1'. Outside the step's range of theta1 it continues along the end slopes.
    Raises InputError when theta1 is not strictly increasing along the plan (no phase variable).
    """

    def __init__(self, x: np.ndarray):
        from scipy.interpolate import CubicHermiteSpline

        th1 = x[:, 0]
        if not self.applies(x):
            raise InputError("the gait's stance-leg angle theta1 does not increase monotonically, so it cannot index "
                             "the replay's reference; use WalkControl.LQR or HINGE_PD")
        self.lo, self.hi = float(th1[0]), float(th1[-1])
        self.spline = CubicHermiteSpline(th1, x[:, 1:3], x[:, 4:6] / x[:, 3:4])
        self.slope, self.curvature = self.spline.derivative(), self.spline.derivative(2)

    @staticmethod
    def applies(x: np.ndarray) -> bool:
        """Whether theta1 indexes the gait x (N+1, 6): strictly increasing, with a positive rate."""
        return bool(np.all(np.diff(x[:, 0]) > 0) and np.all(x[:, 3] > 0))

    def __call__(self, theta1: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(y_d (2,) [rad], dy_d/dtheta1 (2,), d2y_d/dtheta1^2 (2,) [1/rad]) at theta1 [rad]."""
        c = min(max(theta1, self.lo), self.hi)
        d1 = self.slope(c)
        d2 = self.curvature(c) if c == theta1 else np.zeros(2)
        return self.spline(c) + d1 * (theta1 - c), d1, d2


def _output_control(model: PinnedBiped) -> ca.Function:
    """Computed torque of WalkControl.PHASE: (theta (3,), theta' (3,), dy_d (2,), d2y_d (2,), w (2,))
    -> u (2,) [N m] such that y'' = w for y = (theta2, theta3) - y_d(theta1) on the pinned model."""
    th, thd = ca.SX.sym("theta", 3), ca.SX.sym("dtheta", 3)
    d1, d2, w = ca.SX.sym("dy", 2), ca.SX.sym("ddy", 2), ca.SX.sym("w", 2)
    Phi = ca.horzcat(-d1, ca.DM.eye(2))  # y' = Phi theta'
    Minv_B = ca.solve(model.mass(th), model.actuation(th))
    Minv_h = ca.solve(model.mass(th), model.bias(th, thd))
    # y'' = Phi M^-1 (B u - h) - d2 theta1'^2
    u = ca.solve(ca.mtimes(Phi, Minv_B), w + d2 * thd[0] ** 2 + ca.mtimes(Phi, Minv_h))
    return ca.Function("output_control", [th, thd, d1, d2, w], [u])


@dataclass(frozen=True)
class WalkReport(ArraysReadOnly):
    """How the floating robot in MuJoCo walked the gait.

    steps_walked: impacts of the swing foot in front of the stance foot before any fall (of
    `steps_asked`); fell: the hip dropped below FALL_HIP_SHARE of the plan's lowest hip height or the torso
    passed +-90 deg; impact_times [s] (MuJoCo, the first steps_asked landings; the replay runs 20 % longer)
    against the plan's (j+1) T;
    max_hinge_error [rad], max_torso_error [rad], max_hip_height_error [m]: over the steps walked, against the plan
    at the same stance-leg angle (WalkControl.PHASE) or at the same time since the last landing (time-indexed
    modes); max_torque [N m]: up to the last landing asked for (or the fall).
    """

    steps_asked: int
    steps_walked: int
    fell: bool
    impact_times: tuple[float, ...]
    planned_impact_times: tuple[float, ...]
    max_hinge_error: float
    max_torso_error: float
    max_hip_height_error: float
    max_torque: float
    swing_contact_from: float  # [s] into the plan's step when the swing foot's contact switches on (PHASE: at its theta1)
    gains: WalkGains
    step_lengths: tuple[float, ...] = ()  # [m] MuJoCo: new stance foot x minus the old one, per landing
    planned_step_length: float = 0.0  # [m]
    max_base_error_in_time: float = 0.0  # [m] hip (x, z) against the tiled plan at the same time, steps walked

    def to_json(self) -> dict:
        return {"steps_asked": self.steps_asked, "steps_walked": self.steps_walked, "fell": self.fell,
                "impact_times": list(self.impact_times), "planned_impact_times": list(self.planned_impact_times),
                "max_hinge_error_rad": self.max_hinge_error, "max_torso_error_rad": self.max_torso_error,
                "max_hip_height_error_m": self.max_hip_height_error, "max_torque_Nm": self.max_torque,
                "swing_contact_from_s": self.swing_contact_from, "control": self.gains.control.value,
                "step_lengths_m": list(self.step_lengths), "planned_step_length_m": self.planned_step_length,
                "max_base_error_in_time_m": self.max_base_error_in_time,
                "bandwidth_rad_s": self.gains.bandwidth, "kp": self.gains.kp, "kd": self.gains.kd,
                "speed_gain": self.gains.speed_gain, "speed_integral": self.gains.speed_integral}


# A MuJoCo landing counts as a step when the new stance foot is at least this share of the plan's step length ahead.
MIN_STEP_SHARE = 0.5
# The walk fell when the hip drops below this share of the plan's lowest hip height: relative to the plan, as an
# absolute 0.6 m read a walking biped with 0.5 m legs (hip at 0.46 m) as fallen at t = 0. (The shipped biped's gaits
# keep the hip >= 0.92 m and `planner plan biped` >= 0.99 m: falls below 0.55 and 0.60 m, where the test had 0.6 m.)
FALL_HIP_SHARE = 0.6


def replay_gait(model: PinnedBiped, sol: GaitSolution | PinnedGait, task: Task, steps: int,
                gains: WalkGains | None = None, trace: list | None = None, settings=None,
                arm_index: int | None = None) -> WalkReport:
    """Walk the gait `steps` times on the robot file in MuJoCo (replay.build_scene's contact model).

    Control (WalkGains.control): by default the plan's actuated angles indexed by the stance-leg
    angle and tracked by computed torque (WalkControl.PHASE); the time-indexed modes restart the
    reference when MuJoCo's swing foot lands. Legs swap at every landing. PHASE with
    WalkGains.speed_gain/speed_integral: at each landing the torso reference gets a constant forward
    lean, a PI of the stance-leg rate's shortfall against the plan's at its end. The three-link biped has no
    knees: its swing foot touches the ground where the legs cross and, unless they cross exactly
    upright, stays below it until it lands (paper 001 ignores this scuffing). So the swing foot's
    contact pair is switched off (margin -1 m) until the plan keeps the swing foot above -ground_gap
    for the rest of the step -- the usual stand-in for foot clearance -- measured in theta1 for
    PHASE and in time otherwise. If the plan's foot reaches the ground from below (gait 1 and 2: at
    +1.19 m/s), its contact instead stays off until the foot reaches the ground, armed after its
    lowest point; that is the landing. arm_index (optional): the plan's sample from which the swing
    foot's contact and the landing detection are armed instead (e.g. a plan whose swing foot grazes
    the ground at the crossing: its last apex). settings: replay.ContactSettings (default: no push-out
    stiffness, see the comment below). The time-indexed modes need a uniform grid (sol.t).
    trace (optional list) receives (t, step, s, measured pinned x (6,), reference x (6,), motor
    torques u (nu,)) per control update, for diagnostics (PHASE: s is theta1 and the reference is
    the plan at that theta1).
    """
    from .replay import ContactSettings, build_scene, mujoco_rollout  # MuJoCo only when replaying

    expect(sol, (GaitSolution, PinnedGait), "replay_gait's sol")
    expect(gains, (WalkGains, type(None)), "replay_gait's gains")  # ({} was taken as the defaults, {"kp": 1} crashed)
    expect(settings, (ContactSettings, type(None)), "replay_gait's settings")
    _check_steps(steps, "replay_gait")
    if arm_index is not None and not (is_integer(arm_index) and 0 <= arm_index < len(sol.t)):  # (-5: 5 from the end)
        raise InputError(f"replay_gait's arm_index must be a sample index in [0, {len(sol.t) - 1}] or None, got "
                         f"{arm_index!r:.60}")
    gains = WalkGains() if gains is None else gains
    phase = gains.control is WalkControl.PHASE
    # no push-out stiffness: with the positive stance margin, k > 0 would lift the resting foot to the
    # margin's edge, where its contact drops out again; dead-beat damping alone holds it (0.1 um drift per step)
    settings = ContactSettings(stiffness_ratio=0.0) if settings is None else settings
    scene = build_scene(model.robot, task, settings)
    lay, N = model.layout, len(sol.u)
    T, dt = float(sol.t[-1] - sol.t[0]), float(sol.t[1] - sol.t[0])
    if not phase and np.ptp(np.diff(sol.t)) > 1e-9 * T:
        raise InputError(f"walk control {gains.control.value!r} indexes the plan by time and needs a uniform grid; "
                         "use 'phase'")
    pair_of = {p: i for i, p in enumerate(scene.points)}
    _require_feet(lay, scene.points)
    tiled = periodic_walk(model, sol, steps)  # the plan's walk: its step length, and its base against MuJoCo's
    planned_step = tiled.step_length
    foot_pos = {f: model.dyn.point_position(f) for f in (lay.stance_foot, lay.swing_foot)}
    fall_z = FALL_HIP_SHARE * float(np.min(np.array(model.q_of.map(N + 1)(sol.x[:, :3].T))[lay.z]))  # [m]
    state = {"j": 0, "t0": 0.0, "impacts": [], "err": [0.0, 0.0, 0.0], "down": False, "steps": [], "lean": 0.0, "speed_sum": 0.0,
             "last_t": 0.0}
    height = np.array(model.swing_height.map(N + 1)(sol.x[:, :3].T)).ravel()
    below = np.nonzero(height[:-1] < -gains.ground_gap)[0]
    gate_k = min(below[-1] + 1 if len(below) else 0, N - 1)  # at least the last step: the landing needs the contact
    # knee-less landing from below: the plan's swing foot reaches the ground moving up (gait 1: +1.19 m/s);
    # its contact then switches on when it reaches the ground, armed after its lowest point
    from_below = height[N - 1] < 0.0 and arm_index is None
    if from_below:
        gate_k = final_low(height)
    if arm_index is not None:
        gate_k = arm_index
    gate = float(sol.t[gate_k])
    sample_s = gains.sample_every * scene.settings.timestep  # [s] one control sample
    margins = scene.model.pair_margin
    if phase:
        ref = PhaseReference(sol.x)
        output_control = _output_control(model)
        w = gains.bandwidth
        x_of_theta1 = lambda th1: np.array([np.interp(th1, sol.x[:, 0], sol.x[:, i]) for i in range(6)])

    def feet(j):  # (stance, swing) foot names of step j
        return (lay.stance_foot, lay.swing_foot) if j % 2 == 0 else (lay.swing_foot, lay.stance_foot)

    def pinned(q, v, j):  # the pinned state (6,) of step j read from the floating state
        hinges = [lay.stance_hinge, lay.swing_hinge] if j % 2 == 0 else [lay.swing_hinge, lay.stance_hinge]
        th = q[lay.torso] + np.array([q[hinges[0]], q[hinges[1]], 0.0])
        thd = v[lay.torso] + np.array([v[hinges[0]], v[hinges[1]], 0.0])
        return np.concatenate([th, thd]), hinges

    def control(t, q, v):
        if state.get("unstable") or t < state["last_t"] or not (np.all(np.isfinite(q)) and np.all(np.isfinite(v))):
            # MuJoCo reset an unstable simulation (its time back to 0, "Nan, Inf or huge value in QACC"): the walk fell
            # there (a negative time since the landing indexed the plan from its end: an IndexError)
            if not state["down"]:
                state["down"], state["fall_t"] = True, state["last_t"]
            state["unstable"] = True
            return np.zeros(model.robot.nu)
        state["last_t"] = t
        j = state["j"]
        stance, swing = feet(j)
        x, _ = pinned(q, v, j)
        s = x[0] if phase else t - state["t0"]  # progress along the step: theta1 [rad] or time [s]
        armed = s >= (sol.x[gate_k, 0] if phase else gate)
        swing_z = float(foot_pos[swing](q)[2])
        if from_below:  # lands when it reaches the ground within the next control sample
            swing_zdot = float(foot_pos[swing](q + 1e-6 * v)[2] - swing_z) / 1e-6  # [m/s]
            lands = swing_z + sample_s * max(swing_zdot, 0.0) >= 0.0
        else:
            lands = swing_z < gains.ground_gap
        # a landing is a step: half the plan's length at least (a swing foot armed at a mid-stance dip and rising
        # through the ground counted ten 0.1-0.5 mm shuffles in 33 ms as "10 of 10 steps")
        if armed and lands and float(foot_pos[swing](q)[0] - foot_pos[stance](q)[0]) >= MIN_STEP_SHARE * planned_step:
            state["impacts"].append(t)
            state["steps"].append(float(foot_pos[swing](q)[0] - foot_pos[stance](q)[0]))
            # stride-to-stride speed loop: a step that ends slower than the plan leans the torso forward for the
            # next step; the integral removes a steady deficit (MuJoCo's impact loses more than the plan's)
            slow = sol.x[-1, 3] - x[3]  # [rad/s] stance-leg rate short of the plan's at the landing
            state["speed_sum"] += slow
            state["lean"] = gains.speed_gain * slow + gains.speed_integral * state["speed_sum"]
            state["j"], state["t0"] = j + 1, t
            j, (stance, swing) = j + 1, feet(j + 1)
            # MuJoCo resolves the impact over the next steps: this sample still sees the pre-impact rates,
            # so the feedback acts on the rigid impact map's post-impact state (else ~1200 N m for one sample)
            x = model.delta(x)
            s, armed = (x[0], False) if phase else (0.0, False)
        if (q[lay.z] < fall_z or abs(q[lay.torso]) > np.pi / 2) and j < steps and not state["down"]:
            state["down"], state["fall_t"] = True, t
        # the swing foot's contact: off until the plan keeps that foot above ground (no knees, no clearance)
        margins[pair_of[swing]] = gains.stance_margin if armed and not from_below else -1.0
        margins[pair_of[stance]] = gains.stance_margin
        _, hinges = pinned(q, v, j)
        motors = [lay.stance_motor, lay.swing_motor] if j % 2 == 0 else [lay.swing_motor, lay.stance_motor]
        u = np.zeros(model.robot.nu)
        if phase:
            yd, d1, d2 = ref(x[0])
            yd = yd + np.array([0.0, state["lean"]])
            y, ydot = x[1:3] - yd, x[4:6] - d1 * x[3]
            u[motors] = np.array(output_control(x[:3], x[3:], d1, d2, -w * w * y - 2 * w * ydot)).ravel()
            x_ref = x_of_theta1(x[0])
            x_ref[:3] = np.concatenate([[x[0]], yd])
        else:
            k = min(int(s / dt), N - 1)
            a = min(s / dt, N) - min(int(s / dt), N)  # linear interpolation weight of the reference
            kk = min(int(s / dt), N)
            x_ref = (1 - a) * sol.x[kk] + a * sol.x[min(kk + 1, N)]
            if gains.control is WalkControl.LQR:
                u[motors] = sol.u[k] + sol.K[k] @ (x_ref - x)
            else:
                href = np.array(model.q_of(x_ref[:3])).ravel()[[lay.stance_hinge, lay.swing_hinge]]
                hdref = np.array(model.v_of(x_ref[:3], x_ref[3:])).ravel()[[lay.stance_hinge, lay.swing_hinge]]
                u[motors] = sol.u[k] + gains.kp * (href - q[hinges]) + gains.kd * (hdref - v[hinges])
        if trace is not None:  # (t [s], step, progress (time [s] or theta1 [rad]), measured x (6,), reference (6,), u)
            trace.append((t, j, s, x, x_ref, u.copy()))
        if not state["down"] and j < steps:
            err = state["err"]
            hinge_ref = np.array(model.q_of(x_ref[:3])).ravel()[[lay.stance_hinge, lay.swing_hinge]]
            err[0] = max(err[0], float(np.max(np.abs(hinge_ref - q[hinges]))))
            err[1] = max(err[1], abs(x_ref[2] - q[lay.torso]))
            err[2] = max(err[2], abs(float(model.q_of(x_ref[:3])[lay.z]) - q[lay.z]))
        return u

    q0, v0 = model.floating(sol.x[0, :3], sol.x[0, 3:])
    # 20 % spare: a walk whose first steps are slower than the plan's (the speed loop catching up) still ends
    run = mujoco_rollout(scene, q0, v0, (1.2 * steps + 0.5) * T, control, sample_every=gains.sample_every)
    back = np.nonzero(np.diff(run["t"]) < 0)[0]  # MuJoCo's reset of an unstable simulation: the samples after it go
    if len(back):
        run = {key: value[: back[0] + 1] if len(value) == len(run["t"]) else value for key, value in run.items()}
    walked = sum(1 for t in state["impacts"] if t < state.get("fall_t", np.inf))  # landings before any fall
    # the report covers the steps asked: the spare time's landings (12 for 10 steps) and torques are not the walk's
    landings = state["impacts"][:steps]
    until = min(state.get("fall_t", np.inf), landings[-1] if len(landings) == steps else np.inf)
    # the base against the plan tiled in time: timing drift included (information; PHASE ignores time)
    upto = run["t"] <= min(state.get("fall_t", np.inf), steps * T)
    plan_base = np.column_stack([np.interp(run["t"][upto], tiled.t, tiled.q[:, i]) for i in (lay.x, lay.z)])
    base_error = np.linalg.norm(run["q"][upto][:, [lay.x, lay.z]] - plan_base, axis=1)
    return WalkReport(steps_asked=steps, steps_walked=min(walked, steps), fell=state["down"],
                      impact_times=tuple(float(x) for x in landings),
                      planned_impact_times=tuple((j + 1) * T for j in range(steps)),
                      max_hinge_error=state["err"][0], max_torso_error=state["err"][1],
                      max_hip_height_error=state["err"][2],
                      max_torque=float(np.max(np.abs(run["u"][run["t"] <= until]), initial=0.0)),
                      swing_contact_from=gate, gains=gains, step_lengths=tuple(state["steps"][:steps]),
                      planned_step_length=tiled.step_length, max_base_error_in_time=float(np.max(base_error, initial=0.0)))


@dataclass(frozen=True, eq=False)
class GaitRunResult(ArraysReadOnly):
    """What `run_gait` returns (and wrote): the solution, its walk, the MuJoCo report, the summary."""

    robot: str
    task: str
    solution: GaitSolution
    walk: Walk
    walking: WalkReport | None
    summary: dict

    def report(self) -> str:
        """A few human-readable lines for the terminal."""
        s = self.solution
        lines = [f"gait {Path(self.robot).name} ({Path(self.task).name}): {'converged' if s.converged else 'NOT converged'} "
                 f"in {s.solve_time_s:.2f} s, {len(s.loops)} outer loops, {s.pronto_iterations} PRONTO iterations; "
                 f"||x(T) - Delta^-1(x0)|| = {s.final_error:.2e}; cost {s.cost:.6g}"]
        if not s.converged and s.message:  # (only -q's failure line said why)
            lines.append(f"  {s.message}")
        lines += [f"  {violation}" for violation in gait_violations(self.summary)]
        if self.walking is not None:
            w = self.walking
            lines.append(f"MuJoCo ({w.gains.control.value} control): walked {w.steps_walked} of {w.steps_asked} steps"
                         f"{' then fell' if w.fell else ''}; max hinge error {np.rad2deg(w.max_hinge_error):.2f} deg, "
                         f"max torque {w.max_torque:.0f} N m")
        return "\n".join(lines)


def _impact_contact(model: PinnedBiped, x_minus) -> dict:
    """The gait's impact as contacts see it: the swing foot's impulse (tangential, normal) [N s] and the trailing
    foot's vertical velocity right after it [m/s] (the impact map's no-slip landing lets that foot go whatever its
    velocity)."""
    impulse = np.array(model.impulse(x_minus)).ravel()
    theta, dtheta = np.split(model.delta(x_minus), 2)
    q, v = model.floating(theta, dtheta)  # after relabelling the file's swing foot is the one that trails
    trailing = np.array(model.dyn.point_jacobian(model.layout.swing_foot)(q)) @ v
    return {"impact_impulse_N_s": [float(impulse[0]), float(impulse[1])],
            "trailing_foot_lift_off_m_s": float(trailing[2])}


# a gait's contact quantities beyond these bounds are violations (contact_violations): the solver's accuracy, far
# below the shipped gaits' margins (normal force >= 195 N, impulse 20 N s, lift-off +0.33 m/s)
CONTACT_FORCE_TOL_N, CONTACT_IMPULSE_TOL_N_S, LIFT_OFF_TOL_M_S = 1e-6, 1e-9, 1e-9


def gait_violations(summary: dict) -> list[str]:
    """A gait summary's contact, motor and joint-range violations, the lines that make a converged gait no motion of
    the robot."""
    return [*summary.get("contact_violations", ()), *summary.get("motor_violations", ()),
            *summary.get("joint_violations", ())]


def contact_violations(summary: dict) -> list[str]:
    """What a gait asks of the ground that a unilateral contact cannot give, one line each (the paper's OCP has no
    contact constraints; such gaits converged silently, MuJoCo's walk then fell): a stance force that pulls or leaves
    the friction cone, an impact impulse that pulls or leaves it, a trailing foot that does not lift off after the
    impact. mu: the smaller of the two feet's (they swap roles every step)."""
    out = []
    mu = summary["impact_friction_mu"]
    if summary["min_normal_force_N"] < -CONTACT_FORCE_TOL_N:
        out.append(f"the stance foot's normal force falls to {summary['min_normal_force_N']:.4g} N: the ground would "
                   "have to pull it down")
    elif summary["friction_needed"] > summary["friction_mu"] * CONE_SLACK:  # (was only said: --no-validate exited 0)
        out.append(f"the stance foot needs |tangential / normal| force up to {summary['friction_needed']:.3g}, "
                   f"beyond its contact's mu = {summary['friction_mu']:g}: the gait has no friction cone, the foot "
                   "would slide")
    tangential, normal = summary["impact_impulse_N_s"]
    if normal < -CONTACT_IMPULSE_TOL_N_S:
        out.append(f"the impact's normal impulse is {normal:.4g} N s: the ground would have to pull the landing foot")
    elif abs(tangential) > CONE_SLACK * mu * normal + CONTACT_IMPULSE_TOL_N_S:  # the plans' impacts' slack
        ratio = abs(tangential) / max(normal, 1e-300)
        out.append(f"the impact's tangential impulse {tangential:.4g} N s is {ratio:.3g} "
                   f"times its normal one {normal:.4g} N s, beyond mu = {mu:g}: the landing foot would slide")
    if summary["trailing_foot_lift_off_m_s"] < -LIFT_OFF_TOL_M_S:
        out.append(f"the trailing foot moves down at {summary['trailing_foot_lift_off_m_s']:.3g} m/s right after the "
                   "impact: it would not lift off (a double support the gait does not have)")
    return out


MOTOR_TOL_NM = 1e-6  # commands this far beyond a range are the solver's rounding, not a violation [N m]


def motor_violations(robot: Robot, layout: BipedLayout, u: np.ndarray) -> list[str]:
    """The gait's motor commands u (N, 2) [N m] beyond the robot file's control ranges, as one line (the gait's OCP
    has no input bounds; MuJoCo clamps the commands). Each motor drives both roles as the legs swap every step, so
    every command is held to both motors' ranges."""
    motors = [robot.actuators[layout.stance_motor], robot.actuators[layout.swing_motor]]
    lo, hi = max(m.lower for m in motors), min(m.upper for m in motors)
    low, high = float(np.min(u)), float(np.max(u))
    if lo - MOTOR_TOL_NM <= low and high <= hi + MOTOR_TOL_NM:
        return []
    return [f"the motors need commands from {low:.4g} to {high:.4g} N m, beyond the robot file's control range "
            f"[{lo:g}, {hi:g}] of {', '.join(repr(m.name) for m in motors)} (each drives both legs' roles as they "
            "swap): MuJoCo clamps them"]


def joint_violations(robot: Robot, q: np.ndarray) -> list[str]:
    """The walk's joints beyond the robot file's ranges (simulate.joints_outside_range over q (P, nq), the floating
    walk: legs swapped every step, so each hinge in both roles), one line each. The gait's OCP has no joint limits,
    MuJoCo's replay enforces them: a gait with its hinges at -0.80 rad against a range of +-0.5 rad converged silently
    and its walk fell at once, with no reason given."""
    outside = joints_outside_range(robot, q)
    return [line.strip() for line in outside_range_lines({"joints_outside_range": outside}, len(q),
                                                         "the gait's OCP has no joint limits")]


MIRROR_TOL = 1e-9  # relative: the two stance models of mirror-image legs agree to rounding (measured 8e-15)
MIRROR_SAMPLES = 5  # seeded random states at which they are compared


def check_mirror_legs(model: PinnedBiped) -> None:
    """TaskError unless the legs are mirror images: the periodic gait swaps them every step (the walk relabels the
    state and hands each motor the other's command), so the pinned model with the other foot as stance must be the
    same functions (mass matrix, bias, actuation, impact map) at seeded random states. A leg 0.5 kg heavier, or of
    gear 2, converged to a "periodic" walk that was no motion of the robot."""
    lay = model.layout
    other = PinnedBiped(model.robot, model.dyn, find_layout(model.robot, lay.swing_foot, lay.stance_foot))
    rng = np.random.default_rng(0)
    for _ in range(MIRROR_SAMPLES):
        theta, rate = rng.uniform(-0.5, 0.5, 3), rng.uniform(-2.0, 2.0, 3)
        for name, attr, args in (("mass matrix", "mass", (theta,)), ("bias forces", "bias", (theta, rate)),
                                 ("actuation", "actuation", (theta,)), ("impact map", "impact", (theta,))):
            a, b = (np.array(getattr(m, attr)(*args), float) for m in (model, other))
            if np.abs(a - b).max() > MIRROR_TOL * max(np.abs(a).max(), 1.0):
                raise TaskError(f"{model.robot.path}: the legs are not mirror images: with {lay.swing_foot!r} as the "
                                f"stance foot the {name} differs by {np.abs(a - b).max():.3g} (the gait swaps the legs "
                                "every step); give both legs the same masses, inertias, lengths and motor gears")


def _require_feet(layout: BipedLayout, contacts) -> None:
    """TaskError unless both of the layout's feet are among the task's contact points `contacts`."""
    for foot in (layout.stance_foot, layout.swing_foot):
        if foot not in contacts:
            raise TaskError(f"a gait needs both feet as [[contacts]] (the walk and its MuJoCo replay); {foot!r} is missing")


def run_gait(robot: Robot | str | os.PathLike, task: Task | str | os.PathLike, out_dir: str | os.PathLike | None,
             progress: Callable[[OuterLoop], None] | None = None, validate: bool = True,
             result_id: str | None = None) -> GaitRunResult:
    """Solve a task's [gait] with paper 001's strategy and write the results contract to out_dir.

    robot: a Robot or a robot file path; task: a Task or a task file path. progress(OuterLoop) is
    called once per outer loop (OuterLoop.line() is a terminal line). validate: replay the walk in
    MuJoCo (`replay_gait`) and put its report under "walking" in the summary.
    out_dir (None: write nothing) receives trajectory.npz (tau, y, t, q, v, u, impact_times and the
    pinned gait: gait_t, gait_x, gait_u, gait_xd, gait_ud) and summary.json (command "gait"); a gait that did not
    converge writes them under out_dir/failed instead, so a good earlier result in out_dir stays (as `planner plan`).
    result_id: both files' (result.write_files; None: a new one).
    Raises TaskError (no [gait], inconsistent initial state), SolveError (diverged projection).
    """
    from .model import load_robot
    from .task import load_task

    expect(robot, (Robot, str, os.PathLike), "run_gait's robot")
    expect(task, (Task, str, os.PathLike), "run_gait's task")
    validate = plain(validate)
    expect(validate, bool, "run_gait's validate")  # "no" validated
    robot = robot if isinstance(robot, Robot) else load_robot(robot)
    task = task if isinstance(task, Task) else load_task(task)
    spec = GaitSpec.from_task(task)  # (first: check_against warned of a ground_height that this then refused)
    task.check_against(robot)
    g = task.gait
    model = PinnedBiped(robot, layout=find_layout(robot, g.stance, g.swing))
    _require_feet(model.layout, [c.point for c in task.contacts])  # before the solve: the replay refused it after
    check_mirror_legs(model)
    geared = [f"{a.name!r} (gear {a.gear:g})" for a in robot.actuators if a.gear != 1.0]
    if geared:  # (gear 2 converged to another gait, cost 8.48 for 14.14, its "N m" fields half the torques)
        raise TaskError(f"{robot.path}: motor {', '.join(geared)}: paper 001's gait weighs (R) and reports (N m) the "
                        "hinge torques, which are the motor commands with gear 1 only; give the motors gear 1 (their "
                        "ctrlrange in N m)")
    if validate and spec.x0[3] <= 0:  # (the mirror of gait 1 converged, then its walk "fell" at once: exit 1)
        raise TaskError(f"gait.x0 has the stance leg turning at {spec.x0[3]:g} rad/s: "
                        + ("the gait walks towards -x, and " if spec.x0[3] < 0 else "it does not walk forward, and ")
                        + "the MuJoCo walk replays gaits that walk towards +x (theta1 increasing: its phase variable "
                        "and its step count); "
                        + ("mirror the task (negate x0, jump_angle and every initial q and v but z and its rate)"
                           if spec.x0[3] < 0 else "give the stance leg a rate theta1' > 0")
                        + " or do not validate (`planner gait --no-validate`)")
    _check_hip(model, spec.x0)  # (before the initial state's check, whose hint put the hip below the ground)
    q0, v0 = model.floating(spec.x0[:3], spec.x0[3:])
    v_init = np.zeros(robot.nv) if task.initial.v is None else np.array(task.initial.v)
    if np.max(np.abs(q0 - np.array(task.initial.q))) > 1e-6 or np.max(np.abs(v0 - v_init)) > 1e-6:
        raise TaskError(f"initial.q/initial.v must be the floating state of gait.x0 with {g.stance!r} at the origin: "
                        f"q = {np.round(q0, 9).tolist()}, v = {np.round(v0, 9).tolist()}")
    loops: list[OuterLoop] = []

    def record(loop: OuterLoop) -> None:
        loops.append(loop)
        if progress is not None:
            progress(loop)

    start = time.perf_counter()
    try:
        sol = solve_gait(model, spec, record)
    except SolveError as exc:  # (a diverged projection wrote nothing: exit 1 without the loops' diagnostics)
        if out_dir is None:
            raise
        failed = Path(out_dir) / "failed"
        # the contract's keys as a converged gait's summary has them (they were missing: KeyError in a reader)
        write_files(failed, {"task_json": np.array(task_to_json(task))},
                    {"command": "gait", "robot": str(robot.path), "task": task_path(task_source(task)),
                     "robot_sha256": robot.sha256, "converged": False, "solve_time_s": time.perf_counter() - start,
                     "n_nlp": len(loops), "ipopt_iterations": sum(loop.pronto_iterations for loop in loops),
                     "iterations_solver": "pronto", "complementarity_residual": None, "terminal_error": None,
                     "physical_duration_s": None, "impacts": [], "message": str(exc),
                     "outer_loops": [vars(loop) for loop in loops]}, result_id)
        raise SolveError(f"{exc} (the outer loops before it: {failed / 'summary.json'})") from None
    walk = periodic_walk(model, sol, g.steps)
    # a gait whose stance leg stops or turns back has no phase variable: the time-indexed LQR replay
    control = WalkControl.PHASE if PhaseReference.applies(sol.x) else WalkControl.LQR
    walking = replay_gait(model, sol, task, g.steps, WalkGains(control=control)) if validate else None
    # at both ends of every interval, its input held: the state before the impact, x_N with u_{N-1}, too (the force
    # there had been left out: gait 2's smallest normal force read 251 N for 236 N, its friction 0.494 for 0.513)
    force = np.vstack([np.array(model.stance_force.map(spec.N)(sol.x[:-1].T, sol.u.T)).T,
                       np.array(model.stance_force(sol.x[-1], sol.u[-1])).ravel()])
    height = np.array(model.swing_height.map(spec.N + 1)(sol.x[:, :3].T)).ravel()
    u_paper = -sol.u
    near_T = sol.t[:-1] >= min(sol.t[-1] - 0.1, sol.t[-2])  # the last 100 ms, at least the last step (N <= 15: none)
    # the smaller of the two feet's mu: each is the stance foot and the landing foot every other step
    feet_mu = min(c.mu for c in task.contacts if c.point in (g.stance, g.swing))
    summary = {
        "command": "gait", "robot": str(robot.path), "task": task_path(task_source(task)), "robot_sha256": robot.sha256,
        "converged": sol.converged, "solve_time_s": sol.solve_time_s,
        "n_nlp": len(sol.loops), "ipopt_iterations": sol.pronto_iterations, "iterations_solver": "pronto",
        "complementarity_residual": None,  # no complementarity: the contact sequence is fixed
        "terminal_error": sol.final_error, "physical_duration_s": float(walk.t[-1] - walk.t[0]),
        "impacts": [{"time": t, "contact": c, "impulse": imp, "impulse_tangential": imp_t} for t, c, imp, imp_t in walk.impacts],
        "message": sol.message, "cost": sol.cost, "period_s": spec.T, "N": spec.N, "step_length_m": walk.step_length,
        "x0": spec.x0.tolist(), "x_final": sol.x[-1].tolist(), "x_target": sol.x_target.tolist(), "xf": sol.xf.tolist(),
        "max_abs_u_Nm": np.max(np.abs(sol.u), axis=0).tolist(),
        "integral_u_squared": (np.sum(sol.u**2, axis=0) * spec.T / spec.N).tolist(),
        "u_paper_last_100ms_Nm": {"min": np.min(u_paper[near_T], axis=0).tolist(), "max": np.max(u_paper[near_T], axis=0).tolist()},
        "min_normal_force_N": float(np.min(force[:, 1])),
        # where the ground pushes (a pulling ground is a contact violation below, the ratio means nothing there)
        "friction_needed": float(np.max(np.abs(force[:, 0] / force[:, 1]), where=force[:, 1] > 0.0, initial=0.0)),
        "friction_mu": feet_mu,
        **_impact_contact(model, sol.x[-1]),
        "impact_friction_mu": feet_mu,
        "min_swing_foot_height_m": float(np.min(height[1:-1])),
        "outer_loops": [vars(loop) for loop in sol.loops],
        "walking": walking.to_json() if walking else None,
    }
    summary["contact_violations"] = contact_violations(summary)
    summary["motor_violations"] = motor_violations(robot, model.layout, sol.u)
    summary["joint_violations"] = joint_violations(robot, walk.q)
    if out_dir is not None:
        arrays = {"tau": walk.t, "y": np.hstack([walk.q, walk.v, walk.t[:, None]]), "t": walk.t, "q": walk.q, "v": walk.v,
                  "u": walk.u, "impact_times": np.array([i[0] for i in walk.impacts]),
                  "impact_impulses": np.array([i[2] for i in walk.impacts]),
                  "gait_t": sol.t, "gait_x": sol.x, "gait_u": sol.u, "gait_xd": sol.xd, "gait_ud": sol.ud,
                  "gait_x_embedded": sol.x_emb, "gait_u_embedded": sol.u_emb,
                  "state_names": np.array(list(robot.dof_names) + [f"d{n}" for n in robot.dof_names] + ["t"], dtype=str),
                  "task_json": np.array(task_to_json(task))}  # the task solved: view and validate read it from any directory
        write_files(Path(out_dir) if summary["converged"] else Path(out_dir) / "failed", arrays, summary, result_id)
    return GaitRunResult(robot=str(robot.path), task=task_source(task), solution=sol, walk=walk, walking=walking, summary=summary)


# ==================================================================================================
# the time-freezing walk (`planner plan` with plan.periodic) replayed by the same controller
# ==================================================================================================

WALK_VALIDATION_STEPS = 10  # issue 7B: steps a periodic plan must walk in MuJoCo
# the plan's impact keeps the trailing foot's horizontal velocity at 0 (a tangential impulse without a normal
# one); MuJoCo's, like the rigid map, lets it slide off and loses more: without the speed loop the steps slow
# down by ~20 ms each until the robot stalls (8 of 10); P only or I only leaves an 8-step speed oscillation
PLAN_WALK_GAINS = WalkGains(speed_gain=0.5, speed_integral=0.2)


def landing_first(robot: Robot, task: Task, arrays: dict) -> tuple[np.ndarray, ...]:
    """The periodic plan's (t (P,), q (P, nq), v (P, nv), u (P, nu)) started at its landing: with one
    impact at 0 < t_i < T, the samples from the post-impact one at t_i to T, then those after t = 0 up
    to the landing's post-impact sample, relabelled by plan.periodic (q -> S q + step e_along, v -> S v,
    each motor's u to the motor of the swapped joint) and delayed by T; times from 0. By periodicity
    the plan's state at T is the relabelled, shifted state at 0, so the step is continuous. Without
    impact_times, or with another number of impacts or one at either end, the arrays as they are."""
    t, q, v, u = (np.asarray(arrays[k], float) for k in ("t", "q", "v", "u"))
    impacts = np.atleast_1d(np.asarray(arrays.get("impact_times", []), float))
    T = t[-1] - t[0]
    if len(impacts) != 1 or not t[0] + 1e-9 * T < impacts[0] < t[-1] - 1e-9 * T:
        return t, q, v, u
    k = np.nonzero(np.abs(t - impacts[0]) <= 1e-9 * T)[0][-1]  # the landing's post-impact sample
    perm, along, _ = task.periodic_map(robot)
    shift = np.zeros(q.shape[1])
    shift[along] = task.plan.periodic.step
    dofs = [a.dof for a in robot.actuators]
    motors = [dofs.index(perm[d]) for d in dofs]
    before = slice(1, k + 1)
    return (np.concatenate([t[k:], t[before] + T]) - t[k], np.vstack([q[k:], q[before][:, perm] + shift]),
            np.vstack([v[k:], v[before][:, perm]]), np.vstack([u[k:], u[before][:, motors]]))


def check_walkable(robot: Robot, task: Task) -> list[str]:
    """The two feet of a periodic plan MuJoCo can walk (`planner plan` checks it before the solve: it was refused after
    the plan was solved and written). TaskError for a task without plan.periodic, not two contacts, or a swap that is
    not the leg hinges; InputError when the robot is not the floating planar biped."""
    per = task.plan.periodic if task.plan is not None else None
    if per is None:
        raise TaskError(f"{task_source(task) or 'the task'} has no [plan.periodic]: only a periodic plan can be walked")
    points = [c.point for c in task.contacts]
    if len(points) != 2:
        raise TaskError(f"walking a periodic plan needs two contact points (the feet); the task has {points}")
    lay = find_layout(robot, points[0], points[1])  # (either foot's stance: the same two leg hinges)
    hinges = {robot.dof_names[lay.stance_hinge], robot.dof_names[lay.swing_hinge]}
    if len(per.swap) != 1 or set(per.swap[0]) != hinges:
        raise TaskError(f"plan.periodic.swap must be [{sorted(hinges)}] (the leg hinges) to walk the plan; it is "
                        f"{[list(p) for p in per.swap]}")
    return points


def plan_step(robot: Robot, task: Task, arrays: dict) -> tuple[PinnedBiped, PinnedGait]:
    """A periodic plan's step (result arrays t (P,), q (P, nq), v (P, nv), u (P, nu)) on the pinned model.

    A plan whose one landing (arrays["impact_times"], when given) falls inside the period is first
    rotated to start there (`landing_first`), so the step runs from landing to landing on one stance
    foot. The stance foot is the contact point that moves least along x over the step, the other one
    swings; plan.periodic.swap must exchange exactly their two leg hinges (the relabelling of the walk).
    Of samples at one physical time (a frozen impact) the last, post-impact one is kept, but at the
    step's end the first, pre-impact one: the step runs from a landing's post-impact state to the next
    one's pre-impact state (PinnedGait); u[i] drove sample i-1 to i (planner.result.recover). Raises
    TaskError for a task without plan.periodic, not two contacts, or another swap; InputError when the
    robot is not the floating planar biped.
    """
    points = check_walkable(robot, task)
    t, q, v, u = landing_first(robot, task, arrays)
    dyn = Dynamics(robot)
    travel = [np.ptp(np.array(dyn.point_position(p).map(len(t))(q.T))[0]) for p in points]
    stance, swing = (points[0], points[1]) if travel[0] <= travel[1] else (points[1], points[0])
    model = PinnedBiped(robot, dyn, find_layout(robot, stance, swing))
    lay = model.layout
    # the walk reads the step's last state as the landing's pre-impact one (the impact map, the speed loop's rate):
    # ending on the post-impact sample gave them the stance foot's rebound
    last, first = np.append(np.diff(t) > 0, True), np.insert(np.diff(t) > 0, 0, True)
    keep = np.where(t == t[-1], first, last)
    t, q, v, u = t[keep], q[keep], v[keep], u[keep]
    rows = [lay.stance_hinge, lay.swing_hinge]
    x = np.column_stack([q[:, lay.torso, None] + np.column_stack([q[:, rows], np.zeros(len(t))]),
                         v[:, lay.torso, None] + np.column_stack([v[:, rows], np.zeros(len(t))])])
    return model, PinnedGait(t=t - t[0], x=x, u=u[1:][:, [lay.stance_motor, lay.swing_motor]])


@dataclass(frozen=True, eq=False)
class WalkValidation(ArraysReadOnly):
    """MuJoCo validation of a periodic plan: its step repeated `steps` times on the floating robot
    with the phase-indexed controller (`replay_gait`, WalkControl.PHASE), legs swapped per step.

    Passed when every step is walked (no fall), the plan's own step does not penetrate the
    ground beyond replay.MAX_PENETRATION_M (kinematic replay) nor cross a hole between its samples, and, for
    implicit-Euler samples, its positions move at its velocities and its flights' controls give their motion
    (replay.dynamics_failure; `own_dynamics` records the residual: KinematicReport's flight_steps, max_flight_residual,
    flight_residual_dof, flight_residual_time_s, flight_residual_positions). `to_json()` is the contract's
    `validation` object (mode "walk")."""

    passed: bool
    robot: str
    stance_foot: str
    swing_foot: str
    period_s: float
    max_penetration_m: float
    walking: WalkReport
    failures: tuple[str, ...]
    own_dynamics: Mapping = field(default_factory=dict)  # the own-dynamics keys (above); {} when not checked

    def to_json(self) -> dict:
        return {"passed": self.passed, "mode": "walk", "robot": self.robot, "stance_foot": self.stance_foot,
                "swing_foot": self.swing_foot, "period_s": self.period_s, "max_penetration_m": self.max_penetration_m,
                "steps_asked": self.walking.steps_asked, "steps_walked": self.walking.steps_walked,
                "walking": self.walking.to_json(), **dict(self.own_dynamics), "failures": list(self.failures)}

    def report(self) -> str:
        """A few human-readable lines for the command line."""
        from .replay import own_dynamics_text

        w = self.walking
        steps = np.array(w.step_lengths[:w.steps_walked])
        dt = np.array(w.impact_times[:w.steps_walked]) - np.array(w.planned_impact_times[:w.steps_walked])
        lines = [f"MuJoCo walk of {self.robot}: {'PASSED' if self.passed else 'FAILED'}",
                 f"  steps walked in MuJoCo: {w.steps_walked} of {w.steps_asked}{' then fell' if w.fell else ''} "
                 f"({w.gains.control.value} control, {w.gains.bandwidth:g} rad/s; stance {self.stance_foot}, "
                 f"period {self.period_s:.3f} s)",
                 f"  at the same stance-leg angle: max hinge error {np.rad2deg(w.max_hinge_error):.2f} deg, torso "
                 f"{np.rad2deg(w.max_torso_error):.2f} deg, hip height {w.max_hip_height_error * 1e3:.2f} mm; "
                 f"max torque {w.max_torque:.1f} N m",
                 f"  base against the plan in time: max {w.max_base_error_in_time * 1e3:.1f} mm; step lengths "
                 + (f"{steps.min():.4f}-{steps.max():.4f} m (plan {w.planned_step_length:.4f}); landing times "
                    f"{dt.min() * 1e3:+.1f} to {dt.max() * 1e3:+.1f} ms from the plan's" if steps.size else "none"),
                 f"  kinematic: max penetration {self.max_penetration_m * 1e3:.3f} mm"
                 + own_dynamics_text(self.own_dynamics)]
        return "\n".join(lines + [f"  failed: {f}" for f in self.failures])


def final_low(height: np.ndarray) -> int:
    """Index of the lowest point of the swing foot's final approach (height (N+1,)), from which a landing from below is
    armed: the last local minimum. (The global one was a mid-stance dip of a gait with its torso at 0.2 rad: armed
    there, the replay read a landing mid-stride, swapped the legs and fell, where the gait walks 10 of 10 steps.)"""
    k = len(height) - 1
    while k > 0 and height[k - 1] <= height[k]:
        k -= 1
    return k


def last_apex(height: np.ndarray) -> int:
    """Index of the swing foot's last apex: where its final descent to the landing starts (height (N+1,))."""
    k = len(height) - 1
    while k > 0 and height[k - 1] >= height[k]:
        k -= 1
    return k


def validate_walk(robot: Robot, task: Task, arrays: dict, steps: int = WALK_VALIDATION_STEPS,
                  gains: WalkGains | None = None, dynamics: bool = False) -> WalkValidation:
    """Walk a periodic plan `steps` times in MuJoCo (see WalkValidation); gains default to
    PLAN_WALK_GAINS (phase control with the stride-to-stride speed loop). The swing foot's contact
    and the landing detection are armed from its last apex: the time-freezing plan lets the knee-less
    swing foot graze the ground where the legs cross (docs/formulation.md, "Periodic walking").
    dynamics: the samples are the planner's implicit-Euler steps, whose positions (and flight dynamics) are checked
    as replay.validate_trajectory checks them (the walk reads neither the plan's controls nor its base)."""
    from .replay import MAX_PENETRATION_M, _kinematic, build_scene, dynamics_failure, hole_failure

    _check_steps(steps, "validate_walk")

    model, step = plan_step(robot, task, arrays)
    if not PhaseReference.applies(step.x):
        # a valid plan the phase controller cannot replay: the validation fails (exit 1), the input is fine
        raise SolveError(f"the plan's stance-leg angle ({model.layout.stance_foot}) does not increase monotonically "
                         "over its step (double support or a stance that turns back), so it cannot index the walk's "
                         "reference; the plan was not walked in MuJoCo")
    height = np.array(model.swing_height.map(len(step.t))(step.x[:, :3].T)).ravel()
    walking = replay_gait(model, step, task, steps, PLAN_WALK_GAINS if gains is None else gains,
                          arm_index=last_apex(height))
    kin = _kinematic(build_scene(robot, task), robot, np.asarray(arrays["t"], float), np.asarray(arrays["q"], float),
                     tol=1e-3, task=task, dynamics=arrays if dynamics else None)
    failures = []
    if walking.steps_walked < steps:
        failures.append(f"walked {walking.steps_walked} of {steps} steps in MuJoCo")
    if not kin.max_penetration_m <= MAX_PENETRATION_M:
        failures.append(f"penetration {kin.max_penetration_m:.4g} m > {MAX_PENETRATION_M} m")
    if (through := hole_failure(kin)) is not None:
        failures.append(through)
    if (own := dynamics_failure(kin, tracked=False)) is not None:
        failures.append(own)
    lay = model.layout
    return WalkValidation(passed=not failures, robot=str(robot.path), stance_foot=lay.stance_foot,
                          swing_foot=lay.swing_foot, period_s=float(step.t[-1]),
                          max_penetration_m=kin.max_penetration_m, walking=walking, failures=tuple(failures),
                          own_dynamics=kin.own_dynamics)  # (summary.json kept the verdict alone)
