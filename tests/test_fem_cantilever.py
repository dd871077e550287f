"""Steel cantilever 1 m x 0.1 m x 0.1 m clamped at x = 0 with a 1 kN tip load: statics and vibration."""
from dataclasses import replace

import numpy as np
import pytest

from fem.dynamics import energy, step
from fem.mesh import box_tet_mesh, quadratic_tets, select_nodes_in_box
from fem.model import build_fem_model, rest_state
from fem.static import static_displacement
from fem.stress import region_table

LENGTH, SIDE = 1.0, 0.1
E, NU, RHO, LOAD = 2e11, 0.3, 7800.0, 1000.0
AREA, INERTIA = SIDE**2, SIDE**4 / 12
SHEAR_MODULUS = E / (2 * (1 + NU))
# Euler-Bernoulli bending plus Timoshenko shear correction (kappa = 5/6)
TIP_THEORY = LOAD * LENGTH**3 / (3 * E * INERTIA) + LOAD * LENGTH / (5 / 6 * SHEAR_MODULUS * AREA)


def cantilever(order, cells, **options):
    points, tets = box_tet_mesh((LENGTH, SIDE, SIDE), cells)
    points = points + [0.5 * LENGTH, 0.0, 0.0]
    if order == 2:
        points, tets = quadratic_tets(points, tets)
    clamp = select_nodes_in_box(points, [-1, -1, -1], [0, 1, 1])
    tip = select_nodes_in_box(points, [LENGTH, -1, -1], [2, 1, 1])
    model = build_fem_model(points, tets, order=order, density=RHO, young=E, poisson=NU,
                            anchors=[(clamp, [0, 0, 0])], loads=[(tip, [0, 0, -LOAD])], **options)
    return model, tip


def settle(model, dt, steps):
    state = rest_state(model)
    for _ in range(steps):
        state = step(model, state, dt)
    return state


def test_cantilever_tip_deflection_quadratic_tets_matches_beam_theory():
    model, tip = cantilever(2, (20, 2, 2), damping_stiffness=2e-4)
    state = settle(model, 1e-3, 150)
    tip_deflection = -(state.x - model.rest_points)[tip, 2].mean()
    static_tip = -static_displacement(model)[tip, 2].mean()
    print(f"P2 tip {tip_deflection:.5e} m, theory {TIP_THEORY:.5e} m, static {static_tip:.5e} m")
    assert abs(tip_deflection / TIP_THEORY - 1) < 0.03
    # the settled dynamic answer is the static solution on the same mesh
    assert abs(tip_deflection / static_tip - 1) < 0.01
    # the clamp holds the whole load: reaction equals minus the applied force
    table = region_table(model, state)
    assert table[0][0] == "anchor0" and table[1][0] == "load0"
    np.testing.assert_allclose(table[0][1:4], [0, 0, LOAD], atol=1e-3 * LOAD)
    np.testing.assert_allclose(table[1][6], -tip_deflection, rtol=1e-12)


def test_quadratic_cantilever_from_a_scene_shape_clamps_and_loads_its_midside_nodes(sim):
    """``order = 2`` on a box shape: the anchor and load boxes take the midside nodes too, so the
    scene's beam is the same model as the tetra10 one above (selected on the corners alone, its
    clamp face's midside nodes moved and the tip sagged 10% more than theory)."""
    s = sim(f"""
[simulation]
gravity = [0.0, 0.0, 0.0]
[[bodies]]
name = "beam"
model = "fem"
shape = {{ type = "box", size = [{LENGTH}, {SIDE}, {SIDE}], resolution = 0.05 }}
position = [{LENGTH / 2}, 0.0, 0.0]
order = 2
young = {E}
poisson = {NU}
density = {RHO}
[[bodies.anchors]]
box = [[{-LENGTH / 2 - 0.001}, -1, -1], [{-LENGTH / 2 + 0.001}, 1, 1]]
[[bodies.loads]]
box = [[{LENGTH / 2 - 0.001}, -1, -1], [{LENGTH / 2 + 0.001}, 1, 1]]
force = [0.0, 0.0, {-LOAD}]
""")
    model = s.model.fem[0]
    X = model.rest_points
    clamp, tip = X[:, 0] < 1e-9, X[:, 0] > LENGTH - 1e-9
    assert np.array_equal(model.node_anchor >= 0, clamp)        # every node of the clamp face
    np.testing.assert_allclose(model.node_load.sum(axis=0), [0, 0, -LOAD], rtol=1e-12)
    assert np.all(model.node_load[~tip] == 0)
    u = static_displacement(model)
    tip_deflection = -u[tip, 2].mean()
    print(f"scene P2 tip {tip_deflection:.5e} m, theory {TIP_THEORY:.5e} m")
    assert abs(tip_deflection / TIP_THEORY - 1) < 0.03


