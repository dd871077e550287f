"""Events between steps: plastic reference-shape updates and fracture.

    model, state, events = between_steps(model, state)

Each event returns a new model and state (models are never changed). Plastic reference updates
(fem.reference) bake large plastic strain into a body's rest shape and refactorise that body only.

Fracture: called between coupled steps. For each FEM body with a ``fracture_stress`` (or a
``tearing_strain``) the crack search of ``fem.fracture.find_crack`` smooths the element stresses,
finds the elements whose largest principal stress exceeds the strength (or that tear), and chooses
the mesh faces of one crack plane; ``fem.split.split_mesh`` opens them by node duplication and
``fem.split.split_bodies`` gives the connected pieces. Bodies without either field are skipped
entirely (no stress is even computed).

After a split, only the bodies that changed are rebuilt; every
other body keeps its model and factorisation. Anchors and loads go with the nodes they hold; a load
shared by pieces is split between them in proportion to the mass of its nodes in each.
- The largest piece keeps the parent's name and body id; the others become new bodies named
  ``<original>.<k>`` (k counts the original scene body's fragments), appended to
  ``HybridModel.names`` (and to ``scene.bodies``, so per-body scene data such as friction is found).
- Node velocities are copied to the duplicated nodes and node masses are recomputed from each
  piece's own tets, so total mass and linear and angular momentum are unchanged.
- ``fragment_model = "rigid"`` (every piece but the largest) or ``"auto"`` (pieces with fewer
  than ``rigid_fragment_tets`` tets) makes unanchored pieces rigid bodies.
- ``HybridModel.fragment_of`` (one entry per name): the original scene body each body came from
  (itself for scene bodies). ``HybridModel.fracture``: per FEM body :class:`FractureBody` (None
  when the body cannot break), built from the model on first use and returned with a new model.
"""
from __future__ import annotations

import inspect
import time as clock
from dataclasses import dataclass, fields, replace
from dataclasses import field as dataclass_field
from typing import NamedTuple

import numpy as np

from fem.fracture import FractureModel, find_crack, fracture_model
from fem.model import build_fem_model, rest_state
from fem.plastic_flow import rest_frame_plastic_force
from fem.reference import apply_reference_updates
from fem.split import (Fragment, face_tet_slots, fragment_tet_slots, lumped_mass_p1,
                       split_bodies, split_mesh, tet_slot_faces, transfer_node_state)
from fem.stress import element_stress
from rigid import quaternion as quat
from rigid.build import RigidBodyDesc, build_rigid
from rigid.model import RigidState
from rigid.trimesh import compact, tet_boundary


class RigidPiece(NamedTuple):
    """A piece of a split FEM body that becomes a rigid body.

    fragment: its :class:`fem.split.Fragment`. x, v: ``(n, 3)`` its node positions (m) and
    velocities (m/s). node_mass: ``(n,)`` kg, P1-lumped from its own tets.
    """
    fragment: Fragment
    x: np.ndarray
    v: np.ndarray
    node_mass: np.ndarray


# --- FEM pieces ------------------------------------------------------------------------------

def _region_nodes(region_nodes, node_origin, node_index):
    """Fragment-local indices of the fragment nodes whose original node is in ``region_nodes``."""
    return np.flatnonzero(np.isin(node_origin[node_index], region_nodes))


def load_shares(parent, node_origin, vertex_mass, node_index):
    """Share of each of the parent's loads that a piece takes: the mass of the piece's loaded
    nodes over the load's total (``vertex_mass`` (n,) kg of the split mesh), by node count where
    the region has no mass."""
    mine = np.zeros(len(node_origin), dtype=bool)
    mine[node_index] = True
    share = []
    for nodes in parent.load_nodes:
        in_region = np.isin(node_origin, nodes)
        total = vertex_mass[in_region].sum()
        share.append(vertex_mass[in_region & mine].sum() / total if total > 0 else
                     (in_region & mine).sum() / max(in_region.sum(), 1))
    return share


