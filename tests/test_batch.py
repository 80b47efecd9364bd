"""planner.batch: local processes and Dask give the serial loop's results in item order; a raising
job becomes a Crashed record (stage, error, traceback) without stopping the others."""
from __future__ import annotations

import math

import pytest

from planner.batch import CRASHED, Crashed, crashed_record, run_batch, stage
from planner.errors import InputError


def square_or_raise(x):
    """A small deterministic job: raises for negative items, inside a named stage."""
    with stage("outer"):
        if x < 0:
            with stage("check"):
                raise ValueError(f"negative item {x}")
        return {"x": x, "square": x * x, "root": math.sqrt(x)}


def warns(x):
    """A job that warns (as an input notice of the planner does) and returns its item."""
    import warnings

    warnings.warn(f"item {x} is odd", UserWarning)
    return x


def exits(x):
    if x == 1:
        raise SystemExit(3)
    return x


ITEMS = [3, 0, -2, 5, 1.5]


def _serial(items):
    out = []
    for x in items:
        try:
            out.append(square_or_raise(x))
        except ValueError as exc:
            out.append(crashed_record(exc))
    return out


def _check(results):
    expected = _serial(ITEMS)
    assert len(results) == len(ITEMS)
    for got, want, x in zip(results, expected, ITEMS):
        if x < 0:
            assert isinstance(got, Crashed) and got.outcome == CRASHED
            assert got.stage == "check" and got.error == "ValueError: negative item -2"
            assert "Traceback" in got.traceback and "square_or_raise" in got.traceback
            assert got.to_json()["outcome"] == "crashed"
        else:
            assert got == want


def test_in_process_matches_serial():
    """workers=0 (jobs run one after the other in this process) returns the serial loop's results in item order, the
    raising item as a Crashed record naming the innermost stage ("check"), the error and its traceback."""
    _check(run_batch(square_or_raise, ITEMS, workers=0))


def test_local_processes_match_serial():
    """Two local worker processes return the serial loop's results in item order (whatever order the jobs end in),
    the raising item as a Crashed record, and call progress once for every item index."""
    seen = []
    _check(run_batch(square_or_raise, ITEMS, workers=2, progress=lambda i, r: seen.append(i)))
    assert sorted(seen) == list(range(len(ITEMS)))


def test_local_workers_run_with_the_callers_warning_filters(capfd, monkeypatch):
    """Local workers take the caller's warning filters, as jobs run in this process do: under "error" a job's warning
    is its Crashed record, under "ignore" it is not printed (spawned workers started with Python's defaults: the
    warning was printed both times and every job returned); a filter whose category a worker cannot import (one a
    script defines under its `if __name__ == "__main__":`) is left out there (it broke every worker's start: each job
    "the worker process died"). The latest filter takes precedence, as in this process: "ignore" for the job's message
    after "error" for everything gives the workers=0 results (session 66's mutation testing: the workers applied the
    filters in reverse, so every job of a sweep was a Crashed record, with every test green)."""
    import sys
    import warnings

    hidden = type("HiddenWarning", (UserWarning,), {"__module__": "__main__"})
    monkeypatch.setattr(sys.modules["__main__"], "HiddenWarning", hidden, raising=False)  # pickles here only
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", hidden)
        assert run_batch(square_or_raise, [1, 2], workers=2) == [square_or_raise(1), square_or_raise(2)]

    for action in ("error", "ignore"):
        with warnings.catch_warnings():
            warnings.simplefilter(action)
            results = run_batch(warns, [1, 2], workers=2)
        if action == "error":
            assert all(isinstance(r, Crashed) and r.error == f"UserWarning: item {x} is odd"
                       for r, x in zip(results, [1, 2]))
        else:
            assert results == [1, 2] and "is odd" not in capfd.readouterr().err

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.filterwarnings("ignore", message=r"item \d+ is odd")
        assert run_batch(warns, [1, 2], workers=1) == run_batch(warns, [1, 2], workers=0) == [1, 2]


def returns_a_lock(x):
    """A job whose result does not pickle (a lock), so it cannot travel back from a worker."""
    import threading

    return threading.Lock()


def test_a_result_that_does_not_pickle_is_a_crash_of_the_transfer():
    """A job that returns in its worker but whose result cannot be sent back is a Crashed record of stage "transfer"
    naming pickle's error, so a sweep's summary tells it from a worker that died (session 66's mutation testing: it was
    recorded under stage "worker", with every test green)."""
    import pickle

    with pytest.raises(TypeError) as raised:  # the ground truth: pickle's own refusal
        pickle.dumps(returns_a_lock(0))
    (crashed,) = run_batch(returns_a_lock, [0], workers=1)
    assert isinstance(crashed, Crashed) and crashed.stage == "transfer"
    assert str(raised.value) in crashed.error, crashed.error


