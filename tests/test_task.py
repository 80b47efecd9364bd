"""Task files: every default task loads, and every kind of bad key or value is named in the error."""
from __future__ import annotations

import json
import math
import re
import warnings
from dataclasses import replace
from pathlib import Path

import pytest

from planner.errors import InputError, RobotFileError, TaskError, UnknownNameError
from planner.model import load_robot
from planner.simulate import simulate
from planner.task import (Contact, Ellipse, GaitPronto, Homotopy, Horizon, Initial, Periodic, Plan, Task, load_task, parse_task,
                          task_to_json, tasks_apart, tasks_between)

ROBOTS = Path(__file__).resolve().parent.parent / "robots"
ROUNDING = 1e-15  # a + s (b - a) of numbers ~1 in double precision
MINIMAL = {"contacts": [{"point": "foot"}], "initial": {"q": [0.0, 0.4, 0.0, 0.0]}, "horizon": {"tau_f": 1.0, "N": 10}}


@pytest.mark.parametrize("toml", sorted(ROBOTS.glob("*.toml")), ids=lambda p: p.stem)
def test_default_tasks_match_their_robots(toml):
    """Every task in robots/ parses and fits the robot file beside it (NAME_variant.toml: NAME.xml)."""
    stems = (toml.stem, toml.stem.rsplit("_", 1)[0])  # biped_gait1.toml: biped.xml; point_mass_hop.toml: point_mass.xml
    robot_file = next(p for s in stems for p in (toml.with_name(s + ".xml"), toml.with_name(s + ".urdf")) if p.exists())
    load_task(toml).check_against(load_robot(robot_file))


def test_capler_task_holds_the_paper_numbers():
    """robots/capler.toml carries Sec. 7's scene: h = 0.02, mu = 0.8, a_n = 200, a_t = 600, 3 holes."""
    task = load_task(ROBOTS / "capler.toml")
    assert task.horizon.h == pytest.approx(0.02)
    (c,) = task.contacts
    assert (c.mu, c.a_n, c.a_t) == (0.8, 200.0, 600.0)
    assert [e.x for e in task.plan.holes] == [0.5, 1.5, 2.5]
    assert task.plan.homotopy.n_nlp == 5


def _with(path: str, value):
    data = {k: (dict(v) if isinstance(v, dict) else list(v)) for k, v in MINIMAL.items()}
    *parents, key = path.split(".")
    node = data
    for p in parents:
        node = node.setdefault(p, {})
    node[key] = value
    return data


@pytest.mark.parametrize(
    "path, value, message",
    [
        ("bogus", 1, r"unknown key 'bogus'; valid keys: contacts, initial"),
        ("horizon.N", 0, r"horizon.N = 0 .* in \[1, 10000000\]"),
        ("horizon.tau_f", -1.0, r"horizon.tau_f = -1.0 .* > 0"),
        ("horizon.N", 2.5, r"horizon.N must be an integer, got float"),
        ("initial.q", "up", r"initial.q must be an array, got str"),
        ("ground_height", True, r"ground_height must be a number, got bool"),
        ("contacts", [{"point": "foot", "restitution": 1.5}], r"restitution = 1.5 .* in \[0, 1\]"),
        ("contacts", [{"point": "foot", "friction": 1}], r"unknown key 'contacts\[0\].friction'; valid keys: point, mu"),
        ("horizon.tau_f", math.inf, r"horizon.tau_f must be a finite number, got inf"),
        ("initial.q", [0.0, -math.inf], r"initial.q\[1\] must be a finite number, got -inf"),
        ("contacts", [{"point": "foot", "a_n": math.inf}], r"contacts\[0\].a_n must be a finite number, got inf"),
        ("contacts", [{"point": "foot"}, {"point": "foot", "normal": [0.0, 0.0, 2.0]}],
         r"contacts = .* one entry per point and plane"),
        # the same plane by normals that normalize apart by rounding: two half impacts were reported
        ("contacts", [{"point": "foot", "normal": [1.0, 0.0, 1.0]}, {"point": "foot", "normal": [3.0, 0.0, 3.0]}],
         r"contacts = .* one entry per point and plane"),
        # a point named like another's corner label: the plan reported 9.81 N on a point that never touched (the
        # forces looked up by label were the corner's), or crashed in the build with friction (session 64's tester)
        ("contacts", [{"point": "foot"}, {"point": "foot", "normal": [1.0, 0.0, 1.0]}, {"point": "foot#1"}],
         r"contacts\[2\].point = 'foot#1' is not allowed; it must be another name than contacts\[0\]'s label: "
         r"point 'foot' on several planes is labelled foot#1, foot#2"),
        # beyond these the solve overflowed: nan in g (mu), inf in the Jacobian (a hole's half-axis)
        ("contacts", [{"point": "foot", "mu": 1e300}], r"contacts\[0\].mu = 1e\+300 .* in \[0, 1e\+06\]"),
        # a start or target of 1e300 (finite) overflowed in the solve: NaNs, exit 1, or an internal variable named
        ("initial", {"q": [0.0, 0.5, 0.0, 0.0], "v": [1e300, 0.0, 0.0, 0.0]},
         r"^initial.v\[0\] = 1e\+300 is not allowed; it must be within ±1e\+06"),
        ("initial.q", [0.0, -2e6, 0.0, 0.0], r"^initial.q\[1\] = -2000000.0 is not allowed; it must be within ±1e\+06"),
        ("plan", {"target_q": [1e300, 0.4, 0.0, 0.0]}, r"^plan.target_q\[0\] = 1e\+300 is not allowed"),
        ("plan", {"target_q": [3.0, 0.4, 0.0, 0.0], "target_v": [0.0, 0.0, 0.0, -1e7]},
         r"^plan.target_v\[3\] = -10000000.0 is not allowed"),
        ("plan", {"target_q": [3.0, 0.4, 0.0, 0.0], "holes": [{"x": 1e300, "a": 0.1, "b": 0.1}]},
         r"plan.holes\[0\].x = 1e\+300 is not allowed; it must be within ±1e\+06 m"),
        ("ground_height", -2e6, r"^ground_height = -2000000.0 is not allowed; it must be within ±1e\+06"),
        ("plan", {"target_q": [3.0, 0.4, 0.0, 0.0], "holes": [{"x": 1.0, "a": 1e-300, "b": 0.1}]},
         r"plan.holes\[0\].a = 1e-300 .* >= 1e-06"),
        # a repeat doubled the rows (dependent constraints)
        ("plan", {"target_q": [3.0, 0.4, 0.0, 0.0], "above_ground": ["knee", "knee"]},
         r"plan.above_ground = \['knee', 'knee'\] .* each point once"),
        ("plan", {"target_q": [3.0, 0.4, 0.0, 0.0], "holes": [{"x": 1.0, "a": 0.2, "b": 0.1}] * 2},
         r"^plan.holes\[1\] = \[1.0, 0.0, 0.2, 0.1\] is not allowed; it must be each hole once \(it repeats "
         r"plan.holes\[0\]\)$"),  # (it listed every hole: a 646 kB line for 20000)
        ("horizon", {"tau_f": 2.5, "N": 2**31}, r"horizon.N = 2147483648 .* a C int holds, .* own range is checked"),
        ("plan", {"target_q": [3.0, 0.4, 0.0, 0.0], "joint_bounds": [{"joint": "hip", "lower": -1.0}, {"joint": "hip"}]},
         r"plan.joint_bounds = \['hip', 'hip'\] .* one entry per joint"),
        ("plan", {"target_q": [3.0, 0.4, 0.0, 0.0], "homotopy": {"kappa": 1e200, "n_nlp": 3}},
         r"plan.homotopy = .* last penalty .* at most 1e300"),  # kappa**i raised OverflowError in the solve
        ("plan", {"target_q": [3.0, 0.4, 0.0, 0.0], "homotopy": {"kappa": 1e4, "n_nlp": 80}}, r"at most 1e300"),
        # kappa = 1.0001 scheduled 92109 NLPs through SolveOptions.rho_max; n_nlp itself is capped too
        ("plan", {"target_q": [3.0, 0.4, 0.0, 0.0], "homotopy": {"kappa": 1.01, "n_nlp": 101}}, r"n_nlp = 101 .* \[1, 100\]"),
        ("horizon", {"tau_f": 2.5, "N": 10**9}, r"horizon.N = 1000000000 .* in \[1, 10000000\]"),  # built for ever
        # only physical_time adds the speeds of time it bounds: without it the key was a silent no-op
        ("horizon", {"tau_f": 1.0, "N": 10, "max_time_speed": 1.5},
         r"^horizon.max_time_speed = 1.5 is not allowed; it must be left out without horizon.physical_time"),
        ("horizon", {"tau_f": 1.0, "N": 10, "physical_time": 1.0, "max_time_speed": math.nan},
         r"^horizon.max_time_speed must be a number, got nan$"),
        # a finite but absurd horizon overflowed h g: a plan's report gave a physical time of 300 digits
        ("horizon", {"tau_f": 1e300, "N": 10},
         r"^horizon.tau_f = 1e\+300 is not allowed; it must be at most 1e\+06 s$"),
        ("contacts", [{"point": "foot", "a_n": 1e7}], r"contacts\[0\].a_n = 10000000.0 .* in \(0, 1e\+06\]"),  # clock at 1.44x
        ("contacts", [{"point": "foot", "a_t": 1e9}], r"contacts\[0\].a_t = 1000000000.0 .* in \(0, 1e\+06\]"),  # flight sped up
        # a range error names the entry, as a type error does (with two contacts the user could not tell which)
        ("contacts", [{"point": "foot"}, {"point": "base", "mu": -1.0}], r"^contacts\[1\].mu = -1.0 is not allowed"),
        ("plan", {"target_q": [3.0, 0.4, 0.0, 0.0],
                  "holes": [{"x": 1.0, "a": 0.1, "b": 0.1}, {"x": 2.0, "a": -1.0, "b": 0.1}]},
         r"^plan.holes\[1\].a = -1.0 is not allowed"),
        ("plan", {"target_q": [3.0, 0.4, 0.0, 0.0], "joint_bounds": [{"joint": "hip", "lower": 1.0, "upper": 0.5}]},
         r"^plan.joint_bounds\[0\].lower = 1.0 is not allowed; it must be <= upper \(0.5\) of joint 'hip'$"),
    ],
)
def test_bad_values_are_named(path, value, message):
    """Unknown keys, wrong types and out-of-range values raise TaskError naming the key and the rule; infinity only
    where it means unbounded (a bound), so an infinite horizon, state or gain is named here, not a failed solve."""
    with pytest.raises(TaskError, match=message):
        parse_task(_with(path, value))


