"""Contacts between deformable bodies: surface nodes of one against the surface of another.

Each FEM body gets a signed-distance grid of its rest surface (rigid.sdf, built the first time
another body comes near it). A node of body A is tested against body B's grid in B's current
frame (floating frame: best-fit rotation and centre; anchored: the world), which follows B's rigid
motion exactly and its deformation to first order. The contact acts on A's node and on B's
surface node nearest to the contact point; both answer through their bodies' exact implicit
response in the contact solver.
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


def _reach(m, s):
    """Centre (3,) and radius (m) of a sphere holding the body's surface nodes."""
    x = s.x[m.surface_nodes]
    centre = x.mean(axis=0)
    return centre, float(np.sqrt(((x - centre) ** 2).sum(axis=1).max()))


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
    for a, (ma, sa) in enumerate(zip(models, states)):
        ca, ra = spheres[a]
        for b, (mb, sb) in enumerate(zip(models, states)):
            if a == b:
                continue
            cb, rb = spheres[b]
            if np.linalg.norm(ca - cb) > ra + rb + margin + node_sweep.max(initial=0.0):
                continue
            grid = _grid(mb)
            ia = np.arange(node_offset[a], node_offset[a] + len(ma.surface_nodes))
            x = node_x[ia]
            # into b's rest frame: X = R^T (x - c) + X_c (floating); anchored bodies: R = I, c = X_c
            X = (x - sb.c) @ sb.R + mb.rest_center
            phi, n_rest = grid.query(X)
            hit = (phi < margin + node_sweep[ia]) & np.any(n_rest != 0, axis=1)
            if not hit.any():
                continue
            normal = n_rest[hit] @ sb.R.T
            gap = phi[hit]
            point = x[hit] - 0.5 * gap[:, None] * normal
            # b's side: its surface node nearest to the contact point
            nb_x = node_x[node_offset[b]:node_offset[b] + len(mb.surface_nodes)]
            _, nearest = cKDTree(nb_x).query(point)
            out[0].append(ia[hit])
            out[1].append(node_offset[b] + nearest)
            out[2].append(point)
            out[3].append(normal)
            out[4].append(gap)
            k = hit.sum()
            out[5].append(np.full(k, combine_friction(bodies[a].friction, bodies[b].friction)))
            out[6].append(np.full(k, combine_restitution(bodies[a].restitution, bodies[b].restitution)))
    return _stacked(out)


def _stacked(out):
    if not out[0]:
        return (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)),
                np.zeros(0), np.zeros(0), np.zeros(0))
    return tuple(np.concatenate(o) for o in out)
