"""Rigid-body model (built once from a scene) and state (what changes each step).

Each body's *body frame* is its principal frame at the centre of mass, so the body-frame inertia
is diagonal. The *shape frame* is the frame the user's mesh or primitive is given in; a point
``p_body`` in the body frame is at ``shape_rotation @ p_body + shape_offset`` in the shape frame.
"""
from dataclasses import dataclass, field

import numpy as np

from . import quaternion as quat

SHAPE_SPHERE, SHAPE_BOX, SHAPE_CAPSULE, SHAPE_CYLINDER, SHAPE_GRID = 1, 2, 3, 4, 5
SHAPE_CODES = {"sphere": SHAPE_SPHERE, "box": SHAPE_BOX, "capsule": SHAPE_CAPSULE,
               "cylinder": SHAPE_CYLINDER, "mesh": SHAPE_GRID}
# contact point kinds (RigidModel.point_kind)
POINT_PLAIN, POINT_RING, POINT_FEM_ONLY = 0, 1, 2


@dataclass
class RigidModel:
    """Constant description of ``body_count`` rigid bodies and ``plane_count`` static planes.

    body_mass (b,) kg, infinite for fixed bodies; body_inv_mass (b,) 1/kg, 0 for fixed bodies.
    body_inertia (b, 3) kg m^2: principal moments (body frame); body_inv_inertia (b, 3), 0 if fixed.
    body_fixed (b,) bool. body_friction, body_restitution (b,) dimensionless.
    body_radius (b,) m: bounding radius about the centre of mass, contact radii included.
    shape_kind (b,) int: SHAPE_* code of the signed distance used when others touch the body.
    shape_params (b, 4): sphere (r), box (hx, hy, hz), capsule (r, half segment), cylinder (r, hh).
    shape_rotation (b, 3, 3), shape_offset (b, 3) m: body frame -> shape frame.
    grid_index (b,) int: SDF grid of the body (-1 for analytic shapes); grid_* arrays hold all
        grids flat: grid_values (sum of nodes,), grid_start (g,), grid_shape (g, 3) int,
        grid_origin (g, 3) m, grid_cell (g,) m.
    point_body (p,) int, point_local (p, 3) m (body frame), point_radius (p,) m: contact points.
    point_start (b + 1,) int: body i's points are point_start[i] .. point_start[i + 1] - 1
        (derived from point_body when the model is made, never passed).
    point_kind (p,) int: POINT_PLAIN (every detector), POINT_RING (a circle of radius
        point_ring (p,) m about the unit axis point_axis (p, 3) (body frame) through point_local:
        rigid bodies and planes meet its nearest points, so a cylinder rolls as a circle, not a
        polygon) or POINT_FEM_ONLY (used only against FEM surfaces: a mesh vertex on such a
        circle, or an auto body's surface vertex off its convex hull).
    surface_vertices: list of (n_i, 3) body-frame vertices; surface_triangles: list of (m_i, 3).
    plane_point (k, 3), plane_normal (k, 3) unit, plane_friction (k,), plane_restitution (k,).
    names: list of body names.
    """
    names: list
    body_mass: np.ndarray
    body_inv_mass: np.ndarray
    body_inertia: np.ndarray
    body_inv_inertia: np.ndarray
    body_fixed: np.ndarray
    body_friction: np.ndarray
    body_restitution: np.ndarray
    body_radius: np.ndarray
    shape_kind: np.ndarray
    shape_params: np.ndarray
    shape_rotation: np.ndarray
    shape_offset: np.ndarray
    grid_index: np.ndarray
    grid_values: np.ndarray
    grid_start: np.ndarray
    grid_shape: np.ndarray
    grid_origin: np.ndarray
    grid_cell: np.ndarray
    point_body: np.ndarray
    point_local: np.ndarray
    point_radius: np.ndarray
    surface_vertices: list
    surface_triangles: list
    plane_point: np.ndarray
    plane_normal: np.ndarray
    plane_friction: np.ndarray
    plane_restitution: np.ndarray
    body_min_extent: np.ndarray = field(default=None)
    point_kind: np.ndarray = field(default=None)
    point_ring: np.ndarray = field(default=None)
    point_axis: np.ndarray = field(default=None)
    point_start: np.ndarray = field(init=False, repr=False, default=None)

    def __post_init__(self):
        p = len(self.point_radius)
        counts = np.bincount(self.point_body, minlength=len(self.body_mass))
        self.point_start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        if self.point_kind is None:
            self.point_kind = np.full(p, POINT_PLAIN, dtype=np.int64)
        if self.point_ring is None:
            self.point_ring = np.zeros(p)
        if self.point_axis is None:
            self.point_axis = np.zeros((p, 3))

    @property
    def body_count(self):
        """Number of rigid bodies."""
        return len(self.body_mass)


