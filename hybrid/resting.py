"""Resting contact held as a constraint.

A deformable body lying still on static ground (planes, fixed rigid bodies) touches it with the
same nodes step after step, each sticking: no gap closes and static friction stops any sliding,
so the contact asks one velocity of each such node. Holding these nodes in the body's own system
(fem.model.holding: the nodes prescribed as if anchored, factorised once for the set) solves the
whole patch within the step's one back-substitution. Left to the contact solver, the patch costs
a second back-substitution and sweeps over its dense Delassus matrix (a slab of 10k tets on the
ground: 441 nodes, about 11 sweeps over 200k blocks).

The held step checks its answer: the impulse each held node needed (its reaction) must push, not
pull, and lie within the friction cone. Then it is a solution of the contact problem, the one
the solver's sweeps converge to. Otherwise the step is taken again with the nodes free, and the
set must rest anew (and ``RETRY_AFTER`` steps pass) before it is held again.

A set is held once it has rested for ``ENTER_AFTER`` steps: the nodes that were in each of those
steps in exactly one contact, with a static surface, pushing (at least ``MIN_SHARE`` of the
median push) and inside ``STICK_MARGIN`` of their friction cone (nodes that flicker in and out
drop from the set; it is watched anew when it would lose half of the step's candidates). Floating-frame and anchored elastic bodies are
held; corotated and plastic ones always go through the solver.
"""
from dataclasses import dataclass, replace

import numpy as np

from fem.dynamics import implicitness

ENTER_AFTER = 10        # steps a set must rest unchanged before it is held
RETRY_AFTER = 50        # steps after a release before a set may be held again
STICK_MARGIN = 0.7      # a candidate's friction impulse is within this fraction of mu * normal
MIN_SHARE = 0.25        # a candidate pushes at least this fraction of the set's median push


@dataclass(frozen=True)
class Resting:
    """One deformable body's resting nodes: ``nodes`` (k,) sorted body nodes, each on a static
    surface with unit ``normal`` (k, 3) (world, out of the surface), resting on ``point`` (k, 3)
    m with ``friction`` (k,); ``steps`` it has rested unchanged; ``wait`` steps left before it may
    be held (after a release)."""
    nodes: np.ndarray
    normal: np.ndarray
    point: np.ndarray
    friction: np.ndarray
    steps: int = 1
    wait: int = 0

    @property
    def held(self):
        return self.steps > ENTER_AFTER and self.wait == 0 and len(self.nodes) > 0


def eligible(model):
    """Whether a body may be held: elastic, in the floating frame (or anchored)."""
    return model.frame == "floating" and not model.plastic


def held_velocity(model, state, rest, h):
    """End-of-step velocities ``(k, 3)`` m/s of the held nodes: over the step they close no gap
    (a node above its surface comes down to it, none sinks further) and do not slide. Under
    Newmark a node moves with the mean of its start and end velocities."""
    x = state.x[rest.nodes]
    gap = np.einsum("kd,kd->k", rest.normal, x - rest.point)
    mean = rest.normal * (-np.maximum(gap, 0.0) / h)[:, None]
    theta = implicitness(model)
    return (mean - (1.0 - theta) * state.v[rest.nodes]) / theta


def violations(rest, impulse):
    """``(k,)`` bool: held nodes whose impulse ``(k, 3)`` N s (world, on the node) pulls or lies
    outside the friction cone."""
    normal = np.einsum("kd,kd->k", impulse, rest.normal)
    tangent = np.linalg.norm(impulse - normal[:, None] * rest.normal, axis=1)
    size = np.abs(impulse).max(initial=0.0)
    tol = 1e-9 * size
    return (normal < -tol) | (tangent > rest.friction * normal * (1.0 + 1e-9) + tol)


def released(rest):
    """The record after its set let go: watched anew, held again no sooner than RETRY_AFTER steps."""
    return replace(rest, steps=0, wait=RETRY_AFTER)


def observe(last, nodes, others, normal, gap, x, friction, impulse, static, anchored):
    """The body's resting record after a step.

    ``nodes`` (c,) body nodes of its contacts with planes and rigid bodies, with their ``normal``
    (c, 3), ``gap`` (c,) m, ``friction`` (c,), ``impulse`` (c, 3) N s (world, on the node) and
    whether the other side is ``static`` (c,); ``others`` the body nodes in any other contact
    (with deformable bodies, rigid corners on its faces); ``x`` (n, 3) node positions at the
    step's start; ``anchored`` (n,) bool. ``last``: the record before the step (or None).
    """
    if last is not None and last.held:      # a held set stays until it lets go (the step's check)
        return last
    wait = max(last.wait - 1, 0) if last is not None else 0
    count = np.bincount(np.concatenate([nodes, others]).astype(np.int64), minlength=len(x))
    lam = np.einsum("cd,cd->c", impulse, normal)
    slide = np.linalg.norm(impulse - lam[:, None] * normal, axis=1)
    ok = static & (count[nodes] == 1) & ~anchored[nodes] & (friction > 0) & (lam > 0) \
        & (slide <= STICK_MARGIN * friction * lam)
    if ok.any():
        ok &= lam >= MIN_SHARE * np.median(lam[ok])
    order = np.argsort(nodes[ok], kind="stable")
    pick = np.nonzero(ok)[0][order]
    if len(pick) == 0:
        return Resting(nodes[pick], normal[pick], x[nodes[pick]], friction[pick], steps=0, wait=wait) \
            if last is not None else None
    chosen = nodes[pick]
    point = x[chosen] - gap[pick, None] * normal[pick]
    if last is not None and len(last.nodes):
        # the set narrows to the nodes that stay candidates (flickering ones drop out) and is
        # watched anew when it would lose more than half the candidates of the step
        keep = last.nodes[np.isin(last.nodes, chosen)]
        if len(keep) and 2 * len(keep) >= len(chosen):
            at = np.searchsorted(chosen, keep)
            return Resting(keep, normal[pick][at], point[at], friction[pick][at], steps=last.steps + 1,
                           wait=wait)
    return Resting(chosen, normal[pick], point, friction[pick], steps=1, wait=wait)
