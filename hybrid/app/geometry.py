"""Reading meshes named by scene files: closed surfaces for rigid bodies, tet meshes for FEM bodies.

Any format meshio reads is accepted. Every failure raises :class:`MeshError`, whose message names the
file, so the scene loader can report it as a scene problem instead of a traceback.

Conventions (as in :mod:`rigid.trimesh`): vertices ``(n, 3)`` float64 in m, triangles ``(m, 3)`` and
tets ``(t, 4)`` or ``(t, 10)`` int64, surfaces oriented outward, tets with positive volume.
"""
import contextlib
import functools
import io
import warnings
from pathlib import Path

import meshio
import numpy as np

from fem.mesh import check_shapes, check_tets, index_list
from rigid import trimesh

from .scene.schema import LARGEST_LENGTH

# meshio cell types whose first 3 (triangles) or 4 (quads, tets) nodes are the corners
_TET_TYPES = {"tetra": 1, "tetra10": 2}
_TRIANGLE_TYPES = ("triangle", "triangle6", "triangle7")
_QUAD_TYPES = ("quad", "quad8", "quad9")


class MeshError(Exception):
    """A mesh file that cannot be used; ``path`` is the file, ``reason`` says what is wrong."""

    def __init__(self, path, reason):
        self.path = Path(path)
        self.reason = reason
        super().__init__(f"{path}: {reason}")


class MeshWarning(UserWarning):
    """A mesh file that was usable only after a repair (inverted tets reoriented)."""


@contextlib.contextmanager
def caught_mesh_warnings():
    """Collect the MeshWarning messages raised inside the block into the yielded list (for the
    command line to print as ``warning: ...``); other warnings pass through."""
    messages, caught = [], []
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", MeshWarning)
            yield messages
    finally:
        # passed on once the block has ended: inside it the recorder is the warning printer, and
        # passing one on appended it to the list being read, forever (a hang on any STL file)
        for w in caught:
            if issubclass(w.category, MeshWarning):
                if str(w.message) not in messages:     # (a surface read by several builders)
                    messages.append(str(w.message))
            else:
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)


def read_mesh(path):
    """Read ``path`` with meshio; MeshError if it is missing or unreadable."""
    path = Path(path)
    if not path.exists():
        raise MeshError(path, "file not found")
    if not path.is_file():
        raise MeshError(path, "not a regular file")
    if path.stat().st_size == 0:        # (meshio: "need at least one array to concatenate")
        raise MeshError(path, "the file is empty")
    printed = io.StringIO()
    try:
        # meshio prints reader errors to stdout, then calls sys.exit(1) when every reader failed
        # and warns on files it reads correctly (its STL reader overflows trying the binary layout)
        with contextlib.redirect_stdout(printed), contextlib.redirect_stderr(printed), \
                warnings.catch_warnings():
            warnings.simplefilter("ignore")
            mesh = meshio.read(path)
    # format readers raise anything from ReadError to IndexError on corrupt input
    except (Exception, SystemExit) as error:  # noqa: BLE001
        lines = [line.strip() for line in (str(error), printed.getvalue()) if line.strip()]
        lines = [line for line in lines if line not in ("0", "1")]
        detail = lines[0].splitlines()[0] if lines else "unknown format or corrupt file"
        if detail == "need at least one array to concatenate":     # (meshio, of an empty mesh)
            raise MeshError(path, "the file holds no points or cells") from None
        raise MeshError(path, f"cannot read mesh ({detail})") from None
    points = np.asarray(mesh.points, dtype=float)
    if points.size == 0:
        raise MeshError(path, "the file holds no points")
    if points.ndim != 2 or points.shape[1] not in (2, 3):
        raise MeshError(path, f"points have shape {points.shape}, expected (n, 3)")
    if points.shape[1] == 2:
        points = np.column_stack([points, np.zeros(len(points))])
    if not np.all(np.isfinite(points)):
        raise MeshError(path, "point coordinates are not all finite")
    span = float(np.ptp(points, axis=0).max()) if len(points) else 0.0
    if span > LARGEST_LENGTH:        # a unit mistake (volumes overflow from about 1e60 m)
        raise MeshError(path, f"the points span {span:.3g} m; at most {LARGEST_LENGTH:g} m is allowed "
                              f"(check the file's units)")
    mesh.points = points
    return mesh


