"""Thm. 10 recovery on a hand-made trajectory, and the result files of the contract."""
from __future__ import annotations

import copy
import json
import os
import pickle
import shutil
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from planner.errors import InputError
from planner.homotopy import SolveOptions
from planner.model import load_robot, resolve_robot_path
from planner.result import (ENERGY_GAIN_SHARE, ON_PLANE_M, TAP_SHARE, Impact, SimulationResult, SolveStats,
                            Trajectory, check_same_result, hops_of, outside_cone, read_robot, read_start, read_summary,
                            read_task, read_trajectory, recover, tap_flags, write_atomically, write_files,
                            write_results)
from planner.simulate import simulate
from planner.task import Ellipse, default_task_path, load_task, parse_task, task_to_json

EXACT = 1e-12  # hand-made data: sums of a few floats

# Contract keys (shared/design.md, "The contract").
NPZ_KEYS = {"tau", "y", "t", "q", "v", "u", "impact_times"}
SUMMARY_KEYS = {"command", "robot", "task", "converged", "solve_time_s", "n_nlp", "ipopt_iterations",
                "complementarity_residual", "terminal_error", "physical_duration_s", "impacts"}


def handmade():
    """A 1-DoF 'drop' in 6 steps of h = 0.1: two flight steps, a partly frozen entry step (clock +0.04),
    two fully frozen steps, then two running steps. y = (q, v, t)."""
    h = 0.1
    clock = [0.0, 0.1, 0.2, 0.24, 0.24, 0.24, 0.34, 0.44]
    v = [-1.0, -2.0, -3.0, -1.5, -0.5, 0.0, 0.0, 0.0]
    q = [1.0, 0.8, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0]
    y = np.column_stack([q, v, clock])
    dv_aux = np.array([[0.0], [0.0], [2.0], [1.0], [0.5], [0.0], [0.0]])  # the entry step: -3.4 - ... see v_pre
    impulses = dv_aux.reshape(7, 1, 1) * np.array([1.0, 0.0]).reshape(1, 1, 2)
    u = np.arange(7.0).reshape(7, 1)
    tau = h * np.arange(8)
    return tau, y, u, np.full(7, h), dv_aux, impulses


def test_recover_one_impact():
    """A run of frozen steps is one impact at the clock value inside it, with two samples at that
    time: pre = state after the first frozen step minus its auxiliary increment, post = pre + all
    auxiliary increments; impulse = sum of the auxiliary impulses (eq. 22); running samples kept."""
    tau, y, u, dt, dv, imp = handmade()
    t, q, v, uu, impacts = recover(tau, y, u, dt, dv, imp, 1, 1, ("foot",))
    assert len(impacts) == 1
    im = impacts[0]
    assert im.time == pytest.approx(0.24, abs=EXACT) and im.contact == "foot"
    assert im.v_pre[0] == pytest.approx(-1.5 - 2.0, abs=EXACT)
    assert im.v_post[0] == pytest.approx(-3.5 + 3.5, abs=EXACT)
    assert im.impulse == pytest.approx(3.5, abs=EXACT) and im.impulse_tangential == 0.0
    assert (im.tau_start, im.tau_end) == pytest.approx((0.2, 0.5))
    np.testing.assert_allclose(t, [0.0, 0.1, 0.2, 0.24, 0.24, 0.34, 0.44], atol=EXACT)
    np.testing.assert_allclose(v[:, 0], [-1.0, -2.0, -3.0, -3.5, 0.0, 0.0, 0.0], atol=EXACT)
    np.testing.assert_allclose(uu[:, 0], [0, 0, 1, 2, 2, 5, 6])
    assert q.shape == (7, 1)


# kinetic energies [J] of a hand-made impact: 1 % of the larger is the threshold, these lie 0.5 % either side of it
GAIN_BELOW, GAIN_ABOVE = 1.005, 1.015


def test_an_impact_that_gains_kinetic_energy_is_flagged():
    """An impact ends with at most the kinetic energy it started with (restitution <= 1), so one that gains more than
    ENERGY_GAIN_SHARE of it is a push-off lumped into its partly frozen steps: flagged on its report line, counted in
    a line of its own and in summary.json (`gains_energy`). One within the share, or without energies (nan: not
    computed), or within ENERGY_GAIN_FLOOR_J (rounding at rest), is not; a losing one never."""
    from planner.result import ENERGY_GAIN_SHARE

    tau, y, u, dt, dv, imp = handmade()
    (im,) = recover(tau, y, u, dt, dv, imp, 1, 1, ("foot",))[4]
    assert not im.gains_energy and GAIN_BELOW - 1 < ENERGY_GAIN_SHARE < GAIN_ABOVE - 1
    cases = ((1.0, GAIN_ABOVE, True), (1.0, GAIN_BELOW, False), (2.0, 0.5, False), (float("nan"), 1.0, False),
             (0.0, 1e-15, False))  # (at rest: rounding, below ENERGY_GAIN_FLOOR_J)
    for pre, post, gains in cases:
        gained = replace(im, kinetic_energy_pre=pre, kinetic_energy_post=post)
        assert gained.gains_energy is gains and gained.to_json()["gains_energy"] is gains
        result = replace(_tiny_result(2), trajectory=replace(_tiny_result(2).trajectory, impacts=(gained,)))
        report = result.report()
        assert (f"(kinetic energy 1 -> {GAIN_ABOVE:.4g} J)" in report) is gains
        assert ("1 impact(s) gain kinetic energy (up to +0.015 J)" in report) is gains
    assert replace(im, kinetic_energy_pre=float("nan")).to_json()["kinetic_energy_pre_J"] is None


def test_recover_splits_a_run_where_the_clock_ran_after_the_impact():
    """Four partly frozen steps in a row (clock +0.04, +0.05, +0.06, +0.07 of h = 0.1) are two impacts, not one:
    a run takes its first step, the fully frozen ones after it and at most one more, because after a later partly
    frozen step the clock has run past the impact. Each impact has its own run's impulse and pre = post - its
    run's auxiliary increments; the node where the clock ran between them (v = 0.2 at t = 0.19) is a physical
    sample. Lumped into one run, the post-impact velocity would add the second run's increments to the first
    impact, a velocity that no node of the plan has."""
    clock = [0.0, 0.1, 0.14, 0.19, 0.25, 0.32, 0.42, 0.52]
    v = [-1.0, -2.0, -0.5, 0.2, -0.3, 0.1, 0.1, 0.1]
    y = np.column_stack([np.zeros(8), v, clock])
    dv = np.array([[0.0], [1.5], [0.8], [0.9], [0.6], [0.0], [0.0]])
    imp = dv.reshape(7, 1, 1) * np.array([1.0, 0.0]).reshape(1, 1, 2)
    t, _, vs, _, impacts = recover(0.1 * np.arange(8), y, np.zeros((7, 1)), np.full(7, 0.1), dv, imp, 1, 1, ("foot",))
    assert [im.time for im in impacts] == pytest.approx([0.14, 0.25], abs=EXACT)
    assert [(im.tau_start, im.tau_end) for im in impacts] == [pytest.approx((0.1, 0.3)), pytest.approx((0.3, 0.5))]
    assert [im.impulse for im in impacts] == pytest.approx([1.5 + 0.8, 0.9 + 0.6], abs=EXACT)
    assert [(im.v_pre[0], im.v_post[0]) for im in impacts] == [pytest.approx((-2.0, 0.3)), pytest.approx((-1.2, 0.3))]
    np.testing.assert_allclose(t, [0.0, 0.1, 0.14, 0.14, 0.19, 0.25, 0.25, 0.32, 0.42, 0.52], atol=EXACT)
    np.testing.assert_allclose(vs[:, 0], [-1.0, -2.0, -2.0, 0.3, 0.2, -1.2, 0.3, 0.1, 0.1, 0.1], atol=EXACT)


def test_recover_ends_an_impact_in_the_step_that_froze_its_last_bit():
    """A fully frozen step (the impact still on at its end) followed by a step whose clock ran 99.92 % of it (below
    FROZEN_TOL: no frozen step by itself) is one impact: the second step's auxiliary increment and impulse are the
    impact's end, so the inelastic v_post is 0 and the impulse the whole m |v_pre|. Left out, v_post kept moving into
    the ground (a tester's drop: -7.8 mm/s) and the impulse was short by that much. The point must still move into its
    plane at the frozen step's end (approach, per step's start): an impact over by then is followed by a stance's drift
    correction (a replan's push-off had been counted into its landing). A step that froze nothing is left alone."""
    clock = [0.0, 0.1, 0.1, 0.19992, 0.29992]
    y = np.column_stack([np.zeros(5), [-1.0, -2.0, -0.1, 0.0, 0.0], clock])
    dv = np.array([[0.0], [1.9], [0.1], [0.0]])
    imp = dv.reshape(4, 1, 1) * np.array([1.0, 0.0]).reshape(1, 1, 2)
    approach = y[:4, 1:2]  # the point mass's normal velocity is its v
    t, _, vs, _, impacts = recover(0.1 * np.arange(5), y, np.zeros((4, 1)), np.full(4, 0.1), dv, imp, 1, 1, ("foot",),
                                   approach=approach)
    (impact,) = impacts
    assert (impact.time, impact.v_pre[0], impact.v_post[0], impact.impulse) == pytest.approx((0.1, -2.0, 0.0, 2.0))
    assert (impact.tau_start, impact.tau_end) == pytest.approx((0.1, 0.3))
    # the node at t = 0.1 is the pre-impact sample (the step froze whole without advancing the clock): two samples at
    # the impact's time, as every implicit-Euler impact (it was repeated, three)
    np.testing.assert_allclose(t, [0.0, 0.1, 0.1, 0.19992, 0.29992], atol=EXACT)
    np.testing.assert_allclose(vs[:3, 0], [-1.0, -2.0, 0.0], atol=EXACT)
    over = recover(0.1 * np.arange(5), y, np.zeros((4, 1)), np.full(4, 0.1), dv, imp, 1, 1, ("foot",),
                   approach=np.where(np.arange(4)[:, None] == 2, 0.0, approach))[4]  # at rest on its plane at 0.1
    assert [(im.v_post[0], im.impulse, im.tau_end) for im in over] == [pytest.approx((-0.1, 1.9, 0.2))]
    whole = [0.0, 0.1, 0.1, 0.2, 0.3]  # the clock ran all of the next step: the impact ended with the frozen one
    y_whole = np.column_stack([np.zeros(5), [-1.0, -2.0, 0.0, 0.0, 0.0], whole])
    dv_whole = np.array([[0.0], [2.0], [0.0], [0.0]])
    (impact,) = recover(0.1 * np.arange(5), y_whole, np.zeros((4, 1)), np.full(4, 0.1), dv_whole,
                        dv_whole.reshape(4, 1, 1) * np.array([1.0, 0.0]).reshape(1, 1, 2), 1, 1, ("foot",))[4]
    assert (impact.v_post[0], impact.tau_end) == pytest.approx((0.0, 0.2))


def test_recover_dates_an_impact_at_the_node_when_its_frozen_step_only_leaked_the_clock():
    """A fully frozen first step whose clock leaked 2e-8 s (2e-7 of h: IPOPT's bound relaxation, 4.5e-8 s on the
    default biped plan's landing) starts its impact at the node before it: two samples at one time, the node's (the
    pre-impact one) and the post-impact one. Dated at the leaked clock, the node's state was repeated 2e-8 s later as
    the pre-impact sample: three samples of one instant in trajectory.npz, the middle one the node's again to ~1e-7."""
    leak = 2e-8  # [s] of clock over the frozen step
    clock = [0.0, 0.1, 0.1 + leak, 0.19992, 0.29992]  # the test above's, its fully frozen step leaking
    y = np.column_stack([np.zeros(5), [-1.0, -2.0, -0.1, 0.0, 0.0], clock])
    dv = np.array([[0.0], [1.9], [0.1], [0.0]])
    imp = dv.reshape(4, 1, 1) * np.array([1.0, 0.0]).reshape(1, 1, 2)
    t, _, vs, _, (impact,) = recover(0.1 * np.arange(5), y, np.zeros((4, 1)), np.full(4, 0.1), dv, imp, 1, 1,
                                     ("foot",), approach=y[:4, 1:2])
    assert impact.time == 0.1 and (impact.v_pre[0], impact.v_post[0]) == pytest.approx((-2.0, 0.0))
    np.testing.assert_allclose(t, [0.0, 0.1, 0.1, 0.19992, 0.29992], atol=EXACT)
    np.testing.assert_allclose(vs[:3, 0], [-1.0, -2.0, 0.0], atol=EXACT)


def test_recover_keeps_the_end_of_a_tail_step_that_ran_the_clock_with_several_contacts():
    """With several contacts a step is frozen only when its clock stood still (SolveOptions.frozen_tol_several), but a
    run's tail step that ran the clock after the impact (87.5 % of h) still ends at a physical sample: its end state is
    the plan's node, so the samples move at their velocities. Dropped (a bounder's landing lost its next node), the
    next samples were two steps apart and `planner validate` told the user their samples had been edited."""
    clock = [0.0, 0.1, 0.2, 0.2, 0.2875, 0.3875]  # h = 0.1: two flight steps, a fully frozen one, its tail, a stance
    y = np.column_stack([[1.0, 0.8, 0.5, 0.5, 0.5, 0.5], [-1.0, -2.0, -3.0, -0.4, 0.0, 0.0], clock])
    dv = np.array([[0.0], [0.0], [2.6], [0.4], [0.0]])
    imp = np.zeros((5, 2, 2))
    imp[:, 0, 0] = dv[:, 0]  # the landing front contact; the back one is in the air
    t, q, vs, _, impacts = recover(0.1 * np.arange(6), y, np.zeros((5, 1)), np.full(5, 0.1), dv, imp, 1, 1,
                                   ("front", "back"), SolveOptions().frozen_tol_several,
                                   approach=np.column_stack([y[:5, 1], np.zeros(5)]))
    (impact,) = impacts
    assert (impact.time, impact.v_pre[0], impact.v_post[0], impact.impulse) == pytest.approx((0.2, -3.0, 0.0, 3.0))
    np.testing.assert_allclose(t, [0.0, 0.1, 0.2, 0.2, 0.2875, 0.3875], atol=EXACT)
    np.testing.assert_allclose(np.column_stack([q[:, 0], vs[:, 0]])[4], [0.5, 0.0], atol=EXACT)


