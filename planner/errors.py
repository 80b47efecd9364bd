"""One exception tree for the planner.

`InputError` and its subclasses are the user's to fix (the CLI prints one line and exits 2);
`SolveError` means the numerics failed on valid input (exit 1, diagnostics still written).
"""
from __future__ import annotations

import contextlib
import decimal
import errno
import io
import math
import numbers
import os
import signal
import sys
import threading
from collections.abc import Iterable
from dataclasses import fields, is_dataclass
from enum import Enum
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # NumPy loads where it is used: the `planner` command imports this module before main can catch a
    # Ctrl-C, and NumPy's import took a third of that time
    import numpy as np


# OS errors about a path the user gave (a name too long, a loop of links, a file where a directory should be, no
# permission, a read-only or immutable file): the user's to fix, exit 2; the others (a full disk, an I/O error) exit 1
PATH_ERRNOS = frozenset({errno.ENAMETOOLONG, errno.ELOOP, errno.ENOTDIR, errno.ENOENT, errno.EISDIR, errno.EACCES,
                         errno.EROFS, errno.EPERM, errno.EEXIST})


def write_error(path, exc: OSError, doing: str = "cannot write") -> PlannerError:
    """The error to raise for an OSError writing `path`: an InputError when the path is refused (PATH_ERRNOS), else a
    PlannerError (exit 1: a full disk is not the user's input); the message is `DOING PATH: reason`."""
    kind = InputError if exc.errno in PATH_ERRNOS else PlannerError
    return kind(f"{doing} {path}: {exc.strerror or exc}")


def read_error(path, exc: OSError, kind: type | None = None, doing: str = "cannot read") -> PlannerError:
    """The error to raise for an OSError reading `path`, as write_error splits a write's: `kind` (default InputError)
    when the path is refused or the error has no errno, else a PlannerError (exit 1: an I/O error is the machine's);
    the message is `DOING PATH: reason`."""
    user = exc.errno is None or exc.errno in PATH_ERRNOS
    return ((kind or InputError) if user else PlannerError)(f"{doing} {path}: {exc.strerror or exc}")


class PlannerError(Exception):
    """Base of every error the planner raises on purpose."""


class InputError(PlannerError):
    """Bad input: a file, a name, a task key or value. The message says how to fix it."""


class RobotFileError(InputError):
    """The robot file is missing, unreadable, of an unknown format, or not parsable."""


class UnknownNameError(InputError):
    """A name (point, joint, task key, ...) that does not exist; the message lists the valid ones."""

    def __init__(self, kind: str, name: str, valid: Iterable[str], key: str = "", ordered: bool = False):
        """key: where the name was given (a task key such as "plan.joint_bounds[0].joint"), said first; ordered: list
        `valid` as given (joints in coordinate order, the order of the task's vectors), else sorted."""
        self.kind, self.name, self.valid = kind, name, list(valid) if ordered else sorted(valid)
        # a name with spaces at its ends, a comma or a control character is quoted: "valid joints: x , z" hid that
        # the joint was "x " (a joint "x, z" read as two)
        listed = ", ".join(v if v.strip() == v and "," not in v and v.isprintable() and v else repr(v)
                           for v in map(str, self.valid))
        super().__init__(f"{key + ': ' if key else ''}unknown {kind} {name!r}; valid {kind}s: {listed or '(none)'}")

    def __reduce__(self):
        # pickle rebuilt it by calling __init__ with its message alone: a multiprocessing pool's result thread died
        # on the TypeError and the pool hung; the message (args, maybe prefixed since) and attributes are kept as set
        return _new_exception, (type(self),), {**self.__dict__, "args": self.args}


def _new_exception(cls: type) -> BaseException:
    """An instance of the exception class cls without calling its __init__ (UnknownNameError.__reduce__)."""
    return cls.__new__(cls)


class TaskError(InputError):
    """A task file with a wrong key, type or value."""


class SolveError(PlannerError):
    """The numerical solve or the validation failed on valid input."""


