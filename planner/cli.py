"""The `planner` command: one subcommand per job; check-model, simulate, plan and gait take a robot file (or the name
of one in robots/), validate and view a result directory.

Exit codes: 0 success; 1 the solve or the validation failed (diagnostics still written); 2 bad input;
130 interrupted (Ctrl-C). A user error prints one line on stderr, never a traceback.
"""
from __future__ import annotations

import argparse
import contextlib
import errno
import importlib
import json
import multiprocessing
import os
import re
import select
import shutil
import signal
import stat
import sys
import tempfile
import threading
import time
import traceback
import uuid
import warnings
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

from .errors import (PATH_ERRNOS, STOP_SIGNALS, InputError, PlannerError, enum_member, interruptible, options_record,
                     shown)

EXIT_OK, EXIT_FAILED, EXIT_INPUT = 0, 1, 2
# the commands that exit 1 when their check or solve fails (view has no such verdict)
EXIT_1_COMMANDS = frozenset({"check-model", "simulate", "plan", "gait", "validate"})
EXIT_INTERRUPTED = 130  # Ctrl-C: 128 + SIGINT, as shells report it
OUT_OF_MEMORY = ("failed: out of memory (is horizon.N or --steps far too large, ~1 MB per step for a robot of Capler's "
                 "size, or the physical time MuJoCo replays too long for this machine?)")
# `planner plan --discretization fesd` ends its homotopy at rho = 1e5 and polishes from there: on the
# point-mass hop (N = 10, n_fe = 3) the polish from the rho = 1e6 point stopped at its 3000-iteration cap,
# the one from the 1e5 point converged in 48 iterations (docs/formulation.md, "FESD in the OCP")
FESD_RHO_MAX = 1e5


class UsageParser(argparse.ArgumentParser):
    """argparse, but a usage error is one line and exit code 2 (UsageExit: main adds --json's object)."""

    def error(self, message):
        text = f"{message} (see --help)"
        if sys.stderr is not None:  # (closed, `2>&-`: print(file=None) wrote it on stdout)
            # a full stderr (`2>/dev/full`) made the line's OSError a traceback: exit 1, not 2, and no --json object
            print(_escaped(f"{self.prog}: error: {text}"), file=_ReaderMayLeave(sys.stderr, diagnostics=True))
        raise UsageExit(text)


class UsageExit(SystemExit):
    """Exit code 2 of a command-line error, with its text."""

    def __init__(self, text: str):
        super().__init__(EXIT_INPUT)
        self.text = text


def path_argument(text: str) -> Path:
    """A path argument; an empty one (an unset shell variable) would be the working directory: refused."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty path is not allowed (an unset shell variable?)")
    return Path(text)


def page_argument(text: str) -> Path:
    """--html's path: path_argument, refused when it ends in / (view.names_a_directory)."""
    from .view import names_a_directory

    if (named := names_a_directory(text)) is not None:
        raise argparse.ArgumentTypeError(named)
    return path_argument(text)


TASK_HELP = "task file or a shipped task's name, e.g. point_mass_hop (default: the .toml beside the robot file)"


def _add_common(p: argparse.ArgumentParser, *, task: bool = True, out: bool = True, plots: bool = False,
                verbose: bool = False, task_help: str = TASK_HELP) -> None:
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object on stdout")
    if task:
        p.add_argument("--task", type=path_argument, help=task_help)
    if out:
        p.add_argument("--out", type=path_argument, help="directory that receives the results (default results/ROBOT-COMMAND, "
                       "e.g. results/capler-plan)")
    racing = p.prog.endswith(" plan")  # what only plan does (a race, a validation) is said in plan's help only
    if plots:
        p.add_argument("--no-plots", action="store_true",
                       help="write no PNG plots (they take ~1.5 s" + ("; a validating plan draws them while MuJoCo replays"
                                                                   if racing else "") + "; `planner view` still works)")
    verbosity = p.add_mutually_exclusive_group()
    if verbose:  # only the commands that run IPOPT have more to show
        verbosity.add_argument("-v", "--verbose", action="store_true", help="also show IPOPT's own output" + (
            " (a racing plan: each line starts with its arm's name, [default] or [alternate])" if racing else ""))
    verbosity.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors and warnings" + (
        ", a one-line failure notice (exit 1)" if p.prog.split()[-1] in EXIT_1_COMMANDS else "")
        + (", the live viewer's URL" if p.prog.split()[-1] == "view" else "") + " and --json")


