"""FEM body model (built once) and state (changes every step).

A :class:`FemModel` holds the rest mesh, material, assembled matrices, anchors, loads and solver
settings, and owns the cache of what is derived from them on first use (:class:`fem.cache.FemCache`:
the factorised system matrix, contact response, ...); a :class:`FemState` holds node positions,
velocities and the best-fit frame. Build both with :func:`build_fem_model` and :func:`rest_state`.
"""
import warnings
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.sparse as sp

from fem.assembly import ElementData, assemble, assemble_subset
from fem.cache import FemCache
from fem.dynamics import body_frame, system_factorisation
from fem.mesh import check_tets, index_list, quadratic_tets, surface_triangles
from fem.plastic_flow import initial_plastic_fields
from fem.solver import available_linear_solver

FRAMES = ("floating", "corotated")
INTEGRATORS = ("backward_euler", "newmark")
MASSES = ("lumped", "consistent")
COROTATED_SOLVERS = ("cg", "lu")


@dataclass(frozen=True)
class FemModel:
    """Static description of one deformable body (SI units). Rebuilt only by events.

    rest_points: ``(n, 3)`` rest node positions X (m), body coordinates.
    tets: ``(t, 4)`` P1 or ``(t, 10)`` P2 (tetra10 order) node indices, positively oriented.
    order: 1 (linear tets) or 2 (quadratic tets).
    density: kg/m^3. young: Young's modulus E (Pa). poisson: Poisson ratio nu (-).
    mu, lam: Lame parameters (Pa).
    damping_mass, damping_stiffness: Rayleigh alpha (1/s) and beta (s), C = alpha M + beta K.
    frame: "floating" (one best-fit frame per body, factorised once) or "corotated" (per-element
        rotations, stiffness warping, matrix rebuilt each step). A body with anchors uses the
        world frame (R = I) when floating.
    integrator: "backward_euler" (stable, dissipative) or "newmark" (average acceleration,
        gamma = 1/2, beta = 1/4: no numerical damping).
    mass_kind: "lumped" (HRZ diagonal) or "consistent" mass in the equations of motion.
    node_mass: ``(n,)`` lumped (HRZ) nodal mass (kg), all positive; the effective mass of a node
        for contact and the weights of shape matching.
    K: ``(3n, 3n)`` CSR rest stiffness (N/m), node-major DOFs ``3 * node + component``.
    M: ``(3n, 3n)`` CSR mass used by the integrator (kg): diagonal (lumped) or consistent.
    elements: :class:`fem.assembly.ElementData`, per-element rest data.
    rest_center: ``(3,)`` mass-weighted centre of the rest points X_c (m).
    rest_offsets: ``(n, 3)`` X - X_c (m), shape-matching rest offsets.
    anchor_nodes: tuple of ``(k_i,)`` node index arrays, one per anchor region.
    anchor_velocity: ``(a, 3)`` prescribed velocity of each anchor region (m/s).
    node_anchor: ``(n,)`` index of the anchor holding each node, -1 if free.
    free_dofs: ``(f,)`` DOFs solved for; fixed_dofs: ``(3n - f,)`` DOFs prescribed by anchors.
    load_nodes: tuple of ``(k_i,)`` node index arrays, one per load region.
    load_force: ``(l, 3)`` total force of each load region (N).
    node_load: ``(n, 3)`` constant external node forces from all loads (N).
    surface: ``(f, 3)`` outward boundary triangles (P2: four per boundary face).
    surface_nodes: ``(s,)`` sorted indices of the nodes on the boundary.
    yield_stress: von Mises yield stress Y (Pa), or None for a purely elastic body (then no
        plasticity pass runs and the state carries no plastic strain).
    plastic_update_strain: equivalent plastic strain (-) accumulated in some quadrature point since
        the last reference-shape update at which the next update is due (``fem.reference``).
    max_plastic_strain: cap (-) on the accumulated equivalent plastic strain (``tet_peeq``), or None.
    reference_peeq: ``(t, q)`` accumulated equivalent plastic strain at the last reference-shape
        update (-), zeros when built; None for elastic bodies.
    reference_updates: number of reference-shape updates that led to this model.
    held_nodes: ``(k,)`` sorted nodes held by resting contact, or None: set only on the variants
        :func:`holding` makes, whose fixed DOFs are the anchors' and these nodes'.
    anchor_labels, load_labels: the scene index (``anchorK``, ``loadK``) of each anchor and load
        region, or None for 0, 1, ...: a fracture fragment keeps the indices of the regions it
        took (see :attr:`region_names`).
    linear_solver: sparse backend of the model's factorisations, ``"cholmod"`` (CHOLMOD through
        cholespy) or ``"superlu"`` (scipy's SuperLU); see ``fem.solver``.
    corotated_solver: how a corotated body solves its warped system each step: ``"cg"``
        (conjugate gradients warm-started from the last velocities and preconditioned by the rest
        factorisation turned into the best-fit frame) or ``"lu"`` (a new factorisation every step);
        timings in ``benchmarks/fem_solver.py``.
    cache: :class:`fem.cache.FemCache`, what functions derive from this model on first use (its
        factorised system matrix, contact response, ...). ``dataclasses.replace`` keeps it (a
        relabelled region changes nothing it holds); a model whose shape, matrices or prescribed
        DOFs differ is given an empty one, ``cache=FemCache()`` (:func:`with_rest_points`,
        :func:`holding`).
    """
    rest_points: np.ndarray
    tets: np.ndarray
    order: int
    density: float
    young: float
    poisson: float
    mu: float
    lam: float
    damping_mass: float
    damping_stiffness: float
    frame: str
    integrator: str
    mass_kind: str
    node_mass: np.ndarray
    K: sp.csr_matrix
    M: sp.csr_matrix
    elements: ElementData
    rest_center: np.ndarray
    rest_offsets: np.ndarray
    anchor_nodes: tuple
    anchor_velocity: np.ndarray
    node_anchor: np.ndarray
    free_dofs: np.ndarray
    fixed_dofs: np.ndarray
    load_nodes: tuple
    load_force: np.ndarray
    node_load: np.ndarray
    surface: np.ndarray
    surface_nodes: np.ndarray
    yield_stress: float | None = None
    plastic_update_strain: float = 0.02
    max_plastic_strain: float | None = None
    reference_peeq: np.ndarray | None = None
    reference_updates: int = 0
    held_nodes: np.ndarray | None = None
    anchor_labels: tuple | None = None
    load_labels: tuple | None = None
    linear_solver: str = "cholmod"
    corotated_solver: str = "cg"
    cache: FemCache = field(default_factory=FemCache, repr=False, compare=False)

    @property
    def node_count(self):
        """Number of nodes (corner and, for P2, midside)."""
        return len(self.rest_points)

    @property
    def tet_count(self):
        """Number of tetrahedra."""
        return len(self.tets)

    @property
    def plastic(self):
        """True when the body has a yield stress (von Mises perfect plasticity)."""
        return self.yield_stress is not None

    @property
    def quadrature_count(self):
        """Quadrature points per element ``q`` (1 for P1): one plastic strain each."""
        return self.elements.tet_weights.shape[1]

    @property
    def anchored(self):
        """True when some node is prescribed (by an anchor, or held by :func:`holding`)."""
        return len(self.fixed_dofs) > 0

    @property
    def has_anchors(self):
        """True when an anchor region holds nodes (the body then has no floating frame)."""
        return any(len(nodes) for nodes in self.anchor_nodes)

    @property
    def fixed_nodes(self):
        """``(k,)`` sorted nodes whose DOFs are prescribed (every DOF of a prescribed node is)."""
        return self.fixed_dofs[::3] // 3

    @property
    def region_names(self):
        """``anchorK`` for each anchor region, then ``loadK`` for each load region, K its index in
        the scene body's file order: a fracture fragment keeps the labels of the regions it took."""
        anchors = range(len(self.anchor_nodes)) if self.anchor_labels is None else self.anchor_labels
        loads = range(len(self.load_nodes)) if self.load_labels is None else self.load_labels
        return [f"anchor{i}" for i in anchors] + [f"load{i}" for i in loads]


