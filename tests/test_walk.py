"""Planning with several contact points and the periodic walk of the biped (issue 7B).

The one-contact problems are pinned to a fingerprint of main's code at the branch point
(tests/data/one_contact_fingerprint.json, written by `fingerprint` below before any change): same
variables, names, bounds, constraint expressions, Jacobian sparsity and g(x0)."""
from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from planner.errors import TaskError
from planner.gait import RELABEL, WALK_VALIDATION_STEPS as WALK_STEPS, PhaseReference, landing_first, plan_step, validate_walk
from planner.model import load_robot
from planner.problem import build_problem
from planner.task import Horizon, load_task, parse_task

ROBOTS = Path(__file__).resolve().parent.parent / "robots"
FINGERPRINT = Path(__file__).resolve().parent / "data" / "one_contact_fingerprint.json"
# the default task's plan (`planner plan biped`, 2026-11-22): t, q, v, u, impact_times of its one step
WALK_STEP = Path(__file__).resolve().parent / "data" / "biped_walk_step.npz"
# the default task's hint-free plan without its velocity bound (`python -m scripts.bench_biped_walk --lower none`,
# 2026-11-23): foot_2 stands, foot_1 lands inside the period (t = 0.215 of 0.406 s), then stands
MIDSTEP = Path(__file__).resolve().parent / "data" / "biped_walk_midstep.npz"
PERIODIC_TOL = 1e-9  # [rad] the plan's periodicity residual is 2e-14; the pinned angles inherit it
STEP_LENGTH_TOL = 0.01  # [m] MuJoCo's step lengths against the plan's 0.25 m; measured within 2.0 mm (saved plan), 4.6 mm (hint-free)
WALK_ANGLE_TOL = np.deg2rad(3.0)  # [rad] hinge and torso against the plan (plus the speed loop's lean) at the
#   same stance-leg angle; measured 1.6 deg, mostly the lean's step change at a landing


LEG_RATE = 0.3  # [rad/s] robots/biped.toml's lower bound on leg 1's angular velocity (torso + hinge_1)
BOUND_TOL = 1e-6  # [rad/s] IPOPT's constraint tolerance is 1e-8; the polish ends within it
NORM_REL = 1e-14  # ||g(x0)|| on two CPUs (Haswell and SkylakeX BLAS kernels): 1 to 2 ulp apart


def fingerprint(prob) -> dict:
    P = prob.params(1e3, 1.0)
    g = np.asarray(ca.Function("g", [prob.x, prob.p], [prob.g])(prob.x0, P), float).ravel()
    f = float(ca.Function("f", [prob.x, prob.p], [prob.f])(prob.x0, P))
    J = ca.jacobian(prob.g, prob.x).sparsity()

    def h(a):
        return hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()

    return {"nx": prob.nx, "ng": prob.ng, "f_x0": f, "g_x0_sha": h(g), "g_x0_norm": float(np.linalg.norm(g)),
            "var_names_sha": hashlib.sha256("|".join(prob.var_names).encode()).hexdigest(),
            "g_blocks": {k: list(v.shape) for k, v in prob.g_blocks.items()},
            "bounds_sha": h(np.concatenate([prob.lbx, prob.ubx, prob.lbg, prob.ubg, prob.x0])),
            "jac_nnz": J.nnz(), "jac_sha": hashlib.sha256(np.array(J.get_triplet()).tobytes()).hexdigest(),
            "g_str_sha": hashlib.sha256(str(prob.g).encode()).hexdigest(), "g_x0": g.tolist() if prob.ng < 500 else None}


def _one_contact_problems():
    capler = load_robot(ROBOTS / "capler.xml")
    task = load_task(ROBOTS / "capler.toml")
    hop = parse_task({"contacts": [{"point": "point", "mu": 0.5}], "initial": {"q": [0.0, 0.0]}, "horizon": {"tau_f": 1.0, "N": 12},
                      "plan": {"target_q": [0.5, 0.0], "u_bound": 30.0}})
    return {"capler_N10": (capler, dataclasses.replace(task, horizon=Horizon(tau_f=0.5, N=10))),
            "capler_default": (capler, task),
            "point_mass_hop": (load_robot(ROBOTS / "point_mass.xml"), hop)}


@pytest.mark.parametrize("name", ["capler_N10", "capler_default", "point_mass_hop"])
def test_one_contact_problems_are_unchanged(name):
    """Same nx, ng, names, bounds, guess, symbolic g, Jacobian sparsity and g(x0) as main's code."""
    robot, task = _one_contact_problems()[name]
    ref = json.loads(FINGERPRINT.read_text())[name]
    got = fingerprint(build_problem(robot, task))
    assert (got["nx"], got["ng"]) == (ref["nx"], ref["ng"])
    if ref["g_x0"] is not None:
        np.testing.assert_array_equal(got["g_x0"], ref["g_x0"])
    for key in ref:
        if key == "g_x0_norm":  # numpy's norm sums in the order of the CPU's BLAS kernel; g itself is compared bitwise
            assert got[key] == pytest.approx(ref[key], rel=NORM_REL), key
        else:
            assert got[key] == ref[key], key


