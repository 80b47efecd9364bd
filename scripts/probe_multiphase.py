"""A start that brings the motion? Capler's physical-time multi-phase hop OCP and three time-freezing starts from it (issue 9)

The route docs/solve-research.md names for the 10 s goal: plan the hops with a cheaper model whose contact schedule
is given, carry that motion onto the time-freezing grid, and let the time-freezing OCP finish from there.

The cheaper model (`hop_ocp`): stance, flight, stance, ... with K flights and the K - 1 intermediate footholds
(`--landings`, each kept on its side of every hole) as variables; each phase has its own step length. Implicit
Euler in q and v with M(q+)(v+ - v) = dt (B u - h(q+, v+)) + J^T Lambda in stance (Lambda an impulse [N s] in the
friction cone, so the first stance step absorbs the landing as an inelastic impact), the foot's velocity J v = 0 at
every stance node and its position on the foothold at each stance's first node (a position-only stance lets the
discrete impulses inject energy: plans of cost ~1 instead of ~140), flights above the ground and outside the holes,
q0 at rest to the target at rest in --T seconds, cost sum dt u^T u.

Starts on the task's grid (`--start`), each followed by the time-freezing solve a user would run from it:
  interp  the motion sampled at tau (running clock), the controls held, each step's selectors from
          ImplicitEulerStep.guess; then the default hint-free homotopy from that point instead of y_0 everywhere.
  pd      the OCP's own implicit-Euler steps solved one at a time (the simulator's penalty homotopy per step), the
          controls u_ff + P (q_ref - q+) - D (v+ - v_ref) at the joints with the reference read at the step's clock;
          then `planner plan --init`'s solve (held schedule, else the penalty replan).
  track   the same steps with u free in its bounds and ||(q+, v+) - reference||^2 + 1e-4 ||u - u_ff||^2 in each
          step's objective, the friction and impact cones, above-ground rows and holes imposed per step; then as pd.
Per run: the hop OCP's iterations, status, cost and footholds; the start's wall time, per-step IPOPT iterations,
the base's final x [m] and clock [s] (the target is x = 3 m; tau_f = 2.5 s), the largest violation of each
constraint block of the time-freezing NLP and of its bounds at the start (planner.homotopy.constraint_violation);
the solve's verdict, iterations, wall time and control cost.
Writes OUT/results.json.

    python -m scripts.probe_multiphase --landings 0.85 1.85 --T 2.3 --start pd
    python -m scripts.probe_multiphase --quick --json     # CI smoke run: N = 10, 3 nodes per phase, no solve
"""
from __future__ import annotations

import sys
import time
from dataclasses import replace
from pathlib import Path

import casadi as ca
import numpy as np

from planner.dynamics import Dynamics
from planner.homotopy import SolveOptions, constraint_violation, replan_options, solve
from planner.problem import _path_functions, build_problem
from planner.simulate import SimulateOptions, _first_converged, _ipopt_options, _penalized_nlp, _solve_homotopy
from scripts._report import finite_float, out_dir, positive_float, refuse_with_quick, report, run_main, script_parser
from scripts.bench_pipeline import capler_case

HIP, KNEE = 2, 3  # Capler's joint coordinates in q = (x_B, z_B, phi_hip, phi_knee)
STEP_LENGTH = (0.005, 0.25)  # [s] bounds of a phase's step: below, a stance cannot hold its push; above, the grid is too coarse
FOOTHOLD_MARGIN = 0.02  # [m] a foothold's distance from a hole's edge


