"""Build the coupled model and its initial state from a validated scene (done once per run).

:func:`build` also warms up the compiled (numba) kernels the scene's step will call (:func:`warm_up`):
a tiny scene with the same kinds of bodies and contacts is built and stepped a few times, so the
kernels are compiled, or loaded from numba's on-disk cache, before the step loop instead of at
the first contact inside it.
"""
import logging
import os
import time

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


def build(scene, warm=True):
    """HybridModel and initial HybridState of ``scene``; with ``warm``, after :func:`warm_up`."""
    model, state = _build(scene)
    if warm and not _warming:
        warm_up(scene)
    return model, state


def _build(scene):
    """HybridModel and initial HybridState of ``scene`` (no warm-up)."""
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


# -- warm-up of the compiled kernels -----------------------------------------------------------
log = logging.getLogger(__name__)

# The warm-up kinds already stepped in this process (numba keeps what it compiled or loaded), and
# whether a warm-up is under way (its own scene is not warmed up).
_WARMED = set()
_warming = False
WARM_STEPS = 3
_WARM_SIZE = 0.1        # m, edge of a warm-up FEM box (2 x 2 x 2 cells)
_WARM_VELOCITY = [0.0, 0.0, -0.2]       # m/s, of every warm-up body: an impact at the first step
_GEOMETRY_KEYS = ("name", "shape", "mesh", "position", "orientation", "velocity", "angular_velocity",
                  "anchors", "loads", "unbreakable", "fixed")


# The scene fields of an FEM or auto body that choose which kernels its step calls: by value
# (choices) or by whether they are given (optional physics).
_KIND_CHOICES = ("model", "frame", "order", "integrator", "mass_matrix", "fragment_model")
_KIND_GIVEN = ("yield_stress", "fracture_stress", "tearing_strain", "max_plastic_strain", "damping")


def _fem_kind(raw):
    """What decides which kernels an FEM or auto body's step calls: its choices (model, frame,
    order, integrator, ...), which optional physics it has (plasticity, fracture, ...), not their
    values, and whether it is held or loaded."""
    return (tuple(raw.get(k) for k in _KIND_CHOICES), tuple(k in raw for k in _KIND_GIVEN),
            bool(raw.get("anchors")), bool(raw.get("loads")))


def _warm_kinds(scene):
    """The warm-up kinds of ``scene``: ``("plane",)``, ``("rigid", shape type)`` and
    ``("fem", kind)`` entries, each with the raw table it stands for."""
    kinds = {}
    if scene.planes:
        kinds[("plane",)] = None
    raws = scene.raw.get("bodies", [])
    for body, raw in zip(scene.bodies, raws):
        if body.model == "rigid":
            shape = body.shape.type if body.shape is not None else "box"    # a mesh body: a box
            kinds.setdefault(("rigid", shape), raw)
        else:
            kinds.setdefault(("fem",) + _fem_kind(raw), raw)
    return kinds


def _warm_scene(scene, kinds):
    """The scene data of the warm-up: per FEM kind a 0.1 m box resting on the ground (a rigid box
    resting on it when the scene has rigid bodies), per rigid shape a small body resting on the
    ground (a box on a box), all touching from the start and moving into each other (so that
    impacts as well as resting contacts are met)."""
    h = _WARM_SIZE
    rigid_shapes = [k[1] for k in kinds if k[0] == "rigid"]
    bodies, x = [], 0.0
    for key, raw in kinds.items():
        if key[0] != "fem":
            continue
        table = {k: v for k, v in raw.items() if k not in _GEOMETRY_KEYS}
        table |= {"name": f"fem{len(bodies)}", "position": [x, 0.0, 0.5 * h], "velocity": _WARM_VELOCITY,
                  "shape": {"type": "box", "size": [h, h, h], "resolution": 0.5 * h}}
        if key[3]:
            table["anchors"] = [{"box": [[-1.0, -1.0, -0.5 * h - 1e-6], [1.0, 1.0, -0.5 * h + 1e-6]]}]
        if key[4]:
            table["loads"] = [{"box": [[-1.0, -1.0, 0.5 * h - 1e-6], [1.0, 1.0, 0.5 * h + 1e-6]],
                               "force": [0.0, 0.0, -1e-3]}]
        bodies.append(table)
        if rigid_shapes:
            bodies.append({"name": f"on_fem{len(bodies)}", "density": 100.0,
                           "shape": {"type": "box", "size": [0.5 * h] * 3},
                           "position": [x, 0.0, 1.25 * h], "velocity": _WARM_VELOCITY})
        x += 2 * h
    for shape in rigid_shapes:
        size = {"box": {"size": [0.5 * h] * 3}, "sphere": {"radius": 0.25 * h},
                "capsule": {"radius": 0.1 * h, "height": 0.5 * h},
                "cylinder": {"radius": 0.25 * h, "height": 0.5 * h}}[shape]
        low = 0.25 * h if shape != "capsule" else 0.1 * h
        bodies.append({"name": f"rigid_{shape}", "density": 100.0, "shape": {"type": shape} | size,
                       "position": [x, 0.0, low], "velocity": _WARM_VELOCITY})
        if shape == "box":
            bodies.append({"name": "rigid_box_on_box", "density": 100.0, "shape": {"type": "box"} | size,
                           "position": [x, 0.0, 0.75 * h], "velocity": [0.0, 0.0, -0.4]})
        x += 2 * h
    sim = scene.raw.get("simulation", {})
    data = {"simulation": {k: v for k, v in sim.items() if k in ("dt", "solver")} | {"name": "warm_up"},
            "bodies": bodies}
    if scene.planes:
        data["planes"] = [{"point": [0.0, 0.0, 0.0], "normal": [0.0, 0.0, 1.0]}]
    if data["simulation"].get("dt", 0.0) > 0.01:
        data["simulation"]["dt"] = 0.01
    data["simulation"]["duration"] = 1.0
    return data


def warm_up(scene):
    """Compile, or load from numba's on-disk cache, the kernels running ``scene`` calls: run
    (:class:`hybrid.simulation.Simulation`, :data:`WARM_STEPS` steps, no output folder, then the
    fields of a frame) a tiny scene with one small body of each of its kinds of FEM body and
    rigid shape, resting on the ground and on each other. Kinds warmed once in a process are not
    warmed again, and none is with the environment variable ``HYBRID_NO_WARM_UP=1``. Never
    raises: a warm-up that fails leaves the compilation to the step loop (logged at debug
    level). Returns the seconds it took."""
    global _warming
    from hybrid.app.observe import frame_pieces
    from hybrid.app.scene import parse_scene
    from hybrid.simulation import Simulation

    if os.environ.get("HYBRID_NO_WARM_UP", "") not in ("", "0"):
        return 0.0
    kinds = {k: v for k, v in _warm_kinds(scene).items() if k not in _WARMED}
    if not any(k[0] in ("fem", "rigid") for k in kinds):
        return 0.0
    start = time.perf_counter()
    _warming = True
    try:
        sim = Simulation(parse_scene(_warm_scene(scene, kinds), "<warm-up>", "."))
        with np.errstate(all="ignore"):
            sim.run(until=WARM_STEPS * sim.dt, progress=False, log=lambda message: None,
                    checkpoint_every=0)
            frame_pieces(sim.model, sim.state)
    except Exception as error:      # noqa: BLE001 (an optimisation: never stops a run)
        log.debug("kernel warm-up skipped: %s", error)
    finally:
        _warming = False
    _WARMED.update(kinds)
    return time.perf_counter() - start
