"""Share of a run's wall time spent writing its output, frames written in place, by a writer
thread and by a writer process, side by side in one run.

Scenes (``--scenes``): the built-in default scene (rigid bodies, 3 s at 1/240 s, 30 frames/s),
a soft 1,296-tet cube (0.2 m, 6 x 6 x 6 cells, E = 100 kPa) dropped on the ground (1 s at
dt = 1 ms, 100 frames/s, the rate at which writing frames took 0.4 s of 1.5 s per simulated
second) and the 1,000 rigid boxes of benchmarks/rigid_pile.py (1 s, 60 frames/s). Each
scene is run through ``Simulation.run`` (what ``hybrid run SCENE --out DIR`` does) in these
ways, interleaved, ``--repeats`` times:

- ``none``: no output folder (the run still keeps its conserved quantities per frame);
- ``inline``: frames, tables and summary written on the stepping thread (``RunWriter(...,
  background=False)``, the writer before issue 24);
- ``thread``: the same files written by a writer thread (``background="thread"``);
- ``process``: written by a writer process (``background="process"``);
- ``auto``: the default (``background="auto"``): in place until multiprocessing's fork server
  is up, then a process. The server is started before the timed runs, as a process's first run
  that expects to write for 0.3 s more starts it (a shorter run stays in place).

``process`` and ``auto`` take the idle writer process an earlier run left
(``hybrid.app.writer_pool.pool``), as the later runs of a Python process do.

A process's first run: ``--first-runs N`` (default 5; 0 for none) also times N first runs of
the default scene, each in a new Python process, with each way, and ``run``: what ``hybrid run
default --out DIR`` does, ``auto`` with the writer process started while the scene is built
(``hybrid.app.writer_pool.start_early``). ``auto`` there is a script's first
``Simulation.run``, which writes in place while the fork server starts.

The output share of a way is (median wall with output - median wall of ``none``) / median wall
with output; its CPU share the same with the process's CPU time (all threads), steadier when
other jobs load the machine. Also printed: the stepping thread's own time in the output calls (the frame's
fields and rows computed in ``hybrid.app.observe``, and ``write_frame`` / ``write_regions`` /
``close``), which the writer thread cannot take over. The goal line takes the largest share of the
scenes run with the default way (``auto``) and of the first runs as ``hybrid run`` makes them (``run``).

    OPENBLAS_NUM_THREADS=1 python benchmarks/output_share.py [--repeats 5] [--scenes default cube pile]
        [--first-runs 5]
"""
import argparse
import functools
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import cube_scene, write_csv  # noqa: E402
from rigid_pile import scene_toml as pile_toml  # noqa: E402

from hybrid import Simulation  # noqa: E402
from hybrid.app import observe, output, run as run_module  # noqa: E402
from hybrid.app.output_resume import ResumableWriter  # noqa: E402


WAYS = {"none": False, "inline": False, "thread": "thread", "process": "process", "auto": "auto"}
OUTPUT_CALLS = ((observe, "frame_pieces"), (observe, "body_rows"), (observe, "region_rows"),
                (output.RunWriter, "write_frame"), (output.RunWriter, "write_regions"),
                (output.RunWriter, "close"))


class OutputClock:
    """Wall time the calling thread spends in the output calls (wrapped while it is active)."""

    def __init__(self):
        self.seconds = 0.0
        self.saved = []

    def __enter__(self):
        for owner, name in OUTPUT_CALLS:
            original = getattr(owner, name)
            self.saved.append((owner, name, original))
            setattr(owner, name, self._timed(original))
        return self

    def __exit__(self, *exc):
        for owner, name, original in self.saved:
            setattr(owner, name, original)

    def _timed(self, function):
        @functools.wraps(function)
        def timed(*args, **kwargs):
            start = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                self.seconds += time.perf_counter() - start
        return timed


def one_run(scene_file, way, out_dir):
    """``(wall s of Simulation.run, its process CPU s (all threads), s the stepping thread spent
    in output calls)``."""
    sim = Simulation.from_toml(scene_file)
    writer = functools.partial(ResumableWriter, background=WAYS[way])
    saved = run_module.ResumableWriter
    run_module.ResumableWriter = writer
    try:
        with OutputClock() as clock:
            start, cpu = time.perf_counter(), time.process_time()
            sim.run(out=None if way == "none" else out_dir, progress=False, log=lambda message: None,
                    checkpoint_every=0)
            wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    finally:
        run_module.ResumableWriter = saved
    return wall, cpu, clock.seconds


FIRST_RUN = """
import sys, tempfile, time
from hybrid import Simulation
from hybrid.app.writer_pool import start_early
if __name__ == "__main__":
    if sys.argv[1] == "run":
        start_early()        # as hybrid run does as it starts building the scene
    sim = Simulation.from_toml("default")
    with tempfile.TemporaryDirectory() as folder:
        start = time.perf_counter()
        sim.run(out=None if sys.argv[1] == "none" else folder, progress=False, log=lambda m: None)
        print(time.perf_counter() - start)
"""


