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
velocity over the step (``_predict_spin_frame``): either rule on world coordinates moves a spinning
body's nodes along chords, which stretches it and feeds energy into the spin (the trapezoidal rule
then diverges; backward Euler gained 80% in 3 s on a rubber block at w h = 0.3).
K_R is the stiffness seen in the current frame: ``R K R^T`` (floating frame; since M is isotropic
per node, the matrix is ``R A R^T`` and one factorisation of A serves all steps) or the warped
stiffness ``sum_e R_e K_e R_e^T`` (corotated, Mueller and Gross 2004), rebuilt every step.
"""
from dataclasses import dataclass, replace
from typing import NamedTuple

import numba as nb
import numpy as np
import scipy.sparse as sp

from fem.assembly import warped_assembly, warped_energy, warped_forces
from fem.plastic_flow import elastic_energy as plastic_elastic_energy
from fem.plastic_flow import plastic_force, plastic_update
from fem.rotations import element_rotations
from fem.solver import Factorisation, cg_solve
from rigid.shape_matching import best_fit_frame

@dataclass(frozen=True)
class StepData:
    """One step in progress (between ``predict`` and ``finish``).

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
        start of the step: its energy and its ``FemState.energy_slack`` (see ``_cap_energy``);
        None under backward Euler.
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


def body_frame(model, x):
    """Best-fit rotation ``R`` (3, 3) and centre ``c`` (3,) m of positions ``x`` (n, 3) m.

    Anchored bodies have no floating frame: ``(I, X_c)`` (nodes held by resting contact leave
    the frame floating, see :func:`fem.model.holding`).
    """
    if model.has_anchors:
        return np.eye(3), model.rest_center.copy()
    return best_fit_frame(model.rest_offsets, x, model.node_mass)


def warped_stiffness(model, tet_R):
    """Warped stiffness ``sum_e R_e K_e R_e^T`` ``(3n, 3n)`` CSR (N/m) (:func:`fem.assembly.warped_assembly`)."""
    return warped_assembly(model.elements, tet_R, 3 * model.node_count)


def elastic_force(model, state, tet_R=None):
    """Elastic node forces ``(n, 3)`` (N), world frame, linear elasticity in the model's frame."""
    if model.frame == "corotated":
        tet_R = element_rotations(model, state.x) if tet_R is None else tet_R
        return warped_forces(model.elements, tet_R, state.x, model.rest_points, model.node_count)
    u = (state.x - state.c) @ state.R - model.rest_offsets
    return -(model.K @ u.ravel()).reshape(-1, 3) @ state.R.T


def gravity_force(model, gravity):
    """Node weights ``(n, 3)`` (N) for gravity ``(3,)`` m/s^2 (M applied to a uniform field)."""
    key = tuple(np.asarray(gravity, dtype=float).ravel())
    last = model.cache.gravity_force      # the same gravity every step: kept
    if last is None or last[0] != key:
        g = np.broadcast_to(np.asarray(key), (model.node_count, 3))
        last = model.cache.gravity_force = (key, (model.M @ g.ravel()).reshape(-1, 3))
    return last[1].copy()


def _solve_in_frame(model, step_solve, A, rhs_b, v_fixed_b):
    """Solve ``A v = rhs`` on the free DOFs with fixed DOFs prescribed; returns v ``(3n,)``."""
    if not model.anchored:
        return step_solve(rhs_b)
    v = np.zeros_like(rhs_b)
    v[model.fixed_dofs] = v_fixed_b
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


def predict(model, state, dt, gravity=(0.0, 0.0, 0.0), held_velocity=None):
    """Contact-free end-of-step velocities. Returns :class:`StepData` with ``v`` ``(n, 3)`` m/s.

    dt s; gravity ``(3,)`` m/s^2. The floating frame reuses the factorisation cached in the model;
    the corotated frame assembles the warped stiffness and solves (``model.corotated_solver``).
    ``held_velocity``: ``(k, 3)`` m/s, the end-of-step velocities (world) of a variant's
    ``held_nodes`` (:func:`fem.model.holding`).
    """
    if not model.anchored:
        return _predict_spin_frame(model, state, dt, gravity)
    force, K, R, A, solve, iterations = _internal_forces_and_solver(model, dt, state)
    load = gravity_force(model, gravity) + model.node_load
    force += load
    rhs = _right_hand_side(model, dt, state.v, force, K, R)
    if A is None and model.anchored:
        A = system_matrix(model, dt)
    v_fixed = _prescribed_velocity(model, held_velocity)
    v_new = _solve_in_frame(model, solve, A, rhs, (v_fixed @ R).ravel())
    if A is None:
        A = _LazyMatrix(model, dt)
    v_new = v_new.reshape(-1, 3) @ R.T
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
    anchor = model.node_anchor[nodes]
    v = np.zeros((len(nodes), 3))
    v[anchor >= 0] = model.anchor_velocity[anchor[anchor >= 0]]
    if model.held_nodes is not None:
        v[np.searchsorted(nodes, model.held_nodes)] = held_velocity
    return v


