"""Build time of the default signed-distance grids (no timing is asserted in tests; it lives here).

    python benchmarks/sdf_build.py
"""
import time

from rigid import shapes
from rigid.sdf import SignedDistanceGrid


def main():
    SignedDistanceGrid.build(*shapes.box_surface(1.0), cell_size=0.5)  # compile numba once
    for name, (v, t) in (("icosphere", shapes.sphere_surface(1.0)),
                         ("box 1x0.6x0.3", shapes.box_surface((1.0, 0.6, 0.3)))):
        times = []
        for _ in range(3):
            start = time.perf_counter()
            grid = SignedDistanceGrid.build(v, t)
            times.append(time.perf_counter() - start)
        times.sort()
        print(f"{name:14s} {len(v):5d} vertices  grid {grid.shape.tolist()}  median build {times[1]:.3f} s")


if __name__ == "__main__":
    main()
