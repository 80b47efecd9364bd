"""Robot files (MJCF or URDF) parsed by Pinocchio, plus what Pinocchio does not read from them.

Pinocchio gives the kinematic tree, inertias, frames and joint limits. MJCF motors are read from
MuJoCo's compiled model of the same file (Pinocchio's MJCF parser ignores actuators); URDF actuators
are the joints with a positive effort limit.
"""
from __future__ import annotations

import contextlib
import hashlib
import math
import os
import sys
import tempfile
import threading
import warnings
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path

import numpy as np
import pinocchio as pin

from .errors import InputError, PlannerError, RobotFileError, UnknownNameError, expect, plain, read_error
from .result import ON_PLANE_M

_HERE = Path(__file__).resolve().parent
# the shipped robot files and tasks: planner/robots in an installed wheel, the checkout's robots/ otherwise
ROBOTS_DIR = _HERE / "robots" if (_HERE / "robots").is_dir() else _HERE.parent / "robots"
# a degree of freedom lighter than this [kg or kg m^2] moves less than the solvers' absolute tolerances resolve: a
# point-mass drop's height at 0.3 s was off by 3e-5 m at 1e-4 kg, 7e-4 m at 1e-5, 0.01 m at 1e-6, 0.13 m at 1e-7
MIN_DOF_INERTIA = 1e-4
# a joint speed limit at or above this [m/s or rad/s] is none: IPOPT's own infinity (nlp_upper_bound_inf), and Pinocchio
# gives its free-flyer root the largest double
NO_SPEED_LIMIT = 1e19
# a URDF joint axis whose components are all below this is zero (MuJoCo's compiler refused 1e-7 as "too small",
# accepted 2e-7)
MIN_AXIS = 1e-6


class RobotFormat(Enum):
    """The robot file's format (Robot.format), from its root element."""

    MJCF = "mjcf"  # MuJoCo XML, <mujoco>
    URDF = "urdf"  # <robot>


@dataclass(frozen=True)
class Actuator:
    """A motor acting on one degree of freedom: generalized force = gear * u."""

    name: str
    dof: int  # velocity index, 0 <= dof < nv
    gear: float
    lower: float  # control bounds [N m] or [N] divided by the gear: the motor's command u (its force is gear u)
    upper: float


