"""planner.errors: check_field_types, the type check every options dataclass runs before its range checks, and expect,
the check of the public functions' arguments."""
from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass, replace

import numpy as np
import pytest

from planner.discretization import FESDOptions
from planner.dynamics import Dynamics
from planner.errors import InputError, PlannerError, check_field_types
from planner.gait import (GaitSpec, PinnedGait, WalkGains, periodic_walk, replay_gait, run_gait, solve_gait,
                          solve_gait_ipopt, validate_walk)
from planner.homotopy import SolveOptions, solve, solve_options_from_dict
from planner.model import ROBOTS_DIR, load_robot
from planner.problem import ProblemOptions, build_problem
from planner.pronto import ProntoOptions
from planner.race import default_arms, race
from planner.replan import replan
from planner.replay import ContactSettings, TrackingGains, ValidationOptions, validate, validate_plan
from planner.result import read_start, write_results
from planner.simulate import SimulateOptions, simulate
from planner.task import load_task, parse_task
from planner.view import load_result, render_html, serve


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


def test_unknown_name_errors_pickle_with_their_message_and_names():
    """An UnknownNameError (required constructor arguments) survives pickle with its message, a prefix added to it
    since (check_against names the task file) and its attributes: pickle called __init__ with the message alone, and
    a multiprocessing pool's result thread died on the TypeError (the pool hung)."""
    import pickle

    from planner.errors import UnknownNameError

    exc = UnknownNameError("contact point", "foot", ["point"], "contacts[0].point")
    exc.args = (f"task.toml: {exc}",)
    back = pickle.loads(pickle.dumps(exc))
    assert type(back) is UnknownNameError and str(back) == str(exc) == (
        "task.toml: contacts[0].point: unknown contact point 'foot'; valid contact points: point")
    assert (back.kind, back.name, back.valid) == ("contact point", "foot", ["point"])


def test_unknown_name_errors_quote_the_names_a_list_would_hide():
    """The valid names are listed as they are, except those a comma-separated list hides (session 64's tester):
    spaces at their ends ("valid joints: x , z" for "x "), a comma ("x, z" read as two joints), a control character
    or the empty name are quoted."""
    from planner.errors import UnknownNameError

    exc = UnknownNameError("joint", "x", ["x ", "x, z", "a\nb", "", "knee ñ"], ordered=True)
    assert str(exc) == "unknown joint 'x'; valid joints: 'x ', 'x, z', 'a\\nb', '', knee ñ"


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


def test_numpy_numbers_and_arrays_are_read_as_the_python_values_they_hold():
    """A notebook's np.int64 for an int, np.float64 for a float, np.bool_ for a bool and a 1-D np.array for a tuple are
    accepted and stored as Python values (np.int64 was "not an integer" and an array "not a tuple of numbers"); the
    objects equal and hash as those built from plain values; what they hold is checked as before."""

    typed = _Typed(flag=np.bool_(False), count=np.int64(3), scale=np.float32(0.5), items=np.array([1.0, 2.5]),
                   names=np.array(["a", "b"]))
    assert typed == _Typed(flag=False, count=3, scale=0.5, items=(1.0, 2.5), names=("a", "b"))
    assert hash(typed) == hash(_Typed(flag=False, count=3, scale=0.5, items=(1.0, 2.5), names=("a", "b")))
    assert type(typed.count) is int and type(typed.items) is tuple and type(typed.items[0]) is float
    assert SolveOptions(max_iter=np.int64(100)).max_iter == 100
    for bad in ({"count": np.float64(1.5)}, {"items": np.array([1.0, np.nan])}, {"items": np.array([[1.0, 2.0]])},
                {"scale": np.complex128(1j)}):
        with pytest.raises(InputError, match=f"_Typed.{next(iter(bad))} = "):
            _Typed(**bad)


