"""The biped of paper 001 derived from robots/biped.xml: Appendix B and C closed forms, the periodic
gaits of Sec. 4.2 (coarse grid by default, the paper's grid marked slow), and the results contract."""
from __future__ import annotations

import dataclasses
import json
import re
import tomllib

import casadi as ca
import numpy as np
import pytest

from planner.errors import InputError, TaskError
from planner.gait import (STOPPED, GaitOCP, GaitSpec, PhaseReference, PinnedBiped, PinnedGait, WalkGains,
                          _impact_contact, _output_control, desired_curve, final_low, find_layout, periodic_walk,
                          plan_step, replay_gait, run_gait, solve_gait, solve_gait_ipopt)
from planner.model import ROBOTS_DIR, load_robot
from planner.task import GaitPronto, Simulate, load_task, parse_task

M_LEG, M_HIP, M_TORSO, R_LEG, L_TORSO, G = 5.0, 15.0, 10.0, 1.0, 0.5, 9.81
CLOSED_FORM_TOL = 1e-9  # the bound; derivation and closed form differ by round-off only (~1e-14)
FINAL_STATE_TOL = 1e-8  # ||x(T) - Delta^-1(x0)||, the tasks' final_tolerance
COARSE_N = 51  # CI grid: dt = 30 ms instead of 10 ms (RK4 is still accurate to ~1e-4 rad here)
PAPER_U2_CLAIM = 100.0  # [N m] paper 001, Sec. 4.2: gait 1's u2 "is greater than 100 Nm" approaching T
WALK_STEPS = 10  # the bar for the MuJoCo replay
WALK_ANGLE_TOL = np.deg2rad(2.0)  # [rad] hinge and torso error against the plan at the same theta1; measured 0.4 deg
WALK_TORQUE_MARGIN = 1.5  # the replay's peak torque over the plan's: feedback corrections, no landing spikes
SPLINE_TOL = 1e-12  # the phase reference interpolates the plan's samples and slopes exactly (round-off)
DIFF_TOL = 1e-9  # [rad/s] the five-point difference is exact for a cubic; round-off ~1e-16 rad / 10 ms
NEWTON_RATE = 100.0  # [1 / error unit] Newton on x_T: e_next <= C e^2; C <= 12 measured on both coarse gaits
ROUND_OFF_ERROR = 1e-12  # ||x(T) - x_f|| at round-off level, where the quadratic rate no longer shows
EOM_TOL_N = 1e-6  # [N, N m] the floating equation of motion at ~300 N ground forces: round-off (1e-11 measured)
COMPUTED_TORQUE_TOL = 1e-9  # [rad/s^2] y'' = w of the computed torque: round-off (~1e-15 measured)
SAME_STATE_TOL = 1e-10  # [rad, rad/s] one post-impact state along two relabellings: round-off (1.7e-14 measured)


def appendix_b(th, thd):
    """Paper 001, (B.1)-(B.3): M (3, 3) and C + G (3,) of the pinned biped."""
    m, MH, MT, r, l, g = M_LEG, M_HIP, M_TORSO, R_LEG, L_TORSO, G
    t1, t2, t3 = th
    c12, c13, s12, s13 = np.cos(t1 - t2), np.cos(t1 - t3), np.sin(t1 - t2), np.sin(t1 - t3)
    M = np.array([[(1.25 * m + MH + MT) * r**2, -0.5 * m * r**2 * c12, MT * r * l * c13],
                  [-0.5 * m * r**2 * c12, 0.25 * m * r**2, 0.0],
                  [MT * r * l * c13, 0.0, MT * l**2]])
    C = np.array([-0.5 * m * r**2 * s12 * thd[1] ** 2 + MT * r * l * s13 * thd[2] ** 2,
                  0.5 * m * r**2 * s12 * thd[0] ** 2, -MT * r * l * s13 * thd[0] ** 2])
    Gv = np.array([-0.5 * g * (2 * MH + 3 * m + 2 * MT) * r * np.sin(t1), 0.5 * g * m * r * np.sin(t2), -g * MT * l * np.sin(t3)])
    return M, C + Gv


def appendix_c(th):
    """Paper 001, Appendix C as printed: A(theta-) with theta'+ = A theta'- (after relabelling)."""
    m, MH, MT, r, l = M_LEG, M_HIP, M_TORSO, R_LEG, L_TORSO
    t1, t2, t3 = th
    den = -3 * m - 4 * MH - 2 * MT + 2 * m * np.cos(2 * t1 - 2 * t2) + 2 * MT * np.cos(-2 * t2 + 2 * t3)
    A = np.zeros((3, 3))
    A[0, 0] = (2 * MT * np.cos(-t1 - t2 + 2 * t3) - (2 * m + 4 * MH + 2 * MT) * np.cos(t1 - t2)) / den
    A[0, 1] = m / den
    A[1, 0] = (m - (4 * m + 4 * MH + 2 * MT) * np.cos(2 * t1 - 2 * t2) + 2 * MT * np.cos(2 * t1 - 2 * t3)) / den
    A[1, 1] = 2 * m * np.cos(t1 - t2) / den
    A[2, 0] = ((2 * m * r + 2 * MH * r + 2 * MT * r) * np.cos(t1 - 2 * t2 + t3) - 2 * MH * r * np.cos(-t1 + t3)
               - (2 * m * r + 2 * MT * r) * np.cos(-t1 + t3) + m * r * np.cos(-3 * t1 + 2 * t2 + t3)) / (l * den)
    A[2, 1] = -r * m * np.cos(-t2 + t3) / (l * den)
    A[2, 2] = 1.0
    return A


@pytest.fixture(scope="module")
def robot():
    return load_robot(ROBOTS_DIR / "biped.xml")


@pytest.fixture(scope="module")
def biped(robot):
    return PinnedBiped(robot)


def test_a_landing_from_below_is_armed_at_its_final_approachs_lowest_point():
    """The walk replay arms a swing foot that lands from below at the lowest point of its final approach, not at its
    lowest overall: a gait with the torso at 0.2 rad dipped to -7.8 mm at mid-stance and -6.8 mm before landing; armed
    at the dip, the replay read a landing mid-stride and fell after 1 step (10 of 10 armed at the approach)."""
    height = np.array([0.0, -7.8, -2.7, 40.0, 124.0, 60.0, 5.0, -6.8, -3.0, 0.0]) * 1e-3  # [m]
    assert final_low(height) == 7
    assert final_low(np.array([0.1, 0.05, -0.01, 0.0])) == 2  # one dip: the same as the lowest overall


def test_pinned_model_matches_appendix_b(biped):
    """M_r, C + G and the input map derived from the floating robot file equal (B.1)-(B.4) at random
    states (paper inputs u_paper = -u_motor); the file's 1e-12 kg m^2 leg inertia (MuJoCo needs > 0) is
    far below the tolerance."""
    rng = np.random.default_rng(1)
    for _ in range(20):
        th, thd, u = rng.uniform(-1.2, 1.2, 3), rng.uniform(-3, 3, 3), rng.uniform(-50, 50, 2)
        M, h = appendix_b(th, thd)
        assert np.max(np.abs(np.array(biped.mass(th)) - M)) < CLOSED_FORM_TOL
        assert np.max(np.abs(np.array(biped.bias(th, thd)).ravel() - h)) < CLOSED_FORM_TOL
        u_paper = -u
        U = np.array([-u_paper[0], -u_paper[1], u_paper[0] + u_paper[1]])  # (B.4)
        assert np.max(np.abs(np.array(biped.actuation(th)) @ u - U)) < CLOSED_FORM_TOL


def test_impact_map_matches_appendix_c(biped):
    """The swing-foot impact plus relabelling derived from the file equals Appendix C's A(theta-),
    including design.md's check value at theta- = (pi/8, -pi/8, 20 deg); Delta^-1 inverts Delta."""
    check = np.array([[0.518125, -0.053615, 0], [-0.267261, -0.075824, 0], [1.234093, 0.079059, 1]])
    th = np.array([np.pi / 8, -np.pi / 8, np.deg2rad(20)])
    assert np.max(np.abs(np.array(biped.impact(th)) - check)) < 5e-7  # the check value has 6 decimals
    rng = np.random.default_rng(2)
    for _ in range(20):
        th = rng.uniform(-0.8, 0.8, 3)
        assert np.max(np.abs(np.array(biped.impact(th)) - appendix_c(th))) < CLOSED_FORM_TOL
        x = np.concatenate([th, rng.uniform(-2, 2, 3)])
        assert np.max(np.abs(biped.delta_inverse(biped.delta(x)) - x)) < 1e-12


