"""The hard-case table: deliberately hard scenes run to their end, each row saying whether it
stayed stable and how well it kept the physics, written to docs/hard-cases.md.

    OPENBLAS_NUM_THREADS=1 python benchmarks/hard_cases.py            # every row, ~10 minutes
    python benchmarks/hard_cases.py --only cubes heavy                # rows whose name contains these
    python benchmarks/hard_cases.py --short                           # the tests' shortened runs

The scenes are the files of benchmarks/scenes/hard/ (each runs on its own with ``hybrid run``),
some with settings changed per row (``bodies.<name>.<field>``, as ``hybrid sweep --set`` takes
them). Every row is measured the same way, from the start state and every recorded step:

- outcome: ``stable`` when the run ended and every check of the row held; the watchdog's message
  (hybrid.coupling.stability) when the run diverged; else the first check that failed.
- energy: the most total energy (kinetic + elastic + gravitational) ever gained over the start,
  as a share of the energy in play (the largest kinetic energy, or the energy released, whichever
  is larger). Contacts and backward Euler only take energy out, so any gain is an error.
- momentum: in free space (no ground, no fixed body, no anchor) the largest change of the total
  linear momentum (exact: 1e-9) and of the angular momentum (first order in the step where
  deformable bodies meet: 2e-2) against what the bodies carry (hybrid.app.observe.momentum_scales);
  where the ground or anchors push, the momentum left at the end against the largest of the run
  (it rests).
- penetration: the deepest any node or rigid vertex went inside another body or below a plane,
  over the recorded steps (m).
- wall time: of the stepping alone.

tests/test_hard_cases.py runs the same rows shortened (``Case.short``) and asserts the same
checks. The table is written to docs/hard-cases.md and outputs/bench/hard_cases.csv.
"""
import argparse
import csv
import os
import sys
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from hybrid import InstabilityError, Simulation
from hybrid.app.observe import momentum_scales, totals
from hybrid.app.scene import parse_scene
from hybrid.app.variants import apply_setting
from hybrid.coupling.stability import StepFailure
from rigid import quaternion as quat
from rigid.contacts import detect_points
from rigid.sdf import point_triangle_distance_squared

ROOT = Path(__file__).resolve().parent.parent
SCENES = ROOT / "benchmarks" / "scenes" / "hard"
sys.path.insert(0, str(ROOT / "benchmarks"))
from _common import write_csv  # noqa: E402


# ---------------------------------------------------------------- measuring a state

def penetration(model, state):
    """The deepest (m, >= 0) any FEM node or rigid surface vertex lies inside another body or
    below a plane: planes by their equation, rigid bodies by their own contact detection (signed
    distance), FEM bodies by a point-in-tet test and the distance to their surface."""
    rm, rs = model.rigid, state.rigid
    R = quat.to_matrix(rs.orientation) if rm.body_count else np.zeros((0, 3, 3))
    # every body's points in the world: (points, owner) with FEM bodies first
    clouds = [(s.x[m.surface_nodes], ("fem", j)) for j, (m, s) in enumerate(zip(model.fem, state.fem))]
    clouds += [(rs.position[i] + rm.surface_vertices[i] @ R[i].T, ("rigid", i))
               for i in range(rm.body_count) if not rm.body_fixed[i]]
    deepest = 0.0
    for x, owner in clouds:
        for p, n in zip(rm.plane_point, rm.plane_normal):
            deepest = max(deepest, float(-((x - p) @ n).min(initial=0.0)))
        if rm.body_count:
            k = len(x)
            hits = detect_points(rm, rs.position, R, x, np.zeros(k), np.zeros(rm.body_count), 0.0,
                                 np.zeros(k), np.zeros(k))
            own = hits.body_b == owner[1] if owner[0] == "rigid" else np.zeros(len(hits.gap), bool)
            mine = (hits.body_b >= 0) & ~own
            deepest = max(deepest, float(-hits.gap[mine].min(initial=0.0)))
    for j, (m, s) in enumerate(zip(model.fem, state.fem)):
        low, high = s.x.min(axis=0), s.x.max(axis=0)
        for x, owner in clouds:
            if owner == ("fem", j):
                continue
            near = np.all((x >= low) & (x <= high), axis=1)
            if near.any():
                deepest = max(deepest, _depth_inside(m, s, x[near]))
    return deepest


