"""Recording a run: frames and tables at the output rate, and the summary (the progress bar:
:mod:`hybrid.app.progress`).

:class:`hybrid.simulation.Simulation` owns the step loop; a :class:`Recorder` watches it, writing
through :class:`hybrid.app.output.RunWriter` when the run has an output folder and keeping the
conserved quantities of every recorded frame for the summary either way.
"""
import logging
import math
import time as clock
import contextlib
from contextlib import contextmanager

import numpy as np

from rigid.contacts import detect, detect_points
from rigid import quaternion as quat

from hybrid.coupling.stability import OutputFailure

from . import energy_watch, observe
from .output_resume import ResumableWriter
from .run_files import FRAME_PATTERN


def ignored_motion(scene):
    """Warnings for fixed bodies given a velocity or angular velocity, which they ignore."""
    said = []
    for b in scene.bodies:
        given = [f for f in ("velocity", "angular_velocity") if b.fixed and np.any(getattr(b, f))]
        if given:
            said.append(f"body '{b.name}' is fixed: its {' and '.join(given)} "
                        f"{'has' if len(given) == 1 else 'have'} no effect")
    return said


def overlapping_bodies(model, state, tolerance=1e-4):
    """Pairs of bodies (names) that start interpenetrating by more than ``tolerance`` m: rigid
    bodies with each other, and deformable bodies' surface nodes inside rigid bodies."""
    rm, rs = model.rigid, state.rigid
    if rm.body_count == 0:
        return []
    R = quat.to_matrix(rs.orientation)
    still = np.zeros(rm.body_count)
    c = detect(rm, rs.position, R, still, 0.0)
    deep = (c.gap < -tolerance) & (c.body_b >= 0)
    names = [model.names[i] for i in model.rigid_ids]
    pairs = {tuple(sorted((names[a], names[b]))) for a, b in zip(c.body_a[deep], c.body_b[deep])}
    # a body whose centre lies inside itself and another (two bodies placed at one pose meet
    # only vertex to vertex, at no depth, and fell through each other unwarned)
    n = rm.body_count
    centres = detect_points(rm, rs.position, R, rs.position, np.zeros(n), still, 0.0, np.zeros(n), np.zeros(n))
    inside = (centres.gap < -tolerance) & (centres.body_b >= 0)
    own = set(centres.body_a[inside & (centres.body_a == centres.body_b)].tolist())
    pairs |= {tuple(sorted((names[a], names[b]))) for a, b in zip(centres.body_a[inside], centres.body_b[inside])
              if a != b and a in own}
    for j, (m, s) in enumerate(zip(model.fem, state.fem)):
        x = s.x[m.surface_nodes]
        k = len(x)
        hits = detect_points(rm, rs.position, R, x, np.zeros(k), still, 0.0, np.zeros(k), np.zeros(k))
        inside = (hits.gap < -tolerance) & (hits.body_b >= 0)
        pairs |= {(model.names[model.fem_ids[j]], names[b]) for b in np.unique(hits.body_b[inside])}
    return sorted(pairs)


def below_planes(model, state, tolerance=1e-4):
    """``(name, depth m)`` of each body that starts more than ``tolerance`` m inside a plane (the
    deepest of its rigid contact points or deformable surface nodes), in scene order."""
    rm, rs = model.rigid, state.rigid
    if rm.plane_point.shape[0] == 0:
        return []
    R = quat.to_matrix(rs.orientation)
    depth = {}
    if rm.body_count:
        c = detect(rm, rs.position, R, np.zeros(rm.body_count), 0.0)
        for a, gap in zip(c.body_a[c.body_b < 0], c.gap[c.body_b < 0]):
            k = int(model.rigid_ids[a])
            depth[k] = max(depth.get(k, 0.0), -float(gap))
    for j, (m, s) in enumerate(zip(model.fem, state.fem)):
        x = s.x[m.surface_nodes]
        k = len(x)
        hits = detect_points(rm, rs.position, R, x, np.zeros(k), np.zeros(rm.body_count), 0.0,
                             np.zeros(k), np.zeros(k))
        on_plane = hits.gap[hits.body_b < 0]
        if len(on_plane):
            depth[int(model.fem_ids[j])] = -float(on_plane.min())
    return [(model.names[k], d) for k, d in sorted(depth.items()) if d > tolerance]


def _crawl_energy(model):
    """J: ROUND_OFF of the kinetic energy of every body moving its own size over the scene's
    duration, summed: the least energy a drift is measured against (a scene at rest, its energies
    of 1e-36 J from round-off, read an energy drift of 0.99)."""
    rm, T = model.rigid, float(model.scene.simulation.duration)
    free = ~rm.body_fixed if rm.body_count else np.zeros(0, bool)
    total = float((rm.body_mass[free] * (2.0 * rm.body_radius[free]) ** 2).sum()) if rm.body_count else 0.0
    for m in model.fem:
        total += float(m.node_mass.sum() * np.ptp(m.rest_points, axis=0).max() ** 2)
    return ROUND_OFF * total / T / T       # (T ** 2 is 0 for a duration of 1e-200 s)


