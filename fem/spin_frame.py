"""The step of a free deformable body, taken in the frame that spins with it.

Either integration rule on world coordinates moves a spinning body's nodes along chords, which
stretches it and feeds energy into the spin (the trapezoidal rule then diverges; backward Euler
gained 80% in 3 s on a rubber block at w h = 0.3). :func:`predict_spin_frame` steps the
deformation in the frame that moves with the centre of mass and turns over the step as a rigid
body of the same inertia and angular momentum would; ``fem.dynamics.predict`` uses it for every
body without prescribed nodes.
"""
from typing import NamedTuple

import numpy as np

from fem.momentum import (inertia_and_moment, mass_moments, mass_times, mass_weights, skew,
                          weighted_mean)
from fem.system import (LazyMatrix, StepData, gravity_force, implicitness, internal_forces_and_solver,
                        right_hand_side, system_coefficients)


# a frame turning less than this in a step (rad) is at rest: what its turn's square gives is left
# out (a 9,600-tet slab resting on the ground turns by 1e-14 to 1e-13 a step)
STILL_TURN = 1e-10


def _rotation(phi):
    """Rotation matrix ``(3, 3)`` of a rotation vector ``(3,)`` (rad), by Rodrigues' formula."""
    angle = float(np.sqrt(phi @ phi))
    if angle < 1e-300:
        return np.eye(3)
    K = skew(phi / angle)
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)


def _free_turn(inertia, L, h):
    """Rotation matrix ``(3, 3)`` by which a rigid body of ``inertia`` (3, 3) kg m^2 (world axes)
    with angular momentum ``L`` (3,) turns in ``h`` seconds free of torque, so that a body tumbling
    about an axis other than a principal one wobbles as a rigid body does.

    With principal moments ``I1 <= I2 <= I3`` the energy splits as ``|L|^2 / (2 I2) + a Pi1^2 / 2
    - b Pi3^2 / 2`` (``Pi`` the components of L along the axes, ``a = 1/I1 - 1/I2``, ``b = 1/I2 -
    1/I3``): the first part's flow is a turn about L by ``h |L| / I2``, which commutes with the
    others, and those are turns about the first and third axes, taken by Strang splitting. Each turn
    keeps L and its own energy. A spin about a principal axis is turned exactly, and two equal
    moments (a square bar, a disk), whose axes the eigensolver picks at random in their plane, only
    drop a term: the tilt a splitting over those axes adds does not build up from step to step."""
    moments, axes = np.linalg.eigh(inertia)
    a, b = 1.0 / moments[0] - 1.0 / moments[1], 1.0 / moments[1] - 1.0 / moments[2]
    turn = np.eye(3)
    for axis, rate in ((0, 0.5 * h * a), (2, -h * b), (0, 0.5 * h * a)):
        e = turn @ axes[:, axis]
        turn = _rotation(rate * (e @ L) * e) @ turn
    return _rotation(h * L / moments[1]) @ turn


