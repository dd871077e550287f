"""Tet-mesh face topology, crack opening by node duplication, and fragment extraction.

A crack is a set of mesh faces marked as cut. `split_mesh` opens it: every node on a
cut face is duplicated once per connected group of its incident tets, two incident
tets of a node being connected when they share a face that is not cut (the rule of
Bridson's fracture notes; O'Brien and Hodgins 1999 duplicate nodes the same way).
Tets keep their order and count, so per-tet state (stress, plastic strain) carries
over unchanged; per-node state is carried over with `node_origin`
(`transfer_node_state`), and node masses are summed again over each copy's own tets
(`lumped_mass_p1`), which conserves mass and momentum. `components` and `split_bodies`
then give the connected pieces, each a body of its own.

Faces waiting to open are named by (tet, local face) pairs (`face_tet_slots`), which
survive splitting and map to the pieces (`fragment_tet_slots`).

Node order of a tet row: P1 `(4,)` vertices; P2 `(10,)` meshio/VTK tetra10, four
vertices then edge nodes on edges 01, 12, 02, 03, 13, 23.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

# Local vertex slots of face j, the face opposite vertex j.
FACE_VERTEX_SLOTS = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])

# All node slots (vertices, then edge nodes) of face j for each element order.
FACE_NODE_SLOTS = {
    1: FACE_VERTEX_SLOTS,
    2: np.array([[1, 2, 3, 5, 8, 9],
                 [0, 2, 3, 6, 7, 9],
                 [0, 1, 3, 4, 7, 8],
                 [0, 1, 2, 4, 5, 6]]),
}


class TetFaces(NamedTuple):
    """Face topology of a tet mesh (faces identified by their three vertices).

    face_vertices: (face_count, 3) int, sorted vertex ids of each distinct face.
    tet_face: (tet_count, 4) int, face index of local face j (opposite vertex j).
    face_tets: (face_count, 2) int, the tets holding the face; column 1 is -1 on the
        boundary.
    face_local: (face_count, 2) int, local face index j inside each of face_tets
        (-1 where face_tets is -1).
    """

    face_vertices: np.ndarray
    tet_face: np.ndarray
    face_tets: np.ndarray
    face_local: np.ndarray

    @property
    def interior(self) -> np.ndarray:
        """(face_count,) bool, faces shared by two tets."""
        return self.face_tets[:, 1] >= 0


def _triple_keys(sorted_triples: np.ndarray, base: int) -> np.ndarray:
    """One int64 per sorted vertex triple (a*base^2 + b*base + c), collision-free."""
    if float(base) ** 3 >= 2.0**62:
        raise ValueError(f"mesh too large for int64 face keys ({base} nodes)")
    t = sorted_triples.astype(np.int64)
    return (t[:, 0] * base + t[:, 1]) * base + t[:, 2]


def tet_faces(tets: np.ndarray) -> TetFaces:
    """Face topology of a conforming tet mesh (P1 or P2; only the 4 vertices are used).

    Vectorised: all 4*tet_count local faces are sorted, keyed and grouped with one
    `np.unique`. Raises if a face is shared by more than two tets (non-manifold).
    """
    tets = np.asarray(tets)
    tet_count = tets.shape[0]
    local = np.sort(tets[:, :4][:, FACE_VERTEX_SLOTS], axis=2).reshape(-1, 3)
    base = int(tets[:, :4].max()) + 1 if tet_count else 1
    keys, first, inverse, counts = np.unique(
        _triple_keys(local, base), return_index=True, return_inverse=True,
        return_counts=True)
    if counts.size and counts.max() > 2:
        raise ValueError("non-manifold mesh: a face is shared by more than two tets")
    # Sort the local faces by face index; each face's one or two holders are then
    # consecutive, the first one being the lower (tet, local) pair.
    order = np.argsort(inverse, kind="stable")
    start = np.concatenate(([0], np.cumsum(counts)[:-1]))
    holder0 = order[start]
    holder1 = np.where(counts == 2, order[np.minimum(start + 1, order.size - 1)], -1)
    face_tets = np.stack([holder0 // 4, np.where(holder1 >= 0, holder1 // 4, -1)], 1)
    face_local = np.stack([holder0 % 4, np.where(holder1 >= 0, holder1 % 4, -1)], 1)
    return TetFaces(
        face_vertices=local[first],
        tet_face=inverse.reshape(tet_count, 4),
        face_tets=face_tets,
        face_local=face_local,
    )


def find_faces(faces: TetFaces, triples: np.ndarray) -> np.ndarray:
    """Indices into `faces.face_vertices` of the given (f, 3) vertex triples (any order).

    Raises ValueError if a triple is not a face of the mesh.
    """
    triples = np.sort(np.asarray(triples, dtype=np.int64).reshape(-1, 3), axis=1)
    if triples.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    base = int(max(faces.face_vertices.max(), triples.max())) + 1
    mesh_keys = _triple_keys(faces.face_vertices, base)  # sorted: np.unique output
    query = _triple_keys(triples, base)
    index = np.searchsorted(mesh_keys, query)
    index_clipped = np.minimum(index, mesh_keys.size - 1)
    if np.any(mesh_keys[index_clipped] != query):
        missing = triples[mesh_keys[index_clipped] != query][0]
        raise ValueError(f"face {missing.tolist()} is not a face of the mesh")
    return index_clipped


def infer_order(tets: np.ndarray, order: int | None = None) -> int:
    """Element order from the tet row length (4 -> P1, 10 -> P2); checks `order`."""
    nodes_per_tet = np.asarray(tets).shape[1]
    inferred = {4: 1, 10: 2}.get(nodes_per_tet)
    if inferred is None:
        raise ValueError(f"tets must have 4 or 10 nodes per row, got {nodes_per_tet}")
    if order is not None and order != inferred:
        raise ValueError(f"order={order} but tets have {nodes_per_tet} nodes per row")
    return inferred


class SplitMesh(NamedTuple):
    """Result of `split_mesh`.

    points: (new_node_count, 3) float, node positions; the first old_node_count rows
        equal the input points, duplicates are appended.
    tets: (tet_count, nodes_per_tet) int, same tets in the same order, renumbered.
    node_origin: (new_node_count,) int, the input node each new node copies
        (identity on the first old_node_count entries).
    """

    points: np.ndarray
    tets: np.ndarray
    node_origin: np.ndarray


def split_mesh(points: np.ndarray, tets: np.ndarray, cut_faces: np.ndarray,
               order: int | None = None, faces: TetFaces | None = None) -> SplitMesh:
    """Open the cut faces: duplicate each node on a cut face once per connected group.

    points: (n, 3); tets: (t, 4) P1 or (t, 10) P2 (see module docstring);
    cut_faces: (f, 3) vertex triples of faces to open (boundary faces are ignored,
    faces not in the mesh raise). `faces` may pass a precomputed `tet_faces(tets)`.

    Graph over (tet, local node) incidences: two incidences of the same node in two
    tets sharing a face that is not cut are joined; for every node lying on a cut
    face (vertex or P2 edge node) each connected component becomes one node. Tets
    that meet the crack only at a vertex or an edge therefore separate too, and a
    crack that stops inside the mesh keeps its front nodes shared.
    """
    points = np.asarray(points, dtype=float)
    tets = np.asarray(tets, dtype=np.int64)
    face_slots = FACE_NODE_SLOTS[infer_order(tets, order)]
    node_count = points.shape[0]
    faces = tet_faces(tets) if faces is None else faces
    cut = np.zeros(faces.face_vertices.shape[0], dtype=bool)
    cut[find_faces(faces, cut_faces)] = True
    cut &= faces.interior
    if not cut.any():
        return SplitMesh(points.copy(), tets.copy(), np.arange(node_count))
    # Nodes lying on a cut face: these are the only candidates for duplication.
    on_cut = np.zeros(node_count, dtype=bool)
    on_cut[tets[faces.face_tets[cut, 0][:, None], face_slots[faces.face_local[cut, 0]]]] = True
    group_count, group = _incidence_groups(tets, faces, cut, on_cut, face_slots)
    new_tets, node_origin = _node_per_group(tets, on_cut, group, group_count, node_count)
    if tets.shape[1] == 10:
        group_count, group = _conforming_edge_groups(new_tets, group, group_count)
        new_tets, node_origin = _node_per_group(tets, on_cut, group, group_count, node_count)
    return SplitMesh(points[node_origin], new_tets, node_origin)


# P2 edge slots 4..9 lie on the edges 01, 12, 02, 03, 13, 23
EDGE_VERTEX_SLOTS = np.array([[0, 1], [1, 2], [0, 2], [0, 3], [1, 3], [2, 3]])


def _conforming_edge_groups(new_tets, group, group_count):
    """P2: the incidence groups with each edge node's incidences regrouped by the copies of its
    edge's two vertices, so tets that still share both vertices of an edge share its edge node.
    (Grouped through faces, an edge node on the crack could be split while both its vertices stay
    shared through other tets; the mesh was then not conforming: two edge nodes on one edge, of
    which the assembly, one node per edge, keeps one, and the fragment's system was singular.)
    Returns (group_count, group (tets.size,))."""
    ends = np.sort(new_tets[:, EDGE_VERTEX_SLOTS], axis=2).reshape(-1, 2)       # (t * 6, 2)
    _, pair = np.unique(ends, axis=0, return_inverse=True)
    group = group.reshape(new_tets.shape).copy()
    group[:, 4:] = group_count + pair.reshape(-1, 6)
    return group_count + int(pair.max(initial=-1)) + 1, group.ravel()


def _incidence_groups(tets, faces, cut, on_cut, face_slots):
    """Connected groups of the (tet, local node) incidences ``tets.size``: incidences of a node
    on the crack in two tets joined by an uncut interior face are connected.
    Returns (group_count, group (tets.size,) int)."""
    joined = faces.interior & ~cut
    tet_a, tet_b = faces.face_tets[joined, 0], faces.face_tets[joined, 1]
    slots_a = face_slots[faces.face_local[joined, 0]]
    slots_b = face_slots[faces.face_local[joined, 1]]
    # Both tets hold the same face nodes; sorting by node id pairs the slots up.
    nodes_a = tets[tet_a[:, None], slots_a]
    nodes_b = tets[tet_b[:, None], slots_b]
    slots_a = np.take_along_axis(slots_a, np.argsort(nodes_a, axis=1), 1)
    slots_b = np.take_along_axis(slots_b, np.argsort(nodes_b, axis=1), 1)
    keep = on_cut[np.sort(nodes_a, axis=1)]
    nodes_per_tet = tets.shape[1]
    inc_a = (tet_a[:, None] * nodes_per_tet + slots_a)[keep]
    inc_b = (tet_b[:, None] * nodes_per_tet + slots_b)[keep]
    graph = sp.coo_matrix((np.ones(inc_a.size, dtype=np.int8), (inc_a, inc_b)),
                          shape=(tets.size, tets.size)).tocsr()
    return connected_components(graph, directed=False)


def _node_per_group(tets, on_cut, group, group_count, node_count):
    """One node per (node, incidence group) for nodes on the crack; nodes off it keep one copy.
    The first copy keeps the node's id, later copies are appended.
    Returns (new tets, node_origin (new_node_count,))."""
    incidence_node = tets.ravel()
    incidence_group = np.where(on_cut[incidence_node], group, -1)
    key = incidence_node * (group_count + 1) + (incidence_group + 1)
    unique_key, inverse = np.unique(key, return_inverse=True)
    key_node = unique_key // (group_count + 1)
    first_copy = np.ones(unique_key.size, dtype=bool)
    first_copy[1:] = key_node[1:] != key_node[:-1]
    new_id = np.where(first_copy, key_node,
                      node_count + np.cumsum(~first_copy) - 1)
    node_origin = np.concatenate([np.arange(node_count), key_node[~first_copy]])
    return new_id[inverse].reshape(tets.shape), node_origin


def components(tets: np.ndarray, node_count: int) -> tuple[np.ndarray, int]:
    """Connected components of a tet mesh, tets being connected through shared nodes.

    Returns (tet_label (t,) int in [0, count), count); labels are numbered in order of
    their lowest tet index.
    """
    tets = np.asarray(tets, dtype=np.int64)
    tet_count = tets.shape[0]
    if tet_count == 0:
        return np.zeros(0, dtype=np.int64), 0
    rows = np.repeat(np.arange(tet_count), tets.shape[1])
    # Bipartite tet-node graph: tets are vertices 0..t-1, nodes t..t+n-1.
    incidence = sp.coo_matrix((np.ones(rows.size, dtype=np.int8),
                               (rows, tet_count + tets.ravel())),
                              shape=(tet_count + node_count,) * 2).tocsr()
    _, label = connected_components(incidence, directed=False)
    _, first, tet_label = np.unique(label[:tet_count], return_index=True,
                                    return_inverse=True)
    # Renumber by lowest tet index (np.unique orders by scipy's label).
    rank = np.empty(first.size, dtype=np.int64)
    rank[np.argsort(first)] = np.arange(first.size)
    return rank[tet_label], int(first.size)


class Fragment(NamedTuple):
    """One connected piece of a mesh, with compact node numbering.

    points: (fragment_node_count, 3) float, node positions.
    tets: (fragment_tet_count, nodes_per_tet) int, indices into `points`.
    node_index: (fragment_node_count,) int, input node of each fragment node.
    tet_index: (fragment_tet_count,) int, input tet of each fragment tet (ascending).
    """

    points: np.ndarray
    tets: np.ndarray
    node_index: np.ndarray
    tet_index: np.ndarray


def split_bodies(points: np.ndarray, tets: np.ndarray,
                 tet_label: np.ndarray | None = None) -> list[Fragment]:
    """Split a mesh into its connected components, each with compact node numbering.

    `tet_label` may pass labels from `components`. Nodes used by no tet are dropped.
    Loops over fragments only (each fragment is one vectorised `np.unique`).
    """
    points = np.asarray(points)
    tets = np.asarray(tets, dtype=np.int64)
    if tet_label is None:
        tet_label, _ = components(tets, points.shape[0])
    order = np.argsort(tet_label, kind="stable")
    bounds = np.flatnonzero(np.diff(tet_label[order])) + 1
    fragments = []
    for tet_index in np.split(order, bounds):
        node_index, local = np.unique(tets[tet_index], return_inverse=True)
        fragments.append(Fragment(points[node_index], local.reshape(-1, tets.shape[1]),
                                  node_index, tet_index))
    return fragments


def lumped_mass_from_elements(tets: np.ndarray, tet_node_mass: np.ndarray,
                              node_count: int) -> np.ndarray:
    """(n,) node masses, kg: each node sums its incident tets' per-node contributions.

    tet_node_mass: (t, nodes_per_tet) kg, a lumping that is a sum over elements (e.g.
    row sums of element mass matrices). Applied after `split_mesh` to the same per-tet
    contributions, each copy of a node gets the mass of its own tets, so total mass is
    unchanged and, with velocities copied from `node_origin`, momentum is conserved
    exactly.
    """
    return np.bincount(np.asarray(tets).ravel(), weights=np.asarray(tet_node_mass).ravel(),
                       minlength=node_count)


# the share of a P2 tet's (tetra10's) mass each of its nodes carries: HRZ lumping's 1/36 at a
# corner and 4/27 at a mid-edge node (the consistent diagonal, m/70 and 8m/105, scaled to sum to
# m: fem.model._mass_matrices, element by element for straight-sided tets), and in the momentum of
# a consistent mass the rows' sums, -1/20 and 1/5 (fem.momentum.mass_weights)
P2_LUMPED = (1.0 / 36.0,) * 4 + (4.0 / 27.0,) * 6
P2_ROW_SUMS = (-1.0 / 20.0,) * 4 + (1.0 / 5.0,) * 6


def element_mass_shares(tets: np.ndarray, tet_volume: np.ndarray, density, node_count: int,
                        shares) -> np.ndarray:
    """(n,) kg: each tet's mass ``density |V|`` shared among its first ``len(shares)`` nodes in
    the fractions ``shares`` (P2_LUMPED, P2_ROW_SUMS, or a quarter each for P1), summed per node."""
    shares = np.asarray(shares, dtype=float)
    tet_mass = np.abs(np.asarray(tet_volume, dtype=float)) * np.asarray(density, dtype=float)
    return lumped_mass_from_elements(np.asarray(tets)[:, :len(shares)], tet_mass[:, None] * shares,
                                     node_count)


def lumped_mass_p1(tets: np.ndarray, tet_volume: np.ndarray, density,
                   node_count: int) -> np.ndarray:
    """(n,) P1 lumped node masses, kg: each tet gives density*|V|/4 to each of its vertices.

    tets: (t, 4) or (t, 10) (the vertices are used); tet_volume: (t,) m^3, signed or not;
    density: scalar or (t,) kg/m^3.
    """
    tet_mass = np.abs(np.asarray(tet_volume, dtype=float)) * np.asarray(density, dtype=float)
    return lumped_mass_from_elements(np.asarray(tets)[:, :4],
                                     np.repeat(tet_mass[:, None] / 4.0, 4, 1), node_count)


def transfer_node_state(node_origin: np.ndarray, *node_arrays: np.ndarray):
    """Copy per-node arrays (velocity, displacement, ...) to the split mesh's nodes.

    Each new node takes the value of the node it was duplicated from. Returns one array
    per input (a single array if one was given). Recompute masses from the tets (see
    `lumped_mass_from_elements`); do not copy them.
    """
    moved = tuple(np.asarray(a)[node_origin] for a in node_arrays)
    return moved[0] if len(moved) == 1 else moved


def face_tet_slots(faces: TetFaces, face: np.ndarray) -> np.ndarray:
    """(f, 2) int (tet, local face j) naming each face by a tet holding it: unlike a face
    index, the pair survives `split_mesh` (tets keep their order) and maps to fragments
    (`fragment_tet_slots`)."""
    face = np.asarray(face, dtype=np.int64)
    return np.stack([faces.face_tets[face, 0], faces.face_local[face, 0]], 1)


def tet_slot_faces(faces: TetFaces, slots: np.ndarray) -> np.ndarray:
    """(f,) face indices of (tet, local face) pairs, the inverse of `face_tet_slots`."""
    slots = np.asarray(slots, dtype=np.int64).reshape(-1, 2)
    return faces.tet_face[slots[:, 0], slots[:, 1]]


def fragment_tet_slots(faces: TetFaces, face: np.ndarray, tet_index: np.ndarray,
                       fragment_faces: TetFaces) -> np.ndarray:
    """(p, 2) (fragment tet, local face) of the given faces of the parent mesh that are still
    interior faces of a fragment (faces that did not open), one row per holding tet.

    faces: the parent's `TetFaces`; face: (f,) face indices; tet_index: (ft,) ascending
    parent tet of each fragment tet (`Fragment.tet_index`); fragment_faces: the fragment's.
    """
    holders = np.concatenate([np.stack([faces.face_tets[face, k], faces.face_local[face, k]], 1)
                              for k in (0, 1)])
    holders = holders[np.isin(holders[:, 0], tet_index)]
    local_tet = np.searchsorted(tet_index, holders[:, 0])
    still = fragment_faces.interior[fragment_faces.tet_face[local_tet, holders[:, 1]]]
    result = np.stack([local_tet[still], holders[still, 1]], 1)
    return result.reshape(-1, 2).astype(np.int64)
