"""A race of solve variants returns the first converged arm's own plan, bit for bit, and never leaves an arm behind."""
from __future__ import annotations

import dataclasses
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from planner import homotopy as H
from planner import race as R
from planner.errors import InputError, SolveError, UnknownNameError
from planner.model import load_robot
from planner.problem import build_problem

from test_problem import hop_task

# The point-mass hop: both default arms converge on it, with different iteration counts (measured 635 and
# 489 IPOPT iterations), so the race has a winner and a loser.
HOP_N = 40


@pytest.fixture(scope="module")
def hop_problem():
    return build_problem(load_robot("robots/point_mass.xml"), hop_task(N=HOP_N))


@pytest.fixture(scope="module")
def one_by_one(hop_problem):
    """Each default arm solved alone, in this process."""
    return {name: H.solve(hop_problem, options) for name, options in R.default_arms(H.SolveOptions())}


def test_race_returns_a_converged_arms_own_plan_bit_for_bit(hop_problem, one_by_one):
    """The race returns the plan of an arm that converges when solved alone, to the last bit (a forked arm does
    the same arithmetic), with that arm's NLPs and iterations; the table has each arm once, exactly one
    "won", the other stopped or finished; every progress record is labelled with its arm."""
    assert all(r.stats.converged for r in one_by_one.values())  # else the race has nothing to show here
    records = []
    result = R.race(hop_problem, R.default_arms(H.SolveOptions()), progress=records.append, processes=2)
    table = {row["arm"]: row for row in result.extra["race"]}
    assert set(table) == set(one_by_one)
    (winner,) = [name for name, row in table.items() if row["outcome"] == "won"]
    alone = one_by_one[winner]
    assert np.array_equal(result.extra["_x"], alone.extra["_x"])
    assert result.stats.ipopt_iterations == alone.stats.ipopt_iterations == table[winner]["iterations"]
    assert [r.label for r in result.nlps] == [r.label for r in alone.nlps]
    (loser,) = set(table) - {winner}
    assert table[loser]["outcome"] in ("stopped", "converged")
    assert table[loser]["iterations"] <= one_by_one[loser].stats.ipopt_iterations
    assert records and all(r.label.split(": ", 1)[0] in table for r in records)
    assert result.stats.solve_time_s >= table[winner]["wall_s"] > 0
    assert f"race of default {table['default']['outcome']}" in result.stats.message


def test_a_race_never_takes_an_unconverged_arm_over_a_converged_one():
    """An arm that finishes first without converging (capped at one IPOPT iteration per NLP) does not win: the race
    waits for the arm that converges and returns its plan, bit for bit that arm's plain solve, the capped arm listed as
    not converged (session 66's mutation testing: the first arm to finish won, converged or not, and the converging
    arm was stopped, with every test green)."""
    problem = build_problem(load_robot("robots/point_mass.xml"), hop_task(N=10))  # (a short hop: the race waits for it)
    arms = (("capped", H.SolveOptions(max_iter=1)), ("default", H.SolveOptions()))
    result = R.race(problem, arms, processes=2)
    assert result.stats.converged, result.stats.message
    assert np.array_equal(result.extra["_x"], H.solve(problem, H.SolveOptions()).extra["_x"])
    assert [(row["arm"], row["outcome"]) for row in result.extra["race"]] == [("capped", "not converged"),
                                                                              ("default", "won")]


def test_the_alternate_arm_keeps_the_users_mumps_permuting_scaling():
    """default_arms' alternate arm turns MUMPS's permuting scaling off (SECOND_ARM_IPOPT) unless the user's options set
    it: a user's own mumps_permuting_scaling is kept in both arms, as the module says (session 66's mutation testing:
    the arm's 0 replaced the user's 1, with every test green)."""
    def scaling(options):
        return [dict(arm.ipopt).get("mumps_permuting_scaling") for _, arm in R.default_arms(options)]

    assert scaling(H.SolveOptions(ipopt={"mumps_permuting_scaling": 1})) == [1, 1]
    assert scaling(H.SolveOptions()) == [None, 0]


