"""The regularized implicit Euler step (paper eq. 24) as reusable NLP pieces.

One step from y_k to y_{k+1} with control u_k, speed of time s_k and step h [s of numerical time]:

    y_{k+1} = y_k + h s_k F(y_{k+1}, Theta_{k+1}, u_k)           (24b, lifted)
    h_i(y_{k+1}, u_k) = lambda1_i - lambda0_i                    (24c: KKT of min -h_i w, 0 <= w <= 1)
    0 <= lambda0_i  _|_  sigma_i >= 0,  0 <= lambda1_i  _|_  1 - sigma_i >= 0      (24d, 24e)
    objective rho_f ||sigma_{k+1} - sigma*||^2                  (24a)

Lifting (Sec. 5.1): F = sum_j P_j(sigma) f_j with multi-affine P_j. Every monomial of degree >= 2
(e.g. alpha beta gamma) becomes an algebraic variable theta_m with the bilinear constraint
theta_m = theta_{m without its last factor} * sigma_{last factor}, so that F = Fmat(y, u) C z is linear
in z = (1, sigma, theta) with a constant matrix C.

`ImplicitEulerStep(system, rho_f).build(y_k, y_next, u_k, s_k, h)` returns a `Step` with the
algebraic variables (bounds, initial guess, names), the equality constraints, the complementarity
pairs and the objective term, each as named blocks; an OCP concatenates N of them and adds its own
complementarity penalty or relaxation; `planner.simulate` does the same for one step or a horizon.
"""
from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import casadi as ca
import numpy as np

from .timefreezing import ContactModel, TimeFreezingSystem

# The algebraic variables of a step, in this order (StepForm.MASS_MATRIX appends "forces").
W_BLOCKS = ("sigma", "theta", "lambda0", "lambda1")


class StepForm(Enum):
    """How the step writes the velocity rows of y' = F.

    EXPLICIT: v_{k+1} - v_k = h s F_v with the fields' M(q)^-1 inside (symbolic inverse).
    MASS_MATRIX: M(q_{k+1}) (v_{k+1} - v_k) = h s sum_j P_j g_j with generalized forces g_j, and the
    free acceleration, the contact forces and M^-1 J^T lambda as algebraic variables of the step
    (TimeFreezingSystem.mass_matrix_form); same solutions, much cheaper derivatives.
    """

    EXPLICIT = "explicit"
    MASS_MATRIX = "mass_matrix"


class SwitchVelocity(Enum):
    """Which contact-point velocity the switching functions n^T v and t^T v of a step use.

    POINT: n(q_{k+1})^T v_{k+1}, the paper's eq. 24c. In persistent contact the step keeps
    n^T v_{k+1} = 0 but the gap still moves by the curvature term, c_{k+1} - c_k ~ -1/2 dq^T grad^2 c dq
    per step (dq = q_{k+1} - q_k): the foot sinks into the ground step after step (2 cm over a Capler
    stance at h = 0.02), and an exactly complementary plan cannot end standing at c = 0 after moving.
    SECANT: nbar^T v_{k+1} with nbar = the gradient of the point's height (t: of its x) averaged over
    the segment q_k -> q_{k+1} by 3-point Gauss-Legendre quadrature, so that c_{k+1} - c_k = nbar^T dq
    up to O(|dq|^7): a step in persistent contact keeps the gap (and, no slip, the foot's x) where it
    was. When q does not move (a frozen impact) nbar = n(q): the same as POINT. Same switching
    surfaces in continuous time (the average tends to n(q) as h -> 0).
    """

    POINT = "point"
    SECANT = "secant"


# 3-point Gauss-Legendre rule on [0, 1]: exact for polynomials of degree 5
_GAUSS_S = (0.5 - 0.1 * 15**0.5, 0.5, 0.5 + 0.1 * 15**0.5)
_GAUSS_W = (5.0 / 18.0, 4.0 / 9.0, 5.0 / 18.0)

# The equality constraints of a step, in this order (StepForm.MASS_MATRIX appends "contact_forces").
G_BLOCKS = ("dynamics", "stationarity", "lifting")


