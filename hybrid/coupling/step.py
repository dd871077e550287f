"""The coupled step: rigid bodies and FEM bodies advanced together with two-way contact.

    step(model, state) -> state

FEM surface nodes in contact enter the contact solver as particles that answer impulses through
their body's exact implicit response (fem.contact_response), so rigid bodies, planes and
deformable bodies exchange momentum through one impulse mechanism (rigid.step.resolve_contacts).
The impulses a body's nodes receive are then fed through that body's own implicit system (one
more back-substitution, or a product with the cached response columns when that is cheaper),
which gives the velocities the solver expected. Node contacts keep their impulses from one step to
the next (ContactMemory) to warm-start the solver: resting contact then converges in few sweeps.
"""
import logging
from dataclasses import dataclass, replace

import numpy as np

from fem import dynamics as fem_dyn
from fem.contact_response import apply_contact_impulses, contact_set, delassus_block
from fem.model import holding
from rigid import quaternion as quat
from rigid import step as rigid_step
from rigid.contacts import Contacts, concatenate, detect, detect_points

from . import resting
from .model import HybridState
from .fem_contact import detect_fem_pairs, detect_rigid_points, edge_normals


class InstabilityError(RuntimeError):
    """A body's state stopped being finite or physically plausible."""

    def __init__(self, body, time, quantity, value):
        self.body, self.time, self.quantity, self.value = body, time, quantity, value
        super().__init__(f"unstable: body '{body}' at t = {time:.6g} s: {quantity} = {value:.3g}")


# long computations inside a step (a large contact patch's first response columns) report here;
# hybrid.app.run forwards these messages to the run log
log = logging.getLogger("hybrid.coupling.step")


def _reporter(name):
    return lambda message: log.info("%s: %s", name, message)


# coupling rounds of a step with corotated bodies in contact: at most MAX_ROUNDS, done when no
# touched node's velocity differs from the solver's by more than COUPLING_TOL of the step's
# velocity scale (gravity's gain over the step plus the fastest touched node). Two rounds let a
# box resting on the tip of a corotated cantilever bent by 10 degrees sink into it at 0.3 mm/s
MAX_ROUNDS = 10
COUPLING_TOL = 1e-4

# above these the run is declared unstable (no scene of everyday objects gets near them)
MAX_SPEED = 1.0e4       # m/s
MAX_DISTANCE = 1.0e6    # m


def step(model, state):
    """Advance every body by one scene time step ``model.dt``."""
    if not model.fem:
        rigid, _ = rigid_step.step(model.rigid, state.rigid, model.dt, model.gravity, model.settings)
        new = HybridState(rigid=rigid, fem=[], time=state.time + model.dt, steps=state.steps + 1)
    else:
        while True:
            try:
                new = _coupled_step(model, state)
                break
            except _LetGo as go:    # a held body's resting nodes let go: the step again, them free
                records = list(_records(model, state))
                records[go.body] = resting.released(records[go.body])
                state = replace(state, resting=tuple(records))
    check_finite(model, new)
    return new


class _LetGo(Exception):
    """The resting nodes held in deformable body ``body`` (an index into model.fem) let go."""

    def __init__(self, body):
        super().__init__(body)
        self.body = body


def _records(model, state):
    return state.resting if state.resting is not None else (None,) * len(model.fem)