def hop_ocp(robot, task, landings, T: float, nodes: tuple[int, int], max_iter: int) -> dict:
    """The multi-phase hop OCP (module docstring) solved from a guess that puts the base over each foothold in stance
    and on a line between them in flight. landings: foot x [m] of the intermediate stances, ordered.
    Returns the solution (phases, step lengths dts [s], footholds, Q, V (n + 1, nq), U (n, nu)) and IPOPT's record."""
    dyn = Dynamics(robot)
    nq, nv, nu = robot.nq, robot.nv, robot.nu
    B, foot, J_foot = ca.DM(dyn.actuation), dyn.point_position("foot"), dyn.point_jacobian("foot")
    above = [dyn.point_position(p) for p in task.plan.above_ground]
    q_lo, q_hi = task.q_bounds(robot)
    u_lo, u_hi = robot.u_lower, robot.u_upper
    mu, holes = task.contacts[0].mu, task.plan.holes
    q0, qT = np.array(task.initial.q, float), np.array(task.plan.target_q, float)
    K = len(landings) + 1
    phases = ["stance"] + ["flight", "stance"] * K
    holds = [float(foot(q0)[0]), *landings, float(foot(qT)[0])]
    opti = ca.Opti()
    dts, xf = opti.variable(len(phases)), opti.variable(K + 1)
    opti.subject_to(xf[0] == holds[0])
    opti.subject_to(xf[K] == holds[-1])
    for i in range(1, K):  # each foothold stays on the side of every hole its guess is on
        for e in holes:
            opti.subject_to(xf[i] <= e.x - e.a - FOOTHOLD_MARGIN if holds[i] < e.x else xf[i] >= e.x + e.a + FOOTHOLD_MARGIN)
    q, v = ca.DM(q0), ca.DM.zeros(nv)
    Q, V, U, cost, duration, stance = [q], [v], [], 0, 0, -1
    for i, phase in enumerate(phases):
        n, dt = nodes[0] if phase == "stance" else nodes[1], dts[i]
        stance += phase == "stance"
        opti.subject_to(opti.bounded(STEP_LENGTH[0], dt, STEP_LENGTH[1]))
        duration += n * dt
        for j in range(n):
            qn, vn, u = opti.variable(nq), opti.variable(nv), opti.variable(nu)
            opti.subject_to(opti.bounded(u_lo, u, u_hi))
            opti.subject_to(opti.bounded(q_lo, qn, q_hi))
            opti.subject_to(qn == q + dt * vn)
            momentum = ca.mtimes(dyn.mass(qn), vn - v) - dt * (ca.mtimes(B, u) - dyn.bias(qn, vn))
            p = foot(qn)
            if phase == "stance":
                impulse = opti.variable(2)  # (tangential, normal) [N s]
                Jxz = J_foot(qn)[[0, 2], :]
                momentum -= ca.mtimes(Jxz.T, impulse)
                opti.subject_to(impulse[1] >= 0)
                opti.subject_to(opti.bounded(-mu * impulse[1], impulse[0], mu * impulse[1]))
                opti.subject_to(ca.mtimes(Jxz, vn) == 0)
                if j == 0:
                    opti.subject_to(ca.vertcat(p[0] - xf[stance], p[2] - task.ground_height) == 0)
            else:
                opti.subject_to(p[2] >= task.ground_height)
                for e in holes:
                    opti.subject_to(e.metric(p[0], p[2]) >= 1)
            opti.subject_to(momentum == 0)
            for pos in above:
                opti.subject_to(pos(qn)[2] >= task.ground_height)
            cost += dt * ca.sumsqr(u)
            x_guess = holds[stance] if phase == "stance" else holds[stance] + (j + 1) / n * (holds[stance + 1] - holds[stance])
            opti.set_initial(qn, [x_guess, qT[1], 0.0, 0.0])
            Q.append(qn), V.append(vn), U.append(u)
            q, v = qn, vn
    opti.subject_to(q == qT)
    opti.subject_to(v == 0)
    opti.subject_to(duration == T)
    opti.minimize(cost)
    opti.set_initial(dts, T / len(U))
    opti.set_initial(xf, holds)
    opti.solver("ipopt", {"expand": True, "print_time": False}, {"max_iter": max_iter, "print_level": 0, "sb": "yes", "tol": 1e-8})
    start = time.perf_counter()
    try:
        sol = opti.solve()
    except RuntimeError:  # not converged: the last iterate, for the record
        sol = opti.debug
    stats = opti.stats()
    value = lambda e: np.asarray(sol.value(e), float)  # noqa: E731
    steps = np.concatenate([[value(dts[i]).item()] * (nodes[0] if ph == "stance" else nodes[1]) for i, ph in enumerate(phases)])
    return {"phases": phases, "dts": value(dts).ravel(), "footholds": value(xf).ravel(), "t": np.concatenate([[0.0], np.cumsum(steps)]),
            "Q": np.array([value(x).ravel() for x in Q]), "V": np.array([value(x).ravel() for x in V]),
            "U": np.array([value(x).ravel() for x in U]), "cost": float(value(cost)), "iterations": int(stats["iter_count"]),
            "status": str(stats["return_status"]), "wall_s": time.perf_counter() - start}


