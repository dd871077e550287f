"""Contacts between deformable bodies: surface nodes of one against the surface of another.

Each FEM body gets a signed-distance grid of its rest surface (rigid.sdf, built the first time
another body comes near it). A node of body A is tested against body B's grid in B's current frame
(floating frame: best-fit rotation and centre; anchored: the world), which follows B's rigid motion
exactly and gives the normal and the closest point of B's rest surface; the node's place is first
moved back by the displacement of B's surface node now nearest it, so a body bent by more than half
its thickness (a soft bridge under a box) is still met on the face the node touches, not the
opposite face its rest shape puts nearer (or, bent further, off the grid: the box fell through the
bridge, gaining 8 J). That point lies in one of B's rest surface triangles; B's side of the contact
is a place of that triangle now, the sum of its three nodes with barycentric weights: those of the
point's projection onto the triangle as it is now where that falls inside it (with the rest
surface's, the place slid off the point's normal line as B deformed, and a ball striking a soft
block lost 14% of the angular momentum), else the rest surface's. The normal turns with that
triangle, so a bent face is met along its bent normal. The gap is measured along it: a dent in B
moves its surface away from A (against the rest shape it would look like a penetration, whose
recovery, pushing single nodes, doubled the energy of two soft bodies meeting head-on), and it
changes continuously as A slides over B (measured to B's nearest node instead, it jumped by
millimetres when that node changed, and the recovery fed energy in). In the contact solver the place
moves with the weighted sum of its three nodes and its impulse goes to them in the same proportions
(rigid.solver.pgs, places), so the two sides' impulses act along one line: linear momentum is kept
exactly, and what angular momentum still changes is first order in the time step (1.6% at 1 ms,
0.66% at 0.5 ms for a soft block grazing a soft ball; tests/test_coupling.py).
"""
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from rigid.contacts import combine_friction, combine_restitution
from rigid.model import POINT_RING
from rigid.sdf import SignedDistanceGrid

from . import kernels, places, rest_grid

# queries of the nearest current surface node up to this many are answered by brute force
# (hybrid.coupling.kernels.nearest_rows_of) instead of a k-d tree built anew for the moved surface
BRUTE_NEAREST = 64
# queries of the rest surface's nearest nodes are answered by brute force
# (hybrid.coupling.kernels.nearest_three_rows) up to this many query-node pairs
BRUTE_PAIRS = 32768


def _grid(m):
    """Signed-distance grid of body m's rest surface, built once (``m.cache.surface_grid``)."""
    if m.cache.surface_grid is None:
        m.cache.surface_grid = SignedDistanceGrid.build(m.rest_points, m.surface)
    return m.cache.surface_grid


def _surface_index(m):
    """The body's rest surface for lookups, built once: a k-d tree of its surface nodes at rest
    (body coordinates), its triangles as indices into ``surface_nodes`` (f, 3), and the triangles
    around each surface node (s, d), padded with -1. Kept in ``m.cache.surface_index``."""
    found = m.cache.surface_index
    if found is None:
        tri = np.searchsorted(m.surface_nodes, m.surface)
        owner = tri.ravel()
        order = np.argsort(owner, kind="stable")
        owner, face = owner[order], np.repeat(np.arange(len(tri)), 3)[order]
        count = np.bincount(owner, minlength=len(m.surface_nodes))
        around = -np.ones((len(m.surface_nodes), max(1, count.max(initial=0))), dtype=np.int64)
        around[owner, np.arange(len(owner)) - np.repeat(np.cumsum(count) - count, count)] = face
        found = m.cache.surface_index = (cKDTree(m.rest_points[m.surface_nodes]), tri, around)
    return found


def _nearest_nodes(m, Y):
    """The (up to) three surface nodes of body m nearest each rest point Y (p, 3), nearest first:
    ``(p, 3)`` indices into ``surface_nodes``."""
    tree = _surface_index(m)[0]
    if len(Y) * tree.n <= BRUTE_PAIRS:
        return kernels.nearest_three_rows(tree.data, np.ascontiguousarray(Y, dtype=float))
    _, close = tree.query(Y, k=min(3, len(m.surface_nodes)))
    return np.asarray(close).reshape(len(Y), -1)