def test_system_exit_is_a_crash_not_the_end_of_the_sweep():
    """A job raising SystemExit (not an Exception) in a worker process becomes a Crashed record whose error names
    SystemExit, and the jobs before and after it still return their results."""
    out = run_batch(exits, [0, 1, 2], workers=1)
    assert out[0] == 0 and out[2] == 2
    assert isinstance(out[1], Crashed) and out[1].error.startswith("SystemExit")


def sleeps(path):
    """A job of 0.5 s that leaves its file behind when it finishes."""
    import pathlib
    import time

    time.sleep(0.5)
    pathlib.Path(path).write_text("done")
    return path


def test_a_stopped_batch_stops_its_queued_and_running_jobs(tmp_path):
    """An exception in the parent while jobs run (a Ctrl-C; here the progress callback's) cancels the queued jobs and
    ends the running one: leaving the pool waited for every queued job first (a stopped stress run solved all of its
    tasks and kept none). Of six 0.5 s jobs on one worker, the first finishes and no other does."""
    import time

    items = [str(tmp_path / f"job{i}") for i in range(6)]

    def stop(i, result):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_batch(sleeps, items, workers=1, progress=stop)
    time.sleep(1.0)  # a job left running would finish in the meantime
    assert sorted(p.name for p in tmp_path.iterdir()) == ["job0"]


def dies_once(arg):
    """A job that kills its worker the first time any job runs (marker file absent), else sleeps `seconds` and
    leaves its file behind."""
    import os
    import pathlib
    import signal
    import time

    marker, path, seconds = arg
    if not os.path.exists(marker):
        pathlib.Path(marker).write_text("killed")
        os.kill(os.getpid(), signal.SIGKILL)
    time.sleep(seconds)
    pathlib.Path(path).write_text("done")
    return path


def test_a_stopped_batch_stops_the_rerun_of_a_dead_workers_jobs(tmp_path):
    """A Ctrl-C while the jobs of a dead worker are rerun one by one ends the running rerun at once: its pool's `with`
    waited for the job to finish first (a 30 s job kept a stopped sweep 21 s, a Capler task would keep it ~30 min,
    session 59's tester). The first job kills its worker, so both are rerun; the Ctrl-C (an alarm set after the
    first rerun) comes during the second's 3 s, which leaves no file."""
    import signal
    import time

    marker = str(tmp_path / "marker")
    items = [(marker, str(tmp_path / "job0"), 0.0), (marker, str(tmp_path / "job1"), 3.0)]

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGALRM, interrupt)
    try:
        started = time.monotonic()
        with pytest.raises(KeyboardInterrupt):
            run_batch(dies_once, items, workers=1, progress=lambda i, r: signal.setitimer(signal.ITIMER_REAL, 0.3))
        stopped = time.monotonic() - started
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, previous)
    time.sleep(3.5)  # a rerun left running would finish in the meantime
    assert (tmp_path / "job0").exists() and not (tmp_path / "job1").exists(), stopped


def test_rejects_lambda_and_negative_workers():
    """A lambda, and workers that are no integer >= 0 (a str raised TypeError, 2.5 and True ran), are InputErrors."""
    assert run_batch(square_or_raise, []) == []
    with pytest.raises(InputError, match="top-level"):
        run_batch(lambda x: x, [1], workers=1)
    for bad in (-1, "2", 2.5, True):
        with pytest.raises(InputError, match="workers must be None or an integer >= 0"):
            run_batch(square_or_raise, [1], workers=bad)


def test_rejects_what_is_no_function_or_no_items():
    """A fn that is not callable is an InputError with workers=0 too (each job was a Crashed record of "'int' object
    is not callable"), and items that are not iterable are one (a bare TypeError)."""
    for workers in (0, None):
        with pytest.raises(InputError, match="run_batch's fn must be callable, got 3"):
            run_batch(3, [1], workers=workers)
    with pytest.raises(InputError, match="run_batch's items must be iterable, got None"):
        run_batch(square_or_raise, None)


def test_dask_local_cluster_matches_serial():
    """A Dask scheduler, given by its address or as a dask.distributed.Client, returns the serial loop's results in
    item order, the raising item as a Crashed record (skipped when dask.distributed is not installed)."""
    distributed = pytest.importorskip("dask.distributed")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as cluster:
        _check(run_batch(square_or_raise, ITEMS, scheduler=cluster.scheduler_address))
        with distributed.Client(cluster) as client:
            _check(run_batch(square_or_raise, ITEMS, scheduler=client))


