"""Contact detection: every body's contact points against planes and against other bodies' shapes.

Points (mesh vertices with radius 0, or sphere/capsule centres with their radius) are tested
against the signed distance of the other body (Guendelman, Bridson, Fedkiw 2003); a cylinder's
side is tested as rings (its nearest points to the other surface), and a sphere or capsule is met
through its own centre points only. Contacts are
kept speculatively while the gap is below a margin, so the solver can stop bodies before they meet.
Broad phase: bounding spheres, sorted along x (sweep and prune).
"""
from dataclasses import dataclass

import math

import numba as nb
import numpy as np

from .model import POINT_FEM_ONLY, POINT_RING, SHAPE_BOX, SHAPE_CAPSULE, SHAPE_GRID, SHAPE_SPHERE
from .sdf_kernels import box_sdf, shape_sdf


@dataclass
class Contacts:
    """``count`` contacts. body_a is the body pushed along +normal; body_b is -1 for a plane
    (or a body the solver treats as static).

    point (c, 3) m world; normal (c, 3) unit, from b towards a; gap (c,) m, negative when
    penetrating; friction, restitution (c,) combined coefficients.
    """
    body_a: np.ndarray
    body_b: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    gap: np.ndarray
    friction: np.ndarray
    restitution: np.ndarray

    @property
    def count(self):
        """Number of contacts."""
        return len(self.gap)

    def take(self, rows):
        """The contacts ``rows`` (a bool mask or indices) picks."""
        return Contacts(*(getattr(self, name)[rows] for name in (
            "body_a", "body_b", "point", "normal", "gap", "friction", "restitution")))


def combine_friction(mu_a, mu_b):
    """Geometric mean: equal coefficients give that coefficient; a frictionless side gives 0."""
    return np.sqrt(mu_a * mu_b)


def combine_restitution(e_a, e_b):
    """The larger of the two: equal coefficients give that coefficient."""
    return np.maximum(e_a, e_b)


@nb.njit(cache=True)
def _broad_phase(position, radius, sweep, fixed):
    n = len(radius)
    lo = position[:, 0] - radius - sweep
    order = np.argsort(lo)
    pairs = []
    for ii in range(n):
        a = order[ii]
        hi_a = position[a, 0] + radius[a] + sweep[a]
        for jj in range(ii + 1, n):
            b = order[jj]
            if lo[b] > hi_a:
                break
            if fixed[a] and fixed[b]:
                continue
            d0 = position[a, 0] - position[b, 0]
            d1 = position[a, 1] - position[b, 1]
            d2 = position[a, 2] - position[b, 2]
            reach = radius[a] + radius[b] + sweep[a] + sweep[b]
            if d0 * d0 + d1 * d1 + d2 * d2 <= reach * reach:
                pairs.append((min(a, b), max(a, b)))
    out = np.empty((len(pairs), 2), dtype=np.int64)
    for k in range(len(pairs)):
        out[k, 0] = pairs[k][0]
        out[k, 1] = pairs[k][1]
    return out


@nb.njit(cache=True)
def _point_world(R, x, local, k):
    """World point x + R local[k] (indexed element by element: a row view costs a reference
    count per point)."""
    l0, l1, l2 = local[k, 0], local[k, 1], local[k, 2]
    return (x[0] + R[0, 0] * l0 + R[0, 1] * l1 + R[0, 2] * l2,
            x[1] + R[1, 0] * l0 + R[1, 1] * l1 + R[1, 2] * l2,
            x[2] + R[2, 0] * l0 + R[2, 1] * l1 + R[2, 2] * l2)


@nb.njit(cache=True)
def _to_shape(Rb, Sb, xb, offset, px, py, pz):
    """World point -> body frame of b (R^T (p - x)) -> shape frame of b (S p_body + offset)."""
    dx, dy, dz = px - xb[0], py - xb[1], pz - xb[2]
    bx = Rb[0, 0] * dx + Rb[1, 0] * dy + Rb[2, 0] * dz
    by = Rb[0, 1] * dx + Rb[1, 1] * dy + Rb[2, 1] * dz
    bz = Rb[0, 2] * dx + Rb[1, 2] * dy + Rb[2, 2] * dz
    return (Sb[0, 0] * bx + Sb[0, 1] * by + Sb[0, 2] * bz + offset[0],
            Sb[1, 0] * bx + Sb[1, 1] * by + Sb[1, 2] * bz + offset[1],
            Sb[2, 0] * bx + Sb[2, 1] * by + Sb[2, 2] * bz + offset[2])


