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
the solver's sweeps converge to. Otherwise the step is taken again: without the nodes that
failed or came near failing when they are few (``DROP_SHARE`` of the set: the rim of a slab
spreading under a load), else with every node free, and the set must rest anew (and
``RETRY_AFTER`` steps pass, or ``ENTER_AFTER`` when the ground still pushed every node and some
slid: a slab spreading under a blow, which comes to rest within a few steps) before it is held
again.

A body that meets static ground with a patch of ``FIRST_SIGHT`` or more nodes new to its contact
response (a slab laid on the ground) holds them from that step (:func:`first_sight`): solving
their response columns for the solver would cost far more than the held system's factorisation.
Otherwise a set is held once it has rested for ``ENTER_AFTER`` steps: the nodes that were in each of those
steps in exactly one contact, with a static surface, pushing (at least ``MIN_SHARE`` of the
median push) and inside ``STICK_MARGIN`` of their friction cone (nodes that flicker in and out
drop from the set; it is watched anew when it would lose half of the step's candidates). The
margin is the integrator's: backward Euler's resting loads settle, so a node using 95% of its
cone stays inside it, while Newmark's keep oscillating about their mean. While a set is held,
the body's other resting nodes are watched the same way, and once they have rested
``ENTER_AFTER`` steps and number at least ``GROW_SHARE`` of the set they join it (one more
factorisation): a set first held while the body was still settling takes in the nodes that come
to rest later (the rim of a slab spreading under a load, 88-96% of the way to sliding). Every
deformable body may be held: floating or corotated, anchored or not, elastic or plastic (its
return map changes strains, not positions, after the step's check).
"""
from dataclasses import dataclass, replace

import numba as nb
import numpy as np

from fem.dynamics import implicitness

ENTER_AFTER = 10        # steps a set must rest unchanged before it is held
RETRY_AFTER = 50        # steps after a release before a set may be held again
# a candidate's friction impulse is within this fraction of mu * normal, per integrator
STICK_MARGIN = {"backward_euler": 0.95, "newmark": 0.7}
MIN_SHARE = 0.25        # a candidate pushes at least this fraction of the set's median push
GROW_SHARE = 0.05       # newly resting nodes join a held set once they are this share of it
# a body meeting static ground with at least this many nodes new to its contact response holds
# them at once (:func:`first_sight`): their response columns would cost three back-substitutions
# each, while holding them costs one factorisation, about as much as 150-300 batched columns
# (slabs of 1k to 50k tets), and the set would be held after ENTER_AFTER steps anyway
FIRST_SIGHT = 100
# a held set whose failing nodes are at most this share of it lets only them go (:func:`released`)
DROP_SHARE = 0.25


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


def held_velocity(model, state, rest, h):
    """End-of-step velocities ``(k, 3)`` m/s of the held nodes: over the step they close no gap
    (a node above its surface comes down to it, none sinks further) and do not slide. Under
    Newmark a node moves with the mean of its start and end velocities."""
    x = state.x[rest.nodes]
    gap = np.einsum("kd,kd->k", rest.normal, x - rest.point)
    mean = rest.normal * (-np.maximum(gap, 0.0) / h)[:, None]
    theta = implicitness(model)
    return (mean - (1.0 - theta) * state.v[rest.nodes]) / theta


def violations(rest, impulse, margin=1.0):
    """``(k,)`` bool: held nodes whose impulse ``(k, 3)`` N s (world, on the node) pulls or lies
    outside ``margin`` of the friction cone (1: the cone itself)."""
    normal, tangent = normal_and_slide(impulse, rest.normal)
    size = np.abs(impulse).max(initial=0.0)
    tol = 1e-9 * size
    return (normal < -tol) | (tangent > margin * rest.friction * normal * (1.0 + 1e-9) + tol)


def released(rest, failed=None, sliding=False):
    """The record after its set let go: watched anew, held again no sooner than RETRY_AFTER steps
    (ENTER_AFTER when ``sliding``: every node still pushed, some slid).
    When its ``failed`` nodes (sorted: those that would not push or stick, or came near it; None:
    the whole set) are at most DROP_SHARE of it, only they let go and the rest stays held (the
    corners and rim of a slab spreading under a load slide outwards while its middle rests)."""
    if failed is not None and len(failed) <= DROP_SHARE * len(rest.nodes):
        keep = ~sorted_isin(rest.nodes, failed)
        return replace(rest, nodes=rest.nodes[keep], normal=rest.normal[keep],
                       point=rest.point[keep], friction=rest.friction[keep], joining=None)
    return replace(rest, steps=0, wait=ENTER_AFTER if sliding else RETRY_AFTER, joining=None)


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


def first_sight(last, nodes, others, normal, gap, v, x, friction, static, anchored, new, h):
    """A record to hold at once (already :attr:`Resting.held`) when a body meets static ground
    with a large patch of nodes new to its contact response (FIRST_SIGHT or more), else None: a
    slab laid on the ground, a large face landing. Its candidates are the contacts of ``nodes``
    (c,) (body nodes, with ``normal``, ``gap``, ``friction`` and ``static`` as in :func:`observe`)
    that are in no other contact (``others``), not anchored (``anchored`` (n,)), have friction
    and close their gap within the step ``h`` at their mean velocity ``v`` (c, 3) m/s (the solver
    would push them); ``new`` (c,) says which nodes' response columns are not known yet; ``x``
    (n, 3) positions at the step's start. Not after a release (``last`` waiting) or while held.
    The held step checks the answer as any held step does (pushes, inside the friction cone),
    and the nodes that fail are let go as from any held set (:func:`released`)."""
    if last is not None and (last.held or last.wait > 0):
        return None
    count = np.bincount(np.concatenate([nodes, others]).astype(np.int64), minlength=len(x))
    approach = -np.einsum("cd,cd->c", v, normal)
    ok = static & (count[nodes] == 1) & ~anchored[nodes] & (friction > 0) & (gap <= h * approach)
    if np.count_nonzero(ok & new) < FIRST_SIGHT:
        return None
    record = _narrowed(None, nodes, ok, normal, gap, x, friction, 0)
    return replace(record, steps=ENTER_AFTER + 1)


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


@nb.njit(cache=True)
def normal_and_slide(impulse, normal):
    """Each impulse's part along its unit ``normal`` ``(c,)`` and the length of the rest ``(c,)``
    (impulse (c, 3), normal (c, 3)): ``einsum("cd,cd->c")`` and the row norms of
    ``impulse - lam normal``, in one pass."""
    c = len(impulse)
    lam = np.empty(c)
    slide = np.empty(c)
    for k in range(c):
        l = impulse[k, 0] * normal[k, 0] + impulse[k, 1] * normal[k, 1] + impulse[k, 2] * normal[k, 2]
        t0 = impulse[k, 0] - l * normal[k, 0]
        t1 = impulse[k, 1] - l * normal[k, 1]
        t2 = impulse[k, 2] - l * normal[k, 2]
        lam[k] = l
        slide[k] = np.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
    return lam, slide


@nb.njit(cache=True)
def median_of(values, mask):
    """``np.median(values[mask])`` of the selected ``values`` (at least one selected)."""
    return np.median(values[mask])


def sorted_isin(values, sorted_set):
    """``np.isin(values, sorted_set)`` for a sorted ``sorted_set`` (one binary search each)."""
    if len(sorted_set) == 0:
        return np.zeros(len(values), dtype=bool)
    at = np.minimum(np.searchsorted(sorted_set, values), len(sorted_set) - 1)
    return sorted_set[at] == values
