"""Resting contact held as a constraint (hybrid.coupling.resting): a deformable body lying on static
ground steps with its resting nodes held, and must move exactly as the contact solver would
move it, let go when the ground stops pushing, and hold on a slope within its friction cone."""
import math
from dataclasses import replace

import numpy as np
import pytest

SLAB = """
[simulation]
dt = 0.002
[[planes]]
normal = [{nx}, 0.0, {nz}]
[[bodies]]
name = "slab"
model = "fem"
shape = {{ type = "box", size = [0.3, 0.3, 0.06], resolution = 0.05 }}
young = 1.0e6
density = 1000.0
integrator = "{integrator}"
frame = "{frame}"
damping = {{ mass = {damping} }}
position = {position}
orientation = {orientation}
"""

BOX_ON_TOP = """
[[bodies]]
name = "box"
shape = { type = "box", size = [0.1, 0.1, 0.1] }
density = 2000.0
position = [0.0, 0.0, 0.1105]
"""


def slab(integrator="backward_euler", damping=2.0, tilt=0.0, box=True, hold=True, frame="floating"):
    """The slab (and a box on it) on the ground, or on a plane tilted by ``tilt`` degrees about y
    with the slab turned to lie on it; ``hold``: the scene's ``hold_resting``; ``frame``: the
    slab's."""
    t = math.radians(tilt)
    turn = f"[{math.cos(t / 2)}, 0.0, {-math.sin(t / 2)}, 0.0]"     # (w, x, y, z)
    up = 0.0301 * np.array([-math.sin(t), 0.0, math.cos(t)])
    text = SLAB.format(nx=-math.sin(t), nz=math.cos(t), integrator=integrator, frame=frame, damping=damping,
                       orientation=turn, position=[float(u) for u in up])
    solver = "" if hold else "[simulation.solver]\nhold_resting = false\n"
    return text.replace("[[planes]]", solver + "[[planes]]") + (BOX_ON_TOP if box else "")


def positions(s):
    return np.concatenate([s.state.fem[0].x, s.state.rigid.position])


@pytest.mark.parametrize("integrator, frame", [("backward_euler", "floating"), ("newmark", "floating"),
                                               ("backward_euler", "corotated")])
def test_held_slab_moves_as_the_contact_solver_moves_it(sim, integrator, frame):
    """A slab settling on the ground under a box (held once its resting nodes stay the same)
    follows the solver-only trajectory to the solver's own tolerance. The set first held while
    the box still lands grows by the nodes that come to rest later (each set factorised once).
    A corotated slab solves its warped system by CG preconditioned by the held rest system."""
    held = sim(slab(integrator, frame=frame))
    sets, variants = [], []

    def watch(s):
        r = s.state.resting[0]
        sets.append(frozenset(r.nodes.tolist()) if r is not None and r.held else frozenset())
        variant = s.model.fem[0].cache.held
        if variant is not None and not any(variant is v for v in variants):
            variants.append(variant)

    held.advance(0.8, each=watch)
    assert sum(map(bool, sets)) > 100, "the slab was held for too few steps"
    assert any(a and a < b for a, b in zip(sets, sets[1:])), "the held set never grew"
    assert all(v.cache.factor.factor_count == 1 for v in variants)
    if integrator == "backward_euler":      # its loads settle: the whole bottom face rests but
        z = held.model.fem[0].rest_points[:, 2]          # nodes at the very edge of sliding
        assert len(sets[-1]) >= 0.9 * np.sum(z < z.min() + 1e-9)
    free = sim(slab(integrator, hold=False, frame=frame))
    free.advance(0.8)
    assert not any(r is not None and r.held for r in free.state.resting)
    # the solver answers a corotated body through its rest system and ends its coupling rounds
    # at COUPLING_TOL: the free corotated slab sinks into the ground by that much (0.5 um here),
    # the held one stays on it, and they differ by no more than that
    sink = -free.state.fem[0].x[:, 2].min() if frame == "corotated" else 0.0
    assert -held.state.fem[0].x[:, 2].min() < 1e-7
    assert np.abs(positions(held) - positions(free)).max() < 1e-7 + sink
    # the solver stops at 1e-7 of its largest impulse; Newmark carries the difference on in the
    # velocities it alternates (4e-5 m/s of 0.04 here), backward Euler damps it (2e-9 m/s)
    v = free.state.fem[0].v
    assert np.abs(held.state.fem[0].v - v).max() < 1e-6 + 5e-3 * np.abs(v).max()


