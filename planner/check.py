"""`check-model`: the CasADi dynamics against Pinocchio's numeric algorithms and MuJoCo.

At seeded random states (q uniform within the joint limits where both are finite, else in
[-1, 1], quaternions and unit complex numbers normalized; v uniform in [-1, 1]) it compares
M(q) with `pin.crba`, h(q, v) with `pin.rnea(q, v, 0)`, every named point's placement with
`data.oMf`, its frame Jacobian with `pin.getFrameJacobian(..., LOCAL_WORLD_ALIGNED)` and its
drift dJ/dt v with the classical acceleration at zero joint acceleration. It also compares M, h,
the named points' positions and MuJoCo's passive forces (the planner has none) with MuJoCo's compiled
model of the same file (a URDF file as planner.model.mujoco_spec gives it to MuJoCo: a site at every
link), and fails naming what MuJoCo applies that the planner does not model (_named_differences).
`reading_differences` is the same comparison with Pinocchio's numeric reading, which simulate and plan
run before they start.
"""
from __future__ import annotations

import contextlib
import functools
import time
import xml.etree.ElementTree as ET
from dataclasses import asdict, dataclass

import numpy as np
import pinocchio as pin

from .dynamics import Dynamics
from .errors import InputError, RobotFileError, expect, is_integer, shown
from .model import (Robot, RobotFormat, as_written, included_files, mujoco_disabled, mujoco_failure, mujoco_spec,
                    numbers_text, order_hint, wrapper_tags)

TOLERANCE = 1e-9  # every max abs difference must be at most this for `passed`
TIMING_EVALUATIONS = 200  # calls averaged per timed function


