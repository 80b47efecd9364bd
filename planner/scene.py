"""Scene analysis: what the OCP of a robot and a task needs, decided in one place (issue 9).

`analyze_scene(robot, task)` returns a frozen `Skips` record; `build_problem` builds only what it
keeps (`ProblemOptions.scene_analysis = False` builds everything, for comparison) and the record
goes to `Problem.skips` and to summary.json ("scene"). Each skip drops machinery that cannot change
the OCP's solutions (the same state trajectories are feasible and cost the same), though the homotopy, a local
method, may reach another of them (a session-50 tester: 2 of 3 frictionless tasks with holes or a wall ended at other
plans, one of them dearer):

* frictionless: an inelastic contact with mu = 0 gets no tangential switch zeta = theta(t^T v), no
  tangential jump field a_t and hence no lifted products with zeta, no complementarity pairs of zeta
  (the FRICTIONLESS model, eqs. 17, 20). Without the analysis it gets them with a jump gain of 0
  (mu = 0: no tangential impulse; TimeFreezingSystem.frictionless_tangential): with alpha* = 1/2 the
  Sec. 6 polynomials then reduce to the frictionless ones, so F and the state trajectories are the same.
* never_touching: a contact with `touches = false` (docs/tasks.md) gets no time-freezing machinery
  at all (no selectors, fields, multipliers, complementarity pairs, contact forces), only the path
  constraint gap >= 0 at every node (Problem.g_blocks["never_touching"]) besides the holes' rows that every
  contact point gets. The same physics whenever the point indeed never touches in the full
  problem's solution (the task's claim), but another NLP: the homotopy may reach another plan
  (docs/stability.md).
* dropped_holes: a (contact point, hole) pair is dropped when the point provably cannot reach the
  ellipse's bounding box; every hole wholly below a flat ground (Task.buried_holes) is dropped for
  every point (the contact points keep gap >= 0: touching ones by the time-freezing steps, to
  round-off, the others by their row). The rule (conservative, no dynamics): from the root, slide joints with
  world-fixed axes move the point inside a box given by their position bounds (task.q_bounds: the
  robot file's limits or plan.joint_bounds); from the first hinge on, everything further down the
  chain stays within a radius R of that hinge's origin, R = the sum of the lengths of the constant
  offsets and of the largest |q| of later slides (a hinge's bounds are not used). Planar and free
  joints make the box unbounded. The horizon and the start/target are not used: the OCP bounds no
  velocity, so any bounded box can be crossed in any horizon. Capler's default task has unbounded
  base slides, so nothing is dropped there; bounding base_x drops the holes beyond reach.
* elastic_state: not applicable as a skip: the elastic state p is built only per elastic contact
  (restitution > 0) and the OCP refuses elastic contacts, so inelastic-only scenes never had p.
  The record lists the contacts that would get one.

Unused outputs: the NLP holds only the expressions its objective and constraints reference (CasADi
SX graphs), and the diagnostics that are not needed by every NLP are built on first use already
(homotopy's g function, the projection solver); building the whole Capler problem takes 0.7 s of a
solve of minutes, so nothing else is skipped there (docs/benchmarks.md, "Scene skips").
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .dynamics import _expand
from .model import Robot
from .task import Task, contact_labels

REVOLUTE = ("revolute", "revolute_unbounded")


@dataclass(frozen=True)
class Skips:
    """The scene analysis' decisions, with one reason per decision.

    enabled: False when ProblemOptions.scene_analysis is off (then nothing is skipped).
    frictionless (n,): contact labels (task.contact_labels: a point, or point#k for one on several planes) of
      the contacts (mu = 0, inelastic) without tangential machinery.
    never_touching (n,): contact points with touches = false: no contact machinery, gap >= 0 (and the holes) only.
    dropped_holes (n,): (contact point, hole index into task.plan.holes) pairs left out.
    elastic_state (n,): contact points that get an elastic state p (empty: no p is built).
    reasons (n,): one human-readable line per decision.
    """

    enabled: bool = True
    frictionless: tuple[str, ...] = ()
    never_touching: tuple[str, ...] = ()
    dropped_holes: tuple[tuple[str, int], ...] = ()
    elastic_state: tuple[str, ...] = ()
    reasons: tuple[str, ...] = ()

    def to_json(self) -> dict:
        return {"enabled": self.enabled, "frictionless": list(self.frictionless), "never_touching": list(self.never_touching),
                "dropped_holes": [{"contact": c, "hole": i} for c, i in self.dropped_holes],
                "elastic_state": list(self.elastic_state), "reasons": list(self.reasons)}


def analyze_scene(robot: Robot, task: Task, enabled: bool = True) -> Skips:
    """The Skips of `task` on `robot` (module docstring); enabled = False records the decisions as
    not taken (everything is built) and keeps only the facts (elastic_state)."""
    # a touches = false point gets no contact machinery, so no p either (the record said "built for" it)
    elastic = tuple(dict.fromkeys(c.point for c in task.contacts if c.restitution > 0 and (c.touches or not enabled)))
    reasons = ["elastic state p: " + ("built for " + ", ".join(elastic) if elastic else
                                      "not built (no contact that may touch has restitution > 0)")]
    if not enabled:
        return Skips(enabled=False, elastic_state=elastic, reasons=tuple(reasons + ["scene analysis off: everything is built"]))
    never = tuple(dict.fromkeys(c.point for c in task.contacts if not c.touches))  # a corner's point once
    reasons += [f"{p}: touches = false, no contact machinery, only gap >= 0 (and the holes)" for p in never]
    # by contact label: a point on a rough floor and a frictionless wall was listed as frictionless (point#2 is)
    frictionless = tuple(label for label, c in zip(contact_labels(task.contacts), task.contacts)
                         if c.touches and c.mu == 0 and c.restitution == 0)
    reasons += [f"{p}: mu = 0, no tangential switch, jump field or pairs" for p in frictionless]
    dropped = []
    holes = task.plan.holes if task.plan is not None else ()
    if holes:
        lower, upper = task.q_bounds(robot)
        buried = task.buried_holes()
        # every contact point, touches = false too: the holes' rows keep each out (a never-touching knee was let in)
        for point in dict.fromkeys(c.point for c in task.contacts):
            lo, hi = reach_box(robot, point, lower, upper)
            for i, e in enumerate(holes):
                if i in buried:
                    dropped.append((point, i))
                    reasons.append(f"{point}: hole {i} at (x, z) = ({e.x:g}, {e.z:g}) m, half-axes ({e.a:g}, "
                                   f"{e.b:g}) m, lies wholly below the ground")
                elif hi[0] < e.x - e.a or lo[0] > e.x + e.a or hi[2] < e.z - e.b or lo[2] > e.z + e.b:
                    dropped.append((point, i))
                    reasons.append(f"{point}: hole {i} at (x, z) = ({e.x:g}, {e.z:g}) m, half-axes ({e.a:g}, "
                                   f"{e.b:g}) m, is out of reach (x in [{lo[0]:.3g}, {hi[0]:.3g}] m, z in "
                                   f"[{lo[2]:.3g}, {hi[2]:.3g}] m by the joint bounds)")
    return Skips(enabled=True, frictionless=frictionless, never_touching=never, dropped_holes=tuple(dropped),
                 elastic_state=elastic, reasons=tuple(reasons))


def reach_box(robot: Robot, point: str, q_lower, q_upper) -> tuple[np.ndarray, np.ndarray]:
    """A box (lo (3,), hi (3,)) [m], in world coordinates, holding every position of `point` for q in
    [q_lower, q_upper] (nq,) each (module docstring, "dropped_holes"; infinite where unbounded)."""
    model = robot.model
    frame = model.frames[robot.frame_id(point)]
    links, joint_link = _expand(model)
    chain, i = [], joint_link[frame.parentJoint]
    while i >= 0:
        chain.append(links[i])
        i = links[i].parent
    lo, hi, rot, radius, rotated = np.zeros(3), np.zeros(3), np.eye(3), 0.0, False

    def offset(t):  # a constant translation in the current frame
        nonlocal lo, hi, radius
        if rotated:
            radius += float(np.linalg.norm(t))
        else:
            lo, hi = lo + rot @ t, hi + rot @ t

    for link in reversed(chain):
        offset(np.asarray(link.placement.translation, float))
        if not rotated:
            rot = rot @ np.asarray(link.placement.rotation, float)
        if link.kind == "prismatic":
            a, b = q_lower[link.iq], q_upper[link.iq]
            if rotated:
                radius += max(abs(a), abs(b))
            else:
                d = rot @ np.asarray(link.axis, float)
                ends = [np.array([di * x if di else 0.0 for di in d]) for x in (a, b)]  # 0 * inf is 0 here
                lo, hi = lo + np.minimum(*ends), hi + np.maximum(*ends)
        elif link.kind in REVOLUTE:
            rotated = True  # distances from this hinge's origin are kept by everything below it
        else:  # planar, free: translations in a rotating frame, unbounded
            return np.full(3, -np.inf), np.full(3, np.inf)
    offset(np.asarray(frame.placement.translation, float))
    return lo - radius, hi + radius
