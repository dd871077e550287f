"""Primitive rigid shapes as closed triangle surfaces, plus their closed-form inertia.

Every surface is centred on the origin, watertight (each edge shared by exactly two triangles, no
duplicate vertices) and oriented outward (counter-clockwise seen from outside), so it can go straight
into :func:`rigid.mass.mass_properties` and :class:`rigid.sdf.SignedDistanceGrid`. All builders
return ``(vertices (n, 3) float64 in m, triangles (m, 3) int64)``.

``resolution`` is always a target edge length (m); ``None`` picks the default documented per shape.
"""
import math

import numpy as np

SPHERE_DEFAULT_LEVEL = 3  # 642 vertices, 1280 triangles
SPHERE_MAX_LEVEL = 7  # 163842 vertices; finer requests raise
CIRCLE_DEFAULT_SEGMENTS = 32  # cylinder/capsule default: 32 vertices around the axis


def _positive(name, value):
    value = float(value)
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive finite number (m), got {value!r}")
    return value


def _resolution(value):
    return None if value is None else _positive("resolution", value)


# --------------------------------------------------------------------------------------- box
def box_surface(size, resolution=None):
    """Closed box surface with full edge lengths ``size = (sx, sy, sz)`` (m), centred on the origin.

    Each edge of length ``s`` is split into ``max(2, ceil(s / resolution))`` segments, so every face
    has at least 3x3 vertices (an interior vertex, needed for face-on-face contact). The default
    ``resolution`` is ``max(size) / 2``: a cube gets 3x3 vertices per face (26 vertices in all),
    enough for flat face contact (corners, edge midpoints and the centre) at the lowest cost.
    Face quads are split along alternating diagonals, so the mesh has no preferred direction.
    """
    size = np.broadcast_to(np.asarray(size, dtype=float), (3,)).copy()
    for axis, s in zip("xyz", size):
        _positive(f"box size along {axis}", s)
    resolution = _resolution(resolution)
    if resolution is None:
        resolution = size.max() / 2.0
    divisions = np.maximum(2, np.ceil(size / resolution - 1e-9)).astype(np.int64)

    # Vertices live on the integer lattice (0..divisions); shared edge/corner nodes are merged by
    # their lattice index, which is exact.
    lattice_points, quads = [], []
    offset = 0
    for a in range(3):
        b, c = (a + 1) % 3, (a + 2) % 3  # e_b x e_c = +e_a
        nb, nc = divisions[b], divisions[c]
        jb, jc = np.meshgrid(np.arange(nb + 1), np.arange(nc + 1), indexing="ij")
        for side in (0, divisions[a]):
            points = np.zeros((nb + 1, nc + 1, 3), dtype=np.int64)
            points[..., a] = side
            points[..., b] = jb
            points[..., c] = jc
            index = offset + np.arange((nb + 1) * (nc + 1)).reshape(nb + 1, nc + 1)
            q = np.stack([index[:-1, :-1], index[1:, :-1], index[1:, 1:], index[:-1, 1:]], -1)
            q = q.reshape(-1, 4)
            if side == 0:  # the -a face looks along -e_a: reverse the winding
                q = q[:, ::-1]
            quads.append(q)
            lattice_points.append(points.reshape(-1, 3))
            offset += (nb + 1) * (nc + 1)
    lattice_points = np.concatenate(lattice_points)
    quads = np.concatenate(quads)
    unique_points, inverse = np.unique(lattice_points, axis=0, return_inverse=True)
    quads = inverse.ravel()[quads]

    # Alternate the diagonal in a checkerboard (by lattice parity of the quad's first corner).
    corner_parity = unique_points[quads[:, 0]].sum(axis=1) % 2 == 0
    tri_a = np.where(corner_parity[:, None], quads[:, [0, 1, 2]], quads[:, [0, 1, 3]])
    tri_b = np.where(corner_parity[:, None], quads[:, [0, 2, 3]], quads[:, [1, 2, 3]])
    triangles = np.concatenate([tri_a, tri_b]).astype(np.int64)
    vertices = (unique_points / divisions - 0.5) * size
    return vertices.astype(np.float64), triangles


