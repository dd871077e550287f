"""The writer process a Python process keeps for its runs (:data:`pool`), and its start ahead
of the first run (:func:`start_early`, called by ``hybrid run`` as it starts building the scene).

A run takes the idle writer process instead of starting one (no fork, no start-up beside the
stepping) and gives it back when it closes its files (:class:`hybrid.app.output.RunWriter`). It
ends with the Python process, as the fork server does (``writer_process._stop_all``); at exit
an early start still under way is waited for first (:func:`_settle`): a child asked of the fork
server by a thread killed half-way would make the server print an EOFError on the way out.
"""
from __future__ import annotations

import atexit
import os
import threading

from .writer_process import WriterProcess, fork_server, unavailable


class WriterPool:
    """The writer process a Python process keeps between its runs (at most one, idle, its files
    closed): a run takes it instead of starting one and gives it back when it closes its files;
    a writer whose run failed is stopped instead."""

    def __init__(self):
        self._idle: WriterProcess | None = None
        self._owner = os.getpid()           # (a process forked from this one has no child here)
        self._lock = threading.Lock()
        self.starting: threading.Thread | None = None      # the early start (start_early), if any

    def take(self, out_dir: str, pvd_name: str, index_every: float = 0.2) -> WriterProcess | None:
        """The idle writer process, writing the files of ``out_dir`` now; None if there is none
        (or this process may not have one now, :func:`unavailable`)."""
        if unavailable() is not None or os.getpid() != self._owner:
            return None
        with self._lock:
            process, self._idle = self._idle, None
        if process is None:
            return None
        try:
            if process.alive():
                process.reopen(out_dir, pvd_name, index_every)
                return process
        except OSError:
            pass                                # (it ended while idle: a new one)
        process.stop()
        return None

    def clear(self) -> None:
        """Stop the idle writer process, if any (of this process)."""
        with self._lock:
            process, self._idle = self._idle, None
        if process is not None and self._owner == os.getpid():
            process.stop()

    def give(self, process: WriterProcess, idle: bool = False) -> None:
        """Take ``process`` back at the end of its run (:meth:`WriterProcess.release`), or one
        started ``idle`` (no folder: ``WriterProcess(None, ...)``, awaiting :meth:`~WriterProcess.reopen`)."""
        if not (idle or process.release()):
            return
        with self._lock:
            # one idle writer is enough (one kept by the process this one was forked from is its own)
            old = self._idle if self._owner == os.getpid() else None
            self._idle, self._owner = process, os.getpid()
        if old is not None:
            old.stop()

    @property
    def idle_pid(self) -> int | None:
        """The idle writer process's id, or None."""
        idle = self._idle
        return idle.pid if idle is not None else None


pool = WriterPool()


def start_early() -> None:
    """Start this process's writer process ahead of its first run, idle, into :data:`pool`
    (``hybrid run`` calls it as it starts building the scene, which takes longer than the fork
    server's start): the run then writes by that process from its first frame, as a later run
    of a study does, instead of in place while the server starts. Returns at once; does nothing
    where no writer process can be had, or one is kept or starting already."""
    if unavailable() is not None or pool.idle_pid is not None or (pool.starting and pool.starting.is_alive()):
        return
    fork_server.start()         # (here: on the main thread, it ignores Ctrl-C while it imports)
    pool.starting = threading.Thread(target=_idle_writer, name="RunWriter early start", daemon=True)
    pool.starting.start()


def _idle_writer() -> None:
    """A writer process started idle, with no folder (it touches no file until a run reopens it on
    its own), given to the pool once it runs. Only the pool touches it after that: this thread
    never reads its replies, which the process's exit (writer_process._stop_all) may be reading."""
    try:
        process = WriterProcess(None, "")
    except (OSError, RuntimeError):
        return
    if process.start_error() is None:
        pool.give(process, idle=True)
    else:
        process.stop()          # (it never ran: nothing to read)


@atexit.register
def _settle(timeout: float = 10.0) -> None:
    """At exit (registered after writer_process._stop_all, so run before it): let an early start
    and the fork server's warm-up finish asking the server for their children."""
    if pool.starting is not None:
        pool.starting.join(timeout)
    fork_server.wait(timeout)
