"""Does the time-freezing simulator reproduce a plan from the plan's own controls? (issue 9, sessions 31-32)

The route to the speed goal that docs/solve-research.md names starts the OCP from a motion built by stepping the
time-freezing dynamics (a rollout), so it matters whether a rollout can follow a plan at all. This probe replays a
Capler plan (a `planner plan` result directory) on its own grid: step k is solved by the simulator's step NLP
(`planner.simulate`'s penalty homotopy, as scripts/probe_multiphase.py's pd start) from the rollout's state with the
plan's control U_k plus a joint PD towards the plan's next state (hip and knee; at the plan's own states the PD adds
nothing, so the plan is a solution of every step). Reported: the first step where the rollout leaves the plan (state
difference above DEPARTURE_TOL), the plan's and the rollout's selectors (alpha, beta, gamma, zeta) there, how well the plan's
own step solves the simulator's step NLP there (largest equality row, smallest complementarity row), and where the
rollout ends against the plan. --plan-first starts each step's solve at the plan's own solution; --liftoff-first at a
free-flight prediction (explicit Euler under gravity, selectors guessed there), a branch rule that needs no plan;
--first-rho0 R starts either one's penalty homotopy at R; --by-clock reads the plan at the rollout's own clock (a
tracked physical-time plan) instead of at its step; --family K solves step K with its clock advance fixed (clock_family);
--solve then solves the OCP from the rollout. The record lists the plan's landings (nodes reached from above).

    python -m scripts.probe_replay DIR              # DIR: e.g. `planner plan capler --out DIR`
    python -m scripts.probe_replay DIR --plan-first [--first-rho0 1e4]
    python -m scripts.probe_replay DIR --liftoff-first --first-rho0 1e4 [--family K]
    python -m scripts.probe_replay DIR --by-clock [--liftoff-first --first-rho0 1e4] [--solve homotopy|held]
Writes OUT/results.json.
"""
from __future__ import annotations

import sys
from pathlib import Path

import casadi as ca
import numpy as np

from planner.errors import InputError
from planner.homotopy import constraint_violation
from planner.problem import build_problem
from planner.result import check_same_result, read_robot, read_start, read_summary, read_task, read_trajectory
from planner.simulate import SimulateOptions, _ipopt_options, _penalized_nlp
from scripts import probe_multiphase as pm
from scripts._report import nonnegative_float, out_dir, positive_float, report, run_main, script_parser

DEPARTURE_TOL = 1e-3  # [m, rad, m/s, rad/s] the simulator's steps meet IPOPT's tol; 1e-3 is a different branch, not round-off
FAMILY_RHO = (1e2, 1e3, 1e4, 1e5, 1e6, 1e7)  # the simulator's schedule (rho0 1e2, kappa 10) run to its end, never stopped early
FAMILY_POINTS = 11  # clock advances 0, h/10, ..., h
LANDED_GAP = 1e-4  # [m] a node this near the ground has landed (flight nodes are >= 5 mm up in the plans seen)
BASE_Z, GRAVITY = 1, 9.81  # Capler's base height in q [m] and gravity [m/s^2] (robots/capler.xml)


def plan_problem(out_dir: Path, summary: dict | None = None):
    """(problem, x) of the plan in out_dir: the task as kept in its trajectory.npz, the robot its summary.json
    names (summary: that file's contents when already read)."""
    arrays = read_trajectory(out_dir, ("task_json",))
    summary = read_summary(out_dir) if summary is None else summary
    made_by = summary.get("command")
    if made_by not in (None, "plan"):  # (a simulate result was refused for its task: "`planner plan` needs [plan]")
        raise InputError(f"{out_dir} is a `planner {made_by}` result, not a plan: give one of `planner plan`")
    check_same_result(out_dir, summary, arrays)
    problem = build_problem(read_robot(out_dir, summary), read_task(out_dir, arrays))
    return problem, read_start(out_dir, problem.signature, problem.nx, arrays)


