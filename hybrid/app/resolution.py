"""Is an impact resolved? Warnings when a deformable body is struck harder than its mesh or the
time step can follow.

An impact's answer depends on the mesh and the step more than anything else a scene does, and an
under-resolved one gives a quiet, plausible and wrong answer: a steel ball at 20 m/s stops dead on
a coarse aluminium plate without denting it, a brittle slab dropped on the ground does not crack
because the impact's impulse is spread over a step 25 times longer than the impact. These are the
model's honest answers at that resolution; :class:`ImpactWatch` says so, once per body and kind
(again for a later impact that asks for a resolution or step a fifth finer than any told before):

- in space, when the contact patch is carried by fewer than a few nodes: the patch radius is
  estimated from Hertz's impact (and, for a body with a yield stress, the fully plastic contact
  pressure of about 3 Y), with the radius of curvature of the shapes that meet; a flat contact
  (boxes, planes, meshes) is measured instead, by the nodes that touch;
- in time, when the step is longer than a quarter of the impact, or, for a body stepped by backward
  Euler, when its damping over the impact's steps would cost more than a tenth of the rebound
  (EULER_KEPT): an impact lasts about two wave transits
  across the body along the impact (``2 L / sqrt(E / rho)``), or Hertz's contact time (longer
  for a body that yields) when curved shapes meet.

It looks at each step's end (through the Simulation's per-step hook) for surface nodes of FEM
bodies touching rigid bodies or planes, and rigid bodies' contact points on their faces
(hybrid.app.impact_contacts), with the velocities of the step's start: an impact is a
contact that began in the step, approached fast enough that its stress (``rho c v``, the stress of a wave of speed ``v``)
reaches a quarter of the body's yield or fracture stress, or a strain of 1e-4 for an elastic
body. Contacts between two FEM bodies are not examined.
"""
from dataclasses import dataclass

import numpy as np

from .impact_contacts import (RigidMotion, across, approach, just_parked, near, partner_of,
                              same_body, strike_speeds, within_reach)

# an impact is examined when rho c v reaches this share of the body's yield or fracture stress
STRENGTH_SHARE = 0.25
# ... or, for a purely elastic body, when v / c reaches this strain
ELASTIC_STRAIN = 1e-4
# the patch is resolved when its radius spans this many node spacings (about 7 nodes under it)
PATCH_ELEMENTS = 1.5
# the resolution suggested puts this many node spacings across the patch's radius
PATCH_SUGGESTED = 3.0
# a flat contact is resolved when at least this many nodes touch
FLAT_NODES = 3
# the step is resolved when it is at most this share of the impact's duration (at 1.7 steps to
# the impact a ball rebounded from a plate at 2.46 m/s against 6.61 at a small step, unwarned)
STEPS_PER_IMPACT = 4
# backward Euler damps a vibration of angular frequency w by 1 / sqrt(1 + (w h)^2) a step: over an
# impact of n steps (half a period) a body keeps (1 + (pi / n)^2)^(-n / 2) of its rebound speed;
# the step is resolved when that is at least EULER_KEPT (n >= pi^2 / (2 ln(1 / EULER_KEPT)) = 47)
EULER_KEPT = 0.9
EULER_STEPS = np.pi ** 2 / (2.0 * np.log(1.0 / EULER_KEPT))
# Hertz's contact stiffens as it closes (F ~ d^1.5): its squared frequency averaged over the contact
# (1.875 v^2 / d_max^2 at full compression times the mean of sin^0.5) is 1.25 times the half
# period's ((pi / 2.94)^2 v^2 / d_max^2), so a curved contact counts 1.25 times fewer steps: an FEM
# ball (E = 1 MPa) dropped on the ground kept 0.59 / 0.88 / 0.98 of Newmark's rebound at 12 / 48 /
# 194 steps to the impact, estimated 0.62 / 0.88 / 0.97 (0.68 / 0.90 / 0.97 without the factor)
HERTZ_STIFFENING = 1.25
# an impact's sub-stepping (resolve_impacts) goes on while its bodies touch, up to this many of its
# estimated durations (the estimate is short for a plate that gives: stopped at it, a ball left
# a plate at 2.13 m/s sub-stepped from dt = 1e-4, 4.16 from 2e-4)
SUBSTEP_SPAN = 8
# nodes closer than this share of their spacing touch; a contact is looked at within CLOSE
TOUCH = 0.05
CLOSE = 0.25


