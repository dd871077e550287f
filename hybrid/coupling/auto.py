"""Auto bodies (``model = "auto"``): when each is stepped as a rigid body and when as an FEM body.

An auto body is an FEM body while loads deform it and a rigid body while its deformation does not
change (after Mercier-Aubin, Winter, Levin and Kry 2022, adaptive rigidification):

- it becomes rigid (:func:`rigid_due`, checked between steps) once its measured strain has stayed
  below ``rigidify_strain`` for ``window`` steps, no element of it yields, its largest principal
  stress is below ``fracture_margin`` of its ``fracture_stress``, no crack face of it waits to
  open, its anchors are still and, unless anchored, it carries no load;
- it becomes an FEM body again (:func:`fem_due`, checked after a step, before the step is kept)
  when the change of the contact impulses it took in that step, applied to its kept FEM system,
  would strain it by more than ``elastify_strain``: the step is then taken again with it
  deformable (hybrid.coupling.step.advance).

Strain is measured as an element's strain rate (fem.stress.element_strain_rate) times the body's
response time, the longer of its slowest vibration's period over 2 pi (its elastic wave transit
time, largest extent over sqrt(E / rho), times its slenderness) and the step: the strain
amplitude of a vibration when the body answers within a step, the strain one step adds when it
answers more slowly. Both are dimensionless, so one default serves rubber
and steel, centimetres and metres. The switches themselves are :mod:`hybrid.coupling.switch`;
the contact impulses compared, :mod:`hybrid.coupling.touches`.
"""
from dataclasses import dataclass

import numpy as np

from fem import dynamics as fem_dyn
from fem.momentum import rigid_part
from fem.stress import element_strain_rate, element_stress, principal_stress_max
from fem.system import system_factorisation
from rigid import quaternion as quat

from .nodes import element_size
from .touches import impulse_change, switch_groups


@dataclass(frozen=True)
class Switch:
    """An auto body changed how it is stepped. time: s. body: its name. event: ``"rigidify"``
    (stepped as a rigid body from now) or ``"elastify"`` (as an FEM body again)."""
    time: float
    body: str
    event: str

    @property
    def message(self):
        """One line for the run log."""
        kind = "a rigid body" if self.event == "rigidify" else "an FEM body again"
        return f"t = {self.time:.6g} s: '{self.body}' is stepped as {kind} ({self.event})"

    def as_dict(self):
        """JSON-ready summary row: time, body, event kind."""
        return {"time": self.time, "body": self.body, "event": self.event}


def auto_bodies(model):
    """Scene indices ``(a,)`` of the auto bodies, however they are stepped now."""
    fem = [k for k in model.fem_ids if settings(model, k) is not None]
    return np.array(sorted(set(fem) | set(model.parked)), dtype=np.int64)


def settings(model, index):
    """The switching thresholds (scene ``auto`` table) of body ``index``, None unless it is an
    auto body."""
    body = model.scene.bodies[index] if model.scene is not None else None
    return body.auto if body is not None and body.model == "auto" else None


def elastify_threshold(body):
    """The strain at which scene ``body`` (FEM or auto) would turn deformable: its ``auto``
    table's ``elastify_strain``, at most half its yield and fracture strains (it turns deformable
    before anything yields or cracks)."""
    elastify = body.auto.elastify_strain
    for stress in (body.yield_stress, body.fracture_stress):
        if stress is not None:
            elastify = min(elastify, 0.5 * stress / body.young)
    return elastify


def thresholds(model, index):
    """``(rigidify, elastify)`` strains in use for auto body ``index``: :func:`elastify_threshold`
    and the scene's ``rigidify_strain``, at most a tenth of it."""
    elastify = elastify_threshold(model.scene.bodies[index])
    return min(settings(model, index).rigidify_strain, 0.1 * elastify), elastify


def extent(fem):
    """The body's largest extent (m), of its rest shape."""
    return _shape_scales(fem)[0]


