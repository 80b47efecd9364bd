"""A race of solve variants: the same plan solved by several SolveOptions at once, one process each
(forked, so the built problem is shared; by forkserver, the problem pickled, ~1 s more, while the process runs other
threads: start_method); the first arm to converge wins and the others are stopped.

Why: the homotopy's iteration count is a chaotic function of the arithmetic. Any change of IPOPT's
warm start, regularization or round-off draws a new count, and on the seven Capler tasks of
`scripts/bench_pipeline.py --cases capler_set` one variant's count runs from ~2300 to ~8000 while the
other's is uncorrelated (docs/benchmarks.md, "Full solves and the gap to the 10 s goal", session 17). A
second core does not make one solve faster (MUMPS gains nothing from it), but it can run a second draw.

The returned plan is the winning arm's own, bit for bit what that arm gives when solved alone; which
arm wins is a matter of wall time, so two arms that finish close together may swap on another
machine (the summary names the winner). A rule by iteration counts would be load-independent, but
it measured 3.0-3.5x slower on two of seven tasks: an arm's iterations cost 10 to 67 ms, and proving
the slower arm could not win meant waiting for it.
"""
from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import pickle
import signal
import sys
import threading
import time
import traceback
from dataclasses import replace
from multiprocessing.connection import wait

from .errors import (InputError, PlannerError, SolveError, expect, killed_with_parent, plain, signals_held,
                     usable_cpus)
from .homotopy import Progress, Regularization, SolveOptions, WarmStart, solve
from .problem import Problem
from .result import PlanResult, race_arms_text

# The second arm of `planner plan` ("alternate"): multipliers carried from NLP to NLP, IPOPT's inertia correction
# started from the last regularization (Regularization.FROM_LAST: ~1.5 factorizations per iteration instead of ~2.5)
# and MUMPS without its weighted-matching permutation and scaling (IPOPT's mumps_permuting_scaling 0), so that it
# differs from the default from NLP 1 on. Alone on the seven-task set it converged on all seven, in 2348, 3286,
# 3746, 2501, 4832, 3367, 3850 iterations against the default's 2881, 8039, 4120, 3417, 3673, 3367, 2793
# (docs/benchmarks.md, session 18). A user's own mumps_permuting_scaling is kept.
SECOND_ARM = {"warm_start": WarmStart.PRIMAL_DUAL, "regularization": Regularization.FROM_LAST}
SECOND_ARM_IPOPT = {"mumps_permuting_scaling": 0}


def default_arms(options: SolveOptions) -> tuple[tuple[str, SolveOptions], ...]:
    """The arms `planner plan` races: `options` itself ("default") and the same with SECOND_ARM and, with MUMPS,
    SECOND_ARM_IPOPT added to options.ipopt ("alternate")."""
    expect(options, SolveOptions, "default_arms' options")
    ipopt = {**SECOND_ARM_IPOPT, **dict(options.ipopt)} if options.linear_solver == "mumps" else options.ipopt
    return (("default", options), ("alternate", replace(options, ipopt=ipopt, **SECOND_ARM)))


