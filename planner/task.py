"""Task files (TOML): the scene, the initial state, the horizon and the OCP, as frozen dataclasses.

Every key is validated when the file is read: an unknown key, a wrong type or a value out of range
is a `TaskError` naming the key and what is allowed. Robot-dependent checks (vector lengths, point
and joint names, targets inside joint limits) happen in `Task.check_against(robot)`; a plan's need of a motor in
`Task.require_actuators(robot)` (build_problem calls both). Keys are documented in docs/tasks.md.
"""
from __future__ import annotations

import json
import math
import os
import re
import tomllib
import types
import typing
import warnings
from dataclasses import MISSING, asdict, dataclass, field, fields, is_dataclass
from pathlib import Path

import numpy as np

from .errors import (PlannerError, RobotFileError, TaskError, UnknownNameError, check_field_types, expect, plain,
                     read_error, representable)


# gains a_n, a_t [N] (an elastic contact's a_n: a stiffness [1/s^2]) above this make the auxiliary fields stiffer than
# the solves handle: measured, a_n = 1e7 gave a converged Capler plan whose clock ran 1.44x numerical time, a_n = 1e9 a
# point-mass hop running every NLP to its cap for minutes, a_t = 1e9 a free flight gaining 0.2 m/s; the shipped tasks
# use 200-600
MAX_AUX_GAIN = 1e6
# beyond these the solvers' arithmetic overflows: mu = 1e300 filled g with nan, a hole's half-axis 1e-300 its Jacobian
# with inf (mu = 1e6 and a micrometre plan as expected)
MAX_MU = 1e6
# two unit normals of one point this close (each component) are one plane listed twice: rounding of the normalization
SAME_NORMAL_TOL = 1e-9
MIN_HOLE_AXIS_M = 1e-6
# steps of a gait's walk (each a MuJoCo replay of one period): 1e8 failed allocating the tiled walk
MAX_GAIT_STEPS = 1000
# more steps than this are a typo, not a grid (the grids measured go to 10^3): `plan --steps 1000000000` built its NLP
# for ever instead of saying so
MAX_STEPS = 10**7
# a task file's bytes (the shipped ones are < 5 kB; a [simulate] schedule of 20000 controls ~1 MB): a 200 MB array was
# parsed for minutes into 1.9 GB
MAX_TASK_FILE_BYTES = 16 * 2**20
# [m, rad, m/s, rad/s] a start or target coordinate beyond this is a typo (1e300 overflowed into NaNs in the solve)
MAX_STATE = 1e6
# [s] a horizon beyond this is a typo too: the clock t, a state like q and v, runs to about tau_f, so it gets their
# range (11.6 days of motion; the shipped tasks' are 0.6-2.5 s). tau_f = 1e300 overflowed h g into inf and nan: a plan
# failed with a 300-digit physical time in its report, a simulation on a restoration failure of its first step
MAX_HORIZON_S = MAX_STATE
# more NLPs than this in one homotopy are a typo too (the shipped tasks solve 3-5): kappa = 1.0001 scheduled 92109 NLPs
MAX_NLPS = 100


@dataclass(frozen=True)
class Contact:
    """A named point of the robot that may touch a plane: by default the ground z = ground_height.

    normal (3,): the plane's normal (x, 0, z) in the world [unitless, normalized here]; the plane
    passes through (0, 0, ground_height), so the default (0, 0, 1) is the ground. A tilted normal
    makes a wall or a slope (planar robots: the normal must lie in the x-z plane).
    """

    point: str
    mu: float = 0.0  # Coulomb friction coefficient; 0 drops the tangential machinery
    restitution: float = 0.0  # epsilon in [0, 1]: 0 inelastic, > 0 elastic auxiliary ODE (Sec. 4.5)
    a_n: float = 200.0  # normal auxiliary-field gain [N] (elastic: stiffness [1/s^2]); larger = shorter frozen intervals
    a_t: float = 600.0  # tangential auxiliary-field gain [N], a_t >> a_n (Sec. 6)
    normal: tuple[float, ...] = (0.0, 0.0, 1.0)
    touches: bool = True  # false: the task says this point never touches; planning gives it no contact
    # machinery, only the path constraint gap >= 0 (planner.scene)

    def __post_init__(self):
        _typed(self, "contacts")
        _require(len(self.normal) == 3, "contacts.normal", list(self.normal), "3 numbers (x, y, z)")
        # neither overflows (1e200) nor underflows (1e-200) as a sum of squares does; beyond 1.3e308 it is inf
        norm = math.hypot(*self.normal)
        _require(0 < norm < math.inf and self.normal[1] == 0.0, "contacts.normal", list(self.normal),
                 "a nonzero vector in the x-z plane (y = 0) of finite length (below 1.8e308)")
        if abs(norm - 1.0) > 4e-16:  # a unit normal to rounding is kept: a task read back from its JSON equals itself
            object.__setattr__(self, "normal", tuple(float(x) / norm for x in self.normal))
        _require(0 <= self.mu <= MAX_MU, "contacts.mu", self.mu, f"in [0, {MAX_MU:g}]")
        _require(0.0 <= self.restitution <= 1.0, "contacts.restitution", self.restitution, "in [0, 1]")
        _require(0 < self.a_n <= MAX_AUX_GAIN, "contacts.a_n", self.a_n, f"in (0, {MAX_AUX_GAIN:g}]")
        _require(0 < self.a_t <= MAX_AUX_GAIN, "contacts.a_t", self.a_t, f"in (0, {MAX_AUX_GAIN:g}]")
        # (read only by a contact with friction: it was accepted and ignored with mu = 0)
        _require(self.mu > 0 or self.a_t == Contact.a_t, "contacts.a_t", self.a_t,
                 f"left out with mu = 0 (only a contact with friction reads it; its default is {Contact.a_t:g})")

    def beyond(self, ground_height: float) -> str:
        """Where a negative gap puts this point: "below the ground (z = 0)", or behind a tilted plane."""
        if self.normal == (0.0, 0.0, 1.0):
            return f"below the ground (z = {ground_height:g})"
        return f"behind its plane (normal ({', '.join(f'{x:g}' for x in self.normal)}) through z = {ground_height:g})"


@dataclass(frozen=True)
class Initial:
    """Initial state in physical coordinates: q (nq,) [m, rad], v (nv,) [m/s, rad/s]."""

    q: tuple[float, ...]
    v: tuple[float, ...] | None = None  # zeros when omitted

    def __post_init__(self):
        _typed(self, "initial")
        _require_state(self.q, "initial.q")
        _require_state(self.v, "initial.v")


@dataclass(frozen=True)
class Horizon:
    """Numerical-time horizon tau_f [s] split into N implicit-Euler steps of h = tau_f / N."""

    tau_f: float
    N: int
    physical_time: float | None = None  # T [s]: adds speed of time s >= 1 with t(tau_f) = T
    # upper bound of every s_k [unitless]; none: unbounded (the clock's catch-up went into a few steps 6-9 h long)
    max_time_speed: float | None = None

    def __post_init__(self):
        _typed(self, "horizon")
        _require(self.tau_f > 0, "horizon.tau_f", self.tau_f, "> 0")
        _require(self.tau_f <= MAX_HORIZON_S, "horizon.tau_f", self.tau_f, f"at most {MAX_HORIZON_S:g} s")
        _require(1 <= self.N <= MAX_STEPS, "horizon.N", self.N, f"in [1, {MAX_STEPS}]")
        if self.physical_time is not None:
            _require(0 < self.physical_time <= self.tau_f, "horizon.physical_time", self.physical_time, "in (0, tau_f]")
        if self.max_time_speed is not None:
            _require(self.physical_time is not None, "horizon.max_time_speed", self.max_time_speed,
                     "left out without horizon.physical_time (it bounds the speed of time physical_time adds)")
            _require(self.max_time_speed >= 1, "horizon.max_time_speed", self.max_time_speed,
                     ">= 1 (the speed of time s is at least 1)")

    @property
    def h(self) -> float:
        return self.tau_f / self.N


