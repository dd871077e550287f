"""What a run reports about its state: frame geometry, per-body rows, conserved quantities."""
import numpy as np

from fem import dynamics as fem_dyn
from rigid import quaternion as quat
from rigid.model import FORCE_LIKE, posed_by_orientation
from rigid.step_kernels import body_report

from hybrid.coupling.switch import fem_state

from .output import FramePiece
from .peaks import element_strains, principal_stress_of_strains
from .vtu import Deferred


def tet_fields(fem_model, fem_state, deferred=False):
    """Per-tet fields of an FEM body: ``von_mises`` and ``principal_stress`` (largest principal
    stress, Pa) of the element stress, ``plastic_strain`` (accumulated equivalent plastic strain,
    the element's largest over its points; 0.0 without plasticity) and ``yielded`` (0/1).
    ``deferred``: ``principal_stress`` as a :class:`hybrid.app.vtu.Deferred` of the strain rows,
    computed by the run's writer (the batched eigenvalues are most of a frame's fields' time)."""
    e, vm, _, _ = element_strains(fem_model, fem_state)
    strains = (e, float(fem_model.mu), float(fem_model.lam))
    principal = (Deferred(principal_stress_of_strains, strains, rows=len(e)) if deferred
                 else principal_stress_of_strains(*strains))
    fields = {"von_mises": vm, "principal_stress": principal,
              "plastic_strain": 0.0, "yielded": 0}
    if fem_state.tet_peeq is not None:
        fields["plastic_strain"] = fem_state.tet_peeq.max(axis=1)
        fields["yielded"] = fem_state.tet_yielded.astype(np.int8)
    return fields


def _tet_piece(body_id, m, s):
    """The FramePiece of an FEM body (model ``m``, state ``s``): its tets with their fields."""
    cell = "tetra10" if m.order == 2 else "tetra"
    cell_data = tet_fields(m, s, deferred=True) | {"deformable": np.int8(1)}   # rigid bodies' cells: 0
    if m.cache.frame_cells is None:
        m.cache.frame_cells = np.array(m.tets, dtype=np.int64)
        m.cache.frame_cells.flags.writeable = False
    return FramePiece(body_id, s.x, [(cell, m.cache.frame_cells)], cell_data=cell_data,
                      point_data={"displacement": s.x - m.rest_points, "velocity": s.v})


def fem_states(model, state):
    """``(body id, FemModel, FemState)`` of every FEM body and every auto body stepped as rigid
    now (its parked shape carried by the rigid motion, its fields as they were when it became
    rigid), so an auto body is always written as its tet mesh."""
    out = [(int(k), m, s) for k, m, s in zip(model.fem_ids, model.fem, state.fem)]
    for i, k in enumerate(model.rigid_ids):
        parked = model.parked.get(int(k))
        if parked is not None:
            out.append((int(k), parked.fem, fem_state(parked, model.rigid, state.rigid, i,
                                                      model.gravity)))
    return out


def frame_pieces(model, state):
    """The frame's FramePieces, in body order: FEM tet meshes (auto bodies as tet meshes however
    they are stepped) one body each, and rigid surfaces in world coordinates, each run of rigid
    bodies between FEM ones as one piece (ids per cell: one check and one hand-over for a
    thousand boxes, not a thousand)."""
    # the original scene body each piece came from (itself unless it is a fracture fragment)
    origin = model.fragment_of if model.fragment_of is not None else range(len(model.names))
    pieces = [_tet_piece(k, m, s) for k, m, s in fem_states(model, state)]
    for piece in pieces:
        piece.cell_data["fragment_of"] = np.int64(origin[piece.body_id])
    if model.rigid.body_count:
        rs = state.rigid
        for vertices, vertex_body, triangles, cell_id, fragment_of in _rigid_runs(model, pieces, origin):
            # the writer poses the surfaces: a frame hands over the poses, and the surfaces once
            points = Deferred(posed_by_orientation, (vertices, vertex_body, rs.position, rs.orientation),
                              (3,), len(vertices))
            pieces.append(FramePiece(cell_id, points, [("triangle", triangles)],
                                     cell_data={"fragment_of": fragment_of}))
    pieces.sort(key=lambda p: int(np.min(p.body_id)))
    return pieces


