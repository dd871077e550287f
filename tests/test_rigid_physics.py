"""Rigid-body dynamics against closed forms and conservation laws, each on a scene written as TOML.

Free rotation (Euler's equations), ballistic flight with restitution, Coulomb friction on an
incline, resting stacks, extreme mass ratios, momentum in collisions and thin-wall tunnelling.
"""
import math

import numpy as np
import pytest

from hybrid.app.observe import totals
from hybrid.app.run import below_planes, overlapping_bodies
from rigid import quaternion as quat
from rigid.model import angular_velocity, kinetic_energy, reported_velocity

G = 9.81
DT_240 = 1.0 / 240.0


def _box(name, size, position=(0.0, 0.0, 0.0), **extra):
    """A ``[[bodies]]`` table of a box; ``extra`` values are written with repr (TOML-compatible)."""
    lines = ['[[bodies]]', f'name = "{name}"',
             f'shape = {{ type = "box", size = [{", ".join(repr(float(s)) for s in size)}] }}',
             f'position = [{", ".join(repr(float(p)) for p in position)}]']
    for key, value in extra.items():
        if isinstance(value, bool):
            value = "true" if value else "false"
        elif isinstance(value, (tuple, list)):
            value = "[" + ", ".join(repr(float(v)) for v in value) + "]"
        else:
            value = repr(float(value))
        lines.append(f"{key} = {value}")
    return "\n".join(lines) + "\n"


def _simulation(dt, gravity=(0.0, 0.0, -G)):
    return f"[simulation]\ndt = {dt!r}\ngravity = [{', '.join(repr(float(g)) for g in gravity)}]\n"


def _plane(normal=(0.0, 0.0, 1.0), friction=0.5, restitution=0.0):
    return (f"[[planes]]\nnormal = [{', '.join(repr(float(n)) for n in normal)}]\n"
            f"friction = {float(friction)!r}\nrestitution = {float(restitution)!r}\n")


def _sign_change_times(t, y):
    """Times where ``y`` changes sign, linearly interpolated between samples."""
    i = np.nonzero(np.sign(y[1:]) != np.sign(y[:-1]))[0]
    return t[i] - y[i] * (t[i + 1] - t[i]) / (y[i + 1] - y[i])


# ----------------------------------------------------------------------------- free rotation
def test_tennis_racket_flip_period_matches_euler_equations_and_conserves_energy_and_momentum(sim):
    # Box 0.3 x 0.2 x 0.05 m, 1000 kg/m^3: I = (0.010625, 0.023125, 0.0325) kg m^2, y intermediate.
    # Spun at (0.01, 10, 0) rad/s it flips about y; Euler's equations (integrated to 1e-12)
    # give a half-period of 2.8355 s between sign changes of the body-frame w_y.
    s = sim(_simulation(0.01, gravity=(0, 0, 0))
            + _box("racket", (0.3, 0.2, 0.05), density=1000.0, angular_velocity=(0.01, 10.0, 0.0)))
    rm = s.model.rigid
    np.testing.assert_allclose(rm.body_inertia[0], [0.010625, 0.023125, 0.0325], rtol=1e-12)
    energy0 = kinetic_energy(rm, s.state.rigid)[0]
    momentum0 = np.linalg.norm(s.state.rigid.angular_momentum[0])
    times, body_wy = [0.0], [10.0]

    def record(s):
        R = quat.to_matrix(s.state.rigid.orientation)[0]
        times.append(s.state.time)
        body_wy.append((R.T @ angular_velocity(rm, s.state.rigid)[0])[1])

    s.advance(10.0, each=record)
    crossings = _sign_change_times(np.array(times), np.array(body_wy))
    assert len(crossings) >= 3, f"the racket did not flip repeatedly: w_y crossed zero at {crossings}"
    half_period = np.mean(np.diff(crossings))
    assert half_period == pytest.approx(2.8355, rel=0.01)
    assert kinetic_energy(rm, s.state.rigid)[0] == pytest.approx(energy0, rel=1e-3)
    assert np.linalg.norm(s.state.rigid.angular_momentum[0]) == pytest.approx(momentum0, rel=1e-3)


# ----------------------------------------------------------------------------- restitution
@pytest.mark.parametrize("ball_e, plane_e", [(0.5, 0.5), (0.5, 0.0), (0.0, 0.5)])
def test_ball_dropped_from_one_metre_bounces_to_e_squared_heights(sim, ball_e, plane_e):
    # Restitution combines by max, so each pair acts as e = 0.5: apexes 1 m * e^2k.
    s = sim(_simulation(DT_240) + _plane(friction=0.5, restitution=plane_e)
            + '[[bodies]]\nname = "ball"\nshape = { type = "sphere", radius = 0.1 }\n'
              f'position = [0.0, 0.0, 1.1]\nrestitution = {ball_e!r}\nfriction = 0.5\n')
    heights = [1.0]
    s.advance(1.3, each=lambda s: heights.append(s.state.rigid.position[0, 2] - 0.1))
    z = np.array(heights)
    apex = np.nonzero((z[1:-1] > z[:-2]) & (z[1:-1] >= z[2:]))[0] + 1
    assert len(apex) >= 3, f"expected three bounces, found apexes {z[apex]}"
    np.testing.assert_allclose(z[apex[:3]], [0.25, 0.0625, 0.015625], rtol=0.03)
    assert z.min() > -1e-3, "the ball sank into the plane"


