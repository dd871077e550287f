"""Off-screen OpenGL for rendering: which VTK window class works on this machine.

Rendering needs an off-screen OpenGL: EGL (``libegl1 libegl-mesa0 libgl1-mesa-dri``) or OSMesa
(``libosmesa6``); no X display is used. VTK crashes the process instead of raising when neither is
present, so :func:`probe_backend` tries a tiny render in a subprocess first.
"""

from __future__ import annotations

import functools
import os
import signal
import subprocess
import sys

INSTALL_HINT = ("install an off-screen OpenGL library: "
                "apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri (or libosmesa6)")
WINDOW_ENV = "VTK_DEFAULT_OPENGL_WINDOW"
# Off-screen VTK render windows, most capable first.
OFFSCREEN_WINDOWS = ("vtkEGLRenderWindow", "vtkOSOpenGLRenderWindow")
PROBE_TIMEOUT = 60.0

_PROBE_SCRIPT = r"""
import sys
import pyvista as pv
pv.OFF_SCREEN = True
plotter = pv.Plotter(off_screen=True, window_size=(48, 32))
plotter.add_mesh(pv.Cube(), color="red")
image = plotter.screenshot(return_img=True)
name = plotter.ren_win.GetClassName()
plotter.close()
wanted = sys.argv[1]
if wanted and name != wanted:
    sys.exit(f"asked for {wanted}, VTK made {name}")
if image is None or image.std() == 0:
    sys.exit(f"{name} rendered a blank image")
print(name)
"""



def _probe_window(window: str, timeout: float) -> tuple[bool, str]:
    """Render a cube in a subprocess with one window class; (ok, class name or failure reason)."""
    env = dict(os.environ)
    if window:
        env[WINDOW_ENV] = window
    try:
        proc = subprocess.run([sys.executable, "-c", _PROBE_SCRIPT, window], env=env,
                              capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return False, f"{window or 'default window'}: timed out after {timeout:.0f} s"
    if proc.returncode == 0:
        return True, proc.stdout.strip().splitlines()[-1] if proc.stdout.strip() else window
    if proc.returncode < 0:
        try:
            reason = f"crashed with {signal.Signals(-proc.returncode).name}"
        except ValueError:
            reason = f"killed by signal {-proc.returncode}"
    else:
        lines = [line for line in proc.stderr.strip().splitlines() if line.strip()]
        reason = lines[-1] if lines else f"exit code {proc.returncode}"
    return False, f"{window or 'default window'}: {reason}"


def _candidate_windows() -> tuple[str, ...]:
    """Window classes to try: the one named by ``VTK_DEFAULT_OPENGL_WINDOW`` if the user set it,
    else the off-screen ones (EGL, then OSMesa), after the default window when a DISPLAY is set."""
    if os.environ.get(WINDOW_ENV):
        return (os.environ[WINDOW_ENV],)
    if os.environ.get("DISPLAY"):
        return ("",) + OFFSCREEN_WINDOWS
    return OFFSCREEN_WINDOWS


@functools.cache
def _probe(candidates: tuple[str, ...], timeout: float) -> tuple[bool, str, str | None]:
    """(ok, message, window class or None) for the first of ``candidates`` that renders; a fact
    of this machine, remembered per set of candidates."""
    failures = []
    for window in candidates:
        ok, detail = _probe_window(window, timeout)
        if ok:
            return True, f"off-screen rendering works ({detail})", window or None
        failures.append(detail)
    return False, ("off-screen rendering is unavailable (" + "; ".join(failures) + "); "
                   + INSTALL_HINT), None


def probe_backend(timeout: float = PROBE_TIMEOUT, refresh: bool = False) -> tuple[bool, str]:
    """Check that off-screen rendering works here, without risking a crash of this process.

    Tries a tiny pyvista render in a subprocess for each off-screen window type (EGL, then
    OSMesa; the default window first when a DISPLAY is set, or the one named by
    ``VTK_DEFAULT_OPENGL_WINDOW`` if the user set it). Returns ``(ok, message)``; when rendering is
    impossible the message says what failed and which packages to install. The result is
    remembered (per window choice) unless ``refresh``.
    """
    if refresh:
        _probe.cache_clear()
    return _probe(_candidate_windows(), timeout)[:2]


def use_backend() -> str:
    """Fail with the install hint if rendering would crash; select the working window class.
    Returns the probe's message."""
    ok, message, window = _probe(_candidate_windows(), PROBE_TIMEOUT)
    if not ok:
        raise RuntimeError(message)
    if window and not os.environ.get(WINDOW_ENV):
        os.environ[WINDOW_ENV] = window
    return message
