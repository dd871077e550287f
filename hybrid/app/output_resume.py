"""A run's output files continued after a checkpoint: :class:`ResumableWriter`.

A checkpoint (:mod:`hybrid.app.checkpoint`) keeps :meth:`ResumableWriter.snapshot`: how many
frames were written with their times, the field names the frames carry (in order), and the
lengths of ``bodies.csv`` and ``regions.csv``. :meth:`ResumableWriter.resume` takes the run
folder back to that point: frames written after it are deleted, the tables cut to those lengths
(rows an interrupted run wrote after the checkpoint are dropped), ``summary.json`` removed, the
``.pvd`` index rewritten; the run then appends as if it had never stopped.
"""
import os
from pathlib import Path

from .output import FRAMES_DIR, RunWriter
from .run_files import BODIES_CSV, FRAME_PATTERN, REGIONS_CSV, SUMMARY_JSON
from .text_files import atomic_write_text as _atomic_write_text
from .vtu import pvd_text as _pvd_text

CHECKPOINT = "checkpoint.npz"


class ResumeError(ValueError):
    """The run folder no longer holds what the checkpoint wrote (the message names the file)."""


WRITERS = ("auto", "process", "thread", "inline")


def writer_from_environment():
    """The writer the environment variable ``HYBRID_WRITER`` asks for (any case; ``true`` and
    ``false`` as ``thread`` and ``inline``), ``auto`` when it is not set. Raises ValueError naming
    the variable and the values allowed."""
    given = os.environ.get("HYBRID_WRITER", "auto")
    mode = {"true": "thread", "false": "inline"}.get(given.strip().lower(), given.strip().lower())
    if mode not in WRITERS:
        raise ValueError(f"HYBRID_WRITER={given!r}: must be one of {', '.join(WRITERS)} (or unset: auto)")
    return mode


class ResumableWriter(RunWriter):
    """A :class:`hybrid.app.output.RunWriter` whose files can be continued after a checkpoint;
    a new run also removes an earlier run's checkpoint with its other files. It writes with
    ``background="auto"`` unless told otherwise, here or by the environment variable
    ``HYBRID_WRITER`` (``auto``, ``process``, ``thread``, ``inline``): a run's files are written
    by a writer process once multiprocessing's fork server is up (see
    :class:`hybrid.app.output.RunWriter`)."""

    def __init__(self, out_dir, scene_name, background=None):
        super().__init__(out_dir, scene_name, writer_from_environment() if background is None else background)

    def _start(self):
        """Create the run folder on first output, clearing an earlier run's files and checkpoint."""
        if not self._started and not self._closed:
            self._take_lock()           # (another run's checkpoint is left alone)
            (self.out_dir / CHECKPOINT).unlink(missing_ok=True)
        super()._start()

    def snapshot(self):
        """What :meth:`resume` needs to continue these files from now (a JSON-ready dict); waits
        for the frames handed over to reach the disk."""
        state = self._file_state()
        return {"frames": state["count"], "times": state["times"], "files": state["files"],
                "cell_fields": [[n, list(s)] for n, s in self._cell_fields.items()],
                "point_fields": [[n, list(s)] for n, s in self._point_fields.items()],
                "tables": state["tables"]}

    def resume(self, snapshot):
        """Take the run folder back to ``snapshot`` and append from there. Raises ResumeError
        when a frame or table the snapshot counts is missing or shorter."""
        self._take_lock()
        self._wait()
        check_folder(self.out_dir, snapshot)
        times = [float(t) for t in snapshot["times"]]
        files = [str(f) for f in snapshot["files"]]
        tables = {name: snapshot["tables"].get(name) for name in (BODIES_CSV, REGIONS_CSV)}
        for stale in self.frames_dir.iterdir() if self.frames_dir.is_dir() else ():
            if FRAME_PATTERN.match(stale.name) and f"{FRAMES_DIR}/{stale.name}" not in files:
                stale.unlink()
        for name, length in tables.items():
            self._cut(name, length)
        (self.out_dir / SUMMARY_JSON).unlink(missing_ok=True)
        _atomic_write_text(self.pvd_path, _pvd_text(times, files))
        self._cell_fields = {n: tuple(s) for n, s in snapshot["cell_fields"]}
        self._point_fields = {n: tuple(s) for n, s in snapshot["point_fields"]}
        self._queued = int(snapshot["frames"])
        self._submit(("restore", {"count": self._queued, "times": times, "files": files,
                                  "tables": [name for name, length in tables.items() if length is not None]}))
        self._wait()
        self._started = True

    def _cut(self, name, length):
        """The table ``name`` cut to ``length`` bytes (removed when the checkpoint had none)."""
        path = Path(self.out_dir) / name
        if length is None:
            path.unlink(missing_ok=True)
            return
        with open(path, "r+b") as f:
            f.truncate(length)


def check_folder(out_dir, snapshot):
    """ResumeError when run folder ``out_dir`` no longer holds what a writer's ``snapshot``
    counts: a frame missing or not a whole ``.vtu``, a table missing or shorter than it was."""
    out_dir = Path(out_dir)
    for name in (str(f) for f in snapshot["files"]):
        if not (out_dir / name).is_file():
            raise ResumeError(f"{out_dir / name}: missing, the checkpoint counts it")
        if not _whole_vtu(out_dir / name):
            raise ResumeError(f"{out_dir / name}: not a whole .vtu file (damaged since it "
                              f"was written), the checkpoint counts it")
    for name in (BODIES_CSV, REGIONS_CSV):
        length, path = snapshot["tables"].get(name), out_dir / name
        size = path.stat().st_size if path.is_file() else -1
        if length is not None and size < length:
            raise ResumeError(f"{path}: {'missing' if size < 0 else f'{size} bytes'}, the checkpoint "
                              f"wrote {length}")


def _whole_vtu(path):
    """Whether ``path`` reads as a whole .vtu file as the writer leaves one: an XML declaration or
    VTKFile element at its head and the VTKFile element closed at its tail (a frame overwritten
    with garbage was resumed past, leaving a file no reader opens)."""
    with open(path, "rb") as f:
        head = f.read(64)
        f.seek(0, 2)
        f.seek(max(0, f.tell() - 64))
        tail = f.read()
    return head.lstrip().startswith((b"<?xml", b"<VTKFile")) and tail.rstrip().endswith(b"</VTKFile>")
