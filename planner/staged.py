"""The implicit-Euler OCP re-expressed stage by stage for FATROP (prototype; docs/benchmarks.md, "FATROP").

FATROP (`ca.nlpsol(name, "fatrop", nlp, opts)`) solves NLPs of the form

    x = (x_0, u_0, x_1, u_1, ..., x_{N-1}, u_{N-1}, x_N)
    g = (x_1 - F_0(x_0, u_0), G_0(x_0, u_0), x_2 - F_1(x_1, u_1), G_1(x_1, u_1), ..., G_N(x_N))

with a Lagrangian Hessian that is block diagonal in the (x_k, u_k). `build_problem`'s NLP is not of
that form: g is ordered by block (all dynamics rows, then stationarity, ...), the implicit Euler step
couples y_k and y_{k+1} in rows that are not gap-closing, and the l_inf slack s_c is one variable in
every stage's penalty rows. `staged_nlp(problem)` re-expresses the built Problem without changing it
(the Problem's own SX expressions, with the variables substituted stage by stage):

    states   x_k = (y_k, s_{c,k})         (k = 0: s_{c,0} only, y_0 is the task's constant)
    controls u_k = (u_k, s_k, w_k, z_k)   z_k the stage-local copy of y_{k+1} (s_k with physical time)
    gap      y_{k+1} - z_k = 0,  s_{c,k+1} - s_{c,k} = 0
    path     stage k's rows of every block (dynamics, stationarity, lifting, contact_forces,
             above_ground, holes, never_touching, friction_cone, impact_cone, penalty) with
             y_k -> state y_k, y_{k+1} -> z_k, s_c -> s_{c,k}
    stage N  terminal (and physical_time) rows on y_N
    f        the Problem's f with y_N -> state y_N and s_c -> s_{c,0}

Bounds of y_{k+1} go on z_k (where the step is evaluated); the state copies are free; s_c >= 0 on
s_{c,0} only. At a point lifted from the original x (`lift`), f and the path rows equal the original
f and g (`g_rows` maps the path rows to the original rows) and the gap rows are 0.

Not covered (InputError): FESD stages, plan.periodic (y_0 would have to be carried to the last
stage), an objective or row that couples stages in another way (checked: every substituted
expression is verified to be free of the original variables).
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from .errors import InputError
from .problem import Problem

_STEP_BLOCKS = ("dynamics", "stationarity", "lifting", "contact_forces")
_PATH_BLOCKS = ("above_ground", "holes", "never_touching", "friction_cone", "impact_cone", "penalty")
_FINAL_BLOCKS = ("terminal", "physical_time")


@dataclass(eq=False)
class StagedNlp:
    """The stage-ordered NLP: x (nx,), p, f, g with bounds lbx, ubx, lbg, ubg (lbg/ubg for the
    original rows taken from the Problem: `bounds` recomputes them from other lbg/ubg), and the
    FATROP structure N, nxs, nus, ngs (manual structure detection).

    x_src (nx,): index into the original x of every new variable (z_k and the state y_{k+1} both map
    to y_{k+1}, every s_{c,k} to s_c); -1 never occurs. g_src (ng,): the original row of every new
    row, -1 for a gap row. x_main (original nx,): the new index that gives each original variable
    back (z_k for y_{k+1}, s_{c,0} for s_c)."""

    problem: Problem
    x: ca.SX
    p: ca.SX
    f: ca.SX
    g: ca.SX
    lbx: np.ndarray
    ubx: np.ndarray
    lbg: np.ndarray
    ubg: np.ndarray
    x_src: np.ndarray
    g_src: np.ndarray
    x_main: np.ndarray
    N: int
    nxs: list
    nus: list
    ngs: list

    @property
    def nlp(self) -> dict:
        return {"x": self.x, "p": self.p, "f": self.f, "g": self.g}

    def fatrop_options(self, **fatrop) -> dict:
        """nlpsol options for FATROP with this structure; keyword arguments go to FATROP itself."""
        return {"structure_detection": "manual", "N": self.N, "nx": self.nxs, "nu": self.nus, "ng": self.ngs,
                "print_time": False, "fatrop": dict(fatrop)}

    def lift(self, x_orig) -> np.ndarray:
        """The staged x of an original x (the copies z_k, y_{k+1} and every s_{c,k} take its value)."""
        return np.asarray(x_orig, float).ravel()[self.x_src]

    def restrict(self, x_new) -> np.ndarray:
        """The original x of a staged x (z_k for y_{k+1}, s_{c,0} for s_c)."""
        return np.asarray(x_new, float).ravel()[self.x_main]

    def without_free_rows(self, lbg_orig, ubg_orig) -> "StagedNlp":
        """The same NLP without the rows whose bounds (from the original lbg_orig, ubg_orig) are both
        infinite, e.g. the terminal rows of a soft-terminal NLP (they constrain nothing; FATROP would
        carry an unbounded slack for each)."""
        lo, hi = self.bounds(lbg_orig, ubg_orig)
        keep = ~(np.isneginf(lo) & np.isposinf(hi))
        if keep.all():
            return self
        stage_of_row, row = np.empty(len(keep), int), 0
        for k in range(self.N + 1):
            n = (self.nxs[k + 1] if k < self.N else 0) + self.ngs[k]
            stage_of_row[row:row + n] = k
            row += n
        ngs = [int(n - np.sum(~keep & (stage_of_row == k))) for k, n in enumerate(self.ngs)]
        idx = np.flatnonzero(keep)
        return StagedNlp(problem=self.problem, x=self.x, p=self.p, f=self.f, g=self.g[idx.tolist()], lbx=self.lbx, ubx=self.ubx,
                         lbg=self.lbg[idx], ubg=self.ubg[idx], x_src=self.x_src, g_src=self.g_src[idx], x_main=self.x_main,
                         N=self.N, nxs=self.nxs, nus=self.nus, ngs=ngs)

    def bounds(self, lbg_orig, ubg_orig) -> tuple[np.ndarray, np.ndarray]:
        """Staged lbg, ubg for the original rows' bounds lbg_orig, ubg_orig (gap rows: 0)."""
        return _row_bounds(self.g_src, lbg_orig, ubg_orig)


