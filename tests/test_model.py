"""Robot-file loading: actuators, limits, named points, gravity and name resolution."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from planner.dynamics import Dynamics
from planner.errors import InputError, PlannerError, RobotFileError, UnknownNameError
from planner.model import ROBOTS_DIR, RobotFormat, load_robot

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


def test_the_robots_ship_inside_the_package():
    """Every file of robots/ is package data of `planner.robots` (the package robots/ is mapped to), so a wheel (a
    non-editable install) holds them and robot names work there: the wheel held planner/*.py only, and `planner plan
    capler` was refused with an empty list of robots (session 56's tester)."""
    import fnmatch
    import tomllib

    setup = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert "planner.robots" in setup["packages"] and setup["package-dir"]["planner.robots"] == "robots"
    patterns = setup["package-data"]["planner.robots"]
    files = [f.name for f in ROBOTS_DIR.iterdir() if f.is_file()]
    assert "capler.xml" in files and all(any(fnmatch.fnmatch(f, pat) for pat in patterns) for f in files), files


def test_the_dependency_ranges_start_where_they_install():
    """pyproject's lower bounds are versions that install and import together on Python 3.11 (session 59's tester):
    no pin 3.x imports after pip's install (its urdfdom and tinyxml2 libraries), and pin 3.4-3.7 skip an MJCF site of a
    jointless body; every pin in range needs numpy 2, which scipy < 1.13 and matplotlib < 3.8.4 refuse."""
    import tomllib

    from packaging.requirements import Requirement
    from packaging.version import Version

    project = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())["project"]
    lowest = {}
    for line in project["dependencies"]:
        req = Requirement(line)
        lowest[req.name] = min((Version(s.version) for s in req.specifier if s.operator == ">="), default=None)
    floor = {"pin": "4.0", "numpy": "2.0", "scipy": "1.13", "matplotlib": "3.8.4"}
    assert all(lowest[name] >= Version(v) for name, v in floor.items()), lowest


def test_check_inertia_refuses_a_q_of_another_length():
    """Robot.check_inertia with a q of another length than nq is an InputError naming the shape (Pinocchio's
    ValueError)."""
    with pytest.raises(InputError, match=r"check_inertia's q must have shape \(2,\) for 'point_mass', got \(5,\)"):
        load_robot("point_mass").check_inertia(np.zeros(5))
    with pytest.raises(InputError, match=r"check_inertia's q must have shape \(2,\)"):  # (numpy's ValueError)
        load_robot("point_mass").check_inertia("ab")


def test_the_package_says_it_is_typed():
    """planner ships a PEP 561 py.typed marker as package data, so a user's type checker reads the package's
    annotations ("missing library stubs or py.typed marker" for every import of planner, session 59's tester)."""
    import tomllib

    import planner

    setup = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert "py.typed" in setup["package-data"]["planner"]
    assert (Path(planner.__file__).parent / "py.typed").is_file()


def test_an_install_without_robot_files_says_so(tmp_path, monkeypatch):
    """A bare robot name where the install has no robot files says where it looked and to give a path (it listed
    no robots after "one of robots/:")."""
    import planner.model

    monkeypatch.setattr(planner.model, "ROBOTS_DIR", tmp_path)
    monkeypatch.chdir(tmp_path)
    with pytest.raises(RobotFileError, match=r"robot 'capler' is not a file, and this install has no robot files in "
                                             r".*; give a robot file's path$"):
        load_robot("capler")


def test_a_file_of_a_robots_name_in_the_working_directory_is_read_and_said_so(tmp_path, monkeypatch):
    """A file named `capler` in the working directory is the robot `capler` (an existing path wins); when it is not a
    robot file it can read (notes; an MJCF file, which MuJoCo reads only as .xml), the error says that it hid
    robots/capler (a stray notes file made `plan capler` a bare parse error)."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "capler").write_text("notes")
    with pytest.raises(RobotFileError, match=r"malformed XML .*the file 'capler' in the working directory is read, "
                                             r"not robots/capler; to use that one, give its path"):
        load_robot("capler")
    (tmp_path / "capler").write_text((ROBOTS_DIR / "capler.xml").read_text())  # MJCF, refused without .xml (MuJoCo)
    with pytest.raises(RobotFileError, match=r"capler is MJCF, .*rename it to capler.xml \(the file 'capler' in the "
                                             r"working directory is read, not robots/capler"):
        load_robot("capler")
    (tmp_path / "capler").write_text((ROBOTS_DIR / "capler.urdf").read_text())  # a URDF reads under any name
    assert load_robot("capler").path == tmp_path / "capler"


def test_unknown_joint_lists_names():
    """An unknown joint name raises UnknownNameError listing the robot's joints."""
    with pytest.raises(UnknownNameError, match="base_x, base_z, hip, knee"):
        load_robot("capler").dof_index("ankle")


def _hopper(tmp_path, hip: str = "", actuator: str = '<motor name="m" joint="hip" ctrlrange="-20 20"/>', extra: str = "",
            foot: str = '<site name="foot" pos="0 0 -0.3"/>', base: str = 'axis="0 0 1"'):
    """A planar hopper (slide x, z; hinge hip about y) with the given hip attributes, actuator and extra sections."""
    path = tmp_path / "hopper.xml"
    path.write_text(f"""<mujoco><compiler angle="radian"/><worldbody><body name="base"><joint name="x" type="slide" axis="1 0 0"/>
<joint name="z" type="slide" {base}/><inertial pos="0 0 0" mass="2" diaginertia="0.01 0.01 0.01"/>
<body name="leg"><joint name="hip" type="hinge" axis="0 1 0" range="-1 1" {hip}/>
<inertial pos="0 0 -0.15" mass="0.5" diaginertia="0.004 0.004 0.004"/>{foot}</body></body></worldbody>
<actuator>{actuator}</actuator>{extra}</mujoco>""")
    return path


@pytest.mark.parametrize("actuator", ['<position name="p" joint="hip" kp="100" ctrlrange="-1 1"/>',
                                      '<velocity name="v" joint="hip" kv="10"/>',
                                      '<general name="g" joint="hip" gainprm="7"/>'])
def test_servo_actuators_are_refused(tmp_path, actuator):
    """Position, velocity and general actuators are no plain motors (force = gear * ctrl): refused, named, instead of
    being read as a 1 N m motor."""
    with pytest.raises(RobotFileError, match="is not a plain motor"):
        load_robot(_hopper(tmp_path, actuator=actuator))


@pytest.mark.parametrize("actuator, message", [
    ('<motor name="m" joint="hip" gear="0" ctrlrange="-20 20"/>', "'m' has gear 0"),  # simulate divided by it
    ('<motor name="m" joint="hip" ctrlrange="20 -20"/>', "ctrlrange 20 -20 is no limit to MuJoCo"),  # MuJoCo: unlimited
    ('<motor name="m" joint="hip" forcerange="5 -5"/>', "forcerange 5 -5 is no limit"),
    ('<motor name="m" joint="hip" ctrlrange="5 5"/>', "ctrlrange 5 5 is no limit")])
def test_motors_that_do_nothing_or_lost_their_limit_are_refused(tmp_path, actuator, message):
    """A motor of gear 0 exerts no force, and a reversed range is no limit to MuJoCo (a sign typo removed the torque
    bound): refused, naming the actuator and the value."""
    with pytest.raises(RobotFileError, match=message):
        load_robot(_hopper(tmp_path, actuator=actuator))


@pytest.mark.parametrize("attributes, message", [
    ('ctrllimited="false" ctrlrange="-30 30"', r'ctrlrange -30 30 is no limit to MuJoCo \(ctrllimited="false"\); '
                                               r'remove ctrllimited="false" \(or its default class\'s\), or the '
                                               r'range$'),
    ('forcelimited="false" forcerange="-5 5"', r'forcerange -5 5 is no limit to MuJoCo \(forcelimited="false"\); '
                                               r'remove forcelimited="false"'),
    ('ctrlrange="20 -20"', r"ctrlrange 20 -20 is no limit to MuJoCo \(lower not below upper\); write the lower "
                           r"bound first, or remove the range$")])
def test_a_range_declared_unlimited_is_told_the_fix_that_applies(tmp_path, attributes, message):
    """A motor whose range is ordered but declared ctrllimited/forcelimited="false" is told to remove that attribute
    (or the range), and a reversed range to write its lower bound first: the declared one was told to "write the lower
    bound first" though it was, a fix that changes nothing."""
    with pytest.raises(RobotFileError, match=message):
        load_robot(_hopper(tmp_path, actuator=f'<motor name="m" joint="hip" {attributes}/>'))


@pytest.mark.parametrize("text, name", [
    ('<mujoco><worldbody><body name="b"><inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/><site name="s"/></body>'
     '</worldbody></mujoco>', "ball.xml"),
    ('<robot name="r"><link name="b"><inertial><mass value="1"/><inertia ixx="1" iyy="1" izz="1" ixy="0" ixz="0" '
     'iyz="0"/></inertial></link></robot>', "ball.urdf")])
def test_a_robot_without_degrees_of_freedom_is_refused(tmp_path, text, name):
    """A robot file without joints is refused when read (check-model crashed in Pinocchio, simulate in CasADi)."""
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(RobotFileError, match="no degrees of freedom"):
        load_robot(path)


def test_a_second_body_tree_in_the_worldbody_is_named(tmp_path):
    """Pinocchio's MJCF parser reads the first body of <worldbody> only: a marker body before the robot (read as a
    robot "without joints") and a second moving body after it (blamed on a <frame>) are refused naming the bodies and
    the fix; a scenery body without joints after the robot is still read."""
    robot = (ROBOTS_DIR / "point_mass.xml").read_text()
    marker, cart = ('<body name="marker" pos="0.5 0 0.3"><geom type="sphere" size="0.02"/></body>',
                    '<body name="cart"><joint name="cx" type="slide" axis="1 0 0"/>'
                    '<geom type="sphere" size="0.1"/></body>')
    for name, text, first in (("before.xml", robot.replace("<worldbody>", "<worldbody>" + marker), "'marker': 0 of"),
                              ("after.xml", robot.replace("</worldbody>", cart + "</worldbody>"), "'mass': 2 of")):
        (tmp_path / name).write_text(text)
        with pytest.raises(RobotFileError, match=rf"<worldbody> holds 2 bodies .* reads the first one only \({first} "
                                                 r"MuJoCo's \d degrees of freedom\): a robot is one body tree"):
            load_robot(tmp_path / name)
    (tmp_path / "scenery.xml").write_text(robot.replace("</worldbody>", marker + "</worldbody>"))
    assert load_robot(tmp_path / "scenery.xml").nv == 2


def test_an_include_pinocchio_cannot_read_is_named(tmp_path):
    """An MJCF file whose bodies are in an <include>d file (MuJoCo reads it, Pinocchio's parser not): the error says
    that the include is what Pinocchio does not read, not only Pinocchio's "No such node (body)"."""
    (tmp_path / "body.xml").write_text('<mujoco><body name="b"><joint name="z" type="slide" axis="0 0 1"/>'
                                       '<inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/></body></mujoco>')
    path = tmp_path / "robot.xml"
    path.write_text('<mujoco><worldbody><include file="body.xml"/></worldbody></mujoco>')
    with pytest.raises(RobotFileError, match="includes <body>: Pinocchio's MJCF parser skips <include>s"):
        load_robot(path)


def test_an_included_default_is_named_as_what_pinocchio_cannot_read(tmp_path):
    """An MJCF file that includes only its <default> classes (its bodies in the file, using childclass="leg") is
    refused naming <default> as what the include holds: the error blamed "included bodies" in a file that includes
    none, and the user looked for bodies to move."""
    (tmp_path / "defaults.xml").write_text('<mujocoinclude><default><default class="leg"><joint type="hinge" '
                                           'axis="0 1 0"/></default></default></mujocoinclude>')
    path = tmp_path / "robot.xml"
    path.write_text('<mujoco><include file="defaults.xml"/><worldbody><body name="b" childclass="leg"><joint '
                    'name="hip"/><inertial pos="0 0 -0.1" mass="1" diaginertia="1 1 1"/></body></worldbody></mujoco>')
    with pytest.raises(RobotFileError, match=r"\(the file includes <default>: Pinocchio's MJCF parser skips "
                                             r"<include>s; write them into the file: MuJoCo's "
                                             r"mujoco.MjSpec.from_file\(FILE\).to_xml\(\), saved beside it"):
        load_robot(path)


def test_the_files_limits_are_read_as_mujoco_reads_them(tmp_path):
    """A motor's forcerange bounds its control as MuJoCo clamps it: the motor's force (its ctrl) before the gear, so
    the joint's force saturates at gear times the bound (the bound was forcerange / gear: half the motor on gear 2, and
    a plan above MuJoCo's limit on gear 0.5); a joint declared limited="false" has no position limits though it states
    a range (Pinocchio's parser kept the range); an <equality> is refused."""
    import mujoco

    for gear, hip, motor_range, bounds in ((2.0, "", 'forcerange="-5 5"', (-5.0, 5.0)),
                                           (0.5, "", 'forcerange="-5 5"', (-5.0, 5.0)),
                                           (2.0, 'actuatorfrcrange="-5 5"', "", (-2.5, 2.5))):  # the joint's: / gear
        path = _hopper(tmp_path, hip=hip, actuator=f'<motor name="m" joint="hip" gear="{gear}" {motor_range} '
                                                   'ctrlrange="-20 20"/>')
        motor = load_robot(path).actuators[0]
        mj = mujoco.MjModel.from_xml_path(str(path))
        data = mujoco.MjData(mj)
        for bound in (motor.lower, motor.upper):  # MuJoCo's joint force at the bound and beyond it: gear * bound
            for ctrl in (bound, 2 * bound):
                data.ctrl[0] = ctrl
                mujoco.mj_forward(mj, data)
                dof = mj.jnt_dofadr[mj.actuator_trnid[0, 0]]
                assert data.qfrc_actuator[dof] == pytest.approx(gear * bound, abs=EXACT)
        assert (motor.lower, motor.upper) == bounds
    robot = load_robot(_hopper(tmp_path, hip='limited="false"'))
    assert robot.q_lower[2] == -np.inf and robot.q_upper[2] == np.inf
    assert load_robot(_hopper(tmp_path)).q_upper[2] == 1.0
    with pytest.raises(RobotFileError, match="<equality>"):
        load_robot(_hopper(tmp_path, extra='<equality><joint joint1="hip" joint2="x"/></equality>'))


def test_what_a_parser_prints_is_read_as_bytes():
    """What Pinocchio's parsers print on descriptor 2 is kept for the error message (urdfdom's reason) and read with
    undecodable bytes replaced: a Latin-1 joint name there made a valid file "unparsable" (UnicodeDecodeError)."""
    import os

    from planner.model import _quiet

    printed = []
    with _quiet(printed):
        os.write(2, b"Warning: joint j\xe9 has no limits\n")
    assert printed == ["Warning: joint j\ufffd has no limits\n"]


def test_limits_of_joints_sharing_a_body_are_mujocos(tmp_path):
    """A planar base written as three joints of one body (Pinocchio merges them into one composite joint) gets MuJoCo's
    limits per joint, in the file's units: the slide "z" in metres though the compiler reads angles in degrees (it kept
    Pinocchio's degrees-to-radians reading, [-0.017, 0.035], and the file was refused), a slide declared unlimited
    under a default range none, and a hinge with a ref its range as MuJoCo reads it (Pinocchio's was shifted by ref)."""
    import mujoco

    path = tmp_path / "planar.xml"
    path.write_text('<mujoco><default><joint range="-1 1"/></default><worldbody>'
                    '<geom name="ground" type="plane" size="5 1 0.1"/><body name="base" pos="0 0 0.5">'
                    '<joint name="x" type="slide" axis="1 0 0" limited="false"/>'
                    '<joint name="z" type="slide" axis="0 0 1" range="-1 2"/>'
                    '<joint name="pitch" type="hinge" axis="0 1 0" ref="10" range="-20 40"/>'
                    '<inertial pos="0.1 0 0" mass="3" diaginertia="0.05 0.05 0.05"/><site name="foot" pos="0 0 -0.3"/>'
                    '</body></worldbody></mujoco>')
    robot = load_robot(path)
    mj = mujoco.MjModel.from_xml_path(str(path))
    assert list(robot.q_lower) == [-np.inf, -1.0, mj.jnt_range[2, 0]]
    assert list(robot.q_upper) == [np.inf, 2.0, mj.jnt_range[2, 1]]
    assert mj.jnt_range[2, 1] == pytest.approx(np.radians(40), abs=EXACT)


def test_an_inverted_joint_range_is_refused_and_mujocos_element_named(tmp_path):
    """A joint range with its lower bound above the upper, or equal to it but not MuJoCo's default "0 0" (MuJoCo reads
    both as no limit: a sign typo unbounded the joint silently, or check-model blamed MuJoCo) is refused in MJCF and
    URDF, as an inverted ctrlrange is; MuJoCo's compile error keeps the element it names (the body to fix was
    dropped)."""
    mjcf = tmp_path / "inverted.xml"
    mjcf.write_text('<mujoco><compiler angle="radian"/><worldbody><body name="b"><joint name="hip" type="hinge" '
                    'range="1 -1"/><inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/></body></worldbody></mujoco>')
    with pytest.raises(RobotFileError, match="joint 'hip': its range 1 -1 is no limit to MuJoCo"):
        load_robot(mjcf)
    mjcf.write_text(mjcf.read_text().replace('range="1 -1"', 'range="0.2 0.2"'))  # (it planned as unlimited)
    with pytest.raises(RobotFileError, match="joint 'hip': its range 0.2 0.2 is no limit to MuJoCo"):
        load_robot(mjcf)
    mjcf.write_text(mjcf.read_text().replace('range="0.2 0.2"', 'range="0 0"'))  # MuJoCo's default: no range
    assert load_robot(mjcf).q_upper[0] == np.inf
    urdf = tmp_path / "inverted.urdf"
    urdf.write_text('<robot name="r"><link name="a"/><link name="b"><inertial><mass value="1"/><inertia ixx="1" '
                    'iyy="1" izz="1" ixy="0" ixz="0" iyz="0"/></inertial></link><joint name="hip" type="revolute">'
                    '<parent link="a"/><child link="b"/><axis xyz="0 1 0"/><limit lower="1" upper="-1" effort="5" '
                    'velocity="1"/></joint></robot>')
    with pytest.raises(RobotFileError, match=r"joint 'hip' \(1 > -1\): its <limit lower> is above its upper"):
        load_robot(urdf)
    massless = tmp_path / "massless.xml"
    massless.write_text('<mujoco><worldbody><body name="cx"><joint name="x" type="slide" axis="1 0 0"/><body name="b">'
                        '<joint name="hip" type="hinge"/><inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/></body>'
                        '</body></worldbody></mujoco>')
    with pytest.raises(RobotFileError, match="must be larger than mjMINVAL; Element name 'cx', id 1, line 1"):
        load_robot(massless)


@pytest.mark.parametrize("hip, term", [('damping="5"', "damping 5"), ('stiffness="50"', "stiffness 50"),
                                       ('frictionloss="2"', "frictionloss 2"),
                                       ('damping="0 0.5"', "damping 0 0.5"), ('stiffness="0 5"', "stiffness 0 5"),
                                       ('damping="0.2 0.5 0.1"', "damping 0.2 0.5 0.1")])
def test_passive_joint_forces_are_refused_for_simulation(tmp_path, hip, term):
    """Joint damping, stiffness and friction loss, polynomial ones too (named as the file writes them: "dampingpoly
    0.5 0" named no attribute), are recorded (Robot.passive) and refused by a task's check, which simulate and plan
    run: the planner's dynamics have none, MuJoCo's replay would (the polynomial ones were named by check-model's
    passive gap alone)."""
    from planner.errors import RobotFileError as Refused
    from planner.task import parse_task

    robot = load_robot(_hopper(tmp_path, hip=hip))
    assert robot.passive == (f"joint 'hip': {term}",)
    task = parse_task({"contacts": [{"point": "foot"}], "initial": {"q": [0.0, 0.5, 0.0]}, "horizon": {"tau_f": 0.5, "N": 10}})
    with pytest.raises(Refused, match=re.escape(f"hip': {term}: the planner's dynamics have neither passive joint")):
        task.check_against(robot)


@pytest.mark.parametrize("hip, flag", [('damping="5"', "damper"), ('damping="0 5"', "damper"),
                                       ('stiffness="50"', "spring"), ('frictionloss="2"', "frictionloss")])
def test_passive_forces_the_file_disables_are_none(tmp_path, hip, flag):
    """A passive term whose <flag ...="disable"/> the file sets is no passive force (MuJoCo applies none: they were
    refused, "MuJoCo applies what the planner does not model"), and check-model's passive gap agrees."""
    from planner.check import check_model

    robot = load_robot(_hopper(tmp_path, hip=hip, extra=f'<option><flag {flag}="disable"/></option>'))
    assert robot.passive == ()
    assert check_model(robot, samples=2).passed


def test_a_reversed_actuatorfrcrange_is_named(tmp_path):
    """A joint's actuatorfrcrange written upper bound first fails Pinocchio's parse ("min_effort are greater than
    max_effort", no joint named); the refusal names the joint and says to write the lower bound first, as a reversed
    ctrlrange's does."""
    with pytest.raises(RobotFileError, match=r"min_effort are greater than max_effort \(joint 'hip': "
                                             r"actuatorfrcrange 30 -30 has its lower bound above its upper: write the "
                                             r"lower bound first"):
        load_robot(_hopper(tmp_path, hip='actuatorfrcrange="30 -30"'))


def test_a_site_wins_over_a_body_of_the_same_name_and_planar_contacts_are_checked(tmp_path):
    """A contact point is a site: with a body of the same name the site's frame is used (the body's was). A point
    that can move along y (here a base sliding along y) is refused by the task's check: the contacts are planar."""
    from planner.errors import TaskError
    from planner.task import parse_task

    robot = load_robot(_hopper(tmp_path, foot='<body name="foot" pos="0 0 -0.25"><inertial pos="0 0 0" mass="0.1" '
                                              'diaginertia="1e-4 1e-4 1e-4"/><site name="foot" pos="0 0 -0.05"/></body>'))
    data = robot.model.createData()
    import pinocchio as pin

    pin.framesForwardKinematics(robot.model, data, np.zeros(robot.nq))
    assert data.oMf[robot.frame_id("foot")].translation[2] == pytest.approx(-0.3)
    task = parse_task({"contacts": [{"point": "foot"}], "initial": {"q": [0.0, 0.5, 0.0]}, "horizon": {"tau_f": 0.5, "N": 10}})
    task.check_against(robot)
    sideways = load_robot(_hopper(tmp_path, base='axis="0 1 0"'))
    with pytest.raises(TaskError, match="contact point 'foot' can move along y"):
        task.check_against(sideways)


def test_out_of_plane_rates_name_each_joint_that_moves_a_point_along_y(tmp_path):
    """Robot.out_of_plane_rates gives, per degree of freedom that moves the point along y, its largest |dy/dq| (the
    task's refusal quotes them so the user finds the joint): {} for a planar hopper, and for one whose second base
    slide runs along y that slide alone at 1 m/m (the x slide and the hip about y move the foot in x-z only)."""
    assert load_robot(_hopper(tmp_path)).out_of_plane_rates("foot") == {}
    assert load_robot(_hopper(tmp_path, base='axis="0 1 0"')).out_of_plane_rates("foot") == {"z": 1.0}


def test_an_unnamed_site_is_no_point(tmp_path):
    """A site without a name is no contact point: Pinocchio names it ("massSite_0") and simulate planned on it, then
    validate refused the result (MuJoCo has no site of that name). Named sites stay points."""
    from planner.errors import UnknownNameError
    from planner.task import parse_task

    path = tmp_path / "unnamed.xml"
    path.write_text('<mujoco><worldbody><body name="mass"><joint name="x" type="slide" axis="1 0 0"/>'
                    '<joint name="z" type="slide" axis="0 0 1"/><inertial pos="0 0 0" mass="1" '
                    'diaginertia="0.01 0.01 0.01"/><site pos="0.1 0 0"/><site name="foot"/></body>'
                    '</worldbody></mujoco>')
    robot = load_robot(path)
    assert "massSite_0" in [f.name for f in robot.model.frames]  # (Pinocchio's made-up name, which was offered)
    assert robot.sites == ("foot",) and "massSite_0" not in robot.points
    task = parse_task({"contacts": [{"point": "massSite_0"}], "initial": {"q": [0.0, 0.3]},
                       "horizon": {"tau_f": 0.4, "N": 4}})
    with pytest.raises(UnknownNameError, match="unknown contact point 'massSite_0'; valid contact points: foot"):
        task.check_against(robot)


@pytest.mark.parametrize("name", ["world", "universe"])
def test_a_site_named_world_is_a_point(tmp_path, name):
    """A site of the robot's named "world" or "universe" (MuJoCo takes both) is a contact point at the site: it was
    left out with the universe frame ("valid contact points: (none)", session 64's tester)."""
    path = tmp_path / "site.xml"
    path.write_text('<mujoco><worldbody><body name="mass"><joint name="x" type="slide" axis="1 0 0"/>'
                    '<joint name="z" type="slide" axis="0 0 1"/><inertial pos="0 0 0" mass="1" '
                    f'diaginertia="0.01 0.01 0.01"/><site name="{name}" pos="0 0 -0.1"/></body></worldbody></mujoco>')
    robot = load_robot(path)
    assert robot.points == ("mass", name) and robot.model.frames[robot.frame_id(name)].parentJoint > 0


def test_an_unnamed_motor_is_named_apart_from_the_named_ones(tmp_path):
    """An unnamed motor is named actuator_i, primed while a named motor has that name, in the robot and in the replay:
    the unnamed x motor and the z motor named "actuator_0" were one key of the validation's saturation_by_actuator
    (one motor's number lost)."""
    path = tmp_path / "motors.xml"
    path.write_text('<mujoco><worldbody><body name="mass"><joint name="x" type="slide" axis="1 0 0"/>'
                    '<joint name="z" type="slide" axis="0 0 1"/><inertial pos="0 0 0" mass="1" '
                    'diaginertia="0.01 0.01 0.01"/><site name="foot"/></body></worldbody><actuator><motor joint="x"/>'
                    '<motor name="actuator_0" joint="z"/><motor joint="z"/></actuator></mujoco>')
    from planner import replay
    from planner.task import parse_task

    robot = load_robot(path)
    assert [a.name for a in robot.actuators] == ["actuator_0'", "actuator_0", "actuator_2"]
    task = parse_task({"contacts": [{"point": "foot"}], "initial": {"q": [0.0, 0.5]},
                       "horizon": {"tau_f": 0.4, "N": 4}})
    gains = replay.resolve_gains(replay.build_scene(robot, task), replay.TrackingGains(), np.array([0.0, 0.5]))
    assert gains.actuators == ("actuator_0'", "actuator_0", "actuator_2")  # the replay's keys, as the robot's names


def test_unnamed_joints_and_bodies_are_named_as_the_cause(tmp_path):
    """Joints without a name (Pinocchio calls them dof_0 ..., MuJoCo '') fail check-model and the task's check with
    the fix "name every <joint>", and bodies without a name (Pinocchio's parser finds no body, or reads no joints in
    the root) are named as the cause: the messages blamed the joints' order, a <frame> or an <include>, or none."""
    from planner.check import check_model
    from planner.task import parse_task

    body = ('<body{name}><joint{j} type="slide" axis="1 0 0"/><joint{k} type="slide" axis="0 0 1"/>'
            '<inertial pos="0 0 0" mass="1" diaginertia="0.01 0.01 0.01"/><site name="foot"/></body>')
    joints = tmp_path / "joints.xml"
    joints.write_text("<mujoco><worldbody>" + body.format(name=' name="a"', j="", k="") + "</worldbody></mujoco>")
    report = check_model(load_robot(joints))
    assert not report.passed and any("name every <joint>" in f for f in report.failures)
    task = parse_task({"contacts": [{"point": "foot"}], "initial": {"q": [0.0, 0.3]},
                       "horizon": {"tau_f": 0.4, "N": 4}})
    with pytest.raises(RobotFileError, match="name every <joint>"):
        task.check_against(load_robot(joints))
    bodies = tmp_path / "bodies.xml"
    named = body.format(name="", j=' name="x"', k=' name="z"')
    bodies.write_text("<mujoco><worldbody>" + named + "</worldbody></mujoco>")
    with pytest.raises(RobotFileError, match=r"no body found .*reads named bodies only: name every <body>"):
        load_robot(bodies)
    child = ('<body pos="0 0 -0.2"><joint name="h" type="hinge" axis="0 1 0"/><inertial pos="0 0 0" mass="1" '
             'diaginertia="0.01 0.01 0.01"/></body>')
    bodies.write_text("<mujoco><worldbody>" + named.replace("</body>", child + "</body>") + "</worldbody></mujoco>")
    with pytest.raises(RobotFileError, match="nor a body without a name: name every <body>"):
        load_robot(bodies)


def test_a_file_pinocchio_cannot_parse_gets_mujocos_reason(tmp_path):
    """A joint of an undefined <default> class: Pinocchio's parser says only "unordered_map::at"; the refusal adds
    MuJoCo's reading, which names the class, the element and its line."""
    path = tmp_path / "class.xml"
    path.write_text('<mujoco><worldbody><body name="a"><joint name="x" class="nope" type="slide" axis="1 0 0"/>'
                    '<inertial pos="0 0 0" mass="1" diaginertia="0.01 0.01 0.01"/></body></worldbody></mujoco>')
    with pytest.raises(RobotFileError, match=r"Pinocchio cannot parse .* \(MuJoCo cannot read .*unknown default class "
                                             r"name 'nope'; Element 'joint', line 1\)"):
        load_robot(path)


def test_couplings_and_negative_inertias_are_refused(tmp_path):
    """A URDF <mimic> joint (Pinocchio: an independent joint; MuJoCo: an equality constraint, so the replay and the
    plan disagreed and both passed) is refused by simulate and plan (Task.check_against) naming the joint, as passive
    joint forces are; a body of negative mass or inertia (check-model compared garbage, mass errors of 1e115), or of
    principal moments no rigid body has, is refused when the file is read."""
    from planner.model import ROBOTS_DIR
    from planner.task import load_task

    urdf = (ROBOTS_DIR / "capler.urdf").read_text()
    knee_limit = '<limit lower="-1.5707963267948966" upper="1.5707963267948966" effort="60" velocity="0"/>\n  </joint>'
    assert urdf.count(knee_limit) == 1 and urdf.count('<mass value="0.548"/>') == 1
    mimic = tmp_path / "mimic.urdf"
    mimic.write_text(urdf.replace(knee_limit, knee_limit.replace("</joint>", "") + '<mimic joint="hip" multiplier="-1"/>\n  </joint>'))
    with pytest.raises(RobotFileError, match=r"joint 'knee': <mimic> .* nor couplings between joints"):
        load_task(ROBOTS_DIR / "capler.toml").check_against(load_robot(mimic))
    negative = tmp_path / "negative_mass.urdf"
    negative.write_text(urdf.replace('<mass value="0.548"/>', '<mass value="-0.548"/>'))
    with pytest.raises(RobotFileError, match=r"mass -0.548 kg"):
        load_robot(negative)
    # principal moments 1, 1, 3 (g m^2): no rigid body has them; MuJoCo refuses the file, and simulate had run on it
    inertia = '<inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.001"/>'
    impossible = tmp_path / "impossible_inertia.urdf"
    impossible.write_text(urdf.replace(inertia, inertia.replace('izz="0.001"', 'izz="0.003"'), 1))
    with pytest.raises(RobotFileError, match=r"principal moments of inertia \[0.001, 0.001, 0.003\] kg m\^2, .*A \+ B >= C"):
        load_robot(impossible)


def test_an_inertia_only_balanceinertia_makes_valid_is_refused_saying_so(robot_variant):
    """Capler's thigh with principal moments 1, 1, 5 (g m^2) under <compiler balanceinertia="true">: MuJoCo loads the
    file (it replaces the moments by their mean), so the refusal says that Pinocchio does not, beside the triangle
    inequality: it named the inequality alone, and a user who saw MuJoCo accept the file had no cause (session 69's
    tester). Without balanceinertia the refusal does not mention it."""
    text = (ROBOTS_DIR / "capler.xml").read_text()
    thigh = '<inertial pos="0 0 -0.016" mass="1.782" diaginertia="0.001 0.001 0.001"/>'
    assert text.count(thigh) == 1
    text = text.replace(thigh, thigh.replace("0.001 0.001 0.001", "0.005 0.001 0.001"))
    with pytest.raises(RobotFileError, match=r"A \+ B >= C\)$") as plain:
        robot_variant(text, "<compiler", "<compiler", name="plain.xml")
    assert "balanceinertia" not in str(plain.value)
    with pytest.raises(RobotFileError, match=r"A \+ B >= C\); MuJoCo accepts the file because its <compiler "
                                             r'balanceinertia="true"> replaces such moments by their mean, which '
                                             "Pinocchio does not"):
        robot_variant(text, 'autolimits="true"', 'autolimits="true" balanceinertia="true"')


@pytest.mark.parametrize("robot, old, new, message", [
    ("capler.urdf", '<mass value="1.782"/>', '<mass value="1,782"/>',
     r"could not read part of .*Could not parse inertial element for Link \[thigh\]"),
    ("point_mass.xml", '<inertial pos="0 0 0"', '<inertial pos="0,0,0.1"',
     r"mass or inertia that is not finite .* commas"),
])
def test_what_a_parser_could_not_read_is_refused(tmp_path, robot, old, new, message):
    """A URDF element urdfdom cannot read (a thigh's `<mass value="1,782"/>`) is refused with urdfdom's reason: it
    printed an error and returned the model without the element (simulate ran a robot 1.78 kg light, exit 0). An MJCF
    number Pinocchio reads as 2e243 (`pos="0,0,0.1"`) is refused naming the body, not a LinAlgError traceback."""
    text = (ROBOTS_DIR / robot).read_text()
    assert text.count(old) == 1
    typo = tmp_path / f"typo{Path(robot).suffix}"
    typo.write_text(text.replace(old, new))
    with pytest.raises(RobotFileError, match=message):
        load_robot(typo)


def test_mujocos_reading_warnings_are_python_warnings(tmp_path, monkeypatch):
    """What MuJoCo warns while reading a robot file is a Python warning (`-q` hides it), not a line on stderr and an
    entry in MUJOCO_LOG.TXT in the working directory (a hip of equal limits, which load_robot refuses before)."""
    import dataclasses

    from planner.model import mujoco_spec

    urdf = (ROBOTS_DIR / "capler.urdf").read_text()
    hip = '<limit lower="-1.1780972450961724" upper="1.1780972450961724"'
    assert urdf.count(hip) == 1
    monkeypatch.chdir(tmp_path)
    equal = tmp_path / "equal.urdf"
    equal.write_text(urdf.replace(hip, '<limit lower="0" upper="0"'))
    robot = dataclasses.replace(load_robot(ROBOTS_DIR / "capler.urdf"), path=equal)
    with pytest.warns(UserWarning, match=r"MuJoCo reading .*equal.urdf: joint 'hip' has equal lower and upper limits"):
        mujoco_spec(robot)
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()


@pytest.mark.parametrize("edit, said", [
    (('<axis xyz="0 1 0"/>', '<axis xyz="0 0 0"/>'), r"joint 'hip': its <axis xyz> is zero .*; give the direction"),
    (('<axis xyz="0 1 0"/>', '<axis xyz="0 1e-200 0"/>'), r"joint 'hip': its <axis xyz> is zero"),  # MuJoCo: too small
    (('upper="1.1780972450961724"', ""), r"joint 'hip': its <limit> gives lower but no upper, which URDF reads as 0"),
    (('lower="-1.1780972450961724"', ""), r"joint 'hip': its <limit> gives upper but no lower, which URDF reads as 0"),
    # one side beyond 0 (read as inverted: "swap them") or at 0 (read as locked) was refused for the wrong reason
    (('lower="-1.1780972450961724" upper="1.1780972450961724"', 'lower="0.2"'), r"gives lower but no upper"),
    (('lower="-1.1780972450961724" upper="1.1780972450961724"', 'upper="-0.2"'), r"gives upper but no lower"),
    (('lower="-1.1780972450961724" upper="1.1780972450961724"', 'lower="0"'), r"gives lower but no upper"),
])
def test_urdf_joint_mistakes_are_named(tmp_path, edit, said):
    """A URDF joint with a zero axis (refused as a body lighter than MIN_DOF_INERTIA, though it weighed 1 kg) or a limit
    with one side (the other read as 0 by Pinocchio and the joint unlimited by MuJoCo: refused for MuJoCo's range, or
    as inverted or locked) is refused naming the joint and the mistake."""
    from planner.errors import RobotFileError

    urdf = (ROBOTS_DIR / "capler.urdf").read_text()
    hip = urdf.index('<joint name="hip"')
    assert urdf[hip:].count(edit[0]) >= 1
    path = tmp_path / "capler.urdf"
    path.write_text(urdf[:hip] + urdf[hip:].replace(edit[0], edit[1], 1))
    with pytest.raises(RobotFileError, match=said):
        load_robot(path)


def test_limits_and_force_ranges_are_mujocos_and_contacts_are_sites(tmp_path):
    """A hinge's range with a ref is MuJoCo's (Pinocchio's parser shifted it by -ref, refusing targets MuJoCo allows); a
    joint's actuatorfrcrange bounds its one motor's control as forcerange does (the plan used the motor's +-20 where
    MuJoCo clamps at +-5), with two motors the joint's range is checked against their summed reach (a negative gear
    swaps its ends), and a control range those limits leave empty is refused (it was kept inverted); a contact point
    that is an MJCF body, not a site, is refused by the task's check (the simulation ran, and its validation found no
    MuJoCo site); a tendon motor is named in its refusal."""
    from planner.errors import TaskError
    from planner.task import parse_task

    robot = load_robot(_hopper(tmp_path, hip='ref="0.3"'))
    assert (robot.q_lower[2], robot.q_upper[2]) == (-1.0, 1.0)
    robot = load_robot(_hopper(tmp_path, hip='actuatorfrcrange="-5 5"'))
    assert (robot.actuators[0].lower, robot.actuators[0].upper) == (-5.0, 5.0)
    task = parse_task({"contacts": [{"point": "leg"}], "initial": {"q": [0.0, 0.5, 0.0]}, "horizon": {"tau_f": 0.5, "N": 10}})
    with pytest.raises(TaskError, match=r"contact point 'leg' is an MJCF body, not a site; .*\(sites: foot\)"):
        task.check_against(robot)
    from planner.check import reading_differences  # two motors on the joint, one with a negative gear: reach [-3, 1]

    two = load_robot(_hopper(tmp_path, hip='actuatorfrcrange="-2.5 2.5"', actuator='<motor name="a" joint="hip" ctrlrange="-1 1"/>'
                             '<motor name="b" joint="hip" gear="-1" ctrlrange="0 2"/>'))
    assert "joint 'hip': actuatorfrcrange [-2.5, 2.5] narrower than its motors' force range [-3, 1]" in reading_differences(two)
    with pytest.raises(RobotFileError,
                       match="actuator 'm': its ctrlrange, its forcerange .* actuatorfrcrange / gear do not overlap"):
        load_robot(_hopper(tmp_path, hip='actuatorfrcrange="-1 1"', actuator='<motor name="m" joint="hip" ctrlrange="5 10"/>'))
    with pytest.raises(RobotFileError, match="actuator 'tm' does not act on a joint"):
        load_robot(_hopper(tmp_path, actuator='<motor name="tm" tendon="t"/>',
                           extra='<tendon><fixed name="t"><joint joint="hip" coef="1"/></fixed></tendon>'))
    sites = '<site name="foot" pos="0 0 -0.3"/>' + "".join(f'<site name="s{i}"/>' for i in range(1, 5))
    with pytest.raises(RobotFileError, match="actuator 'sm' does not act on a joint"):  # (site 4: IndexError)
        load_robot(_hopper(tmp_path, actuator='<motor name="sm" site="s4"/>', foot=sites))
    # jointinparent on a hinge is a joint motor (refused as "does not act on a joint")
    inparent = load_robot(_hopper(tmp_path, actuator='<general name="g" jointinparent="hip" ctrlrange="-1 1"/>'))
    assert [(a.name, inparent.dof_names[a.dof], a.gear) for a in inparent.actuators] == [("g", "hip", 1.0)]


def test_a_joint_of_several_dof_names_each(tmp_path):
    """An MJCF free joint's six velocity coordinates are root_0 ... root_5 (they were six times "root", so a task's
    joint names could not tell them apart)."""
    path = tmp_path / "free.xml"
    path.write_text('<mujoco><worldbody><body name="b"><freejoint name="root"/><inertial pos="0 0 0" mass="1" '
                    'diaginertia="1 1 1"/><site name="s"/></body></worldbody></mujoco>')
    assert load_robot(path).dof_names == tuple(f"root_{i}" for i in range(6))


def test_the_robot_hash_covers_included_files(tmp_path):
    """Robot.sha256 (summary.json's robot_sha256, which validate, view and --init check) changes when a file the MJCF
    includes changes: an edited <include>d actuator block (gear 1 -> 3) was replayed by validate as the planned
    robot. A file without includes hashes as its bytes alone (the hash of every earlier result); an include loop
    ends."""
    import hashlib

    from planner.model import file_sha256

    text = (ROBOTS_DIR / "point_mass.xml").read_text()
    actuators = text[text.index("<actuator>"):text.index("</actuator>") + len("</actuator>")]
    (tmp_path / "act.xml").write_text(f"<mujoco>{actuators}</mujoco>")
    (tmp_path / "robot.xml").write_text(text.replace(actuators, '<include file="act.xml"/>'))
    robot = load_robot(tmp_path / "robot.xml")
    assert robot.nu == 2 and robot.sha256 == file_sha256(tmp_path / "robot.xml")
    (tmp_path / "act.xml").write_text("<mujoco>" + actuators.replace('gear="1"', 'gear="3"') + "</mujoco>")
    assert file_sha256(tmp_path / "robot.xml") != robot.sha256
    plain = ROBOTS_DIR / "capler.xml"
    assert file_sha256(plain) == hashlib.sha256(plain.read_bytes()).hexdigest()
    (tmp_path / "loop.xml").write_text('<mujoco><include file="loop.xml"/></mujoco>')
    assert len(file_sha256(tmp_path / "loop.xml")) == 64


def test_urdf_transmissions_are_not_read_and_say_so(tmp_path):
    """A URDF's <transmission> elements are not read (a joint's motor is its <limit effort>, gear 1): loading warns, and
    a plan of such a file whose joints have effort 0 names the rule (it said only "no actuators to plan with", and a
    mechanicalReduction of 2 was silently gear 1); the task itself, [plan] and all, is one to simulate."""
    from planner.errors import TaskError
    from planner.task import parse_task

    text = (ROBOTS_DIR / "capler.urdf").read_text()
    transmission = ('<transmission name="t"><type>transmission_interface/SimpleTransmission</type><joint name="hip">'
                    '<hardwareInterface>EffortJointInterface</hardwareInterface></joint><actuator name="m">'
                    '<mechanicalReduction>2</mechanicalReduction></actuator></transmission></robot>')
    path = tmp_path / "geared.urdf"
    path.write_text(text.replace("</robot>", transmission))
    with pytest.warns(UserWarning, match="<transmission> elements are not read"):
        assert [a.gear for a in load_robot(path).actuators] == [1.0, 1.0]
    unactuated = tmp_path / "unactuated.urdf"
    unactuated.write_text(re.sub(r'effort="[^"]*"', 'effort="0"', path.read_text()))
    with pytest.warns(UserWarning, match="<transmission>"):
        robot = load_robot(unactuated)
    task = parse_task({"contacts": [{"point": "foot"}], "initial": {"q": [0.0, 0.4, 0.0, 0.0]},
                       "horizon": {"tau_f": 1.0, "N": 10}, "plan": {"target_q": [0.5, 0.4, 0.0, 0.0]}})
    from planner.problem import build_problem

    with pytest.raises(TaskError, match=r"no actuators to plan with \(a URDF joint is actuated by its <limit effort>"):
        build_problem(robot, task)
    task.check_against(robot)  # a simulation reads no [plan] table: its task was refused (session 64's tester)


def test_a_urdf_is_read_by_mujoco_whatever_its_name_ends_in(tmp_path):
    """MuJoCo picks its reader by a file name's ending: a URDF named .URDF, or with no ending, which Pinocchio and
    simulate read, could never be validated or planned ("could not find decoder for resource"). mujoco_spec reads
    it as it reads robots/capler.urdf: the same compiled model."""
    from planner.model import mujoco_spec

    text = (ROBOTS_DIR / "capler.urdf").read_text()
    reference = mujoco_spec(load_robot(ROBOTS_DIR / "capler.urdf")).compile()
    for name in ("capler.URDF", "capler_urdf"):
        (tmp_path / name).write_text(text)
        model = mujoco_spec(load_robot(tmp_path / name)).compile()
        assert (model.nq, model.nv, model.nu) == (reference.nq, reference.nv, reference.nu)
        np.testing.assert_array_equal(model.body_mass, reference.body_mass)


def test_a_urdf_point_mass_without_rotational_inertia_compiles_in_mujoco(tmp_path):
    """A URDF link of 1 kg with zero inertia on prismatic joints (a point mass: the inertia acts on nothing), which
    Pinocchio and simulate read, compiles in MuJoCo with the massless link's 1e-12 kg m² (MuJoCo refused it: "mass and
    inertia of moving bodies must be larger than mjMINVAL", so no plan of it could be validated); its mass stays."""
    from planner.model import MASSLESS_LINK_INERTIA, mujoco_spec

    zero = '<inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/>'
    limit = '<limit lower="-10" upper="10" effort="100" velocity="100"/>'
    (tmp_path / "pm.urdf").write_text(
        f'<robot name="pm"><link name="world"/><link name="carriage"/>'
        f'<link name="point"><inertial><mass value="1"/>{zero}</inertial></link>'
        f'<joint name="x" type="prismatic"><parent link="world"/><child link="carriage"/><axis xyz="1 0 0"/>{limit}'
        f'</joint><joint name="z" type="prismatic"><parent link="carriage"/><child link="point"/><axis xyz="0 0 1"/>'
        f'{limit}</joint></robot>')
    model = mujoco_spec(load_robot(tmp_path / "pm.urdf"), sites=("point",)).compile()
    point = model.body("point")
    assert point.mass[0] == 1.0 and np.all(point.inertia == MASSLESS_LINK_INERTIA)


def test_robot_paths_in_robots_resolve_to_the_shipped_files_from_any_directory(tmp_path, monkeypatch):
    """`robots/capler.xml` and `capler.urdf`, as the help's examples write them, are the shipped files where no such
    file exists (outside a checkout they were "robot file not found", while tasks written so were found); a file of
    that name in the working directory comes first, and an unknown one is still not found."""
    from planner.errors import RobotFileError
    from planner.model import ROBOTS_DIR, resolve_robot_path

    monkeypatch.chdir(tmp_path)
    assert resolve_robot_path("robots/capler.xml") == ROBOTS_DIR / "capler.xml"
    assert resolve_robot_path("capler.urdf") == ROBOTS_DIR / "capler.urdf"
    (tmp_path / "capler.urdf").write_text("mine")
    assert resolve_robot_path("capler.urdf") == tmp_path / "capler.urdf"
    with pytest.raises(RobotFileError, match="robot file not found: robots/nothing.xml; the shipped robot files are "
                                             "biped.xml, capler.urdf, capler.xml, point_mass.xml"):
        resolve_robot_path("robots/nothing.xml")


def test_no_usable_temporary_directory_is_not_blamed_on_the_robot_file(tmp_path, monkeypatch):
    """Without a usable temporary directory (the parser's messages are caught in a temporary file) loading a robot
    is a PlannerError saying so and to set TMPDIR, not an InputError blaming the file: it read "Pinocchio cannot parse
    robots/point_mass.xml: [Errno 2] No usable temporary directory", exit 2 (session 59's tester)."""
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "missing"))
    with pytest.raises(PlannerError, match="no usable temporary directory .*; set TMPDIR to a writable") as exc:
        load_robot("point_mass")
    assert not isinstance(exc.value, InputError)


def test_robots_loaded_from_several_threads_leave_the_process_streams_as_they_were(monkeypatch):
    """Loads from several threads take the parser's stderr capture (model._quiet) one at a time and leave sys.stdout and
    descriptor 2 as they found them: interleaved swaps left descriptor 2 on a deleted temporary file and sys.stdout on a
    StringIO for the rest of the process (prints and tracebacks lost). The parser is slowed so the loads overlap."""
    import os
    import sys
    import threading
    import time

    parse, inside, most = pin.buildModelFromMJCF, [], []

    def slow(path):
        inside.append(path)
        most.append(len(inside))
        time.sleep(0.02)
        inside.pop()
        return parse(path)

    monkeypatch.setattr(pin, "buildModelFromMJCF", slow)
    stdout, fd2 = sys.stdout, os.fstat(2)
    threads = [threading.Thread(target=lambda: [load_robot("point_mass") for _ in range(5)]) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    after = os.fstat(2)
    assert max(most) == 1 and len(most) == 20
    assert sys.stdout is stdout and (after.st_dev, after.st_ino) == (fd2.st_dev, fd2.st_ino)


def test_an_error_line_another_thread_writes_during_an_mjcf_load_does_not_refuse_the_file(monkeypatch):
    """A log line "Error: ..." that another thread writes on descriptor 2 while an MJCF file is parsed (caught with the
    parser's messages) does not refuse the file: it was read as urdfdom's report of a URDF element it could not read
    (3 of 200 loads of a tester's valid point_mass.xml)."""
    import os

    parse = pin.buildModelFromMJCF

    def logged_meanwhile(path):
        os.write(2, b"Error: client 10.0.0.7 disconnected\n")
        return parse(path)

    monkeypatch.setattr(pin, "buildModelFromMJCF", logged_meanwhile)
    assert load_robot("point_mass").nv == 2


def test_hostile_robot_files_are_refused_in_one_line_before_a_parser_reads_them(tmp_path):
    """Robot files a user may download are refused with a RobotFileError before Pinocchio or MuJoCo reads them:
    elements nested deeper than MuJoCo's reader takes (Pinocchio's MJCF parser crashed the process at 30000 levels,
    inside an element it does not read), an <include> or mesh naming a FIFO (MuJoCo blocked on it forever) or a
    directory, a file larger than MAX_ROBOT_FILE_BYTES (a 40 MB comment parsed for 78 s), and a <!DOCTYPE> (MuJoCo's
    reader ends it at its first '>' and read another model than Pinocchio); a file is looked for where MuJoCo looks."""
    import os

    from planner.model import MAX_ROBOT_FILE_BYTES, MAX_XML_DEPTH

    text = (ROBOTS_DIR / "point_mass.xml").read_text()
    deep = tmp_path / "deep.xml"
    n = 30000
    deep.write_text(text.replace("<worldbody>", "<custom>" + "<a>" * n + "</a>" * n + "</custom><worldbody>", 1))
    os.mkfifo(tmp_path / "fifo")
    os.mkfifo(tmp_path / "fifo.stl")
    (tmp_path / "folder").mkdir()
    cases = {deep: rf"nests its elements {n + 2} deep, more than the {MAX_XML_DEPTH}",
             tmp_path / "inc.xml": (text.replace("<worldbody>", '<include file="fifo"/><worldbody>', 1),
                                    r"<include> names 'fifo', which is no regular file"),
             tmp_path / "mesh.xml": (text.replace("<worldbody>", '<asset><mesh name="m" file="fifo.stl"/></asset>'
                                                  "<worldbody>", 1), r"<mesh> names 'fifo.stl', which is no regular"),
             tmp_path / "dir.xml": (text.replace("<worldbody>", '<include file="folder"/><worldbody>', 1),
                                    "names 'folder', which is no regular file"),
             tmp_path / "doctype.xml": ('<?xml version="1.0"?>\n<!DOCTYPE mujoco [<!ENTITY e "x">]>\n' + text,
                                        "has a <!DOCTYPE>, which neither MuJoCo nor URDF reads"),
             tmp_path / "big.xml": (text.replace("<worldbody>", "<!--" + "x" * MAX_ROBOT_FILE_BYTES + "--><worldbody>"),
                                    rf"is \d+ bytes, more than the {MAX_ROBOT_FILE_BYTES} \(20 MB\) a robot file")}
    for path, case in cases.items():
        if isinstance(case, tuple):
            path.write_text(case[0])
            case = case[1]
        with pytest.raises(RobotFileError, match=case):
            load_robot(path)
    # a directory of the mesh's name beside the file is not where MuJoCo looks when the file names a meshdir (it was
    # refused): the check reads each element where MuJoCo does
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "folder").write_text("solid s\nendsolid s\n")
    beside = tmp_path / "meshdir.xml"
    beside.write_text(text.replace("<worldbody>", '<compiler meshdir="meshes"/><asset><mesh name="m" file="folder"/>'
                                                  "</asset><worldbody>", 1))
    from planner.model import detect_format

    assert detect_format(beside) is RobotFormat.MJCF
    # what MuJoCo opens beyond the file's own <include> and mesh file=: an include's include, a mesh below an included
    # <compiler meshdir>, a cube texture's faces, a path whose directories strippath drops (each blocked MuJoCo)
    (tmp_path / "m").mkdir()
    os.mkfifo(tmp_path / "m" / "deep.stl")
    for sub, top, message in (('<mujoco><include file="fifo"/></mujoco>', "", "<include> names 'fifo'"),
                              ('<mujoco><compiler meshdir="m"/><asset><mesh name="d" file="deep.stl"/></asset>'
                               "</mujoco>", "", "<mesh> names 'deep.stl'"),
                              ("<mujoco/>", '<asset><texture name="t" type="cube" fileright="fifo.stl"/></asset>',
                               "<texture> names 'fifo.stl'"),
                              ("<mujoco/>", '<compiler strippath="true"/><asset><mesh name="z" file="zz/fifo.stl"/>'
                                            "</asset>", "<mesh> names 'fifo.stl'")):
        (tmp_path / "sub.xml").write_text(sub)
        main = tmp_path / "main.xml"
        main.write_text(text.replace("<worldbody>", f'{top}<include file="sub.xml"/><worldbody>', 1))
        with pytest.raises(RobotFileError, match=message):
            detect_format(main)


FREE_BASE_LEG = """<mujoco><compiler angle="radian"/><worldbody><body name="base" pos="0 0 1"><freejoint name="root"/>
  <geom type="box" size="0.1 0.1 0.1" mass="2"/>
  <body name="leg" pos="0 0 -0.1"><joint name="hip" type="hinge" axis="0 1 0" range="-0.5 0.7" limited="true"/>
    <geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.02" mass="1"/><site name="foot" pos="0 0 -0.3"/></body>
</body></worldbody><actuator><motor joint="hip" ctrlrange="-10 10"/></actuator></mujoco>"""


def test_a_hinges_limits_after_a_free_joint_are_at_its_qpos_address(tmp_path):
    """A free joint takes 7 coordinates: the hinge after it gets MuJoCo's range at MuJoCo's qpos address of the hinge
    (session 65's mutation testing: read by the joint's index, the range lands on the base's y coordinate and the
    hinge keeps Pinocchio's reading, with every test green)."""
    import mujoco

    path = tmp_path / "free_base_leg.xml"
    path.write_text(FREE_BASE_LEG)
    robot, mj = load_robot(path), mujoco.MjModel.from_xml_path(str(path))
    hip = mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_JOINT, "hip")
    i = int(mj.jnt_qposadr[hip])
    assert (robot.q_lower[i], robot.q_upper[i]) == tuple(mj.jnt_range[hip]) == (-0.5, 0.7)
    assert robot.q_lower[1] != -0.5 and robot.q_upper[1] != 0.7  # the base's y is not the hip's range


@pytest.mark.parametrize("joint, dof", [('<joint name="root" type="free" stiffness="5"/>', "root_0"),
                                        ('<joint name="ball" type="ball" stiffness="5"/>', "ball_0")])
def test_a_multi_dof_joints_stiffness_is_named_once(tmp_path, joint, dof):
    """MuJoCo's joint stiffness is one spring per joint (jnt_stiffness), not one per degree of freedom: a free or ball
    joint with stiffness 5 is named once in Robot.passive, at its first degree of freedom (ground truth: MuJoCo's model
    has one stiffness entry for the joint). Spread over the joint's dofs (a mutant of session 65's mutation testing) the
    refusal listed the same spring six (three) times, as six springs."""
    import mujoco

    path = tmp_path / "multi.xml"
    body = f'{joint}<inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/><site name="s"/>'
    if "ball" in joint:  # a ball below a slide (a free joint is a root's)
        body = ('<joint name="x" type="slide" axis="1 0 0"/><inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/>'
                f'<body name="c">{body}</body>')
    path.write_text(f'<mujoco><worldbody><body name="b">{body}</body></worldbody></mujoco>')
    mj = mujoco.MjModel.from_xml_path(str(path))
    assert np.count_nonzero(mj.jnt_stiffness) == 1
    assert load_robot(path).passive == (f"joint {dof!r}: stiffness 5",)


POINT_MASS = (ROBOTS_DIR / "point_mass.xml").read_text()  # the file a variant edits


@pytest.mark.parametrize("motor, bounds", [
    ('<motor name="force_x" joint="x"/>', (-np.inf, np.inf)),
    ('<motor name="force_x" joint="x" gear="2" forcerange="-5 5"/>', (-5.0, 5.0))])
def test_a_motor_without_a_ctrlrange_is_unbounded_or_bounded_by_its_forcerange(robot_variant, motor, bounds):
    """A <motor> without ctrlrange is no control limit to MuJoCo (actuator_ctrllimited 0, its ctrlrange stored as 0 0):
    its control bounds are (-inf, inf), or its forcerange (MuJoCo clamps the force ctrl before the gear) when it has
    one. Read as its stored ctrlrange (a mutant of session 65's mutation testing) the motor was bounded to [0, 0]:
    planned with no force at all, and no test noticed (every shipped motor has a ctrlrange)."""
    import mujoco

    robot = robot_variant(POINT_MASS, '<motor name="force_x" joint="x" gear="1" ctrlrange="-100 100"/>', motor)
    mj = mujoco.MjModel.from_xml_path(str(robot.path))
    assert not mj.actuator_ctrllimited[0] and tuple(mj.actuator_ctrlrange[0]) == (0.0, 0.0)
    assert (robot.u_lower[0], robot.u_upper[0]) == bounds
    assert (robot.u_lower[1], robot.u_upper[1]) == (-100.0, 100.0)


CAPLER_URDF = (ROBOTS_DIR / "capler.urdf").read_text()


@pytest.mark.parametrize("text, old, new, named", [
    (POINT_MASS, '<site name="point"', '<site name="point&#10;x"',
     r"<site name='point\\nx'> has a name with the unprintable character '\\n'"),
    (POINT_MASS, '<joint name="z"', '<joint name="z&#13;"', r"<joint name='z\\r'> .* character '\\r'"),
    (POINT_MASS, '<mujoco model="point_mass">', '<mujoco model="point&#9;mass">',
     r"<mujoco model='point\\tmass'> .* character '\\t'"),
    (CAPLER_URDF, '<link name="foot"/>', '<link name="foot&#10;x"/>', r"<link name='foot\\nx'> .* character '\\n'"),
])
def test_a_name_with_a_control_character_is_refused_naming_its_element(robot_variant, text, old, new, named):
    """A robot file's element name holding a newline, a carriage return or a tab (an MJCF site, joint or model name, a
    URDF link) is refused at load with a RobotFileError naming the element, the name escaped: such a name went into
    the one-line-per-item reports (`check-model`'s points line, a plan's impact lines) and split them in two, so a
    reader of the lines saw broken records."""
    name = "variant.urdf" if old.startswith("<link") else "variant.xml"
    with pytest.raises(RobotFileError, match=named) as caught:
        robot_variant(text, old, new, name)
    assert "\n" not in str(caught.value)


# [m/m] Pinocchio's numeric frame Jacobian and the planner's CasADi one of the same point: the same arithmetic (equal
# to the bit on Capler), so only rounding may tell them apart
JACOBIAN_TOL = 1e-12


def test_touching_contacts_are_the_points_on_their_plane_with_their_force_directions():
    """Robot.touching_contacts, which both the task's contact-rank check and the static-torque start
    (problem.static_controls) read, keeps a point within result.ON_PLANE_M of its plane and leaves out one twice that
    above it (in the air), and gives each kept point's generalized force directions J^T n and J^T t (None for a
    frictionless point) as the planner's CasADi dynamics have them: the two callers see the same touching points."""
    from planner.contact import plane_axes
    from planner.result import ON_PLANE_M

    robot = load_robot("capler")
    slope = (0.6, 0.0, 0.8)  # a tilted plane through the origin, under the foot as the ground is
    contacts = [("foot", (0.0, 0.0, 1.0), True), ("foot", slope, False), ("knee", (0.0, 0.0, 1.0), True)]
    q = np.array([0.0, 0.4, 0.0, 0.0])  # the straight leg's foot on the ground [m, m, rad, rad]
    J = np.asarray(Dynamics(robot).point_jacobian("foot")(q), float)
    for lift, touching in ((0.0, [0, 1]), (0.5 * ON_PLANE_M, [0, 1]), (2.0 * ON_PLANE_M, [])):
        found = robot.touching_contacts(contacts, q + [0.0, lift, 0.0, 0.0], 0.0)
        assert [i for i, _, _ in found] == touching == robot.contact_rank(contacts, q + [0.0, lift, 0.0, 0.0], 0.0)[0]
    (_, ground_n, ground_t), (_, slope_n, slope_t) = robot.touching_contacts(contacts, q, 0.0)
    for found, surface, axis in ((ground_n, (0.0, 0.0, 1.0), 0), (ground_t, (0.0, 0.0, 1.0), 1), (slope_n, slope, 0)):
        np.testing.assert_allclose(found, J.T @ np.array(plane_axes(surface)[axis]), rtol=0.0, atol=JACOBIAN_TOL)
    assert slope_t is None
