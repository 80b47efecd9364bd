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

import math
from dataclasses import dataclass, field
from enum import Enum

import casadi as ca
import numpy as np

from .contact import plane_axes
from .errors import InputError, check_field_types, enum_member, shown
from .result import ON_PLANE_M
from .timefreezing import ContactModel, TimeFreezingSystem

# The algebraic variables of a step, in this order (StepForm.MASS_MATRIX appends "forces").
W_BLOCKS = ("sigma", "theta", "lambda0", "lambda1")


# The several-contact guesses below start hint-free solves whose path depends on the last bits of the start
# (the biped walk, FESD steps with two feet). numpy's small solves and products go through the BLAS kernels
# its OpenBLAS picks for the CPU (Haswell or SkylakeX ones: different round-off; with Haswell's the biped walk
# did not converge, docs/formulation.md "Periodic walking"); CasADi's dense solve and product are the same
# code on every machine.
def _solve(A, b) -> np.ndarray:
    """A^-1 b (n,) for a small dense A (n, n); nan where A is singular."""
    return np.asarray(ca.solve(ca.DM(np.asarray(A, float)), ca.DM(np.asarray(b, float))), float).ravel()


def _matvec(A, x) -> np.ndarray:
    """A x for a small dense A (m, n) and x (n,)."""
    return np.asarray(ca.mtimes(ca.DM(np.asarray(A, float)), ca.DM(np.asarray(x, float))), float).ravel()


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
    COLLOCATED: n(q_{k+1})^T v_{k+1} plus the collocation defect of the gap c of the same point,
    (dc - grad c(q_{k+1}) dq) / (h s): dq and dc are the step's increments of q and of c(q) (implicit
    Euler: q_{k+1} - q_k and c(q_{k+1}) - c(q_k); a FESD stage j: the collocation combinations
    sum_l (A^-1)_jl (q_l - q_0) and sum_l (A^-1)_jl (c(q_l) - c(q_0)) over the element's stages, passed
    as `dy` and `dgap`). The switching function is then the collocated rate of the gap, dc / (h s), where
    q moves at the speed of the clock (grad c dq = h s n^T v), and n^T v where q is frozen (dq = 0,
    an impact). So a sliding mode of alpha (persistent contact) keeps c(q) at every stage where the
    element started, to O(h (1 - r) n^T v) with r the stage's clock rate: the position-level condition
    that beta's complementarity needs at every stage (docs/formulation.md, "FESD in persistent contact").
    With POINT, a Radau IIA element (n_s >= 2) in persistent contact holds n^T v = 0 at its stages but
    moves the gap by the collocation error of c(q), up or down; a gap above 0 under a compressive force
    has no complementary selectors. Same switching surfaces in continuous time (dc / (h s) -> n^T v).
    The correction is zero for a point whose gap is linear in q (the point mass).
    """

    POINT = "point"
    SECANT = "secant"
    COLLOCATED = "collocated"


# 3-point Gauss-Legendre rule on [0, 1]: exact for polynomials of degree 5
_GAUSS_S = (0.5 - 0.1 * 15**0.5, 0.5, 0.5 + 0.1 * 15**0.5)
_GAUSS_W = (5.0 / 18.0, 4.0 / 9.0, 5.0 / 18.0)

# The equality constraints of a step, in this order (ImplicitEulerStep.g_block_names appends "contact_forces").
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
    lift_products: True (the paper's lifting) makes every product of selectors a variable of the
    theta block with its bilinear lifting row; False keeps them as products of the selectors inside
    the expressions (theta then holds the factors only, and the lifting block their rows), so a step
    has len(lifted) variables and rows fewer, the same solutions, and the rows that used a product
    get higher-degree terms instead.
    """

    def __init__(self, system: TimeFreezingSystem, rho_f: float = 1.0, switch_scale=None, form: StepForm = StepForm.EXPLICIT,
                 velocity_switch: SwitchVelocity = SwitchVelocity.POINT, lift_products: bool = True):
        try:  # (a numpy 0-d array or a Decimal are numbers; rho_f = "1" was the comparison's TypeError)
            rho = float(rho_f) if not isinstance(rho_f, (str, bytes, bool)) else math.nan
        except (TypeError, ValueError):
            rho = math.nan
        if not 0 <= rho < math.inf:
            raise InputError(f"rho_f must be a finite number >= 0, got {shown(rho_f)}")
        if not isinstance(lift_products, bool):
            raise InputError(f"lift_products must be True or False, got {shown(lift_products)}")
        form = enum_member(form, StepForm, "form")
        velocity_switch = enum_member(velocity_switch, SwitchVelocity, "velocity_switch")
        self.system, self.rho_f, self.form, self.velocity_switch = system, rho, form, velocity_switch
        self._secant = _secant_rows(system) if velocity_switch is SwitchVelocity.SECANT else None
        self._gaps = _gap_rows(system) if velocity_switch is SwitchVelocity.COLLOCATED else None
        self.mm = system.mass_matrix_form() if form is StepForm.MASS_MATRIX else None
        # forces: MASS_MATRIX the form's z; EXPLICIT with several contacts the contact forces lambda
        nz = self.mm.nz if self.mm is not None else system.n_lambda
        n = system.n_sigma
        try:
            self.switch_scale = np.ones(n) if switch_scale is None else np.asarray(switch_scale, dtype=float).ravel()
        except (TypeError, ValueError):
            raise InputError(f"switch_scale must be {n} numbers > 0, got {shown(switch_scale)}") from None
        if self.switch_scale.shape != (n,):  # (numpy's reshape error named no argument)
            raise InputError(f"switch_scale must have one entry per switching function ({n}), got {self.switch_scale.size}")
        if not np.all(np.isfinite(self.switch_scale) & (self.switch_scale > 0)):
            raise InputError(f"switch_scale must be finite and > 0, got {self.switch_scale.tolist()}")
        # variables of the polynomials: the selectors, then the factors (several contacts only)
        factors = system.factors
        n_var = n + len(factors)
        # monomials: constant, the variables, then lifted products with all their prefixes
        polys = list(system.coefficients.values()) + [f.definition for f in factors] + list(system.constraint_switches)
        lifted: set[tuple[int, ...]] = set()
        for poly in polys:
            for m in poly.terms:
                for k in range(2, len(m) + 1):
                    lifted.add(m[:k])
        self.lifted = tuple(sorted(lifted, key=lambda m: (len(m), m)))
        self.lift_products = lift_products
        self.theta_lifted = self.lifted if lift_products else ()  # the products that are variables of theta
        self.monomials = ((),) + tuple((i,) for i in range(n_var)) + self.lifted
        index = {m: j for j, m in enumerate(self.monomials)}
        self._index = index

        def matrix(ps):  # rows: the polynomials as linear maps of the monomial vector z
            A = np.zeros((len(ps), len(self.monomials)))
            for j, poly in enumerate(ps):
                for m, c in poly.terms.items():
                    A[j, index[m]] = c
            return A

        # C (n_fields, n_monomials): P_j(sigma) = sum_m C[j, m] z_m
        self.C = matrix([system.coefficients[f.name] for f in system.fields])
        self.factor_matrix = matrix([f.definition for f in factors])  # factor_d = row d . z
        self.switch_matrix = matrix(system.constraint_switches)  # s (n_lambda,) = S z
        # theta: the factors, then the lifted products (monomials_of: z = (1, sigma, theta) in monomial order)
        self.n_theta = len(factors) + len(self.theta_lifted)
        self.nw = 3 * n + self.n_theta + nz
        names = [s.name for s in system.switches] + [f.name for f in factors]
        self.theta_names = tuple(names[n:] + ["*".join(names[i] for i in m) for m in self.theta_lifted])
        upper = [1.0] * n + [f.upper for f in factors]
        theta_upper = [f.upper for f in factors] + [float(np.prod([upper[i] for i in m])) for m in self.theta_lifted]
        names = names[:n]
        sizes = {"sigma": n, "theta": self.n_theta, "lambda0": n, "lambda1": n, "forces": nz}
        self.w_blocks, start = {}, 0
        for b in W_BLOCKS + (("forces",) if nz else ()):
            self.w_blocks[b] = slice(start, start + sizes[b])
            start += sizes[b]
        force_names = list(self.mm.z_names) if self.mm is not None else list(system.lam_names)
        self.w_names = tuple(list(names) + list(self.theta_names) + [f"lambda0[{s}]" for s in names] + [f"lambda1[{s}]" for s in names]
                             + (force_names if nz else []))
        self.lbw = np.concatenate([np.zeros(n), np.zeros(self.n_theta), np.zeros(2 * n), np.full(nz, -np.inf)])
        self.ubw = np.concatenate([np.ones(n), np.array(theta_upper, dtype=float), np.full(2 * n, np.inf), np.full(nz, np.inf)])
        # where lambda sits inside the forces block (several contacts)
        self.lam_slice = None
        if system.n_lambda:
            self.lam_slice = self.mm.lam_slice if self.mm is not None else slice(0, system.n_lambda)
        self.w0 = self.w_from(system.wanted, np.zeros(n), np.zeros(n))

    def w_from(self, sigma, lam0, lam1, forces=None) -> np.ndarray:
        """Algebraic variables (nw,) from numeric selectors and multipliers (n_sigma,) each; theta = the
        factors and the products; forces (nz,) default zeros."""
        x = self.system.variables(np.asarray(sigma, float)) if self.system.factors else np.asarray(sigma, float)
        theta = list(x[self.system.n_sigma :]) + [np.prod([x[i] for i in m]) for m in self.theta_lifted]
        nz = self.w_blocks["forces"].stop - self.w_blocks["forces"].start if "forces" in self.w_blocks else 0
        forces = np.zeros(nz) if forces is None else np.asarray(forces, float).ravel()
        return np.concatenate([sigma, theta, lam0, lam1, forces]).astype(float)

    @property
    def g_block_names(self) -> tuple[str, ...]:
        """The blocks of a step's g (Step.g_blocks), in order: G_BLOCKS, then "contact_forces" with the mass-matrix
        form (its defining rows) or several contacts (their constraint forces' rows, either form)."""
        return G_BLOCKS + (("contact_forces",) if self.mm is not None or self.system.n_lambda else ())

    def monomials_of(self, w):
        """The monomial vector z (n_monomials,) = (1, sigma, factors, lifted products) of the algebraic
        variables w (nw,), in self.monomials order: numeric (numpy) for a numeric w, else symbolic. Without
        lift_products the products are formed here from the selectors and factors."""
        sigma, theta = w[self.w_blocks["sigma"]], w[self.w_blocks["theta"]]
        numeric = isinstance(w, np.ndarray)
        z = [1.0] + [sigma[i] for i in range(sigma.shape[0])] + [theta[d] for d in range(theta.shape[0])]
        if not self.lift_products:
            for m in self.lifted:  # sorted by degree: every prefix is already in z
                z.append(z[self._index[m[:-1]]] * z[self._index[(m[-1],)]])
        return np.array(z, dtype=float) if numeric else ca.vertcat(*z)

    def forces_at(self, y, u, sigma=None) -> np.ndarray:
        """The algebraic force variables (nz,) that solve their equations at numeric y, u: MASS_MATRIX
        (acc, lambda, d); several contacts the forces of the points switched on by the selectors
        sigma (n_sigma,) (default sigma*), in EXPLICIT form lambda only."""
        sys_, nq, nv = self.system, self.system.nq, self.system.nv
        q, v = np.asarray(y, float)[:nq], np.asarray(y, float)[nq : nq + nv]
        M = np.asarray(sys_.dyn.mass(q), float)
        acc = np.asarray(sys_.dyn.forward(q, v, u), float).ravel()
        if sys_.n_lambda:
            lam = self.contact_forces(y, u, sys_.wanted if sigma is None else sigma)
            if self.mm is None:
                return lam
            Jt = self._stacked_jacobian(y)
            return np.concatenate([acc, lam, _solve(M, _matvec(Jt.T, lam))])
        lam, ds = [], []
        for model, terms in zip(sys_.models, sys_.terms):
            no_slip = model is ContactModel.NO_SLIP
            fn = ca.Function("forces", [sys_.y, sys_.u], [terms.lambda_no_slip if no_slip else terms.lambda_n, terms.normal, terms.tangent])
            lam_c, n_c, t_c = (np.asarray(a, float).ravel() for a in fn(y, u))
            J = np.vstack([n_c, t_c]) if no_slip else n_c[None, :]
            lam.append(lam_c)
            ds.append(np.linalg.solve(M, J.T @ lam_c))  # one contact: kept as it was (the Capler benchmarks' start)
        return np.concatenate([acc, *lam, *ds])

    def _stacked_jacobian(self, y) -> np.ndarray:
        """Several contacts: J (n_lambda, nv), the rows n_i^T (, t_i^T) of every point at numeric y."""
        sys_ = self.system
        if not hasattr(self, "_jac_fn"):
            rows = []
            for model, ct in zip(sys_.models, sys_.terms):
                rows += [ct.normal.T] + ([ct.tangent.T] if model is ContactModel.NO_SLIP else [])
            self._jac_fn = ca.Function("stacked_jacobian", [sys_.y], [ca.vertcat(*rows)])
        return np.asarray(self._jac_fn(y), float)

    def contact_forces(self, y, u, sigma) -> np.ndarray:
        """Several contacts: lambda (n_lambda,) [N] solving the switched rows at numeric y, u and the
        selectors sigma (n_sigma,): the index-reduced forces of the points with s_i = 1, 0 for s_i = 0."""
        sys_ = self.system
        n = sys_.n_sigma
        s = _matvec(self.switch_matrix, self.monomials_of(self.w_from(sigma, np.zeros(n), np.zeros(n))))
        zero = np.zeros(sys_.n_lambda)
        b = np.asarray(sys_.constraint_fn(y, u, zero), float).ravel()  # J f_v + dJ/dt v
        G = np.column_stack([np.asarray(sys_.constraint_fn(y, u, e), float).ravel() - b for e in np.eye(sys_.n_lambda)])
        A = s[:, None] * G + np.diag((1 - s) * sys_.force_scale)
        # with dependent contact rows (e.g. foot and knee on one line) A is singular and any force that
        # balances is as good as another for a guess: least squares. Not always: its round-off differs from
        # the regular solve's, and the biped walk's hint-free solve (tests/test_walk.py) fails from that start
        lam = _solve(A, -s * b)
        if np.all(np.isfinite(lam)):
            return lam
        return np.linalg.lstsq(A, -s * b, rcond=None)[0]

    def guess(self, y, u) -> np.ndarray:
        """Initial guess (nw,) consistent with the switching functions at a numeric state y (ny,), u (nu,):
        sigma = 1 where h > 0, 0 where h < 0, sigma* where h = 0; lambda1 = max(h, 0), lambda0 = max(-h, 0);
        MASS_MATRIX: the force variables that solve their equations at (y, u). Several contacts: the
        forces of the points on the ground (beta = 0), then gamma from their sign. A gap c(q) within
        result.ON_PLANE_M [m] of 0 counts as 0 (on the plane), as in problem.static_controls."""
        sys_ = self.system
        # a start typed to 7 digits leaves its feet ~4e-9 m up: by the exact sign beta would be 1 (flight) and
        # the static start's standing torques would act on a robot guessed in free fall
        gap = np.array([s.function == "c(q)" for s in sys_.switches], dtype=bool)

        def switching(*args):
            h = np.asarray(sys_.switching_fn(*args), dtype=float).ravel()
            return np.where(gap & (np.abs(h) <= ON_PLANE_M), 0.0, h) / self.switch_scale

        if sys_.n_lambda:
            sigma = sys_.wanted.copy()
            for _ in range(2):  # forces with the selectors so far, then the selectors from the forces
                lam = self.contact_forces(y, u, sigma)
                hval = switching(y, u, lam)
                sigma = np.where(hval > 0, 1.0, np.where(hval < 0, 0.0, sys_.wanted))
            forces = self.forces_at(y, u, sigma) if "forces" in self.w_blocks else None
            return self.w_from(sigma, np.maximum(-hval, 0.0), np.maximum(hval, 0.0), forces)
        hval = switching(y, u)
        sigma = np.where(hval > 0, 1.0, np.where(hval < 0, 0.0, sys_.wanted))
        forces = self.forces_at(y, u) if self.mm is not None else None
        return self.w_from(sigma, np.maximum(-hval, 0.0), np.maximum(hval, 0.0), forces)

    def build(self, y_k, y_next, u_k, s_k=1.0, h: float = 0.01, tag: str = "", field_scale=None, dy=None, dgap=None,
              gap_weight=None) -> Step:
        """Create the step's algebraic variables and its constraints (see module docstring).

        y_k, y_next (ny,), u_k (nu,), s_k (scalar) are CasADi expressions (SX or MX) or numbers;
        h [s] the numerical-time step (a number or an expression). The new variables are SX symbols
        unless y_next is MX. `tag` is appended to the variable names (e.g. the step index).
        field_scale (n_fields,) optionally multiplies each field's coefficient P_j (an OCP uses it to
        continue the auxiliary gains a_n, a_t from weak to the task's values; 1 everywhere is the
        task's system). dy (ny,) replaces the increment y_next - y_k that must equal h s F(y_next):
        a collocation stage passes sum_l A^-1_jl (Y_l - y_k) (FESDInterval), with the algebraic
        conditions still at y_next (the stage). dgap (n_sigma,): SwitchVelocity.COLLOCATED only, the
        increment of the gaps c(q) that goes with dy (FESDInterval: sum_l A^-1_jl (c(q_l) - c(q_0)));
        None: c(q_next) - c(q_k). gap_weight (n_sigma,): COLLOCATED only, multiplies each row's correction
        (a number or a parameter: 1 the COLLOCATED switching function, 0 the POINT one); None: 1.
        """
        sys_ = self.system
        sym = ca.MX.sym if isinstance(y_next, ca.MX) else ca.SX.sym
        w = sym(f"w{tag}", self.nw)
        sigma, theta = w[self.w_blocks["sigma"]], w[self.w_blocks["theta"]]
        lam0, lam1 = w[self.w_blocks["lambda0"]], w[self.w_blocks["lambda1"]]
        z = self.monomials_of(w)
        coef = ca.mtimes(ca.DM(self.C), z)
        lam = None
        if sys_.n_lambda:  # several contacts: the unit-force fields get R lambda (R = the f_ODE coefficient)
            lam = w[self.w_blocks["forces"]][self.lam_slice]
            coef = coef + ca.mtimes(ca.DM(self._force_map()), coef[0] * lam)
        if field_scale is not None:
            coef = coef * field_scale
        extra = []
        if self.mm is None:
            F = ca.mtimes(sys_.fields_fn(y_next, u_k), coef)
            dynamics = (y_next - y_k if dy is None else dy) - h * s_k * F
            if lam is None:
                hval = sys_.switching_fn(y_next, u_k)
            else:
                hval = sys_.switching_fn(y_next, u_k, lam)
                extra = [sys_.constraint_rows(y_next, u_k, lam, ca.mtimes(ca.DM(self.switch_matrix), z))]
        else:
            nq, nv = sys_.nq, sys_.nv
            forces = w[self.w_blocks["forces"]]
            fmat, hval, defining, M = self.mm.fn(y_next, u_k, forces)
            F = ca.mtimes(fmat, coef)
            dy = y_next - y_k if dy is None else dy
            dv = ca.mtimes(M, dy[nq : nq + nv])  # velocity rows times M(q_{k+1}): no inverse
            dynamics = ca.vertcat(dy[:nq], dv, dy[nq + nv :]) - h * s_k * F
            extra = [defining]
            if lam is not None:
                s = ca.mtimes(ca.DM(self.switch_matrix), z)
                extra.append(s * self.mm.constraint_fn(y_next, u_k, forces) + (1 - s) * sys_.force_scale * lam)
        if self._secant is not None:
            nq, nv = sys_.nq, sys_.nv
            rows, mask = self._secant
            hval = hval * ca.DM(1.0 - mask) + ca.mtimes(rows(y_k[:nq], y_next[:nq]), y_next[nq : nq + nv])
        if self._gaps is not None:
            nq = sys_.nq
            gaps, grads = self._gaps
            dq = (y_next - y_k if dy is None else dy)[:nq]
            if dgap is None:
                dgap = gaps(y_next[:nq]) - gaps(y_k[:nq])
            correction = (dgap - ca.mtimes(grads(y_next[:nq]), dq)) / (h * s_k)  # rows of n^T v only
            hval = hval + (correction if gap_weight is None else gap_weight * correction)
        stationarity = hval / ca.DM(self.switch_scale) - lam1 + lam0
        index, n = self._index, sys_.n_sigma
        factors = [theta[d] - ca.mtimes(ca.DM(self.factor_matrix[d : d + 1]), z) for d in range(len(sys_.factors))]
        lifting = factors + [z[index[m]] - z[index[m[:-1]]] * z[index[(m[-1],)]] for m in self.theta_lifted]
        g = ca.vertcat(dynamics, stationarity, *lifting, *extra)
        ny = sys_.ny
        g_blocks = {"dynamics": slice(0, ny), "stationarity": slice(ny, ny + n), "lifting": slice(ny + n, ny + n + self.n_theta)}
        if extra:
            start = ny + n + self.n_theta
            g_blocks["contact_forces"] = slice(start, start + sum(e.shape[0] for e in extra))
        comp = tuple((lam0[i], sigma[i]) for i in range(n)) + tuple((lam1[i], 1 - sigma[i]) for i in range(n))
        dev = sigma - ca.DM(sys_.wanted)
        if not sys_.regularized.all():
            dev = dev[np.flatnonzero(sys_.regularized).tolist()]
        objective = self.rho_f * ca.dot(dev, dev)
        names = tuple(f"{nm}{tag}" for nm in self.w_names)
        return Step(w=w, w_names=names, w_blocks=dict(self.w_blocks), lbw=self.lbw.copy(), ubw=self.ubw.copy(), w0=self.w0.copy(),
                    g=g, g_blocks=g_blocks, complementarity=comp, objective=objective)

    def coefficients(self, w) -> np.ndarray:
        """Numeric field coefficients P_j (n_fields,) of a solved step from its algebraic variables w (nw,)."""
        w = np.asarray(w, dtype=float).ravel()
        coef = self.C @ self.monomials_of(w)
        if self.system.n_lambda:
            coef = coef + self._force_map() @ (coef[0] * w[self.w_blocks["forces"]][self.lam_slice])
        return coef

    def _force_map(self) -> np.ndarray:
        """E (n_fields, n_lambda): E[j, k] = 1 when field j is the unit-force field of lambda_k."""
        E = np.zeros((self.system.n_fields, self.system.n_lambda))
        for k, j in enumerate(self.system.force_columns):
            E[j, k] = 1.0
        return E


