"""The homotopy solves a small frictional hop exactly; options are validated."""
from __future__ import annotations

import dataclasses
import pathlib
import re
import warnings

import casadi as ca
import numpy as np
import pytest

from planner import homotopy as H
from planner.errors import InputError
from planner.model import load_robot
from planner.problem import build_problem, static_controls
from planner.result import TAP_SHARE
from planner.task import Horizon, load_task

from test_problem import CROUCH_Q, hop_task

POINT_MASS_XML = pathlib.Path(__file__).resolve().parents[1] / "robots" / "point_mass.xml"  # (not the cwd's)
# Verdict thresholds of the issue: complementarity residual and terminal error at most 1e-6.
COMP_TOL = 1e-6
TERMINAL_TOL = 1e-6  # [m]


@pytest.fixture(scope="module")
def hop():
    robot = load_robot("robots/point_mass.xml")
    prob = build_problem(robot, hop_task(N=40))
    records = []
    result = H.solve(prob, H.SolveOptions(), progress=records.append)
    return prob, result, records


def test_point_mass_hop_converges(hop):
    """From y0 everywhere and u = 0 the no-slip point mass finds a hop to x = 0.5: every NLP
    converges, the polished point has complementarity <= 1e-6 and terminal error <= 1e-6."""
    prob, res, records = hop
    assert res.stats.converged, res.stats.message
    assert all(r.success for r in res.nlps)
    assert res.polished
    assert res.stats.complementarity_residual <= COMP_TOL
    assert res.terminal_error <= TERMINAL_TOL
    assert len(records) == len(res.nlps)
    # the task's rho0 kappa^i without the rho < rho_min = 100 and continued to rho_max = 1e6 (SolveOptions),
    # up to the early stop (test_early_stop_ends_the_homotopy_at_the_first_complementary_nlp)
    schedule = H.task_rho_schedule(prob.task.plan.homotopy, 100.0, 1e6, (3e3,))
    assert schedule == [100.0, 1000.0, 3e3, 1e4, 1e5, 1e6]
    homotopy = [r for r in records if r.label.startswith("homotopy")]
    assert [r.rho for r in homotopy] == schedule[: len(homotopy)] and [r.label for r in records[-2:]] == ["polish", "reoptimize"]


def test_eval_timings_cover_every_ipopt_of_the_solve(hop):
    """timings["ipopt_evals_s"] sums the NLP callbacks' wall time per IPOPT over the whole solve: it names the
    homotopy's, the projection's and the schedule's IPOPTs (the re-scaling before the re-optimization does not
    drop the earlier ones; the hop's warm NLPs share the cold IPOPT, their options being the same), and their
    evaluation time is positive and below the solve's IPOPT time."""
    _, res, records = hop
    evals = res.timings["ipopt_evals_s"]
    assert set(evals) == {"tf_ocp_cold", "tf_ocp_projection", "tf_ocp_schedule"}
    total = sum(sum(v.values()) for v in evals.values())
    assert 0.0 < total < res.timings["ipopt_s"]


# The later NLPs (rho 1e5, 1e6) move an already complementary point by ~1e-5 (IPOPT's restart from
# mu = 0.1 leaves it and comes back); both polishes project onto the same active set.
SAME_PLAN_TOL = 1e-4  # [m, m/s, s] largest difference of the NLP states


def test_early_stop_ends_the_homotopy_at_the_first_complementary_nlp(hop):
    """SolveOptions.early_stop_comp: the homotopy ends at the first NLP after NLP 1 whose largest gated
    product is <= early_stop_comp (every earlier one is above it); with None the whole schedule runs.
    Both converge to the same plan (states within SAME_PLAN_TOL), and the projection polish stays next
    to its start (squared distance <= 1e-6)."""
    prob, res, records = hop
    stop = H.SolveOptions().early_stop_comp
    homotopy = [r for r in records if r.label.startswith("homotopy")]
    assert homotopy[-1].complementarity_residual <= stop and homotopy[-1].success
    assert all(r.complementarity_residual > stop for r in homotopy[1:-1])
    assert len(homotopy) < 6  # the hop's products are ~1e-18 at rho = 1e4: 1e5 and 1e6 are skipped
    full = H.solve(prob, H.SolveOptions(early_stop_comp=None))
    assert full.stats.converged and [r.rho for r in full.nlps if r.label.startswith("homotopy")] == [100.0, 1000.0, 3e3, 1e4, 1e5, 1e6]
    Y0, Y1 = (prob.split(r.extra["_x"])["Y"] for r in (res, full))
    assert np.abs(Y0 - Y1).max() <= SAME_PLAN_TOL
    assert all(next(r for r in run.nlps if r.label == "polish").objective <= 1e-6 for run in (res, full))


def test_point_mass_hop_phases(hop):
    """The plan flies (a hop) and lands inelastically: post-impact normal velocity 0, a tangential
    impulse against the sliding direction. (The z motor can hold the mass at zero height, so the
    plan may glide after the impact instead of sticking: both are solutions of the model.)"""
    _, res, _ = hop
    tr = res.trajectory
    assert len(res.hops) >= 1 and res.hops[0].distance > 0.3
    assert len(tr.impacts) >= 1
    imp = tr.impacts[-1]
    assert imp.impulse > 0 and abs(imp.impulse_tangential) > 0
    assert imp.v_post[1] == pytest.approx(0.0, abs=1e-6)  # inelastic: no normal velocity after the impact
    assert imp.impulse_tangential * imp.v_pre[0] < 0  # friction opposes the sliding velocity
    assert tr.t[-1] == pytest.approx(1.0, abs=0.05)  # the clock ran almost the whole horizon


def test_active_set_bounds_fix_one_side():
    """Polishing bounds fix, per selector, sigma and the opposite multiplier (sigma at a bound) or both
    multipliers (interior sigma)."""
    robot = load_robot("robots/point_mass.xml")
    prob = build_problem(robot, hop_task(N=2))
    x = prob.x0.copy()
    s, l0, l1 = (prob.var_blocks[b][0] for b in ("sigma", "lambda0", "lambda1"))
    x[s[:3]] = [0.0, 1.0, 0.4]
    x[l0[:3]] = [2.0, 0.0, 1e-3]
    x[l1[:3]] = [0.0, 3.0, 1e-3]
    lbx, ubx, xc = H.active_set_bounds(prob, x)
    assert lbx[s[0]] == ubx[s[0]] == 0 and ubx[l1[0]] == 0 and ubx[l0[0]] == np.inf
    assert lbx[s[1]] == ubx[s[1]] == 1 and ubx[l0[1]] == 0 and ubx[l1[1]] == np.inf
    assert ubx[l0[2]] == ubx[l1[2]] == 0 and (lbx[s[2]], ubx[s[2]]) == (0, 1)
    assert np.all(xc >= lbx) and np.all(xc <= ubx)


def test_a_list_for_a_tuple_field_is_stored_as_the_tuple():
    """A list given for a tuple field (SolveOptions built in code, or from JSON) is stored as the tuple: the options
    equal and hash as those built with the tuple (a list kept as given made hash() raise TypeError)."""
    listed, tupled = H.SolveOptions(rho_f_schedule=[10.0, 2.0]), H.SolveOptions(rho_f_schedule=(10.0, 2.0))
    assert listed.rho_f_schedule == (10.0, 2.0) and isinstance(listed.rho_f_schedule, tuple)
    assert listed == tupled and hash(listed) == hash(tupled)


@pytest.mark.parametrize("kwargs, key", [({"tol": 0}, "tol"), ({"max_iter": 0}, "max_iter"),
                                         ({"mu_strategy": "fast"}, "mu_strategy"),
                                         ({"nlp_scaling_method": "magic"}, "nlp_scaling_method"), ({"comp_tol": -1}, "comp_tol"),
                                         ({"polish": "yes"}, "polish"), ({"warm_start": "dual"}, "warm_start"),
                                         ({"mumps_ordering": "amf2"}, "mumps_ordering"),
                                         # not built into the wheel's MUMPS, which took its default (session 56)
                                         ({"mumps_ordering": "pord"}, "mumps_ordering"),
                                         ({"mumps_ordering": "scotch"}, "mumps_ordering"),
                                         # needs HSL's MC19: IPOPT refused it at the solve (session 56)
                                         ({"nlp_scaling_method": "equilibration-based"}, "nlp_scaling_method"),
                                         ({"retry_terminal_weight": 0.0}, "retry_terminal_weight"),
                                         ({"early_stop_comp": 0.0}, "early_stop_comp"),
                                         ({"rho_f_schedule": ()}, "rho_f_schedule"), ({"rho_f_schedule": (10.0, 0.0)}, "rho_f_schedule"),
                                         ({"rho_f_schedule": ["10"]}, "rho_f_schedule"),
                                         ({"tol": "small"}, "tol = 'small' is not allowed; it must be a finite number"),
                                         ({"tol": float("inf")}, "tol = inf is not allowed; it must be a finite number"),
                                         ({"rho_max": float("inf")}, "rho_max = inf"),  # the schedule's loop never ended
                                         ({"rho_schedule": (1.0, float("inf"))}, "rho_schedule = "),
                                         ({"max_iter": 1.5}, "max_iter = 1.5 is not allowed; it must be an integer"),
                                         ({"reoptimize": "yes"}, "reoptimize"), ({"linear_solver": 27}, "linear_solver"),
                                         ({"rho_min": "none"}, "rho_min"), ({"warm_mu_init": "x"}, "warm_mu_init = 'x' is not allowed"),
                                         ({"rho_min": -1.0}, "rho_min = -1.0 is not allowed; it must be > 0"),
                                         ({"rho_min": 1e7}, "rho_min = 10000000.0 is not allowed; it must be <= rho_max = 1000000.0"),
                                         ({"rho_max": 0.0}, "rho_max"), ({"rho_schedule": ()}, "rho_schedule"),
                                         ({"rho_schedule": (100.0, -1.0)}, "rho_schedule"), ({"rho_refine": (0.0,)}, "rho_refine"),
                                         ({"an_schedule": (0.0,)}, "an_schedule"), ({"at_schedule": ()}, "at_schedule"),
                                         ({"l1_schedule": (1.0, -0.5)}, "l1_schedule"), ({"soft_terminal_nlps": -1}, "soft_terminal_nlps"),
                                         ({"soft_terminal_weight": 0.0}, "soft_terminal_weight"), ({"hybrid_ratio": -2.0}, "hybrid_ratio"),
                                         ({"hybrid_rho": 0.0}, "hybrid_rho"),
                                         ({"intermediate_tol": 0.0}, "intermediate_tol"),
                                         # no polish start is no polish at all (session 66's mutation testing: 0 was
                                         # accepted and the polish silently skipped, with every test green)
                                         ({"polish_starts": 0}, "polish_starts = 0 is not allowed; it must be >= 1"),
                                         ({"start_controls": "gravity"}, "start_controls = 'gravity' is not allowed"),
                                         ({"start_controls": True}, "start_controls = True is not allowed")])
def test_bad_options(kwargs, key):
    """Out-of-range or wrongly typed options are InputErrors naming the option."""
    with pytest.raises(InputError, match=re.escape(key)):
        H.SolveOptions(**kwargs)


@pytest.mark.parametrize("kwargs, key", [({"hybrid_rho": 5.0}, "hybrid_rho = 5.0"),
                                         ({"hybrid_ratio": 3.0}, "hybrid_ratio"),
                                         ({"polish": "none", "polish_starts": 5}, "polish_starts = 5"),
                                         ({"polish": "none", "polish_after_failure": False}, "polish_after_failure"),
                                         ({"polish": "none", "polish_projection": False}, "polish_projection")])
def test_options_of_a_polish_not_run_are_refused(kwargs, key):
    """The hybrid polish's options without polish = hybrid, and the polish's starts and after-failure switch with
    polish = none, are InputErrors naming the option: they were accepted, recorded in summary.json and ignored. With
    their polish they are taken."""
    with pytest.raises(InputError, match=re.escape(key) + r".* unless"):
        H.SolveOptions(**kwargs)
    H.SolveOptions(**{**kwargs, "polish": "hybrid"})


@pytest.mark.parametrize("kwargs, key, needs", [
    ({"mu_init": 1e-6}, "mu_init = 1e-06", {"mu_strategy": "monotone"}),
    ({"warm_mu_init": 1e-6}, "warm_mu_init = 1e-06", {"mu_strategy": "monotone"}),
    ({"linear_solver": "spral", "mumps_ordering": "amd"}, "mumps_ordering", {"linear_solver": "mumps"}),
    ({"soft_terminal_nlps": 0, "soft_terminal_weight": 1e6}, "soft_terminal_weight", {"soft_terminal_nlps": 1}),
    ({"rho_schedule": (1e2, 1e4), "rho_min": 5e3}, "rho_min = 5000.0", {"rho_schedule": None}),
    ({"rho_schedule": (1e2, 1e4), "rho_max": 2e4}, "rho_max = 20000.0", {"rho_schedule": None}),
    ({"rho_schedule": (1e2, 1e4), "rho_refine": (7e3,)}, "rho_refine = (7000.0,)", {"rho_schedule": None})])
def test_options_their_solve_does_not_read_are_refused(kwargs, key, needs):
    """A barrier start under the adaptive strategy (IPOPT reads mu_init with monotone only), a MUMPS ordering for
    another linear solver, a soft-terminal weight with no soft-terminal NLP and the changes of the task's penalty
    schedule beside a rho_schedule that replaces it are InputErrors naming the option: each was accepted, recorded in
    summary.json and gave the same iterations and plan as the solve without it. With what reads them they are taken."""
    with pytest.raises(InputError, match=re.escape(key) + r".* unless"):
        H.SolveOptions(**kwargs)
    H.SolveOptions(**{**kwargs, **needs})


