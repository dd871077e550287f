"""FEM bodies of a scene: building them from scene fields (the coupling lives in hybrid.coupling.step)."""
import math
from dataclasses import dataclass

import numpy as np

from fem.mesh import (box_tet_mesh, check_tets, cylinder_tet_mesh, quadratic_tets,
                      select_nodes_in_box, sphere_tet_mesh)
from fem.model import build_fem_model, rest_state
from rigid import quaternion as quat

from hybrid.coupling.stability import beyond_limits

from . import geometry
from .hints import bending_note
from .scene.describe import toml_text


# an FEM box without a `resolution` is meshed in cells about a third of its shortest side when it
# is compact (an even number along each side: see default_box_mesh); when its longest side is at least SLENDER_RATIO times its shortest it bends, and
# that mesh was both too stiff (linear tets locking) and too large (a 30 x 30 x 1 cm plate was
# 145,800 tets, a 0.6 s run tens of minutes): see default_box_mesh
SLENDER_RATIO = 4.0
# the default budget of a slender box: nodes (corner and midside)
NODE_BUDGET = 4000
# longest side of a slender box's default cell over the thickness of its layers
MAX_CELL_ASPECT = 4.0
# a slender box is a plate when its shortest side is at most this fraction of the next
PLATE_RATIO = 0.25


@dataclass(frozen=True)
class DefaultMesh:
    """How a box without a ``resolution`` is meshed: ``cells`` (3,) per axis, element ``order``
    (1 or 2), ``resolution`` m (the shortest cell side) and ``why`` (for the run log)."""
    cells: tuple
    order: int
    resolution: float
    why: str

    @property
    def tet_count(self):
        """Tetrahedra of the mesh (six per cell)."""
        return 6 * math.prod(self.cells)


def _nodes(cells, order):
    """Nodes of a box mesh of ``cells`` (3,) (floats: absurd sizes must not overflow)."""
    return float(np.prod(order * np.asarray(cells, float) + 1.0))


def _cell_counts(size, h):
    """Cells (3,) floats along each side for cells of side ``h`` (at least one, capped at 1e18)."""
    return np.maximum(1.0, np.ceil(np.minimum(size / h, 1e18) - 1e-9))


def _even(cells):
    """Cell counts (3,) rounded up to even ones: the box mesh has the box's mirror symmetries only
    with even counts (fem.mesh.box_tet_mesh), and a rubber cube meshed 3 x 3 x 3 dropped flat
    drifted 14 mm sideways and tilted 3.6 degrees."""
    return 2.0 * np.ceil(0.5 * np.asarray(cells, float))


def default_box_mesh(size, order=None):
    """:class:`DefaultMesh` of an FEM box of ``size`` (3,) m with no ``resolution`` (``order``:
    the scene's, None when not given).

    A compact box (longest side under SLENDER_RATIO times its shortest): cells about a third of
    its shortest side, linear tets unless ``order = 2`` is given, as always. A slender box bends:
    quadratic tets unless ``order = 1`` is given (linear tets a few layers thick lock in bending,
    far too stiff), in two layers through its thin side (and across a bar's other small side;
    four for linear tets), with cells along the long sides as fine as NODE_BUDGET nodes allow but
    at most MAX_CELL_ASPECT times the layers' thickness (beyond that the budget gives way). Every
    count is even (:func:`_even`), so the mesh keeps the box's mirror symmetries."""
    size = np.broadcast_to(np.asarray(size, float), (3,))
    shortest, middle, longest = (float(v) for v in np.sort(size))
    if longest < SLENDER_RATIO * shortest:
        cubic = _even(_cell_counts(size, shortest / 3))
        order = 1 if order is None else order
        return DefaultMesh(tuple(int(c) for c in cubic), order, float(np.min(size / cubic)),
                           "a compact box: cells a third of its shortest side or a little "
                           "less, an even number along each side (the mesh keeps the box's "
                           "mirror symmetries)")
    order = 2 if order is None else order
    plate = shortest <= PLATE_RATIO * middle
    layers = 2 if order == 2 else 4
    thin = shortest / layers
    thin_axis = int(np.argmin(size))

    def cells(h):
        # as coarse as h along the long sides; the layers across the thin side (and a bar's
        # other small side)
        n = np.maximum(_cell_counts(size, h), np.minimum(layers, _cell_counts(size, thin)))
        n[thin_axis] = layers
        return _even(n)

    # the finest long cells, from the layers' thickness to the aspect cap, within the budget
    sides = np.geomspace(thin, MAX_CELL_ASPECT * thin, 64)
    fits = [h for h in sides if _nodes(cells(h), order) <= NODE_BUDGET]
    side = fits[0] if fits else sides[-1]
    kind = ("quadratic tets so it bends without locking" if order == 2 else
            "linear tets (order = 1 given)")
    budget = (f"within the default budget of {NODE_BUDGET} nodes" if fits else
              f"at most {MAX_CELL_ASPECT:g}x the layers' thickness, over the default budget of "
              f"{NODE_BUDGET} nodes")
    why = (f"a {'plate' if plate else 'slender box'}: {layers} layers through its "
           f"{shortest * 1e3:.3g} mm side, {kind}, cells up to {side * 1e3:.3g} mm along its "
           f"long sides ({budget})")
    counts = cells(side)
    return DefaultMesh(tuple(int(c) for c in counts), order, float(np.min(size / counts)), why)


