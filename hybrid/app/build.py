"""Build the coupled model and its initial state from a validated scene (done once per run).

:func:`build` also warms up the compiled (numba) kernels the scene's step will call (:func:`warm_up`):
a tiny scene with the same kinds of bodies and contacts is built and stepped a few times, so the
kernels are compiled, or loaded from numba's on-disk cache, before the step loop instead of at
the first contact inside it.
"""
import functools
import logging
import os
import time

import numpy as np

from rigid.build import PlaneDesc, RigidBodyDesc, build_rigid
from rigid.contacts import combine_friction
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


# A rigid box meets deformable faces at its own sample points, its surface vertices, and at their
# nodes under it. Resting on the nodes alone, its support moves with the deformable body, and with
# nothing holding the two sideways that runs away: a 1,800 kg box on a frictionless 1.8 kg slab on
# frictionless ground was turned by the slab sliding under it, its tilt pushed the slab sideways
# (M / m times harder than it pushes the box), and the slab was squeezed out within 0.4 s. So a
# moving box without a `resolution` that weighs more than HEAVY times a deformable body it meets
# with a friction coefficient under SLIPPERY has sample points no further apart than FACE_SAMPLING
# of the deformable surfaces' edges (the finest body's median edge), at most MAX_FACE_SEGMENTS
# segments along an edge: more of its load sits at its own points. Other boxes keep the coarse
# default: friction holds the slab (the same scene with friction 0.5 rests), at equal masses the
# slide pushes it 1,000 times more gently, and the extra contacts cost solver time (5x on that
# scene with friction, about 5x).
HEAVY = 10.0
SLIPPERY = 0.01
FACE_SAMPLING = 0.4
MAX_FACE_SEGMENTS = 32


def face_sampling(fem_models, fem_bodies):
    """What :func:`rigid_desc` needs of the deformable bodies (scene bodies ``fem_bodies``, built
    into ``fem_models``): (spacing m, [(mass kg, friction)] per body), the spacing FACE_SAMPLING of
    the finest body's median surface edge; None without any."""
    edges = [np.median(np.linalg.norm(m.rest_points[m.surface] - m.rest_points[np.roll(m.surface, 1, axis=1)],
                                      axis=2)) for m in fem_models if len(m.surface)]
    if not edges:
        return None
    return FACE_SAMPLING * float(min(edges)), [(float(m.node_mass.sum()), b.friction)
                                               for m, b in zip(fem_models, fem_bodies)]


def _slides_on_light(body, sampling):
    """Whether rigid ``body`` outweighs (HEAVY) a deformable body it meets nearly without friction
    (SLIPPERY); ``sampling``: :func:`face_sampling`."""
    if body.fixed or body.shape is None or body.shape.type != "box" or sampling is None:
        return False
    mass = body.density * float(np.prod(body.shape.size))
    return any(mass > HEAVY * m and combine_friction(body.friction, mu) < SLIPPERY for m, mu in sampling[1])


def rigid_desc(body, sampling=None):
    """RigidBodyDesc of a scene body (reads its mesh when it has one); ``sampling``: the deformable
    bodies' :func:`face_sampling`, for the sample points of a heavy, slippery box without a
    `resolution`."""
    desc = RigidBodyDesc(name=body.name, density=body.density, position=body.position,
                         orientation=body.orientation, velocity=body.velocity,
                         angular_velocity=body.angular_velocity, friction=body.friction,
                         restitution=body.restitution, fixed=body.fixed)
    if body.shape is not None:
        desc.shape = _shape_dict(body.shape)
        if body.shape.resolution is None and _slides_on_light(body, sampling):
            longest = max(body.shape.size)
            desc.shape["resolution"] = min(0.5 * longest, max(sampling[0], longest / MAX_FACE_SEGMENTS))
    else:
        desc.vertices, desc.triangles = geometry.load_surface(body.mesh)
    return desc


def _build_rigid(bodies, planes, index, sampling=None):
    """build_rigid of the scene's rigid bodies (``sampling``: :func:`rigid_desc`); ValueError naming
    the body and field that cannot be built (found by building each body alone, on this failure
    path only)."""
    descs = [rigid_desc(b, sampling) for b in bodies]
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
    if warm:
        warm_up(scene)
    return model, state


def _build(scene):
    """HybridModel and initial HybridState of ``scene`` (no warm-up)."""
    sim = scene.simulation
    rigid_bodies = [b for b in scene.bodies if b.model == "rigid"]
    fem_bodies = [b for b in scene.bodies if b.model != "rigid"]
    planes = [PlaneDesc(p.point, p.normal, p.friction, p.restitution) for p in scene.planes]
    index = {b.name: i for i, b in enumerate(scene.bodies)}
    fem_models, fem_states = deformable.build_bodies(
        fem_bodies, sim.dt, linear_solver=sim.solver.linear_solver,
        corotated_solver=sim.solver.corotated_solver, indices=[index[b.name] for b in fem_bodies])
    rigid_model, rigid_state = _build_rigid(rigid_bodies, planes, index, face_sampling(fem_models, fem_bodies))
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