def test_static_start_puts_the_static_torques_at_every_step():
    """SolveOptions.start_controls = static (by its JSON value, as planner plan --solve gives it) starts every step's
    u at problem.static_controls, the states at y_0 and the algebraic guess consistent with them (every product 0),
    leaving problem.x0 as built; a start that is not the hint-free one (a plan, --init) is refused before any NLP,
    as its u is the plan's."""
    opts = H.solve_options_from_dict({"start_controls": "static"})
    assert opts.start_controls is H.ControlStart.STATIC and H.SolveOptions().start_controls is H.ControlStart.ZERO
    task = load_task("robots/capler.toml")
    task = dataclasses.replace(task, initial=dataclasses.replace(task.initial, q=CROUCH_Q), horizon=Horizon(0.5, 10))
    prob = build_problem(load_robot("robots/capler.xml"), task)
    built = prob.x0.copy()
    x = H._static_start(prob)
    u, _ = static_controls(prob)
    np.testing.assert_array_equal(x[prob.var_blocks["u"]], np.tile(u, (prob.N, 1)))
    np.testing.assert_array_equal(x[prob.var_blocks["y"]], built[prob.var_blocks["y"]])
    assert np.abs(u).max() > 0 and prob.complementarity_residual(x) == 0.0
    np.testing.assert_array_equal(prob.x0, built)
    prob.x0 = x
    with pytest.raises(InputError, match="start_controls = static replaces the u of the hint-free start"):
        H.solve(prob, opts)


def test_replan_options_refuse_what_they_replace():
    """replan_options refuses options it would replace (rho_schedule 1e5 came back (1e4, 1e6) without a word) and a
    soft-terminal weight its soft_terminal_nlps = 0 leaves unread, naming them; the rest it keeps."""
    with pytest.raises(InputError, match=r"replan_options sets rho_schedule, bound_push: leave them at the default"):
        H.replan_options(H.SolveOptions(rho_schedule=(1e5,), bound_push=0.1))
    with pytest.raises(InputError, match=r"soft_terminal_weight .* \(a replan solves with soft_terminal_nlps = 0"):
        H.replan_options(H.SolveOptions(soft_terminal_weight=1e6))
    with pytest.raises(InputError, match=r"replan_options sets rho_max: leave it at the default"):  # (1e6 was run)
        H.replan_options(H.SolveOptions(rho_max=1e5))
    assert H.replan_options(H.SolveOptions(max_iter=77)).max_iter == 77
    # the replan's own monotone barrier given too is no conflict: warm_mu_init, read under it, stays (it was refused)
    assert H.replan_options(H.SolveOptions(mu_strategy="monotone", warm_mu_init=1e-5)).warm_mu_init == 1e-5


def test_edge_options_are_accepted():
    """The boundary values that mean something are allowed: no soft-terminal NLP, zero l1 weights, no refinement
    penalties, rho_min = rho_max (one NLP), and the options solve() itself derives (replan, FESD)."""
    H.SolveOptions(soft_terminal_nlps=0, l1_schedule=(0.0,), rho_refine=(), rho_min=1e3, rho_max=1e3)
    H.replan_options()


def test_locally_infeasible_homotopy_is_retried_with_a_stronger_soft_terminal(monkeypatch):
    """Point-mass stress task holes-00 (docs/stability.md): with the soft terminal's weight 100, NLP 1
    lands on the hole's edge 0.24 m short and every later NLP is locally infeasible; the retry with
    retry_terminal_weight = 1e4 converges, and both attempts are recorded. The first attempt's IPOPTs are freed
    before the retry makes its own (they stayed alive through it: session 57's tester, 535 against 350 MB)."""
    import gc
    import weakref

    from planner.task import parse_task

    made, freed, real_init, real_retry = [], [], H._Solvers.__init__, H._retry

    def init(self, *args, **kwargs):
        made.append(weakref.ref(self))
        real_init(self, *args, **kwargs)

    def retry(*args, **kwargs):
        gc.collect()
        freed.append(made[0]() is None)
        return real_retry(*args, **kwargs)

    monkeypatch.setattr(H._Solvers, "__init__", init)
    monkeypatch.setattr(H, "_retry", retry)

    robot = load_robot("robots/point_mass.xml")
    hole = {"x": 0.29990508500621443, "z": 0.0, "a": 0.038225447857940895, "b": 0.06721718092065786}
    task = parse_task({"contacts": [{"point": "point", "mu": 0.5, "a_n": 200.0, "a_t": 100.0}], "initial": {"q": [0.0, 0.0]},
                       "horizon": {"tau_f": 1.0, "N": 40}, "plan": {"target_q": [0.5, 0.0], "u_bound": 30.0, "holes": [hole]}})
    res = H.solve(build_problem(robot, task))
    assert res.stats.converged and res.terminal_error <= TERMINAL_TOL, res.stats.message
    assert "after a retry with soft_terminal_weight 10000" in res.stats.message
    first = [r for r in res.nlps if r.label.startswith("try 1: ")]
    assert first and "Infeasible_Problem_Detected" in {r.status for r in first}
    assert res.stats.n_nlp == len(res.nlps)
    assert freed == [True]


def test_warm_start_modes_pass_the_multipliers_only_when_asked():
    """WarmStart.PRIMAL_DUAL turns on IPOPT's warm_start_init_point for the later NLPs (so the
    multipliers passed in are used); PRIMAL does not, and then the later NLPs share NLP 1's IPOPT
    because their options are identical."""
    prob = build_problem(load_robot("robots/point_mass.xml"), hop_task(N=6))
    for mode, shared in ((H.WarmStart.PRIMAL, True), (H.WarmStart.PRIMAL_DUAL, False)):
        opts = H.SolveOptions(warm_start=mode)
        assert ("warm_start_init_point" in H.ipopt_options(opts, warm=True)["ipopt"]) is not shared
        assert "warm_start_init_point" not in H.ipopt_options(opts, warm=False)["ipopt"]
        solvers = H._Solvers(prob, opts)
        assert (solvers.get(warm=True) is solvers.get(warm=False)) is shared


SCALED_NLP_TOL = 1e-9  # relative: the scaled NLP is the same function, only the rounding of x = D xs differs


def test_variable_scaling_sees_the_same_nlp_in_scaled_variables():
    """VariableScaling.FIRST_NLP: variable_scale gives each stage column its largest magnitude (at least
    1, and 1 outside the stage blocks); the scaled warm IPOPT's objective and constraints at xs = x / D
    equal the unscaled ones at x (to rounding), the cold NLP 1 solver stays unscaled (and is dropped once the scale
    is set), and a solve with
    it on the point-mass hop converges with every NLP. The task key [plan.homotopy] scale_variables
    chooses the mode when SolveOptions leaves it None; an unknown mode is rejected."""

    prob = build_problem(load_robot("robots/point_mass.xml"), hop_task(N=8))
    rng = np.random.default_rng(0)
    x = prob.x0 + rng.normal(scale=50.0, size=prob.nx)
    D = H.variable_scale(prob, x)
    u = prob.var_blocks["u"]
    assert np.all(D >= 1.0) and D[prob.var_blocks["s_c"]] == 1.0
    np.testing.assert_array_equal(D[u[0]], np.maximum(np.abs(x[u]).max(axis=0), 1.0))
    solvers = H._Solvers(prob, H.SolveOptions(variable_scaling=H.VariableScaling.FIRST_NLP))
    cold = solvers.get(warm=False)
    solvers.set_scale(D)
    # NLP 1's solver is not kept once the scale is set (it is not used again; ~90 MB at Capler's N = 125); the cold
    # one asked again is unscaled, the warm one scaled
    assert not solvers.cache and not solvers.sees_scale(warm=False) and solvers.sees_scale(warm=True)
    assert solvers.get(warm=False) is not cold and len(solvers.cache) == 1
    assert not next(iter(solvers.cache)).startswith("scaled") and solvers.get(warm=True) is not cold
    P = prob.params(1e3, 1.0)
    fg = ca.Function("fg", [prob.x, prob.p], [prob.f, prob.g])
    fgs = ca.Function("fgs", [solvers.scaled_nlp["x"], solvers.scaled_nlp["p"]], [solvers.scaled_nlp["f"], solvers.scaled_nlp["g"]])
    (f0, g0), (f1, g1) = fg(x, P), fgs(x / D, P)
    np.testing.assert_allclose(float(f1), float(f0), rtol=SCALED_NLP_TOL)
    np.testing.assert_allclose(np.asarray(g1).ravel(), np.asarray(g0).ravel(), rtol=SCALED_NLP_TOL, atol=SCALED_NLP_TOL)

    res = H.solve(build_problem(load_robot("robots/point_mass.xml"), hop_task(N=40)),
                  H.SolveOptions(variable_scaling=H.VariableScaling.FIRST_NLP))
    assert res.stats.converged and all(r.success for r in res.nlps), res.stats.message
    assert res.stats.complementarity_residual <= COMP_TOL and res.terminal_error <= TERMINAL_TOL
    with pytest.raises(InputError, match="first_nlp"):
        H.SolveOptions(variable_scaling="on")
    from planner.task import load_task

    assert load_task("robots/capler.toml").plan.homotopy.scale_variables and not hop_task(N=4).plan.homotopy.scale_variables


def test_mumps_ordering_is_passed_to_ipopt():
    """SolveOptions.mumps_ordering becomes IPOPT's mumps_pivot_order (only with MUMPS); an unknown
    name lists the valid ones."""
    assert H.ipopt_options(H.SolveOptions(mumps_ordering=H.MumpsOrdering.AMD), warm=False)["ipopt"]["mumps_pivot_order"] == 0
    assert H.ipopt_options(H.SolveOptions(mumps_ordering=H.MumpsOrdering.AUTO), warm=True)["ipopt"]["mumps_pivot_order"] == 7
    assert "mumps_pivot_order" not in H.ipopt_options(H.SolveOptions(linear_solver="ma27"), warm=False)["ipopt"]
    with pytest.raises(InputError, match="metis"):
        H.SolveOptions(mumps_ordering="nested")


def test_an_unknown_or_missing_linear_solver_is_an_input_error(hop):
    """linear_solver must be one of IPOPT's names; one whose library is not installed (HSL's ma27: the CasADi wheel
    ships none) is an InputError naming it as soon as IPOPT refuses it, not a result built from IPOPT's unset
    iteration counts and a nan objective."""
    with pytest.raises(InputError, match="linear_solver = 'foo' is not allowed"):
        H.SolveOptions(linear_solver="foo")
    prob = hop[0]
    with pytest.raises(InputError, match="an option needs a library this install lacks, e.g. linear_solver 'ma27'"):
        H.solve(prob, H.SolveOptions(linear_solver="ma27"))
    # HSL's MC19 as the one missing library: the message named the installed linear solver alone (session 56)
    with pytest.raises(InputError, match="or HSL's MC19"):
        H.solve(prob, H.SolveOptions(ipopt={"linear_system_scaling": "mc19"}))


def test_replan_fields_are_the_ones_replan_options_sets():
    """homotopy.REPLAN_FIELDS, which `planner plan --init DIR --solve` refuses (they were replaced silently), are
    exactly the SolveOptions fields replan_options changes and those that act on the task's schedule only, which its
    rho_schedule replaces."""
    default, replan = H.SolveOptions(), H.replan_options()
    changed = {f.name for f in dataclasses.fields(default) if getattr(default, f.name) != getattr(replan, f.name)}
    assert changed | {"rho_min", "rho_max", "rho_refine"} == set(H.REPLAN_FIELDS)


def test_acceptable_tol_below_tol_is_refused():
    """SolveOptions.acceptable_tol set below tol is an InputError naming both: IPOPT was given tol instead, while the
    result's options recorded the value asked for. Equal to tol is allowed, and the default (None) gives IPOPT
    ACCEPTABLE_TOL or tol when that is larger, so tol = 1e-5 alone is accepted."""
    with pytest.raises(InputError, match=r"^SolveOptions\.acceptable_tol = 1e-10 is not allowed; it must be >= tol = 1e-08"):
        H.SolveOptions(acceptable_tol=1e-10)
    assert H.SolveOptions(tol=1e-6, acceptable_tol=1e-6).acceptable_tol == 1e-6
    for tol, given in ((1e-5, 1e-5), (1e-8, H.ACCEPTABLE_TOL)):
        assert H.ipopt_options(H.SolveOptions(tol=tol), warm=False)["ipopt"]["acceptable_tol"] == given


@pytest.mark.parametrize("kwargs, fragment", [
    ({"ipopt": {"no_such_option": 1}}, "No such IPOPT option: no_such_option"),
    ({"ipopt": {"alpha_for_y": "sideways"}}, "Valid: primal, bound-mult, min"),
    ({"warm_ipopt": {"max_cpu_time": -1.0}}, "Range: 0 <"),
    ({"ipopt": {"tol": 1e-3}}, "SolveOptions.tol owns"),
    ({"warm_ipopt": {"mu_init": 1e-3}}, "SolveOptions.warm_mu_init owns"),
    ({"ipopt": {"print_user_options": True}}, "values finite numbers or strings"),
    ({"ipopt": {"constr_viol_tol": float("nan")}}, "values finite numbers or strings"),
    ({"warm_ipopt": {"obj_scaling_factor": float("inf")}}, "values finite numbers or strings"),
    ({"ipopt": ["alpha_for_y"]}, "must be a dict of IPOPT options"),
    ({"warm_ipopt": {"acceptable_iter": 2.5}}, "'acceptable_iter' = 2.5 is not allowed; IPOPT's acceptable_iter is an "
                                               "integer"),  # it ran as 2
    ({"ipopt": {"acceptable_iter": 2**32 + 1}}, "IPOPT's acceptable_iter is an integer a C int holds"),  # ran as 1
    # each NLP wrote it anew (the last NLP's log alone), two race arms over each other (mostly NUL bytes)
    ({"warm_ipopt": {"output_file": "ipopt.log"}}, "sets IPOPT's 'output_file', which each NLP of the homotopy"),
])
def test_ipopt_pass_through_is_checked_by_ipopt_at_construction(kwargs, fragment):
    """SolveOptions.ipopt / warm_ipopt: what IPOPT rejects (unknown name, value outside its list or range), an
    option a field owns, an output file each NLP would overwrite, and a malformed value are InputErrors when the
    options are made, with IPOPT's reason."""
    with pytest.raises(InputError, match=re.escape(fragment)):
        H.SolveOptions(**kwargs)
    numpy = H.SolveOptions(ipopt={"acceptable_iter": np.int64(5), "acceptable_obj_change_tol": np.float32(0.5)})
    assert numpy.ipopt == (("acceptable_iter", 5), ("acceptable_obj_change_tol", 0.5))  # numbers too (were refused)