@nb.njit(cache=True)
def _normal_to_world(Rb, Sb, gx, gy, gz):
    """Shape-frame normal -> body frame (S^T g) -> world (R n)."""
    mx = Sb[0, 0] * gx + Sb[1, 0] * gy + Sb[2, 0] * gz
    my = Sb[0, 1] * gx + Sb[1, 1] * gy + Sb[2, 1] * gz
    mz = Sb[0, 2] * gx + Sb[1, 2] * gy + Sb[2, 2] * gz
    return (Rb[0, 0] * mx + Rb[0, 1] * my + Rb[0, 2] * mz,
            Rb[1, 0] * mx + Rb[1, 1] * my + Rb[1, 2] * mz,
            Rb[2, 0] * mx + Rb[2, 1] * my + Rb[2, 2] * mz)


@nb.njit(cache=True)
def _ring_frame(ax, ay, az, nx, ny, nz):
    """Unit vectors e, f spanning a ring's plane (axis a): e towards the surface of normal n
    (the ring's nearest point to it is the centre + radius e), f = a x e."""
    d = nx * ax + ny * ay + nz * az
    ex, ey, ez = d * ax - nx, d * ay - ny, d * az - nz
    size = np.sqrt(ex * ex + ey * ey + ez * ez)
    if size < 1e-9:     # the ring lies flat on the surface: every point is nearest, pick one
        ex, ey, ez = (az, 0.0, -ax) if abs(ax) > 0.5 or abs(az) > 0.5 else (0.0, az, -ay)
        size = np.sqrt(ex * ex + ey * ey + ez * ez)
    ex, ey, ez = ex / size, ey / size, ez / size
    return ex, ey, ez, ay * ez - az * ey, az * ex - ax * ez, ax * ey - ay * ex


@nb.njit(cache=True)
def _round(kind):
    """Bodies whose contact points are centres with radii: they meet others through those alone."""
    return kind == SHAPE_SPHERE or kind == SHAPE_CAPSULE


# a ring meets a surface at its nearest point and at the points a quarter, half and three
# quarters round from it (which hold a ring lying flat on the surface up)
_RING_COS = np.array([1.0, 0.0, -1.0, 0.0])
_RING_SIN = np.array([0.0, 1.0, 0.0, -1.0])


@nb.njit(cache=True)
def _ring_point(cx, cy, cz, rho, frame, i):
    ex, ey, ez, fx, fy, fz = frame
    c, s = rho * _RING_COS[i], rho * _RING_SIN[i]
    return cx + c * ex + s * fx, cy + c * ey + s * fy, cz + c * ez + s * fz