@pytest.mark.parametrize("dt", [1e-3, 5e-4, 1e-2])
def test_a_tilted_box_bouncing_on_its_corners_never_gains_energy(sim, dt):
    """A box dropped 1 m tilted by 5 degrees, e = 0.8, no friction, lands on a corner, spins, and
    its other corners strike within one step: the energy may only fall. The bodies, moved back
    to the impacts' times together, left corners millimetres deep, and the contact pass pushed
    them out with velocity: at dt = 1 ms the box left at 6.65 m/s after landing at 4.75, its
    energy 2.1 times the start."""
    half = np.radians(5.0) / 2
    q = (np.cos(half), 0.8 * np.sin(half), 0.6 * np.sin(half), 0.0)
    s = sim(_simulation(dt) + _plane(friction=0.0, restitution=0.8)
            + _box("box", (0.2, 0.14, 0.08), (0.0, 0.0, 1.2), restitution=0.8, friction=0.0,
                   orientation=list(q)))
    mass = s.model.rigid.body_mass[0]
    energy = [s.body("box").kinetic_energy + mass * G * s.body("box").position[2]]
    s.advance(1.5, each=lambda s: energy.append(s.body("box").kinetic_energy
                                                + mass * G * s.body("box").position[2]))
    energy = np.array(energy)
    assert energy[-1] < 0.8 * energy[0]                 # it bounced and lost energy
    assert energy.max() <= energy[0] * (1 + 1e-6)


def test_ball_bounces_on_a_stack_of_two_free_boxes_as_on_the_ground(sim):
    """A table is a stack on the ground: a ball bouncing on two boxes lying on the ground (free,
    not fixed) rises to e^2 of each height, as on the ground itself, and the boxes stay put. With
    impacts solved alone the ball pushed the top box into the lower one and did not bounce at all;
    with the resting contacts but no sweep down the stack it left at 2.3 m/s instead of 3.5 and set
    the top box sliding."""
    s = sim(_simulation(DT_240) + _plane()
            + _box("lower", (0.3, 0.3, 0.1), (0.0, 0.0, 0.05))
            + _box("upper", (0.2, 0.2, 0.1), (0.0, 0.0, 0.15))
            + '[[bodies]]\nname = "ball"\nshape = { type = "sphere", radius = 0.05 }\n'
              'position = [0.0, 0.0, 1.25]\ndensity = 7800.0\nrestitution = 0.5\n')
    ball = s.rigid_index("ball")
    heights, boxes_moved = [1.0], []
    s.advance(1.3, each=lambda s: (heights.append(s.state.rigid.position[ball, 2] - 0.25),
                                   boxes_moved.append(np.abs(s.state.rigid.position[:2] - [[0, 0, 0.05], [0, 0, 0.15]]).max())))
    z = np.array(heights)
    apex = np.nonzero((z[1:-1] > z[:-2]) & (z[1:-1] >= z[2:]))[0] + 1
    assert len(apex) >= 3, f"expected three bounces, found apexes {z[apex]}"
    np.testing.assert_allclose(z[apex[:3]], [0.25, 0.0625, 0.015625], rtol=0.03)
    assert max(boxes_moved) < 1e-4
    assert np.abs(s.state.rigid.position[ball, :2]).max() < 1e-6


# ----------------------------------------------------------------------------- Coulomb friction
def _incline_slide(sim, mu_box, mu_plane, seconds=1.0, angle_deg=30.0):
    """Distance a 0.1 m cube resting flat on a plane tilted by ``angle_deg`` slides along it."""
    a = math.radians(angle_deg)
    normal = (-math.sin(a), 0.0, math.cos(a))
    s = sim(_simulation(DT_240) + _plane(normal, friction=mu_plane)
            + _box("cube", (0.1, 0.1, 0.1), position=[0.05 * n for n in normal],
                   orientation=(math.cos(a / 2), 0.0, -math.sin(a / 2), 0.0), friction=mu_box))
    x0 = s.state.rigid.position[0].copy()
    s.advance(seconds)
    moved = s.state.rigid.position[0] - x0
    n = np.array(normal)
    assert abs(moved @ n) < 1e-3, "the cube left or sank into the incline"
    return float(np.linalg.norm(moved - (moved @ n) * n)), a


def test_cube_slides_down_30_degree_incline_with_coulomb_friction(sim):
    distance, a = _incline_slide(sim, 0.3, 0.3)
    assert distance == pytest.approx(0.5 * G * (math.sin(a) - 0.3 * math.cos(a)), rel=0.01)


def test_cube_sticks_on_30_degree_incline_when_friction_exceeds_tan_angle(sim):
    distance, _ = _incline_slide(sim, 0.7, 0.7)
    assert distance < 1e-3


