"""The time-freezing optimal control problem (paper Sec. 7, eq. 29) as one inspectable NLP.

Direct transcription with N regularized implicit-Euler steps (planner.discretization), the step built
once on symbols and called at every k (Problem.stages, which planner.derivatives derives once). Stage k
(k = 0 .. N-1) owns, in this order, the variables

    u_k (nu,)      control, constant over the step [N m or N]
    s_k (1,)       speed of time (only when the task sets horizon.physical_time)
    y_{k+1} (ny,)  state at the end of the step, clock last
    w_k (nw,)      the step's algebraic variables: sigma, theta (lifted products), lambda0, lambda1
                   and, with StepForm.MASS_MATRIX, "forces" (free acceleration, contact forces, M^-1 J^T lam)

and after the N stages the one l_inf slack s_c (Penalty.LINF only). y_0 is the task's initial state,
a constant, except for a periodic task (plan.periodic), where it is the block "y0" (ny,) ahead of
the stages (q in the joint bounds, the fixed coordinates and the clock pinned). The NLP's parameters
(Problem.params) include the complementarity penalty rho, so the homotopy builds IPOPT once and
only changes rho, and the scale r of the holes
(((x - xc)/a)^2 + ((z - zc)/b)^2 >= r^2; r = 1 is the task's scene, r = 0 drops the holes), so the
solver can run a continuation in the scene without rebuilding.

Constraints (named blocks of g, each an (N, m) index array; `Problem.g_blocks`):

    dynamics, stationarity, lifting   the implicit Euler step (eq. 24b, c; lifting of Sec. 5.1)
    above_ground                      z of each task.plan.above_ground point >= ground_height
    holes                             each contact point outside each ellipse (scaled by r), without
                                      the pairs the scene analysis finds out of reach (planner.scene)
    never_touching                    gap >= 0 of each contact with touches = false (planner.scene)
    above_ground_y0, holes_y0, never_touching_y0 (1, m): the same at y_0 where it is free (plan.periodic)
    friction_cone                     P_DAE(sigma) (mu lambda_n -+ lambda_t) >= 0 (see below)
    impact_cone                       mu a_n P_an(sigma) -+ a_t P_at(sigma) >= 0 (ProblemOptions.impact_cone)
    velocity_bounds                   task.plan.velocity_bounds (sums of joint velocities) at y_1 .. y_N
    velocity_bounds_y0 (1, m)         the same at y_0 where it is free (plan.periodic)
    contact_forces                    MASS_MATRIX steps: M acc = B u - h, M d = J^T lam, J (acc + d) + dJ/dt v = 0;
                                      with several contacts (either form) also their constraint forces' rows
    terminal (1, nq [+ nv])           q_N = target_q [, v_N = target_v]
    periodic (1, nq + nv)             plan.periodic instead of terminal: q_N = S q_0 + step e_along, v_N = S v_0
    physical_time (1, 1)              t_N = T (only with horizon.physical_time)
    penalty (N, 2 n_sigma)            s_c - a b >= 0 for every complementarity pair (Penalty.LINF)

The friction cone |lambda_t| <= mu lambda_n holds on the index-reduced no-slip forces (contact.py)
and only where the contact is persistent. The weight that says "persistent" is the coefficient of
the DAE field in F, P_DAE(sigma) = (1 - beta) alpha (1 - gamma) / alpha*: a linear function of the
lifted variables (no new product), equal to 1 on the sliding manifold with the wanted selectors and
0 in flight (beta = 1), in a frozen impact (alpha = 0) and at contact breaking (gamma = 1), where
the explicit forces are meaningless. Multiplying by it keeps the constraint smooth; it is exact at
a complementarity-feasible point because P_DAE is then 0 or 1 wherever the DAE force acts at all.
With several contact points the cone is written on each point's joint force variables and weighted
by the clock rate R (the ODE field's coefficient), through which those forces act (docs/formulation.md,
"Periodic walking").

Bounds: |u| <= u_bound (or the actuators' range), joint bounds on every q_{k+1} (task.q_bounds), the robot file's
joint speed limits on every v_{k+1} (a URDF's <limit velocity>, Robot.v_limit),
selectors and lifted products in [0, 1], multipliers >= 0, 1 <= s_k <= horizon.max_time_speed (none: unbounded),
s_c >= 0.

Objective pieces (`Problem.objective_parts`): control = sum_k h s_k u_k^T u_k (int u^2 dtau, each step h s_k long;
s_k = 1 without physical_time),
selectors = rho_f sum_k ||sigma_k - sigma*||^2 (eq. 24a), penalty = rho s_c (LINF) or
rho sum of all products (L1).

Initial guess x0 (the paper's hint-free start): y_0 at every node, u = 0, s = 1, selectors and
multipliers consistent with the switching functions at y_0 (ImplicitEulerStep.guess), s_c = the
largest product of that guess (0).

FESD stages (ProblemOptions.discretization = FESD; `_build_fesd`): each step is a FESDInterval of
n_fe Radau IIA elements with free lengths and n_s stages each; every stage is an implicit-Euler stage
(same selectors, lifting, stationarity, forces) and the pairs are the cross-complementarity of
FESDInterval. Blocks and shapes are in `_build_fesd`'s docstring; docs/formulation.md, "FESD in the OCP".
"""
from __future__ import annotations

import copy
import hashlib
import math
import pickle
import time
import warnings
from dataclasses import dataclass, field, replace
from enum import Enum

import casadi as ca
import numpy as np

from .discretization import Discretization, FESDInterval, FESDOptions, ImplicitEulerStep, StepForm, SwitchVelocity
from .dynamics import Dynamics, dynamics_for
from .errors import InputError, check_field_types, enum_field, expect, plain, real_array, shown, shown_up
from .contact import plane_axes
from .model import Robot, robot_weight
from .scene import Skips, analyze_scene
from .task import Task, task_source
from .timefreezing import ContactModel, TimeFreezingSystem


HOLE_EDGE_TOL = 1e-9  # a point on a hole's edge (metric 1, e.g. a target at its rim) is outside
START_GAP_M = 1e-9  # [m] a start or target this far into a contact plane is on it (heights typed to 9 digits)
PARAMETERS = ("rho", "hole_scale", "an_scale", "at_scale", "terminal_weight", "rho_l1", "rho_f_scale")  # p, in Problem.params' order


class Penalty(Enum):
    """How the complementarity products enter the objective (paper Sec. 5.2)."""

    LINF = "linf"  # one slack s_c >= every product, + rho s_c (the paper's choice)
    L1 = "l1"  # + rho * sum of the products (no slack, no extra inequalities)


@dataclass(frozen=True)
class ProblemOptions:
    """Formulation choices of the OCP (numbers in docs/formulation.md, "OCP and solve").

    penalty: LINF (default, the paper's) or L1. Ungated, LINF let every product below the slack float
      to the barrier's centre and measured stuck on a contact-mode "flight"; with gating (default)
      that degeneracy is gone and LINF + gating is the only combination measured to converge on
      Capler (docs/formulation.md, "OCP and solve"); L1 prices each pair.
    switch_scale: (function, scale) pairs dividing a switching function in the stationarity
      condition, keyed by Switch.function ("n^T v", "c(q)", "phi", "t^T v"); theta(h / a) = theta(h),
      so the solution is the same and only the multipliers lambda0, lambda1 shrink by a. phi is
      ~100x n^T v on Capler. Complementarity residuals are always reported in the unscaled units.
    friction_cone: impose |lambda_t| <= mu lambda_n weighted by P_DAE (only for NO_SLIP contacts).
    terminal_velocity: also impose v_N = target_v (zeros when the task omits it); the paper imposes
      q only.
    clock_guess_running: initial clock guess t = tau (running) instead of y_0's t = 0.
    gating: multiply the penalty's products of the alpha and zeta pairs by (1 - beta) and of the
      gamma pair by (1 - beta) alpha (the lifted product): F depends on alpha, zeta only through
      (1 - beta) and on gamma only through (1 - beta) alpha, so the gated problem has the same state
      trajectories (the irrelevant selectors are reset by homotopy.ungate afterwards). Removes the
      flight-phase degeneracy. The reported complementarity residual is always the ungated one.
    aux_continuation: multiply the auxiliary fields a_n, a_t by the NLP parameters an_scale,
      at_scale (Problem.params), so the solver can start with weak auxiliary gains (a wrong zeta
      or alpha then buys little free propulsion) and continue to the task's gains (scale 1).
    step_form: StepForm of the implicit Euler steps; MASS_MATRIX (default) keeps M(q)^-1 out of the
      derivatives (the friction cone then uses the step's force variables lambda_n, lambda_t).
    velocity_switch: SwitchVelocity of the steps' n^T v and t^T v (discretization.py). SECANT (default)
      keeps the gap in persistent contact; with the paper's POINT the stances sink (2.6 cm on Capler
      N = 50), an exactly complementary plan cannot end standing at the target after moving, and the
      full Capler task did not converge (docs/formulation.md, "OCP and solve", round 4).
    impact_cone: for one NO_SLIP contact with a_t <= mu a_n, keep each step's auxiliary impulse in the
      friction cone: |a_t P_at(sigma)| <= mu a_n P_an(sigma), with P_an, P_at the coefficients of the
      a_n and a_t fields (linear in the lifted variables). Without it a stance step whose t^T v ends
      at 0 leaves zeta free in [0, 1] and the a_t field can brake any tangential speed within one
      step with the clock running (point-mass stress task rho_f-03: 1.5 m/s in 25 ms, 60 N against
      a friction limit of 4.9 N; docs/stability.md). With the paper's a_t >> a_n (a_t > mu a_n) it
      would forbid every impact with a tangential velocity, so it is not imposed there.
    clock_weight: objective + clock_weight sum_k (R_k (1 - R_k))^2 with R_k the step's clock rate (the
      coefficient of the ODE field, linear in the lifted variables; objective part "clock"): zero
      in running steps (R = 1) and in frozen impacts (R = 0), positive for a partly frozen step.
      Default 0 (off): on the periodic biped walk, where the stance runs partly frozen without it,
      10 and 100 both kept the homotopy from converging (docs/formulation.md, "Periodic walking").
    discretization: Discretization of the stages. IMPLICIT_EULER (default): one ImplicitEulerStep per
      step h. FESD: one FESDInterval per step (n_fe Radau IIA elements of n_s stages with free
      lengths, cross-complementarity; `fesd`), see "FESD stages" below and docs/formulation.md,
      "FESD in the OCP". Needs clock_weight = 0 (InputError otherwise). With gating, a cross pair
      is gated (and reported) with the gate of its selector's stage: a selector switched off by the
      gates may change sign inside an element (e.g. alpha, n^T v, at a flight's apex).
    fesd: FESDOptions (n_s, n_fe, rho_h) of the FESD stages; only the default with IMPLICIT_EULER.
    lift_products: ImplicitEulerStep's lift_products: True (default) makes the products of selectors
      variables with bilinear lifting rows and bounds (the paper's Sec. 5.1); False substitutes them
      (Capler: 4 variables and rows fewer per step, IPOPT iterations ~12 % cheaper, but over the
      seven-task set as many iterations and costlier plans; docs/benchmarks.md, session 22).
    scene_analysis: build only what the scene needs (planner.scene: no tangential machinery for
      mu = 0, no contact machinery for touches = false, no holes out of reach or wholly below a flat
      ground); False builds it all, the reference the skips are measured against (scripts/bench_skips.py).
    """

    penalty: Penalty = Penalty.LINF
    step_form: StepForm = StepForm.MASS_MATRIX
    switch_scale: tuple[tuple[str, float], ...] = ()
    friction_cone: bool = True
    impact_cone: bool = True
    terminal_velocity: bool = True
    clock_guess_running: bool = False
    gating: bool = True
    aux_continuation: bool = False
    velocity_switch: SwitchVelocity = SwitchVelocity.SECANT
    clock_weight: float = 0.0
    scene_analysis: bool = True
    discretization: Discretization = Discretization.IMPLICIT_EULER
    fesd: FESDOptions = FESDOptions()
    lift_products: bool = True

    def __post_init__(self):
        check_field_types(self)  # lift_products, scene_analysis, the cones' flags, clock_weight
        enum_field(self, "discretization", Discretization)
        if not isinstance(self.fesd, FESDOptions):
            raise InputError(f"ProblemOptions.fesd = {self.fesd!r} is not allowed; it must be a FESDOptions(n_s, n_fe, rho_h)")
        if self.discretization is not Discretization.FESD and self.fesd != FESDOptions():
            raise InputError(f"ProblemOptions.fesd = {self.fesd!r} sets the FESD discretization, which discretization "
                             f"= {self.discretization.value} would ignore; add discretization=Discretization.FESD")
        if self.discretization is Discretization.FESD:
            if self.clock_weight != 0:
                raise InputError(f"ProblemOptions.clock_weight = {self.clock_weight!r} is not allowed with discretization fesd; it must be 0")
        # COLLOCATED: planner simulate only (untried in the OCP)
        enum_field(self, "velocity_switch", SwitchVelocity,
                   [p for p in SwitchVelocity if p is not SwitchVelocity.COLLOCATED])
        enum_field(self, "step_form", StepForm)
        if not self.clock_weight >= 0:
            raise InputError(f"ProblemOptions.clock_weight = {self.clock_weight!r} is not allowed; it must be >= 0")
        enum_field(self, "penalty", Penalty)
        entries = self.switch_scale if isinstance(self.switch_scale, (tuple, list)) else None
        for entry in entries if entries is not None else (self.switch_scale,):
            ok = isinstance(entry, (tuple, list)) and len(entry) == 2 and isinstance(entry[0], str)
            scale = plain(entry[1]) if ok else None
            if not (ok and isinstance(scale, (int, float)) and not isinstance(scale, bool) and 0 < scale < float("inf")):
                raise InputError(f"ProblemOptions.switch_scale entry {entry!r} is not allowed; it must be a pair (function name, "
                                 "finite scale > 0), e.g. (('phi', 100.0),)")
        names = [name for name, _ in entries]
        if len(set(names)) != len(names):
            raise InputError(f"ProblemOptions.switch_scale names a function twice: {names}")
        # the plain str of the name: a numpy name (np.str_) kept as given made equal options' reprs, so
        # Problem.signature, differ; str.__str__, not str(), which a str Enum's member answers with "Names.PHI"
        object.__setattr__(self, "switch_scale", tuple((str.__str__(name), float(plain(scale)))
                                                       for name, scale in entries))


