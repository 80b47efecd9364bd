"""Task files (TOML): the scene, the initial state, the horizon and the OCP, as frozen dataclasses.

Every key is validated when the file is read: an unknown key, a wrong type or a value out of range
is a `TaskError` naming the key and what is allowed. Robot-dependent checks (vector lengths, point
and joint names, targets inside joint limits) happen in `Task.check_against(robot)`.
Keys are documented in docs/tasks.md.
"""
from __future__ import annotations

import math
import tomllib
import types
import typing
from dataclasses import MISSING, dataclass, field, fields, is_dataclass
from pathlib import Path

import numpy as np

from .errors import TaskError, UnknownNameError


@dataclass(frozen=True)
class Contact:
    """A named point of the robot that may touch the ground plane z = ground_height."""

    point: str
    mu: float = 0.0  # Coulomb friction coefficient; 0 drops the tangential machinery
    restitution: float = 0.0  # epsilon in [0, 1]: 0 inelastic, > 0 elastic auxiliary ODE (Sec. 4.5)
    a_n: float = 200.0  # normal auxiliary-ODE gain [1/s^2 scaled]; larger = shorter frozen intervals
    a_t: float = 600.0  # tangential auxiliary-ODE gain, a_t >> a_n (Sec. 6)

    def __post_init__(self):
        _require(self.mu >= 0, "contacts.mu", self.mu, ">= 0")
        _require(0.0 <= self.restitution <= 1.0, "contacts.restitution", self.restitution, "in [0, 1]")
        _require(self.a_n > 0, "contacts.a_n", self.a_n, "> 0")
        _require(self.a_t > 0, "contacts.a_t", self.a_t, "> 0")


@dataclass(frozen=True)
class Initial:
    """Initial state in physical coordinates: q (nq,) [m, rad], v (nv,) [m/s, rad/s]."""

    q: tuple[float, ...]
    v: tuple[float, ...] | None = None  # zeros when omitted


@dataclass(frozen=True)
class Horizon:
    """Numerical-time horizon tau_f [s] split into N implicit-Euler steps of h = tau_f / N."""

    tau_f: float
    N: int
    physical_time: float | None = None  # T [s]: adds speed of time s >= 1 with t(tau_f) = T

    def __post_init__(self):
        _require(self.tau_f > 0, "horizon.tau_f", self.tau_f, "> 0")
        _require(self.N >= 1, "horizon.N", self.N, ">= 1")
        if self.physical_time is not None:
            _require(0 < self.physical_time <= self.tau_f, "horizon.physical_time", self.physical_time, "in (0, tau_f]")

    @property
    def h(self) -> float:
        return self.tau_f / self.N


@dataclass(frozen=True)
class Ellipse:
    """A hole or obstacle the contact points must stay out of: ((x-xc)/a)^2 + ((z-zc)/b)^2 >= 1 [m]."""

    x: float
    a: float
    b: float
    z: float = 0.0

    def __post_init__(self):
        _require(self.a > 0, "plan.holes.a", self.a, "> 0")
        _require(self.b > 0, "plan.holes.b", self.b, "> 0")


@dataclass(frozen=True)
class Homotopy:
    """l_inf penalty homotopy: rho_k = rho0 * kappa^k, k = 0 .. n_nlp-1."""

    rho0: float = 1.0
    kappa: float = 10.0
    n_nlp: int = 5

    def __post_init__(self):
        _require(self.rho0 > 0, "plan.homotopy.rho0", self.rho0, "> 0")
        _require(self.kappa > 1, "plan.homotopy.kappa", self.kappa, "> 1")
        _require(self.n_nlp >= 1, "plan.homotopy.n_nlp", self.n_nlp, ">= 1")


@dataclass(frozen=True)
class JointBound:
    """Bounds on one joint position [m or rad]; they replace the robot file's limits."""

    joint: str
    lower: float = -math.inf
    upper: float = math.inf

    def __post_init__(self):
        _require(self.lower <= self.upper, f"plan.joint_bounds.{self.joint}.lower", self.lower, f"<= upper ({self.upper})")


@dataclass(frozen=True)
class Plan:
    """The optimal control problem: reach target_q at tau_f minimizing the integral of u^2."""

    target_q: tuple[float, ...]
    target_v: tuple[float, ...] | None = None  # zeros when omitted
    rho_f: float = 1.0  # weight of ||sigma - sigma*||^2 (regularized implicit Euler)
    homotopy: Homotopy = field(default_factory=Homotopy)
    holes: tuple[Ellipse, ...] = ()
    above_ground: tuple[str, ...] = ()  # named points kept at z >= ground_height (knee, base, ...)
    joint_bounds: tuple[JointBound, ...] = ()
    u_bound: float | None = None  # |u_i| <= u_bound; default: the actuators' ctrlrange

    def __post_init__(self):
        _require(self.rho_f >= 0, "plan.rho_f", self.rho_f, ">= 0")
        if self.u_bound is not None:
            _require(self.u_bound > 0, "plan.u_bound", self.u_bound, "> 0")


