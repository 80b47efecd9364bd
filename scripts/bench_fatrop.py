"""FATROP on the stage-ordered NLP (planner.staged) against IPOPT on the original NLP: NLP 1 of the
homotopy (hint-free start, first rho, holes relaxed, soft terminal: scripts.bench_pipeline.nlp1_arguments)
and optionally the following warm NLP (rho = 1e3 from each solver's own NLP 1 solution, holes on,
hard terminal, unscaled x). Per solver: iterations, status, CPU [ms] per iteration (process time of
the call, one thread), objective, the largest gated product (what the l_inf slack bounds), the
largest constraint violation of the original NLP (with that NLP's lbg/ubg) and the terminal error.

    OMP_NUM_THREADS=1 python -m scripts.bench_fatrop --N 125 --max-iter 150 3000
    OMP_NUM_THREADS=1 python -m scripts.bench_fatrop --N 50 --max-iter 3000 --warm --fatrop-opt tolerance=1e-3
    OMP_NUM_THREADS=1 python -m scripts.bench_fatrop --case hop --N 40 --max-iter 3000 --verbose
    OMP_NUM_THREADS=1 python -m scripts.bench_fatrop --N 50 --max-iter 3000 --solvers ipopt ipopt_staged --ipopt-opt mu_strategy=monotone

Solvers (--solvers): ipopt (the original NLP, planner.homotopy.ipopt_options), fatrop (the staged NLP,
FATROP with IPOPT's tol, acceptable_tol, mu_init, bound_push; --fatrop-opt key=value overrides or adds
FATROP options) and ipopt_staged (IPOPT on the staged NLP: tells the reformulation from the solver).
The warm NLP is unscaled here (solve() scales NLPs 2.. when the task sets scale_variables). Prints a
markdown table (and FATROP's own log, which CasADi writes to stdout); --out writes the JSON record;
--verbose prints both solvers' iteration logs. docs/benchmarks.md, "FATROP"."""
from __future__ import annotations

import json
import os
import sys
from pathlib import Path
import time

import casadi as ca
import numpy as np

from planner.errors import InputError
from planner.homotopy import SolveOptions, gated_complementarity, ipopt_options, task_rho_schedule, terminal_error
from planner.problem import Penalty, ProblemOptions, build_problem
from planner.result import write_atomically
from planner.staged import staged_nlp
from scripts.bench_pipeline import capler_case, hop_case, nlp1_arguments
from scripts._report import run_info, run_main, script_parser, utc_now


def measures(problem, x, p, lbg, ubg) -> dict:
    """Objective, largest gated product, constraint violation (g and bounds) and terminal error at x."""
    g = np.asarray(ca.Function("g", [problem.x, problem.p], [problem.g])(x, p), float).ravel()
    f = float(ca.Function("f", [problem.x, problem.p], [problem.f])(x, p))
    viol = max(float(np.max(np.maximum(lbg - g, 0) + np.maximum(g - ubg, 0))),
               float(np.max(np.maximum(problem.lbx - x, 0) + np.maximum(x - problem.ubx, 0))))
    return {"objective": f, "gated_product_max": gated_complementarity(problem, x), "complementarity_ungated": problem.complementarity_residual(x),
            "constraint_violation": viol, "terminal_error": terminal_error(problem, x)}


def gradient_scaling(st, x0, p, max_grad: float = 100.0) -> tuple[float, np.ndarray]:
    """IPOPT's gradient-based NLP scaling at x0 for the staged NLP: the objective factor and one factor
    per row, min(1, max_grad / max |gradient|); gap rows keep 1 (FATROP needs x_{k+1} - F(x_k, u_k))."""
    gf = np.asarray(ca.Function("gf", [st.x, st.p], [ca.gradient(st.f, st.x)])(x0, p), float).ravel()
    J = ca.Function("J", [st.x, st.p], [ca.jacobian(st.g, st.x)])(x0, p).sparse().tocsr()
    row_max = np.zeros(J.shape[0])
    np.maximum.at(row_max, np.repeat(np.arange(J.shape[0]), np.diff(J.indptr)), np.abs(J.data))
    dg = np.minimum(1.0, max_grad / np.maximum(row_max, 1e-300))
    dg[st.g_src < 0] = 1.0
    return float(min(1.0, max_grad / max(np.max(np.abs(gf)), 1e-300))), dg


