"""Exact contact response of a deformable body: the Delassus block of its touched nodes.

An impulse ``j`` on the nodes of a body changes its end-of-step velocities by ``A^-1 j`` (A the
implicit system matrix), so the velocity of node ``l`` per unit impulse on node ``i`` is the
3x3 block ``W[l, i]`` of ``A^-1``. The contact solver uses these blocks, which makes its impulses
exactly the ones the body can answer: a soft ball gives locally, a stiff slab on the ground
holds a box still, and nothing is created or lost between solver and body.

In the body frame of a floating body (and for an anchored body, whose frame is the world) A is
constant, so the columns ``A^-1 e`` of each node are solved once (one batched back-substitution
with the prefactored matrix) and cached until the model changes; a corotated body uses its rest
system in its best-fit frame, an approximation the coupling rounds correct.
"""
import numpy as np

from .dynamics import system_factorisation

# memory the cached columns of one model may take (each touched node keeps 3 x 3n floats)
MAX_CACHE_BYTES = 400e6


class _ColumnCache:
    def __init__(self, dt):
        self.dt = dt
        self.columns = {}          # node -> (3n, 3) response to unit impulses at the node (body frame)
        self.last_nodes = None     # the last touched set and its body-frame block (resting contact
        self.last_block = None     # touches the same nodes step after step)


def _cache(model, dt):
    cache = getattr(model, "_contact_columns", None)
    if cache is None or cache.dt != dt:
        cache = _ColumnCache(dt)
        object.__setattr__(model, "_contact_columns", cache)
    return cache


def _solve_columns(model, dt, nodes):
    """A^-1 columns (3n, 3 len(nodes)) for unit impulses at ``nodes`` (body frame)."""
    n3 = 3 * model.node_count
    dofs = (3 * np.asarray(nodes)[:, None] + np.arange(3)).ravel()
    out = np.zeros((n3, len(dofs)))
    fact = system_factorisation(model, dt)
    if model.anchored:
        free_index = -np.ones(n3, dtype=np.int64)
        free_index[model.free_dofs] = np.arange(len(model.free_dofs))
        cols = np.nonzero(free_index[dofs] >= 0)[0]       # held DOFs do not respond
        rhs = np.zeros((len(model.free_dofs), len(dofs)))
        rhs[free_index[dofs[cols]], cols] = 1.0
        out[model.free_dofs] = fact.solve(rhs).reshape(len(model.free_dofs), -1)
    else:
        rhs = np.zeros((n3, len(dofs)))
        rhs[dofs, np.arange(len(dofs))] = 1.0
        out[:] = fact.solve(rhs).reshape(n3, -1)
    return out


def contact_set(model, dt, nodes):
    """The nodes to give the solver: ``nodes`` (touched now), or the last set when it still holds
    them and is not much larger. Resting contact flickers a few nodes in and out of the margin;
    keeping the set lets the block be reused instead of rebuilt (the extra nodes carry no contact).
    """
    cache = _cache(model, dt)
    nodes = np.unique(np.asarray(nodes, dtype=np.int64))
    last = cache.last_nodes
    if last is not None:
        union = np.union1d(last, nodes)
        if len(union) <= 1.5 * len(nodes) + 8:
            return union if len(union) > len(last) else last
    return nodes


def delassus_block(model, dt, nodes, R):
    """World-frame blocks ``W`` (k, k, 3, 3): block [l, i] is the velocity of node l per unit
    impulse on node i, for the k ``nodes``; ``R`` (3, 3) is the body's solve frame."""
    cache = _cache(model, dt)
    nodes = np.asarray(nodes, dtype=np.int64)
    k = len(nodes)
    if cache.last_nodes is not None and np.array_equal(cache.last_nodes, nodes):
        W_body = cache.last_block
    else:
        missing = [int(i) for i in nodes if int(i) not in cache.columns]
        if missing:
            per_node = 9 * model.node_count * 8
            if (len(cache.columns) + len(missing)) * per_node > MAX_CACHE_BYTES:
                cache.columns.clear()
                missing = [int(i) for i in nodes]
            cols = _solve_columns(model, dt, missing)
            for j, node in enumerate(missing):
                cache.columns[node] = cols[:, 3 * j:3 * j + 3]
        rows = (3 * nodes[:, None] + np.arange(3)).ravel()
        # (k, 3, k, 3) -> (k, k, 3, 3): block [l, i] = velocity of node l per impulse on node i
        W_body = np.stack([cache.columns[int(i)][rows] for i in nodes], axis=1)
        W_body = np.ascontiguousarray(W_body.reshape(k, 3, k, 3).transpose(0, 2, 1, 3))
        cache.last_nodes, cache.last_block = nodes.copy(), W_body
    # A_world^-1 = R A_body^-1 R^T, node block by node block
    if np.array_equal(R, np.eye(3)):
        return W_body
    # R B R^T for every 3x3 block B, as two large matrix products
    WR = (W_body.reshape(-1, 3) @ R.T).reshape(k, k, 3, 3)                  # B R^T
    return np.ascontiguousarray(                                             # R (B R^T)
        (WR.transpose(0, 1, 3, 2).reshape(-1, 3) @ R.T).reshape(k, k, 3, 3).transpose(0, 1, 3, 2))
