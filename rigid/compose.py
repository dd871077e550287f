"""Rigid models put together and taken apart: bodies appended (fracture pieces, auto bodies turned
rigid) or removed (auto bodies turned deformable), planes kept.

    model, state = append_bodies(model, state, new_model, new_state)
    model, state = take_bodies(model, state, keep)
"""
from dataclasses import replace

import numpy as np

from .model import RigidState

# RigidModel fields with one row per body, in the order bodies are numbered
PER_BODY = ("body_mass", "body_inv_mass", "body_inertia", "body_inv_inertia", "body_fixed",
            "body_friction", "body_restitution", "body_radius", "shape_kind", "shape_params",
            "shape_rotation", "shape_offset", "body_min_extent")
# ... and with one row per contact point (point_body says whose)
PER_POINT = ("point_local", "point_radius", "point_kind", "point_ring", "point_axis")
STATE_FIELDS = ("position", "orientation", "velocity", "angular_momentum", "contact_dv")


def _grids(model):
    """The signed-distance grids of ``model``'s bodies: per body ``(values, shape, origin, cell)``
    or None for an analytic shape."""
    out = []
    for g in model.grid_index:
        if g < 0:
            out.append(None)
            continue
        start, shape = int(model.grid_start[g]), model.grid_shape[g]
        out.append((model.grid_values[start:start + int(np.prod(shape))], shape,
                    model.grid_origin[g], model.grid_cell[g]))
    return out


def _grid_fields(grids):
    """RigidModel's grid_* fields holding ``grids`` (as :func:`_grids` gives them)."""
    kept = [g for g in grids if g is not None]
    index = np.full(len(grids), -1, dtype=np.int64)
    index[[i for i, g in enumerate(grids) if g is not None]] = np.arange(len(kept))
    if not kept:
        return dict(grid_index=index, grid_values=np.zeros(1), grid_start=np.zeros(1, np.int64),
                    grid_shape=np.ones((1, 3), np.int64), grid_origin=np.zeros((1, 3)),
                    grid_cell=np.ones(1))
    sizes = [len(g[0]) for g in kept]
    return dict(grid_index=index, grid_values=np.concatenate([g[0] for g in kept]),
                grid_start=np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64),
                grid_shape=np.array([g[1] for g in kept], dtype=np.int64).reshape(-1, 3),
                grid_origin=np.array([g[2] for g in kept], float).reshape(-1, 3),
                grid_cell=np.array([g[3] for g in kept], float))


def append_bodies(rm, rs, new_model, new_state):
    """RigidModel/RigidState with the bodies of ``new_model``/``new_state`` appended (the planes
    of ``rm`` kept; ``rs``'s time and last step)."""
    changes = {k: np.concatenate([getattr(rm, k), getattr(new_model, k)]) for k in PER_BODY + PER_POINT}
    changes["names"] = list(rm.names) + list(new_model.names)
    changes["surface_vertices"] = list(rm.surface_vertices) + list(new_model.surface_vertices)
    changes["surface_triangles"] = list(rm.surface_triangles) + list(new_model.surface_triangles)
    changes["point_body"] = np.concatenate([rm.point_body, new_model.point_body + rm.body_count])
    model = replace(rm, **changes, **_grid_fields(_grids(rm) + _grids(new_model)))
    state = RigidState(*(np.concatenate([getattr(rs, k), getattr(new_state, k)])
                         for k in STATE_FIELDS), time=rs.time, last_dt=rs.last_dt)
    return model, state


def take_bodies(rm, rs, keep):
    """RigidModel/RigidState of the bodies ``keep`` (ascending indices) only, renumbered in that
    order (the planes kept)."""
    keep = np.asarray(keep, dtype=np.int64)
    renumber = -np.ones(rm.body_count, dtype=np.int64)
    renumber[keep] = np.arange(len(keep))
    points = np.isin(rm.point_body, keep)
    changes = {k: getattr(rm, k)[keep] for k in PER_BODY}
    changes |= {k: getattr(rm, k)[points] for k in PER_POINT}
    changes["names"] = [rm.names[i] for i in keep]
    changes["surface_vertices"] = [rm.surface_vertices[i] for i in keep]
    changes["surface_triangles"] = [rm.surface_triangles[i] for i in keep]
    changes["point_body"] = renumber[rm.point_body[points]]
    grids = _grids(rm)
    model = replace(rm, **changes, **_grid_fields([grids[i] for i in keep]))
    state = RigidState(*(getattr(rs, k)[keep].copy() for k in STATE_FIELDS), time=rs.time,
                       last_dt=rs.last_dt)
    return model, state