def _depth_inside(m, s, points):
    """The deepest of ``points`` (k, 3) inside FEM body (model ``m``, state ``s``): 0 when none
    is inside any of its tets, else its distance to the body's surface (m)."""
    corners = s.x[m.tets[:, :4]]                                    # (t, 4, 3)
    T = np.transpose(corners[:, 1:] - corners[:, :1], (0, 2, 1))    # (t, 3, 3) columns: edges
    ok = np.abs(np.linalg.det(T)) > 0
    inverse = np.zeros_like(T)
    inverse[ok] = np.linalg.inv(T[ok])
    inside = np.zeros(len(points), bool)
    for start in range(0, len(points), 256):
        p = points[start:start + 256]
        w = np.einsum("tij,ktj->kti", inverse, p[:, None, :] - corners[None, :, 0])   # (k, t, 3)
        tol = -1e-9
        hit = (w >= tol).all(axis=2) & (w.sum(axis=2) <= 1 - tol) & ok[None]
        inside[start:start + 256] = hit.any(axis=1)
    if not inside.any():
        return 0.0
    q = points[inside]
    tri = s.x[m.surface[:, :3]]
    k, f = len(q), len(tri)
    d2 = point_triangle_distance_squared(np.repeat(q, f, axis=0), np.tile(tri[:, 0], (k, 1)),
                                         np.tile(tri[:, 1], (k, 1)), np.tile(tri[:, 2], (k, 1)))
    return float(np.sqrt(d2.reshape(k, f).min(axis=1)).max())


def free_space(model):
    """Whether nothing outside the bodies pushes them (no plane, no fixed body, no anchor, no
    gravity): then momentum is conserved."""
    rm = model.rigid
    return (len(rm.plane_point) == 0 and not rm.body_fixed.any()
            and not any(m.has_anchors for m in model.fem) and not np.any(model.gravity))


# ---------------------------------------------------------------- the rows

@dataclass
class Run:
    """What a row's run measured. ``outcome``: ``stable``, the watchdog's message, or the failed
    check; the rest as in the module docstring, plus ``extra`` (the row's own figures)."""
    outcome: str = "stable"
    unstable: str = None
    energy_gain: float = 0.0
    momentum: float = 0.0
    angular: float = 0.0
    momentum_kind: str = "drift"
    penetration: float = 0.0
    wall: float = 0.0
    steps: int = 0
    time: float = 0.0
    extra: dict = field(default_factory=dict)
    checks: list = field(default_factory=list)


@dataclass
class Case:
    """One row. ``scene``: file stem in benchmarks/scenes/hard/; ``settings``: changes to it;
    ``hard``: what makes it hard; ``short``: the tests' duration (s); ``watch``: a function
    ``(sim, run)`` called after every recorded step to fill ``run.extra``; ``checks``: a function
    ``(run) -> [(what, held)]`` of the row's physics; ``max_penetration`` (m),
    ``max_energy_gain`` and ``max_angular_drift`` (shares) the common bounds; ``every``: steps
    between measurements; ``cause``: why the row fails, for the table, where it is a known limit."""
    name: str
    scene: str
    hard: str
    settings: dict = field(default_factory=dict)
    duration: float = None
    short: float = 0.1
    watch: object = None
    checks: object = None
    max_penetration: float = 2e-3
    max_energy_gain: float = 1e-3
    max_angular_drift: float = 2e-2
    every: int = 1
    cause: str = None       # why the row fails, where it does (docs/limits.md has the detail)


