"""planner.dynamics: the CasADi functions against Pinocchio, MuJoCo, finite differences and known values."""
from __future__ import annotations

import functools
from pathlib import Path

import casadi as ca
import mujoco
import numpy as np
import pinocchio as pin
import pytest

from planner.check import check_model, random_state
from planner.dynamics import Dynamics, UnsupportedJointError
from planner.errors import UnknownNameError
from planner.model import ROBOTS_DIR, Robot, RobotFormat, load_robot

# Same algorithms in double precision: differences are rounding, observed <= 3e-13 (Talos h entries ~ 1e3 N m).
TOL_PINOCCHIO = 1e-10
# Independent implementation (MuJoCo's CRB/RNE on the same file): rounding only, observed <= 1e-13.
TOL_MUJOCO = 1e-10
# capler.xml and capler.urdf give the same numbers (composite vs two prismatic joints): rounding only.
TOL_SAME_ROBOT = 1e-12
# Forward dynamics solves with M: the rounding above times cond(M) (up to 2.5e4, Solo-12); observed <= 3e-12 relative.
TOL_FORWARD = 1e-8
# Central differences with step FD_STEP: truncation ~ FD_STEP^2 |f'''| ~ 1e-12, rounding ~ eps |f| / FD_STEP ~ 1e-10.
FD_STEP = 1e-6
TOL_FD = 1e-8
SAMPLES = 5  # random states per robot and test
SEED = 0

PROJECT_ROBOTS = ["capler.xml", "capler.urdf", "biped.xml", "point_mass.xml"]
ERD_FAST = ["ur5", "panda", "solo12", "bolt"]


@functools.cache
def dynamics(robot: Robot) -> Dynamics:
    return Dynamics(robot)


@pytest.fixture(scope="module")
def robot_of(erd_robot, tmp_path_factory):
    """robot_of(spec): a project robot by file name (robots/...), an example-robot-data robot by short
    name, or a synthetic robot ("all_joints", "mjcf_composite"); each loaded once per module."""

    @functools.cache
    def get(spec: str) -> Robot:
        if spec == "all_joints":
            return _all_joints_robot()
        if spec == "mjcf_composite":  # MuJoCo and Pinocchio read files
            path = tmp_path_factory.mktemp("mjcf") / "composite.xml"
            path.write_text(_MJCF_COMPOSITE)
            return load_robot(path)
        return load_robot(ROBOTS_DIR / spec) if "." in spec else erd_robot(spec)

    return get


def _states(robot: Robot, n: int = SAMPLES, seed: int = SEED):
    rng = np.random.default_rng(seed)
    return [random_state(robot.model, rng) for _ in range(n)]


def _np(x) -> np.ndarray:
    return np.array(x, dtype=float).squeeze()


# ---------------------------------------------------------------------------------------------
# Synthetic robots: every supported joint type, unaligned axes, composites, armature


_URDF_JOINTS = [  # (URDF type, axis); parent of joint k is link k // 2 (a branching tree)
    ("revolute", "1 0 0"),
    ("revolute", "0 0.6 0.8"),
    ("continuous", "0 1 0"),
    ("continuous", "0.48 0.6 0.64"),
    ("prismatic", "0 0 1"),
    ("prismatic", "0.6 0 0.8"),
    ("planar", "0 0 1"),
]


def _inertial(rng) -> str:
    A = rng.normal(size=(3, 3))
    I = A @ A.T * 0.01 + 0.01 * np.eye(3)
    xyz, rpy = rng.uniform(-0.2, 0.2, 3), rng.uniform(-1, 1, 3)
    return (
        f'<inertial><origin xyz="{xyz[0]} {xyz[1]} {xyz[2]}" rpy="{rpy[0]} {rpy[1]} {rpy[2]}"/><mass value="{rng.uniform(0.5, 2)}"/>'
        f'<inertia ixx="{I[0, 0]}" ixy="{I[0, 1]}" ixz="{I[0, 2]}" iyy="{I[1, 1]}" iyz="{I[1, 2]}" izz="{I[2, 2]}"/></inertial>'
    )


