"""Auto bodies switching between FEM and rigid (when: :mod:`hybrid.coupling.auto`).

    model, state, events = rigidify(model, state, bodies)    # FEM bodies -> rigid bodies
    model, state, events = elastify(model, state, indices)   # rigid auto bodies -> FEM bodies

A body turned rigid keeps its deformed shape (its sag under load stays in it): its surface is the
FEM surface where the nodes are, its mass, centre of mass and inertia those of its own mass
matrix (lumped or consistent) there, so its linear and angular momentum carry over exactly (and its kinetic energy, for
a velocity field that was rigid); an anchored body becomes a fixed one. Its FEM model and state
are kept, parked in ``HybridModel.parked`` (the model keeps its factorisation): turned back, it
resumes from that deformed shape carried along by the rigid motion since, with the rigid velocity
field as its node velocities and its plastic strain unchanged.
"""
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial import ConvexHull, QhullError, cKDTree

from fem import dynamics as fem_dyn
from fem.momentum import skew
from fem.stress import inverse_deformation_gradients
from rigid import quaternion as quat
from rigid.build import RigidBodyDesc, build_rigid
from rigid.compose import append_bodies, take_bodies
from rigid.model import angular_velocity, report_offset, reported_velocity
from rigid.trimesh import compact

from .auto import Switch, settings, unit_strain
from .fracture import fracture_data


# a vertex within EDGE_TOL of a body's size of two hull facets meeting at more than EDGE_ANGLE
# (rad) lies on a hull edge (hull_points)
EDGE_TOL = 1e-3
EDGE_ANGLE = np.radians(30.0)
EDGE_BLOCK = 1024          # vertices measured against every facet at once


def hull_points(vertices):
    """``(on, off)``: the vertices ``(p, 3)`` on the convex hull of ``vertices`` (all of them for
    a flat set) and the others ``(q, 3)``. A body turned rigid meets planes and rigid bodies
    through the hull's: a plane or a convex part of another body meets a body first at its hull;
    a convex corner of another body pressing into a hollow of this one is found from that body's
    points against this one's distance grid (both directions are tested), so only hollows meeting
    hollows go unseen. A box-like soft body's resting face has about a third of its vertices on
    the hull; its contact rows shrink alike. Against FEM surfaces it meets with all of them, as it
    did while deformable: an FEM deck resting across a support that turned rigid was carried by
    the support's dented edge nodes, which are off the hull, and sagged 2 mm when they went."""
    try:
        hull = ConvexHull(vertices)
    except QhullError:
        return vertices, vertices[:0]
    on = np.zeros(len(vertices), bool)
    on[hull.vertices] = True
    on |= _on_hull_edges(vertices, hull.equations)
    return vertices[on], vertices[~on]


def _on_hull_edges(vertices, facets):
    """Which ``vertices`` lie on an edge of their hull (within EDGE_TOL of its size of two of
    its facets (``facets`` (f, 4): unit normal, offset) whose normals differ by more than
    EDGE_ANGLE): a box's edge nodes between its corners. Box-like bodies stacked with an offset
    rest on each other's edges, and their corners alone, on edges that nearly coincided with
    the other's, met it with tilted normals: the upper one of two auto boxes turned rigid under
    a third sank into the lower one at g / 8."""
    size = np.ptp(vertices, axis=0).max()
    out = np.zeros(len(vertices), bool)
    for start in range(0, len(vertices), EDGE_BLOCK):          # (v, f) in blocks of vertices
        block = vertices[start:start + EDGE_BLOCK]
        near = np.abs(block @ facets[:, :3].T + facets[:, 3]) < EDGE_TOL * size
        for i in np.flatnonzero(near.sum(axis=1) >= 2):
            normals = facets[near[i], :3]
            out[start + i] = (normals @ normals.T).min() < np.cos(EDGE_ANGLE)
    return out