@dataclass(frozen=True)
class Pair:
    """One complementarity pair a * b = 0 with a = x[a] and b = x[b] (b_upper: b = 1 - x[b])."""

    a: int
    b: int
    b_upper: bool
    name: str


@dataclass(frozen=True, eq=False)
class Stages:
    """The implicit-Euler steps of a Problem as one Function called at every k (planner.derivatives derives
    it once, at the size of a step, and maps it over the N steps).

    fn(z (nz,), p) -> (g (m,), cost): the step's rows and its selector cost, z = (y_k, u_k, [s_k], y_{k+1}, w_k).
    z_index (N, nz): index of each z entry in (x, y_0): values >= nx are y_0's constants (y_0 = Problem.y0).
    rows (N, m): the rows of g that step k's rows are. cost_weight: index into p of the factor on the costs
    (f = f_rest + p[cost_weight] sum_k cost_k). f_rest: the objective without the steps' costs (SX of x, p)."""

    fn: ca.Function
    z_index: np.ndarray = field(repr=False)
    rows: np.ndarray = field(repr=False)
    cost_weight: int
    f_rest: ca.SX = field(repr=False)


@dataclass(eq=False)
class Problem:
    """The transcribed OCP. Everything needed to solve, inspect and post-process it.

    x (nx,) SX decision variables, p (7,) SX parameters (Problem.params), f objective, g (ng,)
    constraints with lbg <= g <= ubg; lbx, ubx, x0 (nx,) bounds and the hint-free initial guess.
    var_names (nx,); var_blocks: name -> int index array into x: "u" (N, nu), "s" (N, 1) if
    present, "y" (N, ny) (states y_1 .. y_N), "w" (N, nw) and its parts "sigma", "theta",
    "lambda0", "lambda1" and, with the mass-matrix step form (the default) or several contacts, "forces"; "s_c"
    (1,) if present, "y0" (ny,) with plan.periodic. g_blocks: name -> int index array into g (see the
    module docstring). pairs: the complementarity pairs over the whole horizon (Pair, in x
    indices); pair_scale (n_pairs,) multiplies a product to give it in unscaled units.
    objective_parts: name -> ca.Function(x, p) -> scalar. Functions: products(x) -> unscaled products, a
    casadi.DM column (n_pairs, 1) (np.asarray(...).ravel() for a vector); trajectory parts via `split(x)`.
    skips: the scene analysis' record (planner.scene); system.contacts are the task's contacts without the
    never-touching ones.
    """

    robot: Robot
    task: Task
    options: ProblemOptions
    system: TimeFreezingSystem
    builder: ImplicitEulerStep
    N: int
    h: float
    y0: np.ndarray
    # (repr=False: the expressions and per-variable arrays made repr(problem) 1.4 million characters for Capler)
    x: ca.SX = field(repr=False)
    p: ca.SX = field(repr=False)
    f: ca.SX = field(repr=False)
    g: ca.SX = field(repr=False)
    lbx: np.ndarray = field(repr=False)
    ubx: np.ndarray = field(repr=False)
    lbg: np.ndarray = field(repr=False)
    ubg: np.ndarray = field(repr=False)
    x0: np.ndarray = field(repr=False)
    var_names: tuple[str, ...] = field(repr=False)
    var_blocks: dict[str, np.ndarray] = field(repr=False)
    g_blocks: dict[str, np.ndarray] = field(repr=False)
    pairs: tuple[Pair, ...] = field(repr=False)
    pair_scale: np.ndarray = field(repr=False)
    objective_parts: dict[str, ca.Function] = field(repr=False)
    products: ca.Function = field(repr=False)
    build_time_s: float = 0.0
    notes: dict = field(default_factory=dict, repr=False)
    skips: Skips = field(default_factory=Skips)  # what the scene analysis left out, with reasons
    fesd: FESDInterval | None = None  # the FESD stages' builder (ProblemOptions.discretization FESD), else None
    stages: Stages | None = None  # the steps as one mapped Function (implicit Euler), else None

    @property
    def nx(self) -> int:
        return self.x.shape[0]

    @property
    def ng(self) -> int:
        return self.g.shape[0]

    @property
    def signature(self) -> str:
        """A digest of var_names and options: problems with the same one have the same x, variable by variable
        (the same N, contacts, discretization and ProblemOptions), whatever the task's numbers (target, holes,
        gains, bounds). A plan's x can start another problem with its signature (planner plan --init). The
        options count whole (switch_scale and velocity_switch change what lambda0, lambda1 mean, the others
        the rows a start is read against), but for clock_guess_running: it sets only the default start."""
        formulation = repr(replace(self.options, clock_guess_running=False))
        return hashlib.sha256("\n".join((*self.var_names, formulation)).encode()).hexdigest()[:16]

    @property
    def variables_signature(self) -> str:
        """A digest of var_names only: Problem.signature before session 50, which plans written then carry."""
        return hashlib.sha256("\n".join(self.var_names).encode()).hexdigest()[:16]

    def params(self, rho: float, hole_scale: float = 1.0, an_scale: float = 1.0, at_scale: float = 1.0,
               terminal_weight: float = 0.0, rho_l1: float = 0.0, rho_f_scale: float = 1.0) -> np.ndarray:
        """The parameter vector p (7,): penalty rho, hole scale r, auxiliary gain scales (only with
        ProblemOptions.aux_continuation), soft-terminal weight (objective + w ||terminal residual||^2;
        the solver relaxes the hard terminal rows when it uses w > 0), with Penalty.LINF an extra
        l1 weight rho_l1 on the sum of the (gated) products (0: the pure l_inf penalty), and a factor on
        the task's rho_f (the selectors' regularizer rho_f ||sigma - sigma*||^2; 1: the task's own)."""
        values = (rho, hole_scale, an_scale, at_scale, terminal_weight, rho_l1, rho_f_scale)
        for name, value in zip(PARAMETERS, values):
            if not (isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)):
                raise InputError(f"Problem.params' {name} must be a number, got {type(value).__name__} {value!r:.60}")
            if not (math.isfinite(value) and value >= 0):  # (a nan penalty or a negative one was solved)
                raise InputError(f"Problem.params' {name} must be finite and >= 0, got {value!r}")
        return np.array(values, dtype=float)

    def __reduce__(self):
        # CasADi pickles SX expressions only inside its pickle context (one serializer for all of them), which
        # multiprocessing and concurrent.futures do not open: a built problem could not be sent to a worker
        with ca.global_pickle_context():
            state = pickle.dumps(self.__dict__)
        return _unpickled_problem, (state,)

    def __copy__(self) -> Problem:  # (not through __reduce__: a copy shares the arrays, as dataclasses.replace)
        new = object.__new__(Problem)
        new.__dict__.update(self.__dict__)
        return new

    def __deepcopy__(self, memo: dict) -> Problem:
        new = object.__new__(Problem)
        memo[id(self)] = new
        new.__dict__.update(copy.deepcopy(self.__dict__, memo))
        return new

    @property
    def edited(self) -> tuple[str, ...]:
        """Which of EDITABLE differ from what build_problem made: terms added to f, rows to g (with lbg, ubg and,
        to see them in constraint_violation, a g_blocks entry), bounds changed (a via-point: lbx = ubx). () for a
        problem as built (or one not made by build_problem)."""
        built = self.notes.get("built", {})
        return tuple(name for name in EDITABLE if name in built and not (
            getattr(self, name) is built[name] if name in ("f", "g") else
            np.array_equal(np.asarray(getattr(self, name)), built[name])))

    def check_solvable(self) -> None:
        """InputError when an input build_problem baked into the NLP changed since (BUILT_INPUTS: the robot, the task,
        the options, N, h, y0, the variables): the NLP would solve the old one while the result recorded the new (a
        task swapped by dataclasses.replace was planned for its old target and written with the new, a robot for the
        old masses and written as the new file's). f must stay a scalar and f, g functions of x and p only. Each
        g_blocks entry must be row indices of g (a list or range is made an int array in place): constraint_violation
        reads them only after the homotopy, where a bad one crashed the solve and a negative one named another row."""
        for name, rows in self.g_blocks.items():
            try:
                idx = np.asarray(rows)
            except (ValueError, TypeError):  # (a ragged list)
                idx = None
            if idx is not None and idx.size == 0:
                idx = idx.astype(int)
            if idx is None or idx.dtype.kind not in "iu" or (idx.size and (idx.min() < 0 or idx.max() >= self.ng)):
                raise InputError(f"problem.g_blocks[{name!r}] = {shown(rows)} is not allowed; it must be row indices "
                                 f"of problem.g, integers in 0 .. {self.ng - 1} (a list, range or int array, e.g. "
                                 "np.arange(first, last + 1))")
            self.g_blocks[name] = idx
        built = self.notes.get("built")
        if built is None:
            return
        changed = [name for name in BUILT_INPUTS if not (
            getattr(self, name) is built[name] if name in ("robot", "x") else
            np.array_equal(np.asarray(getattr(self, name)), built[name]) if name == "y0" else
            getattr(self, name) == built[name])]
        if changed:
            raise InputError(f"problem.{', problem.'.join(changed)} changed after build_problem, which built the NLP "
                             "from them: build the problem again (build_problem(robot, task, options)); a built "
                             f"problem takes edits of {', '.join(EDITABLE)} and x0 only (no new variables)")
        if {"f", "g"} & set(self.edited):
            if self.f.shape != (1, 1):
                raise InputError(f"problem.f must be a scalar expression, got shape {self.f.shape}")
            # np.size: bounds extended with casadi.vertcat are DMs, which have no len()
            n_lbg, n_ubg = np.size(np.asarray(self.lbg)), np.size(np.asarray(self.ubg))
            if self.g.shape[1] != 1 or self.g.shape[0] != n_lbg or self.g.shape[0] != n_ubg:
                raise InputError(f"problem.g must be a column with one entry per lbg, ubg entry, got shape "
                                 f"{self.g.shape} and {n_lbg}, {n_ubg} bounds")
            # (by identity, not name: another build's x has the same names, and CasADi's error came after NLP 1)
            uses = ca.Function("edits", [self.x, self.p], [self.f, self.g], {"allow_free": True})
            free = sorted(str(s) for s in uses.free_sx()) if uses.has_free() else []
            if free:
                raise InputError(f"problem.f or problem.g uses symbols that are not problem.x or problem.p: "
                                 f"{', '.join(free[:5])}; new variables are not supported, add costs of x and rows "
                                 "only")

    def point(self, x) -> np.ndarray:
        """x as a float vector (nx,); an InputError when it has another size (a point of another problem)."""
        x = real_array(x, f"a point of this problem ({self.nx} numbers)").ravel()
        if x.shape != (self.nx,):
            raise InputError(f"a point of this problem has nx = {self.nx} entries, got {x.size} (a point of another "
                             "problem? Problem.signature tells problems with the same variables)")
        return x

    def complementarity_residual(self, x) -> float:
        """max over all pairs of a * b at x (nx,), in unscaled units (the switching functions' own)."""
        return float(np.max(np.abs(np.asarray(self.products(self.point(x)), dtype=float)), initial=0.0))

    def split(self, x) -> dict[str, np.ndarray]:
        """Numeric blocks of x: Y (N+1, ny) with y_0 first, U (N, nu), W (N, nw), S (N,) speeds.
        FESD: W holds each step's last stage (the step's end), and the elements are added: lengths
        "h" (N, n_fe) [s of numerical time], stage states "Ys" (N, n_fe, n_s, ny) and stage
        algebraic variables "Ws" (N, n_fe, n_s, nw)."""
        x = self.point(x)
        y0 = x[self.var_blocks["y0"]] if "y0" in self.var_blocks else self.y0
        Y = np.vstack([y0, x[self.var_blocks["y"]]])
        S = x[self.var_blocks["s"]].ravel() if "s" in self.var_blocks else np.ones(self.N)
        if self.fesd is None:
            return {"Y": Y, "U": x[self.var_blocks["u"]], "W": x[self.var_blocks["w"]], "S": S}
        Ws = x[self.var_blocks["w"]]
        return {"Y": Y, "U": x[self.var_blocks["u"]], "W": Ws[:, -1, -1], "S": S, "h": x[self.var_blocks["h"]],
                "Ys": x[self.var_blocks["Y"]], "Ws": Ws}