def test_api_arguments_take_numpy_scalars_as_the_numbers_they_hold():
    """A notebook's numpy scalar (or 0-d array) for a function's number or flag is the Python value it holds, as for
    the options' fields: load_robot's floating np.bool_, tasks_between's s np.float32 or np.array(0.5), GaitSpec's N
    np.int64 were refused ("must be a bool, got bool np.False_", "a number in [0, 1]", "an integer"); a gait's
    desired_input is taken by its value ("zero") like every other mode."""
    from planner.gait import DesiredInput
    from planner.task import tasks_between

    assert load_robot("robots/capler.urdf", floating=np.bool_(False)).nq == load_robot("robots/capler.urdf").nq
    task = load_task(ROBOTS_DIR / "capler.toml")
    assert tasks_between(task, task, np.float32(0.5)) == tasks_between(task, task, np.array(0.5)) == task
    gait = load_task(ROBOTS_DIR / "biped_gait1.toml")
    spec = GaitSpec.from_task(gait, N=np.int64(20))
    assert spec.N == 20 and type(spec.N) is int
    assert replace(spec, desired_input="zero").desired_input is DesiredInput.ZERO


def test_an_int_for_a_float_is_stored_as_a_float():
    """An int, -0.0, a Decimal, a Fraction or a long double given for a float field is stored as the float it stands
    for, and a numpy str naming a switching function as a str, so options that compare equal have one repr and the
    problems built with them one signature (ProblemOptions(clock_weight=0) refused the plan of the default options as
    "other NLP variables"; FESDOptions(rho_h=1), clock_weight=-0.0 and switch_scale's np.str_("phi") likewise); the
    other real numbers were refused as "not a finite number"."""
    import enum
    from decimal import Decimal
    from fractions import Fraction

    typed = _Typed(scale=2, items=(1, 2.5), limit=3)
    assert (type(typed.scale), type(typed.items[0]), type(typed.limit)) == (float, float, float)
    assert repr(typed) == repr(_Typed(scale=2.0, items=(1.0, 2.5), limit=3.0))
    odd = _Typed(scale=Decimal("0.5"), items=(Fraction(1, 4), np.longdouble(2.5)), bound=-0.0)
    assert repr(odd) == repr(_Typed(scale=0.5, items=(0.25, 2.5), bound=0.0))
    for bad in (Decimal("nan"), Decimal("sNaN"), Decimal("1e400"), Fraction(10**400, 3)):  # (sNaN: a ValueError)
        with pytest.raises(InputError, match="_Typed.scale = .* it must be a finite number"):
            _Typed(scale=bad)
    robot, task = load_robot("point_mass"), load_task(ROBOTS_DIR / "point_mass_hop.toml")
    for given, default in ((ProblemOptions(clock_weight=0), ProblemOptions(clock_weight=0.0)),
                           (ProblemOptions(clock_weight=-0.0), ProblemOptions(clock_weight=0.0)),
                           (ProblemOptions(switch_scale=((np.str_("phi"), np.float32(100.0)),)),
                            ProblemOptions(switch_scale=(("phi", 100.0),))),
                           # a str Enum's member: its own str() is "Names.PHI", which no function is named
                           (ProblemOptions(switch_scale=((enum.Enum("Names", {"PHI": "phi"}, type=str).PHI, 100.0),)),
                            ProblemOptions(switch_scale=(("phi", 100.0),))),
                           (ProblemOptions(discretization="fesd", fesd=FESDOptions(rho_h=1)),
                            ProblemOptions(discretization="fesd", fesd=FESDOptions(rho_h=1.0)))):
        assert given == default
        assert build_problem(robot, task, given).signature == build_problem(robot, task, default).signature


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


# a gait step of three samples (t (3,), x (3, 6), u (2, 2)): what replay_gait checks before it reads the robot
STEP = PinnedGait(t=np.linspace(0.0, 0.2, 3), x=np.zeros((3, 6)), u=np.zeros((2, 2)))


