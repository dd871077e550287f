"""Signed distance of each body's shape, evaluated pointwise inside numba kernels.

Analytic for primitives (exact distances, so face contacts of boxes are flat and stacks do not
rock), trilinear on a precomputed grid for general meshes (Guendelman et al. 2003).
Returns (phi, gx, gy, gz): distance (negative inside) and the unit outward normal, shape frame.
"""
import math

import numba as nb
import numpy as np

from .model import SHAPE_BOX, SHAPE_CAPSULE, SHAPE_CYLINDER, SHAPE_GRID, SHAPE_SPHERE
from .sdf import DEFAULT_PADDING_CELLS

FAR = 1.0e30
# grid_sdf beyond the grid's box: steps that look again from nearer the point, each from this
# fraction of the padding (every point that near the surface lies inside the grid)
BEYOND_STEPS = 8
PADDING_REACH = 0.9
# ... until the surface point moves less than this fraction of a cell
SETTLED = 1e-3


@nb.njit(cache=True)
def _unit(x, y, z):
    n = math.sqrt(x * x + y * y + z * z)
    if n < 1e-300:
        return 0.0, 0.0, 1.0
    return x / n, y / n, z / n


@nb.njit(cache=True)
def box_sdf(px, py, pz, hx, hy, hz, cx, cy, cz):
    """Box of half extents h. (cx, cy, cz) is the other body's centre: a point on or near an
    edge or corner (within 2% of the smallest half extent) takes the normal of the face whose
    side the other body lies on, so coincident edges in a stack do not push sideways."""
    qx, qy, qz = abs(px) - hx, abs(py) - hy, abs(pz) - hz
    sx = 1.0 if px >= 0 else -1.0
    sy = 1.0 if py >= 0 else -1.0
    sz = 1.0 if pz >= 0 else -1.0
    qmax = max(qx, qy, qz)
    tol = 0.02 * min(hx, hy, hz)
    if qmax < tol:
        best, pick = -1e300, 0
        for k in range(3):
            qk = (qx, qy, qz)[k]
            if qk >= qmax - tol:
                score = ((cx, cy, cz)[k] * (sx, sy, sz)[k]) / (hx, hy, hz)[k]
                if score > best:
                    best, pick = score, k
        if qx > 0 or qy > 0 or qz > 0:
            d = math.sqrt(max(qx, 0.0) ** 2 + max(qy, 0.0) ** 2 + max(qz, 0.0) ** 2)
        else:
            d = qmax
        if pick == 0:
            return d, sx, 0.0, 0.0
        if pick == 1:
            return d, 0.0, sy, 0.0
        return d, 0.0, 0.0, sz
    if qx > 0 or qy > 0 or qz > 0:
        ox, oy, oz = max(qx, 0.0), max(qy, 0.0), max(qz, 0.0)
        d = math.sqrt(ox * ox + oy * oy + oz * oz)
        return d, sx * ox / d, sy * oy / d, sz * oz / d
    if qx >= qy and qx >= qz:
        return qx, sx, 0.0, 0.0
    if qy >= qz:
        return qy, 0.0, sy, 0.0
    return qz, 0.0, 0.0, sz


@nb.njit(cache=True)
def cylinder_sdf(px, py, pz, r, hh, cx, cy, cz):
    """Capped cylinder along z; near the rim, the side facing the other body's centre wins."""
    rho = math.sqrt(px * px + py * py)
    ux, uy = (px / rho, py / rho) if rho > 1e-300 else (1.0, 0.0)
    dr, dz = rho - r, abs(pz) - hh
    sz = 1.0 if pz >= 0 else -1.0
    qmax = max(dr, dz)
    tol = 0.02 * min(r, hh)
    if qmax < tol and abs(dr - dz) < tol:
        d = math.sqrt(max(dr, 0.0) ** 2 + max(dz, 0.0) ** 2) if (dr > 0 or dz > 0) else qmax
        if (cz * sz) / hh >= (cx * ux + cy * uy) / r:
            return d, 0.0, 0.0, sz
        return d, ux, uy, 0.0
    if dr > 0 or dz > 0:
        a, b = max(dr, 0.0), max(dz, 0.0)
        d = math.sqrt(a * a + b * b)
        return d, ux * a / d, uy * a / d, sz * b / d
    if dr >= dz:
        return dr, ux, uy, 0.0
    return dz, 0.0, 0.0, sz