def tets_from_mesh(mesh, path, solved=True):
    """``(points, tets, order, flipped)`` from a meshio mesh: all its tetra (order 1) or tetra10
    (order 2) cells, in file order.

    Points no tet uses are dropped; tets with negative volume are reoriented and their indices
    returned in ``flipped``; MeshError if there are no tets, both orders are mixed, or tets have
    zero volume, or (``solved``: the tets of a deformable body) are too badly shaped to solve
    (``fem.mesh.check_shapes``); the message names them by index.
    """
    blocks = {kind: [c.data for c in mesh.cells if c.type == kind] for kind in _TET_TYPES}
    present = [kind for kind in _TET_TYPES if blocks[kind]]
    if not present:
        raise MeshError(path, f"no tetra or tetra10 cells (found: {_cell_summary(mesh)})")
    if len(present) > 1:
        raise MeshError(path, "mixes tetra and tetra10 cells; use one element order")
    kind = present[0]
    order = _TET_TYPES[kind]
    tets = _node_indices(np.concatenate(blocks[kind]), len(mesh.points), kind, path)
    used = np.unique(tets)
    remap = -np.ones(len(mesh.points), dtype=np.int64)
    remap[used] = np.arange(len(used))
    points, tets = mesh.points[used], remap[tets]
    try:
        tets, flipped = check_tets(points, tets)
        if solved:
            check_shapes(points, tets)
    except ValueError as error:
        raise MeshError(path, str(error)) from None
    return points, tets, order, flipped


def surface_from_mesh(mesh, path):
    """Closed outward surface ``(vertices, triangles)`` of a meshio mesh.

    Tet cells (tetra, tetra10) give their boundary faces (corner nodes only) and any surface cells
    beside them are ignored (mesh generators often store the boundary too). Without tets, triangle
    cells are used as they are and quads are split in two. MeshError when there is nothing usable,
    the surface is not closed or not consistently oriented, or it encloses no volume.
    """
    if any(c.type in _TET_TYPES for c in mesh.cells):
        points, tets, _, _ = tets_from_mesh(mesh, path, solved=False)   # (its surface only)
        triangles = trimesh.tet_boundary(tets[:, :4])
    else:
        points = mesh.points
        parts = [c.data[:, :3] for c in mesh.cells if c.type in _TRIANGLE_TYPES]
        parts += [c.data[:, [0, 1, 2, 0, 2, 3]].reshape(-1, 3) for c in mesh.cells if c.type in _QUAD_TYPES]
        if not parts:
            raise MeshError(path, f"no triangle, quad or tetra cells (found: {_cell_summary(mesh)})")
        triangles = _node_indices(np.concatenate(parts), len(points), "surface", path)
        if not trimesh.is_closed(triangles):
            # corners written once per triangle (a "triangle soup"): joined where they coincide
            points, triangles, _ = trimesh.merge_coincident(points, triangles)
            triangles = triangles[(triangles[:, 0] != triangles[:, 1]) & (triangles[:, 1] != triangles[:, 2])
                                  & (triangles[:, 2] != triangles[:, 0])]
    vertices, triangles, _ = trimesh.compact(points, triangles)
    _check_closed(triangles, path)
    triangles = trimesh.orient_shells(vertices, triangles)      # a cavity's wall facing into it
    crossing = trimesh.crossing_pieces(vertices, triangles)
    if crossing:
        warnings.warn(f"{path}: {len({min(p) for p in crossing} | {max(p) for p in crossing})} pieces of the "
                      f"surface cross each other: the volume where they overlap counts twice in the "
                      f"body's mass and inertia (join them into one closed surface)", MeshWarning, stacklevel=3)
    scale = np.ptp(vertices, axis=0).max()
    if trimesh.signed_volume(vertices, triangles) <= 1e-12 * scale ** 3:
        raise MeshError(path, "surface encloses zero volume")
    return vertices, triangles


def load_surface(path):
    """Closed outward triangle surface ``(vertices (n, 3) m, triangles (m, 3))`` for a rigid body.

    Reads any format meshio reads; see :func:`surface_from_mesh` for which cells are used.
    Raises MeshError naming the file when the file is missing or unreadable, or the surface unusable.
    A file read before (unchanged since: same size and modification time) is not read again,
    and its warnings are given again (200 bodies of one file read it 400 times, 20 s of a build).
    """
    try:
        stat = Path(path).stat()
        key = (str(Path(path).resolve()), stat.st_mtime_ns, stat.st_size)
    except OSError:                     # (read_mesh says what is wrong with it)
        key = None
    if key is None:
        return _read_surface(path)[:2]
    vertices, triangles, said = _cached_surface(*key, str(path))
    for message in said:
        warnings.warn(message, MeshWarning, stacklevel=2)
    return vertices.copy(), triangles.copy()


@functools.lru_cache(maxsize=8)
def _cached_surface(_resolved, _modified, _size, path):
    """:func:`_read_surface` of ``path``, kept by its resolved path, modification time and size."""
    return _read_surface(path)