def test_recover_finds_an_impact_in_a_short_frozen_element_with_several_contacts():
    """With several contacts a FESD impact in an element half as long as the longest (clock stood still over its
    0.05 s) is an impact: a run is a sliver (no impact) only when it froze less than FROZEN_TOL of the longest
    element, as with one contact, not 1 - FROZEN_TOL of it (frozen_tol_several), which dropped every impact of a
    shorter element."""
    clock = [0.0, 0.1, 0.1, 0.2]  # elements of 0.1, 0.05 (frozen: the impact at its start) and 0.1 s
    y = np.column_stack([[0.2, 0.0, 0.0, 0.0], [-2.0, -2.0, 0.0, 0.0], clock])
    dv = np.array([[0.0], [2.0], [0.0]])
    imp = np.zeros((3, 2, 2))
    imp[:, 0, 0] = dv[:, 0]
    t, _, _, _, impacts = recover(np.array([0.0, 0.1, 0.15, 0.25]), y, np.zeros((3, 1)), np.array([0.1, 0.05, 0.1]),
                                  dv, imp, 1, 1, ("front", "back"), SolveOptions().frozen_tol_several,
                                  switch_at_start=True)
    assert [(im.contact, im.time, im.impulse) for im in impacts] == [("front", pytest.approx(0.1), pytest.approx(2.0))]
    np.testing.assert_allclose(t, [0.0, 0.1, 0.1, 0.1, 0.2], atol=EXACT)  # FESD's three: the flight's end repeated

def test_recover_reads_a_partly_frozen_step_at_rest_as_support_and_ends_an_impact_there():
    """A partly frozen step whose contacts (those taking its normal impulse) rest on their planes at both ends (on the
    plane, normal velocity 0: `resting`, per node) is support, no impact: its auxiliary field carried part of the
    weight (a Coulomb slide was 13 impacts whose v_post read +0.22 m/s off the ground; a physical_time stance 12,
    MuJoCo saw none). Not when another contact takes part of the impulse landing (a plank resting on one end took 2.9
    times the impulse of its other end landing at 6.4 m/s: no impact was left). An impact in a run's first step (a
    landing inside it) goes on into the next frozen step only while its contacts are not at rest at that step's
    start: at rest there the impact is over, and that step (a push-off: moving off at its end) is an impact of its
    own. Unknown resting: as before, one run."""
    clock = [0.0, 0.095, 0.19, 0.29]
    y = np.column_stack([np.zeros(4), [0.0, 0.0, 0.0, 0.0], clock])  # on the ground, v_n = 0 at every node
    dv = np.array([[0.93], [0.93], [0.0]])  # each partly frozen step's support against its gravity, -0.93 m/s
    imp = dv.reshape(3, 1, 1) * np.array([1.0, 0.0]).reshape(1, 1, 2)
    args = (0.1 * np.arange(4), y, np.zeros((3, 1)), np.full(3, 0.1), dv, imp, 1, 1, ("foot",))
    t, _, _, _, impacts = recover(*args, resting=np.ones((4, 1), bool))
    assert impacts == () and t == pytest.approx(clock)
    (lumped,) = recover(*args)[4]
    assert (lumped.v_pre[0], lumped.v_post[0]) == pytest.approx((-0.93, 0.93))
    # the same steps with a second contact that takes part of the impulse while landing (not at rest at node 0)
    two = np.concatenate([imp, 0.35 * imp], axis=1)  # (3, 2, 2): the resting contact's and the lander's
    landing = np.column_stack([np.ones(4, bool), [False, True, True, True]])
    both = recover(*args[:5], two, 1, 1, ("rest", "land"), resting=landing)[4]  # (one Impact per contact)
    assert [(im.contact, im.time) for im in both] == [("rest", pytest.approx(0.095)), ("land", pytest.approx(0.095))]
    # a landing inside step 0 (at rest at node 1), then a partly frozen push-off (moving off at node 2)
    y = np.column_stack([np.zeros(4), [-1.0, 0.0, 0.5, 0.5], clock])
    dv = np.array([[1.0], [0.6], [0.0]])
    imp = dv.reshape(3, 1, 1) * np.array([1.0, 0.0]).reshape(1, 1, 2)
    args = (0.1 * np.arange(4), y, np.zeros((3, 1)), np.full(3, 0.1), dv, imp, 1, 1, ("foot",))
    landing, push = recover(*args, approach=y[:3, 1:2], resting=(y[:, 1:2] == 0.0))[4]
    assert (landing.v_pre[0], landing.v_post[0], landing.impulse) == pytest.approx((-1.0, 0.0, 1.0))
    assert (push.v_pre[0], push.v_post[0], push.impulse) == pytest.approx((-0.1, 0.5, 0.6))
    (lumped,) = recover(*args)[4]
    assert (lumped.v_pre[0], lumped.v_post[0], lumped.impulse) == pytest.approx((-1.0, 0.6, 1.6))


def test_recover_dates_a_landing_at_a_node_there():
    """The same four partly frozen steps, the first starting with the point on its plane moving into it (landed[1, 0]: a
    landing that ended a flight step at the node at t = 0.1): its impact is at that node, posture and pre-impact
    velocity (it was dated at the step's end, 0.14, one step late, with the stance's motion in v_pre), its
    post-impact velocity the step's end state, and the clock ran after it, so the next frozen step starts the next
    impact (dated at its end, as an impact inside its step is), whose run takes one more step by the usual rule. The
    node where the clock stopped running after the landing (t = 0.14) stays a sample. The landing is two samples at
    t = 0.1, as every impact: the node's, which is the pre-impact one, and the post-impact one (the node's sample
    repeated made three, and a user pairing samples of equal time read a spurious impact)."""
    clock = [0.0, 0.1, 0.14, 0.19, 0.25, 0.32, 0.42, 0.52]
    v = [-1.0, -2.0, -0.5, 0.2, -0.3, 0.1, 0.1, 0.1]
    y = np.column_stack([np.arange(8.0), v, clock])
    dv = np.array([[0.0], [1.5], [0.8], [0.9], [0.6], [0.0], [0.0]])
    imp = dv.reshape(7, 1, 1) * np.array([1.0, 0.0]).reshape(1, 1, 2)
    landed = np.array([[False], [True], [False], [False], [False], [False], [False]])  # (steps, contacts)
    t, q, vs, _, impacts = recover(0.1 * np.arange(8), y, np.zeros((7, 1)), np.full(7, 0.1), dv, imp, 1, 1, ("foot",),
                                   landed=landed)
    assert [im.time for im in impacts] == pytest.approx([0.1, 0.19, 0.32], abs=EXACT)
    assert [(im.tau_start, im.tau_end) for im in impacts] == [pytest.approx((0.1, 0.2)), pytest.approx((0.2, 0.4)),
                                                              pytest.approx((0.4, 0.5))]
    assert [im.impulse for im in impacts] == pytest.approx([1.5, 0.8 + 0.9, 0.6], abs=EXACT)
    assert (impacts[0].q[0], impacts[0].v_pre[0], impacts[0].v_post[0]) == pytest.approx((1.0, -2.0, -0.5))
    np.testing.assert_allclose(q[:, 0], [0, 1, 1, 2, 3, 3, 4, 5, 5, 6, 7], atol=EXACT)  # node 2 kept
    np.testing.assert_allclose(t, [0.0, 0.1, 0.1, 0.14, 0.19, 0.19, 0.25, 0.32, 0.32, 0.42, 0.52], atol=EXACT)
    np.testing.assert_allclose(vs[:3, 0], [-1.0, -2.0, -0.5], atol=EXACT)
    unlanded = recover(0.1 * np.arange(8), y, np.zeros((7, 1)), np.full(7, 0.1), dv, imp, 1, 1, ("foot",))[4]
    assert [im.time for im in unlanded] == pytest.approx([0.14, 0.25], abs=EXACT)


def test_recover_never_goes_back_in_time():
    """An impact that starts with a clock 2e-10 s behind the previous sample (an NLP solver's bound
    relaxation: the clock rate of a frozen step at -1e-8) is placed at the previous sample's time:
    physical time never decreases (the contract's t is non-decreasing)."""
    tau, y, u, dt, dv, imp = handmade()
    y = y.copy()
    y[3:6, 2] = 0.2 - 2e-10  # no partial flight: the frozen steps start at the flight's last sample, slightly behind
    y[6:, 2] = [0.3, 0.4]
    t, *_, impacts = recover(tau, y, u, dt, dv, imp, 1, 1, ("foot",))
    assert np.all(np.diff(t) >= 0)
    assert impacts[0].time == pytest.approx(0.2, abs=EXACT)


def test_recover_without_impacts_keeps_every_sample():
    """A trajectory whose clock always runs maps one to one onto physical time."""
    tau = 0.1 * np.arange(4)
    y = np.column_stack([np.zeros(4), np.ones(4), tau])
    t, q, v, u, impacts = recover(tau, y, np.zeros((3, 2)), np.full(3, 0.1), np.zeros((3, 1)), np.zeros((3, 1, 2)), 1, 1, ("p",))
    assert impacts == () and len(t) == 4
    np.testing.assert_allclose(t, tau)


def small_result() -> SimulationResult:
    robot = load_robot("point_mass")
    task = parse_task({"contacts": [{"point": "point", "a_n": 100.0}], "initial": {"q": [0.0, 0.3], "v": [1.0, 0.0]},
                       "horizon": {"tau_f": 0.5, "N": 25}})
    return simulate(robot, task)


def test_hops_leave_out_flight_phases_where_the_point_does_not_move():
    """A flight phase (beta > 0.5) whose contact point stays at its takeoff position is no hop (FESD's point mass at
    rest after its landing with beta = 1 was a second hop of distance and apex 0); a real hop is kept with its takeoff,
    landing, distance and apex, and a hop down a ledge (apex 0, distance > 0) is kept too."""
    clock = np.array([0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7])
    traj = SimpleNamespace(y=clock[:, None], impacts=())
    flight = np.array([0, 1, 1, 0, 1, 1, 0])  # steps 1-2 and 4-5 in flight
    xyz = np.zeros((8, 3))
    xyz[2:4, 0], xyz[2, 2], xyz[3, 0] = 0.25, 0.1, 0.5  # node 2 in the air, lands at x = 0.5 at node 3
    xyz[4:, 0] = 0.5  # then rests at x = 0.5
    (hop,) = hops_of(traj, flight, xyz)
    assert (hop.takeoff_time, hop.landing_time) == (0.1, 0.4)
    assert abs(hop.distance - 0.5) < EXACT and abs(hop.apex - 0.1) < EXACT
    ledge = xyz.copy()
    ledge[5:, 0], ledge[5:, 2] = 0.7, -0.2  # the second phase moves down and forward
    assert [round(h.distance, 12) for h in hops_of(traj, flight, ledge)] == [0.5, 0.2]
    assert hops_of(traj, flight, ledge)[1].apex == 0.0


def test_hops_know_a_fall_from_the_start_and_a_landing_inside_a_step():
    """With the point's gaps at the nodes: a flight phase from node 0 with the point off its plane is a fall, no hop (a
    point mass dropped from 1 m was "1 hop" with takeoff 0.0), and a phase whose last node is still in the air lands in
    the next, partly frozen step: its distance runs to that step's end node (it stopped at the last flight node, 1 cm
    short of where a drop with a_n = 20 landed). Without gaps, as before."""
    clock = 0.1 * np.arange(6)
    traj = SimpleNamespace(y=clock[:, None], impacts=())
    xyz = np.zeros((6, 3))
    xyz[:, 0], xyz[:3, 2] = 0.1 * np.arange(6), (0.3, 0.2, 0.1)  # falls from 0.3 m, lands in step 2
    fall = np.array([1, 1, 0, 0, 0])
    assert hops_of(traj, fall, xyz, gap=xyz[:, 2]) == [] and len(hops_of(traj, fall, xyz)) == 1
    xyz[:, 2] = (0.0, 0.1, 0.05, 0.0, 0.0, 0.0)  # takes off at node 0, still 5 cm up at node 2, landed at node 3
    (hop,) = hops_of(traj, fall, xyz, gap=xyz[:, 2])
    assert abs(hop.distance - 0.3) < EXACT and abs(hop.apex - 0.1) < EXACT
    assert abs(hops_of(traj, fall, xyz)[0].distance - 0.2) < EXACT


def test_a_phase_that_keeps_the_point_on_its_plane_is_a_slide_not_a_hop():
    """A flight phase (beta > 0.5) of two steps or more whose nodes all keep the point's distance from its contact plane
    is a slide, no hop (a point mass sliding 0.5 m with z = 0 at every node was a hop of apex 0; on a slope too); a
    one-step phase that moves along the ground is kept without the gaps, and so is a phase that leaves the plane; with
    the gaps, a one-step phase on the ground at both ends is a skim, no hop (Capler at N = 50 counted three such
    frictionless slides as hops), unless it passes over a hole, and then it lands at its last node (it read a step
    later); a slide that passes over a hole is a hop too."""
    clock = 0.1 * np.arange(6)
    traj = SimpleNamespace(y=clock[:, None], impacts=())
    xyz = np.zeros((6, 3))
    xyz[:, 0] = 0.1 * np.arange(6)  # moving forward at every node, on the ground
    assert hops_of(traj, np.array([0, 1, 1, 1, 0]), xyz) == []
    assert len(hops_of(traj, np.array([0, 1, 0, 0, 0]), xyz)) == 1
    # with the gaps: a skim, unless a hole lies between its nodes (x = 0.1 and 0.2 m); then its last node is on the
    # ground, so it lands there (it read a step later, node 3's 0.3 s)
    assert hops_of(traj, np.array([0, 1, 0, 0, 0]), xyz, gap=xyz[:, 2]) == []
    aside, between = Ellipse(x=0.35, a=0.02, b=0.05), Ellipse(x=0.15, a=0.02, b=0.05)
    assert hops_of(traj, np.array([0, 1, 0, 0, 0]), xyz, gap=xyz[:, 2], holes=(aside,)) == []
    (over,) = hops_of(traj, np.array([0, 1, 0, 0, 0]), xyz, gap=xyz[:, 2], holes=(aside, between))
    assert (over.takeoff_time, over.landing_time) == (0.1, 0.2)
    # a slide along the ground (three steps) is a hop when one of its steps passes over a hole (it was a slide)
    assert hops_of(traj, np.array([0, 1, 1, 1, 0]), xyz, holes=(Ellipse(x=0.9, a=0.02, b=0.05),)) == []
    (across,) = hops_of(traj, np.array([0, 1, 1, 1, 0]), xyz, holes=(between,))
    assert (across.takeoff_time, across.distance) == (0.1, pytest.approx(0.3))
    xyz[2, 2] = 10 * ON_PLANE_M
    assert len(hops_of(traj, np.array([0, 1, 1, 1, 0]), xyz)) == 1
    # down a 30-degree slope (its normal (sin, 0, cos)): the same slide, judged by the distance from the plane
    slope = np.column_stack([0.1 * np.arange(6), np.zeros(6), -0.1 * np.arange(6) * np.tan(np.pi / 6)])
    normal = (np.sin(np.pi / 6), 0.0, np.cos(np.pi / 6))
    assert hops_of(traj, np.array([0, 1, 1, 1, 0]), slope, normal) == []
    assert len(hops_of(traj, np.array([0, 1, 1, 1, 0]), slope)) == 1  # (by its height it would be a hop)


