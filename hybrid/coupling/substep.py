"""A step taken in sub-steps: an impact shorter than the scene's step is resolved by taking that
step as several shorter ones (each followed by its events: fracture, reference updates, auto
bodies switching), then the scene's step again.

Each sub-step is an ordinary :func:`hybrid.coupling.step.advance` of a model whose ``dt`` is the
sub-step's. A deformable body's factorisation and contact response are kept for one step size
(``fem.solver.FactorCache``, ``fem.contact_response``), so a body factorises once for the
sub-step and once again for the scene's step after it; fracture pieces made during sub-steps are
factorised for the sub-step first.
"""
from dataclasses import replace

from .step import advance, next_time


def advance_in_substeps(model, state, count, timings=None, stepped=None):
    """One step of the scene's ``model.dt`` taken as ``count`` sub-steps of ``model.dt / count``,
    each with the events due after it: ``(model, state, events)`` as :func:`advance` returns
    them, the model with the scene's ``dt`` again, the state one step further (``steps`` + 1)
    at ``time + dt``. ``timings`` and ``stepped`` as for :func:`advance` (``stepped`` is called
    after every sub-step, with the sub-step's model)."""
    dt, steps, time = model.dt, state.steps, state.time
    sub = replace(model, dt=dt / count)
    happened = []
    for _ in range(count):
        sub, state, events = advance(sub, state, timings, stepped)
        happened += events
    return replace(sub, dt=dt), replace(state, steps=steps + 1, time=next_time(time, dt)), happened