def build_problem(robot: Robot, task: Task, options: ProblemOptions = ProblemOptions(), dynamics: Dynamics | None = None) -> Problem:
    """Transcribe the task's OCP (task.plan) for the robot. Raises InputError for a task without a
    plan, without contacts, with an elastic contact, or with an initial state below the ground."""
    start = time.perf_counter()
    expect(robot, Robot, "build_problem's robot")
    expect(task, Task, "build_problem's task")
    expect(options, ProblemOptions, "build_problem's options")
    dyn = dynamics_for(robot, dynamics)
    if task.plan is None:
        raise InputError(f"task {task_source(task) or '(in code)'} has no [plan] table; `planner plan` needs one")
    if not task.contacts:
        raise InputError(f"task {task_source(task) or '(in code)'} has no [[contacts]]; the time-freezing OCP needs at "
                         "least one contact point")
    task.check_against(robot)
    task.require_actuators(robot)
    task.warn_dependent_contacts(robot)
    task.warn_buried_holes(options.scene_analysis)
    task.check_no_slip_forces(robot)
    plan, hz = task.plan, task.horizon
    skips = analyze_scene(robot, task, options.scene_analysis)
    contacts = tuple(c for c in task.contacts if c.point not in skips.never_touching)
    if not contacts:
        raise InputError("every [[contacts]] entry has touches = false; the time-freezing OCP needs at least one point that may touch")
    # before the system, which says "set mu = 0" to a frictional one; a touches = false one too (scene analysis
    # dropped it first: accepted with its restitution, refused with scene_analysis off)
    elastic = [c.point for c in task.contacts if c.restitution > 0]
    if elastic:
        raise InputError(f"contact(s) {', '.join(elastic)}: planning with elastic contacts (restitution > 0) is not supported "
                         "yet; set restitution = 0 (`planner simulate` models frictionless elastic impacts)")
    _warn_far_sized(robot, contacts)
    system = TimeFreezingSystem(dyn, contacts, task.ground_height, frictionless_tangential=not skips.enabled)
    known = {s.function for s in system.switches}
    scale_of = dict(options.switch_scale)
    for name in scale_of:
        if name not in known:
            raise InputError(f"ProblemOptions.switch_scale names {name!r}; the switching functions are {sorted(known)}")
    switch_scale = np.array([scale_of.get(s.function, 1.0) for s in system.switches])
    builder = ImplicitEulerStep(system, plan.rho_f, switch_scale, form=options.step_form, velocity_switch=options.velocity_switch,
                                lift_products=options.lift_products)
    nq, nv, nu, ny, nw, n_sig = system.nq, system.nv, system.nu, system.ny, builder.nw, system.n_sigma
    N, h = hz.N, hz.h
    timed = hz.physical_time is not None
    periodic = plan.periodic is not None

    v0 = np.zeros(nv) if task.initial.v is None else np.array(task.initial.v, float)
    y0 = system.initial_state(np.array(task.initial.q, float), v0)
    states = {"initial.q": y0}
    if plan.target_q is not None:  # the terminal row holds q_N there, where the gap rows forbid it: no plan exists
        states["plan.target_q"] = system.initial_state(np.array(plan.target_q, float), np.zeros(nv))
    never = [c for c in task.contacts if c.point in skips.never_touching]
    for key, y in states.items():
        key = _state_key(key, task)
        gaps = list(np.asarray(system.gap_fn(y, np.zeros(nu)), float).ravel())
        for c in never:  # (their gap >= 0 rows start at node 1: a start in the ground was planned, exit 0)
            gaps.append(float(plane_gap(dyn, c, y[:nq], task.ground_height)))
        for c, gap in zip(contacts + tuple(never), gaps):
            if gap < -START_GAP_M:
                raise InputError(f"{key} puts contact point {c.point!r} {shown_up(-gap)} m "
                                 f"{c.beyond(task.ground_height)}"
                                 + (" (touches = false)" if c in never else "")
                                 + f"; move it out by that much (up to {START_GAP_M:g} m in is allowed)")
        for pt in plan.above_ground:  # (their rows start at node 1 too: a knee in the ground was planned, exit 0)
            height = float(dyn.point_position(pt)(y[:nq])[2]) - task.ground_height
            if height < -START_GAP_M:
                raise InputError(f"{key} puts point {pt!r} {shown_up(-height)} m below the ground (plan.above_ground "
                                 f"holds it above); move it up by that much (up to {START_GAP_M:g} m in is allowed)")
    _check_outside_holes(dyn, task.contacts, task)
    _check_target_not_landing(system, task, contacts)

    if options.discretization is Discretization.FESD:
        return _build_fesd(robot, task, options, dyn, skips, contacts, system, builder, switch_scale, y0, start)
    # one step ends at rest, and its q row q_1 - q_0 = h s v_1 then keeps q_1 = q_0: 16 NLPs failed "out of reach"
    # with CasADi's "overconstrained" warnings (FESD's stages, a nonzero target_v or a periodic step may reach it)
    if (N == 1 and plan.target_q is not None and options.terminal_velocity and not np.any(plan.target_v or 0.0)
            and not np.array_equal(plan.target_q, task.initial.q)):
        raise InputError("horizon.N = 1 (or --steps 1) cannot reach plan.target_q away from initial.q: the one "
                         "implicit Euler step ends at rest (plan.target_v zero), so it ends where it starts; "
                         "use N >= 2")

    # --- variables, stage by stage ---------------------------------------------------------------
    sizes = [("u", nu)] + ([("s", 1)] if timed else []) + [("y", ny), ("w", nw)]
    stage_n = sum(n for _, n in sizes)
    linf = options.penalty is Penalty.LINF
    n_y0 = ny if periodic else 0  # plan.periodic: y_0 is a decision variable, ahead of the stages
    nx = n_y0 + N * stage_n + (1 if linf else 0)
    blocks: dict[str, list] = {name: [] for name, _ in sizes}
    off = n_y0
    for k in range(N):
        for name, n in sizes:
            blocks[name].append(np.arange(off, off + n))
            off += n
    var_blocks = {name: np.array(rows, dtype=int) for name, rows in blocks.items()}
    for part in builder.w_blocks:
        var_blocks[part] = var_blocks["w"][:, builder.w_blocks[part]]
    if linf:
        var_blocks["s_c"] = np.array([nx - 1])
    if periodic:
        var_blocks["y0"] = np.arange(ny)

    params, P, field_scale = _parameters(system, options)
    rho, hole_scale, _, _, term_w, rho_l1, rf_scale = params

    u_lo, u_hi = (robot.u_lower, robot.u_upper) if plan.u_bound is None else (np.full(nu, -plan.u_bound), np.full(nu, plan.u_bound))
    q_lo, q_hi = task.q_bounds(robot)
    lbx, ubx = np.full(nx, -np.inf), np.full(nx, np.inf)
    lbx[var_blocks["u"]], ubx[var_blocks["u"]] = u_lo, u_hi
    yb = var_blocks["y"]
    lbx[yb[:, :nq]], ubx[yb[:, :nq]] = q_lo, q_hi
    # (read from the URDF and not applied, a leg's knee limited to 5 rad/s was planned at 14.5)
    lbx[yb[:, nq:nq + nv]], ubx[yb[:, nq:nq + nv]] = -robot.v_limit, robot.v_limit
    lbx[var_blocks["w"]], ubx[var_blocks["w"]] = builder.lbw, builder.ubw
    if timed:
        lbx[var_blocks["s"]] = 1.0
        if hz.max_time_speed is not None:
            ubx[var_blocks["s"]] = hz.max_time_speed
    if linf:
        lbx[nx - 1] = 0.0
    if periodic:
        _bound_periodic_start(lbx, ubx, robot, task, y0, q_lo, q_hi, nq, nv)

    # --- path-constraint functions of (y, u, w) ----------------------------------------------------
    path_fn, ws, coef, field_names = _path_functions(system, builder, dyn, task, contacts, skips, options, hole_scale)

    # --- stages ------------------------------------------------------------------------------------
    # (the explicit form's several-contact force rows were left out of the NLP: its contact forces were free)
    step_blocks = builder.g_block_names
    g_parts: dict[str, list] = {name: [] for name in step_blocks + ("above_ground", "holes", "never_touching", "friction_cone", "impact_cone")}
    control_cost, selector_cost = 0, 0
    pairs: list[Pair] = []
    prods = []
    # one step built once on symbols and called at every k: its derivatives can be derived at the size of a step
    # (Stages); a call replays the step's operations, so g and f are the expressions a build per step gives
    z_y, z_u, z_y1 = ca.SX.sym("y", ny), ca.SX.sym("u", nu), ca.SX.sym("y_next", ny)
    z_s = ca.SX.sym("s") if timed else 1.0
    step = builder.build(z_y, z_y1, z_u, z_s, h, field_scale=field_scale)
    z = ca.vertcat(z_y, z_u, *([z_s] if timed else []), z_y1, step.w)
    step_fn = ca.Function("step", [z, P], [step.g, step.objective], ["z", "p"], ["g", "cost"])
    y_prev = ca.SX.sym("y_0", ny) if periodic else ca.DM(y0)
    x_parts = [y_prev] if periodic else []
    for k in range(N):
        uk = ca.SX.sym(f"u_{k}", nu)
        sk = ca.SX.sym(f"s_{k}") if timed else 1.0
        yk = ca.SX.sym(f"y_{k + 1}", ny)
        wk = ca.SX.sym(f"w_{k}", nw)
        gk, cost_k = step_fn(ca.vertcat(y_prev, uk, *([sk] if timed else []), yk, wk), P)
        x_parts += [uk] + ([sk] if timed else []) + [yk, wk]
        for name in step_blocks:
            g_parts[name].append(gk[step.g_blocks[name]])
        selector_cost += cost_k
        # step k lasts h s_k of the time-freezing system's time: charged at h alone, a push was cheaper in a
        # sped-up step and plans put theirs there (nosnoc scales the stage cost by its speed of time too)
        control_cost += h * sk * ca.dot(uk, uk)
        if path_fn["above_ground"] is not None:
            g_parts["above_ground"].append(path_fn["above_ground"](yk))
        if path_fn["holes"] is not None:
            g_parts["holes"].append(path_fn["holes"](yk, hole_scale))
        if path_fn["never_touching"] is not None:
            g_parts["never_touching"].append(path_fn["never_touching"](yk))
        if path_fn["friction_cone"] is not None:
            g_parts["friction_cone"].append(path_fn["friction_cone"](yk, uk, wk))
        if path_fn["impact_cone"] is not None:
            g_parts["impact_cone"].append(path_fn["impact_cone"](wk))
        sig_idx, l0_idx, l1_idx = var_blocks["sigma"][k], var_blocks["lambda0"][k], var_blocks["lambda1"][k]
        for i, sw in enumerate(system.switches):
            pairs.append(Pair(int(l0_idx[i]), int(sig_idx[i]), False, f"lambda0*sigma[{sw.name}]_{k}"))
        for i, sw in enumerate(system.switches):
            pairs.append(Pair(int(l1_idx[i]), int(sig_idx[i]), True, f"lambda1*(1-sigma)[{sw.name}]_{k}"))
        y_prev = yk
    if linf:
        x_parts.append(ca.SX.sym("s_c"))
    X = ca.vertcat(*x_parts)
    assert X.shape[0] == nx
    for pr in pairs:
        b = 1 - X[pr.b] if pr.b_upper else X[pr.b]
        prods.append(X[pr.a] * b)
    prods = ca.vertcat(*prods)
    gates = _gates(system, builder, var_blocks, X, N) if options.gating else None
    pen_prods = prods * gates if gates is not None else prods
    pair_scale = np.tile(np.concatenate([switch_scale, switch_scale]), N)

    rows = _Rows()
    for name in step_blocks:
        rows.add(name, g_parts[name], 0.0, 0.0)
    for name in ("above_ground", "holes", "never_touching", "friction_cone", "impact_cone"):
        rows.add(name, g_parts[name], 0.0, np.inf)
    if periodic:
        _free_start_rows(rows, path_fn, X[var_blocks["y0"]], hole_scale)
    _velocity_bounds(rows, robot, task, nq, [[X[var_blocks["y"][k]]] for k in range(N)],
                     X[var_blocks["y0"]] if periodic else None)
    term_res = _terminal(rows, robot, task, options, X, var_blocks, y0)
    if linf:
        rows.add("penalty", [X[nx - 1] - pen_prods[k * 2 * n_sig : (k + 1) * 2 * n_sig] for k in range(N)], 0.0, np.inf)
        penalty = rho * X[nx - 1] + rho_l1 * ca.sum1(pen_prods)
    else:
        penalty = rho * ca.sum1(pen_prods)

    f = control_cost + selector_cost + penalty + term_w * ca.dot(term_res, term_res)
    clock_w = options.clock_weight
    clock_cost = 0
    if clock_w > 0:
        rate = ca.Function("clock_rate", [ws], [coef[field_names.index("ode")]])
        for k in range(N):
            Rk = rate(X[var_blocks["w"][k]])
            clock_cost += (Rk * (1 - Rk)) ** 2
        clock_cost = clock_w * clock_cost
        f = f + clock_cost
    f = f + (rf_scale - 1) * selector_cost  # Problem.params' rho_f_scale; at 1 it adds an exact 0: the same f, bit for bit
    y_before = [var_blocks["y0"] if periodic else nx + np.arange(ny), *var_blocks["y"][:-1]]  # y_k of step k
    z_index = np.array([np.concatenate([y_before[k], var_blocks["u"][k], *([var_blocks["s"][k]] if timed else []),
                                        var_blocks["y"][k], var_blocks["w"][k]]) for k in range(N)])
    step_rows = np.full((N, step.g.numel()), -1)
    for name in step_blocks:
        step_rows[:, step.g_blocks[name]] = rows.blocks[name]
    assert step_rows.min() >= 0, "a step row is in no block of the NLP"  # (its derivatives read unset memory)
    stages = Stages(step_fn, z_index, step_rows, PARAMETERS.index("rho_f_scale"),
                    control_cost + penalty + term_w * ca.dot(term_res, term_res) + clock_cost)
    names = [f"{nm}_0" for nm in system.state_names] if periodic else []
    for k in range(N):
        names += [f"u[{i}]_{k}" for i in range(nu)]
        if timed:
            names.append(f"s_{k}")
        names += [f"{nm}_{k + 1}" for nm in system.state_names]
        names += [f"{nm}_{k}" for nm in builder.w_names]
    if linf:
        names.append("s_c")

    # --- the hint-free initial guess --------------------------------------------------------------
    w_guess = builder.guess(y0, np.zeros(nu))
    x0, states = _hint_free_start(nx, var_blocks, y0, N, h, options.clock_guess_running)
    x0[var_blocks["y"]] = states
    x0[var_blocks["w"]] = w_guess
    products = ca.Function("products", [X], [prods * ca.DM(pair_scale)], ["x"], ["ab"])
    notes = {}
    if gates is not None:
        notes["gated_products"] = ca.Function("gated_products", [X], [pen_prods * ca.DM(pair_scale)], ["x"], ["ab"])
        notes["gates"] = ca.Function("gates", [X], [gates], ["x"], ["gate"])
    parts = {
        "control": ca.Function("control_cost", [X, P], [control_cost]),
        "selectors": ca.Function("selector_cost", [X, P], [selector_cost]),
        "penalty": ca.Function("penalty_cost", [X, P], [penalty]),
    }
    if clock_w > 0:
        parts["clock"] = ca.Function("clock_cost", [X, P], [clock_cost])
    if linf:
        x0[nx - 1] = float(np.max(np.asarray(ca.Function("p0", [X], [prods])(x0)), initial=0.0))
    notes["hint_free_x0"] = x0.copy()  # (replan refuses it as a start: it is no plan)
    return _record_built(Problem(
        robot=robot, task=task, options=options, system=system, builder=builder, N=N, h=h, y0=y0, x=X, p=P, f=f,
        g=rows.g(), lbx=lbx, ubx=ubx, lbg=rows.lb(), ubg=rows.ub(), x0=x0, var_names=tuple(names),
        var_blocks=var_blocks, g_blocks=rows.named(), pairs=tuple(pairs), pair_scale=pair_scale, objective_parts=parts,
        products=products, build_time_s=time.perf_counter() - start, notes=notes, skips=skips, stages=stages))


