"""Command line of the batch studies: ``hybrid sweep`` and ``hybrid converge`` (added to the
``hybrid`` parser by :func:`add_commands`)."""
import sys
from pathlib import Path

from . import run_lock

SET_HELP = ("a scene field and its values: simulation.dt=1e-3,5e-4, bodies.<name>.<field>=V1,V2 "
            "(bodies.plate.yield_stress=2e8,3e8), bodies.<name>.shape.resolution=..., "
            "planes.<index>.<field>=...; vectors as [0,0,1] or 0;0;1; repeat --set for more keys")


def add_commands(sub):
    """Add the ``sweep`` and ``converge`` sub-commands to the argparse ``sub``-parsers."""
    p = sub.add_parser("sweep", help="run variants of a scene in parallel (Dask) into a table",
                       description="Run every combination of the --set values (each an ordinary "
                                   "run in DIR/runs/<id>/) and write DIR/results.csv. A rerun keeps "
                                   "the finished runs.")
    p.add_argument("scene", help="scene file (TOML) or the name of a built-in scene")
    p.add_argument("--set", action="append", default=[], metavar="KEY=V1,V2,...", dest="sets",
                   required=True, help=SET_HELP)
    p.add_argument("--zip", action="store_true", help="pair the i-th values of every --set "
                                                      "instead of running the full grid")
    p.add_argument("--plot", metavar="FIGURE[:KEY]", help="draw DIR/FIGURE.png against the first "
                   "key swept over more than one value (or KEY); FIGURE a results.csv column such as energy_drift, "
                   "plastic_dissipation, cracks or <body>.z")
    _common(p, "outputs/<scene>-sweep")
    p = sub.add_parser("converge", help="speed against error: a ladder of time steps (and meshes)",
                       description="Run the scene at --dt halving time steps (and --refine halving "
                                   "mesh resolutions), estimate every run's error against the "
                                   "Richardson extrapolation of the finest runs, and write "
                                   "DIR/convergence.csv, DIR/convergence.png and a recommendation.")
    p.add_argument("scene", help="scene file (TOML) or the name of a built-in scene")
    p.add_argument("--dt", type=int, default=3, metavar="LEVELS",
                   help="time-step levels, each half the last, from the scene's dt (default 3)")
    p.add_argument("--refine", type=int, default=0, metavar="LEVELS",
                   help="mesh levels, each FEM body's shape resolution half the last (default: none)")
    p.add_argument("--mesh", action="append", default=[], metavar="BODY=COARSE,...,FINE",
                   help="a body's mesh ladder (files, coarse to fine) instead of halving its resolution")
    p.add_argument("--set", action="append", default=[], metavar="KEY=V1,V2,...", dest="sets",
                   help="settings to compare, each with a ladder of its own (e.g. bodies.beam.order=1,2)")
    p.add_argument("--quantity", action="append", default=[], metavar="NAME",
                   help="a quantity of interest instead of the defaults: <body>.com, "
                        "<body>.<column of bodies.csv>, <body>.<region>.force, "
                        "<body>.<region>.<column of regions.csv>, <body>.plastic_strain, cracks")
    p.add_argument("--tol", type=float, default=0.01, metavar="E",
                   help="relative error wanted (default 0.01): the cheapest run whose every "
                        "quantity is within E of its scale is recommended")
    _common(p, "outputs/<scene>-converge")


def _common(p, default_out):
    p.add_argument("--out", help=f"study folder (default {default_out}/)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, metavar="N",
                       help="local worker processes (default: the number of cores)")
    where.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                       help="an existing Dask scheduler instead (its workers must see the study folder)")
    p.add_argument("--quiet", action="store_true", help="no progress line")


def _out(args, kind):
    from ..simulation import scene_path
    from .variants import SettingError
    if args.out is not None and not args.out.strip():
        raise SettingError(f"--out is empty; give a folder (default outputs/<scene>-{kind})")
    return Path(args.out) if args.out else Path("outputs") / f"{Path(str(scene_path(args.scene))).stem}-{kind}"


def run_command(args):
    """Run ``hybrid sweep`` or ``hybrid converge`` for parsed ``args``; the exit code."""
    from .scene import SceneError
    from .variants import SettingError
    if args.workers is not None and args.workers < 1:
        return _bad(args.scene, f"--workers {args.workers}: give at least 1")
    tol = getattr(args, "tol", None)
    if tol is not None and not 0.0 < tol < 1.0:
        return _bad(args.scene, f"--tol {tol:g}: give a relative error between 0 and 1 (for example 0.01)")
    try:
        try:
            out = _out(args, args.command)
        except KeyError as err:             # a bare name that is no built-in scene
            return _bad(args.scene, f"no such scene file or built-in scene ({err.args[0]})")
        return (_sweep if args.command == "sweep" else _converge)(args, out)
    except (SettingError, run_lock.RunFolderBusy) as err:     # (a study into a folder another uses)
        return _bad(args.scene, str(err))
    except SceneError as err:
        for problem in err.problems:
            print(problem, file=sys.stderr)
        print(f"{args.scene}: {len(err.problems)} problem(s); nothing was run", file=sys.stderr)
        return 2
    except OSError as err:
        return _bad(args.scene, f"--scheduler {args.scheduler}: {err}" if args.scheduler else str(err))


