"""planner.check (check-model) and the robot-file errors it reports."""
from __future__ import annotations

import json
from pathlib import Path
import re

import numpy as np
import pinocchio as pin
import pytest

from planner.check import TOLERANCE, ModelCheck, check_model, random_state, reading_differences
from planner.errors import InputError, RobotFileError, UnknownNameError
from planner.model import ROBOTS_DIR, load_robot

SAMPLES = 5  # random states per check here; the CLI default is 20
# The CasADi functions reproduce Pinocchio and MuJoCo to rounding (observed <= 3e-13); a tenth of
# check-model's own threshold leaves a margin that still catches any modelling error.
TOL_CHECK = TOLERANCE / 10

JSON_KEYS = {
    "robot", "format", "nq", "nv", "dof_names", "points", "controls", "backend", "samples", "seed", "max_err_mass",
    "max_err_bias",
    "max_err_frames", "max_err_jacobians", "max_err_drift", "mujoco", "mujoco_skipped", "timing", "passed", "tolerance",
    "failures", "passive", "ranges",
}
TIMING_KEYS = {"build_s", "point_build_s", "point", "mass_us", "bias_us", "jacobian_us", "evaluations"}


@pytest.mark.parametrize("name", ["capler.xml", "capler.urdf", "biped.xml", "point_mass.xml"])
def test_project_robots_pass(name):
    """check-model passes on every robot in robots/, MuJoCo compared for MJCF and URDF alike (the URDF as
    planner.model.mujoco_spec gives it to MuJoCo: sites at its links, its carriage MASSLESS_LINK_KG)."""
    result = check_model(load_robot(ROBOTS_DIR / name), samples=SAMPLES)
    assert result.passed and result.backend in ("symbolic", "pinocchio.casadi")
    assert all(err <= TOL_CHECK for err in result.max_errors.values()), result.max_errors
    assert result.mujoco is not None and result.mujoco_skipped is None


@pytest.mark.filterwarnings("ignore:.*<transmission> elements are not read")  # (ur5 has them: check-model needs none)
@pytest.mark.parametrize("name", ["ur5", "panda"])
def test_third_party_urdf_matches_mujoco(erd_robot, name):
    """A fixed-base URDF of example-robot-data (meshes by package:// path, which planner.model.mujoco_spec drops) is
    compared with MuJoCo's own reading of the file: M, h and every link's position agree. The UR5 passes; the Panda
    fails naming what MuJoCo's replay would apply and the planner does not model (its joints' damping, the finger's
    <mimic>), as simulate and plan refuse it."""
    result = check_model(erd_robot(name), samples=SAMPLES)
    assert result.mujoco is not None and result.mujoco_skipped is None
    rigid = {k: v for k, v in result.max_errors.items() if k != "mujoco_max_err_passive"}  # the Panda's damping is not rigid
    assert all(err <= TOL_CHECK for err in rigid.values()), rigid
    if name == "ur5":
        assert result.passed and not result.mujoco.differences
    else:
        assert not result.passed and any(d.startswith("joint 'panda_finger_joint2': <mimic>") for d in result.mujoco.differences)
        assert "MuJoCo applies what the planner does not model: joint 'panda_joint1': damping" in result.report()


def test_solo12_passes_and_is_timed(erd_robot):
    """A free-flyer quadruped passes; the Jacobian timed is the first foot's. MuJoCo is compared (its URDF has no free
    joint: Pinocchio adds it, and check-model adds one to MuJoCo's root body)."""
    result = check_model(erd_robot("solo12"), samples=SAMPLES)
    assert result.passed and (result.nq, result.nv) == (19, 18) and result.mujoco is not None  # free joint added
    assert result.timing.point == "FL_FOOT"


def test_passive_terms_fail_the_check_without_the_mujoco_comparison(tmp_path):
    """A file's joint damping fails check-model also where the MuJoCo comparison is skipped (a URDF read with
    Pinocchio's free flyer): it passed, though simulate and plan refuse it."""
    urdf = (ROBOTS_DIR / "capler.urdf").read_text()
    hip = '<axis xyz="0 1 0"/>\n    <limit lower="-1.1780972450961724"'
    assert urdf.count(hip) == 1
    damped = tmp_path / "damped.urdf"
    damped.write_text(urdf.replace(hip, '<dynamics damping="5"/>' + hip))
    result = check_model(load_robot(damped, floating=True), samples=1)
    assert result.mujoco is None and not result.passed
    assert any("the planner does not model: joint 'hip': damping 5" in f for f in result.failures), result.failures
    assert "the planner does not model: joint 'hip'" in result.report()


def test_json_contract():
    """to_json() is JSON-serializable and has exactly the contract's keys; mujoco is an object where MuJoCo was
    compared (both files) and null where it was skipped (the URDF with a free flyer); numbers are plain floats."""
    floating = check_model(load_robot(ROBOTS_DIR / "capler.urdf", floating=True), samples=1).to_json()
    assert floating["mujoco"] is None and "MuJoCo" in floating["mujoco_skipped"]
    for name, has_mujoco in (("capler.xml", True), ("capler.urdf", True)):
        out = check_model(load_robot(ROBOTS_DIR / name), samples=2).to_json()
        assert json.loads(json.dumps(out)) == out
        assert set(out) == JSON_KEYS and set(out["timing"]) == TIMING_KEYS
        assert (out["robot"], out["format"], out["nq"], out["nv"]) == ("capler", name.split(".")[1].replace("xml", "mjcf"), 4, 4)
        assert out["passed"] is True and out["failures"] == [] and out["tolerance"] == TOLERANCE
        if has_mujoco:
            assert set(out["mujoco"]) == {"max_err_mass", "max_err_bias", "max_err_sites", "max_err_passive",
                                          "max_err_actuation", "missing_sites", "differences", "hints"}
            assert out["mujoco"]["missing_sites"] == [] and out["mujoco"]["differences"] == []
        else:
            assert out["mujoco"] is None
        assert all(type(out[k]) is float for k in JSON_KEYS if k.startswith("max_err"))
        assert out["timing"]["build_s"] > 0 and out["timing"]["mass_us"] > 0 and out["timing"]["point"] == "foot"


def test_the_controls_are_listed_in_the_actuators_order(tmp_path):
    """check-model lists the joint each control drives, in u's order: an MJCF file's <actuator> order, which need not
    be the joints' (u[0] drove the second joint here, and nothing told the user); Capler's are hip, knee in both
    files."""
    for name in ("capler.xml", "capler.urdf"):
        assert check_model(load_robot(ROBOTS_DIR / name), samples=1).controls == ("hip", "knee")
    hip = '<motor name="hip_motor" joint="hip" gear="1" ctrlrange="-60 60"/>'
    knee = '<motor name="knee_motor" joint="knee" gear="1" ctrlrange="-60 60"/>'
    text = (ROBOTS_DIR / "capler.xml").read_text()
    assert hip in text and knee in text
    path = tmp_path / "swapped.xml"
    path.write_text(text.replace(hip, "HIP").replace(knee, hip).replace("HIP", knee))
    assert check_model(load_robot(path), samples=1).controls == ("knee", "hip")


def test_detects_a_wrong_model():
    """check-model fails when Pinocchio's model and the file disagree: a thigh mass changed after
    parsing leaves CasADi = Pinocchio but MuJoCo's M and h differ."""
    robot = load_robot("capler")  # a fresh model: it is mutated below
    thigh = robot.model.getJointId("hip")
    inertia = robot.model.inertias[thigh]
    robot.model.inertias[thigh] = pin.Inertia(inertia.mass + 0.1, inertia.lever, inertia.inertia)
    result = check_model(robot, samples=2)
    assert not result.passed and result.to_json()["passed"] is False
    assert result.max_err_mass <= TOL_CHECK and result.mujoco.max_err_mass > 0.01 and result.mujoco.max_err_bias > 0.1


def test_seeded():
    """The same seed gives the same states and errors; random_state keeps q within finite limits,
    draws unbounded coordinates in [-1, 1] and normalizes quaternions."""
    robot = load_robot("capler")
    a, b = (check_model(robot, samples=3, seed=7) for _ in range(2))
    keys = [k for k in JSON_KEYS if k.startswith("max_err")]
    assert [getattr(a, k) for k in keys] == [getattr(b, k) for k in keys]
    rng = np.random.default_rng(0)
    qs = np.array([random_state(robot.model, rng)[0] for _ in range(200)])
    assert np.all(np.abs(qs[:, :2]) <= 1.0)  # base x, z: no range in capler.xml
    assert np.all(qs[:, 2:] >= robot.q_lower[2:]) and np.all(qs[:, 2:] <= robot.q_upper[2:])
    assert qs[:, 3].min() < -1.2 and qs[:, 3].max() > 1.2  # the knee's +-pi/2 range is used, not [-1, 1]


def test_random_state_normalizes_quaternions(erd_robot):
    """Free-flyer quaternions of random states have unit norm."""
    robot = erd_robot("solo12")
    rng = np.random.default_rng(0)
    for _ in range(20):
        q, v = random_state(robot.model, rng)
        assert np.linalg.norm(q[3:7]) == pytest.approx(1.0, abs=1e-15) and np.all(np.abs(v) <= 1.0)


