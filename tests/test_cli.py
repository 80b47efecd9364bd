"""The command line: exit codes, one-line errors with no traceback, and the JSON contract."""
from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from planner.cli import main
from planner.errors import InputError, PlannerError
from planner.model import ROBOTS_DIR, file_sha256, load_robot
from planner.problem import ProblemOptions, build_problem
from planner.task import load_task, parse_task


def run(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "planner.cli", *argv], capture_output=True, text=True, timeout=120)


def test_check_model_json_contract():
    """`check-model --json` prints one JSON object with the contract's keys, the coordinates in their order and the
    named points (docs/tasks.md sends users there for both), and exits 0 on a good model."""
    proc = run("check-model", "capler", "--json", "--samples", "3")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    for key in ("robot", "format", "nq", "nv", "dof_names", "points", "backend", "max_err_mass", "max_err_bias", "max_err_frames",
                "max_err_jacobians", "mujoco", "passed"):
        assert key in summary
    assert summary["passed"] and summary["mujoco"]["max_err_mass"] < 1e-9
    assert summary["dof_names"] == ["base_x", "base_z", "hip", "knee"] and "foot" in summary["points"]  # docs/tasks.md's order


@pytest.mark.parametrize(
    "argv, fragment",
    [
        (["check-model", "/nonexistent/robot.xml"], "robot file not found"),
        (["check-model", "capler", "--samples", "0"], "--samples must be in [1, 100000], got 0"),
        (["check-model", "capler", "--samples", "99999999999999999999"], "--samples must be in [1, 100000]"),  # 21.5 GB
        (["plan", "point_mass", "--task", "{dir}"], "is a directory"),  # "not found"
        (["plan", "{dir}"], "robot file {dir} is a directory"),
        (["check-model", "/dev/null"], "robot file /dev/null is not a regular file (a device"),  # was "not found"
        (["check-model", "capler", "--seed", "-1"], "--seed must be >= 0, got -1"),
        (["plan", "point_mass", "--solve", '{"rho_min": -1}'],
         "SolveOptions.rho_min = -1.0 is not allowed; it must be > 0"),
        (["check-model"], "the following arguments are required: robot"),
        (["fly", "capler"], "invalid choice: 'fly'"),
        (["plan", "point_mass", "--ipopt", "alpha_for_y=sideways"], "Valid: primal, bound-mult"),
        (["plan", "point_mass", "--warm-ipopt", "tol=1e-3"], "SolveOptions.tol owns"),
        (["plan", "point_mass", "--ipopt", "alpha_for_y"], "expected NAME=VALUE"),
        (["plan", "point_mass", "--ipopt", "mu_min=1e-9", "--ipopt", "mu_min=1e-8"], "sets 'mu_min' twice"),
        (["plan", "point_mass", "--ipopt", "constr_viol_tol=nan"], "values finite numbers or strings"),
        (["plan", "point_mass", "--solve", '{"rho_max": Infinity}'], "rho_max = inf"),  # the schedule's loop never ended
        (["validate", "results", "-v"], "unrecognized arguments: -v"),  # validate runs no IPOPT: nothing more to show
        # said by the subcommand (it was "planner: error:", pointing at a --help that lists no subcommand's options)
        (["simulate", "point_mass", "--no-validate"], "planner simulate: error: unrecognized arguments: --no-validate"),
        (["simulate", "point_mass", "--steps", "0"], "--steps must be in [1, "),
        (["-q", "plan", "point_mass"], "planner plan: error: -q goes after the command: planner plan ... -q"),
        # an option with its value, or combined short flags, before the command: "invalid choice: 'x'" resp.
        # "unrecognized arguments: -qv"
        (["--out", "x", "plan", "point_mass"],
         "planner plan: error: --out x goes after the command: planner plan ... --out x"),
        (["-qv", "simulate", "point_mass"], "planner simulate: error: -qv goes after the command"),
        # only options of the command are said to go after it (review: --bogus, and a typo of the command before an
        # --out named like a command, were)
        (["--bogus", "plan", "point_mass"], "planner plan: error: unrecognized arguments: --bogus"),
        (["plna", "point_mass", "--out", "simulate"], "invalid choice: 'plna'"),
        # an --out named like a command (it said "--out goes after ... --out", and blamed `view` for --out)
        (["--out", "view", "plan", "point_mass"], "planner plan: error: --out view goes after the command"),
        # a replan's flags own these fields and set them after --solve, which was lost (or refused against the flag)
        (["plan", "point_mass", "--solve", '{"keep_schedule": true}'], "--solve: keep_schedule is set by --init DIR (held by default; --penalty-replan turns it off)"),
        (["plan", "point_mass", "--solve", '{"schedule_new_impacts": true}'], "set by --allow-new-impacts"),
        (["plan", "point_mass", "--solve", '{"fesd_start": "implicit_euler"}'], "set by --fesd-start"),  # was ignored
        # replan_options sets these after --solve with --init DIR: they were replaced silently
        (["plan", "point_mass", "--init", "{dir}", "--solve", '{"mu_init": 0.1, "holes": "relaxed_first"}'],
         "--solve: holes, mu_init are set by --init DIR (a replan's own homotopy from the plan, "
         "homotopy.REPLAN_FIELDS; README), not by --solve"),
        # (read on the replan's own options, this one raised their mu_init's error, which the user never gave)
        (["plan", "point_mass", "--init", "{dir}", "--solve", '{"mu_strategy": "adaptive"}'],
         "--solve: mu_strategy is set by --init DIR"),
        (["plan", "point_mass", "-q", "--solve", '{"print_level": 5}'], "print_level shows IPOPT's log and -q"),
        # replace() put the JSON's field in place of the flag's: the flag's IPOPT options or log were lost
        (["plan", "point_mass", "--ipopt", "max_soc=2", "--solve", '{"ipopt": {"alpha_for_y": "min"}}'],
         "--solve: ipopt is set by --ipopt too; give it in one of the two"),
        (["plan", "point_mass", "--warm-ipopt", "max_soc=2", "--solve", '{"warm_ipopt": {}}'],
         "set by --warm-ipopt too"),
        (["plan", "point_mass", "-v", "--solve", '{"print_level": 0}'], "print_level is set by -v too"),
        # root passes os.access there: the error came after the whole solve (as another user, os.access refuses it)
        (["plan", "point_mass", "--out", "/proc/planner-out"],
         "cannot create output directory /proc/planner-out: /proc is not writable"),
        (["plan", "point_mass", "--ipopt", "tol=1"],
         "SolveOptions.tol owns; set that instead (with --solve '{\"tol\": ...}')"),
        (["plan", "point_mass", "--warm-ipopt", "mu_init=0.01"],  # (warm_mu_init alone was refused next)
         "SolveOptions.warm_mu_init owns; set that instead and mu_strategy 'monotone', which it needs"),
        (["simulate", "point_mass", "--discretization", "fesd", "--stages", "4"],
         "--stages/--elements: FESDOptions.n_s = 4"),
        (["plan", "point_mass", "--solve", "{rho_f_schedule: 10}"], "is not JSON"),
        (["plan", "point_mass", "--solve", "[10]"], "expected a JSON object of SolveOptions fields, got an array"),
        (["plan", "point_mass", "--solve", "3"], "expected a JSON object of SolveOptions fields, got a number"),
        (["plan", "point_mass", "--solve", '{"rho_f_schedul": [10]}'],
         "SolveOptions has no field 'rho_f_schedul' (did you mean 'rho_f_schedule'?)"),
        (["plan", "point_mass", "--solve", '{"holes": "sometimes"}'], "must be one of"),
        (["plan", "point_mass", "--solve", '{"rho_f_schedule": [0]}'], "SolveOptions.rho_f_schedule"),
        (["plan", "point_mass", "--solve", '{"tol": "small"}'], "SolveOptions.tol = 'small' is not allowed"),
    ],
)
def test_user_errors_are_one_line_exit_2(argv, fragment, capsys, tmp_path):
    """A user error prints exactly one line on stderr, no traceback, and exits 2."""
    argv, fragment = [a.replace("{dir}", str(tmp_path)) for a in argv], fragment.replace("{dir}", str(tmp_path))
    with pytest.raises(SystemExit) as exit_info:
        code = main(argv)
        raise SystemExit(code)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert fragment in err and len(err.splitlines()) == 1 and "Traceback" not in err


@pytest.mark.parametrize("argv, command, fragment", [
    (["validate", "results", "--controller", "foo", "--json"], "validate",
     "argument --controller: invalid choice: 'foo'"),
    (["plan", "point_mass", "--bogusflag", "--json"], "plan", "unrecognized arguments: --bogusflag"),
    (["fly", "--json"], None, "invalid choice: 'fly'"),
    (["plan", "point_mass", "--js", "--steps", "x"], "plan", "argument --steps: invalid int value: 'x'"),
])
def test_a_usage_error_with_json_prints_the_error_object(argv, command, fragment, capsys):
    """A command-line error argparse finds, with --json (or a prefix argparse takes for it, --js: stdout was empty):
    exit 2, one line on stderr and on stdout the {"command", "exit_code", "error"} object, as for the errors found
    after parsing (stdout was empty)."""
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    out, err = capsys.readouterr()
    assert len(err.strip().splitlines()) == 1 and fragment in err
    obj = json.loads(out)
    assert obj["command"] == command and obj["exit_code"] == 2 and fragment in obj["error"]


def test_malformed_xml_from_a_subprocess(tmp_path):
    """Malformed XML through the real console entry: exit 2, one line on stderr, on stdout (--json) only the error
    object."""
    bad = tmp_path / "bad.xml"
    bad.write_text("<mujoco><worldbody>")
    proc = run("check-model", str(bad), "--json")
    assert proc.returncode == 2 and json.loads(proc.stdout)["exit_code"] == 2
    assert len(proc.stderr.strip().splitlines()) == 1 and "malformed XML" in proc.stderr


POINT_MASS_TASK = """
[[contacts]]
point = "{point}"
[initial]
q = [0.0, {z0}]
[horizon]
tau_f = {tau_f}
N = {N}
"""


def _task(tmp_path, point="point", z0=0.2, tau_f=0.1, N=5) -> str:
    path = tmp_path / "task.toml"
    path.write_text(POINT_MASS_TASK.format(point=point, z0=z0, tau_f=tau_f, N=N))
    return str(path)


def _one_line_exit_2(capsys, argv, fragment):
    code = main(argv)
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert fragment in err and len(err.splitlines()) == 1 and "Traceback" not in err


