"""Hints in the run log: where a scene's choice of model or frame costs time or accuracy.

After a run, :class:`hybrid.simulation.Simulation` logs a note for each body whose largest strain
(``hybrid.app.peaks.Peaks``) says it would be better modelled otherwise: rigid, when an FEM or
auto body never strained enough to need FEM (:func:`rigid_hints`); corotated, when a
floating-frame body strained or turned parts of itself beyond what linear elasticity in one frame
follows (:func:`frame_hints`). Before a run, it warns of free deformable bodies that start
spinning faster than their step in the spinning frame holds (:func:`spin_warnings`).
"""
import math

import numpy as np

# the most a free deformable body may turn in one step (rad) under backward Euler, and under
# Newmark about any axis but its axis of largest inertia: its step in the spinning frame treats
# the centrifugal force explicitly and diverges from about 1 rad (a steel disk at 2000 rad/s
# under backward Euler: stable at dt = 0.3 and 0.4 ms, 430 times its energy at 0.7 ms; a
# 20 x 2 x 3 cm bar tumbling about its intermediate axis kept its energy to 1e-4 at 0.5 rad per
# step and 1.5% at 0.8 under either rule); Newmark held the disk about its largest axis at 2
SPIN_PER_STEP = 0.5


def rigid_hints(model, strains, struck=()):
    """Log lines suggesting ``model = "rigid"`` for FEM or auto bodies whose largest strain over
    every step (``strains``, as for :func:`hybrid.app.run.stepping`) stayed below the strain an auto body would
    turn deformable at (its elastify threshold; the default for an FEM body). Only for free bodies
    without loads: a rigid body carries none, and a fixed one would not show an anchored body's
    deflection, which is what a small strain there is usually wanted for; and not for the bodies
    named in ``struck`` (warned of an under-resolved impact: their strain is underestimated)."""
    from hybrid.coupling.auto import elastify_threshold
    lines = []
    for body in model.scene.bodies:
        strain = strains.get(body.name)
        if body.model not in ("fem", "auto") or strain is None or model.fragment_of[
                model.names.index(body.name)] != model.names.index(body.name):
            continue
        if body.loads or body.anchors or body.name in struck:
            continue
        limit = elastify_threshold(body)
        if strain < limit:
            lines.append(f"note: '{body.name}' never strained beyond {limit:.3g} (largest "
                         f"{strain:.3g}): model = \"rigid\" would step it as fast as a rigid body")
    return lines


# the largest element strain in the floating frame beyond which the run log suggests the
# corotated frame: linear strain grows with the rotation of a part of the body (1 - cos),
# 5% at about 18 degrees; a rubber cantilever at P L^2 / E I = 2 read 0.088, its tip 35% past
# the elastica, without a word
FLOATING_STRAIN = 0.05
# the largest turn of an element in the floating frame beyond which the same is said (the skew
# part of its displacement gradient, t): linear elasticity takes it for no strain, and moves the
# element's points along the tangents, turning it by atan(t) and stretching it sqrt(1 + t^2)-fold
# (5% at 18 degrees); a bar hinged along one edge swung and swelled 8,000-fold in volume with a
# linear strain of 5e-5
FLOATING_TURN = 0.32


def frame_hints(model, strains, spinning=(), turns=None, inverted=()):
    """Log lines suggesting ``frame = "corotated"`` for floating-frame bodies whose largest
    strain over every step (``strains``, as for :func:`hybrid.app.run.stepping`) passed FLOATING_STRAIN, or
    whose largest element turn in their frame (``turns``, rad, hybrid.app.peaks.Peaks.turns)
    passed FLOATING_TURN: linear elasticity in one best-fit frame (the world's for an anchored
    body) does not follow the large rotation of a part of the body; not for bodies named in
    ``spinning`` (warned that their step turns them too far: the corotated frame would not help)
    nor for those named in ``inverted`` (warned that elements of theirs turned inside out: no
    frame holds that strain)."""
    turns, found = turns or {}, {}
    origin = model.fragment_of if model.fragment_of is not None else range(len(model.names))
    for body in model.scene.bodies:
        if body.model not in ("fem", "auto") or body.frame != "floating" or body.name in spinning \
                or model.names[origin[model.names.index(body.name)]] in inverted:
            continue
        strain, turn = strains.get(body.name) or 0.0, turns.get(body.name, 0.0)
        if strain > FLOATING_STRAIN or turn > FLOATING_TURN:
            # a body and its fracture pieces in one line (a shattered tile's hundred pieces)
            own = model.names[origin[model.names.index(body.name)]]
            largest = found.setdefault(own, [0.0, 0.0, 0, bool(body.anchors)])
            largest[:3] = max(largest[0], strain), max(largest[1], turn), largest[2] + 1
    lines = []
    for name, (strain, turn, count, anchored) in found.items():
        said = []
        if strain > FLOATING_STRAIN:
            said.append(f"reached a strain of {strain:.2g}")
        if turn > FLOATING_TURN:
            stretch = math.sqrt(1 + turn * turn)
            said.append(f"turned parts of itself by up to {math.degrees(math.atan(turn)):.0f} degrees "
                        f"against {'its anchors' if anchored else 'its best-fit frame'} (taken "
                        "for no strain, and stretched "
                        + (f"by {stretch - 1:.0%})" if stretch < 2 else f"{stretch:.0f}-fold)"))
        pieces = f" ({count} bodies: it and its fracture pieces, the largest figures)" if count > 1 else ""
        lines.append(f"note: '{name}'{pieces} " + " and ".join(said) + " in the floating frame, "
                     "whose linear elasticity holds for small strains and small rotations of "
                     "its parts; frame = \"corotated\" follows large rotations (docs/fem.md)")
    return lines