@pytest.fixture(scope="module")
def hop():
    """The point mass, a short hop task and its built Problem (N = 4: built in ~0.1 s)."""
    robot = load_robot("point_mass")
    task = parse_task({"contacts": [{"point": "point", "mu": 0.5}], "initial": {"q": [0.0, 0.0]},
                       "horizon": {"tau_f": 1.0, "N": 4}, "plan": {"target_q": [0.5, 0.0], "u_bound": 30.0}})
    return robot, task, build_problem(robot, task)


@pytest.mark.parametrize("call, message", [
    (lambda r, t, p: solve(p, ProblemOptions()), "solve's options must be a SolveOptions"),
    (lambda r, t, p: build_problem(r, t, SolveOptions()),
     "build_problem's options must be a ProblemOptions"),
    (lambda r, t, p: build_problem("point_mass", t), "build_problem's robot must be a Robot"),
    (lambda r, t, p: simulate(r, "robots/point_mass.toml"), "simulate's task must be a Task"),
    (lambda r, t, p: validate("results", SolveOptions()),
     "validate's options must be a ValidationOptions or None"),
    (lambda r, t, p: replan(p, None, t), "replan's options must be a SolveOptions"),
    (lambda r, t, p: race(p, [SolveOptions()]), r"race needs one or more \(name, SolveOptions\) arms"),
    (lambda r, t, p: read_start("results", p.signature, p.nx, robot="point_mass"),
     "read_start's robot must be a Robot"),
    (lambda r, t, p: race(p, SolveOptions()), r"race takes arms, .* race\(problem, default_arms\(options\)\)"),
    (lambda r, t, p: race(p, None), r"race takes arms, a list of \(name, SolveOptions\) pairs, not a NoneType"),
    (lambda r, t, p: race(p, [("a", SolveOptions())], processes="2"),
     "race processes must be an integer >= 1"),
    (lambda r, t, p: solve_options_from_dict({}, base="x"),
     "solve_options_from_dict's base must be a SolveOptions or None"),
    (lambda r, t, p: load_robot(None), "load_robot's spec .* must be a str or PathLike"),
    (lambda r, t, p: load_task(None), "load_task's path must be a str or PathLike"),
    (lambda r, t, p: write_results("x", "out"),
     "write_results' result must be a SimulationResult or PlanResult"),
    (lambda r, t, p: run_gait(3, t, None), "run_gait's robot must be a Robot or str or PathLike"),
    (lambda r, t, p: Dynamics("point_mass"), "Dynamics' robot must be a Robot, got str"),
    (lambda r, t, p: t.check_against("point_mass"), "check_against's robot must be a Robot, got str"),
    # it raised TypeError only after NLP 1, whose work was lost
    (lambda r, t, p: solve(p, SolveOptions(), progress=5), "solve's progress must be a function"),
    (lambda r, t, p: load_robot("robots/capler.urdf", floating="no"), "load_robot's floating must be a bool"),
    (lambda r, t, p: run_gait(r, t, None, validate="no"), "run_gait's validate must be a bool"),  # it validated
    (lambda r, t, p: render_html(3, "x.html"), "render_html's out_dir must be a str or PathLike"),
    (lambda r, t, p: render_html("results", 3), "render_html's html_path must be a str or PathLike"),
    (lambda r, t, p: load_result(5), "load_result's out_dir must be a str or PathLike"),
    (lambda r, t, p: serve("results", slow_motion="yes"), "serve's slow_motion must be a bool"),
    (lambda r, t, p: validate_plan(r, t, {"q": 1}), "validate_plan's trajectory .* must be a Trajectory"),
    (lambda r, t, p: read_start(3, p.signature, p.nx), "read_start's out_dir must be a str or PathLike"),
    (lambda r, t, p: read_start("results", p.signature, str(p.nx)), "read_start's nx .* must be an int, got str"),
    (lambda r, t, p: read_start("results", None, p.nx), "read_start's signature .* must be a str"),
    # an IndexError
    (lambda r, t, p: validate_walk(r, t, {}, steps=0), "validate_walk's steps must be an int >= 1, got 0"),
    # gait's lower functions named no argument: an IndexError, a TypeError, an AttributeError, or defaults for {}
    (lambda r, t, p: replay_gait(None, None, t, 1), "replay_gait's sol must be a GaitSolution or PinnedGait"),
    (lambda r, t, p: replay_gait(None, STEP, t, 1, gains={}), "replay_gait's gains must be a WalkGains or None"),
    (lambda r, t, p: replay_gait(None, STEP, t, 1, settings={}), "replay_gait's settings must be a ContactSettings"),
    (lambda r, t, p: replay_gait(None, STEP, t, 1.5), "replay_gait's steps must be an int >= 1, got 1.5"),
    (lambda r, t, p: replay_gait(None, STEP, t, 1, arm_index=-5), r"arm_index must be a sample index in \[0, 2\]"),
    (lambda r, t, p: periodic_walk(None, STEP, 0), "periodic_walk's steps must be an int >= 1, got 0"),
    (lambda r, t, p: solve_gait(None, None), "solve_gait's spec .* must be a GaitSpec"),
    (lambda r, t, p: solve_gait_ipopt(None, None), "solve_gait_ipopt's spec .* must be a GaitSpec"),
    (lambda r, t, p: solve_gait_ipopt(None, GaitSpec.from_task(load_task(ROBOTS_DIR / "biped_gait1.toml"), N=20),
                                      tol=-1.0), "solve_gait_ipopt's tol must be a number > 0, got -1.0"),
    # the whole homotopy ran on NaN
    (lambda r, t, p: solve(replace(p, x0=np.full(p.nx, np.nan)), SolveOptions()),
     r"problem.x0 holds NaN or inf \(first at .*, entry 0\): a start must be finite"),
    # edited bounds: CasADi's assertion "lb <= ub && lb!=inf" came out as a RuntimeError traceback
    (lambda r, t, p: solve(replace(p, lbx=np.where(np.arange(p.nx) == 3, np.nan, p.lbx)), SolveOptions()),
     r"problem.lbx/ubx at .*, entry 3: \[nan, .*\] is no interval"),
    (lambda r, t, p: solve(replace(p, lbx=p.ubx + 1.0), SolveOptions()),
     r"problem.lbx/ubx at .*, entry 0: .* is no interval"),
    (lambda r, t, p: solve(replace(p, ubg=p.ubg[:-1]), SolveOptions()), r"problem.ubg has .* entries, the problem"),
    # accepted and ignored: only an FESD solve through implicit Euler reads it
    (lambda r, t, p: solve(p, SolveOptions(fesd_rho_schedule=(1e4,))), "fesd_rho_schedule = .* applies to discretization fesd"),
    # ran the hint-free homotopy and recorded fesd_start implicit_euler
    (lambda r, t, p: solve(p, SolveOptions(fesd_start="implicit_euler")),
     "fesd_start = implicit_euler applies to discretization fesd only"),
])
def test_api_calls_with_an_argument_of_the_wrong_kind_are_input_errors(hop, call, message):
    """A public function given an argument of the wrong kind (a path for a Robot, a SolveOptions for a ProblemOptions,
    None for a path) raises an InputError naming the function's argument and what it must be, before any work: they
    raised AttributeError or TypeError from deep inside."""
    with pytest.raises(InputError, match=message):
        call(*hop)