def load(case, duration=None):
    """The row's Simulation (its scene file with its settings), and the duration to run (s)."""
    path = SCENES / f"{case.scene}.toml"
    data = tomllib.loads(path.read_text())
    for key, value in case.settings.items():
        apply_setting(data, key, value)
    scene = parse_scene(data, str(path), path.parent)
    until = duration or case.duration or scene.simulation.duration
    return Simulation(scene), until


def run_case(case, duration=None, log=None):
    """Run one row (to ``duration`` s, default the row's) and measure it: a :class:`Run`."""
    sim, until = load(case, duration)
    out = Run()
    E0, P0, L0 = totals(sim.model, sim.state)
    free = free_space(sim.model)
    energies, momenta, peak_p = [E0], [], 0.0
    kinetic = []
    steps = int(round(until / sim.dt))
    wall = 0.0
    for k in range(steps):
        t0 = time.perf_counter()
        try:
            sim.step()
        except Exception as error:      # noqa: BLE001 (the row's outcome, as a run's)
            failure = error if isinstance(error, InstabilityError) else StepFailure.of(sim.time, error)
            out.unstable = str(failure)
            wall += time.perf_counter() - t0
            break
        wall += time.perf_counter() - t0
        if (k + 1) % case.every and k + 1 < steps:
            continue
        E, P, L = totals(sim.model, sim.state)
        energies.append(E)
        kinetic.append(_kinetic(sim))
        lin, ang = momentum_scales(sim.model, sim.state)
        if free:
            momenta.append((np.linalg.norm(P - P0) / max(lin, 1e-300),
                            np.linalg.norm(L - L0) / max(ang, 1e-300)))
        else:
            peak_p = max(peak_p, lin)
            momenta.append(lin)
        out.penetration = max(out.penetration, penetration(sim.model, sim.state))
        if case.watch is not None:
            case.watch(sim, out)
    out.wall, out.steps, out.time = wall, sim.steps, sim.time
    energies = np.array(energies)
    in_play = max(max(kinetic, default=0.0), E0 - energies.min())
    out.energy_gain = float(max(energies.max() - E0, 0.0) / in_play) if in_play > 0 else 0.0
    if free:
        out.momentum, out.angular = (float(x) for x in np.max(momenta, axis=0)) if momenta else (0.0, 0.0)
    else:
        out.momentum_kind = "left"
        out.momentum = float(momenta[-1] / peak_p) if momenta and peak_p > 0 else 0.0
    out.checks = [("energy gain", out.energy_gain <= case.max_energy_gain),
                  ("penetration", out.penetration <= case.max_penetration)]
    if free:
        # linear momentum is exact; angular momentum changes at first order in the step where
        # deformable bodies meet (hybrid.coupling.fem_contact: 1.6% at 1 ms for a glancing hit)
        out.checks += [("linear momentum", out.momentum <= 1e-9),
                       ("angular momentum", out.angular <= case.max_angular_drift)]
    if case.checks is not None and out.unstable is None:
        # shortened runs (the tests) end before the bodies settle or the pane is in pieces: the
        # checks of the end state ("at end: ...") are for full runs only
        out.checks += [(what, held) for what, held in case.checks(out)
                       if duration is None or not what.startswith("at end")]
    failed = [what for what, held in out.checks if not held]
    if out.unstable is not None:
        out.outcome = out.unstable
    elif failed:
        out.outcome = "fails: " + ", ".join(failed)
    if log is not None:
        log(f"{case.name}: {out.outcome}; {out.steps} steps in {out.wall:.1f} s; {out.extra}")
    return out


