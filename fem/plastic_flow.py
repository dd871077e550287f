"""Von Mises perfect plasticity in the time loop: the plastic force and the after-step return map.

Only bodies with a yield stress (``model.plastic``) ever reach this module:

* ``fem.dynamics.predict`` adds :func:`plastic_force` (the equivalent force of the current plastic
  strain, O'Brien, Bargteil, Hodgins 2002) to the right-hand side; the system matrix is unchanged.
* ``fem.dynamics.finish`` calls :func:`plastic_update` on the end-of-step state: the small strain
  at each quadrature point in the body frame (floating: ``R^T``, anchored: world, corotated: per
  element, as ``fem.stress.quadrature_strain``), the trial stress ``C : (eps - eps_p)``, the radial
  return of ``fem.plasticity.return_map`` at the points outside the yield surface, the plastic
  work, and the updated plastic force for the next step.

The plastic strain is therefore explicit (a staggered scheme): the force of the strain found at
the end of step n acts during step n + 1. Alone, that is one step late: in steady flow every solve
carries the stress of one step's strain increment above the yield surface (a bar pulled at 7% of
its yield strain per step read 7% above Y A, P1 or P2 alike). So the force also carries the
increment the next step is predicted to make, the last one, where the flow continues (elements
that flowed in both of the last two steps; IMPL-EX, Oliver, Huespe and Cante 2008; not under
Newmark, whose energy balance cannot count its work), and anchored
floating bodies report the reaction on the end-of-step stress. The return map itself is exact.
In the elements that have flowed, the pressure comes from the volumetric strain averaged over
node patches (:func:`committed_force`), so that isochoric flow does not lock on coarse meshes.

Both passes work on per-point tensors (point ``k = q e + p`` is quadrature point p of element e)
with the point index last, ``(3, 3, t q)`` ("component-major"): each tensor component is one
contiguous row, so the yield test and the return map are whole-array operations with no per-point
3 x 3 products. The two passes that touch the mesh, the gradient of a node field at every point
(:func:`node_field_gradient`, a gather) and the node force of per-point tensors
(:func:`nodal_force`, a scatter), are compiled loops over the points. Their shape-function data
(:class:`PointGradients`) is built once per model and kept in its ``cache``; corotated bodies also
keep there the element rotations of the end-of-step positions
(:func:`fem.rotations.element_rotations`), which the next ``predict`` reuses.
"""
from dataclasses import dataclass

import numba as nb
import numpy as np

from fem.rotations import element_rotations
from fem.plasticity import (elastic_stress, equivalent_plastic_strain, isotropic_stress,
                            plastic_dissipation_increment, return_map)
from fem.stress import quadrature_strain

# pairs (ij, ji) of off-diagonal components in a flattened 3 x 3 tensor
_OFF_DIAGONAL = ((1, 3), (2, 6), (5, 7))


def initial_plastic_fields(model):
    """``FemState`` fields of a plastic body with no plastic strain yet (keyword arguments)."""
    t, q = model.elements.tet_weights.shape
    return dict(tet_plastic_strain=np.zeros((t, q, 3, 3)), tet_peeq=np.zeros((t, q)),
                tet_yielded=np.zeros(t, dtype=bool),
                node_plastic_force=np.zeros((model.node_count, 3)),
                plastic_dissipation=0.0)


def _plastic_fields(model, state):
    """The state's plastic fields, initialised when the state has none (e.g. built elsewhere)."""
    if state.tet_plastic_strain is None:
        return initial_plastic_fields(model)
    return dict(tet_plastic_strain=state.tet_plastic_strain, tet_peeq=state.tet_peeq,
                tet_yielded=state.tet_yielded, node_plastic_force=state.node_plastic_force,
                plastic_dissipation=state.plastic_dissipation)


