"""Implicit time integration of a deformable body, split so contact impulses can be coupled in.

One step is ``predict`` (contact-free end-of-step velocities from the implicit solve), any number of
``apply_impulse`` calls (the response of the same implicit system to node impulses, one extra
back-substitution each), then ``finish`` (positions, frame, anchor reactions; under Newmark, any
energy the step gained beyond the work done on the body is taken out, ``_cap_energy``).

Equations (h = dt, C = alpha M + beta K_R, f(x) the elastic force, f_ext loads and gravity):
  backward Euler  (M + h C + h^2 K_R) v+ = M v + h (f(x) + f_ext),              x+ = x + h v+
  Newmark (gamma = 1/2, beta = 1/4, i.e. the trapezoidal rule on x and v)
    (M + h/2 C + h^2/4 K_R) v+ = M v + h (f(x) + f_ext) - (h/2 C + h^2/4 K_R) v, x+ = x + h (v + v+)/2
A free body is stepped in the frame that moves with its centre of mass and spins at its angular
velocity over the step (``fem.spin_frame``): either rule on world coordinates moves a spinning
body's nodes along chords, which stretches it and feeds energy into the spin (the trapezoidal rule
then diverges; backward Euler gained 80% in 3 s on a rubber block at w h = 0.3).
K_R is the stiffness seen in the current frame: ``R K R^T`` (floating frame; since M is isotropic
per node, the matrix is ``R A R^T`` and one factorisation of A serves all steps) or the warped
stiffness ``sum_e R_e K_e R_e^T`` (corotated, Mueller and Gross 2004), rebuilt every step.
The system (``fem.system``), the body's mass and momenta (``fem.momentum``) and the free body's
spinning frame (``fem.spin_frame``) have modules of their own; their public names are this
module's too (``__all__``).
"""
from dataclasses import replace

import numpy as np
import scipy.sparse as sp

from fem.warping import warped_energy
from fem.momentum import (angular_momentum, center_of_mass, linear_momentum, mass_moments, mass_times,
                          mass_weights, rigid_part)
from fem.plastic_flow import elastic_energy as plastic_elastic_energy
from fem.plastic_flow import plastic_update
from fem.rotations import element_rotations
from fem.spin_frame import impulse_turn, predict_spin_frame, shift_turned
from fem.step_kernels import anchor_reaction, fit_moment, rotate_back
from fem.system import (LazyMatrix, StepData, elastic_force, gravity_force, implicitness,
                        internal_forces_and_solver, right_hand_side, system_coefficients, system_factorisation,
                        system_matrix, warped_stiffness)
from rigid.shape_matching import best_fit_frame, rotation_of

__all__ = ["StepData", "predict", "apply_impulse", "finish", "step", "body_frame", "energy",
           "kinetic_energy", "elastic_energy", "effective_node_mass", "best_fit_rotation", "volume",
           "system_coefficients", "system_matrix", "system_factorisation", "implicitness",
           "warped_stiffness", "elastic_force", "gravity_force", "mass_weights", "mass_times",
           "mass_moments", "rigid_part", "linear_momentum", "angular_momentum", "center_of_mass"]


def body_frame(model, x):
    """Best-fit rotation ``R`` (3, 3) and centre ``c`` (3,) m of positions ``x`` (n, 3) m.

    Anchored bodies have no floating frame: ``(I, X_c)`` (nodes held by resting contact leave
    the frame floating, see :func:`fem.model.holding`).
    """
    if model.has_anchors:
        return np.eye(3), model.rest_center.copy()
    # rigid.shape_matching.best_fit_frame in one pass over the nodes (fem.step_kernels.fit_moment)
    c, A_pq = fit_moment(model.node_mass, x, model.rest_offsets)
    return rotation_of(A_pq), c


def _solve_in_frame(model, step_solve, A, rhs_b, v_fixed_b):
    """Solve ``A v = rhs`` on the free DOFs with fixed DOFs prescribed; returns v ``(3n,)``."""
    if not model.anchored:
        return step_solve(rhs_b)
    v = np.zeros_like(rhs_b)
    v[model.fixed_dofs] = v_fixed_b
    if not v_fixed_b.any():                 # held still (anchors at rest, resting nodes): no pull
        v[model.free_dofs] = step_solve(rhs_b[model.free_dofs])
        return v
    if A is model.cache.factor.matrix:      # the rest system: its free-fixed block is kept
        pull = model.cache.factor.derived("free_fixed", lambda: sp.csr_matrix(A)[model.free_dofs][
            :, model.fixed_dofs].tocsr()) @ v_fixed_b
    else:
        pull = (A @ v)[model.free_dofs]
    v[model.free_dofs] = step_solve(rhs_b[model.free_dofs] - pull)
    return v