def _right_hand_side(model, dt, v, force, K, R):
    """``(3n,)`` right-hand side (N s) of the step's system for start velocities ``v`` and forces
    ``force`` ``(n, 3)`` (world), in the solve frame: node vectors rotated by ``R^T`` (M is
    isotropic per node, so it commutes). See the module's equations."""
    v_b = (v @ R).ravel()
    Mv = model.M @ v_b
    rhs = Mv + dt * (force @ R).ravel()
    if model.integrator == "newmark":
        a_M, a_K = system_coefficients(model, dt)
        rhs -= (a_M - 1.0) * Mv + a_K * (K @ v_b)
    return rhs


def _internal_forces_and_solver(model, dt, state):
    """This step's internal forces ``(n, 3)`` N (elastic and plastic, world), the stiffness K_R of
    the system, the solve frame R, the system matrix (None: the cached rest one), the solver of
    the free DOFs and its CG iteration count (a one-element list)."""
    a_M, a_K = system_coefficients(model, dt)
    if model.frame == "corotated":
        tet_R = element_rotations(model, state.x)
        force = elastic_force(model, state, tet_R)
        if model.plastic:
            force += plastic_force(model, state, tet_R)
        K = warped_stiffness(model, tet_R)
        A = (a_M * model.M + a_K * K).tocsr()
        solve, iterations = _corotated_solver(model, dt, A, state)
        return force, K, np.eye(3), A, solve, iterations
    force = elastic_force(model, state)
    if model.plastic:
        force += plastic_force(model, state)
    return force, model.K, state.R, None, system_factorisation(model, dt).solve, [0]


def _rotation(phi):
    """Rotation matrix ``(3, 3)`` of a rotation vector ``(3,)`` (rad), by Rodrigues' formula."""
    angle = float(np.sqrt(phi @ phi))
    if angle < 1e-300:
        return np.eye(3)
    K = _skew(phi / angle)
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)


@nb.njit(cache=True)
def _inertia_and_moment(m, y, u):
    """Inertia tensor ``(3, 3)`` (kg m^2) of point masses ``m`` ``(n,)`` at ``y`` ``(n, 3)``, and
    ``sum_i m_i y_i x u_i`` ``(3,)`` for ``u`` ``(n, 3)``, in one pass (compiled: at 2,200 nodes
    the pass takes 19 us, the numpy products it replaces 40-160 us each)."""
    S = np.zeros((3, 3))
    moment = np.zeros(3)
    for i in range(len(m)):
        y0, y1, y2 = y[i, 0], y[i, 1], y[i, 2]
        u0, u1, u2 = u[i, 0], u[i, 1], u[i, 2]
        mi = m[i]
        for a in range(3):
            for b in range(3):
                S[a, b] += mi * y[i, a] * y[i, b]
        moment[0] += mi * (y1 * u2 - y2 * u1)
        moment[1] += mi * (y2 * u0 - y0 * u2)
        moment[2] += mi * (y0 * u1 - y1 * u0)
    inertia = -S
    trace = S[0, 0] + S[1, 1] + S[2, 2]
    for a in range(3):
        inertia[a, a] += trace
    return inertia, moment


def mass_weights(model):
    """``(n,)`` kg: the mass each node's velocity carries into the body's momentum, ``M 1`` per node
    (the lumped masses; the consistent matrix's row sums, negative at P2 corners). The body's
    centre of mass is ``mass_weights @ x / total``."""
    if model.mass_kind == "lumped":
        return model.node_mass
    if model.cache.mass_weights is None:
        model.cache.mass_weights = (model.M @ np.ones(3 * model.node_count))[::3]
    return model.cache.mass_weights


