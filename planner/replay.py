"""MuJoCo replay of a planned trajectory: the independent judge of whether a plan is physically meaningful.

The plan comes from Pinocchio's model of a robot file and the time-freezing contact model; MuJoCo
reads the SAME file (MJCF, or URDF through planner.model.mujoco_spec) and replays the physical-time
trajectory three ways:

1. **kinematic** -- qpos is set sample by sample. Reports how far each contact point is below the
   ground (the pass/fail penetration) and whether MuJoCo's collision detection finds a contact at
   exactly the samples where the plan has one (gap below `contact_gap_tol_m`).
2. **tracking** -- the planned controls as feed-forward plus joint PD in physical time, on the
   planned q, v of the actuated joints or, with `TrackingController.STANCE_RETARGET`, on joint
   references recomputed in stance so that the base is fed back. Reports base and foot tracking errors [m] (the base error is
   the pass/fail tracking error), impact time differences and actuator saturation.
3. **open loop** -- the planned controls only. Reports how long the base stays within
   `open_loop_band_m` of the plan (information only: open-loop drift is expected for unstable robots).

MuJoCo's contacts are made to approximate rigid, inelastic impacts with Coulomb friction; the model
is edited programmatically (mjSpec) so the robot files stay plain. What is changed, and why, is in
`build_scene` and docs/validation.md.

Units: SI throughout (m, s, rad, N, N m). Arrays follow the result contract of docs/results.md:
`t` (P,), `q` (P, nq), `v` (P, nv), `u` (P, nu), `impact_times` (I,).
"""
from __future__ import annotations

import copy
import json
import math
import os
import time as _time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from enum import Enum
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING

import mujoco
import numpy as np
import pinocchio as pin

from .errors import (InputError, PlannerError, RobotFileError, SolveError, UnknownNameError, check_field_types,
                     check_interrupted, as_float, enum_field, expect, is_integer, plain, real_array, shown)
from .model import MASSLESS_LINK_KG, Robot, motor_names, mujoco_failure, mujoco_spec, mujoco_warnings
from .result import (ArraysReadOnly, Trajectory, check_impacts_agree, check_same_result, clock_goes_back,
                     directory_lock, read_robot, read_summary, read_task, read_trajectory, result_dir, write_atomically)
from .task import MAX_STEPS, Task

if TYPE_CHECKING:  # (gait imports this module)
    from .gait import WalkValidation

# --- pass/fail thresholds (reported in the JSON as `thresholds`) ------------------------------------
MAX_TRACKING_ERROR_M = 0.01  # base position error over the tracking replay [m] (issue 5)
MAX_PENETRATION_M = 0.002  # depth of any contact point below the ground along the plan [m] (issue 5)

# --- information-only and detection tolerances -------------------------------------------------------
OPEN_LOOP_BAND_M = 0.05  # open loop: how long the base stays within this distance of the plan [m]
CONTACT_GAP_TOL_M = 1e-3  # a point "is in contact" when its gap is below this [m]; the plan's
#   contact gaps are at the complementarity tolerance (<< 1 mm) while a step of flight moves a foot by cm
# The trajectory's own flight dynamics (_flight_residual), relative: the planner's implicit-Euler plans and
# simulations 6e-16 to 2.3e-2 (docs/validation.md, session 45, relative to the terms' sum; to the largest term since
# session 60, up to ~2x that), controls set to zero ~1
FLIGHT_RESIDUAL_TOL = 0.1
# a plan at rest (its goal its start) moves by the solver's noise, ~1e-13 m/s: its positions' drift against its
# velocities is judged on this speed at least [m/s or rad/s] (on the fastest's 1e-12 it failed as "edited samples")
REST_SPEED = 1e-6
WINDOW_S = 0.1  # length of the windowed tracking replays [s]: the window of the re-simulation
#   defect (scripts/bench_work_precision.py), short against a hop's flight (~0.3 s)
WINDOW_STRIDE_S = 0.025  # a window starts this often [s]; on the Capler plans the window statistics
#   with 10 ms strides agree with these to ~10 % (docs/validation.md), at a quarter of the cost
MIN_FLIGHT_S = 0.01  # a MuJoCo impact is a contact onset after at least this long without contact [s];
#   shorter gaps are chatter of the soft contact, not a flight phase

_UNSUPPORTED_JOINTS = {mujoco.mjtJoint.mjJNT_FREE: "free", mujoco.mjtJoint.mjJNT_BALL: "ball"}
_BAD_STATE_WARNINGS = (mujoco.mjtWarning.mjWARN_BADQACC, mujoco.mjtWarning.mjWARN_BADQPOS,
                       mujoco.mjtWarning.mjWARN_BADQVEL)


# ==================================================================================================
# options
# ==================================================================================================

# between two samples a contact point may cut a hole's rim (the main job's plan reaches metric 0.80: 1 cm into hole 1,
# in the air above it); reaching the hole's inner half (metric < 0.25) is going through it (a plan through a 8 cm
# wide, 100 m tall hole: 6e-9)
HOLE_PASS_METRIC = 0.25
HOLE_SUBSAMPLES = 20  # points per sample interval at which the hole reach is evaluated, at least
HOLE_MAX_SUBSAMPLES = 2000  # and at most (a step's travel of 500 quarter half-axes of the narrowest hole)
# a contact point's depth below the ground between samples that is reported [m]: a resting point's is IPOPT's rounding
# (1e-17 m on the point-mass hop's stance, 1e-7 m on a simulated drop at rest), which read "0.000 mm under the ground"
BETWEEN_FLOOR_M = 1e-6
HOLE_ZOOM = 20  # beyond that, the closest sample's neighbourhood again at 20 times finer spacing, until fine enough
MIN_IMP, MAX_IMP = 1e-4, 0.9999  # MuJoCo's range of a constraint's impedance (mjMINIMP, mjMAXIMP)
# MuJoCo's timestep range for the validation [s]: a replay of T seconds takes T / timestep steps (1e-9 s: 1.5e9
# samples, out of memory), and above 10 ms the one-step penetration v * timestep is centimetres
MIN_TIMESTEP_S, MAX_TIMESTEP_S = 1e-5, 1e-2
MAX_SPHERE_M = 0.01  # [m] a contact site's collision sphere: a larger one is a body of its own (1e300 failed)


class ReplayTooLongError(InputError):
    """A replay of more than MAX_STEPS MuJoCo steps, refused before its arrays are allocated: `planner plan` then
    prints the converged plan's report with the reason (exit 1, as `planner validate` does: no input to fix)."""


@dataclass(frozen=True)
class ContactSettings:
    """MuJoCo settings that approximate rigid, inelastic impacts with Coulomb friction.

    MuJoCo contacts are soft: the solver drives each contact's acceleration towards
    a_ref = -b * v_n - k * r (r the penetration [m], v_n the normal velocity [m/s]). An inelastic
    rigid impact removes the normal velocity at once, so the default is MuJoCo's direct form
    solref = (-k, -b) with b = 1 / timestep (dead-beat: the normal velocity is gone after one step,
    and so is the tangential one while sticking) and a small k = stiffness_ratio / timestep^2, which
    pushes the one-step penetration back out at stiffness_ratio times the impact speed -- no bounce.
    The usual (timeconst, dampratio) = (2 dt, 1) bounces instead: MuJoCo detects the contact one step
    late, the stiffness term acts on the one-step penetration v*dt and relaunches the point at ~v/4
    (measured; see docs/validation.md).

    Known limitation (MuJoCo's convex contact model, not a setting): while a frictional contact
    SLIDES under a sustained tangential load, the solver trades normal against tangential residual
    and the point hops (up to 4 cm for mu = 0.8, measured). The planner's frictional contacts are
    no-slip, so a valid plan does not slide; frictionless (mu = 0) sliding is exact.

    Contacts with restitution > 0 use (timeconst, dampratio) = (elastic_timeconst_steps * timestep,
    zeta(eps)) with the damping ratio of a linear spring-damper whose exit/entry speed ratio is eps. Above
    eps ~0.73 (zeta < 1 / elastic_timeconst_steps) that spring would be stiffer than MuJoCo's step can integrate; it
    gets the direct form (-k, -b) = (-1 / timestep^2, -2 zeta / timestep) instead: the same zeta at frequency
    1 / timestep (measured exit/entry 0.79, 0.90, 1.0001 for eps = 0.8, 0.9, 1).
    """

    timestep: float = 2.5e-4  # [s]; the one-step penetration at impact is v * timestep
    cone: str = "elliptic"  # Coulomb's circular cone, not MuJoCo's default pyramid
    impratio: float = 10.0  # friction-to-normal impedance ratio: stiffer friction, less creep
    noslip_iterations: int = 0  # the dead-beat friction reference already stops creep (0.65 um in 1 s at
    #   95 % of the friction limit, measured); 10 noslip iterations changed no measured number
    stiffness_ratio: float = 0.01  # k * timestep^2; push-out speed / impact speed
    damping_steps: float = 1.0  # b = 1 / (damping_steps * timestep); 1 = dead-beat
    solimp: tuple[float, ...] = (0.999, 0.9999, 0.001, 0.5, 2.0)  # impedance near MuJoCo's max 0.9999
    elastic_timeconst_steps: float = 10.0  # contacts with restitution > 0 (see class docstring)
    sphere_radius: float = 1e-3  # [m] collision sphere put at each contact site

    def __post_init__(self):
        check_field_types(self, "contact")
        _check(MIN_TIMESTEP_S <= self.timestep <= MAX_TIMESTEP_S, "contact.timestep", self.timestep,
               f"in [{MIN_TIMESTEP_S:g}, {MAX_TIMESTEP_S:g}] s")
        _check(self.cone in ("elliptic", "pyramidal"), "contact.cone", self.cone, "'elliptic' or 'pyramidal'")
        _check(self.impratio >= 1, "contact.impratio", self.impratio, ">= 1")
        _check(self.noslip_iterations >= 0, "contact.noslip_iterations", self.noslip_iterations, ">= 0")
        _check(self.stiffness_ratio >= 0, "contact.stiffness_ratio", self.stiffness_ratio, ">= 0")
        _check(self.damping_steps >= 1, "contact.damping_steps", self.damping_steps, ">= 1 (faster is unstable)")
        d0, d1, width, mid, power = self.solimp if len(self.solimp) == 5 else (0.0,) * 5
        # MuJoCo clamps values outside these ranges without a word, so a validation would run with other settings
        _check(len(self.solimp) == 5 and MIN_IMP <= min(d0, d1) and max(d0, d1) <= MAX_IMP and width > 0 and 0 < mid < 1
               and power >= 1, "contact.solimp", self.solimp,
               f"5 numbers (dmin, dmax in [{MIN_IMP}, {MAX_IMP}], width > 0, midpoint in (0, 1), power >= 1)")
        _check(self.elastic_timeconst_steps >= 2, "contact.elastic_timeconst_steps", self.elastic_timeconst_steps, ">= 2")
        _check(0 < self.sphere_radius <= MAX_SPHERE_M, "contact.sphere_radius", self.sphere_radius,
               f"in (0, {MAX_SPHERE_M:g}] m")

    def solref(self, restitution: float = 0.0) -> tuple[float, float]:
        """MuJoCo solref of a contact with the given restitution coefficient in [0, 1]."""
        restitution = plain(restitution)  # np.float32; True was restitution 1
        _check(isinstance(restitution, (int, float)) and not isinstance(restitution, bool)
               and 0.0 <= restitution <= 1.0, "restitution", restitution, "in [0, 1]")
        if restitution <= 0.0:
            stiffness = self.stiffness_ratio / self.timestep**2  # [1/s^2]
            damping = 1.0 / (self.damping_steps * self.timestep)  # [1/s]
            return (-stiffness, -damping)
        log_eps = math.log(restitution)
        zeta = -log_eps / math.sqrt(math.pi**2 + log_eps**2)
        timeconst = self.elastic_timeconst_steps * self.timestep
        if zeta * timeconst >= self.timestep:  # MuJoCo's stiffness 1/(timeconst zeta)^2 is within 1/timestep^2
            return (timeconst, zeta)
        # stiffer, MuJoCo's step goes unstable (restitution 0.9 left at 2.8 times the impact speed), and zeta = 0 is no
        # solref format (MuJoCo's default contact replaced it): the same damping ratio at frequency 1 / timestep
        return (-1.0 / self.timestep**2, -2.0 * zeta / self.timestep)


