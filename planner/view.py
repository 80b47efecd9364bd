"""Meshcat replay of a result directory: a live viewer, or a self-contained static HTML page.

The scene is the robot's own geometry (MJCF geoms or URDF visuals, parsed by Pinocchio's geometry
models), the ground plane, a plan's holes (dark ellipses in the x-z plane), and the task's contact
points (orange spheres). Known, not built: a contact's other planes (a wall or slope: `normal` other than +z) are
not drawn. The replay runs in physical time t; with `slow_motion=True` it runs in
numerical time tau instead, so the frozen intervals (the impacts, where the clock stops and only the
velocities jump) take visible time and the impacting contact point is highlighted while they last.

The same scene-building code drives both outputs through a `meshcat.Visualizer`: for the live view
its window is meshcat's own server; for the static page it is an in-process recorder, so writing HTML
needs no server process, no ports and no network (see `render_html`).

Also here: `load_result`, the reader of the result-directory contract (shared with `planner.plots`).
"""
from __future__ import annotations

import base64
import contextlib
import json
import math
import os
import re
import time
import warnings
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from .errors import InputError, PlannerError, captured_stdout, expect, real_array, signals_held
from .model import Robot, RobotFormat, _quiet
from .result import (ArraysReadOnly, check_impacts_agree, check_same_result, clock_goes_back, read_robot, read_summary,
                     read_task, read_trajectory, result_dir, write_atomically)

FPS = 60  # animation keyframes per second of replay [1/s]
ROOT = "/planner"  # every object the replay draws lives under this meshcat path

# Colours: RGBA in [0, 1]
CONTACT_RGBA = (1.0, 0.45, 0.0, 1.0)  # contact points: orange
IMPACT_RGBA = (0.9, 0.05, 0.05, 0.45)  # impact highlight: translucent red
GROUND_RGBA = (0.62, 0.58, 0.52, 1.0)  # ground: warm grey
HOLE_RGBA = (0.12, 0.12, 0.14, 1.0)  # holes, where they cut the ground: nearly black
HOLE_ABOVE_RGBA = (0.12, 0.12, 0.14, 0.3)  # the part of a hole's ellipse above the ground: keep-out zone
ROBOT_RGBA = (0.35, 0.55, 0.85, 1.0)  # robot parts whose file gives no colour
_PIN_DEFAULT_RGBA = (0.9, 0.9, 0.9, 1.0)  # what Pinocchio assigns to a URDF visual without material
PAGE_BACKGROUND = "linear-gradient(#ffffff, #d6dee6)"  # CSS: light, so every part stands out

IMPACT_FLASH_S = 0.1  # in physical-time replays an impact is instantaneous; highlight it this long [s]
FROZEN_RATE = 0.1  # a tau interval is frozen when dt/dtau is below this (running clock: dt/dtau >= 1)
CAMERA_FOV_DEG = 30.0  # vertical field of view; narrow, so the side view of a planar robot is nearly flat
CAMERA_ASPECT = 4.0 / 3.0  # width/height the framing assumes (a wider window shows more)
CAMERA_MARGIN = 1.15  # framing slack around the swept volume
SERVER_TIMEOUT_S = 5.0  # how long `serve` waits for an existing meshcat server to answer [s]