# a node touching a rigid body whose surface there turns more than this from the node's own face
# (cosine between the rigid normal and the node's inward normal) sits at a rigid edge or corner
EDGE_COS = np.cos(np.radians(70.0))


def contact_node_normals(models, states, node_offset, node_body, contacts):
    """Own outward unit normals ``(r, 3)`` of the surface nodes (side a) of the ``contacts`` with
    rigid bodies (side b >= 0), in their order (:func:`_node_normals`; zero where a node has none)."""
    return _stacked_normals(models, states, node_offset, node_body,
                            contacts.body_a[contacts.body_b >= 0], flat=False)


def smooth_node_normals(models, states, node_offset, node_body, stacked):
    """Own outward unit normals ``(k, 3)`` of the ``stacked`` surface nodes that lie on a smooth
    part of their body's surface; zero rows for those on its edges and corners (:func:`_node_normals`)."""
    return _stacked_normals(models, states, node_offset, node_body, stacked, flat=True)


def edge_normals(contacts, own, near):
    """Normals ``(c, 3)``, gaps ``(c,)`` and which contacts are met from the front ``(c,)`` bool,
    for surface nodes' ``contacts`` (stacked node a, rigid body b >= 0 or a plane).

    A node whose own face turns away from the rigid body by more than 110 degrees has the body
    behind it, on the far side of its own deformable body (the bottom face of a plate a ball comes
    down on): the body reaches it only through the nodes in front, and is not met from the front.
    Taken as a contact along the node's face normal, its distance read as a 3 cm penetration and
    the recovery threw the plate up at 11 m/s.
    A node where the rigid surface turns away from its own face by between 70 and 110 degrees, i.e.
    at or beside a rigid edge or corner, takes its own face's normal, and its gap is measured along
    it. There the rigid normal and distance turn by 90 degrees as the node moves by a micrometre: a
    box whose bottom edges sit on a slab's nodes was pushed sideways by them, or (nodes bulging out
    a few micrometres past the edge) was let sink by their distance to the edge onto the node under
    its middle, balanced there and tipped over, and a 5-box stack on the slab toppled. Nodes a
    little ahead of a sliding box, level with its bottom face, were met on its front face like a
    wall (a box sliding at 2 m/s lost 0.41 m/s in one step and stopped 36% short) while only those
    within a tenth of the contact margin of the edge were turned. Only a node within ``near`` (c,) m
    of the rigid surface (detect.edge_reach) is turned: the gap along its own normal is its height
    over the plane through the rigid body's nearest point, which at an edge is where the node meets
    it; a contact found farther out, ahead of a fast body within its reach, is not at an edge, and
    there that plane cuts through empty space (a soft cube flying beside a rigid ball, 10 cm apart
    at 40 m/s, read it as a 4 cm penetration and was pushed off its course) keeps the rigid
    normal and gap.
    A node without a face normal of its own (``own`` not a unit vector: its surface triangles
    cancel, an edge node or a vertex on the front of a crack that has not crossed the body) keeps
    the rigid body's normal and gap (its own, zero, made the contact's normal zero, and the
    contact solver divided by the length of the tangent built from it).
    ``own``: :func:`contact_node_normals` of ``contacts``. One pass (kernels.edge_turns)."""
    return kernels.edge_turns(contacts.normal, contacts.gap, contacts.body_b, own, float(EDGE_COS),
                              np.asarray(near, float))



