"""Speed of the pipeline (issue 9): where the time of a solve goes, and what the variants change.

For each case: the build (build_problem) [s], the derivation of the NLP's derivatives over the whole graph
and step by step (planner.derivatives, SolveOptions.derivation) [s], the whole graph's read back from CasADi's
serialization (what a cache of them would cost) [s], the creation of the cold IPOPT (nlpsol: the SX
derivatives) [s], and a fixed-iteration run of the homotopy's NLP 1 (the hint-free start, the first
rho of the schedule, holes relaxed, soft terminal: exactly what planner.homotopy.solve runs first;
with --nlp 2 the homotopy's NLP 2 instead, from NLP 1's solution, in the variables solve gives it)
with IPOPT's max_iter = --iters, split per iteration into the function evaluations (per callback:
nlp_f, nlp_g, nlp_grad_f, nlp_jac_g, nlp_hess_l, CasADi's own timers) and the rest (MUMPS and
IPOPT's own work). Every variant starts from the same point with the same options but one, so
the iterates are the same unless the variant changes the pivoting (the record has the iteration
count and the objective reached, to compare). CPU times (process time, one thread) are the
numbers to compare on a loaded machine; wall times are recorded beside them.

Variants (VARIANTS): IPOPT/MUMPS options, and with --codegen the NLP's functions generated as C
(nlpsol.generate_dependencies), compiled with gcc (--codegen-flags) into --cache (file name: the
hash of the C source, so a second run reuses it) and loaded with nlpsol(..., "lib.so"); generate
and compile times are recorded separately. With --full, the default task of each case is also
solved end to end with the default SolveOptions (iterations x per-iteration cost), or once per --solve
JSON object with those SolveOptions fields changed (e.g. '{}' '{"warm_ipopt": {"alpha_for_y": "min"}}'
'{"rho_schedule": [300, 1000, 3000, 1e4, 1e5, 1e6]}': three solves); --full-only skips the
fixed-iteration runs; --race runs each end-to-end solve as `planner plan` does: its options raced against
the alternate arm (race.SECOND_ARM: primal-dual warm start, regularization from_last, MUMPS without its
matching) on two CPUs (planner.race.default_arms; the winner's iterations, the race's wall).

Cases: capler50 (robots/capler.toml with N = 50, h = 0.05 s), capler125 (the default N = 125),
hop (the point mass hopping to x = 0.5 m, N = 40, tests/test_homotopy.py's task); for end-to-end comparisons
also capler75, capler100 and capler_x2.8, capler_x2.9, capler_x3.1 (N = 125, the target's x_B moved), and
capler_set, all seven Capler tasks (CAPLER_SET: one task's iteration count is a draw, docs/benchmarks.md).

    python -m scripts.bench_pipeline [--quick] [--cases NAME ...] [--iters K] [--repeats R]
        [--variants NAME ...] [--nlp 1|2] [--step-form mass_matrix|explicit] [--no-lift] [--codegen] [--full] [--full-only] [--solve JSON ...] [--race] [--out DIR] [--json]

--quick (the CI smoke run): the hop with N = 6, 10 iterations, one repeat.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shlex
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import casadi as ca
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from planner.cli import prepare_out_dir
from planner.homotopy import (SolveOptions, _Solvers, freed_memory_kept, homotopy_nlp, ipopt_options, solve,
                              solve_fields_from_json, solve_options_from_dict, variable_scale)
from planner.derivatives import nlp_derivatives
from planner.errors import InputError, PlannerError
from planner.model import load_robot
from planner.discretization import StepForm
from planner.problem import ProblemOptions, build_problem
from planner.race import default_arms, race
from planner.result import race_arms_text
from planner.task import Horizon, load_task, parse_task
from planner.plots import save_figure
from scripts._report import checked_default, machine_info, out_dir, report, run_main, script_parser

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_OUT = Path("results/bench/pipeline")
DEFAULT_CODEGEN_FLAGS = ["-O1"]
DEFAULT_CACHE = Path.home() / ".cache" / "planner" / "codegen"
CALLBACKS = ("f", "g", "grad_f", "jac_g", "hess_l")

# name -> IPOPT options changed from the default (planner.homotopy.ipopt_options)
VARIANTS = {
    "baseline": {},
    "mumps_amd": {"mumps_pivot_order": 0},
    "spral_metis": {"linear_solver": "spral", "spral_order": "metis", "spral_scaling": "none", "spral_use_gpu": "no"},
    "spral_metis_subtree": {"linear_solver": "spral", "spral_order": "metis", "spral_scaling": "none", "spral_use_gpu": "no",
                            "spral_small_subtree_threshold": 1e12, "spral_ignore_numa": "yes"},
    "mumps_amf": {"mumps_pivot_order": 2},
    "mumps_pord": {"mumps_pivot_order": 4},
    "mumps_metis": {"mumps_pivot_order": 5},
    "mumps_qamd": {"mumps_pivot_order": 6},
    "mumps_pivtol_1e-8": {"mumps_pivtol": 1e-8},
    "mumps_no_scaling": {"mumps_scaling": 0, "mumps_permuting_scaling": 0},
    "mumps_mem_200": {"mumps_mem_percent": 200},
    "mumps_mem_50": {"mumps_mem_percent": 50},  # IPOPT's default is 1000: with keep_freed_memory the same CPU (session 24)
    "slack_based_scaling": {"linear_system_scaling": "slack-based"},
    "fixed_relax_bounds": {"fixed_variable_treatment": "relax_bounds"},
    "perturb_dec_0.6": {"perturb_dec_fact": 0.6},
    # IPOPT's step rules (session 10, run on NLP 2 with --nlp 2 --iters 3000: iterations to convergence)
    "alpha_for_y_min": {"alpha_for_y": "min"},
    "alpha_for_y_safer": {"alpha_for_y": "safer-min-dual-infeas"},
    "alpha_for_y_bound_mult": {"alpha_for_y": "bound-mult"},
    "corrector_affine": {"corrector_type": "affine"},
    "corrector_primal_dual": {"corrector_type": "primal-dual"},
    "recalc_y": {"recalc_y": "yes"},
    "kappa_d_0": {"kappa_d": 0.0},
    "max_soc_0": {"max_soc": 0},
    "mu_globalization_kkt": {"adaptive_mu_globalization": "kkt-error"},
    "mu_globalization_never_monotone": {"adaptive_mu_globalization": "never-monotone-mode"},
    # quasi-Newton Hessian (session 11): no Hessian evaluations, a KKT matrix without the Hessian's fill
    "limited_memory": {"hessian_approximation": "limited-memory"},
    # SPRAL's SSIDS, linked into the CasADi wheel's IPOPT beside MUMPS (session 21): as IPOPT sets it up, and
    # without its matching-based scaling with smaller supernodes (the fastest of seven settings tried)
    "spral": {"linear_solver": "spral"},
    "spral_lean": {"linear_solver": "spral", "spral_scaling": "none", "spral_scaling_1": "none", "spral_scaling_2": "none",
                   "spral_scaling_3": "none", "spral_nemin": 4},
}


def capler_case(N: int, target_x: float | None = None):
    """robots/capler.toml with N steps over its horizon tau_f = 2.5 s (N = 50: h = 0.05 s), and the base's
    target x_B [m] moved to target_x when given."""
    task = load_task(ROOT / "robots" / "capler.toml")
    task = dataclasses.replace(task, horizon=Horizon(tau_f=task.horizon.tau_f, N=N))
    if target_x is not None:
        task = dataclasses.replace(task, plan=dataclasses.replace(task.plan, target_q=(target_x, *task.plan.target_q[1:])))
    return load_robot(ROOT / "robots" / "capler.xml"), task


def hop_case(N: int):
    task = parse_task({"contacts": [{"point": "point", "mu": 0.5}], "initial": {"q": [0.0, 0.0]}, "horizon": {"tau_f": 1.0, "N": N},
                       "plan": {"target_q": [0.5, 0.0], "u_bound": 30.0}})
    return load_robot(ROOT / "robots" / "point_mass.xml"), task


CASES = {"capler50": lambda quick: capler_case(50), "capler75": lambda quick: capler_case(75),
         "capler100": lambda quick: capler_case(100), "capler125": lambda quick: capler_case(125),
         **{f"capler_x{x}": (lambda quick, x=x: capler_case(125, x)) for x in (2.8, 2.9, 3.1)},
         "hop": lambda quick: hop_case(6 if quick else 40)}
# the seven Capler tasks a solver change is judged on (the hint-free solve's iterations are a chaotic function of the
# arithmetic, so one task says little): the default grid and three coarser ones, and the target moved by -0.2 .. +0.1 m
CAPLER_SET = ("capler125", "capler100", "capler75", "capler50", "capler_x2.8", "capler_x2.9", "capler_x3.1")


def nlp1_arguments(problem, options: SolveOptions) -> dict:
    """The arguments planner.homotopy.solve gives NLP 1 (default options: holes relaxed, soft terminal)."""
    nlp = homotopy_nlp(problem, options, 0)
    return {"x0": problem.x0, "p": nlp.p, "lbx": problem.lbx, "ubx": problem.ubx, "lbg": nlp.lbg, "ubg": nlp.ubg}


def nlp2_setup(problem, x1=None) -> tuple[dict, dict]:
    """NLP 1 solved as planner.homotopy.solve solves it (default options; or its solution x1 (nx,) given), then
    the NLP that solve hands IPOPT for NLP 2 (x / D with D from NLP 1's solution when the task scales its
    variables) and its arguments (the second rho of the schedule, holes and hard terminal on, from NLP 1's point)."""
    options = SolveOptions()
    solvers = _Solvers(problem, options)
    if x1 is None:
        x1 = np.asarray(solvers.get(False)(**nlp1_arguments(problem, options))["x"], float).ravel()
    scaled = problem.task.plan.homotopy.scale_variables
    D = variable_scale(problem, x1) if scaled else np.ones(problem.nx)
    solvers.set_scale(D)
    nlp = homotopy_nlp(problem, options, 1)
    args = {"x0": x1 / D, "p": nlp.p, "lbx": problem.lbx / D, "ubx": problem.ubx / D, "lbg": nlp.lbg, "ubg": nlp.ubg}
    return solvers.scaled_nlp, args


def compile_nlp(solver, cache: Path, flags: list[str]) -> dict:
    """Generate the solver's NLP functions as C, compile them with gcc into cache/<hash>.so (reused
    when present): {"so": path or None, "generate_s", "compile_s", "cached", "c_bytes", "skipped"}."""
    gcc = shutil.which("gcc")
    if gcc is None:
        return {"so": None, "skipped": "gcc not found on PATH: the codegen variant needs a C compiler (apt-get install gcc)"}
    cache.mkdir(parents=True, exist_ok=True)
    # CasADi writes the C file into the working directory and takes no path (a C name): it is generated in a private
    # directory of the cache, made the working directory meanwhile. Written in the cwd and moved, it failed across
    # filesystems (a --cache in /dev/shm) and was left there; private: two runs sharing a cache write apart
    work = Path(tempfile.mkdtemp(prefix="nlp_gen_", dir=cache)).resolve()
    try:
        return _compile_in(solver, work, cache, flags, gcc)
    finally:
        shutil.rmtree(work, ignore_errors=True)


def _compile_in(solver, work: Path, cache: Path, flags: list[str], gcc: str) -> dict:
    """compile_nlp's work, its C file generated in `work` (an absolute directory the caller removes)."""
    t0 = time.perf_counter()
    c_file = work / "nlp_tmp.c"
    here = os.getcwd()
    os.chdir(work)
    try:
        solver.generate_dependencies(c_file.name, {"with_header": False})
    finally:
        os.chdir(here)
    generate_s = time.perf_counter() - t0
    source = c_file.read_bytes()
    key = hashlib.sha256(source + " ".join(flags).encode() + ca.__version__.encode()).hexdigest()[:16]
    so = cache / f"nlp_{key}.so"
    out = {"so": str(so), "generate_s": generate_s, "c_bytes": len(source), "flags": flags, "cached": so.exists(), "compile_s": 0.0}
    if not so.exists():
        t0 = time.perf_counter()
        tmp = so.with_suffix(f".{os.getpid()}.so")
        compiled = subprocess.run([gcc, "-fPIC", "-shared", *flags, str(c_file), "-o", str(tmp)], capture_output=True, text=True)
        if compiled.returncode != 0:
            tmp.unlink(missing_ok=True)
            why = " ".join(compiled.stderr.strip().splitlines()[-2:]) or "(no message)"
            if flags != DEFAULT_CODEGEN_FLAGS:  # the user's flags: theirs to fix
                raise InputError(f"gcc refused --codegen-flags {' '.join(flags)}: {why}")
            raise PlannerError(f"gcc failed on the generated NLP functions: {why}")
        tmp.replace(so)  # atomic: a concurrent run never loads a half-written library
        out["compile_s"] = time.perf_counter() - t0
    return out


def run_once(solver, args: dict) -> dict:
    """One fixed-iteration run: per-iteration CPU and wall [ms], split into the callbacks and the rest."""
    c0, w0 = time.process_time(), time.perf_counter()
    sol = solver(**args)
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    st = solver.stats()
    it = max(int(st["iter_count"]), 1)
    # a callback IPOPT never calls has no timer (hess_l with a quasi-Newton Hessian)
    ev_cpu = {c: 1e3 * float(st.get(f"t_proc_nlp_{c}", 0.0)) / it for c in CALLBACKS}
    ev_wall = {c: 1e3 * float(st.get(f"t_wall_nlp_{c}", 0.0)) / it for c in CALLBACKS}
    return {"iterations": int(st["iter_count"]), "objective": float(sol["f"]), "status": str(st["return_status"]),
            "cpu_ms_per_iter": 1e3 * cpu / it, "wall_ms_per_iter": 1e3 * wall / it,
            "eval_cpu_ms_per_iter": ev_cpu, "eval_wall_ms_per_iter": ev_wall,
            "rest_cpu_ms_per_iter": 1e3 * cpu / it - sum(ev_cpu.values()), "rest_wall_ms_per_iter": 1e3 * wall / it - sum(ev_wall.values())}


def median_record(runs: list[dict]) -> dict:
    """Median over the repeats of every timing; the iterate facts of the first run (checked equal)."""
    def med(key, sub=None):
        return statistics.median(r[key][sub] if sub else r[key] for r in runs)
    out = {k: runs[0][k] for k in ("iterations", "objective", "status")}
    out["reproducible"] = all(r["iterations"] == runs[0]["iterations"] and r["objective"] == runs[0]["objective"] for r in runs)
    for key in ("cpu_ms_per_iter", "wall_ms_per_iter", "rest_cpu_ms_per_iter", "rest_wall_ms_per_iter"):
        out[key] = med(key)
    for key in ("eval_cpu_ms_per_iter", "eval_wall_ms_per_iter"):
        out[key] = {c: med(key, c) for c in CALLBACKS}
    out["repeats"] = len(runs)
    return out


def run_case(name: str, quick: bool, iters: int, repeats: int, variants: list[str], codegen: dict | None,
             full: list[tuple[dict, SolveOptions]], log, nlp_index: int = 1, raced: bool = False,
             problem_options: ProblemOptions = ProblemOptions()) -> dict:
    robot, task = CASES[name](quick)
    t0 = time.perf_counter()
    problem = build_problem(robot, task, problem_options)
    rec = {"case": name, "N": task.horizon.N, "h": task.horizon.h, "step_form": problem_options.step_form.value,
           "lift_products": problem_options.lift_products,
           "n_variables": problem.nx, "n_constraints": problem.ng,
           "build_s": time.perf_counter() - t0, "iters": iters, "nlp": nlp_index}
    for stepwise in (False, True):  # the NLP's derivatives as the IPOPTs get them (SolveOptions.derivation)
        t0 = time.perf_counter()
        derivs = nlp_derivatives(problem, stepwise=stepwise)
        rec[f"derivation_{'stepwise' if stepwise else 'whole_graph'}_s"] = time.perf_counter() - t0
        if not stepwise:  # what a cache of the derived functions would cost to read back instead
            blobs = [f.serialize() for f in derivs.values()]
            t0 = time.perf_counter()
            for b in blobs:
                ca.Function.deserialize(b)
            rec["derivation_deserialize_s"] = time.perf_counter() - t0
            rec["derivation_serialized_mb"] = sum(len(b) for b in blobs) / 1e6
    log(name, "derivation", {k: round(v, 3) for k, v in rec.items() if k.startswith("derivation_")})
    options = SolveOptions(max_iter=iters)
    if nlp_index == 2 and variants:
        nlp, args = nlp2_setup(problem)
    else:
        nlp, args = {"x": problem.x, "p": problem.p, "f": problem.f, "g": problem.g}, nlp1_arguments(problem, SolveOptions())
    warm = nlp_index == 2
    solvers, create_s = {}, {}
    for v in variants:
        opts = ipopt_options(options, warm)
        opts["ipopt"].update(VARIANTS[v])
        t0 = time.perf_counter()
        solvers[v] = ca.nlpsol("bench_" + "".join(ch if ch.isalnum() else "_" for ch in v).strip("_").replace("__", "_"), "ipopt", nlp, opts)
        create_s[v] = time.perf_counter() - t0
    if create_s:
        rec["solver_create_s"] = create_s.get("baseline", next(iter(create_s.values())))
    if codegen is not None:
        base = solvers.get("baseline") or next(iter(solvers.values()))
        info = compile_nlp(base, codegen["cache"], codegen["flags"])
        rec["codegen"] = info
        log(name, "codegen", info)
        if info["so"] is not None:
            label = "codegen_" + "".join(codegen["flags"]).replace("-", "")
            t0 = time.perf_counter()
            solvers[label] = ca.nlpsol("bench_codegen", "ipopt", info["so"], ipopt_options(options, warm))
            create_s[label] = time.perf_counter() - t0
    runs = {v: [] for v in solvers}
    for _ in range(repeats):  # interleaved: a load change hits every variant alike
        for v, s in solvers.items():
            runs[v].append(run_once(s, args))
    rec["variants"] = {v: {**median_record(r), "create_s": create_s[v]} for v, r in runs.items()}
    for v, r in rec["variants"].items():
        log(name, v, r)
    rec["full_solves"] = []
    for given, options in full:
        c0, t0 = time.process_time(), time.perf_counter()
        res = race(problem, default_arms(options), processes=2) if raced else solve(problem, options)
        rec["full_solves"].append({
            "solve": given, "race": res.extra.get("race"), "wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0,
            "ipopt_iterations": res.stats.ipopt_iterations, "nlp_iterations": [r.iterations for r in res.nlps],
            "nlp_status": [r.status for r in res.nlps], "rho": [r.rho for r in res.nlps], "hops": len(res.hops),
            "n_nlp": res.stats.n_nlp, "converged": res.stats.converged, "complementarity": res.stats.complementarity_residual,
            "terminal_error": res.terminal_error, "control_cost": res.extra["control_cost"], "timings": res.timings,
            "message": res.stats.message})
        log(name, "full", rec["full_solves"][-1])
    return rec


def table(records) -> str:
    derived = [r for r in records if "derivation_stepwise_s" in r]
    lines = ["| case | derivatives: whole graph, step by step, whole graph deserialized [s] |", "|---|---|", *(
        f"| {r['case']} | {r['derivation_whole_graph_s']:.2f}, {r['derivation_stepwise_s']:.2f}, {r['derivation_deserialize_s']:.2f} "
        f"({r['derivation_serialized_mb']:.0f} MB) |" for r in derived), ""] if derived else []
    lines += ["| case | variant | iterations | objective | CPU ms/it | evals ms/it (f, g, grad_f, jac_g, hess_l) | rest ms/it | wall ms/it | create s |",
              "|---|---|---|---|---|---|---|---|---|"]
    for r in records:
        for v, m in r["variants"].items():
            ev = m["eval_cpu_ms_per_iter"]
            lines.append(f"| {r['case']} | {v} | {m['iterations']} | {m['objective']:.10g} | {m['cpu_ms_per_iter']:.2f} | "
                         f"{sum(ev.values()):.2f} ({', '.join(f'{ev[c]:.2f}' for c in CALLBACKS)}) | {m['rest_cpu_ms_per_iter']:.2f} | "
                         f"{m['wall_ms_per_iter']:.2f} | {m['create_s']:.2f} |")
    full = [(r["case"], f) for r in records for f in r["full_solves"]]
    if full:
        lines += ["", "| case | --solve | end-to-end: iterations per NLP | total | converged | control cost | hops | wall s |",
                  "|---|---|---|---|---|---|---|---|"]
        for case, f in full:
            lines.append(f"| {case} | `{_given(f)}` | {' / '.join(map(str, f['nlp_iterations']))} | {f['ipopt_iterations']} | "
                         f"{f['converged']} | {f['control_cost']:.1f} | {f['hops']} | {f['wall_s']:.1f} |")
        if len(records) > 1:  # the set's verdict per --solve: one case's iteration count is a draw
            lines += ["", "| --solve | converged | iterations: median, total | wall s: median, total |", "|---|---|---|---|"]
            groups: dict[str, list] = {}
            for _, f in full:
                groups.setdefault(json.dumps(f["solve"]) + (" raced" if f.get("race") else ""), []).append(f)
            for given, runs in groups.items():
                its, wall = [f["ipopt_iterations"] for f in runs], [f["wall_s"] for f in runs]
                lines.append(f"| `{given}` | {sum(f['converged'] for f in runs)} of {len(runs)} | {statistics.median(its):.0f}, {sum(its)} | "
                             f"{statistics.median(wall):.1f}, {sum(wall):.1f} |")
    return "\n".join(lines)


def _given(full_solve: dict) -> str:
    """A full solve's --solve object as the tables print it, with the race's arms when it raced."""
    text = json.dumps(full_solve["solve"])
    arms = full_solve.get("race")
    return text if not arms else f"{text} race: {race_arms_text(arms)}"


def plot(records, path: Path) -> None:
    """Stacked bars: CPU ms per iteration of every (case, variant), callbacks and the rest."""
    rows = [(f"{r['case']} {v}", m) for r in records for v, m in r["variants"].items()]
    # the legend beside the bars, not over them: with one or two bars it was cut at the figure's edge
    fig = Figure(figsize=(10.5, max(0.35 * len(rows) + 1.2, 2.2)), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    y = np.arange(len(rows))
    left = np.zeros(len(rows))
    for c in (*CALLBACKS, "rest"):
        w = np.array([m["rest_cpu_ms_per_iter"] if c == "rest" else m["eval_cpu_ms_per_iter"][c] for _, m in rows])
        ax.barh(y, w, left=left, label="nlp_" + c if c != "rest" else "rest (MUMPS + IPOPT)")
        left += w
    ax.set_yticks(y, [label for label, _ in rows], fontsize=7)
    ax.invert_yaxis()
    ax.set_xlabel(f"CPU time per IPOPT iteration [ms] (NLP {records[0]['nlp']}, fixed iterations)")
    fig.legend(fontsize=7, loc="outside right upper")
    save_figure(fig, path, dpi=110)


def main(argv: list[str] | None = None) -> int:
    parser = script_parser(__doc__)
    parser.add_argument("--out", type=out_dir, default=DEFAULT_OUT, help=f"output directory (default {DEFAULT_OUT})")
    parser.add_argument("--quick", action="store_true", help="CI smoke run: the hop with N = 6, 10 iterations, 1 repeat")
    parser.add_argument("--cases", nargs="+", choices=sorted(CASES) + ["capler_set"],
                        help=f"default: capler50, capler125, hop (--quick: hop); capler_set: {', '.join(CAPLER_SET)}")
    parser.add_argument("--variants", nargs="+", choices=list(VARIANTS), help="IPOPT variants (default: all; baseline is always run)")
    parser.add_argument("--iters", type=int, help="IPOPT iterations of the fixed run (default 150, --quick 10)")
    parser.add_argument("--repeats", type=int, help="interleaved repeats, the median is reported (default 3, --quick 1)")
    parser.add_argument("--codegen", action="store_true", help="also the generated-and-compiled NLP functions (gcc; minutes for Capler)")
    parser.add_argument("--codegen-flags", type=str.split, default=DEFAULT_CODEGEN_FLAGS, metavar="'FLAGS'",
                        help="gcc flags of --codegen in one argument (default -O1), e.g. --codegen-flags='-O2 -march=native'")
    # (no default here: _ScriptParser checks a default for every run: a HOME without it refused runs without --codegen)
    parser.add_argument("--cache", type=out_dir, help=f"compiled NLP cache of --codegen (default {DEFAULT_CACHE})")
    parser.add_argument("--full", action="store_true", help="also solve each case end to end with the default SolveOptions")
    parser.add_argument("--full-only", action="store_true", help="only the end-to-end solve (no fixed-iteration runs)")
    parser.add_argument("--nlp", type=int, choices=(1, 2), default=1,
                        help="the homotopy NLP of the fixed-iteration runs: 1 (default) or 2 (from NLP 1's solution, as solve runs it)")
    parser.add_argument("--solve", nargs="+", default=["{}"], metavar="JSON",
                        help="one end-to-end solve per JSON object of SolveOptions fields (default '{}': the defaults), "
                             "e.g. '{\"warm_ipopt\": {\"alpha_for_y\": \"min\"}}'")
    parser.add_argument("--race", action="store_true",
                        help="race each end-to-end solve against the second arm of planner.race.default_arms on two CPUs, as `planner plan` does")
    parser.add_argument("--step-form", choices=[f.value for f in StepForm], default=StepForm.MASS_MATRIX.value,
                        help="ProblemOptions.step_form of every case (default mass_matrix, the package's)")
    parser.add_argument("--no-lift", action="store_true",
                        help="ProblemOptions.lift_products = False: the products of selectors substituted, not lifted variables")
    parser.add_argument("--json", action="store_true", help="print results.json on stdout instead of the table")
    args = parser.parse_args(argv)
    prepare_out_dir(args.out)  # before the runs: an --out that is a file was refused only after them
    problem_options = ProblemOptions(step_form=StepForm(args.step_form), lift_products=not args.no_lift)
    cases = args.cases or (["hop"] if args.quick else ["capler50", "capler125", "hop"])
    # each once (a case or variant named twice, or capler125 beside capler_set, ran twice)
    cases = list(dict.fromkeys(c for name in cases for c in (CAPLER_SET if name == "capler_set" else (name,))))
    variants = [] if args.full_only else ["baseline"] + list(dict.fromkeys(v for v in (args.variants or VARIANTS)
                                                                            if v != "baseline"))
    full = []
    if (args.solve != parser.get_default("solve") or args.race) and not (args.full or args.full_only):  # they apply to the full solves only
        parser.error("--solve and --race apply to the full solves: add --full or --full-only")
    for text in args.solve if (args.full or args.full_only) else []:
        try:
            given = solve_fields_from_json(text)
            full.append((given, solve_options_from_dict(given)))
        except InputError as e:
            parser.error(f"--solve: {e}")
    fixed = [flag for flag, given in (("--variants", args.variants), ("--iters", args.iters),
                                      ("--repeats", args.repeats), ("--nlp", args.nlp != parser.get_default("nlp")),
                                      ("--codegen", args.codegen)) if given]
    if args.full_only and fixed:  # no fixed-iteration run: they were recorded in results.json as if they had applied
        parser.error(f"{', '.join(fixed)} set{'s' if len(fixed) == 1 else ''} the fixed-iteration runs, which "
                     "--full-only skips")
    codegen_only = [flag for flag, key in (("--codegen-flags", "codegen_flags"), ("--cache", "cache"))
                    if getattr(args, key) != parser.get_default(key)]
    if codegen_only and not args.codegen:  # (ignored, and the command line recorded as run)
        verb = "applies" if len(codegen_only) == 1 else "apply"
        parser.error(f"{', '.join(codegen_only)} {verb} to --codegen only: add it")
    for flag, value in (("--iters", args.iters), ("--repeats", args.repeats)):
        if value is not None and value < 1:
            parser.error(f"{flag} must be >= 1, got {value}")
    iters = args.iters or (10 if args.quick else 150)
    repeats = args.repeats or (1 if args.quick else 3)
    if args.codegen and args.cache is None:  # checked here, where it is used (see --cache)
        args.cache = checked_default(parser, "--cache", DEFAULT_CACHE)
    codegen = {"cache": args.cache, "flags": [f for f in args.codegen_flags]} if args.codegen else None

    def log(case, what, rec):  # progress on stderr: stdout keeps the table or the JSON
        if "cpu_ms_per_iter" in rec:
            rec = {k: rec[k] for k in ("iterations", "objective", "cpu_ms_per_iter", "rest_cpu_ms_per_iter", "wall_ms_per_iter")}
        print(f"{case:<10} {what:<20} {json.dumps(rec, default=str)[:300]}", file=sys.stderr, flush=True)

    # solve() does this for its own run: without it MUMPS's page faults add system time to every fixed-iteration run;
    # one block over every case (a solve inside it no longer gives the allocator back between the cases)
    load_before, start = os.getloadavg(), time.perf_counter()
    with freed_memory_kept() as heap_kept:
        records = [run_case(c, args.quick, iters, repeats, variants, codegen, full, log, args.nlp, args.race,
                            problem_options) for c in cases]
    results = {"command": "python -m scripts.bench_pipeline " + shlex.join(argv if argv is not None else sys.argv[1:]),
               "quick": args.quick, "total_wall_time_s": time.perf_counter() - start,
               "machine": {**machine_info(), "keep_freed_memory": heap_kept, "load_average_before": load_before,
                           "load_average_after": os.getloadavg()},
               "variants": {v: VARIANTS[v] for v in variants}, "records": records}
    # results.json first: a plot that fails loses no run; an earlier run's plot would sit beside these results as
    # theirs (where this run draws none, or this plot fails)
    (args.out / "pipeline.png").unlink(missing_ok=True)
    code = report(args.out, results, table(records), args.json)
    if any(r["variants"] for r in records):
        plot(records, args.out / "pipeline.png")
    return code


if __name__ == "__main__":
    sys.exit(run_main(main))