def box_inertia(mass, size):
    """Inertia (3, 3) kg m^2 of a solid box of full edge lengths ``size`` about its centre."""
    sx, sy, sz = np.broadcast_to(np.asarray(size, dtype=float), (3,))
    return mass / 12.0 * np.diag([sy**2 + sz**2, sx**2 + sz**2, sx**2 + sy**2])


# ------------------------------------------------------------------------------------ sphere
def _icosahedron():
    """Unit-circumradius icosahedron: vertices are the cyclic permutations of (0, +-1, +-phi)."""
    phi = (1.0 + 5.0**0.5) / 2.0
    base = np.array([[0, s1, s2 * phi] for s1 in (-1, 1) for s2 in (-1, 1)], dtype=float)
    vertices = np.concatenate([np.roll(base, k, axis=1) for k in range(3)])
    # Faces are the vertex triples whose pairwise distances all equal the edge length 2.
    combos = np.array([(a, b, c) for a in range(12) for b in range(a + 1, 12) for c in range(b + 1, 12)])
    p = vertices[combos]
    edge = np.stack([np.linalg.norm(p[:, 0] - p[:, 1], axis=1), np.linalg.norm(p[:, 1] - p[:, 2], axis=1),
                     np.linalg.norm(p[:, 2] - p[:, 0], axis=1)], axis=1)
    faces = combos[np.all(np.abs(edge - 2.0) < 1e-9, axis=1)]
    p = vertices[faces]
    outward = np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p.sum(axis=1)) > 0
    faces = np.where(outward[:, None], faces, faces[:, ::-1])
    return vertices / np.linalg.norm(vertices, axis=1, keepdims=True), faces.astype(np.int64)


def _subdivide(vertices, triangles):
    """Split each triangle into four through its edge midpoints (shared midpoints merged)."""
    edges = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    unique_edges, inverse = np.unique(np.sort(edges, axis=1), axis=0, return_inverse=True)
    midpoint = len(vertices) + inverse.ravel().reshape(3, -1).T  # (m, 3): ab, bc, ca
    vertices = np.concatenate([vertices, vertices[unique_edges].mean(axis=1)])
    a, b, c = triangles.T
    ab, bc, ca = midpoint.T
    triangles = np.concatenate([np.stack([a, ab, ca], 1), np.stack([b, bc, ab], 1),
                                np.stack([c, ca, bc], 1), np.stack([ab, bc, ca], 1)])
    return vertices, triangles


def _max_edge(vertices, triangles):
    p = vertices[triangles]
    return float(np.linalg.norm(p - np.roll(p, 1, axis=1), axis=2).max())


def sphere_surface(radius, resolution=None):
    """Icosphere of ``radius`` (m): an icosahedron subdivided ``level`` times, projected on the sphere.

    The level is the smallest whose longest edge is <= ``resolution``; the default is level 3
    (642 vertices, 1280 triangles, longest edge about 0.19 radius). Level ``L`` has
    ``10 * 4**L + 2`` vertices; requests finer than level 7 raise ``ValueError``.
    """
    radius = _positive("radius", radius)
    resolution = _resolution(resolution)
    vertices, triangles = _icosahedron()
    level = 0
    while True:
        done = level >= SPHERE_DEFAULT_LEVEL if resolution is None else (
            _max_edge(vertices, triangles) * radius <= resolution)
        if done:
            break
        if level == SPHERE_MAX_LEVEL:
            raise ValueError(f"sphere resolution {resolution} m is finer than icosphere level "
                             f"{SPHERE_MAX_LEVEL} allows for radius {radius} m")
        vertices, triangles = _subdivide(vertices, triangles)
        vertices /= np.linalg.norm(vertices, axis=1, keepdims=True)
        level += 1
    return vertices * radius, triangles


