"""Off-screen rendering of a saved run: real pixels, distinct bodies, fixed camera, a movie."""

import imageio.v2 as imageio
import imageio.v3 as iio
import numpy as np
import pytest

from hybrid.app import render
from hybrid.app.output import FramePiece, RunWriter
from hybrid.app.run_files import read_run
from hybrid.app.render import BODY_PALETTE, movie_fps, probe_backend, render_run

WIDTH, HEIGHT = 320, 240
CUBE_POINTS = np.array([[x, y, z] for x in (0.0, 1.0) for y in (0.0, 1.0) for z in (0.0, 1.0)]) - 0.5
CUBE_TRIANGLES = np.array([
    [0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
    [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3],
])
TET_POINTS = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]])
TETS = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])


def write_two_box_run(run_dir):
    """Body 0 falls from z=2 to z=1.5, body 1 rests on the ground plane z=0."""
    summary = {"scene": {"name": "boxes", "planes": [{"point": [0, 0, 0], "normal": [0, 0, 1]}],
                         "simulation": {"output_fps": 20}}}
    with RunWriter(run_dir, "boxes") as writer:
        for time, height in ((0.0, 2.0), (0.05, 1.5)):
            falling = FramePiece(0, CUBE_POINTS + [0, 0, height], [("triangle", CUBE_TRIANGLES)])
            resting = FramePiece(1, CUBE_POINTS + [1.6, 0.4, 0.5], [("triangle", CUBE_TRIANGLES)],
                                 cell_data={"von_mises": np.full(12, 2.0e6)})
            writer.write_frame(time, [falling, resting], [])
        writer.close(summary)


def chromaticity(rgb):
    rgb = np.asarray(rgb, dtype=float)
    return rgb / np.maximum(rgb.sum(axis=-1, keepdims=True), 1.0)


def pixels_of_body(image, body_id, tolerance=0.03):
    """Mask of pixels whose hue matches the body's palette colour (shading only scales it)."""
    target = chromaticity(BODY_PALETTE[body_id])
    bright_enough = image.sum(axis=-1) > 60
    return bright_enough & (np.abs(chromaticity(image) - target).max(axis=-1) < tolerance)


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    ok, message = probe_backend()
    assert ok, message  # a machine without EGL/OSMesa must fail here, with what to install
    run_dir = tmp_path_factory.mktemp("render") / "boxes"
    write_two_box_run(run_dir)
    calls = []
    result = render_run(run_dir, size=(WIDTH, HEIGHT), progress=lambda done, total: calls.append((done, total)))
    return run_dir, result, calls


def test_probe_backend_finds_offscreen_rendering_on_this_machine():
    ok, message = probe_backend()
    assert ok, message


def test_probe_failure_names_the_packages_to_install(monkeypatch):
    monkeypatch.setenv(render.WINDOW_ENV, "vtkNoSuchRenderWindow")
    ok, message = probe_backend(refresh=True)
    assert not ok
    assert "apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri" in message
    assert "libosmesa6" in message


def test_frames_are_rendered_at_the_requested_size_with_content(rendered):
    run_dir, result, calls = rendered
    assert [p.name for p in result["pngs"]] == ["frame_00000.png", "frame_00001.png"]
    assert all(p.parent == run_dir / "render" for p in result["pngs"])
    assert calls == [(1, 2), (2, 2)]
    for png in result["pngs"]:
        image = iio.imread(png)
        assert image.shape[:2] == (HEIGHT, WIDTH)
        assert image[..., :3].std() > 10
        assert len(np.unique(image[..., :3].reshape(-1, 3), axis=0)) > 2


def test_each_body_gets_its_own_colour_and_the_camera_stays_fixed(rendered):
    _, result, _ = rendered
    first, second = (iio.imread(p)[..., :3] for p in result["pngs"])
    for image in (first, second):
        for body_id in (0, 1):
            assert pixels_of_body(image, body_id).sum() > 200, f"body {body_id} not visible"
    # The resting body covers the same pixels in both frames; the falling one moves down the image.
    resting_0, resting_1 = pixels_of_body(first, 1), pixels_of_body(second, 1)
    assert (resting_0 ^ resting_1).sum() < 0.02 * resting_0.sum()
    falling_rows = [np.nonzero(pixels_of_body(im, 0))[0].mean() for im in (first, second)]
    assert falling_rows[1] > falling_rows[0] + 5


