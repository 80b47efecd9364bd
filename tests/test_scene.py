"""The scene analysis (planner.scene): each skip removes what it says and keeps the solution."""
from __future__ import annotations

import dataclasses

import casadi as ca
import numpy as np
import pytest

from planner.errors import InputError, TaskError
from planner.homotopy import solve
from planner.model import load_robot
from planner.problem import ProblemOptions, build_problem
from planner.scene import analyze_scene, reach_box
from planner.task import Horizon, load_task, parse_task

# The two variants of the frictionless drop reach the same complementarity-exact plan; IPOPT's tol
# 1e-8 and interior-point selectors ~1e-6 off their bounds leave differences of ~1e-5 (measured 1.2e-5)
SAME_SOLUTION_TOL = 1e-4  # [m, m/s, s] on the node states
SAMPLES = 2000  # random configurations for the reach-box checks


def slide_task(N: int):
    """Frictionless point mass dropped from 0.2 m and pushed to x = 0.5 m (one impact, then sliding)."""
    return parse_task({"contacts": [{"point": "point", "mu": 0.0}], "initial": {"q": [0.0, 0.2]},
                       "horizon": {"tau_f": 1.0, "N": N}, "plan": {"target_q": [0.5, 0.0], "u_bound": 30.0}})


def holes_task(N: int):
    """Point-mass hop with x in [-0.1, 0.6] m: hole 0 in reach, holes 1 and 2 far beyond it."""
    holes = [{"x": 0.25, "a": 0.05, "b": 0.05}, {"x": 1.5, "a": 0.25, "b": 0.1}, {"x": 2.5, "a": 0.25, "b": 0.1}]
    return parse_task({"contacts": [{"point": "point", "mu": 0.5}], "initial": {"q": [0.0, 0.0]}, "horizon": {"tau_f": 1.0, "N": N},
                       "plan": {"target_q": [0.5, 0.0], "u_bound": 30.0, "holes": holes,
                                "joint_bounds": [{"joint": "x", "lower": -0.1, "upper": 0.6}]}})


def knee_task(N: int, touches: bool = False):
    """Capler with contacts foot and knee (the knee marked touches = false unless `touches`)."""
    return parse_task({"contacts": [{"point": "foot", "mu": 0.8}, {"point": "knee", "mu": 0.8, "touches": touches}],
                       "initial": {"q": [0.0, 0.4 * np.cos(0.3), 0.3, -0.6]}, "horizon": {"tau_f": 0.3, "N": N},
                       "plan": {"target_q": [0.1, 0.4 * np.cos(0.3), 0.3, -0.6], "above_ground": ["base"]}})


@pytest.fixture(scope="module")
def point_mass():
    return load_robot("robots/point_mass.xml")


@pytest.fixture(scope="module")
def capler():
    return load_robot("robots/capler.xml")


def test_frictionless_skip_drops_the_tangential_machinery(point_mass):
    """mu = 0: per step one selector (zeta), its two multipliers, one lifted product (beta zeta), their
    stationarity, lifting and two penalty rows, and two pairs fewer; everything named zeta is gone."""
    N = 4
    on = build_problem(point_mass, slide_task(N))
    off = build_problem(point_mass, slide_task(N), ProblemOptions(scene_analysis=False))
    assert on.skips.frictionless == ("point",) and off.skips.frictionless == () and not off.skips.enabled
    assert (on.system.n_sigma, off.system.n_sigma) == (3, 4)
    assert off.nx - on.nx == 4 * N and off.ng - on.ng == 4 * N and len(off.pairs) - len(on.pairs) == 2 * N
    extra = set(off.var_names) - set(on.var_names)
    assert extra and all("zeta" in name for name in extra) and set(on.var_names) <= set(off.var_names)


