"""One time step of the rigid bodies: kick, detect, resolve contacts, drift.

Translation is leapfrog: ``state.velocity`` is the velocity the last step drifted with (the
mid-step velocity), which makes free flight under gravity exact at the step times. Contacts are
resolved by :func:`rigid.resolve.resolve_contacts` (collisions at their time of impact, resting
contact, shock propagation, penetration recovery); its names are re-exported here for callers
that step through this module.
"""
from typing import NamedTuple

import numpy as np

from . import quaternion as quat
from .contacts import Contacts, concatenate, detect
from .integrate import rotate_by, rotate_free
from .model import world_inverse_inertia
from .resolve import ContactSettings, Resolution, SolverBodies, resolve_contacts

__all__ = ["ContactSettings", "Resolution", "SolverBodies", "Touches", "drift", "kick", "reach",
           "resolve_contacts", "solver_bodies", "step", "substep_count"]


class Touches(NamedTuple):
    """The contacts a step resolved (every substep's, one after another) and the impulse each
    gave its side a ``(c, 3)`` N s, world (side b took the opposite)."""
    contacts: Contacts
    impulse: np.ndarray


def kick(model, state, h, gravity):
    """Mid-step velocities (leapfrog, allowing a change of step size) and the velocity at t."""
    gvec = np.where(model.body_fixed[:, None], 0.0, gravity)
    v = state.velocity + gvec * 0.5 * (state.last_dt + h)
    return v, v - 0.5 * h * gvec, gvec


def solver_bodies(model, state, v, v_at_t, gvec):
    """The rigid bodies as the contact solver sees them (SolverBodies): velocity ``v`` to drift
    with, ``v_at_t`` at the start of the step, free acceleration ``gvec`` (b, 3) m/s^2, world
    inverse inertia and angular velocity from the state, fixed bodies static."""
    invI = world_inverse_inertia(model, state.orientation)
    w = np.einsum("bij,bj->bi", invI, state.angular_momentum)
    return SolverBodies(model.body_inv_mass, invI, state.position, v, v_at_t, w, gvec,
                        model.body_fixed.copy())


def drift(model, state, res, h, v_kick):
    """Positions and orientations after the step; returns the new state."""
    free = ~model.body_fixed
    R = quat.to_matrix(state.orientation)
    I_world = np.einsum("bij,bj,bkj->bik", R, model.body_inertia, R)
    w0 = np.einsum("bij,bj->bi", world_inverse_inertia(model, state.orientation), state.angular_momentum)
    L = state.angular_momentum + np.where(
        free[:, None], np.einsum("bij,bj->bi", I_world, res.angular - w0) + res.momentum_fix, 0.0)
    new = state.copy()
    new.position = state.position + h * res.velocity + res.shift + h * res.pseudo_velocity
    q = rotate_free(state.orientation, L, model.body_inv_inertia, h)
    new.orientation = rotate_by(q, res.shift_rotation + h * res.pseudo_angular)
    new.velocity = res.velocity
    new.angular_momentum = L
    new.contact_dv = res.velocity - v_kick - res.impact_dv
    new.time = state.time + h
    new.last_dt = h
    return new


def substep_count(model, state, dt, settings):
    """Adaptive substeps so no body moves more than half the thinnest body's thickness."""
    if model.body_count == 0:
        return 1
    w = np.einsum("bij,bj->bi", world_inverse_inertia(model, state.orientation), state.angular_momentum)
    motion = (np.linalg.norm(state.velocity, axis=1) + np.linalg.norm(w, axis=1) * model.body_radius) * dt
    allowed = 0.5 * np.min(model.body_min_extent)
    return int(np.clip(np.ceil(np.max(motion) / allowed), 1, settings.max_substeps))


def step(model, state, dt, gravity, settings=None):
    """Advance ``state`` by ``dt`` seconds; returns the new state and the step's :class:`Touches`.
    ``settings``: ContactSettings (default: its defaults)."""
    settings = ContactSettings() if settings is None else settings
    gravity = np.asarray(gravity, float)
    n = substep_count(model, state, dt, settings)
    touched = Touches(Contacts(*(np.zeros(0, np.int64),) * 2, *(np.zeros((0, 3)),) * 2,
                               *(np.zeros(0),) * 3), np.zeros((0, 3)))
    for _ in range(n):
        h = dt / n
        v, v_at_t, gvec = kick(model, state, h, gravity)
        bodies = solver_bodies(model, state, v, v_at_t, gvec)
        contacts = detect(model, state.position, quat.to_matrix(state.orientation),
                          reach(model, bodies, h), settings.margin)
        res = resolve_contacts(bodies, contacts, h, gravity, settings)
        state = drift(model, state, res, h, v)
        touched = Touches(concatenate(touched.contacts, contacts, 0, 0), np.concatenate(
            [touched.impulse, res.collision_impulse + res.contact_impulse]))
    return state, touched


def reach(model, bodies, h):
    """How far each rigid body's surface can move in a step (m): speculative contact margin."""
    nb = model.body_count
    return (np.linalg.norm(bodies.velocity[:nb], axis=1)
            + np.linalg.norm(bodies.angular[:nb], axis=1) * model.body_radius) * h