@dataclass(frozen=True)
class Parked:
    """An auto body stepped as a rigid body, as it was when it became rigid.

    fem: its FemModel (factorised). state: its FemState then. fracture: its
    hybrid.coupling.fracture.FractureBody (or None). position (3,) m, rotation (3, 3): the rigid
    body's pose then. local: (n, 3) m its nodes in the rigid body's frame. surface_nodes (s,) and
    tree (a cKDTree of their ``local``): to find the node nearest a contact point. inverse_F
    (t, 3, 3): its elements' inverse deformation gradients then (the predicted strain's).
    unit_strain: the strain measure a unit impulse gives it at most (hybrid.coupling.auto.unit_strain).
    patches: per contact partner it rested on then (scene index, -1: a plane or static ground),
    the surface nodes that carried that partner's load (hybrid.coupling.auto.predicted_strain).
    """
    fem: object
    state: object
    fracture: object
    position: np.ndarray
    rotation: np.ndarray
    local: np.ndarray
    surface_nodes: np.ndarray
    tree: object
    inverse_F: np.ndarray
    unit_strain: float
    patches: dict = field(default_factory=dict)

    def nodes_at(self, position, rotation):
        """The nodes ``(n, 3)`` m where the rigid body at pose (position, rotation) has them."""
        return position + self.local @ rotation.T


def _drop(values, index):
    """A per-FEM-body tuple without the entries of ``index`` (None stays None)."""
    return None if values is None else tuple(v for j, v in enumerate(values) if j not in index)


def _rigid_bodies(model, state, bodies):
    """RigidModel/RigidState of FEM ``bodies`` as rigid bodies, momentum carried over."""
    descs = []
    for j in bodies:
        m, s, k = model.fem[j], state.fem[j], model.fem_ids[j]
        scene_body = model.scene.bodies[k]
        vertices, triangles, _ = compact(s.x, m.surface)
        hull, others = hull_points(vertices)
        weights = fem_dyn.mass_weights(m)
        centre = weights @ s.x / weights.sum()
        inertia = fem_dyn.mass_moments(m, s.x - centre, s.v)[0]      # (with its own mass matrix)
        descs.append(RigidBodyDesc(name=model.names[k], vertices=vertices, triangles=triangles,
                                   density=m.density, friction=scene_body.friction,
                                   restitution=scene_body.restitution, fixed=m.has_anchors,
                                   mass_properties=(weights.sum(), centre, inertia),
                                   contact_points=hull, fem_contact_points=others))
    rm, rs = build_rigid(descs, [])
    last_dt = state.rigid.last_dt
    for i, j in enumerate(bodies):
        m, s = model.fem[j], state.fem[j]
        if rm.body_fixed[i]:
            continue
        momentum = fem_dyn.mass_weights(m) @ s.v
        # leapfrog keeps the mid-step velocity; what reporting adds to it (half a step of gravity
        # less the contact's support against it, rigid.model.report_offset) is taken off, so the
        # body reports its FEM momentum; a body resting on the ground goes on taking its weight
        touched = state.touches.of_body(model.fem_ids[j])[2] if state.touches is not None else ()
        rs.contact_dv[i] = np.sum(touched, axis=0) / rm.body_mass[i] if len(touched) else 0.0
        rs.last_dt = last_dt
        rs.velocity[i] = momentum / rm.body_mass[i] - report_offset(rm, rs, model.gravity)[i]
        rs.angular_momentum[i] = fem_dyn.mass_moments(m, s.x - rs.position[i], s.v)[1]
    return rm, rs


def _patches(touches, k, fem, tree, position, rotation):
    """Per partner of body ``k`` in ``touches`` (its last FEM step's contacts), the surface nodes
    of ``fem`` whose contacts carried a load (the body's pose ``position``, ``rotation``; ``tree``
    of its surface nodes in that frame)."""
    if touches is None:
        return {}
    partner, point, impulse = touches.of_body(k)
    carrying = np.any(impulse != 0.0, axis=1)
    if not carrying.any():
        return {}
    nodes = fem.surface_nodes[tree.query((point[carrying] - position) @ rotation)[1]]
    partner = partner[carrying]
    return {int(p): np.unique(nodes[partner == p]) for p in np.unique(partner)}


