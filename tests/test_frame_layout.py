"""Frames that repeat the last frame's layout go to the writer as their values alone
(hybrid.app.frame_layout): every frame on disk is the one its pieces make, written in place, by
a thread or by a process, across changes of layout; only frames of a new layout are checked."""

import meshio
import numpy as np
import pytest

from hybrid.app import output
from hybrid.app.output import FramePiece, RunWriter
from hybrid.app.run_files import read_run
from hybrid.app.vtu import Deferred
from rigid.model import posed_by_orientation


def frozen(array):
    array = np.array(array)
    array.flags.writeable = False
    return array


TETS = frozen([[0, 1, 2, 3], [1, 2, 3, 4]])
TRIANGLES = frozen([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
VERTICES = frozen(np.random.default_rng(0).normal(size=(8, 3)))
VERTEX_BODY = frozen([0, 0, 0, 0, 1, 1, 1, 1])
CELL_IDS = frozen([3, 3, 4, 4])


def frames(rng):
    """Frames of changing layout: a deformable piece (0-3), a field added (4-6), a piece of two
    rigid bodies posed by the writer added (7-9), cells that are not read-only (10-11, checked
    each time), back to the layout of 7-9 (12-13)."""
    out = []
    for k in range(14):
        cdata = {"von_mises": rng.uniform(0.0, 1e6, 2), "deformable": np.int8(1)}
        if k >= 4:
            cdata["plastic_strain"] = rng.uniform(0.0, 0.1, 2)
        tets = TETS.copy() if k in (10, 11) else TETS
        pieces = [FramePiece(2, rng.normal(size=(5, 3)), [("tetra", tets)], cell_data=cdata,
                             point_data={"velocity": rng.normal(size=(5, 3))})]
        if k >= 7:
            poses = (VERTICES, VERTEX_BODY, rng.normal(size=(2, 3)), rng.normal(size=(2, 4)))
            pieces.append(FramePiece(CELL_IDS, Deferred(posed_by_orientation, poses, (3,), 8),
                                     [("triangle", TRIANGLES)], cell_data={"fragment_of": CELL_IDS}))
        out.append((0.01 * k, pieces))
    return out


@pytest.mark.parametrize("background", ["inline", "thread", "process"])
def test_every_frame_on_disk_is_the_one_its_pieces_make_across_changes_of_layout(tmp_path, background):
    reference = RunWriter(tmp_path / "reference", "ref", background=False)
    expected = [reference.build_mesh(pieces) for _, pieces in frames(np.random.default_rng(3))]
    with RunWriter(tmp_path / "run", "layout", background=background) as writer:
        for t, pieces in frames(np.random.default_rng(3)):
            writer.write_frame(t, pieces)
        writer.close({})
    times, paths, _ = read_run(tmp_path / "run")
    assert len(paths) == len(expected) == 14
    for k, (path, mesh) in enumerate(zip(paths, expected)):
        read = meshio.read(path)
        np.testing.assert_array_equal(read.points, mesh.points, err_msg=f"frame {k}")
        assert [c.type for c in read.cells] == [c.type for c in mesh.cells]
        for a, b in zip(read.cells, mesh.cells):
            np.testing.assert_array_equal(a.data, b.data)
        assert read.cell_data.keys() == mesh.cell_data.keys()
        for name in mesh.cell_data:
            for a, b in zip(read.cell_data[name], mesh.cell_data[name]):
                np.testing.assert_array_equal(a, b, err_msg=f"frame {k} {name}")
        np.testing.assert_array_equal(read.point_data["velocity"], mesh.point_data["velocity"])


def test_only_frames_of_a_new_layout_are_checked(tmp_path, monkeypatch):
    checked = []
    real = output.check_pieces

    def counting(pieces, *args):
        checked.append(len(pieces))
        return real(pieces, *args)

    monkeypatch.setattr(output, "check_pieces", counting)
    with RunWriter(tmp_path / "run", "layout", background=False) as writer:
        for t, pieces in frames(np.random.default_rng(3)):
            writer.write_frame(t, pieces)
        writer.close({})
    # frames 0, 4, 7 (new layouts), 10 and 11 (cells that may change), 12 (after 11's layout)
    assert len(checked) == 6


def test_a_bad_frame_after_repeated_ones_is_still_refused(tmp_path):
    rng = np.random.default_rng(1)
    with RunWriter(tmp_path / "run", "layout", background=False) as writer:
        for t, pieces in frames(rng)[:3]:
            writer.write_frame(t, pieces)
        bad = frames(rng)[2][1]
        bad[0].points = bad[0].points[:4]               # 4 points for cells that index 5
        with pytest.raises(ValueError, match="out of range"):
            writer.write_frame(0.5, bad)
        writer.close({})
    assert len(read_run(tmp_path / "run")[1]) == 3


def test_a_values_job_crosses_the_pipe_with_its_arrays_unchanged():
    """A ``values`` job's arrays go to a writer process as their bytes: they come back with the
    same type, shape and values, views and non-contiguous ones included."""
    from hybrid.app.frame_input import KeptArrays
    rng = np.random.default_rng(3)
    block = rng.random((6, 5))
    arrays = [rng.random((8, 3)), block[:, 1:4], block.T, np.arange(12, dtype=np.int32).reshape(3, 4),
              rng.random((0, 3)), np.array([True, False])]
    job = ("values", 0.5, "frame_00001.vtu", [(0, 1)] * len(arrays), arrays, "bodies.csv", ("time",), [(0.5,)])
    back = KeptArrays().loads(KeptArrays().dumps(job))
    assert back[:4] == job[:4] and back[5:] == job[5:]
    for got, sent in zip(back[4], arrays, strict=True):
        assert got.dtype == sent.dtype and got.shape == sent.shape
        np.testing.assert_array_equal(got, sent)
