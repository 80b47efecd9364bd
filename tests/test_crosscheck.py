"""Cross-checks of the time-freezing simulation (planner.simulate) against MuJoCo rollouts of robots
with joints: the same robot file, the same initial state and the same joint PD law on both sides
(the point-mass cross-checks are in tests/test_replay.py). Every tolerance is a named constant with
the reason for its size; the measured values are in docs/validation.md and printed by the tests.
"""
from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from planner import replay
from planner.model import ROBOTS_DIR, load_robot
from planner.simulate import pd_law, simulate
from planner.task import parse_task

DT_MJ = replay.ContactSettings().timestep  # MuJoCo's step [s]

# --- Capler dropped while joint PD holds its posture -------------------------------------------
CAPLER_HOLD = (0.0, 0.3)  # hip, knee [rad]: hip straight, knee bent slightly (foot 6 cm behind the hip)
CAPLER_DROP_M = 0.05  # foot above the ground at the start [m]
CAPLER_KP, CAPLER_KD = 100.0, 2.0  # [N m/rad, N m s/rad]; with kd = 2 the law peaks at 47 N m in MuJoCo
#   (right after the impact), inside the motors' 60 N m: both sides apply the same unsaturated law
CAPLER_MU = 0.8
CAPLER_N = 500  # implicit Euler steps over 1 s: h = 2 ms
# Implicit Euler's free fall runs ahead of the exact one by h/2 in time (z_k = z_0 - g h^2 k (k+1) / 2)
# and the entry step splits the clock exactly for a ballistic approach; MuJoCo notices the contact at
# its first state below the ground, up to one of its steps late (measured 1.03 ms at h = 2 ms).
def impact_time_tol(h: float) -> float:
    return h / 2 + DT_MJ


# The post-impact velocities are compared in the kinetic-energy norm |dv|_M = sqrt(dv^T M dv) at the
# impact posture, relative to |v_pre|_M: joint and base velocities in one unit-consistent measure.
# The time-freezing step that holds the impact also evaluates the joint damping at the post-impact
# velocity (first order in h); MuJoCo's value is read one of its steps after the contact onset, when
# its dead-beat contact has removed the foot's velocity (measured 2.0 % at h = 2 ms; issue: 5 %).
VELOCITY_REL_TOL = 0.03
# Both settle to the same PD stance; the difference is the free-fall lead g t_impact h / 2 = 1.0 mm
# carried through the landing (measured 0.9 mm for base, knee and foot; issue: 1 cm over 1 s).
# The biped drop uses the same three tolerances for the same reasons (measured: impact time 1.0 ms
# before MuJoCo's onsets, velocity 0.53 %, positions 0.86 mm at h = 2 ms).
POSITION_TOL_M = 2e-3


def _capler_task():
    hip, knee = CAPLER_HOLD
    z_base = 0.2 * math.cos(hip) + 0.2 * math.cos(hip + knee) + CAPLER_DROP_M
    return parse_task({"contacts": [{"point": "foot", "mu": CAPLER_MU}], "initial": {"q": [0.0, z_base, hip, knee]},
                       "horizon": {"tau_f": 1.0, "N": CAPLER_N},
                       "simulate": {"pd": {"joints": ["hip", "knee"], "kp": [CAPLER_KP] * 2, "kd": [CAPLER_KD] * 2}}})


def _differences(scene, robot, tr, impact, v_mj: np.ndarray, mj: dict, sites: tuple[str, ...]):
    """Post-impact velocity difference relative to the pre-impact velocity, both in the kinetic-energy
    norm of M(q_impact), and the distances (P, 1 + len(sites)) [m] of the base and the named sites
    from MuJoCo's at the simulation's physical times."""
    M = _mass_matrix(scene, impact.q)
    dv = impact.v_post - v_mj
    v_err = math.sqrt(dv @ M @ dv) / math.sqrt(impact.v_pre @ M @ impact.v_pre)
    q_mj = np.stack([np.interp(tr.t, mj["t"], mj["q"][:, i]) for i in range(robot.nq)], axis=1)
    gap = np.linalg.norm(_positions(scene, tr.q, sites) - _positions(scene, q_mj, sites), axis=2)
    return v_err, gap


def _positions(scene, q: np.ndarray, sites: tuple[str, ...]) -> np.ndarray:
    """Base origin and the named sites (n, 1 + len(sites), 3) [m] of the postures q (n, nq), by MuJoCo."""
    model, data = scene.model, mujoco.MjData(scene.model)
    ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, s) for s in sites]
    out = np.zeros((len(q), 1 + len(sites), 3))
    for k, qk in enumerate(q):
        data.qpos[:] = qk
        mujoco.mj_kinematics(model, data)
        out[k, 0], out[k, 1:] = data.xpos[scene.base_body], data.site_xpos[ids]
    return out