@pytest.mark.parametrize("mu_box, mu_plane, mu_combined", [(0.5, 0.5, 0.5), (0.2, 0.45, 0.3), (0.0, 0.5, 0.0)])
def test_friction_coefficients_combine_by_geometric_mean(sim, mu_box, mu_plane, mu_combined):
    # Equal coefficients give that coefficient; a frictionless side gives a frictionless contact.
    # The coefficient the cube actually felt, from d = g (sin a - mu cos a) t^2 / 2:
    distance, a = _incline_slide(sim, mu_box, mu_plane)
    mu_felt = (math.sin(a) - 2.0 * distance / G) / math.cos(a)
    assert mu_felt == pytest.approx(mu_combined, rel=0.01, abs=1e-6)


# ----------------------------------------------------------------------------- resting contact
@pytest.mark.parametrize("dt", [DT_240, 1.0 / 60.0])
def test_stack_of_ten_cubes_stands_still_for_five_seconds(sim, dt):
    cubes = "".join(_box(f"cube{i}", (0.1, 0.1, 0.1), (0.0, 0.0, 0.05 + 0.1 * i),
                         density=1000.0, friction=0.5, restitution=0.0) for i in range(10))
    s = sim(_simulation(dt) + _plane(friction=0.5) + cubes)
    top0 = s.state.rigid.position[-1].copy()
    worst = [0.0, 0.0]

    def record(s):
        d = s.state.rigid.position[-1] - top0
        worst[0] = max(worst[0], float(np.hypot(d[0], d[1])))
        worst[1] = max(worst[1], abs(float(d[2])))

    s.advance(5.0, each=record)
    assert s.model.rigid.body_mass == pytest.approx(1.0, rel=1e-12)
    assert worst[0] < 1e-3, f"the top cube drifted {worst[0]:.3g} m sideways"
    assert worst[1] < 1e-3, f"the stack settled or grew by {worst[1]:.3g} m"


def test_1000_kg_box_resting_on_1_kg_box_neither_sinks_nor_jitters(sim):
    s = sim(_simulation(DT_240) + _plane(friction=0.5)
            + _box("light", (0.1, 0.1, 0.1), (0.0, 0.0, 0.05), density=1000.0)
            + _box("heavy", (0.1, 0.1, 0.1), (0.0, 0.0, 0.15), density=1.0e6))
    rm = s.model.rigid
    np.testing.assert_allclose(rm.body_mass, [1.0, 1000.0], rtol=1e-12)
    rows = []

    def record(s):
        rs = s.state.rigid
        R = quat.to_matrix(rs.orientation)
        light, heavy = (rs.position[i] + rm.surface_vertices[i] @ R[i].T for i in range(2))
        v = reported_velocity(rm, rs, s.model.gravity)
        tilt = 2.0 * np.arccos(np.clip(np.abs(rs.orientation[:, 0]), 0.0, 1.0)).max()
        # both boxes stay level, so face heights measure penetration directly
        rows.append((rs.time, -light[:, 2].min(), light[:, 2].max() - heavy[:, 2].min(),
                     abs(v[0, 2]), abs(v[1, 2]), tilt))

    s.advance(5.0, each=record)
    t, into_ground, into_light, v_light, v_heavy, tilt = np.array(rows).T
    assert tilt.max() < 1e-3
    assert into_ground.max() < 1e-3
    assert into_light.max() < 1e-3
    settled = t > 0.5
    assert v_light[settled].max() < 1e-3
    assert v_heavy[settled].max() < 1e-3


# ----------------------------------------------------------------------------- conservation
def test_off_centre_collision_of_spinning_box_conserves_linear_and_angular_momentum(sim):
    s = sim(_simulation(DT_240, gravity=(0, 0, 0))
            + _box("spinner", (0.2, 0.1, 0.05), (-0.3, 0.03, 0.01), velocity=(2.0, 0.0, 0.0),
                   angular_velocity=(1.0, 2.0, 15.0), friction=0.3, restitution=0.3)
            + _box("target", (0.1, 0.15, 0.1), density=700.0, friction=0.3, restitution=0.3))
    _, p0, l0 = totals(s.model, s.state)
    v0 = s.state.rigid.velocity.copy()
    w0 = angular_velocity(s.model.rigid, s.state.rigid)
    s.advance(0.5)
    _, p1, l1 = totals(s.model, s.state)
    dv = np.linalg.norm(s.state.rigid.velocity - v0, axis=1)
    dw = np.linalg.norm(angular_velocity(s.model.rigid, s.state.rigid) - w0, axis=1)
    assert dv.min() > 0.1 and dw.min() > 0.1, "the boxes did not collide"
    assert np.linalg.norm(p1 - p0) <= 1e-9 * np.linalg.norm(p0)
    assert np.linalg.norm(l1 - l0) <= 1e-6 * np.linalg.norm(l0)