@dataclass(frozen=True, eq=False)
class Robot:
    """A parsed robot file. `model` is the Pinocchio model; the rest is what the planner adds."""

    path: Path
    format: RobotFormat
    model: pin.Model = field(repr=False)
    actuators: tuple[Actuator, ...]
    points: tuple[str, ...]  # named points: MJCF sites, URDF links and frames
    dof_names: tuple[str, ...]  # one joint name per velocity index (nv,)
    sha256: str
    # the file's passive joint forces ("joint 'hip': damping 5") and URDF <mimic> couplings, which the planner's dynamics
    # do not model: simulate and plan refuse the robot (Task.check_against), check-model fails naming them
    passive: tuple[str, ...] = ()
    floating: bool = False  # a URDF read with the free-flyer root joint only Pinocchio adds (load_robot's floating)
    world_sites: tuple[str, ...] = ()  # an MJCF file's sites on the world body (markers): fixed, no points of the robot
    unread_sites: tuple[str, ...] = ()  # an MJCF file's sites MuJoCo reads, Pinocchio's parser not (<frame>, 2nd body)
    ground_z: float | None = None  # height [m] of an MJCF file's ground plane (the task's ground_height rules)
    # that plane's geom: the world plane named "ground", else the file's only world plane (Menagerie's "floor"); a
    # file of several planes and none named "ground" has none ("", no ground_z), and its planes are scenery
    ground_geom: str = ""
    # the moving bodies (MJCF) or links (URDF) with geoms that can touch the ground in MuJoCo (contype/conaffinity bits
    # that meet the world's, a <pair> with a world geom, a URDF <collision>): the planner's contacts are the task's
    # points only (Task.check_against warns of those no contact or above_ground point moves with)
    colliding: tuple[str, ...] = ()
    # an MJCF file's geoms fixed to the world, other than the ground plane, with contype or conaffinity nonzero (steps,
    # boxes): the planner and its validation model the ground only (Task.check_against warns)
    scenery: tuple[str, ...] = ()
    # an MJCF file whose angles MuJoCo reads in degrees (<compiler angle="degree">, MuJoCo's default): the planner's
    # hinge coordinates, ranges and task values are radians all the same (Robot.range_text says both)
    degrees: bool = False

    def check_inertia(self, q) -> None:
        """RobotFileError when a degree of freedom's inertia (the diagonal of M(q), q (nq,)) is below MIN_DOF_INERTIA
        [kg or kg m^2]: the solvers' tolerances are absolute, so lighter bodies' motions are not resolved. InputError
        for a q of other numbers than nq (Pinocchio's or numpy's ValueError)."""
        try:
            values = np.array(q, float)
        except (TypeError, ValueError):
            values = None
        if values is None or values.shape != (self.nq,):
            raise InputError(f"check_inertia's q must have shape ({self.nq},) for {self.name!r}, got "
                             + (f"{q!r:.60}" if values is None else f"{values.shape}"))
        diagonal = np.diag(pin.crba(self.model, self.model.createData(), values))
        light = [f"{name} ({m:.3g})" for name, m in zip(self.dof_names, diagonal) if not m >= MIN_DOF_INERTIA]
        if light:
            raise RobotFileError(f"{self.path}: degrees of freedom lighter than {MIN_DOF_INERTIA:g} kg (or kg m^2) at "
                                 f"initial.q: {', '.join(light)}; the solvers' tolerances are absolute (a 1e-7 kg point mass "
                                 "fell 0.13 m short in 0.3 s, a 1e-9 kg one not at all), so the planner cannot resolve them")

    @property
    def name(self) -> str:
        return self.model.name or self.path.stem

    def range_text(self, i: int, lower: float | None = None, upper: float | None = None) -> str:
        """Coordinate i's range [lower, upper] (default the file's, Robot.q_lower, q_upper) with its unit, and when
        it is the file's range of a hinge of a file written in degrees those degrees too: messages quoted radians as
        "the file's range". (Other bounds, a task's, are radians in the task file: they get no degrees.)"""
        lower = self.q_lower[i] if lower is None else lower
        upper = self.q_upper[i] if upper is None else upper
        own = (lower, upper) == (self.q_lower[i], self.q_upper[i])
        unit = coordinate_units(self.model)[0][i]
        text = f"[{lower:.10g}, {upper:.10g}]" + (f" {unit}" if unit else "")
        if own and unit == "rad" and self.degrees and np.isfinite([lower, upper]).all():
            text += f" (the file's {np.degrees(lower):.10g} {np.degrees(upper):.10g} degrees)"
        return text

    def carrier(self, name: str, body: bool = False) -> int:
        """The index of the Pinocchio joint that moves a named point (body=True: an MJCF body or URDF link, fixed
        links merged into the link they hang on), 0 for one fixed to the world."""
        return _carrier(self.model, name) if body else int(self.model.frames[self.frame_id(name)].parentJoint)

    @property
    def nq(self) -> int:
        return self.model.nq

    @property
    def nv(self) -> int:
        return self.model.nv

    @property
    def nu(self) -> int:
        return len(self.actuators)

    @property
    def q_lower(self) -> np.ndarray:
        """Joint position lower limits (nq,); -inf where the file gives none."""
        return np.array(self.model.lowerPositionLimit, dtype=float)

    @property
    def q_upper(self) -> np.ndarray:
        """Joint position upper limits (nq,); +inf where the file gives none."""
        return np.array(self.model.upperPositionLimit, dtype=float)

    @property
    def v_limit(self) -> np.ndarray:
        """Joint speed limits (nv,) [m/s or rad/s]: a URDF joint's <limit velocity>, +inf where there is none (an
        MJCF file has none; a URDF's velocity="0", as CAD exporters write an unknown one, is none)."""
        limit = np.array(self.model.velocityLimit, dtype=float)
        if self.format is not RobotFormat.URDF:
            return np.full(self.nv, np.inf)
        return np.where((limit > 0.0) & (limit < NO_SPEED_LIMIT), limit, np.inf)

    @property
    def u_lower(self) -> np.ndarray:
        """Control lower bounds (nu,)."""
        return np.array([a.lower for a in self.actuators], dtype=float)

    @property
    def u_upper(self) -> np.ndarray:
        """Control upper bounds (nu,)."""
        return np.array([a.upper for a in self.actuators], dtype=float)

    @property
    def actuation_matrix(self) -> np.ndarray:
        """B (nv, nu): generalized forces = B @ u."""
        B = np.zeros((self.nv, self.nu))
        for j, a in enumerate(self.actuators):
            B[a.dof, j] = a.gear
        return B

    @property
    def sites(self) -> tuple[str, ...]:
        """The named points a contact may use: an MJCF file's sites (MuJoCo's replay puts contacts there), every URDF
        link and frame (planner.model.mujoco_spec adds a site at each)."""
        if self.format is RobotFormat.URDF:
            return self.points
        return tuple(p for p in self.points if self.model.frames[self.frame_id(p)].type == pin.FrameType.OP_FRAME)

    def frame_id(self, point: str) -> int:
        """Pinocchio frame index of a named point; UnknownNameError lists the valid names."""
        if point not in self.points:
            raise UnknownNameError("point", point, self.points)
        return _point_frames(self.model)[point]

    def moves_out_of_plane(self, point: str, samples: int = 3, tol: float = 1e-9) -> bool:
        """Whether the named point can move along the world's y axis: its translational Jacobian's y row is above tol
        at one of `samples` seeded configurations (joint values in [-1, 1] [rad or m], clipped to the limits). The
        planner's contacts are planar (normal and tangent in the x-z plane), so such a point would slide along y
        without friction."""
        return bool(self.out_of_plane_rates(point, samples, tol))

    def out_of_plane_rates(self, point: str, samples: int = 3, tol: float = 1e-9) -> dict[str, float]:
        """Per degree of freedom that moves the named point along y at one of the seeded samples (moves_out_of_plane),
        the largest |dy/dq| [m/m or m/rad] seen; {} when none does."""
        model, frame = self.model, self.frame_id(point)
        data = model.createData()
        rng = np.random.default_rng(0)
        rates = np.zeros(model.nv)
        for _ in range(samples):
            q = pin.neutral(model)
            if model.nq == model.nv:
                q = np.clip(rng.uniform(-1.0, 1.0, model.nq), self.q_lower, self.q_upper)
            J = pin.computeFrameJacobian(model, data, q, frame, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
            rates = np.maximum(rates, np.abs(np.asarray(J).reshape(6, -1)[1]))
        return {self.dof_names[i]: float(r) for i, r in enumerate(rates) if r > tol}

    def touching_contacts(self, contacts, q: np.ndarray, height: float,
                          touch_tol: float = ON_PLANE_M) -> list[tuple[int, np.ndarray, np.ndarray | None]]:
        """Of the contacts (point, unit plane normal (3,), frictional), those whose point lies on its plane (through
        (0, 0, height) [m]) at q (nq,) to touch_tol [m], each as (its index, J_p(q)^T n (nv,), J_p(q)^T t (nv,) or None
        when not frictional): the generalized forces of a unit normal and tangential contact force (plane_axes' n and
        t; J_p the point's world-frame translational Jacobian (3, nv))."""
        from .contact import plane_axes  # (contact imports the dynamics, which import this module)

        model, data, q = self.model, self.model.createData(), np.asarray(q, float)
        pin.framesForwardKinematics(model, data, q)
        touching = []
        for i, (point, surface, frictional) in enumerate(contacts):
            frame, (n, t) = self.frame_id(point), (np.array(a) for a in plane_axes(surface))
            if abs(n @ (data.oMf[frame].translation - np.array([0.0, 0.0, height]))) > touch_tol:
                continue
            J = np.asarray(pin.computeFrameJacobian(model, data, q, frame, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED))
            J = J.reshape(6, -1)[:3]  # (6,) for one DoF
            touching.append((i, J.T @ n, J.T @ t if frictional else None))
        return touching

    def contact_rank(self, contacts, q: np.ndarray, height: float,
                     touch_tol: float = ON_PLANE_M) -> tuple[list[int], int, int]:
        """Of the contacts (point, unit plane normal (3,), frictional), those whose point lies on its plane (through
        (0, 0, height) [m]) at q (nq,) to touch_tol [m] (touching_contacts): (their indices, the rank of their normal
        rows n^T J_p(q), the rank of those rows and the frictional ones' tangent rows together). A rank below the rows'
        count: the forces of those contacts together are not unique."""
        touching = self.touching_contacts(contacts, q, height, touch_tol)
        normal_rows = [normal for _, normal, _ in touching]
        tangent_rows = [tangent for _, _, tangent in touching if tangent is not None]

        def rank(rows):  # rows: (nv,) each
            return int(np.linalg.matrix_rank(np.array(rows), tol=1e-9)) if rows else 0

        return [i for i, _, _ in touching], rank(normal_rows), rank(normal_rows + tangent_rows)

    def dof_index(self, joint: str, key: str = "") -> int:
        """Velocity index of a 1-DoF joint by name; UnknownNameError lists the valid names (and names `key`, the task
        key that gave the joint, when given)."""
        if joint not in self.dof_names:
            raise UnknownNameError("joint", joint, self.dof_names, key, ordered=True)
        return self.dof_names.index(joint)


def robot_weight(robot: Robot) -> float:
    """The robot's weight m g [N]: its total mass [kg] times the magnitude of its model's gravity [m/s^2]."""
    return float(pin.computeTotalMass(robot.model) * np.linalg.norm(robot.model.gravity.linear))


def resolve_robot_path(spec: str | os.PathLike) -> Path:
    """The absolute path of a robot file given by its path, or by the bare name of one in `robots/` (e.g. `capler`):
    a result's summary.json names it, and `validate` or `view` run from another directory must find it. Where no such
    file exists, a path in robots/ as the docs write them (`robots/capler.xml`, `capler.urdf`) is the shipped file, as
    for tasks (task.shipped_task): the help's examples were refused outside a checkout."""
    path = Path(spec)
    if path.is_file():
        return path.absolute()
    in_robots = path.suffix in (".xml", ".urdf") and path.parent in (Path("."), Path("robots"))
    if in_robots and (ROBOTS_DIR / path.name).is_file():
        return ROBOTS_DIR / path.name
    if not path.suffix and path.parent == Path("."):
        for ext in (".xml", ".urdf"):
            candidate = ROBOTS_DIR / f"{path.name}{ext}"
            if candidate.is_file():
                return candidate
        known = sorted({p.stem for p in ROBOTS_DIR.glob("*") if p.suffix in (".xml", ".urdf")})
        raise RobotFileError(f"robot {str(spec)!r} is neither a file nor one of robots/: {', '.join(known)}" if known
                             else f"robot {str(spec)!r} is not a file, and this install has no robot files in "
                                  f"{ROBOTS_DIR}; give a robot file's path")
    known = sorted(p.name for p in ROBOTS_DIR.glob("*") if p.suffix in (".xml", ".urdf")) if in_robots else []
    if path.exists():  # (/dev/null, a FIFO: "not found" sent the user looking for a typo)
        raise RobotFileError(f"robot file {path} is a directory" if path.is_dir() else
                             f"robot file {path} is not a regular file (a device, a FIFO or a socket)")
    raise RobotFileError(f"robot file not found: {path}"
                         + (f"; the shipped robot files are {', '.join(known)}" if known else ""))


# attributes of placements, sizes and inertias, which must be finite (a URDF <mass>'s value too), and of bounds, where
# +-inf means none; elements no parser of the planner's reads (a URDF's <gazebo> plugin parameters) are not looked at
_FINITE_ATTRIBUTES = frozenset({"pos", "quat", "euler", "axisangle", "xyaxes", "zaxis", "fromto", "size", "mass",
                                "diaginertia", "fullinertia", "axis", "ref", "xyz", "rpy", "ixx", "ixy", "ixz", "iyy",
                                "iyz", "izz"})
_UNREAD_ELEMENTS = frozenset({"gazebo", "transmission", "ros2_control", "plugin", "extension", "custom"})
_BOUND_ATTRIBUTES = frozenset({"range", "ctrlrange", "forcerange", "actuatorfrcrange", "lower", "upper", "effort",
                               "velocity"})


def _numbers(value: str) -> list[float]:
    """The attribute's numbers when every whitespace-separated word of it is one (floats: "nan", "inf" too), else []."""
    try:
        return [float(word) for word in value.split()]
    except ValueError:
        return []


def _element_path(element: ET.Element, parents: dict) -> str:
    """`<tag name='n'>`, after its nearest named ancestor when it has no name itself (a URDF's <mass> inside link
    'thigh': `<link name='thigh'> ... <mass>`)."""
    def shown(e: ET.Element) -> str:
        return f"<{e.tag} name={e.get('name')!r}>" if e.get("name") else f"<{e.tag}>"

    ancestor = parents.get(element)
    while ancestor is not None and not ancestor.get("name") and ancestor in parents:
        ancestor = parents[ancestor]
    if element.get("name") or ancestor is None or not ancestor.get("name"):
        return shown(element)
    return f"{shown(ancestor)} ... {shown(element)}"


# a robot file's bytes: expat rescans a long token at every buffer fill (a 40 MB comment took 78 s, 200 MB did not end
# in 5 minutes) and the file is parsed several times; the largest shipped or example-robot-data file is ~0.1 MB
MAX_ROBOT_FILE_BYTES = 20 * 2**20
# element nesting: MuJoCo's XML reader refuses files about this deep (499 levels and more, with its own message), and
# Pinocchio's MJCF parser crashed (a segmentation fault, no message) at 30000 levels, inside an element it does not read
MAX_XML_DEPTH = 500


class _DoctypeSeen(ET.TreeBuilder):
    """A tree builder that notes a <!DOCTYPE> (ElementTree calls doctype() on its target)."""

    doctype_seen = False

    def doctype(self, name, pubid, system):
        self.doctype_seen = True


def detect_format(path: Path) -> RobotFormat:
    """MJCF or URDF from the XML root element (<mujoco> or <robot>); RobotFileError for a file larger than
    MAX_ROBOT_FILE_BYTES, nested deeper than MAX_XML_DEPTH or with a <!DOCTYPE>, a file it names that is no regular
    file, a placement, size or inertia that is not finite, a bound that is nan, a name with a control (unprintable)
    character, or an MJCF file not named .xml."""
    try:
        size = path.stat().st_size
        if size > MAX_ROBOT_FILE_BYTES:
            raise RobotFileError(f"{path} is {size} bytes, more than the {MAX_ROBOT_FILE_BYTES} (20 MB) a robot file "
                                 "may be (robot files are kilobytes; meshes belong in their own files)")
        builder = _DoctypeSeen()
        root = ET.parse(path, ET.XMLParser(target=builder)).getroot()
    except ET.ParseError as exc:
        raise RobotFileError(f"malformed XML in {path}: {exc}") from None
    except OSError as exc:
        raise read_error(path, exc, RobotFileError, "cannot read robot file") from None
    if builder.doctype_seen:  # MuJoCo's reader ends it at its first '>': a model inside an entity value became its root
        raise RobotFileError(f"{path} has a <!DOCTYPE>, which neither MuJoCo nor URDF reads, and MuJoCo reads such a "
                             "file otherwise than Pinocchio: remove it")
    formats = {"mujoco": RobotFormat.MJCF, "robot": RobotFormat.URDF}
    if root.tag not in formats:
        raise RobotFileError(f"{path} is neither MJCF (<mujoco>) nor URDF (<robot>): root element <{root.tag}>")
    level, depth = [root], 0
    while level:  # level by level (iteratively: the depth is what is in question)
        depth += 1
        level = [child for element in level for child in element]
    if depth > MAX_XML_DEPTH:
        raise RobotFileError(f"{path} nests its elements {depth} deep, more than the {MAX_XML_DEPTH} MuJoCo's reader "
                             "takes")
    _refuse_special_files(path, root)
    parents = {child: parent for parent in root.iter() for child in parent}
    unread = {e for top in root.iter() if top.tag in _UNREAD_ELEMENTS for e in top.iter()}
    for element in (e for e in root.iter() if e not in unread):  # (Pinocchio spread a site's nan into an inertia)
        name = element.get("name") or (element.get("model") if element is root else None) or ""
        unprintable = next((c for c in name if not c.isprintable()), None)
        if unprintable is not None:  # a newline in a site's name split `check-model`'s and the report's lines in two
            named = _element_path(element, parents) if element.get("name") else f"<{root.tag} model={name!r}>"
            raise RobotFileError(f"{path}: {named} has a name with the unprintable character {unprintable!r}, which "
                                 "would break the lines that name it; rename it")
        for key, value in element.attrib.items():
            must_be_finite = key in _FINITE_ATTRIBUTES or (element.tag == "mass" and key == "value")
            numbers = _numbers(value) if must_be_finite or key in _BOUND_ATTRIBUTES else []
            finite = not must_be_finite or all(map(math.isfinite, numbers))
            if any(math.isnan(x) for x in numbers) or not finite:
                raise RobotFileError(f"{path}: {_element_path(element, parents)} {key}=\"{value}\" holds a number that "
                                     "is not finite; write a finite one")
    if formats[root.tag] is RobotFormat.MJCF and path.suffix != ".xml":  # (check-model failed, simulate went on)
        raise RobotFileError(f"{path} is MJCF, which MuJoCo reads only from a file whose name ends in .xml (it picks "
                             f"its reader by the ending): rename it to {path.name.split('.')[0] or path.name}.xml")
    return formats[root.tag]


# attributes that name a file MuJoCo (or the viewer) opens: MJCF's file= (a cube texture's six faces too), URDF's
# mesh filename=
_FILE_KEYS = ("file", "filename", *(f"file{side}" for side in ("right", "left", "up", "down", "front", "back")))


def _refuse_special_files(path: Path, root) -> None:
    """RobotFileError when a file the robot file or a file it includes names is a FIFO, a device or a directory where
    MuJoCo (or the viewer) would look for it: MuJoCo blocked reading a FIFO forever."""
    roots, seen = [(path, root)], {path.resolve()}
    for where_from, tree in roots:  # (grows as included files are read)
        for element in tree.iter("include"):
            target = _include_target(element.get("file"), where_from, path.parent)
            if target is not None and target.resolve() not in seen:
                seen.add(target.resolve())
                with contextlib.suppress(ET.ParseError, OSError, ValueError):  # (loading the robot says why)
                    roots.append((target, ET.parse(target).getroot()))
    compiler = {k: v for _, tree in roots for e in tree.iter("compiler") for k, v in e.attrib.items()}
    strip = compiler.get("strippath", "false") == "true"  # MuJoCo then reads the name's last part only
    asset = compiler.get("assetdir", "")
    # where MuJoCo looks: meshes, skins and height fields in meshdir (else assetdir), textures in texturedir (else
    # assetdir), the rest (an include) beside the file; a URDF's meshes beside it (a directory of the mesh's name
    # beside an MJCF file whose meshdir held the mesh was refused)
    where = {"mesh": compiler.get("meshdir", asset), "skin": compiler.get("meshdir", asset),
             "hfield": compiler.get("meshdir", asset), "texture": compiler.get("texturedir", asset)}
    for where_from, tree in roots:
        for element in tree.iter():
            for name in filter(None, (element.get(key) for key in _FILE_KEYS)):
                if "://" in name:  # (package:// paths are the viewer's to resolve)
                    continue
                name = Path(name).name if strip and element.tag != "include" else name
                candidate = path.parent / where.get(element.tag, "") / name
                with contextlib.suppress(OSError, ValueError):
                    if candidate.exists() and not candidate.is_file():
                        raise RobotFileError(f"{where_from}: <{element.tag}> names {name!r}, which is no regular file "
                                             f"({candidate} is a directory, a FIFO or a device): name a file")


def load_robot(spec: str | os.PathLike, floating: bool = False) -> Robot:
    """Parse a robot file with Pinocchio and collect its actuators and named points.

    spec: a robot file's path (.xml MJCF, .urdf) or a shipped robot's name ("capler": robots/capler.xml).
    floating: give a URDF robot a free-flyer root joint (an MJCF file declares its own <freejoint/>).
    """
    expect(spec, (str, os.PathLike), "load_robot's spec (a robot name or file)")
    floating = plain(floating)  # np.bool_
    expect(floating, bool, "load_robot's floating")  # "no" built a floating robot
    path = resolve_robot_path(spec)
    try:
        fmt = detect_format(path)
    except RobotFileError as exc:
        shadowed = [ROBOTS_DIR / f"{path.name}{ext}" for ext in (".xml", ".urdf")]
        if Path(spec) == Path(path.name) and not path.suffix and any(f.is_file() for f in shadowed):
            # an existing path wins, as everywhere; a stray file named `capler` made `plan capler` a parse error
            raise RobotFileError(f"{exc} (the file {path.name!r} in the working directory is read, not robots/"
                                 f"{path.name}; to use that one, give its path)") from None
        raise
    if floating and fmt is RobotFormat.MJCF:
        raise RobotFileError(f"{path}: floating applies to URDF only; an MJCF file declares its own <freejoint/>")
    printed: list[str] = []  # what the parser printed on descriptor 2: urdfdom's reason ("Error:   ...")
    try:
        with _quiet(printed):
            if fmt is RobotFormat.MJCF:
                model = pin.buildModelFromMJCF(str(path))
            else:
                model = pin.buildModelFromUrdf(str(path), pin.JointModelFreeFlyer()) if floating else pin.buildModelFromUrdf(str(path))
    except PlannerError:  # the environment's, not the file's
        raise
    except Exception as exc:  # Pinocchio raises bare RuntimeError/ValueError with its parser's text
        hint = (f" (the file includes {_included_tags(path)}: Pinocchio's MJCF parser skips <include>s; "
                "write them into the file: MuJoCo's mujoco.MjSpec.from_file(FILE).to_xml(), saved beside it, is the "
                "file in one)" if fmt is RobotFormat.MJCF and included_files(path) else
                " (the file's <default> comes after <worldbody>: Pinocchio's MJCF parser reads the classes only before "
                "their use; move <default> above <worldbody>)"
                if fmt is RobotFormat.MJCF and _defaults_late(path) else "")
        said = _parser_errors(printed)
        reason = _parser_message(exc).rstrip(".") + (": " + "; ".join(said) if said else "")
        if not hint and fmt is RobotFormat.MJCF and "no body found" in reason:  # (a robot whose bodies have no name)
            hint = " (Pinocchio's MJCF parser reads named bodies only: name every <body>)"
        if not hint and fmt is RobotFormat.MJCF and "min_effort are greater than max_effort" in reason:
            hint = f" ({_reversed_force_ranges(path)})"
        if not hint and fmt is RobotFormat.MJCF and _main_class_undeclared(path):  # MuJoCo compiles it: no hint there
            hint = (" (the file uses class \"main\", MuJoCo's name of the top-level <default>, which Pinocchio's MJCF "
                    "parser knows only when declared: write the top-level <default> as <default class=\"main\">, or "
                    "add one if the file has none)")
        if not hint and fmt is RobotFormat.MJCF:  # MuJoCo names the element (an unknown class: "unordered_map::at")
            try:
                _mujoco_model(path)
            except ValueError as mj:
                hint = f" ({mujoco_failure(path, mj, 'read')})"
        wrappers = wrapper_tags(ET.parse(path).getroot()) if fmt is RobotFormat.MJCF else []
        if not hint and wrappers:  # (a <frame> around the root body: "No such node (body)"; last, as the likeliest
            # cause of a file MuJoCo compiles, not before the specific ones: a harmless <frame> hid those)
            hint = (f" (the file has <{'> and <'.join(wrappers)}> elements, whose bodies, geoms and sites Pinocchio's "
                    "MJCF parser does not read: write them out with their own pos and orientation)")
        raise RobotFileError(f"Pinocchio cannot parse {path}: {reason}{hint}") from None
    # (an MJCF file was refused for another thread's "Error: ..." log line caught meanwhile)
    said = _parser_errors(printed) if fmt is RobotFormat.URDF else []
    if said:  # urdfdom returns a model without what it could not read (a thigh's `<mass value="1,782"/>`: no mass)
        raise RobotFileError(f"Pinocchio's URDF parser could not read part of {path}: {'; '.join(said)}; its model "
                             "would lack that element")
    if model.nv == 0 and fmt is RobotFormat.MJCF:  # (MuJoCo's reading, needed for the cause, is made below otherwise)
        with contextlib.suppress(ValueError):  # a file MuJoCo cannot compile: said where its reading is needed
            said = _second_tree(path, _mujoco_model(path), model)
            if said:
                raise RobotFileError(said)
    if model.nv == 0:  # nothing to simulate or plan (check-model crashed in Pinocchio's algorithms)
        raise RobotFileError(f"{path}: the robot has no degrees of freedom (no joints); a robot needs at least one")
    _refuse_negative_inertia(path, model)
    world_sites, unread_sites, (ground_z, ground_geom), unnamed, scenery = (), (), (None, ""), (), ()
    if fmt is RobotFormat.MJCF:
        actuators, dof_names, passive, world_sites, unread_sites, (ground_z, ground_geom), unnamed, \
            (colliding, scenery) = _mjcf_info(path, model)
    else:
        actuators, dof_names, passive = _urdf_info(model)
        root = ET.parse(path).getroot()
        colliding = tuple(link.get("name", "") for link in root.iter("link") if link.find("collision") is not None)
        colliding = tuple(name for name in colliding if name and _carrier(model, name))  # (a world link's: scenery)
        _refuse_joint_mistakes(path, root)  # (before the limits' checks: "swap them" of a limit without an upper)
        lower, upper = model.lowerPositionLimit, model.upperPositionLimit
        one = [(model.names[j], model.joints[j].idx_q) for j in range(1, model.njoints) if model.joints[j].nq == 1]
        inverted = [f"{name!r} ({lower[i]:g} > {upper[i]:g})" for name, i in one if lower[i] > upper[i]]
        if inverted:  # MuJoCo reads such a joint as unlimited (check-model named that, not the swap)
            raise RobotFileError(f"{path}: joint {', '.join(inverted)}: its <limit lower> is above its upper; "
                                 "swap them")
        locked = [f"{name!r} ({lower[i]:g})" for name, i in one if lower[i] == upper[i]]
        if locked:  # (no lower and upper read as 0: the reading differences named MuJoCo's unlimited joint, no fix)
            raise RobotFileError(f"{path}: joint {', '.join(locked)}: its <limit lower> equals its upper (both are 0 "
                                 "when not given): Pinocchio locks the joint there, MuJoCo ignores the limit; give "
                                 "lower < upper")
        passive += _urdf_couplings(root)
        if any(True for _ in root.iter("transmission")):
            warnings.warn(f"{path}: its <transmission> elements are not read: a URDF joint's motor is its <limit "
                          "effort> (> 0) with gear 1, and a joint without one is not actuated")
    return Robot(
        path=path,
        format=fmt,
        model=model,
        actuators=actuators,
        points=tuple(p for p in _point_frames(model) if p not in unnamed),
        dof_names=dof_names,
        sha256=file_sha256(path),
        passive=passive,
        floating=floating,
        world_sites=world_sites,
        unread_sites=unread_sites,
        ground_z=ground_z,
        ground_geom=ground_geom,
        colliding=colliding,
        scenery=scenery,
        degrees=fmt is RobotFormat.MJCF and _in_degrees(path),
    )


def file_sha256(path: Path) -> str:
    """The hex SHA-256 of a robot file's contents and, for an MJCF file, of the files it includes (`<include file=..>`,
    recursively, each after its name as written): what tells two robot files apart (Robot.sha256). An edit of an
    included actuator block was replayed by validate as the planned robot. A file that includes nothing hashes as its
    bytes alone (the hash results have kept since robot_sha256 was added)."""
    path = Path(path)
    digest = hashlib.sha256(path.read_bytes())
    for name, data in included_files(path):
        digest.update(b"\0" + name.encode() + b"\0" + data)
    return digest.hexdigest()


def included_files(path: Path) -> list[tuple[str, bytes]]:
    """(file attribute, contents) of each file the MJCF file at path includes, recursively, depth first."""
    return _included(path, path.parent, {path.resolve()})


def _included(path: Path, model_dir: Path, seen: set) -> list[tuple[str, bytes]]:
    """(file attribute, contents) of each file an MJCF file includes, depth first; a file that does not parse or an
    include that cannot be read is left out (loading the robot reports those)."""
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError, ValueError):
        return []
    found = []
    for element in root.iter("include"):
        name = element.get("file")
        target = _include_target(name, path, model_dir)
        if target is None or target.resolve() in seen:
            continue
        seen.add(target.resolve())
        try:
            found.append((name, target.read_bytes()))
        except OSError:  # unreadable: loading the robot says so
            continue
        found += _included(target, model_dir, seen)
    return found


