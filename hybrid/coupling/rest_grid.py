"""Compiled queries of a deformable body's rest-surface signed-distance grid (rigid.sdf's grid,
built once per body by hybrid.coupling.fem_contact._grid), for the contact stages: points against
the surface (:func:`rest_query`), with the grid's own interpolation (:func:`grid_query`) and, for
points beyond its padding, the distance from the surface point nearest the grid's edge
(:func:`beyond_padding`). tests/test_step_kernels*.py compare them with the numpy code they
replace on random inputs.
"""
import numba as nb
import numpy as np

from rigid.sdf import sdf_sample
from rigid.sdf_kernels import grid_sdf


@nb.njit(cache=True)
def grid_query(origin, h, shape, values, X):
    """Signed distance ``(p,)`` m and unit outward normal ``(p, 3)`` of a signed-distance grid
    (rigid.sdf.SignedDistanceGrid: ``origin``, cell size ``h``, node ``values``) at body-frame
    points ``X`` (p, 3): ``rigid.sdf.sdf_sample`` point by point (outside the grid the value at
    its nearest point plus the distance to it, and a zero normal). ``shape``: the node counts,
    ``values.shape``."""
    p = len(X)
    phi = np.empty(p)
    normal = np.zeros((p, 3))
    for k in range(p):
        phi[k], normal[k, 0], normal[k, 1], normal[k, 2] = sdf_sample(values, origin, h, X[k])
    return phi, normal


@nb.njit(cache=True)
def beyond_padding(origin, h, shape, values, X, radius, phi, normal):
    """Points ``X`` (p, 3) outside the grid (``grid_query``'s, which gives them a zero ``normal``):
    their distance ``phi`` (p,) and outward ``normal`` (p, 3) in place, from the nearest surface
    point as a rigid grid body finds it for points of ``radius`` (p,) m (rigid.sdf_kernels.grid_sdf). A sphere larger than the
    grid's padding touches the surface with its centre outside the grid (a 3 cm ball between the
    5 cm-apart nodes of a box's top face sank 13 mm, met by nothing)."""
    flat = values.ravel()
    for k in range(len(X)):
        if normal[k, 0] != 0 or normal[k, 1] != 0 or normal[k, 2] != 0:
            continue
        outside = False
        for a in range(3):
            u = (X[k, a] - origin[a]) / h
            outside = outside or u < 0 or u > shape[a] - 1
        if outside:
            phi[k], normal[k, 0], normal[k, 1], normal[k, 2] = grid_sdf(
                flat, 0, shape, origin, h, X[k, 0], X[k, 1], X[k, 2], radius[k])


@nb.njit(cache=True)
def rest_query(x, nearest, moved, c, R, rest_center, origin, h, shape, values, radius, reach,
               largest):
    """World points ``x`` (p, 3) against a deformable body's rest surface grid (``origin``, cell
    ``h``, ``shape``, ``values``: grid_query's), each first moved back by the deformation ``moved``
    (s, 3) at its ``nearest`` current surface node (p,) into the rest frame (rotation ``R``, centre
    ``c``, rest centre ``rest_center``): ``X = (x - c) R + rest_center - moved[nearest]``.
    Returns ``(near, X, phi, n_rest)``: the points that may touch (distance less ``radius`` below
    ``reach + largest``, with a normal or within a cell of the surface), their rest points X
    (p, 3), signed distances less their radius (p,) and rest normals (p, 3)
    (hybrid.coupling.fem_contact._against, in one pass)."""
    p = len(x)
    X = np.empty((p, 3))
    for k in range(p):
        y0, y1, y2 = x[k, 0] - c[0], x[k, 1] - c[1], x[k, 2] - c[2]
        for a in range(3):
            X[k, a] = (y0 * R[0, a] + y1 * R[1, a] + y2 * R[2, a]) + rest_center[a] - moved[nearest[k], a]
    phi, n_rest = grid_query(origin, h, shape, values, X)
    beyond_padding(origin, h, shape, values, X, radius, phi, n_rest)
    near = np.empty(p, dtype=np.int64)
    count = 0
    for k in range(p):
        phi[k] -= radius[k]
        has_normal = n_rest[k, 0] != 0 or n_rest[k, 1] != 0 or n_rest[k, 2] != 0
        if phi[k] < reach[k] + largest and (has_normal or abs(phi[k] + radius[k]) <= h):
            near[count] = k
            count += 1
    return near[:count], X, phi, n_rest