@dataclass(frozen=True, eq=False)
class Step:
    """NLP pieces of one regularized implicit-Euler step (symbolic, SX or MX like the inputs).

    w (nw,) algebraic variables, blocks `w_blocks[name]` (slices) for sigma (n_sigma,), theta
    (lifted products), lambda0, lambda1 (n_sigma,); w_names (nw,); lbw, ubw (nw,) bounds; w0 (nw,)
    default initial guess (sigma = sigma*, consistent products, zero multipliers; see
    ImplicitEulerStep.guess for a guess consistent with a state).
    g (ng,) equality constraints g = 0, blocks `g_blocks`: dynamics (ny,), stationarity (n_sigma,),
    lifting (n_theta,).
    complementarity: pairs (a, b) of scalar expressions with a, b >= 0 by the bounds; a * b = 0 wanted.
    objective: rho_f ||sigma - sigma*||^2.
    """

    w: object
    w_names: tuple[str, ...]
    w_blocks: dict[str, slice]
    lbw: np.ndarray
    ubw: np.ndarray
    w0: np.ndarray
    g: object
    g_blocks: dict[str, slice]
    complementarity: tuple[tuple[object, object], ...]
    objective: object

    def block(self, name: str):
        """The variables of block `name` (sigma, theta, lambda0, lambda1)."""
        return self.w[self.w_blocks[name]]

    @property
    def sigma(self):
        return self.block("sigma")

    def comp_products(self):
        """vertcat of a * b over the complementarity pairs."""
        return ca.vertcat(*[a * b for a, b in self.complementarity])