@dataclass(frozen=True)
class ImpactWarning:
    """An under-resolved impact. body: the scene body's name. kind: ``"space"`` or ``"time"``.
    time: s, the impact's step. partner: what struck it (a body's name or ``"plane"``).
    speed: m/s, the speed of approach. have / need: the body's surface node spacing and the
    resolution that would resolve the patch (m, kind space), or the scene's dt and the step that
    would resolve the impact (s, kind time). message: the run log's line."""
    body: str
    kind: str
    time: float
    partner: str
    speed: float
    have: float
    need: float
    message: str

    def as_dict(self):
        """JSON-ready summary row."""
        return {"body": self.body, "kind": self.kind, "time": self.time, "partner": self.partner,
                "impact_speed": self.speed,
                ("resolution" if self.kind == "space" else "dt"): self.have,
                ("resolution_needed" if self.kind == "space" else "dt_needed"): self.need,
                "message": self.message}


@dataclass(frozen=True)
class Impact:
    """One impact estimate: patch radius ``a`` m (None for a flat contact), duration ``tau`` s."""
    a: float | None
    tau: float


def impact_estimate(young, poisson, density, yield_stress, extent, radius, mass, speed):
    """:class:`Impact` of a deformable body (``young`` Pa, ``poisson``, ``density`` kg/m^3,
    ``yield_stress`` Pa or None; ``extent`` m across it along the impact) struck by a rigid
    surface at ``speed`` m/s, the curvatures meeting giving ``radius`` m (inf: flat on flat), the
    two bodies' reduced ``mass`` kg. Hertz (Johnson, Contact Mechanics, ch. 11): largest
    indentation ``d = (15 m v^2 / (16 E* sqrt(R)))^(2/5)``, patch radius ``sqrt(R d)``, contact time
    ``2.87 (m^2 / (R E*^2 v))^(1/5)``; a fully plastic patch carries a mean pressure ``3 Y``, so
    ``1/2 m v^2 = 3 Y pi R d^2`` gives ``d``, a patch radius ``sqrt(2 R d)`` and a loading time
    of a quarter period of that spring. The duration is at least two wave transits
    ``2 extent / sqrt(E / rho)``."""
    transit = extent / np.sqrt(young / density)
    tau = 2.0 * transit
    if not np.isfinite(radius):
        return Impact(None, tau)
    E_star = young / (1.0 - poisson ** 2)
    d = (15.0 * mass * speed ** 2 / (16.0 * E_star * np.sqrt(radius))) ** 0.4
    a = np.sqrt(radius * d)
    tau = max(tau, 2.87 * (mass ** 2 / (radius * E_star ** 2 * speed)) ** 0.2)
    if yield_stress is not None:
        stiffness = 6.0 * np.pi * yield_stress * radius       # F = 3 Y pi (2 R d)
        a = max(a, np.sqrt(2.0 * radius * speed * np.sqrt(mass / stiffness)))
        tau = max(tau, 0.5 * np.pi * np.sqrt(mass / stiffness))
    return Impact(float(a), float(tau))


def shape_radius(body):
    """Radius of curvature (m) of a scene body's surface where it strikes: a sphere's, capsule's
    or cylinder's radius; inf for boxes and meshes (flat faces)."""
    shape = body.shape if body is not None else None
    if shape is not None and shape.type in ("sphere", "capsule", "cylinder"):
        return float(shape.radius)
    return np.inf