def _all_joints_robot() -> Robot:
    """Free-flying tree with every supported joint type; one composite (prismatic unaligned, revolute
    unaligned, planar, unbounded) added programmatically; random placements, inertias and armature."""
    rng = np.random.default_rng(1)
    links = ['<link name="link0">' + _inertial(rng) + "</link>"]
    joints = []
    for k, (kind, axis) in enumerate(_URDF_JOINTS):
        links.append(f'<link name="link{k + 1}">{_inertial(rng)}</link>')
        xyz, rpy = rng.uniform(-0.3, 0.3, 3), rng.uniform(-1, 1, 3)
        limit = '<limit lower="-1" upper="1" effort="10" velocity="10"/>' if kind in ("revolute", "prismatic") else ""
        joints.append(
            f'<joint name="j{k + 1}" type="{kind}"><parent link="link{k // 2}"/><child link="link{k + 1}"/>'
            f'<origin xyz="{xyz[0]} {xyz[1]} {xyz[2]}" rpy="{rpy[0]} {rpy[1]} {rpy[2]}"/><axis xyz="{axis}"/>{limit}</joint>'
        )
    urdf = '<robot name="all_joints">' + "".join(links + joints) + "</robot>"
    model = pin.buildModelFromXML(urdf, pin.JointModelFreeFlyer())

    def placement() -> pin.SE3:
        return pin.SE3(pin.exp3(rng.uniform(-1, 1, 3)), rng.uniform(-0.3, 0.3, 3))

    composite = pin.JointModelComposite()
    composite.addJoint(pin.JointModelPrismaticUnaligned(0.0, 0.6, 0.8), placement())
    composite.addJoint(pin.JointModelRevoluteUnaligned(0.8, 0.0, 0.6), placement())
    composite.addJoint(pin.JointModelPlanar(), placement())
    composite.addJoint(pin.JointModelRUBZ(), placement())
    jid = model.addJoint(model.njoints - 1, composite, placement(), "composite")  # on the last joint: Pinocchio needs depth-first order
    model.appendBodyToJoint(jid, pin.Inertia(1.3, rng.uniform(-0.2, 0.2, 3), np.diag([0.02, 0.03, 0.04])), pin.SE3.Identity())
    model.addFrame(pin.Frame("composite_tip", jid, placement(), pin.FrameType.OP_FRAME))
    model.armature = rng.uniform(0.0, 0.1, model.nv)
    kinds = {j.shortname() for j in model.joints}
    assert {"JointModelRevoluteUnboundedUnaligned", "JointModelPrismaticUnaligned", "JointModelPlanar", "JointModelRUBY"} <= kinds
    points = tuple(f.name for f in model.frames if f.type in (pin.FrameType.BODY, pin.FrameType.OP_FRAME))
    return Robot(Path("all_joints.urdf"), RobotFormat.URDF, model, (), points, (), "")