def _read_surface(path):
    """``(vertices, triangles, warnings' messages)`` of the surface file ``path``."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", MeshWarning)
        mesh = read_mesh(path)
        vertices, triangles = surface_from_mesh(mesh, Path(path))
        _large(vertices, path)
    said = tuple(str(w.message) for w in caught if issubclass(w.category, MeshWarning))
    for w in caught:
        if not issubclass(w.category, MeshWarning):
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return vertices, triangles, said


# a mesh spanning more than this (m) is said to be large: its units may be millimetres
LARGE_MESH = 100.0


def units_hint(bodies, name):
    """What to add to a message about where scene body ``name`` (of ``bodies``) lies when it is a
    mesh file's: the file's units may be millimetres (a 50 mm part so written reads 50 m across)."""
    if all(getattr(b, "mesh", None) is None for b in bodies if b.name == name):
        return ""
    return " (a mesh file is read in metres: one written in millimetres reads 1000 times too large)"


def _large(points, path):
    """A :class:`MeshWarning` for a mesh spanning more than LARGE_MESH metres."""
    span = float(np.ptp(points, axis=0).max()) if len(points) else 0.0
    if span > LARGE_MESH:
        warnings.warn(f"{path}: the mesh spans {span:.3g} m (meshes are read in metres; one written "
                      f"in millimetres reads 1000 times too large: check the file's units)",
                      MeshWarning, stacklevel=3)


def load_tet_mesh(path):
    """Tet mesh ``(points (n, 3) m, tets (t, 4|10), order 1|2)`` for an FEM body.

    tetra cells give order 1, tetra10 cells order 2. Inverted tets are reoriented with a
    :class:`MeshWarning` naming them by index. Raises MeshError naming the file when the file is
    missing or unreadable, has no tet cells, or has degenerate tets.
    """
    mesh = read_mesh(path)
    points, tets, order, flipped = tets_from_mesh(mesh, Path(path))
    _large(points, path)            # (the nodes the tets use: a stray node does not count)
    if len(flipped):
        warnings.warn(f"{path}: {len(flipped)} of {len(tets)} tets were inverted (negative volume) "
                      f"and have been reoriented: {index_list(flipped)}", MeshWarning, stacklevel=2)
    pieces, largest = _pieces(tets, len(points))
    doubled = trimesh.merge_coincident(points, tets[:, :4])[2]
    if pieces > 1:
        warnings.warn(f"{path}: its tets form {pieces} pieces that share no node (the largest has "
                      f"{largest} of {len(tets)} tets); the pieces of one FEM body move apart as if "
                      f"separate bodies" + (f" ({doubled} nodes lie on others: merge them to join "
                      f"the pieces)" if doubled else ""), MeshWarning, stacklevel=2)
    elif doubled:       # one piece, but tets that meet at such a node are not joined there
        warnings.warn(f"{path}: {doubled} of its nodes lie on others, so the tets on either side "
                      f"of them are not joined there (a slit inside the body, which opens under "
                      f"load): merge them", MeshWarning, stacklevel=2)
    return points, tets, order


def _pieces(tets, node_count):
    """``(pieces, tets of the largest)``: the tets' groups joined through shared nodes."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    rows = np.repeat(tets[:, 0], tets.shape[1])
    graph = coo_matrix((np.ones(len(rows)), (rows, tets.ravel())), shape=(node_count, node_count))
    count, label = connected_components(graph, directed=False)
    return count, int(np.bincount(label[tets[:, 0]]).max())


def _check_closed(triangles, path):
    """MeshError unless every edge joins exactly two triangles traversing it in opposite directions."""
    if len(triangles) < 4:
        raise MeshError(path, f"surface is not closed: only {len(triangles)} triangles")
    counts, same_direction = trimesh.edge_use_counts(triangles)
    boundary = int(np.sum(counts == 1))
    non_manifold = int(np.sum(counts > 2))
    if boundary or non_manifold:
        raise MeshError(path, f"surface is not closed: {boundary} boundary edges, "
                              f"{non_manifold} non-manifold edges")
    if same_direction:
        raise MeshError(path, f"surface is not consistently oriented: {same_direction} edges are "
                              "traversed twice in the same direction")


def _node_indices(cells, point_count, kind, path):
    """``cells`` as int64 node indices; MeshError if any names no point of the file."""
    cells = np.asarray(cells).astype(np.int64)
    bad = (cells < 0) | (cells >= point_count)
    if np.any(bad):
        raise MeshError(path, f"{int(np.any(bad, axis=1).sum())} {kind} cells name nodes that do not "
                              f"exist (indices must be 0 to {point_count - 1}, found "
                              f"{int(cells[bad][0])})")
    return cells


def _cell_summary(mesh):
    kinds = sorted({c.type for c in mesh.cells})
    return ", ".join(kinds) if kinds else "no cells"