# what build_problem baked into x, g, the stages and the derivatives: solve() refuses a Problem whose ones changed
BUILT_INPUTS = ("robot", "task", "options", "N", "h", "y0", "x", "var_names")
# what solve() honours when edited on a built Problem (Problem.edited names them)
EDITABLE = ("f", "g", "lbx", "ubx", "lbg", "ubg")


def _unpickled_problem(state: bytes) -> Problem:
    """The Problem that Problem.__reduce__ pickled as `state`."""
    problem = object.__new__(Problem)
    with ca.global_unpickle_context():
        problem.__dict__.update(pickle.loads(state))
    return problem


def _record_built(problem: Problem) -> Problem:
    """problem, with what build_problem built it from kept in its notes (Problem.check_solvable, Problem.edited)."""
    problem.notes["built"] = {name: (np.array(value, copy=True) if isinstance(value, np.ndarray) else value)
                              for name in BUILT_INPUTS + EDITABLE for value in (getattr(problem, name),)}
    return problem


def _bound_periodic_start(lbx, ubx, robot: Robot, task: Task, y0: np.ndarray, q_lo, q_hi, nq: int, nv: int) -> None:
    """Bounds of the free initial state of plan.periodic (x's first ny entries), in place: q within the
    joint bounds, the fixed coordinates and the clock t_0 pinned to y0, |v| <= v_bound if given and the joint speed
    limits (Robot.v_limit)."""
    fixed = task.periodic_map(robot)[2]
    lbx[:nq], ubx[:nq] = q_lo, q_hi
    lbx[fixed], ubx[fixed] = y0[fixed], y0[fixed]
    v_bound = task.plan.periodic.v_bound
    speed = robot.v_limit if v_bound is None else np.minimum(robot.v_limit, v_bound)
    lbx[nq : nq + nv], ubx[nq : nq + nv] = -speed, speed
    lbx[len(y0) - 1] = ubx[len(y0) - 1] = y0[-1]


