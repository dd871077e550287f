"""Run output round-trips: VTK frames, pvd index, CSV tables and summary read back exactly."""

import csv
import json
import xml.etree.ElementTree as ET

import meshio
import numpy as np
import pytest

from hybrid.app.output import FramePiece, RunWriter
from hybrid.app.run_files import BODY_COLUMNS, REGION_COLUMNS, read_run

BOX_POINTS = np.array([[x, y, z] for x in (0.0, 1.0) for y in (0.0, 1.0) for z in (0.0, 1.0)])
BOX_TRIANGLES = np.array([
    [0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
    [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3],
])
TET_POINTS = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]])
TETS = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])


def box_piece(t):
    return FramePiece(body_id=3, points=BOX_POINTS + [0.0, 0.0, 2.0 - t],
                      cells=[("triangle", BOX_TRIANGLES)],
                      point_data={"velocity": np.tile([0.0, 0.0, -1.0], (8, 1))})


def tet_piece(t):
    return FramePiece(body_id=7, points=TET_POINTS + [3.0, 0.0, t], cells=[("tetra", TETS)],
                      cell_data={"von_mises": np.array([1.5e6, 2.5e6]) * (1 + t),
                                 "principal_stress": np.arange(6.0).reshape(2, 3)})


def body_rows(t):
    return [(t, body, 0.1 + 0.2, 1 / 3, t, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, -t, 0.0, 0.0, 0.0, 1e-300 * 7,
             "fem")
            for body in (3, 7)]


def write_three_frames(run_dir):
    times = [0.0, 0.1, 0.30000000000000004]
    with RunWriter(run_dir, "demo") as writer:
        for t in times:
            writer.write_frame(t, [box_piece(t), tet_piece(t)], body_rows(t))
        writer.write_regions([(t, 7, "clamp", 1.0, 2.0, np.float64(3.0), 0.0, 0.0, 1e-9) for t in times[:2]])
        assert writer.frames_written == 3
        writer.close({"scene": {"name": "demo"}, "steps": np.int64(30), "energy": np.float32(0.5),
                      "drift": np.array([0.1, 0.2]), "ok": np.bool_(True)})
    return times


def test_frames_merge_bodies_with_body_id_and_zero_filled_fields(tmp_path):
    run_dir = tmp_path / "run"
    write_three_frames(run_dir)
    mesh = meshio.read(run_dir / "frames" / "frame_00001.vtu")

    np.testing.assert_allclose(mesh.points[:8], BOX_POINTS + [0, 0, 1.9])
    np.testing.assert_allclose(mesh.points[8:], TET_POINTS + [3.0, 0, 0.1])
    assert [block.type for block in mesh.cells] == ["triangle", "tetra"]
    # The tet block's indices are shifted past the box's 8 points.
    np.testing.assert_array_equal(mesh.cells[1].data, TETS + 8)

    body_id = np.concatenate(mesh.cell_data["body_id"])
    assert np.issubdtype(body_id.dtype, np.integer)
    np.testing.assert_array_equal(body_id, [3] * 12 + [7] * 2)

    von_mises = mesh.cell_data["von_mises"]
    np.testing.assert_array_equal(von_mises[0], np.zeros(12))
    np.testing.assert_allclose(von_mises[1], [1.65e6, 2.75e6])
    principal = mesh.cell_data["principal_stress"]
    assert principal[0].shape == (12, 3) and not principal[0].any()
    np.testing.assert_array_equal(principal[1], np.arange(6.0).reshape(2, 3))

    velocity = mesh.point_data["velocity"]
    assert velocity.shape == (13, 3)
    np.testing.assert_array_equal(velocity[:8, 2], -1.0)
    assert not velocity[8:].any()


def test_pvd_lists_every_frame_with_exact_times(tmp_path):
    run_dir = tmp_path / "run"
    times = write_three_frames(run_dir)
    root = ET.parse(run_dir / "demo.pvd").getroot()
    assert root.get("type") == "Collection"
    datasets = list(root.iter("DataSet"))
    assert len(datasets) == 3
    assert [float(d.get("timestep")) for d in datasets] == times
    assert [d.get("file") for d in datasets] == [f"frames/frame_{i:05d}.vtu" for i in range(3)]

    read_times, paths, summary = read_run(run_dir)
    assert read_times == times
    assert all(p.is_file() for p in paths)
    assert summary["steps"] == 30


