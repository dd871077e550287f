"""Eigenvalue-threshold fracture: stress smoothing, crack criterion, crack faces.

Algorithm (Bridson's fracture notes; O'Brien and Hodgins 1999; Mueller and Gross 2004):
1. smooth each element's stress with its face neighbours (volume-weighted mean),
2. take the largest principal stress sigma_1 of the smoothed stress (one batched eigh);
   where sigma_1 exceeds the tensile strength, a crack opens perpendicular to its
   eigenvector (compression, sigma_1 <= 0, never cracks),
3. the crack runs along the cracking element's interior mesh face most nearly parallel
   to the crack plane; `fem.split.split_mesh` then opens the chosen faces.

Stress arrays are (tet_count, 3, 3) in Pa; `points` and stresses must share one frame
(rest frame for the floating-frame model, world frame otherwise).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from fem.split import FACE_VERTEX_SLOTS, TetFaces, tet_faces


def face_neighbours(tets: np.ndarray, faces: TetFaces | None = None) -> sp.csr_matrix:
    """(t, t) symmetric sparse adjacency, 1 where two tets share a face, 0 diagonal."""
    faces = tet_faces(tets) if faces is None else faces
    tet_count = np.asarray(tets).shape[0]
    pair = faces.face_tets[faces.interior]
    rows = np.concatenate([pair[:, 0], pair[:, 1]])
    cols = np.concatenate([pair[:, 1], pair[:, 0]])
    return sp.csr_matrix((np.ones(rows.size), (rows, cols)), shape=(tet_count, tet_count))


def smoothing_operator(volume: np.ndarray, adjacency: sp.spmatrix) -> sp.csr_matrix:
    """(t, t) sparse row-stochastic smoothing operator W.

    W[e, k] = V_k / sum_{j in {e} U N(e)} V_j for k in {e} U N(e) (N = face
    neighbours), else 0: each row is a volume-weighted mean, its weights sum to one.
    volume: (t,) m^3, element volumes (absolute value is used).
    """
    volume = np.abs(np.asarray(volume, dtype=float))
    tet_count = volume.size
    stencil = (sp.csr_matrix(adjacency, shape=(tet_count, tet_count)) != 0).astype(float)
    stencil = stencil + sp.identity(tet_count, format="csr")
    weighted = stencil @ sp.diags(volume)
    row_total = np.asarray(weighted.sum(axis=1)).ravel()
    return (sp.diags(1.0 / row_total) @ weighted).tocsr()


def smooth_stress(sigma: np.ndarray, volume: np.ndarray,
                  adjacency: sp.spmatrix) -> np.ndarray:
    """(t, 3, 3) smoothed stress, Pa: sigma_s[e] = sum_k W[e, k] sigma[k].

    W is `smoothing_operator(volume, adjacency)`: the volume-weighted mean over the
    element and its face neighbours (Bridson's notes: smooth to avoid mesh artifacts).
    """
    sigma = np.asarray(sigma, dtype=float)
    flat = smoothing_operator(volume, adjacency) @ sigma.reshape(sigma.shape[0], 9)
    return flat.reshape(sigma.shape)


class CrackCandidates(NamedTuple):
    """Elements that crack this step, most overstressed first.

    element: (k,) int, element indices.
    normal: (k, 3) float, unit crack normal (eigenvector of the largest principal
        stress; sign fixed so its largest-magnitude component is positive).
    principal_stress: (k,) float, Pa, largest principal stress sigma_1.
    """

    element: np.ndarray
    normal: np.ndarray
    principal_stress: np.ndarray


def fracture_candidates(sigma: np.ndarray, fracture_stress, max_cracks: int | None = None,
                        unbreakable: np.ndarray | None = None) -> CrackCandidates:
    """Elements whose largest principal stress exceeds the tensile strength.

    sigma: (t, 3, 3) Pa, usually smoothed (`smooth_stress`); symmetrised here.
    fracture_stress: scalar or (t,) Pa, tensile strength, must be > 0.
    max_cracks: keep only this many elements per call (the most overstressed, ranked
        by (sigma_1 - s_f) / s_f), so one bad step cannot pulverise a body.
    unbreakable: optional (t,) bool mask of elements that never crack.

    An element cracks iff sigma_1 > fracture_stress; since fracture_stress > 0,
    compression (sigma_1 <= 0) never cracks, whatever its magnitude.
    """
    sigma = np.asarray(sigma, dtype=float)
    threshold = np.broadcast_to(np.asarray(fracture_stress, dtype=float), sigma.shape[:1])
    if np.any(~(threshold > 0.0)):
        raise ValueError("fracture_stress must be positive (tensile strength)")
    # One batched symmetric eigensolve; eigenvalues ascending, so column -1 is sigma_1.
    eigenvalue, eigenvector = np.linalg.eigh(0.5 * (sigma + np.swapaxes(sigma, 1, 2)))
    sigma_1 = eigenvalue[:, -1]
    cracks = sigma_1 > threshold
    if unbreakable is not None:
        cracks &= ~np.asarray(unbreakable, dtype=bool)
    element = np.flatnonzero(cracks)
    overstress = (sigma_1[element] - threshold[element]) / threshold[element]
    element = element[np.argsort(-overstress, kind="stable")]
    if max_cracks is not None:
        element = element[:max(int(max_cracks), 0)]
    normal = eigenvector[element, :, -1]
    # Canonical sign: largest-magnitude component positive (eigh's sign is arbitrary).
    lead = np.take_along_axis(normal, np.argmax(np.abs(normal), axis=1)[:, None], 1)
    normal = normal * np.where(lead < 0.0, -1.0, 1.0)
    return CrackCandidates(element, normal, sigma_1[element])


def crack_faces(points: np.ndarray, tets: np.ndarray, element: np.ndarray,
                normal: np.ndarray, faces: TetFaces | None = None,
                faces_per_element: int = 1) -> np.ndarray:
    """(f, 3) vertex triples of the mesh faces to open for the given cracks.

    The crack through element e is the plane through its centroid perpendicular to
    normal[e]. Rule: among e's interior faces (shared with a neighbour; boundary faces
    would open nothing), take the `faces_per_element` (1 or 2) whose unit normals n_f
    are most nearly parallel to the crack normal, i.e. largest |n_f . normal|: the mesh
    faces whose planes are closest in direction to the crack plane. Ties go to the
    lower local face index. Elements without interior faces yield nothing. Faces chosen
    by several elements appear once.

    points: (n, 3) m; tets: (t, 4) or (t, 10); element: (k,); normal: (k, 3) unit.
    """
    points = np.asarray(points, dtype=float)
    element = np.asarray(element, dtype=np.int64)
    normal = np.asarray(normal, dtype=float).reshape(-1, 3)
    faces = tet_faces(tets) if faces is None else faces
    if element.size == 0:
        return np.zeros((0, 3), dtype=np.int64)
    # Unit normals of the 4 faces of each cracking element: (k, 4, 3).
    corner = points[np.asarray(tets)[element][:, FACE_VERTEX_SLOTS]]
    face_normal = np.cross(corner[:, :, 1] - corner[:, :, 0],
                           corner[:, :, 2] - corner[:, :, 0])
    face_normal /= np.linalg.norm(face_normal, axis=2, keepdims=True)
    alignment = np.abs(np.einsum("kfi,ki->kf", face_normal, normal))
    face_index = faces.tet_face[element]
    interior = faces.interior[face_index]
    alignment = np.where(interior, alignment, -np.inf)
    best = np.argsort(-alignment, axis=1, kind="stable")[:, :faces_per_element]
    chosen = np.take_along_axis(face_index, best, 1)
    valid = np.isfinite(np.take_along_axis(alignment, best, 1))
    return faces.face_vertices[np.unique(chosen[valid])]


def chosen_faces(points, tets, element, normal, faces):
    """Per cracking element, its interior face most parallel to the crack plane:
    (face index (k,) with -1 where it has none, face centroid (k, 3))."""
    corner = points[np.asarray(tets)[element][:, FACE_VERTEX_SLOTS]]
    face_normal = np.cross(corner[:, :, 1] - corner[:, :, 0],
                           corner[:, :, 2] - corner[:, :, 0])
    face_normal /= np.linalg.norm(face_normal, axis=2, keepdims=True)
    alignment = np.abs(np.einsum("kfi,ki->kf", face_normal, normal))
    face_index = faces.tet_face[element]
    alignment = np.where(faces.interior[face_index], alignment, -np.inf)
    best = np.argmax(alignment, axis=1)
    chosen = np.where(np.isfinite(alignment.max(axis=1)),
                      np.take_along_axis(face_index, best[:, None], 1)[:, 0], -1)
    centroid = np.take_along_axis(corner, best[:, None, None, None], 1)[:, 0].mean(axis=1)
    return chosen, centroid


def planar_crack(points: np.ndarray, tets: np.ndarray, candidates: CrackCandidates,
                 faces: TetFaces | None = None, tolerance: float = 0.35,
                 max_cracks: int | None = None) -> CrackCandidates:
    """The candidates that open one planar crack: the most overstressed element (the seed)
    and every candidate whose chosen face lies on the seed's crack plane.

    The plane passes through the centroid of the seed's chosen face (see `crack_faces`) with
    the seed's crack normal; a candidate joins when its chosen face's centroid is within
    `tolerance` times the seed's mean edge length of that plane. One plane per call keeps a
    uniformly stressed body from opening many parallel cracks at once (it breaks where it is
    weakest, then unloads); the rest are re-examined at the next check. `max_cracks` then
    keeps the most overstressed of the plane's elements.
    """
    points = np.asarray(points, dtype=float)
    faces = tet_faces(tets) if faces is None else faces
    if candidates.element.size == 0:
        return candidates
    chosen, centroid = chosen_faces(points, tets, candidates.element, candidates.normal, faces)
    valid = np.flatnonzero(chosen >= 0)
    if valid.size == 0:
        return CrackCandidates(*(a[:0] for a in candidates))
    seed = valid[0]
    corner = points[np.asarray(tets)[candidates.element[seed], :4]]
    edge = np.linalg.norm(corner[:, None] - corner[None], axis=2).sum() / 12.0
    distance = np.abs((centroid - centroid[seed]) @ candidates.normal[seed])
    keep = np.flatnonzero((chosen >= 0) & (distance <= tolerance * edge))
    if max_cracks is not None:
        keep = keep[:max(int(max_cracks), 1)]
    return CrackCandidates(*(a[keep] for a in candidates))


def find_crack_faces(points: np.ndarray, tets: np.ndarray, sigma: np.ndarray,
                     volume: np.ndarray, fracture_stress, max_cracks: int | None = None,
                     unbreakable: np.ndarray | None = None,
                     faces: TetFaces | None = None,
                     faces_per_element: int = 1) -> tuple[np.ndarray, CrackCandidates]:
    """Whole fracture check: smooth, test, choose faces. Returns (cut_faces, candidates).

    Pass `cut_faces` to `fem.split.split_mesh` when it is non-empty.
    """
    faces = tet_faces(tets) if faces is None else faces
    smoothed = smooth_stress(sigma, volume, face_neighbours(tets, faces))
    candidates = fracture_candidates(smoothed, fracture_stress, max_cracks, unbreakable)
    cut = crack_faces(points, tets, candidates.element, candidates.normal, faces,
                      faces_per_element)
    return cut, candidates