def pair_edge_normals(models, states, node_offset, node_body, pairs, near, node_x):
    """Normals ``(c, 3)``, gaps ``(c,)`` and which are met from the front ``(c,)`` bool, of the
    node-against-face ``pairs`` (stacked node a, a place on another deformable body's face b), as
    :func:`edge_normals` gives them for rigid bodies (its ``near`` and angles apply): a node on a
    smooth part of its surface beside an edge or corner of b meets b along its own normal (a soft
    slab's nodes in the dent ahead of a soft block sliding on it met its front face as a wall: the
    block lost a third of its speed and tumbled); a node on an edge or corner of its own body (a
    spinning block's, grazing a ball) keeps the face's normal. A node whose own face, or for one on
    an edge or corner its triangles' mean normal, turns more than 110 degrees from b has b behind
    it (a shattered pane's top nodes read 4 mm inside a piece beside them and took 420 J of strain
    in one step; at a crack's corner a fresh piece's node met the plug beside it from behind, and
    dragged it along as it flew off). A turned node's gap is its height over its place now
    (``node_x`` (k, 3): the stacked nodes' positions), not the face's gap times the cosine between
    the normals, which measures a node beside b's face against its plane past its edge: a plate's
    nodes 5 mm beside a soft box's side face read its 4.7 mrad tilt as a 23 um penetration, 95 um
    under its bottom edge, and held that side up: the box rested balanced on its other edge."""
    own = _stacked_normals(models, states, node_offset, node_body, pairs.a)
    normal, gap, front = kernels.edge_turns(pairs.normal, pairs.gap, np.zeros(pairs.count, np.int64),
                                            own, float(EDGE_COS), np.asarray(near, float))
    turned = np.nonzero(np.any(normal != pairs.normal, axis=1))[0]
    place = np.einsum("cj,cja->ca", pairs.weights[turned], node_x[pairs.corners[turned]])
    gap[turned] = np.einsum("ca,ca->c", node_x[pairs.a[turned]] - place, normal[turned])
    edge = np.nonzero(np.einsum("ij,ij->i", own, own) < 0.5)[0]
    if len(edge):
        mean = _stacked_normals(models, states, node_offset, node_body, pairs.a[edge], flat=False)
        front[edge] &= np.einsum("ij,ij->i", pairs.normal[edge], mean) <= EDGE_COS
    return normal, gap, front


def _stacked_normals(models, states, node_offset, node_body, stacked, flat=True):
    """Own outward unit normals ``(k, 3)`` of the ``stacked`` surface nodes (:func:`_node_normals`),
    with ``flat`` only of those on a smooth part of their body's surface."""
    out = np.zeros((len(stacked), 3))
    for j in np.unique(node_body[stacked]):
        mine = node_body[stacked] == j
        out[mine] = _node_normals(models[j], states[j], stacked[mine] - node_offset[j], flat)
    return out


def _node_normals(m, s, local, flat=False):
    """Current outward unit normals ``(k, 3)`` of body m's surface nodes ``local`` (indices into
    ``surface_nodes``): the area-weighted normals of the triangles around each; with ``flat``,
    zero for a node some triangle around which turns more than 30 degrees from its normal (on an
    edge or a corner of its own body, where a node's normal is no surface's)."""
    _, tri, around = _surface_index(m)
    local = np.asarray(local, np.int64)
    if flat:
        return kernels.flat_node_normals(s.x, m.surface_nodes, tri, around, local,
                                         float(places.SHARP_COS))
    return kernels.node_normals(s.x, m.surface_nodes, tri, around, local)


def _motion(m, s):
    """The body's surface this step (:func:`hybrid.coupling.kernels.surface_motion`): centre (3,)
    and radius (m) of a sphere holding its surface nodes; how far its deformation moved them from
    their rest places ``(s, 3)`` m, in its rest frame (X = R^T (x - c) + X_c; anchored bodies: R =
    I, c = X_c), and the longest of those moves (m)."""
    centre, radius, moved, largest = kernels.surface_motion(
        s.x, m.surface_nodes, np.asarray(s.c, float), np.asarray(s.R, float), m.rest_center, m.rest_points)
    return centre, float(radius), moved, float(largest)


def _current_nearest(m, s, x):
    """The surface node of body m (index into ``surface_nodes``) nearest each world point x (p, 3)
    in its current shape ``s.x``. The k-d tree of the current surface is kept in
    ``m.cache.current_tree`` for the positions it was built from (its ``data``; a step's detection
    asks about the same positions more than once)."""
    if len(x) <= BRUTE_NEAREST:
        return kernels.nearest_rows_of(s.x, m.surface_nodes, np.asarray(x, float))
    surface = s.x[m.surface_nodes]
    tree = m.cache.current_tree
    if tree is None or not np.array_equal(tree.data, surface):
        tree = m.cache.current_tree = cKDTree(surface, balanced_tree=False, compact_nodes=False)
    return tree.query(x)[1] if len(x) else np.zeros(0, np.int64)


# a rigid point within this share of the contact margin of its nearest node, across the normal,
# is that node's contact (detect_rigid_points); one this share of that distance behind it is kept
OFF_NODE = 0.1
OFF_NODE_DEPTH = 0.01