# --- the result directory ----------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Result(ArraysReadOnly):
    """A result directory read back: arrays of `trajectory.npz`, `summary.json`, robot and task.

    Shapes: K numerical-time nodes, P physical-time samples (an impact is two samples with the same
    time), I impacts, C contact points.
    """

    directory: Path
    tau: np.ndarray  # (K,) numerical time [s]
    y: np.ndarray  # (K, ny) time-freezing states (q, v, [p], t); the clock t [s] is the last column
    t: np.ndarray  # (P,) physical time [s], non-decreasing
    q: np.ndarray  # (P, nq) positions [m, rad]
    v: np.ndarray  # (P, nv) velocities [m/s, rad/s]
    u: np.ndarray  # (P, nu) controls [N m or N]
    impact_times: np.ndarray  # (I,) [s]
    lambda_n: np.ndarray | None  # (P, C) normal contact forces [N], when the solver wrote them
    lambda_t: np.ndarray | None  # (P, C) tangential contact forces [N], when the solver wrote them
    summary: dict
    robot: Robot
    task: object | None  # planner.task.Task, or None when summary.json names no task

    @property
    def ground_height(self) -> float:
        """z of the ground plane [m]."""
        return self.task.ground_height if self.task is not None else 0.0

    @property
    def holes(self) -> tuple:
        """A plan's holes (planner.task.Ellipse: centre x, z and half-axes a, b [m]); none for a simulation, which has
        no holes (its task's [plan] ones were drawn, a drop sliding across them)."""
        if self.task is None or self.task.plan is None or self.summary.get("command") != "plan":
            return ()
        return self.task.plan.holes

    @property
    def contact_points(self) -> tuple[str, ...]:
        """Names of the task's contact points (robot points)."""
        return tuple(c.point for c in self.task.contacts) if self.task is not None else ()

    def impacts(self, taps: bool = False) -> list[tuple[float, tuple[str, ...]]]:
        """(time [s], contact points) per impact that is not a tap (taps=True: per tap, summary.json's "tap",
        result.TAP_SHARE): from summary.json, else `impact_times` with every contact (and no taps)."""
        given = self.summary.get("impacts") or []
        if not given:
            return [] if taps else [(float(ti), self.contact_points) for ti in self.impact_times]
        return [(float(imp["time"]), self._hit(imp.get("contact"))) for imp in given if (imp.get("tap") is True) == taps]

    def frozen_intervals(self) -> list[tuple[float, float, tuple[str, ...]]]:
        """(tau_start, tau_end [s], contact points) of each frozen interval of numerical time.

        From summary.json's impacts when each gives tau_start and tau_end; otherwise the maximal runs
        of tau steps whose clock rate dt/dtau is below FROZEN_RATE, each matched to the impact nearest
        in physical time (every contact point when none is within 1% of the duration). Either way without the taps
        (summary.json's "tap": steps whose clock ran at 0.92-0.96, which clock.png shaded and slow motion labelled
        "clock frozen: impact", where the other plots and the physical-time replay mark them as taps).
        """
        given = self.summary.get("impacts") or []
        if given and all(isinstance(i.get("tau_start"), (int, float)) and isinstance(i.get("tau_end"), (int, float))
                         for i in given):
            return [(float(i["tau_start"]), float(i["tau_end"]), self._hit(i.get("contact"))) for i in given
                    if i.get("tap") is not True]
        if len(self.tau) < 2:
            return []
        frozen = np.diff(self.y[:, -1]) / np.diff(self.tau) < FROZEN_RATE
        edges = np.flatnonzero(np.diff(np.concatenate([[0], frozen.astype(int), [0]])))
        marked = [(*imp, False) for imp in self.impacts()] + [(*imp, True) for imp in self.impacts(taps=True)]
        tol = 0.01 * max(float(self.t[-1] - self.t[0]), 1e-3)
        out = []
        for start, stop in zip(edges[::2], edges[1::2]):  # steps start .. stop-1 are frozen
            clock = float(self.y[start + 1, -1])
            names = self.contact_points
            if marked:
                t_imp, hit, tap = min(marked, key=lambda imp: abs(imp[0] - clock))
                if abs(t_imp - clock) <= tol:
                    if tap:
                        continue
                    names = hit
            out.append((float(self.tau[start]), float(self.tau[stop]), names))
        return out

    def _hit(self, contact) -> tuple[str, ...]:
        """The contact points an impact's `contact` (a name or an index) designates."""
        if isinstance(contact, int) and 0 <= contact < len(self.contact_points):
            return (self.contact_points[contact],)
        if isinstance(contact, str) and contact in self.contact_points:
            return (contact,)
        point, _, k = contact.rpartition("#") if isinstance(contact, str) else ("", "", "")
        if k.isdigit() and point in self.contact_points:  # a corner's plane (task.contact_labels): its point
            return (point,)
        return self.contact_points  # unnamed or unknown: do not guess which point hit


