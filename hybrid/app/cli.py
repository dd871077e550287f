"""Command line: ``hybrid run [SCENE | NAME] [--out DIR]``, ``hybrid scenes``, ``hybrid render DIR``,
``hybrid validate SCENE``, ``hybrid sweep`` and ``hybrid converge`` (:mod:`.study_cli`).

Exit codes: 0 success, 2 bad input (scene or mesh problems, missing run folder, a checkpoint
that cannot be resumed from), 3 the simulation went unstable (frames written so far are kept), 4
rendering unavailable, 130 / 143 stopped by SIGINT / SIGTERM (``hybrid run`` writes a
checkpoint first and says how to resume).
"""
import argparse
import math
import os
import shlex
import sys
from importlib import metadata
from importlib import resources
from pathlib import Path

from ..scenes import builtin_names, builtin_path, builtin_summary
from .scene import SceneError, load_scene, validate_command
from . import run_lock


# the cell fields a run writes that `hybrid render --field` can colour by
FIELDS = ("von_mises", "principal_stress", "plastic_strain")


def _version():
    """The installed project's version."""
    try:
        return metadata.version("hybrid-sim")
    except metadata.PackageNotFoundError:
        return "unknown (not installed)"


def _default_scene_path():
    return Path(str(resources.files("hybrid.scenes").joinpath("default.toml")))


def _scenes_text():
    names = builtin_names()
    width = max(map(len, names))
    return "\n".join(f"  {name:<{width}}  {builtin_summary(name)}" for name in names)


def _scenes(args):
    print("built-in scenes (hybrid run NAME; copy one from the path below to start your own):")
    print(_scenes_text())
    print(f"files: {builtin_path('default').parent}")
    meshes = sorted({str((builtin_path(n).parent / b.mesh).resolve()) for n in builtin_names()
                     for b in load_scene(builtin_path(n)).bodies if b.mesh is not None})
    if meshes:      # (a copied scene reads them relative to its own folder: point its `mesh` at them)
        print("meshes the scenes read (a copy's `mesh` path is relative to its own folder): " + ", ".join(meshes))
    return 0


def _rejected(path, err):
    for problem in err.problems:
        print(problem, file=sys.stderr)
    print(f"{path}: {len(err.problems)} problem(s); nothing was run", file=sys.stderr)
    return 2


def _scene_file(name):
    """The scene file ``name`` names (a path, or a built-in scene's name; the default scene for
    None), or None after saying on stderr that it is neither."""
    from ..simulation import scene_path
    try:
        return scene_path(name) if name else _default_scene_path()
    except KeyError as err:             # a bare name that is no built-in scene
        print(f"{name}: no such scene file or built-in scene; {err.args[0].split('; ', 1)[1]}",
              file=sys.stderr)
        return None