def _coupled_step(model, state):
    h, g = model.dt, model.gravity
    rm, rs = model.rigid, state.rigid
    nb = rm.body_count

    # 1. deformable bodies: implicit step without contact (prefactored system); a body resting on
    #    static ground steps with its resting nodes held (hybrid.coupling.resting)
    records = _records(model, state)
    hold = [r if model.settings.hold_resting and r is not None and r.held and resting.eligible(m)
            else None for m, r in zip(model.fem, records)]
    fems = [m if r is None else holding(m, r.nodes) for m, r in zip(model.fem, hold)]
    predicted = [fem_dyn.predict(m, s, h, g, None if r is None else resting.held_velocity(m, s, r, h))
                 for m, s, r in zip(fems, state.fem, hold)]

    # 2. rigid bodies: leapfrog kick
    v, v_at_t, gvec = rigid_step.kick(rm, rs, h, g)
    rigid_bodies = rigid_step.solver_bodies(rm, rs, v, v_at_t, gvec)

    # 3. contacts: rigid bodies among themselves and with planes; surface nodes with planes, rigid
    #    shapes and other deformable bodies (stacked surface node k belongs to body node_body[k])
    nodes = [m.surface_nodes for m in model.fem]
    node_body = np.concatenate([np.full(len(n), j) for j, n in enumerate(nodes)])
    node_local = np.concatenate(nodes)
    node_offset = np.concatenate([[0], np.cumsum([len(n) for n in nodes])]).astype(np.int64)
    node_x = np.concatenate([s.x[n] for s, n in zip(state.fem, nodes)])
    # how fast each node moves over the step: it ends at x_base + x_rate v (backward Euler: at
    # x + h v; Newmark: at x + h (v_t + v) / 2). Contacts ask that no gap closes by the step's end,
    # so the solver works with these velocities and a response scaled by x_rate / h
    node_v = np.concatenate([_moving(p, s, n, h) for p, s, n in zip(predicted, state.fem, nodes)])
    R = quat.to_matrix(rs.orientation)
    rigid_sweep = rigid_step.reach(rm, rigid_bodies, h)
    c_rigid = detect(rm, rs.position, R, rigid_sweep, model.settings.margin)
    fem_bodies = _fem_bodies(model)
    mu = np.array([b.friction for b in fem_bodies])[node_body]
    e = np.array([b.restitution for b in fem_bodies])[node_body]
    sweep = np.linalg.norm(node_v, axis=1) * h
    c_nodes = detect_points(rm, rs.position, R, node_x, sweep, rigid_sweep, model.settings.margin, mu, e)
    c_nodes.normal, c_nodes.gap, front = edge_normals(model.fem, state.fem, node_offset, node_body, c_nodes)
    c_nodes = c_nodes.take(front)
    # surface nodes against other deformable bodies' faces; rigid corners and edges against them
    # (the rigid body is side a); side b is a place in a surface triangle
    pairs = detect_fem_pairs(model.fem, state.fem, fem_bodies, node_offset, node_x, sweep,
                             model.settings.margin)
    on_faces = detect_rigid_points(rm, rs.position, R, rigid_sweep, model.fem, state.fem, fem_bodies,
                                   node_offset, sweep, model.settings.margin)
    corners = np.concatenate([pairs.corners, on_faces.corners])
    weights = np.concatenate([pairs.weights, on_faces.weights])
    # held nodes leave the solver: their contacts with static ground are the hold's
    in_others = np.concatenate([pairs.a, corners[weights > 0]])
    static_b = _static_side(rm, c_nodes.body_b)
    held_rows = _held_rows(hold, nodes, node_offset, node_body, c_nodes, static_b, in_others)
    c_all, static_all = c_nodes, static_b
    c_nodes = c_nodes.take(~held_rows)

    # 4. touched nodes join the solver as particles grouped by body, each group answering
    #    impulses through its body's exact Delassus block (fem.contact_response); the places on
    #    surface triangles join as points that move with, and push, their triangle's nodes
    touched = np.unique(np.concatenate([c_nodes.body_a, pairs.a, corners.ravel()]))
    # per body, the solver's node set (kept across steps while contact rests, see contact_set)
    touched = np.concatenate([node_offset[j] + np.searchsorted(
        nodes[j], contact_set(fems[j], h, node_local[touched[node_body[touched] == j]]))
        for j in np.unique(node_body[touched])]).astype(np.int64) if len(touched) else touched
    parts = _Particles(touched, corners, weights, node_body)
    bodies_touched = np.unique(parts.body)
    blocks = [delassus_block(fems[j], h, node_local[parts.nodes_of(j)], scale=predicted[j].x_rate / h,
                             report=_reporter(model.names[model.fem_ids[j]])) for j in bodies_touched]
    bodies = parts.solver_bodies(rigid_bodies, blocks, [state.fem[j].R for j in bodies_touched],
                                 node_x, node_v)
    keys = np.concatenate([np.full(c_rigid.count, -1, np.int64),
                           contact_keys(c_nodes.body_a, c_nodes.body_b, len(node_x), nb, False),
                           contact_keys(pairs.a, pairs.nearest, len(node_x), nb, True),
                           point_keys(on_faces.sample, on_faces.nearest, len(node_x), nb)])
    c_nodes.body_a = nb + parts.node_particle[c_nodes.body_a]
    place = nb + len(touched) + np.arange(len(corners))
    c_pairs = Contacts(nb + parts.node_particle[pairs.a], place[:pairs.count], pairs.point, pairs.normal,
                       pairs.gap, pairs.friction, pairs.restitution)
    c_points = Contacts(on_faces.a, place[pairs.count:], on_faces.point, on_faces.normal, on_faces.gap,
                        on_faces.friction, on_faces.restitution)
    contacts = concatenate(concatenate(concatenate(c_rigid, c_nodes, 0, 0), c_pairs, 0, 0), c_points, 0, 0)

    # 5. one contact resolution for everything; each deformable body then takes the impulses on
    #    its nodes (a place's shared among its triangle's nodes by its weights) through its own
    #    implicit system (apply_contact_impulses). The blocks are exact for floating and anchored
    #    bodies; corotated ones answer through their rest system, so their contacts are solved
    #    again from the velocities the nodes really took until those are the ones the solver
    #    expected (to COUPLING_TOL), in at most MAX_ROUNDS rounds
    rounds = MAX_ROUNDS if any(model.fem[j].frame == "corotated" for j in bodies_touched) else 1
    warm = state.contact_memory.recall(keys) if state.contact_memory is not None else None
    res, applied = None, np.zeros((contacts.count, 3))
    for _ in range(rounds):
        if res is not None:     # solve again from the velocities the bodies really took
            for j in bodies_touched:
                at = parts.nodes_of(j)
                node_v[at] = _moving(predicted[j], state.fem[j], node_local[at], h)
            expected = res.velocity[nb:nb + len(touched)]
            miss = np.abs(node_v[touched] - expected).max(initial=0.0)
            if miss <= COUPLING_TOL * (h * np.linalg.norm(g) + np.abs(expected).max(initial=0.0)):
                break
            bodies.velocity = np.concatenate([res.velocity[:nb], parts.mean(node_v)])
            bodies.velocity_at_t = bodies.velocity
            bodies.angular = res.angular
        res = rigid_step.resolve_contacts(bodies, contacts, h, g, model.settings, previous=res, warm=warm)
        total = res.collision_impulse + res.contact_impulse
        increment, applied = total - applied, total
        on_a, on_b = contacts.body_a >= nb, contacts.body_b >= nb
        if not (on_a.any() or on_b.any()):
            break
        impulse = np.zeros((parts.count, 3))
        np.add.at(impulse, contacts.body_a[on_a] - nb, increment[on_a])
        np.add.at(impulse, contacts.body_b[on_b] - nb, -increment[on_b])
        node_impulse = parts.spread(impulse, len(node_x))
        for j in bodies_touched:
            at = parts.nodes_of(j)
            predicted[j] = apply_contact_impulses(fems[j], state.fem[j], predicted[j], h,
                                                  node_local[at], node_impulse[at])

    # 6. rigid drift; deformable bodies finish their step; touched nodes take their share of
    #    penetration recovery (positions only; a place's share reached its nodes in the solver)
    rigid_res = rigid_step.Resolution(*(a[:nb] for a in (
        res.velocity, res.angular, res.shift, res.shift_rotation, res.pseudo_velocity,
        res.pseudo_angular, res.impact_dv, res.momentum_fix)))
    new_rigid = rigid_step.drift(rm, rs, rigid_res, h, v)
    new_fem = []
    pseudo = res.pseudo_velocity[nb:nb + len(touched)]
    for j, (m, s, pr) in enumerate(zip(fems, state.fem, predicted)):
        s_new = fem_dyn.finish(m, s, pr, h)
        sel = parts.body == j
        if sel.any() and np.any(pseudo[sel]):
            x = s_new.x.copy()
            x[node_local[parts.nodes[sel]]] += h * pseudo[sel]
            R_fit, c_fit = fem_dyn.body_frame(m, x)
            s_new = s_new.replace(x=x, R=R_fit, c=c_fit)
        new_fem.append(s_new)

    # 7. held nodes: the impulses they took must push and stick, else the step is taken again
    row_impulse = np.zeros((c_all.count, 3))
    row_impulse[~held_rows] = res.contact_impulse[c_rigid.count:c_rigid.count + c_nodes.count]
    for j, r in enumerate(hold):
        if r is None:
            continue
        impulse = h * new_fem[j].node_reaction[r.nodes]
        if resting.violations(r, impulse).any():
            raise _LetGo(j)
        rows = np.nonzero(held_rows & (node_body[c_all.body_a] == j))[0]
        at = np.searchsorted(r.nodes, node_local[c_all.body_a[rows]])
        share = np.bincount(at, minlength=len(r.nodes))[at]
        row_impulse[rows] = impulse[at] / share[:, None]
        reaction = new_fem[j].node_reaction.copy()
        reaction[r.nodes] = 0.0           # the ground's push is a contact's, not an anchor's
        new_fem[j] = new_fem[j].replace(node_reaction=reaction)
    keys = np.concatenate([keys, contact_keys(c_all.body_a[held_rows], c_all.body_b[held_rows],
                                              len(node_x), nb, False)])
    memory = ContactMemory.of(keys, np.concatenate([res.contact_impulse, row_impulse[held_rows]]))
    records = _watch(model, state, records, c_all, static_all, row_impulse, in_others, node_body,
                     node_local)
    return HybridState(rigid=new_rigid, fem=new_fem, time=state.time + h, steps=state.steps + 1,
                       contact_memory=memory, resting=records)


