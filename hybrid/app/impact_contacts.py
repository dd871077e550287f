"""The contacts an impact is judged by (hybrid.app.resolution): a deformable body's surface nodes
against rigid bodies and planes, and rigid bodies' contact points (corners, mesh vertices, sphere
centres) against its faces, where a small body or a corner strikes between its nodes and no node
touches (a 4 mm steel ball on a plate of 4 cm elements stopped dead on one face, unwarned)."""
from dataclasses import dataclass

import numba as nb
import numpy as np

from rigid import quaternion as quat
from rigid.contacts import detect_points
from rigid.model import angular_velocity, reported_velocity

from ..coupling.fem_contact import SurfaceContacts, _node_normals, detect_rigid_points


@dataclass(frozen=True)
class Near:
    """Contacts of one deformable body at a step's end, node contacts first. partner (c,): the
    rigid body (-1: a plane); node (c,): the surface node (index into its ``surface_nodes``) that
    touches, -1 where a partner's point meets a face; corners (c, 3) and weights (c, 3): the
    surface nodes the contact moves and their weights; point (c, 3) m, normal (c, 3) from the
    partner towards the body, gap (c,) m."""
    partner: np.ndarray
    node: np.ndarray
    corners: np.ndarray
    weights: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    gap: np.ndarray


@dataclass(frozen=True)
class RigidMotion:
    """What the impact checks of one step use of the rigid bodies, worked out once for all the
    deformable bodies: ``velocity`` (b, 3) m/s (reported, :func:`rigid.model.reported_velocity`)
    and ``spin`` (b, 3) rad/s at the step's start, ``turn`` (b, 3, 3) their rotations at its end."""
    velocity: np.ndarray
    spin: np.ndarray
    turn: np.ndarray

    @classmethod
    def of(cls, model, old, state):
        """The motion of the step from coupled state ``old`` to ``state``."""
        rm = model.rigid
        if not rm.body_count:
            return cls(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3, 3)))
        return cls(reported_velocity(rm, old.rigid, model.gravity), angular_velocity(rm, old.rigid),
                   quat.to_matrix(state.rigid.orientation))


def near(model, state, j, margin, fast=None, motion=None, reach=None):
    """:class:`Near` of FEM body ``j`` with rigid bodies and planes within ``margin`` m. The
    partners' points on its faces are looked for only on rigid bodies none of its nodes touch
    (found by its nodes, the contact is judged by them) and, with ``fast`` = ``(bounds, speed)``,
    only on those whose bound (b,) m/s on the speed they could have met it at in the step
    (:func:`strike_speeds`) reaches ``speed`` m/s (a body resting on a face, the common case, is
    not looked for every step). ``motion`` (:class:`RigidMotion`) and ``reach``
    (:func:`within_reach` of ``margin``), when the caller has them."""
    rm, rs, m = model.rigid, state.rigid, model.fem[j]
    k = len(m.surface_nodes)
    if motion is not None:
        R = motion.turn
    else:
        R = quat.to_matrix(rs.orientation) if rm.body_count else np.zeros((0, 3, 3))
    c = detect_points(rm, rs.position, R, state.fem[j].x[m.surface_nodes], np.zeros(k),
                      np.zeros(rm.body_count), margin, np.zeros(k), np.zeros(k))
    # rigid bodies within reach of the body's bounding box and not met by its nodes
    looked = within_reach(model, state, j, margin) if reach is None else reach.copy()
    looked[c.body_b[c.body_b >= 0]] = False
    if fast is not None and looked.any():
        looked &= fast[0] >= fast[1]
    f = SurfaceContacts.stacked([])
    if looked.any():
        origin = model.fragment_of if model.fragment_of is not None else range(len(model.names))
        body = model.scene.bodies[origin[int(model.fem_ids[j])]]
        f = detect_rigid_points(rm, rs.position, R, np.where(looked, 0.0, -np.inf), [m],
                                [state.fem[j]], [body], np.array([0, k]), np.zeros(k), margin)
    own = np.zeros((c.count, 3))
    own[:, 0] = 1.0
    return Near(partner=np.concatenate([c.body_b, f.a]),
                node=np.concatenate([c.body_a, np.full(f.count, -1)]),
                corners=np.concatenate([np.repeat(c.body_a[:, None], 3, axis=1), f.corners]),
                weights=np.concatenate([own, f.weights]), point=np.concatenate([c.point, f.point]),
                normal=np.concatenate([c.normal, -f.normal]), gap=np.concatenate([c.gap, f.gap]))