def test_ground_plane_is_drawn_below_the_bodies(rendered):
    _, result, _ = rendered
    image = iio.imread(result["pngs"][0])[..., :3].astype(float)
    # The ground is a light neutral grey; the bottom rows of the image look onto it.
    bottom = image[-HEIGHT // 8:, WIDTH // 3: 2 * WIDTH // 3].reshape(-1, 3)
    assert np.all(bottom.mean(axis=0) > 150)
    assert np.ptp(bottom.mean(axis=0)) < 20


def test_movie_has_every_frame_at_the_scene_output_rate(rendered):
    _, result, _ = rendered
    movie = result["movie"]
    assert movie.name == "boxes.mp4" and movie.stat().st_size > 0
    assert result["fps"] == 20.0
    with imageio.get_reader(movie) as reader:
        assert reader.get_meta_data()["fps"] == pytest.approx(20.0)
        frames = [frame for frame in reader]  # list() trips over len(reader) == inf
    assert len(frames) == 2
    assert frames[0].shape[:2] == (HEIGHT, WIDTH)


def test_field_colouring_uses_one_colour_scale_for_both_frames(tmp_path):
    run_dir = tmp_path / "stress"
    with RunWriter(run_dir, "stress") as writer:
        for time, scale in ((0.0, 1.0), (0.1, 3.0)):
            tet = FramePiece(2, TET_POINTS, [("tetra", TETS)],
                             cell_data={"von_mises": np.array([0.0, 1.0e6]) * scale})
            writer.write_frame(time, [tet], [])
        writer.close({})  # no planes, no output_fps
    result = render_run(run_dir, size=(WIDTH, HEIGHT), field="von_mises")
    assert result["fps"] == pytest.approx(10.0)
    first, second = (iio.imread(p)[..., :3] for p in result["pngs"])
    # Same geometry, higher stress in the second frame: the picture must change.
    assert np.abs(first.astype(int) - second.astype(int)).sum() > 0
    with pytest.raises(ValueError, match="no frame"):
        render_run(run_dir, size=(WIDTH, HEIGHT), field="plastic_strain")


def test_movie_rate_comes_from_summary_else_frame_spacing():
    assert movie_fps([0.0, 0.1, 0.2], {"scene": {"simulation": {"output_fps": 24}}}) == 24.0
    assert movie_fps([0.0, 0.04, 0.08], None) == pytest.approx(25.0)
    assert movie_fps([0.0], {}) == render.DEFAULT_FPS


def test_gif_is_written_when_ffmpeg_is_unavailable(tmp_path, monkeypatch):
    import imageio_ffmpeg

    def no_ffmpeg():
        raise RuntimeError("no ffmpeg here")

    monkeypatch.setattr(imageio_ffmpeg, "get_ffmpeg_exe", no_ffmpeg)
    run_dir = tmp_path / "boxes"
    write_two_box_run(run_dir)
    result = render_run(run_dir, out=tmp_path / "pictures", size=(161, 121))
    assert result["movie"] == tmp_path / "pictures" / "boxes.gif"
    frames = iio.imread(result["movie"], index=None)
    assert frames.shape[:3] == (2, 121, 161)
    assert not (tmp_path / "pictures" / "boxes.mp4").exists()


def test_colour_bar_names_each_field_with_its_unit():
    assert render._scalar_bar("von_mises", 960)["title"] == "von_mises (Pa)"
    assert render._scalar_bar("principal_stress", 960)["title"] == "principal_stress (Pa)"
    assert render._scalar_bar("plastic_strain", 960)["title"] == "plastic_strain (-)"


def test_a_rerun_replaces_the_earlier_movie_and_frames(tmp_path):
    run_dir = tmp_path / "boxes"
    write_two_box_run(run_dir)
    stale = run_dir / "render"
    stale.mkdir(parents=True)
    for name in ("boxes.gif", "boxes.mp4", "frame_00007.png"):      # an earlier, longer render
        (stale / name).write_bytes(b"old")
    result = render_run(run_dir, size=(WIDTH, HEIGHT))
    left = sorted(p.name for p in stale.iterdir())
    assert left == sorted([p.name for p in result["pngs"]] + [result["movie"].name])
    assert result["movie"].read_bytes() != b"old"


def test_render_refuses_a_size_it_cannot_draw(tmp_path, capfd):
    """Too small, or too large to allocate (40000 x 30000 ended the process in the renderer,
    after the earlier render's files were removed): exit 2, and an earlier render stays."""
    from hybrid.app.cli import main
    run_dir = tmp_path / "boxes"
    write_two_box_run(run_dir)
    with pytest.raises(ValueError, match="16 to 8192 pixels"):
        render_run(run_dir, size=(0, -5))
    (run_dir / "render").mkdir()
    (run_dir / "render" / "frame_0000.png").write_bytes(b"earlier")
    for size in (["0", "-5"], ["40000", "30000"]):
        assert main(["render", str(run_dir), "--size", *size]) == 2
        assert "16 to 8192 pixels" in capfd.readouterr().err
    assert (run_dir / "render" / "frame_0000.png").read_bytes() == b"earlier"


def test_a_field_no_frame_has_is_refused_saying_where_fields_are_drawn(tmp_path, capfd):
    """A run of rigid bodies rendered with --field von_mises: refused (exit 2) with what to do."""
    from hybrid.app.cli import main
    run_dir = tmp_path / "boxes"
    write_two_box_run(run_dir)
    assert main(["render", str(run_dir), "--field", "plastic_strain"]) == 2
    err = capfd.readouterr().err
    assert "no frame" in err and "'plastic_strain'" in err and "leave out --field" in err, err
    assert not (run_dir / "render").exists()


@pytest.mark.parametrize("summary", ["missing", "stopped"])
def test_an_unfinished_run_is_rendered_with_a_note_saying_so(tmp_path, capfd, summary):
    """A killed run (no summary.json) or a stopped one rendered as if finished, without a word."""
    import json
    from hybrid.app.cli import main
    run_dir = tmp_path / "boxes"
    write_two_box_run(run_dir)
    if summary == "missing":
        (run_dir / "summary.json").unlink()
    else:
        (run_dir / "summary.json").write_text(json.dumps({"status": "stopped"}))
    assert main(["render", str(run_dir), "--size", "64", "48"]) == 0
    err = capfd.readouterr().err
    said = "no summary.json" if summary == "missing" else "ended with status 'stopped'"
    assert f"note: {run_dir}: its run" in err and said in err and "rendering the 2 frames" in err


@pytest.mark.parametrize("damage", ["index", "render folder"])
def test_a_damaged_index_or_a_file_where_the_render_goes_is_an_exit_2_error(tmp_path, capfd, damage):
    from hybrid.app.cli import main
    run_dir = tmp_path / "boxes"
    write_two_box_run(run_dir)
    if damage == "index":
        next(run_dir.glob("*.pvd")).write_text("garbage")
    else:
        (run_dir / "render").write_text("a file")
    assert main(["render", str(run_dir)]) == 2
    err = capfd.readouterr().err
    assert ("not a finished run folder" if damage == "index" else "cannot write the render") in err
    assert "Traceback" not in err


@pytest.mark.parametrize("damage", ["missing", "cut short"])
def test_a_damaged_frame_is_named_with_exit_code_2_and_no_parser_noise(tmp_path, capfd, damage):
    from hybrid.app.cli import main
    run_dir = tmp_path / "boxes"
    write_two_box_run(run_dir)
    frame = read_run(run_dir)[1][1]
    if damage == "missing":
        frame.unlink()
    else:
        frame.write_bytes(frame.read_bytes()[:300])
    assert main(["render", str(run_dir)]) == 2
    err = capfd.readouterr().err
    assert f"frame file {frame}" in err and ("missing" if damage == "missing" else "cut short") in err
    assert "Traceback" not in err and "vtkXMLParser" not in err


def write_block_and_cube_run(run_dir, stresses=(1.0e6, 2.0e6), field="von_mises"):
    """A deformable two-tet block (``field``, von Mises by default, ``stresses`` in the two frames)
    beside a rigid cube, with the ``deformable`` cell flags a simulation writes."""
    summary = {"scene": {"name": "mixed", "planes": [], "simulation": {"output_fps": 20}}}
    with RunWriter(run_dir, "mixed") as writer:
        for time, stress in zip((0.0, 0.05), stresses):
            block = FramePiece(0, TET_POINTS, [("tetra", TETS)],
                               cell_data={field: np.array([stress, stress]), "deformable": np.int8(1)})
            cube = FramePiece(1, CUBE_POINTS + [2.0, 0.0, 0.5], [("triangle", CUBE_TRIANGLES)])
            writer.write_frame(time, [block, cube], [])
        writer.close(summary)


def test_field_scale_comes_from_deformable_cells_and_rigid_bodies_are_grey(tmp_path):
    run_dir = tmp_path / "mixed"
    write_block_and_cube_run(run_dir, stresses=(1.0e6, 2.0e6))
    frames = read_run(run_dir)[1]
    # the rigid cube's cells (0 Pa, no stress of their own) do not stretch the scale down to 0
    assert render.scene_bounds(frames, "von_mises")[2] == (1.0e6, 2.0e6)
    result = render_run(run_dir, size=(WIDTH, HEIGHT), field="von_mises")
    image = iio.imread(result["pngs"][0])[..., :3].astype(int)
    grey = (np.abs(image - np.round(255 * np.array(render.RIGID_GREY) * 0.9)).max(axis=-1) < 60) \
        & (np.ptp(image, axis=-1) < 8) & (image.sum(axis=-1) > 200)
    assert grey[:, WIDTH // 2:].sum() > 200        # the cube, right of the block, drawn grey


def test_a_field_with_one_value_throughout_the_run_is_rendered_with_a_note_saying_why(tmp_path, capfd):
    """Coloured by plastic_strain, a run in which nothing yielded was drawn in one colour against
    a made-up scale, without a word; a field that varies gets no note."""
    from hybrid.app.cli import main
    run_dir = tmp_path / "mixed"
    write_block_and_cube_run(run_dir, stresses=(0.0, 0.0), field="plastic_strain")
    assert main(["render", str(run_dir), "--size", "64", "48", "--field", "plastic_strain"]) == 0
    err = capfd.readouterr().err
    assert (f"note: {run_dir}: field 'plastic_strain' is 0 in every deformable element of every frame"
            in err and "yield_stress" in err), err
    varying = tmp_path / "varying"
    write_block_and_cube_run(varying, stresses=(1.0e6, 2.0e6))
    assert render_run(varying, size=(64, 48), field="von_mises")["note"] is None


def test_percentile_scale_ignores_a_few_extreme_elements(tmp_path):
    run_dir = tmp_path / "mixed"
    write_block_and_cube_run(run_dir, stresses=(1.0e6, 1.0e6))
    frames = read_run(run_dir)[1]
    values = np.concatenate([np.full(98, 1.0), [1.0e3, 1.0e4]])
    assert render._limits(values, "run") == (1.0, 1.0e4)
    low, high = render._limits(values, "percentile")
    assert low == 1.0 and high < 1.0e3
    with pytest.raises(ValueError, match="colour range"):
        render_run(run_dir, size=(WIDTH, HEIGHT), field="von_mises", colour_range="nope")
    assert frames


def test_frame_scale_draws_each_frame_against_its_own_range(tmp_path):
    run_dir = tmp_path / "mixed"
    write_block_and_cube_run(run_dir, stresses=(1.0e6, 3.0e6))    # uniform stress, tripled
    run_scale = render_run(run_dir, size=(WIDTH, HEIGHT), field="von_mises", colour_range="run")
    first, second = (iio.imread(p)[..., :3].astype(int) for p in run_scale["pngs"])
    assert np.abs(first - second).sum() > 0                    # one scale: the colour changes
    own = render_run(run_dir, out=tmp_path / "own", size=(WIDTH, HEIGHT), field="von_mises",
                     colour_range="frame")
    first, second = (iio.imread(p)[..., :3].astype(int) for p in own["pngs"])
    changed = np.abs(first - second).max(axis=-1) > 2
    bar = int(WIDTH * render._scalar_bar("von_mises", WIDTH)["position_x"])
    assert changed[40:, :bar].sum() < 20              # each frame its own scale: the body the same


def test_colour_bar_has_its_own_room_beside_the_bodies(tmp_path):
    run_dir = tmp_path / "mixed"
    write_block_and_cube_run(run_dir)            # the rigid cube is the rightmost body
    result = render_run(run_dir, size=(WIDTH, HEIGHT), field="von_mises")
    image = iio.imread(result["pngs"][0])[..., :3].astype(int)
    cube = (np.abs(image - np.round(255 * np.array(render.RIGID_GREY) * 0.9)).max(axis=-1) < 60) \
        & (np.ptp(image, axis=-1) < 8) & (image.sum(axis=-1) > 200)
    columns = np.nonzero(cube[40:].sum(axis=0) >= 30)[0]      # the cube (not the bar's grey text)
    assert len(columns) > 10 and columns.max() < WIDTH * render._bar_left("von_mises", WIDTH)


def test_a_body_in_a_walled_bin_is_seen_through_the_walls_nearest_the_camera(tmp_path):
    """Planes are drawn from their open side only: a box inside a bin of four walls stays in view
    (the walls between the fixed camera and the box would cover it)."""
    walls = [{"point": [0, 0, 0], "normal": [0, 0, 1]}] + [
        {"point": list(point), "normal": list(-np.asarray(point) / 1.5)}
        for point in ([1.5, 0, 0], [-1.5, 0, 0], [0, 1.5, 0], [0, -1.5, 0])]
    run_dir = tmp_path / "bin"
    with RunWriter(run_dir, "bin") as writer:
        writer.write_frame(0.0, [FramePiece(0, CUBE_POINTS + [0, 0, 0.5], [("triangle", CUBE_TRIANGLES)])], [])
        writer.close({"scene": {"name": "bin", "planes": walls, "simulation": {"output_fps": 20}}})
    image = iio.imread(render_run(run_dir, size=(WIDTH, HEIGHT))["pngs"][0])[..., :3]
    assert pixels_of_body(image, 0).sum() > 200


def test_a_render_of_a_folder_that_is_not_there_says_so(tmp_path, capfd):
    """A mistyped run folder was told "no .pvd index ... (is it a run directory?)"."""
    from hybrid.app.cli import main
    assert main(["render", str(tmp_path / "no-such-run")]) == 2
    assert "there is no such folder" in capfd.readouterr().err
    (tmp_path / "a-file").write_text("x")
    assert main(["render", str(tmp_path / "a-file")]) == 2
    assert "it is a file" in capfd.readouterr().err


def test_a_render_interrupted_leaves_no_movie_of_the_frames_drawn_so_far(tmp_path):
    """Stopped by Ctrl-C half way, a render left a movie of the frames drawn so far, which looks
    whole: the movie is removed (the frames' PNGs drawn stay), and a rerun makes the whole one."""
    run_dir = tmp_path / "boxes"
    write_two_box_run(run_dir)

    def interrupt(done, total):
        if done == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        render_run(run_dir, size=(64, 48), progress=interrupt)
    render = run_dir / "render"
    assert not list(render.glob("*.mp4")) and not list(render.glob("*.gif"))
    assert len(list(render.glob("frame_*.png"))) == 1
    result = render_run(run_dir, size=(64, 48))
    assert result["movie"].exists() and len(result["pngs"]) == 2
