"""Build a RigidModel and its initial RigidState from per-body descriptions (done once)."""
from dataclasses import dataclass, field

import numpy as np

from . import quaternion as quat
from .mass import mass_properties
from .model import POINT_FEM_ONLY, POINT_PLAIN, POINT_RING, SHAPE_CODES, RigidModel, RigidState
from .sdf import SignedDistanceGrid
from .shapes import make_shape


@dataclass
class RigidBodyDesc:
    """One rigid body as a scene describes it. Lengths m, density kg/m^3, angles rad.

    shape: primitive dict ({"type": "box", "size": [...]}, ...) or None when ``vertices`` and
    ``triangles`` (closed, outward, in the body's own frame) are given. position/orientation place
    the body's own frame in the world; velocity (m/s) is the centre of mass's, angular_velocity
    (rad/s) is world-frame. point_masses: ``(points (n, 3) m, masses (n,) kg)`` in the shape frame,
    whose mass, centre and inertia the body takes instead of its solid's (a deformable body
    turned rigid keeps the momentum and energy of its lumped node masses exactly); None: the
    solid of ``density``. mass_properties: ``(mass kg, centre (3,) m, inertia (3, 3) kg m^2 about
    it)`` taken as they are (a deformable body with a consistent mass matrix turned rigid keeps the
    momentum and energy of that matrix), instead of point_masses'. contact_points: ``(p, 3)`` shape-frame points of a mesh body that meet
    planes and other bodies' surfaces (None: all its vertices); fem_contact_points: ``(q, 3)``
    more points that meet only FEM surfaces (None: none). grid_cells: cells across the largest extent of a mesh body's
    signed-distance grid (None: the grid's default; fewer build faster, for bodies made during a
    run).
    """
    name: str
    shape: dict = None
    vertices: np.ndarray = None
    triangles: np.ndarray = None
    density: float = 1000.0
    position: tuple = (0.0, 0.0, 0.0)
    orientation: tuple = (1.0, 0.0, 0.0, 0.0)
    velocity: tuple = (0.0, 0.0, 0.0)
    angular_velocity: tuple = (0.0, 0.0, 0.0)
    friction: float = 0.5
    restitution: float = 0.0
    fixed: bool = False
    point_masses: tuple = None
    mass_properties: tuple = None
    grid_cells: int = None
    contact_points: np.ndarray = None
    fem_contact_points: np.ndarray = None


@dataclass
class PlaneDesc:
    """A static half-space: a ``point`` (m) on its surface, its outward ``normal`` (the solid side is
    opposite it), Coulomb ``friction`` and ``restitution``."""
    point: tuple = (0.0, 0.0, 0.0)
    normal: tuple = (0.0, 0.0, 1.0)
    friction: float = 0.5
    restitution: float = 0.0


@dataclass
class _Body:
    vertices: np.ndarray
    triangles: np.ndarray
    kind: int
    params: np.ndarray
    points: np.ndarray          # contact points, shape frame
    point_radius: np.ndarray
    grid: object = None
    extra: dict = field(default_factory=dict)
    point_kind: np.ndarray = None      # RigidModel.point_kind; None: all plain
    point_ring: np.ndarray = None      # ring radius (m) of POINT_RING points
    point_axis: np.ndarray = None      # their axis, shape frame


def _geometry(desc, grids=None):
    """Surface, signed-distance kind and contact points of one body, in its shape frame.
    ``grids``: distance grids built so far, by surface and cell, shared by bodies of one mesh (a
    dict this fills)."""
    if desc.shape is not None:
        vertices, triangles = make_shape(desc.shape)
        kind = desc.shape["type"]
    else:
        vertices, triangles = np.asarray(desc.vertices, float), np.asarray(desc.triangles, np.int64)
        kind = "mesh"
    params = np.zeros(4)
    points = vertices if desc.contact_points is None else np.asarray(desc.contact_points, float)
    radius = np.zeros(len(points))
    grid = None
    if kind == "sphere":
        r = float(desc.shape["radius"])
        params[0] = r
        points, radius = np.zeros((1, 3)), np.array([r])
    elif kind == "box":
        size = np.broadcast_to(np.asarray(desc.shape["size"], float), (3,))
        params[:3] = 0.5 * size
    elif kind == "capsule":
        r, h = float(desc.shape["radius"]), float(desc.shape["height"])
        half = max(0.5 * h - r, 0.0)
        params[:2] = r, half
        # the capsule is the set of points within r of its axis segment: sample the segment
        n = max(2, int(np.ceil(2 * half / (0.5 * r))) + 1)
        points = np.zeros((n, 3))
        points[:, 2] = np.linspace(-half, half, n)
        radius = np.full(n, r)
    elif kind == "cylinder":
        r = float(desc.shape["radius"])
        params[:2] = r, 0.5 * float(desc.shape["height"])
        return _cylinder_rings(_Body(vertices, triangles, SHAPE_CODES[kind], params, points, radius), r)
    else:
        cell = None if desc.grid_cells is None else float(np.ptp(vertices, axis=0).max()) / desc.grid_cells
        key = (vertices.tobytes(), triangles.tobytes(), cell)
        grid = None if grids is None else grids.get(key)
        if grid is None:        # (200 bodies of one mesh file took 30 s to build, a grid each)
            grid = SignedDistanceGrid.build(vertices, triangles, cell_size=cell)
            if grids is not None:
                grids[key] = grid
    body = _Body(vertices, triangles, SHAPE_CODES[kind], params, points, radius, grid)
    if desc.fem_contact_points is not None:
        more = np.asarray(desc.fem_contact_points, float).reshape(-1, 3)
        body.points = np.concatenate([points, more])
        body.point_radius = np.concatenate([radius, np.zeros(len(more))])
        body.point_kind = np.concatenate([np.full(len(points), POINT_PLAIN),
                                          np.full(len(more), POINT_FEM_ONLY)])
    return body