def mass_times(model, field):
    """``M field`` ``(n, 3)`` for a node field ``(n, 3)`` (a velocity gives momenta, kg m/s)."""
    if model.mass_kind == "lumped":
        return model.node_mass[:, None] * field
    return (model.M @ np.ascontiguousarray(field).ravel()).reshape(-1, 3)


def mass_moments(model, y, u):
    """Inertia tensor ``(3, 3)`` (kg m^2) of the body's mass at positions ``y`` ``(n, 3)`` about
    their origin, and the angular momentum ``sum_i y_i x (M u)_i`` ``(3,)`` of velocities ``u``
    ``(n, 3)``, both with the body's own mass matrix (lumped or consistent: with the lumped
    masses, a consistent-mass body spinning off its axes lost 1.3% of its angular momentum in 2 s)."""
    if model.mass_kind == "lumped":
        return _inertia_and_moment(model.node_mass, y, u)
    S = y.T @ mass_times(model, y)
    return np.trace(S) * np.eye(3) - S, np.cross(y, mass_times(model, u)).sum(axis=0)


def rigid_part(model, x, v):
    """The rigid motion ``(n, 3)`` m/s in velocities ``v`` of a free body at ``x``: the velocity
    field of its centre-of-mass velocity and angular velocity (``I^-1 L``), with the body's mass
    matrix; ``v`` less it carries no momentum."""
    weights = mass_weights(model)
    total = weights.sum()
    y = x - weights @ x / total
    inertia, L = mass_moments(model, y, v)
    return weights @ v / total + y @ _skew(np.linalg.solve(inertia, L)).T


def _skew(a):
    """``(3, 3)`` matrix of ``a x``: rows ``y`` ``(n, 3)`` give ``a x y_i`` as ``y @ _skew(a).T``."""
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def implicitness(model):
    """Weight theta of the end-of-step velocity in the position update ``x+ = x + h ((1 - theta) v
    + theta v+)``: 1/2 for Newmark (trapezoidal rule), 1 for backward Euler."""
    return 0.5 if model.integrator == "newmark" else 1.0


def _predict_spin_frame(model, state, dt, gravity):
    """Step of a free body in the frame that spins with it.

    Either rule on world coordinates moves nodes along chords: a spinning body is stretched by
    about ``(w h)^2 / 2`` per step, and the stretch feeds energy back into the spin (without
    numerical damping, the trapezoidal rule diverges). So the step is taken in the frame that
    translates with the centre of mass and turns at the body's angular velocity ``w = I^-1 L`` over
    the step: there the rigid motion is at rest, the integrator acts on the deformation only, and
    the frame's motion is exact. The frame adds its inertial forces: centrifugal
    ``-m w x (w x y)`` (explicit, at the mid-step positions: it is what stretches a spinning body)
    and Coriolis ``-2 m w x u`` (as rotations of the relative velocities by ``-w h`` before and
    after the solve, which do no work). The centre of mass takes the net force exactly; mass damping
    slows translation and spin as it slows the deformation. With no spin this is the world-frame
    step, the translation split off. Newmark stays second order (tests/test_fem_free_body.py).
    """
    h, theta = dt, implicitness(model)
    a_M = system_coefficients(model, dt)[0]
    force, K, R, A, solve, iterations = _internal_forces_and_solver(model, dt, state)
    f = _spin_frame(model, state)
    coriolis = _rotation(-h * f.w)                          # Coriolis over half the step
    u = (state.v - f.V - f.y @ _skew(f.w).T) @ coriolis.T   # velocities relative to the spinning frame
    turn = _rotation(h * f.w)                               # the frame's turn over the step
    external = gravity_force(model, gravity) + model.node_load
    net = external.sum(axis=0)
    torque = _inertia_and_moment(np.ones(len(f.m)), f.y, external)[1]
    load = external - np.outer(f.m / f.total, net)          # the net force moves the centre
    rhs, u_new, y_new = _relative_step(model, dt, f, u, force + (1.0 - theta) * load + theta * load @ turn,
                                       K, R, solve)
    u_new = u_new @ coriolis.T                              # and over the other half
    slow = (1.0 - (1.0 - theta) * h * model.damping_mass) / a_M     # mass damping of the rigid motion
    V_new = slow * f.V + h * net / (f.total * a_M)
    u_new, y_new, w_new = _end_spin(model, h, (slow * f.L + h * torque) @ turn, f.w, u_new, y_new)
    x_new = f.c + h * ((1.0 - theta) * f.V + theta * V_new) + y_new @ turn.T
    v_new = V_new + (u_new + y_new @ _skew(w_new).T) @ turn.T
    return StepData(v=v_new, x_base=x_new - theta * h * v_new, x_rate=theta * h, rhs=rhs,
                    impulse=np.zeros_like(state.v), R=R, matrix=_LazyMatrix(model, dt) if A is None else A,
                    solve=solve, iterations=iterations, load=external, allowance=_allowance(model, state))