@nb.njit(cache=True)
def grid_sdf(values, start, shape, origin, cell, px, py, pz, extent=0.0):
    """Signed distance and unit normal of a grid body at a shape-frame point. Beyond the grid's
    box (a sphere or capsule centre further out than the grid's padding, still within its radius
    of the surface): the distance to the nearest surface point, found from the box point closest
    to it (that point less its distance along its normal) and refined by up to BEYOND_STEPS steps
    that each look again from the point of the line towards it at PADDING_REACH of the padding
    from the surface (inside the grid), until the surface point moves less than SETTLED of a
    cell; the normal is along the line to it. Taken once from the box point, a
    face turned against the grid's axes (a body turned rigid as it turns) tilted the normal by
    0.4 degrees for a ball resting 3 cm above it, and the ball rolled off. Only a point with an
    ``extent`` of its own (m: a sphere's or capsule's radius) is refined: one without is beyond
    the padding from the surface, out of reach, and needs no exact normal."""
    nx, ny, nz = shape[0], shape[1], shape[2]
    fx, fy, fz = (px - origin[0]) / cell, (py - origin[1]) / cell, (pz - origin[2]) / cell
    if fx < 0 or fy < 0 or fz < 0 or fx > nx - 1 or fy > ny - 1 or fz > nz - 1:
        qx = origin[0] + cell * min(max(fx, 0.0), nx - 1.0)
        qy = origin[1] + cell * min(max(fy, 0.0), ny - 1.0)
        qz = origin[2] + cell * min(max(fz, 0.0), nz - 1.0)
        reach = PADDING_REACH * DEFAULT_PADDING_CELLS * cell      # within the grid from any surface point
        sx, sy, sz = qx, qy, qz
        for step in range(BEYOND_STEPS + 1 if extent > 0 else 1):
            phi, gx, gy, gz = _grid_inside(values, start, shape, origin, cell, qx, qy, qz)
            tx, ty, tz = qx - phi * gx, qy - phi * gy, qz - phi * gz
            moved = (tx - sx) ** 2 + (ty - sy) ** 2 + (tz - sz) ** 2
            sx, sy, sz = tx, ty, tz
            ux, uy, uz = _unit(px - sx, py - sy, pz - sz)
            if step > 0 and moved < (SETTLED * cell) ** 2:
                break
            qx = min(max(sx + reach * ux, origin[0]), origin[0] + cell * (nx - 1.0))
            qy = min(max(sy + reach * uy, origin[1]), origin[1] + cell * (ny - 1.0))
            qz = min(max(sz + reach * uz, origin[2]), origin[2] + cell * (nz - 1.0))
        d = math.sqrt((px - sx) ** 2 + (py - sy) ** 2 + (pz - sz) ** 2)
        return d, ux, uy, uz
    return _grid_inside(values, start, shape, origin, cell, px, py, pz)


@nb.njit(cache=True)
def _grid_inside(values, start, shape, origin, cell, px, py, pz):
    nx, ny, nz = shape[0], shape[1], shape[2]
    fx, fy, fz = (px - origin[0]) / cell, (py - origin[1]) / cell, (pz - origin[2]) / cell
    i, j, k = min(int(fx), nx - 2), min(int(fy), ny - 2), min(int(fz), nz - 2)
    tx, ty, tz = fx - i, fy - j, fz - k
    c = np.empty(8)
    for a in range(2):
        for b in range(2):
            for d in range(2):
                c[a * 4 + b * 2 + d] = values[start + ((i + a) * ny + (j + b)) * nz + (k + d)]
    # trilinear interpolation and its gradient
    c00 = c[0] * (1 - tx) + c[4] * tx
    c01 = c[1] * (1 - tx) + c[5] * tx
    c10 = c[2] * (1 - tx) + c[6] * tx
    c11 = c[3] * (1 - tx) + c[7] * tx
    c0 = c00 * (1 - ty) + c10 * ty
    c1 = c01 * (1 - ty) + c11 * ty
    phi = c0 * (1 - tz) + c1 * tz
    gz = c1 - c0
    gy = (c10 - c00) * (1 - tz) + (c11 - c01) * tz
    dx0 = (c[4] - c[0]) * (1 - ty) + (c[6] - c[2]) * ty
    dx1 = (c[5] - c[1]) * (1 - ty) + (c[7] - c[3]) * ty
    gx = dx0 * (1 - tz) + dx1 * tz
    gx, gy, gz = _unit(gx, gy, gz)
    return phi, gx, gy, gz


@nb.njit(cache=True)
def shape_sdf(kind, params, grid, values, starts, shapes, origins, cells, px, py, pz, cx, cy, cz,
              extent=0.0):
    """Signed distance and normal of one body's shape at a shape-frame point.

    (cx, cy, cz): centre of the body the point belongs to, same frame (breaks ties at edges)."""
    if kind == SHAPE_SPHERE:
        d = math.sqrt(px * px + py * py + pz * pz)
        nx, ny, nz = _unit(px, py, pz)
        return d - params[0], nx, ny, nz
    if kind == SHAPE_BOX:
        return box_sdf(px, py, pz, params[0], params[1], params[2], cx, cy, cz)
    if kind == SHAPE_CAPSULE:
        z = min(max(pz, -params[1]), params[1])
        dx, dy, dz = px, py, pz - z
        d = math.sqrt(dx * dx + dy * dy + dz * dz)
        nx, ny, nz = _unit(dx, dy, dz)
        return d - params[0], nx, ny, nz
    if kind == SHAPE_CYLINDER:
        return cylinder_sdf(px, py, pz, params[0], params[1], cx, cy, cz)
    if kind == SHAPE_GRID and grid >= 0:
        return grid_sdf(values, starts[grid], shapes[grid], origins[grid], cells[grid], px, py, pz,
                        extent)
    return FAR, 0.0, 0.0, 0.0