def _kinetic(sim):
    """Kinetic energy of every body (J)."""
    from fem import dynamics as fem_dyn
    from rigid.model import kinetic_energy, reported_velocity
    rm, rs = sim.model.rigid, sim.state.rigid
    total = sum(fem_dyn.kinetic_energy(m, s) for m, s in zip(sim.model.fem, sim.state.fem))
    if rm.body_count:
        v = reported_velocity(rm, rs, sim.model.gravity)
        total += float(np.where(rm.body_fixed, 0.0, kinetic_energy(rm, rs, v)).sum())
    return float(total)


# ---------------------------------------------------------------- the rows' own figures

def _keep(run, key, value, how=max):
    """``run.extra[key]`` updated with ``value`` by ``how`` (max, min, or None: the latest)."""
    run.extra[key] = value if how is None or key not in run.extra else how(run.extra[key], value)


def _speeds(sim):
    """The largest speed of any moving body's centre of mass (m/s)."""
    return max(float(np.linalg.norm(sim.body(n).velocity)) for n in _moving(sim))


def _moving(sim):
    fixed = {b.name for b in sim.scene.bodies if b.fixed}
    return [n for n in sim.body_names if n not in fixed]


def settles(top, bottom, height, tol=2e-3):
    """Watch and checks of a body ``top`` resting on ``bottom``: the end speed of every body,
    ``top``'s height over ``bottom``'s (centres, m) against ``height``, and ``bottom``'s sideways
    drift (m)."""
    def watch(sim, run):
        a, b = sim.body(top), sim.body(bottom)
        _keep(run, "end speed (m/s)", _speeds(sim), None)
        _keep(run, "height (m)", float(a.position[2] - b.position[2]), None)
        start = run.extra.setdefault("_start", b.position[:2].copy())
        _keep(run, "drift (m)", float(np.linalg.norm(b.position[:2] - start)))

    def checks(run):
        return [("at end: at rest", run.extra["end speed (m/s)"] < 0.01),
                (f"{top} on {bottom}", abs(run.extra["height (m)"] - height) < tol),
                (f"{bottom} stays under {top}", run.extra["drift (m)"] < 0.01)]
    return watch, checks


def _volume_ratio(sim, name):
    """Volume of FEM body ``name`` now over its rest volume."""
    j = [int(k) for k in sim.model.fem_ids].index(sim.model.names.index(name))
    m, s = sim.model.fem[j], sim.state.fem[j]
    x, X = s.x[m.tets[:, :4]], m.rest_points[m.tets[:, :4]]
    return float(np.linalg.det(x[:, 1:] - x[:, :1]).sum() / np.linalg.det(X[:, 1:] - X[:, :1]).sum())


def rubber_watch(sim, run):
    _keep(run, "volume change", abs(_volume_ratio(sim, "rubber") - 1.0))
    _keep(run, "end speed (m/s)", _speeds(sim), None)


def rubber_checks(run):
    return [("volume kept to 3%", run.extra["volume change"] < 0.03),
            ("at end: at rest", run.extra["end speed (m/s)"] < 0.01)]


def ball_watch(sim, run):
    ball = sim.body("ball")
    _keep(run, "lowest ball centre (m)", float(ball.position[2]), min)
    _keep(run, "ball velocity (m/s)", float(ball.velocity[2]), None)


def ball_checks(run):
    # the plate's mid-surface is z = 0, its bottom z = -0.01: the ball's centre stays above it
    return [("ball stopped by the plate", run.extra["lowest ball centre (m)"] > -0.01),
            ("ball turned back", run.extra["ball velocity (m/s)"] >= 0.0)]


def fragments_watch(sim, run):
    _keep(run, "fragments", len(sim.body_names) - 1, None)


def fragments_checks(run):
    return [("it shatters", run.extra["fragments"] >= 10),
            ("at end: 100+ fragments", run.extra["fragments"] >= 100)]


def pile_watch(sim, run):
    inside = 0.2 + 0.01
    worst = 0.0
    for name in _moving(sim):
        p = sim.body(name).position
        worst = max(worst, float(np.abs(p[:2]).max() - inside), float(-p[2]))
    _keep(run, "escape (m)", worst)
    _keep(run, "end speed (m/s)", _speeds(sim), None)


