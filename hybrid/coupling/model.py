"""The coupled model (constant during a run) and state (everything that changes)."""
from dataclasses import dataclass, field

import numpy as np

from rigid.step import ContactSettings


@dataclass
class HybridModel:
    """Everything constant during a run.

    rigid: RigidModel of the rigid bodies; rigid_ids (r,) scene index of each rigid body.
    fem: list of FemModel, one per deformable body; fem_ids: scene index of each.
    names: every body's name in scene order (fragments appended as they appear).
    gravity (3,) m/s^2. dt s. settings: ContactSettings. scene: the Scene it was built from.
    fragment_of: per name, the scene index of the body it came from (itself for scene bodies).
    fracture: per FEM body, its fracture data (hybrid.coupling.events), None until first used.
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


@dataclass
class HybridState:
    """Everything that changes: rigid state, one FemState per deformable body, time (s), steps,
    the last step's node-contact impulses (hybrid.coupling.step.ContactMemory, a warm start) and each
    deformable body's resting nodes (hybrid.coupling.resting.Resting or None, one per body); both None
    before the first step and after bodies change."""
    rigid: object
    fem: list = field(default_factory=list)
    time: float = 0.0
    steps: int = 0
    contact_memory: object = None
    resting: tuple = None
