"""The largest stresses and plastic strain each deformable body reached over every step of a run.

Written frames show the fields at the output rate only: an impact that lasts a few steps between
two frames leaves no trace in them (a plate struck between frames showed a peak von Mises of
8.7 kPa). :class:`Peaks` looks at every step instead (through the Simulation's per-step hook), and
the summary reports, per scene body (its fracture fragments included), the largest element von
Mises stress, largest principal stress and equivalent plastic strain, each with the time it was
reached.
"""
import numpy as np

from fem.plasticity import von_mises
from fem.stress import element_stress

QUANTITIES = ("von_mises", "principal_stress", "plastic_strain")


class Peaks:
    """Per scene FEM or auto body (by name): ``{quantity: (value, time)}`` for ``von_mises`` (Pa),
    ``principal_stress`` (Pa, the largest principal stress; tension positive) and
    ``plastic_strain`` (accumulated equivalent plastic strain, 0 without a yield stress), the
    largest over every step seen and over the body's elements (element stresses, as the frames'
    cell data; a fragment counts for the body it broke from). ``time`` s is when it was reached."""

    def __init__(self):
        self.bodies = {}

    def update(self, model, state):
        """Take in the step that ended in ``state`` (``model``: the coupled model it was taken
        with). Vectorised over elements: one element stress per body, eigenvalues only for the
        elements whose bound ``p + 2/3 von Mises`` on the largest principal stress beats the peak
        so far."""
        origin = model.fragment_of if model.fragment_of is not None else range(len(model.names))
        for k, m, s in zip(model.fem_ids, model.fem, state.fem):
            name = model.names[origin[int(k)]]
            peak = self.bodies.setdefault(name, {q: (0.0, 0.0) for q in QUANTITIES})
            sigma = element_stress(m, s, s.tet_plastic_strain)
            vm = von_mises(sigma)
            _raise(peak, "von_mises", vm, state.time)
            # the deviator's largest eigenvalue is at most 2/3 of von Mises: only elements whose
            # bound exceeds the peak need their eigenvalues
            bound = np.trace(sigma, axis1=1, axis2=2) / 3.0 + vm * (2.0 / 3.0)
            candidates = bound > peak["principal_stress"][0]
            if candidates.any():
                _raise(peak, "principal_stress", np.linalg.eigvalsh(sigma[candidates])[:, -1],
                       state.time)
            if s.tet_peeq is not None:
                _raise(peak, "plastic_strain", s.tet_peeq, state.time)

    def as_dict(self):
        """The summary's ``peaks`` section: ``{body: {quantity: {"value": v, "time": t}}}``."""
        return {name: {q: {"value": float(v), "time": float(t)} for q, (v, t) in peak.items()}
                for name, peak in self.bodies.items()}

    def snapshot(self):
        """Plain data a checkpoint keeps (see :meth:`restore`)."""
        return {name: {q: [float(v), float(t)] for q, (v, t) in peak.items()}
                for name, peak in self.bodies.items()}

    def restore(self, snapshot):
        """Continue from a :meth:`snapshot`."""
        self.bodies = {name: {q: (float(v), float(t)) for q, (v, t) in peak.items()}
                       for name, peak in snapshot.items()}


def _raise(peak, quantity, values, time):
    """Keep the largest of ``values`` as ``quantity``'s peak if it beats the one so far."""
    if len(values) == 0:
        return
    value = float(np.max(values))
    if value > peak[quantity][0]:
        peak[quantity] = (value, float(time))