@pytest.mark.parametrize(
    "path, bad, good, message",
    [
        # a_n = 0 switches the impact field off: the frozen interval never ends (the clock stops for good)
        ("contacts", [{"point": "foot", "a_n": 0.0}], [{"point": "foot", "a_n": 1e-3}],
         r"contacts\[0\].a_n = 0.0 is not allowed; it must be in \(0, 1e\+06\]"),
        # T > tau_f needs a speed of time s > 1 somewhere, but s >= 1 and t(tau_f) = T is solvable only for T <= tau_f
        ("horizon", {"tau_f": 1.0, "N": 10, "physical_time": 1.5}, {"tau_f": 1.0, "N": 10, "physical_time": 1.0},
         r"horizon.physical_time = 1.5 is not allowed; it must be in \(0, tau_f\]"),
        # s >= 1 is every speed's lower bound: a cap below it leaves no speed of time at all
        ("horizon", {"tau_f": 1.0, "N": 10, "physical_time": 1.0, "max_time_speed": 0.99},
         {"tau_f": 1.0, "N": 10, "physical_time": 1.0, "max_time_speed": 1.0},
         r"^horizon.max_time_speed = 0.99 is not allowed; it must be >= 1"),
        # kappa = 1 repeats the first penalty n_nlp times: the homotopy never tightens the complementarity
        ("plan", {"target_q": [3.0, 0.4, 0.0, 0.0], "homotopy": {"kappa": 1.0}},
         {"target_q": [3.0, 0.4, 0.0, 0.0], "homotopy": {"kappa": 1.5}},
         r"plan.homotopy.kappa = 1.0 is not allowed; it must be > 1"),
    ],
)
def test_range_edges_are_refused_and_their_neighbours_kept(path, bad, good, message):
    """The ends of four ranges: contacts.a_n in (0, MAX], horizon.physical_time in (0, tau_f],
    horizon.max_time_speed >= 1 and plan.homotopy.kappa > 1. A value past the end (an open end itself) raises
    TaskError naming the key and its range; a value inside parses (physical_time = tau_f and max_time_speed = 1 are
    closed ends: s = 1 throughout)."""
    with pytest.raises(TaskError, match=message):
        parse_task(_with(path, bad))
    parse_task(_with(path, good))


def test_a_shipped_task_is_found_by_its_name_or_its_robots_path(tmp_path, monkeypatch):
    """From a directory without robots/ (an installed wheel's user), `point_mass_hop` and `robots/point_mass_hop.toml`
    (the docs' commands) read the shipped task (they were "task file not found"); a file of that name in the working
    directory wins, and an unknown name is still not found, the shipped tasks named (a typo was only "not found")."""
    monkeypatch.chdir(tmp_path)
    shipped = (ROBOTS / "point_mass_hop.toml").resolve()
    for name in ("point_mass_hop", "robots/point_mass_hop.toml"):
        assert Path(load_task(name).source).resolve() == shipped
    (tmp_path / "point_mass_hop.toml").write_text((ROBOTS / "point_mass.toml").read_text())
    assert Path(load_task("point_mass_hop.toml").source).resolve() == (tmp_path / "point_mass_hop.toml").resolve()
    with pytest.raises(TaskError, match="task file not found: no_such_task; the shipped tasks are biped, biped_gait1"):
        load_task("no_such_task")
    with pytest.raises(TaskError, match=r"task file not found: elsewhere/x.toml$"):  # no name looked up
        load_task("elsewhere/x.toml")


def test_a_tangential_gain_without_friction_is_refused():
    """contacts.a_t is read by contacts with friction only: given with mu = 0 it is a TaskError naming it (session 56's
    tester: a_t = 5 with mu = 0 was accepted and ignored); its default with mu = 0, and any a_t with mu > 0, parse."""
    contact = {"point": "foot", "mu": 0.0, "a_t": 5.0}
    with pytest.raises(TaskError, match=r"contacts\[0\].a_t = 5.0 is not allowed; it must be left out with mu = 0"):
        parse_task(_with("contacts", [contact]))
    parse_task(_with("contacts", [{"point": "foot", "mu": 0.0}]))
    parse_task(_with("contacts", [{**contact, "mu": 0.1}]))


def test_robot_dependent_errors():
    """Names and lengths are checked against the robot; targets must lie inside the joint bounds."""
    capler = load_robot("capler")
    with pytest.raises(UnknownNameError, match="valid contact points: foot, knee$"):  # sites: "base" is a body
        parse_task(_with("contacts", [{"point": "toe"}])).check_against(capler)
    with pytest.raises(TaskError, match="initial.q has 2 entries; the robot needs 4"):
        parse_task(_with("initial.q", [0.0, 1.0])).check_against(capler)
    outside = _with("plan", {"target_q": [3.0, 0.4, 2.0, 0.0]})
    with pytest.raises(TaskError, match=r"target_q\[2\] = 2.0 \(hip\) is outside the joint bounds .* \(the robot "
                                        r"file's limits\)"):
        parse_task(outside).check_against(capler)
    start_outside = _with("plan", {"target_q": [3.0, 0.4, 0.0, 0.0], "joint_bounds": [{"joint": "base_x", "lower": 0.2}]})
    # the task's bound, named as such (it said "the joint limits", sending the user to the robot file)
    with pytest.raises(TaskError, match=r"initial.q\[0\] = 0.0 \(base_x\) is outside the joint bounds \[0.2, inf\] m "
                                        r"\(plan.joint_bounds\[0\]\)"):
        parse_task(start_outside).check_against(capler)
    inverted = _with("plan", {"target_q": [3.0, 0.4, 0.0, 0.0], "joint_bounds": [{"joint": "hip", "lower": 1.0, "upper": 0.0}]})
    with pytest.raises(TaskError, match="lower = 1.0 .* <= upper"):
        parse_task(inverted)


def test_a_robot_dependent_error_names_the_task_file(tmp_path):
    """An error check_against finds in a task read from a file names that file first, as load_task's errors do
    ("contacts[0].point: unknown contact point" named no file); a task without a file (parse_task) names none; the
    robot file's own errors keep the robot's path."""
    path = tmp_path / "nose.toml"
    path.write_text((ROBOTS / "point_mass.toml").read_text().replace('point = "point"', 'point = "nose"'))
    with pytest.raises(UnknownNameError, match=rf"^{re.escape(str(path))}: contacts\[0\]\.point: unknown contact"):
        load_task(path).check_against(load_robot("point_mass"))
    with pytest.raises(TaskError, match=r"^initial.q has 2 entries; the robot needs 4"):
        parse_task(_with("initial.q", [0.0, 1.0])).check_against(load_robot("capler"))


def test_an_error_in_a_task_edited_in_code_says_it_is_not_the_files(tmp_path):
    """A task edited in code (dataclasses.replace keeps its file's source) is named "FILE (edited)" in a
    check_against error, not as the file: a target edited to hip = 1.5 rad was reported as capler.toml's, which holds
    hip = 0. The unedited task still names its file plainly, and so does one whose source load_task cannot read back
    (read_task's trajectory.npz); a task file of another suffix is compared as a .toml is."""
    from planner.task import EDITED, task_source

    on_file = load_task(ROBOTS / "capler.toml")
    edited = replace(on_file, plan=replace(on_file.plan, target_q=(3.0, 0.4, 1.5, 0.0)))
    with pytest.raises(TaskError, match=rf"^{re.escape(str(ROBOTS / 'capler.toml') + EDITED)}: plan\.target_q\[2\]"):
        edited.check_against(load_robot("capler"))
    assert task_source(on_file) == on_file.source
    npz = replace(edited, source=str(tmp_path / "trajectory.npz"))
    assert task_source(npz) == npz.source
    other = tmp_path / "capler.task"
    other.write_text((ROBOTS / "capler.toml").read_text())
    assert task_source(replace(edited, source=str(other))) == str(other.absolute()) + EDITED
    assert task_source(replace(on_file, source=str(other))) == str(other)  # (read and compared, not refused)


def test_the_tables_a_task_lacks_are_task_errors():
    """Task.periodic_map and Task.pd_actuators on a task without plan.periodic or simulate.pd raise TaskErrors
    saying so (an AttributeError on NoneType through the API)."""
    robot, task = load_robot("point_mass"), load_task("point_mass")
    with pytest.raises(TaskError, match="the task has no plan.periodic"):
        task.periodic_map(robot)
    with pytest.raises(TaskError, match="the task has no plan.periodic"):
        replace(task, plan=None).periodic_map(robot)
    with pytest.raises(TaskError, match="the task has no simulate.pd"):
        task.pd_actuators(robot)


def test_constant_controls_beyond_the_actuators_range_warn():
    """simulate.u and a schedule's u beyond an actuator's range warn, naming the entry, the actuator and its range:
    MuJoCo's replay clamps them (a 200 N push on a 30 N motor went 56 m and failed validation at 46 m unexplained); a
    joint PD's q_ref beyond its joint's range and a schedule entry at or after tau_f warn likewise. The checks that
    plan and validate share stay silent: those commands do not use these controls."""
    capler = load_robot("capler")
    pushed = parse_task(_with("simulate", {"u": [100.0, 0.0]}))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        pushed.check_against(capler)
    with pytest.warns(UserWarning, match=r"simulate.u\[0\] = 100 \(hip_motor\) is beyond the actuator's range "
                                         r"\[-60, 60\]"):
        pushed.warn_controls_beyond_range(capler)
    schedule = {"schedule": [{"t": 0.5, "u": [0.0, -61.0]}]}
    with pytest.warns(UserWarning, match=r"simulate.schedule\[0\].u\[1\] = -61 \(knee_motor\)"):
        parse_task(_with("simulate", schedule)).warn_controls_beyond_range(capler)
    # a PD target in degrees (a failed step 0, exit 1, unwarned); one inside the joint's range stays silent
    pd = {"joints": ["hip", "knee"], "kp": [100.0, 100.0], "kd": [2.0, 2.0]}
    with pytest.warns(UserWarning, match=r"simulate.pd.q_ref\[0\] = 45 \(hip\) is beyond the joint's range "
                                         r"\[-1.178.*, 1.178.*\] rad"):
        parse_task(_with("simulate", {"pd": {**pd, "q_ref": [45.0, -0.5]}})).warn_controls_beyond_range(capler)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        parse_task(_with("simulate", {"pd": {**pd, "q_ref": [0.5, -0.5]}})).warn_controls_beyond_range(capler)
    late = {"schedule": [{"t": 100.0, "u": [0.0, 0.0]}]}  # (never acted, unsaid: a value meant in ms?)
    with pytest.warns(UserWarning, match=r"simulate.schedule\[0\].t = 100 s is not before the horizon's end"):
        parse_task(_with("simulate", late)).warn_controls_beyond_range(capler)