def first_runs(count):
    """Wall time (s, medians) of ``Simulation.run`` on the default scene as a process's first
    run, ``count`` runs of each way, interleaved, each in a new Python process, printed; returns
    the output share of ``run`` (what ``hybrid run`` does: ``auto``, its writer process started
    while the scene is built). ``auto``: a script's first run (in place while the fork server starts)."""
    walls = {way: [] for way in ("none", "inline", "thread", "auto", "run")}
    with tempfile.TemporaryDirectory() as folder:
        script = Path(folder) / "first_run.py"
        script.write_text(FIRST_RUN)
        for _ in range(count):
            for way in walls:
                env = dict(os.environ, HYBRID_WRITER=way if way not in ("none", "run") else "auto")
                out = subprocess.run([sys.executable, str(script), way], env=env, check=True,
                                     capture_output=True, text=True).stdout
                walls[way].append(float(out.split()[-1]))
    base = statistics.median(walls["none"])
    print(f"\ndefault scene as a process's first run ({count} runs of each way, each in a new process; medians)")
    for way, values in walls.items():
        wall = statistics.median(values)
        print(f"  {way:8s} {wall:8.3f} s  output share {(wall - base) / wall if way != 'none' else 0.0:.3f}")
    run = statistics.median(walls["run"])
    return (run - base) / run


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5, help="runs of each way (medians)")
    parser.add_argument("--csv", default="outputs/bench/output_share.csv")
    parser.add_argument("--scenes", nargs="+", choices=("default", "cube", "pile"),
                        default=["default", "cube", "pile"], help="which scenes to run")
    parser.add_argument("--first-runs", type=int, default=5,
                        help="first runs of the default scene, each in a new process (0: none)")
    args = parser.parse_args(argv)
    first_share = first_runs(args.first_runs) if args.first_runs else None
    from hybrid.app import writer_process
    why = writer_process.unavailable()
    if why is not None:
        sys.exit(f"no writer process here: {why}")
    # as in a process whose runs have written a while: the fork server up
    start = time.perf_counter()
    writer_process.fork_server.start()
    while not writer_process.fork_server.ready() and time.perf_counter() - start < 60:
        time.sleep(0.01)
    print(f"multiprocessing's fork server up in {time.perf_counter() - start:.2f} s (once per process)")
    answers, ends = [], []
    for _ in range(7):
        with tempfile.TemporaryDirectory(prefix="output_share_start_") as folder:
            start = time.perf_counter()
            writer = writer_process.WriterProcess(folder, "start.pvd")
            writer.state()
            answers.append(time.perf_counter() - start)
            start = time.perf_counter()
            writer.stop()
            ends.append(time.perf_counter() - start)
    print(f"a writer process answers its first job {1e3 * statistics.median(answers):.1f} ms after it is "
          f"started and ends in {1e3 * statistics.median(ends):.1f} ms (medians of 7)")
    work = Path(tempfile.mkdtemp(prefix="output_share_"))
    try:
        pile = work / "pile.toml"
        pile.write_text(pile_toml(1000, 1.0))
        scenes = {label: path for key, label, path in (
            ("default", "default", "default"), ("cube", "cube_1296", cube_scene(work)),
            ("pile", "rigid_pile_1000", pile)) if key in args.scenes}
        ways = tuple(WAYS)
        rows, shares = [], {}
        for label, scene in scenes.items():
            one_run(scene, "auto", work / "warm")      # numba caches, imports, the fork server
            walls = {w: [] for w in ways}
            cpus = {w: [] for w in ways}
            inside = {w: [] for w in ways}
            for _ in range(args.repeats):
                for way in ways:
                    wall, cpu, spent = one_run(scene, way, work / f"{label}_{way}")
                    walls[way].append(wall)
                    cpus[way].append(cpu)
                    inside[way].append(spent)
            sim = Simulation.from_toml(scene)
            simulated = sim.scene.simulation.duration
            base = statistics.median(walls["none"])
            base_cpu = statistics.median(cpus["none"])
            print(f"\n{label}: {simulated:g} s simulated, {sim.scene.simulation.output_fps:g} frames/s, "
                  f"{args.repeats} runs of each way (medians; machine shared with other jobs)")
            print(f"  {'way':8s} {'wall s':>8s} {'s/sim s':>8s} {'output share':>13s} {'CPU s':>7s} "
                  f"{'CPU share':>10s} {'stepping thread in output calls':>32s}")
            for way in ways:
                wall = statistics.median(walls[way])
                share = (wall - base) / wall if way != "none" else 0.0
                cpu = statistics.median(cpus[way])
                cpu_share = (cpu - base_cpu) / cpu if way != "none" else 0.0
                spent = statistics.median(inside[way])
                print(f"  {way:8s} {wall:8.3f} {wall / simulated:8.3f} {share:13.3f} {cpu:7.3f} "
                      f"{cpu_share:10.3f} {spent:9.3f} s ({spent / wall:.3f} of the run)")
                rows.append({"scene": label, "way": way, "repeats": args.repeats,
                             "wall_median_s": wall, "wall_per_simulated_s": wall / simulated,
                             "output_share": share, "cpu_median_s": cpu, "cpu_share": cpu_share,
                             "stepping_thread_output_s": spent,
                             "walls": " ".join(f"{w:.4f}" for w in walls[way])})
                if way == "auto":
                    shares[label] = share
            inline = statistics.median(walls["inline"])
            for way in ("thread", "process", "auto"):
                print(f"  {way} / inline wall: {statistics.median(walls[way]) / inline:.3f}")
        write_csv(args.csv, rows)
        if first_share is not None:
            shares["first run (hybrid run)"] = first_share
        worst = max(shares.values())
        print("output shares of the goal: " + ", ".join(f"{k} {v:.3f}" for k, v in shares.items()))
        print(f"\nwrote {args.csv}")
        print(f"GOAL output_share_of_run: measured={worst:.3f} target=0.10 "
              f"{'met' if worst < 0.10 else 'not met'}")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
