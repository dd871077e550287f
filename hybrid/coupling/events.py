"""Events between steps: plastic reference-shape updates and fracture.

    model, state, events = between_steps(model, state)

Plastic reference updates (fem.reference) bake large plastic strain into a body's rest shape
and refactorise that body only. Fracture cracks FEM bodies and turns their fragments into bodies:

Called between coupled steps. For each FEM body with a ``fracture_stress`` (or a
``tearing_strain``) it smooths the element stresses, finds the elements whose largest principal
stress exceeds the strength (``fem.fracture``), opens the mesh faces closest to the crack planes by
node duplication and splits the mesh into its connected components (``fem.split``). Bodies
without either field are skipped entirely (no stress is even computed).

After a split, only the bodies that changed are rebuilt (``fem.model.build_fem_model``, which
refactorises their system matrix); every other body keeps its model and factorisation.
- The largest component keeps the parent's name and body id; the others become new bodies named
  ``<original>.<k>`` (k counts the original scene body's fragments), appended to
  ``HybridModel.names`` (and to ``scene.bodies``, so per-body scene data such as friction is found).
- Node velocities are copied to the duplicated nodes and node masses are recomputed from each
  fragment's own tets, so total mass and linear and angular momentum are unchanged.
- Anchors and loads go with the nodes they hold; a load shared by fragments is split between them
  in proportion to the mass of its nodes in each.
- ``fragment_model = "rigid"`` (every fragment but the largest) or ``"auto"`` (fragments with fewer
  than ``rigid_fragment_tets`` tets) makes unanchored fragments rigid bodies: their current surface
  (``rigid.trimesh.tet_boundary``) is appended to the rigid model with the fragment's momentum.
- ``HybridModel.fragment_of`` (one entry per name): the original scene body each body came from
  (itself for scene bodies). ``HybridModel.fracture``: per FEM body fracture data (None when the
  body cannot break), built on first use.
"""
from __future__ import annotations

import time as clock
from dataclasses import dataclass, fields, replace
from dataclasses import field as dataclass_field

import numpy as np
import scipy.sparse as sp

from fem.fracture import (chosen_faces, face_neighbours, fracture_candidates, planar_crack,
                          smoothing_operator)
from fem.model import build_fem_model, rest_state
from fem.split import TetFaces, components, split_bodies, split_mesh, tet_faces
from fem.stress import element_stress
from rigid import quaternion as quat
from rigid.build import RigidBodyDesc, build_rigid
from rigid.model import RigidState
from rigid.trimesh import compact, tet_boundary


@dataclass(frozen=True)
class FractureBody:
    """Static fracture data of one FEM body (rebuilt when the body splits).

    origin: scene index of the original body this one comes from.
    fracture_stress: tensile strength (Pa); inf when only tearing can break the body.
    tearing_strain: equivalent plastic strain at which an element tears (-), or None.
    max_cracks: most elements cracking per step. fragment_model: "fem" | "rigid" | "auto".
    rigid_fragment_tets: "auto" fragments with fewer tets become rigid.
    tet_unbreakable: ``(t,)`` bool, elements that never crack.
    faces: :class:`fem.split.TetFaces` of the body's current mesh.
    smoothing: ``(t, t)`` CSR volume-weighted neighbour-mean operator (``fem.fracture``).
    pending: ``(p, 2)`` int, (tet, local face) of crack faces chosen but not open yet: a face
        opens by node duplication only once the crack surface through its nodes reaches the
        boundary or an open crack, so chosen faces accumulate here until they do.
    """
    origin: int
    fracture_stress: float
    tearing_strain: float | None
    max_cracks: int
    fragment_model: str
    rigid_fragment_tets: int
    tet_unbreakable: np.ndarray
    faces: TetFaces
    smoothing: sp.csr_matrix
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