def reference(plan: dict):
    """(u_ff, q_ref, v_ref): the hop plan at physical time t [s] (controls held over their step, states linear
    between nodes, the last ones after the plan's end)."""
    t, Q, V, U = plan["t"], plan["Q"], plan["V"], plan["U"]

    def u_ff(tt):
        return U[int(np.clip(np.searchsorted(t, tt) - 1, 0, len(U) - 1))]

    def interp(X):
        return lambda tt: np.array([np.interp(tt, t, X[:, i]) for i in range(X.shape[1])])
    return u_ff, interp(Q), interp(V)


def pack(problem, Y, W, U) -> np.ndarray:
    """The NLP point (nx,) of per-step states Y (N + 1, ny), selectors and forces W (N, nw), controls U (N, nu)."""
    vb, x = problem.var_blocks, np.zeros(problem.nx)
    x[vb["u"]], x[vb["y"]], x[vb["w"]] = U, Y[1:], W
    if "s_c" in vb:
        x[vb["s_c"]] = max(0.0, float(np.max(np.asarray(problem.products(x)))))
    return x


def interpolated_start(problem, plan) -> tuple[np.ndarray, dict]:
    u_ff, q_ref, v_ref = reference(plan)
    N, h, system, builder = problem.N, problem.h, problem.system, problem.builder
    Y, U = np.zeros((N + 1, system.ny)), np.zeros((N, system.nu))
    Y[0] = problem.y0
    for k in range(N):
        t = (k + 1) * h
        Y[k + 1] = np.concatenate([q_ref(t), v_ref(t), [t]])
        U[k] = np.clip(u_ff(t), problem.lbx[problem.var_blocks["u"][k]], problem.ubx[problem.var_blocks["u"][k]])
    W = np.array([builder.guess(Y[k + 1], U[k]) for k in range(N)])
    return pack(problem, Y, W, U), {"step_iterations": 0, "steps_failed": 0}


