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


# contact solve <-> elastic response rounds per step (measured: 3 keep a steel ball from sinking
# into a soft block; each round costs one back-substitution per touched body)
COUPLING_ROUNDS = 6

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
    nb, nf = rm.body_count, len(model.fem)

    # 1. deformable bodies: implicit step without contact (prefactored system)
    predicted = [fem_dyn.predict(m, s, h, g) for m, s in zip(model.fem, state.fem)]

    # 2. rigid bodies: leapfrog kick
    v, v_at_t, gvec = rigid_step.kick(rm, rs, h, g)
    rigid_bodies = rigid_step.solver_bodies(rm, rs, v, v_at_t, gvec)

    # 3. each deformable body joins the solver as a rigid proxy (its mass and inertia), so contacts
    #    on many of its nodes share the body's real inertia; each node's own deformation velocity
    #    enters as a per-contact bias
    proxies = [_proxy(m, s, p.v) for m, s, p in zip(model.fem, state.fem, predicted)]
    bodies = rigid_step.SolverBodies(
        inv_mass=np.concatenate([rigid_bodies.inv_mass, [p.inv_mass for p in proxies]]),
        inv_inertia=np.concatenate([rigid_bodies.inv_inertia, np.array([p.inv_inertia for p in proxies])]),
        position=np.concatenate([rigid_bodies.position, np.array([p.center for p in proxies])]),
        velocity=np.concatenate([rigid_bodies.velocity, np.array([p.velocity for p in proxies])]),
        velocity_at_t=np.concatenate([rigid_bodies.velocity_at_t, np.array([p.velocity for p in proxies])]),
        angular=np.concatenate([rigid_bodies.angular, np.array([p.angular for p in proxies])]),
        accel=np.concatenate([rigid_bodies.accel, np.zeros((nf, 3))]),
        static=np.concatenate([rigid_bodies.static, [p.inv_mass == 0 for p in proxies]]))

    # 4. contacts: rigid bodies among themselves and with planes; surface nodes with planes and
    #    rigid shapes (node k of the stacked surface nodes belongs to proxy nb + node_body[k])
    nodes = [m.surface_nodes for m in model.fem]
    node_body = np.concatenate([np.full(len(n), j) for j, n in enumerate(nodes)])
    node_x = np.concatenate([s.x[n] for s, n in zip(state.fem, nodes)])
    node_v = np.concatenate([p.v[n] for p, n in zip(predicted, nodes)])
    R = quat.to_matrix(rs.orientation)
    c_rigid = detect(rm, rs.position, R, rigid_step.reach(rm, rigid_bodies, h), model.settings.margin)
    fem_bodies = _fem_bodies(model)
    mu = np.array([b.friction for b in fem_bodies])[node_body]
    e = np.array([b.restitution for b in fem_bodies])[node_body]
    c_nodes = detect_points(rm, rs.position, R, node_x, np.linalg.norm(node_v, axis=1) * h,
                            model.settings.margin, mu, e)
    contact_node = c_nodes.body_a.copy()
    node_give = np.concatenate([_node_compliance(m, h)[n] for m, n in zip(model.fem, nodes)])
    c_nodes.body_a = nb + node_body[contact_node]
    contacts = concatenate(c_rigid, c_nodes, 0, 0)
    on_node = np.arange(contacts.count) >= c_rigid.count
    compliance = np.zeros(contacts.count)
    compliance[on_node] = node_give[contact_node]

    # 5. one contact resolution for everything; each deformable body answers the impulses on its
    #    nodes through its own implicit system (one back-substitution), and the contacts are
    #    solved again from the velocities that gives, so solver and elastic response agree
    res, applied = None, np.zeros((contacts.count, 3))
    for _ in range(COUPLING_ROUNDS):
        bias = np.zeros((contacts.count, 3))
        bias[on_node] = _deformation_velocity(proxies, node_body[contact_node], node_v[contact_node],
                                              contacts.point[on_node])
        if res is not None:     # solve again from the velocities the bodies really took
            bodies = rigid_step.SolverBodies(
                bodies.inv_mass, bodies.inv_inertia, bodies.position,
                np.concatenate([res.velocity[:nb], [p.velocity for p in proxies]]),
                np.concatenate([res.velocity[:nb], [p.velocity for p in proxies]]),
                np.concatenate([res.angular[:nb], [p.angular for p in proxies]]),
                bodies.accel, bodies.static)
        res = rigid_step.resolve_contacts(bodies, contacts, h, g, model.settings, previous=res,
                                          bias=bias, compliance=compliance)
        if not on_node.any():
            break
        total = res.collision_impulse + res.contact_impulse
        increment, applied = total - applied, total
        node_impulse = np.zeros((len(node_x), 3))
        np.add.at(node_impulse, contact_node, increment[on_node])
        if np.abs(node_impulse).max() == 0.0:
            break
        start = 0
        for j, (m, n) in enumerate(zip(model.fem, nodes)):
            jn = node_impulse[start:start + len(n)]
            start += len(n)
            if np.any(jn):
                impulse = np.zeros((m.node_count, 3))
                impulse[n] = jn
                predicted[j] = fem_dyn.apply_impulse(m, state.fem[j], predicted[j], impulse)
                proxies[j] = _proxy(m, state.fem[j], predicted[j].v)
        node_v = np.concatenate([p.v[n] for p, n in zip(predicted, nodes)])

    # 6. rigid drift; deformable bodies finish their step and take the proxy's position
    #    corrections (impacts at their time of impact, penetration recovery) as a rigid motion
    rigid_res = rigid_step.Resolution(*(a[:nb] for a in (
        res.velocity, res.angular, res.shift, res.shift_rotation, res.pseudo_velocity,
        res.pseudo_angular, res.impact_dv, res.momentum_fix)))
    new_rigid = rigid_step.drift(rm, rs, rigid_res, h, v)
    new_fem = []
    for j, (m, s, p) in enumerate(zip(model.fem, state.fem, predicted)):
        s_new = fem_dyn.finish(m, s, p, h)
        move = res.shift[nb + j] + h * res.pseudo_velocity[nb + j]
        turn = res.shift_rotation[nb + j] + h * res.pseudo_angular[nb + j]
        if np.any(move) or np.any(turn):
            c = m.node_mass @ s_new.x / m.node_mass.sum()
            x = s_new.x + move + np.cross(turn, s_new.x - c)
            R_fit, c_fit = fem_dyn.body_frame(m, x)      # the frame moves with the body
            s_new = s_new.replace(x=x, R=R_fit, c=c_fit)
        new_fem.append(s_new)
    return HybridState(rigid=new_rigid, fem=new_fem, time=state.time + h, steps=state.steps + 1)