def test_a_hole_wholly_below_the_ground_warns():
    """A hole whose top (z + b) is at or below ground_height warns naming it and its z's meaning: with ground_height
    0.3 and z left out (0) the hole did nothing and the plan was the hole-free one, unsaid. A hole reaching above the
    ground is silent. A plan's check (build_problem) warns; the robot check that `simulate` runs too does not (simulate
    reads no holes, and warned before its one-line error)."""
    from planner.problem import build_problem

    robot = load_robot("point_mass")
    base = {"ground_height": 0.3, "contacts": [{"point": "point", "mu": 0.5}], "initial": {"q": [0.0, 0.3]},
            "horizon": {"tau_f": 1.0, "N": 10}, "plan": {"target_q": [0.5, 0.3], "u_bound": 30.0}}
    below = parse_task({**base, "plan": {**base["plan"], "holes": [{"x": 0.25, "a": 0.1, "b": 0.1}]}})
    above = parse_task({**base, "plan": {**base["plan"], "holes": [{"x": 0.25, "z": 0.3, "a": 0.1, "b": 0.1}]}})
    said = []
    for task in (below, above):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            task.check_against(robot)
            checked = len([w for w in caught if "hole" in str(w.message)])
            build_problem(robot, task)
        said.append([str(w.message) for w in caught if "hole" in str(w.message)])
        assert checked == 0
    assert len(said[0]) == 1 and said[1] == []
    assert re.match(r"plan.holes\[0\] lies wholly below the ground \(its top z \+ b = 0.1 m, ground_height 0.3 m\).* "
                    r"0 when omitted", said[0][0])


def test_a_free_joint_is_refused_with_or_without_contacts(tmp_path):
    """A robot with a free joint (more coordinates than velocities) is refused by the task's check naming the joint and
    the planar alternative: without contacts nothing refused it and simulate crashed in CasADi (a dimension mismatch,
    a traceback, exit 1); with one, it was refused for a point moving along y."""
    path = tmp_path / "freebox.xml"
    path.write_text('<mujoco><worldbody><body name="box" pos="0 0 1"><freejoint name="root"/><geom type="box" '
                    'size="0.1 0.1 0.1" mass="1"/><site name="c" pos="0 0 -0.1"/></body></worldbody></mujoco>')
    task = parse_task({"contacts": [], "initial": {"q": [0, 0, 1, 1, 0, 0, 0]}, "horizon": {"tau_f": 0.2, "N": 10}})
    for contacts in ([], [{"point": "c"}]):
        with pytest.raises(RobotFileError, match=r"joint\(s\) root have more coordinates than velocities .* slide x, "
                                                 r"slide z and a hinge about y"):
            simulate(load_robot(path), replace(task, contacts=tuple(parse_task(
                {"contacts": contacts, "initial": {"q": [0] * 7}, "horizon": {"tau_f": 0.2, "N": 10}}).contacts)))


def test_a_ground_height_other_than_the_files_ground_plane_warns(tmp_path):
    """A task whose ground_height differs from the robot file's ground plane (geom 'ground') warns with the file's:
    the planner plans on the task's and MuJoCo's replay moved the file's plane there without a word (a plane at
    z = 0.1 m in the file, ground_height 0 in the task, passed simulate, validate and view)."""
    capler = load_robot("capler")
    assert capler.ground_z == 0.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        parse_task(MINIMAL).check_against(capler)
    with pytest.warns(UserWarning, match=r"ground plane \(geom 'ground'\) is at z = 0 m, not at the task's "
                                         r"ground_height"):
        parse_task({**MINIMAL, "ground_height": -0.1}).check_against(capler)
    # a URDF has no ground plane to compare, nor has an MJCF file without a plane
    assert load_robot("robots/capler.urdf").ground_z is None
    plank = tmp_path / "plank.xml"
    plank.write_text(PLANK)
    assert load_robot(plank).ground_z is None


def test_a_files_only_plane_is_its_ground_whatever_its_name(tmp_path):
    """A file whose one world plane is not named ground (Menagerie's and Gym's "floor") has that plane read as its
    ground, and the ground-height warning names it: a floor at z = 0.1 m under a task at ground_height 0 was passed
    without a word, the robot moving 0.1 m below the file's floor. Of several planes none named ground, none is the
    ground: each is named as scenery instead (the warning says which plane is read)."""
    floor = tmp_path / "floor.xml"
    floor.write_text((ROBOTS / "capler.xml").read_text().replace('<geom name="ground" type="plane"',
                                                                   '<geom name="floor" type="plane" pos="0 0 0.1"'))
    with pytest.warns(UserWarning, match=r"ground plane \(geom 'floor'\) is at z = 0.1 m, not at the task's"):
        parse_task(MINIMAL).check_against(load_robot(floor))
    floors = tmp_path / "floors.xml"
    floors.write_text(floor.read_text().replace("</worldbody>", '<geom name="floor2" type="plane" size="1 1 0.1" '
                                                                'contype="1" conaffinity="1"/></worldbody>'))
    robot = load_robot(floors)
    assert robot.ground_z is None and robot.scenery == ("floor", "floor2")
    with pytest.warns(UserWarning, match=r"'floor', 'floor2' can collide .*\(the plane named 'ground', else the "
                                         r"file's only plane if level\)"):
        parse_task(MINIMAL).check_against(robot)
    slope = tmp_path / "slope.xml"  # (a tilted plane read as flat ground had the validation's level plane replace it)
    slope.write_text(floor.read_text().replace('<geom name="floor" type="plane"', '<geom name="floor" type="plane" '
                                                                                  'euler="0 0.3 0"'))
    robot = load_robot(slope)
    assert (robot.ground_geom, robot.ground_z, robot.scenery) == ("", None, ("floor",))


def test_colliding_geoms_fixed_to_the_world_warn(tmp_path):
    """A world geom other than the ground that can collide (a box "step" in the path, in <worldbody> or in a body
    without joints) warns naming it: the planner and its validation (which clears its collisions) model the ground
    only, and a plan slid its foot 40 mm deep through such a step, validated. A geom with contype = conaffinity = 0
    (decoration) does not warn, nor does any shipped robot file."""
    text = (ROBOTS / "capler.xml").read_text()
    step = tmp_path / "step.xml"
    step.write_text(text.replace("</worldbody>", '<geom name="step" type="box" pos="0.5 0 0.04" size="0.03 0.3 0.04" '
                                                 'contype="1" conaffinity="1"/><body name="rock" pos="1 0 0"><geom '
                                                 'name="rock_geom" type="box" size="0.1 0.1 0.1" contype="1" '
                                                 'conaffinity="1"/></body></worldbody>'))
    assert load_robot(step).scenery == ("step", "rock_geom")
    with pytest.warns(UserWarning, match=r"step.xml: the world's geom\(s\) 'step', 'rock_geom' can collide in MuJoCo"):
        parse_task(MINIMAL).check_against(load_robot(step))
    decoration = tmp_path / "decoration.xml"
    decoration.write_text(text.replace("</worldbody>", '<geom name="step" type="box" pos="0.5 0 0.04" size="0.03 '
                                                       '0.3 0.04" contype="0" conaffinity="0"/></worldbody>'))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        parse_task(MINIMAL).check_against(load_robot(decoration))
    shipped = sorted(ROBOTS.glob("*.xml")) + sorted((ROBOTS.parent / "docs" / "examples").glob("*.xml"))
    assert shipped and {path.name: load_robot(path).scenery for path in shipped} == {p.name: () for p in shipped}
    pedestal = tmp_path / "pedestal.xml"  # (a jointless body that carries the robot is the robot's, not scenery)
    pedestal.write_text(text.replace('<body name="base" pos="0 0 0">', '<body name="pedestal"><geom name="plinth" '
                                     'type="box" size="0.1 0.1 0.01" contype="1" conaffinity="1"/><body name="base" '
                                     'pos="0 0 0">').replace("</worldbody>", "</body></worldbody>"))
    assert load_robot(pedestal).scenery == ()

def test_a_tasks_source_is_not_part_of_its_equality(tmp_path):
    """The same task read from its file by a relative and an absolute path, parsed from its data, or read back
    with another source, is equal and hashes equal (a replan from a plan of the same task walked between equal
    tasks: read_task names the plan's trajectory.npz as the source)."""
    import os

    absolute = load_task(ROBOTS / "capler.toml")
    relative = load_task(os.path.relpath(ROBOTS / "capler.toml"))
    assert absolute.source != relative.source and absolute == relative and hash(absolute) == hash(relative)
    other = replace(absolute, source=str(tmp_path / "trajectory.npz"))
    assert other == absolute and hash(other) == hash(absolute)
    assert replace(absolute, ground_height=0.01) != absolute