def _fixed_rows(model, A, v):
    """``(A v)[fixed]`` (the anchors' rows), with the rest system's rows kept."""
    if A is model.cache.factor.matrix:
        return model.cache.factor.derived("fixed_rows", lambda: sp.csr_matrix(A)[model.fixed_dofs]) @ v
    return (A @ v)[model.fixed_dofs]


def _fixed_rows_of(model, A, free_columns_only):
    """The rows of the prescribed DOFs of A (CSR, columns in order), with only the free DOFs'
    columns when ``free_columns_only``."""
    rows = sp.csr_matrix(A)[model.fixed_dofs]
    if free_columns_only:
        free = np.zeros(A.shape[1])
        free[model.free_dofs] = 1.0
        rows = sp.csr_matrix(rows.multiply(free[None, :]))
        rows.eliminate_zeros()
        rows.sort_indices()
    return rows


def _anchor_reaction(model, step, dt):
    """The anchors' forces ``(n, 3)`` N (world) over the step: ``(A v+ - rhs - impulse)`` on the
    prescribed DOFs over dt, in the solve frame turned back to world; the rest system's fixed rows
    in one pass (fem.step_kernels.anchor_reaction)."""
    R = np.asarray(step.R, float)
    if step.matrix is model.cache.factor.matrix:
        # prescribed at rest (anchors): their columns add nothing to the rows' products, which
        # then read the free columns alone (a third of the entries at the 10k-tet slab's base)
        at_rest = not step.v[model.fixed_nodes].any()
        rows = model.cache.factor.derived(("fixed_rows", at_rest), lambda: _fixed_rows_of(model, step.matrix, at_rest))
        return anchor_reaction(rows.indptr, rows.indices, rows.data, model.fixed_dofs, step.v,
                               step.impulse, step.rhs, R, dt)
    fixed = model.fixed_dofs
    residual = (_fixed_rows(model, step.matrix, (step.v @ R).ravel())
                - step.rhs[fixed] - (step.impulse @ R).ravel()[fixed])
    r = np.zeros(3 * model.node_count)
    r[fixed] = residual / dt
    return r.reshape(-1, 3) @ R.T


def predict(model, state, dt, gravity=(0.0, 0.0, 0.0), held_velocity=None):
    """Contact-free end-of-step velocities. Returns :class:`StepData` with ``v`` ``(n, 3)`` m/s.

    dt s; gravity ``(3,)`` m/s^2. The floating frame reuses the factorisation cached in the model;
    the corotated frame assembles the warped stiffness and solves (``model.corotated_solver``).
    ``held_velocity``: ``(k, 3)`` m/s, the end-of-step velocities (world) of a variant's
    ``held_nodes`` (:func:`fem.model.holding`).
    """
    if not model.anchored:
        return predict_spin_frame(model, state, dt, gravity, _allowance(model, state))
    force, K, R, A, solve, iterations = internal_forces_and_solver(model, dt, state)
    load = gravity_force(model, gravity) + model.node_load
    force += load
    rhs = right_hand_side(model, dt, state.v, force, K, R)
    if A is None and model.anchored:
        A = system_matrix(model, dt)
    v_fixed = _prescribed_velocity(model, held_velocity)
    v_new = _solve_in_frame(model, solve, A, rhs, (v_fixed @ R).ravel())
    if A is None:
        A = LazyMatrix(model, dt)
    v_new = rotate_back(v_new, np.asarray(R, float))
    if model.integrator == "newmark":
        x_base, x_rate = state.x + 0.5 * dt * state.v, 0.5 * dt
    else:
        x_base, x_rate = state.x, dt
    return StepData(v=v_new, x_base=x_base, x_rate=x_rate, rhs=rhs, impulse=np.zeros_like(state.v), R=R,
                    matrix=A, solve=solve, iterations=iterations, load=load, allowance=_allowance(model, state))


