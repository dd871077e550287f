"""Auto bodies turned rigid rest on each other by their edges too (hybrid.coupling.switch).

A body turned rigid meets rigid bodies through its hull's vertices. Two auto boxes stacked 1 cm
apart, a rigid box on them, rest on each other's edges where those nearly coincide: the corners
alone met the other box with normals tilted by its edge, and the upper box, turned rigid, sank
into the lower one at g / 8 (1.3 mm in 46 ms) until both turned deformable again, six times in
1.5 s with a deformable box on top, ending 5 mm from the all-FEM stack. Nodes on the hull's edges
meet them as well.
"""
import numpy as np

from hybrid import Simulation
from hybrid.coupling.switch import hull_points

SCENE = """
[simulation]
duration = 0.5
dt = 0.002

[[planes]]
friction = 0.5

[[bodies]]
name = "b1"
model = "auto"
shape = { type = "box", size = [0.1, 0.1, 0.1], resolution = 0.025 }
position = [0.0, 0.0, 0.0505]
young = 1.0e6
poisson = 0.4
damping = { stiffness = 0.002 }

[[bodies]]
name = "b2"
model = "auto"
shape = { type = "box", size = [0.1, 0.1, 0.1], resolution = 0.025 }
position = [0.01, 0.0, 0.152]
young = 1.0e6
poisson = 0.4
damping = { stiffness = 0.002 }

[[bodies]]
name = "b3"
shape = { type = "box", size = [0.1, 0.1, 0.1] }
position = [-0.01, 0.005, 0.2535]
"""


def test_a_boxs_hull_points_are_its_corners_and_edge_nodes_not_its_face_nodes():
    g = np.linspace(-0.05, 0.05, 5)
    grid = np.array(np.meshgrid(g, g, g, indexing="ij")).reshape(3, -1).T
    surface = grid[np.abs(grid).max(axis=1) > 0.0499]             # 98 surface nodes
    on, off = hull_points(surface)
    edges = (np.abs(surface) > 0.0499).sum(axis=1) >= 2           # 8 corners, 36 edge nodes
    assert len(on) == edges.sum() == 44 and len(off) == 54
    assert {tuple(p) for p in on} == {tuple(p) for p in surface[edges]}


def test_auto_boxes_stacked_with_an_offset_rest_once_rigid(tmp_path):
    path = tmp_path / "stack.toml"
    path.write_text(SCENE)
    sim = Simulation.from_toml(path)
    heights, switches = [], []
    while sim.time < 0.5 - 1e-9:
        switches += [e for e in sim.step() if getattr(e, "event", None) in ("rigidify", "elastify")]
        if sim.body("b2").kind == "rigid":
            heights.append(sim.body("b2").position[2])
    print(f"b2 rigid over {len(heights)} steps, z {min(heights):.6f}..{max(heights):.6f} m; "
          f"switches {[(e.body, e.event) for e in switches]}")
    assert [e.event for e in switches] == ["rigidify", "rigidify"]      # once each, for good
    assert max(heights) - min(heights) < 1e-5                           # it does not sink
    kinetic = sum(sim.body(n).kinetic_energy for n in sim.body_names)
    assert kinetic < 1e-8
