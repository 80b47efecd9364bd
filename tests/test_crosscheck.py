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