def _fragment_regions(parent, frag, node_origin, load_share):
    """(anchors, anchor labels, loads, load labels) of the parent's regions the piece holds."""
    anchors, anchor_labels = [], []
    for a, nodes in enumerate(parent.anchor_nodes):
        local = _region_nodes(nodes, node_origin, frag.node_index)
        if local.size:
            anchors.append((local, parent.anchor_velocity[a]))
            anchor_labels.append(a)
    loads, load_labels = [], []
    for i, nodes in enumerate(parent.load_nodes):
        local = _region_nodes(nodes, node_origin, frag.node_index)
        if local.size and load_share[i] > 0:
            loads.append((local, load_share[i] * parent.load_force[i]))
            load_labels.append(i)
    # the regions keep their scene names (regions.csv rows continue under the fragment's name)
    labels = [parent.anchor_labels or range(len(parent.anchor_nodes)),
              parent.load_labels or range(len(parent.load_nodes))]
    return (anchors, tuple(labels[0][a] for a in anchor_labels),
            loads, tuple(labels[1][i] for i in load_labels))


def _fragment_model(parent, frag, node_origin, load_share, dt):
    """FemModel of a piece: the parent's material and settings on the piece's mesh."""
    anchors, anchor_labels, loads, load_labels = _fragment_regions(parent, frag, node_origin,
                                                                   load_share)
    model = build_fem_model(frag.points, frag.tets, order=parent.order, density=parent.density,
                            young=parent.young, poisson=parent.poisson,
                            damping_mass=parent.damping_mass,
                            damping_stiffness=parent.damping_stiffness, frame=parent.frame,
                            mass=parent.mass_kind, integrator=parent.integrator, anchors=anchors,
                            loads=loads, dt=dt, **_plastic_parameters(parent))
    model = _carry_model_fields(parent, model, frag.tet_index)
    return replace(model, anchor_labels=anchor_labels, load_labels=load_labels)


def fem_fragment(parent, parent_state, frag, node_origin, node_state, vertex_mass, dt):
    """FemModel and FemState of a piece that stays deformable.

    parent, parent_state: the split body's model and state. frag: the piece's Fragment of the
    split mesh. node_origin: ``(n,)`` parent node of each split-mesh node. node_state: ``(x, v,
    node_reaction)`` of the split mesh's nodes. vertex_mass: ``(n,)`` kg of the split mesh's
    nodes (load shares). dt: s, the step the new matrix is factorised for.
    """
    x, v, reaction = node_state
    share = load_shares(parent, node_origin, vertex_mass, frag.node_index)
    model = _fragment_model(parent, frag, node_origin, share, dt)
    state = rest_state(model, x[frag.node_index], v[frag.node_index])
    state = state.replace(node_reaction=reaction[frag.node_index])
    return model, _carry_state_fields(parent, parent_state, model, state, frag.tet_index,
                                      node_origin, frag.node_index)


def _plastic_parameters(parent):
    """build_fem_model keywords of the parent's plasticity (none for an elastic-only build)."""
    names = ("yield_stress", "plastic_update_strain", "max_plastic_strain")
    accepted = inspect.signature(build_fem_model).parameters
    return {k: getattr(parent, k) for k in names if k in accepted and hasattr(parent, k)}


def _carry_model_fields(parent, model, tet_index=None):
    """Copy scalar FemModel fields build_fem_model does not set (added by other features)."""
    built = set(inspect.signature(build_fem_model).parameters) | {
        "rest_points", "tets", "mu", "lam", "node_mass", "K", "M", "elements", "rest_center",
        "rest_offsets", "anchor_nodes", "anchor_velocity", "node_anchor", "free_dofs",
        "fixed_dofs", "load_nodes", "load_force", "node_load", "surface", "surface_nodes",
        "factor_cache", "mass_kind", "anchor_labels", "load_labels"}
    extra = {f.name: getattr(parent, f.name) for f in fields(parent)
             if f.name not in built and not isinstance(getattr(parent, f.name), np.ndarray)}
    # per-tet model arrays (e.g. reference_peeq (t, q)) follow their tets
    for f in fields(parent):
        value = getattr(parent, f.name)
        if f.name not in built and isinstance(value, np.ndarray) and tet_index is not None \
                and value.ndim and value.shape[0] == parent.tet_count:
            extra[f.name] = value[tet_index]
    return replace(model, **extra) if extra else model