def _row_bounds(g_src: np.ndarray, lbg_orig, ubg_orig) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = np.zeros(len(g_src)), np.zeros(len(g_src))
    rows = g_src >= 0
    lo[rows], hi[rows] = np.asarray(lbg_orig, float)[g_src[rows]], np.asarray(ubg_orig, float)[g_src[rows]]
    return lo, hi


def staged_nlp(problem: Problem) -> StagedNlp:
    """The Problem's NLP in FATROP's stage order (module docstring). Raises InputError for what it
    does not cover."""
    pb = problem
    if pb.fesd is not None:
        raise InputError("staged_nlp: FESD stages are not covered (implicit Euler only)")
    if "y0" in pb.var_blocks:
        raise InputError("staged_nlp: plan.periodic is not covered (y_0 would couple stage 0 and the last stage)")
    vb, gb, N = pb.var_blocks, pb.g_blocks, pb.N
    known = set(_STEP_BLOCKS + _PATH_BLOCKS + _FINAL_BLOCKS)
    if set(gb) - known:
        raise InputError(f"staged_nlp: constraint blocks {sorted(set(gb) - known)} are not covered")
    X = pb.x
    ny = vb["y"].shape[1]
    has_s, linf = "s" in vb, "s_c" in vb
    ctrl_blocks = ["u"] + (["s"] if has_s else []) + ["w"]

    def syms(idx):
        return ca.vertcat(*[X[int(i)] for i in np.ravel(idx)]) if np.size(idx) else ca.SX(0, 1)

    xs, x_src, lbx, ubx = [], [], [], []
    nxs, nus, ngs = [], [], []
    new_y, new_sc, new_z = {}, {}, {}  # stage -> SX

    def add(sym, src, lo, hi):
        xs.append(sym)
        x_src.extend(np.asarray(src, int).ravel().tolist())
        lbx.extend(np.broadcast_to(lo, (sym.shape[0],)).tolist())
        ubx.extend(np.broadcast_to(hi, (sym.shape[0],)).tolist())

    # --- variables in FATROP order ----------------------------------------------------------------
    ctrl = {}
    for k in range(N + 1):
        n_state = 0
        if k > 0:
            new_y[k] = ca.SX.sym(f"Y_{k}", ny)
            add(new_y[k], vb["y"][k - 1], -np.inf, np.inf)
            n_state += ny
        if linf:
            new_sc[k] = ca.SX.sym(f"sc_{k}")
            sc_i = int(vb["s_c"][0])
            add(new_sc[k], [sc_i], pb.lbx[sc_i] if k == 0 else -np.inf, pb.ubx[sc_i] if k == 0 else np.inf)
            n_state += 1
        nxs.append(n_state)
        if k == N:
            nus.append(0)
            break
        n_ctrl = 0
        ctrl[k] = {}
        for name in ctrl_blocks:
            idx = vb[name][k]
            sym = ca.SX.sym(f"{name.upper()}_{k}", len(idx))
            ctrl[k][name] = sym
            add(sym, idx, pb.lbx[idx], pb.ubx[idx])
            n_ctrl += len(idx)
        new_z[k] = ca.SX.sym(f"Z_{k}", ny)
        add(new_z[k], vb["y"][k], pb.lbx[vb["y"][k]], pb.ubx[vb["y"][k]])
        n_ctrl += ny
        nus.append(n_ctrl)
    Xn = ca.vertcat(*xs)
    x_src = np.array(x_src, int)

    def stage_map(k: int, prev: bool):
        """(old symbols, new expressions) of stage k: y_{k+1} -> z_k, u, s, w -> stage controls,
        s_c -> s_{c,k}; prev: also y_k -> state y_k (k >= 1)."""
        old, new = [], []
        for name in ctrl_blocks:
            old.append(syms(vb[name][k]))
            new.append(ctrl[k][name])
        old.append(syms(vb["y"][k]))
        new.append(new_z[k])
        if prev and k > 0:
            old.append(syms(vb["y"][k - 1]))
            new.append(new_y[k])
        if linf:
            old.append(syms(vb["s_c"]))
            new.append(new_sc[k])
        return ca.vertcat(*old), ca.vertcat(*new)

    def subst(ex, old, new, what):
        out = ca.substitute(ex, old, new)
        if ca.depends_on(out, X):
            raise InputError(f"staged_nlp: {what} depends on variables of another stage")
        return out

    # --- rows, stage by stage ---------------------------------------------------------------------
    g_parts, g_src = [], []
    for k in range(N):
        # gap rows of the next state: y_{k+1} - z_k, s_{c,k+1} - s_{c,k}
        g_parts.append(new_y[k + 1] - new_z[k])
        g_src += [-1] * ny
        if linf:
            g_parts.append(new_sc[k + 1] - new_sc[k])
            g_src.append(-1)
        rows = np.concatenate([gb[name][k] for name in _STEP_BLOCKS + _PATH_BLOCKS if name in gb])
        old, new = stage_map(k, prev=True)
        g_parts.append(subst(pb.g[rows.tolist()], old, new, f"stage {k}'s rows"))
        g_src += rows.tolist()
        ngs.append(len(rows))
    final = np.concatenate([gb[name].ravel() for name in _FINAL_BLOCKS if name in gb] or [np.zeros(0, int)]).astype(int)
    old_N, new_N = [syms(vb["y"][N - 1])], [new_y[N]]
    if linf:
        old_N.append(syms(vb["s_c"]))
        new_N.append(new_sc[N])
    if len(final):
        g_parts.append(subst(pb.g[final.tolist()], ca.vertcat(*old_N), ca.vertcat(*new_N), "the terminal rows"))
    g_src += final.tolist()
    ngs.append(len(final))
    G = ca.vertcat(*g_parts)
    g_src = np.array(g_src, int)

    # --- objective: every stage's variables, y_N as the last state, s_c as s_{c,0} ------------------
    old, new = [], []
    for k in range(N):
        for name in ctrl_blocks:
            old.append(syms(vb[name][k]))
            new.append(ctrl[k][name])
    old.append(syms(vb["y"][N - 1]))
    new.append(new_y[N])
    if linf:
        old.append(syms(vb["s_c"]))
        new.append(new_sc[0])
    F = subst(pb.f, ca.vertcat(*old), ca.vertcat(*new), "the objective (states other than y_N)")

    # the original variable of every new column: z_k for y_{k+1}, s_{c,0} for s_c
    x_main = np.full(pb.nx, -1, int)
    first = {}
    for j, src in enumerate(x_src):
        first.setdefault(int(src), j)
    offs = np.cumsum([0] + [a + b for a, b in zip(nxs, nus)])
    for k in range(N):
        z_start = offs[k] + nxs[k] + nus[k] - ny
        x_main[vb["y"][k]] = np.arange(z_start, z_start + ny)
    for name in ctrl_blocks:
        for k in range(N):
            for i in vb[name][k]:
                x_main[int(i)] = first[int(i)]
    if linf:
        x_main[int(vb["s_c"][0])] = first[int(vb["s_c"][0])]
    assert (x_main >= 0).all() and (x_src[x_main] == np.arange(pb.nx)).all()
    lbg, ubg = _row_bounds(g_src, pb.lbg, pb.ubg)
    return StagedNlp(problem=pb, x=Xn, p=pb.p, f=F, g=G, lbx=np.array(lbx), ubx=np.array(ubx), lbg=lbg, ubg=ubg,
                     x_src=x_src, g_src=g_src, x_main=x_main, N=N, nxs=nxs, nus=nus, ngs=ngs)
