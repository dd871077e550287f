"""A grip holds a broken piece only where it pins it (hybrid.coupling.fragments.held_regions).

A brittle bar pulled slowly in two grips cracks first beside a grip, along mesh faces, and cut
one-tet chips out of the grip's layer that the grip held by an edge: a contact's push swung such
a chip 0.2 m in one step about that edge (linear elements in a held body's fixed frame do not
turn), and the run stopped at 2e4 m/s; the bar itself, held by the last node of the moving grip,
was dragged at a point. Pieces held by fewer than three nodes, or by nodes on one line, are let go.
"""
from types import SimpleNamespace

import numpy as np

from fem.split import Fragment
from hybrid import Simulation
from hybrid.coupling.fragments import held_regions

PULL = """
[simulation]
duration = 0.072
dt = 0.0005
gravity = [0.0, 0.0, 0.0]
output_fps = 200

[[bodies]]
name = "bar"
model = "fem"
shape = { type = "box", size = [0.1, 0.01, 0.01], resolution = 0.0033333 }
density = 2500.0
young = 70e9
poisson = 0.22
fracture_stress = 50e6

[[bodies.anchors]]
box = [[-1, -1, -1], [-0.0499, 1, 1]]

[[bodies.anchors]]
box = [[0.0499, -1, -1], [1, 1, 1]]
velocity = [1e-3, 0.0, 0.0]
"""


def _parent(points, anchored):
    """What held_regions reads of a parent: its rest points and one anchor on ``anchored``."""
    node_anchor = -np.ones(len(points), dtype=int)
    node_anchor[anchored] = 0
    return SimpleNamespace(rest_points=points, node_anchor=node_anchor,
                           anchor_nodes=(np.asarray(anchored),))


def test_a_piece_held_by_an_edge_or_a_node_is_let_go_by_a_face_kept():
    cube = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0],
                     [0, 0, 1], [1, 0, 1], [0, 1, 1], [1, 1, 1]], dtype=float)
    origin = np.arange(8)
    parent = _parent(cube, [1, 3, 5, 7])                      # the face x = 1: pins the cube

    def piece(nodes):
        nodes = np.asarray(nodes)
        return Fragment(cube[nodes], np.array([[0, 1, 2, 3]]), nodes, np.array([0]))

    assert held_regions(parent, piece([1, 3, 0, 2]), origin) == []          # by an edge
    assert held_regions(parent, piece([1, 0, 2, 4]), origin) == []          # by one node
    kept = held_regions(parent, piece([1, 3, 5, 0]), origin)                # by a face
    assert len(kept) == 1 and sorted(kept[0][1]) == [0, 1, 2]
    hinge = _parent(cube, [1, 3])                             # the scene holds it on a line
    assert len(held_regions(hinge, piece([1, 3, 0, 2]), origin)) == 1


def test_a_bar_pulled_to_fracture_in_its_grips_stays_stable(tmp_path):
    """Energy check: the pieces' kinetic energy stays below the strain energy the bar held at its
    strength, sigma^2 A L / (2 E); every grip still holding a piece pins it."""
    scene = tmp_path / "pull.toml"
    scene.write_text(PULL)
    sim = Simulation.from_toml(scene)
    sim.run(until=0.072, progress=False, log=lambda message: None)
    assert len(sim.body_names) > 2                            # it broke
    stored = (50e6) ** 2 * 0.01 * 0.01 * 0.1 / (2 * 70e9)
    kinetic = sum(sim.body(name).kinetic_energy for name in sim.body_names)
    print(f"{len(sim.body_names)} pieces, kinetic {kinetic:.3g} J of {stored:.3g} J stored")
    assert kinetic < stored
    for model in sim.model.fem:
        for nodes in model.anchor_nodes:
            held = model.rest_points[nodes]
            assert len(held) >= 3
            assert np.linalg.svd(held - held.mean(axis=0), compute_uv=False)[1] > 1e-9