def _fracture_body(fem_model, origin, body, tet_unbreakable):
    """FractureBody of a mesh (faces and smoothing of its current topology)."""
    faces = tet_faces(fem_model.tets)
    smoothing = smoothing_operator(fem_model.elements.tet_volume,
                                   face_neighbours(fem_model.tets, faces))
    strength = body.fracture_stress if body.fracture_stress is not None else np.inf
    return FractureBody(origin=origin, fracture_stress=float(strength),
                        tearing_strain=body.tearing_strain, max_cracks=body.max_cracks_per_step,
                        fragment_model=body.fragment_model,
                        rigid_fragment_tets=body.rigid_fragment_tets,
                        tet_unbreakable=np.asarray(tet_unbreakable, dtype=bool), faces=faces,
                        smoothing=smoothing)


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


def fragment_of(model):
    """Scene index of the original body of every body (list parallel to ``model.names``)."""
    value = getattr(model, "fragment_of", None)
    if value is None or len(value) != len(model.names):
        value = list(range(len(model.names)))
    return list(value)


def fracture_data(model):
    """Per FEM body :class:`FractureBody` (None when it cannot break), cached on the model."""
    data = getattr(model, "fracture", None)
    if data is not None and len(data) == len(model.fem):
        return data
    origins = fragment_of(model)
    data = []
    for m, body_id in zip(model.fem, model.fem_ids):
        body = model.scene.bodies[body_id]
        data.append(_fracture_body(m, origins[body_id], body, _unbreakable_tets(m, body))
                    if _can_break(body) else None)
    _set(model, fracture=data, fragment_of=origins)
    return data


def _set(model, **values):
    """Set HybridModel attributes (fields if it declares them, else plain attributes)."""
    for key, value in values.items():
        setattr(model, key, value)


def _with(model, **changes):
    """A new HybridModel with ``changes``; extra (undeclared) attributes are carried over."""
    declared = {f.name for f in fields(model)}
    new = replace(model, **{k: v for k, v in changes.items() if k in declared})
    for key in ("fragment_of", "fracture"):
        if key not in declared:
            setattr(new, key, changes.get(key, getattr(model, key, None)))
    return new


# --- crack detection -------------------------------------------------------------------------

def _plastic_strain(fem_state):
    """Plastic strain ``(t, q, 3, 3)`` of a FEM state, or None for an elastic body."""
    return getattr(fem_state, "tet_plastic_strain", None)


def find_cracks(fem_model, fem_state, data):
    """Crack faces of one body this step: ``(cut (f,) face ids in data.faces, CrackCandidates)``.

    ``cut`` holds the pending faces and the new ones; it is empty when no new face was chosen.

    Brittle: smoothed largest principal stress above ``fracture_stress``. Ductile: equivalent
    plastic strain above ``tearing_strain`` in an element still flowing (crack normal = largest
    principal stress direction).
    Both skip unbreakable elements; at most ``max_cracks`` elements per call.
    """
    eps_p = _plastic_strain(fem_state)
    sigma = element_stress(fem_model, fem_state, eps_p)
    smoothed = (data.smoothing @ sigma.reshape(-1, 9)).reshape(sigma.shape)
    found = fracture_candidates(smoothed, data.fracture_stress, None, data.tet_unbreakable)
    peeq = getattr(fem_state, "tet_peeq", None)
    if data.tearing_strain is not None and peeq is not None:
        found = _add_tearing(found, smoothed, peeq.max(axis=1), fem_state.tet_yielded, data)
    found = planar_crack(fem_model.rest_points, fem_model.tets, found, data.faces,
                         max_cracks=data.max_cracks)
    chosen, _ = chosen_faces(fem_model.rest_points, fem_model.tets, found.element, found.normal,
                             data.faces)
    chosen = np.unique(chosen[chosen >= 0])
    pending = data.faces.tet_face[data.pending[:, 0], data.pending[:, 1]]
    if np.all(np.isin(chosen, pending)):
        return np.zeros(0, dtype=np.int64), found
    return np.union1d(pending, chosen), found