def build_parser() -> argparse.ArgumentParser:
    parser = UsageParser(prog="planner", description=" ".join(__doc__.split("\n\n")[0].split()),
                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"planner {_version()}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=UsageParser)

    p = sub.add_parser("check-model", help="compare the CasADi dynamics with Pinocchio and MuJoCo",
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog="example:\n  planner check-model capler --samples 50 --json")
    p.add_argument("robot", help="robot file (MJCF or URDF) or the name of one in robots/")
    p.add_argument("--samples", type=int, default=20, help="random states to compare (default 20)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--floating", action="store_true", help="give a URDF robot a free-flyer root joint (legged robots)")
    _add_common(p, task=False, out=False)
    p.set_defaults(run=_cmd_check_model)

    p = sub.add_parser("simulate", help="forward time-freezing simulation of the task's initial state",
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog="examples:\n  planner simulate point_mass --out results/drop\n"
                              "  planner simulate point_mass --task MY_DROP.toml --json\n"
                              "        MY_DROP.toml: your copy of robots/point_mass.toml, edited\n"
                              "  planner simulate point_mass --discretization fesd --stages 2 --out results/drop_fesd   # impact at sqrt(2/g)")
    p.add_argument("robot", help="robot file (MJCF or URDF) or the name of one in robots/")
    p.add_argument("--discretization", default="implicit_euler", metavar="NAME",
                   help="implicit_euler (default, the paper's) or fesd (finite elements with switch detection)")
    p.add_argument("--stages", type=int, help="fesd: Radau IIA stages per element, 1-3 (default 2)")
    p.add_argument("--elements", type=int,
                   help="fesd: finite elements per step, at least one more than the switches in a step "
                        "(default 4: an impact step holds its start, the end of the frozen phase and the landing mode)")
    p.add_argument("--steps", type=int, metavar="N",
                   help="override the task's [horizon] N (same tau_f, so h = tau_f / N), as `plan --steps` does")
    _add_common(p, plots=True, verbose=True)
    p.set_defaults(run=_cmd_simulate)

    p = sub.add_parser("plan", help="solve the task's time-freezing OCP, then validate it in MuJoCo",
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog="examples:\n"
                              "  planner plan capler --out results/capler --no-validate   # the README's main job\n"
                              "  planner plan point_mass --task robots/point_mass_hop.toml --no-validate --json\n"
                              "  planner plan capler --discretization fesd --stages 1 --elements 2 \\\n"
                              "        --fesd-start implicit_euler --out results/capler_fesd\n"
                              "  planner plan capler --task MY_CAPLER.toml --init results/capler --out results/mine\n"
                              "        a replan; MY_CAPLER.toml: your copy of robots/capler.toml, target_q moved")
    p.add_argument("robot", help="robot file (MJCF or URDF) or the name of one in robots/")
    p.add_argument("--no-validate", action="store_true", help="skip the MuJoCo validation of the plan")
    p.add_argument("--init", type=path_argument, metavar="DIR",
                   help="replan from the plan in DIR (a `planner plan` result with the same contacts, N and options) after a "
                        "change of target, bounds or holes that DIR's plan nearly meets: first one smooth NLP with DIR's contact "
                        "schedule held (its impacts on the same steps; Capler's target moved 0.1 m: ~30 iterations, "
                        "~1 s of solve; 3.0 -> 3.4 m in ~4 s); if that is refused, a walk there through tasks between "
                        "DIR's task and "
                        "this one, every number of the task file moved part of the way (the biped's step 0.25 -> 0.30 m: "
                        "~10 s); if the walk stalls, the penalty replan (--penalty-replan). The held schedule keeps "
                        "DIR's timing; a walk that stalls may re-time it on the way (a penalty replan of the task "
                        "between, named \"retime\"). Implicit Euler only; finds the plan next to DIR's, not a new "
                        "hint-free search")
    p.add_argument("--keep-schedule", action="store_true",
                   help="with --init: what --init does by default (the held schedule first); kept so that older commands run")
    p.add_argument("--penalty-replan", action="store_true",
                   help="with --init: skip the held schedule and the walk; solve one NLP at a high penalty from DIR's plan, "
                        "then polish. It may find a cheaper timing than DIR's, but it can be slower than planning "
                        "hint-free: Capler's target moved to 2.9 m took 5878 iterations against the 3.0 m plan's 2338 "
                        "(to 3.1 m, 1126; docs/benchmarks.md sessions 41 and 61)")
    p.add_argument("--allow-new-impacts", action="store_true",
                   help="with --init: also accept a held schedule that adds impacts DIR's plan does not have, of any "
                        "impulse (SolveOptions.schedule_new_impacts; without it only taps below 5%% of DIR's largest impulse; on the "
                        "biped it takes dearer gaits)")
    p.add_argument("--discretization", default="implicit_euler", metavar="NAME",
                   help="implicit_euler (default, the paper's) or fesd (finite elements with switch detection; converges on the "
                        "point-mass hop; on Capler with --stages 1 --elements 2, hint-free or through --fesd-start implicit_euler; docs/formulation.md \"FESD in the OCP\")")
    p.add_argument("--stages", type=int, help="fesd: Radau IIA stages per element, 1-3 (default 2)")
    p.add_argument("--elements", type=int,
                   help="fesd: finite elements per step (default 3: a landing step holds the touchdown and the ends of the tangential and normal jumps)")
    p.add_argument("--steps", type=int, metavar="N",
                   help="override the task's [horizon] N (same tau_f, so h = tau_f / N): e.g. a coarser grid to compare "
                        "implicit Euler and FESD plans on")
    p.add_argument("--fesd-start", metavar="NAME",
                   help="fesd: hint_free (default: the FESD homotopy from y_0 everywhere, u = 0) or implicit_euler (solve the "
                        "implicit-Euler OCP from its hint-free start, map its plan onto the FESD variables, then FESD NLPs at "
                        "rho 1e4 and 1e5 and the polish; docs/formulation.md \"FESD in the OCP\")")
    p.add_argument("--ipopt", action="append", default=[], metavar="NAME=VALUE",
                   help="an IPOPT option for every NLP of the homotopy (repeatable), e.g. --ipopt alpha_for_y=min; "
                        "checked by IPOPT (SolveOptions.ipopt)")
    p.add_argument("--warm-ipopt", action="append", default=[], metavar="NAME=VALUE",
                   help="the same for NLP 2 and later only (SolveOptions.warm_ipopt)")
    p.add_argument("--solve", metavar="JSON", action="append", default=[],
                   help="SolveOptions fields as a JSON object, over the flags above, e.g. --solve '{\"rho_f_schedule\": [10]}' "
                        "(enums by value, lists for tuples; an unknown field or value is an error; repeatable, "
                        "each field once; planner.homotopy.SolveOptions)")
    p.add_argument("--no-race", action="store_true",
                   help="solve with the default variant only (deterministic). Without it a hint-free implicit-Euler plan "
                        "races a second variant (multipliers carried between NLPs, the inertia correction started from its "
                        "last value, MUMPS without its matching) on a second CPU, if there is one, and keeps the first to "
                        "converge (planner.race; two that finish close together may swap between machines)")
    _add_common(p, plots=True, verbose=True)
    p.set_defaults(run=_cmd_plan)

    p = sub.add_parser("gait", help="periodic biped gait by paper 001's embedding, relaxation, Newton and PRONTO",
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog="example:\n  planner gait biped --task biped_gait1 --out results/gait1")
    p.add_argument("robot", help="robot file (MJCF or URDF) or the name of one in robots/")
    p.add_argument("--no-validate", action="store_true", help="skip the MuJoCo walking replay")
    _add_common(p, task_help="task file with a [gait] table or a shipped one's name (required, e.g. biped_gait1)")
    p.set_defaults(run=_cmd_gait)

    p = sub.add_parser("validate", help="replay a plan in MuJoCo (kinematic, tracking, open loop)",
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog="example:\n  planner validate results/capler --json")
    p.add_argument("dir", type=path_argument, help="a result directory written by `planner plan` or `planner simulate`")
    p.add_argument("--controller", choices=("joint_pd", "stance_retarget"), default=None,
                   help="feedback law of the tracking replay (default joint_pd; docs/validation.md)")
    p.add_argument("--window", type=float, default=None, metavar="SECONDS",
                   help="length of the windows in which the tracking replay restarts from the plan [s] "
                        "(default 0.1; one starts every 25 ms)")
    _add_common(p, task=False, out=False)
    p.set_defaults(run=_cmd_validate)

    p = sub.add_parser("view", help="meshcat replay of a result: live, or a self-contained HTML page",
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog="examples:\n  planner view results/capler                 # live; prints the URL\n"
                              "  planner view results/capler --html hop.html --slow-motion")
    p.add_argument("dir", type=path_argument, help="a result directory written by `planner plan`, `planner simulate` or `planner gait`")
    p.add_argument("--html", type=page_argument, help="write a static page that works offline instead of serving")
    p.add_argument("--slow-motion", action="store_true", help="also show the frozen (impact) intervals")
    _add_common(p, task=False, out=False)
    p.set_defaults(run=_cmd_view)
    parser.subcommands = sub.choices  # (a usage error's --json object names the command given)
    return parser


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("planner")
    except PackageNotFoundError:  # (a checkout on sys.path, not installed)
        return "(not installed)"


def _parse(parser: argparse.ArgumentParser, argv: list[str]) -> argparse.Namespace:
    """parse_args, with an unknown argument refused by its subcommand's parser: the top-level parser said "planner:
    error: unrecognized arguments" and pointed at its own --help, which lists no subcommand's options; what is given
    before the command, other than the top-level options, is said to go after it (`--out x plan` was "invalid choice:
    'x'")."""
    top = set(parser._option_string_actions)
    for first in (i for i, a in enumerate(argv) if i and a in parser.subcommands):  # (a value may be named like one)
        early = argv[:first]
        if _options_of(parser.subcommands[argv[first]], early, top):
            parser.subcommands[argv[first]].error(
                f"{' '.join(early)} goes after the command: planner {argv[first]} ... {' '.join(early)}")
    args, extra = parser.parse_known_args(argv)
    if extra:
        parser.subcommands[args.command].error(f"unrecognized arguments: {' '.join(extra)}")
    return args


def _options_of(command: argparse.ArgumentParser, tokens: list[str], top: set[str]) -> bool:
    """Whether tokens given before `command` are options of it with their values (`--out x`, `-qv`) besides the
    top-level ones, and nothing else: an unknown option or a stray word is argparse's to refuse (`--bogus` was told to
    go after the command, and `plna x --out simulate` that `plna` did)."""
    known, rest, mine = command._option_string_actions, list(tokens), False
    while rest:
        token = rest.pop(0)
        key = token.split("=", 1)[0]
        if key in top:
            continue
        if key in known:
            mine = True
            if known[key].nargs != 0 and "=" not in token:
                if not rest:
                    return False  # (its value is the command's name: `--out plan plan x` lost it)
                rest.pop(0)  # its value
        elif key.startswith("-") and not key.startswith("--") and all(f"-{c}" in known for c in key[1:]):
            mine = True  # combined short flags
        else:
            return False
    return mine


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    _closed_to_devnull()
    parser = build_parser()
    try:
        args = _parse(parser, argv)
    except UsageExit as exc:  # argparse stops before --json is read: the JSON object was missing
        if any(len(a) > 2 and "--json".startswith(a) for a in argv):  # (argparse takes --js for --json too)
            command = next((a for a in argv if a in parser.subcommands), None)
            print(json.dumps({"command": command, "exit_code": EXIT_INPUT, "error": exc.text}), flush=True)
        raise
    # stdout is the command's summary (--json: one JSON object); everything else printed there (IPOPT's log with -v,
    # which CasADi writes to sys.stdout, also from the race's forked arms) goes to stderr
    # (None: closed by the shell, >&-)
    out, err = (None if stream is None else _ReaderMayLeave(stream, diagnostics) for stream, diagnostics in
                ((sys.stdout, False), (sys.stderr, True)))
    args.stdout, args.stderr = out, err
    redirect = getattr(args, "json", False) or getattr(args, "verbose", False) or _asks_ipopt_log(args)
    quiet_stdout = contextlib.redirect_stdout(err if redirect else out)
    try:
        # NumPy and Pinocchio before the command's own libraries, as `import planner` loaded them (the shared objects'
        # load order of every documented run), here where a Ctrl-C during their load is the one line as well
        importlib.import_module(".model", __package__)
        # restores showwarning for an in-process caller
        # a solving command's Ctrl-C that a library swallowed (CasADi's callbacks) is raised once it returns (view's
        # server ends by Ctrl-C, exit 0)
        solving = interruptible() if args.command in ("simulate", "plan", "gait") else contextlib.nullcontext()
        # (the live view's server ends by it, exit 0)
        with quiet_stdout, contextlib.redirect_stderr(err), warnings.catch_warnings(), _term_as_ctrl_c(), solving:
            # one line, as every other message: Python's format adds the source line that issued it
            # libraries' deprecations are for their callers' developers (Python hides them outside __main__; a test
            # runner showed pyzmq's through meshcat as a second line of a one-line error)
            warnings.simplefilter("ignore", DeprecationWarning)
            for category in (UserWarning, RuntimeWarning):  # printed as warnings also under PYTHONWARNINGS=error,
                # which made the planner's input warnings tracebacks (PYTHONWARNINGS=ignore still silences them)
                if next((f[0] for f in warnings.filters if issubclass(category, f[2])), "default") == "error":
                    warnings.simplefilter("default", category)
            warnings.showwarning = lambda message, category, *_: _to_stderr(
                args, f"planner {args.command}: warning: {message}"
                + ("" if category is UserWarning else f" ({category.__name__})"))
            code = args.run(args)
        # -q hides the report, not the failure (an exit 1 printed nothing at all)
        if code == EXIT_FAILED and getattr(args, "quiet", False):  # where its diagnostics went, and a replan's advice
            written, advice = getattr(args, "written", None), getattr(args, "advice", None)
            _to_stderr(args, f"planner {args.command}: failed{_failure(getattr(args, 'summary', {}))}"
                       + (f" (results in {written})" if written else "") + (f"; {advice}" if advice else ""))
        return code
    except InputError as exc:
        return _stop(args, EXIT_INPUT, f"error: {exc}")
    except PlannerError as exc:
        return _stop(args, EXIT_FAILED, f"failed: {exc}")
    except BrokenPipeError:  # `planner ... | head`: the reader left; that is not an error
        _to_devnull(sys.stdout.fileno())
        return EXIT_OK
    except OSError as exc:
        where = f": {exc.filename}" if exc.filename else ""
        try:
            os.getcwd()
        except FileNotFoundError:  # ("failed: No such file or directory", exit 1, naming nothing)
            return _stop(args, EXIT_INPUT, "error: the working directory no longer exists; change to one that does")
        if exc.errno in PATH_ERRNOS and exc.filename:  # a path the system refuses that no check above named
            return _stop(args, EXIT_INPUT, f"error: {exc.strerror}{where}")
        return _stop(args, EXIT_FAILED, f"failed: {exc.strerror or exc}{where}")  # e.g. a full disk
    except MemoryError:  # e.g. horizon.N = 1e9: numpy's allocation, not a traceback
        return _stop(args, EXIT_FAILED, OUT_OF_MEMORY)
    except RuntimeError as exc:  # CasADi's C++ allocation (N = 5000 under a 2.5 GB limit): a 35-line traceback
        if "std::bad_alloc" not in str(exc):
            raise
        return _stop(args, EXIT_FAILED, OUT_OF_MEMORY)
    except KeyboardInterrupt:  # Ctrl-C: one line, the shell's code for SIGINT; results are written atomically or not at all
        with _interrupts_ignored():
            _written_line(args)
            return _stop(args, EXIT_INTERRUPTED, "interrupted")
    except SystemError as exc:  # a Ctrl-C in a Python callback CasADi called: "returned a result with an exception set"
        if isinstance(exc.__cause__ or exc.__context__, KeyboardInterrupt):
            with _interrupts_ignored():
                return _stop(args, EXIT_INTERRUPTED, "interrupted")
        raise


@contextlib.contextmanager
def _interrupts_ignored():
    """Ctrl-C, SIGTERM and SIGHUP ignored while the interruption is reported (on the main thread), the handlers restored
    after: a second Ctrl-C 10-80 ms after the first (a double press) printed a traceback from inside the report."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.signal(s, signal.SIG_IGN) for s in STOP_SIGNALS}
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h if h is not None else signal.SIG_DFL)


@contextlib.contextmanager
def _term_as_ctrl_c():
    """SIGTERM (`timeout`, a CI cancellation, systemd) and SIGHUP (the terminal closed) handled as the Ctrl-C they
    stand for: the results are written whole or not at all, and a good earlier result keeps its plots (a SIGTERM while
    they were set aside hid them in a temporary directory; one while the new plots were drawn left none); `view`'s
    meshcat server is stopped. Where Ctrl-C is ignored (a background job of a script) it is raised as
    KeyboardInterrupt all the same; a forked child (a race's arm) ends as before. An ignored SIGHUP (`nohup`) stays
    ignored."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    owner = os.getpid()

    def term(signum, frame):
        if os.getpid() != owner:  # (the handler is inherited by fork)
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
            return
        handler = signal.getsignal(signal.SIGINT)
        if not callable(handler):
            raise KeyboardInterrupt
        handler(signal.SIGINT, frame)

    stops = [signal.SIGTERM] + [signal.SIGHUP] * (signal.getsignal(signal.SIGHUP) is not signal.SIG_IGN)
    previous = {s: signal.signal(s, term) for s in stops}
    # an ignored Ctrl-C (a script's background job, which the script's Ctrl-C must not stop) stays ignored: it was
    # switched on, and a Ctrl-C meant for the script stopped the plan. SIGTERM's handler raises the KeyboardInterrupt
    # itself, and errors.interruptible wraps that handler as it wraps Ctrl-C's (IPOPT stops, then the interruption)
    try:
        yield
    finally:  # (None: a handler not installed from Python)
        for s, handler in previous.items():
            signal.signal(s, signal.SIG_DFL if handler is None else handler)


def _asks_ipopt_log(args) -> bool:
    """Whether a --solve object sets print_level > 0: IPOPT's log, which goes to stderr as -v's does (it went to
    stdout, into the command's summary)."""
    for text in getattr(args, "solve", None) or ():
        with contextlib.suppress(ValueError, AttributeError, RecursionError):  # (not JSON or no object: said later)
            level = json.loads(text).get("print_level")
            if isinstance(level, int) and level > 0:
                return True
    return False


# [s] how long a write to a non-blocking stderr waits for its reader to take any byte before the reader counts as
# gone: a blocking stream waits for ever, but a reader that stopped for good (a paused pipeline) must not hang the solve
# or, with Ctrl-C ignored while it is reported, the "interrupted" line; a slow reader (`| less`, a busy terminal
# multiplexer) takes some bytes well within it. stdout has none while a Ctrl-C can end its wait: it is written after
# the results, and its reader (--json's) needs the whole text, which a reader that paused longer got cut short (exit 1)
STALLED_READER_S = 10.0


class _ReaderMayLeave:
    """A text stream whose reader may go away (`planner plan ... 2>&1 | grep -m1 homotopy`, or a terminal that closed):
    at the first write or flush error that says so (a broken pipe; a terminal's hang-up, EIO) the stream's descriptor
    is pointed at /dev/null, so that the text and all later output of the run are dropped, and the command goes on,
    writes its results and exits as it would (the solve stopped at the first progress line the pipe refused, nothing
    was written and the exit code was 0; a plan whose terminal hung up exited 1 on the EIO of its "interrupted" line,
    not 130). diagnostics: stderr, where any other write or flush error does the same (`2>/dev/full` stopped a solve at
    its first progress line, exit 1, nothing written); a full stdout still fails the command ("No space left on
    device", exit 1: --json's reader would get nothing). A non-blocking stream (a terminal multiplexer's, or a pipe
    another process set so) whose reader is momentarily behind is not one that left: the text is written as bytes
    straight to its descriptor, waiting for the reader as a blocking stream would (the first time its pipe was full,
    the rest of the run's stderr went to /dev/null); for diagnostics, only while it takes any byte within
    STALLED_READER_S: one that takes nothing for so long is gone."""

    def __init__(self, stream, diagnostics: bool = False):
        self._stream, self._diagnostics = stream, diagnostics

    def _guarded(self, name: str, *args):
        try:
            if self._nonblocking():
                return self._patiently(name, *args)
            return getattr(self._stream, name)(*args)
        except OSError as exc:
            if not (self._diagnostics or isinstance(exc, BrokenPipeError) or exc.errno == errno.EIO and self._tty()):
                raise
            # the stream's buffer still holds the text: flushed into /dev/null at exit, not another BrokenPipeError
            with contextlib.suppress(OSError, ValueError):
                _to_devnull(self._stream.fileno())
            return len(args[0]) if args else None

    def _nonblocking(self) -> bool:
        """Whether the stream has a descriptor set non-blocking (checked at each write: a terminal multiplexer may set
        it at any time); a stream without one (a StringIO) is not."""
        try:
            return not os.get_blocking(self._stream.fileno())
        except (OSError, ValueError, AttributeError):
            return False

    def _patiently(self, name: str, *args):
        """The stream's `name` ("write" or "flush") on its non-blocking descriptor, every byte written once and in
        order: the text layer of a TextIOWrapper cannot say which of its bytes a BlockingIOError lost (and over an
        unbuffered descriptor, PYTHONUNBUFFERED=1, it drops them without one), so what the stream holds is flushed
        first (a buffered stream keeps what it could not write, and the flush is tried again) and the text is encoded
        and written by os.write, which says how many bytes it took. Raises the BlockingIOError when the reader took
        nothing for STALLED_READER_S, for diagnostics or while Ctrl-C is ignored; otherwise a Ctrl-C ends the wait."""
        fd = self._stream.fileno()
        writable = select.poll()  # (select.select refuses a descriptor of 1024 or more: a ValueError, a traceback)
        writable.register(fd, select.POLLOUT)

        # a wait nothing can stop (Ctrl-C ignored: while an interruption is reported, or in a background job) gives
        # up as stderr's does: after a Ctrl-C a full stdout's --json line hung the command, deaf to SIGTERM too
        bounded = self._diagnostics or signal.getsignal(signal.SIGINT) is signal.SIG_IGN

        def waiting(call, *call_args):
            deadline = time.monotonic() + STALLED_READER_S if bounded else None
            while True:
                try:
                    return call(*call_args)
                except BlockingIOError:
                    left_ms = None if deadline is None else (deadline - time.monotonic()) * 1000  # (None: no timeout)
                    if left_ms is not None and left_ms <= 0 or not writable.poll(left_ms):
                        raise

        waiting(self._stream.flush)
        if name == "flush":
            return None
        encoding, errors = (getattr(self._stream, a, None) for a in ("encoding", "errors"))
        data = memoryview(args[0].encode(encoding or "utf-8", errors or "strict"))
        while data:
            data = data[waiting(os.write, fd, data):]
        return len(args[0])

    def _tty(self) -> bool:
        """Whether the stream is a terminal's (a character device: a hung-up one is no tty to isatty), whose EIO is
        its hang-up; a file's EIO is a failing disk, which still fails the command (--json's file was cut short)."""
        try:
            return stat.S_ISCHR(os.fstat(self._stream.fileno()).st_mode)
        except (OSError, ValueError, AttributeError):
            return False

    def write(self, text: str):
        try:
            return self._guarded("write", text)
        except UnicodeEncodeError:  # a path the stream's encoding cannot print (PYTHONIOENCODING=ascii and an "ü" in
            # --out) was a traceback after the results were written: escaped instead, as stderr does
            encoding = getattr(self._stream, "encoding", None) or "ascii"
            return self._guarded("write", text.encode(encoding, "backslashreplace").decode(encoding))

    def flush(self):
        return self._guarded("flush")

    def __getattr__(self, name):
        return getattr(self._stream, name)


def _closed_to_devnull() -> None:
    """The standard descriptors the shell closed (`<&-`, `>&-`, `2>&-`) opened on /dev/null: left free, the next file
    opened took the number (a plot's temporary file became descriptor 2, where C libraries write their warnings).
    sys.stdout and sys.stderr stay None, so the command's own lines still skip them."""
    for fd in (0, 1, 2):
        try:
            os.fstat(fd)
        except OSError:
            _to_devnull(fd)


def _to_devnull(fd: int) -> None:
    """Point descriptor `fd` at /dev/null: what is still buffered for a reader that left is dropped at exit. A closed
    `fd` below which every descriptor is open (the standard ones, taken in order) is the number the open takes."""
    devnull = os.open(os.devnull, os.O_RDWR)
    if devnull != fd:
        try:
            os.dup2(devnull, fd)
        finally:
            os.close(devnull)


def _stop(args, code: int, text: str) -> int:
    """A command that ended early: `planner COMMAND: TEXT` on stderr and, with --json, {"command", "exit_code",
    "error"} on stdout unless the summary is there already (a script reading it got no JSON); returns code, or
    EXIT_INTERRUPTED when a Ctrl-C stops the writing (a reader that stalled): main calls it from its except clauses,
    whose sibling `except KeyboardInterrupt` cannot catch it, and it escaped as a traceback."""
    try:
        _to_stderr(args, f"planner {args.command}: {text}")
        if getattr(args, "json", False) and args.stdout is not None and not hasattr(args, "summary"):  # one object only
            with contextlib.suppress(OSError):  # (a closed or broken stdout: the line above said it)
                # the exit code says which kind: "error: " or "failed: " is stderr's prefix
                reason = text.split(": ", 1)[1] if text.startswith(("error: ", "failed: ")) else text
                print(json.dumps({"command": args.command, "exit_code": code, "error": reason}), file=args.stdout,
                      flush=True)
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED
    return code


def _written_line(args) -> None:
    """After a Ctrl-C: when this run's result had replaced DIR's (its result_id in DIR's summary.json; a Ctrl-C held
    over the write is raised once both files are in place), one line that says so and what it lacks, before
    "interrupted": that alone let the earlier, replaced result seem kept (also after the validation was stored)."""
    from .plots import PLOT_FILES

    target = getattr(args, "written", None)
    summary = _summary_of(target, args.result_id) if target is not None else None
    if summary is None:
        return
    missing = [what for what, gone in (
        ("plots", not getattr(args, "no_plots", True) and not any((target / n).exists() for n in PLOT_FILES)),
        ("validation", getattr(args, "validating", False) and "validation" not in summary)) if gone]
    _to_stderr(args, f"planner {args.command}: {'converged' if summary.get('converged') else 'FAILED'}: results in "
                     f"{target}" + (f", without {' or '.join(missing)}" if missing else ""))


# control characters escaped in a printed line: a file named with a newline or an escape sequence forged a second
# "planner ..." line, coloured the terminal or set its title (a tab is printed as it is)
_ESCAPED = {**{i: f"\\x{i:02x}" for i in (*range(32), *range(127, 160)) if i != 9}, 10: "\\n", 13: "\\r"}


def _escaped(text) -> str:
    """str(text) with its control characters escaped (a tab kept): a path's newline forged a report line of its own
    ("converged: ...")."""
    return str(text).translate(_ESCAPED)


def _to_stderr(args, line: str) -> None:
    """One line on the command's stderr (a reader may leave), none when it is closed (`2>&-`): print(file=None)
    wrote it on stdout, after or before --json's object."""
    stream = getattr(args, "stderr", None) or sys.stderr
    if stream is not None:
        print(_escaped(line), file=stream, flush=True)


def _progress(args, line: str) -> None:
    """Progress goes to stderr, so that --json keeps stdout to one JSON object; -q hides it."""
    if not args.quiet:
        _to_stderr(args, line)


def _failure(summary: dict) -> str:
    """Why a command's summary says it failed, as ": reason" (the -q failure line), or "" when it does not say."""
    if summary.get("converged") is False:
        return f": {summary.get('message') or 'did not converge'}"
    if summary.get("command") == "gait":
        from .gait import gait_violations

        if gait_violations(summary):
            return ": " + "; ".join(gait_violations(summary))
        walking = summary.get("walking")  # (its fall printed "planner gait: failed", no reason)
        if isinstance(walking, dict) and walking.get("fell"):
            return (f": the MuJoCo walk fell after {walking.get('steps_walked')} of {walking.get('steps_asked')} steps "
                    f"({walking.get('control')} control)")
    if summary.get("validation_not_run"):
        return f": MuJoCo validation not run: {summary['validation_not_run']}"
    validation = summary.get("validation", summary)
    if isinstance(validation, dict) and validation.get("passed") is False:
        return ": " + "; ".join(validation.get("failures") or ["the validation failed"])
    return ""


def _emit(args, summary: dict, text: str, written: bool = False) -> None:
    """Print the summary (--json) or the text (unless -q). written: the command wrote a result, whose versions
    and result_id the printed summary gets too (--json printed summary.json without them): args.result_id, the one
    this run wrote (read back from DIR, it could be another run's written after it)."""
    if written:
        from .result import software_versions
        summary = {**summary, "versions": software_versions(), "result_id": args.result_id}
    args.summary = summary  # the -q failure line reads it
    if args.stdout is None:  # closed (`>&-`): print(file=None) wrote --json's object on stderr
        return
    if args.json:
        print(json.dumps(summary), file=args.stdout)
    elif not args.quiet:  # a name's or path's escape sequences (a terminal's title, colours): escaped
        print("\n".join(map(_escaped, text.split("\n"))), file=args.stdout)


def _emit_then_plots(args, summary: dict, text: str, plots_drawn: Callable[[], None]) -> None:
    """_emit a written result's summary, then wait for its plots, whose failure is raised after the report (a full
    disk hid the outcome); with --json before it, so that the one JSON object is the failure's, with its reason."""
    if args.json:
        plots_drawn()
    _emit(args, summary, text, written=True)
    if not args.json:
        plots_drawn()


def _cmd_check_model(args) -> int:
    from .check import MAX_SAMPLES, check_model
    from .model import load_robot

    if not 1 <= args.samples <= MAX_SAMPLES:
        raise InputError(f"--samples must be in [1, {MAX_SAMPLES}], got {shown(args.samples)}")
    if args.seed < 0:
        raise InputError(f"--seed must be >= 0, got {args.seed}")
    result = check_model(load_robot(args.robot, floating=args.floating), samples=args.samples, seed=args.seed)
    _emit(args, result.to_json(), result.report())
    return EXIT_OK if result.passed else EXIT_FAILED


def _load_inputs(args):
    """Robot, task (the .toml beside the robot unless --task) and the output directory."""
    from .model import load_robot
    from .task import MAX_STEPS, default_task_path, load_task

    steps = getattr(args, "steps", None)  # (simulate, plan)
    if steps is not None and not 1 <= steps <= MAX_STEPS:  # the task's horizon.N range: said of the flag
        raise InputError(f"--steps must be in [1, {MAX_STEPS}], got {steps}")
    robot = load_robot(args.robot)
    task_path = args.task or default_task_path(robot.path)
    if args.task is None and not task_path.is_file():
        raise InputError(f"no task file beside {robot.path} (expected {task_path}); give one with --task")
    task = load_task(task_path)
    if steps is not None:
        task = replace(task, horizon=replace(task.horizon, N=steps))
    task.check_against(robot)
    out = prepare_out_dir(args.out or Path("results") / f"{robot.path.stem}-{args.command}", failed=True)
    return robot, task, out


def _replan_failed(init: str, result) -> str:
    """The line after a replan from `init` that did not converge: the change was too large for that start (Capler's
    target moved 0.3 m: its contacts no longer fit), or, for the start's own task, nothing changed (it had said the
    change may be too large; the start's own plan stands)."""
    from .replan import SAME_TASK

    init = _escaped(init)
    if SAME_TASK in (result.extra.get("no_walk") or ""):
        return (f"the replan of {init}'s own task did not converge from its plan (the task is unchanged); that plan "
                f"stands in {init}")
    return f"the replan from {init} did not converge: the change may be too large for that start; plan without --init"


def _write(args, result, out: Path, background: bool = False) -> tuple[Path, Callable[[], None]]:
    """Results of a converged run go to `out`; a failed run's diagnostics go to `out/failed`, so a
    good earlier result in `out` is never overwritten (and a converged run removes an earlier failure's
    `out/failed`). Returns that directory and a call that waits for the plots and raises their failure: background
    draws them in a child process meanwhile (the caller validates, on the other CPU), else they are drawn before this
    returns. The caller prints its report before that call: a plot failure (a full disk) hid the outcome."""
    from .result import write_results

    target = out if result.stats.converged else prepare_out_dir(out / "failed")
    # this run's id, not read back from DIR: another run writing DIR after it had lent it its id and validation
    args.result_id, args.written, aside = uuid.uuid4().hex, target, None  # (a Ctrl-C from here on: _written_line)
    try:
        # first: one it cannot move left the new result beside the earlier result's plots; back if the write fails
        # (a full disk deleted them)
        aside = _plots_aside(target)
        write_results(result, target, args.result_id)
    finally:  # (a Ctrl-C held over the write is raised once both files are in place: then they are this run's)
        _plots_back(aside, target, restore=_summary_of(target, args.result_id) is None)
    if result.stats.converged:
        _remove_failed(out / "failed")
    if args.no_plots:
        return target, lambda: None
    if not background:
        with interruptible(defer=True):  # a Ctrl-C left the new result with part of its plots
            try:
                outcome = ("drawn", _draw(target))
            except Exception as exc:  # one line, as the background drawing's (a singular matrix was a traceback)
                outcome = ("error", _unexpected(exc))
        return target, lambda: _plots_outcome(args, result.stats.converged, target, *outcome)
    ctx = multiprocessing.get_context("fork")  # the child needs nothing but the directory; fork starts it in ms
    reader, writer = ctx.Pipe(duplex=False)
    child = ctx.Process(target=_draw_into, args=(target, writer), name="planner-plots", daemon=True)
    # Ctrl-C, SIGTERM and SIGHUP masked over the fork (the child unblocks them): raised inside logging's fork handlers,
    # they printed tracebacks
    held = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
    try:
        child.start()
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, held)
    writer.close()

    def finish() -> None:
        try:
            kind, message = reader.recv()
        except KeyboardInterrupt:  # the child ignores Ctrl-C: let it finish its plot files (a kill at exit left a temp file)
            child.join()
            raise
        except EOFError:
            kind, message = "error", "the plotting process ended without a word"
        child.join()
        _plots_outcome(args, result.stats.converged, target, kind, message)

    return target, finish


def _plots_outcome(args, converged: bool, target: Path, kind: str, message: str | None) -> None:
    """Raise what the drawing of target's plots ended in: ("error", one line) a PlannerError, ("drawn", why not or
    None) as _plotted."""
    if kind == "error":
        raise PlannerError(f"the plots of {target} failed: {message} (the results are written there)")
    _plotted(args, converged, message)


def _remove_failed(stale: Path) -> None:
    """Remove the files an earlier failed run wrote into `stale` (DIR/failed), which no longer describe DIR, and the
    directory if that empties it; anything else there, or a `stale` that is a symlink or no planner result, stays."""
    from .plots import PLOT_FILES
    from .result import read_summary

    if stale.is_symlink() or not (stale / "summary.json").is_file():
        return
    try:
        if "command" not in read_summary(stale, require=()):
            return
    except InputError:
        return
    for name in ("trajectory.npz", "summary.json", *PLOT_FILES):
        (stale / name).unlink(missing_ok=True)
    with contextlib.suppress(OSError):  # not empty: the user's own files stay
        stale.rmdir()


def _draw(target: Path) -> str | None:
    """Draw the plots of `target`: None, or why they could not be drawn (an InputError's message)."""
    from .plots import plot_results

    try:
        plot_results(target)
    except InputError as exc:
        return str(exc)
    return None


def _unexpected(exc: Exception) -> str:
    """An unexpected error in one line, with where it was raised (file:line in function: the innermost frame of this
    package's code, else the innermost): without the traceback, a bug in the plots was a message no one could place.
    A PlannerError (a full disk) is its message alone: no bug to place."""
    if isinstance(exc, PlannerError):
        return str(exc)
    frames = traceback.extract_tb(exc.__traceback__)
    ours = [f for f in frames if Path(f.filename).parent == Path(__file__).parent] or frames
    where = f" (raised at {Path(ours[-1].filename).name}:{ours[-1].lineno} in {ours[-1].name})" if ours else ""
    return f"{type(exc).__name__}: {exc}{where}"


def _draw_into(target: Path, conn) -> None:
    """_draw in a child process: ("drawn", what it returns) goes back through `conn`, or ("error", one line).
    Ctrl-C, SIGTERM and SIGHUP (`timeout` and a closed terminal signal the whole process group) are the parent's to
    handle: it waits for the plots, then reports the interruption."""
    for s in STOP_SIGNALS:
        signal.signal(s, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)  # (blocked by the parent's fork)
    try:
        conn.send(("drawn", _draw(target)))
    except Exception as exc:  # an unexpected failure reaches the parent as one line, not as the child's traceback
        conn.send(("error", _unexpected(exc)))
    finally:
        conn.close()


def _plotted(args, converged: bool, message: str | None) -> None:
    """A plot failure is the user's error for a converged result; a failed solve's iterate need not be a
    physical trajectory (e.g. its clock may run back), so its plots are only skipped, with a note."""
    if message is None:
        return
    if converged:
        raise InputError(message)
    _progress(args, f"plots skipped for the failed run: {message}")


@contextlib.contextmanager
def _said_of(flags: str):
    """An options class's InputError (it names its own fields, e.g. "FESDOptions.n_s") said of the flags that set them;
    a field another one owns gets the --solve that sets it."""
    try:
        yield
    except InputError as exc:
        owner = re.search(r"SolveOptions\.(\w+) owns", str(exc))
        monotone = ', "mu_strategy": "monotone"' if owner and owner[1] in ("mu_init", "warm_mu_init") else ""
        hint = f" (with --solve '{{\"{owner[1]}\": ...{monotone}}}')" if owner else ""
        raise InputError(f"{flags}: {exc}{hint}") from None


def _discretization(args, elements: int):
    """(Discretization, FESDOptions) of --discretization, --stages (default FESDOptions' n_s) and --elements (default
    `elements`, the command's own). InputError naming the valid values, and for an FESD flag without --discretization
    fesd (it would be ignored)."""
    from .discretization import Discretization, FESDOptions

    discretization = enum_member(args.discretization, Discretization, "--discretization")
    given = [flag for flag, value in (("--stages", args.stages), ("--elements", args.elements),
                                      ("--fesd-start", getattr(args, "fesd_start", None))) if value is not None]
    if given and discretization is not Discretization.FESD:
        raise InputError(f"{' and '.join(given)} set{'s' if len(given) == 1 else ''} the FESD discretization; add --discretization fesd")
    if discretization is not Discretization.FESD:
        return discretization, FESDOptions()
    n_s = FESDOptions().n_s if args.stages is None else args.stages
    with _said_of("--stages/--elements"):
        return discretization, FESDOptions(n_s=n_s, n_fe=elements if args.elements is None else args.elements)


def _cmd_simulate(args) -> int:
    from .simulate import SimulateOptions, simulate

    discretization, fesd = _discretization(args, elements=4)
    options = SimulateOptions(verbose=args.verbose, discretization=discretization, fesd=fesd)
    robot, task, out = _load_inputs(args)
    result = simulate(robot, task, options)
    target, plots_drawn = _write(args, result, out)
    verdict = "converged" if result.stats.converged else "FAILED"
    text = f"{result.report()}\n{verdict}: results in {_escaped(target)}"
    _emit_then_plots(args, result.summary(), text, plots_drawn)
    return EXIT_OK if result.stats.converged else EXIT_FAILED


# SolveOptions fields that `plan`'s flags own: --solve may not set them
HELD = "--init DIR (held by default; --penalty-replan turns it off)"
FLAG_OWNED = {"keep_schedule": HELD, "schedule_only": HELD,
              "schedule_new_impacts": "--allow-new-impacts (with --init DIR)",
              "fesd_start": "--fesd-start (with --discretization fesd)"}


def _ipopt_args(flag: str, items: list[str]) -> dict:
    """NAME=VALUE strings as IPOPT options: VALUE an int, a float or else a string (IPOPT checks it)."""
    out = {}
    for item in items:
        name, sep, text = item.partition("=")
        if not sep or not name:
            raise InputError(f"{flag} {item!r}: expected NAME=VALUE, e.g. {flag} alpha_for_y=min")
        if name in out:  # the last one silently won
            raise InputError(f"{flag} sets {name!r} twice; give each IPOPT option once")
        for kind in (int, float, str):
            try:
                out[name] = kind(text)
                break
            except ValueError:
                continue
    return out


def _cmd_plan(args) -> int:
    from .discretization import Discretization
    from .homotopy import (REPLAN_FIELDS, FESDStart, SolveOptions, replan_options, solve, solve_fields_from_json,
                           solve_options_from_dict)
    from .problem import ProblemOptions, build_problem

    discretization, fesd = _discretization(args, elements=3)
    problem_options = ProblemOptions(discretization=discretization, fesd=fesd)
    with _said_of("--ipopt/--warm-ipopt"):
        solve_options = SolveOptions(print_level=5 if args.verbose else 0, ipopt=_ipopt_args("--ipopt", args.ipopt),
                                     warm_ipopt=_ipopt_args("--warm-ipopt", args.warm_ipopt))
    fields = {}
    if args.solve:
        try:
            for text in args.solve:  # (a second --solve replaced the first, its fields dropped unsaid)
                more = solve_fields_from_json(text)
                twice = sorted(set(fields) & set(more))
                if twice:
                    raise InputError(f"{', '.join(twice)} given by two --solve objects; give each field once")
                fields.update(more)
            # a replan's flags set them after --solve, so another value was lost; the flags' own (a summary.json's
            # recorded options fed back) is no conflict
            held_by_flags = args.init is not None and not args.penalty_replan
            by_flags = {"keep_schedule": held_by_flags, "schedule_only": False,
                        "schedule_new_impacts": bool(args.allow_new_impacts),
                        "fesd_start": args.fesd_start or FESDStart.HINT_FREE.value}
            owned = sorted(k for k in set(fields) & set(FLAG_OWNED) if fields[k] != by_flags[k])
            if owned:
                raise InputError(f"{', '.join(owned)} {'is' if len(owned) == 1 else 'are'} set by "
                                 f"{', '.join(sorted({FLAG_OWNED[k] for k in owned}))}, not by --solve")
            replanned = sorted(set(fields) & set(REPLAN_FIELDS)) if args.init is not None else []
            if replanned:  # (read together on the replan's own options: mu_init needs its monotone barrier)
                own = replan_options()
                try:
                    given = solve_options_from_dict({k: fields[k] for k in replanned}, own)
                    replanned = [k for k in replanned if getattr(given, k) != getattr(own, k)]
                except InputError:  # not the replan's own (an adaptive mu_strategy beside its mu_init): a conflict
                    pass
            if replanned:  # replan_options sets them after --solve: another value was lost likewise
                raise InputError(f"{', '.join(replanned)} {'is' if len(replanned) == 1 else 'are'} set by --init DIR "
                                 "(a replan's own homotopy from the plan, homotopy.REPLAN_FIELDS; README), not by "
                                 "--solve")
            for key, flag, given in (("ipopt", "--ipopt", args.ipopt), ("warm_ipopt", "--warm-ipopt", args.warm_ipopt),
                                     ("print_level", "-v", args.verbose)):
                if key in fields and given:  # the JSON's field replaces the flag's: the flag was lost
                    raise InputError(f"{key} is set by {flag} too; give it in one of the two")
            if args.init is None:
                solve_options = solve_options_from_dict(fields, solve_options)
            else:  # read on the replan's options (its own mu_init needs its monotone barrier)
                try:
                    solve_options = solve_options_from_dict(fields, replan_options(solve_options))
                except InputError as exc:  # (soft_terminal_weight: "unless soft_terminal_nlps >= 1", unexplained)
                    raise InputError(f"{exc} (--init DIR solves with a replan's options, homotopy.replan_options: "
                                     "soft_terminal_nlps = 0, a monotone barrier)") from None
        except InputError as exc:
            raise InputError(f"--solve: {exc}") from None
    if args.quiet and solve_options.print_level > 0:  # (as -v -q: IPOPT's log went to stdout)
        raise InputError("--solve's print_level shows IPOPT's log and -q hides all but errors; drop one of them")
    fesd_start = enum_member(args.fesd_start or FESDStart.HINT_FREE.value, FESDStart, "--fesd-start")
    if discretization is Discretization.FESD and fesd_start is FESDStart.IMPLICIT_EULER:
        # the implicit-Euler stage runs its own default homotopy (to rho 1e6); the FESD NLPs follow fesd_rho_schedule
        solve_options = replace(solve_options, fesd_start=FESDStart.IMPLICIT_EULER)
    elif discretization is Discretization.FESD and "rho_max" not in fields and solve_options.rho_schedule is None:
        # (--solve's wins: it was replaced; a rho_schedule replaces the task's schedule, which rho_max changes)
        solve_options = replace(solve_options, rho_max=FESD_RHO_MAX)
    if args.init is not None and discretization is not Discretization.IMPLICIT_EULER:
        raise InputError("--init works with --discretization implicit_euler only")
    for flag, given in (("--keep-schedule", args.keep_schedule), ("--penalty-replan", args.penalty_replan),
                        ("--allow-new-impacts", args.allow_new_impacts)):
        if given and args.init is None:
            raise InputError(f"{flag} needs --init DIR: the plan to replan from")
    if args.penalty_replan and (args.keep_schedule or args.allow_new_impacts):
        raise InputError(f"--penalty-replan skips the held schedule that {'--keep-schedule' if args.keep_schedule else '--allow-new-impacts'} "
                         "asks for; give one of them")
    held = args.init is not None and not args.penalty_replan  # --init's default: the held schedule, then the walk
    robot, task, out = _load_inputs(args)
    if task.plan is None:
        raise InputError(f"task {task.source} has no [plan] table; `planner plan` needs one (see docs/tasks.md)")

    def progress(rec):
        _progress(args, f"  {rec.label:<11} rho {rec.rho:8.3g}  objective {rec.objective:10.4g}  complementarity "
                        f"{rec.complementarity_residual:.1e}  {rec.iterations:5d} it  {rec.time_s:7.2f} s  {rec.status}"
                        + (f"; {rec.note}" if rec.note else ""))

    if not args.no_validate:  # what the validation cannot model (a tilted plane, a ball joint) is said before the solve
        from .replay import build_scene

        build_scene(robot, task)
        if task.is_periodic:  # its validation walks it (after the solve)
            from .gait import check_walkable

            try:
                check_walkable(robot, task)
            except InputError as exc:
                raise InputError(f"{exc} (the validation walks a periodic plan in MuJoCo; --no-validate plans it "
                                 "without)") from None
    problem = build_problem(robot, task, problem_options)
    if args.init is not None:
        from .result import check_start, read_start, read_trajectory

        start_arrays = read_trajectory(args.init)
        check_start(args.init, robot, start_arrays)
        _warn_if_edited(args.init)
        options_apart = _options_apart(args.init, problem.options)
        # a plan written before session 50 digested its variables only: its options by its summary.json instead
        old = str(start_arrays.get("nlp_signature")) == problem.variables_signature
        signature = problem.variables_signature if old and not options_apart else problem.signature
        try:
            problem = replace(problem, x0=read_start(args.init, signature, problem.nx, start_arrays))
        except InputError as exc:  # contacts, N and options the same: said as "other NLP variables" only
            apart = (_skips_apart(args.init, start_arrays, task) + options_apart
                     if "other NLP variables" in str(exc) else "")
            raise InputError(f"{exc}{apart}") from None
        solve_options = replace(replan_options(solve_options), keep_schedule=held,
                                schedule_new_impacts=args.allow_new_impacts)
    if held:
        from .replan import replan

        result = replan(problem, solve_options, _start_task(args, start_arrays), progress=progress)
    elif args.no_race or args.init is not None or discretization is not Discretization.IMPLICIT_EULER:
        result = solve(problem, solve_options, progress=progress)
    else:  # the hint-free homotopy's iteration count is a draw: two draws on two CPUs (docs/benchmarks.md)
        from .race import default_arms, race

        result = race(problem, default_arms(solve_options), progress=progress)
    if args.init is not None:
        # summary.json says which plan this one started from: its directory and its result_id (the directory may be
        # --out itself, or be written again later)
        start_id = str(start_arrays["result_id"]) if "result_id" in start_arrays else None
        result = replace(result, options={**result.options, "init": os.path.abspath(args.init),
                                          "init_result_id": start_id})
    # a failed solve's last iterate is no motion to validate: one whose clock never ran or went back by 1e-9 s was
    # refused as an input error (exit 2, no failure line), one spanning 980 s replayed for 10 minutes after the failure
    # (`planner validate DIR/failed` replays it on request)
    validating = args.validating = (not args.no_validate and result.stats.converged
                                    and result.trajectory.physical_duration > 0)
    target, plots_drawn = _write(args, result, out, background=validating)
    summary, ok = result.summary(), result.stats.converged
    text = f"{result.report()}\n{'converged' if ok else 'FAILED'}: results in {_escaped(target)}"
    if args.init is not None and not ok:
        args.advice = _replan_failed(args.init, result)
        text += "\n" + args.advice
    if validating:
        from .replay import ReplayTooLongError, validate, write_validation, write_validation_not_run

        # (tau_f = 1e6 s) the converged plan's report is still the user's to read, and why it was not validated: also
        # in summary.json, which read as a --no-validate plan's, and in --json's object, which gave no reason
        why = None
        try:
            try:
                validation = validate(target)
            except (ReplayTooLongError, MemoryError) as exc:
                why = str(exc) if isinstance(exc, ReplayTooLongError) else (
                    f"its replay of {result.trajectory.physical_duration:.6g} s ran out of memory")
            # (each refused when another run wrote target meanwhile)
            if why is None:
                write_validation(target, validation, args.result_id)
            else:
                write_validation_not_run(target, why, args.result_id)
        # the validation's error (or Ctrl-C) is the one to report, once the plots are done:
        except BaseException:
            with contextlib.suppress(PlannerError):  # exiting kills the plotting child mid-file (a temp file stayed)
                plots_drawn()
            raise
        if why is not None:  # (_failure gives the -q failure line its reason)
            summary["validation_not_run"] = why
            _emit_then_plots(args, summary, f"{text}\nMuJoCo validation not run: {why}", plots_drawn)
            return EXIT_FAILED
        summary["validation"] = validation.to_json()
        ok = ok and validation.passed
        text += f"\n{validation.report()}"
    _emit_then_plots(args, summary, text, plots_drawn)
    return EXIT_OK if ok else EXIT_FAILED


def _npz_keys(path: Path) -> list[str] | None:
    """The array names of an .npz file, or None when it cannot be read (the command that reads it says why)."""
    import numpy as np

    if not path.is_file():  # (a FIFO blocked np.load forever)
        return None
    try:
        with np.load(path, allow_pickle=False) as arrays:
            return list(arrays.files)
    except Exception:  # (a truncated or empty file: zipfile's BadZipFile, EOFError; validate then says it in a line)
        return None


def _summary_of(target: Path, result_id: str) -> dict | None:
    """target's summary.json when it is the result result_id's, else None."""
    try:
        summary = json.loads((target / "summary.json").read_text())
    except (OSError, ValueError):
        return None
    return summary if isinstance(summary, dict) and summary.get("result_id") == result_id else None


def _plots_aside(target: Path) -> Path | None:
    """The plots of an earlier result in `target` (it holds a summary.json: other PNGs are the user's) moved into a
    hidden directory there, which is returned (None: none), so that they do not mix in with the new result's files;
    a plot that cannot be moved (an immutable file) puts the others back and raises."""
    from .plots import PLOT_FILES
    from .result import STALE_TEMP_S

    for stale in target.glob(".planner-earlier-plots-*"):  # a run killed (SIGKILL) between its aside and back
        with contextlib.suppress(OSError):
            if time.time() - stale.lstat().st_mtime > STALE_TEMP_S:
                shutil.rmtree(stale)
    old = [n for n in PLOT_FILES if (target / n).exists()] if (target / "summary.json").is_file() else []
    if not old:
        return None
    aside = Path(tempfile.mkdtemp(prefix=".planner-earlier-plots-", dir=target))
    try:
        for name in old:
            os.replace(target / name, aside / name)
    except BaseException:  # (the ones moved so far are the directory's)
        _plots_back(aside, target, restore=True)
        raise
    return aside


def _plots_back(aside: Path | None, target: Path, restore: bool) -> None:
    """_plots_aside's directory removed, its plots first put back into `target` when `restore` (the write failed)."""
    if aside is None:
        return
    if restore:
        for name in os.listdir(aside):
            with contextlib.suppress(OSError):
                os.replace(aside / name, target / name)
    shutil.rmtree(aside, ignore_errors=True)


def _remove_plots(target: Path) -> None:
    """An earlier result's plots in `target` (--no-plots now, a plot this robot has not, a gait that draws none) would
    mix in with the new result's files."""
    from .plots import PLOT_FILES

    for name in PLOT_FILES:
        (target / name).unlink(missing_ok=True)


def _skips_apart(init: Path, arrays: dict, task) -> str:
    """Why a start's NLP variables differ from this task's: another N, a contact in one task only, a scene skip one
    task has and the other not (mu = 0 drops a contact's tangential variables, touches = false its complementarity
    variables), or horizon.physical_time (a speed of time per step) in one of them, as "; ..." text, or ""."""
    from .result import read_task

    try:
        start = read_task(init, arrays)
    except InputError:
        return ""
    # contact by contact: a wall added on the ground's point was said to change the ground contact's mu
    pairs = list(zip(start.contacts, task.contacts)) if len(start.contacts) == len(task.contacts) else []
    apart = [f"{c.point!r} has mu {old.mu:g} there and {c.mu:g} here" for old, c in pairs
             if (old.mu == 0) != (c.mu == 0)]
    said = f"; contact {', '.join(apart)}: mu = 0 drops a contact's tangential variables, so plan without --init" \
        if apart else ""
    apart = [f"{c.point!r} has touches = {str(old.touches).lower()} there and {str(c.touches).lower()} here"
             for old, c in pairs if old.touches != c.touches]
    if apart:  # touches = false is the larger skip: the contact keeps only its gap rows
        said += (f"; contact {', '.join(apart)}: touches = false drops a contact's complementarity variables, so "
                 "plan without --init")
    if len(start.contacts) != len(task.contacts):
        said += (f"; {len(start.contacts)} contact(s) there and {len(task.contacts)} here: each contact has its own "
                 "variables, so plan without --init")
    if start.horizon.N != task.horizon.N:  # (the list of causes named N among others)
        said += (f"; horizon.N is {start.horizon.N} there and {task.horizon.N} here (--steps included): give "
                 f"--steps {start.horizon.N} to replan from it, or plan without --init")
    periodic = [start.is_periodic, task.is_periodic]
    if periodic[0] != periodic[1]:  # (it named robot, contacts, N, discretization and options, all the same)
        said += (f"; the plan there is {'periodic' if periodic[0] else 'to a target'} and this task "
                 f"{'is periodic' if periodic[1] else 'has a target'}: a periodic plan's free start y_0 adds "
                 "variables, so plan without --init")
    timed = [t.horizon.physical_time is not None for t in (start, task)]
    if timed[0] != timed[1]:  # (the message's list of causes named neither)
        said += (f"; horizon.physical_time is set {'there' if timed[0] else 'here'} only: it adds a speed of time per "
                 "step, so plan without --init")
    return said


def _warn_if_edited(init: Path) -> None:
    """A warning when init's plan, by its summary.json's edited_problem, was solved from a Problem edited through the
    Python API: --init rebuilds the task file's problem, so the edits are not replanned."""
    from .result import read_summary

    try:
        edits = read_summary(init, require=()).get("edited_problem")
    except (InputError, AttributeError):
        return
    if edits:
        names = ", ".join(map(str, edits)) if isinstance(edits, list) else str(edits)
        warnings.warn(f"{init}'s plan was solved from a Problem edited through the Python API ({names}); this replan "
                      "starts from it but solves the task file's problem without those edits")


def _options_apart(init: Path, options) -> str:
    """The ProblemOptions fields (Problem.signature counts them) in which init's plan, by its summary.json, was
    built otherwise than `options`, as "; ..." text, or "" (none, or no summary to tell)."""
    from .discretization import Discretization
    from .result import read_summary

    try:
        recorded = read_summary(init, require=()).get("options", {}).get("problem")
    except (InputError, AttributeError):
        return ""
    if not isinstance(recorded, dict):
        return ""
    # (fesd is read with discretization fesd only: before session 48's end the CLI recorded its default n_fe = 3 for
    # implicit-Euler plans too, and their --init was refused with a fix no flag can give)
    unread = {"clock_guess_running"} | ({"fesd"} if options.discretization is Discretization.IMPLICIT_EULER else set())
    # a key the record lacks is an option younger than the plan, which was built as its default then: the variables
    # decide (a plan before lift_products was refused for it, with a fix no flag gives)
    apart = [k for k, v in options_record(options).items() if k not in unread and k in recorded and recorded[k] != v]
    if "discretization" in apart:  # (replanning it "with those options", --discretization fesd, is refused too)
        return (f"; the plan was built with discretization {shown(recorded.get('discretization'))}, and --init replans "
                "implicit-Euler plans only: plan without --init")
    return (f"; the plan was built with other ProblemOptions ({', '.join(apart)}): plan without --init, or replan "
            "it with those options (the Python API sets the fields no flag sets)" if apart else "")


def _start_task(args, arrays: dict):
    """The task the --init plan solved, for the replan's walk from it (planner.replan): result.read_task from the
    plan's trajectory arrays, with --steps as given now; None, with a note on stderr, when it cannot be read: the
    replan then does not walk."""
    from .result import read_task

    try:
        task = read_task(args.init, arrays)
    except InputError as exc:
        _progress(args, f"  (no walk from the start's task: {exc})")
        return None
    return task if args.steps is None else replace(task, horizon=replace(task.horizon, N=args.steps))


def _cmd_gait(args) -> int:
    from .gait import gait_violations, run_gait
    from .model import load_robot

    if args.task is None:
        raise InputError("--task is required: a task file with a [gait] table, or a shipped one's name (biped_gait1, "
                         "biped_gait2)")
    robot = load_robot(args.robot)
    out = prepare_out_dir(args.out or Path("results") / f"{robot.path.stem}-gait", failed=True)
    args.result_id = uuid.uuid4().hex  # (_emit prints this run's, not one another run wrote into DIR after it)
    held = {d: (d / "summary.json").is_file() for d in (out, out / "failed")}  # (other PNGs there are the user's)
    result = run_gait(robot, args.task, out, progress=lambda loop: _progress(args, loop.line()),
                      validate=not args.no_validate, result_id=args.result_id)
    converged = bool(result.summary["converged"])
    if converged:
        _remove_failed(out / "failed")
    target = out if converged else out / "failed"  # run_gait's choice: a failure never overwrites a good gait
    args.result_id, args.written = result.summary.get("result_id"), target  # (-q's failure line names it)
    if held[target]:
        _remove_plots(target)  # an earlier plan's plots in DIR read as the gait's (a gait draws none)
    walked = result.walking is None or result.walking.steps_walked >= result.walking.steps_asked
    # a gait that asks the ground to pull (or to hold beyond friction), or its motors or joints beyond their ranges, is
    # no motion of the robot: it fails as a fall
    valid = walked and not gait_violations(result.summary)
    broken = "the MuJoCo walk fell" if not walked else "the gait violates its contacts, motor ranges or joint ranges"
    verdict = ("converged" if valid else f"converged, but {broken}") if converged else "FAILED"
    _emit(args, result.summary, f"{result.report()}\n{verdict}: results in {_escaped(target)}", written=True)
    return EXIT_OK if converged and valid else EXIT_FAILED  # the walk is the gait's validation, as MuJoCo's for a plan


def _cmd_validate(args) -> int:
    from .replay import ReplayTooLongError, ValidationOptions, validate, write_validation
    from .result import read_summary, result_dir

    result_dir(args.dir)
    if not os.access(args.dir, os.W_OK | os.X_OK):  # before the replays: the verdict is written into DIR/summary.json
        raise InputError(f"result directory {args.dir} is not writable: the validation is stored in its summary.json")
    # flags given (a periodic plan refuses them, the defaults spelled out too: they would do nothing), else None
    given = {k: v for k, v in (("controller", args.controller), ("window_s", args.window)) if v is not None}
    summary = read_summary(args.dir, require=())
    result_id = summary.get("result_id")  # a run writing DIR meanwhile: its verdict is not stored
    if summary.get("robot_sha256", "") == "":  # a result written before the hash (or with it deleted): said, not silent
        _progress(args, f"note: {args.dir / 'summary.json'} has no robot_sha256: the robot file is not checked against "
                        "the one the result was computed from")
    keys = _npz_keys(args.dir / "trajectory.npz")
    if summary.get("command") == "plan" and keys is not None and "task_json" not in keys:
        _progress(args, f"note: {args.dir / 'trajectory.npz'} has no task_json (an older planner's plan): its task is "
                        "read from the task file as it is now, and an edit since or the plan's --steps is not seen")
    with _said_of("/".join(f for f, k in (("--controller", "controller"), ("--window", "window_s")) if k in given)):
        options = ValidationOptions(**given) if given else None
    try:
        result = validate(args.dir, options)
    except ReplayTooLongError as exc:  # a valid result the machine cannot replay: exit 1 as `plan` does, not 2
        raise PlannerError(f"MuJoCo validation not run: {exc}") from None
    write_validation(args.dir, result, result_id)
    # (the verdict alone did not say whose: the result it judged is named as summary.json names it)
    _emit(args, {"command": "validate", "result_id": result_id, **result.to_json()}, result.report())
    return EXIT_OK if result.passed else EXIT_FAILED


def _cmd_view(args) -> int:
    from . import view

    if args.html is not None:
        page = view.render_html(args.dir, args.html, slow_motion=args.slow_motion)
        _emit(args, {"command": "view", "html": str(page)}, f"wrote {_escaped(page)}")
        return EXIT_OK
    # SIGTERM ends it as Ctrl-C does (main's _term_as_ctrl_c, installed before the server starts: a SIGTERM right after
    # the URL, CI's test, killed the command): meshcat stops its server at exit (atexit), a kill skipped it
    url = view.serve(args.dir, slow_motion=args.slow_motion, print_url=False)
    try:  # a stop once the URL is out is the normal end
        _emit(args, {"command": "view", "url": url}, f"meshcat replay: {url}  (Ctrl-C to stop)")
        if args.quiet and not args.json:  # the URL is the result: a server left running, none to find it (port 7000+)
            print(url, file=args.stdout)
        if args.stdout is not None:  # (closed, `>&-`: an AttributeError's traceback)
            args.stdout.flush()
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        return EXIT_OK


def prepare_out_dir(path: Path, failed: bool = False) -> Path:
    """Check that the output directory can be used, or say in one line why not. It is created when the results are
    written (result.write_files), so a later input error leaves no empty directory behind."""
    if path.is_symlink() and not path.exists():  # a loop or a dangling link: "File exists" after the whole solve
        raise InputError(f"--out {path} is a symbolic link to nothing (dangling or a loop)")
    if path.exists() and not path.is_dir():
        raise InputError(f"--out {path} is a file, not a directory")
    below = path / "failed"  # failed: a solve's command, whose failure writes there (refused then, its diagnostics lost)
    if failed and (below.exists() and not below.is_dir() or below.is_symlink() and not below.exists()):
        raise InputError(f"--out {path}: {below} is not a directory, and a failed solve writes there")
    if failed and below.is_dir() and not os.access(below, os.W_OK | os.X_OK):  # found after the solve: result mixed
        raise InputError(f"--out {path}: {below} is not writable, and a solve writes there or clears it")
    for name in ("trajectory.npz", "summary.json"):  # write_files refuses them, but after the whole solve
        if (path / name).is_dir():
            raise InputError(f"--out {path}: {path / name} is a directory, where the result's file goes")
    existing = next(p for p in (path, *path.absolute().parents) if p.exists())  # the root always exists
    dangling = next((p for p in path.absolute().parents if p.is_symlink() and not p.exists()), None)
    if dangling is not None:  # below it: "File exists" after the whole solve
        raise InputError(f"cannot create output directory {path}: {dangling} is a symbolic link to nothing (dangling "
                         "or a loop)")
    if not existing.is_dir():
        raise InputError(f"cannot create output directory {path}: {existing} is a file")
    writable = os.access(existing, os.W_OK | os.X_OK)
    if writable:  # root passes os.access everywhere (/proc, a chmod 555 directory): a file made there tells
        try:
            with tempfile.TemporaryFile(dir=existing):
                pass
        except OSError as exc:
            if exc.errno not in PATH_ERRNOS:  # (a full disk, too many open files: not the user's path)
                raise
            writable = False
    if not writable:
        raise InputError(f"output directory {path} is not writable" if existing == path else
                         f"cannot create output directory {path}: {existing} is not writable")
    return path


if __name__ == "__main__":
    sys.exit(main())