def _run(args):
    from ..simulation import Simulation
    path = _scene_file(args.scene)
    if path is None:
        return 2
    try:
        scene = _with_settings(load_scene(path), args.set)
    except SceneError as err:
        return _rejected(path, err)
    except ValueError as err:           # (SettingError: a key that leads nowhere, two values)
        print(f"{path}: {err}", file=sys.stderr)
        return 2
    from .geometry import MeshError
    from hybrid.coupling.stability import OutputFailure
    from hybrid.coupling.step import InstabilityError
    out = _run_folder(path, args, scene)
    if out is None:
        return 2
    from .checkpoint import CheckpointError, Stopped, stop_on_signals
    from .output_resume import CHECKPOINT, writer_from_environment
    if not args.resume and (out / CHECKPOINT).exists():
        # a run started afresh there would remove it: an hour's run lost to a missing flag
        print(f"{path}: --out {out} holds a run that did not finish ({CHECKPOINT}): add --resume to continue "
              f"it, or delete {out / CHECKPOINT} to start again there", file=sys.stderr)
        return 2
    try:
        writer = writer_from_environment()
    except ValueError as err:
        print(f"{err}", file=sys.stderr)
        return 2
    if writer in ("auto", "process"):
        # the writer process starts while the scene is built (its first frame is then written there)
        from .writer_pool import start_early
        start_early()
    created = _create_folder(out)       # before a build that can take a minute
    if isinstance(created, str):
        print(f"{path}: --out {out}: {created}", file=sys.stderr)
        return 2
    deformable = sum(b.model != "rigid" for b in scene.bodies)
    if deformable and not args.resume:      # (a large mesh's factorisation can take a minute)
        print(f"building '{scene.name}': meshing and factorising {deformable} deformable "
              f"bod{'y' if deformable == 1 else 'ies'}", flush=True)
    try:
        sim = Simulation.resume(scene if args.set else path, out) if args.resume else Simulation(scene)
    except (SceneError, MeshError, ValueError, CheckpointError) as err:
        _remove_folders(created)        # nothing is left of a run that did not start
        if isinstance(err, SceneError):     # problems only the built bodies show
            return _rejected(path, err)
        print(f"{path}: {err}", file=sys.stderr)
        return 2
    except BaseException:               # Ctrl-C or SIGTERM while building: nothing is written
        _remove_folders(created)
        raise
    print(f"{'resuming' if args.resume else 'running'} '{scene.name}' ({len(scene.bodies)} bodies, "
          f"{scene.simulation.duration} s at dt = {scene.simulation.dt:g} s"
          f"{f', from t = {sim.time:.6g} s' if args.resume else ''}) -> {out}")
    try:
        with stop_on_signals() as stop:
            summary = sim.run(out=out, progress=not args.quiet, log=lambda m: print(m, file=sys.stderr),
                              checkpoint_every=args.checkpoint_every, stop=stop)
    except InstabilityError as err:
        print(f"{path}: {err}; frames written so far are kept in {out}", file=sys.stderr)
        return 2 if isinstance(err, OutputFailure) else 3
    except (CheckpointError, run_lock.RunFolderBusy, OSError) as err:   # the folder changed since the
        return _not_written(path, out, err)     # checkpoint, another run writes there, a full disk
    except Stopped as stopped:
        return _stopped(args, out, stopped)
    c = summary["conservation"]
    drift = (f"energy drift {c['energy_relative_drift']:.3g} (largest change of total energy over "
             f"the frames, relative to the largest |energy| or the energy the bodies convert; "
             f"friction, inelastic contact, damping, plastic flow and fracture lower it)"
             if "moving anchors" not in c.get("energy_changed_by", []) else
             "energy drift not measured: moving anchors do work on their bodies")
    print(f"done: {summary['steps']} steps, {summary['frames']} frames in {summary['wall_time']:.1f} s "
          f"({summary['steps_per_second']:.3g} steps/s); {drift}")
    regions = ", regions.csv" if (out / "regions.csv").exists() else ""
    print(f"wrote {out}/{scene.name}.pvd, frames/, bodies.csv{regions}, summary.json")
    print(f"render it with: hybrid render {shlex.quote(str(out))}")
    return 0


def _with_settings(scene, texts):
    """``scene`` with the ``--set KEY=VALUE`` fields changed (keys as ``hybrid sweep`` takes them,
    one value each); SceneError for a value the field does not take, SettingError otherwise."""
    if not texts:
        return scene
    import copy
    from .scene import parse_scene
    from .variants import SettingError, apply_setting, parse_settings
    data = copy.deepcopy(scene.raw)
    for key, values in parse_settings(texts):
        if len(values) != 1:
            raise SettingError(f"--set {key}: run takes one value ({len(values)} given: several "
                               f"make a study, hybrid sweep)")
        apply_setting(data, key, values[0])
    return parse_scene(data, str(scene.source_path), scene.source_path.parent)


def _not_written(path, out, err):
    """Say why a run could not write in its folder ``out`` (stderr); exit code 2."""
    print(f"{path}: --out {out}: cannot write there: {err.strerror or err}" if isinstance(err, OSError)
          else f"{path}: {err}", file=sys.stderr)
    return 2


def _built(sim):
    """``hybrid validate``'s look at the built bodies: their mesh lines (stderr, as a run logs
    them: a body of linear tets that locks in bending is said there) and the run's warnings."""
    for line in sim.notes:
        print(line, file=sys.stderr)
    return sim.warnings


