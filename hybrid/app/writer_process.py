"""The writer process of a run's output (:class:`WriterProcess`).

:class:`hybrid.app.output.RunWriter` checks each frame on the stepping thread
(:mod:`hybrid.app.frame_input`) and hands it over as plain data (numpy arrays,
numbers, strings: no simulation objects) in a job. A :class:`hybrid.app.vtu.FrameFiles` runs the
jobs in order: it merges the bodies into one mesh, encodes the ``.vtu``, appends the CSV rows
and keeps the ``.pvd`` index. It runs on the caller's thread, on a writer thread, or in a writer
process: a child process of the run (started through multiprocessing's fork server, so it is
never forked from a process whose numba or BLAS threads are running) that receives the jobs
pickled through a pipe. The stepping thread's part is then
to check and copy; the interpreter lock no longer makes the stepping wait for the encoding.

The process ignores SIGINT (a Ctrl-C reaches every process of the terminal's group; the run
stops cleanly and closes its writer, which writes every frame handed over), writes what it has
received, and stops at the first job that fails: later jobs are dropped and the error is raised
on the stepping thread, naming the process. When the run closes its writer the process closes
the run's files and waits, idle, for the next run of the same Python process
(:mod:`hybrid.app.writer_pool`); it ends when that process ends or is gone (its end of the pipe closed). Its own
side is :mod:`hybrid.app.writer_child`.
"""
from __future__ import annotations

import atexit
import multiprocessing
import multiprocessing.util
import os
import pickle
import queue
import re
import select
import sys
import threading
import weakref
from collections import deque
from pathlib import Path

from . import fork_server as forking
from .fork_server import start_fork_server
from .frame_input import KeptArrays
from .writer_child import serve


class WriterProcessError(OSError):
    """The writer process ended without saying why (killed, or out of memory): an output failure
    (an OSError, as a full disk), not the physics."""


class RemoteTraceback(Exception):
    """The traceback of an error raised in the writer process (the ``__cause__`` of the error
    raised again on the stepping thread)."""

    def __str__(self):
        return self.args[0]


def unavailable() -> str | None:
    """Why this process cannot start a writer process, or None when it can."""
    if multiprocessing.current_process().daemon:
        return "a daemonic process (a Dask worker) cannot start processes"
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return "multiprocessing's fork server is not available on this platform"
    main = sys.modules.get("__main__")
    path = getattr(main, "__file__", None)
    if path is None or getattr(main, "__spec__", None) is not None:
        return None                 # interactive, -c, or run by name (python -m): not imported again
    if getattr(getattr(main, "main", None), "__module__", None) == "hybrid.app.cli":
        return None                 # the hybrid command
    try:
        text = Path(path).read_text(errors="replace")
    except OSError:
        text = ""
    if not _MAIN_GUARD.search(text):
        # multiprocessing imports the main script again in the new process: a script without
        # the guard would run again there
        return f"the script {path} has no 'if __name__ == \"__main__\":' guard"
    return None


_MAIN_GUARD = re.compile(r"""^if\s+__name__\s*==\s*['"]__main__['"]\s*:""", re.MULTILINE)


fork_server = forking.fork_server      # the fork server, as the auto writers see it