# ----------------------------------------------------------------------------- tunnelling
@pytest.mark.parametrize("restitution", [0.0, 0.5])
def test_box_thrown_at_20_m_per_s_never_passes_through_2_cm_slab(sim, restitution):
    # At dt = 1/240 the box moves 8.3 cm per step, four times the slab's thickness.
    s = sim(_simulation(DT_240, gravity=(0, 0, 0))
            + _box("slab", (0.02, 1.0, 1.0), fixed=True, restitution=restitution)
            + _box("bullet", (0.1, 0.1, 0.1), (-0.5, 0.0, 0.0), velocity=(20.0, 0.0, 0.0),
                   restitution=restitution))
    front = []
    s.advance(0.2, each=lambda s: front.append(s.state.rigid.position[1, 0] + 0.05))
    assert max(front) < -0.01 + 1e-3, f"the box's front face reached x = {max(front):.4f} m"
    vx = s.state.rigid.velocity[1, 0]
    if restitution == 0.0:
        assert abs(vx) < 1e-6
    else:
        assert vx == pytest.approx(-20.0 * restitution, rel=0.02)


# ----------------------------------------------------------------------------- warnings
def test_overlap_warning_names_the_two_interpenetrating_bodies(sim):
    s = sim(_box("a", (0.1, 0.1, 0.1)) + _box("b", (0.1, 0.1, 0.1), (0.05, 0.0, 0.0))
            + '[[bodies]]\nname = "apart"\nshape = { type = "sphere", radius = 0.05 }\n'
              'position = [1.0, 0.0, 0.0]\n')
    assert overlapping_bodies(s.model, s.state) == [("a", "b")]


def test_overlap_warning_is_silent_for_bodies_that_only_touch(sim):
    s = sim(_box("a", (0.1, 0.1, 0.1)) + _box("b", (0.1, 0.1, 0.1), (0.1, 0.0, 0.0)))
    assert overlapping_bodies(s.model, s.state) == []


BURIED = """
[[planes]]
[[bodies]]
name = "{name}"
model = "{model}"
young = 1e6
shape = {{ type = "box", size = [0.2, 0.2, 0.2] }}
position = [0, 0, {z}]
"""


@pytest.mark.parametrize("model", ["rigid", "fem", "auto"])
def test_a_body_starting_inside_the_ground_is_warned_of_with_its_depth(sim, model):
    """A box whose centre is 5 cm above the ground starts 5 cm inside it (a deformable one was
    thrown up at 6.7 m/s without a word; it is now refused, naming its position, as deeper than
    1% of its size); one resting on it (centre 10 cm up) is not warned of."""
    from hybrid import SceneError
    young = "" if model == "rigid" else "young = 1e6"
    resting = sim(BURIED.format(name="crate", model=model, z=0.1).replace("young = 1e6", young))
    assert below_planes(resting.model, resting.state) == [] and not resting.warnings
    if model != "rigid":
        with pytest.raises(SceneError, match="field 'position' starts it 0.05 m inside a plane"):
            sim(BURIED.format(name="crate", model=model, z=0.05).replace("young = 1e6", young))
        return
    buried = sim(BURIED.format(name="crate", model=model, z=0.05).replace("young = 1e6", young))
    assert [name for name, _ in below_planes(buried.model, buried.state)] == ["crate"]
    assert below_planes(buried.model, buried.state)[0][1] == pytest.approx(0.05, rel=1e-6)
    assert any("'crate' starts 0.05 m inside a plane" in w for w in buried.warnings)


def test_a_rigid_body_buried_deeper_than_its_size_is_refused_and_one_less_deep_rests_on_top(sim):
    """A 0.1 m box started 0.55 m under the ground was warned of and pushed out, and its run
    stopped as unstable: the energy watch allows a body's weight times its size, and the push-out
    gave it its weight times 0.55 m. Deeper than its size (the diameter of its bounding sphere,
    0.346 m for a 0.2 m box) a rigid body is refused naming its position; 0.3 m deep it comes out,
    a run ends ok, and it rests on the ground at rest (z = its half height, within the contact
    slop, speed round-off)."""
    from hybrid import SceneError
    with pytest.raises(SceneError, match=r"field 'position' starts it 0.55 m inside a plane, deeper "
                                         r"than its 0.346 m size"):
        sim(BURIED.format(name="crate", model="rigid", z=-0.45).replace("young = 1e6", ""))
    deep = sim(BURIED.format(name="crate", model="rigid", z=-0.2).replace("young = 1e6", ""))
    assert deep.run(until=0.5, progress=False, log=lambda m: None)["status"] == "ok"
    assert deep.body("crate").position[2] == pytest.approx(0.1, abs=1e-3)
    assert np.linalg.norm(deep.body("crate").velocity) < 1e-6


def _cylinder_scene(orientation, position, plane_normal=(0.0, 0.0, 1.0)):
    return f"""
[simulation]
dt = 0.001
[[planes]]
normal = [{", ".join(repr(float(c)) for c in plane_normal)}]
friction = 0.8
[[bodies]]
name = "cylinder"
shape = {{ type = "cylinder", radius = 0.1, height = 0.2 }}
orientation = [{", ".join(repr(float(c)) for c in orientation)}]
position = [{", ".join(repr(float(c)) for c in position)}]
friction = 0.8
"""