def test_dynamics_of_another_robot_are_refused(hop):
    """build_problem and simulate given dynamics built from another robot file refuse them (another robot's masses
    were planned with silently, under this robot's name); dynamics built from the same file's contents are reused."""
    robot, task, problem = hop
    other = Dynamics(load_robot("capler"))
    for call in (lambda: build_problem(robot, task, dynamics=other), lambda: simulate(robot, task, dynamics=other)):
        with pytest.raises(InputError, match=r"dynamics were built from .*capler.xml, not from the robot .*point_mass.xml"):
            call()
    assert build_problem(robot, task, dynamics=Dynamics(load_robot("point_mass"))).nx == problem.nx
    fixed, floating = load_robot("robots/capler.urdf"), load_robot("robots/capler.urdf", floating=True)
    with pytest.raises(InputError, match="dynamics were built from"):  # the same file, read with a free flyer
        build_problem(fixed, parse_task({"contacts": [{"point": "foot"}], "initial": {"q": [0.0, 0.4, 0.0, 0.0]},
                                         "horizon": {"tau_f": 1.0, "N": 2}, "plan": {"target_q": [0.1, 0.4, 0.0, 0.0]}}),
                      dynamics=Dynamics(floating))


def test_solve_options_from_dict_takes_enum_members_and_values():
    """An Enum field takes its member as well as its value (Polish.NONE and "none" alike); the member was refused as
    "not allowed", listing the value it stands for."""
    from planner.homotopy import Polish

    assert solve_options_from_dict({"polish": Polish.NONE}) == solve_options_from_dict({"polish": "none"})
    assert solve_options_from_dict({"polish": "none"}).polish is Polish.NONE