def test_each_contacts_frictionless_slides_are_found_by_its_own_beta_and_gap():
    """slides_of lists one contact point's flight-mode phases (its own beta > 0.5) of two steps or more that keep it on
    its plane at every node and move it, with their first and last node's clocks and x distance: the back foot of a
    bounder slid so while the front foot stood, where no friction acts and MuJoCo's replay then fails the plan, and
    hops_of, which reads the robot's flight (every beta) and the first contact, saw none of it. A phase that leaves the
    plane at a node, does not move the point, or passes over a hole (a hop) is no slide; a one-step phase is a skim,
    listed once, in skims when given, by its point's name (it was listed as a slide too when hops_of's skim matched it,
    and under the first contact's name and distance when it did not)."""
    from planner.result import slides_of

    clock = np.arange(10) / 10
    traj = SimpleNamespace(y=clock[:, None], impacts=())
    beta = np.zeros((9, 2))  # the front foot (column 0) stands throughout
    beta[[1, 2, 3, 5, 7], 1] = 1.0  # the back foot flies in steps 1-3, 5 and 7
    front, back = np.zeros((10, 3)), np.zeros((10, 3))
    back[:, 0] = (0.0, 0.0, 0.05, 0.15, 0.2, 0.2, 0.1, 0.1, 0.1, 0.1)  # slides 0.2 m on, 0.1 m back, rests in step 7
    gaps = np.column_stack([front[:, 2], back[:, 2]])
    assert hops_of(traj, beta.min(axis=1), front, gap=gaps.min(axis=1)) == []
    slides = slides_of(traj, beta[:, 1], back, gaps[:, 1], "back_foot", skims=(skims := []))
    assert slides == [{"point": "back_foot", "start_time": 0.1, "end_time": 0.4, "distance": pytest.approx(0.2)}]
    assert skims == [{"point": "back_foot", "takeoff_time": 0.5, "landing_time": 0.6, "distance": pytest.approx(-0.1),
                      "apex": 0.0}]
    assert slides_of(traj, beta[:, 1], back, gaps[:, 1], "back_foot") == slides  # (no list: skims are not slides)
    assert slides_of(traj, beta[:, 0], front, gaps[:, 0], "front_foot", skims=(none := [])) == [] and none == []
    assert slides_of(traj, beta[:, 1], back, gaps[:, 1], "back_foot", holes=(Ellipse(x=0.1, a=0.02, b=0.05),)) == []
    lifted = back.copy()
    lifted[2, 2] = 10 * ON_PLANE_M  # off the plane at one node of the first phase: a flight, not a slide
    assert slides_of(traj, beta[:, 1], lifted, lifted[:, 2], "back_foot") == []


def test_one_contacts_skims_are_the_phases_hops_of_leaves_out():
    """With one contact point, slides_of's skims are the one-step phases on the ground at both ends that hops_of leaves
    out as no hops, with their nodes' clocks, x distance and apex, named by the point, while the phase that leaves the
    ground stays hops_of's hop: a one-contact plan's skims (Capler's, the hopper's) are the robot's, as when hops_of
    listed them."""
    from planner.result import slides_of

    clock = np.arange(6) / 10
    traj = SimpleNamespace(y=clock[:, None], impacts=())
    flight = np.array([0, 1, 0, 1, 1])
    xyz = np.zeros((6, 3))
    xyz[:, 0] = (0.0, 0.0, 0.1, 0.1, 0.3, 0.4)
    xyz[4, 2] = 0.05  # steps 3-4: a hop (its middle node is off the ground)
    (hop,) = hops_of(traj, flight, xyz, gap=xyz[:, 2])
    assert (hop.takeoff_time, hop.landing_time) == (0.3, 0.5)
    assert slides_of(traj, flight, xyz, xyz[:, 2], "foot", skims=(skims := [])) == []
    assert skims == [{"point": "foot", "takeoff_time": 0.1, "landing_time": 0.2, "distance": pytest.approx(0.1),
                      "apex": 0.0}]


def test_a_step_along_the_plane_inside_a_longer_flight_is_a_skim():
    """slides_of also reads the runs of a flight phase's steps that keep the point on its plane: one such step inside a
    longer flight (the point up, then along the ground, then up again) moves it without friction as a one-step phase
    does, and is a skim (the default biped plan's swing foot slid 3.1 cm at 1.5 m/s so, unreported: a session-68
    tester); two such steps a slide; a step whose ends are on the plane but that does not move the point is neither,
    nor a hop's take-off or landing step along the ground (the phase's first or last node and the next on the plane:
    the hop's distance holds it; a crouched Capler's first hop was listed as a skim too)."""
    from planner.result import slides_of

    clock = np.arange(9) / 10
    traj = SimpleNamespace(y=clock[:, None], impacts=())
    flight = np.array([0, 1, 1, 1, 1, 1, 1, 0])  # one flight phase: nodes 1-7
    xyz = np.zeros((9, 3))
    xyz[:, 0] = (0.0, 0.0, 0.05, 0.1, 0.13, 0.13, 0.2, 0.2, 0.2)
    xyz[[2, 5, 6], 2] = 0.02  # up at nodes 2 and 5-6, on the ground at 3-4 (moving) and 7
    assert slides_of(traj, flight, xyz, xyz[:, 2], "foot", skims=(skims := [])) == []
    assert skims == [{"point": "foot", "takeoff_time": 0.3, "landing_time": 0.4, "distance": pytest.approx(0.03),
                      "apex": 0.0}]
    xyz[5, 2], xyz[5, 0] = 0.0, 0.16  # on the ground at nodes 3-5: two moving steps
    (slide,) = slides_of(traj, flight, xyz, xyz[:, 2], "foot", skims=(skims := []))
    assert (slide["start_time"], slide["end_time"], skims) == (0.3, 0.5, [])
    xyz[3:6, 0] = 0.1  # on the ground at nodes 3-5 again, but at one place
    assert slides_of(traj, flight, xyz, xyz[:, 2], "foot", skims=(skims := [])) == [] and skims == []
    xyz[:, 0] = 0.05 * np.arange(9)  # moving at every node
    for ground in ((1, 2), (6, 7)):  # the take-off step, the landing step along the ground
        xyz[:, 2] = 0.02
        xyz[[0, 1, 7, 8], 2] = 0.0  # (on the ground before and after the phase)
        xyz[list(ground), 2] = 0.0
        assert slides_of(traj, flight, xyz, xyz[:, 2], "foot", skims=(skims := [])) == [] and skims == [], ground


def test_unrecorded_landings_name_each_point_that_lands_in_steps_that_ran_the_clock():
    """unrecorded_landings lists each contact point's runs of nodes on its plane while moving into it faster than
    APPROACH_MPS that no Impact of that point holds, with the run's first node's clock, its fastest approach (the node
    before's counts when its step moved the point down: the running step before can brake part of the landing) and the
    share of the step from that node the clock ran (where the point, arriving into the plane, is braked: the step a
    recovered impact freezes, not the flight step that brought it down): a bounder's feet landed at 3.2-6.8 m/s in
    steps that ran the clock, which the several-contact recovery records as no impact, and the report said "0
    impact(s), 2 hop(s)". A point on its plane at the node before (whatever its node velocity) or moving into it off
    the plane is no landing, nor one an Impact of its own holds (another point's does not), nor a run slower than
    LANDING_MIN_MPS (a foot settling: the biped's 0.03-0.07 m/s); the node before's velocity is the approach only
    when its step moved the point down."""
    from planner.result import APPROACH_MPS, LANDING_MIN_MPS, unrecorded_landings

    h = 0.05
    clock = h * np.array([0.0, 1.0, 1.98, 2.9, 3.9, 4.9, 5.9])  # (the clock ran 98 % of step 1, 92 % of step 2)
    traj = SimpleNamespace(y=clock[:, None], tau=h * np.arange(7), impacts=())
    gap = np.zeros((7, 2))
    gap[:2, 1] = (0.2, 0.05)  # the back foot falls, and lies on the ground from node 2
    approach = np.zeros((7, 2))
    approach[:, 0] = 0.1 * APPROACH_MPS  # the front foot rests (drift below the threshold)
    approach[1:5, 1] = (-5.5, -1.2, -0.4, 0.01)  # on the ground at -1.2 m/s after -5.5 m/s in the air, then stops
    dt, feet = np.full(6, h), ("front_foot", "back_foot")
    landing = {"point": "back_foot", "time": pytest.approx(clock[2], abs=EXACT),
               "approach_mps": pytest.approx(5.5, abs=EXACT), "clock_share": pytest.approx(0.92, abs=EXACT)}
    assert unrecorded_landings(traj, approach, gap, dt, feet) == [landing]
    held = replace(_impact(2.0, 0.0, "back_foot"), time=clock[2], tau_start=traj.tau[2], tau_end=traj.tau[4])
    for impact, found in ((held, []), (replace(held, contact="front_foot"), [landing])):
        assert unrecorded_landings(SimpleNamespace(**{**vars(traj), "impacts": (impact,)}), approach, gap, dt,
                                   feet) == found
    # a foot on its plane at the node before (standing, or skimming along it) whose node velocity J v points into it
    # while it stays put (a bounder's, its joints turning 0.4-2.5 rad per step: 0.18-3.9 m/s) is no landing
    approach[2:4, 0] = -0.7
    assert unrecorded_landings(traj, approach, gap, dt, feet) == [landing]
    approach[2:4, 0] = 0.1 * APPROACH_MPS
    # the node before's velocity counts only when its step moved the foot down to it (a bounder's 16.3 m/s was read
    # from a node whose step had lifted the foot 12 cm)
    gap[:2, 1] = (0.05, 0.01)
    approach[1, 1] = 5.5  # (moving up at node 1: its step lifted the foot, and the node's velocity is no approach)
    gap[0, 1] = 0.005
    assert unrecorded_landings(traj, approach, gap, dt, feet) == [{**landing, "approach_mps": pytest.approx(1.2)}]
    # the gap it came down over its last step's physical time, when the node reads slower (a tribot's foot came down
    # 6.75 cm in a whole step read at 0.21 m/s by its node's J v)
    gap[1, 1] = 0.1
    assert unrecorded_landings(traj, approach, gap, dt, feet) == [
        {**landing, "approach_mps": pytest.approx(0.1 / (clock[2] - clock[1]))}]
    clock[1] = clock[2] - 1e-8  # (step 1 fully frozen, its clock leaked: the quotient would be solver noise)
    gap[1, 1] = 0.01
    assert unrecorded_landings(traj, approach, gap, dt, feet) == [{**landing, "approach_mps": pytest.approx(1.2)}]
    clock[1] = h
    gap[:2, 1], approach[1, 1] = (0.2, 0.05), -5.5
    approach[6, 0] = -1.0  # (the last node starts no step, so holds no landing)
    gap[4:, 0], approach[4, 0] = 0.1, -2.0  # (off the plane: still in the air, to the end: no landing after it)
    assert unrecorded_landings(traj, approach, gap, dt, feet) == [landing]
    approach[1:4, 1] = (-0.9, -0.5, -0.2) * np.array(LANDING_MIN_MPS)  # a foot settling onto its plane
    gap[1, 1] = 0.2 * LANDING_MIN_MPS * (clock[2] - clock[1])  # (from just above it)
    assert unrecorded_landings(traj, approach, gap, dt, feet) == []


def test_unrecorded_landings_find_a_landing_braked_to_rest_before_its_node():
    """A point that comes down from the air to its plane over a step that ran the clock lands there even when its node
    velocity J v no longer points into the plane: the step's auxiliary dynamics can brake it to rest before the node,
    and the report must not hide that landing (listed at the mean speed it came down over the step's physical time).
    An Impact of that point over the step that brought it down holds it (one frozen step's impact ends at the node and
    is dated at the node before when its clock leaked), and a point that settles from just above its plane slower than
    LANDING_MIN_MPS is no landing, while one that fell fast to just above it over the step before landed at the node
    before's J v (in implicit Euler that velocity moved it down). Its clock_share is that of the step that brought it
    down and braked it, where an impact would have been, not of the step after."""
    from planner.result import LANDING_MIN_MPS, unrecorded_landings

    h = 0.05
    clock = h * np.array([0.0, 1.0, 1.98, 2.9, 3.9])  # (the clock ran 98 % of step 1, 92 % of steps 2 and 3)
    traj = SimpleNamespace(y=clock[:, None], tau=h * np.arange(5), impacts=())
    gap = np.zeros((5, 2))
    gap[:2, 1] = (0.2, 0.05)  # the back foot falls, and lies on the ground from node 2
    approach = np.zeros((5, 2))
    dt, feet = np.full(4, h), ("front_foot", "back_foot")
    for approach[1, 1] in (-1.0, 1.0):  # (J v at node 1 down or up alike: J v at the landing node is 0)
        assert unrecorded_landings(traj, approach, gap, dt, feet) == [
            {"point": "back_foot", "time": pytest.approx(clock[2], abs=EXACT),
             "approach_mps": pytest.approx(0.05 / (clock[2] - clock[1]), abs=EXACT),
             "clock_share": pytest.approx(0.98, abs=EXACT)}], approach[1, 1]
    held = replace(_impact(2.0, 0.0, "back_foot"), time=clock[1], tau_start=traj.tau[1], tau_end=traj.tau[2])
    assert unrecorded_landings(SimpleNamespace(**{**vars(traj), "impacts": (held,)}), approach, gap, dt, feet) == []
    settle = 0.5 * LANDING_MIN_MPS * (clock[2] - clock[1])  # settling from just above the plane, 2.45 mm
    gap[:2, 1] = (2 * settle, settle)
    for approach[1, 1] in (0.0, -settle / (clock[1] - clock[0])):  # (the node before's J v as slow as its fall)
        assert unrecorded_landings(traj, approach, gap, dt, feet) == [], approach[1, 1]
    gap[0, 1] = 0.2  # (it fell from 0.2 m to 2.45 mm over the step before: a landing at that J v, 3.95 m/s)
    approach[1, 1] = -(0.2 - settle) / (clock[1] - clock[0])
    assert [f["approach_mps"] for f in unrecorded_landings(traj, approach, gap, dt, feet)] == [
        pytest.approx(-approach[1, 1], abs=EXACT)]


