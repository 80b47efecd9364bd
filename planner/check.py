"""`check-model`: the CasADi dynamics against Pinocchio's numeric algorithms and MuJoCo.

At seeded random states (q uniform within the joint limits where both are finite, else in
[-1, 1], quaternions and unit complex numbers normalized; v uniform in [-1, 1]) it compares
M(q) with `pin.crba`, h(q, v) with `pin.rnea(q, v, 0)`, every named point's placement with
`data.oMf`, its frame Jacobian with `pin.getFrameJacobian(..., LOCAL_WORLD_ALIGNED)` and its
drift dJ/dt v with the classical acceleration at zero joint acceleration. It also compares M, h
and the named points' positions with MuJoCo's compiled model of the same file (a URDF file as
planner.model.mujoco_spec gives it to MuJoCo: a site at every link).
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np
import pinocchio as pin

from .dynamics import Dynamics
from .errors import InputError, RobotFileError
from .model import Robot, mujoco_failure, mujoco_spec

TOLERANCE = 1e-9  # every max abs difference must be at most this for `passed`
TIMING_EVALUATIONS = 200  # calls averaged per timed function


@dataclass(frozen=True)
class MujocoCheck:
    """Max abs differences between the CasADi dynamics and MuJoCo (same units as ModelCheck)."""

    max_err_mass: float
    max_err_bias: float
    max_err_sites: float  # site positions [m], sites matched to named points by name
    missing_sites: tuple[str, ...] = ()  # MuJoCo sites Pinocchio's reading lacks (e.g. inside a <frame>): a failure


@dataclass(frozen=True)
class Timing:
    """How long building and evaluating the CasADi functions takes (wall clock, this machine)."""

    build_s: float  # Dynamics(robot): mass, bias, forward and integrate functions [s]
    point_build_s: float  # position, Jacobian and drift functions of `point` [s]
    point: str  # the point whose Jacobian is timed
    mass_us: float  # mean time of one evaluation [us]
    bias_us: float
    jacobian_us: float
    evaluations: int  # evaluations averaged per function


@dataclass(frozen=True)
class ModelCheck:
    """Result of check_model; to_json() gives the check-model JSON object."""

    robot: str
    format: str  # "mjcf" or "urdf"
    nq: int
    nv: int
    dof_names: tuple[str, ...]  # (nv,) the joint of each velocity coordinate: the order of a task's vectors
    points: tuple[str, ...]  # the named points a task may use (MJCF sites, URDF links and frames)
    backend: str  # "pinocchio.casadi" or "symbolic"
    samples: int
    seed: int
    max_err_mass: float  # max abs difference of M entries [kg, kg m, kg m^2]
    max_err_bias: float  # of h entries [N, N m]
    max_err_frames: float  # of point positions [m] and rotation-matrix entries
    max_err_jacobians: float  # of frame-Jacobian entries (linear and angular rows)
    max_err_drift: float  # of dJ/dt v [m/s^2]
    mujoco: MujocoCheck | None  # None when skipped (see mujoco_skipped)
    mujoco_skipped: str | None  # why the file was not compared with MuJoCo
    timing: Timing

    @property
    def max_errors(self) -> dict[str, float]:
        """Every compared quantity's max abs difference, MuJoCo's prefixed with `mujoco_`."""
        errors = {k: getattr(self, k) for k in ("max_err_mass", "max_err_bias", "max_err_frames", "max_err_jacobians", "max_err_drift")}
        if self.mujoco is not None:
            errors.update({f"mujoco_{k}": v for k, v in asdict(self.mujoco).items() if k.startswith("max_err_")})
        return errors

    @property
    def passed(self) -> bool:
        """Every difference <= TOLERANCE (a NaN fails), every MuJoCo site is one of Pinocchio's points, and MuJoCo reads
        the file as Pinocchio does (a file it cannot compile, or reads with other coordinates, cannot be replayed)."""
        return (all(err <= TOLERANCE for err in self.max_errors.values()) and not (self.mujoco and self.mujoco.missing_sites)
                and not (self.mujoco_skipped or "").startswith(MUJOCO_FAILED))

    def to_json(self) -> dict:
        out = asdict(self)
        out["dof_names"], out["points"] = list(self.dof_names), list(self.points)  # as JSON reads them back
        if out["mujoco"] is not None:
            out["mujoco"]["missing_sites"] = list(out["mujoco"]["missing_sites"])  # as JSON reads it back
        out["passed"] = self.passed
        out["tolerance"] = TOLERANCE
        return out

    def report(self) -> str:
        """A few lines for people: verdict, max errors, MuJoCo, timing."""
        t = self.timing
        pinocchio = "  ".join(f"{k} {getattr(self, f'max_err_{k}'):.1e}" for k in ("mass", "bias", "frames", "jacobians", "drift"))
        if self.mujoco is not None:
            mujoco = "  ".join(f"{k} {v:.1e}" for k, v in (("mass", self.mujoco.max_err_mass), ("bias", self.mujoco.max_err_bias), ("sites", self.mujoco.max_err_sites)))
            if self.mujoco.missing_sites:
                mujoco += (f"; MuJoCo sites missing in Pinocchio's reading: {', '.join(self.mujoco.missing_sites)} "
                           "(Pinocchio's MJCF parser skips a site inside a <frame>)")
        else:
            failed = self.mujoco_skipped.startswith(MUJOCO_FAILED)
            mujoco = self.mujoco_skipped if failed else f"skipped: {self.mujoco_skipped}"
        return "\n".join(
            [
                f"check-model {self.robot} ({self.format}, nq={self.nq}, nv={self.nv}, backend {self.backend}, "
                f"{self.samples} samples, seed {self.seed}): {'PASSED' if self.passed else 'FAILED'} (tolerance {TOLERANCE:g})",
                f"  coordinates:  {', '.join(self.dof_names)}; points: {', '.join(self.points)}",
                f"  vs Pinocchio: {pinocchio}",
                f"  vs MuJoCo:    {mujoco}",
                f"  timing:       build {t.build_s * 1e3:.1f} ms (+{t.point_build_s * 1e3:.1f} ms for {t.point}); "
                f"eval M {t.mass_us:.1f} us, h {t.bias_us:.1f} us, J({t.point}) {t.jacobian_us:.1f} us",
            ]
        )


def random_state(model: pin.Model, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(q, v): q uniform within finite limits else in [-1, 1], normalized; v uniform in [-1, 1]."""
    lo, hi = np.asarray(model.lowerPositionLimit), np.asarray(model.upperPositionLimit)
    u = rng.uniform(0.0, 1.0, model.nq)
    with np.errstate(over="ignore", invalid="ignore"):  # Pinocchio writes "no limit" as +-DBL_MAX
        span = hi - lo
        q = np.where(np.isfinite(span), lo + u * span, 2.0 * u - 1.0)
    return pin.normalize(model, q), rng.uniform(-1.0, 1.0, model.nv)


