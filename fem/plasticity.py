"""Von Mises perfect plasticity for linear-elastic P1 tetrahedra.

The one definition of every yield and plastic-flow quantity in the project: the stepper, the VTK
output and the tests all call these functions.

Conventions
-----------
* Tensors are entity-first: a stress or strain field is ``(..., 3, 3)`` (usually ``(tet_count, 3,
  3)``), symmetric. Stresses are in Pa, strains are dimensionless.
* Lame parameters ``mu`` (shear modulus) and ``lam`` in Pa, yield stress ``Y`` in Pa. Each may be a
  scalar or an array broadcastable to the leading shape ``(...)`` (e.g. one value per tet).
* Small-strain additive split (O'Brien, Bargteil, Hodgins 2002): ``eps_e = eps - eps_p`` and
  ``sigma = 2 mu eps_e + lam tr(eps_e) I``. The plastic strain ``eps_p`` is deviatoric (trace 0),
  so it changes shape, never volume.
* Von Mises (Bridson's notes): ``f(sigma) = sqrt(3/2) |dev sigma|_F - Y``; yielding is ``f > 0``.
* Perfect plastic flow (associative): where ``f > 0``,
  ``eps_p += gamma dev(sigma)/|dev sigma|_F`` with ``gamma = (|dev sigma|_F - sqrt(2/3) Y)/(2 mu)``,
  which returns the stress exactly onto ``f = 0`` (radial return).
* The plastic strain enters the FEM as an equivalent nodal force (``plastic_nodal_forces``), so the
  system matrix never changes.
"""
import numpy as np

_SQRT_3_2 = np.sqrt(1.5)
_SQRT_2_3 = np.sqrt(2.0 / 3.0)


# ---------------------------------------------------------------------------------------------
# Invariants and the yield criterion
# ---------------------------------------------------------------------------------------------

def _trace(a):
    """Trace of tensors ``(..., 3, 3)``, shape ``(...)``: a sum of three strided views (np.trace
    over the last axes is 10x slower here)."""
    return a[..., 0, 0] + a[..., 1, 1] + a[..., 2, 2]


def _add_to_diagonal(a, value):
    """``a += value I`` in place for tensors ``a`` ``(..., 3, 3)`` and ``value`` ``(...)``: three
    strided updates, no ``(..., 3, 3)`` temporary. Returns ``a``."""
    for i in range(3):
        a[..., i, i] += value
    return a


def deviatoric(sigma):
    """Deviatoric part ``sigma - tr(sigma)/3 I`` of tensors ``(..., 3, 3)``; same shape and unit."""
    sigma = np.asarray(sigma, dtype=float)
    return _add_to_diagonal(np.copy(sigma), -_trace(sigma) / 3.0)   # np.copy keeps the layout


def frobenius_norm(a):
    """``|a|_F = sqrt(a : a)`` of tensors ``(..., 3, 3)``, shape ``(...)``."""
    a = np.asarray(a, dtype=float)
    return np.sqrt(np.einsum('...ij,...ij->...', a, a))


def von_mises(sigma):
    """Von Mises equivalent stress ``sqrt(3/2) |dev sigma|_F`` in Pa, shape ``(...)``.

    Equals ``sqrt(((s1-s2)^2 + (s2-s3)^2 + (s3-s1)^2)/2)`` in principal stresses, the axial stress
    under uniaxial tension and ``sqrt(3) tau`` under pure shear ``tau``; zero for any pressure.
    """
    return _SQRT_3_2 * frobenius_norm(deviatoric(sigma))


def yield_function(sigma, Y):
    """Von Mises yield function ``f = von_mises(sigma) - Y`` in Pa, shape ``(...)``.

    ``f < 0`` elastic, ``f = 0`` on the yield surface, ``f > 0`` not admissible (plastic flow).
    ``Y`` is a scalar or broadcastable to ``(...)``.
    """
    return von_mises(sigma) - np.asarray(Y, dtype=float)


# ---------------------------------------------------------------------------------------------
# Hooke's law
# ---------------------------------------------------------------------------------------------