C_INT_MAX = 2**31 - 1  # IPOPT and CasADi read an int option as a C int


@pytest.mark.parametrize("field, value, allowed", [
    # IPOPT wrapped it around to 3 iterations
    ("max_iter", 2**32 + 3, r"an integer a C int holds, in \[-2147483648, 2147483647\] \(its own range"),
    ("tol", 10**400, "a finite number"),  # an int beyond a double: OverflowError inside the solve
    ("max_iter", True, "an integer$"),  # not an int at all: the C int range was named as if it were the field's
    ("max_iter", 1e3, "an integer$"),
], ids=["max_iter", "tol", "max_iter_bool", "max_iter_float"])
def test_numbers_a_c_int_or_a_double_cannot_hold_are_refused(field, value, allowed):
    """An int field beyond a C int (SolveOptions(max_iter=2**32 + 3): IPOPT read it as 3 and stopped after 3
    iterations) and a float field given an int beyond a double (tol = 10**400: OverflowError where it was converted)
    are InputErrors naming the field, as check_field_types' other type errors are; the largest C int is still an
    int option's value. A value that is no int (True, 1e3) is told "an integer", not the C int range (which read as
    the field's valid range)."""
    with pytest.raises(InputError, match=rf"^SolveOptions\.{field} = [\w.]+ is not allowed; it must be {allowed}"):
        SolveOptions(**{field: value})
    assert SolveOptions(max_iter=C_INT_MAX).max_iter == C_INT_MAX


def test_enum_fields_take_their_values():
    """An options field typed by an Enum takes the member or its value (stored as the member), as `--solve` JSON gives
    it; a value outside the allowed members is an InputError listing them (a valid value was refused by a message that
    listed it as valid)."""
    from planner.discretization import Discretization, SwitchVelocity
    from planner.homotopy import MuStrategy, SolveOptions
    from planner.problem import Penalty, ProblemOptions
    from planner.simulate import SimulateOptions, Strategy
    assert SolveOptions(mu_strategy="monotone") == SolveOptions(mu_strategy=MuStrategy.MONOTONE)
    assert ProblemOptions(penalty="l1").penalty is Penalty.L1
    assert ProblemOptions(discretization="fesd").discretization is Discretization.FESD
    assert SimulateOptions(strategy="horizon").strategy is Strategy.HORIZON
    assert SimulateOptions(velocity_switch="collocated").velocity_switch is SwitchVelocity.COLLOCATED
    assert SolveOptions(variable_scaling=None).variable_scaling is None
    with pytest.raises(InputError, match=r"ProblemOptions.velocity_switch = 'collocated' is not allowed; it must be "
                                         r"one of \['point', 'secant'\]"):
        ProblemOptions(velocity_switch="collocated")  # planner simulate only
    with pytest.raises(InputError, match=r"SolveOptions.mu_strategy = None is not allowed"):
        SolveOptions(mu_strategy=None)