def check_model(robot: Robot, samples: int = 20, seed: int = 0, point: str | None = None) -> ModelCheck:
    """Compare the CasADi dynamics with Pinocchio and MuJoCo at `samples` random states.

    point: the named point whose Jacobian is timed; default the first point with "foot" in its
    name, else the last named point. Raises UnknownNameError for an unknown point.
    """
    def integer(value) -> bool:  # not a bool, a float or nan (nan < 1 is False: it slipped through)
        return isinstance(value, (int, np.integer)) and not isinstance(value, bool)

    if not integer(samples) or samples < 1:
        raise InputError(f"samples must be a positive integer, got {samples!r}")
    if not integer(seed) or seed < 0:  # numpy's generators take seeds >= 0 only
        raise InputError(f"seed must be an integer >= 0, got {seed!r}")
    if not robot.points:
        raise InputError(f"{robot.path} has no named points (MJCF sites or URDF links) to check")
    if point is None:
        point = next((p for p in robot.points if "foot" in p.lower()), robot.points[-1])
    robot.frame_id(point)

    start = time.perf_counter()
    dyn = Dynamics(robot)
    build_s = time.perf_counter() - start
    start = time.perf_counter()
    for build in (dyn.point_position, dyn.point_jacobian, dyn.point_drift):
        build(point)
    point_build_s = time.perf_counter() - start

    rng = np.random.default_rng(seed)
    states = [random_state(robot.model, rng) for _ in range(samples)]
    errors = _pinocchio_errors(robot, dyn, states)
    mujoco_check, skipped = _mujoco_errors(robot, dyn, states)

    q, v = states[0]
    jacobian = dyn.point_jacobian(point)
    timing = Timing(
        build_s=build_s,
        point_build_s=point_build_s,
        point=point,
        mass_us=_mean_us(lambda: dyn.mass(q)),
        bias_us=_mean_us(lambda: dyn.bias(q, v)),
        jacobian_us=_mean_us(lambda: jacobian(q)),
        evaluations=TIMING_EVALUATIONS,
    )
    return ModelCheck(
        robot=robot.name,
        format=robot.format.value,
        nq=robot.nq,
        nv=robot.nv,
        dof_names=robot.dof_names,
        points=robot.points,
        backend=dyn.backend,
        samples=samples,
        seed=seed,
        **errors,
        mujoco=mujoco_check,
        mujoco_skipped=skipped,
        timing=timing,
    )


def _err(a, b) -> float:
    return float(np.max(np.abs(np.asarray(a, dtype=float).reshape(np.shape(b)) - b), initial=0.0))


