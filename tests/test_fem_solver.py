"""The sparse solver backends give the same answers, for one and many right-hand sides."""
import numpy as np
import pytest
import scipy.sparse as sp

from fem import solver
from fem.dynamics import system_matrix
from fem.mesh import box_tet_mesh
from fem.model import build_fem_model


def _system():
    points, tets = box_tet_mesh((0.4, 0.2, 0.1), (8, 4, 2))
    model = build_fem_model(points, tets, density=7800.0, young=2e11, poisson=0.3)
    return system_matrix(model, 1e-3).tocsc()


@pytest.mark.parametrize("backend", ["superlu", "cholmod"])
def test_backend_solves_the_system_to_round_off(backend):
    if backend == "cholmod" and solver.CholeskySolverD is None:
        pytest.fail("cholespy is a dependency of the project and should be installed")
    A = _system()
    f = solver.Factorisation(A, backend=backend)
    assert f.backend == backend
    rng = np.random.default_rng(1)
    b = rng.standard_normal(A.shape[0])
    B = rng.standard_normal((A.shape[0], 5))
    x, X = f.solve(b), f.solve(B)
    # relative residuals at the level of round-off times the condition of a steel system
    assert np.linalg.norm(A @ x - b) <= 1e-10 * np.linalg.norm(b)
    assert np.linalg.norm(A @ X - B) <= 1e-10 * np.linalg.norm(B)
    # many right-hand sides at once equal the columns solved one by one
    np.testing.assert_allclose(X[:, 2], f.solve(B[:, 2]), rtol=0, atol=1e-12 * np.abs(X).max())
    assert f.solve_cost > A.nnz


def test_cholmod_falls_back_to_lu_for_an_indefinite_matrix():
    if solver.CholeskySolverD is None:
        pytest.fail("cholespy is a dependency of the project and should be installed")
    A = sp.csc_matrix(np.array([[1.0, 2.0], [2.0, 1.0]]))
    with pytest.warns(RuntimeWarning, match="SuperLU"):
        f = solver.Factorisation(A, backend="cholmod")
    assert f.backend == "superlu"
    np.testing.assert_allclose(A @ f.solve([1.0, 0.0]), [1.0, 0.0], atol=1e-14)


def test_unknown_backend_is_named():
    with pytest.raises(ValueError, match="'cholmod' or 'superlu'"):
        solver.Factorisation(sp.identity(3, format="csc"), backend="pardiso")
