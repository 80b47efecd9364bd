"""FESD in the optimal control problem (ProblemOptions.discretization = FESD): the transcription's
blocks, the options it refuses, and the point-mass hop solved with exact switch detection."""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from planner import homotopy as H
from planner.discretization import Discretization, FESDOptions
from planner.errors import InputError
from planner.model import load_robot
from planner.problem import Penalty, ProblemOptions, build_problem, fesd_start_from_implicit_euler

from test_problem import hop_task

G = 9.81  # [m/s^2], robots/point_mass.xml
MASS = 1.0  # [kg]
EVAL_TOL = 1e-12  # the same expression built two ways: rounding only
COMP_TOL = 1e-6  # the verdict's complementarity and terminal thresholds (SolveOptions defaults)
TERMINAL_TOL = 1e-6  # [m, m/s]
# impact time against the parabola integrated in closed form from the take-off state with the
# plan's piecewise-constant controls: IPOPT's bound relaxation leaves the landing boundary ~1e-8 off
IMPACT_TIME_TOL = 1e-6  # [s]


def fesd_options(n_s: int = 2, n_fe: int = 3, **kwargs) -> ProblemOptions:
    return ProblemOptions(discretization=Discretization.FESD, fesd=FESDOptions(n_s=n_s, n_fe=n_fe), **kwargs)


def test_blocks_and_shapes():
    """Stage k owns u_k (nu,), the element lengths h (n_fe,), and per element e and stage j the state
    Y (ny,) and algebraic variables w (nw,); y_{k+1} is the last stage of the last element. The step
    rows are (N, n_fe n_s m) blocks, the element-length row (N, 1), the boundary path constraints
    (N, n_fe m), the per-stage cones (N, n_fe n_s m), the penalty one row per pair (N, pairs per
    step), and the pairs are FESDInterval's cross-complementarity, 2 (n_s + 1) n_s n_sigma per element."""
    robot = load_robot("robots/point_mass.xml")
    N, n_s, n_fe = 4, 2, 3
    prob = build_problem(robot, hop_task(N=N, holes=[{"x": 0.25, "z": 0.0, "a": 0.1, "b": 0.05}]), fesd_options(n_s, n_fe))
    ny, nu, nw, n = prob.system.ny, robot.nu, prob.builder.nw, prob.system.n_sigma
    vb, gb = prob.var_blocks, prob.g_blocks
    assert vb["u"].shape == (N, nu) and vb["h"].shape == (N, n_fe)
    assert vb["Y"].shape == (N, n_fe, n_s, ny) and vb["w"].shape == (N, n_fe, n_s, nw)
    assert vb["sigma"].shape == (N, n_fe, n_s, n)
    np.testing.assert_array_equal(vb["y"], vb["Y"][:, -1, -1])
    assert prob.nx == N * (nu + prob.fesd.nx) + N + 1 == len(prob.var_names) == len(prob.x0)  # + the step slacks and s_c
    assert vb["s_c_step"].shape == (N, 1) and gb["penalty_max"].shape == (N, 1)
    assert gb["element_lengths"].shape == (N, 1)
    assert gb["dynamics"].shape == (N, n_fe * n_s * ny) and gb["stationarity"].shape == (N, n_fe * n_s * n)
    assert gb["holes"].shape == (N, n_fe) and gb["friction_cone"].shape == (N, n_fe * n_s * 2)
    pairs_per_step = n_fe * n_s * 2 * (n_s + 1) * n
    assert len(prob.pairs) == N * pairs_per_step and gb["penalty"].shape == (N, pairs_per_step)
    assert set(prob.objective_parts) == {"control", "selectors", "equilibration", "penalty"}
    assert np.all(prob.lbx[vb["h"]] == 0) and np.allclose(prob.ubx[vb["h"]], prob.h)
    # the hint-free guess: y_0 at every stage, equal lengths, every product zero
    assert np.allclose(prob.x0[vb["Y"]], prob.y0) and np.allclose(prob.x0[vb["h"]], prob.h / n_fe)
    assert prob.complementarity_residual(prob.x0) == pytest.approx(0.0, abs=EVAL_TOL)
    # the pairs are the interval's own: step 1 (whose left boundary is step 0's end) against FESDInterval
    rng = np.random.default_rng(0)
    x = rng.uniform(0.1, 1.0, prob.nx)
    mine = np.asarray(prob.notes["gated_products"](x), float).ravel()[pairs_per_step : 2 * pairs_per_step]
    gates = np.asarray(prob.notes["pair_gates"](x), float).ravel()[pairs_per_step : 2 * pairs_per_step]
    end0 = vb["w"][0, -1, -1]
    lam_prev = ca.vertcat(prob.x[end0[prob.builder.w_blocks["lambda0"]].tolist()], prob.x[end0[prob.builder.w_blocks["lambda1"]].tolist()])
    iv = prob.fesd.build(prob.x[vb["y"][0].tolist()], lambda y: prob.x[vb["u"][1].tolist()], prob.h, lam_prev, tag="_check")
    sub = ca.Function("interval", [iv.x, prob.x], [iv.comp_products()])
    first = vb["u"][1][-1] + 1
    theirs = np.asarray(sub(x[first : first + prob.fesd.nx], x), float).ravel()
    np.testing.assert_allclose(mine, theirs * gates, atol=EVAL_TOL)


