"""Stiffness and mass assembly with scikit-fem, plus per-element data for warping and stress.

Degrees of freedom are node-major, ``dof = 3 * node + component``, matching ``(n, 3)`` arrays
flattened in C order. scikit-fem numbers its own DOFs (component-first within a node, vertices
before edges); the permutation between the two is built once here and nowhere else.
"""
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np
import scipy.sparse as sp
import skfem
from skfem.models.elasticity import lame_parameters, linear_elasticity


@dataclass(frozen=True)
class ElementData:
    """Static per-element arrays (rest configuration), entity-first.

    tet_nodes: ``(t, b)`` node indices of each element in scikit-fem's local basis order
        (b = 4 for P1, 10 for P2; vertices first, then edges 01, 12, 02, 03, 13, 23).
    tet_gradients: ``(t, q, b, 3)`` gradients of the scalar shape functions at the quadrature
        points (1/m).
    tet_weights: ``(t, q)`` quadrature weights times |J| (m^3); they sum to the element volume.
    tet_volume: ``(t,)`` rest volume (m^3).
    tet_rest_inverse: ``(t, 3, 3)`` inverse of the rest edge matrix ``[X1-X0, X2-X0, X3-X0]``
        (1/m), so the deformation gradient of the vertex simplex is ``F = Ds @ tet_rest_inverse``.
    tet_stiffness: ``(t, 3b, 3b)`` element stiffness blocks (N/m), local DOF ``3 a + i``.
    pattern_rows, pattern_cols: ``(nnz,)`` CSR pattern (row indices, column indices) of the
        assembled stiffness, node-major DOFs.
    pattern_indptr: ``(3 n + 1,)`` CSR row pointer of that pattern.
    block_to_csr: ``(t * 9 b^2,)`` position in the CSR data of each entry of ``tet_stiffness``
        (flattened), so a warped stiffness is assembled with one ``np.bincount``.
    lame: ``(mu, lam)`` Pa, the Lame parameters ``tet_stiffness`` was built with (:func:`_element_stiffness`):
        linear elements warp their stiffness and forces from their gradients with them (None: from
        ``tet_stiffness``).
    """
    tet_nodes: np.ndarray
    tet_gradients: np.ndarray
    tet_weights: np.ndarray
    tet_volume: np.ndarray
    tet_rest_inverse: np.ndarray
    tet_stiffness: np.ndarray
    pattern_rows: np.ndarray
    pattern_cols: np.ndarray
    pattern_indptr: np.ndarray
    block_to_csr: np.ndarray
    lame: tuple | None = None


def _skfem_mesh(points, tets):
    """scikit-fem mesh on the vertex nodes; returns (mesh, vertex_node_ids)."""
    vertex_nodes = np.unique(tets[:, :4])
    remap = -np.ones(len(points), dtype=np.int64)
    remap[vertex_nodes] = np.arange(len(vertex_nodes))
    mesh = skfem.MeshTet(np.ascontiguousarray(points[vertex_nodes].T),
                         np.ascontiguousarray(remap[tets[:, :4]].T))
    return mesh, vertex_nodes


def _scalar_dof_to_node(basis, mesh, vertex_nodes, tets):
    """Node index ``(N,)`` of each scalar scikit-fem DOF."""
    node = np.empty(basis.N, dtype=np.int64)
    node[basis.nodal_dofs[0]] = vertex_nodes
    if tets.shape[1] == 10:
        # our midside node of each vertex pair, looked up by a sorted pair key
        local = np.array([[0, 1], [1, 2], [0, 2], [0, 3], [1, 3], [2, 3]])
        pairs = np.sort(tets[:, local], axis=2).reshape(-1, 2)
        n = len(tets) and int(tets.max()) + 1
        keys, first = np.unique(pairs[:, 0] * n + pairs[:, 1], return_index=True)
        mids = tets[:, 4:].reshape(-1)[first]
        sk_pairs = np.sort(vertex_nodes[mesh.edges], axis=0)
        pos = np.searchsorted(keys, sk_pairs[0] * n + sk_pairs[1])
        node[basis.edge_dofs[0]] = mids[pos]
    return node


def _element_stiffness(grads, weights, mu, lam):
    """Ke[a i, b j] = sum_q w (mu (d_ij ga.gb + ga_j gb_i) + lam ga_i gb_j); (t, 3b, 3b) N/m."""
    t, q, b, _ = grads.shape
    gg = np.einsum("tq,tqak,tqbk->tab", weights, grads, grads)
    outer = np.einsum("tq,tqai,tqbj->taibj", weights, grads, grads)
    Ke = mu * np.einsum("tab,ij->taibj", gg, np.eye(3))
    Ke += mu * outer.transpose(0, 1, 4, 3, 2) + lam * outer
    return Ke.reshape(t, 3 * b, 3 * b)


