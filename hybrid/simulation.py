"""The one step loop: a scene built once, stepped with the events between steps, recorded.

    from hybrid import Simulation
    sim = Simulation.from_toml("dent")          # a built-in scene by name, or a path to a .toml
    sim.run(until=0.02, out="outputs/dent")      # frames, bodies.csv, regions.csv, summary.json
    print(sim.time, sim.body("ball").position)

The command line (``hybrid run``), the tests and the benchmarks all step scenes through this
class, so a scene gives the same numbers whichever of them runs it.
"""
import os
import time as clock
from dataclasses import dataclass

import numpy as np

from .app import checkpoint, geometry, observe, run_args
from .app.build import build
from .app.deformable import beyond, deep_starts, material_warnings, mesh_notes
from .app.peaks import Peaks
from .app.resolution import ImpactWatch
from .app.hints import frame_hints, rigid_hints, spin_warnings
from .app.progress import Progress
from .app.run import (Recorder, below_planes, forwarded, ignored_motion, overlapping_bodies,
                      summary)
from .app.scene import SceneError, load_scene
from .app.scene.data import rechecked
from .coupling.stability import OutputFailure, StepFailure
from .coupling.step import InstabilityError, advance, log as step_log
from .coupling.substep import advance_in_substeps

# most sub-steps a step with an impact is taken in (a scene's resolve_impacts)
MAX_SUBSTEPS = 64
from .scenes import scene_path


@dataclass(frozen=True)
class Body:
    """One body as the simulation has it now (a copy: changing it changes nothing).

    name: the body's name (fracture pieces: ``<name>.<k>``). kind: ``"rigid"`` or ``"fem"``, how
    it is stepped now (an auto body switches).
    position (3,) m: centre of mass. orientation (4,): unit quaternion (w, x, y, z) of the body's
    frame (FEM: its scene orientation turned by its best-fit rotation). velocity (3,) m/s: of the
    centre of mass. angular_velocity (3,) rad/s. kinetic_energy J. mass kg (a rigid body's from
    its surface mesh, a deformable body's from its tets).
    FEM and auto bodies only (None for rigid ones; an auto body stepped as rigid gives its tet
    mesh carried by the rigid motion, its fields as they were when it became rigid): points
    (n, 3) m, node positions; node_velocities (n, 3) m/s; node_masses (n,) kg (lumped: the
    body's momentum is their sum with the velocities); tets (t, 4 or 10)
    node indices; von_mises (t,) Pa and principal_stress (t,) Pa, of each element's stress;
    plastic_strain (t,) accumulated equivalent plastic strain (0 without a yield_stress).
    """
    name: str
    kind: str
    position: np.ndarray
    orientation: np.ndarray
    velocity: np.ndarray
    angular_velocity: np.ndarray
    kinetic_energy: float
    mass: float
    points: np.ndarray = None
    node_velocities: np.ndarray = None
    node_masses: np.ndarray = None
    tets: np.ndarray = None
    von_mises: np.ndarray = None
    principal_stress: np.ndarray = None
    plastic_strain: np.ndarray = None


def _uneven_duration(duration, dt):
    """A warning (in a list) when ``duration`` is no whole number of steps of ``dt``: the run
    takes the nearest number of steps, ending early or late."""
    steps = duration / dt
    n = run_args.nearest_whole(steps)
    if abs(steps - n) <= 1e-6 * max(1.0, steps):
        return []
    return [f"duration {duration:g} s is {steps:.4g} steps of dt = {dt:g} s: the run takes {n} "
            f"steps and ends at {n * dt:.6g} s (make duration a whole number of steps)"]


def _loaded(scene):
    """A scene file's path or a built-in scene's name loaded, or a parsed scene (perhaps changed in
    Python) checked again (:func:`hybrid.app.scene.data.rechecked`)."""
    if isinstance(scene, (str, os.PathLike)):
        return load_scene(scene_path(scene))
    return rechecked(scene)


