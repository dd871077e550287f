"""Shared test helpers: step scenes written inline as TOML text through the Simulation API."""
import os
import tomllib
from pathlib import Path

# single-threaded BLAS: measured far faster than threaded on the small vectors here
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import signal

import numpy as np
import pytest

# the tests that stop runs with Ctrl-C stand for a user at a terminal: a suite started in the
# background by a shell without job control (`(cmd &)`) inherits SIGINT ignored, and so would the
# runs it starts (they then ran to their end); a handler of our own is reset to the default at
# exec, so the runs start as a terminal starts them
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

from hybrid import Simulation
from hybrid.app.scene import parse_scene


class Sim(Simulation):
    """A scene written as TOML text, stepped in-process: ``sim.advance(seconds)``, ``sim.model``,
    ``sim.state`` (the product's own step loop, events included)."""

    def __init__(self, toml_text, base_dir=Path("."), keep_before_events=False):
        super().__init__(parse_scene(tomllib.loads(toml_text), "<test scene>", Path(base_dir)))
        self.keep_before_events = keep_before_events
        self.before_events = None

    def _stepped(self, model, state):
        # with keep_before_events, the model and state of the last step before its events
        if self.keep_before_events:
            self.before_events = (model, state)

    def advance(self, seconds, each=None):
        n = int(round(seconds / self.model.dt))
        for _ in range(n):
            self.step()
            if each is not None:
                each(self)
        return self

    def rigid_index(self, name):
        """Index of a rigid body among the rigid bodies."""
        return int(np.nonzero(self.model.rigid_ids == self.model.names.index(name))[0][0])


@pytest.fixture
def sim():
    return Sim