class ImpactWatch:
    """Watches a run's steps for under-resolved impacts (see the module). ``check`` returns the
    new warnings; ``warnings`` keeps every one (at most one per scene body and kind). With
    ``max_substeps`` > 1 (a scene's ``resolve_impacts``) it also says how many sub-steps a step
    needs (:meth:`substeps_needed`, :meth:`substeps_now`; hybrid.coupling.substep takes them)
    and warns in time only about impacts shorter than ``dt / max_substeps``."""

    def __init__(self, max_substeps=1):
        self.warnings = []
        self._spacing = {}
        self.touching = set()       # (FEM body, partner) names in contact at the last step seen
        # sub-stepping of impact steps (the scene's resolve_impacts): at most this many sub-steps
        # per step; step_tau: the shortest impact (s) that began in the last step checked and is
        # shorter than it, else None, and step_steps: the most steps any of them should span (its
        # body's steps_per_impact); substepped: what sub-stepping did so far (the summary's)
        self.max_substeps = max_substeps
        self.step_tau, self.step_steps = None, STEPS_PER_IMPACT
        self.step_pairs = set()     # (FEM body, partner) names of those impacts
        # an impact under way is sub-stepped: (until s, sub-steps, at the latest s, its pairs)
        self.resolving = None
        self.substepped = {"steps": 0, "substeps": 0, "smallest_dt": None}

    def substeps_needed(self, dt, end):
        """Sub-steps the last step checked (ending at time ``end`` s) should be taken in (1:
        none): enough that its shortest impact spans its body's :func:`steps_per_impact`, at most
        ``max_substeps``. The steps that follow until the impact is over (``end`` plus its
        duration, and while its bodies touch: :meth:`keep_resolving`, up to SUBSTEP_SPAN
        durations) are to be sub-stepped as well (:meth:`substeps_now`)."""
        if self.step_tau is None or self.max_substeps <= 1:
            return 1
        count = int(min(self.max_substeps, np.ceil(dt * self.step_steps / self.step_tau - 1e-9)))
        if count <= 1:
            return 1
        until, most, latest, pairs = self.resolving if self.resolving is not None else (end, count, end, set())
        self.resolving = (max(until, end + self.step_tau), max(most, count),
                          max(latest, end + SUBSTEP_SPAN * self.step_tau), pairs | self.step_pairs)
        return count

    def keep_resolving(self, model, state):
        """After a sub-stepped step ending at ``state``: the next step is sub-stepped too while
        the impact's bodies still touch (its estimated duration is short for a body that gives),
        until SUBSTEP_SPAN durations have passed."""
        if self.resolving is None:
            return
        until, most, latest, pairs = self.resolving
        if until <= state.time + 1e-9 * model.dt < latest and self._touch(model, state, pairs):
            self.resolving = (state.time + model.dt, most, latest, pairs)

    def _touch(self, model, state, pairs):
        """Whether any (FEM body, partner) of ``pairs`` (names) is in contact at ``state``."""
        for j, m in enumerate(model.fem):
            name = model.names[model.fem_ids[j]]
            partners = {p for b, p in pairs if b == name}
            if partners:
                c = near(model, state, j, CLOSE * self._node_spacing(m))
                found = {model.names[int(model.rigid_ids[p])] if p >= 0 else "plane" for p in c.partner}
                if found & partners:
                    return True
        return False

    def substeps_now(self, time):
        """Sub-steps a step starting at ``time`` s is taken in because an impact is under way
        (1: none is)."""
        if self.resolving is None or time >= self.resolving[0]:
            self.resolving = None
            return 1
        return self.resolving[1]

    def substepped_step(self, count, dt):
        """Count a step of ``dt`` s taken in ``count`` sub-steps (the summary's ``substeps``)."""
        done = self.substepped
        done["steps"] += 1
        done["substeps"] += count
        h = dt / count
        done["smallest_dt"] = h if done["smallest_dt"] is None else min(done["smallest_dt"], h)

    def check(self, before, model, state):
        """New :class:`ImpactWarning` of the step from ``before`` (the coupled ``(model, state)``
        at its start) to ``state`` (``model``: the model it was taken with). Steps taken with
        another model than they started with (an auto body turned deformable) are skipped."""
        old_model, old = before
        self.step_tau, self.step_steps, self.step_pairs = None, STEPS_PER_IMPACT, set()
        if old_model is not model or not model.fem or old.fem is None or len(old.fem) != len(model.fem):
            return []
        rm = model.rigid
        if rm.body_count == 0 and rm.plane_point.shape[0] == 0:
            return []
        # per body and kind, the finest resolution or step asked for so far: a later impact is
        # told only when it asks for a fifth less or finer (once per body and kind, but a slow
        # first contact does not hide a fast blow: Hertz's contact time goes as v^-1/5)
        asked = {}
        for w in self.warnings:
            asked[w.body, w.kind] = min(w.need, asked.get((w.body, w.kind), np.inf))
        origin = model.fragment_of if model.fragment_of is not None else range(len(model.names))
        new, touching, motion = [], set(), RigidMotion.of(model, old, state)
        for j in range(len(model.fem)):
            scene_body = model.scene.bodies[origin[int(model.fem_ids[j])]]
            for found in self._impacts(model, (old, state, motion), j, scene_body, touching):
                key = (found.body, found.kind)
                if found.need < 0.8 * asked.get(key, np.inf):
                    asked[key] = found.need
                    new.append(found)
        self.warnings += new
        self.touching = touching
        return new

    def _impacts(self, model, step, j, body, touching):
        """The warnings (either kind) of FEM body ``j`` (scene ``body``) in the ``step`` = ``(old,
        state, motion)`` from coupled state ``old`` to ``state`` (``motion``: its
        :class:`RigidMotion`), of contacts that began in that step; the names of its contact
        pairs are added to ``touching``."""
        old, state, motion = step
        m, s1 = model.fem[j], state.fem[j]
        name = model.names[model.fem_ids[j]]
        spacing = self._node_spacing(m)
        relevant = _relevant_speed(m, body)
        rigid, plane = strike_speeds(model, old, j, motion)
        reach = within_reach(model, state, j, CLOSE * spacing)
        if max(plane, rigid[reach].max(initial=0.0)) < relevant:
            # nothing within reach could meet the body fast enough to matter: no contact that
            # begins now is judged, so none is looked for (a slab resting under a box looked for
            # its contacts every step, 7% of the step); those it had are taken as kept
            touching.update(pair for pair in self.touching if pair[0] == name)
            return []
        c = near(model, state, j, CLOSE * spacing, (rigid, relevant), motion, reach)
        speeds = approach(model, old, state, j, c, motion)
        # a partner meets the body from the step that ends within a step's approach of it (or
        # the contacts' slop): looked for within CLOSE spacings, a steel block falling on a box
        # was said to be struck 31 mm before it was, at 0.6 m/s where it struck at 1.0
        closing = c.gap <= np.maximum(speeds, 0.0) * model.dt + model.settings.slop
        partners = {int(p): model.names[int(model.rigid_ids[p])] if p >= 0 else "plane"
                    for p in np.unique(c.partner[closing])}
        touching.update((name, p) for p in partners.values())
        # resting contact (the common case) is not new: nothing more to do
        began = [p for p, p_name in partners.items() if (name, p_name) not in self.touching
                 and not same_body(model, j, p) and not just_parked(model, state, p)]
        if not began:
            return []
        out = []
        for partner in began:
            partner_name, on = partners[partner], c.partner == partner
            speed = float(speeds[on].max())
            if not _relevant(m, body, speed):
                continue
            # the nodes that meet at once: within TOUCH of the leading one (a face landing flat is
            # met by all of its nodes in the step the contact begins, none of them touching yet);
            # a partner's point on a face between nodes is carried by none
            lead = on & (c.gap <= c.gap[on].min() + TOUCH * spacing) & (c.node >= 0)
            normal = across(model, state, j, c, int(np.argmax(np.where(on, speeds, -np.inf))), lead)
            extent = float(np.ptp(s1.x @ normal))
            partner_body, partner_mass = partner_of(model, int(partner))
            curvature = 1.0 / shape_radius(body) + 1.0 / shape_radius(partner_body)
            radius = 1.0 / curvature if curvature > 0 else np.inf
            mass = float(m.node_mass.sum())
            reduced = mass * partner_mass / (mass + partner_mass) if np.isfinite(partner_mass) else mass
            impact = impact_estimate(m.young, m.poisson, m.density, m.yield_stress, extent, radius,
                                     reduced, speed)
            nodes_on = int(np.unique(c.node[lead]).size)
            where = (f"t = {state.time:.6g} s: '{body.name}' struck by '{partner_name}' at "
                     f"{speed:.3g} m/s")
            per = steps_per_impact(m.integrator, impact.a is not None)
            if impact.tau < per * model.dt:
                self.step_tau = min(impact.tau, self.step_tau or np.inf)
                self.step_steps = max(self.step_steps, per)
                self.step_pairs.add((name, partner_name))
            out += _judged(impact, where, spacing, nodes_on, (model.dt, self.max_substeps, m.integrator), extent,
                           (body.name, state.time, partner_name, speed))
        return out

    def _node_spacing(self, m):
        """Median edge length (m) of a body's surface triangles (its nodes' spacing on its
        surface; a box mesh's face diagonals do not count), memoised per model."""
        key = id(m)
        hit = self._spacing.get(key)
        if hit is not None and hit[0] is m:
            return hit[1]
        p = m.rest_points[m.surface]
        edges = np.linalg.norm(p - np.roll(p, 1, axis=1), axis=2)
        spacing = float(np.median(edges))
        if len(self._spacing) > 256:
            self._spacing.clear()
        self._spacing[key] = (m, spacing)
        return spacing

    def snapshot(self):
        """Plain data a checkpoint keeps: the warnings so far and the contacts of the last step
        (see :meth:`restore`)."""
        return {"warnings": [w.__dict__.copy() for w in self.warnings],
                "touching": sorted(list(pair) for pair in self.touching),
                "substepped": dict(self.substepped),
                "resolving": None if self.resolving is None else
                [*self.resolving[:3], sorted(list(pair) for pair in self.resolving[3])]}

    def restore(self, snapshot):
        """Continue from a :meth:`snapshot`."""
        self.warnings = [ImpactWarning(**w) for w in snapshot["warnings"]]
        self.touching = {tuple(pair) for pair in snapshot["touching"]}
        self.substepped = dict(snapshot["substepped"])
        r = snapshot["resolving"]
        if r is not None and len(r) == 2:       # (a checkpoint of before the pairs were kept)
            r = [r[0], r[1], r[0], []]
        self.resolving = None if r is None else (*r[:3], {tuple(pair) for pair in r[3]})