CPU_LIMIT = 1e-9  # [s] IPOPT's max_cpu_time: expires at the first check, so the NLP's status shows the option arrived


def test_ipopt_pass_through_reaches_the_cold_and_the_warm_nlps():
    """ipopt reaches every homotopy NLP, warm_ipopt only NLP 2 on: with max_cpu_time ~0 there, exactly those
    NLPs stop with IPOPT's CPU-time status; the options are kept as sorted pairs."""
    robot, task = load_robot("robots/point_mass.xml"), hop_task(N=10)
    problem = build_problem(robot, task)
    base = dict(rho_schedule=(100.0, 1000.0), polish=H.Polish.NONE, retry_terminal_weight=None, early_stop_comp=None)
    warm = H.solve(problem, H.SolveOptions(**base, warm_ipopt={"max_cpu_time": CPU_LIMIT}))
    assert [r.status for r in warm.nlps] == ["Solve_Succeeded", "Maximum_CpuTime_Exceeded"]
    every = H.solve(problem, H.SolveOptions(**base, ipopt={"max_cpu_time": CPU_LIMIT}))
    assert [r.status for r in every.nlps] == ["Maximum_CpuTime_Exceeded"] * 2
    opts = H.SolveOptions(ipopt={"max_soc": 0, "alpha_for_y": "min"})
    assert opts.ipopt == (("alpha_for_y", "min"), ("max_soc", 0))
    assert H.ipopt_options(opts, warm=False)["ipopt"]["alpha_for_y"] == "min"


def _ipopt_options_seen(monkeypatch) -> dict:
    """name -> the IPOPT options of each nlpsol CasADi builds from now on in the test."""
    seen, real = {}, H.ca.nlpsol

    def spy(name, solver, nlp, opts):
        seen[name] = dict(opts["ipopt"])
        return real(name, solver, nlp, opts)

    monkeypatch.setattr(H.ca, "nlpsol", spy)
    return seen


def test_the_users_ipopt_options_reach_the_schedule_and_projection_nlps(monkeypatch):
    """SolveOptions.ipopt (and warm_ipopt for a warm NLP) win over the held-schedule and projection NLPs' own IPOPT
    settings: `--ipopt acceptable_iter=10 accept_every_trial_step=no mumps_permuting_scaling=7` was recorded and
    replaced there (IPOPT's list of user options showed 2, yes and 0)."""
    problem = build_problem(load_robot("robots/point_mass.xml"), hop_task(N=3))
    seen = _ipopt_options_seen(monkeypatch)
    given = {"acceptable_iter": 10, "accept_every_trial_step": "no", "mumps_permuting_scaling": 7}
    solvers = H._Solvers(problem, H.SolveOptions(ipopt=given, warm_ipopt={"acceptable_iter": 11}))
    solvers.get(True, schedule=True)
    solvers.projection()
    assert {k: seen["tf_ocp_schedule"][k] for k in given} == {**given, "acceptable_iter": 11}
    assert {k: seen["tf_ocp_projection"][k] for k in given} == given


def test_the_projection_polish_leaves_a_restoration_phase_early(monkeypatch):
    """The projection polish's IPOPT, and only it, stops after PROJECTION_MAX_RESTO_ITER successive restoration
    iterations: a projection starts next to a feasible point, and one that entered restoration (Capler without holes,
    N = 40) stayed there to the 3000 cap from both starts, 130 s for a failed solve. The homotopy's NLPs keep IPOPT's
    default: their restoration is how a warm start far from feasible comes back."""
    problem = build_problem(load_robot("robots/point_mass.xml"), hop_task(N=3))
    seen = _ipopt_options_seen(monkeypatch)
    solvers = H._Solvers(problem, H.SolveOptions())
    solvers.get(False)
    solvers.get(True)
    solvers.get(True, schedule=True)
    solvers.projection()
    assert seen["tf_ocp_projection"]["max_resto_iter"] == H.PROJECTION_MAX_RESTO_ITER
    assert [n for n, opts in seen.items() if "max_resto_iter" in opts] == ["tf_ocp_projection"]
    H._Solvers(problem, H.SolveOptions(ipopt={"max_resto_iter": 7})).projection()  # (the user's own value wins)
    assert seen["tf_ocp_projection"]["max_resto_iter"] == 7


def test_a_kept_projection_iterate_is_accepted_only_when_complementary(hop, monkeypatch):
    """_accepted takes a projection's kept iterate (IPOPT did not converge) only if its complementarity is within
    comp_tol, as a converged polish's is by its fixed active set: an accepted polish ends the search over
    polish_starts, so a kept point the verdict then refuses would cost the next start's try."""
    prob, res, _ = hop
    x, options = res.extra["_x"], H.SolveOptions()
    kept = dataclasses.replace(res.nlps[-1], success=False, kept_iteration=3, terminal_error=0.0)
    assert H._accepted(prob, options, x, kept)
    monkeypatch.setattr(prob, "complementarity_residual", lambda x: 10 * options.comp_tol)
    assert not H._accepted(prob, options, x, kept)
    assert H._accepted(prob, options, x, dataclasses.replace(kept, success=True, kept_iteration=None))


KEPT_ITERATE_TOL = 1e-12  # the callback's copy of an iterate against IPOPT's returned point: the same numbers


@pytest.mark.parametrize("cap, rows, stall_tol", [
    (3, "circle", 0.0),  # the nearest is iterate 0 (violations 0.15, 17.2, 4.08, 0.82): not the last
    (6, "circle", 0.0),  # the nearest is the last (..., 0.094, 2.4e-3, 6.7e-6): not the first
    (6, "circle", 0.01),  # iterates 5 and 6 within the tolerance: the smaller objective, 5's
    (4, "slack", 0.0),  # an inactive row, every violation 0: the smallest objective (here the last)
])
def test_nearest_feasible_keeps_the_iterate_nearest_its_rows_bounds(cap, rows, stall_tol):
    """_NearestFeasible keeps, of the iterates IPOPT visits, the one whose rows lie nearest their bounds, of those
    within stall_tol the one of smallest objective (the projection's distance to its start; then the latest), with
    its iteration number, unscaled by D: checked against IPOPT's own iterates, each got by capping max_iter at j
    (IPOPT then returns iterate j), on a circle-constrained least squares (or its row inactive)."""
    x = ca.SX.sym("x", 2)
    g, lbg, ubg = (ca.sumsqr(x), 1.0, 1.0) if rows == "circle" else (x[0], -10.0, 10.0)
    nlp = {"x": x, "f": (x[0] - 3) ** 2 + x[1] ** 2, "g": g}
    D = np.array([2.0, 0.5])  # (the callback sees the solver's variables; the kept point is x = D xs)

    def run(max_iter):
        keep = []
        opts = {"print_time": False, "ipopt": {"print_level": 0, "sb": "yes", "max_iter": max_iter}}
        f = H._nlpsol("circle", nlp, opts, keep, nearest_feasible=True)
        keep[-1].reset(np.array([lbg]), np.array([ubg]), D, stall_tol)
        sol = f(x0=[0.2, 0.9], lbg=lbg, ubg=ubg)
        return np.asarray(sol["x"], float).ravel(), keep[-1], f.stats()

    iterates = [run(j)[0] for j in range(cap + 1)]
    gfun = ca.Function("g", [x], [g])
    viol = [max(lbg - float(gfun(xj)), float(gfun(xj)) - ubg, 0.0) for xj in iterates]
    objective = [float(ca.Function("f", [x], [nlp["f"]])(xj)) for xj in iterates]
    _, kept, stats = run(cap)
    assert stats["return_status"] == "Maximum_Iterations_Exceeded"  # (else the test would not cap anything)
    best = min(range(cap + 1), key=lambda j: (max(viol[j], stall_tol), objective[j], -j))
    assert kept.best[1] == best
    assert abs(kept.best[0] - viol[best]) <= KEPT_ITERATE_TOL
    assert np.max(np.abs(kept.best[2] - D * iterates[best])) <= KEPT_ITERATE_TOL


def _unfinishable_projection(monkeypatch, max_iter: int):
    """From now on the projection polish's IPOPT has tolerances it cannot reach and max_iter; (problem, options, result
    of the point-mass hop solved so, its variables scaled by VariableScaling.FIRST_NLP)."""
    real = H.ca.nlpsol

    def unfinishable(name, solver, nlp, opts):
        if name == "tf_ocp_projection":
            # (tiny_step_tol 0: IPOPT's own stop on tiny steps, at rows ~1e-15, would end the hop's projection first)
            opts = dict(opts, ipopt=dict(opts["ipopt"], tol=1e-30, dual_inf_tol=1e-30, acceptable_tol=1e-30,
                                         acceptable_iter=0, tiny_step_tol=0.0, max_iter=max_iter))
        return real(name, solver, nlp, opts)

    monkeypatch.setattr(H.ca, "nlpsol", unfinishable)
    scales, made = [], []
    real_reset = H._NearestFeasible.reset

    def reset(self, lbg, ubg, D, stall_tol):
        scales.append(np.array(D))
        made.append(self)
        real_reset(self, lbg, ubg, D, stall_tol)

    monkeypatch.setattr(H._NearestFeasible, "reset", reset)
    problem = build_problem(load_robot(POINT_MASS_XML), hop_task())
    # scaled, so that the kept point must be unscaled (the hop task itself does not scale its variables)
    options = H.SolveOptions(reoptimize=False, variable_scaling=H.VariableScaling.FIRST_NLP)
    result = H.solve(problem, options)
    assert scales and all(np.ptp(D) > 0 for D in scales[1:])  # ([0]: the callback's own construction)
    return problem, options, result, made[-1]


def test_a_projection_polish_ipopt_does_not_finish_keeps_its_feasible_iterate(monkeypatch):
    """A projection polish that IPOPT does not finish (here: tolerances it cannot reach, as Capler without holes at
    N = 40 reached rows within 1.8e-8 but a dual infeasibility stuck at 4e-4) still polishes the plan: its iterate
    nearest feasibility is kept when the plan's checks accept it, and the record says which iterate it was. Without
    it the polish was refused and the plan fell back to the homotopy's point (or failed)."""
    problem, options, result, _ = _unfinishable_projection(monkeypatch, max_iter=20)
    polish = next(r for r in result.nlps if r.label == "polish")
    assert polish.status == "Maximum_Iterations_Exceeded" and not polish.success
    assert polish.kept_iteration is not None and "kept" in polish.note
    assert result.polished and result.stats.converged
    x = result.extra["_x"]
    assert max(H.constraint_violation(problem, x).values()) <= options.constraint_tol
    assert polish.terminal_error == H.terminal_error(problem, x)


def test_a_stalled_projection_polish_stops_early_and_keeps_its_iterate(monkeypatch):
    """A projection IPOPT does not finish ends PROJECTION_STALL_ITER iterations after its rows came within
    constraint_tol (User_Requested_Stop) with its nearest iterate kept, instead of running to its cap: the penalty
    replan of Capler's N = 40 no-holes plan spent 3000 iterations (24 s) with the rows within 8e-9."""
    max_iter = 10 * H.PROJECTION_STALL_ITER
    problem, options, result, callback = _unfinishable_projection(monkeypatch, max_iter=max_iter)
    polish = next(r for r in result.nlps if r.label == "polish")
    assert polish.status == "User_Requested_Stop"
    assert polish.iterations == callback.feasible_since + H.PROJECTION_STALL_ITER
    assert max(callback.best[0], 0.0) <= options.constraint_tol and callback.best[1] == polish.kept_iteration
    assert polish.kept_iteration is not None and result.polished and result.stats.converged
    assert max(H.constraint_violation(problem, result.extra["_x"]).values()) <= options.constraint_tol


def test_gating_and_ungate_keep_the_trajectory():
    """ProblemOptions.gating: the penalty's products of alpha/zeta are weighted by 1 - beta and of
    gamma by (1 - beta) alpha; ungate resets the selectors a gate switches off to theta(h) without
    changing any constraint value (the state trajectory stays)."""
    from planner.problem import ProblemOptions
    robot = load_robot("robots/point_mass.xml")
    prob = build_problem(robot, hop_task(N=3), ProblemOptions(gating=True))
    x = prob.x0.copy()
    names = [s.name.split("[")[0] for s in prob.system.switches]
    b = prob.builder
    w = x[prob.var_blocks["w"][0]]
    sigma = w[b.w_blocks["sigma"]].copy()
    sigma[names.index("beta")] = 1.0  # flight at step 0: alpha, gamma, zeta do not act
    sigma[names.index("alpha")] = 0.3
    x[prob.var_blocks["w"][0]] = b.w_from(sigma, w[b.w_blocks["lambda0"]], w[b.w_blocks["lambda1"]], w[b.w_blocks["forces"]])
    gates = np.asarray(prob.notes["gates"](x), float).ravel()
    n = prob.system.n_sigma
    assert gates[names.index("alpha")] == 0 and gates[names.index("zeta")] == 0 and gates[names.index("beta")] == 1
    g_before = np.asarray(H._nlp_fn(prob, "g")(x, prob.params(0.0)), float).ravel()
    xu = H.ungate(prob, x)
    rows = np.concatenate([prob.g_blocks[b].ravel() for b in ("dynamics", "stationarity")])
    g_after = np.asarray(H._nlp_fn(prob, "g")(xu, prob.params(0.0)), float).ravel()
    assert np.allclose(g_after[rows], g_before[rows], atol=1e-12)
    assert np.allclose(g_after[prob.g_blocks["lifting"].ravel()], 0.0, atol=1e-12)  # lifted products recomputed
    prods = np.asarray(prob.products(xu), float).ravel()[: 2 * n]
    ia, iz = names.index("alpha"), names.index("zeta")
    assert np.all(np.abs(prods[[ia, iz, n + ia, n + iz]]) <= 1e-12)
    assert len(gates) == 2 * n * prob.N