def _rigid_runs(model, fem_pieces, origin):
    """The rigid bodies' surfaces in runs of bodies with no FEM piece between them (by scene
    index; parked auto bodies are FEM pieces): per run ``(vertices (n, 3) body frame, their rigid
    body (n,), triangles (t, 3) into them, each triangle's scene index and fragment_of (t,))``,
    read-only, built once per model and set of FEM pieces (``model.cache.rigid_frames``).
    ``origin``: the scene body each body came from, by scene index."""
    written = tuple(p.body_id for p in fem_pieces)
    memo = model.cache.rigid_frames
    if memo is not None and memo[0] == written:
        return memo[1]
    rm, ids = model.rigid, [int(k) for k in model.rigid_ids]
    rigid = sorted((k, i) for i, k in enumerate(ids) if k not in model.parked)
    run_of = np.searchsorted(np.sort(np.asarray(written, dtype=np.int64)), [k for k, _ in rigid])
    runs = {}
    for (k, i), run in zip(rigid, run_of.tolist()):
        runs.setdefault(run, []).append((k, i))
    out = []
    for members in runs.values():
        counts = [len(rm.surface_vertices[i]) for _, i in members]
        start = np.cumsum([0] + counts[:-1])
        sizes = [len(rm.surface_triangles[i]) for _, i in members]
        arrays = (np.concatenate([rm.surface_vertices[i] for _, i in members]).astype(float),
                  np.repeat([i for _, i in members], counts).astype(np.int64),
                  np.concatenate([np.asarray(rm.surface_triangles[i], np.int64) + s
                                  for (_, i), s in zip(members, start)]),
                  np.repeat([k for k, _ in members], sizes).astype(np.int64),
                  np.repeat([origin[k] for k, _ in members], sizes).astype(np.int64))
        for a in arrays:
            a.flags.writeable = False
        out.append(arrays)
    model.cache.rigid_frames = (written, out)
    return out


def rigid_table(model, state):
    """Every rigid body's report (b, 14) at the state's time, from one compiled pass
    (rigid.step_kernels.body_report): centre of mass (3), orientation of its shape frame (4),
    velocity (3, rigid.model.reported_velocity), angular velocity (3), kinetic energy (J)."""
    rm, rs = model.rigid, state.rigid
    return body_report(rs.position, rs.orientation, rs.velocity, rs.angular_momentum,
                       rs.contact_dv, rm.body_fixed, rm.body_mass, rm.body_inv_inertia,
                       rm.shape_rotation, np.asarray(model.gravity, float), float(rs.last_dt),
                       FORCE_LIKE)


def body_rows(model, state, only=None):
    """Rows ``time,body,x,y,z,qw,qx,qy,qz,vx,vy,vz,wx,wy,wz,kinetic_energy,model`` in scene
    order; ``model`` is how the body was stepped (``rigid`` or ``fem``). ``only``: the scene
    index of the one body whose row to make (``Simulation.body``: making all 404 rows of a pile
    for one took 0.7 ms).

    Rigid: centre of mass, orientation of the body's own frame, velocity at the frame's time; an
    auto body stepped as rigid: the orientation its FEM row would give (continuous across switches).
    FEM: centre of mass, its scene orientation turned by its best-fit rotation (shape matching),
    momentum / mass, and the angular
    velocity I^-1 L of the node cloud about its centre of mass.
    """
    rows = {}
    t = float(state.time)
    ids = [int(k) for k in model.rigid_ids]
    if model.rigid.body_count and (only is None or only in ids):
        table = rigid_table(model, state)
        for k in model.parked:
            if only is None or k == only:
                i = ids.index(k)
                table[i, 3:7] = _parked_orientation(model, state, i, k)
        if only is not None:
            table, ids = table[[ids.index(only)]], [only]
        # one conversion of the whole table to Python floats (not one per value)
        table = table.tolist()
        rows = {k: (t, model.names[k], *values, "rigid") for k, values in zip(ids, table)}
    for j, (m, s) in enumerate(zip(model.fem, state.fem)):
        if only is not None and model.fem_ids[j] != only:
            continue
        weights = fem_dyn.mass_weights(m)          # with the body's own mass matrix
        mass = weights.sum()
        com = weights @ s.x / mass
        p = weights @ s.v
        I, L = fem_dyn.mass_moments(m, s.x - com, s.v)
        w = np.linalg.solve(I, L)
        # the body was placed at its scene orientation, and the best-fit rotation turns it from there
        placed = model.scene.bodies[model.fem_ids[j]].orientation
        q = quat.from_matrix(s.R @ quat.to_matrix(np.asarray(placed, float)))
        ke = fem_dyn.kinetic_energy(m, s)
        values = np.concatenate([com, q, p / mass, w, [ke]]).tolist()
        rows[int(model.fem_ids[j])] = (t, model.names[model.fem_ids[j]], *values, "fem")
    return [rows[k] for k in sorted(rows)]


def _parked_orientation(model, state, i, k):
    """Orientation (4,) of rigid auto body ``i`` (scene index ``k``) as its FEM row gives it: its
    scene orientation turned by its best-fit rotation, carried by the rigid rotation since."""
    parked = model.parked[k]
    turn = quat.to_matrix(state.rigid.orientation[i]) @ parked.rotation.T
    placed = quat.to_matrix(np.asarray(model.scene.bodies[k].orientation, float))
    return quat.from_matrix(turn @ parked.state.R @ placed)


