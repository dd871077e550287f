"""One time step of the rigid bodies: detect, collide, contact, shock-propagate, recover, drift.

Translation is leapfrog: ``state.velocity`` is the velocity the last step drifted with, i.e. the
velocity at mid-step, which makes free flight under gravity exact at the step times. Impacts found
inside a step get their restitution at their time of impact: the impulse is computed from the
approach velocity at that instant and the position is moved back by ``tau * dv`` (as if the
velocity had changed at ``t + tau`` and not at ``t``), so bounce heights do not depend on where
in a step the impact falls.
"""
from dataclasses import dataclass

import numpy as np

from . import quaternion as quat
from .contacts import detect
from .integrate import rotate_by, rotate_free
from .model import world_inverse_inertia
from .solver import arms, normal_velocity, pgs, shock_scales, stack_levels


@dataclass
class ContactSettings:
    """Solver parameters (all have scene-file fields under [simulation.solver]).

    iterations: Gauss-Seidel sweeps of the contact pass. margin m: contacts are kept while the gap
    is below it (plus the distance bodies can travel in a step). slop m: penetration tolerated
    without correction. recovery: fraction of the penetration beyond ``slop`` removed per step
    (position only, no velocity is added). restitution_threshold m/s: slower impacts are inelastic,
    so resting bodies do not jitter. max_substeps: cap on the adaptive substeps taken when a body
    moves more than half the thinnest body's thickness in one step (no tunnelling).
    """
    iterations: int = 20
    margin: float = 0.005
    slop: float = 0.0005
    recovery: float = 0.4
    restitution_threshold: float = 0.05
    shock_iterations: int = 4
    max_substeps: int = 32


def substep_count(model, state, dt, settings):
    """Adaptive substeps so no body moves more than half the thinnest body's thickness."""
    if model.body_count == 0:
        return 1
    w = np.einsum("bij,bj->bi", world_inverse_inertia(model, state.orientation), state.angular_momentum)
    motion = (np.linalg.norm(state.velocity, axis=1) + np.linalg.norm(w, axis=1) * model.body_radius) * dt
    allowed = 0.5 * np.min(model.body_min_extent)
    return int(np.clip(np.ceil(np.max(motion) / allowed), 1, settings.max_substeps))


def step(model, state, dt, gravity, settings=ContactSettings()):
    """Advance ``state`` by ``dt`` seconds; returns the new state and the last substep's contacts."""
    n = substep_count(model, state, dt, settings)
    contacts = None
    for _ in range(n):
        state, contacts = _substep(model, state, dt / n, np.asarray(gravity, float), settings)
    return state, contacts


def time_of_impact(gap, vn, an, h):
    """First time in [0, inf) at which gap + vn t + an t^2 / 2 reaches 0 (inf if never).

    Uses the conjugate form 2 gap / (sqrt(vn^2 - 2 an gap) - vn), stable for an -> 0.
    """
    disc = vn * vn - 2.0 * an * np.maximum(gap, 0.0)
    root = np.sqrt(np.maximum(disc, 0.0))
    den = root - vn
    with np.errstate(divide="ignore", invalid="ignore"):
        tau = np.where((disc >= 0) & (den > 0), 2.0 * np.maximum(gap, 0.0) / den, np.inf)
    return np.where(gap <= 0, 0.0, tau)


