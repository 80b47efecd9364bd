"""The NLP's derivatives for IPOPT (nlpsol's grad_f, jac_g and hess_lag), derived at the size of a step.

CasADi derives a Hessian over the whole expression graph: on the default Capler task (N = 125) ~1 s for
the Lagrangian's Hessian and ~0.5 s for the constraints' Jacobian, most of creating an IPOPT. The
implicit-Euler steps are one Function called N times (Problem.stages), so their Jacobian and the
Hessian of their part of the Lagrangian are derived once for one step and mapped over the N steps; the
rest of the NLP (path rows, terminal, penalty rows, objective without the selectors' cost) is a tenth
of the graph and keeps CasADi's derivation. The pieces are summed into the global sparse matrices by
a constant 0/1 matrix on their nonzeros: ~0.2 s instead of ~1.5 s, the values equal to rounding. Rounding
moves a hint-free homotopy onto another path, so the homotopy keeps the whole-graph derivation unless
SolveOptions.derivation says otherwise; a replan's held-schedule NLP uses these (docs/benchmarks.md, session 26).
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from .problem import Problem


def _assemble(shape: tuple[int, int], pieces: list) -> tuple[ca.Sparsity, ca.MX]:
    """The sparsity of a sum of pieces (rows (n,), cols (n,), values: MX (n,)) and its nonzeros (MX, in that
    sparsity's column-major order): entries at the same (row, col) add up."""
    rows = np.concatenate([r for r, _, _ in pieces])
    cols = np.concatenate([c for _, c, _ in pieces])
    key, where = np.unique(cols * shape[0] + rows, return_inverse=True)
    sp = ca.Sparsity.triplet(shape[0], shape[1], (key % shape[0]).tolist(), (key // shape[0]).tolist())
    values = ca.vertcat(*[v for _, _, v in pieces])
    if key.size == rows.size:  # one piece per entry: a permutation
        return sp, values[np.argsort(where).tolist()]
    add = ca.DM(ca.Sparsity.triplet(key.size, rows.size, where.tolist(), list(range(rows.size))), 1.0)
    return sp, ca.mtimes(add, values)


def _entries(sp: ca.Sparsity, row_of: np.ndarray, col_of: np.ndarray, n_rows: int, nx: int):
    """A step's nonzeros (sparsity sp) at every k (k-major, as a mapped Function's outputs stack): their global
    rows and columns, and which to keep (not on y_0's constants, whose indices are >= nx)."""
    r, c = (np.array(a, dtype=int) for a in sp.get_triplet())
    R, C = row_of[:, r].ravel(), col_of[:, c].ravel()
    return R, C, np.flatnonzero((R < n_rows) & (C < nx))


def nlp_derivatives(problem: Problem, n_extra: int = 0, stepwise: bool = True) -> dict[str, ca.Function]:
    """nlpsol's options grad_f (x, p) -> (f, grad f), jac_g (x, p) -> (g, J) and hess_lag (x, p, lam_f, lam_g) ->
    triu(H) for x (nx + n_extra,) = (problem.x, n_extra variables that appear nowhere). stepwise: derived step by
    step (equal to CasADi's derivation to rounding, tests/test_derivatives.py); False, a problem without
    Problem.stages (FESD) or one whose f or g was edited after the build (Problem.edited: the stages hold the built
    ones; a cost term added was missing from the Hessian): CasADi's derivation over the whole graph."""
    pb, nx = problem, problem.nx
    n = nx + n_extra
    x_sx = ca.vertcat(pb.x, ca.SX.sym("extra", n_extra))
    oracle = ca.Function("nlp", [x_sx, pb.p], [pb.f, pb.g], ["x", "p"], ["f", "g"])
    grad_f = oracle.factory("nlp_grad_f", ["x", "p"], ["f", "grad:f:x"])
    st = pb.stages
    if st is None or not stepwise or {"f", "g"} & set(pb.edited):
        return {"grad_f": grad_f, "jac_g": oracle.factory("nlp_jac_g", ["x", "p"], ["g", "jac:g:x"]),
                "hess_lag": oracle.factory("nlp_hess_l", ["x", "p", "lam:f", "lam:g"], ["triu:hess:gamma:x:x"], {"gamma": ["f", "g"]})}

    N, nz = st.z_index.shape
    m = st.rows.shape[1]
    x, p, lam_f, lam_g = ca.MX.sym("x", n), ca.MX.sym("p", pb.p.numel()), ca.MX.sym("lam_f"), ca.MX.sym("lam_g", pb.ng)
    xa = ca.vertcat(x[:nx], ca.DM(pb.y0))
    Z = ca.reshape(xa[st.z_index.ravel().tolist()], nz, N)
    P = ca.repmat(p, 1, N)
    rest = np.setdiff1d(np.arange(pb.ng), st.rows.ravel())
    g_rest = pb.g[rest.tolist()]

    # one step: z -> (rows, cost); its Jacobian and its Lagrangian's Hessian as Functions of their nonzeros
    z, ps, lam_k, w = ca.SX.sym("z", nz), ca.SX.sym("p", pb.p.numel()), ca.SX.sym("lam", m), ca.SX.sym("w")
    g_k, cost_k = st.fn(z, ps)
    J_k = ca.jacobian(g_k, z)
    H_k = ca.triu(ca.hessian(ca.dot(lam_k, g_k) + w * cost_k, z)[0])
    J_map = ca.Function("step_jac", [z, ps], [g_k, J_k.nz[:]]).map(N)
    H_map = ca.Function("step_hess", [z, ps, lam_k, w], [H_k.nz[:]]).map(N)
    lam_f_sx, lam_rest = ca.SX.sym("lam_f"), ca.SX.sym("lam_rest", rest.size)
    J_rest = ca.jacobian(g_rest, pb.x)
    H_rest = ca.triu(ca.hessian(lam_f_sx * st.f_rest + ca.dot(lam_rest, g_rest), pb.x)[0])
    J_rest_fn = ca.Function("rest_jac", [pb.x, pb.p], [g_rest, J_rest.nz[:]])
    H_rest_fn = ca.Function("rest_hess", [pb.x, pb.p, lam_f_sx, lam_rest], [H_rest.nz[:]])

    # Jacobian: the steps' rows (mapped) and the rest's
    R, C, keep = _entries(J_k.sparsity(), st.rows, st.z_index, pb.ng, nx)
    jr, jc = (np.array(a, dtype=int) for a in J_rest.sparsity().get_triplet())
    (g_steps, J_steps), (g_r, J_r) = J_map(Z, P), J_rest_fn(x[:nx], p)
    sp_J, J_nz = _assemble((pb.ng, n), [(R[keep], C[keep], ca.vec(J_steps)[keep.tolist()]), (rest[jr], jc, J_r)])
    _, g = _assemble((pb.ng, 1), [(st.rows.ravel(), np.zeros(st.rows.size, dtype=int), ca.vec(g_steps)),
                                  (rest, np.zeros(rest.size, dtype=int), g_r)])
    jac_g = ca.Function("nlp_jac_g", [x, p], [g, ca.sparsity_cast(J_nz, sp_J)], ["x", "p"], ["g", "jac_g_x"])

    # Hessian of the Lagrangian, upper triangle: the steps' (mapped) and the rest's
    R, C, keep = _entries(H_k.sparsity(), st.z_index, st.z_index, nx, nx)
    LAM = ca.reshape(lam_g[st.rows.ravel().tolist()], m, N)
    W = ca.repmat(lam_f * p[st.cost_weight], 1, N)
    hr, hc = (np.array(a, dtype=int) for a in H_rest.sparsity().get_triplet())
    sp_H, H_nz = _assemble((n, n), [(np.minimum(R, C)[keep], np.maximum(R, C)[keep], ca.vec(H_map(Z, P, LAM, W))[keep.tolist()]),
                                    (hr, hc, H_rest_fn(x[:nx], p, lam_f, lam_g[rest.tolist()]))])
    hess_lag = ca.Function("nlp_hess_l", [x, p, lam_f, lam_g], [ca.sparsity_cast(H_nz, sp_H)],
                           ["x", "p", "lam_f", "lam_g"], ["triu_hess_gamma_x_x"])
    return {"grad_f": grad_f, "jac_g": jac_g, "hess_lag": hess_lag}
