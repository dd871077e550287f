"""Per-element rotations of a deformed body: the polar decomposition of each element's deformation
gradient (stiffness warping, Mueller and Gross 2004). The corotated frame's forces and stiffness
(``fem.dynamics``), its strains and stresses (``fem.stress``) and its plastic flow
(``fem.plastic_flow``) all turn each element by these.
"""
import numpy as np

from rigid.shape_matching import rotation_of


def tet_rotations(model, x):
    """Per-element rotations ``(t, 3, 3)`` from the polar decomposition of the vertex simplex's
    deformation gradient ``F = Ds Dm^-1`` of positions ``x`` (n, 3) m."""
    xs = x[model.tets[:, :4]]
    Ds = (xs[:, 1:] - xs[:, :1]).transpose(0, 2, 1)
    return rotation_of(Ds @ model.elements.tet_rest_inverse)


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