# ---------------------------------------------------------------------------------------------
# Shape-function data (built once per model), gradients, forces and element rotations
# ---------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class PointGradients:
    """Shape-function data of every quadrature point of a body (rest frame), contiguous arrays
    for the compiled loops over the points of :func:`node_field_gradient` and :func:`nodal_force`.

    Point ``k = q e + p`` is quadrature point p of element e (``q = t q // t``).

    gradient: ``(t q, b, 3)`` (1/m): ``dN_a/dX_j`` at ``[k, a, j]`` for element node ``a``.
    nodes: ``(t, b)`` int: the node of element node ``a`` of element ``e``.
    weight: ``(t q,)`` (m^3): quadrature weight times |J| of point ``k``.
    corners: ``(t, 4)`` int: the corner nodes of each element (node patches,
        :func:`patch_dilatation`).
    patch_volume: ``(n,)`` (m^3): the volume of the elements around each node (1 off the corners,
        where no patch is centred).
    """
    gradient: np.ndarray
    nodes: np.ndarray
    weight: np.ndarray
    corners: np.ndarray
    patch_volume: np.ndarray


def point_gradients(model):
    """The model's :class:`PointGradients`, built on first use and kept in
    ``model.cache.point_gradients``."""
    if model.cache.point_gradients is None:
        e = model.elements
        t, q, b, _ = e.tet_gradients.shape
        corners = np.ascontiguousarray(e.tet_nodes[:, :4], dtype=np.intp)
        patch = np.bincount(corners.ravel(), np.repeat(e.tet_weights.sum(axis=1), 4), model.node_count)
        model.cache.point_gradients = PointGradients(
            gradient=np.ascontiguousarray(e.tet_gradients.reshape(t * q, b, 3), dtype=float),
            nodes=np.ascontiguousarray(e.tet_nodes, dtype=np.intp),
            weight=np.ascontiguousarray(e.tet_weights.ravel(), dtype=float),
            corners=corners, patch_volume=np.where(patch > 0.0, patch, 1.0))
    return model.cache.point_gradients


@nb.njit(cache=True)
def _gather_gradient(v, gradient, nodes):
    """``H[i, j, k] = sum_a v[nodes[e, a], i] gradient[k, a, j]``, ``e = k // q``; (3, 3, t q)."""
    points, b, _ = gradient.shape
    q = points // nodes.shape[0]
    H = np.empty((3, 3, points))
    for k in range(points):
        e = k // q
        h00 = h01 = h02 = h10 = h11 = h12 = h20 = h21 = h22 = 0.0
        for a in range(b):
            n = nodes[e, a]
            v0, v1, v2 = v[n, 0], v[n, 1], v[n, 2]
            g0, g1, g2 = gradient[k, a, 0], gradient[k, a, 1], gradient[k, a, 2]
            h00 += v0 * g0
            h01 += v0 * g1
            h02 += v0 * g2
            h10 += v1 * g0
            h11 += v1 * g1
            h12 += v1 * g2
            h20 += v2 * g0
            h21 += v2 * g1
            h22 += v2 * g2
        H[0, 0, k], H[0, 1, k], H[0, 2, k] = h00, h01, h02
        H[1, 0, k], H[1, 1, k], H[1, 2, k] = h10, h11, h12
        H[2, 0, k], H[2, 1, k], H[2, 2, k] = h20, h21, h22
    return H


@nb.njit(cache=True)
def _scatter_force(tau, points, gradient, nodes, weight, node_count):
    """``f[nodes[e, a], i] += weight[k] sum_j tau[i, j, c] gradient[k, a, j]`` for ``k = points[c]``,
    ``e = k // q``; (node_count, 3), summed point after point."""
    b = gradient.shape[1]
    q = gradient.shape[0] // nodes.shape[0]
    f = np.zeros((node_count, 3))
    for c in range(points.shape[0]):
        k = points[c]
        e = k // q
        w = weight[k]
        t00, t01, t02 = w * tau[0, 0, c], w * tau[0, 1, c], w * tau[0, 2, c]
        t10, t11, t12 = w * tau[1, 0, c], w * tau[1, 1, c], w * tau[1, 2, c]
        t20, t21, t22 = w * tau[2, 0, c], w * tau[2, 1, c], w * tau[2, 2, c]
        for a in range(b):
            n = nodes[e, a]
            g0, g1, g2 = gradient[k, a, 0], gradient[k, a, 1], gradient[k, a, 2]
            f[n, 0] += t00 * g0 + t01 * g1 + t02 * g2
            f[n, 1] += t10 * g0 + t11 * g1 + t12 * g2
            f[n, 2] += t20 * g0 + t21 * g1 + t22 * g2
    return f