_MJCF_COMPOSITE = """
<mujoco model="composite">
  <option gravity="0 0 -9.81"/>
  <worldbody>
    <body name="a" pos="0.1 -0.2 0.3" quat="0.9 0.1 0.3 0.2">
      <joint name="s" type="slide" axis="1 0 1"/>
      <joint name="h1" type="hinge" axis="0.3 0.4 0.5" pos="0.1 0 0"/>
      <joint name="h2" type="hinge" axis="0 1 0" pos="0 0.2 0"/>
      <inertial pos="0.05 0.02 -0.1" mass="2" fullinertia="0.05 0.04 0.03 0.004 -0.002 0.001"/>
      <site name="a_tip" pos="0.2 0.1 -0.3"/>
      <body name="b" pos="0 0 -0.4" euler="0.3 -0.2 0.5">
        <joint name="h3" type="hinge" axis="1 1 0" range="-1 1"/>
        <joint name="s2" type="slide" axis="0 0 1" pos="0.1 0.1 0"/>
        <inertial pos="0 0.03 -0.2" mass="1.5" diaginertia="0.02 0.03 0.01"/>
        <site name="b_tip" pos="0 0 -0.4"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


# ---------------------------------------------------------------------------------------------
# Against Pinocchio


def _check_against_pinocchio(robot: Robot, samples: int = SAMPLES) -> None:
    dyn, model = dynamics(robot), robot.model
    data = model.createData()
    rng = np.random.default_rng(SEED)
    for q, v in _states(robot, samples):
        M = pin.crba(model, data, q)
        M = np.triu(M) + np.triu(M, 1).T
        np.testing.assert_allclose(_np(dyn.mass(q)), M, rtol=0, atol=TOL_PINOCCHIO)
        np.testing.assert_allclose(_np(dyn.bias(q, v)), pin.rnea(model, data, q, v, 0 * v), rtol=0, atol=TOL_PINOCCHIO)
        u = rng.uniform(-1, 1, robot.nu)
        ref = pin.aba(model, data, q, v, robot.actuation_matrix @ u)
        np.testing.assert_allclose(_np(dyn.forward(q, v, u)), ref, rtol=0, atol=TOL_FORWARD * (1 + np.abs(ref).max()))
        for dt in (0.0, 1e-9, 1e-3, 0.7):  # zero, series and closed-form branches of the exponentials
            np.testing.assert_allclose(_np(dyn.integrate(q, v * dt)), pin.integrate(model, q, v * dt), rtol=0, atol=TOL_PINOCCHIO)
        pin.computeJointJacobians(model, data, q)
        pin.forwardKinematics(model, data, q, v, 0 * v)
        pin.updateFramePlacements(model, data)
        for name in robot.points:
            fid = robot.frame_id(name)
            np.testing.assert_allclose(_np(dyn.point_position(name)(q)), data.oMf[fid].translation, rtol=0, atol=TOL_PINOCCHIO)
            np.testing.assert_allclose(_np(dyn.point_rotation(name)(q)), data.oMf[fid].rotation, rtol=0, atol=TOL_PINOCCHIO)
            J = pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)
            np.testing.assert_allclose(_np(dyn.frame_jacobian(name)(q)).reshape(6, -1), J, rtol=0, atol=TOL_PINOCCHIO)
            np.testing.assert_allclose(_np(dyn.point_jacobian(name)(q)).reshape(3, -1), J[:3], rtol=0, atol=TOL_PINOCCHIO)
            drift = pin.getFrameClassicalAcceleration(model, data, fid, pin.LOCAL_WORLD_ALIGNED).linear
            np.testing.assert_allclose(_np(dyn.point_drift(name)(q, v)), drift, rtol=0, atol=TOL_PINOCCHIO)


@pytest.mark.parametrize("spec", PROJECT_ROBOTS + ERD_FAST + ["all_joints", "mjcf_composite"])
def test_matches_pinocchio(spec, robot_of):
    """M = crba (symmetrized), h = rnea(q, v, 0), forward = aba(B u), integrate = pin.integrate, and
    every named point's placement, LOCAL_WORLD_ALIGNED Jacobian and classical drift equal Pinocchio's."""
    _check_against_pinocchio(robot_of(spec))


@pytest.mark.slow
def test_matches_pinocchio_talos(erd_robot):
    """As test_matches_pinocchio on Talos (free flyer + 32 joints, 100+ frames)."""
    _check_against_pinocchio(erd_robot("talos"), samples=2)


def test_function_shapes(erd_robot):
    """Every function has the documented input and output shapes; B is numpy (nv, nu)."""
    robot = erd_robot("solo12")
    dyn = dynamics(robot)
    nq, nv, nu = dyn.nq, dyn.nv, dyn.nu
    assert (nq, nv, nu) == (19, 18, 12) and dyn.backend == "symbolic"
    assert isinstance(dyn.actuation, np.ndarray) and dyn.actuation.shape == (nv, nu)
    shapes = {
        dyn.mass: ([(nq, 1)], (nv, nv)),
        dyn.bias: ([(nq, 1), (nv, 1)], (nv, 1)),
        dyn.forward: ([(nq, 1), (nv, 1), (nu, 1)], (nv, 1)),
        dyn.integrate: ([(nq, 1), (nv, 1)], (nq, 1)),
        dyn.point_position("FL_FOOT"): ([(nq, 1)], (3, 1)),
        dyn.point_rotation("FL_FOOT"): ([(nq, 1)], (3, 3)),
        dyn.point_jacobian("FL_FOOT"): ([(nq, 1)], (3, nv)),
        dyn.frame_jacobian("FL_FOOT"): ([(nq, 1)], (6, nv)),
        dyn.point_drift("FL_FOOT"): ([(nq, 1), (nv, 1)], (3, 1)),
    }
    for f, (inputs, output) in shapes.items():
        assert [f.size_in(i) for i in range(f.n_in())] == inputs and f.size_out(0) == output, f.name()
    assert dyn.point_jacobian("FL_FOOT") is dyn.point_jacobian("FL_FOOT")  # cached


def test_unknown_point_lists_valid_names():
    """An unknown point name raises UnknownNameError whose one-line message lists the valid names."""
    dyn = dynamics(load_robot("capler"))
    with pytest.raises(UnknownNameError, match="unknown point 'toe'") as err:
        dyn.point_jacobian("toe")
    assert "base, foot, knee, shank, thigh" in str(err.value) and "\n" not in str(err.value)


def test_unsupported_joint_is_named():
    """A joint type without a symbolic implementation (spherical) raises UnsupportedJointError naming the joint, its
    type as a robot file calls it (a ball joint) and the types the planner takes."""
    model = pin.Model()
    jid = model.addJoint(0, pin.JointModelSpherical(), pin.SE3.Identity(), "shoulder_ball")
    model.appendBodyToJoint(jid, pin.Inertia.FromSphere(1.0, 0.1), pin.SE3.Identity())
    robot = Robot(Path("ball.urdf"), RobotFormat.URDF, model, (), (), (), "")
    with pytest.raises(UnsupportedJointError, match=r"joint 'shoulder_ball' has type JointModelSpherical "
                       r"\(a ball joint\), which the symbolic dynamics does not support; it takes hinge") as err:
        Dynamics(robot)
    assert "\n" not in str(err.value)


def test_integrate_is_differentiable_at_zero(robot_of):
    """d integrate(q, dq)/d dq at dq = 0 is finite (no 0/0 in the exponential) and equals the
    finite-difference derivative."""
    robot = robot_of("all_joints")
    dyn = dynamics(robot)
    q, _ = _states(robot, 1)[0]
    dq = ca.SX.sym("dq", dyn.nv)
    jac = ca.Function("d_integrate", [dq], [ca.jacobian(dyn.integrate(q, dq), dq)])
    J = _np(jac(np.zeros(dyn.nv)))
    assert np.all(np.isfinite(J))
    fd = np.column_stack([(_np(dyn.integrate(q, FD_STEP * e)) - _np(dyn.integrate(q, -FD_STEP * e))) / (2 * FD_STEP) for e in np.eye(dyn.nv)])
    np.testing.assert_allclose(J, fd, rtol=0, atol=TOL_FD)


# ---------------------------------------------------------------------------------------------
# Against MuJoCo


@pytest.mark.parametrize("spec", [p.name for p in sorted(ROBOTS_DIR.glob("*.xml"))] + ["mjcf_composite"])
def test_matches_mujoco(spec, robot_of):
    """MuJoCo's mass matrix (mj_fullM), bias (qfrc_bias) and site positions of the same MJCF file equal
    the CasADi functions with qpos = q, qvel = v (hinge and slide joints)."""
    robot = robot_of(spec)
    dyn = dynamics(robot)
    mj = mujoco.MjModel.from_xml_path(str(robot.path))
    data = mujoco.MjData(mj)
    M = np.zeros((mj.nv, mj.nv))
    for q, v in _states(robot):
        data.qpos[:], data.qvel[:] = q, v
        mujoco.mj_forward(mj, data)
        mujoco.mj_fullM(mj, data, M)
        np.testing.assert_allclose(_np(dyn.mass(q)), M, rtol=0, atol=TOL_MUJOCO)
        np.testing.assert_allclose(_np(dyn.bias(q, v)), data.qfrc_bias, rtol=0, atol=TOL_MUJOCO)
        for s in range(mj.nsite):
            name = mujoco.mj_id2name(mj, mujoco.mjtObj.mjOBJ_SITE, s)
            np.testing.assert_allclose(_np(dyn.point_position(name)(q)), data.site_xpos[s], rtol=0, atol=TOL_MUJOCO)


# ---------------------------------------------------------------------------------------------
# Ground truths independent of Pinocchio


def _central(f, dyn: Dynamics, q: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """d/dt f(q (+) t direction) at t = 0 by central differences."""
    return (_np(f(_np(dyn.integrate(q, FD_STEP * direction)))) - _np(f(_np(dyn.integrate(q, -FD_STEP * direction))))) / (2 * FD_STEP)


@pytest.mark.parametrize("spec", ["capler.xml", "biped.xml", "solo12", "panda", "all_joints"])
def test_jacobian_and_drift_are_derivatives(spec, robot_of):
    """point_jacobian column k = d position / d(q (+) e_k), and point_drift = d/dt (J(q(t)) v) along
    q(t) = q (+) t v (constant v): central differences, no Pinocchio involved."""
    robot = robot_of(spec)
    dyn = dynamics(robot)
    for q, v in _states(robot, 2):
        for name in robot.points:
            position, jacobian = dyn.point_position(name), dyn.point_jacobian(name)
            fd = np.column_stack([_central(position, dyn, q, e) for e in np.eye(dyn.nv)])
            np.testing.assert_allclose(_np(jacobian(q)).reshape(3, -1), fd, rtol=0, atol=TOL_FD)
            fd_drift = _central(lambda qq: _np(jacobian(qq)).reshape(3, -1) @ v, dyn, q, v)
            np.testing.assert_allclose(_np(dyn.point_drift(name)(q, v)), fd_drift, rtol=0, atol=TOL_FD)


CAPLER_Q0 = np.array([0.0, 0.4, 0.0, 0.0])
CAPLER_MASS = 3.975 + 1.782 + 0.548  # base + thigh + shank [kg]


@pytest.mark.parametrize("spec", ["capler.xml", "capler.urdf"])
def test_capler_values(spec):
    """Capler at q0 = (0, 0.4, 0, 0): M[0,0] = M[1,1] = total mass 6.305 kg and the bias's z entry is
    +6.305 * 9.81 = +61.852 N (RNEA convention: h = -generalized gravity force)."""
    dyn = dynamics(load_robot(ROBOTS_DIR / spec))
    M, h = _np(dyn.mass(CAPLER_Q0)), _np(dyn.bias(CAPLER_Q0, np.zeros(4)))
    assert CAPLER_MASS == pytest.approx(6.305, abs=1e-15)
    assert M[0, 0] == pytest.approx(CAPLER_MASS, abs=TOL_SAME_ROBOT) and M[1, 1] == pytest.approx(CAPLER_MASS, abs=TOL_SAME_ROBOT)
    assert h[1] == pytest.approx(CAPLER_MASS * 9.81, abs=TOL_SAME_ROBOT) and round(h[1], 3) == 61.852


def test_capler_mjcf_equals_urdf():
    """capler.xml and capler.urdf describe one robot: same M, h and foot position at random states."""
    xml, urdf = (dynamics(load_robot(ROBOTS_DIR / f)) for f in ("capler.xml", "capler.urdf"))
    for q, v in _states(xml.robot, 10):
        np.testing.assert_allclose(_np(xml.mass(q)), _np(urdf.mass(q)), rtol=0, atol=TOL_SAME_ROBOT)
        np.testing.assert_allclose(_np(xml.bias(q, v)), _np(urdf.bias(q, v)), rtol=0, atol=TOL_SAME_ROBOT)
        np.testing.assert_allclose(_np(xml.point_position("foot")(q)), _np(urdf.point_position("foot")(q)), rtol=0, atol=TOL_SAME_ROBOT)


def test_dynamics_of_another_robot_file_with_the_same_joints_is_refused(tmp_path):
    """Dynamics passed to simulate or build_problem must come from the robot's own file contents: a copy of
    capler.xml whose base weighs 1 kg more (same nq, nv and joint names, so only the file's SHA-256 tells them apart)
    is an InputError naming both files (it simulated and planned the real Capler with the heavier one's mass
    matrix); an unchanged copy under another name is the same robot and is accepted."""
    from planner.dynamics import dynamics_for
    from planner.errors import InputError
    from planner.problem import build_problem
    from planner.simulate import simulate
    from planner.task import load_task

    real = load_robot(ROBOTS_DIR / "capler.xml")
    text = (ROBOTS_DIR / "capler.xml").read_text()
    assert text.count('mass="3.975"') == 1
    (tmp_path / "heavy.xml").write_text(text.replace('mass="3.975"', 'mass="4.975"'))
    (tmp_path / "same.xml").write_text(text)
    heavy = Dynamics(load_robot(tmp_path / "heavy.xml"))
    assert (heavy.robot.nq, heavy.robot.nv, heavy.robot.dof_names) == (real.nq, real.nv, real.dof_names)
    assert _np(heavy.mass(CAPLER_Q0))[0, 0] == pytest.approx(CAPLER_MASS + 1.0, abs=TOL_SAME_ROBOT)
    task = load_task(ROBOTS_DIR / "capler.toml")
    for run in (simulate, build_problem):
        with pytest.raises(InputError, match=r"dynamics were built from .*heavy.xml, not from the robot .*capler.xml"):
            run(real, task, dynamics=heavy)
    same = Dynamics(load_robot(tmp_path / "same.xml"))
    assert dynamics_for(real, same) is same


def test_accurate_far_from_origin():
    """M and h do not depend on the base position: Capler at x, z = 1e3 m equals Capler at 0 to 1e-12."""
    dyn = dynamics(load_robot("capler"))
    q, v = np.array([0.0, 0.0, 0.3, -0.5]), np.array([0.3, -0.2, 0.5, 1.0])
    far = q + np.array([1e3, -1e3, 0, 0])
    np.testing.assert_allclose(_np(dyn.mass(far)), _np(dyn.mass(q)), rtol=0, atol=TOL_SAME_ROBOT)
    np.testing.assert_allclose(_np(dyn.bias(far, v)), _np(dyn.bias(q, v)), rtol=0, atol=TOL_SAME_ROBOT)


# the point mass's file and its <option> line, whose gravity a variant replaces
POINT_MASS = (ROBOTS_DIR / "point_mass.xml").read_text()
OPTION = '<option timestep="0.001" gravity="0 0 -9.81" cone="elliptic" impratio="10"/>'


@pytest.mark.parametrize("gravity", ["0 0 -1.62", "1.5 0 -9.81"])
def test_the_files_gravity_is_the_dynamics_gravity(robot_variant, gravity):
    """A file's <option gravity> (the Moon's; a slope's tilted one) is the gravity of the planner's dynamics: the bias
    forces h(q, v) equal MuJoCo's qfrc_bias of the same file at seeded states (ground truth: MuJoCo's RNE), and
    check-model passes. Every shipped robot has gravity (0, 0, -9.81), so a dynamics that ignored
    Pinocchio's model.gravity for a hardcoded -9.81 passed every test (a mutant of session 65's mutation testing)."""
    import mujoco

    from planner.dynamics import Dynamics

    robot = robot_variant(POINT_MASS, OPTION, OPTION.replace("0 0 -9.81", gravity))
    mj = mujoco.MjModel.from_xml_path(str(robot.path))
    data = mujoco.MjData(mj)
    dyn = Dynamics(robot)
    rng = np.random.default_rng(SEED)
    for _ in range(5):
        q, v = random_state(robot.model, rng)
        data.qpos[:], data.qvel[:] = q, v
        mujoco.mj_forward(mj, data)
        h = np.asarray(dyn.bias(q, v), float).ravel()
        assert np.max(np.abs(h - data.qfrc_bias)) <= TOL_MUJOCO, (h, data.qfrc_bias)
    assert np.allclose(np.asarray(dyn.bias(np.zeros(2), np.zeros(2)), float).ravel(),
                       -np.array([float(g) for g in gravity.split()])[[0, 2]], rtol=0.0, atol=TOL_MUJOCO)
    assert check_model(robot, samples=2).passed
