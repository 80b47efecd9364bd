"""The result plots (planner.plots): written, not blank, and drawing the right things.

Uses the synthetic Capler result of tests/test_view.py (a hop over the first hole, one impact).
"""
from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from planner import plots, view
from planner.model import coordinate_units, load_robot
from test_view import ROBOTS, T_IMPACT, make_result_dir

MIN_PIXEL_STD = 1.0  # a plot with a smaller pixel standard deviation is blank [0-255 levels]
MIN_SIZE = (400, 200)  # every plot is at least this many pixels (width, height)
POS_TOL = 1e-9  # contact point positions from forward kinematics [m]

ALL_PLOTS = {"states.png", "torques.png", "contact_forces.png", "clock.png", "foot_path.png"}


@pytest.fixture
def result_dir(tmp_path):
    return make_result_dir(tmp_path)


def test_every_plot_is_written_and_not_blank(result_dir):
    """plot_results writes the five PNGs into the result directory; each is large enough and not blank."""
    paths = plots.plot_results(result_dir)
    assert {p.name for p in paths} == ALL_PLOTS
    for p in paths:
        assert p.parent == result_dir and p.stat().st_size > 0
        img = np.asarray(Image.open(p).convert("RGB")).astype(float)
        assert img.shape[1] >= MIN_SIZE[0] and img.shape[0] >= MIN_SIZE[1]
        assert img.std() > MIN_PIXEL_STD, f"{p.name} is blank"
    assert not list(result_dir.glob(".*.tmp"))  # atomic writes leave no temporary files


def test_plots_are_not_written_beside_another_runs_result(result_dir, monkeypatch):
    """A plot is renamed in only while summary.json is still the result it was drawn from: a run's plots, drawn after
    its result was written, landed beside the result another run wrote into the same directory meanwhile (session
    57's tester: B's summary and trajectory with A's five plots). Nothing of them is left, no temp file either."""
    import json

    from planner.result import write_files

    summary_path = result_dir / "summary.json"
    summary = {**json.loads(summary_path.read_text()), "result_id": "this-run"}
    with np.load(result_dir / "trajectory.npz") as npz:
        arrays = {**npz, "result_id": np.array("this-run")}
    write_files(result_dir, arrays, summary, "this-run")
    drawn_from = plots.load_result(result_dir)
    summary["result_id"] = "another-run"
    summary_path.write_text(json.dumps(summary))  # another run's result, written after this one was read
    monkeypatch.setattr(plots, "load_result", lambda out_dir: drawn_from)
    assert plots.plot_results(result_dir) == []
    assert not list(result_dir.glob("*.png")) and not list(result_dir.glob(".*.tmp"))

def test_contact_forces_plot_is_skipped_without_forces(result_dir):
    """lambda_n and lambda_t are optional in the contract: without them there is no force plot."""
    with np.load(result_dir / "trajectory.npz") as npz:
        arrays = {k: npz[k] for k in npz.files if not k.startswith("lambda")}
    np.savez(result_dir / "trajectory.npz", **arrays)
    assert {p.name for p in plots.plot_results(result_dir)} == ALL_PLOTS - {"contact_forces.png"}


def test_impacts_are_marked_on_every_time_panel(result_dir):
    """Each state panel carries a vertical line at the impact time."""
    fig, _ = plots._states(view.load_result(result_dir))
    panels = [ax for ax in fig.axes if ax.get_visible()]
    assert len(panels) == 8  # q and v of Capler's 4 coordinates
    for ax in panels:
        verticals = [ln for ln in ax.get_lines() if np.ptp(ln.get_xdata()) == 0]
        assert any(np.isclose(ln.get_xdata()[0], T_IMPACT) for ln in verticals)


