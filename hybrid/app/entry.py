"""The ``hybrid`` command's entry point: signals are handled before anything heavy is imported.

Importing the simulator (numpy, scipy, numba's cached kernels, scikit-fem) and building a large
scene take seconds; a Ctrl-C then printed a KeyboardInterrupt traceback, and a SIGTERM (a job
scheduler's, ``timeout``'s) ended the process without a word. Once a run steps,
:func:`hybrid.app.checkpoint.stop_on_signals` takes the signals over (a checkpoint, then exit
130 / 143); before that, and in commands without a run, they end the command with one line and
those exit codes.
"""
import os
import signal
import sys


class Terminated(BaseException):
    """SIGTERM arrived outside a run's stepping (a BaseException, as KeyboardInterrupt is: the
    broad ``except Exception`` of a step or a cache lookup must not swallow it; one did, and a
    run given SIGTERM while it started ran to its end)."""


class _OnSignal:
    """A handler of SIGINT or SIGTERM before a run steps: raises ``error`` (KeyboardInterrupt or
    :class:`Terminated`), and keeps that it did (``received``). Raised inside a callback (an
    import lock's, a weakref's) or a library's bare ``except`` the exception is swallowed and the
    command goes on; a run that then starts stepping finds the handler it replaces with
    ``received`` set and stops at once (hybrid.app.checkpoint.stop_on_signals)."""

    def __init__(self, error):
        self.error, self.received = error, False

    def __call__(self, signum, frame):
        self.received = True
        raise self.error()


def _unraisable(hook):
    """``sys.unraisablehook`` that keeps quiet about a stop signal's exception swallowed where it
    landed (a ctypes callback of numba's compiler printed its traceback): the handler recorded
    it, and the run stops on it (:class:`_OnSignal`); anything else goes to ``hook``."""
    def quiet(unraisable):
        if not isinstance(unraisable.exc_value, (KeyboardInterrupt, Terminated)):
            hook(unraisable)
    return quiet


def main(argv=None):
    """Run the command line (:func:`hybrid.app.cli.main`) with SIGINT and SIGTERM ending it
    cleanly; returns its exit code."""
    previous = {signal.SIGINT: signal.signal(signal.SIGINT, _OnSignal(KeyboardInterrupt)),
                signal.SIGTERM: signal.signal(signal.SIGTERM, _OnSignal(Terminated))}
    hook, sys.unraisablehook = sys.unraisablehook, _unraisable(sys.unraisablehook)
    try:
        from .cli import main as command
        return command(argv)
    except KeyboardInterrupt:
        print("hybrid: interrupted (Ctrl-C)", file=sys.stderr)
        return 130
    except Terminated:
        print("hybrid: stopped (SIGTERM)", file=sys.stderr)
        return 143
    except BrokenPipeError:
        # the reader of the output left (``hybrid scenes | head -1``): no traceback, and none
        # again when Python flushes stdout at exit
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    finally:
        sys.unraisablehook = hook
        for s, handler in previous.items():
            signal.signal(s, handler)
