"""Reference-shape updates: bake accumulated plastic strain into a plastic body's rest shape.

An event between steps (it returns a new model and state, and refactorises only that body).

Method (what "shape matching removes the rigid motion and the elastic part" means here): the
plastic part of the deformation is the displacement ``u_p`` the plastic strain alone produces in
the unloaded body, the static solution of

    K u_p = f_p = sum_e int B^T C eps_p      (anchored nodes held at u = 0)

(plus the force of the plastic zone's patch-averaged pressure, ``fem.plastic_flow.committed_force``,
which depends on the elastic volumetric strain alone and so is unchanged by the update).

For a free body K is singular; f_p is self-equilibrated, so ``(K + s M) u = f_p`` with a tiny
shift ``s`` plus a few steps of iterative refinement converges to it, and the rigid part is
removed after every refinement by the mass-weighted projection on the rigid modes (translations
and small rotations: the linearised form of shape matching's best-fit frame, which keeps the
plastic stretch exact where the nonlinear fit would mix the large rigid round-off of the singular
solve into it). The new rest shape is ``X_new = X + u_p`` (body frame) and the plastic strain is reset
to ``eps_p - eps(u_p)``, the incompatible part that no displacement can relieve (~0 for a
compatible plastic strain, and it keeps the residual stress of a dent exactly); to be exact, by
the change of each point's strain ``eps(u)`` as the new shape (and frame) measures the same
positions, which is ``-eps(u_p)`` to first order. So the elastic strain ``eps(u) - eps_p`` of every
point is unchanged by the reset, and the stress, the elastic energy and the positions do not jump
at the update: the body keeps its shape, springs back only by its elastic part, and vibrates about
the new rest shape.

An update is due when the accumulated equivalent plastic strain of some quadrature point has grown
by ``model.plastic_update_strain`` since the last update; each update therefore bakes at most
that much (plus one step's increment) into the rest shape.
"""
import numpy as np

from fem.dynamics import body_frame
from fem.model import with_rest_points
from fem.momentum import angular_momentum, center_of_mass, linear_momentum, mass_moments, mass_weights
from fem.plastic_flow import rest_frame_plastic_force, state_plastic_force
from fem.solver import Factorisation
from fem.stress import quadrature_strain

# shift of the singular free-body stiffness, relative to the mean of diag(K)/diag(M)
_SHIFT = 1e-10
_REFINEMENTS = 4


def reference_update_due(model, state):
    """True when a plastic body has flowed by ``plastic_update_strain`` since its last update."""
    if not model.plastic or state.tet_peeq is None:
        return False
    return float(np.max(state.tet_peeq - model.reference_peeq)) > model.plastic_update_strain


def plastic_displacement(model, state):
    """Displacement ``u_p`` ``(n, 3)`` (m, rest frame) of the plastic strain of ``state`` in the
    unloaded body: ``K u_p = f_p`` with anchors held, rigid motion removed (free bodies). ``f_p``
    includes the plastic zone's averaged pressure (``fem.plastic_flow.state_plastic_force``), so
    the rest shape takes all of the set."""
    f = state_plastic_force(model, state).ravel()
    u = np.zeros_like(f)
    if model.anchored:
        free = model.free_dofs
        u[free] = Factorisation(model.K[free][:, free], model.linear_solver).solve(f[free])
        return u.reshape(-1, 3)
    shift = _SHIFT * float(np.mean(model.K.diagonal() / model.M.diagonal()))
    solve = Factorisation(model.K + shift * model.M, model.linear_solver).solve
    remove_rigid = _rigid_projector(model)
    for _ in range(_REFINEMENTS):
        u = remove_rigid(u + solve(f - model.K @ u))
    return u.reshape(-1, 3)


def _rigid_projector(model):
    """``u -> u - G (G^T M G)^-1 G^T M u``: removes the mass-weighted best-fit (linearised) rigid
    motion, translations and small rotations ``w x (X - X_c)`` (the linear form of shape matching)."""
    n, r = model.node_count, model.rest_offsets
    G = np.zeros((n, 3, 6))
    G[:, :, :3] = np.eye(3)
    for k in range(3):   # rotation about axis k: e_k x r
        G[:, :, 3 + k] = np.cross(np.eye(3)[k], r)
    G = G.reshape(3 * n, 6)
    MG = model.M @ G
    gram = G.T @ MG
    return lambda u: u - G @ np.linalg.solve(gram, MG.T @ u)


def update_reference(model, state, dt=None):
    """Bake the plastic deformation into the rest shape. Returns ``(new_model, new_state)``.

    The new model has rest points ``X + u_p`` (see the module docstring), rebuilt K, M and element
    data, and its own factorisation (done now for ``dt`` s if given, floating frame); positions and
    velocities are unchanged, the plastic strain is reset so that each point's elastic strain is
    unchanged (``eps_p - eps(u_p)`` to first order).
    """
    eps_p = state.tet_plastic_strain
    u_p = plastic_displacement(model, state)
    new_model = with_rest_points(model, model.rest_points + u_p, dt,
                                 reference_peeq=state.tet_peeq.copy(),
                                 reference_updates=model.reference_updates + 1)
    R, c = body_frame(new_model, state.x)
    # eps_p - eps(u_p) to first order, but exactly the strain that keeps each point's elastic
    # strain: the new shape's gradients (and frame) measure the same positions differently, by
    # eps(u_p) times the strain, which in a neck flowing 80% put updates at 13 Y
    eps_p_new = eps_p + quadrature_strain(new_model, state.replace(R=R, c=c)) \
        - quadrature_strain(model, state)
    # the plastic force of the reset strain, and the increment the next step is predicted to make
    # (fem.plastic_flow.plastic_update) carried over, so that an update does not change the flow
    force = rest_frame_plastic_force(new_model, eps_p_new)
    if state.node_plastic_force is not None:
        force += state.node_plastic_force - rest_frame_plastic_force(model, eps_p)
    shift = u_p if state.node_rest_shift is None else state.node_rest_shift + u_p
    return new_model, state.replace(R=R, c=c, tet_plastic_strain=eps_p_new, node_plastic_force=force,
                                    node_rest_shift=shift, v=_momenta_kept(model, new_model, state))


def _momenta_kept(model, new_model, state):
    """The velocities ``(n, 3)`` with which ``new_model`` (its nodes' masses shared out anew by
    the new shape) carries the linear and angular momentum ``model`` carried: ``v`` plus the
    rigid motion that makes up the difference. Kept as they were, a plate dented by a ball at
    30 m/s gained 1.8e-6 N s at an update, where every step keeps it to 1e-14. Anchored bodies
    (their anchors take momentum) keep ``v``."""
    v, x = state.v, state.x
    if model.has_anchors:
        return v
    p_old, p_new = linear_momentum(model, state), linear_momentum(new_model, state)
    total = mass_weights(new_model).sum()
    c = center_of_mass(new_model, state)
    a = (p_old - p_new) / total
    inertia, _ = mass_moments(new_model, x - c, v)
    dl = angular_momentum(model, state) - angular_momentum(new_model, state) - total * np.cross(c, a)
    b = np.linalg.solve(inertia, dl)
    return v + a + np.cross(b, x - c)


def apply_reference_updates(models, states, dt):
    """Run the update on every body that is due. ``models``/``states``: sequences of FemModel and
    FemState. Returns ``(models, states, updated)`` as new lists and the indices updated."""
    models, states, updated = list(models), list(states), []
    for j, (m, s) in enumerate(zip(models, states)):
        if reference_update_due(m, s):
            models[j], states[j] = update_reference(m, s, dt)
            updated.append(j)
    return models, states, updated