@pytest.mark.parametrize("kwargs, key", [({"discretization": "fed"}, "discretization"), ({"fesd": (2, 3)}, "fesd"),
                                         ({"discretization": Discretization.FESD, "clock_weight": 1.0}, "clock_weight")])
def test_invalid_options_raise(kwargs, key):
    """A discretization that is none of the Enum's values, fesd that is not FESDOptions, and FESD with the clock
    weight (not transcribed for FESD) are InputErrors naming the option and the valid values."""
    with pytest.raises(InputError, match=key):
        ProblemOptions(**kwargs)
    with pytest.raises(InputError, match="n_fe"):
        FESDOptions(n_fe=0)


def test_hybrid_polish_is_refused():
    """Polish.HYBRID reads one selector's own multipliers only: with FESD solve refuses it, naming the valid polishes."""
    prob = build_problem(load_robot("robots/point_mass.xml"), hop_task(N=2), fesd_options())
    with pytest.raises(InputError, match="active_set"):
        H.solve(prob, H.SolveOptions(polish=H.Polish.HYBRID))


def test_implicit_euler_default_is_unchanged():
    """The default ProblemOptions still transcribes implicit Euler: no FESD builder, the old blocks."""
    prob = build_problem(load_robot("robots/point_mass.xml"), hop_task(N=3))
    assert prob.fesd is None and prob.options.discretization is Discretization.IMPLICIT_EULER
    assert prob.var_blocks["w"].shape == (3, prob.builder.nw) and "h" not in prob.var_blocks


@pytest.fixture(scope="module")
def hop():
    """The point-mass hop of tests/test_problem.py (no slip: it must hop to x = 0.5 m) with FESD n_s = 2,
    n_fe = 3, solved from the hint-free start with the CLI's FESD schedule (rho up to 1e5, then the polish)."""
    from planner.cli import FESD_RHO_MAX

    prob = build_problem(load_robot("robots/point_mass.xml"), hop_task(N=HOP_N), fesd_options(2, 3))
    res = H.solve(prob, H.SolveOptions(rho_max=FESD_RHO_MAX))
    return prob, res


FLIGHT_BETA = 1 - 1e-3  # an element flies when beta exceeds this at every stage (the barrier leaves it ~1e-8 below 1)
HOP_N = 10  # steps of h = 0.1 s: the landing step holds the touchdown and both jumps' ends (3 elements)
REST_TOL = 1e-6  # [m/s] a velocity at rest: the polish's constraint tolerance (1e-8) times the elements' dynamics