@pytest.mark.parametrize("method", ["fork", "forkserver"])
def test_verbose_arms_label_every_line_of_their_ipopt_logs(hop_problem, one_by_one, method, monkeypatch):
    """With print_level > 0 the arms' logs reach the race's own sys.stdout (here a redirect_stdout StringIO: forked
    arms wrote to their copy of it and every line was lost, forkserver's arms to the server's descriptor 1), every line
    starting with "[default] " or "[alternate] ", both arms' IPOPT logs there (their iteration tables, the winner's
    EXIT line of each of its NLPs); the winner's
    plan is that arm's quiet plan bit for bit (printing does not change the arithmetic)."""
    import contextlib
    import io

    monkeypatch.setattr(R, "start_method", lambda: method)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        result = R.race(hop_problem, R.default_arms(H.SolveOptions(print_level=5)), processes=2)
    lines = [line for line in out.getvalue().splitlines() if line]
    labels = {f"[{name}] " for name in one_by_one}
    assert lines and all(line[: line.find("] ") + 2] in labels for line in lines), [x for x in lines if not x.startswith("[")][:3]
    for label in labels:
        assert any(line.startswith(label) and "iter    objective" in line for line in lines), label
    (won,) = [row["arm"] for row in result.extra["race"] if row["outcome"] == "won"]
    assert np.array_equal(result.extra["_x"], one_by_one[won].extra["_x"])
    # every NLP's log reached the race, its last NLP's too (the arm sends what it gathered before its result)
    assert sum(line.startswith(f"[{won}] EXIT:") for line in lines) == len(result.nlps)


def test_verbose_arms_without_a_stdout_still_race(hop_problem, one_by_one, monkeypatch):
    """With print_level > 0 and sys.stdout None (`planner plan -v 2>&-`, pythonw) the arms' log lines are dropped and
    the race returns its plan (writing them raised AttributeError: the plan was lost, exit 1)."""
    import contextlib

    monkeypatch.setattr(R, "start_method", lambda: "fork")
    with contextlib.redirect_stdout(None):
        result = R.race(hop_problem, R.default_arms(H.SolveOptions(print_level=3)), processes=2)
    (won,) = [row["arm"] for row in result.extra["race"] if row["outcome"] == "won"]
    assert np.array_equal(result.extra["_x"], one_by_one[won].extra["_x"])


class _Recording:
    """An arm's end of the pipe that records what it is sent (sent: the messages, in order)."""

    def __init__(self):
        self.sent = []

    def send(self, message):
        self.sent.append(message)

    def close(self):
        pass


@pytest.fixture
def relay_clock(monkeypatch):
    """race.py's time.monotonic frozen at clock[0] [s], which the test moves."""
    clock = [0.0]
    monkeypatch.setattr(R.time, "monotonic", lambda: clock[0])
    return clock


def test_relayed_stream_sends_whole_lines_in_batches(monkeypatch, relay_clock):
    """_Relayed (an arm's sys.stdout) buffers a partial line until its end and sends complete lines in batches: once
    RELAY_LINES have gathered or RELAY_S has passed since the last batch (one message per line made a race at
    print_level 12 3.7x slower), the rest at send() or finish(), which also sends a last partial line; each line once,
    in order; other attributes are the arm's own stream's."""
    import io

    conn = _Recording()
    sent = conn.sent
    monkeypatch.setattr(R, "RELAY_LINES", 3)
    stream = R._Relayed(io.StringIO("x"), conn)
    stream.write("one\ntw")
    assert sent == []  # gathered
    stream.write("o\n\nthree")
    assert sent == [("log", ["one", "two", ""])]  # RELAY_LINES reached
    stream.write("\nfour\n")
    relay_clock[0] = R.RELAY_S
    stream.write("five")
    assert sent[-1] == ("log", ["three", "four"])  # RELAY_S passed
    stream.flush()
    stream.finish()
    assert sent[-1] == ("log", ["five"]) and len(sent) == 3 and stream.getvalue() == "x"
    stream.send()
    assert len(sent) == 3  # nothing gathered: no empty message


def test_one_process_solves_the_first_arm_here(hop_problem, one_by_one):
    """With processes = 1 the race is the first arm's plain solve (no fork, no race table); a numpy int is the number
    it holds (np.int64(1) was refused as "not an integer")."""
    result = R.race(hop_problem, R.default_arms(H.SolveOptions()), processes=np.int64(1))
    assert "race" not in result.extra
    assert np.array_equal(result.extra["_x"], one_by_one["default"].extra["_x"])


# how long the patched race waits after each wake-up: long enough for the other arm (which finishes LATE_ARM_S
# after the winner) to have sent its result and exited before the race looks at it
WAKE_DELAY_S, LATE_ARM_S = 1.0, 0.2


