"""Compiled kernels of a deformable body's step (numba, cached on disk): one pass over the nodes
where numpy made several (each pass over 2,000-10,000 nodes cost 10-80 us, and a step made a few
dozen). They compute what the numpy code they replace computed, to round-off
(tests/test_step_kernels.py compares them on random inputs)."""
import numba as nb
import numpy as np


@nb.njit(cache=True)
def frame_offsets(x, c, R, rest_offsets):
    """``(x - c) R - rest_offsets`` ``(n, 3)`` m: each node's displacement in the body frame of
    rotation ``R`` (3, 3) and centre ``c`` (3,), from positions ``x`` (n, 3)."""
    n = len(x)
    u = np.empty((n, 3))
    for i in range(n):
        y0, y1, y2 = x[i, 0] - c[0], x[i, 1] - c[1], x[i, 2] - c[2]
        for a in range(3):
            u[i, a] = (y0 * R[0, a] + y1 * R[1, a] + y2 * R[2, a]) - rest_offsets[i, a]
    return u


@nb.njit(cache=True)
def fit_moment(weights, x, rest_offsets):
    """The weighted centre ``c`` (3,) m of positions ``x`` (n, 3) and the moment matrix
    ``A_pq = sum_i w_i (x_i - c) (X_i - X_c)^T`` (3, 3) of shape matching (Mueller 2005, eq. 7),
    ``rest_offsets`` being ``X - X_c``; its rotation is the best-fit frame's."""
    total = 0.0
    c = np.zeros(3)
    for i in range(len(x)):
        total += weights[i]
        for a in range(3):
            c[a] += weights[i] * x[i, a]
    for a in range(3):
        c[a] = c[a] / total
    A = np.zeros((3, 3))
    for i in range(len(x)):
        w = weights[i]
        for a in range(3):
            p = w * (x[i, a] - c[a])
            for b in range(3):
                A[a, b] += p * rest_offsets[i, b]
    return c, A


@nb.njit(cache=True)
def lumped_rhs(mass, v, R, force, dt):
    """The right-hand side ``M (v R) + dt (force R)`` ``(3n,)`` (N s) of a lumped-mass body's
    system in the frame turned by ``R`` (3, 3): node masses ``mass`` (n,) kg, start velocities
    ``v`` and forces ``force`` (n, 3), world."""
    n = len(v)
    out = np.empty(3 * n)
    for i in range(n):
        for a in range(3):
            vb = v[i, 0] * R[0, a] + v[i, 1] * R[1, a] + v[i, 2] * R[2, a]
            fb = force[i, 0] * R[0, a] + force[i, 1] * R[1, a] + force[i, 2] * R[2, a]
            out[3 * i + a] = mass[i] * vb + dt * fb
    return out


@nb.njit(cache=True)
def rotate_back(v_b, R):
    """Node vectors ``(n, 3)`` from the frame turned by ``R``: ``v_b.reshape(-1, 3) @ R.T``."""
    n = len(v_b) // 3
    out = np.empty((n, 3))
    for i in range(n):
        b0, b1, b2 = v_b[3 * i], v_b[3 * i + 1], v_b[3 * i + 2]
        for a in range(3):
            out[i, a] = R[a, 0] * b0 + R[a, 1] * b1 + R[a, 2] * b2
    return out


@nb.njit(cache=True)
def block_rows(W, slots, scale, tol):
    """The Delassus matrix of the nodes at ``slots`` (k,) of a dense inverse-system block ``W``
    (3m, 3m) (node i's rows and columns ``3 slots[i] .. 3 slots[i] + 2``), times ``scale``, as
    block rows without its negligible blocks: ``(ptr (k + 1,), col (nnz,), blocks (nnz, 3, 3))``,
    row l holding blocks [l, col[p]] for p in ptr[l]..ptr[l+1]-1, its diagonal block first, then
    the others by column. Block [l, i] is kept when its Frobenius norm exceeds ``tol`` times the
    geometric mean of those of the diagonal blocks [l, l] and [i, i]
    (fem.contact_response.sparse_rows, without building the dense (k, k, 3, 3) array first)."""
    k = len(slots)
    norm = np.empty((k, k))
    for l in range(k):
        for i in range(k):
            s = 0.0
            for a in range(3):
                for b in range(3):
                    w = scale * W[3 * slots[l] + a, 3 * slots[i] + b]
                    s += w * w
            norm[l, i] = np.sqrt(s)
    d = np.empty(k)
    for l in range(k):
        d[l] = np.sqrt(norm[l, l])
    ptr = np.zeros(k + 1, dtype=np.int64)
    for l in range(k):
        count = 1
        for i in range(k):
            if i != l and norm[l, i] > tol * (d[l] * d[i]):
                count += 1
        ptr[l + 1] = ptr[l] + count
    col = np.empty(ptr[k], dtype=np.int64)
    blocks = np.empty((ptr[k], 3, 3))
    for l in range(k):
        p = ptr[l]
        col[p] = l
        for i in range(-1, k):
            if i >= 0 and (i == l or not norm[l, i] > tol * (d[l] * d[i])):
                continue
            c = l if i < 0 else i
            for a in range(3):
                for b in range(3):
                    blocks[p, a, b] = scale * W[3 * slots[l] + a, 3 * slots[c] + b]
            col[p] = c
            p += 1
    return ptr, col, blocks