def isotropic_stress(eps, mu, lam):
    """Isotropic Hooke's law ``2 mu eps + lam tr(eps) I`` for strains ``(..., 3, 3)``; Pa.

    ``mu`` and ``lam`` (Pa) are scalars or broadcastable to ``(...)``.
    """
    eps = np.asarray(eps, dtype=float)
    pressure = np.asarray(lam, dtype=float) * _trace(eps)
    sigma = 2.0 * np.asarray(mu, dtype=float)[..., None, None] * eps   # keeps the layout of eps
    lead = np.broadcast_shapes(sigma.shape[:-2], pressure.shape)
    if sigma.shape[:-2] != lead:   # lam has more entries than eps and mu
        sigma = np.broadcast_to(sigma, lead + (3, 3)).copy()
    return _add_to_diagonal(sigma, pressure)


def elastic_stress(eps, eps_p, mu, lam):
    """Stress ``C : (eps - eps_p)`` of total strain ``eps`` and plastic strain ``eps_p`` (..., 3, 3)."""
    return isotropic_stress(np.asarray(eps, dtype=float) - np.asarray(eps_p, dtype=float), mu, lam)


# ---------------------------------------------------------------------------------------------
# Plastic strain measures and the return mapping
# ---------------------------------------------------------------------------------------------

def equivalent_plastic_strain(eps_p):
    """Equivalent plastic strain ``sqrt(2/3) |eps_p|_F`` (dimensionless), shape ``(...)``.

    For uniaxial plastic flow ``eps_p = e diag(1, -1/2, -1/2)`` this is ``|e|``.
    """
    return _SQRT_2_3 * frobenius_norm(eps_p)


def capped_increment(d_eps_p, room):
    """Plastic strain increments ``d_eps_p`` (..., 3, 3) scaled, their direction kept, so that
    their equivalent plastic strain is at most ``room`` (...; scalar or broadcastable): what the
    cap leaves an element, ``max_plastic_strain`` less its accumulated equivalent plastic strain
    (none below 0: an element at the cap flows no more). Increments within it are returned
    unchanged (bitwise)."""
    d_eps_p = np.asarray(d_eps_p, dtype=float)
    room = np.maximum(np.asarray(room, dtype=float), 0.0)
    step = equivalent_plastic_strain(d_eps_p)
    over = step > room
    scale = np.where(over, room / np.where(over, step, 1.0), 1.0)
    return np.where(over[..., None, None], d_eps_p * scale[..., None, None], d_eps_p)


