"""The meshcat replay (planner.view): the result reader, the scene, the animation timeline, the static
HTML page (self-contained, checked in a real headless chromium), and the live server.

`make_result_dir` writes a small synthetic Capler result in the contract format (design.md, "The
contract"); tests/test_plots.py uses it too. It is deterministic: no random numbers.
"""
from __future__ import annotations

import base64
import json
import math
import os
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from planner.errors import InputError
from planner.model import load_robot
from planner import view
from planner.cli import main

ROBOTS = Path(__file__).resolve().parent.parent / "robots"
GRAVITY = 9.81  # [m/s^2]
CAPLER_MASS = 3.975 + 1.782 + 0.548  # [kg]

# the synthetic motion: stance until T_LIFT, flight until T_IMPACT (inelastic impact, the foot sticks),
# stance until T_END; in numerical time the clock stops for FROZEN_TAU at the impact
T_LIFT, T_IMPACT, T_END, FROZEN_TAU = 0.1, 0.6, 0.8, 0.1  # [s]

Q_TOL = 1e-12  # interpolation at a sample time returns the sample [m, rad]
BLANK_STD = 5.0  # a screenshot whose pixel standard deviation is below this is blank [0-255 levels]
MIN_ROBOT_PIXELS = 100  # Capler's legs cover ~500 px at 800x600; fewer means the robot is missing
MIN_MARKER_PIXELS = 30  # the impact marker (a red sphere, half in the ground) covers ~300 px
MIN_MOVED_PIXELS = 100  # pixels that change between two replay times when the robot moves
XML_NAMESPACES = {"http://www.w3.org/1999/xhtml", "http://www.w3.org/2000/svg"}  # identifiers, never fetched


def _capler_q(t: float) -> np.ndarray:
    """q = (x_B, z_B, phi_hip, phi_knee) [m, m, rad, rad] of the synthetic hop at physical time t [s]."""
    if t <= T_LIFT:  # stance on a straight leg, the foot fixed at the origin
        x = 0.1 * t / T_LIFT
        hip = math.asin(x / 0.4)
        return np.array([x, 0.4 * math.cos(hip), hip, 0.0])
    if t <= T_IMPACT:  # ballistic flight to x = 1 (over the first hole), legs swinging forward
        s, d = t - T_LIFT, T_IMPACT - T_LIFT
        hip0 = math.asin(0.25)
        z0 = 0.4 * math.cos(hip0)
        vz = (0.4 - z0 + GRAVITY * d * d / 2) / d
        return np.array([0.1 + 0.9 * s / d, z0 + vz * s - GRAVITY * s * s / 2,
                         hip0 * (1 - s / d) - 0.4 * math.sin(math.pi * s / d), -0.8 * math.sin(math.pi * s / d)])
    return np.array([1.0, 0.4, 0.0, 0.0])  # landed: standing still on the foot at x = 1


def _capler_v(t: float) -> np.ndarray:
    """dq/dt of `_capler_q` [m/s, rad/s] by a one-sided difference (the left limit at phase ends)."""
    h = 1e-7
    return (_capler_q(t) - _capler_q(t - h)) / h if t > 0 else (_capler_q(h) - _capler_q(0.0)) / h


def make_result_dir(tmp_path: Path, robot: str = "capler.xml") -> Path:
    """Write `tmp_path/result` in the contract format: a Capler hop with one inelastic impact at T_IMPACT.

    trajectory.npz: tau (K,), y (K, 9) = (q, v, t), t (P,) with the impact time twice (pre- and
    post-impact velocity), q (P, 4), v (P, 4), u (P, 2), impact_times (1,), lambda_n and lambda_t (P, 1).
    """
    t = np.concatenate([np.linspace(0.0, T_LIFT, 11), np.linspace(T_LIFT, T_IMPACT, 51)[1:],
                        np.linspace(T_IMPACT, T_END, 11)])
    i_post = 11 + 50  # index of the post-impact sample; t[i_post - 1] == t[i_post] == T_IMPACT
    q = np.array([_capler_q(ti) for ti in t])
    v = np.array([_capler_v(ti) for ti in t])
    v[i_post:] = 0.0
    u = np.column_stack([30 * np.sin(2 * np.pi * t / T_END), -20 * np.cos(2 * np.pi * t / T_END)])
    stance = (t <= T_LIFT) | (np.arange(len(t)) >= i_post)
    lambda_n = np.where(stance, CAPLER_MASS * GRAVITY, 0.0)[:, None]
    lambda_t = 0.1 * lambda_n

    tau = np.linspace(0.0, T_END + FROZEN_TAU, 91)
    clock = np.minimum(tau, T_IMPACT) + np.maximum(tau - T_IMPACT - FROZEN_TAU, 0.0)
    yq = np.array([_capler_q(c) for c in clock])
    # while frozen, q stays and v goes linearly from the pre-impact velocity to zero (the state jump)
    w = np.clip((tau - T_IMPACT) / FROZEN_TAU, 0.0, 1.0)[:, None]
    yv = np.where((tau <= T_IMPACT)[:, None], np.array([_capler_v(c) for c in clock]), (1 - w) * v[i_post - 1])
    yv[tau >= T_IMPACT + FROZEN_TAU] = 0.0
    y = np.column_stack([yq, yv, clock])

    out = Path(tmp_path) / "result"
    out.mkdir()
    np.savez(out / "trajectory.npz", tau=tau, y=y, t=t, q=q, v=v, u=u, impact_times=np.array([T_IMPACT]),
             lambda_n=lambda_n, lambda_t=lambda_t)
    summary = {"command": "plan", "robot": str(ROBOTS / robot), "task": str(ROBOTS / "capler.toml"),
               "converged": True, "impacts": [{"time": T_IMPACT, "contact": "foot", "impulse": 12.3}]}
    (out / "summary.json").write_text(json.dumps(summary))
    return out


@pytest.fixture
def result_dir(tmp_path):
    return make_result_dir(tmp_path)


# --- reading the result directory ------------------------------------------------------------------

def test_load_result_reads_the_contract(result_dir):
    """Every array of the contract comes back with its shape, and robot and task are loaded."""
    res = view.load_result(result_dir)
    assert res.tau.shape == (91,) and res.y.shape == (91, 9)
    assert res.q.shape == (72, 4) and res.v.shape == (72, 4) and res.u.shape == (72, 2) and res.t.shape == (72,)
    assert res.lambda_n.shape == (72, 1) and res.lambda_t.shape == (72, 1)
    assert res.robot.name == "capler" and res.contact_points == ("foot",)
    assert len(res.holes) == 3 and res.ground_height == 0.0
    assert res.impacts() == [(T_IMPACT, ("foot",))]