ALARM_S = 0.3  # into the Capler simulation's IPOPT solves (~2.4 s in all: its ~2400 iterations), after the build


def test_an_exception_a_signal_handler_raises_inside_ipopt_is_raised():
    """A program's SIGALRM handler that raises (a timeout) stops simulate() with that exception: CasADi's IPOPT
    caught it and the steps went on, so the call returned its whole result after the timeout (solve() returned a
    converged plan; the NLP records said NonIpopt_Exception_Thrown)."""
    import signal
    import time

    class Timeout(Exception):
        pass

    def on_alarm(signum, frame):
        raise Timeout("the program's budget")

    robot, task = load_robot("capler"), load_task(ROBOTS_DIR / "capler.toml")
    previous = signal.signal(signal.SIGALRM, on_alarm)
    try:
        t0 = time.perf_counter()
        signal.setitimer(signal.ITIMER_REAL, ALARM_S)
        with pytest.raises(Timeout, match="budget"):
            simulate(robot, task)
        assert time.perf_counter() - t0 < 20 * ALARM_S  # not after the whole simulation
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def test_a_signal_handler_that_raises_nothing_stops_nothing():
    """A program's own SIGINT handler that only records the request (a graceful stop) leaves an interruptible block
    running and raises nothing after it: solve() raised KeyboardInterrupt whatever the handler did."""
    import os
    import signal

    from planner.errors import interruptible

    requests, finished = [], []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: requests.append(signum))
    try:
        for defer in (False, True):
            with interruptible(defer=defer):
                os.kill(os.getpid(), signal.SIGINT)
                finished.append(defer)
    finally:
        signal.signal(signal.SIGINT, previous)
    assert finished == [False, True] and requests == [signal.SIGINT] * 2


def test_a_deferred_signal_is_not_lost_behind_the_blocks_error_nor_a_handler_set_inside_undone():
    """A Ctrl-C during a deferring block whose own code then raises still interrupts after it (KeyboardInterrupt, the
    block's error its context; the error alone came out), and a handler the block installs for another signal stays
    after the block (the blocks restored every signal's entry handler)."""
    import os
    import signal

    from planner.errors import interruptible

    previous_int = signal.signal(signal.SIGINT, signal.default_int_handler)
    previous_usr1 = signal.signal(signal.SIGUSR1, lambda signum, frame: None)
    try:
        with pytest.raises(KeyboardInterrupt) as caught:
            with interruptible(defer=True):
                os.kill(os.getpid(), signal.SIGINT)
                raise ValueError("the block's own error")
        assert isinstance(caught.value.__context__, ValueError)

        def mine(signum, frame):
            pass

        with interruptible():
            signal.signal(signal.SIGUSR1, mine)
        assert signal.getsignal(signal.SIGUSR1) is mine
    finally:
        signal.signal(signal.SIGINT, previous_int)
        signal.signal(signal.SIGUSR1, previous_usr1)


def test_a_swallowed_ctrl_c_is_seen_by_interrupted_and_raised_by_check_interrupted_alike():
    """A Ctrl-C that a library swallowed inside an interruptible block is what interrupted() reports and
    check_interrupted() raises (IPOPT's callback stops the NLP on the one, a replay's loop stops on the other: they
    must agree), on the main thread only; a deferring block's Ctrl-C is neither until the block ends."""
    import contextlib
    import os
    import signal
    import threading

    from planner.errors import check_interrupted, interruptible, interrupted

    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        seen = []
        with pytest.raises(KeyboardInterrupt):
            with interruptible():
                with contextlib.suppress(KeyboardInterrupt):  # as CasADi's callbacks swallow it
                    os.kill(os.getpid(), signal.SIGINT)
                other = threading.Thread(target=lambda: seen.append(interrupted()))
                other.start()
                other.join()
                seen.append(interrupted())
                with pytest.raises(KeyboardInterrupt):
                    check_interrupted()
        with pytest.raises(KeyboardInterrupt):
            with interruptible(defer=True):
                os.kill(os.getpid(), signal.SIGINT)
                seen.append(interrupted())
                check_interrupted()
        assert seen == [False, True, False] and not interrupted()
    finally:
        signal.signal(signal.SIGINT, previous)