def pile_checks(run):
    return [("none escapes the bin", run.extra["escape (m)"] <= 0.0),
            ("at end: at rest", run.extra["end speed (m/s)"] < 0.05)]


def cubes_watch(sim, run):
    spin = max(float(np.linalg.norm(sim.body(n).angular_velocity)) for n in ("left", "right"))
    _keep(run, "spin (rad/s)", spin)
    _keep(run, "parting speed (m/s)", float(sim.body("right").velocity[0] - sim.body("left").velocity[0]),
          None)


def cubes_checks(run):
    return [("they part", run.extra["parting speed (m/s)"] > 0.1),
            ("no turn (solver tolerance)", run.extra["spin (rad/s)"] < 1e-6)]


_STEEL = settles("cube", "block", 0.1)
_HEAVY = settles("box", "slab", 0.06, tol=1e-3)
_LIGHT = settles("box", "slab", 0.06, tol=1e-3)
_STIFF = settles("cube", "block", 0.08)


def _stiffness(young):
    """Watch and checks of the stiffness range at ``young``: the cube's height over the block
    within the block's compression under its own weight and the cube's (m, a static estimate,
    (cube weight / area + rho g L / 2) L / E), at least 2 mm."""
    squeeze = (0.06 ** 3 * 2000.0 * 9.81 / 0.1 ** 2 + 1000.0 * 9.81 * 0.05) * 0.1 / young
    return settles("cube", "block", 0.08, tol=max(2e-3, squeeze))