class _SpinFrame(NamedTuple):
    """A free body's frame at the start of a step: mass weights ``m`` (n,) kg and their ``total``,
    centre of mass ``c`` (3,) m, node offsets ``y`` (n, 3) m from it, its velocity ``V`` (3,) m/s,
    ``inertia`` (3, 3) kg m^2 and angular momentum ``L`` (3,) kg m^2/s about it, and the angular
    velocity ``w = I^-1 L`` (3,) rad/s."""
    m: np.ndarray
    total: float
    c: np.ndarray
    y: np.ndarray
    V: np.ndarray
    inertia: np.ndarray
    L: np.ndarray
    w: np.ndarray


def _spin_frame(model, state):
    """The :class:`_SpinFrame` of a free body's ``state``, with its own mass matrix."""
    m = mass_weights(model)
    total = m.sum()
    c = m @ state.x / total                                 # the centre of mass (lumped: state.c)
    y = state.x - c
    inertia, L = mass_moments(model, y, state.v)            # about the centre of mass
    return _SpinFrame(m, total, c, y, m @ state.v / total, inertia, L, np.linalg.solve(inertia, L))


def _relative_step(model, dt, frame, u, applied, K, R, solve):
    """The deformation's step in the spinning ``frame`` from relative velocities ``u`` (n, 3) m/s
    under the ``applied`` forces (internal and external, n, 3) N: ``(rhs, u_new, y_new)``, the
    system's right-hand side and the end-of-step relative velocities and offsets (m/s, m)."""
    h, theta = dt, implicitness(model)
    y, W = frame.y, _skew(frame.w)
    y_mid = y + 0.5 * h * u                                 # centrifugal force at mid-step
    rhs = _right_hand_side(model, dt, u, applied - mass_times(model, y_mid @ (W @ W).T), K, R)
    u_new = solve(rhs).reshape(-1, 3) @ R.T
    y_new = y + h * ((1.0 - theta) * u + theta * u_new)
    if theta != 0.5:
        # the rigid turn relative to the frame (the spin's change, e.g. a wobble) by the trapezoidal
        # rule: it meets no stiffness to damp, and with backward Euler's first-order turn a tumbling
        # steel box drifted 4.3 degrees from Euler's equations in 1 s (0.033 with this)
        turn_rate = np.linalg.solve(frame.inertia, mass_moments(model, y, u - u_new)[1])
        y_new += (theta - 0.5) * h * y @ _skew(turn_rate).T
    return rhs, u_new, y_new


def _end_spin(model, h, L_new, w, u_new, y_new):
    """The end spin from the angular momentum balance, ``L_new`` (3,) in the frame's end axes:
    ``(u_new, y_new, w_new)`` with the relative motion's spin taken out of it. The body's spin
    slows as it stretches, and wobble (spin off a principal axis) keeps L exactly. The linear
    force of a frame carries a small torque (second order in the strain); the balance takes it
    out as a rigid turn over the step (trapezoidal rule), so the positions keep second order too."""
    inertia, moment = mass_moments(model, y_new, u_new)
    spin_change = np.linalg.solve(inertia, L_new - moment) - w
    u_new = u_new + y_new @ _skew(spin_change).T
    y_new = y_new + 0.5 * h * y_new @ _skew(spin_change).T
    inertia, moment = mass_moments(model, y_new, u_new)
    return u_new, y_new, np.linalg.solve(inertia, L_new - moment)