def sphere_inertia(mass, radius):
    """Inertia (3, 3) kg m^2 of a solid sphere about its centre: ``2/5 m r^2`` on the diagonal."""
    return 0.4 * mass * radius**2 * np.eye(3)


# ---------------------------------------------------------------------- solids of revolution
def _revolve(rho, z, segments):
    """Closed surface of revolution about z from a profile running from the bottom pole to the top.

    ``rho``/``z`` are the profile's interior points (rho > 0), ordered from bottom to top; the two
    poles ``(0, z_bottom)``/``(0, z_top)`` are passed as the first and last entries of ``z`` with
    ``rho`` 0. Each interior point becomes a ring of ``segments`` vertices.
    """
    rho_ring, z_ring = np.asarray(rho[1:-1], float), np.asarray(z[1:-1], float)
    ring_count = len(rho_ring)
    theta = 2.0 * np.pi * np.arange(segments) / segments
    rings = np.stack([rho_ring[:, None] * np.cos(theta), rho_ring[:, None] * np.sin(theta),
                      np.broadcast_to(z_ring[:, None], (ring_count, segments))], axis=-1)
    vertices = np.concatenate([[[0.0, 0.0, z[0]]], rings.reshape(-1, 3), [[0.0, 0.0, z[-1]]]])
    bottom, top = 0, len(vertices) - 1
    index = 1 + np.arange(ring_count * segments).reshape(ring_count, segments)
    nxt = np.roll(index, -1, axis=1)
    # Side quads (a_i, a_i+1, b_i+1, b_i): e_theta x e_up points outward.
    a, a1, b, b1 = index[:-1], nxt[:-1], index[1:], nxt[1:]
    sides = np.concatenate([np.stack([a, a1, b1], -1).reshape(-1, 3), np.stack([a, b1, b], -1).reshape(-1, 3)])
    fan_bottom = np.stack([np.full(segments, bottom), nxt[0], index[0]], -1)
    fan_top = np.stack([index[-1], nxt[-1], np.full(segments, top)], -1)
    triangles = np.concatenate([fan_bottom, sides, fan_top]).astype(np.int64)
    return vertices, triangles


def _segments(radius, resolution):
    if resolution is None:
        return CIRCLE_DEFAULT_SEGMENTS, 2.0 * np.pi * radius / CIRCLE_DEFAULT_SEGMENTS
    return max(8, int(math.ceil(2.0 * np.pi * radius / resolution - 1e-9))), resolution


def _splits(length, resolution, minimum=1):
    return max(minimum, int(math.ceil(length / resolution - 1e-9)))


def cylinder_surface(radius, height, resolution=None):
    """Capped cylinder along z from ``-height/2`` to ``height/2`` (m).

    The circle has ``max(8, ceil(2 pi r / resolution))`` segments (default 32, and the default
    ``resolution`` is that segment length); the side has ``ceil(height / resolution)`` bands and
    each cap ``ceil(radius / resolution)`` concentric rings, so the flat caps have interior vertices.
    """
    radius, height = _positive("radius", radius), _positive("height", height)
    segments, resolution = _segments(radius, _resolution(resolution))
    cap = _splits(radius, resolution)
    bands = _splits(height, resolution)
    cap_rho = radius * np.arange(1, cap + 1) / cap
    rho = np.concatenate([[0.0], cap_rho, np.full(bands - 1, radius), cap_rho[::-1], [0.0]])
    side_z = -height / 2 + height * np.arange(1, bands) / bands
    z = np.concatenate([np.full(cap + 1, -height / 2), side_z, np.full(cap + 1, height / 2)])
    return _revolve(rho, z, segments)


def cylinder_inertia(mass, radius, height):
    """Inertia (3, 3) kg m^2 of a solid cylinder (axis z) about its centre."""
    side = mass * (3.0 * radius**2 + height**2) / 12.0
    return np.diag([side, side, 0.5 * mass * radius**2])