@dataclass(frozen=True)
class TrackingGains:
    """Joint PD of the tracking replay, per actuator: tau = kp (q_ref - q) + kd (v_ref - v).

    By default each actuated joint gets a critically damped loop of `frequency_hz` on its own
    inertia: kp = M_ii w^2, kd = 2 zeta M_ii w, w = 2 pi f, M_ii the joint's diagonal entry of the
    mass matrix at the initial posture [kg m^2 or kg]. Explicit kp, kd (nu,) override it, each on its
    own (kp alone keeps the rule's kd) [N m/rad, N m s/rad for hinges; N/m, N s/m for slides].
    """

    frequency_hz: float = 20.0  # well above a hopper's stance dynamics, well below 1 / timestep
    damping_ratio: float = 1.0
    kp: tuple[float, ...] | None = None
    kd: tuple[float, ...] | None = None

    def __post_init__(self):
        check_field_types(self, "gains")
        _check(self.frequency_hz > 0, "gains.frequency_hz", self.frequency_hz, "> 0")
        _check(self.damping_ratio >= 0, "gains.damping_ratio", self.damping_ratio, ">= 0")
        for key in ("kp", "kd"):  # a negative gain pushes away from the plan
            values = getattr(self, key)
            _check(values is None or all(v >= 0 for v in values), f"gains.{key}", values, "None or gains >= 0")


class TrackingController(Enum):
    """Feedback law of the tracking replay (both add the joint PD of `TrackingGains` to the planned
    controls).

    JOINT_PD: PD on the planned q, v of the actuated joints. The unactuated coordinates (a hopper's
    base) are not fed back, so a take-off velocity error becomes a landing error.
    STANCE_RETARGET: while a contact point is in contact both in the plan and in MuJoCo, the joint
    references are recomputed from where MuJoCo has the contact points: the joint positions that put
    the unactuated coordinates on their plan with those points where they are, and the joint
    velocities that move the unactuated coordinates at their planned velocity with the points at
    rest (as they are in MuJoCo). With the foot pinned the base is a function of the joints, so the joint PD then steers the
    base. Elsewhere (flight, or plan and MuJoCo disagree on the contact) it is JOINT_PD. A fully
    actuated robot has no unactuated coordinate: both laws are the same.
    """

    JOINT_PD = "joint_pd"
    STANCE_RETARGET = "stance_retarget"


@dataclass(frozen=True)
class ValidationOptions:
    """Everything the validation can be told; the defaults are the documented settings.

    controller: a TrackingController or its value ("joint_pd", "stance_retarget"); an unknown name
    raises InputError. JOINT_PD stays the default by measurement (docs/validation.md): on the
    default Capler plan STANCE_RETARGET cuts the base error of the first 0.75 s from 106 to 35 mm but
    is worse over the first 0.35 s (5.1 vs 1.6 mm) and over the whole plan (3.4 vs 3.0 m; on session 43's default
    plan 1.0 vs 0.24 m), and on a fully actuated robot both are the same law.
    """

    contact: ContactSettings = field(default_factory=ContactSettings)
    gains: TrackingGains = field(default_factory=TrackingGains)
    controller: TrackingController = TrackingController.JOINT_PD
    max_tracking_error_m: float = MAX_TRACKING_ERROR_M
    max_penetration_m: float = MAX_PENETRATION_M
    open_loop_band_m: float = OPEN_LOOP_BAND_M
    contact_gap_tol_m: float = CONTACT_GAP_TOL_M
    min_flight_s: float = MIN_FLIGHT_S
    window_s: float = WINDOW_S
    window_stride_s: float = WINDOW_STRIDE_S

    def __post_init__(self):
        check_field_types(self)
        for key, cls in (("contact", ContactSettings), ("gains", TrackingGains)):
            _check(isinstance(getattr(self, key), cls), key, getattr(self, key), f"a {cls.__name__}")
        for key in ("max_tracking_error_m", "max_penetration_m", "open_loop_band_m", "contact_gap_tol_m"):
            _check(getattr(self, key) > 0, key, getattr(self, key), "> 0")
        _check(self.min_flight_s >= 0, "min_flight_s", self.min_flight_s, ">= 0")
        _check(self.window_s > 0, "window_s", self.window_s, "> 0")
        _check(self.window_stride_s > 0, "window_stride_s", self.window_stride_s, "> 0")
        enum_field(self, "controller", TrackingController)


# ==================================================================================================
# the MuJoCo scene
# ==================================================================================================

@dataclass(frozen=True, eq=False)
class Scene:
    """The robot file compiled by MuJoCo with the validation's contact model.

    points[i] (task contact i) is MuJoCo site `site_ids[i]`, carrying collision sphere `geom_ids[i]`.
    """

    model: mujoco.MjModel = field(repr=False)
    robot: Robot = field(repr=False)
    task: Task = field(repr=False)
    settings: ContactSettings
    points: tuple[str, ...]  # contact point names, task order
    site_ids: tuple[int, ...]
    geom_ids: tuple[int, ...]
    base_body: int  # the first moving body: its origin is "the base" of the tracking errors
    base_name: str
    # a robot whose base cannot translate (a fixed arm): its first moving body's origin moves little or not at all
    # (it was 0 mm for an arm whose tip missed by 32 mm), so the tracking errors are those of the first contact point
    base_site: int | None
    qpos_adr: np.ndarray = field(repr=False)  # (nu,) qpos index of each actuator's joint
    dof_adr: np.ndarray = field(repr=False)  # (nu,) qvel index of each actuator's joint
    gear: np.ndarray = field(repr=False)  # (nu,)
    ctrl_lower: np.ndarray = field(repr=False)  # (nu,), -inf when unlimited
    ctrl_upper: np.ndarray = field(repr=False)

    @property
    def ground_height(self) -> float:
        return self.task.ground_height

    def contact_state(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
        """Per contact point (C,): the smallest MuJoCo distance [m] (inf if none detected) and
        whether a force-carrying contact exists (penetration, dist < 0)."""
        n = len(self.points)
        dist, active = np.full(n, np.inf), np.zeros(n, dtype=bool)
        if data.ncon == 0:
            return dist, active
        point_of = self._point_of_geom
        # one contact at a time: called at every MuJoCo step, where the arrays of a whole-contact-list
        # numpy expression cost twice as much as this loop over the one or two contacts there are
        for i in range(data.ncon):
            contact = data.contact[i]
            g0, g1 = contact.geom
            c = point_of.get(g0, point_of.get(g1))  # each collision pair is (ground, one contact sphere)
            if c is None:
                continue
            dist[c] = min(dist[c], contact.dist)
            active[c] |= contact.exclude == 0
        return dist, active

    @cached_property
    def _point_of_geom(self) -> dict[int, int]:
        """Contact point index (task order) of each collision sphere's geom id."""
        return {int(g): c for c, g in enumerate(self.geom_ids)}


def _expect_inputs(robot, task, call: str) -> None:
    """InputError naming the argument when a call is given a path or a name for the Robot or the Task (load_robot,
    load_task read them), not an AttributeError from inside."""
    expect(robot, Robot, f"{call}'s robot (planner.model.load_robot)")
    expect(task, Task, f"{call}'s task (planner.task.load_task)")


def build_scene(robot: Robot, task: Task, settings: ContactSettings | None = None,
                detect_within_m: float = CONTACT_GAP_TOL_M) -> Scene:
    """Compile the robot file with MuJoCo and give it the validation's contact model.

    Edits (in memory, the file is untouched):
    - a sphere of radius `settings.sphere_radius`, mass 0 (the body's inertia is unchanged), centred
      at each task contact site, and the plane geom "ground" lowered by that radius to the task's
      ground_height: MuJoCo's contact distance is then exactly the site's height above the ground,
      the plan's gap. A missing "ground" geom is added (beside a file's ground plane of another name, e.g. a
      Menagerie "floor", which is kept, drawn, with its collisions cleared as below).
    - only explicit pairs (ground, sphere) collide: every geom's contype/conaffinity is cleared and
      the file's pairs and excludes are dropped, since the plan models contact at those points only.
    - each pair: friction mu of its task contact (condim 3; condim 1 when mu = 0), solref from
      `settings.solref(restitution)`, `settings.solimp`; margin 0 and gap `detect_within_m`, so a
      contact is reported (but carries no force) from `detect_within_m` above the ground.
    - options: timestep, cone, impratio, noslip iterations from `settings`; semi-implicit Euler.
    A URDF file is read by MuJoCo's own URDF parser and given what MJCF states and URDF does not
    (planner.model.mujoco_spec): a site at each task contact link's origin, a motor per actuated
    joint as the planner reads them, and model.MASSLESS_LINK_KG on a moving link without mass.
    Raises InputError for an unknown site (link), a free/ball joint or a tilted ground.
    """
    _expect_inputs(robot, task, "build_scene")
    expect(settings, (ContactSettings, type(None)), "build_scene's settings")
    settings = settings or ContactSettings()
    spec = mujoco_spec(robot, [c.point for c in task.contacts])
    try:
        original = spec.compile()  # a URDF's fixed links are fused into their parents here, sites and all
    except ValueError as exc:
        raise RobotFileError(mujoco_failure(robot.path, exc)) from None
    for j in range(original.njnt):
        kind = _UNSUPPORTED_JOINTS.get(mujoco.mjtJoint(original.jnt_type[j]))
        if kind is not None:
            raise InputError(f"{robot.path}: joint {original.joint(j).name!r} is a {kind} joint; MuJoCo validation supports "
                             "hinge and slide joints only (quaternion conventions differ between Pinocchio and MuJoCo)")
    if original.nq != robot.nq or original.nv != robot.nv or original.nu != robot.nu:
        raise RobotFileError(f"{robot.path}: MuJoCo has nq={original.nq}, nv={original.nv}, nu={original.nu} but the "
                             f"robot has nq={robot.nq}, nv={robot.nv}, nu={robot.nu}")
    if original.njnt == 0:
        raise InputError(f"{robot.path} has no joints: nothing moves, nothing to validate")

    tilted = [c.point for c in task.contacts if c.normal != (0.0, 0.0, 1.0)]
    if tilted:
        raise InputError(f"contact point(s) {', '.join(tilted)} touch a tilted plane (contacts.normal); the MuJoCo "
                         "validation models the ground plane only, so such a result is not validated (`planner plan "
                         "--no-validate` plans it; `planner simulate` validates nothing)")
    site_names = [original.site(i).name for i in range(original.nsite) if original.site(i).name]
    site_ids = []
    for contact in task.contacts:
        sid = mujoco.mj_name2id(original, mujoco.mjtObj.mjOBJ_SITE, contact.point)
        if sid < 0:
            raise UnknownNameError("MuJoCo site", contact.point, site_names)
        if original.site_bodyid[sid] == 0:
            raise InputError(f"contact point {contact.point!r} is a site of the world body; it cannot move")
        site_ids.append(sid)

    ground = spec.geom("ground")
    radius = settings.sphere_radius
    if ground is None:
        spec.worldbody.add_geom(name="ground", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 1],
                                pos=[0, 0, task.ground_height - radius])
    else:
        gid = mujoco.mj_name2id(original, mujoco.mjtObj.mjOBJ_GEOM, "ground")
        normal = _quat_zaxis(original.geom_quat[gid])
        if original.geom_type[gid] != mujoco.mjtGeom.mjGEOM_PLANE or original.geom_bodyid[gid] != 0 \
                or abs(normal[2] - 1.0) > 1e-9:
            raise InputError(f"{robot.path}: geom 'ground' must be a horizontal plane of the world body")
        ground.pos = [ground.pos[0], ground.pos[1], task.ground_height - radius]

    for geom in spec.geoms:
        geom.contype, geom.conaffinity = 0, 0
    for item in [*spec.pairs, *spec.excludes]:
        spec.delete(item)

    sphere_names = []
    for i, (contact, sid) in enumerate(zip(task.contacts, site_ids)):
        body = spec.site(contact.point).parent
        name = f"validate_contact_{i}_{contact.point}"
        body.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[radius, 0, 0],
                      pos=list(original.site_pos[sid]), mass=0.0, contype=0, conaffinity=0,
                      group=4, rgba=[0.9, 0.2, 0.2, 0.5])
        frictional = contact.mu > 0
        spec.add_pair(name=f"validate_pair_{i}", geomname1="ground", geomname2=name,
                      condim=3 if frictional else 1,
                      # condim 1 ignores friction; MuJoCo still wants positive values
                      friction=[contact.mu, contact.mu, 0.0, 0.0, 0.0] if frictional else [1.0, 1.0, 0.0, 0.0, 0.0],
                      solref=list(settings.solref(contact.restitution)), solimp=list(settings.solimp),
                      margin=0.0, gap=detect_within_m)
        sphere_names.append(name)

    spec.option.timestep = settings.timestep
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC if settings.cone == "elliptic" else mujoco.mjtCone.mjCONE_PYRAMIDAL
    spec.option.impratio = settings.impratio
    spec.option.noslip_iterations = settings.noslip_iterations
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_EULER
    # MuJoCo's own constraint solver settings, not the file's (PGS with one iteration moved a validation 8.8 -> 12.9 mm)
    default = mujoco.MjSpec().option
    for key in ("solver", "iterations", "ls_iterations", "tolerance", "ls_tolerance"):
        setattr(spec.option, key, getattr(default, key))
    try:
        model = spec.compile()
    except ValueError as exc:
        raise RobotFileError(f"MuJoCo cannot compile the validation model of {robot.path}: {exc}") from None
    # the spheres are massless: the dynamics must be the file's
    assert np.allclose(model.body_mass, original.body_mass) and np.allclose(model.body_inertia, original.body_inertia)

    trn = model.actuator_trnid[:, 0]
    # the first body that moves and has mass (a URDF's carriage link has only model.MASSLESS_LINK_KG)
    jointed = [int(b) for b in model.jnt_bodyid]
    base_body = next((b for b in jointed if model.body_mass[b] > MASSLESS_LINK_KG), jointed[0])
    site_ids = tuple(mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, c.point) for c in task.contacts)
    return Scene(
        model=model, robot=robot, task=task, settings=settings,
        points=tuple(c.point for c in task.contacts),
        site_ids=site_ids, base_site=None if _translates(model, base_body) or not site_ids else site_ids[0],
        geom_ids=tuple(mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, n) for n in sphere_names),
        base_body=base_body, base_name=model.body(base_body).name or f"body_{base_body}",
        qpos_adr=np.array(model.jnt_qposadr[trn], dtype=int), dof_adr=np.array(model.jnt_dofadr[trn], dtype=int),
        gear=np.array(model.actuator_gear[:, 0], dtype=float),
        # the robot's control bounds: MuJoCo's ctrlrange, forcerange and the joint's actuatorfrcrange together (the
        # ctrlrange alone missed a forcerange's saturation)
        ctrl_lower=np.array([a.lower for a in robot.actuators], dtype=float).reshape(model.nu),
        ctrl_upper=np.array([a.upper for a in robot.actuators], dtype=float).reshape(model.nu),
    )


