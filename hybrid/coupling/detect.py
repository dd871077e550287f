"""Contact detection of the coupled step: rigid bodies among themselves and with planes; surface
nodes of deformable bodies against planes, rigid shapes and other deformable bodies' faces; rigid
corners and edges against deformable faces."""
from dataclasses import dataclass, fields

import numpy as np

from rigid import quaternion as quat
from rigid import step as rigid_step
from rigid.contacts import Contacts, detect, detect_points

from .fem_contact import (EDGE_COS, OFF_NODE, SurfaceContacts, contact_node_normals, detect_fem_pairs,
                          detect_rigid_points, edge_normals, pair_edge_normals, smooth_node_normals)
from .nodes import element_size, row_norms


@dataclass
class Found:
    """Every contact of a step, in the index space of its kind.

    rigid: rigid bodies against rigid bodies and planes (rigid body indices).
    nodes: stacked surface nodes (side a) against planes (-1) and rigid bodies (side b).
    nodes_static (nodes.count,) bool: side b is static (a plane or a fixed rigid body).
    pairs: stacked surface nodes against places on other deformable bodies' surface triangles.
    on_faces: rigid sample points (side a, rigid bodies) against places on deformable faces.
    corners (q, 3) stacked nodes and weights (q, 3): the places of pairs then on_faces.
    in_others: stacked nodes in a contact with another deformable body or a rigid point.
    """
    rigid: Contacts
    nodes: Contacts
    nodes_static: np.ndarray
    pairs: SurfaceContacts
    on_faces: SurfaceContacts
    corners: np.ndarray
    weights: np.ndarray
    in_others: np.ndarray


def fem_bodies(model):
    """The scene bodies of the FEM bodies, in FEM body order."""
    return [model.scene.bodies[i] for i in model.fem_ids]


def detect_all(model, state, nodes, rigid_bodies, h, rotation=None):
    """Every contact of the step (:class:`Found`): ``nodes`` are the stacked surface nodes
    (:class:`hybrid.coupling.nodes.SurfaceNodes`), ``rigid_bodies`` the rigid solver bodies after
    the kick; ``rotation`` (b, 3, 3) the rigid bodies' rotations, if already at hand."""
    rm, rs, margin = model.rigid, state.rigid, model.settings.margin
    R = quat.to_matrix(rs.orientation) if rotation is None else rotation
    rigid_sweep = rigid_step.reach(rm, rigid_bodies, h)
    c_rigid = detect(rm, rs.position, R, rigid_sweep, margin)
    bodies = fem_bodies(model)
    mu = np.array([b.friction for b in bodies])[nodes.body]
    e = np.array([b.restitution for b in bodies])[nodes.body]
    sweep = row_norms(nodes.v, float(h))      # how far each node may move this step
    c_nodes = detect_points(rm, rs.position, R, nodes.x, sweep, rigid_sweep, margin, mu, e)
    own = contact_node_normals(model.fem, state.fem, nodes.offset, nodes.body, c_nodes)
    c_nodes = _facing_faces(model, nodes, c_nodes, own,
                            lambda k, toward: detect_points(rm, rs.position, R, nodes.x[k], sweep[k],
                                                            rigid_sweep, margin, mu[k], e[k], toward))
    # at rigid edges along the node's own face normal (fem_contact.edge_normals); kept: met from
    # the front, and not an anchored node against static ground (nothing moves there)
    reach = edge_reach(model.fem, nodes.body, margin)
    c_nodes.normal, c_nodes.gap, front = edge_normals(c_nodes, own, reach[c_nodes.body_a])
    anchored = np.concatenate([m.node_anchor[n] >= 0 for m, n in zip(model.fem, nodes.per_body)]) \
        if len(model.fem) != 1 else model.fem[0].node_anchor[nodes.per_body[0]] >= 0
    c_nodes = c_nodes.take(np.nonzero(front & ~(anchored[c_nodes.body_a] & static_side(rm, c_nodes.body_b)))[0])
    # surface nodes against other deformable bodies' faces; rigid corners and edges against them
    # (the rigid body is side a); side b is a place in a surface triangle
    pairs = detect_fem_pairs(model.fem, state.fem, bodies, nodes.offset, nodes.x, sweep, margin)
    pairs.normal, pairs.gap, front = pair_edge_normals(model.fem, state.fem, nodes.offset, nodes.body,
                                                       pairs, reach[pairs.a], nodes.x)
    pairs = _movable(pairs, anchored[pairs.a], anchored, front)
    on_faces = detect_rigid_points(rm, rs.position, R, rigid_sweep, model.fem, state.fem, bodies,
                                   nodes.offset, sweep, margin)
    fixed = rm.body_fixed[on_faces.a] if rm.body_count else np.zeros(on_faces.count, bool)
    on_faces = _movable(on_faces, fixed, anchored)
    c_nodes = _under_rounded(model, state, nodes, c_nodes, on_faces, OFF_NODE * margin)
    corners = np.concatenate([pairs.corners, on_faces.corners])
    weights = np.concatenate([pairs.weights, on_faces.weights])
    return Found(rigid=c_rigid, nodes=c_nodes, nodes_static=static_side(rm, c_nodes.body_b),
                 pairs=pairs, on_faces=on_faces, corners=corners, weights=weights,
                 in_others=np.concatenate([pairs.a, corners[weights > 0]]))


def edge_reach(models, node_body, margin):
    """How near its contact a stacked surface node is turned at an edge (fem_contact.edge_normals),
    per node (n,) m: the contact margin, but no more than its body's element size (the edge of
    a regular tet of its mean volume). The margin is absolute: a millimetre cube 3 mm from a
    rigid ball 0.5 mm across, within the default 5 mm, had nodes beside its edges turned to their
    own normals, which read their 3 mm gaps as 0.6 mm inside the ball, and the recovery pulled
    the two together."""
    if len(models) == 1:
        return np.full(len(node_body), min(float(margin), element_size(models[0])))
    return np.minimum(float(margin), np.array([element_size(m) for m in models]))[node_body]