def capsule_surface(radius, height, resolution=None):
    """Capsule along z: a cylinder with hemispherical caps, ``height`` the TOTAL length (m).

    ``height`` must be at least ``2 * radius`` (equality gives a sphere). Sampling follows
    :func:`cylinder_surface`; each hemisphere has ``max(2, ceil(pi r / 2 / resolution))`` latitude
    bands. Volume ``pi r^2 (h - 2r) + 4/3 pi r^3``.
    """
    radius, height = _positive("radius", radius), _positive("height", height)
    if height < 2.0 * radius:
        raise ValueError(f"capsule height {height} m is the total length including both caps and "
                         f"must be >= 2 * radius = {2.0 * radius} m")
    segments, resolution = _segments(radius, _resolution(resolution))
    half = height / 2.0 - radius  # half length of the straight part
    latitudes = _splits(0.5 * np.pi * radius, resolution, minimum=2)
    polar = 0.5 * np.pi * np.arange(0, latitudes + 1) / latitudes  # 0 at the pole, pi/2 at the equator
    cap_rho, cap_dz = radius * np.sin(polar), radius * np.cos(polar)
    bands = _splits(2.0 * half, resolution) if half > 0 else 1
    side_z = -half + 2.0 * half * np.arange(1, bands) / bands  # rings strictly between the equators
    # Bottom hemisphere (pole..equator), straight part, top hemisphere (equator..pole); with no
    # straight part the two equators are the same ring and it is kept once.
    top = slice(0, None) if half > 0 else slice(1, None)
    rho = np.concatenate([cap_rho, np.full(len(side_z), radius), cap_rho[::-1][top]])
    z = np.concatenate([-half - cap_dz, side_z, (half + cap_dz[::-1])[top]])
    return _revolve(rho, z, segments)


def capsule_volume(radius, height):
    """Volume (m^3) of a capsule of total length ``height``."""
    return np.pi * radius**2 * (height - 2.0 * radius) + 4.0 / 3.0 * np.pi * radius**3


# ---------------------------------------------------------------------------------- dispatch
_SHAPE_KEYS = {
    "box": ({"size"}, {"resolution"}),
    "sphere": ({"radius"}, {"resolution"}),
    "cylinder": ({"radius", "height"}, {"resolution"}),
    "capsule": ({"radius", "height"}, {"resolution"}),
}


def make_shape(spec):
    """Surface ``(vertices, triangles)`` from a dict such as a scene file's shape table.

    ``{"type": "box", "size": [sx, sy, sz]}`` (a single number makes a cube),
    ``{"type": "sphere", "radius": r}``, ``{"type": "cylinder"|"capsule", "radius": r, "height": h}``;
    every type accepts an optional ``"resolution"`` (target edge length, m). Lengths in m.
    Raises ``ValueError`` naming the offending key for unknown types, missing/unknown keys or
    non-positive values.
    """
    if not isinstance(spec, dict) or "type" not in spec:
        raise ValueError(f"shape spec must be a dict with a 'type' key, got {spec!r}")
    kind = spec["type"]
    if kind not in _SHAPE_KEYS:
        raise ValueError(f"unknown shape type {kind!r}; expected one of {sorted(_SHAPE_KEYS)}")
    required, optional = _SHAPE_KEYS[kind]
    keys = set(spec) - {"type"}
    if required - keys:
        raise ValueError(f"{kind} shape needs key(s) {sorted(required - keys)}")
    if keys - required - optional:
        raise ValueError(f"{kind} shape does not accept key(s) {sorted(keys - required - optional)}; "
                         f"allowed: {sorted(required | optional)}")
    resolution = spec.get("resolution")
    if kind == "box":
        size = np.asarray(spec["size"], dtype=float)
        if size.shape not in ((), (3,)):
            raise ValueError(f"box size must be a number or three numbers (m), got {spec['size']!r}")
        return box_surface(size, resolution)
    if kind == "sphere":
        return sphere_surface(spec["radius"], resolution)
    if kind == "cylinder":
        return cylinder_surface(spec["radius"], spec["height"], resolution)
    return capsule_surface(spec["radius"], spec["height"], resolution)