def default_resolution(shape):
    """Edge length (m) an FEM body's shape is meshed at when the scene gives no ``resolution``:
    for a box its default mesh's shortest cell side (:func:`default_box_mesh`; its cells may be
    longer along its long sides), half a radius for spheres and cylinders."""
    return default_box_mesh(shape.size).resolution if shape.type == "box" else shape.radius / 2


def box_cells(shape, order=None):
    """Cell counts (3,) int of a deformable box ``shape``: its default mesh's
    (:func:`default_box_mesh`, for the scene's ``order``, None when not given) or cubic cells of
    its ``resolution``, each split ``refine`` times along each side."""
    if shape.resolution is None:
        cells = np.asarray(default_box_mesh(shape.size, order).cells)
    else:
        cells = _cell_counts(np.broadcast_to(np.asarray(shape.size, float), (3,)), shape.resolution)
    return (cells * shape.refine).astype(int)


def body_order(body, file_order=1):
    """Element order (1 or 2) a body is built with: its ``order``, else its mesh file's
    (``file_order``: tetra10 cells are quadratic tets; dropping their midside nodes unasked made a
    cantilever 40% too stiff), else its default mesh's (a box without a ``resolution``), else 1."""
    if body.order is not None:
        return body.order
    if body.mesh is not None:
        return file_order
    s = body.shape
    if body.mesh is None and s is not None and s.type == "box" and s.resolution is None:
        return default_box_mesh(s.size).order
    return 1


def _tet_mesh(body):
    """Rest tet mesh of a body in its own frame: (points, tets, order of the file)."""
    if body.mesh is not None:
        return geometry.load_tet_mesh(body.mesh)
    s = body.shape
    if s.type == "box":
        points, tets = box_tet_mesh(np.asarray(s.size, float), box_cells(s, body.order))
        return points, tets, 1
    h = s.resolution or default_resolution(s)
    # the fem.mesh generators take cell counts; scene resolutions are edge lengths in metres
    if s.type == "sphere":
        points, tets = sphere_tet_mesh(s.radius, 2 * s.radius / h)
    elif s.type == "cylinder":
        points, tets = cylinder_tet_mesh(s.radius, s.height, 2 * s.radius / h)
    else:
        raise ValueError(fem_shape_message(s.type))
    return points, tets, 1


# the shapes a deformable body is meshed from (others need a tet mesh)
FEM_SHAPES = ("box", "sphere", "cylinder")


def fem_shape_message(shape_type):
    """What a deformable body of shape ``shape_type`` (not one of FEM_SHAPES) is told."""
    return f"FEM bodies support box, sphere and cylinder shapes or a tet mesh, not '{shape_type}'"


def _fem_models(model):
    """The FemModel of every FEM or auto body of a model, by scene index (an auto body stepped as
    rigid: the one it parked)."""
    return dict(zip(model.fem_ids, model.fem)) | {k: p.fem for k, p in model.parked.items()}


def mesh_notes(model):
    """One run-log line per FEM or auto body of a model just built from its scene: its element
    count, nodes, resolution and order, and why (given, or the default's reason)."""
    lines, fem = [], _fem_models(model)
    for k, body in enumerate(model.scene.bodies):
        m = fem.get(k)
        if m is None:
            continue
        kind = "quadratic" if m.order == 2 else "linear"
        head = f"mesh: '{body.name}': {m.tet_count} {kind} tets, {m.node_count} nodes"
        s = body.shape
        if body.mesh is not None:
            lines.append(f"{head}, from {body.mesh.name}")
        elif s.resolution is not None:
            split = f", each cell split {s.refine} times" if s.type == "box" and s.refine > 1 else ""
            lines.append(f"{head}, resolution {s.resolution:.3g} m (given{split})")
        elif s.type == "box":
            d = default_box_mesh(s.size, body.order)
            cells = " x ".join(f"{a * 1e3:.3g}" for a in np.asarray(s.size) / box_cells(s, body.order))
            split = f", each cell split {s.refine} times" if s.refine > 1 else ""
            lines.append(f"{head}, cells {cells} mm (default: {d.why}{split}; set `resolution` to choose)")
        else:
            lines.append(f"{head}, resolution {default_resolution(s):.3g} m (default: half the "
                         f"radius; set `resolution` to choose)")
        lines[-1] += f"; {locking}" if (locking := bending_note(m, SLENDER_RATIO)) else ""
    return lines


