"""The built-in scenes (hybrid/scenes/*.toml) run by name, each briefly, and do what their header
says: no energy from nowhere, the dent plate yields under the ball and slows it, the pulled bar
flows at yield_stress * area, the ductile bar tears, the tile shatters, the slab's pieces become
rigid, the pile settles.

The checks marked "longer" step a scene past the moment its point happens (yield, plateau, tear,
settling); each takes a few seconds.
"""
import numpy as np
import pytest

from hybrid import Simulation
from hybrid.app.observe import totals
from hybrid.app.scene import load_scene
from hybrid.scenes import builtin_names, builtin_path, builtin_summary

SHIPPED = ["cantilever", "default", "dent", "fragments", "jelly", "pile", "pull", "shatter", "tear"]
FIELDS = ("von_mises", "principal_stress", "plastic_strain")


def supplied_power(sim):
    """Power (W) the anchors put into the FEM bodies now: the reaction of each anchor times its
    prescribed velocity."""
    return sum(float(np.dot(s.node_reaction[nodes].sum(axis=0), velocity))
               for m, s in zip(sim.model.fem, sim.state.fem)
               for nodes, velocity in zip(m.anchor_nodes, m.anchor_velocity))


def load_work(sim):
    """Work (J) the constant loads have done so far: node forces times node displacements."""
    return sum(float(np.sum(m.node_load * (s.x - m.rest_points)))
               for m, s in zip(sim.model.fem, sim.state.fem) if m.node_load is not None)


class Run:
    """A built-in scene stepped in this process, recording after every step its total energy
    (kinetic + elastic + gravitational, J) and the work anchors and loads have done on it (J)."""

    def __init__(self, name):
        self.sim = Simulation.from_toml(name)
        self.energy = [totals(self.sim.model, self.sim.state)[0]]
        self.work = [0.0]
        self.anchor_work = 0.0

    def advance(self, seconds, each=None):
        for _ in range(int(round(seconds / self.sim.dt))):
            self.sim.step()
            self.anchor_work += self.sim.dt * supplied_power(self.sim)
            self.energy.append(totals(self.sim.model, self.sim.state)[0])
            self.work.append(self.anchor_work + load_work(self.sim))
            if each is not None:
                each(self.sim)
        return self

    def slack(self):
        """What integrating free fall may gain in energy (J): each moving body's mass times
        (g dt)^2, the size of the error a time step makes in m g z against m v^2 / 2."""
        rm, g, dt = self.sim.model.rigid, self.sim.model.gravity, self.sim.dt
        mass = fem_mass(self.sim) + float(rm.body_mass[~rm.body_fixed].sum() if rm.body_count else 0.0)
        return mass * float(g @ g) * dt * dt

    def gained(self):
        """Largest energy gain over the start beyond the work done on the bodies (J), and the
        scale it is measured against."""
        energy, work = np.array(self.energy), np.array(self.work)
        scale = max(abs(energy[0]), np.abs(work).max(), 1e-9)
        return float((energy - energy[0] - work).max()), scale


def fem_mass(sim):
    return sum(float(m.node_mass.sum()) for m in sim.model.fem)


def rigid_mass(sim, names):
    rm = sim.model.rigid
    return sum(float(rm.body_mass[list(sim.model.rigid_ids).index(sim.model.names.index(n))])
               for n in names)


def regions(sim):
    """{region name: (force (3,) N, mean displacement (3,) m)} of every anchor and load region."""
    from hybrid.app.observe import region_rows
    return {row[2]: (np.array(row[3:6]), np.array(row[6:9])) for row in region_rows(sim.model, sim.state)}


# ----------------------------------------------------------------------------- the registry

def test_registry_lists_every_shipped_scene_with_a_summary_and_a_render_command():
    assert builtin_names() == SHIPPED
    for name in SHIPPED:
        path = builtin_path(name)
        assert path.name == f"{name}.toml" and path.is_file()
        assert load_scene(path).name == name
        header = "".join(line for line in path.read_text().splitlines(keepends=True)
                         if line.startswith("#"))
        summary = builtin_summary(name)
        assert summary and header.startswith(f"# {summary}\n") and len(summary) < 100
        assert f"hybrid run {name}" in header and f"hybrid render outputs/{name}" in header
    # every deformable scene names the field to render, one the output writes
    for name in ("dent", "pull", "shatter", "tear", "fragments", "pile", "jelly", "cantilever"):
        assert any(f"--field {field}" in builtin_path(name).read_text() for field in FIELDS), name


