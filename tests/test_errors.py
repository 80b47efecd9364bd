"""planner.errors: check_field_types, the type check every options dataclass runs before its range checks."""
from __future__ import annotations

from dataclasses import dataclass

import pytest

from planner.discretization import FESDOptions
from planner.errors import InputError, PlannerError, check_field_types
from planner.gait import WalkGains
from planner.homotopy import SolveOptions
from planner.problem import ProblemOptions
from planner.pronto import ProntoOptions
from planner.replay import ContactSettings, TrackingGains, ValidationOptions
from planner.simulate import SimulateOptions


@dataclass(frozen=True)
class _Typed:
    flag: bool = True
    count: int = 1
    scale: float = 1.0
    name: str = "a"
    limit: float | None = None
    items: tuple[float, ...] = ()
    bound: float = 0.0  # may be infinite
    names: tuple[str, ...] = ()

    def __post_init__(self):
        check_field_types(self, unbounded={"bound"})


NAN, INF = float("nan"), float("inf")


@pytest.mark.parametrize("kwargs, ok", [
    ({}, True), ({"scale": 2}, True), ({"limit": None}, True), ({"limit": 3}, True), ({"items": (1, 2.5)}, True),
    ({"bound": -INF}, True), ({"names": ("a", "b")}, True),
    ({"flag": 1}, False), ({"count": 1.0}, False), ({"count": True}, False), ({"scale": "1"}, False), ({"scale": False}, False),
    ({"name": 1}, False), ({"limit": "x"}, False), ({"items": ("x",)}, False), ({"items": 1.0}, False),
    ({"items": (1.0, True)}, False), ({"names": ("a", 1)}, False),
    ({"scale": NAN}, False), ({"scale": INF}, False), ({"limit": -INF}, False), ({"items": (1.0, NAN)}, False),
    ({"items": (INF,)}, False), ({"bound": NAN}, False),
])
def test_check_field_types(kwargs, ok):
    """bool, int, float, str fields (or that or None, or tuples of one of them) hold that type, an int standing for
    a float but a bool for neither; None passes only where the annotation allows it; a float is never nan (it would
    pass every `x > 0` range check as False-y comparisons do not raise) and finite unless the field is declared
    unbounded."""
    if ok:
        _Typed(**kwargs)
        return
    with pytest.raises(InputError) as err:
        _Typed(**kwargs)
    field = next(iter(kwargs))
    assert f"_Typed.{field} = {kwargs[field]!r} is not allowed" in str(err.value)
    assert isinstance(err.value, PlannerError)


@pytest.mark.parametrize("cls, field, value, owner", [
    (SolveOptions, "tol", "small", "SolveOptions"), (ProblemOptions, "clock_weight", "x", "ProblemOptions"),
    (SimulateOptions, "max_iter", 10.5, "SimulateOptions"), (FESDOptions, "rho_h", "1", "FESDOptions"),
    (WalkGains, "sample_every", 4.0, "WalkGains"), (ProntoOptions, "newton", "yes", "ProntoOptions"),
    (ContactSettings, "cone", 1, "contact"), (TrackingGains, "frequency_hz", None, "gains"),
    (ValidationOptions, "window_s", "1", "ValidationOptions"),
])
def test_options_check_their_types(cls, field, value, owner):
    """Each options dataclass rejects a value of the wrong type with an InputError naming its field (not a TypeError
    from a range check), as its range checks name it (ValidationOptions' contact and gains by their field there); its
    defaults pass."""
    kwargs = {"feedback_q": (1.0,), "feedback_r": (1.0,)} if cls is ProntoOptions else {}
    cls(**kwargs)
    with pytest.raises(InputError, match=rf"^{owner}\.{field} = "):
        cls(**kwargs, **{field: value})
