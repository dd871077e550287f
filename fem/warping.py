"""Stiffness warping (Mueller and Gross 2004): the corotated body's stiffness ``sum_e R_e K_e R_e^T``
assembled on the fixed pattern of its rest stiffness, and its elastic forces and energy, for element
rotations ``R_e`` (``fem.rotations``). Linear tets take their blocks from their four shape-function
gradients (``fem.assembly._element_stiffness``); other elements from their stored blocks.
"""
import numba as nb
import numpy as np
import scipy.sparse as sp


def warped_assembly(data, rotations, dof_count):
    """Warped stiffness ``sum_e R_e K_e R_e^T`` ``(3n, 3n)`` CSR (N/m) for element rotations
    ``(t, 3, 3)``: each node-pair block of ``tet_stiffness`` rotated and summed into the
    precomputed pattern in one compiled pass (stiffness warping, Mueller and Gross 2004)."""
    return sp.csr_matrix((warped_values(data, rotations), data.pattern_cols, data.pattern_indptr),
                         shape=(dof_count, dof_count))


def warped_values(data, rotations):
    """The values ``(nnz,)`` of :func:`warped_assembly` on the pattern of ``data``."""
    values = np.zeros(len(data.pattern_cols))
    R = np.ascontiguousarray(rotations, dtype=float)
    if _linear(data):
        _warp_linear_into(data.tet_gradients[:, 0], data.tet_weights[:, 0], *data.lame, R,
                          data.block_to_csr, values)
    else:
        _warp_into(data.tet_stiffness, R, data.block_to_csr, values)
    return values


def _linear(data):
    """Whether the elements are linear tets (one quadrature point) with their Lame parameters
    known: their warped blocks and forces then come from the four gradients (_element_stiffness),
    not from the 144 numbers of each block read every step."""
    return data.lame is not None and data.tet_gradients.shape[1:3] == (1, 4)


@nb.njit(cache=True)
def _warp_linear_into(G, V, mu, lam, R, block_to_csr, values):
    """:func:`_warp_into` for linear tets from their gradients ``G`` (t, 4, 3) and volumes ``V``
    (t,): block (a, c) of ``R_e K_e R_e^T`` is ``V (lam r_a r_c^T + mu r_c r_a^T + mu (g_a . g_c) I)``
    with the turned gradients ``r = R_e g`` (:func:`_element_stiffness`)."""
    t = G.shape[0]
    r = np.empty((4, 3))
    W = np.empty((3, 3))
    for e in range(t):
        for a in range(4):
            for i in range(3):
                r[a, i] = R[e, i, 0] * G[e, a, 0] + R[e, i, 1] * G[e, a, 1] + R[e, i, 2] * G[e, a, 2]
        v = V[e]
        base = e * 144
        for a in range(4):
            for c in range(a, 4):
                dot = mu * (G[e, a, 0] * G[e, c, 0] + G[e, a, 1] * G[e, c, 1] + G[e, a, 2] * G[e, c, 2])
                for i in range(3):
                    for j in range(3):
                        w = lam * r[a, i] * r[c, j] + mu * r[c, i] * r[a, j]
                        W[i, j] = v * (w + dot if i == j else w)
                _scatter_pair(values, block_to_csr, base, 12, a, c, W)


@nb.njit(cache=True, inline="always")
def _scatter_pair(values, block_to_csr, base, m, a, c, W):
    """Add the turned block W (3, 3) of node pair (a, c) of the element whose entries start at
    ``base`` in ``block_to_csr`` (m = 3b DOFs a row) to ``values``, and its transpose as the pair
    (c, a) when c != a."""
    for i in range(3):
        row = base + (3 * a + i) * m + 3 * c
        for j in range(3):
            values[block_to_csr[row + j]] += W[i, j]
    if c != a:
        for i in range(3):
            row = base + (3 * c + i) * m + 3 * a
            for j in range(3):
                values[block_to_csr[row + j]] += W[j, i]


@nb.njit(cache=True)
def _warp_into(Ke, R, block_to_csr, values):
    """values[block_to_csr[e, 3a+i, 3c+j]] += (R_e Ke[e]_{ac} R_e^T)_ij for every element e and
    node pair (a, c); Ke (t, 3b, 3b), R (t, 3, 3), block_to_csr flattened (t, 3b, 3b). Ke is
    symmetric, so each pair above the diagonal is turned once and its mirror takes the transpose
    (the warped stiffness comes out exactly symmetric)."""
    t, m, _ = Ke.shape
    b = m // 3
    RB = np.empty((3, 3))
    W = np.empty((3, 3))
    for e in range(t):
        Re = R[e]
        base = e * m * m
        for a in range(b):
            for c in range(a, b):
                # RB = R_e B, B the (a, c) block of Ke[e]; W = RB R_e^T
                for i in range(3):
                    for j in range(3):
                        acc = 0.0
                        for k in range(3):
                            acc += Re[i, k] * Ke[e, 3 * a + k, 3 * c + j]
                        RB[i, j] = acc
                for i in range(3):
                    for j in range(3):
                        acc = 0.0
                        for k in range(3):
                            acc += RB[i, k] * Re[j, k]
                        W[i, j] = acc
                _scatter_pair(values, block_to_csr, base, m, a, c, W)