def test_range_messages_give_units_and_a_degree_files_own_degrees(tmp_path):
    """Joint ranges quoted in messages carry their unit, and a hinge of an MJCF file MuJoCo reads in degrees (its
    <compiler angle>, or MuJoCo's default without one) also the file's degrees: "[-1.178, 1.178] (the robot file's
    limits)" for a file written -67.5 67.5 (session 61's tester); a task's own bounds and an unlimited hinge get
    none. Robot.degrees follows the last angle, one in an included file in its place."""
    text = (ROBOTS / "capler.xml").read_text()
    degrees = tmp_path / "degrees.xml"
    degrees.write_text(text.replace('angle="radian"', 'angle="degree"').replace(
        'range="-1.1780972450961724 1.1780972450961724"', 'range="-67.5 67.5"'))
    silent = tmp_path / "silent.xml"  # no angle: MuJoCo's default, degrees
    silent.write_text(text.replace('angle="radian" ', ""))
    robot = load_robot(degrees)
    assert robot.degrees and load_robot(silent).degrees and not load_robot("capler").degrees
    hip = robot.dof_names.index("hip")
    assert robot.range_text(hip) == "[-1.178097245, 1.178097245] rad (the file's -67.5 67.5 degrees)"
    assert robot.range_text(robot.dof_names.index("base_x"), -1.0, 2.0) == "[-1, 2] m"
    # a task's bounds are radians in the task file (they were said to be "the file's 11.5 57.3 degrees"); an
    # unlimited hinge has no degrees to give
    assert robot.range_text(hip, 0.2, 1.0) == "[0.2, 1] rad"
    free = tmp_path / "free.xml"
    free.write_text(degrees.read_text().replace('range="-67.5 67.5"', ""))
    assert load_robot(free).range_text(hip) == "[-inf, inf] rad"
    # a <compiler angle> in an included file counts in its place, the last one winning (it was not read)
    (tmp_path / "deg.xml").write_text('<mujocoinclude><compiler angle="degree"/></mujocoinclude>')
    (tmp_path / "rad.xml").write_text('<mujocoinclude><compiler angle="radian"/></mujocoinclude>')
    for name, include, expected in (("inc_deg.xml", "deg.xml", True), ("inc_rad.xml", "rad.xml", False)):
        (tmp_path / name).write_text(degrees.read_text().replace('<compiler angle="degree" autolimits="true"/>',
                                                                 '<compiler angle="radian" autolimits="true"/>'
                                                                 f'<include file="{include}"/>'))
        assert load_robot(tmp_path / name).degrees is expected, name
    task = load_task(ROBOTS / "capler.toml")
    target = list(task.plan.target_q)
    target[hip] = 30.0  # meant in degrees
    with pytest.raises(TaskError, match=r"plan.target_q\[2\] = 30.0 \(hip\) is outside the joint bounds "
                                        r"\[-1.178097245, 1.178097245\] rad \(the file's -67.5 67.5 degrees\)"):
        replace(task, plan=replace(task.plan, target_q=tuple(target), joint_bounds=())).check_against(robot)


@pytest.mark.filterwarnings("ignore:.*the world's geom\\(s\\) 'geom \\d+' can collide")  # (the rock: checked below)
def test_colliding_geoms_without_a_contact_point_warn(tmp_path):
    """A robot file whose bodies' geoms collide in MuJoCo (contype/conaffinity, an explicit <pair>, a URDF
    <collision>) warns naming the bodies that carry no contact or above_ground point of the task: the plan and the
    validation (which clears their collisions) let them through the ground without a word. Scenery welded to the
    world is not named; capler.xml (contype 0) and its default task give no warning."""
    text = (ROBOTS / "capler.xml").read_text()
    colliding = tmp_path / "capler.xml"
    colliding.write_text(text.replace('<geom contype="0" conaffinity="0" rgba', '<geom rgba').replace(
        "</worldbody>", '<body name="rock" pos="1 0 0"><geom type="box" size="0.1 0.1 0.1"/></body></worldbody>'))
    robot = load_robot(colliding)
    assert robot.colliding == ("base", "thigh", "shank")
    with pytest.warns(UserWarning, match=r"the geoms of 'base', 'thigh' collide in MuJoCo, but no contact point of the "
                                         r"task is on them: the plan or simulation and its validation let them pass"):
        parse_task(MINIMAL).check_against(robot)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.warns(UserWarning, match=r"the world's geom\(s\) 'geom \d+' can collide"):  # the rock, only
            load_task(ROBOTS / "capler.toml").check_against(robot)  # above_ground = ["knee", "base"] keeps the others
        parse_task(MINIMAL).check_against(load_robot("capler"))
    paired = tmp_path / "paired.xml"  # contype 0 everywhere, one explicit pair of the thigh with the ground
    paired.write_text(text.replace("</worldbody>",
                                   '</worldbody><contact><pair geom1="thigh_geom" geom2="ground"/></contact>'))
    assert load_robot(paired).colliding == ("thigh",)
    urdf = tmp_path / "capler.urdf"
    urdf.write_text((ROBOTS / "capler.urdf").read_text().replace(
        '<visual><origin xyz="0 0 -0.1"/><geometry><cylinder radius="0.012"',
        '<collision><geometry><sphere radius="0.01"/></geometry></collision><visual><origin xyz="0 0 -0.1"/>'
        '<geometry><cylinder radius="0.012"'))
    assert load_robot(urdf).colliding == ("shank",) and load_robot("robots/capler.urdf").colliding == ()
    with pytest.warns(UserWarning, match=r"the <collision>s of 'shank' collide .* remove the <collision>s"):
        parse_task({**MINIMAL, "contacts": [{"point": "knee"}]}).check_against(load_robot(urdf))  # (knee: on the thigh)
    floor = tmp_path / "floor.xml"  # no geom named ground, the world's own colliding with nothing: the validation's
    # plane (1/1) counts (a file without a ground warned, the same with a contype-0 floor did not)
    floor.write_text(text.replace('<geom contype="0" conaffinity="0" rgba', '<geom rgba').replace(
        '<geom name="ground" type="plane" size="5 1 0.1" contype="1" conaffinity="1"',
        '<geom name="floor00" type="plane" size="5 1 0.1" contype="0" conaffinity="0"'))
    assert load_robot(floor).colliding == ("base", "thigh", "shank")
    with warnings.catch_warnings():  # the foot link is fixed on the shank: its contact point keeps the shank's
        warnings.simplefilter("error")
        parse_task(MINIMAL).check_against(load_robot(urdf))
    # (regression tester: a world link's collision, and bits that never meet the ground's, warned)
    world = tmp_path / "world.urdf"
    world.write_text((ROBOTS / "capler.urdf").read_text().replace(
        '<link name="world"/>',
        '<link name="world"><collision><geometry><box size="1 1 0.1"/></geometry></collision></link>'))
    assert load_robot(world).colliding == ()
    selfish = tmp_path / "selfish.xml"  # the robot's geoms collide with each other only (the ground is 1/1)
    selfish.write_text(text.replace('<geom contype="0" conaffinity="0" rgba', '<geom contype="2" conaffinity="2" rgba'))
    assert load_robot(selfish).colliding == ()


PLANK = """<mujoco><worldbody><body name="plank"><joint name="px" type="slide" axis="1 0 0"/>
<joint name="pz" type="slide" axis="0 0 1"/><joint name="pitch" type="hinge" axis="0 1 0"/>
<inertial pos="0 0 0" mass="3" diaginertia="0.04 0.04 0.04"/><site name="left" pos="-0.2 0 -0.02"/>
<site name="right" pos="0.2 0 -0.02"/></body></worldbody><actuator><motor name="m" joint="pz"/></actuator></mujoco>"""


@pytest.mark.parametrize("mu_right, z, fix", [(0.6, 0.02, "1 friction direction(s) are surplus: give mu = 0 to 1 "
                                                           "contact(s) with friction"),
                                               (0.0, 0.02, None), (0.6, 0.1, None)])
def test_dependent_sticking_contacts_at_the_start_warn(tmp_path, mu_right, z, fix):
    """Two sticking points of one rigid plank on the ground: 4 contact rows on 3 degrees of freedom, so their forces
    are not unique (a plan burnt 433 s at its caps, a simulation reported 1e15 N): a warning naming the contacts, the
    counts and the fix, from the check of the commands that solve (Task.warn_dependent_contacts), not from
    check_against, which validate runs too. One frictionless point (3 rows), or the plank in the air at the start,
    gives none."""
    path = tmp_path / "plank.xml"
    path.write_text(PLANK)
    task = parse_task({"contacts": [{"point": "left", "mu": 0.6}, {"point": "right", "mu": mu_right}],
                       "initial": {"q": [0.0, z, 0.0]}, "horizon": {"tau_f": 0.3, "N": 30}})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        task.check_against(load_robot(path))
        assert caught == []  # validate's check: it solves nothing ("the solver may fail" was said there too)
        task.warn_dependent_contacts(load_robot(path))
    messages = [str(w.message) for w in caught]
    assert messages == ([] if fix is None else [
        "contacts[0] (left), contacts[1] (right) on their planes at initial.q constrain 4 directions but only 3 "
        "independently, so their forces together are not unique (e.g. two sticking points of one rigid body) and the "
        f"solver may fail; {fix}"])


HAMMER = """<mujoco><worldbody><body name="arm" pos="0 0 0.5"><joint name="hinge" type="hinge" axis="0 1 0"/>
<inertial pos="0.2 0 0" mass="1" diaginertia="0.01 0.01 0.01"/><site name="head" pos="0.4 0 0"/></body></worldbody>
<actuator><motor name="m" joint="hinge"/></actuator></mujoco>"""


@pytest.mark.parametrize("mu, q, message", [
    (0.5, 0.3, r"contacts\[0\] \(head\) with friction cannot move along its plane independently of its normal at "
               r"initial.q, so its no-slip force is undefined there \(NaN in the solve\): give it mu = 0 \(no friction\), "
               "start from another pose"),
    (0.5, math.pi / 2, r"contacts\[0\] \(head\) with friction cannot move along its plane's normal at initial.q"),
    (0.0, 0.3, None),
    # frictionless too: its force divides by n^T M^-1 n, 0 there (an arm hanging straight down failed on NaN)
    (0.0, math.pi / 2, r"contacts\[0\] \(head\) cannot move along its plane's normal at initial.q, so its contact "
                       "force is undefined there"),
])
def test_a_contact_whose_force_is_undefined_at_the_start_is_refused(tmp_path, mu, q, message):
    """A one-hinge hammer's head moves along one direction only: with friction its normal and tangent rows are
    dependent (with the arm vertical, q = pi / 2, it cannot move along the ground's normal at all), so its no-slip
    force solves a singular system (NaN: a simulation ran 170794 IPOPT iterations, a plan said its start held NaN).
    Task.check_no_slip_forces, which simulate and build_problem call, raises a TaskError naming the contact and the
    fixes; a frictionless head is fine where it can move along the normal, and check_against (a replay's check) does
    not judge it."""
    path = tmp_path / "hammer.xml"
    path.write_text(HAMMER)
    robot = load_robot(path)
    task = parse_task({"contacts": [{"point": "head", "mu": mu}], "initial": {"q": [q]},
                       "horizon": {"tau_f": 0.3, "N": 30}})
    task.check_against(robot)
    if message is None:
        task.check_no_slip_forces(robot)
    else:
        with pytest.raises(TaskError, match=message):
            task.check_no_slip_forces(robot)
        with pytest.raises(TaskError, match=message):  # what `planner simulate` says, before any step
            simulate(robot, task)


