"""Rigid bodies coupled with plastic, fracturing tetrahedral FEM.

``from hybrid import Simulation`` is the Python API (see :mod:`hybrid.simulation`), with
``sweep`` and ``converge`` for batch studies of a scene on Dask (:mod:`hybrid.app.study`,
:mod:`hybrid.app.converge`); ``hybrid`` on
the command line runs, validates and renders scenes (:mod:`hybrid.app.cli`). Sub-packages:
:mod:`hybrid.coupling` (the coupled step and the events between steps) and :mod:`hybrid.app`
(scene files, building models, output, rendering, command line).
"""
from .app.scene import SceneError
from .coupling.step import InstabilityError
from .app.converge import converge
from .app.study import sweep
from .simulation import Body, Simulation

__all__ = ["Simulation", "Body", "SceneError", "InstabilityError", "sweep", "converge"]