def test_bad_arguments():
    """samples < 1, > MAX_SAMPLES or not an integer (nan, 2.5, a bool), a negative or non-integer seed and an unknown
    timing point are input errors; the unknown point's message lists the valid ones. A robot's name in place of the
    Robot is one too (an AttributeError on str)."""
    robot = load_robot("capler")
    with pytest.raises(InputError, match="check_model's robot .* must be a Robot, got str 'capler'"):
        check_model("capler")
    with pytest.raises(InputError, match="samples"):
        check_model(robot, samples=0)
    with pytest.raises(InputError, match="seed must be an integer >= 0, got -1"):
        check_model(robot, seed=-1)
    for samples in (float("nan"), 2.5, True, 10**20):  # nan < 1 is False: it reached numpy as a TypeError; 1e20 21.5 GB
        with pytest.raises(InputError, match=r"samples must be an integer in \[1, 100000\]"):
            check_model(robot, samples=samples)
    with pytest.raises(InputError, match="seed must be an integer >= 0, got 1.5"):
        check_model(robot, seed=1.5)
    with pytest.raises(UnknownNameError, match="unknown point 'toe'; valid points: base, foot, knee, shank, thigh"):
        check_model(robot, point="toe")


URDF_BROKEN = '<robot name="broken"><link name="a"/><joint name="j" type="revolute"><parent link="a"/><child link="missing"/></joint></robot>'


@pytest.mark.parametrize(
    "text, message",
    [
        (None, "robot file not found"),
        ('<sdf version="1.6"><model name="m"/></sdf>', "neither MJCF (<mujoco>) nor URDF (<robot>): root element <sdf>"),
        ("<mujoco><worldbody>", "malformed XML"),
        (URDF_BROKEN, "valid URDF model: Joint [j] is of type REVOLUTE but it does not specify limits"),
        ('<mujoco><worldbody><body><joint type="hinge"/><geom type="sphere" size="-1"/></body></worldbody></mujoco>', "Pinocchio cannot parse"),
        # MuJoCo compiles it; Pinocchio's parser said only "unordered_map::at"
        ('<mujoco><worldbody><body pos="0 0 1"><joint name="z" type="slide" axis="0 0 1"/><geom class="ball" '
         'type="sphere" size="0.1"/><site name="p"/></body></worldbody><default><default class="ball"><geom mass="1"/>'
         '</default></default></mujoco>', "move <default> above <worldbody>"),
        # class "main" is MuJoCo's top-level <default>: MuJoCo compiles it, Pinocchio's parser said "unordered_map::at"
        ('<mujoco><default><geom mass="1"/></default><worldbody><body pos="0 0 1" childclass="main"><joint name="z" '
         'type="slide" axis="0 0 1"/><geom type="sphere" size="0.1"/><site name="p"/></body></worldbody></mujoco>',
         'write the top-level <default> as <default class="main">'),
    ],
    ids=["missing", "not-a-robot", "malformed", "unparsable-urdf", "unparsable-mjcf", "late-defaults", "class-main"],
)
def test_bad_robot_files(tmp_path, text, message):
    """A missing, foreign, malformed or unparsable robot file raises RobotFileError (an InputError) with a
    one-line message naming the problem (a URDF's with urdfdom's reason, which it prints only on descriptor 2)."""
    path = tmp_path / "robot.xml"
    if text is not None:
        path.write_text(text)
    with pytest.raises(RobotFileError) as err:
        load_robot(path)
    assert message in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("name", ["robot.txt", "robot.XML", "robot", "robot.xml.bak"])  # (the last: robot.xml.xml)
def test_an_mjcf_file_not_named_xml_is_refused_with_the_rename(tmp_path, name):
    """MuJoCo picks its reader by the file name's ending and reads MJCF only from .xml: such a file was planned and
    simulated (the comparison with MuJoCo skipped) and then refused by validate and check-model (session 57's
    tester). It is refused on loading, with the name to give it; a URDF reads under any name."""
    path = tmp_path / name
    path.write_text((ROBOTS_DIR / "point_mass.xml").read_text())
    with pytest.raises(RobotFileError, match=r"is MJCF, which MuJoCo reads only from a file whose name ends in .xml.*"
                                             r"rename it to robot.xml$"):
        load_robot(path)
    urdf = tmp_path / "capler.txt"
    urdf.write_text((ROBOTS_DIR / "capler.urdf").read_text())
    assert load_robot(urdf).nq == 4


@pytest.mark.parametrize("file, old, new, named", [
    ("point_mass.xml", '<site name="point" pos="0 0 0"', '<site name="point" pos="nan 0 0"', "<site name='point'> pos"),
    ("point_mass.xml", '<joint name="x"', '<joint name="x" range="nan 1"', "<joint name='x'> range"),
    ("capler.urdf", '<mass value="1.782"/>', '<mass value="inf"/>', "<link name='thigh'> ... <mass> value")])
def test_a_robot_file_number_that_is_not_finite_is_named(tmp_path, file, old, new, named):
    """A placement, size or inertia that is not finite, or a bound that is nan, is refused naming the element (or its
    nearest named ancestor) and attribute: Pinocchio spread a site's nan into a body's inertia, and the message blamed
    the mass under a joint name of its own, asking about commas (session 57's tester). An infinite bound (no bound),
    a name that reads as a number and a Gazebo plugin's parameter are no such mistake."""
    text = (ROBOTS_DIR / file).read_text()
    assert text.count(old) == 1
    path = tmp_path / f"robot{Path(file).suffix}"
    path.write_text(text.replace(old, new))
    refused = rf"{path.name}: {re.escape(named)}=\"[^\"]+\" holds a number that is not finite"
    with pytest.raises(RobotFileError, match=refused):
        load_robot(path)
    if file == "point_mass.xml":
        unbounded = text.replace('<joint name="x"', '<joint name="x" range="-inf 1"')
        path.write_text(unbounded.replace('<site name="point"', '<site name="inf"'))
        assert "inf" in load_robot(path).points
    else:  # a plugin parameter no parser of the planner's reads (a Gazebo controller's): not looked at
        gazebo = '<gazebo><plugin name="c" filename="libc.so"><param name="max_effort" value="inf"/></plugin></gazebo>'
        path.write_text(text.replace("</robot>", gazebo + "</robot>"))
        assert load_robot(path).nq == 4

def test_floating_is_urdf_only():
    """floating=True adds a free flyer to a URDF and is refused for MJCF, which declares its own."""
    assert load_robot(ROBOTS_DIR / "capler.urdf", floating=True).nq == 4 + 7
    with pytest.raises(RobotFileError, match="floating applies to URDF only"):
        load_robot("capler", floating=True)


def test_report_text():
    """report() states the verdict, the max errors against Pinocchio and MuJoCo, and the timing."""
    text = check_model(load_robot("capler"), samples=2).report()
    lines = text.splitlines()
    assert lines[0].startswith("check-model capler (mjcf, nq=4, nv=4") and "PASSED" in lines[0]
    assert "vs Pinocchio: mass" in text and "vs MuJoCo:    mass" in text and "J(foot)" in text
    assert "vs MuJoCo:    mass" in check_model(load_robot(ROBOTS_DIR / "capler.urdf"), samples=1).report()
    assert "vs MuJoCo:    skipped: " in check_model(load_robot(ROBOTS_DIR / "capler.urdf", floating=True), samples=1).report()


def test_an_mjcf_free_joint_passes_with_mujoco_compared(tmp_path):
    """An MJCF <freejoint/> is one MuJoCo joint and six named degrees of freedom (root_0 ... root_5): check-model
    compares it with Pinocchio and with MuJoCo in MuJoCo's coordinates (it failed every such file on the joint names,
    then skipped MuJoCo)."""
    path = tmp_path / "free.xml"
    path.write_text('<mujoco><worldbody><body name="b"><freejoint name="root"/><inertial pos="0 0 0" mass="1" '
                    'diaginertia="1 1 1"/><site name="s"/></body></worldbody></mujoco>')
    result = check_model(load_robot(path), samples=2)
    assert result.passed and result.mujoco is not None and result.mujoco_skipped is None


def test_an_mjcf_free_joint_is_compared_with_mujoco(tmp_path):
    """A free body placed and turned in the file is compared in MuJoCo's coordinates (world pose, wxyz, world linear
    velocity), so a body MuJoCo weighs by its geoms and Pinocchio not fails (it passed with the comparison skipped)."""
    body = '<body name="b" pos="0 0 0.5" quat="0.9659 0.2588 0 0"><freejoint name="root"/>{}<geom type="box" size=".2 .1 .05" contype="0" conaffinity="0"/><site name="s" pos=".2 .1 -.05"/></body>'
    path = tmp_path / "free.xml"
    inertial = '<inertial pos="0 0 0" mass="1" diaginertia=".01 .02 .025"/>'
    path.write_text(f"<mujoco><worldbody>{body.format(inertial)}</worldbody></mujoco>")
    assert check_model(load_robot(path), samples=3).passed
    path.write_text(f"<mujoco><worldbody>{body.format('')}</worldbody></mujoco>")
    result = check_model(load_robot(path), samples=3)
    assert not result.passed and "body masses b 8 kg in MuJoCo, 0 kg in Pinocchio" in result.report()


def test_result_is_frozen():
    """ModelCheck is immutable."""
    result = check_model(load_robot("point_mass"), samples=1)
    assert isinstance(result, ModelCheck)
    with pytest.raises(AttributeError):
        result.passed = False
    with pytest.raises(AttributeError):
        result.max_err_mass = 1.0