def test_held_plastic_slab_yields_as_under_the_contact_solver(sim):
    """A plastic slab (yield stress 300 Pa) yielding under the box on it is held like an elastic
    one (its return map does not move nodes) and flows as the solver-only slab does: the same
    plastic strain and positions to the solver's tolerance, through its reference-shape updates."""
    def plastic(hold):
        return slab(hold=hold).replace("young = 1.0e6", "young = 1.0e6\nyield_stress = 300.0")
    held, free = sim(plastic(True)), sim(plastic(False))
    steps = []
    held.advance(0.8, each=lambda s: steps.append(s.state.resting[0] is not None and s.state.resting[0].held))
    free.advance(0.8)
    assert sum(steps) > 100 and not any(r is not None and r.held for r in free.state.resting)
    a, b = held.state.fem[0], free.state.fem[0]
    assert np.abs(b.tet_plastic_strain).max() > 3e-3            # it yields
    assert np.abs(a.tet_plastic_strain - b.tet_plastic_strain).max() < 1e-3 * np.abs(b.tet_plastic_strain).max()
    assert np.abs(positions(held) - positions(free)).max() < 2e-7
    assert len(held.events) == len(free.events) > 0              # reference-shape updates


def test_ground_carries_the_weight_of_a_held_slab_and_its_load(sim):
    """At rest, the impulses the held nodes take per step add up to the weight of the slab and
    the box on it, and they push only along the ground's normal."""
    s = sim(slab(damping=20.0))
    s.advance(0.6)
    assert s.state.resting[0].held
    h, g = s.model.dt, 9.81
    weight = (1000.0 * 0.3 * 0.3 * 0.06 + 2000.0 * 0.1 ** 3) * g
    memory = s.state.contact_memory
    # the ground's contacts among the remembered ones (hybrid.coupling.step.contact_keys: b = -1)
    nodes, bodies = len(s.model.fem[0].surface_nodes), s.model.rigid.body_count
    ground = (memory.keys % (nodes + bodies + 1) == nodes) & (memory.keys < nodes * (nodes + bodies + 1))
    total = memory.impulse[ground].sum(axis=0) / h
    assert total[2] == pytest.approx(weight, rel=2e-3)
    assert abs(total[0]) < 1e-3 * weight and abs(total[1]) < 1e-3 * weight


def test_held_nodes_let_go_when_the_slab_is_thrown_up(sim):
    """A held slab given 1 m/s upwards: the ground would have to pull, so the step is taken again
    with the nodes free, and the slab flies as it does without holding."""
    def thrown(s):
        s.advance(0.3)
        fem = s.state.fem[0]
        s.state = replace(s.state, fem=[fem.replace(v=fem.v + [0.0, 0.0, 1.0])])
        z0 = s.state.fem[0].c[2]
        s.advance(0.05)
        return s, z0

    held, z0 = thrown(sim(slab(box=False)))
    record = held.state.resting[0]
    assert record is None or not record.held
    rise = held.state.fem[0].c[2] - z0
    # flight with the slab's mass damping a = 2/s: z = (v0 + g/a)(1 - e^-at)/a - g t/a
    t, a, g = 0.05, 2.0, 9.81
    assert rise == pytest.approx((1.0 + g / a) * (1.0 - math.exp(-a * t)) / a - g * t / a, rel=0.03)
    free, _ = thrown(sim(slab(box=False, hold=False)))
    assert np.abs(positions(held) - positions(free)).max() < 1e-7


@pytest.mark.parametrize("frame", ["floating", "corotated"])
def test_slab_held_on_a_slope_inside_its_friction_cone(sim, frame):
    """On a 20 degree slope (tan 20 = 0.36 < mu = 0.5) the slab sticks: it is held, its reactions
    carry m g sin 20 along the slope and m g cos 20 across it, and it does not slide; a corotated
    slab too (its warped system solved by CG, preconditioned by the held rest system)."""
    s = sim(slab(damping=20.0, tilt=20.0, box=False, frame=frame))
    s.advance(0.4)
    c0 = s.state.fem[0].c.copy()
    s.advance(0.2)
    assert s.state.resting[0].held
    t = math.radians(20.0)
    n = np.array([-math.sin(t), 0.0, math.cos(t)])
    along = np.array([math.cos(t), 0.0, math.sin(t)])
    weight = 1000.0 * 0.3 * 0.3 * 0.06 * 9.81
    total = s.state.contact_memory.impulse.sum(axis=0) / s.model.dt
    assert total @ n == pytest.approx(weight * math.cos(t), rel=2e-3)
    assert total @ along == pytest.approx(weight * math.sin(t), rel=2e-3)
    assert np.linalg.norm(s.state.fem[0].c - c0) < 1e-6