def _included_tags(path: Path) -> str:
    """The top-level elements of the files an MJCF file includes, e.g. "<default>, <worldbody>"."""
    tags = []
    for _, data in included_files(path):
        with contextlib.suppress(ET.ParseError):
            tags += [e.tag for e in ET.fromstring(data) if isinstance(e.tag, str) and e.tag not in tags]
    return ", ".join(f"<{t}>" for t in tags) or "a file"


def _include_target(name: str | None, path: Path, model_dir: Path) -> Path | None:
    """The file an <include file=name> of the MJCF file at path reads (MuJoCo: the main file's directory first),
    None when there is none."""
    candidates = [model_dir / name, path.parent / name] if name else []
    return next((c for c in candidates if c.is_file()), None)


def _point_frames(model: pin.Model) -> dict[str, int]:
    """Named points: operational frames (MJCF sites) and bodies (URDF links), the universe excluded. A site and a
    body of the same name are the site (docs/tasks.md: a contact point is an MJCF site; the body's frame had won)."""
    points: dict[str, int] = {}  # in the frames' order
    for fid, frame in enumerate(model.frames):
        # the universe and a "world" link are fixed, no points; a site of the robot's may be named so (it was left
        # out: "unknown contact point 'world'; valid contact points: (none)")
        if frame.type not in (pin.FrameType.OP_FRAME, pin.FrameType.BODY) or fid == 0 or (
                frame.type == pin.FrameType.BODY and frame.name in ("universe", "world")):
            continue
        if frame.name not in points or (frame.type == pin.FrameType.OP_FRAME
                                        and model.frames[points[frame.name]].type != pin.FrameType.OP_FRAME):
            points[frame.name] = fid
    return points


