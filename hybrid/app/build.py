"""Build the coupled model and its initial state from a validated scene (done once per run)."""
import numpy as np

from rigid.build import PlaneDesc, RigidBodyDesc, build_rigid
from rigid.step import ContactSettings

from hybrid.coupling.model import HybridModel, HybridState

from . import deformable, geometry


def _shape_dict(shape):
    d = {"type": shape.type}
    for key in ("size", "radius", "height", "resolution"):
        value = getattr(shape, key)
        if value is not None:
            d[key] = list(value) if isinstance(value, tuple) else value
    return d


def rigid_desc(body):
    """RigidBodyDesc of a scene body (reads its mesh when it has one)."""
    desc = RigidBodyDesc(name=body.name, density=body.density, position=body.position,
                         orientation=body.orientation, velocity=body.velocity,
                         angular_velocity=body.angular_velocity, friction=body.friction,
                         restitution=body.restitution, fixed=body.fixed)
    if body.shape is not None:
        desc.shape = _shape_dict(body.shape)
    else:
        desc.vertices, desc.triangles = geometry.load_surface(body.mesh)
    return desc


def _build_rigid(bodies, planes, index):
    """build_rigid of the scene's rigid bodies; ValueError naming the body and field that cannot be
    built (found by building each body alone, on this failure path only)."""
    descs = [rigid_desc(b) for b in bodies]
    try:
        return build_rigid(descs, planes)
    except ValueError:
        for body, desc in zip(bodies, descs):
            try:
                build_rigid([desc], [])
            except ValueError as error:
                field = "mesh" if body.mesh is not None else "shape"
                raise ValueError(f"{deformable.body_label(body, index[body.name])}: field '{field}' "
                                 f"gives an unusable body: {error}") from None
        raise


def build(scene):
    """HybridModel and initial HybridState of ``scene``."""
    sim = scene.simulation
    rigid_bodies = [b for b in scene.bodies if b.model == "rigid"]
    fem_bodies = [b for b in scene.bodies if b.model != "rigid"]
    planes = [PlaneDesc(p.point, p.normal, p.friction, p.restitution) for p in scene.planes]
    index = {b.name: i for i, b in enumerate(scene.bodies)}
    rigid_model, rigid_state = _build_rigid(rigid_bodies, planes, index)
    fem_models, fem_states = deformable.build_bodies(
        fem_bodies, sim.dt, linear_solver=sim.solver.linear_solver,
        corotated_solver=sim.solver.corotated_solver, indices=[index[b.name] for b in fem_bodies])
    settings = ContactSettings(iterations=sim.solver.iterations,
                               deformable_iterations=sim.solver.deformable_iterations,
                               margin=sim.solver.contact_margin,
                               hold_resting=sim.solver.hold_resting)
    model = HybridModel(rigid=rigid_model, rigid_ids=np.array([index[b.name] for b in rigid_bodies], dtype=int),
                        fem=fem_models, fem_ids=[index[b.name] for b in fem_bodies],
                        names=[b.name for b in scene.bodies], gravity=np.asarray(sim.gravity, float),
                        dt=sim.dt, settings=settings, scene=scene,
                        fragment_of=list(range(len(scene.bodies))))
    return model, HybridState(rigid=rigid_state, fem=fem_states)