def test_a_frictionless_contact_that_cannot_leave_its_plane_is_refused(tmp_path):
    """A frictionless point that cannot move along its plane's normal at initial.q (the hammer's head at the bottom of
    its arc) has a contact force that divides by n^T M^-1 n = 0: refused like the frictional ones, on the ground or
    above it (Capler's massless carriage as a contact simulated to lambda_n = inf with exit 0; an arm hanging with its
    tip 0.2 m up stopped at step 0 on IPOPT's Invalid_Number_Detected); the head off the bottom is fine."""
    path = tmp_path / "hammer.xml"
    path.write_text(HAMMER)
    robot = load_robot(path)
    for ground, q, refused in ((0.5 - 0.4, math.pi / 2, True), (0.0, math.pi / 2, True), (0.0, 0.3, False)):
        task = parse_task({"ground_height": ground, "contacts": [{"point": "head"}], "initial": {"q": [q]},
                           "horizon": {"tau_f": 0.3, "N": 30}})
        if not refused:
            task.check_no_slip_forces(robot)
            continue
        with pytest.raises(TaskError, match=r"^contacts\[0\] \(head\) cannot move along its plane's normal at "
                                            r"initial.q, so its contact force is undefined there"):
            task.check_no_slip_forces(robot)


def test_one_contact_of_dependent_rows_is_told_of_itself(tmp_path):
    """The hammer's head on the ground with friction: its own normal and tangent rows are dependent, and the warning
    speaks of that one contact (it said "remove one of them" of contacts that were one)."""
    path = tmp_path / "hammer.xml"
    path.write_text(HAMMER)
    head_z = 0.5 - 0.4 * math.sin(0.3)  # the arm turned by q about +y from its pivot at z = 0.5
    task = parse_task({"ground_height": head_z, "contacts": [{"point": "head", "mu": 0.5}], "initial": {"q": [0.3]},
                       "horizon": {"tau_f": 0.3, "N": 30}})
    with pytest.warns(UserWarning, match=r"^contacts\[0\] \(head\) on its plane at initial.q constrains 2 directions "
                                         r"but only 1 .* it cannot slide independently of its normal: give it mu = 0$"):
        task.warn_dependent_contacts(load_robot(path))


def test_a_point_in_a_corner_is_told_which_contact_to_change(tmp_path):
    """A point in a corner, a rough floor and a frictionless wall: 3 rows on 2 degrees of freedom; the warning names
    both planes' contacts by index (the same point) and asks for mu = 0 on the one with friction, not on the wall; with
    friction on both it asks for mu = 0 on both (counted)."""
    task = parse_task({"contacts": [{"point": "point", "mu": 0.5}, {"point": "point", "normal": [1.0, 0.0, 0.0]}],
                       "initial": {"q": [0.0, 0.0]}, "horizon": {"tau_f": 0.3, "N": 30}})
    with pytest.warns(UserWarning, match=r"^contacts\[0\] \(point\), contacts\[1\] \(point\) on their planes at "
                                         r"initial.q constrain 3 directions but only 2 .* give mu = 0 to 1 "
                                         r"contact\(s\) with friction$"):
        task.warn_dependent_contacts(load_robot("point_mass"))
    # both with friction: 4 rows on 2, and one mu = 0 left 3 (the warning asked for "one of them")
    rough = parse_task({"contacts": [{"point": "point", "mu": 0.5}, {"point": "point", "normal": [1.0, 0.0, 0.0],
                                                                     "mu": 0.5}],
                        "initial": {"q": [0.0, 0.0]}, "horizon": {"tau_f": 0.3, "N": 30}})
    with pytest.warns(UserWarning, match=r"constrain 4 directions but only 2 .* give mu = 0 to 2 contact\(s\) with "
                                         r"friction$"):
        rough.warn_dependent_contacts(load_robot("point_mass"))


def test_joint_bounds_beyond_the_files_range_warn():
    """plan.joint_bounds replaces the file's range, but MuJoCo's replay enforces the file's: a bound beyond it (e.g. in
    degrees: +-60 on a +-1 rad hinge, planned silently to -2.8 rad) warns naming the joint and both ranges; bounds
    inside the range, and bounds of a joint without a range (base_x), do not."""
    capler = load_robot("capler")
    wide = _with("plan", {"target_q": [3.0, 0.4, 0.0, 0.0],
                          "joint_bounds": [{"joint": "hip", "lower": -60.0, "upper": 60.0}]})
    with pytest.warns(UserWarning, match=r"joint_bounds\[0\] \(hip: \[-60, 60\]\) goes beyond the robot file's range "
                                         r"\[-1.178097245, 1.178097245\] rad"):
        parse_task(wide).check_against(capler)
    inside = _with("plan", {"target_q": [3.0, 0.4, 0.0, 0.0], "joint_bounds": [
        {"joint": "hip", "lower": -1.0, "upper": 1.0}, {"joint": "base_x", "lower": -5.0, "upper": 5.0}]})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        parse_task(inside).check_against(capler)


def test_a_u_bound_beyond_the_files_control_range_warns():
    """plan.u_bound replaces the file's control bounds, but MuJoCo's replay clamps to the file's: a bound beyond them
    (30 N on a box's +-5 N motor: a 277 s plan, then "saturation 73 %" and a failed validation; inf) warns naming the
    actuators and their range, as joint_bounds beyond the file's range does; a bound within every range does not."""
    capler = load_robot("capler")  # motors +-60 N m
    for u_bound, shown in ((90.0, "90"), (float("inf"), "inf")):
        with pytest.warns(UserWarning, match=rf"plan.u_bound = {shown} goes beyond the robot file's control range of "
                                             r"hip_motor \[-60, 60\], knee_motor \[-60, 60\], which MuJoCo's replay"):
            parse_task(_with("plan", {"target_q": [3.0, 0.4, 0.0, 0.0], "u_bound": u_bound})).check_against(capler)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for u_bound in (60.0, 10.0):
            parse_task(_with("plan", {"target_q": [3.0, 0.4, 0.0, 0.0], "u_bound": u_bound})).check_against(capler)


def test_plan_needs_actuators(tmp_path):
    """A plan of a robot without motors is refused with a clear message; the same task simulates (a simulation reads
    no [plan] table: the task was refused for having one, session 64's tester)."""
    xml = tmp_path / "passive.xml"
    xml.write_text('<mujoco><worldbody><body name="b"><joint name="z" type="slide" axis="0 0 1"/>'
                   '<inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/><site name="p"/></body></worldbody></mujoco>')
    task = parse_task({"contacts": [{"point": "p"}], "initial": {"q": [1.0]}, "horizon": {"tau_f": 1.0, "N": 5},
                       "plan": {"target_q": [1.0]}})
    with pytest.raises(TaskError, match="no actuators"):
        task.require_actuators(load_robot(xml))
    task.check_against(load_robot(xml))


def test_a_degree_of_freedom_too_light_to_resolve_is_refused(tmp_path):
    """A body whose inertia at initial.q is below model.MIN_DOF_INERTIA is refused naming its degrees of freedom (a
    1e-9 kg point mass simulated as hovering, "converged", and its validation PASSED); 1e-4 kg passes."""
    task = parse_task({"contacts": [{"point": "point"}], "initial": {"q": [0.0, 1.0]}, "horizon": {"tau_f": 1.0, "N": 5}})
    source = load_robot("point_mass").path.read_text()
    for mass, refused in (("1e-9", True), ("1e-4", False)):
        path = tmp_path / f"pm_{mass}.xml"
        path.write_text(source.replace('mass="1"', f'mass="{mass}"'))
        if refused:
            with pytest.raises(RobotFileError, match=r"lighter than 0.0001 kg \(or kg m\^2\) at initial.q: x \(1e-09\), z \(1e-09\)"):
                task.check_against(load_robot(path))
        else:
            task.check_against(load_robot(path))


BIPED_PERIODIC = {"contacts": [{"point": "foot_1", "mu": 1.0}, {"point": "foot_2", "mu": 1.0}],
                  "initial": {"q": [0.0, 0.99, 0.0, -0.1, 0.1]}, "horizon": {"tau_f": 0.6, "N": 10},
                  "plan": {"periodic": {"step": 0.25, "swap": [["hinge_1", "hinge_2"]]}}}


def _periodic(**changes):
    plan = {**BIPED_PERIODIC["plan"], "periodic": {**BIPED_PERIODIC["plan"]["periodic"]}}
    for key, value in changes.items():
        if key.startswith("periodic."):
            plan["periodic"][key.split(".", 1)[1]] = value
        else:
            plan[key] = value
    return {**BIPED_PERIODIC, "plan": plan}


def test_periodic_plan_keys():
    """plan.periodic: defaults (along x, x(0) fixed), target_q no longer required, indices from names."""
    task = parse_task(_periodic())
    per = task.plan.periodic
    assert (per.step, per.along, per.swap, per.fixed, per.v_bound) == (0.25, "x", (("hinge_1", "hinge_2"),), ("x",), None)
    assert task.plan.target_q is None
    perm, along, fixed = task.periodic_map(load_robot(ROBOTS / "biped.xml"))
    assert perm.tolist() == [0, 1, 2, 4, 3] and along == 0 and fixed.tolist() == [0]