def within_reach(model, state, j, margin):
    """Which rigid bodies (b,) are within ``margin`` m of FEM body ``j``'s bounding box."""
    rs = state.rigid
    low, high = _bounds(state.fem[j].x)
    outside = np.maximum(0.0, np.maximum(low - rs.position, rs.position - high))
    return np.linalg.norm(outside, axis=1) <= model.rigid.body_radius + margin


@nb.njit(cache=True)
def _bounds(x):
    """The corners ``(low, high)`` (3,) of the box bounding points ``x`` (n >= 1, 3), in one pass
    (``x.min(axis=0)`` takes a strided pass per column)."""
    low, high = x[0].copy(), x[0].copy()
    for i in range(1, len(x)):
        for a in range(3):
            low[a] = min(low[a], x[i, a])
            high[a] = max(high[a], x[i, a])
    return low, high


def strike_speeds(model, old, j, motion):
    """``(per rigid body (b,), against a plane)``: bounds (m/s) on the speed at which each could
    meet FEM body ``j`` in the step from the coupled state ``old`` (its speed and its spin times
    its radius, plus the body's fastest node; a plane: that node alone); ``motion``: the
    step's :class:`RigidMotion`."""
    rm, v = model.rigid, old.fem[j].v
    node = float(np.sqrt(np.einsum("ni,ni->n", v, v).max())) if len(v) else 0.0
    if not rm.body_count:
        return np.zeros(0), node
    spin = np.sqrt(np.einsum("bi,bi->b", motion.spin, motion.spin))
    return np.sqrt(np.einsum("bi,bi->b", motion.velocity, motion.velocity)) + spin * rm.body_radius \
        + node, node


def approach(model, old, state, j, c, motion):
    """Speed of approach (c,) m/s of contacts ``c`` (:class:`Near`) at the step's start: the
    body's velocity at the contact against the partner's there, along the normal (``motion``:
    the step's :class:`RigidMotion`)."""
    rs = state.rigid
    count = len(c.gap)
    v_partner = np.zeros((count, 3))
    if model.rigid.body_count and count:
        rigid = c.partner >= 0
        b = c.partner[rigid]
        v_partner[rigid] = motion.velocity[b] + np.cross(motion.spin[b], c.point[rigid] - rs.position[b])
    v_surface = old.fem[j].v[model.fem[j].surface_nodes]
    v_body = np.einsum("ck,cki->ci", c.weights, v_surface[c.corners])
    return -np.einsum("ci,ci->c", v_body - v_partner, c.normal)


def same_body(model, j, partner):
    """Whether rigid body ``partner`` broke from the same scene body as FEM body ``j`` (its own
    debris: the fracture, not an impact the scene set up)."""
    if partner < 0 or model.fragment_of is None:
        return False
    return model.fragment_of[int(model.rigid_ids[partner])] == model.fragment_of[int(model.fem_ids[j])]


def just_parked(model, state, partner):
    """Whether rigid body ``partner`` is an auto body that turned rigid at the end of the last
    step: a contact with it then is one the two had while both were deformable (not judged),
    not one that began."""
    if partner < 0:
        return False
    since = state.rigid_since.get(int(model.rigid_ids[partner]))
    return since is not None and state.steps - since <= 1


def partner_of(model, partner):
    """``(scene body or None, mass kg)`` of a contact partner: rigid body ``partner`` (its scene
    body; None for a fracture fragment, whose shape is not the scene's) or a plane (-1)."""
    if partner < 0:
        return None, np.inf
    k = int(model.rigid_ids[partner])
    origin = model.fragment_of[k] if model.fragment_of is not None else k
    return (model.scene.bodies[origin] if origin == k else None), float(model.rigid.body_mass[partner])


def across(model, state, j, c, k, lead):
    """The direction (3,) across FEM body ``j`` that the contacts of :class:`Near` ``c`` strike it
    along: the mean own outward normal of the nodes that meet at once (``lead`` (c,) bool), their
    face's (the wave the blow launches runs into the body square to its surface); with none of
    those, contact ``k``'s normal. A rigid ridge meeting a bar's face took its slanted sides'
    normals, along which the bar measured 149 mm where it is 10 mm thick."""
    nodes = np.unique(c.node[lead])
    if len(nodes):
        own = _node_normals(model.fem[j], state.fem[j], nodes).sum(axis=0)
        size = float(np.linalg.norm(own))
        if size > 1e-9 * len(nodes):
            return -own / size
    return c.normal[k]