@dataclass(frozen=True)
class MujocoCheck:
    """Max abs differences between the CasADi dynamics and MuJoCo (same units as ModelCheck)."""

    max_err_mass: float
    max_err_bias: float
    max_err_sites: float  # site positions [m], sites matched to named points by name
    max_err_passive: float = 0.0  # MuJoCo's passive forces [N, N m] (the planner's dynamics have none)
    # the motors' generalized forces B u against MuJoCo's qfrc_actuator at seeded controls within the bounds [N, N m]
    max_err_actuation: float = 0.0
    missing_sites: tuple[str, ...] = ()  # MuJoCo sites Pinocchio's reading lacks (e.g. inside a <frame>): a failure
    # what MuJoCo applies that the planner does not model (flags, gravcomp, tendons, fluid, joint passive terms,
    # other joint ranges): a failure, as simulate and plan refuse the file
    differences: tuple[str, ...] = ()
    # constructs Pinocchio's MJCF parser reads otherwise than MuJoCo, named beside the mass, bias or point gaps they
    # may explain (check._parser_gaps)
    hints: tuple[str, ...] = ()


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
    # (nu,) the joint each control drives, in the order of a task's u vectors: MJCF <actuator> order, URDF joint order
    controls: tuple[str, ...]
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
    # the file's passive joint terms and couplings (Robot.passive), which fail the check with or without the MuJoCo
    # comparison (a file with damping passed under --floating, where MuJoCo's was skipped)
    passive: tuple[str, ...] = ()
    # (nv,) each degree of freedom's range as the planner reads it, with its unit and a degree file's degrees (a file of
    # radian numbers without <compiler angle="radian"> is read in degrees: its ranges said nothing of it); "" for one
    # whose coordinates are no angle or length (a free joint's, a URDF continuous joint's cos and sin): a floating
    # robot's hip and knee ranges were dropped with them
    ranges: tuple[str, ...] = ()

    @property
    def max_errors(self) -> dict[str, float]:
        """Every compared quantity's max abs difference, MuJoCo's prefixed with `mujoco_`."""
        errors = {k: getattr(self, k) for k in ("max_err_mass", "max_err_bias", "max_err_frames", "max_err_jacobians", "max_err_drift")}
        if self.mujoco is not None:
            errors.update({f"mujoco_{k}": v for k, v in asdict(self.mujoco).items() if k.startswith("max_err_")})
        return errors

    @property
    def failures(self) -> list[str]:
        """Why the check fails, one entry per reason ([] when it passes): a difference above TOLERANCE (or NaN), MuJoCo
        sites that are no points of Pinocchio's reading, physics MuJoCo applies that the planner does not model, and a
        file MuJoCo cannot compile or reads with other coordinates (which cannot be replayed)."""
        out = [f"{name} {err:.1e} > {TOLERANCE:g}" for name, err in self.max_errors.items() if not err <= TOLERANCE]
        if self.mujoco and self.mujoco.missing_sites:
            out.append(f"MuJoCo sites missing in Pinocchio's reading: {', '.join(self.mujoco.missing_sites)}")
        if self.mujoco and self.mujoco.differences:
            out.append(f"MuJoCo applies what the planner does not model: {'; '.join(self.mujoco.differences)}")
        if self.mujoco and self.mujoco.hints:
            out.append(f"Pinocchio's parser reads otherwise: {'; '.join(self.mujoco.hints)}")
        if (self.mujoco_skipped or "").startswith(MUJOCO_FAILED):
            out.append(self.mujoco_skipped.removeprefix(MUJOCO_FAILED))
        if self.passive and self.mujoco is None:  # (the compared reading names them among its differences)
            out.append(f"the planner does not model: {'; '.join(self.passive)}")
        return out

    @property
    def passed(self) -> bool:
        """No failures (ModelCheck.failures)."""
        return not self.failures

    def to_json(self) -> dict:
        out = asdict(self)
        out["dof_names"], out["points"], out["controls"] = list(self.dof_names), list(self.points), list(self.controls)
        out["passive"], out["ranges"] = list(self.passive), list(self.ranges)
        if out["mujoco"] is not None:
            for key in ("missing_sites", "differences", "hints"):  # as JSON reads them back
                out["mujoco"][key] = list(out["mujoco"][key])
        out["passed"] = self.passed
        out["failures"] = self.failures  # (the -q failure line reads them)
        out["tolerance"] = TOLERANCE
        return out

    def report(self) -> str:
        """A few lines for people: verdict, max errors, MuJoCo, timing."""
        t = self.timing
        pinocchio = "  ".join(f"{k} {getattr(self, f'max_err_{k}'):.1e}" for k in ("mass", "bias", "frames", "jacobians", "drift"))
        if self.mujoco is not None:
            m = self.mujoco
            mujoco = "  ".join(f"{k} {v:.1e}" for k, v in (("mass", m.max_err_mass), ("bias", m.max_err_bias),
                                                            ("sites", m.max_err_sites), ("passive", m.max_err_passive),
                                                            ("actuation", m.max_err_actuation)))
            if self.mujoco.missing_sites:
                mujoco += (f"; MuJoCo sites missing in Pinocchio's reading: {', '.join(self.mujoco.missing_sites)} "
                           "(Pinocchio's MJCF parser skips a site inside a <frame> or a <replicate>, and every body "
                           "of <worldbody> after the first)")
            if self.mujoco.differences:
                mujoco += f"; MuJoCo applies what the planner does not model: {'; '.join(self.mujoco.differences)}"
            if self.mujoco.hints:
                mujoco += f"; Pinocchio's parser reads otherwise: {'; '.join(self.mujoco.hints)}"
        else:
            failed = self.mujoco_skipped.startswith(MUJOCO_FAILED)
            mujoco = self.mujoco_skipped if failed else f"skipped: {self.mujoco_skipped}"
            if self.passive:
                mujoco += f"; the planner does not model: {'; '.join(self.passive)}"
        return "\n".join(
            [
                f"check-model {self.robot} ({self.format}, nq={self.nq}, nv={self.nv}, backend {self.backend}, "
                f"{self.samples} samples, seed {self.seed}): {'PASSED' if self.passed else 'FAILED'} (tolerance {TOLERANCE:g})",
                # (nq > nv: the names are the nv velocities', which the header's nq contradicted as "coordinates")
                f"  {'coordinates:' if self.nq == self.nv else 'velocities: '}  {', '.join(self.dof_names)}; points: "
                f"{', '.join(self.points)}; controls (u) drive: {', '.join(self.controls) or 'none'}",
                *([f"  ranges:       {', '.join(f'{n} {r}' for n, r in zip(self.dof_names, self.ranges) if r)}"]
                  if any(self.ranges) else []),
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


# Random states per check: 1e5 take minutes; 1e20 were drawn into one list and filled 21.5 GB before the first
# comparison.
MAX_SAMPLES = 100_000


def check_model(robot: Robot, samples: int = 20, seed: int = 0, point: str | None = None) -> ModelCheck:
    """Compare the CasADi dynamics with Pinocchio and MuJoCo at `samples` random states.

    point: the named point whose Jacobian is timed; default the first point with "foot" in its
    name, else the last named point. Raises UnknownNameError for an unknown point.
    """
    expect(robot, Robot, "check_model's robot (planner.model.load_robot)")  # (a name: an AttributeError)
    if not is_integer(samples) or not 1 <= samples <= MAX_SAMPLES:
        raise InputError(f"samples must be an integer in [1, {MAX_SAMPLES}], got {shown(samples)}")
    if not is_integer(seed) or seed < 0:  # numpy's generators take seeds >= 0 only
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
        controls=tuple(robot.dof_names[a.dof] for a in robot.actuators),
        backend=dyn.backend,
        samples=samples,
        seed=seed,
        **errors,
        mujoco=mujoco_check,
        mujoco_skipped=skipped,
        timing=timing,
        passive=robot.passive,
        ranges=_dof_ranges(robot),
    )


def _dof_ranges(robot: Robot) -> tuple[str, ...]:
    """(nv,) Robot.range_text of each degree of freedom whose joint has as many coordinates as velocities (hinges,
    slides), "" for the others' (a free joint's position and quaternion, a continuous joint's cos and sin)."""
    model, out = robot.model, []
    for j in range(1, model.njoints):
        joint = model.joints[j]
        out += ([robot.range_text(joint.idx_q + k) for k in range(joint.nq)] if joint.nq == joint.nv
                else [""] * joint.nv)
    return tuple(out)


def _err(a, b) -> float:
    return float(np.max(np.abs(np.asarray(a, dtype=float).reshape(np.shape(b)) - b), initial=0.0))


def _pinocchio_errors(robot: Robot, dyn: Dynamics, states) -> dict[str, float]:
    model, data = robot.model, robot.model.createData()
    err: dict[str, list[float]] = {k: [0.0] for k in ("max_err_mass", "max_err_bias", "max_err_frames", "max_err_jacobians", "max_err_drift")}
    for q, v in states:
        err["max_err_mass"].append(_err(dyn.mass(q), _symmetric(pin.crba(model, data, q))))
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
# MuJoCo settings of a file that change the replay's physics and that the planner does not model ([option] flags): a
# disabled gravity, contact, constraint or actuation, an enabled contact override (the validation's contact replaced)
DISABLED_PHYSICS = ("gravity", "contact", "constraint", "actuation")
ENABLED_PHYSICS = ("override",)
READING_STATES = 3  # seeded states at which simulate and plan compare the two readings (reading_differences)


SKIPPED, UNREADABLE, DIFFERENT = "skipped", "unreadable", "different"  # why _compile returns no model


def _compile(robot: Robot):
    """(MuJoCo's compiled model of the robot file, None, None), or (None, kind, why): SKIPPED when MuJoCo's coordinates
    cannot be compared directly with Pinocchio's (a free or ball joint, Pinocchio's own free flyer), UNREADABLE when
    MuJoCo cannot read or compile the file (the replay cannot run), DIFFERENT when MuJoCo reads other coordinates or
    another joint order than the planner plans for."""
    import mujoco

    if robot.floating:  # (_mujoco_errors adds it to MuJoCo's root body, and appends why when that fails)
        return None, SKIPPED, ("Pinocchio's free-flyer root joint (--floating) is not in the file MuJoCo reads, and a "
                               "free joint added to MuJoCo's root body does not give Pinocchio's coordinates")
    try:
        spec = mujoco_spec(robot, robot.points, check_order=False)
    except RobotFileError as exc:
        return None, UNREADABLE, str(exc)
    kept = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
    kinds = {int(mujoco.mjtJoint.mjJNT_FREE): "free", int(mujoco.mjtJoint.mjJNT_BALL): "ball"}
    other = [f"{kinds[int(j.type)]} joint {j.name or f'joint_{i}'}" for i, j in enumerate(spec.joints)
             if int(j.type) not in kept]
    try:
        mj = spec.compile()
    except ValueError as exc:  # e.g. a URDF's meshes MuJoCo cannot find, an inertia it refuses: the replay cannot run
        return None, UNREADABLE, mujoco_failure(robot.path, exc)
    if other:  # before the names: a free joint is one MuJoCo joint and six named degrees of freedom (root_0 ...)
        # (a ball joint reaches here with the pinocchio.casadi backend only: the symbolic one refuses it)
        return None, SKIPPED, (f"{', '.join(other)}: MuJoCo's coordinates differ from Pinocchio's, and check-model "
                               "converts a free joint's only in a robot of free, hinge and slide joints")
    order = _order_difference(robot, tuple(j.name for j in spec.joints))
    if order:
        return None, DIFFERENT, order
    if (mj.nq, mj.nv) != (robot.nq, robot.nv):  # e.g. a URDF continuous joint: Pinocchio (cos, sin), MuJoCo an angle
        model = robot.model
        unbounded = [f"{model.names[j]!r}" for j in range(1, model.njoints) if model.joints[j].nq == 2 and model.joints[j].nv == 1]
        why = (f" (joint {', '.join(unbounded)}: a URDF continuous joint, which Pinocchio reads as cos and sin; make it "
               "revolute with limits)" if unbounded else "")
        return None, DIFFERENT, f"MuJoCo has nq, nv = {mj.nq}, {mj.nv} but Pinocchio {robot.nq}, {robot.nv}{why}"
    return mj, None, None


def _order_difference(robot: Robot, names: tuple[str, ...]) -> str | None:
    """Why MuJoCo's joints, named along its velocities (names, (nv,)), are not the robot's dof_names, or None."""
    if names == robot.dof_names:
        return None
    # a URDF planar joint (MuJoCo's three, Pinocchio's one), URDF siblings
    return f"MuJoCo orders the joints {names}, Pinocchio {robot.dof_names}{order_hint(robot, names)}"


def _named_differences(robot: Robot, mj) -> tuple[str, ...]:
    """What MuJoCo applies from the file beyond the rigid-body dynamics and the joint passive terms Robot.passive
    names: [option] flags, gravity compensation, tendon forces and limits, actuators' armature, damping and delay,
    fluid forces, joint actuator force ranges, joint limits other than Pinocchio's (the planner's bounds) and limits
    with a margin."""
    import mujoco

    def name(kind, i):
        return mujoco.mj_id2name(mj, kind, i) or f"#{i}"

    gravity = np.asarray(robot.model.gravity.linear, float)  # an MJCF file's is MuJoCo's; a URDF's <mujoco> may set one
    out = [] if np.allclose(mj.opt.gravity, gravity, rtol=0.0, atol=TOLERANCE) else [
        f"gravity {np.round(mj.opt.gravity, 9).tolist()} m/s^2 in MuJoCo (<option gravity>), "
        f"{np.round(gravity, 9).tolist()} in Pinocchio"]
    out += [f"<option><flag {flag}=\"disable\"/>" for flag in DISABLED_PHYSICS if mujoco_disabled(mj, flag)]
    # (a term the file's flags turn off MuJoCo does not apply: not named, as Robot.passive's joint terms are not)
    damper, spring, friction = (not mujoco_disabled(mj, flag) for flag in ("damper", "spring", "frictionloss"))
    out += [f"<option><flag {flag}=\"enable\"/>" for flag in ENABLED_PHYSICS
            if mj.opt.enableflags & int(getattr(mujoco.mjtEnableBit, f"mjENBL_{flag.upper()}"))]
    out += [f"body {name(mujoco.mjtObj.mjOBJ_BODY, b)!r}: gravcomp {mj.body_gravcomp[b]:g}" for b in range(mj.nbody) if mj.body_gravcomp[b]]
    for t in range(mj.ntendon):
        terms = [f"{label} {value:g}" for label, value in
                 (("stiffness", mj.tendon_stiffness[t] * spring), ("damping", mj.tendon_damping[t] * damper),
                  ("frictionloss", mj.tendon_frictionloss[t] * friction)) if value]
        terms += [f"range [{mj.tendon_range[t][0]:g}, {mj.tendon_range[t][1]:g}]"] if mj.tendon_limited[t] else []
        if terms:
            out.append(f"tendon {name(mujoco.mjtObj.mjOBJ_TENDON, t)!r}: {', '.join(terms)}")
    for a in range(mj.nu):  # (named by their mass, passive or actuation gap alone, "masses MuJoCo infers" among causes)
        terms = [f"{label} {numbers_text(values[a])}" for label, values in
                 (("armature", mj.actuator_armature),
                  ("damping", as_written(mj.actuator_damping, mj.actuator_dampingpoly) * damper),
                  ("delay", mj.actuator_delay)) if np.any(values[a])]
        if terms:
            out.append(f"actuator {name(mujoco.mjtObj.mjOBJ_ACTUATOR, a)!r}: {', '.join(terms)}")
    if mj.opt.density or mj.opt.viscosity or np.any(mj.opt.wind):
        out.append(f"fluid forces (<option> density {mj.opt.density:g}, viscosity {mj.opt.viscosity:g}, wind {np.round(mj.opt.wind, 9).tolist()})")
    if robot.format is RobotFormat.MJCF:  # (the mass gap alone was named, "masses MuJoCo rescales" among its causes)
        out += [f"<compiler settotalmass=\"{c.get('settotalmass')}\">: MuJoCo rescales the masses, Pinocchio does not"
                for c in _rescaling(ET.parse(robot.path).getroot())]
    lower, upper = robot.q_lower, robot.q_upper
    for j in range(mj.njnt):
        joint, i = name(mujoco.mjtObj.mjOBJ_JOINT, j), int(mj.jnt_qposadr[j])
        last = j == max(k for k in range(mj.njnt) if mj.jnt_bodyid[k] == mj.jnt_bodyid[j])
        if mj.qpos0[i] and not last:  # (only "point 'foot' is 0.2 m apart"; a body's last joint's ref Pinocchio reads)
            unit = "m" if mj.jnt_type[j] == mujoco.mjtJoint.mjJNT_SLIDE else "rad"
            out.append(f"joint {joint!r}: ref {mj.qpos0[i]:g} {unit}, which Pinocchio's parser ignores on a joint "
                       "before its body's last; remove ref or make it its body's last joint")
        if mj.jnt_actfrclimited[j]:  # MuJoCo clamps the joint's summed actuator force: fine where the motors stay inside
            drives = [a for a in robot.actuators if a.dof == int(mj.jnt_dofadr[j])]
            reach = (sum(min(a.gear * a.lower, a.gear * a.upper) for a in drives),  # a negative gear swaps its ends
                     sum(max(a.gear * a.lower, a.gear * a.upper) for a in drives))
            lo, hi = (float(x) for x in mj.jnt_actfrcrange[j])
            if reach[0] < lo - TOLERANCE or reach[1] > hi + TOLERANCE:
                out.append(f"joint {joint!r}: actuatorfrcrange [{lo:g}, {hi:g}] narrower than its motors' force range "
                           f"[{reach[0]:g}, {reach[1]:g}]")
        # (a plan on its bounds validated 45-198 mm off the plan's path; <flag limit="disable"/>: no limit acts)
        if mj.jnt_limited[j] and mj.jnt_margin[j] and not mujoco_disabled(mj, "limit"):
            out.append(f"joint {joint!r}: margin {mj.jnt_margin[j]:g}: MuJoCo's limit pushes that far inside the "
                       "range, where the planner's bounds allow motion; remove margin")
        mujoco_range = tuple(float(x) for x in mj.jnt_range[j]) if mj.jnt_limited[j] else (-np.inf, np.inf)
        # (a free joint's range: Pinocchio's placeholders)
        if mj.jnt_type[j] != mujoco.mjtJoint.mjJNT_FREE and not np.allclose(
                mujoco_range, (lower[i], upper[i]), rtol=0.0, atol=TOLERANCE):
            out.append(f"joint {joint!r}: range [{mujoco_range[0]:g}, {mujoco_range[1]:g}] in MuJoCo, [{lower[i]:g}, {upper[i]:g}] in Pinocchio")
    return tuple(out)


def _mujoco_gaps(mj, states, mass, bias, position, robot: Robot) -> dict[str, float]:
    """Max abs differences at `states` ((q, v) pairs) between MuJoCo's compiled model mj and a reading of the same file
    given as mass(q) (nv, nv), bias(q, v) (nv,) and position(point, q) (3,) callables: "mass" [kg, kg m, kg m^2],
    "bias" [N, N m], "passive" (MuJoCo's passive forces, which the planner does not have) [N, N m], "actuation" (the
    robot's B u against MuJoCo's actuator forces at seeded controls u within its bounds) [N, N m], and per MuJoCo site
    named as one of robot.points, its position [m] (the dict "sites": name -> difference)."""
    import mujoco

    data = mujoco.MjData(mj)
    rng = np.random.default_rng(1)  # (a gear read or applied otherwise had no check: every robot's gear was 1)
    B, lower, upper = robot.actuation_matrix, robot.u_lower, robot.u_upper
    sites = [(s, mujoco.mj_id2name(mj, mujoco.mjtObj.mjOBJ_SITE, s)) for s in range(mj.nsite)]
    sites = [(s, name) for s, name in sites if name in robot.points]
    err = {"mass": [0.0], "bias": [0.0], "passive": [0.0], "actuation": [0.0]}
    apart = {name: [0.0] for _, name in sites}
    M = np.zeros((mj.nv, mj.nv))
    for q, v in states:
        data.qpos[:], data.qvel[:] = q, v
        u = np.clip(10.0 * rng.standard_normal(mj.nu), lower, upper)
        data.ctrl[:] = u
        mujoco.mj_forward(mj, data)
        err["actuation"].append(_err(B @ u, data.qfrc_actuator))
        mujoco.mj_fullM(mj, data, M)
        err["mass"].append(_err(mass(q), M))
        err["bias"].append(_err(bias(q, v), data.qfrc_bias))
        err["passive"].append(float(np.max(np.abs(data.qfrc_passive), initial=0.0)))
        for s, name in sites:
            apart[name].append(_err(position(name, q), data.site_xpos[s]))
    gaps = {k: float(np.max(e)) for k, e in err.items()}  # np.max keeps a NaN, which fails the check
    return {**gaps, "sites": {name: float(np.max(e)) for name, e in apart.items()}}


def _symmetric(M) -> np.ndarray:
    """Pinocchio's crba fills the upper triangle only: the whole symmetric matrix."""
    return np.triu(M) + np.triu(M, 1).T


@functools.lru_cache(maxsize=16)
def reading_differences(robot: Robot) -> tuple[str, ...]:
    """How MuJoCo, which replays plans and simulations, reads other physics from the robot file than Pinocchio, whose
    reading the planner's dynamics are: _named_differences, then mass matrix, bias forces, passive forces (unless a
    named cause above accounts for them) and named points' positions differing by more than TOLERANCE at
    READING_STATES seeded states (Pinocchio's numeric algorithms; check-model compares the CasADi functions at more).
    () when they agree, or when MuJoCo's reading cannot be compared or cannot be read at all (free or ball joints; a
    file MuJoCo cannot compile: check-model and the validation say so); other coordinates or joint order are a
    difference. Simulate and plan refuse a robot with any (Task.check_against)."""
    mj, kind, why = _compile(robot)
    if mj is None:
        return (why,) if kind == DIFFERENT else ()
    named = _named_differences(robot, mj)
    model, data = robot.model, robot.model.createData()
    rng = np.random.default_rng(0)

    def position(point, q):
        pin.framesForwardKinematics(model, data, q)
        return data.oMf[robot.frame_id(point)].translation

    gaps = _mujoco_gaps(mj, [random_state(model, rng) for _ in range(READING_STATES)],
                        lambda q: _symmetric(pin.crba(model, data, q)),
                        lambda q, v: pin.rnea(model, data, q, v, np.zeros(model.nv)), position, robot)
    out = list(named)
    what = {"mass": "mass matrix [kg, kg m, kg m^2] differs by up to {:.3g} (e.g. masses MuJoCo infers from geoms, a "
                    "geom's mass or a mesh's inertia, which Pinocchio's parser reads otherwise, or masses MuJoCo "
                    "rescales)",
            "bias": "bias forces [N, N m] differ by up to {:.3g}", "passive": "passive forces [N, N m] up to {:.3g}",
            "actuation": "the motors' generalized forces [N, N m] differ by up to {:.3g}"}
    for key, text in what.items():
        if not gaps[key] <= TOLERANCE and not (key == "passive" and named):  # gravcomp, tendons, fluid: said once, by name
            out.append(text.format(gaps[key]))
    out += [f"point {point!r} is up to {err:.3g} m apart" for point, err in gaps["sites"].items() if not err <= TOLERANCE]
    out += _hints(robot, gaps, mj)
    return tuple(out + (_include_hint(robot) if out else []))


def _hints(robot: Robot, gaps: dict, mj) -> list[str]:
    """_body_masses and _parser_gaps of an MJCF file, a URDF's <mujoco><compiler boundmass/boundinertia>, when the
    mass, bias or point gaps (_mujoco_gaps) exceed TOLERANCE, else []: they explain those gaps, not a named
    difference."""
    measured = not (gaps["mass"] <= TOLERANCE and gaps["bias"] <= TOLERANCE
                    and all(err <= TOLERANCE for err in gaps["sites"].values()))
    if not measured:
        return []
    root = ET.parse(robot.path).getroot()
    if robot.format is not RobotFormat.MJCF:  # (Pinocchio's MJCF parser applies boundmass, its URDF parser not)
        return [f"<mujoco><compiler {key}=\"{c.get(key)}\">: MuJoCo raises lighter {what} to it, Pinocchio's URDF "
                "parser does not; remove it and give each link its own <inertial>"
                for c in root.iter("compiler") for key, what in (("boundmass", "masses"), ("boundinertia", "inertias"))
                if _positive(c.get(key))]
    return _body_masses(robot, mj, root) + _parser_gaps(root)


def _include_hint(robot: Robot) -> list[str]:
    """The hint for an MJCF file with an <include>, given with any difference (a gap or a named one): an included
    <compiler angle="radian"> was blamed on "masses MuJoCo infers from geoms" in a file of none, and an included
    <default> damping's passive forces named no cause."""
    if robot.format is not RobotFormat.MJCF or not included_files(robot.path):
        return []
    return ["the file has an <include>, whose <compiler> and <default> Pinocchio's MJCF parser does not read: the "
            "differences above may be theirs; write them into the file"]


def _positive(text: str | None) -> bool:
    """Whether an attribute's text is a number > 0 (MuJoCo's boundmass="0" is no bound)."""
    with contextlib.suppress(TypeError, ValueError):
        return float(text) > 0
    return False


def _body_masses(robot: Robot, mj, root: ET.Element) -> list[str]:
    """The bodies (by the joint that moves them, jointless ones welded to it) whose mass MuJoCo and Pinocchio read
    differently: MuJoCo weighs a body without <inertial> by its geoms, Pinocchio's parser otherwise, for the causes
    _weighing_causes tells (the check named a mass gap, and no body)."""
    import mujoco

    model, mass, names = robot.model, np.zeros(robot.model.njoints), [[] for _ in range(robot.model.njoints)]
    for b in range(1, mj.nbody):
        body = mujoco.mj_id2name(mj, mujoco.mjtObj.mjOBJ_BODY, b)
        if body is None or not model.existFrame(body, pin.FrameType.BODY):  # (a site may share its body's name)
            return []  # (bodies not matched by name: no per-body comparison)
        j = model.frames[model.getFrameId(body, pin.FrameType.BODY)].parentJoint
        mass[j] += mj.body_mass[b]
        names[j].append(body)
    if _rescaling(root):
        return []  # (named: MuJoCo rescales every mass; "give those bodies an <inertial>" was wrong advice, review)
    weighed = {b.get("name") for b in root.iter("body") if b.find("inertial") is None}
    geometric = any(c.get("inertiafromgeom") == "true" for c in root.iter("compiler"))
    joints = [j for j in range(1, model.njoints) if abs(mass[j] - model.inertias[j].mass) > TOLERANCE
              and (geometric or weighed.intersection(names[j]))]
    apart = [f"{'+'.join(names[j])} {_apart(mass[j], model.inertias[j].mass)}" for j in joints]
    if not apart:
        return []
    # (a body with its own <inertial> weighs that in both readings, unless inertiafromgeom: its geoms tell no cause)
    causes = "; ".join(_weighing_causes(mj, root, [name for j in joints for name in names[j]
                                                   if geometric or name in weighed]))
    if geometric:
        return [f"body masses {'; '.join(apart)}: with <compiler inertiafromgeom=\"true\"> both weigh every body by "
                f"its geoms instead of its <inertial>; {causes}; remove it and give each body an <inertial>"]
    return [f"body masses {'; '.join(apart)}: MuJoCo weighs a body without <inertial> by its geoms; {causes}; give "
            "those bodies an <inertial>"]


def _weighing_causes(mj, root: ET.Element, bodies: list[str]) -> list[str]:
    """Why MuJoCo and Pinocchio's parser weigh these bodies (names) apart, as far as the compiled model and the file's
    <compiler> and <default> tell it cheaply; a neutral one when they tell none (the message blamed geoms that collide
    with nothing in files whose cause was a mesh, inertiagrouprange or discardvisual: session 69's tester)."""
    import mujoco

    ids = [mj.body(name).id for name in bodies]
    geoms = [g for g in range(mj.ngeom) if mj.geom_bodyid[g] in ids]
    colliding = [g for g in geoms if mj.geom_contype[g] or mj.geom_conaffinity[g]]
    compiler = {"inertiagrouprange": "0 5"}  # (MuJoCo's default range)
    compiler.update({key: c.get(key) for c in root.iter("compiler") for key in ("discardvisual", "inertiagrouprange")
                     if c.get(key) is not None})
    causes = []
    # (discardvisual drops them from the compiled model after MuJoCo weighed them: the file still counts them)
    written = sum(len(b.findall("geom")) for b in root.iter("body") if b.get("name") in bodies)
    discarded = compiler.get("discardvisual") == "true" and written > len(geoms)
    if discarded or len(colliding) < len(geoms):
        causes.append("Pinocchio's parser weighs only the geoms that collide (contype or conaffinity nonzero)"
                      + (", MuJoCo also those <compiler discardvisual=\"true\"> discards" if discarded else ""))
    if any(mj.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH for g in colliding):
        causes.append("Pinocchio's parser weighs a colliding mesh geom 1 kg whatever its size, MuJoCo by its volume")
    with contextlib.suppress(ValueError):
        low, high = (int(x) for x in compiler["inertiagrouprange"].split())
        if any(not low <= mj.geom_group[g] <= high for g in colliding):
            causes.append(f"MuJoCo weighs only the geoms of groups {low} to {high} (<compiler inertiagrouprange="
                          f"\"{compiler['inertiagrouprange']}\">), Pinocchio's parser those of every group")
    if _default_mass_geoms(root, bodies):
        causes.append("Pinocchio's parser does not read a <default>'s geom mass")
    return causes or ["Pinocchio's parser weighs them otherwise"]


def _default_mass_geoms(root: ET.Element, bodies: list[str]) -> bool:
    """Whether a geom of these bodies (names) without a mass of its own takes one from its <default> class (its class,
    else its nearest body's childclass, else the top-level default; a class inherits its parent's): an unused class's
    mass was named as the cause of a mesh's gap."""
    massive = set()

    def walk(default: ET.Element, inherited: bool) -> None:
        has = inherited or any(g.get("mass") is not None for g in default.findall("geom"))
        if has:
            massive.add(default.get("class", "main"))
        for child in default.findall("default"):
            walk(child, has)

    for default in root.findall("default"):
        walk(default, False)

    parents = {child: parent for parent in root.iter() for child in parent}

    def childclass(node: ET.Element | None) -> str:  # (a body's own childclass applies to its own geoms too)
        while node is not None:
            if node.tag == "body" and node.get("childclass"):
                return node.get("childclass")
            node = parents.get(node)
        return "main"

    return any(geom.get("mass") is None and geom.get("class", childclass(body)) in massive
               for body in root.iter("body") if body.get("name") in bodies for geom in body.findall("geom"))


def _rescaling(root: ET.Element) -> list[ET.Element]:
    """The <compiler> elements with a settotalmass > 0: MuJoCo rescales every mass to it."""
    return [c for c in root.iter("compiler") if float(c.get("settotalmass", -1)) > 0]


def _apart(mujoco_kg: float, pinocchio_kg: float) -> str:
    """The two masses with the digits that tell them apart (a mesh's float32 volume read "1 kg in MuJoCo, 1 kg")."""
    for spec in (".6g", ".9g", ".12g", ".17g"):
        if format(mujoco_kg, spec) != format(pinocchio_kg, spec):
            break
    return f"{mujoco_kg:{spec}} kg in MuJoCo, {pinocchio_kg:{spec}} kg in Pinocchio"


AXIS_TOL = 1e-12  # an axisangle axis whose length differs from 1 by more is one Pinocchio's parser does not normalize
ANTIPARALLEL = 1e-2  # a zaxis within this angle [rad] of -z (but not on it) may be turned otherwise by Pinocchio's
# parser (measured: 1e-9 a half turn about another axis, 1e-5 and 1e-3 gaps of 1e-8 and 1e-9 in the bias forces)


def _parser_gaps(root: ET.Element) -> list[str]:
    """MJCF constructs of the file at `root` that MuJoCo reads and Pinocchio's MJCF parser (3.x) reads otherwise, as
    measured (session 56): they explain a mass, bias or point difference that reading_differences found and the mass
    message's "e.g." does not."""
    out = []
    placed = [e for e in root.iter() if e.tag in ("body", "inertial", "site", "frame")]  # what Pinocchio places

    def turned(text):  # (a malformed one MuJoCo refuses first)
        with contextlib.suppress(ValueError):
            return any(float(x) for x in text.split())
        return False

    compilers = root.findall("compiler")
    late = [e.tag for e in root].index("worldbody") if root.find("worldbody") is not None else len(root)
    first = next((c for c in root[:late] if c.tag == "compiler"), None)  # the one Pinocchio's parser reads
    read = dict(first.attrib) if first is not None else {}
    # (two that agree are no gap: the hint came before a file's real cause)
    if any(read.get(k) != v for c in compilers if c is not first for k, v in c.attrib.items()):
        which = f"{len(compilers)} <compiler> elements" if len(compilers) > 1 else "<compiler> after <worldbody>"
        out.append(f"{which}: Pinocchio's parser reads the first only and only before <worldbody>, MuJoCo all of "
                   "them; merge them into one <compiler> before <worldbody>")
    wrapped = wrapper_tags(root)
    if wrapped:
        out.append(f"<{'> and <'.join(wrapped)}> elements: Pinocchio's parser does not read the bodies, geoms and "
                   "sites inside them (MuJoCo does); write those out with their own pos and orientation")
    for e in placed:  # (measured: zaxis "1e-9 0 -1" is a half turn about x to MuJoCo, about y to Pinocchio)
        try:
            z = np.array((e.get("zaxis") or "0 0 1").split(), float)
        except ValueError:  # MuJoCo refuses it first
            continue
        if z.shape == (3,) and np.any(z[:2]) and z[2] < 0 and np.linalg.norm(z[:2]) < ANTIPARALLEL * abs(z[2]):
            named = f" name={e.get('name')!r}" if e.get("name") else ""
            out.append(f"<{e.tag}{named}> zaxis {e.get('zaxis')!r}, nearly opposite to z, which Pinocchio's parser "
                       "turns about another axis than MuJoCo; give the orientation as quat or xyaxes")
    seq = next((c.get("eulerseq") for c in root.iter("compiler") if c.get("eulerseq")), "xyz")
    if seq != seq.lower() and any(turned(e.get("euler") or "") for e in placed):
        out.append(f"<compiler eulerseq=\"{seq}\">: Pinocchio's parser reads an extrinsic (upper-case) sequence as "
                   "intrinsic; write the orientations as quat or in the lower-case sequence")
    for e in placed:
        axis = (e.get("axisangle") or "").split()[:3]
        try:
            length = float(np.linalg.norm(np.array(axis, float))) if len(axis) == 3 else 1.0
        except ValueError:  # MuJoCo refuses it first
            continue
        if abs(length - 1.0) > AXIS_TOL:
            out.append(f"<{e.tag} name={e.get('name')!r}> axisangle axis of length {length:.12g}, which Pinocchio's "
                       "parser does not normalize (MuJoCo does); give a unit axis to full precision, or a quat")
    for d in root.iter("default"):
        where = f"<default class={d.get('class')!r}>" if d.get("class") else "<default>"
        out += [f"{where} gives <{e.tag}> pos, which Pinocchio's parser does not apply; write pos on each {e.tag}"
                for e in d.findall("*") if e.tag in ("joint", "site") and e.get("pos")]

    def jointless(body):
        return body.tag == "body" and not body.findall("joint") and not body.findall("freejoint")

    for body in root.iter("body"):
        inner = [b for b in body.findall("body") if jointless(b) and b.findall("site")]
        if jointless(body):
            out += [f"site(s) {[s.get('name') for s in b.findall('site')]} on body {b.get('name')!r}, a body without "
                    f"joints inside the body without joints {body.get('name')!r}, which Pinocchio's parser places "
                    "otherwise; merge the two bodies" for b in inner]
    return out


def _mujoco_errors(robot: Robot, dyn: Dynamics, states) -> tuple[MujocoCheck | None, str | None]:
    """CasADi vs MuJoCo on the same robot file, or (None, reason) when the coordinates differ.

    For hinge and slide joints qpos and qvel are Pinocchio's q and v in the same depth-first order.
    A free joint's qpos holds the world pose with a wxyz quaternion and its linear velocity is in
    the world frame (Pinocchio: xyzw, body frame): a robot of free, hinge and slide joints is
    compared in MuJoCo's coordinates (_free_joint_map), a --floating URDF's other joints in Pinocchio's order only
    (as _compile's); one that also has a ball joint, or a --floating URDF MuJoCo cannot read with a free root joint
    at Pinocchio's root link (e.g. a root link named world), is skipped.
    Sites are matched to named points by name. MuJoCo's passive forces are compared with zero (the planner has none),
    and what _named_differences finds fails the check, as do the file's Robot.passive terms.
    """
    import mujoco

    mj, kind, why = _compile(robot)
    mass, bias, position = dyn.mass, dyn.bias, lambda name, q: dyn.point_position(name)(q)
    if mj is None and kind == SKIPPED:
        mapped = _free_joint_map(robot)
        if isinstance(mapped, str):
            why = f"{why}: {mapped}" if robot.floating else why  # (otherwise _compile's names each joint's type)
        else:  # free joints: compare in MuJoCo's coordinates
            mj, to_mujoco, to_pinocchio = mapped
            mass, bias, position = _in_mujoco_coordinates(dyn, to_pinocchio)
            states = [to_mujoco(q, v) for q, v in states]
            # _compile's order check never ran, and a URDF's sibling branches may be ordered otherwise (an MJCF file's
            # are in file order in both readings): MuJoCo's first joint is the free root, named as Pinocchio's six
            order = robot.floating and _order_difference(
                robot, robot.dof_names[:6] + tuple(mj.joint(k).name for k in range(1, mj.njnt)))
            if order:
                mj, kind, why = None, DIFFERENT, order
    if mj is None:
        return None, why if kind == SKIPPED else MUJOCO_FAILED + why
    gaps = _mujoco_gaps(mj, states, mass, bias, position, robot)
    names = [mujoco.mj_id2name(mj, mujoco.mjtObj.mjOBJ_SITE, s) for s in range(mj.nsite)]
    missing = tuple(name for name in names if name and name not in robot.points and name not in robot.world_sites)
    differences, hints = _named_differences(robot, mj) + robot.passive, _hints(robot, gaps, mj)
    gapped = any(not gaps[key] <= TOLERANCE for key in ("mass", "bias", "passive", "actuation")) or any(
        not err <= TOLERANCE for err in gaps["sites"].values())
    return MujocoCheck(max_err_mass=gaps["mass"], max_err_bias=gaps["bias"], max_err_passive=gaps["passive"],
                       max_err_actuation=gaps["actuation"],
                       max_err_sites=float(np.max(list(gaps["sites"].values()), initial=0.0)), missing_sites=missing,
                       differences=differences,
                       hints=tuple(hints + (_include_hint(robot) if differences or hints or gapped else []))), None


def _mean_us(call) -> float:
    call()  # first call outside the timing
    start = time.perf_counter()
    for _ in range(TIMING_EVALUATIONS):
        call()
    return (time.perf_counter() - start) / TIMING_EVALUATIONS * 1e6


def _free_joint_map(robot: Robot):
    """(MuJoCo's compiled model, to_mujoco(q, v) -> (qpos, qvel), to_pinocchio(qpos, qvel) -> (q, v, T, Tdot_v)) when
    the robot's only joints other than hinges and slides are MJCF free joints at the same coordinate addresses in
    both readings, else why not (a str, the skip's cause under --floating: it listed every possible one). A free
    joint: MuJoCo's qpos is the body's world pose (position, wxyz quaternion), Pinocchio's q is relative to the
    joint's placement (position, xyzw); MuJoCo's linear velocity is in the world frame, Pinocchio's in the body frame
    (qvel = T v, T = blockdiag(R, I) on the joint's block)."""
    import mujoco

    model = robot.model
    try:
        spec = mujoco_spec(robot, robot.points, check_order=False)
    except RobotFileError as exc:
        return str(exc)
    if robot.floating:  # Pinocchio's free-flyer root (--floating): the same joint on MuJoCo's root link
        root = spec.worldbody.first_body()
        # (a URDF's root link has no joint of its own: MuJoCo's root body has joints, as capler.urdf's 'carriage'
        # has base_x, only when the root link is world)
        if not _is_free_flyer_body(model, root.name):
            return ("the root link is named world, which MuJoCo reads as its world body, so the free joint would move "
                    f"the link after it ({root.name!r})")
        root.add_freejoint()
    try:
        mj = spec.compile()
    except ValueError as exc:
        return mujoco_failure(robot.path, exc)
    free = [j for j in range(1, model.njoints) if model.joints[j].shortname() == "JointModelFreeFlyer"]
    unequal = [model.names[j] for j in range(1, model.njoints) if j not in free
               and model.joints[j].nq != model.joints[j].nv]
    if unequal:
        return f"joint {', '.join(map(repr, unequal))} has more coordinates than velocities in Pinocchio's reading"
    mj_free = [k for k in range(mj.njnt) if mj.jnt_type[k] == mujoco.mjtJoint.mjJNT_FREE]
    if (mj.nq, mj.nv) != (model.nq, model.nv) or len(mj_free) != len(free) or any(
            (model.joints[j].idx_q, model.joints[j].idx_v) != (mj.jnt_qposadr[k], mj.jnt_dofadr[k])
            for j, k in zip(free, mj_free)):
        return (f"MuJoCo reads nq, nv = {mj.nq}, {mj.nv} with {len(mj_free)} free joint(s), Pinocchio {model.nq}, "
                f"{model.nv} with {len(free)}, or their free joints at other coordinates")
    blocks = [(model.joints[j].idx_q, model.joints[j].idx_v, model.jointPlacements[j]) for j in free]

    def to_mujoco(q, v):
        qm, vm = np.array(q, float), np.array(v, float)
        for iq, iv, placement in blocks:
            world = placement * pin.XYZQUATToSE3(q[iq:iq + 7])
            quat = pin.Quaternion(world.rotation)
            qm[iq:iq + 7] = [*world.translation, quat.w, quat.x, quat.y, quat.z]
            vm[iv:iv + 3] = world.rotation @ v[iv:iv + 3]
        return qm, vm

    def to_pinocchio(qm, vm):
        q, v = np.array(qm, float), np.array(vm, float)
        T, Tdot_v = np.eye(model.nv), np.zeros(model.nv)
        for iq, iv, placement in blocks:
            w, x, y, z = qm[iq + 3:iq + 7]
            R = pin.Quaternion(w, x, y, z).normalized().matrix()
            local = placement.inverse() * pin.SE3(R, np.array(qm[iq:iq + 3], float))
            q[iq:iq + 7] = pin.SE3ToXYZQUAT(local)
            v[iv:iv + 3] = R.T @ vm[iv:iv + 3]
            T[iv:iv + 3, iv:iv + 3] = R
            Tdot_v[iv:iv + 3] = R @ np.cross(v[iv + 3:iv + 6], v[iv:iv + 3])
        return q, v, T, Tdot_v

    return mj, to_mujoco, to_pinocchio


def _is_free_flyer_body(model: pin.Model, name: str) -> bool:
    """Whether the link MuJoCo gave the free joint (name) sits at Pinocchio's free flyer: a root link named world is
    MuJoCo's world body, so the free joint goes to the link after it, at the fixed joint's offset, and the two readings'
    free-joint poses would differ by that offset."""
    if not model.existFrame(name, pin.FrameType.BODY):
        return False
    frame = model.frames[model.getFrameId(name, pin.FrameType.BODY)]
    return frame.parentJoint == 1 and frame.placement.isIdentity()


def _in_mujoco_coordinates(dyn: Dynamics, to_pinocchio):
    """mass(qpos), bias(qpos, qvel) and position(point, qpos) of the CasADi dynamics in MuJoCo's coordinates:
    qvel = T v gives M_mj = T^-T M T^-1 and h_mj = T^-T h - M_mj Tdot v."""
    def mass(qm):
        q, _, T, _ = to_pinocchio(qm, np.zeros(dyn.nv))
        Ti = np.linalg.inv(T)
        return Ti.T @ np.asarray(dyn.mass(q), float) @ Ti

    def bias(qm, vm):
        q, v, T, Tdot_v = to_pinocchio(qm, vm)
        Ti = np.linalg.inv(T)
        M = Ti.T @ np.asarray(dyn.mass(q), float) @ Ti
        return Ti.T @ np.asarray(dyn.bias(q, v), float).ravel() - M @ Tdot_v

    def position(name, qm):
        q, _, _, _ = to_pinocchio(qm, np.zeros(dyn.nv))
        return dyn.point_position(name)(q)

    return mass, bias, position
