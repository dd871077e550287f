"""The coupled step: rigid bodies and FEM bodies advanced together with two-way contact.

    step(model, state, dt) -> state

FEM surface nodes in contact enter the contact solver as particles that answer impulses through
their body's exact implicit response (fem.contact_response), so rigid bodies, planes and
deformable bodies exchange momentum through one impulse mechanism (rigid.step.resolve_contacts).
The impulses a body's nodes receive are then fed through that body's own implicit system, which
gives the velocities the solver expected. Node contacts keep their impulses from one step to the
next (hybrid.coupling.memory) to warm-start the solver: resting contact converges in few sweeps.
Each stage owns one index space: bodies (rigid and FEM), stacked surface nodes
(hybrid.coupling.nodes), contacts (hybrid.coupling.detect) and solver bodies
(hybrid.coupling.problem).
"""
from dataclasses import replace

import numpy as np

from fem import dynamics as fem_dyn
from fem.model import holding
from rigid import step as rigid_step

from . import held, resting
from .auto import auto_bodies, fem_due, scene_indices
from .touches import Touches, held_touches
from .detect import detect_all
from .events import between_steps
from .memory import ContactMemory, contact_keys
from .nodes import SurfaceNodes
from .problem import build_problem, log  # noqa: F401  (log: the step's messages)
from .solve import integrate, solve
from .switch import elastify
from .stability import MAX_DISTANCE, MAX_SPEED, InstabilityError, check_finite  # noqa: F401


# a held set's factorisation expected to take this long (s) or longer is said in the log
REPORT_AFTER = 2.0


def next_time(time, dt):
    """The simulated time ``dt`` after ``time`` (s), on the grid of multiples of ``dt`` when
    ``time`` is on it: adding the step each time left 0.06750000000000005 after 135 steps of
    0.5 ms in events and frames (one rounding, of the multiple, and no sum of them)."""
    after = time + dt
    count = round(after / dt)
    return count * dt if abs(after - count * dt) <= 1e-6 * dt else after


def step(model, state, dt=None):
    """Advance every body by one time step ``dt`` (s; default the scene's ``model.dt``). Pure:
    the same model and state give the same new state (the model's caches only memoise). Raises
    InstabilityError naming the body whose state diverged."""
    dt = model.dt if dt is None else dt
    if not model.fem:
        rigid, touched = rigid_step.step(model.rigid, state.rigid, dt, model.gravity, model.settings)
        auto = auto_bodies(model)
        touches = Touches.of(auto, *touched, scene_indices(model)) if len(auto) else None
        new = replace(state, rigid=rigid, time=next_time(state.time, dt), steps=state.steps + 1,
                      touches=touches)
    else:
        new = coupled_step(model, state, dt)
        # a held body's resting nodes let go: again, them free; a large new resting patch: again,
        # it held at once
        while isinstance(new, (held.LetGo, held.HoldNow)):
            state = held.released(model, state, new) if isinstance(new, held.LetGo) \
                else held.held_now(model, state, new)
            new = coupled_step(model, state, dt)
    check_finite(model, new)
    return new


def advance(model, state, timings=None, stepped=None):
    """One step of the simulation: ``(model, state, events)``. The bodies step (:func:`step`);
    a rigid auto body the step would strain past its threshold makes it be taken again with that
    body deformable (hybrid.coupling.auto.fem_due, before the step is kept); then the events
    between steps (hybrid.coupling.events.between_steps: reference-shape updates, fracture, auto
    bodies turning rigid). ``timings``: see hybrid.coupling.fracture.apply_fracture.
    ``stepped(model, state, start)``, if given, is called with them after the step, before its
    events, ``start`` the state the step was taken from (with ``model``: an auto body that turned
    deformable for the step is deformable in it)."""
    new, switched = step(model, state), []
    due = fem_due(model, state, new)
    while due:
        model, state, events = elastify(model, state, due)
        switched += events
        new = step(model, state)
        due = fem_due(model, state, new)
    if stepped is not None:
        stepped(model, new, state)
    model, new, events = between_steps(model, new, timings)
    return model, new, switched + events