def step_nlp(problem, u_k: np.ndarray, clock_advance: bool = False):
    """The simulator's step NLP under the fixed control u_k (nu,), no PD: unknowns (y_next, w, s_c), parameters
    (y_k, [c,] rho); with clock_advance a last row y_next's clock - y_k's - c (to be held at 0). Returns (nlp, comp_fn,
    number of equalities, number of complementarity rows, the step's lbw and ubw)."""
    ny = problem.system.ny
    y_k, y_next, c = ca.SX.sym("y_k", ny), ca.SX.sym("y_next", ny), ca.SX.sym("c")
    step = problem.builder.build(y_k, y_next, ca.DM(u_k), 1.0, problem.h)
    nlp, comp_fn, n_eq, n_comp = _penalized_nlp(ca.vertcat(y_next, step.w), [step], ca.vertcat(y_k, c) if clock_advance else y_k)
    if clock_advance:
        nlp["g"] = ca.vertcat(nlp["g"], y_next[-1] - y_k[-1] - c)
    return nlp, comp_fn, n_eq, n_comp, (step.lbw, step.ubw)


def step_residual(problem, k: int, Y: np.ndarray, W: np.ndarray, U: np.ndarray) -> dict:
    """The plan's step k (Y (N + 1, ny), W (N, nw), U (N, nu)) in the simulator's step NLP (controls U_k, no PD):
    the largest equality row and the smallest complementarity row (>= 0 when its pairs are complementary)."""
    nlp, _, n_eq, _, _ = step_nlp(problem, U[k])
    g = np.asarray(ca.Function("g", [nlp["x"], nlp["p"]], [nlp["g"]])(np.concatenate([Y[k + 1], W[k], [0.0]]),
                                                                       np.concatenate([Y[k], [1.0]]))).ravel()
    return {"equality_max": float(np.max(np.abs(g[:n_eq]))), "complementarity_min": float(np.min(g[n_eq:]))}


def landings(problem, Y: np.ndarray, W: np.ndarray, U: np.ndarray) -> list[dict]:
    """The plan's landings (Y (N + 1, ny), W (N, nw), U (N, nu)), in node order: nodes k where a contact's gap [m] is
    below LANDED_GAP after a node above it, with the contact, the gap there, and the selectors and clock advance [s] of
    the steps k - 1 (into the node) and k (out of it). A whole flight step (selectors 0, 1, 0, 1, advance h) ending at a
    gap of ~0 is a landing at the node; a step with beta < 1 enters the ground inside the step."""
    gaps = np.array([np.asarray(problem.system.gap_fn(Y[k], U[min(k, len(U) - 1)])).ravel() for k in range(len(Y))])
    ns, labels = problem.system.n_sigma, problem.system.labels
    return [{"node": k, "contact": labels[c], "gap_m": float(gaps[k, c]),
             "into": {"selectors": W[k - 1, :ns].tolist(), "advance_s": float(Y[k, -1] - Y[k - 1, -1])},
             "out": {"selectors": W[k, :ns].tolist(), "advance_s": float(Y[k + 1, -1] - Y[k, -1])}}
            for k in range(1, len(Y) - 1) for c in range(gaps.shape[1]) if gaps[k - 1, c] > LANDED_GAP >= gaps[k, c]]


def clock_family(problem, k: int, y_k: np.ndarray, U: np.ndarray, start: np.ndarray, advances) -> list[dict]:
    """Step k from the state y_k (ny,) under the control U[k] (no PD), its clock advance t+ - t fixed to each of
    `advances` [s]: the largest complementarity product the penalty homotopy reaches (rho = FAMILY_RHO, each NLP
    warm-started from the last, the first from start: (y_next, w) of a solution of the step) and the selectors.
    Products at the simulator's tolerance for a whole interval of advances: the step has a family of solutions."""
    ny, ns = problem.system.ny, problem.system.n_sigma
    nlp, comp_fn, n_eq, n_comp, (lbw, ubw) = step_nlp(problem, U[k], clock_advance=True)
    solver = ca.nlpsol("family", "ipopt", nlp, _ipopt_options(SimulateOptions()))
    bounds = {"lbx": np.concatenate([np.full(ny, -np.inf), lbw, [0.0]]), "ubx": np.concatenate([np.full(ny, np.inf), ubw, [np.inf]]),
              "lbg": np.zeros(n_eq + n_comp + 1), "ubg": np.concatenate([np.zeros(n_eq), np.full(n_comp, np.inf), [0.0]])}
    rows = []
    for a in advances:
        x = np.concatenate([start, [0.0]])
        for rho in FAMILY_RHO:
            p = np.concatenate([y_k, [a, rho]])
            x = np.asarray(solver(x0=x, p=p, **bounds)["x"]).ravel()
        rows.append({"advance_s": float(a), "complementarity": float(np.max(np.asarray(comp_fn(x, p)))),
                     "selectors": x[ny : ny + ns].tolist()})
    return rows