def test_an_arm_that_ends_after_the_winner_unread_is_listed_as_stopped(hop_problem, one_by_one, monkeypatch):
    """An arm whose result arrives after the winner's, and which has exited by the time the race stops the
    others, is still in the race table (as stopped): its unread outcome once left a gap (KeyError)."""
    done = one_by_one["default"]

    def quick(problem, options, progress=None):
        if options.warm_start is H.WarmStart.PRIMAL_DUAL:
            time.sleep(LATE_ARM_S)
        return done

    real_wait = R.wait

    def slow_wait(readers):
        ready = real_wait(readers)
        time.sleep(WAKE_DELAY_S)
        return ready

    monkeypatch.setattr(R, "solve", quick)  # the forked arms inherit the patch
    monkeypatch.setattr(R, "start_method", lambda: "fork")  # (a thread left by another test: forkserver)
    monkeypatch.setattr(R, "wait", slow_wait)
    result = R.race(hop_problem, R.default_arms(H.SolveOptions()), processes=2)
    assert [(row["arm"], row["outcome"]) for row in result.extra["race"]] == [("default", "won"), ("alternate", "stopped")]


def test_a_failing_arm_loses_and_the_first_arms_error_is_raised_when_none_converges(hop_problem, monkeypatch):
    """An arm that raises does not take the race down: the other arm wins. If no arm converges and the
    first one raised, the race raises that error, as the plain solve would."""
    solve = H.solve

    def flaky(problem, options, progress=None):
        if options.warm_start is H.WarmStart.PRIMAL_DUAL:
            raise InputError("arm says no")
        return solve(problem, options, progress)

    monkeypatch.setattr(R, "solve", flaky)  # the forked arms inherit the patch
    monkeypatch.setattr(R, "start_method", lambda: "fork")  # (a thread left by another test: forkserver)
    quick = H.SolveOptions()
    result = R.race(hop_problem, R.default_arms(quick), processes=2)
    table = {row["arm"]: row for row in result.extra["race"]}
    assert table["alternate"]["outcome"] == "error: planner.errors.InputError: arm says no"
    assert table["default"]["outcome"] == "won"
    arms = (("first", dataclasses.replace(quick, warm_start=H.WarmStart.PRIMAL_DUAL)), ("second", quick))
    monkeypatch.setattr(R, "start_method", lambda: "fork")  # the forked arms inherit the patch below
    monkeypatch.setattr(R, "solve", lambda problem, options, progress=None:
                        (_ for _ in ()).throw(InputError("always no")))
    with pytest.raises(InputError, match="always no"):
        R.race(hop_problem, arms, processes=2)


class TwoPartInputError(InputError):
    """A user error whose constructor needs two arguments: pickle cannot rebuild it from its message."""

    def __init__(self, what, where):
        super().__init__(f"{what} at {where}")


@pytest.mark.parametrize("make, expected, fragment", [
    (lambda: type("Local", (Exception,), {})("no pickle"), SolveError, "Local: no pickle"),  # a class pickle cannot find
    # (required init args: it arrived as an InputError by its message; since session 61 it pickles, as itself)
    (lambda: UnknownNameError("joint", "elbow", ["hip", "knee"]), InputError, "valid joints: hip, knee"),
    # one that does not pickle (session 66's mutation testing: it arrived as a SolveError, the CLI's exit 1, with every
    # test green: UnknownNameError, above, no longer reached the rule)
    (lambda: TwoPartInputError("bad joint", "elbow"), InputError, "bad joint at elbow"),
])
def test_arm_errors_that_do_not_pickle_arrive_as_the_nearest_planner_error(hop_problem, monkeypatch, make, expected, fragment):
    """An arm's exception that cannot cross the process boundary arrives with its message: a user error as an
    InputError (the CLI's exit 2), anything else as a SolveError naming the original type."""
    def fail(problem, options, progress=None):
        raise make()

    monkeypatch.setattr(R, "solve", fail)
    monkeypatch.setattr(R, "start_method", lambda: "fork")  # the forked arms inherit the patch
    with pytest.raises(expected, match=fragment):
        R.race(hop_problem, R.default_arms(H.SolveOptions()), processes=2)