def _substep(model, state, h, g, settings):
    free = ~model.body_fixed
    gvec = np.where(free[:, None], g, 0.0)
    inv_m = model.body_inv_mass
    x, q, L = state.position, state.orientation, state.angular_momentum.copy()

    # kick: mid-step velocity (leapfrog with a possibly changed step size) and the velocity at t
    v = state.velocity + gvec * 0.5 * ((state.last_dt or 0.0) + h)
    v_at_t = v - 0.5 * h * gvec
    invI = world_inverse_inertia(model, q)
    w = np.einsum("bij,bj->bi", invI, L)
    R = quat.to_matrix(q)
    sweep = (np.linalg.norm(v, axis=1) + np.linalg.norm(w, axis=1) * model.body_radius) * h
    contacts = detect(model, x, R, sweep, settings.margin)

    shift_x, shift_rot = np.zeros_like(x), np.zeros_like(x)
    pseudo_v, pseudo_w = np.zeros_like(x), np.zeros_like(x)
    v_kick = v.copy()
    bounce_dv = np.zeros_like(x)
    if contacts.count:
        ia, ib, nrm = contacts.body_a, contacts.body_b, contacts.normal
        ra, rb = arms(ia, ib, contacts.point, x)
        ones = np.ones(contacts.count)
        w_before = w.copy()

        # 1. collisions: restitution at the time of impact within this step
        vn_t = normal_velocity(ia, ib, ra, rb, nrm, v_at_t, w)
        g_b = np.where((ib >= 0)[:, None], gvec[np.maximum(ib, 0)], 0.0)
        an = np.einsum("ck,ck->c", gvec[ia] - g_b, nrm)
        tau = time_of_impact(contacts.gap, vn_t, an, h)
        approach = -(vn_t + an * np.minimum(tau, h))
        # slower approaches are resting contact, left to the contact pass (no bounce, no jitter)
        threshold = max(settings.restitution_threshold, 2.0 * np.linalg.norm(g) * h)
        impact = (tau <= h) & (approach > threshold)
        if impact.any():
            e = contacts.restitution
            target = normal_velocity(ia, ib, ra, rb, nrm, v, w) + (1.0 + e) * approach
            lam = np.zeros((contacts.count, 3))
            imp = pgs(ia, ib, ra, rb, nrm, target, contacts.friction, ones, ones, impact, lam,
                      inv_m, invI, v, w, settings.iterations)
            # the impulse acted at t + tau: move each body back by tau * (its velocity change)
            t_imp = np.where(impact, tau, 0.0)[:, None]
            dva, dwa = imp * inv_m[ia][:, None], np.einsum("cij,cj->ci", invI[ia], np.cross(ra, imp))
            np.add.at(shift_x, ia, -t_imp * dva)
            np.add.at(shift_rot, ia, -t_imp * dwa)
            np.add.at(bounce_dv, ia, dva)
            # angular momentum stays exact when the arm is taken from where the body is at impact
            np.add.at(L, ia, t_imp * np.cross(imp, v[ia]))
            has_b = ib >= 0
            if has_b.any():
                jb, rbb, ib_ = -imp[has_b], rb[has_b], ib[has_b]
                tb = t_imp[has_b]
                dvb, dwb = jb * inv_m[ib_][:, None], np.einsum("cij,cj->ci", invI[ib_], np.cross(rbb, jb))
                np.add.at(shift_x, ib_, -tb * dvb)
                np.add.at(shift_rot, ib_, -tb * dwb)
                np.add.at(bounce_dv, ib_, dvb)
                np.add.at(L, ib_, tb * np.cross(jb, v[ib_]))

        # 2. contacts: no gap may close by the end of the step (inelastic, Coulomb friction)
        shift_n = (np.einsum("ck,ck->c", shift_x[ia] + np.cross(shift_rot[ia], ra), nrm)
                   - np.einsum("ck,ck->c", np.where((ib >= 0)[:, None],
                                                    shift_x[np.maximum(ib, 0)] + np.cross(shift_rot[np.maximum(ib, 0)], rb), 0.0), nrm))
        target = -(np.maximum(contacts.gap, 0.0) + shift_n) / h
        lam = np.zeros((contacts.count, 3))
        all_on = np.ones(contacts.count, dtype=bool)
        pgs(ia, ib, ra, rb, nrm, target, contacts.friction, ones, ones, all_on, lam, inv_m, invI, v, w,
            settings.iterations)

        # 3. shock propagation: sweep the stack bottom-up with the lower side frozen (Guendelman 2003)
        gnorm = np.linalg.norm(g)
        if gnorm > 0:
            level = stack_levels(ia, ib, nrm, -g / gnorm, model.body_count, model.body_fixed)
            c_level, sa, sb = shock_scales(ia, ib, level)
            for lv in np.unique(c_level):
                pgs(ia, ib, ra, rb, nrm, target, contacts.friction, sa, sb, c_level == lv, lam,
                    inv_m, invI, v, w, settings.shock_iterations)
        else:
            sa = sb = ones

        # 4. penetration recovery: move positions only (split impulse), never add velocity
        deep = contacts.gap < -settings.slop
        if deep.any():
            target_p = settings.recovery * (-contacts.gap - settings.slop) / h
            pgs(ia, ib, ra, rb, nrm, target_p, np.zeros(contacts.count), sa, sb, deep,
                np.zeros((contacts.count, 3)), inv_m, invI, pseudo_v, pseudo_w, settings.iterations)

        # the solver changed w; carry the change into the angular momentum L = I w
        I_world = np.einsum("bij,bj,bkj->bik", R, model.body_inertia, R)
        L = L + np.where(free[:, None], np.einsum("bij,bj->bi", I_world, w - w_before), 0.0)

    # drift
    x = x + h * v + shift_x + h * pseudo_v
    q = rotate_free(q, L, model.body_inv_inertia, h)
    q = rotate_by(q, shift_rot + h * pseudo_w)
    new = state.copy()
    new.position, new.orientation, new.velocity, new.angular_momentum = x, q, v, L
    new.contact_dv = v - v_kick - bounce_dv
    new.time = state.time + h
    new.last_dt = h
    return new, contacts
