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
drop from the set; it is watched anew when it would lose half of the step's candidates). The
margin is the integrator's: backward Euler's resting loads settle, so a node using 95% of its
cone stays inside it, while Newmark's keep oscillating about their mean. While a set is held,
the body's other resting nodes are watched the same way, and once they have rested
``ENTER_AFTER`` steps and number at least ``GROW_SHARE`` of the set they join it (one more
factorisation): a set first held while the body was still settling takes in the nodes that come
to rest later (the rim of a slab spreading under a load, 88-96% of the way to sliding). Floating-
frame and anchored elastic bodies are held; corotated and plastic ones always go through the
solver.
"""
from dataclasses import dataclass, replace

import numpy as np

from fem.dynamics import implicitness

from .kernels import median_of, normal_and_slide, sorted_isin

ENTER_AFTER = 10        # steps a set must rest unchanged before it is held
RETRY_AFTER = 50        # steps after a release before a set may be held again
# a candidate's friction impulse is within this fraction of mu * normal, per integrator
STICK_MARGIN = {"backward_euler": 0.95, "newmark": 0.7}
MIN_SHARE = 0.25        # a candidate pushes at least this fraction of the set's median push
GROW_SHARE = 0.05       # newly resting nodes join a held set once they are this share of it


@dataclass(frozen=True)
class Resting:
    """One deformable body's resting nodes: ``nodes`` (k,) sorted body nodes, each on a static
    surface with unit ``normal`` (k, 3) (world, out of the surface), resting on ``point`` (k, 3)
    m with ``friction`` (k,); ``steps`` it has rested unchanged; ``wait`` steps left before it may
    be held (after a release); while held, ``joining``: the body's other resting nodes, watched
    the same way (a Resting, or None)."""
    nodes: np.ndarray
    normal: np.ndarray
    point: np.ndarray
    friction: np.ndarray
    steps: int = 1
    wait: int = 0
    joining: "Resting" = None

    @property
    def held(self):
        """Whether the set is held: it has rested unchanged over ``ENTER_AFTER`` steps, no wait
        after a release remains, and it is not empty."""
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
    normal, tangent = normal_and_slide(impulse, rest.normal)
    size = np.abs(impulse).max(initial=0.0)
    tol = 1e-9 * size
    return (normal < -tol) | (tangent > rest.friction * normal * (1.0 + 1e-9) + tol)


def released(rest):
    """The record after its set let go: watched anew, held again no sooner than RETRY_AFTER steps."""
    return replace(rest, steps=0, wait=RETRY_AFTER, joining=None)


def stick_margin(model):
    """The share of its friction cone a node may use to join a held set (:data:`STICK_MARGIN`)."""
    return STICK_MARGIN[model.integrator]


def observe(last, nodes, others, normal, gap, x, friction, impulse, static, anchored, margin):
    """The body's resting record after a step.

    ``nodes`` (c,) body nodes of its contacts with planes and rigid bodies, with their ``normal``
    (c, 3), ``gap`` (c,) m, ``friction`` (c,), ``impulse`` (c, 3) N s (world, on the node) and
    whether the other side is ``static`` (c,); ``others`` the body nodes in any other contact
    (with deformable bodies, rigid corners on its faces); ``x`` (n, 3) node positions at the
    step's start; ``anchored`` (n,) bool; ``margin`` the body's :func:`stick_margin`. ``last``:
    the record before the step (or None). A held set stays until it lets go (the step's check),
    or grows by the nodes that have come to rest beside it.
    """
    count = np.bincount(np.concatenate([nodes, others]).astype(np.int64), minlength=len(x))
    lam, slide = normal_and_slide(impulse, normal)
    ok = static & (count[nodes] == 1) & ~anchored[nodes] & (friction > 0) & (lam > 0) \
        & (slide <= margin * friction * lam)
    if ok.any():
        ok &= lam >= MIN_SHARE * median_of(lam, ok)
    if last is not None and last.held:
        joining = _narrowed(last.joining, nodes, ok & ~sorted_isin(nodes, last.nodes), normal, gap, x,
                            friction, 0)
        if joining is not None and joining.held and len(joining.nodes) >= GROW_SHARE * len(last.nodes):
            return _joined(last, joining)
        return replace(last, joining=joining)
    wait = max(last.wait - 1, 0) if last is not None else 0
    return _narrowed(last, nodes, ok, normal, gap, x, friction, wait)


def _joined(rest, more):
    """The held set ``rest`` with the resting nodes ``more`` added (still held)."""
    nodes = np.concatenate([rest.nodes, more.nodes])
    order = np.argsort(nodes, kind="stable")
    return replace(rest, nodes=nodes[order], joining=None, **{
        name: np.concatenate([getattr(rest, name), getattr(more, name)])[order]
        for name in ("normal", "point", "friction")})


def _narrowed(last, nodes, ok, normal, gap, x, friction, wait):
    """The record of the candidates ``ok`` (c,) among the contacts of ``nodes`` after a step, from
    the record ``last`` of the same watch before it (or None)."""
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
        keep = last.nodes[sorted_isin(last.nodes, chosen)]
        if len(keep) and 2 * len(keep) >= len(chosen):
            at = np.searchsorted(chosen, keep)
            return Resting(keep, normal[pick][at], point[at], friction[pick][at], steps=last.steps + 1,
                           wait=wait)
    return Resting(chosen, normal[pick], point, friction[pick], steps=1, wait=wait)