def test_csv_tables_have_exact_header_and_round_trip_floats(tmp_path):
    run_dir = tmp_path / "run"
    times = write_three_frames(run_dir)
    with open(run_dir / "bodies.csv", newline="") as f:
        rows = list(csv.reader(f))
    assert tuple(rows[0]) == BODY_COLUMNS
    assert len(rows) == 1 + 2 * len(times)
    first = dict(zip(rows[0], rows[1]))
    assert float(first["x"]) == 0.1 + 0.2  # 0.30000000000000004 survives
    assert float(first["y"]) == 1 / 3
    assert float(first["kinetic_energy"]) == 7e-300
    assert first["body"] == "3"
    assert [float(r[0]) for r in rows[1::2]] == times

    with open(run_dir / "regions.csv", newline="") as f:
        regions = list(csv.reader(f))
    assert tuple(regions[0]) == REGION_COLUMNS
    assert regions[1] == ["0.0", "7", "clamp", "1.0", "2.0", "3.0", "0.0", "0.0", "1e-09"]
    assert len(regions) == 3


def test_summary_is_plain_json_and_no_temporary_files_remain(tmp_path):
    run_dir = tmp_path / "run"
    write_three_frames(run_dir)
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary == {"scene": {"name": "demo"}, "steps": 30, "energy": 0.5,
                       "drift": [0.1, 0.2], "ok": True}
    names = sorted(p.relative_to(run_dir).as_posix() for p in run_dir.rglob("*"))
    assert names == ["bodies.csv", "demo.pvd", "frames", "frames/frame_00000.vtu",
                     "frames/frame_00001.vtu", "frames/frame_00002.vtu", "regions.csv",
                     "summary.json"]


def test_writer_creates_nothing_until_something_is_written(tmp_path):
    run_dir = tmp_path / "never"
    with pytest.raises(RuntimeError):
        with RunWriter(run_dir, "demo"):
            raise RuntimeError("scene failed validation")
    writer = RunWriter(run_dir, "demo")
    writer.write_regions([])
    writer.close()
    assert not run_dir.exists()


def test_bad_rows_and_shapes_are_rejected_before_writing(tmp_path):
    run_dir = tmp_path / "run"
    writer = RunWriter(run_dir, "demo")
    with pytest.raises(ValueError, match="17"):
        writer.write_frame(0.0, [box_piece(0.0)], [(0.0, 1, 2.0)])
    bad = FramePiece(1, BOX_POINTS, [("triangle", BOX_TRIANGLES)], cell_data={"von_mises": np.ones(5)})
    with pytest.raises(ValueError, match="von_mises"):
        writer.write_frame(0.0, [bad], [])
    with pytest.raises(ValueError, match="at least one"):
        writer.write_frame(0.0, [], [])
    assert not run_dir.exists()
    writer.close()


def test_new_run_replaces_stale_files_of_an_earlier_run(tmp_path):
    run_dir = tmp_path / "run"
    write_three_frames(run_dir)
    # the earlier run's render showed its frames; a user's own file there stays
    (run_dir / "render").mkdir()
    for name in ("frame_00000.png", "old.mp4", "old.gif", "notes.txt"):
        (run_dir / "render" / name).write_text("x")
    with RunWriter(run_dir, "demo") as writer:
        writer.write_frame(0.0, [box_piece(0.0)], [dict(zip(BODY_COLUMNS, body_rows(0.0)[0]))])
    times, paths, summary = read_run(run_dir)
    assert times == [0.0] and summary is None
    assert sorted(p.name for p in (run_dir / "frames").iterdir()) == ["frame_00000.vtu"]
    assert not (run_dir / "regions.csv").exists()
    assert len((run_dir / "bodies.csv").read_text().splitlines()) == 2
    assert [p.name for p in (run_dir / "render").iterdir()] == ["notes.txt"]