def _secant_rows(system: TimeFreezingSystem) -> tuple[ca.Function, np.ndarray]:
    """SwitchVelocity.SECANT: Function (q_a, q_b) -> (n_sigma, nv) whose row i is the Gauss-averaged
    gradient of switch i's coordinate (along the contact plane's normal for n^T v, along its tangent
    for t^T v) over the segment q_a -> q_b (zero rows for the other switches), and the (n_sigma,) mask
    of the rows it replaces."""
    nq, nv = system.nq, system.nv
    qa, qb = ca.SX.sym("q_a", nq), ca.SX.sym("q_b", nq)
    rows, mask = [], np.zeros(system.n_sigma)
    for i, sw in enumerate(system.switches):
        if sw.function not in ("n^T v", "t^T v") or sw.contact is None:
            rows.append(ca.SX.zeros(1, nv))
            continue
        contact = system.contacts[system.labels.index(sw.contact)]
        normal, tangent = plane_axes(contact.normal)
        direction = ca.DM(normal if sw.function == "n^T v" else tangent)
        jac = system.dyn.point_jacobian(contact.point)
        rows.append(sum(w * ca.mtimes(direction.T, jac(qa + s * (qb - qa))[:3, :]) for s, w in zip(_GAUSS_S, _GAUSS_W)))
        mask[i] = 1.0
    return ca.Function("secant_rows", [qa, qb], [ca.vertcat(*rows)], ["q_a", "q_b"], ["rows"]), mask