def test_fesd_hop_converges(hop):
    """The FESD OCP of the hop converges: polished, complementarity (own-stage pairs and the gated
    cross-complementarity) <= 1e-6, terminal error <= 1e-6, every constraint kept, one hop to x = 0.5 and no other
    (the plan rests after its landing with beta = 1 on some steps: no hop), landing at its impact's time."""
    prob, res = hop
    assert res.stats.converged, res.stats.message
    assert res.polished
    assert res.stats.complementarity_residual <= COMP_TOL and res.terminal_error <= TERMINAL_TOL
    assert len(res.hops) == 1 and res.hops[0].distance == pytest.approx(0.5, abs=1e-6)
    landing = res.hops[0].landing_time  # the touchdown, not the end of the element after the frozen impact element
    assert any(imp.time == landing for imp in res.trajectory.impacts), [i.time for i in res.trajectory.impacts]


def test_fesd_hop_impact_time_is_exact(hop):
    """The landing is on an element boundary at the analytic touchdown time: the parabola of each
    flight element (constant acceleration u_z/m - g of its step), chained in closed form from the
    plan's take-off state, reaches z = 0 where the plan's impact is, to IMPACT_TIME_TOL."""
    prob, res = hop
    parts = prob.split(res.extra["_x"])
    K = prob.N * prob.fesd.n_fe
    lengths = parts["h"].ravel()
    nodes = np.vstack([parts["Y"][:1], parts["Ys"].reshape(K, prob.fesd.n_s, -1)[:, -1]])
    u = np.repeat(parts["U"], prob.fesd.n_fe, axis=0)
    flight = next(hp for hp in res.hops if hp.distance > 0.1)
    impact = min(res.trajectory.impacts, key=lambda imp: abs(imp.time - flight.landing_time))  # the landing
    tau = np.concatenate([[0.0], np.cumsum(lengths)])
    land = int(np.argmin(np.abs(tau - impact.tau_start)))  # the element boundary where the impact starts
    beta = parts["Ws"].reshape(K, prob.fesd.n_s, -1)[:, :, prob.builder.w_blocks["sigma"]][:, :, 1]
    takeoff = land
    # the flight's elements: beta = 1 at every stage (a stance may hold beta fractional, e.g. 0.95 with the
    # a_n field carrying part of the weight at gap 0; it is no flight)
    while takeoff > 0 and np.all(beta[takeoff - 1] > FLIGHT_BETA):
        takeoff -= 1
    assert land - takeoff >= 2
    z, vz, t = nodes[takeoff, 1], nodes[takeoff, 3], nodes[takeoff, -1]
    for n in range(takeoff, land - 1):  # whole flight elements in closed form
        a = u[n, 1] / MASS - G
        z, vz, t = z + vz * lengths[n] + 0.5 * a * lengths[n] ** 2, vz + a * lengths[n], t + lengths[n]
        assert z > 0
    a = u[land - 1, 1] / MASS - G
    root = (-vz - np.sqrt(vz**2 - 2 * a * z)) / a  # the later root of z + vz s + a s^2 / 2 = 0 (a < 0)
    assert impact.time == pytest.approx(t + root, abs=IMPACT_TIME_TOL)


def test_fesd_impacts_end_in_the_plans_state(hop):
    """An FESD impact's post-impact velocity is the state where its run of frozen elements ends: the stance whose
    element runs the clock at 95 % (the a_n field carrying part of the weight) and the landing both end at rest, so
    no impact gains kinetic energy (v_pre plus the elements' auxiliary increments read +0.94 m/s and +0.32 m/s upward:
    the support over the running part counted, gravity not)."""
    _, res = hop
    assert len(res.trajectory.impacts) == 2
    for imp in res.trajectory.impacts:
        assert not imp.gains_energy, (imp.time, imp.v_pre, imp.v_post)
        np.testing.assert_allclose(imp.v_post, 0.0, atol=REST_TOL)  # the point rests after both (no slip)

