"""Quasi-static plastic equilibrium of an anchored body (reference answers and load-stepping studies).

The initial-stiffness method: with the rest stiffness factorised once, repeat
``K u = f + f_p(eps_p)`` (anchored DOFs prescribed) and the return map of ``fem.plastic_flow``
until the displacement stops changing. Each iteration is exactly one step of the staggered scheme
the dynamics use, without inertia. Below the collapse load it converges; at and above it the
plastic strain grows without bound and the iteration does not converge.
"""
import numpy as np

from fem.plastic_flow import plastic_update, state_plastic_force
from fem.solver import Factorisation


def static_solver(model):
    """Factorisation of the rest stiffness on the free DOFs (anchored bodies only)."""
    if not model.anchored:
        raise ValueError("static plastic solves need an anchored body")
    free = model.free_dofs
    return Factorisation(model.K[free][:, free], model.linear_solver)


def static_plastic_solve(model, state, node_force, solver=None, max_iterations=400, rtol=1e-7):
    """Plastic equilibrium under node forces ``(n, 3)`` N with anchored nodes held where they are.

    Starts from ``state`` (its plastic strain is the history). Returns ``(state, iterations,
    converged)``; converged when the largest displacement change of an iteration is below ``rtol``
    times the largest displacement.
    """
    solver = static_solver(model) if solver is None else solver
    free, fixed = model.free_dofs, model.fixed_dofs
    X = model.rest_points.ravel()
    u = state.x.ravel() - X
    f = np.asarray(node_force, dtype=float).ravel()
    K_fc = model.K[free][:, fixed]
    for iteration in range(1, max_iterations + 1):
        f_p = state_plastic_force(model, state).ravel()
        u_new = u.copy()
        u_new[free] = solver.solve(f[free] + f_p[free] - K_fc @ u[fixed])
        change = np.max(np.abs(u_new - u))
        u = u_new
        state = plastic_update(model, state.replace(x=(X + u).reshape(-1, 3)))
        if change <= rtol * np.max(np.abs(u)):
            return state, iteration, True
    return state, max_iterations, False