def load_result(out_dir) -> Result:
    """Read a result directory (the contract in docs/results.md). Raises InputError naming what is wrong."""
    expect(out_dir, (str, os.PathLike), "load_result's out_dir")
    directory = result_dir(out_dir)
    npz_path, summary_path = directory / "trajectory.npz", directory / "summary.json"
    for p in (npz_path, summary_path):
        if not p.is_file():
            failed = (" (a failed run's diagnostics are in its failed/ folder)"
                      if (directory / "failed" / p.name).is_file() else "")
            raise InputError(f"{directory} is not a result directory: {p.name} is missing{failed}")
    summary = read_summary(directory, require=("robot",))  # without a task: no ground, holes or contacts
    required, optional = ("tau", "y", "t", "q", "v", "u", "impact_times"), ("lambda_n", "lambda_t")
    raw = read_trajectory(directory, required)  # writers may add non-numeric arrays: keep the numeric ones
    check_same_result(directory, summary, raw)
    arrays = {}
    for k in (k for k in required + optional if k in raw):
        arrays[k] = real_array(raw[k], f"{npz_path}: {k}")
        if not np.all(np.isfinite(arrays[k])):
            raise InputError(f"{npz_path}: {k} is not finite (nan or inf)")
    robot = read_robot(directory, summary)
    if summary.get("task") is not None and not isinstance(summary["task"], str):
        raise InputError(f"{summary_path}: task must be a file path, got {summary['task']!r}")
    task = read_task(directory, raw, summary) if "task_json" in raw or summary.get("task") else None

    impacts = summary.get("impacts") or []
    if not isinstance(impacts, list) or not all(
            isinstance(i, dict) and isinstance(i.get("time"), (int, float)) for i in impacts):
        raise InputError(f"{summary_path}: impacts must be a list of objects with a numeric time")
    if "impacts" in summary:  # (an edited summary's impact was drawn where the trajectory has none; validate refused)
        check_impacts_agree(directory, impacts, arrays["impact_times"])

    a = arrays
    for key in ("t", "tau"):  # a 0-d array had no shape[0]: an IndexError
        if a[key].ndim != 1:
            raise InputError(f"{npz_path}: {key} must be a 1-D array, got shape {a[key].shape}")
    P = a["t"].shape[0]
    checks = [
        (a["tau"].ndim == 1, "tau must be (K,)"),
        (a["y"].ndim == 2 and a["y"].shape[0] == a["tau"].shape[0], "y must be (K, ny) with K = len(tau)"),
        (a["y"].ndim == 2 and a["y"].shape[1] >= robot.nq + robot.nv + 1, "y has fewer columns than (q, v, t)"),
        (a["t"].ndim == 1 and P >= 1, "t must be (P,) with P >= 1"),
        (a["q"].shape == (P, robot.nq), f"q must be (P, nq) = ({P}, {robot.nq})"),
        (a["v"].shape == (P, robot.nv), f"v must be (P, nv) = ({P}, {robot.nv})"),
        (a["u"].shape == (P, robot.nu), f"u must be (P, nu) = ({P}, {robot.nu})"),  # (4 panels for 2 motors)
        (bool(np.all(np.diff(a["t"]) >= 0)), "t must be non-decreasing"),
        (bool(np.all(np.diff(a["tau"]) >= 0)), "tau must be non-decreasing"),
    ]
    for key in ("lambda_n", "lambda_t"):
        if key in a:
            checks.append((a[key].ndim == 2 and a[key].shape[0] == P, f"{key} must be (P, n_contacts) with P = {P}"))
    if "lambda_n" in a and "lambda_t" in a:  # (the contact-force plot's IndexError)
        checks.append((a["lambda_t"].shape == a["lambda_n"].shape,
                       f"lambda_t must have lambda_n's shape {a['lambda_n'].shape}, got {a['lambda_t'].shape}"))
    for ok, message in checks:
        if not ok:
            back = clock_goes_back(a["t"]) if message.startswith("t must") else ""
            if back and summary.get("converged") is False:  # (its "t must be non-decreasing" said not why or where)
                raise InputError(f"{directory} holds a failed solve's last iterate whose clock runs backwards "
                                 f"({back}): no motion to show; its failure is in summary.json's message")
            raise InputError(f"{npz_path}: {message}" + (f" ({back})" if back else ""))
    # a repeated numerical time is an instantaneous jump (`planner gait` relabels the legs at each impact): its two
    # samples become two frames 1 ns apart, so the time grid increases as the animation needs
    a["tau"] = a["tau"] + 1e-9 * np.concatenate([[0], np.cumsum(np.diff(a["tau"]) == 0)])
    return Result(directory=directory, tau=a["tau"], y=a["y"], t=a["t"], q=a["q"], v=a["v"], u=a["u"],
                  impact_times=a["impact_times"].reshape(-1), lambda_n=a.get("lambda_n"),
                  lambda_t=a.get("lambda_t"), summary=summary, robot=robot, task=task)


# --- what to draw --------------------------------------------------------------------------------------

@dataclass(frozen=True)
class _Part:
    """One rigid drawable piece of the robot: meshcat geometries fixed in the frame of one joint."""

    name: str
    joint: int  # Pinocchio joint index it moves with (0: the world)
    placement: np.ndarray  # (4, 4) pose of the piece in the joint frame
    pieces: tuple  # ((meshcat geometry, (4, 4) pose in the piece frame), ...)
    rgba: tuple[float, float, float, float]


def robot_parts(robot: Robot) -> tuple[list[_Part], str | None]:
    """The robot's own visual geometry, or a kinematic-tree fallback.

    Returns (parts, note); `note` says why the fallback was used, None when the file's geometry is drawn.
    """
    try:
        with _quiet():  # (the C++ side's warnings on the stderr descriptor too)
            if robot.format is RobotFormat.MJCF:
                geom_model = pin.buildGeomFromMJCF(robot.model, str(robot.path), pin.GeometryType.VISUAL)
            else:
                # package://name/... meshes: let Pinocchio look for name/ beside every ancestor directory
                package_dirs = [str(d) for d in robot.path.resolve().parents]
                geom_model = pin.buildGeomFromUrdf(robot.model, str(robot.path), pin.GeometryType.VISUAL,
                                                   package_dirs=package_dirs)
    except Exception as exc:  # Pinocchio's parsers raise bare RuntimeError/ValueError (e.g. a missing mesh)
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        return _skeleton_parts(robot), f"Pinocchio could not read the geometry of {robot.path} ({first})"
    parts, skipped = [], []
    # a part's name is its meshcat path: Pinocchio names an unnamed geom as a named one may be ("base" body's
    # "baseGeom_0"), and the second part of one name replaced the first in the replay; '/' would nest it
    paths = [obj.name.replace("/", "|") for obj in geom_model.geometryObjects]
    repeated = Counter(paths)
    for i, obj in enumerate(geom_model.geometryObjects):
        pieces = _pieces(obj)
        if pieces is None:
            skipped.append(f"{obj.name} ({type(obj.geometry).__name__})")
            continue
        if not pieces:  # planes and half-spaces: the replay draws its own ground
            continue
        rgba = tuple(float(c) for c in obj.meshColor)
        if np.allclose(rgba, _PIN_DEFAULT_RGBA):
            rgba = ROBOT_RGBA
        name = paths[i] + (f" #{i}" if repeated[paths[i]] > 1 else "")
        parts.append(_Part(name, int(obj.parentJoint), obj.placement.homogeneous, tuple(pieces), rgba))
    if skipped:
        warnings.warn(f"meshcat replay: cannot draw geometry {', '.join(skipped)} of {robot.path}", stacklevel=2)
    if not any(p.joint > 0 for p in parts):
        return _skeleton_parts(robot), f"{robot.path} has no visual geometry on its moving bodies"
    return parts, None


