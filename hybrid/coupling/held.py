"""The coupled step's side of resting contact (hybrid.coupling.resting): which deformable bodies
step with their resting nodes held to static ground, the held nodes' contact rows, the impulses
the hold gave them, and each body's resting record after the step.

A held node in any contact but its hold with static ground, or a hold whose impulses stop pushing
and sticking, lets go: the step answers :class:`LetGo` and is taken again with that body free.
"""
from dataclasses import dataclass, replace

import numpy as np

from . import resting


@dataclass(frozen=True)
class LetGo:
    """The resting nodes held in deformable body ``body`` (an index into model.fem) let go;
    ``failed``: those whose impulses would not push or stick (sorted; None: not so found)."""
    body: int
    failed: np.ndarray = None
    sliding: bool = False


@dataclass(frozen=True)
class HoldNow:
    """Deformable body ``body`` (an index into model.fem) meets static ground with a large patch
    of new nodes: the step is taken again with them held at once (``record``,
    hybrid.coupling.resting.first_sight)."""
    body: int
    record: resting.Resting


def records(model, state):
    """Each FEM body's resting record (None where there is none yet)."""
    return state.resting if state.resting is not None else (None,) * len(model.fem)


def hold_sets(model, state):
    """Per FEM body, its resting record when the body steps with its resting nodes held, else None."""
    return [r if model.settings.hold_resting and r is not None and r.held else None
            for r in records(model, state)]


def held_rows(hold, nodes, found):
    """Which node contacts of ``found`` (stacked nodes on side a) are held nodes' contacts with
    static ground, ``(c,)`` bool; and the LetGo of the first body with a held node in any other
    contact (None when there is none)."""
    held = np.zeros(nodes.count, dtype=bool)
    for j, r in enumerate(hold):
        if r is not None:
            held[nodes.stacked(j, r.nodes)] = True
    contacts = found.nodes
    rows = held[contacts.body_a]
    for at in (contacts.body_a[rows & ~found.nodes_static], found.in_others[held[found.in_others]]):
        if len(at):
            return rows, LetGo(int(nodes.body[at[0]]))
    return rows, None


def first_sight(model, state, hold, nodes, found, h):
    """The :class:`HoldNow` of the first free body whose node contacts with static
    ground make a large new resting patch (hybrid.coupling.resting.first_sight), else None."""
    if not model.settings.hold_resting:
        return None
    contacts, others = found.nodes, found.in_others
    body = nodes.body[contacts.body_a]
    for j, (m, s, last) in enumerate(zip(model.fem, state.fem, records(model, state))):
        on = np.nonzero((body == j) & found.nodes_static)[0]
        if hold[j] is not None or len(on) < resting.FIRST_SIGHT:
            continue
        local = nodes.local[contacts.body_a[on]]
        record = resting.first_sight(
            last, local, nodes.local[others[nodes.body[others] == j]], contacts.normal[on],
            contacts.gap[on], nodes.v[contacts.body_a[on]], s.x, contacts.friction[on],
            found.nodes_static[on], m.node_anchor >= 0, _unsolved(m, h, local), h)
        if record is not None:
            return HoldNow(j, record)
    return None


def _unsolved(model, h, local):
    """``(k,)`` bool: which of body ``model``'s nodes ``local`` have no contact response solved for
    steps of ``h`` s (fem.contact_response's cache, read, not made)."""
    cache = model.cache.response
    if cache is None or cache.dt != h:
        return np.ones(len(local), dtype=bool)
    return cache.slot[local] < 0


def idle_rows(hold, nodes, found, h):
    """``(c,)`` bool: the node contacts of ``found`` that need no solve this step: every contact of
    a body that is not held, is in no contact but with static ground, and closes none of those
    within the step ``h`` at its nodes' mean velocities (a body falling towards the ground and
    found within reach a step before it lands). Nothing else acts on such a body in the step, so
    its contacts take no impulse, as the solver would find; left out, their response columns are
    not solved for nothing, and the face that lands next step is new to its response and may be
    held at first sight (:func:`first_sight`)."""
    contacts = found.nodes
    body = nodes.body[contacts.body_a]
    approach = -np.einsum("cd,cd->c", nodes.v[contacts.body_a], contacts.normal)
    busy = np.zeros(len(hold), dtype=bool)
    busy[body[~found.nodes_static | (contacts.gap <= h * approach)]] = True
    busy[nodes.body[found.in_others]] = True
    busy[[j for j, r in enumerate(hold) if r is not None]] = True
    return ~busy[body]


def held_now(model, state, hold_now):
    """The state with the record of :class:`HoldNow` ``hold_now`` as its body's (held)."""
    out = list(records(model, state))
    out[hold_now.body] = hold_now.record
    return replace(state, resting=tuple(out))


def hold_impulses(model, hold, nodes, found, rows, new_fem, solved_impulse, h):
    """The impulse (N s, on side a) each node contact took: ``solved_impulse`` for the rows the
    solver had, the hold's push (the held nodes' reactions, shared among a node's rows) for held
    rows; ``new_fem`` loses those reactions (the ground's push is a contact's, not an anchor's).
    Returns (row impulses (c, 3), the LetGo of a hold that stopped pushing or sticking, or None)."""
    contacts = found.nodes
    row_impulse = np.zeros((contacts.count, 3))
    row_impulse[~rows] = solved_impulse
    for j, r in enumerate(hold):
        if r is None:
            continue
        impulse = h * new_fem[j].node_reaction[r.nodes]
        if resting.violations(r, impulse).any():
            # those that fail and those near failing (as a watched node must be to join)
            failed = resting.violations(r, impulse, resting.stick_margin(model.fem[j]))
            pushing = resting.normal_and_slide(impulse, r.normal)[0] > 0
            return row_impulse, LetGo(j, r.nodes[failed], sliding=bool(pushing.all()))
        mine = np.nonzero(rows & (nodes.body[contacts.body_a] == j))[0]
        at = np.searchsorted(r.nodes, nodes.local[contacts.body_a[mine]])
        share = np.bincount(at, minlength=len(r.nodes))[at]
        row_impulse[mine] = impulse[at] / share[:, None]
        # (in place: the reactions are this step's own, made by fem.dynamics.finish for this state)
        new_fem[j].node_reaction[r.nodes] = 0.0
    return row_impulse, None


def watch(model, state, nodes, found, row_impulse):
    """Each deformable body's resting record after the step (hybrid.coupling.resting.observe) from
    its node contacts with planes and rigid bodies and the stacked nodes in any other contact;
    None where bodies are not held."""
    if not model.settings.hold_resting:
        return (None,) * len(model.fem)
    contacts, others = found.nodes, found.in_others
    body = nodes.body[contacts.body_a]
    out = []
    for j, (m, s, last) in enumerate(zip(model.fem, state.fem, records(model, state))):
        on = body == j
        out.append(resting.observe(
            last, nodes.local[contacts.body_a[on]], nodes.local[others[nodes.body[others] == j]],
            contacts.normal[on], contacts.gap[on], s.x, contacts.friction[on], row_impulse[on],
            found.nodes_static[on], m.node_anchor >= 0, resting.stick_margin(m)))
    return tuple(out)


def released(model, state, let_go):
    """The state after :class:`LetGo` ``let_go``: its body's held resting nodes let go."""
    out = list(records(model, state))
    out[let_go.body] = resting.released(out[let_go.body], let_go.failed, let_go.sliding)
    return replace(state, resting=tuple(out))
