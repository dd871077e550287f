"""Checkpoints: a run written to one file it can be continued from, bit for bit.

    hybrid run SCENE --checkpoint-every 0.05     # a checkpoint every 0.05 simulated seconds
    hybrid run SCENE --resume                    # continue from DIR/checkpoint.npz

``DIR/checkpoint.npz`` (format ``hybrid-checkpoint``, :data:`VERSION`) is a numpy ``.npz``
archive: the member ``manifest`` holds a JSON manifest as UTF-8 bytes (``uint8``), every other
member ``a0``, ``a1``, ... is an array the manifest names. The manifest holds the format and its
version, the hybrid version that wrote it, the scene's name and file with the SHA-256 of the
file's content, the time and step, and under ``content`` the run as a tree of plain values
(:mod:`hybrid.app.codec`): the coupled model and state (fracture pieces, rest shapes, held sets,
plastic strain, warm starts, parked auto bodies), the run's events, FEM time per body, the
recorder's totals and where the output files stood. It is read with ``allow_pickle=False`` and
only the project's own classes are built from it, so loading one runs no code from the file.
The file is written to a temporary name in the folder and moved into place, so a checkpoint
on disk is always whole; each member carries the zip CRC, so a damaged one is refused.
"""
import hashlib
import json
import math
import os
import signal
import tomllib
import threading
import time as clock
import zipfile
from contextlib import contextmanager
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

import numpy as np

from .codec import CodecError, decode, encode
from .output_resume import CHECKPOINT, ResumeError, check_folder
from .text_files import temporary_path

FORMAT = "hybrid-checkpoint"
VERSION = 1
# a run without --checkpoint-every writes one every tenth of its duration, or after this many
# seconds of wall time since the last one, whichever comes first; but none in its first
# QUICK seconds of wall time (a run that short loses little; a stop still writes one)
WALL_EVERY = 300.0
QUICK = 10.0


class CheckpointError(Exception):
    """A checkpoint that cannot be resumed from: missing, of another scene, truncated or
    corrupted, of another format version, or a run folder changed since (the message says which,
    naming the file)."""


@dataclass
class Position:
    """Where a run is and where it ends: until s (simulated time it runs to), end_step (the step
    it stops after), next_frame s (when the next frame is due), wall s (wall time of the run so
    far, resumed runs included), first_event (index in ``Simulation.events`` of the run's first),
    first_step (the simulation's step count when the run began)."""
    until: float
    end_step: int
    next_frame: float
    wall: float = 0.0
    first_event: int = 0
    first_step: int = 0


def scene_digest(scene):
    """SHA-256 (hex) of the scene file's content, with the scene's tables when they are not the
    file's (a scene changed in Python: resumed from its file alone, a run continued with the
    changed values and its summary showed the file's); of its tables when there is no file."""
    path = Path(str(scene.source_path))
    tables = json.dumps(scene.raw, sort_keys=True, default=str).encode()
    if not path.is_file():
        return hashlib.sha256(tables).hexdigest()
    content = path.read_bytes()
    try:
        as_file = tomllib.loads(content.removeprefix(b"\xef\xbb\xbf").decode("utf-8")) == scene.raw
    except (tomllib.TOMLDecodeError, UnicodeDecodeError):
        as_file = False
    return hashlib.sha256(content if as_file else content + tables).hexdigest()


def _version():
    try:
        return metadata.version("hybrid-sim")
    except metadata.PackageNotFoundError:
        return "unknown"


