"""Contacts between deformable bodies: surface nodes of one against the surface of another.

Each FEM body gets a signed-distance grid of its rest surface (rigid.sdf, built the first time
another body comes near it). A node of body A is tested against body B's grid in B's current
frame (floating frame: best-fit rotation and centre; anchored: the world), which follows B's rigid
motion exactly and gives the normal and the closest point of B's rest surface. B's side of the
contact is the surface node whose rest place is nearest that point, and the gap is measured to
where that node is now: a dent in B moves its surface away from A, and against the rest shape it
would look like a penetration (whose recovery, pushing single nodes, doubled the energy of two
soft bodies meeting head-on). Both nodes answer through their bodies' exact implicit response in
the contact solver. The impulse on B acts at its node rather than at the contact point, so the
pair's moment is off by the node's distance from that point (within half an edge): angular
momentum is kept to that order, linear momentum exactly.
"""
import numpy as np
from scipy.spatial import cKDTree

from rigid.contacts import combine_friction, combine_restitution
from rigid.sdf import SignedDistanceGrid


def _grid(m):
    grid = getattr(m, "_surface_grid", None)
    if grid is None:
        grid = SignedDistanceGrid.build(m.rest_points, m.surface)
        object.__setattr__(m, "_surface_grid", grid)
    return grid


def _rest_tree(m):
    """k-d tree of the body's surface nodes at their rest places (body coordinates)."""
    tree = getattr(m, "_surface_tree", None)
    if tree is None:
        tree = cKDTree(m.rest_points[m.surface_nodes])
        object.__setattr__(m, "_surface_tree", tree)
    return tree


def _reach(m, s):
    """Centre (3,) and radius (m) of a sphere holding the body's surface nodes."""
    x = s.x[m.surface_nodes]
    centre = x.mean(axis=0)
    return centre, float(np.sqrt(((x - centre) ** 2).sum(axis=1).max()))


def _moved(m, s):
    """How far the body's deformation moved its surface nodes from their rest places ``(s, 3)`` m,
    in its rest frame: X = R^T (x - c) + X_c (floating); anchored bodies: R = I, c = X_c."""
    return (s.x[m.surface_nodes] - s.c) @ s.R + m.rest_center - m.rest_points[m.surface_nodes]


def _against(mb, sb, moved, x, reach, radius=None):
    """Points ``x`` (p, 3) world (with ``radius`` (p,) m, default 0) against FEM body b's surface,
    those closer than ``reach`` (p,) m, ``moved`` being b's :func:`_moved`: ``(rows, nearest, point,
    normal, gap)``, ``nearest`` the index into ``mb.surface_nodes`` of b's side and ``normal``
    pointing from b towards the point."""
    radius = np.zeros(len(x)) if radius is None else radius
    X = (x - sb.c) @ sb.R + mb.rest_center                  # into b's rest frame
    phi, n_rest = _grid(mb).query(X)
    phi = phi - radius
    near = np.nonzero((phi < reach + np.sqrt((moved ** 2).sum(axis=1).max(initial=0.0)))
                      & np.any(n_rest != 0, axis=1))[0]
    # b's side: the surface node whose rest place is nearest the closest rest surface point; the
    # gap is measured to where that node is now (a dent in b moves its surface away)
    _, nearest = _rest_tree(mb).query(X[near] - (phi[near] + radius[near])[:, None] * n_rest[near])
    gap = phi[near] - np.einsum("ij,ij->i", moved[nearest], n_rest[near])
    hit = gap < reach[near]
    rows, nearest, gap = near[hit], nearest[hit], gap[hit]
    normal = n_rest[rows] @ sb.R.T
    point = x[rows] - (radius[rows] + 0.5 * gap)[:, None] * normal
    return rows, nearest, point, normal, gap


def _overlap(ca, ra, cb, rb, slack):
    return np.linalg.norm(ca - cb) <= ra + rb + slack