def _gap_rows(system: TimeFreezingSystem) -> tuple[ca.Function, ca.Function]:
    """SwitchVelocity.COLLOCATED: Functions q -> (n_sigma,) gaps and q -> (n_sigma, nq) their gradients,
    row i the gap of switch i's contact when switch i is an n^T v, zero otherwise."""
    q = ca.SX.sym("q", system.nq)
    rows = []
    for sw in system.switches:
        if sw.function != "n^T v" or sw.contact is None:
            rows.append(ca.SX(0))
            continue
        contact = system.contacts[system.labels.index(sw.contact)]
        normal, _ = plane_axes(contact.normal)
        rows.append(ca.dot(ca.DM(normal), system.dyn.point_position(contact.point)(q)[:3]))
    gaps = ca.vertcat(*rows)
    return ca.Function("gap_rows", [q], [gaps]), ca.Function("gap_gradients", [q], [ca.jacobian(gaps, q)])


# ==================================================================================================
# finite elements with switch detection (FESD)
# ==================================================================================================

class Discretization(Enum):
    """How a simulation discretizes the time-freezing system.

    IMPLICIT_EULER: the paper's regularized implicit Euler step (ImplicitEulerStep), one per step h.
    FESD: finite elements with switch detection (Nurkanovic et al.): each step h is split into
    n_fe Radau IIA elements of free lengths h_n (sum h), and cross-complementarity puts every switch
    of the selectors on an element boundary (FESDInterval).
    """

    IMPLICIT_EULER = "implicit_euler"
    FESD = "fesd"


