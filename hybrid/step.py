"""The coupled step: rigid bodies and FEM bodies advanced together with two-way contact.

    step(model, state) -> state

FEM surface nodes enter the contact solver as particles carrying their lumped mass, so rigid
bodies, planes and deformable bodies exchange momentum through one impulse mechanism
(rigid.step.resolve_contacts). The impulses a body's nodes receive are then fed back through that
body's own implicit system (one more back-substitution), so the elastic response is consistent.
"""
import numpy as np

from fem import dynamics as fem_dyn
from rigid import quaternion as quat
from rigid import step as rigid_step
from rigid.contacts import concatenate, detect, detect_points

from .build import HybridState


class InstabilityError(RuntimeError):
    """A body's state stopped being finite or physically plausible."""

    def __init__(self, body, time, quantity, value):
        self.body, self.time, self.quantity, self.value = body, time, quantity, value
        super().__init__(f"unstable: body '{body}' at t = {time:.6g} s: {quantity} = {value:.3g}")


# above these the run is declared unstable (no scene of everyday objects gets near them)
MAX_SPEED = 1.0e4       # m/s
MAX_DISTANCE = 1.0e6    # m


def step(model, state):
    """Advance every body by one scene time step ``model.dt``."""
    if not model.fem:
        rigid, _ = rigid_step.step(model.rigid, state.rigid, model.dt, model.gravity, model.settings)
        new = HybridState(rigid=rigid, fem=[], time=state.time + model.dt, steps=state.steps + 1)
    else:
        new = _coupled_step(model, state)
    check_finite(model, new)
    return new


def _coupled_step(model, state):
    h, g = model.dt, model.gravity
    rm, rs = model.rigid, state.rigid
    nb = rm.body_count

    # 1. deformable bodies: implicit step without contact (prefactored system)
    predicted = [fem_dyn.predict(m, s, h, g) for m, s in zip(model.fem, state.fem)]

    # 2. rigid bodies: leapfrog kick
    v, v_at_t, gvec = rigid_step.kick(rm, rs, h, g)
    rigid_bodies = rigid_step.solver_bodies(rm, rs, v, v_at_t, gvec)

    # 3. surface nodes join the solver as particles (anchored nodes are immovable)
    nodes = [m.surface_nodes for m in model.fem]
    node_x = np.concatenate([s.x[n] for s, n in zip(state.fem, nodes)])
    node_v = np.concatenate([p.v[n] for p, n in zip(predicted, nodes)])
    node_inv_m = np.concatenate([_node_inverse_mass(m)[n] for m, n in zip(model.fem, nodes)])
    k = len(node_x)
    bodies = rigid_step.SolverBodies(
        inv_mass=np.concatenate([rigid_bodies.inv_mass, node_inv_m]),
        inv_inertia=np.concatenate([rigid_bodies.inv_inertia, np.zeros((k, 3, 3))]),
        position=np.concatenate([rigid_bodies.position, node_x]),
        velocity=np.concatenate([rigid_bodies.velocity, node_v]),
        velocity_at_t=np.concatenate([rigid_bodies.velocity_at_t, node_v]),
        angular=np.concatenate([rigid_bodies.angular, np.zeros((k, 3))]),
        accel=np.concatenate([rigid_bodies.accel, np.zeros((k, 3))]),
        static=np.concatenate([rigid_bodies.static, node_inv_m == 0]))

    # 4. contacts: rigid bodies among themselves and with planes; nodes with planes and rigid shapes
    R = quat.to_matrix(rs.orientation)
    c_rigid = detect(rm, rs.position, R, rigid_step.reach(rm, rigid_bodies, h), model.settings.margin)
    mu = np.concatenate([np.full(len(n), b.friction) for n, b in zip(nodes, _fem_bodies(model))])
    e = np.concatenate([np.full(len(n), b.restitution) for n, b in zip(nodes, _fem_bodies(model))])
    c_nodes = detect_points(rm, rs.position, R, node_x, np.linalg.norm(node_v, axis=1) * h,
                            model.settings.margin, mu, e)
    contacts = concatenate(c_rigid, c_nodes, nb, 0)

    # 5. one contact resolution for everything
    res = rigid_step.resolve_contacts(bodies, contacts, h, g, model.settings)

    # 6. rigid drift; deformable bodies answer their nodes' impulses through their own system
    rigid_res = rigid_step.Resolution(*(a[:nb] for a in (
        res.velocity, res.angular, res.shift, res.shift_rotation, res.pseudo_velocity,
        res.pseudo_angular, res.impact_dv, res.momentum_fix)))
    new_rigid = rigid_step.drift(rm, rs, rigid_res, h, v)
    new_fem = []
    start = nb
    for m, s, p, n in zip(model.fem, state.fem, predicted, nodes):
        sl = slice(start, start + len(n))
        start += len(n)
        impulse = np.zeros_like(s.x)
        impulse[n] = m.node_mass[n, None] * (res.velocity[sl] - p.v[n])
        if np.any(impulse):
            p = fem_dyn.apply_impulse(m, s, p, impulse)
        s_new = fem_dyn.finish(m, s, p, h)
        correction = res.shift[sl] + h * res.pseudo_velocity[sl]
        if np.any(correction):
            x = s_new.x.copy()
            x[n] += correction
            s_new = s_new.replace(x=x)
        new_fem.append(s_new)
    return HybridState(rigid=new_rigid, fem=new_fem, time=state.time + h, steps=state.steps + 1)


def _node_inverse_mass(m):
    inv = 1.0 / m.node_mass
    if len(m.anchor_nodes):
        inv[np.concatenate([np.atleast_1d(a) for a in m.anchor_nodes])] = 0.0
    return inv


def _fem_bodies(model):
    return [model.scene.bodies[i] for i in model.fem_ids]


def check_finite(model, state):
    """Raise InstabilityError naming the first body whose state diverged."""
    rs = state.rigid
    if model.rigid.body_count:
        for quantity, values, limit in (("speed (m/s)", np.linalg.norm(rs.velocity, axis=1), MAX_SPEED),
                                        ("distance from origin (m)", np.linalg.norm(rs.position, axis=1), MAX_DISTANCE)):
            bad = ~np.isfinite(values) | (values > limit)
            if bad.any():
                i = int(np.argmax(bad))
                raise InstabilityError(model.names[model.rigid_ids[i]], state.time, quantity, float(values[i]))
    for j, s in enumerate(state.fem):
        for quantity, values, limit in (("node speed (m/s)", np.linalg.norm(s.v, axis=1), MAX_SPEED),
                                        ("node distance from origin (m)", np.linalg.norm(s.x, axis=1), MAX_DISTANCE)):
            worst = float(np.max(values)) if len(values) else 0.0
            if not np.isfinite(values).all() or worst > limit:
                raise InstabilityError(model.names[model.fem_ids[j]], state.time, quantity,
                                       worst if np.isfinite(worst) else float("nan"))