def _carry_state_fields(parent_model, parent_state, model, state, tet_index, node_origin,
                        node_index):
    """Copy per-tet / per-node FemState fields other features added (e.g. plastic strain)."""
    known = {"x", "v", "R", "c", "node_reaction", "time"}
    extra = {}
    for f in fields(parent_state):
        value = getattr(parent_state, f.name)
        if f.name in known or not isinstance(value, np.ndarray) or value.ndim == 0:
            continue
        if value.shape[0] == parent_model.tet_count and not f.name.startswith("node"):
            extra[f.name] = value[tet_index]
        elif value.shape[0] == parent_model.node_count:
            extra[f.name] = value[node_origin][node_index]
    state = state.replace(time=parent_state.time, **extra)
    if getattr(state, "node_plastic_force", None) is not None:
        # a sum over elements: recompute it on the fragment's own elements (copying would give
        # every duplicated node the whole force)
        state = state.replace(node_plastic_force=rest_frame_plastic_force(
            model, state.tet_plastic_strain))
    return state


# --- rigid pieces ----------------------------------------------------------------------------

def rigid_fragments(pieces, gravity, last_dt):
    """One RigidModel/RigidState for the pieces turned rigid, carrying their momentum.

    pieces: list of ``(name, scene body, RigidPiece)``; the scene body gives density, friction
    and restitution. gravity: ``(3,)`` m/s^2. last_dt: s, the rigid state's last step.
    """
    descs = []
    for name, body, piece in pieces:
        vertices, triangles, _ = compact(piece.x, tet_boundary(piece.fragment.tets[:, :4]))
        descs.append(RigidBodyDesc(name=name, vertices=vertices, triangles=triangles,
                                   density=body.density, friction=body.friction,
                                   restitution=body.restitution))
    model, state = build_rigid(descs, [])
    for i, (_, _, piece) in enumerate(pieces):
        momentum = piece.node_mass @ piece.v
        # leapfrog stores the mid-step velocity; reported_velocity adds back half a gravity step
        state.velocity[i] = momentum / model.body_mass[i] - 0.5 * np.asarray(gravity) * last_dt
        r = piece.x - state.position[i]
        state.angular_momentum[i] = np.cross(r, piece.node_mass[:, None] * piece.v).sum(axis=0)
    return model, state


def _grid_count(rm):
    return int(rm.grid_index.max()) + 1 if rm.body_count and rm.grid_index.max() >= 0 else 0


def _appended_grids(rm, new_model):
    """RigidModel fields of the signed-distance grids of ``rm`` followed by ``new_model``'s."""
    ga, gb = _grid_count(rm), _grid_count(new_model)
    grid_index_b = np.where(new_model.grid_index >= 0, new_model.grid_index + ga, -1)
    changes = {"grid_index": np.concatenate([rm.grid_index, grid_index_b])}
    if gb:
        src = (rm,) if ga else ()
        offset = len(rm.grid_values) if ga else 0
        changes["grid_values"] = np.concatenate([g.grid_values for g in src + (new_model,)])
        changes["grid_start"] = np.concatenate([rm.grid_start] * bool(ga) +
                                               [new_model.grid_start + offset]).astype(np.int64)
        for key in ("grid_shape", "grid_origin", "grid_cell"):
            changes[key] = np.concatenate([getattr(g, key) for g in src + (new_model,)])
    return changes