def slenderness(fem):
    """How much longer than thick the body's rest shape is (>= 1): the square root of the ratio of
    the largest to the smallest variance of its nodes along their principal axes (a 0.5 m beam
    5 cm thick: 10; a cube or a sphere: 1)."""
    return _shape_scales(fem)[1]


def _shape_scales(fem):
    """``(extent, slenderness)`` of the rest shape, kept in ``fem.cache.extent``."""
    if fem.cache.extent is None:
        points = fem.rest_points
        variance = np.linalg.eigvalsh(np.cov(points.T))
        ratio = variance[-1] / variance[0] if variance[0] > 0.0 else np.inf
        fem.cache.extent = (float(np.ptp(points, axis=0).max()), float(np.sqrt(ratio)))
    return fem.cache.extent


def response_time(fem, h):
    """The body's response time (s): the period over 2 pi of its slowest elastic vibration, or the
    step ``h`` when that is longer. A compact body's is its elastic wave transit time (largest
    extent / wave speed); a slender one bends more slowly than that by its slenderness (a beam or
    plate of length L and thickness t bends at about c t / L^2 rad/s: a 0.5 m aluminium beam 5 cm
    thick, anchored at one end, rings at 164 Hz, 1 / omega = 0.97 ms against L / c = 0.1 ms)."""
    return max(extent(fem) / wave_speed(fem) * slenderness(fem), h)


def wave_speed(fem):
    """The body's elastic wave speed sqrt(E / rho) (m/s)."""
    return float(np.sqrt(fem.young / fem.density))


def element_time(fem, h):
    """The time (s) over which one step's velocity change in the body becomes strain: the step
    ``h``, or the wave's transit across an element (edge of a regular tet of the body's mean
    element volume) when that is longer. A change of velocity ``dv`` then strains the body by
    its wave strain ``dv / c`` (the wave it launches spreads over ``max(c h, element)``), which
    for a load kept on is the strain it settles to; and when the body answers within the step,
    by the strain the step adds."""
    return max(element_size(fem) / wave_speed(fem), h)


def strain_measure(fem, x, v, h, inverse_F=None):
    """Largest element strain rate of velocities ``v`` (one step's change) at shape ``x`` times
    :func:`element_time` (``inverse_F``: see fem.stress.element_strain_rate): how much the change
    deforms the body anywhere, the elastify test."""
    return float(element_strain_rate(fem, x, v, inverse_F).max()) * element_time(fem, h)


def body_strain_measure(fem, x, v, h):
    """Root mean square over the body's volume of its element strain rates of velocities ``v`` at
    shape ``x``, times the response time: how much the body as a whole is still deforming, the
    rigidify test (the contact solver's jitter at a few elements under a resting contact does not
    keep a settled body deformable, as the largest element's rate would)."""
    rate = element_strain_rate(fem, x, v)
    volume = fem.elements.tet_volume
    return float(np.sqrt(volume @ (rate * rate) / volume.sum())) * response_time(fem, h)


# --- rigidify ----------------------------------------------------------------------------------

def may_be_rigid(fem):
    """Whether the body can be stepped as a rigid body at all: anchors still (an anchored body
    is then fixed) and, unless anchored, no load (a rigid body carries no applied force) and no
    mass-proportional damping (which slows a free body's rigid motion too: a rigid body would
    keep its speed)."""
    if fem.has_anchors:
        return not np.any(fem.anchor_velocity)
    return not np.any(fem.load_force) and fem.damping_mass == 0.0


def _may_turn(model, state, j):
    """Whether FEM body ``j`` may turn rigid now, however it moves: it can be rigid at all
    (:func:`may_be_rigid`), nothing in it yields and no crack face of it waits to open."""
    m, s = model.fem[j], state.fem[j]
    if not may_be_rigid(m) or (s.tet_yielded is not None and s.tet_yielded.any()):
        return False
    return state.fracture_pending is None or not len(state.fracture_pending[j])