def _wide(text):
    """The slab of :func:`slab` 0.6 m wide (169 nodes on its bottom face), laid on the ground."""
    return text.replace("size = [0.3, 0.3, 0.06]", "size = [0.6, 0.6, 0.06]") \
        .replace(", 0.0301]", ", 0.03]").replace("position = [0.0, 0.0, 0.1105]", "position = [0.0, 0.0, 0.1104]")


@pytest.mark.parametrize("integrator", ["backward_euler", "newmark"])
def test_a_large_face_laid_on_the_ground_is_held_at_first_sight(sim, integrator):
    """A slab laid on the ground with a box on it, its bottom face of 169 nodes (at least
    resting.FIRST_SIGHT), is held from its first step: the face's response columns (three
    back-substitutions a node) are never solved, and the slab and the box move as the contact
    solver moves them. The corners and rim, sliding outwards as the slab spreads under the box,
    let go by themselves while the rest stays held."""
    from fem.contact_response import response_cache
    held = sim(_wide(slab(integrator)))
    counts = []
    held.advance(0.3, each=lambda s: counts.append(len(s.state.resting[0].nodes)
                                                   if s.state.resting[0] is not None and s.state.resting[0].held else 0))
    assert counts[0] == 169 and min(counts) >= 100, counts
    assert len(response_cache(held.model.fem[0], held.model.dt).known) < 100
    free = sim(_wide(slab(integrator, hold=False)))
    free.advance(0.3)
    assert np.abs(positions(held) - positions(free)).max() < 1e-7
    v = free.state.fem[0].v
    assert np.abs(held.state.fem[0].v - v).max() < 1e-6 + 5e-3 * np.abs(v).max()


def test_a_large_face_landing_flat_is_held_from_the_step_it_lands(sim):
    """The wide slab dropped 5 mm: while it falls within reach of the ground its contacts close
    no gap and nothing else touches it, so they leave the solver (they take no impulse) and its
    face's response columns are not solved; the step it lands, the face is held at first sight.
    It moves as the contact solver moves it."""
    from fem.contact_response import response_cache
    drop = _wide(slab(box=False)).replace(", 0.03]", ", 0.035]")
    held = sim(drop)
    counts = []
    held.advance(0.2, each=lambda s: counts.append(len(s.state.resting[0].nodes)
                                                   if s.state.resting[0] is not None and s.state.resting[0].held else 0))
    landing = next(i for i, c in enumerate(counts) if c)
    # free fall of 5 mm at g takes 32 ms, 16 steps of 2 ms
    assert 13 <= landing <= 17 and counts[landing] == 169, (landing, counts[:20])
    assert len(response_cache(held.model.fem[0], held.model.dt).known) == 0
    free = sim(_wide(slab(box=False, hold=False)).replace(", 0.03]", ", 0.035]"))
    free.advance(0.2)
    assert np.abs(positions(held) - positions(free)).max() < 1e-7


def test_a_held_set_whose_factorisation_takes_long_is_said_in_the_log(sim, monkeypatch):
    """A 50k-tet block landing stalled 8 s at a time (its held system factorised) with nothing
    said: a new held set whose factorisation will take as long as the body's own did, over
    REPORT_AFTER s, is said in the run's log before it is factorised, naming the body."""
    from hybrid.coupling import step
    messages = []
    s = sim(_wide(slab()))
    monkeypatch.setattr(step, "REPORT_AFTER", 0.0)     # (this slab factorises in milliseconds)
    s.run(until=0.01, progress=False, log=messages.append)
    held = [m for m in messages if "holding" in m]
    assert held and held[0].startswith("slab: holding 169 resting nodes: factorising its system"), messages
    monkeypatch.setattr(step, "REPORT_AFTER", 1e9)
    quiet = []
    sim(_wide(slab())).run(until=0.01, progress=False, log=quiet.append)
    assert not [m for m in quiet if "holding" in m]
