"""Batch execution of independent jobs (sweeps, stress runs): local processes or a Dask cluster.

    from planner.batch import run_batch, stage
    results = run_batch(fn, items)                            # local processes (spawn), item order
    results = run_batch(fn, items, workers=0)                 # in this process, one after the other
    results = run_batch(fn, items, scheduler="tcp://host:8786")   # a Dask distributed scheduler

`fn(item)` must be a top-level function (it is sent to the workers by module and name; a function of a
script loaded by path, e.g. scripts/stress.py, is found again from its file) and items and results
must pickle. Every item gives exactly one result, in item order: fn's return value, or a `Crashed`
record when fn raised (or its worker process died, or its result did not come back). A crash never
stops the sweep. `with stage("solve"): ...` inside fn names the stage a crash came from.

Local processes are spawned, so a script that calls run_batch needs the `if __name__ == "__main__":` guard (without
it every job reads "the worker process died"). When a worker dies (killed from outside, or by its job), every job
the pool had not returned is rerun, one at a time, each in a fresh process: only a job that kills its worker again
is a `Crashed` record, a job killed once from outside is rerun without a trace, and the sweep goes on serially.
Dask retries a lost job on other workers as its scheduler is set to.

Dask (`pip install "dask[distributed]"`, the `batch` extra) is imported only when a scheduler is given.
"""
from __future__ import annotations

import contextlib
import importlib
import importlib.util
import multiprocessing
import re
import sys
import traceback
import warnings
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any

from .errors import InputError, killed_with_parent, plain, shown, usable_cpus

CRASHED = "crashed"
DEFAULT_STAGE = "task"  # the stage of a crash outside any `with stage(...)` block


@dataclass(frozen=True)
class Crashed:
    """One item whose job raised instead of returning: the stage, the error line and the traceback."""

    stage: str  # the innermost `with stage(...)` active when it raised, "worker" (process died), "transfer"
    error: str  # "ExceptionType: message"
    traceback: str  # the formatted traceback text
    outcome: str = CRASHED

    def to_json(self) -> dict:
        return {"outcome": self.outcome, "stage": self.stage, "error": self.error, "traceback": self.traceback}


_STAGE_ATTR = "_planner_batch_stage"


@contextlib.contextmanager
def stage(name: str) -> Iterator[None]:
    """Label the exceptions raised inside the block with stage `name` (the innermost label wins)."""
    try:
        yield
    except BaseException as exc:
        if getattr(exc, _STAGE_ATTR, None) is None:
            try:
                setattr(exc, _STAGE_ATTR, name)
            except AttributeError:  # an exception type with __slots__: the stage is lost, not the error
                pass
        raise


def stage_of(exc: BaseException, default: str = DEFAULT_STAGE) -> str:
    """The stage an exception was labelled with by `stage`, else `default`."""
    return getattr(exc, _STAGE_ATTR, None) or default


def crashed_record(exc: BaseException, default_stage: str = DEFAULT_STAGE) -> Crashed:
    """The Crashed record of a caught exception (its stage, one error line, the traceback text)."""
    text = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
    return Crashed(stage=stage_of(exc, default_stage), error=f"{type(exc).__name__}: {exc}", traceback=text)


@dataclass(frozen=True)
class _FnRef:
    """A top-level function by module, qualified name and source file: what the workers import."""

    module: str
    qualname: str
    file: str | None

    @classmethod
    def of(cls, fn: Callable) -> _FnRef | Callable:
        module, qualname = getattr(fn, "__module__", None), getattr(fn, "__qualname__", "")
        if module is None or "<" in qualname:
            raise InputError(f"run_batch needs a top-level function (workers import it by name), got {fn!r}")
        if module == "__main__":  # spawn re-runs the main script in the workers; pickle handles it by name
            return fn
        return cls(module, qualname, getattr(sys.modules.get(module), "__file__", None))

    def resolve(self) -> Callable:
        try:
            mod = importlib.import_module(self.module)
        except ModuleNotFoundError:
            mod = sys.modules.get(self.module)
            if mod is None:
                if not self.file:
                    raise
                spec = importlib.util.spec_from_file_location(self.module, self.file)
                mod = importlib.util.module_from_spec(spec)
                sys.modules[self.module] = mod  # dataclasses look their module up while a class is built
                spec.loader.exec_module(mod)
        obj = mod
        for part in self.qualname.split("."):
            obj = getattr(obj, part)
        return obj