def test_unrecorded_landings_leave_out_a_point_hovering_just_above_its_plane():
    """A point a few micrometres above its plane (ON_PLANE_M) that drifts onto it made no landing, whatever the step's
    clock or the node before's J v: a 1.5 um drift over a step whose clock ran 1e-4 h reads 0.30 m/s, and a J v of
    -0.5 m/s at the node before hovering 2 um up is no fall either; nor is a point that an Impact left 1.2 um above its
    plane reaching it at the next node (the impact recorded that landing: without it, that node is listed), nor one
    that settled slowly from 0.1 mm over two steps, the last one's clock leaked. Listing these would report landings at
    0.2-0.5 m/s that MuJoCo's replay never sees."""
    from planner.result import unrecorded_landings

    h, feet = 0.05, ("front_foot", "back_foot")
    dt, tau = np.full(4, h), h * np.arange(5)
    gap, approach = np.zeros((5, 2)), np.zeros((5, 2))
    gap[:, 1] = (3e-6, 2e-6, 0.5e-6, 0.5e-6, 0.5e-6)  # (above ON_PLANE_M at nodes 0 and 1, on it from node 2)
    leaked = h * np.array([0.0, 1.0, 1.0001, 2.0001, 3.0])  # (step 1's clock ran 1e-4 of it)
    assert unrecorded_landings(SimpleNamespace(y=leaked[:, None], tau=tau, impacts=()), approach, gap, dt, feet) == []
    running = SimpleNamespace(y=tau[:, None], tau=tau, impacts=())
    approach[1, 1] = -0.5
    assert unrecorded_landings(running, approach, gap, dt, feet) == []
    # a fall onto the plane in a frozen step 1, its Impact ending at node 2 with the foot 1.2 um up, still
    # approaching: the foot reaches the plane at node 3
    clock = h * np.array([0.0, 1.0, 1.0 + 2e-6, 2.0, 3.0])
    impact = replace(_impact(2.0, 0.0, "back_foot"), time=clock[1], tau_start=tau[1], tau_end=tau[2])
    gap[:, 1], approach[:3, 1] = (0.1, 0.02, 1.2e-6, 0.5e-6, 0.5e-6), (-3.0, -3.0, -0.2)
    assert unrecorded_landings(SimpleNamespace(y=clock[:, None], tau=tau, impacts=(impact,)), approach, gap, dt,
                               feet) == []
    assert [f["time"] for f in unrecorded_landings(SimpleNamespace(y=clock[:, None], tau=tau, impacts=()), approach,
                                                   gap, dt, feet)] == [pytest.approx(clock[3], abs=EXACT)]
    # settling at 2 mm/s from 102 um to 1.5 um, then 1 um onto the plane over a step whose clock leaked 1e-4 h: its
    # fall over the two steps, not the last step's drift over the leaked clock (read 0.2 m/s)
    gap[:, 1], approach[:, 1] = (1.02e-4, 1.5e-6, 0.5e-6, 0.5e-6, 0.5e-6), (0.0, -2e-3, 0.0, 0.0, 0.0)
    assert unrecorded_landings(SimpleNamespace(y=leaked[:, None], tau=tau, impacts=()), approach, gap, dt, feet) == []


def test_unrecorded_landings_find_a_fall_that_a_flight_step_left_micrometres_up():
    """A point that a flight step brings down at 4 m/s to 50 um above its plane (below FALL_MIN_M), and the next step,
    which runs the clock, stops on the plane with J v 0 at the node, landed: the fall is read over the two steps, at the
    node before's J v (listed at b70ba65's 4 m/s; the height rule alone dropped it)."""
    from planner.result import unrecorded_landings

    h, feet = 0.05, ("front_foot", "back_foot")
    tau = h * np.arange(5)
    gap, approach = np.zeros((5, 2)), np.zeros((5, 2))
    gap[:2, 1] = (0.2, 5e-5)
    approach[1, 1] = -(0.2 - 5e-5) / h
    listed = unrecorded_landings(SimpleNamespace(y=tau[:, None], tau=tau, impacts=()), approach, gap, np.full(4, h),
                                 feet)
    assert [(f["point"], f["time"], f["approach_mps"]) for f in listed] == [
        ("back_foot", pytest.approx(tau[2], abs=EXACT), pytest.approx(-approach[1, 1], abs=EXACT))]


def test_the_report_and_summary_name_each_slide():
    """A plan's extra["slides"] gives one report line that counts the slides and names each point, start time and
    distance, and summary.json carries them, so a user sees why a plan that slides a foot in flight mode (no friction)
    fails MuJoCo's replay; a plan without slides has no such line."""
    plan = _hop_plan()
    assert "slide(s)" not in plan.report()
    slides = [{"point": "back_foot", "start_time": 0.41, "end_time": 0.47, "distance": 0.194},
              {"point": "back_foot", "start_time": 1.372, "end_time": 1.422, "distance": -0.15}]
    sliding = replace(plan, extra={**plan.extra, "slides": slides})
    assert ("\n  2 slide(s) of a contact point along its plane in flight mode, where no friction acts: back_foot "
            "t = 0.41 s +0.194 m, back_foot t = 1.372 s -0.15 m\n") in sliding.report()
    assert sliding.summary()["slides"] == slides


def test_the_reports_cost_line_says_when_the_speed_of_time_scales_it():
    """The report's cost line reads "integral of u^T u over numerical time" for a plan without physical_time, and adds
    "scaled by the speed of time s" for one with it, whose control_cost is h sum s_k u_k^T u_k: read as the integral
    over numerical time alone it was h sum u_k^T u_k, which understated a physical_time plan's effort (session 70)."""
    plan = _hop_plan()
    cost = f"{plan.extra['control_cost']:.4g}"
    assert f"cost: integral of u^T u over numerical time {cost}" in plan.report().splitlines()
    task = plan.extra["_task"]
    timed_task = replace(task, horizon=replace(task.horizon, physical_time=1.0))
    timed = replace(plan, extra={**plan.extra, "_task": timed_task})
    line = f"cost: integral of u^T u over numerical time scaled by the speed of time s {cost}"
    assert line in timed.report().splitlines()


def test_the_report_and_summary_name_each_skims_point_and_each_landing_without_an_impact():
    """A plan's extra["skims"] names each skim's contact point in its report line, and extra["unrecorded_landings"]
    gives one line that counts them and names each point, time, approach speed and the share of the step the clock
    ran, and summary.json carries both: a bounder's report read "0 impact(s), 2 hop(s)" while its feet landed at
    3.2-6.8 m/s, and its one skim line gave the front foot's time beside no name. A plan without them has no such
    lines."""
    plan = _hop_plan()
    assert "landing(s) with no impact record" not in plan.report() and "skim(s)" not in plan.report()
    skims = [{"point": "back_foot", "takeoff_time": 0.285, "landing_time": 0.374, "distance": 0.194, "apex": 0.0},
             {"point": "front_foot", "takeoff_time": 1.372, "landing_time": 1.422, "distance": 0.107, "apex": 0.0}]
    landings = [{"point": "back_foot", "time": 0.3961, "approach_mps": 5.54, "clock_share": 0.981},
                {"point": "front_foot", "time": 1.337, "approach_mps": 4.9, "clock_share": 1.401}]
    marked = replace(plan, extra={**plan.extra, "skims": skims, "unrecorded_landings": landings})
    assert ("\n  2 skim(s) along the ground in one flight-mode step, where no friction acts (no hops): back_foot "
            "t = 0.285 s +0.194 m, front_foot t = 1.372 s +0.107 m") in marked.report()
    assert ("\n  2 landing(s) with no impact record, in steps that ran the clock (several contacts: "
            "docs/formulation.md, \"Partly frozen stance\"): back_foot t = 0.3961 s at 5.54 m/s (the clock ran 0.98 "
            "times the step's numerical length), front_foot t = 1.337 s at 4.9 m/s (the clock ran 1.4 times the step's "
            "numerical length)\n") in marked.report()
    assert marked.summary()["skims"] == skims and marked.summary()["unrecorded_landings"] == landings


def test_an_unrecorded_landings_clock_above_its_step_reads_as_a_rate_not_a_share():
    """A landing whose step ran the clock longer than the step's numerical length (clock_share 1.4: a stance step's
    clock rate or speed of time above 1) is reported as the clock running 1.4 times the step's numerical length, not
    as "140% of the step", which a tester read as a share that cannot exceed 100 % and so as a bug."""
    plan = _hop_plan()
    landing = {"point": "front_foot", "time": 1.337, "approach_mps": 4.9, "clock_share": 1.401}
    report = replace(plan, extra={**plan.extra, "unrecorded_landings": [landing]}).report()
    assert "front_foot t = 1.337 s at 4.9 m/s (the clock ran 1.4 times the step's numerical length)\n" in report
    assert "%" not in report.split("landing(s) with no impact record")[1].splitlines()[0]


def test_write_results_follows_the_contract(tmp_path):
    """trajectory.npz and summary.json carry the contract's keys with consistent shapes, the impacts
    as objects with time, contact, impulse; no temporary file is left behind. Trajectory.taps is computed once
    and read-only."""
    result = small_result()
    out = tmp_path / "out"
    write_results(result, out)
    assert sorted(p.name for p in out.iterdir()) == ["summary.json", "trajectory.npz"]
    with np.load(out / "trajectory.npz") as z:
        assert NPZ_KEYS <= set(z.files)
        K, ny = z["y"].shape
        P = len(z["t"])
        assert z["tau"].shape == (K,) and ny == 5
        assert z["q"].shape == (P, 2) and z["v"].shape == (P, 2) and z["u"].shape == (P, 2)
        np.testing.assert_allclose(z["y"][:, -1], result.trajectory.y[:, -1])
        assert len(z["impact_times"]) == 1
        # an impact is two samples at the same time
        assert np.sum(z["t"] == z["impact_times"][0]) == 2
    summary = json.loads((out / "summary.json").read_text())
    assert SUMMARY_KEYS <= set(summary)
    assert summary["command"] == "simulate" and summary["converged"] is True and summary["robot"].endswith("point_mass.xml")
    assert summary["terminal_error"] is None
    assert set(summary["impacts"][0]) >= {"time", "contact", "impulse"}
    assert summary["impacts"][0]["contact"] == "point" and summary["impacts"][0]["tap"] is False  # the only impact
    imp = result.trajectory.impacts[0]
    assert summary["impacts"][0]["impulse_norm"] == pytest.approx(np.hypot(imp.impulse, imp.impulse_tangential), abs=EXACT)
    assert summary["physical_duration_s"] == pytest.approx(result.trajectory.physical_duration)
    assert "impact" in result.report()
    taps = result.trajectory.taps  # computed once per trajectory, so read-only for every reader after the first
    assert taps is result.trajectory.taps and taps.tolist() == [False]
    with pytest.raises(ValueError):
        taps[0] = True


def test_read_task_is_the_task_the_plan_solved(tmp_path):
    """read_task returns trajectory.npz's task_json (the task solved, here with another N, as `--steps` makes it)
    over the task file summary.json names; without the copy, that file; a copy that is not a JSON object is an
    InputError naming task_json. read_robot loads the robot summary.json names."""
    task_file = tmp_path / "task.toml"
    shutil.copy(default_task_path(resolve_robot_path("point_mass")), task_file)
    on_file = load_task(task_file)
    solved = replace(on_file, horizon=replace(on_file.horizon, N=on_file.horizon.N + 3))
    (tmp_path / "summary.json").write_text(json.dumps({"robot": "point_mass", "task": str(task_file)}))
    for kept, expected in ((task_to_json(solved), solved.horizon.N), (None, on_file.horizon.N)):
        np.savez(tmp_path / "trajectory.npz", t=np.zeros(1), **({} if kept is None else {"task_json": np.array(kept)}))
        assert read_task(tmp_path).horizon.N == expected
    for garbled in ("{", "[1, 2]"):
        np.savez(tmp_path / "trajectory.npz", task_json=np.array(garbled))
        with pytest.raises(InputError, match="task_json"):
            read_task(tmp_path)
    assert read_robot(tmp_path, read_summary(tmp_path)).nq == load_robot("point_mass").nq


def test_taps_are_impacts_below_a_share_of_the_largest():
    """tap_flags marks an impulse norm below TAP_SHARE of the plan's largest (Capler's main-job plan: a 24.6 N s
    landing, a 2.0 N s hop, 0.1 N s taps), not one at the share, never the largest, and nothing when every impulse is
    zero."""
    assert tap_flags([24.6, 2.0, 0.1, TAP_SHARE * 24.6]).tolist() == [False, False, True, False]
    assert tap_flags([]).tolist() == [] and tap_flags([0.0, 0.0]).tolist() == [False, False]