def _refuse_joint_mistakes(path: Path, root) -> None:
    """RobotFileError naming a joint of the URDF (path, its parsed root element) whose <axis xyz> is zero (Pinocchio
    reads a joint that moves nothing, which simulate and plan refused as a body lighter than MIN_DOF_INERTIA: its
    thigh weighed 1 kg), whose <limit> gives one of lower and upper (URDF reads the other as 0, MuJoCo the joint as
    unlimited: the refusal named MuJoCo's unlimited range, or said "swap them"). (A negative <limit velocity> is
    Pinocchio's parse error.)"""
    for joint in root.iter("joint"):
        name, axis, limit = joint.get("name", "?"), joint.find("axis"), joint.find("limit")
        if joint.get("type") not in ("revolute", "prismatic", "continuous"):
            continue
        with contextlib.suppress(ValueError):  # (a malformed one is the parser's error, said before this)
            # (1e-200 passed Pinocchio, and MuJoCo found it "too small")
            if axis is not None and np.max(np.abs(np.array(axis.get("xyz", "1 0 0").split(), float))) < MIN_AXIS:
                raise RobotFileError(f"{path}: joint {name!r}: its <axis xyz> is zero (every component below "
                                     f"{MIN_AXIS:g}); give the direction it turns or slides along (e.g. \"0 1 0\")")
        sides = [side for side in ("lower", "upper") if limit is not None and limit.get(side) is not None]
        if joint.get("type") != "continuous" and len(sides) == 1:
            missing = "upper" if sides == ["lower"] else "lower"
            raise RobotFileError(f"{path}: joint {name!r}: its <limit> gives {sides[0]} but no {missing}, which URDF "
                                 f"reads as 0 and MuJoCo as no limit; give both lower and upper")