def test_the_impacts_contact_quantities_are_mujocos(robot, biped):
    """The gait's impact as the contacts see it (summary.json's impact_impulse_N_s, trailing_foot_lift_off_m_s) equals
    an inelastic no-slip impact computed from MuJoCo's mass matrix and Jacobians of the same file at gait 1's
    pre-impact state Delta^-1(x0): M (v+ - v-) = Js' Lambda, Js v+ = 0 (docs/biped.md: (-15.36, 20.02) N s, +0.33
    m/s)."""
    import mujoco

    from planner.gait import _impact_contact

    x_minus = biped.delta_inverse(_spec("biped_gait1.toml").x0)
    got = _impact_contact(biped, x_minus)
    q, v = biped.floating(x_minus[:3], x_minus[3:])
    mj = mujoco.MjModel.from_xml_path(str(robot.path))
    data = mujoco.MjData(mj)
    data.qpos[:], data.qvel[:] = q, v
    mujoco.mj_forward(mj, data)
    M = np.zeros((mj.nv, mj.nv))
    mujoco.mj_fullM(mj, data, M)

    def jacobian(site):
        jac = np.zeros((3, mj.nv))
        mujoco.mj_jacSite(mj, data, jac, None, mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_SITE, site))
        return jac

    Js = jacobian(biped.layout.swing_foot)[[0, 2]]
    impulse = -np.linalg.solve(Js @ np.linalg.solve(M, Js.T), Js @ v)
    v_plus = v + np.linalg.solve(M, Js.T @ impulse)
    assert got["impact_impulse_N_s"] == pytest.approx(impulse.tolist(), abs=CLOSED_FORM_TOL)
    assert got["trailing_foot_lift_off_m_s"] == pytest.approx((jacobian(biped.layout.stance_foot) @ v_plus)[2],
                                                              abs=CLOSED_FORM_TOL)
    assert got["impact_impulse_N_s"] == pytest.approx([-15.36, 20.02], abs=0.005)  # docs/biped.md's two decimals


def test_a_gait_that_asks_the_ground_to_pull_or_slide_says_so():
    """contact_violations names what a unilateral, frictional contact cannot give (such gaits converged silently, and
    MuJoCo's walk fell without a reason): a stance force that pulls (-1356 N, a T = 1 s gait), an impact impulse that
    pulls (-10.2 N s) or leaves the friction cone (ratio 10.3 at mu = 1), a stance force beyond the friction cone,
    a trailing foot moving down after the impact (-0.067 m/s). The shipped gaits' margins give none, nor an impact
    0.5 % outside the cone (the slack a plan's impacts have)."""
    from planner.gait import contact_violations

    good = {"friction_mu": 1.0, "impact_friction_mu": 1.0, "min_normal_force_N": 195.0, "friction_needed": 0.648,
            "impact_impulse_N_s": [-15.36, 20.02], "trailing_foot_lift_off_m_s": 0.33}
    assert contact_violations(good) == []
    cases = (({"min_normal_force_N": -1356.5}, "normal force falls to -1356 N"),
             # gait 1 on a foot of mu = 0.6: it was only said, and `gait --no-validate` exited 0
             ({"friction_needed": 0.648, "friction_mu": 0.6}, "needs |tangential / normal| force up to 0.648, beyond "
                                                              "its contact's mu = 0.6"),
             ({"impact_impulse_N_s": [1.0, -10.19]}, "normal impulse is -10.19 N s"),
             ({"impact_impulse_N_s": [19.5, 1.9]}, "is 10.3 times its normal one 1.9 N s, beyond mu = 1"),
             ({"trailing_foot_lift_off_m_s": -0.067}, "trailing foot moves down at -0.067 m/s"))
    for change, message in cases:
        (line,) = contact_violations({**good, **change})
        assert message in line
    # backwards too (session 65's mutation testing: the tangential impulse's sign kept, 19.5 N s backwards passed)
    (line,) = contact_violations({**good, "impact_impulse_N_s": [-19.5, 1.9]})
    assert "is 10.3 times its normal one 1.9 N s, beyond mu = 1" in line
    # within the 1 % slack the plans' impacts and the stance force have (result.CONE_SLACK): no violation; beyond, one
    assert contact_violations({**good, "impact_impulse_N_s": [10.05, 10.0]}) == []
    assert len(contact_violations({**good, "impact_impulse_N_s": [10.2, 10.0]})) == 1

def test_motor_commands_beyond_the_files_range_are_a_violation(tmp_path):
    """The gait's OCP has no input bounds: commands beyond the robot file's control range (gait 1 needs 72 N m, a
    file of +-30) are a motor violation naming both motors and the range (exit 0 with --no-validate, no word before);
    each motor is held to the other's range too, as the legs swap every step. Within the range: none."""
    from planner.gait import find_layout, gait_violations, motor_violations

    xml = (ROBOTS_DIR / "biped.xml").read_text()
    assert xml.count('ctrlrange="-500 500"') == 2
    path = tmp_path / "weak.xml"
    path.write_text(xml.replace('ctrlrange="-500 500"', 'ctrlrange="-30 30"', 1))  # hip_1 only
    robot = load_robot(path)
    layout = find_layout(robot)
    u = np.array([[71.96, -10.0], [5.0, 62.26]])
    (line,) = motor_violations(robot, layout, u)
    assert line.startswith("the motors need commands from -10 to 71.96 N m, beyond the robot file's control range "
                           "[-30, 30] of 'hip_1', 'hip_2'"), line
    assert motor_violations(robot, layout, np.clip(u, -30.0, 30.0)) == []
    assert gait_violations({"contact_violations": ["a"], "motor_violations": [line]}) == ["a", line]
    # the other motor weak instead (session 65's mutation testing: the first motor's range alone passed this test)
    second = xml.index('ctrlrange="-500 500"', xml.index('ctrlrange="-500 500"') + 1)
    path.write_text(xml[:second] + xml[second:].replace('ctrlrange="-500 500"', 'ctrlrange="-30 30"', 1))  # hip_2
    robot = load_robot(path)
    (line,) = motor_violations(robot, find_layout(robot), u)
    assert "[-30, 30] of 'hip_1', 'hip_2'" in line, line


def test_a_gait_beyond_the_files_joint_ranges_is_a_violation(tmp_path, capsys):
    """The gait's OCP has no joint limits and MuJoCo's replay enforces the robot file's: hinges of range +-0.5 rad,
    which gait 1 leaves (x0 has hinge_1 at -0.74 rad), are one violation line per joint naming its range and how far
    the walk goes, listed in summary.json, and `planner gait --no-validate` exits 1 (it said "converged", exit 0, and
    its walk fell with no reason given). Within the ranges: none."""
    from planner.cli import main
    from planner.gait import gait_violations, joint_violations

    xml = (ROBOTS_DIR / "biped.xml").read_text()
    for hinge in ("hinge_1", "hinge_2"):
        old = f'<joint name="{hinge}" type="hinge" axis="0 1 0"/>'
        assert xml.count(old) == 1
        xml = xml.replace(old, old[:-2] + ' range="-0.5 0.5"/>')
    path = tmp_path / "limited.xml"
    path.write_text(xml)
    robot = load_robot(path)
    q = np.zeros((3, robot.nq))
    q[1, robot.dof_names.index("hinge_1")] = -0.8
    (line,) = joint_violations(robot, q)
    assert line == ("hinge_1 left the robot file's range [-0.5, 0.5] rad at 1 of 3 nodes (to -0.8): the gait's OCP "
                    "has no joint limits, MuJoCo's replay enforces the range"), line
    assert joint_violations(robot, np.clip(q, -0.5, 0.5)) == []
    assert gait_violations({"motor_violations": ["m"], "joint_violations": [line]}) == ["m", line]
    coarse = tmp_path / "n15.toml"
    coarse.write_text((ROBOTS_DIR / "biped_gait1.toml").read_text().replace("\nN = 153\n", "\nN = 15\n"))
    assert main(["gait", str(path), "--task", str(coarse), "--out", str(tmp_path / "out"), "--no-validate", "-q"]) == 1
    err = capsys.readouterr().err
    assert "failed: hinge_1 left the robot file's range [-0.5, 0.5] rad" in err and "hinge_2 left" in err, err
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert [v.split()[0] for v in summary["joint_violations"]] == ["hinge_1", "hinge_2"]