# a_n / (m g) beyond which build_problem warns (the shipped robots' tasks: 0.58 (biped) to 20 (point-mass hop)): above
# 1e3, an impact below 0.01 h a_n is read as drift and not recorded (docs/tasks.md, a_n), which at h = 0.02 s is a
# landing of up to 2 m/s (a 1 g point mass at the default a_n = 200, 2e4: its landing at 1.6 m/s went unrecorded);
# below 0.05, a 1 m/s landing stays frozen for m v / a_n = 2 s of numerical time, the length of a whole horizon
AN_PER_WEIGHT_RANGE = (0.05, 1e3)


def _warn_far_sized(robot: Robot, contacts) -> None:
    """Warn of each contact whose a_n [N] is far from the robot's weight m g (AN_PER_WEIGHT_RANGE)."""
    weight = robot_weight(robot)
    for ct in contacts:
        if weight > 0 and not AN_PER_WEIGHT_RANGE[0] <= ct.a_n / weight <= AN_PER_WEIGHT_RANGE[1]:
            warnings.warn(f"contact {ct.point}: a_n = {ct.a_n:g} N is {ct.a_n / weight:.3g} times the robot's weight "
                          f"m g = {weight:.3g} N, outside [{AN_PER_WEIGHT_RANGE[0]:g}, {AN_PER_WEIGHT_RANGE[1]:g}]: "
                          "scale a_n and a_t (and u_bound, rho_f, rho_schedule, soft_terminal_weight) with the mass "
                          "(docs/tasks.md, \"Robots of other sizes\")", stacklevel=3)


# [N, N m] the static balance B u + J^T lambda = g(q0) that the cone-constrained forces must meet: else they are not
# taken and lambda goes free (rounding of a solvable balance is ~1e-12 on the shipped robots)
STATIC_BALANCE_TOL = 1e-6
# relative: singular values below this in the static balance are rounding of a direction the contacts span (a planar
# quadruped's was 1.3e-14 of 10, which NumPy's default cut-off 1e-15 inverted into a torque of rounding noise)
STATIC_RCOND = 1e-10


def static_controls(problem: Problem) -> tuple[np.ndarray, np.ndarray]:
    """The least-norm controls u (nu,) [N m or N] that hold the start's configuration q0 at rest, and the contact
    forces (n_contacts, 2) [N] (normal, tangential along the plane, per problem.system.contacts) they go with:
    B u + sum_i (n_i lambda_n,i + t_i lambda_t,i) = g(q0) (g: the gravity term, RNEA at zero velocity and
    acceleration), with only the points on their plane at the start bearing (Robot.touching_contacts, to
    result.ON_PLANE_M: a start typed to 7 digits sits ~1e-8 m off its plane; the others, and a
    frictionless point's tangential force, 0). The forces keep lambda_n >= 0 and |lambda_t| <= mu lambda_n when such
    forces balance q0 (a small QP); else they are free (the least-squares u with any contact force). u is clipped
    to its bounds (problem.lbx, ubx). An InputError when no contact point touches its plane at the start (nothing can
    hold it at rest: the least-squares u bent a falling hopper's leg); a UserWarning when the u and forces found do
    not hold it (the torque bounds, a posture whose weight is not over its touching points, the friction cones), naming
    the imbalance."""
    system, dyn = problem.system, problem.system.dyn
    q0 = problem.y0[: system.nq]
    grav = np.asarray(dyn.bias(q0, np.zeros(system.nv)), float).ravel()
    B = np.asarray(dyn.actuation, float)
    columns, cone, slots = [], [], []  # contact force directions (nv,), (normal col, tangent col or None, mu), (i, k)
    for i, normal, tangent in problem.robot.touching_contacts(
            [(c.point, c.normal, model is ContactModel.NO_SLIP) for c, model in zip(system.contacts, system.models)],
            q0, problem.task.ground_height):
        columns.append(normal)
        slots.append((i, 0))
        tangential = tangent is not None
        if tangential:
            columns.append(tangent)
            slots.append((i, 1))
        cone.append((len(columns) - 1 - tangential, len(columns) - 1 if tangential else None, system.contacts[i].mu))
    if not columns:
        raise InputError("SolveOptions.start_controls = static holds the start at rest on the contact points that touch "
                         f"their plane there, but none of {', '.join(system.labels)} does (the start is in the air); "
                         "leave start_controls at zero")
    Jc = np.column_stack(columns)
    # lambda free: the min-norm u balancing what the contacts cannot (least squares), then the forces for the rest
    rest = np.eye(system.nv) - Jc @ np.linalg.pinv(Jc, rcond=STATIC_RCOND)
    u = np.linalg.pinv(rest @ B, rcond=STATIC_RCOND) @ (rest @ grav)
    lam = np.linalg.pinv(Jc, rcond=STATIC_RCOND) @ (grav - B @ u)
    if not _in_cones(lam, cone):
        u, lam = _static_in_cones(B, Jc, grav, cone, u, lam)
    forces = np.zeros((len(system.contacts), 2))
    for (i, k), value in zip(slots, lam):
        forces[i, k] = value
    u_block = problem.var_blocks["u"][0]
    unclipped = np.abs(B @ u + Jc @ lam - grav).max()
    clipped = np.clip(u, problem.lbx[u_block], problem.ubx[u_block])
    # (a posture whose weight is not over its points, under torque bounds that clipped its u, blamed the posture alone)
    causes = (["no torque can hold this posture on the contact points touching: its weight is not over them"]
              if unclipped > STATIC_BALANCE_TOL else []) + (["the torque bounds"] if np.any(clipped != u) else [])
    u = clipped
    imbalance = np.abs(B @ u + Jc @ lam - grav).max()
    if imbalance > STATIC_BALANCE_TOL:
        warnings.warn(f"the static start does not hold the start at rest: {imbalance:.3g} N or N m of gravity left "
                      f"unbalanced ({'; and '.join(causes)})", UserWarning, stacklevel=2)
    elif not _in_cones(lam, cone, STATIC_BALANCE_TOL):
        warnings.warn("the static start holds the start at rest only with contact forces outside their friction cones "
                      "or pulling; its u is that of those forces", UserWarning, stacklevel=2)
    return u, forces


def _in_cones(lam: np.ndarray, cone, tol: float = 0.0) -> bool:
    """Whether each bearing point's forces in lam keep lambda_n >= 0 and |lambda_t| <= mu lambda_n (to tol [N])."""
    return all(lam[n] >= -tol and (t is None or abs(lam[t]) <= mu * lam[n] + tol) for n, t, mu in cone)


def _static_in_cones(B, Jc, grav, cone, u, lam) -> tuple[np.ndarray, np.ndarray]:
    """static_controls' QP: min ||u||^2 over (u, lambda) with B u + Jc lambda = grav and the forces in their cones
    (linear in the plane: lambda_n >= 0, mu lambda_n -+ lambda_t >= 0), from the free forces' (u, lam); those when
    no such forces balance."""
    from scipy.optimize import minimize  # (imported here: only a start whose free forces leave a cone needs SciPy)

    nu = B.shape[1]
    eye, rows = np.eye(Jc.shape[1]), []
    for n, t, mu in cone:
        rows += [eye[n]] + ([] if t is None else [mu * eye[n] - eye[t], mu * eye[n] + eye[t]])
    C = np.hstack([np.zeros((len(rows), nu)), np.array(rows)])
    A = np.hstack([B, Jc])
    found = minimize(lambda z: z[:nu] @ z[:nu], np.concatenate([u, np.maximum(lam, 0.0)]),
                     jac=lambda z: np.concatenate([2 * z[:nu], np.zeros(Jc.shape[1])]), method="SLSQP",
                     constraints=[{"type": "eq", "fun": lambda z: A @ z - grav, "jac": lambda z: A},
                                  {"type": "ineq", "fun": lambda z: C @ z, "jac": lambda z: C}])
    z = found.x
    balanced = np.abs(A @ z - grav).max() <= STATIC_BALANCE_TOL
    if found.success and balanced and _in_cones(z[nu:], cone, STATIC_BALANCE_TOL):
        return z[:nu], z[nu:]
    return u, lam


def _hint_free_start(nx: int, var_blocks, y0: np.ndarray, N: int, h: float, clock_running: bool) -> tuple[np.ndarray, np.ndarray]:
    """The paper's hint-free start: x0 (nx,) with y_0 in the periodic block "y0" and speeds of time 1
    where those blocks exist (zeros elsewhere), and the node states (N, ny) to place: y_0 at every node,
    its clock t_0 + (k + 1) h when clock_running."""
    x0 = np.zeros(nx)
    if "y0" in var_blocks:
        x0[var_blocks["y0"]] = y0
    if "s" in var_blocks:
        x0[var_blocks["s"]] = 1.0
    states = np.tile(y0, (N, 1))
    if clock_running:
        states[:, -1] = y0[-1] + np.arange(1, N + 1) * h
    return x0, states


def _gates(system: TimeFreezingSystem, builder: ImplicitEulerStep, var_blocks, X, N) -> ca.SX:
    """(n_pairs,) gate of every pair in Problem.pairs order (ProblemOptions.gating): 1 - beta for the
    alpha and zeta pairs, (1 - beta) alpha for the gamma pair (via the lifted alpha*beta when it
    exists), 1 for beta and for the selectors of elastic contacts. Several contacts: each point's
    selectors are gated by its own beta_i, and the gamma_i pair by 1 - beta_i only (gamma_i switches
    the force row s_i = (1 - beta_i)(1 - gamma_i); docs/formulation.md, "Periodic walking")."""
    names = [s.name for s in system.switches]
    n_fac = len(system.factors)  # theta = (factors, lifted products); no factors with one contact
    mono = {m: n_fac + j for j, m in enumerate(builder.theta_lifted)}
    out = []
    for k in range(N):
        sig, th = var_blocks["sigma"][k], var_blocks["theta"][k]
        stage = []
        for i, sw in enumerate(system.switches):
            model = system.models[system.labels.index(sw.contact)]
            kind = sw.name.split("[")[0]
            if model is ContactModel.ELASTIC or kind not in ("alpha", "gamma", "zeta"):
                stage.append(1)
                continue
            ib, ia = names.index(f"beta[{sw.contact}]"), names.index(f"alpha[{sw.contact}]")
            one_minus_beta = 1 - X[sig[ib]]
            if kind == "gamma" and system.factors:
                # several contacts: gamma_i also switches point i's force row, s_i = (1 - beta_i)(1 - gamma_i),
                # whose force acts through R even where alpha_i = 0 if beta_i is fractional: gate by 1 - beta_i only
                stage.append(one_minus_beta)
            elif kind == "gamma":
                key = tuple(sorted((ia, ib)))
                ab = X[th[mono[key]]] if key in mono else X[sig[ia]] * X[sig[ib]]
                stage.append(X[sig[ia]] - ab)
            else:
                stage.append(one_minus_beta)
        out += stage + stage  # lambda0 pairs, then lambda1 pairs, same gates
    return ca.vertcat(*out)


