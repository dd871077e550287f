"""The ``hybrid`` command's entry point: signals are handled before anything heavy is imported.

Importing the simulator (numpy, scipy, numba's cached kernels, scikit-fem) and building a large
scene take seconds; a Ctrl-C then printed a KeyboardInterrupt traceback, and a SIGTERM (a job
scheduler's, ``timeout``'s) ended the process without a word. Once a run steps,
:func:`hybrid.app.checkpoint.stop_on_signals` takes the signals over (a checkpoint, then exit
130 / 143); before that, and in commands without a run, they end the command with one line and
those exit codes.
"""
import signal
import sys


class _Terminated(BaseException):
    """SIGTERM arrived outside a run's stepping (a BaseException, as KeyboardInterrupt is: the
    broad ``except Exception`` of a step or a cache lookup must not swallow it; one did, and a
    run given SIGTERM while it started ran to its end)."""


class _OnTerm:
    """The SIGTERM handler before a run steps: raises :class:`_Terminated`, and keeps that it did
    (``received``). Raised inside a callback (an import lock's, a weakref's) the exception is
    printed as ignored and the command goes on; a run that then starts stepping finds the
    handler it replaces with ``received`` set and stops at once
    (hybrid.app.checkpoint.stop_on_signals)."""

    def __init__(self):
        self.received = False

    def __call__(self, signum, frame):
        self.received = True
        raise _Terminated()


def main(argv=None):
    """Run the command line (:func:`hybrid.app.cli.main`) with SIGINT and SIGTERM ending it
    cleanly; returns its exit code."""
    previous = signal.signal(signal.SIGTERM, _OnTerm())
    try:
        from .cli import main as command
        return command(argv)
    except KeyboardInterrupt:
        print("hybrid: interrupted (Ctrl-C)", file=sys.stderr)
        return 130
    except _Terminated:
        print("hybrid: stopped (SIGTERM)", file=sys.stderr)
        return 143
    finally:
        signal.signal(signal.SIGTERM, previous)