def append_rigid(rm, rs, new_model, new_state):
    """RigidModel/RigidState with the bodies of ``new_model`` appended (planes of ``rm`` kept)."""
    per_body = ("body_mass", "body_inv_mass", "body_inertia", "body_inv_inertia", "body_fixed",
                "body_friction", "body_restitution", "body_radius", "shape_kind", "shape_params",
                "shape_rotation", "shape_offset", "point_local", "point_radius", "point_kind",
                "point_ring", "point_axis", "body_min_extent")
    changes = {k: np.concatenate([getattr(rm, k), getattr(new_model, k)]) for k in per_body}
    changes["names"] = list(rm.names) + list(new_model.names)
    changes["surface_vertices"] = list(rm.surface_vertices) + list(new_model.surface_vertices)
    changes["surface_triangles"] = list(rm.surface_triangles) + list(new_model.surface_triangles)
    changes["point_body"] = np.concatenate([rm.point_body, new_model.point_body + rm.body_count])
    model = replace(rm, **changes, **_appended_grids(rm, new_model))
    count = np.bincount(changes["point_body"], minlength=model.body_count)
    # point_start is not a RigidModel field (rigid.build sets it the same way on a new model)
    model.point_start = np.concatenate([[0], np.cumsum(count)]).astype(np.int64)
    state = RigidState(*(np.concatenate([getattr(rs, k), getattr(new_state, k)])
                         for k in ("position", "orientation", "velocity", "angular_momentum",
                                   "contact_dv")), time=rs.time, last_dt=rs.last_dt)
    return model, state


@dataclass(frozen=True)
class FractureBody:
    """Fracture data of one FEM body of the hybrid model (rebuilt when the body splits).

    origin: scene index of the original body this one comes from.
    fragment_model: "fem" | "rigid" | "auto". rigid_fragment_tets: "auto" pieces with fewer tets
        become rigid.
    fracture: :class:`fem.fracture.FractureModel` of the body's current mesh (strength, tearing
        strain, max cracks per step, unbreakable elements, faces, smoothing).
    pending: ``(p, 2)`` int, (tet, local face) of crack faces chosen but not open yet: a face
        opens by node duplication only once the crack surface through its nodes reaches the
        boundary or an open crack, so chosen faces accumulate here until they do.
    """
    origin: int
    fragment_model: str
    rigid_fragment_tets: int
    fracture: FractureModel
    pending: np.ndarray = dataclass_field(default_factory=lambda: np.zeros((0, 2), np.int64))


@dataclass(frozen=True)
class FractureEvent:
    """One body cracking in one step.

    time: s. body: name of the body that cracked. origin: scene index of its original body.
    cracks: elements that cracked. faces: mesh faces opened.
    new_bodies: names of the bodies split off (empty while the crack has not separated it).
    rigid_bodies: those of new_bodies that became rigid.
    normal: ``(cracks, 3)`` unit crack normals, rest frame. principal_stress: ``(cracks,)`` Pa.
    element: ``(cracks,)`` cracked element indices (of the body's mesh before the split).
    """
    time: float
    body: str
    origin: int
    cracks: int
    faces: int
    new_bodies: tuple
    rigid_bodies: tuple
    normal: np.ndarray
    principal_stress: np.ndarray
    element: np.ndarray

    @property
    def message(self):
        """One line for the run log."""
        text = f"t = {self.time:.4f} s: body '{self.body}' cracked ({self.cracks} elements, " \
               f"{self.faces} faces)"
        if self.new_bodies:
            text += f", split off {', '.join(self.new_bodies)}"
            if self.rigid_bodies:
                text += f" (rigid: {', '.join(self.rigid_bodies)})"
        return text

    def as_dict(self):
        """JSON-ready summary row: time, body, cracks, faces, new bodies."""
        return {"time": self.time, "body": self.body, "cracks": self.cracks, "faces": self.faces,
                "new_bodies": list(self.new_bodies), "rigid_bodies": list(self.rigid_bodies)}


# --- per-body fracture data ------------------------------------------------------------------

def _can_break(body):
    return getattr(body, "fracture_stress", None) is not None or \
        getattr(body, "tearing_strain", None) is not None


