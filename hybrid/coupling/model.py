"""The coupled model (constant during a run) and state (everything that changes)."""
from dataclasses import dataclass, field

import numpy as np

from rigid.step import ContactSettings


@dataclass
class CouplingCache:
    """Memos of the coupled step that depend only on the model and give the same answer whatever
    ran before (so they never change results), built on first use.

    stacked_rows: the last ``(blocks, rigid_count)`` given to the contact problem's row stacking
    and its answer (hybrid.coupling.problem); resting contact asks the same again every step.
    rigid_frames: the rigid bodies' surfaces as the frames write them, stacked, for the last set
    of FEM pieces they were asked with (hybrid.app.observe.frame_pieces).
    """
    stacked_rows: tuple = None
    rigid_frames: tuple = None


@dataclass
class HybridModel:
    """Everything constant during a run.

    rigid: RigidModel of the rigid bodies; rigid_ids (r,) scene index of each rigid body.
    fem: list of FemModel, one per deformable body; fem_ids: scene index of each.
    names: every body's name in scene order (fragments appended as they appear).
    gravity (3,) m/s^2. dt s. settings: ContactSettings. scene: the Scene it was built from.
    fragment_of: per name, the scene index of the body it came from (itself for scene bodies).
    fracture: per FEM body, its :class:`hybrid.coupling.fracture.FractureBody` (what the crack
    search needs of the body's mesh: strength, faces, smoothing, scene origin; None for a body
    that cannot break); None on a model built from a scene until the first fracture check fills
    it (hybrid.coupling.fracture.fracture_data), rebuilt only for the pieces of a split body.
    parked: the auto bodies stepped as rigid bodies now, by scene index: each one's
    :class:`hybrid.coupling.switch.Parked` (its FEM model, kept factorised, and its FEM state
    when it became rigid); empty when none is.
    cache: CouplingCache, the coupled step's memos (a derived model starts with an empty one).
    """
    rigid: object
    rigid_ids: np.ndarray
    fem: list
    fem_ids: list
    names: list
    gravity: np.ndarray
    dt: float
    settings: ContactSettings
    scene: object = None
    fragment_of: list = None
    fracture: list = None
    parked: dict = field(default_factory=dict)
    cache: CouplingCache = field(default_factory=CouplingCache, init=False, compare=False, repr=False)


@dataclass
class HybridState:
    """Everything that changes.

    rigid: RigidState. fem: one FemState per deformable body. time (s), steps.
    Step history, None before the first step and after the bodies change (an event):
    contact_memory: the last step's node-contact impulses (hybrid.coupling.memory.ContactMemory,
    the solver's warm start). resting: per deformable body, its resting nodes
    (hybrid.coupling.resting.Resting or None). contact_sets: per deformable body, the node set
    its contacts were solved on in its last step with contacts ((k,) int64 or None; see
    fem.contact_response.contact_set).
    Event history, kept unchanged by the step and changed only by the events:
    fracture_pending: per deformable body, the crack faces chosen but not open yet, ``(p, 2)``
    int64 rows of (tet, local face j) of the body's mesh (``fem.split.face_tet_slots``; a face
    opens by node duplication only once the crack surface through its nodes reaches the boundary
    or an open crack, so chosen faces wait here until they do); None when no face waits in any
    body (hybrid.coupling.fracture). A split hands each deformable piece its own still-closed
    faces; reference-shape updates keep the tets, so the rows stay valid.
    Auto bodies (hybrid.coupling.auto): touches: the last step's contact impulses on rigid auto
    bodies (:class:`hybrid.coupling.touches.Touches`, None without any); calm: per FEM auto body
    (scene index), how many steps in a row it has been calm enough to become rigid (negative: it
    was deforming, and is looked at again after that many steps). backoff: per
    auto body, the factor its calm window is stretched by (doubled each time it turns deformable
    again within a window of turning rigid, so a body whose contacts settle differently as a
    rigid body does not switch back and forth); rigid_since / fem_since: per auto body, the step
    count when it last turned rigid / deformable.
    """
    rigid: object
    fem: list = field(default_factory=list)
    time: float = 0.0
    steps: int = 0
    contact_memory: object = None
    resting: tuple = None
    contact_sets: tuple = None
    fracture_pending: tuple = None
    touches: object = None
    calm: dict = field(default_factory=dict)
    backoff: dict = field(default_factory=dict)
    rigid_since: dict = field(default_factory=dict)
    fem_since: dict = field(default_factory=dict)