def _facing_faces(model, nodes, c_nodes, own, detect_again):
    """The node contacts with rigid shapes, those at a shape's edge or corner that took a face
    turned away from the node's own face met instead on the face facing it. The shape's edge ties
    break towards the node itself, and a soft cube's front edge nodes, bulging a micrometre past
    a rigid cube's side faces, took those faces and were dropped as met from behind
    (edge_normals): the cubes, face on, parted turning. ``detect_again(k, toward)`` detects
    stacked nodes ``k`` again with ties broken towards the points ``toward`` (far behind each
    node along its own inward normal); ``own``: the contacts' nodes' own normals
    (fem_contact.contact_node_normals)."""
    at = np.nonzero(c_nodes.body_b >= 0)[0]
    if not len(at):
        return c_nodes
    node = c_nodes.body_a[at]
    away = np.einsum("ij,ij->i", c_nodes.normal[at], own) > EDGE_COS       # (n . -own < -EDGE_COS)
    if not away.any():
        return c_nodes
    k, first = np.unique(node[away], return_index=True)
    far = 1e3 * float(model.rigid.body_radius.max()) + 1.0
    again = detect_again(k, nodes.x[k] - far * own[away][first])
    found = {(int(k[a]), int(b)): i for i, (a, b) in enumerate(zip(again.body_a, again.body_b))}
    for i in at[away]:
        j = found.get((int(c_nodes.body_a[i]), int(c_nodes.body_b[i])))
        if j is not None:
            c_nodes.normal[i], c_nodes.gap[i], c_nodes.point[i] = again.normal[j], again.gap[j], again.point[j]
    return c_nodes


def _under_rounded(model, state, nodes, c_nodes, on_faces, off):
    """The node contacts ``c_nodes``, those of a node on a smooth part of its surface right under a
    rounded rigid point (a ball's centre, a point of a capsule's axis) that meets the faces around
    the node (``on_faces``, within ``off`` m of the node across the normal) met along the node's
    own normal, as the ball meets those faces: the gap is the height of the ball's surface over
    the node along it, the point straight under the ball's centre (no lever about it). Along the
    ball's own normal, which tilts as the ball moves off the node, a ball laid on a flat plate
    right over a node stood on a pin and rolled off it, faster tenfold every 0.1 s, until it sank
    onto the faces around and rolled on with the energy of that fall."""
    if not c_nodes.count or not on_faces.count:
        return c_nodes
    radius = model.rigid.point_radius[on_faces.sample]
    f = np.nonzero(radius > 0.0)[0]
    if not len(f):
        return c_nodes
    d = nodes.x[on_faces.nearest[f]] - on_faces.point[f]
    across = d - np.einsum("ij,ij->i", d, on_faces.normal[f])[:, None] * on_faces.normal[f]
    f = f[np.einsum("ij,ij->i", across, across) <= off * off]
    if not len(f):
        return c_nodes
    span = model.rigid.body_count + 1           # (node, rigid body) keys; one point per key
    keys, first = np.unique(on_faces.nearest[f] * span + on_faces.a[f], return_index=True)
    key = c_nodes.body_a * span + c_nodes.body_b
    at = np.minimum(np.searchsorted(keys, key), len(keys) - 1)
    mine = np.nonzero((c_nodes.body_b >= 0) & (keys[at] == key))[0]
    f = f[first[at[mine]]]
    own = smooth_node_normals(model.fem, state.fem, nodes.offset, nodes.body, c_nodes.body_a[mine])
    r = radius[f]
    centre = on_faces.point[f] + (r + 0.5 * on_faces.gap[f])[:, None] * on_faces.normal[f]
    d = centre - nodes.x[c_nodes.body_a[mine]]
    up = np.einsum("ij,ij->i", d, own)
    side = np.einsum("ij,ij->i", d, d) - up * up
    ok = np.any(own != 0.0, axis=1) & (side < r * r)
    mine, own, centre, r = mine[ok], own[ok], centre[ok], r[ok]
    gap = up[ok] - np.sqrt(r * r - side[ok])
    c_nodes.normal[mine], c_nodes.gap[mine] = -own, gap
    c_nodes.point[mine] = centre - (r + 0.5 * gap)[:, None] * own
    return c_nodes


def _movable(found, a_immovable, anchored, front=None):
    """The contacts of ``found`` (:class:`SurfaceContacts` with places on side b) that can move:
    not those whose side a (``a_immovable`` (c,) bool: an anchored node, a fixed rigid body) and
    whose place (every corner it has weight on anchored, stacked nodes ``anchored``) are both
    held, which no impulse can move (no effective mass); nor those without a unit normal (a
    place on an edge between two faces turned opposite ways); nor, with ``front`` (c,) bool,
    those not met from the front (fem_contact.pair_edge_normals)."""
    if found.count == 0:
        return found
    held_place = np.all(anchored[found.corners] | (found.weights <= 0.0), axis=1)
    unit = np.abs(np.einsum("ij,ij->i", found.normal, found.normal) - 1.0) < 1e-6
    keep = unit & ~(a_immovable & held_place)
    if front is not None:
        keep &= front
    if keep.all():
        return found
    return type(found)(*(getattr(found, f.name)[keep] for f in fields(found)))


def static_side(rigid_model, body_b):
    """``(c,)`` bool: side b is static (a plane, or a fixed rigid body)."""
    if rigid_model.body_count == 0:
        return body_b < 0
    return (body_b < 0) | rigid_model.body_fixed[np.maximum(body_b, 0)]