def test_foot_path_plot_draws_the_foot_the_holes_and_the_impact(result_dir):
    """The foot path is the foot's forward kinematics (start at x = 0, landing at x = 1 on the ground),
    the three holes are a x b ellipses at their centres, and the impact is marked where the foot lands."""
    from matplotlib.patches import Ellipse

    res = view.load_result(result_dir)
    fig, _ = plots._foot_path(res)
    ax = fig.axes[0]
    (path,) = [ln for ln in ax.get_lines() if ln.get_label() == "foot path"]
    x, z = np.asarray(path.get_xdata()), np.asarray(path.get_ydata())
    assert len(x) == len(res.t)
    assert abs(x[0]) < POS_TOL and abs(z[0]) < POS_TOL
    assert abs(x[-1] - 1.0) < POS_TOL and abs(z[-1]) < POS_TOL
    ellipses = sorted((p for p in ax.patches if isinstance(p, Ellipse)), key=lambda e: e.center[0])
    assert [(e.center, e.width, e.height) for e in ellipses] == [((h.x, h.z), 2 * h.a, 2 * h.b) for h in res.holes]
    (impact,) = [ln for ln in ax.get_lines() if ln.get_label() == "impact"]
    assert np.allclose([impact.get_xdata()[0], impact.get_ydata()[0]], [1.0, 0.0], atol=POS_TOL)


def test_clock_plot_shades_the_frozen_interval(result_dir):
    """The clock plot shades exactly the tau intervals where the clock stops (the impact)."""
    fig, _ = plots._clock(view.load_result(result_dir))
    spans = fig.axes[0].patches  # the shaded intervals are the only patches
    xs = np.array([[p.get_x(), p.get_x() + p.get_width()] for p in spans])
    assert np.isclose(xs.min(), T_IMPACT) and np.isclose(xs.max(), T_IMPACT + 0.1)


@pytest.mark.parametrize("robot_file, q_units, v_units", [
    ("capler.xml", ["m", "m", "rad", "rad"], ["m", "m", "rad", "rad"]),  # composite slide-x/slide-z base
    ("capler.urdf", ["m", "m", "rad", "rad"], ["m", "m", "rad", "rad"]),
])
def test_axis_units_follow_the_joint_types(robot_file, q_units, v_units):
    """Slide joints are in m, hinges in rad, whichever way the file declares the planar base."""
    assert coordinate_units(load_robot(ROBOTS / robot_file).model) == (q_units, v_units)


def test_without_a_task_there_is_no_foot_path(result_dir):
    """summary.json may name no task: the plots that need none are still written."""
    import json

    summary = json.loads((result_dir / "summary.json").read_text())
    (result_dir / "summary.json").write_text(json.dumps({**summary, "task": None}))
    assert {p.name for p in plots.plot_results(result_dir)} == ALL_PLOTS - {"foot_path.png"}


def test_contact_forces_are_drawn_as_held_steps(result_dir):
    """A sample's contact force is its step's (the step ending there), so the force plot draws steps ("steps-pre"), as
    the torques: a ramp from a stance's 9.8 N to a flight step's 0 drew 4.9 N on a foot already in the air."""
    fig, _ = plots._contact_forces(view.load_result(result_dir))
    lines = [ln for ax in fig.axes for ln in ax.get_lines() if np.ptp(ln.get_xdata()) > 0]
    assert lines and all(ln.get_drawstyle() == "steps-pre" for ln in lines)