def _cylinder_rings(body, r):
    """A cylinder's vertices on its side (rims and bands) stand, against rigid bodies and planes,
    for the circles they lie on: one ring point per height. On its polygon a cylinder rolled from
    vertex to vertex, losing energy at each (a solid cylinder on a 30 degree slope accelerated at
    3.0 m/s^2 against 3.27) and drifting sideways (0.15 m/s within 1 s)."""
    on_side = np.abs(np.hypot(body.points[:, 0], body.points[:, 1]) - r) <= 1e-9 * r
    heights = np.unique(body.points[on_side, 2])
    rings = np.column_stack([np.zeros((len(heights), 2)), heights])
    count = len(body.points)
    body.points = np.concatenate([body.points, rings])
    body.point_radius = np.zeros(len(body.points))
    body.point_kind = np.concatenate([np.where(on_side, POINT_FEM_ONLY, POINT_PLAIN),
                                      np.full(len(heights), POINT_RING)])
    body.point_ring = np.concatenate([np.zeros(count), np.full(len(heights), r)])
    body.point_axis = np.zeros((len(body.points), 3))
    body.point_axis[count:, 2] = 1.0
    return body


def build_rigid(bodies, planes):
    """RigidModel and initial RigidState from lists of RigidBodyDesc and PlaneDesc."""
    grids = {}
    geo = [_geometry(d, grids) for d in bodies]
    b = len(bodies)
    mass, inertia, axes, com = _principal_frames(bodies, geo)
    fixed = np.array([d.fixed for d in bodies], dtype=bool)
    # body frame = principal frame at the centre of mass: p_shape = A p_body + com
    to_body = lambda i, p: (np.asarray(p) - com[i]) @ axes[i]
    local_points = [to_body(i, g.points) for i, g in enumerate(geo)]
    model = RigidModel(
        names=[d.name for d in bodies], body_mass=np.where(fixed, np.inf, mass),
        body_inv_mass=np.where(fixed, 0.0, 1.0 / mass), body_inertia=inertia,
        body_inv_inertia=np.where(fixed[:, None], 0.0, 1.0 / inertia),
        body_fixed=fixed, body_friction=np.array([d.friction for d in bodies], float),
        body_restitution=np.array([d.restitution for d in bodies], float),
        body_radius=np.array([np.max(np.linalg.norm(p, axis=1) + g.point_radius)
                              for p, g in zip(local_points, geo)]) if b else np.zeros(0),
        shape_kind=np.array([g.kind for g in geo], dtype=np.int64),
        shape_params=np.array([g.params for g in geo]).reshape(b, 4),
        shape_rotation=axes, shape_offset=com, **_grids(geo), **_contact_points(geo, axes, local_points),
        surface_vertices=[to_body(i, g.vertices) for i, g in enumerate(geo)],
        surface_triangles=[g.triangles for g in geo],
        plane_point=np.array([p.point for p in planes], float).reshape(-1, 3),
        plane_normal=np.array([np.asarray(p.normal, float) / np.linalg.norm(p.normal) for p in planes]).reshape(-1, 3),
        plane_friction=np.array([p.friction for p in planes], float),
        plane_restitution=np.array([p.restitution for p in planes], float),
        body_min_extent=np.array([np.min(np.ptp(g.vertices, axis=0)) for g in geo]) if b else np.zeros(0))
    return model, _initial_state(bodies, fixed, inertia, axes, com)