def _unbreakable_tets(fem_model, body):
    """(t,) bool: tets whose centroid lies in one of the body's unbreakable boxes (body coords)."""
    mask = np.zeros(fem_model.tet_count, dtype=bool)
    if not body.unbreakable:
        return mask
    # rest points are placed: X = R p + position, so body coordinates are R^T (X - position)
    R = quat.to_matrix(np.asarray(body.orientation, float))
    local = (fem_model.rest_points - np.asarray(body.position, float)) @ R
    centroid = local[fem_model.tets[:, :4]].mean(axis=1)
    for region in body.unbreakable:
        low, high = np.asarray(region.box[0]), np.asarray(region.box[1])
        mask |= np.all((centroid >= low - 1e-9) & (centroid <= high + 1e-9), axis=1)
    return mask


def _scene_fracture_body(fem_model, origin, body):
    """FractureBody of a scene body's FEM model."""
    fracture = fracture_model(fem_model.tets, fem_model.elements.tet_volume, body.fracture_stress,
                              body.tearing_strain, body.max_cracks_per_step,
                              _unbreakable_tets(fem_model, body))
    return FractureBody(origin=origin, fragment_model=body.fragment_model,
                        rigid_fragment_tets=body.rigid_fragment_tets, fracture=fracture)


def fragment_of(model):
    """Scene index of the original body of every body (list parallel to ``model.names``)."""
    value = model.fragment_of
    if value is None or len(value) != len(model.names):
        value = list(range(len(model.names)))
    return list(value)


def fracture_data(model):
    """Per FEM body :class:`FractureBody` (None when it cannot break): ``model.fracture``, or, when
    the model has none yet, built from its bodies (:func:`apply_fracture` returns them with the
    model it returns)."""
    if model.fracture is not None and len(model.fracture) == len(model.fem):
        return model.fracture
    origins = fragment_of(model)
    bodies = [model.scene.bodies[body_id] for body_id in model.fem_ids]
    return tuple(_scene_fracture_body(m, origins[body_id], body) if _can_break(body) else None
                 for m, body_id, body in zip(model.fem, model.fem_ids, bodies))


# --- crack search and splitting of one body --------------------------------------------------

def find_cracks(fem_model, fem_state, data):
    """Crack faces of one body this step: ``(cut (f,) face ids in data.fracture.faces,
    CrackCandidates)``; ``cut`` holds the pending faces and the new ones, and is empty when no
    new face was chosen (``fem.fracture.find_crack`` on the body's rest shape)."""
    sigma = element_stress(fem_model, fem_state, fem_state.tet_plastic_strain)
    peeq = fem_state.tet_peeq
    return find_crack(data.fracture, fem_model.rest_points, fem_model.tets, sigma,
                      None if peeq is None else peeq.max(axis=1), fem_state.tet_yielded,
                      tet_slot_faces(data.fracture.faces, data.pending))


@dataclass
class _Piece:
    """One piece of a split body: its FEM model, state and fracture data, or, to become a rigid
    body, ``rigid`` (model, state and data None)."""
    model: object
    state: object
    data: FractureBody | None
    rigid: RigidPiece | None = None


def _turns_rigid(fem_model, data, frag, node_origin):
    """Whether a piece other than the largest becomes rigid: unanchored, and ``fragment_model``
    "rigid", or "auto" with fewer than ``rigid_fragment_tets`` tets."""
    anchored = np.any(fem_model.node_anchor[node_origin[frag.node_index]] >= 0)
    return not anchored and (data.fragment_model == "rigid" or (
        data.fragment_model == "auto" and len(frag.tet_index) < data.rigid_fragment_tets))


def _fragment_data(data, fem_model, frag, cut):
    """FractureBody of an FEM piece: the parent's material on the piece's mesh, with the cut faces
    that did not open still pending."""
    parent = data.fracture
    fracture = fracture_model(fem_model.tets, fem_model.elements.tet_volume,
                              parent.fracture_stress, parent.tearing_strain, parent.max_cracks,
                              parent.tet_unbreakable[frag.tet_index])
    pending = fragment_tet_slots(parent.faces, cut, frag.tet_index, fracture.faces)
    return replace(data, fracture=fracture, pending=pending)


