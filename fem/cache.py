"""What a deformable body's model derives from itself and keeps: :class:`FemCache`.

A :class:`fem.model.FemModel` is constant; the data derived from it (its factorised system
matrix, contact response columns, gravity force, ...) is built the first time a function needs it
and kept in the model's one ``cache``. Every slot is a memo: it holds what the function that fills
it would compute anew from the model alone, or from the exact inputs the slot records with it, so
what ran before never changes an answer. Step history (the last contact set, held nodes, warm
starts) belongs to the state, never here.
"""
from dataclasses import dataclass, field

from fem.solver import FactorCache


@dataclass(eq=False)
class FemCache:
    """Memos of one :class:`fem.model.FemModel`, each slot filled on first use by the function named.

    A model derived with a new shape, new matrices or other prescribed DOFs (an event's new rest
    shape, a held variant) is given an empty cache of its own; ``dataclasses.replace`` alone keeps
    the cache (a fracture fragment's relabelled regions change nothing it holds).

    factor: :class:`fem.solver.FactorCache`, the system matrix and its factorisation for one time
        step (``fem.dynamics.system_matrix``, ``fem.dynamics.system_factorisation``).
    response: the contact response (Delassus blocks and response columns) for one time step
        (``fem.contact_response``), None until a contact asks.
    gravity_force: ``(gravity, force)``: a gravity ``(3,)`` m/s^2 (as a tuple) and its node weights
        ``(n, 3)`` N (``fem.dynamics.gravity_force``).
    mass_weights: ``(n,)`` kg row sums of a consistent mass matrix (``fem.dynamics.mass_weights``).
    point_gradients: shape-function data of the quadrature points
        (``fem.plastic_flow.point_gradients``).
    mean_gradients: ``(t, b, 3)`` shape-function gradients averaged over each element
        (``hybrid.app.peaks.mean_gradients``).
    rotations: ``(x, tet_R)``: positions ``(n, 3)`` m (a copy) and their read-only element rotations
        ``(t, 3, 3)`` (``fem.rotations.element_rotations``).
    elastic_energy: ``(x, plastic_strain, energy)``: positions, plastic strain (copies; None for an
        elastic state) and their elastic energy (J) (``fem.dynamics.energy``).
    held: the variant of the model whose nodes ``held.held_nodes`` are held
        (``fem.model.holding``), the last node set asked for.
    surface_grid: signed-distance grid of the rest surface (``hybrid.coupling.fem_contact``).
    surface_index: ``(tree, triangles, around)`` lookups of the rest surface
        (``hybrid.coupling.fem_contact``).
    current_tree: k-d tree of the surface nodes at the positions it was built from (its ``data``)
        (``hybrid.coupling.fem_contact``).
    extent: the rest shape's largest extent (m) and slenderness (``hybrid.coupling.auto.extent``).
    element_size: edge (m) of a regular tet of the mean element volume (``hybrid.coupling.nodes.element_size``).
    warped_places: where a corotated body's mass and free block sit in its stiffness pattern
        (``fem.system._warped_places``).
    frame_cells: the tets as the frames write them, a read-only copy (a writer process keeps it
        from frame to frame; ``hybrid.app.observe``).
    """
    factor: FactorCache = field(default_factory=FactorCache)
    response: object = None
    gravity_force: tuple | None = None
    mass_weights: object = None
    point_gradients: object = None
    mean_gradients: object = None
    rotations: tuple | None = None
    elastic_energy: tuple | None = None
    held: object = None
    surface_grid: object = None
    surface_index: tuple | None = None
    current_tree: object = None
    extent: tuple | None = None
    element_size: float | None = None
    warped_places: tuple | None = None
    frame_cells: object = None
