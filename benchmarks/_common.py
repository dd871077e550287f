"""Shared by the benchmark scripts: writing their result tables, the soft cube scene."""
import csv
from pathlib import Path

import meshio


def write_csv(path, rows):
    """Write a list of dicts (same keys) as CSV, creating the folder."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


# a soft 20 cm cube of 1,296 tets dropped on the ground, written at 100 frames/s (the scene of
# issue 24's output and cold-start figures)
CUBE_SCENE = """
[simulation]
name = "cube"
duration = 1.0
dt = 0.001
output_fps = 100

[[planes]]
friction = 0.5

[[bodies]]
name = "cube"
model = "fem"
mesh = "cube.vtu"
position = [0.0, 0.0, 0.15]
density = 1000.0
young = 1.0e5
poisson = 0.3
damping = { mass = 0.0, stiffness = 0.01 }
"""


def cube_scene(folder):
    """The soft cube's scene file ``cube.toml`` in ``folder`` (its mesh written beside it);
    returns its path. Imports the project only when called (cold_start.py times a run's own
    imports)."""
    from fem.mesh import box_tet_mesh
    folder = Path(folder)
    points, tets = box_tet_mesh([0.2, 0.2, 0.2], (6, 6, 6))
    meshio.write(folder / "cube.vtu", meshio.Mesh(points, [("tetra", tets)]))
    (folder / "cube.toml").write_text(CUBE_SCENE)
    return folder / "cube.toml"