def _watch(model, state, records, contacts, static_b, impulse, in_others, node_body, node_local):
    """Each deformable body's resting record after the step (hybrid.coupling.resting.observe) from its
    node contacts with planes and rigid bodies (stacked nodes on side a, their ``impulse``) and
    the stacked nodes ``in_others`` in any other contact; None where bodies are not held."""
    if not model.settings.hold_resting:
        return (None,) * len(model.fem)
    body = node_body[contacts.body_a]
    out = []
    for j, (m, s) in enumerate(zip(model.fem, state.fem)):
        on = body == j
        out.append(resting.observe(
            records[j], node_local[contacts.body_a[on]], node_local[in_others[node_body[in_others] == j]],
            contacts.normal[on], contacts.gap[on], s.x, contacts.friction[on], impulse[on], static_b[on],
            m.node_anchor >= 0, resting.stick_margin(m)) if resting.eligible(m) else None)
    return tuple(out)


def _static_side(rigid_model, body_b):
    """``(c,)`` bool: side b is static (a plane, or a fixed rigid body)."""
    if rigid_model.body_count == 0:
        return body_b < 0
    return (body_b < 0) | rigid_model.body_fixed[np.maximum(body_b, 0)]


def _held_rows(hold, nodes, node_offset, node_body, contacts, static_b, in_others):
    """Which node contacts (stacked nodes on side a) are held nodes' contacts with static ground,
    ``(c,)`` bool. A held node in any other contact lets go."""
    held = np.zeros(len(node_body), dtype=bool)
    for j, r in enumerate(hold):
        if r is not None:
            held[node_offset[j] + np.searchsorted(nodes[j], r.nodes)] = True
    rows = held[contacts.body_a]
    for at in (contacts.body_a[rows & ~static_b], in_others[held[in_others]]):
        if len(at):
            raise _LetGo(int(node_body[at[0]]))
    return rows


