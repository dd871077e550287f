"""Stacks of bodies smaller than the contact margin stand as larger ones do.

Contacts are found within the contact margin (5 mm by default) of touching: under a stack of
1 mm cubes the ground lies within it of every cube. Those contacts across a gap carry nothing,
and the shock propagation's levels count only contacts that carry a load (rigid.shock)."""
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from hybrid import Simulation
from hybrid.app.scene import parse_scene

SIZE = 0.001        # m, the cubes' side


def _scene(plane_normal, boxes, seconds):
    text = (f"[simulation]\nduration = {seconds}\ndt = 0.0005\n[[planes]]\n"
            f"normal = [{float(plane_normal[0])!r}, 0.0, {float(plane_normal[2])!r}]\nfriction = 0.5\n")
    for k, (position, orientation) in enumerate(boxes):
        text += (f'[[bodies]]\nname = "c{k}"\nshape = {{ type = "box", size = [{SIZE}, {SIZE}, {SIZE}] }}\n'
                 f"density = 7800.0\nfriction = 0.5\nposition = {list(map(float, position))}\n"
                 f"orientation = {list(map(float, orientation))}\n")
    return Simulation(parse_scene(tomllib.loads(text), "<test>", Path(".")))


def _tilt_degrees(q):
    return np.degrees(2.0 * np.arccos(np.minimum(1.0, np.abs(q[:, 0]))))


@pytest.mark.parametrize("count", [2, 3])
def test_a_stack_of_millimetre_cubes_stands_at_the_default_margin(count):
    """Three 1 mm steel cubes stacked on the ground: they leaned 4-5 degrees in 0.5 s and the
    top one moved 0.15 mm sideways (two: 1 degree), while 1 cm cubes stood. They stand."""
    sim = _scene((0.0, 0.0, 1.0), [((0, 0, (k + 0.5) * SIZE), (1, 0, 0, 0)) for k in range(count)], 0.5)
    start = sim.state.rigid.position.copy()
    sim.run(progress=False, log=lambda m: None)
    rs = sim.state.rigid
    assert _tilt_degrees(rs.orientation).max() < 0.01
    assert np.abs(rs.position - start).max() < 1e-3 * SIZE


def test_millimetre_boxes_stacked_on_a_slope_within_their_friction_stay():
    """Two 1 mm boxes stacked on a 20 degree slope with mu = 0.5 (> tan 20 = 0.36: friction
    holds them): the top one crept 5.5% of its size and turned 2.3 degrees in 1 s."""
    a = math.radians(20.0)
    n = np.array([-math.sin(a), 0.0, math.cos(a)])
    q = (math.cos(a / 2), 0.0, -math.sin(a / 2), 0.0)
    sim = _scene(n, [(n * (k + 0.5) * SIZE, q) for k in range(2)], 1.0)
    start = sim.state.rigid.position.copy()
    sim.run(progress=False, log=lambda m: None)
    rs = sim.state.rigid
    assert np.abs(rs.position - start).max() < 0.01 * SIZE
    assert np.abs(_tilt_degrees(rs.orientation) - 20.0).max() < 0.05
