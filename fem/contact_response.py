"""Exact contact response of a deformable body: the Delassus block of its touched nodes.

An impulse ``j`` on the nodes of a body changes its end-of-step velocities by ``A^-1 j`` (A the
implicit system matrix), so the velocity of node ``l`` per unit impulse on node ``i`` is the
3x3 block ``W[l, i]`` of ``A^-1``. The contact solver uses these blocks, which makes its impulses
exactly the ones the body can answer: a soft ball gives locally, a stiff slab on the ground
holds a box still, and nothing is created or lost between solver and body.

In the body frame of a floating body (and for an anchored body, whose frame is the world) A is
constant, so the columns ``A^-1 e`` of each node are solved once (one batched back-substitution
with the prefactored matrix) and kept in the model's cache (:class:`ResponseCache`,
``model.cache.response``); a corotated body uses its rest system in its best-fit frame, an
approximation the coupling rounds correct. The node set a body keeps across steps while contact
rests is step history: the caller keeps it and passes it back (:func:`contact_set`).
"""
import time
from dataclasses import replace

import numpy as np

from .dynamics import apply_impulse, system_factorisation
from .step_kernels import add_free_response, block_rows

# memory the response columns of one model may keep for applying impulses as a product (each node
# keeps 3 x 3n floats); nodes beyond it apply their impulses by back-substitution instead
MAX_COLUMN_BYTES = 400e6
# memory the Delassus blocks between all nodes a model has met may take (9 k^2 floats for k nodes);
# beyond it only the blocks of the current contact set are kept
MAX_BLOCK_BYTES = 400e6
# memory one batch of response columns may take while it is solved (right-hand sides and answers)
BATCH_BYTES = 64e6
# a long column solve reports its progress every this many seconds
REPORT_EVERY = 5.0
# relative size below which a Delassus block between two nodes is left out (see sparse_rows): in a
# soft or large body the response to an impulse decays fast with distance within one step, and
# the solver's sweeps only visit the blocks kept
DROP_TOL = 1e-7