def spin_warnings(scene, model, state):
    """Warnings ``{body name: message}`` for free deformable bodies that start turning more than
    SPIN_PER_STEP in a step: under backward Euler, and under Newmark about any axis but one of
    largest inertia (one moment larger than the others by 1%, or all three equal)."""
    dt, said = scene.simulation.dt, {}
    bodies = {b.name: b for b in scene.bodies}
    for k, m, s in zip(model.fem_ids, model.fem, state.fem):
        b = bodies.get(model.names[k])
        w = math.hypot(*b.angular_velocity) if b is not None else 0.0    # (no overflow)
        # (past the limit by more than round-off: at it, the step that holds is the step given)
        if b is None or b.anchors or not w * dt > SPIN_PER_STEP * (1 + 1e-9) or not math.isfinite(w):
            continue
        steady = _about_largest_axis(m.node_mass, s.x, np.asarray(b.angular_velocity, float) / w)
        if steady and b.integrator != "backward_euler":
            continue
        how = ("a free deformable body's step with backward Euler holds up to about "
               f"{SPIN_PER_STEP} rad per step and diverges from about 1; give dt = "
               f"{SPIN_PER_STEP / w:.2g} s or less, or integrator = \"newmark\"") if steady else (
            "it spins about an axis other than its axis of largest inertia, so it wobbles or "
            f"tumbles, and a free deformable body's step then holds up to about {SPIN_PER_STEP} "
            "rad per step and diverges from about 1 under either integrator; give dt = "
            f"{SPIN_PER_STEP / w:.2g} s or less")
        said[b.name] = f"body '{b.name}' spins at {w:.4g} rad/s, {w * dt:.2g} rad per step of {dt:.3g} s: {how}"
    return said


def _about_largest_axis(mass, x, axis):
    """Whether the unit ``axis`` (3,) is an axis of largest inertia of node masses ``mass`` (n,)
    at ``x`` (n, 3) that spin about it steadily: the largest principal moment exceeds the middle
    one by 1% and the axis is within 8 degrees of its direction, or all three moments agree to 1%
    (a cube's, a sphere's)."""
    y = x - mass @ x / mass.sum()
    inertia = np.eye(3) * (mass @ np.einsum("ij,ij->i", y, y)) - np.einsum("i,ij,ik->jk", mass, y, y)
    moments, axes = np.linalg.eigh(inertia)
    if moments[0] >= 0.99 * moments[2]:
        return True
    return moments[2] > 1.01 * moments[1] and abs(axes[:, 2] @ axis) > 0.99


# a slender body of linear tets whose cells along it are longer than this share of its thickness
# is said to lock in bending (a clamped beam at 1/8 of it sags 0.96 of beam theory)
BENDING_CELL_SHARE = 0.15


def bending_note(model, slender_ratio):
    """The run log's note (a string) for a deformable ``model`` of linear tets that is slender (its
    longest principal extent at least ``slender_ratio`` times its shortest) with cells along it
    longer than BENDING_CELL_SHARE of its thickness, else None: linear tets lock in bending, so
    where it bends it bends less than it should (a user's clamped beam 5 layers thick sagged 15%
    short, one of cells 8 times as long as thick 54% short, with nothing said)."""
    share = _cell_share(model, slender_ratio)
    if share is None or share <= BENDING_CELL_SHARE:
        return None
    return (f"its cells along it are {share:.2g} of its thickness long: linear tets lock in bending, "
            f"so where it bends it bends less than it should (a clamped beam's sag with cells 1/8, "
            f"1/4, 1/2 and 1 of its thickness long: 0.96, 0.85-0.91, 0.58-0.72 and 0.39-0.40 of beam "
            f"theory); order = 2, or shorter cells along it, if it bends")


def _cell_share(model, slender_ratio):
    """For a slender body of linear tets, the length of its cells along its longest extent over
    its thickness (median over the tets), else None."""
    if model.order != 1:
        return None
    x = model.rest_points
    # the body's own axes or its principal ones (a square bar's two small ones may come out
    # turned 45 degrees), whichever shows the thinner side
    frames = [np.eye(3), np.linalg.eigh(np.cov(x.T))[1]]
    spans = [np.ptp(x @ axes, axis=0) for axes in frames]
    best = int(np.argmin([s.min() for s in spans]))
    order = np.argsort(spans[best])
    along = (x @ frames[best])[:, order]
    thin, long = spans[best][order[0]], spans[best][order[-1]]
    if long < slender_ratio * thin:
        return None
    # each tet's extent along the body (a box cell's tets span the whole cell)
    return float(np.median(np.ptp(along[model.tets[:, :4], 2], axis=1)) / thin)