def predict_spin_frame(model, state, dt, gravity, allowance):
    """Step of a free body in the frame that spins with it.

    Either rule on world coordinates moves nodes along chords: a spinning body is stretched by
    about ``(w h)^2 / 2`` per step, and the stretch feeds energy back into the spin (without
    numerical damping, the trapezoidal rule diverges). So the step is taken in the frame that
    translates with the centre of mass and turns as a rigid body of the body's inertia and angular
    momentum does over the step (:func:`_free_turn`, its spin ``w = I^-1 L`` at the start and
    ``w_end`` at the end): there the rigid motion is at rest, the integrator acts on the deformation
    only, and the frame's motion is that of the rigid body, wobble and all (a frame turning at the
    starting spin throughout left a tumbling bar's rigid turn to the integrator, which gained
    energy from 0.2 rad per step). The frame adds its inertial forces at the mid-step spin
    ``w_mid``: centrifugal ``-m w_mid x (w_mid x y)`` (explicit, at the mid-step positions: it is
    what stretches a spinning body), the frame's Euler force, which takes out the centrifugal
    force's torque (the torque that turns a rigid body is the frame's turn already), and Coriolis
    ``-2 m w_mid x u`` (as rotations of the relative velocities by ``-w_mid h`` before and after
    the solve, which do no work). The centre of mass takes the net force exactly; mass damping
    slows translation and spin as it slows the deformation. With no spin this is the world-frame
    step, the translation split off. Newmark stays second order (tests/test_fem_free_body.py).
    ``allowance``: the step's :attr:`StepData.allowance`.
    """
    h, theta = dt, implicitness(model)
    a_M = system_coefficients(model, dt)[0]
    force, K, R, A, solve, iterations = internal_forces_and_solver(model, dt, state)
    f = _spin_frame(model, state)
    # (a body at rest turns by round-off: its turn is taken about its spin, its frame's inertial
    # forces, the loads' turn within the step and its wobble, of the order of that squared, left out)
    still = h * np.sqrt(f.w @ f.w) <= STILL_TURN
    # the frame's turn (a rigid body's) and its end spin (frame axes)
    turn = _rotation(h * f.w) if still else _free_turn(f.inertia, f.L, h)
    w_end = f.w if still else np.linalg.solve(f.inertia, f.L @ turn)
    w_mid = 0.5 * (f.w + w_end)
    coriolis = _rotation(-h * w_mid)                        # Coriolis over half the step
    u = (state.v - f.V - f.y @ skew(f.w).T) @ coriolis.T   # velocities relative to the spinning frame
    external = gravity_force(model, gravity) + model.node_load
    net = external.sum(axis=0)
    # the loads' torque about the centre at the step's start and, turned with the frame, its end
    # (a world-fixed load on a spinning body turns its lever arms within the step; taken at the
    # start alone, a bar spun at 150 rad/s with a load on one end gained energy at first order)
    ones = np.ones(len(f.m))
    torque = inertia_and_moment(ones, f.y, external)[1]
    if not still:
        torque = 0.5 * (torque + inertia_and_moment(ones, f.y @ turn.T, external)[1])
    load = external - np.outer(f.m / f.total, net)          # the net force moves the centre
    applied = force + (load if still else (1.0 - theta) * load + theta * load @ turn)
    rhs, u_new, y_new = _relative_step(model, dt, f, u, applied, K, R, solve, None if still else w_mid)
    u_new = u_new @ coriolis.T                              # and over the other half
    slow = (1.0 - (1.0 - theta) * h * model.damping_mass) / a_M     # mass damping of the rigid motion
    V_new = slow * f.V + h * net / (f.total * a_M)
    u_new, y_new, w_new = _end_spin(model, h, (slow * f.L + h * torque) @ turn, w_end, u_new, y_new)
    x_new = f.c + h * ((1.0 - theta) * f.V + theta * V_new) + y_new @ turn.T
    v_new = V_new + (u_new + y_new @ skew(w_new).T) @ turn.T
    return StepData(v=v_new, x_base=x_new - theta * h * v_new, x_rate=theta * h, rhs=rhs,
                    impulse=np.zeros_like(state.v), R=R, matrix=LazyMatrix(model, dt) if A is None else A,
                    solve=solve, iterations=iterations, load=external, allowance=allowance, v_free=v_new)


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


def _relative_step(model, dt, frame, u, applied, K, R, solve, spin):
    """The deformation's step in the ``frame`` (a :class:`_SpinFrame`) from relative velocities
    ``u`` (n, 3) m/s under the ``applied`` forces (internal and external, n, 3) N, with the
    frame's inertial forces at its mid-step ``spin`` (3,) rad/s (None: a frame at rest):
    ``(rhs, u_new, y_new)``, the system's right-hand side and the end-of-step relative velocities
    and offsets (m/s, m)."""
    h, theta = dt, implicitness(model)
    y = frame.y
    if spin is not None:
        W = skew(spin)
        y_mid = y + 0.5 * h * u                             # centrifugal force at mid-step
        inertial = -(y_mid @ (W @ W).T)
        # and the frame's Euler force, -dw/dt x y: the frame turns as a rigid body does, whose
        # spin changes by Euler's equations, I dw/dt = the centrifugal torque (so a body spinning
        # about a principal axis feels none): taken at mid-step, the force field less its turn
        inertia_mid, torque = mass_moments(model, y_mid, inertial)
        inertial -= y_mid @ skew(np.linalg.solve(inertia_mid, torque)).T
        applied = applied + mass_times(model, inertial)
    rhs = right_hand_side(model, dt, u, applied, K, R)
    u_new = solve(rhs).reshape(-1, 3) @ R.T
    y_new = y + h * ((1.0 - theta) * u + theta * u_new)
    if theta != 0.5:
        # the rigid turn relative to the frame (the spin's change, e.g. a wobble) by the trapezoidal
        # rule: it meets no stiffness to damp, and with backward Euler's first-order turn a tumbling
        # steel box drifted 4.3 degrees from Euler's equations in 1 s (0.033 with this)
        turn_rate = np.linalg.solve(frame.inertia, mass_moments(model, y, u - u_new)[1])
        y_new += (theta - 0.5) * h * y @ skew(turn_rate).T
    return rhs, u_new, y_new