def race(problem: Problem, arms, progress: Progress | None = None, processes: int | None = None) -> PlanResult:
    """Solve `problem` with each (name, SolveOptions) of `arms` at once; returns the winner's PlanResult.

    The winner is the first arm to converge; the others are stopped then. If none converges, the first
    arm's result. Only the first `processes` arms run (default: the usable CPUs); with one (processes=1, or a
    one-CPU machine), the first arm is solved in this process as solve() would: no race, so its progress labels,
    message and extra have no arm names and no "race" record. Otherwise progress gets each arm's NLP records,
    labelled "name: label", the result's stats.solve_time_s is the race's wall time [s], its message names the
    outcome of every arm, and extra["race"] lists them (summary.json): arm, outcome, IPOPT iterations of its
    finished NLPs, wall time [s] at which it finished or was stopped.
    """
    expect(problem, Problem, "race's problem")
    problem.check_solvable()  # (here, not in each arm: one error, before the processes start)
    if isinstance(arms, SolveOptions) or not isinstance(arms, (list, tuple)):  # (a TypeError: "not iterable")
        raise InputError(f"race takes arms, a list of (name, SolveOptions) pairs, not a {type(arms).__name__}: "
                         "race(problem, default_arms(options)) races the default two")
    arms = tuple(arms)
    if not arms or not all(isinstance(a, tuple) and len(a) == 2 and isinstance(a[0], str) and isinstance(a[1], SolveOptions)
                            for a in arms):
        raise InputError(f"race needs one or more (name, SolveOptions) arms, got {arms!r:.80}")
    names = [name for name, _ in arms]
    if len(set(names)) != len(names):
        raise InputError(f"race arm names must differ, got {names}")
    processes = plain(processes)  # a notebook's np.int64
    if processes is not None and (not isinstance(processes, int) or isinstance(processes, bool) or processes < 1):
        raise InputError(f"race processes must be an integer >= 1 (or None: the usable CPUs), got {processes!r}")
    n = min(len(arms), usable_cpus() if processes is None else processes)
    if n == 1:
        return solve(problem, arms[0][1], progress)
    if mp.current_process().daemon:  # (multiprocessing's AssertionError "daemonic processes are not allowed to have
        # children" came from the first arm's start)
        raise InputError("race starts a process per arm, which a daemonic process (a multiprocessing.Pool worker) "
                         "cannot: pass race processes=1 (the first arm, solved in this process), or run the jobs with "
                         "planner.batch.run_batch or concurrent.futures.ProcessPoolExecutor, whose workers can start "
                         "processes")
    start = time.perf_counter()
    ctx = mp.get_context(start_method())
    pipes, procs = [], []
    for i in range(n):
        reader, writer = ctx.Pipe(duplex=False)  # one pipe per arm: killing an arm cannot corrupt another's channel
        proc = ctx.Process(target=_arm, args=(problem, arms[i][1], writer, names[i]), name=f"planner-race-{names[i]}", daemon=True)
        proc.start()
        writer.close()
        pipes.append(reader)
        procs.append(proc)
    done: dict[int, tuple[str, PlanResult | None, float]] = {}  # arm -> (outcome, result, wall [s])
    iterations = [0] * n  # IPOPT iterations of each arm's finished NLPs
    errors: dict[int, Exception] = {}
    win: int | None = None  # the first arm that converged
    try:
        while win is None and len(done) < n:
            for reader in wait([p for i, p in enumerate(pipes) if i not in done]):
                i = pipes.index(reader)
                try:
                    kind, payload = reader.recv()
                except (EOFError, OSError):  # the arm died without a word (e.g. killed by the OS; mid-message: OSError)
                    done[i] = ("died", None, time.perf_counter() - start)
                    continue
                if kind == "log":  # one writer: the arms' lines never mix within a line
                    _show(sys.stdout, "".join(f"[{names[i]}] {line}\n" for line in payload))
                elif kind == "progress":
                    iterations[i] += payload.iterations
                    if progress:
                        progress(replace(payload, label=f"{names[i]}: {payload.label}"))
                elif kind == "error":
                    errors[i] = payload[0]
                    done[i] = ("error: " + payload[1].strip().splitlines()[-1], None, time.perf_counter() - start)
                else:
                    iterations[i] = payload.stats.ipopt_iterations
                    done[i] = ("converged" if payload.stats.converged else "not converged", payload, time.perf_counter() - start)
                    if payload.stats.converged and win is None:
                        win = i
    finally:
        for proc in procs:  # every arm first: a second Ctrl-C during one arm's join left the next one running
            if proc.is_alive():
                proc.kill()
        with signals_held():
            for proc in procs:
                proc.join()
        for i in range(n):
            if i not in done:  # killed here, or it ended after the winner with its own outcome still unread
                done[i] = ("stopped", None, time.perf_counter() - start)
    pick = 0 if win is None else win  # none converged: the first arm's result, as its plain solve would give
    result = done[pick][1]
    if result is None:  # no arm converged and the first one raised or died: what a single solve would have done
        raise errors.get(pick) or SolveError(f"race: arm {names[pick]!r} {done[pick][0]}")
    table = [{"arm": names[i], "outcome": "won" if i == win else done[i][0], "iterations": iterations[i], "wall_s": done[i][2]}
             for i in range(n)]
    stats = replace(result.stats, solve_time_s=time.perf_counter() - start, message=f"{result.stats.message}; race of {race_arms_text(table)}")
    return replace(result, stats=stats, extra=dict(result.extra, race=table))


