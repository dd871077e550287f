"""Tetrahedral meshes: generators, orientation checks and the quadratic (P2) node layout.

Conventions: points ``(n, 3)`` float64 in metres; linear tets ``(t, 4)`` int64, positively oriented
(``det[x1-x0, x2-x0, x3-x0] > 0``); quadratic tets ``(t, 10)`` in meshio/VTK tetra10 order: the four
vertices, then the midside nodes of edges 01, 12, 02, 03, 13, 23.
"""
import numpy as np

from rigid.trimesh import is_closed

# local vertex pairs of the six tet edges, tetra10 order (also scikit-fem's local edge order)
TET_EDGES = np.array([[0, 1], [1, 2], [0, 2], [0, 3], [1, 3], [2, 3]])


# the shape quality (tet_quality) below which a file's tet is refused (check_shapes)
MIN_TET_QUALITY = 1e-6


def tet_signed_volumes(points, tets):
    """Signed volumes ``(t,)`` (m^3) of the tets' vertex simplices (first four nodes)."""
    x = np.asarray(points, dtype=float)[np.asarray(tets)[:, :4]]
    return np.linalg.det(x[:, 1:] - x[:, :1]) / 6.0


def check_tets(points, tets, rel_tol=1e-10):
    """Reorient inverted tets and reject degenerate ones.

    Returns ``(tets, flipped)``: a copy with every tet positively oriented and the indices ``(k,)``
    of the tets that were inverted (swap of vertices 1 and 2; for tetra10 the midside nodes are
    permuted to match), so the caller can warn. Raises ``ValueError`` naming the indices of tets
    whose volume is below ``rel_tol`` times the mean absolute tet volume.
    """
    tets = np.array(tets, dtype=np.int64)
    vol = tet_signed_volumes(points, tets)
    scale = np.mean(np.abs(vol)) if len(vol) else 0.0
    degenerate = np.nonzero(np.abs(vol) <= rel_tol * scale)[0]
    if len(degenerate) or scale == 0.0:
        raise ValueError(f"{len(degenerate)} of {len(tets)} tets are degenerate (near-zero volume): "
                         f"{index_list(degenerate)}")
    flipped = np.nonzero(vol < 0)[0]
    if tets.shape[1] == 4:
        swap = [0, 2, 1, 3]
    else:
        # swapping vertices 1 and 2 maps edges 01<->02, 12->21, 03, 13<->23
        swap = [0, 2, 1, 3, 6, 5, 4, 7, 9, 8]
    tets[flipped] = tets[flipped][:, swap]
    return tets, flipped


def tet_quality(points, tets):
    """Shape quality ``(t,)`` of the tets' vertex simplices: volume over that of the regular tet
    on their longest edge (1 regular; 0.27 for the cells' tets of a box mesh; near 0 for flat
    slivers and needles)."""
    x = np.asarray(points, dtype=float)[np.asarray(tets)[:, :4]]
    edges = x[:, [1, 2, 3, 2, 3, 3]] - x[:, [0, 0, 0, 1, 1, 2]]
    longest = np.linalg.norm(edges, axis=2).max(axis=1)
    return np.abs(tet_signed_volumes(points, tets)) * 6.0 * np.sqrt(2.0) / np.maximum(longest, 1e-300) ** 3


def check_shapes(points, tets, min_quality=MIN_TET_QUALITY):
    """Reject tets so flat or needle-shaped (:func:`tet_quality` below ``min_quality``) that the
    stiffness of their body is singular in floating point: a needle of quality 5e-8 in a 480-tet
    mesh made the step's matrix not positive definite to CHOLMOD, and the body, falling freely,
    reached 2e8 m/s in two steps. ``ValueError`` naming them and what to do."""
    quality = tet_quality(points, tets)
    bad = np.nonzero(quality < min_quality)[0]
    if len(bad):
        raise ValueError(f"{len(bad)} of {len(tets)} tets are too badly shaped to solve (flat or "
                         f"needle-shaped: volume below {min_quality:g} of the regular tet on their "
                         f"longest edge, worst {quality.min():.2g}): {index_list(bad)}; remesh with "
                         f"a quality bound (e.g. TetGen -q, gmsh's Optimize)")


def index_list(indices, shown=10):
    """``"tets 3, 17, 40"`` for messages: the first ``shown`` indices, then how many more."""
    indices = [int(i) for i in indices]
    text = ", ".join(map(str, indices[:shown]))
    more = len(indices) - shown
    return f"tets {text}" + (f" and {more} more" if more > 0 else "")


