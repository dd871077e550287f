"""The collision pass of a step's contact resolution (rigid.resolve): impacts get their
restitution at their time of impact, solved together with the resting contacts that pass them
on, and the bodies are moved back by the time their impulses acted times the velocity they gave."""
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from .shock import STACK_COS
from .solver import normal_velocity

# the collision pass may add at most this share of a group's kinetic energy (round-off)
ENERGY_TOL = 1e-9


def finite(impulse):
    """The impulses with the NaN rows of contacts a pass left out as zeros (np.nan_to_num, called
    only when the sum shows a value that is not finite: it costs more than the sum)."""
    return impulse if np.isfinite(impulse.sum()) else np.nan_to_num(impulse)


def _scatter(target, index, values):
    keep = index >= 0
    np.add.at(target, index[keep], values[keep])


def collide(out, problem, impact, support, tau, approach, h, gravity, settings):
    """Collision pass: each impact reaches its restitution target (e times its approach) at its
    time of impact ``tau``, solved together with the ``support`` contacts (the other rigid
    contacts, held to close no further than their gap, as in the contact pass), so a body lying on
    the ground passes an impact on to it: solved alone, a ball falling at 3 m/s with e = 0.5 on a
    box lying on the ground pushed the box into the ground and left at 0.08 m/s instead of 1.5.
    Then, as in the contact pass, the stack is swept bottom-up with the lower side of each
    contact frozen (Guendelman 2003), which the sweeps alone reach only slowly through a stack
    (a ball on two stacked boxes left at 2.3 m/s instead of 3.5 after 20 sweeps, and set the top
    box sliding). Where the targets met together would add energy, the impacts follow Poisson's
    rule instead. Updates out.velocity, out.angular in place and fills ``out``'s collision
    fields."""
    contacts, v, w = problem.contacts, out.velocity, out.angular
    ia, ib = contacts.body_a, contacts.body_b
    active = impact | support
    vn = normal_velocity(ia, ib, problem.ra, problem.rb, contacts.normal, v, w)
    held = -np.maximum(contacts.gap, 0.0) / h
    v0, w0 = v.copy(), w.copy()
    imp, swept = _solve(problem, np.where(impact, vn + (1.0 + contacts.restitution) * approach, held),
                        active, support, gravity, settings, v, w)
    # one restitution target per contact cannot all be met when impacts pass on through one
    # another in a step (a row of balls, corners of a box): met as far as they can be, they
    # added energy (five balls in a row, two of them moving, gained 40%). Where they would, in a
    # group of bodies touching through the pass's contacts, the group takes Poisson's rule: the
    # inelastic impulses, and e times them again, which never adds energy
    group = _groups(problem.bodies, ia, ib, active)
    bouncy = np.zeros(group.max() + 1 if len(group) else 0, dtype=bool)
    bouncy[group[ia[impact & (contacts.restitution > 0)]]] = True
    out.bouncing = bouncy[group]
    energy0 = _kinetic(problem.bodies, v0, w0)
    before = np.bincount(group, energy0)
    gained = np.bincount(group, _kinetic(problem.bodies, v, w) - energy0)
    poisson = gained > ENERGY_TOL * (before + 1e-300)
    if poisson.any():
        v_newton, w_newton, imp_newton = v.copy(), w.copy(), imp
        v[:], w[:] = v0, w0
        imp, swept = _solve(problem, np.where(impact, vn + approach, held), active, support,
                            gravity, settings, v, w)
        e = np.zeros(len(before))
        np.maximum.at(e, group[ia[impact]], contacts.restitution[impact])
        body = poisson[group][:, None]
        v[:] = np.where(body, v0 + (1.0 + e[group][:, None]) * (v - v0), v_newton)
        w[:] = np.where(body, w0 + (1.0 + e[group][:, None]) * (w - w0), w_newton)
        mine = poisson[group[ia]][:, None]
        imp = np.where(mine, (1.0 + e[group[ia]][:, None]) * imp, imp_newton)
    out.collision_impulse = finite(imp)
    out.impact_dv = v - v0
    t_contact = _impulse_times(ia, ib, np.where(impact, tau, 0.0), support, len(v))
    _move_back(out, problem, t_contact, active, swept, v0, w0)
    out.momentum_fix *= ~_held(problem.bodies, ia, ib, active, group)[group][:, None]


def _solve(problem, target, active, support, gravity, settings, v, w):
    """The collision pass's sweeps to ``target``, then down the stack (updating v and w):
    ``(impulses (c, 3), whether the stack was swept)``."""
    contacts = problem.contacts
    ones = np.ones(contacts.count)
    lam = np.zeros((contacts.count, 3))
    imp = problem.solve(target, contacts.friction, ones, ones, active, lam, v, w, settings.iterations)
    gnorm = np.linalg.norm(gravity)
    swept = bool(support.any() and gnorm > 0)
    if swept:
        up = -np.asarray(gravity) / gnorm
        # only contacts that stack (a sideways hit keeps the answer of the sweeps above: frozen,
        # the box it hits would act as a wall)
        stacked = active & (np.abs(contacts.normal @ up) > STACK_COS)
        problem.sweep_stack(up, stacked, target, lam, v, w, settings.shock_iterations, imp)
    return imp, swept


