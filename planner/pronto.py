"""PRONTO, the projection operator Newton method (Hauser 2002; paper 001, Appendix A), discretized.

The problem is the discrete-time optimal control problem

    min  g = sum_{k<N} l(x_k, u_k, p_k, theta) + m(x_N, theta)
    s.t. x_{k+1} = f(x_k, u_k),   x_0 given,

on a fixed grid (f is one integrator step, l already carries its step length). One iteration:

1. **projection feedback**: K_k from a time-varying LQR (Riccati) on the linearization (A_k, B_k)
   about the current trajectory, with the option weights; it defines the projection operator
   P(alpha, mu) = the trajectory of x_{k+1} = f(x_k, u_k), u_k = mu_k + K_k (alpha_k - x_k).
2. **Newton direction**: zeta = (z, v) minimizes Dg . zeta + 1/2 D^2g(zeta, zeta) over the tangent
   space z_{k+1} = A_k z_k + B_k v_k, z_0 = 0. The second-order term is exact for the projected
   functional g(P(.)): its weight is the Hessian of l_k + q_{k+1}' f(x_k, u_k) with the
   closed-loop costate q_k = a_k - K_k' b_k + (A_k - B_k K_k)' q_{k+1}, q_N = m_x (Hauser's
   derivation; q equals the open-loop multiplier at a stationary point). When that LQ problem is
   not convex (a leading minor of R + B'PB <= 0) or its solution is not a descent direction, the
   iteration falls back to the quasi-Newton LQ without the dynamics' curvature, which is convex
   for the quadratic costs used here.
3. **Armijo line search** on g(P(xi + gamma zeta)), gamma = 1, beta, beta^2, ...
   At convergence (predicted decrease below the tolerance) one last full Newton step is taken
   without line search when it does not raise g beyond round-off (not counted as an iteration).

Every sweep over time (projection, Riccati recursions, costate, LQ forward pass) and every
derivative evaluation is one compiled CasADi graph (map / mapaccum); Python only loops over
iterations and line-search trials.

Array conventions of the public API: time-major numpy arrays, x (N+1, n), u (N, m), p (N, n_p).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from .errors import InputError, SolveError, check_field_types

ROUNDOFF = 1e-13  # relative round-off of a cost evaluation: ~N = 1e2 terms of relative error 1e-16, with margin


@dataclass(frozen=True)
class DiscreteOCP:
    """A discrete-time OCP for PRONTO.

    step (x (n,), u (m,)) -> x_next (n,): one integrator step of the dynamics.
    stage (x (n,), u (m,), p (n_p,), theta (n_theta,)) -> l: the running cost of one step (its
      integral over the step, i.e. already multiplied by the step length).
    terminal (x (n,), theta (n_theta,)) -> m: the terminal cost.
    N: number of steps. All functions must be twice differentiable CasADi SX functions.
    """

    step: ca.Function
    stage: ca.Function
    terminal: ca.Function
    N: int

    def __post_init__(self):
        check_field_types(self)
        if self.N < 1:
            raise InputError(f"DiscreteOCP.N = {self.N} must be >= 1")

    @property
    def n(self) -> int:
        return self.step.size1_in(0)

    @property
    def m(self) -> int:
        return self.step.size1_in(1)

    @property
    def n_p(self) -> int:
        return self.stage.size1_in(2)

    @property
    def n_theta(self) -> int:
        return self.stage.size1_in(3)


@dataclass(frozen=True)
class ProntoOptions:
    """Settings of one PRONTO solve.

    feedback_q (n,), feedback_r (m,): diagonal per-step LQR weights of the projection feedback
    (a regulator design choice, not the cost); the terminal weight is feedback_q too.
    """

    feedback_q: tuple[float, ...]
    feedback_r: tuple[float, ...]
    max_iterations: int = 50
    tolerance: float = 1e-12  # stop when -Dg.zeta (twice the predicted Newton decrease) < tolerance; absolute,
    #   because penalty terms make g large while the part of it that can still change is small
    armijo_c: float = 0.4  # sufficient decrease: g_new <= g + c gamma Dg.zeta
    armijo_beta: float = 0.5  # backtracking factor
    min_step: float = 1e-10  # give up (not converged) below this step length
    newton: bool = True  # False: always the quasi-Newton LQ (first-order dynamics terms only)

    def __post_init__(self):
        check_field_types(self)
        if self.max_iterations < 1:
            raise InputError(f"pronto.max_iterations = {self.max_iterations} must be >= 1")
        if not (self.tolerance > 0 and 0 < self.armijo_c < 0.5 and 0 < self.armijo_beta < 1 and self.min_step > 0):
            raise InputError("pronto options: need tolerance > 0, 0 < armijo_c < 0.5, 0 < armijo_beta < 1, min_step > 0")
        if not (self.feedback_q and self.feedback_r) or min(self.feedback_q) < 0 or min(self.feedback_r) <= 0:
            raise InputError(f"pronto feedback weights feedback_q = {self.feedback_q}, feedback_r = "
                             f"{self.feedback_r} are not allowed: each needs one weight per state (q, >= 0) or input "
                             "(r, > 0)")


@dataclass(frozen=True)
class ProntoIteration:
    """One PRONTO iteration: cost before it, directional derivative Dg.zeta, accepted step, and
    whether the Newton (second-order) LQ was used."""

    cost: float
    slope: float
    step: float
    newton: bool


@dataclass(frozen=True, eq=False)
class ProntoResult:
    """x (N+1, n), u (N, m): the final trajectory; K (N, m, n): its projection feedback; polished: a converged
    solve's final full Newton step (not counted in `iterations`) was taken and kept: it is tried only when its slope
    is negative and kept only when it does not raise g beyond round-off."""

    x: np.ndarray
    u: np.ndarray
    K: np.ndarray
    cost: float
    converged: bool
    iterations: int
    solve_time_s: float
    history: tuple[ProntoIteration, ...] = field(default=())
    message: str = ""
    polished: bool = False


class Pronto:
    """The compiled PRONTO machinery of one DiscreteOCP (build once, solve many times)."""

    def __init__(self, ocp: DiscreteOCP, options: ProntoOptions):
        n, m = ocp.n, ocp.m
        if len(options.feedback_q) != n or len(options.feedback_r) != m:
            raise InputError(f"pronto feedback weights need {n} state and {m} input entries; got "
                             f"{len(options.feedback_q)} and {len(options.feedback_r)}")
        self.ocp, self.options = ocp, options
        self._build()

    # ---------------------------------------------------------------------------------------------
    # public API

    def project(self, x0, alpha, mu, K) -> tuple[np.ndarray, np.ndarray, float]:
        """P(alpha, mu) with gains K: x0 (n,), alpha (N+1, n), mu (N, m), K (N, m, n).
        Returns the trajectory x (N+1, n), u (N, m) and its cost g (with the parameters last set
        by `set_parameters`)."""
        X, U, g = self._project(np.asarray(x0, float), _cols(alpha)[:, :-1], _cols(mu), _kcols(K), self._P, self._theta)
        return np.hstack([np.asarray(x0, float)[:, None], np.array(X)]).T, np.array(U).T, float(g)

    def set_parameters(self, p, theta) -> None:
        """Stage parameters p (N, n_p) and global parameters theta (n_theta,) of the cost."""
        self._P = ca.DM(_cols(p).reshape(self.ocp.n_p, self.ocp.N))
        self._theta = ca.DM(np.asarray(theta, float).reshape(-1))

    def feedback(self, x, u) -> np.ndarray:
        """LQR gains K (N, m, n) of the projection about the curve x (N+1, n), u (N, m)."""
        return _unkcols(np.array(self._gains(_cols(x), _cols(u))), self.ocp.m, self.ocp.n)

    def solve(self, x0, x, u, K=None) -> ProntoResult:
        """Minimize from the initial curve x (N+1, n), u (N, m) (projected first).

        K (N, m, n): gains for that first projection (default: LQR about the curve itself).
        Raises SolveError if an iterate is not finite.
        """
        opts = self.options
        start = time.perf_counter()
        if K is None:
            K = self.feedback(x, u)
        x, u, g = self.project(x0, x, u, K)
        history: list[ProntoIteration] = []
        converged, message, polished = False, "iteration limit", False
        for _ in range(opts.max_iterations):
            if not np.isfinite(g):
                raise SolveError("PRONTO: the projected trajectory is not finite (the projection feedback could not "
                                 "stabilize it); try a better initial curve or stronger feedback weights")
            newton = opts.newton
            K, Z, V, slope, minors = self._direction_at(x, u, newton)
            if newton and (np.min(minors) <= 0 or not slope < 0):
                # the exact LQ is not convex here (far from a minimizer): fall back to quasi-Newton
                newton = False
                K, Z, V, slope, minors = self._direction_at(x, u, False)
            if -slope < opts.tolerance:  # also catches a (round-off) slope >= 0 at the optimum
                if slope < 0:
                    # polish with the full Newton step: its decrease is below the round-off of g (a large
                    # terminal penalty), so Armijo cannot see it, but the step still moves x_N; without it a
                    # Newton update of the target x_T after a converged solve would not move the trajectory
                    xn, un, gn = self.project(x0, x + Z, u + V, K)
                    if np.isfinite(gn) and gn <= g + ROUNDOFF * max(abs(g), 1.0):
                        x, u, g, polished = xn, un, gn, True
                converged, message = True, "converged"
                break
            gamma = 1.0
            while True:
                xn, un, gn = self.project(x0, x + gamma * Z, u + gamma * V, K)
                if np.isfinite(gn) and gn <= g + opts.armijo_c * gamma * slope:
                    break
                gamma *= opts.armijo_beta
                if gamma < opts.min_step:
                    break
            history.append(ProntoIteration(g, slope, gamma, newton))
            if gamma < opts.min_step:
                message = "line search failed"
                break
            x, u, g = xn, un, gn
        if not converged:  # else K is the last direction's, about x (the polish moves x by a round-off-level step)
            K = self.feedback(x, u)
        return ProntoResult(x=x, u=u, K=K, cost=g, converged=converged, iterations=len(history),
                            solve_time_s=time.perf_counter() - start, history=tuple(history), message=message,
                            polished=polished)

    def terminal_response(self, x, u, K, dr) -> np.ndarray:
        """Sensitivity of the optimal final state to the terminal cost's gradient.

        At a minimizer (x (N+1, n), u (N, m), gains K (N, m, n)), a change dr (n, c) of the
        gradient of the terminal cost moves the minimizer's x_N by the returned (n, c) matrix
        (implicit function theorem: the Newton LQ with only that linear term).
        """
        dr = np.asarray(dr, float)
        return np.array(self._response(_cols(x), _cols(u), _kcols(K), self._P, self._theta, dr))

    # ---------------------------------------------------------------------------------------------
    # compiled graphs

    def _direction_at(self, x, u, newton: bool):
        out = self._direction(_cols(x), _cols(u), self._P, self._theta, 1.0 if newton else 0.0)
        K, Z, V, slope, minors = out
        m, n = self.ocp.m, self.ocp.n
        return (_unkcols(np.array(K), m, n), np.array(Z).T, np.array(V).T, float(slope), np.array(minors))

    def _build(self) -> None:
        ocp, opts = self.ocp, self.options
        n, m, N, n_p, n_t = ocp.n, ocp.m, ocp.N, ocp.n_p, ocp.n_theta
        self._P, self._theta = ca.DM.zeros(n_p, N), ca.DM.zeros(n_t)
        xs, us, ps, ts = ca.SX.sym("x", n), ca.SX.sym("u", m), ca.SX.sym("p", n_p), ca.SX.sym("theta", n_t)
        qs, s2 = ca.SX.sym("q", n), ca.SX.sym("second_order")
        fx = ocp.step(xs, us)
        l = ocp.stage(xs, us, ps, ts)
        mT = ocp.terminal(xs, ts)
        w = ca.vertcat(xs, us)
        A, B = ca.jacobian(fx, xs), ca.jacobian(fx, us)
        # common-subexpression elimination: the derivatives of an integrator step repeat many terms
        # (biped RK4: Jacobians 20.8k -> 13.5k instructions, Hessian 67.6k -> 54.9k); they dominate an iteration
        sx_opts = {"cse": True}
        lin = ca.Function("lin", [xs, us], [A, B], sx_opts)
        grad = ca.Function("grad", [xs, us, ps, ts], [ca.gradient(l, xs), ca.gradient(l, us)])
        # Hessian of l + second_order * q' f: the exact weight of PRONTO's second-order LQ
        hl = ca.hessian(l, w)[0]
        hf = ca.hessian(ca.dot(qs, fx), w)[0]
        hess = ca.Function("lagrangian_hessian", [xs, us, ps, ts, qs, s2], [hl + s2 * hf], sx_opts)
        term = ca.Function("term", [xs, ts], [mT, ca.gradient(mT, xs), ca.hessian(mT, xs)[0]])

        # closed-loop step of the projection: u = mu + K (alpha - x)
        Ks = ca.SX.sym("K", m, n)
        al, mu = ca.SX.sym("alpha", n), ca.SX.sym("mu", m)
        ucl = mu + ca.mtimes(Ks, al - xs)
        cl_step = ca.Function("cl_step", [xs, al, mu, Ks], [ocp.step(xs, ucl), ucl], sx_opts)
        roll = cl_step.mapaccum("projection", N)

        # LQR Riccati step for the projection feedback (per-step weights Qp, Rp)
        Qp, Rp = np.diag(opts.feedback_q), np.diag(opts.feedback_r)
        Pn, As, Bs = ca.SX.sym("P", n, n), ca.SX.sym("A", n, n), ca.SX.sym("B", n, m)
        Ruu = Rp + ca.mtimes([Bs.T, Pn, Bs])
        Kk = ca.solve(Ruu, ca.mtimes([Bs.T, Pn, As]))
        Pk = Qp + ca.mtimes([As.T, Pn, As]) - ca.mtimes([ca.mtimes(As.T, Pn), Bs, Kk])
        lqr = ca.Function("lqr", [Pn, As, Bs], [0.5 * (Pk + Pk.T), Kk]).mapaccum("lqr", N)

        # closed-loop costate step
        qn, ak, bk = ca.SX.sym("qn", n), ca.SX.sym("a", n), ca.SX.sym("b", m)
        qk = ak - ca.mtimes(Ks.T, bk) + ca.mtimes((As - ca.mtimes(Bs, Ks)).T, qn)
        costate = ca.Function("costate", [qn, ak, bk, As, Bs, Ks], [qk, qn]).mapaccum("costate", N)

        # LQ Riccati step (P, s) with a right-hand side of c columns, and its forward pass
        def lq_functions(c: int):
            sn, ac, bc = ca.SX.sym("s", n, c), ca.SX.sym("a", n, c), ca.SX.sym("b", m, c)
            H = ca.SX.sym("H", n + m, n + m)
            Qxx = H[:n, :n] + ca.mtimes([As.T, Pn, As])
            Qux = H[n:, :n] + ca.mtimes([Bs.T, Pn, As])
            Quu = H[n:, n:] + ca.mtimes([Bs.T, Pn, Bs])
            qu = bc + ca.mtimes(Bs.T, sn)
            Ko, kff = ca.solve(Quu, Qux), ca.solve(Quu, qu)
            Pk2 = Qxx - ca.mtimes(Qux.T, Ko)
            sk = ac + ca.mtimes(As.T, sn) - ca.mtimes(Qux.T, kff)
            minors = ca.vertcat(*[ca.det(Quu[:i, :i]) for i in range(1, m + 1)]) if m <= 4 else ca.SX.ones(1)
            back = ca.Function("lq_back", [Pn, sn, As, Bs, H, ac, bc], [0.5 * (Pk2 + Pk2.T), sk, Ko, kff, minors])
            zs, Kos, kfs = ca.SX.sym("z", n, c), ca.SX.sym("Ko", m, n), ca.SX.sym("kff", m, c)
            vk = -ca.mtimes(Kos, zs) - kfs
            fwd = ca.Function("lq_fwd", [zs, As, Bs, Kos, kfs], [ca.mtimes(As, zs) + ca.mtimes(Bs, vk), vk])
            return back.mapaccum("lq_back", N, 2), fwd.mapaccum("lq_fwd", N)

        lq_back1, lq_fwd1 = lq_functions(1)
        lq_backn, lq_fwdn = lq_functions(n)

        # --- MX graphs over the whole horizon ---
        X, U = ca.MX.sym("X", n, N + 1), ca.MX.sym("U", m, N)
        Pm, Th, S2 = ca.MX.sym("P", n_p, N), ca.MX.sym("theta", n_t), ca.MX.sym("second_order")
        x0m, Al, Mu, Km = ca.MX.sym("x0", n), ca.MX.sym("alpha", n, N), ca.MX.sym("mu", m, N), ca.MX.sym("K", m, n * N)
        Xr, Ur = roll(x0m, Al, Mu, Km)
        gcost = ca.sum2(ocp.stage.map(N)(ca.horzcat(x0m, Xr[:, :-1]), Ur, Pm, Th)) + ocp.terminal(Xr[:, -1], Th)
        self._project = ca.Function("project", [x0m, Al, Mu, Km, Pm, Th], [Xr, Ur, gcost])

        Xk = X[:, :N]
        Aall, Ball = lin.map(N)(Xk, U)  # (n, nN), (n, mN)

        def gains(Aall, Ball):
            _, Krev = lqr(ca.DM(Qp), _rev(Aall, n, N), _rev(Ball, m, N))
            return _rev(Krev, n, N)  # (m, nN)

        self._gains = ca.Function("gains", [X, U], [gains(Aall, Ball)])

        def lq_terms(Kall, second_order):
            a, b = grad.map(N)(Xk, U, Pm, Th)
            _, r1, P1 = term(X[:, N], Th)
            _, qnext_rev = costate(r1, _rev(a, 1, N), _rev(b, 1, N), _rev(Aall, n, N), _rev(Ball, m, N),
                                   _rev(Kall, n, N))
            qnext = _rev(qnext_rev, 1, N)
            H = hess.map(N)(Xk, U, Pm, Th, qnext, second_order)
            return a, b, r1, P1, H

        Kall = gains(Aall, Ball)
        a, b, r1, P1, H = lq_terms(Kall, S2)
        _, _, Korev, kffrev, minors = lq_back1(P1, r1, _rev(Aall, n, N), _rev(Ball, m, N), _rev(H, n + m, N), _rev(a, 1, N), _rev(b, 1, N))
        Ko, kff = _rev(Korev, n, N), _rev(kffrev, 1, N)
        Zr, Vr = lq_fwd1(ca.MX.zeros(n), Aall, Ball, Ko, kff)
        Z = ca.horzcat(ca.MX.zeros(n), Zr)
        slope = ca.sum1(ca.sum2(a * Z[:, :N])) + ca.sum1(ca.sum2(b * Vr)) + ca.dot(r1, Z[:, N])
        self._direction = ca.Function("direction", [X, U, Pm, Th, S2], [Kall, Z, Vr, slope, ca.mmin(minors)])

        # sensitivity of x_N to the terminal gradient: the Newton LQ with only that right-hand side
        Kin, dR = ca.MX.sym("Kin", m, n * N), ca.MX.sym("dR", n, n)
        a, b, r1, P1, H = lq_terms(Kin, 1.0)
        _, _, Korev, kffrev, _ = lq_backn(P1, dR, _rev(Aall, n, N), _rev(Ball, m, N), _rev(H, n + m, N),
                                         ca.MX.zeros(n, n * N), ca.MX.zeros(m, n * N))
        Zr, _ = lq_fwdn(ca.MX.zeros(n, n), Aall, Ball, _rev(Korev, n, N), _rev(kffrev, n, N))
        self._response = ca.Function("response", [X, U, Kin, Pm, Th, dR], [Zr[:, -n:]])


def _rev(M: ca.MX, width: int, N: int) -> ca.MX:
    """Reverse the order of N column blocks of the given width (backward sweeps run as mapaccum)."""
    idx = [j for k in reversed(range(N)) for j in range(k * width, (k + 1) * width)]
    return M[:, idx]


def _cols(a) -> np.ndarray:
    """Time-major (N, d) -> CasADi's column-per-step (d, N)."""
    a = np.asarray(a, float)
    return a.reshape(len(a), -1).T


def _kcols(K) -> np.ndarray:
    """Gains (N, m, n) -> horizontally stacked (m, n N)."""
    K = np.asarray(K, float)
    return np.concatenate(list(K), axis=1) if len(K) else np.zeros((0, 0))


def _unkcols(K: np.ndarray, m: int, n: int) -> np.ndarray:
    """(m, n N) -> (N, m, n)."""
    return K.reshape(m, -1, n).transpose(1, 0, 2)