# a yield or fracture strain (stress / young) above which the linear elasticity the body is
# stepped with is out of its range before it yields or cracks (metals yield at 0.1-1%, glass
# breaks at about 0.1%)
LARGE_MATERIAL_STRAIN = 0.1


def material_warnings(model):
    """Warnings for FEM or auto bodies of a model just built whose strength cannot act as meant:
    a yield or fracture strain past LARGE_MATERIAL_STRAIN (never reached in the strains linear
    elasticity holds for), or a strength below the stress its own weight makes across its height
    along gravity, ``density |g| h`` (it yields or cracks as it rests); and auto bodies that can
    never be made rigid (hybrid.coupling.auto.may_be_rigid) or whose rigidify_strain, given in
    the scene, is not used as given (above a tenth of their elastify strain)."""
    from hybrid.coupling.auto import elastify_threshold, may_be_rigid
    said, g, fem = [], float(np.linalg.norm(model.gravity)), _fem_models(model)
    for k, body in enumerate(model.scene.bodies):
        m = fem.get(k)
        if m is None:
            continue
        height = float(np.ptp(m.rest_points @ (model.gravity / g))) if g > 0 else 0.0
        weight = body.density * g * height
        for field, what, done in (("yield_stress", "yield", "yields"),
                                  ("fracture_stress", "fracture", "cracks")):
            stress = getattr(body, field, None)
            if stress is None:
                continue
            if stress / body.young > LARGE_MATERIAL_STRAIN:
                said.append(f"body '{body.name}': {field} {stress:.3g} Pa over young {body.young:.3g} Pa "
                            f"is a {what} strain of {stress / body.young:.3g}: linear elasticity "
                            f"holds for strains of a few percent, so the body never {done} as meant")
            elif stress < weight:
                said.append(f"body '{body.name}': {field} {stress:.3g} Pa is below the stress its "
                            f"own weight makes across its height (density g h = {weight:.3g} Pa): "
                            f"it {done} under its own weight wherever it rests or hangs")
        if body.model == "auto" and not may_be_rigid(m):
            why = ("its anchors move" if m.has_anchors else "it carries loads (a rigid body carries no "
                   "applied force)" if np.any(m.load_force) else "it has mass damping, which would "
                   "slow its rigid motion too")
            said.append(f"body '{body.name}': model = \"auto\" never makes it rigid, as {why}: it is "
                        f"stepped as FEM throughout, with the auto checks' cost (docs/auto.md); "
                        f"model = \"fem\" says so")
        elastify = elastify_threshold(body) if body.model == "auto" else None
        chosen = body.auto.rigidify_strain != type(body.auto)().rigidify_strain   # (not the default)
        if elastify is not None and chosen and body.auto.rigidify_strain > 0.1 * elastify:
            said.append(f"body '{body.name}': auto rigidify_strain {body.auto.rigidify_strain:.3g} is used as "
                        f"{0.1 * elastify:.3g}, a tenth of the strain at which it turns deformable "
                        f"({elastify:.3g}: elastify_strain, at most half its yield and fracture "
                        f"strains), so that a body never sits between the two (docs/auto.md)")
    return said


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