@pytest.mark.parametrize(
    "changes, message",
    [
        ({"periodic.bogus": 1}, r"unknown key 'plan.periodic.bogus'; valid keys: step, along, swap, fixed, v_bound"),
        ({"periodic.step": "far"}, r"plan.periodic.step must be a number, got str"),
        ({"periodic.swap": [["hinge_1"]]}, r"plan.periodic.swap\[0\] = \['hinge_1'\] is not allowed; it must be two different"),
        ({"periodic.swap": [["hinge_1", "hinge_2"], ["hinge_2", "torso"]]}, r"plan.periodic.swap\[1\] .* another pair"),
        ({"periodic.swap": "hinge_1"}, r"plan.periodic.swap must be an array, got str"),
        ({"periodic.fixed": ["x", "x"]}, r"plan.periodic.fixed .* without repeated names"),
        ({"periodic.v_bound": 0.0}, r"plan.periodic.v_bound = 0.0 .* > 0"),
        ({"target_q": [0.25, 0.99, 0.0, 0.1, -0.1]}, r"plan.target_q .* omitted with plan.periodic"),
    ],
)
def test_bad_periodic_values_are_named(changes, message):
    """Each bad plan.periodic value (an unknown key, a step that is no number, a swap that is no pair of different
    names or repeats a name, a repeated fixed name, v_bound <= 0) and a target_q given with periodic is a TaskError
    whose message names the key, its value and what is allowed."""
    with pytest.raises(TaskError, match=message):
        parse_task(_periodic(**changes))


@pytest.mark.parametrize(
    "bound, message",
    [
        ({"joints": [], "lower": 0.1}, r"plan.velocity_bounds\[0\].joints = \[\] .* one or more different joint names"),
        ({"joints": ["torso", "torso"], "lower": 0.1}, r"plan.velocity_bounds\[0\].joints .* different joint names"),
        ({"joints": ["torso"], "lower": 1.0, "upper": 0.5}, r"plan.velocity_bounds\[0\].lower = 1.0 .* <= upper \(0.5\)"),
        ({"joints": ["torso"]}, r"plan.velocity_bounds\[0\].lower/upper = \[-inf, inf\] .* a finite lower or upper"),
        ({"joint": "torso", "lower": 0.1}, r"unknown key 'plan.velocity_bounds\[0\].joint'; valid keys: joints, lower, upper"),
    ],
)
def test_bad_velocity_bounds_are_named(bound, message):
    """plan.velocity_bounds entries: a non-empty set of names and a real (non-empty, not infinite) interval."""
    with pytest.raises(TaskError, match=message):
        parse_task(_periodic(velocity_bounds=[bound]))


def test_a_task_that_is_not_a_table_is_named():
    """parse_task of something other than a dict (e.g. a JSON array) is a TaskError, not Python's TypeError."""
    with pytest.raises(TaskError, match="task must be a table, got list"):
        parse_task([1, 2])


def test_infinite_bounds_mean_unbounded():
    """A bound may be written as +-inf (TOML's inf): the task keeps it, as the unbounded default would be."""
    task = parse_task(_periodic(velocity_bounds=[{"joints": ["torso"], "lower": 0.1, "upper": math.inf}], u_bound=math.inf))
    assert task.plan.velocity_bounds[0].upper == math.inf and task.plan.u_bound == math.inf


def test_velocity_bounds_as_rows():
    """Each bound is one row of A (0/1 on the named joints' velocity indices) with its lower and upper
    bound; an unknown joint names the task key that gave it (it said only "unknown joint 'knee'") and lists the
    robot's joints, as an unknown joint of plan.joint_bounds and an unknown point of plan.above_ground do."""
    robot = load_robot(ROBOTS / "biped.xml")
    task = parse_task(_periodic(velocity_bounds=[{"joints": ["torso", "hinge_1"], "lower": 0.3},
                                                 {"joints": ["x"], "lower": -1.0, "upper": 2.0}]))
    A, lower, upper = task.velocity_rows(robot)
    assert A.tolist() == [[0, 0, 1, 1, 0], [1, 0, 0, 0, 0]]
    assert lower.tolist() == [0.3, -1.0] and upper.tolist() == [float("inf"), 2.0]
    with pytest.raises(UnknownNameError, match=r"^plan.velocity_bounds\[0\].joints: unknown joint 'knee'; "
                                               r"valid joints: x, z, torso, hinge_1, hinge_2"):
        parse_task(_periodic(velocity_bounds=[{"joints": ["knee"], "lower": 0.0}])).check_against(robot)
    with pytest.raises(UnknownNameError, match=r"^plan.joint_bounds\[0\].joint: unknown joint 'knee'"):
        parse_task(_periodic(joint_bounds=[{"joint": "knee", "lower": 0.0, "upper": 1.0}])).check_against(robot)
    with pytest.raises(UnknownNameError, match=r"^plan.above_ground\[0\]: unknown point 'knee'; valid points: foot_1"):
        parse_task(_periodic(above_ground=["knee"])).check_against(robot)


def test_plan_without_target_or_periodic():
    """A plan with neither plan.target_q nor plan.periodic is a TaskError naming the missing target_q and saying it
    is required unless plan.periodic is given."""
    with pytest.raises(TaskError, match=r"missing key 'plan.target_q' \(required unless plan.periodic"):
        parse_task({**BIPED_PERIODIC, "plan": {"rho_f": 1.0}})


def test_periodic_robot_dependent_errors():
    """Unknown coordinate names list the valid ones (an 'x' of along's or fixed's default said to be the default's);
    initial.q (the guess of q(0)) must lie in the bounds."""
    robot = load_robot(ROBOTS / "biped.xml")
    with pytest.raises(UnknownNameError, match="hinge_3"):
        parse_task(_periodic(**{"periodic.swap": [["hinge_1", "hinge_3"]]})).check_against(robot)
    with pytest.raises(UnknownNameError, match=r"^plan.periodic.along: unknown joint 'y'"):
        parse_task(_periodic(**{"periodic.along": "y"})).check_against(robot)
    # a robot whose forward base joint is not x: the 'x' is the default's, not the file's (it read as the user's)
    capler_periodic = {"contacts": [{"point": "foot", "mu": 0.8}], "initial": {"q": [0.0, 0.4, 0.0, 0.0]},
                       "horizon": {"tau_f": 1.0, "N": 10}, "plan": {"periodic": {"step": 0.3}}}
    with pytest.raises(UnknownNameError, match=r"^plan.periodic.along \(by default 'x', the forward base joint: name "
                                               r"yours in along and fixed\): unknown joint 'x'"):
        parse_task(capler_periodic).check_against(load_robot("capler"))
    capler_periodic["plan"]["periodic"]["along"] = "base_x"
    with pytest.raises(UnknownNameError, match=r"^plan.periodic.fixed \(by default 'x'"):
        parse_task(capler_periodic).check_against(load_robot("capler"))
    bounds = [{"joint": "torso", "lower": 0.1, "upper": 0.2}]
    with pytest.raises(TaskError, match=r"initial.q\[2\] = 0.0 \(torso\) is outside the joint bounds"):
        parse_task(_periodic(joint_bounds=bounds)).check_against(robot)


def test_tasks_between_moves_every_number_and_nothing_else():
    """tasks_between(a, b, s): each float of the task (a target coordinate, a hole's x, a contact's mu, the
    horizon's tau_f) is a + s (b - a), s = 0 and 1 give a's and b's numbers exactly, and the source is b's; what is not
    a Task is refused. Tasks
    that differ in an integer (N), a name, the number of holes or between an infinite and a finite bound have no
    tasks between them (None), and tasks_apart names the first such key by its path; equal infinite bounds stay."""
    a = load_task(ROBOTS / "capler.toml")
    plan = a.plan
    b = replace(a, source="moved.toml", horizon=replace(a.horizon, tau_f=3.0),
                contacts=(replace(a.contacts[0], mu=0.4),),
                plan=replace(plan, target_q=(3.1,) + plan.target_q[1:], holes=(replace(plan.holes[0], x=0.7),) + plan.holes[1:]))
    mid = tasks_between(a, b, 0.25)
    assert mid.plan.target_q == (3.025,) + plan.target_q[1:]
    assert (mid.plan.holes[0].x, mid.horizon.tau_f, mid.contacts[0].mu) == pytest.approx((0.55, 2.625, 0.7), abs=ROUNDING)
    assert mid.plan.holes[1:] == plan.holes[1:] and mid.initial == a.initial and mid.horizon.N == a.horizon.N
    assert mid.source == "moved.toml"
    assert tasks_between(a, b, 0.0) == replace(a, source="moved.toml") and tasks_between(a, b, 1.0) == b
    for apart, key in ((replace(b, horizon=replace(b.horizon, N=50)), "horizon.N"),
                       (replace(b, contacts=(replace(b.contacts[0], point="knee"),)), "contacts[0].point"),
                       (replace(b, plan=replace(b.plan, holes=b.plan.holes[:2])), "plan.holes")):
        assert tasks_between(a, apart, 0.5) is None and tasks_apart(a, apart) == key  # (the replan's note names it)
    assert tasks_apart(a, b) is None
    bounded = load_task(ROBOTS / "biped.toml")  # plan.velocity_bounds: lower 0.3, upper inf
    assert bounded.plan.velocity_bounds[0].upper == math.inf
    assert tasks_between(bounded, bounded, 0.5) == bounded
    finite = replace(bounded.plan.velocity_bounds[0], upper=5.0)
    assert tasks_between(bounded, replace(bounded, plan=replace(bounded.plan, velocity_bounds=(finite,))), 0.5) is None
    for s in (5.0, -0.1, math.nan, "0.5"):  # 5 extrapolated; nan was reported as a task value
        with pytest.raises(TaskError, match=r"tasks_between's s = .* a number in \[0, 1\]"):
            tasks_between(a, b, s)
    with pytest.raises(InputError, match="tasks_between's start must be a Task, got str 'a'"):
        tasks_between("a", "a", 0.5)  # returned 'a'
    # an omitted target_v is zeros (docs/tasks.md): a start without it and a task with 0.2 m/s had no tasks between
    assert a.plan.target_v is None
    moving = replace(a, plan=replace(a.plan, target_v=(0.2, 0.0, 0.0, 0.0)))
    assert tasks_between(a, moving, 0.5).plan.target_v == pytest.approx((0.1, 0.0, 0.0, 0.0), abs=ROUNDING)
    assert tasks_between(a, moving, 1.0) == moving and tasks_between(moving, a, 1.0) == a


@pytest.mark.parametrize("toml", sorted(ROBOTS.glob("*.toml")), ids=lambda p: p.stem)
def test_task_to_json_reads_back_equal(toml):
    """task_to_json's text (what a plan keeps beside it for a replan's walk) parses back to the same task: every
    default task, with their infinite bounds and optional tables."""
    task = load_task(toml)
    assert parse_task(json.loads(task_to_json(task)), source=task.source) == task