def steps_per_impact(integrator, curved=False):
    """Steps an impact on a body stepped by ``integrator`` should span: STEPS_PER_IMPACT, and
    for backward Euler at least EULER_STEPS (its damping), HERTZ_STIFFENING times more for a
    ``curved`` (Hertz) contact."""
    if integrator != "backward_euler":
        return STEPS_PER_IMPACT
    return max(STEPS_PER_IMPACT, EULER_STEPS * (HERTZ_STIFFENING if curved else 1.0))


def _down(x):
    """``x`` > 0 rounded down to two significant digits (a step suggested so is short enough)."""
    unit = 10.0 ** (np.floor(np.log10(x)) - 1)
    return float(np.floor(x / unit * (1 + 1e-12)) * unit)


def _relevant(m, body, speed):
    """Whether an approach at ``speed`` m/s matters to FEM body ``m`` (scene ``body``)."""
    return speed > 0 and speed >= _relevant_speed(m, body)


def _relevant_speed(m, body):
    """The least approach speed (m/s) that matters to FEM body ``m`` (scene ``body``): its wave
    stress ``rho c v`` reaches STRENGTH_SHARE of its yield or fracture stress, or for an elastic
    body a strain ``v / c`` of ELASTIC_STRAIN (``c = sqrt(E / rho)``)."""
    c_wave = np.sqrt(m.young / m.density)
    strengths = [v for v in (m.yield_stress, body.fracture_stress) if v is not None]
    if strengths:
        return STRENGTH_SHARE * min(strengths) / (m.density * c_wave)
    return ELASTIC_STRAIN * c_wave


