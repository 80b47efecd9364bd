"""Replanning from a plan with its contact schedule held, walked from the plan's task to the new one.

`planner plan --init DIR` starts the new task's NLP from DIR's plan. The held-schedule NLP
(SolveOptions.keep_schedule: one smooth NLP, the plan's impacts on their steps) converges in tens of
iterations when the task moved a little (Capler's target 3.0 -> 3.1 m: 26; 3.4 m: 131, session 41), and is refused when it
moved more: it does not converge, or its plan adds an impact (the biped's step 0.25 -> 0.28 m: the stance foot's at
the period's start; taps below result.TAP_SHARE are not refused), after which the penalty replan from DIR's
plan may not converge. Through tasks between (tasks_between: every number of the task file linear from DIR's task
to the new one), each held-schedule NLP starts next to its answer, and where the schedule must change a re-timing
changes it there: the biped's step 0.28-0.32 m in 6-13 s, Capler's target 3.2 m in 25 s before taps were accepted
(docs/benchmarks.md, "Replanning", sessions 27-29).

The walk halves its step after a held schedule that is refused and doubles it after one that is accepted.
Where it stalls (MAX_REFUSALS, MIN_STEP) the schedule has to change: the penalty replan (which may move the
impacts) runs for the refused task from the walk's last plan (RETIME_MAX_ITER iterations per NLP), and the walk
goes on from its plan (at most MAX_RETIMINGS times). When that fails too, the penalty replan runs from DIR's plan,
as without the walk.
"""
from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from .errors import InputError, expect, options_record
from .homotopy import SCHEDULE_KEPT, SolveOptions, solve
from .problem import Problem, build_problem
from .result import PlanResult
from .task import Task, tasks_apart, tasks_between

FIRST_STEP = 0.5  # the walk's first task is halfway: the whole way was just tried
MIN_STEP = 0.125  # the walk stalls below this step: each refused held schedule costs up to schedule_max_iter iterations (20-135 on Capler)
MAX_REFUSALS = 3  # refused held schedules between stalls
MAX_RETIMINGS = 2  # penalty replans inside the walk (Capler 3.0 -> 3.3 m needed one)
# IPOPT iterations per NLP of a re-timing: the ones that converged took 112-469 (Capler, the biped), one that failed
# took 3000, 3000, 3000 and 2103 in its four NLPs (Capler 3.1 -> 3.15 m, 300 s) before the penalty replan from DIR's plan
RETIME_MAX_ITER = 600
SAME_TASK = "the start's task is this task"  # extra["no_walk"]'s reason when there is nothing to walk


def replan(problem: Problem, options: SolveOptions, start_task: Task | None = None, progress=None) -> PlanResult:
    """The plan of problem.task from problem.x0, a plan of start_task with the same Problem.signature.

    First the held-schedule NLP for problem.task (options with keep_schedule and schedule_only). If it is
    refused and start_task is given: the walk through tasks_between(start_task, problem.task, s), s = 0.5, ...,
    1 (its held-schedule NLPs labelled "walk s", its penalty replans "retime s: <NLP>"). If there is no walk or it
    fails: the penalty replan from problem.x0 (`solve` with options as given, keep_schedule off). The result's
    nlps, iterations, solve time and timings cover every NLP run; extra["walk"] lists the fractions of the way
    each accepted step of the walk reached, extra["no_walk"] says why there was no walk (tasks that differ in more
    than numbers, or other NLP variables between them, the same task, or a problem edited after build_problem,
    Problem.edited). progress(record) as in `solve`.
    """
    expect(problem, Problem, "replan's problem")
    expect(options, SolveOptions, "replan's options")
    expect(start_task, (Task, type(None)), "replan's start_task")
    guess = problem.notes.get("hint_free_x0")
    if guess is not None and np.array_equal(np.asarray(problem.x0, float), guess):  # (it held the guess's
        # "schedules", each to its cap, then re-timed, and said "walked there")
        raise InputError("replan's problem.x0 is build_problem's hint-free guess, not a plan of start_task: give it "
                         "the plan's NLP point, dataclasses.replace(problem, x0=result.nlp_point(problem)) (README)")
    options = replace(options, keep_schedule=True)  # what runs first, recorded so (as the CLI's; False was recorded)
    start = time.perf_counter()
    held = replace(options, keep_schedule=True, schedule_only=True)
    penalty = replace(options, keep_schedule=False, schedule_only=False, schedule_new_impacts=False)
    parts = [solve(problem, held, progress)]
    result = parts[-1]
    no_walk = None
    if not result.stats.converged and start_task is not None:
        if start_task.plan is not None and problem.task.plan is not None:
            # the homotopy's settings are the solve's, not the scene's: the walk solves with the task's own (the
            # start's n_nlp 5 against the task's 6 had refused the walk, though the held schedule reads neither)
            start_task = replace(start_task, plan=replace(start_task.plan, homotopy=problem.task.plan.homotopy),
                                 simulate=problem.task.simulate)  # (nor the [simulate] table: a plan reads none)
        apart = tasks_apart(start_task, problem.task)
        if problem.edited:  # (the tasks between are built afresh: each walk step solved the unedited problem)
            no_walk = (f"the problem's {', '.join(problem.edited)} were edited after build_problem, and the tasks "
                       "between would be built without the edits")
        elif start_task == problem.task:  # (every task between is this one: the walk repeated the held schedule)
            no_walk = SAME_TASK
        elif apart is None:
            walked, no_walk = _walk(problem, held, penalty, start_task, parts, progress)
            if walked is not None:
                return _totals(walked, parts, time.perf_counter() - start, options)
        else:  # said: the --init help promises a walk
            no_walk = f"the two tasks differ in {apart!r} by more than a finite number's change"  # (inf too)
    if no_walk:
        no_walk = f"no walk from the start's task: {no_walk}; the penalty replan instead"
    if not result.stats.converged:
        result = solve(problem, penalty, progress)
        parts.append(result)
    result = _totals(result, parts, time.perf_counter() - start, options)
    return replace(result, extra={**result.extra, "no_walk": no_walk}) if no_walk else result