def test_a_loaded_result_is_frozen_through_its_arrays(result_dir):
    """load_result's Result is read-only through its arrays too, as the planner's own results are (r.q[0] = ... and
    flags.writeable = True worked)."""
    res = view.load_result(result_dir)
    for array in (res.tau, res.q, res.t, res.lambda_n):
        with pytest.raises(ValueError, match="read-only"):
            array[0] = 1.0
        with pytest.raises(ValueError, match="WRITEABLE"):
            array.flags.writeable = True


def test_a_repeated_numerical_time_is_shown_as_two_frames(result_dir):
    """A result whose tau repeats a value (`planner gait` writes tau = t, an impact's two samples at one time) loads:
    the repeat becomes a frame 1 ns later, so tau increases and the rest of the grid is unchanged to 1 ns."""
    original = view.load_result(result_dir).tau
    _changed(result_dir, "tau", lambda tau: np.concatenate([tau[:10], tau[9:-1]]))
    tau = view.load_result(result_dir).tau
    assert np.all(np.diff(tau) > 0) and tau[10] == pytest.approx(original[9] + 1e-9, abs=1e-15)
    assert np.max(np.abs(tau[11:] - original[10:-1])) <= 1.1e-9


def test_taps_are_apart_from_the_impacts(result_dir):
    """An impact summary.json marks as a tap (result.TAP_SHARE) is not an impact to flash or mark with a cross; it is
    among the taps. A summary without tap flags has none (the old files)."""
    summary = json.loads((result_dir / "summary.json").read_text())
    summary["impacts"].append({"time": T_END / 2, "contact": "foot", "impulse": 0.1, "tap": True})
    (result_dir / "summary.json").write_text(json.dumps(summary))
    with np.load(result_dir / "trajectory.npz") as npz:  # (the two files say the same impacts)
        arrays = {k: npz[k] for k in npz.files}
    np.savez(result_dir / "trajectory.npz", **{**arrays, "impact_times": np.array([T_IMPACT, T_END / 2])})
    res = view.load_result(result_dir)
    assert res.impacts() == [(T_IMPACT, ("foot",))] and res.impacts(taps=True) == [(T_END / 2, ("foot",))]
    del summary["impacts"][1]["tap"]
    (result_dir / "summary.json").write_text(json.dumps(summary))
    assert view.load_result(result_dir).impacts(taps=True) == []


def test_an_impact_on_a_corners_plane_marks_its_point_only(result_dir):
    """An impact on one plane of a point listed with several (a corner: labels `foot#1`, `foot#2`) marks that point
    only; it marked every contact point (the knee glowed at each of the foot's impacts). An unknown label still marks
    every point (no guess)."""
    import dataclasses

    summary = json.loads((result_dir / "summary.json").read_text())
    summary["impacts"][0]["contact"] = "foot#2"
    (result_dir / "summary.json").write_text(json.dumps(summary))
    res = view.load_result(result_dir)
    (floor,) = res.task.contacts
    corner = (floor, dataclasses.replace(floor, normal=(-1.0, 0.0, 0.0)), dataclasses.replace(floor, point="knee"))
    res = dataclasses.replace(res, task=dataclasses.replace(res.task, contacts=corner))
    assert res.impacts() == [(T_IMPACT, ("foot",))]
    assert res._hit("hand#1") == res._hit("foot#x") == ("foot", "foot", "knee")


def test_a_result_whose_two_files_disagree_on_its_impacts_is_refused(result_dir):
    """summary.json's impacts and trajectory.npz's impact_times must say the same (result.check_impacts_agree), as
    validate refuses: an edited summary's impact time was drawn by view where the trajectory has none."""
    summary = json.loads((result_dir / "summary.json").read_text())
    summary["impacts"][0]["time"] = T_IMPACT + 0.3
    (result_dir / "summary.json").write_text(json.dumps(summary))
    with pytest.raises(InputError, match=r"impact_times\[0\] = .* summary.json's impacts\[0\] time .* the two files "
                                         r"disagree"):
        view.load_result(result_dir)


def test_frozen_intervals_from_the_clock_or_from_the_summary(result_dir):
    """Without tau_start/tau_end in summary.json, the frozen interval is where the clock stops; with
    them (as planner.result writes), they are used. Extra arrays (string names) are ignored."""
    res = view.load_result(result_dir)
    ((start, end, hit),) = res.frozen_intervals()
    assert np.isclose(start, T_IMPACT) and np.isclose(end, T_IMPACT + FROZEN_TAU) and hit == ("foot",)

    with np.load(result_dir / "trajectory.npz") as npz:
        arrays = {k: npz[k] for k in npz.files}
    np.savez(result_dir / "trajectory.npz", **arrays, state_names=np.array(["x_B", "z_B"]))
    summary = json.loads((result_dir / "summary.json").read_text())
    summary["impacts"][0].update(tau_start=0.59, tau_end=0.71)
    (result_dir / "summary.json").write_text(json.dumps(summary))
    assert view.load_result(result_dir).frozen_intervals() == [(0.59, 0.71, ("foot",))]


def _drop_key(d: Path, key: str) -> None:
    with np.load(d / "trajectory.npz") as npz:
        arrays = {k: npz[k] for k in npz.files if k != key}
    np.savez(d / "trajectory.npz", **arrays)


def _changed(d: Path, key: str, change) -> None:
    with np.load(d / "trajectory.npz") as npz:
        arrays = {k: npz[k] for k in npz.files}
    arrays[key] = change(arrays[key])
    np.savez(d / "trajectory.npz", **arrays)


def _bad_q(d: Path) -> None:
    _changed(d, "q", lambda q: q[:, :3])


def _failed_only(d: Path) -> None:
    """d as a failed plan leaves it: its diagnostics in d/failed, nothing in d."""
    (d / "failed").mkdir()
    for name in ("trajectory.npz", "summary.json"):
        (d / name).rename(d / "failed" / name)


def _nan_q(d: Path) -> None:
    _changed(d, "q", lambda q: np.where(np.arange(q.size).reshape(q.shape) == 1, np.nan, q))