class Simulation:
    """A scene being simulated: ``Simulation(scene)`` builds its bodies (``scene``: a parsed
    scene, or a scene file's path or a built-in scene's name as :meth:`from_toml` takes; raises
    :class:`hybrid.app.scene.SceneError` for problems only the built bodies show, such as an anchor
    box that holds no node); :meth:`step` and :meth:`run` advance it.

    model: the coupled model (:class:`hybrid.coupling.model.HybridModel`, constant between events;
    events such as fracture replace it). state: the coupled state (everything that changes).
    events: every event so far (fracture, reference-shape updates), each with ``.message`` and
    ``.as_dict()``. warnings: what building the scene found worth saying (repaired meshes, bodies
    overlapping at the start). notes: one line per FEM body on its mesh (elements, nodes,
    resolution, order and why). timings: wall time (s) of event work by kind. peaks: every FEM
    body's largest stresses and plastic strain over every step
    (:class:`hybrid.app.peaks.Peaks`); impacts: the under-resolved impacts found so far
    (:class:`hybrid.app.resolution.ImpactWatch`, its ``warnings``). The first run logs the notes
    and warnings.
    """

    def __init__(self, scene):
        self.scene = scene = _loaded(scene)
        try:
            with geometry.caught_mesh_warnings() as repaired:
                self.model, self.state = build(scene)
        except (ValueError, geometry.MeshError) as error:
            raise SceneError([f"{scene.source_path}: {error}"]) from None
        self.warnings = list(repaired) + [f"bodies '{a}' and '{b}' overlap at the start"
                                          for a, b in overlapping_bodies(self.model, self.state)]
        self.warnings += _uneven_duration(scene.simulation.duration, scene.simulation.dt)
        below = below_planes(self.model, self.state)
        problems = deep_starts(scene, self.model, below) + beyond(scene, self.model, self.state)
        if problems:
            raise SceneError(problems)
        self.warnings += [f"body '{name}' starts {depth:.3g} m inside a plane: it is pushed out in its first "
                          f"step{'s' if name in self.model.rigid.names else ''}{geometry.units_hint(scene.bodies, name)}"
                          for name, depth in below]
        self.spinning = spin_warnings(scene, self.model, self.state)
        self.warnings += ignored_motion(scene) + list(self.spinning.values()) + material_warnings(self.model)
        self.notes = mesh_notes(self.model)
        self.events, self.timings = [], {}
        # seconds each body was stepped as FEM, and seconds stepped (the summary's models section)
        self.fem_time, self.stepped_time = {}, 0.0
        self.resumed = None     # what the next run continues from (set by resume)
        self._watch()

    @classmethod
    def from_toml(cls, path):
        """Load, validate and build a scene file, or a built-in scene given by name (``hybrid
        scenes`` lists them). Raises SceneError listing every problem (a missing file among them),
        KeyError for a name that is no built-in scene, TypeError for a ``path`` that is neither a
        string nor a path."""
        if not isinstance(path, (str, os.PathLike)):
            raise TypeError(f"from_toml takes a scene file's path (a str or pathlib.Path) or a "
                            f"built-in scene's name, not {type(path).__name__}")
        return cls(scene_path(path))

    @classmethod
    def resume(cls, path, out):
        """The scene file ``path`` (or built-in scene name, or a parsed Scene as ``Simulation``
        takes: a run of a scene changed in Python resumes with that scene) as the checkpoint in folder ``out``
        left it (``out/checkpoint.npz``, see :mod:`hybrid.app.checkpoint`); :meth:`run` with that
        ``out`` then continues the run there, ending as the run would have without the stop.
        Raises SceneError for a scene file with problems and
        :class:`hybrid.app.checkpoint.CheckpointError` for a checkpoint that is missing, of
        another scene, truncated or corrupted, of another format version, or whose run folder
        has lost or damaged a frame or table it counts."""
        return checkpoint.restore(cls.__new__(cls), _loaded(path), out)

    @property
    def time(self):
        """Simulated time (s)."""
        return self.state.time

    @property
    def steps(self):
        """Steps taken."""
        return self.state.steps

    @property
    def dt(self):
        """The scene's time step (s)."""
        return self.model.dt

    @property
    def body_names(self):
        """Every body's name, in scene order (fracture pieces appended as they appear)."""
        return list(self.model.names)

    def _watch(self):
        """Start watching the steps: :attr:`peaks` (:class:`hybrid.app.peaks.Peaks`, every FEM
        body's largest stresses and plastic strain over every step) and :attr:`impacts`
        (:class:`hybrid.app.resolution.ImpactWatch`, under-resolved impacts: its ``warnings``,
        once per body and kind, again for one that asks a fifth finer; the run log gets
        each as it is found)."""
        most = MAX_SUBSTEPS if getattr(self.scene.simulation, "resolve_impacts", False) else 1
        self.peaks, self.impacts, self._said = Peaks(), ImpactWatch(most), []

    def step(self):
        """Advance every body by one time step, with the events due (reference-shape updates,
        fracture, auto bodies switching between rigid and FEM). Returns this step's events.
        Raises InstabilityError (naming the body, the time and the quantity) when a body's state
        diverges; the simulation is then left at the last finite state."""
        if not hasattr(self, "peaks"):          # made by resume, without __init__
            self._watch()
        self._before = (self.model, self.state)
        count = self.impacts.substeps_now(self.time)       # an impact under way: sub-steps
        if count == 1:
            kept = (dict(self.fem_time), self.stepped_time,
                    self.peaks.snapshot() if self.impacts.max_substeps > 1 else None)
            model, state, happened = advance(self.model, self.state, self.timings, self._took)
            count = self.impacts.substeps_needed(self.model.dt, state.time)
            if count > 1:
                # an impact shorter than the step began in it: the step again, in sub-steps
                # (what the first try counted is forgotten; its warnings were judged against
                # the sub-steps)
                self.fem_time, self.stepped_time, peaks = kept
                self.peaks.restore(peaks)
        if count > 1:
            model, state, happened = advance_in_substeps(self.model, self.state, count,
                                                         self.timings, self._took)
            self.impacts.substepped_step(count, self.model.dt)
            self.impacts.keep_resolving(model, state)
        self.model, self.state = model, state
        self.events.extend(happened)
        return happened

    def _took(self, model, state, start):
        """After each step (before its events): count the step's time as FEM time for the bodies
        it stepped as FEM, take the step's peaks and look for under-resolved impacts (from the
        step's ``start``, so that a rigid auto body struck, turned deformable for the step, is
        judged at the speed it was struck at; sub-steps are judged by the step they divide)."""
        h = model.dt
        self.stepped_time += h
        for k in model.fem_ids:
            name = model.names[k]
            self.fem_time[name] = self.fem_time.get(name, 0.0) + h
        if model.fem:
            self.peaks.update(model, state)
            self._said += self.peaks.said
            self.peaks.said = []
            before = (model, start) if model.dt == self.model.dt else self._before
            self._said += [w.message for w in self.impacts.check(before, model, state)]
        self._stepped(model, state)

    def _stepped(self, model, state):
        """Called after each step with its model and state, before the events between steps
        (a hook for subclasses; nothing here)."""

    def run(self, until=None, out=None, progress=True, log=print, checkpoint_every=None,
            stop=None):
        """Step until simulated time ``until`` (s; default the scene's ``duration``), recording a
        frame at the scene's ``output_fps`` (and one at the current time and one at the end). With ``out`` (a
        folder), write the frames (.vtu and a .pvd index), bodies.csv, regions.csv and
        summary.json there, as ``hybrid run`` does, and checkpoints (``out/checkpoint.npz``,
        :mod:`hybrid.app.checkpoint`) every ``checkpoint_every`` simulated seconds (None: every
        tenth of the duration or five minutes of wall time, whichever comes first; 0: only when
        stopped); the last one is removed when the run ends well. A simulation made by
        :meth:`resume` continues its run instead (``until`` is then the stopped run's).
        ``stop``: a :class:`hybrid.app.checkpoint.StopRequest` or a ``threading.Event``; once set
        (from code, or by a signal: :func:`hybrid.app.checkpoint.stop_on_signals`) the run finishes its step, writes a
        checkpoint and the summary (status ``stopped``) and raises
        :class:`hybrid.app.checkpoint.Stopped`. Messages (warnings, events) go to ``log``.
        Returns the summary (a dict). On instability the frames so far and the summary are kept
        and the InstabilityError is raised again. ValueError for an ``until`` that is no time at
        or after :attr:`time`, an ``out`` that is (or lies in) a file, the folder this simulation's
        last run wrote (a run into it again would replace that run's frames) or one holding a
        stopped run's checkpoint (it would be lost); :class:`hybrid.app.run_lock.RunFolderBusy` (a
        ValueError) for a folder another live run writes in."""
        stop, progress = checkpoint.stop_request(stop), run_args.checked_progress(progress)
        out = run_args.checked_out(out, self.time, getattr(self, "_last_out", None), self.resumed is not None)
        checkpoint.check_every(checkpoint_every)
        position, snapshot = self._position(until)
        for message in getattr(self, "notes", []):
            log(message)
        for message in self.warnings:
            log(f"warning: {message}")
        self.warnings, self.notes = [], []
        bar = Progress(position.until, enabled=progress, first_steps=self.steps)
        wall0 = clock.perf_counter() - position.wall
        if not hasattr(self, "peaks"):          # made by resume, without __init__
            self._watch()
        # a state running away (absurd scene values) overflows on its way to the finiteness
        # check, which names the body: numpy's warnings about it (in the steps, the frames' totals
        # and the summary's drifts) would only be noise around it
        with forwarded(step_log, log), Recorder(out, self.scene.name, position.until) as recorder, \
                np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            recorder.watch(self.peaks, self.impacts)
            if snapshot is None:
                recorder.record(self.model, self.state)
            else:
                checkpoint.resume_recorder(recorder, snapshot, out)
            if out is not None:     # (the folder is this run's once its first frame is handed over)
                self._last_out = out.resolve()
            saver = checkpoint.Checkpoints(self, out, checkpoint_every, position, wall0, stop, log)
            failure = self._steps(position, recorder, bar, log, saver)
            bar.update(self.time, self.steps, force=True)
            bar.done()
            wall = clock.perf_counter() - wall0
            result = summary(self.scene, self.model, self.state, wall, recorder, failure,
                             self.events[position.first_event:], self.timings,
                             (self.fem_time, self.stepped_time), self.peaks, self.impacts,
                             position.first_step)
            if saver.stopped is not None:
                result["status"] = "stopped"
            struck = {w.body for w in self.impacts.warnings}
            # (a run stopped early has not seen its strains: a slab stopped after one step was
            # told it never strained, which it did by 0.4 later)
            for line in ([] if saver.stopped is not None else
                         rigid_hints(self.model, self.peaks.strains, struck)
                         + frame_hints(self.model, self.peaks.strains, getattr(self, "spinning", {}),
                                       self.peaks.turns, self.peaks.inverted())):
                log(line)
            failure = recorder.close(result) or failure
        if isinstance(failure, OutputFailure):
            raise failure               # (its checkpoint kept: resumed once there is room)
        if saver.stopped is not None:
            raise saver.stopped
        saver.finished()                # (resuming an unstable run would run into it again)
        if failure is not None:
            raise failure
        return result

    def _position(self, until):
        """``(Position, recorder snapshot)`` the run starts from: a new run's (snapshot None),
        or the checkpoint's of a resumed simulation."""
        if self.resumed is not None:
            position, snapshot = self.resumed
            self.resumed = None
            return position, snapshot
        sim = self.scene.simulation
        until, steps = run_args.steps_until(until, self.time, sim.dt, sim.duration)
        end_step = self.steps + steps
        return checkpoint.Position(until, end_step, self.time + 1.0 / sim.output_fps, 0.0,
                                   len(self.events), self.steps), None

    def _steps(self, position, recorder, bar, log, saver):
        """Take steps until ``position.end_step``, recording frames at the output rate (at the
        first step at or after each frame time) and at the last step, and
        writing checkpoints (``saver``, which also ends the steps when a stop was asked); the
        InstabilityError that stopped them, or None."""
        frame_every = 1.0 / self.scene.simulation.output_fps
        try:
            while self.steps < position.end_step:
                for event in self.step():
                    log(event.message)
                for message in self._said:
                    log(message)
                self._said = []
                if self.time >= position.next_frame - 1e-9 * self.dt:
                    recorder.record(self.model, self.state)
                    position.next_frame += frame_every
                elif self.steps == position.end_step:     # the run's end, between frame times
                    recorder.record(self.model, self.state)
                bar.update(self.time, self.steps)
                if saver.after_step(recorder):
                    break
        except InstabilityError as error:
            return error
        except OSError as error:        # the disk, not the physics
            return OutputFailure(self.time, error)
        except Exception as error:      # noqa: BLE001 (the run's boundary)
            # a bug or a case the simulator does not handle: the run still ends with its frames,
            # its summary and a message naming the time and the stage, not a traceback
            return StepFailure.of(self.time, error)
        return None

    def body(self, name):
        """The body called ``name`` now (a :class:`Body`); KeyError naming the bodies there are."""
        if name not in self.model.names:
            raise KeyError(f"no body '{name}'; bodies: {', '.join(self.model.names)}")
        index = self.model.names.index(name)
        row = observe.body_rows(self.model, self.state, only=index)[0]
        values = np.array(row[2:-1], float)
        pose = dict(name=name, position=values[0:3], orientation=values[3:7], velocity=values[7:10],
                    angular_velocity=values[10:13], kinetic_energy=float(values[13]))
        kind = "fem" if index in self.model.fem_ids else "rigid"
        if kind == "fem":
            pose["mass"] = float(self.model.fem[list(self.model.fem_ids).index(index)].node_mass.sum())
        else:
            pose["mass"] = float(self.model.rigid.body_mass[list(self.model.rigid_ids).index(index)])
        deformable = [(m, s) for k, m, s in observe.fem_states(self.model, self.state) if k == index]
        if not deformable:
            return Body(kind=kind, **pose)
        m, s = deformable[0]
        fields = observe.tet_fields(m, s)
        plastic = np.broadcast_to(fields["plastic_strain"], (m.tet_count,)).copy()
        return Body(kind=kind, points=s.x.copy(), node_velocities=s.v.copy(), node_masses=m.node_mass.copy(),
                    tets=m.tets.copy(), von_mises=fields["von_mises"],
                    principal_stress=fields["principal_stress"], plastic_strain=plastic, **pose)
