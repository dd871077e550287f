"""The fracture event: FEM bodies crack and their pieces become bodies of the hybrid model.

    model, state, events = apply_fracture(model, state)

Called between coupled steps. For each FEM body with a ``fracture_stress`` (or a
``tearing_strain``) the crack search of ``fem.fracture.find_crack`` smooths the element stresses,
finds the elements whose largest principal stress exceeds the strength (or that tear), and chooses
the mesh faces of one crack plane; ``fem.split.split_mesh`` opens them by node duplication and
``fem.split.split_bodies`` gives the connected pieces. Bodies without either field are skipped
entirely (no stress is even computed).

After a split, only the bodies that changed are rebuilt (:mod:`hybrid.coupling.fragments`); every
other body keeps its model and factorisation.
- The largest piece keeps the parent's name and body id; the others become new bodies named
  ``<original>.<k>`` (k counts the original scene body's fragments), appended to
  ``HybridModel.names`` (and to ``scene.bodies``, so per-body scene data such as friction is found).
- Node velocities are copied to the duplicated nodes and node masses are recomputed from each
  piece's own tets, so total mass and linear and angular momentum are unchanged.
- ``fragment_model = "rigid"`` makes every piece but the largest a rigid body, unless it holds
  anchor or load nodes;
  ``"auto"`` makes the pieces auto bodies (hybrid.coupling.auto: rigid while calm, FEM while
  struck; those under ``rigid_fragment_tets`` tets rigid at once), as are an auto body's pieces.
- ``HybridModel.fragment_of`` (one entry per name): the original scene body each body came from
  (itself for scene bodies). ``HybridModel.fracture``: per FEM body :class:`FractureBody` (None
  when the body cannot break), what depends only on the body's mesh: built once from the scene
  bodies (:func:`fracture_bodies`; on first use when the built model has none) and for the pieces
  of a split body.
- ``HybridState.fracture_pending``: per FEM body, the crack faces chosen but not open yet
  (history: a check that only adds waiting faces returns a new state and the same model).
"""
from __future__ import annotations

import time as clock
from dataclasses import dataclass, replace

import numpy as np

from fem.fracture import FractureModel, find_crack, fracture_model
from fem.split import (P2_LUMPED, P2_ROW_SUMS, element_mass_shares, face_tet_slots,
                       fragment_tet_slots, lumped_mass_p1, split_bodies, split_mesh, tet_slot_faces,
                       transfer_node_state)
from fem.stress import element_stress
from rigid import quaternion as quat
from rigid.compose import append_bodies

from .fragments import RigidPiece, fem_fragment, held_regions, rigid_fragments