def _finish(points, tets):
    points = np.asarray(points, dtype=float)
    points = points - 0.5 * (points.min(axis=0) + points.max(axis=0))
    tets, _ = check_tets(points, tets)
    if not is_closed(surface_triangles(tets)):
        raise ValueError("generated tet mesh has an open boundary")
    return points, tets


def box_tet_mesh(size, resolution):
    """Box of ``size`` (3,) metres centred at the origin, ``resolution`` (3,) or int cells per axis.

    An int resolution is the cell count along the longest side; the others get proportionally
    many (at least one). Each hexahedral cell is split into six tets around one of its diagonals
    (Kuhn), mirrored in every other cell along each axis, so the mesh has the box's mirror
    symmetries wherever the cell counts are even. With the same diagonal in every cell (scikit-fem's
    ``init_tensor``) the mesh is anisotropic: a steel cantilever loaded straight down also bent
    sideways by 5-9% of its deflection, a sagging bridge twisted (its top face tilted 1.4 degrees
    across), and P1 tip errors were larger (21% against 15% at 40 x 4 x 4 cells).
    Returns ``(points (n, 3), tets (t, 4))``.
    """
    size = np.broadcast_to(np.asarray(size, dtype=float), (3,))
    if np.ndim(resolution) == 0:
        cells = np.maximum(1, np.round(resolution * size / size.max())).astype(int)
    else:
        cells = np.asarray(resolution, dtype=int)
    axes = [np.linspace(-0.5 * s, 0.5 * s, k + 1) for s, k in zip(size, cells)]
    points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    cell = np.stack(np.meshgrid(*(np.arange(k) for k in cells), indexing="ij"), axis=-1).reshape(-1, 3)
    mirrored = cell % 2
    stride = np.array([(cells[1] + 1) * (cells[2] + 1), cells[2] + 1, 1])
    tets = []
    for order in _AXIS_ORDERS:       # each tet walks from one corner to the opposite one, an axis at a time
        walk = np.cumsum(np.vstack([np.zeros(3, int), np.eye(3, dtype=int)[list(order)]]), axis=0)  # (4, 3)
        corners = cell[:, None, :] + np.abs(walk[None] - mirrored[:, None, :])             # (c, 4, 3)
        tets.append(corners @ stride)
    return _finish(points, np.concatenate(tets))


_AXIS_ORDERS = ((0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0))


def _disk_triangles(radius, resolution):
    """Triangulated disk ``(points (n, 2), triangles (m, 3))`` with ~``resolution`` cells across."""
    rings = max(1, int(np.ceil(resolution / 2)))
    pts = [np.zeros((1, 2))]
    for k in range(1, rings + 1):
        count = 6 * k
        angle = np.arange(count) * 2 * np.pi / count
        pts.append(radius * k / rings * np.column_stack([np.cos(angle), np.sin(angle)]))
    pts = np.concatenate(pts)
    from scipy.spatial import Delaunay
    return pts, Delaunay(pts).simplices.astype(np.int64)


def cylinder_tet_mesh(radius, height, resolution):
    """Cylinder along z, centred at the origin; ``resolution`` ~ cells across the diameter.

    A Delaunay-triangulated disk of concentric rings is extruded into prisms, each split into three
    tets with diagonals chosen by global vertex index so neighbouring prisms conform.
    Returns ``(points (n, 3), tets (t, 4))``.
    """
    xy, tri = _disk_triangles(radius, resolution)
    cell = 2 * radius / max(1, int(np.ceil(resolution / 2))) / 2
    layers = max(1, int(np.round(height / cell)))
    z = np.linspace(-0.5 * height, 0.5 * height, layers + 1)
    n2 = len(xy)
    points = np.column_stack([np.tile(xy, (layers + 1, 1)), np.repeat(z, n2)])
    tri = np.sort(tri, axis=1)
    a, b, c = tri.T
    tets = []
    for layer in range(layers):
        lo, hi = layer * n2, (layer + 1) * n2
        # quad-face diagonals run from the lower-index bottom vertex to the higher-index top one
        tets += [np.column_stack([a + lo, b + lo, c + lo, c + hi]),
                 np.column_stack([a + lo, b + lo, b + hi, c + hi]),
                 np.column_stack([a + lo, a + hi, b + hi, c + hi])]
    return _finish(points, np.concatenate(tets))