def _pieces(obj) -> list | None:
    """meshcat geometries for one Pinocchio GeometryObject; [] for ground-like shapes, None if unknown."""
    import meshcat.geometry as mg

    geom, kind = obj.geometry, type(obj.geometry).__name__
    y_to_z = _rot_x(math.pi / 2)  # three.js cylinders run along y; coal's along z
    if kind == "Box":
        return [(mg.Box(list(2.0 * np.asarray(geom.halfSide))), np.eye(4))]
    if kind == "Sphere":
        return [(mg.Sphere(float(geom.radius)), np.eye(4))]
    if kind == "Ellipsoid":
        return [(mg.Ellipsoid(list(np.asarray(geom.radii, dtype=float))), np.eye(4))]
    if kind in ("Cylinder", "Capsule"):
        r, h = float(geom.radius), float(geom.halfLength)
        pieces = [(mg.Cylinder(2.0 * h, r), y_to_z)]
        if kind == "Capsule":  # meshcat 0.3 has no capsule: a cylinder with two spheres
            pieces += [(mg.Sphere(r), _translation(0, 0, s * h)) for s in (-1.0, 1.0)]
        return pieces
    if kind in ("Halfspace", "Plane"):
        return []
    mesh_path = Path(obj.meshPath) if obj.meshPath else None
    if mesh_path is not None and mesh_path.is_file():
        readers = {".stl": mg.StlMeshGeometry, ".obj": mg.ObjMeshGeometry, ".dae": mg.DaeMeshGeometry}
        reader = readers.get(mesh_path.suffix.lower())
        if reader is not None:
            # the mesh bytes are embedded in the command, so the static page stays self-contained
            return [(reader.from_file(str(mesh_path)), np.diag([*np.asarray(obj.meshScale, dtype=float), 1.0]))]
    return None


def _skeleton_parts(robot: Robot) -> list[_Part]:
    """Fallback drawing: a rod from each joint to its child joints and named points, a ball at each joint."""
    import meshcat.geometry as mg

    model = robot.model
    size = _robot_size(robot)
    r = 0.02 * size
    parts = []
    for j in range(1, model.njoints):
        parts.append(_Part(f"joint_{model.names[j]}", j, np.eye(4), ((mg.Sphere(1.5 * r), np.eye(4)),), ROBOT_RGBA))
    ends = [(model.parents[j], model.jointPlacements[j].translation, model.names[j]) for j in range(2, model.njoints)]
    ends += [(model.frames[robot.frame_id(p)].parentJoint, model.frames[robot.frame_id(p)].placement.translation, p)
             for p in robot.points]
    for parent, tip, name in ends:
        length = float(np.linalg.norm(tip))
        if parent == 0 or length < 1e-6:
            continue
        axis = pin.Quaternion.FromTwoVectors(np.array([0.0, 1.0, 0.0]), tip / length).matrix()
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = axis, tip / 2
        parts.append(_Part(f"rod_{model.names[parent]}_{name}", int(parent), pose,
                           ((mg.Cylinder(length, r), np.eye(4)),), ROBOT_RGBA))
    return parts


def _robot_size(robot: Robot) -> float:
    """A length scale of the robot [m]: the spread of its joints and points at the neutral pose."""
    data = robot.model.createData()
    q = pin.neutral(robot.model)
    pin.framesForwardKinematics(robot.model, data, q)
    pts = [data.oMi[j].translation for j in range(1, robot.model.njoints)]
    pts += [data.oMf[robot.frame_id(p)].translation for p in robot.points]
    pts = np.array(pts) if pts else np.zeros((1, 3))
    return max(float(np.max(np.ptp(pts, axis=0))), 0.1)


# --- the animation -------------------------------------------------------------------------------------

@dataclass(frozen=True)
class _Timeline:
    """What the replay shows at each keyframe: F frames at FPS."""

    replay: np.ndarray  # (F,) replay time [s] from 0: k / FPS, and the exact end last
    q: np.ndarray  # (F, nq) positions
    t: np.ndarray  # (F,) physical time [s]
    tau: np.ndarray | None  # (F,) numerical time [s] (slow motion only)
    highlight: dict  # contact point -> (F,) bool: show the impact marker