@dataclass(frozen=True)
class Ellipse:
    """A hole or obstacle the contact points must stay out of: centre (x, z), semi-axes a, b [m]; a point (px, pz)
    is outside when ((px - x)/a)^2 + ((pz - z)/b)^2 >= 1."""

    x: float
    a: float
    b: float
    z: float = 0.0

    def __post_init__(self):
        _typed(self, "plan.holes")
        for key in ("a", "b"):
            _require(getattr(self, key) >= MIN_HOLE_AXIS_M, f"plan.holes.{key}", getattr(self, key),
                     f">= {MIN_HOLE_AXIS_M:g} (a micrometre)")
        for key in ("x", "z", "a", "b"):  # (a hole at x = 1e300 overflowed into IPOPT's Invalid_Number_Detected)
            _require(abs(getattr(self, key)) <= MAX_STATE, f"plan.holes.{key}", getattr(self, key),
                     f"within ±{MAX_STATE:g} m")

    def metric(self, x, z):
        """((x - self.x)/a)^2 + ((z - self.z)/b)^2 of points x, z [m] (floats, arrays or CasADi expressions): 1 on the
        rim, below 1 inside."""
        return ((x - self.x) / self.a) ** 2 + ((z - self.z) / self.b) ** 2


@dataclass(frozen=True)
class Homotopy:
    """l_inf penalty homotopy: rho_k = rho0 * kappa^k, k = 0 .. n_nlp-1. scale_variables: the NLPs after
    the first see every variable divided by its largest magnitude in NLP 1's solution
    (planner.homotopy.VariableScaling.FIRST_NLP; measured per task, docs/formulation.md round 6)."""

    rho0: float = 1.0
    kappa: float = 10.0
    n_nlp: int = 5
    scale_variables: bool = False

    def __post_init__(self):
        _typed(self, "plan.homotopy")
        _require(self.rho0 > 0, "plan.homotopy.rho0", self.rho0, "> 0")
        _require(self.kappa > 1, "plan.homotopy.kappa", self.kappa, "> 1")
        _require(1 <= self.n_nlp <= MAX_NLPS, "plan.homotopy.n_nlp", self.n_nlp, f"in [1, {MAX_NLPS}]")
        # rho0 kappa^(n_nlp - 1) overflowed to inf (a nan solve) or raised OverflowError
        last = math.log10(self.rho0) + (self.n_nlp - 1) * math.log10(self.kappa)
        _require(last <= 300, "plan.homotopy", {"rho0": self.rho0, "kappa": self.kappa, "n_nlp": self.n_nlp},
                 "a schedule whose last penalty rho0 kappa^(n_nlp - 1) is at most 1e300")


@dataclass(frozen=True)
class JointBound:
    """Bounds on one joint position [m or rad]; they replace the robot file's limits."""

    joint: str
    lower: float = -math.inf
    upper: float = math.inf

    def __post_init__(self):
        _typed(self, "plan.joint_bounds")
        _require(self.lower <= self.upper, "plan.joint_bounds.lower", self.lower,
                 f"<= upper ({self.upper}) of joint {self.joint!r}")


@dataclass(frozen=True)
class VelocityBound:
    """lower <= sum of the named coordinates' velocities <= upper [m/s or rad/s] at every node of the
    plan. A planar link's angle to the vertical is the sum of the joint angles from the floating base
    to it, so its angular velocity is a sum of joint rates: e.g. ["torso", "hinge_1"] is the biped's
    leg 1 (robots/biped.toml), whose increasing angle is the phase variable of its walk replay."""

    joints: tuple[str, ...]
    lower: float = -math.inf
    upper: float = math.inf

    def __post_init__(self):
        _typed(self, "plan.velocity_bounds")
        _require(len(self.joints) > 0 and len(set(self.joints)) == len(self.joints), "plan.velocity_bounds.joints",
                 list(self.joints), "one or more different joint names")
        _require(self.lower <= self.upper, "plan.velocity_bounds.lower", self.lower, f"<= upper ({self.upper})")
        _require(math.isfinite(self.lower) or math.isfinite(self.upper), "plan.velocity_bounds.lower/upper",
                 [self.lower, self.upper], "a finite lower or upper bound")


@dataclass(frozen=True)
class Periodic:
    """One step of a periodic gait (`plan.periodic`): q(tau_f) = S q(0) + step e_along and
    v(tau_f) = S v(0), S the relabelling that swaps each pair of coordinates in `swap`; the
    initial state becomes a decision variable except the coordinates in `fixed`, which keep their
    values from initial.q (initial.q and initial.v are the initial guess of y_0)."""

    step: float  # shift of coordinate `along` over one period [m or rad]
    along: str = "x"  # the coordinate that advances by `step`
    swap: tuple[tuple[str, ...], ...] = ()  # pairs of coordinates (joint names) exchanged by S
    fixed: tuple[str, ...] = ("x",)  # coordinates of q(0) fixed to initial.q
    v_bound: float | None = None  # |v_i(0)| <= v_bound on the free initial velocity; none: free

    def __post_init__(self):
        _typed(self, "plan.periodic")
        _require(math.isfinite(self.step), "plan.periodic.step", self.step, "a finite number")
        seen = []
        for i, pair in enumerate(self.swap):
            _require(len(pair) == 2 and pair[0] != pair[1], f"plan.periodic.swap[{i}]", list(pair),
                     "two different coordinate names, e.g. [\"hinge_1\", \"hinge_2\"]")
            _require(not set(pair) & set(seen), f"plan.periodic.swap[{i}]", list(pair), "names not already in another pair")
            seen += list(pair)
        _require(len(set(self.fixed)) == len(self.fixed), "plan.periodic.fixed", list(self.fixed), "without repeated names")
        if self.v_bound is not None:
            _require(self.v_bound > 0, "plan.periodic.v_bound", self.v_bound, "> 0")


@dataclass(frozen=True)
class Plan:
    """The optimal control problem: reach target_q at tau_f minimizing the integral of u^2, or,
    with `periodic`, one step of a periodic gait (target_q then must be omitted)."""

    target_q: tuple[float, ...] | None = None  # required unless periodic
    target_v: tuple[float, ...] | None = None  # zeros when omitted
    rho_f: float = 1.0  # weight of ||sigma - sigma*||^2 (regularized implicit Euler)
    homotopy: Homotopy = field(default_factory=Homotopy)
    holes: tuple[Ellipse, ...] = ()
    above_ground: tuple[str, ...] = ()  # named points kept at z >= ground_height (knee, base, ...)
    joint_bounds: tuple[JointBound, ...] = ()
    velocity_bounds: tuple[VelocityBound, ...] = ()  # on sums of joint velocities at every node
    u_bound: float | None = None  # |u_i| <= u_bound; default: the actuators' ctrlrange
    periodic: Periodic | None = None  # one step of a periodic gait instead of a target

    def __post_init__(self):
        _typed(self, "plan")
        joints = [b.joint for b in self.joint_bounds]
        _require(len(set(joints)) == len(joints), "plan.joint_bounds", joints, "one entry per joint (which one "
                                                                                  "would hold?)")
        # (a repeat doubled the rows: dependent constraints handed to IPOPT)
        _require(len(set(self.above_ground)) == len(self.above_ground), "plan.above_ground", list(self.above_ground),
                 "each point once")
        first: dict = {}  # hole -> its first index (a list's `in` took 56 s for 20000 holes)
        for i, h in enumerate(self.holes):
            _require(h not in first, f"plan.holes[{i}]", [h.x, h.z, h.a, h.b],
                     f"each hole once (it repeats plan.holes[{first.get(h)}])")  # (every hole was listed)
            first[h] = i
        if self.periodic is None and self.target_q is None:
            raise TaskError("missing key 'plan.target_q' (required unless plan.periodic is given)")
        if self.periodic is not None:
            for key in ("target_q", "target_v"):
                _require(getattr(self, key) is None, f"plan.{key}", list(getattr(self, key) or ()),
                         "omitted with plan.periodic (the end state is the relabelled, shifted initial state)")
        _require(self.rho_f >= 0, "plan.rho_f", self.rho_f, ">= 0")
        _require_state(self.target_q, "plan.target_q")
        _require_state(self.target_v, "plan.target_v")
        if self.u_bound is not None:
            _require(self.u_bound > 0, "plan.u_bound", self.u_bound, "> 0")