def _race_in_a_pool_worker(_):
    """race() of the hop with two arms in a multiprocessing.Pool worker (a daemonic process): its error's type and
    message."""
    try:
        R.race(build_problem(load_robot("robots/point_mass.xml"), hop_task(N=6)), R.default_arms(H.SolveOptions()),
               processes=2)
    except Exception as exc:  # (returned, not raised: the test reads it in the parent)
        return type(exc).__name__, str(exc)
    return None, ""


def test_a_race_in_a_daemonic_process_is_an_input_error_naming_the_alternatives():
    """race() in a multiprocessing.Pool worker, which may start no processes, is an InputError naming processes=1
    and run_batch (multiprocessing's AssertionError "daemonic processes are not allowed to have children")."""
    import multiprocessing

    with multiprocessing.get_context("fork").Pool(1) as pool:
        name, message = pool.map(_race_in_a_pool_worker, [0])[0]
    assert name == "InputError" and "processes=1" in message and "run_batch" in message, (name, message)


@pytest.mark.parametrize("arms, processes, fragment", [
    ((), None, r"one or more \(name, SolveOptions\) arms"),
    ((H.SolveOptions(),), None, r"one or more \(name, SolveOptions\) arms"),  # TypeError: cannot unpack
    ((("a", H.SolveOptions()), ("a", H.SolveOptions())), None, "must differ"),
    ((("a", H.SolveOptions()),), 0, "processes must be an integer >= 1"),
    ((("a", H.SolveOptions()),), 1.5, "processes must be an integer >= 1"),  # TypeError in min()
])
def test_bad_race_input(hop_problem, arms, processes, fragment):
    """No arms, arms that are not (name, SolveOptions) pairs, two arms of one name, or a process count that is not an
    integer >= 1 is an InputError saying which."""
    with pytest.raises(InputError, match=fragment):
        R.race(hop_problem, arms, processes=processes)


# How long an arm may outlive its race's parent: the kernel's PR_SET_PDEATHSIG, or the parent's cleanup, acts at once
ARM_EXIT_S = 5.0
# The racing process takes Ctrl-C as a terminal delivers it: a shell without job control starts background commands
# with SIGINT ignored, and the child would inherit that (the suite run as `bash .ci/run &` failed here: the
# racing process never exited and proc.wait timed out after ARM_EXIT_S).
ARMS_THAT_SLEEP = """
import multiprocessing as mp, signal, threading, time
signal.signal(signal.SIGINT, signal.default_int_handler)
from planner import race as R
from planner.homotopy import SolveOptions
from planner.model import load_robot
from planner.problem import build_problem
from planner.task import parse_task
problem = build_problem(load_robot("point_mass"), parse_task({"contacts": [{"point": "point"}], "initial": {"q": [0.0, 0.0]},
                        "horizon": {"tau_f": 1.0, "N": 2}, "plan": {"target_q": [0.5, 0.0], "u_bound": 30.0}}))
R.solve = lambda problem, options, progress=None: time.sleep(120)
R.start_method = lambda: "fork"  # (the reporting thread below would make it forkserver, whose arms import R afresh)
def report():  # once both arms run (a fixed 1 s found none on a loaded box, and the test failed)
    deadline = time.monotonic() + 60
    while len(mp.active_children()) < 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    print(*[c.pid for c in mp.active_children()], flush=True)
threading.Thread(target=report, daemon=True).start()
R.race(problem, R.default_arms(SolveOptions()), processes=2)
"""


# The same race with its arms started by forkserver (the reporting thread makes race choose it): the server imports
# SLEEPY_ARMS first (set_forkserver_preload), so its arms sleep too.
SLEEPY_ARMS = """
import time
import planner.race as R
R.solve = lambda problem, options, progress=None: time.sleep(120)
"""
ARMS_BY_FORKSERVER = ARMS_THAT_SLEEP.replace('R.start_method = lambda: "fork"',
                                             'mp.set_forkserver_preload(["sleepy_arms"])')
assert 'lambda: "fork"' not in ARMS_BY_FORKSERVER


