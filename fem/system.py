"""The implicit system of a deformable body's step: its matrix, forces and right-hand side.

``A = a_M M + a_K K_R`` with the coefficients of the model's integrator
(:func:`system_coefficients`), K_R the rest stiffness turned into the body's frame (floating and
anchored bodies: one factorisation of the rest system, kept in ``model.cache``) or the warped
stiffness of a corotated body (assembled and solved every step, ``model.corotated_solver``). See
``fem.dynamics`` for the equations and the step that uses them.
"""
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from fem.warping import warped_assembly, warped_forces
from fem.plastic_flow import plastic_force
from fem.rotations import element_rotations
from fem.solver import Factorisation, cg_solve
from fem.step_kernels import frame_elastic_force, lumped_rhs


@dataclass(frozen=True)
class StepData:
    """One step in progress (between ``fem.dynamics.predict`` and ``fem.dynamics.finish``).

    v: ``(n, 3)`` end-of-step node velocities (m/s), world frame.
    x_base, x_rate: end-of-step positions are ``x_base + x_rate * v`` (``(n, 3)`` m, s), so contact
        impulses move the nodes they speed up.
    rhs: ``(3n,)`` right-hand side of the system in the solve frame (N s).
    impulse: ``(n, 3)`` node impulses applied so far (N s), world frame.
    R: ``(3, 3)`` rotation of the solve frame (body frame for a floating body, else identity).
    matrix: ``(3n, 3n)`` system matrix A in the solve frame (kg).
    solve: callable mapping a free-DOF right-hand side ``(f,)`` to ``A_ff^-1`` of it.
    iterations: one-element list, CG iterations spent by this step's corotated solves.
    load: ``(n, 3)`` external node forces over the step (gravity and loads, N), world frame.
    allowance: under Newmark, the most energy (kinetic and elastic, J) the body may hold at the
        start of the step: its energy and its ``FemState.energy_slack`` (see ``fem.dynamics._cap_energy``);
        None under backward Euler.
    v_free: for a body stepped in its spinning frame (``fem.spin_frame``), ``v`` before any
        impulse (m/s, world); its impulses' rigid turn is then taken exactly (``fem.spin_frame.turn``).
    """
    v: np.ndarray
    x_base: np.ndarray
    x_rate: float
    rhs: np.ndarray
    impulse: np.ndarray
    R: np.ndarray
    matrix: sp.csr_matrix
    solve: object
    iterations: list
    load: np.ndarray
    allowance: float | None
    v_free: np.ndarray | None = None


def system_coefficients(model, dt):
    """``(a_M, a_K)`` with system matrix ``A = a_M M + a_K K`` for the model's integrator."""
    alpha, beta = model.damping_mass, model.damping_stiffness
    if model.integrator == "newmark":
        return 1.0 + 0.5 * dt * alpha, 0.5 * dt * beta + 0.25 * dt * dt
    return 1.0 + dt * alpha, dt * beta + dt * dt


def _free_block(model, A):
    if not model.anchored:
        return A
    return A[model.free_dofs][:, model.free_dofs]


def system_matrix(model, dt, K=None):
    """System matrix ``a_M M + a_K K`` ``(3n, 3n)`` (rest K, cached with the factorisation,
    unless a warped one is given)."""
    a_M, a_K = system_coefficients(model, dt)
    if K is None:
        return model.cache.factor.system(dt, lambda h: (a_M * model.M + a_K * model.K).tocsr())
    return (a_M * model.M + a_K * K).tocsr()


def system_factorisation(model, dt):
    """Cached factorisation of the rest system matrix on the free DOFs (factorised once per dt)."""
    return model.cache.factor.get(dt, lambda h: _free_block(model, system_matrix(model, h)),
                                  model.linear_solver)


def implicitness(model):
    """Weight theta of the end-of-step velocity in the position update ``x+ = x + h ((1 - theta) v
    + theta v+)``: 1/2 for Newmark (trapezoidal rule), 1 for backward Euler."""
    return 0.5 if model.integrator == "newmark" else 1.0


def warped_stiffness(model, tet_R):
    """Warped stiffness ``sum_e R_e K_e R_e^T`` ``(3n, 3n)`` CSR (N/m) (:func:`fem.warping.warped_assembly`)."""
    return warped_assembly(model.elements, tet_R, 3 * model.node_count)


