"""The contact impulses rigid auto bodies take in a step (:class:`Touches`) and how a step changed
them (:func:`impulse_change`), which hybrid.coupling.auto.fem_due turns into a predicted strain;
:func:`switch_groups`, the auto bodies in contact with one that has just switched."""
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components


@dataclass(frozen=True)
class Touches:
    """The contact impulses rigid auto bodies took over one step, one row per contact side:
    body (c,) the auto body's scene index, partner (c,) the other side's (-1: a plane or static
    ground), point (c, 3) m world, impulse (c, 3) N s on the auto body (world), normal (c, 3)
    unit, from the partner towards the auto body."""
    body: np.ndarray
    partner: np.ndarray
    point: np.ndarray
    impulse: np.ndarray
    normal: np.ndarray

    @classmethod
    def between(cls, auto, a, b, point, impulse, normal):
        """The rows of contacts between scene bodies ``a`` and ``b`` (c,) (-1: a plane or static
        ground) at ``point`` (c, 3) with ``impulse`` (c, 3) on side a and ``normal`` (c, 3) from b
        towards a, that touch a body of ``auto`` (scene indices), from that body's side."""
        if not len(a):
            return EMPTY
        is_auto = np.zeros(max(int(auto.max(initial=-1)), int(a.max(initial=-1)),
                               int(b.max(initial=-1))) + 2, dtype=bool)
        is_auto[auto] = True                        # is_auto[-1] (planes, ground) stays False
        on_a, on_b = is_auto[a], is_auto[b]
        return cls(np.concatenate([a[on_a], b[on_b]]), np.concatenate([b[on_a], a[on_b]]),
                   np.concatenate([point[on_a], point[on_b]]),
                   np.concatenate([impulse[on_a], -impulse[on_b]]),
                   np.concatenate([normal[on_a], -normal[on_b]]))

    @classmethod
    def of(cls, auto, contacts, impulse, scene_of):
        """:meth:`between` for ``contacts`` whose bodies are numbered as ``scene_of`` (s,) gives
        their scene indices (-1 stays -1)."""
        a = np.where(contacts.body_a >= 0, scene_of[np.maximum(contacts.body_a, 0)], -1)
        b = np.where(contacts.body_b >= 0, scene_of[np.maximum(contacts.body_b, 0)], -1)
        return cls.between(auto, a, b, contacts.point, impulse, contacts.normal)

    def plus(self, other):
        """These rows followed by ``other``'s."""
        if not len(other.body):
            return self
        if not len(self.body):
            return other
        return Touches(*(np.concatenate([getattr(self, f), getattr(other, f)])
                         for f in ("body", "partner", "point", "impulse", "normal")))

    def of_body(self, k):
        """``(partner, point, impulse)`` rows of body ``k``."""
        rows = self.body == k
        return self.partner[rows], self.point[rows], self.impulse[rows]


EMPTY = Touches(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)),
                np.zeros((0, 3)))


def impulse_change(before, after, k, group=None):
    """``(points (r, 3), changes (g, 3), group (r,), partners (g,))``: how the load the contacts
    put on body ``k`` changed from the touches ``before`` to ``after``: for each partner
    ``partners[g]`` (scene index, -1: a plane or static ground), the change of its total impulse
    ``changes[g]``, and the partner's contact points now (those it had, for a partner that let
    go) with their partner's index ``g``. Only totals are compared: how a rigid
    body's contact points share a load is not determined (the sweeps end in one sharing or
    another, differently from step to step and from the FEM body's), and a settled box turned
    rigid, its load the same and shared differently, would otherwise turn back at its first
    rigid step. With ``group`` (scene indices: ``k`` alone, or the auto bodies in contact with
    ``k`` and each other, one of which has just switched, :func:`switch_groups`), the change of
    the load from outside the group, one change at all of ``k``'s points (partners empty): a
    switch re-shares a resting load among the supports, which rigid bodies share as the solver's
    sweeps end (a box lying across two others, or leaning on a neighbour's side), without a
    change of the load the group carries; a blow from outside changes it. None when nothing
    touches ``k`` in either."""
    partner, point, impulse = after.of_body(k)
    old_partner, old_point, old_impulse = (before.of_body(k) if before is not None
                                           else (np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3))))
    if not len(partner) and not len(old_partner):
        return None
    if group is not None:
        members = np.fromiter(group, np.int64)
        change = after.impulse[np.isin(after.body, members)].sum(axis=0)
        if before is not None:
            change = change - before.impulse[np.isin(before.body, members)].sum(axis=0)
        at = point if len(point) else old_point
        return at, change[None], np.zeros(len(at), np.int64), np.zeros(0, np.int64)
    points, changes, group = [], [], []
    partners = np.union1d(partner, old_partner)
    for g, p in enumerate(partners):
        rows, old_rows = partner == p, old_partner == p
        at = point[rows] if rows.any() else old_point[old_rows]
        points.append(at)
        changes.append(impulse[rows].sum(axis=0) - old_impulse[old_rows].sum(axis=0))
        group.append(np.full(len(at), g))
    return np.concatenate(points), np.array(changes), np.concatenate(group), partners


def switch_groups(before, after, switched):
    """Per auto body in contact (in the touches ``before`` or ``after``), directly or through
    other auto bodies, with one of the bodies ``switched`` (scene indices) the set of them all
    (frozenset of scene indices, the switched body's among them)."""
    if not switched:
        return {}
    touches = [t for t in (before, after) if t is not None]
    if not touches:
        return {}
    body = np.concatenate([t.body for t in touches])
    partner = np.concatenate([t.partner for t in touches])
    auto = np.union1d(body, switched)                      # sorted: an index by searchsorted
    inner = np.isin(partner, auto)
    rows, cols = np.searchsorted(auto, body[inner]), np.searchsorted(auto, partner[inner])
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(auto), len(auto)))
    _, label = connected_components(graph, directed=False)
    out = {}
    for k in switched:
        members = frozenset(auto[label == label[np.searchsorted(auto, k)]].tolist())
        out.update({b: members for b in members})
    return out


def held_touches(model, auto, nodes, contacts, impulse):
    """:class:`Touches` of held resting nodes' contacts (found's numbering: stacked surface nodes
    ``nodes`` on side a, rigid bodies or -1 on side b) with ``impulse`` (c, 3) on the nodes."""
    fem_ids = np.asarray(model.fem_ids, dtype=np.int64)
    a = fem_ids[nodes.body[contacts.body_a]]
    rigid = np.asarray(model.rigid_ids, dtype=np.int64)
    b = np.where(contacts.body_b >= 0, rigid[np.maximum(contacts.body_b, 0)] if len(rigid) else -1, -1)
    return Touches.between(auto, a, b, contacts.point, impulse, contacts.normal)