def beyond(scene, model, state):
    """Problems (scene file messages) of the bodies that start beyond the limits of the check
    after every step (hybrid.coupling.stability.beyond_limits): run, they would stop as unstable
    at their first step."""
    index = {b.name: i for i, b in enumerate(scene.bodies)}
    said = []
    for name, field, quantity, unit, value, limit in beyond_limits(model, state):
        body = scene.bodies[index[name]]
        if field == "position" and body.mesh is not None and math.hypot(*body.position) <= limit:
            # the mesh file's own coordinates put it there, not its position
            field = "mesh"
        said.append(f"{scene.source_path}: {body_label(body, index[name])}: field '{field}' starts it "
                    f"at a {quantity} of {value:.3g} {unit}: a run stops as unstable beyond "
                    f"{limit:.0e} {unit} (allowed: up to {limit:.0e} {unit})")
    return said


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
    order = body_order(body, file_order)
    if file_order == 2 and order == 1:
        tets = tets[:, :4]
        points = points[: tets.max() + 1]
    if order == 2 and tets.shape[1] == 4:
        # the midside nodes first, so anchor and load boxes take them too (selected on the
        # corners alone, a clamped P2 beam's clamp face moved 0.18 mm and its tip sagged 10% more)
        points, tets = quadratic_tets(points, tets)
    anchors = _regions(body, label, "anchors", points)
    loads = _regions(body, label, "loads", points)
    _check_unbreakable(body, label, points, tets)
    # the rest shape is the placed one: rotate by `orientation`, move by `position`
    R = quat.to_matrix(np.asarray(body.orientation, float))
    placed = points @ R.T + np.asarray(body.position, float)
    try:
        return build_fem_model(placed, tets, order=order, density=body.density,
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


def _disjoint_anchors(found, label):
    """Anchor regions ``(nodes, velocity)`` with each node in the first that holds it: anchors
    that share nodes (a plate clamped on edges that meet at its corners) must prescribe them the
    same velocity, and each reports the reaction of its own nodes (shared ones were counted
    twice); ValueError naming the two anchors when they disagree (the second won, the first
    reported its nodes moving)."""
    owner = np.full(1 + max((int(n.max()) for n, _ in found if len(n)), default=0), -1)
    out = []
    for k, (nodes, velocity) in enumerate(found):
        firsts = owner[nodes]
        held = firsts >= 0
        for first in np.unique(firsts[held]):
            if not np.array_equal(np.asarray(found[first][1], float), np.asarray(velocity, float)):
                raise ValueError(f"{label}: field 'anchors': [[bodies.anchors]] {first} and {k} both "
                                 f"hold {int((firsts == first).sum())} node(s) at different "
                                 f"velocities; a node follows one velocity: make the boxes disjoint "
                                 f"or their velocities equal")
        owner[nodes[~held]] = k
        out.append((nodes[~held], velocity))
    return out


def _check_unbreakable(body, label, points, tets):
    """ValueError for an unbreakable box holding no element's centroid (it would keep nothing
    whole, as an anchor box holding no node would hold nothing)."""
    centroid = points[tets[:, :4]].mean(axis=1)
    for k, region in enumerate(body.unbreakable):
        low, high = np.asarray(region.box[0]), np.asarray(region.box[1])
        if not np.all((centroid >= low - 1e-9) & (centroid <= high + 1e-9), axis=1).any():
            span = [np.round(e, 6).tolist() for e in (points.min(axis=0), points.max(axis=0))]
            raise ValueError(f"{label}: field 'unbreakable': [[bodies.unbreakable]] {k} box "
                             f"{list(map(list, region.box))} contains no element's centre (boxes are "
                             f"in the body's own coordinates, where its mesh spans {span[0]} to {span[1]})")


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
    if what == "anchors":
        found = _disjoint_anchors(found, label)
    return found


# a deformable body may start at most this part of its size inside a plane
DEEP_START = 0.01


def deep_starts(scene, model, below):
    """Problems (scene file messages) of the deformable bodies that start more than DEEP_START of
    their size inside a plane (``below``: run.below_planes, ``(name, depth m)``): the recovery
    pushes their nodes out in one step, and the strain that makes throws them (a soft cube started
    half in the ground was strained by 0.6 and gained 33 J in 0.017 s); and of the rigid bodies
    that start deeper than their size (their bounding sphere's diameter), wholly under it: pushed
    out, a box buried 0.5 m under the ground gained its weight times that depth, which the run's
    energy watch took for a divergence (it allows a body's weight times its size)."""
    index = {b.name: i for i, b in enumerate(scene.bodies)}
    size = {model.names[k]: float(np.ptp(m.rest_points, axis=0).max()) for k, m in zip(model.fem_ids, model.fem)}
    rigid = {model.names[k]: 2.0 * float(r) for k, r in zip(model.rigid_ids, model.rigid.body_radius)}
    return [f"{scene.source_path}: {body_label(scene.bodies[index[name]], index[name])}: field 'position' "
            f"starts it {depth:.3g} m inside a plane ({100 * depth / size[name]:.2g}% of its "
            f"{size[name]:.3g} m size, at most {100 * DEEP_START:g}% for a deformable body, whose nodes "
            f"are pushed out in one step): place it on or above the plane{geometry.units_hint(scene.bodies, name)}"
            for name, depth in below if name in size and depth > DEEP_START * size[name]] + \
        [f"{scene.source_path}: {body_label(scene.bodies[index[name]], index[name])}: field 'position' "
         f"starts it {depth:.3g} m inside a plane, deeper than its {rigid[name]:.3g} m size (at most "
         f"that for a rigid body, which is pushed out in its first steps): place it on or above the "
         f"plane{geometry.units_hint(scene.bodies, name)}" for name, depth in below if name in rigid and depth > rigid[name]]