def _pinocchio_errors(robot: Robot, dyn: Dynamics, states) -> dict[str, float]:
    model, data = robot.model, robot.model.createData()
    err: dict[str, list[float]] = {k: [0.0] for k in ("max_err_mass", "max_err_bias", "max_err_frames", "max_err_jacobians", "max_err_drift")}
    for q, v in states:
        M = pin.crba(model, data, q)
        err["max_err_mass"].append(_err(dyn.mass(q), np.triu(M) + np.triu(M, 1).T))  # the upper triangle is Pinocchio's
        err["max_err_bias"].append(_err(dyn.bias(q, v), pin.rnea(model, data, q, v, np.zeros(model.nv))))
        pin.computeJointJacobians(model, data, q)
        pin.forwardKinematics(model, data, q, v, np.zeros(model.nv))
        pin.updateFramePlacements(model, data)
        for name in robot.points:
            fid = robot.frame_id(name)
            oMf = data.oMf[fid]
            err["max_err_frames"] += [_err(dyn.point_position(name)(q), oMf.translation), _err(dyn.point_rotation(name)(q), oMf.rotation)]
            err["max_err_jacobians"].append(_err(dyn.frame_jacobian(name)(q), pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)))
            drift = pin.getFrameClassicalAcceleration(model, data, fid, pin.LOCAL_WORLD_ALIGNED).linear
            err["max_err_drift"].append(_err(dyn.point_drift(name)(q, v), drift))
    return {k: float(np.max(e)) for k, e in err.items()}  # np.max keeps a NaN, which fails the check


MUJOCO_FAILED = "FAILED: "  # how mujoco_skipped starts when MuJoCo's reading of the file fails the check


def _mujoco_errors(robot: Robot, dyn: Dynamics, states) -> tuple[MujocoCheck | None, str | None]:
    """CasADi vs MuJoCo on the same robot file, or (None, reason) when the coordinates differ.

    Only hinge and slide joints are compared: there qpos and qvel are Pinocchio's q and v in the
    same depth-first order. A free joint's qpos holds a wxyz quaternion and its linear velocity is
    in the world frame (Pinocchio: xyzw, body frame), a ball joint's likewise; converting M and h
    needs the velocity map and its time derivative, so such files are skipped instead.
    Sites are matched to named points by name.
    """
    import mujoco

    try:
        mj = mujoco_spec(robot, robot.points).compile()
    except RobotFileError as exc:  # e.g. a URDF with a free flyer only Pinocchio adds (floating=True)
        return None, str(exc)
    except ValueError as exc:  # e.g. a URDF's meshes MuJoCo cannot find, an inertia it refuses: the replay cannot run
        return None, MUJOCO_FAILED + mujoco_failure(robot.path, exc)
    kept = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
    other = [mujoco.mj_id2name(mj, mujoco.mjtObj.mjOBJ_JOINT, j) or f"joint_{j}" for j in range(mj.njnt) if int(mj.jnt_type[j]) not in kept]
    if other:
        return None, f"free/ball joints {', '.join(other)}: MuJoCo's coordinates differ from Pinocchio's"
    if (mj.nq, mj.nv) != (robot.nq, robot.nv):  # e.g. a URDF continuous joint: Pinocchio (cos, sin), MuJoCo an angle
        return None, MUJOCO_FAILED + f"MuJoCo has nq, nv = {mj.nq}, {mj.nv} but Pinocchio {robot.nq}, {robot.nv}"
    data = mujoco.MjData(mj)
    names = [mujoco.mj_id2name(mj, mujoco.mjtObj.mjOBJ_SITE, s) for s in range(mj.nsite)]
    sites = [(s, name) for s, name in enumerate(names) if name in robot.points]
    missing = tuple(name for name in names if name and name not in robot.points)
    err: dict[str, list[float]] = {"max_err_mass": [0.0], "max_err_bias": [0.0], "max_err_sites": [0.0]}
    M = np.zeros((mj.nv, mj.nv))
    for q, v in states:
        data.qpos[:], data.qvel[:] = q, v
        mujoco.mj_forward(mj, data)
        mujoco.mj_fullM(mj, data, M)
        err["max_err_mass"].append(_err(dyn.mass(q), M))
        err["max_err_bias"].append(_err(dyn.bias(q, v), data.qfrc_bias))
        err["max_err_sites"] += [_err(dyn.point_position(name)(q), data.site_xpos[s]) for s, name in sites]
    return MujocoCheck(**{k: float(np.max(e)) for k, e in err.items()}, missing_sites=missing), None


def _mean_us(call) -> float:
    call()  # first call outside the timing
    start = time.perf_counter()
    for _ in range(TIMING_EVALUATIONS):
        call()
    return (time.perf_counter() - start) / TIMING_EVALUATIONS * 1e6
