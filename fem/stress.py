"""Element stresses, their invariants, and per-region reports (anchor reactions, load regions).

Stresses are small-strain stresses of the displacement measured in the model's frame, expressed in
rest (material) coordinates: the floating frame removes the body's best-fit rotation ``R`` (and
centre), the corotated frame each element's own rotation ``R_e``. Rotate with ``R sigma R^T`` for
world coordinates; the invariants (von Mises, principal values) do not depend on it.
"""
import numpy as np

from fem.rotations import element_rotations
from fem.plasticity import elastic_stress, von_mises  # the project's one von Mises

__all__ = ["quadrature_stress", "element_stress", "element_strain_rate", "von_mises",
           "principal_stress_max", "region_table"]


def _corotated_displacement(model, x, tet_R):
    """Element displacements in each element's frame, ``R_e^T x_e - X_e`` ``(t, b, 3)`` (m), as
    :func:`fem.warping.warped_forces` forms them per element (here for the strains)."""
    nodes = model.elements.tet_nodes
    u = np.einsum("taj,tji->tai", x[nodes], tet_R) - model.rest_points[nodes]
    # drop each element's mean translation (K_e ignores it) so far-away bodies keep their digits
    return u - u.mean(axis=1, keepdims=True)


def quadrature_strain(model, state):
    """Small strain at each element quadrature point ``(t, q, 3, 3)`` (dimensionless)."""
    data = model.elements
    if model.frame == "corotated":
        u = _corotated_displacement(model, state.x, element_rotations(model, state.x))
    else:
        u = ((state.x - state.c) @ state.R - model.rest_offsets)[data.tet_nodes]
    # grad_u[t, q] = u_t^T G_tq, as one batched matmul (several times faster than einsum here)
    grad_u = np.swapaxes(u, 1, 2)[:, None] @ data.tet_gradients
    return 0.5 * (grad_u + grad_u.transpose(0, 1, 3, 2))


def quadrature_stress(model, state, tet_plastic_strain=None):
    """Cauchy stress at each quadrature point ``(t, q, 3, 3)`` (Pa), rest coordinates.

    tet_plastic_strain: optional plastic strain subtracted from the strain, ``(t, 3, 3)`` (one per
    element) or ``(t, q, 3, 3)`` (one per quadrature point, as ``FemState.tet_plastic_strain``).
    """
    eps = quadrature_strain(model, state)
    eps_p = 0.0 if tet_plastic_strain is None else np.asarray(tet_plastic_strain)
    if np.ndim(eps_p) == 3:
        eps_p = eps_p[:, None]
    return elastic_stress(eps, eps_p, model.mu, model.lam)


def element_stress(model, state, tet_plastic_strain=None):
    """Volume-averaged stress of each element ``(t, 3, 3)`` (Pa), rest coordinates.

    P1: the element's constant stress; P2: average over the element's quadrature points.
    """
    sigma = quadrature_stress(model, state, tet_plastic_strain)
    w = model.elements.tet_weights
    return np.einsum("tq,tqij->tij", w, sigma) / w.sum(axis=1)[:, None, None]


def inverse_deformation_gradients(model, x):
    """``F^-1`` of each element at positions ``x`` ``(n, 3)`` m: ``(t, 3, 3)``, its corner
    simplex's, for linear elements; ``(t, q, 3, 3)``, at each quadrature point, for quadratic ones,
    whose deformation gradient varies within the element (the adjugate over the determinant:
    several times faster than a batched LAPACK inverse)."""
    data = model.elements
    if data.tet_nodes.shape[1] == 4:
        ds = np.swapaxes(x[model.tets[:, 1:4]] - x[model.tets[:, :1]], 1, 2)     # (t, 3, 3) edge columns
        F = ds @ data.tet_rest_inverse
    else:
        F = np.swapaxes(x[data.tet_nodes], 1, 2)[:, None] @ data.tet_gradients   # (t, q, 3, 3)
    a, b, c = F[..., 0], F[..., 1], F[..., 2]
    rows = np.stack([np.cross(b, c), np.cross(c, a), np.cross(a, b)], axis=-2)   # adj(F) = rows
    det = np.einsum("...i,...i->...", a, rows[..., 0, :])
    return rows / det[..., None, None]


def element_strain_rate(model, x, v, inverse_F=None):
    """Largest strain rate of each element ``(t,)`` (1/s): the Frobenius norm of the symmetric
    part of the velocity gradient ``grad_x v``, taken in the deformed shape ``x`` ``(n, 3)`` m (so a
    rigid motion of any shape gives zero) for node velocities ``v`` ``(n, 3)`` m/s; the largest
    over the element's quadrature points (``inverse_F``: :func:`inverse_deformation_gradients` at
    ``x``, when known)."""
    data = model.elements
    if inverse_F is None:
        inverse_F = inverse_deformation_gradients(model, x)
    if inverse_F.ndim == 3:
        inverse_F = inverse_F[:, None]
    grad_v = np.swapaxes(v[data.tet_nodes], 1, 2)[:, None] @ data.tet_gradients @ inverse_F
    rate = 0.5 * (grad_v + np.swapaxes(grad_v, 2, 3))
    return np.sqrt(np.einsum("tqij,tqij->tq", rate, rate)).max(axis=1)


def principal_stress_max(sigma):
    """Largest principal stress ``(...)`` (Pa) of symmetric tensors ``(..., 3, 3)``."""
    return np.linalg.eigvalsh(sigma)[..., -1]


def region_table(model, state):
    """One row per region: ``(name, fx, fy, fz, ux, uy, uz)``.

    Anchors (``anchor0``, ...): f is the force the anchor exerted on the body during the last step
    (N). Loads (``load0``, ...): f is the applied total force (N). u is the mean displacement
    ``x - X`` of the region's nodes (m), world frame, X the rest shape the body was built with
    (the plastic displacement reference updates baked into the rest shape added back: a load-
    deflection curve runs on through them).
    """
    if not model.region_names:
        return []
    u = state.x - model.rest_points
    if state.node_rest_shift is not None:
        u = u + state.node_rest_shift
    rows = [(*state.node_reaction[nodes].sum(axis=0), *u[nodes].mean(axis=0))
            for nodes in model.anchor_nodes]
    rows += [(*model.load_force[i], *u[nodes].mean(axis=0)) for i, nodes in enumerate(model.load_nodes)]
    return [(name, *map(float, values)) for name, values in zip(model.region_names, rows)]
