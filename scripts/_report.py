"""The common ending of the scripts' main(): OUT/results.json written atomically, then JSON or a table on stdout; and
run_main, which runs a main() as a command the way `planner` runs its own (a bad input is one line and exit 2), and
script_parser, the argument parser that reports a usage error the same way."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from planner.cli import UsageParser, path_argument, prepare_out_dir
from planner.errors import PATH_ERRNOS, InputError, PlannerError
from planner.result import write_atomically


def report(out: Path, results, table: str, as_json: bool, printed=None) -> int:
    """Write `results` to out/results.json (atomically; out created), print `printed` (default: results) as JSON
    when as_json, else `table`; return 0, main()'s exit code."""
    out.mkdir(parents=True, exist_ok=True)
    write_atomically(out / "results.json", json.dumps(results, indent=1, default=str) + "\n")
    print(json.dumps(results if printed is None else printed, indent=1, default=str) if as_json else table)
    return 0


def out_dir(text: str) -> Path:
    """An --out argument: refused at once, as `planner` refuses it, when empty (an unset shell variable: results.json
    went to the working directory) or when no directory can be made there (a file, an unwritable place; found only
    after the whole run before)."""
    try:
        return prepare_out_dir(path_argument(text))
    except PlannerError as exc:  # (argparse names the flag itself)
        raise argparse.ArgumentTypeError(str(exc).removeprefix("--out ")) from None


def script_parser(doc: str, **kwargs) -> UsageParser:
    """The script's argument parser, described by the first paragraph of its docstring `doc`: a usage error is one line
    and exit code 2, as in `planner`."""
    return UsageParser(prog=Path(sys.argv[0]).stem, description=doc.split("\n\n")[0], **kwargs)  # run_main's name too


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
    except OSError as exc:  # e.g. --out in /proc: what the checks before the run cannot see
        name = Path(sys.argv[0]).stem
        if exc.errno in PATH_ERRNOS and exc.filename:  # a path refused: the user's input
            print(f"{name}: error: cannot use {exc.filename}: {exc.strerror}", file=sys.stderr)
            return 2
        print(f"{name}: failed: {exc.strerror or exc}" + (f": {exc.filename}" if exc.filename else ""), file=sys.stderr)
        return 1
