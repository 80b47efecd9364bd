"""Result plots (PNG): states and torques against physical time, contact forces, the clock t(tau), and
the contact points' path in the x-z plane with the ground and the task's holes.

Drawn with matplotlib's object API on Agg canvases (`matplotlib.figure.Figure`, no pyplot), so no
display is needed and the caller's matplotlib backend and global state are left alone.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin

from .model import coordinate_units
from .result import TAP_SHARE, write_beside_result
from .task import contact_labels
from .view import Result, load_result

MAX_PANELS_PER_COLUMN = 8  # with more coordinates than this, several share a panel
DPI = 110
IMPACT_STYLE = dict(color="tab:red", linestyle="--", linewidth=0.9, alpha=0.8)
TAP_STYLE = dict(color="tab:red", linestyle=":", linewidth=0.8, alpha=0.45)  # a tap (result.TAP_SHARE): no landing
# a corner of the clipped region this close to its plane (relative to |x| [m]) is on it: the edge drawn as the plane
ON_PLANE_REL = 1e-9


PLOT_FILES = ("states.png", "torques.png", "contact_forces.png", "clock.png", "foot_path.png")  # all plot_results may write


def plot_results(out_dir) -> list[Path]:
    """Write the result plots of `out_dir` into it and return their paths.

    Files: `states.png` (q and v against t), `torques.png` (u against t, when the robot has
    actuators), `contact_forces.png` (when `trajectory.npz` holds lambda_n), `clock.png` (t against
    tau), `foot_path.png` (contact points in x-z, when the task names contact points). Impacts are
    dashed red lines (or crosses on the path). A plot is written only while the directory holds the result it was
    drawn from (summary.json's result_id): the paths returned are those written. Raises InputError for an unusable
    result directory.
    """
    from matplotlib import rc_context

    res = load_result(out_dir)
    writers = [_states, _torques, _contact_forces, _clock, _foot_path]
    paths = []
    # the robot file's names and the paths are text, not mathtext: a joint named "$\\foo$" failed the plots, so the
    # command (exit 1) of a validated plan
    with rc_context({"text.parse_math": False}):
        for write in writers:
            fig_and_name = write(res)
            if fig_and_name is not None:
                fig, name = fig_and_name
                # only beside the result drawn: another run may have written its own into the directory meanwhile
                if save_figure(fig, res.directory / name, result_id=res.summary.get("result_id")):
                    paths.append(res.directory / name)
    return paths


def _label(name: str) -> str:
    """A name as a legend entry: matplotlib leaves out entries whose label starts with '_' (an actuator '_fx')."""
    return " " + name if name.startswith("_") else name


def save_figure(fig, path: Path, dpi: int = DPI, result_id: str | None = None) -> bool:
    """fig as a PNG at path [dpi: dots per inch], atomically: an earlier plot of the same name stays whole until the
    new one is (a Ctrl-C mid-write); a path refused is an InputError (write_atomically). result_id: written only while
    the directory's summary.json is that result's (result.write_beside_result); whether it was written."""
    return write_beside_result(path, lambda f: fig.savefig(f, format="png", dpi=dpi), result_id)


def _new_figure(width: float, height: float):
    """A figure on its own Agg canvas [inches]: no pyplot, no display, no global backend switch."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _figure(rows: int, cols: int, width: float, row_height: float, **kwargs):
    """A figure with a rows x cols grid of axes; row_height and width in inches."""
    fig = _new_figure(width, max(2.2, row_height * rows + 0.8))
    return fig, fig.subplots(rows, cols, squeeze=False, **kwargs)


def _mark_impacts(ax, res: Result, legend: bool) -> None:
    """Dashed vertical lines at the impact times, dotted fainter ones at the taps (summary.json's "tap": the report
    counts them apart, and 13 alike lines read as 13 impacts for its 9); `legend`: name them in this panel's legend."""
    said = res.summary.get("impacts") or []
    taps = ([isinstance(i, dict) and i.get("tap") is True for i in said] if len(said) == len(res.impact_times)
            else [False] * len(res.impact_times))
    named = set()
    for ti, tap in zip(res.impact_times, taps):
        kind = "tap" if tap else "impact"
        ax.axvline(ti, label=kind if legend and kind not in named else None, **(TAP_STYLE if tap else IMPACT_STYLE))
        named.add(kind)


def _groups(n: int) -> list[list[int]]:
    """Split n coordinates into at most MAX_PANELS_PER_COLUMN panels of consecutive indices."""
    if n == 0:
        return []
    count = min(n, MAX_PANELS_PER_COLUMN)
    return [list(g) for g in np.array_split(np.arange(n), count)]


def _title(res: Result, what: str) -> str:
    """A plot's title: the robot and what is drawn, marked when the run did not converge (a failed run's last iterate
    looked like a plan; the HTML replay's title said so, the plots did not)."""
    return f"{res.robot.name}: {what}" + (" (NOT converged)" if res.summary.get("converged") is False else "")


def _states(res: Result):
    """q (left) and v (right) against physical time, one panel per coordinate (or group)."""
    robot = res.robot
    q_units, v_units = coordinate_units(robot.model)
    q_names = list(robot.dof_names) if robot.nq == robot.nv else [f"q[{i}]" for i in range(robot.nq)]
    v_units = [f"{u}/s" if u else "" for u in v_units]
    columns = [("position", res.q, q_names, q_units), ("velocity", res.v, list(robot.dof_names), v_units)]
    groups = [_groups(values.shape[1]) for _, values, _, _ in columns]
    rows = max(len(g) for g in groups)
    fig, axes = _figure(rows, 2, 11.0, 1.7, sharex=True)
    for c, ((kind, values, names, units), col_groups) in enumerate(zip(columns, groups)):
        for r in range(rows):
            ax = axes[r, c]
            if r >= len(col_groups):
                ax.set_visible(False)
                continue
            for i in col_groups[r]:
                ax.plot(res.t, values[:, i], linewidth=1.3, label=_label(names[i]))
            _mark_impacts(ax, res, legend=(r, c) == (0, 0))
            unit = {units[i] for i in col_groups[r]}
            unit_text = f" [{unit.pop()}]" if len(unit) == 1 and "" not in unit else ""
            if len(col_groups[r]) == 1:
                ax.set_ylabel(f"{names[col_groups[r][0]]}{unit_text}")
            else:
                ax.set_ylabel(f"{kind}{unit_text}")
                ax.legend(fontsize="x-small", ncols=2, loc="best")
            ax.grid(alpha=0.3)
        bottom = axes[len(col_groups) - 1, c]
        bottom.set_xlabel("physical time t [s]")
        bottom.tick_params(labelbottom=True)  # shared x hides it when this column is shorter
        axes[0, c].set_title("positions q" if kind == "position" else "velocities v (they jump at impacts)")
    if len(res.impact_times):
        axes[0, 0].legend(fontsize="x-small", loc="best")
    fig.suptitle(_title(res, "states"))
    return fig, "states.png"


def _torques(res: Result):
    """Controls u against physical time."""
    robot = res.robot
    if res.u.shape[1] == 0:
        return None
    names = [a.name for a in robot.actuators] if len(robot.actuators) == res.u.shape[1] else \
        [f"u[{j}]" for j in range(res.u.shape[1])]
    _, v_units = coordinate_units(robot.model)
    force_units = {"m": "N", "rad": "N m"}
    known = len(robot.actuators) == res.u.shape[1]
    # the joint's torque or force is gear u (a gear-2 motor's u = 1 was drawn as 1 N)
    gears = [robot.actuators[j].gear if known else 1.0 for j in range(res.u.shape[1])]
    groups = _groups(res.u.shape[1])
    fig, axes = _figure(len(groups), 1, 9.0, 2.2, sharex=True)
    for r, group in enumerate(groups):
        ax = axes[r, 0]
        for j in group:
            # u[i] is held from sample i-1 to sample i (zero-order hold): steps, not the ramps a line drew between them
            label = _label(names[j] if gears[j] == 1.0 else f"{names[j]} (gear {gears[j]:g} x u)")
            ax.plot(res.t, gears[j] * res.u[:, j], linewidth=1.3, label=label, drawstyle="steps-pre")
        _mark_impacts(ax, res, legend=r == 0)
        # per panel, as the states' (a slide's N beside a hinge's N m left both panels without a unit)
        units = {force_units.get(v_units[robot.actuators[j].dof], "") for j in group} if known else {""}
        what = "u" if all(gears[j] == 1.0 for j in group) else "gear x u"
        ax.set_ylabel(what + (f" [{next(iter(units))}]" if len(units) == 1 and "" not in units else ""))
        ax.legend(fontsize="small", loc="best")
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("physical time t [s]")
    fig.suptitle(_title(res, "controls (motor torques or forces)"))
    return fig, "torques.png"


def _contact_forces(res: Result):
    """Normal and tangential contact forces against physical time, with the friction cone bound."""
    if res.lambda_n is None:
        return None
    n_contacts = res.lambda_n.shape[1]
    # the forces' columns are a plan's contacts that touch (touches = false has none; a simulation reads touches
    # nowhere), labelled as the report labels them (point#1, point#2 for one point on two planes): "contact 0" and no
    # cone lines, or one name twice, before
    plan = res.summary.get("command") == "plan"
    touching = [c for c in res.task.contacts if c.touches or not plan] if res.task is not None else []
    named = len(touching) == n_contacts
    names = list(contact_labels(touching)) if named else [f"contact {i}" for i in range(n_contacts)]
    mus = [c.mu for c in touching] if named else None
    rows = 2 if res.lambda_t is not None else 1
    fig, axes = _figure(rows, 1, 9.0, 2.4, sharex=True)
    for i in range(n_contacts):
        # a sample's force is its step's (the step ending there): steps, as the torques (a take-off's ramp drew 4.9 N
        # on a point mass already in the air)
        line, = axes[0, 0].plot(res.t, res.lambda_n[:, i], linewidth=1.3, label=_label(names[i]),
                               drawstyle="steps-pre")
        if rows == 2:
            axes[1, 0].plot(res.t, res.lambda_t[:, i], linewidth=1.3, color=line.get_color(), label=_label(names[i]),
                            drawstyle="steps-pre")
            if mus is not None and mus[i] > 0:
                for sign in (1, -1):
                    axes[1, 0].plot(res.t, sign * mus[i] * res.lambda_n[:, i], color=line.get_color(), linewidth=0.8,
                                    linestyle=":", label=f"±μ λn ({names[i]})" if sign == 1 else None,
                                    drawstyle="steps-pre")
    axes[0, 0].set_ylabel("normal λn [N]")
    if rows == 2:
        axes[1, 0].set_ylabel("tangential λt [N]")
    for r, ax in enumerate(axes[:, 0]):
        _mark_impacts(ax, res, legend=r == 0)
        ax.legend(fontsize="small", loc="best")
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("physical time t [s]")
    fig.suptitle(_title(res, "contact forces (impacts are impulses, not shown as forces)"))
    return fig, "contact_forces.png"


def _clock(res: Result):
    """The clock state t against numerical time tau; frozen intervals (impacts) shaded."""
    clock = res.y[:, -1]
    fig, axes = _figure(1, 1, 7.0, 3.6)
    ax = axes[0, 0]
    ax.plot(res.tau, res.tau - res.tau[0] + clock[0], color="0.6", linewidth=0.9, linestyle="--",
            label="t = τ (clock at speed 1)")
    ax.plot(res.tau, clock, linewidth=1.6, label="t(τ)")
    for k, (tau_start, tau_end, _) in enumerate(res.frozen_intervals()):
        ax.axvspan(tau_start, tau_end, color="tab:red", alpha=0.18, linewidth=0,
                   label="frozen (impact)" if k == 0 else None)
    ax.set_xlabel("numerical time τ [s]")
    ax.set_ylabel("physical time t [s]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize="small", loc="best")  # (upper left hid the first frozen band)
    fig.suptitle(_title(res, "clock"))
    return fig, "clock.png"


def _behind(n, z0: float, box) -> list[tuple[float, float]]:
    """The corners (x [m], z [m]) of the part of box (x_lo, x_hi, z_lo, z_hi) behind the plane through (0, z0) of
    normal n = (n_x, n_z): where n_x x + n_z (z - z0) <= 0, the box clipped by that half-plane."""
    x_lo, x_hi, z_lo, z_hi = box
    corners = [(x_lo, z_lo), (x_hi, z_lo), (x_hi, z_hi), (x_lo, z_hi)]
    side = [n[0] * x + n[1] * (z - z0) for x, z in corners]
    out = []
    for i, (a, da) in enumerate(zip(corners, side)):
        b, db = corners[(i + 1) % 4], side[(i + 1) % 4]
        if da <= 0:
            out.append(a)
        if (da < 0 < db) or (db < 0 < da):  # the edge crosses the plane: where it does
            f = da / (da - db)
            out.append((a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1])))
    return out