def test_run_of_another_scene_into_the_same_directory_leaves_one_index(tmp_path):
    """The earlier scene's .pvd named frames that the new run replaced: it goes with them (before,
    it stayed and read_run could open the old index on the new frames)."""
    run_dir = tmp_path / "run"
    write_three_frames(run_dir)
    (run_dir / "notes.pvd").write_text("<VTKFile/>")          # not a run's index: left alone
    with RunWriter(run_dir, "other") as writer:
        writer.write_frame(0.0, [box_piece(0.0)])
    assert sorted(p.name for p in run_dir.glob("*.pvd")) == ["notes.pvd", "other.pvd"]
    times, paths, _ = read_run(run_dir)
    assert times == [0.0] and [p.name for p in paths] == ["frame_00000.vtu"]


def test_drift_figures_stay_meaningful_when_a_quantity_starts_at_zero():
    from hybrid.app.run import _drift
    assert _drift([0.0, 5.0, 3.0], 0.0) == pytest.approx(1.0)          # was 5 / 1e-300
    assert _drift([2.0, 2.02, 1.99], 2.0) == pytest.approx(0.02 / 2.02)
    assert _drift(np.zeros((4, 3)), np.zeros(3)) == 0.0
    # no total at all (two bodies meeting head-on) but 10 units carried: a change of 1e-5 is 1e-6
    assert _drift([[0, 0, 0], [0, 1e-5, 0]], np.zeros(3), [10.0, 9.0]) == pytest.approx(1e-6)


def test_a_piece_of_several_bodies_writes_each_cells_own_body_id(tmp_path):
    """A piece may carry one id per cell (many rigid bodies in one piece): the frame holds each
    cell's id; a list of ids that does not match the cells is refused before writing."""
    two_boxes = FramePiece(body_id=np.repeat([2, 5], 12), points=np.vstack([BOX_POINTS, BOX_POINTS + 2.0]),
                           cells=[("triangle", np.vstack([BOX_TRIANGLES, BOX_TRIANGLES + 8]))])
    with RunWriter(tmp_path / "run", "demo", background=False) as writer:
        writer.write_frame(0.0, [two_boxes, tet_piece(0.0)])
        with pytest.raises(ValueError, match="23 body ids for 24 cells"):
            writer.write_frame(0.1, [FramePiece(np.repeat([2, 5], [11, 12]), two_boxes.points, two_boxes.cells)])
        with pytest.raises(ValueError, match="integer"):
            writer.write_frame(0.1, [FramePiece(np.full(24, 2.0), two_boxes.points, two_boxes.cells)])
    mesh = meshio.read(tmp_path / "run" / "frames" / "frame_00000.vtu")
    np.testing.assert_array_equal(np.concatenate(mesh.cell_data["body_id"]), [2] * 12 + [5] * 12 + [7, 7])
    assert len(list((tmp_path / "run" / "frames").glob("*.vtu"))) == 1


def test_frame_pieces_write_rigid_runs_as_the_bodies_own_surfaces(sim):
    """frame_pieces puts each run of rigid bodies between FEM ones into one piece: every rigid
    body's cells are its own surface turned and moved to its pose (by the writer: the points are
    deferred), with its scene index and fragment_of, and the frame lists bodies in scene order."""
    from hybrid.app.observe import frame_pieces
    from rigid import quaternion as quat
    scene = """
[simulation]
duration = 0.05
gravity = [0, 0, 0]
[[bodies]]
name = "r0"
shape = { type = "box", size = [0.2, 0.1, 0.3] }
angular_velocity = [1, 2, 3]
[[bodies]]
name = "soft"
model = "fem"
young = 1e5
shape = { type = "box", size = [0.2, 0.2, 0.1], resolution = 0.1 }
position = [1, 0, 0]
[[bodies]]
name = "r1"
shape = { type = "sphere", radius = 0.05 }
position = [0, 1, 0]
velocity = [0, 0, 1]
[[bodies]]
name = "r2"
shape = { type = "capsule", radius = 0.05, height = 0.2 }
position = [0, -1, 0]
angular_velocity = [0, 4, 0]
"""
    run = sim(scene)
    for _ in range(10):
        run.step()
    model, state = run.model, run.state
    pieces = frame_pieces(model, state)
    ids = [np.unique(p.body_id).tolist() for p in pieces]
    assert ids == [[0], [1], [2, 3]]
    R = quat.to_matrix(state.rigid.orientation)
    rm = model.rigid
    for piece in (pieces[0], pieces[2]):
        tri = piece.cells[0][1]
        for k in np.unique(piece.body_id):
            i = run.rigid_index(model.names[k])
            mine = piece.body_id == k
            expected = state.rigid.position[i] + rm.surface_vertices[i] @ R[i].T
            used = np.unique(tri[mine])
            np.testing.assert_allclose(piece.points.value()[used], expected, rtol=0, atol=1e-15)
            np.testing.assert_array_equal(tri[mine] - used.min(), rm.surface_triangles[i])
            np.testing.assert_array_equal(piece.cell_data["fragment_of"][mine], k)