def _against(mb, sb, motion, x, reach, radius=None, off_nodes=None, facing=None):
    """Points ``x`` (p, 3) world (with ``radius`` (p,) m, default 0) against FEM body b's surface,
    those closer than ``reach`` (p,) m, ``motion`` being b's :func:`_motion`: ``(rows, corners,
    weights, nearest, point, normal, gap)``. b's side is a place in its surface triangle ``corners``
    (indices into ``mb.surface_nodes``) with barycentric ``weights``; ``nearest`` is b's surface
    node nearest it (the contact's identity across steps); ``normal`` points from b towards x. With
    ``off_nodes`` (m), points within that distance of their nearest node across the normal are left
    out (that node's own contact covers them), unless they lie more than ``OFF_NODE_DEPTH *
    off_nodes`` behind it (under it: a box's edge sunk under a soft pad's rim node that slid out
    past it, which meets the box at its own height) or have a radius (a ball's centre: the node
    meets the ball along the ball's own normal, which tilts as the ball moves off it, so a ball
    resting right over a node of a flat face stood on a pin and rolled off it, faster by tenfold
    every 0.1 s, until it sank between the nodes and rolled on with the energy of the fall). ``facing`` (p, 3): the points' own outward unit
    normals (world; nodes of another deformable body), which choose the face they meet at b's sharp
    edges (places.places); None: none."""
    radius = np.zeros(len(x)) if radius is None else radius
    moved, largest = motion[2], motion[3]
    # into b's rest frame, less the deformation there: the displacement of b's surface node now
    # nearest each point (bent by more than its half thickness, b's rest surface would put a
    # point pressing on its top face nearer the bottom face, or off b's grid)
    # (a point exactly on an edge or a corner may find the grid's gradient zero, its neighbouring
    # samples cancelling: one within a cell of the surface stays, to be met along the faces
    # there, places.places; a place left without a unit normal is dropped, detect._movable)
    grid = _grid(mb)
    R = np.asarray(sb.R, float)
    nearest = _current_nearest(mb, sb, x)
    near, X, phi, n_rest = rest_grid.rest_query(
        x, nearest, moved, np.asarray(sb.c, float), R, mb.rest_center, grid.origin, grid.cell_size,
        grid.shape, grid.values, radius, reach, largest)
    if not len(near):
        return near, np.zeros((0, 3), np.int64), np.zeros((0, 3)), near, np.zeros((0, 3)), \
            np.zeros((0, 3)), np.zeros(0)
    Y = X[near] - (phi[near] + radius[near])[:, None] * n_rest[near]     # closest rest surface points
    close = _nearest_nodes(mb, Y)
    if off_nodes is not None:
        keep = np.nonzero(kernels.off_nodes_kept(sb.x, mb.surface_nodes, np.ascontiguousarray(close[:, 0]),
                                                 x[near], n_rest[near], R, off_nodes, OFF_NODE_DEPTH * off_nodes)
                          | (radius[near] > 0.0))[0]
        near, Y, close = near[keep], Y[keep], close[keep]
        if not len(near):
            return near, np.zeros((0, 3), np.int64), np.zeros((0, 3)), near, np.zeros((0, 3)), \
                np.zeros((0, 3)), np.zeros(0)
    local = moved[nearest]
    # its triangle; the normal turns with that triangle (a bent body's face is sloped where its
    # rest face was level: on the rest normal a frictionless ball stayed put on an 11 degree slope
    # of a sagging bridge), and the gap is measured along it to the place as it is now (a dent
    # in b moves its surface away). On an edge or a vertex the normal is turned with each
    # triangle around it, averaged (with the first triangle found alone, mirror-image corners
    # turned differently, and a soft cube hit face on by a rigid one left spinning about the
    # impact axis)
    # A point without a radius (a node, a rigid sample point) within a grid cell of the surface
    # is placed from itself as well as from Y, and keeps the place from itself where the two
    # gaps agree to half a cell: near the surface the grid's interpolated distance and gradient
    # put Y off the closest place (by 2% of an edge beside a cube's corner), and mirror-image
    # nodes met mirror-image places at different gaps; pressed into a thin fragment, the point
    # itself may lie nearer another face (a glass pane's pieces flew apart at 1e7 m/s).
    tree, tri, around = _surface_index(mb)
    P = tree.data                  # the surface nodes' rest positions (the tree keeps them)
    X_now = X[near] + local[near]
    # the points' own normals in b's rest frame, as X
    toward = np.zeros((len(near), 3)) if facing is None else facing[near] @ R
    corners, weights, n, gap = places.places(Y, close, around, tri, P, moved, n_rest[near], X_now,
                                              radius[near], toward)
    own = np.nonzero((radius[near] == 0.0) & (np.abs(phi[near]) <= grid.cell_size))[0]
    if len(own):
        mine = places.places(X[near[own]], close[own], around, tri, P, moved, n_rest[near[own]],
                              X_now[own], radius[near[own]], toward[own])
        keep = np.abs(mine[3] - gap[own]) <= 0.5 * grid.cell_size
        for whole, part in zip((corners, weights, n, gap), mine):
            whole[own[keep]] = part[keep]
    hit = gap < reach[near]
    rows, corners, weights, nearest, gap = near[hit], corners[hit], weights[hit], close[hit, 0], gap[hit]
    weights = _current_weights(sb.x[mb.surface_nodes[corners]], x[rows], weights)
    normal = n[hit] @ sb.R.T
    point = x[rows] - (radius[rows] + 0.5 * gap)[:, None] * normal
    return rows, corners, weights, nearest, point, normal, gap


