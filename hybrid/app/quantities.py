"""Quantities of interest of a finished run folder, by name, for ``hybrid converge``.

Names (``<body>`` a scene body, ``<region>`` one of its ``anchorK`` / ``loadK`` regions):

- ``<body>.com``: the centre-of-mass trajectory, (x, y, z) at every written frame (m);
- ``<body>.<column>``: one column of ``bodies.csv`` over the frames (``vz``, ``kinetic_energy``, ...);
- ``<body>.<region>.force``: the region's force (fx, fy, fz) over the frames (N; an anchor's
  reaction); ``<body>.<region>.<column>``: one column of ``regions.csv`` (``ux``, ``fz``, ...);
- ``<body>.plastic_strain``: the largest equivalent plastic strain in the body and its fragments
  at the last frame;
- ``cracks``: the number of elements that cracked (``summary.json``);
- any time series above with ``@end``: its value at the last frame only (``beam.load0.uz@end``).

A quantity is an array ``(frames, components)`` with the frame times, or ``(1, 1)`` with no times.
"""
import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .run_files import BODIES_CSV, BODY_COLUMNS, REGION_COLUMNS, REGIONS_CSV, read_run, read_summary

BODY_VALUES = tuple(c for c in BODY_COLUMNS if c not in ("time", "body", "model"))
REGION_VALUES = tuple(c for c in REGION_COLUMNS if c not in ("time", "body", "region"))
# quantities measured from where a body started: their scale is how far it went
POSITIONAL = ("com", "x", "y", "z", "ux", "uy", "uz")


@dataclass(frozen=True)
class Quantity:
    """One quantity of one run. times: (frames,) s, or None for a single value. values:
    (frames, components), or (1, 1) for a single value, in the quantity's unit."""
    times: np.ndarray
    values: np.ndarray


def _body_regions(body):
    return [f"anchor{k}" for k in range(len(body.anchors))] + [f"load{k}" for k in range(len(body.loads))]


def available(scene):
    """Every quantity name the scene's runs can give (for messages and ``--quantity``): the
    plastic strain of bodies with a yield stress only, ``cracks`` only when a body can break."""
    names = ["cracks"] if _breakable(scene) else []
    for body in scene.bodies:
        names += [f"{body.name}.com"]
        if body.model != "rigid" and body.yield_stress is not None:
            names.append(f"{body.name}.plastic_strain")
        names += [f"{body.name}.{c}" for c in BODY_VALUES]
        for region in _body_regions(body):
            names += [f"{body.name}.{region}.force"] + [f"{body.name}.{region}.{c}" for c in REGION_VALUES]
    return names


def defaults(scene):
    """The quantities checked when none is asked for: every moving body's ``com``, every anchor's
    ``force``, the ``plastic_strain`` of bodies with a yield stress, ``cracks`` when a body can
    break."""
    names = []
    for body in scene.bodies:
        if not body.fixed:
            names.append(f"{body.name}.com")
        names += [f"{body.name}.anchor{k}.force" for k in range(len(body.anchors))]
        if body.model != "rigid" and body.yield_stress is not None:
            names.append(f"{body.name}.plastic_strain")
    if _breakable(scene):
        names.append("cracks")
    return names


def _breakable(scene):
    """Whether some body of ``scene`` can crack (a fracture stress or a tearing strain)."""
    return any(b.model != "rigid" and (b.fracture_stress is not None or b.tearing_strain is not None)
               for b in scene.bodies)


def _table(path, key_columns):
    """``{key: {column: array}}`` of a CSV table grouped by the values of ``key_columns``."""
    groups = {}
    if not Path(path).exists():
        return groups
    with open(path, newline="") as stream:
        for row in csv.DictReader(stream):
            key = tuple(row[k] for k in key_columns)
            groups.setdefault(key, []).append(row)
    return {key: {c: np.array([_number(r[c]) for r in rows]) for c in rows[0]
                  if c not in key_columns} for key, rows in groups.items()}


def _number(text):
    try:
        return float(text)
    except ValueError:
        return np.nan


class RunQuantities:
    """Reads quantities of one run folder on demand (each table once)."""

    def __init__(self, folder, scene):
        self.folder, self.scene = Path(folder), scene
        self._bodies = self._regions = None

    def get(self, name):
        """The :class:`Quantity` called ``name`` (see the module docs); KeyError if the run has
        no such body, region or column."""
        if name.endswith("@end"):
            series = self.get(name[:-4])
            return Quantity(None, series.values[-1:])
        if name == "cracks":
            return Quantity(None, np.array([[float(read_summary(self.folder)["fracture"]["cracks"])]]))
        # the longest body name the quantity begins with (bodies "ball" and "ball.v2")
        body = max((b.name for b in self.scene.bodies if name.startswith(b.name + ".")), key=len, default=None)
        if body is None:
            raise KeyError(name)
        rest = name[len(body) + 1:]
        if rest == "plastic_strain":
            return Quantity(None, np.array([[self._largest_plastic_strain(body)]]))
        if "." in rest:
            region, column = rest.split(".", 1)
            columns = ("fx", "fy", "fz") if column == "force" else (column,)
            return self._series(self._region_table().get((body, region)), columns, name)
        columns = ("x", "y", "z") if rest == "com" else (rest,)
        return self._series(self._body_table().get((body,)), columns, name)

    def _body_table(self):
        if self._bodies is None:
            self._bodies = _table(self.folder / BODIES_CSV, ("body",))
        return self._bodies

    def _region_table(self):
        if self._regions is None:
            self._regions = _table(self.folder / REGIONS_CSV, ("body", "region"))
        return self._regions

    @staticmethod
    def _series(table, columns, name):
        if table is None or any(c not in table for c in columns):
            raise KeyError(name)
        return Quantity(table["time"], np.column_stack([table[c] for c in columns]))

    def _largest_plastic_strain(self, body):
        """Largest plastic strain of the body and its fragments in the run's last frame."""
        import meshio
        index = [b.name for b in self.scene.bodies].index(body)
        _, frames, _ = read_run(self.folder)
        mesh = meshio.read(frames[-1])
        origin = np.concatenate(mesh.cell_data["fragment_of"]).ravel()
        strain = np.concatenate(mesh.cell_data["plastic_strain"]).ravel()
        mine = strain[origin == index]
        return float(mine.max()) if mine.size else 0.0


def distance(a, b):
    """RMS over frames of the Euclidean distance between two quantities' values (same shape)."""
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def common_times(quantities):
    """Frame times every run of a ladder covers: the coarsest run's times up to the earliest end."""
    times = [q.times for q in quantities]
    if times[0] is None:
        return None
    end = min(t[-1] for t in times)
    return times[0][times[0] <= end + 1e-12]


def resampled(quantity, times):
    """The quantity's values at ``times`` (linear between frames); unchanged without times."""
    if times is None:
        return quantity.values
    return np.column_stack([np.interp(times, quantity.times, quantity.values[:, c])
                            for c in range(quantity.values.shape[1])])


def positional(name):
    """Whether quantity ``name`` is a position or displacement (its error is judged against how
    far it moved)."""
    return name.removesuffix("@end").rsplit(".", 1)[-1] in POSITIONAL


def scale(name, reference):
    """The size the error of quantity ``name`` is judged against: how far it moved from its first
    value for positions and displacements (``reference`` a whole series of them), its largest
    magnitude otherwise."""
    if positional(name) and len(reference) > 1:
        return float(np.max(np.linalg.norm(reference - reference[0], axis=1)))
    return float(np.max(np.linalg.norm(reference, axis=1)))