class ImplicitEulerStep:
    """Builder of regularized implicit-Euler steps for a time-freezing system.

    rho_f >= 0 weights ||sigma - sigma*||^2 (paper: 1; 0 gives the plain implicit Euler MPCC).
    switch_scale (n_sigma,) > 0 optionally divides the switching functions in the stationarity
    condition (theta(h / a) = theta(h) for a > 0; it rescales the multipliers, not the solution).
    form: StepForm (EXPLICIT by default; MASS_MATRIX adds the block "forces" to w and the
    equality block "contact_forces"). velocity_switch: SwitchVelocity (POINT by default, the paper's).
    """

    def __init__(self, system: TimeFreezingSystem, rho_f: float = 1.0, switch_scale=None, form: StepForm = StepForm.EXPLICIT,
                 velocity_switch: SwitchVelocity = SwitchVelocity.POINT):
        if rho_f < 0:
            raise ValueError(f"rho_f must be >= 0, got {rho_f}")
        if not isinstance(velocity_switch, SwitchVelocity):
            raise ValueError(f"velocity_switch must be one of {[m.value for m in SwitchVelocity]}, got {velocity_switch!r}")
        self.system, self.rho_f, self.form, self.velocity_switch = system, float(rho_f), form, velocity_switch
        self._secant = _secant_rows(system) if velocity_switch is SwitchVelocity.SECANT else None
        self.mm = system.mass_matrix_form() if form is StepForm.MASS_MATRIX else None
        nz = self.mm.nz if self.mm is not None else 0
        n = system.n_sigma
        self.switch_scale = np.ones(n) if switch_scale is None else np.asarray(switch_scale, dtype=float).reshape(n)
        if np.any(self.switch_scale <= 0):
            raise ValueError("switch_scale must be > 0")
        # monomials: constant, the selectors, then lifted products with all their prefixes
        lifted: set[tuple[int, ...]] = set()
        for poly in system.coefficients.values():
            for m in poly.terms:
                for k in range(2, len(m) + 1):
                    lifted.add(m[:k])
        self.lifted = tuple(sorted(lifted, key=lambda m: (len(m), m)))
        self.monomials = ((),) + tuple((i,) for i in range(n)) + self.lifted
        index = {m: j for j, m in enumerate(self.monomials)}
        # C (n_fields, n_monomials): P_j(sigma) = sum_m C[j, m] z_m
        C = np.zeros((system.n_fields, len(self.monomials)))
        for j, f in enumerate(system.fields):
            for m, c in system.coefficients[f.name].terms.items():
                C[j, index[m]] = c
        self.C = C
        self.n_theta = len(self.lifted)
        self.nw = 3 * n + self.n_theta + nz
        names = [s.name for s in system.switches]
        self.theta_names = tuple("*".join(names[i] for i in m) for m in self.lifted)
        sizes = {"sigma": n, "theta": self.n_theta, "lambda0": n, "lambda1": n, "forces": nz}
        self.w_blocks, start = {}, 0
        for b in W_BLOCKS + (("forces",) if nz else ()):
            self.w_blocks[b] = slice(start, start + sizes[b])
            start += sizes[b]
        self.w_names = tuple(list(names) + list(self.theta_names) + [f"lambda0[{s}]" for s in names] + [f"lambda1[{s}]" for s in names]
                             + (list(self.mm.z_names) if nz else []))
        self.lbw = np.concatenate([np.zeros(n), np.zeros(self.n_theta), np.zeros(2 * n), np.full(nz, -np.inf)])
        self.ubw = np.concatenate([np.ones(n), np.ones(self.n_theta), np.full(2 * n, np.inf), np.full(nz, np.inf)])
        self.w0 = self.w_from(system.wanted, np.zeros(n), np.zeros(n))

    def w_from(self, sigma, lam0, lam1, forces=None) -> np.ndarray:
        """Algebraic variables (nw,) from numeric selectors and multipliers (n_sigma,) each; theta = products;
        forces (MASS_MATRIX only, nz,) default zeros."""
        theta = [np.prod([sigma[i] for i in m]) for m in self.lifted]
        nz = self.mm.nz if self.mm is not None else 0
        forces = np.zeros(nz) if forces is None else np.asarray(forces, float).ravel()
        return np.concatenate([sigma, theta, lam0, lam1, forces]).astype(float)

    def forces_at(self, y, u) -> np.ndarray:
        """MASS_MATRIX: the algebraic force variables (nz,) that solve `defining` at numeric y, u."""
        sys_, nq, nv = self.system, self.system.nq, self.system.nv
        q, v = np.asarray(y, float)[:nq], np.asarray(y, float)[nq : nq + nv]
        M = np.asarray(sys_.dyn.mass(q), float)
        acc = np.asarray(sys_.dyn.forward(q, v, u), float).ravel()
        lam, ds = [], []
        for model, terms in zip(sys_.models, sys_.terms):
            no_slip = model is ContactModel.NO_SLIP
            fn = ca.Function("forces", [sys_.y, sys_.u], [terms.lambda_no_slip if no_slip else terms.lambda_n, terms.normal, terms.tangent])
            lam_c, n_c, t_c = (np.asarray(a, float).ravel() for a in fn(y, u))
            J = np.vstack([n_c, t_c]) if no_slip else n_c[None, :]
            lam.append(lam_c)
            ds.append(np.linalg.solve(M, J.T @ lam_c))
        return np.concatenate([acc, *lam, *ds])

    def guess(self, y, u) -> np.ndarray:
        """Initial guess (nw,) consistent with the switching functions at a numeric state y (ny,), u (nu,):
        sigma = 1 where h > 0, 0 where h < 0, sigma* where h = 0; lambda1 = max(h, 0), lambda0 = max(-h, 0);
        MASS_MATRIX: the force variables that solve their equations at (y, u)."""
        hval = np.asarray(self.system.switching_fn(y, u), dtype=float).ravel() / self.switch_scale
        sigma = np.where(hval > 0, 1.0, np.where(hval < 0, 0.0, self.system.wanted))
        forces = self.forces_at(y, u) if self.mm is not None else None
        return self.w_from(sigma, np.maximum(-hval, 0.0), np.maximum(hval, 0.0), forces)

    def build(self, y_k, y_next, u_k, s_k=1.0, h: float = 0.01, tag: str = "", field_scale=None) -> Step:
        """Create the step's algebraic variables and its constraints (see module docstring).

        y_k, y_next (ny,), u_k (nu,), s_k (scalar) are CasADi expressions (SX or MX) or numbers;
        h [s] the numerical-time step. The new variables are SX symbols unless y_next is MX.
        `tag` is appended to the variable names (e.g. the step index). field_scale (n_fields,)
        optionally multiplies each field's coefficient P_j (an OCP uses it to continue the auxiliary
        gains a_n, a_t from weak to the task's values; 1 everywhere is the task's system).
        """
        sys_ = self.system
        sym = ca.MX.sym if isinstance(y_next, ca.MX) else ca.SX.sym
        w = sym(f"w{tag}", self.nw)
        sigma, theta = w[self.w_blocks["sigma"]], w[self.w_blocks["theta"]]
        lam0, lam1 = w[self.w_blocks["lambda0"]], w[self.w_blocks["lambda1"]]
        z = ca.vertcat(1, sigma, theta)  # the monomials, in self.monomials order
        coef = ca.mtimes(ca.DM(self.C), z)
        if field_scale is not None:
            coef = coef * field_scale
        extra = []
        if self.mm is None:
            F = ca.mtimes(sys_.fields_fn(y_next, u_k), coef)
            dynamics = y_next - y_k - h * s_k * F
            hval = sys_.switching_fn(y_next, u_k)
        else:
            nq, nv = sys_.nq, sys_.nv
            fmat, hval, defining, M = self.mm.fn(y_next, u_k, w[self.w_blocks["forces"]])
            F = ca.mtimes(fmat, coef)
            dy = y_next - y_k
            dv = ca.mtimes(M, dy[nq : nq + nv])  # velocity rows times M(q_{k+1}): no inverse
            dynamics = ca.vertcat(dy[:nq], dv, dy[nq + nv :]) - h * s_k * F
            extra = [defining]
        if self._secant is not None:
            nq, nv = sys_.nq, sys_.nv
            rows, mask = self._secant
            hval = hval * ca.DM(1.0 - mask) + ca.mtimes(rows(y_k[:nq], y_next[:nq]), y_next[nq : nq + nv])
        stationarity = hval / ca.DM(self.switch_scale) - lam1 + lam0
        index = {m: j for j, m in enumerate(self.monomials)}
        lifting = [z[index[m]] - z[index[m[:-1]]] * sigma[m[-1]] for m in self.lifted]
        g = ca.vertcat(dynamics, stationarity, *lifting, *extra)
        ny, n = sys_.ny, sys_.n_sigma
        g_blocks = {"dynamics": slice(0, ny), "stationarity": slice(ny, ny + n), "lifting": slice(ny + n, ny + n + self.n_theta)}
        if extra:
            start = ny + n + self.n_theta
            g_blocks["contact_forces"] = slice(start, start + extra[0].shape[0])
        comp = tuple((lam0[i], sigma[i]) for i in range(n)) + tuple((lam1[i], 1 - sigma[i]) for i in range(n))
        dev = sigma - ca.DM(sys_.wanted)
        objective = self.rho_f * ca.dot(dev, dev)
        names = tuple(f"{nm}{tag}" for nm in self.w_names)
        return Step(w=w, w_names=names, w_blocks=dict(self.w_blocks), lbw=self.lbw.copy(), ubw=self.ubw.copy(), w0=self.w0.copy(),
                    g=g, g_blocks=g_blocks, complementarity=comp, objective=objective)

    def coefficients(self, w) -> np.ndarray:
        """Numeric field coefficients P_j (n_fields,) of a solved step from its algebraic variables w (nw,)."""
        w = np.asarray(w, dtype=float).ravel()
        z = np.concatenate([[1.0], w[self.w_blocks["sigma"]], w[self.w_blocks["theta"]]])
        return self.C @ z


def _secant_rows(system: TimeFreezingSystem) -> tuple[ca.Function, np.ndarray]:
    """SwitchVelocity.SECANT: Function (q_a, q_b) -> (n_sigma, nv) whose row i is the Gauss-averaged
    gradient of switch i's coordinate (height for n^T v, x for t^T v) over the segment q_a -> q_b (zero
    rows for the other switches), and the (n_sigma,) mask of the rows it replaces."""
    nq, nv = system.nq, system.nv
    qa, qb = ca.SX.sym("q_a", nq), ca.SX.sym("q_b", nq)
    coord = {"n^T v": 2, "t^T v": 0}
    rows, mask = [], np.zeros(system.n_sigma)
    for i, sw in enumerate(system.switches):
        if sw.function not in coord or sw.contact is None:
            rows.append(ca.SX.zeros(1, nv))
            continue
        jac = system.dyn.point_jacobian(sw.contact)
        rows.append(sum(w * jac(qa + s * (qb - qa))[coord[sw.function], :] for s, w in zip(_GAUSS_S, _GAUSS_W)))
        mask[i] = 1.0
    return ca.Function("secant_rows", [qa, qb], [ca.vertcat(*rows)], ["q_a", "q_b"], ["rows"]), mask
