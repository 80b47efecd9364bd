"""Shared fixtures: the example-robot-data robots folder and a loader for its robots; the stop signals' handlers
restored after each test."""
from __future__ import annotations

import functools
import importlib.metadata
import signal
from pathlib import Path

import pytest

from planner.errors import STOP_SIGNALS
from planner.model import Robot, load_robot


@pytest.fixture(autouse=True)
def _stop_signals_restored():
    """Each test leaves SIGINT, SIGTERM and SIGHUP as it found them: code under test ignores them (the plotting child,
    an interruption's report), and a test that left SIGTERM ignored hung a later one for good (Pool.terminate's
    SIGTERM could not stop its worker; session 67's CI)."""
    handlers = {s: signal.getsignal(s) for s in STOP_SIGNALS}
    yield
    for s, handler in handlers.items():
        signal.signal(s, handler if handler is not None else signal.SIG_DFL)


@functools.cache
def erd_robots_dir() -> Path:
    """example-robot-data's `robots/` folder inside the installed distribution (it has no Python loader)."""
    dist = importlib.metadata.distribution("example-robot-data")
    return Path(dist.locate_file("cmeel.prefix/share/example-robot-data/robots"))


# name -> (file under robots/, floating base): URDFs have no free joint, Pinocchio adds the free flyer
ERD_ROBOTS = {
    "ur5": ("ur_description/urdf/ur5_robot.urdf", False),
    "panda": ("panda_description/urdf/panda.urdf", False),
    "solo12": ("solo_description/robots/solo12.urdf", True),
    "bolt": ("bolt_description/robots/bolt.urdf", True),
    "talos": ("talos_data/robots/talos_reduced.urdf", True),
}


@functools.cache
def _load_erd(name: str) -> Robot:
    path, floating = ERD_ROBOTS[name]
    file = erd_robots_dir() / path
    if not file.is_file():
        pytest.skip(f"example-robot-data has no {path}")
    return load_robot(file, floating=floating)


@pytest.fixture(scope="session")
def robots_dir() -> Path:
    """example-robot-data's `robots/` folder."""
    return erd_robots_dir()


@pytest.fixture(scope="session")
def erd_robot():
    """erd_robot(name) -> Robot: an example-robot-data robot by short name (see ERD_ROBOTS), loaded once."""
    return _load_erd


@pytest.fixture
def robot_variant(tmp_path):
    """robot_variant(text, old, new, name="variant.xml") -> Robot: a robot file's text with its one `old` replaced by
    `new`, written under tmp_path and loaded (a test's variant of a shipped robot: its gravity, a motor, a joint)."""
    def make(text: str, old: str, new: str, name: str = "variant.xml") -> Robot:
        assert text.count(old) == 1, old
        path = tmp_path / name
        path.write_text(text.replace(old, new))
        return load_robot(path)

    return make
