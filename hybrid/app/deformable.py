"""FEM bodies of a scene: building them from scene fields (the coupling lives in hybrid.coupling.step)."""
import numpy as np

from fem.mesh import (box_tet_mesh, cylinder_tet_mesh, quadratic_tets, select_nodes_in_box,
                      sphere_tet_mesh)
from fem.model import build_fem_model, rest_state
from rigid import quaternion as quat

from . import geometry


def _tet_mesh(body):
    """Rest tet mesh of a body in its own frame: (points, tets, order of the file)."""
    if body.mesh is not None:
        return geometry.load_tet_mesh(body.mesh)
    s = body.shape
    resolution = s.resolution
    # the fem.mesh generators take cell counts; scene resolutions are edge lengths in metres
    if s.type == "box":
        size = np.broadcast_to(np.asarray(s.size, float), (3,))
        h = resolution or float(np.min(size)) / 3
        points, tets = box_tet_mesh(size, np.maximum(1, np.ceil(size / h - 1e-9)).astype(int))
    elif s.type == "sphere":
        h = resolution or s.radius / 2
        points, tets = sphere_tet_mesh(s.radius, 2 * s.radius / h)
    elif s.type == "cylinder":
        h = resolution or s.radius / 2
        points, tets = cylinder_tet_mesh(s.radius, s.height, 2 * s.radius / h)
    else:
        raise ValueError(f"body '{body.name}': FEM bodies support box, sphere and cylinder shapes "
                         f"or a tet mesh, not '{s.type}'")
    return points, tets, 1


def build_bodies(bodies, dt, *, linear_solver="cholmod", corotated_solver="cg"):
    """FemModel and initial FemState of each FEM body (in scene order).

    linear_solver ("cholmod" | "superlu") and corotated_solver ("cg" | "lu") are the scene's
    ``[simulation.solver]`` choices, the same for every body."""
    models, states = [], []
    for body in bodies:
        points, tets, file_order = _tet_mesh(body)
        if file_order == 2 and body.order == 1:
            tets = tets[:, :4]
            points = points[: tets.max() + 1]
        if body.order == 2 and tets.shape[1] == 4:
            # the midside nodes first, so anchor and load boxes take them too (selected on the
            # corners alone, a clamped P2 beam's clamp face moved 0.18 mm and its tip sagged 10% more)
            points, tets = quadratic_tets(points, tets)
        anchors = [(select_nodes_in_box(points, a.box[0], a.box[1]), a.velocity) for a in body.anchors]
        loads = [(select_nodes_in_box(points, l.box[0], l.box[1]), l.force) for l in body.loads]
        for what, regions in (("anchors", body.anchors), ("loads", body.loads)):
            for k, (nodes, _) in enumerate(anchors if what == "anchors" else loads):
                if len(np.atleast_1d(np.nonzero(nodes)[0] if np.asarray(nodes).dtype == bool else nodes)) == 0:
                    low, high = (np.round(e, 6).tolist() for e in (points.min(axis=0), points.max(axis=0)))
                    raise ValueError(f"body '{body.name}': [[bodies.{what}]] {k} box "
                                     f"{list(map(list, regions[k].box))} contains no mesh node (boxes "
                                     f"are in the body's own coordinates, where its mesh spans {low} "
                                     f"to {high})")
        # the rest shape is the placed one: rotate by `orientation`, move by `position`
        R = quat.to_matrix(np.asarray(body.orientation, float))
        placed = points @ R.T + np.asarray(body.position, float)
        loads = [(nodes, force) for nodes, force in loads]
        model = build_fem_model(placed, tets, order=body.order, density=body.density,
                                young=body.young, poisson=body.poisson,
                                damping_mass=body.damping.mass, damping_stiffness=body.damping.stiffness,
                                frame=body.frame, mass=body.mass_matrix, integrator=body.integrator,
                                anchors=anchors, loads=loads, dt=dt, yield_stress=body.yield_stress,
                                plastic_update_strain=body.plastic_update_strain,
                                max_plastic_strain=body.max_plastic_strain,
                                linear_solver=linear_solver, corotated_solver=corotated_solver)
        x = model.rest_points
        w = np.asarray(body.angular_velocity, float)
        center = np.average(x, axis=0, weights=model.node_mass)
        v = np.asarray(body.velocity, float) + np.cross(w, x - center)
        models.append(model)
        states.append(rest_state(model, v=v))
    return models, states