FRAMED_SITE = """<mujoco><worldbody><body name="base"><joint name="z" type="slide" axis="0 0 1"/>
<inertial pos="0 0 0" mass="1" diaginertia="0.1 0.1 0.1"/>
<frame pos="0 0 -0.1"><site name="foot"/></frame><site name="top" pos="0 0 0.1"/></body></worldbody></mujoco>"""


def test_a_site_pinocchio_does_not_read_fails_the_check(tmp_path):
    """A MuJoCo site that Pinocchio's MJCF reading lacks (one inside a <frame>) fails check-model and is named, instead
    of passing on the sites both know and failing later as an unknown contact point."""
    path = tmp_path / "framed.xml"
    path.write_text(FRAMED_SITE)
    result = check_model(load_robot(path), samples=2)
    assert result.mujoco is not None and result.mujoco.missing_sites == ("foot",)
    assert not result.passed and "missing in Pinocchio's reading: foot" in result.report()
    assert result.failures == ["MuJoCo sites missing in Pinocchio's reading: foot"]


WORLD_SITE = FRAMED_SITE.replace('<frame pos="0 0 -0.1"><site name="foot"/></frame>', "").replace(
    "<worldbody>", '<worldbody><site name="marker" pos="1 0 0"/>').replace(
    "</worldbody>", '</worldbody><actuator><motor joint="z" ctrlrange="-50 50"/></actuator>')


def test_a_site_on_the_world_body_is_no_point_of_the_robot(tmp_path, capsys):
    """A site on the world body (a target marker) is fixed in the world: check-model passes without it (it failed, as a
    site inside a <frame>, with no <frame> in the file), and a task that names it as a contact point or an above-ground
    point is told so (it read "unknown contact point"), as one naming a site inside a <frame>. `planner check-model -q`
    of a failing file names the reasons (it printed "the validation failed")."""
    from planner.cli import main
    from planner.errors import TaskError
    from planner.task import parse_task

    path = tmp_path / "world.xml"
    path.write_text(WORLD_SITE)
    robot = load_robot(path)
    assert robot.world_sites == ("marker",) and "marker" not in robot.points
    assert check_model(robot, samples=2).passed
    base = {"initial": {"q": [0.5]}, "horizon": {"tau_f": 0.5, "N": 10}}
    with pytest.raises(TaskError, match=r"contacts\[0\].point = 'marker' is a site on the world body"):
        parse_task({**base, "contacts": [{"point": "marker"}]}).check_against(robot)
    above = {**base, "contacts": [{"point": "top"}], "plan": {"target_q": [0.5], "above_ground": ["marker"]}}
    with pytest.raises(TaskError, match=r"plan.above_ground\[0\] = 'marker' is a site on the world body"):
        parse_task(above).check_against(robot)
    framed = tmp_path / "framed.xml"
    framed.write_text(FRAMED_SITE)
    assert main(["check-model", str(framed), "--samples", "2", "-q"]) == 1
    assert "MuJoCo sites missing in Pinocchio's reading: foot" in capsys.readouterr().err
    assert load_robot(framed).unread_sites == ("foot",)  # a task naming it is told why (it read "valid: (none)")
    with pytest.raises(TaskError, match=r"contacts\[0\].point = 'foot' is a site Pinocchio's MJCF parser skips"):
        parse_task({**base, "contacts": [{"point": "foot"}]}).check_against(load_robot(framed))


PLANAR_URDF = """<robot name="p"><link name="world"/><link name="base"><inertial><mass value="1"/>
<inertia ixx="0.1" iyy="0.1" izz="0.1" ixy="0" ixz="0" iyz="0"/></inertial></link>
<joint name="base" type="planar"><parent link="world"/><child link="base"/><axis xyz="0 1 0"/></joint></robot>"""


def test_a_urdf_planar_joint_is_named_with_its_fix(tmp_path):
    """A URDF planar joint (MuJoCo: three joints, Pinocchio: one) fails check-model with the joint named and the fix
    (it said only that the two readings order the joints differently)."""
    path = tmp_path / "planar.urdf"
    path.write_text(PLANAR_URDF)
    (failure,) = check_model(load_robot(path), samples=2).failures
    assert failure.startswith("MuJoCo orders the joints") and failure.endswith(
        "(URDF planar joint 'base': MuJoCo reads it as three joints, Pinocchio as one; write it as two prismatic "
        "joints and a revolute one)")

def test_urdf_siblings_out_of_name_order_are_named_with_the_fix(tmp_path):
    """A URDF listing a link's child joints out of their names' order (right_hip before left_hip) fails check-model,
    saying that Pinocchio orders sibling branches by name and MuJoCo as the file lists them, and how to fix it (the
    message gave the two orders only); listed in name order, the same robot passes."""
    link = ('<link name="{}"><inertial><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/>'
            '</inertial></link>')
    joint = ('<joint name="{}" type="{}"><parent link="{}"/><child link="{}"/><axis xyz="{}"/>'
             '<limit lower="-1" upper="1" effort="{}" velocity="1"/></joint>')
    right, left = (joint.format(f"{side}_hip", "revolute", "c", side[0], "0 1 0", 9) for side in ("right", "left"))
    head = ('<robot name="b"><link name="world"/>' + "".join(link.format(n) for n in "crl")
            + joint.format("x", "prismatic", "world", "c", "1 0 0", 0))
    for name, siblings, passed in (("right_first.urdf", right + left, False), ("left_first.urdf", left + right, True)):
        (tmp_path / name).write_text(head + siblings + "</robot>")
        result = check_model(load_robot(tmp_path / name), samples=1)
        assert result.passed is passed
        if not passed:
            assert result.failures[0].endswith(
                "(Pinocchio's URDF parser orders sibling branches by their joints' names, MuJoCo as the file lists "
                "them: write the <joint> elements of each link's children in the order of their names)"), result.failures


def test_a_file_mujoco_reads_otherwise_fails(tmp_path):
    """A URDF whose knee is `continuous` (Pinocchio: cos and sin, nq 5; MuJoCo: an angle, nq 4) cannot be replayed, so
    check-model fails saying why (it said PASSED, the comparison "skipped"), and simulate and plan refuse it (they ran
    on it); a free flyer only Pinocchio adds is still a documented skip."""
    urdf = (ROBOTS_DIR / "capler.urdf").read_text()
    assert urdf.count('<joint name="knee" type="revolute">') == 1
    path = tmp_path / "continuous.urdf"
    path.write_text(urdf.replace('<joint name="knee" type="revolute">', '<joint name="knee" type="continuous">'))
    result = check_model(load_robot(path), samples=1)
    assert not result.passed and result.mujoco_skipped.startswith("FAILED: MuJoCo has nq, nv = 4, 4 but Pinocchio 5, 4")
    assert "vs MuJoCo:    FAILED: MuJoCo has nq" in result.report()
    assert "(joint 'knee': a URDF continuous joint, which Pinocchio reads as cos and sin; make it revolute" in result.report()
    assert check_model(load_robot(ROBOTS_DIR / "capler.urdf", floating=True), samples=1).passed
    from planner.task import load_task

    # planned, and simulated, before; refused for its coordinates first (the task's check of every joint, session 55)
    with pytest.raises(RobotFileError, match=r"joint\(s\) knee have more coordinates than velocities .* continuous "
                                             r"joint: make that one revolute with limits"):
        load_task(ROBOTS_DIR / "capler.toml").check_against(load_robot(path))


POINT_MASS = (ROBOTS_DIR / "point_mass.xml").read_text()
X_JOINT = '<joint name="x" type="slide" axis="1 0 0"/>'
MASS_BODY = '<body name="mass" pos="0 0 0">'
OPTION = '<option timestep="0.001" gravity="0 0 -9.81" cone="elliptic" impratio="10"/>'