def node_field_gradient(model, v):
    """Gradient ``(3, 3, t q)`` of a node field ``v`` ``(n, 3)`` at every quadrature point,
    ``[i, j, k] = sum_a v[node_a, i] dN_a/dX_j`` (unit of v per m), component-major."""
    p = point_gradients(model)
    return _gather_gradient(np.ascontiguousarray(v, dtype=float), p.gradient, p.nodes)


def nodal_force(model, tau, points=None):
    """Node force ``sum_k int B^T tau_k`` ``(n, 3)`` (N) of per-point tensors ``tau`` (Pa) given
    component-major, ``(3, 3, k)``, at the quadrature points ``points`` (flat indices ``(k,)``,
    default all ``t q``): ``f[node_a, i] += w_k sum_j tau[i, j, k] dN_a/dX_j``. ``tau`` need not
    be symmetric."""
    p = point_gradients(model)
    points = np.arange(p.weight.size) if points is None else np.asarray(points, dtype=np.intp)
    return _scatter_force(np.asarray(tau, dtype=float), points, p.gradient, p.nodes, p.weight,
                          model.node_count)


def _point_rotations(model, tet_R):
    """Element rotations ``(t, 3, 3)`` repeated for each quadrature point, ``(t q, 3, 3)``."""
    q = model.quadrature_count
    return tet_R if q == 1 else np.repeat(tet_R, q, axis=0)


def _component_major(a):
    """Per-point tensors ``(..., 3, 3)`` as a contiguous component-major array ``(3, 3, k)``
    (a copy unless ``a`` is laid out so already, e.g. made by :func:`_tensors`)."""
    return np.ascontiguousarray(a.reshape(-1, 9).T).reshape(3, 3, -1)


def _tensors(a):
    """A component-major array ``(9, k)`` seen as ``k`` tensors ``(k, 3, 3)`` (a view)."""
    return a.T.reshape(-1, 3, 3)


# ---------------------------------------------------------------------------------------------
# Strain and force
# ---------------------------------------------------------------------------------------------

def displacement_gradient(model, state):
    """Displacement gradient ``H`` ``(3, 3, t q)`` (-) at each quadrature point in the model's frame,
    component-major; the small strain is its symmetric part (``fem.stress.quadrature_strain``).

    Floating and anchored bodies: the gradient of the body-frame displacement
    ``u = (x - c) R - (X - X_c)``. Corotated bodies: ``R_e^T F - I`` with ``F`` the world
    deformation gradient (the gradient of ``x - c``; ``c`` drops out since the shape gradients of
    an element sum to zero) and ``R_e`` from :func:`fem.rotations.element_rotations`.
    """
    if model.frame == "corotated":
        F = node_field_gradient(model, state.x - state.c)
        # (R^T F)_ij = sum_m R_mi F_mj, both operands component-major (10x faster than point-major)
        R = _component_major(_point_rotations(model, element_rotations(model, state.x)))
        H = np.einsum("mik,mjk->ijk", R, F, order="C")
        for i in range(3):
            H[i, i] -= 1.0
        return H
    return node_field_gradient(model, (state.x - state.c) @ state.R - model.rest_offsets)


def rest_frame_plastic_force(model, eps_p):
    """Equivalent plastic node force ``f_p = sum_e int B^T (C : eps_p)`` ``(n, 3)`` (N) in the rest
    (body) frame, for plastic strains ``eps_p`` ``(t, q, 3, 3)``."""
    return nodal_force(model, _component_major(isotropic_stress(eps_p, model.mu, model.lam)))