def coupled_step(model, state, h):
    """One step of ``h`` s with FEM bodies: the new HybridState, or held.LetGo when a body's held
    resting nodes must let go (the caller takes the step again with them free)."""
    # 1. deformable bodies: implicit step without contact (prefactored system), a body resting on
    #    static ground with its resting nodes held; rigid bodies: leapfrog kick
    hold = held.hold_sets(model, state)
    fems = [m if r is None else _holding(m, r.nodes, model.names[i])
            for m, r, i in zip(model.fem, hold, model.fem_ids)]
    predicted = [fem_dyn.predict(m, s, h, model.gravity,
                                 None if r is None else resting.held_velocity(m, s, r, h))
                 for m, s, r in zip(fems, state.fem, hold)]
    v, v_at_t, gvec = rigid_step.kick(model.rigid, state.rigid, h, model.gravity)
    frames = rigid_step.frames(model.rigid, state.rigid)
    rigid_bodies = rigid_step.solver_bodies(model.rigid, state.rigid, v, v_at_t, gvec, frames)

    # 2. contacts of every kind; held nodes leave the solver (their contacts with static ground
    #    are the hold's), as do those of a body only nearing static ground (they take nothing)
    nodes = SurfaceNodes.of(model, state, predicted, h)
    found = detect_all(model, state, nodes, rigid_bodies, h, frames[0])
    rows, let_go = held.held_rows(hold, nodes, found)
    if let_go is not None:
        return let_go
    rows |= held.idle_rows(hold, nodes, found, h)
    hold_now = held.first_sight(model, state, hold, nodes, found, h)
    if hold_now is not None:
        return hold_now

    # 3. one contact problem over rigid bodies, touched nodes and places; solved, each touched
    #    deformable body taking its nodes' impulses through its own implicit system
    problem = build_problem(model, state, fems, predicted, nodes, found, rows, rigid_bodies, h)
    res = solve(model, state, fems, predicted, nodes, problem, h)

    # 4. rigid drift; deformable bodies finish their steps
    new_rigid, new_fem = integrate(model, state, fems, predicted, nodes, problem, res, v, h)

    # 5. held nodes: the impulses they took must push and stick, else the step is taken again;
    #    the impulses of node contacts are remembered for the next step, resting sets watched
    start = found.rigid.count
    row_impulse, let_go = held.hold_impulses(model, hold, nodes, found, rows, new_fem,
                                             res.contact_impulse[start:start + problem.node_rows], h)
    if let_go is not None:
        return let_go
    c_held = found.nodes.take(rows)
    auto = auto_bodies(model)
    touches = None if not len(auto) else Touches.of(
        auto, problem.contacts, res.collision_impulse + res.contact_impulse,
        scene_indices(model, problem.parts)).plus(
        held_touches(model, auto, nodes, c_held, row_impulse[rows]))
    keys = np.concatenate([problem.keys, contact_keys(c_held.body_a, c_held.body_b, nodes.count,
                                                      model.rigid.body_count, False)])
    memory = ContactMemory.of(keys, np.concatenate([res.contact_impulse, row_impulse[rows]]))
    # history the step does not change (faces waiting to open) carries over
    return replace(state, rigid=new_rigid, fem=new_fem, time=next_time(state.time, h), steps=state.steps + 1,
                   contact_memory=memory, resting=held.watch(model, state, nodes, found, row_impulse),
                   contact_sets=problem.contact_sets, touches=touches)


def _holding(model, nodes, name):
    """fem.model.holding of a resting set's ``nodes`` (sorted and distinct): the variant kept for
    them when they are the last asked for (``model.cache.held``), without holding's np.unique
    (22 us for a set of 441 nodes, every step). A new set whose factorisation will take a while
    (as long as the body's own took, over REPORT_AFTER s) is said in the log, naming the body
    ``name``: a 50k-tet block landing stalled 8 s at a time with nothing said."""
    last = model.cache.held
    if last is not None and np.array_equal(last.held_nodes, nodes):
        return last
    seconds = model.cache.factor.seconds
    if seconds >= REPORT_AFTER:
        log.info("%s: holding %d resting nodes: factorising its system with them held (about %.0f s)",
                 name, len(nodes), seconds)
    return holding(model, nodes)