WARM_STEPS = 3
WARM_SOURCE = "<warm-up>"               # the warm-up scene's source name (it is not warmed up itself)
_WARM_SIZE = 0.1        # m, edge of a warm-up FEM box (2 x 2 x 2 cells)
_WARM_VELOCITY = [0.0, 0.0, -0.2]       # m/s, of every warm-up body: an impact at the first step
# The scene fields of an FEM or auto body that choose which kernels its step calls: by value
# (choices) or by whether they are given (optional physics, warmed with the values below).
_KIND_CHOICES = ("model", "frame", "order", "integrator", "mass_matrix", "fragment_model")
_KIND_GIVEN = {"yield_stress": 2e3, "fracture_stress": 1e12, "tearing_strain": 10.0,
               "max_plastic_strain": 1.0, "damping": {"mass": 1.0, "stiffness": 1e-3}}


def _fem_kind(raw):
    """What decides which kernels an FEM or auto body's step calls: its choices (model, frame,
    order, integrator, ...), which optional physics it has (plasticity, fracture, ...), not their
    values, and whether it is held or loaded."""
    return ("fem", tuple(raw.get(k) for k in _KIND_CHOICES), tuple(k in raw for k in _KIND_GIVEN),
            bool(raw.get("anchors")), bool(raw.get("loads")))


def warm_kinds(scene):
    """The kinds of work stepping ``scene`` calls kernels for (a frozenset): ``("plane",)``,
    ``("rigid", shape type)`` and one ``("fem", ...)`` per kind of FEM or auto body."""
    kinds = {("plane",)} if scene.planes else set()
    for body, raw in zip(scene.bodies, scene.raw.get("bodies", [])):
        if body.model == "rigid":
            kinds.add(("rigid", body.shape.type if body.shape is not None else "box"))  # a mesh: a box
        else:
            kinds.add(_fem_kind(raw))
    return frozenset(kinds)


def _fem_table(kind, x):
    """The warm-up body of an FEM kind: a 0.1 m box resting on the ground at ``x``, with the
    kind's choices and its optional physics (held at its bottom, loaded on its top if the kind is)."""
    _, choices, given, anchored, loaded = kind
    h = _WARM_SIZE
    table = {k: v for k, v in zip(_KIND_CHOICES, choices) if v is not None}
    table |= {k: v for (k, v), g in zip(_KIND_GIVEN.items(), given) if g}
    table |= {"density": 1000.0, "young": 1e5, "poisson": 0.3, "position": [x, 0.0, 0.5 * h],
              "velocity": _WARM_VELOCITY, "shape": {"type": "box", "size": [h, h, h], "resolution": 0.5 * h}}
    if anchored:
        table["anchors"] = [{"box": [[-1.0, -1.0, -0.5 * h - 1e-6], [1.0, 1.0, -0.5 * h + 1e-6]]}]
    if loaded:
        table["loads"] = [{"box": [[-1.0, -1.0, 0.5 * h - 1e-6], [1.0, 1.0, 0.5 * h + 1e-6]],
                           "force": [0.0, 0.0, -1e-3]}]
    return table


def _rigid_tables(shape, x):
    """The warm-up bodies of a rigid shape: one resting on the ground at ``x`` (a box: two, one on
    the other, and one beside them spinning on its face, which has its load shared over the face,
    rigid.patches: compiled in the first step of the default scene's loop, 8 s)."""
    h = _WARM_SIZE
    size = {"box": {"size": [0.5 * h] * 3}, "sphere": {"radius": 0.25 * h},
            "capsule": {"radius": 0.1 * h, "height": 0.5 * h},
            "cylinder": {"radius": 0.25 * h, "height": 0.5 * h}}[shape]
    low = 0.25 * h if shape != "capsule" else 0.1 * h
    tables = [{"density": 100.0, "shape": {"type": shape} | size, "position": [x, 0.0, low],
               "velocity": _WARM_VELOCITY}]
    if shape == "box":
        tables.append({"density": 100.0, "shape": {"type": "box"} | size,
                       "position": [x, 0.0, 0.75 * h], "velocity": [0.0, 0.0, -0.4]})
        tables.append({"density": 100.0, "shape": {"type": "box"} | size, "position": [x, h, low],
                       "angular_velocity": [0.0, 0.0, 20.0]})
    return tables


