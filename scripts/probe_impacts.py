"""What a plan's recovered impacts are, step by step: landings, or push-offs lumped into an impact? (session 35)

For each impact of a plan (summary.json), the contact point's normal and tangential velocity and the kinetic energy
before and after it (the recovery's v_pre, v_post at the impact's posture), and for each step of its frozen run the
clock rate R (the step's physical time over h s) and an energy balance on the plan's own states:

    dKE = motors + gravity + auxiliary + rest,   motors = (B u_k)^T (q_{k+1} - q_k),   gravity = V(q_k) - V(q_{k+1}),

auxiliary the work of the step's auxiliary impulses P on the contact point's velocity at the step's end (P^T J(q_{k+1})
v_{k+1}), rest that of the contact forces of the DAE fields plus implicit Euler's own loss, -dv^T M dv / 2 with M
constant (the point mass, where a step without a DAE share has exactly that rest).

What it found on Capler's main-job plan (docs/validation.md, session 35): four of its six impacts have a push-off
lumped into the impact (three right after a landing, one inside a stance), partly frozen steps (R 0.35-0.64) in which
the motors do 5-15 J while the auxiliary impulse, at n(q_{k+1}) on an end velocity whose point already rises (the
secant normal velocity nbar^T v_{k+1} is 0 there, so alpha is free), does up to +14 J of work; the recovery then
reported post-impact normal velocities of +1.5 to +6.6 m/s and more kinetic energy after the "impact" than before,
because its v_post lumped every auxiliary increment of the frozen run, the support of its running parts included.
Since session 36 a run ends where the clock ran after its impact (result.recover): the same plan has 11 impacts and
post-impact normal velocities up to +1.78 m/s. A run of two partly frozen steps is still one impact, so the
point-mass drop's landing still reads +0.89 m/s after impact while the plan's states rest on the ground.

--plan runs `planner plan ARGS` with a variant of the step, not kept: the auxiliary fields act along the step's secant
normal and tangent (the averaged gradients SwitchVelocity.SECANT already uses in alpha's and zeta's switching
functions) instead of n(q_{k+1}), t(q_{k+1}). Their impulse then does no work on v_{k+1} where alpha is free (nbar^T
v_{k+1} = 0) and removes energy where it acts: dissipative by construction. StepForm.MASS_MATRIX only.

    python -m scripts.probe_impacts DIR                          # the plan in DIR (needs its nlp_x)
    python -m scripts.probe_impacts --plan capler --out DIR --no-validate   # the hint-free plan with the variant
Writes OUT/results.json (default results/probe/impacts, beside probe_early_stop's, probe_lqr's and probe_steps'; the
plan's directory stays as written).
"""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import sys
from pathlib import Path
from unittest import mock

import casadi as ca
import numpy as np
import pinocchio as pin

from planner.contact import plane_axes
from planner.discretization import ImplicitEulerStep
from planner.errors import InputError
from planner.result import read_summary, read_trajectory
from scripts._report import out_dir, refuse_beside, report, run_main, script_parser
from scripts.probe_replay import plan_problem

DEFAULT_OUT = Path("results/probe/impacts")


@contextlib.contextmanager
def secant_impulses():
    """Within the block, every ImplicitEulerStep built (not FESD's stages) moves the velocities by its auxiliary
    impulses along the secant gradients of its velocity switches instead of the end point's (module docstring)."""
    plain = ImplicitEulerStep.build

    def build(self, y_k, y_next, u_k, s_k=1.0, h=0.01, tag="", field_scale=None, dy=None, dgap=None, gap_weight=None):
        step = plain(self, y_k, y_next, u_k, s_k, h, tag, field_scale, dy, dgap, gap_weight)
        if dy is not None or self._secant is None:
            return step
        if self.mm is None:
            raise InputError("the secant impulses need ProblemOptions.step_form MASS_MATRIX (the default)")
        sys_ = self.system
        nq, nv = sys_.nq, sys_.nv
        rows, mask = self._secant
        q_k, q_next = y_k[:nq], y_next[:nq]
        shift = rows(q_k, q_next) - rows(q_next, q_next)  # (n_sigma, nv): secant minus end-point gradients
        coef = ca.mtimes(ca.DM(self.C), self.monomials_of(step.w))
        if sys_.n_lambda:
            coef = coef + ca.mtimes(ca.DM(self._force_map()), coef[0] * step.w[self.w_blocks["forces"]][self.lam_slice])
        if field_scale is not None:
            coef = coef * field_scale
        rates = ca.mtimes(sys_.impulse_fn(y_next, u_k), coef)  # (2 n_contacts,): normal, tangential impulse rates [N]
        force = ca.DM.zeros(nv)
        for i, sw in enumerate(sys_.switches):
            if mask[i]:
                c = sys_.labels.index(sw.contact)
                force = force + shift[i, :].T * rates[2 * c + (0 if sw.function == "n^T v" else 1)]
        # the mass-matrix step's velocity rows are M dv - h s (generalized forces)
        g = ca.vertcat(step.g[:nq], step.g[nq : nq + nv] - h * s_k * force, step.g[nq + nv :])
        return dataclasses.replace(step, g=g)

    with mock.patch.object(ImplicitEulerStep, "build", build):
        yield