def _urdf_couplings(root) -> tuple[str, ...]:
    """A URDF's <mimic> joints (root: its parsed root element) as Robot.passive entries: Pinocchio reads such a joint
    as independent, MuJoCo as an equality constraint (MJCF's <equality> is refused), so simulate and plan refuse them;
    check-model compares the tree, which both read alike (a gripper's mimic finger)."""
    return tuple(f"joint {j.get('name', '?')!r}: <mimic> (a coupling MuJoCo makes an equality constraint)"
                 for j in root.iter("joint") if j.find("mimic") is not None)


def _second_tree(path: Path, mj, model: pin.Model) -> str | None:
    """The error when <worldbody> holds several bodies and Pinocchio, whose MJCF parser reads the first of them only,
    has other degrees of freedom than MuJoCo's compiled model mj (a marker body placed before the robot left a robot
    "without joints", a second moving body after it was blamed on a <frame>), else None. Scenery bodies without joints
    after the robot stay allowed (MuJoCo's replay keeps them out of collisions)."""
    roots = [mj.body(b).name or f"body {b}" for b in range(1, mj.nbody) if mj.body_parentid[b] == 0]
    if len(roots) < 2 or mj.nv == model.nv:
        return None
    return (f"{path}: <worldbody> holds {len(roots)} bodies ({', '.join(map(repr, roots))}) and Pinocchio's MJCF "
            f"parser reads the first one only ({roots[0]!r}: {model.nv} of MuJoCo's {mj.nv} degrees of freedom): a "
            "robot is one body tree; put its root body first, and scenery (bodies without joints) after it or as "
            "geoms and sites of <worldbody> itself")


def _parser_errors(printed: list[str]) -> list[str]:
    """urdfdom's "Error:" lines (they start so) in what was printed (`_quiet`), once each, without the prefix."""
    errors = (ln.split("Error:", 1)[1].strip() for ln in "".join(printed).splitlines()
              if ln.lstrip().startswith("Error:"))
    return [ln for ln in dict.fromkeys(errors) if ln]


def _refuse_negative_inertia(path: Path, model: pin.Model) -> None:
    """RobotFileError naming a body whose mass is negative or whose rotational inertia is not positive semi-definite
    (a URDF ixx = -1, a mass of -5 kg): its dynamics were garbage (check-model: mass errors of 1e115); or one whose
    principal moments break the triangle inequality, which MuJoCo refuses."""
    for jid in range(1, model.njoints):
        inertia = model.inertias[jid]
        if not all(np.all(np.isfinite(x)) for x in (inertia.mass, inertia.inertia, inertia.lever)):
            # (an MJCF `pos="0,0,0.1"` is read as 2e243 by Pinocchio: eigvalsh raised LinAlgError on the nan inertia)
            raise RobotFileError(f"{path}: the body of joint {model.names[jid]!r} has a mass or inertia that is not "
                                 f"finite as Pinocchio reads the file (mass {inertia.mass:g} kg, centre of mass "
                                 f"{np.asarray(inertia.lever).tolist()} m): is a number written with commas?")
        if not (inertia.mass >= 0.0 and np.all(np.linalg.eigvalsh(inertia.inertia) >= -1e-12)):
            raise RobotFileError(f"{path}: the body of joint {model.names[jid]!r} has mass {inertia.mass:g} kg and rotational "
                                 f"inertia eigenvalues {np.round(np.linalg.eigvalsh(inertia.inertia), 9).tolist()} kg m^2; "
                                 "masses and inertias must be non-negative")
        a, b, c = np.linalg.eigvalsh(inertia.inertia)  # ascending
        if a + b < c * (1.0 - 1e-9) - 1e-12:  # no body has them (MuJoCo refuses the file; a URDF was simulated first)
            raise RobotFileError(f"{path}: the body of joint {model.names[jid]!r} has principal moments of inertia "
                                 f"{np.round([a, b, c], 9).tolist()} kg m^2, and no rigid body's smaller two sum to "
                                 f"less than the largest (A + B >= C){_balanced(path)}")


def _balanced(path: Path) -> str:
    """Why MuJoCo accepts the file's impossible inertia when a <compiler balanceinertia="true"> is what makes it (a
    user saw MuJoCo load it and the refusal name the triangle inequality alone, session 69's tester), else ""."""
    with contextlib.suppress(ET.ParseError, OSError):
        if any(c.get("balanceinertia") == "true" for c in ET.parse(path).getroot().iter("compiler")):
            return ("; MuJoCo accepts the file because its <compiler balanceinertia=\"true\"> replaces such moments "
                    "by their mean, which Pinocchio does not, so the two would simulate different bodies: write "
                    "moments that satisfy A + B >= C")
    return ""


def _urdf_info(model: pin.Model) -> tuple[tuple[Actuator, ...], tuple[str, ...], tuple[str, ...]]:
    """URDF: every 1-DoF joint with a positive, finite effort limit is a motor with gear 1; the joints' <dynamics>
    damping and friction are the passive terms (Robot.passive)."""
    actuators, dof_names = [], []
    for jid in range(1, model.njoints):
        joint, jname = model.joints[jid], model.names[jid]
        dof_names += [jname] if joint.nv == 1 else [f"{jname}_{i}" for i in range(joint.nv)]
        if joint.nv != 1:
            continue
        effort = float(model.effortLimit[joint.idx_v])
        if 0.0 < effort < np.inf:
            actuators.append(Actuator(jname, joint.idx_v, 1.0, -effort, effort))
    passive = _passive_terms(dof_names, (("damping", model.damping), ("friction", model.friction)))
    return tuple(actuators), tuple(dof_names), passive


def _unnamed(name: str, taken) -> str:
    """The name of an element the file leaves unnamed: `name`, primed until no named element of its kind has it (an
    unnamed motor's "actuator_0" and a motor named "actuator_0" were one key of the validation's saturations)."""
    while name in taken:
        name += "'"
    return name


def motor_names(mj) -> list[str]:
    """The MuJoCo model mj's actuator names (nu,), an unnamed one's actuator_i primed apart from the named ones."""
    taken = {mj.actuator(i).name for i in range(mj.nu)}
    return [mj.actuator(i).name or _unnamed(f"actuator_{i}", taken) for i in range(mj.nu)]


