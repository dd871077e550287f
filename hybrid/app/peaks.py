"""The largest stresses and plastic strain each deformable body reached over every step of a run.

Written frames show the fields at the output rate only: an impact that lasts a few steps between
two frames leaves no trace in them (a plate struck between frames showed a peak von Mises of
8.7 kPa). :class:`Peaks` looks at every step instead (through the Simulation's per-step hook), and
the summary reports, per scene body (its fracture fragments included), the largest element von
Mises stress, largest principal stress and equivalent plastic strain, each with the time it was
reached; and per body (fragments by their own names) the largest elastic strain, which the
``models`` section and the run log's ``model = "rigid"`` hints read.
"""
import numba as nb
import numpy as np

from fem.mesh import tet_signed_volumes
from fem.plasticity import elastic_stress
from fem.stress import principal_stress_max
from fem.rotations import element_rotations

QUANTITIES = ("von_mises", "principal_stress", "plastic_strain")
# the symmetric strain's components (i, j), i <= j, in the rows of the strain operator
_PAIRS = ((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))
_NO_PLASTIC = np.zeros((1, 6))
# an element can only be turned inside out when its displacement gradient is of order one: its
# corners' volumes are looked at in steps whose largest strain, turn or plastic strain passes this
INVERSION_WATCH = 0.3


