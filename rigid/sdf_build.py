"""Compiled loops of the signed-distance grid build (rigid.sdf.SignedDistanceGrid.build).

The exact point-triangle distance of one point and one triangle (a scalar copy of
rigid.sdf.closest_point_weights, the regions of Ericson's Real-Time Collision Detection 5.1.5 in
the same priority), and the three loops that call it: the narrow band over each triangle's grown
box of grid nodes, the distances of given node-triangle pairs, and the propagation's repair pass
over each far node's six neighbours.
"""
import numba
import numpy as np


@numba.njit(cache=True)
def _closest_weights(px, py, pz, a0, a1, a2, b0, b1, b2, c0, c1, c2):
    """:func:`closest_point_weights` of one point ``(px, py, pz)`` and one triangle with corners
    ``a, b, c``, the same regions in the same priority (corners, then edges ab, ac, bc, then the
    face)."""
    ab0, ab1, ab2 = b0 - a0, b1 - a1, b2 - a2
    ac0, ac1, ac2 = c0 - a0, c1 - a1, c2 - a2
    ap0, ap1, ap2 = px - a0, py - a1, pz - a2
    d1 = ab0 * ap0 + ab1 * ap1 + ab2 * ap2
    d2 = ac0 * ap0 + ac1 * ap1 + ac2 * ap2
    bp0, bp1, bp2 = px - b0, py - b1, pz - b2
    d3 = ab0 * bp0 + ab1 * bp1 + ab2 * bp2
    d4 = ac0 * bp0 + ac1 * bp1 + ac2 * bp2
    cp0, cp1, cp2 = px - c0, py - c1, pz - c2
    d5 = ab0 * cp0 + ab1 * cp1 + ab2 * cp2
    d6 = ac0 * cp0 + ac1 * cp1 + ac2 * cp2
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    if d1 <= 0 and d2 <= 0:
        return 0.0, 0.0
    if d3 >= 0 and d4 <= d3:
        return 1.0, 0.0
    if d6 >= 0 and d5 <= d6:
        return 0.0, 1.0
    if vc <= 0 and d1 >= 0 and d3 <= 0:
        den = d1 - d3
        return d1 / (den if den != 0 else 1.0), 0.0
    if vb <= 0 and d2 >= 0 and d6 <= 0:
        den = d2 - d6
        return 0.0, d2 / (den if den != 0 else 1.0)
    if va <= 0 and d4 >= d3 and d5 >= d6:
        den = (d4 - d3) + (d5 - d6)
        edge_bc = (d4 - d3) / (den if den != 0 else 1.0)
        return 1.0 - edge_bc, edge_bc
    total = va + vb + vc
    total = total if total != 0 else 1.0
    return vb / total, vc / total


@numba.njit(cache=True)
def _distance_squared(px, py, pz, corners, t):
    """Squared distance from one point to triangle ``t`` of ``corners`` (T, 3, 3)
    (:func:`point_triangle_distance_squared`)."""
    a0, a1, a2 = corners[t, 0, 0], corners[t, 0, 1], corners[t, 0, 2]
    b0, b1, b2 = corners[t, 1, 0], corners[t, 1, 1], corners[t, 1, 2]
    c0, c1, c2 = corners[t, 2, 0], corners[t, 2, 1], corners[t, 2, 2]
    v, w = _closest_weights(px, py, pz, a0, a1, a2, b0, b1, b2, c0, c1, c2)
    o0 = px - a0 - v * (b0 - a0) - w * (c0 - a0)
    o1 = py - a1 - v * (b1 - a1) - w * (c1 - a1)
    o2 = pz - a2 - v * (b2 - a2) - w * (c2 - a2)
    return o0 * o0 + o1 * o1 + o2 * o2


@numba.njit(cache=True)
def band_distances(corners, origin, h, shape, first, extent, best_d2, best_tri):
    """The narrow band's loop over triangles and the grid nodes of their grown boxes (see
    :func:`_narrow_band`); the last triangle attaining a node's minimum names it."""
    ny, nz = shape[1], shape[2]
    for t in range(len(corners)):
        for i in range(first[t, 0], first[t, 0] + extent[t, 0]):
            px = origin[0] + h * i
            for j in range(first[t, 1], first[t, 1] + extent[t, 1]):
                py = origin[1] + h * j
                for k in range(first[t, 2], first[t, 2] + extent[t, 2]):
                    d2 = _distance_squared(px, py, origin[2] + h * k, corners, t)
                    node = (i * ny + j) * nz + k
                    if d2 <= best_d2[node]:
                        best_d2[node] = d2
                        best_tri[node] = t


@numba.njit(cache=True)
def pair_distances(flat, tri, corners, origin, h, shape):
    """Squared distances (k,) from grid nodes ``flat`` (k,) to their triangles ``tri`` (k,)."""
    ny, nz = shape[1], shape[2]
    out = np.empty(len(flat))
    for p in range(len(flat)):
        n = flat[p]
        out[p] = _distance_squared(origin[0] + h * (n // (ny * nz)), origin[1] + h * ((n // nz) % ny),
                                   origin[2] + h * (n % nz), corners, tri[p])
    return out


@numba.njit(cache=True)
def neighbour_pass(far, d2, tri, corners, origin, h, shape):
    """The propagation's repair pass (see :func:`_propagate`): each far node ``far`` (k,) tries
    the closest triangles its six neighbours had, ``tri`` before the pass, in the order -x, +x,
    -y, +y, -z, +z, and keeps any strictly closer; updates ``d2`` and returns the new ``tri``."""
    nx, ny, nz = shape[0], shape[1], shape[2]
    out = tri.copy()
    for p in range(len(far)):
        n = far[p]
        i, j, k = n // (ny * nz), (n // nz) % ny, n % nz
        px, py, pz = origin[0] + h * i, origin[1] + h * j, origin[2] + h * k
        best, best_tri = d2[n], out[n]
        for axis in range(3):
            for step in (-1, 1):
                a, b, c = i, j, k
                if axis == 0:
                    a = min(max(i + step, 0), nx - 1)
                elif axis == 1:
                    b = min(max(j + step, 0), ny - 1)
                else:
                    c = min(max(k + step, 0), nz - 1)
                other = tri[(a * ny + b) * nz + c]
                trial = _distance_squared(px, py, pz, corners, other)
                if trial < best:
                    best, best_tri = trial, other
        d2[n], out[n] = best, best_tri
    return out