def test_csv_rows_write_every_kind_of_value_as_csv_value_formats_it():
    """Floats, ints and strings go to the csv module as they are (the fast path); the text is
    the one csv_value's formatting of each value gives: floats at full precision, numpy scalars,
    bools as 0/1, nan and inf, quoted strings, dict rows."""
    import io
    from hybrid.app.text_files import csv_rows, csv_value
    rng = np.random.default_rng(2)
    values = [0.1, 1 / 3, 7e-300, -0.0, 1e300, float("nan"), float("-inf"), 2**60, True, np.float64(0.2),
              np.int64(5), 'say "a,b"', "x", np.bool_(False), 0.30000000000000004, 5e-324, np.float32(0.1)]
    values += list(rng.normal(size=340) * 10.0 ** rng.integers(-300, 300, 340))
    rows = [tuple(values[i:i + 3]) for i in range(0, len(values) - 3, 3)]
    reference = io.StringIO()
    writer = csv.writer(reference, lineterminator="\n")
    for row in rows:
        writer.writerow([csv_value(v) for v in row])
    assert csv_rows(rows, ("a", "b", "c")) == reference.getvalue()
    assert csv_rows([dict(zip("abc", rows[0]))], "abc") == reference.getvalue().splitlines(True)[0]
    assert [float(v) for v in next(csv.reader(io.StringIO(csv_rows([(1 / 3, 2 / 3, 7e-300)], "abc"))))] \
        == [1 / 3, 2 / 3, 7e-300]


def test_poorly_compressing_arrays_are_stored_and_every_array_reads_back_exactly(tmp_path):
    """A frame's arrays that zlib would shrink by less than 30% (random positions) go into the
    file's blocks uncompressed, those that shrink (zeros) compressed; both read back bit for bit."""
    from hybrid.app import vtu
    rng = np.random.default_rng(4)
    points = rng.random((20000, 3))                          # 480 kB: more than one block
    tris = np.arange(60000).reshape(-1, 3) % 20000
    quiet = np.zeros(len(tris))
    piece = FramePiece(body_id=1, points=points, cells=[("triangle", tris)],
                       cell_data={"quiet": quiet}, point_data={"noise": rng.random(20000)})
    with RunWriter(tmp_path / "run", "noise", background=False) as writer:
        path = writer.write_frame(0.0, [piece])
    mesh = meshio.read(path)
    np.testing.assert_array_equal(mesh.points, points)
    np.testing.assert_array_equal(mesh.point_data["noise"], piece.point_data["noise"])
    np.testing.assert_array_equal(mesh.cell_data["quiet"][0], quiet)
    encoder = vtu.VtuEncoder()
    stored = len(encoder.encode("p", points)[1])
    assert stored > 4 / 3 * points.nbytes                   # base64 of every byte, and the headers
    assert len(encoder.encode("q", quiet)[1]) < 0.05 * quiet.nbytes
    assert len(encoder.encode("c", tris)[1]) < 0.5 * 4 / 3 * tris.nbytes     # connectivity
