"""Eigenvalue-threshold fracture of one tet mesh: stress smoothing, crack criterion, crack faces.

Algorithm (Bridson's fracture notes; O'Brien and Hodgins 1999; Mueller and Gross 2004):
1. smooth each element's stress with its face neighbours (volume-weighted mean),
2. take the largest principal stress sigma_1 of the smoothed stress (one batched eigh of
   the elements that a cheap bound, `tension_bound`, does not rule out);
   where sigma_1 exceeds the tensile strength, a crack opens perpendicular to its
   eigenvector (compression, sigma_1 <= 0, never cracks); ductile bodies also tear where
   their equivalent plastic strain passes a tearing strain while they flow,
3. the crack runs along the cracking element's interior mesh face most nearly parallel
   to the crack plane, one plane per check (`planar_crack`); `fem.split.split_mesh` then
   opens the chosen faces.

`find_crack` is the whole check as the simulator runs it; `FractureModel` holds what it
needs of a mesh (built once per mesh by `fracture_model`).

Stress arrays are (tet_count, 3, 3) in Pa; `points` and stresses must share one frame
(rest frame for the floating-frame model, world frame otherwise).
"""

from __future__ import annotations

from dataclasses import dataclass
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


def smooth_stress(sigma: np.ndarray, smoothing: sp.spmatrix) -> np.ndarray:
    """(t, 3, 3) smoothed stress, Pa: sigma_s[e] = sum_k W[e, k] sigma[k].

    smoothing: W, `smoothing_operator(volume, face_neighbours(tets))`, the volume-weighted
    mean over the element and its face neighbours (Bridson's notes: smooth to avoid mesh
    artifacts).
    """
    sigma = np.asarray(sigma, dtype=float)
    return (smoothing @ sigma.reshape(sigma.shape[0], 9)).reshape(sigma.shape)


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

    def take(self, index) -> CrackCandidates:
        """The candidates at `index` (an index array or a slice), in that order."""
        return CrackCandidates(*(a[index] for a in self))

    def then(self, other: CrackCandidates) -> CrackCandidates:
        """These candidates followed by `other`'s."""
        return CrackCandidates(*(np.concatenate(pair) for pair in zip(self, other)))


