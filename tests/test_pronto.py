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
STATIONARY_TOL = 1e-9  # |dg/du| at a converged solve: 1.3e-12 measured; stopped without the last Newton step, 9e-6
SAME_ITERATES_TOL = 1e-12  # [N m] a constant in the cost changes no iterate (measured: bit-identical)
RICCATI_TOL = 1e-10  # LQR gains, the same recursion evaluated in another order: round-off (~1e-14 measured)
PENDULUM_FEEDBACK = dict(feedback_q=(DT * 10, DT), feedback_r=(DT * 0.1,))  # the pendulum's projection weights


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


def _pendulum(constant=0.0):
    x, u, p, th = ca.SX.sym("x", 2), ca.SX.sym("u", 1), ca.SX.sym("p", 0), ca.SX.sym("th", 0)
    f = lambda x, u: ca.vertcat(x[1], -9.81 * ca.sin(x[0]) - 0.1 * x[1] + u[0])
    k1 = f(x, u); k2 = f(x + DT / 2 * k1, u); k3 = f(x + DT / 2 * k2, u); k4 = f(x + DT * k3, u)
    goal = ca.DM([np.pi, 0.0])
    step = ca.Function("f", [x, u], [x + DT / 6 * (k1 + 2 * k2 + 2 * k3 + k4)])
    stage = ca.Function("l", [x, u, p, th], [0.5 * DT * (0.1 * ca.sumsqr(x - goal) + 0.01 * u[0] ** 2)])
    term = ca.Function("m", [x, th], [50.0 * ca.sumsqr(x - goal) + constant])
    return DiscreteOCP(step, stage, term, N)


def _shooting_cost(ocp):
    """The pendulum's cost as a function of its inputs U (1, N) alone (single shooting from rest), built without
    PRONTO: (U, J)."""
    U = ca.MX.sym("U", 1, N)
    X = ocp.step.mapaccum("roll", N)(ca.DM.zeros(2), U)
    stages = ocp.stage.map(N)(ca.horzcat(ca.DM.zeros(2), X[:, :-1]), U, ca.DM.zeros(0, N), ca.DM.zeros(0))
    return U, ca.sum2(stages) + ocp.terminal(X[:, -1], ca.DM.zeros(0))


@pytest.fixture(scope="module")
def pendulum_solution():
    ocp = _pendulum()
    pr = Pronto(ocp, ProntoOptions(**PENDULUM_FEEDBACK))
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
    U, J = _shooting_cost(ocp)
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


def test_a_converged_solve_is_stationary_to_round_off(pendulum_solution):
    """At the returned optimum the gradient of the cost in the inputs, differentiated through a single-shooting
    rollout without PRONTO, vanishes to round-off: the solve ends with the full Newton step its stopping rule no
    longer sees (a penalty's decrease sinks below the tolerance while x_N still moves; the gait's Newton loop on x_T
    stalled at 1e-8 without it) (session 66's mutation testing: the final Newton step dropped, with every test
    green)."""
    ocp, res = pendulum_solution
    U, J = _shooting_cost(ocp)
    gradient = ca.Function("gradient", [U], [ca.gradient(J, U)])
    assert res.converged and np.max(np.abs(np.array(gradient(res.u.T)))) < STATIONARY_TOL


@pytest.mark.parametrize("start, polished", [(0.0, False), (1e-8, True)])
def test_a_converged_solve_says_whether_it_took_its_final_newton_step(start, polished):
    """ProntoResult.polished is true only when the converged solve took (and kept) its final full Newton step: at the
    exact optimum (x0 = 0 of a tracking cost of 0: slope 0) no step is taken, near it (x0 = 1e-8: slope -3e-17, below
    the tolerance) it is. Both converge in 0 counted iterations, and a gait's progress line said of each that its
    final step moved it (review r3)."""
    ocp, _, _ = _lq_ocp(np.random.default_rng(0))
    pr = Pronto(ocp, ProntoOptions(feedback_q=(1.0,) * 3, feedback_r=(1.0,) * 2))
    pr.set_parameters(np.zeros((N, 3)), np.zeros(0))
    res = pr.solve(np.full(3, start), np.zeros((N + 1, 3)), np.zeros((N, 2)))
    assert (res.converged, res.iterations, res.polished) == (True, 0, polished)