def test_an_exception_a_signal_handler_raises_while_ipopt_iterates_is_raised_after_it():
    """An alarm that fires while CasADi's IPOPT iterates (a long unconstrained solve: all of its time is IPOPT's) is
    raised by interruptible once IPOPT has stopped: IPOPT caught it and returned as a failed NLP."""
    import signal
    import time

    import casadi as ca

    from planner.errors import interruptible

    class Timeout(Exception):
        pass

    def on_alarm(signum, frame):
        raise Timeout("the program's budget")

    n = 400  # a chained Rosenbrock from far away: thousands of iterations, seconds of IPOPT
    x = ca.SX.sym("x", n)
    f = ca.sum1(100 * (x[1:] - x[:-1] ** 2) ** 2 + (1 - x[:-1]) ** 2)
    solver = ca.nlpsol("s", "ipopt", {"x": x, "f": f}, {"print_time": False, "ipopt": {
        "print_level": 0, "max_iter": 3000, "tol": 1e-300, "acceptable_iter": 0, "hessian_approximation":
            "limited-memory"}})
    previous = signal.signal(signal.SIGALRM, on_alarm)
    try:
        t0 = time.perf_counter()
        signal.setitimer(signal.ITIMER_REAL, ALARM_S)
        with pytest.raises(Timeout, match="budget"):
            with interruptible():
                solver(x0=np.full(n, -3.0))
        assert time.perf_counter() - t0 < 20 * ALARM_S
        assert solver.stats()["return_status"] == "NonIpopt_Exception_Thrown"  # IPOPT was running when it fired
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def test_solve_options_built_in_two_threads_leave_sys_stdout_as_it_was():
    """The race's default arms (SolveOptions with IPOPT options, each checked by creating IPOPT with sys.stdout
    captured) built in two threads at once leave the program's sys.stdout as it was: the overlapping swaps left it on
    a StringIO (5 of 5 runs of a tester), every later print lost."""
    import sys
    import threading

    stdout = sys.stdout

    def build():
        for _ in range(60):
            default_arms(SolveOptions())

    threads = [threading.Thread(target=build) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sys.stdout is stdout


@pytest.mark.parametrize("parent_pid, exits", [(1, False), (4242, True)])
def test_a_worker_whose_parent_is_pid_1_is_no_orphan(monkeypatch, parent_pid, exits):
    """killed_with_parent ends a worker reparented to PID 1 (its parent died before the death signal was set), but
    not one whose parent is PID 1 itself: the planner as a container's first process (every race arm and batch worker
    exited as an orphan there). The prctl call is left out: it would apply to this test process."""
    import ctypes
    import multiprocessing
    import os

    from planner.errors import killed_with_parent

    def no_prctl(*args, **kwargs):
        raise OSError("not here")

    def exit_(code):
        raise SystemExit(code)

    monkeypatch.setattr(ctypes, "CDLL", no_prctl)
    monkeypatch.setattr(os, "getppid", lambda: 1)
    monkeypatch.setattr(multiprocessing, "parent_process", lambda: type("Parent", (), {"pid": parent_pid})())
    monkeypatch.setattr(os, "_exit", exit_)
    if exits:
        with pytest.raises(SystemExit):
            killed_with_parent()
    else:
        killed_with_parent()


def test_usable_cpus_are_the_affinity_masks():
    """usable_cpus() counts the CPUs the process may run on (taskset, a container's cpuset), not the machine's: under a
    one-CPU affinity it is 1, so a race runs one arm there (session 66's mutation testing: os.cpu_count() read 2 on this
    2-CPU box with every test green)."""
    code = ("import os; os.sched_setaffinity(0, {min(os.sched_getaffinity(0))}); "
            "from planner.errors import usable_cpus; print(usable_cpus())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "1"
