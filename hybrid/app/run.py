"""Run a scene: step it, write frames at the output rate, report progress and a summary."""
import logging
import sys
import time as clock
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from rigid.contacts import detect
from rigid import quaternion as quat

from . import geometry, observe
from .build import build
from .output import RunWriter
from .scene import SceneError
from hybrid.coupling.events import between_steps
from hybrid.coupling.step import InstabilityError, step
from hybrid.coupling.step import log as step_log


class Progress:
    """A one-line progress bar on stderr (simulated time, steps/s); quiet when disabled."""

    def __init__(self, duration, enabled=True, stream=sys.stderr):
        self.duration, self.enabled, self.stream = duration, enabled, stream
        self.start = clock.perf_counter()
        self.last = -1.0
        self.tty = hasattr(stream, "isatty") and stream.isatty()
        self.last_decile = -1

    def update(self, t, steps, force=False):
        if not self.enabled:
            return
        now = clock.perf_counter()
        frac = min(t / self.duration, 1.0) if self.duration > 0 else 1.0
        rate = steps / max(now - self.start, 1e-9)
        if self.tty:
            if force or now - self.last > 0.2:
                bar = "#" * int(30 * frac) + "-" * (30 - int(30 * frac))
                self.stream.write(f"\r[{bar}] t = {t:7.3f} / {self.duration:.3f} s  {rate:8.1f} steps/s")
                self.stream.flush()
                self.last = now
        elif int(frac * 10) > self.last_decile or force:
            self.last_decile = int(frac * 10)
            self.stream.write(f"{100 * frac:5.1f}%  t = {t:.3f} s  {rate:.1f} steps/s\n")
            self.stream.flush()

    def done(self):
        if self.enabled and self.tty:
            self.stream.write("\n")


def overlapping_bodies(model, state, tolerance=1e-4):
    """Pairs of rigid bodies (names) that start interpenetrating by more than ``tolerance`` m."""
    rm, rs = model.rigid, state.rigid
    if rm.body_count < 2:
        return []
    c = detect(rm, rs.position, quat.to_matrix(rs.orientation), np.zeros(rm.body_count), 0.0)
    deep = (c.gap < -tolerance) & (c.body_b >= 0)
    pairs = {tuple(sorted((int(a), int(b)))) for a, b in zip(c.body_a[deep], c.body_b[deep])}
    return [(model.names[model.rigid_ids[a]], model.names[model.rigid_ids[b]]) for a, b in sorted(pairs)]


def _drift(values, reference, scales=()):
    """max |q(t) - q(0)| over the largest |q| of the run, or the largest of ``scales`` (how much of
    q the bodies carry without cancellations, see observe.momentum_scales) when larger: a body
    starting at rest (q(0) = 0) that is then loaded gets a figure of at most 2, not one over zero
    (1e302 before), and two bodies meeting head-on, with no total angular momentum, get their
    change of it against what they carry (it read 1.0 for a change of 1e-5)."""
    values = np.asarray(values, float)
    change = float(np.max(np.abs(values - reference)))
    scale = max(float(np.max(np.abs(reference))), float(np.max(np.abs(values))),
                max(scales, default=0.0))
    return change / scale if scale > 0 else 0.0


def run_scene(scene, out_dir, progress=True, log=print):
    """Simulate ``scene`` and write its results into ``out_dir``; returns the summary dict.

    On instability the frames written so far are kept, the summary records the failure, and the
    InstabilityError is raised again for the caller to report.
    """
    with _forwarded(step_log, log):
        return _run(scene, out_dir, progress, log)


class _Forward(logging.Handler):
    def __init__(self, log):
        super().__init__(logging.INFO)
        self.log = log

    def emit(self, record):
        self.log(record.getMessage())


@contextmanager
def _forwarded(logger, log):
    """Messages of ``logger`` (long work inside a step) go to the run's ``log`` while it runs."""
    handler, level = _Forward(log), logger.level
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    try:
        yield
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)