def _end_spin(model, h, L_new, w, u_new, y_new):
    """The end spin from the angular momentum balance, ``L_new`` (3,) in the frame's end axes, where
    the frame itself ends spinning at ``w`` (3,): ``(u_new, y_new, w_new)`` with the relative
    motion's spin taken out of it. The body's spin
    slows as it stretches, and wobble (spin off a principal axis) keeps L exactly. The linear
    force of a frame carries a small torque (second order in the strain); the balance takes it
    out as a rigid turn over the step (trapezoidal rule), so the positions keep second order too."""
    inertia, moment = mass_moments(model, y_new, u_new)
    spin_change = np.linalg.solve(inertia, L_new - moment) - w
    u_new = u_new + y_new @ skew(spin_change).T
    y_new = y_new + 0.5 * h * y_new @ skew(spin_change).T
    inertia, moment = mass_moments(model, y_new, u_new)
    return u_new, y_new, np.linalg.solve(inertia, L_new - moment)


def impulse_turn(model, state, step):
    """End positions and velocities ``(x, v)`` ``(n, 3)`` of a free body's ``step`` whose contact
    impulses turned it, with the turn taken exactly.

    ``x_base + x_rate v`` moves the nodes along chords by the impulses' velocity change, whose
    rigid part turns the body: a steel bar landing tilted at dt = 10 ms turned 6.5 degrees in
    its landing step and was stretched by about ``(w h)^2 / 2`` (thousands of joules). And the
    response's rigid part turns the body about its shape at the start of the step, not its end:
    at the end it is not rigid. So the velocity change is split into a rigid part, about the
    rest shape in the start's best-fit frame (where the system's rigid modes are), and the
    deformation ``d`` that remains; the body's predicted end (before impulses) takes ``x_rate d``
    and its centre's move and turns exactly by ``x_rate`` times the spin the impulses' angular
    momentum gives it, its end spin what the angular momentum (predicted plus the impulses')
    gives the turned shape. Linear and angular momentum are those of the chord step.
    """
    x_free = step.x_base + step.x_rate * step.v_free
    dv = step.v - step.v_free
    move, _, d = _rigid_split(model, state, dv)
    y = x_free - weighted_mean(model, x_free)
    inertia, L_free = mass_moments(model, y, step.v_free)
    L_turn = mass_moments(model, y, dv)[1]
    turn = _rotation(step.x_rate * np.linalg.solve(inertia, L_turn))
    return _turned(model, x_free + step.x_rate * (move + d), step.v_free + move + d, turn, L_free + L_turn)


def shift_turned(model, state, x, v, dx):
    """Positions and velocities ``(x, v)`` of a free body moved by ``dx`` ``(n, 3)`` m (positions
    only: penetration recovery), its rigid turn taken exactly: moved along ``dx``, a body turned
    by it is stretched as by a chord, and its velocities are no longer a rigid spin about it
    (a steel bar spinning at 20 rad/s gained 190 J from a 0.5 mm push). The turn is the rigid
    part of ``dx`` about the rest shape in the start's best-fit frame; the velocities' deformation
    part turns with the body and its spin keeps the angular momentum."""
    move, rotation, d = _rigid_split(model, state, dx)
    y = x - weighted_mean(model, x)
    return _turned(model, x + move + d, v, _rotation(rotation), mass_moments(model, y, v)[1])


def _rigid_split(model, state, field):
    """A node field ``(n, 3)`` (velocities or moves) as ``(mean (3,), rotation (3,), rest (n, 3))``:
    its mass-weighted mean, the small rotation of its rigid part about the centre (``I^-1`` of
    its angular moment), and what remains, each about the rest shape in the start's best-fit frame
    (where the system's rigid modes lie): the rest carries no momentum."""
    rest = model.rest_offsets - weighted_mean(model, model.rest_offsets)
    rest = rest @ np.asarray(state.R, float).T
    inertia, moment = mass_moments(model, rest, field)
    mean, rotation = weighted_mean(model, field), np.linalg.solve(inertia, moment)
    return mean, rotation, field - mean - rest @ skew(rotation).T


def _turned(model, x, v, turn, L):
    """Positions and velocities ``(x, v)`` turned about their centre of mass by the rotation matrix
    ``turn`` (3, 3), the velocities' deformation part turned along and their spin the one that
    gives angular momentum ``L`` (3,) about the centre with the turned shape."""
    c, V = weighted_mean(model, x), weighted_mean(model, v)
    y = x - c
    inertia, moment = mass_moments(model, y, v)
    u = v - V - y @ skew(np.linalg.solve(inertia, moment)).T
    y_end, u_end = y @ turn.T, u @ turn.T
    inertia_end, moment_end = mass_moments(model, y_end, u_end)
    return c + y_end, V + u_end + y_end @ skew(np.linalg.solve(inertia_end, L - moment_end)).T