@pytest.mark.parametrize("old, new, named", [
    (MASS_BODY, '<body name="mass" pos="0 0 0" gravcomp="1">', "body 'mass': gravcomp 1"),
    (OPTION, OPTION + '<option><flag gravity="disable"/></option>', '<option><flag gravity="disable"/>'),
    (OPTION, OPTION + '<option><flag contact="disable"/></option>', '<option><flag contact="disable"/>'),
    (OPTION, OPTION + '<option><flag override="enable"/></option>', '<option><flag override="enable"/>'),
    (OPTION, OPTION + '<option viscosity="20"/>', "fluid forces (<option> density 0, viscosity 20"),
    ("</worldbody>", '</worldbody><tendon><fixed name="t" stiffness="100"><joint joint="x" coef="1"/></fixed></tendon>',
     "tendon 't': stiffness 100"),
    ("</worldbody>", '</worldbody><tendon><fixed name="t" limited="true" range="-1 0.2"><joint joint="x" coef="1"/></fixed>'
     '</tendon>', "tendon 't': range [-1, 0.2]"),
    (X_JOINT, '<joint name="x" type="slide" axis="1 0 0" ref="0.3"/>', "point 'point' is up to 0.3 m apart"),
    (X_JOINT, '<joint name="x" type="slide" axis="1 0 0" ref="0.3"/>', "joint 'x': ref 0.3 m, which Pinocchio's parser "
     "ignores on a joint before its body's last"),
    (OPTION, '<compiler settotalmass="2"/>' + OPTION, '<compiler settotalmass="2">: MuJoCo rescales the masses'),
    (X_JOINT, '<joint name="x" type="slide" axis="1 0 0" range="-1 1" margin="0.2"/>', "joint 'x': margin 0.2: "
     "MuJoCo's limit pushes that far inside the range"),
    ('<motor name="force_x" joint="x"', '<motor name="force_x" armature="0.01" damping="0.3" joint="x"',
     "actuator 'force_x': armature 0.01, damping 0.3"),
    ('<motor name="force_z" joint="z"', '<motor name="force_z" delay="0.02" nsample="20" joint="z"',
     "actuator 'force_z': delay 0.02"),
    ('<site name="point"', '<body name="load"><geom type="sphere" size="0.02" mass="2"/></body><site name="point"',
     "mass matrix [kg, kg m, kg m^2] differs by up to 2 (e.g. masses MuJoCo infers from geoms"),
])
def test_physics_only_mujoco_reads_fails_and_is_refused(tmp_path, old, new, named):
    """A robot file MuJoCo reads with physics Pinocchio's reading lacks (gravity compensation, [option] flags, fluid
    forces, tendon springs and limits, a slide joint's ref, settotalmass, a mass MuJoCo infers from a geom, a joint
    limit's margin, a motor's armature, damping or delay) fails
    check-model, naming it (the geom mass's as its mass error only; the ref and settotalmass were named by their site
    and mass errors alone), and simulate and plan refuse it naming it
    (Task.check_against): each of them had planned, and its MuJoCo validation PASSED, for physics the replay does not
    have (a gravity-compensated point mass that never falls)."""
    from planner.check import reading_differences
    from planner.task import load_task

    assert POINT_MASS.count(old) == 1
    path = tmp_path / "variant.xml"
    path.write_text(POINT_MASS.replace(old, new))
    robot = load_robot(path)
    assert any(d.startswith(named) for d in reading_differences(robot)), reading_differences(robot)
    if "settotalmass" in new:  # the rescale is named: no per-body hint that blames missing <inertial>s (review)
        assert not any(d.startswith("body masses") for d in reading_differences(robot)), reading_differences(robot)
    result = check_model(robot, samples=2)
    numeric = named.startswith(("point", "mass matrix"))  # check-model reports these as its sites and mass errors
    assert not result.passed and (numeric or named in result.report())
    with pytest.raises(RobotFileError, match="MuJoCo reads other physics from this file than Pinocchio"):
        load_task(ROBOTS_DIR / "point_mass.toml").check_against(robot)


def test_the_motors_forces_are_compared_with_mujocos(tmp_path, monkeypatch):
    """check-model and the reading check compare the robot's B u with MuJoCo's actuator forces at seeded controls:
    Capler with its knee motor at gear 2 (negative for the hip) passes as read; a B that drops the gears (monkeypatched
    Robot.actuation_matrix) fails both, naming the motors' forces. Every shipped robot has gear 1, and a B of gear 1
    passed every test (session 56's test audit)."""
    import planner.model
    from planner.check import reading_differences

    text = (ROBOTS_DIR / "capler.xml").read_text()
    for motor, gear in (("knee_motor", "2"), ("hip_motor", "-1.5")):
        old = f'<motor name="{motor}" joint="{motor[:-6]}" gear="1"'
        assert text.count(old) == 1
        text = text.replace(old, old.replace('gear="1"', f'gear="{gear}"'))
    path = tmp_path / "geared.xml"
    path.write_text(text)
    robot = load_robot(path)
    assert sorted(abs(a.gear) for a in robot.actuators) == [1.5, 2.0]
    result = check_model(robot, samples=2)
    assert result.passed and result.mujoco.max_err_actuation <= TOLERANCE, result.failures
    assert reading_differences(robot) == ()
    ungeared = property(lambda self: np.eye(self.nv)[:, [a.dof for a in self.actuators]])
    monkeypatch.setattr(planner.model.Robot, "actuation_matrix", ungeared)
    robot = load_robot(path)
    assert any(f.startswith("mujoco_max_err_actuation") for f in check_model(robot, samples=2).failures)
    named = "the motors' generalized forces [N, N m] differ by up to"
    assert any(d.startswith(named) for d in reading_differences(robot))


CAPLER = (ROBOTS_DIR / "capler.xml").read_text()
SHANK = '<body name="shank" pos="0 0 -0.2">'
KNEE = '<joint name="knee" type="hinge" axis="0 1 0" range="-1.5707963267948966 1.5707963267948966"/>'
FOOT = '<site name="foot" pos="0 0 -0.2" size="0.012"/>'
SHANK_INERTIAL = '<inertial pos="0 0 -0.1" mass="0.548" diaginertia="0.0032 0.0032 0.0032"/>'


@pytest.mark.parametrize("edits, named", [
    ([(SHANK, SHANK[:-1] + ' axisangle="0 2 0 0.3">')], "<body name='shank'> axisangle axis of length 2, which"),
    ([('autolimits="true"', 'autolimits="true" eulerseq="XYZ"'), (SHANK, SHANK[:-1] + ' euler="0.1 0.3 0.5">')],
     '<compiler eulerseq="XYZ">: Pinocchio\'s parser reads an extrinsic'),
    ([(KNEE, KNEE.replace('range', 'ref="0.3" range')
       + '<joint name="ext" type="slide" axis="0 0 1" range="-0.05 0.05"/>')],
     "joint 'knee': ref 0.3 rad, which Pinocchio's parser ignores on a joint before its body's last"),
    ([("</default>", '<default class="tip"><site pos="0 0 -0.2"/></default></default>'),
      (FOOT, '<site name="foot" class="tip" size="0.012"/>')], "<default class='tip'> gives <site> pos, which"),
    ([(FOOT, FOOT + '<body name="sole" pos="0 0 -0.2"><body name="spur" pos="0.02 0 0"><site name="tip" '
      'pos="0.01 0 0"/></body></body>')], "site(s) ['tip'] on body 'spur', a body without joints inside"),
    # masses MuJoCo infers from geoms that collide with nothing: the check said only "mass 2.5e-01" (session 58)
    ([(SHANK_INERTIAL, "")], "body masses shank 0.0977161 kg in MuJoCo, 0 kg in Pinocchio: MuJoCo weighs a body "
                             "without <inertial> by its geoms"),
    # a site named as its body: Pinocchio's frame lookup by name alone raised "Several frames match" (regression tester)
    ([(SHANK_INERTIAL, '<site name="shank" pos="0 0 -0.05"/>')], "body masses shank 0.0977161 kg in MuJoCo"),
    # (session 61's tester: these three were refused as "e.g. masses MuJoCo infers from geoms" or with no cause)
    ([('<compiler angle="radian" autolimits="true"/>', '<compiler autolimits="true"/><compiler angle="radian"/>'),
      (SHANK, SHANK[:-1] + ' euler="0 0.5 0">')], "2 <compiler> elements: Pinocchio's parser reads the first only"),
    ([(SHANK_INERTIAL, SHANK_INERTIAL + '<frame pos="0 0 -0.2"><body name="pad"><inertial pos="0 0 0" mass="0.4" '
       'diaginertia="0.001 0.001 0.001"/></body></frame>')], "<frame> elements: Pinocchio's parser does not read"),
    ([(SHANK, SHANK[:-1] + ' zaxis="1e-9 0 -1">')], "<body name='shank'> zaxis '1e-9 0 -1', nearly opposite to z"),
    ([(SHANK, SHANK[:-1] + ' zaxis="1e-5 0 -1">')], "<body name='shank'> zaxis '1e-5 0 -1', nearly opposite to z"),
    ([('autolimits="true"', 'autolimits="true" inertiafromgeom="true"')],
     "body masses base 0.768 kg in MuJoCo, 0 kg in Pinocchio; thigh 0.155509 kg in MuJoCo, 0 kg in Pinocchio; shank "
     '0.0977161 kg in MuJoCo, 0 kg in Pinocchio: with <compiler inertiafromgeom="true">'),
])
def test_what_pinocchios_mjcf_parser_reads_otherwise_is_named(tmp_path, edits, named):
    """Capler's MJCF file with a construct MuJoCo reads and Pinocchio's parser reads otherwise (a non-unit axisangle
    axis, an extrinsic eulerseq, a hinge's ref before its body's last joint, a site's pos from a <default>, a site
    on a jointless body in a jointless body, a body weighed by its geoms, inertiafromgeom) differs in its mass matrix
    or points and is refused naming that construct (session 56's tester: refused with "e.g. masses MuJoCo infers from
    geoms" in a file of none, or points apart); check-model names it beside its gaps."""
    from planner.check import reading_differences

    text = CAPLER
    for old, new in edits:
        assert text.count(old) == 1
        text = text.replace(old, new)
    path = tmp_path / "variant.xml"
    path.write_text(text)
    robot = load_robot(path)
    differences = reading_differences(robot)
    assert any(d.startswith(named) for d in differences), differences
    if not named.startswith("joint"):  # check-model names them too (it printed the gaps alone; a ref is a difference)
        result = check_model(robot, samples=2)
        assert any(h.startswith(named) for h in result.mujoco.hints), result.mujoco.hints
        assert any(f.startswith("Pinocchio's parser reads otherwise: ") for f in result.failures)


SHANK_GEOM = '<geom name="shank_geom" type="capsule" fromto="0 0 0 0 0 -0.2" size="0.012"/>'
COLLIDING_SHANK_GEOM = SHANK_GEOM.replace("/>", ' contype="1"/>')
TETRAHEDRON = "v 0 0 0\nv 0.03 0 0\nv 0 0.03 0\nv 0 0 0.03\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"
COLLIDE = "Pinocchio's parser weighs only the geoms that collide"