@pytest.mark.parametrize("build, message", [
    (lambda: Contact(point="foot", mu="0.8"), r"contacts.mu = '0.8' .* a finite number"),
    (lambda: Contact(point="foot", touches="no"), r"contacts.touches = 'no' .* true or false"),
    (lambda: Horizon(tau_f=1.5, N=15.5), r"horizon.N = 15.5 .* an integer"),
    (lambda: Horizon(tau_f=math.inf, N=10), r"horizon.tau_f = inf .* a finite number"),
    (lambda: Initial(q=(math.nan, 1.0)), r"initial.q = \(nan, 1.0\) .* each is a finite number"),
    (lambda: Ellipse(x=math.nan, a=0.25, b=0.1), r"plan.holes.x = nan"),
    (lambda: Homotopy(n_nlp=2.5), r"plan.homotopy.n_nlp = 2.5"),
    (lambda: GaitPronto(feedback_r=(1.0, math.nan)), r"gait.pronto.feedback_r = \(1.0, nan\)"),  # min() skipped a later nan
    # nested tables of the wrong kind: AttributeErrors in build_problem or solve, or silently accepted
    (lambda: Plan(target_q=(0.0, 0.0), homotopy={"rho0": 1.0}), r"plan.homotopy = .* must be a Homotopy"),
    (lambda: Plan(target_q=(0.0, 0.0), holes=Ellipse(x=0.5, a=0.25, b=0.1)), r"plan.holes = .* a tuple of Ellipse"),
    (lambda: Plan(target_q=(0.0, 0.0), joint_bounds=("x",)), r"plan.joint_bounds = \('x',\) .* a tuple of JointBound"),
    (lambda: Plan(target_q=(0.0, 0.0), periodic="x"), r"plan.periodic = 'x' .* a Periodic"),
    (lambda: Periodic(step=0.1, swap=("xz",)), r"plan.periodic.swap = \('xz',\) .* a list of lists of names"),  # read as (x, z)
    (lambda: Task(contacts=Contact(point="p"), initial=Initial(q=(0.0,)), horizon=Horizon(tau_f=1.0, N=3)),
     r"contacts = Contact\(.* a tuple of Contact"),
    (lambda: Task(contacts=(Contact(point="p"),), initial=Initial(q=(0.0,)), horizon=Horizon(tau_f=1.0, N=3), simulate=None),
     r"simulate = None .* a Simulate"),
])
def test_dataclasses_built_in_code_follow_the_readers_rules(build, message):
    """A task dataclass built in Python is checked as the TOML reader checks its key: types, nan anywhere in a
    tuple, infinity outside bounds, and a nested table that is not its dataclass are TaskErrors naming the key, not a
    TypeError, an AttributeError or a failed solve later."""
    with pytest.raises(TaskError, match=message):
        build()


ULP_TOL = 2.3e-16  # two units in the last place of 0.707: a division's rounding, not a normalization error


def test_periodic_swap_pairs_built_in_code_are_tuples():
    """Periodic.swap given as lists of lists is stored as the reader stores it (tuples of tuples): equal to the read
    task and hashable, as a frozen dataclass should be (the inner lists made hash() raise)."""
    built = Periodic(step=0.1, swap=[["hinge_1", "hinge_2"]])
    assert built.swap == (("hinge_1", "hinge_2"),) and hash(built) == hash(Periodic(step=0.1, swap=(("hinge_1", "hinge_2"),)))


def test_contact_normals_are_unit_and_read_back_equal():
    """A normal is normalized without overflow or underflow of its squares (1e200 and 1e-200 give the same unit
    vector as (1, 0, 1)), an int given for a float is stored as a float, and a task with a tilted normal reads back
    from its JSON equal to itself."""
    unit = Contact(point="foot", normal=(1.0, 0.0, 1.0)).normal
    assert unit == pytest.approx((math.sqrt(0.5), 0.0, math.sqrt(0.5)), abs=ULP_TOL)
    for scale in (1e200, 1e-200):
        assert Contact(point="foot", normal=(scale, 0.0, scale)).normal == pytest.approx(unit, abs=ULP_TOL)
    assert Contact(point="foot", normal=(0.3, 0, 1)) == Contact(point="foot", normal=(0.3, 0.0, 1.0))
    task = load_task(ROBOTS / "point_mass.toml")
    tilted = replace(task, contacts=(replace(task.contacts[0], normal=(0.3, 0.0, 1.0)),))
    assert parse_task(json.loads(task_to_json(tilted)), source=tilted.source) == tilted


def test_a_task_file_that_is_not_utf8_is_named(tmp_path):
    """TOML is UTF-8: a binary task file is a TaskError naming the file, not a UnicodeDecodeError."""
    path = tmp_path / "binary.toml"
    path.write_bytes(b"\xff\xfe[horizon]\n")
    with pytest.raises(TaskError, match=r"binary.toml: not valid TOML"):
        load_task(path)


def test_a_task_file_larger_than_any_task_is_refused_before_it_is_parsed(tmp_path):
    """A task file of more than MAX_TASK_FILE_BYTES is a TaskError naming its size, before TOML reads it (a 200 MB
    array was parsed for minutes into 1.9 GB); a shipped task with a long comment below the limit still loads."""
    from planner.task import MAX_TASK_FILE_BYTES

    text = (ROBOTS / "capler.toml").read_text()
    path = tmp_path / "big.toml"
    path.write_text(text + "#" + "x" * MAX_TASK_FILE_BYTES + "\n")
    with pytest.raises(TaskError, match=rf"big.toml is \d+ bytes, more than the {MAX_TASK_FILE_BYTES} a task file"):
        load_task(path)
    path.write_text(text + "#" + "x" * (MAX_TASK_FILE_BYTES - len(text.encode()) - 2) + "\n")
    assert load_task(path).plan == load_task(ROBOTS / "capler.toml").plan


def test_a_task_path_that_is_no_regular_file_is_said_so():
    """A task path that exists but is no regular file (/dev/null) is said to be one, not "not found"."""
    with pytest.raises(TaskError, match=r"task file /dev/null is not a regular file"):
        load_task("/dev/null")


def test_an_integer_too_long_to_read_is_named_without_pythons_advice(tmp_path):
    """An integer of more than 4300 digits (Python's limit on reading one) is a TaskError naming the file and the
    limit, without Python's advice to call sys.set_int_max_str_digits (no option of a task file)."""
    path = tmp_path / "long.toml"
    path.write_text("N = 1" + "0" * 5000 + "\n")
    with pytest.raises(TaskError, match=r"long.toml: Exceeds the limit \(4300 digits\).*; no task value needs") as err:
        load_task(path)
    assert "set_int_max_str_digits" not in str(err.value)


HUGE_INT = 10**400  # beyond a double's 1.8e308: converting it to a float raises OverflowError
BIG_INT = 2**40  # beyond a C int's 2**31 - 1, what IPOPT, CasADi and NumPy's indexing read an int as


