"""Resolved contact stresses against theory: a rigid sphere pressed slowly into a finely meshed
elastic block follows Hertz's force-depth law (issue 23)."""
import meshio
import numpy as np

from fem.mesh import box_tet_mesh

E, NU, R = 1e6, 0.3, 0.05            # block's Young's modulus (Pa), Poisson ratio; sphere radius (m)
E_STAR = E / (1 - NU ** 2)           # the sphere is rigid
A = 0.005                            # contact radius at the deepest indentation (m)
D_MAX = A * A / R                    # Hertz: a^2 = R d
STEPS, DT = 10, 0.05                 # backward Euler at 50 ms against a 3 ms wave transit: quasi-static


def graded(h, inner, outer, ratio):
    """Node coordinates from 0 to ``outer``: cells of ``h`` up to ``inner``, then each ``ratio``
    times longer than the last."""
    xs, step = list(np.arange(0.0, inner + 1e-12, h)), h
    while xs[-1] < outer - 1e-12:
        step *= ratio
        xs.append(min(xs[-1] + step, outer))
    if outer - xs[-2] < 0.5 * (xs[-2] - xs[-3]):
        xs.pop(-2)
    return np.array(xs)


def block_mesh(path, half, height):
    """A block ``2 half`` wide and ``height`` tall (m), its top at z = height: cells a third of
    the contact radius within 1.5 contact radii of the top's centre, growing 1.8x a cell beyond."""
    side = graded(A / 3, 1.5 * A, half, 1.8)
    xs = np.concatenate([-side[:0:-1], side])
    zs = height - graded(A / 3, 1.5 * A, height, 1.8)[::-1]
    cells = np.array([len(xs) - 1, len(xs) - 1, len(zs) - 1])
    points, tets = box_tet_mesh(cells.astype(float), cells)
    index = points + cells / 2                  # each node's grid index along each axis
    points = np.column_stack([np.interp(index[:, 0], np.arange(len(xs)), xs),
                              np.interp(index[:, 1], np.arange(len(xs)), xs),
                              np.interp(index[:, 2], np.arange(len(zs)), zs)])
    meshio.write(path, meshio.Mesh(points, [("tetra", tets)]))


def hertz_surface_displacement(F, r):
    """Hertz: vertical surface displacement (m) of a half-space at radius ``r`` > a under the
    contact of force ``F`` (N) (Johnson, Contact Mechanics, eq. 3.42)."""
    a = (3 * F * R / (4 * E_STAR)) ** (1 / 3)
    p0 = 3 * F / (2 * np.pi * a * a)
    return p0 / (2 * a * E_STAR) * ((2 * a * a - r * r) * np.arcsin(a / r)
                                    + r * a * np.sqrt(1 - a * a / (r * r)))


def test_rigid_sphere_pressed_into_block_follows_hertz_force_depth_law(sim, tmp_path):
    half = height = 10 * A
    block_mesh(tmp_path / "block.vtu", half, height)
    speed = D_MAX / (STEPS * DT)
    s = sim(f"""
[simulation]
dt = {DT}
duration = {STEPS * DT}
gravity = [0.0, 0.0, 0.0]
[simulation.solver]
hold_resting = false
[[bodies]]
name = "block"
model = "fem"
mesh = "block.vtu"
young = {E}
poisson = {NU}
friction = 0.0
[[bodies.anchors]]
box = [[-1, -1, -1e-6], [1, 1, 1e-6]]
velocity = [0.0, 0.0, {speed}]
[[bodies]]
name = "sphere"
fixed = true
friction = 0.0
shape = {{ type = "sphere", radius = {R} }}
position = [0.0, 0.0, {height + R}]
""", base_dir=tmp_path)
    m = s.model.fem[0]
    X = m.rest_points
    centre = int(np.argmin(np.linalg.norm(X - [0.0, 0.0, height], axis=1)))
    r = np.hypot(X[:, 0], X[:, 1])
    ring = (np.abs(X[:, 2] - height) < 1e-9) & (np.abs(r - 3 * A) < 0.6 * A)
    forces, depths = [], []
    for _ in range(STEPS):
        s.step()
        state = s.state.fem[0]
        F = state.node_reaction[m.anchor_nodes[0]].sum(axis=0)[2]     # what the sphere takes
        uz = state.x[:, 2] - X[:, 2]
        # the block is finite (its base held, 10 contact radii down): depth is the approach of
        # the contact's centre to the surface 3 contact radii out, plus what Hertz's pressure
        # moves that surface in a half-space (against the anchor's travel it is 12-19% stiffer)
        depths.append(float(np.mean(uz[ring] - uz[centre] + hertz_surface_displacement(F, r[ring]))))
        forces.append(F)
    forces, depths = np.array(forces), np.array(depths)
    assert np.max(np.abs(s.state.fem[0].x[centre, 2] - height)) < 0.01 * D_MAX   # it touches
    hertz = 4 / 3 * E_STAR * np.sqrt(R) * depths ** 1.5
    deep = slice(STEPS // 2, None)            # contact radius at least 0.7 A: 2 cells and more
    assert np.all(np.abs(forces[deep] / hertz[deep] - 1) < 0.10), forces / hertz
    exponent = np.polyfit(np.log(depths[deep]), np.log(forces[deep]), 1)[0]
    assert abs(exponent - 1.5) < 0.15, exponent