@pytest.mark.parametrize("edits, cause", [
    ([], COLLIDE),  # the shank's geom collides with nothing (capler's <default>)
    ([('autolimits="true"', 'autolimits="true" discardvisual="true"')],
     COLLIDE + ' (contype or conaffinity nonzero), MuJoCo also those <compiler discardvisual="true"> discards'),
    ([(SHANK_GEOM, '<geom type="mesh" mesh="tip" contype="1"/>'),
      ("<worldbody>", '<asset><mesh name="tip" file="tip.obj"/></asset><worldbody>')],
     "Pinocchio's parser weighs a colliding mesh geom 1 kg whatever its size"),
    ([('autolimits="true"', 'autolimits="true" inertiagrouprange="0 1"'),
      (SHANK_GEOM, COLLIDING_SHANK_GEOM + '<geom type="box" size="0.02 0.02 0.02" group="3" contype="1"/>')],
     'MuJoCo weighs only the geoms of groups 0 to 1 (<compiler inertiagrouprange="0 1">)'),
    ([(SHANK_GEOM, COLLIDING_SHANK_GEOM + '<geom type="box" size="0.02 0.02 0.02" group="6" contype="1"/>')],
     'MuJoCo weighs only the geoms of groups 0 to 5 (<compiler inertiagrouprange="0 5">)'),  # (MuJoCo's default)
    ([(SHANK_GEOM, COLLIDING_SHANK_GEOM.replace("<geom", '<geom class="heavy"')),
      ("</default>", '<default class="heavy"><geom mass="5"/></default></default>')],
     "Pinocchio's parser does not read a <default>'s geom mass"),
    # an unused class's mass beside a colliding mesh, and a jointless child with its own <inertial> whose colliding
    # mesh weighs that in both readings: neither is named
    ([(SHANK_GEOM, '<geom type="mesh" mesh="tip" contype="1"/>'),
      ("</default>", '<default class="heavy"><geom mass="5"/></default></default>'),
      ("<worldbody>", '<asset><mesh name="tip" file="tip.obj"/></asset><worldbody>')],
     "Pinocchio's parser weighs a colliding mesh geom 1 kg whatever its size"),
    ([(SHANK_GEOM, SHANK_GEOM + '<body name="pad"><inertial pos="0 0 0" mass="0.1" diaginertia="1e-5 1e-5 1e-5"/>'
                                '<geom type="mesh" mesh="tip" contype="1"/></body>'),
      ("<worldbody>", '<asset><mesh name="tip" file="tip.obj"/></asset><worldbody>')], COLLIDE),
])
def test_a_body_mass_gap_names_the_cause_that_applies(tmp_path, edits, cause):
    """Capler's shank without <inertial>, weighed by MuJoCo and Pinocchio's parser apart for one cause each (a geom
    that collides with nothing, also under discardvisual; a colliding mesh, which Pinocchio weighs 1 kg; a geom
    outside inertiagrouprange, written or MuJoCo's default 0 to 5; a <default> class's geom mass): the body-mass hint
    names that cause and no other (not an unused class's mass, nor the mesh of a child weighed by its own
    <inertial>), and keeps the advice. It blamed the
    geoms that collide with nothing for all four, which sent a user looking for contype in a file of colliding
    geoms (session 69's tester)."""
    from planner.check import reading_differences

    text = CAPLER.replace(SHANK_INERTIAL, "")
    for old, new in edits:
        assert text.count(old) == 1
        text = text.replace(old, new)
    (tmp_path / "tip.obj").write_text(TETRAHEDRON)
    path = tmp_path / "variant.xml"
    path.write_text(text)
    hint = next(d for d in reading_differences(load_robot(path)) if d.startswith("body masses shank"))
    assert cause in hint and hint.endswith("give those bodies an <inertial>"), hint
    others = [COLLIDE, "discardvisual", "mesh", "inertiagrouprange", "<default>"]
    assert not [other for other in others if other not in cause and other in hint], hint


def test_parser_hints_come_with_the_gaps_they_explain(tmp_path):
    """The hints on Pinocchio's MJCF parser are given only beside a mass, bias or point gap, and for constructs that
    place what Pinocchio reads: an upper-case eulerseq with an euler on a geom only, beside a named gravcomp, gave the
    eulerseq hint for a difference it does not cause (session 56's review)."""
    from planner.check import reading_differences

    geom = '<geom name="base_geom" type="box"'
    assert CAPLER.count(geom) == 1 and CAPLER.count('<body name="thigh" pos="0 0 0">') == 1
    text = (CAPLER.replace('autolimits="true"', 'autolimits="true" eulerseq="XYZ"')
            .replace(geom, geom + ' euler="0.1 0.2 0.3"')
            .replace('<body name="thigh" pos="0 0 0">', '<body name="thigh" pos="0 0 0" gravcomp="1">'))
    path = tmp_path / "hinted.xml"
    path.write_text(text)
    differences = reading_differences(load_robot(path))
    assert any(d.startswith("body 'thigh': gravcomp 1") for d in differences), differences
    assert not any("eulerseq" in d for d in differences), differences


@pytest.mark.parametrize("joint, ref", [("base_z", "0.1"), ("knee", "0.3")])
def test_a_ref_on_a_bodys_last_joint_is_read_alike(tmp_path, joint, ref):
    """A joint's ref on its body's last joint (a slide or a hinge) is read by Pinocchio's parser as MuJoCo reads it
    (the points and masses agree at every q), so the file passes check-model and is not refused: a slide's was refused
    as "MuJoCo's slide joint reads and Pinocchio's does not" (session 56's tester)."""
    from planner.check import reading_differences

    old = f'<joint name="{joint}" type='
    assert CAPLER.count(old) == 1
    path = tmp_path / "ref.xml"
    path.write_text(CAPLER.replace(old, f'<joint name="{joint}" ref="{ref}" type='))
    robot = load_robot(path)
    assert reading_differences(robot) == ()
    result = check_model(robot, samples=2)
    assert result.passed, result.failures


def test_a_urdf_link_of_no_mass_keeps_its_inertia_for_mujoco(tmp_path):
    """A URDF link with a joint, mass 0 and an inertia of its own gets MASSLESS_LINK_KG for MuJoCo and keeps that
    inertia, as Pinocchio does: its inertia was replaced too, and check-model failed by the link's 1e-3 kg m^2 blaming
    masses MuJoCo infers or rescales."""
    path = tmp_path / "thigh0.urdf"
    text = (ROBOTS_DIR / "capler.urdf").read_text()
    assert text.count('<mass value="1.782"/>') == 1
    path.write_text(text.replace('<mass value="1.782"/>', '<mass value="0"/>'))
    result = check_model(load_robot(path), samples=2)
    assert result.passed, result.failures


def test_a_urdf_link_with_a_collision_and_no_inertial_stays_massless_for_mujoco(tmp_path):
    """A URDF link without <inertial> is massless (the URDF spec, Pinocchio), also when it has a primitive <collision>
    (a sensor on a fixed joint): MuJoCo inferred 0.113 kg from the sphere, and every plan of the file was refused
    ("mass matrix differs by up to 0.113")."""
    path = tmp_path / "sensor.urdf"
    path.write_text((ROBOTS_DIR / "capler.urdf").read_text().replace("</robot>", (
        '<link name="sensor"><collision><geometry><sphere radius="0.03"/></geometry></collision></link>'
        '<joint name="mount" type="fixed"><parent link="foot"/><child link="sensor"/></joint></robot>')))
    result = check_model(load_robot(path), samples=2)
    assert result.passed, result.failures


def test_an_included_compiler_is_named_as_a_possible_cause(tmp_path):
    """An MJCF file whose <include> holds <compiler angle="radian">: MuJoCo reads a body's euler="0 0.3 0" in
    radians, Pinocchio (which reads no included <compiler>) in degrees. The differences found end with the include
    as their possible cause (they blamed "masses MuJoCo infers from geoms" in a file without geoms)."""
    from planner.check import reading_differences

    (tmp_path / "comp.xml").write_text('<mujoco><compiler angle="radian"/></mujoco>')
    path = tmp_path / "tilted.xml"
    path.write_text('<mujoco><include file="comp.xml"/><worldbody><body name="base"><joint name="x" type="slide" '
                    'axis="1 0 0"/><inertial pos="0 0 0" mass="2" diaginertia="0.01 0.01 0.01"/><body name="leg" '
                    'euler="0 0.3 0"><joint name="hip" type="hinge" axis="0 1 0"/><inertial pos="0 0 -0.2" mass="0.5" '
                    'diaginertia="0.005 0.005 0.001"/><site name="foot" pos="0 0 -0.4"/></body></body></worldbody>'
                    '</mujoco>')
    found = reading_differences(load_robot(path))
    assert len(found) >= 2 and found[-1].startswith("the file has an <include>, whose <compiler> and <default>"), found