def split_body(fem_model, fem_state, data, cut, dt):
    """Open ``cut`` faces of one body; returns its pieces (largest first), FEM or rigid-to-be.

    While nothing opens, the one piece is the body itself with ``cut`` pending.
    """
    faces = data.fracture.faces
    split = split_mesh(fem_model.rest_points, fem_model.tets, faces.face_vertices[cut],
                       fem_model.order, faces)
    if len(split.points) == fem_model.node_count:
        # nothing opened yet: the chosen faces wait until the crack reaches the surface
        return [_Piece(fem_model, fem_state, replace(data, pending=face_tet_slots(faces, cut)))]
    fragments = sorted(split_bodies(split.points, split.tets), key=lambda f: -len(f.tet_index))
    origin, volume = split.node_origin, fem_model.elements.tet_volume
    node_state = transfer_node_state(origin, fem_state.x, fem_state.v, fem_state.node_reaction)
    vertex_mass = lumped_mass_p1(split.tets, volume, fem_model.density, len(split.points))
    pieces = []
    for k, frag in enumerate(fragments):
        if k > 0 and _turns_rigid(fem_model, data, frag, origin):
            node_mass = lumped_mass_p1(frag.tets, volume[frag.tet_index], fem_model.density,
                                       len(frag.points))
            x, v = (a[frag.node_index] for a in node_state[:2])
            pieces.append(_Piece(None, None, None, rigid=RigidPiece(frag, x, v, node_mass)))
            continue
        model, state = fem_fragment(fem_model, fem_state, frag, origin, node_state, vertex_mass,
                                    dt)
        pieces.append(_Piece(model, state, _fragment_data(data, model, frag, cut)))
    return pieces


# --- the event -------------------------------------------------------------------------------

@dataclass
class _Bodies:
    """The hybrid model's bodies while an event changes them (lists copied from the model)."""
    fem: list
    fem_states: list
    fem_ids: list
    data: list
    names: list
    origins: list
    scene_bodies: list
    rigid_ids: list
    rigid_new: list

    @classmethod
    def of(cls, model, state, data):
        return cls(list(model.fem), list(state.fem), list(model.fem_ids), list(data),
                   list(model.names), fragment_of(model), list(model.scene.bodies),
                   list(model.rigid_ids), [])

    def new_name(self, root):
        """``<original>.<k>`` for the next piece of scene body ``root`` (k counts its pieces so
        far, the original counting as 0; the first k whose name is free)."""
        k = sum(1 for o in self.origins if o == root)
        while f"{self.names[root]}.{k}" in self.names:
            k += 1
        return f"{self.names[root]}.{k}"

    def add(self, piece, parent_body, root):
        """Register a piece split off a body of scene origin ``root``; returns its name."""
        name = self.new_name(root)
        new_id = len(self.names)
        self.names.append(name)
        self.origins.append(root)
        if piece.model is None:
            self.scene_bodies.append(replace(parent_body, name=name, model="rigid", anchors=(),
                                             loads=()))
            self.rigid_new.append((name, parent_body, piece.rigid))
            self.rigid_ids.append(new_id)
        else:
            self.scene_bodies.append(replace(parent_body, name=name))
            self.fem.append(piece.model)
            self.fem_states.append(piece.state)
            self.fem_ids.append(new_id)
            self.data.append(piece.data)
        return name

    def hybrid(self, model, state):
        """The new HybridModel and HybridState holding these bodies."""
        rigid_model, rigid_state = model.rigid, state.rigid
        if self.rigid_new:
            add_model, add_state = rigid_fragments(self.rigid_new, model.gravity,
                                                   rigid_state.last_dt)
            rigid_model, rigid_state = append_rigid(rigid_model, rigid_state, add_model,
                                                    add_state)
        scene = replace(model.scene, bodies=tuple(self.scene_bodies))
        new_model = replace(model, rigid=rigid_model, rigid_ids=np.array(self.rigid_ids, dtype=int),
                            fem=self.fem, fem_ids=self.fem_ids, names=self.names, scene=scene,
                            fragment_of=self.origins, fracture=tuple(self.data))
        new_state = replace(state, rigid=rigid_state, fem=self.fem_states, contact_memory=None,
                            resting=None)
        return new_model, new_state