def _add_tearing(found, smoothed, tet_peeq, tet_yielded, data):
    """Append elements whose accumulated equivalent plastic strain ``(t,)`` exceeds the tearing
    strain while they are flowing (``tet_yielded`` ``(t,)``, last step) (ductile tearing; crack
    normal = largest principal stress direction). Unloaded elements do not tear: peeq never
    decreases, so without this the elements of a fresh tear surface would keep cracking every
    step along the arbitrary principal directions of their residual stress."""
    torn = (tet_peeq > data.tearing_strain) & tet_yielded & ~data.tet_unbreakable
    torn[found.element] = False
    element = np.flatnonzero(torn)
    if element.size == 0:
        return found
    # most strained first: planar_crack seeds the crack plane at the first candidate and applies
    # max_cracks itself, so all torn elements stay candidates (a uniformly flowing bar tears
    # across one whole section instead of chipping at the first max_cracks by index)
    element = element[np.argsort(-tet_peeq[element], kind="stable")]
    eigenvalue, eigenvector = np.linalg.eigh(smoothed[element])
    normal = eigenvector[:, :, -1]
    # canonical sign (CrackCandidates): largest-magnitude component positive
    lead = np.take_along_axis(normal, np.argmax(np.abs(normal), axis=1)[:, None], 1)
    normal = normal * np.where(lead < 0.0, -1.0, 1.0)
    return type(found)(np.concatenate([found.element, element]),
                       np.concatenate([found.normal, normal]),
                       np.concatenate([found.principal_stress, eigenvalue[:, -1]]))


# --- splitting a body ------------------------------------------------------------------------

@dataclass
class _Piece:
    """One component of a split body: its new FEM model/state or rigid description."""
    model: object
    state: object
    data: FractureBody | None
    rigid: tuple | None = None      # (RigidBodyDesc, velocity (3,), angular momentum (3,))


def _region_nodes(region_nodes, node_origin, node_index):
    """Fragment-local indices of the fragment nodes whose original node is in ``region_nodes``."""
    return np.flatnonzero(np.isin(node_origin[node_index], region_nodes))


def _build_fragment(parent, frag, node_origin, x, v, reaction, load_share, dt):
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
    model = build_fem_model(frag.points, frag.tets, order=parent.order, density=parent.density,
                            young=parent.young, poisson=parent.poisson,
                            damping_mass=parent.damping_mass,
                            damping_stiffness=parent.damping_stiffness, frame=parent.frame,
                            mass=parent.mass_kind, integrator=parent.integrator, anchors=anchors,
                            loads=loads, dt=dt, **_plastic_parameters(parent))
    model = _carry_model_fields(parent, model, frag.tet_index)
    # the regions keep their scene names (regions.csv rows continue under the fragment's name)
    labels = [parent.anchor_labels or range(len(parent.anchor_nodes)),
              parent.load_labels or range(len(parent.load_nodes))]
    model = replace(model, anchor_labels=tuple(labels[0][a] for a in anchor_labels),
                    load_labels=tuple(labels[1][i] for i in load_labels))
    state = rest_state(model, x[frag.node_index], v[frag.node_index])
    state = state.replace(node_reaction=reaction[frag.node_index])
    return model, state


def _plastic_parameters(parent):
    """build_fem_model keywords of the parent's plasticity (none for an elastic-only build)."""
    import inspect
    names = ("yield_stress", "plastic_update_strain", "max_plastic_strain")
    accepted = inspect.signature(build_fem_model).parameters
    return {k: getattr(parent, k) for k in names if k in accepted and hasattr(parent, k)}


def _carry_model_fields(parent, model, tet_index=None):
    """Copy scalar FemModel fields build_fem_model does not set (added by other features)."""
    import inspect
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
        from fem.plastic_flow import rest_frame_plastic_force
        state = state.replace(node_plastic_force=rest_frame_plastic_force(
            model, state.tet_plastic_strain))
    return state