def patch_dilatation(model, theta):
    """The volumetric strain ``theta`` ``(t, q)`` averaged over node patches, ``(t, q)``: each
    element's volume-weighted mean goes to its corner nodes, each node takes the volume-weighted
    mean of its elements, each element the mean of its corners (nodally averaged dilatation,
    Bonet and Burton 1998)."""
    p = point_gradients(model)
    moment = (p.weight.reshape(theta.shape) * theta).sum(axis=1)
    node = np.bincount(p.corners.ravel(), np.repeat(moment, 4), model.node_count)
    node /= p.patch_volume
    return np.broadcast_to(node[p.corners].mean(axis=1)[:, None], theta.shape)


def committed_force(model, eps_p, peeq, volumetric):
    """Rest-frame plastic node force ``(n, 3)`` (N) of the plastic strain ``eps_p`` ``(t, q, 3, 3)``,
    with the pressure of the elements that have flowed taken from their volumetric strain
    averaged over node patches.

    Von Mises flow is isochoric. Where it must happen in elements that cannot deform at constant
    volume point by point (linear tets, quadratic ones on coarse meshes, any element beside a
    clamp), the volumetric strain the flow drags along carries a pressure that grows with the
    flow, and the body hardens: a steel cantilever on a 10 x 1 x 2 P2 mesh collapsed at
    1.18 M_p / L. So in the elements with ``peeq > 0`` the pressure is ``K e_bar``, ``e_bar`` the
    elastic volumetric strain ``volumetric`` ``(t, q)`` averaged over node patches
    (:func:`patch_dilatation`), instead of the point's own ``K e``: the force also carries
    ``K (e - e_bar) I`` there, K the bulk modulus (the mean dilatation of Nagtegaal, Parks and
    Rice 1974, averaged at nodes as Bonet and Burton 1998, confined to the plastic zone). An
    element that never flows keeps its pointwise pressure, so elastic bodies are unchanged; in
    uniform flow ``e_bar = e``. ``e`` is the elastic strain's trace, which a reference update
    (``fem.reference``) leaves unchanged, so updates do not change the force either.
    """
    t, q = peeq.shape
    flowed = (peeq > 0.0).any(axis=1)                               # elements that have flowed
    if not flowed.any():
        return rest_frame_plastic_force(model, eps_p)
    relief = (model.lam + 2.0 * model.mu / 3.0) * (volumetric - patch_dilatation(model, volumetric))
    # eps_p is zero outside the elements that flowed until a reference update spreads its
    # compatible part; a small plastic zone is gathered, a large one summed over the whole body
    if model.reference_updates or np.count_nonzero(flowed) > t // 4:
        tau = _component_major(isotropic_stress(eps_p, model.mu, model.lam))
        relief[~flowed] = 0.0
        points = None
    else:
        points = (np.flatnonzero(flowed)[:, None] * q + np.arange(q)).ravel()
        tau = _component_major(isotropic_stress(eps_p.reshape(t * q, 3, 3)[points], model.mu, model.lam))
        relief = relief[flowed]
    for i in range(3):
        tau[i, i] += relief.ravel()
    return nodal_force(model, tau, points)


def state_plastic_force(model, state):
    """:func:`committed_force` of ``state`` (rest frame, N, ``(n, 3)``; zeros for a body with no
    plastic strain): the force of its plastic strain and its plastic zone's averaged pressure,
    without the increment the dynamics predict."""
    if state.tet_plastic_strain is None:
        return np.zeros_like(state.x)
    H = displacement_gradient(model, state)
    eps_p = state.tet_plastic_strain
    volumetric = (H[0, 0] + H[1, 1] + H[2, 2]).reshape(state.tet_peeq.shape) \
        - (eps_p[..., 0, 0] + eps_p[..., 1, 1] + eps_p[..., 2, 2])
    return committed_force(model, eps_p, state.tet_peeq, volumetric)