def sphere_tet_mesh(radius, resolution):
    """Ball of ``radius`` (m) centred at the origin; ``resolution`` cells across the diameter
    (rounded up to an even count, at least 2).

    The mirrored box mesh of the cube (:func:`box_tet_mesh`) mapped onto the ball: each cube shell
    ``max(|x|, |y|, |z|) = s`` goes to the sphere of radius ``s radius`` (Fong's mapping of the
    cube's surface to the sphere, which spreads the cells evenly), so the ball has the cube's mirror
    symmetries and cells about ``2 radius / resolution`` wide all through. scikit-fem's refined
    octahedron (``init_ball``), used before, moved only its boundary vertices onto the sphere: its
    boundary layer stayed stretched (longest edge 0.35 radius however fine), its refinements did
    not keep mirror symmetry (a soft ball of 64 tets dropped straight down left its first bounce
    spinning), and its edges were about twice the resolution asked for.
    Returns ``(points (n, 3), tets (t, 4))``.
    """
    cells = 2 * max(1, int(np.ceil(np.asarray(resolution, dtype=float) / 2 - 1e-9)))
    points, tets = box_tet_mesh((2.0, 2.0, 2.0), (cells, cells, cells))
    shell = np.abs(points).max(axis=1)
    on_cube = points / np.where(shell > 0, shell, 1.0)[:, None]         # on the shell's unit cube
    sq = on_cube ** 2
    # Fong (2015): x sqrt(1 - y^2/2 - z^2/2 + y^2 z^2/3), and cyclically, lies on the unit sphere
    other = np.stack([sq[:, [1, 2]], sq[:, [2, 0]], sq[:, [0, 1]]], axis=1)           # (n, 3, 2)
    sphere = on_cube * np.sqrt(1 - other.sum(axis=2) / 2 + other.prod(axis=2) / 3)
    return _finish(radius * shell[:, None] * sphere, tets)


def quadratic_tets(points, tets):
    """Quadratic (P2) layout of a linear tet mesh.

    Returns ``(points (n + e, 3), tets10 (t, 10))``: the input points followed by one midside node
    per unique edge ``e``, and tetra10 connectivity (vertices, then edges 01, 12, 02, 03, 13, 23).
    """
    points = np.asarray(points, dtype=float)
    tets = np.asarray(tets, dtype=np.int64)
    pairs = np.sort(tets[:, TET_EDGES], axis=2).reshape(-1, 2)
    edges, inverse = np.unique(pairs, axis=0, return_inverse=True)
    mid = 0.5 * (points[edges[:, 0]] + points[edges[:, 1]])
    tets10 = np.concatenate([tets, len(points) + inverse.reshape(-1, 6)], axis=1)
    return np.concatenate([points, mid]), tets10


def select_nodes_in_box(points, box_min, box_max, tol=1e-9):
    """Indices ``(k,)`` of the nodes inside the closed box ``[box_min, box_max]`` (m), +- ``tol``."""
    p = np.asarray(points, dtype=float)
    inside = np.all((p >= np.asarray(box_min) - tol) & (p <= np.asarray(box_max) + tol), axis=1)
    return np.nonzero(inside)[0]


def surface_triangles(tets):
    """Outward boundary triangles ``(f, 3)`` of a positively oriented tet mesh.

    A face is on the boundary when exactly one tet owns it. For tetra10 each boundary face is split
    into four triangles through its midside nodes (three corner triangles and the middle one).
    """
    tets = np.asarray(tets, dtype=np.int64)
    # face opposite vertex k, counter-clockwise seen from outside, then its edge nodes m01 m12 m20
    local = np.array([[1, 2, 3, 5, 9, 8],
                      [0, 3, 2, 7, 9, 6],
                      [0, 1, 3, 4, 8, 7],
                      [0, 2, 1, 6, 5, 4]])
    if tets.shape[1] == 4:
        local = local[:, :3]
    faces = tets[:, local].reshape(len(tets) * 4, -1)
    key = np.sort(faces[:, :3], axis=1)
    base = int(tets.max(initial=0)) + 1
    if float(base) ** 3 < 2.0 ** 62:
        # one int64 per sorted corner triple: a 1-D unique, several times faster than rows
        key = (key[:, 0] * base + key[:, 1]) * base + key[:, 2]
        _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    else:
        _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    f = faces[counts[inverse.ravel()] == 1]
    if tets.shape[1] == 4:
        return f
    return np.concatenate([f[:, [0, 3, 5]], f[:, [3, 1, 4]], f[:, [5, 4, 2]], f[:, [3, 4, 5]]])