def test_frictionless_reference_has_the_same_vector_field(point_mass):
    """Without the skip, F is the same for every selector value: the tangential jump field has gain 0
    and with alpha* = 1/2 the Sec. 6 polynomials equal the frictionless ones (zeta is free)."""
    on = build_problem(point_mass, slide_task(2)).system
    off = build_problem(point_mass, slide_task(2), ProblemOptions(scene_analysis=False)).system
    rng = np.random.default_rng(0)
    for _ in range(20):
        y, u, sigma = rng.normal(size=on.ny), rng.normal(size=on.nu), rng.uniform(size=on.n_sigma)
        zeta = rng.uniform()
        f_on = np.asarray(ca.evalf(on.vector_field(sigma, ca.DM(y), ca.DM(u))), float)
        f_off = np.asarray(ca.evalf(off.vector_field(np.append(sigma, zeta), ca.DM(y), ca.DM(u))), float)
        np.testing.assert_allclose(f_off, f_on, rtol=0, atol=1e-12)
    assert not off.regularized[-1] and off.regularized[:-1].all()  # zeta has no sigma* to be pulled to


def test_frictionless_skip_gives_the_same_solution(point_mass):
    """Solved with and without the skip (N = 6): the same plan, node by node."""
    a = solve(build_problem(point_mass, slide_task(6)))
    b = solve(build_problem(point_mass, slide_task(6), ProblemOptions(scene_analysis=False)))
    assert a.stats.converged and b.stats.converged
    assert np.max(np.abs(a.trajectory.y - b.trajectory.y)) <= SAME_SOLUTION_TOL


def test_never_touching_point_gets_only_a_gap_constraint(capler):
    """touches = false: one contact (foot) instead of two, no selectors or forces for the knee, and the
    row gap >= 0 of the knee at every node; without the analysis the knee is a full contact."""
    N = 3
    on = build_problem(capler, knee_task(N))
    off = build_problem(capler, knee_task(N), ProblemOptions(scene_analysis=False))
    assert [c.point for c in on.system.contacts] == ["foot"] and on.skips.never_touching == ("knee",)
    assert [c.point for c in off.system.contacts] == ["foot", "knee"]
    assert on.g_blocks["never_touching"].shape == (N, 1) and "never_touching" not in off.g_blocks
    assert not any("[knee]" in name and not name.startswith(("q[", "v[")) for name in on.var_names)  # knee is also a joint
    assert on.nx < off.nx and on.ng < off.ng and len(on.pairs) < len(off.pairs)
    g = np.asarray(ca.Function("g", [on.x, on.p], [on.g])(on.x0, on.params(1.0)), float).ravel()
    knee_z = float(np.asarray(on.system.dyn.point_position("knee")(on.y0[:4]), float).ravel()[2])
    np.testing.assert_allclose(g[on.g_blocks["never_touching"].ravel()], knee_z, atol=1e-12)  # x0 holds y0 at every node
    # the same task with the knee touching builds what the analysis-off problem builds
    same = build_problem(capler, knee_task(N, touches=True))
    assert (same.nx, same.ng, len(same.pairs)) == (off.nx, off.ng, len(off.pairs))


def test_a_never_touching_point_stays_out_of_the_holes(capler):
    """touches = false skips a point's contact machinery, not the holes: its hole rows are built as with the analysis
    off (they were dropped, and a plan put the knee in a hole), and a target that puts it in a hole is refused."""
    N = 3
    hole = {"x": 0.5, "z": 0.5, "a": 0.03, "b": 0.03}
    task = knee_task(N)
    with_hole = dataclasses.replace(task, plan=dataclasses.replace(task.plan, holes=parse_task(
        {"contacts": [{"point": "foot"}], "initial": {"q": [0.0] * 4}, "horizon": {"tau_f": 1.0, "N": 2},
         "plan": {"target_q": [0.0] * 4, "holes": [hole]}}).plan.holes))
    on = build_problem(capler, with_hole)
    off = build_problem(capler, with_hole, ProblemOptions(scene_analysis=False))
    assert on.g_blocks["holes"].shape == off.g_blocks["holes"].shape == (N, 2)  # foot and knee
    knee = np.asarray(on.system.dyn.point_position("knee")(np.array(task.plan.target_q)), float).ravel()
    inside = dataclasses.replace(with_hole.plan.holes[0], x=float(knee[0]), z=float(knee[2]))
    with pytest.raises(InputError, match="contact point 'knee' .* inside plan.holes"):
        build_problem(capler, dataclasses.replace(with_hole, plan=dataclasses.replace(with_hole.plan, holes=(inside,))))