def split_body(fem_model, fem_state, data, cut, dt):
    """Open ``cut`` faces of one body; returns its pieces (largest first), FEM or rigid-to-be.

    Rigid-to-be pieces come back with ``model`` None and ``rigid`` set; see module docstring.
    """
    split = split_mesh(fem_model.rest_points, fem_model.tets, data.faces.face_vertices[cut],
                       fem_model.order, data.faces)
    if len(split.points) == fem_model.node_count:
        # nothing opened yet: the chosen faces wait until the crack reaches the surface
        pending = np.stack([data.faces.face_tets[cut, 0], data.faces.face_local[cut, 0]], 1)
        return [_Piece(fem_model, fem_state, replace(data, pending=pending))]
    label, count = components(split.tets, len(split.points))
    fragments = split_bodies(split.points, split.tets, label)
    fragments.sort(key=lambda f: -len(f.tet_index))
    origin = split.node_origin
    x, v, reaction = fem_state.x[origin], fem_state.v[origin], fem_state.node_reaction[origin]
    # load shares: mass of each fragment's loaded nodes over the total (P1 lumping of the vertices)
    tet_mass = fem_model.density * np.abs(fem_model.elements.tet_volume)
    vertex_mass = np.bincount(split.tets[:, :4].ravel(), np.repeat(tet_mass / 4, 4),
                              minlength=len(split.points))
    pieces = []
    for k, frag in enumerate(fragments):
        rigid = k > 0 and not np.any(fem_model.node_anchor[origin[frag.node_index]] >= 0) and (
            data.fragment_model == "rigid" or (data.fragment_model == "auto"
                                               and len(frag.tet_index) < data.rigid_fragment_tets))
        sub = replace(data, tet_unbreakable=data.tet_unbreakable[frag.tet_index])
        if rigid:
            pieces.append(_Piece(None, None, sub, rigid=(frag, x[frag.node_index], v[frag.node_index])))
            continue
        share = []
        for nodes in fem_model.load_nodes:
            in_region = np.isin(origin, nodes)
            mine = np.zeros(len(origin), dtype=bool)
            mine[frag.node_index] = True
            total = vertex_mass[in_region].sum()
            share.append(vertex_mass[in_region & mine].sum() / total if total > 0 else
                         (in_region & mine).sum() / max(in_region.sum(), 1))
        model, state = _build_fragment(fem_model, frag, origin, x, v, reaction, share, dt)
        state = _carry_state_fields(fem_model, fem_state, model, state, frag.tet_index, origin,
                                    frag.node_index)
        fb = _fracture_body(model, data.origin, _BodyFields(data), sub.tet_unbreakable)
        pieces.append(_Piece(model, state, replace(fb, pending=_still_pending(
            data.faces, cut, frag.tet_index, fb.faces))))
    return pieces


def _still_pending(faces, cut, tet_index, fragment_faces):
    """(p, 2) (fragment tet, local face) of the cut faces that are still interior faces of a
    fragment (faces that did not open)."""
    holders = np.concatenate([np.stack([faces.face_tets[cut, k], faces.face_local[cut, k]], 1)
                              for k in (0, 1)])
    holders = holders[np.isin(holders[:, 0], tet_index)]
    local_tet = np.searchsorted(tet_index, holders[:, 0])
    still = fragment_faces.interior[fragment_faces.tet_face[local_tet, holders[:, 1]]]
    result = np.stack([local_tet[still], holders[still, 1]], 1)
    return result.reshape(-1, 2).astype(np.int64)


class _BodyFields:
    """The scene fields `_fracture_body` reads, taken from an existing FractureBody."""

    def __init__(self, data):
        self.fracture_stress = None if np.isinf(data.fracture_stress) else data.fracture_stress
        self.tearing_strain = data.tearing_strain
        self.max_cracks_per_step = data.max_cracks
        self.fragment_model = data.fragment_model
        self.rigid_fragment_tets = data.rigid_fragment_tets