@dataclass(frozen=True)
class FemState:
    """Everything about a deformable body that changes in time (SI units).

    x, v: ``(n, 3)`` node positions (m, world coordinates) and velocities (m/s).
    R: ``(3, 3)`` best-fit rotation of the body (shape matching), identity for anchored bodies.
    c: ``(3,)`` mass-weighted centre of the nodes (m); X_c for anchored bodies.
    node_reaction: ``(n, 3)`` force the anchors exerted on each anchored node over the last step
        (N), zero elsewhere. time: simulated time (s).
    Plastic bodies only (None / 0 for elastic ones, see ``fem.plastic_flow``):
    tet_plastic_strain: ``(t, q, 3, 3)`` plastic strain eps_p at each quadrature point (-), rest
        (material) coordinates; q = 1 for P1.
    tet_peeq: ``(t, q)`` accumulated equivalent plastic strain ``sum sqrt(2/3) |d eps_p|`` (-).
    tet_yielded: ``(t,)`` bool, the element yielded in the last step.
    node_plastic_force: ``(n, 3)`` equivalent plastic force ``f_p = sum_e int B^T C eps_p`` (N),
        body (rest) frame, including the predicted increment of elements still flowing
        (IMPL-EX, ``fem.plastic_flow``); zeros for corotated bodies, whose stored strain is
        rotated per element in ``predict`` (the predicted part only is kept here).
    plastic_dissipation: plastic work dissipated since the start (J).
    node_rest_shift: ``(n, 3)`` plastic displacement the reference updates have baked into the
        rest shape so far (m, rest coordinates), None before the first.
    energy_slack: Newmark bodies only, how far (J) the body's energy (kinetic and elastic) is
        below what it may hold: its energy when created plus the work done on it by its steps
        (``fem.dynamics.finish`` takes any excess out). Its energy may rise by this much more than
        the work done on it.
    """
    x: np.ndarray
    v: np.ndarray
    R: np.ndarray
    c: np.ndarray
    node_reaction: np.ndarray
    time: float = 0.0
    tet_plastic_strain: np.ndarray | None = None
    tet_peeq: np.ndarray | None = None
    tet_yielded: np.ndarray | None = None
    node_plastic_force: np.ndarray | None = None
    plastic_dissipation: float = 0.0
    node_rest_shift: np.ndarray | None = None
    energy_slack: float = 0.0

    def replace(self, **changes):
        """A copy of this state with ``changes`` (field name = new value)."""
        return replace(self, **changes)