def _current_weights(triangles, x, weights):
    """Barycentric weights ``(c, 3)`` of points ``x`` (c, 3) projected onto their triangles as they
    are now (``triangles`` (c, 3, 3), world), where the projection falls inside; elsewhere the
    ``weights`` found on the rest surface. Found on the rest surface, a place slides off the line
    through the point along the normal as the body deforms, and the two sides' impulses then turn
    each other: a ball striking a soft block off-centre lost 14% of the angular momentum."""
    a = triangles[:, 0]
    e0, e1, d = triangles[:, 1] - a, triangles[:, 2] - a, x - a
    d00, d01, d11 = (np.einsum("ci,ci->c", u, w) for u, w in ((e0, e0), (e0, e1), (e1, e1)))
    d20, d21 = np.einsum("ci,ci->c", d, e0), np.einsum("ci,ci->c", d, e1)
    den = d00 * d11 - d01 * d01
    ok = den > 1e-12 * (d00 * d11 + 1e-300)
    safe = np.where(ok, den, 1.0)
    v, w = (d11 * d20 - d01 * d21) / safe, (d00 * d21 - d01 * d20) / safe
    now = np.column_stack([1.0 - v - w, v, w])
    inside = ok & (now >= 0.0).all(axis=1)
    return np.where(inside[:, None], now, weights)


@dataclass
class SurfaceContacts:
    """Contacts of side a (a stacked surface node, or a rigid body) with places on FEM surfaces
    (side b). ``corners`` (c, 3) are the stacked surface nodes of b's triangle and ``weights``
    (c, 3) the place's barycentric weights in it; ``nearest`` (c,) the stacked node of b nearest
    the place (the contact's identity across steps); ``sample`` (c,) the rigid sample point
    (``rigid.point_local`` index) for rigid side a, else -1. point, normal (from b towards a),
    gap, friction and restitution as in :class:`rigid.contacts.Contacts`."""
    a: np.ndarray
    corners: np.ndarray
    weights: np.ndarray
    nearest: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    gap: np.ndarray
    friction: np.ndarray
    restitution: np.ndarray
    sample: np.ndarray

    @staticmethod
    def stacked(parts):
        """One :class:`SurfaceContacts` of ``parts`` (a list of them) in order; empty if none."""
        if not parts:
            return SurfaceContacts(np.zeros(0, np.int64), np.zeros((0, 3), np.int64), np.zeros((0, 3)),
                                   np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)),
                                   np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0, np.int64))
        return SurfaceContacts(*(np.concatenate(p) for p in zip(*parts)))

    @property
    def count(self):
        """Number of contacts."""
        return len(self.gap)