def write(path, sim, position, recorder):
    """Write the checkpoint of ``sim`` (a Simulation) at ``path`` atomically: its model and state,
    the run's events and counters, ``position`` and the ``recorder``'s totals and files."""
    content = {"model": sim.model, "state": sim.state, "events": sim.events[position.first_event:],
               "timings": sim.timings, "fem_time": sim.fem_time, "stepped_time": sim.stepped_time,
               "position": {"until": position.until, "end_step": position.end_step,
                            "next_frame": position.next_frame, "wall": position.wall,
                            "first_step": position.first_step},
               "recorder": recorder.snapshot()}
    tree, arrays = encode(content)
    manifest = {"format": FORMAT, "version": VERSION, "hybrid": _version(),
                "scene": sim.scene.name, "scene_file": str(sim.scene.source_path),
                "scene_sha256": scene_digest(sim.scene), "time": sim.time, "steps": sim.steps,
                "written": clock.strftime("%Y-%m-%dT%H:%M:%S%z"), "arrays": sorted(arrays),
                "content": tree}
    data = np.frombuffer(json.dumps(manifest).encode("utf-8"), dtype=np.uint8)
    path = Path(path)
    tmp = temporary_path(path)         # (created with the mode the other outputs get)
    try:
        with open(tmp, "wb") as f:
            np.savez(f, manifest=data, **arrays)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def _load(path):
    """``(manifest, arrays)`` of the checkpoint file; CheckpointError if it is missing, not a
    checkpoint, truncated or corrupted."""
    if not path.is_file():
        raise CheckpointError(f"{path}: no checkpoint to resume from (a run writes one when "
                              f"stopped and every --checkpoint-every; a run that finished removes "
                              f"it, and one ended at once by a second Ctrl-C or killed before its "
                              f"first leaves none: run it again without --resume)")
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {name: z[name] for name in z.files}       # reads all: checks every CRC
        manifest = json.loads(arrays.pop("manifest").tobytes().decode("utf-8"))
    except (zipfile.BadZipFile, ValueError, OSError, EOFError, KeyError, UnicodeDecodeError) as error:
        # (numpy's words for a file it takes for pickled data advise loading it unsafely: not here)
        why = "it is not a .npz archive" if "allow_pickle" in str(error) else error
        raise CheckpointError(f"{path}: truncated or corrupted checkpoint ({why}); it cannot be "
                              f"resumed from") from None
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise CheckpointError(f"{path}: not a hybrid checkpoint (no '{FORMAT}' manifest)")
    if manifest.get("version") != VERSION:
        raise CheckpointError(f"{path}: checkpoint format version {manifest.get('version')} "
                              f"(written by hybrid {manifest.get('hybrid')}); this hybrid "
                              f"({_version()}) reads version {VERSION} only")
    if sorted(arrays) != manifest.get("arrays"):
        raise CheckpointError(f"{path}: truncated or corrupted checkpoint (its arrays are not the "
                              f"ones its manifest lists)")
    return manifest, arrays


def read(path, scene):
    """The content of the checkpoint at ``path`` (see :func:`write`) for ``scene`` (the scene as
    loaded now), with the manifest under ``"manifest"``. Raises CheckpointError when it is
    missing, truncated or corrupted, of another format version, or of another scene file (its
    content's SHA-256 differs) or name (the run's files are named after it)."""
    path = Path(path)
    manifest, arrays = _load(path)
    digest = scene_digest(scene)
    if manifest.get("scene_sha256") != digest:
        raise CheckpointError(f"{path}: checkpoint of scene '{manifest.get('scene')}' (file "
                              f"{manifest.get('scene_file')}) with other values than "
                              f"{scene.source_path} gives now: the file's content differs, or "
                              f"the run changed its values (`hybrid run --set`: resume with the "
                              f"same --set, as the command printed when it stopped has them; the "
                              f"values of a scene changed in Python: resume with that scene, "
                              f"Simulation.resume(scene, out)) "
                              f"(SHA-256 {digest[:12]}..., the checkpoint's "
                              f"{str(manifest.get('scene_sha256'))[:12]}...)")
    if manifest.get("scene") != scene.name:        # (the same content in a file named otherwise)
        raise CheckpointError(f"{path}: checkpoint of scene '{manifest.get('scene')}' (file "
                              f"{manifest.get('scene_file')}), whose files it names after it, "
                              f"resumed as '{scene.name}': resume with the scene file under its "
                              f"name")
    try:
        content = decode(manifest["content"], arrays)
    except (CodecError, KeyError) as error:
        raise CheckpointError(f"{path}: written by hybrid {manifest.get('hybrid')}, whose stored "
                              f"classes this version does not read ({error})") from None
    content["manifest"] = manifest
    return content