def _prescribed_velocity(model, held_velocity):
    """``(k, 3)`` world velocities (m/s) of the prescribed nodes (``model.fixed_nodes``): their
    anchor's, or for held nodes ``held_velocity`` (in ``model.held_nodes`` order)."""
    nodes = model.fixed_nodes
    if model.held_nodes is None and not model.anchor_velocity.any():    # anchors at rest
        return np.zeros((len(nodes), 3))
    anchor = model.node_anchor[nodes]
    v = np.zeros((len(nodes), 3))
    v[anchor >= 0] = model.anchor_velocity[anchor[anchor >= 0]]
    if model.held_nodes is not None:
        v[np.searchsorted(nodes, model.held_nodes)] = held_velocity
    return v


def apply_impulse(model, state, step, node_impulse):
    """Add node impulses ``(n, 3)`` N s applied during the step: ``v += A^-1 impulse``.

    The response is that of the same implicit system (one back-substitution with the step's
    factorisation); anchored nodes do not respond. Returns a new :class:`StepData`.
    """
    j = np.asarray(node_impulse, dtype=float)
    dv = impulse_velocity(model, step.solve, (j @ step.R).ravel())
    return replace(step, v=step.v + dv.reshape(-1, 3) @ step.R.T, impulse=step.impulse + j)


def impulse_velocity(model, solve, j_b):
    """Velocity change ``(3n,)`` (body frame) of node impulses ``j_b`` ``(3n,)`` N s (body frame)
    through a factorised system ``solve`` on the free DOFs; prescribed DOFs do not respond."""
    if not model.anchored:
        return solve(j_b)
    dv = np.zeros_like(j_b)
    dv[model.free_dofs] = solve(j_b[model.free_dofs])
    return dv


def finish(model, state, step, dt, shift=None):
    """Advance positions with the step's velocities, update the best-fit frame and anchor reactions,
    under Newmark keep the body's energy within its allowance (``_cap_energy``), and (plastic
    bodies only) return-map the new strain onto the yield surface
    (``fem.plastic_flow.plastic_update``). Returns the new :class:`fem.model.FemState`.
    ``shift``: ``(nodes (k,), dx (k, 3) m)``, moves of some nodes' end positions (a contact's
    penetration recovery, positions only), made before the energy is held to its allowance (after
    it, a soft block struck by a ball under Newmark kept the 23% of energy the moves put in), and
    for a plastic body after its return map; the frame is fitted to the moved nodes.
    """
    x, v = step.x_base + step.x_rate * step.v, step.v
    if step.v_free is not None and step.impulse.any():
        x, v = impulse_turn(model, state, step)        # (the rigid turn of its impulses, exactly)
        step = replace(step, v=v)
    late = shift is not None and model.plastic
    if shift is not None and not late:      # nothing below reads the positions: move them now
        x, v = _shifted(model, state, step, x, v, shift)
    if model.anchored:
        # A v+ - rhs - impulse on the prescribed DOFs is dt times the force the anchors applied
        reaction = _anchor_reaction(model, step, dt)
    else:
        reaction = np.zeros_like(x)
    R, c = body_frame(model, x)
    new = state.replace(x=x, v=v.copy(), R=R, c=c, node_reaction=reaction, time=state.time + dt)
    if step.allowance is not None:
        new = _cap_energy(model, state, step, new, dt)
    if model.plastic:
        new = plastic_update(model, new)
    if late:
        x, v = _shifted(model, state, step, new.x, new.v, shift)
        R, c = body_frame(model, x)
        new = new.replace(x=x, v=v, R=R, c=c)
    return new


def _shifted(model, state, step, x, v, shift):
    """End positions and velocities after the ``shift`` of :func:`finish` (for a body stepped in
    its spinning frame, its turn taken exactly: ``fem.spin_frame.shift_turned``)."""
    nodes, dx = shift
    if step.v_free is not None:
        full = np.zeros_like(x)
        full[nodes] = dx
        return shift_turned(model, state, x, v, full)
    x = x.copy()
    x[nodes] += dx
    return x, v


def energy(model, state):
    """Kinetic and elastic energy (J). The elastic part of the last positions (and plastic strain)
    asked for is kept in ``model.cache.elastic_energy`` (a Newmark step's end is the next one's
    start)."""
    last = model.cache.elastic_energy
    eps_p = state.tet_plastic_strain
    if last is not None and np.array_equal(last[0], state.x) and (
            last[1] is None and eps_p is None
            or last[1] is not None and eps_p is not None and np.array_equal(last[1], eps_p)):
        elastic = last[2]
    else:
        elastic = elastic_energy(model, state)
        model.cache.elastic_energy = (np.array(state.x, dtype=float),
                                      None if eps_p is None else np.array(eps_p, dtype=float), elastic)
    return kinetic_energy(model, state) + elastic