# ==================================================================================================
# reports
# ==================================================================================================

@dataclass(frozen=True)
class Thresholds:
    """Pass/fail limits and the tolerances the metrics depend on: the first five are ValidationOptions' fields of the
    same names, the last two the module constants HOLE_PASS_METRIC and FLIGHT_RESIDUAL_TOL.

    max_tracking_error_m, max_penetration_m [m]: pass/fail limits. open_loop_band_m [m]: the open-loop replay's band
    (information only). contact_gap_tol_m [m]: a point is in contact below this gap. min_flight_s [s]: a MuJoCo
    impact follows at least this long without contact. min_hole_metric (no unit: the ellipse metric
    ((x - xc)/a)^2 + ((z - zc)/b)^2, 1 on the rim): a plan's contact points between samples must stay at or above it
    (KinematicReport.min_hole_metric). max_flight_residual (no unit: relative to the largest term): the plan's own
    flight dynamics (KinematicReport.max_flight_residual).
    """

    max_tracking_error_m: float
    max_penetration_m: float
    open_loop_band_m: float
    contact_gap_tol_m: float
    min_flight_s: float
    min_hole_metric: float = HOLE_PASS_METRIC
    max_flight_residual: float = FLIGHT_RESIDUAL_TOL


@dataclass(frozen=True)
class KinematicReport(ArraysReadOnly):
    """qpos set along the plan's samples (P of them)."""

    samples: int
    max_penetration_m: float  # max over samples and points of (ground - site height), >= 0
    worst_point: str | None
    worst_time_s: float | None
    penetration_by_point_m: dict[str, float]
    plan_contact_samples: int  # (sample, point) pairs with Pinocchio gap < tol
    mujoco_contact_samples: int  # (sample, point) pairs where MuJoCo detects a contact within tol
    contact_mismatches: int  # pairs where the two disagree
    mismatch_times_s: tuple[float, ...]  # the first few
    max_site_disagreement_m: float  # |Pinocchio - MuJoCo| height of the contact points
    # the contact points' deepest reach into the task's holes along q interpolated linearly between samples (the
    # tracking reference's path; plans only): ((x - xc)/a)^2 + ((z - zc)/b)^2, 1 on the rim; None without holes
    min_hole_metric: float | None = None
    hole_point: str | None = None
    hole_index: int | None = None
    hole_time_s: float | None = None  # where on that path [s]
    hole_at_sample: bool = False  # there at a sample itself, not between two
    # the contact points' deepest reach below the ground along the same path, at HOLE_SUBSAMPLES - 1 points between
    # two samples (information: the OCP keeps them above it at its nodes only, and MuJoCo tracks that path), 0 unless
    # deeper than BETWEEN_FLOOR_M [m]
    max_penetration_between_m: float = 0.0
    between_point: str | None = None
    between_time_s: float | None = None
    # the plan's own dynamics on its flight steps (_flight_residual): the largest |M(q+) (v+ - v)/dt + h(q+, v+) - B u|
    # of a degree of freedom, relative to the largest of its terms on those steps, or the positions' q+ = q + dt v+ on
    # every running step when larger (flight_residual_positions); None without a running step
    flight_steps: int = 0
    max_flight_residual: float | None = None
    flight_residual_dof: str | None = None
    flight_residual_time_s: float | None = None
    # or, when larger, |(q+ - q)/dt - v+| relative to the fastest |(q+ - q)/dt| + |v+| (the step's positions)
    flight_residual_positions: bool = False

    @property
    def own_dynamics(self) -> dict:
        """The own-dynamics record (OWN_DYNAMICS_KEYS), {} when the dynamics were not checked."""
        return {key: getattr(self, key) for key in OWN_DYNAMICS_KEYS} if self.max_flight_residual is not None else {}

    @property
    def contacts_agree(self) -> bool:
        return self.contact_mismatches == 0


@dataclass(frozen=True)
class ImpactMatch(ArraysReadOnly):
    """A planned impact and the nearest MuJoCo impact of the same point (None: MuJoCo has none)."""

    point: str
    planned_time_s: float
    mujoco_time_s: float | None
    difference_s: float | None  # mujoco - planned
    tap: bool = False  # below result.TAP_SHARE of the plan's largest impulse: the whole replay lists it without a match


@dataclass(frozen=True)
class RolloutReport(ArraysReadOnly):
    """A dynamic replay (tracking or open loop) over [t_0, t_end] in MuJoCo steps."""

    duration_s: float
    steps: int
    max_base_error_m: float
    final_base_error_m: float
    max_foot_error_m: dict[str, float]
    final_foot_error_m: dict[str, float]
    mujoco_impacts: tuple[tuple[str, float], ...]  # (point, time [s])
    impacts: tuple[ImpactMatch, ...]
    max_abs_impact_time_difference_s: float | None
    saturation_fraction: float  # fraction of (step, actuator) commands beyond the control range
    saturation_by_actuator: dict[str, float]
    max_dynamic_penetration_m: float  # MuJoCo's own (soft-contact) penetration, information
    time_within_band_s: float  # from t_0 until the base first leaves the open-loop band
    diverged: bool  # MuJoCo reported a bad state (NaN/huge acceleration) and reset
    wall_time_s: float


@dataclass(frozen=True)
class WindowReport(ArraysReadOnly):
    """The tracking replay restarted from the plan's state (q, v) in overlapping windows.

    Window j starts at starts_s[j] (every stride_s) and runs the same controller for window_s from
    the plan's state there, so an error made in one hop does not carry into the next:
    max_base_error_m[j] is how far MuJoCo's physics takes the base from the plan within one window,
    not how the unstable hopper's errors grow over the whole plan (information only; the pass/fail
    tracking error is the whole replay's). Overlapping windows make the statistics independent of
    where the window boundaries fall relative to the impacts.
    """

    window_s: float
    stride_s: float
    starts_s: tuple[float, ...]  # (W,) [s]
    max_base_error_m: tuple[float, ...]  # (W,) [m]
    diverged: bool
    # each planned impact against the MuJoCo impacts of the window that started stride_s to 2 stride_s before it
    # (the first window for an impact that early): the impact's time error from the plan's state, which the whole
    # replay's matching (RolloutReport.impacts) cannot give once its errors have grown over the hops before
    impacts: tuple[ImpactMatch, ...] = ()
    max_abs_impact_time_difference_s: float | None = None

    @property
    def mean_m(self) -> float:
        return float(np.mean(self.max_base_error_m)) if self.max_base_error_m else 0.0

    @property
    def median_m(self) -> float:
        return float(np.median(self.max_base_error_m)) if self.max_base_error_m else 0.0

    @property
    def p90_m(self) -> float:
        return float(np.percentile(self.max_base_error_m, 90)) if self.max_base_error_m else 0.0

    @property
    def worst_m(self) -> float:
        return max(self.max_base_error_m, default=0.0)

    @property
    def landed(self) -> int:
        """How many planned impacts MuJoCo landed in their windows (the others: none, a push-off or a stance tap)."""
        return sum(m.difference_s is not None for m in self.impacts)

    def summary(self) -> dict:
        return {"mean_m": self.mean_m, "median_m": self.median_m, "p90_m": self.p90_m, "worst_m": self.worst_m,
                "impacts_landed": self.landed}


def _impacts_text(matches: Sequence[ImpactMatch]) -> str:
    return ", ".join(f"{m.point}@{m.planned_time_s:.3f}s: " + ("tap " if m.tap and m.difference_s is not None else "")
                     + (("tap" if m.tap else "none") if m.difference_s is None else f"{m.difference_s * 1e3:+.1f} ms")
                     for m in matches) or "no planned impacts"


@dataclass(frozen=True)
class ResolvedGains:
    actuators: tuple[str, ...]
    kp: tuple[float, ...]
    kd: tuple[float, ...]
    frequency_hz: float | None
    damping_ratio: float | None


@dataclass(frozen=True)
class Validation(ArraysReadOnly):
    """Result of a MuJoCo validation. `to_json()` is the contract's `validation` object.

    max_tracking_error_m / final_tracking_error_m: the base position error [m] of the tracking
    replay (of the first contact point when the base does not translate: `tracked` says
    which); max_penetration_m: the kinematic penetration [m]. `passed` when `failures` (one line per failed check)
    is empty: MuJoCo did not diverge in the tracking replay, the tracking error and the penetration are within the
    thresholds, no contact point goes through a hole (plans), every planned impact's point is on the ground, the
    trajectory's own flight dynamics hold (implicit-Euler samples) and, for validate(DIR), the result converged.
    """

    passed: bool
    mode: str
    max_tracking_error_m: float
    final_tracking_error_m: float
    max_penetration_m: float
    thresholds: Thresholds
    kinematic: KinematicReport
    tracking: RolloutReport
    open_loop: RolloutReport
    contact_settings: ContactSettings
    gains: ResolvedGains
    failures: tuple[str, ...]
    robot: str
    controller: TrackingController = TrackingController.JOINT_PD
    windows: WindowReport | None = None
    mujoco_version: str = mujoco.__version__
    tracked: str = "base"  # what the tracking errors measure: the base, or a fixed-base robot's first contact point

    def to_json(self) -> dict:
        out = {
            "passed": self.passed,
            "mode": self.mode,
            "max_tracking_error_m": self.max_tracking_error_m,
            "final_tracking_error_m": self.final_tracking_error_m,
            "max_penetration_m": self.max_penetration_m,
            "thresholds": asdict(self.thresholds),
            "failures": list(self.failures),
            "kinematic": {**asdict(self.kinematic), "contacts_agree": self.kinematic.contacts_agree},
            "tracking": asdict(self.tracking),
            "open_loop": asdict(self.open_loop),
            "contact_settings": {**asdict(self.contact_settings),
                                 "solref_inelastic": list(self.contact_settings.solref(0.0))},
            "gains": asdict(self.gains),
            "controller": self.controller.value,
            "windows": None if self.windows is None else {
                **asdict(self.windows), **self.windows.summary()},
            "robot": self.robot,
            "mujoco_version": self.mujoco_version,
            "tracked": self.tracked,
        }
        return _jsonable(out)

    def report(self) -> str:
        """A few human-readable lines for the command line."""
        k, tr, ol, th = self.kinematic, self.tracking, self.open_loop, self.thresholds
        where = "at a sample" if k.hole_at_sample else "between samples"
        lines = [
            f"MuJoCo validation of {self.robot}: {'PASSED' if self.passed else 'FAILED'}",
            f"  kinematic: max penetration {k.max_penetration_m * 1e3:.3f} mm (limit {th.max_penetration_m * 1e3:.1f} mm); "
            f"contacts agree on {k.samples * len(k.penetration_by_point_m) - k.contact_mismatches}/"
            f"{k.samples * len(k.penetration_by_point_m)} samples"
            + ("" if k.min_hole_metric is None else f"; deepest into a hole {where}: ellipse metric "
               f"{metric_text(k.min_hole_metric, '.2f')} (fails below {HOLE_PASS_METRIC}, rim 1), {k.hole_point} in "
               f"holes[{k.hole_index}]"
               if k.min_hole_metric < 1.0 else  # outside every hole: "deepest into" and "in" read as an entry
               f"; closest to a hole {where}: ellipse metric {metric_text(k.min_hole_metric, '.2f')} "
               "(outside: rim 1), "
               f"{k.hole_point} by holes[{k.hole_index}]")
            + ("" if k.between_point is None else "; between samples (q linear) "
               f"{k.max_penetration_between_m * 1e3:.3f} mm under the ground, {k.between_point} at "
               f"t = {k.between_time_s:.4g} s (information)")
            + own_dynamics_text(k.own_dynamics, th.max_flight_residual),
            f"  tracking ({self.controller.value}): {self.tracked} error max {tr.max_base_error_m * 1e3:.2f} mm, final {tr.final_base_error_m * 1e3:.2f} mm "
            f"(limit {th.max_tracking_error_m * 1e3:.1f} mm); "
            + ("feet max " + ", ".join(f"{p} {e * 1e3:.2f} mm" for p, e in tr.max_foot_error_m.items()) + "; "
               if tr.max_foot_error_m else "")  # a task without contact points has no feet
            + f"saturation {tr.saturation_fraction:.1%}",
            f"  impacts (MuJoCo - plan): {_impacts_text(tr.impacts)}",
        ]
        if self.windows is not None:
            w = self.windows
            # a window longer than the plan is clipped to it
            span = (f"{len(w.starts_s)} windows of {w.window_s:g} s" if w.window_s < ol.duration_s else
                    f"1 window, the whole {ol.duration_s:.3g} s plan (window {w.window_s:g} s),")
            lines.append(f"  tracking in {span} from the plan: {self.tracked} error "
                         f"mean {w.mean_m * 1e3:.2f} mm, median {w.median_m * 1e3:.2f} mm, worst {w.worst_m * 1e3:.2f} mm")
            if w.impacts:
                start = ("in the window (MuJoCo - plan, from the plan's start)" if len(w.starts_s) == 1 else
                         f"in the windows (MuJoCo - plan, from the plan's state {w.stride_s * 1e3:g}-"
                         f"{2 * w.stride_s * 1e3:g} ms before)")
                lines.append(f"  impacts {start}: {_impacts_text(w.impacts)}")
        lines += [
            f"  open loop: {self.tracked} within {th.open_loop_band_m * 1e2:.0f} cm for {ol.time_within_band_s:.3f} of {ol.duration_s:.3f} s",
        ]
        lines += [f"  failed: {f}" for f in self.failures]
        return "\n".join(lines)