def scaled_nlp(st, df: float, dg: np.ndarray) -> dict:
    return {"x": st.x, "p": st.p, "f": df * st.f, "g": ca.DM(dg) * st.g}


def fatrop_solver(name: str, st, fatrop_opts: dict, df: float, dg: np.ndarray, convexify: str | None):
    """FATROP on the staged NLP st scaled by (df, dg), with CasADi's Hessian convexification if asked."""
    fopts = st.fatrop_options(**fatrop_opts)
    if convexify:
        fopts.update(convexify_strategy=convexify, convexify_margin=1e-7)
    return ca.nlpsol(name, "fatrop", scaled_nlp(st, df, dg), fopts)


def run(solver, args) -> tuple[dict, np.ndarray]:
    c0, w0 = time.process_time(), time.perf_counter()
    sol = solver(**args)
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    st = solver.stats()
    it = max(int(st["iter_count"]), 1)
    ev = sum(float(st.get(f"t_proc_nlp_{c}", 0.0)) for c in ("f", "g", "grad_f", "jac_g", "hess_l"))
    rec = {"iterations": int(st["iter_count"]), "status": str(st["return_status"]), "success": bool(st["success"]),
           "cpu_s": cpu, "wall_s": wall, "cpu_ms_per_iter": 1e3 * cpu / it, "eval_cpu_ms_per_iter": 1e3 * ev / it}
    if "fatrop" in st:
        fs = st["fatrop"]
        rec["fatrop_stats"] = {k: (float(v) if isinstance(v, (int, float)) else str(v)) for k, v in fs.items()}
    return rec, np.asarray(sol["x"], float).ravel()


def parse_options(pairs) -> dict:
    """key=value strings to a dict: true/false to bool, numbers to int or float, the rest as strings."""
    out = {}
    for kv in pairs:
        k, sep, v = kv.partition("=")
        if not sep or not k:
            raise InputError(f"option {kv!r}: expected key=value, e.g. max_iter=100")
        if v in ("true", "false"):
            out[k] = v == "true"
            continue
        try:
            out[k] = int(v) if v.lstrip("-").isdigit() else float(v)
        except ValueError:
            out[k] = v
    return out


def check_options(solvers: list[str], ipopt: dict, fatrop: dict) -> None:
    """The given solver options tried on a one-variable NLP before any run: IPOPT refuses an unknown name or a wrong
    type when its solver is made, FATROP only when it solves, so one found in a later solver's run stopped the script
    after the runs before it (main() turns the RuntimeError into one line)."""
    x = ca.SX.sym("x")
    nlp = {"x": x, "f": x ** 2}
    if {"ipopt", "ipopt_staged"} & set(solvers):
        ca.nlpsol("ipopt_options", "ipopt", nlp, {"ipopt": {"print_level": 0, **ipopt}, "print_time": False})
    if "fatrop" in solvers:
        options = {"fatrop": {"print_level": 0, **fatrop}, "print_time": False}
        ca.nlpsol("fatrop_options", "fatrop", nlp, options)(x0=1.0)