def _call(fn, item):
    """Run one job in a worker: fn(item), or the Crashed record of whatever it raised."""
    try:
        if isinstance(fn, _FnRef):
            with stage("import"):
                fn = fn.resolve()
        return fn(item)
    except KeyboardInterrupt:
        raise
    except BaseException as exc:  # noqa: BLE001 -- every failure of one job (even sys.exit) becomes its record
        return crashed_record(exc)


def default_workers(n_items: int) -> int:
    """The local processes run_batch starts for n_items jobs when given no `workers`: min(usable CPUs, n_items), the
    CPUs of the process's affinity (`taskset`, a container's cpuset) as race counts them, not the machine's."""
    return min(usable_cpus(), n_items)


def _filters() -> tuple[list[tuple], ...]:
    """The caller's warning filters as filterwarnings' arguments, each category by its module and name (a worker is
    spawned with Python's defaults: "ignore" did not silence a job's warnings, "error" did not make it a Crashed
    record)."""
    return ([(action, _pattern(message), (category.__module__, category.__qualname__), _pattern(module), lineno)
             for action, message, category, module, lineno in warnings.filters],)


def _pattern(given) -> str:
    """A filter's message or module as filterwarnings' regex: a str (Python's own filters) matches exactly."""
    return given.pattern if hasattr(given, "pattern") else re.escape(given) + r"\Z" if given else ""


def _worker_start(filters: list[tuple]) -> None:
    """A local worker's start: it dies with the batch's process and runs with the caller's warning filters, but for
    those whose category it cannot import (one defined under the caller's `if __name__ == "__main__":` or in a
    function; as a pickled class it broke every worker's start). Warnings the worker's own imports issue fall under
    them too (under "error" such a job is a Crashed record of the "import" stage)."""
    killed_with_parent()
    warnings.resetwarnings()
    for action, message, (where, name), module, lineno in reversed(filters):  # each inserted at the front
        try:
            category = importlib.import_module(where)
            for part in name.split("."):
                category = getattr(category, part)
        except Exception:  # noqa: BLE001 -- not importable here
            continue
        warnings.filterwarnings(action, message, category, module, lineno)


