"""The contact problem of a coupled step: every contact of the step in one solver index space.

Solver bodies are the rigid bodies (0..nb-1), then the particles: the touched surface nodes,
grouped by FEM body, each group answering impulses through its body's exact Delassus block
(fem.contact_response), then the places on surface triangles, which move with and push their
triangle's nodes.
"""
import logging
from dataclasses import dataclass, replace

import numpy as np

from fem.contact_response import contact_set, delassus_block
from rigid import step as rigid_step
from rigid.contacts import Contacts, concatenate

from .memory import contact_keys, point_keys

# long computations inside a step (a large contact patch's first response columns) report here;
# a running Simulation forwards these messages to the run log
log = logging.getLogger("hybrid.step")

PLACE_HELD_SHARE = 0.01     # a place whose free corners carry less of its weight is held


@dataclass
class Problem:
    """The step's contact problem.

    parts: the particles and places (:class:`Particles`). touched_bodies: FEM bodies with
    particles, ascending. bodies: rigid_step.SolverBodies (rigid bodies, then particles, places).
    contacts: every contact, renumbered into solver bodies: rigid, node, pair, point contacts in
    that order. keys (contacts,): their identities across steps (-1: rigid-rigid, not remembered).
    node_rows: how many node contacts follow the rigid ones.
    contact_sets: per FEM body, its solver node set of its last step with contacts (this one's
    where it has contacts now), for the next step's state.
    """
    parts: object
    touched_bodies: np.ndarray
    bodies: object
    contacts: Contacts
    keys: np.ndarray
    node_rows: int
    contact_sets: tuple


def build_problem(model, state, fems, predicted, nodes, found, held_rows, rigid_bodies, h):
    """The contact problem (:class:`Problem`) of the contacts ``found`` less the held nodes' rows
    ``held_rows``; ``fems`` the FEM models as they step (held variants), ``predicted`` their steps
    without contact, ``nodes`` the stacked surface nodes, ``rigid_bodies`` the kicked rigid bodies."""
    nb = model.rigid.body_count
    # (a new Contacts either way: its body_a is renumbered below, found's stays)
    c_nodes = found.nodes.take(~held_rows) if held_rows.any() else replace(found.nodes)
    pairs, on_faces, corners = found.pairs, found.on_faces, found.corners
    in_contact = c_nodes.body_a if not (pairs.count or len(corners)) else \
        np.concatenate([c_nodes.body_a, pairs.a, corners.ravel()])
    touched, sets = _solver_nodes(fems, state, nodes, in_contact, h)
    parts = Particles(touched, corners, found.weights, nodes.body)
    touched_bodies = _distinct(parts.body)
    blocks = [delassus_block(fems[j], h, nodes.local[parts.nodes_of(j)], scale=predicted[j].x_rate / h,
                             report=_reporter(model.names[model.fem_ids[j]])) for j in touched_bodies]
    bodies = parts.solver_bodies(rigid_bodies, _stacked_rows(model.cache, blocks, nb),
                                 [state.fem[j].R for j in touched_bodies], nodes.x, nodes.v)
    keys = contact_keys(c_nodes.body_a, c_nodes.body_b, nodes.count, nb, False)
    if found.rigid.count or pairs.count or on_faces.count:
        keys = np.concatenate([np.full(found.rigid.count, -1, np.int64), keys,
                               contact_keys(pairs.a, pairs.nearest, nodes.count, nb, True),
                               point_keys(on_faces.sample, on_faces.nearest, nodes.count, nb)])
    # the rigid side of a node contact takes its impulse where the node takes the opposite one,
    # so friction passes no torque that is not returned (at the rigid surface's nearest point, a
    # gap away, a rigid fragment in contact with its pane drifted the angular momentum by 6%)
    c_nodes.point = nodes.x[c_nodes.body_a]
    c_nodes.body_a = nb + parts.node_particle[c_nodes.body_a]
    place = nb + len(touched) + np.arange(len(corners))
    c_pairs = Contacts(nb + parts.node_particle[pairs.a], place[:pairs.count], pairs.point, pairs.normal,
                       pairs.gap, pairs.friction, pairs.restitution)
    c_points = Contacts(on_faces.a, place[pairs.count:], on_faces.point, on_faces.normal, on_faces.gap,
                        on_faces.friction, on_faces.restitution)
    contacts = _concatenate_all([(found.rigid, 0, 0), (c_nodes, 0, 0), (c_pairs, 0, 0), (c_points, 0, 0)])
    return Problem(parts, touched_bodies, bodies, contacts, keys, c_nodes.count, sets)


