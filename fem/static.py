"""Direct static solves of the rest-frame linear problem (reference answers for the dynamics)."""
import numpy as np
import skfem

from fem.dynamics import gravity_force


def static_displacement(model, gravity=(0.0, 0.0, 0.0), fixed_dofs=None, fixed_values=None):
    """Static displacement ``(n, 3)`` (m) of ``K u = f`` with scikit-fem's condense and solve.

    f: the model's loads plus gravity ``(3,)`` m/s^2. Constrained DOFs: ``fixed_dofs`` (node-major
    ``3 * node + component``) with values ``fixed_values`` (m), default the anchored DOFs held at
    zero displacement.
    """
    f = (model.node_load + gravity_force(model, gravity)).ravel()
    D = model.fixed_dofs if fixed_dofs is None else np.asarray(fixed_dofs, dtype=np.int64)
    u = np.zeros(3 * model.node_count)
    if fixed_values is not None:
        u[D] = fixed_values
    u = skfem.solve(*skfem.condense(model.K, f, x=u, D=D))
    return u.reshape(-1, 3)