def _run_folder(path, args, scene):
    """The run's folder (``--out``, or outputs/<scene name>), or None after saying on stderr why
    it cannot be one."""
    if args.out is not None and not args.out.strip():
        print(f"{path}: --out is empty; give a folder (default outputs/{scene.name})", file=sys.stderr)
        return None
    out = Path(args.out) if args.out else Path("outputs") / scene.name
    blocking = next((p for p in (out, *out.parents) if p.exists() and not p.is_dir()), None)
    if blocking is not None:
        print(f"{path}: --out {out}: {blocking} is a file; give a folder (it is created if missing)",
              file=sys.stderr)
        return None
    busy = run_lock.holder(out)         # (first: a live run's periodic checkpoint is not a stopped run's)
    if busy is not None:
        print(f"{path}: --out {out}: {busy}", file=sys.stderr)
        return None
    return out


def _create_folder(out):
    """Create the run folder ``out`` and the folders above it that are missing: the list of those
    created (deepest first, the order to remove them in), or why the folder cannot take the run's
    files (then nothing is created)."""
    missing = [p for p in (out, *out.parents) if not p.exists()]
    try:
        out.mkdir(parents=True, exist_ok=True)
        if os.access(out, os.W_OK | os.X_OK):
            return missing
        why = "cannot write in this folder (no permission, or a read-only file system)"
    except OSError as err:
        why = f"cannot create the folder: {err.strerror or err}"
    _remove_folders(missing)
    return why


def _remove_folders(folders):
    """Remove the empty ``folders`` (deepest first) this command created."""
    for folder in folders:
        try:
            folder.rmdir()
        except OSError:                 # not created after all, or something was written there
            pass


def _stopped(args, out, stopped):
    """Say where a run stopped by a signal is kept and the command that resumes it; its exit code
    (128 + the signal's number)."""
    if stopped.checkpoint is None:
        print(f"\n{out}: {stopped}; no checkpoint could be written; whole frames written so far "
              f"are kept", file=sys.stderr)
        return stopped.exit_code
    command = ["hybrid", "run", *([args.scene] if args.scene else []), "--out", str(out), "--resume"]
    command += [part for text in args.set for part in ("--set", text)]
    if args.checkpoint_every is not None:
        command += ["--checkpoint-every", repr(args.checkpoint_every)]
    command += ["--quiet"] if args.quiet else []
    print(f"\n{out}: {stopped}; checkpoint written to {stopped.checkpoint}, whole frames so far "
          f"kept. Resume with:\n  {shlex.join(command)}", file=sys.stderr)
    return stopped.exit_code


def _seconds(text):
    """A ``--checkpoint-every`` value: simulated seconds, finite and not negative (0: only the
    checkpoint a stop writes)."""
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"{text!r}: give simulated seconds, 0 or more (0: a "
                                         f"checkpoint only when stopped)")
    return value


def _unfinished(run_dir):
    """Why the run in ``run_dir`` did not finish (no summary: it runs still, or was stopped or
    killed; or the summary's status), or None when it did."""
    import json
    try:
        status = json.loads((run_dir / "summary.json").read_text()).get("status")
    except FileNotFoundError:
        return "its run has no summary.json: it is still running, or was stopped or killed"
    except (OSError, ValueError, AttributeError):
        return "its summary.json cannot be read"
    return None if status in ("ok", None) else f"its run ended with status '{status}'"


def _render(args):
    from xml.etree.ElementTree import ParseError
    from .run_files import read_run
    from .render import MAX_SIZE, render_run
    run_dir = Path(args.dir)
    if not (16 <= min(args.size) and max(args.size) <= MAX_SIZE):
        print(f"{run_dir}: --size {args.size[0]} {args.size[1]}: give a width and height of 16 to "
              f"{MAX_SIZE} pixels", file=sys.stderr)
        return 2
    try:
        times, frames, _ = read_run(run_dir)
    except (FileNotFoundError, OSError, ValueError, ParseError) as err:
        print(f"{run_dir}: not a finished run folder ({err})", file=sys.stderr)
        return 2
    if not frames:
        print(f"{run_dir}: no frames to render", file=sys.stderr)
        return 2
    unfinished = _unfinished(run_dir)
    if unfinished:
        print(f"note: {run_dir}: {unfinished}; rendering the {len(frames)} frames written "
              f"(to t = {times[-1]:.6g} s)", file=sys.stderr)

    tty = sys.stderr.isatty()
    end = "\n" if tty else ""          # ends the progress line a terminal rewrites

    def progress(done, total):
        # on a terminal one line rewritten; in a log one line per tenth of the frames
        if tty:
            print(f"\rrendering frame {done}/{total}", end="", file=sys.stderr, flush=True)
        elif done == total or (10 * done) // total > (10 * (done - 1)) // total:
            print(f"rendering frame {done}/{total}", file=sys.stderr, flush=True)

    try:
        result = render_run(run_dir, size=tuple(args.size), field=args.field, progress=progress,
                            colour_range=args.range)
    except RuntimeError as err:
        print(f"{end}{err}", file=sys.stderr)
        return 4
    except ValueError as err:
        print(f"{end}{run_dir}: {err}", file=sys.stderr)
        return 2
    except OSError as err:              # its render folder a file, or not writable
        print(f"{end}{run_dir}: cannot write the render ({err})", file=sys.stderr)
        return 2
    if result.get("note"):
        print(f"{end}note: {run_dir}: {result['note']}", file=sys.stderr)
        end = ""
    print(f"{end}wrote {len(result['pngs'])} PNG frames and {result['movie']}")
    return 0