def _principal_frames(bodies, geo):
    """Mass (b,) kg, principal moments (b, 3) kg m^2, principal axes (b, 3, 3) (columns, shape
    frame, proper) and centre of mass (b, 3) m (shape frame) of every body."""
    b = len(bodies)
    mass, inertia = np.zeros(b), np.zeros((b, 3))
    axes, com = np.zeros((b, 3, 3)), np.zeros((b, 3))
    for i, (d, g) in enumerate(zip(bodies, geo)):
        if d.mass_properties is not None:
            mass[i], com[i], I = d.mass_properties
        elif d.point_masses is None:
            props = mass_properties(g.vertices, g.triangles, d.density)
            mass[i], com[i], I = props.mass, props.com, props.inertia
        else:
            mass[i], com[i], I = _point_mass_properties(*d.point_masses)
        off = np.abs(I - np.diag(np.diag(I))).max()
        if off <= 1e-12 * np.abs(I).max():
            inertia[i], axes[i] = np.diag(I), np.eye(3)   # keep the user's axes when already principal
        else:
            inertia[i], axes[i] = np.linalg.eigh(I)
            if np.linalg.det(axes[i]) < 0:
                axes[i][:, 2] *= -1
        if d.point_masses is None and d.mass_properties is None and not (mass[i] > 0 and np.isfinite(inertia[i]).all()
                                           and np.all(inertia[i] > 1e-12 * inertia[i].max())):
            # a box 1e8 m long and 1 m thick: its moment about the long axis, a difference of
            # terms 1e16 times larger, came out 0, and the first step divided by it
            raise ValueError(f"its mass ({mass[i]:.3g} kg) and principal moments of inertia "
                             f"({', '.join(f'{x:.3g}' for x in inertia[i])} kg m^2) are beyond double "
                             f"precision (the least not positive, or under 1e-12 of the largest): a "
                             f"shape this thin for its length, or this large, cannot be stepped")
    return mass, inertia, axes, com


def _point_mass_properties(points, masses):
    """Mass (kg), centre of mass (3,) m and inertia (3, 3) kg m^2 about it of point masses."""
    points, masses = np.asarray(points, float), np.asarray(masses, float)
    total = masses.sum()
    com = masses @ points / total
    r = points - com
    inertia = np.eye(3) * (masses @ np.einsum("ni,ni->n", r, r)) - np.einsum("n,ni,nj->ij", masses, r, r)
    return total, com, inertia


def _contact_points(geo, axes, local_points):
    """RigidModel's point_* fields: every body's contact points (``local_points``, body frame)
    one after the other, with their radii, kinds, ring radii and axes (turned into the body frame)."""
    if not geo:
        return dict(point_body=np.zeros(0, np.int64), point_local=np.zeros((0, 3)),
                    point_radius=np.zeros(0), point_kind=np.zeros(0, np.int64),
                    point_ring=np.zeros(0), point_axis=np.zeros((0, 3)))
    return dict(
        point_body=np.repeat(np.arange(len(geo)), [len(p) for p in local_points]),
        point_local=np.concatenate(local_points),
        point_radius=np.concatenate([g.point_radius for g in geo]),
        point_kind=np.concatenate([np.full(len(g.points), POINT_PLAIN) if g.point_kind is None
                                   else g.point_kind for g in geo]).astype(np.int64),
        point_ring=np.concatenate([np.zeros(len(g.points)) if g.point_ring is None else g.point_ring
                                   for g in geo]),
        point_axis=np.concatenate([np.zeros((len(g.points), 3)) if g.point_axis is None
                                   else g.point_axis @ axes[i] for i, g in enumerate(geo)]))


def _grids(geo):
    """RigidModel's grid_index and flat grid_* fields for the bodies whose distance is a grid."""
    grids, index_of = [], {}            # a grid shared by several bodies is stored once
    grid_index = np.full(len(geo), -1, dtype=np.int64)
    for i, g in enumerate(geo):
        if g.grid is not None:
            if id(g.grid) not in index_of:
                index_of[id(g.grid)] = len(grids)
                grids.append(g.grid)
            grid_index[i] = index_of[id(g.grid)]
    if not grids:
        return dict(grid_index=grid_index, grid_values=np.zeros(1), grid_start=np.zeros(1, np.int64),
                    grid_shape=np.ones((1, 3), np.int64), grid_origin=np.zeros((1, 3)),
                    grid_cell=np.ones(1))
    sizes = [int(np.prod(gr.shape)) for gr in grids]
    return dict(grid_index=grid_index, grid_values=np.concatenate([gr.values.ravel() for gr in grids]),
                grid_start=np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64),
                grid_shape=np.array([gr.shape for gr in grids], dtype=np.int64).reshape(-1, 3),
                grid_origin=np.array([gr.origin for gr in grids]).reshape(-1, 3),
                grid_cell=np.array([gr.cell_size for gr in grids], float))


def _initial_state(bodies, fixed, inertia, axes, com):
    """RigidState at the user's poses: the user places the shape frame; the state holds the pose
    of the principal frame at the centre of mass."""
    b = len(bodies)
    q_user = quat.normalize(np.array([d.orientation for d in bodies], float).reshape(b, 4))
    R_user = quat.to_matrix(q_user)
    position = np.array([d.position for d in bodies], float).reshape(b, 3) + np.einsum("bij,bj->bi", R_user, com)
    orientation = quat.normalize(quat.multiply(q_user, quat.from_matrix(axes))) if b else np.zeros((0, 4))
    R = quat.to_matrix(orientation)
    w = np.array([d.angular_velocity for d in bodies], float).reshape(b, 3)
    I_world = np.einsum("bij,bj,bkj->bik", R, inertia, R)
    L = np.where(fixed[:, None], 0.0, np.einsum("bij,bj->bi", I_world, w))
    v = np.where(fixed[:, None], 0.0, np.array([d.velocity for d in bodies], float).reshape(b, 3))
    return RigidState(position=position, orientation=orientation, velocity=v, angular_momentum=L,
                      contact_dv=np.zeros((b, 3)))