class Peaks:
    """Per scene FEM or auto body (by name): ``{quantity: (value, time)}`` for ``von_mises`` (Pa),
    ``principal_stress`` (Pa, the largest principal stress; tension positive) and
    ``plastic_strain`` (accumulated equivalent plastic strain, 0 without a yield stress), the
    largest over every step seen and over the body's elements (element stresses, as the frames'
    cell data; a fragment counts for the body it broke from). ``time`` s is when it was reached.
    A body with a yield stress also has ``first_yield``: the first step that ended with an element
    flowing, its time and its largest element von Mises stress (the yield stress, to the return
    mapping's tolerance, for linear elements; at or below it for quadratic ones, whose element
    stress is the mean of quadrature points that yield one by one; (0, 0) while none has). A body
    some of whose elements were turned inside out has ``inverted_elements``: the most at once,
    and when."""

    def __init__(self):
        self.bodies = {}
        # warnings found in the last update, for the run log (the Simulation takes them)
        self.said = []
        # per body stepped as FEM, by its own name: the largest element strain (elastic, Frobenius
        # norm) over every step, and the largest turn of an element in the body's frame (rad)
        self.strains, self.turns = {}, {}

    def update(self, model, state):
        """Take in the step that ended in ``state`` (``model``: the coupled model it was taken
        with). Vectorised over elements: von Mises and the mean stress of every element, the
        eigenvalues only of those whose bound ``p + 2/3 von Mises`` on the largest principal
        stress (the deviator's largest eigenvalue is at most 2/3 of von Mises) beats the peak."""
        origin = model.fragment_of if model.fragment_of is not None else range(len(model.names))
        for k, m, s in zip(model.fem_ids, model.fem, state.fem):
            name = model.names[origin[int(k)]]
            peak = self.bodies.setdefault(name, {q: (0.0, 0.0) for q in QUANTITIES})
            e, vm, mean, turn = element_strains(m, s)
            _raise(peak, "von_mises", vm, state.time)
            own = model.names[int(k)]
            strain, turned = largest_strain(m, vm, mean), float(turn.max(initial=0.0))
            self.strains[own] = max(self.strains.get(own, 0.0), strain)
            self.turns[own] = max(self.turns.get(own, 0.0), turned)
            flowed = float(s.tet_peeq.max(initial=0.0)) if s.tet_peeq is not None else 0.0
            if max(strain, turned, flowed) > INVERSION_WATCH:
                self._inverted(peak, name, m, s, strain, state.time)
            candidates = np.nonzero(mean + vm * (2.0 / 3.0) > peak["principal_stress"][0])[0]
            if len(candidates):
                stress = elastic_stress(strain_tensors(e[candidates]), 0.0, m.mu, m.lam)
                _raise(peak, "principal_stress", np.linalg.eigvalsh(stress)[:, -1], state.time)
            if s.tet_peeq is not None:
                _raise(peak, "plastic_strain", s.tet_peeq, state.time)
                # the first step that ends with an element flowing, and its largest von Mises
                if peak.setdefault("first_yield", (0.0, 0.0))[1] == 0.0 and s.tet_yielded.any():
                    peak["first_yield"] = (float(vm.max(initial=0.0)), float(state.time))

    def _inverted(self, peak, name, m, s, strain, time):
        """Count the elements of body ``m`` (state ``s``; of scene body ``name``) turned inside
        out (their corners' volume at or below zero) as the peak ``inverted_elements``; the first
        time a body has any, say so in :attr:`said`."""
        count = int(np.count_nonzero(tet_signed_volumes(s.x, m.elements.tet_nodes) <= 0.0))
        if count == 0:
            return
        first = peak.setdefault("inverted_elements", (0.0, 0.0))[0] == 0.0
        _raise(peak, "inverted_elements", np.array([float(count)]), time)
        if first:
            wave = float(np.sqrt(m.young / m.density))
            self.said.append(
                f"warning: t = {time:.6g} s: '{name}' has {count} of its {len(m.elements.tet_nodes)} "
                f"elements turned inside out (largest strain {strain:.2g}): strained far beyond "
                f"linear elasticity, it no longer keeps its shape, and bodies pressed into it may "
                f"pass through it. Impacts near its wave speed sqrt(young / density) = {wave:.3g} m/s "
                f"do this: make it stiffer or its impacts slower (docs/limits.md)")

    def inverted(self):
        """The scene bodies some of whose elements were turned inside out."""
        return {name for name, peak in self.bodies.items() if peak.get("inverted_elements", (0.0,))[0] > 0}

    def as_dict(self):
        """The summary's ``peaks`` section: ``{body: {quantity: {"value": v, "time": t}}}``."""
        return {name: {q: {"value": float(v), "time": float(t)} for q, (v, t) in peak.items()}
                for name, peak in self.bodies.items()}

    def snapshot(self):
        """Plain data a checkpoint keeps (see :meth:`restore`)."""
        return {"peaks": {name: {q: [float(v), float(t)] for q, (v, t) in peak.items()}
                          for name, peak in self.bodies.items()},
                "strains": dict(self.strains), "turns": dict(self.turns)}

    def restore(self, snapshot):
        """Continue from a :meth:`snapshot` (or one of the peaks alone, as checkpoints without
        the strains held them: the strains, and turns, then start from those steps on)."""
        peaks, strains, turns = snapshot, {}, {}
        if set(snapshot) in ({"peaks", "strains"}, {"peaks", "strains", "turns"}) \
                and isinstance(snapshot["strains"], dict) \
                and all(isinstance(v, (int, float)) for v in snapshot["strains"].values()):
            peaks, strains, turns = snapshot["peaks"], snapshot["strains"], snapshot.get("turns", {})
        self.bodies = {name: {q: (float(v), float(t)) for q, (v, t) in peak.items()}
                       for name, peak in peaks.items()}
        self.strains = {name: float(v) for name, v in strains.items()}
        self.turns = {name: float(v) for name, v in turns.items()}


def largest_strain(m, von_mises, mean):
    """The largest elastic strain (-, Frobenius norm) of body ``m``'s elements, from their von
    Mises and mean stresses (:func:`element_strains`): an isotropic linear-elastic strain's
    deviator has norm ``von_mises / (sqrt(6) mu)`` and its trace is ``mean / K`` (bulk modulus
    ``K = lam + 2 mu / 3``), so the square of its norm is their sum of squares with the trace's
    over 3."""
    if len(von_mises) == 0:
        return 0.0
    bulk = m.lam + 2.0 * m.mu / 3.0
    squared = (von_mises / (np.sqrt(6.0) * m.mu)) ** 2 + (mean / bulk) ** 2 / 3.0
    return float(np.sqrt(squared.max()))