# ==================================================================================================
# entry points
# ==================================================================================================

def validate(out_dir: str | Path, options: ValidationOptions | None = None) -> Validation | WalkValidation:
    """Validate the plan in result directory `out_dir` (trajectory.npz + summary.json): a Validation,
    or for a periodic plan (task plan.periodic) a planner.gait.WalkValidation: its step walked
    gait.WALK_VALIDATION_STEPS times with the phase-indexed controller (`options` do not apply).

    The robot is the file named in summary.json (a relative path is tried from the working directory,
    then from `out_dir`), the task the one the plan solved (result.read_task: trajectory.npz's copy, else
    the file summary.json names). Missing or garbled files raise InputError.
    """
    expect(out_dir, (str, os.PathLike), "validate's out_dir")
    expect(options, (ValidationOptions, type(None)), "validate's options")
    out_dir = result_dir(out_dir)
    summary = read_summary(out_dir, require=("robot",))  # the task: trajectory.npz's copy, else summary.json's path
    if summary.get("command") == "gait":
        # its samples relabel the legs at every impact (q jumps), which no tracking replay follows
        raise InputError(f"{out_dir} is a result of `planner gait`, which validates its walk in MuJoCo itself (summary.json's "
                         "\"walking\"; `planner gait` without --no-validate); `planner validate` replays plans and simulations")
    robot = read_robot(out_dir, summary)
    traj = read_trajectory(out_dir, required=REQUIRED_ARRAYS)
    check_same_result(out_dir, summary, traj)
    task = read_task(out_dir, traj, summary)
    if summary.get("command") not in ("plan", "simulate"):  # (the hole and own-dynamics checks were skipped unsaid)
        raise InputError(f"{out_dir}/summary.json: command {shown(summary.get('command'))} is none of 'plan', "
                         "'simulate' (was the file edited?)")
    t = traj["t"]
    back = (clock_goes_back(t) if summary.get("converged") is False and t.ndim == 1 and t.dtype.kind in "fiu"
            and np.all(np.isfinite(t)) else "")
    if back:  # (refused as the input's "t must be non-decreasing", exit 2, though README offers to replay it)
        raise SolveError(f"{out_dir} holds a failed solve's last iterate whose clock runs backwards ({back}): no "
                         "motion MuJoCo can replay; its failure is in summary.json's message")
    if task.is_periodic and summary.get("command") == "plan":
        validation = _walk(robot, task, traj, options, _stepped_by_implicit_euler(summary, out_dir))
    else:
        contacts, taps = _impact_points(summary, task, check_trajectory(robot, traj)["impact_times"], out_dir)
        validation = validate_trajectory(robot, task, traj, options, impact_points=contacts, impact_taps=taps,
                                         holes=summary.get("command") == "plan",  # a simulation has no holes
                                         dynamics=_stepped_by_implicit_euler(summary, out_dir))
    if summary.get("converged") is not True:  # a replay of the last iterate tracked is no verdict on a motion
        said = "" if summary.get("converged") is False else f"; its converged is {shown(summary.get('converged'))}"
        return replace(validation, passed=False, failures=validation.failures + (  # ("yes", or none, passed)
            f"the {'simulation' if summary.get('command') == 'simulate' else 'plan'} did not converge (summary.json"
            f"{said}): MuJoCo replayed its last iterate",))
    return validation


def _walk(robot: Robot, task: Task, arrays: Mapping[str, np.ndarray], options: ValidationOptions | None,
          dynamics: bool):
    """A periodic plan's validation: its step walked in MuJoCo (planner.gait.validate_walk), with its own dynamics
    checked when dynamics (implicit-Euler samples)."""
    from .gait import validate_walk

    if options is not None:  # (--window was accepted and did nothing)
        raise InputError("a periodic plan is validated by walking its step in MuJoCo, with no tracking replay: "
                         "ValidationOptions (--controller, --window) do not apply; give none")
    return validate_walk(robot, task, check_trajectory(robot, arrays), dynamics=dynamics)


def _stepped_by_implicit_euler(summary: dict, out_dir) -> bool:
    """Whether a result's samples are the planner's implicit-Euler steps (a plan of that discretization, a `planner
    simulate` run without FESD): what the flight-dynamics check judges. A MuJoCo recording (semi-implicit substeps)
    and FESD's Radau stages meet that step's relation only to O(dt): a Capler drop swinging its legs recorded every
    2 ms broke it by 0.9 of its terms, an FESD simulation of it (2 stages) by 0.24. InputError for a summary.json
    that names an unknown discretization or strategy (an edited one skipped the check unsaid)."""
    from .discretization import Discretization
    from .simulate import Strategy

    if summary.get("command") == "plan":
        options = summary.get("options")
        problem = options.get("problem") if isinstance(options, dict) else None
        key, valid = "options.problem.discretization", [d.value for d in Discretization]
        value = problem.get("discretization") if isinstance(problem, dict) else None
    else:  # (FESD's discretization is named beside the strategy)
        key, value, valid = "strategy", summary.get("strategy"), [s.value for s in Strategy]
    if value is None:  # written by other code in the results' format (a MuJoCo recording): not the planner's steps
        return False
    if value not in valid:
        raise InputError(f"{out_dir}/summary.json: {key} {shown(value)} is none of {valid} (was the file edited?)")
    return value == Discretization.IMPLICIT_EULER.value or (key == "strategy" and "discretization" not in summary)


def validate_plan(robot: Robot, task: Task, trajectory: Trajectory, options: ValidationOptions | None = None,
                  dynamics: bool = False):
    """validate_trajectory of a solved plan's Trajectory, in memory: its physical-time samples, and its impacts'
    contact points and taps as `validate(DIR)` reads them from summary.json. dynamics: the trajectory is the planner's
    implicit-Euler steps, so its own flight dynamics are checked (validate(DIR) reads that from summary.json). A
    periodic plan (task plan.periodic) is walked as `validate(DIR)` walks it: a planner.gait.WalkValidation."""
    _expect_inputs(robot, task, "validate_plan")
    expect(trajectory, Trajectory, "validate_plan's trajectory (PlanResult.trajectory; arrays: validate_trajectory)")
    expect(options, (ValidationOptions, type(None)), "validate_plan's options")
    expect(dynamics, bool, "validate_plan's dynamics")
    arrays = {"t": trajectory.t, "q": trajectory.q, "v": trajectory.v, "u": trajectory.u, "impact_times": trajectory.impact_times}
    if task.is_periodic:  # (it was tracked, and failed where validate passed)
        return _walk(robot, task, arrays, options, dynamics)
    return validate_trajectory(robot, task, arrays, options, impact_points=[imp.contact for imp in trajectory.impacts],
                               impact_taps=trajectory.taps, dynamics=dynamics)


def validate_trajectory(robot: Robot, task: Task, traj: Mapping[str, np.ndarray],
                        options: ValidationOptions | None = None,
                        impact_points: Sequence[str | None] | None = None,
                        impact_taps: Sequence[bool] | None = None, holes: bool = True,
                        dynamics: bool = False) -> Validation:
    """Replay a physical-time trajectory (contract arrays t, q, v, u, impact_times) in MuJoCo.

    holes: check that the contact points stay out of task.plan's holes between the samples (a plan's trajectory;
    `planner simulate` does not model holes).
    dynamics: check the samples' own flight dynamics (_flight_residual): for samples of the planner's implicit-Euler
    steps only (validate(DIR) sets it for those results); other sources meet the step's relation only to O(dt).
    impact_points (I,): the contact point of each planned impact; None (or a None entry) means the
    point whose gap is smallest at the impact time. impact_taps (I,): which planned impacts are taps
    (Trajectory.taps), listed but not matched against the whole replay's MuJoCo impacts (the windows match them
    too); None: none.
    """
    _expect_inputs(robot, task, "validate_trajectory")
    expect(options, (ValidationOptions, type(None)), "validate_trajectory's options")
    for flag, name in ((holes, "holes"), (dynamics, "dynamics")):
        expect(flag, bool, f"validate_trajectory's {name}")
    options = options or ValidationOptions()
    scene = build_scene(robot, task, options.contact, detect_within_m=options.contact_gap_tol_m)
    task.check_against(robot)
    arrays = check_trajectory(robot, traj)
    t, q = arrays["t"], arrays["q"]
    n_impacts = len(np.atleast_1d(arrays["impact_times"]))
    for name, values in (("impact_points", impact_points), ("impact_taps", impact_taps)):
        if values is not None and len(values) != n_impacts:
            raise InputError(f"validate_trajectory's {name} has {len(values)} entries; the trajectory has {n_impacts} impacts")
    for point in impact_points or ():
        if point is not None and point not in scene.points:  # it stood for the lowest point, silently
            raise UnknownNameError("contact point", point, scene.points)

    duration, dt = float(t[-1] - t[0]), scene.settings.timestep
    if duration > MAX_STEPS * dt:  # tau_f = 1e6 s: 4e9 steps asked numpy for 30 GiB ("out of memory" after the solve)
        raise ReplayTooLongError(f"a replay of the trajectory's {duration:.6g} s of physical time would take "
                                 f"{duration / dt:.3g} MuJoCo steps of {dt} s, more than {MAX_STEPS}: MuJoCo "
                                 f"validates at most {MAX_STEPS * dt:.6g} s")
    reference = _Reference(arrays, dt)
    samples = _window_samples(reference, options)  # (a window too short was refused after the first two replays)
    kinematic = _kinematic(scene, robot, t, q, options.contact_gap_tol_m, task if holes else None,
                           arrays if dynamics else None)
    planned = _planned_impacts(scene, arrays, impact_points, impact_taps)
    gains = resolve_gains(scene, options.gains, reference.q[0])
    tracking = _replay(scene, reference, gains, planned, options, options.controller)
    windows = _windows(scene, reference, gains, options, samples, planned)
    open_loop = _replay(scene, reference, None, planned, options)

    failures = []
    if tracking.diverged:
        failures.append("MuJoCo diverged during the tracking replay")
    tracked = "base" if scene.base_site is None else f"contact point {scene.points[0]!r}"
    if not tracking.max_base_error_m <= options.max_tracking_error_m:
        failures.append(f"{tracked} tracking error {tracking.max_base_error_m:.4g} m > {options.max_tracking_error_m} m"
                        + ("" if scene.base_site is None else " (the base does not translate: its first contact point is tracked)"))
    if not kinematic.max_penetration_m <= options.max_penetration_m:
        failures.append(f"penetration {kinematic.max_penetration_m:.4g} m of {kinematic.worst_point!r} at "
                        f"t = {kinematic.worst_time_s:.4g} s > {options.max_penetration_m} m")
    if (through := hole_failure(kinematic)) is not None:
        failures.append(through)
    failures += _impacts_off_ground(robot, scene, arrays, planned, options.contact_gap_tol_m)
    if (own := dynamics_failure(kinematic)) is not None:
        failures.append(own)
    return Validation(
        passed=not failures, mode="tracking",
        max_tracking_error_m=tracking.max_base_error_m, final_tracking_error_m=tracking.final_base_error_m,
        max_penetration_m=kinematic.max_penetration_m,
        thresholds=Thresholds(options.max_tracking_error_m, options.max_penetration_m, options.open_loop_band_m,
                              options.contact_gap_tol_m, options.min_flight_s),
        kinematic=kinematic, tracking=tracking, open_loop=open_loop, contact_settings=scene.settings,
        gains=gains, failures=tuple(failures), robot=str(robot.path), controller=options.controller,
        windows=windows, tracked=tracked,
    )