def _mass_matrices(M_scalar, mass):
    """``(node_mass (n,), M (3n, 3n))`` from the consistent scalar mass: HRZ lumping (diagonal
    scaled to the total mass, all positive) and the integrator's mass (lumped or consistent)."""
    diag = M_scalar.diagonal()
    node_mass = diag * (M_scalar.sum() / diag.sum())
    if mass == "lumped":
        return node_mass, sp.diags(np.repeat(node_mass, 3)).tocsr()
    return node_mass, sp.kron(M_scalar, sp.identity(3), format="csr")


def with_rest_points(model, points, dt=None, **changes):
    """A new model with rest shape ``points`` ``(n, 3)`` m (same mesh, material, anchors, loads):
    K, M, element data, lumped masses and shape-matching offsets are rebuilt for the new shape,
    the density scaled to keep the body's mass (new volumes need not add up to the old: a bar
    pulled to 10% lost 4% of its mass); its own cache, its system factorised now for ``dt`` s if
    given (floating frame). ``changes`` replace further fields. Used by reference-shape updates.
    """
    points = np.asarray(points, dtype=float)
    K, M_scalar, elements = assemble(points, model.tets, model.young, model.poisson, model.density)
    scale = model.node_mass.sum() / M_scalar.sum()
    node_mass, M = _mass_matrices(M_scalar * scale, model.mass_kind)
    rest_center = node_mass @ points / node_mass.sum()
    new = replace(model, rest_points=points, K=K, M=M, elements=elements, node_mass=node_mass,
                  density=model.density * scale, rest_center=rest_center,
                  rest_offsets=points - rest_center, cache=FemCache(), **changes)
    if dt is not None and new.frame == "floating":
        system_factorisation(new, dt)
    return new


def holding(model, nodes):
    """A variant of ``model`` whose ``nodes`` are also prescribed, as if anchored: a body resting
    on static ground is stepped with its resting nodes held at the velocities the contact asks of
    them (hybrid.coupling.resting). It shares K, M and the rest data, keeps the body's frame (floating
    bodies still fit their best rotation) and has its own cache, so its own factorisation and
    contact response (solved on its first use). The variant for the last ``nodes`` asked for is
    kept in ``model.cache.held``."""
    nodes = np.unique(np.asarray(nodes, dtype=np.int64))
    last = model.cache.held
    if last is not None and np.array_equal(last.held_nodes, nodes):
        return last
    fixed = np.zeros(3 * model.node_count, dtype=bool)
    fixed[model.fixed_dofs] = True
    fixed[(3 * nodes[:, None] + np.arange(3)).ravel()] = True
    variant = replace(model, free_dofs=np.nonzero(~fixed)[0], fixed_dofs=np.nonzero(fixed)[0],
                      held_nodes=nodes, cache=FemCache())
    model.cache.held = variant
    return variant


