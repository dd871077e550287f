"""Exact mass properties of a closed triangle surface of uniform density.

The solid is split into signed tetrahedra (a reference point + each triangle); volume, first and
second moments are exact polynomial integrals over each tet (Tonon 2004, Eberly "Polyhedral Mass
Properties"), so a box or any polyhedron is integrated without discretisation error.
"""
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class MassProperties:
    """Mass properties of a uniform solid, in the frame of the mesh it was computed from.

    mass:    total mass, kg.
    volume:  enclosed volume, m^3.
    com:     centre of mass, (3,) m.
    inertia: inertia tensor about the centre of mass, (3, 3) kg m^2, symmetric positive definite.
    """

    mass: float
    volume: float
    com: np.ndarray
    inertia: np.ndarray


def mass_properties(vertices, triangles, density):
    """Exact mass, volume, centre of mass and inertia of the closed surface ``(vertices, triangles)``.

    ``vertices`` (n, 3) m, ``triangles`` (m, 3) outward oriented, ``density`` kg/m^3 (> 0).
    Raises ``ValueError`` when the enclosed volume is not positive (open, inverted or flat mesh).
    """
    density = float(density)
    if not (np.isfinite(density) and density > 0):
        raise ValueError(f"density must be positive and finite (kg/m^3), got {density!r}")
    vertices = np.asarray(vertices, dtype=np.float64)
    # Integrate about a point inside the mesh's extent to avoid cancellation for far-off meshes.
    reference = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    p = (vertices - reference)[np.asarray(triangles, dtype=np.int64)]  # (m, 3 corners, 3)
    a, b, c = p[:, 0], p[:, 1], p[:, 2]

    # Signed tet (reference, a, b, c): det = 6 V.
    det = np.einsum("ij,ij->i", a, np.cross(b, c))
    volume = det.sum() / 6.0
    if not (np.isfinite(volume) and volume > 0):
        raise ValueError(f"enclosed volume must be positive, got {float(volume):.3g} m^3: the "
                         "surface is open, inward-facing, degenerate, or too small for its volume "
                         "to be computed")
    corner_sum = a + b + c  # the reference corner is the origin
    first_moment = np.einsum("i,ij->j", det, corner_sum) / 24.0  # sum V (0 + a + b + c) / 4
    # Second moment of a tet with a corner at the origin:
    # int x x^T dV = V / 20 (sum_i v_i v_i^T + s s^T), s = sum_i v_i (Tonon 2004).
    outer = (np.einsum("ij,ik->ijk", a, a) + np.einsum("ij,ik->ijk", b, b)
             + np.einsum("ij,ik->ijk", c, c) + np.einsum("ij,ik->ijk", corner_sum, corner_sum))
    second_moment = np.einsum("i,ijk->jk", det, outer) / 120.0

    com_local = first_moment / volume
    # Parallel-axis shift of the covariance to the centre of mass.
    covariance = density * (second_moment - volume * np.outer(com_local, com_local))
    covariance = 0.5 * (covariance + covariance.T)
    inertia = np.trace(covariance) * np.eye(3) - covariance
    return MassProperties(mass=float(density * volume), volume=float(volume), com=com_local + reference,
                          inertia=inertia)


def principal_axes(inertia):
    """Principal moments and axes of a symmetric inertia tensor.

    Returns ``(moments (3,) ascending kg m^2, R (3, 3))`` where the columns of ``R`` are the
    corresponding unit axes and ``det R = +1``, so ``inertia = R diag(moments) R^T``.
    """
    inertia = np.asarray(inertia, dtype=np.float64)
    moments, axes = np.linalg.eigh(0.5 * (inertia + inertia.T))
    if np.linalg.det(axes) < 0:
        axes[:, 2] = -axes[:, 2]
    return moments, axes