def test_unreachable_scheduler_is_an_input_error(monkeypatch):
    """A scheduler address Dask cannot connect to is an InputError naming the address (the CLI's one line, exit 2),
    not distributed's OSError traceback; the connection failure is simulated (a real one waits distributed's 30 s)."""
    distributed = pytest.importorskip("dask.distributed")

    class Unreachable:
        def __init__(self, address, **kwargs):
            raise OSError(f"Timed out trying to connect to {address} after 30 s")

    monkeypatch.setattr(distributed, "Client", Unreachable)
    with pytest.raises(InputError, match=r"cannot use the Dask scheduler 'tcp://127.0.0.1:1': Timed out"):
        run_batch(square_or_raise, [1], scheduler="tcp://127.0.0.1:1")


def test_a_scheduler_of_another_type_is_an_input_error():
    """A scheduler that is neither an address nor a Cluster (42) is an InputError naming it, not distributed's
    TypeError (session 59's tester)."""
    pytest.importorskip("dask.distributed")
    with pytest.raises(InputError, match=r"cannot use the Dask scheduler 42: .*string or a Cluster"):
        run_batch(square_or_raise, [1], scheduler=42)


def test_missing_dask_says_what_to_install(monkeypatch):
    """A scheduler given while dask cannot be imported (the import is made to fail) is an InputError that names the
    pip install 'dask[distributed]' to run, not an ImportError."""
    import builtins

    real_import = builtins.__import__

    def no_dask(name, *args, **kwargs):
        if name.startswith("dask"):
            raise ImportError(f"No module named {name!r}")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_dask)
    with pytest.raises(InputError, match=r"pip install 'dask\[distributed\]'"):
        run_batch(square_or_raise, [1], scheduler="tcp://127.0.0.1:1")


def test_default_workers_count_the_cpus_the_process_may_run_on(monkeypatch):
    """run_batch's default worker count is the CPUs of the process's affinity (`taskset -c 0`, a container's cpuset),
    as race counts them: it was the machine's count, two workers competing for one CPU."""
    import os

    from planner.batch import default_workers

    if not hasattr(os, "sched_getaffinity"):
        pytest.skip("no CPU affinity on this platform")
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0})
    assert default_workers(8) == 1


def test_in_process_runs_what_no_worker_could_import():
    """workers=0 runs the jobs in this process, so a function no worker process could import (a lambda) runs too
    (session 65's mutation testing sent workers=0 to a process pool, which refused the lambda, and every test stayed
    green: the in-process test's function imports anywhere)."""
    assert run_batch(lambda x: 2 * x, [1, 2], workers=0) == [2, 4]


def kills_its_worker(arg):
    """("ok", marker): returns "ok"; ("once", marker): kills its worker the first time (marker file absent), then
    returns "once"; ("always", marker): kills its worker every time."""
    import os
    import pathlib
    import signal

    kind, marker = arg
    if kind == "always" or (kind == "once" and not os.path.exists(marker)):
        if kind == "once":
            pathlib.Path(marker).write_text("killed")
        os.kill(os.getpid(), signal.SIGKILL)
    return kind


def test_the_jobs_of_a_dead_worker_are_rerun_each_once_in_its_own_process(tmp_path):
    """A worker's death loses the jobs its pool had not returned; each is rerun once in a fresh process (module
    docstring): a job whose worker dies once (SIGKILL) gives its own result on its rerun, without a trace; the job
    that kills its worker again is the one Crashed record, of stage "worker", "the worker process died"; the jobs after
    it are not hurt; progress is called once per item (session 66's mutation testing: a lost job made a Crashed record
    without its rerun; the reruns sharing one pool, whose break made every later job a crash; a lost job's progress
    called twice, first with None; the rerun's death recorded as stage "transfer"; with every test green)."""
    marker = str(tmp_path / "marker")
    items = [("ok", marker), ("once", marker), ("always", marker), ("ok", marker)]
    seen = []
    results = run_batch(kills_its_worker, items, workers=1, progress=lambda i, result: seen.append(i))
    assert results[0] == results[3] == "ok" and results[1] == "once", results
    assert isinstance(results[2], Crashed) and results[2].stage == "worker", results[2]
    assert results[2].error.startswith("the worker process died")
    assert sorted(seen) == [0, 1, 2, 3]