def _node_indices(selection, n):
    selection = np.asarray(selection)
    if selection.dtype == bool:
        if selection.shape != (n,):
            raise ValueError(f"node mask must have shape ({n},), got {selection.shape}")
        return np.nonzero(selection)[0]
    return np.unique(selection.astype(np.int64))


def _spread_force(nodes, total, weights):
    w = weights[nodes]
    return np.outer(w / w.sum(), total)


def _surface_node_area(points, surface):
    """Area (m^2) attributed to each node by the surface triangles (one third each)."""
    p = points[surface]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    return np.bincount(surface.ravel(), weights=np.repeat(area / 3.0, 3), minlength=len(points))


def _checked_mesh(points, tets, order):
    """``(points (n, 3), tets (t, 4 or 10))`` of the given order (midside nodes added to a linear
    mesh for ``order=2``), inverted tets reoriented with a warning to build_fem_model's caller."""
    points = np.asarray(points, dtype=float)
    tets = np.asarray(tets, dtype=np.int64)
    if order == 2 and tets.shape[1] == 4:
        points, tets = quadratic_tets(points, tets)
    if tets.shape[1] != (4 if order == 1 else 10):
        raise ValueError(f"order {order} needs tets with {4 if order == 1 else 10} nodes")
    tets, flipped = check_tets(points, tets)
    if len(flipped):
        warnings.warn(f"{len(flipped)} of {len(tets)} tets were inverted (negative volume) and have "
                      f"been reoriented: {index_list(flipped)}", stacklevel=3)
    return points, tets


def _anchor_fields(anchors, n):
    """FemModel fields of the anchor regions ``(selection, velocity)``: anchor_nodes,
    anchor_velocity, node_anchor, free_dofs and fixed_dofs."""
    anchor_nodes = tuple(_node_indices(sel, n) for sel, _ in anchors)
    node_anchor = -np.ones(n, dtype=np.int64)
    for i, nodes in enumerate(anchor_nodes):
        node_anchor[nodes] = i
    fixed = np.repeat(node_anchor >= 0, 3)
    return dict(anchor_nodes=anchor_nodes, node_anchor=node_anchor,
                anchor_velocity=np.array([np.asarray(vel, dtype=float) for _, vel in anchors]).reshape(-1, 3),
                free_dofs=np.nonzero(~fixed)[0], fixed_dofs=np.nonzero(fixed)[0])


def _load_fields(loads, points, surface, node_mass):
    """FemModel fields of the load regions ``(selection, total_force[, "area"])``: load_nodes,
    load_force and node_load (each total spread by lumped mass, or by surface area)."""
    n = len(points)
    load_nodes, load_force = [], []
    node_load = np.zeros((n, 3))
    area = None
    for load in loads:
        nodes, total = _node_indices(load[0], n), np.asarray(load[1], dtype=float)
        spread = load[2] if len(load) > 2 else "mass"
        if spread == "area":
            area = _surface_node_area(points, surface) if area is None else area
            weights = area if area[nodes].sum() > 0 else node_mass
        else:
            weights = node_mass
        node_load[nodes] += _spread_force(nodes, total, weights)
        load_nodes.append(nodes)
        load_force.append(total)
    return dict(load_nodes=tuple(load_nodes), load_force=np.array(load_force).reshape(-1, 3),
                node_load=node_load)


def _plastic_fields(yield_stress, plastic_update_strain, max_plastic_strain, elements):
    """FemModel fields of von Mises plasticity (a purely elastic body when yield_stress is None)."""
    return dict(yield_stress=None if yield_stress is None else float(yield_stress),
                plastic_update_strain=float(plastic_update_strain),
                max_plastic_strain=None if max_plastic_strain is None else float(max_plastic_strain),
                reference_peeq=None if yield_stress is None else np.zeros(elements.tet_weights.shape))