def test_a_never_touching_point_in_the_ground_at_the_start_or_target_is_refused(capler):
    """touches = false keeps a point's gap >= 0 row from node 1 on; a start or target that puts the point in the ground
    is an InputError, as for a touching point (the start was planned, exit 0, MuJoCo then saw 30 mm penetration; the
    target ran 16 NLPs to "out of reach"). Its restitution builds no elastic state and the record says so."""
    knee_in_ground = (0.0, 0.05, 1.1, 1.5)  # knee 4 cm below the ground, foot 13 cm above it
    task = knee_task(3)
    with pytest.raises(InputError,
                       match=r"initial.q puts contact point 'knee' 0.0407\d* m below .* \(touches = false\)"):
        build_problem(capler, dataclasses.replace(task, initial=dataclasses.replace(task.initial, q=knee_in_ground)))
    with pytest.raises(InputError, match=r"plan.target_q puts contact point 'knee' .* \(touches = false\)"):
        build_problem(capler, dataclasses.replace(task, plan=dataclasses.replace(task.plan, target_q=knee_in_ground)))
    elastic_knee = dataclasses.replace(task, contacts=(task.contacts[0], dataclasses.replace(task.contacts[1],
                                                                                               restitution=0.5)))
    skips = analyze_scene(capler, elastic_knee)
    assert skips.elastic_state == () and "elastic state p: not built" in skips.reasons[0]
    assert analyze_scene(capler, elastic_knee, enabled=False).elastic_state == ("knee",)


def test_an_infeasible_plan_names_the_never_touching_points(tmp_path, point_mass):
    """A plan IPOPT finds locally infeasible lists what may make it so: the never-touching points' rows too (a point
    starting on the ground, moving into it at 2 m/s, that no control within u_bound keeps off it in one step; the
    message named the control bounds, holes and joint limits only)."""
    xml = point_mass.path.read_text()
    assert xml.count('<site name="point"') == 1
    path = tmp_path / "probe.xml"
    path.write_text(xml.replace('<site name="point"', '<site name="probe" pos="0.1 0 -0.05" size="0.01"/>'
                                '<site name="point"'))
    task = parse_task({"contacts": [{"point": "point", "mu": 0.5}, {"point": "probe", "mu": 0.5, "touches": False}],
                       "initial": {"q": [0.0, 0.05], "v": [0.0, -2.0]}, "horizon": {"tau_f": 0.5, "N": 10},
                       "plan": {"target_q": [0.2, 0.05], "u_bound": 30.0}})
    result = solve(build_problem(load_robot(path), task))
    assert not result.stats.converged
    assert "locally infeasible" in result.stats.message
    assert "and probe kept off the ground (touches = false)" in result.stats.message


def test_touches_key_is_checked(capler):
    """contacts.touches must be a boolean; a task whose every contact is touches = false cannot be planned."""
    with pytest.raises(TaskError, match="contacts\\[0\\].touches must be true or false"):
        parse_task({"contacts": [{"point": "foot", "touches": "no"}], "initial": {"q": [0.0, 0.4, 0, 0]},
                    "horizon": {"tau_f": 1.0, "N": 2}})
    task = knee_task(2)
    task = dataclasses.replace(task, contacts=(task.contacts[1],))
    with pytest.raises(InputError, match="touches = false"):
        build_problem(capler, task)


def test_unreachable_holes_are_dropped_and_cannot_be_active(point_mass):
    """Holes 1 and 2 lie beyond every position the bounded point can take: dropped, and positive at
    every sampled configuration of the unskipped problem (so never active); the kept rows are the same."""
    N = 3
    on = build_problem(point_mass, holes_task(N))
    off = build_problem(point_mass, holes_task(N), ProblemOptions(scene_analysis=False))
    assert on.skips.dropped_holes == (("point", 1), ("point", 2))
    assert on.g_blocks["holes"].shape == (N, 1) and off.g_blocks["holes"].shape == (N, 3)
    assert on.nx == off.nx and off.ng - on.ng == 2 * N
    g_on, g_off = (ca.Function("g", [pb.x, pb.p], [pb.g]) for pb in (on, off))
    keep = np.setdiff1d(np.arange(off.ng), off.g_blocks["holes"][:, 1:].ravel())
    rng = np.random.default_rng(1)
    lo, hi = np.array([-0.1, -1.0]), np.array([0.6, 1.0])
    for _ in range(20):
        x = on.x0 + rng.normal(size=on.nx)
        x[on.var_blocks["y"][:, :2]] = rng.uniform(lo, hi, size=(N, 2))  # q inside the bounds (z: any height)
        a = np.asarray(g_on(x, on.params(1.0)), float).ravel()
        b = np.asarray(g_off(x, off.params(1.0)), float).ravel()
        np.testing.assert_allclose(a, b[keep], rtol=0, atol=1e-12)
        assert np.all(b[off.g_blocks["holes"][:, 1:].ravel()] > 0)


