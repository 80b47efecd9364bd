"""planner.replan: a replan that holds the start plan's contact schedule, walked through the tasks between."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import planner.homotopy as H
import planner.replan as R
from planner.errors import InputError
from planner.model import load_robot
from planner.problem import ProblemOptions, build_problem
from planner.replan import replan

from test_problem import hop_task

TERMINAL_TOL = 1e-6  # SolveOptions.terminal_tol, the verdict's
# How far the held schedule reaches in these tests [m]: a held-schedule NLP whose target is further than this from
# where its start ends is refused, as Capler's 3.0 -> 3.1 m is (the point-mass hop's own NLP reaches further)
BASIN = 0.06


@pytest.fixture(scope="module")
def hop_plan():
    """The point-mass hop to x = 0.5 m (N = 20), planned hint-free: (problem, its plan's NLP point)."""
    prob = build_problem(load_robot("robots/point_mass.xml"), hop_task(N=20))
    res = H.solve(prob, H.SolveOptions())
    assert res.stats.converged, res.stats.message
    return prob, res.nlp_point(prob)


@pytest.fixture
def basin(monkeypatch):
    """The held schedule refused beyond BASIN of its start's end."""
    real = H._keep_schedule

    def held(problem, solvers, options, x0, records, progress):
        x = real(problem, solvers, options, x0, records, progress)
        end = problem.split(x0)["Y"][-1][0]
        return x if abs(problem.task.plan.target_q[0] - end) <= BASIN else None

    monkeypatch.setattr(H, "_keep_schedule", held)


def _moved(prob, x0, target_x: float):
    task = dataclasses.replace(prob.task, plan=dataclasses.replace(prob.task.plan, target_q=(target_x, 0.0)))
    return dataclasses.replace(build_problem(prob.robot, task), x0=x0)


def test_walk_reaches_the_task_through_the_one_halfway(hop_plan, basin):
    """The hop moved 0.5 -> 0.6 m with a held schedule that reaches 0.06 m: the direct one is refused, the walk's
    task halfway (0.55 m) and then the task itself are accepted. The result is the task's converged, exactly
    complementary plan at its target; its records are the three NLPs in order, and its iterations their sum; its
    options say keep_schedule."""
    prob, x0 = hop_plan
    seen = []
    res = replan(_moved(prob, x0, 0.6), H.replan_options(), prob.task, progress=seen.append)
    assert res.stats.converged, res.stats.message
    assert [r.label for r in res.nlps] == [r.label for r in seen] == ["schedule", "walk 0.5", "walk 1"]
    assert res.extra["walk"] == [0.5, 1.0]
    assert res.stats.complementarity_residual == 0.0 and res.terminal_error <= TERMINAL_TOL
    assert res.trajectory.q[-1, 0] == pytest.approx(0.6, abs=TERMINAL_TOL)
    # what ran first is recorded, as the CLI records it (keep_schedule false was recorded for the held schedule)
    assert res.options["solve"]["keep_schedule"] is True
    assert (res.stats.n_nlp, res.stats.ipopt_iterations) == (3, sum(r.iterations for r in res.nlps))
    assert res.timings["ipopt_s"] == pytest.approx(sum(r.time_s for r in res.nlps))


def test_the_homotopy_settings_do_not_stop_the_walk(hop_plan, basin):
    """Tasks that differ in plan.homotopy (n_nlp 6 against 5: integers, not numbers a walk moves) besides the target
    are walked: the homotopy's settings are the solve's, which the held schedule does not read (the walk was refused,
    "the two tasks differ in 'plan.homotopy.n_nlp'", and the penalty replan ran instead)."""
    prob, x0 = hop_plan
    moved = _moved(prob, x0, 0.6)
    task = dataclasses.replace(moved.task, plan=dataclasses.replace(
        moved.task.plan, homotopy=dataclasses.replace(moved.task.plan.homotopy, n_nlp=6)))
    res = replan(dataclasses.replace(build_problem(prob.robot, task), x0=x0), H.replan_options(), prob.task)
    assert res.stats.converged and "no_walk" not in res.extra, res.extra.get("no_walk")
    assert [r.label for r in res.nlps] == ["schedule", "walk 0.5", "walk 1"]


def test_a_plan_in_memory_gives_its_nlp_point_to_a_problem_of_the_same_variables(hop_plan):
    """PlanResult.nlp_point(problem) is the plan's NLP point (what trajectory.npz's nlp_x keeps for --init), a copy,
    for a problem of the same variables (the moved task's, or one whose only other option is the clock's default
    guess); one of other variables (N = 10) or other options (switch_scale) is an InputError naming why (the point
    was only in the private result.extra["_x"])."""
    prob, x0 = hop_plan
    res = H.solve(dataclasses.replace(prob, x0=x0), H.replan_options())
    point = res.nlp_point(_moved(prob, x0, 0.55))
    np.testing.assert_array_equal(point, res.extra["_x"])
    point[0] += 1.0
    assert res.nlp_point(prob)[0] == res.extra["_x"][0]
    with pytest.raises(InputError, match="are not those of the problem .*same robot, contacts, N"):
        res.nlp_point(build_problem(prob.robot, hop_task(N=10)))
    # the same variables under other options: lambda0, lambda1 in other units (they had been taken as a start)
    with pytest.raises(InputError, match="are not those of the problem"):
        res.nlp_point(build_problem(prob.robot, prob.task, ProblemOptions(switch_scale=(("c(q)", 100.0),))))
    guessed = build_problem(prob.robot, prob.task, ProblemOptions(clock_guess_running=True))  # the guess only
    np.testing.assert_array_equal(res.nlp_point(guessed), res.extra["_x"])


def _steps(res) -> list[str]:
    """The replan's stages in order: each held schedule's label, each re-timing once ("retime t")."""
    heads = [r.label.split(":")[0] for r in res.nlps]
    return [h for i, h in enumerate(heads) if i == 0 or h != heads[i - 1] or h.startswith("walk")]


def test_a_stalled_walk_retimes_with_the_penalty_replan(hop_plan, basin, monkeypatch):
    """0.5 -> 0.8 m with that held schedule: the walk halves its step after each refusal and doubles it after each
    acceptance (0.5, 0.25 refused, 0.125 accepted, 0.375 refused, 0.25 accepted, 0.5 refused); after MAX_REFUSALS + 1
    refusals the penalty replan takes the refused task (0.5) from the walk's last plan, and the walk goes on from
    its plan, the rest of the way at once, until a second stall is re-timed at the task itself. The plan
    converges at 0.8 m. Each re-timing's NLPs are capped at RETIME_MAX_ITER iterations, or the options' max_iter if
    lower (session 66's mutation testing: they ran to max_iter 3000, a failing re-timing's ~300 s on Capler, with every
    test green)."""
    prob, x0 = hop_plan
    retimings, real = [], R.solve

    def solve(problem, options, progress=None):
        if not options.keep_schedule:  # (the walk's held schedules keep it; a re-timing is the penalty replan)
            retimings.append(options.max_iter)
        return real(problem, options, progress)

    monkeypatch.setattr(R, "solve", solve)
    res = replan(_moved(prob, x0, 0.8), H.replan_options(), prob.task)
    assert retimings == [min(H.replan_options().max_iter, R.RETIME_MAX_ITER)] * 2
    assert _steps(res) == ["schedule", "walk 0.5", "walk 0.25", "walk 0.125", "walk 0.375", "walk 0.25", "walk 0.5", "retime 0.5",
                           "walk 1", "walk 0.75", "walk 0.625", "walk 0.875", "walk 0.75", "walk 1", "retime 1"]
    assert res.extra["walk"] == [0.125, 0.25, 0.5, 0.625, 0.75, 1.0]
    assert res.stats.converged and res.terminal_error <= TERMINAL_TOL
    assert res.trajectory.q[-1, 0] == pytest.approx(0.8, abs=TERMINAL_TOL)


def test_without_a_walk_the_penalty_replan_starts_from_the_plan(hop_plan, basin, monkeypatch):
    """When the walk may not re-time (MAX_RETIMINGS = 0) its first stall ends it, and the penalty replan runs from
    the start plan: the same plan as a replan without the start's task (no walk at all), and as one whose held
    schedule may add impacts (schedule_new_impacts: the penalty replan runs without it)."""
    prob, x0 = hop_plan
    monkeypatch.setattr(R, "MAX_RETIMINGS", 0)
    moved = _moved(prob, x0, 0.8)
    res = replan(moved, H.replan_options(), prob.task)
    assert _steps(res)[:8] == ["schedule", "walk 0.5", "walk 0.25", "walk 0.125", "walk 0.375", "walk 0.25", "walk 0.5", "homotopy 1"]
    assert "walk" not in res.extra and res.stats.converged
    plain = replan(moved, H.replan_options())
    assert _steps(plain)[:2] == ["schedule", "homotopy 1"]
    np.testing.assert_array_equal(plain.extra["_x"], res.extra["_x"])
    tapped = replan(moved, dataclasses.replace(H.replan_options(), keep_schedule=True, schedule_new_impacts=True))
    assert _steps(tapped) == _steps(plain)
    np.testing.assert_array_equal(tapped.extra["_x"], plain.extra["_x"])
    # a start task that differs in more than numbers (here N) has no walk, and the result says why (it was silent)
    apart = dataclasses.replace(prob.task, horizon=dataclasses.replace(prob.task.horizon, N=prob.task.horizon.N + 1))
    unwalked = replan(moved, H.replan_options(), apart)
    assert _steps(unwalked) == _steps(plain)
    assert "differ in 'horizon.N' by more than a finite number's change" in unwalked.extra["no_walk"]
    assert "(no walk from the start's task" in unwalked.report() and "no_walk" not in plain.extra


def test_schedule_only_stops_after_the_held_schedule(hop_plan):
    """SolveOptions.schedule_only: a refused held schedule (IPOPT capped at one iteration) ends the solve, not
    converged, with the start as its point; without keep_schedule the option is refused."""
    prob, x0 = hop_plan
    moved = _moved(prob, x0, 0.6)
    options = dataclasses.replace(H.replan_options(), keep_schedule=True, schedule_only=True, schedule_max_iter=1)
    res = H.solve(moved, options)
    assert [r.label for r in res.nlps] == ["schedule"] and not res.stats.converged
    assert "held-schedule NLP was not accepted" in res.stats.message
    np.testing.assert_array_equal(res.extra["_x"], H.ungate(moved, x0) if "gates" in moved.notes else x0)
    with pytest.raises(InputError, match="schedule_only"):
        H.SolveOptions(schedule_only=True)


def test_a_walk_that_was_retimed_does_not_say_the_start_schedule_was_kept(hop_plan):
    """A walk whose last, held-schedule NLP follows a re-timing (a penalty replan on the way) ends on the re-timed
    schedule, not on the start's: its message says so (it said "the start's contact schedule kept", from the last
    NLP's label); one that ends on a re-timing says it after that NLP's message (it said "ok (active-set polished, ..)"
    only). A walk of held schedules only keeps that message. The report's last line is that message."""
    prob, x0 = hop_plan
    held = replan(_moved(prob, x0, 0.52), H.replan_options(), prob.task)
    assert held.stats.converged and held.stats.message == "ok" + H.SCHEDULE_KEPT

    def labelled(label, walk):
        return dataclasses.replace(held, nlps=tuple(dataclasses.replace(r, label=label) for r in held.nlps),
                                   extra={**held.extra, "walk": walk})

    walk = labelled("walk 1", (0.5, 1.0))
    retimed = R._totals(walk, [labelled("retime 0.5: reoptimize", (0.0, 0.5)), walk], 1.0, H.replan_options())
    assert retimed.stats.message == "ok (walked there: the contact schedule re-timed by a penalty replan on the way)"
    polished = dataclasses.replace(walk, stats=dataclasses.replace(walk.stats, message="ok (active-set polished)"))
    last = R._totals(polished, [walk, labelled("retime 1: homotopy 1", (0.5, 1.0))], 1.0, H.replan_options())
    assert last.stats.message == "ok (active-set polished); walked there, re-timing the contact schedule last"
    kept = R._totals(walk, [labelled("walk 0.5", (0.0, 0.5)), walk], 1.0, H.replan_options())
    assert kept.stats.message == held.stats.message
    # the report says it too (only summary.json did): how the plan's schedule came about
    assert held.report().splitlines()[-1] == "  ok" + H.SCHEDULE_KEPT
    assert retimed.report().splitlines()[-1] == "  " + retimed.stats.message


def test_a_task_between_that_cannot_be_built_ends_the_walk_not_the_replan(hop_plan, basin, monkeypatch):
    """A task between the start's and the new one that build_problem refuses (its target inside a hole, which a target
    moved across the hole passes through) ends the walk, said in no_walk, and the penalty replan runs: it raised the
    InputError, exit 2, naming a target the user never gave. The result records the options the replan was given,
    not its last part's (a re-timing's max_iter 600, or schedule_only)."""
    prob, x0 = hop_plan
    real = R.build_problem

    def refused(robot, task, *args, **kw):
        raise InputError("plan.target_q puts contact point 'point' inside plan.holes[0]")

    monkeypatch.setattr(R, "build_problem", refused)
    given = dataclasses.replace(H.replan_options(), max_iter=2500)
    res = replan(_moved(prob, x0, 0.8), given, prob.task)
    monkeypatch.setattr(R, "build_problem", real)
    assert "the task 0.5 of the way there is refused (plan.target_q puts" in res.extra["no_walk"]
    assert _steps(res)[:2] == ["schedule", "homotopy 1"]
    assert res.options["solve"]["max_iter"] == 2500 and res.options["solve"]["schedule_only"] is False


def test_a_problem_still_at_its_hint_free_guess_is_no_start(hop_plan):
    """replan's problem.x0 must be a plan (README: dataclasses.replace(problem, x0=result.nlp_point(problem))): the
    hint-free guess build_problem gives is refused, naming the fix (it held the guess's "schedules", each to its cap,
    then re-timed for 1229 iterations and said "walked there")."""
    prob, x0 = hop_plan
    fresh = build_problem(prob.robot, prob.task)
    with pytest.raises(InputError, match=r"problem.x0 is build_problem's hint-free guess, not a plan of start_task: "
                                         r"give it the plan's NLP point"):
        replan(fresh, H.replan_options(), prob.task)
    assert replan(dataclasses.replace(fresh, x0=x0), H.replan_options(), prob.task).stats.converged


def test_an_edited_problem_or_the_same_task_is_not_walked(hop_plan, basin):
    """A problem edited after build_problem (a bound) is not walked from the start's task: the tasks between would be
    built without the edit (each walk step solved the unedited problem), so no_walk says so and the penalty replan
    runs on the edited problem; a start task equal to the task is not walked either (every task between is it)."""
    prob, x0 = hop_plan
    moved = _moved(prob, x0, 0.6)
    edited = dataclasses.replace(moved, ubx=moved.ubx.copy())
    edited.ubx[edited.var_names.index("q[z]_10")] = 0.2  # [m] a ceiling at node 10
    assert edited.edited == ("ubx",) and moved.edited == ()
    res = replan(edited, H.replan_options(), prob.task)
    assert "the problem's ubx were edited after build_problem" in res.extra["no_walk"], res.extra.get("no_walk")
    assert [r.label for r in res.nlps][:2] == ["schedule", "homotopy 1"] and "walk" not in res.extra
    assert res.stats.converged and res.extra["edited_problem"] == ["ubx"]
    assert res.nlp_point(edited)[edited.var_names.index("q[z]_10")] <= 0.2 + TERMINAL_TOL
    # (a start task read back from a plan's trajectory.npz names that file as its source: it was walked between
    # tasks all equal to this one, 19 NLPs instead of 4)
    same = replan(moved, H.replan_options(), dataclasses.replace(moved.task, source="elsewhere/trajectory.npz"))
    assert same.extra["no_walk"].startswith("no walk from the start's task: the start's task is this task")
    # (nor its [simulate] table, which a plan does not read: it walked through tasks all equal to this one's plan)
    simulated = dataclasses.replace(moved.task, simulate=dataclasses.replace(moved.task.simulate, rho_f=2.0))
    same = replan(moved, H.replan_options(), simulated)
    assert same.extra["no_walk"].startswith("no walk from the start's task: the start's task is this task")


def test_a_task_between_of_other_nlp_variables_ends_the_walk_not_the_replan(hop_plan, basin, monkeypatch):
    """A task between whose problem has another Problem.signature than the task's (here built with another
    switch_scale: the same number of variables in other units, which a start x could be solved from without an
    error) is not solved from the walk's point: the walk ends there, no_walk names the fraction of the way, and the
    penalty replan runs (session 66's mutation testing: the signature compared at the task itself only, and the
    walk's step solved in the wrong units, with every test green)."""
    prob, x0 = hop_plan
    real = R.build_problem

    def rescaled(robot, task, options, **kw):
        return real(robot, task, dataclasses.replace(options, switch_scale=(("c(q)", 100.0),)), **kw)

    monkeypatch.setattr(R, "build_problem", rescaled)
    res = replan(_moved(prob, x0, 0.6), H.replan_options(), prob.task)
    monkeypatch.setattr(R, "build_problem", real)
    no_walk = res.extra.get("no_walk", "")
    assert "the task 0.5 of the way there has other NLP variables" in no_walk, res.extra.get("walk")
    assert _steps(res)[:2] == ["schedule", "homotopy 1"] and "walk" not in res.extra
    assert res.stats.converged, res.stats.message