def stepwise_start(problem, plan, mode: str, kp=(200.0, 200.0), kd=(5.0, 5.0), at=None, first=None,
                   first_rho0: float | None = None) -> tuple[np.ndarray, dict]:
    """Module docstring, starts pd and track: the time-freezing steps solved one at a time. A step whose penalty
    homotopy does not reach the simulator's complementarity tolerance from any of its starts keeps its last iterate
    (counted in steps_failed). at(k, clock) -> (u_ff (nu,), q_ref (nq,), v_ref (nv,)), the reference of step k from
    the state whose clock is `clock` [s]; default: the plan read at clock + h (scripts/probe_replay.py reads a
    time-freezing plan by its step index instead). first(k, y_k, u_ff): a start of step k's solve from the state y_k
    (ny,) with the feed-forward u_ff (nu,) (its unknowns and the slack) to try before the others, or None; its penalty
    homotopy from first_rho0 (default the simulator's rho0)."""
    system, builder, task = problem.system, problem.builder, problem.task
    ny, nu, nw, nq, nv, h, N = system.ny, system.nu, builder.nw, system.nq, system.nv, problem.h, problem.N
    y_k, y_next = ca.SX.sym("y_k", ny), ca.SX.sym("y_next", ny)
    u_ff_s, ref = ca.SX.sym("u_ff", nu), ca.SX.sym("ref", nq + nv)
    u_lo, u_hi = problem.lbx[problem.var_blocks["u"][0]], problem.ubx[problem.var_blocks["u"][0]]
    if mode == "pd":
        u = ca.vertcat(*[u_ff_s[a] + kp[a] * (ref[j] - y_next[j]) - kd[a] * (y_next[nq + j] - ref[nq + j]) for a, j in enumerate((HIP, KNEE))])
    else:
        u = ca.SX.sym("u", nu)
    step = builder.build(y_k, y_next, u, 1.0, h)
    unknowns = ca.vertcat(y_next, step.w) if mode == "pd" else ca.vertcat(y_next, step.w, u)
    nlp, comp_fn, n_eq, n_comp = _penalized_nlp(unknowns, [step], ca.vertcat(y_k, u_ff_s, ref))
    n_extra = 0
    lbx = np.concatenate([np.full(ny, -np.inf), step.lbw] + ([] if mode == "pd" else [u_lo]) + [[0.0]])
    ubx = np.concatenate([np.full(ny, np.inf), step.ubw] + ([] if mode == "pd" else [u_hi]) + [[np.inf]])
    if mode == "track":
        e = y_next[: nq + nv] - ref
        weight = ca.DM([100.0, 100.0, 10.0, 10.0] + [1.0] * nv)  # the base's position first: it is what the joints cannot fix later
        nlp["f"] += ca.dot(weight * e, e) + 1e-4 * ca.dot(u - u_ff_s, u - u_ff_s)
        paths, *_ = _path_functions(system, builder, system.dyn, task, system.contacts, problem.skips, problem.options, ca.SX.sym("hole_scale"))
        rows = [fn(*args) for fn, args in ((paths["above_ground"], (y_next,)), (paths["friction_cone"], (y_next, u, step.w)),
                                           (paths["impact_cone"], (step.w,)), (paths["holes"], (y_next, 1.0))) if fn is not None]
        extra = ca.vertcat(*rows)
        n_extra = extra.shape[0]
        nlp["g"] = ca.vertcat(nlp["g"], extra)
        q_lo, q_hi = task.q_bounds(problem.robot)
        lbx[:nq], ubx[:nq] = q_lo, q_hi
    lbg = np.concatenate([np.zeros(n_eq), np.zeros(n_comp), np.zeros(n_extra)])
    ubg = np.concatenate([np.zeros(n_eq), np.full(n_comp + n_extra, np.inf)])
    options = SimulateOptions()
    solver = ca.nlpsol(f"{mode}_step", "ipopt", nlp, _ipopt_options(options))
    applied = ca.Function("u", [unknowns, ca.vertcat(y_k, u_ff_s, ref)], [u])
    if at is None:
        u_ff, q_ref, v_ref = reference(plan)

        def at(k, clock):
            t = min(clock + h, plan["t"][-1])
            return u_ff(t), q_ref(t), v_ref(t)
    Y, W, U = np.zeros((N + 1, ny)), np.zeros((N, nw)), np.zeros((N, nu))
    Y[0] = problem.y0
    total = {"n_nlp": 0, "iterations": 0, "comp": 0.0, "ok": True, "message": "", "restarted_steps": 0}
    failed, w_prev = 0, None
    for k in range(N):
        u_k, q_k, v_k = at(k, Y[k, -1])
        p = np.concatenate([Y[k], u_k, q_k, v_k])
        fresh = builder.guess(Y[k], u_k)
        tail = [] if mode == "pd" else [np.clip(u_k, u_lo, u_hi)]
        starts = [(np.concatenate([Y[k], w, *tail, [0.0]]), replace(options, rho0=rho0))
                  for rho0 in (options.rho0, options.restart_rho0, 1e-3) for w in ((fresh,) if w_prev is None else (w_prev, fresh))]
        if first is not None:
            starts.insert(0, (first(k, Y[k], u_k), options if first_rho0 is None else replace(options, rho0=first_rho0)))
        x = _first_converged(solver, comp_fn, iter(starts), p, (lbx, ubx, lbg, ubg), options, total, f"step {k}")
        if x is None:
            failed += 1
            x = _solve_homotopy(solver, comp_fn, starts[0][0], p, lbx, ubx, lbg, ubg, options)[0]
        Y[k + 1], W[k] = x[:ny], x[ny : ny + nw]
        U[k] = np.asarray(applied(x[:-1], p)).ravel()
        w_prev = W[k]
    return pack(problem, Y, W, U), {"step_iterations": total["iterations"], "steps_failed": failed}


STARTS = {"interp": interpolated_start, "pd": lambda pb, plan: stepwise_start(pb, plan, "pd"),
          "track": lambda pb, plan: stepwise_start(pb, plan, "track")}


def probe(N: int, landings, T: float, nodes, start: str, max_iter: int, run_solve: bool) -> dict:
    robot, task = capler_case(N)
    plan = hop_ocp(robot, task, landings, T, nodes, max_iter)
    rec = {"N": N, "T": T, "nodes": list(nodes), "start": start,
           "hop_ocp": {k: plan[k] for k in ("iterations", "status", "wall_s", "cost")} | {"footholds": plan["footholds"].tolist()}}
    problem = build_problem(robot, task)
    t0 = time.perf_counter()
    x, info = STARTS[start](problem, plan)
    y_end = x[problem.var_blocks["y"][-1]]
    rec["start_state"] = info | {"wall_s": time.perf_counter() - t0, "base_x_end": float(y_end[0]), "clock_end": float(y_end[-1]),
                                 "violations": constraint_violation(problem, x)}
    if run_solve:
        rec["solve"] = solve_from(problem, x, held=start != "interp")
    return rec