def region_rows(model, state):
    """Rows ``time,body,region,fx,fy,fz,ux,uy,uz`` for every anchor and load region."""
    from fem.stress import region_table
    if not any(m.region_names for m in model.fem) and not any(p.fem.region_names for p in model.parked.values()):
        return []                   # (no body has regions: no states posed for none)
    out = []
    for k, m, s in fem_states(model, state):
        for name, *values in region_table(m, s):
            out.append((state.time, model.names[k], name, *values))
    return out


def plastic_dissipation(model, state):
    """Plastic work dissipated by all FEM bodies since the start (J), auto bodies stepped as rigid
    now included (as it was when they became rigid); 0 without plastic bodies."""
    return float(sum(s.plastic_dissipation for s in state.fem)
                 + sum(p.state.plastic_dissipation for p in model.parked.values()))


def momentum_scales(model, state):
    """How much momentum the bodies carry, without the cancellations of the totals: the sums of
    |p| (kg m/s) and of |x x p| plus |spin| (kg m^2/s) over bodies and nodes, a rigid body's
    also with |p| times its radius (the angular momentum its momentum carries at its own size).
    Two bodies meeting head-on have no total angular momentum, nor has a ball falling through the
    origin: a drift is measured against these instead (against the ball's round-off, 1e-19, its
    drift read 0.99)."""
    linear, angular = 0.0, 0.0
    rm, rs = model.rigid, state.rigid
    if rm.body_count:
        free = ~rm.body_fixed
        p = np.where(free, rm.body_mass, 0.0)[:, None] * rigid_table(model, state)[:, 7:10]
        linear += float(np.linalg.norm(p, axis=1).sum())
        angular += float(np.linalg.norm(np.cross(rs.position, p), axis=1).sum()
                         + np.linalg.norm(np.where(free[:, None], rs.angular_momentum, 0.0), axis=1).sum()
                         + (np.linalg.norm(p, axis=1) * rm.body_radius).sum())
    for mm, s in zip(model.fem, state.fem):
        p = (mm.M @ s.v.ravel()).reshape(-1, 3)
        linear += float(np.linalg.norm(p, axis=1).sum())
        angular += float(np.linalg.norm(np.cross(s.x, p), axis=1).sum())
    return linear, angular


def body_energies(model, state):
    """Per body (by name) its kinetic energy, plus its elastic energy for an FEM body (J)."""
    out = {}
    if model.rigid.body_count:
        ke = rigid_table(model, state)[:, 13]
        out = {model.names[k]: float(e) for k, e in zip(model.rigid_ids, ke)}
    for k, m, s in zip(model.fem_ids, model.fem, state.fem):
        out[model.names[k]] = fem_dyn.kinetic_energy(m, s) + fem_dyn.elastic_energy(m, s)
    return out


def kinetic(model, state):
    """The kinetic energy of every moving body (J), at the state's time."""
    total = float(rigid_table(model, state)[:, 13].sum()) if model.rigid.body_count else 0.0
    return total + sum(fem_dyn.kinetic_energy(m, s) for m, s in zip(model.fem, state.fem))


def totals(model, state):
    """Total energy (kinetic + gravitational + elastic, J), linear momentum (kg m/s) and angular
    momentum about the origin (kg m^2/s) of the moving bodies."""
    g = model.gravity
    energy, P, L = 0.0, np.zeros(3), np.zeros(3)
    rm, rs = model.rigid, state.rigid
    if rm.body_count:
        table = rigid_table(model, state)
        v = table[:, 7:10]
        m = np.where(rm.body_fixed, 0.0, rm.body_mass)
        energy += float(table[:, 13].sum() - (m * (rs.position @ g)).sum())
        P += (m[:, None] * v).sum(axis=0)
        L += (np.cross(rs.position, m[:, None] * v) + rs.angular_momentum).sum(axis=0)
    for mm, s in zip(model.fem, state.fem):
        energy += fem_dyn.kinetic_energy(mm, s) + fem_dyn.elastic_energy(mm, s) - float(mm.node_mass @ (s.x @ g))
        P += fem_dyn.linear_momentum(mm, s)
        L += fem_dyn.angular_momentum(mm, s)
    return energy + parked_energy(model), P, L


def parked_energy(model):
    """Energy (J) the auto bodies stepped as rigid keep that the rigid sums leave out: the elastic
    energy of the deformed shape each keeps, and for one held by its anchors (a fixed rigid body)
    its weight's potential energy where it is held; constant while they stay rigid."""
    energy = 0.0
    for i, k in enumerate(model.rigid_ids):
        parked = model.parked.get(int(k))
        if parked is not None:
            energy += fem_dyn.elastic_energy(parked.fem, parked.state)
            if model.rigid.body_fixed[i]:
                energy -= float(parked.fem.node_mass @ (parked.state.x @ model.gravity))
    return energy