def test_cantilever_linear_tets_converge_with_refinement():
    sizes, errors = [], []
    for cells in [(10, 1, 1), (20, 2, 2), (40, 4, 4)]:
        model, tip = cantilever(1, cells)
        tip_deflection = -static_displacement(model)[tip, 2].mean()
        sizes.append(LENGTH / cells[0])
        errors.append(abs(tip_deflection / TIP_THEORY - 1))
    rate = np.polyfit(np.log(sizes), np.log(errors), 1)[0]
    print(f"P1 cantilever errors {errors}, rate {rate:.2f}")
    assert errors[0] > errors[1] > errors[2]
    assert rate > 0.8
    # settled dynamics equals the static solve on the finest mesh too
    state = settle(model, 1e-2, 40)
    np.testing.assert_allclose(-(state.x - model.rest_points)[tip, 2].mean(), tip_deflection, rtol=0.01)


def test_cantilever_released_from_loaded_shape_vibrates_at_first_bending_frequency():
    model, tip = cantilever(2, (10, 1, 1), integrator="newmark")
    u = static_displacement(model)
    # release: same beam without the tip load
    released = replace(model, node_load=np.zeros_like(model.node_load))
    frequency = 1.875**2 / (2 * np.pi) * np.sqrt(E * INERTIA / (RHO * AREA * LENGTH**4))
    period = 1 / frequency
    dt = period / 60
    state = rest_state(released, x=released.rest_points + u)
    times, tip_z = [], []
    for _ in range(int(3.5 * period / dt)):
        state = step(released, state, dt)
        times.append(state.time)
        tip_z.append((state.x - released.rest_points)[tip, 2].mean())
    times, tip_z = np.array(times), np.array(tip_z)
    # zero crossings by linear interpolation, half a period apart
    k = np.nonzero(np.sign(tip_z[1:]) != np.sign(tip_z[:-1]))[0]
    crossings = times[k] - tip_z[k] * (times[k + 1] - times[k]) / (tip_z[k + 1] - tip_z[k])
    measured = 1 / (2 * np.mean(np.diff(crossings)))
    print(f"first bending frequency {measured:.2f} Hz, Euler-Bernoulli {frequency:.2f} Hz")
    assert len(crossings) >= 5
    assert abs(measured / frequency - 1) < 0.05
    # Newmark without damping keeps the amplitude
    assert np.abs(tip_z[-int(period / dt):]).max() > 0.95 * np.abs(u[tip, 2].mean())


@pytest.mark.parametrize("frame", ["floating", "corotated"])
def test_bar_pulled_by_its_anchor_under_newmark_holds_the_work_the_anchors_did(frame):
    """A rubber bar, one end held, the other pulled at 1 cm/s for 2 s (undamped Newmark): its
    energy equals the work of the anchor reactions, and the slow pull leaves the static stretch
    energy EA d^2 / (2 L). Newmark steps keep within the energy the body started with plus the work
    done on it (fem.dynamics._cap_energy), so the reactions' work must be counted to let it in."""
    points, tets = box_tet_mesh((1.0, 0.1, 0.1), (10, 1, 1))
    points = points + [0.5, 0, 0]
    left = select_nodes_in_box(points, [-1, -1, -1], [1e-6, 1, 1])
    right = select_nodes_in_box(points, [1 - 1e-6, -1, -1], [2, 1, 1])
    young = 1e6
    model = build_fem_model(points, tets, density=1000.0, young=young, poisson=0.0, frame=frame,
                            integrator="newmark", anchors=[(left, [0, 0, 0]), (right, [0.01, 0, 0])])
    state, work = rest_state(model), 0.0
    for _ in range(2000):
        before = state
        state = step(model, state, 1e-3)
        work += np.sum(state.node_reaction * (state.x - before.x))
    stretch = state.x[right, 0].mean() - 1.0
    assert stretch == pytest.approx(0.02, rel=1e-3)
    assert energy(model, state) == pytest.approx(work, rel=1e-6)
    assert energy(model, state) == pytest.approx(0.5 * young * 0.01 * stretch**2 / 1.0, rel=2e-3)