# the exit code of a study some of whose runs failed or went unstable (its table written): that
# of `hybrid run` for an unstable run, so a batch script sees it without reading the table
RUNS_FAILED = 3


def _say_failed(rows):
    """Print each failed or unstable run's id and message (stderr); returns those rows."""
    failed = [r for r in rows if r["status"] != "ok"]
    for r in failed:
        error = str(r["error"])        # an instability's message says "unstable: ..." itself
        said = error if error.startswith(f"{r['status']}:") else f"{r['status']}: {error}"
        print(f"{r['id']}: {said}", file=sys.stderr)
    return failed


def _bad(scene, message):
    print(f"{scene}: {message}; nothing was run", file=sys.stderr)
    return 2


def _sweep(args, out):
    from .study import sweep
    rows = sweep(args.scene, args.sets, out, zipped=args.zip, workers=args.workers,
                 scheduler=args.scheduler, progress=not args.quiet, plot=args.plot)
    failed = _say_failed(rows)
    print(f"{len(rows) - len(failed)} of {len(rows)} runs ok; wrote {out}/results.csv"
          + (f" and {out}/{args.plot.partition(':')[0]}.png" if args.plot else ""))
    return RUNS_FAILED if failed else 0


def _converge(args, out):
    from .converge import converge
    from .variants import SettingError, split_values
    meshes = {}
    for text in args.mesh:
        body, sep, files = text.partition("=")
        if not sep or not files:
            raise SettingError(f"--mesh {text}: give BODY=COARSE.msh,...,FINE.msh")
        meshes[body] = split_values(files)
    rows = converge(args.scene, out, dt_levels=args.dt, refine_levels=args.refine, meshes=meshes,
                    across=args.sets, quantities=args.quantity, tol=args.tol, workers=args.workers,
                    scheduler=args.scheduler, progress=not args.quiet)
    _say_failed(rows)
    for line in report(rows, args.tol):
        print(line)
    print(f"wrote {out}/convergence.csv and {out}/convergence.png")
    return RUNS_FAILED if any(r["status"] != "ok" for r in rows) else 0


def report(rows, tol):
    """Lines for the terminal: each quantity's estimate (in each group of runs a ``--set`` made),
    and the recommended setting."""
    from .converge import row_groups
    names = [k.split(":", 1)[1] for k in rows[0] if k.startswith("error:")]
    lines, third_level = [], False
    for label, group in row_groups(rows):
        ok = [r for r in group if r["status"] == "ok"]
        # a ladder gives an order from three levels: with two, or runs missing, there is none to test
        # (the shortest ladder of those that vary: --dt 3 --refine 2 has a mesh ladder of two)
        ladders = [n for n in (len({r["dt"] for r in group}), len({r["resolution"] for r in group})) if n > 1]
        levels = min(ladders, default=1)
        why = ("no run finished ok: nothing to estimate" if not ok else
               f"a ladder of {levels} levels gives no observed order (three or more do)" if levels < 3
               else "runs of the ladder did not finish ok" if len(ok) < len(group)
               else "the differences between levels do not shrink steadily at one order (contact "
                    "events, fracture, runs swinging about the limit, or a coarsest level too coarse)")
        extrapolated = False        # some quantity's order observed (once, from three levels)
        for name in names:
            if {r[f"estimate:{name}"] for r in group} == {"richardson"}:
                extrapolated = True
                continue
            name = f"{name} ({label})" if label else name
            lines.append(f"{name}: {why}: its errors are differences from the finest run, not an "
                         f"extrapolation" if ok else f"{name}: {why}")
        third_level |= bool(ok) and levels == 3 and extrapolated
    if third_level:
        lines.append("each order was observed once (three levels): a fourth level (--dt 4, or "
                     "--refine 4) checks that it holds")
    for r in rows:
        if r["status"] != "ok":
            lines.append(f"{r['id']}: {r['status']} (left out of the estimates)")
    pick = next((r for r in rows if r["recommended"]), None)
    against_finest = pick is not None and any(pick[f"estimate:{n}"] != "richardson" for n in names)
    ok = [r for r in rows if r["status"] == "ok"]
    if not ok:
        lines.append("no estimate: every run failed (their messages are above and in "
                     "convergence.csv)")
    elif pick is None:
        lines.append(f"no run tried reaches a relative error of {tol:g}; add --dt levels "
                     f"(or --refine) and run again (finished runs are kept)")
    else:
        setting = f"dt = {pick['dt']:.4g} s" + (f", resolution = {pick['resolution']}" if pick["resolution"] != "" else "")
        setting += "".join(f", {label}" for label, group in row_groups(rows) if label and pick in group)
        lines.append(f"recommended: {setting} ({pick['id']}): largest estimated relative error "
                     f"{pick['max_relative_error']:.2g} (tol {tol:g}) at {pick['wall_per_sim_s']:.3g} s "
                     f"of wall time per simulated second"
                     + ("; measured against the finest run, which is not converged itself: the "
                        "error to the answer may be larger (add a finer level to see it hold)"
                        if against_finest else ""))
    return lines