def test_physical_time_and_l1_blocks():
    """With horizon.physical_time every FESD step gets a speed of time s_k >= 1 (block "s" (N, 1), in
    every stage's dynamics) and the row t_N = T; Penalty.L1 has no slacks and no penalty rows."""
    import dataclasses

    from planner.task import Horizon

    robot = load_robot("robots/point_mass.xml")
    task = dataclasses.replace(hop_task(N=3), horizon=Horizon(tau_f=1.0, N=3, physical_time=0.8))
    prob = build_problem(robot, task, fesd_options(2, 2))
    assert prob.var_blocks["s"].shape == (3, 1) and np.all(prob.lbx[prob.var_blocks["s"]] == 1)
    rows = prob.g_blocks["physical_time"].ravel()
    assert np.all(prob.lbg[rows] == 0.8) and np.all(prob.ubg[rows] == 0.8)
    dyn = ca.Function("dyn", [prob.x], [ca.jacobian(prob.g[prob.g_blocks["dynamics"][1].tolist()], prob.x[prob.var_blocks["s"][1].tolist()])])
    assert np.any(np.asarray(dyn(prob.x0), float) != 0)  # s_1 scales step 1's stage increments
    l1 = build_problem(robot, hop_task(N=3), fesd_options(2, 2, penalty=Penalty.L1))
    assert "s_c" not in l1.var_blocks and "penalty" not in l1.g_blocks and "s_c_step" not in l1.var_blocks


MAP_TOL = 1e-8  # rows the implicit-Euler plan keeps to IPOPT's tolerance (tol 1e-8) and the mapping copies


def test_implicit_euler_plan_maps_onto_fesd():
    """FESDStart.IMPLICIT_EULER's start (fesd_start_from_implicit_euler) from the solved implicit-Euler hop:
    every step's end state is the implicit-Euler node y_{k+1}, the element lengths are h / n_fe, the
    lifting, terminal and bound rows hold to MAP_TOL, each step's last stage satisfies its dynamics row
    to MAP_TOL (a straight segment's collocation increment is its slope: the implicit-Euler step), every
    pair within a step is as complementary as the implicit-Euler plan (the stages of a step are equal),
    and the only violated pairs pair a multiplier at the previous step's end (the switch implicit Euler
    put inside a step); the l_inf slacks bound the products."""
    robot = load_robot("robots/point_mass.xml")
    task = hop_task(N=HOP_N)
    euler = build_problem(robot, task)
    res = H.solve(euler)
    assert res.stats.converged, res.stats.message
    prob = build_problem(robot, task, fesd_options(2, 3), dynamics=euler.system.dyn)
    x0 = fesd_start_from_implicit_euler(prob, euler, res.extra["_x"])
    vb, gb = prob.var_blocks, prob.g_blocks
    np.testing.assert_array_equal(x0[vb["y"]], euler.split(res.extra["_x"])["Y"][1:])
    np.testing.assert_allclose(x0[vb["h"]], prob.h / 3, rtol=0, atol=EVAL_TOL)
    viol = H.constraint_violation(prob, x0)
    for name in ("lifting", "terminal", "bounds", "element_lengths"):
        assert viol[name] <= MAP_TOL, (name, viol[name])
    g = np.asarray(H._nlp_fn(prob, "g")(x0, prob.params(0.0)), float).ravel()
    ny = prob.system.ny
    assert np.max(np.abs(g[gb["dynamics"][:, -ny:]])) <= MAP_TOL  # the last stage of the last element: the step's end
    prods = np.asarray(prob.notes["gated_products"](x0), float).ravel()
    across = np.array([name.split("*")[0].split("]_")[1].split("_")[0] != name.split("_")[-3] for name in (p.name for p in prob.pairs)])
    assert np.max(np.abs(prods[~across])) <= MAP_TOL
    assert x0[vb["s_c"][0]] >= np.max(prods) and np.all(x0[vb["s_c_step"].ravel()] >= prods.reshape(prob.N, -1).max(axis=1) - EVAL_TOL)
    with pytest.raises(InputError, match="grid"):
        fesd_start_from_implicit_euler(build_problem(robot, hop_task(N=HOP_N + 1), fesd_options(2, 3)), euler, res.extra["_x"])