def _walk(problem: Problem, held: SolveOptions, penalty: SolveOptions, start_task: Task, parts: list[PlanResult],
          progress) -> tuple[PlanResult | None, str | None]:
    """The walk from problem.x0 (every solve's result appended to parts): (the result at problem.task, None), or
    (None, why there was no walk) when the tasks between have other NLP variables, or (None, None) when it stalled."""
    s, step, refusals, retimings, x = 0.0, FIRST_STEP, 0, 0, problem.x0
    while True:
        t = min(1.0, s + step)
        task = tasks_between(start_task, problem.task, t)
        try:
            pb = problem if t == 1.0 else build_problem(problem.robot, task, problem.options,
                                                        dynamics=problem.system.dyn)
        except InputError as exc:  # (it ended the replan, exit 2, naming a target the user never gave)
            return None, f"the task {t:g} of the way there is refused ({exc})"
        if pb.signature != problem.signature:  # e.g. mu from 0: the tangential variables appear
            return None, f"the task {t:g} of the way there has other NLP variables (e.g. a mu from 0)"
        result = _labelled(pb, x, held, lambda label, t=t: f"walk {t:.3g}", (s, t), parts, progress)
        if not result.stats.converged:
            refusals, step = refusals + 1, step / 2
            if refusals <= MAX_REFUSALS and step >= MIN_STEP:
                continue
            if retimings == MAX_RETIMINGS:
                return None, None
            retimings += 1
            retime = replace(penalty, max_iter=min(penalty.max_iter, RETIME_MAX_ITER))
            result = _labelled(pb, x, retime, lambda label, t=t: f"retime {t:.3g}: {label}", (s, t), parts, progress)
            if not result.stats.converged:
                return None, None
            refusals, step = 0, FIRST_STEP  # then the rest of the way at once
        if t == 1.0:
            return result, None
        s, x, step = t, result.extra["_x"], min(2 * step, 1.0 - t)  # not past the task: a refusal there halves the rest


def _labelled(problem: Problem, x0, options: SolveOptions, rename, walk: tuple[float, float], parts: list[PlanResult],
              progress) -> PlanResult:
    """solve from x0, each record labelled rename(its label), extra["walk"] = (from, to) fractions of the way."""
    def named(rec):
        return replace(rec, label=rename(rec.label))

    result = solve(replace(problem, x0=x0), options, None if progress is None else lambda rec: progress(named(rec)))
    result = replace(result, nlps=tuple(named(r) for r in result.nlps), extra={**result.extra, "walk": walk})
    parts.append(result)
    return result


def _totals(result: PlanResult, parts: list[PlanResult], wall: float, given: SolveOptions) -> PlanResult:
    """result with every NLP of the replan (parts, in order) in its records, iterations, solve time and timings
    (the numbers of every part's timings summed), and the options the replan was given (the last part's, e.g. a
    re-timing's max_iter 600, were recorded as the run's); extra["walk"]: where each accepted step of the walk
    reached, when the walk made the plan."""
    records = [r for part in parts for r in part.nlps]
    stats = replace(result.stats, solve_time_s=wall, n_nlp=len(records), ipopt_iterations=sum(r.iterations for r in records))
    if "walk" in result.extra and any(r.label.startswith("retime") for r in records):  # not the start's schedule then
        said = " (walked there: the contact schedule re-timed by a penalty replan on the way)"
        if SCHEDULE_KEPT in stats.message:
            stats = replace(stats, message=stats.message.replace(SCHEDULE_KEPT, said))
        elif records[-1].label.startswith("retime") and stats.converged:  # (it said "ok (active-set polished ..)")
            stats = replace(stats, message=f"{stats.message}; walked there, re-timing the contact schedule last")
    timings = {k: sum(p.timings.get(k, 0.0) for p in parts) if isinstance(v, float) else v for k, v in result.timings.items()}
    extra = {k: v for k, v in result.extra.items() if k != "walk"}
    if "walk" in result.extra:
        extra["walk"] = [p.extra["walk"][1] for p in parts if "walk" in p.extra and p.stats.converged]
    options = {**result.options, "solve": options_record(given)}
    return replace(result, nlps=tuple(records), stats=stats, timings=timings, extra=extra, options=options)