def _mass_matrix(scene, q: np.ndarray) -> np.ndarray:
    data = mujoco.MjData(scene.model)
    data.qpos[:] = q
    mujoco.mj_forward(scene.model, data)
    M = np.zeros((scene.model.nv, scene.model.nv))
    mujoco.mj_fullM(scene.model, data, M)
    return M


def _crosscheck(robot, task):
    """Simulate the task both ways with the same PD law: (result, MuJoCo arrays, unclamped MuJoCo controls)."""
    result = simulate(robot, task)
    assert result.stats.converged, result.stats.message
    law = pd_law(robot, task)
    scene = replay.build_scene(robot, task)
    v0 = np.zeros(robot.nv) if task.initial.v is None else task.initial.v

    def control(t, q, v):
        return law(task.simulate.controls_at(t, robot.nu), q, v)

    mj = replay.mujoco_rollout(scene, task.initial.q, v0, float(result.trajectory.t[-1]), control)
    u_mj = np.array([control(t, q, v) for t, q, v in zip(mj["t"], mj["q"], mj["v"])])
    return result, mj, u_mj, scene


@pytest.mark.slow
def test_capler_drop_with_pd_posture_hold(capsys):
    """Capler dropped with its foot 5 cm above the ground (mu = 0.8) while joint PD holds hip 0, knee
    0.3 rad: both simulators see one impact at the same time, the same post-impact velocity (the
    rigid no-slip impact map) and the same motion of base, knee and foot over 1 s, with the same
    unsaturated PD law."""
    robot = load_robot(ROBOTS_DIR / "capler.xml")
    task = _capler_task()
    result, mj, u_mj, scene = _crosscheck(robot, task)
    tr, h = result.trajectory, task.horizon.h
    assert result.extra["pd"]["steps_beyond_actuator_bounds"] == 0
    assert np.all((u_mj >= robot.u_lower) & (u_mj <= robot.u_upper))  # MuJoCo never clamps: the same law

    assert len(tr.impacts) == 1 and mj["impact_times"].size == 1
    impact, t_mj = tr.impacts[0], float(mj["impact_times"][0])
    k_mj = int(np.searchsorted(mj["t"], t_mj))
    v_mj = mj["v"][k_mj + 1]  # one MuJoCo step after the contact onset
    v_err, gap = _differences(scene, robot, tr, impact, v_mj, mj, ("knee", "foot"))
    with capsys.disabled():
        print(f"\ncapler PD drop (h = {h * 1e3:g} ms): simulate {result.stats.solve_time_s:.1f} s, impact t {impact.time:.5f} "
              f"vs MuJoCo {t_mj:.5f} s; v_post {np.round(impact.v_post, 4).tolist()} vs {np.round(v_mj, 4).tolist()} "
              f"(M-norm {v_err:.2%}); max position difference base/knee/foot {np.round(gap.max(axis=0) * 1e3, 2).tolist()} mm, "
              f"final {np.round(gap[-1] * 1e3, 2).tolist()} mm")
    assert abs(impact.time - t_mj) <= impact_time_tol(h)
    assert v_err <= VELOCITY_REL_TOL
    assert gap.max() <= POSITION_TOL_M


# --- the biped dropped onto both feet ----------------------------------------------------------
BIPED_SPREAD = 0.2  # hinge angles +-0.2 rad: the feet 40 cm apart, at the same height
BIPED_DROP_M = 0.05
BIPED_KP, BIPED_KD = 2000.0, 50.0  # [N m/rad, N m s/rad]: 40 rad/s, damping ratio 0.5 on a leg's 1.25 kg m^2