def _cylinder_axis(model):
    """The cylinder's axis (its shape's z) in its body frame."""
    return model.rigid.shape_rotation[0].T @ [0.0, 0.0, 1.0]


def test_cylinder_rolls_down_a_30_degree_slope_as_a_circle(sim):
    """A solid cylinder on its side rolls without slipping: a = g sin(30) / (1 + I / (m r^2)),
    straight down the slope, and rolling loses no energy. On its polygon of 32 vertices it fell from
    vertex to vertex: 3.0 m/s^2 against 3.27, 9% of the energy lost in 1 s, and it drifted sideways
    at up to 0.15 m/s."""
    slope = math.radians(30.0)
    normal = (-math.sin(slope), 0.0, math.cos(slope))
    down = np.array([-math.cos(slope), 0.0, -math.sin(slope)])
    axis_along_y = (math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0, 0.0)
    s = sim(_cylinder_scene(axis_along_y, (0.0, 0.0, 0.1 / math.cos(slope)), normal))
    rm = s.model.rigid
    m, r, a = rm.body_mass[0], 0.1, _cylinder_axis(s.model)
    I_axis = a @ (rm.body_inertia[0] * a)
    e0, z0 = totals(s.model, s.state)[0], s.state.rigid.position[0, 2]
    t, speed, sideways = [], [], []

    def watch(s):
        v = reported_velocity(rm, s.state.rigid, s.model.gravity)[0]
        t.append(s.state.time)
        speed.append(v @ down)
        sideways.append(abs(v[1]))

    s.advance(1.0, each=watch)
    accel = np.polyfit(t, speed, 1)[0]
    assert accel == pytest.approx(G * math.sin(slope) / (1 + I_axis / (m * r * r)), rel=2e-3)
    assert max(sideways) < 1e-6
    released = m * G * (z0 - s.state.rigid.position[0, 2])
    assert abs(totals(s.model, s.state)[0] - e0) < 1e-3 * released


def test_cylinder_standing_on_its_cap_stays_upright_and_still(sim):
    """Standing on its flat cap the cylinder's rim meets the ground all round (every point of the
    rim is nearest it): it rests without tilting, sliding or spinning."""
    s = sim(_cylinder_scene((1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.1005)))
    s.advance(1.0)
    rs = s.state.rigid
    up = quat.to_matrix(rs.orientation)[0] @ _cylinder_axis(s.model)
    assert abs(up[2]) > 1 - 1e-9
    assert np.linalg.norm(rs.position[0, :2]) < 1e-6
    assert rs.position[0, 2] == pytest.approx(0.1, abs=1e-4)
    assert np.linalg.norm(reported_velocity(s.model.rigid, rs, s.model.gravity)[0]) < 1e-4
    assert np.linalg.norm(angular_velocity(s.model.rigid, rs)[0]) < 1e-4


@pytest.mark.parametrize("dt", [1e-3, 2e-4])
def test_fast_ball_bounces_straight_up_off_a_box_face_beside_its_vertex(sim, dt):
    """A ball falling at 30 m/s onto a fixed box's top face, 1.5 cm beside the face's centre vertex,
    bounces straight back at e times its speed. The box's vertex tested against the ball pushed
    along the ball's normal there, tilted 14 degrees: the ball left sideways at 3.2 m/s at 1 ms."""
    s = sim(f"""
[simulation]
dt = {dt}
gravity = [0.0, 0.0, 0.0]
{_box("table", (0.3, 0.3, 0.1), (0.0, 0.0, 0.05), fixed=True)}
[[bodies]]
name = "ball"
shape = {{ type = "sphere", radius = 0.05 }}
position = [0.015, 0.0, 0.25]
velocity = [0.0, 0.0, -30.0]
density = 7800.0
restitution = 0.5
""")
    s.advance(0.012)
    v = s.state.rigid.velocity[s.rigid_index("ball")]
    np.testing.assert_allclose(v, [0.0, 0.0, 15.0], atol=1e-9)


# ----------------------------------------------------------------------------- spin friction
def _spin_down(sim, shape, height, seconds, friction=0.5, spin=20.0):
    """A body spun at ``spin`` rad/s about the vertical, resting on its face on the ground (both
    friction ``friction``), run for ``seconds``: its spin-down rate (rad/s^2, over the first 0.1
    s), its spin at the end (rad/s) and the distance its centre moved (m)."""
    text = (_simulation(1e-3) + _plane(friction=friction) + "[[bodies]]\nname = \"b\"\n"
            f"shape = {shape}\nposition = [0.0, 0.0, {0.5 * height!r}]\n"
            f"angular_velocity = [0.0, 0.0, {spin!r}]\nfriction = {friction!r}\n")
    s = sim(text)
    start = s.state.rigid.position[0].copy()
    s.advance(0.1)
    rate = (spin - angular_velocity(s.model.rigid, s.state.rigid)[0, 2]) / 0.1
    s.advance(seconds - 0.1)
    return rate, angular_velocity(s.model.rigid, s.state.rigid)[0, 2], \
        np.linalg.norm(s.state.rigid.position[0, :2] - start[:2])