def test_a_constant_in_the_cost_changes_no_iterate(pendulum_solution):
    """A constant added to the cost (a penalty that makes g large) moves no minimizer and no iterate: the stopping
    rule reads the predicted decrease absolutely, not relative to g, so the solve takes the same iterations to the
    same inputs (session 66's mutation testing: the tolerance made relative to |g|, stopping one iteration early,
    with every test green)."""
    _, res = pendulum_solution
    pr = Pronto(_pendulum(constant=1e7), ProntoOptions(**PENDULUM_FEEDBACK))
    pr.set_parameters(np.zeros((N, 0)), np.zeros(0))
    shifted = pr.solve(np.zeros(2), np.zeros((N + 1, 2)), np.zeros((N, 1)))
    assert shifted.converged and shifted.iterations == res.iterations
    assert np.max(np.abs(shifted.u - res.u)) < SAME_ITERATES_TOL


def test_the_projection_feedback_is_the_lqr_of_the_linearization():
    """Pronto.feedback (ProntoResult.K, the walk's LQR gains) is the time-varying LQR of the curve's linearization
    with the option weights, terminal weight feedback_q included: K_k = (R + B'PB)^-1 B'PA, P = Q + A'P(A - BK) from
    P_N = Q, written out with numpy at a random curve (session 66's mutation testing: the recursion started from
    P_N = 0, the last gain off by 0.485, with every test green)."""
    ocp = _pendulum()
    pr = Pronto(ocp, ProntoOptions(**PENDULUM_FEEDBACK))
    rng = np.random.default_rng(3)
    x, u = rng.normal(size=(N + 1, 2)), rng.normal(size=(N, 1))
    xs, us = ca.SX.sym("x", 2), ca.SX.sym("u", 1)
    nxt = ocp.step(xs, us)
    jacobians = ca.Function("jacobians", [xs, us], [ca.jacobian(nxt, xs), ca.jacobian(nxt, us)])
    Q, R = np.diag(PENDULUM_FEEDBACK["feedback_q"]), np.diag(PENDULUM_FEEDBACK["feedback_r"])
    P, K = Q, np.zeros((N, 1, 2))
    for k in reversed(range(N)):
        A, B = (np.array(J) for J in jacobians(x[k], u[k]))
        K[k] = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
        P = Q + A.T @ P @ (A - B @ K[k])
    assert np.max(np.abs(pr.feedback(x, u) - K)) < RICCATI_TOL


def test_a_newton_lq_that_is_not_convex_falls_back_to_quasi_newton(monkeypatch):
    """Where the exact (Newton) LQ is not convex (a leading minor of R + B'PB <= 0), its direction may lead to a saddle
    whatever its slope: the iteration takes the quasi-Newton direction instead, as it does for a Newton direction
    that is not a descent. Pronto._direction_at is wrapped (not changed) to see which LQ each direction came from: the
    result alone cannot show it (the pendulum reached the same optimum in 24 iterations instead of 20) (session 66's
    mutation testing: the fallback taken only when both failed, with every test green)."""
    calls, direction_at = [], Pronto._direction_at

    def recorded(self, x, u, newton):
        out = direction_at(self, x, u, newton)
        calls.append((newton, float(np.min(out[4])), out[3]))  # (Newton LQ?, smallest leading minor, slope)
        return out

    monkeypatch.setattr(Pronto, "_direction_at", recorded)
    pr = Pronto(_pendulum(), ProntoOptions(**PENDULUM_FEEDBACK))
    pr.set_parameters(np.zeros((N, 0)), np.zeros(0))
    res = pr.solve(np.zeros(2), np.zeros((N + 1, 2)), np.zeros((N, 1)))
    not_convex = [i for i, (newton, minor, _) in enumerate(calls) if newton and minor <= 0]
    assert res.converged and not_convex  # from rest, the pendulum meets non-convex Newton LQs
    assert all(not calls[i + 1][0] for i in not_convex)
    assert sum(not h.newton for h in res.history) >= len(not_convex)