@dataclass(frozen=True)
class ControlChange:
    """From physical time t [s] on, the simulation applies controls u (nu,) [N m or N]."""

    t: float
    u: tuple[float, ...]

    def __post_init__(self):
        _typed(self, "simulate.schedule")
        _require(self.t >= 0, "simulate.schedule.t", self.t, ">= 0")


@dataclass(frozen=True)
class JointPD:
    """Joint PD feedback of the simulation, added to the scheduled controls.

    For each named joint j (driven by one actuator of gear g): u += (kp_j (q_ref_j - q_j) - kd_j v_j) / g,
    evaluated at the end of each implicit Euler step (an implicit controller). kp (len(joints),)
    [N m/rad or N/m], kd (len(joints),) [N m s/rad or N s/m], q_ref (len(joints),) [rad or m],
    default: the joints' values in initial.q. Not saturated (docs/tasks.md).
    """

    joints: tuple[str, ...]
    kp: tuple[float, ...]
    kd: tuple[float, ...]
    q_ref: tuple[float, ...] | None = None

    def __post_init__(self):
        _typed(self, "simulate.pd")
        n = len(self.joints)
        _require(n >= 1, "simulate.pd.joints", list(self.joints), "at least one joint name")
        _require(len(set(self.joints)) == n, "simulate.pd.joints", list(self.joints), "without repeated names")
        for key in ("kp", "kd") + (("q_ref",) if self.q_ref is not None else ()):
            values = getattr(self, key)
            _require(len(values) == n, f"simulate.pd.{key}", list(values), f"{n} number{'s' if n != 1 else ''}, one per joint in simulate.pd.joints")
            _require(all(math.isfinite(x) for x in values), f"simulate.pd.{key}", list(values), "finite")
        _require(all(x >= 0 for x in self.kp), "simulate.pd.kp", list(self.kp), ">= 0")
        _require(all(x >= 0 for x in self.kd), "simulate.pd.kd", list(self.kd), ">= 0")


@dataclass(frozen=True)
class Simulate:
    """Forward simulation: controls u (nu,) [N m or N] (zero when omitted), changed by `schedule`
    at given physical times, plus an optional joint PD (`pd`), and the weight rho_f of the
    regularized implicit Euler scheme."""

    u: tuple[float, ...] | None = None
    schedule: tuple[ControlChange, ...] = ()  # strictly increasing t; each entry replaces u from its time on
    rho_f: float = 1.0  # weight of ||sigma - sigma*||^2; 0 gives the plain implicit Euler MPCC (Fig. 5)
    pd: JointPD | None = None  # joint PD feedback added to u (none when omitted)

    def __post_init__(self):
        _typed(self, "simulate")
        _require(self.rho_f >= 0, "simulate.rho_f", self.rho_f, ">= 0")
        times = [c.t for c in self.schedule]
        _require(all(a < b for a, b in zip(times, times[1:])), "simulate.schedule", times,
                 "sorted by strictly increasing t (two entries at one time: which would act?)")

    def controls_at(self, t: float, nu: int) -> np.ndarray:
        """Controls (nu,) in force at physical time t [s]."""
        u = np.zeros(nu) if self.u is None else np.array(self.u, dtype=float)
        for change in self.schedule:
            if t >= change.t:
                u = np.array(change.u, dtype=float)
        return u


GAIT_DESIRED_INPUTS = ("inverse_dynamics", "zero")


@dataclass(frozen=True)
class GaitContinuation:
    """Steps 2 and 3 of paper 001's Sec. 3: penalty continuation and Newton on the target x_T.

    rho_emb, rho_f: initial penalty weights; each is multiplied by `factor` per outer loop while
    its goal is not met: max |u_emb| < emb_tolerance [N m] (step 2), then ||x(T) - x_f|| <=
    newton_radius (step 3), after which Newton on x_T drives ||x(T) - x_f|| < final_tolerance.
    """

    rho_emb: float = 1.0
    rho_f: float = 10.0
    factor: float = 2.0
    emb_tolerance: float = 1e-3  # [N m]
    newton_radius: float = 0.1  # 2-norm over (rad, rad/s)
    final_tolerance: float = 1e-8  # 2-norm over (rad, rad/s)
    max_outer: int = 60  # outer loops (PRONTO solves) over both steps

    def __post_init__(self):
        _typed(self, "gait.continuation")
        _require(self.rho_emb > 0, "gait.continuation.rho_emb", self.rho_emb, "> 0")
        _require(self.rho_f > 0, "gait.continuation.rho_f", self.rho_f, "> 0")
        _require(self.factor > 1, "gait.continuation.factor", self.factor, "> 1")
        _require(self.emb_tolerance > 0, "gait.continuation.emb_tolerance", self.emb_tolerance, "> 0")
        _require(self.newton_radius > 0, "gait.continuation.newton_radius", self.newton_radius, "> 0")
        _require(self.final_tolerance > 0, "gait.continuation.final_tolerance", self.final_tolerance, "> 0")
        _require(self.max_outer >= 1, "gait.continuation.max_outer", self.max_outer, ">= 1")


@dataclass(frozen=True)
class GaitPronto:
    """The inner PRONTO solver: iteration limit, stopping tolerance on the predicted decrease
    (-Dg.zeta, absolute), and the continuous-time LQR weights of its projection feedback
    (state (6,) [1/rad^2, s^2/rad^2 per s], input (2,) [1/(N m)^2 per s]; the fictitious torso input
    of step 2 uses the last input weight)."""

    max_iterations: int = 50
    tolerance: float = 1e-12
    feedback_q: tuple[float, ...] = (100.0, 100.0, 100.0, 1.0, 1.0, 1.0)
    feedback_r: tuple[float, ...] = (0.01, 0.01)

    def __post_init__(self):
        _typed(self, "gait.pronto")
        _require(self.max_iterations >= 1, "gait.pronto.max_iterations", self.max_iterations, ">= 1")
        _require(self.tolerance > 0, "gait.pronto.tolerance", self.tolerance, "> 0")
        _require(len(self.feedback_q) == 6 and min(self.feedback_q) >= 0, "gait.pronto.feedback_q", list(self.feedback_q), "6 numbers >= 0")
        _require(len(self.feedback_r) == 2 and min(self.feedback_r) > 0, "gait.pronto.feedback_r", list(self.feedback_r), "2 numbers > 0")