def test_a_verdict_on_ungated_pairs_says_what_the_table_showed():
    """An unpolished point whose gated pairs are complementary (the homotopy's table: 1e-12) but whose ungated pairs are
    not is refused, and the message says that the table's number is of the gated pairs (a user saw 3.7e-12 in the table
    and "complementarity residual 0.00134 > 1e-06" as the verdict, unexplained); so does a gated number above the
    tolerance but below the verdict's (a failed plan's header said 6.9e+00, its last row 2.9e-02, unexplained)."""
    from planner.result import NlpRecord
    prob = build_problem(load_robot("robots/point_mass.xml"), hop_task(N=3))
    x = prob.x0.copy()
    names = [s.name.split("[")[0] for s in prob.system.switches]
    b = prob.builder
    w = x[prob.var_blocks["w"][0]]
    sigma, lam1 = w[b.w_blocks["sigma"]].copy(), w[b.w_blocks["lambda1"]].copy()
    sigma[names.index("beta")], sigma[names.index("alpha")] = 1.0, 0.3  # flight at step 0: alpha's pair is gated off
    lam1[names.index("alpha")] = 0.5
    x[prob.var_blocks["w"][0]] = b.w_from(sigma, w[b.w_blocks["lambda0"]], lam1, w[b.w_blocks["forces"]])
    assert prob.complementarity_residual(x) > H.SolveOptions().comp_tol
    record = NlpRecord(label="homotopy 1", rho=100.0, hole_scale=1.0, objective=0.0, complementarity_residual=1e-12,
                       iterations=1, time_s=0.0, status="Solve_Succeeded", success=True, terminal_error=0.0)
    message = H._result(prob, H.SolveOptions(), x, [record], None, 0.0, {}).stats.message
    assert "homotopy 1's 1.0e-12 is of the gated pairs" in message
    record = dataclasses.replace(record, complementarity_residual=1e-4)
    message = H._result(prob, H.SolveOptions(), x, [record], None, 0.0, {}).stats.message
    assert "homotopy 1's 1.0e-04 is of the gated pairs" in message
    same = dataclasses.replace(record, complementarity_residual=prob.complementarity_residual(x) * (1 - 1e-12))
    # one rounding apart: nothing to explain
    assert "gated pairs" not in H._result(prob, H.SolveOptions(), x, [same], None, 0.0, {}).stats.message


def test_aux_continuation_scale_one_is_the_task():
    """ProblemOptions.aux_continuation with an_scale = at_scale = 1 gives the task's constraints."""
    from planner.problem import ProblemOptions
    robot = load_robot("robots/point_mass.xml")
    a = build_problem(robot, hop_task(N=3))
    b = build_problem(robot, hop_task(N=3), ProblemOptions(aux_continuation=True))
    rng = np.random.default_rng(0)
    x = a.x0 + 0.1 * rng.standard_normal(a.nx)
    ga = np.asarray(H._nlp_fn(a, "g")(x, a.params(1.0)), float).ravel()
    gb = np.asarray(H._nlp_fn(b, "g")(x, b.params(1.0)), float).ravel()
    assert np.allclose(ga, gb)
    gh = np.asarray(H._nlp_fn(b, "g")(x, b.params(1.0, 1.0, 0.5, 0.5)), float).ravel()
    assert not np.allclose(ga, gh)


def test_task_rho_schedule():
    """rho_min drops the weak penalties, rho_max continues the task's geometric schedule (and refuses a rho0 above
    it), refine sorts extra values in: only inside the schedule as rho_min and rho_max leave it and not in it already
    (a refine equal to a schedule value adds no second NLP at that penalty, one below rho_min none; session 66's
    mutation testing: a value kept when it differed from any schedule value, not from all, and the refines picked
    before rho_min, with every test green)."""
    from types import SimpleNamespace
    hom = SimpleNamespace(rho0=1.0, kappa=10.0, n_nlp=5)
    assert H.task_rho_schedule(hom) == [1.0, 10.0, 100.0, 1000.0, 10000.0]
    assert H.task_rho_schedule(hom, 100.0, 1e7) == [100.0, 1000.0, 1e4, 1e5, 1e6, 1e7]
    assert H.task_rho_schedule(hom, 1e9) == [1e4]
    assert H.task_rho_schedule(hom, 100.0, 1e7, (3e3, 1e9)) == [100.0, 1000.0, 3e3, 1e4, 1e5, 1e6, 1e7]
    assert H.task_rho_schedule(hom, 100.0, 1e7, (1e4,)) == [100.0, 1000.0, 1e4, 1e5, 1e6, 1e7]
    assert H.task_rho_schedule(hom, 100.0, 1e7, (50.0, 3e3)) == [100.0, 1000.0, 3e3, 1e4, 1e5, 1e6, 1e7]
    # a rho0 above rho_max ran its NLP anyway (1e200: 3000 iterations to objective -1e192, blamed on the target)
    with pytest.raises(InputError, match=r"plan.homotopy.rho0 = 1e\+200 is above rho_max = 1000000.0"):
        H.task_rho_schedule(SimpleNamespace(rho0=1e200, kappa=10.0, n_nlp=1), None, 1e6)


def test_homotopy_nlp_is_what_solve_hands_ipopt():
    """homotopy_nlp(problem, options, i) is NLP i as solve() runs it: the same parameters, row bounds and tolerance
    on the hop with two soft-terminal NLPs and per-NLP schedules shorter than the homotopy (the last value kept);
    the terminal rows are free exactly in the soft NLPs, the holes scaled 0 only in the first, the last NLP tight."""
    prob = build_problem(load_robot("robots/point_mass.xml"), hop_task(N=20))
    options = H.SolveOptions(soft_terminal_nlps=2, l1_schedule=(0.5, 0.0), rho_f_schedule=(10.0, 2.0), polish=H.Polish.NONE,
                             early_stop_comp=None)
    seen = {}
    real_run = H._run

    def spy(problem, solvers, x0, lam_x, lam_g, p, lbx, ubx, label, lbg=None, ubg=None, **kwargs):
        seen[label] = (np.asarray(p, float).copy(), lbg, ubg, kwargs.get("loose", False))
        return real_run(problem, solvers, x0, lam_x, lam_g, p, lbx, ubx, label, lbg, ubg, **kwargs)

    H._run = spy
    try:
        H.solve(prob, options)
    finally:
        H._run = real_run
    rhos = H.homotopy_rhos(prob, options)
    rows = H._terminal_rows(prob)
    assert len(seen) == len(rhos) >= 3
    for i, rho in enumerate(rhos):
        nlp = H.homotopy_nlp(prob, options, i)
        p, lbg, ubg, loose = seen[nlp.label]
        assert np.array_equal(p, nlp.p) and np.array_equal(lbg, nlp.lbg) and np.array_equal(ubg, nlp.ubg) and loose == nlp.loose
        assert p[0] == rho and p[5] == (0.5 if i == 0 else 0.0) and p[6] == (10.0 if i == 0 else 2.0)
        assert nlp.soft == (i < 2) and np.all(np.isinf(nlp.lbg[rows])) == nlp.soft and (p[4] > 0) == nlp.soft
        assert nlp.hole_scale == (0.0 if i == 0 else 1.0) and nlp.loose == (i < len(rhos) - 1)


def _mmaps_64_mib() -> bool:
    """Whether glibc serves a block of 64 MiB (the size class of MUMPS's factor storage) or more by a fresh mmap:
    mallinfo2's mmapped bytes grow. Skips off Linux and below glibc 2.33 (no mallinfo2)."""
    import ctypes
    import ctypes.util
    import sys

    if not sys.platform.startswith("linux"):
        pytest.skip("glibc's mallopt: Linux only")
    libc = ctypes.CDLL(ctypes.util.find_library("c") or None)
    if not hasattr(libc, "mallinfo2"):
        pytest.skip("glibc < 2.33 has no mallinfo2")

    class MallInfo2(ctypes.Structure):
        _fields_ = [(n, ctypes.c_size_t) for n in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks",
                                                    "fsmblks", "uordblks", "fordblks", "keepcost")]

    libc.mallinfo2.restype = MallInfo2
    libc.malloc.restype, libc.malloc.argtypes = ctypes.c_void_p, [ctypes.c_size_t]
    libc.free.argtypes = [ctypes.c_void_p]
    # more than the heap's free bytes together: a free hole of 64 MiB below a live block (a solve's freed factors)
    # survives malloc_trim and served the block whatever the settings (the test failed after others, session 64)
    size = max(64 << 20, libc.mallinfo2().fordblks + (1 << 20))
    before = libc.mallinfo2().hblkhd
    p = libc.malloc(size)
    try:
        assert p
        return libc.mallinfo2().hblkhd > before
    finally:
        libc.free(p)


def test_keep_freed_memory_serves_large_blocks_from_the_heap():
    """After keep_freed_memory() glibc serves a 64 MiB block from the heap, not from a fresh mmap."""
    with H.freed_memory_kept():
        assert H.keep_freed_memory() and not _mmaps_64_mib()


def test_solve_gives_the_allocator_back():
    """solve() keeps freed memory only while it runs: afterwards glibc serves a 64 MiB block by mmap again (and frees
    it to the system). A solve through the API left the setting on, and a program's 512 MB array deleted after it
    stayed resident. Nested blocks (the implicit Euler start's solve inside an FESD solve) undo it after the last."""
    H.keep_freed_memory()  # as a process that ran an earlier solve, or a benchmark, had left it
    with H.freed_memory_kept():
        with H.freed_memory_kept():
            pass
        assert not _mmaps_64_mib()
    assert _mmaps_64_mib()
    H.keep_freed_memory()
    H.solve(build_problem(load_robot("robots/point_mass.xml"), hop_task(N=6)))
    assert _mmaps_64_mib()


@pytest.mark.parametrize("mode", list(H.Regularization))
def test_shared_derivatives_are_the_derivatives_of_each_ipopts_own_nlp(mode):
    """Every IPOPT of a solve gets its gradient, Jacobian and Lagrangian Hessian from one derivation of the
    unscaled NLP (_Solvers.derivatives): for the unscaled NLP, the scaled one (xs = x / D) and the
    projection (distance to x_ref in xs, no probe variable) they equal, value and sparsity, what CasADi
    derives from that IPOPT's own NLP, with and without the Regularization.FROM_LAST probe."""
    prob = build_problem(load_robot("robots/point_mass.xml"), hop_task(N=8))
    rng = np.random.default_rng(1)
    x = prob.x0 + rng.normal(scale=2.0, size=prob.nx)
    solvers = H._Solvers(prob, H.SolveOptions(regularization=mode))
    solvers.set_scale(H.variable_scale(prob, 30.0 * x))
    D = solvers.scale
    lam_g = rng.normal(size=prob.g.numel())
    for scaled, projection in ((False, False), (True, False), (True, True)):
        nlp = solvers.scaled_nlp if scaled else solvers.nlp
        xv = np.concatenate([x / D if scaled else x, np.zeros(solvers.n_probe)])
        p = prob.params(1e3, 1.0)
        if projection:
            x_ref = ca.SX.sym("x_ref", prob.nx)
            dist = nlp["x"][: prob.nx] - x_ref
            nlp = {"x": nlp["x"][: prob.nx], "p": ca.vertcat(x_ref, nlp["p"]), "f": ca.dot(dist, dist), "g": nlp["g"]}
            xv, p = xv[: prob.nx], np.concatenate([xv[: prob.nx] + 0.1, p])
        own = ca.Function("own", [nlp["x"], nlp["p"]], [nlp["f"], nlp["g"]], ["x", "p"], ["f", "g"])
        ref = {"grad_f": own.factory("a", ["x", "p"], ["f", "grad:f:x"]), "jac_g": own.factory("b", ["x", "p"], ["g", "jac:g:x"]),
               "hess_lag": own.factory("c", ["x", "p", "lam:f", "lam:g"], ["triu:hess:gamma:x:x"], {"gamma": ["f", "g"]})}
        shared = solvers.derivatives(scaled, projection)
        for name, args in (("grad_f", (xv, p)), ("jac_g", (xv, p)), ("hess_lag", (xv, p, 0.7, lam_g))):
            got, want = shared[name].call(list(args)), ref[name].call(list(args))
            assert shared[name].name_out() == ref[name].name_out()
            for a, b in zip(got, want):
                assert a.sparsity() == b.sparsity(), (scaled, projection, name)
                np.testing.assert_allclose(np.asarray(ca.densify(a)), np.asarray(ca.densify(b)), rtol=SCALED_NLP_TOL,
                                           atol=SCALED_NLP_TOL, err_msg=f"{name} scaled={scaled} projection={projection}")


@pytest.mark.parametrize("derivation", list(H.Derivation))
def test_derivation_routes_the_homotopy_and_the_replan(derivation):
    """SolveOptions.derivation picks the homotopy NLPs' derivatives: WHOLE_GRAPH CasADi's over the whole SX graph
    (SX Functions), STEPWISE planner.derivatives' mapped ones (MX); the held schedule and the projection take
    whatever exists, and with nothing derived yet (a replan) the step-by-step ones."""
    prob = build_problem(load_robot("robots/point_mass.xml"), hop_task(N=5))
    solvers = H._Solvers(prob, H.SolveOptions(derivation=derivation))
    assert solvers.derivatives()["hess_lag"].is_a("MXFunction")  # nothing derived yet: a replan's held schedule
    homotopy = solvers.derivatives(homotopy=True)["hess_lag"]
    assert homotopy.is_a("MXFunction") == (derivation is H.Derivation.STEPWISE)
    assert solvers.derivatives()["hess_lag"] is homotopy  # the projection and the held schedule reuse them


def test_regularization_from_last_skips_the_unregularized_try():
    """Regularization.FROM_LAST: IPOPT regularizes the Hessian in every iteration after its degeneracy
    test (it starts each factorization from the last delta instead of trying delta = 0 first), while with
    FROM_ZERO some iterations of the same NLP run unregularized; the probe variable stays invisible (x and
    lam_x have the problem's nx entries) and both converge. The projection polish is built without it."""
    prob = build_problem(load_robot("robots/point_mass.xml"), hop_task(N=10))
    regularized = {}
    for mode in H.Regularization:
        solvers = H._Solvers(prob, H.SolveOptions(regularization=mode))
        x, lam_x, _, rec = H._run(prob, solvers, prob.x0, None, None, prob.params(100.0, 1.0), prob.lbx, prob.ubx, "nlp 1")
        assert rec.success and x.shape == lam_x.shape == (prob.nx,)
        sizes = np.asarray(solvers.get(warm=False).stats()["iterations"]["regularization_size"])
        regularized[mode] = sizes[4:] > 0  # the first iterations are IPOPT's degeneracy test
        solvers.set_scale(np.ones(prob.nx))
        assert solvers.projection().size_in(0) == (prob.nx, 1)
    assert regularized[H.Regularization.FROM_LAST].all()
    assert not regularized[H.Regularization.FROM_ZERO].all()
    assert H.SolveOptions(regularization="from_last").regularization is H.Regularization.FROM_LAST  # its value too
    with pytest.raises(InputError, match="regularization"):
        H.SolveOptions(regularization="last")