def _csr_pattern(tet_nodes, dof_count):
    """CSR pattern of element blocks and the map from block entries to CSR data positions.

    Found on node pairs (b^2 per element, sorted once) and spread to their 3 x 3 DOF blocks: a
    node pair (r, c) at place m of node row r's k_r columns holds DOF (3r+i, 3c+j) at CSR place
    ``9 start_r + 3 k_r i + 3 m + j``, start_r the node pairs in the rows before r (the same
    pattern as sorting every DOF pair, nine times fewer keys to sort)."""
    t, b = tet_nodes.shape
    n = dof_count // 3
    rows = np.repeat(tet_nodes, b, axis=1).ravel()
    cols = np.tile(tet_nodes, (1, b)).ravel()
    keys, pair_of_entry = np.unique(rows * n + cols, return_inverse=True)
    pair_row, pair_col = keys // n, keys % n
    count = np.bincount(pair_row, minlength=n)
    start = np.concatenate([[0], np.cumsum(count)])
    place = np.arange(len(keys)) - start[pair_row]                       # m of each pair
    i, j = np.arange(3)[:, None], np.arange(3)[None, :]
    # (pairs, 3, 3) CSR place of DOF (3r+i, 3c+j)
    csr = (9 * start[pair_row] + 3 * place)[:, None, None] + 3 * count[pair_row][:, None, None] * i + j
    pattern_rows = np.empty(9 * len(keys), dtype=np.int64)
    pattern_cols = np.empty(9 * len(keys), dtype=np.int64)
    pattern_rows[csr] = (3 * pair_row[:, None, None] + i).repeat(3, axis=2)
    pattern_cols[csr] = (3 * pair_col[:, None, None] + j).repeat(3, axis=1)
    indptr = np.empty(dof_count + 1, dtype=np.int64)
    indptr[:-1] = (9 * start[:-1, None] + 3 * count[:, None] * np.arange(3)).ravel()
    indptr[-1] = 9 * start[-1]
    # block entry (e, 3a+i, 3c+j) of node pair (e, a, c)
    block = csr[pair_of_entry.reshape(t, b, b)]                          # (t, b, b, 3, 3)
    return pattern_rows, pattern_cols, indptr, block.transpose(0, 1, 3, 2, 4).ravel()


def assemble_from_blocks(data, blocks, dof_count):
    """CSR matrix ``(3n, 3n)`` summing per-element blocks ``(t, 3b, 3b)`` with the precomputed pattern."""
    values = np.bincount(data.block_to_csr, weights=blocks.ravel(), minlength=len(data.pattern_cols))
    return sp.csr_matrix((values, data.pattern_cols, data.pattern_indptr), shape=(dof_count, dof_count))


def assemble(points, tets, young, poisson, density):
    """Assemble a tet mesh with scikit-fem.

    points ``(n, 3)`` m; tets ``(t, 4)`` (P1) or ``(t, 10)`` (P2, tetra10 order); young Pa;
    poisson; density kg/m^3. Returns ``(K, M_scalar, element_data)``: stiffness ``(3n, 3n)`` N/m
    (CSR, node-major DOFs), consistent scalar mass ``(n, n)`` kg (CSR; the vector mass is
    ``kron(M_scalar, I3)``) and :class:`ElementData`. P2 geometry is affine (midside nodes are
    assumed at edge midpoints).
    """
    points = np.asarray(points, dtype=float)
    tets = np.asarray(tets, dtype=np.int64)
    n = len(points)
    order = 1 if tets.shape[1] == 4 else 2
    mesh, vertex_nodes = _skfem_mesh(points, tets)
    element = skfem.ElementTetP1() if order == 1 else skfem.ElementTetP2()
    # P1 gradients are constant: one point integrates stiffness exactly
    stiff_basis = skfem.Basis(mesh, skfem.ElementVector(element), intorder=2 * (order - 1) or 1)
    scalar_basis = skfem.Basis(mesh, element, intorder=2 * (order - 1) or 1)
    mass_basis = skfem.Basis(mesh, element, intorder=2 * order)
    mu, lam = lame_parameters(young, poisson)[1], lame_parameters(young, poisson)[0]

    node_of_scalar = _scalar_dof_to_node(scalar_basis, mesh, vertex_nodes, tets)
    # vector DOF k of scikit-fem: node of its scalar DOF, component from its row in the dof arrays
    vec_node = np.empty(stiff_basis.N, dtype=np.int64)
    vec_comp = np.empty(stiff_basis.N, dtype=np.int64)
    for dofs, scalar in [(stiff_basis.nodal_dofs, scalar_basis.nodal_dofs)] + (
            [(stiff_basis.edge_dofs, scalar_basis.edge_dofs)] if order == 2 else []):
        for comp in range(3):
            vec_node[dofs[comp]] = node_of_scalar[scalar[0]]
            vec_comp[dofs[comp]] = comp
    ours = 3 * vec_node + vec_comp
    P = sp.csr_matrix((np.ones(len(ours)), (ours, np.arange(len(ours)))), shape=(3 * n, stiff_basis.N))
    K_sk = skfem.asm(linear_elasticity(lam, mu), stiff_basis)
    K = (P @ K_sk @ P.T).tocsr()

    @skfem.BilinearForm
    def mass(u, v, w):
        return density * u * v

    Ps = sp.csr_matrix((np.ones(mass_basis.N), (node_of_scalar, np.arange(mass_basis.N))),
                       shape=(n, mass_basis.N))
    M_scalar = (Ps @ skfem.asm(mass, mass_basis) @ Ps.T).tocsr()

    # per-element data in our node numbering
    # (C order, as every later mesh's: a Fortran-ordered copy of the first made the compiled
    # kernels taking it compile again, in the step loop, for the first fracture piece)
    tet_nodes = np.ascontiguousarray(node_of_scalar[scalar_basis.element_dofs.T])
    grads = np.stack([scalar_basis.basis[a][0].grad for a in range(tet_nodes.shape[1])])
    grads = grads.transpose(2, 3, 0, 1)  # (b, 3, t, q) -> (t, q, b, 3)
    weights = np.asarray(scalar_basis.dx)
    X = points[tets[:, :4]]
    Ke = _element_stiffness(grads, weights, mu, lam)
    pattern = _csr_pattern(tet_nodes, 3 * n)
    data = ElementData(
        tet_nodes=tet_nodes, tet_gradients=grads, tet_weights=weights, tet_volume=weights.sum(axis=1),
        tet_rest_inverse=np.linalg.inv((X[:, 1:] - X[:, :1]).transpose(0, 2, 1)), tet_stiffness=Ke,
        pattern_rows=pattern[0], pattern_cols=pattern[1], pattern_indptr=pattern[2],
        block_to_csr=pattern[3], lame=(float(mu), float(lam)))
    return K, M_scalar, data