def _timeline(res: Result, slow_motion: bool) -> _Timeline:
    """Resample the trajectory at FPS over physical time, or over numerical time for slow motion."""
    model, nq = res.robot.model, res.robot.nq
    if slow_motion:
        grid, samples = res.tau, res.y[:, :nq]
    else:
        grid, samples = res.t, res.q
    times = grid[0] + np.arange(int(math.floor((grid[-1] - grid[0]) * FPS + 1e-9)) + 1) / FPS
    if grid[-1] - times[-1] > 1e-9:  # end on the final state, not up to 1/FPS before it
        times = np.append(times, grid[-1])
    n = len(times)
    q = np.array([_interpolate(model, grid, samples, s) for s in times])
    highlight = {p: np.zeros(n, dtype=bool) for p in res.contact_points}
    if slow_motion:
        for tau_start, tau_end, hit in res.frozen_intervals():
            on = (times >= tau_start) & (times <= tau_end)
            for p in hit:
                highlight[p] |= on
        return _Timeline(times - grid[0], q, np.interp(times, res.tau, res.y[:, -1]), times, highlight)
    for t_imp, hit in res.impacts():
        on = (times >= t_imp - 0.5 / FPS) & (times <= t_imp + IMPACT_FLASH_S)
        for p in hit:
            highlight[p] |= on
    return _Timeline(times - grid[0], q, times, None, highlight)


def _interpolate(model: pin.Model, grid: np.ndarray, samples: np.ndarray, s: float) -> np.ndarray:
    """q at grid time s, interpolated on the configuration manifold (quaternions stay unit)."""
    i = int(np.clip(np.searchsorted(grid, s, side="right") - 1, 0, len(grid) - 1))
    if i == len(grid) - 1:
        return samples[i]
    span = grid[i + 1] - grid[i]
    alpha = 0.0 if span <= 0 else float(np.clip((s - grid[i]) / span, 0.0, 1.0))
    return pin.interpolate(model, samples[i], samples[i + 1], alpha)


def _draw(vis, res: Result, slow_motion: bool) -> dict:
    """Draw the scene and its animation into a meshcat Visualizer; return the overlay's data."""
    import meshcat.animation as ma
    import meshcat.geometry as mg

    robot, model = res.robot, res.robot.model
    data = model.createData()
    parts, note = robot_parts(robot)
    if note:
        warnings.warn(f"meshcat replay: {note}; drawing the kinematic tree instead", stacklevel=3)
    timeline = _timeline(res, slow_motion)
    size = _robot_size(robot)
    contact_r = float(np.clip(0.05 * size, 0.01, 0.05))  # [m]: visible, yet smaller than a foot

    vis[ROOT].delete()
    # meshcat's gradient background renders garbage once its colours are changed (meshcat 0.3.2 in
    # chromium 156), so it is hidden: the page's own light background shows through the canvas.
    # No grid either: the ground is drawn, and a side view of the grid is one line.
    vis["/Background"].set_property("visible", False)
    vis["/Grid"].set_property("visible", False)
    vis["/Axes"].set_property("visible", False)

    for part in parts:
        for k, (geometry, pose) in enumerate(part.pieces):
            node = vis[f"{ROOT}/robot/{part.name}/{k}"]
            node.set_object(geometry, _material(part.rgba))
            node.set_transform(pose)
    for p in res.contact_points:
        vis[f"{ROOT}/contacts/{p}/point"].set_object(mg.Sphere(contact_r), _material(CONTACT_RGBA))
        vis[f"{ROOT}/contacts/{p}/impact"].set_object(mg.Sphere(3.0 * contact_r), _material(IMPACT_RGBA))
        vis[f"{ROOT}/contacts/{p}/impact"].set_transform(np.diag([1e-3, 1e-3, 1e-3, 1.0]))  # hidden until lit

    # sweep the motion once: keyframes, and the extent for the ground and the camera
    anim = ma.Animation(default_framerate=FPS)
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for f, q in enumerate(timeline.q):
        pin.framesForwardKinematics(model, data, q)
        with anim.at_frame(vis, float(timeline.replay[f] * FPS)) as frame:  # meshcat: time = frame / fps
            for part in parts:
                pose = data.oMi[part.joint].homogeneous @ part.placement
                frame[f"{ROOT}/robot/{part.name}"].set_transform(pose)
                lo, hi = np.minimum(lo, pose[:3, 3]), np.maximum(hi, pose[:3, 3])
            for p in res.contact_points:
                pose = data.oMf[robot.frame_id(p)].homogeneous
                frame[f"{ROOT}/contacts/{p}"].set_transform(pose)
                s = 1.0 if timeline.highlight[p][f] else 1e-3  # 0 would make a singular matrix
                frame[f"{ROOT}/contacts/{p}/impact"].set_property("scale", "vector3", [s, s, s])
                lo, hi = np.minimum(lo, pose[:3, 3]), np.maximum(hi, pose[:3, 3])
    lo, hi = lo - size / 2, hi + size / 2  # the part origins are not their extremities

    x_lo, x_hi, z_lo, z_hi = lo[0], hi[0], lo[2], hi[2]
    if res.task is not None:  # the ground comes from the task; without one there is none to draw
        z0, holes = res.ground_height, res.holes
        x_lo = min([x_lo] + [h.x - h.a for h in holes]) - 0.3 * size
        x_hi = max([x_hi] + [h.x + h.a for h in holes]) + 0.3 * size
        depth = max([0.1] + [1.5 * (z0 - (h.z - h.b)) for h in holes])  # deep enough to show each hole's bottom
        half_width_y = 0.4 * size
        vis[f"{ROOT}/ground"].set_object(mg.Box([x_hi - x_lo, 2 * half_width_y, depth]), _material(GROUND_RGBA))
        vis[f"{ROOT}/ground"].set_transform(_translation((x_lo + x_hi) / 2, 0.0, z0 - depth / 2))
        for i, h in enumerate(holes):
            # an elliptic prism through the slab, a bit deeper (in y) than it, so the side view shows the
            # a x b ellipse: opaque where it cuts the ground, translucent where it is a keep-out zone above
            for name, below, rgba in (("cut", True, HOLE_RGBA), ("above", False, HOLE_ABOVE_RGBA)):
                mesh = _elliptic_prism(h.x, h.z, h.a, h.b, 1.02 * half_width_y, z0, below)
                if mesh is not None:
                    vis[f"{ROOT}/holes/{i}/{name}"].set_object(mesh, _material(rgba))
        z_lo, z_hi = min(z_lo, z0 - depth), max(z_hi, z0)

    _set_camera(vis, np.array([x_lo, z_lo]), np.array([x_hi, z_hi]))
    vis.set_animation(anim, play=True, repetitions=10**6)  # loop: a replay is watched more than once
    mode = "slow motion (numerical time)" if slow_motion else "physical time"
    return {
        # (a failed run's last iterate looked like a plan)
        "title": f"{robot.name}: {mode}" + (" (NOT converged)" if res.summary.get("converged") is False else ""),
        "fps": FPS,
        "t": [round(float(x), 4) for x in timeline.t],
        "tau": None if timeline.tau is None else [round(float(x), 4) for x in timeline.tau],
        "impact": [bool(any(h[f] for h in timeline.highlight.values())) for f in range(len(timeline.t))],
        "note": note,
        "end": float(timeline.replay[-1]),
    }