def _moving(step, state, nodes, h):
    """Mean velocity ``(k, 3)`` m/s of ``nodes`` over a deformable body's step in progress."""
    return (step.x_base[nodes] - state.x[nodes] + step.x_rate * step.v[nodes]) / h


@dataclass
class _Particles:
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
        return len(self.nodes) + len(self.corners)

    def nodes_of(self, j):
        """Stacked surface nodes (sorted) that are body j's particles."""
        return self.nodes[self.body == j]

    def solver_bodies(self, rigid, blocks, rotations, node_x, node_v):
        """The rigid solver bodies followed by the particles (block rows: ``blocks``, one per
        touched body in body order, whose frames turn by ``rotations``) and the places (no rows;
        they move with and push their corners)."""
        nb, k, q = len(rigid.inv_mass), len(self.nodes), len(self.corners)
        w_ptr, w_col, W, held = _stacked_rows(blocks, nb)
        corner = -np.ones((nb + k + q, 3), dtype=np.int64)
        corner[nb + k:] = nb + self.node_particle[self.corners]
        group = np.unique(self.body, return_inverse=True)[1].ravel()
        # a place that moves with held corners for all but a hundredth of its weight is held, on
        # those corners alone: an anchored node meeting a place that lay on another anchored node
        # (crack faces at a grip) met a response of round-off size from the place's free corners
        # and took an impulse of 1e9 N s (an anchor force of 1e13 N)
        corner_held = held[self.node_particle[self.corners]]
        weights = self.weights.copy()
        place_held = np.where(corner_held, 0.0, weights).sum(axis=1) < PLACE_HELD_SHARE
        on_held = np.where(corner_held, weights, 0.0)[place_held]
        weights[place_held] = on_held / on_held.sum(axis=1, keepdims=True)
        held = np.concatenate([held, place_held])
        return rigid_step.SolverBodies(
            inv_mass=np.concatenate([rigid.inv_mass, np.zeros(k + q)]),
            inv_inertia=np.concatenate([rigid.inv_inertia, np.zeros((k + q, 3, 3))]),
            position=np.concatenate([rigid.position, self.mean(node_x)]),
            velocity=np.concatenate([rigid.velocity, self.mean(node_v)]),
            velocity_at_t=np.concatenate([rigid.velocity_at_t, self.mean(node_v)]),
            angular=np.concatenate([rigid.angular, np.zeros((k + q, 3))]),
            accel=np.concatenate([rigid.accel, np.zeros((k + q, 3))]),
            static=np.concatenate([rigid.static, held]),
            group_of=np.concatenate([np.full(nb, -1, np.int64), group, group[self.node_particle[self.corners[:, 0]]]]),
            group_R=np.array(rotations) if blocks else np.eye(3)[None],
            w_ptr=np.concatenate([w_ptr, np.full(q, w_ptr[-1])]), w_col=w_col, W=W, corner=corner,
            corner_w=np.concatenate([np.zeros((nb + k, 3)), weights]))

    def mean(self, node_values):
        """Each particle's and place's value ``(count, 3)`` from stacked node values ``(nodes, 3)``."""
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