def elastic_force(model, state, tet_R=None):
    """Elastic node forces ``(n, 3)`` (N), world frame, linear elasticity in the model's frame."""
    if model.frame == "corotated":
        tet_R = element_rotations(model, state.x) if tet_R is None else tet_R
        return warped_forces(model.elements, tet_R, state.x, model.rest_points, model.node_count)
    # (fem.step_kernels.frame_elastic_force: frame_offsets, K u and rotate_back in one pass)
    ptr, col, blocks = stiffness_blocks(model)
    return frame_elastic_force(ptr, col, blocks, state.x, np.asarray(state.c, float),
                               np.asarray(state.R, float), model.rest_offsets)


def stiffness_blocks(model):
    """The rest stiffness K as 3x3 block rows ``(ptr, col, blocks)`` (scipy's BSR arrays), built
    once and kept with the model's system (``model.cache.factor``; keyed by the K it was built
    from, which the memo holds on to, so a model with another K builds its own)."""
    return model.cache.factor.derived(("stiffness_blocks", id(model.K)), lambda: _blocks(model.K))[1]


def _blocks(K):
    B = sp.bsr_matrix(K, blocksize=(3, 3))
    B.sort_indices()
    return K, (B.indptr.astype(np.int64), B.indices.astype(np.int64), np.ascontiguousarray(B.data))


def gravity_force(model, gravity):
    """Node weights ``(n, 3)`` (N) for gravity ``(3,)`` m/s^2 (M applied to a uniform field)."""
    key = tuple(np.asarray(gravity, dtype=float).ravel())
    last = model.cache.gravity_force      # the same gravity every step: kept
    if last is None or last[0] != key:
        g = np.broadcast_to(np.asarray(key), (model.node_count, 3))
        last = model.cache.gravity_force = (key, (model.M @ g.ravel()).reshape(-1, 3))
    return last[1].copy()


def right_hand_side(model, dt, v, force, K, R):
    """``(3n,)`` right-hand side (N s) of the step's system for start velocities ``v`` and forces
    ``force`` ``(n, 3)`` (world), in the solve frame: node vectors rotated by ``R^T`` (M is
    isotropic per node, so it commutes). See the equations of ``fem.dynamics``."""
    if model.mass_kind == "lumped" and model.integrator != "newmark":
        # M is the diagonal of the node masses: one pass (fem.step_kernels.lumped_rhs)
        return lumped_rhs(model.node_mass, v, np.asarray(R, float), force, dt)
    v_b = (v @ R).ravel()
    Mv = model.M @ v_b
    rhs = Mv + dt * (force @ R).ravel()
    if model.integrator == "newmark":
        a_M, a_K = system_coefficients(model, dt)
        rhs -= (a_M - 1.0) * Mv + a_K * (K @ v_b)
    return rhs


def internal_forces_and_solver(model, dt, state):
    """This step's internal forces ``(n, 3)`` N (elastic and plastic, world), the stiffness K_R of
    the system, the solve frame R, the system matrix (None: the cached rest one), the solver of
    the free DOFs and its CG iteration count (a one-element list)."""
    a_M, a_K = system_coefficients(model, dt)
    if model.frame == "corotated":
        tet_R = element_rotations(model, state.x)
        force = elastic_force(model, state, tet_R)
        if model.plastic:
            force += plastic_force(model, state, tet_R)
        K, A, A_ff = _warped_system(model, dt, tet_R)
        solve, iterations = _corotated_solver(model, dt, A_ff, state)
        return force, K, np.eye(3), A, solve, iterations
    force = elastic_force(model, state)
    if model.plastic:
        force += plastic_force(model, state)
    return force, model.K, state.R, None, system_factorisation(model, dt).solve, [0]


class LazyMatrix:
    """Stands for the rest system matrix until someone needs it (reactions of free bodies: never)."""

    def __init__(self, model, dt):
        self.model, self.dt = model, dt

    def __matmul__(self, vector):
        return system_matrix(self.model, self.dt) @ vector