def test_a_box_spun_flat_on_the_ground_slows_as_friction_shared_over_its_face_points(sim):
    """A box touches the ground through its face's sample points (corners, edge midpoints and
    the centre); its weight is shared equally over them (rigid.patches), so the friction torque is
    mu m g times their mean distance from the centre and the spin slows at that over I_zz / m
    (the sweeps alone put the weight on one point: a cylinder on its end spun for good)."""
    a = 0.2
    rate, _, moved = _spin_down(sim, f'{{ type = "box", size = [{a}, {a}, 0.05] }}', 0.05, 0.1)
    arms = [0.0] + [0.5 * a] * 4 + [math.sqrt(0.5) * a] * 4
    assert rate == pytest.approx(0.5 * G * np.mean(arms) / (2 * a * a / 12), rel=0.01)
    assert moved < 1e-5


def test_a_puck_spun_on_its_end_stops_at_the_rate_of_its_shared_weight_without_drifting(sim):
    """A cylinder (r = 0.1 m) spun at 20 rad/s on its flat end on the ground slows and stops: the
    continuum answer for even pressure is 4 mu g / (3 r) = 65 rad/s^2; its points (the end's fan
    of vertices and the rim) lie closer to the axis on average than an even spread, and it slows
    at 0.7-0.9 of that. Sharing, then sweeping again in rounds, keeps its centre put (sweeping
    once from the shared split, friction pushed it 1 cm sideways)."""
    r = 0.1
    rate, spin, moved = _spin_down(sim, f'{{ type = "cylinder", radius = {r}, height = 0.05 }}', 0.05, 0.6)
    assert 0.7 < rate / (4 * 0.5 * G / (3 * r)) < 0.9
    assert abs(spin) < 1e-3
    assert moved < 1e-4


@pytest.mark.parametrize("shape", ['{ type = "cylinder", radius = 0.1, height = 0.05 }',
                                   '{ type = "box", size = [0.2, 0.2, 0.05] }'])
def test_a_body_spun_on_a_fixed_table_slows_as_on_the_ground(sim, shape):
    """A puck or box spun flat on a fixed box turned at 20 rad/s for good, while on the ground
    it stopped: its weight rested on the table's one point against it, which no flat patch took
    in (the patch was its own points against the table, carrying nothing). The table's points
    against it belong to the same patch now: it slows at the rate it does on the ground, to 2%."""
    rates = []
    for table in (False, True):
        text = _simulation(1e-3) + (_plane(friction=0.5) if not table else (
            '[[bodies]]\nname = "table"\nshape = { type = "box", size = [1.0, 1.0, 0.1] }\n'
            'position = [0.0, 0.0, -0.05]\nfixed = true\nfriction = 0.5\n'))
        text += (f'[[bodies]]\nname = "b"\nshape = {shape}\nposition = [0.0, 0.0, 0.025]\n'
                 f'angular_velocity = [0.0, 0.0, 20.0]\nfriction = 0.5\n')
        s = sim(text)
        s.advance(0.1)
        k = s.rigid_index("b")
        rates.append((20.0 - angular_velocity(s.model.rigid, s.state.rigid)[k, 2]) / 0.1)
    assert rates[0] > 30.0 and rates[1] == pytest.approx(rates[0], rel=0.02), rates


def test_a_pyramid_of_four_spheres_holds_still(sim):
    """Three touching spheres on the ground and a fourth on top, friction 0.5 (the pyramid holds
    for mu >= tan(theta / 2) = 0.318). At 20 sweeps a step the contact solve left a residual that
    rolled the pile apart: 11 mm and 7-9 degrees in 10 s, its speed rising; a pass with so few
    contacts sweeps on (up to 100) until it has converged."""
    r = 0.1
    spheres = [(0.0, 0.0, r), (2 * r, 0.0, r), (r, math.sqrt(3) * r, r),
               (r, r / math.sqrt(3), r + 2 * r * math.sqrt(2.0 / 3.0))]
    text = _simulation(DT_240) + _plane(friction=0.5) + "".join(
        f'[[bodies]]\nname = "s{k}"\nshape = {{ type = "sphere", radius = {r} }}\n'
        f'position = [{x!r}, {y!r}, {z!r}]\nfriction = 0.5\n' for k, (x, y, z) in enumerate(spheres))
    s = sim(text)
    start = s.state.rigid.position.copy()
    s.advance(10.0)
    assert np.abs(s.state.rigid.position - start).max() < 5e-5
    assert np.abs(angular_velocity(s.model.rigid, s.state.rigid)).max() < 1e-4