class WriterProcess:
    """Runs :class:`FrameFiles` jobs in a child process, in order (the process counterpart of
    :class:`hybrid.app.writer_thread.WriterThread`, with jobs as data).

    Jobs are pickled on the caller's thread (a copy: the caller may change its arrays as soon as
    :meth:`submit` returns) and written to the pipe when it surely takes them at once, else by a
    feeder thread, so the caller does not wait for a child that is starting or busy; it waits when more than ``limit_bytes`` of jobs (and more
    than ``limit`` jobs) are in flight. ``start_method``: ``forkserver`` (default; the fork
    server is started once per process and imports this module, so a writer process starts in a
    few ms) or ``spawn``. With ``out_dir`` None it starts idle, touching no file until :meth:`reopen`
    gives it a run's folder."""

    limit = 8
    limit_bytes = 64 << 20
    direct_bytes = 64 << 10
    start_method = "forkserver"

    def __init__(self, out_dir: str | None, pvd_name: str, index_every: float = 0.2, start_method: str | None = None):
        why = unavailable()
        if why is not None:
            raise RuntimeError(f"no writer process: {why}")
        method = start_method or self.start_method
        context = multiprocessing.get_context(method)
        receive, self._jobs = context.Pipe(duplex=False)
        self._replies, send = context.Pipe(duplex=False)
        # (absolute: a writer kept for a later run does not follow a change of directory)
        self._process = context.Process(target=serve, args=(receive, send, out_dir and os.path.abspath(out_dir), pvd_name, index_every),
                                        name="RunWriter process", daemon=True)
        if method == "forkserver":     # (its imports done once: a writer process starts in ms)
            start_fork_server()
        # whether a reply waits: one poll(2) call (Connection.poll builds a selector each time)
        self._replied = select.poll()
        self._replied.register(self._replies.fileno(), select.POLLIN)
        # the feeder thread starts the child (2-4 ms waiting for the fork server's fork, not on
        # the caller's thread), then sends the payloads put in the outbox, in order; large jobs
        # go by it, and all jobs until it has sent those before (a pipe of 1 MB takes a frame in
        # one write). _handed: items put in the outbox, the start first; _fed (written by the
        # feeder only): [items it has done, the error that stopped the child's start or None]
        self._pipe_bytes = _widen(self._jobs)
        self._outbox: queue.SimpleQueue = queue.SimpleQueue()
        self._handed, self._fed = 1, [0, None]
        self._started = threading.Event()
        self._feeder = threading.Thread(target=_feed, name="RunWriter feeder", daemon=True,
                                        args=(self._process, (receive, send), self._started, self._outbox,
                                              self._jobs, self._fed))
        self._feeder.start()
        self.seconds = 0.0                  # the child's time in jobs (s)
        self._sent = self._done = 0
        self._in_flight: deque[int] = deque()   # bytes of the jobs not yet done, in order
        self._in_flight_bytes = 0
        self._error: BaseException | None = None
        self._error_raised = False
        self._gone = False                  # the child's end of the replies closed
        self._state: dict | None = None
        self._keeping = KeptArrays()
        self._owner = os.getpid()
        _LIVE.add(self)
        # a worker of a process pool (any multiprocessing child) ends by multiprocessing's exit
        # function, not atexit, which joins its children: a writer kept idle for a next run (it
        # ignores SIGTERM, to write what it has) waited for jobs for ever, and the worker with it
        self._exit_hook = multiprocessing.util.Finalize(self, _stop_at_exit, args=(weakref.ref(self),),
                                                        exitpriority=10)
        # a writer dropped without stop(): its process still writes what it has and ends
        self._finalizer = weakref.finalize(self, _finish, self._process, self._outbox, self._feeder)

    @property
    def pid(self) -> int | None:
        """The writer process's id (None if it could not start); waits until it has started."""
        self.start_error()
        return self._process.pid

    def start_error(self) -> BaseException | None:
        """Wait until the child has started; the error that kept it from starting, or None."""
        while not self._started.wait(1.0):
            if not self._feeder.is_alive():         # (it ended before it tried)
                return WriterProcessError("the writer's feeder thread ended early")
        return self._fed[1]

    def submit(self, job: tuple, always: bool = False) -> None:
        """Hand ``job`` over; dropped when an earlier job failed (see :meth:`raise_error`) unless
        ``always`` (the child still answers ``state``)."""
        self._read(block=False)
        if self._error is None and len(self._in_flight) > self.limit \
                and self._in_flight_bytes > self.limit_bytes:
            self.wait()
        if self._error is not None and not always or self._gone:
            return
        self._send(job)

    def _send(self, job: tuple) -> None:
        payload = self._keeping.dumps(job)
        self._in_flight.append(len(payload))
        self._in_flight_bytes += len(payload)
        self._sent += 1
        # a small job is written here when the pipe surely takes it at once (the feeder idle, all
        # unfinished jobs fit): by the feeder a 2 kB frame cost 0.25 ms of CPU (its wake-up, the
        # lock), here 0.01 ms; larger ones (a 200 kB frame: 2 ms here) go by the feeder
        if len(payload) > self.direct_bytes or self._handed > self._fed[0] \
                or self._in_flight_bytes + 8 * len(self._in_flight) > self._pipe_bytes:
            self._handed += 1
            self._outbox.put(payload)
            return
        try:
            self._jobs.send_bytes(payload)
        except OSError:
            pass                # the child is gone: _read reports it

    def _read(self, block: bool) -> None:
        """Take the child's replies (blocking for one when ``block``; none once stopped)."""
        if self._process is None:
            return
        if self._fed[1] is not None and not self._gone:
            self._gone = True
            self._error = self._error or WriterProcessError(f"the writer process could not start: {self._fed[1]}")
            return
        while not self._gone and (block or self._replied.poll(0)):
            if block and not self._replied.poll(1000):          # no reply for a second
                if not self._feeder.is_alive() and self._fed[0] < self._handed:
                    # the feeder thread ended with jobs it did not send: no reply can come
                    self._gone = True
                    self._error = self._error or WriterProcessError("the writer's feeder thread ended early")
                    return
                continue
            block = False
            try:
                kind, *values = self._replies.recv()
            except (EOFError, OSError):
                self._gone = True
                self._process.join(5.0)
                self._error = self._error or WriterProcessError(
                    f"the writer process (pid {self.pid}) ended unexpectedly (exit code "
                    f"{self._process.exitcode}); the frames it wrote stay (the .pvd may not list the last ones)")
                return
            if kind == "done":
                done, self.seconds, result = values
                for _ in range(done - self._done):
                    self._in_flight_bytes -= self._in_flight.popleft()
                self._done = done
                if result is not None:
                    self._state = result
            elif kind == "error" and self._error is None:
                error, remote = values
                error.__cause__ = RemoteTraceback(remote)
                error.add_note(f"(raised in the run's writer process, pid {self.pid})")
                self._error = error

    def pending(self) -> int:
        """Jobs handed over and not yet done."""
        self._read(block=False)
        return self._sent - self._done

    def wait(self) -> None:
        """Block until every job handed over is done (or dropped after a failure)."""
        self._read(block=False)
        if not self._gone and self._done < self._sent:
            self._send(("sync",))               # answered once the jobs before it are done
        while not self._gone and self._done < self._sent:
            self._read(block=True)

    def state(self) -> dict:
        """The files' :meth:`FrameFiles.state` once every job before is done (also after a
        failure: the files as the failure left them)."""
        self._state = None
        self.submit(("state",), always=True)
        self.wait()
        if self._state is None:
            self.raise_error()
            raise self._error
        return self._state

    def raise_error(self) -> None:
        """Raise the writer's error, once (later calls return)."""
        self._read(block=False)
        if self._error is not None and not self._error_raised:
            self._error_raised = True
            raise self._error

    def release(self) -> bool:
        """Close this run's files, every job done, and keep the process for another run
        (:meth:`reopen`): True when it can be kept (it is alive and no job failed); otherwise
        it is stopped (its error kept for :meth:`raise_error`)."""
        self.wait()
        if self._error is None and not self._gone:
            # answered once the files are closed; no sync after it (the child then awaits "open")
            self.submit(("release",))
            while not self._gone and self._done < self._sent:
                self._read(block=True)
        if self._error is not None or self._gone:
            self.stop()
            return False
        return True

    def alive(self) -> bool:
        """Whether the child runs and can take jobs (not stopped, gone or failed)."""
        if self._process is None or self._gone:
            return False
        self._read(block=False)
        return not self._gone and self._error is None and self._process.is_alive()

    def reopen(self, out_dir: str, pvd_name: str, index_every: float = 0.2) -> None:
        """Write another run's files (a released writer: nothing in flight, its feeder idle)."""
        self.seconds, self._sent, self._done, self._state = 0.0, 0, 0, None
        self._in_flight.clear()
        self._in_flight_bytes = 0
        self._keeping = KeptArrays()
        self._jobs.send_bytes(pickle.dumps(("open", os.path.abspath(out_dir), pvd_name, index_every)))

    def stop(self, timeout: float = 60.0) -> None:
        """Let the child write what it has, close its files and end; it is terminated if it has
        not ended after ``timeout`` s. Its error, if any, is kept for :meth:`raise_error`."""
        if self._process is None:
            return
        self._outbox.put(b"")
        self._outbox.put(None)
        self._feeder.join()
        self._read(block=False)
        _finish(self._process, None, None, timeout)
        self._finalizer.detach()
        for conn in (self._jobs, self._replies):
            conn.close()
        self._process.close()
        self._process = None
        self._exit_hook.cancel()
        _LIVE.discard(self)


