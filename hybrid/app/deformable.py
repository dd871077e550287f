"""FEM bodies of a scene: building them from scene fields (the coupling lives in hybrid.coupling.step)."""
import numpy as np

from fem.mesh import (box_tet_mesh, check_tets, cylinder_tet_mesh, quadratic_tets,
                      select_nodes_in_box, sphere_tet_mesh)
from fem.model import build_fem_model, rest_state
from rigid import quaternion as quat

from . import geometry
from .scene.describe import toml_text


def default_resolution(shape):
    """Edge length (m) an FEM body's shape is meshed at when the scene gives no ``resolution``:
    a third of a box's shortest side, half a radius."""
    return float(min(shape.size)) / 3 if shape.type == "box" else shape.radius / 2


def _tet_mesh(body):
    """Rest tet mesh of a body in its own frame: (points, tets, order of the file)."""
    if body.mesh is not None:
        return geometry.load_tet_mesh(body.mesh)
    s = body.shape
    h = s.resolution or default_resolution(s)
    # the fem.mesh generators take cell counts; scene resolutions are edge lengths in metres
    if s.type == "box":
        size = np.broadcast_to(np.asarray(s.size, float), (3,))
        points, tets = box_tet_mesh(size, np.maximum(1, np.ceil(size / h - 1e-9)).astype(int))
    elif s.type == "sphere":
        points, tets = sphere_tet_mesh(s.radius, 2 * s.radius / h)
    elif s.type == "cylinder":
        points, tets = cylinder_tet_mesh(s.radius, s.height, 2 * s.radius / h)
    else:
        raise ValueError(f"FEM bodies support box, sphere and cylinder shapes or a tet mesh, "
                         f"not '{s.type}'")
    return points, tets, 1


def build_bodies(bodies, dt, *, linear_solver="cholmod", corotated_solver="cg", indices=None):
    """FemModel and initial FemState of each FEM body (in scene order).

    linear_solver ("cholmod" | "superlu") and corotated_solver ("cg" | "lu") are the scene's
    ``[simulation.solver]`` choices, the same for every body. ``indices`` are the bodies' places
    in the scene's ``[[bodies]]`` (default 0, 1, ...), for messages. A body that cannot be built
    raises ValueError naming it and the field at fault, as the scene loader words problems."""
    models, states = [], []
    for k, body in enumerate(bodies):
        label = body_label(body, k if indices is None else indices[k])
        model = _build_model(body, label, dt, linear_solver, corotated_solver)
        x = model.rest_points
        w = np.asarray(body.angular_velocity, float)
        center = np.average(x, axis=0, weights=model.node_mass)
        v = np.asarray(body.velocity, float) + np.cross(w, x - center)
        models.append(model)
        states.append(rest_state(model, v=v))
    return models, states


def body_label(body, index):
    """How scene problems name a body: ``[bodies] "name" (bodies[index])``."""
    return f"[bodies] {toml_text(body.name)} (bodies[{index}])"


def _build_model(body, label, dt, linear_solver, corotated_solver):
    """The FemModel of one body; ValueError naming the field that makes it unbuildable."""
    source = "mesh" if body.mesh is not None else "shape"
    try:
        points, tets, file_order = _tet_mesh(body)
    except ValueError as error:
        raise ValueError(f"{label}: field '{source}' cannot be meshed: {error}") from None
    if file_order == 2 and body.order == 1:
        tets = tets[:, :4]
        points = points[: tets.max() + 1]
    if body.order == 2 and tets.shape[1] == 4:
        # the midside nodes first, so anchor and load boxes take them too (selected on the
        # corners alone, a clamped P2 beam's clamp face moved 0.18 mm and its tip sagged 10% more)
        points, tets = quadratic_tets(points, tets)
    anchors = _regions(body, label, "anchors", points)
    loads = _regions(body, label, "loads", points)
    # the rest shape is the placed one: rotate by `orientation`, move by `position`
    R = quat.to_matrix(np.asarray(body.orientation, float))
    placed = points @ R.T + np.asarray(body.position, float)
    try:
        return build_fem_model(placed, tets, order=body.order, density=body.density,
                               young=body.young, poisson=body.poisson,
                               damping_mass=body.damping.mass, damping_stiffness=body.damping.stiffness,
                               frame=body.frame, mass=body.mass_matrix, integrator=body.integrator,
                               anchors=anchors, loads=loads, dt=dt, yield_stress=body.yield_stress,
                               plastic_update_strain=body.plastic_update_strain,
                               max_plastic_strain=body.max_plastic_strain,
                               linear_solver=linear_solver, corotated_solver=corotated_solver)
    except ValueError as error:
        raise ValueError(f"{label}: {_culprit(points, tets, body, source)}: {error}") from None


def _culprit(points, tets, body, source):
    """Which field spoilt a mesh that failed once placed: ``position`` when the unplaced mesh is
    sound (placed far from the origin, doubles no longer resolve its tets), else its source."""
    try:
        check_tets(points, tets)
    except ValueError:
        return f"field '{source}' gives an unusable mesh"
    extent = float(np.ptp(points, axis=0).max())
    return (f"field 'position' is too far from the origin for a body {extent:.3g} m across (its "
            f"tets lose their volume in double precision)")


def _regions(body, label, what, points):
    """(nodes, vector) of each anchor or load box; ValueError for a box holding no node."""
    regions = getattr(body, what)
    found = [(select_nodes_in_box(points, r.box[0], r.box[1]), r.velocity if what == "anchors" else r.force)
             for r in regions]
    for k, (nodes, _) in enumerate(found):
        if len(nodes) == 0:
            low, high = (np.round(e, 6).tolist() for e in (points.min(axis=0), points.max(axis=0)))
            raise ValueError(f"{label}: field '{what}': [[bodies.{what}]] {k} box "
                             f"{list(map(list, regions[k].box))} contains no mesh node (boxes are in "
                             f"the body's own coordinates, where its mesh spans {low} to {high})")
    return found