def probe(out_dir: Path) -> dict:
    """The records of the plan in out_dir (module docstring): per impact its point's velocities [m/s], kinetic
    energies [J] and its steps' energy balance [J]."""
    summary = read_summary(out_dir)
    problem, x = plan_problem(out_dir, summary)  # implicit Euler: a FESD plan's point does not fit it (InputError)
    parts = problem.split(x)
    Y, U, W, S, h = parts["Y"], parts["U"], parts["W"], parts["S"], problem.h
    sys_ = problem.system
    dyn, nq, nv = sys_.dyn, sys_.nq, sys_.nv
    model = dyn.robot.model
    data = model.createData()
    B = np.asarray(dyn.actuation, float)

    def kinetic(q, v) -> float:
        return 0.5 * float(v @ np.asarray(dyn.mass(q)) @ v)

    def potential(q) -> float:
        return float(pin.computePotentialEnergy(model, data, q))

    def point_velocity(contact: str, q, v) -> tuple[float, float]:
        c = sys_.contacts[sys_.labels.index(contact)]
        normal, tangent = plane_axes(c.normal)
        vel = np.asarray(dyn.point_jacobian(c.point)(q))[:3] @ v
        return float(normal @ vel), float(tangent @ vel)

    def balance(k: int) -> dict:
        q0, q1, v0, v1 = Y[k, :nq], Y[k + 1, :nq], Y[k, nq : nq + nv], Y[k + 1, nq : nq + nv]
        dke, motors, gravity = kinetic(q1, v1) - kinetic(q0, v0), float((B @ U[k]) @ (q1 - q0)), potential(q0) - potential(q1)
        # the step's auxiliary impulses (normal, tangential per contact) [N s] and their work on v_{k+1}
        impulses = np.asarray(sys_.impulse_fn(Y[k + 1], U[k])) @ problem.builder.coefficients(W[k]) * h * S[k]
        auxiliary = sum(float(np.dot(impulses[2 * c : 2 * c + 2], point_velocity(label, q1, v1))) for c, label in enumerate(sys_.labels))
        return {"step": k, "clock_rate": float((Y[k + 1, -1] - Y[k, -1]) / (h * S[k])), "dke": dke, "motors": motors,
                "gravity": gravity, "auxiliary": float(auxiliary), "rest": dke - motors - gravity - float(auxiliary),
                "impulse": impulses.tolist()}

    records = []
    t, q_samples = (read_trajectory(out_dir)[k] for k in ("t", "q"))
    for imp in summary.get("impacts", []):
        a, b = round(imp["tau_start"] / h), round(imp["tau_end"] / h)
        # the recovery's posture of the impact, its sample's (the end of its first frozen step, or for a landing at
        # a node that node: Y[a + 1] there gave other energies than the summary's)
        q = q_samples[int(np.argmin(np.abs(t - imp["time"])))]
        v_pre, v_post = np.asarray(imp["v_pre"], float), np.asarray(imp["v_post"], float)
        (vn_pre, vt_pre), (vn_post, vt_post) = (point_velocity(imp["contact"], q, v) for v in (v_pre, v_post))
        steps = [balance(k) for k in range(a, b)]
        records.append({"time": imp["time"], "contact": imp["contact"], "tap": bool(imp.get("tap", False)),
                        "impulse": imp["impulse"], "impulse_tangential": imp["impulse_tangential"],
                        "normal_velocity": [vn_pre, vn_post], "tangential_velocity": [vt_pre, vt_post],
                        "kinetic_energy": [kinetic(q, v_pre), kinetic(q, v_post)], "steps": steps})
    return {"plan": str(out_dir), "impacts": records}


def table(rec: dict) -> str:
    lines = [f"impacts of {rec['plan']} (velocities of the contact point [m/s], energies [J]; steps: clock rate R, "
             "dKE = motors + gravity + auxiliary + rest)",
             "| time [s] | point | impulse n, t [N s] | v_n before -> after | v_t before -> after | KE before -> after | steps (R, motors, gravity, auxiliary, rest) |",
             "|---|---|---|---|---|---|---|"]
    for r in rec["impacts"]:
        steps = "; ".join(f"{s['step']}: R {round(s['clock_rate'], 2) + 0.0:.2f}, {s['motors']:+.2f}, {s['gravity']:+.2f}, "
                          f"{s['auxiliary']:+.2f}, {s['rest']:+.2f}" for s in r["steps"])
        (n0, n1), (t0, t1), (e0, e1) = r["normal_velocity"], r["tangential_velocity"], r["kinetic_energy"]
        lines.append(f"| {r['time']:.4f}{' (tap)' if r['tap'] else ''} | {r['contact']} | {r['impulse']:.3f}, "
                     f"{r['impulse_tangential']:+.3f} | {n0:+.3f} -> {n1:+.3f} | {t0:+.3f} -> {t1:+.3f} | "
                     f"{e0:.2f} -> {e1:.2f} | {steps} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = script_parser(__doc__)
    parser.add_argument("plan_dir", type=Path, nargs="?", help="a plan's result directory")
    parser.add_argument("--out", type=out_dir, default=DEFAULT_OUT, help=f"where results.json goes (default {DEFAULT_OUT})")
    parser.add_argument("--json", action="store_true", help="print the records as JSON instead of the table")
    parser.add_argument("--plan", nargs=argparse.REMAINDER, metavar="ARGS",
                        help="run `planner plan ARGS` with the secant impulses instead (last option)")
    args = parser.parse_args(argv)
    if args.plan is not None:  # (its plan directory, --out and --json were dropped, no results.json written)
        refuse_beside(parser, args, ["plan_dir", "out", "json"],
                      "--plan runs `planner plan ARGS`, which writes its --out")
        from planner.cli import main as cli

        with secant_impulses():
            return cli(["plan", *args.plan])
    if args.plan_dir is None:
        parser.error("give a plan's result directory, or --plan ARGS")
    rec = probe(args.plan_dir)
    return report(args.out, rec, table(rec), args.json)


if __name__ == "__main__":
    sys.exit(run_main(main))