# energies below this part of the bodies' energy at a crawl are round-off (_crawl_energy)
ROUND_OFF = 1e-12


def _drift(values, reference, scales=()):
    """max |q(t) - q(0)| over the largest |q| of the run, or the largest of ``scales`` (how much of
    q the bodies carry without cancellations, see observe.momentum_scales) when larger: a body
    starting at rest (q(0) = 0) that is then loaded gets a figure of at most 2, and two bodies
    meeting head-on, with no total angular momentum, get their change of it against what they
    carry."""
    values = np.asarray(values, float)
    change = float(np.max(np.abs(values - reference)))
    scale = max(float(np.max(np.abs(reference))), float(np.max(np.abs(values))),
                max(scales, default=0.0))
    return change / scale if scale > 0 else 0.0


class _Forward(logging.Handler):
    def __init__(self, log):
        super().__init__(logging.INFO)
        self.log = log

    def emit(self, record):
        self.log(record.getMessage())


@contextmanager
def forwarded(logger, log):
    """Messages of ``logger`` (long work inside a step) go to the run's ``log`` while it runs."""
    handler, level = _Forward(log), logger.level
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    try:
        yield
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)


class Recorder:
    """Frames of one run: written to ``out_dir`` (a
    :class:`hybrid.app.output_resume.ResumableWriter`) when it is given, and the totals (energy,
    momenta, the momentum the bodies carry) of every recorded frame kept for the summary. Use it
    as a context manager so the files are closed on error."""

    def __init__(self, out_dir, scene_name, until=None):
        self.writer = ResumableWriter(out_dir, scene_name) if out_dir is not None else None
        self.until, self._first = until, None   # the run's end (simulated s); the first frame's (wall s, t)
        self.energies, self.momenta, self.angular, self.carried = [], [], [], []
        self.kinetic = []       # the frames' kinetic energies (J), for the energy watchdog
        self.potentials = []    # and the loads' potential energies (J)
        self.dissipated = []    # and the plastic work dissipated so far (J; None: not counted)
        self.frames = 0
        self.watched = None     # (Peaks, ImpactWatch) of the run's steps, kept in checkpoints

    def watch(self, peaks, impacts):
        """Keep ``peaks`` (hybrid.app.peaks.Peaks) and ``impacts``
        (hybrid.app.resolution.ImpactWatch), which watch every step, in this recorder's
        snapshots, so a resumed run reports the peaks and warnings from before its stop."""
        self.watched = (peaks, impacts)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        if self.writer is not None:
            self.writer.__exit__(*exc)

    def record(self, model, state):
        """One frame: the bodies' geometry and fields, their rows and the regions' rows."""
        if self.writer is not None:
            self.writer.write_frame(state.time, observe.frame_pieces(model, state),
                                    observe.body_rows(model, state))
            regions = observe.region_rows(model, state)
            if regions:
                self.writer.write_regions(regions)
            self._expect(float(state.time))
        e, p, l = observe.totals(model, state)
        self.energies.append(e), self.momenta.append(p), self.angular.append(l)
        self.kinetic.append(observe.kinetic(model, state))
        self.carried.append(observe.momentum_scales(model, state))
        self.potentials.append(energy_watch.loads(model, state))
        if self.dissipated is not None:
            self.dissipated.append(observe.plastic_dissipation(model, state))
        self.frames += 1
        energy_watch.check(model, state, self.energies, self.kinetic, self.potentials, self.dissipated)

    def _expect(self, t):
        """Tell the writer the wall time left to ``until`` at the run's rate since its first frame."""
        now = clock.perf_counter()
        self._first = self._first or (now, t)
        if self.until is not None and t > self._first[1]:
            self.writer.expect((now - self._first[0]) / (t - self._first[1]) * (self.until - t))

    def snapshot(self):
        """What :meth:`restore` needs to continue this recorder (a checkpoint keeps it): the
        totals so far and where the files stand."""
        return {"energies": list(self.energies), "momenta": list(self.momenta),
                "angular": list(self.angular), "carried": list(self.carried), "frames": self.frames,
                "kinetic": list(self.kinetic), "potentials": list(self.potentials),
                "dissipated": None if self.dissipated is None else list(self.dissipated),
                "files": None if self.writer is None else self.writer.snapshot(),
                "watched": None if self.watched is None else [w.snapshot() for w in self.watched]}

    def restore(self, snapshot):
        """Continue from a :meth:`snapshot`: its totals, and the files taken back to it
        (hybrid.app.output_resume.ResumableWriter.resume)."""
        self.energies, self.momenta = list(snapshot["energies"]), list(snapshot["momenta"])
        self.angular, self.carried = list(snapshot["angular"]), list(snapshot["carried"])
        self.frames = snapshot["frames"]
        self.kinetic = list(snapshot.get("kinetic", [0.0] * len(self.energies)))
        self.potentials = list(snapshot.get("potentials", [0.0] * len(self.energies)))
        kept = snapshot.get("dissipated")     # (a checkpoint that did not keep them: not counted)
        self.dissipated = None if kept is None else list(kept)
        if self.watched is not None and snapshot.get("watched") is not None:
            for watcher, kept in zip(self.watched, snapshot["watched"]):
                watcher.restore(kept)
        if self.writer is not None and snapshot["files"] is not None:
            self.writer.resume(snapshot["files"])

    def frames_on_disk(self):
        """The frames counted that reached the disk: after a failed write (a full disk) the
        count handed over is one or more ahead of the files."""
        if self.writer is None or not self.writer.frames_dir.is_dir():
            return self.frames
        return min(self.frames, sum(1 for f in self.writer.frames_dir.iterdir() if FRAME_PATTERN.match(f.name)))

    def close(self, summary):
        """Write ``summary.json`` and close the tables (nothing without an output folder). A write
        that failed after the last step (found as the files close) is an OutputFailure, returned
        with the summary written as the failed run's; else None."""
        if self.writer is None:
            return None
        try:
            self.writer.close(summary)
        except OSError as error:
            failure = OutputFailure(summary["simulated_time"], error)
            summary.update(status="failed", error=str(failure), frames=self.frames_on_disk())
            with contextlib.suppress(OSError):      # (a full disk may take no summary either)
                self.writer.write_summary(summary)
            return failure
        return None

    def conservation(self, model):
        """The summary's conservation section: drifts of energy and momenta over the frames."""
        no_external = not np.any(model.gravity) and model.rigid.plane_point.shape[0] == 0 \
            and not np.any(model.rigid.body_fixed) and not any(m.anchor_nodes or m.load_nodes for m in model.fem)
        E, P, L = np.array(self.energies), np.array(self.momenta), np.array(self.angular)
        if len(self.potentials) == len(E):      # with the constant loads' potential (their work)
            E = E + np.array(self.potentials)
        # what the bodies carry: the largest kinetic energy, or change of potential and elastic
        # energy (a body falling from rest at z = 0 has a total energy of zero throughout)
        K = np.array(self.kinetic)
        carried = [float(K.max()), float(np.max(np.abs(E - K - E[0] + K[0])))] if len(K) == len(E) > 0 else []
        carried.append(_crawl_energy(model))
        changers = energy_changers(model)
        return {
            "momentum_conserved_expected": bool(no_external),
            "energy_conserved_expected": not changers,
            "energy_changed_by": changers,
            "energy_relative_drift": _drift(E, E[0], carried) if len(E) else None,
            "linear_momentum_relative_drift": _drift(P, P[0], [c[0] for c in self.carried]) if len(P) else None,
            "angular_momentum_relative_drift": _drift(L, L[0], [c[1] for c in self.carried]) if len(L) else None,
            "note": "drifts are max |q(t) - q(0)| over written frames, relative to the largest |q|, or "
                    "when larger, for energy the largest kinetic energy or change of potential and "
                    "elastic energy (a body falling from rest at z = 0 has none in total) or 1e-12 of "
                    "the bodies' kinetic energy moving their own size over the duration, for momenta "
                    "the largest sum of the bodies' and nodes' own |p| or |x x p| (bodies meeting "
                    "head-on carry momentum that sums to zero); energy includes "
                    "gravity, elastic energy and the loads' potential and is conserved only without friction, inelastic "
                    "contact or damping, and not where an anchor moves (it does work); momenta only "
                    "without gravity, planes, fixed bodies or anchors",
        }