def _warm_scene(kinds, dt):
    """The scene data of the warm-up: per FEM kind a small box resting on the ground (the first
    kind's with a second, unanchored, on it; a rigid box on top when there are rigid kinds), per
    rigid shape a small body resting on the ground (boxes: one on another, one spinning beside
    them), all touching from the start and moving into each other (so that impacts as well as
    resting contacts are met)."""
    rigid = sorted(k[1] for k in kinds if k[0] == "rigid")
    bodies, x = [], 0.0
    for i, kind in enumerate(sorted((k for k in kinds if k[0] == "fem"), key=repr)):
        bodies.append(_fem_table(kind, x))
        top = _WARM_SIZE
        if i == 0:          # a second one on the first: contact between deformable bodies
            bodies.append(_fem_table(kind, x) | {"position": [x, 0.0, 1.5 * _WARM_SIZE]})
            bodies[-1].pop("anchors", None)
            top = 2 * _WARM_SIZE
        if rigid:
            bodies += _rigid_tables("box", x)[1:2]                # a rigid box on the FEM box
            bodies[-1]["position"] = [x, 0.0, top + 0.25 * _WARM_SIZE]
        x += 2 * _WARM_SIZE
    for shape in rigid:
        bodies += _rigid_tables(shape, x)
        x += 2 * _WARM_SIZE
    for i, body in enumerate(bodies):
        body["name"] = f"warm{i}"
    data = {"simulation": {"name": "warm_up", "dt": min(dt, 0.01), "duration": 1.0}, "bodies": bodies}
    if ("plane",) in kinds:
        data["planes"] = [{"point": [0.0, 0.0, 0.0], "normal": [0.0, 0.0, 1.0]}]
    return data


def warm_up(scene):
    """Compile, or load from numba's on-disk cache, the kernels running ``scene`` calls: run
    (:class:`hybrid.simulation.Simulation`, :data:`WARM_STEPS` steps, no output folder, then the
    fields of a frame) a tiny scene with one small body of each of its kinds of FEM body and
    rigid shape (:func:`warm_kinds`), resting on the ground and on each other. A set of kinds is
    warmed once per process; none is with the environment variable ``HYBRID_NO_WARM_UP=1``. Never
    raises: a warm-up that fails leaves the compilation to the step loop (logged at debug level).
    Returns the seconds the warm-up of these kinds took (the first time in the process; 0 when
    there was nothing to warm up)."""
    if os.environ.get("HYBRID_NO_WARM_UP", "") not in ("", "0") or str(scene.source_path) == WARM_SOURCE:
        return 0.0
    kinds = warm_kinds(scene)
    if not any(k[0] in ("fem", "rigid") for k in kinds):
        return 0.0
    seconds = _warm_once(kinds, float(scene.simulation.dt))
    # a contact pass between rigid bodies alone (no deformable node in it) runs the solver's
    # rigid-only kernels, which the scene of every kind does not reach: the shatter tile's
    # fragments compiled them in the step loop (19 s)
    rigid = frozenset(k for k in kinds if k[0] != "fem")
    if rigid != kinds and any(k[0] == "rigid" for k in rigid):
        seconds += _warm_once(rigid, float(scene.simulation.dt))
    return seconds


def _warm_held():
    """Compile the kernels of a deformable body held at rest (hybrid.coupling.held: stepped as
    an anchored one), which a few warm-up steps do not reach, on empty input."""
    from fem.step_kernels import anchor_reaction, rotate_back
    rotate_back(np.zeros(3), np.eye(3))
    ptr = np.zeros(2, np.int32)         # (scipy's CSR index type)
    anchor_reaction(ptr, ptr[:0], np.zeros(0), np.zeros(1, np.int64), np.zeros((1, 3)),
                    np.zeros((1, 3)), np.zeros(3), np.eye(3), 1.0)


@functools.lru_cache(maxsize=None)
def _warm_once(kinds, dt):
    """:func:`warm_up` of a set of kinds, memoised for the process: numba keeps what it compiled
    or loaded, so a second warm-up of the same kinds would do nothing."""
    from hybrid.app.observe import frame_pieces
    from hybrid.app.scene import parse_scene
    from hybrid.simulation import Simulation

    start = time.perf_counter()
    try:
        sim = Simulation(parse_scene(_warm_scene(kinds, dt), WARM_SOURCE, "."))
        with np.errstate(all="ignore"):
            sim.run(until=WARM_STEPS * sim.dt, progress=False, log=lambda message: None,
                    checkpoint_every=0)
            frame_pieces(sim.model, sim.state)
            if sim.model.fem:
                _warm_held()
    except Exception as error:      # noqa: BLE001 (an optimisation: never stops a run)
        log.debug("kernel warm-up skipped: %s", error)
    return time.perf_counter() - start