class _LazyMatrix:
    """Stands for the rest system matrix until someone needs it (reactions of free bodies: never)."""

    def __init__(self, model, dt):
        self.model, self.dt = model, dt

    def __matmul__(self, vector):
        return system_matrix(self.model, self.dt) @ vector


def _corotated_solver(model, dt, A, state):
    """Solver for this step's warped system on the free DOFs; returns ``(solve, iterations)``
    where ``iterations`` is a one-element list counting CG iterations (stays 0 for LU)."""
    A_ff = _free_block(model, A)
    iterations = [0]
    if model.corotated_solver == "lu":
        return Factorisation(A_ff, model.linear_solver).solve, iterations
    # precondition with the rest system rotated into the body's best-fit frame: exact for a rigid
    # rotation of the whole body, close while the elements rotate together (R = I when anchored)
    rest = system_factorisation(model, dt)
    R = state.R

    def precondition(r):
        if model.anchored:
            return rest.solve(r)
        return (rest.solve((r.reshape(-1, 3) @ R).ravel()).reshape(-1, 3) @ R.T).ravel()

    guess = state.v.ravel()[model.free_dofs] if model.anchored else state.v.ravel()

    def solve(rhs):
        x, its = cg_solve(A_ff, rhs, guess, precondition)
        iterations[0] += its
        return x

    return solve, iterations


def apply_impulse(model, state, step, node_impulse):
    """Add node impulses ``(n, 3)`` N s applied during the step: ``v += A^-1 impulse``.

    The response is that of the same implicit system (one back-substitution with the step's
    factorisation); anchored nodes do not respond. Returns a new :class:`StepData`.
    """
    j = np.asarray(node_impulse, dtype=float)
    j_b = (j @ step.R).ravel()
    dv = np.zeros_like(j_b)
    if model.anchored:
        dv[model.free_dofs] = step.solve(j_b[model.free_dofs])
    else:
        dv = step.solve(j_b)
    return replace(step, v=step.v + dv.reshape(-1, 3) @ step.R.T, impulse=step.impulse + j)


def finish(model, state, step, dt):
    """Advance positions with the step's velocities, update the best-fit frame and anchor reactions,
    under Newmark keep the body's energy within its allowance (``_cap_energy``), and (plastic
    bodies only) return-map the new strain onto the yield surface
    (``fem.plastic_flow.plastic_update``). Returns the new :class:`fem.model.FemState`.
    """
    x = step.x_base + step.x_rate * step.v
    reaction = np.zeros_like(x)
    if model.anchored:
        # A v+ - rhs - impulse on the prescribed DOFs is dt times the force the anchors applied
        fixed = model.fixed_dofs
        residual = (_fixed_rows(model, step.matrix, (step.v @ step.R).ravel())
                    - step.rhs[fixed] - (step.impulse @ step.R).ravel()[fixed])
        r = np.zeros(3 * model.node_count)
        r[fixed] = residual / dt
        reaction = r.reshape(-1, 3) @ step.R.T
    R, c = body_frame(model, x)
    new = state.replace(x=x, v=step.v.copy(), R=R, c=c, node_reaction=reaction, time=state.time + dt)
    if step.allowance is not None:
        new = _cap_energy(model, state, step, new, dt)
    if model.plastic:
        new = plastic_update(model, new)
    return new


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


def linear_momentum(model, state):
    """Total linear momentum ``(3,)`` (kg m/s)."""
    return (model.M @ state.v.ravel()).reshape(-1, 3).sum(axis=0)


def angular_momentum(model, state):
    """Total angular momentum about the origin ``(3,)`` (kg m^2/s)."""
    p = (model.M @ state.v.ravel()).reshape(-1, 3)
    return np.cross(state.x, p).sum(axis=0)


def center_of_mass(model, state):
    """Centre of mass ``(3,)`` (m) of the body's mass matrix (:func:`mass_weights`)."""
    weights = mass_weights(model)
    return weights @ state.x / weights.sum()


def best_fit_rotation(model, state):
    """Best-fit rotation ``(3, 3)`` of the current shape to the rest shape (shape matching)."""
    return best_fit_frame(model.rest_offsets, state.x, model.node_mass)[0]


def volume(model, x):
    """Volume (m^3) enclosed by the deformed vertex simplices."""
    xs = x[model.tets[:, :4]]
    return float(np.linalg.det(xs[:, 1:] - xs[:, :1]).sum() / 6.0)