def _foot_path(res: Result):
    """Each contact point's path in the x-z plane, the ground, the holes, and the impact points."""
    from matplotlib.patches import Ellipse, Polygon

    points = tuple(dict.fromkeys(res.contact_points))  # a corner's point once (its legend entry was drawn twice)
    if not points:
        return None
    robot, model = res.robot, res.robot.model
    data = model.createData()
    paths = {p: np.empty((len(res.t), 3)) for p in points}
    for k, q in enumerate(res.q):
        pin.framesForwardKinematics(model, data, q)
        for p in points:
            paths[p][k] = data.oMf[robot.frame_id(p)].translation
    z0, holes = res.ground_height, res.holes

    xs = np.concatenate([paths[p][:, 0] for p in points] + [np.array([h.x - h.a, h.x + h.a]) for h in holes])
    zs = np.concatenate([paths[p][:, 2] for p in points] + [np.array([h.z - h.b, h.z + h.b]) for h in holes] + [[z0]])
    pad = 0.08 * max(np.ptp(xs), np.ptp(zs), 0.1)
    x_lo, x_hi, z_lo, z_hi = xs.min() - pad, xs.max() + pad, min(zs.min(), z0) - pad, zs.max() + pad
    aspect = (z_hi - z_lo) / (x_hi - x_lo)
    fig = _new_figure(10.0, float(np.clip(10.0 * aspect, 2.5, 8.0)) + 0.9)  # equal axes: height follows
    ax = fig.subplots()
    normals = dict.fromkeys(c.normal for c in res.task.contacts) if res.task is not None else {(0.0, 0.0, 1.0): None}
    for normal in normals:  # each plane the task's contacts touch, through (0, z0): a slope or wall was drawn as ground
        behind = _behind(np.array(normal)[[0, 2]], z0, (x_lo, x_hi, z_lo, z_hi))
        if len(behind) < 3:
            continue
        flat = normal == (0.0, 0.0, 1.0)
        ax.add_patch(Polygon(behind, closed=True, facecolor="#d8cfc0", edgecolor="none", hatch="//", zorder=0,
                             label="ground" if flat else f"plane, normal ({normal[0]:.3g}, 0, {normal[2]:.3g})"))
        edge = [v for v in behind if abs(normal[0] * v[0] + normal[2] * (v[1] - z0)) < ON_PLANE_REL * (1 + abs(v[0]))]
        ax.plot(*np.array(edge).T, color="#6b5b45", linewidth=1.2, zorder=1)
    for i, h in enumerate(holes):
        # the hole cuts the ground (white), and its ellipse above the ground is a keep-out zone too
        ax.add_patch(Ellipse((h.x, h.z), 2 * h.a, 2 * h.b, facecolor="white", edgecolor="0.15", linewidth=1.0,
                             linestyle="--", zorder=1, label="hole (keep-out ellipse)" if i == 0 else None))
    for p in points:
        line, = ax.plot(paths[p][:, 0], paths[p][:, 2], linewidth=1.6, zorder=3, label=_label(f"{p} path"))
        ax.plot(*paths[p][0, [0, 2]], "o", color=line.get_color(), markersize=5, zorder=4)
        ax.plot(*paths[p][-1, [0, 2]], "s", color=line.get_color(), markersize=5, zorder=4)
    for taps, style, label in ((False, dict(marker="x", color="tab:red", markersize=9, markeredgewidth=2), "impact"),
                               (True, dict(marker=".", color="tab:gray", markersize=7), f"tap (impulse < {TAP_SHARE:.0%} of the largest)")):
        labelled = False
        for t_imp, hit in res.impacts(taps):
            k = int(np.clip(np.searchsorted(res.t, t_imp), 0, len(res.t) - 1))
            for p in hit:
                ax.plot(paths[p][k, 0], paths[p][k, 2], linestyle="none", zorder=5, label=None if labelled else label, **style)
                labelled = True
    ax.set_xlim(x_lo, x_hi)
    ax.set_ylim(z_lo, z_hi)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("z [m]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize="small", loc="upper right", ncols=2)
    ax.set_title(_title(res, "contact point path (o start, □ end)"))
    return fig, "foot_path.png"