def principal_tension(sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Largest principal stress (k,) Pa and its unit direction (k, 3) of stresses (k, 3, 3).

    One batched symmetric eigensolve of the symmetrised stress; the direction's sign is
    canonical (largest-magnitude component positive; eigh's sign is arbitrary).
    """
    sigma = np.asarray(sigma, dtype=float)
    # Eigenvalues ascending, so column -1 is sigma_1.
    eigenvalue, eigenvector = np.linalg.eigh(0.5 * (sigma + np.swapaxes(sigma, 1, 2)))
    normal = eigenvector[:, :, -1]
    lead = np.take_along_axis(normal, np.argmax(np.abs(normal), axis=1)[:, None], 1)
    return eigenvalue[:, -1], normal * np.where(lead < 0.0, -1.0, 1.0)


def tension_bound(sigma: np.ndarray) -> np.ndarray:
    """(k,) Pa, an upper bound of the largest principal stress of stresses (k, 3, 3) (their
    symmetric part): ``tr/3 + sqrt(2/3) |dev|_F`` (the deviatoric eigenvalues sum to zero, so
    the largest is at most sqrt(2/3) of their norm; equal for uniaxial stress), raised by 1e-10
    of ``|sigma|_F`` to cover the eigensolver's rounding. Cheap (no eigensolve), so the checks
    solve for the principal stress only where it may matter.
    """
    flat = np.asarray(sigma, dtype=float).reshape(-1, 9)
    mean = (flat[:, 0] + flat[:, 4] + flat[:, 8]) / 3.0
    dev = 0.5 * (flat + flat[:, [0, 3, 6, 1, 4, 7, 2, 5, 8]])
    dev[:, [0, 4, 8]] -= mean[:, None]
    return mean + np.sqrt(2.0 / 3.0 * np.einsum("ki,ki->k", dev, dev)) + \
        1e-10 * np.sqrt(np.einsum("ki,ki->k", flat, flat))


def fracture_candidates(sigma: np.ndarray, fracture_stress, max_cracks: int | None = None,
                        unbreakable: np.ndarray | None = None) -> CrackCandidates:
    """Elements whose largest principal stress exceeds the tensile strength.

    sigma: (t, 3, 3) Pa, usually smoothed (`smooth_stress`); symmetrised here.
    fracture_stress: scalar or (t,) Pa, tensile strength, must be > 0 (inf: never).
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
    # only elements whose bound (tension_bound) passes the strength can crack: the eigensolve
    # runs on those alone (each matrix is solved on its own, so the values are a full solve's)
    maybe = tension_bound(sigma) > threshold
    if unbreakable is not None:
        maybe &= ~np.asarray(unbreakable, dtype=bool)
    maybe = np.flatnonzero(maybe)
    sigma_1, normal = principal_tension(sigma[maybe])
    cracks = sigma_1 > threshold[maybe]
    element, sigma_1, normal = maybe[cracks], sigma_1[cracks], normal[cracks]
    overstress = (sigma_1 - threshold[element]) / threshold[element]
    order = np.argsort(-overstress, kind="stable")
    if max_cracks is not None:
        order = order[:max(int(max_cracks), 0)]
    return CrackCandidates(element[order], normal[order], sigma_1[order])


def tearing_candidates(sigma: np.ndarray, tet_peeq: np.ndarray, tet_yielded: np.ndarray,
                       tearing_strain: float,
                       unbreakable: np.ndarray | None = None) -> CrackCandidates:
    """Ductile tearing: elements whose equivalent plastic strain passes the tearing strain while
    they flow, most strained first; the crack normal is the largest principal stress direction.

    sigma: (t, 3, 3) Pa, smoothed stress. tet_peeq: (t,) accumulated equivalent plastic strain
    (-). tet_yielded: (t,) bool, the element flowed in the last step. Unloaded elements do not
    tear: peeq never decreases, so otherwise the elements of a fresh tear surface would keep
    cracking every step along the arbitrary principal directions of their residual stress.
    """
    torn = (tet_peeq > tearing_strain) & tet_yielded
    if unbreakable is not None:
        torn &= ~np.asarray(unbreakable, dtype=bool)
    element = np.flatnonzero(torn)
    element = element[np.argsort(-tet_peeq[element], kind="stable")]
    sigma_1, normal = principal_tension(np.asarray(sigma)[element])
    return CrackCandidates(element, normal, sigma_1)


class CrackFaces(NamedTuple):
    """Per cracking element, the interior mesh face the crack runs along.

    face: (k,) int, face index in the mesh's `TetFaces` (-1: the element has no interior face).
    centroid: (k, 3) m, centroid of that face.
    """

    face: np.ndarray
    centroid: np.ndarray


def crack_faces(points: np.ndarray, tets: np.ndarray, element: np.ndarray,
                normal: np.ndarray, faces: TetFaces | None = None) -> CrackFaces:
    """The mesh face each cracking element opens.

    The crack through element e is perpendicular to its normal. Rule: among e's interior
    faces (shared with a neighbour; boundary faces would open nothing), take the one whose
    unit normal n_f is most nearly parallel to the crack normal, i.e. largest
    |n_f . normal|: the mesh face closest in direction to the crack plane. Ties go to the
    lower local face index.

    points: (n, 3) m; tets: (t, 4) or (t, 10); element: (k,); normal: (k, 3) unit.
    """
    points = np.asarray(points, dtype=float)
    element = np.asarray(element, dtype=np.int64)
    normal = np.asarray(normal, dtype=float).reshape(-1, 3)
    faces = tet_faces(tets) if faces is None else faces
    # Unit normals of the 4 faces of each cracking element: (k, 4, 3).
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
    return CrackFaces(chosen, centroid)


def planar_crack(points: np.ndarray, tets: np.ndarray, candidates: CrackCandidates,
                 faces: TetFaces | None = None, tolerance: float = 0.35,
                 max_cracks: int | None = None, pending: np.ndarray | None = None) -> CrackCandidates:
    """The candidates that open one planar crack: the most overstressed element (the seed)
    and every candidate whose crack face lies on the seed's crack plane.

    The plane passes through the centroid of the seed's crack face (see `crack_faces`) with
    the seed's crack normal; a candidate joins when its crack face's centroid is within
    `tolerance` times the seed's mean edge length of that plane. One plane per call keeps a
    uniformly stressed body from opening many parallel cracks at once (it breaks where it is
    weakest, then unloads); the rest are re-examined at the next check. `max_cracks` then
    keeps the most overstressed of the plane's elements, of those whose crack face is not one of
    the `pending` faces (chosen before, waiting to open) when they are given: `find_crack` gives
    them when the plane's elements would only choose waiting faces (the stress peaks at a
    waiting crack's front; a crack inside a finely meshed bar chose nothing new at every check
    while the load rose to 2.7 times its strength).
    """
    points = np.asarray(points, dtype=float)
    faces = tet_faces(tets) if faces is None else faces
    if candidates.element.size == 0:
        return candidates
    chosen, centroid = crack_faces(points, tets, candidates.element, candidates.normal, faces)
    valid = np.flatnonzero(chosen >= 0)
    if valid.size == 0:
        return candidates.take(slice(0, 0))
    seed = valid[0]
    corner = points[np.asarray(tets)[candidates.element[seed], :4]]
    edge = np.linalg.norm(corner[:, None] - corner[None], axis=2).sum() / 12.0
    distance = np.abs((centroid - centroid[seed]) @ candidates.normal[seed])
    keep = np.flatnonzero((chosen >= 0) & (distance <= tolerance * edge))
    if pending is not None and len(pending):
        keep = keep[~np.isin(chosen[keep], pending)]
    if max_cracks is not None:
        keep = keep[:max(int(max_cracks), 1)]
    return candidates.take(keep)


@dataclass(frozen=True)
class FractureModel:
    """What the fracture check needs of one tet mesh (rebuilt when the mesh splits).

    fracture_stress: tensile strength (Pa); inf when only tearing can break the mesh.
    tearing_strain: equivalent plastic strain at which a flowing element tears (-), or None.
    max_cracks: most elements cracking per check (None: no limit).
    tet_unbreakable: (t,) bool, elements that never crack.
    faces: `fem.split.TetFaces` of the mesh.
    smoothing: (t, t) CSR volume-weighted neighbour-mean operator (`smoothing_operator`).
    """

    fracture_stress: float
    tearing_strain: float | None
    max_cracks: int | None
    tet_unbreakable: np.ndarray
    faces: TetFaces
    smoothing: sp.csr_matrix

    @property
    def can_open(self) -> bool:
        """Whether a crack can open in this mesh at all: it has an interior face (a lone tet
        has none, so `find_crack` would find nothing to cut whatever its stress)."""
        return bool(self.faces.interior.any())


def fracture_model(tets: np.ndarray, tet_volume: np.ndarray, fracture_stress=None,
                   tearing_strain: float | None = None, max_cracks: int | None = None,
                   tet_unbreakable: np.ndarray | None = None) -> FractureModel:
    """FractureModel of a mesh: its faces and smoothing operator, with the material's strength.

    tets: (t, 4) or (t, 10); tet_volume: (t,) m^3; fracture_stress: Pa, None or inf for a
    body that only tears; tet_unbreakable: (t,) bool, default none.
    """
    faces = tet_faces(tets)
    tet_count = np.asarray(tets).shape[0]
    unbreakable = np.zeros(tet_count, dtype=bool) if tet_unbreakable is None else \
        np.asarray(tet_unbreakable, dtype=bool)
    return FractureModel(
        fracture_stress=np.inf if fracture_stress is None else float(fracture_stress),
        tearing_strain=tearing_strain, max_cracks=max_cracks, tet_unbreakable=unbreakable,
        faces=faces, smoothing=smoothing_operator(tet_volume, face_neighbours(tets, faces)))


def find_crack(fracture: FractureModel, points: np.ndarray, tets: np.ndarray,
               sigma: np.ndarray, tet_peeq: np.ndarray | None = None,
               tet_yielded: np.ndarray | None = None,
               pending: np.ndarray | None = None) -> tuple[np.ndarray, CrackCandidates]:
    """The whole fracture check of one mesh: smooth, test, take one crack plane, choose faces.

    sigma: (t, 3, 3) Pa, element stress. tet_peeq, tet_yielded: (t,) plastic strain and
    flowing flags (tearing only). pending: (p,) face indices chosen by earlier checks that
    have not opened yet (a face opens by node duplication only once the crack surface through
    its nodes reaches the boundary or an open crack).

    Returns (cut, candidates): cut (f,) face indices in `fracture.faces`, the pending faces and
    the new ones, empty when no new face was chosen; pass
    `fracture.faces.face_vertices[cut]` to `fem.split.split_mesh`.
    """
    smoothed = smooth_stress(sigma, fracture.smoothing)
    found = fracture_candidates(smoothed, fracture.fracture_stress, None,
                                fracture.tet_unbreakable)
    if fracture.tearing_strain is not None and tet_peeq is not None:
        # planar_crack seeds the plane at the first candidate and applies max_cracks itself, so
        # every torn element stays a candidate (a uniformly flowing bar tears across one whole
        # section instead of chipping at the first max_cracks by index)
        brittle = np.zeros(len(fracture.tet_unbreakable), dtype=bool)
        brittle[found.element] = True
        found = found.then(tearing_candidates(smoothed, tet_peeq, tet_yielded,
                                              fracture.tearing_strain,
                                              fracture.tet_unbreakable | brittle))
    if found.element.size == 0:
        return np.zeros(0, dtype=np.int64), found
    pending = np.zeros(0, dtype=np.int64) if pending is None else np.asarray(pending)
    plane = planar_crack(points, tets, found, fracture.faces, max_cracks=fracture.max_cracks)
    chosen = _chosen_faces(points, tets, plane, fracture.faces)
    if np.all(np.isin(chosen, pending)):
        # every face chosen waits already (the stress peaks at a waiting crack's front): the
        # crack grows into the plane's elements beyond it, if any are overstressed
        plane = planar_crack(points, tets, found, fracture.faces, max_cracks=fracture.max_cracks,
                             pending=pending)
        chosen = _chosen_faces(points, tets, plane, fracture.faces)
        if np.all(np.isin(chosen, pending)):
            return np.zeros(0, dtype=np.int64), plane
    return np.union1d(pending, chosen), plane


def _chosen_faces(points, tets, found, faces):
    """The faces (sorted face ids) the candidates ``found`` open (:func:`crack_faces`)."""
    chosen = crack_faces(points, tets, found.element, found.normal, faces).face
    return np.unique(chosen[chosen >= 0])
