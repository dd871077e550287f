"""One time step of the rigid bodies: kick, detect, resolve contacts, drift.

Translation is leapfrog: ``state.velocity`` is the velocity the last step drifted with (the
mid-step velocity), which makes free flight under gravity exact at the step times. Contacts are
resolved by :func:`rigid.resolve.resolve_contacts` (collisions at their time of impact, resting
contact, shock propagation, penetration recovery); its names are re-exported here for callers
that step through this module.
"""
import math
from typing import NamedTuple

import numpy as np

from .contacts import Contacts, concatenate, detect
from .model import RigidState
from .resolve import ContactSettings, Resolution, SolverBodies, resolve_contacts
from .step_kernels import body_frames, body_speeds, drift_bodies

# the impacts' move back may add at most this share of a body's spin energy (round-off)
SPIN_GAIN_TOL = 1e-12

__all__ = ["ContactSettings", "Resolution", "SolverBodies", "Touches", "drift", "frames", "kick",
           "reach", "resolve_contacts", "solver_bodies", "step", "substep_count"]


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


def frames(model, state):
    """Rotation matrices (b, 3, 3), world inverse inertia (b, 3, 3) 1/(kg m^2) and angular
    velocity (b, 3) rad/s of the state's bodies (one compiled pass: rigid.step_kernels)."""
    return body_frames(*(np.ascontiguousarray(a, dtype=float) for a in (
        state.orientation, model.body_inv_inertia, state.angular_momentum)))


def solver_bodies(model, state, v, v_at_t, gvec, known_frames=None):
    """The rigid bodies as the contact solver sees them (SolverBodies): velocity ``v`` to drift
    with, ``v_at_t`` at the start of the step, free acceleration ``gvec`` (b, 3) m/s^2, world
    inverse inertia and angular velocity from the state (``known_frames``: :func:`frames` of it,
    if already at hand), fixed bodies static."""
    _, invI, w = frames(model, state) if known_frames is None else known_frames
    return SolverBodies(model.body_inv_mass, invI, state.position, v, v_at_t, w, gvec,
                        model.body_fixed.copy())


def drift(model, state, res, h, v_kick):
    """Positions and orientations after the step; returns the new state. Angular momentum takes
    what the contacts did to the angular velocity; orientations follow the torque-free flow of
    the new momentum, then the small rotations of impacts and penetration recovery
    (rigid.step_kernels.drift_bodies); the impacts' move back where it adds no spin energy
    (:func:`_spin_kept`)."""
    shift, turn, fix = _spin_kept(model, state, res, h)
    position, L, q = drift_bodies(state.position, state.orientation, state.angular_momentum,
                                  model.body_fixed, model.body_inertia, model.body_inv_inertia,
                                  float(h), res.velocity, res.angular, shift, turn,
                                  res.pseudo_velocity, res.pseudo_angular, fix)
    return RigidState(position, q, res.velocity.copy(), L, res.velocity - v_kick - res.impact_dv,
                      state.time + h, h)


def _spin_kept(model, state, res, h):
    """The impacts' move back (``res.shift``, ``shift_rotation``, ``momentum_fix``: rigid.collide)
    less that of the bodies whose spin energy it would raise. The collision pass keeps the
    energy in the bodies' configuration at the start of the step; moving a body back turns it by
    ``-tau dw`` with its angular momentum kept, and gives its spin the angular momentum its shift
    takes from its motion, which change its spin energy ``L . w / 2`` to first order in tau, the
    more the faster it spins (a box spinning at 32 rad/s struck a ball with e = 1 and gained 6.7%
    at dt = 2 ms, one at 45 rad/s landing on a plane 6.8%). Such a body keeps its impulses at
    the start of the step: no turn, and where its shift was balanced by a momentum correction,
    neither (each body's correction balances its own shift, so momenta stay exact). Only bodies
    in a group that bounces (``res.bouncing``): in an inelastic one the impact takes more than the
    move adds, and the move keeps its corners out of what it struck (moved back without it, the
    boxes of a pile of 1,000 sank up to the slop, 0.5 mm, where they sink 0.03)."""
    shift, turn, fix = res.shift, res.shift_rotation, res.momentum_fix
    if res.bouncing is None:
        return shift, turn, fix
    moved = res.bouncing & ~model.body_fixed & ((turn != 0).any(axis=1) | (fix != 0).any(axis=1))
    if not moved.any():
        return shift, turn, fix
    b = np.flatnonzero(moved)
    balanced = (fix[b] != 0).any(axis=1)[:, None]

    def spin_energy(keep):
        _, L, q = drift_bodies(state.position[b], state.orientation[b], state.angular_momentum[b],
                               model.body_fixed[b], model.body_inertia[b], model.body_inv_inertia[b],
                               float(h), res.velocity[b], res.angular[b],
                               np.where(balanced, keep * shift[b], shift[b]), keep * turn[b],
                               res.pseudo_velocity[b], res.pseudo_angular[b], keep * fix[b])
        return 0.5 * np.einsum("bi,bi->b", body_frames(q, model.body_inv_inertia[b], L)[2], L)

    start = spin_energy(0.0)
    gains = spin_energy(1.0) > start + SPIN_GAIN_TOL * np.abs(start)
    if not gains.any():
        return shift, turn, fix
    drop = np.zeros(len(moved), dtype=bool)
    drop[b[gains]] = True
    balanced_all = drop & (fix != 0).any(axis=1)
    return (np.where(balanced_all[:, None], 0.0, shift), np.where(drop[:, None], 0.0, turn),
            np.where(drop[:, None], 0.0, fix))


def substep_count(model, state, dt, settings, angular=None):
    """Adaptive substeps so no body moves more than half the thinnest body's thickness.
    ``angular``: the bodies' angular velocities (b, 3) rad/s, if already at hand."""
    if model.body_count == 0:
        return 1
    w = frames(model, state)[2] if angular is None else angular
    motion = np.max(body_speeds(state.velocity, w, model.body_radius)) * dt
    ratio = motion / (0.5 * np.min(model.body_min_extent))
    return settings.max_substeps if ratio > settings.max_substeps else max(1, math.ceil(ratio))


def step(model, state, dt, gravity, settings=None):
    """Advance ``state`` by ``dt`` seconds; returns the new state and the step's :class:`Touches`.
    ``settings``: ContactSettings (default: its defaults)."""
    settings = ContactSettings() if settings is None else settings
    gravity = np.asarray(gravity, float)
    known_frames = frames(model, state)
    n = substep_count(model, state, dt, settings, known_frames[2])
    touched = None
    for i in range(n):
        h = dt / n
        if i > 0:
            known_frames = frames(model, state)
        v, v_at_t, gvec = kick(model, state, h, gravity)
        bodies = solver_bodies(model, state, v, v_at_t, gvec, known_frames)
        contacts = detect(model, state.position, known_frames[0], reach(model, bodies, h),
                          settings.margin)
        res = resolve_contacts(bodies, contacts, h, gravity, settings)
        state = drift(model, state, res, h, v)
        impulse = res.collision_impulse + res.contact_impulse
        touched = Touches(contacts, impulse) if touched is None else Touches(
            concatenate(touched.contacts, contacts, 0, 0), np.concatenate([touched.impulse, impulse]))
    return state, touched


def reach(model, bodies, h):
    """How far each rigid body's surface can move in a step (m): speculative contact margin."""
    nb = model.body_count
    return body_speeds(bodies.velocity[:nb], bodies.angular[:nb], model.body_radius) * h