def _elliptic_prism(xc, zc, a, b, half_y, z_cut, below, n=64):
    """The part of the ellipse ((x-xc)/a)^2 + ((z-zc)/b)^2 <= 1 below (or above) z = z_cut [m], as a
    prism through y in [-half_y, half_y]: a meshcat mesh, or None when that part is empty."""
    import meshcat.geometry as mg

    angle = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    ring = np.column_stack([xc + a * np.cos(angle), zc + b * np.sin(angle)])
    side = (ring[:, 1] <= z_cut) if below else (ring[:, 1] >= z_cut)
    # clip the convex polygon at the horizontal line z = z_cut (one pass of Sutherland-Hodgman)
    poly = []
    for k in range(n):
        p, nxt = ring[k], ring[(k + 1) % n]
        if side[k]:
            poly.append(p)
        if side[k] != side[(k + 1) % n]:
            s = (z_cut - p[1]) / (nxt[1] - p[1])
            poly.append(p + s * (nxt - p))
    if len(poly) < 3:
        return None
    poly = np.array(poly)
    m = len(poly)
    vertices = np.vstack([np.column_stack([poly[:, 0], np.full(m, y), poly[:, 1]]) for y in (-half_y, half_y)])
    faces = [[0, k, k + 1] for k in range(1, m - 1)] + [[m, m + k + 1, m + k] for k in range(1, m - 1)]
    for k in range(m):  # side walls
        k1 = (k + 1) % m
        faces += [[k, m + k, m + k1], [k, m + k1, k1]]
    return mg.TriangularMeshGeometry(vertices, np.array(faces))


def _set_camera(vis, lo: np.ndarray, hi: np.ndarray) -> None:
    """Look along +y (x to the right, z up) at the box [lo, hi] in the x-z plane [m], fitting it whole.

    meshcat's camera sits under /Cameras/default/rotated, which is rotated +90 deg about x: a camera
    position (0, 0, d) there is (0, -d, 0) in the world. Its orbit controls always aim at the world
    origin (meshcat 0.3 has no command to move their target), so the scene is shifted instead: ROOT is
    translated to put the centre of the box at the origin.
    """
    import meshcat.geometry as mg

    centre, half = (lo + hi) / 2, np.maximum((hi - lo) / 2, 0.05)
    tan_half = math.tan(math.radians(CAMERA_FOV_DEG) / 2)
    distance = CAMERA_MARGIN * max(half[0] / (tan_half * CAMERA_ASPECT), half[1] / tan_half)
    vis[ROOT].set_transform(_translation(-centre[0], 0.0, -centre[1]))
    vis["/Cameras/default"].set_transform(np.eye(4))
    vis["/Cameras/default/rotated"].set_object(
        mg.PerspectiveCamera(fov=CAMERA_FOV_DEG, aspect=CAMERA_ASPECT, near=0.01, far=100.0 * distance))
    vis["/Cameras/default/rotated/<object>"].set_property("position", [0.0, 0.0, distance])


def _material(rgba):
    import meshcat.geometry as mg

    r, g, b, a = rgba
    colour = (int(round(255 * r)) << 16) | (int(round(255 * g)) << 8) | int(round(255 * b))
    return mg.MeshLambertMaterial(color=colour, opacity=float(a))


def _translation(x, y, z) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = (x, y, z)
    return T