def main(argv=None) -> int:
    ap = script_parser(__doc__)
    ap.add_argument("--N", type=int, default=125, help="steps of the case's horizon (default 125, Capler's own)")
    ap.add_argument("--case", choices=["capler", "hop"], default="capler", help="robots/capler.toml (tau_f 2.5 s, N steps) or the point-mass hop")
    ap.add_argument("--penalty", choices=["linf", "l1"], default="linf", help="ProblemOptions.penalty (l1: no slack s_c, no penalty rows)")
    ap.add_argument("--max-iter", type=int, nargs="+", default=[150],
                    help="NLP 1's iteration caps, one run per cap and solver (default 150)")
    ap.add_argument("--warm", action="store_true", help="also the next NLP (rho 1e3) from each solver's NLP 1 solution (max_iter 3000)")
    ap.add_argument("--fatrop-opt", nargs="*", default=[], help="key=value FATROP options (numbers parsed)")
    ap.add_argument("--ipopt-opt", nargs="*", default=[], help="key=value IPOPT options for ipopt and ipopt_staged (numbers parsed)")
    ap.add_argument("--solvers", nargs="+", choices=["ipopt", "fatrop", "ipopt_staged"], default=["ipopt", "fatrop"],
                    help="ipopt (the original NLP), fatrop and ipopt_staged (the staged NLP); default ipopt fatrop")
    ap.add_argument("--verbose", action="store_true", help="print the solvers' iteration logs")
    ap.add_argument("--convexify", default=None, choices=["regularize", "eigen-reflect", "eigen-clip"],
                    help="FATROP: CasADi's convexify_strategy of the Hessian blocks")
    ap.add_argument("--drop-free", action="store_true", help="FATROP: leave out the rows with both bounds infinite (NLP 1's soft terminal rows)")
    ap.add_argument("--scale", action="store_true", help="FATROP: IPOPT's gradient-based scaling (objective, rows) computed at x0")
    ap.add_argument("--out", default=None, help="write the JSON record to this file (FATROP prints its log to stdout)")
    a = ap.parse_args(argv)
    fatrop_only = [flag for flag, given in (("--fatrop-opt", a.fatrop_opt), ("--convexify", a.convexify),
                                            ("--scale", a.scale), ("--drop-free", a.drop_free)) if given]
    if fatrop_only and "fatrop" not in a.solvers:  # (ignored, and written into the record as if used)
        ap.error(f"{', '.join(fatrop_only)} appl{'ies' if len(fatrop_only) == 1 else 'y'} to FATROP, which --solvers "
                 f"{' '.join(a.solvers)} does not run")
    if a.out is not None:  # each found only after the whole run before, or (empty) nothing written at all
        target = Path(a.out)
        if not a.out.strip() or target.is_dir():
            ap.error(f"--out {a.out!r} must name a file to write")
        if not target.parent.is_dir() or not os.access(target.parent, os.W_OK | os.X_OK):
            ap.error(f"--out {a.out}: no writable directory {target.parent}")
    robot, task = capler_case(a.N) if a.case == "capler" else hop_case(a.N)
    t0 = time.perf_counter()
    problem = build_problem(robot, task, ProblemOptions(penalty=Penalty(a.penalty)))
    build_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    st = staged_nlp(problem)
    staged_s = time.perf_counter() - t0
    opts = SolveOptions()
    args1 = nlp1_arguments(problem, opts)
    rhos = task_rho_schedule(problem.task.plan.homotopy, opts.rho_min, opts.rho_max, opts.rho_refine)
    fat_extra, ip_extra = parse_options(a.fatrop_opt), parse_options(a.ipopt_opt)
    out = {"case": a.case, "N": a.N, "penalty": a.penalty, "nx": problem.nx, "ng": problem.ng, "staged_nx": st.x.shape[0], "staged_ng": st.g.shape[0],
           "build_s": build_s, "staged_s": staged_s, "rho_nlp1": rhos[0], "fatrop_options": fat_extra, "ipopt_options": ip_extra, "convexify": a.convexify, "scale": a.scale, "drop_free": a.drop_free,
           "date": utc_now(), "casadi": ca.__version__,
           "load_before": os.getloadavg(), "runs": [], "run": run_info()}
    log = (lambda *s: print(*s, file=sys.stderr, flush=True))
    try:
        check_options(a.solvers, ip_extra, fat_extra)
        for max_iter in a.max_iter:
            for name in a.solvers:
                t0 = time.perf_counter()
                if name == "ipopt":
                    o = ipopt_options(SolveOptions(max_iter=max_iter, print_level=5 if a.verbose else 0), False)
                    o["ipopt"].update(ip_extra)
                    solver = ca.nlpsol("ipopt_nlp1", "ipopt", {"x": problem.x, "p": problem.p, "f": problem.f, "g": problem.g}, o)
                    args = dict(args1)
                elif name == "fatrop":
                    st1 = st.without_free_rows(args1["lbg"], args1["ubg"]) if a.drop_free else st
                    acceptable = ipopt_options(opts, False)["ipopt"]["acceptable_tol"]  # as IPOPT gets it
                    fo = dict(tolerance=opts.tol, tol_acceptable=acceptable, mu_init=opts.mu_init,
                              bound_push=opts.bound_push, max_iter=max_iter, print_level=5 if a.verbose else 0)
                    fo.update(fat_extra)
                    df, dg = gradient_scaling(st1, st1.lift(args1["x0"]), args1["p"]) if a.scale else (1.0, np.ones(st1.g.shape[0]))
                    out["scaling"] = {"objective": df, "rows_scaled": int(np.sum(dg < 1)), "row_min": float(np.min(dg))}
                    solver = fatrop_solver("fatrop_nlp1", st1, fo, df, dg, a.convexify)
                    lbg, ubg = st1.bounds(args1["lbg"], args1["ubg"])
                    args = {"x0": st1.lift(args1["x0"]), "p": args1["p"], "lbx": st1.lbx, "ubx": st1.ubx, "lbg": lbg * dg, "ubg": ubg * dg}
                elif name == "ipopt_staged":  # IPOPT on the staged NLP: separates the reformulation from the solver
                    o = ipopt_options(SolveOptions(max_iter=max_iter, print_level=5 if a.verbose else 0), False)
                    o["ipopt"].update(ip_extra)
                    solver = ca.nlpsol("ipopt_staged_nlp1", "ipopt", st.nlp, o)
                    lbg, ubg = st.bounds(args1["lbg"], args1["ubg"])
                    args = {"x0": st.lift(args1["x0"]), "p": args1["p"], "lbx": st.lbx, "ubx": st.ubx, "lbg": lbg, "ubg": ubg}
                create_s = time.perf_counter() - t0
                rec, x = run(solver, args)
                if name != "ipopt":
                    x = st.restrict(x)
                rec.update(solver=name, nlp=1, max_iter=max_iter, create_s=create_s,
                           **measures(problem, x, args1["p"], args1["lbg"], args1["ubg"]))
                log({k: v for k, v in rec.items() if k != "fatrop_stats"})
                out["runs"].append(rec)
                if a.warm and name in ("ipopt", "fatrop"):
                    p2 = problem.params(rhos[1], 1.0)
                    if name == "ipopt":
                        o = ipopt_options(SolveOptions(max_iter=3000, print_level=5 if a.verbose else 0), True)
                        solver = ca.nlpsol("ipopt_nlp2", "ipopt", {"x": problem.x, "p": problem.p, "f": problem.f, "g": problem.g}, o)
                        args = {"x0": x, "p": p2, "lbx": problem.lbx, "ubx": problem.ubx, "lbg": problem.lbg, "ubg": problem.ubg}
                    else:
                        fo["max_iter"] = 3000
                        x0n = st.lift(x)
                        df, dg = gradient_scaling(st, x0n, p2) if a.scale else (1.0, np.ones(st.g.shape[0]))
                        solver = fatrop_solver("fatrop_nlp2", st, fo, df, dg, a.convexify)
                        args = {"x0": x0n, "p": p2, "lbx": st.lbx, "ubx": st.ubx, "lbg": st.lbg * dg, "ubg": st.ubg * dg}
                    rec2, x2 = run(solver, args)
                    if name != "ipopt":
                        x2 = st.restrict(x2)
                    rec2.update(solver=name, nlp=2, rho=rhos[1], **measures(problem, x2, p2, problem.lbg, problem.ubg))
                    log({k: v for k, v in rec2.items() if k != "fatrop_stats"})
                    out["runs"].append(rec2)
    except RuntimeError as exc:  # an option IPOPT or FATROP does not know (a traceback before)
        last = str(exc).strip().splitlines()[-1]
        if "option" not in last.lower() and "type mismatch" not in last.lower():  # tol=abc: CasADi's type mismatch
            raise
        texts = [f"{k}={v}" for k, v in {**ip_extra, **fat_extra}.items() if isinstance(v, str)]
        hint = f": a number expected? given as text: {', '.join(texts)}" if "type mismatch" in last and texts else ""
        raise InputError(f"{last.split(': ', 1)[-1]} (--ipopt-opt, --fatrop-opt){hint}") from None
    out["load_after"] = os.getloadavg()
    if a.out:
        write_atomically(a.out, json.dumps(out, indent=1) + "\n")
    print(f"N = {a.N}: {problem.nx} / {problem.ng} (staged {out['staged_nx']} / {out['staged_ng']}), {out['date']}")
    print("| solver | NLP | max_iter | it. | status | CPU ms/it (evals) | objective | gated prod. | viol. | terminal |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in out["runs"]:
        print(f"| {r['solver']} | {r['nlp']} | {r.get('max_iter', 3000)} | {r['iterations']} | {r['status']} | "
              f"{r['cpu_ms_per_iter']:.2f} ({r['eval_cpu_ms_per_iter']:.2f}) | {r['objective']:.6f} | {r['gated_product_max']:.2e} | "
              f"{r['constraint_violation']:.1e} | {r['terminal_error']:.2e} |")
    return 0


if __name__ == "__main__":
    sys.exit(run_main(main))