def test_write_results_replaces_atomically(tmp_path):
    """Writing twice replaces the files in place (os.replace), leaving only the two result files; a file given as the
    directory is an InputError and is left as it was."""
    tr = Trajectory(tau=np.zeros(1), y=np.zeros((1, 3)), state_names=("q", "v", "t"), sigma=np.zeros((0, 0)),
                    selector_names=(), t=np.zeros(1), q=np.zeros((1, 1)), v=np.zeros((1, 1)), u=np.zeros((1, 0)))
    result = SimulationResult(robot="r", task="t.toml", trajectory=tr, stats=SolveStats(True, 0.0, 0, 0, 0.0), strategy="stepwise",
                              h=0.1, rho_f=1.0)
    write_results(result, tmp_path)
    write_results(result, tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["summary.json", "trajectory.npz"]
    assert json.loads((tmp_path / "summary.json").read_text())["impacts"] == []
    with pytest.raises(InputError, match="it is a file, not a directory"):  # a file where the directory should be stays
        write_results(result, tmp_path / "summary.json")
    assert json.loads((tmp_path / "summary.json").read_text())["impacts"] == []


def test_write_atomically_keeps_the_old_file_when_the_writer_fails(tmp_path):
    """A writer that raises half-way leaves the previous file byte for byte and no temporary file behind."""
    path = tmp_path / "results.json"
    write_atomically(path, '{"good": 1}\n')

    def crash(f):
        f.write(b'{"half')
        raise RuntimeError("crash while writing")

    with pytest.raises(RuntimeError):
        write_atomically(path, crash)
    assert path.read_text() == '{"good": 1}\n'
    assert [p.name for p in tmp_path.iterdir()] == ["results.json"]


def test_write_atomically_keeps_the_mode_and_takes_long_names(tmp_path):
    """A file replaced keeps its permission bits (`planner validate` made a private summary.json, mode 600,
    world-readable 644), a new file gets 666 minus the umask, and a name of 245 characters, which the file system takes,
    is written (its temp file, 14 characters longer, was refused as "File name too long")."""
    import stat

    path = tmp_path / "summary.json"
    write_atomically(path, "{}\n")
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask
    path.chmod(0o600)
    write_atomically(path, '{"validated": 1}\n')
    assert stat.S_IMODE(path.stat().st_mode) == 0o600 and path.read_text() == '{"validated": 1}\n'
    long = tmp_path / ("a" * 240 + ".html")
    write_atomically(long, "page")
    write_atomically(long, "page 2")
    assert long.read_text() == "page 2"
    assert not list(tmp_path.glob(".*.tmp"))
    undecodable = os.fsdecode(bytes(tmp_path) + b"/page\xff.html")  # a name the OS gives as surrogate escapes
    write_atomically(undecodable, "page")  # (measuring it as UTF-8 raised UnicodeEncodeError, a traceback)
    assert Path(undecodable).read_text() == "page"


def test_write_atomically_writes_through_a_symbolic_link(tmp_path):
    """A path that is a symbolic link (`view --html LINK`) keeps the link: its target gets the new file (the link was
    replaced by a file, the page it pointed at left stale)."""
    (tmp_path / "pages").mkdir()
    target, link = tmp_path / "pages" / "real.html", tmp_path / "link.html"
    target.write_text("old")
    link.symlink_to(Path("pages") / "real.html")
    write_atomically(link, "new")
    assert link.is_symlink() and target.read_text() == "new"


def _tiny_result(n: int = 1) -> SimulationResult:
    """A SimulationResult of n samples of a 1-DOF trajectory, to write."""
    tr = Trajectory(tau=np.zeros(n), y=np.zeros((n, 3)), state_names=("q", "v", "t"), sigma=np.zeros((0, 0)),
                    selector_names=(), t=np.arange(n, dtype=float), q=np.zeros((n, 1)), v=np.zeros((n, 1)), u=np.zeros((n, 0)))
    return SimulationResult(robot="r", task="t.toml", trajectory=tr, stats=SolveStats(True, 0.0, 0, 0, 0.0), strategy="stepwise",
                            h=0.1, rho_f=1.0)


def test_the_force_samples_skip_a_frozen_steps_clock_leak():
    """contact_force_samples reads a step as running when its clock ran more than FROZEN_TOL of it: a frozen impact
    step whose clock leaked 1e-7 s (IPOPT's tolerance; a biped landing's step ran 2e-6 of itself) gave the impact's
    post sample that step's force (99 N, the NLP's value there) instead of the force before and after the impact."""
    tau = np.array([0.0, 0.1, 0.2, 0.3])
    clock = np.array([0.0, 0.1, 0.1 + 1e-7, 0.2 + 1e-7])
    tr = Trajectory(tau=tau, y=np.column_stack([np.zeros(4), np.zeros(4), clock]), state_names=("q", "v", "t"),
                    sigma=np.zeros((3, 0)), selector_names=(), t=clock, q=np.zeros((4, 1)), v=np.zeros((4, 1)),
                    u=np.zeros((4, 0)), contact_force=np.array([[[10.0, 0.0]], [[99.0, 0.0]], [[20.0, 0.0]]]))
    lam_n, _ = tr.contact_force_samples()
    np.testing.assert_allclose(lam_n[:, 0], [10.0, 10.0, 10.0 + 1e-5, 20.0], rtol=1e-9)


def test_a_trajectory_of_arrays_that_disagree_in_length_is_refused():
    """A Trajectory whose physical-time samples (t, q, v, u) or grid (tau, y) differ in length is an InputError naming
    the lengths: one edited with dataclasses.replace (q shorter than t) was written and validated."""
    tr = _tiny_result(3).trajectory
    for change in ({"q": tr.q[:2]}, {"u": np.zeros((4, 0))}, {"y": tr.y[:1]}):
        with pytest.raises(InputError, match="a Trajectory's arrays must agree in length"):
            replace(tr, **change)

def test_a_simulation_report_names_a_penetration_beyond_a_millimetre():
    """A simulation whose contact went deeper than PENETRATION_NOTE_M into its plane says so in its report, with the
    point, the depth [mm] and the time (it said only "converged" with a fixed arm's tip 45.6 mm in the ground); a
    shallower one, or a result without the record (read from an older run), has no such line."""
    from planner.result import PENETRATION_NOTE_M

    deep = replace(_tiny_result(2), extra={"penetration": {"max_m": 0.0456, "point": "tip", "t": 0.5683}})
    assert "tip went 45.6 mm into its plane (t = 0.5683 s)" in deep.report()
    for extra in ({"penetration": {"max_m": PENETRATION_NOTE_M, "point": "tip", "t": 0.5}}, {}):
        assert "into its plane" not in replace(_tiny_result(2), extra=extra).report()


def test_a_persistent_force_outside_the_friction_cone_is_named():
    """forces_outside_cone lists each contact whose persistent force has |lambda_t| > CONE_SLACK mu lambda_n (+ a
    micronewton), with the number of samples, the largest tangential force outside and mu lambda_n there, and the
    simulation report prints a line for each (a brick on two corners was held by +-3641 N against 0.016 N of normal
    force, and the report said nothing). Inside the cone (|lambda_t| = mu lambda_n), on a frictionless contact, or
    without the task or the forces: nothing. A pulling normal force is named as one."""
    from planner.result import forces_outside_cone
    from planner.task import Contact

    tr = replace(_tiny_result(3).trajectory, y=np.column_stack([np.zeros((3, 2)), [0.0, 0.1, 0.2]]), t=np.array([0.0, 0.1, 0.2]),
                 contact_force=np.array([[[10.0, 5.0], [1.0, 9.0]], [[10.0, -7.5], [1.0, 9.0]]]))  # (steps, contacts, n/t)
    task = replace(load_task(default_task_path(resolve_robot_path("capler"))),
                   contacts=(Contact(point="foot", mu=0.5), Contact(point="knee", mu=0.0)))
    assert forces_outside_cone(tr, task) == [{"point": "foot", "samples": 1, "max_tangential_N": 7.5,
                                              "mu_normal_N": 5.0, "normal_N": 10.0}]
    assert forces_outside_cone(tr, None) == [] and forces_outside_cone(replace(tr, contact_force=None), task) == []
    flagged = replace(_tiny_result(3), trajectory=tr, extra={"forces_outside_friction_cone": forces_outside_cone(tr, task)})
    assert ("foot's contact force outside its friction cone at 1 of 3 samples (|tangential| up to 7.5 N where mu normal "
            "= 5 N)") in flagged.report()
    assert "friction cone" not in replace(flagged, extra={}).report()
    # a pulling normal force is said as such (it read "mu normal = 0 N" of -4.23 N, the bound clipped at 0)
    pulled = replace(tr, contact_force=np.array([[[-4.0, 5.0], [1.0, 9.0]], [[10.0, 1.0], [1.0, 9.0]]]))
    entry = forces_outside_cone(pulled, task)
    assert entry[0]["normal_N"] == -4.0 and entry[0]["mu_normal_N"] == 0.0
    pulling = replace(flagged, extra={"forces_outside_friction_cone": entry})
    assert "where the normal force pulls, -4 N)" in pulling.report()


def test_a_result_is_written_whole_or_not_at_all(tmp_path):
    """write_files writes both files before it renames either: a summary that cannot be written (a value JSON cannot
    hold), or a summary.json that is a directory, leaves the earlier trajectory.npz byte for byte and no temp file
    (the new npz replaced the old one, beside the old summary). Both files carry one result_id."""
    write_results(_tiny_result(2), tmp_path)
    npz = (tmp_path / "trajectory.npz").read_bytes()
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert str(np.load(tmp_path / "trajectory.npz")["result_id"]) == summary["result_id"]
    with pytest.raises(TypeError):
        write_files(tmp_path, {"t": np.zeros(5)}, {"bad": object()})
    assert (tmp_path / "trajectory.npz").read_bytes() == npz
    assert sorted(p.name for p in tmp_path.iterdir()) == ["summary.json", "trajectory.npz"]
    other = tmp_path / "other"
    (other / "summary.json").mkdir(parents=True)
    with pytest.raises(InputError, match="summary.json: it is a directory"):
        write_results(_tiny_result(3), other)
    assert not (other / "trajectory.npz").exists()


def test_a_rename_that_fails_rolls_back_the_ones_before_it(tmp_path, monkeypatch):
    """When the second rename fails (an immutable or foreign summary.json), the trajectory.npz already renamed is put
    back byte for byte, so the directory keeps the earlier result whole (it held the new npz beside the old summary:
    "files of two different results"); a refused path is an InputError (exit 2), a full disk a PlannerError that is not
    one (exit 1), and no temp file or kept link is left. Into an empty directory the rollback leaves it empty."""
    import errno
    import os

    from planner.errors import PlannerError

    write_results(_tiny_result(2), tmp_path)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    real = os.replace

    def failing(code):
        def replace(src, dst):
            if str(dst).endswith("summary.json") and str(src).endswith(".tmp"):
                raise OSError(code, os.strerror(code), str(dst))
            return real(src, dst)
        return replace

    for code, kind in ((errno.EPERM, InputError), (errno.ENOSPC, PlannerError)):
        monkeypatch.setattr(os, "replace", failing(code))
        with pytest.raises(kind, match=f"cannot write .*summary.json: {os.strerror(code)}") as caught:
            write_results(_tiny_result(3), tmp_path)
        assert (type(caught.value) is PlannerError) == (code == errno.ENOSPC)
        assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
    (tmp_path / "empty").mkdir()
    with pytest.raises(PlannerError):
        write_results(_tiny_result(3), tmp_path / "empty")
    assert list((tmp_path / "empty").iterdir()) == []


def test_a_result_is_not_renamed_into_a_directory_another_writer_holds(tmp_path):
    """write_files renames under the directory's lock (directory_lock, which write_validation holds from reading the
    summary to writing it back): a validation had written the old summary, plus its verdict, over a new result that
    landed in between. Here a thread holds the lock for HOLD_S; the write waits for it, and no lock file is left."""
    import threading
    import time

    from planner.result import directory_lock

    HOLD_S = 0.3  # long against a rename (microseconds), short for the suite
    write_results(_tiny_result(2), tmp_path)
    order = []

    def hold():
        with directory_lock(tmp_path):
            order.append("held")
            time.sleep(HOLD_S)
            order.append("released")

    holder = threading.Thread(target=hold)
    holder.start()
    while not order:
        time.sleep(0.01)
    write_results(_tiny_result(3), tmp_path)
    order.append("written")
    holder.join()
    assert order == ["held", "released", "written"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["summary.json", "trajectory.npz"]


def test_a_killed_writers_old_temp_file_is_removed_by_the_next_write(tmp_path):
    """A temp file a killed writer left (`.states.png.XXXX.tmp`: SIGKILL, or the plot process ended at exit) and
    older than STALE_TEMP_S is removed by the next write of the same file; a fresh one (a live writer's) and the temp
    files of other names stay. Nothing cleaned them before."""
    import os

    from planner.result import STALE_TEMP_S, write_atomically

    stale, fresh, other = (tmp_path / name for name in (".a.json.x1.tmp", ".a.json.x2.tmp", ".b.json.x3.tmp"))
    for p in (stale, fresh, other):
        p.write_text("half")
    old = os.stat(stale).st_mtime - 2 * STALE_TEMP_S
    for p in (stale, other):
        os.utime(p, (old, old))
    write_atomically(tmp_path / "a.json", "{}")
    assert sorted(p.name for p in tmp_path.iterdir()) == [".a.json.x2.tmp", ".b.json.x3.tmp", "a.json"]


def test_files_of_two_results_are_refused(tmp_path):
    """check_same_result refuses a summary.json and a trajectory.npz of two different writes (a run stopped between
    their renames: validate replayed the mix), also when only one of them has an id (a summary.json without its id
    beside another run's trajectory.npz was validated as one result); files of one write, and older files without
    ids, pass."""
    for name, n in (("a", 2), ("b", 3)):
        write_results(_tiny_result(n), tmp_path / name)
    a, b = (read_summary(tmp_path / name, require=()) for name in ("a", "b"))
    arrays = {name: dict(np.load(tmp_path / name / "trajectory.npz")) for name in ("a", "b")}
    check_same_result(tmp_path / "a", a, arrays["a"])
    no_id = {k: v for k, v in a.items() if k != "result_id"}
    check_same_result(tmp_path / "a", no_id, {k: v for k, v in arrays["b"].items() if k != "result_id"})
    for summary in (a, no_id):
        with pytest.raises(InputError, match="files of two different results"):
            check_same_result(tmp_path / "a", summary, arrays["b"])


def test_broken_result_files_are_input_errors(tmp_path):
    """A summary.json nested too deeply for Python's JSON reader (RecursionError), a FIFO named summary.json (reading
    it waited for a writer for ever) and a plan whose nlp_x is not numeric are InputErrors; a start of the same size
    but other variables says so (it read "291 against 291"); a directory whose run failed points at its failed/."""
    (tmp_path / "failed").mkdir()
    (tmp_path / "failed" / "summary.json").write_text("{}")
    with pytest.raises(InputError, match="a failed run's diagnostics are in .*failed"):
        read_summary(tmp_path)
    with pytest.raises(InputError, match="trajectory.npz not found; a failed run's diagnostics are in .*failed"):
        read_trajectory(tmp_path)  # (`plan --init DIR` reads it first: it said "not found" only)
    os.mkfifo(tmp_path / "summary.json")
    with pytest.raises(InputError, match="summary.json is not a regular file"):
        read_summary(tmp_path)
    (tmp_path / "summary.json").unlink()
    (tmp_path / "summary.json").write_text('{"robot": "r", "x": ' + "[" * 100000 + "]" * 100000 + "}")
    with pytest.raises(InputError, match="nested too deeply"):
        read_summary(tmp_path)
    arrays = {"nlp_x": np.array(["a", "b"]), "nlp_signature": np.array("sig")}
    with pytest.raises(InputError, match="nlp_x must hold numbers"):
        read_start(tmp_path, "sig", 2, arrays)
    with pytest.raises(InputError, match="variables 'other' against this problem's 'sig'"):
        read_start(tmp_path, "sig", 2, {"nlp_x": np.zeros(2), "nlp_signature": np.array("other")})


def test_written_files_have_the_umasks_mode_and_os_errors_are_input_errors(tmp_path):
    """A result file is readable by others as a plain open() would make it (0666 less the umask, not mkstemp's
    0600); a directory that cannot hold it (here: below a file) is an InputError naming the path, from
    write_atomically and from write_results alike, with no temporary file left."""
    import os

    umask = os.umask(0o022)
    try:
        path = tmp_path / "summary.json"
        write_atomically(path, "{}\n")
        assert path.stat().st_mode & 0o777 == 0o644
    finally:
        os.umask(umask)
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    with pytest.raises(InputError, match="cannot write .*a_file/x.json"):
        write_atomically(blocker / "x.json", "{}")
    robot = load_robot("point_mass")
    task = load_task(default_task_path(robot.path))
    result = simulate(robot, replace(task, horizon=replace(task.horizon, N=5)))
    with pytest.raises(InputError, match="cannot create output directory"):
        write_results(result, blocker / "out")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file", "summary.json"]


def test_a_result_id_is_a_string(tmp_path):
    """write_files refuses a result_id that is not a string before writing: an int 123 was written to summary.json and
    its readers, comparing it with the npz's '123', refused the directory as two results' files."""
    with pytest.raises(InputError, match="result_id must be a str or None, got int 123"):
        write_files(tmp_path / "out", {"t": np.zeros(2)}, {"command": "x"}, result_id=123)
    assert not (tmp_path / "out").exists()


def test_a_result_is_frozen_through_its_arrays(tmp_path):
    """A Trajectory's and an Impact's arrays are read-only (writing raises ValueError), so a result cannot be changed
    in place (`trajectory.t[0] = 123` changed physical_duration): not after `flags.writeable = True` on them or on
    their `.base`, nor in a pickled
    or deep-copied result (they came back writable, a cached `taps` too); the
    arrays the caller built stay writable and are not shared."""
    robot = load_robot("point_mass")
    result = simulate(robot, load_task(default_task_path(robot.path)))
    result.trajectory.taps  # cached before the copies: they restored it writable, and the summary reads it
    for tr in (result.trajectory, pickle.loads(pickle.dumps(result)).trajectory, copy.deepcopy(result).trajectory):
        assert tr.impacts
        for array in (tr.t, tr.q, tr.tau, tr.y, tr.impacts[0].v_post, tr.taps):
            with pytest.raises(ValueError, match="read-only"):
                array[0] = 123.0
            with pytest.raises(ValueError, match="WRITEABLE"):
                array.flags.writeable = True
            if array.base is not None:  # (an owning copy behind the view was made writable through it)
                with pytest.raises(ValueError, match="WRITEABLE"):
                    array.base.flags.writeable = True
    own = np.zeros(3)
    impact = replace(result.trajectory.impacts[0], q=own)
    own[0] = 1.0
    assert impact.q[0] == 0.0 and not impact.q.flags.writeable


def test_recover_ignores_a_frozen_sliver_of_numerical_time():
    """A FESD element 1e-4 of the longest (above result.COLLAPSED) whose clock leaks (advance 2e-11 s)
    is frozen by the per-step test, but a frozen run that stops the clock for less than frozen_tol of
    the longest step is no impact: its samples are kept as running ones. The real impact of the same
    trajectory is still found."""
    tau, y, u, dt, dv, imp = handmade()
    sliver = 1e-5  # [s] of numerical time; the FESD biped run had 2e-8 s against elements of 3.3e-3 s
    y = np.insert(y, 7, y[6] + [0.0, 0.0, 2e-11], axis=0)
    tau = np.insert(tau, 7, tau[6] + sliver)
    dt, u = np.insert(dt, 6, sliver), np.insert(u, 6, u[6], axis=0)
    dv, imp = np.insert(dv, 6, [1e-6], axis=0), np.insert(imp, 6, [[1e-6, 0.0]], axis=0)
    t, _, _, _, impacts = recover(tau, y, u, dt, dv, imp, 1, 1, ("foot",))
    assert [im.time for im in impacts] == pytest.approx([0.24], abs=EXACT)
    assert len(t) == 8  # the sliver's end is one more running sample


def test_a_complementarity_of_negative_zero_is_zero():
    """A complementarity residual of -0.0 (a product a * b with a = 0, b < 0) is stored as 0.0 in NLP records and solve
    stats: it printed as "complementarity -0.0e+00"."""
    from planner.result import NlpRecord

    record = NlpRecord("walk 1", 1.0, 1.0, 0.0, -0.0, 3, 0.1, "Solve_Succeeded", True, 0.0)
    assert f"{record.complementarity_residual:.1e}" == "0.0e+00"
    assert f"{SolveStats(True, 0.0, 1, 3, -0.0).complementarity_residual:.1e}" == "0.0e+00"


@pytest.mark.parametrize("name", ["SIGINT", "SIGHUP"])
def test_ctrl_c_waits_for_both_renames(tmp_path, monkeypatch, name):
    """A Ctrl-C (or a SIGHUP, which the CLI handles as one) that arrives while write_files renames its two files is
    held until both are renamed (it left a new trajectory.npz beside the earlier summary.json: files of two results),
    then raised; also with another thread alive, to which the kernel gives the signal when the main thread masks it
    (the mask held nothing then: this test failed in the full suite, which leaves threads behind)."""
    import os
    import signal
    import threading

    stop = threading.Event()
    other = threading.Thread(target=stop.wait, daemon=True)
    other.start()

    write_results(_tiny_result(2), tmp_path)
    real_replace = os.replace

    def interrupted(src, dst):
        real_replace(src, dst)
        os.kill(os.getpid(), getattr(signal, name))  # delivered between the two renames, were it not held

    monkeypatch.setattr(os, "replace", interrupted)
    # Python's Ctrl-C handler, also where the suite runs with SIGINT ignored (a background job of a script: CI)
    previous = signal.signal(getattr(signal, name), signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            write_results(_tiny_result(3), tmp_path)
    finally:
        signal.signal(getattr(signal, name), previous)
        stop.set()
    monkeypatch.setattr(os, "replace", real_replace)
    summary, arrays = read_summary(tmp_path, require=()), dict(np.load(tmp_path / "trajectory.npz"))
    check_same_result(tmp_path, summary, arrays)
    assert arrays["t"].size == 3 and sorted(p.name for p in tmp_path.iterdir()) == ["summary.json", "trajectory.npz"]


def test_the_race_line_says_a_stopped_arms_count_is_of_finished_nlps():
    """A stopped arm's iterations are those of its finished NLPs (planner.race counts them as they end), and the line
    says so: "default stopped (0 it, 17.1 s)" read as an arm that never iterated."""
    from planner.result import race_arms_text

    line = race_arms_text([{"arm": "default", "outcome": "stopped", "iterations": 0, "wall_s": 17.14},
                           {"arm": "alternate", "outcome": "won", "iterations": 2338, "wall_s": 17.1}])
    assert line == "default stopped (0 it in finished NLPs, 17.1 s), alternate won (2338 it, 17.1 s)"


# the slide's impact (docs/tasks.md, a_t row: 4.24 against 4.39 N s); a hundredth covers rounding of the two impulses
# and the simulator's tolerances, far from mu = 0.8 and 2, which the test tells apart
SLIDE_IMPULSE_RATIO, SLIDE_RATIO_TOL = 0.966, 0.01


def test_an_impact_outside_the_friction_cone_is_flagged():
    """An impact whose tangential impulse exceeds mu times its normal one is flagged in the report and in summary.json
    (`outside_friction_cone`): a simulation of a point mass thrown along the ground at 5 m/s (mu 0.8, a_t 80, a_n 100)
    ends its impact with 4.24 N s tangential against 4.39 N s normal, 0.97 of it (docs/tasks.md); with mu = 2 the
    same impact is inside the cone, and a frictionless contact has none to leave."""
    import dataclasses

    from planner.model import load_robot
    from planner.simulate import simulate

    robot = load_robot("point_mass")
    base = {"initial": {"q": [0.0, 1.0], "v": [5.0, 0.0]}, "horizon": {"tau_f": 0.8, "N": 80}}
    for mu, outside in ((0.8, True), (2.0, False)):
        task = parse_task({**base, "contacts": [{"point": "point", "mu": mu, "a_n": 100.0, "a_t": 80.0}]})
        result = simulate(robot, task)
        (imp,) = result.trajectory.impacts
        assert abs(imp.impulse_tangential) / imp.impulse == pytest.approx(SLIDE_IMPULSE_RATIO, abs=SLIDE_RATIO_TOL)
        assert result.summary()["impacts"][0]["outside_friction_cone"] is outside
        assert ("(outside the friction cone)" in result.report()) is outside
    frictionless = dataclasses.replace(task, contacts=(dataclasses.replace(task.contacts[0], mu=0.0, a_t=600.0),))
    assert simulate(robot, frictionless).summary()["impacts"][0]["outside_friction_cone"] is False


def test_an_impact_that_pulls_its_point_to_the_plane_is_said():
    """An impact with a negative normal impulse (a contact holding its point on the plane where it should lift off: a
    biped's stance foot took -16.7 N s next to the landing foot's +18.6, flagged only as outside the friction cone) is
    said on its line and in a line of its own; positive impulses are not."""
    import dataclasses

    from planner.result import _trajectory_lines

    tr = small_result().trajectory
    assert not any("pulls" in line or "negative normal" in line for line in _trajectory_lines(tr))
    (imp,) = tr.impacts
    pulled = dataclasses.replace(tr, impacts=(imp, dataclasses.replace(imp, impulse=-0.9 * imp.impulse)))
    lines = _trajectory_lines(pulled)
    assert lines[2].endswith("(pulls the point to its plane)") and "pulls" not in lines[1]
    assert lines[-1].startswith("  1 impact(s) with a negative normal impulse: the contact held its point on the plane")


def test_a_plan_of_a_task_edited_in_code_does_not_claim_its_file():
    """summary.json's task (and PlanResult.task) of a plan whose task was edited in code with dataclasses.replace,
    which keeps the file's source, is the file's absolute path followed by " (edited)": it named point_mass_hop.toml,
    whose target is 0.5 m, for a plan to 0.3 m. The task as its file holds it keeps the plain path (task_source)."""
    from planner.homotopy import solve
    from planner.problem import build_problem
    from planner.result import task_path
    from planner.task import EDITED, task_source

    on_file = load_task("point_mass_hop")
    # N = 10 keeps the solve short: an edit like the target's
    edited = replace(on_file, plan=replace(on_file.plan, target_q=(0.3, 0.0)), horizon=replace(on_file.horizon, N=10))
    path = str(Path(on_file.source).absolute())
    assert task_path(task_source(on_file)) == path
    marked = solve(build_problem(load_robot("point_mass"), edited), SolveOptions())
    assert marked.summary()["task"] == marked.task == path + EDITED


def _hop_plan():
    """A converged plan of the point mass's hop on 10 steps (~0.5 s): a PlanResult with every dict field filled."""
    from planner.homotopy import SolveOptions, solve
    from planner.problem import build_problem

    task = parse_task({"contacts": [{"point": "point", "mu": 0.5}], "initial": {"q": [0.0, 0.0]},
                       "horizon": {"tau_f": 1.0, "N": 10}, "plan": {"target_q": [0.5, 0.0], "u_bound": 30.0}})
    result = solve(build_problem(load_robot("point_mass"), task), SolveOptions())
    assert result.stats.converged, result.stats.message
    return result


DICT_WRITES = {  # each way of changing a dict in place
    "setitem": lambda d: d.__setitem__("new", 1), "delitem": lambda d: d.__delitem__(next(iter(d))),
    "update": lambda d: d.update(new=1), "pop": lambda d: d.pop(next(iter(d))), "popitem": lambda d: d.popitem(),
    "setdefault": lambda d: d.setdefault("new", 1), "clear": lambda d: d.clear(), "ior": lambda d: d.__ior__({"new": 1}),
}


def test_a_results_dicts_are_read_only_too():
    """A PlanResult's dict fields (extra, options, timings, constraint_violation) and a SimulationResult's extra, with
    the dicts and arrays inside them, cannot be changed in place: every dict write raises TypeError and the NLP point
    extra["_x"] is a read-only array (`result.extra["_x"][0] = 123` changed the nlp_x written and a replan's start,
    and any caller could add or drop summary.json's keys). So after pickle and copy.deepcopy. A changed copy is
    dataclasses.replace(result, extra={**result.extra, key: value}), itself read-only, the original unchanged."""
    plan = _hop_plan()
    simulation = replace(_tiny_result(2), extra={"discretization": {"name": "fesd"}, "_y": np.zeros(3)})
    for result, fields in ((plan, ("extra", "options", "timings", "constraint_violation")), (simulation, ("extra",))):
        for copied in (result, pickle.loads(pickle.dumps(result)), copy.deepcopy(result)):
            dicts = [getattr(copied, name) for name in fields]
            dicts += [v for d in dicts for v in d.values() if isinstance(v, dict)]  # nested: options["solve"], ...
            assert len(dicts) > len(fields)
            for d in dicts:
                before = dict(d)
                for name, write in DICT_WRITES.items():
                    with pytest.raises(TypeError, match="read-only"):
                        write(d)
                assert d == before
            arrays = [v for v in copied.extra.values() if isinstance(v, np.ndarray)]
            assert arrays
            for array in arrays:
                with pytest.raises(ValueError, match="read-only"):
                    array[0] = 123.0
    lists = [v for v in plan.extra.values() if isinstance(v, list)] + [plan.extra["scene"]["reasons"]]
    for listed in lists:  # summary.json's lists: extra["race"] of a raced plan, the scene's reasons
        for write in (lambda x: x.append(1), lambda x: x.__setitem__(0, 1), lambda x: x.extend([1]), lambda x: x.clear()):
            with pytest.raises(TypeError, match="read-only"):
                write(listed)
        assert listed == list(listed) and json.loads(json.dumps(listed)) == list(listed)
    changed = replace(plan, extra={**plan.extra, "k": 1})
    assert changed.extra["k"] == 1 and "k" not in plan.extra
    np.testing.assert_array_equal(changed.extra["_x"], plan.extra["_x"])
    with pytest.raises(TypeError, match="read-only"):
        changed.extra["k"] = 2
    with pytest.raises(ValueError, match="read-only"):
        changed.extra["_x"][0] = 123.0


def test_an_empty_output_directory_is_refused(tmp_path, monkeypatch):
    """write_results and write_files with out_dir "" raise an InputError and write nothing: Path("") is the working
    directory, where they wrote trajectory.npz and summary.json (an unset variable in a script's out_dir). "." still
    names the working directory."""
    monkeypatch.chdir(tmp_path)
    for write in (lambda: write_results(_tiny_result(2), ""), lambda: write_files("", {"t": np.zeros(2)}, {"command": "x"})):
        with pytest.raises(InputError, match=r"output directory is empty"):
            write()
    with pytest.raises(InputError, match=r"the output directory must be a str or PathLike, got NoneType"):
        write_results(_tiny_result(2), None)  # a TypeError from os.fspath before
    assert list(tmp_path.iterdir()) == []
    write_results(_tiny_result(2), ".")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["summary.json", "trajectory.npz"]


def _ending_in_an_impact(restitution: float) -> SimulationResult:
    """A hand-made drop whose horizon (tau 0 .. 0.3) ends inside its impact on "point" (frozen from tau = 0.1 on),
    with the task of a contact of that restitution in extra["_task"], as simulate() keeps it."""
    from planner.result import Impact

    n = 4
    tau = 0.1 * np.arange(n)
    tr = Trajectory(tau=tau, y=np.column_stack([np.zeros(n), np.zeros(n), [0.0, 0.1, 0.1, 0.1]]), state_names=("q", "v", "t"),
                    sigma=np.zeros((0, 0)), selector_names=(), t=np.array([0.0, 0.1, 0.1]), q=np.zeros((3, 1)),
                    v=np.array([[-1.0], [-1.0], [-0.2]]), u=np.zeros((3, 0)),
                    impacts=(Impact(time=0.1, contact="point", impulse=0.8, impulse_tangential=0.0, q=np.zeros(1),
                                    v_pre=np.array([-1.0]), v_post=np.array([-0.2]), tau_start=0.1, tau_end=tau[-1]),))
    task = parse_task({"contacts": [{"point": "point", "restitution": restitution}], "initial": {"q": [0.0, 0.3]},
                       "horizon": {"tau_f": 0.3, "N": 3}})
    return SimulationResult(robot="r", task="t.toml", trajectory=tr, stats=SolveStats(True, 0.0, 3, 9, 0.0),
                            strategy="stepwise", h=0.1, rho_f=1.0, extra={"_task": task})


def test_a_horizon_ending_inside_an_elastic_impact_names_zeno():
    """When the horizon ends inside the last impact and that impact's contact is elastic (restitution > 0), the report
    says the bounces may accumulate to a point in time (Zeno), which the time-freezing simulation does not pass, and
    that restitution = 0 makes the landing a stance: it advised only a longer tau_f or a larger a_n, which cannot end
    a Zeno sequence. An inelastic contact's report keeps the plain advice, without Zeno. A failed run's report says
    why it failed instead (it advised a longer tau_f for a step that did not converge)."""
    elastic, inelastic = _ending_in_an_impact(0.5), _ending_in_an_impact(0.0)
    assert elastic.ends_in_impact and inelastic.ends_in_impact
    assert "Zeno" in elastic.report() and "restitution = 0" in elastic.report()
    assert "the horizon ends inside the last impact" in inelastic.report()
    assert "Zeno" not in inelastic.report() and "restitution = 0" not in inelastic.report()
    # a run that failed stopped where its last node is: no horizon ended there, and the report says why it failed
    failed = replace(elastic, stats=SolveStats(False, 0.0, 3, 9, 0.0, message="step 3 did not converge"))
    assert not failed.ends_in_impact and "horizon ends" not in failed.report()
    assert failed.report().endswith("\n  step 3 did not converge")


def test_an_io_error_reading_trajectory_npz_is_the_machines_not_the_users(tmp_path, monkeypatch):
    """An I/O error reading trajectory.npz (EIO: a failing disk) is a PlannerError, exit 1, not an InputError (exit 2:
    the user's to fix), as errors.PATH_ERRNOS splits a write's errors; a refused path (EACCES) stays the user's."""
    import errno

    import planner.result as result
    from planner.errors import PlannerError

    np.savez(tmp_path / "trajectory.npz", t=np.zeros(2))
    for code, user_error in ((errno.EIO, False), (errno.EACCES, True)):
        def failing(*args, **kwargs):
            raise OSError(code, os.strerror(code))

        monkeypatch.setattr(result.np, "load", failing)
        with pytest.raises(PlannerError, match=f"trajectory.npz.*{os.strerror(code)}") as caught:
            result.read_trajectory(tmp_path)
        assert isinstance(caught.value, InputError) is user_error


def test_an_io_error_reading_any_input_file_is_the_machines(tmp_path, monkeypatch):
    """EIO reading summary.json, trajectory.npz, a task file or a robot file exits 1 (PlannerError);
    EACCES (a refused path) stays the user's error, of the reader's own kind (session 57's reviewer: only
    trajectory.npz was split)."""
    import errno
    from pathlib import Path as P

    from planner.errors import PlannerError, RobotFileError, TaskError
    from planner.model import detect_format
    from planner.result import read_summary, read_trajectory

    (tmp_path / "summary.json").write_text("{}")
    np.savez(tmp_path / "trajectory.npz", t=np.zeros(2))
    for code, user_error in ((errno.EIO, False), (errno.EACCES, True)):
        def failing(self, *args, **kwargs):
            raise OSError(code, os.strerror(code))

        monkeypatch.setattr(P, "read_text", failing)
        monkeypatch.setattr(P, "read_bytes", failing)
        readers = ((lambda: read_summary(tmp_path), InputError), (lambda: load_task(tmp_path / "t.toml"), TaskError),
                   (lambda: read_trajectory(tmp_path), InputError))  # (its zip check took EIO for "no zip archive")
        for call, kind in readers:
            with pytest.raises(PlannerError, match=os.strerror(code)) as caught:
                (tmp_path / "t.toml").touch()
                call()
            assert isinstance(caught.value, kind) is user_error
        monkeypatch.undo()
    import xml.etree.ElementTree as ET

    def eio(*args, **kwargs):
        raise OSError(errno.EIO, os.strerror(errno.EIO))

    (tmp_path / "robot.xml").write_text("<robot/>")  # (its size is read first)
    monkeypatch.setattr(ET, "parse", eio)
    with pytest.raises(PlannerError, match="cannot read robot file") as caught:
        detect_format(tmp_path / "robot.xml")
    assert not isinstance(caught.value, RobotFileError)


def test_summary_records_the_software_that_wrote_it(tmp_path, monkeypatch):
    """summary.json's `versions` names the planner, Python and the libraries that shape a plan, each as the imported
    module reports it (a hint-free plan reproduces only on the same CasADi), and a module that does not import is
    "not installed", not a crash."""
    import platform

    import casadi
    import mujoco
    import pinocchio

    import planner
    write_results(_tiny_result(2), tmp_path / "a")
    versions = json.loads((tmp_path / "a" / "summary.json").read_text())["versions"]
    assert versions == {"planner": planner.__version__, "python": platform.python_version(),
                        "casadi": casadi.__version__, "pinocchio": pinocchio.__version__, "mujoco": mujoco.__version__,
                        "numpy": np.__version__}
    monkeypatch.setattr("planner.result.VERSIONED", ("casadi", "no_such_module"))
    write_results(_tiny_result(2), tmp_path / "b")
    versions = json.loads((tmp_path / "b" / "summary.json").read_text())["versions"]
    assert versions["no_such_module"] == "not installed" and "mujoco" not in versions


def test_write_atomically_reads_the_umask_without_changing_it(tmp_path, monkeypatch):
    """write_atomically gives a new file the mode the umask allows without setting the umask (os.umask(0) and back
    left it 0 for a moment, and another thread's files came out world-writable): os.umask is not called on Linux."""
    import os
    import stat
    import sys

    from planner.result import write_atomically

    if not sys.platform.startswith("linux"):
        pytest.skip("/proc/self/status: Linux only")
    umask = os.umask(0o027)
    try:
        calls = []
        monkeypatch.setattr(os, "umask", lambda mask: calls.append(mask) or 0)
        write_atomically(tmp_path / "a.txt", "x")
        assert calls == [] and stat.S_IMODE((tmp_path / "a.txt").stat().st_mode) == 0o640
    finally:
        monkeypatch.undo()
        os.umask(umask)


def test_each_frozen_steps_impulse_is_in_exactly_one_impact():
    """Every frozen step's auxiliary impulse lands in exactly one impact (session 65's mutation testing found no test
    of either end of a frozen run): a horizon that ends inside an impact gives one impact with all of its impulse
    (3.5 N s, not 3.0 + 0.5 split at the last step), and landings at two consecutive nodes count each step's impulse
    once (their total, not a step's impulse in both impacts)."""
    tau, y, u, dt, dv, imp = handmade()
    *_, impacts = recover(tau[:6], y[:6], u[:5], dt[:5], dv[:5], imp[:5], 1, 1, ("foot",))
    assert [(i.impulse, i.tau_end) for i in impacts] == [pytest.approx((3.5, 0.5), abs=EXACT)]
    # 1-DoF (q, v, t): steps 1 and 2 both partly frozen landing steps (0.5 N s each), at consecutive nodes 1 and 2
    y2 = np.column_stack([[1.0, 0.9, 0.9, 0.9, 0.9], [-1.0, -1.0, -0.5, 0.0, 0.0], [0.0, 0.1, 0.15, 0.2, 0.3]])
    dv2 = np.array([[0.0], [0.5], [0.5], [0.0]])
    imp2 = dv2.reshape(4, 1, 1) * np.array([1.0, 0.0]).reshape(1, 1, 2)
    *_, impacts = recover(0.1 * np.arange(5), y2, np.zeros((4, 1)), np.full(4, 0.1), dv2, imp2, 1, 1, ("foot",),
                          landed=np.array([[False], [True], [True], [False]]))
    assert sum(i.impulse for i in impacts) == pytest.approx(imp2[:, 0, 0].sum(), abs=EXACT)


def test_taps_are_judged_by_the_impulse_norm():
    """A tap is an impact whose impulse norm (normal and tangential) is below TAP_SHARE of the largest, as the README
    says: an impact of 0.05 N s normal and 1 N s tangential is no tap beside one of 2 N s (judged by the normal part
    alone it was; session 65's mutation testing)."""
    trajectory = small_result().trajectory
    impact = trajectory.impacts[0]
    two = replace(trajectory, impacts=(replace(impact, impulse=2.0, impulse_tangential=0.0),
                                       replace(impact, impulse=0.05, impulse_tangential=1.0)))
    assert two.taps.tolist() == [False, False]


def _impact(impulse: float, tangential: float, contact: str = "point", pre: float = float("nan"),
            post: float = float("nan")) -> Impact:
    """A hand-made impact of a 1-DOF point (only its impulses, contact and energies are read here)."""
    return Impact(time=0.1, contact=contact, impulse=impulse, impulse_tangential=tangential, q=np.zeros(1),
                  v_pre=np.zeros(1), v_post=np.zeros(1), tau_start=0.1, tau_end=0.2, kinetic_energy_pre=pre,
                  kinetic_energy_post=post)


def test_an_impact_that_pulls_is_outside_the_friction_cone_at_any_tangential_impulse():
    """The friction cone of a normal impulse p_n is |p_t| <= mu max(p_n, 0): a contact cannot pull, so an impact with a
    negative normal impulse (a biped's stance foot held by -16.7 N s) and any tangential impulse is outside it
    (outside_cone's bound is mu max(p_n, 0), not mu |p_n|). Ground truth: with mu = 0.5, p_n = -2 and p_t = 0.5, the
    bound is 0 < 0.5 (outside), though 0.5 < mu |p_n| = 1; the same impact pushing (p_n = +2) is inside."""
    task = parse_task({"contacts": [{"point": "point", "mu": 0.5}], "initial": {"q": [0.0, 0.0]},
                       "horizon": {"tau_f": 1.0, "N": 10}})
    tr = SimpleNamespace(impacts=(_impact(-2.0, 0.5), _impact(2.0, 0.5), _impact(-2.0, 0.0)))
    assert outside_cone(tr, task).tolist() == [True, False, False]


def test_taps_are_measured_against_the_largest_impulse_not_the_mean():
    """A tap is an impact whose impulse norm is below TAP_SHARE of the largest one (result.TAP_SHARE's definition).
    Ground truth: with norms [10, 0.4 x 4] the largest is 10, so each 0.4 < 0.05 x 10 = 0.5 is a tap (their mean, 2.32,
    would make the bound 0.116 and none a tap); one impact alone is never a tap of itself."""
    assert TAP_SHARE == 0.05  # (the ground truth above is worked out for this share)
    assert tap_flags([10.0, 0.4, 0.4, 0.4, 0.4]).tolist() == [False, True, True, True, True]
    assert tap_flags([0.4]).tolist() == [False]


# the window in which "more than ENERGY_GAIN_SHARE of the larger energy" and "... of the energy before" disagree is
# (1 + s, 1 / (1 - s)) times the energy before, 1.0100-1.0101 for s = 1 %: a post-impact energy in its middle
GAIN_IN_WINDOW = 1.01005


def test_an_energy_gain_is_a_share_of_the_larger_energy():
    """Impact.gains_energy compares the gain with ENERGY_GAIN_SHARE of the larger of the two energies (its docstring):
    from 1 J to 1.01005 J the gain 0.01005 J is below 1 % of 1.01005 J (0.0101005 J), so it is no gain, though it is
    above 1 % of the energy before (0.01 J)."""
    assert ENERGY_GAIN_SHARE == 0.01
    assert 1.0 + ENERGY_GAIN_SHARE < GAIN_IN_WINDOW < 1.0 / (1.0 - ENERGY_GAIN_SHARE)
    assert _impact(1.0, 0.0, pre=1.0, post=GAIN_IN_WINDOW).gains_energy is False
    assert _impact(1.0, 0.0, pre=1.0, post=1.0 / (1.0 - ENERGY_GAIN_SHARE) + 1e-6).gains_energy is True


def test_a_hops_apex_is_above_its_takeoff_height_on_a_raised_ground():
    """Hop.apex is the highest point's height above the takeoff height (its field comment), wherever the ground is: a
    hop taking off from a ground at z = 0.3 m that peaks at z = 0.45 m has apex 0.15 m (not 0.45 m, the height above
    z = 0), and its distance is the x travel, 0.5 m."""
    clock = 0.1 * np.arange(5)
    traj = SimpleNamespace(y=clock[:, None], impacts=())
    xyz = np.zeros((5, 3))
    xyz[:, 2] = 0.3  # the ground's height
    xyz[2, 0], xyz[2, 2], xyz[3:, 0] = 0.25, 0.45, 0.5  # takes off at node 1, peaks at node 2, lands at node 3
    (hop,) = hops_of(traj, np.array([0, 1, 1, 0]), xyz)
    assert abs(hop.apex - 0.15) < EXACT and abs(hop.distance - 0.5) < EXACT


def test_a_cone_breach_names_the_largest_force_outside_the_cone_not_the_largest_force():
    """cone_breach's entry names the largest tangential force among the samples outside the cone, with its normal force:
    of a contact holding 10 N tangential under 100 N normal (inside, mu = 0.5: 50 N) and 1 N tangential with no normal
    force (outside), the breach is the 1 N one, where mu normal is 0 N; the 10 N sample, inside, is not named (the line
    "10 N where mu normal = 50 N" would call an inside force outside)."""
    from planner.result import cone_breach

    entry = cone_breach("foot", "samples", 0.5, np.array([10.0, 1.0]), np.array([100.0, 0.0]))
    assert entry == {"point": "foot", "samples": 1, "max_tangential_N": 1.0, "mu_normal_N": 0.0, "normal_N": 0.0}


def test_a_hop_whose_last_flight_node_is_on_the_plane_lands_at_its_impact():
    """hops_of dates a landing at the flight's impact when one lies after the takeoff and by the node that ends the
    landing step (LANDING_SLACK_S); only without an impact does a phase whose last node is on the plane land there. An
    impact exactly at that end node (implicit Euler's landing step ends at it) is the landing: 0.4 s here, not the last
    flight node's 0.3 s."""
    clock = 0.1 * np.arange(6)
    xyz = np.zeros((6, 3))
    xyz[:, 0] = 0.1 * np.arange(6)
    xyz[2, 2] = 0.05  # in the air at node 2 only: on the plane at node 3, the last flight node
    flight = np.array([0, 1, 1, 0, 0])
    without = SimpleNamespace(y=clock[:, None], impacts=())
    assert [h.landing_time for h in hops_of(without, flight, xyz, gap=xyz[:, 2])] == [clock[3]]
    with_impact = SimpleNamespace(y=clock[:, None], impacts=(SimpleNamespace(time=float(clock[4])),))
    (hop,) = hops_of(with_impact, flight, xyz, gap=xyz[:, 2])
    assert hop.landing_time == clock[4]


def test_a_vertical_hop_in_place_is_a_hop():
    """A flight phase is left out as no hop only when the point does not move (HOP_MIN_TRAVEL_M in any direction): a
    point that jumps 0.1 m straight up and lands where it took off is a hop of distance 0 and apex 0.1 m (its x alone
    does not move)."""
    clock = 0.1 * np.arange(5)
    traj = SimpleNamespace(y=clock[:, None], impacts=())
    xyz = np.zeros((5, 3))
    xyz[2, 2] = 0.1  # up at node 2, back down at node 3
    (hop,) = hops_of(traj, np.array([0, 1, 1, 0]), xyz)
    assert hop.distance == 0.0 and abs(hop.apex - 0.1) < EXACT


def test_the_npz_impact_impulses_are_the_normal_impulses(tmp_path):
    """trajectory.npz's impact_impulses hold each impact's normal impulse, as summary.json's impacts[i].impulse
    (docs/results.md: "the **normal** impulse of each impact only"), also for an impact with a tangential impulse: a
    point mass thrown along the ground at 5 m/s (mu 0.8) lands with about 4.4 N s normal and 4.2 N s tangential."""
    import json

    from planner.model import load_robot
    from planner.result import write_results
    from planner.simulate import simulate

    task = parse_task({"initial": {"q": [0.0, 1.0], "v": [5.0, 0.0]}, "horizon": {"tau_f": 0.8, "N": 80},
                       "contacts": [{"point": "point", "mu": 0.8, "a_n": 100.0, "a_t": 80.0}]})
    result = simulate(load_robot("point_mass"), task)
    (imp,) = result.trajectory.impacts
    assert abs(imp.impulse_tangential) > 0.5 * imp.impulse  # (the norm is far from the normal impulse)
    write_results(result, tmp_path / "throw")
    impulses = np.load(tmp_path / "throw" / "trajectory.npz")["impact_impulses"]
    said = json.loads((tmp_path / "throw" / "summary.json").read_text())["impacts"]
    assert impulses.tolist() == [i["impulse"] for i in said] == [imp.impulse]


def _report_of(*impacts, task=None) -> str:
    """The report lines (result._trajectory_lines) of a hand-made trajectory holding these impacts."""
    from planner.result import _trajectory_lines

    tr = SimpleNamespace(impacts=impacts, taps=tap_flags([i.impulse_norm for i in impacts]), physical_duration=1.0,
                         tau=np.array([0.0, 1.0]))
    return "\n".join(_trajectory_lines(tr, task=task))


def test_the_report_says_the_largest_energy_gain():
    """The line counting the impacts that gain kinetic energy gives the largest gain ("up to"): of gains +0.015 J and
    +0.5 J, +0.5 J."""
    report = _report_of(_impact(1.0, 0.0, pre=1.0, post=1.015), _impact(1.0, 0.0, pre=1.0, post=1.5))
    assert "2 impact(s) gain kinetic energy (up to +0.5 J)" in report


def test_the_report_counts_the_impacts_outside_the_friction_cone():
    """The friction-cone line counts the impacts outside the cone only: of two impacts with mu = 0.5, normal 1 N s, the
    one with tangential 0.9 N s is outside (0.9 > 1.01 x 0.5) and the one with 0.1 N s is not: 1 impact(s)."""
    task = parse_task({"contacts": [{"point": "point", "mu": 0.5}], "initial": {"q": [0.0, 0.0]},
                       "horizon": {"tau_f": 1.0, "N": 10}})
    report = _report_of(_impact(1.0, 0.9), _impact(1.0, 0.1), task=task)
    assert "\n  1 impact(s) outside the friction cone" in report


def test_the_report_counts_the_taps():
    """The headline counts the taps (impulse norm below TAP_SHARE of the largest): of norms 10, 0.2 and 3 N s one is
    a tap (0.2 < 0.5), so "3 impact(s) (1 tap(s): ...)"."""
    report = _report_of(_impact(10.0, 0.0), _impact(0.2, 0.0), _impact(3.0, 0.0))
    assert "; 3 impact(s) (1 tap(s): below 5% of the largest impulse, by norm)" in report


def test_a_pull_is_judged_against_the_largest_impulse_magnitude():
    """An impact pulls when its normal impulse is below -PULL_SHARE of the largest |normal impulse| (result.PULL_SHARE):
    with impulses +1, -20 and -0.005 N s the bound is -0.02 N s, so only the -20 N s impact pulls (against the largest
    signed impulse, +1, the -0.005 one would too)."""
    from planner.result import PULL_SHARE

    assert PULL_SHARE == 1e-3
    report = _report_of(_impact(1.0, 0.0), _impact(-20.0, 0.0), _impact(-0.005, 0.0))
    assert report.count("(pulls the point to its plane)") == 1 and "impulse -20 N s normal" in report
    assert "\n  1 impact(s) with a negative normal impulse" in report


def test_a_bare_task_name_in_a_summary_is_not_read_as_a_robot(tmp_path):
    """locate_input resolves a bare name (no suffix, no directory) to robots/ for a robot only (`capler` is
    robots/capler.xml); a task named `capler` that is not found is an InputError saying so, not robots/capler.xml read
    as a task file."""
    from planner.errors import InputError
    from planner.result import locate_input

    assert locate_input("capler", tmp_path, "robot").name == "capler.xml"
    with pytest.raises(InputError, match=r"the task file 'capler' named in .* was not found"):
        locate_input("capler", tmp_path, "task")


def test_a_start_point_that_is_not_finite_is_refused(tmp_path):
    """read_start refuses an NLP point with a nan or inf in it (a replan's IPOPT then starts from garbage): an
    InputError naming trajectory.npz; the same point made finite is returned as stored."""
    from planner.errors import InputError
    from planner.result import read_start

    x = np.linspace(0.0, 1.0, 5)
    for bad, expected in ((np.nan, False), (np.inf, False), (0.5, True)):
        stored = x.copy()
        stored[2] = bad
        arrays = {"nlp_x": stored, "nlp_signature": np.array("sig")}
        if expected:
            assert np.array_equal(read_start(tmp_path, "sig", 5, arrays), stored)
        else:
            with pytest.raises(InputError, match=r"the NLP point in .*trajectory.npz is not finite"):
                read_start(tmp_path, "sig", 5, arrays)


def test_a_start_with_only_one_of_its_two_arrays_holds_no_nlp_point(tmp_path):
    """A trajectory.npz with nlp_x but no nlp_signature, or the signature without the point (a plan of an older
    planner, or an edited file), holds no NLP point to start from: one InputError that says so, and an older plan's
    summary.json (command "plan") gets the older-planner hint (session 66's mutation testing: only a file without both
    refused, a KeyError traceback for one with one of them, with every test green)."""
    from planner.result import read_start

    (tmp_path / "summary.json").write_text(json.dumps({"command": "plan"}))
    for arrays in ({"nlp_x": np.zeros(5)}, {"nlp_signature": np.array("sig")}):
        with pytest.raises(InputError, match="holds no NLP point: the plan was written by an older planner"):
            read_start(tmp_path, "sig", 5, arrays)


def test_read_task_keeps_the_solved_task_when_given_the_read_files(tmp_path):
    """read_task given trajectory.npz's arrays and summary.json already read (as load_result and validate call it)
    still returns task_json's task, the one solved (here with another N, as `--steps` makes it), over the task file
    that summary.json names (session 66's mutation testing: the named file taken first when a summary is passed, a
    replay of an edited file's task, with every test green)."""
    task_file = tmp_path / "task.toml"
    shutil.copy(default_task_path(resolve_robot_path("point_mass")), task_file)
    on_file = load_task(task_file)
    solved = replace(on_file, horizon=replace(on_file.horizon, N=on_file.horizon.N + 3))
    (tmp_path / "summary.json").write_text(json.dumps({"robot": "point_mass", "task": str(task_file)}))
    np.savez(tmp_path / "trajectory.npz", t=np.zeros(1), task_json=np.array(task_to_json(solved)))
    task = read_task(tmp_path, read_trajectory(tmp_path), read_summary(tmp_path))
    assert task.horizon.N == solved.horizon.N != on_file.horizon.N


def test_an_input_named_in_a_summary_is_found_from_the_working_directory_first(tmp_path, monkeypatch):
    """locate_input reads a path summary.json names as written, from the working directory, before trying it relative
    to the result directory (as its docstring says): with a file of that name in both, the working directory's
    (session 66's mutation testing: the result directory's taken first, with every test green)."""
    from planner.result import locate_input

    out, cwd = tmp_path / "out", tmp_path / "cwd"
    for d in (out, cwd):
        (d / "robots").mkdir(parents=True)
        (d / "robots" / "r.xml").write_text(d.name)
    monkeypatch.chdir(cwd)
    assert locate_input("robots/r.xml", out, "robot").read_text() == "cwd"
    (cwd / "robots" / "r.xml").unlink()
    assert locate_input("robots/r.xml", out, "robot").read_text() == "out"


def test_a_joint_outside_its_range_of_an_older_summary_without_units_is_reported():
    """An older summary's joints_outside_range entries have no "unit" (results written before it was kept): the report
    line is written without one, the rest as for a new entry (session 66's mutation testing: the unit read as always
    present, a KeyError for an older result, with every test green)."""
    from planner.result import outside_range_lines

    entry = {"joint": "x", "nodes": 3, "farthest": 1.5, "lower": -1.0, "upper": 1.0}
    (old,) = outside_range_lines({"joints_outside_range": [entry]}, 10, "why")
    (new,) = outside_range_lines({"joints_outside_range": [entry | {"unit": "m"}]}, 10, "why")
    assert old == new.replace("[-1, 1] m", "[-1, 1]") and "[-1, 1] at 3 of 10 nodes (to 1.5)" in old


def test_clock_goes_back_names_the_largest_fall_and_counts_the_others():
    """clock_goes_back says where a result's physical time falls most (by how much, from and to which time, at which
    sample) and how many other samples fall, and "" for a clock that never falls (repeats are no fall)."""
    from planner.result import clock_goes_back
    assert clock_goes_back(np.array([0.0, 0.1, 0.1, 0.2])) == ""
    t = np.array([0.0, 0.5, 0.4, 0.6, 0.1, 0.2, 0.15])
    assert clock_goes_back(t) == "t falls by 0.5 s, from 0.6 s to 0.1 s at sample 4, and falls at 2 more sample(s)"
