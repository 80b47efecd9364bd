"""The NLP's step-by-step derivatives (planner.derivatives) are CasADi's whole-graph derivation, value and sparsity."""
from __future__ import annotations

import dataclasses

import casadi as ca
import numpy as np
import pytest

from planner.derivatives import nlp_derivatives
from planner.discretization import Discretization
from planner.model import load_robot
from planner.problem import Penalty, ProblemOptions, build_problem
from planner.task import Horizon, load_task
from test_problem import hop_task

# the same terms summed in another order: a few ulps of the largest entry (Capler's Hessian reaches ~1e3)
DERIV_RTOL = 1e-12
DERIV_ATOL = 1e-10


def _task(robot_name: str, **horizon):
    """The robot's task on N = 4 steps (the point mass: test_problem's hop)."""
    task = hop_task() if robot_name == "point_mass" else load_task(f"robots/{robot_name}.toml")
    tau_f = 1.0 if robot_name == "point_mass" else 0.2
    return dataclasses.replace(task, horizon=Horizon(tau_f=tau_f, N=4, **horizon))


CASES = {  # every piece of Problem.stages: y_0 constant or free, s_k, the step's parameters, f_rest's terms, penalties
    "capler": ("capler", {}, ProblemOptions()),
    "capler_aux_clock_l1": ("capler", {}, ProblemOptions(aux_continuation=True, clock_weight=0.3, penalty=Penalty.L1)),
    "capler_substituted_products": ("capler", {}, ProblemOptions(lift_products=False)),
    "point_mass_timed": ("point_mass", {"physical_time": 0.8}, ProblemOptions()),
    "biped_periodic": ("biped", {}, ProblemOptions()),
}


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("n_extra", [0, 1])
def test_stepwise_derivatives_equal_casadis(case, n_extra):
    """grad_f, jac_g and hess_lag derived step by step equal, value and sparsity, what CasADi derives from the whole
    NLP, at a random point with random multipliers and parameters (with n_extra unused variables appended: the
    Regularization.FROM_LAST probe)."""
    robot_name, horizon, options = CASES[case]
    prob = build_problem(load_robot(f"robots/{robot_name}.xml"), _task(robot_name, **horizon), options)
    assert prob.stages is not None
    rng = np.random.default_rng(7)
    x = np.concatenate([prob.x0 + rng.normal(scale=0.3, size=prob.nx), rng.normal(size=n_extra)])
    p = prob.params(1e3, 0.8, 1.2, 0.7, 5.0, 2.0, 3.0)
    args = {"grad_f": (x, p), "jac_g": (x, p), "hess_lag": (x, p, 0.9, rng.normal(size=prob.ng))}
    stepwise, whole = nlp_derivatives(prob, n_extra), nlp_derivatives(prob, n_extra, stepwise=False)
    for name, a in args.items():
        assert stepwise[name].name_out() == whole[name].name_out()
        for got, want in zip(stepwise[name].call(list(a)), whole[name].call(list(a))):
            assert got.sparsity() == want.sparsity(), name
            np.testing.assert_allclose(np.asarray(ca.densify(got)), np.asarray(ca.densify(want)), rtol=DERIV_RTOL,
                                       atol=DERIV_ATOL, err_msg=name)


def test_fesd_problems_keep_the_whole_graph_derivation():
    """FESD problems have no Problem.stages: nlp_derivatives falls back to the whole-graph derivation, shaped as nlpsol wants it."""
    task = _task("point_mass")
    prob = build_problem(load_robot("robots/point_mass.xml"), task, ProblemOptions(discretization=Discretization.FESD))
    assert prob.stages is None
    d = nlp_derivatives(prob)
    assert d["hess_lag"].name_out() == ["triu_hess_gamma_x_x"] and d["hess_lag"].size1_in(0) == prob.nx


def test_an_edited_cost_is_in_the_hessian():
    """A cost term added to a built problem's f (a penalty on the base height) is in hess_lag however asked for:
    the step-by-step derivation, whose steps hold the built cost, falls back to the whole graph (its Hessian had
    missed the term, 2 w at the term's entry, and NLP 1 took 3000 iterations instead of 56)."""
    robot = load_robot("robots/capler.xml")
    prob = build_problem(robot, _task("capler"))
    z = prob.x[prob.var_blocks["y"][1, 1]]  # the base height at node 2 [m]
    edited = dataclasses.replace(prob, f=prob.f + 2.5 * z**2)
    rng = np.random.default_rng(3)
    x, p = prob.x0 + rng.normal(scale=0.3, size=prob.nx), prob.params(1e3)
    lam = rng.normal(size=prob.ng)
    H = [np.asarray(ca.densify(nlp_derivatives(pb, stepwise=s)["hess_lag"](x, p, 1.0, lam)))
         for pb, s in ((edited, True), (edited, False), (prob, True))]
    np.testing.assert_allclose(H[0], H[1], rtol=DERIV_RTOL, atol=DERIV_ATOL)
    k = int(prob.var_blocks["y"][1, 1])
    assert H[0][k, k] - H[2][k, k] == pytest.approx(5.0, rel=1e-9)
