"""The largest stresses and plastic strain each deformable body reached over every step of a run.

Written frames show the fields at the output rate only: an impact that lasts a few steps between
two frames leaves no trace in them (a plate struck between frames showed a peak von Mises of
8.7 kPa). :class:`Peaks` looks at every step instead (through the Simulation's per-step hook), and
the summary reports, per scene body (its fracture fragments included), the largest element von
Mises stress, largest principal stress and equivalent plastic strain, each with the time it was
reached.
"""
import numpy as np
import scipy.sparse as sp

from fem.plasticity import elastic_stress, von_mises
from fem.stress import element_stress

QUANTITIES = ("von_mises", "principal_stress", "plastic_strain")
# the symmetric strain's components (i, j), i <= j, in the rows of the strain operator
_PAIRS = ((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))


class Peaks:
    """Per scene FEM or auto body (by name): ``{quantity: (value, time)}`` for ``von_mises`` (Pa),
    ``principal_stress`` (Pa, the largest principal stress; tension positive) and
    ``plastic_strain`` (accumulated equivalent plastic strain, 0 without a yield stress), the
    largest over every step seen and over the body's elements (element stresses, as the frames'
    cell data; a fragment counts for the body it broke from). ``time`` s is when it was reached."""

    def __init__(self):
        self.bodies = {}
        self._operators = {}    # per FEM model (by id, with the model): its strain operator

    def update(self, model, state):
        """Take in the step that ended in ``state`` (``model``: the coupled model it was taken
        with). Vectorised over elements: von Mises and the mean stress of every element, the
        eigenvalues only of those whose bound ``p + 2/3 von Mises`` on the largest principal
        stress (the deviator's largest eigenvalue is at most 2/3 of von Mises) beats the peak."""
        origin = model.fragment_of if model.fragment_of is not None else range(len(model.names))
        for k, m, s in zip(model.fem_ids, model.fem, state.fem):
            name = model.names[origin[int(k)]]
            peak = self.bodies.setdefault(name, {q: (0.0, 0.0) for q in QUANTITIES})
            vm, mean, stress_of = self._stress(m, s)
            _raise(peak, "von_mises", vm, state.time)
            candidates = np.nonzero(mean + vm * (2.0 / 3.0) > peak["principal_stress"][0])[0]
            if len(candidates):
                _raise(peak, "principal_stress", np.linalg.eigvalsh(stress_of(candidates))[:, -1],
                       state.time)
            if s.tet_peeq is not None:
                _raise(peak, "plastic_strain", s.tet_peeq, state.time)

    def _stress(self, m, s):
        """``(von Mises (t,) Pa, mean stress (t,) Pa, stress of elements (k,) -> (k, 3, 3) Pa)``
        of a body's element stresses, as fem.stress.element_stress gives them. A body without
        per-element rotations goes through a sparse operator from its displacement in its frame
        to its elements' mean strain (one product; the batched 3 x 4 products of element_stress
        took 3 ms a step for 7,680 tets), and von Mises and the mean stress come from the strain's
        six components."""
        if m.frame == "corotated":
            sigma = element_stress(m, s, s.tet_plastic_strain)
            mean = (sigma[:, 0, 0] + sigma[:, 1, 1] + sigma[:, 2, 2]) / 3.0
            return von_mises(sigma), mean, lambda rows: sigma[rows]
        hit = self._operators.get(id(m))
        if hit is None or hit[0] is not m:
            if len(self._operators) > 64:
                self._operators.clear()
            hit = self._operators[id(m)] = (m, strain_operator(m))
        u = (s.x - s.c) @ s.R - m.rest_offsets
        e = (hit[1] @ u.ravel()).reshape(-1, 6)
        if s.tet_plastic_strain is not None:
            rows, cols = [i for i, _ in _PAIRS], [j for _, j in _PAIRS]
            eps_p = s.tet_plastic_strain[:, :, rows, cols]          # (t, q, 6)
            if m.quadrature_count > 1:
                w = m.elements.tet_weights
                e = e - np.einsum("tq,tqc->tc", w, eps_p) / w.sum(axis=1)[:, None]
            else:
                e = e - eps_p[:, 0]
        trace = e[:, 0] + e[:, 1] + e[:, 2]
        deviator = (e[:, :3] - trace[:, None] / 3.0) ** 2
        # sigma_dev = 2 mu e_dev: von Mises is 2 mu sqrt(3/2) |e_dev|
        vm = 2.0 * m.mu * np.sqrt(1.5 * (deviator.sum(axis=1) + 2.0 * (e[:, 3:] ** 2).sum(axis=1)))
        mean = (m.lam + 2.0 * m.mu / 3.0) * trace

        def stress_of(rows):
            eps = np.empty((len(rows), 3, 3))
            for c, (i, j) in enumerate(_PAIRS):
                eps[:, i, j] = eps[:, j, i] = e[rows, c]
            return elastic_stress(eps, 0.0, m.mu, m.lam)
        return vm, mean, stress_of

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


def strain_operator(m):
    """Sparse ``(6 t, 3 n)`` operator from a body's node displacements (flat, node-major, m) to
    its elements' volume-averaged small strain, components ``_PAIRS`` per element:
    ``eps_ij = (grad_j u_i + grad_i u_j) / 2`` with the shape-function gradients averaged over
    the element's quadrature points by their weights."""
    data = m.elements
    w = data.tet_weights
    G = np.einsum("tq,tqbj->tbj", w, data.tet_gradients) / w.sum(axis=1)[:, None, None]
    t, b = data.tet_nodes.shape
    rows, cols, vals = [], [], []
    for k, (i, j) in enumerate(_PAIRS):
        row = np.repeat(6 * np.arange(t) + k, b)
        for a, c in ((i, j), (j, i)):      # u_a's gradient along c, half each
            rows.append(row)
            cols.append((3 * data.tet_nodes + a).ravel())
            vals.append(0.5 * G[:, :, c].ravel())
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(6 * t, 3 * m.node_count))


def _raise(peak, quantity, values, time):
    """Keep the largest of ``values`` as ``quantity``'s peak if it beats the one so far."""
    if len(values) == 0:
        return
    value = float(np.max(values))
    if value > peak[quantity][0]:
        peak[quantity] = (value, float(time))