class Stopped(Exception):
    """A run stopped by a signal after a whole step: ``signal`` (its number), ``time`` (s, where
    the run stopped), ``checkpoint`` (the file to resume from; None without an output folder or
    when it could not be written). ``exit_code``: 128 + the signal's number (130 for SIGINT,
    143 for SIGTERM). ``requested``: asked for from code (:meth:`StopRequest.set`, an event),
    not by the signal itself."""

    def __init__(self, signum, time, checkpoint, requested=False):
        name = signal.Signals(signum).name
        by = f"on request (as by {name})" if requested else f"by {name}"
        super().__init__(f"stopped {by} at t = {time:.6g} s")
        self.signal, self.time, self.checkpoint = signum, time, checkpoint
        self.exit_code = 128 + signum


class StopRequest:
    """What a run checks after each step: ``signal``, the number of the first stop signal
    received (None while there was none). :meth:`set` asks for a stop from code (another
    thread, a callback): the run stops as on that signal. ``requested``: the stop was asked for
    so, not by a signal."""

    def __init__(self):
        self.signal = None
        self.requested = False

    def set(self, signum=signal.SIGINT):
        """Ask the run to stop after its step, as on ``signum`` (its exit code 128 + signum)."""
        if self.signal is None:
            self.signal = int(signum)
            self.requested = True


_SIGINT = int(signal.SIGINT)


class EventStop(StopRequest):
    """A :class:`StopRequest` read from an event (``threading.Event`` or anything with
    ``is_set()`` and ``set()``): once it is set the run stops as on SIGINT."""
    requested = True

    def __init__(self, event):
        self.event = event

    def set(self, signum=signal.SIGINT):
        """Set the event: the run stops as on SIGINT (whatever ``signum``)."""
        self.event.set()

    @property
    def signal(self):
        """SIGINT's number once the event is set, else None (read as ``StopRequest.signal``)."""
        return _SIGINT if self.event.is_set() else None


def stop_request(stop):
    """``stop`` as a run reads it: None, a :class:`StopRequest`, or an event (:class:`EventStop`);
    TypeError for anything else (a run given one failed at its first step, reported unstable)."""
    if stop is None or isinstance(stop, StopRequest):
        return stop
    if callable(getattr(stop, "is_set", None)) and callable(getattr(stop, "set", None)):
        return EventStop(stop)
    raise TypeError(f"stop must be a hybrid.app.checkpoint.StopRequest or a threading.Event, "
                    f"not {type(stop).__name__}")


@contextmanager
def stop_on_signals(signals=(signal.SIGINT, signal.SIGTERM)):
    """While in the block, the first SIGINT or SIGTERM sets the yielded :class:`StopRequest`
    (a run given it finishes its step, writes a checkpoint and stops); a second one ends the
    process as the signal would (KeyboardInterrupt for SIGINT, exit 128 + its number otherwise).
    Nothing is installed outside the main thread. A signal the entry point's handler was given
    before (hybrid.app.entry: its exception swallowed where it landed) is taken as given here."""
    request = StopRequest()
    for s in signals:
        if request.signal is None and getattr(signal.getsignal(s), "received", False):
            request.signal = s
    if threading.current_thread() is not threading.main_thread():
        yield request
        return

    def handler(signum, frame):
        if request.signal is None:
            request.signal = signum
        elif signum == signal.SIGINT:
            raise KeyboardInterrupt
        else:
            raise SystemExit(128 + signum)

    previous = {s: signal.signal(s, handler) for s in signals}
    try:
        yield request
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


def check_every(every):
    """ValueError unless ``every`` is None or simulated seconds, finite and not negative (what
    ``Simulation.run(checkpoint_every=...)`` takes, as ``--checkpoint-every`` does)."""
    if every is None:
        return
    if isinstance(every, bool) or not isinstance(every, (int, float, np.integer, np.floating)) \
            or not (math.isfinite(every) and every >= 0):
        raise ValueError(f"checkpoint_every must be simulated seconds, 0 or more (0: a checkpoint "
                         f"only when stopped; None: the default), got {every!r}")


