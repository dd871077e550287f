"""The particles of the contact solver (rigid.solver.pgs): FEM surface nodes of one deformable
body (a group) answer impulses through the group's Delassus matrix, block-sparse by rows and kept
in the group's frame; a place (a point of the surface between nodes) is shared among three corner
particles by weights. ``groups`` is the tuple (group_of, group_R, w_ptr, w_col, W, corner,
corner_w) that pgs documents, extended by :func:`with_place_rows` with each place's own row
(place_ptr, place_col, place_W): the weighted sum of its corners' rows, so that an impulse on a
place is one pass over the particles it moves instead of three overlapping ones. The rigid-only
specialisation of the sweeps never calls these.
"""
import numba as nb
import numpy as np


@nb.njit(cache=True, inline="always")
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


@nb.njit(cache=True, inline="always")
def _apply_particle(i, j0, j1, j2, v, groups):
    """Impulse (j0, j1, j2) (world) on particle i, or on place i shared among its corners by
    their weights (through the place's own row, :func:`with_place_rows`)."""
    if groups[5][i, 0] >= 0:
        _push_row(i, j0, j1, j2, v, groups[0], groups[1], groups[7], groups[8], groups[9])
    else:
        _push_row(i, j0, j1, j2, v, groups[0], groups[1], groups[2], groups[3], groups[4])


@nb.njit(cache=True, inline="always")
def _push_row(i, J0, J1, J2, v, group_of, group_R, ptr, col, B):
    """Impulse J (world) on solver body i of a group through its block row ``B[ptr[i]:ptr[i+1]]``
    (columns ``col``): every particle l of the row moves by B[p]^T R^T J (group frame)."""
    g = group_of[i]
    j0 = group_R[g, 0, 0] * J0 + group_R[g, 1, 0] * J1 + group_R[g, 2, 0] * J2
    j1 = group_R[g, 0, 1] * J0 + group_R[g, 1, 1] * J1 + group_R[g, 2, 1] * J2
    j2 = group_R[g, 0, 2] * J0 + group_R[g, 1, 2] * J1 + group_R[g, 2, 2] * J2
    for p in range(ptr[i], ptr[i + 1]):
        l = col[p]
        v[l, 0] += B[p, 0, 0] * j0 + B[p, 1, 0] * j1 + B[p, 2, 0] * j2
        v[l, 1] += B[p, 0, 1] * j0 + B[p, 1, 1] * j1 + B[p, 2, 1] * j2
        v[l, 2] += B[p, 0, 2] * j0 + B[p, 1, 2] * j1 + B[p, 2, 2] * j2


@nb.njit(cache=True)
def with_place_rows(ia, ib, groups):
    """``groups`` extended by the rows of the places the contacts (ia, ib) touch: (place_ptr (n + 1,),
    place_col, place_W (q, 3, 3)), where place i's row is the sum over its corners c of
    corner_w[i, c] W[c, :] (group frame, columns merged), so that pushing an impulse through it
    moves every particle as pushing each corner's share through the corner's row does (to
    round-off). Other solver bodies have empty rows. Neighbouring corners move mostly the same
    particles: a place's row is about a third of its corners' rows together (a pile of soft boxes:
    94 blocks against 281)."""
    group_of, w_ptr, w_col, W, corner, corner_w = (groups[0], groups[2], groups[3], groups[4],
                                                   groups[5], groups[6])
    n = len(group_of)
    used = np.zeros(n, np.bool_)
    for k in range(len(ia)):
        for i in (ia[k], ib[k]):
            if i >= 0 and group_of[i] >= 0 and corner[i, 0] >= 0:
                used[i] = True
    seen = np.full(n, -1, np.int64)         # the place whose row last took column l
    at = np.zeros(n, np.int64)              # and where in that row
    ptr = np.zeros(n + 1, np.int64)
    for i in range(n):                      # row lengths: the union of the corners' columns
        count = 0
        if used[i]:
            for c in range(3):
                q = corner[i, c]
                if corner_w[i, c] != 0.0:
                    for p in range(w_ptr[q], w_ptr[q + 1]):
                        if seen[w_col[p]] != i:
                            seen[w_col[p]] = i
                            count += 1
        ptr[i + 1] = ptr[i] + count
    col = np.empty(ptr[n], np.int64)
    B = np.zeros((ptr[n], 3, 3))
    seen[:] = -1
    for i in range(n):
        if not used[i]:
            continue
        end = ptr[i]
        for c in range(3):
            q, f = corner[i, c], corner_w[i, c]
            if f == 0.0:
                continue
            for p in range(w_ptr[q], w_ptr[q + 1]):
                l = w_col[p]
                if seen[l] != i:
                    seen[l] = i
                    at[l] = end
                    col[end] = l
                    end += 1
                for a in range(3):
                    for b in range(3):
                        B[at[l], a, b] += f * W[p, a, b]
    return (groups[0], groups[1], groups[2], groups[3], groups[4], groups[5], groups[6], ptr, col, B)


@nb.njit(cache=True, inline="always")
def _add_pair_block(i, l, D, scale, groups, out, Db):
    """Add scale * D R W[i, l] R^T D^T to out (3, 3) for particles or places i and l of one group
    (a place's block is the weighted sum of its corners'): block W[i, l] (group frame, zero when
    dropped) seen along the rows of D (world directions). ``Db`` (3, 3): scratch, the rows of D
    in the group frame."""
    group_of, group_R, w_ptr, w_col, W, corner, corner_w = (groups[0], groups[1], groups[2], groups[3],
                                                            groups[4], groups[5], groups[6])
    R = group_R[group_of[i]]
    for e in range(3):
        for a in range(3):
            Db[e, a] = D[e, 0] * R[0, a] + D[e, 1] * R[1, a] + D[e, 2] * R[2, a]
    ni = 3 if corner[i, 0] >= 0 else 1
    nl = 3 if corner[l, 0] >= 0 else 1
    for a in range(ni):
        p, fp = (corner[i, a], corner_w[i, a]) if ni == 3 else (i, 1.0)
        for b in range(nl):
            q, fq = (corner[l, b], corner_w[l, b]) if nl == 3 else (l, 1.0)
            if fp != 0.0 and fq != 0.0:
                _add_block(_block_at(p, q, w_ptr, w_col), W, Db, scale * fp * fq, out)


@nb.njit(cache=True, inline="always")
def _block_at(i, l, w_ptr, w_col):
    """Where block [i, l] is in W (-1 when it was dropped as negligible)."""
    for p in range(w_ptr[i], w_ptr[i + 1]):
        if w_col[p] == l:
            return p
    return -1


@nb.njit(cache=True, inline="always")
def _add_block(p, W, Db, scale, out):
    """Add scale * Db W[p] Db^T to out (3, 3) (nothing for p = -1, a dropped block)."""
    if p < 0:
        return
    for e in range(3):
        for f in range(3):
            acc = 0.0
            for a in range(3):
                for b in range(3):
                    acc += Db[f, a] * W[p, a, b] * Db[e, b]
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
