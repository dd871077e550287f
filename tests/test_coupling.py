"""Two-way coupling of rigid and FEM bodies through the shared contact solver (issue: FEM)."""
import numpy as np
import pytest

from hybrid.app.observe import totals
from rigid import quaternion as quat


def fem_com_velocity(model, state, j=0):
    m = model.fem[j]
    return m.node_mass @ state.fem[j].v / m.node_mass.sum()


@pytest.mark.parametrize("integrator", ["backward_euler", "newmark"])
def test_rigid_ball_hitting_free_fem_block_conserves_linear_momentum(sim, integrator):
    s = sim("""
[simulation]
dt = 0.001
gravity = [0.0, 0.0, 0.0]
[[bodies]]
name = "ball"
shape = { type = "sphere", radius = 0.05 }
density = 7800.0
position = [-0.2, 0.0, 0.02]
velocity = [5.0, 0.0, 0.0]
restitution = 0.3
[[bodies]]
name = "block"
model = "fem"
shape = { type = "box", size = [0.2, 0.2, 0.2], resolution = 0.05 }
density = 1000.0
young = 1e6
poisson = 0.3
integrator = "INTEGRATOR"
""".replace("INTEGRATOR", integrator))
    _, P0, _ = totals(s.model, s.state)
    s.advance(0.08)
    _, P1, _ = totals(s.model, s.state)
    # the collision happened: the block took a sizeable share of the momentum
    assert fem_com_velocity(s.model, s.state)[0] > 1.0
    assert np.linalg.norm(P1 - P0) / np.linalg.norm(P0) < 1e-6


def test_undamped_corotated_newmark_jelly_tumbling_on_the_ground_never_gains_energy(sim):
    """A soft cube (corotated, Newmark, no damping) dropped tumbling at a large step: the warped
    force's energy error gained 4.25 J (83% of the start energy) by 3 s and kept growing before
    Newmark steps were held to their start energy plus the work done on the body (here gravity
    and contact impulses, fem.dynamics._cap_energy); now the total never grows."""
    s = sim("""
[simulation]
dt = 0.005
[[planes]]
friction = 0.6
[[bodies]]
name = "jelly"
model = "fem"
frame = "corotated"
integrator = "newmark"
shape = { type = "box", size = [0.12, 0.12, 0.12], resolution = 0.03 }
position = [0.0, 0.0, 0.3]
orientation = [0.9238795325112867, 0.3826834323650898, 0.0, 0.0]
angular_velocity = [0.0, 4.0, 0.0]
density = 1000.0
young = 5.0e4
poisson = 0.45
""")
    E0 = totals(s.model, s.state)[0]
    energies = []
    s.advance(3.0, lambda sim_: energies.append(totals(sim_.model, sim_.state)[0]))
    print(f"jelly: largest gain {max(energies) - E0:.3g} J, end {energies[-1] - E0:.3g} J of {E0:.3g} J")
    assert max(energies) <= E0 + 1e-9 * abs(E0)
    # it landed and stays on the ground: contact took energy (inelastic, friction)
    assert energies[-1] < E0 - 0.2 * abs(E0)
    assert s.state.fem[0].x[:, 2].min() > -0.01