@pytest.mark.parametrize("damage, message", [
    (lambda d: shutil.rmtree(d), "result directory not found"),
    (lambda d: (d / "trajectory.npz").unlink(), "trajectory.npz is missing"),
    (lambda d: _failed_only(d), "trajectory.npz is missing (a failed run's diagnostics are in its failed/ folder)"),
    (lambda d: _drop_key(d, "tau"), "lacks tau"),
    (_bad_q, "q must be (P, nq)"),
    (_nan_q, "q is not finite"),  # numpy's LinAlgError came out of the drawing
    (lambda d: _changed(d, "impact_times", lambda t: np.array(["soon"] * t.size)), "impact_times must hold numbers"),
    (lambda d: (d / "summary.json").write_text(json.dumps({"robot": "/nowhere/r.xml"})), "was not found"),
    (lambda d: _changed(d, "q", lambda q: q + 1j), "q must hold real numbers"),  # drawn from the real part, with a warning
    # four control panels for two motors were drawn; lambda_t narrower than lambda_n raised the plot's IndexError
    (lambda d: _changed(d, "u", lambda u: np.hstack([u, u])), "u must be (P, nu)"),
    (lambda d: _changed(d, "lambda_t", lambda lt: np.zeros((lt.shape[0], lt.shape[1] + 1))), "lambda_t must have "
                                                                                             "lambda_n's shape"),
])
def test_load_result_rejects_a_bad_directory_in_one_line(result_dir, damage, message):
    """A broken result directory is an InputError (exit 2 in the CLI) whose one line says what is wrong."""
    damage(result_dir)
    with pytest.raises(InputError) as err:
        view.load_result(result_dir)
    assert message in str(err.value) and "\n" not in str(err.value)


# --- the scene ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("robot_file, expected", [
    ("capler.xml", {"base_geom", "thigh_geom", "shank_geom"}),  # MJCF geoms; the ground plane is skipped
    ("capler.urdf", {"base_0", "thigh_0", "shank_0"}),  # URDF visuals
])
def test_robot_geometry_comes_from_the_robot_file(robot_file, expected):
    """The replay draws the file's own geometry through Pinocchio, each piece on a moving joint."""
    parts, note = view.robot_parts(load_robot(ROBOTS / robot_file))
    assert note is None
    assert {p.name for p in parts} == expected
    assert all(p.joint > 0 and p.pieces for p in parts)


def test_parts_of_one_name_are_drawn_apart(tmp_path):
    """An unnamed geom that Pinocchio names as a named one ("baseGeom_0") is a part of its own: a part's name is its
    meshcat path, and the second part of one name replaced the first (a sphere missing from the replay); a '/' in a
    name does not nest its path (session 64's tester)."""
    xml = tmp_path / "twins.xml"
    xml.write_text((ROBOTS / "capler.xml").read_text().replace(
        '<geom name="base_geom"', '<geom type="sphere" size="0.03"/><geom name="baseGeom_0" type="box" '
        'size="0.01 0.01 0.01"/><geom name="a/b" type="sphere" size="0.02"/>'
        '<geom name="a|b" type="sphere" size="0.02"/><geom name="base_geom"', 1))
    names = [p.name for p in view.robot_parts(load_robot(xml))[0]]
    assert len(set(names)) == len(names) == 7 and not any("/" in n for n in names), names


def test_the_pages_overlay_keeps_the_html_parser_out_of_script_states():
    """Names and paths in the page's overlay (its title, its note) are inlined with every '<' escaped: a robot named
    'm<!--<script>x' put the browser's parser into its script-data escape states, and the rest of the page was read
    as script (a blank page); the overlay still reads back as given."""
    overlay = {"title": "m<!--<script>x", "note": "dir</script><b>"}
    html = view._page([], overlay)
    inlined = re.search(r"var planner = (.*);\n", html).group(1)
    assert "<" not in inlined and json.loads(inlined) == overlay


def test_kinematic_tree_fallback_for_a_robot_without_visuals(tmp_path):
    """Without visual geometry, the replay draws rods between joint origins and to named points."""
    inertia = '<inertial><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial>'
    urdf = tmp_path / "bare.urdf"
    urdf.write_text(f"""<robot name="bare"><link name="world"/><link name="a">{inertia}</link>
      <link name="b">{inertia}</link><link name="tip"/>
      <joint name="j1" type="revolute"><parent link="world"/><child link="a"/><axis xyz="0 1 0"/>
        <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
      <joint name="j2" type="revolute"><parent link="a"/><child link="b"/><origin xyz="0 0 -0.5"/>
        <axis xyz="0 1 0"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
      <joint name="jt" type="fixed"><parent link="b"/><child link="tip"/><origin xyz="0 0 -0.3"/></joint>
    </robot>""")
    parts, note = view.robot_parts(load_robot(urdf))
    assert note is not None and "no visual geometry" in note
    rods = {p.name: p for p in parts if p.name.startswith("rod_")}
    assert set(rods) >= {"rod_j1_j2", "rod_j2_tip"}
    # a rod's centre is half-way to its end: 0.5 m below j1, 0.3 m below j2
    assert np.allclose(rods["rod_j1_j2"].placement[:3, 3], [0, 0, -0.25])
    assert np.allclose(rods["rod_j2_tip"].placement[:3, 3], [0, 0, -0.15])


def test_a_missing_mesh_is_one_warning_line_in_the_cli(tmp_path, capsys):
    """`planner view DIR --html` of a robot whose URDF names a mesh file that is not there draws the kinematic tree
    and says why in one stderr line (Python's warning format added the source line that issued it)."""
    urdf = tmp_path / "mesh.urdf"
    source = (ROBOTS / "capler.urdf").read_text()
    assert source.count('<box size="0.12 0.08 0.08"/>') == 1
    urdf.write_text(source.replace('<box size="0.12 0.08 0.08"/>', '<mesh filename="missing_body.stl"/>'))
    out = make_result_dir(tmp_path, robot=str(urdf))
    assert main(["view", str(out), "--html", str(tmp_path / "page.html")]) == 0
    (line,) = capsys.readouterr().err.splitlines()  # (libraries' DeprecationWarnings stay hidden under pytest too)
    assert line.startswith("planner view: warning: ") and "meshcat replay" in line, line
    assert "could not read the geometry" in line and "missing_body.stl" in line, line


# --- the animation timeline ----------------------------------------------------------------------------

def test_physical_timeline_samples_the_motion_at_fps(result_dir):
    """Frames are 1/FPS apart in physical time, hit the samples exactly, and flash the impact briefly."""
    res = view.load_result(result_dir)
    tl = view._timeline(res, slow_motion=False)
    assert len(tl.t) == int(round(T_END * view.FPS)) + 1
    assert np.allclose(np.diff(tl.t), 1.0 / view.FPS)
    for k in (0, 6, 36, len(tl.t) - 1):  # t = 0, 0.1, 0.6, 0.8 are samples of the fixture
        i = int(np.argmin(np.abs(res.t - tl.t[k])))
        assert np.max(np.abs(tl.q[k] - res.q[i])) < Q_TOL
    lit = tl.t[tl.highlight["foot"]]
    assert lit.min() >= T_IMPACT - 1.0 / view.FPS and lit.max() <= T_IMPACT + view.IMPACT_FLASH_S
    assert lit.size >= 2