def detect_fem_pairs(models, states, bodies, node_offset, node_x, node_sweep, margin):
    """Node-against-surface contacts between every pair of nearby FEM bodies.

    node_offset[j]: index of body j's first surface node in the stacked node arrays node_x (k, 3)
    and node_sweep (k,) (how far each node may move this step). bodies: the scene bodies (for
    friction and restitution). Returns (node_a, node_b, point, normal, gap, friction, restitution)
    with node_a / node_b stacked node indices; normal points from b's body towards a.
    """
    out = [[] for _ in range(7)]
    if len(models) < 2:
        return _stacked(out)
    spheres = [_reach(m, s) for m, s in zip(models, states)]
    moved = {}
    for a, ma in enumerate(models):
        for b, (mb, sb) in enumerate(zip(models, states)):
            if a == b or not _overlap(*spheres[a], *spheres[b], margin + node_sweep.max(initial=0.0)):
                continue
            ia = np.arange(node_offset[a], node_offset[a] + len(ma.surface_nodes))
            ib = node_offset[b] + np.arange(len(mb.surface_nodes))
            reach = margin + node_sweep[ia] + node_sweep[ib].max(initial=0.0)
            if b not in moved:
                moved[b] = _moved(mb, sb)
            rows, nearest, point, normal, gap = _against(mb, sb, moved[b], node_x[ia], reach)
            _append(out, ia[rows], ib[nearest], point, normal, gap,
                    combine_friction(bodies[a].friction, bodies[b].friction),
                    combine_restitution(bodies[a].restitution, bodies[b].restitution))
    return _stacked(out)


def detect_rigid_points(rigid, position, rotation, rigid_sweep, models, states, bodies, node_offset,
                        node_sweep, margin):
    """Contact points of rigid bodies (their sample points, ``rigid.point_local``) against the
    surfaces of nearby FEM bodies: a rigid edge or corner pressing on a coarse FEM face between
    its nodes, which the nodes' own contacts do not see (a box on a slab one element wider than
    it balanced on a single node, tipped and sank in). position (b, 3), rotation (b, 3, 3):
    the rigid bodies' pose; rigid_sweep (b,) how far each may move this step (m).

    Returns (rigid body, stacked node, point, normal, gap, friction, restitution, point index),
    the normal pointing from the FEM body towards the rigid one.
    """
    out = [[] for _ in range(8)]
    if rigid.body_count == 0 or not models:
        return _stacked(out)
    spheres = [_reach(m, s) for m, s in zip(models, states)]
    for j, (mb, sb) in enumerate(zip(models, states)):
        ib = node_offset[j] + np.arange(len(mb.surface_nodes))
        slack = margin + node_sweep[ib].max(initial=0.0)
        moved = None
        for r in range(rigid.body_count):
            if not _overlap(position[r], rigid.body_radius[r] + rigid_sweep[r], *spheres[j], slack):
                continue
            at = np.arange(rigid.point_start[r], rigid.point_start[r + 1])
            x = position[r] + rigid.point_local[at] @ rotation[r].T
            reach = np.full(len(at), slack + rigid_sweep[r])
            moved = _moved(mb, sb) if moved is None else moved
            rows, nearest, point, normal, gap = _against(mb, sb, moved, x, reach, rigid.point_radius[at])
            # a point right over its node (within a tenth of the margin across the normal) is the
            # node's own contact with the rigid body; a second one there only slows the solver
            # (a box's corners on the benchmark slab's nodes: 20 sweeps instead of 9)
            offset = sb.x[mb.surface_nodes[nearest]] - x[rows]
            offset -= np.einsum("ij,ij->i", offset, normal)[:, None] * normal
            apart = np.linalg.norm(offset, axis=1) > 0.1 * margin
            rows, nearest, point, normal, gap = rows[apart], nearest[apart], point[apart], normal[apart], gap[apart]
            _append(out, np.full(len(rows), r), ib[nearest], point, normal, gap,
                    combine_friction(rigid.body_friction[r], bodies[j].friction),
                    combine_restitution(rigid.body_restitution[r], bodies[j].restitution), at[rows])
    return _stacked(out)


def _append(out, a, b, point, normal, gap, friction, restitution, *extra):
    if not len(a):
        return
    for o, value in zip(out, (a, b, point, normal, gap, np.full(len(a), friction),
                              np.full(len(a), restitution)) + extra):
        o.append(value)


def _stacked(out):
    if not out[0]:
        empty = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)),
                 np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0, np.int64))
        return empty[:len(out)]
    return tuple(np.concatenate(o) for o in out)