@nb.njit(cache=True)
def add_free_response(v, dv_free, free_dofs, R):
    """``v + rotate_back(dv, R)`` ``(n, 3)``: node velocities ``v`` (n, 3) (world) plus a velocity
    change ``dv`` (3n,) in the frame turned by ``R`` (3, 3) that is ``dv_free`` on the DOFs
    ``free_dofs`` and zero on the others (prescribed DOFs do not respond), in one pass."""
    n = len(v)
    dv = np.zeros(3 * n)
    for p in range(len(free_dofs)):
        dv[free_dofs[p]] = dv_free[p]
    out = np.empty((n, 3))
    for i in range(n):
        b0, b1, b2 = dv[3 * i], dv[3 * i + 1], dv[3 * i + 2]
        for a in range(3):
            out[i, a] = v[i, a] + (R[a, 0] * b0 + R[a, 1] * b1 + R[a, 2] * b2)
    return out


@nb.njit(cache=True)
def frame_elastic_force(ptr, col, blocks, x, c, R, rest_offsets):
    """Elastic node forces ``-(K u) R^T`` ``(n, 3)`` N (world) of a linear body in the frame of
    rotation ``R`` (3, 3) and centre ``c`` (3,): ``u = (x - c) R - rest_offsets`` (n, 3) m
    (:func:`frame_offsets`) and K (3n, 3n) N/m given by 3x3 block rows (``ptr`` (n + 1,), block
    columns ``col``, ``blocks`` (nnz, 3, 3), as scipy's BSR format), in one pass: the blocks'
    indices take a ninth of CSR's, and the step reads K every time."""
    n = len(x)
    u = frame_offsets(x, c, R, rest_offsets)
    out = np.empty((n, 3))
    for i in range(n):
        s0 = s1 = s2 = 0.0
        for p in range(ptr[i], ptr[i + 1]):
            j = col[p]
            u0, u1, u2 = u[j, 0], u[j, 1], u[j, 2]
            s0 += blocks[p, 0, 0] * u0 + blocks[p, 0, 1] * u1 + blocks[p, 0, 2] * u2
            s1 += blocks[p, 1, 0] * u0 + blocks[p, 1, 1] * u1 + blocks[p, 1, 2] * u2
            s2 += blocks[p, 2, 0] * u0 + blocks[p, 2, 1] * u1 + blocks[p, 2, 2] * u2
        for a in range(3):
            out[i, a] = -(R[a, 0] * s0 + R[a, 1] * s1 + R[a, 2] * s2)
    return out


@nb.njit(cache=True)
def anchor_reaction(ptr, col, data, fixed, v, impulse, rhs, R, dt):
    """Node forces ``(n, 3)`` N (world) the prescribed DOFs ``fixed`` (f,) took over a step:
    ``(A (v R) - rhs - impulse R)[fixed] / dt`` turned back by ``R`` (3, 3), zero on the free
    DOFs; A's rows ``fixed`` given as CSR (``ptr`` (f + 1,), ``col``, ``data``), end velocities
    ``v`` and impulses ``impulse`` (n, 3) world, ``rhs`` (3n,) the step's right-hand side in the
    frame turned by R (fem.dynamics.finish, in one pass)."""
    n = len(v)
    vb = np.empty(3 * n)
    for i in range(n):
        for a in range(3):
            vb[3 * i + a] = v[i, 0] * R[0, a] + v[i, 1] * R[1, a] + v[i, 2] * R[2, a]
    r = np.zeros(3 * n)
    for p in range(len(fixed)):
        s = 0.0
        for q in range(ptr[p], ptr[p + 1]):
            s += data[q] * vb[col[q]]
        d = fixed[p]
        i, a = d // 3, d % 3
        ib = impulse[i, 0] * R[0, a] + impulse[i, 1] * R[1, a] + impulse[i, 2] * R[2, a]
        r[d] = (s - rhs[d] - ib) / dt
    out = np.zeros((n, 3))
    for i in range(n):
        b0, b1, b2 = r[3 * i], r[3 * i + 1], r[3 * i + 2]
        if b0 == 0.0 and b1 == 0.0 and b2 == 0.0:
            continue
        for a in range(3):
            out[i, a] = R[a, 0] * b0 + R[a, 1] * b1 + R[a, 2] * b2
    return out