def _gone(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] in ("Z", "X")  # a zombie nobody reaped has exited
    except (FileNotFoundError, ProcessLookupError):  # the latter: reaped between open and read (CI, session 63)
        return True


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc and relies on prctl")
@pytest.mark.parametrize("script", [ARMS_THAT_SLEEP, ARMS_BY_FORKSERVER], ids=["fork", "forkserver"])
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGINT])
def test_arms_do_not_outlive_the_race(sig, script, tmp_path):
    """Killing the racing process (SIGKILL: the arms get the kernel's death signal, and by forkserver, whose server
    lived as long as an arm, they watch the race's process themselves) or interrupting it (SIGINT: its cleanup kills
    them; the arms themselves ignore Ctrl-C) leaves no arm running within ARM_EXIT_S."""
    (tmp_path / "sleepy_arms.py").write_text(SLEEPY_ARMS)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True, env=env)
    pids = [int(p) for p in proc.stdout.readline().split()]
    assert len(pids) == 2
    os.kill(proc.pid, sig)
    proc.wait(timeout=ARM_EXIT_S)
    deadline = time.monotonic() + ARM_EXIT_S
    while not all(_gone(p) for p in pids) and time.monotonic() < deadline:
        time.sleep(0.05)
    left = [p for p in pids if not _gone(p)]
    for pid in left:  # a failing run must not leave sleepers behind
        os.kill(pid, signal.SIGKILL)
    assert not left


def test_a_race_beside_a_solving_thread_starts_its_arms_by_forkserver_and_returns_the_arms_plan(hop_problem,
                                                                                                one_by_one):
    """While another thread of the process solves, race starts its arms by forkserver (the problem pickled), not by
    fork, which gave the arms CasADi's and the allocator's locks held by that thread (they waited forever, 4 of 4
    races of a tester); the winner's plan is still its arm's own, bit for bit."""
    import threading

    stop = threading.Event()

    def solving():
        while not stop.is_set():
            H.solve(hop_problem)

    thread = threading.Thread(target=solving)
    thread.start()
    try:
        assert R.start_method() == "forkserver"
        result = R.race(hop_problem, R.default_arms(H.SolveOptions()), processes=2)
    finally:
        stop.set()
        thread.join()
    (winner,) = [row["arm"] for row in result.extra["race"] if row["outcome"] == "won"]
    assert np.array_equal(result.extra["_x"], one_by_one[winner].extra["_x"])


def test_a_second_ctrl_c_while_the_arms_are_reaped_leaves_none_running(hop_problem):
    """A Ctrl-C during a race kills every arm before it reaps any, and a second one while they are reaped waits for
    the reaping (the arms were killed and joined one at a time, and a second Ctrl-C inside the first join left the
    other arm running and a zombie)."""
    import multiprocessing
    import multiprocessing.process

    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    join = multiprocessing.process.BaseProcess.join
    pressed = []

    def join_pressed(self, timeout=None):
        if not pressed:
            pressed.append(True)
            os.kill(os.getpid(), signal.SIGINT)  # the second Ctrl-C, inside the first join
        return join(self, timeout)

    def first(record):
        raise KeyboardInterrupt  # the first Ctrl-C, in the parent while the arms solve

    try:
        multiprocessing.process.BaseProcess.join = join_pressed
        with pytest.raises(KeyboardInterrupt):
            R.race(hop_problem, R.default_arms(H.SolveOptions()), progress=first, processes=2)
    finally:
        multiprocessing.process.BaseProcess.join = join
        signal.signal(signal.SIGINT, previous)
    assert pressed and multiprocessing.active_children() == []


def test_a_race_that_nobody_wins_returns_the_first_arms_result(hop_problem):
    """When no arm converges (each stops at its iteration cap) the race returns the first arm's result, as its
    docstring says and the plain solve with the first arm's options would (session 65's mutation testing: the last
    arm's was returned and no test could tell, the one test of a lost race having both arms raise the same error). No
    arm is listed as having won, in the table (summary.json) or the message (session 66's mutation testing: the first
    arm "won" a race nobody converged in, with every test green)."""
    arms = (("first", H.SolveOptions(max_iter=2, polish=H.Polish.NONE)),
            ("second", H.SolveOptions(max_iter=3, polish=H.Polish.NONE)))
    result = R.race(hop_problem, arms, processes=2)
    assert not result.stats.converged and result.options["solve"]["max_iter"] == 2
    assert [(row["arm"], row["outcome"]) for row in result.extra["race"]] == [("first", "not converged"),
                                                                              ("second", "not converged")]
    assert "won" not in result.stats.message, result.stats.message


