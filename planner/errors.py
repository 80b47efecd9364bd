"""One exception tree for the planner.

`InputError` and its subclasses are the user's to fix (the CLI prints one line and exits 2);
`SolveError` means the numerics failed on valid input (exit 1, diagnostics still written).
"""
from __future__ import annotations

from collections.abc import Iterable


class PlannerError(Exception):
    """Base of every error the planner raises on purpose."""


class InputError(PlannerError):
    """Bad input: a file, a name, a task key or value. The message says how to fix it."""


class RobotFileError(InputError):
    """The robot file is missing, unreadable, of an unknown format, or not parsable."""


class UnknownNameError(InputError):
    """A name (point, joint, task key, ...) that does not exist; the message lists the valid ones."""

    def __init__(self, kind: str, name: str, valid: Iterable[str]):
        self.kind, self.name, self.valid = kind, name, sorted(valid)
        super().__init__(f"unknown {kind} {name!r}; valid {kind}s: {', '.join(self.valid) or '(none)'}")


class TaskError(InputError):
    """A task file with a wrong key, type or value."""


class SolveError(PlannerError):
    """The numerical solve or the validation failed on valid input."""
