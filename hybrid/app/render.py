"""Off-screen rendering of a finished run, reading only its saved files.

``render_run(run_dir)`` reads the ``.pvd`` index, the frame files and ``summary.json`` that
``hybrid.app.output.RunWriter`` wrote, and writes ``run_dir/render/frame_NNNNN.png`` for every frame
plus a movie (``<scene>.mp4`` with libx264, or ``<scene>.gif`` when ffmpeg is unavailable).

Rendering needs an off-screen OpenGL (``hybrid.app.offscreen``, whose ``probe_backend`` and
``WINDOW_ENV`` are re-exported here); no X display is used.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from hybrid.app.offscreen import WINDOW_ENV, probe_backend, use_backend  # noqa: F401 (re-exported)
from hybrid.app.run_files import find_pvd, read_run

# Categorical colours indexed by body_id (saturated, none of them grey like the ground).
BODY_PALETTE = np.array([
    (31, 119, 180), (230, 97, 1), (44, 160, 44), (214, 39, 40), (148, 103, 189),
    (23, 190, 207), (188, 189, 34), (227, 119, 194), (140, 86, 75), (255, 187, 0),
], dtype=np.uint8)
GROUND_COLOR = (0.9, 0.9, 0.88)
VIEW_DIRECTION = np.array([1.0, -1.6, 0.9]) / np.linalg.norm([1.0, -1.6, 0.9])
VIEW_ANGLE_DEG = 30.0
DEFAULT_FPS = 30.0
RIGID_GREY = (0.62, 0.62, 0.6)  # rigid bodies when deformable ones are coloured by a field
DEFORMABLE = "deformable"      # cell data marking the deformable bodies' cells (1) in a frame
COLOUR_RANGES = ("run", "percentile", "frame")


def _read_points_and_range(path: Path, field: str | None):
    """Frame points and (values, "cell" or "point") of ``field`` (magnitude for vectors; the
    deformable bodies' cells only when the frame marks them), None without values.

    Only the points and that one array are read. Raises ValueError naming the file when it is
    missing or holds no points (damaged: VTK's own parser messages are kept quiet).
    """
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkCommonCore import vtkObject
    from vtkmodules.vtkIOXML import vtkXMLUnstructuredGridReader

    if not Path(path).is_file():
        raise ValueError(f"frame file {path} is missing")
    reader = vtkXMLUnstructuredGridReader()
    reader.SetFileName(str(path))
    shown = vtkObject.GetGlobalWarningDisplay()
    vtkObject.GlobalWarningDisplayOff()
    try:
        reader.UpdateInformation()
        for selection in (reader.GetPointDataArraySelection(), reader.GetCellDataArraySelection()):
            selection.DisableAllArrays()
            if field:
                selection.EnableArray(field)
        reader.GetCellDataArraySelection().EnableArray(DEFORMABLE)
        reader.Update()
    finally:
        vtkObject.SetGlobalWarningDisplay(shown)
    grid = reader.GetOutput()
    points = grid.GetPoints()
    if points is None or points.GetNumberOfPoints() == 0:
        raise ValueError(f"frame file {path} holds no points (damaged or cut short)")
    xyz = vtk_to_numpy(points.GetData())
    value_range = None
    if field:
        for association, data in (("cell", grid.GetCellData()), ("point", grid.GetPointData())):
            array = data.GetArray(field)
            if array is not None and array.GetNumberOfTuples():
                values = vtk_to_numpy(array).astype(float)
                if values.ndim > 1:
                    values = np.linalg.norm(values, axis=1)
                flags = grid.GetCellData().GetArray(DEFORMABLE)
                if association == "cell" and flags is not None:
                    values = values[vtk_to_numpy(flags) > 0]   # rigid bodies' cells carry no field
                if len(values):
                    value_range = (values, association)
                break
    return xyz, value_range


def scene_bounds(frame_paths: Sequence[Path], field: str | None = None, colour_range: str = "run"):
    """Union (lo, hi) of all frames' points; the colour range of ``field`` over all frames
    (``colour_range`` "run": its smallest to largest value; "percentile": its 2nd to 98th
    percentile, so a few extreme elements do not wash out every frame), its association, and
    its one value when it has the same in every cell of every frame (else None)."""
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    values, association = [], "cell"
    for path in frame_paths:
        xyz, found = _read_points_and_range(path, field)
        if len(xyz):
            lo = np.minimum(lo, xyz.min(axis=0))
            hi = np.maximum(hi, xyz.max(axis=0))
        if found:
            values.append(found[0])
            association = found[1]
    if not np.all(np.isfinite(lo)):
        lo, hi = -np.ones(3) * 0.5, np.ones(3) * 0.5
    values = np.concatenate(values) if values else None
    clim = _limits(values, colour_range) if values is not None else None
    constant = float(values[0]) if values is not None and len(values) and np.all(values == values[0]) else None
    return lo, hi, clim, association, constant


def _limits(values, colour_range):
    """Colour limits (low, high) of ``values``: min-max ("run", "frame") or 2nd-98th percentile."""
    low, high = (np.percentile(values, [2.0, 98.0]) if colour_range == "percentile"
                 else (values.min(), values.max()))
    low, high = float(low), float(high)
    return low, high if high > low else low + max(abs(low), 1.0)


def camera_for_bounds(lo: np.ndarray, hi: np.ndarray, aspect: float,
                      view_angle_deg: float = VIEW_ANGLE_DEG, margin: float = 1.12):
    """Fixed 3/4 elevated camera (position, focal point, up) whose view holds the whole box.

    Looks at the box centre along ``-VIEW_DIRECTION`` with z up; the distance is the smallest at
    which every box corner projects inside the window (vertical view angle, width/height
    ``aspect``), times ``margin``.
    """
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    centre = (lo + hi) / 2
    back = VIEW_DIRECTION  # from the focal point towards the camera
    screen_up = np.array([0.0, 0.0, 1.0]) - back[2] * back
    screen_up /= np.linalg.norm(screen_up)
    screen_right = np.cross(screen_up, back)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for z in (lo[2], hi[2])]) - centre
    tan_v = np.tan(np.radians(view_angle_deg) / 2)
    tan_h = tan_v * aspect
    # A corner at depth a towards the camera fits if |offset| <= (D - a) tan(half angle).
    needed = corners @ back + np.maximum(np.abs(corners @ screen_right) / tan_h,
                                         np.abs(corners @ screen_up) / tan_v)
    extent = max(float(np.linalg.norm(hi - lo)), 1e-6)
    distance = margin * max(float(needed.max()), 0.5 * extent)
    position = centre + distance * back
    return [tuple(position), tuple(centre), (0.0, 0.0, 1.0)]


def movie_fps(times: Sequence[float], summary: Mapping[str, Any] | None) -> float:
    """Playback rate: the scene's output_fps if recorded, else from the spacing of frame times."""
    try:
        fps = float(summary["scene"]["simulation"]["output_fps"])
        if fps > 0:
            return fps
    except (KeyError, TypeError, ValueError):
        pass
    if len(times) > 1:
        spacing = float(np.median(np.diff(times)))
        if spacing > 0:
            return 1.0 / spacing
    return DEFAULT_FPS


def _scene_planes(summary: Mapping[str, Any] | None) -> list[tuple[np.ndarray, np.ndarray]]:
    try:
        planes = summary["scene"]["planes"]
    except (KeyError, TypeError):
        return []
    result = []
    for plane in planes or []:
        normal = np.asarray(plane.get("normal", (0, 0, 1)), dtype=float)
        norm = np.linalg.norm(normal)
        if norm > 0:
            result.append((np.asarray(plane.get("point", (0, 0, 0)), dtype=float), normal / norm))
    return result


def _even_frame(image: np.ndarray) -> np.ndarray:
    """Pad by one edge row/column so both sides are even (yuv420p needs it)."""
    pad_rows, pad_cols = image.shape[0] % 2, image.shape[1] % 2
    if pad_rows or pad_cols:
        image = np.pad(image, ((0, pad_rows), (0, pad_cols), (0, 0)), mode="edge")
    return image


class _MovieWriter:
    """mp4 via imageio-ffmpeg (libx264), or an animated gif if ffmpeg is unavailable."""

    def __init__(self, stem: Path, fps: float):
        import imageio.v2 as imageio

        self.fps = fps
        self.path = stem.with_suffix(".mp4")
        self._gif_frames: list[np.ndarray] | None = None
        try:
            import imageio_ffmpeg

            imageio_ffmpeg.get_ffmpeg_exe()
            self._writer = imageio.get_writer(self.path, format="FFMPEG", mode="I", fps=fps,
                                              codec="libx264", pixelformat="yuv420p",
                                              macro_block_size=1, quality=8)
        except Exception:
            self.path.unlink(missing_ok=True)
            self.path = stem.with_suffix(".gif")
            self._writer = None
            self._gif_frames = []

    def append(self, image: np.ndarray) -> None:
        if self._writer is not None:
            self._writer.append_data(_even_frame(image))
        else:
            self._gif_frames.append(image)

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
        elif self._gif_frames:
            import imageio.v3 as iio

            iio.imwrite(self.path, np.stack(self._gif_frames), duration=1000.0 / self.fps, loop=0)


def _frame_mesh(path: Path, field: str | None, association: str = "cell"):
    """Read one frame; add per-cell body colours, or zeros for a field this frame lacks."""
    import pyvista as pv

    mesh = pv.read(path)
    if field is None:
        body_id = np.asarray(mesh.cell_data.get("body_id", np.zeros(mesh.n_cells, int)), dtype=np.int64)
        mesh.cell_data["body_color"] = BODY_PALETTE[body_id % len(BODY_PALETTE)]
    elif association == "cell" and field not in mesh.cell_data:
        mesh.cell_data[field] = np.zeros(mesh.n_cells)
    elif association == "point" and field not in mesh.point_data:
        mesh.point_data[field] = np.zeros(mesh.n_points)
    if field is not None and association == "cell" and DEFORMABLE in mesh.cell_data:
        # rigid bodies carry no stress: no value, drawn in RIGID_GREY instead of the scale's zero
        values = np.asarray(mesh.cell_data[field], dtype=float).copy()
        values[np.asarray(mesh.cell_data[DEFORMABLE]) == 0] = np.nan
        mesh.cell_data[field] = values
    return mesh


# units of the cell fields a run writes (hybrid.app.observe.tet_fields); '-' for a pure number
FIELD_UNITS = {"von_mises": "Pa", "principal_stress": "Pa", "plastic_strain": "-", "yielded": "-"}

# colour bar text (pixels) and the room its widest label ("-1.23e+06") and the bar take
BAR_FONT = 14
BAR_WIDTH = 0.05    # the colour bar's width, a fraction of the image's (pyvista's default)
BAR_ROOM = 40 + 9 * 0.62 * BAR_FONT


# why a field may have one value throughout a run (render_run's note)
UNIFORM_WHY = {"plastic_strain": " (no element yielded: only bodies with a yield_stress flow)"}


def _scalar_bar(field, width):
    """Colour bar arguments: vertical at the right edge, placed so that its labels stay inside an
    image ``width`` pixels wide (at 0.86 of the width, 640 px cut "-1.31e+06" to "-1.31e+0")."""
    return {"title": f"{field} ({FIELD_UNITS.get(field, '-')})", "color": "black", "vertical": True, "fmt": "%.3g",
            "title_font_size": BAR_FONT, "label_font_size": BAR_FONT, "width": BAR_WIDTH,
            "position_x": min(0.86, 1.0 - (BAR_ROOM + 16) / width), "position_y": 0.1}


def _bar_left(field, width):
    """Where the colour bar and its title, centred over it, begin (a fraction of the width)."""
    bar = _scalar_bar(field, width)
    title = 0.62 * BAR_FONT * len(bar["title"])         # pixels, as BAR_ROOM estimates a label
    return min(bar["position_x"], bar["position_x"] + (BAR_WIDTH * width - title) / (2 * width))


# the largest image side (pixels): off-screen OpenGL's own limit is 16384 at best, and a
# 40000 x 30000 frame ended the process in the renderer's allocation after the earlier render's
# files were gone
MAX_SIZE = 8192


def render_run(run_dir: Path | str, out: Path | str | None = None,
               size: tuple[int, int] = (960, 540), fps: float | None = None,
               field: str | None = None,
               progress: Callable[[int, int], None] | None = None,
               colour_range: str = "run") -> dict[str, Any]:
    """Render every saved frame of a run to PNG and assemble a movie.

    run_dir: a directory written by ``hybrid.app.output.RunWriter``.
    out: output folder (default ``run_dir/render``).
    size: (width, height) of the images in pixels.
    fps: movie frame rate; default the scene's output_fps, else from the frame times.
    field: colour by this cell (or point) field with a scalar bar, e.g. ``"von_mises"``;
        default colours each body by its ``body_id``.
    progress: called as ``progress(frames_done, frame_count)`` after each frame.
    colour_range: the field's colour scale: "run" (smallest to largest value over the run),
        "percentile" (2nd to 98th percentile over the run) or "frame" (each frame's own range).
        Only deformable bodies carry a field; rigid bodies are drawn grey.

    Returns ``{"pngs": [paths], "movie": path, "fps": fps, "backend": message, "note": text}``,
    the note (else None) saying that ``field`` has one value throughout the run. Raises
    RuntimeError with the packages to install when off-screen OpenGL is unavailable.
    """
    run_dir = Path(run_dir)
    times, frame_paths, summary = read_run(run_dir)
    if not frame_paths:
        raise ValueError(f"{run_dir} has no frames to render")
    out_dir = Path(out) if out is not None else run_dir / "render"
    scene = find_pvd(run_dir, summary).stem
    fps = float(fps) if fps else movie_fps(times, summary)
    width, height = int(size[0]), int(size[1])
    if not (16 <= width <= MAX_SIZE and 16 <= height <= MAX_SIZE):
        raise ValueError(f"--size {width} {height}: give a width and height of 16 to {MAX_SIZE} pixels")

    if colour_range not in COLOUR_RANGES:
        raise ValueError(f"colour range {colour_range!r}: one of {', '.join(COLOUR_RANGES)}")
    lo, hi, clim, association, constant = scene_bounds(frame_paths, field, colour_range)
    if field is not None and clim is None:
        # (the fields are the deformable bodies': a run of rigid bodies only has none)
        raise ValueError(f"no frame of {run_dir} has a field named {field!r} (fields are drawn on "
                         f"deformable bodies; rigid ones are grey: leave out --field to render them)")
    backend = use_backend()
    import pyvista as pv

    pv.OFF_SCREEN = True
    out_dir.mkdir(parents=True, exist_ok=True)
    # an earlier render's frames and movie (a rerun with fewer frames, or a GIF where ffmpeg was)
    for stale in (*out_dir.glob("frame_*.png"), *out_dir.glob(f"{scene}.mp4"), *out_dir.glob(f"{scene}.gif")):
        stale.unlink()

    plotter = pv.Plotter(off_screen=True, window_size=(width, height))
    movie = None
    try:
        room = 1.0 if field is None else _bar_left(field, width) - 0.02
        _set_stage(plotter, lo, hi, _scene_planes(summary), width / height, room)
        movie = _MovieWriter(out_dir / scene, fps)
        pngs = _render_frames(plotter, times, frame_paths, out_dir, movie, (field, association, clim, colour_range),
                              (width, height), progress)
    except BaseException:
        # a movie of the frames drawn before an interruption or error looks whole: none is left
        if movie is not None:
            movie.close()
            movie.path.unlink(missing_ok=True)
            movie = None
        raise
    finally:
        if movie is not None:
            movie.close()
        plotter.close()
    note = None if constant is None else (
        f"field {field!r} is {constant:g} in every deformable element of every frame, so the "
        "bodies are drawn in one colour" + UNIFORM_WHY.get(field, ""))
    return {"pngs": pngs, "movie": movie.path, "fps": fps, "backend": backend, "note": note}


def _set_stage(plotter, lo, hi, planes, aspect, room=1.0):
    """Background, the scene's planes as ground squares around the bodies' box ``lo``-``hi``
    (seen from their open side only: the walls of a bin between the camera and the bodies are
    not drawn), and a fixed camera that holds the whole box in the left ``room`` of the image's
    width (the rest is the colour bar's)."""
    import pyvista as pv

    plotter.set_background("#f7f8fa", top="#dde4ec")
    centre = (lo + hi) / 2
    ground_size = 2.5 * max(float(np.max(hi - lo)), 1e-3)
    for point, normal in planes:
        foot = centre - np.dot(centre - point, normal) * normal
        ground = pv.Plane(center=foot, direction=normal, i_size=ground_size, j_size=ground_size)
        plotter.add_mesh(ground, color=GROUND_COLOR, ambient=0.45, diffuse=0.55, specular=0.0,
                         culling="back")
    plotter.camera_position = camera_for_bounds(lo, hi, aspect * room)
    plotter.camera.view_angle = VIEW_ANGLE_DEG
    # the view's centre at the middle of that room: viewport x runs from -1 to 1
    plotter.camera.SetWindowCenter(1.0 - room, 0.0)
    plotter.reset_camera_clipping_range()
    # Keep the camera fixed even when later add_mesh calls would reset it.
    plotter.camera_set = True


def _add_bodies(plotter, mesh, colouring, width):
    """The bodies' mesh on screen: coloured by body, or by ``colouring`` = (field, association,
    clim, colour range) with a scalar bar."""
    field, association, clim, _ = colouring
    style = dict(show_edges=True, edge_color=(0.15, 0.15, 0.15), edge_opacity=0.25,
                 line_width=1.0, ambient=0.25, diffuse=0.75, specular=0.0,
                 name="bodies", reset_camera=False, render=False)
    if field is None:
        plotter.add_mesh(mesh, scalars="body_color", rgb=True, **style)
    else:
        plotter.add_mesh(mesh, scalars=field, preference=association, clim=clim, cmap="viridis",
                         nan_color=RIGID_GREY, scalar_bar_args=_scalar_bar(field, width), **style)


def _render_frames(plotter, times, frame_paths, out_dir, movie, colouring, size, progress):
    """Every frame, copied into the one mesh on screen with its time in a corner, to a PNG and
    the movie; returns the PNG paths."""
    import imageio.v3 as iio

    width, height = size
    shown = None  # the mesh on screen; later frames are copied into it (one actor)
    label = plotter.add_text("", position=(10, height - 28), font_size=12, color="black",
                             name="time", render=False)
    pngs: list[Path] = []
    for index, (time, path) in enumerate(zip(times, frame_paths)):
        mesh = _frame_mesh(path, colouring[0], colouring[1])
        if shown is None:
            shown = mesh
            _add_bodies(plotter, shown, colouring, width)
        else:
            shown.copy_from(mesh, deep=False)
        if colouring[3] == "frame":      # this frame's own range
            values = np.asarray(shown.cell_data[colouring[0]] if colouring[1] == "cell"
                                else shown.point_data[colouring[0]], dtype=float)
            values = values[np.isfinite(values)]
            if values.ndim == 1 and len(values):
                plotter.update_scalar_bar_range(_limits(values, "frame"))
        label.input = f"t = {time:.3f} s"
        plotter.reset_camera_clipping_range()
        plotter.render()
        image = plotter.screenshot(return_img=True)
        png = out_dir / f"frame_{index:05d}.png"
        iio.imwrite(png, image, compress_level=1)
        movie.append(image)
        pngs.append(png)
        if progress is not None:
            progress(index + 1, len(frame_paths))
    return pngs