def _mjcf_info(path: Path, model: pin.Model) -> tuple[tuple[Actuator, ...], tuple[str, ...], tuple[str, ...],
                                                     tuple[str, ...], tuple[str, ...], tuple[float | None, str],
                                                     tuple[str, ...], tuple[tuple[str, ...], tuple[str, ...]]]:
    """MJCF: joint motors, joint names, passive joint terms (Robot.passive), the sites on the world body
    (Robot.world_sites), those Pinocchio's parser skips (Robot.unread_sites), the ground plane's
    height and geom (Robot.ground_z, Robot.ground_geom) read from MuJoCo's compiled model of the same
    file, the names Pinocchio made up for unnamed sites (no points: MuJoCo's replay has no site of
    that name), and the bodies with colliding geoms and the world's colliding geoms (Robot.colliding, Robot.scenery);
    Pinocchio's joint limits made MuJoCo's (_mujoco_limits).

    MuJoCo and Pinocchio both number degrees of freedom depth-first through the tree, so MuJoCo's
    dof address is Pinocchio's velocity index (check-model proves it by comparing mass matrices).
    """
    import mujoco

    try:
        mj = _mujoco_model(path)
    except ValueError as exc:
        raise RobotFileError(mujoco_failure(path, exc)) from None
    if mj.nv != model.nv:
        unnamed = ("" if all(mj.body(b).name for b in range(1, mj.nbody))
                   else ", nor a body without a name: name every <body>")
        raise RobotFileError(_second_tree(path, mj, model) or (
            f"{path}: MuJoCo has {mj.nv} DoF but Pinocchio {model.nv} (a body or joint inside a <frame>, or an "
            f"<include>, is not read by Pinocchio's MJCF parser{unnamed})"))
    if mj.neq:  # Pinocchio's model has no such coupling: the planner's motion would break it
        raise RobotFileError(f"{path}: {mj.neq} <equality> constraint(s); the planner models kinematic trees without "
                             "equality constraints")
    # Pinocchio's MJCF parser ignores <option gravity>; the file's value is MuJoCo's.
    model.gravity = pin.Motion(np.array(mj.opt.gravity, dtype=float), np.zeros(3))
    dofs = np.bincount(mj.dof_jntid, minlength=mj.njnt)  # a joint of several (free, ball) names each: "root_0", ...

    joint_names = {mujoco.mj_id2name(mj, mujoco.mjtObj.mjOBJ_JOINT, j) for j in range(mj.njnt)}

    def dof_name(i: int) -> str:
        j = int(mj.dof_jntid[i])
        name = mujoco.mj_id2name(mj, mujoco.mjtObj.mjOBJ_JOINT, j) or _unnamed(f"dof_{i}", joint_names)
        return f"{name}_{i - int(mj.jnt_dofadr[j])}" if dofs[j] > 1 else name

    dof_names = tuple(dof_name(i) for i in range(mj.nv))
    actuators = []
    for i, name in enumerate(motor_names(mj)):
        # jointinparent is joint's transmission on a hinge or slide (they differ on ball and free joints only); the
        # joint's type is read for it alone (a site's or tendon's id is no joint's), as an int (numpy's int is no
        # member of a tuple of mjtJoint values)
        one_dof = mj.actuator_trntype[i] == mujoco.mjtTrn.mjTRN_JOINTINPARENT and int(
            mj.jnt_type[mj.actuator_trnid[i, 0]]) in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE)
        if not (mj.actuator_trntype[i] == mujoco.mjtTrn.mjTRN_JOINT or one_dof):
            raise RobotFileError(f"{path}: actuator {name!r} does not act on a joint; only joint motors are supported")
        # a <position>, <velocity> or <general> actuator is a servo or has dynamics: its force is not gear * ctrl
        if (mj.actuator_dyntype[i] != mujoco.mjtDyn.mjDYN_NONE or mj.actuator_biastype[i] != mujoco.mjtBias.mjBIAS_NONE
                or mj.actuator_gaintype[i] != mujoco.mjtGain.mjGAIN_FIXED or mj.actuator_gainprm[i, 0] != 1.0):
            raise RobotFileError(f"{path}: actuator {name!r} is not a plain motor (force = gear * ctrl): position, velocity "
                                 "and general actuators (gain, bias or dynamics) are not supported; use <motor>")
        jnt = mj.actuator_trnid[i, 0]
        gear = float(mj.actuator_gear[i, 0])
        if gear == 0.0:  # its force gear * ctrl is always 0 (a PD law divided by it)
            raise RobotFileError(f"{path}: actuator {name!r} has gear 0, so it exerts no force; give it a nonzero gear "
                                 "or remove it")
        for what, limited, values in (("ctrlrange", mj.actuator_ctrllimited[i], mj.actuator_ctrlrange[i]),
                                      ("forcerange", mj.actuator_forcelimited[i], mj.actuator_forcerange[i])):
            if not limited and np.any(values != 0.0):  # autolimits drops a range whose lower is not below its upper:
                # a sign typo unbounded the motor silently
                flag = what.replace("range", "limited")  # (an ordered range told to "write the lower bound first")
                why, fix = (("lower not below upper", "write the lower bound first, or remove the range")
                            if values[0] >= values[1] else
                            (f'{flag}="false"', f'remove {flag}="false" (or its default class\'s), or the range'))
                raise RobotFileError(f"{path}: actuator {name!r}: its {what} {values[0]:g} {values[1]:g} is no "
                                     f"limit to MuJoCo ({why}); {fix}")
        lo, hi = (mj.actuator_ctrlrange[i] if mj.actuator_ctrllimited[i] else (-np.inf, np.inf))
        if mj.actuator_forcelimited[i]:  # MuJoCo clamps the motor's force ctrl (gain 1) to forcerange before the gear
            flo, fhi = mj.actuator_forcerange[i]
            lo, hi = max(lo, float(flo)), min(hi, float(fhi))
        if mj.jnt_actfrclimited[jnt] and np.sum(mj.actuator_trnid[:, 0] == jnt) == 1:  # the joint's actuatorfrcrange:
            # it clamps the joint's force gear * ctrl (several motors: check.reading_differences)
            flo, fhi = sorted(np.asarray(mj.jnt_actfrcrange[jnt], float) / gear)
            lo, hi = max(lo, flo), min(hi, fhi)
        if lo > hi:  # the plan's bounds would be empty (they were kept inverted)
            raise RobotFileError(f"{path}: actuator {name!r}: its ctrlrange, its forcerange (before the gear) and the "
                                 "joint's actuatorfrcrange / gear do not overlap; no control is allowed")
        actuators.append(Actuator(name, int(mj.jnt_dofadr[jnt]), gear, float(lo), float(hi)))
    _mujoco_limits(path, model, mj, mujoco)
    first = np.array([mj.jnt_dofadr[mj.dof_jntid[i]] == i for i in range(mj.nv)])  # a joint's stiffness, once
    # a term the file's <flag damper/spring/frictionloss="disable"/> turns off MuJoCo does not apply (it was refused)
    on = {flag: not mujoco_disabled(mj, flag) for flag in ("damper", "spring", "frictionloss")}
    stiffness = np.where(first[:, None], as_written(mj.jnt_stiffness, mj.jnt_stiffnesspoly)[mj.dof_jntid], 0.0)
    passive = _passive_terms(dof_names, (("damping", as_written(mj.dof_damping, mj.dof_dampingpoly) * on["damper"]),
                                         ("frictionloss", mj.dof_frictionloss * on["frictionloss"]),
                                         ("stiffness", stiffness * on["spring"])))
    site_names = [mujoco.mj_id2name(mj, mujoco.mjtObj.mjOBJ_SITE, s) or "" for s in range(mj.nsite)]
    world_sites = tuple(name for s, name in enumerate(site_names) if name and mj.site_bodyid[s] == 0)
    frames = {f.name for f in model.frames if f.type == pin.FrameType.OP_FRAME}  # (a body of the site's name hid it)
    unread = tuple(name for s, name in enumerate(site_names) if name and mj.site_bodyid[s] != 0 and name not in frames)
    ground = mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_GEOM, "ground")
    planes = [g for g in range(mj.ngeom) if mj.geom_bodyid[g] == 0 and mj.geom_type[g] == mujoco.mjtGeom.mjGEOM_PLANE]
    _, x, y, _ = mj.geom_quat[planes[0]] if planes else (1.0, 0.0, 0.0, 0.0)
    # a Menagerie-style "floor": the file's one plane is its ground if level (a tilted one is scenery: a slope read as
    # flat ground had the validation's own plane replace it)
    if ground < 0 and len(planes) == 1 and 1.0 - 2.0 * (x * x + y * y) >= 1.0 - 1e-9:
        ground = planes[0]
    ground_z = (float(mj.geom_pos[ground][2]) if ground >= 0 and mj.geom_type[ground] == mujoco.mjtGeom.mjGEOM_PLANE
                and mj.geom_bodyid[ground] == 0 else None)
    ground_geom = (mujoco.mj_id2name(mj, mujoco.mjtObj.mjOBJ_GEOM, ground) or f"geom {ground}") if ground >= 0 else ""
    # (a box in a jointless body is as fixed as one in <worldbody>: a step written either way was passed through; a
    # jointless body that carries the robot, a pedestal or an arm's base link, is the robot's own)
    carries = set()
    for body in range(mj.nbody):
        b = body if mj.body_jntnum[body] else 0
        while b:  # (the jointed body and its ancestors up to the world)
            carries.add(b)
            b = mj.body_parentid[b]
    scenery = tuple(mujoco.mj_id2name(mj, mujoco.mjtObj.mjOBJ_GEOM, g) or f"geom {g}" for g in range(mj.ngeom)
                    if mj.body_weldid[mj.geom_bodyid[g]] == 0 and mj.geom_bodyid[g] not in carries and g != ground
                    and (mj.geom_contype[g] or mj.geom_conaffinity[g]))
    unnamed = tuple(f.name for f in model.frames if f.type == pin.FrameType.OP_FRAME and f.name not in site_names)
    colliding = _colliding_bodies(mj)
    return (tuple(actuators), dof_names, passive, world_sites, unread, (ground_z, ground_geom), unnamed,
            (colliding, scenery))


