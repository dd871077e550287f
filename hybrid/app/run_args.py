"""The arguments of ``Simulation.run`` checked: the run folder, the time to run until, the
progress flag. Each refusal names the argument and what it takes."""
import math
import os
from pathlib import Path

import numpy as np

from . import run_lock
from .scene.schema import MAX_STEPS


def nearest_whole(steps):
    """The whole number of steps nearest ``steps``, halves up, also where the division left the
    half a hair under (0.35 / 0.1 = 3.4999999999999996)."""
    return math.floor(steps + 0.5 + 1e-9 * max(1.0, abs(steps)))


def checked_out(out, time, last_out, resumed):
    """``out`` as a Path (None stays None), refused as ``Simulation.run`` says: ``time`` the
    simulation's (s), ``last_out`` the folder its last run wrote (resolved, or None), ``resumed``
    whether it continues a stopped run there."""
    if out is None:
        return None
    if not isinstance(out, (str, os.PathLike)):
        raise TypeError(f"out must be a folder's path (a str or pathlib.Path), got {out!r}")
    if isinstance(out, str) and not out.strip():
        raise ValueError("out '': give a folder's path (it is created if missing)")
    out = Path(out)
    blocking = next((p for p in (out, *out.parents) if p.exists() and not p.is_dir()), None)
    if blocking is not None:
        raise ValueError(f"out {out}: {blocking} is a file; give a folder (it is created if missing)")
    run_lock.check(out)
    if not resumed and (out / "checkpoint.npz").exists():   # a stopped run's (also this one's)
        raise ValueError(f"out {out} holds a run that did not finish (checkpoint.npz): "
                         f"Simulation.resume continues it; delete the checkpoint to start again there")
    if not resumed and last_out == out.resolve():
        raise ValueError(f"out {out}: this simulation's last run wrote there; a run from "
                         f"t = {time:.6g} s would replace its frames: give another folder")
    return out


def steps_until(until, time, dt, duration):
    """``(until, steps)``: the time (s) a run from ``time`` goes to (``until``, or the scene's
    ``duration`` for None) and its whole number of steps of ``dt``; ValueError for a time
    before ``time``, more than MAX_STEPS steps on, or that rounds to no step without being
    ``time`` (a loop asking for less than half a step at a time never got anywhere)."""
    if until is None and duration < time - 0.5 * dt:
        raise ValueError(f"the simulation's time {time:.6g} s is past the scene's duration "
                         f"{duration:g} s: give run a later until")
    until = duration if until is None else until
    if isinstance(until, np.ndarray) and until.shape == ():
        until = until[()]
    given = until
    if isinstance(until, (bool, np.bool_)) or not isinstance(until, (int, float, np.integer, np.floating)):
        until = math.nan
    until = float(until)            # (the checks in float64: an np.float16 overflowed in them)
    if not math.isfinite(until) or until < time - 0.5 * dt or (until - time) / dt > MAX_STEPS:
        raise ValueError(f"until must be a time (s) at or after the simulation's time {time:.6g} s "
                         f"and at most {MAX_STEPS:.0e} steps of dt = {dt:g} s later, got {given!r}")
    ahead = (until - time) / dt
    if nearest_whole(ahead) == 0 and abs(ahead) > 1e-6:
        raise ValueError(f"until {until!r} is {ahead:.3g} steps of dt = {dt:g} s from the "
                         f"simulation's time {time:.6g} s: a run takes whole steps (the nearest "
                         f"number): give a time at least half a step later")
    return until, nearest_whole(ahead)


def checked_progress(progress):
    """``progress`` as a bool; TypeError for anything but True, False (or 1, 0): "no" showed the
    bar."""
    if isinstance(progress, (bool, np.bool_)) or (isinstance(progress, int) and progress in (0, 1)):
        return bool(progress)
    raise TypeError(f"progress must be True or False, got {progress!r}")
