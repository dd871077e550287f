"""Mass properties of primitive shapes against closed forms; the primitive surfaces themselves."""
import numpy as np
import pytest

from rigid import quaternion, shapes, trimesh
from rigid.mass import MassProperties, mass_properties, principal_axes

DENSITY = 7800.0  # steel, kg/m^3


def random_rotation(seed):
    q = np.random.default_rng(seed).normal(size=4)
    return quaternion.to_matrix(q / np.linalg.norm(q))


@pytest.mark.parametrize("size", [(1.0, 1.0, 1.0), (0.2, 0.5, 1.3), (3.0, 0.01, 0.4)])
def test_box_mass_com_inertia_exact_against_closed_form(size):
    vertices, triangles = shapes.box_surface(size)
    offset = np.array([10.0, -3.0, 250.0])  # far from the origin: exercises the reference shift
    props = mass_properties(vertices + offset, triangles, DENSITY)
    volume = np.prod(size)
    assert isinstance(props, MassProperties)
    assert props.volume == pytest.approx(volume, rel=1e-12)
    assert props.mass == pytest.approx(DENSITY * volume, rel=1e-12)
    np.testing.assert_allclose(props.com, offset, atol=1e-12 * np.abs(offset).max())
    expected = shapes.box_inertia(DENSITY * volume, size)
    np.testing.assert_allclose(props.inertia, expected, rtol=1e-10, atol=1e-10 * expected.max())


def test_sphere_inertia_converges_to_two_fifths_m_r2_at_second_order():
    radius = 0.3
    exact = shapes.sphere_inertia(DENSITY * 4.0 / 3.0 * np.pi * radius**3, radius)
    edges, errors = [], []
    for level in range(1, 6):
        # the longest edge of icosphere level L is about 1.26 * 1.05 r / 2^L; ask for that level
        resolution = 1.4 * radius / 2**level
        vertices, triangles = shapes.sphere_surface(radius, resolution)
        assert len(vertices) == 10 * 4**level + 2
        props = mass_properties(vertices, triangles, DENSITY)
        errors.append(np.abs(props.inertia - exact).max() / exact[0, 0])
        edges.append(resolution)
        # symmetric polyhedron: centre of mass at the centre, inertia isotropic
        np.testing.assert_allclose(props.com, 0.0, atol=1e-14)
        assert np.ptp(np.diag(props.inertia)) < 1e-9 * exact[0, 0]
    errors = np.array(errors)
    rate = np.polyfit(np.log(edges), np.log(errors), 1)[0]
    print(f"sphere inertia relative errors {errors}, observed order {rate:.2f}")
    assert np.all(np.diff(errors) < 0)
    assert 1.8 < rate < 2.2  # inscribed polyhedron: volume defect ~ edge^2
    assert errors[3] < 0.01 and errors[-1] < 1e-3


def test_cylinder_inertia_converges_to_closed_form():
    radius, height = 0.2, 0.9
    mass = DENSITY * np.pi * radius**2 * height
    exact = shapes.cylinder_inertia(mass, radius, height)
    resolutions = 2.0 * np.pi * radius / np.array([8, 16, 32, 64, 128])
    errors = []
    for resolution in resolutions:
        vertices, triangles = shapes.cylinder_surface(radius, height, resolution)
        props = mass_properties(vertices, triangles, DENSITY)
        errors.append(np.max(np.abs(np.diag(props.inertia) / np.diag(exact) - 1)))
        assert props.com[2] == pytest.approx(0.0, abs=1e-14)
    errors = np.array(errors)
    rate = np.polyfit(np.log(resolutions), np.log(errors), 1)[0]
    print(f"cylinder inertia relative errors {errors}, observed order {rate:.2f}")
    assert np.all(np.diff(errors) < 0)
    assert 1.8 < rate < 2.2  # inscribed polygon area defect ~ (2 pi / n)^2
    assert errors[3] < 0.01  # 64 segments


def test_rotated_translated_mesh_moves_com_and_rotates_inertia():
    vertices, triangles = shapes.capsule_surface(0.15, 0.8)
    vertices = vertices * [1.0, 1.7, 1.0] + [0.05, 0.0, 0.1]  # break the symmetry
    base = mass_properties(vertices, triangles, DENSITY)
    R, shift = random_rotation(3), np.array([1.5, -2.0, 0.25])
    moved = mass_properties(vertices @ R.T + shift, triangles, DENSITY)
    assert moved.mass == pytest.approx(base.mass, rel=1e-12)
    np.testing.assert_allclose(moved.com, R @ base.com + shift, atol=1e-12)
    np.testing.assert_allclose(moved.inertia, R @ base.inertia @ R.T, atol=1e-10 * base.inertia.max())


def test_principal_axes_diagonalise_inertia_with_right_handed_frame():
    R = random_rotation(7)
    moments = np.array([0.5, 2.0, 3.5])
    inertia = R @ np.diag(moments) @ R.T
    found, axes = principal_axes(inertia)
    np.testing.assert_allclose(found, moments, rtol=1e-12)
    assert np.linalg.det(axes) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(axes @ np.diag(found) @ axes.T, inertia, atol=1e-12)
    np.testing.assert_allclose(np.abs(axes.T @ R), np.eye(3), atol=1e-9)


