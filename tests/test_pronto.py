"""PRONTO (planner.pronto) on problems with known solutions: a linear-quadratic problem (one Newton
step, equal to the KKT solution), and a nonlinear pendulum swing-up (quadratic convergence near the
optimum, same optimum as IPOPT on the same discretization)."""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from planner.errors import InputError
from planner.pronto import DiscreteOCP, Pronto, ProntoOptions

N, DT = 60, 0.05
SAME_OPTIMUM_TOL = 1e-6  # inputs [N m]; both solvers stop at ~1e-10 on the gradient


def _lq_ocp(rng):
    n, m = 3, 2
    A = np.eye(n) + DT * rng.normal(size=(n, n))
    B = DT * rng.normal(size=(n, m))
    x, u, p, th = ca.SX.sym("x", n), ca.SX.sym("u", m), ca.SX.sym("p", n), ca.SX.sym("th", 0)
    step = ca.Function("f", [x, u], [ca.mtimes(ca.DM(A), x) + ca.mtimes(ca.DM(B), u)])
    stage = ca.Function("l", [x, u, p, th], [0.5 * DT * (ca.sumsqr(x - p) + 0.1 * ca.sumsqr(u))])
    term = ca.Function("m", [x, th], [5.0 * ca.sumsqr(x)])
    return DiscreteOCP(step, stage, term, N), A, B


def test_lq_problem_is_solved_in_one_newton_step():
    """For linear dynamics and a quadratic cost, the first Newton direction is the exact optimum: one
    iteration, equal to the solution of the KKT system written out with numpy."""
    rng = np.random.default_rng(0)
    ocp, A, B = _lq_ocp(rng)
    n, m = 3, 2
    pr = Pronto(ocp, ProntoOptions(feedback_q=(1.0,) * n, feedback_r=(1.0,) * m))
    ref = rng.normal(size=(N, n))
    pr.set_parameters(ref, np.zeros(0))
    x0 = rng.normal(size=n)
    res = pr.solve(x0, np.zeros((N + 1, n)), np.zeros((N, m)))
    assert res.converged and res.iterations == 1
    # the same problem as one quadratic program in u: x = Phi x0 + Gamma u (condensed)
    Phi = [np.eye(n)]
    for _ in range(N):
        Phi.append(A @ Phi[-1])
    Gam = np.zeros((N + 1, n, N, m))
    for k in range(1, N + 1):
        for j in range(k):
            Gam[k, :, j, :] = np.linalg.matrix_power(A, k - 1 - j) @ B
    Gam = Gam.reshape((N + 1) * n, N * m)
    free = np.concatenate([P @ x0 for P in Phi])
    W = np.kron(np.diag([DT] * N + [0.0]), np.eye(n)) + np.kron(np.diag([0.0] * N + [10.0]), np.eye(n))
    target = np.concatenate([ref.ravel(), np.zeros(n)])  # the terminal cost pulls x_N to 0
    H = Gam.T @ W @ Gam + 0.1 * DT * np.eye(N * m)
    u_star = np.linalg.solve(H, -Gam.T @ W @ (free - target))
    assert np.max(np.abs(res.u.ravel() - u_star)) < 1e-9


def _pendulum():
    x, u, p, th = ca.SX.sym("x", 2), ca.SX.sym("u", 1), ca.SX.sym("p", 0), ca.SX.sym("th", 0)
    f = lambda x, u: ca.vertcat(x[1], -9.81 * ca.sin(x[0]) - 0.1 * x[1] + u[0])
    k1 = f(x, u); k2 = f(x + DT / 2 * k1, u); k3 = f(x + DT / 2 * k2, u); k4 = f(x + DT * k3, u)
    goal = ca.DM([np.pi, 0.0])
    step = ca.Function("f", [x, u], [x + DT / 6 * (k1 + 2 * k2 + 2 * k3 + k4)])
    stage = ca.Function("l", [x, u, p, th], [0.5 * DT * (0.1 * ca.sumsqr(x - goal) + 0.01 * u[0] ** 2)])
    term = ca.Function("m", [x, th], [50.0 * ca.sumsqr(x - goal)])
    return DiscreteOCP(step, stage, term, N)