def warped_forces(data, rotations, x, rest_points, node_count):
    """Elastic node forces ``(n, 3)`` (N) of stiffness warping: per element,
    ``-R_e K_e (R_e^T x_e - X_e)`` with each element's mean translation removed (K_e ignores it;
    removing it keeps the digits of far-away bodies), summed over elements in one compiled pass."""
    return _warped(data, rotations, x, rest_points, node_count)[0]


def warped_energy(data, rotations, x, rest_points):
    """Strain energy ``sum_e 1/2 u_e^T K_e u_e`` (J) of stiffness warping, ``u_e`` as in
    :func:`warped_forces` (whose force is its gradient when ``R_e`` are the polar rotations)."""
    return _warped(data, rotations, x, rest_points, len(x))[1]


def _warped(data, rotations, x, rest_points, node_count):
    out = np.zeros((node_count, 3))
    R = np.ascontiguousarray(rotations, dtype=float)
    x, X = np.ascontiguousarray(x, dtype=float), np.ascontiguousarray(rest_points, dtype=float)
    if _linear(data):
        energy = _warped_linear_forces_into(data.tet_gradients[:, 0], data.tet_weights[:, 0], *data.lame,
                                            R, data.tet_nodes, x, X, out)
    else:
        energy = _warped_forces_into(data.tet_stiffness, R, data.tet_nodes, x, X, out)
    return out, energy


@nb.njit(cache=True)
def _warped_linear_forces_into(G, V, mu, lam, R, tet_nodes, x, X, out):
    """:func:`_warped_forces_into` for linear tets from their gradients ``G`` (t, 4, 3) and
    volumes ``V`` (t,): with ``H = sum_a u_a g_a^T`` (u as there), ``K_e u`` at node a is
    ``V sigma g_a``, ``sigma = lam tr(H) I + mu (H + H^T)``, and the energy ``V sigma : H / 2``."""
    t = G.shape[0]
    u = np.empty((4, 3))
    H = np.empty((3, 3))
    S = np.empty((3, 3))
    energy = 0.0
    for e in range(t):
        m0 = m1 = m2 = 0.0
        for a in range(4):
            node = tet_nodes[e, a]
            for i in range(3):      # (R^T x - X)_i
                u[a, i] = (R[e, 0, i] * x[node, 0] + R[e, 1, i] * x[node, 1] + R[e, 2, i] * x[node, 2]
                           - X[node, i])
            m0, m1, m2 = m0 + u[a, 0], m1 + u[a, 1], m2 + u[a, 2]
        for a in range(4):
            u[a, 0] -= m0 / 4
            u[a, 1] -= m1 / 4
            u[a, 2] -= m2 / 4
        for i in range(3):
            for j in range(3):
                H[i, j] = u[0, i] * G[e, 0, j] + u[1, i] * G[e, 1, j] + u[2, i] * G[e, 2, j] + u[3, i] * G[e, 3, j]
        trace = H[0, 0] + H[1, 1] + H[2, 2]
        v = V[e]
        work = 0.0
        for i in range(3):
            for j in range(3):
                S[i, j] = v * (mu * (H[i, j] + H[j, i]) + (lam * trace if i == j else 0.0))
                work += S[i, j] * H[i, j]
        energy += 0.5 * work
        for a in range(4):
            node = tet_nodes[e, a]
            f0 = S[0, 0] * G[e, a, 0] + S[0, 1] * G[e, a, 1] + S[0, 2] * G[e, a, 2]
            f1 = S[1, 0] * G[e, a, 0] + S[1, 1] * G[e, a, 1] + S[1, 2] * G[e, a, 2]
            f2 = S[2, 0] * G[e, a, 0] + S[2, 1] * G[e, a, 1] + S[2, 2] * G[e, a, 2]
            for i in range(3):
                out[node, i] -= R[e, i, 0] * f0 + R[e, i, 1] * f1 + R[e, i, 2] * f2
    return energy


@nb.njit(cache=True)
def _warped_forces_into(Ke, R, tet_nodes, x, X, out):
    """out[node] -= (R_e K_e u_e)[node] for every element e, u_e = R_e^T x_e - X_e less its mean;
    Ke (t, 3b, 3b), R (t, 3, 3), tet_nodes (t, b), x and X (n, 3). Returns the strain energy
    ``sum_e 1/2 u_e . K_e u_e``."""
    t, m, _ = Ke.shape
    b = m // 3
    u = np.empty(m)
    g = np.empty(m)
    energy = 0.0
    for e in range(t):
        Re = R[e]
        mean = np.zeros(3)
        for a in range(b):
            node = tet_nodes[e, a]
            for i in range(3):      # (R^T x - X)_i
                u[3 * a + i] = (Re[0, i] * x[node, 0] + Re[1, i] * x[node, 1] + Re[2, i] * x[node, 2]
                                - X[node, i])
                mean[i] += u[3 * a + i]
        for a in range(b):
            for i in range(3):
                u[3 * a + i] -= mean[i] / b
        for r in range(m):
            acc = 0.0
            for c in range(m):
                acc += Ke[e, r, c] * u[c]
            g[r] = acc
            energy += 0.5 * u[r] * acc
        for a in range(b):
            node = tet_nodes[e, a]
            for i in range(3):
                out[node, i] -= Re[i, 0] * g[3 * a] + Re[i, 1] * g[3 * a + 1] + Re[i, 2] * g[3 * a + 2]
    return energy