@dataclass(frozen=True)
class ControlChange:
    """From physical time t [s] on, the simulation applies controls u (nu,) [N m or N]."""

    t: float
    u: tuple[float, ...]

    def __post_init__(self):
        _require(self.t >= 0, "simulate.schedule.t", self.t, ">= 0")


@dataclass(frozen=True)
class Simulate:
    """Forward simulation: controls u (nu,) [N m or N] (zero when omitted), changed by `schedule`
    at given physical times, and the weight rho_f of the regularized implicit Euler scheme."""

    u: tuple[float, ...] | None = None
    schedule: tuple[ControlChange, ...] = ()  # sorted by t; each entry replaces u from its time on
    rho_f: float = 1.0  # weight of ||sigma - sigma*||^2; 0 gives the plain implicit Euler MPCC (Fig. 5)

    def __post_init__(self):
        _require(self.rho_f >= 0, "simulate.rho_f", self.rho_f, ">= 0")
        times = [c.t for c in self.schedule]
        _require(times == sorted(times), "simulate.schedule", times, "sorted by increasing t")

    def controls_at(self, t: float, nu: int) -> np.ndarray:
        """Controls (nu,) in force at physical time t [s]."""
        u = np.zeros(nu) if self.u is None else np.array(self.u, dtype=float)
        for change in self.schedule:
            if t >= change.t:
                u = np.array(change.u, dtype=float)
        return u


@dataclass(frozen=True)
class Task:
    """A whole task file."""

    contacts: tuple[Contact, ...]
    initial: Initial
    horizon: Horizon
    ground_height: float = 0.0  # [m]
    plan: Plan | None = None
    simulate: Simulate = field(default_factory=Simulate)
    source: str = ""  # path of the file it came from, for messages; not a TOML key

    def check_against(self, robot) -> None:
        """Robot-dependent validation: names exist, lengths match, targets are inside the limits."""
        for c in self.contacts:
            if c.point not in robot.points:
                raise UnknownNameError("contact point", c.point, robot.points)
        _length("initial.q", self.initial.q, robot.nq)
        if self.initial.v is not None:
            _length("initial.v", self.initial.v, robot.nv)
        if self.simulate.u is not None:
            _length("simulate.u", self.simulate.u, robot.nu)
        for i, change in enumerate(self.simulate.schedule):
            _length(f"simulate.schedule[{i}].u", change.u, robot.nu)
        if self.plan is None:
            return
        if robot.nu == 0:
            raise TaskError(f"the task has a [plan] but robot {robot.name!r} has no actuators to plan with")
        for p in self.plan.above_ground:
            if p not in robot.points:
                raise UnknownNameError("point", p, robot.points)
        _length("plan.target_q", self.plan.target_q, robot.nq)
        if self.plan.target_v is not None:
            _length("plan.target_v", self.plan.target_v, robot.nv)
        lower, upper = self.q_bounds(robot)
        for i, (qi, lo, hi) in enumerate(zip(self.plan.target_q, lower, upper)):
            if not lo <= qi <= hi:
                raise TaskError(f"plan.target_q[{i}] = {qi} ({robot.dof_names[i]}) is outside the joint limits [{lo}, {hi}]")

    def q_bounds(self, robot) -> tuple[np.ndarray, np.ndarray]:
        """Joint position bounds (nq,): the robot file's limits, replaced by plan.joint_bounds."""
        lower, upper = robot.q_lower.copy(), robot.q_upper.copy()
        for b in self.plan.joint_bounds if self.plan else ():
            i = robot.dof_index(b.joint)
            lower[i], upper[i] = b.lower, b.upper
        return lower, upper


def load_task(path: str | Path) -> Task:
    """Read and validate a task file. Raises TaskError with the offending key."""
    path = Path(path)
    if not path.is_file():
        raise TaskError(f"task file not found: {path}")
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise TaskError(f"{path}: not valid TOML: {exc}") from None
    return parse_task(data, source=str(path))


def parse_task(data: dict, source: str = "") -> Task:
    """Build a Task from a TOML-like dict (the same rules as `load_task`)."""
    task = _build(Task, {**data}, "", exclude={"source"})
    return Task(**{**{f.name: getattr(task, f.name) for f in fields(Task)}, "source": source})


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
    return cls(**kwargs)


def _convert(tp, value, key: str):
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        inner = [a for a in args if a is not type(None)]
        if value is None and len(inner) < len(args):
            return None
        return _convert(inner[0], value, key)
    if origin is tuple:
        if not isinstance(value, list):
            raise TaskError(f"{key} must be an array, got {_typename(value)}")
        return tuple(_convert(args[0], v, f"{key}[{i}]") for i, v in enumerate(value))
    if is_dataclass(tp):
        return _build(tp, value, key)
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise TaskError(f"{key} must be a number, got {_typename(value)}")
        if math.isnan(value):
            raise TaskError(f"{key} must be a number, got nan")
        return float(value)
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


def _require(ok: bool, key: str, value, allowed: str) -> None:
    if not ok:
        raise TaskError(f"{key} = {value!r} is not allowed; it must be {allowed}")


def _length(key: str, values, n: int) -> None:
    if len(values) != n:
        raise TaskError(f"{key} has {len(values)} entries; the robot needs {n}")
