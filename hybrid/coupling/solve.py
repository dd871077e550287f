"""Solving the contact problem: one contact resolution for every body, each deformable body then
taking the impulses on its nodes through its own implicit system; and integrating to the step's end.
"""
import numba as nb
import numpy as np

from fem import dynamics as fem_dyn
from fem.contact_response import apply_contact_impulses, impulse_velocity_change
from rigid import step as rigid_step

from .nodes import moving

# coupling rounds of a step with corotated bodies in contact: at most MAX_ROUNDS, done when no
# touched node's velocity differs from the solver's by more than COUPLING_TOL of the step's
# velocity scale (gravity's gain over the step plus the fastest touched node). Two rounds let a
# box resting on the tip of a corotated cantilever bent by 10 degrees sink into it at 0.3 mm/s
MAX_ROUNDS = 10
COUPLING_TOL = 1e-4


def solve(model, state, fems, predicted, nodes, problem, h):
    """Contact impulses of the step (rigid_step.Resolution over all solver bodies). Each touched
    deformable body takes the impulses on its nodes (a place's shared among its triangle's nodes
    by its weights) through its own implicit system: ``predicted[j]`` is replaced by the body's
    step with them. The Delassus blocks are exact for floating and anchored bodies; corotated
    ones answer through their rest system, so their contacts are solved again from the velocities
    the nodes really took until those are the ones the solver expected (to COUPLING_TOL), in at
    most MAX_ROUNDS rounds."""
    nb = model.rigid.body_count
    parts, bodies, contacts = problem.parts, problem.bodies, problem.contacts
    rounds = MAX_ROUNDS if any(model.fem[j].frame == "corotated" for j in problem.touched_bodies) else 1
    warm = state.contact_memory.recall(problem.keys) if state.contact_memory is not None else None
    res, applied = None, np.zeros((contacts.count, 3))
    for _ in range(rounds):
        if res is not None and _settled(model, state, predicted, nodes, problem, res, h):
            break
        res = rigid_step.resolve_contacts(bodies, contacts, h, model.gravity, model.settings,
                                          previous=res, warm=warm)
        total = res.collision_impulse + res.contact_impulse
        increment, applied = total - applied, total
        if not parts.count:
            break
        impulse = particle_impulses(contacts.body_a, contacts.body_b, increment, nb, parts.count)
        if len(problem.touched_bodies) == 1 and not len(parts.corners):     # (spread: the same)
            j = problem.touched_bodies[0]
            predicted[j] = apply_contact_impulses(fems[j], state.fem[j], predicted[j], h,
                                                  nodes.local[parts.nodes], impulse)
            continue
        node_impulse = parts.spread(impulse, nodes.count)
        for j in problem.touched_bodies:
            at = parts.nodes_of(j)
            predicted[j] = apply_contact_impulses(fems[j], state.fem[j], predicted[j], h,
                                                  nodes.local[at], node_impulse[at])
    return res


def _settled(model, state, predicted, nodes, problem, res, h):
    """Whether the touched nodes move as the last solve expected; if not, the solver bodies take
    the velocities the bodies really took, to be solved again."""
    nb, parts, bodies = model.rigid.body_count, problem.parts, problem.bodies
    for j in problem.touched_bodies:
        at = parts.nodes_of(j)
        nodes.v[at] = moving(predicted[j], state.fem[j], nodes.local[at], h)
    expected = res.velocity[nb:nb + len(parts.nodes)]
    miss = np.abs(nodes.v[parts.nodes] - expected).max(initial=0.0)
    if miss <= COUPLING_TOL * (h * np.linalg.norm(model.gravity) + np.abs(expected).max(initial=0.0)):
        return True
    bodies.velocity = np.concatenate([res.velocity[:nb], parts.mean(nodes.v)])
    bodies.velocity_at_t = bodies.velocity
    bodies.angular = res.angular
    return False


def integrate(model, state, fems, predicted, nodes, problem, res, v, h):
    """The step's end: rigid bodies drift with their resolved velocities (``v``: the kicked ones);
    deformable bodies finish their steps, those the penetration recovery pushed moving their
    positions by their response to its pseudo-impulses. Returns (rigid state, FEM states)."""
    nb = model.rigid.body_count
    rigid_res = rigid_step.Resolution(*(a[:nb] for a in (
        res.velocity, res.angular, res.shift, res.shift_rotation, res.pseudo_velocity,
        res.pseudo_angular, res.impact_dv, res.momentum_fix)),
        bouncing=None if res.bouncing is None else res.bouncing[:nb])
    new_rigid = rigid_step.drift(model.rigid, state.rigid, rigid_res, h, v)
    shifts = _recovery_shifts(model, state, fems, predicted, nodes, problem, res, h)
    new_fem = [fem_dyn.finish(m, s, pr, h, shift) for m, s, pr, shift in zip(fems, state.fem, predicted, shifts)]
    return new_rigid, new_fem


def _recovery_shifts(model, state, fems, predicted, nodes, problem, res, h):
    """Each deformable body's move out of penetration, ``(nodes, dx (k, 3) m)`` or None: its
    whole response (positions only) to the recovery's pseudo-impulses on its touched nodes, the
    moves the solver saw at those nodes. Shifting the touched nodes alone strained a stiff body:
    a steel bar landing at dt = 10 ms took 3 kJ of strain energy from a 0.5 mm push on one node."""
    shifts = [None] * len(fems)
    parts, pseudo = problem.parts, res.pseudo_impulse
    if pseudo is None or not parts.count or not pseudo.any():
        return shifts
    # each side takes its share (none where shock propagation froze it: it did not move)
    c, nb, none = problem.contacts, model.rigid.body_count, np.full(problem.contacts.count, -1)
    push = particle_impulses(c.body_a, none, pseudo * res.pseudo_share[:, :1], nb, parts.count) \
        + particle_impulses(c.body_b, none, -pseudo * res.pseudo_share[:, 1:], nb, parts.count)
    node_push = parts.spread(push, nodes.count)
    for j in problem.touched_bodies:
        at = parts.nodes_of(j)
        if node_push[at].any():
            shifts[j] = (np.arange(fems[j].node_count), predicted[j].x_rate * impulse_velocity_change(
                fems[j], state.fem[j], predicted[j], h, nodes.local[at], node_push[at]))
    return shifts


@nb.njit(cache=True)
def particle_impulses(body_a, body_b, impulse, first, count):
    """Each of ``count`` solver particles' total impulse ``(count, 3)`` N s from the contacts'
    impulses ``impulse`` (c, 3) on side a (solver bodies ``body_a``, ``body_b`` (c,); particle i
    is solver body ``first + i``; side b takes the opposite): ``np.add.at`` over side a, then
    over side b, in one pass each."""
    out = np.zeros((count, 3))
    for k in range(len(body_a)):
        i = body_a[k] - first
        if i >= 0:
            for d in range(3):
                out[i, d] += impulse[k, d]
    for k in range(len(body_b)):
        i = body_b[k] - first
        if body_b[k] >= 0 and i >= 0:
            for d in range(3):
                out[i, d] -= impulse[k, d]
    return out