def _kinetic(bodies, v, w):
    """Kinetic energy (n,) J of each solver body at velocities ``v``, ``w``."""
    m = np.where(bodies.inv_mass > 0, 1.0 / np.where(bodies.inv_mass > 0, bodies.inv_mass, 1.0), 0.0)
    inertia = np.linalg.pinv(bodies.inv_inertia)
    return 0.5 * (m * np.einsum("bi,bi->b", v, v) + np.einsum("bi,bij,bj->b", w, inertia, w))


def _groups(bodies, ia, ib, active):
    """Group label (n,) of each solver body: bodies that can move and touch through the
    ``active`` contacts share one (static bodies and planes join none)."""
    n = len(bodies.inv_mass)
    movable = bodies.inv_mass > 0
    ib0 = np.maximum(ib, 0)
    edge = active & (ib >= 0) & movable[ia] & movable[ib0]
    graph = coo_matrix((np.ones(int(edge.sum())), (ia[edge], ib0[edge])), shape=(n, n))
    return connected_components(graph, directed=False)[1]


def _held(bodies, ia, ib, active, group):
    """Whether each group (of :func:`_groups`) touches a static body or a plane through an
    ``active`` contact. A held group has no angular momentum of its own to keep (what holds it
    takes any), so moving it back needs no momentum correction, and the correction would change
    its spin's energy: a cube tumbling onto the ground with e = 1 gained 15% at dt = 1/240."""
    movable = bodies.inv_mass > 0
    a_free = (ia >= 0) & movable[np.maximum(ia, 0)]
    b_free = (ib >= 0) & movable[np.maximum(ib, 0)]
    held = np.zeros(group.max() + 1 if len(group) else 0, dtype=bool)
    for free, other_free, side in ((a_free, b_free, ia), (b_free, a_free, ib)):
        touch = active & free & ~other_free
        held[group[side[touch]]] = True
    return held


def _move_back(out, problem, t_contact, active, swept, v0, w0):
    """The bodies are moved back by the time their impulses acted times the velocity they gave,
    so bounces do not depend on where an impact falls in the step; their spin takes the angular
    momentum that moving them back takes from their motion, so it stays exact. Fills out.shift,
    shift_rotation and momentum_fix."""
    contacts, bodies, v, w = problem.contacts, problem.bodies, out.velocity, out.angular
    ia, ib, n = contacts.body_a, contacts.body_b, len(v)
    inv_m, invI = bodies.inv_mass, bodies.inv_inertia
    if swept:
        # frozen sides took less than the impulses: each body's own change, at the mean time of
        # its impulses, weighted by their size (at the latest, a box landing with its corners at
        # 0.4 to 0.7 ms was moved back so far that its first corner ended 0.8 mm deep)
        weight = np.where(active, np.linalg.norm(out.collision_impulse, axis=1), 0.0)
        t_body, w_body = np.zeros(n + 1), np.zeros(n + 1)
        for side in (np.where(ia >= 0, ia, n), np.where(ib >= 0, ib, n)):
            np.add.at(t_body, side, weight * t_contact)
            np.add.at(w_body, side, weight)
        t_body = np.where(w_body > 0, t_body / np.where(w_body > 0, w_body, 1.0), 0.0)[:n, None]
        out.shift = -t_body * (v - v0)
        out.shift_rotation = -t_body * (w - w0)
        mass = np.where(inv_m > 0, 1.0 / np.where(inv_m > 0, inv_m, 1.0), 0.0)[:, None]
        out.momentum_fix = t_body * np.cross(mass * (v - v0), v)
        return
    imp = out.collision_impulse
    for side, r, j in ((ia, problem.ra, imp), (ib, problem.rb, -imp)):
        s = np.maximum(side, 0)
        t = t_contact[:, None]          # each impulse at its own time
        _scatter(out.shift, side, -t * j * inv_m[s][:, None])
        _scatter(out.shift_rotation, side, -t * np.einsum("cij,cj->ci", invI[s], np.cross(r, j)))
        _scatter(out.momentum_fix, side, t * np.cross(j, v[s]))


def _impulse_times(ia, ib, tau, support, n, sweeps=8):
    """When in the step each collision-pass impulse acts (s, (c,)): an impact at its own time
    ``tau``; a support at the time of the impacts it passes on, found through the bodies it shares
    with them (down a stack, one body per sweep). The bodies are moved back by these times the
    velocity they took, so a body that passes an impact on takes no net shift (a box lying on the
    ground, shifted by the ball's impact but not by the ground's answer to it, rose 2 mm into the
    ball, which then left at 21 m/s instead of 15)."""
    t = tau.copy()
    for _ in range(sweeps):
        body = np.zeros(n + 1)                  # slot n: planes and static bodies (-1)
        np.maximum.at(body, np.where(ia >= 0, ia, n), t)
        np.maximum.at(body, np.where(ib >= 0, ib, n), t)
        body[n] = 0.0
        reached = np.where(support, np.maximum(body[np.where(ia >= 0, ia, n)], body[np.where(ib >= 0, ib, n)]), t)
        if np.array_equal(reached, t):
            break
        t = reached
    return t