@pytest.mark.parametrize("order", [1, 2])
def test_cantilever_loaded_straight_down_does_not_bend_sideways(order):
    """The beam's cross-section is symmetric, so a load straight down bends it straight down. A
    box mesh with the same cell diagonal everywhere is not: the tip also moved sideways by 8.6%
    (P1) and 0.03% (P2) of its deflection at 20 x 2 x 2 cells."""
    model, tip = cantilever(order, (20, 2, 2))
    u = static_displacement(model)[tip].mean(axis=0)
    assert abs(u[1]) < 1e-9 * abs(u[2])


def test_a_tetra10_mesh_without_an_order_is_built_with_quadratic_tets(sim):
    """The built-in cantilever's mesh file has tetra10 cells; without `order` in the scene the
    body is built from them as they are (its corner nodes alone gave a tip deflection of 0.60 of
    the quadratic mesh's), the same body as with `order = 2`."""
    from hybrid.scenes import builtin_path
    text = builtin_path("cantilever").read_text()
    assert "order = 2" in text
    base = builtin_path("cantilever").parent
    quadratic = sim(text, base_dir=base).model.fem[0]
    unasked = sim(text.replace("order = 2", ""), base_dir=base).model.fem[0]
    assert unasked.order == 2 and unasked.node_count == quadratic.node_count
    assert np.array_equal(unasked.rest_points, quadratic.rest_points)


def test_anchors_sharing_nodes_report_the_weight_they_hold_once(sim):
    """A block held at rest by two anchor boxes that overlap along an edge of its base (the same
    velocity, zero): the anchors' reactions add up to its weight (the shared nodes' reaction
    was counted in both)."""
    from hybrid.app.observe import region_rows
    s = sim("""
[simulation]
dt = 0.01
[[bodies]]
name = "block"
model = "fem"
shape = { type = "box", size = [0.2, 0.2, 0.2], resolution = 0.05 }
young = 1e7
density = 1000.0
damping = { mass = 20.0 }
[[bodies.anchors]]
box = [[-1, -1, -1], [0.01, 1, -0.099]]
[[bodies.anchors]]
box = [[-0.01, -1, -1], [1, 1, -0.099]]
""")
    s.advance(2.0)
    rows = region_rows(s.model, s.state)
    assert len(rows) == 2
    weight = 1000.0 * 0.2 ** 3 * 9.81
    assert sum(r[5] for r in rows) == pytest.approx(weight, rel=1e-3)


@pytest.mark.parametrize("young, frame, noted", [(3e5, "floating", True), (3e5, "corotated", False),
                                                  (3e8, "floating", False)])
def test_a_floating_body_strained_far_beyond_small_strain_gets_a_corotated_note(sim, young, frame,
                                                                               noted):
    """A soft cantilever sagging far under its own weight in the floating frame gives a linear
    answer with no word of it (a rubber beam at P L^2 / E I = 2 sagged 35% past the elastica);
    the run log notes that the corotated frame follows large rotations. A stiff one (strain 2e-3)
    and a corotated one are not noted."""
    s = sim(f"""
[simulation]
duration = 0.3
dt = 0.005
[[bodies]]
name = "beam"
model = "fem"
shape = {{ type = "box", size = [1.0, 0.05, 0.05], resolution = 0.025 }}
young = {young}
density = 1000.0
frame = "{frame}"
damping = {{ mass = 10.0 }}
[[bodies.anchors]]
box = [[-1, -1, -1], [-0.49, 1, 1]]
""")
    lines = []
    s.run(progress=False, log=lines.append)
    notes = [line for line in lines if 'frame = "corotated"' in line]
    assert len(notes) == int(noted)
    if noted:
        assert notes[0].startswith("note: 'beam' reached a strain of 0.13")


