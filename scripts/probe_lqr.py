"""Does a time-varying LQR along the plan track a Capler plan over its whole horizon in MuJoCo? (session 34)

docs/validation.md names "an LQR along the plan with the contact mode scheduled" as what could close the whole
joint-PD replay's failure on Capler (its base is unactuated: a take-off velocity error becomes a landing error). This
probe builds that controller for a `planner plan` result and replays it in the validation's MuJoCo scene:

- the contact schedule from the plan's own samples: a point is in stance on (t_i, t_i+1] when its gap is below
  --gap-tol at both samples (the reference's chords between stance samples lift a rotating foot by up to ~1 mm, so
  the MuJoCo-grid reference cannot tell it);
- the dynamics linearized about the reference on MuJoCo's grid (every --every steps, and at every mode change) with
  the stance points pinned (no slip; MuJoCo's mass matrix, bias forces and site Jacobians, central differences),
  discretized as MuJoCo's semi-implicit Euler, the plastic impact map v+ = (I - M^-1 J^T (J M^-1 J^T)^-1 J) v- at
  each touchdown;
- the backward Riccati sweep of the cost sum dt (x^T Q x + u^T R u) with Q = diag(q on positions, v on velocities;
  both times --base-factor on the unactuated coordinates), R = r I, and 10 Q / dt at the end;
- u = u_ref - K_k (x - x_ref) in MuJoCo, against the validation's joint PD on the same reference.

Reported per controller: the largest base error up to each horizon [m], the saturation share and MuJoCo's impacts.

    python -m scripts.probe_lqr DIR [--q 1e4] [--v 1e2] [--r 1] [--base-factor 1] [--every 20]
    python -m scripts.probe_lqr --quick --json     # CI smoke run: the point-mass hop planned here (N = 10)
Writes OUT/results.json.
"""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import mujoco
import numpy as np

from planner import replay as R
from planner.result import check_same_result, read_robot, read_summary, read_task, read_trajectory
from scripts._report import (nonnegative_float, out_dir, planner_command, positive_float, refuse_with_quick, report,
                             run_main, script_parser)

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_OUT = Path("results/probe/lqr")
FD_STEP = 1e-6  # [m, rad, m/s, rad/s, N m] central differences of the accelerations: O(1e-12) truncation, 1e-10 round-off
HORIZONS = (0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 2.0)  # [s] of physical time from the plan's start
QUICK_TASK = (ROOT / "robots" / "point_mass_hop.toml").read_text().replace("\nN = 20\n", "\nN = 10\n")
assert "\nN = 10\n" in QUICK_TASK, "robots/point_mass_hop.toml's horizon line changed"


def load(out_dir: Path):
    """The validation's scene and MuJoCo-grid reference of the plan in out_dir, and the plan's checked arrays."""
    summary = read_summary(out_dir)
    robot, traj = read_robot(out_dir, summary), read_trajectory(out_dir)
    check_same_result(out_dir, summary, traj)
    task = read_task(out_dir, traj, summary)
    options = R.ValidationOptions()
    scene = R.build_scene(robot, task, options.contact, detect_within_m=options.contact_gap_tol_m)
    arrays = R.check_trajectory(robot, traj)
    return scene, R._Reference(arrays, scene.settings.timestep), arrays


def schedule(scene, ref, arrays, gap_tol: float) -> np.ndarray:
    """(n+1, C) stance of each contact point at MuJoCo step k: on the ground at both plan samples around it."""
    _, sites = R._planned_positions(scene, arrays["q"])
    on = sites[:, :, 2] - scene.ground_height < gap_tol  # (P, C)
    t = arrays["t"]
    after = np.clip(np.searchsorted(t, ref.times, side="left"), 1, len(t) - 1)
    stance = on[after - 1] & on[after]
    stance[0] = on[0]
    return stance


