"""A process that has stepped contact scenes can fork: multiprocessing's default start method on
Linux (fork) ran a script's Pool for ever once the script had run a contact scene, its children
killed by GNU OpenMP, numba's default threading layer there (rigid.sdf chooses a fork-safe one)."""
import os
import subprocess
import sys

import pytest

CHILD = """
import os, sys
import numba, numpy as np
from rigid.sdf import winding_number
from rigid.shapes import sphere_surface
v, t = sphere_surface(1.0, 0.2)
points = np.random.default_rng(0).uniform(-1.5, 1.5, (4000, 3))
inside = winding_number(points, v, t)              # the parallel kernel, threads started
print(numba.threading_layer(), flush=True)
pid = os.fork()
if pid == 0:                                       # the child runs the kernel again
    again = winding_number(points, v, t)
    os._exit(0 if np.array_equal(again, inside) else 3)
_, status = os.waitpid(pid, 0)
print("child", os.waitstatus_to_exitcode(status), flush=True)
"""


@pytest.mark.skipif(not hasattr(os, "fork"), reason="os.fork is POSIX only")
def test_a_child_forked_after_the_parallel_kernel_ran_runs_it_again():
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_THREADING_LAYER"}
    done = subprocess.run([sys.executable, "-c", CHILD], env=env, capture_output=True, text=True,
                          timeout=240)
    assert done.returncode == 0, done.stderr
    layer, child = done.stdout.split("\n")[:2]
    assert layer in ("workqueue", "tbb")
    assert child == "child 0", done.stderr