def plastic_force(model, state, tet_R=None):
    """Plastic node force ``(n, 3)`` (N) in world coordinates for the right-hand side of a step.

    Floating and anchored bodies rotate the cached body-frame ``node_plastic_force`` by ``R``.
    Corotated bodies rotate each point's stress by its element's rotation ``tet_R`` ``(t, 3, 3)``
    (default: those of ``state.x``), ``sum_e int B^T (R_e C : eps_p)``, and the force of the
    predicted increment (``node_plastic_force`` less the rest-frame force of ``eps_p``, see
    :func:`plastic_update`) by the body's best-fit ``R``.
    """
    if state.tet_plastic_strain is None:
        return np.zeros_like(state.x)
    if model.frame != "corotated":
        return state.node_plastic_force @ state.R.T
    tet_R = element_rotations(model, state.x) if tet_R is None else tet_R
    # R_e (C : eps_p), both operands component-major (10x faster than point-major)
    sigma = _component_major(isotropic_stress(state.tet_plastic_strain, model.mu, model.lam))
    R = _component_major(_point_rotations(model, tet_R))
    force = nodal_force(model, np.einsum("imk,mjk->ijk", R, sigma))
    if state.node_plastic_force is not None and state.tet_yielded is not None and state.tet_yielded.any():
        # a predicted increment is only made where the last step flowed
        force += (state.node_plastic_force - nodal_force(model, sigma)) @ state.R.T
    return force


# ---------------------------------------------------------------------------------------------
# The return map after a step
# ---------------------------------------------------------------------------------------------

