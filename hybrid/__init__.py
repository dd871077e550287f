"""Rigid bodies coupled with plastic, fracturing tetrahedral FEM.

``from hybrid import Simulation`` is the Python API (see :mod:`hybrid.simulation`), with
``sweep`` and ``converge`` for batch studies of a scene on Dask (:mod:`hybrid.app.study`,
:mod:`hybrid.app.converge`); ``hybrid`` on
the command line runs, validates and renders scenes (:mod:`hybrid.app.cli`). Sub-packages:
:mod:`hybrid.coupling` (the coupled step and the events between steps) and :mod:`hybrid.app`
(scene files, building models, output, rendering, command line).
"""
import importlib

# each name and the module it comes from, imported when first asked for: the command line starts
# with this package imported and nothing heavy yet, so a Ctrl-C in its first second stops it
# cleanly (hybrid.app.entry) instead of in the middle of importing numba and scikit-fem
_FROM = {"Simulation": ".simulation", "Body": ".simulation", "SceneError": ".app.scene",
         "InstabilityError": ".coupling.step", "SettingError": ".app.variants", "sweep": ".app.study",
         "converge": ".app.converge"}

__all__ = list(_FROM)


def __getattr__(name):
    if name not in _FROM:
        raise AttributeError(f"module 'hybrid' has no attribute {name!r}")
    value = getattr(importlib.import_module(_FROM[name], __name__), name)
    globals()[name] = value
    return value