@dataclass(frozen=True)
class FractureBody:
    """Fracture data of one FEM body of the hybrid model: constant, it depends only on the body's
    mesh and scene data (built once, and for each piece when the body splits). The crack faces
    waiting to open are history: ``HybridState.fracture_pending``.

    origin: scene index of the original body this one comes from.
    fragment_model: "fem" | "rigid" | "auto". rigid_fragment_tets: "auto" pieces with fewer tets
        become rigid.
    fracture: :class:`fem.fracture.FractureModel` of the body's current mesh (strength, tearing
        strain, max cracks per step, unbreakable elements, faces, smoothing).
    """
    origin: int
    fragment_model: str
    rigid_fragment_tets: int
    fracture: FractureModel


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
        text = f"t = {self.time:.6g} s: body '{self.body}' cracked ({self.cracks} elements, " \
               f"{self.faces} faces)"
        if self.new_bodies:
            text += f", split off {', '.join(self.new_bodies)}"
            if self.rigid_bodies:
                text += f" (rigid: {', '.join(self.rigid_bodies)})"
        return text

    def as_dict(self):
        """JSON-ready summary row: time, body, event kind ("fracture"), cracks, faces, new bodies."""
        return {"time": self.time, "body": self.body, "event": "fracture", "cracks": self.cracks,
                "faces": self.faces,
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


def fracture_bodies(model):
    """Per FEM body of ``model`` its :class:`FractureBody` built from the body's mesh and scene
    data (None when it cannot break): the value of ``HybridModel.fracture`` for a model built
    from a scene."""
    origins = fragment_of(model)
    bodies = [model.scene.bodies[body_id] for body_id in model.fem_ids]
    return tuple(_scene_fracture_body(m, origins[body_id], body) if _can_break(body) else None
                 for m, body_id, body in zip(model.fem, model.fem_ids, bodies))


def fracture_data(model):
    """Per FEM body :class:`FractureBody` (None when it cannot break): ``model.fracture``, or, when
    the model has none yet, :func:`fracture_bodies` (:func:`apply_fracture` returns them with the
    model it returns, so they are built once)."""
    if model.fracture is not None and len(model.fracture) == len(model.fem):
        return model.fracture
    return fracture_bodies(model)


def pending_faces(model, state):
    """Per FEM body the ``(p, 2)`` (tet, local face) rows of its crack faces waiting to open
    (``state.fracture_pending``; empty rows where none wait)."""
    pending = state.fracture_pending
    if pending is None:
        return tuple(np.zeros((0, 2), np.int64) for _ in model.fem)
    if len(pending) != len(model.fem):
        raise ValueError(f"HybridState.fracture_pending has {len(pending)} entries for "
                         f"{len(model.fem)} FEM bodies (an event replaced bodies without it)")
    return tuple(pending)


# --- crack search and splitting of one body --------------------------------------------------

def find_cracks(fem_model, fem_state, data, pending):
    """Crack faces of one body this step: ``(cut (f,) face ids in data.fracture.faces,
    CrackCandidates)``; ``cut`` holds the ``pending`` faces ((p, 2) (tet, local face) rows) and
    the new ones, and is empty when no new face was chosen (``fem.fracture.find_crack`` on the
    body's rest shape)."""
    sigma = element_stress(fem_model, fem_state, fem_state.tet_plastic_strain)
    peeq = fem_state.tet_peeq
    return find_crack(data.fracture, fem_model.rest_points, fem_model.tets, sigma,
                      None if peeq is None else peeq.max(axis=1), fem_state.tet_yielded,
                      tet_slot_faces(data.fracture.faces, pending))


@dataclass
class _Piece:
    """One piece of a split body: its FEM model, state, fracture data and ``(p, 2)`` crack faces
    still waiting to open, or, to become a rigid body, ``rigid`` (the others None)."""
    model: object
    state: object
    data: FractureBody | None
    pending: np.ndarray | None
    rigid: RigidPiece | None = None


def _turns_rigid(fem_model, data, frag, node_origin):
    """Whether a piece other than the largest becomes a rigid body for good: held by no anchor
    (that pins it, hybrid.coupling.fragments.held_regions) and holding no load node (anchors and
    loads go with the nodes they hold, and a rigid body has neither), and ``fragment_model =
    "rigid"`` (``"auto"`` pieces are auto bodies, see hybrid.coupling.auto)."""
    nodes = node_origin[frag.node_index]
    anchored = bool(held_regions(fem_model, frag, node_origin))
    loaded = any(np.isin(nodes, held).any() for held in fem_model.load_nodes)
    return not anchored and not loaded and data.fragment_model == "rigid"


def _fragment_data(data, fem_model, frag, cut):
    """FractureBody of an FEM piece (the parent's material on the piece's mesh) and the
    ``(p, 2)`` rows of the cut faces that did not open, still pending in the piece."""
    parent = data.fracture
    fracture = fracture_model(fem_model.tets, fem_model.elements.tet_volume,
                              parent.fracture_stress, parent.tearing_strain, parent.max_cracks,
                              parent.tet_unbreakable[frag.tet_index])
    pending = fragment_tet_slots(parent.faces, cut, frag.tet_index, fracture.faces)
    return replace(data, fracture=fracture), pending


def split_body(fem_model, fem_state, data, cut, dt):
    """Open ``cut`` faces of one body; returns its pieces (largest first), FEM or rigid-to-be.

    While nothing opens, the one piece is the body itself with ``cut`` pending.
    """
    faces = data.fracture.faces
    split = split_mesh(fem_model.rest_points, fem_model.tets, faces.face_vertices[cut],
                       fem_model.order, faces)
    if len(split.points) == fem_model.node_count:
        # nothing opened yet: the chosen faces wait until the crack reaches the surface
        return [_Piece(fem_model, fem_state, data, face_tet_slots(faces, cut))]
    fragments = sorted(split_bodies(split.points, split.tets), key=lambda f: -len(f.tet_index))
    origin, volume = split.node_origin, fem_model.elements.tet_volume
    node_state = transfer_node_state(origin, fem_state.x, fem_state.v, fem_state.node_reaction)
    vertex_mass = lumped_mass_p1(split.tets, volume, fem_model.density, len(split.points))
    pieces = []
    for k, frag in enumerate(fragments):
        if k > 0 and _turns_rigid(fem_model, data, frag, origin):
            # its nodes' masses as the body's own lumping shares them (P2: HRZ; mid-edge nodes
            # carry most), and the weights its momentum was carried with (a consistent mass's rows)
            quadratic = fem_model.order == 2
            lumped = P2_LUMPED if quadratic else (0.25,) * 4
            carried = P2_ROW_SUMS if quadratic and fem_model.mass_kind == "consistent" else lumped
            node_mass, weights = (element_mass_shares(frag.tets, volume[frag.tet_index],
                                                      fem_model.density, len(frag.points), shares)
                                  for shares in (lumped, carried))
            x, v = (a[frag.node_index] for a in node_state[:2])
            pieces.append(_Piece(None, None, None, None,
                                 rigid=RigidPiece(frag, x, v, node_mass, weights)))
            continue
        model, state = fem_fragment(fem_model, fem_state, frag, origin, node_state, vertex_mass,
                                    dt)
        pieces.append(_Piece(model, state, *_fragment_data(data, model, frag, cut)))
    return pieces


# --- the event -------------------------------------------------------------------------------

@dataclass
class _Bodies:
    """The hybrid model's bodies while an event changes them (lists copied from the model and
    state)."""
    fem: list
    fem_states: list
    fem_ids: list
    data: list
    pending: list
    names: list
    origins: list
    scene_bodies: list
    rigid_ids: list
    rigid_new: list

    @classmethod
    def of(cls, model, state, data, pending):
        return cls(list(model.fem), list(state.fem), list(model.fem_ids), list(data),
                   list(pending), list(model.names), fragment_of(model),
                   list(model.scene.bodies), list(model.rigid_ids), [])

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
            # pieces of an auto body, or of fragment_model = "auto", are auto bodies
            auto = "auto" in (parent_body.model, parent_body.fragment_model)
            self.scene_bodies.append(replace(parent_body, name=name,
                                             model="auto" if auto else parent_body.model))
            self.fem.append(piece.model)
            self.fem_states.append(piece.state)
            self.fem_ids.append(new_id)
            self.data.append(piece.data)
            self.pending.append(piece.pending)
        return name

    def hybrid(self, model, state):
        """The new HybridModel and HybridState holding these bodies."""
        rigid_model, rigid_state = model.rigid, state.rigid
        if self.rigid_new:
            add_model, add_state = rigid_fragments(self.rigid_new, model.gravity,
                                                   rigid_state.last_dt)
            rigid_model, rigid_state = append_bodies(rigid_model, rigid_state, add_model,
                                                     add_state)
        scene = replace(model.scene, bodies=tuple(self.scene_bodies))
        new_model = replace(model, rigid=rigid_model, rigid_ids=np.array(self.rigid_ids, dtype=int),
                            fem=self.fem, fem_ids=self.fem_ids, names=self.names, scene=scene,
                            fragment_of=self.origins, fracture=tuple(self.data))
        new_state = replace(state, rigid=rigid_state, fem=self.fem_states, contact_memory=None,
                            resting=None, contact_sets=None,
                            fracture_pending=self.fracture_pending())
        return new_model, new_state

    def fracture_pending(self):
        """``HybridState.fracture_pending`` of these bodies (None when no face waits)."""
        return tuple(self.pending) if any(len(p) for p in self.pending) else None


def _crack(bodies, j, cut, found, model, state):
    """Split FEM body ``j`` along ``cut``, registering its pieces; the FractureEvent, or None
    while the crack has not opened."""
    body_id = bodies.fem_ids[j]
    parent_body, root = bodies.scene_bodies[body_id], bodies.origins[body_id]
    pieces = split_body(model.fem[j], state.fem[j], bodies.data[j], cut, model.dt)
    first = pieces[0]
    bodies.fem[j], bodies.fem_states[j], bodies.data[j], bodies.pending[j] = (
        first.model, first.state, first.data, first.pending)
    if first.model is model.fem[j]:
        return None
    # the plastic work the body dissipated stays with the piece in its place (the pieces start
    # from none: summary.json's plastic_dissipation read 0 once a pulled bar tore)
    bodies.fem_states[j] = first.state.replace(plastic_dissipation=state.fem[j].plastic_dissipation)
    new_names = [bodies.add(piece, parent_body, root) for piece in pieces[1:]]
    rigid_names = [name for name, piece in zip(new_names, pieces[1:]) if piece.model is None]
    still_pending = sum(len(p.pending) for p in pieces if p.model is not None)
    return FractureEvent(
        time=float(state.time), body=bodies.names[body_id], origin=root,
        cracks=int(found.element.size), faces=int(len(cut) - still_pending // 2),
        new_bodies=tuple(new_names), rigid_bodies=tuple(rigid_names), normal=found.normal,
        principal_stress=found.principal_stress, element=found.element)


def apply_fracture(model, state, timings=None):
    """Crack and split the FEM bodies that fail this step; returns ``(model, state, events)``.

    ``model``/``state`` are returned unchanged (same objects) when nothing cracks; a new state
    with the same model when crack faces were chosen but none opened (they wait in
    ``state.fracture_pending``); a new model and state when a body split (models are never
    changed). A model without its fracture data yet comes back once holding it (see
    :func:`fracture_data`). ``events`` is a list of :class:`FractureEvent` (``event.message`` for
    the log, ``event.as_dict()`` for the summary). ``timings``: optional dict; seconds spent are
    added under "fracture_check" and "fracture_rebuild".
    """
    timings = {} if timings is None else timings
    timings.setdefault("fracture_check", 0.0)
    timings.setdefault("fracture_rebuild", 0.0)
    t0 = clock.perf_counter()
    data, pending = fracture_data(model), pending_faces(model, state)
    if data is not model.fracture:
        model = replace(model, fracture=data, fragment_of=fragment_of(model))
    # a body without an interior face (a lone tet) has nothing to open: no stress is computed
    cracked = [(j, *find_cracks(model.fem[j], state.fem[j], d, pending[j]))
               for j, d in enumerate(data) if d is not None and d.fracture.can_open]
    cracked = [(j, cut, found) for j, cut, found in cracked if len(cut)]
    t1 = clock.perf_counter()
    timings["fracture_check"] += t1 - t0
    if not cracked:
        return model, state, []
    bodies = _Bodies.of(model, state, data, pending)
    events = [_crack(bodies, j, cut, found, model, state) for j, cut, found in cracked]
    events = [event for event in events if event is not None]
    if events:
        model, state = bodies.hybrid(model, state)
    else:
        # only pending faces changed: same bodies, same model
        state = replace(state, fracture_pending=bodies.fracture_pending())
    timings["fracture_rebuild"] += clock.perf_counter() - t1
    return model, state, events