@lru_cache(maxsize=None)
def _unit_mass(order):
    """Element mass of unit density over unit volume ``(b, b)``, scikit-fem's local basis order:
    its mass matrix on one reference tet divided by that tet's volume (affine elements, so every
    element's mass is its volume times this)."""
    mesh = skfem.MeshTet(np.array([[0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0],
                                   [0.0, 0.0, 0.0, 1.0]]), np.array([[0], [1], [2], [3]]))
    element = skfem.ElementTetP1() if order == 1 else skfem.ElementTetP2()
    basis = skfem.Basis(mesh, element, intorder=2 * order)

    @skfem.BilinearForm
    def mass(u, v, w):
        return u * v

    dofs = basis.element_dofs[:, 0]
    return 6.0 * skfem.asm(mass, basis).toarray()[np.ix_(dofs, dofs)]


def assemble_subset(data, parent_tets, tet_index, tets, density):
    """What :func:`assemble` returns for some elements of a mesh assembled before, from that
    mesh's element data alone (no scikit-fem assembly): a fracture piece's matrices.

    data: :class:`ElementData` of the assembled mesh, whose tets are ``parent_tets`` ``(T, b)``.
    tet_index: ``(t,)`` the elements kept. tets: ``(t, b)`` those elements' rows (same slots) in
    the new node numbering ``0 .. n-1`` (every node used). density: kg/m^3.
    Element blocks, gradients, weights and rest inverses are the kept elements'; stiffness is
    their blocks summed, the consistent mass each element's volume times the unit element mass.
    Returns ``(K, M_scalar, element_data)`` as :func:`assemble` does, equal to its result on the
    new mesh up to round-off (element nodes keep the old mesh's local order).
    """
    tet_index = np.asarray(tet_index, dtype=np.int64)
    tets = np.asarray(tets, dtype=np.int64)
    n = int(tets.max()) + 1 if tets.size else 0
    old_nodes = data.tet_nodes[tet_index]
    # slot of each element node in the element's row of tets (tet_nodes is a permutation of it)
    slot = np.argmax(old_nodes[:, :, None] == np.asarray(parent_tets)[tet_index][:, None, :], axis=2)
    tet_nodes = np.take_along_axis(tets, slot, axis=1)
    rows, cols, indptr, block_to_csr = _csr_pattern(tet_nodes, 3 * n)
    elements = replace(data, tet_nodes=tet_nodes, tet_gradients=data.tet_gradients[tet_index],
                       tet_weights=data.tet_weights[tet_index],
                       tet_volume=data.tet_volume[tet_index],
                       tet_rest_inverse=data.tet_rest_inverse[tet_index],
                       tet_stiffness=data.tet_stiffness[tet_index], pattern_rows=rows,
                       pattern_cols=cols, pattern_indptr=indptr, block_to_csr=block_to_csr)
    K = assemble_from_blocks(elements, elements.tet_stiffness, 3 * n)
    K.eliminate_zeros()     # as the scikit-fem product leaves it
    b = tet_nodes.shape[1]
    mass = (density * elements.tet_volume)[:, None, None] * _unit_mass(1 if b == 4 else 2)
    M_scalar = sp.csr_matrix((mass.ravel(), (np.repeat(tet_nodes, b, axis=1).ravel(),
                                             np.tile(tet_nodes, (1, b)).ravel())), shape=(n, n))
    return K, M_scalar, elements