PLACE_HELD_SHARE = 0.01     # a place whose free corners carry less of its weight is held

_last_stack = [None, None]    # the last call's (blocks, nb) and answer: resting contact repeats it


def _stacked_rows(blocks, nb):
    """The groups' block rows (fem.contact_response.sparse_rows, one per touched body, particles
    numbered from ``nb`` on in group order) as the solver's (w_ptr (n + 1,), w_col, W), with empty
    rows for the nb rigid bodies; and which particles are held (anchored nodes answer nothing).
    Unchanged blocks (the same objects, reused by fem.contact_response) give the last answer."""
    key, answer = _last_stack
    if key is not None and key[1] == nb and len(key[0]) == len(blocks) \
            and all(a is b for a, b in zip(key[0], blocks)):
        return answer
    answer = _stack(blocks, nb)
    _last_stack[:] = [(list(blocks), nb), answer]
    return answer


def _stack(blocks, nb):
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


def contact_keys(a, b, node_count, rigid_count, node_pairs):
    """Identity of node contacts across steps (int64): stacked surface node ``a`` against stacked
    node ``b`` (``node_pairs``), or against rigid body ``b`` (-1: a plane). Ordered pairs of
    distinct (a, b) give distinct keys."""
    other = b if node_pairs else node_count + 1 + b
    return (np.asarray(a, np.int64) * (node_count + rigid_count + 1) + other).astype(np.int64)