@dataclass(frozen=True)
class Gait:
    """A periodic walking gait of a floating planar biped (paper 001): one step of period
    horizon.tau_f [s] on horizon.N steps, from x0 = (theta1, theta2, theta3 [rad], their rates
    [rad/s]) of the pinned stance model, ending on Delta^-1(x0) in the jump set theta1 = jump_angle.
    Cost 1/2 int ||x - x_d||_Q^2 + ||u - u_d||_R^2 with diagonal Q (6,) and R (2,); x_d is the cubic
    Hermite curve between x0 and Delta^-1(x0), u_d its inverse-dynamics input or zero."""

    x0: tuple[float, ...]
    jump_angle: float  # [rad]
    q_weights: tuple[float, ...]
    r_weights: tuple[float, ...]
    desired_input: str = "inverse_dynamics"  # one of GAIT_DESIRED_INPUTS
    stance: str = "foot_1"  # stance foot of the first step (a point of the robot)
    swing: str = "foot_2"
    steps: int = 4  # steps of the periodic walk written to trajectory.npz and replayed in MuJoCo
    continuation: GaitContinuation = field(default_factory=GaitContinuation)
    pronto: GaitPronto = field(default_factory=GaitPronto)

    def __post_init__(self):
        _typed(self, "gait")
        _require(len(self.x0) == 6, "gait.x0", list(self.x0), "6 numbers (theta1, theta2, theta3, and their rates)")
        _require(len(self.q_weights) == 6 and min(self.q_weights) >= 0, "gait.q_weights", list(self.q_weights), "6 numbers >= 0")
        _require(len(self.r_weights) == 2 and min(self.r_weights) > 0, "gait.r_weights", list(self.r_weights), "2 numbers > 0")
        _require(self.desired_input in GAIT_DESIRED_INPUTS, "gait.desired_input", self.desired_input,
                 " or ".join(repr(x) for x in GAIT_DESIRED_INPUTS))
        _require(self.stance != self.swing, "gait.swing", self.swing, f"a point other than gait.stance ({self.stance!r})")
        _require(1 <= self.steps <= MAX_GAIT_STEPS, "gait.steps", self.steps, f"in [1, {MAX_GAIT_STEPS}]")


def contact_labels(contacts) -> tuple[str, ...]:
    """One label per contact: its point name, or `point#k` (k = 1, 2, ...) for a point listed
    several times (e.g. one point against two walls)."""
    points = [c.point for c in contacts]
    seen: dict[str, int] = {}
    labels = []
    for p in points:
        seen[p] = seen.get(p, 0) + 1
        labels.append(p if points.count(p) == 1 else f"{p}#{seen[p]}")
    return tuple(labels)