def test_a_hole_straddling_an_edge_of_the_reach_box_is_kept(point_mass):
    """The point's reach box is x in [-0.1, 0.6] m (joint bounds of holes_task). A hole over x in [-0.17, -0.07] m
    contains the box's lower edge, and one over [0.55, 0.65] m its upper edge: the point can stand in either at
    x = -0.1 or 0.6 m, so neither is dropped; holes wholly beyond the edges (x in [-0.3, -0.2], [0.7, 0.8]) are."""
    holes = [{"x": -0.12, "a": 0.05, "b": 0.05}, {"x": 0.6, "a": 0.05, "b": 0.05},
             {"x": -0.25, "a": 0.05, "b": 0.05}, {"x": 0.75, "a": 0.05, "b": 0.05}]
    plan = {"target_q": [0.5, 0.0], "u_bound": 30.0, "holes": holes,
            "joint_bounds": [{"joint": "x", "lower": -0.1, "upper": 0.6}]}
    task = parse_task({"contacts": [{"point": "point", "mu": 0.5}], "initial": {"q": [0.0, 0.0]},
                       "horizon": {"tau_f": 1.0, "N": 2}, "plan": plan})
    lo, hi = reach_box(point_mass, "point", *task.q_bounds(point_mass))
    assert (lo[0], hi[0]) == (-0.1, 0.6)
    assert analyze_scene(point_mass, task).dropped_holes == (("point", 2), ("point", 3))


def test_reach_box_holds_every_sampled_position(capler):
    """Capler with bounded base slides: every sampled foot and knee position lies in its reach box;
    unbounded slides (the default task) give an unbounded box in x and z, so no hole is dropped."""
    task = load_task("robots/capler.toml")
    lower, upper = task.q_bounds(capler)
    lo_x, hi_x = lower.copy(), upper.copy()
    lo_x[:2], hi_x[:2] = (-0.1, 0.2), (1.0, 0.6)
    rng = np.random.default_rng(2)
    from planner.dynamics import Dynamics

    dyn = Dynamics(capler)
    for point in ("foot", "knee"):
        box_lo, box_hi = reach_box(capler, point, lo_x, hi_x)
        pos = np.array([np.asarray(dyn.point_position(point)(rng.uniform(lo_x, hi_x)), float).ravel() for _ in range(SAMPLES)])
        assert np.all(pos >= box_lo - 1e-12) and np.all(pos <= box_hi + 1e-12), point
        lo, hi = reach_box(capler, point, lower, upper)
        assert np.isinf(lo[[0, 2]]).all() and np.isinf(hi[[0, 2]]).all()
    assert analyze_scene(capler, task).dropped_holes == ()


def test_scene_record_and_option(point_mass):
    """Problem.skips says what was left out and why (the JSON that summary.json carries); the elastic
    state is never built for inelastic scenes; scene_analysis must be a bool."""
    pb = build_problem(point_mass, holes_task(2))
    rec = pb.skips.to_json()
    assert rec["enabled"] and rec["dropped_holes"] == [{"contact": "point", "hole": 1}, {"contact": "point", "hole": 2}]
    assert rec["elastic_state"] == [] and any("elastic state p: not built" in r for r in rec["reasons"])
    assert sum("out of reach" in r for r in rec["reasons"]) == 2
    # the hole's place and size are said (one out of reach in z was named by its x only, inside the x range)
    assert "point: hole 1 at (x, z) = (1.5, 0) m, half-axes (0.25, 0.1) m, is out of reach (x in [-0.1, 0.6] m" in (
        " ".join(rec["reasons"]))
    assert pb.system.ny == 2 * 2 + 1  # q, v, clock: no p
    with pytest.raises(InputError, match="scene_analysis"):
        ProblemOptions(scene_analysis="yes")


