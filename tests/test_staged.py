"""planner.staged: the stage-ordered NLP for FATROP is the Problem's NLP re-expressed."""
from __future__ import annotations

import dataclasses

import casadi as ca
import numpy as np
import pytest

from planner.model import load_robot
from planner.problem import build_problem
from planner.staged import staged_nlp
from planner.task import Horizon, load_task

ROBOTS = "robots"


@pytest.fixture(scope="module")
def capler_staged():
    robot = load_robot(f"{ROBOTS}/capler.xml")
    task = load_task(f"{ROBOTS}/capler.toml")
    prob = build_problem(robot, dataclasses.replace(task, horizon=Horizon(tau_f=0.5, N=10)))
    return prob, staged_nlp(prob)


def test_same_values_up_to_permutation(capler_staged):
    """At a random seeded point x (and random parameters), the staged NLP at lift(x) has the original
    f(x), its rows are the original g(x) rows permuted (every original row exactly once), the added
    gap rows (y_{k+1} - z_k, s_c copies) are 0, its bounds are the original bounds of the variables
    they copy, and restrict(lift(x)) = x."""
    _assert_same_values(*capler_staged)


def test_a_timed_tasks_staged_nlp_is_its_problems_nlp():
    """A task with plan.physical_time (its rows "physical_time", its step sizes s_k) is staged too, with the same
    values as the Problem's NLP (session 66's mutation testing: either of two slips refused every such task, with
    every test green)."""
    task = load_task(f"{ROBOTS}/point_mass_hop.toml")
    pb = build_problem(load_robot(f"{ROBOTS}/point_mass.xml"),
                       dataclasses.replace(task, horizon=Horizon(tau_f=1.0, N=4, physical_time=0.8)))
    assert "physical_time" in pb.g_blocks and "s" in pb.var_blocks
    _assert_same_values(pb, staged_nlp(pb))


def _assert_same_values(pb, st):
    rng = np.random.default_rng(7)
    x = rng.uniform(-2.0, 2.0, pb.nx)
    p = pb.params(rng.uniform(1, 1e3), rng.uniform(0, 1), terminal_weight=rng.uniform(0, 100), rho_l1=rng.uniform(0, 10))
    f0 = float(ca.Function("f", [pb.x, pb.p], [pb.f])(x, p))
    g0 = np.asarray(ca.Function("g", [pb.x, pb.p], [pb.g])(x, p), float).ravel()
    xn = st.lift(x)
    f1 = float(ca.Function("f", [st.x, st.p], [st.f])(xn, p))
    g1 = np.asarray(ca.Function("g", [st.x, st.p], [st.g])(xn, p), float).ravel()
    orig = st.g_src >= 0
    assert np.array_equal(np.sort(st.g_src[orig]), np.arange(pb.ng))
    assert f1 == pytest.approx(f0, rel=1e-12, abs=1e-12)
    np.testing.assert_allclose(g1[orig], g0[st.g_src[orig]], rtol=1e-12, atol=1e-12)
    assert np.all(g1[~orig] == 0.0)
    np.testing.assert_array_equal(st.restrict(xn), x)
    np.testing.assert_array_equal(st.lbg[orig], pb.lbg[st.g_src[orig]])
    main = st.x_main  # the bounded copy of every original variable carries its bounds
    np.testing.assert_array_equal(st.lbx[main], pb.lbx)
    np.testing.assert_array_equal(st.ubx[main], pb.ubx)


def test_fatrop_structure(capler_staged):
    """The staged NLP has FATROP's form: the Jacobian fits the stage blocks (FATROP's interface accepts
    the manual structure) and the Lagrangian Hessian is block diagonal in the stages (x_k, u_k):
    FATROP keeps only those blocks, so an entry outside them would be dropped silently."""
    pb, st = capler_staged
    assert len(st.nxs) == len(st.nus) == len(st.ngs) == st.N + 1
    assert sum(st.nxs) + sum(st.nus) == st.x.shape[0]
    assert sum(st.nxs[1:]) + sum(st.ngs) == st.g.shape[0]
    lam = ca.SX.sym("lam", st.g.shape[0])
    H = ca.hessian(st.f + ca.dot(lam, st.g), st.x)[0].sparsity()
    offs = np.cumsum([0] + [a + b for a, b in zip(st.nxs, st.nus)])
    stage = np.searchsorted(offs, np.arange(st.x.shape[0]), side="right") - 1
    rows, cols = H.get_triplet()
    assert np.all(stage[np.array(rows)] == stage[np.array(cols)])
    ca.nlpsol("staged_fatrop", "fatrop", st.nlp, st.fatrop_options(print_level=0))  # raises on a structure mismatch


def test_without_free_rows(capler_staged):
    """With NLP 1's soft terminal (terminal rows unbounded both ways) the free rows are exactly the
    terminal rows, all on the last stage; the rest of the NLP and its structure are unchanged."""
    pb, st = capler_staged
    lbg, ubg = pb.lbg.copy(), pb.ubg.copy()
    term = pb.g_blocks["terminal"].ravel()
    lbg[term], ubg[term] = -np.inf, np.inf
    st2 = st.without_free_rows(lbg, ubg)
    assert st2.g.shape[0] == st.g.shape[0] - len(term)
    assert st2.ngs[:-1] == st.ngs[:-1] and st2.ngs[-1] == st.ngs[-1] - len(term)
    assert set(st.g_src) - set(st2.g_src) == set(term.tolist())
    assert st.without_free_rows(pb.lbg, pb.ubg) is st


def test_bench_fatrop_smoke(tmp_path):
    """scripts/bench_fatrop.py runs both solvers and the staged IPOPT on a tiny hop and writes its record."""
    import json

    from scripts import bench_fatrop
    out = tmp_path / "r.json"
    assert bench_fatrop.main(["--case", "hop", "--N", "6", "--max-iter", "3", "--solvers", "ipopt", "fatrop", "ipopt_staged",
                              "--out", str(out)]) == 0
    rec = json.loads(out.read_text())
    assert [r["solver"] for r in rec["runs"]] == ["ipopt", "fatrop", "ipopt_staged"]
    assert all(r["iterations"] >= 1 and r["cpu_ms_per_iter"] > 0 for r in rec["runs"])