@dataclass(frozen=True)
class Task:
    """A whole task file."""

    contacts: tuple[Contact, ...]
    initial: Initial
    horizon: Horizon
    ground_height: float = 0.0  # [m]
    plan: Plan | None = None
    simulate: Simulate = field(default_factory=Simulate)
    gait: Gait | None = None  # a periodic gait for `planner gait` (docs/tasks.md)
    # path of the file it came from, for messages; not a TOML key, nor part of a task's equality (a task read back from
    # a plan's trajectory.npz, or the same file by another path, is the same task: a replan walked between equal tasks)
    source: str = field(default="", compare=False)

    def __post_init__(self):
        _typed(self, "")
        _require(abs(self.ground_height) <= MAX_STATE, "ground_height", self.ground_height, f"within ±{MAX_STATE:g} m")
        planes = [(c.point, c.normal) for c in self.contacts]
        # a point may touch several planes (a corner), but the same plane twice doubles its contact forces (normals
        # normalized apart by rounding, [1, 0, 1] and [3, 0, 3], were two planes: two half impacts)
        twice = any(p == q and max(abs(a - b) for a, b in zip(m, n)) <= SAME_NORMAL_TOL
                    for i, (p, m) in enumerate(planes) for q, n in planes[i + 1:])
        _require(not twice, "contacts", [f"{p} {list(n)}" for p, n in planes],
                 "one entry per point and plane (a point repeats only with another normal, a corner)")
        # a repeated point's planes are labelled point#1, point#2, ...: a point of that name would share a label with
        # one of them, and the forces and selectors looked up by label were the other's
        points = [c.point for c in self.contacts]
        for j, label in enumerate(contact_labels(self.contacts)):
            if label != points[j] and label in points:
                _require(False, f"contacts[{points.index(label)}].point", label,
                         f"another name than contacts[{j}]'s label: point {points[j]!r} on several planes is labelled "
                         f"{points[j]}#1, {points[j]}#2, ... (rename the point in the robot file)")
        # touches = false drops a point's contact machinery, so it is the point's, not one plane's: false on one plane
        # of a corner dropped the other plane's contact as well, silently
        mixed = sorted({c.point for c in self.contacts} & {c.point for c in self.contacts if not c.touches}
                       & {c.point for c in self.contacts if c.touches})
        _require(not mixed, "contacts", [f"{c.point} touches = {str(c.touches).lower()}" for c in self.contacts
                                         if c.point in mixed],
                 "the same touches on every entry of a point (touches = false says the point never touches any "
                 "plane)")

    def check_no_slip_forces(self, robot) -> None:
        """TaskError for a touching contact with friction whose point cannot move along its plane and its normal
        independently at initial.q: its no-slip force solves [n t]^T M^-1 [n t] lambda = ..., singular there, NaN in
        every step (a one-hinge hammer's head: a simulation ran 170794 IPOPT iterations). Simulations and plans only:
        a replay needs no force. A frictionless point that cannot move along its plane's normal at initial.q is
        refused too, on its plane or not: its force divides by n^T M^-1 n = 0 (Capler's massless carriage as a contact
        wrote lambda_n = inf with exit 0; an arm hanging straight down, its tip 0.2 m up, stopped at step 0 on IPOPT's
        Invalid_Number_Detected)."""
        for i, c in enumerate(self.contacts):
            if not c.touches:
                continue
            if c.mu == 0:
                _, normal_rank, _ = robot.contact_rank([(c.point, c.normal, False)], self.initial.q,
                                                       self.ground_height, touch_tol=math.inf)
                if normal_rank == 0:
                    raise TaskError(f"contacts[{i}] ({c.point}) cannot move along its plane's normal at initial.q, so "
                                    "its contact force is undefined there (a division by zero in the solve): start "
                                    "from another pose, or give the robot a degree of freedom that moves it so")
                continue
            _, normal_rank, rank = robot.contact_rank([(c.point, c.normal, True)], self.initial.q, self.ground_height,
                                                      touch_tol=math.inf)
            if rank == 2:
                continue
            how = ("cannot move at all" if rank == 0 else "cannot move along its plane's normal" if normal_rank == 0
                   else "cannot move along its plane independently of its normal")
            raise TaskError(f"contacts[{i}] ({c.point}) with friction {how} at initial.q, so its no-slip force is "
                            "undefined there (NaN in the solve): give it mu = 0 (no friction), start from another "
                            "pose, or give the robot a degree of freedom that moves it so")

    @property
    def is_periodic(self) -> bool:
        """Whether the task plans one step of a periodic gait (plan.periodic) instead of reaching a target."""
        return self.plan is not None and self.plan.periodic is not None

    def check_against(self, robot) -> None:
        """Robot-dependent validation: names exist, lengths match, targets are inside the limits; the robot's physics
        is what the planner models (no passive joint forces, contact points in the x-z plane). An error in the task
        names its file first (source), as load_task's do."""
        from .model import Robot

        expect(robot, Robot, "check_against's robot")
        try:
            self._check_against(robot)
        except (TaskError, UnknownNameError) as exc:  # ("contacts[0].point: unknown ..." named no file)
            if self.source:
                exc.args = (f"{task_source(self)}: {exc}",)
            raise

    def require_actuators(self, robot) -> None:
        """TaskError unless the robot has a motor to plan with (the plan's check; a simulation of a file without
        motors reads no [plan] table, and its task was refused for having one)."""
        from .model import RobotFormat  # here: reading a task needs no Pinocchio

        if robot.nu == 0:
            urdf = (" (a URDF joint is actuated by its <limit effort> > 0; <transmission> elements are not read)"
                    if robot.format is RobotFormat.URDF else "")
            raise TaskError(f"{task_source(self) + ': ' if self.source else ''}the task has a [plan] but robot "
                            f"{robot.name!r} has no actuators to plan with{urdf}")

    def _check_against(self, robot) -> None:
        from .model import RobotFormat  # here: reading a task needs no Pinocchio

        model = robot.model
        unplanar = [model.names[j] for j in range(1, model.njoints) if model.joints[j].nq != model.joints[j].nv]
        if unplanar:  # (a task without contacts reached a CasADi dimension mismatch: a traceback, exit 1)
            raise RobotFileError(f"{robot.path}: joint(s) {', '.join(unplanar)} have more coordinates than velocities "
                                 "(a free, ball or URDF planar joint, Pinocchio's free flyer, or a continuous joint: "
                                 "make that one revolute with limits): the planner takes slide and hinge joints (a "
                                 "floating planar base: slide x, slide z and a hinge about y)")
        if robot.passive:  # MuJoCo's replay applies them, the planner's dynamics do not
            raise RobotFileError(f"{robot.path}: {'; '.join(robot.passive)}: the planner's dynamics have neither passive joint "
                                 "forces (damping, stiffness, friction) nor couplings between joints; remove them from the robot "
                                 "file to simulate or plan")
        from .check import reading_differences

        differences = reading_differences(robot)
        if differences:  # the plan or simulation would be for physics the MuJoCo replay (the validation) does not have
            raise RobotFileError(f"{robot.path}: MuJoCo reads other physics from this file than Pinocchio, whose reading the "
                                 f"planner's dynamics are: {'; '.join(differences)}; `planner check-model {robot.path}` compares "
                                 "the two readings")
        for i, c in enumerate(self.contacts):
            if c.point not in robot.points:  # the valid ones are the sites: a body named here is refused below
                _not_on_the_world(c.point, robot, f"contacts[{i}].point")
                raise UnknownNameError("contact point", c.point, robot.sites, f"contacts[{i}].point")
            if c.point not in robot.sites:  # MuJoCo's replay has no site of that name (validate failed later)
                raise TaskError(f"contacts[{i}].point: contact point {c.point!r} is an MJCF body, not a site; add "
                                f"<site name=\"...\"/> where the body touches and name it (sites: "
                                f"{', '.join(sorted(robot.sites)) or 'none'})")
            rates = robot.out_of_plane_rates(c.point)
            if rates:
                largest = ", ".join(f"{j} {r:.3g}" for j, r in sorted(rates.items(), key=lambda item: -item[1]))
                tiny = (" (so small a rate is a joint axis a little off y in the robot file, e.g. a rounded rpy or "
                        "axis: write it to full precision)" if max(rates.values()) < 1e-4 else "")
                raise TaskError(f"contact point {c.point!r} can move along y: the planner's contacts are planar (normal and "
                                "friction in the x-z plane), so it would slide along y without friction; dy/dq up to "
                                f"{largest} (m per m or rad) at seeded postures{tiny}")
        kept = {robot.carrier(c.point) for c in self.contacts}  # (by the joint that moves them: a URDF's fixed links)
        kept |= {robot.carrier(p) for p in (self.plan.above_ground if self.plan else ()) if p in robot.points}
        loose = [b for b in robot.colliding if robot.carrier(b, body=True) not in kept | {0}]
        if loose:  # MuJoCo's replay clears their collisions as well (replay.build_scene): a knee in the ground passed
            mjcf = robot.format is RobotFormat.MJCF
            what, where = ("geoms", "site on") if mjcf else ("<collision>s", "link fixed to")
            warnings.warn(f"{robot.path}: the {what} of {', '.join(map(repr, loose))} collide in MuJoCo, but no "
                          "contact point of the task is on them: the plan or simulation and its validation let them "
                          f"pass through the ground; list a {where} each in contacts (touches = false keeps it above "
                          "the ground) or plan.above_ground, or "
                          + ("set the geoms' contype and conaffinity to 0" if mjcf else "remove the <collision>s"))
        if robot.ground_z is not None and abs(robot.ground_z - self.ground_height) > GROUND_MISMATCH_M:
            # (the task's value left out: a replan's walk checks tasks in between, which warned once each)
            warnings.warn(f"the robot file's ground plane (geom {robot.ground_geom!r}) is at z = {robot.ground_z:g} m, "
                          "not at the task's ground_height: the planner and MuJoCo's replay use the task's; set "
                          "ground_height to the file's if that is the ground meant")
        if robot.scenery:  # the replay clears their collisions too (replay.build_scene): a step was passed through
            warnings.warn(f"{robot.path}: the world's geom(s) {', '.join(map(repr, robot.scenery))} can collide in "
                          "MuJoCo (contype or conaffinity nonzero), but the planner and its validation model the "
                          "ground plane only (the plane named 'ground', else the file's only plane if level): a plan "
                          "or simulation may pass through them; set their contype and conaffinity to 0 if they are "
                          "decoration")
        _length("initial.q", self.initial.q, robot.nq, robot)
        if self.initial.v is not None:
            _length("initial.v", self.initial.v, robot.nv)
        robot.check_inertia(self.initial.q)
        for key, u in self._constant_controls():
            _length(key, u, robot.nu)
        if self.simulate.pd is not None:
            self.pd_actuators(robot)
        if self.plan is None:
            return
        for i, p in enumerate(self.plan.above_ground):
            if p not in robot.points:
                _not_on_the_world(p, robot, f"plan.above_ground[{i}]")
                raise UnknownNameError("point", p, robot.points, f"plan.above_ground[{i}]")
        self.velocity_rows(robot)
        for r, b in enumerate(self.plan.joint_bounds):
            i = robot.dof_index(b.joint, f"plan.joint_bounds[{r}].joint")
            lo, hi = robot.q_lower[i], robot.q_upper[i]
            if b.lower < lo or b.upper > hi:  # (an unlimited joint reads +-inf here: never wider)
                warnings.warn(f"plan.joint_bounds[{r}] ({b.joint}: [{b.lower:g}, {b.upper:g}]) goes beyond the robot "
                              f"file's range {robot.range_text(i)}, which MuJoCo's replay enforces; the plan may leave "
                              "it (the report names a joint it left)")
        wider = [f"{a.name} [{a.lower:g}, {a.upper:g}]" for a in robot.actuators
                 if self.plan.u_bound is not None and (-self.plan.u_bound < a.lower or self.plan.u_bound > a.upper)]
        if wider:  # (as joint_bounds: the replay's saturation was the first a user heard of it)
            warnings.warn(f"plan.u_bound = {self.plan.u_bound:g} goes beyond the robot file's control range of "
                          f"{', '.join(wider)}, which MuJoCo's replay clamps to; the plan may use more")
        if self.plan.periodic is not None:
            self.periodic_map(robot)
            return
        _length("plan.target_q", self.plan.target_q, robot.nq)
        if self.plan.target_v is not None:
            _length("plan.target_v", self.plan.target_v, robot.nv)
        lower, upper = self.q_bounds(robot)
        bounded = {b.joint: r for r, b in enumerate(self.plan.joint_bounds)}  # (the task's, named as such)
        for key, q in (("initial.q", self.initial.q), ("plan.target_q", self.plan.target_q)):
            # the plan's first node is bounded too: a start outside jumped onto the bound in one step
            for i, (qi, lo, hi) in enumerate(zip(q, lower, upper)):
                if not lo <= qi <= hi:
                    name = robot.dof_names[i]
                    whose = f"plan.joint_bounds[{bounded[name]}]" if name in bounded else "the robot file's limits"
                    raise TaskError(f"{key}[{i}] = {qi} ({name}) is outside the joint bounds "
                                    f"{robot.range_text(i, lo, hi)} ({whose})")

    def _constant_controls(self) -> list[tuple[str, tuple[float, ...]]]:
        """(task key, controls (nu,)) of simulate.u and each schedule entry."""
        controls = [("simulate.u", self.simulate.u)] if self.simulate.u is not None else []
        return controls + [(f"simulate.schedule[{i}].u", change.u) for i, change in enumerate(self.simulate.schedule)]

    def warn_controls_beyond_range(self, robot) -> None:
        """Warn for each constant simulate.u or schedule control beyond its actuator's range (MuJoCo's replay clamps
        it; the simulation does not), for each simulate.pd.q_ref beyond its joint's range and each schedule entry at
        or after the horizon's end. For `simulate` only: plan and validate do not use these controls. Lengths are
        check_against's."""
        for key, u in self._constant_controls():
            for j, (uj, a) in enumerate(zip(u, robot.actuators)):
                if not a.lower <= uj <= a.upper:  # a PD's controls are counted in summary.json instead
                    warnings.warn(f"{key}[{j}] = {uj:g} ({a.name}) is beyond the actuator's range [{a.lower:g}, "
                                  f"{a.upper:g}], to which MuJoCo's replay clamps it")
        for i, change in enumerate(self.simulate.schedule):
            if change.t >= self.horizon.tau_f:  # (physical time never gets there: t = 100 for 0.1 s went unsaid)
                warnings.warn(f"simulate.schedule[{i}].t = {change.t:g} s is not before the horizon's end (tau_f = "
                              f"{self.horizon.tau_f:g} s of numerical time, physical time at most that): it never acts")
        pd = self.simulate.pd
        if pd is not None and pd.q_ref is not None:  # (degrees for radians: a failed step 0, exit 1, unwarned)
            for j, (iq, _, _) in enumerate(self.pd_actuators(robot)):
                lo, hi = robot.q_lower[iq], robot.q_upper[iq]
                if not lo <= pd.q_ref[j] <= hi:
                    warnings.warn(f"simulate.pd.q_ref[{j}] = {pd.q_ref[j]:g} ({pd.joints[j]}) is beyond the joint's "
                                  f"range {robot.range_text(iq)}")

    def periodic_map(self, robot) -> tuple[np.ndarray, int, np.ndarray]:
        """plan.periodic as indices: (perm (nq,), the index of `along`, the fixed q indices), with
        (S q)[i] = q[perm[i]]. Raises UnknownNameError for an unknown coordinate and TaskError for a
        robot whose q and v coordinates differ (nq != nv) or for initial.q outside the joint bounds, and for a task
        without plan.periodic."""
        per = None if self.plan is None else self.plan.periodic
        if per is None:  # (an AttributeError on NoneType through the API)
            raise TaskError("the task has no plan.periodic")
        if robot.nq != robot.nv:
            raise TaskError(f"plan.periodic needs a robot with nq == nv (one coordinate per joint); {robot.name!r} has "
                            f"nq = {robot.nq}, nv = {robot.nv}")
        perm = np.arange(robot.nq)
        for pair in per.swap:
            i, j = (robot.dof_index(name, "plan.periodic.swap") for name in pair)
            perm[i], perm[j] = j, i
        # (a robot whose forward base joint is not named x was told of an 'x' its task file does not have)
        by_default = " (by default 'x', the forward base joint: name yours in along and fixed)"
        along = robot.dof_index(per.along, "plan.periodic.along" + (by_default if per.along == Periodic.along else ""))
        key = "plan.periodic.fixed" + (by_default if per.fixed == Periodic.fixed else "")
        fixed = np.array([robot.dof_index(name, key) for name in per.fixed], dtype=int)
        lower, upper = self.q_bounds(robot)
        for i, (qi, lo, hi) in enumerate(zip(self.initial.q, lower, upper)):
            if not lo <= qi <= hi:
                raise TaskError(f"initial.q[{i}] = {qi} ({robot.dof_names[i]}) is outside the joint bounds "
                                f"{robot.range_text(i, lo, hi)}; with plan.periodic it is the initial guess of q(0)")
        return perm, along, fixed

    def pd_actuators(self, robot) -> tuple[tuple[int, int, int], ...]:
        """(q index, v index, actuator index) of each simulate.pd joint, in its order.

        Raises UnknownNameError for an unknown joint and TaskError for a joint without exactly one
        actuator or a robot whose q and v coordinates differ (nq != nv), and for a task without simulate.pd.
        """
        pd = self.simulate.pd
        if pd is None:
            raise TaskError("the task has no simulate.pd")
        if robot.nq != robot.nv:
            raise TaskError(f"simulate.pd needs a robot with nq == nv (one coordinate per joint); {robot.name!r} has "
                            f"nq = {robot.nq}, nv = {robot.nv}")
        out = []
        for joint in pd.joints:
            dof = robot.dof_index(joint, "simulate.pd.joints")
            drives = [i for i, a in enumerate(robot.actuators) if a.dof == dof]
            if len(drives) != 1:
                raise TaskError(f"simulate.pd.joints: joint {joint!r} is driven by {len(drives)} actuators; PD needs exactly one "
                                f"(actuated joints: {', '.join(robot.dof_names[a.dof] for a in robot.actuators) or 'none'})")
            out.append((dof, dof, drives[0]))
        return tuple(out)

    def warn_dependent_contacts(self, robot) -> None:
        """Warn when the touching contacts on their planes at initial.q constrain more directions than they do
        independently (their forces are not unique: a plan burnt 433 s at its caps), naming them and counting the fix:
        the check of the commands that solve (simulate, plan); `validate`, which solves nothing, said "the solver may
        fail" too."""
        touching = [i for i, c in enumerate(self.contacts) if c.touches]
        on, normal_rank, rank = robot.contact_rank([(self.contacts[i].point, self.contacts[i].normal,
                                                     self.contacts[i].mu > 0) for i in touching],
                                                    self.initial.q, self.ground_height)
        on = [touching[k] for k in on]
        rows = len(on) + sum(self.contacts[i].mu > 0 for i in on)
        if rank < rows:  # (checked where the task starts: later double stances are not seen)
            names = ", ".join(f"contacts[{i}] ({self.contacts[i].point})" for i in on)
            if len(on) == 1:  # (its own normal and friction direction: "remove one of them" named no other contact)
                fix = ("it cannot move along its normal: start from another pose" if normal_rank < 1 else
                       "it cannot slide independently of its normal: give it mu = 0")
                warnings.warn(f"{names} on its plane at initial.q constrains {rows} directions but only {rank} "
                              f"independently, so its forces are not unique and the solver may fail; {fix}")
            else:
                # (counted: "give mu = 0 to one of them" left a point mass in a corner dependent, 3 rows for 2)
                extra = len(on) - normal_rank
                # (removing a contact drops its friction row too: counted after that, mu = 0 was asked of too many)
                surplus = rows - rank - extra
                fix = (f"their normals alone are dependent: remove {extra} of them, then check the others' friction"
                       if extra else f"{surplus} friction direction(s) are surplus: give mu = 0 to {surplus} "
                       "contact(s) with friction")
                warnings.warn(f"{names} on their planes at initial.q constrain {rows} directions but only {rank} "
                              "independently, so their forces together are not unique (e.g. two sticking points of "
                              f"one rigid body) and the solver may fail; {fix}")

    def buried_holes(self) -> tuple[int, ...]:
        """Indices of the plan.holes entries wholly below a flat ground (every contact's plane the ground): no contact
        point goes into them, so the scene analysis drops them (their rows had moved the plan)."""
        flat = all(c.normal == (0.0, 0.0, 1.0) for c in self.contacts)
        return tuple(i for i, e in enumerate(self.plan.holes if self.plan is not None and flat else ())
                     if e.z + e.b <= self.ground_height)

    def warn_buried_holes(self, dropped: bool = True) -> None:
        """Warn of each plan.holes entry wholly below a flat ground (a plan's check: `simulate` reads no holes, and
        warned of them before its one-line error); `dropped`: the scene analysis drops them (it is on)."""
        for i in self.buried_holes():  # (ground_height 0.3 with z omitted: a hole that did nothing)
            e = self.plan.holes[i]
            warnings.warn(f"plan.holes[{i}] lies wholly below the ground (its top z + b = {e.z + e.b:g} m, "
                          f"ground_height {self.ground_height:g} m): no contact point goes into it"
                          f"{' (the scene analysis drops it)' if dropped else ''}; its z is the centre's height [m], 0 "
                          "when omitted")

    def velocity_rows(self, robot) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """plan.velocity_bounds as (A (m, nv) of 0/1, lower (m,), upper (m,)): lower <= A v <= upper.
        Raises UnknownNameError for a joint the robot does not have."""
        bounds = self.plan.velocity_bounds if self.plan else ()
        A = np.zeros((len(bounds), robot.nv))
        for r, b in enumerate(bounds):
            A[r, [robot.dof_index(name, f"plan.velocity_bounds[{r}].joints") for name in b.joints]] = 1.0
        return A, np.array([b.lower for b in bounds]), np.array([b.upper for b in bounds])

    def q_bounds(self, robot) -> tuple[np.ndarray, np.ndarray]:
        """Joint position bounds (nq,): the robot file's limits, replaced by plan.joint_bounds."""
        lower, upper = robot.q_lower.copy(), robot.q_upper.copy()
        for r, b in enumerate(self.plan.joint_bounds if self.plan else ()):
            i = robot.dof_index(b.joint, f"plan.joint_bounds[{r}].joint")
            lower[i], upper[i] = b.lower, b.upper
        return lower, upper