@pytest.mark.slow
def test_biped_drop_onto_both_feet(capsys):
    """The biped dropped flat onto both feet (5 cm) while joint PD holds its legs +-0.2 rad: both feet
    take an impulse in one frozen interval (several contact points, docs/formulation.md "Several
    contacts"), at the same impact time as MuJoCo's two onsets, with the same post-impact velocity
    and the same motion of hip and feet."""
    robot = load_robot(ROBOTS_DIR / "biped.xml")
    z_hip = math.cos(BIPED_SPREAD) + BIPED_DROP_M
    task = parse_task({"contacts": [{"point": "foot_1", "mu": 0.8}, {"point": "foot_2", "mu": 0.8}],
                       "initial": {"q": [0.0, z_hip, 0.0, BIPED_SPREAD, -BIPED_SPREAD]}, "horizon": {"tau_f": 1.0, "N": 500},
                       "simulate": {"pd": {"joints": ["hinge_1", "hinge_2"], "kp": [BIPED_KP] * 2, "kd": [BIPED_KD] * 2}}})
    result, mj, u_mj, scene = _crosscheck(robot, task)
    tr, h = result.trajectory, task.horizon.h
    assert np.all((u_mj >= robot.u_lower) & (u_mj <= robot.u_upper))
    assert mj["impact_times"].size == 2  # MuJoCo: one onset per foot
    assert sorted(imp.contact for imp in tr.impacts) == ["foot_1", "foot_2"]  # one frozen interval, both feet
    assert tr.impacts[0].time == tr.impacts[1].time and min(imp.impulse for imp in tr.impacts) > 0
    impact, t_mj = tr.impacts[0], float(mj["impact_times"].min())
    k_mj = int(np.searchsorted(mj["t"], float(mj["impact_times"].max())))
    v_mj = mj["v"][k_mj + 1]  # one MuJoCo step after the second onset
    v_err, gap = _differences(scene, robot, tr, impact, v_mj, mj, ("foot_1", "foot_2"))
    with capsys.disabled():
        print(f"\nbiped drop (h = {h * 1e3:g} ms): impact t {impact.time:.5f} vs MuJoCo {np.round(mj['impact_times'], 5).tolist()} s; "
              f"M-norm velocity difference {v_err:.2%}; max position difference hip/feet {np.round(gap.max(axis=0) * 1e3, 2).tolist()} mm")
    assert abs(impact.time - t_mj) <= impact_time_tol(h)
    assert v_err <= VELOCITY_REL_TOL
    assert gap.max() <= POSITION_TOL_M


# --- a point mass between two frictionless walls (issue 7A: the corner of Sec. 4.5) ---------------
CORNER_RADIUS_M = 0.01  # the MuJoCo sphere; the walls are moved out by it, so its centre is the point
CORNER_DT_MJ = 2.5e-4  # MuJoCo's step [s]: the walls' contacts are stiff (solref 2 ms, damping ratio 1)
# MuJoCo's soft contact shares the weight between the walls only up to its penetration (~1e-5 m here)
# and its force solver's tolerance: measured agreement 2e-4 relative after 0.5 s of settling
CORNER_FORCE_RTOL = 0.01
# The slide down the 60 deg wedge's left wall reaches the corner at the same time on both sides up
# to the time-freezing step (h = 5 ms, free-fall-like lead of ~h/2) and MuJoCo's stiff contact onset
CORNER_ARRIVAL_TOL_S = 5e-3
CORNER_REST_TOL_M = 2e-3  # both end at rest in the corner: MuJoCo's penetration and soft settling


def _corner_mujoco(slope_deg: float) -> mujoco.MjModel:
    """The point mass (slides x, z, 1 kg) above two frictionless walls through the origin with
    slopes +-slope_deg, written like the planner's tilted contact planes (tests/test_simulate.py)."""
    a, r = math.radians(slope_deg), CORNER_RADIUS_M
    walls = "".join(
        f'<geom name="wall{i}" type="plane" size="1 1 0.1" euler="0 {s * a} 0" pos="{-s * r * math.sin(a)} 0 {-r * math.cos(a)}" '
        f'condim="1" solref="0.002 1"/>' for i, s in ((1, 1), (2, -1)))
    xml = f"""<mujoco><compiler angle="radian"/><option timestep="{CORNER_DT_MJ}" gravity="0 0 -9.81"/>
      <worldbody>{walls}<body name="mass"><joint name="x" type="slide" axis="1 0 0"/><joint name="z" type="slide" axis="0 0 1"/>
      <geom type="sphere" size="{r}" mass="1" condim="1" solref="0.002 1"/></body></worldbody></mujoco>"""
    return mujoco.MjModel.from_xml_string(xml)


def _corner_rollout(slope_deg: float, x0: float, duration: float):
    """MuJoCo from rest on the left wall at x0: times (K,), positions (K, 2), the last step's normal
    contact force per wall [N] (wall1, wall2)."""
    from test_simulate import corner_task

    model = _corner_mujoco(slope_deg)
    data = mujoco.MjData(model)
    data.qpos[:] = corner_task(slope_deg, x0, 1.0, 10).initial.q
    ts, qs = [], []
    for _ in range(int(round(duration / CORNER_DT_MJ))):
        mujoco.mj_step(model, data)
        ts.append(data.time)
        qs.append(data.qpos.copy())
    force = np.zeros(2)
    for i in range(data.ncon):
        f = np.zeros(6)
        mujoco.mj_contactForce(model, data, i, f)
        wall = {model.geom("wall1").id: 0, model.geom("wall2").id: 1}[min(data.contact[i].geom1, data.contact[i].geom2)]
        force[wall] += f[0]
    return np.array(ts), np.array(qs), force