def test_simulate_writes_the_contract(tmp_path, capsys):
    """`simulate --json` exits 0, prints the summary and writes trajectory.npz, summary.json and plots; the printed
    summary is summary.json's, result_id included (it was missing: the id is made when the files are written)."""
    out = tmp_path / "out"
    assert main(["simulate", "point_mass", "--task", _task(tmp_path), "--out", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["command"] == "simulate" and summary["converged"]
    assert summary == json.loads((out / "summary.json").read_text()) and len(summary["result_id"]) == 32
    assert {"trajectory.npz", "summary.json", "clock.png"} <= {p.name for p in out.iterdir()}


def test_simulate_steps_overrides_the_tasks_horizon(tmp_path, capsys):
    """`simulate --steps N` sets the task's horizon.N as `plan --steps` does (same tau_f, h = tau_f / N): it was an
    unrecognized argument, and comparing step sizes meant editing a copy of the task."""
    out = tmp_path / "out"
    assert main(["simulate", "point_mass", "--task", _task(tmp_path), "--out", str(out), "--json", "--no-plots",
                 "--steps", "7"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["n_steps"] == 7

def test_no_plots_writes_the_contract_without_pngs(tmp_path, capsys):
    """`simulate --no-plots` (as `plan --no-plots`) writes trajectory.npz and summary.json and no PNG at all; the plots
    of an earlier result in that directory are removed, not left beside the new result."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "states.png").write_bytes(b"an earlier result's plot")
    (out / "summary.json").write_text('{"converged": true}')  # (a PNG where no result was is the user's: kept)
    assert main(["simulate", "point_mass", "--task", _task(tmp_path), "--out", str(out), "--no-plots", "-q"]) == 0
    names = {p.name for p in out.iterdir()}
    assert {"trajectory.npz", "summary.json"} <= names and not any(n.endswith(".png") for n in names), names
    capsys.readouterr()
    with pytest.raises(SystemExit):
        main(["plan", "--help"])
    assert "--no-plots" in capsys.readouterr().out


FESD_IMPACT_TOL_S = 1e-7  # the switch sits on an element boundary: solver tolerance, not the step h


def test_simulate_fesd_from_the_command_line(tmp_path, capsys):
    """`simulate --discretization fesd` detects the drop's impact at sqrt(2 z0 / g) (z0 = 0.2 m)
    where implicit Euler's h = 0.04 s grid cannot; an unknown discretization is exit 2, one line."""
    out = tmp_path / "out"
    argv = ["simulate", "point_mass", "--task", _task(tmp_path, tau_f=0.4, N=10), "--out", str(out), "--json",
            "--discretization", "fesd", "--stages", "2"]
    assert main(argv) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["converged"] and summary["impacts"]
    assert abs(summary["impacts"][0]["time"] - np.sqrt(2 * 0.2 / 9.81)) <= FESD_IMPACT_TOL_S
    assert main(argv[:-5] + ["--discretization", "fesd", "--stages", "2"]) == 0  # the terminal's headline
    assert "(10 steps of h = 0.04 s" in capsys.readouterr().out  # steps, not the elements the trajectory samples
    _one_line_exit_2(capsys, argv[:-4] + ["--discretization", "rk4"], "--discretization = 'rk4' is not allowed")


@pytest.mark.parametrize(
    "task_kwargs, fragment",
    [
        ({"point": "toe"}, "unknown contact point 'toe'; valid contact points: point"),  # the sites: not the body "mass"
        ({"N": 0}, "horizon.N = 0 is not allowed"),
        ({"tau_f": -1.0}, "horizon.tau_f = -1.0 is not allowed"),
        ({"z0": -0.1}, "initial.q"),
    ],
)
def test_simulate_bad_task(tmp_path, capsys, task_kwargs, fragment):
    """Bad task values reach the user as one line and exit 2."""
    _one_line_exit_2(capsys, ["simulate", "point_mass", "--task", _task(tmp_path, **task_kwargs),
                              "--out", str(tmp_path / "o")], fragment)


def test_output_path_that_is_a_file(tmp_path, capsys):
    """--out naming an existing file is refused before any work is done."""
    blocker = tmp_path / "file"
    blocker.write_text("x")
    _one_line_exit_2(capsys, ["simulate", "point_mass", "--task", _task(tmp_path), "--out", str(blocker)],
                     "is a file, not a directory")


def test_unwritable_output_directory(tmp_path, capsys):
    """An output directory that cannot be created (even by root: /proc refuses) is exit 2, one line."""
    _one_line_exit_2(capsys, ["simulate", "point_mass", "--task", _task(tmp_path), "--out", "/proc/planner-out"],
                     "cannot create output directory")


def test_input_errors_leave_no_output_directory(tmp_path, capsys):
    """An input error found after the arguments are read (a task without [plan]; a tilted plane the validation cannot
    model, said before the solve) is exit 2 in one line and creates no --out directory; an empty --out (an unset
    shell variable) is refused instead of writing into the working directory."""
    out = tmp_path / "new" / "out"
    _one_line_exit_2(capsys, ["plan", "point_mass", "--task", _task(tmp_path), "--out", str(out)], "has no [plan] table")
    tilted = tmp_path / "tilted.toml"
    tilted.write_text(HOP_TASK.replace('mu = 0.5\n', 'mu = 0.5\nnormal = [0.1, 0.0, 1.0]\n'))
    _one_line_exit_2(capsys, ["plan", "point_mass", "--task", str(tilted), "--out", str(out)], "touch a tilted plane")
    assert not (tmp_path / "new").exists()
    with pytest.raises(SystemExit) as exc:  # argparse's usage error, one line (planner.cli.UsageParser)
        main(["simulate", "point_mass", "--task", _task(tmp_path), "--out", ""])
    err = capsys.readouterr().err.strip()
    assert exc.value.code == 2 and "an empty path is not allowed" in err and len(err.splitlines()) == 1


def test_validate_refuses_a_directory_it_cannot_write_before_replaying(tmp_path, capsys, monkeypatch):
    """`validate DIR` stores its verdict in DIR/summary.json: a DIR it may not write is exit 2 in one line before any
    replay (it ran the whole replay, then raised PermissionError). Root may write anywhere, so os.access is faked."""
    import planner.cli

    monkeypatch.setattr(planner.cli.os, "access", lambda path, mode: False)
    _one_line_exit_2(capsys, ["validate", str(tmp_path)], "is not writable")


def test_missing_default_task(tmp_path, capsys):
    """A robot with no task beside it and no --task says where the task was expected."""
    robot = tmp_path / "lonely.xml"
    robot.write_text((Path(__file__).resolve().parent.parent / "robots" / "point_mass.xml").read_text())
    _one_line_exit_2(capsys, ["simulate", str(robot)], "no task file beside")


HOP_TASK = (ROBOTS_DIR / "point_mass_hop.toml").read_text().replace("\nN = 20\n", "\nN = 10\n")  # hop 0.5 m, N = 10
assert "\nN = 10\n" in HOP_TASK, "robots/point_mass_hop.toml's horizon line changed"


def test_the_plotting_child_is_forked_with_ctrl_c_held(tmp_path, capsys, monkeypatch):
    """Ctrl-C, SIGTERM and SIGHUP are blocked while the plotting child is forked (raised inside logging's fork handlers
    they printed tracebacks, session 57's tester) and unblocked again after it, in the parent and in the child."""
    import multiprocessing.context
    import signal
    from types import SimpleNamespace

    import planner.cli

    masks, real_start = [], multiprocessing.context.ForkProcess.start

    def start(self):
        masks.append(signal.pthread_sigmask(signal.SIG_BLOCK, []))
        return real_start(self)

    monkeypatch.setattr(multiprocessing.context.ForkProcess, "start", start)
    task = tmp_path / "hop.toml"
    task.write_text(HOP_TASK)
    out = str(tmp_path / "out")
    assert main(["plan", "point_mass", "--task", str(task), "--out", out, "-q", "--no-race"]) in (0, 1)
    stops = {signal.SIGINT, signal.SIGTERM, signal.SIGHUP}
    assert masks and all(stops <= mask for mask in masks)
    assert not stops & signal.pthread_sigmask(signal.SIG_BLOCK, [])
    handlers = {sig: signal.getsignal(sig) for sig in stops}
    signal.pthread_sigmask(signal.SIG_BLOCK, stops)  # as the child starts
    try:
        conn = SimpleNamespace(send=lambda message: None, close=lambda: None)
        planner.cli._draw_into(tmp_path / "nothing-here", conn)
        assert not stops & signal.pthread_sigmask(signal.SIG_BLOCK, [])
    finally:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, stops)
        for sig, handler in handlers.items():
            signal.signal(sig, handler)


def test_an_earlier_runs_plots_left_aside_by_a_kill_are_removed_once_stale(tmp_path):
    """A run killed (SIGKILL) between moving the earlier plots aside and removing them left a hidden directory that
    nothing removed (session 57's tester); the next write into the directory removes those older than
    result.STALE_TEMP_S, and leaves a live run's."""
    import os

    import planner.cli
    from planner.result import STALE_TEMP_S

    (tmp_path / "summary.json").write_text("{}")
    stale, live = tmp_path / ".planner-earlier-plots-old", tmp_path / ".planner-earlier-plots-new"
    for d in (stale, live):
        d.mkdir()
        (d / "states.png").write_bytes(b"png")
    os.utime(stale, (0, os.stat(stale).st_mtime - STALE_TEMP_S - 60))
    assert planner.cli._plots_aside(tmp_path) is None  # no plots of its own to put aside
    assert not stale.exists() and (live / "states.png").is_file()

def test_plan_draws_its_plots_while_it_validates(tmp_path, capsys):
    """A validated plan draws its plots in a child process meanwhile: summary.json holds the validation and the
    PNGs are byte for byte those that planner.plots draws in this process from the same result."""
    from planner.plots import plot_results

    task = tmp_path / "hop.toml"
    task.write_text(HOP_TASK)
    out = tmp_path / "out"
    code = main(["plan", "point_mass", "--task", str(task), "--out", str(out), "--json", "--no-race"])
    summary = json.loads(capsys.readouterr().out)
    assert code in (0, 1) and summary["converged"] and "validation" in summary
    assert summary == json.loads((out / "summary.json").read_text())  # the validation and the result_id too
    again = tmp_path / "again"
    again.mkdir()
    for name in ("trajectory.npz", "summary.json"):
        (again / name).write_bytes((out / name).read_bytes())
    drawn = plot_results(again)
    assert drawn and all((out / p.name).read_bytes() == p.read_bytes() for p in drawn)


@pytest.mark.parametrize("error, code, fragment", [(InputError("cannot draw this"), 2, "cannot draw this"),
                                                   (RuntimeError("boom"), 1, "RuntimeError: boom")])
def test_a_plot_failure_in_the_child_is_one_line(tmp_path, capsys, monkeypatch, error, code, fragment):
    """A converged plan whose plots fail in the drawing child (validation on) reports it as the in-process
    drawing would: a user error (InputError) exits 2, anything else exits 1, each one line without a traceback."""
    import planner.plots

    def broken(out_dir):
        raise error

    monkeypatch.setattr(planner.plots, "plot_results", broken)  # the forked child inherits the patch
    task = tmp_path / "hop.toml"
    task.write_text(HOP_TASK)
    assert main(["plan", "point_mass", "--task", str(task), "--out", str(tmp_path / "out"), "-q", "--no-race"]) == code
    err = capsys.readouterr().err.strip()
    assert fragment in err and len(err.splitlines()) == 1 and "Traceback" not in err


def test_ctrl_c_during_validation_is_reported_over_a_plot_failure(tmp_path, capsys, monkeypatch):
    """Ctrl-C while MuJoCo validates is reported as the interruption (exit 130, one line) even when the plots
    drawn meanwhile fail: the plots' error does not replace it."""
    import planner.plots
    import planner.replay

    def broken(out_dir):
        raise InputError("cannot draw this")

    def interrupted(out_dir, options=None):
        raise KeyboardInterrupt

    monkeypatch.setattr(planner.plots, "plot_results", broken)
    monkeypatch.setattr(planner.replay, "validate", interrupted)
    task = tmp_path / "hop.toml"
    task.write_text(HOP_TASK)
    assert main(["plan", "point_mass", "--task", str(task), "--out", str(tmp_path / "out"), "-q", "--no-race"]) == 130
    assert capsys.readouterr().err.splitlines()[-1] == "planner plan: interrupted"


def test_a_refused_validation_write_waits_for_the_plots(tmp_path, capsys, monkeypatch):
    """When the validation cannot be written (another run wrote the directory meanwhile: exit 1, one line) the command
    still waits for the plots drawn meanwhile: exiting killed the plotting child mid-file and left a temp file."""
    import planner.replay
    from planner.plots import PLOT_FILES

    def refused(out_dir, validation, result_id):
        raise PlannerError(f"{out_dir} was written by another run while it was validated")

    monkeypatch.setattr(planner.replay, "validate", lambda out_dir, options=None: None)  # at once: the plots still run
    monkeypatch.setattr(planner.replay, "write_validation", refused)
    task = tmp_path / "hop.toml"
    task.write_text(HOP_TASK)
    out = tmp_path / "out"
    assert main(["plan", "point_mass", "--task", str(task), "--out", str(out), "-q", "--no-race"]) == 1
    assert "written by another run" in capsys.readouterr().err
    assert all((out / name).is_file() for name in PLOT_FILES) and not list(out.glob(".*.tmp"))

def test_failed_plan_keeps_earlier_results(tmp_path, capsys):
    """An infeasible plan (target 50 m away with |u| <= 1 N in 0.2 s) exits 1, writes its diagnostics
    under DIR/failed, and leaves the results already in DIR byte for byte intact."""
    task = tmp_path / "far.toml"
    task.write_text('[[contacts]]\npoint = "point"\nmu = 0.5\n[initial]\nq = [0.0, 0.0]\n'
                    '[horizon]\ntau_f = 0.2\nN = 5\n[plan]\ntarget_q = [50.0, 0.0]\nu_bound = 1.0\n')
    out = tmp_path / "out"
    out.mkdir()
    earlier = {"summary.json": b'{"converged": true}', "trajectory.npz": b"earlier result"}
    for name, data in earlier.items():
        (out / name).write_bytes(data)
    assert main(["plan", "point_mass", "--task", str(task), "--out", str(out), "--no-validate", "--json"]) == 1
    summary = json.loads(capsys.readouterr().out)
    assert summary["converged"] is False
    assert "locally infeasible: the target may be out of reach" in summary["message"]  # (the last NLP's status only)
    for name, data in earlier.items():
        assert (out / name).read_bytes() == data
    assert json.loads((out / "failed" / "summary.json").read_text())["converged"] is False


def test_converged_plan_removes_an_earlier_failure(tmp_path, capsys):
    """A converged plan into DIR removes the files an earlier failed plan left in DIR/failed (they no longer describe
    DIR) and the directory once empty; it keeps the user's own files there (a whole user directory was deleted), a
    DIR/failed that holds no planner result, and a DIR/failed that is a symlink (rmtree raised a traceback)."""
    far, hop = tmp_path / "far.toml", tmp_path / "hop.toml"
    far.write_text('[[contacts]]\npoint = "point"\nmu = 0.5\n[initial]\nq = [0.0, 0.0]\n'
                   '[horizon]\ntau_f = 0.2\nN = 5\n[plan]\ntarget_q = [50.0, 0.0]\nu_bound = 1.0\n')
    hop.write_text(HOP_TASK)
    out, mixed, other, linked = (tmp_path / name for name in ("out", "mixed", "other", "linked"))
    for directory in (out, mixed):
        assert main(["plan", "point_mass", "--task", str(far), "--out", str(directory), "--no-validate", "-q", "--no-plots"]) == 1
        assert (directory / "failed" / "summary.json").is_file()
    (mixed / "failed" / "mine").mkdir()
    (mixed / "failed" / "mine" / "notes.txt").write_text("mine")
    (other / "failed").mkdir(parents=True)
    (other / "failed" / "notes.txt").write_text("mine")
    linked.mkdir()
    target = tmp_path / "elsewhere"  # a planner result that a symlink DIR/failed points to: not this DIR's to remove
    shutil.copytree(mixed / "failed", target, ignore=shutil.ignore_patterns("mine"))
    (linked / "failed").symlink_to(target)
    for directory in (out, mixed, other, linked):
        assert main(["plan", "point_mass", "--task", str(hop), "--out", str(directory), "--no-validate", "-q",
                     "--no-plots", "--no-race"]) == 0
        assert json.loads((directory / "summary.json").read_text())["converged"] is True
    assert not (out / "failed").exists() and (linked / "failed").is_symlink()
    assert json.loads((target / "summary.json").read_text())["converged"] is False
    assert sorted(p.name for p in (mixed / "failed").iterdir()) == ["mine"]
    assert (mixed / "failed" / "mine" / "notes.txt").read_text() == "mine"
    assert (other / "failed" / "notes.txt").read_text() == "mine"


def test_a_path_the_system_refuses_is_one_line_and_exit_2(tmp_path, capsys):
    """A path component longer than the file system allows (255 bytes) is one line and exit 2 in every command that
    takes a path (an OSError traceback, exit 1, before)."""
    long_name = str(tmp_path / ("a" * 300))
    for argv in (["validate", long_name], ["plan", "point_mass", "--out", long_name, "--no-validate"],
                 ["simulate", "point_mass", "--out", long_name]):
        _one_line_exit_2(capsys, argv, "File name too long")


def test_plan_rejects_an_unknown_fesd_start(tmp_path, capsys):
    """`plan --fesd-start NAME` with a NAME that is not an FESDStart exits 2 with one line naming the valid ones."""
    _one_line_exit_2(capsys, ["plan", "point_mass", "--discretization", "fesd", "--fesd-start", "euler", "--out", str(tmp_path / "o")],
                     "hint_free")


def test_a_periodic_plan_that_cannot_be_walked_is_refused_before_the_solve(tmp_path, capsys):
    """A periodic task on a robot whose validation cannot walk it (one contact point) is exit 2 before any solve, with
    the way out (--no-validate): the whole homotopy ran and wrote its result first."""
    task = tmp_path / "periodic.toml"
    task.write_text(HOP_TOML.format(x=0.5).replace("target_q = [0.5, 0.0]\n", "") + "[plan.periodic]\nstep = 0.2\n")
    out = tmp_path / "o"
    _one_line_exit_2(capsys, ["plan", "point_mass", "--task", str(task), "--out", str(out), "--no-race"],
                     "walking a periodic plan needs two contact points (the feet); the task has ['point'] (the "
                     "validation walks a periodic plan in MuJoCo; --no-validate plans it without)")
    assert not out.exists()


def test_a_plan_through_implicit_euler_records_the_options_given(tmp_path, capsys):
    """`plan --discretization fesd --fesd-start implicit_euler`: summary.json's solve options are those the command
    ran with, fesd_start implicit_euler among them (they were the inner FESD solve's: fesd_start hint_free, its own
    rho schedule, monotone barrier and enforced holes)."""
    argv = ["plan", "point_mass", "--task", str(ROBOTS_DIR / "point_mass_hop.toml"), "--steps", "5", "--discretization",
            "fesd", "--stages", "1", "--elements", "2", "--fesd-start", "implicit_euler", "--out", str(tmp_path / "o"),
            "--no-plots", "--no-validate", "--json"]
    assert main(argv) == 0
    solve = json.loads(capsys.readouterr().out)["options"]["solve"]
    assert solve["fesd_start"] == "implicit_euler" and solve["holes"] != "enforced" and solve["rho_schedule"] is None


@pytest.mark.parametrize("argv, flags", [(["plan", "point_mass", "--stages", "3"], "--stages sets"),
                                         (["plan", "point_mass", "--elements", "2", "--fesd-start", "implicit_euler"],
                                          "--elements and --fesd-start set"),
                                         (["simulate", "point_mass", "--elements", "2"], "--elements sets")])
def test_fesd_flags_without_fesd_are_input_errors(tmp_path, capsys, argv, flags):
    """An FESD flag without --discretization fesd exits 2 naming the flag and the fix, before any solve (it used to be
    ignored: `plan capler --stages 3` solved the implicit-Euler plan)."""
    _one_line_exit_2(capsys, argv + ["--out", str(tmp_path / "o")], f"{flags} the FESD discretization; add --discretization fesd")
    assert not (tmp_path / "o").exists()


def test_plan_fesd_from_the_command_line(tmp_path, capsys):
    """`plan --discretization fesd` solves the point-mass hop (no slip, to x = 0.5 m, N = 10) with FESD
    stages and says so in summary.json; n_fe = 0 elements is exit 2, one line naming n_fe."""
    task = tmp_path / "hop.toml"
    task.write_text('[[contacts]]\npoint = "point"\nmu = 0.5\n[initial]\nq = [0.0, 0.0]\n'
                    '[horizon]\ntau_f = 1.0\nN = 10\n[plan]\ntarget_q = [0.5, 0.0]\nu_bound = 30.0\n')
    argv = ["plan", "point_mass", "--task", str(task), "--out", str(tmp_path / "out"), "--no-validate", "--json",
            "--discretization", "fesd", "--stages", "2", "--elements", "3"]
    assert main(argv) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["converged"] and summary["polished"]
    assert summary["options"]["problem"]["discretization"] == "fesd" and summary["options"]["problem"]["fesd"]["n_fe"] == 3
    assert summary["options"]["solve"]["rho_max"] == 1e5
    _one_line_exit_2(capsys, argv[:-1] + ["0"], "n_fe = 0 is not allowed")


def test_solves_rho_max_wins_over_fesds_default(tmp_path, monkeypatch):
    """`plan --discretization fesd` ends its homotopy at FESD_RHO_MAX unless --solve sets rho_max: that value was
    replaced silently (summary.json said 1e5 for a requested 1e6)."""
    import planner.homotopy as H
    from planner.cli import FESD_RHO_MAX

    seen = []

    def record(problem, options, progress=None):
        seen.append(options.rho_max)
        raise KeyboardInterrupt  # enough: the options reached the solve

    monkeypatch.setattr(H, "solve", record)
    argv = ["plan", "point_mass", "--task", str(ROBOTS_DIR / "point_mass_hop.toml"), "--steps", "4", "--no-race",
            "--no-validate", "--discretization", "fesd", "--out", str(tmp_path / "o")]
    # a rho_schedule replaces the task's schedule that rho_max extends: FESD's rho_max is not set beside it (refused)
    for extra, rho_max in (([], FESD_RHO_MAX), (["--solve", '{"rho_max": 1e6}'], 1e6),
                           (["--solve", '{"rho_schedule": [1e3, 1e5]}'], H.SolveOptions.rho_max)):
        assert main(argv + extra) == 130
    assert seen == [FESD_RHO_MAX, 1e6, H.SolveOptions.rho_max]


def test_plan_steps_overrides_the_horizon(tmp_path, capsys):
    """`plan --steps N` plans the task on N steps of h = tau_f / N instead of the task's own N (the hop's
    task says 40; the plan has 8 steps of 0.125 s); --steps 0 and --steps 1e8 are exit 2, one line naming --steps (not
    the task's horizon.N)."""
    task = tmp_path / "hop.toml"
    task.write_text('[[contacts]]\npoint = "point"\nmu = 0.5\n[initial]\nq = [0.0, 0.0]\n'
                    '[horizon]\ntau_f = 1.0\nN = 40\n[plan]\ntarget_q = [0.5, 0.0]\nu_bound = 30.0\n')
    argv = ["plan", "point_mass", "--task", str(task), "--out", str(tmp_path / "out"), "--no-validate", "--json", "--steps", "8"]
    assert main(argv) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["n_steps"] == 8 and summary["h"] == 0.125
    _one_line_exit_2(capsys, argv[:-1] + ["0"], "--steps must be in [1, ")
    _one_line_exit_2(capsys, argv[:-1] + ["100000000"], "--steps must be in [1, 10000000], got 100000000")


def test_verbose_json_keeps_stdout_one_json_object(tmp_path):
    """`plan -v --json` (raced: both arms' IPOPT logs) prints IPOPT's log to stderr and only the summary to stdout,
    which parses as one JSON object (the log came first on stdout)."""
    task = tmp_path / "hop.toml"
    task.write_text(HOP_TOML.format(x=0.5))
    proc = run("plan", "point_mass", "--task", str(task), "--out", str(tmp_path / "out"), "--no-validate", "-v", "--json",
               "--steps", "8")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert json.loads(proc.stdout)["n_steps"] == 8
    assert "EXIT: Optimal Solution Found" in proc.stderr or "Number of Iterations" in proc.stderr


def test_a_solve_print_level_puts_ipopts_log_on_stderr(tmp_path):
    """`--solve '{"print_level": 5}'` shows IPOPT's log as -v does, on stderr: stdout keeps the command's summary only
    (the log went to stdout, 1187 lines mixed with the summary)."""
    task = tmp_path / "hop.toml"
    task.write_text(HOP_TOML.format(x=0.5))
    proc = run("plan", "point_mass", "--task", str(task), "--out", str(tmp_path / "out"), "--no-plots", "--no-validate",
               "--steps", "8", "--no-race", "--solve", '{"print_level": 5}')
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "Ipopt" not in proc.stdout and "Number of Iterations" in proc.stderr


@pytest.mark.parametrize("command", ["plan", "simulate"])
def test_verbose_puts_ipopts_log_on_stderr(tmp_path, command):
    """`-v` without --json prints IPOPT's log on stderr, as the README says, and keeps stdout to the command's summary
    (the log went to stdout: 1211 lines before a plan's summary, 8721 before a simulation's)."""
    task = tmp_path / "hop.toml"
    task.write_text(HOP_TOML.format(x=0.5))
    proc = run(command, "point_mass", "--task", str(task), "--out", str(tmp_path / "out"), "-v", "--no-plots",
               *(["--no-validate", "--steps", "8"] if command == "plan" else []))
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "Ipopt" not in proc.stdout and "Number of Iterations" in proc.stderr
    assert "results in" in proc.stdout.strip().splitlines()[-1]


def test_plan_solve_options_from_json(tmp_path, capsys):
    """`plan --solve JSON` sets SolveOptions fields over the flags: the summary's solve options carry them (a list as
    the tuple, an enum by its value) beside the --ipopt option, which the JSON did not name; repeated, the objects'
    fields add up, each given once."""
    task = tmp_path / "hop.toml"
    task.write_text(HOP_TOML.format(x=0.5))
    argv = ["plan", "point_mass", "--task", str(task), "--out", str(tmp_path / "out"), "--no-validate", "--json", "--no-race",
            "--ipopt", "alpha_for_y=primal", "--solve", '{"rho_f_schedule": [10], "holes": "enforced"}',
            "--solve", '{"reoptimize": false}']
    assert main(argv) == 0
    solve = json.loads(capsys.readouterr().out)["options"]["solve"]
    assert solve["rho_f_schedule"] == [10] and solve["holes"] == "enforced" and solve["reoptimize"] is False
    assert ["alpha_for_y", "primal"] in solve["ipopt"]
    # two --solve objects add up (the second replaced the first unsaid); a field in both is refused
    assert main(argv + ["--solve", '{"holes": "relaxed_first"}']) == 2
    assert capsys.readouterr().err.strip() == ("planner plan: error: --solve: holes given by two --solve objects; give "
                                               "each field once")


HOP_TOML = ('[[contacts]]\npoint = "point"\nmu = 0.5\n[initial]\nq = [0.0, 0.0]\n'
            '[horizon]\ntau_f = 1.0\nN = 20\n[plan]\ntarget_q = [{x}, 0.0]\nu_bound = 30.0\n')


def test_a_run_knows_its_own_result_from_one_written_after_it(tmp_path, capsys, monkeypatch):
    """Another run that writes the same --out right after this one: this run prints its own result_id (it read the
    other's back from disk), and its validation, which MuJoCo then ran on the other run's files, is refused (exit 2)
    instead of being stored and reported as this plan's (a passing plan exited 1 on the other's failed tracking)."""
    import planner.result

    (tmp_path / "hop.toml").write_text(HOP_TOML.format(x=0.5))
    other = tmp_path / "other"
    assert main(["simulate", "point_mass", "--task", _task(tmp_path), "--out", str(other), "--no-plots", "-q"]) == 0
    real, ids = planner.result.write_results, []

    def then_the_other_run(result, out_dir, result_id=None):
        ids.append(result_id)
        written = real(result, out_dir, result_id)
        for name in ("trajectory.npz", "summary.json"):
            shutil.copy(other / name, Path(out_dir) / name)
        return written

    monkeypatch.setattr(planner.result, "write_results", then_the_other_run)
    argv = ["plan", "point_mass", "--task", str(tmp_path / "hop.toml"), "--no-race", "--no-plots", "--json"]
    capsys.readouterr()
    assert main(argv + ["--out", str(tmp_path / "a"), "--no-validate"]) == 0
    printed = json.loads(capsys.readouterr().out)["result_id"]
    assert printed == ids[-1] != json.loads((other / "summary.json").read_text())["result_id"]
    assert main(argv + ["--out", str(tmp_path / "b"), "-q"]) == 1  # another run's write, not bad input (it was 2)
    err = capsys.readouterr().err.strip()
    assert "was written by another run while it was validated" in err and len(err.splitlines()) == 1, err


def test_summary_names_the_task_file_by_its_absolute_path(tmp_path, monkeypatch, capsys):
    """summary.json's task is the task file's absolute path, as its robot's is: a --task given relative to the
    working directory was stored as typed and meant nothing from another one."""
    monkeypatch.chdir(tmp_path)
    Path("hop.toml").write_text(HOP_TOML.format(x=0.5))
    assert main(["simulate", "point_mass", "--task", "hop.toml", "--out", "o", "--no-plots", "-q"]) == 0
    stored = json.loads(Path("o/summary.json").read_text())["task"]
    assert Path(stored).is_absolute() and Path(stored).resolve() == (tmp_path / "hop.toml").resolve()


def test_init_variables_apart_names_a_touches_change(tmp_path, monkeypatch):
    """A start whose task marks a contact touches = false where this task does not (the largest scene skip, 223
    against 385 variables on Capler) is named as the reason its NLP variables differ, as a mu = 0 change is."""
    from dataclasses import replace

    import planner.result
    from planner.cli import _skips_apart
    from planner.model import ROBOTS_DIR
    from planner.task import Contact

    capler = load_task(ROBOTS_DIR / "capler.toml")
    here = replace(capler, contacts=capler.contacts + (Contact(point="knee", mu=0.8),))
    there = replace(capler, contacts=capler.contacts + (Contact(point="knee", mu=0.8, touches=False),))
    monkeypatch.setattr(planner.result, "read_task", lambda init, arrays: there)
    assert _skips_apart(tmp_path, {}, here) == (
        "; contact 'knee' has touches = false there and true here: touches = false drops a contact's complementarity "
        "variables, so plan without --init")


def test_plan_init_replans_from_an_earlier_plan(tmp_path, capsys):
    """`plan --init DIR` starts the hop to x = 0.55 m from the plan of the hop to 0.5 m in DIR: by default in the
    one NLP that holds DIR's contact schedule (--keep-schedule says the same); with --penalty-replan it converges
    with one NLP at the replan penalty, the second one skipped (summary.json's options say so, and name DIR and
    its result_id).
    DIR keeps the task its plan solved (trajectory.npz's task_json, what the replan walks from), so the replan
    needs no task file of it; --allow-new-impacts reaches SolveOptions.schedule_new_impacts. A DIR without a plan's
    NLP point (a simulation), a plan on another grid (--steps) or with mu = 0 where DIR's was not (its tangential
    variables skipped: named as the cause) or with other ProblemOptions (named), FESD, --keep-schedule,
    --penalty-replan or
    --allow-new-impacts without --init, --penalty-replan with either of the other two, a plan that did not converge
    and a plan of another robot file are exit 2, one line each; read_start given the robot refuses those two as well."""
    for name, x in (("hop.toml", 0.5), ("closer.toml", 0.55)):
        (tmp_path / name).write_text(HOP_TOML.format(x=x))
    first = ["plan", "point_mass", "--task", str(tmp_path / "hop.toml"), "--out", str(tmp_path / "hop"), "--no-validate", "--json"]
    assert main(first) == 0
    capsys.readouterr()
    (tmp_path / "x").mkdir()  # --init x/../hop: stored as tmp_path/hop (it kept the "..")
    argv = ["plan", "point_mass", "--task", str(tmp_path / "closer.toml"), "--out", str(tmp_path / "closer"), "--no-validate", "--json",
            "--init", str(tmp_path / "x" / ".." / "hop")]
    assert main([a if a != str(tmp_path / "closer") else str(tmp_path / "penalty") for a in argv] + ["--penalty-replan"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["converged"] and summary["polished"]
    # the NLP at 1e4 ends complementary enough (<= REPLAN_STOP_COMP) to skip the one at 1e6: that NLP, the polish, its re-optimization
    assert summary["options"]["solve"]["rho_schedule"] == [1e4, 1e6]
    assert [n["label"] for n in summary["nlps"]] == ["homotopy 1", "polish", "reoptimize"]
    assert summary["options"]["init"] == str(tmp_path / "hop")
    start_id = json.loads((tmp_path / "hop" / "summary.json").read_text())["result_id"]
    assert summary["options"]["init_result_id"] == start_id  # the directory may be written again, or be --out
    assert summary["options"]["solve"]["keep_schedule"] is False
    for out_name, extra in (("closer", []), ("kept", ["--keep-schedule"])):
        assert main([a if a != str(tmp_path / "closer") else str(tmp_path / out_name) for a in argv] + extra) == 0
        summary = json.loads(capsys.readouterr().out)
        assert summary["converged"] and [n["label"] for n in summary["nlps"]] == ["schedule"]
        assert summary["options"]["solve"]["keep_schedule"] is True
    with np.load(tmp_path / "hop" / "trajectory.npz") as npz:  # the task the start plan solved, kept beside it
        assert parse_task(json.loads(str(npz["task_json"])), source=str(tmp_path / "hop.toml")) == load_task(tmp_path / "hop.toml")
    (tmp_path / "hop.toml").rename(tmp_path / "gone.toml")  # the walk's start task comes from DIR, not the file
    assert main([a if a != str(tmp_path / "closer") else str(tmp_path / "kept2") for a in argv] + ["--allow-new-impacts"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["converged"] and "no walk" not in err
    assert json.loads(out)["options"]["solve"]["schedule_new_impacts"] is True
    (tmp_path / "gone.toml").rename(tmp_path / "hop.toml")
    for flag in ("--keep-schedule", "--penalty-replan", "--allow-new-impacts"):
        _one_line_exit_2(capsys, first + [flag], f"{flag} needs --init DIR")
    _one_line_exit_2(capsys, argv + ["--penalty-replan", "--keep-schedule"], "--penalty-replan skips the held schedule that --keep-schedule")
    _one_line_exit_2(capsys, argv + ["--penalty-replan", "--allow-new-impacts"], "that --allow-new-impacts asks for")
    assert main(["simulate", "point_mass", "--task", _task(tmp_path), "--out", str(tmp_path / "drop")]) == 0
    capsys.readouterr()
    _one_line_exit_2(capsys, argv[:-1] + [str(tmp_path / "drop")], "holds no NLP point")
    _one_line_exit_2(capsys, argv + ["--steps", "10"],  # (N among others; said with what to do, as the others)
                     "; horizon.N is 20 there and 10 here (--steps included): give --steps 20 to replan from it, or "
                     "plan without --init")
    (tmp_path / "slippery.toml").write_text(HOP_TOML.format(x=0.55).replace("mu = 0.5", "mu = 0.0"))
    slippery = [a if a != str(tmp_path / "closer.toml") else str(tmp_path / "slippery.toml") for a in argv]
    _one_line_exit_2(capsys, slippery,
                     "contact 'point' has mu 0.5 there and 0 here: mu = 0 drops a contact's tangential variables")
    # a wall added on the ground contact's point was said to change the ground contact's mu
    (tmp_path / "wall.toml").write_text(HOP_TOML.format(x=0.55)
                                        + '[[contacts]]\npoint = "point"\nnormal = [1.0, 0.0, 0.0]\n')
    walled = [a if a != str(tmp_path / "closer.toml") else str(tmp_path / "wall.toml") for a in argv]
    assert main(walled) == 2  # (a line warning of the two contacts' rank comes first)
    assert capsys.readouterr().err.splitlines()[-1].endswith("; 1 contact(s) there and 2 here: each contact has its "
                                                              "own variables, so plan without --init")
    (tmp_path / "timed.toml").write_text(HOP_TOML.format(x=0.55).replace("N = 20\n", "N = 20\nphysical_time = 0.9\n"))
    timed = [a if a != str(tmp_path / "closer.toml") else str(tmp_path / "timed.toml") for a in argv]
    _one_line_exit_2(capsys, timed, "horizon.physical_time is set here only: it adds a speed of time per step")
    # a periodic task from a plan to a target: its free start y_0 (it named robot, contacts, N, ... all the same)
    (tmp_path / "cycle.toml").write_text(HOP_TOML.format(x=0.5).replace("target_q = [0.5, 0.0]\n", "")
                                         + '[plan.periodic]\nstep = 0.5\nfixed = ["x", "z"]\n')
    cycle = [a if a != str(tmp_path / "closer.toml") else str(tmp_path / "cycle.toml") for a in argv]
    _one_line_exit_2(capsys, cycle, "; the plan there is to a target and this task is periodic: a periodic plan's "
                     "free start y_0 adds variables, so plan without --init")
    _one_line_exit_2(capsys, argv + ["--discretization", "fesd"], "--init works with --discretization implicit_euler only")
    # a failed plan's last iterate, and a plan of another robot file whose names match (another mass): accepted before
    summary = json.loads((tmp_path / "hop" / "summary.json").read_text())
    failed = tmp_path / "failed_start"
    shutil.copytree(tmp_path / "hop", failed)
    (failed / "summary.json").write_text(json.dumps({**summary, "converged": False}))
    _one_line_exit_2(capsys, argv[:-1] + [str(failed)], "holds a plan that did not converge")
    from planner.result import read_start  # the API's start, given the robot, refuses it as --init (it replanned)

    hop_problem = build_problem(load_robot("point_mass"), load_task(tmp_path / "hop.toml"))
    with pytest.raises(InputError, match="holds a plan that did not converge"):
        read_start(failed, hop_problem.signature, hop_problem.nx, robot=hop_problem.robot)
    start = read_start(tmp_path / "hop", hop_problem.signature, hop_problem.nx, robot=hop_problem.robot)
    assert start.shape == (hop_problem.nx,)
    # a plan built through the API with other ProblemOptions (lambda0, lambda1 in other units): it had been a start
    scaled = tmp_path / "scaled"
    shutil.copytree(tmp_path / "hop", scaled)
    options = ProblemOptions(switch_scale=(("c(q)", 100.0),))
    with np.load(tmp_path / "hop" / "trajectory.npz") as npz:
        arrays = dict(npz)
    arrays["nlp_signature"] = np.array(build_problem(load_robot("point_mass"), load_task(tmp_path / "hop.toml"),
                                                     options).signature)
    np.savez(scaled / "trajectory.npz", **arrays)
    problem_record = {**summary["options"]["problem"], "switch_scale": [["c(q)", 100.0]]}
    options_record = {**summary["options"], "problem": problem_record}
    (scaled / "summary.json").write_text(json.dumps({**summary, "options": options_record}))
    _one_line_exit_2(capsys, argv[:-1] + [str(scaled)], "the plan was built with other ProblemOptions (switch_scale)")
    fesd_start = tmp_path / "fesd_start"  # (it said "replan it with those options": --discretization fesd, refused)
    shutil.copytree(tmp_path / "hop", fesd_start)
    np.savez(fesd_start / "trajectory.npz", **{**arrays, "nlp_signature": np.array("FESD variables")})
    fesd_problem = {**summary["options"], "problem": {**summary["options"]["problem"], "discretization": "fesd"}}
    (fesd_start / "summary.json").write_text(json.dumps({**summary, "options": fesd_problem}))
    _one_line_exit_2(capsys, argv[:-1] + [str(fesd_start)], "the plan was built with discretization 'fesd', and --init "
                     "replans implicit-Euler plans only: plan without --init")
    # a plan written before session 50, whose digest had its variables only: a start when its options are these
    old = tmp_path / "old"
    shutil.copytree(tmp_path / "hop", old)
    plain = build_problem(load_robot("point_mass"), load_task(tmp_path / "hop.toml"))
    np.savez(old / "trajectory.npz", **{**arrays, "nlp_signature": np.array(plain.variables_signature)})
    assert main(argv[:-1] + [str(old)]) == 0
    capsys.readouterr()
    # one that recorded the FESD elements' default for an implicit-Euler plan (the CLI did until session 48): fesd is
    # unread there, so no reason to refuse (it said "replan it with those options", which nothing can set)
    fesd_record = {**summary["options"]["problem"], "fesd": {**summary["options"]["problem"]["fesd"], "n_fe": 3}}
    fesd_summary = {**summary, "options": {**summary["options"], "problem": fesd_record}}
    (old / "summary.json").write_text(json.dumps(fesd_summary))
    assert main(argv[:-1] + [str(old)]) == 0
    capsys.readouterr()
    # one older than an option (lift_products, session 22: products lifted, today's default) lacks it in its record:
    # the variables decide (it was refused "with other ProblemOptions (lift_products)", a fix no flag gives)
    younger = {k: v for k, v in summary["options"]["problem"].items() if k != "lift_products"}
    (old / "summary.json").write_text(json.dumps({**summary, "options": {**summary["options"], "problem": younger}}))
    assert main(argv[:-1] + [str(old)]) == 0
    capsys.readouterr()
    # a plan of a planner that kept no NLP point (nlp_x since 2026-11-22) is said to be one, not "not a plan"
    no_point = tmp_path / "no_point"
    shutil.copytree(tmp_path / "hop", no_point)
    np.savez(no_point / "trajectory.npz", **{k: v for k, v in arrays.items() if k not in ("nlp_x", "nlp_signature")})
    _one_line_exit_2(capsys, argv[:-1] + [str(no_point)], "holds no NLP point: the plan was written by an older "
                     "planner, which did not keep it; plan without --init")
    (old / "summary.json").write_text(json.dumps({**summary, "options": options_record}))  # another switch_scale
    _one_line_exit_2(capsys, argv[:-1] + [str(old)], "the plan was built with other ProblemOptions (switch_scale)")
    heavy_robot = tmp_path / "heavy.xml"
    heavy_robot.write_text(Path(summary["robot"]).read_text().replace('mass="1"', 'mass="2"'))
    heavy = tmp_path / "heavy"
    shutil.copytree(tmp_path / "hop", heavy)
    (heavy / "summary.json").write_text(json.dumps({**summary, "robot": str(heavy_robot), "robot_sha256": file_sha256(heavy_robot)}))
    _one_line_exit_2(capsys, argv[:-1] + [str(heavy)], f"was computed for another robot file, {heavy_robot}, not")
    # a result written before summary.json kept robot_sha256: the file it names is compared as it is now
    (heavy / "summary.json").write_text(json.dumps({k: v for k, v in summary.items() if k != "robot_sha256"} | {"robot": str(heavy_robot)}))
    _one_line_exit_2(capsys, argv[:-1] + [str(heavy)], "whose contents differ from")
    with pytest.raises(InputError, match="whose contents differ from"):
        read_start(heavy, hop_problem.signature, hop_problem.nx, robot=hop_problem.robot)
    # the plan's own robot file edited in place since (the heavy file planned, then made the point mass's contents)
    (heavy / "summary.json").write_text(json.dumps({**summary, "robot": str(heavy_robot), "robot_sha256": file_sha256(heavy_robot)}))
    heavy_robot.write_text(Path(summary["robot"]).read_text())
    _one_line_exit_2(capsys, [argv[0], str(heavy_robot), *argv[2:-1], str(heavy)], "has other contents")


def test_plan_races_two_variants_unless_told_not_to(tmp_path, capsys, monkeypatch):
    """A hint-free `plan` races the default variant against the alternate one (race.SECOND_ARM; two CPUs assumed
    here) and summary.json lists both arms, exactly one of them "won", with the winner's options
    in options.solve; `--no-race` solves the default variant alone, with no race in the summary."""
    from planner import race

    monkeypatch.setattr(race, "usable_cpus", lambda: 2)
    (tmp_path / "hop.toml").write_text(HOP_TOML.format(x=0.5))
    argv = ["plan", "point_mass", "--task", str(tmp_path / "hop.toml"), "--out", str(tmp_path / "out"), "--no-validate", "--json"]
    assert main(argv) == 0
    summary = json.loads(capsys.readouterr().out)
    arms = {a["arm"]: a for a in summary["race"]}
    assert set(arms) == {"default", "alternate"} and [a["outcome"] for a in arms.values()].count("won") == 1
    second = next(name for name, a in arms.items() if a["outcome"] == "won") != "default"
    solve = summary["options"]["solve"]
    assert solve["warm_start"] == ("primal_dual" if second else "primal")
    assert solve["regularization"] == ("from_last" if second else "from_zero")
    assert (["mumps_permuting_scaling", 0] in solve["ipopt"]) == second
    assert main(argv + ["--no-race"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert "race" not in summary
    assert summary["options"]["solve"]["warm_start"] == "primal" and summary["options"]["solve"]["ipopt"] == []


def test_ctrl_c_is_one_line_and_exit_130(tmp_path, capsys, monkeypatch):
    """Ctrl-C during a command (KeyboardInterrupt) prints one line naming the command, no traceback, and
    exits 130 (128 + SIGINT, as shells report it)."""
    from planner import cli

    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "_cmd_plan", interrupted)
    assert main(["plan", "point_mass", "--out", str(tmp_path / "o")]) == 130
    err = capsys.readouterr().err
    assert err.strip() == "planner plan: interrupted"


def test_a_result_of_a_relative_robot_path_validates_from_another_directory(tmp_path, monkeypatch, capsys):
    """A result made from a robot file given by a relative path names it by its absolute path in summary.json, so
    `validate DIR` and `view DIR --html` work from any working directory (they said the file was not found)."""
    robots = tmp_path / "work" / "robots"
    robots.mkdir(parents=True)
    for name in ("point_mass.xml", "point_mass.toml"):
        (robots / name).write_text((Path(__file__).resolve().parents[1] / "robots" / name).read_text())
    monkeypatch.chdir(tmp_path / "work")
    assert main(["simulate", "robots/point_mass.xml", "--out", "drop", "-q", "--no-plots"]) == 0
    assert json.loads(Path("drop/summary.json").read_text())["robot"] == str(robots / "point_mass.xml")
    monkeypatch.chdir(tmp_path)
    assert main(["validate", "work/drop", "-q"]) == 0
    assert main(["view", "work/drop", "--html", str(tmp_path / "drop.html"), "-q"]) == 0


def test_deeply_nested_inputs_and_system_failures_are_one_line(tmp_path, capsys, monkeypatch):
    """A --solve JSON or a task TOML nested too deeply for Python's parsers is one line and exit 2 (a RecursionError
    traceback); an OS error that is not about a path the user gave (a full disk) is one line and exit 1, not 2."""
    import errno

    import planner.cli

    _one_line_exit_2(capsys, ["plan", "point_mass", "--out", str(tmp_path / "o"), "--solve", "[" * 5000 + "]" * 5000],
                     "nested too deeply")
    deep = tmp_path / "deep.toml"
    deep.write_text("x = " + "[" * 5000 + "]" * 5000 + "\n")
    _one_line_exit_2(capsys, ["simulate", "point_mass", "--task", str(deep), "--out", str(tmp_path / "o")], "nested too deeply")

    def full_disk(args):
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "o" / "summary.json"))

    monkeypatch.setattr(planner.cli, "_cmd_check_model", full_disk)
    assert main(["check-model", "point_mass"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("planner check-model: failed: No space left on device") and len(err.splitlines()) == 1


def test_ctrl_c_inside_ipopt_stops_the_command(tmp_path):
    """Ctrl-C while IPOPT runs in this process (here a plan --no-race; a replan from --init runs the same homotopy._run)
    ends the command with exit 130 and one line, writing no result: CasADi's IPOPT caught it and returned as a failed
    NLP, so the homotopy went on (a plan interrupted in its second NLP was written as converged, exit 0). The hop on
    100 steps spends ~13 s in its fourth NLP, where the signal lands (CasADi says it caught it)."""
    import signal
    import time

    task = tmp_path / "hop.toml"
    task.write_text(HOP_TASK.replace("N = 10", "N = 100"))
    proc = subprocess.Popen([sys.executable, "-m", "planner.cli", "plan", "point_mass", "--task", str(task), "--out",
                             str(tmp_path / "out"), "--no-validate", "--no-plots", "--no-race"],
                            stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True,
                            # Ctrl-C's default, which Python turns into KeyboardInterrupt, also where the suite runs
                            # with SIGINT ignored (a background job of a script: CI) and the child would inherit that
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    lines = []
    while not any("homotopy 3" in line for line in lines):  # the progress line of NLP 3: NLP 4 is running
        lines.append(proc.stderr.readline())
        assert lines[-1], "".join(lines)
    time.sleep(1.0)  # into NLP 4's IPOPT, past the homotopy's work between NLPs
    proc.send_signal(signal.SIGINT)
    err = "".join(lines) + proc.stderr.read()
    assert proc.wait(timeout=60) == 130, err
    assert "KeyboardInterruptException" in err and "homotopy 4" not in err, err
    assert err.strip().splitlines()[-1] == "planner plan: interrupted" and "Traceback" not in err
    assert not (tmp_path / "out").exists()


def test_ctrl_c_while_ipopts_log_is_written_stops_the_nlp(tmp_path, monkeypatch, ctrl_c):
    """With -v, a Ctrl-C that Python takes while IPOPT's log line is written (CasADi prints it through sys.stdout)
    stops the NLP there, exit 130 and one line: the write dropped the KeyboardInterrupt, CasADi's own check saw no
    signal left, and the NLP ran to its end first (6-7 s on the default Capler task, 0.2 s without -v). The hop's
    NLP 1 takes 59 iterations; the signal lands in the write of its 20th."""
    import io
    import signal

    task = tmp_path / "hop.toml"
    task.write_text(HOP_TASK)
    iterations, after = [], []  # IPOPT's iteration lines up to the signal; all text written after it

    class Stderr(io.StringIO):
        def write(self, text):
            if len(iterations) == 20:
                after.append(text)
            elif re.match(r"\s*\d+\s+-?\d\.\d+e[+-]\d+ ", text):  # "  19  1.1e+02 ...": an iteration's line
                iterations.append(text)
                if len(iterations) == 20:
                    os.kill(os.getpid(), signal.SIGINT)
            return len(text)

    monkeypatch.setattr(sys, "stderr", Stderr())
    code = main(["plan", "point_mass", "--task", str(task), "--out", str(tmp_path / "out"), "--no-validate",
                 "--no-plots", "--no-race", "-v"])
    log = "".join(after)
    assert code == 130 and log.strip().splitlines()[-1] == "planner plan: interrupted", log
    assert "Optimal Solution Found" not in log and not (tmp_path / "out").exists(), log


# a sitecustomize that sends its process a SIGINT as the module named by $STOP_AT is first imported: a Ctrl-C at a
# chosen point of the command's imports, not at a time that a slow or loaded machine would shift
STOP_AT_IMPORT = """
import os, signal, sys

class _StopAt:
    def find_spec(self, name, path=None, target=None):
        if name == os.environ["STOP_AT"]:
            sys.meta_path.remove(self)
            os.kill(os.getpid(), signal.SIGINT)
        return None

sys.meta_path.insert(0, _StopAt())
"""


@pytest.mark.parametrize("library", ["numpy", "pinocchio"])
@pytest.mark.parametrize("entry", [
    ["-c", "import sys\nfrom planner.cli import main\nsys.exit(main())"],  # the console script pip writes
    ["-m", "planner"]])
def test_ctrl_c_while_the_libraries_load_is_one_line_and_exit_130(tmp_path, library, entry):
    """A Ctrl-C in the first fraction of a second of a command, while NumPy or Pinocchio loads, ends it as a later one
    does: the line "planner COMMAND: interrupted" and exit 130. `import planner` loaded them before main ran, so the
    user saw Python's traceback and the process died of the SIGINT (-2 here)."""
    import signal

    (tmp_path / "sitecustomize.py").write_text(STOP_AT_IMPORT)
    env = {**os.environ, "STOP_AT": library,
           "PYTHONPATH": os.pathsep.join(filter(None, [str(tmp_path), os.environ.get("PYTHONPATH")]))}
    proc = subprocess.run([sys.executable, *entry, "check-model", "point_mass", "--samples", "1"], env=env,
                          capture_output=True, text=True, timeout=60,
                          # Ctrl-C's default also where the suite runs with SIGINT ignored (as in the test above)
                          preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    assert (proc.returncode, proc.stderr) == (130, "planner check-model: interrupted\n")


def test_a_failed_verdict_exits_1_and_a_failed_simulation_keeps_its_diagnostics(tmp_path, capsys, monkeypatch):
    """Exit code 1 (a valid input whose run failed), never 0 or 2: a simulation whose step did not converge (IPOPT's
    failure stubbed at a complementary point) exits 1 and writes its diagnostics to DIR/failed; `validate` of a
    result that did not converge exits 1; a plan that converged but whose MuJoCo validation fails (stubbed) exits 1.
    No test asserted these codes: each could have been 0."""
    import dataclasses

    import planner.replay
    import planner.simulate as sim

    drop = tmp_path / "drop"
    assert main(["simulate", "point_mass", "--task", _task(tmp_path), "--out", str(drop), "-q"]) == 0
    summary = json.loads((drop / "summary.json").read_text())
    (drop / "summary.json").write_text(json.dumps({**summary, "converged": False}))  # same result_id: still one result
    assert main(["validate", str(drop), "-q"]) == 1
    real_validate = planner.replay.validate
    monkeypatch.setattr(planner.replay, "validate",
                        lambda *a, **k: dataclasses.replace(real_validate(*a, **k), passed=False, failures=("stubbed",)))
    task = tmp_path / "hop.toml"
    task.write_text(HOP_TASK)
    assert main(["plan", "point_mass", "--task", str(task), "--out", str(tmp_path / "plan"), "-q", "--no-race", "--no-plots"]) == 1
    assert json.loads((tmp_path / "plan" / "summary.json").read_text())["converged"] is True
    real_solve = sim._solve_homotopy

    def failing(*args, **kwargs):
        x, lam, comp, n_nlp, iterations, _, _ = real_solve(*args, **kwargs)
        return x, lam, comp, n_nlp, iterations, False, "Maximum_Iterations_Exceeded"

    monkeypatch.setattr(sim, "_solve_homotopy", failing)
    assert main(["simulate", "point_mass", "--task", _task(tmp_path), "--out", str(tmp_path / "stuck"), "-q"]) == 1
    assert json.loads((tmp_path / "stuck" / "failed" / "summary.json").read_text())["converged"] is False
    capsys.readouterr()


def test_a_result_keeps_its_robot_files_hash_and_validate_refuses_the_file_changed_since(tmp_path, capsys):
    """summary.json of `planner simulate` and of `planner plan` holds robot_sha256, the SHA-256 of the robot file's
    contents (planner.model.file_sha256). `validate DIR` after that file was edited in place (the 1 kg point mass made
    1.3 kg) exits 2 with one line saying the file has other contents than the result was computed from: it replayed
    the result with the other mass, named only by the file's path. A summary.json without robot_sha256 (a result
    written before it was kept) still validates, with a note on stderr that the file was not checked (deleting the
    key switched the check off silently); a robot_sha256 that is not a string is exit 2 (a number did the same)."""
    robot = tmp_path / "pm.xml"
    robot.write_text((Path(__file__).resolve().parents[1] / "robots" / "point_mass.xml").read_text())
    hop = tmp_path / "hop.toml"
    hop.write_text(HOP_TASK)
    drop, plan = tmp_path / "drop", tmp_path / "plan"
    assert main(["simulate", str(robot), "--task", _task(tmp_path), "--out", str(drop), "-q", "--no-plots"]) == 0
    assert main(["plan", str(robot), "--task", str(hop), "--out", str(plan), "-q", "--no-plots", "--no-validate", "--no-race"]) == 0
    for out in (drop, plan):
        assert json.loads((out / "summary.json").read_text())["robot_sha256"] == file_sha256(robot)
    source = robot.read_text()
    assert source.count('mass="1"') == 1
    robot.write_text(source.replace('mass="1"', 'mass="1.3"'))
    _one_line_exit_2(capsys, ["validate", str(drop)], "has other contents")
    summary = json.loads((drop / "summary.json").read_text())
    (drop / "summary.json").write_text(json.dumps({**summary, "robot_sha256": 12345}))
    _one_line_exit_2(capsys, ["validate", str(drop)], "robot_sha256 must be a string")
    (drop / "summary.json").write_text(json.dumps({k: v for k, v in summary.items() if k != "robot_sha256"}))
    assert main(["validate", str(drop), "-q"]) == 0
    assert capsys.readouterr().err == ""
    assert main(["validate", str(drop)]) == 0
    assert "has no robot_sha256: the robot file is not checked" in capsys.readouterr().err


FAR_TASK = ('[[contacts]]\npoint = "point"\nmu = 0.5\n[initial]\nq = [0.0, 0.0]\n'
            '[horizon]\ntau_f = 0.2\nN = 5\n[plan]\ntarget_q = [50.0, 0.0]\nu_bound = 1.0\n')  # infeasible: 50 m at 1 N


def test_validate_fails_a_plan_whose_controls_were_zeroed(tmp_path, capsys):
    """The point-mass hop (both slides driven) validates; the same result with every control set to zero exits 1 on
    its own flight dynamics, while the tracking PD still follows it (it passed: the feedback carried the mass);
    --json prints the verdict with the command and the judged result's id."""
    hop = tmp_path / "hop.toml"
    hop.write_text(HOP_TASK)
    plan = tmp_path / "plan"
    # (20 steps: the task's 10 track to 12.5 mm, beyond the limit, docs/validation.md)
    assert main(["plan", "point_mass", "--task", str(hop), "--out", str(plan), "-q", "--no-plots", "--no-race",
                 "--steps", "20"]) == 0
    assert json.loads((plan / "summary.json").read_text())["validation"]["kinematic"]["max_flight_residual"] < 1e-6
    arrays = dict(np.load(plan / "trajectory.npz"))
    np.savez(plan / "trajectory.npz", **{**arrays, "u": np.zeros_like(arrays["u"])})
    capsys.readouterr()
    assert main(["validate", str(plan), "--json"]) == 1
    validation = json.loads(capsys.readouterr().out)
    # --json names the command and the result it judged (the verdict alone did not say whose, session 56)
    summary = json.loads((plan / "summary.json").read_text())
    assert validation["command"] == "validate" and validation["result_id"] == summary["result_id"]
    assert validation["max_tracking_error_m"] <= validation["thresholds"]["max_tracking_error_m"]
    assert [f.split(":")[0] for f in validation["failures"]] == ["the trajectory's own dynamics"], \
        validation["failures"]


def test_a_failed_iterate_whose_clock_runs_backwards_is_said_so_by_validate_and_view(tmp_path, capsys):
    """`planner validate DIR/failed` (which README offers for a failed solve's last iterate) and `view --html` of a
    failed iterate whose physical time falls say in one line that its clock runs backwards, where and by how much,
    so it is no motion to replay: validate exits 1 (a failed verdict, as for any failed iterate), view 2 (it has no
    verdict, a result it cannot draw is refused). Both said only "t must be non-decreasing" (exit 2), the far-hole
    hop's iterate going back from 0.541 s to -0.110 s (session 70's tester)."""
    far = tmp_path / "far.toml"
    far.write_text('[[contacts]]\npoint = "point"\nmu = 0.5\n[initial]\nq = [0.0, 0.0]\n'
                   '[horizon]\ntau_f = 0.2\nN = 5\n[plan]\ntarget_q = [50.0, 0.0]\nu_bound = 1.0\n')
    out = tmp_path / "out"
    assert main(["plan", "point_mass", "--task", str(far), "--out", str(out), "--no-validate", "--no-race",
                 "--no-plots", "-q", "--solve", '{"max_iter": 3}']) == 1
    failed = out / "failed"
    arrays = dict(np.load(failed / "trajectory.npz"))
    t = arrays["t"].copy()
    t[3:] -= t[3] - t[2] + 0.25  # the clock falls by 0.25 s at sample 3
    np.savez(failed / "trajectory.npz", **{**arrays, "t": t})
    capsys.readouterr()
    fall = f"clock runs backwards (t falls by 0.25 s, from {t[2]:.6g} s to {t[3]:.6g} s at sample 3)"
    assert main(["validate", str(failed)]) == 1
    err = capsys.readouterr().err.strip()
    assert err == f"planner validate: failed: {failed} holds a failed solve's last iterate whose {fall}: no motion " \
        "MuJoCo can replay; its failure is in summary.json's message"
    assert main(["view", str(failed), "--html", str(tmp_path / "view.html")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("planner view: error: ") and fall in err and len(err.splitlines()) == 1


@pytest.mark.parametrize("command", ["plan", "validate"])
def test_quiet_still_says_that_a_command_failed(tmp_path, capsys, command):
    """With -q, a command that fails (exit 1: a plan that does not converge; `validate` of a result that did not
    converge) prints exactly one line on stderr saying that it failed, and nothing on stdout: -q hid the report
    and with it the failure, so exit 1 printed nothing at all. A plan's line names where its diagnostics went (it did
    not: the default verbosity's "FAILED: results in DIR/failed" alone did)."""
    if command == "plan":
        task = tmp_path / "far.toml"
        task.write_text(FAR_TASK)
        argv = ["plan", "point_mass", "--task", str(task), "--out", str(tmp_path / "out"), "--no-validate", "--no-plots",
                "--no-race", "-q"]
    else:
        drop = tmp_path / "drop"
        assert main(["simulate", "point_mass", "--task", _task(tmp_path), "--out", str(drop), "-q", "--no-plots"]) == 0
        summary = json.loads((drop / "summary.json").read_text())
        (drop / "summary.json").write_text(json.dumps({**summary, "converged": False}))  # same result_id: one result
        capsys.readouterr()
        argv = ["validate", str(drop), "-q"]
    assert main(argv) == 1
    out, err = capsys.readouterr()
    assert out == "" and len(err.strip().splitlines()) == 1, (out, err)
    assert err.startswith(f"planner {command}: failed") and "Traceback" not in err
    if command == "plan":
        assert err.strip().endswith(f" (results in {tmp_path / 'out' / 'failed'})"), err


def test_a_quiet_failed_replan_says_where_its_diagnostics_went_and_what_to_do(tmp_path, capsys):
    """With -q, a replan (--init) that does not converge says on its one line where the diagnostics went and the
    replan's advice (plan without --init), which only the default verbosity printed."""
    start, far = tmp_path / "hop", tmp_path / "far.toml"
    assert main(["plan", "point_mass", "--task", "point_mass_hop", "--out", str(start), "-q", "--no-validate",
                 "--no-plots", "--no-race"]) == 0
    far.write_text((ROBOTS_DIR / "point_mass_hop.toml").read_text().replace("target_q = [0.5", "target_q = [20.0"))
    capsys.readouterr()
    assert main(["plan", "point_mass", "--task", str(far), "--init", str(start), "--out", str(tmp_path / "o"), "-q",
                 "--no-validate", "--no-plots"]) == 1
    out, err = capsys.readouterr()
    assert out == "" and len(err.strip().splitlines()) == 1, (out, err)
    assert err.strip().endswith(f" (results in {tmp_path / 'o' / 'failed'}); the replan from {start} did not converge: "
                                "the change may be too large for that start; plan without --init"), err


def test_inputs_a_tester_found_each_give_one_line(tmp_path, capsys):
    """What a robustness tester found (session 44), each now one line and exit 2 before any work, or read as the file
    means it: an --out that is a symbolic-link loop or below a dangling one (refused after the whole solve as "File
    exists"); an --out whose
    failed/ is a file (a failed solve's diagnostics were lost); `view --html` onto the result's own summary.json (it
    replaced it); a summary.json with a 5000-digit integer, a trajectory whose t is 0-d, `--window 1e308` (three
    tracebacks); an --init whose converged is "no" (read as converged); a task file with a byte-order mark (refused
    as TOML) and an empty one (its error named no file)."""
    out = tmp_path / "drop"
    assert main(["simulate", "point_mass", "--task", _task(tmp_path), "--out", str(out), "-q", "--no-plots"]) == 0
    (tmp_path / "loopA").symlink_to(tmp_path / "loopB")
    (tmp_path / "loopB").symlink_to(tmp_path / "loopA")
    _one_line_exit_2(capsys, ["simulate", "point_mass", "--out", str(tmp_path / "loopA")], "symbolic link to nothing")
    (tmp_path / "dangling").symlink_to(tmp_path / "nowhere")  # below it (session 52: refused after the solve too)
    _one_line_exit_2(capsys, ["simulate", "point_mass", "--out", str(tmp_path / "dangling" / "sub")],
                     "dangling is a symbolic link to nothing")
    (tmp_path / "q2").mkdir()
    (tmp_path / "q2" / "failed").write_text("hi")
    _one_line_exit_2(capsys, ["simulate", "point_mass", "--out", str(tmp_path / "q2")], "failed is not a directory")
    summary = (out / "summary.json").read_text()
    _one_line_exit_2(capsys, ["view", str(out), "--html", str(out / "summary.json")], "would overwrite a file that")
    assert (out / "summary.json").read_text() == summary
    assert main(["validate", str(out), "--window", "1e308", "-q"]) in (0, 1)  # the whole plan as one window
    huge = tmp_path / "huge"
    shutil.copytree(out, huge)
    (huge / "summary.json").write_text(summary.rstrip().rstrip("}") + ', "x": 1' + "0" * 5000 + "}")
    _one_line_exit_2(capsys, ["validate", str(huge)], "cannot be read as a result's summary")
    scalar = tmp_path / "scalar"
    shutil.copytree(out, scalar)
    arrays = dict(np.load(out / "trajectory.npz"))
    np.savez(scalar / "trajectory.npz", **{**arrays, "t": np.array(1.0)})
    _one_line_exit_2(capsys, ["view", str(scalar), "--html", str(tmp_path / "p.html")], "t must be a 1-D array")
    bom = tmp_path / "bom.toml"
    bom.write_bytes(b"\xef\xbb\xbf" + Path(_task(tmp_path)).read_bytes())
    assert main(["simulate", "point_mass", "--task", str(bom), "--out", str(tmp_path / "b"), "-q", "--no-plots"]) == 0
    (tmp_path / "empty.toml").write_text("")
    _one_line_exit_2(capsys, ["simulate", "point_mass", "--task", str(tmp_path / "empty.toml")], "empty.toml: missing key 'contacts'")


def test_inputs_session_48s_tester_found_each_give_one_line(tmp_path, capsys):
    """What a robustness tester found (session 48), each now one line and exit 2 before any work: `view --html` onto a
    file that is not an HTML page (the robot file the result reads was replaced; a page without the .html suffix is
    written again; another suffix, or a name ending in /, is refused) or below a file ("File exists");
    an --out whose summary.json is a directory (refused after the whole solve); a --solve field given twice (the last
    won); a file given as a result directory ("afile/trajectory.npz not found", "result directory not found")."""
    out = tmp_path / "drop"
    assert main(["simulate", "point_mass", "--task", _task(tmp_path), "--out", str(out), "-q", "--no-plots"]) == 0
    robot = tmp_path / "robot.xml"
    robot.write_text("<mujoco/>")
    _one_line_exit_2(capsys, ["view", str(out), "--html", str(robot)], "would overwrite a file that is not an HTML")
    assert robot.read_text() == "<mujoco/>"
    _one_line_exit_2(capsys, ["view", str(out), "--html", str(robot / "page.html")], "robot.xml is a file, not a")
    for _ in range(2):  # a page written without an .html suffix is a page: written again
        assert main(["view", str(out), "--html", str(tmp_path / "page"), "-q"]) == 0
    # another suffix, or a directory's name ending in /, new: written as the page, exit 0
    _one_line_exit_2(capsys, ["view", str(out), "--html", str(tmp_path / "x.png")], "is no HTML file's name (.png)")
    for end in ("/", "/.", "/.."):  # (Path drops them: "nd/." was written as a file nd, "nd/.." failed, exit 1)
        with pytest.raises(SystemExit) as usage:  # (a usage error: argparse exits)
            main(["view", str(out), "--html", str(tmp_path / "newdir") + end])
        err = capsys.readouterr().err.strip()
        assert usage.value.code == 2 and "names a directory; name the page's file" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "x.png").exists() and not (tmp_path / "newdir").exists()
    (tmp_path / "taken" / "summary.json").mkdir(parents=True)
    _one_line_exit_2(capsys, ["simulate", "point_mass", "--task", _task(tmp_path), "--out", str(tmp_path / "taken")],
                     "summary.json is a directory, where the result's file goes")
    hop = str(ROBOTS_DIR / "point_mass_hop.toml")
    _one_line_exit_2(capsys, ["plan", "point_mass", "--task", hop, "--solve", '{"tol": 1, "tol": 2}'], "more than once")
    for argv in (["validate", str(robot)], ["view", str(robot)],
                 ["plan", "point_mass", "--task", hop, "--init", str(robot)]):
        _one_line_exit_2(capsys, argv, "robot.xml is a file, not a result directory")


def test_init_refuses_a_summary_whose_converged_is_not_true(tmp_path, capsys):
    """--init starts only from a plan whose summary.json says converged: true ("no", an edited file, passed)."""
    plan = tmp_path / "hop"
    task = tmp_path / "hop.toml"
    task.write_text(HOP_TASK)
    assert main(["plan", "point_mass", "--task", str(task), "--out", str(plan), "--no-validate", "--no-race", "-q",
                 "--no-plots"]) == 0
    summary = json.loads((plan / "summary.json").read_text())
    (plan / "summary.json").write_text(json.dumps({**summary, "converged": "no"}))
    _one_line_exit_2(capsys, ["plan", "point_mass", "--task", str(task), "--init", str(plan), "--out", str(tmp_path / "r")],
                     "converged is 'no'")


def test_init_from_an_edited_problems_plan_warns(tmp_path, capsys):
    """--init from a plan whose summary.json names edited_problem (a Problem edited through the Python API) warns
    that the replan solves the task file's problem without those edits; it replanned in silence."""
    plan = tmp_path / "hop"
    task = tmp_path / "hop.toml"
    task.write_text(HOP_TASK)
    assert main(["plan", "point_mass", "--task", str(task), "--out", str(plan), "--no-validate", "--no-race", "-q",
                 "--no-plots"]) == 0
    argv = ["plan", "point_mass", "--task", str(task), "--init", str(plan), "--no-validate", "-q", "--no-plots"]
    assert main(argv + ["--out", str(tmp_path / "plain")]) == 0
    assert "edited" not in capsys.readouterr().err
    summary = json.loads((plan / "summary.json").read_text())
    (plan / "summary.json").write_text(json.dumps({**summary, "edited_problem": ["f", "ubx"]}))
    assert main(argv + ["--out", str(tmp_path / "r")]) == 0
    err = capsys.readouterr().err
    assert "warning:" in err and "edited through the Python API (f, ubx)" in err and "without those edits" in err


def test_a_closed_stdout_is_not_blamed_on_the_robot_file(tmp_path):
    """`planner simulate ... >&-` ran (Python's sys.stdout is None): the model loader flushed it and the error was
    read as "Pinocchio cannot parse point_mass.xml" (exit 2)."""
    proc = subprocess.run(f"{sys.executable} -m planner.cli simulate point_mass --task {_task(tmp_path)} --out {tmp_path / 'o'} "
                          "--no-plots >&-", shell=True, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0 and "cannot parse" not in proc.stderr, proc.stderr


def test_a_reader_that_leaves_does_not_stop_the_plan(tmp_path):
    """`planner plan ... 2>&1 | grep -m1 homotopy`: the reader of the progress lines left after the first; the solve
    stopped there, nothing was written and the exit code was 0. Now the lines are dropped and the plan is written."""
    task = ROBOTS_DIR / "point_mass_hop.toml"
    out, code = tmp_path / "o", tmp_path / "code"
    proc = subprocess.run(f"({sys.executable} -m planner.cli plan point_mass --task {task} --out {out} --no-plots "
                          f"--no-validate --no-race; echo $? > {code}) 2>&1 | head -c 1", shell=True,
                          capture_output=True, text=True, timeout=300)
    assert proc.stdout == " "  # the first character of the first progress line, then the reader left
    assert code.read_text().strip() == "0" and json.loads((out / "summary.json").read_text())["converged"] is True


def test_json_is_one_object_on_every_exit(tmp_path, capsys):
    """With --json, stdout holds one JSON object also when a command stops on an error: {"command", "exit_code",
    "error"} (it held nothing, so a script reading stdout failed to parse it), the error without stderr's "error: "
    prefix (the exit code says which kind); stderr keeps its one line."""
    assert main(["plan", "point_mass", "--task", str(tmp_path), "--json"]) == 2
    captured = capsys.readouterr()
    assert json.loads(captured.out) == {"command": "plan", "exit_code": 2,
                                        "error": f"task file {tmp_path} is a directory"}
    assert captured.err.strip() == f"planner plan: error: task file {tmp_path} is a directory"
    assert main(["simulate", "point_mass", "--task", _task(tmp_path), "--out", str(tmp_path / "s"), "--json", "--no-plots"]) == 0
    assert json.loads(capsys.readouterr().out)["command"] == "simulate"  # a success: the summary alone


@pytest.fixture
def ctrl_c():
    """Python's own SIGINT handler for the test, the one before restored after: a shell's background job (CI's
    `bash .ci/run &`) starts Python with SIGINT ignored, and the planner leaves an ignored Ctrl-C ignored."""
    import signal

    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def test_ctrl_c_while_the_plots_are_drawn_waits_for_them(ctrl_c):
    """A Ctrl-C (SIGINT) inside errors.interruptible(defer=True), around the drawing of a result's plots, lets the block
    finish and then interrupts (KeyboardInterrupt, exit 130): it stopped the drawing half way, and the new result
    stood beside part of its plots."""
    import os
    import signal

    from planner.errors import interruptible

    finished = []
    with pytest.raises(KeyboardInterrupt):
        with interruptible(defer=True):
            os.kill(os.getpid(), signal.SIGINT)
            finished.append(True)
    assert finished == [True] and signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_a_ctrl_c_casadi_raised_as_its_own_error_is_an_interruption(ctrl_c):
    """A Ctrl-C inside errors.interruptible whose block then raises another error (CasADi's "Error in Function::call
    ... KeyboardInterrupt" RuntimeError, 1 in 15 interrupts of an FESD simulate) is a KeyboardInterrupt (exit 130):
    the RuntimeError had escaped as a traceback and exit 1. Without a Ctrl-C the block's error is not hidden."""
    import os
    import signal

    from planner.errors import interruptible

    with pytest.raises(KeyboardInterrupt):
        with interruptible():
            try:
                os.kill(os.getpid(), signal.SIGINT)
            except KeyboardInterrupt:
                raise RuntimeError("Error in Function::call for 'fesd_collocated' [IpoptInterface]: KeyboardInterrupt")
    with pytest.raises(RuntimeError, match="not an interrupt"):
        with interruptible():
            raise RuntimeError("not an interrupt")


def test_a_ctrl_c_casadi_turned_into_a_system_error_is_an_interruption(tmp_path, capsys, monkeypatch):
    """A Ctrl-C inside a Python callback that CasADi calls comes back as SystemError ("returned a result with an
    exception set") with the KeyboardInterrupt as its cause: exit 130 and one line, as Ctrl-C elsewhere (it was a
    traceback and exit 1). Another SystemError is not hidden."""
    import planner.cli as cli

    def interrupted(args):
        raise SystemError("<function DM.__array__> returned a result with an exception set") from KeyboardInterrupt()

    monkeypatch.setattr(cli, "_cmd_simulate", interrupted)
    assert main(["simulate", "point_mass", "--out", str(tmp_path / "out")]) == 130
    assert capsys.readouterr().err.strip() == "planner simulate: interrupted"

    def broken(args):
        raise SystemError("something else")

    monkeypatch.setattr(cli, "_cmd_simulate", broken)
    with pytest.raises(SystemError, match="something else"):
        main(["simulate", "point_mass", "--out", str(tmp_path / "out")])


def test_a_ctrl_c_in_the_validation_says_the_result_was_written(tmp_path, capsys, monkeypatch):
    """A Ctrl-C during a plan's validation, after the new result replaced the earlier one, says where the result is and
    that it is without validation before the interruption's line (exit 130): "interrupted" alone let the earlier result
    seem kept; right after the verdict was stored it says the result is there, nothing missing."""
    import planner.replay as replay

    def interrupted(target, options=None):
        raise KeyboardInterrupt

    real_validate = replay.validate
    monkeypatch.setattr(replay, "validate", interrupted)
    out = tmp_path / "out"
    assert main(["plan", "point_mass", "--task", str(ROBOTS_DIR / "point_mass_hop.toml"), "--steps", "10", "--no-race",
                 "--no-plots", "-q", "--out", str(out)]) == 130
    assert capsys.readouterr().err.splitlines() == [f"planner plan: converged: results in {out}, without validation",
                                                    "planner plan: interrupted"]
    assert (out / "summary.json").is_file()
    # a Ctrl-C right after the verdict was stored: the result is there, validated (it said "not validated")
    real = replay.write_validation

    def then_interrupted(*a, **k):
        real(*a, **k)
        raise KeyboardInterrupt

    monkeypatch.setattr(replay, "validate", real_validate)
    monkeypatch.setattr(replay, "write_validation", then_interrupted)
    assert main(["plan", "point_mass", "--task", str(ROBOTS_DIR / "point_mass_hop.toml"), "--steps", "10", "--no-race",
                 "--no-plots", "-q", "--out", str(out)]) == 130
    assert capsys.readouterr().err.splitlines() == [f"planner plan: converged: results in {out}",
                                                    "planner plan: interrupted"]
    assert "validation" in json.loads((out / "summary.json").read_text())


def test_a_ctrl_c_held_while_the_result_is_written_says_it_was_written(tmp_path, capsys, monkeypatch):
    """A Ctrl-C during the write is held until both files are in place (result.write_files) and then raised: the
    command says the result is there, without plots or validation, before the interruption's line (exit 130), as a
    Ctrl-C in the validation does; "interrupted" alone let the earlier, replaced result seem kept."""
    import planner.result as result_module

    real = result_module.write_results

    def held(result, target, result_id=None):
        real(result, target, result_id)
        raise KeyboardInterrupt

    monkeypatch.setattr(result_module, "write_results", held)
    out = tmp_path / "out"
    assert main(["plan", "point_mass", "--task", str(ROBOTS_DIR / "point_mass_hop.toml"), "--steps", "10", "--no-race",
                 "-q", "--out", str(out)]) == 130
    assert capsys.readouterr().err.splitlines() == [f"planner plan: converged: results in {out}, without plots or "
                                                    "validation", "planner plan: interrupted"]
    # simulate's foreground plots: a Ctrl-C held over their drawing (only "interrupted", DIR replaced)
    import planner.cli as cli_module

    monkeypatch.setattr(result_module, "write_results", real)
    monkeypatch.setattr(cli_module, "_plotted", lambda *a: (_ for _ in ()).throw(KeyboardInterrupt()))
    assert main(["simulate", "point_mass", "-q", "--out", str(tmp_path / "sim")]) == 130
    assert capsys.readouterr().err.splitlines() == [f"planner simulate: converged: results in {tmp_path / 'sim'}",
                                                    "planner simulate: interrupted"]


def test_a_failed_plan_that_spans_no_physical_time_is_reported_not_validated(tmp_path, capsys):
    """A plan stopped after 3 IPOPT iterations per NLP whose last iterate never runs the clock (a box on two corners)
    spans no physical time: it is reported as failed (exit 1, its diagnostics in DIR/failed) without a validation,
    which refused such a trajectory as an input error (exit 2, no report)."""
    robot = tmp_path / "box.xml"
    robot.write_text(
        '<mujoco><option gravity="0 0 -9.81"/><worldbody><body name="box"><joint name="x" type="slide" axis="1 0 0"/>'
        '<joint name="z" type="slide" axis="0 0 1"/><joint name="pitch" type="hinge" axis="0 1 0"/>'
        '<inertial pos="0 0 0" mass="2" diaginertia="0.01 0.01 0.01"/><site name="left" pos="-0.1 0 -0.05"/>'
        '<site name="right" pos="0.1 0 -0.05"/></body></worldbody><actuator><motor name="fx" joint="x" '
        'ctrlrange="-50 50"/><motor name="fz" joint="z" ctrlrange="-50 50"/><motor name="tp" joint="pitch" '
        'ctrlrange="-10 10"/></actuator></mujoco>')
    task = tmp_path / "box.toml"
    task.write_text('[[contacts]]\npoint = "left"\nmu = 0.5\n[[contacts]]\npoint = "right"\nmu = 0.5\n[initial]\n'
                    'q = [0.0, 0.05, 0.0]\n[horizon]\ntau_f = 0.6\nN = 12\n[plan]\ntarget_q = [0.2, 0.05, 0.0]\n')
    out = tmp_path / "out"
    assert main(["plan", str(robot), "--task", str(task), "--out", str(out), "--solve", '{"max_iter": 3}', "--no-race",
                 "--no-plots"]) == 1
    printed = capsys.readouterr().out
    assert f"FAILED: results in {out / 'failed'}" in printed


def test_a_failed_plan_is_not_replayed_in_mujoco(tmp_path, capsys, monkeypatch):
    """`plan` reports a failed solve (exit 1, the failure line) without replaying its last iterate: an iterate whose
    clock went back by 1e-9 s was refused by the validation as an input error (exit 2, no failure line), and one
    spanning 980 s of physical time was replayed for ten minutes after the solve had failed."""
    import planner.replay as replay

    def replayed(target, options=None):
        raise AssertionError("a failed plan was replayed")

    monkeypatch.setattr(replay, "validate", replayed)
    out = tmp_path / "out"
    assert main(["plan", "point_mass", "--task", str(ROBOTS_DIR / "point_mass_hop.toml"), "--solve", '{"max_iter": 3}',
                 "--no-race", "--no-plots", "--out", str(out)]) == 1
    assert f"FAILED: results in {out / 'failed'}" in capsys.readouterr().out


BAD_ALLOC = RuntimeError("Error in Function::factory for 'nlp_hess_l' [MXFunction] at .../function.cpp:1912: "
                         "std::bad_alloc")  # CasADi's words when its C++ allocation fails


@pytest.mark.parametrize("error", [MemoryError(), BAD_ALLOC])
def test_running_out_of_memory_is_one_line_that_names_the_likely_causes(tmp_path, capsys, monkeypatch, error):
    """A MemoryError (a huge horizon.N, or the physical time MuJoCo replays at its 0.25 ms step) or CasADi's C++
    std::bad_alloc (N = 5000 under a 2.5 GB limit: it was a 35-line traceback, session 57's tester) is one line,
    exit 1, naming both causes (it named N only, which was 20) and the memory a step takes."""
    import planner.cli as cli

    def exhausted(*args, **kwargs):
        raise error

    monkeypatch.setattr(cli, "_write", exhausted)
    assert main(["plan", "point_mass", "--task", str(ROBOTS_DIR / "point_mass_hop.toml"), "--steps", "10", "--no-race",
                 "--no-plots", "-q", "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == ("planner plan: failed: out of memory (is horizon.N or --steps far too large, ~1 MB per step for "
                       "a robot of Capler's size, or the physical time MuJoCo replays too long for this machine?)")


@pytest.mark.parametrize("limit, error", [(10, None), (None, MemoryError())])
def test_a_converged_plan_mujoco_cannot_replay_is_reported_with_the_reason(tmp_path, capsys, monkeypatch, limit, error):
    """A converged plan whose MuJoCo replay would take more than MAX_STEPS steps (tau_f = 1e6 s: 4e9), or runs out of
    memory, prints its report and one line that the validation did not run and why, exit 1 as a failed validation:
    it printed only "failed: out of memory", hiding the converged plan (session 70's tester). The reason is also
    summary.json's `validation_not_run`, --json's and -q's failure line's: they gave none, and summary.json read as
    a --no-validate plan's (review r3)."""
    import planner.replay as replay

    def exhausted(target, options=None):
        raise error

    if limit is not None:  # the hop's 1 s at MuJoCo's 0.25 ms step is 4000 steps
        monkeypatch.setattr(replay, "MAX_STEPS", limit)
    else:
        monkeypatch.setattr(replay, "validate", exhausted)
    out = tmp_path / "out"
    assert main(["plan", "point_mass", "--task", str(ROBOTS_DIR / "point_mass_hop.toml"), "--steps", "10", "--no-race",
                 "--no-plots", "--out", str(out)]) == 1
    printed = capsys.readouterr().out.splitlines()
    assert f"converged: results in {out}" in printed
    assert printed[-1].startswith("MuJoCo validation not run: ")
    assert ("MuJoCo steps of 0.00025 s, more than 10:" if limit else "ran out of memory") in printed[-1]
    why = printed[-1].removeprefix("MuJoCo validation not run: ")
    assert json.loads((out / "summary.json").read_text())["validation_not_run"] == why
    assert main(["plan", "point_mass", "--task", str(ROBOTS_DIR / "point_mass_hop.toml"), "--steps", "10", "--no-race",
                 "--no-plots", "--out", str(out), "--json", "-q"]) == 1
    printed = capsys.readouterr()
    assert json.loads(printed.out)["validation_not_run"] == why
    assert printed.err.strip().splitlines()[-1] == (f"planner plan: failed: MuJoCo validation not run: {why} "
                                                    f"(results in {out})")


def test_validate_of_a_result_mujoco_cannot_replay_exits_1(tmp_path, capsys, monkeypatch):
    """`planner validate DIR` of a valid result whose replay would take more than MAX_STEPS MuJoCo steps exits 1 with
    one "failed:" line saying the validation did not run and why, as `planner plan` does for the same result: it
    exited 2 with "error:", which tells the user to fix an input that is not at fault (review r3)."""
    import planner.replay as replay

    drop = tmp_path / "drop"
    assert main(["simulate", "point_mass", "--task", _task(tmp_path), "--out", str(drop), "-q", "--no-plots"]) == 0
    monkeypatch.setattr(replay, "MAX_STEPS", 10)  # the drop's 0.1 s at MuJoCo's 0.25 ms step is 400 steps
    capsys.readouterr()
    assert main(["validate", str(drop), "-q"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("planner validate: failed: MuJoCo validation not run: a replay of "), err


def test_a_plot_that_fails_unexpectedly_is_one_line(tmp_path, capsys, monkeypatch):
    """An unexpected error while a simulation's plots are drawn in the command's own process (a singular matrix of a
    ground at 1e15 m) is one "failed:" line, exit 1, as in the plotting child of a validating plan: it was a
    traceback. The line says where the error was raised, so a bug in the plots can be placed without one."""
    import numpy as np

    import planner.plots as plots

    def singular(target):
        raise np.linalg.LinAlgError("Singular matrix")

    monkeypatch.setattr(plots, "plot_results", singular)
    out = tmp_path / "out"
    assert main(["simulate", "point_mass", "--out", str(out), "-q"]) == 1
    err = capsys.readouterr().err.strip()  # (the innermost planner frame: the patched plot_results is this file's)
    assert re.fullmatch(rf"planner simulate: failed: the plots of {re.escape(str(out))} failed: LinAlgError: "
                        r"Singular matrix \(raised at cli.py:\d+ in _draw\) \(the results are written there\)",
                        err), err


@pytest.mark.parametrize("command", [["simulate", "point_mass"],
                                     ["plan", "point_mass", "--task", "point_mass_hop", "--no-race", "--no-validate"],
                                     ["plan", "point_mass", "--task", "point_mass_hop", "--no-race"]])
def test_plots_that_cannot_be_written_come_after_the_report(tmp_path, capsys, monkeypatch, command):
    """Plots that cannot be written (a full disk, a PlannerError) after a converged run: the run's report is printed
    first, with its "converged: results in DIR" line, then one "failed:" line (exit 1) that says the results are
    written, without the internal "raised at" place of a bug (the report was never printed and the line read as a
    bug's, session 59's tester). With --json the one JSON object is the failure's, with its reason (the review: the
    summary came first and the reason was on stderr only)."""
    import planner.plots as plots

    def full(target):
        raise PlannerError(f"cannot write {target}/clock.png: No space left on device")

    monkeypatch.setattr(plots, "plot_results", full)
    out = tmp_path / "out"
    assert main([*command, "--out", str(out)]) == 1
    captured = capsys.readouterr()
    assert f"converged: results in {out}" in captured.out
    reason = (f"the plots of {out} failed: cannot write {out}/clock.png: No space left on device (the results are "
              "written there)")
    assert captured.err.strip().splitlines()[-1] == f"planner {command[0]}: failed: {reason}"
    assert main([*command, "--out", str(out), "--json"]) == 1
    assert json.loads(capsys.readouterr().out) == {"command": command[0], "exit_code": 1, "error": reason}


def test_plots_that_cannot_be_removed_leave_the_earlier_result_whole(tmp_path, capsys, monkeypatch):
    """The earlier result's plots are set aside before the new result is written: when one cannot be (an immutable
    file), the command stops (exit 2) with the earlier result and its plots as they were (the new result had replaced
    it first and stood beside the old plots); when the write fails (a full disk), the plots are put back (they were
    deleted); PNGs in a directory that held no result are the user's, left alone (--no-plots deleted them)."""
    import errno

    import planner.cli as cli
    import planner.result as result_module

    out = tmp_path / "out"
    assert main(["simulate", "point_mass", "--task", _task(tmp_path), "--out", str(out), "-q"]) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    real_replace = os.replace

    def refused(src, dst):
        if Path(src).name == "torques.png":
            raise PermissionError(1, "Operation not permitted", str(src))
        real_replace(src, dst)

    monkeypatch.setattr(cli.os, "replace", refused)
    assert main(["simulate", "point_mass", "--task", _task(tmp_path, z0=0.3), "--out", str(out), "-q"]) == 2
    assert "Operation not permitted" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # (no hidden directory left either)
    monkeypatch.setattr(cli.os, "replace", real_replace)

    def full(*args):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(result_module, "write_results", full)
    assert main(["simulate", "point_mass", "--task", _task(tmp_path, z0=0.3), "--out", str(out), "-q"]) == 1
    assert "No space left on device" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    monkeypatch.undo()
    mine = tmp_path / "figures"
    mine.mkdir()
    (mine / "states.png").write_bytes(b"my own figure")
    assert main(["simulate", "point_mass", "--task", _task(tmp_path), "--out", str(mine), "-q", "--no-plots"]) == 0
    assert (mine / "states.png").read_bytes() == b"my own figure"


@pytest.mark.parametrize("name", ["SIGTERM", "SIGHUP"])
def test_a_sigterm_is_a_ctrl_c(tmp_path, capsys, monkeypatch, ctrl_c, name):
    """A SIGTERM (timeout, a CI cancellation) or a SIGHUP (a closed terminal, an ssh session that ended) during a
    command is handled as Ctrl-C: inside the deferred block around a result's plots the block finishes first, then
    exit 130 and one line (the signal killed the process there, the earlier result's plots left hidden in a temporary
    directory; a SIGHUP left `view`'s meshcat server running). The signal's handler is the one before afterwards. Under
    `nohup` (SIGHUP ignored) a SIGHUP stays ignored and the command runs to its end."""
    import os
    import signal

    import planner.cli as cli
    from planner.errors import interruptible

    finished, sig = [], getattr(signal, name)

    def plotting(args):
        with interruptible(defer=True):
            os.kill(os.getpid(), sig)
            finished.append(True)
        return cli.EXIT_OK

    def unhandled(signum, frame):  # (the default would end the test run itself)
        raise AssertionError(f"the command left {name} to the handler before it")

    before = signal.signal(sig, unhandled)
    try:
        monkeypatch.setattr(cli, "_cmd_simulate", plotting)
        assert main(["simulate", "point_mass", "--out", str(tmp_path / "out")]) == 130 and finished == [True]
        assert capsys.readouterr().err.strip() == "planner simulate: interrupted"
        assert signal.getsignal(sig) is unhandled
        # Ctrl-C ignored, as in a script's background job: the signal still ends the command as an interruption,
        # through the same blocks (IPOPT's caught interrupt read as a failed NLP there: the solve went on, exit 0), and
        # Ctrl-C is ignored again after it
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        finished.clear()
        assert main(["simulate", "point_mass", "--out", str(tmp_path / "out")]) == 130 and finished == [True]
        assert capsys.readouterr().err.strip() == "planner simulate: interrupted"
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
        # and a Ctrl-C meant for the script stays ignored by the command (it was switched on, and stopped the plan)
        finished.clear()
        monkeypatch.setattr(cli, "_cmd_simulate", lambda args: (os.kill(os.getpid(), signal.SIGINT),
                                                                finished.append(True), cli.EXIT_OK)[-1])
        assert main(["simulate", "point_mass", "--out", str(tmp_path / "out")]) == 0 and finished == [True]
        monkeypatch.setattr(cli, "_cmd_simulate", plotting)
        # `view --html` too (it ended by the signal, exit 143 and no word; only the live view had a handler)
        signal.signal(signal.SIGINT, signal.default_int_handler)
        monkeypatch.setattr(cli, "_cmd_view", plotting)
        assert main(["view", str(tmp_path), "--html", str(tmp_path / "page.html")]) == 130
        assert capsys.readouterr().err.strip() == "planner view: interrupted"
        if sig == signal.SIGHUP:  # nohup's
            signal.signal(sig, signal.SIG_IGN)
            finished.clear()
            assert main(["simulate", "point_mass", "--out", str(tmp_path / "out")]) == 0 and finished == [True]
            assert capsys.readouterr().err.strip() == ""
            assert signal.getsignal(sig) is signal.SIG_IGN
    finally:
        signal.signal(sig, before)


def test_a_closed_stderr_keeps_the_progress_out_of_stdout(tmp_path):
    """With stderr closed (`2>&-`) the progress lines are dropped, not printed into stdout's report (print(file=None)
    wrote them on stdout, mixed into the summary; signals tester, session 65): stdout is the report alone."""
    run = subprocess.run([sys.executable, "-m", "planner.cli", "plan", "point_mass", "--task",
                          str(ROBOTS_DIR / "point_mass_hop.toml"), "--out", str(tmp_path / "out"), "--no-validate"],
                         stdout=subprocess.PIPE, text=True, preexec_fn=lambda: os.close(2),
                         env={**os.environ, "OMP_NUM_THREADS": "1"}, timeout=600)
    assert run.returncode == 0
    assert run.stdout.startswith("plan point_mass.xml: converged"), run.stdout[:300]
    assert not re.search(r"^\s+(default|alternate): ", run.stdout, re.M), run.stdout
    usage = subprocess.run([sys.executable, "-m", "planner.cli", "plan", "point_mass", "--no-such-flag"],
                           stdout=subprocess.PIPE, text=True, preexec_fn=lambda: os.close(2), timeout=600)
    assert (usage.returncode, usage.stdout) == (2, "")  # a usage error's line too


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
def test_a_full_stderr_does_not_stop_the_solve(tmp_path):
    """Progress to a stderr that refuses every write (`2>/dev/full`) is dropped and the plan goes on to its results,
    exit 0 (it stopped at the first progress line: exit 1, nothing written, no word anywhere; signals tester,
    session 65)."""
    with open("/dev/full", "w") as full:
        run = subprocess.run([sys.executable, "-m", "planner.cli", "plan", "point_mass", "--task",
                              str(ROBOTS_DIR / "point_mass_hop.toml"), "--out", str(tmp_path / "out"), "--no-validate"],
                             stdout=subprocess.PIPE, stderr=full, text=True, env={**os.environ, "OMP_NUM_THREADS": "1"},
                             timeout=600)
    assert run.returncode == 0 and run.stdout.startswith("plan point_mass.xml: converged"), run.stdout[:300]
    assert (tmp_path / "out" / "summary.json").is_file()


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
def test_a_usage_error_with_a_full_stderr_still_exits_2_with_its_json():
    """A usage error whose line a full stderr (`2>/dev/full`) refuses still exits 2 with --json's object on stdout:
    the line's OSError was a traceback, exit 1 and nothing on stdout, so a script read no JSON and a wrong code."""
    with open("/dev/full", "w") as full:
        usage = subprocess.run([sys.executable, "-m", "planner.cli", "plan", "point_mass", "--bogus", "--json"],
                               stdout=subprocess.PIPE, stderr=full, text=True, timeout=120)
    assert (usage.returncode, json.loads(usage.stdout)["exit_code"]) == (2, 2), usage.stdout


def test_an_eio_is_a_hang_up_only_on_a_terminal(tmp_path):
    """The command's output stream drops an EIO only where it is a terminal's hang-up (a character device); a file's
    EIO is a failing disk, and it still fails the command (reviewer, session 65: dropped everywhere, `--json >
    out.json` on a failing disk left a cut-short file and exit 0)."""
    import errno

    from planner.cli import _ReaderMayLeave

    class Failing:
        def __init__(self, fileno):
            self._fileno = fileno

        def write(self, text):
            raise OSError(errno.EIO, "Input/output error")

        def fileno(self):
            return self._fileno

    with open(tmp_path / "out.json", "w") as regular, open(os.devnull, "w") as character:
        with pytest.raises(OSError, match="Input/output error"):
            _ReaderMayLeave(Failing(regular.fileno())).write("{}")
        assert _ReaderMayLeave(Failing(character.fileno())).write("{}") == 2


SLOW_READER_START_S = 0.05  # [s] the reader's first read waits so long: the writer fills the 64 KiB pipe meanwhile
SLOW_READER_PAUSE_S = 0.001  # [s] between its 4 KiB reads, so that the pipe is full again at almost every write
READER_DONE_S = 30  # [s] the reader has read everything well within it; room for a loaded box


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="sets the pipe's size")
@pytest.mark.parametrize("unbuffered", [False, True], ids=["line-buffered", "PYTHONUNBUFFERED"])
def test_a_slow_reader_of_a_non_blocking_stderr_gets_every_line(unbuffered):
    """stderr set non-blocking (a terminal multiplexer, or `planner plan ... -v 2>&1 | slow_reader` with a pipe set
    so) whose reader is momentarily behind is waited for, not taken for one that left: 144 kB of lines, more than the
    pipe holds, all arrive once, whole and in order (its first full pipe sent the text and the rest of the run's
    stderr, the final "interrupted" or error line included, to /dev/null; under PYTHONUNBUFFERED=1 the text layer
    dropped what the pipe refused without an error)."""
    import io
    import threading
    import time

    from planner.cli import _ReaderMayLeave

    read_end, write_end, _ = _small_nonblocking_pipe()  # (one page: 144 kB fill it on any page size)
    arrived = bytearray()

    def slow_reader():
        time.sleep(SLOW_READER_START_S)
        while chunk := os.read(read_end, 4096):
            arrived.extend(chunk)
            time.sleep(SLOW_READER_PAUSE_S)

    reader = threading.Thread(target=slow_reader, daemon=True)
    reader.start()
    try:  # sys.stderr's two kinds: line-buffered over a BufferedWriter, and write-through over the descriptor's FileIO
        raw = io.FileIO(write_end, "w", closefd=False)
        stream = io.TextIOWrapper(raw if unbuffered else io.BufferedWriter(raw), encoding="utf-8",
                                  errors="backslashreplace", line_buffering=not unbuffered, write_through=unbuffered)
        err = _ReaderMayLeave(stream, diagnostics=True)
        lines = [f"{i:04d} über {'x' * 60}\n" for i in range(2000)]  # (a two-byte character: bytes, not characters)
        for line in lines:
            print(line, end="", file=err, flush=True)
        stream.flush()
    finally:
        os.close(write_end)
        reader.join(READER_DONE_S)
        os.close(read_end)
    assert arrived.decode() == "".join(lines)


STALL_S = 0.05  # [s] STALLED_READER_S for the test: the write must give up soon after it
# [s] how much later than STALL_S a stopped reader's write may give up: room for a loaded box, and well under the
# 10 s of the real STALLED_READER_S that a write ignoring the patched one would take
GIVE_UP_SLACK_S = 3.0
PAUSED_READER_S = 0.5  # [s] the stdout reader's pause before its first read: ten times STALL_S


def _small_nonblocking_pipe() -> tuple[int, int, int]:
    """A pipe (read end, write end) whose write end is non-blocking, and the bytes it holds [B]: set to one page (the
    kernel's least), so that a write of that many bytes plus one fills it on any page size (64 KiB pages: 1 MiB by
    default)."""
    import fcntl

    read_end, write_end = os.pipe()
    fcntl.fcntl(write_end, fcntl.F_SETPIPE_SZ, 4096)
    os.set_blocking(write_end, False)
    return read_end, write_end, fcntl.fcntl(write_end, fcntl.F_GETPIPE_SZ)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/fd, sets the pipe's size")
def test_a_non_blocking_stderr_whose_reader_stopped_does_not_hang_the_run(monkeypatch):
    """stderr set non-blocking whose reader stopped reading for good (a paused pipeline) counts as gone once it took
    nothing for STALLED_READER_S: the write returns soon after it, so the solve and its "interrupted" line, printed
    with Ctrl-C ignored, do not wait for ever, and stderr is pointed at /dev/null as for a reader that left."""
    import time

    import planner.cli

    monkeypatch.setattr(planner.cli, "STALLED_READER_S", STALL_S)
    read_end, write_end, size = _small_nonblocking_pipe()
    try:
        with open(write_end, "w", buffering=1, closefd=False) as stream:
            err = planner.cli._ReaderMayLeave(stream, diagnostics=True)
            start = time.monotonic()
            assert err.write("x" * size + "\n") == size + 1  # one byte more than the pipe holds
            assert time.monotonic() - start < STALL_S + GIVE_UP_SLACK_S
            assert os.readlink(f"/proc/self/fd/{write_end}") == os.devnull
    finally:
        os.close(write_end)
        os.close(read_end)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="sets the pipe's size")
def test_a_non_blocking_stdout_waits_for_a_reader_that_pauses_longer_than_stderr_would(monkeypatch):
    """stdout set non-blocking whose reader pauses for longer than STALLED_READER_S (--json's reader busy elsewhere)
    is waited for as a blocking stream is, and the reader gets the whole text: stdout is written after the results,
    and a write that gave up there ended the run with exit 1 and half a JSON object."""
    import signal
    import threading
    import time

    import planner.cli

    monkeypatch.setattr(planner.cli, "STALLED_READER_S", STALL_S)
    read_end, write_end, size = _small_nonblocking_pipe()
    arrived = bytearray()

    def paused_reader():
        time.sleep(PAUSED_READER_S)
        while chunk := os.read(read_end, 65536):
            arrived.extend(chunk)

    reader = threading.Thread(target=paused_reader, daemon=True)
    reader.start()
    text = "x" * 2 * size + "\n"  # twice what the pipe holds
    # Ctrl-C as in a terminal, also where the suite runs with it ignored (nohup, a background job): a wait nothing
    # could stop gives up as stderr's does
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with open(write_end, "w", closefd=False) as stream:
            assert planner.cli._ReaderMayLeave(stream).write(text) == len(text)
    finally:
        signal.signal(signal.SIGINT, previous)
        os.close(write_end)
        reader.join(READER_DONE_S)
        os.close(read_end)
    assert arrived.decode() == text



@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="sets the pipe's size")
def test_a_non_blocking_stdout_whose_reader_stopped_gives_up_while_ctrl_c_is_ignored(monkeypatch):
    """stdout set non-blocking whose reader stopped for good gives up after STALLED_READER_S, as stderr does, while
    Ctrl-C is ignored (the report of an interruption, a background job): nothing could end that wait, and after a
    Ctrl-C a full stdout's --json line hung the command for good, SIGTERM ignored too (second reviewer, session 67)."""
    import signal
    import threading
    import time

    import planner.cli

    monkeypatch.setattr(planner.cli, "STALLED_READER_S", STALL_S)
    read_end, write_end, size = _small_nonblocking_pipe()
    outcome = []

    def writer():
        start = time.monotonic()
        try:
            with open(write_end, "w", closefd=False) as stream:
                planner.cli._ReaderMayLeave(stream).write("x" * size + "\n")  # one byte more than the pipe holds
        except BlockingIOError:
            outcome.append(time.monotonic() - start)

    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        thread = threading.Thread(target=writer, daemon=True)  # (one that waits for ever must not hold the suite)
        thread.start()
        thread.join(STALL_S + GIVE_UP_SLACK_S)
    finally:
        signal.signal(signal.SIGINT, previous)
        os.close(read_end)  # (a writer still waiting wakes on the broken pipe)
        thread.join(READER_DONE_S)
        os.close(write_end)
    assert len(outcome) == 1 and outcome[0] < STALL_S + GIVE_UP_SLACK_S, outcome


def test_a_ctrl_c_while_an_error_line_is_written_is_exit_130(tmp_path, monkeypatch):
    """A Ctrl-C that lands while a command's error line (or --json's object) is written, a reader having stalled, ends
    the command with exit 130 as any Ctrl-C does: main writes it from an except clause, where the KeyboardInterrupt
    escaped as a traceback (second reviewer, session 67)."""
    import planner.cli

    def interrupted(args, text):
        raise KeyboardInterrupt

    monkeypatch.setattr(planner.cli, "_to_stderr", interrupted)
    try:
        code = main(["plan", str(tmp_path / "missing.xml"), "--out", str(tmp_path / "out")])
    except KeyboardInterrupt:
        code = "a traceback"
    assert code == 130


CLOSED_RUN = """import os, sys
from planner.cli import main
rc = main(['check-model', 'point_mass', '--json'])
with open(sys.argv[1], 'w') as report:
    report.write(f"{rc} {os.readlink('/proc/self/fd/1')} {os.readlink('/proc/self/fd/2')}")
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/fd")
def test_closed_standard_descriptors_are_not_reused_and_get_nothing(tmp_path):
    """With stdout and stderr closed (`>&- 2>&-`) the command opens /dev/null on descriptors 1 and 2, so that no file
    it opens takes their numbers (a plot's temporary file became descriptor 2, where C libraries write); with stdout
    alone closed, --json's object is dropped, not printed on stderr (reviewer, session 65)."""
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    report = tmp_path / "report.txt"

    def closing(*fds):
        return lambda: [os.close(fd) for fd in fds]

    run = subprocess.run([sys.executable, "-c", CLOSED_RUN, str(report)], preexec_fn=closing(1, 2), env=env,
                         timeout=600)
    assert run.returncode == 0 and report.read_text() == "0 /dev/null /dev/null"
    run = subprocess.run([sys.executable, "-m", "planner.cli", "check-model", "point_mass", "--json"],
                         stderr=subprocess.PIPE, text=True, preexec_fn=closing(1), env=env, timeout=600)
    assert (run.returncode, run.stderr) == (0, "")


SOLVE_START_S = 120  # [s] the race's arms are forked ~3 s after the command starts; a loaded CI box takes longer
HANGUP_EXIT_S = 30  # [s] the arms are killed and the line printed within a second; room for a loaded box


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc; a pty's hang-up as Linux sends it")
def test_a_plan_whose_terminal_hangs_up_ends_as_interrupted(tmp_path):
    """A terminal that closes under a running `planner plan` (an ssh session that ended) sends its SIGHUP: the command
    ends as Ctrl-C ends it, exit 130, no result written and no race arm left running. (It died of the signal, and
    `view`'s meshcat server outlived it; with SIGHUP taken, the "interrupted" line's write to the closed terminal
    failed with EIO and the command exited 1.)"""
    import pty
    import signal
    import time

    out = tmp_path / "out"
    pid, fd = pty.fork()
    if pid == 0:  # the command, on the terminal's other end, its session's leader
        os.environ["OMP_NUM_THREADS"] = "1"
        signal.signal(signal.SIGHUP, signal.SIG_DFL)  # as a terminal's shell starts it (the suite may run under nohup)
        os.execv(sys.executable, [sys.executable, "-m", "planner.cli", "plan", "capler", "--out", str(out),
                                  "--no-validate"])
    arms, status = [], None
    try:
        deadline = time.time() + SOLVE_START_S
        # the two arms, forked from the command, have its command line (a helper's, as the glfw probe that `import
        # mujoco` starts, has not: hanging up then tested no race)
        while len(arms) < 2 and time.time() < deadline:
            time.sleep(0.2)
            arms = [c for c in _children(pid) if _cmdline(c) == _cmdline(pid)]
        assert len(arms) == 2, "the race's arms never started"
        os.close(fd)  # the hang-up
        fd = None
        deadline = time.time() + HANGUP_EXIT_S
        while status is None and time.time() < deadline:
            done, code = os.waitpid(pid, os.WNOHANG)
            status = os.waitstatus_to_exitcode(code) if done else time.sleep(0.1)
        assert status == 130
        assert not out.exists()
        while any(_running(arm) for arm in arms) and time.time() < deadline:
            time.sleep(0.1)
        assert not any(_running(arm) for arm in arms)
    finally:
        if fd is not None:
            os.close(fd)
        for child in [pid] * (status is None) + arms:  # a failed check leaves nothing running
            if _running(child):
                os.kill(child, signal.SIGKILL)
        if status is None:
            os.waitpid(pid, 0)


def _children(pid: int) -> list[int]:
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as f:
            return [int(c) for c in f.read().split()]
    except OSError:
        return []


def _cmdline(pid: int) -> bytes:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read()
    except OSError:
        return b""


def _running(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.parametrize("stop", ["SIGTERM", "SIGHUP"])
def test_the_plotting_process_finishes_its_plots_through_a_sigterm(tmp_path, monkeypatch, stop):
    """The child that draws a result's plots while the parent validates ignores SIGTERM and SIGHUP as it ignores Ctrl-C:
    `timeout` and a closed terminal signal the whole process group, and the child died with part of the plots written
    and a temporary file left (the parent, which handles them as Ctrl-C, waits for the plots)."""
    import multiprocessing
    import os
    import signal

    import planner.cli as cli

    sig = getattr(signal, stop)

    def draw(target):
        os.kill(os.getpid(), sig)
        return "drawn whole"

    monkeypatch.setattr(cli, "_draw", draw)
    reader, writer = multiprocessing.Pipe(duplex=False)

    def unhandled(signum, frame):  # (the default would end the test run itself)
        raise AssertionError(f"the plotting process took the {stop}")

    signal.signal(sig, unhandled)  # (conftest restores the handlers: _draw_into ignores all three stop signals)
    cli._draw_into(tmp_path, writer)
    assert reader.recv() == ("drawn", "drawn whole")


def test_a_ctrl_c_a_library_swallowed_still_ends_in_exit_130(tmp_path, capsys, monkeypatch, ctrl_c):
    """A Ctrl-C whose KeyboardInterrupt a library catches (CasADi's callbacks swallowed some: the simulation ran to its
    end and exited 0) is still an interruption once the command returns: exit 130 and one line. The handler that
    notes it is Python's own again afterwards. `view`, whose server ends by Ctrl-C, keeps its exit 0."""
    import os
    import signal

    import planner.cli as cli

    def swallowed(args):
        try:
            os.kill(os.getpid(), signal.SIGINT)
        except KeyboardInterrupt:
            pass
        return cli.EXIT_OK

    monkeypatch.setattr(cli, "_cmd_simulate", swallowed)
    assert main(["simulate", "point_mass", "--out", str(tmp_path / "out")]) == 130
    assert capsys.readouterr().err.strip() == "planner simulate: interrupted"
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    monkeypatch.setattr(cli, "_cmd_view", swallowed)  # view's server ends by Ctrl-C: that is its exit 0
    assert main(["view", str(tmp_path)]) == 0 and capsys.readouterr().err == ""


def test_version_is_printed_by_the_command_and_python_m_planner():
    """`planner --version` and `python -m planner --version` print the installed package's version, exit 0 (the
    first was a usage error, the second "No module named planner.__main__")."""
    from importlib.metadata import version

    with pytest.raises(SystemExit) as done:
        main(["--version"])
    assert done.value.code == 0
    proc = subprocess.run([sys.executable, "-m", "planner", "--version"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and proc.stdout.strip() == f"planner {version('planner')}", proc.stderr


def test_an_unexpected_error_is_placed_at_the_planners_own_line():
    """The one line of an unexpected error names the innermost frame of the planner's code, not the library's where it
    was raised (a singular matrix named numpy's _linalg.py, session 57's reviewer)."""
    from pathlib import Path

    import numpy as np

    import planner.cli

    namespace = {"np": np}
    fake = str(Path(planner.cli.__file__).parent / "plots_fake.py")  # a frame of the package's own code
    exec(compile("def draw():\n    return np.linalg.inv(np.zeros((2, 2)))\n", fake, "exec"), namespace)
    try:
        namespace["draw"]()
    except np.linalg.LinAlgError as exc:
        line = planner.cli._unexpected(exc)
    assert line == "LinAlgError: Singular matrix (raised at plots_fake.py:2 in draw)", line


def test_the_top_level_help_says_the_whole_description(capsys):
    """`planner --help` shows the module docstring's first paragraph whole: its first line only cut the sentence at
    "(or the name" (session 57's tester)."""
    with pytest.raises(SystemExit) as done:
        main(["--help"])
    assert done.value.code == 0
    assert "take a robot file (or the name of one in robots/), validate and view a result directory." in \
        " ".join(capsys.readouterr().out.split())


def test_a_path_the_terminal_cannot_encode_is_escaped(tmp_path):
    """With stdout in ASCII (PYTHONIOENCODING=ascii, output piped) a result directory named with a "ü" is printed
    escaped and the converged simulation exits 0: it printed a UnicodeEncodeError traceback after writing the
    results, exit 1 (session 59's tester)."""
    out = tmp_path / "sim_ü"
    proc = subprocess.run([sys.executable, "-m", "planner.cli", "simulate", "point_mass", "--out", str(out)],
                          capture_output=True, timeout=120, env={**os.environ, "PYTHONIOENCODING": "ascii"})
    assert proc.returncode == 0, proc.stderr.decode()
    assert f"converged: results in {tmp_path}/sim_\\xfc".encode() in proc.stdout and b"Traceback" not in proc.stderr
    assert (out / "summary.json").is_file()


def test_the_cli_leaves_the_callers_stdout_as_it_was(capsys):
    """main() run in-process does not change the caller's sys.stdout (it had set its errors handler for good)."""
    errors = sys.stdout.errors
    assert main(["check-model", "point_mass", "-q"]) == 0
    assert sys.stdout.errors == errors


def test_the_planners_warnings_stay_warnings_under_an_error_filter(tmp_path, capsys):
    """A process whose warnings filter turns warnings into errors (PYTHONWARNINGS=error) still gets the planner's input
    warnings as one "warning:" line and the command's own outcome: the ground-plane warning was a traceback, exit 1."""
    task = tmp_path / "gh.toml"
    task.write_text("ground_height = 0.1\n" + (ROBOTS_DIR / "point_mass.toml").read_text())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # (PYTHONWARNINGS=ignore: silent, as it was before errors were handled)
        assert main(["simulate", "point_mass", "--task", str(task), "--out", str(tmp_path / "o"), "-q"]) == 0
    assert "warning" not in capsys.readouterr().err
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert main(["simulate", "point_mass", "--task", str(task), "--out", str(tmp_path / "o"), "-q"]) == 0
    line = "planner simulate: warning: the robot file's ground plane (geom 'ground') is at z = 0 m"
    assert line in capsys.readouterr().err


def test_a_deleted_working_directory_is_said(tmp_path, capsys, monkeypatch):
    """A command run from a directory deleted meanwhile (`cd gone; rmdir ../gone`) is told so, exit 2: it said
    "failed: No such file or directory", exit 1, naming nothing."""
    gone = tmp_path / "gone"
    gone.mkdir()
    monkeypatch.chdir(gone)
    gone.rmdir()
    assert main(["plan", "point_mass", "--task", "point_mass_hop", "--no-validate", "--no-race", "-q"]) == 2
    assert capsys.readouterr().err.strip() == ("planner plan: error: the working directory no longer exists; change to "
                                               "one that does")


def test_validating_a_plan_without_its_task_json_says_the_task_file_is_read_as_it_is(tmp_path, capsys):
    """A plan written before trajectory.npz kept its task (task_json) is validated against its task file as it is now:
    `planner validate` says so in a note (an edited task file had changed the verdict unsaid); a plan with its
    task_json gets no note."""
    out = tmp_path / "hop"
    hop = str(ROBOTS_DIR / "point_mass_hop.toml")
    assert main(["plan", "point_mass", "--task", hop, "--out", str(out), "--no-validate", "--no-plots", "--no-race",
                 "-q"]) == 0
    assert main(["validate", str(out)]) == 0
    assert "task_json" not in capsys.readouterr().err
    with np.load(out / "trajectory.npz") as npz:
        arrays = {k: v for k, v in npz.items() if k != "task_json"}
    np.savez(out / "trajectory.npz", **arrays)
    assert main(["validate", str(out)]) == 0
    assert (f"note: {out / 'trajectory.npz'} has no task_json (an older planner's plan): its task is read from the "
            "task file as it is now, and an edit since or the plan's --steps is not seen") in capsys.readouterr().err
    (out / "trajectory.npz").write_bytes(b"")  # (the note's reading of it was a traceback, the review)
    assert main(["validate", str(out)]) == 2
    assert "trajectory.npz is not a readable .npz file: it is no zip archive" in capsys.readouterr().err


def test_a_periodic_plans_report_calls_its_residual_periodicity(tmp_path, capsys):
    """A periodic plan's headline calls its terminal rows' residual the periodicity error (they are
    q(tau_f) = S q(0) + step e_along and v(tau_f) = S v(0); it read "terminal error" of a task without a target)."""
    task = tmp_path / "cycle.toml"
    task.write_text(HOP_TOML.format(x=0.4).replace("target_q = [0.4, 0.0]\n", "")
                    + '[plan.periodic]\nstep = 0.4\nfixed = ["x", "z"]\n')
    assert main(["plan", "point_mass", "--task", str(task), "--out", str(tmp_path / "o"), "--no-validate",
                 "--no-plots", "--no-race"]) == 0
    headline = capsys.readouterr().out.splitlines()[0]
    assert ", periodicity error " in headline and "terminal error" not in headline, headline


def test_a_failed_replan_of_the_starts_own_task_says_nothing_changed():
    """A replan whose task is the start's own (replan.SAME_TASK in its no_walk) that did not converge says that the
    start's plan stands, not that the change may be too large for that start (the task's was none; a Capler plan at
    N = 25 whose re-optimization had hit its cap failed so); another failed replan keeps the old line."""
    from types import SimpleNamespace

    from planner.cli import _replan_failed
    from planner.replan import SAME_TASK

    same = SimpleNamespace(extra={"no_walk": f"no walk from the start's task: {SAME_TASK}; the penalty replan instead"})
    assert _replan_failed("results/c", same) == ("the replan of results/c's own task did not converge from its plan "
                                                 "(the task is unchanged); that plan stands in results/c")
    assert "may be too large for that start" in _replan_failed("results/c", SimpleNamespace(extra={}))


def test_a_plans_recorded_solve_options_fed_back_through_solve_plan_it_again(tmp_path):
    """summary.json's options.solve given back to --solve plans the same again, a plan's and a replan's (with --init):
    the fields the flags own (keep_schedule, schedule_only, schedule_new_impacts, fesd_start) and, with --init, those
    replan_options sets are refused only when they differ from what the flags and the replan set (the recorded
    values were refused, though the Python API took them)."""
    import json

    task = tmp_path / "hop.toml"
    task.write_text(HOP_TASK)
    common = ["--task", str(task), "--no-validate", "--no-plots", "-q"]
    for run, extra in (("a", ["--no-race"]), ("r", ["--init", str(tmp_path / "a")])):
        assert main(["plan", "point_mass", "--out", str(tmp_path / run), *common, *extra]) == 0
        first = json.loads((tmp_path / run / "summary.json").read_text())
        solve = json.dumps(first["options"]["solve"])
        assert main(["plan", "point_mass", "--out", str(tmp_path / f"{run}2"), *common, *extra, "--solve", solve]) == 0
        again = json.loads((tmp_path / f"{run}2" / "summary.json").read_text())
        assert again["options"]["solve"] == first["options"]["solve"]
        assert (again["ipopt_iterations"], again["control_cost"]) == (first["ipopt_iterations"], first["control_cost"])
    # one replan field alone at the replan's own value (its mu_init was read on the adaptive barrier and refused)
    own = json.dumps({"mu_init": first["options"]["solve"]["mu_init"]})
    assert main(["plan", "point_mass", "--out", str(tmp_path / "r3"), *common, "--init", str(tmp_path / "a"),
                 "--solve", own]) == 0


def test_a_second_ctrl_c_while_the_interruption_is_reported_is_ignored(tmp_path, capsys, monkeypatch, ctrl_c):
    """A second Ctrl-C while the first is reported (a double press, 10-80 ms apart) does not interrupt the report: it
    printed a traceback from inside it (the lazy import of _written_line). The command ends with exit 130 and its one
    line, and Python's handler is back afterwards."""
    import os
    import signal

    from planner import cli

    def interrupted(args):
        raise KeyboardInterrupt

    reported = cli._written_line

    def pressed_again(args):
        os.kill(os.getpid(), signal.SIGINT)
        reported(args)

    monkeypatch.setattr(cli, "_cmd_plan", interrupted)
    monkeypatch.setattr(cli, "_written_line", pressed_again)
    try:
        code = main(["plan", "point_mass", "--out", str(tmp_path / "o")])
    except KeyboardInterrupt:  # (raised out of main, it would end the whole test session)
        pytest.fail("the second Ctrl-C interrupted the report")
    assert code == 130
    assert capsys.readouterr().err.strip() == "planner plan: interrupted"
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_with_stderr_closed_a_json_error_is_the_only_thing_on_stdout(tmp_path):
    """With stderr closed (`2>&-`) an input error's line is dropped, not printed on stdout before --json's object
    (print(file=None) writes to stdout): stdout is one JSON object, exit 2."""
    import os

    proc = subprocess.run([sys.executable, "-m", "planner.cli", "check-model", str(tmp_path / "missing.xml"), "--json"],
                          stdout=subprocess.PIPE, text=True, preexec_fn=lambda: os.close(2), timeout=120)
    assert proc.returncode == 2
    record = json.loads(proc.stdout)
    assert record["exit_code"] == 2 and "missing.xml" in record["error"]


def test_with_stderr_closed_a_quiet_failure_line_is_not_printed_on_stdout(tmp_path, capsys, monkeypatch):
    """-q's failure line (exit 1) goes to stderr only: with stderr closed (`2>&-`, sys.stderr None) it was printed on
    stdout after --json's object, which then no longer parsed."""
    from planner import cli

    monkeypatch.setattr(cli, "_cmd_plan", lambda args: cli.EXIT_FAILED)
    monkeypatch.setattr(sys, "stderr", None)
    assert main(["plan", "point_mass", "-q", "--json", "--out", str(tmp_path / "o")]) == cli.EXIT_FAILED
    monkeypatch.undo()
    assert capsys.readouterr().out == ""


def test_downloaded_files_cannot_forge_lines_block_or_write_elsewhere(tmp_path, capsys):
    """Hostile names and result directories (session 63's tester): a robot file named with a newline and escape
    sequences is named on one line with them escaped (it forged a second "planner ..." line and set the terminal's
    title); `validate` of a directory whose trajectory.npz is a FIFO ends in one line (it blocked forever); `validate`
    of a directory whose summary.json links to another directory's writes the verdict into its own summary.json (it
    rewrote the link's target)."""
    import os

    odd = tmp_path / "r\x1b]0;TITLE\x07\x1b[31mRED\nplanner plan: converged.xml"
    odd.write_text("<mujoco>")
    assert main(["check-model", str(odd)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "\x1b" not in err
    assert "\\x1b]0;TITLE\\x07\\x1b[31mRED\\nplanner" in err
    accented = tmp_path / "robot é\tü.xml"  # printable text prints as itself, a tab too
    accented.write_text("<mujoco>")
    assert main(["check-model", str(accented)]) == 2
    assert str(accented) in capsys.readouterr().err
    from types import SimpleNamespace

    from planner.cli import _progress

    _progress(SimpleNamespace(quiet=False), f"note: {odd}/summary.json has no robot_sha256")  # (validate's note)
    assert "\x1b" not in capsys.readouterr().err
    with pytest.raises(SystemExit) as stopped:  # argparse's line (the usage error raises: exit 2)
        main(["check-model", "--no-such-flag\x1b[31m"])
    assert stopped.value.code == 2 and "\x1b" not in capsys.readouterr().err
    drop = tmp_path / "drop"
    assert main(["simulate", "point_mass", "--task", _task(tmp_path), "--out", str(drop), "-q", "--no-plots"]) == 0
    blocked = tmp_path / "blocked"
    blocked.mkdir()
    (blocked / "summary.json").write_text((drop / "summary.json").read_text())
    os.mkfifo(blocked / "trajectory.npz")
    _one_line_exit_2(capsys, ["validate", str(blocked)], "trajectory.npz")
    linked = tmp_path / "linked"
    linked.mkdir()
    (linked / "trajectory.npz").write_bytes((drop / "trajectory.npz").read_bytes())
    (linked / "summary.json").symlink_to(drop / "summary.json")
    before = (drop / "summary.json").read_text()
    assert main(["validate", str(linked), "-q"]) in (0, 1)
    assert (drop / "summary.json").read_text() == before and not (linked / "summary.json").is_symlink()
    assert "validation" in json.loads((linked / "summary.json").read_text())


def test_a_reports_names_and_paths_cannot_forge_its_lines(tmp_path, capsys):
    """The report on stdout escapes control characters in its lines and in the paths the CLI adds (results in DIR,
    view's "wrote PAGE"), as the stderr lines do: an --out path with a newline and "converged: fake" printed that as a
    line of its own (session 64's tester and reviewer)."""
    out = tmp_path / "out\nconverged: fake\x1b[31m"
    assert main(["simulate", "point_mass", "--task", _task(tmp_path), "--out", str(out), "--no-plots"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert not any(line.startswith("converged: fake") for line in lines) and "\x1b" not in "".join(lines)
    assert any("out\\nconverged: fake\\x1b[31m" in line for line in lines), lines
    assert main(["view", str(out), "--html", str(tmp_path / "p\nconverged: fake.html")]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 1 and lines[0].startswith("wrote ") and lines[0].endswith("p\\nconverged: fake.html"), lines


DROP_TASK = """
[[contacts]]
point = "point"
[initial]
q = [0.0, 0.2]
[horizon]
tau_f = 0.1
N = 5
"""


def test_validate_q_says_why_the_validation_failed(tmp_path, capsys, monkeypatch):
    """`planner validate DIR -q` of a failing validation prints one failure line with the validation's own reasons
    (_failure reads them: "planner validate: failed: stubbed"), not "did not converge": validate's summary has no
    `converged`, and the result it judged did converge."""
    import dataclasses

    import planner.replay
    from planner.cli import main

    task, drop = tmp_path / "drop.toml", tmp_path / "drop"
    task.write_text(DROP_TASK)
    assert main(["simulate", "point_mass", "--task", str(task), "--out", str(drop), "--no-plots", "-q"]) == 0
    real_validate = planner.replay.validate
    monkeypatch.setattr(planner.replay, "validate", lambda *a, **k: dataclasses.replace(
        real_validate(*a, **k), passed=False, failures=("stubbed",)))
    capsys.readouterr()
    assert main(["validate", str(drop), "-q"]) == 1
    out, err = capsys.readouterr()
    assert out == "" and err.strip().splitlines()[-1] == "planner validate: failed: stubbed"


def test_the_walks_start_task_of_an_older_plan_takes_the_steps_flag(tmp_path):
    """A plan written before trajectory.npz kept its task (no task_json) is walked from its summary.json's task file,
    with --steps as given now (cli._start_task): --init accepts only a start on the same grid (read_start), so the plan
    solved N = --steps, not the file's N; a start task of the file's N = 10 against the new task's 8 was refused as
    "the two tasks differ in 'horizon.N'", and the replan lost its walk."""
    from planner.cli import _start_task
    from planner.task import load_task

    task_file = ROBOTS_DIR / "point_mass_hop.toml"
    assert load_task(task_file).horizon.N != 8
    (tmp_path / "summary.json").write_text(json.dumps({"command": "plan", "task": str(task_file)}))
    args = SimpleNamespace(init=tmp_path, steps=8, quiet=True)
    assert _start_task(args, {}).horizon.N == 8
    assert _start_task(SimpleNamespace(init=tmp_path, steps=None, quiet=True), {}) == load_task(task_file)


def test_a_stop_after_the_json_summary_adds_no_second_object():
    """With --json, stdout holds one JSON object: a command stopped after its summary was printed (a Ctrl-C raised on
    leaving the solve, once the summary is out) says so on stderr only (_stop: "unless the summary is there
    already"); stopped before it, its stdout gets the {"command", "exit_code", "error"} object."""
    import io
    import json

    from planner.cli import _stop

    for printed in (True, False):
        args = SimpleNamespace(command="plan", json=True, stdout=io.StringIO(), stderr=io.StringIO())
        if printed:
            args.summary = {"command": "plan", "converged": True}
        assert _stop(args, 130, "interrupted") == 130
        assert args.stderr.getvalue() == "planner plan: interrupted\n"
        lines = args.stdout.getvalue().splitlines()
        assert lines == ([] if printed else [json.dumps({"command": "plan", "exit_code": 130, "error": "interrupted"})])