_LIVE: "weakref.WeakSet[WriterProcess]" = weakref.WeakSet()

def _feed(process, child_ends, started, outbox, jobs, fed) -> None:
    """The feeder thread: start ``process`` (closing this process's copies of its ends of the
    pipes), then send the payloads put in ``outbox``, in order, until None; ``fed``: [items done,
    the start counted, the error that stopped the start or None]. A module function, so that
    the thread keeps no reference to its writer (a writer dropped unstopped is finalised)."""
    try:
        process.start()
    except BaseException as error:      # noqa: BLE001 (reported by WriterProcess._read)
        fed[1] = error
    finally:
        for end in child_ends:
            end.close()
        started.set()
    fed[0] += 1
    while (payload := outbox.get()) is not None:
        if fed[1] is None:
            try:
                jobs.send_bytes(payload)
            except OSError:
                pass        # the child is gone: WriterProcess._read reports it
        fed[0] += 1


def _widen(connection) -> int:
    """Make the pipe of ``connection`` hold 1 MB if the system allows; the bytes it holds."""
    try:
        import fcntl
        fcntl.fcntl(connection.fileno(), getattr(fcntl, "F_SETPIPE_SZ", 1031), 1 << 20)
        return int(fcntl.fcntl(connection.fileno(), getattr(fcntl, "F_GETPIPE_SZ", 1032)))
    except (ImportError, OSError):
        return 4096


def _finish(process, outbox, feeder, timeout: float = 60.0) -> None:
    """End ``process``: the stop message through ``outbox`` and the ``feeder`` done (unless
    done already), then wait for it (terminated after ``timeout`` s)."""
    if outbox is not None:
        outbox.put(b"")
        outbox.put(None)
    if feeder is not None and feeder is not threading.current_thread():
        feeder.join()
    if process.pid is None:
        return              # never started
    process.join(timeout)
    if process.exitcode is None:
        process.terminate()
        process.join(5.0)


@atexit.register
def _stop_all() -> None:
    """At exit, before multiprocessing ends its daemonic children (registered after its own
    exit function, so run before it): this process's writer processes still running write what
    they have and end (those a forked process inherited are its parent's)."""
    for writer in list(_LIVE):
        if writer._owner == os.getpid():
            writer.stop()


def _stop_at_exit(ref) -> None:
    """At multiprocessing's exit, the writer ``ref`` (a weak reference) stopped if it is still
    there and this process's (a forked process inherits its parent's)."""
    writer = ref()
    if writer is not None and writer._owner == os.getpid():
        writer.stop()