def test_slow_motion_timeline_freezes_at_the_impact(result_dir):
    """In numerical time the clock stops for FROZEN_TAU at the impact: q holds and the foot is lit."""
    res = view.load_result(result_dir)
    tl = view._timeline(res, slow_motion=True)
    assert np.isclose(tl.tau[-1], T_END + FROZEN_TAU)
    frozen = (tl.tau >= T_IMPACT + 1e-9) & (tl.tau < T_IMPACT + FROZEN_TAU - 1e-9)
    assert np.array_equal(tl.highlight["foot"][frozen], np.ones(frozen.sum(), dtype=bool))
    assert not tl.highlight["foot"][~frozen & ((tl.tau < T_IMPACT - 0.02) | (tl.tau > T_IMPACT + FROZEN_TAU + 0.02))].any()
    assert np.allclose(tl.t[frozen], T_IMPACT)
    assert np.max(np.abs(tl.q[frozen] - _capler_q(T_IMPACT))) < 1e-9


# --- the static page -----------------------------------------------------------------------------------

def _page_commands(html: str) -> list[dict]:
    """The meshcat commands embedded in a page, decoded."""
    import umsgpack

    blobs = re.search(r'(\[(?:"[A-Za-z0-9+/=]+",?\s*)+\])\.forEach', html)
    assert blobs, "no embedded scene commands"
    return [umsgpack.unpackb(base64.b64decode(b)) for b in json.loads(blobs.group(1))]


def _scene(commands: list[dict]) -> tuple[dict, dict, dict]:
    """A page's decoded commands as (geometries, fixed, clips): each object's first geometry by path, each fixed
    (4, 4) transform by path, and the animation's clip by path."""
    geometries = {c["path"]: c["object"]["geometries"][0] for c in commands
                  if c["type"] == "set_object" and "geometries" in c["object"]}
    fixed = {c["path"]: np.array(c["matrix"]).reshape(4, 4).T for c in commands if c["type"] == "set_transform"}
    (anim,) = [c for c in commands if c["type"] == "set_animation"]
    return geometries, fixed, {a["path"]: a["clip"] for a in anim["animations"]}


def test_static_page_is_self_contained_and_animated(result_dir, tmp_path):
    """The page fetches nothing (every http(s) string is an XML namespace identifier, no src/href/
    import), and embeds the scene (robot parts, ground, 3 holes, contact) and an animation of them. Its directories
    are made, as --out's are (a missing one was refused)."""
    html = view.render_html(result_dir, tmp_path / "pages" / "replay.html").read_text()
    urls = set(re.findall(r"https?://[^\s\"'<>)\\]+", html))
    assert urls <= XML_NAMESPACES, urls - XML_NAMESPACES
    assert not re.search(r"<(script|img|link|iframe)[^>]*\s(src|href)\s*=", html, re.IGNORECASE)
    assert not re.search(r"@import|url\(\s*['\"]?(https?:)?//", html, re.IGNORECASE)
    assert "MeshCat.Viewer" in html and len(html) > 500_000  # the viewer bundle is inlined

    commands = _page_commands(html)
    objects = {c["path"] for c in commands if c["type"] == "set_object"}
    assert {f"{view.ROOT}/robot/{n}/0" for n in ("base_geom", "thigh_geom", "shank_geom")} <= objects
    assert f"{view.ROOT}/ground" in objects and f"{view.ROOT}/contacts/foot/point" in objects
    assert {f"{view.ROOT}/holes/{i}/cut" for i in range(3)} <= objects
    clips = _scene(commands)[2]
    assert {f"{view.ROOT}/robot/thigh_geom", f"{view.ROOT}/contacts/foot", f"{view.ROOT}/contacts/foot/impact"} <= set(clips)
    keys = clips[f"{view.ROOT}/contacts/foot"]["tracks"][0]["keys"]
    assert len(keys) == int(round(T_END * view.FPS)) + 1 and clips[f"{view.ROOT}/contacts/foot"]["fps"] == view.FPS


def test_render_html_refuses_a_directory_as_the_output(result_dir, tmp_path):
    """--html pointing at a directory is bad input, and nothing is written."""
    with pytest.raises(InputError, match="is a directory"):
        view.render_html(result_dir, tmp_path)


def test_render_html_refuses_a_device_or_fifo_and_titles_a_failed_run(result_dir, tmp_path):
    """--html onto a FIFO (or a device: `--html /dev/full` deleted it) is an InputError and the node stays as it was
    (the atomic rename replaced it with a regular file); a run that did not converge says so in the page's title (its
    last iterate looked like a plan)."""
    import os
    import stat

    fifo = tmp_path / "pipe.html"
    os.mkfifo(fifo)
    with pytest.raises(InputError, match="is not a regular file"):
        view.render_html(result_dir, fifo)
    assert stat.S_ISFIFO(fifo.stat().st_mode)
    summary = json.loads((result_dir / "summary.json").read_text())
    (result_dir / "summary.json").write_text(json.dumps({**summary, "converged": False}))
    page = view.render_html(result_dir, tmp_path / "failed.html").read_text()
    assert "<title>capler: physical time (NOT converged) - planner replay</title>" in page


# --- in a real browser ---------------------------------------------------------------------------------

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
needs_chromium = pytest.mark.skipif(CHROMIUM is None, reason="needs Debian's chromium: apt-get install -y chromium")
CHROMIUM_FLAGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--use-angle=swiftshader", "--enable-unsafe-swiftshader",  # WebGL on the CPU (no GPU in CI)
    "--host-resolver-rules=MAP * ~NOTFOUND",  # offline: no host name resolves
    "--window-size=800,600", "--virtual-time-budget=1500", "--hide-scrollbars",
]


def _screenshot(url: str, tmp_path: Path, name: str, local_server: bool = False) -> np.ndarray:
    """An 800x600 RGB screenshot of `url` in headless chromium, as ints in [0, 255].

    Offline: no host name resolves, not even 127.0.0.1 unless `local_server` (the live viewer's).
    """
    from PIL import Image

    png = tmp_path / f"{name}.png"
    profile = tmp_path / f"profile-{name}"
    flags = [f + ", EXCLUDE 127.0.0.1" if local_server and f.startswith("--host-resolver-rules") else f
             for f in CHROMIUM_FLAGS]
    run = subprocess.run([CHROMIUM, *flags, f"--user-data-dir={profile}", f"--screenshot={png}", url],
                         timeout=120, capture_output=True, text=True)
    # chromium exits 0 even when the page failed to load; then it writes no screenshot
    assert run.returncode == 0 and png.is_file(), f"chromium made no screenshot of {url}:\n{run.stderr[-2000:]}"
    return np.asarray(Image.open(png).convert("RGB")).astype(int)