HOP_VX_BOUND = 1.0  # [m/s] below the unbounded hop's top speed (1.51 m/s), so the bound must act
BOUND_TOL = 1e-6  # [m/s] IPOPT's constraint tolerance is 1e-8; the polish ends within it
BOUND_ACTIVE = 1e-3  # [m/s] the bounded hop's top speed is this close to the bound (measured 6.5e-8 below)


def test_velocity_bound_caps_the_hop_and_is_active(hop):
    """plan.velocity_bounds on x: the hop's speed stays <= 1 m/s at every node and reaches it (the
    unbounded hop flies faster), and the plan still converges to the target."""
    from planner.task import VelocityBound

    prob, free, _ = hop
    assert free.extra["_x"][prob.var_blocks["y"]][:, 2].max() > HOP_VX_BOUND + 0.1
    task = hop_task(N=40)
    task = dataclasses.replace(task, plan=dataclasses.replace(task.plan, velocity_bounds=(VelocityBound(("x",), upper=HOP_VX_BOUND),)))
    bounded = build_problem(load_robot("robots/point_mass.xml"), task)
    res = H.solve(bounded)
    assert res.stats.converged and res.terminal_error <= TERMINAL_TOL
    vx = res.extra["_x"][bounded.var_blocks["y"]][:, 2]
    assert HOP_VX_BOUND - BOUND_ACTIVE <= vx.max() <= HOP_VX_BOUND + BOUND_TOL


# A replan from the plan of a nearby task keeps its contact sequence and only moves it: measured 79
# iterations against the hint-free hop's 620 (and 378 for the moved task itself). A third is a margin
# against round-off in the path, still far below any hint-free solve of these tasks.
REPLAN_SHARE = 1 / 3
REPLAN_TARGET_X = 0.55  # [m] the hop's target moved by 5 cm
CAPLER_TAP = 0.01  # an added impact's impulse against the start's largest: Capler's taps were 0.003-0.008


def _an_impact_added(monkeypatch, moved, share: float = 1.0):
    """Every point but moved's start (the point the schedule is read from) reads as having one impact more, its
    impulse share x the start's one impact's."""
    start = H.ungate(moved, moved.x0) if "gates" in moved.notes else moved.x0
    monkeypatch.setattr(H, "_impacts", lambda problem, x, options: [("point", 38, 39, 2.0)] + ([] if np.array_equal(x, start) else [("point", 30, 31, 2.0 * share)]))


def _moved_hop(prob):
    """The hop's problem with its target at REPLAN_TARGET_X (same grid and options)."""
    task = dataclasses.replace(prob.task, plan=dataclasses.replace(prob.task.plan, target_q=(REPLAN_TARGET_X, 0.0)))
    return build_problem(prob.robot, task)


def test_replan_from_a_nearby_plan_converges_in_a_fraction_of_the_iterations(hop):
    """The hop's plan starts the same hop to x = 0.55 m (same signature: only the target changed) with
    replan_options: one NLP at REPLAN_RHO and the polish converge to a complementary plan at the new
    target, in fewer than REPLAN_SHARE of the hint-free solve's iterations. A problem on another grid
    has another signature."""
    prob, res, _ = hop
    moved = _moved_hop(prob)
    assert moved.signature == prob.signature
    assert build_problem(prob.robot, hop_task(N=20)).signature != prob.signature
    warm = H.solve(dataclasses.replace(moved, x0=res.extra["_x"]), H.replan_options())
    assert warm.stats.converged and warm.polished, warm.stats.message
    assert [r.rho for r in warm.nlps if r.label.startswith("homotopy")] == [H.REPLAN_RHO]
    assert warm.stats.complementarity_residual <= COMP_TOL and warm.terminal_error <= TERMINAL_TOL
    assert warm.trajectory.q[-1, 0] == pytest.approx(REPLAN_TARGET_X, abs=TERMINAL_TOL)
    assert warm.stats.ipopt_iterations < REPLAN_SHARE * res.stats.ipopt_iterations


def test_reoptimize_makes_the_polished_plan_the_cheapest_on_its_schedule(hop, monkeypatch):
    """The hop's default solve ends with the "reoptimize" NLP (the task's cost with the polished plan's
    contact schedule held): the plan it returns is exactly complementary, at the target, and its NLP
    objective is no larger than the polished plan's (SolveOptions(reoptimize=False)). A re-optimized
    point that is not cheaper is not taken: the polished plan is returned as without the stage."""
    prob, res, _ = hop
    plain = H.solve(prob, H.SolveOptions(reoptimize=False))
    assert [r.label for r in plain.nlps][-1] == "polish" and plain.stats.message == "ok (active-set polished)"
    assert [r.label for r in res.nlps][-2:] == ["polish", "reoptimize"]
    f = ca.Function("f", [prob.x, prob.p], [prob.f])
    cost = {run: float(f(run.extra["_x"], prob.params(0.0, 1.0))) for run in (res, plain)}
    assert res.stats.converged and res.stats.complementarity_residual == 0.0 and res.terminal_error <= TERMINAL_TOL
    assert cost[res] <= cost[plain]
    if res.stats.message.endswith("re-optimized on its contact schedule)"):
        assert cost[res] < cost[plain]
    else:
        np.testing.assert_array_equal(res.extra["_x"], plain.extra["_x"])
    def no_cheaper(problem, solvers, options, x0, records, progress, label, refuse=None, failed_note=""):
        return None if refuse(x0, x0) else x0  # the polished plan itself: refused as no cheaper

    with monkeypatch.context() as patch:
        patch.setattr(H, "_held", no_cheaper)
        kept = H.solve(prob, H.SolveOptions())
    assert kept.stats.message == "ok (active-set polished)"
    np.testing.assert_array_equal(kept.extra["_x"], plain.extra["_x"])
    # a re-optimization that fails says on its row that the polished plan is kept (it read as the plan's source)
    real = H._accepted
    monkeypatch.setattr(H, "_accepted", lambda problem, options, x, rec: rec.label != "reoptimize" and real(
        problem, options, x, rec))
    failed = H.solve(prob, H.SolveOptions())
    assert failed.nlps[-1].label == "reoptimize" and failed.nlps[-1].note == "not taken: the polished plan is kept"
    assert failed.stats.converged and failed.stats.message == "ok (active-set polished)"


def test_keep_schedule_moves_the_plan_with_its_impacts_on_their_steps(hop, monkeypatch):
    """keep_schedule from the hop's plan for the hop to x = 0.55 m: the one "schedule" NLP (the start's
    contact schedule held) is accepted: converged, exactly complementary, at the new target, with the
    start's impacts on the same steps, in fewer iterations than the penalty replan. When it is not
    accepted (IPOPT stopped after one iteration, or the plan has an impact the start has not) the penalty replan runs
    from the same start and converges as without it."""
    prob, res, _ = hop
    moved = dataclasses.replace(_moved_hop(prob), x0=res.extra["_x"])
    options = dataclasses.replace(H.replan_options(), keep_schedule=True)
    held = H.solve(moved, options)
    assert [r.label for r in held.nlps] == ["schedule"] and held.stats.converged and held.polished, held.stats.message
    assert held.stats.complementarity_residual == 0.0 and held.terminal_error <= TERMINAL_TOL
    assert [i[:3] for i in H._impacts(moved, held.extra["_x"], options)] == [i[:3] for i in H._impacts(prob, res.extra["_x"], options)]
    assert held.stats.ipopt_iterations < H.solve(moved, H.replan_options()).stats.ipopt_iterations
    capped = H.solve(moved, dataclasses.replace(options, schedule_max_iter=1))
    _an_impact_added(monkeypatch, moved)
    moved_impacts = H.solve(moved, options)
    for run in (capped, moved_impacts):
        assert run.nlps[0].label == "schedule" and run.nlps[1].label == "homotopy 1"
        assert run.stats.converged and run.stats.message.startswith("ok (active-set polished")


@pytest.mark.parametrize("share, accepted", [(CAPLER_TAP, True), (TAP_SHARE, False)])
def test_a_tap_does_not_refuse_the_held_schedule(hop, monkeypatch, share, accepted):
    """A held-schedule point whose one impact more than the start has an impulse below result.TAP_SHARE of the start's
    largest (a tap: Capler's were 0.3-0.8 %) is accepted as if it had none (the one "schedule" NLP); one at
    TAP_SHARE is a new impact and refused (the schedule only: not converged), its record's note saying so."""
    prob, res, _ = hop
    moved = dataclasses.replace(_moved_hop(prob), x0=res.extra["_x"])
    _an_impact_added(monkeypatch, moved, share)
    run = H.solve(moved, dataclasses.replace(H.replan_options(), keep_schedule=True, schedule_only=True))
    assert [r.label for r in run.nlps] == ["schedule"] and run.stats.converged is accepted
    # a refusal says why in its record (IPOPT's success stood alone, with no reason for the walk after it)
    assert run.nlps[0].success and (run.nlps[0].note == "") is accepted
    assert accepted or "set aside: it adds 1 impact(s) the start does not have" in run.report()


def test_schedule_new_impacts_lifts_only_the_new_impact_refusal(hop, monkeypatch):
    """With schedule_new_impacts the held-schedule point that has an impact the start has not is accepted (the one
    "schedule" NLP, converged, exactly complementary, at the target) where without it the penalty replan runs; a
    point IPOPT did not converge to (one iteration) is still refused. The option needs keep_schedule."""
    prob, res, _ = hop
    moved = dataclasses.replace(_moved_hop(prob), x0=res.extra["_x"])
    options = dataclasses.replace(H.replan_options(), keep_schedule=True, schedule_only=True)
    _an_impact_added(monkeypatch, moved)
    assert not H.solve(moved, options).stats.converged
    tapped = H.solve(moved, dataclasses.replace(options, schedule_new_impacts=True))
    assert [r.label for r in tapped.nlps] == ["schedule"] and tapped.stats.converged, tapped.stats.message
    assert tapped.stats.complementarity_residual == 0.0 and tapped.terminal_error <= TERMINAL_TOL
    assert tapped.trajectory.q[-1, 0] == pytest.approx(REPLAN_TARGET_X, abs=TERMINAL_TOL)
    capped = H.solve(moved, dataclasses.replace(options, schedule_new_impacts=True, schedule_max_iter=1))
    assert not capped.stats.converged
    with pytest.raises(InputError, match="schedule_new_impacts"):
        H.SolveOptions(schedule_new_impacts=True)


def test_rho_f_schedule_weighs_the_regularizer_in_the_homotopy_only():
    """SolveOptions.rho_f_schedule multiplies the task's rho_f in the homotopy's NLPs (the last factor repeats) and in
    no other NLP: on the hop with factor 10, every homotopy NLP's objective at its own point is the task's objective
    there plus 9 times the selectors' regularizer, while the polish's and the re-optimization's are the task's (rho 0,
    factor 1)."""
    robot = load_robot("robots/point_mass.xml")
    prob = build_problem(robot, hop_task(N=20))
    seen = []
    real_run = H._run

    def spy(problem, solvers, x0, lam_x, lam_g, p, *args, **kwargs):
        x, lx, lg, rec = real_run(problem, solvers, x0, lam_x, lam_g, p, *args, **kwargs)
        seen.append((rec.label, np.asarray(p, float)[-problem.p.numel():], x, rec.objective))
        return x, lx, lg, rec

    H._run = spy
    try:
        res = H.solve(prob, H.SolveOptions(rho_f_schedule=(10.0,)))
    finally:
        H._run = real_run
    assert res.stats.converged
    f, sel = H._nlp_fn(prob, "f"), prob.objective_parts["selectors"]
    homotopy = [(p, x, obj) for label, p, x, obj in seen if label.startswith("homotopy")]
    assert len(homotopy) >= 2 and all(p[-1] == 10.0 for p, _, _ in homotopy)
    for p, x, obj in homotopy:
        task_p = p.copy()
        task_p[-1] = 1.0
        assert obj == pytest.approx(float(f(x, task_p)) + 9.0 * float(sel(x, task_p)), rel=1e-9, abs=1e-9)
    assert all(p[-1] == 1.0 for label, p, _, _ in seen if not label.startswith("homotopy"))


@pytest.mark.parametrize("weight, what", [
    (1e308, "the objective's Hessian (at "),  # overflows the Hessian built here too
    (3e307, "IPOPT's own derivatives"),  # only IPOPT's Hessian of the Lagrangian, at its pushed start, is NaN
])
def test_a_homotopy_nlp_not_finite_at_its_start_stops_the_solve_naming_what(monkeypatch, weight, what):
    """The first NLP, which IPOPT stops at its start with Invalid_Number_Detected because its functions are not finite
    there, stops the solve with an InputError that names what is not finite and the NLP's weights: rho_f_schedule
    [1e308] (finite and > 0, so accepted) overflows the objective's Hessian, and the solve ran 15 more NLPs and a retry
    on inf and NaN (100 s, session 70's tester) before failing "out of reach". No later NLP is started."""
    prob = build_problem(load_robot("robots/point_mass.xml"), hop_task(N=5))
    labels, real_run = [], H._run

    def spy(problem, solvers, x0, lam_x, lam_g, p, lbx, ubx, label, *args, **kwargs):
        labels.append(label)
        return real_run(problem, solvers, x0, lam_x, lam_g, p, lbx, ubx, label, *args, **kwargs)

    monkeypatch.setattr(H, "_run", spy)
    with pytest.raises(InputError) as raised:
        H.solve(prob, H.SolveOptions(rho_f_schedule=(weight,)))
    message = str(raised.value)
    assert message.startswith("homotopy 1's NLP is not finite at its start: " + what)
    assert "Invalid_Number_Detected" in message and f"rho_f_schedule {weight:g}" in message
    assert labels == ["homotopy 1"]