def detect_fem_pairs(models, states, bodies, node_offset, node_x, node_sweep, margin):
    """Node-against-surface contacts between every pair of nearby FEM bodies.

    node_offset[j]: index of body j's first surface node in the stacked node arrays node_x (k, 3)
    and node_sweep (k,) (how far each node may move this step). bodies: the scene bodies (for
    friction and restitution). Returns :class:`SurfaceContacts` with ``a`` the stacked node.
    Each body's surface is queried once, with the nodes of every other body near it (a shattered
    part of 17 pieces pressing on each other made 270 pairs, each a query of its own).
    """
    parts = []
    if len(models) < 2:
        return SurfaceContacts.stacked(parts)
    node_body = np.repeat(np.arange(len(models)), np.diff(node_offset))
    mu = np.array([body.friction for body in bodies])
    e = np.array([body.restitution for body in bodies])
    for b, (mb, sb) in enumerate(zip(models, states)):
        ib = np.arange(node_offset[b], node_offset[b + 1])
        motion = _motion(mb, sb)
        centre, radius = motion[0], motion[1]
        slack = margin + node_sweep[ib].max(initial=0.0)
        # other bodies' nodes within reach of b's bounding sphere
        near = np.nonzero((node_body != b) & (np.linalg.norm(node_x - centre, axis=1)
                                              <= radius + slack + node_sweep))[0]
        if not len(near):
            continue
        found = _against(mb, sb, motion, node_x[near], slack + node_sweep[near],
                         facing=_stacked_normals(models, states, node_offset, node_body, near))
        rows, corners, weights, nearest, point, normal, gap = found
        a = near[rows]
        _append(parts, a, ib[corners], weights, ib[nearest], point, normal, gap,
                combine_friction(mu[node_body[a]], mu[b]), combine_restitution(e[node_body[a]], e[b]),
                np.full(len(rows), -1))
    return SurfaceContacts.stacked(parts)


def detect_rigid_points(rigid, position, rotation, rigid_sweep, models, states, bodies, node_offset,
                        node_sweep, margin):
    """Contact points of rigid bodies (their sample points, ``rigid.point_local``) against the
    surfaces of nearby FEM bodies: a rigid edge or corner pressing on a coarse FEM face between
    its nodes, which the nodes' own contacts do not see (a box on a slab one element wider than
    it balanced on a single node, tipped and sank in). position (b, 3), rotation (b, 3, 3):
    the rigid bodies' pose; rigid_sweep (b,) how far each may move this step (m).

    Returns :class:`SurfaceContacts` with ``a`` the rigid body, the normal pointing from the FEM
    body towards it.
    """
    parts = []
    if rigid.body_count == 0 or not models:
        return SurfaceContacts.stacked(parts)
    for j, (mb, sb) in enumerate(zip(models, states)):
        ib = node_offset[j] + np.arange(len(mb.surface_nodes))
        slack = margin + node_sweep[node_offset[j]:node_offset[j + 1]].max(initial=0.0)
        motion = _motion(mb, sb)
        centre, radius = motion[0], motion[1]
        # every sample point of the rigid bodies whose bounding spheres reach this body, at once
        near = np.nonzero(np.linalg.norm(position - centre, axis=1)
                          <= rigid.body_radius + rigid_sweep + radius + slack)[0]
        if not len(near):
            continue
        # a cylinder meets deformable faces with its side's vertices, not the rings they lie on
        owner, at, x = kernels.sample_points(near, rigid.point_start, rigid.point_local, rigid.point_kind,
                                             POINT_RING, position, np.asarray(rotation, float))
        # a point right over a node (within a tenth of the margin across the normal) is that
        # node's own contact with the rigid body; a second one there only slows the solver
        # (a box's corners on the benchmark slab's nodes: 20 sweeps instead of 9)
        rows, corners, weights, nearest, point, normal, gap = _against(
            mb, sb, motion, x, slack + rigid_sweep[owner], rigid.point_radius[at], OFF_NODE * margin)
        r = owner[rows]
        _append(parts, r, ib[corners], weights, ib[nearest], point, normal, gap,
                combine_friction(rigid.body_friction[r], bodies[j].friction),
                combine_restitution(rigid.body_restitution[r], bodies[j].restitution), at[rows])
    return SurfaceContacts.stacked(parts)


def _append(parts, a, corners, weights, nearest, point, normal, gap, friction, restitution, sample):
    if len(a):
        parts.append((a, corners, weights, nearest, point, normal, gap,
                      np.broadcast_to(friction, len(a)), np.broadcast_to(restitution, len(a)), sample))