def test_corner_rest_and_wedge_against_mujoco(capsys):
    """Two frictionless walls meeting at an angle, on both simulators: in the 140 deg corner the mass
    rests and each wall carries m g / (2 cos 20 deg) (MuJoCo's contact forces = the time-freezing
    simulation's index-reduced forces); released 0.1 m left of the 60 deg wedge's bottom, it reaches
    the corner at the same time and rests there on both."""
    from test_simulate import corner_task, dynamics, robot

    _, _, force_mj = _corner_rollout(20.0, 0.0, 0.5)
    rest = simulate(robot(), corner_task(20.0, 0.0, 0.2, 20), dynamics=dynamics()).trajectory
    np.testing.assert_allclose(force_mj, rest.forces[-1], rtol=CORNER_FORCE_RTOL)

    t_mj, q_mj, _ = _corner_rollout(60.0, -0.1, 0.5)
    tf = simulate(robot(), corner_task(60.0, -0.1, 0.5, 100), dynamics=dynamics()).trajectory
    arrive_mj = t_mj[np.argmax(q_mj[:, 0] > -1e-3)]
    arrive_tf = tf.impacts[0].time
    with capsys.disabled():
        print(f"\ncorner: wall forces MuJoCo {force_mj} N, time-freezing {rest.forces[-1]} N; wedge arrival MuJoCo "
              f"{arrive_mj:.4f} s, time-freezing {arrive_tf:.4f} s")
    assert abs(arrive_mj - arrive_tf) <= CORNER_ARRIVAL_TOL_S
    np.testing.assert_allclose(q_mj[-1], 0.0, atol=CORNER_REST_TOL_M)
    np.testing.assert_allclose(tf.q[-1], 0.0, atol=CORNER_REST_TOL_M)


# MuJoCo's exit velocity is read 10 ms after the corner, when its soft contact has settled; by then
# gravity along the 20 deg wall has taken g sin 20 * 0.01 = 0.034 m/s (3 %) of the LCP speed
CORNER_LCP_RTOL = 0.05
# The time-freezing step leaves the obtuse corner at 79 % of the rigid (LCP) speed: it pulls on the
# left wall while its clock restarts (docs/formulation.md, "Several contacts", a known defect)
CORNER_EXIT_SPEED_RATIO = (0.75, 1.0)


def test_obtuse_corner_exit_against_mujoco(capsys):
    """Sliding down the 140 deg corner's left wall through the corner: MuJoCo leaves along the right
    wall at the rigid LCP velocity v- - (n2 . v-) n2 (to 5 %); the time-freezing simulation arrives at
    the same time and leaves exactly along the LCP direction, but slower (the known 79 % exit speed, pinned
    here so that a fix or a regression shows)."""
    from test_simulate import corner_task, dynamics, robot, wall_normals

    t, q, _ = _corner_rollout(20.0, -0.3, 0.6)
    v = np.diff(q, axis=0) / np.diff(t)[:, None]
    k = int(np.argmax(q[:, 0] > 0))
    n2 = np.array(wall_normals(20.0)[1])[[0, 2]]
    v_pre, v_mj = v[k - 5], v[k + int(round(0.01 / CORNER_DT_MJ))]
    lcp = v_pre - (n2 @ v_pre) * n2
    np.testing.assert_allclose(v_mj, lcp, rtol=CORNER_LCP_RTOL, atol=CORNER_LCP_RTOL * np.linalg.norm(lcp))
    imp = simulate(robot(), corner_task(20.0, -0.3, 0.6, 120), dynamics=dynamics()).trajectory.impacts[0]
    ratio = np.linalg.norm(imp.v_post) / np.linalg.norm(v_mj)
    with capsys.disabled():
        print(f"\nobtuse corner: MuJoCo v+ {v_mj} (LCP {lcp}) at {t[k]:.4f} s; time-freezing v+ {imp.v_post} at {imp.time:.4f} s, "
              f"speed ratio {ratio:.3f}")
    assert abs(imp.time - t[k]) <= CORNER_ARRIVAL_TOL_S
    assert imp.v_post[0] * lcp[1] - imp.v_post[1] * lcp[0] == pytest.approx(0.0, abs=1e-6)  # along the right wall
    assert CORNER_EXIT_SPEED_RATIO[0] <= ratio <= CORNER_EXIT_SPEED_RATIO[1]