@nb.njit(cache=True)
def _plane_contacts(position, rotation, sweep, fixed, point_start, point_local, point_radius,
                    point_kind, point_ring, point_axis, plane_point, plane_normal, margin, out_a,
                    out_b, out_p, out_n, out_gap):
    """Every free body's contact points against every plane (a ring: its nearest points to the
    plane), written from out_*[0]; returns their count (b = -1 - plane index)."""
    c = 0
    zero = np.zeros(3)
    for a in range(len(fixed)):
        if fixed[a]:
            continue
        Ra, xa = rotation[a], position[a]
        for k in range(point_start[a], point_start[a + 1]):
            if point_kind[k] == POINT_FEM_ONLY:
                continue
            px, py, pz = _point_world(Ra, xa, point_local, k)
            ring = point_kind[k] == POINT_RING
            ax, ay, az = _point_world(Ra, zero, point_axis, k)
            for j in range(len(plane_point)):
                nx, ny, nz = plane_normal[j, 0], plane_normal[j, 1], plane_normal[j, 2]
                frame = _ring_frame(ax, ay, az, nx, ny, nz) if ring else (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
                for i in range(4 if ring else 1):
                    qx, qy, qz = _ring_point(px, py, pz, point_ring[k], frame, i) if ring else (px, py, pz)
                    dist = ((qx - plane_point[j, 0]) * nx + (qy - plane_point[j, 1]) * ny
                            + (qz - plane_point[j, 2]) * nz)
                    gap = dist - point_radius[k]
                    if gap < margin + sweep[a]:
                        # at the body's own surface point (a static plane needs no common point):
                        # halfway across a resting tip's 0.5 mm overlap, friction held a point
                        # 0.25 mm up the axis of a top spinning at 1000 rad/s, whose tip then
                        # slid at 9 cm/s
                        if c < len(out_gap):
                            h = point_radius[k]
                            out_a[c] = a
                            out_b[c] = -1 - j
                            out_p[c, 0], out_p[c, 1], out_p[c, 2] = qx - nx * h, qy - ny * h, qz - nz * h
                            out_n[c, 0], out_n[c, 1], out_n[c, 2] = nx, ny, nz
                            out_gap[c] = gap
                        c += 1
    return c


@nb.njit(cache=True)
def _pair_contacts(pairs, position, rotation, sweep, fixed, body_radius, point_start, point_local,
                   point_radius, point_kind, point_ring, point_axis, shape_kind, shape_params,
                   shape_rotation, shape_offset, grid_index, grid_values, grid_start, grid_shape,
                   grid_origin, grid_cell, margin, out_a, out_b, out_p, out_n, out_gap, c):
    """Every broad-phase pair both ways: body a's contact points against body b's signed distance
    (a ring: its nearest points to b's surface), written from out_*[c]; returns the new count."""
    zero = np.zeros(3)
    for q in range(len(pairs)):
        for side in range(2):
            a = pairs[q, side]
            b = pairs[q, 1 - side]
            if fixed[a] and fixed[b]:
                continue
            # a sphere or capsule is met through its own centre points against a's distance, which
            # finds the nearest point of a's surface; a's vertices against it would push along the
            # sphere's normal at each vertex (a ball falling on a box face off its centre vertex
            # left sideways at 3.2 m/s), so they are left out; two round bodies meet once
            if _round(shape_kind[b]) and (not _round(shape_kind[a]) or side == 1):
                continue
            Ra, xa = rotation[a], position[a]
            Rb, Sb, xb, ob = rotation[b], shape_rotation[b], position[b], shape_offset[b]
            kind, params, grid = shape_kind[b], shape_params[b], grid_index[b]
            reach = margin + sweep[a] + sweep[b]
            # centre of a in the shape frame of b (tie-break at edges)
            cx, cy, cz = _to_shape(Rb, Sb, xb, ob, xa[0], xa[1], xa[2])
            for k in range(point_start[a], point_start[a + 1]):
                if point_kind[k] == POINT_FEM_ONLY:
                    continue
                px, py, pz = _point_world(Ra, xa, point_local, k)
                if kind == SHAPE_BOX or kind == SHAPE_GRID:
                    # a box or a mesh lies inside its bounding sphere (about its centre, through its
                    # corners or hull vertices): points farther than the reach from that sphere
                    # (with their radii, and a micrometre for round-off) touch nothing
                    dx, dy, dz = px - xb[0], py - xb[1], pz - xb[2]
                    far = body_radius[b] + reach + point_radius[k] + point_ring[k] + 1e-6
                    if dx * dx + dy * dy + dz * dz > far * far:
                        continue
                ring = point_kind[k] == POINT_RING
                frame = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
                if ring:    # towards b's surface as seen from the ring's centre
                    sx, sy, sz = _to_shape(Rb, Sb, xb, ob, px, py, pz)
                    phi, gx, gy, gz = shape_sdf(kind, params, grid, grid_values, grid_start,
                                                grid_shape, grid_origin, grid_cell, sx, sy, sz,
                                                cx, cy, cz, point_ring[k] + point_radius[k])
                    if phi - point_ring[k] >= reach:
                        continue
                    nx, ny, nz = _normal_to_world(Rb, Sb, gx, gy, gz)
                    ax, ay, az = _point_world(Ra, zero, point_axis, k)
                    frame = _ring_frame(ax, ay, az, nx, ny, nz)
                for i in range(4 if ring else 1):
                    qx, qy, qz = _ring_point(px, py, pz, point_ring[k], frame, i) if ring else (px, py, pz)
                    sx, sy, sz = _to_shape(Rb, Sb, xb, ob, qx, qy, qz)
                    if kind == SHAPE_BOX:   # (shape_sdf's box, without passing it the arrays)
                        phi, gx, gy, gz = box_sdf(sx, sy, sz, params[0], params[1], params[2],
                                                  cx, cy, cz)
                    else:
                        phi, gx, gy, gz = shape_sdf(kind, params, grid, grid_values, grid_start,
                                                    grid_shape, grid_origin, grid_cell, sx, sy,
                                                    sz, cx, cy, cz, point_radius[k])
                    gap = phi - point_radius[k]
                    if gap >= reach:
                        continue
                    nx, ny, nz = _normal_to_world(Rb, Sb, gx, gy, gz)
                    if c < len(out_gap):     # the point halfway across the gap
                        h = point_radius[k] + 0.5 * gap
                        out_a[c] = a
                        out_b[c] = b
                        out_p[c, 0], out_p[c, 1], out_p[c, 2] = qx - nx * h, qy - ny * h, qz - nz * h
                        out_n[c, 0], out_n[c, 1], out_n[c, 2] = nx, ny, nz
                        out_gap[c] = gap
                    c += 1
    return c


def detect(model, position, rotation, sweep, margin):
    """All contacts with gap below ``margin + sweep`` (m). ``sweep`` (b,) is each body's reach."""
    fixed = model.body_fixed
    pairs = _broad_phase(position, model.body_radius + margin, sweep, fixed)
    capacity = max(64, 4 * len(model.point_radius))     # grows below if more are found
    while True:
        out_a = np.empty(capacity, np.int64)
        out_b = np.empty(capacity, np.int64)
        out_p = np.empty((capacity, 3))
        out_n = np.empty((capacity, 3))
        out_gap = np.empty(capacity)
        points = (model.point_start, model.point_local, model.point_radius, model.point_kind,
                  model.point_ring, model.point_axis)
        out = (out_a, out_b, out_p, out_n, out_gap)
        count = 0
        if len(model.plane_point):
            count = _plane_contacts(position, rotation, sweep, fixed, *points, model.plane_point,
                                    model.plane_normal, margin, *out)
        if len(pairs):
            count = _pair_contacts(pairs, position, rotation, sweep, fixed, model.body_radius, *points,
                                   model.shape_kind, model.shape_params, model.shape_rotation,
                                   model.shape_offset, model.grid_index, model.grid_values,
                                   model.grid_start, model.grid_shape, model.grid_origin,
                                   model.grid_cell, margin, *out, count)
        if count <= capacity:
            break
        capacity = count
    a, b = out_a[:count], out_b[:count]
    return Contacts(a, np.where(b < 0, -1, b), out_p[:count], out_n[:count], out_gap[:count],
                    *_combine(model, b, model.body_friction[a], model.body_restitution[a]))


@nb.njit(cache=True)
def _points_narrow_phase(points, toward, sweep, body_sweep, position, rotation, body_radius, shape_kind, shape_params,
                         shape_rotation, shape_offset, grid_index, grid_values, grid_start,
                         grid_shape, grid_origin, grid_cell, plane_point, plane_normal, margin,
                         out_a, out_b, out_p, out_n, out_gap):
    cap = len(out_gap)
    c = 0
    for k in range(len(points)):
        px, py, pz = points[k, 0], points[k, 1], points[k, 2]
        for j in range(len(plane_point)):
            nx, ny, nz = plane_normal[j, 0], plane_normal[j, 1], plane_normal[j, 2]
            gap = (px - plane_point[j, 0]) * nx + (py - plane_point[j, 1]) * ny + (pz - plane_point[j, 2]) * nz
            if gap < margin + sweep[k]:
                if c < cap:
                    out_a[c], out_b[c] = k, -1 - j
                    out_p[c, 0], out_p[c, 1], out_p[c, 2] = px - 0.5 * gap * nx, py - 0.5 * gap * ny, pz - 0.5 * gap * nz
                    out_n[c, 0], out_n[c, 1], out_n[c, 2] = nx, ny, nz
                    out_gap[c] = gap
                c += 1
        for b in range(len(body_radius)):
            dx, dy, dz = px - position[b, 0], py - position[b, 1], pz - position[b, 2]
            # how far the point and the body may close in together this step
            ahead = margin + sweep[k] + body_sweep[b]
            reach = body_radius[b] + ahead
            if dx * dx + dy * dy + dz * dz > reach * reach:
                continue
            Rb, Sb = rotation[b], shape_rotation[b]
            sx, sy, sz = _to_shape(Rb, Sb, position[b], shape_offset[b], px, py, pz)
            # edge ties break towards ``toward`` (a point on the side the point comes from)
            cx, cy, cz = _to_shape(Rb, Sb, position[b], shape_offset[b], toward[k, 0], toward[k, 1],
                                   toward[k, 2])
            if shape_kind[b] == SHAPE_BOX:  # (shape_sdf's box, without passing it the arrays)
                phi, gx, gy, gz = box_sdf(sx, sy, sz, shape_params[b, 0], shape_params[b, 1],
                                          shape_params[b, 2], cx, cy, cz)
            else:
                phi, gx, gy, gz = shape_sdf(shape_kind[b], shape_params[b], grid_index[b],
                                            grid_values, grid_start, grid_shape, grid_origin,
                                            grid_cell, sx, sy, sz, cx, cy, cz)
            if phi >= ahead:
                continue
            nx, ny, nz = _normal_to_world(Rb, Sb, gx, gy, gz)
            if c < cap:
                out_a[c], out_b[c] = k, b
                out_p[c, 0], out_p[c, 1], out_p[c, 2] = px - 0.5 * phi * nx, py - 0.5 * phi * ny, pz - 0.5 * phi * nz
                out_n[c, 0], out_n[c, 1], out_n[c, 2] = nx, ny, nz
                out_gap[c] = phi
            c += 1
    return c


def detect_points(model, position, rotation, points, sweep, body_sweep, margin, friction, restitution,
                  toward=None):
    """Contacts of free points (FEM surface nodes) with planes and rigid bodies: gap below
    ``margin`` plus how far the point (``sweep`` (k,) m) and the body (``body_sweep`` (b,) m) may
    move this step, so a fast body is met before it passes the points (a ball at 30 m/s, met only
    within the points' own reach, ended its step 1 cm inside a block).

    body_a is the point's index; body_b a rigid body index or -1 for a plane. ``friction`` and
    ``restitution`` (k,) are the points' own coefficients, combined with the other side's.
    ``toward`` (k, 3): for a point at a shape's edge or corner, the face taken is the one whose
    side this point lies on (as the other body's centre for a rigid pair); default the points
    themselves.
    """
    toward = points if toward is None else toward
    capacity = max(64, 2 * len(points))
    while True:
        out_a = np.empty(capacity, np.int64)
        out_b = np.empty(capacity, np.int64)
        out_p = np.empty((capacity, 3))
        out_n = np.empty((capacity, 3))
        out_gap = np.empty(capacity)
        count = _points_narrow_phase(points, toward, sweep, body_sweep, position, rotation, model.body_radius,
                                     model.shape_kind, model.shape_params, model.shape_rotation,
                                     model.shape_offset, model.grid_index, model.grid_values,
                                     model.grid_start, model.grid_shape, model.grid_origin,
                                     model.grid_cell, model.plane_point, model.plane_normal, margin,
                                     out_a, out_b, out_p, out_n, out_gap)
        if count <= capacity:
            break
        capacity = count
    a, b = out_a[:count], out_b[:count]
    return Contacts(a, np.where(b < 0, -1, b), out_p[:count], out_n[:count], out_gap[:count],
                    *_combine(model, b, friction[a], restitution[a]))


def _combine(model, b, mu_a, e_a):
    """Combined friction and restitution of side a with side b (body index, or -1 - plane)."""
    return _combined(b, np.ascontiguousarray(mu_a, dtype=float), np.ascontiguousarray(e_a, dtype=float),
                     model.body_friction, model.body_restitution, model.plane_friction,
                     model.plane_restitution)


@nb.njit(cache=True)
def _combined(b, mu_a, e_a, body_friction, body_restitution, plane_friction, plane_restitution):
    """(c,) each: :func:`combine_friction` and :func:`combine_restitution` of side a's
    coefficients with side b's, b a body index or -1 - plane index."""
    c = len(b)
    mu = np.empty(c)
    e = np.empty(c)
    for k in range(c):
        mu_b = e_b = 0.0
        if b[k] < 0 and len(plane_friction):
            mu_b, e_b = plane_friction[-1 - b[k]], plane_restitution[-1 - b[k]]
        elif len(body_friction):
            mu_b, e_b = body_friction[max(b[k], 0)], body_restitution[max(b[k], 0)]
        mu[k] = math.sqrt(mu_a[k] * mu_b)      # geometric mean
        e[k] = max(e_a[k], e_b)                # the larger
    return mu, e


def concatenate(first, second, offset_a, offset_b):
    """Contacts of ``first`` followed by ``second`` with its body indices shifted."""
    sb = np.where(second.body_b >= 0, second.body_b + offset_b, -1)
    return Contacts(np.concatenate([first.body_a, second.body_a + offset_a]),
                    np.concatenate([first.body_b, sb]),
                    np.concatenate([first.point, second.point]),
                    np.concatenate([first.normal, second.normal]),
                    np.concatenate([first.gap, second.gap]),
                    np.concatenate([first.friction, second.friction]),
                    np.concatenate([first.restitution, second.restitution]))