def test_a_frictionless_wall_beside_a_rough_floor_is_named_by_its_contact(point_mass):
    """A point on a rough floor and a frictionless wall: the scene lists the wall's contact label (point#2) as
    frictionless, not the point, whose floor contact keeps its friction."""
    task = parse_task({"contacts": [{"point": "point", "mu": 0.5}, {"point": "point", "normal": [1.0, 0.0, 0.0]}],
                       "initial": {"q": [0.1, 0.0]}, "horizon": {"tau_f": 0.3, "N": 3}})
    skips = analyze_scene(point_mass, task)
    assert skips.frictionless == ("point#2",) and any(r.startswith("point#2: mu = 0") for r in skips.reasons)


def test_summary_carries_the_scene(point_mass):
    """solve() puts the record into the result's summary (summary.json key "scene")."""
    task = dataclasses.replace(slide_task(2), horizon=Horizon(tau_f=0.2, N=2))
    res = solve(build_problem(point_mass, task))
    assert res.summary()["scene"]["frictionless"] == ["point"]


def test_the_report_names_the_holes_left_out(point_mass):
    """A plan's report names each hole the scene analysis left out as out of reach (summary.json's scene listed them,
    the run said nothing, session 58's tester); the hole in reach is not named."""
    res = solve(build_problem(point_mass, holes_task(20)))
    left = [line for line in res.report().splitlines() if line.startswith("  left out: ")]
    assert [line.split(" at (x, z)")[0] for line in left] == ["  left out: point: hole 1", "  left out: point: hole 2"]
    assert all("is out of reach (x in [-0.1, 0.6] m" in line for line in left), left


def test_a_hole_wholly_below_the_ground_is_dropped(point_mass):
    """A hole whose top (z + b) is at or below a flat ground, where no contact point goes, is dropped for every point
    (the warning said so, yet its row stayed and moved the hop's path): the NLP is the one without it, and the plan
    equals that one's to the bit."""
    N = 6
    base = {"contacts": [{"point": "point", "mu": 0.5}], "initial": {"q": [0.0, 0.0]}, "horizon": {"tau_f": 1.0, "N": N},
            "plan": {"target_q": [0.5, 0.0], "u_bound": 30.0}}
    buried = dict(base, plan=dict(base["plan"], holes=[{"x": 0.25, "z": -5.0, "a": 0.25, "b": 0.1},
                                                       {"x": 0.4, "z": -0.1, "a": 0.1, "b": 0.1}]))
    task = parse_task(buried)
    assert task.buried_holes() == (0, 1)
    with pytest.warns(UserWarning, match=r"wholly below the ground .* \(the scene analysis drops it\)"):
        with_holes = build_problem(point_mass, task)
    without = build_problem(point_mass, parse_task(base))
    with pytest.warns(UserWarning, match=r"wholly below the ground") as said:  # analysis off: kept, not said dropped
        assert build_problem(point_mass, task, ProblemOptions(scene_analysis=False)).skips.dropped_holes == ()
    assert not any("drops it" in str(w.message) for w in said)
    assert with_holes.skips.dropped_holes == (("point", 0), ("point", 1))
    assert with_holes.nx == without.nx and with_holes.ng == without.ng
    a, b = solve(with_holes), solve(without)
    assert np.array_equal(a.trajectory.y, b.trajectory.y)


# [m] a sampled position against its box: the box is built from the same kinematics, rounding only
BOX_ROUNDING = 1e-12
HINGE_THEN_SLIDE = """<mujoco><worldbody><body name="arm" pos="0 0 1">
  <joint name="hinge" type="hinge" axis="0 1 0"/>
  <geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.02" mass="1"/>
  <body name="rod" pos="0 0 -0.3"><joint name="slide" type="slide" axis="0 0 1" range="-0.5 0.1"/>
    <geom type="sphere" size="0.02" mass="0.5"/><site name="tip" pos="0 0 0"/></body>
</body></worldbody>
<actuator><motor joint="hinge"/><motor joint="slide"/></actuator></mujoco>"""