def _carrier(model: pin.Model, body: str) -> int:
    """The index of the joint that moves an MJCF body or URDF link, 0 for one fixed to the world (or unknown)."""
    frame = model.getFrameId(body, pin.FrameType.BODY)
    return int(model.frames[frame].parentJoint) if frame < model.nframes else 0


def _colliding_bodies(mj) -> tuple[str, ...]:
    """The moving bodies of an MJCF model with a geom that can touch a geom of the world (or, without a geom named
    ground, the validation's plane, contype = conaffinity = 1): contype and conaffinity bits that meet, or an explicit
    <pair> with a world geom. Robot.colliding."""
    import mujoco

    welded = {int(b) for b in range(mj.nbody) if mj.body_weldid[b] == 0}
    world = [g for g in range(mj.ngeom) if int(mj.geom_bodyid[g]) in welded]
    bits = [(int(mj.geom_contype[w]), int(mj.geom_conaffinity[w])) for w in world]
    if mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_GEOM, "ground") < 0:  # (the validation's own plane: 1/1)
        bits.append((1, 1))
    paired = {int(g) for a, b in zip(mj.pair_geom1, mj.pair_geom2) if a in world or b in world for g in (a, b)}
    bodies = sorted({int(mj.geom_bodyid[g]) for g in range(mj.ngeom) if int(mj.geom_bodyid[g]) not in welded and (
        g in paired or any(int(mj.geom_contype[g]) & conaffinity or contype & int(mj.geom_conaffinity[g])
                           for contype, conaffinity in bits))})
    return tuple(mj.body(b).name or f"body {b}" for b in bodies)


def _mujoco_limits(path, model: pin.Model, mj, mujoco) -> None:
    """Pinocchio's hinge and slide joint limits set to MuJoCo's: none where MuJoCo reads the joint as unlimited
    (limited="false", or no range: Pinocchio's MJCF parser keeps a range the file declares unlimited), MuJoCo's range
    where it is limited (Pinocchio's parser shifts a hinge's range by its ref)."""
    lower, upper = np.array(model.lowerPositionLimit, float), np.array(model.upperPositionLimit, float)  # copies
    for j in range(mj.njnt):
        if int(mj.jnt_type[j]) not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
            continue
        # by MuJoCo's qpos address, as the actuators and dof_names are: Pinocchio merges a body's several joints into
        # one "Composite_<first>" joint, so a planar base's slide "z" had no Pinocchio joint of its name (its range
        # kept Pinocchio's degrees-to-radians reading of its metres, and the file was refused)
        i = int(mj.jnt_qposadr[j])
        lo, hi = mj.jnt_range[j]
        # autolimits drops a range whose lower is not below its upper: a sign typo, or "0.2 0.2" (a joint held at one
        # value) planned as unlimited, silently; "0 0" is the default, no range
        if not mj.jnt_limited[j] and (lo > hi or lo == hi != 0.0):
            name = mujoco.mj_id2name(mj, mujoco.mjtObj.mjOBJ_JOINT, j) or f"joint_{j}"
            raise RobotFileError(f"{path}: joint {name!r}: its range {lo:g} {hi:g} is no limit to MuJoCo (lower not "
                                 "below upper); give a lower bound below the upper, or remove the range")
        lower[i], upper[i] = mj.jnt_range[j] if mj.jnt_limited[j] else (-np.inf, np.inf)
    model.lowerPositionLimit, model.upperPositionLimit = lower, upper


def _passive_terms(dof_names, per_dof) -> tuple[str, ...]:
    """The file's joint damping, stiffness and friction loss, as "joint 'hip': damping 5" or, with polynomial terms,
    "joint 'hip': damping 0 0.5" (none: ()). per_dof: (label, (nv,) or (nv, k) values) pairs."""
    return tuple(f"joint {dof_names[i]!r}: {label} {numbers_text(values[i])}"
                 for label, values in per_dof for i in range(len(dof_names)) if np.any(values[i] != 0.0))


def as_written(linear, poly) -> np.ndarray:
    """A damping or stiffness attribute as the file writes it, (n, 1 + k): MuJoCo keeps damping="0 0.5" as dof_damping
    0 and dof_dampingpoly (0.5, 0), where "dampingpoly 0.5 0" named no attribute of the file (session 60's tester)."""
    return np.column_stack([np.asarray(linear, float), np.asarray(poly, float)])


def numbers_text(values) -> str:
    """A number or a vector as the file would write it, trailing zeros of a vector dropped: "0.5", "0 0.5"."""
    values = np.atleast_1d(np.asarray(values, float))
    kept = max(1, int(np.flatnonzero(values)[-1]) + 1) if np.any(values) else 1
    return " ".join(f"{x:g}" for x in values[:kept])


def mujoco_disabled(mj, flag: str) -> bool:
    """Whether the compiled MuJoCo model mj has <option><flag FLAG="disable"/> (flag: "damper", "limit", ...)."""
    import mujoco

    return bool(mj.opt.disableflags & int(getattr(mujoco.mjtDisableBit, f"mjDSBL_{flag.upper()}")))


# A URDF link with a joint but no mass (the carriage of a planar base made of two prismatic joints) is fine for
# Pinocchio, but MuJoCo refuses a moving body without mass and inertia: it gets this much (and MASSLESS_LINK_INERTIA
# [kg m^2]). Every link below the carriage moves with its joint, so the carriage's mass only adds to the mass matrix
# entries that already hold the whole robot's (Capler: 1e-12 of 6.3 kg).
MASSLESS_LINK_KG = 1e-12
MASSLESS_LINK_INERTIA = 1e-12


@contextlib.contextmanager
def mujoco_warnings(handler):
    """MuJoCo's warnings go to handler(message) instead of its own, which prints them on stderr, through `-q`, and
    appends them to MUJOCO_LOG.TXT in the caller's working directory. The previous handler is restored."""
    import mujoco

    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(handler)
    try:
        yield
    finally:
        mujoco.set_mju_user_warning(previous)


def _mujoco_model(path: Path):
    """MuJoCo's compiled model of the MJCF file at path, its warnings held back: MuJoCo printed them raw (a deprecated
    `settotalmass` went to stderr and into MUJOCO_LOG.TXT in the working directory), and mujoco_spec's reading of the
    same file, which the commands make too, says them as Python warnings."""
    import mujoco

    with mujoco_warnings(lambda message: None):
        return mujoco.MjModel.from_xml_path(str(path))


def mujoco_spec(robot: Robot, sites: Sequence[str] = (), check_order: bool = True):
    """The robot file as MuJoCo reads it, as an editable mujoco.MjSpec (the file is untouched).

    MJCF: the file. URDF: MuJoCo's URDF parser without the mesh geoms, plus what MJCF states and URDF
    does not: a site named after each link in `sites` at the link's origin, a joint motor per
    `robot.actuators` entry (its gear and control range, so MuJoCo's nu is the planner's), and
    MASSLESS_LINK_KG on each link that has a joint but no mass. Raises RobotFileError when MuJoCo
    cannot read the file or (check_order) orders a URDF's joints differently from Pinocchio, UnknownNameError for a
    site that names no link.
    """
    import mujoco

    said: list[str] = []
    try:
        with mujoco_warnings(said.append):
            # MuJoCo picks its reader by the file name's ending (a URDF named .URDF, or with none: "could not find
            # decoder for resource"); a URDF includes no files, so its text reads the same
            by_name = robot.format is RobotFormat.MJCF or robot.path.suffix in (".urdf", ".xml")
            spec = mujoco.MjSpec.from_file(str(robot.path)) if by_name else mujoco.MjSpec.from_string(
                robot.path.read_text())
    except ValueError as exc:
        raise RobotFileError(mujoco_failure(robot.path, exc, "read")) from None
    for message in dict.fromkeys(said):
        warnings.warn(f"MuJoCo reading {robot.path}: {message}", stacklevel=2)
    if robot.format is RobotFormat.MJCF:
        return spec
    # MuJoCo loads a mesh when it compiles (a URDF's package:// paths are not files); the planner models no link's
    # geometry and takes inertias from <inertial> only, so meshes go and links without <inertial> stay massless (a
    # primitive <collision> on such a link weighed 0.113 kg in MuJoCo, mass inferred from the geom, 0 in Pinocchio)
    spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_FALSE
    for geom in [g for g in spec.geoms if g.type == mujoco.mjtGeom.mjGEOM_MESH]:
        spec.delete(geom)
    for mesh in list(spec.meshes):
        spec.delete(mesh)
    links = [b.name for b in spec.bodies if b.name != "world"]
    for name in dict.fromkeys(sites):
        if name not in links:
            raise UnknownNameError("URDF link", name, links)
        spec.body(name).add_site(name=name, pos=[0.0, 0.0, 0.0])
    for body in (b for b in spec.bodies if b.joints):
        if body.mass == 0.0:
            body.mass = MASSLESS_LINK_KG
        full = np.nan_to_num(np.asarray(body.fullinertia, float))
        # (a link's own inertia, which Pinocchio keeps, stays; a point mass's zero inertia, which MuJoCo refused to
        # compile, gets the massless link's)
        if not np.any(body.inertia) and not np.any(full):
            body.inertia = [MASSLESS_LINK_INERTIA] * 3
            # unset (a URDF's full inertia): MuJoCo refuses both
            body.fullinertia = [np.nan, 0.0, 0.0, 0.0, 0.0, 0.0]
    for a in robot.actuators:
        spec.add_actuator(name=a.name, target=a.name, trntype=mujoco.mjtTrn.mjTRN_JOINT, gear=[a.gear, 0, 0, 0, 0, 0],
                          ctrlrange=[a.lower, a.upper], ctrllimited=bool(np.isfinite([a.lower, a.upper]).all()))
    names = tuple(j.name for j in spec.joints)
    if check_order and names != robot.dof_names:
        raise RobotFileError(f"{robot.path}: MuJoCo orders the joints {names}, Pinocchio {robot.dof_names}"
                             f"{order_hint(robot, names)}")
    return spec