def test_an_nlp_that_meets_an_invalid_number_after_its_start_goes_on(monkeypatch):
    """Only IPOPT's stop at the task's start refuses the solve: an NLP that met an invalid number after some
    iterations, or a later NLP (it starts at an earlier one's iterate), is a failed NLP like any other, and the
    homotopy goes on to its next NLP and returns a PlanResult."""
    prob = build_problem(load_robot("robots/point_mass.xml"), hop_task(N=5))
    labels, real_run = [], H._run

    def invalid(problem, solvers, x0, lam_x, lam_g, p, lbx, ubx, label, *args, **kwargs):
        labels.append(label)
        out = real_run(problem, solvers, x0, lam_x, lam_g, p, lbx, ubx, label, *args, **kwargs)
        if label in ("homotopy 1", "homotopy 2"):  # (1 after 3 iterations, 2 at its start)
            out = (*out[:3], dataclasses.replace(out[3], status="Invalid_Number_Detected", success=False,
                                                 iterations=3 if label == "homotopy 1" else 0))
        return out

    monkeypatch.setattr(H, "_run", invalid)
    result = H.solve(prob, H.SolveOptions(retry_terminal_weight=None))
    assert labels[:3] == ["homotopy 1", "homotopy 2", "homotopy 3"]
    assert [r.status for r in result.nlps[:2]] == ["Invalid_Number_Detected"] * 2


def test_a_failed_plan_with_physical_time_names_it_as_a_cause():
    """A failed plan of a task with horizon.physical_time says that a T below what the motion needs makes the target
    unreachable (physical_time = 1e-6 s failed after 35 s blaming only control bounds, holes and joint limits, session
    70's tester); a failed plan without the key, or with T = tau_f, does not mention it."""
    task = hop_task(N=10)
    short = dataclasses.replace(task, horizon=dataclasses.replace(task.horizon, physical_time=1e-6))
    options = H.SolveOptions(max_iter=2, polish_after_failure=False, retry_terminal_weight=None)
    robot = load_robot(POINT_MASS_XML)
    failed = H.solve(build_problem(robot, short), options)
    assert not failed.stats.converged
    assert ("; horizon.physical_time T = 1e-06 s may be below the time the motion needs, which makes the target "
            "unreachable: the speed of time s >= 1 only speeds the clock up, so a T below tau_f = 1 s is met only by "
            "frozen time (docs/tasks.md, physical_time)") in failed.stats.message
    plain = H.solve(build_problem(robot, task), options)
    assert not plain.stats.converged and "physical_time" not in plain.stats.message
    # T = tau_f, the paper's use, is no such cause
    paper = dataclasses.replace(task, horizon=dataclasses.replace(task.horizon, physical_time=task.horizon.tau_f))
    timed = H.solve(build_problem(robot, paper), options)
    assert not timed.stats.converged and "physical_time" not in timed.stats.message


def test_a_bound_broken_within_ipopts_relaxation_is_said_so(hop):
    """IPOPT relaxes each bound by 1e-8 of its (scaled) variable: a multiplier scaled by D = 1e5 may end at -1e-3 in
    x. _within_relaxation tells that from a real violation (the failed solve's message then says so): the same
    -1e-3 with D = 1 is beyond the relaxation, and so is -2e-3 with D = 1e5."""
    prob = hop[0]
    i = int(np.flatnonzero(prob.lbx == 0.0)[0])  # a variable bounded below by 0 (a multiplier or a selector)
    x = np.clip(prob.x0.copy(), prob.lbx, prob.ubx)
    relaxed = np.full(prob.nx, 1e-8)
    x[i] = -1e-3
    assert not H._within_relaxation(prob, x, relaxed, tol=1e-6)
    relaxed[i] = 1e-8 * 1e5
    assert H._within_relaxation(prob, x, relaxed, tol=1e-6)
    x[i] = -2e-3
    assert not H._within_relaxation(prob, x, relaxed, tol=1e-6)


def test_schedules_the_problem_cannot_use_are_refused():
    """an_schedule and at_schedule scale parameters only a problem built with aux_continuation has, and l1_schedule
    adds to Penalty.LINF's slack: given to another problem they are InputErrors naming the option (they were
    silently ignored, the default solve's exact iterations)."""
    from planner.problem import Penalty, ProblemOptions

    robot = load_robot("robots/point_mass.xml")
    plain = build_problem(robot, hop_task(N=3))
    for options in (H.SolveOptions(an_schedule=(0.1, 1.0)), H.SolveOptions(at_schedule=(0.5,))):
        with pytest.raises(InputError, match=r"_schedule needs a problem built with ProblemOptions\(aux_continuation=True\)"):
            H.solve(plain, options)
    with pytest.raises(InputError, match="l1_schedule adds an l1 sum to Penalty.LINF's slack; the problem's penalty is l1"):
        H.solve(build_problem(robot, hop_task(N=3), ProblemOptions(penalty=Penalty.L1)), H.SolveOptions(l1_schedule=(1.0,)))
    with pytest.raises(InputError, match="an_schedule needs"):  # the probes build the homotopy's NLPs without solve
        H.homotopy_nlp(plain, H.SolveOptions(an_schedule=(0.1,)), 0)


def test_functions_of_a_point_refuse_a_point_of_another_size():
    """Problem.split, complementarity_residual and the homotopy's functions of x (constraint_violation, terminal_error,
    ungate, active_set_bounds, variable_scale), and solve with such an x0, refuse an x of another size with an
    InputError naming nx (CasADi's shape error, IndexError or a silently ignored tail before), and an x that holds no
    doubles too (strings, complex numbers, None, an int of 400 digits); Problem.params refuses a parameter that is not
    a number (a string was numpy's ValueError, True read as 1); homotopy_nlp refuses an NLP index outside its homotopy
    (-1 gave the last NLP, 99 an IndexError) and takes a numpy int (refused as "not allowed")."""
    prob = build_problem(load_robot("robots/point_mass.xml"), hop_task(N=3))
    wrong = np.zeros(prob.nx + 10)
    calls = [prob.split, prob.complementarity_residual, lambda x: H.constraint_violation(prob, x),
             lambda x: H.terminal_error(prob, x), lambda x: H.ungate(prob, x), lambda x: H.active_set_bounds(prob, x),
             lambda x: H.variable_scale(prob, x), lambda x: H.solve(dataclasses.replace(prob, x0=x))]
    for call in calls:
        with pytest.raises(InputError, match=rf"a point of this problem has nx = {prob.nx} entries, got {prob.nx + 10}"):
            call(wrong)
    # not numbers: numpy's ValueError before; an int of 400 digits an OverflowError, complex numbers and strings
    # solved (the imaginary part dropped, "1.0" parsed), None a point of "1 entries"
    for bad, got in ((["a"] * prob.nx, "strings"), ([10**400] * prob.nx, "an integer beyond a double's range"),
                     (None, "None"), ([0.0] * prob.nx + [object()], "[0.0"),
                     ([None] + [0.0] * (prob.nx - 1), "None"),  # (a None inside was nan)
                     ([[0.0] * 2, [0.0]], "sequences of different lengths")):
        for call in calls[:2]:
            with pytest.raises(InputError, match=rf"a point of this problem \({prob.nx} numbers\) must hold numbers a "
                                                 rf"double can hold, got {re.escape(got)}"):
                call(bad)
    for call in calls:
        with pytest.raises(InputError, match=r"a point of this problem \(\d+ numbers\) must hold real numbers, got "
                                             "complex"):
            call(prob.x0 + 1j)
    with pytest.raises(InputError, match="Problem.params' rho must be a number, got str 'a'"):
        prob.params("a")
    with pytest.raises(InputError, match="Problem.params' rho_f_scale must be a number, got bool True"):
        prob.params(1.0, rho_f_scale=True)
    assert prob.params(np.float64(3.0), 2)[:2].tolist() == [3.0, 2.0]
    for bad in (float("nan"), -5.0, float("inf")):  # a nan or negative penalty was solved
        with pytest.raises(InputError, match=r"Problem.params' rho must be finite and >= 0"):
            prob.params(bad)
    for i in (-1, 99, True):  # True ran NLP 2
        with pytest.raises(InputError, match=rf"homotopy_nlp's i = {i} is not allowed"):
            H.homotopy_nlp(prob, H.SolveOptions(), i)
    assert H.homotopy_nlp(prob, H.SolveOptions(), np.int64(1)).label == H.homotopy_nlp(prob, H.SolveOptions(), 1).label


def test_a_schedule_of_more_than_a_hundred_nlps_is_refused():
    """rho_max continues the task's geometric schedule, at most planner.task.MAX_NLPS = 100 NLPs after those below
    rho_min are dropped: kappa = 1.0001 from rho0 = 1 to rho_max = 1e4 scheduled 92109 NLPs (a plan of days) and is an
    InputError naming the cause, counted before the penalties are listed; the task's own n_nlp = 101 is a TaskError, an
    explicit rho_schedule of 101 penalties an InputError; a schedule of the shipped tasks' kind is unchanged."""
    from planner.errors import TaskError
    from planner.task import Homotopy

    with pytest.raises(InputError, match=r"rho_max = None, 10000.0 .* kappa = 1.0001 schedule about 9.21e\+04 NLPs, more than 100"):
        H.task_rho_schedule(Homotopy(rho0=1.0, kappa=1.0001, n_nlp=5), rho_max=1e4)
    # counted after the NLPs below rho_min are dropped: 95 are solved here (the first cap refused it)
    assert len(H.task_rho_schedule(Homotopy(rho0=1.0, kappa=1.05, n_nlp=5), rho_min=1e4, rho_max=1e6)) == 95
    with pytest.raises(InputError, match=r"more than 100"):  # rho0 = 1e-300: 4.6e7 penalties listed below rho_min
        H.task_rho_schedule(Homotopy(rho0=1e-300, kappa=1.0000001, n_nlp=1), rho_min=100.0, rho_max=1e4)
    with pytest.raises(InputError, match=r"rho_schedule = .* at most 100 penalties"):
        H.SolveOptions(rho_schedule=(1.0,) * 101)
    with pytest.raises(TaskError, match=r"plan.homotopy.n_nlp = 101 .* in \[1, 100\]"):
        Homotopy(n_nlp=101)
    assert H.task_rho_schedule(Homotopy(rho0=1.0, kappa=10.0, n_nlp=5), 100.0, 1e7) == [100.0, 1000.0, 1e4, 1e5, 1e6, 1e7]
    exactly = H.task_rho_schedule(Homotopy(rho0=1.0, kappa=2.0, n_nlp=5), rho_max=2.0**99)  # 2^0 .. 2^99: 100 NLPs
    assert len(exactly) == 100 and exactly[-1] == 2.0**99


def test_a_plans_last_landing_keeps_its_post_impact_energy():
    """A plan's impacts all have their kinetic energy after the impact: the terminal rows finish the last one, so the
    simulation's rule for an impact still frozen at the horizon's end (nan) does not apply (the point-mass hop's
    landing, and the biped's heel strike at tau_f, had read null)."""
    from test_problem import hop_task

    result = H.solve(build_problem(load_robot("point_mass"), hop_task(N=20)), H.SolveOptions())
    assert result.stats.converged and result.trajectory.impacts
    assert all(np.isfinite(i.kinetic_energy_post) for i in result.trajectory.impacts)


def test_an_edited_terminal_row_is_met_anywhere_in_its_range():
    """terminal_error is the terminal rows' distance outside [lbg, ubg], not |g - lbg|: a hop whose final x-velocity
    row is freed (lbg = -inf, ubg = inf) converges (it ended "NOT converged ... terminal error inf", the polish
    refused), a range around the plan's end reads 0 and a range beside it its distance."""
    prob = build_problem(load_robot("robots/point_mass.xml"), hop_task(N=10))
    rows = prob.g_blocks["terminal"].ravel()  # q_x, q_z, v_x, v_z
    prob.lbg[rows[2]], prob.ubg[rows[2]] = -np.inf, np.inf
    res = H.solve(prob)
    assert res.stats.converged and res.terminal_error <= TERMINAL_TOL, res.stats.message
    x = res.extra["_x"]
    prob.lbg[rows[0]], prob.ubg[rows[0]] = 0.0, 0.6  # the plan ends at x = 0.5
    assert H.terminal_error(prob, x) <= TERMINAL_TOL
    prob.lbg[rows[0]], prob.ubg[rows[0]] = 0.7, 0.8
    assert H.terminal_error(prob, x) == pytest.approx(0.2, abs=TERMINAL_TOL)


def test_bounds_and_start_as_any_sequence_are_solved_as_float_vectors():
    """A Problem's x0, lbx/ubx and lbg/ubg given as tuples, lists or a (1, n) array are solved as the (n,) float
    vectors they hold (a tuple x0 or lbx was an AttributeError, a (1, nx) lbx an IndexError in the polish after the
    whole homotopy), and a bound that is no numbers is an InputError."""
    prob = build_problem(load_robot("robots/point_mass.xml"), hop_task(N=10))
    odd = dataclasses.replace(prob, x0=tuple(prob.x0), lbx=tuple(prob.lbx), ubx=prob.ubx.reshape(1, -1),
                              lbg=list(prob.lbg))
    res = H.solve(odd)
    assert res.stats.converged and res.polished, res.stats.message
    for name in ("x0", "lbx", "ubx", "lbg", "ubg"):
        assert getattr(odd, name).shape == (getattr(prob, "nx" if name[-1] != "g" else "ng"),)
    with pytest.raises(InputError, match=rf"problem.lbx \({prob.nx} numbers\) must hold numbers a double can hold, got "
                                         "strings"):
        H.solve(dataclasses.replace(prob, lbx=["a"] * prob.nx))
    with pytest.raises(InputError, match=rf"problem.ubg \({prob.ng} numbers\) must hold numbers a double can hold, got "
                                         "an integer beyond"):  # an OverflowError from numpy before
        H.solve(dataclasses.replace(prob, ubg=[10**400] * prob.ng))
    with pytest.raises(InputError, match=r"problem.lbx \(\d+ numbers\) must hold real numbers, got complex"):
        H.solve(dataclasses.replace(prob, lbx=prob.lbx + 1j))  # solved, the imaginary part dropped with a warning