def _robot_pixels(img: np.ndarray) -> np.ndarray:
    """Pixels of Capler's legs' blue (0.35, 0.55, 0.85), whatever the shading; nothing else is this blue."""
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    return (b > r + 60) & (b > g + 20)


def _marker_pixels(img: np.ndarray) -> np.ndarray:
    """Pixels of the translucent red impact marker: red, with green and blue alike (orange has g >> b)."""
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    return (r > g + 60) & (np.abs(g - b) < 30)


@needs_chromium
def test_static_page_shows_the_moving_robot_in_headless_chromium(result_dir, tmp_path):
    """Offline, from file://, the page renders a non-blank scene with the robot in it, and the robot
    is somewhere else at another replay time (the animation drives it)."""
    page = view.render_html(result_dir, tmp_path / "replay.html")
    start = _screenshot(f"{page.as_uri()}#time=0", tmp_path, "start")
    flight = _screenshot(f"{page.as_uri()}#time=0.35", tmp_path, "flight")
    for img in (start, flight):
        assert img.std() > BLANK_STD
        assert _robot_pixels(img).sum() > MIN_ROBOT_PIXELS
    moved = _robot_pixels(start) ^ _robot_pixels(flight)
    assert moved.sum() > MIN_MOVED_PIXELS


@needs_chromium
def test_slow_motion_page_lights_the_impact_while_the_clock_is_frozen(result_dir, tmp_path):
    """In the slow-motion page the impact marker shows inside the frozen interval and not in flight."""
    page = view.render_html(result_dir, tmp_path / "slow.html", slow_motion=True)
    frozen = _screenshot(f"{page.as_uri()}#time={T_IMPACT + FROZEN_TAU / 2}", tmp_path, "frozen")
    flight = _screenshot(f"{page.as_uri()}#time=0.35", tmp_path, "flight")
    assert _marker_pixels(frozen).sum() > MIN_MARKER_PIXELS
    assert _marker_pixels(flight).sum() < MIN_MARKER_PIXELS / 3
    assert _robot_pixels(frozen).sum() > MIN_ROBOT_PIXELS


@needs_chromium
def test_live_view_serves_the_scene_to_a_browser(result_dir, tmp_path, capsys):
    """`serve` draws into a running meshcat server, prints its URL, and a browser there sees the robot."""
    from meshcat.servers.zmqserver import start_zmq_server_as_subprocess

    proc, zmq_url, web_url = start_zmq_server_as_subprocess()
    try:
        url = view.serve(result_dir, zmq_url=zmq_url)
        assert url == web_url
        assert capsys.readouterr().out.strip() == f"meshcat replay: {url}"
        img = _screenshot(url, tmp_path, "live", local_server=True)
        assert img.std() > BLANK_STD
        assert _robot_pixels(img).sum() > MIN_ROBOT_PIXELS
    finally:
        proc.kill()
        proc.wait(timeout=10)


SERVER_START_S = 60  # [s] meshcat's server starts in ~1 s; a command that prints nothing by then is a failure, not a hang


@pytest.mark.parametrize("quiet, stop", [(False, "SIGTERM"), (True, "SIGTERM"), (False, "SIGHUP")])
def test_live_view_stops_its_server_on_sigterm(result_dir, quiet, stop):
    """`planner view DIR` started its own meshcat server; a SIGTERM, or the SIGHUP of a closed terminal, ends the
    command with exit 0 as Ctrl-C does, and the server process it started is gone (it stayed behind, listening on its
    port; after a SIGHUP until session 65). With -q the URL alone is printed (nothing was: a server running that no one
    could find)."""
    import os
    import signal
    import subprocess
    import sys
    import time

    # the signal's default in the command, as a terminal's shell starts it (the suite may run under nohup)
    proc = subprocess.Popen([sys.executable, "-m", "planner.cli", "view", str(result_dir)] + ["-q"] * quiet,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(getattr(signal, stop), signal.SIG_DFL))
    children = []
    try:
        import select

        assert select.select([proc.stdout], [], [], SERVER_START_S)[0], "no URL printed"
        line = proc.stdout.readline()
        if quiet:
            assert line.startswith("http://") and line.strip().endswith("/static/")
        else:
            assert line.startswith("meshcat replay: ")
        children = [c for c in _children(proc.pid) if "meshcat.servers.zmqserver" in _cmdline(c)]
        assert children  # the meshcat server (not a helper: `import mujoco` starts a glfw probe)
        proc.send_signal(getattr(signal, stop))
        assert proc.wait(timeout=30) == 0
        deadline = time.time() + 10
        while time.time() < deadline and any(_alive(c) for c in children):
            time.sleep(0.1)
        assert not any(_alive(c) for c in children)
    finally:
        proc.kill()
        proc.wait()
        for child in children:  # a failed check leaves no server behind
            if _alive(child):
                os.kill(child, signal.SIGKILL)


def _children(pid: int) -> list[int]:
    return [int(p) for p in os.listdir("/proc") if p.isdigit() and _parent(int(p)) == pid]


def _cmdline(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def _parent(pid: int) -> int | None:
    try:
        with open(f"/proc/{pid}/status") as f:
            return next(int(line.split()[1]) for line in f if line.startswith("PPid:"))
    except (OSError, StopIteration, ValueError):
        return None


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/status") as f:
            return not any(line.startswith("State:") and "Z" in line.split()[1] for line in f)
    except OSError:
        return False


def test_serve_fails_in_one_line_when_no_server_answers(result_dir, monkeypatch):
    """A zmq_url with no meshcat server behind it is a PlannerError, not a hang."""
    from planner.errors import PlannerError

    monkeypatch.setattr(view, "SERVER_TIMEOUT_S", 0.2)
    with pytest.raises(PlannerError, match="no meshcat server answers"):
        view.serve(result_dir, zmq_url="tcp://127.0.0.1:5")  # a privileged port nothing listens on


def test_without_a_task_the_page_has_no_ground(result_dir, tmp_path):
    """summary.json may name no task (null): the robot is replayed without ground, holes or contacts."""
    summary = json.loads((result_dir / "summary.json").read_text())
    (result_dir / "summary.json").write_text(json.dumps({**summary, "task": None}))
    objects = {c["path"] for c in _page_commands(view.render_html(result_dir, tmp_path / "r.html").read_text())
               if c["type"] == "set_object"}
    assert f"{view.ROOT}/robot/thigh_geom/0" in objects
    assert not any(p.startswith((f"{view.ROOT}/ground", f"{view.ROOT}/holes", f"{view.ROOT}/contacts")) for p in objects)


def test_the_physical_timeline_ends_on_the_final_state(tmp_path):
    """The animation's last frame is the plan's last sample also when the duration is no multiple of 1/FPS (the
    fixture's 0.8 s is one: session 65's mutation testing dropped the final frame, up to 1/FPS before the end, and
    every test stayed green)."""
    from test_result import small_result

    from planner.result import write_results

    write_results(small_result(), tmp_path / "r")
    res = view.load_result(tmp_path / "r")
    assert not math.isclose((res.t[-1] - res.t[0]) * view.FPS % 1.0, 0.0, abs_tol=1e-6)  # no multiple of 1/FPS
    tl = view._timeline(res, slow_motion=False)
    assert tl.t[-1] == pytest.approx(res.t[-1] - res.t[0]) and np.max(np.abs(tl.q[-1] - res.q[-1])) < Q_TOL


def test_a_stop_signal_waits_until_meshcats_server_has_started(result_dir, monkeypatch):
    """A Ctrl-C while serve starts meshcat's server comes once the server has started and meshcat has registered its
    cleanup at exit (signals tester, session 65: one between meshcat's Popen and its atexit.register, 6 of 12 Ctrl-Cs
    0.5 s after `planner view`, left the server running on its port)."""
    import os
    import signal

    started = []

    def visualizer(window, zmq_url=None):
        os.kill(os.getpid(), signal.SIGINT)  # as a Ctrl-C between meshcat's Popen and its atexit.register
        started.append(True)
        return None

    monkeypatch.setattr(view, "_visualizer", visualizer)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)  # (the suite may run with SIGINT ignored)
    try:
        with pytest.raises(KeyboardInterrupt):
            view.serve(result_dir)
    finally:
        signal.signal(signal.SIGINT, previous)
    assert started == [True]