def order_hint(robot: Robot, mujoco_names) -> str:
    """" (...)" naming why MuJoCo's joints (mujoco_names) differ from the robot's and the fix, or "": a URDF planar
    joint MuJoCo reads as three joints, Pinocchio as one (x, y and the angle's cos and sin); URDF sibling branches,
    which Pinocchio orders by their joints' names and MuJoCo as the file lists them."""
    planar = [robot.model.names[j] for j in range(1, robot.model.njoints)
              if robot.model.joints[j].shortname() == "JointModelPlanar"]
    if planar:
        return (f" (URDF planar joint {', '.join(map(repr, planar))}: MuJoCo reads it as three joints, Pinocchio as "
                "one; write it as two prismatic joints and a revolute one)")
    if not all(mujoco_names):  # (Pinocchio names them dof_0 ...: "MuJoCo orders the joints ('', '')" said no fix)
        return " (joints without a name: the two readings are matched by name; name every <joint>)"
    if robot.format is RobotFormat.URDF and sorted(mujoco_names) == sorted(robot.dof_names):
        return (" (Pinocchio's URDF parser orders sibling branches by their joints' names, MuJoCo as the file lists "
                "them: write the <joint> elements of each link's children in the order of their names)")
    return ""


def mujoco_failure(path, exc: Exception, step: str = "compile") -> str:
    """`MuJoCo cannot STEP PATH: ` and MuJoCo's error text (its ValueError) on one line: the error and the element it
    names ("Element name 'cx', id 1, line 4", the body to fix)."""
    lines = (ln.strip() for ln in str(exc).strip().splitlines())
    return f"MuJoCo cannot {step} {path}: " + "; ".join(ln for ln in lines if ln)


def _parser_message(exc: Exception) -> str:
    """The useful line of a Pinocchio parser error (its first line is often just the source file)."""
    text = str(exc).strip()
    if "message:" in text:
        text = text.split("message:", 1)[1].strip()
    lines = [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.strip().startswith("From file")]
    return lines[0] if lines else type(exc).__name__


def _defaults_late(path: Path) -> bool:
    """Whether an MJCF file's <default> follows its <worldbody> (MuJoCo compiles that; Pinocchio's parser failed on it
    with "unordered_map::at")."""
    tags = [child.tag for child in ET.parse(path).getroot()]
    return "default" in tags and "worldbody" in tags and tags.index("default") > tags.index("worldbody")


def coordinate_units(model: pin.Model) -> tuple[list[str], list[str]]:
    """Units of each configuration and velocity coordinate: 'm', 'rad' or '' (quaternion, cos/sin)."""
    q_units, v_units = [], []

    def visit(joint):
        kind = joint.shortname().replace("JointModel", "")
        if kind == "Composite":
            for sub in joint.extract().joints:
                visit(sub)
        elif kind.startswith("P"):  # PX, PY, PZ, PrismaticUnaligned, Planar handled below
            if kind == "Planar":
                q_units.extend(["m", "m", "", ""])
                v_units.extend(["m", "m", "rad"])
            else:
                q_units.append("m")
                v_units.append("m")
        elif kind == "FreeFlyer":
            q_units.extend(["m"] * 3 + [""] * 4)
            v_units.extend(["m"] * 3 + ["rad"] * 3)
        elif kind == "Translation":
            q_units.extend(["m"] * 3)
            v_units.extend(["m"] * 3)
        else:  # revolute family, spherical, helical, universal, ...
            q_units.extend(["rad" if joint.nq == joint.nv else ""] * joint.nq)
            v_units.extend(["rad"] * joint.nv)

    for j in range(1, model.njoints):
        visit(model.joints[j])
    if len(q_units) != model.nq or len(v_units) != model.nv:  # a joint kind not listed above
        return [""] * model.nq, [""] * model.nv
    return q_units, v_units


def _in_degrees(path: Path) -> bool:
    """Whether MuJoCo reads an MJCF file's angles in degrees: the last <compiler angle>, its included files' in
    their place (one in an <include> was missed), else MuJoCo's default."""
    angles = _compiler_angles(path, path.parent, {path.resolve()})
    return (angles[-1] if angles else "degree") == "degree"


def _compiler_angles(path: Path, model_dir: Path, seen: set) -> list[str]:
    """The <compiler angle> values of an MJCF file and of the files it includes, in document order."""
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError, ValueError):  # (loading the robot reports those)
        return []
    out = []
    for element in root.iter():
        name = element.get("file") if element.tag == "include" else None
        if element.tag == "compiler" and element.get("angle"):
            out.append(element.get("angle"))
        elif name:
            target = _include_target(name, path, model_dir)
            if target is not None and target.resolve() not in seen:
                seen.add(target.resolve())
                out += _compiler_angles(target, model_dir, seen)
    return out


def wrapper_tags(root: ET.Element) -> list[str]:
    """The MJCF wrapper elements (<frame>, <replicate>) of the file at `root`: Pinocchio's MJCF parser does not read
    the bodies, geoms and sites inside them, MuJoCo does."""
    return sorted({e.tag for e in root.iter() if e.tag in ("frame", "replicate")})


def _main_class_undeclared(path: Path) -> bool:
    """Whether an MJCF file gives an element class or childclass "main" without a <default class="main">."""
    elements = list(ET.parse(path).getroot().iter())
    used = any("main" in (e.get("class"), e.get("childclass")) for e in elements if e.tag != "default")
    return used and not any(e.get("class") == "main" for e in elements if e.tag == "default")


def _reversed_force_ranges(path: Path) -> str:
    """What to fix where Pinocchio found a joint's effort limits reversed: the MJCF joints whose actuatorfrcrange
    writes its lower bound last (a reversed ctrlrange or range is named so too)."""
    def reversed_(text: str) -> bool:
        try:
            lower, upper = (float(x) for x in text.split())
        except ValueError:  # not two numbers: Pinocchio's own message stands for it
            return False
        return lower > upper

    joints = [f"joint {e.get('name', '(unnamed)')!r}: actuatorfrcrange {e.get('actuatorfrcrange')}"
              for e in ET.parse(path).iter("joint") if reversed_(e.get("actuatorfrcrange", ""))]
    return ("; ".join(joints or ["a joint's actuatorfrcrange"])
            + " has its lower bound above its upper: write the lower bound first")


_QUIET = threading.Lock()  # descriptor 2 is the process's: two loads' swaps interleaved left it on a deleted file
os.register_at_fork(after_in_child=lambda: globals().update(_QUIET=threading.Lock()))  # (held by another thread)


@contextlib.contextmanager
def _quiet(printed: list[str] | None = None):
    """Pinocchio's parsers (C++) print warnings on the stderr file descriptor; keep the CLI's output clean (one error
    line on stderr). What went to the descriptor is appended to `printed` (a URDF's parse error says its reason only
    there). One thread at a time; another thread's writes to descriptor 2 meanwhile are caught too. sys.stdout is not
    swapped: nothing the parsers print reaches it, and other threads' prints were lost while it was."""
    with _QUIET:
        if sys.stderr is not None:  # None when the shell closed it (`2>&-`)
            sys.stderr.flush()
        try:
            saved = os.dup(2)
        except OSError:  # descriptor 2 closed (`2>&-`): nothing there to keep clean
            yield
            return
        try:
            try:
                caught = tempfile.TemporaryFile("w+b")
            except OSError as exc:  # (it read "Pinocchio cannot parse" the robot file, exit 2)
                raise PlannerError(f"no usable temporary directory for the robot file parser's messages ({exc}); set "
                                   "TMPDIR to a writable directory") from None
            with caught:
                os.dup2(caught.fileno(), 2)
                try:
                    yield
                finally:
                    os.dup2(saved, 2)
                    if printed is not None:  # bytes: a file's Latin-1 joint name refused a valid file as undecodable
                        caught.seek(0)
                        printed.append(caught.read().decode(errors="replace"))
        finally:
            os.close(saved)