def test_numbers_beyond_a_double_or_a_c_int_are_task_errors(tmp_path, capsys):
    """A float key given an integer beyond a double (contacts.mu = 10**400: the reader's nan check raised
    OverflowError: `planner simulate` printed its traceback, exit 1) and an int key beyond a C int (gait.steps =
    2**40, accepted) are TaskErrors naming the key, from a dict and from a TOML file alike; `planner simulate` on
    such a file is a user error: exit 2, one line."""
    from planner.cli import main

    with pytest.raises(TaskError, match=r"^contacts\[0\]\.mu must be a finite number"):
        parse_task(_with("contacts", [{"point": "foot", "mu": HUGE_INT}]))
    gait = (ROBOTS / "biped_gait1.toml").read_text()
    assert gait.count("\nsteps = 10 ") == 1
    many_steps = tmp_path / "steps.toml"
    many_steps.write_text(gait.replace("\nsteps = 10 ", f"\nsteps = {BIG_INT} "))
    with pytest.raises(TaskError, match=r"gait\.steps .*2147483647"):
        load_task(many_steps)
    drop = (ROBOTS / "point_mass.toml").read_text()
    assert drop.count("\nmu = 0.0\n") == 1
    huge_mu = tmp_path / "mu.toml"
    huge_mu.write_text(drop.replace("\nmu = 0.0\n", f"\nmu = {HUGE_INT}\n"))
    assert main(["simulate", "point_mass", "--task", str(huge_mu), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert "contacts[0].mu must be a finite number" in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "out").exists()


def test_a_normal_whose_length_overflows_is_refused():
    """A normal whose length is beyond a double (1.7e308, 0, 1.7e308: math.hypot is inf) is a TaskError naming
    contacts.normal: each component divided by inf made the normal (0, 0, 0), a plane without a direction, accepted.
    A normal of large but finite length (1e200) still normalizes to the unit vector."""
    with pytest.raises(TaskError, match=r"^contacts\.normal = .* of finite length"):
        Contact(point="foot", normal=(1.7e308, 0.0, 1.7e308))
    assert Contact(point="foot", normal=(1e200, 0.0, 1e200)).normal == pytest.approx(
        (math.sqrt(0.5), 0.0, math.sqrt(0.5)), abs=ULP_TOL)


def test_an_unknown_contact_point_lists_the_sites_only():
    """An unknown contact point lists the robot's sites as the valid names, those MuJoCo's validation can put a
    contact on: the point mass's "point", not its body "mass", which the message offered and check_against then
    refused as a body; that refusal names the entry, as the unknown name's does."""
    robot = load_robot("point_mass")
    with pytest.raises(UnknownNameError, match=r"unknown contact point 'toe'; valid contact points: point$"):
        parse_task({"contacts": [{"point": "toe"}], "initial": {"q": [0.0, 1.0]},
                    "horizon": {"tau_f": 1.0, "N": 5}}).check_against(robot)
    with pytest.raises(TaskError, match=r"^contacts\[0\].point: contact point 'mass' is an MJCF body, not a site"):
        parse_task({"contacts": [{"point": "mass"}], "initial": {"q": [0.0, 1.0]},
                    "horizon": {"tau_f": 1.0, "N": 5}}).check_against(robot)


def test_a_task_built_from_numpy_values_equals_the_one_from_plain_values():
    """parse_task takes what a notebook holds: a 1-D np.array or a Python tuple for an array, np.int64 for an integer
    (refused before as "initial.q must be an array, got ndarray" and "horizon.N must be an integer, got int64"); the
    task equals the one read from lists and ints. A 2-D array where numbers go is still refused."""
    import numpy as np

    plain = {"contacts": [{"point": "point"}], "initial": {"q": [0.0, 1.0]}, "horizon": {"tau_f": 0.2, "N": 10}}
    numpy = {"contacts": ({"point": "point"},), "initial": {"q": np.array([0.0, 1.0])},
             "horizon": {"tau_f": np.float64(0.2), "N": np.int64(10)}}
    assert parse_task(numpy) == parse_task(plain)
    assert type(parse_task(numpy).horizon.N) is int
    with pytest.raises(TaskError, match=r"initial.q\[0\] must be a number"):
        parse_task({**plain, "initial": {"q": np.zeros((1, 2))}})


def test_touches_is_the_same_on_every_plane_of_a_corner():
    """A point listed with two normals (a corner) takes one `touches` for both: false on one plane only dropped the
    contact machinery of the point, so of its other plane too, silently (a biped's foot_1 on the ground and a wall
    planned as if foot_1 never landed). False on every entry stays allowed."""
    base = {"initial": {"q": [0.0, 0.0]}, "horizon": {"tau_f": 1.0, "N": 4}}
    wall = {"point": "point", "normal": [1.0, 0.0, 0.0]}
    with pytest.raises(TaskError, match=r"contacts = \['point touches = true', 'point touches = false'\] is not "
                                        "allowed; it must be the same touches on every entry of a point"):
        parse_task({**base, "contacts": [{"point": "point"}, {**wall, "touches": False}]})
    both = parse_task({**base, "contacts": [{"point": "point", "touches": False}, {**wall, "touches": False}]})
    assert [c.touches for c in both.contacts] == [False, False]


def test_tasks_between_takes_an_omitted_initial_v_as_zeros_and_ignores_the_simulate_table():
    """A task whose initial.v is written as zeros or whose [simulate] table differs (written out at its defaults,
    or edited) walks from a start that omits them as from its own: tasks_apart found them apart (a replan then had no
    walk), though the plan reads zeros for the omitted v and no [simulate] at all; the tasks between take the end's
    [simulate]."""
    a = load_task(ROBOTS / "capler.toml")
    a = replace(a, initial=replace(a.initial, v=None))  # (the file writes its zeros)
    still = replace(a, initial=replace(a.initial, v=(0.0,) * 4), simulate=replace(a.simulate, u=(1.0, 2.0)))
    assert tasks_apart(a, still) is None and tasks_apart(still, a) is None
    moving = replace(still, initial=replace(still.initial, v=(0.2, 0.0, 0.0, 0.0)))
    mid = tasks_between(a, moving, 0.5)
    assert mid.initial.v == pytest.approx((0.1, 0.0, 0.0, 0.0), abs=ROUNDING) and mid.simulate == moving.simulate


@pytest.mark.parametrize("normal", [(0.0, 1.0, 0.0), (0.6, 0.1, 0.8)])
def test_a_contact_normal_out_of_the_x_z_plane_is_refused(normal):
    """A contact plane's normal must lie in the x-z plane, where the planner's robots move: its y part would be dropped
    by the contact model (0.6 0.1 0.8 a plane tilted otherwise than the user wrote; 0 1 0 a wall of Delassus 0), so it
    is refused naming the plane (no test gave a normal with y != 0: session 65's mutation testing dropped the check
    and every test stayed green)."""
    with pytest.raises(TaskError, match=r"contacts\.normal = .*x-z plane"):
        Contact("foot", normal=normal)


HOP_TASK = {"contacts": [{"point": "point"}], "initial": {"q": [0.0, 0.0]}, "horizon": {"tau_f": 1.0, "N": 10},
            "plan": {"target_q": [1.0, 0.0], "u_bound": 30.0}}


@pytest.mark.parametrize("b", [0.0, -0.1, 1e-300])
def test_a_holes_vertical_half_axis_is_held_to_the_same_range_as_its_horizontal_one(b):
    """plan.holes' b is a half-axis as a is, so both must be >= MIN_HOLE_AXIS_M: b = 0 divides the hole's metric by
    zero (the NLP was built with an infinite row), and b = -0.1 read as a hole whose top z + b lies below the ground,
    dropped by the scene analysis with a warning, not the 0.1 m hole the user meant. Each is a TaskError naming b."""
    data = {**HOP_TASK, "plan": {**HOP_TASK["plan"], "holes": [{"x": 0.5, "a": 0.1, "b": b}]}}
    with pytest.raises(TaskError, match=r"^plan.holes\[0\].b = .* is not allowed; it must be >= 1e-06"):
        parse_task(data)


def test_a_homotopy_whose_last_penalty_is_1e300_is_kept():
    """The schedule's last penalty is rho0 kappa^(n_nlp - 1) (rho_k for k = 0 .. n_nlp - 1, Homotopy's docstring), and
    up to 1e300 is allowed: rho0 = 1, kappa = 1e30, n_nlp = 11 ends at log10 exactly 300 (kept); n_nlp = 12 at 1e330
    (refused)."""
    from planner.task import Homotopy

    assert Homotopy(rho0=1.0, kappa=1e30, n_nlp=11).n_nlp == 11
    with pytest.raises(TaskError, match=r"plan.homotopy = .* at most 1e300"):
        Homotopy(rho0=1.0, kappa=1e30, n_nlp=12)


def test_the_task_all_the_way_between_two_tasks_is_the_end_task_exactly():
    """tasks_between(start, end, 1) is end with its own numbers, bit for bit (its docstring: "s = 1: end's numbers
    exactly"): a + 1 * (b - a) rounds off b for a = 0.1, b = 0.001 (0.0010000000000000009), and a walk's last task
    then differed from the task it was walking to."""
    from planner.task import tasks_between

    assert 0.1 + 1.0 * (0.001 - 0.1) != 0.001  # (the rounding this checks against)
    start = parse_task({**HOP_TASK, "plan": {**HOP_TASK["plan"], "target_q": [0.1, 0.0]}})
    end = parse_task({**HOP_TASK, "plan": {**HOP_TASK["plan"], "target_q": [0.001, 0.0]}})
    assert tasks_between(start, end, 1.0) == end and tasks_between(start, end, 1.0).plan.target_q[0] == 0.001


def test_two_control_changes_at_one_time_are_refused():
    """simulate.schedule must be sorted by strictly increasing t (Simulate's rule: two entries at one time leave open
    which acts); equal times are a TaskError naming simulate.schedule, increasing ones parse."""
    base = {"contacts": [{"point": "point"}], "initial": {"q": [0.0, 0.2]}, "horizon": {"tau_f": 0.1, "N": 5}}
    parse_task({**base, "simulate": {"schedule": [{"t": 0.1, "u": [1.0]}, {"t": 0.2, "u": [2.0]}]}})
    with pytest.raises(TaskError, match=r"simulate.schedule .* strictly increasing t"):
        parse_task({**base, "simulate": {"schedule": [{"t": 0.1, "u": [1.0]}, {"t": 0.1, "u": [2.0]}]}})


def test_a_negative_pd_damping_is_refused():
    """simulate.pd.kd >= 0 (JointPD's rule), as kp >= 0: a negative damping gain pumps energy into the joint. kd = -1
    is a TaskError naming simulate.pd.kd; kd = 0 parses."""
    base = {"contacts": [{"point": "point"}], "initial": {"q": [0.0, 0.2]}, "horizon": {"tau_f": 0.1, "N": 5}}
    parse_task({**base, "simulate": {"pd": {"joints": ["x"], "kp": [1.0], "kd": [0.0]}}})
    with pytest.raises(TaskError, match=r"simulate.pd.kd = \[-1.0\] is not allowed; it must be >= 0"):
        parse_task({**base, "simulate": {"pd": {"joints": ["x"], "kp": [1.0], "kd": [-1.0]}}})


def test_two_planes_whose_normals_share_their_x_are_two_planes():
    """A point may touch several planes (a corner); only the same plane twice (normals equal in every component, to
    SAME_NORMAL_TOL) is refused. Normals (0.6, 0, 0.8) and (0.6, 0, -0.8) share their x but are two planes through the
    same line, a wedge: the task parses with both."""
    task = parse_task({"contacts": [{"point": "point", "normal": [0.6, 0.0, 0.8]},
                                    {"point": "point", "normal": [0.6, 0.0, -0.8]}],
                       "initial": {"q": [0.0, 0.0]}, "horizon": {"tau_f": 0.1, "N": 5}})
    assert [c.normal for c in task.contacts] == [(0.6, 0.0, 0.8), (0.6, 0.0, -0.8)]


def test_a_rounded_joint_axis_is_named_in_the_out_of_plane_refusal(tmp_path):
    """A URDF whose hip axis is turned onto y by a CAD-rounded rpy (1.5708 for pi/2: the axis 4e-6 rad off y) moves the
    foot along y by ~1e-6 m per rad: the refusal names the joints with their dy/dq and says to write the rotation to
    full precision. It named the task's contact point only, so the user looked for the cause in the task file."""
    text = (ROBOTS / "capler.urdf").read_text()
    hip, knee = '<child link="thigh"/>\n    <axis xyz="0 1 0"/>', '<child link="shank"/>\n    <origin xyz="0 0 -0.2"/>'
    assert text.count(hip) == text.count(knee) == 1
    rounded = tmp_path / "rounded.urdf"  # (the knee turned back, so only the hip's axis is off y)
    rounded.write_text(text.replace(hip, '<child link="thigh"/><origin rpy="1.5708 0 0"/><axis xyz="0 0 -1"/>').replace(
        knee, '<child link="shank"/><origin xyz="0 -0.2 0" rpy="-1.5708 0 0"/>'))
    with pytest.raises(TaskError, match=r"contact point 'foot' can move along y: .*; dy/dq up to (.*, )?hip "
                                        r"\d\.\d+e-0[5-7].* \(so small a rate is a joint axis a little off y in the "
                                        r"robot file, e\.g\. a rounded rpy or axis: write it to full precision\)"):
        parse_task(MINIMAL).check_against(load_robot(rounded))