def test_a_spinning_top_precesses_as_theory_says_on_a_tip_that_stays_put(sim, tmp_path):
    """A solid cone (R 5 cm, H 10 cm) on its tip, spun at 1000 rad/s about its axis tilted 20
    degrees, friction 0.9: it precesses at the slow root of the steady-precession equation
    ``A W^2 - I3 w3 W + m g l = 0`` (``A = (I1 - I3) cos(tilt)``, I1 about the tip, l = 3H/4) and
    its tip stays where it is. Friction acted halfway across the tip's 0.5 mm overlap, 0.25 mm up
    the spinning axis, and the tip slid at 9 cm/s (17 cm in 3 s; precession 2.5% fast)."""
    R, H, N, rho, tilt, w3 = 0.05, 0.1, 64, 1000.0, np.radians(20.0), 1000.0
    angles = 2 * np.pi * np.arange(N) / N
    ring = [(float(R * np.cos(a)), float(R * np.sin(a)), H) for a in angles]
    faces = [f for k in range(N) for f in ((1, 3 + (k + 1) % N, 3 + k), (2, 3 + k, 3 + (k + 1) % N))]
    (tmp_path / "cone.obj").write_text("v 0 0 0\nv 0 0 %r\n" % H
                                       + "".join("v %r %r %r\n" % v for v in ring)
                                       + "".join("f %d %d %d\n" % f for f in faces))
    q = (float(np.cos(tilt / 2)), float(np.sin(tilt / 2)), 0.0, 0.0)
    axis = [0.0, float(-w3 * np.sin(tilt)), float(w3 * np.cos(tilt))]
    s = sim(f"""
[simulation]
dt = 0.0005
[[planes]]
friction = 0.9
[[bodies]]
name = "top"
mesh = "{tmp_path / 'cone.obj'}"
density = {rho}
friction = 0.9
orientation = [{q[0]!r}, {q[1]!r}, {q[2]!r}, {q[3]!r}]
position = [0.0, 0.0, 1e-5]
angular_velocity = [{axis[0]!r}, {axis[1]!r}, {axis[2]!r}]
""")
    m = s.model.rigid.body_mass[0]
    I3, I1 = np.sort(s.model.rigid.body_inertia[0])[:2]
    l = 0.75 * H
    A = (I1 + m * l * l - I3) * np.cos(tilt)
    slow = (I3 * w3 - np.sqrt((I3 * w3) ** 2 - 4 * A * m * G * l)) / (2 * A)
    tips, phi = [], []

    def watch(s):
        body = s.body("top")
        turn = quat.to_matrix(body.orientation)          # the cone's axis: its third column
        tips.append(body.position - turn[:, 2] * l)
        phi.append(np.arctan2(turn[1, 2], turn[0, 2]))

    s.advance(1.0, each=watch)
    tips, phi = np.array(tips), np.unwrap(phi)
    rate = np.polyfit(np.arange(len(phi)) * 0.0005, phi, 1)[0]
    assert rate == pytest.approx(slow, rel=0.01)
    assert np.linalg.norm(tips[-1, :2] - tips[0, :2]) < 0.01


@pytest.mark.parametrize("gap", [1e-3, 1e-4])
def test_a_row_of_balls_struck_in_one_step_never_gains_energy(sim, gap):
    """Newton's cradle without gravity: five 5 cm balls in a row, ``gap`` apart, e = 1, the first
    two moving at 1 m/s, 5 cm short of the other three. Two impacts that pass on through the
    resting balls in the same step cannot each meet their restitution target: met as far as they
    could be, the balls left at [-0.6, 0.4, 0.4, 1.4, 0.4] m/s with 40% more energy. Momentum is
    kept exactly and energy never rises; 1 mm apart (one impact per ball a step) the last two
    leave at 1 m/s and the rest stop, as the cradle does."""
    balls = "".join(f"""
[[bodies]]
name = "s{k}"
shape = {{ type = "sphere", radius = 0.05 }}
restitution = 1.0
friction = 0.0
velocity = [{1.0 if k < 2 else 0.0}, 0.0, 0.0]
position = [{k * (0.1 + gap) + (0.05 if k > 1 else 0.0)!r}, 0.0, 0.0]
""" for k in range(5))
    # and, 2 m away, two inelastic balls (e = 0) meeting at 0.1 m/s in the same step: they stop,
    # however the cradle's impacts are taken (one restitution for the whole scene bounced them)
    pair = "".join(f"""
[[bodies]]
name = "p{k}"
shape = {{ type = "sphere", radius = 0.05 }}
restitution = 0.0
friction = 0.0
velocity = [{0.1 * sign!r}, 0.0, 0.0]
position = [{-0.05515 * sign!r}, 2.0, 0.0]
""" for k, sign in enumerate((1.0, -1.0)))
    s = sim(_simulation(1e-3, gravity=(0.0, 0.0, 0.0)) + balls + pair)
    mass = s.body("s0").mass
    s.advance(0.4)
    v = np.array([s.body(f"s{k}").velocity[0] for k in range(5)])
    assert v.sum() * mass == pytest.approx(2.0 * mass, rel=1e-9)
    assert 0.5 * mass * (v ** 2).sum() <= 1.0 * mass * (1 + 1e-9)
    if gap == 1e-3:
        np.testing.assert_allclose(v, [0.0, 0.0, 0.0, 1.0, 1.0], atol=1e-6)
    np.testing.assert_allclose([s.body("p0").velocity[0], s.body("p1").velocity[0]], 0.0, atol=1e-9)