def _warped_system(model, dt, tet_R):
    """The warped stiffness K_R, the step's system ``A = a_M M + a_K K_R`` and A's block on the free
    DOFs (CSR), all on the fixed pattern of K (:func:`_warped_places`): the sum is taken value by
    value, the mass added at its places, and the free block gathered from A's values, instead of
    summing and slicing sparse matrices every step (the same numbers)."""
    a_M, a_K = system_coefficients(model, dt)
    K = warped_stiffness(model, tet_R)
    places = _warped_places(model)
    if places is None:
        A = (a_M * model.M + a_K * K).tocsr()
        return K, A, _free_block(model, A)
    at, mass, free_entries, free_indices, free_indptr = places
    a = a_K * K.data
    a[at] += a_M * mass
    A = sp.csr_matrix((a, K.indices, K.indptr), shape=K.shape)
    if not model.anchored:
        return K, A, A
    f = len(model.free_dofs)
    return K, A, sp.csr_matrix((a[free_entries], free_indices, free_indptr), shape=(f, f))


def _warped_places(model):
    """Where the mass matrix's entries sit in the stiffness pattern, and which pattern entries make
    the free block: ``(at (m,), mass (m,), free_entries, free_indices, free_indptr)``, the last
    three the free block's CSR data positions, columns and row pointer; None when M has an entry
    outside the pattern. Built once per model (a held variant has its own cache)."""
    if model.cache.warped_places is None:
        data, n3 = model.elements, 3 * model.node_count
        rows = np.repeat(np.arange(n3), np.diff(data.pattern_indptr))
        keys = rows * n3 + data.pattern_cols             # sorted: rows in order, columns within
        M = sp.csr_matrix(model.M)
        M.sum_duplicates()
        m_keys = np.repeat(np.arange(n3), np.diff(M.indptr)) * n3 + M.indices
        at = np.minimum(np.searchsorted(keys, m_keys), len(keys) - 1)
        if len(keys) == 0 or not np.array_equal(keys[at], m_keys):
            model.cache.warped_places = (None,)
        else:
            free = np.zeros(n3, dtype=bool)
            free[model.free_dofs] = True
            entries = np.nonzero(free[rows] & free[data.pattern_cols])[0]
            renumber = np.cumsum(free) - 1
            indptr = np.concatenate([[0], np.cumsum(np.bincount(renumber[rows[entries]],
                                                                 minlength=len(model.free_dofs)))])
            model.cache.warped_places = (at, M.data.copy(), entries, renumber[data.pattern_cols[entries]],
                                         indptr)
    places = model.cache.warped_places
    return None if places[0] is None else places


def _corotated_solver(model, dt, A_ff, state):
    """Solver for this step's warped system on the free DOFs (``A_ff``); returns ``(solve,
    iterations)`` where ``iterations`` is a one-element list counting CG iterations (stays 0 for
    LU)."""
    iterations = [0]
    if model.corotated_solver == "lu":
        return Factorisation(A_ff, model.linear_solver).solve, iterations
    # precondition with the rest system rotated into the body's best-fit frame: exact for a rigid
    # rotation of the whole body, close while the elements rotate together (R = I when anchored;
    # a body whose resting nodes are held keeps its floating frame, and every DOF of a held node
    # is prescribed, so its free DOFs turn node by node too)
    rest = system_factorisation(model, dt)
    R = np.asarray(state.R, float)
    turned = not np.array_equal(R, np.eye(3))

    def precondition(r):
        if not turned:
            return rest.solve(r)
        return (rest.solve((r.reshape(-1, 3) @ R).ravel()).reshape(-1, 3) @ R.T).ravel()

    # the step's first solve is for its velocities, warm-started from the last ones; the later
    # ones answer impulses (velocity changes) and start from zero
    guess = [state.v.ravel()[model.free_dofs] if model.anchored else state.v.ravel()]

    direct = []      # this step's factorisation, made only if CG fails to converge

    def solve(rhs):
        if not direct:
            try:
                x, its = cg_solve(A_ff, rhs, guess.pop() if guess else None, precondition)
                iterations[0] += its
                return x
            except RuntimeError:
                # a body crushed far from its best-fit frame (an order-2 pane at 60 m/s) left the
                # preconditioner too poor: this step solves directly instead
                direct.append(Factorisation(A_ff, model.linear_solver))
        return direct[0].solve(rhs)

    return solve, iterations