def _parameters(system, options: ProblemOptions) -> tuple[list, ca.SX, ca.SX | None]:
    """The NLP's parameters as SX symbols (PARAMETERS' order), stacked into p, and the auxiliary fields' scale
    (a_n fields by an_scale, a_t fields by at_scale, the others 1; None without options.aux_continuation)."""
    params = [ca.SX.sym(name) for name in PARAMETERS]
    an_scale, at_scale = params[PARAMETERS.index("an_scale")], params[PARAMETERS.index("at_scale")]
    field_scale = None
    if options.aux_continuation:
        field_scale = ca.vertcat(*[an_scale if f.name.startswith("a_n[") else at_scale if f.name.startswith("a_t[") else 1
                                   for f in system.fields])
    return params, ca.vertcat(*params), field_scale


def _path_functions(system: TimeFreezingSystem, builder: ImplicitEulerStep, dyn: Dynamics, task: Task, contacts, skips: Skips,
                    options: ProblemOptions, hole_scale):
    """The path constraints as Functions of one point's (y, u, w) (module docstring): a dict name ->
    Function or None, and the symbol w (nw,) with the field coefficients P_j(sigma) (n_fields,) of
    it and the field names (the clock rate of ProblemOptions.clock_weight)."""
    plan, nq, nw = task.plan, system.nq, builder.nw
    ys, us, ws = system.y, system.u, ca.SX.sym("w", nw)
    q_sym = ys[:nq]
    ground = task.ground_height
    above = [dyn.point_position(pt)(q_sym)[2] - ground for pt in plan.above_ground]
    hole_exprs = []
    for ct in task.contacts:  # touches = false too: a contact point stays out of the holes whether it may touch or not
        pos = dyn.point_position(ct.point)(q_sym)
        for i, e in enumerate(plan.holes):
            if (ct.point, i) in skips.dropped_holes:
                continue
            hole_exprs.append(e.metric(pos[0], pos[2]) - hole_scale**2)
    coef = ca.mtimes(ca.DM(builder.C), builder.monomials_of(ws))  # P_j(sigma) per field, linear in the monomials
    field_names = [f.name for f in system.fields]
    cone = []
    if options.friction_cone and len(contacts) > 1:
        # several contacts: the joint forces lambda_i are step variables (switched off, = 0, where the
        # point's force row is off) and act through the clock R = prod_i r_i (the coefficient of the
        # ODE field): R = 1 on every sliding manifold, 0 in any frozen impact (docs/formulation.md)
        weight = coef[field_names.index("ode")]
        for label, model in zip(system.labels, system.models):
            if model is not ContactModel.NO_SLIP:
                continue
            mu = contacts[system.labels.index(label)].mu
            lam_all = ws[builder.w_blocks["forces"]]
            sl = builder.mm.lam_index[label] if builder.mm is not None else system.lam_index[label]
            lam = lam_all[sl]
            cone += [weight * (mu * lam[0] - lam[1]), weight * (mu * lam[0] + lam[1])]
    elif options.friction_cone:
        for ct, model, terms in zip(contacts, system.models, system.terms):
            if model is not ContactModel.NO_SLIP:
                continue
            weight = coef[field_names.index(f"dae_f[{ct.point}]")]
            if builder.mm is None:
                lam_n, lam_t = terms.lambda_no_slip[0], terms.lambda_no_slip[1]
            else:  # the step's own force variables: no M^-1 here either
                lam = ws[builder.w_blocks["forces"]][builder.mm.lam_index[ct.point]]
                lam_n, lam_t = lam[0], lam[1]
            cone += [weight * (ct.mu * lam_n - lam_t), weight * (ct.mu * lam_n + lam_t)]
    # touches = false: the gap of the point's plane
    clearance = [plane_gap(dyn, ct, q_sym, ground) for ct in task.contacts if ct.point in skips.never_touching]
    for ct, model in zip(contacts, system.models):  # the contacts the system is built for (planner.scene)
        # (a plan slid 0.5 m where Coulomb's mu = 0.5 let it slide 0.07 m); a_t = mu a_n to rounding is it. Any count
        # of contacts, with or without impact_cone (a box's two corners were not warned of)
        if model is ContactModel.NO_SLIP and ct.a_t < ct.mu * ct.a_n * (1.0 - 1e-9):
            warnings.warn(f"contact {ct.point}: a_t = {ct.a_t:g} < mu a_n = {ct.mu * ct.a_n:g}, so a plan may slide "
                          f"along the ground braked at a_t / a_n = {ct.a_t / ct.a_n:.3g} of its normal force, less "
                          f"than mu = {ct.mu:g}; a_t = mu a_n makes that sliding Coulomb's", stacklevel=2)
    impact = []
    if options.impact_cone and len(contacts) == 1:
        for ct, model in zip(contacts, system.models):
            if model is ContactModel.NO_SLIP and ct.a_t <= ct.mu * ct.a_n:
                p_an, p_at = coef[field_names.index(f"a_n[{ct.point}]")], coef[field_names.index(f"a_t[{ct.point}]")]
                impact += [ct.mu * ct.a_n * p_an - ct.a_t * p_at, ct.mu * ct.a_n * p_an + ct.a_t * p_at]
    path_fn = {
        "never_touching": ca.Function("never_touching", [ys], [ca.vertcat(*clearance)]) if clearance else None,
        "impact_cone": ca.Function("impact_cone", [ws], [ca.vertcat(*impact)]) if impact else None,
        "above_ground": ca.Function("above_ground", [ys], [ca.vertcat(*above)]) if above else None,
        "holes": ca.Function("holes", [ys, hole_scale], [ca.vertcat(*hole_exprs)]) if hole_exprs else None,
        "friction_cone": ca.Function("friction_cone", [ys, us, ws], [ca.vertcat(*cone)]) if cone else None,
    }

    return path_fn, ws, coef, field_names