def build_fem_model(points, tets, *, order=1, density, young, poisson, damping_mass=0.0,
                    damping_stiffness=0.0, frame="floating", mass="lumped",
                    integrator="backward_euler", anchors=(), loads=(), dt=None, yield_stress=None,
                    plastic_update_strain=0.02, max_plastic_strain=None, linear_solver="cholmod",
                    corotated_solver="cg", elements_of=None):
    """Build a deformable body.

    points ``(n, 3)`` m and tets ``(t, 4)``: a linear tet mesh (``order=1``), or with ``order=2``
    either the same linear mesh (midside nodes are added, appended after the input points) or a
    tetra10 mesh ``(t, 10)``. Inverted tets are reoriented, degenerate ones raise ValueError.
    density kg/m^3, young Pa, poisson -, damping_mass alpha 1/s, damping_stiffness beta s.
    frame: "floating" | "corotated"; mass: "lumped" | "consistent";
    integrator: "backward_euler" | "newmark".
    anchors: sequence of ``(node_mask_or_indices, velocity (3,))``: those nodes move with the
        prescribed velocity (m/s); node indices refer to the returned model's nodes.
    loads: sequence of ``(node_indices, total_force (3,))`` or ``(nodes, total_force, "area")``:
        a constant total force (N) spread over the nodes by lumped mass (default) or by surface
        area.
    dt: if given, the system matrix for this step size (s) is factorised now.
    yield_stress: von Mises yield stress (Pa); None (default) for a purely elastic body.
    plastic_update_strain: accumulated equivalent plastic strain between reference-shape updates.
    max_plastic_strain: cap on the equivalent plastic strain, or None.
    linear_solver: "cholmod" | "superlu", the sparse backend of its factorisations ("superlu", with
        a warning, when cholespy is not installed); corotated_solver: "cg" | "lu" (corotated frame).
    elements_of: ``(parent, tet_index)`` when the mesh is elements ``tet_index`` of the FemModel
        ``parent`` (same material and rest points, ``tets`` renumbered, same order; a fracture
        piece): its matrices and element data are then taken from the parent's element blocks
        (:func:`fem.assembly.assemble_subset`) instead of assembled again, and the parent's
        checked orientation is kept.
    Returns a :class:`FemModel`. Note: with ``order=2`` from a linear mesh, select anchor/load
    nodes on ``fem.mesh.quadratic_tets(points, tets)[0]`` (same as ``model.rest_points``).
    """
    if frame not in FRAMES or integrator not in INTEGRATORS or mass not in MASSES \
            or corotated_solver not in COROTATED_SOLVERS:
        raise ValueError(f"frame in {FRAMES}, integrator in {INTEGRATORS}, mass in {MASSES}, "
                         f"corotated_solver in {COROTATED_SOLVERS}")
    linear_solver = available_linear_solver(linear_solver)
    if elements_of is None:
        points, tets = _checked_mesh(points, tets, order)
        K, M_scalar, elements = assemble(points, tets, young, poisson, density)
    else:
        parent, tet_index = elements_of
        points, tets = np.asarray(points, dtype=float), np.asarray(tets, dtype=np.int64)
        if tets.shape[1] != parent.tets.shape[1] or order != parent.order or \
                (young, poisson) != (parent.young, parent.poisson):
            raise ValueError("elements_of: the parent's element order, Young's modulus and "
                             "Poisson ratio must be the piece's")
        K, M_scalar, elements = assemble_subset(parent.elements, parent.tets, tet_index, tets,
                                                density)
    node_mass, M = _mass_matrices(M_scalar, mass)
    rest_center = node_mass @ points / node_mass.sum()
    surface = surface_triangles(tets)
    model = FemModel(
        rest_points=points, tets=tets, order=order, density=float(density), young=float(young),
        poisson=float(poisson), mu=young / (2 * (1 + poisson)),
        lam=young * poisson / ((1 + poisson) * (1 - 2 * poisson)), damping_mass=float(damping_mass),
        damping_stiffness=float(damping_stiffness), frame=frame, integrator=integrator,
        mass_kind=mass, node_mass=node_mass, K=K, M=M, elements=elements, rest_center=rest_center,
        rest_offsets=points - rest_center, surface=surface, surface_nodes=np.unique(surface),
        **_anchor_fields(anchors, len(points)), **_load_fields(loads, points, surface, node_mass),
        **_plastic_fields(yield_stress, plastic_update_strain, max_plastic_strain, elements),
        linear_solver=linear_solver, corotated_solver=corotated_solver)
    if dt is not None and frame == "floating":
        system_factorisation(model, dt)
    return model


def rest_state(model, x=None, v=None):
    """State at rest (or with given positions ``x`` (n, 3) m and velocities ``v`` (n, 3) m/s);
    the best-fit frame is computed from ``x``."""
    x = model.rest_points.copy() if x is None else np.array(x, dtype=float)
    v = np.zeros_like(x) if v is None else np.array(v, dtype=float)
    R, c = body_frame(model, x)
    state = FemState(x=x, v=v, R=R, c=c, node_reaction=np.zeros_like(x))
    if model.plastic:
        state = state.replace(**initial_plastic_fields(model))
    return state
