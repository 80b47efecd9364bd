"""One exception tree for the planner.

`InputError` and its subclasses are the user's to fix (the CLI prints one line and exits 2);
`SolveError` means the numerics failed on valid input (exit 1, diagnostics still written).
"""
from __future__ import annotations

from collections.abc import Iterable
from dataclasses import fields


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


def check_field_types(options, owner: str | None = None) -> None:
    """Each field of the dataclass `options` annotated bool, int, float or str (or that or None) holds a value of that
    type (an int for a float): an InputError naming the field and the type, not a TypeError from a range check
    later (values from JSON: `planner plan --solve`). owner: how the message names the dataclass, as its own range
    checks do (e.g. "contact" for ValidationOptions.contact); default its class name."""
    kinds = {"bool": "true or false", "int": "an integer", "float": "a number", "str": "a string"}
    for f in fields(options):
        names = [t.strip() for t in str(f.type).split("|")]
        value = getattr(options, f.name)
        if names[0] not in kinds or (value is None and "None" in names):
            continue
        if names[0] == "bool":
            ok = isinstance(value, bool)
        elif names[0] == "str":
            ok = isinstance(value, str)
        else:
            ok = isinstance(value, int if names[0] == "int" else (int, float)) and not isinstance(value, bool)
        if not ok:
            raise InputError(f"{owner or type(options).__name__}.{f.name} = {value!r} is not allowed; it must be {kinds[names[0]]}")