@pytest.fixture(scope="module")
def pendulum_solution():
    ocp = _pendulum()
    pr = Pronto(ocp, ProntoOptions(feedback_q=(DT * 10, DT), feedback_r=(DT * 0.1,)))
    pr.set_parameters(np.zeros((N, 0)), np.zeros(0))
    return ocp, pr.solve(np.zeros(2), np.zeros((N + 1, 2)), np.zeros((N, 1)))


def test_pendulum_swing_up_converges_quadratically(pendulum_solution):
    """From rest (no hint), PRONTO converges; its last full Newton steps shrink the directional
    derivative quadratically: |slope_{k+1}| <= C |slope_k|^2 with a modest C."""
    _, res = pendulum_solution
    assert res.converged
    tail = [h for h in res.history if h.newton and h.step == 1.0]
    slopes = [-h.slope for h in tail][-3:]
    assert len(slopes) >= 2
    for a, b in zip(slopes, slopes[1:]):
        assert b <= 100.0 * a**2 or b < 1e-12
    assert abs(res.x[-1, 0] - np.pi) < 0.05


def test_pendulum_matches_ipopt(pendulum_solution):
    """IPOPT (single shooting, exact Hessian) on the same discrete problem finds the same optimum."""
    ocp, res = pendulum_solution
    U = ca.MX.sym("U", 1, N)
    X = ocp.step.mapaccum("roll", N)(ca.DM.zeros(2), U)
    J = ca.sum2(ocp.stage.map(N)(ca.horzcat(ca.DM.zeros(2), X[:, :-1]), U, ca.DM.zeros(0, N), ca.DM.zeros(0))) + ocp.terminal(X[:, -1], ca.DM.zeros(0))
    solver = ca.nlpsol("s", "ipopt", {"x": U.T, "f": J}, {"print_time": False, "ipopt.print_level": 0, "ipopt.sb": "yes", "ipopt.tol": 1e-12})
    sol = solver(x0=res.u.ravel())  # started at PRONTO's optimum: a check of the optimum, not a race
    assert abs(float(sol["f"]) - res.cost) < 1e-9
    assert np.max(np.abs(np.array(sol["x"]).ravel() - res.u.ravel())) < SAME_OPTIMUM_TOL


def test_bad_options_are_input_errors():
    """Wrong or empty feedback weights or Armijo constants are InputError with the reason."""
    with pytest.raises(InputError):
        ProntoOptions(feedback_q=(1.0,), feedback_r=(1.0,), armijo_c=0.9)
    for empty in ({"feedback_q": ()}, {"feedback_r": ()}):  # min() of an empty tuple raised ValueError
        with pytest.raises(InputError, match="feedback"):
            ProntoOptions(**{"feedback_q": (1.0,), "feedback_r": (1.0,), **empty})
    with pytest.raises(InputError, match="feedback"):
        Pronto(_pendulum(), ProntoOptions(feedback_q=(1.0,), feedback_r=(1.0,)))


def test_every_accepted_step_meets_the_armijo_condition(pendulum_solution):
    """Each accepted PRONTO step decreases the cost by the Armijo rule: g_new <= g + c gamma slope (slope < 0). The
    pendulum converges whatever the line search accepts, so its solution alone could not tell a sign slip that took
    steps raising the cost (172 -> 177 -> 195; session 65's mutation testing)."""
    _, result = pendulum_solution
    history, c = result.history, ProntoOptions(feedback_q=(DT * 10, DT), feedback_r=(DT * 0.1,)).armijo_c
    assert len(history) > 2
    assert all(b.cost <= a.cost + c * a.step * a.slope for a, b in zip(history, history[1:]))
