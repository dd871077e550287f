"""Fracture pieces becoming bodies of the hybrid model.

A piece of a split FEM body (a :class:`fem.split.Fragment` of the split mesh) becomes either

- an FEM body of its own (:func:`fem_fragment`): its matrices are summed from the parent's
  element blocks (``fem.model.build_fem_model`` with ``elements_of``, no new assembly) and
  refactorised, anchors and loads go with the nodes they hold (a load shared by
  pieces is split between them in proportion to the mass of its nodes in each), the regions keep
  their scene names, and the parent's per-node and per-element state is carried over; or
- a rigid body (:func:`rigid_fragments`, then :func:`rigid.compose.append_bodies`): its current surface
  (``rigid.trimesh.tet_boundary``) with the piece's mass, linear and angular momentum.
"""
from __future__ import annotations

import inspect
from dataclasses import fields, replace
from typing import NamedTuple

import numpy as np

from fem.model import build_fem_model, rest_state
from fem.plastic_flow import rest_frame_plastic_force
from fem.split import Fragment
from rigid.build import RigidBodyDesc, build_rigid
from rigid.trimesh import compact, tet_boundary


class RigidPiece(NamedTuple):
    """A piece of a split FEM body that becomes a rigid body.

    fragment: its :class:`fem.split.Fragment`. x, v: ``(n, 3)`` its node positions (m) and
    velocities (m/s). node_mass: ``(n,)`` kg, lumped from its own tets as the body's mass is
    (all positive). weights: ``(n,)`` kg, the mass each node's velocity carried into the body's
    momentum (node_mass, or a consistent mass's row sums, negative at P2 corners).
    """
    fragment: Fragment
    x: np.ndarray
    v: np.ndarray
    node_mass: np.ndarray
    weights: np.ndarray


# --- FEM pieces ------------------------------------------------------------------------------

# anchored nodes pin a piece when they spread across a plane by more than this share of its size
PIN_TOL = 1e-6

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


def held_regions(parent, frag, node_origin):
    """The parent's anchors that hold the piece, ``[(anchor, fragment-local nodes (k,))]``: an
    anchor that pinned the parent holds a piece only where it pins it, by three nodes or more not
    all on one line. Held by one node or one edge of a grip (a chip in its layer, or the bar
    itself by the last node a crack left it), the piece would turn about them as on a hinge,
    which linear elements in a held body's fixed frame cannot follow (a tet held by an edge swung
    0.2 m in one step at a contact's push, 100-fold strain), and one node dragged the bar at a
    point: the piece has broken free of that grip, and is let go. A body its scene holds on a
    line (a hinge) keeps that hold in its pieces."""
    out = []
    for a, nodes in enumerate(parent.anchor_nodes):
        local = _region_nodes(nodes, node_origin, frag.node_index)
        if local.size and (_pins(frag.points[local], frag.points)
                           or not _pins(parent.rest_points[nodes], parent.rest_points)):
            out.append((a, local))
    return out


def _pins(held, points):
    """Whether held points ``(k, 3)`` span a plane, not only a line or a point, in a body of
    rest points ``points``."""
    if len(held) < 3:
        return False
    spread = np.linalg.svd(held - held.mean(axis=0), compute_uv=False)
    return spread[1] > PIN_TOL * np.ptp(points, axis=0).max()


def _fragment_regions(parent, frag, node_origin, load_share):
    """(anchors, anchor labels, loads, load labels) of the parent's regions the piece holds
    (anchors only where they pin it, :func:`held_regions`)."""
    anchors, anchor_labels = [], []
    for a, local in held_regions(parent, frag, node_origin):
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
                            loads=loads, dt=dt, linear_solver=parent.linear_solver,
                            corotated_solver=parent.corotated_solver,
                            elements_of=(parent, frag.tet_index), **_plastic_parameters(parent))
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
        "cache", "mass_kind", "anchor_labels", "load_labels"}
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

    pieces: list of ``(name, scene body, RigidPiece)``; the scene body gives friction and
    restitution, and each piece keeps its nodes' masses (its mass, centre of mass and inertia). gravity: ``(3,)`` m/s^2. last_dt: s, the rigid state's last step.
    """
    descs = []
    for name, body, piece in pieces:
        vertices, triangles, _ = compact(piece.x, tet_boundary(piece.fragment.tets[:, :4]))
        # mass, centre and inertia of its nodes' masses, as an auto body turned rigid takes them
        # (the scene density over a stretched or squashed shape made mass: a soft tile's pieces
        # weighed up to 4 times their tets)
        descs.append(RigidBodyDesc(name=name, vertices=vertices, triangles=triangles,
                                   density=body.density, friction=body.friction,
                                   restitution=body.restitution, point_masses=(piece.x, piece.node_mass)))
    model, state = build_rigid(descs, [])
    for i, (_, _, piece) in enumerate(pieces):
        momentum = piece.weights @ piece.v
        # leapfrog stores the mid-step velocity; reported_velocity adds back half a gravity step
        state.velocity[i] = momentum / model.body_mass[i] - 0.5 * np.asarray(gravity) * last_dt
        r = piece.x - state.position[i]
        state.angular_momentum[i] = np.cross(r, piece.weights[:, None] * piece.v).sum(axis=0)
    return model, state