def test_a_converged_report_names_the_nlps_that_stopped_early(hop):
    """A converged plan's report says which homotopy NLPs IPOPT stopped early (their status column shows it; the
    note was in summary.json's message only) and that the verdict is the returned point's; a plan whose NLPs all
    succeeded says nothing of it."""
    _, res, _ = hop
    marked = dataclasses.replace(res, nlps=tuple(dataclasses.replace(r, success=False, status="Restoration_Failed")
                                                 if r.label == "homotopy 2" else r for r in res.nlps))
    assert "  on the way, IPOPT stopped early in homotopy 2; the verdict is the returned point's" in marked.report()
    assert "on the way" not in res.report()


def test_a_never_touching_point_on_its_plane_is_warned_about(tmp_path):
    """A touches = false point that the converged plan puts on its plane (a second site 5 cm below the point mass,
    starting and ending on the ground, the z motor holding it) is warned about, naming it and its nodes: the plan
    exited 0 with no word, while the task said the point never touches (session 56's tester). A plan that keeps it
    off is not."""
    from planner.task import parse_task

    from planner.model import ROBOTS_DIR

    text = (ROBOTS_DIR / "point_mass.xml").read_text()
    site = '<site name="point" pos="0 0 0" size="0.01"/>'
    assert text.count(site) == 1
    path = tmp_path / "two_sites.xml"
    path.write_text(text.replace(site, site + '<site name="low" pos="0 0 -0.05" size="0.01"/>'))
    robot = load_robot(path)

    def plan(z: float):
        task = parse_task({"contacts": [{"point": "point", "mu": 0.5}, {"point": "low", "mu": 0.5, "touches": False}],
                           "initial": {"q": [0.0, z]}, "horizon": {"tau_f": 1.0, "N": 10},
                           "plan": {"target_q": [0.5, z], "u_bound": 30.0}})
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            res = H.solve(build_problem(robot, task), H.SolveOptions())
        assert res.stats.converged, res.stats.message
        return [str(w.message) for w in caught if "touches = false" in str(w.message)]

    (said,) = plan(0.05)  # (it starts and ends there; the plan lifts it in between)
    assert re.match(r"contact 'low' \(touches = false\) lies on its plane at \d+ of 11 nodes \(0, .*10; gap <=",
                    said), said
    assert plan(0.3) == []


def test_a_plan_reports_braking_beyond_the_friction_cone():
    """A point mass sliding at 2 m/s on the ground (mu = 0.5, the default a_t = 600) planned to stop 0.2 m on brakes in
    a step whose clock runs with the tangential auxiliary field, beyond mu times its normal force: the plan's summary
    names the contact in braked_outside_friction_cone and its report says so, as a simulation's do (a plan reported
    only its impacts outside the cone; its friction_cone rows bound the persistent forces, session 58's tester)."""
    from planner.task import parse_task

    task = parse_task({"contacts": [{"point": "point", "mu": 0.5}], "initial": {"q": [0.0, 0.0], "v": [2.0, 0.0]},
                       "horizon": {"tau_f": 1.0, "N": 25}, "plan": {"target_q": [0.2, 0.0], "u_bound": 30.0}})
    result = H.solve(build_problem(load_robot("robots/point_mass.xml"), task), H.SolveOptions())
    assert result.stats.converged, result.stats.message
    (brake,) = result.summary()["braked_outside_friction_cone"]
    # stopping 2 m/s within a few 40 ms steps takes tens of N against mu m g = 4.9 N: far beyond the cone
    assert brake["point"] == "point" and brake["steps"] >= 1 and brake["max_tangential_N"] > 2 * brake["mu_normal_N"]
    assert "point braked by the tangential auxiliary field beyond its friction cone" in result.report()
    hop_free = H.solve(build_problem(load_robot("robots/point_mass.xml"), dataclasses.replace(
        task, initial=dataclasses.replace(task.initial, v=(0.0, 0.0)))), H.SolveOptions())
    assert hop_free.stats.converged and hop_free.summary()["braked_outside_friction_cone"] == []


def test_a_built_problem_solves_with_its_edits():
    """solve honours rows appended to g (with lbg, ubg and a g_blocks entry), a cost term added to f and a bound
    edited in place: the point-mass hop kept under a 5 cm ceiling at every node plans within it, reports the row in
    constraint_violation and names the edits in extra["edited_problem"]; its bounds edited again are honoured, and the
    unedited original solved after its edited variant (they share the notes) has its own rows (a cached g Function of
    the variant's size crashed the polish)."""
    pb = build_problem(load_robot("robots/point_mass.xml"), hop_task(N=20))
    z = pb.x[pb.var_blocks["y"][:, 1]]  # the height at nodes 1 .. N [m]
    rows = np.arange(pb.ng, pb.ng + pb.N)
    edited = dataclasses.replace(pb, g=ca.vertcat(pb.g, z), lbg=np.append(pb.lbg, np.full(pb.N, -np.inf)),
                                 ubg=np.append(pb.ubg, np.full(pb.N, 0.05)), g_blocks={**pb.g_blocks, "ceiling": rows},
                                 f=pb.f + 10.0 * ca.sumsqr(pb.x[pb.var_blocks["u"][:, 0]]))
    res = H.solve(edited)
    assert res.stats.converged, res.stats.message
    assert res.trajectory.q[:, 1].max() <= 0.05 + TERMINAL_TOL
    assert res.constraint_violation["ceiling"] <= TERMINAL_TOL
    assert res.extra["edited_problem"] == ["f", "g", "lbg", "ubg"]
    lower = dataclasses.replace(edited, ubg=np.append(pb.ubg, np.full(pb.N, 0.03)))
    assert H.solve(lower).trajectory.q[:, 1].max() <= 0.03 + TERMINAL_TOL
    plain = H.solve(pb)
    assert plain.stats.converged and "edited_problem" not in plain.extra and "ceiling" not in plain.constraint_violation
    assert plain.trajectory.q[:, 1].max() > 0.05  # (the ceiling binds)


def test_a_contact_holding_force_off_its_plane_is_named():
    """_levitating names each contact whose persistent normal force acts while it is off its plane (a failed plan's
    message then says so: Capler with its knee a contact failed "out of reach" with the knee holding 2.4 N 0.17 m up),
    and nothing for forces on the plane or below LEVITATION_N."""
    from types import SimpleNamespace

    pb = build_problem(load_robot("robots/point_mass.xml"), hop_task(N=4))
    nodes = np.zeros((5, 1))
    nodes[2, 0] = 0.17  # the point 0.17 m up at node 2, the end of step 1
    force = np.zeros((4, 1, 2))
    force[1, 0, 0], force[3, 0, 0] = 2.4, 9.81  # [N] step 1 off the plane, step 3 on it
    assert H._levitating(pb, SimpleNamespace(contact_force=force), nodes) == [
        "point carried up to 2.4 N while 0.17 m off its plane"]
    force[1, 0, 0] = 0.5 * H.LEVITATION_N
    assert H._levitating(pb, SimpleNamespace(contact_force=force), nodes) == []


def test_a_failed_plan_says_which_contact_levitates(monkeypatch):
    """A plan that fails with a contact holding force off its plane says so in its message (one contact: no advice
    to declare it touches = false, which the only contact cannot be); a converged one does not look."""
    pb = build_problem(load_robot("robots/point_mass.xml"), hop_task(N=10))
    monkeypatch.setattr(H, "_levitating", lambda problem, traj, gaps: ["point carried up to 2.4 N while 0.17 m off"])
    failed = H.solve(pb, H.SolveOptions(max_iter=2, polish_after_failure=False))
    assert not failed.stats.converged
    assert "; point carried up to 2.4 N while 0.17 m off: levitating on the contact field" in failed.stats.message
    assert "touches = false" not in failed.stats.message
    assert "levitating" not in H.solve(pb).stats.message


def test_a_levitating_failure_says_the_target_may_be_out_of_reach(monkeypatch):
    """A failed plan held up by the contact field names an unreachable target as a cause beside the local minimum
    (the field's support also meets a target the robot cannot reach: Capler 30 m in 2.5 s blamed only the homotopy,
    session 70's tester)."""
    pb = build_problem(load_robot("robots/point_mass.xml"), hop_task(N=10))
    monkeypatch.setattr(H, "_levitating", lambda problem, traj, gaps: ["point carried up to 2.4 N while 0.17 m off"])
    failed = H.solve(pb, H.SolveOptions(max_iter=2, polish_after_failure=False))
    assert not failed.stats.converged and "Infeasible_Problem_Detected" not in failed.stats.message
    assert "levitating on the contact field, the penalty homotopy's local minimum, or the target may be out of reach" \
        in failed.stats.message