def test_taps_are_marked_apart_from_impacts(result_dir):
    """An impact summary.json marks as a tap is drawn dotted and labelled "tap", not as one more "impact" line (13
    alike lines for a report of 9 impacts and 4 taps), and clock.png and the slow-motion replay
    (Result.frozen_intervals) do not shade it as a frozen impact."""
    import json

    summary = json.loads((result_dir / "summary.json").read_text())
    (result_dir / "summary.json").write_text(json.dumps({**summary, "impacts": [{**i, "tap": True}
                                                                               for i in summary["impacts"]]}))
    fig, _ = plots._states(view.load_result(result_dir))
    verticals = [ln for ln in fig.axes[0].get_lines() if np.ptp(ln.get_xdata()) == 0]
    assert verticals and all(ln.get_linestyle() == ":" for ln in verticals)
    assert "tap" in [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    clock, _ = plots._clock(view.load_result(result_dir))  # (a tap's step was shaded "frozen (impact)")
    assert len(clock.axes[0].patches) == 0 and view.load_result(result_dir).frozen_intervals() == []
    for tap, spans in ((True, 0), (False, 1)):  # as summary.json gives them, with their numerical times
        timed = [{**i, "tap": tap, "tau_start": 0.3, "tau_end": 0.35} for i in summary["impacts"]]
        (result_dir / "summary.json").write_text(json.dumps({**summary, "impacts": timed}))
        assert len(view.load_result(result_dir).frozen_intervals()) == spans


def test_torques_are_drawn_as_held_steps(result_dir):
    """u[i] is held from sample i-1 to sample i (zero-order hold), so the torque plot draws steps ("steps-pre"): midway
    through a step it reads the held u[i], not the ramp from u[i-1] a line drew (a hop's 7.84 N push read 3.92 N)."""
    res = view.load_result(result_dir)
    fig, _ = plots._torques(res)
    (line, *_) = [ln for ln in fig.axes[0].get_lines() if np.ptp(ln.get_xdata()) > 0]
    assert line.get_drawstyle() == "steps-pre"


def test_a_simulation_draws_no_holes_and_a_corner_point_is_one_path(result_dir):
    """The holes are a plan's: a simulation (which has none) draws none, where its task's [plan] holes were drawn under
    a drop sliding across them; a point listed by two contacts (a corner) is one path in the legend, not two."""
    import dataclasses
    import json

    summary = json.loads((result_dir / "summary.json").read_text())
    (result_dir / "summary.json").write_text(json.dumps({**summary, "command": "simulate"}))
    res = view.load_result(result_dir)
    assert res.task.plan.holes and res.holes == ()
    wall = dataclasses.replace(res.task.contacts[0], normal=(1.0, 0.0, 0.0))
    corner = dataclasses.replace(res.task, contacts=(*res.task.contacts, wall))
    fig, _ = plots._foot_path(dataclasses.replace(res, task=corner))
    assert [ln.get_label() for ln in fig.axes[0].get_lines()].count("foot path") == 1


def test_foot_path_draws_the_planes_the_contacts_touch(result_dir):
    """foot_path.png shades what lies behind each plane the task's contacts touch, through (0, ground_height): a
    slope's shaded region is bounded by its own line (it was always a horizontal ground, which a point sliding down
    the slope crossed), and a task without the ground normal draws no ground."""
    import dataclasses

    from matplotlib.patches import Polygon

    res = view.load_result(result_dir)
    n = np.array([-0.5, 0.0, np.sqrt(3) / 2])
    slope = dataclasses.replace(res.task, contacts=(dataclasses.replace(res.task.contacts[0], normal=tuple(n)),))
    fig, _ = plots._foot_path(dataclasses.replace(res, task=slope))
    (plane,) = [p for p in fig.axes[0].patches if isinstance(p, Polygon)]
    assert plane.get_label().startswith("plane, normal (-0.5, 0, 0.866)")
    corners = plane.get_xy()
    side = n[0] * corners[:, 0] + n[2] * (corners[:, 1] - res.ground_height)
    assert np.all(side <= POS_TOL) and np.sum(np.abs(side) <= POS_TOL) >= 2  # its edge on the line
    flat, = [p for p in plots._foot_path(res)[0].axes[0].patches if isinstance(p, Polygon)]
    assert flat.get_label() == "ground" and np.isclose(flat.get_xy()[:, 1].max(), res.ground_height)


def test_contact_force_legends_name_the_touching_contacts_as_the_report_does(result_dir):
    """The force columns are the contacts that touch: beside a touches = false contact the foot keeps its name and its
    ±μ λn lines ("contact 0" and none before); one point on two planes is foot#1 and foot#2 (the report's labels),
    not "foot" twice."""
    import dataclasses

    res = view.load_result(result_dir)
    foot = res.task.contacts[0]
    never = dataclasses.replace(foot, point="knee", touches=False)
    fig, _ = plots._contact_forces(dataclasses.replace(res, task=dataclasses.replace(res.task, contacts=(foot, never))))
    labels = [ln.get_label() for ax in fig.axes for ln in ax.get_lines()]
    assert "foot" in labels and "±μ λn (foot)" in labels and "contact 0" not in labels
    wall = dataclasses.replace(foot, normal=(1.0, 0.0, 0.0))
    corner = dataclasses.replace(res, task=dataclasses.replace(res.task, contacts=(foot, wall)),
                                 lambda_n=np.tile(res.lambda_n, 2), lambda_t=np.tile(res.lambda_t, 2))
    fig, _ = plots._contact_forces(corner)
    assert [ln.get_label() for ln in fig.axes[0].get_lines()][:2] == ["foot#1", "foot#2"]
    # a simulation reads touches nowhere: its columns are every contact's
    both = dataclasses.replace(corner, task=dataclasses.replace(res.task, contacts=(foot, never)),
                               summary={**res.summary, "command": "simulate"})
    fig, _ = plots._contact_forces(both)
    assert [ln.get_label() for ln in fig.axes[0].get_lines()][:2] == ["foot", "knee"]


def test_torque_panels_carry_their_own_units(result_dir, tmp_path):
    """A robot with slide and hinge motors: each torque panel says its own unit (N for the slides, N m for the hinge),
    as the states' panels do; a panel set's mixed units left every panel without one."""
    fig = _torques_of(result_dir, tmp_path / "cart.xml", 0.0, (
        '<mujoco><worldbody><body name="cart"><joint name="x" type="slide" axis="1 0 0"/><joint name="z" type="slide" '
        'axis="0 0 1"/><inertial pos="0 0 0" mass="1" diaginertia="0.01 0.01 0.01"/><body name="pole"><joint '
        'name="twist" type="hinge" axis="0 1 0"/><inertial pos="0 0 -0.1" mass="0.1" diaginertia="0.001 0.001 0.001"/>'
        '</body></body></worldbody><actuator><motor name="push" joint="x"/><motor name="lift" joint="z"/><motor '
        'name="turn" joint="twist"/></actuator></mujoco>'))
    assert [ax.get_ylabel() for ax in fig.axes] == ["u [N]", "u [N]", "u [N m]"]


def _torques_of(result_dir, path, u: float, xml: str):
    """The torques figure of result_dir's result on the robot file `xml` (written to path), every control u."""
    import dataclasses

    path.write_text(xml)
    res = view.load_result(result_dir)
    robot = load_robot(path)
    fig, _ = plots._torques(dataclasses.replace(res, robot=robot, u=np.full((len(res.t), robot.nu), u)))
    return fig


def test_a_geared_motor_is_drawn_as_its_joint_force(result_dir, tmp_path):
    """A motor with gear 2 acts on its joint with 2 u: its panel draws gear x u in N, says so in its label, and a
    gear-1 motor beside it stays u (u = 1 of a gear-2 motor was drawn as 1 N where the mass felt 2 N)."""
    fig = _torques_of(result_dir, tmp_path / "geared.xml", 1.0, (
        '<mujoco><worldbody><body name="mass"><joint name="x" type="slide" axis="1 0 0"/><joint name="z" type="slide" '
        'axis="0 0 1"/><inertial pos="0 0 0" mass="1" diaginertia="0.01 0.01 0.01"/></body></worldbody><actuator>'
        '<motor name="push" joint="x" gear="2"/><motor name="lift" joint="z"/></actuator></mujoco>'))
    (push,), (lift,) = (ax.get_lines()[:1] for ax in fig.axes)
    assert [ax.get_ylabel() for ax in fig.axes] == ["gear x u [N]", "u [N]"]
    assert push.get_label() == "push (gear 2 x u)" and np.all(push.get_ydata() == 2.0)
    assert lift.get_label() == "lift" and np.all(lift.get_ydata() == 1.0)


def test_a_failed_runs_plots_say_it_did_not_converge(result_dir):
    """A failed run's plots (DIR/failed) are titled NOT converged, as its HTML replay is (its last iterate looked like
    a plan); a converged run's are not."""
    import dataclasses

    res = view.load_result(result_dir)
    for converged, marked in ((True, False), (False, True)):
        shown = dataclasses.replace(res, summary={**res.summary, "converged": converged})
        for draw in (plots._states, plots._torques, plots._clock):
            fig, _ = draw(shown)
            assert fig._suptitle.get_text().endswith(" (NOT converged)") is marked


def test_names_are_drawn_as_text_and_listed_in_legends(result_dir, tmp_path, monkeypatch):
    """The robot file's names are text, not mathtext: a robot named '$\\foo$' failed every plot (ParseFatalException),
    so the command of a validated plan exited 1; an actuator named '_fx' is in its panel's legend (matplotlib leaves
    out labels that start with '_')."""
    import dataclasses

    res = view.load_result(result_dir)
    (tmp_path / "math.xml").write_text((ROBOTS / "capler.xml").read_text().replace('model="capler"', 'model="$\\foo$"'))
    named = dataclasses.replace(res, robot=load_robot(tmp_path / "math.xml"))
    assert named.robot.name == "$\\foo$"
    monkeypatch.setattr(plots, "load_result", lambda out_dir: named)
    assert {p.name for p in plots.plot_results(result_dir)} == ALL_PLOTS
    fig = _torques_of(result_dir, tmp_path / "under.xml", 1.0, (
        '<mujoco><worldbody><body name="mass"><joint name="x" type="slide" axis="1 0 0"/><joint name="z" type="slide" '
        'axis="0 0 1"/><inertial pos="0 0 0" mass="1" diaginertia="0.01 0.01 0.01"/></body></worldbody><actuator>'
        '<motor name="_fx" joint="x"/><motor name="lift" joint="z"/></actuator></mujoco>'))
    assert [t.get_text() for ax in fig.axes for t in ax.get_legend().get_texts()][:1] == [" _fx"]


def test_the_impact_lines_are_named_once_in_the_torque_legends(tmp_path):
    """Every torque panel draws the impact line, but only the first panel's legend names it (_mark_impacts' legend
    flag): Capler's two motors are two panels, and the second's legend lists its motor alone."""
    fig, _ = plots._torques(view.load_result(make_result_dir(tmp_path)))
    panels = [ax for ax in fig.axes if ax.get_visible()]
    assert len(panels) == 2
    for ax in panels:  # the line is drawn in both
        assert any(np.ptp(ln.get_xdata()) == 0 and np.isclose(ln.get_xdata()[0], T_IMPACT) for ln in ax.get_lines())
    labels = [ax.get_legend_handles_labels()[1] for ax in panels]
    assert "impact" in labels[0] and "impact" not in labels[1]


def test_the_cone_lines_are_mu_times_the_normal_force(result_dir):
    """contact_forces.png's dotted cone lines are +-mu lambda_n of the task's contact, as its legend says (session 66's
    mutation testing: drawn at +-lambda_n, a cone 1/mu times too wide, with every test green)."""
    res = view.load_result(result_dir)
    mu = res.task.contacts[0].mu
    assert mu not in (0.0, 1.0)
    fig, _ = plots._contact_forces(res)
    dotted = [line for line in fig.axes[1].get_lines() if line.get_linestyle() == ":"]
    assert len(dotted) == 2
    for line, sign in zip(dotted, (1.0, -1.0)):
        np.testing.assert_allclose(line.get_ydata(), sign * mu * res.lambda_n[:, 0])


def test_velocity_panels_are_per_second(result_dir):
    """states.png's four velocity panels are in m/s or rad/s (session 66's mutation testing: labelled m and rad with
    every test green)."""
    fig, _ = plots._states(view.load_result(result_dir))
    labels = [ax.get_ylabel() for ax in fig.axes if ax.get_visible()]
    assert sum(label.endswith("/s]") for label in labels) == 4, labels


def test_the_impact_is_marked_where_the_foot_is_at_it(result_dir):
    """The impact cross sits at the foot's forward kinematics at the impact's sample, also when the foot moves on after
    it (here the whole robot moved 0.1 m along x from the sample after the impact's pair; session 66's mutation
    testing: the cross at the next sample, 0.1 m off, with every test green)."""
    import dataclasses

    res = view.load_result(result_dir)
    ((t_impact, _),) = res.impacts()
    first = int(np.searchsorted(res.t, t_impact))
    assert res.t[first + 1] == res.t[first]  # the impact's pair of samples
    q = res.q.copy()
    q[first + 2:, 0] += 0.1  # base_x
    fig, _ = plots._foot_path(dataclasses.replace(res, q=q))
    (impact,) = [line for line in fig.axes[0].get_lines() if line.get_label() == "impact"]
    assert np.allclose([impact.get_xdata()[0], impact.get_ydata()[0]], [1.0, 0.0], atol=POS_TOL)