def _calm_count(model, state, j, window):
    """FEM body ``j``'s count of calm steps in a row after this step (``HybridState.calm``): one
    more than before if it is calm enough to count towards becoming rigid; 0 if it may not turn
    rigid now; and if it is deforming, minus the steps to wait before looking again (half its
    ``window``: it must then stay calm a whole window anyway, so looking less often delays its
    turn by at most that, and spares a body that never calms down the strain-rate checks)."""
    prior = state.calm.get(model.fem_ids[j], 0)
    if prior < 0:
        return prior + 1
    m, s = model.fem[j], state.fem[j]
    if not _may_turn(model, state, j):
        return 0
    rigidify = thresholds(model, model.fem_ids[j])[0]
    if _approaching(model, state, j, rigidify):
        return 0
    if _restless(m, s, rigidify, model.dt) or body_strain_measure(m, s.x, s.v, model.dt) >= rigidify \
            or _unbalanced(model, state, j):
        return -(window // 2)
    strength = model.scene.bodies[model.fem_ids[j]].fracture_stress
    if strength is not None:
        sigma = element_stress(m, s, s.tet_plastic_strain)
        if float(principal_stress_max(sigma).max()) >= settings(model, model.fem_ids[j]).fracture_margin * strength:
            return 0
    return prior + 1


# a body whose velocities depart from a rigid motion by more than this many times the rigidify
# strain over its response time, times its size, is not calm (a cheap test before the strain
# rates: a field of strain rate d across a body of size L departs from rigid by about d L, more
# for a thin flexing sheet, which then only turns rigid later)
RESTLESS = 10.0


def _restless(m, s, rigidify, h):
    """Whether FEM body (model ``m``, state ``s``) certainly moves too far from rigidly to be
    calm (see RESTLESS)."""
    u = s.v if m.has_anchors else s.v - rigid_part(m, s.x, s.v)
    return float(np.abs(u).max()) > RESTLESS * rigidify * extent(m) / response_time(m, h)


# an anchored body whose forces (weight, loads, anchor reactions, contacts) sum to more than this
# part of its weight and loads is still accelerating as a whole, not at rest on its anchors; a
# body turned rigid at the balance's limit holds about that part of its sag too little or too
# much (an aluminium cantilever's tip: 2.4% short at 5%, 1.2% at 2%)
BALANCE = 0.02


def _unbalanced(model, state, j):
    """Whether anchored FEM body ``j`` is not yet held by its anchors: the forces on it over the
    last step (weight, loads, the anchors' reactions, its contacts' impulses over the step) sum to
    more than BALANCE of its weight and loads. A beam let go straight sags into its bend with
    strain rates below the rigidify strain (its whole sag is a strain of 1e-4), and turned rigid
    then keeps the anchor reaction of that moment (a fifth to two fifths off its weight and
    loads); a free body's balance is not checked (its contacts share its weight in many ways)."""
    m, s = model.fem[j], state.fem[j]
    if not m.has_anchors:
        return False
    weight = float(m.node_mass.sum()) * np.asarray(model.gravity, float)
    held = weight + m.node_load.sum(axis=0)
    scale = float(np.linalg.norm(weight)) + float(np.linalg.norm(m.node_load, axis=1).sum())
    if scale == 0.0:
        return False
    net = held + s.node_reaction.sum(axis=0)
    if state.touches is not None:
        net = net + state.touches.of_body(model.fem_ids[j])[2].sum(axis=0) / model.dt
    return float(np.linalg.norm(net)) > BALANCE * scale


def _approaching(model, state, j, rigidify):
    """Whether FEM body ``j`` is moving towards a contact it took no impulse from, waiting within
    reach (it is about to touch something: turned rigid now, it would turn back on landing). A
    body counts as moving at a centre speed above ``rigidify`` strain over its response time; a
    body resting on the ground (planes, fixed rigid bodies), at that speed along the normal of a
    waiting contact with the ground: a box sliding on the ground keeps unloaded contacts at its
    rear corners with the ground that carries it, and is not landing on them. (On other bodies,
    which may sway under it, any motion counts.)"""
    if state.touches is None:
        return False
    t = state.touches
    rows = np.nonzero(t.body == model.fem_ids[j])[0]
    loaded = np.any(t.impulse[rows] != 0.0, axis=1)
    if not len(rows) or loaded.all():
        return False
    m, s = model.fem[j], state.fem[j]
    velocity = fem_dyn.mass_weights(m) @ s.v / float(m.node_mass.sum())
    fixed = np.zeros(len(model.names) + 1, bool)     # (fracture pieces after the scene's; -1: planes)
    fixed[:len(model.scene.bodies)] = [b.fixed for b in model.scene.bodies]
    fixed[-1] = True
    ground = fixed[t.partner[rows]]
    resting = ground & np.any(ground[loaded])        # on the ground (planes, fixed bodies)
    across = np.where(resting, np.abs(t.normal[rows] @ velocity), np.linalg.norm(velocity))
    return bool(np.any(across[~loaded] > rigidify * extent(m) / response_time(m, model.dt)))


def rigid_due(model, state):
    """``(calm, due)``: every FEM auto body's count of calm steps in a row (scene index ->
    steps) and the FEM bodies (indices into model.fem) to turn rigid now: those calm for their
    ``window`` (stretched by ``state.backoff``), and fracture pieces smaller than
    ``rigid_fragment_tets`` at once when they were never rigid (the size hint of ``fragment_model
    = "auto"``: a few elements flying off are not worth an FEM body; one a blow turned deformable
    waits for its window like any auto body: struck again and again, a piece switched every
    step)."""
    calm, due = {}, []
    for j, k in enumerate(model.fem_ids):
        auto = settings(model, k)
        if auto is None:
            continue
        calm[k] = _calm_count(model, state, j, auto.window)
        small = model.fragment_of is not None and model.fragment_of[k] != k \
            and model.fem[j].tet_count < model.scene.bodies[k].rigid_fragment_tets \
            and k not in state.rigid_since
        if calm[k] >= auto.window * state.backoff.get(k, 1) or (small and _may_turn(model, state, j)):
            due.append(j)
    return calm, due


# --- elastify ----------------------------------------------------------------------------------

# surface nodes (the lightest, which answer an impulse most) whose unit impulses along each axis
# measure how much strain a body turned rigid takes per N s (Parked.unit_strain); a step's change
# of impulses under a third of its elastify strain by that measure is not solved for
PROBE_NODES = 6
PROBE_MARGIN = 3.0


def _velocity_change(fem, rest, node_impulse, h):
    """Velocity change ``(n, 3)`` (world when parked) of node impulses ``(n, 3)`` N s (same
    frame) through the body's FEM system."""
    dv = fem_dyn.impulse_velocity(fem, system_factorisation(fem, h).solve,
                                  (node_impulse @ rest.R).ravel())
    return dv.reshape(-1, 3) @ rest.R.T


def unit_strain(fem, rest, inverse_F, h):
    """Largest strain measure per N s of a unit impulse along an axis at one of the body's
    PROBE_NODES lightest free surface nodes (its FEM model ``fem``, state ``rest``)."""
    free = fem.surface_nodes[fem.node_anchor[fem.surface_nodes] < 0]
    nodes = free[np.argsort(fem.node_mass[free], kind="stable")[:PROBE_NODES]]
    largest = 0.0
    for node in nodes:
        for axis in range(3):
            impulse = np.zeros((fem.node_count, 3))
            impulse[node, axis] = 1.0
            dv = _velocity_change(fem, rest, impulse, h)
            largest = max(largest, strain_measure(fem, rest.x, dv, h, inverse_F))
    return largest


def predicted_strain(parked, position, rotation, points, changes, group, h, partners=()):
    """The strain measure of the velocity change that the impulses ``changes`` (g, 3) N s (world),
    each shared among the surface nodes nearest its group of ``points`` (r, 3) m (``group``
    (r,)) in proportion to their masses, would give the parked body's FEM system, the body's
    rigid pose now being ``position`` (3,), ``rotation`` (3, 3). Shared so, a change of load
    moves the nodes it acts on alike, as a change of pressure over the patch would, not its
    lightest nodes at the patch's rim more. The change from a partner ``partners[g]`` the body
    rested on as an FEM body is shared over that contact's patch then as well
    (``parked.patches``): a rigid body meets it at a few points (a box at its corners), the FEM
    body's load spread over every node of the face."""
    fem, rest = parked.fem, parked.state
    local = (points - position) @ rotation               # body frame, as parked.local
    nodes = parked.surface_nodes[parked.tree.query(local)[1]]
    node_impulse = np.zeros((fem.node_count, 3))
    # world now -> world when parked (turn back by the rotation since), -> the FEM body's frame
    turn = rotation @ parked.rotation.T
    for g in range(len(changes)):
        touched = np.unique(nodes[group == g])
        if g < len(partners) and int(partners[g]) in parked.patches:
            touched = np.union1d(touched, parked.patches[int(partners[g])])
        share = fem.node_mass[touched] / fem.node_mass[touched].sum()
        node_impulse[touched] += share[:, None] * (changes[g] @ turn)
    return strain_measure(fem, rest.x, _velocity_change(fem, rest, node_impulse, h), h,
                          parked.inverse_F)


def fem_due(model, before, after):
    """Scene indices of the rigid auto bodies that the step from ``before`` to ``after`` would
    strain beyond their ``elastify_strain`` (they must take it again as FEM bodies). In the step
    right after a switch, a body in contact with the switched one (:func:`switch_groups`) counts
    a change of load only as far as both its own whole load and the load its group takes from
    outside changed (the smaller strain of the two): a blow changes both; the switch's re-sharing
    of a resting load among the group's supports changes neither the group's, and a cold start of
    the contact solver that leaves one body's supports unbalanced, not the others' own."""
    if not model.parked or after.touches is None:
        return []
    due = []
    switched = sorted({k for since in (before.rigid_since, before.fem_since)
                       for k, at in since.items() if at == before.steps})
    groups = switch_groups(before.touches, after.touches, switched)
    for k, parked in sorted(model.parked.items()):
        elastify = thresholds(model, k)[1]
        views = [None] if k not in groups else [frozenset({k}), groups[k]]
        if all(_strain(model, before, parked, k, impulse_change(before.touches, after.touches, k, view),
                       elastify) > elastify for view in views):
            due.append(k)
    return due


def _strain(model, before, parked, k, change, elastify):
    """The strain measure the load ``change`` (:func:`impulse_change`) gives parked body ``k``
    (0 for none, or one too small to be solved for)."""
    if change is None or not len(change[0]):
        return 0.0
    if PROBE_MARGIN * parked.unit_strain * np.linalg.norm(change[1], axis=1).sum() < elastify:
        return 0.0              # far too small a change to matter: not solved for
    i = int(np.flatnonzero(model.rigid_ids == k)[0])
    R = quat.to_matrix(before.rigid.orientation[i])
    points, changes, group, partners = change
    return predicted_strain(parked, before.rigid.position[i], R, points, changes, group, model.dt,
                            partners)


def scene_indices(model, parts=None):
    """Scene index of every solver body: the rigid bodies, then (with ``parts``, the step's
    :class:`hybrid.coupling.problem.Particles`) the particles and places of FEM bodies."""
    rigid = np.asarray(model.rigid_ids, dtype=np.int64)
    if parts is None:
        return rigid
    fem_ids = np.asarray(model.fem_ids, dtype=np.int64)
    place_body = parts.node_body[parts.corners[:, 0]] if len(parts.corners) else np.zeros(0, np.int64)
    return np.concatenate([rigid, fem_ids[parts.body], fem_ids[place_body]])