CASES = [
    Case("steel dt=0.01", "steel_large_dt",
         "E = 2e11 at dt = 0.01 s: the block's stiffest modes are ~1000x faster than the step",
         watch=_STEEL[0], checks=_STEEL[1], short=0.5),
    Case("rubber poisson=0.49", "rubber_incompressible",
         "nearly incompressible (bulk modulus 17 E): volumetric locking, stiff volume modes",
         watch=rubber_watch, checks=rubber_checks, short=0.2),
    *[Case(f"E={young:g} at dt=1e-3", "stiffness_range",
           f"E = {young:g} Pa at the one dt = 1 ms ("
           + ("its own weight strains it ~1" if young < 1e4 else "8 orders of stiffness, one dt") + ")",
           settings={"bodies.block.young": young}, watch=_stiffness(young)[0],
           checks=_stiffness(young)[1], short=0.12, duration=3.0 if young < 1e4 else None,
           cause=None if young > 1e4 else
           "strains of order one (its weight alone: rho g L / E = 1), beyond linear elasticity: "
           "the block is crushed and gives way sideways, nodes end up 0.35-2 cm inside")
      for young in (1e3, 1e5, 1e7, 1e9, 2e11)],
    Case("1000:1 frictionless", "heavy_on_light",
         "a 1,800 kg box on a 1.8 kg slab, no friction: ill-conditioned contact, nothing holds the slab",
         watch=_HEAVY[0], checks=_HEAVY[1], short=0.1,
         cause="the undamped slab rings sideways under the box (its centre at up to 0.27 m/s in "
               "the first 0.4 s, nothing but the step's numerical damping slowing it) and its "
               "speed at the end is a sample of that ringing, not a drift: the box moved 1 nm "
               "to either side ends with the slab at 0.002-0.023 m/s, and contact impulses that "
               "differ by round-off (1e-14) move it across the at-rest check's 0.01 m/s either "
               "way; the box stays put (its end speed 6e-6 to 1.2e-4 m/s)"),
    Case("1000:1 friction 0.5", "heavy_on_light",
         "the same with friction 0.5 on every surface",
         settings={"planes.0.friction": 0.5, "bodies.slab.friction": 0.5, "bodies.box.friction": 0.5},
         watch=_HEAVY[0], checks=_HEAVY[1], short=0.1),
    Case("1:1000 frictionless", "light_on_heavy",
         "a 1.8 kg box on an 1,800 kg slab, no friction: its impulses are 1e-3 of the slab's",
         watch=_LIGHT[0], checks=_LIGHT[1], short=0.1),
    Case("1:1000 friction 0.5", "light_on_heavy", "the same with friction 0.5 on every surface",
         settings={"planes.0.friction": 0.5, "bodies.slab.friction": 0.5, "bodies.box.friction": 0.5},
         watch=_LIGHT[0], checks=_LIGHT[1], short=0.1),
    Case("50 m/s ball, 2 cm plate", "fast_ball_plate",
         "the ball moves 5 cm a step through a 2 cm plate (E = 70 GPa) held on two edges",
         watch=ball_watch, checks=ball_checks, short=0.01),
    Case("sliver and flat tets", "slivers",
         "the input mesh has slivers and nearly flat tets (volume down to 1e-4 of a regular one)",
         watch=_STIFF[0], checks=_STIFF[1], short=0.12),
    Case("100+ fragments", "shatter_small",
         "a glass pane shatters into 100+ pieces that then meet one another",
         # the ball moves 4 mm a step through pieces that are rigid bodies: penetration up to
         # one step of its travel is the resolution of that impact
         watch=fragments_watch, checks=fragments_checks, short=0.0006, every=5,
         max_penetration=4e-3),
    Case("pile of 20 soft bodies", "pile20",
         "20 deformable bodies stacked three deep on the ground and on each other, in a bin",
         watch=pile_watch, checks=pile_checks, short=0.12, every=10),
    Case("cubes face on", "cubes_face_on",
         "coinciding edges: nodes lie exactly on the other cube's edges; mirror symmetry",
         watch=cubes_watch, checks=cubes_checks, short=0.1,
         cause="(stable since places on sharp edges are met the same way for mirror images: "
               "hybrid.coupling.kernels.places)"),
    Case("cubes face on, mu=0.5 Newmark", "cubes_face_on",
         "the same with friction 0.5 and the Newmark integrator (reported at 4.2 rad/s)",
         settings={"bodies.left.friction": 0.5, "bodies.right.friction": 0.5,
                   "bodies.left.integrator": "newmark", "bodies.right.integrator": "newmark"},
         watch=cubes_watch, checks=cubes_checks, short=0.1,
         cause="(stable since places on sharp edges are met the same way for mirror images: "
               "hybrid.coupling.kernels.places)"),
    Case("rigid and soft cubes face on, mu=0.5", "rigid_soft_face_on",
         "a rigid cube's corners and edges lie exactly on the soft cube's edges; mirror symmetry",
         watch=cubes_watch, checks=cubes_checks, short=0.1,
         cause="(stable since a node at a rigid edge that took a face turned away from its own "
               "is met on the face facing it: hybrid.coupling.detect._facing_faces)"),
]


# ---------------------------------------------------------------- the sliver mesh

def sliver_mesh(flatten=1e-4, count=24, seed=3):
    """A 10 cm cube of 8 x 8 x 8 cells (3,072 tets) with ``count`` interior nodes each moved until
    one of its tets keeps ``flatten`` of its volume: nearly flat tets (a node close to the plane of
    the opposite face, inside it: caps; across an edge: slivers). Returns ``(points, tets,
    quality)``, quality (t,) the mean-ratio shape measure (1 for a regular tet, 0 for a flat one)."""
    from fem.mesh import box_tet_mesh, tet_signed_volumes
    points, tets = box_tet_mesh([0.1, 0.1, 0.1], 8)
    rng = np.random.default_rng(seed)
    interior = np.nonzero(np.all(np.abs(points) < 0.05 - 1e-9, axis=1))[0]
    moved = set()
    for node in rng.permutation(interior):
        if len(moved) == count:
            break
        mine = np.nonzero((tets == node).any(axis=1))[0]
        if any(int(n) in moved for n in np.unique(tets[mine])):
            continue                                   # one flattened tet per neighbourhood
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        vol = tet_signed_volumes(points, tets[mine])
        trial = points.copy()
        trial[node] += 1e-3 * direction
        rate = (tet_signed_volumes(trial, tets[mine]) - vol) / 1e-3     # dV/ds along direction
        shrinking = rate < 0
        if not shrinking.any():
            continue
        reach = -vol[shrinking] / rate[shrinking]
        first = np.argmin(reach)
        points[node] += (1.0 - flatten) * reach[first] * direction
        moved.add(int(node))
    return points, tets, mesh_quality(points, tets)


