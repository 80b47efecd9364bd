"""Robot-file loading: actuators, limits, named points, gravity and name resolution."""
from __future__ import annotations

import numpy as np
import pytest

from planner.dynamics import Dynamics
from planner.errors import RobotFileError, UnknownNameError
from planner.model import RobotFormat, load_robot

EXACT = 1e-12  # parsed numbers are copied, not computed


def test_capler_actuators_and_limits():
    """MJCF motors (from MuJoCo's compile) and URDF effort limits give the same B, bounds and limits."""
    mjcf, urdf = load_robot("capler"), load_robot("robots/capler.urdf")
    assert mjcf.format is RobotFormat.MJCF and urdf.format is RobotFormat.URDF
    for robot in (mjcf, urdf):
        assert robot.dof_names == ("base_x", "base_z", "hip", "knee")
        np.testing.assert_array_equal(robot.actuation_matrix, [[0, 0], [0, 0], [1, 0], [0, 1]])
        np.testing.assert_array_equal(robot.u_upper, [60, 60])
        np.testing.assert_allclose(robot.q_upper[2:], [3 * np.pi / 8, np.pi / 2], atol=EXACT)
        assert {"foot", "knee"} <= set(robot.points)


def test_mjcf_gravity_is_read(tmp_path):
    """<option gravity> reaches the dynamics (Pinocchio's MJCF parser alone ignores it)."""
    xml = (tmp_path / "drop.xml")
    xml.write_text('<mujoco><option gravity="0 0 -5"/><worldbody><body name="b"><joint type="slide" axis="0 0 1"/>'
                   '<inertial pos="0 0 0" mass="2" diaginertia="1 1 1"/></body></worldbody></mujoco>')
    bias = Dynamics(load_robot(xml)).bias([0.0], [0.0])
    assert float(bias) == pytest.approx(10.0, abs=EXACT)


def test_bare_name_resolves_to_robots_dir():
    """`capler` names robots/capler.xml; an unknown bare name lists the robots that exist."""
    assert load_robot("capler").path.name == "capler.xml"
    with pytest.raises(RobotFileError, match="biped, capler, point_mass"):
        load_robot("no_such_robot")


def test_unknown_joint_lists_names():
    """An unknown joint name raises UnknownNameError listing the robot's joints."""
    with pytest.raises(UnknownNameError, match="base_x, base_z, hip, knee"):
        load_robot("capler").dof_index("ankle")
