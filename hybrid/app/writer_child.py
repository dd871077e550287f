"""The writer process's own side (:func:`serve`): it runs the jobs of one run after another
that :class:`hybrid.app.writer_process.WriterProcess` sends it, in order, and answers on the
replies pipe. Imported by the fork server, so that a writer process starts without imports."""
from __future__ import annotations

import math
import pickle
import select
import signal
import time
import traceback

from .frame_input import KeptArrays
from .vtu import FrameFiles

# A pipe write that wakes a reader blocked on the pipe costs the writing process 40-50 us on a
# virtual machine (waking the other core), a third of a small frame's hand-over. For NAPPING s
# after each job the writer process naps NAP s at a time and looks for the next one instead of
# blocking, so that a run handing over frames more often than that wakes no one; after that it
# blocks (a run that hands over a frame a second pays the wake-up, not a thousand looks a second).
NAP = 0.001
NAPPING = 0.05


def serve(jobs, replies, out_dir: str | None, pvd_name: str, index_every: float) -> None:
    """The writer process: run the jobs received on ``jobs`` until an empty message (stop) or
    the end of the pipe, replying ``("done", jobs done, seconds, result)`` or ``("error", error,
    traceback)`` on ``replies``. A ``("release",)`` job closes the run's files (answered with the
    result ``"released"``); an ``("open", out_dir, pvd_name, index_every)`` message then starts
    the next run's, its jobs counted from zero; with ``out_dir`` None it awaits that message first
    (started idle). Ctrl-C and SIGTERM are the run's to handle (sent
    to the whole process group, they reach this process too): it keeps writing until the run
    stops it, or until the run's process is gone."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    waiting = select.poll()
    waiting.register(jobs.fileno(), select.POLLIN)
    target = (out_dir, pvd_name, index_every) if out_dir is not None else _next_run(jobs)
    while target is not None:
        target = _serve_run(jobs, replies, waiting, FrameFiles(*target))


def _serve_run(jobs, replies, waiting, files: FrameFiles) -> tuple | None:
    """One run's jobs, written by ``files``; the next run's ``(out_dir, pvd_name, index_every)``
    after a release, or None at the stop."""
    keeping = KeptArrays()
    seconds, failed, done = 0.0, False, 0
    last = time.monotonic()
    try:
        while True:
            # while jobs come often, nap and look instead of blocking (see NAP)
            while not waiting.poll(0) and time.monotonic() - last < NAPPING:
                time.sleep(NAP)
            payload = _receive(jobs)
            if payload is None:
                return None                 # stopped, or the run's process is gone
            job = keeping.loads(payload)
            if job[0] == "release":
                break
            result = None
            if job[0] != "sync" and (not failed or job[0] == "state"):
                start = time.perf_counter()
                try:
                    result = files.run(job, idle=not waiting.poll(0))
                except BaseException as error:     # noqa: BLE001 (sent to the stepping thread)
                    failed = True
                    _reply_error(replies, error)
                seconds += time.perf_counter() - start
            done += 1
            # a reply when the run waits (a sync job), with a result, and every 32 jobs: not one
            # per job (a reply read on the stepping thread costs 40-50 us)
            if result is not None or done % 32 == 0 or job[0] == "sync":
                replies.send(("done", done, seconds, result))
            # (the run waits for a sync: what comes next, often the stop, is answered at once)
            last = -math.inf if job[0] == "sync" else time.monotonic()
    finally:
        if not failed:
            files.index()
        files.close()
    replies.send(("done", done + 1, seconds, "released"))
    return _next_run(jobs)


def _next_run(jobs) -> tuple | None:
    """The next run's ``(out_dir, pvd_name, index_every)`` (an ``open`` message), or None at the stop."""
    payload = _receive(jobs)
    job = None if payload is None else pickle.loads(payload)
    return tuple(job[1:]) if job is not None and job[0] == "open" else None


def _receive(jobs) -> bytes | None:
    """The next message, or None for the stop (an empty one) or the end of the pipe."""
    try:
        payload = jobs.recv_bytes()
    except (EOFError, OSError):
        return None
    return payload or None


def _reply_error(replies, error: BaseException) -> None:
    """Send ``error`` with its traceback (as a RuntimeError naming it if it does not pickle)."""
    remote = "".join(traceback.format_exception(error))
    try:
        pickle.loads(pickle.dumps(error))
    except Exception:                       # noqa: BLE001
        error = RuntimeError(f"{type(error).__name__}: {error}")
    replies.send(("error", error, remote))
