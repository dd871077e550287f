"""Shared test helpers: build and step scenes written inline as TOML text."""
import os
import tomllib
from pathlib import Path

# single-threaded BLAS: measured far faster than threaded on the small vectors here
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
import pytest

from hybrid.app.build import build
from hybrid.app.scene import parse_scene
from hybrid.coupling.step import step


class Sim:
    """A scene being stepped in-process: ``sim.advance(seconds)``, ``sim.model``, ``sim.state``."""

    def __init__(self, toml_text, base_dir=Path(".")):
        self.scene = parse_scene(tomllib.loads(toml_text), "<test scene>", Path(base_dir))
        self.model, self.state = build(self.scene)

    def advance(self, seconds, each=None):
        n = int(round(seconds / self.model.dt))
        for _ in range(n):
            self.state = step(self.model, self.state)
            if each is not None:
                each(self)
        return self

    def rigid_index(self, name):
        """Index of a rigid body among the rigid bodies."""
        return int(np.nonzero(self.model.rigid_ids == self.model.names.index(name))[0][0])


@pytest.fixture
def sim():
    return Sim
