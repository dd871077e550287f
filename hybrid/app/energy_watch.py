"""The energy watchdog of a run: a scene in which nothing does work cannot gain energy.

Contacts, friction, damping, plastic flow and fracture only take energy out, and backward Euler
damps; so in a scene without moving anchors the total energy (kinetic, elastic, gravitational,
the constant loads' potential, and the plastic work dissipated so far: flow turns energy into
heat, it makes none) of a frame exceeding the first frame's by more than the energy in play is a
divergence the finiteness checks do not see (a Newmark bar bouncing on the ground at a large step
climbed from 56 J to 7e12 J at 127 m/s, and the run ended "ok"). The run then stops as unstable,
naming the body with the most energy. The energy in play is the largest of: the first frame's
kinetic energy, the energy released so far (the first frame's less the least since), and the
bodies' weight times their size (a body started a little inside the ground rises by its overlap
when pushed out). (Not the largest kinetic energy so far: a body whose speed a defect keeps
raising would then never gain more than it.)
"""
import numpy as np

from hybrid.coupling.stability import InstabilityError

from . import observe

# the most a frame's total energy may exceed the first frame's, in units of the energy in play
GAIN_LIMIT = 1.0


def does_work(model):
    """Whether something in the scene adds energy the watch cannot count: an anchor that moves,
    or a load on an auto body (its load leaves the count while it is rigid). A deformable body's
    loads are constant forces, whose work the frames' load potential counts (:func:`loads`)."""
    auto = any(b.model == "auto" and b.loads for b in model.scene.bodies)
    return auto or any(np.any(m.anchor_velocity) for m in model.fem)


def loads(model, state):
    """Potential energy (J) of the deformable bodies' loads, ``-sum f . x`` over their nodes:
    constant forces, so the total energy with it is conserved as with gravity's (an auto body
    held rigid by its anchors keeps its loads where they were)."""
    parked = [(p.fem, p.state) for p in model.parked.values()]
    return -float(sum(np.einsum("ij,ij->", m.node_load, s.x) for m, s in [*zip(model.fem, state.fem), *parked]
                      if np.any(m.node_load)))


def load_scale(model):
    """The loads' size times the bodies' size, summed (J): |F| L per loaded body."""
    return float(sum(np.abs(m.node_load).sum() * np.ptp(m.rest_points, axis=0).max()
                     for m in model.fem if np.any(m.node_load)))


def weight_scale(model):
    """The bodies' weight times their size, summed (J): |g| m L per body (L: a rigid body's
    bounding diameter, an FEM body's largest rest extent)."""
    g = float(np.linalg.norm(model.gravity))
    rm = model.rigid
    free = ~rm.body_fixed if rm.body_count else np.zeros(0, bool)
    total = float((rm.body_mass[free] * 2.0 * rm.body_radius[free]).sum()) if rm.body_count else 0.0
    for m in model.fem:
        total += float(m.node_mass.sum() * np.ptp(m.rest_points, axis=0).max())
    return g * total


def check(model, state, energies, kinetic, potentials=None, dissipated=None):
    """Raise InstabilityError when the last of the frames' total ``energies`` (J; the first is
    the run's start), with the loads' ``potentials`` (J, :func:`loads`) and the plastic work
    ``dissipated`` by then (J), exceeds the first by more than GAIN_LIMIT times the energy in
    play (``kinetic``: the frames' kinetic energies, the first's counts); nothing in a scene that
    does work the watch cannot count. (A bar loaded above its plastic limit load flowed until its
    elements turned inside out, its plastic work 40 times the loads' work; counting the elastic
    energy alone, its total stayed within the energy in play.)"""
    if len(energies) < 2 or does_work(model):
        return
    for part in (potentials, dissipated):
        if part is not None:
            energies = np.add(energies, part)
    start = energies[0]
    in_play = max(kinetic[0], start - min(energies), weight_scale(model) + load_scale(model))
    gain = energies[-1] - start
    if in_play > 0.0 and gain > GAIN_LIMIT * in_play:
        body, _ = max(observe.body_energies(model, state).items(), key=lambda item: item[1])
        work = "the loads' work counted" if load_scale(model) > 0 else "nothing in the scene does work"
        raise InstabilityError(body, state.time, f"total energy gained over the start (J; energy "
                               f"in play {in_play:.3g} J, {work}{_limit_hint(model)})", gain)


def _limit_hint(model):
    """A clause naming the loaded bodies that yield: a load above a perfectly plastic body's limit
    load (a bar's area times its yield stress) has no equilibrium, and the body stretches until
    the run stops (a bar under 1.05 times it reached a strain of 13 in 0.1 s)."""
    names = [b.name for b in model.scene.bodies if b.loads and b.yield_stress is not None]
    broken = [b.name for b in model.scene.bodies if b.loads and (b.fracture_stress is not None
                                                                 or b.tearing_strain is not None)]
    hint = (f"; {', '.join(repr(n) for n in names)} carries loads and yields: loads above its "
            f"plastic limit load (a bar's area times yield_stress) have no equilibrium") if names else ""
    if broken and model.fragment_of is not None:
        # (a 22 kN load on a 15 g piece broken off a brittle bar took it to 2.8 km/s)
        hint += (f"; {', '.join(repr(n) for n in broken)} carries loads and broke: a load the body "
                 f"could not hold, left on a piece that broke off, accelerates it without end")
    return hint