def test_unknown_scene_name_raises_key_error_listing_the_built_in_scenes():
    with pytest.raises(KeyError, match="no built-in scene 'dnet'; built-in scenes: cantilever, "
                                       "default, dent"):
        builtin_path("dnet")
    with pytest.raises(KeyError):
        builtin_path("../scenes/dent")


# ----------------------------------------------------------------------------- every scene, briefly

@pytest.mark.parametrize("name", ["cantilever", "default", "jelly"])
def test_builtin_scene_gains_no_energy_beyond_the_work_done_on_it(name):
    """The scenes without a test of their own below (each of those checks energy too)."""
    run = Run(name)
    run.advance(0.05)
    gain, scale = run.gained()
    assert gain <= run.slack() + 1e-9 * scale, f"{name}: gained {gain:.3g} J ({scale:.3g} J)"
    for body in run.sim.body_names:
        assert np.all(np.isfinite(run.sim.body(body).position))


# ----------------------------------------------------------------------------- dent

def test_dent_ball_is_slowed_by_the_plate_which_yields_most_under_it():
    run = Run("dent").advance(0.003)
    sim = run.sim
    ball, plate = sim.body("ball"), sim.body("plate")
    # 10 m/s down before; bounced back up, slowed to a fraction of it (measured +0.69 m/s)
    assert 0.0 < ball.velocity[2] < 2.0
    gain, scale = run.gained()
    assert gain <= 1e-9 * scale
    # the plate yielded most under the ball (measured 0.39 %), and in bending between the
    # supports (at most 0.17 % beyond 1 cm of the point of impact); nothing over the supports
    centroid = plate.points[plate.tets].mean(axis=1)
    r = np.linalg.norm(centroid[:, :2], axis=1)
    peeq = plate.plastic_strain
    assert peeq.max() > 2e-3 and np.all(peeq[r < 0.01] > 0)
    assert peeq[r > 0.01].max() < 0.5 * peeq.max()
    assert np.all(peeq[np.abs(centroid[:, 0]) > 0.05] == 0)
    # it stays on the supports (their tops at z = 3 cm) and the ball above it
    assert plate.points[:, 2].min() > 0.03 - 1e-3
    assert ball.position[2] - 0.02 > plate.points[:, 2].max()


# ----------------------------------------------------------------------------- pull

def pull_force(sim):
    force, displacement = regions(sim)["anchor1"]
    return force[0], displacement[0]


def test_pull_bar_force_rises_with_EA_over_L_before_yield():
    run = Run("pull").advance(0.1)
    force, u = pull_force(run.sim)
    E, A, L = 70e9, 0.01 ** 2, 0.1
    # the clamped ends stiffen the bar by ~1.5 % on this mesh
    assert force == pytest.approx(E * A / L * u, rel=0.025)
    assert run.sim.body("bar").plastic_strain.max() == 0.0
    gain, scale = run.gained()
    assert gain <= 1e-6 * scale


def test_pull_bar_flattens_at_yield_stress_times_area_longer():
    """Longer: 0.6 s of pulling, to twice the yield strain."""
    forces = []
    Run("pull").advance(0.6, each=lambda sim: forces.append(pull_force(sim)[0]))
    YA = 100e6 * 0.01 ** 2
    plateau = np.array(forces[-200:])                      # the last 0.2 s
    assert np.all(np.abs(plateau / YA - 1.0) < 0.02)       # measured 1.0003-1.0010 YA
    assert np.ptp(plateau) < 0.005 * YA                    # flat: no hardening
    assert max(forces) < 1.02 * YA


# ----------------------------------------------------------------------------- tear

def test_tear_bar_yields_flows_then_tears_in_two_longer():
    """Longer: 0.55 s of pulling, past the tear (measured at 0.31 s)."""
    rows = []

    def record(sim):
        force = sum(f[0] for name, (f, _) in regions(sim).items() if name == "anchor1")
        rows.append((sim.time, force, len(sim.body_names)))

    run = Run("tear").advance(0.55, each=record)
    t, force, bodies = np.array(rows).T
    YA = 1.0e6 * 0.02 ** 2
    torn = int(np.argmax(bodies > 1))
    assert torn > 0 and run.sim.body_names == ["bar", "bar.1"], "the bar never tore in two"
    # it flowed on yield_stress * area (the clamped ends add ~1.5 %) ...
    flowing = (t > 0.15) & (np.arange(len(t)) < torn)
    assert np.all(np.abs(force[flowing] / YA - 1.0) < 0.03)
    # ... well past its elastic elongation (Y L / E = 2 mm, pulled at 2 cm/s) before it tore
    assert 0.02 * t[torn] > 3 * 1.0e6 * 0.2 / 1.0e8
    # and then carried nothing
    assert np.abs(force[torn + 10:]).max() < 0.05 * YA
    assert all(run.sim.body(b).plastic_strain.max() > 0.04 for b in run.sim.body_names)
    gain, scale = run.gained()
    assert gain <= 1e-6 * scale