def test_reach_box_of_a_slide_below_a_hinge_holds_every_sampled_position(tmp_path):
    """A slide below a hinge, its range [-0.5, 0.1] wider below zero than above: every sampled tip position lies in
    the tip's reach box (session 65's mutation testing: a radius from the slide's upper end, not its larger
    magnitude, drops a reachable hole at (0, 0.3) as out of reach; Capler, the other reach-box test's robot, has no
    slide below a hinge to show it)."""
    from planner.dynamics import Dynamics

    path = tmp_path / "arm.xml"
    path.write_text(HINGE_THEN_SLIDE)
    robot = load_robot(str(path))
    lo, hi = reach_box(robot, "tip", robot.q_lower, robot.q_upper)
    tip, rng = Dynamics(robot).point_position("tip"), np.random.default_rng(1)
    for q in zip(rng.uniform(-np.pi, np.pi, SAMPLES), rng.uniform(-0.5, 0.1, SAMPLES)):
        p = np.asarray(tip(np.array(q)), float).ravel()
        assert np.all(p >= lo - BOX_ROUNDING) and np.all(p <= hi + BOX_ROUNDING), (q, p, lo, hi)


def test_a_hole_below_the_ground_is_kept_when_a_point_touches_only_a_wall(capler):
    """A hole below the ground is dropped as buried only when every contact point is held above the ground; the
    knee, whose only contact is a wall (normal along x), is not, so the hole stays (session 65's mutation testing:
    `any` for `all` drops it, and the knee could be planned into it, with every test green)."""
    task = parse_task({"contacts": [{"point": "foot"}, {"point": "knee", "normal": [1.0, 0.0, 0.0]}],
                       "initial": {"q": [0.5, 0.4, 0.0, 0.0]}, "horizon": {"tau_f": 0.5, "N": 10},
                       "plan": {"target_q": [0.6, 0.4, 0.0, 0.0],
                                "holes": [{"x": 1.0, "z": -0.5, "a": 0.2, "b": 0.1}]}})
    assert task.buried_holes() == ()
    assert analyze_scene(capler, task).dropped_holes == ()


# a hinge whose tip sits at a diagonal offset (0.3, 0, -0.4) from it: 0.5 m away, though no component exceeds 0.4 m
DIAGONAL_ARM = """<mujoco><worldbody><body name="arm" pos="0 0 1">
  <joint name="hinge" type="hinge" axis="0 1 0"/>
  <geom type="capsule" fromto="0 0 0 0.3 0 -0.4" size="0.02" mass="1"/>
  <site name="tip" pos="0.3 0 -0.4"/>
</body></worldbody>
<actuator><motor joint="hinge"/></actuator></mujoco>"""
DIAGONAL_SEED = 3  # the sampled hinge angles


def test_the_reach_of_a_diagonal_offset_below_a_hinge_is_its_length(tmp_path):
    """Below a hinge, a point reaches as far as the length of its offset from the hinge (the module docstring: R is
    the sum of the offsets' lengths): the tip 0.5 m from the hinge sweeps a circle of radius 0.5 m, so every sampled
    tip position lies in its reach box, and a small hole 0.47-0.51 m from the hinge, around the tip's point (0.5, 1),
    is kept (session 65's mutation testing: a radius from the offset's largest component, 0.4 m, dropped it as out of
    reach, and the plan could cross it)."""
    from planner.dynamics import Dynamics

    path = tmp_path / "arm.xml"
    path.write_text(DIAGONAL_ARM)
    robot = load_robot(str(path))
    lo, hi = reach_box(robot, "tip", robot.q_lower, robot.q_upper)
    tip, rng = Dynamics(robot).point_position("tip"), np.random.default_rng(DIAGONAL_SEED)
    for angle in rng.uniform(-np.pi, np.pi, SAMPLES):
        p = np.asarray(tip(np.array([angle])), float).ravel()
        assert np.all(p >= lo - BOX_ROUNDING) and np.all(p <= hi + BOX_ROUNDING), (angle, p, lo, hi)
    task = parse_task({"contacts": [{"point": "tip"}], "initial": {"q": [0.0]}, "horizon": {"tau_f": 1.0, "N": 10},
                       "plan": {"target_q": [0.5], "holes": [{"x": 0.49, "z": 1.0, "a": 0.02, "b": 0.02}]}})
    assert analyze_scene(robot, task).dropped_holes == ()