def _allowance(model, state):
    """The energy a Newmark step may end with before the work done in it (J): the body's energy
    and its slack; None for backward Euler."""
    if model.integrator != "newmark":
        return None
    return energy(model, state) + state.energy_slack


# relative size of an energy gain left alone: round-off
ENERGY_TOL = 1e-12


def _cap_energy(model, state, step, end, dt):
    """The end state ``end`` of a Newmark step with any energy beyond its allowance taken out.

    The trapezoidal rule conserves the energy of a linear system exactly, but neither frame is
    quite linear: the corotated force turns with its elements within the step (a rubber block at
    dt = 0.003 gained 138% in 3 s, and 50% with the rule solved to convergence by chord
    iterations) and the floating frame's best-fit rotation is not the energy's (a gain second
    order in the strain, 1.4% in 3 s at dt = 0.001). Nothing in the rule damps such gains. So a
    body may hold at most its allowance: the energy it was created with plus the work done on it
    by its steps (external forces, contact impulses and anchor reactions at each step's mean
    velocity: the trapezoidal rule's own balance). A step that ends above it loses the excess
    from the deformation's velocities (the velocity field less its rigid motion for a free body;
    the free nodes' velocities for a held one), which keeps linear and angular momentum (an
    energy projection, as in Dinev et al. 2018, "FEPR: fast energy projection ..."). Below the
    allowance nothing changes: the rule's energy error oscillates, and taking out its upswings
    step by step damped a rubber block to a quarter of its energy in 3 s. The state
    keeps how far below the allowance it ends (``energy_slack``), so what happens to it between
    steps (a plastic return map's dissipation, a kick, a new rest shape) moves the allowance too.
    """
    v = step.v
    mean = 0.5 * (state.v + v)
    allowance = step.allowance + float(np.sum((dt * (step.load + end.node_reaction) + step.impulse) * mean))
    excess = energy(model, end) - allowance
    if not excess > ENERGY_TOL * abs(allowance):
        return end.replace(energy_slack=-excess)
    if model.anchored:
        rigid = np.zeros_like(v)
        rigid[model.fixed_nodes] = v[model.fixed_nodes]
    else:
        rigid = rigid_part(model, end.x, v)
    u = (v - rigid).ravel()
    Mu = model.M @ u
    # kinetic energy with the deformation's velocities scaled by s is a + b s + c s^2: take out
    # the excess, c (1 - s^2) + b (1 - s) = excess, by the root in [0, 1] (0 if out of reach)
    b, c = float(rigid.ravel() @ Mu), 0.5 * float(u @ Mu)
    disc = b * b + 4.0 * c * (c + b - excess)
    s = (-b + np.sqrt(disc)) / (2.0 * c) if disc >= 0.0 and c > 0.0 else 0.0
    s = min(max(s, 0.0), 1.0)
    return end.replace(v=rigid + s * (v - rigid), energy_slack=0.0)    # at the allowance, or above


def step(model, state, dt, gravity=(0.0, 0.0, 0.0)):
    """One step without contacts: ``finish(predict(...))``."""
    return finish(model, state, predict(model, state, dt, gravity), dt)


# --- diagnostics -----------------------------------------------------------------------------

def effective_node_mass(model):
    """Mass of each node for contact impulses ``(n,)`` (kg): the lumped mass."""
    return model.node_mass


def kinetic_energy(model, state):
    """``1/2 v^T M v`` (J)."""
    v = state.v.ravel()
    return 0.5 * float(v @ (model.M @ v))


def elastic_energy(model, state):
    """Strain energy of the linear model in its frame (J); plastic bodies: of ``eps - eps_p``."""
    if model.plastic and state.tet_plastic_strain is not None:
        return plastic_elastic_energy(model, state)
    if model.frame == "corotated":
        return warped_energy(model.elements, element_rotations(model, state.x), state.x, model.rest_points)
    u = ((state.x - state.c) @ state.R - model.rest_offsets).ravel()
    return 0.5 * float(u @ (model.K @ u))


def best_fit_rotation(model, state):
    """Best-fit rotation ``(3, 3)`` of the current shape to the rest shape (shape matching)."""
    return best_fit_frame(model.rest_offsets, state.x, model.node_mass)[0]


def volume(model, x):
    """Volume (m^3) enclosed by the deformed vertex simplices."""
    xs = x[model.tets[:, :4]]
    return float(np.linalg.det(xs[:, 1:] - xs[:, :1]).sum() / 6.0)