# a robot file's ground plane this far [m] from the task's ground_height warns: far below any contact's accuracy, far
# above rounding of the file's numbers
GROUND_MISMATCH_M = 1e-9


def _not_on_the_world(point: str, robot, key: str) -> None:
    """TaskError when `point`, not a point of the robot, names a site on the world body (it exists in the file but never
    moves with the robot) or one Pinocchio's parser skipped: it read as an unknown name."""
    if point in robot.world_sites:
        raise TaskError(f"{key} = {point!r} is a site on the world body, fixed in the world, not a point of the robot; "
                        "move the <site> into the robot's body that touches")
    if point in robot.unread_sites:  # ("valid contact points: (none)" of a file that plainly has the site)
        raise TaskError(f"{key} = {point!r} is a site Pinocchio's MJCF parser skips (one inside a <frame> or a "
                        "<replicate>, or on a body of <worldbody> after the first, which is the robot); move the "
                        "<site> out of the <frame> into its body, with the frame's pos and orientation (a "
                        "<replicate>'s copies written out), or onto the robot")


def _names_a_shipped_task(path: Path) -> bool:
    """A bare name or robots/NAME(.toml), as the docs name the shipped tasks."""
    return path.parent in (Path("."), Path("robots")) and path.suffix in ("", ".toml")