@dataclass
class RigidState:
    """Everything about the rigid bodies that changes in time.

    position (b, 3) m: centre of mass, world frame.
    orientation (b, 4): unit quaternion (w, x, y, z) of the body (principal) frame.
    velocity (b, 3) m/s: the velocity the last step drifted with (leapfrog: v at t - dt/2).
    angular_momentum (b, 3) kg m^2/s: world frame, about the centre of mass.
    contact_dv (b, 3) m/s: velocity change the last step's contact forces gave (for reporting
        the velocity at time t, see :func:`reported_velocity`).
    time float s; last_dt float s: size of the last step.
    """
    position: np.ndarray
    orientation: np.ndarray
    velocity: np.ndarray
    angular_momentum: np.ndarray
    contact_dv: np.ndarray
    time: float = 0.0
    last_dt: float = 0.0

    def copy(self):
        """A deep copy (every array copied)."""
        return RigidState(self.position.copy(), self.orientation.copy(), self.velocity.copy(),
                          self.angular_momentum.copy(), self.contact_dv.copy(), self.time,
                          self.last_dt)


def world_inverse_inertia(model, orientation):
    """I^-1 in the world frame, ``R diag(1/I0) R^T`` for every body, (b, 3, 3)."""
    R = quat.to_matrix(orientation)
    # the sums over j written out: the numbers einsum("bij,bj,bkj->bik") gives, at 4x its speed
    # for a thousand bodies
    A = R * model.body_inv_inertia[:, None, :]
    return A[:, :, None, 0] * R[:, None, :, 0] + A[:, :, None, 1] * R[:, None, :, 1] \
        + A[:, :, None, 2] * R[:, None, :, 2]


def angular_velocity(model, state):
    """World angular velocity w = I^-1 L, (b, 3) rad/s."""
    return np.einsum("bij,bj->bi", world_inverse_inertia(model, state.orientation),
                     state.angular_momentum)


# a step's contact velocity change of at most this many steps of gravity acted as a force over
# the step (resting, sliding, rolling); a larger one is a collision's
FORCE_LIKE = 2.0


def report_offset(model, state, gravity):
    """What :func:`reported_velocity` adds to the stored mid-step velocities, ``(b, 3)`` m/s.

    Half the last step of gravity and half the last step's contact velocity change where that
    was a force's (at most FORCE_LIKE steps of gravity: resting, sliding, rolling; it acted over
    the step, of which the stored velocity holds half): a body at rest reports zero, a falling
    one the exact ballistic velocity, a sliding one its velocity with the whole step's friction
    (half of it was left out: 0.5 dt mu g too fast on the ground, a velocity into an incline).
    A larger change is a collision's: it counts whole at the frame's time, as it does for FEM
    bodies (whose end-of-step velocities hold the whole impulse), but for the support it gave
    against gravity (along the upward direction, at most a step of gravity's worth). So
    momentum summed over the bodies of a frame is the momentum the solver conserves.
    """
    out = np.zeros_like(state.velocity)
    g = np.asarray(gravity, float)
    step = float(np.linalg.norm(g)) * state.last_dt
    if state.last_dt == 0.0 or step == 0.0:
        return out
    up = -g / np.linalg.norm(g)
    dv = state.contact_dv
    support = np.clip(dv @ up, 0.0, step)[:, None] * up
    force = (np.linalg.norm(dv, axis=1) <= FORCE_LIKE * step)[:, None]
    free = ~model.body_fixed
    out[free] = 0.5 * (g * state.last_dt + np.where(force, dv, support)[free])
    return out


def reported_velocity(model, state, gravity):
    """Velocity at the state's time (leapfrog stores the mid-step velocity): the stored velocity
    plus :func:`report_offset`."""
    return state.velocity + report_offset(model, state, gravity)


def kinetic_energy(model, state, velocity=None, omega=None):
    """Per-body kinetic energy (b,) J (0 for fixed bodies); ``omega``: the bodies'
    :func:`angular_velocity`, if already at hand."""
    v = state.velocity if velocity is None else velocity
    w = angular_velocity(model, state) if omega is None else omega
    m = np.where(model.body_fixed, 0.0, model.body_mass)
    return 0.5 * m * np.einsum("bi,bi->b", v, v) + 0.5 * np.einsum("bi,bi->b", w, state.angular_momentum)


def posed_points(vertices, owner, position, rotation):
    """World positions ``(n, 3)`` of body-frame points ``vertices`` (n, 3) of bodies ``owner``
    (n,) at positions (b, 3) and rotations ``rotation`` (b, 3, 3): ``x + R v`` for each."""
    turn = rotation[owner]
    return position[owner] + (turn[:, :, 0] * vertices[:, :1] + turn[:, :, 1] * vertices[:, 1:2]
                              + turn[:, :, 2] * vertices[:, 2:])


def posed_by_orientation(vertices, owner, position, orientation):
    """:func:`posed_points` with the bodies' rotations given as unit quaternions (b, 4)."""
    return posed_points(vertices, owner, position, quat.to_matrix(orientation))


def body_pose_in_shape_frame(model, state):
    """World pose of each body's own (shape) frame: rotation (b,3,3) and origin (b,3)."""
    R = quat.to_matrix(state.orientation)
    # p_world = x + R p_body and p_shape = S p_body + t  =>  p_world = x + R S^T (p_shape - t)
    R_shape = np.einsum("bij,bkj->bik", R, model.shape_rotation)
    origin = state.position - np.einsum("bij,bj->bi", R_shape, model.shape_offset)
    return R_shape, origin