def plastic_update(model, state):
    """Return-map the end-of-step state onto the yield surface; returns the new state.

    Updates ``tet_plastic_strain``, ``tet_peeq``, ``tet_yielded``, ``plastic_dissipation`` (points
    outside the yield surface flow; none at ``max_plastic_strain``: further flow is elastic there),
    ``node_plastic_force`` and, for anchored bodies in the floating frame, ``node_reaction``.

    ``node_plastic_force`` is the rest-frame force the next step applies: that of the new plastic
    strain plus the force of this step's increment at the points of elements that flowed in the
    last step too, the increment the next step is predicted to make (IMPL-EX, Oliver, Huespe and
    Cante 2008): without it the staggered scheme is one step late, and steady flow carries the
    stress of one step's strain increment above the yield surface in every solve (a bar pulled
    at 7% of its yield strain per step pulled 7% above Y A). Newmark bodies make no prediction:
    its force does work outside their energy balance (a plastic ball landing at 5 m/s, flowing
    5% a step, gained 14 J from 6.4 J), so they stay one step late. ``node_reaction`` becomes the
    anchors' reaction on the end-of-step stress (as if the step had applied the new plastic
    strain's force), not on the trial stress of the step's solve.
    """
    fields = _plastic_fields(model, state)
    eps_p = fields["tet_plastic_strain"]
    t, q = eps_p.shape[:2]
    # deviator of the elastic strain eps - eps_p, component-major (9, t q), built in place on the
    # displacement gradient H: eps_p is symmetric, so sym(H) - eps_p = sym(H - eps_p)
    dev = displacement_gradient(model, state).reshape(9, t * q)
    dev -= eps_p.reshape(t * q, 9).T
    for ij, ji in _OFF_DIAGONAL:
        dev[ij] += dev[ji]
        dev[ij] *= 0.5
        dev[ji] = dev[ij]
    trace = dev[0] + dev[4] + dev[8]
    dev[::4] -= trace / 3.0
    # yield test on the deviator alone: von_mises(C : eps_e) = sqrt(3/2) 2 mu |dev eps_e|
    dev_norm2 = np.einsum("ck,ck->k", dev, dev)
    yielded = (dev_norm2 > (2.0 / 3.0) * (model.yield_stress / (2.0 * model.mu)) ** 2).reshape(t, q)
    yielded &= model.max_plastic_strain is None or fields["tet_peeq"] < (1 - 1e-12) * model.max_plastic_strain
    fields["tet_yielded"] = yielded.any(axis=1)
    flowed = np.flatnonzero(yielded)
    d_eps_p = _flow(model, fields, dev, trace, flowed) if len(flowed) else np.zeros((0, 3, 3))
    was_flowing = state.tet_yielded is not None and state.tet_plastic_strain is not None \
        and state.tet_yielded.any()
    # the elastic strain's trace is the volumetric strain: eps_p is deviatoric
    force = committed_force(model, fields["tet_plastic_strain"], fields["tet_peeq"],
                            trace.reshape(t, q))      # the elastic strain's trace
    if model.anchored and model.frame != "corotated" and state.node_plastic_force is not None:
        fields["node_reaction"] = _end_of_step_reaction(model, state, force)
    if was_flowing and len(flowed) and model.integrator != "newmark":
        steady = state.tet_yielded[flowed // q]        # flowed in the last step too
        force = force + nodal_force(model, _component_major(isotropic_stress(
            d_eps_p[steady], model.mu, model.lam)), flowed[steady])
    fields["node_plastic_force"] = force
    return state.replace(**fields)


def _end_of_step_reaction(model, state, force):
    """``node_reaction`` ``(n, 3)`` N as if the step had applied the rest-frame plastic force
    ``force`` ``(n, 3)`` instead of ``state.node_plastic_force``: the anchors' reaction on the
    end-of-step stress (the step's own is that of the stress before this step's return map)."""
    change = (force - state.node_plastic_force) @ state.R.T
    reaction = state.node_reaction.copy()
    fixed = model.fixed_nodes
    reaction[fixed] -= change[fixed]
    return reaction


def _flow(model, fields, dev, trace, flowed):
    """Radial return at the points ``flowed`` ``(k,)`` from the elastic strain's deviator ``dev``
    ``(9, t q)`` and trace ``(t q,)``; updates ``fields`` and returns the increments (k, 3, 3)."""
    eps_p = fields["tet_plastic_strain"]
    t, q = eps_p.shape[:2]
    # return map at the yielded points only (Bridson's radial return, fem.plasticity.return_map), their
    # tensors gathered component-major (9, k) as (k, 3, 3) views (_tensors): contiguous along points
    old = _tensors(np.take(eps_p.reshape(t * q, 9), flowed, axis=0).T.copy())
    # trial stress C : eps_e = 2 mu dev + (lam + 2 mu / 3) tr I
    sigma_trial = np.take(dev, flowed, axis=1)
    sigma_trial *= 2.0 * model.mu
    sigma_trial[::4] += (model.lam + 2.0 * model.mu / 3.0) * np.take(trace, flowed)
    peeq = fields["tet_peeq"].copy()        # (the cap bounds it: the room it leaves)
    room = None if model.max_plastic_strain is None else model.max_plastic_strain - peeq.ravel()[flowed]
    new, sigma_new, _, _ = return_map(_tensors(sigma_trial), old, model.mu, model.yield_stress, room)
    d_eps_p = new - old
    eps_p = eps_p.copy()
    eps_p.reshape(t * q, 3, 3)[flowed] = new
    peeq.reshape(t * q)[flowed] += equivalent_plastic_strain(d_eps_p)
    weights = np.take(point_gradients(model).weight, flowed)
    fields.update(tet_plastic_strain=eps_p, tet_peeq=peeq,
                  plastic_dissipation=fields["plastic_dissipation"]
                  + plastic_dissipation_increment(sigma_new, d_eps_p, weights))
    return d_eps_p


def elastic_energy(model, state):
    """Stored elastic energy (J) of a plastic body, ``1/2 sum w (eps - eps_p) : C : (eps - eps_p)``
    with ``1/2 K e e_bar`` for ``1/2 K e^2`` in the elements that have flowed (``e`` the elastic
    strain's trace, ``e_bar`` its patch average, :func:`committed_force`): patch averaging is
    symmetric in the volume-weighted sum, so this is the energy whose gradient the forces are (a
    bent steel beam's hinge pressure counted pointwise made it 2.3x too large)."""
    eps_e = quadrature_strain(model, state) - state.tet_plastic_strain
    sigma = elastic_stress(eps_e, 0.0, model.mu, model.lam)
    w = model.elements.tet_weights
    energy = 0.5 * float(np.einsum("tq,tqij,tqij->", w, sigma, eps_e))
    flowed = (state.tet_peeq > 0.0).any(axis=1)
    if flowed.any():
        e = eps_e[..., 0, 0] + eps_e[..., 1, 1] + eps_e[..., 2, 2]
        relief = e * (patch_dilatation(model, e) - e)
        energy += 0.5 * (model.lam + 2.0 * model.mu / 3.0) * float((w * relief)[flowed].sum())
    return energy