_UNCHECKED = object()


def write_validation(out_dir: str | Path, validation, result_id=_UNCHECKED) -> Path:
    """Store `validation.to_json()` (a Validation, or a periodic plan's planner.gait.WalkValidation) as the
    `validation` object of out_dir/summary.json (dropping a `validation_not_run` reason stored earlier).

    Written to a temporary file and renamed, so a reader never sees half a summary. result_id: the summary's
    `result_id` (None for a result written without one) when the validation started; if another run has written
    out_dir since, the verdict is of the earlier result and is not stored (PlannerError). Not given: not checked.
    """
    from .gait import WalkValidation  # (gait imports this module)

    expect(validation, (Validation, WalkValidation), "write_validation's validation")
    return _store_in_summary(Path(out_dir), "validation", validation.to_json(), result_id)


def write_validation_not_run(out_dir: str | Path, why: str, result_id=_UNCHECKED) -> Path:
    """Store `why` MuJoCo could not validate out_dir's converged plan (its replay too long, or out of memory) as the
    `validation_not_run` string of out_dir/summary.json, as write_validation stores a verdict (atomically, and not
    when another run has written out_dir since result_id): without it the summary read as a --no-validate plan's."""
    expect(why, str, "write_validation_not_run's why")
    return _store_in_summary(Path(out_dir), "validation_not_run", why, result_id)


def _store_in_summary(out_dir: Path, key: str, value, result_id) -> Path:
    """out_dir/summary.json with `key` ("validation" or "validation_not_run", which replaces the other) set to
    `value`, renamed into place under the directory's lock; its path."""
    path = out_dir / "summary.json"
    with directory_lock(out_dir):  # no other result may land between the read and the write
        summary = read_summary(out_dir, require=())
        if result_id is not _UNCHECKED and summary.get("result_id") != result_id:
            # (the machine's race, not the user's input: exit 1; a plan's own result is no longer anywhere)
            what = "the verdict" if key == "validation" else "why it was not validated"
            raise PlannerError(f"{out_dir} was written by another run while it was validated: {what}, of the "
                               "result that run replaced, is not stored; `planner validate DIR` judges the one there "
                               "now")
        for stale in ("validation", "validation_not_run"):
            summary.pop(stale, None)
        summary[key] = value
        write_atomically(path, json.dumps(summary, indent=2) + "\n", follow_links=False)
    return path


# ==================================================================================================
# reading and checking the result files
# ==================================================================================================

REQUIRED_ARRAYS = ("t", "q", "v", "u", "impact_times")