def run_batch(fn: Callable[[Any], Any], items: Iterable[Any], scheduler: Any = None, workers: int | None = None,
              progress: Callable[[int, Any], None] | None = None) -> list[Any]:
    """fn(item) for every item, results in item order; a job that raised gives a `Crashed` record.

    scheduler: None runs local processes (concurrent.futures, spawn start method, `workers` of them,
    default min(cpu count, number of items)); workers=0 runs the jobs in this process, one after the
    other (debugging, monkeypatched tests). A string is the address of a Dask distributed scheduler
    ("tcp://host:8786"), a dask.distributed.Client is used as it is; `workers` is then ignored.
    progress(index, result) is called as each job finishes (in completion order).
    Local workers run with the caller's warning filters (`warnings.simplefilter("error")` makes a job's warning its
    Crashed record); what they print goes to the descriptors 1 and 2 they inherit, not to a caller's
    `contextlib.redirect_stdout`/`redirect_stderr`.
    """
    if not callable(fn):  # (workers=0 made every job a Crashed record; the pool refused it otherwise)
        raise InputError(f"run_batch's fn must be callable, got {shown(fn)}")
    try:
        items = list(items)
    except TypeError:
        raise InputError(f"run_batch's items must be iterable, got {shown(items)}") from None
    if not items:
        return []
    if scheduler is not None:
        return _run_dask(fn, items, scheduler, progress)
    if workers is not None and (not isinstance(plain(workers), int) or isinstance(plain(workers), bool) or workers < 0):
        raise InputError(f"workers must be None or an integer >= 0, got {shown(workers)}")
    if workers == 0:
        out = []
        for i, item in enumerate(items):
            out.append(_call(fn, item))
            if progress:
                progress(i, out[-1])
        return out
    ref = _FnRef.of(fn)
    n = min(workers, len(items)) if workers else default_workers(len(items))
    ctx = multiprocessing.get_context("spawn")  # no fork of a process holding threads (IPOPT, MuJoCo, BLAS)
    results: list[Any] = [None] * len(items)
    lost: list[int] = []
    # (a stopped sweep's workers solved on with no parent: stress's Capler tasks take up to ~1900 s)
    pool = ProcessPoolExecutor(max_workers=n, mp_context=ctx, initializer=_worker_start, initargs=_filters())
    try:
        futures = {pool.submit(_call, ref, item): i for i, item in enumerate(items)}
        for fut in as_completed(futures):
            i = futures[fut]
            try:
                results[i] = fut.result()
            except BrokenProcessPool:  # some worker died: rerun the affected jobs one by one below
                lost.append(i)
                continue
            except Exception as exc:  # noqa: BLE001 -- e.g. a result that does not pickle
                results[i] = crashed_record(exc, "transfer")
            if progress:
                progress(i, results[i])
    except BaseException:
        _stop(pool)
        raise
    pool.shutdown()
    for i in sorted(lost):  # each in its own process, so the one that kills its worker is the one reported
        pool = ProcessPoolExecutor(max_workers=1, mp_context=ctx, initializer=_worker_start, initargs=_filters())
        try:
            results[i] = pool.submit(_call, ref, items[i]).result()
        except BrokenProcessPool as exc:
            results[i] = Crashed(stage="worker", error=f"the worker process died ({type(exc).__name__}: {exc})",
                                 traceback="".join(traceback.format_exception(type(exc), exc, exc.__traceback__)))
        except Exception as exc:  # noqa: BLE001
            results[i] = crashed_record(exc, "transfer")
        except BaseException:  # (a `with` waited for the running job on a Ctrl-C: up to its whole solve)
            _stop(pool)
            raise
        pool.shutdown()
        if progress:
            progress(i, results[i])
    return results


def _stop(pool: ProcessPoolExecutor) -> None:
    """Cancel the queued jobs and end the running ones (a Ctrl-C, a progress callback's error): leaving the pool's
    `with` waited for every queued job, so a stopped stress run solved all of them and kept none."""
    running = list((getattr(pool, "_processes", None) or {}).values())  # (no public handle on the workers)
    pool.shutdown(wait=False, cancel_futures=True)
    for process in running:
        process.terminate()
    for process in running:
        process.join()


def _run_dask(fn, items: Sequence[Any], scheduler: Any, progress) -> list[Any]:
    try:
        from dask.distributed import Client, as_completed as dask_as_completed
    except ImportError:
        raise InputError("a Dask scheduler was given but dask.distributed is not installed; "
                         "install it with: pip install 'dask[distributed]' (or the planner's `batch` extra)") from None
    own = not isinstance(scheduler, Client)
    try:
        client = Client(scheduler) if own else scheduler
    except (OSError, ValueError, TypeError) as exc:  # unreachable (distributed's connect timeout), not an address
        raise InputError(f"cannot use the Dask scheduler {scheduler!r}: {exc}") from None
    try:
        ref = _FnRef.of(fn)
        futures = client.map(_call, [ref] * len(items), items, pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        results: list[Any] = [None] * len(items)
        for fut in dask_as_completed(futures):
            i = index[fut.key]
            try:
                results[i] = fut.result()
            except Exception as exc:  # noqa: BLE001 -- KilledWorker, a lost connection, an unpicklable result
                results[i] = crashed_record(exc, "worker")
            if progress:
                progress(i, results[i])
        return results
    finally:
        if own:
            client.close()