def test_the_live_view_with_stdout_closed_serves_until_stopped(result_dir):
    """`planner view DIR >&-` (stdout closed) serves until its SIGTERM and exits 0 without a traceback (it flushed
    the missing stdout: AttributeError, exit 1; signals tester, session 65)."""
    import os
    import signal
    import subprocess
    import sys
    import time

    proc = subprocess.Popen([sys.executable, "-m", "planner.cli", "view", str(result_dir)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, preexec_fn=lambda: os.close(1))
    children = []
    try:
        deadline = time.time() + SERVER_START_S
        while not children and proc.poll() is None and time.time() < deadline:
            time.sleep(0.2)
            children = [c for c in _children(proc.pid) if "meshcat.servers.zmqserver" in _cmdline(c)]
        assert children and proc.poll() is None, proc.stderr.read()
        time.sleep(1.0)  # past the URL, where the flush was
        assert proc.poll() is None, proc.stderr.read()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 0
        assert "Traceback" not in proc.stderr.read()
    finally:
        proc.kill()
        proc.wait()
        for child in children:
            if _alive(child):
                os.kill(child, signal.SIGKILL)


LATE_ANSWER_S = 10.0  # [s] the fake server's answer to meshcat's request; a Ctrl-C must not wait for it
PROMPT_S = 5.0  # [s] KeyboardInterrupt within this of the Ctrl-C: Python's handler runs at once, pyzmq checks signals
POLL_MS = 100  # the fake server's poll, so that it sees the test's end
RESEND_S = 0.2  # [s] between the fake user's Ctrl-Cs: PROMPT_S holds many


def test_a_ctrl_c_stops_serve_waiting_on_a_server_that_stopped_answering(result_dir):
    """serve(zmq_url=...) on a server that answered the check and then stops answering is stopped by Ctrl-C at once:
    the signals are held only while serve starts a server of its own (reviewer, session 65: held around the
    connection, a Ctrl-C waited for an answer that might never come). The Ctrl-C comes when meshcat's request has
    arrived, whatever the machine's speed; the server's thread alone uses its socket."""
    import signal
    import threading
    import time

    import zmq

    ctx, stop, asked = zmq.Context(), threading.Event(), []
    rep = ctx.socket(zmq.REP)
    rep.setsockopt(zmq.LINGER, 0)
    port = rep.bind_to_random_port("tcp://127.0.0.1")

    def server():  # answers the check at once, meshcat's request late (after a Ctrl-C), anything after it at once
        try:
            while not stop.is_set():
                if not rep.poll(POLL_MS):
                    continue
                rep.recv()
                if len(asked) == 1:  # meshcat's request, the first after the check
                    asked.append(time.time())
                    # a Ctrl-C, and another each RESEND_S as a user presses again: one that lands after Python's last
                    # signal check and before libzmq's poll starts is noted but wakes nothing (libzmq does not watch
                    # Python's wakeup descriptor), and the wait went on to the late answer (1 run in 12)
                    os.kill(os.getpid(), signal.SIGINT)
                    while not stop.wait(RESEND_S) and time.time() - asked[1] < LATE_ANSWER_S:
                        os.kill(os.getpid(), signal.SIGINT)
                else:
                    asked.append(None)
                if not stop.is_set():
                    rep.send(b"http://127.0.0.1:7000/static/")
        finally:
            rep.close()

    def first_only(signum, frame):  # the first Ctrl-C is serve's; the repeats after it change nothing
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        raise KeyboardInterrupt

    thread = threading.Thread(target=server, daemon=True)
    previous = signal.signal(signal.SIGINT, first_only)  # (the suite may run with SIGINT ignored)
    try:
        thread.start()
        with pytest.raises(KeyboardInterrupt):
            view.serve(result_dir, zmq_url=f"tcp://127.0.0.1:{port}", print_url=False)
        assert len(asked) == 2 and time.time() - asked[1] < PROMPT_S
    finally:
        signal.signal(signal.SIGINT, previous)
        stop.set()
        thread.join(timeout=LATE_ANSWER_S)
        ctx.term()


def test_an_impact_named_by_the_index_of_the_first_contact_lights_that_point_only(tmp_path):
    """An impact's `contact` may be an index into the task's contacts (Result._hit: "a name or an index"): index 0 is
    the first contact's point alone, as index 1 is the second's; only an unknown index lights every point."""
    from dataclasses import replace

    from planner.task import Contact

    res = view.load_result(make_result_dir(tmp_path))
    two = replace(res, task=replace(res.task, contacts=(Contact(point="foot"), Contact(point="knee"))))
    assert two._hit(0) == ("foot",) and two._hit(1) == ("knee",) and two._hit(2) == ("foot", "knee")


TIME_ROUNDING = 1e-12  # [s] frame and sample times ~1 s against the fixture's: a few sums' rounding


def test_the_frame_nearest_an_impact_between_two_frames_shows_it(tmp_path):
    """The physical-time replay lights an impact from half a frame before it (the frame nearest the impact) to
    IMPACT_FLASH_S after: an impact 0.3 frame after the frame at 0.6 s is shown from that frame on (a frame before an
    impact is no later than 0.5 frame from it), and the frame before that stays dark."""
    from dataclasses import replace

    res = view.load_result(make_result_dir(tmp_path))
    when = T_IMPACT + 0.3 / view.FPS
    moved = replace(res, summary={**res.summary, "impacts": [{**res.summary["impacts"][0], "time": when}]})
    tl = view._timeline(moved, slow_motion=False)
    nearest = int(np.argmin(np.abs(tl.t - when)))
    assert abs(tl.t[nearest] - T_IMPACT) < TIME_ROUNDING  # (the frame at 0.6 s, 0.3 frame before the impact)
    assert tl.highlight["foot"][nearest] and not tl.highlight["foot"][nearest - 1]


def test_a_frozen_interval_matches_an_impact_within_one_percent_of_the_physical_duration(tmp_path):
    """Without tau_start/tau_end in summary.json, frozen_intervals matches each frozen run of numerical time to the
    impact nearest in physical time when it lies within 1 % of the physical duration (0.8 s here: 8 ms), else to every
    contact point. The fixture's numerical horizon is 0.9 s (its impact freezes the clock for 0.1 s), so an impact 8.5
    ms from the frozen run is within 1 % of that but not of the physical duration: no match, both points lit."""
    from dataclasses import replace

    from planner.task import Contact

    res = view.load_result(make_result_dir(tmp_path))
    two = replace(res, task=replace(res.task, contacts=(Contact(point="foot"), Contact(point="knee"))))
    assert abs(0.01 * (res.t[-1] - res.t[0]) - 0.008) < TIME_ROUNDING and res.tau[-1] - res.tau[0] > 0.85
    for offset, hit in ((0.007, ("foot",)), (0.0085, ("foot", "knee"))):
        moved = replace(two, summary={**two.summary, "impacts": [{"time": T_IMPACT + offset, "contact": "foot"}]})
        ((start, end, names),) = moved.frozen_intervals()
        assert names == hit and abs(start - T_IMPACT) < TIME_ROUNDING


# --- the scene against MuJoCo and the page's timing (session 66's third mutation round) ----------------------------

# [m] MuJoCo's and Pinocchio's kinematics of one file agree to rounding; meshcat keeps positions as float64
SCENE_TOL = 1e-9
GROUND_Z = 0.2  # [m] a raised ground, so that a slab drawn with its top anywhere else shows


def _keyed_pose(clip: dict, frame: int) -> np.ndarray:
    """The (4, 4) pose a meshcat clip's .position and .quaternion tracks ([x, y, z, w], three.js) give at `frame`."""
    import pinocchio as pin

    tracks = {t["name"]: {k["time"]: k["value"] for k in t["keys"]} for t in clip["tracks"]}
    x, y, z, w = tracks[".quaternion"][frame]
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = pin.Quaternion(w, x, y, z).matrix(), tracks[".position"][frame]
    return pose


def test_the_scene_puts_each_geom_and_contact_point_where_mujoco_does(result_dir, tmp_path):
    """At keyframes that are samples of the motion, each geom of capler.xml drawn in the page (a part's keyed pose times
    its piece's fixed pose) is where MuJoCo puts that geom at the sample's q, with MuJoCo's size: the box centred with
    its half sizes, a capsule's cylinder centred along the geom's z axis (three.js cylinders run along y) and its two
    caps at +-half-length; the contact marker is MuJoCo's foot site (session 66's mutation testing: a pose composed
    as placement @ joint pose, caps along y, a box of half its size, an unrotated cylinder, and the marker at the
    shank's joint instead of the foot, with every test green)."""
    import mujoco

    res = view.load_result(result_dir)
    geometry, fixed, clips = _scene(_page_commands(view.render_html(result_dir, tmp_path / "page.html").read_text()))
    mj = mujoco.MjModel.from_xml_path(str(ROBOTS / "capler.xml"))
    data = mujoco.MjData(mj)
    for t in (0.0, 0.35, T_END):  # frames 0, 21, 48: samples of the fixture (a flight pose bends the knee)
        frame = int(round(t * view.FPS))
        data.qpos[:] = res.q[int(np.argmin(np.abs(res.t - t)))]
        mujoco.mj_kinematics(mj, data)
        for name in ("base_geom", "thigh_geom", "shank_geom"):
            g = mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_GEOM, name)
            centre, axes, size = data.geom_xpos[g], data.geom_xmat[g].reshape(3, 3), mj.geom_size[g]
            part = _keyed_pose(clips[f"{view.ROOT}/robot/{name}"], frame)
            world = [part @ fixed[f"{view.ROOT}/robot/{name}/{k}"] for k in range(3 if name != "base_geom" else 1)]
            assert np.max(np.abs(world[0][:3, 3] - centre)) < SCENE_TOL, (name, t)
            if name == "base_geom":
                box = geometry[f"{view.ROOT}/robot/{name}/0"]
                assert np.allclose([box["width"], box["height"], box["depth"]], 2 * size, atol=SCENE_TOL)
                assert np.max(np.abs(world[0][:3, :3] - axes)) < SCENE_TOL
                continue
            cylinder = geometry[f"{view.ROOT}/robot/{name}/0"]
            assert abs(cylinder["height"] - 2 * size[1]) < SCENE_TOL
            assert abs(cylinder["radiusTop"] - size[0]) < SCENE_TOL
            along = min(np.max(np.abs(world[0][:3, 1] - sign * axes[:, 2])) for sign in (1.0, -1.0))
            assert along < SCENE_TOL, (name, t)  # the cylinder's y axis is the geom's z axis
            caps = sorted((w[:3, 3] for w in world[1:]), key=lambda p: float(p @ axes[:, 2]))
            for cap, s in zip(caps, (-1.0, 1.0)):
                assert np.max(np.abs(cap - (centre + s * size[1] * axes[:, 2]))) < SCENE_TOL, (name, t)
        foot = data.site_xpos[mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_SITE, "foot")]
        assert np.max(np.abs(_keyed_pose(clips[f"{view.ROOT}/contacts/foot"], frame)[:3, 3] - foot)) < SCENE_TOL, t