def _biped(N: int = 6):
    task = load_task(ROBOTS / "biped.toml")
    if N is not None:
        task = dataclasses.replace(task, horizon=Horizon(tau_f=task.horizon.tau_f * N / task.horizon.N, N=N))
    return load_robot(ROBOTS / "biped.xml"), task


def test_periodic_problem_has_free_initial_state_and_periodic_rows():
    """y_0 is a variable block ahead of the stages (x(0) and t(0) pinned, q(0) in the joint bounds);
    the "periodic" rows are q_N - S q_0 - step e_x and v_N - S v_0 (legs swapped)."""
    robot, task = _biped()
    pb = build_problem(robot, task)
    ny, nq, nv = pb.system.ny, pb.system.nq, pb.system.nv
    assert pb.var_blocks["y0"].tolist() == list(range(ny)) and pb.var_blocks["u"][0, 0] == ny
    assert pb.var_names[0] == "q[x]_0" and pb.var_names[ny - 1] == "t_0"
    assert pb.lbx[0] == pb.ubx[0] == 0.0 and pb.lbx[ny - 1] == pb.ubx[ny - 1] == 0.0
    assert (pb.lbx[2], pb.ubx[2]) == (-0.2, 0.2)  # torso
    assert np.all(np.isinf(pb.lbx[nq : nq + nv]))
    assert "terminal" not in pb.g_blocks and pb.g_blocks["periodic"].shape == (1, nq + nv)
    # a state pair that is exactly periodic
    rng = np.random.default_rng(0)
    x = pb.x0.copy()
    y0 = rng.normal(size=ny)
    yN = y0.copy()
    yN[[3, 4]], yN[[nq + 3, nq + 4]] = y0[[4, 3]], y0[[nq + 4, nq + 3]]
    yN[0] += 0.25
    x[pb.var_blocks["y0"]], x[pb.var_blocks["y"][-1]] = y0, yN
    g = np.asarray(ca.Function("g", [pb.x, pb.p], [pb.g])(x, pb.params(1.0)), float).ravel()
    np.testing.assert_allclose(g[pb.g_blocks["periodic"].ravel()], 0.0, atol=1e-12)
    yN[3] += 1e-3
    x[pb.var_blocks["y"][-1]] = yN
    g = np.asarray(ca.Function("g", [pb.x, pb.p], [pb.g])(x, pb.params(1.0)), float).ravel()
    assert g[pb.g_blocks["periodic"][0, 3]] == pytest.approx(1e-3)
    np.testing.assert_array_equal(pb.split(x)["Y"][0], y0)


def test_several_contacts_cone_and_gates():
    """Per point: two cone rows on its joint force (lambda_n, lambda_t), weighted by the clock R; gates
    1 - beta_i for alpha_i, zeta_i and gamma_i of the same point (1 at the hint-free guess, which stands)."""
    robot, task = _biped(N=3)
    pb = build_problem(robot, task)
    assert pb.g_blocks["friction_cone"].shape == (3, 4)
    names = [s.name for s in pb.system.switches]
    gates = np.asarray(pb.notes["gates"](pb.x0), float).ravel()
    n = len(names)
    assert gates.shape == (3 * 2 * n,)
    # standing guess: beta = 0 for both feet, so every gate is 1
    np.testing.assert_allclose(gates, 1.0)
    # foot_2 in flight at stage 0: its alpha, gamma, zeta gates drop to 0, foot_1's stay
    x = pb.x0.copy()
    x[pb.var_blocks["sigma"][0][names.index("beta[foot_2]")]] = 1.0
    gates = np.asarray(pb.notes["gates"](x), float).ravel()[:n]
    for i, nm in enumerate(names):
        expect = 0.0 if nm in ("alpha[foot_2]", "gamma[foot_2]", "zeta[foot_2]") else 1.0
        assert gates[i] == expect, nm