def shipped_task(path: Path) -> Path:
    """`path`, or the shipped task it names where no such file exists: a bare name (`point_mass_hop`) or a path in
    robots/ as the docs write them (`robots/point_mass_hop.toml`), from outside a checkout (an installed wheel holds
    them in planner/robots, and the README's commands were refused there)."""
    if path.exists() or not _names_a_shipped_task(path):
        return path
    from .model import ROBOTS_DIR  # (here: reading a task file needs no Pinocchio)

    shipped = ROBOTS_DIR / f"{path.stem}.toml"
    return shipped if shipped.is_file() else path


def _shipped_tasks_hint(path: Path) -> str:
    """"; the shipped tasks are ..." for a name shipped_task would have looked up (a typo such as point_mass_hopp was
    only "not found"), else ""."""
    if not _names_a_shipped_task(path):
        return ""
    from .model import ROBOTS_DIR

    names = sorted(p.stem for p in ROBOTS_DIR.glob("*.toml"))
    return f"; the shipped tasks are {', '.join(names)}" if names else ""


def load_task(path: str | Path) -> Task:
    """Read and validate a task file, by its path or a shipped task's name ("point_mass_hop":
    robots/point_mass_hop.toml). Raises TaskError with the offending key."""
    expect(path, (str, os.PathLike), "load_task's path")
    path = shipped_task(Path(path))
    if not path.is_file():
        raise TaskError(f"task file {path} is a directory" if path.is_dir() else f"task file {path} is not a regular "
                        "file (a device, a FIFO or a socket)" if path.exists() else f"task file not found: {path}"
                        + _shipped_tasks_hint(path))
    try:
        size = path.stat().st_size
        if size > MAX_TASK_FILE_BYTES:
            raise TaskError(f"{path} is {size} bytes, more than the {MAX_TASK_FILE_BYTES} a task file may be (tasks "
                            "are a few kilobytes)")
        data = tomllib.loads(path.read_text(encoding="utf-8-sig"))  # a byte-order mark (some editors) is not TOML
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:  # TOML is UTF-8 text
        raise TaskError(f"{path}: not valid TOML: {exc}") from None
    except ValueError as exc:  # an integer of more than 4300 digits: Python's limit on reading one
        said = str(exc).split(";")[0]  # (without Python's advice to call sys.set_int_max_str_digits)
        raise TaskError(f"{path}: {said}; no task value needs such an integer") from None
    except RecursionError:
        raise TaskError(f"{path}: nested too deeply to be a task") from None
    except OSError as exc:
        raise read_error(path, exc, TaskError, "cannot read task file") from None
    try:
        return parse_task(data, source=str(path))
    except TaskError as exc:  # "missing key 'contacts'" named no file
        exc.args = (f"{path}: {exc}",)
        raise


# after a task's path: the task differs from what that file holds (edited in code, by --steps, or the file changed)
EDITED = " (edited)"


def task_source(task: Task) -> str:
    """task.source for a result and a message: its file's path, or that path (absolute) + EDITED when the task is no
    longer what the file holds. dataclasses.replace keeps the source: a plan of a target edited to 0.3 m named, as its
    task, a file whose target is 0.5 m, and an error blamed that file for a value it does not contain. A source that is
    no file is kept, and so is a trajectory.npz's (read_task's; load_task cannot read it)."""
    path = Path(task.source)
    if not task.source or path.suffix == ".npz" or not path.is_file():  # (read_task's trajectory.npz)
        return task.source
    try:
        same = load_task(path) == task  # (equality leaves the source out)
    except PlannerError:  # the file changed since into something that is not a task
        same = False
    return task.source if same else f"{path.absolute()}{EDITED}"


def parse_task(data: dict, source: str = "") -> Task:
    """Build a Task from a TOML-like dict (the same rules as `load_task`)."""
    if isinstance(data, dict) and data.get("plan") is not None and data.get("gait") is not None:  # (each command
        # ignored the other's table; task_to_json writes null for a table the task has not)
        raise TaskError("a task has a [plan] (for `planner plan`) or a [gait] (for `planner gait`, which reads no "
                        "[plan]: its bounds are the robot file's), not both")
    task = _build(Task, dict(data) if isinstance(data, dict) else data, "", exclude={"source"})  # not a dict: TaskError
    return Task(**{**{f.name: getattr(task, f.name) for f in fields(Task)}, "source": source})


def task_to_json(task: Task) -> str:
    """The task as JSON text that parse_task(json.loads(text)) reads back equal (but for its source): a plan
    keeps the task it solved beside it (trajectory.npz's task_json), for a replan's walk from it."""
    data = asdict(task)
    del data["source"]
    return json.dumps(data)


def tasks_between(start: Task, end: Task, s: float) -> Task | None:
    """The task a fraction s in [0, 1] of the way from `start` to `end`: every number (float) linear between
    the two, everything else (names, integers such as N, flags, the number of holes or contacts, an infinite
    bound) equal in both; None when they differ in anything but finite numbers. The source is end's. A replan
    walks the task from its start plan's task to the new one through these (planner.replan). The [simulate] table,
    which a plan does not read, is end's too; an omitted initial.v or plan.target_v is zeros."""
    expect(start, Task, "tasks_between's start")
    expect(end, Task, "tasks_between's end")
    s = plain(s)  # np.float32, a 0-d array
    _require(isinstance(s, (int, float)) and not isinstance(s, bool) and 0 <= s <= 1, "tasks_between's s", s,
             "a number in [0, 1] (0: start, 1: end)")
    try:
        return _between(start, end, float(s), "")
    except _Apart:
        return None