def return_map(sigma_trial, eps_p, mu, Y, room=None):
    """Perfect-plastic radial return of trial stresses onto the von Mises surface.

    The flow is computed at the yielded elements only (without a gather when all of them yield, as
    for the points ``fem.plastic_flow.plastic_update`` passes); inputs of any memory layout work.

    Parameters
    ----------
    sigma_trial : (..., 3, 3) Pa
        Trial stress ``C : (eps - eps_p)`` with the current (old) plastic strain.
    eps_p : (..., 3, 3)
        Current plastic strain, deviatoric.
    mu : float or (...) Pa
        Shear modulus.
    Y : float or (...) Pa
        Yield stress (scalar or one per element).
    room : float or (...), optional
        The equivalent plastic strain each element may still flow (``max_plastic_strain`` less
        its accumulated equivalent plastic strain): a larger increment is scaled down to it
        (``capped_increment``) and the stress recomputed from it, so it may then lie outside the
        yield surface (further flow is elastic).

    Returns
    -------
    eps_p_new : (..., 3, 3)
        Updated plastic strain ``eps_p + gamma n`` with ``n = dev(sigma_trial)/|dev sigma_trial|_F``.
    sigma_new : (..., 3, 3) Pa
        ``C : (eps - eps_p_new) = sigma_trial - 2 mu (eps_p_new - eps_p)`` (the plastic increment is
        deviatoric, so ``lam`` drops out); lies on ``f = 0`` where the element yielded.
    gamma : (...)
        Plastic multiplier ``(|dev sigma_trial|_F - sqrt(2/3) Y) / (2 mu)`` where yielded (before
        any cap), 0 elsewhere; the Frobenius norm of the uncapped plastic strain increment.
    yielded : (...) bool
        ``yield_function(sigma_trial, Y) > 0``. Elements not yielded are returned bitwise unchanged.
    """
    sigma_trial = np.asarray(sigma_trial, dtype=float)
    lead = sigma_trial.shape[:-2]
    eps_p = np.asarray(eps_p, dtype=float)
    if eps_p.shape != sigma_trial.shape:
        eps_p = np.broadcast_to(eps_p, sigma_trial.shape)

    s = deviatoric(sigma_trial)
    s_norm = frobenius_norm(s)
    yielded = _SQRT_3_2 * s_norm - np.asarray(Y, dtype=float) > 0.0
    if not yielded.any():
        # elements inside the surface are left untouched, bit for bit
        return eps_p.copy(), sigma_trial.copy(), np.zeros(lead), yielded
    # flow computed at the yielded elements only: all of them (no gather) or an index subset
    at = Ellipsis if yielded.all() else np.nonzero(yielded)
    new, sigma, gamma = _radial_return(sigma_trial, eps_p, s, s_norm, mu, Y, room, at)
    if at is Ellipsis:
        return new, sigma, gamma, yielded
    eps_p_new, sigma_new, gamma_all = eps_p.copy(), sigma_trial.copy(), np.zeros(lead)
    eps_p_new[at], sigma_new[at], gamma_all[at] = new, sigma, gamma
    return eps_p_new, sigma_new, gamma_all, yielded


def _taken_at(value, lead, at):
    """A scalar, or a per-element value broadcastable to ``lead`` taken at the elements ``at``."""
    value = np.asarray(value, dtype=float)
    return value if value.ndim == 0 else np.broadcast_to(value, lead)[at]


def _radial_return(sigma_trial, eps_p, s, s_norm, mu, Y, room, at):
    """The flow of :func:`return_map` at the yielded elements ``at`` (an index or Ellipsis):
    ``(eps_p_new, sigma_new, gamma)`` there, from the trial stress, the old plastic strain and the
    trial deviator ``s`` with its norm (all elements)."""
    lead = sigma_trial.shape[:-2]
    s, s_norm, Y, mu = s[at], s_norm[at], _taken_at(Y, lead, at), _taken_at(mu, lead, at)
    # Bridson's notes: gamma chosen so that f(sigma_new) = 0 (radial return for linear isotropy)
    gamma = (s_norm - _SQRT_2_3 * Y) / (2.0 * mu)
    # increment gamma n along the associative flow direction n = df/dsigma = s / |s| (|s| > 0
    # wherever f > 0)
    old = eps_p[at]
    d_eps_p = (gamma / s_norm)[..., None, None] * s
    if room is not None:
        d_eps_p = capped_increment(d_eps_p, _taken_at(room, lead, at))
    new = old + d_eps_p
    mu_per_tensor = mu if mu.ndim == 0 else mu[..., None, None]
    return new, sigma_trial[at] - 2.0 * mu_per_tensor * d_eps_p, gamma


def plastic_dissipation_increment(sigma_new, d_eps_p, volume):
    """Energy dissipated by a plastic increment, ``sum_e V_e sigma_e : d_eps_p_e`` in J.

    ``sigma_new`` (..., 3, 3) Pa is the stress after the return map, ``d_eps_p`` (..., 3, 3) the
    plastic strain increment of the step, ``volume`` (...) m^3. Non-negative for associative flow.
    """
    work_density = np.einsum('...ij,...ij->...', np.asarray(sigma_new, dtype=float),
                             np.asarray(d_eps_p, dtype=float))
    return float(np.sum(work_density * np.asarray(volume, dtype=float)))


# ---------------------------------------------------------------------------------------------
# P1 tetrahedra: shape gradients and the equivalent plastic force
# ---------------------------------------------------------------------------------------------