@pytest.mark.slow
def test_biped_walks_periodically_from_a_hint_free_start():
    """robots/biped.toml from the standing guess: periodic to 1e-6, exact complementarity, single
    support, exactly one impact per step (the swing foot: normal and tangential impulse), leg 1 turning
    forward at >= 0.3 rad/s (the task's velocity bound), and the plan walks 10 of 10 steps in MuJoCo with
    the phase-indexed replay (validate_walk), step lengths close to the plan's."""
    from planner.homotopy import solve

    robot, task = _biped(N=None)
    pb = build_problem(robot, task)
    res = solve(pb)
    assert res.stats.converged, res.stats.message
    x = res.extra["_x"]
    g = np.asarray(ca.Function("g", [pb.x, pb.p], [pb.g])(x, pb.params(0.0)), float).ravel()
    assert np.max(np.abs(g[pb.g_blocks["periodic"].ravel()])) <= 1e-6
    assert res.stats.complementarity_residual <= 1e-6
    names = [s.name for s in pb.system.switches]
    sig = x[pb.var_blocks["sigma"]]
    b1, b2 = sig[:, names.index("beta[foot_1]")] > 0.5, sig[:, names.index("beta[foot_2]")] > 0.5
    assert np.sum(b1 ^ b2) >= pb.N // 2  # single support most of the step
    f1, f2 = sig[:, names.index("beta[foot_1]")] > 0.99, sig[:, names.index("beta[foot_2]")] > 0.99
    assert not np.any(f1 & f2)  # never both feet in the air (walking, not running; the landing step mixes, beta in (0, 1))
    impacts = res.trajectory.impacts
    assert len(impacts) == 1, impacts
    (imp,) = impacts
    assert imp.impulse > 1.0 and abs(imp.impulse_tangential) > 0.1
    # one foot swings (in flight most of the step), the other stands; the landing is the swing foot's late in
    # the step, or early the stance foot's (the previous step's swing foot, relabelled by the periodic map)
    flight = {"foot_1": int(b1.sum()), "foot_2": int(b2.sum())}
    swinger = max(flight, key=flight.get)
    assert flight[swinger] >= pb.N // 2 and min(flight.values()) <= 1, flight
    assert (imp.contact == swinger) == (imp.time > res.trajectory.t[-1] / 2), (imp.contact, imp.time, flight)
    ys = np.vstack([x[pb.var_blocks["y0"]], x[pb.var_blocks["y"]]])
    leg_1 = ys[:, robot.nq + robot.dof_index("torso")] + ys[:, robot.nq + robot.dof_index("hinge_1")]
    assert leg_1.min() >= LEG_RATE - BOUND_TOL
    tr = res.trajectory
    walk = validate_walk(robot, task, {"t": tr.t, "q": tr.q, "v": tr.v, "u": tr.u})
    assert walk.passed, walk.failures
    assert (walk.walking.steps_walked, walk.walking.steps_asked) == (WALK_STEPS, WALK_STEPS)
    steps = np.array(walk.walking.step_lengths[:WALK_STEPS])
    assert np.max(np.abs(steps - walk.walking.planned_step_length)) < STEP_LENGTH_TOL


def _saved_step():
    return dict(np.load(WALK_STEP))


def test_plan_step_is_the_pinned_stance_of_the_saved_plan():
    """The saved plan's step on the pinned model: foot_2 stands (it lands at t = 0), foot_1 swings; the
    frozen landing's pre-impact samples are dropped (time strictly increasing from 0); the stance-leg
    angle indexes the step; the end angles are the start's with the legs swapped (periodicity)."""
    robot, task = _biped(N=None)
    model, step = plan_step(robot, task, _saved_step())
    assert (model.layout.stance_foot, model.layout.swing_foot) == ("foot_2", "foot_1")
    assert step.t[0] == 0.0 and np.all(np.diff(step.t) > 0) and step.u.shape == (len(step.t) - 1, 2)
    assert PhaseReference.applies(step.x)
    np.testing.assert_allclose(RELABEL @ step.x[-1, :3], step.x[0, :3], atol=PERIODIC_TOL)
    with pytest.raises(TaskError, match="periodic"):
        plan_step(robot, dataclasses.replace(task, plan=None), _saved_step())