def start_method() -> str:
    """How race starts its arms: "fork" (the children inherit the built problem: CasADi functions do not pickle
    cheaply) while this process runs one thread, else "forkserver" (the problem pickled): a fork while another thread
    solved gave the arms CasADi's and the allocator's locks held, and they waited forever."""
    return "fork" if threading.active_count() == 1 else "forkserver"


def _arm(problem: Problem, options: SolveOptions, conn, name: str) -> None:
    """One arm, in its own process: solve, sending each NLP record, then the result (or the error). With
    print_level > 0 each line of IPOPT's log (CasADi writes it to sys.stdout) is sent to the race, which writes it to
    its own sys.stdout with "[name] " in front (race's `log`)."""
    _die_with_parent()
    relay = _Relayed(sys.stdout, conn) if options.print_level > 0 else None
    sys.stdout = relay or sys.stdout

    def progress(record) -> None:
        if relay:  # the log's lines before the NLP's record, as they were written
            relay.send()
        conn.send(("progress", record))

    try:
        try:
            message = ("done", solve(problem, options, progress))
        except Exception as exc:  # the parent re-raises it if this arm's result is the one to return
            message = ("error", (_portable(exc), traceback.format_exc()))
        if relay:  # the log's last lines before the outcome
            relay.finish()
        conn.send(message)
    finally:
        conn.close()


def _show(stream, text: str) -> None:
    """Write an arm's log lines to the race's stream; none (sys.stdout None: `2>&-` under -v, pythonw) or one whose
    reader left drops them (the race's AttributeError lost the plan)."""
    if stream is not None:
        with contextlib.suppress(OSError, ValueError):  # (a broken pipe; a closed file)
            stream.write(text)
            stream.flush()


RELAY_S = 0.1  # [s] how long an arm's log lines may wait to be sent to the race
RELAY_LINES = 1000


class _Relayed:
    """An arm's sys.stdout: its complete lines sent to the race as ("log", lines), at the first write RELAY_S after
    the last batch or once RELAY_LINES have gathered (one message per line took 3.7x the time at print_level 12; lines
    written before a long silence wait for the next write), the rest by `send` (before each NLP's record) and `finish`
    (a partial line as a line). The arm's own sys.stdout wrote to the race's only where it was the descriptor 1 they
    share: a caller's redirect_stdout (a StringIO, copied by the fork) or pytest's capture lost every line, and arms
    started by forkserver wrote to the server's descriptor 1."""

    def __init__(self, stream, conn):
        self.stream, self.conn, self.partial, self.lines, self.sent = stream, conn, "", [], time.monotonic()

    def write(self, text: str) -> int:
        *lines, self.partial = (self.partial + text).split("\n")
        self.lines += lines
        if len(self.lines) >= RELAY_LINES or time.monotonic() - self.sent >= RELAY_S:
            self.send()
        return len(text)

    def send(self) -> None:
        """Send the gathered complete lines, if any."""
        if self.lines:
            self.conn.send(("log", self.lines))
            self.lines, self.sent = [], time.monotonic()

    def flush(self) -> None:
        pass

    def finish(self) -> None:
        if self.partial:
            self.lines.append(self.partial)
            self.partial = ""
        self.send()

    def __getattr__(self, name):  # encoding, isatty, ...: the arm's own stream's
        return getattr(self.stream, name)


def _portable(exc: Exception) -> Exception:
    """exc if it survives a trip through pickle, else the nearest planner error with its message (an InputError
    stays one: the CLI's exit 2). Exceptions whose constructor needs more than their message do not, unless they
    reduce themselves (UnknownNameError does since session 61)."""
    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:
        if isinstance(exc, PlannerError):
            return (InputError if isinstance(exc, InputError) else SolveError)(str(exc))
        return SolveError(f"{type(exc).__name__}: {exc}")


def _die_with_parent() -> None:
    """The arm never outlives the race: Ctrl-C is the parent's to handle (it kills the arms), and on Linux the
    arm gets SIGKILL if the parent dies (prctl PR_SET_PDEATHSIG) instead of solving on for minutes."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    killed_with_parent()  # (not Linux: the parent's finally still kills the arms on any exception)
    parent = mp.parent_process()
    if parent is not None:  # the race's process, also by forkserver, whose arms' kernel parent is the server: the
        # death signal followed the server, which lives while an arm does (a SIGKILLed race left both running)
        def orphaned():
            wait([parent.sentinel])
            os._exit(1)

        threading.Thread(target=orphaned, daemon=True, name="planner-race-parent").start()