@pytest.mark.parametrize("kwargs, key", [({"fesd_start": "euler"}, "fesd_start"),
                                         ({"fesd_rho_schedule": ()}, "fesd_rho_schedule"),
                                         ({"fesd_rho_schedule": (1e4, -1.0)}, "fesd_rho_schedule")])
def test_invalid_fesd_start_options_raise(kwargs, key):
    """fesd_start must be one of FESDStart's values, fesd_rho_schedule a non-empty tuple of positive penalties."""
    with pytest.raises(InputError, match=key):
        H.SolveOptions(**kwargs)


def test_active_set_reads_cross_multipliers():
    """The polish's active set (active_set_bounds) compares an FESD selector with every multiplier of its
    element it is paired with, not only its own: a selector at 1 whose own lambda1 is ~0 but whose left
    boundary's lambda1 is 4.2 (the switching function > 0 there: no switch) is held at 1, so that lambda1
    stays free; before, the selector was left free and the cross rule zeroed the 4.2 (Capler N = 50: a
    stationarity row 4.2 off at the polish start). A selector whose element multipliers are all ~0 stays free
    and they are fixed to 0 (the own-stage rule of implicit Euler)."""
    robot = load_robot("robots/point_mass.xml")
    prob = build_problem(robot, hop_task(N=2), fesd_options(1, 3))
    names = [s.name for s in prob.system.switches]
    i = names.index("beta[point]")  # gate 1: its cross pairs are imposed
    sig, l0, l1 = (prob.var_blocks[b] for b in ("sigma", "lambda0", "lambda1"))
    x = prob.x0.copy()
    x[sig[0, 0, 0, i]], x[l0[0, 0, 0, i]], x[l1[0, 0, 0, i]] = 1.0, 0.0, 4.2  # the left boundary of element 1
    x[sig[0, 1, 0, i]], x[l0[0, 1, 0, i]], x[l1[0, 1, 0, i]] = 1.0 - 1e-6, 1e-9, 1e-9  # own lambda1 < 1 - sigma
    x[sig[0, 2, 0, i]], x[l0[0, 2, 0, i]], x[l1[0, 2, 0, i]] = 0.4, 1e-9, 1e-9  # element 2: its multipliers and its left boundary's ~0
    lbx, ubx, xc = H.active_set_bounds(prob, x)
    assert lbx[sig[0, 1, 0, i]] == ubx[sig[0, 1, 0, i]] == 1.0  # held by the left boundary's lambda1 = 4.2
    assert ubx[l1[0, 0, 0, i]] == np.inf and xc[l1[0, 0, 0, i]] == 4.2  # which stays free
    assert (lbx[sig[0, 2, 0, i]], ubx[sig[0, 2, 0, i]]) == (0.0, 1.0)  # interior: free
    assert ubx[l0[0, 2, 0, i]] == ubx[l1[0, 2, 0, i]] == 0.0
    assert np.all(xc >= lbx) and np.all(xc <= ubx)


def test_the_fesd_stage_after_implicit_euler_takes_a_given_soft_terminal_weight(monkeypatch):
    """FESDStart.IMPLICIT_EULER with a soft_terminal_weight of the user's (read by the implicit-Euler stage) derives
    the FESD stage's options without refusing it there (soft_terminal_nlps = 0 there: the refusal of a weight no NLP
    reads fired after the whole implicit-Euler solve, exit 2)."""
    problem = build_problem(load_robot("robots/point_mass.xml"), hop_task(N=4), fesd_options(2, 2))
    given = _stages_stubbed(monkeypatch, None)
    with pytest.raises(_FesdStageReached):
        H._solve_through_implicit_euler(problem, H.SolveOptions(soft_terminal_weight=1e3,
                                                                fesd_start=H.FESDStart.IMPLICIT_EULER), None)
    assert given[0][1].soft_terminal_weight == 1e3 and given[1][1].soft_terminal_nlps == 0