@contextlib.contextmanager
def interruptible(defer: bool = False):
    """Around a CasADi solver call: an exception that a signal's Python handler raises during it (Ctrl-C's
    KeyboardInterrupt, a program's SIGALRM timeout) is raised once the call returns. CasADi's IPOPT catches it,
    stops with NonIpopt_Exception_Thrown and returns as if the NLP had failed, so the homotopy went on to its next NLP
    (a --no-race plan interrupted after 1 s wrote a converged plan, exit 0; an API solve under an alarm returned
    converged). A handler that raises nothing (a program's graceful stop) stops nothing. Where a signal is ignored (a
    race's arms, a background job) or off the main thread, nothing changes. defer: the handlers run only after the
    block, which the signal does not stop at all (a result's plots, drawn whole)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    handlers = {s: h for s in signal.valid_signals() if callable(h := signal.getsignal(s))}
    raised: list[BaseException] = []  # what the handlers raised, the first one re-raised after the block
    deferred: list = []  # (handler, signum) to run after a deferring block

    def wrap(previous):
        def note(signum, frame):
            if defer:
                deferred.append((previous, signum))
                return
            try:
                previous(signum, frame)  # raising stops CasADi's IPOPT at its next check
            except BaseException as exc:
                raised.append(exc)
                raise
        return note

    wrappers = {s: wrap(h) for s, h in handlers.items()}
    for s, w in wrappers.items():
        signal.signal(s, w)
    entry = (raised, defer)
    _PENDING.append(entry)
    try:
        yield
    except Exception:  # CasADi may return the interrupt as its own RuntimeError ("... KeyboardInterrupt"): a traceback
        if not raised:
            raise
    finally:
        _PENDING[:] = [e for e in _PENDING if e is not entry]  # its own, should blocks end out of order
        for s, h in handlers.items():
            if signal.getsignal(s) is wrappers[s]:  # a handler the block installed itself stays
                signal.signal(s, h)
        for previous, signum in deferred:  # also after the block's own error (the Ctrl-C was lost behind it)
            previous(signum, None)
    if raised:
        raise raised[0]


_PENDING: list = []  # (exceptions raised by signal handlers, defer) of each interruptible block (main thread only)


def _pending_interrupt() -> BaseException | None:
    """The first exception a signal's handler raised during an interruptible block that does not defer it; off the
    main thread (whose blocks these are), none."""
    if threading.current_thread() is not threading.main_thread():
        return None
    return next((raised[0] for raised, defer in list(_PENDING) if raised and not defer), None)


def check_interrupted() -> None:
    """The exception a signal's handler raised during an interruptible block that does not defer it, when a library
    swallowed it: for loops of many CasADi calls (a MuJoCo replay's controller), which otherwise ran to their end
    (`planner gait` walked all its steps and printed its summary, then exited 130). Off the main thread: nothing."""
    if (exc := _pending_interrupt()) is not None:
        raise exc


def interrupted() -> bool:
    """Whether check_interrupted would raise: for a callback whose exceptions its caller swallows (IPOPT's iteration
    callback, homotopy._StopWhenInterrupted)."""
    return _pending_interrupt() is not None


_STDOUT = threading.Lock()  # sys.stdout is the process's: two threads' swaps interleaved left it on a StringIO
os.register_at_fork(after_in_child=lambda: globals().update(_STDOUT=threading.Lock()))  # (held by another thread)


@contextlib.contextmanager
def captured_stdout():
    """sys.stdout swapped for a StringIO (yielded) while a library prints there (CasADi's IPOPT, meshcat), one thread
    at a time: two threads' overlapping swaps left the program's sys.stdout on a StringIO for good. Other threads'
    prints meanwhile are caught too."""
    with _STDOUT, contextlib.redirect_stdout(io.StringIO()) as printed:
        yield printed


# what stops a command: Ctrl-C, SIGTERM (`timeout`, a CI cancellation) and SIGHUP (its terminal closed, its ssh
# session ended: meshcat's server outlived a `planner view` that died of it)
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


@contextlib.contextmanager
def signals_held():
    """Ctrl-C, SIGTERM and SIGHUP (STOP_SIGNALS) wait until the block has ended (on the main thread), then come as
    they would have: Python's KeyboardInterrupt, the CLI's handler, or death. They are held by handlers that note
    them, not by a signal mask, which holds one thread only: with another thread in the process (a test suite's
    leftovers, a server) the kernel gave the signal to that one and Python raised it inside the block (between a
    result's renames: files of two results; inside a race's reaping: arms left unreaped). An ignored one stays
    ignored; off the main thread: none."""
    main = threading.current_thread() is threading.main_thread()
    previous = {sig: signal.getsignal(sig) for sig in STOP_SIGNALS} if main else {}
    swapped = [sig for sig, handler in previous.items() if handler is not signal.SIG_IGN and handler is not None]
    arrived: list[int] = []
    for sig in swapped:
        signal.signal(sig, lambda signum, frame: arrived.append(signum))
    try:
        yield
    finally:
        for sig in swapped:
            signal.signal(sig, previous[sig])
        for sig in dict.fromkeys(arrived):
            signal.raise_signal(sig)


def usable_cpus() -> int:
    """The CPUs this process may run on (its affinity mask, not the machine's count)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def killed_with_parent() -> None:
    """A worker process gets SIGKILL when its parent dies (Linux prctl PR_SET_PDEATHSIG), instead of solving on for
    minutes with no one to read its result (a race's arm, a batch's worker after the sweep was stopped); it exits at
    once when the parent died before the call."""
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # 1 = PR_SET_PDEATHSIG
    except (OSError, AttributeError):  # not Linux: the parent's own cleanup is all there is
        pass
    import multiprocessing

    # reparented to PID 1: orphaned, unless the parent is PID 1 itself (the planner as a container's first process,
    # `docker run` without --init: every race arm and batch worker took itself for an orphan and the race failed)
    parent = multiprocessing.parent_process()
    if os.getppid() == 1 and (parent is None or parent.pid != 1):
        os._exit(1)


def expect(value, kind: type | tuple[type, ...], what: str) -> None:
    """InputError naming `what` when `value` is not a `kind` (an API call given a path for a Robot, a SolveOptions for a
    ProblemOptions): the user's slip named at the call, not an AttributeError from deep inside."""
    if not isinstance(value, kind):
        names = " or ".join("None" if k is type(None) else k.__name__ for k in (kind if isinstance(kind, tuple) else (kind,)))
        raise InputError(f"{what} must be a {names}, got {type(value).__name__} {value!r:.60}")


C_INT_MAX = 2**31 - 1  # IPOPT and CasADi read ints as C ints: max_iter = 2**32 + 3 wrapped around to 3 iterations


def representable(value, kind: str) -> bool:
    """Whether the number `value` fits where it goes: a C int for kind "int", a double for kind "float" (an int of 400
    digits raised OverflowError deep inside instead of the field's message)."""
    if kind == "int":
        return -C_INT_MAX - 1 <= value <= C_INT_MAX
    return not isinstance(value, int) or abs(value) <= sys.float_info.max


def plain(value):
    """A numpy scalar or array as the Python number or (nested) list it holds, anything else as it is: a notebook's
    np.int64 for an int field or np.array for a tuple was refused as "not an integer", "not an array"."""
    return value.tolist() if type(value).__module__ == "numpy" and hasattr(value, "tolist") else value


def real_array(value, what: str) -> np.ndarray:
    """`value` as a float array (a copy); an InputError naming `what` when it holds complex numbers (float() would
    drop the imaginary part with a warning), strings (numpy parsed "1.0"), None or a number no double holds."""
    import numpy as np

    given = None
    try:
        given = None if value is None else np.asarray(value)
        kind = "N" if given is None else given.dtype.kind
        if kind == "O" and any(v is None for v in given.ravel()):  # (float() of None is nan: no error)
            kind = "N"
        if kind not in "cNUS":
            return np.array(value, dtype=float)
    except OverflowError:
        kind = "int"
    except ValueError:
        kind = "ragged" if given is None and value is not None else "O"  # (lists of several lengths; a float() refusal)
    except TypeError:  # an object no float takes
        kind = "O"
    if kind == "c":
        raise InputError(f"{what} must hold real numbers, got complex numbers")
    got = {"N": "None", "U": "strings", "S": "bytes", "int": "an integer beyond a double's range",
           "ragged": "sequences of different lengths"}.get(kind, shown(value))
    raise InputError(f"{what} must hold numbers a double can hold, got {got}")


def options_record(opts) -> dict:
    """An options dataclass as summary.json records it: Enums by value, tuples as lists, nested dataclasses as dicts."""
    out = {}
    for k, v in vars(opts).items():
        if is_dataclass(v):  # e.g. ProblemOptions.fesd
            out[k] = options_record(v)
            continue
        out[k] = (v.value if isinstance(v, Enum) else
                  [list(e) if isinstance(e, tuple) else e for e in v] if isinstance(v, tuple) else v)
    return out


def is_integer(value) -> bool:
    """An int (numpy's too), not a bool (a float or nan is none: nan < 1 is False, and it slipped through)."""
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def shown_up(value: float, decimals: int = 10) -> str:
    """value >= 0 (a depth [m]) rounded up at `decimals` decimals, trailing zeros dropped: added back as printed, it
    clears the 1e-9 m the depth was refused by (0.0187355 of 6 significant digits did not, nor 10 digits at 12 m)."""
    scaled = float(value) * 10**decimals  # (a numpy float warned of its overflow on the way)
    if not math.isfinite(scaled):  # (1e300 m overflowed math.ceil)
        return f"{value:.17g}"
    # rounding first: 0.07 printed as 0.0700000001, its float error rounded up as depth
    return f"{math.ceil(round(scaled, 6)) / 10**decimals:.{decimals}f}".rstrip("0").rstrip(".")


def shown(value, width: int = 60) -> str:
    """repr(value) cut to `width` characters for a message (an int of more than 4300 digits, which Python refuses to
    write out, is named as such)."""
    try:
        text = repr(value)
    except ValueError:
        return "<a value with an integer too long to write out>"
    return text if len(text) <= width else text[: width - 3] + "..."


def enum_member(given, enum: type, what: str, allowed: Iterable | None = None):
    """The member of `enum` (of `allowed` if given) that `given` is or whose value it holds ("monotone" from a script as
    from `--solve` JSON), or an InputError naming `what`, the value and the valid values."""
    members = list(enum) if allowed is None else list(allowed)
    member = given if isinstance(given, enum) else next((m for m in members if m.value == plain(given)), None)
    if member not in members:
        raise InputError(f"{what} = {shown(given)} is not allowed; it must be one of {[m.value for m in members]}")
    return member


def enum_field(options, key: str, enum: type, allowed: Iterable | None = None, optional: bool = False) -> None:
    """The field `key` of the frozen dataclass `options` holds a member of `enum` (of `allowed` if given; None too if
    `optional`), given as the member or its value: stored as the member, or an InputError naming the field, the value
    and the valid values (a value was refused by a message that listed it as valid)."""
    given = getattr(options, key)
    if given is None and optional:
        return
    what = f"{type(options).__name__}.{key}"
    try:
        member = enum_member(given, enum, what, allowed)
    except InputError as exc:
        raise InputError(f"{exc}" + (" or None" if optional else "")) from None
    object.__setattr__(options, key, member)


def as_float(value):
    """A Decimal, Fraction or long double as the double it stands for (a float field stores; one too large for a
    double, or Decimal's sNaN, as given), anything else as given."""
    if isinstance(value, (numbers.Real, decimal.Decimal)) and not isinstance(value, (int, float)):
        try:
            return float(value)
        except (OverflowError, ValueError):  # (Decimal("sNaN") raises ValueError)
            pass
    return value


def check_field_types(options, owner: str | None = None, unbounded: Iterable[str] = (), error: type = InputError) -> None:
    """Each field of the dataclass `options` annotated bool, int, float or str, or a tuple of one of them (or that or
    None), holds values of that type (an int for a float) that a C int or a double can hold, and a float is a number,
    not nan, and finite unless its field is in `unbounded` (a bound, where inf means none): an `error` naming the field
    and what is allowed, not a TypeError or a silent nan from a range check later (values from JSON: `planner plan
    --solve`; `x > 0` is False for nan but True for inf). owner: how the message names the dataclass, as its own range
    checks do (e.g. "contact" for ValidationOptions.contact, "" for none); default its class name. A list given for a
    tuple field is stored as a tuple; an int, a Decimal, a Fraction or a long double given for a float as a float, and
    -0.0 as 0.0 (equal options have one repr: Problem.signature)."""
    kinds = {"bool": "true or false", "int": "an integer", "float": "a number", "str": "a string"}
    for f in fields(options):
        names = [t.strip() for t in str(f.type).split("|")]
        given = getattr(options, f.name)
        many = names[0].startswith("tuple[") and names[0].endswith(", ...]")
        kind = names[0][len("tuple["):-len(", ...]")] if many else names[0]
        if kind not in kinds or (given is None and "None" in names):
            continue
        value = plain(given)
        if many and isinstance(value, (tuple, list)):
            value = [plain(v) for v in value]
        if kind == "float":  # Decimal, Fraction, np.longdouble were refused as "not a finite number"
            value = [as_float(v) for v in value] if many and isinstance(value, list) else as_float(value)
        items = value if many and isinstance(value, (tuple, list)) else (value,)
        inf_ok = f.name in unbounded
        if many and not isinstance(value, (tuple, list)):
            ok = False
        elif kind == "bool":
            ok = all(isinstance(v, bool) for v in items)
        elif kind == "str":
            ok = all(isinstance(v, str) for v in items)
        else:
            ok = all(isinstance(v, int if kind == "int" else (int, float)) and not isinstance(v, bool) for v in items)
            ok = ok and all(representable(v, kind) for v in items)
            ok = ok and (kind == "int" or all(v == v and (inf_ok or abs(v) != float("inf")) for v in items))
        if not ok:
            integers = all(isinstance(v, int) and not isinstance(v, bool) for v in items)  # only too large for C
            what = (f"an integer a C int holds, in [{-C_INT_MAX - 1}, {C_INT_MAX}] (its own range is checked next)"
                    if kind == "int" and integers
                    else kinds[kind] if kind != "float"
                    else "a number within a double's range, not nan (inf: no bound)" if inf_ok else "a finite number")
            label = type(options).__name__ if owner is None else owner
            raise error(f"{label + '.' if label else ''}{f.name} = {shown(given, 200)} is not allowed; it must be "
                        + (f"a tuple of which each is {what}" if many else what))
        if kind == "float":  # an int stored as given, or -0.0 (== 0.0), made equal options' reprs, so
            # Problem.signature, differ
            value = [float(v) + 0.0 for v in value] if many else float(value) + 0.0
        if many:  # stored as the tuple it is typed (a list field made hash() raise), of Python numbers
            object.__setattr__(options, f.name, tuple(value))
        elif value is not given:
            object.__setattr__(options, f.name, value)