# a command as PID 1 of a new PID namespace, its user mapped to root in a new user namespace (so also without root);
# --kill-child: a timeout's kill of unshare ends the command too
AS_PID_1 = ["unshare", "--user", "--map-root-user", "--pid", "--fork", "--kill-child", "--mount-proc"]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux's PID namespaces")
def test_a_race_run_as_pid_1_converges(tmp_path):
    """`planner plan` as the first process of a PID namespace (a container's, `docker run` without --init) races its
    arms and converges: an arm whose parent is PID 1 is not an orphan (each arm exited at once as one, and the race
    failed with "arm 'default' died", exit 1; --no-race converged). Skipped where namespaces are not allowed."""
    import shutil

    from planner.model import ROBOTS_DIR

    if shutil.which("unshare") is None or subprocess.run(AS_PID_1 + ["true"], capture_output=True,
                                                         timeout=60).returncode != 0:
        pytest.skip("`unshare --user --pid` is not allowed here")
    run = subprocess.run(AS_PID_1 + [sys.executable, "-m", "planner.cli", "plan", "point_mass", "--task",
                                     str(ROBOTS_DIR / "point_mass_hop.toml"), "--out", str(tmp_path / "out"),
                                     "--no-validate", "-q"],
                         capture_output=True, text=True, env={**os.environ, "OMP_NUM_THREADS": "1"}, timeout=600)
    assert run.returncode == 0, run.stderr
    assert (tmp_path / "out" / "summary.json").is_file()


def test_an_arm_sends_its_log_lines_before_each_record_and_its_last_partial_line_before_its_result(monkeypatch,
                                                                                                      relay_clock):
    """An arm at print_level > 0 (_arm, run here with a recording connection and a solve that prints): the lines
    written before an NLP's record reach the race before that record, in order, even when RELAY_S has not passed;
    after the record a partial last line (no newline) is sent as a line before the result; a line written after
    the RELAY_S batch waits for the next batch (session 66's mutation testing: the record sent before its NLP's
    lines, the last partial line dropped at the end, and every line after the first RELAY_S its own message, with
    every test green)."""
    import io

    conn = _Recording()
    sent = conn.sent

    def solve(problem, options, progress):
        print("iter 1")
        print("EXIT: first")
        progress("record 1")
        print("EXIT: last", end="")
        return "result"

    monkeypatch.setattr(R, "_die_with_parent", lambda: None)  # (not in a process of its own here)
    monkeypatch.setattr(R, "solve", solve)
    monkeypatch.setattr(sys, "stdout", io.StringIO())  # _arm replaces sys.stdout with its relay
    R._arm(None, H.SolveOptions(print_level=5), conn, "default")
    assert sent == [("log", ["iter 1", "EXIT: first"]), ("progress", "record 1"), ("log", ["EXIT: last"]),
                    ("done", "result")]
    # the batches: one at RELAY_S, then nothing until RELAY_S has passed again
    sent.clear()
    stream = R._Relayed(io.StringIO(), conn)
    relay_clock[0] = R.RELAY_S
    stream.write("one\n")
    stream.write("two\n")
    assert sent == [("log", ["one"])]
    relay_clock[0] = 2 * R.RELAY_S
    stream.write("three\n")
    assert sent == [("log", ["one"]), ("log", ["two", "three"])]


def test_the_race_writes_each_relayed_line_once_whole_and_labelled(hop_problem, one_by_one, monkeypatch):
    """The race writes the log batches its arms send (arms stubbed: two batches each, then the arm's plan marked not
    converged, so that the race reads every arm to its end) to its sys.stdout as they were written: every line of
    every batch once, whole, in order, with its arm's label and a newline. The verbose race's IPOPT logs are long
    enough to pass either way (session 66's mutation testing: each batch's first line dropped, and each batch's last
    line run into the next batch's first for want of its newline, with every test green)."""
    import contextlib
    import io

    def arm(problem, options, conn, name):
        conn.send(("log", [f"{name} 1", f"{name} 2"]))
        conn.send(("log", [f"{name} 3"]))
        plan = one_by_one[name]
        conn.send(("done", dataclasses.replace(plan, stats=dataclasses.replace(plan.stats, converged=False))))
        conn.close()

    monkeypatch.setattr(R, "start_method", lambda: "fork")
    monkeypatch.setattr(R, "_arm", arm)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        R.race(hop_problem, R.default_arms(H.SolveOptions()), processes=2)
    text = out.getvalue()
    assert text.endswith("\n")
    for name in one_by_one:
        mine = [line for line in text.splitlines() if line.startswith(f"[{name}] ")]
        assert mine == [f"[{name}] {name} {k}" for k in (1, 2, 3)], text
    assert len(text.splitlines()) == 3 * len(one_by_one)