def energy_changers(model):
    """What in the scene may change its total energy, in the summary's words: "moving anchors"
    (they do work on their bodies), "loads on auto bodies", "friction", "restitution below 1", "deformable contact"
    (inelastic whatever the restitution), "damping", "backward
    Euler" (the default integrator of deformable bodies damps their vibrations), "plastic flow"
    and "fracture" (friction and restitution only where something can touch something); empty
    when the energy is expected to be conserved."""
    scene = model.scene
    deformable = [b for b in scene.bodies if b.model != "rigid"]
    touching = (*scene.bodies, *scene.planes) if len(scene.bodies) + len(scene.planes) > 1 else ()
    found = {
        "moving anchors": any(np.any(m.anchor_velocity) for m in model.fem),
        # (a deformable body's loads are counted by their potential; an auto body's not while rigid)
        "loads on auto bodies": any(b.model == "auto" and b.loads for b in scene.bodies),
        "friction": any(x.friction > 0 for x in touching),
        # (restitution acts on rigid contacts, taking the larger of the two counts: a deformable
        # body's contacts are inelastic, and a plane's restitution meets only rigid bodies)
        "restitution below 1": sum(x.restitution < 1 for x in touching) >= 2 and any(
            getattr(x, "model", "plane") in ("rigid", "auto") and x.restitution < 1 for x in touching),
        "deformable contact": bool(touching) and bool(deformable),
        "damping": any(b.damping.mass > 0 or b.damping.stiffness > 0 for b in deformable),
        "backward Euler": any(b.integrator == "backward_euler" for b in deformable),
        "plastic flow": any(b.yield_stress is not None for b in deformable),
        "fracture": any(b.fracture_stress is not None for b in deformable),
    }
    return [name for name, present in found.items() if present]


