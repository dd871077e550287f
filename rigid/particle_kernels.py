"""The particles of the contact solver (rigid.solver.pgs): FEM surface nodes of one deformable
body (a group) answer impulses through the group's Delassus matrix, block-sparse by rows and kept
in the group's frame; a place (a point of the surface between nodes) is shared among three corner
particles by weights. ``groups`` is the tuple (group_of, group_R, w_ptr, w_col, W, corner,
corner_w) that pgs documents. The rigid-only specialisation of the sweeps never calls these.
"""
import numba as nb
import numpy as np


@nb.njit(cache=True)
def _block(i, l, W, w_ptr, w_col):
    """W[i, l] (3, 3), group frame: velocity of particle i per unit impulse on particle l (zero
    when the block was dropped as negligible)."""
    for p in range(w_ptr[i], w_ptr[i + 1]):
        if w_col[p] == l:
            return W[p]
    return np.zeros((3, 3))


@nb.njit(cache=True)
def _push_group(i, J0, J1, J2, v, groups):
    """Impulse J (world) on particle i: every particle l of its group moves by W[l, i] R^T J
    (group-frame velocities, see pgs). W is symmetric, so W[l, i] = W[i, l]^T is read from row i."""
    group_of, group_R, w_ptr, w_col, W = groups[0], groups[1], groups[2], groups[3], groups[4]
    g = group_of[i]
    j0 = group_R[g, 0, 0] * J0 + group_R[g, 1, 0] * J1 + group_R[g, 2, 0] * J2
    j1 = group_R[g, 0, 1] * J0 + group_R[g, 1, 1] * J1 + group_R[g, 2, 1] * J2
    j2 = group_R[g, 0, 2] * J0 + group_R[g, 1, 2] * J1 + group_R[g, 2, 2] * J2
    for p in range(w_ptr[i], w_ptr[i + 1]):
        l = w_col[p]
        v[l, 0] += W[p, 0, 0] * j0 + W[p, 1, 0] * j1 + W[p, 2, 0] * j2
        v[l, 1] += W[p, 0, 1] * j0 + W[p, 1, 1] * j1 + W[p, 2, 1] * j2
        v[l, 2] += W[p, 0, 2] * j0 + W[p, 1, 2] * j1 + W[p, 2, 2] * j2


@nb.njit(cache=True)
def _particle_velocity(i, v, groups):
    """World velocity of particle or place i: its group-frame velocity rotated out (a place: the
    weighted sum of its corner particles')."""
    group_of, group_R, corner, corner_w = groups[0], groups[1], groups[5], groups[6]
    g = group_of[i]
    if corner[i, 0] >= 0:
        u0 = u1 = u2 = 0.0
        for c in range(3):
            q, f = corner[i, c], corner_w[i, c]
            u0 += f * v[q, 0]
            u1 += f * v[q, 1]
            u2 += f * v[q, 2]
    else:
        u0, u1, u2 = v[i, 0], v[i, 1], v[i, 2]
    return (group_R[g, 0, 0] * u0 + group_R[g, 0, 1] * u1 + group_R[g, 0, 2] * u2,
            group_R[g, 1, 0] * u0 + group_R[g, 1, 1] * u1 + group_R[g, 1, 2] * u2,
            group_R[g, 2, 0] * u0 + group_R[g, 2, 1] * u1 + group_R[g, 2, 2] * u2)


@nb.njit(cache=True)
def _apply_particle(i, j0, j1, j2, v, groups):
    """Impulse (j0, j1, j2) (world) on particle i, or on place i shared among its corners by
    their weights."""
    corner, corner_w = groups[5], groups[6]
    if corner[i, 0] >= 0:
        for c in range(3):
            f = corner_w[i, c]
            if f != 0.0:
                _push_group(corner[i, c], f * j0, f * j1, f * j2, v, groups)
    else:
        _push_group(i, j0, j1, j2, v, groups)


@nb.njit(cache=True)
def _add_pair_block(i, l, D, scale, groups, out):
    """:func:`_add_block` for particles or places i and l of one group (a place's block is the
    weighted sum of its corners')."""
    corner, corner_w = groups[5], groups[6]
    ni = 3 if corner[i, 0] >= 0 else 1
    nl = 3 if corner[l, 0] >= 0 else 1
    for a in range(ni):
        p, fp = (corner[i, a], corner_w[i, a]) if ni == 3 else (i, 1.0)
        for b in range(nl):
            q, fq = (corner[l, b], corner_w[l, b]) if nl == 3 else (l, 1.0)
            if fp != 0.0 and fq != 0.0:
                _add_block(p, q, D, scale * fp * fq, groups, out)


@nb.njit(cache=True)
def _add_block(i, l, D, scale, groups, out):
    """Add scale * D R W[i, l] R^T D^T to out (3, 3): block W[i, l] (group frame) seen along the
    rows of D (world directions)."""
    group_of, group_R, w_ptr, w_col, W = groups[0], groups[1], groups[2], groups[3], groups[4]
    R = group_R[group_of[i]]
    Wb = _block(i, l, W, w_ptr, w_col)
    Db = np.zeros((3, 3))                               # directions in the group frame
    for e in range(3):
        for a in range(3):
            Db[e, a] = D[e, 0] * R[0, a] + D[e, 1] * R[1, a] + D[e, 2] * R[2, a]
    for e in range(3):
        for f in range(3):
            acc = 0.0
            for a in range(3):
                for b in range(3):
                    acc += Db[f, a] * Wb[a, b] * Db[e, b]
            out[f, e] += scale * acc


@nb.njit(cache=True)
def _rotate_particles(v, group_of, group_R, to_group):
    """Particle velocities from world to their group frame (to_group) or back, in place."""
    for i in range(len(group_of)):
        g = group_of[i]
        if g >= 0:
            R = group_R[g]
            x0, x1, x2 = v[i, 0], v[i, 1], v[i, 2]
            for a in range(3):
                v[i, a] = (R[0, a] * x0 + R[1, a] * x1 + R[2, a] * x2 if to_group
                           else R[a, 0] * x0 + R[a, 1] * x1 + R[a, 2] * x2)
