"""A state that diverged stops the run with a message naming the body, the time and the quantity."""
import numpy as np
import pytest

from fem import dynamics as fem_dyn
from hybrid.app.observe import totals
from hybrid.coupling.step import InstabilityError, MAX_SPEED, check_finite

SCENE = """
[simulation]
dt = 0.001
[[planes]]
[[bodies]]
name = "block"
model = "fem"
shape = { type = "box", size = [0.2, 0.2, 0.2], resolution = 0.1 }
position = [0.0, 0.0, 0.5]
density = 1000.0
young = 1e6
poisson = 0.3
[[bodies]]
name = "ball"
shape = { type = "sphere", radius = 0.1 }
position = [1.0, 0.0, 0.5]
density = 1000.0
"""


def test_healthy_state_passes(sim):
    s = sim(SCENE).advance(0.01)
    check_finite(s.model, s.state)


@pytest.mark.parametrize("bad", [np.nan, np.inf, 2 * MAX_SPEED])
def test_fem_node_speed_that_diverged_names_the_body(sim, bad):
    s = sim(SCENE).advance(0.01)
    v = s.state.fem[0].v.copy()
    v[3, 1] = bad
    s.state.fem[0] = s.state.fem[0].replace(v=v)
    with pytest.raises(InstabilityError) as err:
        check_finite(s.model, s.state)
    assert err.value.body == "block" and err.value.quantity == "node speed (m/s)"
    assert err.value.time == pytest.approx(0.01)
    assert "block" in str(err.value) and "t = 0.01" in str(err.value)
    if np.isfinite(bad):
        assert err.value.value == pytest.approx(bad)


def test_rigid_body_far_away_names_the_body(sim):
    s = sim(SCENE).advance(0.01)
    s.state.rigid.position[0] = [0.0, 0.0, 2e6]
    with pytest.raises(InstabilityError) as err:
        check_finite(s.model, s.state)
    assert err.value.body == "ball" and err.value.quantity == "distance from origin (m)"
    assert err.value.value == pytest.approx(2e6)


def test_largest_norms_match_numpy_on_random_states_with_nan_and_inf():
    """The one-pass kernel behind the FEM check gives numpy's largest row norms, NaN where a row
    holds a NaN, inf where one is infinite."""
    import numpy as np
    from hybrid.coupling.stability import largest_norms
    rng = np.random.default_rng(7)
    for n in (1, 5, 300):
        for poison in (None, np.nan, np.inf):
            v, x = rng.standard_normal((n, 3)) * 10.0, rng.standard_normal((n, 3)) * 1e3
            if poison is not None:
                v[rng.integers(n), rng.integers(3)] = poison
            got = largest_norms(v, x)
            want = [float(np.sqrt(np.einsum("ij,ij->i", a, a).max())) for a in (v, x)]
            np.testing.assert_equal(got, want)


def test_a_rest_shape_update_without_a_finite_shape_names_the_body(sim, monkeypatch):
    """A plastic flow the small-strain update cannot bake into a rest shape (a P2 corotated box of
    yield strain 0.2 crushed by a steel ball gave NaN plastic displacements) stops the step with
    the body, the time and the quantity, the simulation left at the state before it."""
    import fem.reference
    s = sim(SCENE.replace('young = 1e6', 'young = 1e6\nyield_stress = 1e3')).advance(0.002)
    due = {"count": 0}

    def nan_displacement(model, state):
        due["count"] += 1
        return np.full((model.node_count, 3), np.nan)

    monkeypatch.setattr(fem.reference, "plastic_displacement", nan_displacement)
    monkeypatch.setattr(fem.reference, "reference_update_due", lambda model, state: True)
    before = s.state
    with pytest.raises(InstabilityError) as err:
        s.step()
    assert due["count"] == 1
    assert err.value.body == "block" and "rest-shape update" in err.value.quantity
    assert err.value.time == pytest.approx(0.003)
    assert s.state is before


BOUNCING_BAR = """
[simulation]
duration = 0.3
dt = 0.01
output_fps = 20
[[planes]]
restitution = 0.5
[[bodies]]
name = "bar"
model = "fem"
shape = {{ type = "box", size = [0.3, 0.05, 0.05], resolution = 0.025 }}
position = [0.0, 0.0, 0.3]
density = 7800.0
young = {young}
integrator = "{integrator}"
frame = "{frame}"
angular_velocity = {spin}
velocity = [1.0, 0.0, -3.0]
"""


def bouncing_bar(young, integrator="newmark", frame="floating", spin=(3.0, 20.0, 5.0)):
    return BOUNCING_BAR.format(young=young, integrator=integrator, frame=frame, spin=list(spin))


@pytest.mark.parametrize("integrator, frame, spin", [
    ("backward_euler", "floating", (0.0, 2.0, 0.0)), ("backward_euler", "floating", (3.0, 20.0, 5.0)),
    ("backward_euler", "corotated", (3.0, 20.0, 5.0)), ("newmark", "floating", (3.0, 20.0, 5.0))])
def test_a_steel_bar_landing_at_a_large_step_never_gains_energy(sim, integrator, frame, spin):
    """A steel bar spinning onto the ground at a 10 ms step turns by up to 6.5 degrees in its
    landing step under the contact impulses, and is pushed out of the ground by penetration
    recovery. Taken along chords, the turn stretched it by (w h)^2 / 2 and the push strained
    the nodes it moved: 56 J became 7 kJ (backward Euler) and 7e12 J (Newmark). Turned exactly,
    and pushed through its own response, nothing does work on it but gravity: its total energy
    never exceeds the start (Newmark's own error in free flight: 1e-4 of it)."""
    s = sim(bouncing_bar(2e11, integrator, frame, spin))
    start = totals(s.model, s.state)[0]
    most, lowest = [start], [1.0]

    def watch(s):
        most.append(totals(s.model, s.state)[0])
        lowest.append(s.state.fem[0].x[:, 2].min())

    s.advance(0.3, each=watch)
    tolerance = 1e-9 if integrator == "backward_euler" else 1e-3
    assert max(most) <= start * (1.0 + tolerance)
    assert min(lowest) < 1e-3 and min(most) < 0.9 * start     # it did land, and lost energy


