"""The deformable bodies' surface nodes stacked into one index space, as the contact stages see
them: stacked node k is node ``local[k]`` of FEM body ``body[k]``."""
from dataclasses import dataclass

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
        return cls(per_body=nodes,
                   body=np.concatenate([np.full(len(n), j) for j, n in enumerate(nodes)]),
                   local=np.concatenate(nodes),
                   offset=np.concatenate([[0], np.cumsum([len(n) for n in nodes])]).astype(np.int64),
                   x=np.concatenate([s.x[n] for s, n in zip(state.fem, nodes)]),
                   v=np.concatenate([moving(p, s, n, h) for p, s, n in zip(predicted, state.fem, nodes)]))

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
