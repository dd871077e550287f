"""Per-element rotations of a deformed body: the polar decomposition of each element's deformation
gradient (stiffness warping, Mueller and Gross 2004). The corotated frame's forces and stiffness
(``fem.dynamics``), its strains and stresses (``fem.stress``) and its plastic flow
(``fem.plastic_flow``) all turn each element by these.
"""
import numba as nb
import numpy as np

from rigid.shape_matching import rotation_of


def tet_rotations(model, x):
    """Per-element rotations ``(t, 3, 3)`` from the polar decomposition of the vertex simplex's
    deformation gradient ``F = Ds Dm^-1`` of positions ``x`` (n, 3) m."""
    return rotation_of(deformation_gradients(np.asarray(x, dtype=float), model.tets,
                                             model.elements.tet_rest_inverse))


@nb.njit(cache=True)
def deformation_gradients(x, tets, rest_inverse):
    """``F = Ds Dm^-1`` ``(t, 3, 3)`` of each element's vertex simplex: ``Ds`` the edge matrix
    ``[x1 - x0, x2 - x0, x3 - x0]`` of positions ``x`` (n, 3) m at the first four nodes of ``tets``,
    ``rest_inverse`` ``(t, 3, 3)`` the inverse rest edge matrices; one pass over the elements."""
    t = tets.shape[0]
    F = np.empty((t, 3, 3))
    for e in range(t):
        p = tets[e, 0]
        for i in range(3):
            d1 = x[tets[e, 1], i] - x[p, i]
            d2 = x[tets[e, 2], i] - x[p, i]
            d3 = x[tets[e, 3], i] - x[p, i]
            for j in range(3):
                F[e, i, j] = d1 * rest_inverse[e, 0, j] + d2 * rest_inverse[e, 1, j] + d3 * rest_inverse[e, 2, j]
    return F


def element_rotations(model, x):
    """:func:`tet_rotations` of positions ``x`` (n, 3) m, kept for the last positions asked for.

    A step's end (its energy under Newmark, a plastic body's return map) finds the rotations of
    the end-of-step positions and the next ``predict`` asks for the same positions again (any
    change of ``x`` in between computes them anew). Kept in ``model.cache.rotations`` with a copy
    of the positions they belong to; the returned array is read-only.
    """
    last = model.cache.rotations
    if last is not None and np.array_equal(last[0], x):
        return last[1]
    tet_R = tet_rotations(model, x)
    tet_R.flags.writeable = False
    model.cache.rotations = (np.array(x, dtype=float), tet_R)
    return tet_R
