"""multiprocessing's fork server for the run's writer processes
(:mod:`hybrid.app.writer_process`): started once per process, with the writer's modules imported
in it, so that a writer process starts in a few ms; ``fork_server`` tells the ``auto`` writers
whether it is up yet."""
from __future__ import annotations

import multiprocessing
import multiprocessing.forkserver
import multiprocessing.spawn
import os
import runpy
import signal
import sys
import threading
import time
import types

# the module the fork server imports before it forks writers (it imports this one)
_PRELOAD = "hybrid.app.writer_process"


def _noop() -> None:
    """A child that does nothing (:func:`ForkServer` warms the fork server with it)."""


class ForkServer:
    """multiprocessing's fork server, as the ``auto`` writers of this process see it: started
    (once) by the first of them on a thread of its own, with the writer's modules imported in it, and
    ready once a first child forked from it has ended; until then the writers write on their
    thread."""

    def __init__(self):
        self._thread: threading.Thread | None = None
        self._ready = False
        self.seconds: float | None = None     # wall time it took to get ready (s)

    def start(self) -> None:
        """Start the fork server and its first child on a thread (once; returns at once)."""
        if self._thread is None:
            try:
                start_fork_server()
            except Exception:                   # noqa: BLE001 (the writers stay on their thread)
                return
            self._thread = threading.Thread(target=self._warm, name="RunWriter fork server", daemon=True)
            self._thread.start()

    def _warm(self) -> None:
        start = time.perf_counter()
        try:
            context = multiprocessing.get_context("forkserver")
            child = context.Process(target=_noop, name="RunWriter fork server warm-up", daemon=True)
            child.start()
            child.join()
        except Exception:                       # noqa: BLE001 (the writers stay on their thread)
            return
        self.seconds = time.perf_counter() - start
        self._ready = True

    def wait(self, timeout: float) -> None:
        """Wait up to ``timeout`` s for the warm-up under way, if any, to end."""
        if self._thread is not None:
            self._thread.join(timeout)

    def ready(self) -> bool:
        """Whether a writer process now starts in a few ms."""
        return self._ready


fork_server = ForkServer()


def start_fork_server():
    """Start multiprocessing's fork server (with the writer's modules to import) if it is not running,
    with Ctrl-C ignored while it is spawned when called on the main thread: the server inherits
    that, so a Ctrl-C to the process group while it imports the project does not print its
    KeyboardInterrupt traceback into the run's output (it ignores SIGINT once its imports are
    done; its writer processes too). The spawn takes milliseconds; the imports happen after."""
    multiprocessing.get_context("forkserver").set_forkserver_preload([_PRELOAD])
    main_path = multiprocessing.spawn.get_preparation_data("RunWriter").get("init_main_from_path")
    os.environ.update({} if main_path is None else {_MAIN_PATH: main_path})
    main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN) if main_thread else None
    try:
        multiprocessing.forkserver.ensure_running()
    finally:
        os.environ.pop(_MAIN_PATH, None)
        if main_thread:
            signal.signal(signal.SIGINT, previous)


_MAIN_PATH = "HYBRID_FORK_SERVER_MAIN"      # the main script's path, for _preload_main


def _preload_main() -> None:
    """In the fork server (imported there with the writer's modules): a stand-in for the run's main script as
    ``__main__``, with its path, so that children do not each run the script on start (for the
    ``hybrid`` command, the whole project imported again, 0.3-0.6 s before a run's first frame;
    a script's top-level code, such as removing an output folder, in every writer process). The
    script runs only when a child asks the stand-in for one of its names: writers never do."""
    path = os.environ.pop(_MAIN_PATH, None)
    if path is None or getattr(sys.modules.get("__main__"), "__file__", None) == path:
        return
    stand_in = types.ModuleType("__mp_main__")
    stand_in.__file__ = path

    def __getattr__(name):
        if name.startswith("__") and name.endswith("__"):
            raise AttributeError(name)
        stand_in.__dict__.update(runpy.run_path(path, run_name="__mp_main__"))
        del stand_in.__getattr__
        return getattr(stand_in, name)

    stand_in.__getattr__ = __getattr__
    sys.modules["__main__"] = sys.modules["__mp_main__"] = stand_in


_preload_main()