def replay(problem, x_plan: np.ndarray, kp: float, kd: float, plan_first: bool, tol: float = DEPARTURE_TOL,
           first_rho0: float | None = None, liftoff_first: bool = False, family_step: int | None = None,
           by_clock: bool = False, solve: str | None = None) -> dict:
    """The record of the module docstring for the plan x_plan (nx,) of problem; first_rho0: the penalty the
    plan-first or lift-off-first start's homotopy begins with (None: the simulator's); family_step: a step whose
    clock_family is recorded from the plan's and from the rollout's state there (FAMILY_POINTS advances in [0, h]).
    by_clock: the reference (control and PD target) is the plan read at the rollout's own clock + h, as a tracked
    physical-time plan would be (probe_multiphase.reference), instead of the plan's step k; then the departure is
    measured on the base against the plan at the rollout's clock, and no step's selectors are compared. solve:
    "homotopy" or "held", the OCP then solved from the rollout (probe_multiphase.solve_from), with the rollout's
    violations of the OCP's constraint blocks recorded."""
    if plan_first and liftoff_first:
        raise ValueError("plan_first and liftoff_first are two rules for the same first start: choose one")
    nq, nv, system, builder = problem.system.nq, problem.system.nv, problem.system, problem.builder
    plan = problem.split(x_plan)
    Y, U, W = plan["Y"], plan["U"], plan["W"]

    def at(k, clock):
        return U[k], Y[k + 1, :nq], Y[k + 1, nq : nq + nv]

    physical = {"t": Y[:, -1], "Q": Y[:, :nq], "V": Y[:, nq : nq + nv], "U": U}  # frozen nodes repeat a time: np.interp takes one

    def plan_start(k, y_k, u_ff):  # the plan's own solution of step k
        return np.concatenate([Y[k + 1], W[k], [0.0]])

    def liftoff_start(k, y_k, u_ff):
        # free flight for one step, explicit: the base falls, the joints keep their speed. Not the simulator's restart
        # predictor (planner.simulate._predictor, the implicit-Euler step with every selector 1): from its prediction
        # the main job's replay still stays on the ground at step 26 (measured, --first-rho0 1e4: 0.43 m short)
        y = y_k.copy()
        y[nq + BASE_Z] -= GRAVITY * problem.h
        y[:nq] += problem.h * y[nq : nq + nv]
        y[-1] += problem.h
        return np.concatenate([y, builder.guess(y, u_ff), [0.0]])

    first = plan_start if plan_first else liftoff_start if liftoff_first else None
    x, info = pm.stepwise_start(problem, physical if by_clock else None, "pd", kp=(kp, kp), kd=(kd, kd), at=None if by_clock else at,
                                first=first, first_rho0=first_rho0)
    rollout = problem.split(x)
    Yr, Wr = rollout["Y"], rollout["W"]
    if by_clock:  # the base (x, z) [m] against the plan at the rollout's clock, read as the reference was
        q_at = pm.reference(physical)[1]
        base = [0, BASE_Z]
        dev = np.array([np.max(np.abs(q_at(y[-1])[base] - y[base])) for y in Yr])
    else:
        dev = np.max(np.abs(Yr[:, : nq + nv] - Y[:, : nq + nv]), axis=1)  # per node
    rec = {"N": problem.N, "kp": kp, "kd": kd, "plan_first": plan_first, "liftoff_first": liftoff_first, "first_rho0": first_rho0, "tol": tol,
           "by_clock": by_clock, "end_clock_s": float(Yr[-1, -1]), "plan_end_clock_s": float(Y[-1, -1]),
           "steps_failed": info["steps_failed"], "max_deviation": float(dev.max()),
           "end_base_error_m": (Yr[-1, :2] - Y[-1, :2]).tolist(), "departure": None}
    if dev.max() > tol:
        k = int(np.argmax(dev > tol)) - 1  # the step whose end state left the plan
        rec["departure"] = {"step": k, "clock_s": float((Yr if by_clock else Y)[k, -1]), "deviation": float(dev[k + 1])}
        if not by_clock:  # the plan's step k is the rollout's step k only when read by step
            n_sel = system.n_sigma
            rec["departure"] |= {"plan_selectors": W[k, :n_sel].tolist(), "rollout_selectors": Wr[k, :n_sel].tolist(),
                                 "plan_step_in_simulator": step_residual(problem, k, Y, W, U)}
    rec["landings"] = landings(problem, Y, W, U)
    if solve is not None:
        rec["start_violations"] = constraint_violation(problem, x)
        rec["solve"] = pm.solve_from(problem, x, held=solve == "held")
    if family_step is not None:
        k, start = family_step, np.concatenate([Y[family_step + 1], W[family_step]])
        advances = np.linspace(0.0, problem.h, FAMILY_POINTS)
        rec["family"] = {"step": k, **{name: {"gap_m": np.asarray(system.gap_fn(y[k], U[k])).ravel().tolist(),
                                              "rows": clock_family(problem, k, y[k], U, start, advances)}
                                       for name, y in (("plan", Y), ("rollout", Yr))}}
    return rec


