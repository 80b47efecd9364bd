"""The time-freezing system (paper Secs. 4-6): vector fields, switching functions, wanted selectors.

State y = (q (nq,), v (nv,), p (one per elastic contact), t) in R^ny, the clock t last. The
system is a piecewise smooth ODE written with set-valued step functions sigma_i in theta(h_i(y, u)):

    y' = s * F(y, sigma, u),    F = sum_j P_j(sigma) f_j(y, u)

where the f_j are smooth vector fields (f_ODE, f_DAE, f_A,n, ...) and the P_j are multi-affine
polynomials in the selectors (eqs. 17, 20, 27). Keeping F in this "polynomial times field" form lets
the discretization lift every product of selectors into one algebraic variable (Sec. 5.1) and lets
the recovery know which part of a step was an auxiliary (clock-frozen) motion.

Contact models (one per contact point, chosen from the task's mu and restitution):

* FRICTIONLESS (mu = 0, eps = 0): selectors (alpha, beta, gamma) of (n^T v, c, phi);
  F = beta f_ODE + (1-beta)((1-alpha) f_A,n + alpha f_DF),
  f_DF = (1-gamma)(2 f_DAE - f_A,n) + 2 gamma f_ODE                      (eqs. 17, 20)
* NO_SLIP (mu > 0, eps = 0): adds zeta of t^T v and the tangential jump, Sec. 6 simplified
  (a_t >> a_n, xi* = alpha*): f_jmp = (1-alpha) f_A,n + (1-2 zeta) f_A,t,
  f_DF,f = ((1-gamma) f_DAE,f + gamma f_ODE)/alpha* - (1-gamma) f_A,n,
  F = beta f_ODE + (1-beta)(f_jmp + alpha f_DF,f)                          (eq. 27)
* ELASTIC (mu = 0, eps > 0): the auxiliary oscillator of Sec. 4.5 with q frozen on c = 0, in the
  well-posed form derived in docs/formulation.md (selectors alpha, beta, eta of n^T v, c, p):
  F = beta [eta f_ODE + (1-eta) f_push] + (1-beta)[eta((1-alpha) f_osc + alpha f_ODE) + (1-eta) f_osc]

Several contact points (all inelastic; docs/formulation.md, "Several contacts"): per point i the
selectors alpha_i, beta_i, gamma_i (, zeta_i) of n_i^T v, c_i, -lambda_n,i (, t_i^T v), its
auxiliary fields a_n[i] (, a_t[i]) and unit-force fields lam_n[i] (, lam_t[i]) = (0, M^-1 n_i, 0);
the contact forces lambda (n_lambda,) are algebraic variables of the step, defined jointly by
    s_i (J_i a + dJ_i/dt v) + (1 - s_i) kappa lambda_i = 0,   a = f_v + M^-1 sum_k J_k^T lambda_k,
    s_i = (1 - beta_i)(1 - gamma_i),
so that the points with s_i = 1 get the index-reduced forces of their stacked Jacobian. With the
per-point clock factors r_i = beta_i + (1 - beta_i) alpha_i / alpha* and R = prod_i r_i,
R_-i = prod_{k != i} r_k (lifted as chains of factor variables, see Factor):
    F = R (f_ODE + sum_i lam fields * lambda_i) + sum_i [(1 - beta_i)(1 - alpha_i) f_A,n,i
        + (1 - beta_i)(1 - 2 zeta_i) f_A,t,i - R_-i (1 - beta_i) alpha_i (1 - gamma_i) f_A,n,i].
A robot without contacts gives F = f_ODE (no selectors); one contact keeps the forms above.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

import casadi as ca
import numpy as np

from .contact import ContactTerms, contact_terms
from .dynamics import Dynamics
from .errors import InputError
from .task import Contact, contact_labels

# Wanted selectors on the sliding manifolds (Prop. 9, Sec. 6); xi* = alpha* in the simplified
# frictional form. eta* = 1: in flight p rests at 0 and eta only multiplies identical fields.
ALPHA_STAR, BETA_STAR, GAMMA_STAR, ZETA_STAR, ETA_STAR = 0.5, 0.0, 0.0, 0.5, 1.0

# Speed [m/s] at which the elastic model's push field moves p back to 0 (and q onto c = 0) when a
# trajectory touches the nonphysical region c > 0, p < 0. It must exceed the normal speed at which
# a contact leaves the ground; 10 m/s is the speed after a 5 m fall.
PUSH_SPEED = 10.0


class ContactModel(Enum):
    """Which time-freezing construction a contact point gets."""

    FRICTIONLESS = "frictionless"  # inelastic, no tangential jump (eqs. 17, 20)
    NO_SLIP = "no_slip"  # inelastic with tangential jump to zero slip (Sec. 6, simplified)
    ELASTIC = "elastic"  # frictionless, restitution eps > 0 (Sec. 4.5)


def contact_model(contact: Contact) -> ContactModel:
    """The model of a task contact: eps > 0 elastic, else mu > 0 no-slip, else frictionless."""
    if contact.restitution > 0:
        if contact.mu > 0:
            raise InputError(f"contact {contact.point!r}: restitution = {contact.restitution} with mu = {contact.mu} is not "
                             "supported; elastic impacts are frictionless (set mu = 0) and frictional impacts inelastic "
                             "(set restitution = 0)")
        return ContactModel.ELASTIC
    return ContactModel.NO_SLIP if contact.mu > 0 else ContactModel.FRICTIONLESS


def oscillator_gains(restitution: float, stiffness: float) -> tuple[float, float]:
    """Stiffness k [1/s^2] and damping c [1/s] of the elastic auxiliary oscillator p'' = -k p - c p'.

    Started at p = 0 with p' = w_s < 0, the underdamped oscillator (damping ratio zeta < 1,
    omega0 = sqrt(k), omega_d = omega0 sqrt(1 - zeta^2)) is p(tau) = (w_s/omega_d) exp(-zeta omega0 tau)
    sin(omega_d tau). It is back at p = 0 after tau_jump = pi/omega_d with
    p' = -w_s exp(-pi zeta / sqrt(1 - zeta^2)). Setting that ratio to eps gives
    zeta = -ln(eps) / sqrt(pi^2 + ln(eps)^2), hence c = 2 zeta sqrt(k). eps = 1 gives c = 0.
    """
    if not 0.0 < restitution <= 1.0:
        raise InputError(f"restitution = {restitution} is not allowed for the elastic oscillator; it must be in (0, 1]")
    if stiffness <= 0:
        raise InputError(f"oscillator stiffness = {stiffness} must be > 0")
    log_eps = math.log(restitution)
    zeta = -log_eps / math.sqrt(math.pi**2 + log_eps**2)
    return stiffness, 2.0 * zeta * math.sqrt(stiffness)


class Poly:
    """A multi-affine polynomial in the selectors: {monomial: coefficient}.

    A monomial is a sorted tuple of selector indices, () the constant. Selector products never
    repeat a factor, which `__mul__` checks.
    """

    def __init__(self, terms: dict[tuple[int, ...], float] | None = None):
        self.terms = {m: float(c) for m, c in (terms or {}).items() if c != 0.0}

    @staticmethod
    def var(i: int) -> Poly:
        return Poly({(i,): 1.0})

    def __add__(self, other) -> Poly:
        other = _poly(other)
        out = dict(self.terms)
        for m, c in other.terms.items():
            out[m] = out.get(m, 0.0) + c
        return Poly(out)

    __radd__ = __add__

    def __neg__(self) -> Poly:
        return Poly({m: -c for m, c in self.terms.items()})

    def __sub__(self, other) -> Poly:
        return self + (-_poly(other))

    def __rsub__(self, other) -> Poly:
        return _poly(other) + (-self)

    def __mul__(self, other):
        if isinstance(other, Mix):
            return NotImplemented
        other = _poly(other)
        out: dict[tuple[int, ...], float] = {}
        for m1, c1 in self.terms.items():
            for m2, c2 in other.terms.items():
                if set(m1) & set(m2):
                    raise ValueError("selector products must be multi-affine")
                m = tuple(sorted(m1 + m2))
                out[m] = out.get(m, 0.0) + c1 * c2
        return Poly(out)

    __rmul__ = __mul__

    def __call__(self, sigma):
        """Value at selectors sigma (numbers or CasADi expressions, indexable)."""
        total = 0.0
        for m, c in self.terms.items():
            term = c
            for i in m:
                term = term * sigma[i]
            total = total + term
        return total


def _poly(x) -> Poly:
    return x if isinstance(x, Poly) else Poly({(): float(x)})


class Mix:
    """A combination sum_j P_j f_j of named vector fields with polynomial coefficients."""

    def __init__(self, parts: dict[str, Poly]):
        self.parts = {k: p for k, p in parts.items() if p.terms}

    @staticmethod
    def field(name: str) -> Mix:
        return Mix({name: Poly({(): 1.0})})

    def __add__(self, other: Mix) -> Mix:
        out = dict(self.parts)
        for k, p in other.parts.items():
            out[k] = out.get(k, Poly()) + p
        return Mix(out)

    def __sub__(self, other: Mix) -> Mix:
        return self + (-1.0) * other

    def __rmul__(self, scale) -> Mix:
        return Mix({k: _poly(scale) * p for k, p in self.parts.items()})

    __mul__ = __rmul__


@dataclass(frozen=True)
class Switch:
    """One switching function h_i(y, u) and its step function sigma_i in theta(h_i)."""

    name: str  # selector name, e.g. "alpha[point]"
    contact: str
    function: str  # what h_i is, e.g. "n^T v"
    wanted: float  # sigma_i* used by rho_f ||sigma - sigma*||^2
    # False: no rho_f term: zeta of a frictionless contact (frictionless_tangential) multiplies a zero field,
    # so there is no sliding mode for sigma* to select, and a rho_f term would price tangential sliding
    regularized: bool = True


@dataclass(frozen=True)
class Field:
    """One smooth vector field f_j(y, u) in R^ny."""

    name: str  # e.g. "ode", "a_n[point]"
    contact: str | None  # the contact it belongs to, None for f_ODE
    auxiliary: bool  # True when it freezes the clock and its v-part is an impulse (state jump in slow motion)


@dataclass(frozen=True)
class Factor:
    """A derived algebraic variable x = definition(selectors, earlier factors) of the multi-contact
    rule (a clock factor r_i, a gate g_i or a chain product of clock factors). Factors are variables
    n_sigma, n_sigma + 1, ... of the coefficient polynomials, so a product across contacts is one
    monomial of factors and the discretization lifts it with a few bilinear constraints instead of
    expanding it into 3^m monomials of selectors. 0 <= x <= upper."""

    name: str
    definition: Poly
    upper: float


class TimeFreezingSystem:
    """The time-freezing PSS of a robot with contact points (one contact: eqs. 17-27; several: the
    composition rule of the module docstring).

    Attributes:
      dyn, contacts (task Contacts), models (ContactModel per contact), terms (ContactTerms per contact)
      nq, nv, nu, ny; y (SX ny), u (SX nu) the symbols every expression below is written in
      state_names (ny,), switches (Switch, ...), fields (Field, ...)
      coefficients: dict field name -> Poly (F = sum_j P_j(sigma) f_j)
      field_matrix: SX (ny, n_fields), column j = f_j(y, u)
      switching: SX (n_sigma,), the h_i(y, u)
      impulse_rates: SX (2 * n_contacts, n_fields): normal and tangential impulse per unit numerical
        time [N] of each field (a_n for f_A,n, a_t for f_A,t, the oscillator force for f_osc, 0 else)
      Functions of (y, u): fields_fn -> field_matrix, switching_fn -> switching,
        impulse_fn -> impulse_rates, gap_fn -> (n_contacts,) gaps c [m], normal_velocity_fn -> (n_contacts,) n^T v [m/s]
      labels (n_contacts,): contact names used in field and selector names (contact_labels)
    Several contacts (empty otherwise): factors (Factor, ...), the polynomial variables after the
      selectors; lam SX (n_lambda,) contact forces [N], lam_names, lam_index (label -> slice);
      force_columns (n_lambda,) the unit-force field of each lambda entry (coefficient R lambda_k);
      constraint SX (n_lambda,) = J a + dJ/dt v with a = M^-1 (B u - h + J^T lam), constraint_fn
      (y, u, lam); constraint_switches (n_lambda,) Polys s_i; force_scale kappa [1/kg];
      switching_fn takes (y, u, lam) (gamma_i switches on -lambda_n,i).
    """

    def __init__(self, dyn: Dynamics, contacts: tuple[Contact, ...] | list[Contact], ground_height: float = 0.0,
                 frictionless_tangential: bool = False):
        contacts = tuple(contacts)
        self.dyn, self.contacts = dyn, contacts
        # frictionless_tangential: give frictionless contacts the tangential switch zeta and a jump field
        # a_t of gain 0 too (mu = 0: no tangential impulse). F is unchanged (with alpha* = 1/2 the NO_SLIP
        # polynomials reduce to the frictionless ones); it is what the system carries when the scene
        # analysis is off (planner.scene), so that a benchmark can measure what dropping it saves.
        self.frictionless_tangential = bool(frictionless_tangential)
        self.models = tuple(contact_model(c) for c in contacts)
        self.labels = contact_labels(contacts)
        if len(contacts) > 1 and ContactModel.ELASTIC in self.models:
            raise InputError(f"{len(contacts)} contact points given ({', '.join(self.labels)}) with an elastic one "
                             "(restitution > 0); several contact points must all be inelastic (restitution = 0)")
        # multi-contact additions (empty for one contact): factor variables, contact forces
        self.factors: tuple[Factor, ...] = ()
        self.lam = ca.SX(0, 1)
        self.lam_names: tuple[str, ...] = ()
        self.lam_index: dict[str, slice] = {}
        self.force_columns: tuple[int, ...] = ()
        self.constraint_switches: tuple[Poly, ...] = ()
        self.nq, self.nv, self.nu = dyn.nq, dyn.nv, dyn.nu
        n_p = sum(m is ContactModel.ELASTIC for m in self.models)
        self.ny = self.nq + self.nv + n_p + 1
        self.y, self.u = ca.SX.sym("y", self.ny), ca.SX.sym("u", self.nu)
        q, v = self.y[: self.nq], self.y[self.nq : self.nq + self.nv]  # no field depends on the clock
        dofs = dyn.robot.dof_names
        self.state_names = tuple([f"q[{d}]" for d in dofs] + [f"v[{d}]" for d in dofs]
                                 + [f"p[{c.point}]" for c, m in zip(contacts, self.models) if m is ContactModel.ELASTIC] + ["t"])

        M = dyn.mass(q)
        fv = dyn.forward(q, v, self.u)
        self._mass, self._mm_form = M, None
        zq, zv, zp = ca.SX.zeros(self.nq), ca.SX.zeros(self.nv), ca.SX.zeros(n_p)
        values: dict[str, ca.SX] = {"ode": ca.vertcat(v, fv, zp, 1)}
        self.fields = [Field("ode", None, False)]
        impulses: dict[str, tuple] = {"ode": (0, 0)}
        self.switches: list[Switch] = []
        h: list[ca.SX] = []
        mix = Mix.field("ode")
        self.terms: list[ContactTerms] = []
        if len(contacts) > 1:
            self._compose(ground_height, q, v, M, fv, values, impulses, h)
            return
        ip = self.nq + self.nv  # index of the next elastic p state
        for contact, model in zip(contacts, self.models):
            ct = contact_terms(dyn, contact.point, ground_height, q, v, self.u, M=M, fv=fv, surface=contact.normal)
            self.terms.append(ct)
            pt = contact.point

            def switch(name, expr, what, wanted, regularized=True):
                h.append(expr)
                self.switches.append(Switch(f"{name}[{pt}]", pt, what, wanted, regularized))
                return Poly.var(len(self.switches) - 1)

            def field(name, value, auxiliary, impulse=(0, 0)):
                key = f"{name}[{pt}]"
                values[key] = value
                impulses[key] = impulse
                self.fields.append(Field(key, pt, auxiliary))
                return Mix.field(key)

            ode = Mix.field("ode")
            if model is ContactModel.ELASTIC:
                k, c_damp = oscillator_gains(contact.restitution, contact.a_n)
                p = self.y[ip]
                e_p = ca.DM.zeros(n_p)
                e_p[ip - self.nq - self.nv] = 1
                w = ct.normal_velocity
                a_osc = (-k * p - c_damp * w) / ct.delassus  # normal force of the oscillator, w' = -k p - c w
                osc = field("osc", ca.vertcat(zq, ct.minv_normal * a_osc, e_p * w, 0), True, (a_osc, 0))
                push = field("push", ca.vertcat(-PUSH_SPEED * ct.normal / ca.dot(ct.normal, ct.normal), zv, e_p * PUSH_SPEED, 0), True)
                al = switch("alpha", w, "n^T v", ALPHA_STAR)
                be = switch("beta", ct.gap, "c(q)", BETA_STAR)
                et = switch("eta", p, "p", ETA_STAR)
                ip += 1
                mix = be * (et * ode + (1 - et) * push) + (1 - be) * (et * ((1 - al) * osc + al * ode) + (1 - et) * osc)
                continue
            no_slip = model is ContactModel.NO_SLIP
            a_n = field("a_n", ca.vertcat(zq, contact.a_n * ct.minv_normal, zp, 0), True, (contact.a_n, 0))
            dae_v = ct.dae_no_slip_v if no_slip else ct.dae_v
            dae = field("dae_f" if no_slip else "dae", ca.vertcat(v, dae_v, zp, 1), False)
            al = switch("alpha", ct.normal_velocity, "n^T v", ALPHA_STAR)
            be = switch("beta", ct.gap, "c(q)", BETA_STAR)
            ga = switch("gamma", ct.phi, "phi", GAMMA_STAR)
            if no_slip or self.frictionless_tangential:
                a_tg = contact.a_t if no_slip else 0.0
                a_t = field("a_t", ca.vertcat(zq, a_tg * ct.minv_tangent, zp, 0), True, (0, a_tg))
                ze = switch("zeta", ct.tangential_velocity, "t^T v", ZETA_STAR, no_slip)
                jmp = (1 - al) * a_n + (1 - 2 * ze) * a_t
                df = (1 / ALPHA_STAR) * ((1 - ga) * dae + ga * ode) - (1 - ga) * a_n
                mix = be * ode + (1 - be) * (jmp + al * df)
            else:
                df = (1 - ga) * (2.0 * dae - a_n) + 2.0 * ga * ode
                mix = be * ode + (1 - be) * ((1 - al) * a_n + al * df)

        self._finish(mix, values, impulses, h)

    def _finish(self, mix: Mix, values: dict, impulses: dict, h: list) -> None:
        """Freeze fields and switches and build the numeric Functions (shared by both constructions)."""
        self.fields, self.switches = tuple(self.fields), tuple(self.switches)
        names = [f.name for f in self.fields]
        self.coefficients = {name: mix.parts.get(name, Poly()) for name in names}
        self.field_matrix = ca.horzcat(*[values[name] for name in names])
        self.switching = ca.vertcat(*h) if h else ca.SX(0, 1)
        rows = []
        for label in self.labels:  # normal and tangential impulse rates of each contact
            for k in (0, 1):
                rows.append(ca.horzcat(*[impulses[f.name][k] if f.contact in (None, label) else 0 for f in self.fields]))
        self.impulse_rates = ca.vertcat(*rows) if rows else ca.SX(0, len(names))
        args, arg_names = [self.y, self.u], ["y", "u"]
        self.fields_fn = ca.Function("tf_fields", args, [self.field_matrix], arg_names, ["f"])
        sw_args = args + ([self.lam] if self.n_lambda else [])  # several contacts: gamma_i switches on -lambda_n,i
        self.switching_fn = ca.Function("tf_switching", sw_args, [self.switching], arg_names + (["lam"] if self.n_lambda else []), ["h"])
        self.impulse_fn = ca.Function("tf_impulse", args, [self.impulse_rates], arg_names, ["impulse_rate"])
        gaps = ca.vertcat(*[ct.gap for ct in self.terms]) if self.terms else ca.SX(0, 1)
        self.gap_fn = ca.Function("tf_gap", args, [gaps], arg_names, ["c"])
        approach = ca.vertcat(*[ct.normal_velocity for ct in self.terms]) if self.terms else ca.SX(0, 1)
        self.normal_velocity_fn = ca.Function("tf_normal_velocity", args, [approach], arg_names, ["nv"])

    def _compose(self, ground_height: float, q, v, M, fv, values: dict, impulses: dict, h: list) -> None:
        """The multi-contact rule (module docstring; docs/formulation.md, "Several contacts")."""
        dyn, zq = self.dyn, ca.SX.zeros(self.nq)
        self.terms = [contact_terms(dyn, c.point, ground_height, q, v, self.u, M=M, fv=fv, surface=c.normal) for c in self.contacts]
        # contact forces: (lambda_n, lambda_t) per no-slip point, lambda_n per frictionless point [N]
        sizes = [2 if m is ContactModel.NO_SLIP else 1 for m in self.models]
        self.lam = ca.SX.sym("lam", sum(sizes))
        start, names, rows_J, rows_jdv, minv_JT = 0, [], [], [], []
        for label, size, ct in zip(self.labels, sizes, self.terms):
            self.lam_index[label] = slice(start, start + size)
            names += [f"lambda_{'nt'[j]}[{label}]" for j in range(size)]
            rows_J += [ct.normal.T, ct.tangent.T][:size]
            rows_jdv += [ct.normal_drift, ct.tangent_drift][:size]
            minv_JT += [ct.minv_normal, ct.minv_tangent][:size]
            start += size
        self.lam_names = tuple(names)
        J, jdv = ca.vertcat(*rows_J), ca.vertcat(*rows_jdv)
        acc = fv + ca.mtimes(ca.horzcat(*minv_JT), self.lam)  # a = M^-1 (B u - h + J^T lambda)
        self.constraint = ca.mtimes(J, acc) + jdv  # J a + dJ/dt v (n_lambda,) [m/s^2]
        # kappa [1/kg] turns a force into an acceleration in the rows of points that are switched off
        self.force_scale = 1.0 / max(sum(float(i.mass) for i in dyn.robot.model.inertias), 1e-9)
        zp = ca.SX.zeros(0)
        selectors = []
        for contact, model, ct, label in zip(self.contacts, self.models, self.terms, self.labels):
            def switch(name, expr, what, wanted, regularized=True):
                h.append(expr)
                self.switches.append(Switch(f"{name}[{label}]", label, what, wanted, regularized))
                return Poly.var(len(self.switches) - 1)

            lam_n = self.lam[self.lam_index[label].start]
            sel = {"alpha": switch("alpha", ct.normal_velocity, "n^T v", ALPHA_STAR),
                   "beta": switch("beta", ct.gap, "c(q)", BETA_STAR),
                   "gamma": switch("gamma", -lam_n, "-lambda_n", GAMMA_STAR)}
            if model is ContactModel.NO_SLIP or self.frictionless_tangential:
                sel["zeta"] = switch("zeta", ct.tangential_velocity, "t^T v", ZETA_STAR, model is ContactModel.NO_SLIP)
            selectors.append(sel)
        # fields: per point the auxiliary a_n (, a_t) and the unit-force fields of its lambda entries
        force_fields = []
        for contact, model, ct, label in zip(self.contacts, self.models, self.terms, self.labels):
            def field(name, value, auxiliary, impulse=(0, 0)):
                key = f"{name}[{label}]"
                values[key], impulses[key] = value, impulse
                self.fields.append(Field(key, label, auxiliary))

            field("a_n", ca.vertcat(zq, contact.a_n * ct.minv_normal, zp, 0), True, (contact.a_n, 0))
            if model is ContactModel.NO_SLIP or self.frictionless_tangential:
                a_tg = contact.a_t if model is ContactModel.NO_SLIP else 0.0
                field("a_t", ca.vertcat(zq, a_tg * ct.minv_tangent, zp, 0), True, (0, a_tg))
            field("lam_n", ca.vertcat(zq, ct.minv_normal, zp, 0), False)
            force_fields.append(f"lam_n[{label}]")
            if model is ContactModel.NO_SLIP:
                field("lam_t", ca.vertcat(zq, ct.minv_tangent, zp, 0), False)
                force_fields.append(f"lam_t[{label}]")
        names = [f.name for f in self.fields]
        self.force_columns = tuple(names.index(n) for n in force_fields)
        # factors: clock factor r_i and DAE-forming gate g_i per point, then prefix/suffix chains of the r_i
        n_sigma, factors = len(self.switches), []

        def factor(name, definition, upper):
            factors.append(Factor(name, definition, upper))
            return Poly.var(n_sigma + len(factors) - 1), upper

        r, g = [], []
        for sel, label in zip(selectors, self.labels):
            al, be, ga = sel["alpha"], sel["beta"], sel["gamma"]
            r.append(factor(f"r[{label}]", be + (1 / ALPHA_STAR) * (1 - be) * al, 1 / ALPHA_STAR))
            g.append(factor(f"g[{label}]", (1 - be) * al * (1 - ga), 1.0))
        m = len(r)
        pre, suf = [(Poly({(): 1.0}), 1.0)] * (m + 1), [(Poly({(): 1.0}), 1.0)] * (m + 2)
        pre[1], suf[m] = r[0], r[m - 1]
        for k in range(2, m):  # pre[k] = r_1 ... r_k, suf[k] = r_k ... r_m as factors (k < m, k > 1)
            pre[k] = factor(f"r[1..{k}]", pre[k - 1][0] * r[k - 1][0], pre[k - 1][1] * r[k - 1][1])
        for k in range(m - 1, 1, -1):
            suf[k] = factor(f"r[{k}..{m}]", r[k - 1][0] * suf[k + 1][0], r[k - 1][1] * suf[k + 1][1])
        self.factors = tuple(factors)
        clock = pre[m - 1][0] * r[m - 1][0]  # R = prod_i r_i
        mix = clock * Mix.field("ode")
        for i, (sel, label, model) in enumerate(zip(selectors, self.labels, self.models)):
            al, be = sel["alpha"], sel["beta"]
            others = pre[i][0] * suf[i + 2][0]  # R_-i
            mix = mix + ((1 - be) * (1 - al) - others * g[i][0]) * Mix.field(f"a_n[{label}]")
            if "zeta" in sel:
                mix = mix + ((1 - be) * (1 - 2 * sel["zeta"])) * Mix.field(f"a_t[{label}]")
        switches = []
        for sel, size in zip(selectors, sizes):
            switches += [(1 - sel["beta"]) * (1 - sel["gamma"])] * size
        self.constraint_switches = tuple(switches)
        self._finish(mix, values, impulses, h)
        self.constraint_fn = ca.Function("tf_constraint", [self.y, self.u, self.lam], [self.constraint], ["y", "u", "lam"], ["Ja"])

    def mass_matrix_form(self) -> MassMatrixForm:
        """The fields with M^-1 taken out (see MassMatrixForm); built on first use.
        Raises InputError for elastic contacts (their oscillator force is not written in this form)."""
        if self._mm_form is None:
            self._mm_form = _mass_matrix_form(self)
        return self._mm_form

    @property
    def n_sigma(self) -> int:
        return len(self.switches)

    @property
    def n_lambda(self) -> int:
        """Number of algebraic contact forces (0 for one contact)."""
        return self.lam.shape[0]

    def variables(self, sigma):
        """The polynomial variables (n_sigma + n_factors,): the selectors sigma, then the factors
        evaluated in order (numbers or CasADi expressions)."""
        vals = [sigma[i] for i in range(self.n_sigma)]
        for f in self.factors:
            vals.append(f.definition(vals))
        if isinstance(sigma, (ca.SX, ca.MX)):
            return ca.vertcat(*vals) if vals else sigma
        return np.array([float(x) for x in vals])

    @property
    def n_fields(self) -> int:
        return len(self.fields)

    @property
    def wanted(self) -> np.ndarray:
        """sigma* (n_sigma,)."""
        return np.array([s.wanted for s in self.switches], dtype=float)

    @property
    def regularized(self) -> np.ndarray:
        """(n_sigma,) bool: the selectors in rho_f ||sigma - sigma*||^2 (Switch.regularized)."""
        return np.array([s.regularized for s in self.switches], dtype=bool)

    @property
    def auxiliary_mask(self) -> np.ndarray:
        """(n_fields,) bool: which fields are auxiliary (clock-frozen) motions."""
        return np.array([f.auxiliary for f in self.fields])

    def coefficient_vector(self, sigma, lam=None):
        """(n_fields,) values P_j(sigma) for numbers or CasADi expressions sigma (n_sigma,). Several
        contacts: the unit-force fields get R lambda_k (lam (n_lambda,) [N], default the symbols),
        R the coefficient of f_ODE."""
        symbolic = isinstance(sigma, (ca.SX, ca.MX))
        x = self.variables(sigma) if self.factors else sigma
        vals = [self.coefficients[f.name](x) for f in self.fields]
        if self.n_lambda:
            lam = self.lam if lam is None else lam
            clock = vals[0]  # the coefficient of "ode"
            for k, j in enumerate(self.force_columns):
                vals[j] = vals[j] + clock * lam[k]
        if symbolic or any(isinstance(v, (ca.SX, ca.MX)) for v in vals):
            return ca.vertcat(*vals)
        return np.array([float(v) for v in vals])

    def vector_field(self, sigma, y=None, u=None, lam=None):
        """F(y, sigma, u) (ny,), the unlifted multi-affine field (eq. 17 / 27); y, u default to the symbols
        (several contacts: lam (n_lambda,) the contact forces, default the symbols)."""
        fmat = self.field_matrix if y is None and u is None else self.fields_fn(self.y if y is None else y, self.u if u is None else u)
        coef = self.coefficient_vector(sigma, lam)
        return ca.mtimes(fmat, ca.DM(coef) if isinstance(coef, np.ndarray) else coef)

    def constraint_rows(self, y, u, lam, s):
        """The switched force rows s_i (J_i a + dJ_i/dt v) + (1 - s_i) kappa lambda_i (n_lambda,) at
        y (ny,), u (nu,), lam (n_lambda,) and the per-row switches s (n_lambda,) (several contacts)."""
        return s * self.constraint_fn(y, u, lam) + (1 - s) * self.force_scale * lam

    def field(self, name: str) -> ca.SX:
        """The symbolic field f_j(y, u) named `name` (ny,)."""
        names = [f.name for f in self.fields]
        if name not in names:
            raise InputError(f"no field {name!r}; fields: {', '.join(names)}")
        return self.field_matrix[:, names.index(name)]

    def initial_state(self, q0, v0) -> np.ndarray:
        """y0 = (q0, v0, p = 0, t = 0) (ny,)."""
        y0 = np.zeros(self.ny)
        y0[: self.nq], y0[self.nq : self.nq + self.nv] = q0, v0
        return y0


@dataclass(frozen=True, eq=False)
class MassMatrixForm:
    """The time-freezing fields without M(q)^-1: every field's velocity part is M^-1 g_j with a
    generalized force g_j (ode: B u - h; a_n: a_n n; a_t: a_t t; DAE: B u - h + J^T lambda), and the
    quantities that need M^-1 become algebraic variables z = (acc, lam, d) defined by equations:

        M acc = B u - h                   (acc = f_v, the free acceleration; phi = n^T acc + drift_z)
        M d = J^T lam                     (one d (nv,) per contact)
        J (acc + d) + dJ/dt v = 0         (the no-slip / normal index-1 condition; J = [n t]^T, or n^T
                                           for a frictionless contact) -> lam = the index-reduced force

    A discretization multiplies the velocity rows of y' = F by M(q) and adds `defining` = 0: the
    same solutions, with only M(q), its products and polynomial kinematics in the derivatives (no
    symbolic inverse whose Hessian is expensive).

    Symbols: y (ny,), u (nu,) of the system, z (nz,) = vertcat(acc, lam, d); z_names (nz,).
    force_matrix (ny, n_fields): column j is f_j with its velocity rows replaced by g_j.
    switching (n_sigma,): h(y, u) with phi written with acc. defining (nz,): the equations above.
    mass (nv, nv): M(q). lam_index: contact point -> slice of lam inside z (n, t order).
    fn: Function (y, u, z) -> (force_matrix, switching, defining, mass).
    """

    z: ca.SX
    z_names: tuple[str, ...]
    force_matrix: ca.SX
    switching: ca.SX
    defining: ca.SX
    mass: ca.SX
    lam_index: dict
    fn: ca.Function
    # several contacts: z = (acc, lam, d) with ONE d = M^-1 J^T lam (nv,) for all points; `defining`
    # holds M acc = B u - h and M d = J^T lam, `constraint` (n_lambda,) = J (acc + d) + dJ/dt v, which
    # the step switches per point (TimeFreezingSystem.constraint_rows); constraint_fn (y, u, z).
    lam_slice: slice | None = None
    constraint_fn: ca.Function | None = None

    @property
    def nz(self) -> int:
        return self.z.shape[0]


def _mass_matrix_form(system: TimeFreezingSystem) -> MassMatrixForm:
    if any(m is ContactModel.ELASTIC for m in system.models):
        raise InputError("the mass-matrix form is not available for elastic contacts (restitution > 0)")
    if system.n_lambda:
        return _mass_matrix_form_several(system)
    dyn, nq, nv = system.dyn, system.nq, system.nv
    y, u = system.y, system.u
    q, v = y[:nq], y[nq : nq + nv]
    M = system._mass
    tau = ca.mtimes(ca.DM(dyn.actuation), u) - dyn.bias(q, v)
    acc = ca.SX.sym("acc", nv)
    lams, ds, defining, lam_index = [], [], [ca.mtimes(M, acc) - tau], {}
    lam_names, d_names = [], []
    forces = {"ode": tau}
    phi = {}
    n_lam = 0
    for contact, model, ct in zip(system.contacts, system.models, system.terms):
        pt = contact.point
        no_slip = model is ContactModel.NO_SLIP
        J = ca.horzcat(ct.normal, ct.tangent).T if no_slip else ct.normal.T
        jdv = ca.vertcat(ct.normal_drift, ct.tangent_drift) if no_slip else ct.normal_drift
        m = J.shape[0]
        lam = ca.SX.sym(f"lam_{len(lams)}", m)
        d = ca.SX.sym(f"d_{len(ds)}", nv)
        lam_index[pt] = slice(n_lam, n_lam + m)
        n_lam += m
        lams.append(lam)
        ds.append(d)
        lam_names += [f"lambda_{'nt'[j]}[{pt}]" for j in range(m)]
        d_names += [f"d[{pt}][{j}]" for j in range(nv)]
        defining += [ca.mtimes(M, d) - ca.mtimes(J.T, lam), ca.mtimes(J, acc + d) + jdv]
        forces[f"a_n[{pt}]"] = contact.a_n * ct.normal
        if no_slip:
            forces[f"a_t[{pt}]"] = contact.a_t * ct.tangent
            forces[f"dae_f[{pt}]"] = tau + ca.mtimes(J.T, lam)
        else:
            forces[f"dae[{pt}]"] = tau + ca.mtimes(J.T, lam)
            forces[f"a_t[{pt}]"] = ca.SX.zeros(nv)  # frictionless_tangential: the jump field of gain 0
        phi[pt] = ca.dot(ct.normal, acc) + ct.normal_drift
    names = [f"acc[{i}]" for i in range(nv)] + lam_names + d_names
    cols = []
    for j, f in enumerate(system.fields):
        col = system.field_matrix[:, j]
        cols.append(ca.vertcat(col[:nq], forces[f.name], col[nq + nv :]))
    sw = [phi[s.contact] if s.function == "phi" else system.switching[i] for i, s in enumerate(system.switches)]
    # lam before d so that lam_index slices are offsets from nv
    z = ca.vertcat(acc, *lams, *ds)
    lam_index = {pt: slice(nv + sl.start, nv + sl.stop) for pt, sl in lam_index.items()}
    fmat, switching, defn = ca.horzcat(*cols), ca.vertcat(*sw), ca.vertcat(*defining)
    fn = ca.Function("tf_mass_matrix_form", [y, u, z], [fmat, switching, defn, M], ["y", "u", "z"], ["g", "h", "defining", "M"])
    return MassMatrixForm(z=z, z_names=tuple(names), force_matrix=fmat, switching=switching, defining=defn, mass=M,
                          lam_index=lam_index, fn=fn)


def _mass_matrix_form_several(system: TimeFreezingSystem) -> MassMatrixForm:
    """Several contacts: z = (acc, lam, d); see MassMatrixForm."""
    dyn, nq, nv = system.dyn, system.nq, system.nv
    y, u = system.y, system.u
    q, v = y[:nq], y[nq : nq + nv]
    M = system._mass
    tau = ca.mtimes(ca.DM(dyn.actuation), u) - dyn.bias(q, v)
    acc, d = ca.SX.sym("acc", nv), ca.SX.sym("d", nv)
    lam = ca.SX.sym("lam", system.n_lambda)
    rows_J, rows_jdv, forces = [], [], {"ode": tau}
    for contact, model, ct, label in zip(system.contacts, system.models, system.terms, system.labels):
        no_slip = model is ContactModel.NO_SLIP
        rows_J += [ct.normal.T] + ([ct.tangent.T] if no_slip else [])
        rows_jdv += [ct.normal_drift] + ([ct.tangent_drift] if no_slip else [])
        forces[f"a_n[{label}]"] = contact.a_n * ct.normal
        forces[f"lam_n[{label}]"] = ct.normal
        forces[f"a_t[{label}]"] = (contact.a_t if no_slip else 0.0) * ct.tangent  # 0: frictionless_tangential
        if no_slip:
            forces[f"lam_t[{label}]"] = ct.tangent
    J = ca.vertcat(*rows_J)
    defining = ca.vertcat(ca.mtimes(M, acc) - tau, ca.mtimes(M, d) - ca.mtimes(J.T, lam))
    constraint = ca.mtimes(J, acc + d) + ca.vertcat(*rows_jdv)
    cols = []
    for j, f in enumerate(system.fields):
        col = system.field_matrix[:, j]
        cols.append(ca.vertcat(col[:nq], forces[f.name], col[nq + nv :]))
    switching = ca.substitute(system.switching, system.lam, lam)  # gamma_i: -lambda_n,i, the z entry
    z = ca.vertcat(acc, lam, d)
    names = [f"acc[{i}]" for i in range(nv)] + list(system.lam_names) + [f"d[{i}]" for i in range(nv)]
    lam_index = {label: slice(nv + sl.start, nv + sl.stop) for label, sl in system.lam_index.items()}
    fmat = ca.horzcat(*cols)
    fn = ca.Function("tf_mass_matrix_form", [y, u, z], [fmat, switching, defining, M], ["y", "u", "z"], ["g", "h", "defining", "M"])
    cfn = ca.Function("tf_mass_matrix_constraint", [y, u, z], [constraint], ["y", "u", "z"], ["Ja"])
    return MassMatrixForm(z=z, z_names=tuple(names), force_matrix=fmat, switching=switching, defining=defining, mass=M,
                          lam_index=lam_index, fn=fn, lam_slice=slice(nv, nv + system.n_lambda), constraint_fn=cfn)