class _FesdStageReached(Exception):
    """Raised by _stages_stubbed's FESD stage: its own solve is not these tests'."""


def _stages_stubbed(monkeypatch, mapped):
    """Stub FESDStart.IMPLICIT_EULER's two solves: the implicit-Euler stage returns a converged stub, the FESD stage
    raises _FesdStageReached once it has its (problem, options), and the mapping returns `mapped`. Returns the list
    the two solves' (problem, options) are appended to."""
    given = []

    class Stub:
        extra, nlps = {"_x": None}, ()
        stats = H.SolveStats(converged=True, solve_time_s=0.0, n_nlp=0, ipopt_iterations=0,
                             complementarity_residual=0.0, message="")

    def solved(prob, options, progress=None):
        given.append((prob, options))
        if len(given) == 2:
            raise _FesdStageReached
        return Stub()

    monkeypatch.setattr(H, "solve", solved)
    monkeypatch.setattr("planner.problem.fesd_start_from_implicit_euler", lambda *args: mapped)
    return given


def test_the_fesd_stage_after_implicit_euler_starts_from_the_mapped_plan_with_its_own_schedule(monkeypatch):
    """FESDStart.IMPLICIT_EULER solves the FESD problem from fesd_start_from_implicit_euler's point (the implicit-Euler
    stage's plan mapped), over fesd_rho_schedule (not rho_schedule, the implicit-Euler stage's), with the holes
    enforced from its first NLP (the mapped start already keeps them) whatever the given hole schedule (session 66's
    mutation testing: the FESD stage started from the problem's own x0, took rho_schedule, or relaxed the holes at
    its first NLP, with every test green)."""
    problem = build_problem(load_robot("robots/point_mass.xml"), hop_task(N=4), fesd_options(2, 2))
    mapped = np.full(problem.nx, 0.25)  # a point no solve would give: the mapping's, passed on as it is
    given = _stages_stubbed(monkeypatch, mapped)
    options = H.SolveOptions(fesd_start=H.FESDStart.IMPLICIT_EULER, holes=H.HoleSchedule.RELAXED_FIRST,
                             rho_schedule=(1e2, 1e3), fesd_rho_schedule=(1e4, 1e5))
    with pytest.raises(_FesdStageReached):
        H._solve_through_implicit_euler(problem, options, None)
    (euler, first), (fesd, second) = given
    assert euler.fesd is None and first.rho_schedule == (1e2, 1e3) and first.holes is H.HoleSchedule.RELAXED_FIRST
    assert fesd.fesd is not None and np.array_equal(fesd.x0, mapped)
    assert second.rho_schedule == (1e4, 1e5) and second.holes is H.HoleSchedule.ENFORCED
    assert second.fesd_start is H.FESDStart.HINT_FREE


def test_a_solve_through_implicit_euler_counts_the_nlps_of_both_stages():
    """FESDStart.IMPLICIT_EULER's result (the point-mass hop, N = 5, n_s = 1, n_fe = 2) records every NLP of both
    stages, the implicit-Euler ones first and labelled "implicit Euler: ...": its n_nlp is their number, its IPOPT
    iterations their sum, and extra["implicit_euler"]'s iterations the sum over the implicit-Euler ones (session 66's
    mutation testing: the FESD stage's iterations alone, and its NLP records alone, with every test green)."""
    problem = build_problem(load_robot("robots/point_mass.xml"), hop_task(N=5), fesd_options(1, 2))
    res = H.solve(problem, H.SolveOptions(fesd_start=H.FESDStart.IMPLICIT_EULER))
    euler = [r for r in res.nlps if r.label.startswith("implicit Euler: ")]
    assert euler and len(euler) < len(res.nlps) and res.nlps[: len(euler)] == tuple(euler)
    assert res.stats.n_nlp == len(res.nlps)
    assert res.stats.ipopt_iterations == sum(r.iterations for r in res.nlps)
    assert res.extra["implicit_euler"]["ipopt_iterations"] == sum(r.iterations for r in euler)