def point_keys(point, node, node_count, rigid_count):
    """Identity across steps of rigid sample point ``point`` against stacked surface node ``node``
    (int64), above every key of :func:`contact_keys`."""
    base = (node_count + 1) * (node_count + rigid_count + 1) + 1
    return (base + np.asarray(point, np.int64) * (node_count + 1) + np.asarray(node, np.int64)).astype(np.int64)


@dataclass(frozen=True)
class ContactMemory:
    """Last step's contact-pass impulses of node contacts (world, on side a, N s) by contact key:
    resting contact persists, so they start the next contact pass close to its answer (warm
    start); only a starting guess, the solver raises or lowers them as the new step needs."""
    keys: np.ndarray
    impulse: np.ndarray

    @staticmethod
    def of(keys, impulse):
        keep = (keys >= 0) & np.isfinite(impulse).all(axis=1)
        order = np.argsort(keys[keep], kind="stable")
        return ContactMemory(keys[keep][order], impulse[keep][order])

    def recall(self, keys):
        """(c, 3) remembered impulses for ``keys`` (zero where a contact is new or not a node's)."""
        out = np.zeros((len(keys), 3))
        if len(self.keys) == 0:
            return out
        at = np.clip(np.searchsorted(self.keys, keys), 0, len(self.keys) - 1)
        hit = (self.keys[at] == keys) & (keys >= 0)
        out[hit] = self.impulse[at[hit]]
        return out


def _fem_bodies(model):
    return [model.scene.bodies[i] for i in model.fem_ids]


def check_finite(model, state):
    """Raise InstabilityError naming the first body whose state diverged."""
    rs = state.rigid
    if model.rigid.body_count:
        for quantity, values, limit in (("speed (m/s)", rs.velocity, MAX_SPEED),
                                        ("distance from origin (m)", rs.position, MAX_DISTANCE)):
            size = _row_norms(values)
            bad = ~np.isfinite(size) | (size > limit)
            if bad.any():
                i = int(np.argmax(bad))
                raise InstabilityError(model.names[model.rigid_ids[i]], state.time, quantity, float(size[i]))
    for j, s in enumerate(state.fem):
        for quantity, values, limit in (("node speed (m/s)", s.v, MAX_SPEED),
                                        ("node distance from origin (m)", s.x, MAX_DISTANCE)):
            # the largest row norm; NaN anywhere makes it NaN
            worst = float(np.sqrt(_row_norms(values, squared=True).max(initial=0.0)))
            if not np.isfinite(worst) or worst > limit:
                raise InstabilityError(model.names[model.fem_ids[j]], state.time, quantity,
                                       worst if np.isfinite(worst) else float("nan"))


def _row_norms(a, squared=False):
    sq = np.einsum("ij,ij->i", a, a)
    return sq if squared else np.sqrt(sq)
