"""A writer thread: file work run in order off the caller's thread (:class:`WriterThread`).

:class:`hybrid.app.output.RunWriter` hands it the writing of each frame, so the step loop does
not wait for the disk. The thread lives while there is work and LINGER seconds after, so
frames that come faster reuse it, and ends at once when :meth:`WriterThread.wait` is called (it
never keeps the interpreter alive long once the work is done); at most ``limit`` jobs wait, beyond that the caller
waits. The first job that raises stops it: later jobs are dropped, and the error is raised once
on the caller's thread by :meth:`WriterThread.raise_error`.
"""
from __future__ import annotations

import threading
import time
from collections import deque
from typing import Callable

# how long (s) an idle thread waits for the next job before it ends: a new thread for every
# frame cost its start (60-110 us on a quiet machine, milliseconds on a busy one) on the
# stepping thread, which waits for the thread to come up
LINGER = 0.5


class WriterThread:
    """Runs jobs (callables without arguments) in the order given, on a thread of its own, or at
    once on the caller's thread when ``background`` is false (the same work, for comparison and
    debugging). ``seconds``: wall time spent in jobs so far."""

    def __init__(self, background: bool = True, limit: int = 8, name: str = "writer"):
        self.background, self.limit, self.name = bool(background), int(limit), name
        self.seconds = 0.0
        self._jobs: deque = deque()
        self._busy = False                    # a job taken from the queue is running
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        self._error_raised = False
        self._ending = False                  # wait() asked the thread to end once idle
        self._lock = threading.Condition()

    def submit(self, job: Callable[[], None]) -> None:
        """Run ``job`` after the jobs before it; waits while ``limit`` jobs are waiting. A job
        submitted after one failed is dropped (the failure is raised by :meth:`raise_error`)."""
        if not self.background:
            start = time.perf_counter()
            try:
                job()
            except BaseException as error:
                self._error, self._error_raised = error, True
                raise
            finally:
                self.seconds += time.perf_counter() - start
            return
        with self._lock:
            while len(self._jobs) >= self.limit and self._error is None:
                self._lock.wait()
            if self._error is not None:
                return
            self._jobs.append(job)
            self._ending = False
            self._lock.notify_all()           # (a lingering thread takes it)
            if self._thread is None:
                self._thread = threading.Thread(target=self._work, name=self.name, daemon=False)
                self._thread.start()

    def _work(self) -> None:
        """The thread: run the jobs in order until none is left for LINGER seconds, or
        :meth:`wait` asks it to end, or a job fails."""
        while True:
            with self._lock:
                idle_until = time.monotonic() + LINGER
                while not self._jobs and self._error is None and not self._ending:
                    left = idle_until - time.monotonic()
                    if left <= 0.0:
                        break
                    self._lock.wait(left)
                if not self._jobs or self._error is not None:
                    self._jobs.clear()
                    self._thread = None
                    self._lock.notify_all()
                    return
                job = self._jobs.popleft()
                self._busy = True
                self._lock.notify_all()
            start = time.perf_counter()
            try:
                job()
            except BaseException as error:     # noqa: BLE001 (kept for the caller's thread)
                with self._lock:
                    self._error = error
            finally:
                with self._lock:
                    self._busy = False
                    self.seconds += time.perf_counter() - start

    def pending(self) -> int:
        """Jobs waiting to run (not counting the one running)."""
        with self._lock:
            return len(self._jobs)

    def wait(self) -> None:
        """Block until every job submitted has run (or was dropped after a failure)."""
        thread = self._thread
        if thread is None or thread is threading.current_thread():
            return
        with self._lock:
            self._ending = True
            self._lock.notify_all()
            while self._jobs or self._busy or self._thread is not None:
                self._lock.wait()

    def failed(self) -> bool:
        """Whether a job failed (its error raised or not)."""
        with self._lock:
            return self._error is not None

    def raise_error(self) -> None:
        """Raise the error of the job that failed, once (later calls return)."""
        with self._lock:
            error = None if self._error_raised else self._error
            self._error_raised = self._error_raised or error is not None
        if error is not None:
            raise error