def solve_from(problem, x: np.ndarray, held: bool) -> dict:
    """The OCP solved from the start x (nx,): the held-schedule replan (`--init`'s default) or the hint-free homotopy."""
    options = replace(replan_options(), keep_schedule=True) if held else SolveOptions()
    result = solve(replace(problem, x0=x), options)
    return {"held": held, "converged": result.stats.converged, "iterations": result.stats.ipopt_iterations,
            "wall_s": result.stats.solve_time_s, "control_cost": result.summary().get("control_cost"),
            "nlps": [[r.label, r.iterations, r.status] for r in result.nlps]}


def table(rec: dict) -> str:
    ocp, st = rec["hop_ocp"], rec["start_state"]
    lines = [f"hop OCP (T = {rec['T']} s, {rec['nodes']} nodes per stance/flight): {ocp['iterations']} it, {ocp['status']}, "
             f"{ocp['wall_s']:.2f} s, cost {ocp['cost']:.2f}, footholds {np.round(ocp['footholds'], 3).tolist()}",
             f"start {rec['start']}: {st['wall_s']:.2f} s, {st['step_iterations']} step iterations, {st['steps_failed']} steps failed, "
             f"base x {st['base_x_end']:.3f} m, clock {st['clock_end']:.3f} s",
             "  violations: " + ", ".join(f"{k} {v:.1e}" for k, v in st["violations"].items())]
    if "solve" in rec:
        s = rec["solve"]
        lines.append(f"solve: converged {s['converged']}, {s['iterations']} it, {s['wall_s']:.1f} s, control cost {s['control_cost']}")
        lines += [f"  {label:<24} {it:5d} it  {status}" for label, it, status in s["nlps"]]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = script_parser(__doc__)
    parser.add_argument("--landings", type=finite_float, nargs="*", default=[0.85, 1.85],
                        help="intermediate footholds' guesses [m]")
    parser.add_argument("--T", type=positive_float, default=2.3,
                        help="the hop plan's duration [s] (the time-freezing plans' clocks end at 2.3-2.5 s)")
    parser.add_argument("--nodes", type=int, nargs=2, default=[8, 8], metavar=("STANCE", "FLIGHT"),
                        help="the hop OCP's nodes per stance and per flight phase (default 8 8)")
    parser.add_argument("--start", choices=sorted(STARTS), default="pd",
                        help="the time-freezing start from the hop plan: interp, pd (default) or track (see above)")
    parser.add_argument("--N", type=int, default=125, help="time-freezing steps over the task's tau_f (default the task's 125)")
    parser.add_argument("--max-iter", type=int, default=3000, help="IPOPT iterations of the hop OCP")
    parser.add_argument("--no-solve", action="store_true", help="stop after the start")
    parser.add_argument("--out", type=out_dir, default=Path("results/bench/probe_multiphase"),
                        help="output directory (default results/bench/probe_multiphase)")
    parser.add_argument("--quick", action="store_true", help="CI smoke run: N = 10, one landing, 3 nodes per phase, no solve")
    parser.add_argument("--json", action="store_true", help="print the record as JSON instead of the table")
    args = parser.parse_args(argv)
    refuse_with_quick(parser, args, ["N", "landings", "nodes", "max_iter"],
                      "N = 10, one landing, 3 nodes per phase, 200 iterations, no solve")
    if args.quick:
        args.N, args.landings, args.nodes, args.max_iter, args.no_solve = 10, [1.0], [3, 3], 200, True
    if min(args.nodes) < 1 or args.N < 1 or args.max_iter < 1:
        parser.error(f"--nodes, --N and --max-iter must be >= 1, got {args.nodes}, {args.N}, {args.max_iter}")
    rec = probe(args.N, sorted(args.landings), args.T, tuple(args.nodes), args.start, args.max_iter, not args.no_solve)
    return report(args.out, rec, table(rec), args.json)


if __name__ == "__main__":
    sys.exit(run_main(main))
