"""Closed triangle surfaces: boundary of tet meshes, closedness and orientation checks.

Conventions: vertices are ``(n, 3)`` float64 (m), triangles ``(m, 3)`` int64 indices, counter-
clockwise seen from outside (outward normals), so the signed volume of a closed surface is positive.
"""
import numpy as np


def tet_boundary(tets):
    """Boundary triangles ``(f, 3)`` of a tet mesh ``(t, 4)``, oriented outward for positive tets.

    A face is on the boundary when exactly one tet owns it. Works for the vertex part of
    quadratic tets too (pass ``tets[:, :4]``).
    """
    tets = np.asarray(tets, dtype=np.int64)
    # faces opposite vertex 0..3, ordered so that their normal points away from the opposite vertex
    local = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])
    faces = tets[:, local].reshape(-1, 3)
    key = np.sort(faces, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return faces[counts[inverse.ravel()] == 1]


def tet_boundary_owner(tets):
    """Like :func:`tet_boundary` but also returns the owning tet and local face index of each face."""
    tets = np.asarray(tets, dtype=np.int64)
    local = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])
    faces = tets[:, local].reshape(-1, 3)
    key = np.sort(faces, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    keep = counts[inverse.ravel()] == 1
    index = np.nonzero(keep)[0]
    return faces[keep], index // 4, index % 4


def edge_use_counts(triangles):
    """Directed-edge bookkeeping: returns (undirected edge counts, directed duplicates count)."""
    tri = np.asarray(triangles, dtype=np.int64)
    directed = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    undirected = np.sort(directed, axis=1)
    _, counts = np.unique(undirected, axis=0, return_counts=True)
    _, dcounts = np.unique(directed, axis=0, return_counts=True)
    return counts, int(np.sum(dcounts > 1))


def is_closed(triangles):
    """True when every edge is shared by exactly two triangles with opposite directions."""
    if len(triangles) < 4:
        return False
    counts, duplicated = edge_use_counts(triangles)
    return bool(np.all(counts == 2) and duplicated == 0)


def signed_volume(vertices, triangles):
    """Volume enclosed by a closed surface (m^3); negative when the triangles face inward."""
    v = np.asarray(vertices, dtype=float)[np.asarray(triangles)]
    return float(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0)


def orient_outward(vertices, triangles):
    """Return the triangles flipped if needed so the enclosed volume is positive."""
    triangles = np.asarray(triangles, dtype=np.int64)
    if signed_volume(vertices, triangles) < 0:
        return triangles[:, ::-1].copy()
    return triangles


def shells(triangles):
    """``(count, label)``: the connected pieces of a surface (triangles joined through shared
    edges: two closed shells touching at a vertex are two pieces) and each triangle's piece (m,)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    t = np.asarray(triangles, dtype=np.int64)
    m = len(t)
    if m == 0:
        return 0, np.zeros(0, np.int64)
    edges = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    _, edge = np.unique(edges, axis=0, return_inverse=True)
    edge = edge.ravel()
    order = np.argsort(edge, kind="stable")
    owner = np.tile(np.arange(m), 3)[order]
    same = edge[order][1:] == edge[order][:-1]      # the triangles along one edge, in a chain
    graph = coo_matrix((np.ones(int(same.sum())), (owner[:-1][same], owner[1:][same])), shape=(m, m))
    count, label = connected_components(graph, directed=False)
    return int(count), label.astype(np.int64)


def winding_number(point, vertices, triangles):
    """How many times the closed surface winds around ``point`` (3,): the triangles' solid
    angles seen from it over 4 pi (Van Oosterom and Strackee); about 1 inside an outward
    surface, -1 inside an inward one, 0 outside."""
    v = np.asarray(vertices, dtype=float)[np.asarray(triangles)] - np.asarray(point, dtype=float)
    a, b, c = v[:, 0], v[:, 1], v[:, 2]
    la, lb, lc = (np.linalg.norm(x, axis=1) for x in (a, b, c))
    numerator = np.einsum("ij,ij->i", a, np.cross(b, c))
    denominator = la * lb * lc + np.einsum("ij,ij->i", a, b) * lc + np.einsum("ij,ij->i", a, c) * lb \
        + np.einsum("ij,ij->i", b, c) * la
    return float(2.0 * np.arctan2(numerator, denominator).sum() / (4.0 * np.pi))


def orient_shells(vertices, triangles):
    """The triangles of a closed surface with every piece facing away from the solid: a piece
    inside an even number of others (the outer surface; an island inside a cavity) outward, one
    inside an odd number (a cavity's wall) inward, however each was written. Nesting is read from
    the winding number of one vertex of each piece about the pieces whose box holds its box."""
    triangles = np.asarray(triangles, dtype=np.int64)
    count, label = shells(triangles)
    if count <= 1:
        return orient_outward(vertices, triangles)
    v = np.asarray(vertices, dtype=float)
    order = np.argsort(label, kind="stable")
    members = np.split(order, np.cumsum(np.bincount(label, minlength=count))[:-1])
    corners = [v[np.unique(triangles[m])] for m in members]
    low, high = np.array([c.min(axis=0) for c in corners]), np.array([c.max(axis=0) for c in corners])
    out = triangles.copy()
    for k, m in enumerate(members):
        holds = np.flatnonzero(np.all(low <= low[k], axis=1) & np.all(high >= high[k], axis=1))
        depth = sum(abs(winding_number(corners[k][0], v, triangles[members[j]])) > 0.5
                    for j in holds if j != k)
        if (signed_volume(v, triangles[m]) > 0) != (depth % 2 == 0):
            out[m] = triangles[m][:, ::-1]
    return out


def crossing_pieces(vertices, triangles, samples=64):
    """Pairs ``(i, j)`` of the surface's pieces (:func:`shells` labels) that cross each other:
    some of piece i's vertices (up to ``samples`` of them, spread over it) lie inside piece j
    and some outside (by the winding number about j). Nested pieces (a cavity, an island) lie
    wholly inside or outside; crossing ones overlap, and their overlap counts twice."""
    triangles = np.asarray(triangles, dtype=np.int64)
    count, label = shells(triangles)
    if count <= 1:
        return []
    v = np.asarray(vertices, dtype=float)
    members = [triangles[label == k] for k in range(count)]
    corners = [np.unique(m) for m in members]
    low = np.array([v[c].min(axis=0) for c in corners])
    high = np.array([v[c].max(axis=0) for c in corners])
    meet = np.all(low[:, None] <= high[None], axis=2) & np.all(high[:, None] >= low[None], axis=2)
    np.fill_diagonal(meet, False)
    out = []
    for i, j in zip(*np.nonzero(meet)):
        pick = corners[i][np.linspace(0, len(corners[i]) - 1, min(samples, len(corners[i]))).astype(int)]
        inside = [abs(winding_number(v[p], v, members[j])) > 0.5 for p in pick]
        if any(inside) and not all(inside):
            out.append((int(i), int(j)))
    return out


def compact(vertices, triangles):
    """Drop vertices no triangle uses; returns (vertices, triangles, kept_vertex_indices)."""
    used = np.unique(triangles)
    remap = -np.ones(len(vertices), dtype=np.int64)
    remap[used] = np.arange(len(used))
    return np.asarray(vertices)[used], remap[triangles], used


def vertex_normals(vertices, triangles):
    """Area-weighted unit vertex normals ``(n, 3)``."""
    v = np.asarray(vertices, dtype=float)
    face_n = np.cross(v[triangles[:, 1]] - v[triangles[:, 0]], v[triangles[:, 2]] - v[triangles[:, 0]])
    n = np.zeros_like(v)
    for k in range(3):
        np.add.at(n, triangles[:, k], face_n)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return n / np.where(length > 0, length, 1.0)


def merge_coincident(vertices, triangles, tolerance=1e-6):
    """``(vertices, triangles, merged)``: vertices within ``tolerance`` times the mesh's extent of
    each other made one (a surface whose triangles each carry their own corners, as some
    exporters write them, in single precision too), triangles renumbered; ``merged``: how many
    vertices were dropped."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree
    v = np.asarray(vertices, dtype=float)
    scale = float(np.ptp(v, axis=0).max()) if len(v) else 0.0
    pairs = cKDTree(v).query_pairs(tolerance * scale, output_type="ndarray") if scale > 0 else ()
    if not len(pairs):
        return v, triangles, 0
    n = len(v)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    count, label = connected_components(graph, directed=False)
    first = np.full(count, n)
    np.minimum.at(first, label, np.arange(n))
    return v[first], label[triangles], n - count
