"""A deformable box dropped onto a deformable plate anchored at both ends comes to rest flat.

The plate's top nodes beside the box, within the contact margin of its side faces, meet it along
their own normals (hybrid.coupling.fem_contact.pair_edge_normals); their gap must be their height
under the box, not the side face's gap times the cosine between the normals, which read the side
face's tilt times their distance to it as a penetration and held the box's raised side up: it came
to rest balanced on one bottom edge, tilted by 4.7 mrad (94 um across its 2 cm)."""
import numpy as np
import pytest

from conftest import Sim

SCENE = """
[simulation]
duration = 0.2
dt = 0.001
[[bodies]]
name = "plate"
model = "fem"
shape = {{ type = "box", size = [0.42, 0.05, 0.01], resolution = 0.01 }}
order = 2
density = 2700.0
young = 7.0e10
damping = {{ mass = 100.0 }}
[[bodies.anchors]]
box = [[-1, -1, -1], [-0.2, 1, 1]]
[[bodies.anchors]]
box = [[0.2, -1, -1], [1, 1, 1]]
[[bodies]]
name = "box"
model = "fem"
shape = {{ type = "box", size = [0.02, 0.02, 0.02] }}
density = 7800.0
young = 2.0e11
position = [0.0, 0.0, {z}]
"""


def _bottom_tilt(sim):
    """The box's bottom face now: its tilt (rad, of the plane through its nodes), the spread of
    their heights (m) and their mean height (m)."""
    assert sim.model.names[sim.model.fem_ids[1]] == "box"
    rest, state = sim.model.fem[1].rest_points, sim.state.fem[1]
    bottom = np.abs(rest[:, 2] - rest[:, 2].min()) < 1e-9
    x = state.x[bottom]
    slope = np.linalg.lstsq(np.c_[x[:, 0], x[:, 1], np.ones(len(x))], x[:, 2], rcond=None)[0][:2]
    return float(np.hypot(*slope)), float(np.ptp(x[:, 2])), float(x[:, 2].mean())


@pytest.mark.parametrize("drop", [0.2e-3, 5e-3])
def test_box_dropped_on_anchored_quadratic_plate_rests_flat(drop):
    # the box's bottom starts ``drop`` m over the plate's top face (z = 5 mm)
    sim = Sim(SCENE.format(z=0.015 + drop)).advance(0.2)
    tilt, spread, height = _bottom_tilt(sim)
    assert tilt < 1e-4, f"tilted {tilt:.2e} rad"
    assert spread < 1e-6, f"bottom face spans {spread * 1e6:.2f} um"
    # lying on the plate's top face, at rest
    assert abs(height - 0.005) < 2e-5
    assert np.abs(sim.state.fem[1].v).max() < 1e-5
