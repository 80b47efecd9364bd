"""The command line: exit codes, one-line errors with no traceback, and the JSON contract."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from planner.cli import main


def run(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "planner.cli", *argv], capture_output=True, text=True, timeout=120)


def test_check_model_json_contract():
    """`check-model --json` prints one JSON object with the contract's keys and exits 0 on a good model."""
    proc = run("check-model", "capler", "--json", "--samples", "3")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    for key in ("robot", "format", "nq", "nv", "backend", "max_err_mass", "max_err_bias", "max_err_frames",
                "max_err_jacobians", "mujoco", "passed"):
        assert key in summary
    assert summary["passed"] and summary["mujoco"]["max_err_mass"] < 1e-9


@pytest.mark.parametrize(
    "argv, fragment",
    [
        (["check-model", "/nonexistent/robot.xml"], "robot file not found"),
        (["check-model", "capler", "--samples", "0"], "--samples must be >= 1"),
        (["check-model"], "the following arguments are required: robot"),
        (["fly", "capler"], "invalid choice: 'fly'"),
    ],
)
def test_user_errors_are_one_line_exit_2(argv, fragment, capsys):
    """A user error prints exactly one line on stderr, no traceback, and exits 2."""
    with pytest.raises(SystemExit) as exit_info:
        code = main(argv)
        raise SystemExit(code)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert fragment in err and len(err.splitlines()) == 1 and "Traceback" not in err


def test_malformed_xml_from_a_subprocess(tmp_path):
    """Malformed XML through the real console entry: exit 2, one line, nothing on stdout."""
    bad = tmp_path / "bad.xml"
    bad.write_text("<mujoco><worldbody>")
    proc = run("check-model", str(bad), "--json")
    assert proc.returncode == 2 and proc.stdout == ""
    assert len(proc.stderr.strip().splitlines()) == 1 and "malformed XML" in proc.stderr