def _rot_x(angle: float) -> np.ndarray:
    T = np.eye(4)
    c, s = math.cos(angle), math.sin(angle)
    T[1:3, 1:3] = [[c, -s], [s, c]]
    return T


# --- outputs -------------------------------------------------------------------------------------------

class _Recorder:
    """A meshcat window that keeps the commands instead of sending them to a server.

    meshcat's own `Visualizer.static_html()` asks its server for the scene; replaying the recorded
    commands in order builds the same scene in the page (a later command overrides an earlier one just
    as it does in the server's tree).
    """

    def __init__(self):
        self.commands: list[bytes] = []

    def send(self, command) -> None:
        import umsgpack

        self.commands.append(umsgpack.packb(command.lower()))


def render_html(out_dir, html_path, slow_motion: bool = False) -> Path:
    """Write a self-contained static HTML replay of the result in `out_dir` to `html_path`.

    The page inlines meshcat's viewer script and every scene command (meshes included), and decodes
    the commands synchronously in order, so it works offline from a file:// URL with no server.
    Opening `page.html#time=T` shows the replay paused at replay time T [s] (tau in slow motion).
    Returns the path written. Raises InputError for an unusable result directory or output path.
    """
    expect(out_dir, (str, os.PathLike), "render_html's out_dir")
    expect(html_path, (str, os.PathLike), "render_html's html_path")
    expect(slow_motion, bool, "render_html's slow_motion")
    if (named := names_a_directory(str(html_path))) is not None:
        raise InputError(f"--html {named}")
    html_path = Path(html_path)
    if html_path.is_dir():
        raise InputError(f"--html {html_path} is a directory, not a file")
    # `--html DIR/summary.json` replaced the result's own file, `--html robot.xml` the robot file the result reads
    if html_path.is_file() and html_path.suffix.lower() not in (".html", ".htm") and not _is_page(html_path):
        raise InputError(f"--html {html_path} would overwrite a file that is not an HTML page; name an .html file")
    if html_path.suffix.lower() not in ("", ".html", ".htm") and not html_path.is_file():  # (x.png written, exit 0)
        raise InputError(f"--html {html_path} is no HTML file's name ({html_path.suffix}); name an .html file")
    existing = next(p for p in html_path.absolute().parents if p.exists())  # the root always exists
    if not existing.is_dir():  # mkdir said "File exists" of the page
        raise InputError(f"cannot write {html_path}: {existing} is a file, not a directory")
    vis = _visualizer(_Recorder())
    overlay = _draw(vis, load_result(out_dir), slow_motion)
    html = _page(vis.window.commands, overlay)
    try:
        html_path.parent.mkdir(parents=True, exist_ok=True)  # as --out's directories are
        write_atomically(html_path, html)
    except OSError as exc:
        raise InputError(f"cannot write {html_path}: {exc.strerror}") from None
    return html_path


def names_a_directory(text: str) -> str | None:
    """What is wrong with a page's path `text` that ends in /, /. or /.. (Path drops the slash: a new "DIR/" became a
    file named DIR), else None; render_html and the CLI's --html parser say it."""
    if not text.endswith(("/", os.sep)) and re.split(r"[/\\]", text)[-1] not in (".", ".."):  # ("nd/." is nd too)
        return None
    return f"{text} names a directory; name the page's file (e.g. {os.path.join(text, 'replay.html')})"


def _is_page(path: Path) -> bool:
    """Whether the file at `path` is an HTML page (one render_html wrote without an .html suffix may be written
    again)."""
    with open(path, "rb") as f:
        return f.read(15).lower() == b"<!doctype html>"


def serve(out_dir, slow_motion: bool = False, zmq_url: str | None = None, *, block: bool = False,
          print_url: bool = True) -> str:
    """Show the replay in a live meshcat viewer; return (and print) the URL to open in a browser.

    Starts meshcat's server as a subprocess unless `zmq_url` names a running one (`meshcat-server`): one server per
    call, each until this Python process exits normally (meshcat stops them at exit; a process killed by a signal
    without a handler, e.g. SIGTERM, leaves them running, since meshcat starts them in a session of their own). To
    reuse one server, start `meshcat-server` and pass its `zmq_url` (each call's drawing replaces the one before).
    `block=True` waits for Ctrl-C instead of returning.
    """
    expect(slow_motion, bool, "serve's slow_motion")
    expect(zmq_url, (str, type(None)), "serve's zmq_url")
    res = load_result(out_dir)  # fail on bad input before starting a server
    if zmq_url is not None:
        _check_server(zmq_url)  # meshcat itself would wait forever for a server that is not there
    try:
        # meshcat prints its own banner; keep stdout for --json. A stop signal waits until the server it starts has
        # started and meshcat registered its cleanup at exit: one in between left the server running (6 of 12 Ctrl-Cs
        # 0.5 s in). Not when it connects to a running one: a server that stops answering would block it for good
        with captured_stdout(), signals_held() if zmq_url is None else contextlib.nullcontext():
            vis = _visualizer(None, zmq_url=zmq_url)
    except PlannerError:
        raise
    except Exception as exc:  # meshcat raises bare Exception/RuntimeError when its server cannot start
        raise PlannerError(f"cannot start the meshcat server: {exc}") from None
    _draw(vis, res, slow_motion)
    url = vis.url()
    if print_url:
        print(f"meshcat replay: {url}", flush=True)
    if block:
        try:
            while True:
                time.sleep(3600)
        except KeyboardInterrupt:
            pass
    return url