def rigidify(model, state, bodies):
    """Turn the FEM auto ``bodies`` (indices into model.fem) into rigid bodies; returns the new
    model, state and their Switch events."""
    if not bodies:
        return model, state, []
    rm, rs = _rigid_bodies(model, state, bodies)
    model = replace(model, fracture=fracture_data(model))       # each body's own goes parked with it
    parked = dict(model.parked)
    for i, j in enumerate(bodies):
        m, s = model.fem[j], state.fem[j]
        R = quat.to_matrix(rs.orientation[i])
        local = (s.x - rs.position[i]) @ R
        inverse_F = inverse_deformation_gradients(m, s.x)
        tree = cKDTree(local[m.surface_nodes])
        parked[model.fem_ids[j]] = Parked(m, s, model.fracture[j], rs.position[i].copy(), R, local,
                                          m.surface_nodes, tree, inverse_F,
                                          unit_strain(m, s, inverse_F, model.dt),
                                          _patches(state.touches, model.fem_ids[j], m, tree,
                                                   rs.position[i], R))
    rigid, rigid_state = append_bodies(model.rigid, state.rigid, rm, rs)
    gone = set(bodies)
    keep = [j for j in range(len(model.fem)) if j not in gone]
    new_model = replace(model, rigid=rigid, rigid_ids=np.concatenate(
        [model.rigid_ids, [model.fem_ids[j] for j in bodies]]).astype(int),
        fem=[model.fem[j] for j in keep], fem_ids=[model.fem_ids[j] for j in keep],
        fracture=_drop(model.fracture, gone), parked=parked)
    since = dict(state.rigid_since) | {model.fem_ids[j]: state.steps for j in bodies}
    new_state = replace(state, rigid=rigid_state, fem=[state.fem[j] for j in keep],
                        contact_memory=None, rigid_since=since, resting=_drop(state.resting, gone),
                        contact_sets=_drop(state.contact_sets, gone),
                        fracture_pending=_drop(state.fracture_pending, gone))
    events = [Switch(float(state.time), model.names[model.fem_ids[j]], "rigidify") for j in bodies]
    return new_model, new_state, events


def fem_state(parked, rm, rs, i, gravity):
    """The FemState of parked body at rigid index ``i``: its parked shape moved by the rigid
    motion since, node velocities the rigid velocity field now."""
    s = parked.state
    if rm.body_fixed[i]:
        return s.replace(v=np.zeros_like(s.v), time=rs.time)
    R = quat.to_matrix(rs.orientation[i])
    position = rs.position[i]
    x = parked.nodes_at(position, R)
    v_c = reported_velocity(rm, rs, gravity)[i]
    w = angular_velocity(rm, rs)[i]
    turn = R @ parked.rotation.T
    return s.replace(x=x, v=v_c + (x - position) @ skew(w).T, R=turn @ s.R,
                     c=position + turn @ (s.c - parked.position), time=rs.time)


# most a body's calm window is stretched by when it keeps turning back soon after turning rigid
MAX_BACKOFF = 64


def _backoff(model, state, indices):
    """``state.backoff`` after the bodies ``indices`` turn deformable: doubled (at most
    MAX_BACKOFF) for one that turns back within its window of turning rigid, reset for one that
    stayed rigid longer."""
    out = dict(state.backoff)
    for k in indices:
        window = settings(model, k).window * out.get(k, 1)
        soon = state.steps - state.rigid_since.get(k, -10 ** 9) <= window
        out[k] = min(2 * out.get(k, 1), MAX_BACKOFF) if soon else 1
    return out


def elastify(model, state, indices):
    """Turn the rigid auto bodies of scene ``indices`` back into FEM bodies; returns the new
    model, state and their Switch events."""
    if not indices:
        return model, state, []
    rm, rs = model.rigid, state.rigid
    at = [int(np.flatnonzero(model.rigid_ids == k)[0]) for k in indices]
    fems = [model.parked[k].fem for k in indices]
    states = [fem_state(model.parked[k], rm, rs, i, model.gravity) for k, i in zip(indices, at)]
    keep = [i for i in range(rm.body_count) if i not in at]
    rigid, rigid_state = take_bodies(rm, rs, keep)
    parked = {k: p for k, p in model.parked.items() if k not in indices}
    fracture = tuple(fracture_data(model)) + tuple(model.parked[k].fracture for k in indices)
    new_model = replace(model, rigid=rigid, rigid_ids=model.rigid_ids[keep],
                        fem=list(model.fem) + fems, fem_ids=list(model.fem_ids) + list(indices),
                        fracture=fracture, parked=parked)
    more = (None,) * len(indices)
    pending = None if state.fracture_pending is None else \
        tuple(state.fracture_pending) + tuple(np.zeros((0, 2), np.int64) for _ in indices)
    new_state = replace(state, rigid=rigid_state, fem=list(state.fem) + states,
                        contact_memory=None,
                        resting=None if state.resting is None else tuple(state.resting) + more,
                        contact_sets=None if state.contact_sets is None else tuple(state.contact_sets) + more,
                        fracture_pending=pending,
                        calm={k: c for k, c in state.calm.items() if k not in indices},
                        backoff=_backoff(model, state, indices),
                        fem_since=dict(state.fem_since) | {k: state.steps for k in indices})
    events = [Switch(float(state.time), model.names[k], "elastify") for k in indices]
    return new_model, new_state, events