def test_a_box_bouncing_flat_with_e_1_never_gains_energy(sim):
    """A 0.2 m cube dropped flat from 1 m, e = 1: its face strikes over a few tenths of a
    millisecond as round-off tilts it, and the bounces never raise its energy (a box moved back
    to the latest of its corners' impact times ended with its first corners deep, was pushed out
    with velocity, and gained 25% in 8 s)."""
    s = sim(_simulation(1e-3) + _plane(friction=0.5, restitution=1.0)
            + _box("box", (0.2, 0.2, 0.2), (0.0, 0.0, 1.1), restitution=1.0))
    mass = s.body("box").mass
    energy = []
    s.advance(8.0, each=lambda s: energy.append(s.body("box").kinetic_energy
                                                + mass * G * s.body("box").position[2]))
    assert max(energy) <= mass * G * 1.1 * (1 + 1e-5)


@pytest.mark.parametrize("dt", [DT_240, 1e-3])
def test_a_cube_tumbling_onto_the_ground_with_e_1_keeps_its_energy(sim, dt):
    """A 0.2 m cube dropped 1 m tilted by 30 degrees, e = 1, with friction, lands on a corner and
    tumbles: its energy never rises. Moved back to its impact's time, its spin took the angular
    momentum that keeps the total about the origin exact, which the ground does not keep anyway,
    and that spin added 15% of the energy at dt = 1/240 (1% at 1 ms)."""
    half = np.radians(30.0) / 2
    q = (np.cos(half), 0.8 * np.sin(half), 0.6 * np.sin(half), 0.0)
    s = sim(_simulation(dt) + _plane(friction=0.5, restitution=1.0)
            + _box("box", (0.2, 0.2, 0.2), (0.0, 0.0, 1.2), restitution=1.0, friction=0.5,
                   orientation=list(q)))
    mass = s.body("box").mass
    energy = [mass * G * 1.2]
    s.advance(2.0, each=lambda s: energy.append(s.body("box").kinetic_energy
                                                + mass * G * s.body("box").position[2]))
    assert max(energy) <= energy[0] * (1 + 1e-6)


@pytest.mark.parametrize("angle", [0.0, 30.0])
def test_a_sliding_box_reports_its_velocity_with_the_whole_steps_friction(sim, angle):
    """The reported velocity (bodies.csv, Simulation.body) left out half a step of the contact's
    friction: a box sliding on the ground read 0.5 dt mu g too fast, and one sliding down a slope
    moved into it. A contact velocity change of a force's size counts as acting over the step:
    sent up the slope, its speed is v0 - g (mu cos a + sin a) t to round-off, and nothing
    crosses the plane."""
    a = math.radians(angle)
    n = (-math.sin(a), 0.0, math.cos(a))
    up = np.array([math.cos(a), 0.0, math.sin(a)])             # up the slope
    s = sim(_simulation(DT_240) + _plane(normal=n, friction=0.4) + _box(
        "b", (0.3, 0.2, 0.1), position=tuple(0.05 * np.array(n)), friction=0.4,
        orientation=(math.cos(a / 2), 0.0, -math.sin(a / 2), 0.0), velocity=tuple(3.0 * up)))
    for _ in range(4):
        s.advance(0.05)
        v = s.body("b").velocity
        expected = 3.0 - G * (0.4 * math.cos(a) + math.sin(a)) * s.time
        assert v @ up == pytest.approx(expected, abs=1e-9)
        assert abs(v @ np.array(n)) < 1e-9


def test_bodies_of_one_mesh_file_share_one_distance_grid_and_rest_on_each_other(sim):
    """Each body read from a mesh file built its own distance grid (200 bodies of one file took
    30 s to build): bodies of one surface share it. Two capsules (r = 5 cm, 30 cm long, from
    meshes/capsule_surface.obj) laid crosswise come to rest one on the other, their centres 2 r
    apart."""
    from pathlib import Path
    mesh = Path(__file__).parent.parent / "meshes" / "capsule_surface.obj"
    s = sim(f"""
[simulation]
dt = 0.002
[[planes]]
[[bodies]]
name = "low"
mesh = "{mesh}"
orientation = [0.7071067811865476, 0.7071067811865476, 0.0, 0.0]
position = [0.0, 0.0, 0.055]
[[bodies]]
name = "high"
mesh = "{mesh}"
orientation = [0.5, 0.5, 0.5, 0.5]
position = [0.0, 0.0, 0.16]
""")
    rm = s.model.rigid
    assert rm.grid_index[0] == rm.grid_index[1] and len(rm.grid_cell) == 1
    s.advance(0.6)
    low, high = s.body("low"), s.body("high")
    assert abs(low.position[2] - 0.05) < 1e-3 and abs(high.position[2] - low.position[2] - 0.1) < 1.5e-3
    assert np.abs(high.velocity).max() < 1e-2