def table(rec: dict) -> str:
    lines = [f"replay of {rec.get('plan', 'the plan')} (N = {rec['N']}, PD kp {rec['kp']:g} kd {rec['kd']:g}, plan first: "
             f"{rec['plan_first']}, lift-off first: {rec['liftoff_first']}, reference by {'clock' if rec['by_clock'] else 'step'}): "
             f"{rec['steps_failed']} steps failed, largest deviation {rec['max_deviation']:.3g}, end base error "
             f"{np.round(rec['end_base_error_m'], 4).tolist()} m, end clock {rec['end_clock_s']:.3f} s (plan {rec['plan_end_clock_s']:.3f} s)"]
    d = rec["departure"]
    if d is None:
        lines.append(f"  the rollout stays within {rec['tol']:g} of the plan")
    elif rec["by_clock"]:
        lines.append(f"  the base leaves the plan at step {d['step']} (clock {d['clock_s']:.4f} s, deviation {d['deviation']:.3g} m)")
    else:
        r = d["plan_step_in_simulator"]
        lines += [f"  leaves the plan at step {d['step']} (clock {d['clock_s']:.4f} s, deviation {d['deviation']:.3g})",
                  f"  selectors there: plan {np.round(d['plan_selectors'], 3).tolist()}, rollout {np.round(d['rollout_selectors'], 3).tolist()}",
                  f"  the plan's step in the simulator's NLP: equality rows {r['equality_max']:.1e}, complementarity rows >= {r['complementarity_min']:.1e}"]
    for ld in rec.get("landings", []):
        lines.append(f"  plan lands at node {ld['node']} ({ld['contact']}, gap {ld['gap_m']:+.1e} m): step in {np.round(ld['into']['selectors'], 3).tolist()} "
                     f"{ld['into']['advance_s'] * 1e3:.2f} ms, step out {np.round(ld['out']['selectors'], 3).tolist()} {ld['out']['advance_s'] * 1e3:.2f} ms")
    if "solve" in rec:
        sv = rec["solve"]
        lines.append("  the rollout's violations: " + ", ".join(f"{k} {v:.1e}" for k, v in rec["start_violations"].items()))
        lines.append(f"  {'held schedule' if sv['held'] else 'homotopy'} from the rollout: converged {sv['converged']}, {sv['iterations']} it, "
                     f"{sv['wall_s']:.1f} s, control cost {sv['control_cost']}")
        lines += [f"    {label:<24} {it:5d} it  {status}" for label, it, status in sv["nlps"]]
    f = rec.get("family")
    if f is not None:
        lines.append(f"  step {f['step']} with its clock advance fixed (plan's control, no PD), largest complementarity product reached:")
        lines.append("    advance [ms]: " + " ".join(f"{row['advance_s'] * 1e3:7.1f}" for row in f["plan"]["rows"]))
        for name in ("plan", "rollout"):
            lines.append(f"    {name:7s} (gap {f[name]['gap_m'][0]:+.1e} m): " + " ".join(f"{row['complementarity']:7.0e}" for row in f[name]["rows"]))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = script_parser(__doc__)
    parser.add_argument("plan", type=Path, help="a `planner plan` result directory of Capler (hip and knee PD)")
    parser.add_argument("--kp", type=nonnegative_float, default=200.0, help="joint PD stiffness [N m/rad]")
    parser.add_argument("--kd", type=nonnegative_float, default=5.0, help="joint PD damping [N m s/rad]")
    parser.add_argument("--plan-first", action="store_true", help="start each step's solve at the plan's own solution")
    parser.add_argument("--liftoff-first", action="store_true", help="start each step's solve at a free-flight prediction")
    parser.add_argument("--first-rho0", type=positive_float,
                        help="with --plan-first or --liftoff-first: the penalty that start's homotopy "
                        "begins with (default the simulator's; 1e4 keeps the start's branch where a weak penalty lets the regularizer move it)")
    parser.add_argument("--by-clock", action="store_true", help="read the plan (control, PD target) at the rollout's own clock + h "
                        "instead of at its step index")
    parser.add_argument("--solve", choices=("homotopy", "held"), help="then solve the OCP from the rollout: the hint-free "
                        "homotopy or the held-schedule replan")
    parser.add_argument("--family", type=int, metavar="K", help="also solve step K with its clock advance fixed at "
                        f"{FAMILY_POINTS} values in [0, h], from the plan's and from the rollout's state there")
    parser.add_argument("--out", type=out_dir, default=Path("results/bench/probe_replay"),
                        help="output directory (default results/bench/probe_replay)")
    parser.add_argument("--json", action="store_true", help="print the record as JSON instead of the table")
    args = parser.parse_args(argv)
    if args.plan_first and args.liftoff_first:
        parser.error("--plan-first and --liftoff-first are two rules for the same first start: choose one")
    if args.first_rho0 is not None and not (args.plan_first or args.liftoff_first):
        parser.error("--first-rho0 needs --plan-first or --liftoff-first")
    if args.by_clock and args.plan_first:
        parser.error("--plan-first starts step k at the plan's step k, which --by-clock no longer follows: choose one")
    if args.family is not None and args.family < 0:
        parser.error(f"--family must be a step index >= 0, got {args.family}")
    problem, x = plan_problem(args.plan)
    if problem.robot.dof_names != ("base_x", "base_z", "hip", "knee"):  # its PD and starts index Capler's hip and knee
        raise InputError(f"{args.plan} holds a plan of {problem.robot.name!r} (joints {', '.join(problem.robot.dof_names)}); "
                         "this probe reads plans of Capler (joints base_x, base_z, hip, knee)")
    if args.family is not None and args.family >= problem.N:
        parser.error(f"--family must be a step index < N = {problem.N}, got {args.family}")
    rec = {"plan": str(args.plan), **replay(problem, x, args.kp, args.kd, args.plan_first, first_rho0=args.first_rho0,
                                                liftoff_first=args.liftoff_first, family_step=args.family, by_clock=args.by_clock,
                                                solve=args.solve)}
    return report(args.out, rec, table(rec), args.json)


if __name__ == "__main__":
    sys.exit(run_main(main))