class _Model:
    """Constrained forward dynamics of the MuJoCo model with chosen contact points pinned."""

    def __init__(self, scene):
        self.scene, self.model = scene, scene.model
        self.data, self.moved = mujoco.MjData(scene.model), mujoco.MjData(scene.model)
        nv, nu = scene.model.nv, scene.model.nu
        self.B = np.zeros((nv, nu))
        self.B[scene.dof_adr, np.arange(nu)] = scene.gear

    def _kinematics(self, data, q) -> None:
        data.qpos[:] = q
        mujoco.mj_kinematics(self.model, data)
        mujoco.mj_comPos(self.model, data)

    def _jacobian(self, data, points) -> np.ndarray:
        """(2 S, nv) x and z rows of the points' Jacobians (the robots are planar)."""
        jac, rows = np.zeros((3, self.model.nv)), []
        for c in points:
            mujoco.mj_jacSite(self.model, data, jac, None, self.scene.site_ids[c])
            rows.append(jac[[0, 2]].copy())
        return np.vstack(rows)

    def mass(self, q) -> np.ndarray:
        self._kinematics(self.data, q)
        mujoco.mj_crb(self.model, self.data)
        M = np.zeros((self.model.nv, self.model.nv))
        mujoco.mj_fullM(self.model, self.data, M)
        return M

    def accel(self, q, v, u, points) -> np.ndarray:
        """a (nv,) with the points pinned: [M, -J^T; J, 0] [a; f] = [B u - c; -J' v]."""
        nv = self.model.nv
        M = self.mass(q)
        self.data.qvel[:] = v
        mujoco.mj_comVel(self.model, self.data)
        c = np.zeros(nv)
        mujoco.mj_rne(self.model, self.data, 0, c)
        rhs = self.B @ u - c
        if not points:
            return np.linalg.solve(M, rhs)
        J = self._jacobian(self.data, points)
        ahead = np.array(q, dtype=float)
        mujoco.mj_integratePos(self.model, ahead, v, FD_STEP)  # the posture FD_STEP later along v
        self._kinematics(self.moved, ahead)
        dJv = (self._jacobian(self.moved, points) - J) @ v / FD_STEP
        S = len(J)
        kkt = np.block([[M, -J.T], [J, np.zeros((S, S))]])
        return np.linalg.solve(kkt, np.concatenate([rhs, -dJv]))[:nv]

    def impact_map(self, q, points) -> np.ndarray:
        """(2 nv, 2 nv) state map of a plastic, no-slip impact of the points at posture q."""
        nv = self.model.nv
        Minv = np.linalg.inv(self.mass(q))
        J = self._jacobian(self.data, points)
        P = np.eye(nv) - Minv @ J.T @ np.linalg.solve(J @ Minv @ J.T, J)
        return np.block([[np.eye(nv), np.zeros((nv, nv))], [np.zeros((nv, nv)), P]])

    def linearize(self, q, v, u, points, dt) -> tuple[np.ndarray, np.ndarray]:
        """A (2 nv, 2 nv), B (2 nv, nu) of one semi-implicit Euler step about (q, v, u)."""
        nv, nu = self.model.nv, self.model.nu

        def diff(shift, n):
            return np.column_stack([(self.accel(*shift(e), points) - self.accel(*shift(-e), points)) / (2 * FD_STEP)
                                    for e in FD_STEP * np.eye(n)])

        da_dq = diff(lambda e: (q + e, v, u), nv)
        da_dv = diff(lambda e: (q, v + e, u), nv)
        da_du = diff(lambda e: (q, v, u + e), nu)
        eye = np.eye(nv)
        A = np.block([[eye + dt * dt * da_dq, dt * (eye + dt * da_dv)], [dt * da_dq, eye + dt * da_dv]])
        return A, np.vstack([dt * dt * da_du, dt * da_du])