class ResponseCache:
    """What one model keeps of its contact response for a time step ``dt`` (``model.cache.response``).

    ``known`` are the nodes it has met (in order) and ``W`` their dense Delassus matrix
    ``(3 len(known), 3 len(known))``, block [l, i] the velocity of known node l per unit impulse
    on known node i (body frame); it grows by the columns of new nodes only, so a contact patch
    that creeps by a few nodes costs a few solves. ``columns`` keeps full response columns
    ``(3n, 3)`` per node while they fit in MAX_COLUMN_BYTES. ``block`` is the last
    :func:`delassus_block` asked for, ``(nodes, scale, rows)``, and ``block_columns`` the last
    nodes' columns side by side on the body's free DOFs, ``(nodes, (f, 3k))`` (the prescribed DOFs'
    rows are zero; :func:`impulse_response`): resting contact asks for the same nodes step after
    step.
    """

    def __init__(self, dt, node_count):
        self.dt = dt
        self.known = np.zeros(0, dtype=np.int64)
        self.slot = -np.ones(node_count, dtype=np.int64)   # node -> index in known, -1 if unknown
        self._W = np.zeros((0, 0))     # room for more nodes than known (grows by a quarter)
        self.columns = {}
        self.block = None
        self.block_columns = None

    @property
    def nbytes(self):
        """Memory the cache keeps (bytes): the dense block with its room, the kept columns and
        the last block's columns side by side."""
        total = self._W.nbytes + sum(c.nbytes for c in self.columns.values())
        if self.block_columns is not None:
            total += self.block_columns[1].nbytes
        return total

    @property
    def W(self):
        """The dense inverse-system block ``(3k, 3k)`` (s/kg) of the ``k`` known nodes, in their order."""
        m3 = 3 * len(self.known)
        return self._W[:m3, :m3]

    def keep_only(self, nodes):
        """Forget every known node outside ``nodes`` (the dense block would outgrow its memory)."""
        keep = np.nonzero(np.isin(self.known, nodes))[0]
        dofs = (3 * keep[:, None] + np.arange(3)).ravel()
        self._W = np.ascontiguousarray(self.W[np.ix_(dofs, dofs)])
        self.slot[self.known] = -1
        self.known = self.known[keep]
        self.slot[self.known] = np.arange(len(self.known))

    def reserve(self, count):
        """Make room for ``count`` known nodes (a quarter more, so a creeping patch rarely copies)."""
        if 3 * count > len(self._W):
            room = np.empty((3 * (count + count // 4),) * 2)
            m3 = 3 * len(self.known)
            room[:m3, :m3] = self.W
            self._W = room

    def add(self, nodes, columns):
        """Append ``nodes`` with their response columns ``(3n, 3 len(nodes))`` to the dense block."""
        m, c = len(self.known), len(nodes)
        self.reserve(m + c)
        self.known = np.concatenate([self.known, nodes])
        self.slot[nodes] = np.arange(m, m + c)
        rows = (3 * self.known[:, None] + np.arange(3)).ravel()
        W = self.W
        W[:, 3 * m:] = columns[rows]
        W[3 * m:, :3 * m] = W[:3 * m, 3 * m:].T      # A^-1 is symmetric


def response_cache(model, dt):
    """The model's :class:`ResponseCache` for step ``dt`` s (a new, empty one for another ``dt``)."""
    cache = model.cache.response
    if cache is None or cache.dt != dt:
        cache = model.cache.response = ResponseCache(dt, model.node_count)
    return cache


def _solve_columns(model, dt, nodes):
    """A^-1 columns (3n, 3 len(nodes)) for unit impulses at ``nodes`` (body frame)."""
    n3 = 3 * model.node_count
    dofs = (3 * np.asarray(nodes)[:, None] + np.arange(3)).ravel()
    fact = system_factorisation(model, dt)
    if model.anchored:
        out = np.zeros((n3, len(dofs)))
        free_index = -np.ones(n3, dtype=np.int64)
        free_index[model.free_dofs] = np.arange(len(model.free_dofs))
        cols = np.nonzero(free_index[dofs] >= 0)[0]       # held DOFs do not respond
        rhs = np.zeros((len(model.free_dofs), len(dofs)))
        rhs[free_index[dofs[cols]], cols] = 1.0
        out[model.free_dofs] = fact.solve(rhs).reshape(rhs.shape)
    else:
        rhs = np.zeros((n3, len(dofs)))
        rhs[dofs, np.arange(len(dofs))] = 1.0
        out = fact.solve(rhs).reshape(n3, -1)
    return out


def contact_set(model, dt, nodes, previous=None):
    """The body's node set to give the contact solver this step, sorted ``(k,)``: ``nodes``
    (touched now), or with ``previous`` (the set this returned for the body's last step with
    contacts, None if none) when that set and ``nodes`` together are not much larger than
    ``nodes``: ``previous`` itself if it holds them all, else their union. Resting contact
    flickers a few nodes in and out of the margin; keeping the set lets the body's Delassus block
    be reused instead of rebuilt (the extra nodes carry no contact). ``model`` and ``dt`` name the
    body and step the sets belong to (the answer depends on the sets alone). Pure: the caller
    keeps the returned set (in its state) and passes it as ``previous`` next step.
    """
    nodes = np.asarray(nodes, dtype=np.int64)
    if len(nodes) > 1 and not (nodes[1:] > nodes[:-1]).all():     # (sorted and distinct as given)
        nodes = np.unique(nodes)
    if previous is not None:
        previous = np.asarray(previous, dtype=np.int64)
        at = np.minimum(np.searchsorted(previous, nodes), len(previous) - 1)
        if len(previous) and (previous[at] == nodes).all():     # resting contact: a subset
            return previous if len(previous) <= 1.5 * len(nodes) + 8 else nodes
        union = np.union1d(previous, nodes)
        if len(union) <= 1.5 * len(nodes) + 8:
            return union if len(union) > len(previous) else np.asarray(previous, dtype=np.int64)
    return nodes


def _learn(model, dt, cache, new, nodes, report):
    """Solve the response columns of the ``new`` nodes of the contact set ``nodes`` in batches and
    add them to the cache."""
    per_node = 3 * 3 * model.node_count * 8
    if (len(cache.columns) + len(new)) * per_node > MAX_COLUMN_BYTES:
        current = set(nodes.tolist())
        cache.columns = {i: c for i, c in cache.columns.items() if i in current}
    batch = max(1, int(BATCH_BYTES // (2 * per_node)))
    start = last_report = time.perf_counter()
    for b in range(0, len(new), batch):
        part = new[b:b + batch]
        cols = _solve_columns(model, dt, part)
        cache.add(part, cols)
        if (len(cache.columns) + len(part)) * per_node <= MAX_COLUMN_BYTES:
            for j, node in enumerate(part):
                cache.columns[int(node)] = cols[:, 3 * j:3 * j + 3].copy()
        done, now = b + len(part), time.perf_counter()
        left = (now - start) * (len(new) - done) / done
        if report is not None and done < len(new) and (b == 0 and left > REPORT_EVERY
                                                         or now - last_report >= REPORT_EVERY):
            report(f"contact response of {len(new)} new contact nodes: {done} solved in "
                   f"{now - start:.0f} s, about {left:.0f} s left")
            last_report = now


def delassus_block(model, dt, nodes, report=None, scale=1.0):
    """The Delassus matrix of the k ``nodes`` in the body's solve frame (world = R W R^T, R the
    frame's rotation, e.g. the best-fit rotation of a floating body), block-sparse by rows
    (:func:`sparse_rows`): block [l, i] is the velocity of node l per unit impulse on node i.
    ``scale`` multiplies every block: the solver may want the response of another velocity than
    the end-of-step one (the nodes' mean velocity over the step under Newmark, half of it).

    Nodes met for the first time cost three back-substitutions each (solved in batches);
    ``report(message)``, when given, hears about the progress of a solve that takes long.
    """
    cache = response_cache(model, dt)
    nodes = np.asarray(nodes, dtype=np.int64)
    if cache.block is not None and np.array_equal(cache.block[0], nodes) and cache.block[1] == scale:
        return cache.block[2]
    new = nodes[cache.slot[nodes] < 0]
    if len(new):
        if 72.0 * (len(cache.known) + len(new)) ** 2 > MAX_BLOCK_BYTES:
            cache.keep_only(nodes)
        cache.reserve(len(cache.known) + len(new))
        _learn(model, dt, cache, new, nodes, report)
    # block [l, i] = velocity of node l per impulse on node i, as the rows of :func:`sparse_rows`
    # read straight from the dense block (a first contact of 1,346 nodes: 130 MB copied 3 times)
    W = block_rows(cache._W, cache.slot[nodes], float(scale), DROP_TOL)
    cache.block, cache.block_columns = (nodes.copy(), scale, W), None
    return W


def sparse_rows(W, tol=None):
    """Block rows of a symmetric (k, k, 3, 3) W without its negligible blocks:
    ``(ptr (k + 1,), col (nnz,), blocks (nnz, 3, 3))``, row l holding blocks [l, col[p]] for p in
    ptr[l]..ptr[l+1]-1, its diagonal block first. Block [l, i] is dropped when its norm is below
    ``tol`` (default DROP_TOL) times the geometric mean of the diagonal blocks [l, l] and [i, i]
    (Frobenius norms)."""
    tol = DROP_TOL if tol is None else tol
    k = len(W)
    norm = np.sqrt(np.einsum("liab,liab->li", W, W))
    d = np.sqrt(np.diagonal(norm))
    keep = norm > tol * np.outer(d, d)
    np.fill_diagonal(keep, True)
    rows, cols = np.nonzero(keep)
    order = np.lexsort((cols, cols != rows, rows))      # by row, the diagonal first
    rows, cols = rows[order], cols[order]
    return np.searchsorted(rows, np.arange(k + 1)), cols, W[rows, cols]


def apply_contact_impulses(model, state, step, dt, nodes, impulse):
    """The body takes contact impulses ``(k, 3)`` N s (world) on its ``nodes`` during ``step``
    (:func:`fem.dynamics.apply_impulse`): through the cached response columns when that is cheaper
    than a back-substitution (floating and anchored bodies), else by one solve."""
    nodes = np.asarray(nodes, dtype=np.int64)
    impulse = np.asarray(impulse, dtype=float)
    R = np.asarray(step.R, float)
    dv = None if model.frame == "corotated" else _free_response(model, dt, nodes, impulse @ R)
    if dv is None:
        node_impulse = np.zeros((model.node_count, 3))
        node_impulse[nodes] = impulse
        return apply_impulse(model, state, step, node_impulse)
    # (fem.step_kernels.add_free_response: step.v + rotate_back(dv, R), dv zero off the free DOFs)
    total = step.impulse.copy()
    total[nodes] += impulse                 # (nodes are distinct: a contact set)
    return replace(step, v=add_free_response(step.v, dv, _response_rows(model), R), impulse=total)


def impulse_velocity_change(model, state, step, dt, nodes, impulse):
    """Velocity change ``(n, 3)`` m/s (world) that impulses ``(k, 3)`` N s (world) on ``nodes``
    would give the body in ``step`` (:func:`apply_contact_impulses` from rest)."""
    start = replace(step, v=np.zeros_like(step.v), impulse=np.zeros_like(step.impulse))
    return apply_contact_impulses(model, state, start, dt, nodes, impulse).v


def _response_rows(model):
    """The DOFs the rows of a body's kept response columns stand for: its free ones (every DOF of
    a body without prescribed nodes)."""
    return model.free_dofs


def _free_response(model, dt, nodes, impulse):
    """Velocity change (body frame) on the DOFs of :func:`_response_rows` for impulses ``(k, 3)``
    N s (body frame) on ``nodes``, as one product with their response columns on those rows (the
    prescribed DOFs' rows are zero: left out of the product); None as for
    :func:`impulse_response`."""
    cache = response_cache(model, dt)
    rows = _response_rows(model)
    last = cache.block_columns      # (a checkpoint written before it kept free rows only: rebuilt)
    if last is None or not np.array_equal(last[0], nodes) or last[1].shape[0] != len(rows):
        if 9 * model.node_count * len(nodes) > system_factorisation(model, dt).solve_cost:
            return None
        if any(int(i) not in cache.columns for i in nodes):
            return None
        columns = np.concatenate([cache.columns[int(i)] for i in nodes], axis=1)
        # column-major: the product reads each column once in order (a third faster, cold)
        cache.block_columns = (nodes.copy(), np.asfortranarray(columns[rows]))
    return cache.block_columns[1] @ impulse.ravel()


def impulse_response(model, dt, nodes, impulse):
    """Velocity change ``(3n,)`` (body frame) for impulses ``(k, 3)`` N s (body frame) on
    ``nodes``, as one product with their response columns (kept since their
    :func:`delassus_block`); None when that would read more numbers than one back-substitution or
    some node's columns are not kept (then solve instead). Exact for the same system the blocks
    describe (floating and anchored bodies)."""
    nodes = np.asarray(nodes, dtype=np.int64)
    dv_free = _free_response(model, dt, nodes, np.asarray(impulse, dtype=float))
    if dv_free is None:
        return None
    dv = np.zeros(3 * model.node_count)
    dv[_response_rows(model)] = dv_free
    return dv