def _crack(bodies, j, cut, found, model, state):
    """Split FEM body ``j`` along ``cut``, registering its pieces; the FractureEvent, or None
    while the crack has not opened."""
    body_id = bodies.fem_ids[j]
    parent_body, root = bodies.scene_bodies[body_id], bodies.origins[body_id]
    pieces = split_body(model.fem[j], state.fem[j], bodies.data[j], cut, model.dt)
    bodies.fem[j], bodies.fem_states[j], bodies.data[j] = (pieces[0].model, pieces[0].state,
                                                            pieces[0].data)
    if pieces[0].model is model.fem[j]:
        return None
    new_names = [bodies.add(piece, parent_body, root) for piece in pieces[1:]]
    rigid_names = [name for name, piece in zip(new_names, pieces[1:]) if piece.model is None]
    still_pending = sum(len(p.data.pending) for p in pieces if p.model is not None)
    return FractureEvent(
        time=float(state.time), body=bodies.names[body_id], origin=root,
        cracks=int(found.element.size), faces=int(len(cut) - still_pending // 2),
        new_bodies=tuple(new_names), rigid_bodies=tuple(rigid_names), normal=found.normal,
        principal_stress=found.principal_stress, element=found.element)


def apply_fracture(model, state, timings=None):
    """Crack and split the FEM bodies that fail this step; returns ``(model, state, events)``.

    ``model``/``state`` are returned unchanged (same objects) when nothing cracks and the model
    holds its fracture data; a new model otherwise (models are never changed). ``events`` is a
    list of :class:`FractureEvent` (``event.message`` for the log, ``event.as_dict()`` for the
    summary). ``timings``: optional dict; seconds spent are added under "fracture_check" and
    "fracture_rebuild".
    """
    timings = {} if timings is None else timings
    timings.setdefault("fracture_check", 0.0)
    timings.setdefault("fracture_rebuild", 0.0)
    t0 = clock.perf_counter()
    data = fracture_data(model)
    cracked = [(j, *find_cracks(model.fem[j], state.fem[j], d)) for j, d in enumerate(data)
               if d is not None]
    cracked = [(j, cut, found) for j, cut, found in cracked if len(cut)]
    t1 = clock.perf_counter()
    timings["fracture_check"] += t1 - t0
    if not cracked:
        if data is not model.fracture:
            model = replace(model, fracture=data, fragment_of=fragment_of(model))
        return model, state, []
    bodies = _Bodies.of(model, state, data)
    events = [_crack(bodies, j, cut, found, model, state) for j, cut, found in cracked]
    events = [event for event in events if event is not None]
    if events:
        model, state = bodies.hybrid(model, state)
    else:
        # only pending faces changed: same bodies, same matrices
        model = replace(model, fracture=tuple(bodies.data), fragment_of=bodies.origins)
    timings["fracture_rebuild"] += clock.perf_counter() - t1
    return model, state, events


@dataclass(frozen=True)
class ReferenceUpdate:
    """A body's rest shape absorbed its plastic strain (and its matrix was refactorised).

    time: s. body: the body's name.
    """
    time: float
    body: str

    @property
    def message(self):
        """One line for the run log."""
        return f"t = {self.time:.4f} s: '{self.body}' took its plastic deformation into its rest shape"

    def as_dict(self):
        """JSON-ready summary row: time, body, event kind."""
        return {"time": self.time, "body": self.body, "event": "reference_update"}


def between_steps(model, state, timings=None):
    """All events due after a step: reference-shape updates, then fracture.

    Returns ``(model, state, events)``: events are FractureEvents and ReferenceUpdate records,
    each with ``.message`` and ``.as_dict()``. ``timings``: see :func:`apply_fracture`."""
    events = []
    fem, fem_states, updated = apply_reference_updates(model.fem, state.fem, model.dt)
    if updated:
        model = replace(model, fem=fem)
        state = replace(state, fem=fem_states)
        events += [ReferenceUpdate(float(state.time), model.names[model.fem_ids[j]]) for j in updated]
    model, state, cracks = apply_fracture(model, state, timings)
    return model, state, events + cracks