def gains(scene, ref, stance: np.ndarray, q_w: float, v_w: float, r_w: float, base_factor: float, every: int) -> list[np.ndarray]:
    """K_k (nu, 2 nv) for k = 0..n-1 from the Riccati sweep along the reference (module docstring)."""
    model, dt, n = _Model(scene), ref.dt, ref.steps
    nv = scene.model.nv
    cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    AB = []
    for k in range(n):
        at = (k // every) * every
        at = at if np.array_equal(stance[at], stance[k]) else k  # relinearized where the mode changes
        if at not in cache:
            cache[at] = model.linearize(ref.q[at], ref.v[at], ref.u[at], list(np.nonzero(stance[at])[0]), dt)
        A, B = cache[at]
        landing = stance[k + 1] & ~stance[k]
        if landing.any():
            G = model.impact_map(ref.q[k + 1], list(np.nonzero(stance[k + 1])[0]))
            A, B = G @ A, G @ B
        AB.append((A, B))
    weights = np.concatenate([np.full(nv, q_w), np.full(nv, v_w)])
    unactuated = np.setdiff1d(np.arange(nv), scene.dof_adr)
    weights[unactuated] *= base_factor
    weights[nv + unactuated] *= base_factor
    Q, Rm = np.diag(weights) * dt, r_w * dt * np.eye(scene.model.nu)
    P, K = 10.0 * Q / dt, [None] * n
    for k in range(n - 1, -1, -1):
        A, B = AB[k]
        BtP = B.T @ P
        K[k] = np.linalg.solve(Rm + BtP @ B, BtP @ A)
        P = Q + A.T @ P @ (A - B @ K[k])
        P = 0.5 * (P + P.T)
    return K


def replay(scene, ref, command, horizons) -> dict:
    """MuJoCo run of `command`; the largest base error up to each horizon [m], saturation, MuJoCo's impacts."""
    run = R._simulate(scene, ref.q[0], ref.v[0], ref.steps, ref.times[0], command)
    base_ref, _ = R._planned_positions(scene, ref.q)
    err = np.linalg.norm(run.base - base_ref, axis=1)
    elapsed = ref.times - ref.times[0]
    saturated = (run.ctrl < scene.ctrl_lower) | (run.ctrl > scene.ctrl_upper)
    impacts = R.detect_impacts(run.times, run.active, scene.points, R.MIN_FLIGHT_S, run.touching0)
    return {"max_base_error_m": float(err.max()), "final_base_error_m": float(err[-1]),
            "base_error_up_to_m": {f"{h:g}": float(err[elapsed <= h].max()) for h in horizons if h < elapsed[-1]},
            "saturation": float(saturated.mean()) if saturated.size else 0.0, "diverged": run.diverged,
            "mujoco_impacts_s": [round(float(t), 4) for _, t in impacts]}


def probe(out_dir: Path, q_w: float, v_w: float, r_w: float, base_factor: float, every: int, gap_tol: float) -> dict:
    scene, ref, arrays = load(out_dir)
    stance = schedule(scene, ref, arrays, gap_tol)
    K = gains(scene, ref, stance, q_w, v_w, r_w, base_factor, every)

    def lqr(k, data):
        return ref.u[k] - K[k] @ np.concatenate([data.qpos - ref.q[k], data.qvel - ref.v[k]])

    pd = R.resolve_gains(scene, R.TrackingGains(), ref.q[0])
    kp, kd, qa, va = np.array(pd.kp), np.array(pd.kd), scene.qpos_adr, scene.dof_adr

    def joint_pd(k, data):  # the validation's TrackingController.JOINT_PD
        return ref.u[k] + (kp * (ref.q[k][qa] - data.qpos[qa]) + kd * (ref.v[k][va] - data.qvel[va])) / scene.gear

    return {"plan": str(out_dir), "steps": ref.steps, "stance_share": float(stance.any(axis=1).mean()),
            "weights": {"q": q_w, "v": v_w, "r": r_w, "base_factor": base_factor}, "every": every, "gap_tol_m": gap_tol,
            "largest_gain": float(max(np.abs(k).max() for k in K)),
            "lqr": replay(scene, ref, lqr, HORIZONS), "joint_pd": replay(scene, ref, joint_pd, HORIZONS)}


def table(rec: dict) -> str:
    horizons = list(rec["joint_pd"]["base_error_up_to_m"])
    lines = ["| controller | " + " | ".join(f"up to {h} s" for h in horizons) + " | whole | saturation |",
             "|---|" + "---|" * (len(horizons) + 2)]
    for name in ("joint_pd", "lqr"):
        r = rec[name]
        cells = " | ".join(f"{1e3 * r['base_error_up_to_m'][h]:.2f}" for h in horizons)
        lines.append(f"| {name} | {cells} | {1e3 * r['max_base_error_m']:.2f} | {r['saturation']:.3f} |")
    return "base error [mm]\n" + "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = script_parser(__doc__)
    parser.add_argument("plan", nargs="?", type=Path, help="a `planner plan` result directory")
    parser.add_argument("--q", type=nonnegative_float, default=1e4, help="position weight (default 1e4)")
    parser.add_argument("--v", type=nonnegative_float, default=1e2, help="velocity weight (default 1e2)")
    parser.add_argument("--r", type=positive_float, default=1.0, help="torque weight, > 0: R is inverted (default 1)")
    parser.add_argument("--base-factor", type=nonnegative_float, default=1.0,
                        help="factor on the unactuated coordinates' weights (default 1)")
    parser.add_argument("--every", type=int, default=20, help="MuJoCo steps between linearizations (default 20: 5 ms)")
    parser.add_argument("--gap-tol", type=positive_float, default=1e-6,
                        help="gap below which a plan sample is in stance [m] (default 1e-6)")
    parser.add_argument("--quick", action="store_true", help="CI smoke run: the point-mass hop planned here, N = 10")
    parser.add_argument("--out", type=out_dir, default=DEFAULT_OUT, help=f"output directory (default {DEFAULT_OUT})")
    parser.add_argument("--json", action="store_true", help="print results.json on stdout instead of the table")
    args = parser.parse_args(argv)
    if args.every < 1:
        parser.error("--every must be >= 1")
    refuse_with_quick(parser, args, ["plan"], "the point-mass hop it plans (N = 10)")
    with tempfile.TemporaryDirectory() as tmp:
        plan = args.plan
        if args.quick:
            task = Path(tmp) / "hop.toml"
            task.write_text(QUICK_TASK)
            plan = Path(tmp) / "hop"
            if planner_command(["plan", "point_mass", "--task", str(task), "--out", str(plan), "--no-validate", "--no-plots", "-q"]) != 0:
                raise SystemExit("the quick hop did not converge")
        elif plan is None:
            parser.error("a plan directory is required (or --quick)")
        rec = probe(plan, args.q, args.v, args.r, args.base_factor, args.every, args.gap_tol)
    return report(args.out, rec, table(rec), args.json)


if __name__ == "__main__":
    sys.exit(run_main(main))