def test_rigid_box_resting_on_elastic_slab_settles_without_jitter(sim):
    s = sim("""
[simulation]
dt = 0.002
[[planes]]
[[bodies]]
name = "slab"
model = "fem"
shape = { type = "box", size = [0.4, 0.4, 0.06], resolution = 0.08 }
position = [0.0, 0.0, 0.03]
density = 1000.0
young = 2e6
poisson = 0.3
damping = { mass = 0.0, stiffness = 0.005 }
[[bodies]]
name = "box"
shape = { type = "box", size = [0.1, 0.1, 0.1] }
density = 2000.0
position = [0.0, 0.0, 0.111]
""")
    heights, speeds = [], []

    def record(sim_):
        i = sim_.rigid_index("box")
        heights.append(sim_.state.rigid.position[i, 2])
        speeds.append(abs(sim_.state.rigid.velocity[i, 2]))

    s.advance(1.5, record)
    late = slice(len(heights) // 2, None)          # after 0.75 s
    assert max(speeds[late]) < 1e-3                 # m/s: no jitter
    assert np.ptp(heights[late]) < 1e-4             # m: rests still
    # the box rests on the slab's top surface, slightly pressed in but never through it
    slab_top = s.state.fem[0].x[:, 2].max()
    assert 0.05 < heights[-1] - 0.05 < slab_top + 0.001


def dropped_ball(fields):
    """A soft ball (radius 0.1 m) dropped from 0.4 m onto the ground, with its other ``fields``."""
    return """
[simulation]
dt = 0.002
[[planes]]
[[bodies]]
name = "ball"
model = "fem"
shape = { type = "sphere", radius = 0.1, resolution = 0.04 }
poisson = 0.3
position = [0.0, 0.0, 0.4]
""" + fields


def test_fem_ball_dropped_on_ground_bounces_and_comes_to_rest(sim):
    s = sim(dropped_ball("""
density = 1000.0
young = 1e5
restitution = 0.0
damping = { mass = 0.5, stiffness = 0.002 }
"""))
    vz, kinetic, lowest = [], [], []

    def record(sim_):
        m, st = sim_.model.fem[0], sim_.state.fem[0]
        vz.append(fem_com_velocity(sim_.model, sim_.state)[2])
        kinetic.append(0.5 * m.node_mass @ np.einsum("ni,ni->n", st.v, st.v))
        lowest.append(st.x[:, 2].min())

    s.advance(3.0, record)
    vz, kinetic = np.array(vz), np.array(kinetic)
    first_impact = np.argmax(np.array(lowest) < 0.002)
    assert first_impact > 0
    assert vz[first_impact:].max() > 0.2            # m/s upward: it bounced (elastic rebound)
    assert kinetic[-50:].max() < 1e-3 * kinetic.max()   # and came to rest
    assert min(lowest) > -0.003                     # never sank more than 3 mm into the ground


def test_undamped_newmark_ball_bounces_on_the_ground_without_gaining_energy(sim):
    """Under Newmark a node ends its step at x + h (v_t + v) / 2: contacts must keep the gap open
    along that path. Asked only that the end velocity not close it (backward Euler's path), the
    nodes ended each impact step 2 mm inside the ground, the penetration recovery pushed them out
    and every bounce went higher: +26% energy in 2 s."""
    s = sim(dropped_ball("""
young = 1.0e6
integrator = "newmark"
"""))
    E0 = totals(s.model, s.state)[0]
    energies, lowest = [], []

    def record(sim_):
        energies.append(totals(sim_.model, sim_.state)[0])
        lowest.append(sim_.state.fem[0].x[:, 2].min())

    s.advance(2.0, record)
    assert max(energies) <= E0 + 1e-3 * abs(E0)
    assert min(lowest) > -5e-4                      # the slop: nothing for the recovery to do
    assert sum(np.diff(np.array(lowest) < 1e-3) == 1) >= 3     # it bounced, again and again


@pytest.mark.parametrize("integrator", ["backward_euler", "newmark"])
def test_ball_dropped_straight_down_bounces_without_spinning(sim, integrator):
    """Gravity and a level ground have no torque about a symmetric ball's centre: dropped straight
    down it bounces without turning. On the refined-octahedron ball used before (not mirror
    symmetric, 64 tets) the bounces left it spinning at 4.5-6.7 rad/s."""
    s = sim(dropped_ball(f"""
density = 1000.0
young = 1.0e5
integrator = "{integrator}"
""").replace("resolution = 0.04", "resolution = 0.05"))
    m = s.model.fem[0]
    spin, lowest = [], []

    def record(sim_):
        st = sim_.state.fem[0]
        r = st.x - m.node_mass @ st.x / m.node_mass.sum()
        L = (m.node_mass[:, None] * np.cross(r, st.v)).sum(axis=0)
        spin.append(np.linalg.norm(L) / (2 / 3 * m.node_mass @ np.einsum("ni,ni->n", r, r)))
        lowest.append(st.x[:, 2].min())

    s.advance(1.5, record)
    assert sum(np.diff(np.array(lowest) < 1e-3) == 1) >= 2     # it bounced
    assert max(spin) < 0.05                                    # rad/s


@pytest.mark.parametrize("integrator", ["backward_euler", "newmark"])
def test_rigid_box_hitting_a_soft_cube_face_on_leaves_it_without_spin(sim, integrator):
    """A rigid cube meets a soft cube of the same size face on, corner on corner, frictionless, in
    free space: every impulse lies in the cubes' mirror planes, so neither turns. Where the box's
    corners meet the soft cube's corners the place lies on a vertex of several surface triangles;
    the normal turned with the first of them found (by index) differed from corner to corner, and
    under Newmark the cube left spinning at 0.34 rad/s about the impact axis (now 2e-7)."""
    s = sim(f"""
[simulation]
dt = 0.001
gravity = [0.0, 0.0, 0.0]
[[bodies]]
name = "soft"
model = "fem"
shape = {{ type = "box", size = [0.1, 0.1, 0.1], resolution = 0.05 }}
young = 1.0e6
friction = 0.0
integrator = "{integrator}"
position = [-0.1, 0.0, 0.0]
velocity = [1.0, 0.0, 0.0]
[[bodies]]
name = "box"
shape = {{ type = "box", size = [0.1, 0.1, 0.1] }}
density = 1000.0
friction = 0.0
position = [0.1, 0.0, 0.0]
velocity = [-1.0, 0.0, 0.0]
""")
    s.advance(0.15)
    m, st = s.model.fem[0], s.state.fem[0]
    c = m.node_mass @ st.x / m.node_mass.sum()
    v = m.node_mass @ st.v / m.node_mass.sum()
    L = (m.node_mass[:, None] * np.cross(st.x - c, st.v - v)).sum(axis=0)
    spin = np.linalg.norm(L) / (m.node_mass.sum() * 0.1 ** 2 / 6)      # rad/s, a cube's I
    assert v[0] < -0.2                                   # they met and parted
    assert spin < 1e-3                                   # was 0.34 under Newmark
    assert np.linalg.norm(s.state.rigid.angular_momentum) < 1e-6


def ball_falls_on(thickness, speed, resolution):
    """A steel ball (radius 0.05 m) falling at ``speed`` m/s onto a stiff FEM plate (E = 1 GPa,
    0.3 m square, ``thickness`` m) lying on the ground, 1 cm above it; dt = 1 ms, so the ball
    moves further in a step than the plate is thick."""
    return f"""
[simulation]
dt = 0.001
[[planes]]
[[bodies]]
name = "plate"
model = "fem"
young = 1e9
shape = {{ type = "box", size = [0.3, 0.3, {thickness}], resolution = {resolution} }}
position = [0.0, 0.0, {thickness / 2}]
[[bodies]]
name = "ball"
density = 7800
shape = {{ type = "sphere", radius = 0.05 }}
position = [0.0, 0.0, {thickness + 0.06}]
velocity = [0.0, 0.0, {-speed}]
"""


@pytest.mark.parametrize("thickness,speed", [(0.1, 30.0), (0.02, 40.0)])
def test_fast_ball_is_stopped_at_the_surface_of_a_plate_on_the_ground(sim, thickness, speed):
    """The ball is met as soon as it can reach the plate within the step (its own sweep counts, not
    only the nodes'), the plate's bottom nodes, with the ball behind their face, are not its
    contacts, and its impact on the ground below waits while the plate stops it. Before, the ball
    at 30 m/s ended its step 1 cm inside a 10 cm block; at 40 m/s it struck the ground through a
    2 cm plate and bounced off both, and the plate, its bottom nodes pushed up by a 3 cm
    'penetration', flew off at 15 m/s."""
    s = sim(ball_falls_on(thickness, speed, 0.05 if thickness > 0.05 else 0.025))
    ball = s.rigid_index("ball")
    E0 = totals(s.model, s.state)[0]
    inside, lowest, plate_speed, energy = [], [], [], []

    def record(sim_):
        st = sim_.state
        x, centre = st.fem[0].x, st.rigid.position[ball]
        inside.append(0.05 - np.linalg.norm(x - centre, axis=1).min())
        lowest.append(centre[2] - 0.05)
        plate_speed.append(np.abs(fem_com_velocity(sim_.model, st)[2]))
        energy.append(totals(sim_.model, st)[0])

    s.advance(0.02, record)
    assert max(inside) < 2e-3                           # no node more than 2 mm inside the ball
    assert min(lowest) > thickness - 5e-3               # it stops at the plate's top face
    assert max(plate_speed) < 1.0                       # m/s: the plate stays on the ground
    assert max(energy) <= E0 * (1 + 1e-6)


def test_heavy_box_on_a_light_soft_slab_settles_without_sinking_in(sim):
    """1000:1: a 1,800 kg box on a 1.8 kg slab (E = 100 MPa) on the ground. The contact sweeps
    over the deformable body's contacts go on until converged (deformable_iterations): after 20
    the box sank into the slab's top face at 10 um/s (60 um in 1.5 s) and the slab's bottom
    nodes lay 47 um inside the ground."""
    s = sim("""
[simulation]
dt = 0.001
[[planes]]
[[bodies]]
name = "slab"
model = "fem"
young = 1e8
shape = { type = "box", size = [0.3, 0.3, 0.02], resolution = 0.025 }
position = [0.0, 0.0, 0.01]
[[bodies]]
name = "heavy"
density = 1.8e6
shape = { type = "box", size = [0.1, 0.1, 0.1] }
position = [0.0, 0.0, 0.07]
""")
    box, m = s.rigid_index("heavy"), s.model.fem[0]
    R = m.rest_points
    under = (np.abs(R[:, 0]) < 0.05 + 1e-9) & (np.abs(R[:, 1]) < 0.05 + 1e-9)
    top, bottom = under & (R[:, 2] > 0.02 - 1e-9), under & (R[:, 2] < 1e-9)
    t, z, into_box, into_ground = [], [], [], []

    def record(sim_):
        st = sim_.state
        x, zb = st.fem[0].x, st.rigid.position[box, 2]
        t.append(st.time), z.append(zb)
        into_box.append(x[top, 2].max() - (zb - 0.05))
        into_ground.append(-x[bottom, 2].min())

    s.advance(1.0, record)
    t, z = np.array(t), np.array(z)
    late = t > 0.4
    rate = np.polyfit(t[late], z[late], 1)[0]
    print(f"sinking {rate:.3g} m/s, into box {max(into_box[200:]):.3g} m, into ground {max(into_ground[200:]):.3g} m")
    assert abs(rate) < 2e-6                              # m/s
    assert max(into_box[200:]) < 1e-5                    # m
    assert max(into_ground[200:]) < 1e-5
    # the slab carries the box: pressed, but less than its own thickness of 2 cm by far
    assert 0.0699 > z[-1] > 0.0695


def test_two_fem_bodies_collide_exchanging_momentum_without_passing_through(sim):
    s = sim("""
[simulation]
dt = 0.002
gravity = [0.0, 0.0, 0.0]
[[bodies]]
name = "block"
model = "fem"
shape = { type = "box", size = [0.1, 0.1, 0.1], resolution = 0.034 }
position = [-0.1, 0.0, 0.0]
velocity = [1.0, 0.0, 0.0]
young = 1e5
[[bodies]]
name = "ball"
model = "fem"
shape = { type = "sphere", radius = 0.05, resolution = 0.025 }
position = [0.1, 0.02, 0.0]
young = 1e5
""")
    E0, P0, _ = totals(s.model, s.state)
    s.advance(0.3)
    E1, P1, _ = totals(s.model, s.state)
    v_block, v_ball = fem_com_velocity(s.model, s.state, 0), fem_com_velocity(s.model, s.state, 1)
    assert v_ball[0] > v_block[0] > 0.0                       # hit, and now moving apart
    assert np.linalg.norm(P1 - P0) / np.linalg.norm(P0) < 1e-9
    assert E1 <= E0 * (1 + 1e-9)                               # no energy from nowhere
    # no node of the block got inside the ball
    ball = s.state.fem[1].x
    centre = s.model.fem[1].node_mass @ ball / s.model.fem[1].node_mass.sum()
    assert np.linalg.norm(s.state.fem[0].x - centre, axis=1).min() > 0.045


def block_meets_ball(dt=0.001, friction=0.5, spin=0.0, ball_at=(0.2, 0.0, 0.0)):
    """A soft block (2 m/s, spinning at ``spin`` rad/s about z) meets a softer ball (-1 m/s) in
    free space, both under Newmark."""
    return f"""
[simulation]
dt = {dt}
gravity = [0.0, 0.0, 0.0]
[[bodies]]
name = "block"
model = "fem"
shape = {{ type = "box", size = [0.1, 0.1, 0.1], resolution = 0.03 }}
young = 1.0e6
poisson = 0.35
friction = {friction}
integrator = "newmark"
position = [-0.2, 0.0, 0.0]
velocity = [2.0, 0.0, 0.0]
angular_velocity = [0.0, 0.0, {spin}]
[[bodies]]
name = "ball"
model = "fem"
shape = {{ type = "sphere", radius = 0.06, resolution = 0.03 }}
density = 2000.0
young = 5.0e5
friction = {friction}
integrator = "newmark"
position = {list(ball_at)}
velocity = [-1.0, 0.0, 0.0]
"""


def collide(s, seconds):
    """Step ``seconds``; the largest total energy on the way, the change of total linear and
    angular momentum (relative), and each body's mean velocity at the end."""
    E0, P0, L0 = totals(s.model, s.state)
    energies = []
    s.advance(seconds, each=lambda s: energies.append(totals(s.model, s.state)[0]))
    _, P1, L1 = totals(s.model, s.state)
    velocities = [fem_com_velocity(s.model, s.state, j) for j in range(2)]
    return (max(energies) / E0, np.linalg.norm(P1 - P0) / np.linalg.norm(P0),
            np.linalg.norm(L1 - L0) / np.linalg.norm(L0), velocities)


def test_soft_bodies_colliding_head_on_under_newmark_gain_no_energy(sim):
    """Contact between deformable bodies is measured to where the other body's surface is now:
    against its rest shape, a dent looked like a penetration of a few millimetres and the
    penetration recovery pushed single nodes out of it, which doubled the energy (2.64 -> 5.27 J)
    and sent the bodies apart faster than they met."""
    peak, dP, _, (v_block, v_ball) = collide(sim(block_meets_ball()), 0.2)
    assert peak <= 1 + 1e-3
    assert 0.0 < v_ball[0] - v_block[0] <= 3.0          # apart, no faster than they met (3 m/s)
    assert dP < 1e-9


def test_glancing_hit_between_soft_bodies_gains_no_energy_and_keeps_angular_momentum(sim):
    """A spinning soft block grazes a soft ball, frictionless, under Newmark. The ball's side of
    each contact is the place in its surface triangle across from the block's node, so the gap
    changes continuously as the node slides (measured to the nearest node of the ball it jumped by
    4 mm when that node changed, and the penetration recovery fed in 19% more energy), and the
    impulses act along one line (at the nearest node: 15% of L lost). Contacts ask that no gap
    close by the step's end along the nodes' Newmark path. What is left of the change in L is
    first order in the step."""
    dL = []
    for dt in (0.001, 0.0005):
        s = sim(block_meets_ball(dt, friction=0.0, spin=5.0, ball_at=(0.2, 0.07, 0.02)))
        peak, dP, change, (v_block, v_ball) = collide(s, 0.25)
        assert peak <= 1 + 1e-3
        assert dP < 1e-9
        assert v_ball[1] > 0.05 and v_block[1] < -0.05          # they did meet, and glanced off
        dL.append(change)
    assert dL[0] < 0.025                        # measured 0.016 (0.15 before)
    assert dL[0] / dL[1] > 1.7                  # measured 2.5


# a soft slab on the ground meshed at 0.05 m: a 0.1 m box on it spans two elements
COARSE_SLAB = """
[simulation]
dt = 0.002
[[planes]]
[[bodies]]
name = "slab"
model = "fem"
shape = { type = "box", size = [0.4, 0.4, 0.05], resolution = 0.05 }
young = 1.0e6
damping = { mass = 0.0, stiffness = 0.01 }
position = [0.0, 0.0, 0.025]
"""


@pytest.mark.parametrize("at", ["0.003, 0.002", "0.0, 0.0"], ids=["between_nodes", "edges_on_nodes"])
def test_rigid_box_on_a_slab_one_element_wider_than_it_stays_level(sim, at):
    """A 0.1 m box on a slab meshed at 0.05 m has a single slab node under its middle: the corners
    of the box must meet the slab's faces too (the nodes' contacts alone let it balance on that
    node, tip 21 degrees and push a corner 2.4 mm into the slab). Centred, its bottom edges lie on
    lines of nodes, where the box's own normal and distance turn by 90 degrees within a
    micrometre: those nodes contact it along their own face's normal (measured against the box's
    edge, the nodes bulging out past it let the box sink onto the middle node, and it tipped by
    1.3 degrees in 1.2 s, on its way over)."""
    s = sim(COARSE_SLAB + f"""[[bodies]]
name = "box"
shape = {{ type = "box", size = [0.1, 0.1, 0.1] }}
density = 3000.0
position = [{at}, 0.102]
""")
    s.advance(1.0)
    R = quat.to_matrix(s.state.rigid.orientation[0])
    assert np.degrees(np.arccos(min(R[2, 2], 1.0))) < 0.05
    # on the slab's top (z = 0.05 m), pressing it in by about the slab's strain under the box's
    # weight, (3 kg g / 0.01 m^2) / E * 0.05 m = 0.15 mm
    assert abs(s.state.rigid.position[0, 2] - 0.1) < 5e-4


def test_five_box_stack_stands_on_a_coarse_elastic_slab(sim):
    """Five 0.1 m boxes stacked on a soft slab meshed at 0.05 m (nodes under the bottom box's
    edges). Shock propagation needs the stack's levels: the slab's touched nodes are one body
    (before, the nodes under the box touched nothing below them, so every box got the same level
    and the tower leaned over within 2 s), and contacts with a deformable body are left to the
    contact pass, which knows its compliance (frozen, the nodes took the bottom box's weight
    unevenly and it tilted)."""
    boxes = "".join(f"""
[[bodies]]
name = "box{k}"
shape = {{ type = "box", size = [0.1, 0.1, 0.1] }}
density = 500.0
position = [0.0, 0.0, {0.102 + 0.1 * k}]
""" for k in range(5))
    s = sim(COARSE_SLAB + boxes)
    s.advance(2.0)
    R = quat.to_matrix(s.state.rigid.orientation)
    assert np.degrees(np.arccos(np.minimum(R[:, 2, 2], 1.0))).max() < 0.2      # measured 0.03
    assert np.abs(s.state.rigid.position[:, :2]).max() < 0.002                  # measured 0.4 mm
    # each box on the one below, the bottom one on the slab pressed in by about 0.1 mm
    np.testing.assert_allclose(s.state.rigid.position[:, 2], 0.1 + 0.1 * np.arange(5), atol=5e-4)


def test_soft_block_rests_on_soft_block_on_the_ground(sim):
    s = sim("""
[simulation]
dt = 0.002
[[planes]]
[[bodies]]
name = "lower"
model = "fem"
shape = { type = "box", size = [0.2, 0.2, 0.1], resolution = 0.05 }
position = [0.0, 0.0, 0.05]
young = 2e5
damping = { mass = 0.0, stiffness = 0.01 }
[[bodies]]
name = "upper"
model = "fem"
shape = { type = "box", size = [0.1, 0.1, 0.1], resolution = 0.05 }
position = [0.0, 0.0, 0.151]
young = 2e5
damping = { mass = 0.0, stiffness = 0.01 }
""")
    heights = []
    s.advance(1.5, lambda sim_: heights.append(fem_com_velocity(sim_.model, sim_.state, 1)[2]))
    upper, lower = s.state.fem[1].x, s.state.fem[0].x
    assert np.abs(heights[-100:]).max() < 2e-3                # m/s: settled
    # the upper block sits on the lower one (its bottom above the lower's top, within 2 mm)
    assert upper[:, 2].min() > lower[:, 2].max() - 0.002
    assert upper[:, 2].min() < lower[:, 2].max() + 0.006


def test_warm_start_and_dropped_blocks_leave_the_contact_answer_unchanged(sim, monkeypatch):
    """Warm starting from last step's impulses and leaving out negligible Delassus blocks only
    change how fast the solver gets there: one step of a settling slab-and-box pile, solved to
    convergence with both and with neither (cold start, every block), ends at the same velocities."""
    from dataclasses import replace

    import fem.contact_response as response
    from hybrid.coupling import resting
    from hybrid.coupling.step import step

    monkeypatch.setattr(resting, "ENTER_AFTER", 10 ** 9)     # the patch stays with the solver
    monkeypatch.setattr(resting, "FIRST_SIGHT", 10 ** 9)

    s = sim("""
[simulation]
dt = 0.001
[simulation.solver]
iterations = 400
[[planes]]
[[bodies]]
name = "slab"
model = "fem"
shape = { type = "box", size = [0.6, 0.6, 0.1], resolution = 0.05 }
position = [0.0, 0.0, 0.05]
density = 1000.0
young = 1e6
poisson = 0.3
damping = { mass = 1.0 }
[[bodies]]
name = "box"
shape = { type = "box", size = [0.2, 0.2, 0.2] }
density = 2000.0
position = [0.0, 0.0, 0.2]
""")
    s.advance(0.03)                       # mid-settling: contact impulses still change every step
    slab = s.model.fem[0]
    fast = step(s.model, s.state)
    ptr, col, _ = slab.cache.response.block[2]
    k = len(ptr) - 1
    assert k > 100 and len(col) < 0.95 * k * k     # the scene does exercise dropped blocks

    slab.cache.response = None          # the blocks again, none dropped
    monkeypatch.setattr(response, "DROP_TOL", 0.0)
    exact = step(s.model, replace(s.state, contact_memory=None))
    assert len(slab.cache.response.block[2][1]) == k * k

    assert s.state.contact_memory is not None and len(s.state.contact_memory.keys) > 100
    dv_nodes = np.abs(fast.fem[0].v - exact.fem[0].v).max()
    dv_box = np.abs(fast.rigid.velocity - exact.rigid.velocity).max()
    scale = np.abs(exact.fem[0].v - s.state.fem[0].v).max()      # the step's velocity change
    assert scale > 1e-3
    assert dv_nodes < 1e-4 * scale and dv_box < 1e-4 * scale


def test_box_dropped_on_a_soft_bridge_bends_it_past_half_its_thickness_and_stays_on_it(sim):
    """A box dropped on a soft bridge (held at both ends) bends it by more than half its
    thickness. Its corners are found on the bridge's bent top face, not on the bottom face its
    rest shape would put nearer (it then fell through, gaining 8 J): it stays on the top face, and
    the total energy never rises."""
    s = sim("""
[simulation]
dt = 0.002
[[bodies]]
name = "bridge"
model = "fem"
shape = { type = "box", size = [0.6, 0.2, 0.03], resolution = 0.025 }
position = [0.0, 0.0, 0.3]
density = 500.0
young = 2.0e6
damping = { mass = 2.0, stiffness = 0.002 }
[[bodies.anchors]]
box = [[-0.301, -0.2, -0.1], [-0.299, 0.2, 0.1]]
[[bodies.anchors]]
box = [[0.299, -0.2, -0.1], [0.301, 0.2, 0.1]]
[[bodies]]
name = "box"
shape = { type = "box", size = [0.1, 0.1, 0.1] }
density = 2000.0
position = [0.0, 0.0, 0.415]
""")
    rest = s.model.fem[0].rest_points
    under = (np.abs(rest[:, 0]) <= 0.05) & (np.abs(rest[:, 1]) <= 0.05) & (rest[:, 2] > 0.3)
    e0 = totals(s.model, s.state)[0]
    lowest, worst_gap, gain = [], [], []

    def watch(s):
        x = s.state.fem[0].x
        lowest.append(x[:, 2].min())
        worst_gap.append(s.state.rigid.position[0, 2] - 0.05 - x[under, 2].max())
        gain.append(totals(s.model, s.state)[0] - e0)

    s.advance(0.5, each=watch)
    assert min(lowest) < 0.285 - 0.015, "the bridge did not bend past half its thickness"
    assert min(worst_gap) > -2e-3, "the box sank into the bridge's top face"
    assert max(gain) < 0.01          # J; the drop releases 2 kg x g x 5 cm = 0.98 J


def test_contact_normal_on_a_deformed_body_turns_with_its_face(sim):
    """A held (anchored) block whose nodes have been turned by 0.3 rad about y, as a bent
    body's face turns: a sphere over its top face meets that face along the face's turned normal,
    at the sphere's true distance from it (on the rest normal it was pushed straight up, whatever
    the face's slope)."""
    from hybrid.coupling.fem_contact import detect_rigid_points
    s = sim("""
[[bodies]]
name = "block"
model = "fem"
shape = { type = "box", size = [0.4, 0.4, 0.1], resolution = 0.1 }
young = 1e6
[[bodies.anchors]]
box = [[-0.2, -0.2, -0.05], [0.2, 0.2, -0.05]]
[[bodies]]
name = "ball"
shape = { type = "sphere", radius = 0.02 }
""")
    m = s.model.fem[0]
    angle = 0.3
    turn = np.array([[np.cos(angle), 0.0, np.sin(angle)], [0.0, 1.0, 0.0], [-np.sin(angle), 0.0, np.cos(angle)]])
    s.state.fem[0] = s.state.fem[0].replace(x=m.rest_points @ turn.T)
    n = turn @ [0.0, 0.0, 1.0]
    expected_gap = 0.003
    centre = turn @ [0.033, 0.011, 0.05] + (0.02 + expected_gap) * n
    found = detect_rigid_points(
        s.model.rigid, centre[None], np.eye(3)[None], np.zeros(1), s.model.fem, s.state.fem,
        [s.model.scene.bodies[i] for i in s.model.fem_ids], np.array([0, len(m.surface_nodes)]),
        np.zeros(len(m.surface_nodes)), 0.005)
    assert found.count == 1
    assert np.allclose(found.normal[0], n, atol=1e-12)
    assert found.gap[0] == pytest.approx(expected_gap, abs=1e-12)


def test_frictionless_ball_on_a_sagging_bridge_slides_down_its_slope(sim):
    """A frictionless ball lying on a soft bridge (held at both ends) that sags under its own
    weight: the contact normal follows the bent face, so the ball slides towards the middle with
    the horizontal acceleration g sin(a) cos(a) of the local slope a (on the rest normal it stayed
    put on an 11 degree slope)."""
    s = sim("""
[[bodies]]
name = "bridge"
model = "fem"
shape = { type = "box", size = [1.0, 0.1, 0.02], resolution = 0.025 }
young = 2e6
density = 1000.0
friction = 0.0
damping = { mass = 20.0 }
[[bodies.anchors]]
box = [[-0.501, -1.0, -1.0], [-0.499, 1.0, 1.0]]
[[bodies.anchors]]
box = [[0.499, -1.0, -1.0], [0.501, 1.0, 1.0]]
[[bodies]]
name = "ball"
shape = { type = "sphere", radius = 0.015 }
position = [-0.25, 0.0, 0.026]
density = 500.0
friction = 0.0
""")
    rest = s.model.fem[0].rest_points
    top = rest[:, 2] > 0.009
    seen = []

    def watch(s):
        ball, x = s.state.rigid.position[0], s.state.fem[0].x
        under = top & (np.abs(rest[:, 0] - ball[0]) < 0.05) & (np.abs(rest[:, 1] - ball[1]) < 0.03)
        slope = np.polyfit(x[under, 0], x[under, 2], 1)[0]       # of the bent top face, dz/dx
        seen.append((s.state.time, s.state.rigid.velocity[0, 0], slope))

    s.advance(0.3, each=watch)
    t, vx, slope = np.array(seen).T
    window = t > 0.1                         # the bridge has sagged by then
    assert slope[window].min() < -0.15       # a real slope under the ball (8.5 degrees or more)
    measured = np.polyfit(t[window], vx[window], 1)[0]
    expected = np.mean(-9.81 * slope[window] / (1.0 + slope[window] ** 2))
    assert measured == pytest.approx(expected, rel=0.2)


@pytest.mark.parametrize("integrator", ["backward_euler", "newmark"])
def test_soft_block_sliding_on_the_ground_decelerates_at_mu_g(sim, integrator):
    """Coulomb friction opposes each node's sliding: the two tangents are solved together and
    projected into the friction disk. One after the other, nodes of an undamped Newmark block,
    whose lateral vibration asked more than the disk held, got friction at 45 degrees to their
    motion or along it, and the block slowed at 0.90 mu g."""
    s = sim(f"""
[simulation]
dt = 0.001
[[planes]]
friction = 0.3
[[bodies]]
name = "block"
model = "fem"
integrator = "{integrator}"
shape = {{ type = "box", size = [0.1, 0.1, 0.1], resolution = 0.025 }}
position = [0.0, 0.0, 0.0502]
velocity = [2.5, 0.0, 0.0]
young = 1e7
friction = 0.3
""")
    t, vx = [], []
    s.advance(0.4, lambda sim_: (t.append(sim_.state.time), vx.append(fem_com_velocity(sim_.model, sim_.state)[0])))
    t, vx = np.array(t), np.array(vx)
    late = t > 0.05                                  # landed and sliding
    deceleration = -np.polyfit(t[late], vx[late], 1)[0]
    print(f"{integrator}: {deceleration:.4f} m/s^2 against mu g = {0.3 * 9.81:.4f}")
    assert deceleration == pytest.approx(0.3 * 9.81, rel=0.01)


def test_box_sliding_on_an_elastic_slab_decelerates_at_mu_g_without_snags(sim):
    """A box sliding at 2 m/s on a soft slab (mu = 0.3) slows at mu g and stops at v0^2 / (2 mu g).
    The slab's nodes just ahead of the box, level with its bottom face, were met on the box's front
    face, whose normal there is horizontal: they stopped it like a wall (0.41 m/s lost in one step,
    and it stopped 36% short)."""
    s = sim("""
[simulation]
dt = 0.001
[[planes]]
friction = 0.3
[[bodies]]
name = "slab"
model = "fem"
shape = { type = "box", size = [1.0, 0.4, 0.05], resolution = 0.05 }
position = [0.0, 0.0, 0.025]
young = 1e6
friction = 0.3
damping = { mass = 1.0 }
[[bodies]]
name = "box"
shape = { type = "box", size = [0.1, 0.1, 0.1] }
position = [-0.35, 0.0, 0.1001]
velocity = [2.0, 0.0, 0.0]
friction = 0.3
""")
    mu_g = 0.3 * 9.81
    seen = []
    s.advance(0.75, each=lambda s: seen.append((s.state.time, s.state.rigid.velocity[0, 0],
                                                s.state.rigid.position[0, 0])))
    t, vx, x = np.array(seen).T
    sliding = (t > 0.02) & (vx > 0.1)           # landed (it starts 0.1 mm above the slab)
    assert -np.polyfit(t[sliding], vx[sliding], 1)[0] == pytest.approx(mu_g, rel=0.02)
    assert np.diff(vx[t > 0.02]).min() > -3 * mu_g * 0.001
    assert x[-1] - (-0.35) == pytest.approx(2.0 ** 2 / (2 * mu_g), rel=0.03)


def test_box_resting_on_the_bent_tip_of_a_corotated_cantilever_does_not_sink_in(sim):
    """A box comes to rest on the tip of a soft corotated cantilever that it and gravity bend by
    about 10 degrees there. The corotated beam answers the contact solver through its rest system,
    so the step solves its contacts again until the beam's nodes move as the solver expected:
    with two rounds the box sank into the beam at 0.3 mm/s (0.35 mm by 0.6 s) and slid off."""
    s = sim("""
[simulation]
dt = 0.002
[[bodies]]
name = "beam"
model = "fem"
frame = "corotated"
shape = { type = "box", size = [0.5, 0.05, 0.05], resolution = 0.025 }
position = [0.25, 0.0, 0.0]
young = 5.0e6
damping = { mass = 25.0 }
[[bodies.anchors]]
box = [[-0.26, -0.1, -0.1], [-0.2499, 0.1, 0.1]]
[[bodies]]
name = "box"
shape = { type = "box", size = [0.05, 0.05, 0.05] }
position = [0.485, 0.0, 0.06]
""")
    top = np.nonzero(s.model.fem[0].rest_points[:, 2] > 0.0249)[0]
    depth, sag = [], []

    def watch(s):
        rs = s.state.rigid
        local = (s.state.fem[0].x[top] - rs.position[0]) @ quat.to_matrix(rs.orientation[0])
        under = (np.abs(local[:, 0]) < 0.025) & (np.abs(local[:, 1]) < 0.025)
        depth.append((local[under, 2] + 0.025).max(initial=-1.0))   # > 0: inside the box
        sag.append(-0.025 - s.state.fem[0].x[:, 2].min())

    s.advance(0.6, each=watch)
    print(f"tip sag {max(sag):.4f} m, deepest {max(depth[100:]):.3e} m")
    assert max(sag) > 0.05, "the beam did not bend"      # m, at its 0.5 m tip
    assert max(depth[100:]) < 1e-5          # m, once the box has landed


@pytest.mark.parametrize("x", [0.02, 0.0])
def test_a_ball_smaller_than_the_elements_rests_on_the_face_between_their_nodes(sim, x):
    """A 3 cm steel ball on a stiff box whose top face has nodes 5 cm apart: the ball's centre
    meets the face (radius and all) from beyond the face's signed-distance grid, whose padding is
    1.5 cm (hybrid.coupling.rest_grid.beyond_padding), so it rests on the face, not on the two
    nodes it fits between (13 mm down, its centre out of the grid; over a node it sank through
    the box within a second)."""
    s = sim(f"""
[simulation]
dt = 0.002
[[planes]]
[[bodies]]
name = "box"
model = "fem"
young = 1e9
density = 1000
shape = {{ type = "box", size = [0.2, 0.1, 0.1], resolution = 0.05 }}
position = [0, 0, 0.05]
[[bodies]]
name = "ball"
shape = {{ type = "sphere", radius = 0.03 }}
density = 7800
position = [{x}, 0.0, 0.3]
""")
    ball = s.rigid_index("ball")
    s.advance(0.3)
    gaps = []
    s.advance(0.7, lambda sim_: gaps.append(sim_.state.rigid.position[ball][2] - 0.03 - 0.1))
    assert max(abs(g) for g in gaps) < 5e-4                 # on the top face, to the solver's slop
    assert np.linalg.norm(s.state.rigid.velocity[ball]) < 1e-2


@pytest.mark.parametrize("friction, integrator", [(0.0, "backward_euler"), (0.5, "backward_euler"),
                                                 (0.0, "newmark")])
def test_a_ball_striking_a_soft_block_off_centre_keeps_the_angular_momentum(sim, friction, integrator):
    """A steel ball (4 kg, 3 m/s) strikes a free soft block (8 kg, E = 1 MPa) 6 cm off its centre
    in zero gravity, squashing it by tens of percent. The ball's sample point meets the block's
    faces at a place of a surface triangle: placed by its weights on the rest surface, the place
    slid off the line through the ball's centre along the normal as the block deformed, and the
    two sides' impulses turned each other: 14% (frictionless) to 19% (friction 0.5) of the
    angular momentum was lost, and with friction the energy rose 20-59% within the contact.
    Placed on the triangles as they are now: within 1%, and the energy never rises. (Under Newmark
    the energy rose 23% and kept it: penetration recovery moved the block's nodes after its
    energy was held to what the contact's work allows; they are moved first.)"""
    from hybrid.app.observe import totals
    s = sim(f"""
[simulation]
dt = 0.001
gravity = [0.0, 0.0, 0.0]
[[bodies]]
name = "ball"
shape = {{ type = "sphere", radius = 0.05 }}
density = 7800.0
position = [-0.2, 0.06, 0.0]
velocity = [3.0, 0.0, 0.0]
friction = {friction}
[[bodies]]
name = "block"
model = "fem"
shape = {{ type = "box", size = [0.2, 0.2, 0.2], resolution = 0.04 }}
young = 1.0e6
poisson = 0.3
friction = {friction}
integrator = "{integrator}"
""")
    E0, P0, L0 = totals(s.model, s.state)
    energies = []
    s.advance(0.08, each=lambda s: energies.append(totals(s.model, s.state)[0]))
    E, P, L = totals(s.model, s.state)
    assert s.body("ball").velocity[0] < 2.0                       # it struck
    assert np.abs(L - L0).max() < 0.01 * np.linalg.norm(L0)
    assert np.abs(P - P0).max() < 1e-9 * np.linalg.norm(P0)
    assert max(energies) <= E0 * (1.0 + 1e-9)


PAD = """
[simulation]
duration = 1.5
dt = 0.001
[[planes]]
[[bodies]]
name = "pad"
model = "fem"
young = 1e5
poisson = 0.4
density = 1100
shape = { type = "box", size = [0.2, 0.2, 0.05], resolution = 0.025 }
position = [0.0, 0.0, 0.025]
damping = { stiffness = 0.002 }
[[bodies]]
name = "weight"
shape = { type = "box", size = [0.1, 0.1, 0.1] }
density = 7800
position = [0.0, 0.0, 0.1005]
"""


def test_a_heavy_box_settled_on_a_soft_pad_stays_at_rest(sim):
    """A 7.8 kg box on a soft pad (E = 100 kPa, 7% strain under it) settled by 0.7 s, then rattled
    and sank: the pad's rim nodes slid out past the box's bottom edges, whose contact points
    were left out as covered by those nodes (within half a millimetre across), until the edges
    were met 1.5 mm deep and thrown up (+0.03 J a time). A settled box stays settled: the energy
    never rises from one frame to the next after the settling, and the box ends at rest."""
    s = sim(PAD)
    energies = []
    while s.time < 1.5 - 1e-9:
        s.step()
        if s.time > 0.7 and s.steps % 10 == 0:
            energies.append(totals(s.model, s.state)[0])
    rises = np.diff(energies)
    assert rises.max() < 1e-6                         # J; the box's weight times 13 nm
    assert s.body("weight").kinetic_energy < 1e-9