def test_inward_facing_surface_is_rejected():
    vertices, triangles = shapes.box_surface(1.0)
    with pytest.raises(ValueError, match="volume must be positive"):
        mass_properties(vertices, triangles[:, ::-1], DENSITY)
    with pytest.raises(ValueError, match="density"):
        mass_properties(vertices, triangles, -1.0)


SURFACES = {
    "box": lambda: shapes.box_surface((0.4, 1.0, 0.25)),
    "box_fine": lambda: shapes.box_surface((1.0, 1.0, 1.0), 0.1),
    "sphere": lambda: shapes.sphere_surface(0.5),
    "cylinder": lambda: shapes.cylinder_surface(0.3, 1.2),
    "flat_cylinder": lambda: shapes.cylinder_surface(1.0, 0.05, 0.2),
    "capsule": lambda: shapes.capsule_surface(0.25, 1.0),
    "capsule_as_sphere": lambda: shapes.capsule_surface(0.25, 0.5),
}


@pytest.mark.parametrize("name", sorted(SURFACES))
def test_primitive_surface_is_closed_outward_and_has_no_duplicate_vertices(name):
    vertices, triangles = SURFACES[name]()
    assert vertices.dtype == np.float64 and triangles.dtype == np.int64
    assert trimesh.is_closed(triangles)
    assert trimesh.signed_volume(vertices, triangles) > 0
    assert len(np.unique(vertices.round(12), axis=0)) == len(vertices)
    assert len(np.unique(triangles)) == len(vertices)
    # every primitive is convex and centred: each face normal points away from the origin
    corners = vertices[triangles]
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    assert np.all(np.linalg.norm(normal, axis=1) > 0)
    assert np.all(np.einsum("ij,ij->i", normal, corners.mean(axis=1)) > 0)
    np.testing.assert_allclose(0.5 * (vertices.min(axis=0) + vertices.max(axis=0)), 0.0, atol=1e-12)


def test_default_box_faces_have_interior_vertices():
    size = np.array([0.4, 1.0, 0.25])
    vertices, _ = shapes.box_surface(size)
    half = size / 2
    for axis in range(3):
        others = [a for a in range(3) if a != axis]
        for sign in (-1, 1):
            on_face = np.isclose(vertices[:, axis], sign * half[axis])
            interior = on_face & np.all(np.abs(vertices[:, others]) < half[others] - 1e-12, axis=1)
            assert interior.sum() >= 1, (axis, sign)


def test_capsule_volume_converges_to_cylinder_plus_sphere():
    radius, height = 0.2, 1.0
    exact = np.pi * radius**2 * (height - 2 * radius) + 4.0 / 3.0 * np.pi * radius**3
    assert shapes.capsule_volume(radius, height) == pytest.approx(exact)
    errors = []
    for segments in (16, 32, 64, 128):
        vertices, triangles = shapes.capsule_surface(radius, height, 2 * np.pi * radius / segments)
        assert vertices[:, 2].max() == pytest.approx(height / 2)
        errors.append(abs(trimesh.signed_volume(vertices, triangles) / exact - 1))
    print(f"capsule volume relative errors {errors}")
    assert np.all(np.diff(errors) < 0) and errors[-1] < 1e-3


def test_capsule_shorter_than_its_caps_is_rejected():
    with pytest.raises(ValueError, match="total length"):
        shapes.capsule_surface(0.5, 0.9)


def test_make_shape_dispatches_and_rejects_bad_specs():
    v, t = shapes.make_shape({"type": "box", "size": [1.0, 2.0, 3.0]})
    assert trimesh.signed_volume(v, t) == pytest.approx(6.0)
    v, t = shapes.make_shape({"type": "box", "size": 0.5, "resolution": 0.1})
    assert trimesh.signed_volume(v, t) == pytest.approx(0.125) and len(v) == 6 * 16 + 12 * 4 + 8
    v, t = shapes.make_shape({"type": "sphere", "radius": 2.0})
    assert np.linalg.norm(v, axis=1) == pytest.approx(2.0)
    v, t = shapes.make_shape({"type": "cylinder", "radius": 1.0, "height": 2.0})
    assert np.ptp(v[:, 2]) == pytest.approx(2.0)
    v, t = shapes.make_shape({"type": "capsule", "radius": 1.0, "height": 3.0})
    assert np.ptp(v[:, 2]) == pytest.approx(3.0)
    bad = [
        ({"type": "cone", "radius": 1.0}, "unknown shape type"),
        ({"radius": 1.0}, "'type'"),
        ({"type": "sphere"}, "needs key"),
        ({"type": "sphere", "radius": 1.0, "size": 2.0}, "does not accept"),
        ({"type": "sphere", "radius": -1.0}, "radius must be a positive"),
        ({"type": "box", "size": [1.0, 0.0, 1.0]}, "box size along y"),
        ({"type": "box", "size": [1.0, 1.0]}, "three numbers"),
        ({"type": "cylinder", "radius": 1.0, "height": float("nan")}, "height"),
        ({"type": "sphere", "radius": 1.0, "resolution": 0.0}, "resolution"),
    ]
    for spec, message in bad:
        with pytest.raises(ValueError, match=message):
            shapes.make_shape(spec)