def _visualizer(window, zmq_url: str | None = None):
    """A meshcat Visualizer drawing into `window`, or into a (new, when zmq_url is None) server."""
    try:
        import meshcat
    except ImportError:  # pragma: no cover - a declared dependency
        raise PlannerError("the replay needs meshcat: pip install 'meshcat>=0.3.2,<0.4'") from None
    return meshcat.Visualizer(zmq_url=zmq_url, window=window)


def _check_server(zmq_url: str) -> None:
    """Raise PlannerError unless a meshcat server answers at zmq_url within SERVER_TIMEOUT_S."""
    import zmq

    sock = zmq.Context.instance().socket(zmq.REQ)
    sock.setsockopt(zmq.LINGER, 0)
    try:
        sock.connect(zmq_url)
        sock.send(b"url")
        if not sock.poll(int(SERVER_TIMEOUT_S * 1000)):
            raise PlannerError(f"no meshcat server answers at {zmq_url} (start one with meshcat-server)")
        sock.recv()
    except zmq.ZMQError as exc:
        raise PlannerError(f"cannot reach a meshcat server at {zmq_url}: {exc}") from None
    finally:
        sock.close()


def _viewer_script() -> str:
    """meshcat's bundled viewer (three.js and all), to inline in the page."""
    import meshcat

    path = Path(meshcat.__file__).parent / "viewer" / "dist" / "main.min.js"
    return path.read_text(encoding="utf-8")


def _script_safe(text: str) -> str:
    """Text that cannot close the <script> element it is inlined in."""
    return re.sub(r"</(script)", r"<\\/\1", text, flags=re.IGNORECASE)


def _json_in_script(value) -> str:
    """value as a JavaScript literal inside <script>: every '<' escaped, as a name's "<!--<script>" put the HTML
    parser into its script-data states and the rest of the page was read as script (a blank page)."""
    return json.dumps(value).replace("<", "\\u003c")


def _page(commands: list[bytes], overlay: dict) -> str:
    blobs = json.dumps([base64.b64encode(c).decode("ascii") for c in commands])
    return f"""<!DOCTYPE html>
<html>
<head>
<meta charset="utf-8">
<title>{_html_escape(overlay["title"])} - planner replay</title>
<style>
  body {{ margin: 0; overflow: hidden; background: {PAGE_BACKGROUND}; }}
  #meshcat-pane {{ width: 100vw; height: 100vh; overflow: hidden; }}
  #planner-overlay {{ position: absolute; left: 10px; top: 8px; font: 14px/1.4 sans-serif; color: #222;
                      background: rgba(255, 255, 255, 0.75); padding: 4px 8px; border-radius: 4px; }}
  #planner-clock {{ font-family: monospace; }}
</style>
</head>
<body>
<div id="meshcat-pane"></div>
<div id="planner-overlay"><b id="planner-title"></b><br><span id="planner-clock"></span><br>
<small id="planner-note"></small></div>
<script>{_script_safe(_viewer_script())}</script>
<script>
var viewer = new MeshCat.Viewer(document.getElementById("meshcat-pane"));
// decode and apply every scene command now, in order (no fetch: nothing asynchronous to reorder)
{_script_safe(blobs)}.forEach(function (b64) {{
  var raw = atob(b64), bytes = new Uint8Array(raw.length);
  for (var i = 0; i < raw.length; i++) bytes[i] = raw.charCodeAt(i);
  viewer.handle_command_bytearray(bytes);
}});
var planner = {_json_in_script(overlay)};
// page.html#time=0.65 opens paused at that replay time [s] (a moment to link to, or to screenshot)
var plannerSeek = /(?:^#|&)time=([0-9.eE+-]+)/.exec(location.hash);
if (plannerSeek) {{
  viewer.animator.pause();
  viewer.animator.seek(parseFloat(plannerSeek[1]));
  viewer.animator.display_progress(parseFloat(plannerSeek[1]));
}}
document.getElementById("planner-title").textContent = planner.title;
if (planner.note) document.getElementById("planner-note").textContent = "kinematic tree shown: " + planner.note;
function plannerClock() {{
  // frames are 1/fps apart, except the last one, which is the exact end
  var n = planner.t.length, time = viewer.animator.time;
  var f = time >= planner.end ? n - 1 : Math.min(n - 1, Math.max(0, Math.round(time * planner.fps)));
  var text = "t = " + planner.t[f].toFixed(3) + " s";
  if (planner.tau) text = "\\u03c4 = " + planner.tau[f].toFixed(3) + " s, " + text;
  if (planner.impact[f]) text += planner.tau ? "  (clock frozen: impact)" : "  (impact)";
  document.getElementById("planner-clock").textContent = text;
  requestAnimationFrame(plannerClock);
}}
plannerClock();
</script>
</body>
</html>
"""


def _html_escape(text: str) -> str:
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