def test_check_model_names_an_included_compiler_as_a_possible_cause(tmp_path):
    """check-model's "vs MuJoCo" line (and its failures) ends with the <include> as the possible cause of the gaps it
    measures: a radian file whose <compiler> is included was FAILED there without a cause, while `plan` named the
    include and sent the user to check-model."""
    (tmp_path / "common_rad.xml").write_text('<mujocoinclude><compiler angle="radian" autolimits="true"/>'
                                             '</mujocoinclude>')
    path = tmp_path / "rad_inc.xml"
    path.write_text('<mujoco><include file="common_rad.xml"/><default><geom contype="0" conaffinity="0"/></default>'
                    '<worldbody><geom name="ground" type="plane" size="5 1 0.1" contype="1" conaffinity="1"/>'
                    '<body name="base" pos="0 0 0.4"><joint name="base_x" type="slide" axis="1 0 0"/><joint '
                    'name="base_z" type="slide" axis="0 0 1"/><inertial pos="0 0 0" mass="4" '
                    'diaginertia="0.01 0.01 0.01"/><body name="thigh" euler="0 0.3 0"><joint name="hip" type="hinge" '
                    'axis="0 1 0" range="-1 1"/><inertial pos="0 0 -0.1" mass="1.5" diaginertia="0.005 0.005 0.0005"/>'
                    '<site name="foot" pos="0 0 -0.2"/></body></body></worldbody><actuator><motor name="hm" '
                    'joint="hip" ctrlrange="-30 30"/></actuator></mujoco>')
    result = check_model(load_robot(path), samples=2)
    assert not result.passed
    assert "Pinocchio's parser reads otherwise: the file has an <include>, whose <compiler>" in result.report(), \
        result.report()
    assert any("the file has an <include>" in f for f in result.failures), result.failures


def test_an_included_default_is_named_with_the_passive_forces_it_gives(tmp_path):
    """A file whose <include> holds only a <default> joint damping differs from Pinocchio's reading in its passive
    forces alone (no mass, bias or point gap): the include is named as their possible cause too, by check-model and by
    the reading check plan and simulate run (it was named only beside a mass, bias or point gap)."""
    from planner.check import reading_differences

    (tmp_path / "damped.xml").write_text('<mujocoinclude><default><joint damping="3"/></default></mujocoinclude>')
    path = tmp_path / "robot.xml"
    path.write_text('<mujoco><include file="damped.xml"/><worldbody><geom name="ground" type="plane" size="5 1 0.1"/>'
                    '<body name="b" pos="0 0 0.4"><joint name="x" type="slide" axis="1 0 0"/><joint name="z" '
                    'type="slide" axis="0 0 1"/><inertial pos="0 0 0" mass="1" diaginertia="0.01 0.01 0.01"/>'
                    '<site name="foot"/></body></worldbody></mujoco>')
    robot = load_robot(path)
    differences = reading_differences(robot)
    assert any(d.startswith("passive forces") for d in differences), differences
    assert differences[-1].startswith("the file has an <include>"), differences
    assert any("the file has an <include>" in f for f in check_model(robot, samples=2).failures)


def test_mujoco_prints_no_warning_of_its_own_when_a_robot_is_read(tmp_path, capfd, monkeypatch):
    """Reading a robot file MuJoCo warns about (a deprecated settotalmass) prints nothing raw on stderr and writes no
    MUJOCO_LOG.TXT into the working directory (both went through -q); the check says it as a Python warning."""
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "variant.xml"
    path.write_text(POINT_MASS.replace(OPTION, '<compiler settotalmass="2"/>' + OPTION))
    with pytest.warns(UserWarning, match="settotalmass"):
        check_model(load_robot(path), samples=2)
    assert "settotalmass" not in capfd.readouterr().err and not (tmp_path / "MUJOCO_LOG.TXT").exists()


def test_urdf_readings_mujoco_makes_otherwise_are_refused(tmp_path):
    """A URDF planar joint (Pinocchio: x-y about z; MuJoCo: its own three joints) and a URDF <mujoco> block's gravity
    (MuJoCo applies it, Pinocchio does not) fail check-model and are refused by a task's check; the planar joint's
    check said PASSED ("skipped"). A revolute joint with <limit> but no lower and upper (Pinocchio: locked at 0;
    MuJoCo: unlimited) is refused when the file is read, naming the fix."""
    from planner.check import reading_differences

    urdf = (ROBOTS_DIR / "capler.urdf").read_text()
    gravity = tmp_path / "gravity.urdf"
    gravity.write_text(urdf.replace("</robot>", '<mujoco><option gravity="0 0 -3"/></mujoco></robot>'))
    said = reading_differences(load_robot(gravity))
    assert "gravity [0.0, 0.0, -3.0] m/s^2 in MuJoCo (<option gravity>), [0.0, 0.0, -9.81] in Pinocchio" in said, said
    assert any(d.startswith("bias forces") for d in said)
    assert not check_model(load_robot(gravity), samples=1).passed
    hip = '<limit lower="-1.1780972450961724" upper="1.1780972450961724" effort="60" velocity="0"/>'
    assert urdf.count(hip) == 1
    unlimited = tmp_path / "unlimited.urdf"
    unlimited.write_text(urdf.replace(hip, '<limit effort="60" velocity="0"/>'))
    with pytest.raises(RobotFileError,
                       match=r"joint 'hip' \(0\): its <limit lower> equals its upper .* give lower < upper"):
        load_robot(unlimited)


@pytest.mark.parametrize("old, new", [
    ('<motor name="force_x" joint="x"', '<motor name="force_x" damping="0.3" joint="x"'),
    (X_JOINT, '<joint name="x" type="slide" axis="1 0 0" range="-1 1" margin="0.2"/>'),
    ("</worldbody>", '</worldbody><tendon><fixed name="t" damping="5"><joint joint="x" coef="1"/></fixed></tendon>'),
])
def test_terms_the_file_disables_are_no_difference(tmp_path, old, new):
    """A motor's or tendon's damping under <flag damper="disable"/> and a limit's margin under <flag limit="disable"/>
    are no reading difference: MuJoCo applies none of them (they were named, and the file refused, though its
    passive forces were 0 and no limit row existed), as Robot.passive leaves out the joints' disabled terms."""
    from planner.check import reading_differences

    flag = "limit" if "margin" in new else "damper"
    assert POINT_MASS.count(old) == 1 and POINT_MASS.count(OPTION) == 1
    path = tmp_path / "variant.xml"
    path.write_text(POINT_MASS.replace(old, new).replace(OPTION, OPTION + f'<option><flag {flag}="disable"/></option>'))
    robot = load_robot(path)
    assert reading_differences(robot) == ()
    path.write_text(POINT_MASS.replace(old, new))  # the same file with the term on: named
    assert reading_differences(load_robot(path)) != ()


def test_a_urdfs_mujoco_boundmass_and_a_frame_around_the_root_are_named(tmp_path):
    """A URDF's <mujoco><compiler boundmass> (MuJoCo raises the massless links, Pinocchio's URDF parser not) is
    named beside the mass gap, and an MJCF <frame> around the root body, which Pinocchio's parser fails on ("No such
    node (body)"), is named in the parse error (session 61's tester: neither said a cause)."""
    from planner.check import reading_differences

    urdf = tmp_path / "capler.urdf"
    urdf.write_text((ROBOTS_DIR / "capler.urdf").read_text().replace(
        "</robot>", '<mujoco><compiler boundmass="0.6"/></mujoco></robot>'))
    assert any(d.startswith('<mujoco><compiler boundmass="0.6">: MuJoCo raises lighter masses to it')
               for d in reading_differences(load_robot(urdf)))
    # (regression tester: boundmass="0" is MuJoCo's "no bound", and was named)
    urdf.write_text((ROBOTS_DIR / "capler.urdf").read_text().replace(
        "</robot>", '<mujoco><compiler boundmass="0" boundinertia="0.01"/></mujoco></robot>'))
    differences = reading_differences(load_robot(urdf))
    assert any("boundinertia" in d for d in differences) and not any("boundmass" in d for d in differences)
    agreeing = tmp_path / "agreeing.xml"  # a second <compiler> that repeats the first is no cause (it was named first)
    compiler = '<compiler angle="radian" autolimits="true"/>'
    agreeing.write_text(CAPLER.replace(compiler, compiler + '<compiler angle="radian"/>').replace(
        SHANK, SHANK[:-1] + ' axisangle="0 2 0 0.3">'))
    differences = reading_differences(load_robot(agreeing))
    assert any("axisangle" in d for d in differences) and not any("<compiler>" in d for d in differences)
    framed = tmp_path / "framed.xml"
    framed.write_text(CAPLER.replace('<body name="base"', '<frame pos="0 0 0.5"><body name="base"').replace(
        "</worldbody>", "</frame></worldbody>"))
    with pytest.raises(RobotFileError, match=r"No such node \(body\) \(the file has <frame> elements, whose bodies"):
        load_robot(framed)
    classy = tmp_path / "classy.xml"  # a harmless <frame> beside an unknown class: MuJoCo's cause, not the frame's
    classy.write_text(CAPLER.replace('<geom name="base_geom"', '<geom class="nosuch" name="base_geom"').replace(
        "</worldbody>", '<frame pos="1 0 0"><site name="marker"/></frame></worldbody>'))
    with pytest.raises(RobotFileError, match="unknown default class name 'nosuch'"):
        load_robot(classy)


def test_check_model_lists_the_ranges_with_units_and_a_degree_files_degrees(tmp_path):
    """check-model lists each coordinate's range as the planner reads it, with its unit, and for a file MuJoCo
    reads in degrees (no <compiler angle="radian">) the file's own numbers as degrees: a file of radian numbers
    without angle="radian" (hip +-1.18 degrees) passed check-model without a word of its ranges (session 61)."""
    plain = check_model(load_robot("capler"), samples=1)
    assert plain.ranges[2] == "[-1.178097245, 1.178097245] rad" and plain.ranges[0] == "[-inf, inf] m"
    assert "ranges:       base_x [-inf, inf] m" in plain.report() and plain.to_json()["ranges"] == list(plain.ranges)
    forgot = tmp_path / "forgot.xml"
    forgot.write_text(CAPLER.replace('angle="radian" ', ""))
    ranges = check_model(load_robot(forgot), samples=1).ranges
    assert ranges[2] == "[-0.02056167584, 0.02056167584] rad (the file's -1.178097245 1.178097245 degrees)"