def tet_shape_gradients(points, tets):
    """Constant shape-function gradients and volumes of P1 tetrahedra.

    Parameters
    ----------
    points : (n, 3) m
        Node positions.
    tets : (t, 4) int
        Node indices of each tetrahedron (either orientation).

    Returns
    -------
    grad_n : (t, 4, 3) 1/m
        ``grad_n[e, a] = grad N_a`` of the linear hat function of local node ``a`` in tet ``e``;
        ``sum_a grad N_a = 0`` and ``sum_a x_a (x) grad N_a = I``.
    volume : (t,) m^3
        Unsigned tet volumes ``|det D| / 6``.
    """
    x = np.asarray(points, dtype=float)[np.asarray(tets)]          # (t, 4, 3)
    # columns of D are the edges x_b - x_0, b = 1..3
    D = np.swapaxes(x[:, 1:, :] - x[:, :1, :], -1, -2)             # (t, 3, 3)
    D_inv = np.linalg.inv(D)
    # grad N_b = row b of D^-1 (b = 1..3); grad N_0 = -sum of the others (partition of unity)
    grad_rest = D_inv                                              # (t, 3, 3), row per node
    grad_n = np.concatenate([-grad_rest.sum(axis=1, keepdims=True), grad_rest], axis=1)
    volume = np.abs(np.linalg.det(D)) / 6.0
    return grad_n, volume


def plastic_element_forces(grad_n, eps_p, mu, lam, volume):
    """Per-element equivalent plastic nodal forces ``V_e (C : eps_p_e) grad N_a``, (t, 4, 3) N.

    ``grad_n`` (t, 4, 3) 1/m and ``volume`` (t,) m^3 from ``tet_shape_gradients``; ``eps_p``
    (t, 3, 3); ``mu``, ``lam`` Pa, scalar or (t,). See ``plastic_nodal_forces`` for the sign.
    """
    sigma_p = isotropic_stress(eps_p, mu, lam)                     # (t, 3, 3)
    return np.asarray(volume, dtype=float)[:, None, None] * np.einsum('eij,eaj->eai', sigma_p,
                                                                       np.asarray(grad_n))


def plastic_nodal_forces(grad_n, eps_p, mu, lam, volume, tets, node_count):
    """Equivalent nodal force of the plastic strain, ``f_p = sum_e V_e B_e^T (C : eps_p_e)``.

    The P1 internal force is ``f_int = -K u + f_p``: the elastic energy
    ``sum_e V_e/2 (eps_e - eps_p_e) : C : (eps_e - eps_p_e)`` differentiated in ``u``. Add ``f_p``
    to the right-hand side next to the external forces; ``K`` (and any factorisation) is unchanged.

    Parameters
    ----------
    grad_n : (t, 4, 3) 1/m
        Shape-function gradients from ``tet_shape_gradients`` (rest configuration).
    eps_p : (t, 3, 3)
        Plastic strain per tet.
    mu, lam : float or (t,) Pa
        Lame parameters.
    volume : (t,) m^3
        Rest volume per tet.
    tets : (t, 4) int
        Node indices, in the same local order as ``grad_n``.
    node_count : int
        Number of nodes ``n``.

    Returns
    -------
    (n, 3) N
        Node forces, entity-first: node ``i`` gets ``sum V_e sigma_p_e @ grad N_a`` over the tets
        ``e`` and local slots ``a`` with ``tets[e, a] == i``. ``f.ravel()`` is node-interleaved
        (``3 i + component``), the order of scikit-fem's ``ElementVector(ElementTetP1())`` dofs.
        Sums to zero force and zero torque on every tet (pure self-equilibrated stress).
    """
    element_forces = plastic_element_forces(grad_n, eps_p, mu, lam, volume)   # (t, 4, 3)
    tets = np.asarray(tets)
    nodal = np.zeros((node_count, 3))
    for component in range(3):   # tiny fixed dimension; bincount is vectorised over tets
        nodal[:, component] = np.bincount(tets.ravel(), weights=element_forces[..., component].ravel(),
                                          minlength=node_count)
    return nodal