def test_the_pages_last_keyframe_and_clock_end_are_the_replays_end(result_dir, tmp_path):
    """The page's last keyframe is at the replay's exact end in frames ((t_end - t_0) FPS, no whole number for a
    duration that is no multiple of 1/FPS), and the overlay's clock shows its last frame from that end on: in
    physical time t_end - t_0, in slow motion tau_end - tau_0 (0.9 s for the fixture, whose physical end is 0.8 s).
    The animation loops (session 66's mutation testing: the last keyframe at its index instead of its time, the
    slow-motion clock's end at the physical end, and a replay that played once, with every test green)."""
    from test_result import small_result

    from planner.result import write_results

    write_results(small_result(), tmp_path / "r")
    for directory, slow in ((tmp_path / "r", False), (result_dir, True)):
        res = view.load_result(directory)
        html = view.render_html(directory, tmp_path / f"page_{slow}.html", slow_motion=slow).read_text()
        grid = res.tau if slow else res.t
        end = float(grid[-1] - grid[0])
        assert slow or not math.isclose(end * view.FPS % 1.0, 0.0, abs_tol=1e-6)  # no multiple of 1/FPS
        (anim,) = [c for c in _page_commands(html) if c["type"] == "set_animation"]
        assert anim["options"]["repetitions"] > 1
        keys = [a["clip"]["tracks"][0]["keys"] for a in anim["animations"]]
        assert all(k[-1]["time"] == pytest.approx(end * view.FPS, abs=TIME_ROUNDING) for k in keys), (slow, end)
        overlay = json.loads(re.search(r"var planner = (.*);\n", html).group(1))
        assert overlay["end"] == pytest.approx(end, abs=TIME_ROUNDING), slow