def main(argv=None):
    """Run the ``hybrid`` command line (``run``, ``render``, ``scenes``, ``validate``, ``sweep``,
    ``converge``) on ``argv``
    (default ``sys.argv[1:]``) and return its exit code: 0 ok, 2 bad input, 3 unstable, 4
    rendering unavailable, 130 interrupted."""
    parser = argparse.ArgumentParser(
        prog="hybrid", formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Rigid bodies coupled with plastic, fracturing tetrahedral FEM: scene files in, "
                    "VTK frames, tables and renders out.",
        epilog=f"built-in scenes (hybrid run NAME):\n{_scenes_text()}\n\n"
               "exit codes: 0 ok, 2 bad input, 3 unstable (frames so far kept), 4 rendering "
               "unavailable, 130 / 143 stopped by SIGINT / SIGTERM (run: checkpoint written)")
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("run", help="simulate a scene (the built-in default scene if none is given)")
    p.add_argument("scene", nargs="?", help="scene file (TOML) or the name of a built-in scene")
    p.add_argument("--out", help="output folder (default outputs/<scene name>/)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--checkpoint-every", type=_seconds, metavar="T",
                   help="write DIR/checkpoint.npz every T simulated seconds (default: every tenth "
                        "of the duration or 5 minutes of wall time, whichever comes first, none "
                        "in the first 10 s; 0: only when stopped). SIGINT or SIGTERM stops a run cleanly "
                        "with a checkpoint (exit 130 / 143)")
    p.add_argument("--resume", action="store_true",
                   help="continue the run in DIR from its checkpoint (same scene file and --set)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="change a field of the scene for this run, e.g. simulation.duration=0.01 or "
                        "bodies.ball.velocity=[0,0,-5] (keys as hybrid sweep takes them; repeat for more)")
    p = sub.add_parser("render", help="render a finished run off-screen to PNG frames and a movie")
    p.add_argument("dir", help="run folder written by 'hybrid run'")
    p.add_argument("--size", type=int, nargs=2, default=[960, 540], metavar=("W", "H"))
    p.add_argument("--field", choices=FIELDS,
                   help="colour FEM bodies by a cell field: von_mises, principal_stress (Pa) or "
                        "plastic_strain")
    p.add_argument("--range", choices=("run", "percentile", "frame"), default="run",
                   help="the field's colour scale: the run's smallest to largest value (default), its "
                        "2nd to 98th percentile, or each frame's own range")
    sub.add_parser("scenes", help="list the built-in scenes")
    p = sub.add_parser("validate", help="check a scene file (or built-in scene) and report every problem")
    p.add_argument("scene", help="a .toml scene file, or a built-in scene's name")
    from .study_cli import add_commands, run_command
    add_commands(sub)                   # sweep, converge: batch studies on Dask
    args = parser.parse_args(argv)
    if args.command == "validate":
        from ..simulation import Simulation     # meshes and regions are checked on the built bodies
        path = _scene_file(args.scene)          # a file, or a built-in scene's name as for run
        return 2 if path is None else validate_command(path, check=lambda scene: _built(Simulation(scene)))
    try:
        return {"run": _run, "render": _render, "scenes": _scenes, "sweep": run_command,
                "converge": run_command}[args.command](args)
    except KeyboardInterrupt:
        print("\ninterrupted (Ctrl-C); files written so far are whole (each is written atomically)",
              file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