@pytest.mark.parametrize("frame", ["floating", "corotated"])
def test_a_bar_hinged_along_an_edge_in_the_floating_frame_is_told_it_swells(sim, frame):
    """A bar held along one edge swings about it: the floating frame (the world's for an anchored
    body) takes the turn for no strain and moves the bar along the tangents, so it swelled (an
    8,000-fold volume at 0.5 s) with a largest strain of 5e-5 and not a word. The turn of its
    elements is watched: past 18 degrees the run log says so; corotated, the bar swings and
    keeps its volume, and its elements turn by nothing in their own frames."""
    s = sim(f"""
[simulation]
duration = 0.25
dt = 0.001
[[bodies]]
name = "bar"
model = "fem"
shape = {{ type = "box", size = [0.1, 0.01, 0.01], resolution = 0.005 }}
position = [0.0, 0.0, 0.5]
density = 1100.0
young = 1e7
frame = "{frame}"
[[bodies.anchors]]
box = [[-1, -1, 0.0049], [1, -0.0049, 1]]
""")
    lines = []
    result = s.run(progress=False, log=lines.append)
    notes = [line for line in lines if 'frame = "corotated"' in line]
    turn = result["models"]["bar"]["largest_turn_degrees"]
    m, st = s.model.fem[0], s.state.fem[0]
    p = st.x[m.elements.tet_nodes[:, :4]]
    volume = np.einsum("ij,ij->i", p[:, 1] - p[:, 0], np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 0])).sum() / 6
    if frame == "floating":
        assert len(notes) == 1 and "turned parts of itself by up to" in notes[0] and "its anchors" in notes[0]
        assert turn > 45 and volume > 2 * 1e-5          # (swollen: what the note is about)
    else:
        assert not notes and turn < 1e-6 and volume == pytest.approx(1e-5, rel=0.01)


def test_linear_tets_with_cells_long_against_a_slender_body_s_thickness_are_noted_to_lock(sim):
    """A clamped beam 20 times as long as thick, linear tets in the box mesh, sags under its weight
    by the share of Euler-Bernoulli theory the run log's note quotes, which follows the cells' length
    along the beam over its thickness (1/2: 0.58 with 2 layers of cubic cells, 0.69 with 4 layers
    of cells twice as long; poisson 0); the note is given to such bodies only: a user's
    5-layer beam sagged 15% short, one of cells 8 times as long as thick 54%, with nothing said."""
    from types import SimpleNamespace
    from hybrid.app.deformable import SLENDER_RATIO, mesh_notes
    from hybrid.app.hints import bending_note
    length, side, young, density, g = 1.0, 0.05, 1e9, 1000.0, 9.81
    theory = density * g * side**2 * length**4 / (8 * young * side**4 / 12)
    for layers, aspect, share in ((2, 1, 0.577), (4, 2, 0.692), (4, 1, 0.847), (4, 4, 0.391)):
        model = _beam_model(length, side, young, density, layers, aspect)
        tip = np.isclose(model.rest_points[:, 0], model.rest_points[:, 0].max())
        sag = -static_displacement(model, gravity=(0.0, 0.0, -g))[tip, 2].mean()
        assert sag / theory == pytest.approx(share, abs=0.002)

    s = sim("""[simulation]\nduration = 0.01\ndt = 0.001\n[[bodies]]\nname = "b"\nmodel = "fem"
young = 1e9\norder = 1\nshape = { type = "box", size = [0.3, 0.05, 0.05], resolution = 0.01 }\n""")
    assert "; its cells along it are 0.2 of its thickness long: linear tets lock in bending" \
        in mesh_notes(s.model)[0]

    def note(order, size, cells):
        points, tets = box_tet_mesh(size, cells)
        return bending_note(SimpleNamespace(order=order, rest_points=points, tets=tets), SLENDER_RATIO)
    assert note(1, (0.6, 0.6, 0.04), (24, 24, 4))               # a plate of 4 layers: 0.62
    assert note(1, (1.0, 0.05, 0.05), (20, 8, 8))               # 8 layers of long cells: 1.0
    assert note(2, (0.3, 0.05, 0.05), (30, 5, 5)) is None       # quadratic tets bend freely
    assert note(1, (0.3, 0.05, 0.05), (48, 8, 8)) is None       # 8 layers of cubic cells: 1/8
    assert note(1, (0.1, 0.05, 0.05), (10, 5, 5)) is None       # compact: no beam


def _beam_model(length, side, young, density, layers, aspect=1):
    points, tets = box_tet_mesh((length, side, side), (int(round(length * layers / (aspect * side))),
                                                       layers, layers))
    clamp = select_nodes_in_box(points, [-2, -1, -1], [-0.5 * length + 1e-9, 1, 1])
    return build_fem_model(points, tets, order=1, density=density, young=young, poisson=0.0,
                           anchors=[(clamp, [0, 0, 0])])