def stepping(model, peaks, fem_time, simulated):
    """The summary's ``models`` section: per body stepped as FEM (by name, from ``peaks``, the
    run's hybrid.app.peaks.Peaks or None: the largest elastic strain it reached over every step,
    and the largest turn of an element in its frame) how it was modelled, the fraction of the
    run's simulated time (``simulated`` s) it was stepped as FEM (``fem_time``: seconds by name),
    that strain and that turn (degrees, atan of the skew part of the displacement gradient); auto
    bodies never stepped as FEM (fracture pieces turned rigid at once) too, with fraction 0 and no
    strain."""
    strains, turns = ({}, {}) if peaks is None else (peaks.strains, peaks.turns)
    scene_models = {b.name: b.model for b in model.scene.bodies}
    names = list(strains) + [b.name for b in model.scene.bodies
                             if b.model == "auto" and b.name not in strains]
    return {name: {"model": scene_models.get(name, "fem"),
                   "fem_time_fraction": fem_time.get(name, 0.0) / simulated if simulated > 0 else None,
                   "largest_strain": strains.get(name),
                   "largest_turn_degrees": math.degrees(math.atan(turns[name])) if name in turns else None}
            for name in names}


def summary(scene, model, state, wall, recorder, failure, events, timings, fem_time=None,
            peaks=None, impacts=None, first_step=0):
    """The run's ``summary.json`` content. ``fem_time``: ``(seconds stepped as FEM by body name,
    seconds simulated)``, for the ``models`` section. ``peaks``: the run's
    :class:`hybrid.app.peaks.Peaks` (the ``peaks`` section), ``impacts``: its
    :class:`hybrid.app.resolution.ImpactWatch` (``impact_warnings``). ``first_step``: the step
    count the run began at (its steps per second count its own steps)."""
    return {
        "scene": scene.raw | {"simulation": scene.raw.get("simulation", {}) | {"name": scene.name}},
        "scene_file": str(scene.source_path),
        "status": "ok" if failure is None else "failed" if isinstance(failure, OutputFailure) else "unstable",
        "error": None if failure is None else str(failure),
        "bodies": model.names,
        "simulated_time": state.time,
        "steps": state.steps,
        "frames": recorder.frames_on_disk() if isinstance(failure, OutputFailure) else recorder.frames,
        "wall_time": wall,
        "steps_per_second": (state.steps - first_step) / wall if wall > 0 else None,
        "plastic_dissipation": observe.plastic_dissipation(model, state),
        "plastic_dissipation_note": "plastic work (J) dissipated by von Mises flow in bodies with a "
                                    "yield_stress, since the start; 0 when no body has one",
        "conservation": recorder.conservation(model),
        "events": [e.as_dict() for e in events],
        "models": stepping(model, peaks, *(fem_time or ({}, 0.0))),
        "peaks": {} if peaks is None else peaks.as_dict(),
        "peaks_note": "per FEM or auto body (fragments counted with the body they broke from): "
                      "the largest element von Mises stress (Pa), largest principal stress (Pa) "
                      "and equivalent plastic strain over every step, with the time (s) each was "
                      "reached; written frames show only the output rate's steps",
        "impact_warnings": [] if impacts is None else [w.as_dict() for w in impacts.warnings],
        "substeps": None if impacts is None or impacts.max_substeps <= 1 else dict(impacts.substepped),
        "substeps_note": "with resolve_impacts: steps taken in sub-steps because an impact shorter "
                         "than the step began in them, the sub-steps they took and the shortest "
                         "sub-step (s); null without resolve_impacts",
        "fracture": {
            "cracks": int(sum(getattr(e, "cracks", 0) for e in events)),
            "bodies_at_end": len(model.names),
            "fragments": len(model.names) - len(scene.bodies),
            "timings": timings,
        },
    }