@pytest.mark.parametrize("old, new, differs", [('mass="5"', 'mass="5.5"', "mass matrix"),
                                                ('gear="1"', 'gear="2"', "actuation")])
def test_a_biped_whose_legs_differ_is_refused(tmp_path, old, new, differs):
    """The periodic gait swaps the legs every step, so they must be mirror images: leg 2 0.5 kg heavier, or its motor
    of gear 2, is a TaskError naming what differs (it converged to a 10-step "periodic" walk that was no motion of the
    robot, exit 0); the shipped biped passes."""
    from planner.gait import check_mirror_legs

    xml = (ROBOTS_DIR / "biped.xml").read_text()
    leg_2 = xml.index('<body name="leg_2"') if old.startswith("mass") else xml.index('<motor name="hip_2"')
    cut = xml.index(old, leg_2)
    path = tmp_path / "uneven.xml"
    path.write_text(xml[:cut] + new + xml[cut + len(old):])
    with pytest.raises(TaskError, match=rf"the legs are not mirror images: with 'foot_2' as the stance foot the "
                                        rf"{differs} differs by .* give both legs the same"):
        check_mirror_legs(PinnedBiped(load_robot(path)))
    check_mirror_legs(PinnedBiped(load_robot("biped")))


def test_a_biped_whose_motors_are_geared_is_refused(tmp_path):
    """Both motors of gear 2 (mirror images still) are a TaskError before the solve naming them and the fix: the gait
    weighs and reports the commands as hinge torques, and such a robot converged to another gait (cost 8.48 for 14.14)
    whose "N m" fields were half its torques."""
    from planner.gait import run_gait

    path = tmp_path / "geared.xml"
    path.write_text((ROBOTS_DIR / "biped.xml").read_text().replace('gear="1"', 'gear="2"'))
    with pytest.raises(TaskError, match=r"motor 'hip_1' \(gear 2\), 'hip_2' \(gear 2\): .* give the motors gear 1"):
        run_gait(path, ROBOTS_DIR / "biped_gait1.toml", tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_a_diverged_projection_still_writes_its_diagnostics(tmp_path):
    """A PRONTO projection that diverges (no state feedback, 8 s period) is a SolveError (exit 1) that still writes
    DIR/failed/summary.json, converged false with the message, the outer loops before it and the contract's keys
    (solve time, loops, iterations, no impacts), and says where (it wrote nothing)."""
    from planner.errors import SolveError
    from planner.gait import run_gait

    text = (ROBOTS_DIR / "biped_gait1.toml").read_text()
    assert text.count("\ntau_f = 1.53\n") == 1 and text.count("\nN = 153\n") == 1
    task = tmp_path / "diverge.toml"
    task.write_text(text.replace("\ntau_f = 1.53\n", "\ntau_f = 8.0\n").replace("\nN = 153\n", "\nN = 20\n")
                    + "[gait.pronto]\nfeedback_q = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]\nfeedback_r = [1e6, 1e6]\n")
    with pytest.raises(SolveError, match=r"not finite .* \(the outer loops before it: .*failed/summary.json\)"):
        run_gait("biped", task, tmp_path / "out", validate=False)
    summary = json.loads((tmp_path / "out" / "failed" / "summary.json").read_text())
    assert summary["converged"] is False and "not finite" in summary["message"] and summary["command"] == "gait"
    assert isinstance(summary["outer_loops"], list) and not (tmp_path / "out" / "summary.json").exists()
    # the contract's keys too, as a converged gait's summary has them (session 56's tester: KeyError in a reader)
    assert summary["n_nlp"] == len(summary["outer_loops"]) and summary["impacts"] == [] and summary["solve_time_s"] > 0
    assert summary["ipopt_iterations"] == sum(loop["pronto_iterations"] for loop in summary["outer_loops"])
    assert summary["physical_duration_s"] is None and summary["iterations_solver"] == "pronto"


def test_a_gait_towards_minus_x_is_not_walked(tmp_path):
    """The MuJoCo walk replays gaits towards +x (theta1 increasing indexes its reference, a landing in front of the
    stance foot counts a step): the mirror image of gait 1 (x0 negated) is refused before the solve when it is to be
    validated, naming the fix (it converged, and its walk then "fell" at step 0: exit 1 for a valid gait)."""
    from planner.gait import run_gait

    text = (ROBOTS_DIR / "biped_gait1.toml").read_text()
    x0 = ("x0 = [-0.39269908169872414, 0.39269908169872414, 0.3490658503988659, 0.8726646259971648, 0.0, "
          "1.5707963267948966]")
    assert text.count(x0) == 1
    mirrored = x0.replace("[-0.392", "[0.392").replace(", 0.392", ", -0.392").replace(", 0.349", ", -0.349") \
        .replace(", 0.872", ", -0.872").replace(", 1.57", ", -1.57")
    task = tmp_path / "mirror.toml"
    task.write_text(text.replace(x0, mirrored))
    with pytest.raises(TaskError, match=r"walks towards -x, .* mirror the task .*`planner gait --no-validate`"):
        run_gait("biped", task, None)
    still = tmp_path / "still.toml"  # a stance leg that does not turn walks nowhere, not towards -x
    still.write_text(text.replace(x0, x0.replace(", 0.8726646259971648,", ", 0.0,")))
    with pytest.raises(TaskError, match=r"turning at 0 rad/s: it does not walk forward, .*; give the stance leg a "
                       r"rate theta1' > 0 or do not validate"):  # (a mirror of a rate 0 is a rate 0, review)
        run_gait("biped", still, None)


def test_desired_curve_meets_the_boundary_states_and_is_differentiated(biped):
    """The desired curve starts at x0 and ends at Delta^-1(x0) in angles and rates (paper Sec. 2.2:
    x_d(0) = x0, x_d(T) = x_f), and its rates are the time derivative of its angles."""
    spec = _spec("biped_gait1.toml", N=153)
    xf = biped.delta_inverse(spec.x0)
    t, xd, ude = desired_curve(biped, spec.x0, xf, spec.T, spec.N)
    assert np.max(np.abs(xd[0] - spec.x0)) < 1e-12 and np.max(np.abs(xd[-1] - xf)) < 1e-12
    dt = t[1] - t[0]
    th = xd[:, :3]
    rates = (-th[4:] + 8 * th[3:-1] - 8 * th[1:-3] + th[:-4]) / (12 * dt)  # exact for polynomials of degree <= 4
    assert np.max(np.abs(rates - xd[2:-2, 3:])) < DIFF_TOL


def _spec(name, N=COARSE_N):
    return GaitSpec.from_task(load_task(ROBOTS_DIR / name), N)


@pytest.fixture(scope="module")
def gaits(biped):
    return {name: solve_gait(biped, _spec(name)) for name in ("biped_gait1.toml", "biped_gait2.toml")}


def test_gaits_meet_the_final_state_constraint(gaits, biped):
    """Both gaits of Sec. 4.2 (coarse grid) end on Delta^-1(x0), so that Delta(x(T)) = x0: periodic;
    theta1 reaches the jump set pi/8 only at T."""
    for sol in gaits.values():
        assert sol.converged and sol.final_error < FINAL_STATE_TOL
        x0 = biped.delta(sol.x[-1])
        assert np.max(np.abs(x0 - sol.x[0])) < 10 * FINAL_STATE_TOL
        assert np.all(sol.x[:-1, 0] < np.pi / 8)


def test_the_walks_inputs_follow_the_results_contract(gaits, biped):
    """The walk written to trajectory.npz holds u[i] as the input that drove sample i-1 to sample i (the results'
    contract; plots draw it steps-pre): sample k + 1 of a step holds the gait's u_k (it held u_{k+1}, 10 ms early)."""
    from planner.gait import periodic_walk

    sol = gaits["biped_gait1.toml"]
    walk = periodic_walk(biped, sol, 2)
    N, lay = len(sol.u), biped.layout
    np.testing.assert_array_equal(walk.u[1:N + 1, lay.stance_motor], sol.u[:, 0])
    np.testing.assert_array_equal(walk.u[1:N + 1, lay.swing_motor], sol.u[:, 1])
    np.testing.assert_array_equal(walk.u[N + 2:2 * N + 2, lay.swing_motor], sol.u[:, 0])  # legs swapped


def test_gait_findings_of_section_4_2(gaits):
    """Gait 1 tracks the desired curve closer than gait 2; gait 2's swing torque u2 is near zero at T
    and it uses less torque overall (integral of u^2 and peak)."""
    g1, g2 = gaits["biped_gait1.toml"], gaits["biped_gait2.toml"]
    track = lambda s: np.max(np.abs(s.x[:, :3] - s.xd[:, :3]))
    assert track(g1) < 0.5 * track(g2)
    assert abs(g2.u[-1, 1]) < 5.0  # N m: "approaches zero"; gait 1 ends at ~62 N m
    assert abs(g1.u[-1, 1]) > 40.0
    assert np.sum(g2.u**2) < 0.7 * np.sum(g1.u**2)
    assert np.max(np.abs(g2.u)) < np.max(np.abs(g1.u))


def test_gait1_terminal_torque_needs_ten_times_the_printed_state_weights(biped):
    """Why gait 1's u2 > 100 N m is not reproduced (docs/biped.md): with the printed Q and R the
    optimum of OCP (5) ends at u2(T) ~ 62 N m (paper sign); the terminal peak grows with Q/R and
    passes the paper's 100 N m only from 10 times the printed Q (paper's grid, IPOPT)."""
    spec = _spec("biped_gait1.toml", N=153)
    u2_end = lambda Q: -solve_gait_ipopt(biped, dataclasses.replace(spec, Q=Q)).u[-1, 1]
    assert 40.0 < u2_end(spec.Q) < PAPER_U2_CLAIM
    assert u2_end(10.0 * spec.Q) > PAPER_U2_CLAIM


def test_ipopt_finds_the_same_gait(gaits, biped):
    """IPOPT on the same discretized OCP with the hard final-state constraint reaches the same
    trajectory and cost as the PRONTO strategy (gait 2, coarse grid)."""
    sol = gaits["biped_gait2.toml"]
    ip = solve_gait_ipopt(biped, _spec("biped_gait2.toml"))
    assert ip.success
    assert abs(ip.cost - sol.cost) < 1e-6 * sol.cost
    assert np.max(np.abs(ip.x - sol.x)) < 1e-6


def test_a_gait_whose_newton_step_overshoots_still_reaches_ipopts(biped):
    """Gait 1's weights over T = 2 s instead of 1.53 (x0 the paper's): the first Newton step on the target raises the
    final-state error above newton_radius, and the rho_f continuation that follows must pull x(T) to Delta^-1(x0)
    again, not to the moved target (the stance leg turned two full turns toward it and the gait failed after 60 outer
    loops). The strategy reaches the optimum IPOPT finds on the same discretized OCP with the hard final state."""
    spec = dataclasses.replace(_spec("biped_gait1.toml"), T=2.0)
    sol, ip = solve_gait(biped, spec), solve_gait_ipopt(biped, spec)
    assert ip.success and sol.converged
    assert any(loop.action == "newton x_T" for loop in sol.loops) and abs(sol.cost - ip.cost) < 1e-6 * ip.cost


def test_a_walk_that_makes_mujoco_unstable_is_a_fall_not_a_crash(tmp_path, robot, biped):
    """Gait 1 from the paper's x0 with the torso leaning back (theta3 = -20 deg): the gait converges, and its LQR walk
    drives MuJoCo unstable ("Nan, Inf or huge value in QACC"), which resets MuJoCo's time to 0. The walk is then a
    fall after the landings before it, and the results are written (an IndexError from a negative time since the
    landing ended the command before; nothing was written)."""
    task = load_task(ROBOTS_DIR / "biped_gait1.toml")
    x0 = np.array(task.gait.x0)
    x0[2] = -x0[2]
    q0, v0 = biped.floating(x0[:3], x0[3:])
    task = dataclasses.replace(task, initial=dataclasses.replace(task.initial, q=tuple(q0), v=tuple(v0)),
                               gait=dataclasses.replace(task.gait, x0=tuple(x0)),
                               horizon=dataclasses.replace(task.horizon, N=COARSE_N))
    result = run_gait(robot, task, tmp_path)
    assert result.solution.converged and result.walking.fell and result.walking.steps_walked < result.walking.steps_asked
    assert (tmp_path / "summary.json").is_file() and json.loads((tmp_path / "summary.json").read_text())["walking"]["fell"]


def test_a_short_legged_biped_that_walks_is_not_a_fall(tmp_path):
    """The walk's fall is the hip below a share of the plan's own lowest hip height, not below a fixed 0.6 m: gait 1's
    x0 on a biped with 0.5 m legs (its hip at 0.46-0.5 m all along the plan) walks its step in MuJoCo, where the fixed
    height read "walked 0 of 10 steps then fell" at t = 0 (and recorded no tracking error after it)."""
    xml = (ROBOTS_DIR / "biped.xml").read_text()
    short = {'pos="0 0 -0.5" mass="5"': 'pos="0 0 -0.25" mass="5"', '0 0 0 0 0 -1"': '0 0 0 0 0 -0.5"',
             'pos="0 0 -1" size': 'pos="0 0 -0.5" size'}  # legs of r = 0.5 m, their masses at r / 2 as the paper's
    for old, new in short.items():
        assert xml.count(old) == 2
        xml = xml.replace(old, new)
    path = tmp_path / "short.xml"
    path.write_text(xml)
    model = PinnedBiped(load_robot(path))
    task = load_task(ROBOTS_DIR / "biped_gait1.toml")
    spec = GaitSpec.from_task(task, COARSE_N)
    ip = solve_gait_ipopt(model, spec)  # (the same gait as PRONTO's, in a third of its time)
    assert ip.success
    hip = np.array(model.q_of.map(COARSE_N + 1)(ip.x[:, :3].T))[model.layout.z]
    assert hip.max() < 0.6  # the whole plan below the fixed height
    walking = replay_gait(model, PinnedGait(t=np.linspace(0.0, spec.T, COARSE_N + 1), x=ip.x, u=ip.u), task, 1)
    assert walking.steps_walked == 1 and not walking.fell and walking.max_hinge_error < WALK_ANGLE_TOL, walking


def test_an_x0_whose_landing_is_off_the_ground_is_refused(biped):
    """x0 = (-0.3, pi/8, 20 deg, ...) jumps from theta1 = jump_angle = pi/8 (the old check), but at Delta^-1(x0) its
    swing foot is cos(pi/8) - cos(0.3) = -31.5 mm below the ground (legs of 1 m): the impact map applies on the ground
    only, and the gait "converged" with the robot lifted through the floor. Refused before the solve."""
    spec = _spec("biped_gait1.toml")
    x0 = np.array(spec.x0)
    x0[0] = -0.3
    with pytest.raises(TaskError, match=r"lands its swing foot 31.5 mm below the ground"):
        solve_gait(biped, dataclasses.replace(spec, x0=x0))
    assert abs(float(biped.swing_height(biped.delta_inverse(spec.x0)[:3]))) < 1e-9  # the paper's x0 lands on it


def test_run_gait_writes_the_contract(tmp_path, robot):
    """run_gait writes trajectory.npz and summary.json with the contract's names, one progress record
    per outer loop, and impacts as repeated time samples (coarse grid, no MuJoCo); the result is read-only."""
    task = load_task(ROBOTS_DIR / "biped_gait2.toml")
    task = dataclasses.replace(task, horizon=dataclasses.replace(task.horizon, N=COARSE_N))
    records = []
    res = run_gait(robot, task, tmp_path, progress=records.append, validate=False)
    summary = json.loads((tmp_path / "summary.json").read_text())
    for key in ("command", "robot", "task", "converged", "solve_time_s", "n_nlp", "ipopt_iterations",
                "complementarity_residual", "terminal_error", "physical_duration_s", "impacts"):
        assert key in summary
    assert summary["command"] == "gait" and summary["converged"] and summary["n_nlp"] == len(records)
    assert summary["contact_violations"] == [] and summary["trailing_foot_lift_off_m_s"] > 0
    data = np.load(tmp_path / "trajectory.npz")
    for key in ("tau", "y", "t", "q", "v", "u", "impact_times"):
        assert key in data
    assert len(data["impact_times"]) == task.gait.steps == len(summary["impacts"])
    for t_imp in data["impact_times"]:
        assert np.sum(data["t"] == t_imp) == 2  # exactly: 10.709999999999999 and 10.71 were one impact's samples
    assert res.walk.q.shape[1] == robot.nq
    # the stance force is judged at both ends of every interval, the input held: the state before the impact too
    # (left out, gait 2's smallest normal force read 251 N for 236 N)
    sol, model = res.solution, PinnedBiped(robot, layout=find_layout(robot, task.gait.stance, task.gait.swing))
    lam_t, lam_n = np.array(model.stance_force(sol.x[-1], sol.u[-1])).ravel()
    assert summary["min_normal_force_N"] <= lam_n and summary["friction_needed"] >= abs(lam_t / lam_n)
    # frozen through its arrays and dicts, as a plan's result is (`res.walk.q[:] = 0` and summary edits went through)
    for write in (lambda: res.solution.x.__setitem__((0, 0), 99.0), lambda: res.walk.q.__setitem__(0, 0.0),
                  lambda: res.summary.__setitem__("converged", False)):
        with pytest.raises((ValueError, TypeError), match="read-only"):
            write()


def test_a_failed_gait_keeps_the_good_one(tmp_path, robot):
    """A gait that does not converge (one outer loop of one PRONTO iteration) writes its files under DIR/failed and
    leaves a good gait in DIR byte for byte (it overwrote it, summary and trajectory), its report says why; `planner
    gait` exits 1 naming DIR/failed."""
    from planner.cli import main
    from planner.task import GaitContinuation, GaitPronto

    task = load_task(ROBOTS_DIR / "biped_gait1.toml")
    short = dataclasses.replace(task, gait=dataclasses.replace(task.gait, continuation=GaitContinuation(max_outer=1),
                                                               pronto=GaitPronto(max_iterations=1)))
    earlier = {"summary.json": b'{"converged": true}', "trajectory.npz": b"a good gait"}
    for name, data in earlier.items():
        (tmp_path / name).write_bytes(data)
    res = run_gait(robot, short, tmp_path, validate=False)
    assert not res.summary["converged"] and json.loads((tmp_path / "failed" / "summary.json").read_text())["converged"] is False
    # its one loop was the embedding's: the saved trajectory is the embedded system's, and the message says so
    assert [(loop.stage, loop.action) for loop in res.solution.loops] == [("embedding", STOPPED)]  # (not "drop u_emb")
    assert res.summary["message"].startswith("outer-loop limit (gait.continuation.max_outer) reached in the embedding "
                                             "stage: the trajectory is the embedded system's")
    assert res.report().splitlines()[1] == f"  {res.summary['message']}"  # (only -q's failure line said why)
    for name, data in earlier.items():
        assert (tmp_path / name).read_bytes() == data
    toml = tmp_path / "short.toml"
    toml.write_text((ROBOTS_DIR / "biped_gait1.toml").read_text() + "\n[gait.continuation]\nmax_outer = 1\n"
                    "[gait.pronto]\nmax_iterations = 1\n")
    assert main(["gait", "biped", "--task", str(toml), "--out", str(tmp_path), "--no-validate", "-q"]) == 1
    assert (tmp_path / "trajectory.npz").read_bytes() == earlier["trajectory.npz"]


def test_inconsistent_initial_state_is_a_task_error(tmp_path, robot):
    """A gait task whose [initial] is not the floating image of gait.x0 is rejected with the values to use."""
    task = load_task(ROBOTS_DIR / "biped_gait1.toml")
    bad = dataclasses.replace(task, initial=dataclasses.replace(task.initial, q=(0.0,) * 5))
    with pytest.raises(TaskError, match="initial.q"):
        run_gait(robot, bad, None, validate=False)


def test_phase_reference_interpolates_the_plan(gaits):
    """The replay's phase reference passes through the plan's (theta2, theta3) at the plan's theta1
    samples with slopes theta_j' / theta1', and continues linearly beyond the step's ends."""
    x = gaits["biped_gait1.toml"].x
    ref = PhaseReference(x)
    for k in (0, 7, len(x) - 1):
        yd, d1, _ = ref(x[k, 0])
        assert np.max(np.abs(yd - x[k, 1:3])) < SPLINE_TOL
        assert np.max(np.abs(d1 - x[k, 4:6] / x[k, 3])) < SPLINE_TOL
    yd, d1, d2 = ref(x[-1, 0] + 0.01)
    assert np.max(np.abs(yd - (x[-1, 1:3] + 0.01 * x[-1, 4:6] / x[-1, 3]))) < SPLINE_TOL and not d2.any()
    with pytest.raises(InputError, match="monotonically"):
        PhaseReference(x[::-1])


def test_walk_gains_are_validated():
    """An unknown replay control is an InputError naming the valid modes, and a control's value stands for it
    ("phase" was refused as unknown while the message listed it); a bandwidth <= 0 or a negative gain is an InputError
    naming the field and its value (the message listed every rule); a gain the chosen control does not read is an
    InputError naming the control that reads it."""
    from planner.gait import WalkControl

    with pytest.raises(InputError, match=r"WalkGains.control = 'dance' is not allowed; it must be one of .*'phase'"):
        WalkGains(control="dance")
    assert WalkGains(control="hinge_pd").control is WalkControl.HINGE_PD
    with pytest.raises(InputError, match=r"^WalkGains.bandwidth = 0.0 is not allowed; it must be > 0$"):
        WalkGains(bandwidth=0.0)
    for key in ("kp", "kd", "ground_gap", "stance_margin", "speed_gain", "speed_integral"):
        with pytest.raises(InputError, match=rf"^WalkGains.{key} = -0.1 is not allowed; it must be >= 0$"):
            WalkGains(**{key: -0.1})
    # a gain the chosen control law does not read is refused (it was recorded in the walk's report and ignored)
    for control, key in (("lqr", "kp"), ("phase", "kd"), ("hinge_pd", "bandwidth"), ("lqr", "speed_gain"),
                         ("hinge_pd", "speed_integral")):
        with pytest.raises(InputError, match=rf"^WalkGains.{key} = 1.5 is not allowed with control '{control}'"):
            WalkGains(control=control, **{key: 1.5})
    assert WalkGains(control="hinge_pd", kp=1.5, kd=1.5).kp == 1.5 and WalkGains(speed_gain=1.5).speed_gain == 1.5


@pytest.mark.slow
def test_paper_grid_gaits_walk_in_mujoco(biped):
    """On the paper's grid (dt = 10 ms) both gaits converge, and the pinned model's gait walks the
    floating robot in MuJoCo for WALK_STEPS steps without falling (phase-indexed computed torque):
    each landing in front, the first within 20 ms of T, actuated angles within WALK_ANGLE_TOL of the
    plan at the same stance-leg angle, peak torque within WALK_TORQUE_MARGIN of the plan's."""
    for name in ("biped_gait1.toml", "biped_gait2.toml"):
        task = load_task(ROBOTS_DIR / name)
        sol = solve_gait(biped, GaitSpec.from_task(task))
        assert sol.converged and sol.final_error < FINAL_STATE_TOL
        report = replay_gait(biped, sol, task, WALK_STEPS)
        assert report.steps_walked == WALK_STEPS and not report.fell
        assert len(report.impact_times) == len(report.step_lengths) == WALK_STEPS  # not the spare 20 %'s too
        assert abs(report.impact_times[0] - sol.t[-1]) < 0.02
        assert report.max_hinge_error < WALK_ANGLE_TOL and report.max_torso_error < WALK_ANGLE_TOL
        assert report.max_torque < WALK_TORQUE_MARGIN * np.max(np.abs(sol.u))


def test_a_gait_task_with_what_the_gait_model_ignores_is_refused():
    """The gait model walks on z = 0 with the period horizon.tau_f and lands inelastically: a ground_height, a tilted
    contact normal, a restitution (a converged gait exited on friction only, the elastic contact unsaid), a foot that
    never touches (it walked on it), a horizon.physical_time, the time-freezing gains a_n, a_t or a [simulate] table
    are refused before the solve, named (they were ignored: a ground at 0.3 m planned the same gait, and MuJoCo's
    replay on the moved ground fell after one step), with no warning before; a [plan] beside the [gait] is refused
    when the task is read."""
    import warnings

    from planner.gait import run_gait

    task = load_task(ROBOTS_DIR / "biped_gait1.toml")
    tilted = dataclasses.replace(task.contacts[0], normal=(0.1, 0.0, 0.995))
    elastic = dataclasses.replace(task.contacts[1], restitution=0.8)
    for changed, said in ((dataclasses.replace(task, ground_height=0.3), "ground_height = 0.3"),
                          (dataclasses.replace(task, contacts=(tilted, *task.contacts[1:])), "contacts[0].normal"),
                          (dataclasses.replace(task, contacts=(task.contacts[0], elastic)),
                           "contacts[1].restitution = 0.8"),
                          (dataclasses.replace(task, horizon=dataclasses.replace(task.horizon, physical_time=1.0)),
                           "horizon.physical_time = 1"),
                          (dataclasses.replace(task, contacts=(task.contacts[0], dataclasses.replace(
                              task.contacts[1], touches=False))), "contacts[1].touches = false"),
                          # (the time-freezing gains and simulate's table were dropped unsaid too)
                          (dataclasses.replace(task, contacts=(dataclasses.replace(task.contacts[0], a_t=50.0),
                                                               task.contacts[1])), "contacts[0].a_t = 50"),
                          (dataclasses.replace(task, simulate=Simulate(rho_f=2.0)), "[simulate]")):
        with pytest.raises(TaskError, match=rf"{re.escape(said)}.* would be ignored by `planner gait`"):
            GaitSpec.from_task(changed)
    # a [plan] beside [gait] (its u_bound = 30 walked at 72 N m; without a target: "missing key 'plan.target_q'")
    data = tomllib.loads((ROBOTS_DIR / "biped_gait1.toml").read_text())
    for plan in ({"u_bound": 30.0}, {"periodic": {"step": 0.25}}):
        with pytest.raises(TaskError, match=r"^a task has a \[plan\] \(for `planner plan`\) or a \[gait\]"):
            parse_task({**data, "plan": plan})
    # run_gait refuses it before the robot check, which warned first of the moved ground as if it were used
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(TaskError, match="ground_height = 0.3"):
            run_gait("biped", dataclasses.replace(task, ground_height=0.3), None)


def test_gait_spec_checks_its_grid_and_is_frozen_through_its_arrays():
    """GaitSpec.from_task's N overrides the horizon's only when given, and must be an integer in [2, MAX_STEPS] (N = 0
    silently meant the task's 153, 2.5 was accepted, N = 1 ended in a ValueError after the solve); the spec's arrays are read-only and the spec hashes and compares
    by identity (its arrays made hash() raise TypeError and == raise ValueError)."""
    task = load_task(ROBOTS_DIR / "biped_gait1.toml")
    assert GaitSpec.from_task(task).N == task.horizon.N and GaitSpec.from_task(task, 20).N == 20
    for N in (0, 1, -5, 2.5, "20", True):
        with pytest.raises(InputError, match=r"GaitSpec.N = .* an integer in \[2, 10000000\]"):
            GaitSpec.from_task(task, N)
    one = dataclasses.replace(task, horizon=dataclasses.replace(task.horizon, N=1))  # said of the file, not GaitSpec
    with pytest.raises(TaskError, match=r"biped_gait1.toml \(edited\): horizon.N = 1 is not allowed; a gait's horizon.N must be"):
        GaitSpec.from_task(one)
    spec = GaitSpec.from_task(task)
    with pytest.raises(ValueError, match="read-only"):
        spec.x0[0] = 9.0
    assert spec == spec and spec != GaitSpec.from_task(task) and len({spec, spec}) == 1


def test_a_gaits_fall_is_the_quiet_failure_lines_reason():
    """-q's failure line of a gait whose MuJoCo walk fell, its contacts and motors fine, says so (it printed "planner
    gait: failed" with no reason)."""
    from planner.cli import _failure

    walking = {"fell": True, "steps_walked": 1, "steps_asked": 10, "control": "phase"}
    summary = {"command": "gait", "converged": True, "contact_violations": [], "motor_violations": [],
               "walking": walking}
    assert _failure(summary) == ": the MuJoCo walk fell after 1 of 10 steps (phase control)"
    assert _failure({**summary, "walking": {**walking, "fell": False}}) == ""


def test_gait_command_exits_1_when_the_walk_falls_and_checks_its_task_first(tmp_path, capsys, monkeypatch):
    """`planner gait` exits 1 when its MuJoCo walk falls (mu = 0: it converged, printed "converged" and exited 0) or
    when the gait violates its contacts (-q's line names them and where the result went; without the walk it exited 0
    in silence); a
    coarse grid (N = 15: no sample in the last 100 ms) writes its result with the task it solved (task_json, which
    `view` reads from any directory) instead of a ValueError traceback; a task without both feet as contacts is
    refused before the solve (after it, or not at all with --no-validate); an earlier plan's plots in --out are removed
    (a gait draws none), PNGs in a directory that held no result are left alone."""
    import planner.gait
    from planner.cli import main

    gait1 = (ROBOTS_DIR / "biped_gait1.toml").read_text()
    assert gait1.count("\nmu = ") == 2 and "\nN = 153\n" in gait1
    slippery, coarse = tmp_path / "mu0.toml", tmp_path / "n15.toml"
    slippery.write_text(gait1.replace("\nmu = 1.0", "\nmu = 0.0"))
    coarse.write_text(gait1.replace("\nN = 153\n", "\nN = 15\n"))
    assert "\nmu = 0.0" in slippery.read_text()
    assert main(["gait", "biped", "--task", str(slippery), "--out", str(tmp_path / "fell"), "-q"]) == 1
    (tmp_path / "coarse").mkdir()
    (tmp_path / "coarse" / "states.png").write_bytes(b"an earlier plan's plot")
    (tmp_path / "coarse" / "summary.json").write_text('{"converged": true}')
    assert main(["gait", "biped", "--task", str(coarse), "--out", str(tmp_path / "coarse"), "--no-validate", "-q"]) == 0
    assert not (tmp_path / "coarse" / "states.png").exists()  # it read as the gait's
    (tmp_path / "mine").mkdir()  # a directory that held no result: its PNGs are the user's (they were deleted)
    (tmp_path / "mine" / "states.png").write_bytes(b"my own figure")
    assert main(["gait", "biped", "--task", str(coarse), "--out", str(tmp_path / "mine"), "--no-validate", "-q"]) == 0
    assert (tmp_path / "mine" / "states.png").read_bytes() == b"my own figure"
    with np.load(tmp_path / "coarse" / "trajectory.npz") as npz:
        assert load_task(coarse).gait == parse_task(json.loads(str(npz["task_json"]))).gait
    capsys.readouterr()
    monkeypatch.setattr(planner.gait, "contact_violations", lambda summary: ["the ground would have to pull"])
    assert main(["gait", "biped", "--task", str(coarse), "--out", str(tmp_path / "pull"), "--no-validate", "-q"]) == 1
    assert capsys.readouterr().err.strip() == ("planner gait: failed: the ground would have to pull (results in "
                                              f"{tmp_path / 'pull'})")  # (where the failed gait went: unsaid)
    monkeypatch.undo()
    one_foot = tmp_path / "one_foot.toml"
    text = gait1.split("[[contacts]]")
    one_foot.write_text("[[contacts]]".join(text[:2]) + "\n[" + text[2].split("\n[", 1)[1])
    assert main(["gait", "biped", "--task", str(one_foot), "--out", str(tmp_path / "one"), "--no-validate"]) == 2
    assert "a gait needs both feet as [[contacts]]" in capsys.readouterr().err


@pytest.mark.parametrize("field, value", [
    ("desired_input", "Zero"),  # a value of no DesiredInput (anything but the member silently meant ZERO)
    ("x0", np.zeros(3)), ("Q", np.ones(2)), ("R", np.array([0.01, 0.0])), ("T", -1.0), ("continuation", None),
    ("jump_angle", float("nan")),
], ids=["desired_input", "x0", "Q", "R", "T", "continuation", "jump_angle"])
def test_gait_spec_refuses_what_the_ocp_cannot_use(field, value):
    """GaitSpec checks each field as GaitSpec.N is checked: an InputError naming the field for a desired input given
    as its string (anything but the enum member fell through to the zero input: gait 1 was solved with gait 2's
    u_d = 0), an initial state or weights of the wrong length, a zero input weight, a period <= 0, a continuation
    that is not a GaitContinuation and a nan jump angle; all were accepted and failed later inside the solve, or not
    at all. The spec of a shipped task passes."""
    spec = GaitSpec.from_task(load_task(ROBOTS_DIR / "biped_gait1.toml"), N=20)
    assert dataclasses.replace(spec).desired_input is spec.desired_input
    with pytest.raises(InputError, match=rf"^GaitSpec\.{field} "):
        dataclasses.replace(spec, **{field: value})


def test_a_foot_that_is_not_on_a_motor_driven_leg_is_named(robot):
    """find_layout with a point that does not hang from an actuated leg hinge (gait.stance = "torso_top") names that
    point and why ("leg hinge 'x' has no motor" named neither the point nor the [gait] key's role)."""
    assert find_layout(robot, "foot_1", "foot_2").stance_foot == "foot_1"
    with pytest.raises(InputError, match=r"the stance foot 'torso_top' is not on a motor-driven leg hinge"):
        find_layout(robot, "torso_top", "foot_2")
    with pytest.raises(InputError, match=r"the swing foot 'torso_top' is not on a motor-driven leg hinge"):
        find_layout(robot, "foot_1", "torso_top")
    # an unknown point is said of its [gait] key, as the task's other names are
    with pytest.raises(InputError, match=r"^gait.swing: unknown point 'foot_3'; valid points: "):
        find_layout(robot, "foot_1", "foot_3")


def test_a_gait_whose_hip_starts_below_the_ground_is_refused(biped):
    """x0 with |theta1| >= pi/2 (the jump angle 1.6 rad: the stance leg points up from its foot, the hip below the
    ground) is refused before the solve, naming the hip's depth (it "converged" in 27 s to a ground that pulls with
    4168 N, session 58's tester)."""
    from planner.gait import solve_gait

    spec = GaitSpec.from_task(load_task(ROBOTS_DIR / "biped_gait1.toml"), N=20)
    x0 = np.array([-1.6, 1.6, 0.3, 0.8, 0.0, 1.5])
    with pytest.raises(TaskError, match=r"gait.x0 puts the hip at or below the ground \(z = -[0-9.]+ mm, theta1 = "
                                        r"-1.6 rad\)"):
        solve_gait(biped, dataclasses.replace(spec, x0=x0, jump_angle=1.6))


def test_the_hip_is_checked_before_the_initial_state(tmp_path):
    """planner gait with x0 putting the hip below the ground and the task's initial state left as it was says so first
    (the initial-state check came first, and its hint was the floating state with the hip below the ground)."""
    from planner.gait import run_gait

    text = (ROBOTS_DIR / "biped_gait1.toml").read_text()
    x0 = "x0 = [-0.39269908169872414, 0.39269908169872414,"
    assert text.count(x0) == 1 and text.count("jump_angle = 0.39269908169872414") == 1
    task = tmp_path / "below.toml"
    task.write_text(text.replace(x0, "x0 = [-1.7, 1.7,").replace("jump_angle = 0.39269908169872414",
                                                                     "jump_angle = 1.7"))
    with pytest.raises(TaskError, match=r"gait.x0 puts the hip at or below the ground"):
        run_gait("biped", task, None)


@pytest.mark.parametrize("order", [("z", "x", "torso"), ("torso", "x", "z")])
def test_a_biped_whose_root_joints_are_in_another_order_is_refused(tmp_path, order):
    """The gait reads the root's three degrees of freedom as slide x, slide z, hinge about y in that order: a file
    whose root joints come in another order is refused naming them (its hint put the hip's x into the z slide, and the
    task that followed it was refused with a swing foot 541 mm below the ground, session 58's tester)."""
    text = (ROBOTS_DIR / "biped.xml").read_text()
    joints = {name: re.search(rf'<joint name="{name}"[^>]*/>', text).group(0) for name in ("x", "z", "torso")}
    for k, name in enumerate(joints):
        text = text.replace(joints[name], f"@{k}@")
    for k, name in enumerate(order):
        text = text.replace(f"@{k}@", joints[name])
    path = tmp_path / "biped_reordered.xml"
    path.write_text(text)
    with pytest.raises(InputError, match=rf"root joints in the order slide x .* this file's are {', '.join(order)}: "):
        find_layout(load_robot(path))


def test_the_desired_input_drives_the_papers_dynamics_along_the_desired_curve(biped):
    """Gait 1's u_d (desired_input = "inverse_dynamics") is the input that moves the biped along the desired curve:
    with the spline's acceleration (a five-point difference of its rates, exact for the cubic's quadratic rates),
    Appendix B's M(theta) theta'' + C + G equals (B.4)'s B u plus the torso torque u_emb on theta3 at every inner
    sample; else gait 1 is another gait than the paper's OCP (session 66's mutation testing: the inverse dynamics
    with -h_r, gait 1 converged to cost 119 instead of 14.0, with every test green)."""
    spec = _spec("biped_gait1.toml", N=153)
    t, xd, ude = desired_curve(biped, spec.x0, biped.delta_inverse(spec.x0), spec.T, spec.N)
    rates = xd[:, 3:]
    acc = (-rates[4:] + 8 * rates[3:-1] - 8 * rates[1:-3] + rates[:-4]) / (12 * (t[1] - t[0]))
    for x, u, a in zip(xd[2:-2], ude[2:-2], acc):
        M, h = appendix_b(x[:3], x[3:])
        U = np.array([u[0], u[1], -u[0] - u[1] + u[2]])  # (B.4) with u_paper = -u; u_emb acts on theta3
        assert np.max(np.abs(M @ a + h - U)) < CLOSED_FORM_TOL


def test_the_embedded_stage_cost_is_paper_eq_8(biped):
    """The embedded OCP's cost is paper eq. (8): 1/2 dt (||x - xd||_Q^2 + ||u - ud||_R^2 + rho_emb^2 u_emb^2) per
    step and 1/2 rho_f^2 ||x_N - x_T||^2, written out with numpy at a random point; the continuation on rho_emb is
    tuned to the square (session 66's mutation testing: rho_emb not squared, the embedding took 14 outer loops
    instead of 8, with every test green)."""
    spec = _spec("biped_gait1.toml", N=20)
    ocp = GaitOCP(biped, spec)
    rng = np.random.default_rng(5)
    x, xd, x_target = rng.normal(size=(3, 6))
    ue, ud, rho_emb, rho_f = rng.normal(size=3), rng.normal(size=2), 3.0, 7.0
    theta = np.concatenate([[rho_emb, rho_f], x_target])
    stage = 0.5 * ocp.dt * (spec.Q @ (x - xd) ** 2 + spec.R @ (ue[:2] - ud) ** 2 + rho_emb**2 * ue[2] ** 2)
    assert abs(float(ocp.embedded.stage(x, ue, np.concatenate([xd, ud]), theta)) - stage) < CLOSED_FORM_TOL
    assert abs(float(ocp.embedded.terminal(x, theta)) - 0.5 * rho_f**2 * np.sum((x - x_target) ** 2)) < CLOSED_FORM_TOL


def test_the_gait_pronto_settings_reach_both_pronto_solvers(biped):
    """gait.pronto's iteration limit and tolerance are those of both PRONTO solvers, the embedded one (step 2) and the
    underactuated one (step 3); a user's looser tolerance must not be silently ignored in step 3 (session 66's
    mutation testing: step 3's solver kept the default tolerance 1e-12, with every test green)."""
    spec = dataclasses.replace(_spec("biped_gait1.toml", N=20), pronto=GaitPronto(max_iterations=7, tolerance=1e-6))
    ocp = GaitOCP(biped, spec)
    for solver in (ocp.pronto_e, ocp.pronto_u):
        assert (solver.options.max_iterations, solver.options.tolerance) == (7, 1e-6)


def test_a_loop_of_no_counted_iteration_says_its_final_step_moved_it():
    """A converged PRONTO solve may end with one full Newton step that is not counted (pronto.py), so the last Newton
    loop of gait 1 moves x(T) from 8.0e-8 to 7.9e-15 in "0 PRONTO it.": its progress line says so. PRONTO takes that
    step only when its slope is negative and keeps it only when the cost does not rise, so a converged loop whose
    step was not taken (ProntoResult.polished false) claims none (review r3: every converged 0-iteration loop did);
    the lines of counted iterations and of a solve that did not converge stay as they were."""
    from planner.gait import OuterLoop

    loop = OuterLoop(index=13, stage="final_state", rho_emb=None, rho_f=10.0, cost=6191.74, pronto_iterations=0,
                     pronto_converged=True, pronto_polished=True, emb_max=None, final_error=7.9e-15, action="done",
                     time_s=5.7)
    assert loop.line() == ("[13] final_state rho_f 10: cost 6191.74, ||x(T) - x_f|| 7.90e-15, 0 PRONTO it. + its "
                           "final full step, not counted -> done")
    assert dataclasses.replace(loop, pronto_polished=False).line().endswith(", 0 PRONTO it. -> done")
    assert dataclasses.replace(loop, pronto_iterations=2).line().endswith(", 2 PRONTO it. -> done")
    assert dataclasses.replace(loop, pronto_converged=False, pronto_polished=False).line().endswith(
        ", 0 PRONTO it. -> done")


def test_the_newton_loop_on_the_target_converges_quadratically(gaits):
    """Once ||x(T) - x_f|| is within newton_radius, each Newton update of the target x_T squares the final-state
    error (gait 1 on this coarse grid: 1.0e-4, 3.8e-8, 5.2e-15; docs/biped.md gives the paper grid's 1.5e-4, 8.0e-8,
    7.9e-15), down to round-off: a loop that stalls costs an outer loop and a PRONTO solve each (session 66's
    mutation testing: without PRONTO's final Newton step the loop stalled between 3e-8 and 9e-8 for 26 of 40 outer
    loops, with every test green)."""
    for sol in gaits.values():
        pairs = [(a.final_error, b.final_error) for a, b in zip(sol.loops, sol.loops[1:]) if a.action == "newton x_T"]
        assert len(pairs) >= 3
        assert all(b <= NEWTON_RATE * a**2 or b < ROUND_OFF_ERROR for a, b in pairs)


def test_the_embedding_ends_with_a_small_torso_torque_over_the_whole_step(gaits):
    """The embedding stage drops u_emb only when max |u_emb| over the whole step is below
    gait.continuation.emb_tolerance, and its progress record (emb_max) reports that maximum (session 66's mutation
    testing: only the last sample was measured, the record said 4.7e-4 N m while u_emb reached 3.2e-2 N m, with every
    test green)."""
    for name, sol in gaits.items():
        last = [loop for loop in sol.loops if loop.stage == "embedding"][-1]
        assert last.action == "drop u_emb"
        assert last.emb_max == np.max(np.abs(sol.u_emb[:, 2])) < _spec(name).continuation.emb_tolerance


def test_the_stance_force_satisfies_the_floating_robots_equation_of_motion(gaits, biped):
    """The stance foot's ground force (summary.json's min_normal_force_N, friction_needed, and the contact
    violations read from them) closes the floating robot's equation of motion J' lambda = M v' + h - B u at both ends
    of every interval of both gaits, v' the time derivative of the floating velocity along the pinned motion
    (session 66's mutation testing: the stance force with +B u, gait 1's minimum normal force 229 N for 241 N, with
    every test green)."""
    th, thd, thdd = ca.SX.sym("theta", 3), ca.SX.sym("dtheta", 3), ca.SX.sym("ddtheta", 3)
    v_dot = ca.Function("v_dot", [th, thd, thdd],
                        [ca.jtimes(biped.v_of(th, thd), ca.vertcat(th, thd), ca.vertcat(thd, thdd))])
    dyn, lay = biped.dyn, biped.layout
    B = dyn.actuation[:, [lay.stance_motor, lay.swing_motor]]
    for sol in gaits.values():
        for x, u in zip(sol.x, np.vstack([sol.u, sol.u[-1:]])):  # the last state with the input held into it
            q, v = biped.floating(x[:3], x[3:])
            acc = np.array(biped.xdot(x, np.concatenate([u, [0.0]]))).ravel()[3:]
            M, h = np.array(dyn.mass(q)), np.array(dyn.bias(q, v)).ravel()
            J = np.array(dyn.point_jacobian(lay.stance_foot)(q))[[0, 2]]
            lam = np.array(biped.stance_force(x, u)).ravel()
            residual = J.T @ lam - (M @ np.array(v_dot(x[:3], x[3:], acc)).ravel() + h - B @ u)
            assert np.max(np.abs(residual)) < EOM_TOL_N


def test_the_phase_control_imposes_the_output_acceleration(biped):
    """WalkControl.PHASE's computed torque gives y'' = w for y = (theta2, theta3) - y_d(theta1), whatever the state
    and the reference's slope dy and curvature d2y: with Appendix B's dynamics (B.1)-(B.4) at random values,
    theta''[1:] - dy theta1'' - d2y theta1'^2 = w; else the MuJoCo replay tracks its plan worse (session 66's
    mutation testing: the curvature term's sign flipped, the hinge error 3.7 deg for 0.4 deg, with every test
    green)."""
    control = _output_control(biped)
    rng = np.random.default_rng(4)
    for _ in range(20):
        th, thd = rng.uniform(-0.8, 0.8, 3), rng.uniform(-2, 2, 3)
        dy, d2y, w = rng.normal(size=(3, 2))
        u = np.array(control(th, thd, dy, d2y, w)).ravel()
        M, h = appendix_b(th, thd)
        acc = np.linalg.solve(M, np.array([u[0], u[1], -u[0] - u[1]]) - h)  # (B.4) with u_paper = -u
        assert np.max(np.abs(acc[1:] - dy * acc[0] - d2y * thd[0] ** 2 - w)) < COMPUTED_TORQUE_TOL


def test_the_walks_impacts_name_the_foot_that_lands_in_front(gaits, biped):
    """Each impact of the walk (summary.json's impacts, Walk.impacts) names the foot that lands: at the step's
    pre-impact sample, the one ahead of the other (session 66's mutation testing: every impact named the foot that
    lifts off, with every test green)."""
    sol = gaits["biped_gait1.toml"]
    N, feet = len(sol.u), (biped.layout.stance_foot, biped.layout.swing_foot)
    walk = periodic_walk(biped, sol, 3)
    for j, (time, foot, _, _) in enumerate(walk.impacts):
        before = (j + 1) * (N + 1) - 1  # the step's last, pre-impact sample
        assert walk.t[before] == time
        x = {name: float(np.array(biped.dyn.point_position(name)(walk.q[before])).ravel()[0]) for name in feet}
        assert x[foot] == max(x.values()) > min(x.values())


def test_the_walks_impacts_give_the_normal_then_the_tangential_impulse(gaits, biped):
    """Walk.impacts (summary.json, trajectory.npz) hold (time, foot, normal, tangential impulse) as documented: the
    impulse of the impact checked against MuJoCo (_impact_contact: tangential, normal), the normal one pushing
    (session 66's mutation testing: the two swapped, a normal impulse of -15.4 N s, with every test green)."""
    sol = gaits["biped_gait1.toml"]
    tangential, normal = _impact_contact(biped, sol.x[-1])["impact_impulse_N_s"]
    walk = periodic_walk(biped, sol, 2)
    assert [impact[2:] for impact in walk.impacts] == [(normal, tangential)] * 2 and normal > 0


def test_the_walks_last_sample_is_the_next_steps_first(gaits, biped):
    """A walk's last sample, the post-impact state of its last landing, is the state a longer walk starts its next
    step from (legs relabelled as that step's): trajectory.npz's final velocity is the robot's (session 66's mutation
    testing: the last sample's legs swapped the wrong way, its hinge rates exchanged by 0.87 rad/s, with every test
    green)."""
    sol = gaits["biped_gait1.toml"]
    N = len(sol.u)
    for steps in (1, 2):
        walk, longer = periodic_walk(biped, sol, steps), periodic_walk(biped, sol, steps + 1)
        first = steps * (N + 1)  # the first sample of the longer walk's next step
        assert walk.t[-1] == longer.t[first]
        assert np.max(np.abs(walk.q[-1] - longer.q[first])) < SAME_STATE_TOL
        assert np.max(np.abs(walk.v[-1] - longer.v[first])) < SAME_STATE_TOL


def test_a_plans_step_runs_from_a_post_impact_state_to_a_pre_impact_one(robot):
    """plan_step keeps, of a plan's samples at one physical time (an impact's pre- and post-impact ones), the last at
    the step's start and in it but the first at its end: the walk reads the step's last state as the next landing's
    pre-impact one (its impact map, the speed loop's stance-leg rate). Ending on the post-impact sample, the default
    biped plan's step lost its pre-impact node once the recovery wrote a landing's two samples at one time."""
    t = np.array([0.0, 0.0, 0.1, 0.2, 0.2])  # a landing at either end, pre and post; no impact_times: not rotated
    q = np.tile([0.0, 1.0, 0.0, 0.1, -0.1], (len(t), 1))
    v = np.outer(np.arange(len(t)), [0.0, 0.0, 1.0, 0.0, 0.0])  # sample i: the torso turning at i rad/s
    u = np.outer(np.arange(len(t)), [1.0, 1.0])
    _, step = plan_step(robot, load_task(ROBOTS_DIR / "biped.toml"), {"t": t, "q": q, "v": v, "u": u})
    np.testing.assert_array_equal(step.t, [0.0, 0.1, 0.2])
    np.testing.assert_array_equal(step.x[:, 5], [1.0, 2.0, 3.0])  # the post-impact start, the pre-impact end
    np.testing.assert_array_equal(step.u, [[2.0, 2.0], [3.0, 3.0]])  # u[i] drove sample i-1 to i
