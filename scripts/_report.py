"""The common ending of the scripts' main(): OUT/results.json written atomically (with the "run" stamp: command, date,
machine), then JSON or a table on stdout; and run_main, which runs a main() as a command the way `planner` runs its own
(a bad input is one line and exit 2), and script_parser, the argument parser that reports a usage error the same way,
with the argument types and checks the scripts share."""
from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import platform
import shlex
import sys
from pathlib import Path

from planner.cli import UsageParser, path_argument, prepare_out_dir
from planner.errors import PATH_ERRNOS, InputError, PlannerError, usable_cpus
from planner.result import write_atomically


# the command line that script_parser's parser last read, for the "run" stamp: report() has no argv of its own
_command: str | None = None


def utc_now() -> str:
    """The date-time now, UTC, ISO 8601 to the second (a local day could not be compared across machines)."""
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


def _cpu_model() -> str | None:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:  # not Linux
        pass
    return platform.processor() or None


def machine_info() -> dict:
    """Where and when a script ran: platform, CPU model, cores (all and usable: nproc), Python, CasADi and NumPy
    versions, OMP_NUM_THREADS, load averages, date (UTC). The benchmarks' "machine" adds their own keys to it."""
    import casadi
    import numpy

    return {"platform": platform.platform(), "machine": platform.machine(), "cpu_model": _cpu_model(),
            "cpu_count": os.cpu_count(), "usable_cpus": usable_cpus(), "python": platform.python_version(),
            "casadi": casadi.__version__, "numpy": numpy.__version__,
            "omp_num_threads": os.environ.get("OMP_NUM_THREADS"),
            "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None, "date": utc_now()}


def run_info() -> dict:
    """results.json's "run": the command line (as parsed by script_parser's parser) and machine_info()."""
    return {"command": _command, **machine_info()}


def report(out: Path, results, table: str, as_json: bool, printed=None) -> int:
    """Write `results` to out/results.json (atomically; out created; a dict gets the "run" stamp), print `printed`
    (default: results) as JSON when as_json, else `table`; return 0, main()'s exit code."""
    if isinstance(results, dict) and "run" not in results:
        results = {**results, "run": run_info()}
    out.mkdir(parents=True, exist_ok=True)
    write_atomically(out / "results.json", json.dumps(results, indent=1, default=str) + "\n")
    print(json.dumps(results if printed is None else printed, indent=1, default=str) if as_json else table)
    return 0


def drop_results(out: Path) -> None:
    """Remove out/results.json before a run replaces the run directories it describes: an interrupted rerun left it
    naming directories the new run had already emptied."""
    (out / "results.json").unlink(missing_ok=True)


def out_dir(text: str) -> Path:
    """An --out argument: refused at once, as `planner` refuses it, when empty (an unset shell variable: results.json
    went to the working directory), when no directory can be made there (a file, an unwritable place; found only
    after the whole run before) or when its results.json is a directory."""
    try:
        out = prepare_out_dir(path_argument(text))
    except PlannerError as exc:  # (argparse names the flag itself)
        raise argparse.ArgumentTypeError(str(exc).removeprefix("--out ")) from None
    if (out / "results.json").is_dir():  # its write failed after the whole run
        raise argparse.ArgumentTypeError(f"{out / 'results.json'} is a directory; results.json is written there")
    return out


class _ScriptParser(UsageParser):
    def parse_known_args(self, args=None, namespace=None):
        global _command
        words = sys.argv[1:] if args is None else list(args)
        _command = shlex.join(["python", "-m", f"scripts.{self.prog}", *map(str, words)])
        namespace, extras = super().parse_known_args(args, namespace)
        # argparse converts string defaults only: a Path default --out was never checked (not where it goes unused:
        # --plan runs `planner plan` with its own --out, --list writes nothing)
        writes = getattr(namespace, "plan", None) is None and not getattr(namespace, "list", False)
        for action in self._actions if writes else ():
            default = action.default
            if action.type is out_dir and default is not None and getattr(namespace, action.dest) is default:
                setattr(namespace, action.dest, checked_default(self, "/".join(action.option_strings), default))
        return namespace, extras


def checked_default(parser, flag: str, default: Path) -> Path:
    """The default directory of an out_dir argument `flag`, checked as out_dir checks a given one (a refusal is the
    usage error "argument FLAG (default): ..."), for a script to call where the run will write it: a default that is
    never used must not stop a run (a --cache without --codegen), nor one checked only after it (a results.json that
    is a directory)."""
    try:
        return out_dir(str(default))
    except argparse.ArgumentTypeError as exc:
        parser.error(f"argument {flag} (default): {exc}")


def script_parser(doc: str, **kwargs) -> UsageParser:
    """The script's argument parser, described by the first paragraph of its docstring `doc`: a usage error is one line
    and exit code 2, as in `planner`; the command line it reads is the "run" stamp's."""
    return _ScriptParser(prog=Path(sys.argv[0]).stem, description=doc.split("\n\n")[0], **kwargs)  # run_main's name too


def _number(text: str, ok, what: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and ok(value)):  # nan compares false: a NaN weight ran on, writing NaN
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
    return value


def finite_float(text: str) -> float:
    """A float argument that is a finite number (nan and inf refused)."""
    return _number(text, lambda v: True, "a finite number")


def positive_float(text: str) -> float:
    """A float argument that is finite and > 0."""
    return _number(text, lambda v: v > 0, "a finite number > 0")


def nonnegative_float(text: str) -> float:
    """A float argument that is finite and >= 0."""
    return _number(text, lambda v: v >= 0, "a finite number >= 0")


def refuse_with_quick(parser, args, dests: list[str], runs: str) -> None:
    """--quick runs its own settings (`runs`, said in the error): an argument of `dests` given beside it was dropped
    silently before, so it is a usage error."""
    if args.quick:
        refuse_beside(parser, args, dests, f"--quick runs {runs}")


def refuse_beside(parser, args, dests: list[str], why: str) -> None:
    """A usage error "`why`: give no ... with it" naming the arguments of `dests` given (not at their defaults)."""
    given = [a.option_strings[0] if a.option_strings else a.dest for a in parser._actions
             if a.dest in dests and getattr(args, a.dest) != a.default]
    if given:
        parser.error(f"{why}: give no {' or '.join(given)} with it")


def planner_command(argv: list[str]) -> int:
    """`planner ARGV` in this process, its exit code; a Ctrl-C in it (exit 130) stops the script as a Ctrl-C of the
    script would, instead of being read as a failed or refused run (the next run went on)."""
    from planner.cli import EXIT_INTERRUPTED
    from planner.cli import main as planner_main

    code = planner_main(argv)
    if code == EXIT_INTERRUPTED:
        raise KeyboardInterrupt
    return code


def run_main(main) -> int:
    """main()'s exit code; a PlannerError (a bad input: a missing result directory, a bad task value) is printed as one
    line `SCRIPT: error: ...` on stderr and gives exit code 2, as planner's own commands do, instead of a traceback; a
    Ctrl-C is `SCRIPT: interrupted` and exit code 130, as `planner`'s."""
    try:
        return main()
    except KeyboardInterrupt:
        print(f"{Path(sys.argv[0]).stem}: interrupted", file=sys.stderr)
        return 130
    except InputError as exc:
        print(f"{Path(sys.argv[0]).stem}: error: {exc}", file=sys.stderr)
        return 2
    except PlannerError as exc:  # not the input's fault (a full disk): exit 1, as `planner`'s
        print(f"{Path(sys.argv[0]).stem}: failed: {exc}", file=sys.stderr)
        return 1
    except BrokenPipeError:  # `... --list | head`: the reader left; that is no failure (it said "failed", exit 1)
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # what is still buffered is dropped at exit
        os.close(devnull)
        return 0
    except OSError as exc:  # e.g. --out in /proc: what the checks before the run cannot see
        name = Path(sys.argv[0]).stem
        if exc.errno in PATH_ERRNOS and exc.filename:  # a path refused: the user's input
            print(f"{name}: error: cannot use {exc.filename}: {exc.strerror}", file=sys.stderr)
            return 2
        print(f"{name}: failed: {exc.strerror or exc}" + (f": {exc.filename}" if exc.filename else ""), file=sys.stderr)
        return 1