def element_strains(m, s):
    """``(e (t, 6), von Mises (t,) Pa, mean stress (t,) Pa, turn (t,) rad)`` of a body's elements
    (model ``m``, state ``s``): each element's mean elastic strain (components ``_PAIRS``; the
    plastic strain taken off) and the turn its displacement gradient holds (the norm of its skew
    part, an angle in the small-angle sense: linear elasticity takes it for no strain), whose stress is fem.stress.element_stress's (to round-off), in one compiled pass
    over the elements (the batched products of element_stress took 3 ms a step for 7,680 tets in
    the floating frame, 5 ms for 9,600 corotated ones)."""
    G = m.cache.mean_gradients
    if G is None:
        G = m.cache.mean_gradients = mean_gradients(m)
    eps_p = _NO_PLASTIC
    if s.tet_plastic_strain is not None:
        rows, cols = [i for i, _ in _PAIRS], [j for _, j in _PAIRS]
        eps_p = s.tet_plastic_strain[:, :, rows, cols]          # (t, q, 6)
        if m.quadrature_count > 1:
            w = m.elements.tet_weights
            eps_p = np.einsum("tq,tqc->tc", w, eps_p) / w.sum(axis=1)[:, None]
        else:
            eps_p = eps_p[:, 0]
    eps_p = np.ascontiguousarray(eps_p)
    if m.frame == "corotated":
        return _element_strains_turned(s.x, element_rotations(m, s.x), m.rest_points,
                                       m.elements.tet_nodes, G, eps_p, m.mu, m.lam)
    return _element_strains(s.x, s.c, s.R, m.rest_offsets, m.elements.tet_nodes, G, eps_p, m.mu, m.lam)


def principal_stress_of_strains(e, mu, lam):
    """Largest principal stress ``(k,)`` (Pa) of the isotropic elastic stress (Lame ``mu``,
    ``lam``) of strain rows ``e`` ``(k, 6)`` (:func:`element_strains`): what a frame's
    ``principal_stress`` field holds, computed by the run's writer from the rows (half the bytes
    of the stress tensors, and none of their products on the stepping thread)."""
    return principal_stress_max(elastic_stress(strain_tensors(e), 0.0, mu, lam))


def strain_tensors(e):
    """The symmetric strains ``(k, 3, 3)`` of rows ``e`` ``(k, 6)`` of :func:`element_strains`."""
    eps = np.empty((len(e), 3, 3))
    for c, (i, j) in enumerate(_PAIRS):
        eps[:, i, j] = eps[:, j, i] = e[:, c]
    return eps


def mean_gradients(m):
    """``(t, b, 3)`` gradients (1/m) of each element's scalar shape functions averaged over its
    quadrature points by their weights: the element's mean strain is
    ``(grad_j u_i + grad_i u_j) / 2`` with them."""
    w = m.elements.tet_weights
    G = np.einsum("tq,tqbj->tbj", w, m.elements.tet_gradients) / w.sum(axis=1)[:, None, None]
    return np.ascontiguousarray(G)


@nb.njit(cache=True)
def _element_strains(x, c, R, rest_offsets, tet_nodes, G, eps_p, mu, lam):
    """Per element its mean elastic strain ``(t, 6)`` (components _PAIRS, less ``eps_p`` (t, 6)
    or (1, 6) zeros), von Mises stress ``(t,)`` Pa and mean stress ``(t,)`` Pa, of node positions
    ``x`` (n, 3) m in the body's frame (centre ``c``, rotation ``R``): the nodes' displacements
    in that frame once each, then one pass over the elements (taking each element's nodes into
    the frame again made the pass 1.5x as long). ``sigma_dev = 2 mu e_dev``, so von Mises is
    ``2 mu sqrt(3/2) |e_dev|``."""
    t, b = tet_nodes.shape
    u = np.empty((len(x), 3))
    for node in range(len(x)):
        # u = (x - c) R - X: the displacement in the body's frame
        d0, d1, d2 = x[node, 0] - c[0], x[node, 1] - c[1], x[node, 2] - c[2]
        for i in range(3):
            u[node, i] = d0 * R[0, i] + d1 * R[1, i] + d2 * R[2, i] - rest_offsets[node, i]
    e, vm, mean, turn = np.zeros((t, 6)), np.empty(t), np.empty(t), np.empty(t)
    grad = np.empty((3, 3))
    for k in range(t):
        grad[:] = 0.0
        for a in range(b):
            node = tet_nodes[k, a]
            for i in range(3):
                for j in range(3):
                    grad[i, j] += u[node, i] * G[k, a, j]
        _strain_row(k, grad, eps_p, mu, lam, e, vm, mean, turn)
    return e, vm, mean, turn