def test_landing_first_starts_a_midstep_landing_plan_at_its_landing():
    """landing_first on a plan whose landing is inside the period: the same number of samples, times
    from 0 to T (non-decreasing), starting with the landing's post-impact sample and ending with it
    relabelled and shifted one step; the seam joins the plan's last sample to its relabelled second
    one, which holds because the plan's state at T is its relabelled, shifted state at 0 (checked). The
    rotated step has one stance foot whose leg angle indexes the replay (the unrotated plan's does
    not). A plan landing at t = 0, and arrays without impact_times, come back as they are."""
    robot, task = _biped(N=None)
    a = dict(np.load(MIDSTEP))
    t, q, v, u = (a[k] for k in ("t", "q", "v", "u"))
    perm, along, _ = task.periodic_map(robot)
    shift = np.zeros(robot.nq)
    shift[along] = task.plan.periodic.step
    np.testing.assert_allclose(q[0][perm] + shift, q[-1], atol=PERIODIC_TOL)
    np.testing.assert_allclose(v[0][perm], v[-1], atol=PERIODIC_TOL)
    k = np.nonzero(t == a["impact_times"][0])[0][-1]
    t2, q2, v2, u2 = landing_first(robot, task, a)
    assert len(t2) == len(t) and t2[0] == 0.0 and t2[-1] == pytest.approx(t[-1]) and np.all(np.diff(t2) >= 0)
    np.testing.assert_array_equal(q2[0], q[k])
    np.testing.assert_array_equal(q2[-1], q[k][perm] + shift)
    np.testing.assert_array_equal(v2[-1], v[k][perm])
    np.testing.assert_array_equal(u2[-1], u[k][::-1])  # the two motors drive the swapped hinges
    seam = len(t) - k
    np.testing.assert_array_equal(q2[seam - 1], q[-1])
    np.testing.assert_array_equal(q2[seam], q[1][perm] + shift)
    model, step = plan_step(robot, task, a)
    assert model.layout.stance_foot == "foot_1" and PhaseReference.applies(step.x)  # from its landing to the next
    assert not PhaseReference.applies(plan_step(robot, task, {k: a[k] for k in ("t", "q", "v", "u")})[1].x)
    saved = _saved_step()
    for arrays in (saved, {k: a[k] for k in ("t", "q", "v", "u")}):
        for got, key in zip(landing_first(robot, task, arrays), ("t", "q", "v", "u")):
            np.testing.assert_array_equal(got, arrays[key])


def test_midstep_landing_plan_walks_ten_steps_in_mujoco():
    """The plan whose landing is inside the period (refused before landing_first: its stance-leg angle
    turned back) walks 10 of 10 steps in MuJoCo, step lengths close to the plan's."""
    robot, task = _biped(N=None)
    walk = validate_walk(robot, task, dict(np.load(MIDSTEP)))
    assert walk.passed, walk.failures
    steps = np.array(walk.walking.step_lengths[:WALK_STEPS])
    assert np.max(np.abs(steps - walk.walking.planned_step_length)) < STEP_LENGTH_TOL


def test_saved_walk_plan_walks_ten_steps_in_mujoco(tmp_path):
    """`planner validate` on a periodic plan walks its step 10 times on the floating robot in MuJoCo
    (phase-indexed virtual constraints, legs swapped per step) and reports it: exit 0, steps walked
    10 of 10, step lengths and angles close to the plan's; the report lists the 10 landings asked for and their
    step lengths, not also those of the replay's spare 20 % (it listed 12 for 10 steps)."""
    from planner.cli import main
    from planner.result import write_files

    write_files(tmp_path, _saved_step(), {"command": "plan", "robot": str(ROBOTS / "biped.xml"),
                                          "task": str(ROBOTS / "biped.toml"), "converged": True})
    assert main(["validate", str(tmp_path), "-q"]) == 0
    v = json.loads((tmp_path / "summary.json").read_text())["validation"]
    assert v["mode"] == "walk" and v["passed"] and (v["steps_walked"], v["steps_asked"]) == (WALK_STEPS, WALK_STEPS)
    w = v["walking"]
    assert len(w["impact_times"]) == len(w["step_lengths_m"]) == WALK_STEPS
    assert np.max(np.abs(np.array(w["step_lengths_m"]) - w["planned_step_length_m"])) < STEP_LENGTH_TOL
    assert max(w["max_hinge_error_rad"], w["max_torso_error_rad"]) < WALK_ANGLE_TOL


def test_a_walk_validation_checks_the_plans_own_positions():
    """With dynamics (a plan of implicit-Euler steps, as validate(DIR) reads from summary.json), a periodic plan's
    validation also holds its samples' positions to their velocities: the saved step passes, and the same step with
    the hip 2 cm higher at one stance sample fails naming it (the walk reads neither the plan's base nor its
    controls: such a plan walked 10 of 10 and passed). The residual is recorded in to_json() and the report, as a
    tracking validation's (it kept the verdict alone)."""
    robot, task = _biped(N=None)
    saved = _saved_step()
    good = validate_walk(robot, task, saved, dynamics=True)
    # the residual is recorded, as a tracking validation's (summary.json kept the verdict alone)
    assert good.passed and good.to_json()["max_flight_residual"] < 1e-6 and "; own dynamics" in good.report()
    raised = {**saved, "q": saved["q"].copy()}
    raised["q"][10, robot.dof_index("z")] += 0.02  # [m]
    plain = validate_walk(robot, task, raised)
    assert plain.passed and "max_flight_residual" not in plain.to_json()  # (the walk alone)
    walk = validate_walk(robot, task, raised, dynamics=True)
    assert not walk.passed and any(f.startswith("the trajectory's own dynamics: its positions do not move at its "
                                                "velocities") and "in 'z'" in f for f in walk.failures), walk.failures
    assert walk.to_json()["flight_residual_positions"] and walk.to_json()["flight_residual_dof"] == "z"