# ----------------------------------------------------------------------------- shatter

def test_shatter_tile_breaks_into_several_pieces_small_ones_rigid():
    run = Run("shatter")
    mass = fem_mass(run.sim)
    run.advance(0.02)
    sim = run.sim
    pieces = [n for n in sim.body_names if n.startswith("tile.")]
    assert len(pieces) >= 4, sim.body_names                # measured 10 by 0.05 s
    rigid = [n for n in pieces if sim.body(n).kind == "rigid"]
    assert rigid, "no small fragment became rigid"
    # fragment_model = "auto": pieces under rigid_fragment_tets = 4 elements turn rigid at once,
    # and are deformable again only when struck hard enough (an elastify event names them)
    elastified = {e.as_dict()["body"] for e in sim.events if e.as_dict().get("event") == "elastify"}
    small = [sim.model.names[j] for m, j in zip(sim.model.fem, sim.model.fem_ids)
             if sim.model.names[j].startswith("tile") and m.tet_count < 4]
    assert set(small) <= elastified, (small, elastified)
    # a rigid piece's mass is integrated over its deformed surface (measured +1.2e-4)
    assert fem_mass(sim) + rigid_mass(sim, rigid) == pytest.approx(mass, rel=1e-3)
    gain, scale = run.gained()
    assert gain <= 1e-9 * scale
    # the ball went through, slowed from 20 m/s
    assert -20.0 < sim.body("ball").velocity[2] < 0.0


# ----------------------------------------------------------------------------- fragments

def test_shatter_pieces_struck_again_and_again_do_not_switch_every_step():
    """Small auto pieces turned rigid at once at every check after a blow made them deformable:
    a piece under the ball switched every step for 8 ms (and a glass pane's crumbs, with
    fragment_model = "auto", 5,239 times in 20 steps, five times as slow). Rigid at once when
    they break off; struck, they wait their window as any auto body."""
    sim = Simulation.from_toml("shatter")
    summary = sim.run(until=0.12, progress=False, log=lambda line: None)
    switched = {}
    for event in summary["events"]:
        if event["event"] in ("rigidify", "elastify"):
            switched.setdefault(event["body"], []).append(round(event["time"] / sim.dt))
    assert len(switched) >= 4, switched                  # pieces were made and struck
    for body, steps in switched.items():
        assert len(steps) <= 3, (body, steps)
        assert all(b - a > 3 for a, b in zip(steps[1:], steps[2:])), (body, steps)


def test_fragments_slab_breaks_on_the_ridge_and_its_pieces_become_rigid():
    run = Run("fragments")
    mass = fem_mass(run.sim)
    run.advance(0.025)
    sim = run.sim
    pieces = [n for n in sim.body_names if n.startswith("slab.")]
    assert len(pieces) >= 2, sim.body_names                 # measured 5 by 0.02 s
    # fragment_model = "rigid": every piece split off is rigid, the largest stays deformable
    assert all(sim.body(n).kind == "rigid" for n in pieces)
    assert sim.body("slab").kind == "fem"
    assert all(e.rigid_bodies == e.new_bodies for e in sim.events if getattr(e, "new_bodies", ()))
    # a rigid piece's mass is integrated over its deformed surface (measured +1.5e-4)
    assert fem_mass(sim) + rigid_mass(sim, pieces) == pytest.approx(mass, rel=1e-3)
    gain, scale = run.gained()
    assert gain <= 1e-9 * scale


# ----------------------------------------------------------------------------- pile

def test_pile_settles_each_body_resting_on_the_one_below_longer():
    """Longer: 0.4 s, by when the pile is still (measured at rest from 0.3 s)."""
    run = Run("pile").advance(0.4)
    sim = run.sim
    gain, scale = run.gained()
    assert gain <= 1e-9 * scale
    bodies = {n: sim.body(n) for n in sim.body_names}
    assert sum(b.kinetic_energy for b in bodies.values()) < 1e-3
    # stacked: base on the ground, cube and ball on the base, brick on them, crate on the brick
    z = {n: b.position[2] for n, b in bodies.items()}
    assert z["base"] < min(z["cube"], z["ball"]) < z["brick"] < z["crate"]
    base_top = bodies["base"].points[:, 2].max()
    for name in ("cube", "ball"):
        assert bodies[name].points[:, 2].min() > base_top - 0.01      # on it, not sunk into it
    assert all(b.points[:, 2].min() > -1e-3 for b in bodies.values() if b.kind == "fem")
