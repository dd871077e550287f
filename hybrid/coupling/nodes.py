"""The deformable bodies' surface nodes stacked into one index space, as the contact stages see
them: stacked node k is node ``local[k]`` of FEM body ``body[k]``."""
from dataclasses import dataclass

import numba as nb
import numpy as np


@dataclass
class SurfaceNodes:
    """Stacked surface nodes of the FEM bodies for one step.

    per_body: list of (s_j,) each body's surface nodes (sorted, body-local indices).
    body (k,): FEM body of each stacked node; local (k,): its index within that body;
    offset (bodies + 1,): first stacked node of each body.
    x (k, 3) m: positions at the step's start. v (k, 3) m/s: how fast each node moves over the
    step in progress (see :func:`moving`); the coupling rounds update it.
    """
    per_body: list
    body: np.ndarray
    local: np.ndarray
    offset: np.ndarray
    x: np.ndarray
    v: np.ndarray

    @classmethod
    def of(cls, model, state, predicted, h):
        """The surface nodes of every FEM body of ``model``, with the predicted steps' velocities."""
        nodes = [m.surface_nodes for m in model.fem]
        offset = np.concatenate([[0], np.cumsum([len(n) for n in nodes])]).astype(np.int64)
        x, v = np.empty((offset[-1], 3)), np.empty((offset[-1], 3))
        for j, (p, s, n) in enumerate(zip(predicted, state.fem, nodes)):
            # (hybrid.coupling.kernels.stack_moving: :func:`moving` written into its rows)
            stack_moving(s.x, p.x_base, p.v, float(p.x_rate), n, float(h), x, v, offset[j])
        return cls(per_body=nodes,
                   body=np.repeat(np.arange(len(nodes)), np.diff(offset)),
                   local=np.concatenate(nodes) if len(nodes) != 1 else nodes[0],
                   offset=offset, x=x, v=v)

    @property
    def count(self):
        """Number of stacked surface nodes (k)."""
        return len(self.local)

    def stacked(self, j, local):
        """Stacked indices of body ``j``'s surface nodes ``local`` (body-local, each a surface node)."""
        return self.offset[j] + np.searchsorted(self.per_body[j], local)


def moving(step, state, nodes, h):
    """Mean velocity ``(k, 3)`` m/s of ``nodes`` over a deformable body's step in progress: it
    ends at x_base + x_rate v (backward Euler: at x + h v; Newmark: at x + h (v_t + v) / 2).
    Contacts ask that no gap closes by the step's end, so the solver works with these velocities
    and a response scaled by x_rate / h."""
    return (step.x_base[nodes] - state.x[nodes] + step.x_rate * step.v[nodes]) / h


@nb.njit(cache=True)
def stack_moving(x, x_base, v, x_rate, nodes, h, out_x, out_v, start):
    """Write the positions ``x[nodes]`` and the mean velocities over the step in progress
    ``(x_base[nodes] - x[nodes] + x_rate v[nodes]) / h`` (hybrid.coupling.nodes.moving) of one
    body's ``nodes`` (k,) into rows ``start .. start + k - 1`` of ``out_x`` and ``out_v``
    (stacked surface nodes, (s, 3)): one pass instead of two gathers, a product and a concatenate."""
    for k in range(len(nodes)):
        i = nodes[k]
        for a in range(3):
            out_x[start + k, a] = x[i, a]
            out_v[start + k, a] = (x_base[i, a] - x[i, a] + x_rate * v[i, a]) / h


def element_size(model):
    """Edge (m) of a regular tet of FEM ``model``'s mean element volume, kept in its cache
    (``model.cache.element_size``): the contact detection asks every step."""
    if model.cache.element_size is None:
        model.cache.element_size = float(np.cbrt(6.0 * np.sqrt(2.0) * model.elements.tet_volume.mean()))
    return model.cache.element_size


@nb.njit(cache=True)
def row_norms(a, scale):
    """``scale`` times the Euclidean norm of each row of ``a`` (k, 3): ``np.linalg.norm(a, axis=1)
    * scale`` in one pass."""
    out = np.empty(len(a))
    for k in range(len(a)):
        out[k] = np.sqrt(a[k, 0] * a[k, 0] + a[k, 1] * a[k, 1] + a[k, 2] * a[k, 2]) * scale
    return out