@nb.njit(cache=True)
def _element_strains_turned(x, tet_R, rest_points, tet_nodes, G, eps_p, mu, lam):
    """:func:`_element_strains` of a corotated body: each element's displacement measured in its
    own frame, ``R_e^T x_e - X_e`` (element rotations ``tet_R`` (t, 3, 3)), positions taken about
    the element's mean (its translation strains nothing; far from the origin it keeps the
    digits), as fem.stress._corotated_displacement forms it."""
    t, b = tet_nodes.shape
    e, vm, mean, turn = np.zeros((t, 6)), np.empty(t), np.empty(t), np.empty(t)
    grad = np.empty((3, 3))
    for k in range(t):
        grad[:] = 0.0
        xm0 = xm1 = xm2 = Xm0 = Xm1 = Xm2 = 0.0
        for a in range(b):
            node = tet_nodes[k, a]
            xm0, xm1, xm2 = xm0 + x[node, 0], xm1 + x[node, 1], xm2 + x[node, 2]
            Xm0, Xm1, Xm2 = Xm0 + rest_points[node, 0], Xm1 + rest_points[node, 1], Xm2 + rest_points[node, 2]
        xm0, xm1, xm2, Xm0, Xm1, Xm2 = xm0 / b, xm1 / b, xm2 / b, Xm0 / b, Xm1 / b, Xm2 / b
        for a in range(b):
            node = tet_nodes[k, a]
            d0, d1, d2 = x[node, 0] - xm0, x[node, 1] - xm1, x[node, 2] - xm2
            D0, D1, D2 = rest_points[node, 0] - Xm0, rest_points[node, 1] - Xm1, rest_points[node, 2] - Xm2
            for i in range(3):
                u = d0 * tet_R[k, 0, i] + d1 * tet_R[k, 1, i] + d2 * tet_R[k, 2, i] \
                    - (D0 if i == 0 else D1 if i == 1 else D2)
                for j in range(3):
                    grad[i, j] += u * G[k, a, j]
        _strain_row(k, grad, eps_p, mu, lam, e, vm, mean, turn)
    return e, vm, mean, turn


@nb.njit(cache=True, inline="always")
def _strain_row(k, grad, eps_p, mu, lam, e, vm, mean, turn):
    """Element k's row of :func:`_element_strains` from its mean displacement gradient ``grad``."""
    turn[k] = 0.5 * np.sqrt((grad[2, 1] - grad[1, 2]) ** 2 + (grad[0, 2] - grad[2, 0]) ** 2
                            + (grad[1, 0] - grad[0, 1]) ** 2)
    p = k if eps_p.shape[0] == len(e) else 0
    e[k, 0] = grad[0, 0] - eps_p[p, 0]
    e[k, 1] = grad[1, 1] - eps_p[p, 1]
    e[k, 2] = grad[2, 2] - eps_p[p, 2]
    e[k, 3] = 0.5 * (grad[1, 2] + grad[2, 1]) - eps_p[p, 3]
    e[k, 4] = 0.5 * (grad[0, 2] + grad[2, 0]) - eps_p[p, 4]
    e[k, 5] = 0.5 * (grad[0, 1] + grad[1, 0]) - eps_p[p, 5]
    trace = e[k, 0] + e[k, 1] + e[k, 2]
    dev = 0.0
    for i in range(3):
        dev += (e[k, i] - trace / 3.0) ** 2 + 2.0 * e[k, 3 + i] ** 2
    vm[k] = 2.0 * mu * np.sqrt(1.5 * dev)
    mean[k] = (lam + 2.0 * mu / 3.0) * trace


def _raise(peak, quantity, values, time):
    """Keep the largest of ``values`` as ``quantity``'s peak if it beats the one so far."""
    if len(values) == 0:
        return
    value = float(np.max(values))
    if value > peak[quantity][0]:
        peak[quantity] = (value, float(time))