SEED = 0  # the seeded states below
EXACT_PRODUCT = 1e-12  # one product of numbers ~1, computed two ways


def test_a_margin_on_an_unlimited_joint_is_no_difference(robot_variant):
    """A joint margin acts on a limit only (MuJoCo: no range, no limit constraint, margin or not): a file whose
    <default><joint margin="0.2"/> reaches an unlimited slide reads as MuJoCo reads it, no named difference, and
    check-model passes. A check that named every margin (its limited test dropped) refused such files (a mutant of
    session 65's mutation testing); the limited joint's margin stays named."""
    robot = robot_variant(POINT_MASS, X_JOINT, '<joint name="x" type="slide" axis="1 0 0" margin="0.2"/>')
    assert robot.q_lower[0] == -np.inf and robot.q_upper[0] == np.inf
    assert reading_differences(robot) == ()
    assert check_model(robot, samples=2).passed
    limited = robot_variant(POINT_MASS, X_JOINT, '<joint name="x" type="slide" axis="1 0 0" range="-1 1" '
                            'margin="0.2"/>', "limited.xml")
    assert any(d.startswith("joint 'x': margin 0.2") for d in reading_differences(limited))


def test_a_wrong_point_rotation_fails_the_check(monkeypatch):
    """check-model compares each named point's rotation with Pinocchio's oMf (not only its position): a dynamics whose
    point_rotation is transposed (Capler's foot turns with the hip and knee) fails with max_err_frames of order 1. With
    the rotation left out of the comparison (a mutant of session 65's mutation testing), a wrong rotation passed."""
    import casadi as ca

    from planner.dynamics import Dynamics

    right = Dynamics.point_rotation

    def transposed(self, name):
        f = right(self, name)
        q = ca.SX.sym("q", self.nq)
        return ca.Function(f"{f.name()}_t", [q], [f(q).T])

    robot = load_robot("capler")
    assert check_model(robot, samples=3).passed
    monkeypatch.setattr(Dynamics, "point_rotation", transposed)
    result = check_model(robot, samples=3)
    assert not result.passed and result.max_err_frames > 0.1, result.max_errors


def test_random_states_cover_both_signs_of_an_unbounded_coordinate():
    """random_state draws a coordinate without a range uniformly in [-1, 1] (its docstring), both signs: of 200 seeded
    states, Capler's base x and z (no range in capler.xml) reach below -0.9 and above 0.9. Drawn in [0, 1] (a mutant of
    session 65's mutation testing), check-model never compared the dynamics at a negative base coordinate; test_seeded
    checked |q| <= 1 only."""
    robot = load_robot("capler")
    rng = np.random.default_rng(SEED)
    qs = np.array([random_state(robot.model, rng)[0] for _ in range(200)])
    assert np.all(qs[:, :2].min(axis=0) < -0.9) and np.all(qs[:, :2].max(axis=0) > 0.9)


def test_the_passive_gap_is_mujocos_passive_force(robot_variant):
    """check-model's mujoco.max_err_passive is the largest MuJoCo passive force at its states: a slide with damping 5
    at the seeded velocities gives 5 max |v_x| (ground truth: MuJoCo's damper, qfrc_passive = -b v). A gap read as 0
    (a mutant of session 65's mutation testing) hid it in the report, which printed "passive 0" next to "damping 5"."""
    robot = robot_variant(POINT_MASS, X_JOINT, '<joint name="x" type="slide" axis="1 0 0" damping="5"/>')
    samples = 4
    result = check_model(robot, samples=samples, seed=SEED)
    rng = np.random.default_rng(SEED)
    v_x = [random_state(robot.model, rng)[1][0] for _ in range(samples)]
    # MuJoCo's damper force against 5 v: one product, rounding only
    assert result.mujoco.max_err_passive == pytest.approx(5.0 * max(abs(v) for v in v_x), rel=EXACT_PRODUCT)
    assert not result.passed


def test_a_negative_gears_force_range_is_compared_with_the_joints(robot_variant):
    """Two motors on Capler's hip, one of gear -2 with ctrlrange [0, 10] (forces [-20, 0]: a negative gear swaps its
    ends) and one of gear 1 with [0, 10], and the joint's actuatorfrcrange [-15, 15]: MuJoCo clamps their summed force,
    which reaches -20, so the reading check names the range (ground truth: MuJoCo's qfrc_actuator at the controls' ends
    is -15, not the planner's B u = -20). Read as gear * lower (a mutant of session 65's mutation testing) the reach was
    [0, 10] and the file passed, to be planned with a force MuJoCo's replay clamps."""
    import mujoco

    hip = '<joint name="hip" type="hinge" axis="0 1 0"'
    assert CAPLER.count(hip) == 1
    text = CAPLER.replace(hip, hip + ' actuatorfrcrange="-15 15"')
    old = '<motor name="hip_motor" joint="hip" gear="1" ctrlrange="-60 60"/>'
    new = ('<motor name="hip_motor" joint="hip" gear="-2" ctrlrange="0 10"/>'
           '<motor name="hip_motor2" joint="hip" gear="1" ctrlrange="0 10"/>')
    robot = robot_variant(text, old, new)
    mj = mujoco.MjModel.from_xml_path(str(robot.path))
    data = mujoco.MjData(mj)
    names = [a.name for a in robot.actuators]
    u = np.zeros(robot.nu)
    u[names.index("hip_motor")] = 10.0
    mujoco.mj_forward(mj, data)
    data.ctrl[:] = u
    mujoco.mj_forward(mj, data)
    dof = robot.actuators[names.index("hip_motor")].dof
    assert (robot.actuation_matrix @ u)[dof] == pytest.approx(-20.0) and data.qfrc_actuator[dof] == pytest.approx(-15.0)
    assert any(d.startswith("joint 'hip': actuatorfrcrange [-15, 15] narrower than its motors' force range [-20, 10]")
               for d in reading_differences(robot)), reading_differences(robot)


FAKE_CLOCK_REL = 1e-9  # a fake clock's 200 steps of 1e-6 s summed and divided: round-off only


def test_an_evaluations_time_is_one_calls_not_the_totals(monkeypatch):
    """Timing's mass_us, bias_us and jacobian_us are one evaluation's time [us]: a call that advances a fake clock by
    1 us reads 1 us (session 66's mutation testing: the 200 calls' total read 200 us, with every test green)."""
    from planner import check

    clock = [0.0]
    monkeypatch.setattr(check.time, "perf_counter", lambda: clock[0])

    def one_microsecond():
        clock[0] += 1e-6

    assert check._mean_us(one_microsecond) == pytest.approx(1.0, rel=FAKE_CLOCK_REL)


def test_the_sites_error_is_the_worst_sites(robot_variant):
    """Capler with its foot site placed by a <default class> pos (MuJoCo applies it, Pinocchio's parser does not: the
    foot 0.25 m apart along the shank) and its knee site as it is: max_err_sites is the foot's gap, at least
    0.25 / sqrt(2) m in x or z whatever the shank's angle (session 66's mutation testing: the best site's 0 was
    reported with every test green)."""
    text = (ROBOTS_DIR / "capler.xml").read_text()
    assert text.count("<default>") == 1
    text = text.replace("<default>", '<default><default class="off"><site pos="0 0 -0.25"/></default>')
    robot = robot_variant(text, '<site name="foot" pos="0 0 -0.2" size="0.012"/>',
                          '<site name="foot" class="off" size="0.012"/>')
    result = check_model(robot, samples=3)
    assert result.mujoco.max_err_sites >= 0.25 / np.sqrt(2)
    assert any(f.startswith("mujoco_max_err_sites") for f in result.failures), result.failures


def test_the_report_gives_each_mujoco_gap_its_own_number(robot_variant):
    """The report's "vs MuJoCo" line puts each quantity's own gap after its name: the point mass with a 2 kg body that
    MuJoCo weighs by its geom and Pinocchio's parser does not, where the mass and bias gaps differ (session 66's
    mutation testing: the two numbers swapped, with every test green)."""
    old = '<site name="point"'
    load = '<body name="load"><geom type="sphere" size="0.02" mass="2"/></body>'
    result = check_model(robot_variant(POINT_MASS, old, load + old), samples=2)
    gaps = result.mujoco
    assert f"{gaps.max_err_mass:.1e}" != f"{gaps.max_err_bias:.1e}"
    line = next(line for line in result.report().splitlines() if line.strip().startswith("vs MuJoCo"))
    words = line.split(":", 1)[1].split(";")[0].split()
    shown = dict(zip(words[::2], words[1::2]))
    assert (shown["mass"], shown["bias"]) == (f"{gaps.max_err_mass:.1e}", f"{gaps.max_err_bias:.1e}")


def test_without_a_foot_the_last_point_is_timed(robot_variant):
    """With no point named like "foot", the Jacobian timed is the last named point's, as check_model's docstring says
    (session 66's mutation testing: the first point's was timed with every test green)."""
    robot = robot_variant((ROBOTS_DIR / "capler.xml").read_text(), '<site name="foot"', '<site name="toe"')
    assert not any("foot" in point for point in robot.points) and len(robot.points) >= 2
    assert check_model(robot, samples=1).timing.point == robot.points[-1] == "toe"


