"""A run's output files continued after a checkpoint: :class:`ResumableWriter`.

A checkpoint (:mod:`hybrid.app.checkpoint`) keeps :meth:`ResumableWriter.snapshot`: how many
frames were written with their times, the field names the frames carry (in order), and the
lengths of ``bodies.csv`` and ``regions.csv``. :meth:`ResumableWriter.resume` takes the run
folder back to that point: frames written after it are deleted, the tables cut to those lengths
(rows an interrupted run wrote after the checkpoint are dropped), ``summary.json`` removed, the
``.pvd`` index rewritten; the run then appends as if it had never stopped.
"""
from pathlib import Path

from .output import (BODIES_CSV, FRAME_PATTERN, FRAMES_DIR, REGIONS_CSV, SUMMARY_JSON, RunWriter,
                     _atomic_write_text, _pvd_text)

CHECKPOINT = "checkpoint.npz"


class ResumeError(ValueError):
    """The run folder no longer holds what the checkpoint wrote (the message names the file)."""


class ResumableWriter(RunWriter):
    """A :class:`hybrid.app.output.RunWriter` whose files can be continued after a checkpoint;
    a new run also removes an earlier run's checkpoint with its other files."""

    def _start(self):
        """Create the run folder on first output, clearing an earlier run's files and checkpoint."""
        if not self._started and not self._closed:
            (self.out_dir / CHECKPOINT).unlink(missing_ok=True)
        super()._start()

    def _tables(self):
        """``(file name, open file or None)`` of the two tables."""
        return ((BODIES_CSV, self._bodies_file), (REGIONS_CSV, self._regions_file))

    def snapshot(self):
        """What :meth:`resume` needs to continue these files from now (a JSON-ready dict)."""
        for _, f in self._tables():
            if f is not None:
                f.flush()
        return {"frames": self.frames_written, "times": list(self._times), "files": list(self._files),
                "cell_fields": [[n, list(s)] for n, s in self._cell_fields.items()],
                "point_fields": [[n, list(s)] for n, s in self._point_fields.items()],
                "tables": {name: f.tell() for name, f in self._tables() if f is not None}}

    def resume(self, snapshot):
        """Take the run folder back to ``snapshot`` and append from there. Raises ResumeError
        when a frame or table the snapshot counts is missing or shorter."""
        self.frames_written = int(snapshot["frames"])
        self._times = [float(t) for t in snapshot["times"]]
        self._files = [str(f) for f in snapshot["files"]]
        self._cell_fields = {n: tuple(s) for n, s in snapshot["cell_fields"]}
        self._point_fields = {n: tuple(s) for n, s in snapshot["point_fields"]}
        for name in self._files:
            if not (self.out_dir / name).is_file():
                raise ResumeError(f"{self.out_dir / name}: missing, the checkpoint counts it")
        for stale in self.frames_dir.iterdir() if self.frames_dir.is_dir() else ():
            if FRAME_PATTERN.match(stale.name) and f"{FRAMES_DIR}/{stale.name}" not in self._files:
                stale.unlink()
        self._bodies_file = self._cut(BODIES_CSV, snapshot["tables"].get(BODIES_CSV))
        self._regions_file = self._cut(REGIONS_CSV, snapshot["tables"].get(REGIONS_CSV))
        (self.out_dir / SUMMARY_JSON).unlink(missing_ok=True)
        _atomic_write_text(self.pvd_path, _pvd_text(self._times, self._files))
        self._started = True

    def _cut(self, name, length):
        """The table ``name`` cut to ``length`` bytes and open for appending (None, and the file
        removed, when the checkpoint had none)."""
        path = Path(self.out_dir) / name
        if length is None:
            path.unlink(missing_ok=True)
            return None
        size = path.stat().st_size if path.is_file() else -1
        if size < length:
            raise ResumeError(f"{path}: {'missing' if size < 0 else f'{size} bytes'}, the checkpoint "
                              f"wrote {length}")
        with open(path, "r+b") as f:
            f.truncate(length)
        return open(path, "a", encoding="utf-8", newline="")
