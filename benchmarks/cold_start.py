"""Cold start of ``hybrid run``: the first run after numba's caches are cleared against the second.

Each scene runs as ``hybrid run SCENE --out DIR --quiet`` in a fresh process, twice, with
``NUMBA_CACHE_DIR`` pointing at a new empty folder (so the first run compiles every kernel it
calls and writes the cache, the second loads them; the project's own ``__pycache__`` is not
touched). Both with the kernels warmed up before the step loop (hybrid.app.build.warm_up, the
default) and without (``HYBRID_NO_WARM_UP=1``). Printed per run: the process's wall and CPU time, the
step loop's wall time (summary.json ``wall_time``) and what came before it (imports, scene, build,
warm-up). Scenes: the default scene (rigid bodies) and a 1,296-tet soft cube dropped on the
ground (its first contact comes 0.1 s into the run).

Also checks the source: every ``numba.njit`` kernel of rigid/, fem/ and hybrid/ must say
``cache=True`` (listed otherwise).

    OPENBLAS_NUM_THREADS=1 python benchmarks/cold_start.py [--scenes default cube]
"""
import argparse
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path


sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import cube_scene, write_csv  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
DECORATOR = re.compile(r"@(?:nb\.|numba\.)?(?:njit|jit)\b(\([^)]*\))?")


def uncached_kernels():
    """``file:line`` of every numba kernel in rigid/, fem/ and hybrid/ without ``cache=True``."""
    found = []
    for folder in ("rigid", "fem", "hybrid"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            for number, line in enumerate(path.read_text().splitlines(), 1):
                match = DECORATOR.search(line)
                if match and "cache=True" not in (match.group(1) or ""):
                    found.append(f"{path.relative_to(ROOT)}:{number}")
    return found


def kernel_count():
    return sum(len(DECORATOR.findall(path.read_text()))
               for folder in ("rigid", "fem", "hybrid") for path in (ROOT / folder).rglob("*.py"))


def one_run(scene, out, cache, warm):
    """``(process wall s, process CPU s, step loop wall s, simulated s)`` of ``hybrid run scene``
    in a new process."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), HYBRID_NO_WARM_UP="0" if warm else "1")
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "hybrid", "run", scene, "--out", str(out), "--quiet"],
                          env=env, capture_output=True, text=True, cwd=ROOT)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    if done.returncode != 0:
        raise RuntimeError(f"hybrid run {scene} failed ({done.returncode}):\n{done.stderr[-2000:]}")
    summary = json.loads((Path(out) / "summary.json").read_text())
    return wall, cpu, summary["wall_time"], summary["simulated_time"]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=["default", "cube"], choices=["default", "cube"])
    parser.add_argument("--csv", default="outputs/bench/cold_start.csv")
    args = parser.parse_args(argv)

    uncached = uncached_kernels()
    print(f"numba kernels in rigid/, fem/, hybrid/: {kernel_count()}, without cache=True: "
          f"{len(uncached)}{' (' + ', '.join(uncached) + ')' if uncached else ''}")
    work = Path(tempfile.mkdtemp(prefix="cold_start_"))
    rows = []
    try:
        scenes = {"default": "default", "cube": str(cube_scene(work)) if "cube" in args.scenes else None}
        for label in args.scenes:
            print(f"\n{label}: hybrid run {scenes[label] if label == 'default' else 'cube.toml'} "
                  f"(machine shared with other jobs)")
            print(f"  {'warm-up':8s} {'run':6s} {'process s':>10s} {'CPU s':>8s} {'loop s':>8s} "
                  f"{'before loop s':>14s} {'loop s/sim s':>13s}")
            for warm in (True, False):
                cache = work / f"cache_{label}_{warm}"
                results = {}
                for run in ("first", "second"):
                    wall, cpu, loop, simulated = one_run(scenes[label], work / f"out_{label}", cache, warm)
                    results[run] = (wall, cpu)
                    print(f"  {'on' if warm else 'off':8s} {run:6s} {wall:10.2f} {cpu:8.2f} {loop:8.2f} "
                          f"{wall - loop:14.2f} {loop / simulated:13.3f}")
                    rows.append({"scene": label, "warm_up": warm, "run": run, "process_wall_s": wall,
                                 "process_cpu_s": cpu, "loop_wall_s": loop, "before_loop_s": wall - loop,
                                 "loop_per_simulated_s": loop / simulated})
                print(f"  {'':8s} first / second: process wall {results['first'][0] / results['second'][0]:.2f}, "
                      f"CPU {results['first'][1] / results['second'][1]:.2f}")
        write_csv(args.csv, rows)
        print(f"\nwrote {args.csv}")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