def check_trajectory(robot: Robot, traj: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Float copies of the contract arrays after checking names, shapes, finiteness and time order."""
    missing = [k for k in REQUIRED_ARRAYS if k not in traj]
    if missing:
        raise InputError(f"trajectory lacks array(s) {', '.join(missing)}; it needs {', '.join(REQUIRED_ARRAYS)}")
    out = {}
    for key in REQUIRED_ARRAYS:
        out[key] = real_array(traj[key], f"trajectory array {key!r}")
    t = out["t"]
    if t.ndim == 1 and t.size == 1:  # (a simulation that failed its first step: said as an array's shape)
        raise InputError("the trajectory holds one sample (its run stopped at its first step): there is no motion to "
                         "replay")
    if t.ndim != 1 or t.size < 2:
        raise InputError(f"trajectory 't' must have shape (P,) with P >= 2, got {t.shape}")
    P = t.size
    for key, n in (("q", robot.nq), ("v", robot.nv), ("u", robot.nu)):
        if n == 0 and out[key].size == 0:
            out[key] = np.zeros((P, 0))
        if out[key].shape != (P, n):
            raise InputError(f"trajectory {key!r} has shape {out[key].shape}; robot {robot.name!r} needs ({P}, {n})")
    out["impact_times"] = np.atleast_1d(out["impact_times"])
    if out["impact_times"].ndim != 1:
        raise InputError(f"trajectory 'impact_times' must have shape (I,), got {out['impact_times'].shape}")
    for key, arr in out.items():
        if not np.all(np.isfinite(arr)):
            raise InputError(f"trajectory {key!r} holds NaN or inf")
    if np.any(np.diff(t) < 0):
        raise InputError("trajectory 't' must be non-decreasing (an impact repeats a time, never goes back)")
    if t[-1] <= t[0]:
        raise InputError(f"trajectory spans no physical time (t from {t[0]} to {t[-1]})")
    slack = 1e-9 * max(1.0, abs(t[0]), abs(t[-1]))  # rounding of an impact at either end
    outside = out["impact_times"][(out["impact_times"] < t[0] - slack) | (out["impact_times"] > t[-1] + slack)]
    if outside.size:  # impact times shifted by 100 s were matched against nothing and passed
        raise InputError(f"trajectory impact time {outside[0]:g} s lies outside its samples' span "
                         f"[{t[0]:g}, {t[-1]:g}] s")
    return out


def _impact_points(summary: dict, task: Task, impact_times: np.ndarray,
                   out_dir: Path) -> tuple[list[str | None] | None, list[bool] | None]:
    """The point of each planned impact and whether it is a tap, from summary['impacts'] when it matches
    impact_times (I,) [s] (a summary written before taps were marked has none). InputError when their times differ:
    the two files no longer say the same (impact_times moved by 0.1 s validated against the moved times)."""
    impacts = summary.get("impacts")
    if not isinstance(impacts, list):
        return None, None
    check_impacts_agree(out_dir, impacts, impact_times)
    names = [c.point for c in task.contacts]
    points: list[str | None] = []
    taps = [isinstance(item, dict) and item.get("tap") is True for item in impacts]
    for item in impacts:
        contact = item.get("contact") if isinstance(item, dict) else None
        if isinstance(contact, str) and contact in names:
            points.append(contact)
        elif isinstance(contact, int) and not isinstance(contact, bool) and 0 <= contact < len(names):
            points.append(names[contact])
        else:
            points.append(None)
    return points, taps


# ==================================================================================================
# the three replays
# ==================================================================================================

def _kinematic(scene: Scene, robot: Robot, t: np.ndarray, q: np.ndarray, tol: float, task: Task | None = None,
               dynamics: Mapping[str, np.ndarray] | None = None) -> KinematicReport:
    """Set qpos at every sample: penetration (MuJoCo's kinematics) and contact agreement, where the
    plan's contact is Pinocchio's gap < tol and MuJoCo's is its collision detection within tol; with the task's
    holes, how deep its contact points reach into them between the samples (_hole_reach); with the trajectory's
    arrays as `dynamics`, its own flight dynamics on the samples without a contact (_flight_residual)."""
    model, data = scene.model, mujoco.MjData(scene.model)
    pdata = robot.model.createData()
    frames = [robot.frame_id(p) for p in scene.points]
    C = len(scene.points)
    height_mj, height_pin = np.zeros((t.size, C)), np.zeros((t.size, C))
    detected = np.zeros((t.size, C), dtype=bool)
    for i in range(t.size):
        data.qpos[:] = q[i]
        mujoco.mj_fwdPosition(model, data)  # kinematics + collision detection
        height_mj[i] = data.site_xpos[list(scene.site_ids), 2]
        detected[i] = scene.contact_state(data)[0] < tol
        pin.framesForwardKinematics(robot.model, pdata, q[i])
        height_pin[i] = [pdata.oMf[f].translation[2] for f in frames]
    depth = np.maximum(scene.ground_height - height_mj, 0.0)
    planned = (height_pin - scene.ground_height) < tol
    mismatch = planned != detected
    worst = np.unravel_index(int(np.argmax(depth)), depth.shape) if depth.size else None
    max_depth = float(depth.max()) if depth.size else 0.0
    return KinematicReport(
        samples=int(t.size), max_penetration_m=max_depth,
        worst_point=scene.points[worst[1]] if worst is not None and max_depth > 0 else None,
        worst_time_s=float(t[worst[0]]) if worst is not None and max_depth > 0 else None,
        penetration_by_point_m={p: float(depth[:, c].max()) for c, p in enumerate(scene.points)},
        plan_contact_samples=int(planned.sum()), mujoco_contact_samples=int(detected.sum()),
        contact_mismatches=int(mismatch.sum()),
        mismatch_times_s=tuple(float(x) for x in t[np.nonzero(mismatch.any(axis=1))[0][:10]]),
        max_site_disagreement_m=float(np.abs(height_mj - height_pin).max()) if C else 0.0,
        **_hole_reach(robot, task, t, q),
        **_ground_between(robot, scene, t, q),
        **({} if dynamics is None else _flight_residual(robot, dynamics, ~planned.any(axis=1))),
    )


def _flight_residual(robot: Robot, arrays: Mapping[str, np.ndarray], airborne: np.ndarray) -> dict:
    """The trajectory's own equations of motion on its flight steps: between two samples i, i+1 at which no contact
    point is in contact (airborne (P,), _kinematic's), with no impact between, the planner's implicit-Euler step has
    M(q+) (v+ - v) / dt + h(q+, v+) = B u+ (u+ the control held over the step). Its largest violation per degree of
    freedom, relative to the largest of those terms there over the flight steps: 6e-16 to 2.3e-2 for the planner's plans
    and simulations (measured against the terms' sum until session 60: up to ~2x that now), ~1 for controls that do
    not move the robot as its samples do (for other sources of samples see _stepped_by_implicit_euler). And on every
    running step (no impact in it, stance too) the positions' q+ = q + dt v+, relative to the coordinate's largest
    speed (floored at 1e-3 of the fastest's and at REST_SPEED). KinematicReport's flight fields (the larger of the
    two; flight_steps 0 and the positions' alone without a flight step); empty without a running step."""
    t, q, v, u = arrays["t"], arrays["q"], arrays["v"], arrays["u"]
    impacts = np.atleast_1d(arrays["impact_times"])
    model, data = robot.model, robot.model.createData()
    running = [i for i in range(t.size - 1) if t[i + 1] > t[i] and not np.any((impacts > t[i]) & (impacts <= t[i + 1]))]
    steps = [i for i in running if airborne[i] and airborne[i + 1]]
    if not running:
        return {}
    # the samples' positions against their velocities on every running step, stance too (q+ = q + dt v+ holds there
    # as well: a flight raised 5 cm passed, its jumps at the take-off and the landing being no flight steps)
    drift, speed = np.zeros((len(running), robot.nv)), np.zeros(robot.nv)  # [m/s, rad/s]
    for n, i in enumerate(running):
        chord = pin.difference(model, q[i], q[i + 1]) / (t[i + 1] - t[i])
        drift[n] = chord - v[i + 1]
        speed = np.maximum.reduce([speed, np.abs(chord), np.abs(v[i + 1])])
    B = robot.actuation_matrix
    residual, scale, momentum = np.zeros((len(steps), robot.nv)), np.zeros(robot.nv), 0.0
    for n, i in enumerate(steps):
        M = pin.crba(model, data, q[i + 1])
        M = np.triu(M) + np.triu(M, 1).T  # (Pinocchio fills the upper triangle)
        inertial = M @ (v[i + 1] - v[i]) / (t[i + 1] - t[i])
        momentum = max(momentum, float(np.abs(M @ v[i + 1]).max()) / (t[i + 1] - t[i]))
        bias = pin.rnea(model, data, q[i + 1], v[i + 1], np.zeros(robot.nv))
        control = B @ u[i + 1]
        residual[n] = inertial + bias - control
        # the largest term, as documented (their sum, ~2x it in flight, let controls 18 % off pass at 0.083)
        scale = np.maximum.reduce([scale, np.abs(inertial), np.abs(bias), np.abs(control)])
    # a coordinate on which nothing acts in flight: its terms are rounding, judged on the others' scale, the robot's
    # weight (an arm hanging at rest has only rounding, ~1e-16, in every term) or, without gravity, the momentum a
    # step carries (a coasting mass in a zero-gravity file has rounding in every term, and had failed at ratio 1)
    weight = pin.computeTotalMass(model) * np.linalg.norm(model.gravity.linear)
    relative = np.abs(residual) / np.maximum(scale, 1e-6 * max(scale.max(), weight, momentum, 1e-12))
    # the samples' positions against their velocities (v zeroed, or z raised 5 cm over a flight, passed: the momentum
    # equation reads v and u only); a coordinate at rest is judged on the fastest one's speed, which the solver's
    # tolerance (~1e-8 m per step) cannot reach at 1e-3 of it
    moved = np.abs(drift) / np.maximum(speed, max(1e-3 * speed.max(), REST_SPEED))
    n, j = np.unravel_index(int(np.argmax(relative)), relative.shape) if steps else (0, 0)
    nq_, jq = np.unravel_index(int(np.argmax(moved)), moved.shape)
    positions = not steps or bool(moved[nq_, jq] > relative[n, j])
    i, j = (running[nq_], jq) if positions else (steps[n], j)
    return {"flight_steps": len(steps), "max_flight_residual": float((moved if positions else relative).max()),
            "flight_residual_dof": robot.dof_names[j], "flight_residual_time_s": float(t[i + 1]),
            "flight_residual_positions": positions}


OWN_DYNAMICS_KEYS = ("flight_steps", "max_flight_residual", "flight_residual_dof", "flight_residual_time_s",
                     "flight_residual_positions")  # KinematicReport's record of _flight_residual


def own_dynamics_text(record: Mapping, limit: float = FLIGHT_RESIDUAL_TOL) -> str:
    """The report's "; own dynamics ..." clause of a record of OWN_DYNAMICS_KEYS, "" without a residual."""
    if record.get("max_flight_residual") is None:
        return ""
    where = ("; own dynamics (positions, over every running step)" if record["flight_residual_positions"]
             else f"; own dynamics over {record['flight_steps']} flight steps")
    return f"{where} to {record['max_flight_residual']:.1e} (limit {limit})"


def dynamics_failure(kinematic: KinematicReport, tracked: bool = True) -> str | None:
    """The failure line of a trajectory whose own dynamics (_flight_residual) break FLIGHT_RESIDUAL_TOL, else None.
    tracked: the validation replays it with a tracking controller (a walk does not)."""
    k = kinematic
    if k.max_flight_residual is None or k.max_flight_residual <= FLIGHT_RESIDUAL_TOL:
        return None
    where = f"in {k.flight_residual_dof!r} at t = {k.flight_residual_time_s:.4g} s > {FLIGHT_RESIDUAL_TOL}"
    if k.flight_residual_positions:
        return (f"the trajectory's own dynamics: its positions do not move at its velocities ((q+ - q) / dt - v+ is "
                f"{k.max_flight_residual:.3g} of its speed {where}): its samples are not consecutive implicit-Euler "
                "steps (one edited or missing; a plan's own: please report it)")
    return (f"the trajectory's own dynamics: in flight its controls do not give its motion (M a + h - B u is "
            f"{k.max_flight_residual:.3g} of its terms {where})"
            + ("; the tracking replay's feedback can hide that on a robot whose every coordinate has a motor"
               if tracked else ""))


def _impacts_off_ground(robot: Robot, scene: Scene, arrays: Mapping[str, np.ndarray],
                        planned: Sequence[tuple[str, float, bool]], tol: float) -> list[str]:
    """A failure line per planned impact (_planned_impacts' (point, time [s], tap): an unnamed point is the lowest)
    whose contact point is more than tol [m] above the ground at its samples (between two: at both): no contact could
    give that impulse (an impact moved to a flight's apex, 6.5 cm up, passed, and hid the flight step it sat in from
    the dynamics check). The planner's impacts sit on the ground to ~4e-11 m."""
    t, q = arrays["t"], arrays["q"]
    data = robot.model.createData()
    out = []
    for point, time, _ in planned:
        if point not in scene.points:  # ("?": a scene without contact points)
            continue
        heights = []
        at = np.flatnonzero(np.abs(t - time) <= 1e-9 * max(1.0, abs(time)))
        # (an impact between two samples: the lower of them; its step is no running step of the dynamics check)
        around = np.clip([np.searchsorted(t, time) - 1, np.searchsorted(t, time)], 0, t.size - 1)
        for i in at if at.size else np.unique(around):
            pin.framesForwardKinematics(robot.model, data, q[i])
            heights.append(data.oMf[robot.frame_id(point)].translation[2] - scene.ground_height)
        if heights and min(heights) > tol:
            out.append(f"the impact at t = {time:.4g} s is listed with contact point {point!r} {min(heights):.3g} m "
                       f"above the ground (> {tol} m): no contact there")
    return out


def _ground_between(robot: Robot, scene: Scene, t: np.ndarray, q: np.ndarray) -> dict:
    """The contact points' deepest reach below the ground along q linear between the samples t (P,), q (P, nq), at
    HOLE_SUBSAMPLES - 1 points between two samples (an impact's repeated time is no step): a leg swinging through a
    landing can dip its foot under the ground between two nodes that are above it (N = 40 Capler: 135 mm).
    KinematicReport's max_penetration_between_m, between_point and between_time_s; empty when no point goes deeper
    than BETWEEN_FLOOR_M."""
    data = robot.model.createData()
    frames = [robot.frame_id(p) for p in scene.points]
    worst = (BETWEEN_FLOOR_M, None, None)
    for i in np.nonzero(np.diff(t) > 0)[0]:
        for s in np.linspace(0.0, 1.0, HOLE_SUBSAMPLES + 1)[1:-1]:
            pin.framesForwardKinematics(robot.model, data, (1.0 - s) * q[i] + s * q[i + 1])
            depth = [scene.ground_height - data.oMf[f].translation[2] for f in frames]
            c = int(np.argmax(depth)) if depth else 0
            if depth and depth[c] > worst[0]:
                worst = (float(depth[c]), scene.points[c], float(t[i] + s * (t[i + 1] - t[i])))
    keys = ("max_penetration_between_m", "between_point", "between_time_s")
    return dict(zip(keys, worst)) if worst[1] else {}


def _hole_reach(robot: Robot, task: Task | None, t: np.ndarray, q: np.ndarray) -> dict:
    """The smallest ellipse metric a contact point reaches in a hole of task.plan along q linear between the
    samples t (P,), q (P, nq), from the second sample on (the OCP's hole rows start at node 1, and a point starting in
    a hole may leave it in the first step): the OCP keeps the points out of the holes at its nodes only, so a hole
    narrower than a step's travel can be crossed between two (a plan went through an 8 cm wide, 100 m tall one).
    Each step is evaluated at HOLE_SUBSAMPLES points, more where the points travel farther than a quarter of the
    narrowest hole's half-axis (up to HOLE_MAX_SUBSAMPLES; beyond, each point's closest sample to each hole its path
    comes near is searched HOLE_ZOOM times finer until it is). KinematicReport's hole fields; empty without holes."""
    holes = task.plan.holes if task is not None and task.plan is not None else ()
    points = list(dict.fromkeys(c.point for c in task.contacts)) if holes else []  # touches = false too, as in the OCP
    if not points:
        return {}
    data = robot.model.createData()
    frames = [robot.frame_id(p) for p in points]
    finest = min(min(e.a, e.b) for e in holes)

    def xz(qi: np.ndarray) -> np.ndarray:  # (points, 2) [m]
        pin.framesForwardKinematics(robot.model, data, qi)
        return np.array([data.oMf[f].translation[[0, 2]] for f in frames])

    def metric(positions: np.ndarray) -> np.ndarray:  # (..., points, 2) -> (..., points, holes)
        return np.stack([e.metric(positions[..., 0], positions[..., 1]) for e in holes], axis=-1)

    start = xz(q[0])
    inside_at_start = metric(start) < 1.0
    centre, half = np.array([(e.x, e.z) for e in holes]), np.array([(e.a, e.b) for e in holes])
    worst = (math.inf, None, None, None, False)
    for i in range(t.size - 1):
        end = xz(q[i + 1])
        travel = np.abs(end - start).max()

        def closest(grid, pair=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            """Over the s of grid, updating worst: each (point, hole) pair's s of its smallest metric, its nearest
            distance to the hole's bounding box [m] and each point's largest move between two s [m]; pair: that
            (point, hole) pair's alone (the others inf)."""
            nonlocal worst
            pos = np.array([end if s == 1.0 else xz((1.0 - s) * q[i] + s * q[i + 1]) for s in grid])  # (G, points, 2)
            near, hop = None, None
            if pair is None:
                m = metric(pos)  # (G, points, holes)
                near = np.hypot(np.maximum(np.abs(pos[..., :1] - centre[:, 0]) - half[:, 0], 0.0),
                                np.maximum(np.abs(pos[..., 1:] - centre[:, 1]) - half[:, 1], 0.0)).min(axis=0)
                hop = np.linalg.norm(np.diff(pos, axis=0), axis=-1).max(axis=0, initial=0.0)
            else:
                m = np.full((len(grid), len(points), len(holes)), np.inf)
                m[:, pair[0], pair[1]] = holes[pair[1]].metric(pos[:, pair[0], 0], pos[:, pair[0], 1])
            if i == 0:
                m = np.where(inside_at_start, np.inf, m)
            g, k, h = np.unravel_index(int(np.argmin(m)), m.shape)
            if m[g, k, h] < worst[0]:
                s = grid[g]  # sample i + 1 included, sample i is the previous step's
                worst = (float(m[g, k, h]), points[k], int(h), float(t[i] + s * (t[i + 1] - t[i])), bool(s == 1.0))
            return np.asarray(grid)[np.argmin(m, axis=0)], near, hop

        n = int(min(HOLE_MAX_SUBSAMPLES, max(HOLE_SUBSAMPLES, math.ceil(4.0 * travel / finest))))
        at, near, hop = closest(np.linspace(0.0, 1.0, n + 1)[1:])
        # the cap left samples farther apart than a quarter of a hole's narrower half-axis (a 2 um wall was crossed
        # unseen between two 60 um apart): zoom in around each pair's own closest sample, HOLE_ZOOM times finer, where
        # the point's path comes within two of its largest moves between samples of the hole's bounding box
        for h, e in enumerate(holes):
            needed = math.ceil(4.0 * travel / min(e.a, e.b))
            for k in range(len(points)):
                s_k, level = at[k, h], n
                while level < needed and near[k, h] <= 2.0 * hop[k]:
                    grid = np.clip(s_k + np.linspace(-1.0, 1.0, 2 * HOLE_ZOOM + 1) / level, 0.0, 1.0)
                    s_k = closest(grid, (k, h))[0][k, h]
                    level *= HOLE_ZOOM
        start = end
    keys = ("min_hole_metric", "hole_point", "hole_index", "hole_time_s", "hole_at_sample")
    return dict(zip(keys, worst)) if worst[1] else {}


def metric_text(metric: float, first: str) -> str:
    """An ellipse metric in the format `first`, or with more digits where that one rounds it across HOLE_PASS_METRIC
    (0.2451 read "0.25 (limit 0.25)", 0.24999977 "0.25 < 0.25")."""
    for spec in (first, ".6g", ".9g", ".17g"):
        text = format(metric, spec)
        if (float(text) < HOLE_PASS_METRIC) == (metric < HOLE_PASS_METRIC):
            return text
    return repr(metric)


def hole_failure(kinematic: KinematicReport) -> str | None:
    """The validation's failure when a contact point goes through a hole's inner half, else None."""
    k = kinematic
    if k.min_hole_metric is None or k.min_hole_metric >= HOLE_PASS_METRIC:
        return None
    where = (f"{k.hole_point!r} goes through plan.holes[{k.hole_index}] near t = {k.hole_time_s:.4g} s (ellipse "
             f"metric {metric_text(k.min_hole_metric, '.3g')} < {HOLE_PASS_METRIC})")
    if k.hole_at_sample:  # (the grid was blamed for a node the OCP itself keeps out: an edited or unconverged plan)
        return (f"{where} at a sample of the trajectory: the plan's own node is inside the hole, which a converged "
                "plan's hole rows forbid")
    # (it said "plan on a finer grid", where a monopod's foot then swept the hole faster: metric 0.14 -> 0.007)
    return (f"{where} between the plan's nodes, which alone the OCP keeps out of holes (docs/validation.md, \"Holes "
            "between samples\"); another grid (horizon.N, `planner plan --steps`) may avoid it, a finer one not always")


class _Reference:
    """The plan sampled on MuJoCo's time grid t_0 + k dt, k = 0..n.

    q is linear between samples; at a repeated time (an impact) the later, post-impact sample holds
    from that time on. v is the slope of that piecewise-linear q on the interval (t_{i-1}, t_i] a
    time falls in (v[0] at t_0): the only velocity consistent with the position reference. The
    sampled v is not: a first-order plan moves by h v_{i+1} over a step, and linear interpolation of
    v lags it by h a / 2, which the PD's damping turned into a steady position error (up to 12 cm on
    the point-mass stress plans at h = 40 ms). Semi-implicit Euler (MuJoCo) has the same step rule,
    so a MuJoCo rollout sampled every step replays bit for bit.
    u[i] is the control that drove the plan from sample i-1 to sample i (planner.result.recover),
    so u[i+1] is held on [t_i, t_{i+1}) (zero-order hold).
    """

    def __init__(self, arrays: Mapping[str, np.ndarray], dt: float):
        t, q, v = arrays["t"], arrays["q"], arrays["v"]
        self.dt = dt
        self.steps = max(1, int(round((t[-1] - t[0]) / dt)))
        self.times = t[0] + dt * np.arange(self.steps + 1)
        last = t.size - 1
        idx = np.clip(np.searchsorted(t, self.times, side="right") - 1, 0, last)
        nxt = np.minimum(idx + 1, last)
        span = t[nxt] - t[idx]
        w = np.clip(np.where(span > 0, (self.times - t[idx]) / np.where(span > 0, span, 1.0), 0.0), 0.0, 1.0)[:, None]
        self.q = q[idx] + w * (q[nxt] - q[idx])  # (n+1, nq)
        end = np.clip(np.searchsorted(t, self.times, side="left"), 1, last)
        chord_dt = t[end] - t[end - 1]
        chord = (q[end] - q[end - 1]) / np.where(chord_dt > 0, chord_dt, 1.0)[:, None]
        self.v = np.where((chord_dt > 0)[:, None], chord, v[end])  # (n+1, nv)
        self.v[0] = v[idx[0]]
        self.u = arrays["u"][nxt]  # (n+1, nu)

    def window(self, first: int, last: int) -> "_Reference":
        """The reference from MuJoCo step `first` to step `last` (both included)."""
        out = copy.copy(self)
        out.steps = last - first
        out.times, out.q, out.v, out.u = (a[first:last + 1] for a in (self.times, self.q, self.v, self.u))
        return out


def resolve_gains(scene: Scene, gains: TrackingGains, q0: np.ndarray) -> ResolvedGains:
    """Per-actuator kp, kd (see TrackingGains) with the mass matrix at posture q0 (nq,): a gain given
    explicitly replaces the rule's, the other keeps the rule's (one given alone is not the other at 0)."""
    names = tuple(motor_names(scene.model))
    nu = scene.model.nu
    for key in ("kp", "kd"):
        values = getattr(gains, key)
        if values is not None and len(values) != nu:
            raise InputError(f"gains {key} needs {nu} entries (one per actuator), got {len(values)}")
    if gains.kp is not None and gains.kd is not None:
        return ResolvedGains(names, tuple(map(float, gains.kp)), tuple(map(float, gains.kd)), None, None)
    data = mujoco.MjData(scene.model)
    data.qpos[:] = q0
    mujoco.mj_forward(scene.model, data)
    mass = np.zeros((scene.model.nv, scene.model.nv))
    mujoco.mj_fullM(scene.model, data, mass)
    inertia = mass[scene.dof_adr, scene.dof_adr]
    omega = 2 * math.pi * gains.frequency_hz
    kp = inertia * omega**2 if gains.kp is None else np.asarray(gains.kp, dtype=float)
    kd = 2 * gains.damping_ratio * inertia * omega if gains.kd is None else np.asarray(gains.kd, dtype=float)
    return ResolvedGains(names, tuple(map(float, kp)), tuple(map(float, kd)), gains.frequency_hz, gains.damping_ratio)


@dataclass
class _Rollout:
    """What one MuJoCo run recorded at the states k = 0..n (times t_0 + k dt)."""

    times: np.ndarray  # (n+1,)
    qpos: np.ndarray  # (n+1, nq)
    qvel: np.ndarray  # (n+1, nv)
    base: np.ndarray  # (n+1, 3)
    sites: np.ndarray  # (n+1, C, 3)
    active: np.ndarray  # (n+1, C) force-carrying contact
    depth: np.ndarray  # (n+1, C) penetration >= 0 [m]
    ctrl: np.ndarray  # (n, nu) commands before clamping
    diverged: bool
    touching0: np.ndarray | None = None  # (C,) within the detection gap of the ground at the start


def _simulate(scene: Scene, q0: np.ndarray, v0: np.ndarray, steps: int, t0: float,
              command: Callable[[int, mujoco.MjData], np.ndarray]) -> _Rollout:
    """Run `steps` MuJoCo steps from (q0, v0); command(k, data) gives the control (nu,) at state k.

    mj_step evaluates the forward dynamics (kinematics, contacts) at state k before integrating,
    so what is read after it describes state k, consistently with the control applied there.
    """
    model, data = scene.model, mujoco.MjData(scene.model)
    data.qpos[:], data.qvel[:], data.time = q0, v0, t0
    C, site_ids = len(scene.points), list(scene.site_ids)
    rec = _Rollout(times=t0 + scene.settings.timestep * np.arange(steps + 1),
                   qpos=np.zeros((steps + 1, model.nq)), qvel=np.zeros((steps + 1, model.nv)),
                   base=np.zeros((steps + 1, 3)), sites=np.zeros((steps + 1, C, 3)),
                   active=np.zeros((steps + 1, C), dtype=bool), depth=np.zeros((steps + 1, C)),
                   ctrl=np.zeros((steps, model.nu)), diverged=False)
    dist = np.full((steps + 1, C), np.inf)  # none detected, until a step has contacts
    lower, upper = scene.ctrl_lower, scene.ctrl_upper
    with mujoco_warnings(lambda message: None):  # the rollout reads them from data.warning
        for k in range(steps + 1):
            check_interrupted()
            rec.qpos[k], rec.qvel[k] = data.qpos, data.qvel
            if k < steps:
                u = command(k, data)
                rec.ctrl[k] = u
                data.ctrl[:] = np.minimum(np.maximum(u, lower), upper)  # np.clip, at half its call cost
                mujoco.mj_step(model, data)
            else:
                mujoco.mj_forward(model, data)
            rec.base[k] = _base_position(scene, data)
            rec.sites[k] = data.site_xpos[site_ids]
            if data.ncon:
                dist[k], rec.active[k] = scene.contact_state(data)
    rec.touching0 = np.isfinite(dist[0])  # detected: within the pair's gap of the ground
    rec.depth[:] = np.maximum(-np.where(np.isfinite(dist), dist, 0.0), 0.0)
    rec.diverged = any(data.warning[w].number > 0 for w in _BAD_STATE_WARNINGS)
    for w in range(mujoco.mjtWarning.mjNWARNING):  # the bad states are the report's `diverged`; the rest said once
        if w not in _BAD_STATE_WARNINGS and data.warning[w].number > 0:
            warnings.warn(f"MuJoCo: {mujoco.mju_warningText(w, data.warning[w].lastinfo)}", stacklevel=2)
    return rec


def _replay(scene: Scene, ref: _Reference, gains: ResolvedGains | None, planned: list[tuple[str, float, bool]],
            options: ValidationOptions, controller: TrackingController = TrackingController.JOINT_PD,
            positions: tuple[np.ndarray, np.ndarray] | None = None) -> RolloutReport:
    """Tracking replay (gains given) or open-loop replay (gains None) of the reference. positions: the
    reference's base (n+1, 3) and contact sites (n+1, C, 3) when the caller has them (_planned_positions)."""
    started = _time.perf_counter()
    if gains is None:
        def command(k, data):
            return ref.u[k]
    else:
        kp, kd = np.array(gains.kp), np.array(gains.kd)
        qa, va = scene.qpos_adr, scene.dof_adr
        retarget = _StanceRetarget(scene, ref, options.contact_gap_tol_m) \
            if controller is TrackingController.STANCE_RETARGET else None

        def command(k, data):
            q_ref, v_ref = retarget(k, data) if retarget is not None else (ref.q[k], ref.v[k])
            tau = kp * (q_ref[qa] - data.qpos[qa]) + kd * (v_ref[va] - data.qvel[va])
            return ref.u[k] + tau / scene.gear

    run = _simulate(scene, ref.q[0], ref.v[0], ref.steps, ref.times[0], command)
    base_ref, sites_ref = positions if positions is not None else _planned_positions(scene, ref.q)
    base_err = np.linalg.norm(run.base - base_ref, axis=1)
    foot_err = np.linalg.norm(run.sites - sites_ref, axis=2)
    if run.diverged:
        base_err[:], foot_err[:] = np.inf, np.inf
    outside = np.nonzero(base_err > options.open_loop_band_m)[0]
    within = ref.times[outside[0]] - ref.times[0] if outside.size else ref.times[-1] - ref.times[0]
    saturated = (run.ctrl < scene.ctrl_lower) | (run.ctrl > scene.ctrl_upper)
    mj_impacts = detect_impacts(run.times, run.active, scene.points, options.min_flight_s, run.touching0)
    matches = _match_impacts(planned, mj_impacts)
    names = motor_names(scene.model)
    return RolloutReport(
        duration_s=float(ref.times[-1] - ref.times[0]), steps=ref.steps,
        max_base_error_m=float(base_err.max()), final_base_error_m=float(base_err[-1]),
        max_foot_error_m={p: float(foot_err[:, c].max()) for c, p in enumerate(scene.points)},
        final_foot_error_m={p: float(foot_err[-1, c]) for c, p in enumerate(scene.points)},
        mujoco_impacts=tuple((p, float(x)) for p, x in mj_impacts),
        impacts=tuple(matches), max_abs_impact_time_difference_s=_largest_difference(matches),
        saturation_fraction=float(saturated.mean()) if saturated.size else 0.0,
        saturation_by_actuator={n: float(saturated[:, i].mean()) for i, n in enumerate(names)},
        max_dynamic_penetration_m=float(run.depth.max()) if run.depth.size else 0.0,
        time_within_band_s=float(within), diverged=run.diverged,
        wall_time_s=_time.perf_counter() - started,
    )


def _window_samples(ref: _Reference, options: ValidationOptions) -> tuple[int, int]:
    """The replay's samples per window and per stride of the windowed tracking; InputError for a window in which the
    planned impacts cannot be timed (checked before any replay runs)."""
    # shorter, a window ran one sample and was reported at its asked length
    _check(options.window_stride_s >= ref.dt, "window_stride_s", options.window_stride_s,
           f">= the replay's sample step {ref.dt:g} s")
    span = (ref.steps + 1) * ref.dt  # a window or stride beyond the plan is the plan (1e308 s overflowed int())
    per = max(1, int(round(min(options.window_s, span) / ref.dt)))
    stride = max(1, int(round(min(options.window_stride_s, span) / ref.dt)))
    # an impact is timed in the window started one to two strides before it: shorter, the window ended before the
    # impact and its landings read "none" (MuJoCo saw no landing) at --window 0.03
    # (one limit said: the sample step's was named, then the strides' refused what it allowed)
    _check(options.window_s >= ref.dt and (per >= ref.steps or per >= 3 * stride), "window_s", options.window_s,
           f">= 3 x window_stride_s ({options.window_stride_s:g} s) = {3 * options.window_stride_s:g} s (an impact is "
           "timed in the window started one to "
           "two strides before it, which must run a stride past it), or the plan's length")
    return per, stride


def _windows(scene: Scene, ref: _Reference, gains: ResolvedGains, options: ValidationOptions,
             samples: tuple[int, int], planned: Sequence[tuple[str, float, bool]] = ()) -> WindowReport:
    """The tracking replay restarted from the reference in overlapping windows (WindowReport) of samples = (samples
    per window, per stride) (_window_samples).

    A window shorter than half of window_s at the end of the plan is not started. Each planned impact
    (point, time [s], tap), taps too, is matched (_match_impacts) to the MuJoCo impacts of the window that
    started window_stride_s to twice that before it (the first window if none did).
    """
    per, stride = samples
    starts, errors, onsets, diverged = [], [], [], False
    base, sites = _planned_positions(scene, ref.q)  # once, not per window: the windows overlap four times
    # a window as long as the plan is the one window the report names (30 more, each clipped to the plan's end, ran)
    for first in range(0, 1 if per >= ref.steps else max(1, ref.steps - per // 2), stride):
        last = min(first + per, ref.steps)
        run = _replay(scene, ref.window(first, last), gains, [], options, options.controller,
                      positions=(base[first:last + 1], sites[first:last + 1]))
        starts.append(float(ref.times[first]))
        errors.append(run.max_base_error_m)
        onsets.append(run.mujoco_impacts)
        diverged |= run.diverged
    lead = stride * ref.dt
    # started at least one stride before the impact, so MuJoCo, not the restart, decides when the point lands
    chosen = [max(0, int(np.searchsorted(starts, when - lead + 1e-9 * ref.dt, side="right")) - 1) for _, when, _ in planned]
    # taps are matched too: from the plan's state a tap in a stance finds no onset, and a light landing below
    # TAP_SHARE (main job: 1.086 s) its own
    # (not in a window started earlier, as the one window of a plan-long --window: a tap took another hop's landing,
    # -56.9 ms, the match the whole replay leaves taps out of)
    matches = [_match_impacts(planned, list(onsets[j]), taps=planned[i][1] - starts[j] <= 2 * lead + 1e-9 * ref.dt)[i]
               for i, j in enumerate(chosen)]
    return WindowReport(options.window_s, options.window_stride_s, tuple(starts), tuple(errors), diverged,
                        tuple(matches), _largest_difference(matches))


class _StanceRetarget:
    """Joint references of TrackingController.STANCE_RETARGET: call(k, data) -> (q_ref (nq,), v_ref (nv,)).

    With the points S in contact (in the plan's reference posture and in MuJoCo, gap < tol), the
    actuated coordinates a of q_ref solve p_S(q_u = plan, q_a) = MuJoCo's p_S (two Gauss-Newton steps
    from the plan's q_a; least squares), and v_a solves J_S,u v_u + J_S,a v_a = MuJoCo's dp_S/dt
    (about 0: the points are at rest) with v_u the plan's. A MuJoCo rollout used as the plan is
    therefore its own retargeted reference and still replays exactly.
    Positions and Jacobians are MuJoCo's (x and z rows: the robots are planar). Needs the joint
    coordinates to be scalar (qpos index = dof index), which build_scene ensures.
    """

    def __init__(self, scene: Scene, ref: _Reference, tol: float):
        model = scene.model
        self.scene, self.ref, self.tol = scene, ref, tol
        self.unactuated = np.setdiff1d(np.arange(model.nv), scene.dof_adr)
        _, sites = _planned_positions(scene, ref.q)
        self.plan_contact = sites[:, :, 2] - scene.ground_height < tol  # (n+1, C)
        self.kin = mujoco.MjData(model)
        self.site_ids = list(scene.site_ids)

    def _points(self, q: np.ndarray, contacts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(x, z) of the contact points `contacts` (2 S,) and their Jacobian (2 S, nv) at posture q."""
        model, kin = self.scene.model, self.kin
        kin.qpos[:] = q
        mujoco.mj_kinematics(model, kin)
        mujoco.mj_comPos(model, kin)
        jac = np.zeros((3, model.nv))
        pos, rows = [], []
        for c in contacts:
            mujoco.mj_jacSite(model, kin, jac, None, self.site_ids[c])
            pos.append(kin.site_xpos[self.site_ids[c]][[0, 2]].copy())
            rows.append(jac[[0, 2]].copy())
        return np.concatenate(pos), np.vstack(rows)

    def __call__(self, k: int, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
        q_ref, v_ref = self.ref.q[k], self.ref.v[k]
        if self.unactuated.size == 0 or not self.plan_contact[k].any():
            return q_ref, v_ref
        # data.site_xpos is still that of the previous step's state (mj_step integrates after it)
        now, jac_now = self._points(data.qpos, range(len(self.site_ids)))
        touching = now[1::2] - self.scene.ground_height < self.tol
        contacts = np.nonzero(self.plan_contact[k] & touching)[0]
        if contacts.size == 0:
            return q_ref, v_ref
        rows = np.ravel([[2 * c, 2 * c + 1] for c in contacts])
        target = now[rows]
        moving = jac_now[rows] @ data.qvel  # MuJoCo's soft contact lets a point creep and sink a little
        qa, va, vu = self.scene.qpos_adr, self.scene.dof_adr, self.unactuated
        q, v = q_ref.copy(), v_ref.copy()
        for _ in range(2):  # the plan's posture is close: two Gauss-Newton steps
            pos, jac = self._points(q, contacts)
            q[qa] -= np.linalg.lstsq(jac[:, va], pos - target, rcond=None)[0]
        _, jac = self._points(q, contacts)
        v[va] = np.linalg.lstsq(jac[:, va], moving - jac[:, vu] @ v_ref[vu], rcond=None)[0]
        return q, v


def _translates(model: mujoco.MjModel, body: int) -> bool:
    """Whether a free or slide joint moves `body` (its own or an ancestor's: a URDF's massless carriage links)."""
    translating = (int(mujoco.mjtJoint.mjJNT_FREE), int(mujoco.mjtJoint.mjJNT_SLIDE))  # model.jnt_type holds ints
    while body > 0:
        if any(model.jnt_type[j] in translating for j in np.nonzero(model.jnt_bodyid == body)[0]):
            return True
        body = int(model.body_parentid[body])
    return False


def _base_position(scene: Scene, data: mujoco.MjData) -> np.ndarray:
    return data.xpos[scene.base_body] if scene.base_site is None else data.site_xpos[scene.base_site]


def _planned_positions(scene: Scene, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Base origin (n, 3) and contact sites (n, C, 3) of the postures q (n, nq), by MuJoCo."""
    model, data = scene.model, mujoco.MjData(scene.model)
    base, sites = np.zeros((len(q), 3)), np.zeros((len(q), len(scene.points), 3))
    site_ids = list(scene.site_ids)
    for k, qk in enumerate(q):
        data.qpos[:] = qk
        mujoco.mj_kinematics(model, data)
        base[k], sites[k] = _base_position(scene, data), data.site_xpos[site_ids]
    return base, sites


# ==================================================================================================
# impacts
# ==================================================================================================

def detect_impacts(times: np.ndarray, active: np.ndarray, points: Sequence[str],
                   min_flight_s: float = MIN_FLIGHT_S, initial_contact: np.ndarray | None = None) -> list[tuple[str, float]]:
    """Contact onsets after flight: (point, time [s]) sorted by time.

    active (n, C): whether point c carries a contact at times[k]. An onset counts when the point was
    free for at least min_flight_s before it, or free since the first sample. initial_contact (C,)
    marks points that start in contact although active[0] is False (resting exactly on the ground,
    where the soft contact carries no force yet): settling onto the ground is not an impact.
    """
    out = []
    for c, point in enumerate(points):
        starts_free = not active[0, c] and not (initial_contact is not None and initial_contact[c])
        free_since = times[0] if starts_free else None
        for k in range(1, len(times)):
            if active[k, c] and not active[k - 1, c]:
                if free_since is not None and (free_since == times[0] or times[k] - free_since >= min_flight_s):
                    out.append((point, float(times[k])))
                free_since = None
            elif not active[k, c] and active[k - 1, c]:
                free_since = times[k]
    return sorted(out, key=lambda item: item[1])


def _planned_impacts(scene: Scene, arrays: Mapping[str, np.ndarray], points: Sequence[str | None] | None,
                     taps: Sequence[bool] | None = None) -> list[tuple[str, float, bool]]:
    """(point, time, tap) of each planned impact; an unknown point is the lowest one at that time."""
    t, q = arrays["t"], arrays["q"]
    model, data = scene.model, mujoco.MjData(scene.model)
    out = []
    for i, when in enumerate(arrays["impact_times"]):
        point = points[i] if points is not None and i < len(points) else None
        if point is None or point not in scene.points:
            k = int(np.argmin(np.abs(t - when)))
            data.qpos[:] = q[k]
            mujoco.mj_kinematics(model, data)
            point = scene.points[int(np.argmin(data.site_xpos[list(scene.site_ids), 2]))] if scene.points else "?"
        out.append((point, float(when), bool(taps[i]) if taps is not None and i < len(taps) else False))
    return out


def _largest_difference(matches: Sequence[ImpactMatch]) -> float | None:
    """The largest |MuJoCo - plan| [s] over the matched impacts; None if none is matched."""
    return max((abs(m.difference_s) for m in matches if m.difference_s is not None), default=None)


def _match_impacts(planned: Sequence[tuple[str, float, bool]], mujoco_impacts: Sequence[tuple[str, float]],
                   taps: bool = False) -> list[ImpactMatch]:
    """Each planned (point, time [s], tap) against the nearest MuJoCo impact of its point among those to which it
    is the nearest planned impact; taps are matched (and claim MuJoCo impacts) only if `taps`."""
    eligible = [(p, w) for p, w, tap in planned if taps or not tap]

    def claims(point: str, when: float, x: float) -> bool:
        # a MuJoCo impact goes to one planned impact: a push-off planned just after a landing (the main job's 1.222 s
        # after 1.189 s) would otherwise take the landing's onset as its own
        return min((w for p, w in eligible if p == point), key=lambda w: abs(w - x)) == when

    matches = []
    for point, when, tap in planned:
        candidates = [] if tap and not taps else [x for p, x in mujoco_impacts if p == point and claims(point, when, x)]
        if not candidates:
            matches.append(ImpactMatch(point, when, None, None, tap=tap))
            continue
        nearest = min(candidates, key=lambda x: abs(x - when))
        matches.append(ImpactMatch(point, when, nearest, nearest - when, tap=tap))
    return matches


# ==================================================================================================
# MuJoCo rollouts in the contract format (ground truth for tests, cross-checks of the simulation)
# ==================================================================================================

def mujoco_rollout(scene: Scene, q0: Sequence[float], v0: Sequence[float], duration: float,
                   control: Callable[[float, np.ndarray, np.ndarray], Sequence[float]] | None = None,
                   sample_every: int = 1, min_flight_s: float = MIN_FLIGHT_S) -> dict[str, np.ndarray]:
    """Simulate the scene from (q0 (nq,), v0 (nv,)) for `duration` [s] and return contract arrays.

    control(t, q, v) -> u (nu,) is evaluated every `sample_every` MuJoCo steps and held in between
    (zero-order hold, like the plan's controls); None means u = 0. The samples are those instants,
    and `u[i]` is the control that acted on [t_{i-1}, t_i) (u[0] = u[1]), the convention of the
    planner's trajectories (planner.result.recover). MuJoCo's contacts are soft, so an impact spans steps
    and has no repeated-time sample; `impact_times` are the contact onsets after flight and
    `impact_points` (I,) their contact points. Also returns `tau` = t and `y` = (q, v, t).
    """
    model = scene.model
    duration, sample_every, min_flight_s = as_float(plain(duration)), plain(sample_every), as_float(plain(min_flight_s))
    for name, value in (("duration", duration), ("min_flight_s", min_flight_s)):  # a str or nan crashed in arithmetic
        if not (isinstance(value, (int, float)) and not isinstance(value, bool) and 0 <= value < math.inf):
            raise InputError(f"mujoco_rollout's {name} must be a finite number >= 0 [s], got {shown(value)}")
    if not (is_integer(sample_every) and sample_every >= 1):  # -1 returned no samples, 0 divided by zero
        raise InputError(f"mujoco_rollout's sample_every must be an integer >= 1 [steps], got {shown(sample_every)}")
    if control is not None and not callable(control):
        raise InputError(f"mujoco_rollout's control must be a function control(t, q, v) -> u or None, got "
                         f"{shown(control)}")
    if duration > MAX_STEPS * scene.settings.timestep:  # 1e9 s asked numpy for 29 TiB (1e306 s: an OverflowError)
        raise InputError(f"mujoco_rollout's duration {duration} s is more than {MAX_STEPS} MuJoCo steps of "
                         f"{scene.settings.timestep} s: shorten it")
    steps = int(round(duration / scene.settings.timestep))
    steps -= steps % sample_every  # end on a sample
    if steps < sample_every:
        raise InputError(f"duration {duration} s is shorter than one sample ({sample_every} steps)")
    start = {}
    for name, value, n in (("q0", q0, model.nq), ("v0", v0, model.nv)):  # numpy broadcast a length-1 q0 to every entry
        start[name] = real_array(value, f"mujoco_rollout's {name}")
        if start[name].shape != (n,) or not np.all(np.isfinite(start[name])):
            raise InputError(f"mujoco_rollout's {name} must be {n} finite numbers (the scene's n{name[0]}), got "
                             f"{start[name].tolist()!r:.80}")
    held = np.zeros(model.nu)

    def command(k, data):
        if k % sample_every == 0 and control is not None:
            u = real_array(control(data.time, data.qpos.copy(), data.qvel.copy()), "mujoco_rollout's control(t, q, v)")
            if u.shape != held.shape:  # a scalar drove every motor
                raise InputError(f"mujoco_rollout's control(t, q, v) must return nu = {model.nu} numbers, got shape "
                                 f"{u.shape}")
            held[:] = u
        return held.copy()

    run = _simulate(scene, start["q0"], start["v0"], steps, 0.0, command)
    impacts = detect_impacts(run.times, run.active, scene.points, min_flight_s, run.touching0)
    picks = np.arange(0, steps + 1, sample_every)
    u = run.ctrl[np.maximum(picks - 1, 0)] if model.nu else np.zeros((picks.size, 0))
    u = np.clip(u, scene.ctrl_lower, scene.ctrl_upper)  # what MuJoCo applied
    t, q, v = run.times[picks], run.qpos[picks], run.qvel[picks]
    return {"tau": t.copy(), "y": np.hstack([q, v, t[:, None]]), "t": t, "q": q, "v": v, "u": u,
            "impact_times": np.array([x for _, x in impacts]), "impact_points": np.array([p for p, _ in impacts], dtype=str)}


# ==================================================================================================
# helpers
# ==================================================================================================

def _quat_zaxis(quat: np.ndarray) -> np.ndarray:
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, np.asarray(quat, dtype=float))
    return mat.reshape(3, 3)[:, 2]


def _check(ok: bool, key: str, value, allowed: str) -> None:
    if not ok:
        raise InputError(f"validation option {key} = {value!r} is not allowed; it must be {allowed}")


def _jsonable(value):
    """Plain JSON types: numpy scalars/arrays to Python, non-finite floats to None (strict JSON)."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    return value