def tasks_apart(start: Task, end: Task) -> str | None:
    """The key in which two tasks differ by more than finite numbers (tasks_between is None for them), else None."""
    try:
        _between(start, end, 1.0, "")
    except _Apart as exc:
        return str(exc) or "task"
    return None


class _Apart(Exception):
    """Two tasks differ in something that is not a number."""


def _between(a, b, s: float, key: str):
    """key: the dotted path of a and b in the task ("plan.holes[0].a"), which _Apart names."""
    if key in ("source", "simulate"):  # not read by a plan (a [simulate] written out or edited refused the walk)
        return b
    if key in ("plan.target_v", "initial.v") and (a is None) != (b is None):  # omitted is zeros (the walk was refused)
        zeros = tuple(0.0 for _ in (a or b))
        return b if s == 1.0 else _between(zeros if a is None else a, zeros if b is None else b, s, key)
    if is_dataclass(a) and type(a) is type(b):
        return type(a)(**{f.name: _between(getattr(a, f.name), getattr(b, f.name), s, _join(key, f.name))
                          for f in fields(a)})
    if isinstance(a, tuple) and isinstance(b, tuple) and len(a) == len(b):
        return tuple(_between(x, y, s, f"{key}[{i}]") for i, (x, y) in enumerate(zip(a, b)))
    if type(a) is float and type(b) is float and a != b and math.isfinite(a) and math.isfinite(b):
        return b if s == 1.0 else a + s * (b - a)  # s = 1: end's numbers exactly
    if type(a) is type(b) and a == b:
        return a
    raise _Apart(key)


def default_task_path(robot_path: Path) -> Path:
    """The task beside the robot file: robots/capler.xml -> robots/capler.toml."""
    return robot_path.with_suffix(".toml")


# --- a small schema-driven reader: dataclass fields and their annotations are the schema -------------

def _build(cls, data, where: str, exclude=frozenset()):
    if not isinstance(data, dict):
        raise TaskError(f"{where or 'task'} must be a table, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    known = [f.name for f in fields(cls) if f.name not in exclude]
    for key in data:
        if key not in known:
            raise TaskError(f"unknown key {_join(where, key)!r}; valid keys: {', '.join(known)}")
    kwargs = {}
    for f in fields(cls):
        if f.name in exclude:
            continue
        key = _join(where, f.name)
        if f.name not in data:
            if f.default is MISSING and f.default_factory is MISSING:
                raise TaskError(f"missing key {key!r}")
            continue
        kwargs[f.name] = _convert(hints[f.name], data[f.name], key)
    try:
        return cls(**kwargs)
    except TaskError as exc:  # an entry's range check names its section ("contacts.mu"): name the entry, contacts[1]
        section = re.sub(r"\[\d+\]", "", where)
        if section == where or not str(exc).startswith(f"{section}."):
            raise
        raise TaskError(f"{where}{str(exc)[len(section):]}") from None


# the keys that may be +-inf in a task file: bounds, where inf means unbounded (e.g. velocity_bounds' lower = -inf)
UNBOUNDED_OK = frozenset({"lower", "upper", "u_bound", "v_bound"})


def _convert(tp, value, key: str):
    value = plain(value)  # numpy's numbers and arrays (a task built in a notebook) as the Python ones they hold
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        inner = [a for a in args if a is not type(None)]
        if value is None and len(inner) < len(args):
            return None
        return _convert(inner[0], value, key)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise TaskError(f"{key} must be an array, got {_typename(value)}")
        return tuple(_convert(args[0], v, f"{key}[{i}]") for i, v in enumerate(value))
    if is_dataclass(tp):
        return _build(tp, value, key)
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise TaskError(f"{key} must be a number, got {_typename(value)}")
        if not representable(value, "float"):
            allowed = ("a number within a double's range (inf: no bound)" if key.rsplit(".", 1)[-1] in UNBOUNDED_OK
                       else "a finite number")
            raise TaskError(f"{key} must be {allowed}, got an integer beyond a double's range")
        if math.isnan(value):
            raise TaskError(f"{key} must be a number, got nan")
        if math.isinf(value) and key.rsplit(".", 1)[-1] not in UNBOUNDED_OK:
            raise TaskError(f"{key} must be a finite number, got {value}")
        return float(value)
    if tp is bool:
        if not isinstance(value, bool):
            raise TaskError(f"{key} must be true or false, got {_typename(value)}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise TaskError(f"{key} must be an integer, got {_typename(value)}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise TaskError(f"{key} must be a string, got {_typename(value)}")
        return value
    raise TypeError(f"unsupported schema type {tp!r}")  # a bug in the schema, not the user's input


def _typename(value) -> str:
    return f"{type(value).__name__} {value!r}"


def _join(where: str, key: str) -> str:
    return f"{where}.{key}" if where else key


def _typed(obj, section: str) -> None:
    """The reader's type rules for a dataclass built in code too: numbers, not nan, finite but for bounds; a nested
    table is its dataclass (a Homotopy, a tuple of Contact); an int given for a float (or a list for a tuple) is stored
    as the reader stores it, so both tasks are equal."""
    check_field_types(obj, section, unbounded=UNBOUNDED_OK, error=TaskError)
    for f in fields(obj):
        value, kind = getattr(obj, f.name), str(f.type).split("|")[0].strip()
        key = _join(section, f.name)
        item = kind[len("tuple["):-len(", ...]")] if kind.startswith("tuple[") and kind.endswith(", ...]") else None
        table = globals().get(item if item else kind)
        if value is None and "None" in str(f.type) or not (isinstance(table, type) and is_dataclass(table)
                                                             or item == "tuple[str, ...]"):
            pass
        elif not item:
            _require(isinstance(value, table), key, value, f"{'an' if kind[0] in 'AEIOU' else 'a'} {kind} (the [{key}] table)")
        elif item == "tuple[str, ...]":  # pairs of names: Periodic.swap
            _require(isinstance(value, (tuple, list)) and all(
                isinstance(p, (tuple, list)) and all(isinstance(n, str) for n in p) for p in value),
                key, value, 'a list of lists of names, e.g. [["hinge_1", "hinge_2"]]')
            object.__setattr__(obj, f.name, tuple(tuple(p) for p in value))
            continue
        else:
            _require(isinstance(value, (tuple, list)) and all(isinstance(v, table) for v in value), key, value,
                     f"a tuple of {item} (the [[{key}]] tables)")
        if kind == "float" and isinstance(value, int):
            object.__setattr__(obj, f.name, float(value))
        elif kind == "tuple[float, ...]" and value is not None:
            object.__setattr__(obj, f.name, tuple(float(v) for v in value))
        elif kind.startswith("tuple[") and isinstance(value, list):
            object.__setattr__(obj, f.name, tuple(value))


def _require(ok: bool, key: str, value, allowed: str) -> None:
    if not ok:
        raise TaskError(f"{key} = {value!r} is not allowed; it must be {allowed}")


def _require_state(values: tuple[float, ...] | None, key: str) -> None:
    """Each coordinate of a start or target state within MAX_STATE."""
    for i, x in enumerate(values or ()):
        _require(abs(x) <= MAX_STATE, f"{key}[{i}]", x, f"within ±{MAX_STATE:g} (m, rad, m/s or rad/s)")


def _length(key: str, values, n: int, robot=None) -> None:
    if len(values) != n:
        extra = ("" if robot is None or robot.nq == robot.nv else f" (nq = {robot.nq} positions for nv = {robot.nv} "
                 "velocities: a free flyer's or a URDF continuous joint's orientation takes more than one number, "
                 "e.g. cos and sin)")
        raise TaskError(f"{key} has {len(values)} entries; the robot needs {n}{extra}")