def _build_fesd(robot: Robot, task: Task, options: ProblemOptions, dyn: Dynamics, skips: Skips, contacts, system: TimeFreezingSystem,
                builder: ImplicitEulerStep, switch_scale: np.ndarray, y0: np.ndarray, start: float) -> Problem:
    """build_problem with FESD stages (ProblemOptions.discretization FESD; docs/formulation.md, "FESD in the OCP").

    Stage k owns u_k (nu,), s_k (only with horizon.physical_time) and the FESDInterval's variables:
    element lengths "h" (n_fe,) [s, numerical time], then per element e and Radau stage j the state
    "Y" (ny,) and the algebraic variables "w" (nw,); the step's end y_{k+1} ("y") is the last stage of
    the last element. The interval's rows (lengths sum to h, every stage's step equations) become the
    blocks element_lengths (N, 1), dynamics, stationarity, lifting [, contact_forces] (N, n_fe n_s m).
    Path constraints: above_ground, holes, never_touching, velocity_bounds at every element boundary (N, n_fe m);
    friction_cone, impact_cone at every stage (N, n_fe n_s m). Complementarity (Problem.pairs): per
    step, element, stage j and point j' of the element (its left boundary, then its stages) the
    cross-complementarity lambda0_j' sigma_j, lambda1_j' (1 - sigma_j), as FESDInterval; the left
    boundary of step k's first element is step k-1's end, and for step 0 its own first stage (y_0's
    multipliers would depend on u_0). Penalty.LINF: the step slacks "s_c_step" (N, 1) bound the
    step's products (block penalty (N, pairs per step)) and s_c bounds them (block penalty_max (N, 1)):
    the same l_inf penalty as one slack over every pair, without a KKT column coupled to all 144 N
    rows of Capler's pairs (measured 1.0 s against 0.08 s per IPOPT iteration at N = 50, n_fe = 3).
    Objective: control h sum_k s_k u_k^T u_k, selectors (each stage's rho_f term weighted b_j h_n / h),
    equilibration (rho_h sum_n ((h_n - h/n_fe) / (h/n_fe))^2), penalty."""
    plan, hz = task.plan, task.horizon
    fesd = FESDInterval(builder, options.fesd)
    nq, nv, nu, ny, nw, n = system.nq, system.nv, system.nu, system.ny, builder.nw, system.n_sigma
    n_fe, n_s = fesd.n_fe, fesd.n_s
    N, h = hz.N, hz.h
    timed, periodic, linf = hz.physical_time is not None, plan.periodic is not None, options.penalty is Penalty.LINF

    # --- variables: index arrays into x ------------------------------------------------------------
    n_y0 = ny if periodic else 0
    stage_n = nu + int(timed) + fesd.nx
    nx = n_y0 + N * stage_n + (N + 1 if linf else 0)
    base = n_y0 + stage_n * np.arange(N)
    iv0 = base + nu + int(timed)  # where each interval's x starts
    first = np.array([[fesd.stage_slice(e, j).start for j in range(n_s)] for e in range(n_fe)])
    Yi = (iv0[:, None, None] + first[None])[..., None] + np.arange(ny)  # (N, n_fe, n_s, ny)
    Wi = Yi[..., :1] + ny + np.arange(nw)  # (N, n_fe, n_s, nw)
    var_blocks = {"u": base[:, None] + np.arange(nu), "h": iv0[:, None] + np.arange(n_fe), "Y": Yi, "w": Wi, "y": Yi[:, -1, -1]}
    if timed:
        var_blocks["s"] = (base + nu)[:, None]
    for part, sl in builder.w_blocks.items():
        var_blocks[part] = Wi[..., sl]
    if linf:  # one slack per step, then s_c >= each of them (keeps IPOPT's KKT matrix free of a dense s_c column)
        var_blocks["s_c_step"] = np.arange(nx - 1 - N, nx - 1)[:, None]
        var_blocks["s_c"] = np.array([nx - 1])
    if periodic:
        var_blocks["y0"] = np.arange(ny)

    params, P, field_scale = _parameters(system, options)
    rho, hole_scale, _, _, term_w, rho_l1, rf_scale = params
    path_fn, _, _, _ = _path_functions(system, builder, dyn, task, contacts, skips, options, hole_scale)

    # --- stages ------------------------------------------------------------------------------------
    step_blocks = ("element_lengths",) + builder.g_block_names
    at_bounds, at_stages = ("above_ground", "holes", "never_touching"), ("friction_cone", "impact_cone")
    g_parts: dict[str, list] = {name: [] for name in step_blocks + at_bounds + at_stages}
    lbx, ubx = np.full(nx, -np.inf), np.full(nx, np.inf)
    x_parts, names = [], []
    y_prev = ca.DM(y0)
    if periodic:
        y_prev = ca.SX.sym("y_0", ny)
        x_parts, names = [y_prev], [f"{nm}_0" for nm in system.state_names]
    control_cost, selector_cost, equilibration = 0, 0, 0
    for k in range(N):
        uk = ca.SX.sym(f"u_{k}", nu)
        sk = ca.SX.sym(f"s_{k}") if timed else 1.0
        iv = fesd.build(y_prev, lambda y: uk, h, ca.DM.zeros(2 * n), tag=f"_{k}", s_k=sk, field_scale=field_scale)
        x_parts += [uk] + ([sk] if timed else []) + [iv.x]
        names += [f"u[{i}]_{k}" for i in range(nu)] + ([f"s_{k}"] if timed else []) + [f"h_{k}_{e}" for e in range(n_fe)]
        for e in range(n_fe):
            for j in range(n_s):
                names += [f"{nm}_{k}_{e}_{j}" for nm in system.state_names] + [f"{nm}_{k}_{e}_{j}" for nm in builder.w_names]
        lbx[iv0[k] : iv0[k] + fesd.nx], ubx[iv0[k] : iv0[k] + fesd.nx] = iv.lbx, iv.ubx
        for name in step_blocks:
            g_parts[name].append(iv.g[iv.g_blocks[name].tolist()])
        control_cost += h * sk * ca.dot(uk, uk)  # (s_k: as the implicit-Euler build)
        selector_cost += iv.objective - iv.equilibration
        equilibration += iv.equilibration
        stage = lambda e, j: iv.x[fesd.stage_slice(e, j)]  # noqa: E731  (Y_ej, w_ej)
        for name in at_bounds:
            if path_fn[name] is not None:
                args = (hole_scale,) if name == "holes" else ()
                g_parts[name].append(ca.vertcat(*[path_fn[name](stage(e, n_s - 1)[:ny], *args) for e in range(n_fe)]))
        if path_fn["friction_cone"] is not None:
            g_parts["friction_cone"].append(ca.vertcat(*[path_fn["friction_cone"](stage(e, j)[:ny], uk, stage(e, j)[ny:])
                                                         for e in range(n_fe) for j in range(n_s)]))
        if path_fn["impact_cone"] is not None:
            g_parts["impact_cone"].append(ca.vertcat(*[path_fn["impact_cone"](stage(e, j)[ny:]) for e in range(n_fe) for j in range(n_s)]))
        y_prev = iv.y_end

    # --- complementarity pairs, in FESDInterval's order --------------------------------------------
    sig, lam0, lam1 = var_blocks["sigma"], var_blocks["lambda0"], var_blocks["lambda1"]
    pairs: list[Pair] = []
    own: list[bool] = []  # the pair's multiplier is at its selector's own stage
    for k in range(N):
        for e in range(n_fe):
            if e > 0:
                left = (k, e - 1, n_s - 1)
            else:
                left = (k - 1, n_fe - 1, n_s - 1) if k > 0 else (k, 0, 0)
            points = [left] + [(k, e, j) for j in range(n_s)]
            for j in range(n_s):
                for upper, lam, kind in ((False, lam0, "lambda0"), (True, lam1, "lambda1")):
                    for p_k, p_e, p_j in points:
                        for i, sw in enumerate(system.switches):
                            own.append((p_k, p_e, p_j) == (k, e, j))
                            pairs.append(Pair(int(lam[p_k, p_e, p_j, i]), int(sig[k, e, j, i]), upper,
                                              f"{kind}[{sw.name}]_{p_k}_{p_e}_{p_j}*{'(1-sigma)' if upper else 'sigma'}_{k}_{e}_{j}"))
    pair_scale = np.array([switch_scale[i] for _ in range(len(pairs) // n) for i in range(n)])

    # --- bounds --------------------------------------------------------------------------------------
    u_lo, u_hi = (robot.u_lower, robot.u_upper) if plan.u_bound is None else (np.full(nu, -plan.u_bound), np.full(nu, plan.u_bound))
    q_lo, q_hi = task.q_bounds(robot)
    lbx[var_blocks["u"]], ubx[var_blocks["u"]] = u_lo, u_hi
    lbx[Yi[..., :nq]], ubx[Yi[..., :nq]] = q_lo, q_hi  # every stage state within the joint bounds
    lbx[Yi[..., nq:nq + nv]], ubx[Yi[..., nq:nq + nv]] = -robot.v_limit, robot.v_limit  # and speed limits
    if timed:
        lbx[var_blocks["s"]] = 1.0
        if hz.max_time_speed is not None:
            ubx[var_blocks["s"]] = hz.max_time_speed
    if linf:
        lbx[nx - 1 - N :] = 0.0
        x_parts += [ca.SX.sym("s_c_step", N), ca.SX.sym("s_c")]
        names += [f"s_c_{k}" for k in range(N)] + ["s_c"]
    X = ca.vertcat(*x_parts)
    assert X.shape[0] == nx == len(names)
    if periodic:
        _bound_periodic_start(lbx, ubx, robot, task, y0, q_lo, q_hi, nq, nv)
    prods = ca.vertcat(*[X[pr.a] * (1 - X[pr.b] if pr.b_upper else X[pr.b]) for pr in pairs])
    notes = {}
    pen_prods, reported = prods, prods
    if options.gating:
        # the gates of every stage (its lambda0 gates then its lambda1 gates, as _gates), and of every
        # pair the gate of its selector's stage: a switched-off selector need not switch on a boundary
        stage_vb = {b: var_blocks[b].reshape(N * n_fe * n_s, var_blocks[b].shape[-1]) for b in ("sigma", "theta")}
        stage_gates = _gates(system, builder, stage_vb, X, N * n_fe * n_s)
        gate_of = {int(sig.ravel()[m * n + i]): stage_gates[m * 2 * n + i] for m in range(N * n_fe * n_s) for i in range(n)}
        pair_gates = ca.vertcat(*[gate_of[pr.b] for pr in pairs])
        pen_prods = prods * pair_gates
        own_mask = ca.DM(np.array(own, dtype=float))
        reported = own_mask * prods + (1 - own_mask) * pen_prods  # own-stage pairs ungated, as implicit Euler reports
        notes["gated_products"] = ca.Function("gated_products", [X], [pen_prods * ca.DM(pair_scale)], ["x"], ["ab"])
        notes["gates"] = ca.Function("gates", [X], [stage_gates], ["x"], ["gate"])
        notes["pair_gates"] = ca.Function("pair_gates", [X], [pair_gates], ["x"], ["gate"])
    notes["own_pairs"] = np.array(own, dtype=bool)

    # --- constraint rows -------------------------------------------------------------------------------
    rows = _Rows()
    for name in step_blocks:
        rows.add(name, g_parts[name], 0.0, 0.0)
    for name in at_bounds + at_stages:
        rows.add(name, g_parts[name], 0.0, np.inf)
    if periodic:
        _free_start_rows(rows, path_fn, X[var_blocks["y0"]], hole_scale)
    _velocity_bounds(rows, robot, task, nq, [[X[Yi[k, e, -1]] for e in range(n_fe)] for k in range(N)],
                     X[var_blocks["y0"]] if periodic else None)
    term_res = _terminal(rows, robot, task, options, X, var_blocks, y0)
    per_step = len(pairs) // N
    if linf:
        s_step = X[var_blocks["s_c_step"].ravel().tolist()]
        rows.add("penalty", [s_step[k] - pen_prods[k * per_step : (k + 1) * per_step] for k in range(N)], 0.0, np.inf)
        rows.add("penalty_max", [X[nx - 1] - s_step[k] for k in range(N)], 0.0, np.inf)
        penalty = rho * X[nx - 1] + rho_l1 * ca.sum1(pen_prods)
    else:
        penalty = rho * ca.sum1(pen_prods)
    f = control_cost + selector_cost + equilibration + penalty + term_w * ca.dot(term_res, term_res)
    f = f + (rf_scale - 1) * selector_cost

    # --- the hint-free initial guess: y_0 at every stage, equal element lengths ----------------------
    w_guess = builder.guess(y0, np.zeros(nu))
    x0, states = _hint_free_start(nx, var_blocks, y0, N, h, options.clock_guess_running)
    for k in range(N):
        x0[iv0[k] : iv0[k] + fesd.nx] = fesd.guess(h, states[k], w_guess)
    products = ca.Function("products", [X], [reported * ca.DM(pair_scale)], ["x"], ["ab"])
    if linf:
        p0 = np.asarray(ca.Function("p0", [X], [pen_prods])(x0), float).reshape(N, per_step)
        x0[var_blocks["s_c_step"].ravel()] = np.max(p0, axis=1, initial=0.0)
        x0[nx - 1] = float(np.max(p0, initial=0.0))
    parts = {"control": ca.Function("control_cost", [X, P], [control_cost]),
             "selectors": ca.Function("selector_cost", [X, P], [selector_cost]),
             "equilibration": ca.Function("equilibration_cost", [X, P], [equilibration]),
             "penalty": ca.Function("penalty_cost", [X, P], [penalty])}
    return _record_built(Problem(
        robot=robot, task=task, options=options, system=system, builder=builder, N=N, h=h, y0=y0, x=X, p=P, f=f,
        g=rows.g(), lbx=lbx, ubx=ubx, lbg=rows.lb(), ubg=rows.ub(), x0=x0, var_names=tuple(names),
        var_blocks=var_blocks, g_blocks=rows.named(), pairs=tuple(pairs), pair_scale=pair_scale, objective_parts=parts,
        products=products, build_time_s=time.perf_counter() - start, notes=notes, skips=skips, fesd=fesd))


def fesd_start_from_implicit_euler(fesd_problem: Problem, euler_problem: Problem, x_euler) -> np.ndarray:
    """A start x0 (fesd_problem.nx,) for the FESD OCP from a solution x_euler (euler_problem.nx,) of the
    implicit-Euler OCP of the same task and grid (homotopy.FESDStart.IMPLICIT_EULER; docs/formulation.md,
    "FESD in the OCP"). Per step k: equal element lengths h / n_fe [s]; the stage states on the segment
    y_k -> y_{k+1}, Y_ej = y_k + (e + c_j) / n_fe (y_{k+1} - y_k) (continuous across steps, the step's
    end exactly y_{k+1}); every stage's algebraic variables the step's w_k (selectors, lifted products,
    multipliers, forces); u_k, s_k and a periodic y_0 copied; the l_inf slacks the largest gated product
    of their step (and of all).

    What this point satisfies: the lifting rows, the bounds, the terminal rows and the step-end states
    as implicit Euler did; every own-stage and within-step cross pair exactly as implicit Euler's plan
    (the stages of a step are equal there); a stage's dynamics row is (h / n_fe)(F(y_{k+1}, w_k) -
    F(Y_ej, w_k)) (the collocation increment of a straight segment is the segment's slope), zero at the
    step's end; the stationarity and force rows are off by the change of h(y), forces(y) along the
    segment. Keeping w_k at every stage was measured better than re-solving the multipliers and forces
    at each stage state (which makes those rows exact but the products up to 30 on Capler N = 50): a
    violated row costs IPOPT a restoration step, a product ~1 costs rho times it in the objective.
    What it violates are the cross pairs across a step boundary where implicit Euler switched inside
    the step (its switch is not on an element boundary): moving the lengths is then the FESD solve's job."""
    if fesd_problem.fesd is None or euler_problem.fesd is not None:
        raise InputError("fesd_start_from_implicit_euler needs an FESD problem and an implicit-Euler problem")
    if (fesd_problem.N, fesd_problem.h) != (euler_problem.N, euler_problem.h) or fesd_problem.builder.nw != euler_problem.builder.nw:
        raise InputError(f"the implicit-Euler problem (N = {euler_problem.N}, h = {euler_problem.h}) is not on the FESD problem's grid "
                         f"(N = {fesd_problem.N}, h = {fesd_problem.h}) or has other algebraic variables")
    parts = euler_problem.split(x_euler)
    fesd, vb, N = fesd_problem.fesd, fesd_problem.var_blocks, fesd_problem.N
    Y, W = parts["Y"], parts["W"]
    x0 = np.zeros(fesd_problem.nx)
    frac = (np.arange(fesd.n_fe)[:, None] + fesd.c[None, :]) / fesd.n_fe  # (n_fe, n_s) where each stage sits in the step
    x0[vb["u"]] = parts["U"]
    x0[vb["h"]] = fesd_problem.h / fesd.n_fe
    x0[vb["Y"]] = Y[:-1, None, None, :] + frac[None, :, :, None] * (Y[1:] - Y[:-1])[:, None, None, :]
    x0[vb["y"]] = Y[1:]  # the step's end as implicit Euler's node, not y_k + 1 (y_{k+1} - y_k) rounded
    x0[vb["w"]] = W[:, None, None, :]
    if "s" in vb:
        x0[vb["s"]] = parts["S"][:, None]
    if "y0" in vb:
        x0[vb["y0"]] = Y[0]
    if "s_c" in vb:
        gp = fesd_problem.notes.get("gated_products", fesd_problem.products)
        prods = np.asarray(gp(x0), float).reshape(N, -1) / fesd_problem.pair_scale.reshape(N, -1)  # the penalty's own units
        x0[vb["s_c_step"].ravel()] = np.max(prods, axis=1, initial=0.0).clip(0.0)
        x0[vb["s_c"]] = float(np.max(prods, initial=0.0).clip(0.0))
    return x0


def _velocity_bounds(rows: "_Rows", robot, task: Task, nq: int, ends: list, y0) -> None:
    """Blocks velocity_bounds (N, m per state in ends[k]) and velocity_bounds_y0 (1, m; y0 the free
    initial state or None) of task.plan.velocity_bounds: lower <= A v <= upper (Task.velocity_rows)."""
    A, lo, hi = task.velocity_rows(robot)
    if not len(lo):
        return
    rate = lambda y: ca.mtimes(ca.DM(A), y[nq:nq + A.shape[1]])  # noqa: E731
    n_states = len(ends) * len(ends[0])
    rows.add("velocity_bounds", [ca.vertcat(*[rate(y) for y in ys]) for ys in ends], np.tile(lo, n_states), np.tile(hi, n_states))
    if y0 is not None:
        rows.add("velocity_bounds_y0", [rate(y0)], lo, hi)


class _Rows:
    """Named constraint blocks of g: `add(name, rows, lo, hi)` appends rows (a list of equally long
    expressions, one per stage) as block `name` (len(rows), m) with lo <= g <= hi."""

    def __init__(self):
        self.parts, self.lo, self.hi, self.blocks, self.row = [], [], [], {}, 0

    def add(self, name: str, rows: list, lo, hi) -> None:
        if not rows:
            return
        G = ca.vertcat(*rows)
        m = G.shape[0]
        self.parts.append(G)
        self.lo.append(np.broadcast_to(lo, (m,)).astype(float))
        self.hi.append(np.broadcast_to(hi, (m,)).astype(float))
        self.blocks[name] = np.arange(self.row, self.row + m).reshape(len(rows), m // len(rows))
        self.row += m

    def named(self) -> dict[str, np.ndarray]:
        """The blocks that hold rows (lift_products=False left a `lifting` of shape (N, 0), reported as 0)."""
        return {name: rows for name, rows in self.blocks.items() if rows.size}

    def g(self):
        return ca.vertcat(*self.parts)

    def lb(self) -> np.ndarray:
        return np.concatenate(self.lo)

    def ub(self) -> np.ndarray:
        return np.concatenate(self.hi)


def plane_gap(dyn: Dynamics, contact, q, ground: float):
    """The gap c = s^T p(q) - s_z ground [m] of a contact's point from its plane (s its unit normal), for q (nq,)
    numbers or CasADi symbols."""
    s = plane_axes(contact.normal)[0]
    p = dyn.point_position(contact.point)(q)
    return s[0] * p[0] + s[1] * p[1] + s[2] * p[2] - s[2] * ground


def _free_start_rows(rows: _Rows, path_fn: dict, y_0, hole_scale) -> None:
    """Blocks above_ground_y0, holes_y0, never_touching_y0 (1, m): a periodic plan's start y_0 is a variable, which the
    task's checks of initial.q do not see, held as the nodes are (a periodic point mass started inside a hole, exit
    0, session 58's tester); blocks of their own, as a FESD step's rows are per element."""
    for name in ("above_ground", "holes", "never_touching"):
        if path_fn[name] is not None:
            rows.add(f"{name}_y0", [path_fn[name](y_0, *((hole_scale,) if name == "holes" else ()))], 0.0, np.inf)


TARGET_LANDING_MPS = 1e-3  # [m/s] a target contact on its plane moving into it faster than this ends in an impact
# [m] "on its plane" for that: a point-mass target 1e-6 m up at -1 m/s ended inside an impact too, 1e-5 m to 1.2 mm
# up failed "out of reach" at some N; 2 mm planned at N = 4 and 10, at 0.5 to 2 m/s down (session 60)
TARGET_LANDING_GAP_M = 2e-3


def _check_target_not_landing(system: TimeFreezingSystem, task: Task, contacts) -> None:
    """InputError when plan.target_v moves a contact point into its plane while plan.target_q puts it on that plane
    (within TARGET_LANDING_GAP_M): the plan's last steps then freeze inside the impact (the point-mass hop with
    target_v = (0, -1) m/s ended with an impact whose "post-impact" velocity still pointed 1 m/s into the ground,
    exit 0)."""
    plan = task.plan
    if plan.target_q is None or plan.target_v is None:  # (terminal_velocity=False refuses a target_v)
        return
    y = system.initial_state(np.array(plan.target_q, float), np.array(plan.target_v, float))
    u = np.zeros(system.nu)
    gaps = np.asarray(system.gap_fn(y, u), float).ravel()
    speeds = np.asarray(system.normal_velocity_fn(y, u), float).ravel()
    for c, gap, speed in zip(contacts, gaps, speeds):
        if gap < TARGET_LANDING_GAP_M and speed < -TARGET_LANDING_MPS:
            raise InputError(f"plan.target_q puts contact point {c.point!r} {max(gap, 0.0):.3g} m from its plane and "
                             f"plan.target_v moves it {-speed:.6g} m/s into it: the plan would end inside an impact; "
                             f"give a target_v without speed into the plane there, or a target at least "
                             f"{TARGET_LANDING_GAP_M:g} m from it")


def _state_key(key: str, task: Task) -> str:
    """A start or target's task key as a refusal names it: a periodic task's initial.q is the guess of q(0), which
    the node rows move (yet a guess in the ground or in a hole is refused too)."""
    return key + (" (with plan.periodic the initial guess of q(0))" if key == "initial.q" and task.is_periodic else "")


def _check_outside_holes(dyn: Dynamics, contacts, task: Task) -> None:
    """InputError when task.initial.q or plan.target_q (nq,) [m, rad] puts a contact point inside one of the plan's
    holes. The last node is held both at the target and out of the holes, so no plan exists (Capler's target x = 2.6 m
    stands its foot in the third hole; the solve only found that out by failing, in 224 s). The holes' rows start at
    node 1, so a start standing in a hole, on ground that is not there, was planned and validated."""
    plan = task.plan
    for key, q in (("initial.q", task.initial.q), ("plan.target_q", plan.target_q)):
        if q is None:
            continue
        for c in contacts:
            p = np.asarray(dyn.point_position(c.point)(np.array(q, float)), float).ravel()
            for i, e in enumerate(plan.holes):
                if e.metric(p[0], p[2]) < 1.0 - HOLE_EDGE_TOL:
                    start = key == "initial.q"
                    # (the metric, not only the position: 1 nm inside the rim printed x = 0.25, the rim itself)
                    raise InputError(f"{_state_key(key, task)} puts contact point {c.point!r} at x = {p[0]:.10g}, "
                                     f"z = {p[2]:.10g} m, "
                                     f"inside plan.holes[{i}] (x = {e.x:g}, z = {e.z:g}, a = {e.a:g}, b = {e.b:g}; "
                                     f"ellipse metric {e.metric(p[0], p[2]):.10g} < 1); no "
                                     f"plan can {'start' if start else 'end'} there: move the "
                                     f"{'start' if start else 'target'} or the hole")


def _terminal(rows: _Rows, robot: Robot, task: Task, options: ProblemOptions, X, var_blocks, y0) -> ca.SX:
    """Add the terminal (or periodic) and physical-time rows; returns the terminal residual the soft
    terminal penalizes. Same rows as the implicit Euler transcription."""
    plan, hz = task.plan, task.horizon
    nq, nv, ny = robot.nq, robot.nv, len(y0)
    y_N = X[var_blocks["y"][-1]]
    if plan.periodic is not None:
        if not options.terminal_velocity:  # (ignored, yet another Problem.signature: a start refused for no reason)
            raise InputError("ProblemOptions(terminal_velocity=False) drops the terminal velocity rows, which a "
                             "periodic plan (plan.periodic) does not have: its end velocity is the relabelled start's")
        perm, along, _ = task.periodic_map(robot)
        shift = np.zeros(nq)
        shift[along] = plan.periodic.step
        y_0 = X[var_blocks["y0"]]
        term_res = ca.vertcat(y_N[:nq] - y_0[:nq][perm.tolist()] - shift, y_N[nq : nq + nv] - y_0[nq : nq + nv][perm.tolist()])
        rows.add("periodic", [term_res], 0.0, 0.0)
    elif options.terminal_velocity:
        target_v = np.zeros(nv) if plan.target_v is None else np.array(plan.target_v, float)
        A, lower, upper = task.velocity_rows(robot)  # they hold at y_N too: no plan exists (IPOPT said "infeasible")
        rate = A @ target_v
        slack = 1e-9 * np.maximum(1.0, np.abs(rate))  # (0.1 + 0.2 against an upper bound of 0.3 meets it)
        outside = np.flatnonzero((rate < lower - slack) | (rate > upper + slack))
        if outside.size:
            r, omitted = outside[0], " (omitted: zeros)" if plan.target_v is None else ""
            raise InputError(f"plan.velocity_bounds[{r}] = [{lower[r]:g}, {upper[r]:g}] excludes the end velocity, "
                             f"{rate[r]:g} by plan.target_v{omitted}, which the last node must meet: widen the bound "
                             "or give a plan.target_v inside it")
        fast = [f"{robot.dof_names[j]} ({target_v[j]:g} beyond {robot.v_limit[j]:g})" for j in range(nv)
                if abs(target_v[j]) > robot.v_limit[j]]
        if fast:  # (plan.target_v is read in the robot's units: rad/s or m/s)
            raise InputError(f"plan.target_v exceeds the robot file's joint speed limit (<limit velocity>) of "
                             f"{', '.join(fast)}, which every node must meet: give a plan.target_v within it")
        target = np.concatenate([np.array(plan.target_q, float), target_v])
        rows.add("terminal", [y_N[: nq + nv]], target, target)
        term_res = y_N[: nq + nv] - target
    else:
        if plan.target_v is not None:  # (built without it, silently: the task's end velocity dropped)
            raise InputError(f"plan.target_v = {list(plan.target_v)} needs the terminal velocity rows, which "
                             "ProblemOptions(terminal_velocity=False) leaves out: drop target_v or keep the rows")
        target_q = np.array(plan.target_q, float)
        rows.add("terminal", [y_N[:nq]], target_q, target_q)
        term_res = y_N[:nq] - target_q
    if hz.physical_time is not None:
        rows.add("physical_time", [y_N[ny - 1]], hz.physical_time, hz.physical_time)
    return term_res