def _run(scene, out_dir, progress, log):
    sim = scene.simulation
    try:
        with geometry.caught_mesh_warnings() as repaired:
            model, state = build(scene)
    except (ValueError, geometry.MeshError) as error:    # what only the built bodies show
        raise SceneError([f"{scene.source_path}: {error}"]) from None
    for message in repaired:
        log(f"warning: {message}")
    for a, b in overlapping_bodies(model, state):
        log(f"warning: bodies '{a}' and '{b}' overlap at the start")
    steps_total = int(round(sim.duration / sim.dt))
    frame_every = 1.0 / sim.output_fps
    bar = Progress(sim.duration, enabled=progress)
    energies, momenta, angular, carried = [], [], [], []
    events, timings = [], {}
    failure = None
    wall0 = clock.perf_counter()
    out_dir = Path(out_dir)
    with RunWriter(out_dir, scene.name) as writer:
        next_frame = 0.0

        def record(model, state):
            writer.write_frame(state.time, observe.frame_pieces(model, state), observe.body_rows(model, state))
            regions = observe.region_rows(model, state)
            if regions:
                writer.write_regions(regions)
            e, p, l = observe.totals(model, state)
            energies.append(e), momenta.append(p), angular.append(l)
            carried.append(observe.momentum_scales(model, state))

        record(model, state)
        next_frame += frame_every
        try:
            for _ in range(steps_total):
                state = step(model, state)
                model, state, happened = between_steps(model, state, timings)
                for event in happened:
                    log(event.message)
                events.extend(happened)
                if state.time >= next_frame - 1e-9 * sim.dt:
                    record(model, state)
                    next_frame += frame_every
                bar.update(state.time, state.steps)
        except InstabilityError as err:
            failure = err
        bar.update(state.time, state.steps, force=True)
        bar.done()
        wall = clock.perf_counter() - wall0
        summary = _summary(scene, model, state, wall, energies, momenta, angular, carried, writer.frames_written, failure)
        summary["events"] = [e.as_dict() for e in events]
        summary["fracture"] = {
            "cracks": int(sum(getattr(e, "cracks", 0) for e in events)),
            "bodies_at_end": len(model.names),
            "fragments": len(model.names) - len(scene.bodies),
            "timings": timings,
        }
        writer.close(summary)
    if failure is not None:
        raise failure
    return summary


def _summary(scene, model, state, wall, energies, momenta, angular, carried, frames, failure):
    no_external = not np.any(model.gravity) and model.rigid.plane_point.shape[0] == 0 \
        and not np.any(model.rigid.body_fixed) and not any(m.anchor_nodes or m.load_nodes for m in model.fem)
    E, P, L = np.array(energies), np.array(momenta), np.array(angular)
    return {
        "scene": scene.raw | {"simulation": scene.raw.get("simulation", {}) | {"name": scene.name}},
        "scene_file": str(scene.source_path),
        "status": "ok" if failure is None else "unstable",
        "error": None if failure is None else str(failure),
        "bodies": model.names,
        "simulated_time": state.time,
        "steps": state.steps,
        "frames": frames,
        "wall_time": wall,
        "steps_per_second": state.steps / wall if wall > 0 else None,
        "plastic_dissipation": observe.plastic_dissipation(model, state),
        "plastic_dissipation_note": "plastic work (J) dissipated by von Mises flow in bodies with a "
                                    "yield_stress, since the start; 0 when no body has one",
        "conservation": {
            "momentum_conserved_expected": bool(no_external),
            "energy_relative_drift": _drift(E, E[0]) if len(E) else None,
            "linear_momentum_relative_drift": _drift(P, P[0], [c[0] for c in carried]) if len(P) else None,
            "angular_momentum_relative_drift": _drift(L, L[0], [c[1] for c in carried]) if len(L) else None,
            "note": "drifts are max |q(t) - q(0)| over written frames, relative to the largest |q|, or "
                    "for momenta the largest sum of the bodies' and nodes' own |p| or |x x p| when "
                    "larger (bodies meeting head-on carry momentum that sums to zero); energy includes "
                    "gravity and elastic energy and is conserved only without friction, inelastic "
                    "contact or damping; momenta only without gravity, planes, fixed bodies or anchors",
        },
    }