# A free body placed and turned in the file, with a hinge (its range in radians) and an off-axis mass below it.
FREE_ARM = """<mujoco><compiler angle="radian"/><worldbody>
<body name="b" pos="0.1 -0.2 0.5" quat="0.9659 0.2588 0 0"><freejoint name="root"/>
<inertial pos="0.01 0 0" mass="1" diaginertia=".01 .02 .025"/>
<body name="arm" pos="0.2 0 0"><joint name="hip" type="hinge" axis="0 1 0" range="-0.5 0.5"/>
<inertial pos="0 0.03 -0.1" mass="0.3" diaginertia=".002 .003 .001"/><site name="foot" pos="0 0 -0.2"/></body>
</body></worldbody></mujoco>"""
ROUND_TRIP = 1e-12  # a pose through an SE3 product, a quaternion and back: rounding of numbers ~1


def test_a_floating_robots_report_names_its_velocities_and_its_joints_ranges(tmp_path):
    """check-model's report on a free-base robot (nq 8 > nv 7) heads its names "velocities" (they are the nv
    velocity coordinates; "coordinates" contradicted the header's nq) and lists the hinge's range, which was dropped
    with the free joint's; JSON `ranges` runs along dof_names with "" for the free joint's six."""
    path = tmp_path / "free_arm.xml"
    path.write_text(FREE_ARM)
    result = check_model(load_robot(path), samples=1)
    text = result.report()
    assert (result.nq, result.nv) == (8, 7) and "  velocities:   root_0, root_1" in text
    assert "  ranges:       hip [-0.5, 0.5] rad\n" in text
    assert result.to_json()["ranges"] == [""] * 6 + ["[-0.5, 0.5] rad"]


def test_the_free_joint_map_is_mujocos_reading(tmp_path):
    """_free_joint_map's state map, checked against MuJoCo itself: a seeded (q, v) mapped to MuJoCo's coordinates and
    back is the same state (the quaternion up to its sign), and in MuJoCo's coordinates the mapped mass matrix and bias
    forces of a placed, turned free body with a hinge are MuJoCo's mj_fullM and qfrc_bias (check-model's free-joint
    comparison stands on this map: a wrong frame or a missing velocity-map derivative would compare wrong numbers)."""
    import mujoco

    from planner.check import _free_joint_map, _in_mujoco_coordinates
    from planner.dynamics import Dynamics

    path = tmp_path / "free_arm.xml"
    path.write_text(FREE_ARM)
    robot = load_robot(path)
    mj, to_mujoco, to_pinocchio = _free_joint_map(robot)
    mass, bias, _ = _in_mujoco_coordinates(Dynamics(robot), to_pinocchio)
    data, rng = mujoco.MjData(mj), np.random.default_rng(SEED)
    for _ in range(3):
        q, v = random_state(robot.model, rng)
        qm, vm = to_mujoco(q, v)
        back, v_back, _, _ = to_pinocchio(qm, vm)
        sign = np.sign(back[3:7] @ q[3:7])
        assert np.allclose(back, np.r_[q[:3], sign * q[3:7], q[7:]], rtol=0.0, atol=ROUND_TRIP)
        assert np.allclose(v_back, v, rtol=0.0, atol=ROUND_TRIP)
        data.qpos[:], data.qvel[:] = qm, vm
        mujoco.mj_forward(mj, data)
        full = np.zeros((mj.nv, mj.nv))
        mujoco.mj_fullM(mj, data, full)
        assert np.allclose(mass(qm), full, rtol=0.0, atol=TOL_CHECK)
        assert np.allclose(bias(qm, vm), data.qfrc_bias, rtol=0.0, atol=TOL_CHECK)


def test_the_skip_reason_names_each_joints_type(tmp_path):
    """When MuJoCo's reading is skipped, the reason names each joint that is no hinge or slide with its type ("free
    joint root, ball joint hip", where "free/ball joints root, hip" left the user to guess which is which, and a ball
    joint reaches it with the pinocchio.casadi backend only), and a --floating URDF's says that the free joint
    check-model adds to MuJoCo's root body did not give Pinocchio's coordinates (Capler's root link is world): "is not in the file MuJoCo reads" alone no longer said why, as files with one added are compared."""
    from planner.check import SKIPPED, _compile

    path = tmp_path / "ball.xml"
    path.write_text(FREE_ARM.replace('<joint name="hip" type="hinge" axis="0 1 0" range="-0.5 0.5"/>',
                                     '<joint name="hip" type="ball"/>'))
    _, kind, why = _compile(load_robot(path))  # (the symbolic dynamics refuses the ball joint; pinocchio.casadi not)
    assert kind == SKIPPED and why.startswith("free joint root, ball joint hip: MuJoCo's coordinates differ"), why
    skipped = check_model(load_robot(ROBOTS_DIR / "capler.urdf", floating=True), samples=1).mujoco_skipped
    assert "a free joint added to MuJoCo's root body does not give Pinocchio's coordinates: the root link" in skipped


# A base with two identical legs whose joints the file lists out of their names' order (z_hip before a_hip), no motors
INERTIAL = ('<inertial><origin xyz="{}"/><mass value="{}"/>'
            '<inertia ixx="{i}" iyy="{i}" izz="{i}" ixy="0" ixz="0" iyz="0"/></inertial>')
LEG_JOINT = ('<joint name="{}" type="revolute"><parent link="base"/><child link="{}"/><origin xyz="0.2 0 0"/>'
             '<axis xyz="0 1 0"/><limit lower="-1" upper="1" effort="0" velocity="10"/></joint>')
TWO_LEGS = ('<link name="base">' + INERTIAL.format("0 0 0", 2, i=0.1) + "</link>"
            + "".join(f'<link name="leg_{s}">' + INERTIAL.format("0 0 -0.1", 0.5, i=0.01) + "</link>" for s in "za")
            + LEG_JOINT.format("z_hip", "leg_z") + LEG_JOINT.format("a_hip", "leg_a"))


def test_floating_urdf_siblings_out_of_name_order_fail_on_the_order(tmp_path):
    """A --floating URDF whose sibling branches are not listed in their joints' name order fails check-model with the
    order and its fix, as without --floating: it PASSED when the legs were identical, MuJoCo's z_hip compared with
    Pinocchio's a_hip (the free-joint comparison skipped the order check), so a wrong-joint replay went unflagged."""
    path = tmp_path / "legs.urdf"
    path.write_text(f'<robot name="legs">{TWO_LEGS}</robot>')
    result = check_model(load_robot(path, floating=True), samples=1)
    assert not result.passed and result.mujoco is None
    (failure,) = result.failures
    assert failure.startswith("MuJoCo orders the joints") and failure.endswith(
        "(Pinocchio's URDF parser orders sibling branches by their joints' names, MuJoCo as the file lists "
        "them: write the <joint> elements of each link's children in the order of their names)"), failure


def test_a_floating_urdf_rooted_at_world_is_skipped_with_why(tmp_path):
    """A --floating URDF whose root link is `world` (MuJoCo's world body, so its free joint moves the next link, at
    the fixed joint's offset, where Pinocchio's free flyer moves `world`) skips MuJoCo saying so: it FAILED on mass,
    bias and sites gaps the file does not have. The same robot rooted at another link is still compared and passes."""
    fixed = ('<joint name="fix" type="fixed"><parent link="{}"/><child link="base"/>'
             '<origin xyz="0.05 0.02 0.3" rpy="0.3 0.2 0.1"/></joint>')
    for root, compared in (("world", False), ("footprint", True)):
        path = tmp_path / f"{root}.urdf"
        path.write_text(f'<robot name="legs"><link name="{root}"/>{fixed.format(root)}'
                        f'{TWO_LEGS.replace("a_hip", "b_hip").replace("z_hip", "a_hip")}</robot>')  # in name order
        result = check_model(load_robot(path, floating=True), samples=1)
        assert result.passed, result.failures
        assert (result.mujoco is not None) is compared
        if not compared:
            assert "the root link is named world, which MuJoCo reads as its world body" in result.mujoco_skipped


def test_a_floating_skip_names_only_the_cause_that_applies(tmp_path):
    """Each --floating URDF MuJoCo cannot be compared with names its own cause, not every possible one (the skip
    listed "e.g. joints of its own, or the root link is named world" for both, a reviewer's note): capler.urdf's root
    link is world, so MuJoCo's root body is carriage (which also has the slide base_x: named for the world, its
    cause, not for the joint, a second reviewer); a robot whose root link `world` is fixed to its base gets the free
    joint on the link after it."""
    world = "the root link is named world, which MuJoCo reads as its world body"
    capler = check_model(load_robot(ROBOTS_DIR / "capler.urdf", floating=True), samples=1).mujoco_skipped
    assert world in capler and "'carriage'" in capler and "joints of its own" not in capler, capler
    path = tmp_path / "world.urdf"
    path.write_text('<robot name="legs"><link name="world"/><joint name="fix" type="fixed"><parent link="world"/>'
                    f'<child link="base"/><origin xyz="0.05 0.02 0.3"/></joint>{TWO_LEGS}</robot>')
    rooted = check_model(load_robot(path, floating=True), samples=1).mujoco_skipped
    assert world in rooted and "joints of its own" not in rooted, rooted