def test_the_ground_is_the_tasks_plane_and_the_camera_frames_the_motion(result_dir, tmp_path):
    """The ground slab's top face is the task's ground height (0.2 m here), under the robot; ROOT is shifted so that
    the camera, which looks along +y at the origin from its distance, has every keyframed part and contact point within
    its field of view and is aimed at their middle (session 66's mutation testing: a slab above the plane and the scene
    shifted the wrong way in z, with every test green)."""
    lifted, source = tmp_path / "lifted.toml", (ROBOTS / "capler.toml").read_text()
    assert source.count("ground_height = 0.0\n") == 1
    lifted.write_text(source.replace("ground_height = 0.0\n", f"ground_height = {GROUND_Z}\n"))
    summary = json.loads((result_dir / "summary.json").read_text())
    (result_dir / "summary.json").write_text(json.dumps({**summary, "task": str(lifted)}))
    commands = _page_commands(view.render_html(result_dir, tmp_path / "page.html").read_text())
    geometries, fixed, clips = _scene(commands)
    box = geometries[f"{view.ROOT}/ground"]
    assert abs(fixed[f"{view.ROOT}/ground"][2, 3] + box["depth"] / 2 - GROUND_Z) < SCENE_TOL
    distance = [c["value"][2] for c in commands if c["type"] == "set_property" and c["property"] == "position"][-1]
    tan_half = math.tan(math.radians(view.CAMERA_FOV_DEG) / 2)
    shift = fixed[view.ROOT][:3, 3]
    keyed = np.array([k["value"] for clip in clips.values() for track in clip["tracks"]
                      if track["name"] == ".position" for k in track["keys"]]) + shift
    assert np.all(np.abs(keyed[:, 0]) <= distance * tan_half * view.CAMERA_ASPECT)
    assert np.all(np.abs(keyed[:, 2]) <= distance * tan_half)
    # aimed at the middle of what it shows (the slab's bottom to the highest part) up to the half robot size of slack
    # the framing adds around the parts' origins
    bottom = GROUND_Z - box["depth"] + shift[2]
    slack = view._robot_size(load_robot(ROBOTS / "capler.xml")) / 2
    assert abs((bottom + keyed[:, 2].max()) / 2) <= slack + SCENE_TOL, (bottom, keyed[:, 2].max(), slack)



def test_a_mesh_is_drawn_at_its_files_scale(tmp_path):
    """A URDF mesh's scale attribute (2, 3, 4) is the scale of its piece (session 66's mutation testing: the scale
    dropped, every mesh drawn at unit scale, with every test green)."""
    import itertools

    stl = tmp_path / "tet.stl"
    corners = ((0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1))  # a tetrahedron
    facets = "".join("facet normal 0 0 0\nouter loop\n" + "".join(f"vertex {a} {b} {c}\n" for a, b, c in tri)
                     + "endloop\nendfacet\n" for tri in itertools.combinations(corners, 3))
    stl.write_text(f"solid t\n{facets}endsolid t\n")
    source = (ROBOTS / "capler.urdf").read_text()
    assert source.count('<box size="0.12 0.08 0.08"/>') == 1
    urdf = tmp_path / "mesh.urdf"
    urdf.write_text(source.replace('<box size="0.12 0.08 0.08"/>', f'<mesh filename="{stl}" scale="2 3 4"/>'))
    parts, note = view.robot_parts(load_robot(urdf))
    assert note is None
    (base,) = [p for p in parts if p.name.startswith("base")]
    assert np.array_equal(base.pieces[0][1], np.diag([2.0, 3.0, 4.0, 1.0]))


def test_load_result_reads_each_array_as_written(result_dir):
    """load_result's arrays are trajectory.npz's own, each under its own name: lambda_t is the file's lambda_t (a tenth
    of lambda_n in the fixture), not lambda_n (session 66's mutation testing: lambda_t read from lambda_n, with every
    test green)."""
    res = view.load_result(result_dir)
    with np.load(result_dir / "trajectory.npz") as npz:
        for key in ("t", "q", "v", "u", "y", "lambda_n", "lambda_t"):
            assert np.array_equal(getattr(res, key), npz[key]), key


def test_an_older_summary_without_impacts_takes_them_from_the_trajectory(result_dir):
    """A summary.json without "impacts" (an older result) has its impacts from trajectory.npz's impact_times, each on
    every contact point, and the physical-time replay lights the foot at T_IMPACT (session 66's mutation testing: no
    impacts at all for such a result, nothing lit, with every test green)."""
    summary = json.loads((result_dir / "summary.json").read_text())
    (result_dir / "summary.json").write_text(json.dumps({k: v for k, v in summary.items() if k != "impacts"}))
    res = view.load_result(result_dir)
    assert res.impacts() == [(T_IMPACT, ("foot",))] and res.impacts(taps=True) == []
    tl = view._timeline(res, slow_motion=False)
    assert tl.highlight["foot"][int(np.argmin(np.abs(tl.t - T_IMPACT)))]


def test_slow_motion_lights_the_frames_at_both_ends_of_a_frozen_interval(result_dir):
    """A frozen interval [tau_start, tau_end] is closed: the slow-motion frames at its two ends are lit, the frames
    just outside it are not (session 66's mutation testing: an open interval that left the frames where the clock
    stops and restarts dark, with every test green)."""
    from dataclasses import replace

    res = view.load_result(result_dir)
    start, end = (float(res.tau[0] + k / view.FPS) for k in (36, 42))  # the frame times the timeline computes
    moved = replace(res, summary={**res.summary, "impacts": [{**res.summary["impacts"][0], "tau_start": start,
                                                              "tau_end": end}]})
    lit = np.flatnonzero(view._timeline(moved, slow_motion=True).highlight["foot"])
    assert lit.tolist() == list(range(36, 43))