def test_a_run_whose_energy_grows_with_nothing_doing_work_stops_naming_the_body(sim, tmp_path, monkeypatch):
    """A defect that feeds a body energy (here its velocities grown by 3% each step) stops the
    run at the first frame that has gained more than the energy in play, as unstable, naming
    the body, with the frames so far kept."""
    finish = fem_dyn.finish

    def feeding(model, state, step, dt, shift=None):
        new = finish(model, state, step, dt, shift)
        return new.replace(v=1.03 * new.v)

    monkeypatch.setattr(fem_dyn, "finish", feeding)
    s = sim(bouncing_bar(1e6))
    with pytest.raises(InstabilityError) as error:
        s.run(out=tmp_path / "out", progress=False, log=lambda message: None)
    assert error.value.body == "bar" and "total energy gained" in error.value.quantity
    assert error.value.value > 39.0
    summary = (tmp_path / "out" / "summary.json").read_text()
    assert '"status": "unstable"' in summary
    assert (tmp_path / "out" / "frames" / "frame_00000.vtu").exists()


def test_a_run_that_loses_energy_is_not_stopped(sim):
    """The same bar, soft (E = 1 MPa), bounces, loses energy at each landing, and runs to its
    end: the watchdog does not stop what only dissipates."""
    s = sim(bouncing_bar(1e6))
    summary = s.run(progress=False, log=lambda message: None)
    assert summary["status"] == "ok" and s.time == pytest.approx(0.3)


LOADED_BAR = """
[simulation]
duration = {duration}
dt = {dt}
gravity = [0.0, 0.0, 0.0]
output_fps = 100
[[bodies]]
name = "bar"
model = "fem"
shape = {{ type = "box", size = [0.4, 0.04, 0.04], resolution = 0.02 }}
young = 1e6
integrator = "{integrator}"
angular_velocity = [0.0, 0.0, {spin}]
[[bodies.loads]]
box = [[0.19, -1.0, -1.0], [0.21, 1.0, 1.0]]
force = [{force}, 0.0, 0.0]
[[bodies.loads]]
box = [[-0.21, -1.0, -1.0], [-0.19, 1.0, 1.0]]
force = [{minus}, 0.0, 0.0]
"""


def test_the_energy_watch_counts_the_loads_work(sim):
    """Loads switched the watch off: a free bar spun at 2 rad per step diverged with two equal and
    opposite 1 uN loads on it and the run ended "ok". Constant loads are conservative, so the
    watch counts their potential -f . x: an undamped Newmark bar stretched from rest by 5 N at
    each end (its energy all the loads' work) runs to its end, and the diverging one stops."""
    from hybrid.app.energy_watch import loads
    stretched = sim(LOADED_BAR.format(duration=0.5, dt=1e-3, integrator="newmark", spin=0.0,
                                      force=5.0, minus=-5.0))
    start = totals(stretched.model, stretched.state)[0] + loads(stretched.model, stretched.state)
    assert stretched.run(progress=False, log=lambda m: None)["status"] == "ok"
    end = totals(stretched.model, stretched.state)[0] + loads(stretched.model, stretched.state)
    elastic = fem_dyn.elastic_energy(stretched.model.fem[0], stretched.state.fem[0])
    assert elastic > 1e-4 and abs(end - start) < 0.01 * elastic     # the loads' work, kept
    spinning = sim(LOADED_BAR.format(duration=2.0, dt=0.05, integrator="backward_euler", spin=40.0,
                                     force=1e-6, minus=-1e-6))
    with pytest.raises(InstabilityError) as error:
        spinning.run(progress=False, log=lambda m: None)
    assert error.value.body == "bar" and "the loads' work counted" in error.value.quantity


YIELDING_BAR = """
[simulation]
duration = 0.5
dt = 0.001
gravity = [0.0, 0.0, 0.0]
output_fps = 20
[[bodies]]
name = "bar"
model = "fem"
shape = {{ type = "box", size = [0.1, 0.01, 0.01], resolution = 0.005 }}
density = 2700.0
young = 70e9
yield_stress = 100e6
[[bodies.anchors]]
box = [[-1.0, -1.0, -1.0], [-0.049999, 1.0, 1.0]]
[[bodies.loads]]
box = [[0.049999, -1.0, -1.0], [1.0, 1.0, 1.0]]
force = [{force}, 0.0, 0.0]
"""


@pytest.mark.parametrize("share", [0.9, 1.05])
def test_a_load_above_the_plastic_limit_stops_the_run_saying_why(sim, share):
    """A bar of 1 cm^2 and 100 MPa yield stress carries at most 10 kN: under 1.05 times that it
    has no equilibrium and stretches until the energy watch stops it, whose message then says
    that the load may exceed what the body carries once yielded (it said only 'unstable'); at
    0.9 times it the bar runs to its end."""
    s = sim(YIELDING_BAR.format(force=share * 1e-4 * 100e6))
    if share < 1.0:
        assert s.run(progress=False, log=lambda m: None)["status"] == "ok"
        return
    with pytest.raises(InstabilityError) as error:
        s.run(progress=False, log=lambda m: None)
    assert error.value.body == "bar" and "plastic limit load" in error.value.quantity