def _solver_nodes(fems, state, nodes, in_contact, h):
    """The stacked surface nodes that join the solver: per body, the solver's node set for its
    nodes ``in_contact`` (fem.contact_response.contact_set, kept from the body's last step with
    contacts while contact rests); and every body's set for the next step."""
    sets = list(state.contact_sets) if state.contact_sets is not None else [None] * len(fems)
    # (node contacts come in node order: then their distinct nodes need no sort)
    ordered = len(in_contact) < 2 or bool((in_contact[1:] >= in_contact[:-1]).all())
    touched = _distinct(in_contact) if ordered else np.unique(in_contact)
    if not len(touched):
        return touched, tuple(sets)
    if len(fems) == 1:
        sets[0] = contact_set(fems[0], h, nodes.local[touched], sets[0])
        return nodes.stacked(0, sets[0]).astype(np.int64), tuple(sets)
    bodies = _distinct(nodes.body[touched])       # stacked nodes are grouped by body
    for j in bodies:
        sets[j] = contact_set(fems[j], h, nodes.local[touched[nodes.body[touched] == j]], sets[j])
    return np.concatenate([nodes.stacked(j, sets[j]) for j in bodies]).astype(np.int64), tuple(sets)


def _distinct(sorted_values):
    """The distinct values of a sorted array, in order (np.unique without its sort)."""
    if len(sorted_values) == 0:
        return sorted_values
    return sorted_values[np.concatenate([[True], sorted_values[1:] != sorted_values[:-1]])]


def _reporter(name):
    return lambda message: log.info("%s: %s", name, message)


@dataclass
class Particles:
    """The solver's particles and places. Particle i (i < k) is the stacked surface node
    ``nodes[i]`` (grouped by body, sorted within it); place u (after them) is the sum of the
    stacked nodes ``corners[u]`` (3,), all among ``nodes``, with ``weights[u]``. ``node_body``
    (stacked nodes,) is each stacked surface node's body."""
    nodes: np.ndarray
    corners: np.ndarray
    weights: np.ndarray
    node_body: np.ndarray

    def __post_init__(self):
        self.body = self.node_body[self.nodes]
        self.node_particle = -np.ones(len(self.node_body), dtype=np.int64)
        self.node_particle[self.nodes] = np.arange(len(self.nodes))

    @property
    def count(self):
        """Number of particles and places together."""
        return len(self.nodes) + len(self.corners)

    def nodes_of(self, j):
        """Stacked surface nodes (sorted) that are body j's particles."""
        return self.nodes[self.body == j]

    def solver_bodies(self, rigid, rows, rotations, node_x, node_v):
        """The rigid solver bodies followed by the particles (block rows ``rows``, see
        :func:`stack_rows`, of the touched bodies in body order, whose frames turn by
        ``rotations``) and the places (no rows; they move with and push their corners)."""
        nb, k, q = len(rigid.inv_mass), len(self.nodes), len(self.corners)
        w_ptr, w_col, W, held = rows
        corner = -np.ones((nb + k + q, 3), dtype=np.int64)
        corner[nb + k:] = nb + self.node_particle[self.corners]
        # each particle's group, the touched bodies numbered in order (particles are grouped by body)
        group = np.concatenate([[0], np.cumsum(self.body[1:] != self.body[:-1])]).astype(np.int64) \
            if len(self.body) else np.zeros(0, np.int64)
        weights, place_held = self._held_places(held)
        moving = self.mean(node_v)
        return rigid_step.SolverBodies(
            inv_mass=np.concatenate([rigid.inv_mass, np.zeros(k + q)]),
            inv_inertia=np.concatenate([rigid.inv_inertia, np.zeros((k + q, 3, 3))]),
            position=np.concatenate([rigid.position, self.mean(node_x)]),
            velocity=np.concatenate([rigid.velocity, moving]),
            velocity_at_t=np.concatenate([rigid.velocity_at_t, moving]),
            angular=np.concatenate([rigid.angular, np.zeros((k + q, 3))]),
            accel=np.concatenate([rigid.accel, np.zeros((k + q, 3))]),
            static=np.concatenate([rigid.static, held, place_held]),
            group_of=np.concatenate([np.full(nb, -1, np.int64), group, group[self.node_particle[self.corners[:, 0]]]]),
            group_R=np.array(rotations) if rotations else np.eye(3)[None],
            w_ptr=np.concatenate([w_ptr, np.full(q, w_ptr[-1])]), w_col=w_col, W=W, corner=corner,
            corner_w=np.concatenate([np.zeros((nb + k, 3)), weights]))

    def _held_places(self, held):
        """The places' corner weights and which places are held, given which particles are held.
        A place that moves with held corners for all but PLACE_HELD_SHARE of its weight is held, on
        those corners alone: an anchored node meeting a place that lay on another anchored node
        (crack faces at a grip) met a response of round-off size from the place's free corners."""
        if not len(self.corners):
            return self.weights.copy(), np.zeros(0, dtype=bool)
        corner_held = held[self.node_particle[self.corners]]
        weights = self.weights.copy()
        place_held = np.where(corner_held, 0.0, weights).sum(axis=1) < PLACE_HELD_SHARE
        on_held = np.where(corner_held, weights, 0.0)[place_held]
        weights[place_held] = on_held / on_held.sum(axis=1, keepdims=True)
        return weights, place_held

    def mean(self, node_values):
        """Each particle's and place's value ``(count, 3)`` from stacked node values ``(nodes, 3)``."""
        if not len(self.corners):
            return node_values[self.nodes]
        return np.concatenate([node_values[self.nodes],
                               np.einsum("pi,pij->pj", self.weights, node_values[self.corners])])

    def spread(self, impulse, node_count):
        """Particle and place impulses ``(count, 3)`` as impulses on the stacked surface nodes
        ``(node_count, 3)`` (a place's shared among its corners by their weights)."""
        out = np.zeros((node_count, 3))
        k = len(self.nodes)
        out[self.nodes] = impulse[:k]
        np.add.at(out, self.corners.ravel(), (self.weights[:, :, None] * impulse[k:, None, :]).reshape(-1, 3))
        return out