class Checkpoints:
    """When a run writes its checkpoints to ``out/checkpoint.npz`` (never without ``out``), and
    whether it was asked to stop. ``every``: simulated seconds between checkpoints (0: none but
    the one a stop writes); None: every tenth of the scene's duration, or :data:`WALL_EVERY`
    seconds of wall time after the last one, whichever comes first, none in the run's first
    :data:`QUICK` seconds of wall time. A stop writes one in any case. ``wall0``: the wall clock
    (``time.perf_counter``) at which the run's wall time would be zero. ``stop``: a
    :class:`StopRequest` or None. Messages (a checkpoint that could not be written) go to ``log``.
    """

    def __init__(self, sim, out, every, position, wall0, stop=None, log=print):
        self.sim, self.position, self.wall0, self.stop, self.log = sim, position, wall0, stop, log
        self.path = None if out is None else Path(out) / CHECKPOINT
        off = every is not None and not every > 0
        self.every = float("inf") if off else float(every or max(sim.scene.simulation.duration / 10,
                                                                  sim.dt))
        self.wall_every = WALL_EVERY if every is None else float("inf")
        self.next_time = sim.time + self.every
        self.quick_until = clock.perf_counter() + (QUICK if every is None else 0.0)
        self.next_wall = clock.perf_counter() + self.wall_every
        self.stopped = None

    def after_step(self, recorder):
        """Called after each step, its frame recorded: writes a checkpoint when one is due or a
        stop was asked. True when the run must stop now (``stopped`` then holds the
        :class:`Stopped` to raise once the run's files are closed)."""
        asked = self.stop is not None and self.stop.signal is not None
        now, t = clock.perf_counter(), self.sim.time
        written = None
        passed = t >= self.next_time - 1e-9 * self.sim.dt
        if self.path is not None and (asked or now >= self.next_wall
                                      or (passed and now >= self.quick_until)):
            written = self._write(recorder, now)
            self.next_wall = now + self.wall_every
        if self.next_time <= t + 1e-9 * self.sim.dt:
            # the first multiple of ``every`` past now, in one step (adding it in a loop never
            # ended for --checkpoint-every 1e-300, below the time's round-off)
            ahead = math.floor((t + 1e-9 * self.sim.dt - self.next_time) / self.every) + 1
            self.next_time = max(self.next_time + ahead * self.every, math.nextafter(t, math.inf))
        if asked:
            self.stopped = Stopped(self.stop.signal, t, written, self.stop.requested)
        return asked

    def _write(self, recorder, now):
        """Write the checkpoint; its path, or None (logged) when it could not be written."""
        position = Position(self.position.until, self.position.end_step, self.position.next_frame,
                            now - self.wall0, self.position.first_event, self.position.first_step)
        try:
            return write(self.path, self.sim, position, recorder)
        except (OSError, CodecError) as error:
            self.log(f"warning: checkpoint not written to {self.path}: {error}")
            return None

    def finished(self):
        """The run ended without a stop: its last checkpoint (now behind it) is removed."""
        if self.path is not None:
            self.path.unlink(missing_ok=True)


def restore(sim, scene, out):
    """Set ``sim`` (a bare Simulation) to the checkpoint in folder ``out`` of ``scene``: its
    model, state, events and counters; ``sim.resumed`` keeps what its next run continues from
    (:class:`Position`, the recorder's snapshot). Raises CheckpointError."""
    content = read(Path(out) / CHECKPOINT, scene)
    files = content["recorder"].get("files")
    if files is not None:           # said before the run starts, not once it has said "resuming"
        try:
            check_folder(out, files)
        except (ResumeError, OSError) as error:
            raise _changed(out, error) from None
    sim.scene, sim.warnings = scene, []
    sim.model, sim.state, sim.events = content["model"], content["state"], list(content["events"])
    sim.timings, sim.fem_time = content["timings"], content["fem_time"]
    sim.stepped_time = content["stepped_time"]
    p = content["position"]
    sim.resumed = (Position(p["until"], p["end_step"], p["next_frame"], p["wall"], 0, p.get("first_step", 0)),
                   content["recorder"])
    return sim


def resume_recorder(recorder, snapshot, out):
    """Continue ``recorder`` (a fresh hybrid.app.run.Recorder of folder ``out``) from its
    ``snapshot``: its totals, and its files taken back to the checkpoint. CheckpointError when
    the folder no longer holds what the checkpoint wrote."""
    try:
        recorder.restore(snapshot)
    except (ResumeError, OSError) as error:
        raise _changed(out, error) from None


def _changed(out, error):
    return CheckpointError(f"{out}: the run folder changed since the checkpoint ({error})")