def mesh_quality(points, tets):
    """Mean-ratio quality (t,) of each tet: 6 sqrt(2) V / l_rms^3 (1 regular, 0 flat)."""
    from fem.mesh import tet_signed_volumes
    x = points[tets]
    edges = [x[:, b] - x[:, a] for a, b in ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))]
    l_rms = np.sqrt(np.mean([np.einsum("ij,ij->i", e, e) for e in edges], axis=0))
    return 6.0 * np.sqrt(2.0) * tet_signed_volumes(points, tets) / l_rms ** 3


def write_sliver_mesh(path=SCENES / "slivers.vtu"):
    """Write :func:`sliver_mesh` to ``path`` (the scene slivers.toml reads it)."""
    import meshio
    points, tets, quality = sliver_mesh()
    meshio.write(path, meshio.Mesh(points, [("tetra", tets)]))
    return quality


# ---------------------------------------------------------------- the table

def _figure(value):
    return f"{value:.2g}" if value else "0"


def table_rows(results):
    """Rows (dicts) of the table, one per (case, run)."""
    rows = []
    for case, run in results:
        extra = {k: v for k, v in run.extra.items() if not k.startswith("_")}
        rows.append({
            "scene": case.name, "file": f"{case.scene}.toml", "hard": case.hard,
            "outcome": run.outcome, "simulated (s)": round(run.time, 6), "steps": run.steps,
            "energy gain": run.energy_gain,
            "momentum": (f"drift {_figure(run.momentum)}, angular {_figure(run.angular)}"
                         if run.momentum_kind == "drift" else f"left {_figure(run.momentum)}"),
            "penetration (m)": run.penetration, "wall (s)": round(run.wall, 2),
            "figures": "; ".join(f"{k} {_figure(v) if isinstance(v, float) else v}"
                                 for k, v in extra.items()),
            "cause": "" if run.outcome == "stable" else (case.cause or "not known yet"),
        })
    return rows