def test_a_failed_plan_of_a_robot_far_from_the_shipped_sizes_points_to_the_docs(robot_variant):
    """A failed plan of a robot whose weight (or plan.u_bound) is far from the shipped robots' says that the
    homotopy's weights are absolute and where docs/tasks.md says how to scale them: a 1000 kg point mass with its
    forces scaled failed "out of reach", and converged once rho_schedule and soft_terminal_weight were scaled along
    (session 70's tester); a failed plan of the 1 kg point mass does not say it."""
    text = POINT_MASS_XML.read_text()
    heavy = robot_variant(text, 'mass="1"', 'mass="1e3"')
    task = dataclasses.replace(hop_task(N=10), plan=dataclasses.replace(hop_task().plan, u_bound=3e4))
    options = H.SolveOptions(max_iter=2, polish_after_failure=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # (a_n = 100 is 0.01 of its weight: build_problem's warning)
        failed = H.solve(build_problem(heavy, task), options)
    assert not failed.stats.converged
    assert ("; the robot's weight m g = 9.81e+03 N and plan.u_bound = 3e+04 N or N m outside [0.1, 1000], the sizes "
            "the homotopy's absolute weights suit") in failed.stats.message
    assert "Robots of other sizes" in failed.stats.message
    assert "Robots of other sizes" not in H.solve(build_problem(load_robot(POINT_MASS_XML), hop_task(N=10)),
                                                  options).stats.message
    # without gravity the robot weighs 0 N: no size to read from it (its failures read "weight m g = 0 N" before)
    weightless = robot_variant(text, 'gravity="0 0 -9.81"', 'gravity="0 0 0"')
    floating = H.solve(build_problem(weightless, hop_task(N=10)), options)
    assert not floating.stats.converged and "Robots of other sizes" not in floating.stats.message


def test_a_plan_that_leaves_the_files_joint_range_says_so(tmp_path):
    """A plan whose NLP bounds on a joint (the task's joint_bounds, or lbx/ubx edited through the API) are wider
    than the robot file's range, and which uses that room, lists the joint in extra["joints_outside_range"] (with its
    unit) and in its report: MuJoCo's replay enforces the file's range, and the validation failed it as a tracking
    error without naming the joint (session 61's tester). A plan inside the range has no such key, nor one resting
    on the file's limit within PLAN_RANGE_TOL (IPOPT's relaxed bounds leave it ~1e-8 past), with or without wider
    bounds on the joint's other side."""
    from planner.task import JointBound

    robot_file = tmp_path / "short_x.xml"
    robot_file.write_text(POINT_MASS_XML.read_text().replace(
        '<joint name="x" type="slide" axis="1 0 0"/>', '<joint name="x" type="slide" axis="1 0 0" range="-1 0.3"/>'))
    task = hop_task(N=10)
    wide = dataclasses.replace(task, plan=dataclasses.replace(task.plan, joint_bounds=(JointBound("x", -1.0, 1.0),)))
    with pytest.warns(UserWarning, match=r"goes beyond the robot file's range \[-1, 0.3\] m"):
        res = H.solve(build_problem(load_robot(robot_file), wide), H.SolveOptions(max_iter=500))
    assert res.stats.converged
    (entry,) = res.extra["joints_outside_range"]
    assert entry["joint"] == "x" and entry["unit"] == "m" and entry["farthest"] == pytest.approx(0.5, abs=1e-6)
    assert "x left the robot file's range [-1, 0.3] m at" in res.report() and "plan.joint_bounds, or" in res.report()
    inside = H.solve(build_problem(load_robot("robots/point_mass.xml"), task), H.SolveOptions(max_iter=500))
    assert inside.stats.converged and "joints_outside_range" not in inside.extra
    # a plan resting on the file's own limit (no joint_bounds) ends ~1e-8 past it by IPOPT's relaxed bounds: no entry
    # (the reviewer's "z left the robot file's range [-1, 0.03] m ..." of a task without joint_bounds)
    low = tmp_path / "low_z.xml"
    low.write_text(POINT_MASS_XML.read_text().replace(
        '<joint name="z" type="slide" axis="0 0 1"/>', '<joint name="z" type="slide" axis="0 0 1" range="-1 0.03"/>'))
    capped = H.solve(build_problem(load_robot(low), task), H.SolveOptions(max_iter=500))
    z = capped.trajectory.q[:, 1]
    assert capped.stats.converged and z.max() > 0.03 - 1e-6 and "joints_outside_range" not in capped.extra, z.max()
    lower = dataclasses.replace(task, plan=dataclasses.replace(task.plan, joint_bounds=(JointBound("z", -2.0, 0.03),)))
    resting = H.solve(build_problem(load_robot(low), lower), H.SolveOptions(max_iter=500))
    assert resting.stats.converged and "joints_outside_range" not in resting.extra, resting.trajectory.q[:, 1].max()
    # the bounds widened through the Python API count as the task's do (regression tester: x to 0.5 unsaid)
    near = dataclasses.replace(task, plan=dataclasses.replace(task.plan, target_q=(0.3, 0.0)))
    edited = build_problem(load_robot(robot_file), near)
    edited.ubx[edited.var_blocks["y"][:, 0]] = 1.0
    edited.lbx[edited.var_blocks["y"][4, 0]] = 0.6  # [m] a via-point past the file's 0.3
    res = H.solve(edited, H.SolveOptions(max_iter=500))
    assert res.stats.converged and [j["joint"] for j in res.extra["joints_outside_range"]] == ["x"]


def test_the_homotopy_never_stops_at_its_holes_relaxed_nlp():
    """early_stop_comp ends the homotopy only at an NLP with the holes at full size (SolveOptions' docstring): with
    no soft-terminal NLP and a threshold every NLP meets, the point-mass hop over a hole still runs on to hole scale 1
    (session 65's mutation testing let it stop at NLP 1, holes relaxed, and every test stayed green)."""
    from planner.task import parse_task

    hole = {"x": 0.25, "z": 0.0, "a": 0.05, "b": 0.05}
    task = parse_task({"contacts": [{"point": "point", "mu": 0.5, "a_n": 200.0, "a_t": 100.0}],
                       "initial": {"q": [0.0, 0.0]}, "horizon": {"tau_f": 1.0, "N": 30},
                       "plan": {"target_q": [0.5, 0.0], "u_bound": 30.0, "holes": [hole]}})
    result = H.solve(build_problem(load_robot(POINT_MASS_XML), task),
                     H.SolveOptions(early_stop_comp=1e3, soft_terminal_nlps=0))
    homotopy = [r for r in result.nlps if r.label.startswith("homotopy")]
    assert homotopy[0].hole_scale < 1.0 and homotopy[-1].hole_scale == 1.0, [(r.label, r.hole_scale) for r in homotopy]


def test_bound_frac_takes_ipopts_whole_range():
    """SolveOptions.bound_frac is IPOPT's bound_frac, whose range is 0 < bound_frac <= 0.5 (IPOPT's option list): 0.5
    is accepted by SolveOptions as by IPOPT (a tiny NLP solves with it), just above it is refused by both, as 0 is."""
    import casadi as ca

    import planner.homotopy as H
    from planner.errors import InputError

    assert H.SolveOptions(bound_frac=0.5).bound_frac == 0.5
    for bad in (0.0, 0.50001):
        with pytest.raises(InputError, match="bound_frac"):
            H.SolveOptions(bound_frac=bad)
    x = ca.SX.sym("x")
    for frac, accepted in ((0.5, True), (0.50001, False)):  # IPOPT, the ground truth
        try:
            s = ca.nlpsol("s", "ipopt", {"x": x, "f": (x - 1) ** 2, "g": x},
                          {"ipopt.bound_frac": frac, "ipopt.print_level": 0, "print_time": 0, "ipopt.sb": "yes"})
            s(x0=0, lbg=0, ubg=2)
            ok = s.stats()["success"]
        except RuntimeError:  # "Invalid options were detected by Ipopt"
            ok = False
        assert ok is accepted


def test_a_one_nlp_homotopy_solves_with_its_holes_at_full_size():
    """holes = relaxed_first relaxes the holes in NLP 1 only when a later NLP enforces them: a homotopy of one NLP (a
    rho_schedule of one penalty) solves that NLP with the task's holes (hole scale 1, the parameter IPOPT gets), else
    the homotopy's point is planned as if the holes were not there; with two NLPs the first is relaxed (session 66's
    mutation testing: the only NLP was solved with the holes relaxed, with every test green)."""
    prob = build_problem(load_robot(POINT_MASS_XML), hop_task(N=3))
    one = H.SolveOptions(rho_schedule=(1e4,), holes=H.HoleSchedule.RELAXED_FIRST)
    assert len(H.homotopy_rhos(prob, one)) == 1
    only = H.homotopy_nlp(prob, one, 0)
    assert only.hole_scale == 1.0 and only.p[1] == 1.0  # (Problem.params' second entry is the hole scale)
    two = dataclasses.replace(one, rho_schedule=(1e3, 1e4))
    assert [H.homotopy_nlp(prob, two, i).p[1] for i in range(2)] == [0.0, 1.0]


def test_the_homotopy_never_stops_at_a_soft_terminal_nlp():
    """early_stop_comp ends the homotopy only at an NLP whose terminal rows are constraints (SolveOptions' docstring):
    with two soft-terminal NLPs, the holes enforced in every NLP and a threshold every NLP meets, the hop runs on to
    NLP 3, the first hard-terminal one, which meets the target (the soft ones end 0.1 and 0.3 m off it) (session 66's
    mutation testing: it stopped at NLP 1, whose terminal is only a penalty, with every test green;
    test_the_homotopy_never_stops_at_its_holes_relaxed_nlp guards the condition's holes half)."""
    prob = build_problem(load_robot(POINT_MASS_XML), hop_task(N=20))
    options = H.SolveOptions(early_stop_comp=1e3, soft_terminal_nlps=2, holes=H.HoleSchedule.ENFORCED,
                             polish=H.Polish.NONE)
    homotopy = [r for r in H.solve(prob, options).nlps if r.label.startswith("homotopy")]
    soft = [H.homotopy_nlp(prob, options, i).soft for i in range(len(homotopy))]
    assert soft == [True, True, False], [(r.label, r.terminal_error) for r in homotopy]
    assert homotopy[-1].success and homotopy[-1].terminal_error <= TERMINAL_TOL


def test_a_polish_not_accepted_leaves_the_verdict_to_the_homotopys_point(hop):
    """When no polish is accepted the plan is the homotopy's last point, and the verdict judges it by that NLP's
    record: a failed polish's record after the homotopy's gives the verdict and message of the same point with no
    polish at all (session 66's mutation testing: the failed polish's record was judged, "IPOPT did not converge in
    polish", failing a good plan, with every test green). The point is the hop's plan (complementary, at its target)."""
    prob, res, _ = hop
    homotopy = [r for r in res.nlps if r.label.startswith("homotopy")]
    failed = dataclasses.replace(next(r for r in res.nlps if r.label == "polish"), success=False,
                                 status="Maximum_Iterations_Exceeded")
    x = res.extra["_x"]
    alone = H._result(prob, H.SolveOptions(), x, homotopy, None, 0.0, {})
    after = H._result(prob, H.SolveOptions(), x, homotopy + [failed], None, 0.0, {})
    assert alone.stats.converged, alone.stats.message
    assert (after.stats.converged, after.stats.message) == (alone.stats.converged, alone.stats.message)


# [m] an error put into one dynamics state of a polish point: far beyond SolveOptions.constraint_tol (1e-6, in x's
# units), while IPOPT's success is judged on its scaled NLP with its own tolerances
DYNAMICS_DEFECT = 1e-3


def test_a_polish_point_that_breaks_a_constraint_is_not_accepted(hop):
    """A polishing NLP's point stands in for the homotopy's only if it keeps the constraints within constraint_tol,
    whatever IPOPT's success says: with a record IPOPT calls solved, the hop's plan is accepted and the same point
    DYNAMICS_DEFECT off one dynamics state (its violation recomputed: beyond constraint_tol) is not, so the next start
    or the homotopy's point is used (session 66's mutation testing: it was accepted on IPOPT's success and terminal
    error alone, and the verdict then failed the plan, with every test green)."""
    prob, res, _ = hop
    options = H.SolveOptions()
    solved = next(r for r in res.nlps if r.label == "polish")
    assert solved.success and solved.terminal_error <= options.terminal_tol
    x = res.extra["_x"]
    off = x.copy()
    off[prob.var_blocks["y"][3, 0]] += DYNAMICS_DEFECT
    assert H.constraint_violation(prob, off)["dynamics"] > options.constraint_tol
    assert H._accepted(prob, options, x, solved) and not H._accepted(prob, options, off, solved)


def test_polish_after_failure_false_skips_the_polish_once_any_homotopy_nlp_stopped_early():
    """polish_after_failure = False polishes only a homotopy whose every NLP IPOPT solved: on the N = 10 hop with
    max_iter 95 NLP 4 stops at the cap while the others succeed, and no polishing NLP runs (session 66's mutation
    testing: one solved NLP was enough to polish, with every test green; the option's one other test has every NLP
    fail). The cap sits midway between NLPs 1-3's 54-59 iterations and NLP 4's 130 (measured), so rounding on another
    machine does not move an NLP across it."""
    prob = build_problem(load_robot(POINT_MASS_XML), hop_task(N=10))
    res = H.solve(prob, H.SolveOptions(max_iter=95, polish_after_failure=False))
    solved = [r.success for r in res.nlps if r.label.startswith("homotopy")]
    assert any(solved) and not all(solved), solved  # (else this is not the mixed case)
    assert all(r.label.startswith("homotopy") for r in res.nlps) and not res.polished, [r.label for r in res.nlps]


# the KKT stationarity at NLP 1's solution: IPOPT's tol is 1e-8 (measured 7e-11 on the N = 6 hop); bound multipliers
# scaled the wrong way leave ~1
STATIONARITY_TOL = 1e-6


def test_a_scaled_warm_start_hands_ipopt_the_multipliers_of_the_scaled_nlp(monkeypatch):
    """WarmStart.PRIMAL_DUAL with VariableScaling.FIRST_NLP: NLP 2 starts from NLP 1's KKT point in the scaled
    variables (xs = x / D, so the bound multipliers are D lam_x): with the x0, lam_x0 and lam_g0 handed to IPOPT the
    scaled NLP's Lagrangian is stationary for NLP 1's parameters, recomputed by CasADi (session 66's mutation testing:
    lam_x was divided by D, IPOPT converged along another path, with every test green). The solver is replaced by
    one that records its arguments: what NLP 2 starts from is all this reads."""
    prob = build_problem(load_robot(POINT_MASS_XML), hop_task(N=6))
    options = H.SolveOptions(warm_start=H.WarmStart.PRIMAL_DUAL, variable_scaling=H.VariableScaling.FIRST_NLP)
    solvers = H._Solvers(prob, options)
    first, second = H.homotopy_nlp(prob, options, 0), H.homotopy_nlp(prob, options, 1)
    x, lam_x, lam_g, rec = H._run(prob, solvers, prob.x0, None, None, first.p, prob.lbx, prob.ubx, first.label,
                                  first.lbg, first.ubg, loose=first.loose)
    assert rec.success, rec.status
    solvers.set_scale(H.variable_scale(prob, x))
    assert solvers.sees_scale(warm=True) and solvers.scale.max() > 1.0
    handed = {}

    class Handed(Exception):
        pass

    def recording(**args):
        handed.update(args)
        raise Handed

    monkeypatch.setattr(solvers, "get", lambda *args, **kwargs: recording)
    with pytest.raises(Handed):
        H._run(prob, solvers, x, lam_x, lam_g, second.p, prob.lbx, prob.ubx, second.label, second.lbg, second.ubg,
               loose=second.loose)
    nlp = solvers.scaled_nlp
    lam = ca.SX.sym("lam", prob.ng)
    grad = ca.Function("grad", [nlp["x"], nlp["p"], lam], [ca.gradient(nlp["f"] + ca.dot(lam, nlp["g"]), nlp["x"])])
    stationarity = np.asarray(grad(handed["x0"], first.p, handed["lam_g0"])).ravel() + handed["lam_x0"]
    assert np.abs(stationarity).max() <= STATIONARITY_TOL


def test_a_failed_hybrid_stage_leaves_the_polish_to_start_from_the_homotopys_point(hop, monkeypatch):
    """polish = hybrid: when the hybrid stage fails, the active-set polish starts from the homotopy's point (its
    active-set start, recomputed by active_set_bounds), not from where the failed stage stopped (session 66's mutation
    testing: the failed stage's point was taken, 9 -> 1742 polish iterations on the hop, with every test green). The
    NLPs are stubbed, every one failing 0.3 off its start: the hop's hybrid stage succeeds, and the polish's start is
    all this reads."""
    prob, res, _ = hop
    x = res.extra["_x"]
    starts = {}

    def failing(problem, solvers, x0, lam_x, lam_g, p, lbx, ubx, label, *args, **kwargs):
        starts[label] = np.array(x0, float)
        rec = dataclasses.replace(res.nlps[-1], label=label, success=False, status="Maximum_Iterations_Exceeded")
        return np.asarray(x0, float) + 0.3, lam_x, lam_g, rec

    monkeypatch.setattr(H, "_run", failing)
    records = []
    no_solvers = H._Solvers(prob, H.SolveOptions())  # (none made: _run is stubbed)
    assert H._polish(prob, no_solvers, H.SolveOptions(polish=H.Polish.HYBRID), x, None, None, records, None,
                     "polish") is None
    assert [r.label for r in records] == ["hybrid", "polish"]
    homotopys = H.ungate(prob, x) if "gates" in prob.notes else x  # (the polish reads the ungated point)
    np.testing.assert_array_equal(starts["polish"], H.active_set_bounds(prob, homotopys)[2])


@pytest.mark.parametrize("held, new", [
    (("point", 8, 10, 1.0), True),  # begins where the start's ends: the spans are half-open, so they share no step
    (("point", 2, 5, 1.0), True),  # ends where the start's begins
    (("point", 12, 14, 1.0), True),  # apart
    (("point", 7, 10, 1.0), False),  # shares the start's last step: the same impact, ending later
    (("other", 5, 8, 1.0), True),  # the same steps at another contact point
    (("point", 8, 10, 0.99 * TAP_SHARE * 2.0), False),  # a tap: below TAP_SHARE of the start's 2 N s
    (("point", 8, 10, TAP_SHARE * 2.0), True),
])
def test_an_impact_is_new_unless_it_shares_a_step_with_one_of_the_starts_or_is_a_tap(hop, monkeypatch, held, new):
    """_new_impacts: an impact of the held schedule's point (steps first .. last + 1, half-open) is new when it shares
    no step with an impact of the start at the same contact point and its impulse is at least TAP_SHARE of the start's
    largest; the start has one impact at steps 5-7 of 2 N s, the held point that one and `held` (session 66's mutation
    testing: an impact beginning at the step after the start's one took it for the same, with every test green)."""
    impacts = {"start": [("point", 5, 8, 2.0)], "held": [("point", 5, 8, 2.0), held]}
    monkeypatch.setattr(H, "_impacts", lambda problem, x, options: impacts[x])
    said = H._new_impacts(hop[0], H.SolveOptions(), "start", "held")
    assert said.startswith("set aside: it adds 1 impact(s)") if new else said == "", said