def radau_iia(n_s: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Butcher tableau of the n_s-stage Radau IIA collocation method (order 2 n_s - 1, stiffly accurate).

    Returns A (n_s, n_s), b (n_s,), c (n_s,) with c the right Radau points on [0, 1] (c[-1] = 1) and
    b = A[-1]: the last stage is the end of the element. n_s = 1 is implicit Euler.
    """
    if n_s not in (1, 2, 3):
        raise InputError(f"n_s must be 1, 2 or 3, got {shown(n_s)}")
    # right Radau points: the roots of P_s(2c - 1) - P_{s-1}(2c - 1) (Legendre P), all in (0, 1]
    legendre = np.polynomial.legendre.Legendre
    x = (legendre.basis(n_s) - legendre.basis(n_s - 1)).roots()
    c = np.sort(np.real((x + 1.0) / 2.0))
    c[-1] = 1.0
    A = np.zeros((n_s, n_s))
    for l in range(n_s):
        others = np.delete(c, l)
        basis = np.polynomial.Polynomial(np.atleast_1d(np.poly(others))[::-1]) / np.prod(c[l] - others)  # Lagrange basis of c_l
        integral = basis.integ()
        A[:, l] = integral(c) - integral(0.0)
    return A, A[-1].copy(), c


# more finite elements per step than this are a typo (the tasks use 2-3): n_fe = 10**7 ran out of memory building N = 1
MAX_ELEMENTS = 1000


@dataclass(frozen=True)
class FESDOptions:
    """Settings of the FESD discretization.

    n_s: Radau IIA stages per element (1..3; order 2 n_s - 1 between switches). n_fe: finite elements
    per step h (>= 1; from 2 on an element boundary per step is free to move onto a switch, and a step holds at
    most n_fe - 1 switches; n_fe = 1 holds none, and is not the implicit-Euler step: `planner simulate point_mass
    --discretization fesd --stages 1 --elements 1` fails at the impact that implicit Euler passes). rho_h: weight of
    the step equilibration penalty
    rho_h sum_n ((h_n - h/n_fe) / (h/n_fe))^2, which fixes the lengths that no switch pins (without
    it they are free and the NLP degenerate). The complementarity penalty grows past it in the
    homotopy; with rho_h = 0.1 the point-mass drop started with two elements of length ~0 (free
    selectors there), with 1 it did not.
    """

    n_s: int = 2
    n_fe: int = 2
    rho_h: float = 1.0

    def __post_init__(self):
        check_field_types(self)
        checks = [(self.n_s in (1, 2, 3), "n_s", self.n_s, "1, 2 or 3"),
                  (1 <= self.n_fe <= MAX_ELEMENTS, "n_fe", self.n_fe, f"in [1, {MAX_ELEMENTS}]"),
                  (self.rho_h >= 0, "rho_h", self.rho_h, ">= 0")]
        for ok, key, value, allowed in checks:
            if not ok:
                raise InputError(f"FESDOptions.{key} = {value!r} is not allowed; it must be {allowed}")


@dataclass(frozen=True, eq=False)
class Interval:
    """NLP pieces of one FESD step of length H [s] (symbolic, SX).

    x (nx,) variables: the element lengths h (n_fe,) [s], then per element n and stage j the stage
    state Y_nj (ny,) and the stage's algebraic variables w_nj (nw, ImplicitEulerStep blocks);
    lbx, ubx (nx,) bounds; y_end (ny,) the step's end state (the last stage of the last element).
    g (ng,) equalities: sum h = H, then every stage's Step.g. complementarity: pairs (a, b), a, b >= 0,
    a * b = 0 wanted: per element, selector, stage j and point j' (the element's stages and its left
    boundary), the cross-complementarity lambda0_j' sigma_j and lambda1_j' (1 - sigma_j).
    objective: the stages' rho_f terms weighted b_j h_n / H (with constant weights, collapsing an
    element to h_n = 0 would let its selectors go to sigma* for free), plus the step equilibration
    (also alone as `equilibration`). g_blocks: name -> rows of g, "element_lengths" (1,) and each
    Step.g block over the stages in element-major order (e.g. "dynamics" (n_fe n_s ny,)).
    """

    x: object
    lbx: np.ndarray
    ubx: np.ndarray
    y_end: object
    g: object
    complementarity: tuple[tuple[object, object], ...]
    objective: object
    equilibration: object = 0.0
    g_blocks: dict = field(default_factory=dict)

    def comp_products(self):
        """vertcat of a * b over the complementarity pairs."""
        return ca.vertcat(*[a * b for a, b in self.complementarity])


class FESDInterval:
    """Builder of FESD steps (finite elements with switch detection) for a time-freezing system.

    Every stage of every element is one ImplicitEulerStep stage: the same selectors, lifting,
    stationarity and (several contacts) force rows, with the collocation increment in place of the
    Euler one. Elements are Radau IIA of n_s stages; the element lengths h_n are variables with sum
    H. Cross-complementarity: within an element and with its left boundary (the previous element's
    last stage, or the previous step's end given as a parameter), a selector may not be at a bound
    at one point while its multiplier is positive at another; so a selector changes its bound only
    at an element boundary, and the free h_n put that boundary on the switching surface. With a
    step of SwitchVelocity.COLLOCATED, each stage's n^T v switching function gets the collocation
    defect of its point's gap (ImplicitEulerStep.build's dgap).
    """

    def __init__(self, step: ImplicitEulerStep, options: FESDOptions = FESDOptions()):
        self.step, self.options = step, options
        self.A, self.b, self.c = radau_iia(options.n_s)
        self.A_inv = np.linalg.inv(self.A)
        ny, nw = step.system.ny, step.nw
        self.n_fe, self.n_s, self.n_stage = options.n_fe, options.n_s, ny + nw
        self.nx = self.n_fe + self.n_fe * self.n_s * self.n_stage

    def stage_slice(self, n: int, j: int) -> slice:
        """Where stage j of element n (Y_nj, then w_nj) sits in x."""
        start = self.n_fe + (n * self.n_s + j) * self.n_stage
        return slice(start, start + self.n_stage)

    def build(self, y_k, control, H: float, lam_prev, tag: str = "", s_k=1.0, field_scale=None, gap_weight=None) -> Interval:
        """One FESD step from y_k (ny,) over H [s] of numerical time with speed of time s_k (a number
        or an expression; every stage integrates h_n s_k F).

        control(y) -> u (nu,): the control acting at a stage state y (a constant, or a feedback law).
        lam_prev (2 n_sigma,): (lambda0, lambda1) at y_k, the left boundary of the first element.
        field_scale: as in ImplicitEulerStep.build (an OCP's auxiliary-gain continuation).
        gap_weight (n_sigma,): SwitchVelocity.COLLOCATED only, as in ImplicitEulerStep.build (every stage).
        """
        st, opts = self.step, self.options
        sys_ = st.system
        ny, n = sys_.ny, sys_.n_sigma
        hs = ca.SX.sym(f"h{tag}", self.n_fe)
        h_bar = H / self.n_fe
        x, lbx, ubx, g, pairs = [hs], [np.zeros(self.n_fe)], [np.full(self.n_fe, H)], [ca.sum1(hs) - H], []
        equilibration = opts.rho_h * ca.sumsqr((hs - h_bar) / h_bar)
        objective = equilibration
        rows: dict[str, list] = {"element_lengths": [0]}
        row = 1
        start, lam0_left, lam1_left = y_k, lam_prev[:n], lam_prev[n:]
        for e in range(self.n_fe):
            Y = [ca.SX.sym(f"Y{tag}_{e}_{j}", ny) for j in range(self.n_s)]
            stages = []
            gap_inc = None  # SwitchVelocity.COLLOCATED: c(q_l) - c(q_0) of the stages
            if st._gaps is not None:
                gaps, nq = st._gaps[0], sys_.nq
                gap_inc = [gaps(Y[l][:nq]) - gaps(start[:nq]) for l in range(self.n_s)]
            for j in range(self.n_s):
                dy = sum(self.A_inv[j, l] * (Y[l] - start) for l in range(self.n_s))
                dgap = None if gap_inc is None else sum(self.A_inv[j, l] * gap_inc[l] for l in range(self.n_s))
                stages.append(st.build(start, Y[j], control(Y[j]), s_k, hs[e], tag=f"{tag}_{e}_{j}", field_scale=field_scale, dy=dy,
                                       dgap=dgap, gap_weight=gap_weight))
            for j, stage in enumerate(stages):
                x += [Y[j], stage.w]
                lbx += [np.full(ny, -np.inf), stage.lbw]
                ubx += [np.full(ny, np.inf), stage.ubw]
                g.append(stage.g)
                for name, sl in stage.g_blocks.items():
                    rows.setdefault(name, []).extend(range(row + sl.start, row + sl.stop))
                row += stage.g.shape[0]
                objective += self.b[j] * hs[e] / H * stage.objective  # quadrature of the regularization over the step
            # one pair per (multiplier point, stage), not sums: IPOPT relaxes bounds by ~1e-8, and in a
            # sum a stage at -1e-8 cancels another at +1e-8 (measured with sums: the switch 3e-8 m off
            # the surface, the free-flight clock 5e-9 slow, the impact time 1e-8 off)
            lam0 = [lam0_left] + [s.block("lambda0") for s in stages]
            lam1 = [lam1_left] + [s.block("lambda1") for s in stages]
            for s in stages:
                sig = s.block("sigma")
                pairs += [(l0[i], sig[i]) for l0 in lam0 for i in range(n)] + [(l1[i], 1 - sig[i]) for l1 in lam1 for i in range(n)]
            start, lam0_left, lam1_left = Y[-1], stages[-1].block("lambda0"), stages[-1].block("lambda1")
        return Interval(x=ca.vertcat(*x), lbx=np.concatenate(lbx), ubx=np.concatenate(ubx), y_end=start,
                        g=ca.vertcat(*g), complementarity=tuple(pairs), objective=objective, equilibration=equilibration,
                        g_blocks={name: np.array(r, dtype=int) for name, r in rows.items()})

    def guess(self, H: float, y, w) -> np.ndarray:
        """Initial guess (nx,): equal lengths H / n_fe, every stage at the state y (ny,) with the
        algebraic variables w (nw,)."""
        return np.concatenate([np.full(self.n_fe, H / self.n_fe)] + [np.concatenate([y, w])] * (self.n_fe * self.n_s))

    def unpack(self, x) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Element lengths h (n_fe,) [s], stage states Y (n_fe, n_s, ny) and algebraic variables
        W (n_fe, n_s, nw) of a numeric x (nx,)."""
        x = np.asarray(x, float).ravel()
        ny = self.step.system.ny
        body = x[self.n_fe : self.nx].reshape(self.n_fe, self.n_s, self.n_stage)
        return x[: self.n_fe].copy(), body[:, :, :ny].copy(), body[:, :, ny:].copy()