class _Proxy:
    """Rigid stand-in of a deformable body for the contact solver (world frame, SI)."""
    __slots__ = ("inv_mass", "inv_inertia", "center", "velocity", "angular")


def _proxy(m, s, v):
    """Mass, inertia about the centre of mass, and the rigid part (P/M, I^-1 L) of velocities v.

    A body held by anchors does not move as a whole: its proxy is static."""
    p = _Proxy()
    mass = m.node_mass.sum()
    p.center = m.node_mass @ s.x / mass
    if m.anchored:
        p.inv_mass, p.inv_inertia = 0.0, np.zeros((3, 3))
        p.velocity, p.angular = np.zeros(3), np.zeros(3)
        return p
    r = s.x - p.center
    inertia = np.einsum("n,nij->ij", m.node_mass,
                        np.einsum("ni,ni->n", r, r)[:, None, None] * np.eye(3) - np.einsum("ni,nj->nij", r, r))
    p.inv_mass, p.inv_inertia = 1.0 / mass, np.linalg.inv(inertia)
    p.velocity = m.node_mass @ v / mass
    p.angular = p.inv_inertia @ np.cross(r, m.node_mass[:, None] * v).sum(axis=0)
    return p


def _node_compliance(m, h):
    """Each node's own give within a step in the contact solver (1/kg): 1/(a_M m_i), the give of
    a free particle, which no elastic response exceeds (A >= a_M M). The solver therefore never
    pushes harder than the body can answer (no energy is created at impacts), and the coupling
    rounds add what the stiffness of the body really resisted."""
    a_M, _ = fem_dyn.system_coefficients(m, h)
    return 1.0 / (a_M * m.node_mass)


def _deformation_velocity(proxies, body, node_v, point):
    """Node velocity minus the proxy's rigid velocity at the contact point, per node contact."""
    out = np.empty((len(body), 3))
    for j, p in enumerate(proxies):
        sel = body == j
        if sel.any():
            out[sel] = node_v[sel] - (p.velocity + np.cross(p.angular, point[sel] - p.center))
    return out


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