# --- rigid model growth ----------------------------------------------------------------------

def _grid_count(rm):
    return int(rm.grid_index.max()) + 1 if rm.body_count and rm.grid_index.max() >= 0 else 0


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
    ga, gb = _grid_count(rm), _grid_count(new_model)
    grid_index_b = np.where(new_model.grid_index >= 0, new_model.grid_index + ga, -1)
    changes["grid_index"] = np.concatenate([rm.grid_index, grid_index_b])
    if gb:
        src = (rm,) if ga else ()
        offset = len(rm.grid_values) if ga else 0
        changes["grid_values"] = np.concatenate([g.grid_values for g in src + (new_model,)])
        changes["grid_start"] = np.concatenate([rm.grid_start] * bool(ga) +
                                               [new_model.grid_start + offset]).astype(np.int64)
        for key in ("grid_shape", "grid_origin", "grid_cell"):
            changes[key] = np.concatenate([getattr(g, key) for g in src + (new_model,)])
    model = replace(rm, **changes)
    count = np.bincount(changes["point_body"], minlength=model.body_count)
    model.point_start = np.concatenate([[0], np.cumsum(count)]).astype(np.int64)
    state = RigidState(*(np.concatenate([getattr(rs, k), getattr(new_state, k)])
                         for k in ("position", "orientation", "velocity", "angular_momentum",
                                   "contact_dv")), time=rs.time, last_dt=rs.last_dt)
    return model, state


def _rigid_bodies(pieces_with_names, gravity, last_dt):
    """One RigidModel/RigidState for the fragments turned rigid, carrying their momentum."""
    descs, motion = [], []
    for name, body, piece, node_mass in pieces_with_names:
        frag, x, v = piece.rigid
        surface = tet_boundary(frag.tets[:, :4])
        vertices, triangles, _ = compact(x, surface)
        descs.append(RigidBodyDesc(name=name, vertices=vertices, triangles=triangles,
                                   density=body.density, friction=body.friction,
                                   restitution=body.restitution))
        motion.append((x, v, node_mass))
    model, state = build_rigid(descs, [])
    for i, (x, v, node_mass) in enumerate(motion):
        momentum = node_mass @ v
        # leapfrog stores the mid-step velocity; reported_velocity adds back half a gravity step
        state.velocity[i] = momentum / model.body_mass[i] - 0.5 * np.asarray(gravity) * last_dt
        r = x - state.position[i]
        state.angular_momentum[i] = np.cross(r, node_mass[:, None] * v).sum(axis=0)
    return model, state


# --- the event -------------------------------------------------------------------------------

