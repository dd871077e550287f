"""Events between steps: plastic reference-shape updates, fracture, then auto bodies turning rigid.

    model, state, events = between_steps(model, state)

Each event returns a new model and state (models are never changed) and rebuilds only the bodies
it touched. Plastic reference updates (``fem.reference``) bake large plastic strain into a body's
rest shape and refactorise that body only; fracture (:mod:`hybrid.coupling.fracture`) cracks FEM
bodies and turns their pieces into bodies (:mod:`hybrid.coupling.fragments`). History the events
keep between steps is state (``HybridState.fracture_pending``: crack faces waiting to open), so a
check that only chooses faces returns the same model. Auto bodies calm long enough become rigid
bodies (:mod:`hybrid.coupling.auto`, :mod:`hybrid.coupling.switch`); how many steps each has been
calm is state (``HybridState.calm``).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from fem.reference import apply_reference_updates

from .auto import rigid_due
from .fracture import FractureEvent, apply_fracture, fragment_of
from .stability import InstabilityError
from .switch import rigidify

__all__ = ["between_steps", "apply_fracture", "fragment_of", "FractureEvent", "ReferenceUpdate"]


@dataclass(frozen=True)
class ReferenceUpdate:
    """A body's rest shape absorbed its plastic strain (and its matrix was refactorised).

    time: s. body: the body's name.
    """
    time: float
    body: str

    @property
    def message(self):
        """One line for the run log."""
        return (f"t = {self.time:.6g} s: '{self.body}' took its plastic deformation into its "
                "rest shape")

    def as_dict(self):
        """JSON-ready summary row: time, body, event kind."""
        return {"time": self.time, "body": self.body, "event": "reference_update"}


def between_steps(model, state, timings=None):
    """All events due after a step: reference-shape updates, fracture, auto bodies turning rigid.

    Returns ``(model, state, events)``: events are FractureEvents and ReferenceUpdate records,
    each with ``.message`` and ``.as_dict()``. ``timings``: see :func:`apply_fracture`."""
    events = []
    fem, fem_states, updated = apply_reference_updates(model.fem, state.fem, model.dt)
    for j in updated:
        moved = float(np.abs(fem[j].rest_points - model.fem[j].rest_points).max())
        if not np.isfinite(moved):
            # a plastic flow far beyond small strain (inverted elements) has no rest shape
            raise InstabilityError(model.names[model.fem_ids[j]], float(state.time),
                                   "rest-shape update's plastic displacement (m)", moved)
    if updated:
        # a new rest shape on the same tets: the bodies' fracture data (faces, smoothing) and
        # their crack faces waiting to open (state.fracture_pending) stay as they are
        model = replace(model, fem=fem)
        state = replace(state, fem=fem_states, contact_sets=_forget(state.contact_sets, updated))
        events += [ReferenceUpdate(float(state.time), model.names[model.fem_ids[j]])
                   for j in updated]
    model, state, cracks = apply_fracture(model, state, timings)
    calm, due = rigid_due(model, state)
    model, state, switched = rigidify(model, replace(state, calm=calm), due)
    return model, state, events + cracks + switched


def _forget(contact_sets, bodies):
    """The contact sets with those of ``bodies`` dropped (their models changed)."""
    if contact_sets is None:
        return None
    return tuple(None if j in bodies else s for j, s in enumerate(contact_sets))