def _judged(impact, where, spacing, nodes_on, stepping, extent, about):
    """The warnings an :class:`Impact` deserves: ``where`` opens their messages, ``spacing`` m
    of the body's surface nodes, ``nodes_on`` of them touch, ``stepping``: the step ``dt`` s,
    the most sub-steps it may be taken in and the body's integrator, the body ``extent`` m along
    the impact; ``about``: (body, time, partner, speed) of the warnings."""
    dt, most, integrator = stepping
    see = "check with `hybrid converge` (docs/studies.md)"
    out = []
    touching = f"{nodes_on} touching" if nodes_on else "none touching: it strikes inside a face"
    if impact.a is not None and impact.a < PATCH_ELEMENTS * spacing:
        need = impact.a / PATCH_SUGGESTED
        out.append(ImpactWarning(
            about[0], "space", *about[1:], spacing, need,
            f"warning: {where}: the contact patch (radius about {impact.a * 1e3:.3g} mm, under "
            f"{PATCH_ELEMENTS:g} node spacings: nodes {spacing * 1e3:.3g} mm apart; {touching}) is "
            f"carried by few nodes, so the stress under it is smeared over the elements and a dent or crack "
            f"there is underestimated; a resolution of about {need:.2g} m would resolve it: {see}"))
    elif impact.a is None and nodes_on < FLAT_NODES:
        need = spacing / 2.0
        out.append(ImpactWarning(
            about[0], "space", *about[1:], spacing, need,
            f"warning: {where}: the contact is carried by {nodes_on} node(s) ("
            f"{'an edge or corner strikes' if nodes_on else 'it strikes inside a face'}; nodes "
            f"{spacing * 1e3:.3g} mm apart), so the stress under it is smeared over "
            f"the elements; refine (resolution {need:.2g} m or finer): {see}"))
    steps = impact.tau / (dt / most)
    euler = integrator == "backward_euler"
    curved = impact.a is not None
    if steps < steps_per_impact(integrator, curved):
        lasts = "two wave transits" if impact.a is None else "contact time, at least two wave transits"
        step = f"dt = {dt:.2g} s" + (f" even in {most} sub-steps" if most > 1 else "")
        opening = (f"warning: {where}: the impact lasts about {impact.tau:.2g} s ({lasts} across "
                   f"{extent * 1e3:.3g} mm), {steps:.2g} step(s) of {step}")
        lower = ("(the estimate is a lower bound of the impact's length; a body that gives, a "
                 "plate flexing, keeps contact longer)")
        # what is wrong: the impulse spread over the steps, backward Euler's damping, or both
        wrong = []
        if steps < STEPS_PER_IMPACT:
            wrong.append("its impulse is spread over them and its peak stress and rebound are "
                         "underestimated")
        if euler and steps >= STEPS_PER_IMPACT:     # (the estimate holds for a few steps or more)
            n = steps / (HERTZ_STIFFENING if curved else 1.0)
            kept = (1.0 + (np.pi / n) ** 2) ** (-n / 2.0)
            wrong.append(f"backward Euler's damping over them keeps about {kept:.0%} of the "
                         f"rebound speed and lowers the peak stress")
        need = impact.tau / steps_per_impact(integrator, curved)
        ways = [f"dt = {_down(need):.2g} s or less {lower}"] + (
            ["`integrator = \"newmark\"` (which does not damp)"] if euler else []) + (
            ["`resolve_impacts`"] if most == 1 else [])
        message = f"{opening}: {'; '.join(wrong)}; {' or '.join(ways)}: {see}"
        out.append(ImpactWarning(about[0], "time", *about[1:], dt / most, need, message))
    return out