def _stacked_rows(cache, blocks, nb):
    """The groups' block rows (fem.contact_response.sparse_rows, one per touched body, particles
    numbered from ``nb`` on in group order) as the solver's (w_ptr (n + 1,), w_col, W), with empty
    rows for the nb rigid bodies; and which particles are held (anchored nodes answer nothing).
    Unchanged blocks (the same objects, reused by fem.contact_response) give the answer memoised
    in ``cache`` (the model's CouplingCache)."""
    last = cache.stacked_rows
    if last is not None and last[1] == nb and len(last[0]) == len(blocks) \
            and all(a is b for a, b in zip(last[0], blocks)):
        return last[2]
    answer = stack_rows(blocks, nb)
    cache.stacked_rows = (list(blocks), nb, answer)
    return answer


def stack_rows(blocks, nb):
    """The block rows of ``blocks`` stacked after ``nb`` rigid bodies (see :func:`_stacked_rows`)."""
    if not blocks:
        return np.zeros(nb + 1, np.int64), np.zeros(1, np.int64), np.zeros((1, 3, 3)), np.zeros(0, bool)
    first = nb + np.cumsum([0] + [len(ptr) - 1 for ptr, _, _ in blocks])      # each group's first particle
    start = np.cumsum([0] + [len(col) for _, col, _ in blocks])               # its first block
    w_ptr = np.concatenate([np.zeros(nb, np.int64)] + [ptr[:-1] + o for (ptr, _, _), o in zip(blocks, start)]
                           + [start[-1:]]).astype(np.int64)
    w_col = np.concatenate([col + f for (_, col, _), f in zip(blocks, first)]).astype(np.int64)
    W = np.concatenate([w for _, _, w in blocks])
    diagonal = W[w_ptr[nb:-1]]                                                 # first in each row
    return w_ptr, w_col, W, ~diagonal.reshape(len(diagonal), -1).any(axis=1)


def _concatenate_all(parts):
    """Contacts of every ``(contacts, offset_a, offset_b)`` of ``parts`` in order, each shifted as
    by rigid.contacts.concatenate (the first part taken as it is, unshifted); parts without contacts
    are skipped, and a single one with contacts is returned itself (not copied) when it needs no
    shift."""
    first = parts[0][0]
    rest = [(c, oa, ob) for c, oa, ob in parts[1:] if c.count]
    if not rest:
        return first
    if not first.count and len(rest) == 1 and rest[0][1] == 0 and rest[0][2] == 0 \
            and not (rest[0][0].body_b < -1).any():
        return rest[0][0]
    out = first
    for c, oa, ob in rest:
        out = concatenate(out, c, oa, ob)
    return out