def markdown(rows, command, load):
    """docs/hard-cases.md from the table's rows; ``load``: the machine's load averages (1 minute)
    when the run began and ended."""
    lines = [
        "# Hard cases",
        "",
        "Deliberately hard scenes, each run to its end by `benchmarks/hard_cases.py`, which wrote",
        "this page. Reproduce it with:",
        "",
        "```bash",
        command,
        "```",
        "",
        "The scenes are the files of `benchmarks/scenes/hard/` (`hybrid run` runs each one; rows with",
        "settings of their own say so in the script). **outcome**: `stable` when the run ended and",
        "every check of the row held, the watchdog's message when the state diverged, else the",
        "checks that failed. **energy gain**: the most total energy (kinetic, elastic,",
        "gravitational) ever gained over the start, as a share of the energy in play (contacts and",
        "backward Euler only take energy out, so this should be 0). **momentum**: in free space the",
        "largest change of the total linear momentum (`drift`, checked to 1e-9) and of the angular",
        "momentum (`angular`, checked to 2e-2: it changes at first order in the step where",
        "deformable bodies meet, [coupling.md](coupling.md)), each against what the bodies carry;",
        "`left` where the ground or anchors push: the momentum left at the end against the most of",
        "the run (0 at rest). **penetration**: the deepest any node or rigid vertex went",
        "inside another body or below the ground over the measured steps. **wall**: seconds of",
        f"stepping on this project's 2-core machine (load average {load[0]:.1f} when the run began and",
        f"{load[1]:.1f} when it ended; rows rerun alone with `--only` keep the figures of their own run).",
        "`tests/test_hard_cases.py` runs the rows that are stable, shortened, and asserts the same",
        "checks (except those of the end state: at rest, 100+ fragments).",
        "",
        "| scene | what makes it hard | outcome | energy gain | momentum | penetration (m) | wall (s) | row's figures |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r['scene']} (`{r['file']}`, {r['simulated (s)']:g} s) | {r['hard']} | "
                     f"{r['outcome']} | {_figure(r['energy gain'])} | {r['momentum']} | "
                     f"{_figure(r['penetration (m)'])} | {r['wall (s)']:.1f} | {r['figures']} |")
    failing = [r for r in rows if r["outcome"] != "stable"]
    if failing:
        lines += ["", "## Rows that are not stable", "",
                  "Each is a known limit, with its cause and measurements, in [limits.md](limits.md).", ""]
        lines += [f"- **{r['scene']}**: {r['cause']}." for r in failing]
    return "\n".join(lines) + "\n"


def main(argv=None):
    parser = argparse.ArgumentParser(description="The hard-case table: deliberately hard scenes "
                                     "run to their end, written to docs/hard-cases.md.")
    parser.add_argument("--only", nargs="*", default=None, help="rows whose name contains one of these")
    parser.add_argument("--short", action="store_true", help="the tests' shortened runs")
    parser.add_argument("--doc", default=str(ROOT / "docs" / "hard-cases.md"),
                        help="where to write the table (default docs/hard-cases.md; --only rewrites the "
                             "rows it runs in the last full table; --short writes nothing)")
    args = parser.parse_args(argv)
    cases = [c for c in CASES if args.only is None or any(o in c.name for o in args.only)]
    began = os.getloadavg()[0]
    results = []
    for case in cases:
        run = run_case(case, case.short if args.short else None, log=print)
        results.append((case, run))
    rows = table_rows(results)
    for r in rows:
        print(f"{r['scene']:32s} {r['outcome'][:60]:60s} E+{_figure(r['energy gain']):8s} "
              f"{r['momentum']:14s} pen {_figure(r['penetration (m)']):8s} {r['wall (s)']:7.1f} s")
    if args.short:
        return
    # --only: the rows run replace theirs in the last full table, which is written again
    table = ROOT / "outputs" / "bench" / "hard_cases.csv"
    if args.only is not None:
        if not table.exists():
            return
        with table.open() as f:
            old = list(csv.DictReader(f))
        new = {r["scene"]: r for r in rows}
        kept = {r["scene"]: _typed(r) for r in old}
        rows = [new.get(c.name, kept.get(c.name)) for c in CASES if c.name in new or c.name in kept]
    write_csv(table, rows)
    stable = sum(r["outcome"] == "stable" for r in rows)
    print(f"GOAL hard cases stable: measured={stable / len(rows):.2f} target=1.00 "
          f"{'met' if stable == len(rows) else 'not met'}")
    Path(args.doc).write_text(markdown(rows, "OPENBLAS_NUM_THREADS=1 python benchmarks/hard_cases.py",
                                       (began, os.getloadavg()[0])))


def _typed(row):
    """A row read back from the CSV with its numbers as numbers."""
    out = dict(row)
    for key in ("simulated (s)", "energy gain", "penetration (m)", "wall (s)"):
        out[key] = float(out[key])
    case = next((c for c in CASES if c.name == out["scene"]), None)
    out["cause"] = "" if out["outcome"] == "stable" else (case and case.cause or "not known yet")
    return out


if __name__ == "__main__":
    main()