def apply_fracture(model, state, timings=None):
    """Crack and split the FEM bodies that fail this step; returns ``(model, state, events)``.

    ``model``/``state`` are returned unchanged (same objects) when nothing cracks. ``events`` is a
    list of :class:`FractureEvent` (``event.message`` for the log, ``event.as_dict()`` for the
    summary). ``timings``: optional dict; seconds spent are added under "fracture_check" and
    "fracture_rebuild".
    """
    timings = {} if timings is None else timings
    timings.setdefault("fracture_check", 0.0)
    timings.setdefault("fracture_rebuild", 0.0)
    t0 = clock.perf_counter()
    data = fracture_data(model)
    cracked = []
    for j, d in enumerate(data):
        if d is None:
            continue
        cut, found = find_cracks(model.fem[j], state.fem[j], d)
        if len(cut):
            cracked.append((j, cut, found))
    t1 = clock.perf_counter()
    timings["fracture_check"] += t1 - t0
    if not cracked:
        return model, state, []

    fem, fem_states, fem_ids = list(model.fem), list(state.fem), list(model.fem_ids)
    data = list(data)
    names, origins = list(model.names), fragment_of(model)
    bodies = list(model.scene.bodies)
    rigid_ids = list(model.rigid_ids)
    rigid_new = []
    events = []
    for j, cut, found in cracked:
        body_id = fem_ids[j]
        parent_body = bodies[body_id]
        root = origins[body_id]
        pieces = split_body(fem[j], state.fem[j], data[j], cut, model.dt)
        opened = pieces[0].model is not fem[j]
        fem[j], fem_states[j], data[j] = pieces[0].model, pieces[0].state, pieces[0].data
        if not opened:
            continue
        new_names, rigid_names = [], []
        for piece in pieces[1:]:
            k = sum(1 for o in origins if o == root)   # fragments so far (the original counts as 0)
            name = f"{names[root]}.{k}"
            while name in names:
                k += 1
                name = f"{names[root]}.{k}"
            new_id = len(names)
            names.append(name)
            origins.append(root)
            new_names.append(name)
            if piece.model is None:
                bodies.append(replace(parent_body, name=name, model="rigid", anchors=(), loads=()))
                frag = piece.rigid[0]
                node_mass = np.bincount(frag.tets[:, :4].ravel(), np.repeat(
                    fem[j].density * np.abs(model.fem[j].elements.tet_volume[frag.tet_index]) / 4,
                    4), minlength=len(frag.points))
                rigid_new.append((name, parent_body, piece, node_mass))
                rigid_ids.append(new_id)
                rigid_names.append(name)
            else:
                bodies.append(replace(parent_body, name=name))
                fem.append(piece.model)
                fem_states.append(piece.state)
                fem_ids.append(new_id)
                data.append(piece.data)
        events.append(FractureEvent(
            time=float(state.time), body=names[body_id], origin=root, cracks=int(found.element.size),
            faces=int(len(cut) - sum(len(p.data.pending) for p in pieces if p.data is not None
                                     and p.model is not None) // 2), new_bodies=tuple(new_names), rigid_bodies=tuple(rigid_names),
            normal=found.normal, principal_stress=found.principal_stress, element=found.element))

    if not events:
        # only pending faces changed: same bodies, same matrices
        _set(model, fracture=data)
        timings["fracture_rebuild"] += clock.perf_counter() - t1
        return model, state, []
    rigid_model, rigid_state = model.rigid, state.rigid
    if rigid_new:
        add_model, add_state = _rigid_bodies(rigid_new, model.gravity, rigid_state.last_dt)
        rigid_model, rigid_state = append_rigid(rigid_model, rigid_state, add_model, add_state)
    scene = replace(model.scene, bodies=tuple(bodies)) if model.scene is not None else None
    new_model = _with(model, rigid=rigid_model, rigid_ids=np.array(rigid_ids, dtype=int), fem=fem,
                      fem_ids=fem_ids, names=names, scene=scene, fragment_of=origins,
                      fracture=data)
    new_state = replace(state, rigid=rigid_state, fem=fem_states, contact_memory=None, resting=None)
    timings["fracture_rebuild"] += clock.perf_counter() - t1
    return new_model, new_state, events


def between_steps(model, state, timings=None):
    """All events due after a step: reference-shape updates, then fracture.

    Returns ``(model, state, events)``: events are FractureEvents and ReferenceUpdate records,
    each with ``.message`` and ``.as_dict()``."""
    from fem.reference import apply_reference_updates
    events = []
    fem, fem_states, updated = apply_reference_updates(model.fem, state.fem, model.dt)
    if updated:
        model = _with(model, fem=fem)
        state = replace(state, fem=fem_states)
        events += [ReferenceUpdate(float(state.time), model.names[model.fem_ids[j]]) for j in updated]
    model, state, cracks = apply_fracture(model, state, timings)
    return model, state, events + cracks


@dataclass(frozen=True)
class ReferenceUpdate:
    """A body's rest shape absorbed its plastic strain (and its matrix was refactorised)."""
    time: float
    body: str

    @property
    def message(self):
        return f"t = {self.time:.4f} s: '{self.body}' took its plastic deformation into its rest shape"

    def as_dict(self):
        return {"time": self.time, "body": self.body, "event": "reference_update"}
